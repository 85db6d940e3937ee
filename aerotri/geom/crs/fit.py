"""Datum/grid transformation parameters estimated from common points (Gauss-Markov least squares).

The models and their conventions (helmert2d, affine2d, bursa-wolf7, translation3) are defined where
they are applied, in ``aerotri.geom.crs.datum``.

Least squares (Gauss-Markov): observations l (target coordinates), v = A x^ - l (residual =
transformed source minus given target), sigma0^2 = v'Pv / r with redundancy r = n - u, parameter
covariance C = sigma0^2 (A'PA)^-1. Redundancy numbers r_i = 1 - h_ii (h the hat-matrix diagonal)
tell how well each point is controlled by the others: r_i near 0 means an error in that point
would not show in its residual (Baarda's internal reliability).
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from aerotri.core.errors import InputError
from aerotri.geom.crs.datum import MIN_POINTS, MODELS, PARAMETER_NAMES, Transformation, bursa_wolf, rotation_cf
from aerotri.geom.crs.ellipsoid import ARCSEC_PER_RAD, enu_rotation

# ----------------------------------------------------------------------------------------------
# Gauss-Markov least squares
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class GaussMarkov:
    x: np.ndarray  # estimated parameters
    Qxx: np.ndarray  # cofactor matrix (A'PA)^-1
    v: np.ndarray  # residuals A x - l
    redundancy: int
    sigma0: float  # a-posteriori sigma naught, nan when r = 0
    redundancy_numbers: np.ndarray  # r_i = 1 - h_ii per observation

    @property
    def covariance(self):
        if not np.isfinite(self.sigma0):
            return None
        return self.sigma0**2 * self.Qxx


def gauss_markov(A, l, weights=None, what: str = "model") -> GaussMarkov:
    """Solve v = A x - l in least squares (optional diagonal weights), with column equilibration
    and SVD so that translations of millions of metres and rotations of micro-radians coexist."""
    A = np.asarray(A, dtype=float)
    l = np.asarray(l, dtype=float)
    w = np.ones(len(l)) if weights is None else np.asarray(weights, dtype=float)
    sw = np.sqrt(w)
    col = np.linalg.norm(A * sw[:, None], axis=0)
    col[col == 0] = 1.0
    As = A * sw[:, None] / col
    U, s, Vt = np.linalg.svd(As, full_matrices=False)
    if s.size < A.shape[1] or s[-1] < 1e-10 * s[0]:
        raise InputError(
            f"{what}: the common points do not determine the parameters (coincident or collinear "
            "points; normal equations singular)"
        )
    xs = Vt.T @ ((U.T @ (l * sw)) / s)
    x = xs / col
    v = A @ x - l
    r = len(l) - A.shape[1]
    sigma0 = float(np.sqrt(np.sum(w * v * v) / r)) if r > 0 else float("nan")
    Qs = (Vt.T / s**2) @ Vt
    Qxx = Qs / np.outer(col, col)
    h = np.sum(U * U, axis=1)  # hat-matrix diagonal of the weighted problem
    return GaussMarkov(x, Qxx, v, r, sigma0, np.clip(1.0 - h, 0.0, 1.0))


# ----------------------------------------------------------------------------------------------
# Fitting
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ResidualRms:
    """RMS of the fit's residuals (m): east, north, horizontal (of the plan vectors) and up (None: a plan fit)."""

    e_m: float
    n_m: float
    horizontal_m: float
    u_m: float | None = None


@dataclasses.dataclass
class FitResult:
    transformation: Transformation
    ids: list
    residuals_m: np.ndarray  # (n, 2) dE dN or (n, 3) dE dN dU, transformed minus given
    redundancy_numbers: np.ndarray  # (n,) smallest r_i over each point's coordinates
    sigma0_m: float
    redundancy: int
    covariance: np.ndarray | None  # in the units of PARAMETER_NAMES
    warnings: list
    # what the z columns held (a spatial set: "ellipsoidal heights h ..."), in the report and the parameter file
    heights: str | None = None

    @property
    def rms_m(self) -> ResidualRms:
        v = self.residuals_m
        return ResidualRms(e_m=_rms(v[:, 0]), n_m=_rms(v[:, 1]), horizontal_m=_rms(np.hypot(v[:, 0], v[:, 1])),
                           u_m=_rms(v[:, 2]) if v.shape[1] == 3 else None)

    @property
    def correlation(self):
        if self.covariance is None:
            return None
        sd = np.sqrt(np.diag(self.covariance))
        return self.covariance / np.outer(sd, sd)

    def to_json(self) -> str:
        """The parameter file's text (``aerotri crs fit``): the transformation (``Transformation.to_dict``, what
        ``load_transformation`` reads) followed by the fit's report: counts, sigma0, RMS, residuals, correlation."""
        d = self.transformation.to_dict()
        d["n_points"] = len(self.ids)
        d["redundancy"] = self.redundancy
        d["sigma0_m"] = None if not np.isfinite(self.sigma0_m) else self.sigma0_m
        rms = self.rms_m
        d["rms_m"] = {"e": rms.e_m, "n": rms.n_m, "horizontal": rms.horizontal_m} | (
            {"u": rms.u_m} if rms.u_m is not None else {})
        names = ("de_m", "dn_m", "du_m")
        d["residuals"] = [
            {"id": pid, **{names[k]: float(r[k]) for k in range(len(r))}, "redundancy_number": float(ri)}
            for pid, r, ri in zip(self.ids, self.residuals_m, self.redundancy_numbers)
        ]
        corr = self.correlation
        d["correlation"] = None if corr is None else np.round(corr, 6).tolist()
        d["warnings"] = list(self.warnings)
        if self.heights is not None:
            d["heights"] = self.heights
        return json.dumps(d, indent=2, allow_nan=False) + "\n"


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


def _check_counts(model, ids, src, dst):
    if model not in MODELS:
        raise InputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    n = len(src)
    if len(dst) != n or len(ids) != n:
        raise InputError("source, target and ids must have the same number of points")
    seen = {}
    for i, pid in enumerate(ids):
        if pid in seen:
            raise InputError(f"duplicate point id {pid!r} (points {seen[pid] + 1} and {i + 1})")
        seen[pid] = i
    if n < MIN_POINTS[model]:
        raise InputError(
            f"{model} needs at least {MIN_POINTS[model]} common points ({len(PARAMETER_NAMES[model])} "
            f"parameters), got {n}; more points than the minimum give residuals and standard deviations"
        )


def geometry_warnings(en_m, model: str, redundancy_numbers=None, ids=None) -> list:
    """Warnings about the common points' layout in the plane (metres): collinear, clustered, or
    single points that nothing else checks (redundancy number below 0.1)."""
    en = np.asarray(en_m, dtype=float)
    out = []
    if len(en) >= 2:
        c = en - en.mean(axis=0)
        sv = np.sqrt(np.linalg.eigvalsh(c.T @ c / len(en)))  # ascending principal spreads
        spread = float(sv[-1])
        diameter = float(np.max(np.linalg.norm(en[:, None, :] - en[None, :, :], axis=-1)))
        # (a similarity is fixed by two points, a line of them too: no warning for helmert2d, trial s96 F11)
        if len(en) >= 3 and sv[0] < 0.05 * sv[-1] and model not in ("helmert2d", "translation3"):
            out.append(
                f"poor geometry: common points nearly collinear (principal spreads {sv[-1]:.0f} m and "
                f"{sv[0]:.0f} m); the transformation is weakly determined across that line"
            )
        if diameter < 1000.0:
            out.append(
                f"poor geometry: common points clustered within {diameter:.0f} m; the parameters hold only "
                "near them and errors grow with distance"
            )
        if len(en) >= 4:
            d = np.linalg.norm(c, axis=1)
            far = d > 3.0 * np.median(d) + 1e-9
            if far.any() and (~far).sum() >= len(en) - 2 and spread > 0:
                names = [str(ids[i]) if ids is not None else str(i + 1) for i in np.flatnonzero(far)]
                out.append(
                    "poor geometry: points clustered, with outlying point(s) " + ", ".join(names)
                    + " far from the others controlling the rest of the area alone"
                )
    if redundancy_numbers is not None:
        weak = np.flatnonzero(redundancy_numbers < 0.1)
        if len(weak) and len(weak) < len(redundancy_numbers):
            names = [str(ids[i]) if ids is not None else str(i + 1) for i in weak]
            out.append(
                "weakly checked point(s) " + ", ".join(names) + " (redundancy number < 0.1): an error in "
                "them would barely show in the residuals"
            )
    return out


def _point_min(r_obs, dim):
    return r_obs.reshape(-1, dim).min(axis=1)


def fit_plane(model: str, ids, src_xy_m, dst_xy_m, *, from_crs="", to_crs="", weights=None,
              check_blunders: bool = True) -> FitResult:
    """Fit ``helmert2d`` or ``affine2d`` between two metre grids; coordinates are (n, 2) easting, northing.
    ``check_blunders``: each point also checked against a fit of the others (``blunder_warnings``)."""
    ids = [str(i) for i in ids]
    src = np.asarray(src_xy_m, dtype=float)[:, :2]
    dst = np.asarray(dst_xy_m, dtype=float)[:, :2]
    _check_counts(model, ids, src, dst)
    # Reduce to centroids for conditioning (zone-prefixed eastings are ~4e7 m).
    s0, d0 = src.mean(axis=0), dst.mean(axis=0)
    x, y = (src - s0).T
    n = len(src)
    l = (dst - d0).reshape(-1)
    one, zero = np.ones(n), np.zeros(n)
    if model == "helmert2d":
        # unknowns a, b, tcx, tcy with a = s cos(theta), b = s sin(theta)
        A = np.empty((2 * n, 4))
        A[0::2] = np.column_stack([x, -y, one, zero])
        A[1::2] = np.column_stack([y, x, zero, one])
    elif model == "affine2d":
        A = np.zeros((2 * n, 6))
        A[0::2, :3] = np.column_stack([one, x, y])
        A[1::2, 3:] = np.column_stack([one, x, y])
    else:
        raise InputError(f"{model} is a spatial model; use fit_spatial")
    w = None if weights is None else np.repeat(np.asarray(weights, dtype=float), 2)
    gm = gauss_markov(A, l, w, what=model)
    ex, ey = s0
    if model == "helmert2d":
        a, b, tcx, tcy = gm.x
        # back from centroid-reduced to absolute translations: linear map J
        J = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [-ex, ey, 1, 0], [-ey, -ex, 0, 1]], dtype=float)
        tx = d0[0] + tcx - a * ex + b * ey
        ty = d0[1] + tcy - b * ex - a * ey
        s = math.hypot(a, b)
        theta = math.atan2(b, a)
        # (a, b, tx, ty) -> (tx, ty, scale_ppm, rotation_arcsec)
        K = np.array(
            [
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [1e6 * a / s, 1e6 * b / s, 0, 0],
                [-ARCSEC_PER_RAD * b / s**2, ARCSEC_PER_RAD * a / s**2, 0, 0],
            ]
        )
        values = (tx, ty, (s - 1.0) * 1e6, theta * ARCSEC_PER_RAD)
        M = K @ J
    else:
        c0, a1, a2, d0c, b1, b2 = gm.x
        a0 = d0[0] + c0 - a1 * ex - a2 * ey
        b0 = d0[1] + d0c - b1 * ex - b2 * ey
        M = np.eye(6)
        M[0, 1:3] = [-ex, -ey]
        M[3, 4:6] = [-ex, -ey]
        values = (a0, a1, a2, b0, b1, b2)
    names = PARAMETER_NAMES[model]
    cov = None if gm.covariance is None else M @ gm.covariance @ M.T
    sds = None if cov is None else dict(zip(names, np.sqrt(np.diag(cov))))
    extent = _extent(src)
    T = Transformation(model, dict(zip(names, map(float, values))), from_crs, to_crs, sds, fit_extent=extent)
    residuals = T.apply(src) - dst
    r_pt = _point_min(gm.redundancy_numbers, 2)
    warns = geometry_warnings(src, model, r_pt if gm.redundancy > 0 else None, ids)
    if gm.redundancy == 0:
        warns.append(f"no redundancy: {n} points is the minimum for {model}; residuals are zero by construction "
                     "and no standard deviations can be given")
    if check_blunders:
        def others(keep):
            f = fit_plane(model, [ids[k] for k in np.flatnonzero(keep)], src[keep], dst[keep],
                          weights=None if weights is None else np.asarray(weights)[keep], check_blunders=False)
            return f.transformation.apply(src[~keep]) - dst[~keep], f.sigma0_m
        warns += blunder_warnings(model, ids, r_pt, others)
    return FitResult(T, ids, residuals, r_pt, gm.sigma0, gm.redundancy, cov, warns)


def fit_spatial(model: str, ids, src_XYZ_m, dst_XYZ_m, *, dst_lat_lon_deg=None, from_crs="", to_crs="",
                src_plane_m=None, weights=None, check_blunders: bool = True) -> FitResult:
    """Fit ``bursa-wolf7`` or ``translation3`` on geocentric coordinates (n, 3) in metres; ``check_blunders``:
    each point also checked against a fit of the others (``blunder_warnings``).

    ``dst_lat_lon_deg`` (n, 2) turns residuals into local east/north/up; ``src_plane_m`` (n, 2)
    source grid coordinates for the geometry checks and the fit extent.
    """
    ids = [str(i) for i in ids]
    src = np.asarray(src_XYZ_m, dtype=float)
    dst = np.asarray(dst_XYZ_m, dtype=float)
    _check_counts(model, ids, src, dst)
    n = len(src)
    w = None if weights is None else np.repeat(np.asarray(weights, dtype=float), 3)
    names = PARAMETER_NAMES[model]
    if model == "translation3":
        A = np.tile(np.eye(3), (n, 1))
        gm = gauss_markov(A, (dst - src).reshape(-1), w, what=model)
        values = gm.x
        M = np.eye(3)
    elif model == "bursa-wolf7":
        # Gauss-Newton on the exact (1 + m) R product; the model is nearly linear, 2-3 steps suffice.
        p = np.zeros(7)
        for _ in range(10):
            f = (bursa_wolf(src, p) - dst).reshape(-1)
            J = _bursa_wolf_jacobian(src, p)
            gm = gauss_markov(J, -f, w, what=model)
            p = p + gm.x
            if np.max(np.abs(gm.x[:3])) < 1e-7 and np.max(np.abs(gm.x[3:])) < 1e-14:
                break
        J = _bursa_wolf_jacobian(src, p)
        gm = gauss_markov(J, -(bursa_wolf(src, p) - dst).reshape(-1), w, what=model)
        gm.v = (bursa_wolf(src, p) - dst).reshape(-1)
        gm.sigma0 = float(np.sqrt(np.sum(gm.v**2) / gm.redundancy)) if gm.redundancy > 0 else float("nan")
        values = np.concatenate([p[:3], p[3:6] * ARCSEC_PER_RAD, [p[6] * 1e6]])
        M = np.diag([1, 1, 1, ARCSEC_PER_RAD, ARCSEC_PER_RAD, ARCSEC_PER_RAD, 1e6])
    else:
        raise InputError(f"{model} is a plane model; use fit_plane")
    cov = None if gm.covariance is None else M @ gm.covariance @ M.T
    sds = None if cov is None else dict(zip(names, np.sqrt(np.diag(cov))))
    plane = None if src_plane_m is None else np.asarray(src_plane_m, dtype=float)[:, :2]
    T = Transformation(model, dict(zip(names, map(float, values))), from_crs, to_crs, sds,
                       fit_extent=None if plane is None else _extent(plane))
    v = T.apply(src) - dst
    if dst_lat_lon_deg is not None:
        ll = np.asarray(dst_lat_lon_deg, dtype=float)
        R = enu_rotation(ll[:, 0], ll[:, 1])
        v = np.einsum("nij,nj->ni", R, v)
    r_pt = _point_min(gm.redundancy_numbers, 3)
    if plane is None and dst_lat_lon_deg is not None:
        # local plane coordinates for the geometry check: ENU of the target points about their centroid
        ll = np.asarray(dst_lat_lon_deg, dtype=float)
        R0 = enu_rotation(ll[:, 0].mean(), ll[:, 1].mean())
        plane = ((dst - dst.mean(axis=0)) @ R0.T)[:, :2]
    if plane is not None and model == "bursa-wolf7" and n >= 3:
        c = plane - plane.mean(axis=0)
        across, along = np.sqrt(np.maximum(np.linalg.eigvalsh(c.T @ c / n), 0.0))
        if across < COLLINEAR_SPREAD_RATIO * along:
            # the rotation about the line is undetermined: the set fits the line and tilts the rest (trial s96 F3:
            # rx 963" +- 3044", 131 m of height 10 km off the line, written under exit 0)
            raise InputError(f"{model}: the {n} common points lie on a line (principal spreads {along:.0f} m along, "
                             f"{across:.1f} m across): the rotation about it is undetermined; add points off the "
                             "line (spread over the area), or fit translation3")
    warns = [] if plane is None else geometry_warnings(plane, model, r_pt if gm.redundancy > 0 else None, ids)
    corr_warn = _correlation_warning(cov, names, plane)
    if corr_warn:
        warns.append(corr_warn)
    size_warn = _implausible_set_warning(T)
    if size_warn:
        warns.append(size_warn)
    if gm.redundancy == 0:
        warns.append(f"no redundancy: {n} points is the minimum for {model}; no standard deviations")
    if check_blunders:
        def others(keep):
            f = fit_spatial(model, [ids[k] for k in np.flatnonzero(keep)], src[keep], dst[keep],
                            weights=None if weights is None else np.asarray(weights)[keep], check_blunders=False)
            d = f.transformation.apply(src[~keep]) - dst[~keep]
            if dst_lat_lon_deg is not None:  # local east, north, up as the residuals
                ll = np.asarray(dst_lat_lon_deg, dtype=float)[~keep]
                d = np.einsum("nij,nj->ni", enu_rotation(ll[:, 0], ll[:, 1]), d)
            return d, f.sigma0_m
        warns += blunder_warnings(model, ids, r_pt, others)
    return FitResult(T, ids, v, r_pt, gm.sigma0, gm.redundancy, cov, warns)


# a 7-parameter set from points spread less than this across their line is refused (rotation about it undetermined)
COLLINEAR_SPREAD_RATIO = 0.01
BLUNDER_FACTOR = 5.0  # times the others' sigma0 over sqrt(r_i): about 5 sigma of a good point's discrepancy
BLUNDER_FLOOR_M = 0.005  # below this no discrepancy is called a blunder (exact synthetic data)


def blunder_warnings(model: str, ids, redundancy_numbers, others, *, min_points: int | None = None,
                     axes=("east", "north", "up"), factor: float = BLUNDER_FACTOR,
                     min_redundancy: float = 0.1) -> list:
    """Points that the others place elsewhere: each point left out in turn, ``others(keep)`` returns its
    discrepancy (transformed minus given, m, per coordinate) under the fit of the rest and that fit's sigma0. A
    point is named when a coordinate's discrepancy exceeds ``BLUNDER_FACTOR`` x sigma0 / sqrt(r_i) (a good point's
    discrepancy has about sigma0 / sqrt(r_i) per coordinate) and ``BLUNDER_FLOOR_M``. One blunder among the
    points spreads into every residual of the fit and raises sigma0 without a warning otherwise (a typo in one
    coordinate of 7 points: sigma0 3.2 m, its own residual 10.7 m of 13.8 m). ``min_points``: the model's minimum
    (default ``MIN_POINTS[model]``); ``axes``: the names of the discrepancy's coordinates; ``factor`` and
    ``min_redundancy`` (the floor of r_i) as the caller's statistics need."""
    n = len(ids)
    if n - 1 < (MIN_POINTS[model] if min_points is None else min_points) + 1:  # the others need redundancy too
        return []
    out = []
    for i in range(n):
        keep = np.ones(n, bool)
        keep[i] = False
        d, s0 = others(keep)
        d = np.abs(np.asarray(d, dtype=float).reshape(-1))
        r = max(float(redundancy_numbers[i]), min_redundancy)
        if not np.isfinite(s0) or d.max() <= max(factor * s0 / math.sqrt(r), BLUNDER_FLOOR_M):
            continue
        axis = axes[int(np.argmax(d))]
        out.append(f"point {ids[i]} lies {d.max():.3f} m ({axis}) from where the other {n - 1} points put it (they "
                   f"fit with sigma0 {s0:.3f} m): a blunder (a typo, swapped digits, another point)? Correct it or "
                   "leave it out and fit again")
    return out


def _bursa_wolf_jacobian(XYZ, p):
    """d(model)/d(tx, ty, tz, rx, ry, rz, m), rows interleaved X, Y, Z per point."""
    n = len(XYZ)
    X, Y, Z = XYZ.T
    k = 1.0 + p[6]
    zero = np.zeros(n)
    J = np.zeros((n, 3, 7))
    J[:, :, :3] = np.eye(3)
    J[:, :, 3] = k * np.column_stack([zero, Z, -Y])
    J[:, :, 4] = k * np.column_stack([-Z, zero, X])
    J[:, :, 5] = k * np.column_stack([Y, -X, zero])
    J[:, :, 6] = XYZ @ rotation_cf(*p[3:6]).T
    return J.reshape(3 * n, 7)


def _correlation_warning(cov, names, plane):
    if cov is None or len(names) < 7:
        return None
    sd = np.sqrt(np.diag(cov))
    corr = np.abs(cov / np.outer(sd, sd))
    np.fill_diagonal(corr, 0.0)
    i, j = np.unravel_index(np.argmax(corr), corr.shape)
    if corr[i, j] < 0.999:
        return None
    size = "" if plane is None else f" over a {np.ptp(plane, axis=0).max() / 1000:.1f} km area"
    return (
        f"bursa-wolf7 parameters highly correlated{size} (|rho| = {corr[i, j]:.5f} between {names[i]} and "
        f"{names[j]}): the set works as a whole near the points but single parameters are not meaningful "
        "and extrapolation is unsafe; helmert2d or translation3 may be more robust for small areas"
    )


# A datum change between geodetic datums rotates by arc-seconds and scales by tens of ppm at most (EPSG's published
# Bursa-Wolf sets, and the trial's CGCS2000 -> Xian 1980: 3.2", 2.7 ppm); chosen from those, not fitted: a set 20 times
# larger is a wrong grid on one side (trial-datum: Xian 1980 CM 114E coordinates with --to the 6-degree CM 117E gave
# rz -10,792" and -988 ppm, 4 m residuals, no word beyond them)
PLAUSIBLE_ROTATION_ARCSEC = 60.0
PLAUSIBLE_SCALE_PPM = 100.0


def _implausible_set_warning(T) -> str | None:
    p = T.parameters
    if T.model != "bursa-wolf7":
        return None
    sd = T.std_devs or {}

    def beyond(k, limit):
        # beyond the limit by more than 3 of its own standard deviations: a small site's rotations are poorly
        # determined (review 38: 0.2 km with 30 mm of noise warned 10 of 20 good fits, blaming the grids)
        return abs(p[k]) - limit > 3.0 * float(sd.get(k) or 0.0)

    rot = {k: p[k] for k in ("rx_arcsec", "ry_arcsec", "rz_arcsec")}
    big = [f"{k.split('_')[0]} {v:+.1f}\" ({v / 3600.0:+.3f} deg)" for k, v in rot.items()
           if beyond(k, PLAUSIBLE_ROTATION_ARCSEC)]
    if beyond("scale_ppm", PLAUSIBLE_SCALE_PPM):
        big.append(f"scale {p['scale_ppm']:+.1f} ppm")
    if not big:
        return None
    return (f"implausible datum change: {', '.join(big)} (datum changes rotate by arc-seconds and scale by tens of "
            f"ppm at most; limits {PLAUSIBLE_ROTATION_ARCSEC:g}\" and {PLAUSIBLE_SCALE_PPM:g} ppm): are the "
            f"coordinates of both sides in the grids --from {T.from_crs} and --to {T.to_crs} name? Another zone or "
            "central meridian on one side (a 3- or 6-degree zone: 3 deg = 10,800\"), x and y swapped, heights that "
            "are not ellipsoidal, or a mistyped common point")


def _extent(xy):
    xy = np.asarray(xy, dtype=float)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return {"xmin_m": float(lo[0]), "ymin_m": float(lo[1]), "xmax_m": float(hi[0]), "ymax_m": float(hi[1])}
