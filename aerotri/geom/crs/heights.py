"""Height anomaly surfaces (GNSS levelling): normal height H = h - zeta.

From points with both ellipsoidal height h (GNSS) and normal height H (levelling), the height anomaly
zeta = h - H is modelled over the block as

- ``plane``: zeta = c0 + c1 dx + c2 dy (at least 3 points),
- ``quadratic``: + c3 dx^2 + c4 dx dy + c5 dy^2 (at least 6 points),
- ``tps``: a thin-plate spline with a linear trend (scipy RBFInterpolator; at least 3 points),
  interpolating exactly unless ``smoothing`` > 0,

with dx, dy = (x - x0, y - y0) / 1000 in kilometres from the points' centroid (x = easting,
y = northing in metres of a projected CRS). Residuals are fitted minus given zeta; for an honest
accuracy figure the leave-one-out residuals (each point predicted from all the others) are also
reported: they are what a check point would show, and for an interpolating spline the only
meaningful ones.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from aerotri.core.errors import InputError
from aerotri.geom.crs.datum import (HEIGHT_MODELS, MIN_HEIGHT_POINTS, HeightAnomalyModel, convex_hull_m,
                                    height_design_matrix, thin_plate_spline)


@dataclasses.dataclass
class HeightFitResult:
    model: HeightAnomalyModel
    ids: list
    zeta_m: np.ndarray  # given h - H
    residuals_m: np.ndarray  # fitted minus given zeta
    loo_residuals_m: np.ndarray  # leave-one-out prediction minus given zeta
    sigma0_m: float
    warnings: list

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m**2)))

    @property
    def loo_rms_m(self) -> float:
        """RMS of the leave-one-out residuals; NaN when no point has one (the minimum number of points)."""
        loo = self.loo_residuals_m[np.isfinite(self.loo_residuals_m)]
        return float(np.sqrt(np.mean(loo**2))) if loo.size else float("nan")

    def to_json(self) -> str:
        """The model file's text (``aerotri crs fit-heights``): the model (``HeightAnomalyModel.to_dict``, what
        ``load_height_model`` reads) followed by the fit's report: counts, sigma0, RMS, residuals."""
        d = self.model.to_dict()
        d["n_points"] = len(self.ids)
        d["sigma0_m"] = None if not np.isfinite(self.sigma0_m) else self.sigma0_m
        d["rms_m"] = self.rms_m
        d["loo_rms_m"] = _finite(self.loo_rms_m)  # null at the minimum number of points: no point can be left out
        d["residuals"] = [
            {"id": pid, "zeta_m": float(z), "residual_m": float(r), "loo_residual_m": _finite(lr)}
            for pid, z, r, lr in zip(self.ids, self.zeta_m, self.residuals_m, self.loo_residuals_m)
        ]
        d["warnings"] = list(self.warnings)
        return json.dumps(d, indent=2, allow_nan=False) + "\n"


def _finite(v) -> float | None:
    return float(v) if np.isfinite(v) else None


def fit_height_anomaly(ids, x_m, y_m, h_m, H_m, *, model: str = "plane", smoothing: float = 0.0,
                       crs: str | None = None, h_crs: str | None = None) -> HeightFitResult:
    """Fit zeta = h - H over the points; see the module docstring for the models. ``crs``: the CRS of x, y;
    ``h_crs``: the geographic CRS of h (its datum's ellipsoid is the one the model is applied on), recorded."""
    from aerotri.geom.crs.fit import geometry_warnings

    if model not in HEIGHT_MODELS:
        raise InputError(f"unknown height model {model!r}; choose one of {', '.join(HEIGHT_MODELS)}")
    ids = [str(i) for i in ids]
    seen = {}
    for i, pid in enumerate(ids):
        if pid in seen:
            raise InputError(f"duplicate point id {pid!r} (points {seen[pid] + 1} and {i + 1})")
        seen[pid] = i
    x, y, h, H = (np.asarray(a, dtype=float) for a in (x_m, y_m, h_m, H_m))
    n = len(x)
    if n < MIN_HEIGHT_POINTS[model]:
        raise InputError(f"height model {model} needs at least {MIN_HEIGHT_POINTS[model]} points, got {n}")
    zeta = h - H
    origin = (float(x.mean()), float(y.mean()))
    dx, dy = (x - origin[0]) / 1000.0, (y - origin[1]) / 1000.0
    warns = geometry_warnings(np.column_stack([x, y]), model)
    if model in ("plane", "quadratic"):
        A = height_design_matrix(dx, dy, model)
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        if s[-1] < 1e-9 * s[0]:
            raise InputError(f"height model {model}: points collinear or coincident, surface undetermined")
        c = Vt.T @ ((U.T @ zeta) / s)
        res = A @ c - zeta
        r = n - A.shape[1]
        hat = np.sum(U * U, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            loo = np.where(hat < 1 - 1e-9, res / (1.0 - hat), np.nan)  # exact leave-one-out
        sigma0 = float(np.sqrt(res @ res / r)) if r > 0 else float("nan")
        hm = HeightAnomalyModel(model, origin, coefficients=c.tolist(), crs=crs, h_crs=h_crs,
                                hull_m=convex_hull_m(np.column_stack([x, y])))
        if r == 0:
            warns.append(f"no redundancy: {n} points is the minimum for {model}; residuals are zero, and no point "
                         "can be left out to check it (a levelled point more gives a check)")
        else:
            warns += _height_blunders(model, ids, res, loo, hat, r)
    else:
        pts = np.column_stack([x, y, zeta])
        hm = HeightAnomalyModel(model, origin, points_m=pts.tolist(), smoothing=smoothing, crs=crs,
                                h_crs=h_crs)
        try:
            res = hm.zeta_m(x, y) - zeta
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise InputError(f"height model tps: points do not determine a spline ({exc})") from None
        loo = np.full(n, np.nan)
        if n > 3:
            for i in range(n):
                keep = np.arange(n) != i
                try:
                    f = thin_plate_spline(pts[keep, :2], pts[keep, 2], origin, smoothing)
                    loo[i] = f(np.array([[dx[i], dy[i]]]))[0] - zeta[i]
                except (np.linalg.LinAlgError, ValueError):
                    pass
        sigma0 = float("nan")
        if n == MIN_HEIGHT_POINTS[model]:
            warns.append(f"no redundancy: {n} points is the minimum for {model}; the spline passes through them and "
                         "no point can be left out to check it (a levelled point more gives a check)")
    return HeightFitResult(hm, ids, zeta, res, loo, sigma0, warns)


def _height_blunders(model: str, ids, res, loo, hat, r: int) -> list:
    """A levelled point the others place elsewhere (``aerotri.geom.crs.fit.blunder_warnings``): its leave-one-out
    residual against the others' sigma0 (from the residuals without it: sum of squares less res_i^2 / (1 - h_i),
    r - 1 degrees of freedom) over the square root of its redundancy number 1 - h_i (not floored: a point on the
    hull of a quadratic's is an extrapolation), beyond Student's t of r - 1 degrees of freedom at 0.001 two-sided
    and at least the spatial fits' factor 5 (few degrees of freedom make sigma0 itself uncertain: 9 points of a
    quadratic, r 3, named two hull points beside the blunder). A height 0.25 m off among points fitting to 3 cm
    went without a word (trial s96 F6)."""
    from scipy.stats import t as student_t

    from aerotri.geom.crs.fit import BLUNDER_FACTOR, blunder_warnings

    ssr = float(res @ res)

    def others(keep):
        i = int(np.flatnonzero(~keep)[0])
        if r - 1 < 1 or not np.isfinite(loo[i]):
            return np.array([0.0]), float("nan")
        s0 = np.sqrt(max(ssr - res[i] ** 2 / (1.0 - hat[i]), 0.0) / (r - 1))
        return np.array([loo[i]]), float(s0)

    factor = max(BLUNDER_FACTOR, float(student_t.ppf(1 - 0.0005, r - 1))) if r > 1 else BLUNDER_FACTOR
    return blunder_warnings(model, ids, 1.0 - hat, others, min_points=MIN_HEIGHT_POINTS[model],
                            axes=("height anomaly",), factor=factor, min_redundancy=1e-9)
