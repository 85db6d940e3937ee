"""Datum parameter sets and height anomaly models: applying them, inverting them, reading their files.

Estimating them from common points is ``fit`` and ``heights``; every coordinate operation of the
toolkit (``transform``) may include one.

Plane models (x = easting, y = northing in metres) and spatial models (X, Y, Z geocentric metres):

- ``helmert2d`` (4 parameters, similarity): ``X' = tx + s (x cos(theta) - y sin(theta))``,
  ``Y' = ty + s (x sin(theta) + y cos(theta))``, s = 1 + scale_ppm * 1e-6, theta counter-clockwise
  in the (easting, northing) plane. Note the textbook form with x = northing has the opposite sign.
- ``affine2d`` (6 parameters): ``X' = a0 + a1 x + a2 y``, ``Y' = b0 + b1 x + b2 y``.
- ``bursa-wolf7`` (7 parameters, coordinate-frame rotation convention, EPSG method 9607 /
  ``+proj=helmert +convention=coordinate_frame``): ``X' = T + (1 + m) R X`` with the small-angle
  ``R = [[1, rz, -ry], [-rz, 1, rx], [ry, -rx, 1]]``. The position-vector convention (EPSG 9606)
  has the rotation signs flipped; published parameter sets in that convention are applied with
  ``convention="position_vector"``.
- ``translation3`` (3 parameters): ``X' = X + T``.

Height anomaly (GNSS levelling): normal height H = h - zeta(x, y), zeta modelled as a ``plane``,
``quadratic`` or thin-plate spline (``tps``) of dx, dy = (x - x0, y - y0) / 1000 in kilometres.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.core.errors import ConfigError, InputError
from aerotri.core.textio import read_json
from aerotri.geom.crs.ellipsoid import ARCSEC_PER_RAD

MODELS = ("helmert2d", "affine2d", "bursa-wolf7", "translation3")
MIN_POINTS = {"helmert2d": 2, "affine2d": 3, "bursa-wolf7": 3, "translation3": 1}
SPATIAL = {"helmert2d": False, "affine2d": False, "bursa-wolf7": True, "translation3": True}
PARAMETER_NAMES = {
    "helmert2d": ("tx_m", "ty_m", "scale_ppm", "rotation_arcsec"),
    "affine2d": ("a0_m", "a1", "a2", "b0_m", "b1", "b2"),
    "bursa-wolf7": ("tx_m", "ty_m", "tz_m", "rx_arcsec", "ry_arcsec", "rz_arcsec", "scale_ppm"),
    "translation3": ("tx_m", "ty_m", "tz_m"),
}


# ----------------------------------------------------------------------------------------------
# The transformations themselves
# ----------------------------------------------------------------------------------------------

# parameter units as people write them -> the suffix of the parameter's name
_UNIT_SPELLINGS = {"m": "m", "metre": "m", "meter": "m", "metres": "m", "meters": "m",
                   "arcsec": "arcsec", "arc-sec": "arcsec", "arc sec": "arcsec", "arcsecond": "arcsec",
                   "arc-second": "arcsec", "arcseconds": "arcsec", "arc-seconds": "arcsec", "sec": "arcsec",
                   '"': "arcsec", "ppm": "ppm", "parts per million": "ppm", "deg": "deg", "degree": "deg",
                   "degrees": "deg"}


@dataclasses.dataclass
class Transformation:
    """A parameter set: ``apply`` maps (n, 2) grid or (n, 3) geocentric coordinates in metres.

    ``inverse()`` gives the same set applied backwards (``to_crs`` -> ``from_crs``), exactly: every
    model is affine, ``x' = A x + t``, so ``x = A^-1 (x' - t)``.
    """

    model: str
    parameters: dict  # name (with unit suffix) -> value
    from_crs: str = ""
    to_crs: str = ""
    std_devs: dict | None = None
    convention: str = "coordinate_frame"
    fit_extent: dict | None = None  # {"xmin_m", "ymin_m", "xmax_m", "ymax_m"} of the fit points, from_crs
    inverted: bool = False  # apply backwards (from_crs/to_crs are then already swapped)
    # the CRSs themselves (WKT; ``crs fit`` writes them beside the labels): a label names a PROJ string, a stated
    # datum (+datum=EPSG:nnnn) or a .prj file's CRS for people, and did not parse back (review 44); "" in files of
    # before
    from_crs_wkt: str = ""
    to_crs_wkt: str = ""

    def __post_init__(self):
        if self.model not in MODELS:
            raise InputError(f"unknown model {self.model!r}; choose one of {', '.join(MODELS)}")
        missing = [p for p in PARAMETER_NAMES[self.model] if p not in self.parameters]
        if missing:
            raise InputError(f"{self.model}: parameters missing: {', '.join(missing)}")
        if self.convention not in ("coordinate_frame", "position_vector"):
            raise InputError(f"unknown rotation convention {self.convention!r}")

    @property
    def spatial(self) -> bool:
        return SPATIAL[self.model]

    @property
    def from_crs_def(self) -> str:
        """The source CRS to parse: its WKT when the file records it, else its label (files of before)."""
        return self.from_crs_wkt or self.from_crs

    @property
    def to_crs_def(self) -> str:
        """The target CRS to parse: its WKT when the file records it, else its label (files of before)."""
        return self.to_crs_wkt or self.to_crs

    def inverse(self) -> "Transformation":
        """The set applied from ``to_crs`` to ``from_crs`` (the fit extent does not carry over)."""
        return dataclasses.replace(self, from_crs=self.to_crs, to_crs=self.from_crs, fit_extent=None,
                                   inverted=not self.inverted, from_crs_wkt=self.to_crs_wkt,
                                   to_crs_wkt=self.from_crs_wkt)

    def matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, t) of the forward model ``x' = A x + t`` (2x2 or 3x3 and 2 or 3)."""
        p = self.parameters
        if self.model == "helmert2d":
            s = 1.0 + p["scale_ppm"] * 1e-6
            theta = p["rotation_arcsec"] / ARCSEC_PER_RAD
            a, b = s * math.cos(theta), s * math.sin(theta)
            return np.array([[a, -b], [b, a]]), np.array([p["tx_m"], p["ty_m"]])
        if self.model == "affine2d":
            return np.array([[p["a1"], p["a2"]], [p["b1"], p["b2"]]]), np.array([p["a0_m"], p["b0_m"]])
        T = np.array([p["tx_m"], p["ty_m"], p["tz_m"]])
        if self.model == "translation3":
            return np.eye(3), T
        sign = 1.0 if self.convention == "coordinate_frame" else -1.0
        rx, ry, rz = (sign * p[k] / ARCSEC_PER_RAD for k in ("rx_arcsec", "ry_arcsec", "rz_arcsec"))
        return (1.0 + p["scale_ppm"] * 1e-6) * rotation_cf(rx, ry, rz), T

    def apply(self, coords):
        coords = np.asarray(coords, dtype=float)
        if self.inverted:
            A, t = self.matrix()
            return np.linalg.solve(A, (coords - t).T).T
        p = self.parameters
        if self.model == "helmert2d":
            s = 1.0 + p["scale_ppm"] * 1e-6
            theta = p["rotation_arcsec"] / ARCSEC_PER_RAD
            a, b = s * math.cos(theta), s * math.sin(theta)
            return _helmert2d(coords, a, b, p["tx_m"], p["ty_m"])
        if self.model == "affine2d":
            x, y = coords[:, 0], coords[:, 1]
            return np.column_stack(
                [p["a0_m"] + p["a1"] * x + p["a2"] * y, p["b0_m"] + p["b1"] * x + p["b2"] * y]
            )
        T = np.array([p["tx_m"], p["ty_m"], p["tz_m"]])
        if self.model == "translation3":
            return coords + T
        sign = 1.0 if self.convention == "coordinate_frame" else -1.0
        rx, ry, rz = (sign * p[k] / ARCSEC_PER_RAD for k in ("rx_arcsec", "ry_arcsec", "rz_arcsec"))
        return bursa_wolf(coords, np.array([*T, rx, ry, rz, p["scale_ppm"] * 1e-6]))

    def convention_lines(self) -> list:
        """How the rotations (and the 4 parameters' axes) are to be read, with the values of the other usual
        convention: a user copying rx, ry, rz into a position-vector tool (PROJ's +towgs84) or a 4-parameter set
        into a surveying program with X = northing gets the signs flipped otherwise, without a word."""
        p = self.parameters
        if self.model == "bursa-wolf7":
            other = "position_vector" if self.convention == "coordinate_frame" else "coordinate_frame"
            names = {"coordinate_frame": "coordinate frame (EPSG method 1032/9607, PROJ +convention=coordinate_frame)",
                     "position_vector": "position vector (EPSG method 1033/9606, PROJ +towgs84 and "
                                        "+convention=position_vector)"}
            flipped = ", ".join(f"{k.split('_')[0]} {-p[k]:+.4f}" for k in ("rx_arcsec", "ry_arcsec", "rz_arcsec"))
            return [f"Rotations in the {names[self.convention]} convention; X' = T + (1 + scale_ppm 1e-6) R X, "
                    f"geocentric metres, rotations in arc-seconds, scale in ppm.",
                    f"In the {names[other]} convention the same set has {flipped} arcsec (translations and scale "
                    "unchanged)."]
        if self.model == "helmert2d":
            return ["x = easting, y = northing; rotation counter-clockwise in the (easting, northing) plane: "
                    "E' = tx + s (E cos t - N sin t), N' = ty + s (E sin t + N cos t), s = 1 + scale_ppm 1e-6.",
                    "In the surveying form with X = northing, Y = easting (X' = dX + s (X cos a - Y sin a), "
                    f"Y' = dY + s (X sin a + Y cos a)): dX = {p['ty_m']:.4f} m, dY = {p['tx_m']:.4f} m, "
                    f"a = {-p['rotation_arcsec']:+.4f} arcsec (the opposite sign), scale the same."]
        if self.model == "affine2d":
            return ["x = easting, y = northing: E' = a0 + a1 E + a2 N, N' = b0 + b1 E + b2 N."]
        return []

    # JSON parameter file --------------------------------------------------------------------
    def to_dict(self) -> dict:
        units = {n: (n.rsplit("_", 1)[1] if "_" in n else "1") for n in PARAMETER_NAMES[self.model]}
        params = {}
        for n in PARAMETER_NAMES[self.model]:
            entry = {"value": float(self.parameters[n]), "unit": units[n]}
            if self.std_devs is not None and self.std_devs.get(n) is not None:
                entry["std_dev"] = float(self.std_devs[n])
            params[n] = entry
        out = {"model": self.model, "from_crs": self.from_crs, "to_crs": self.to_crs}
        if self.from_crs_wkt or self.to_crs_wkt:  # (what is read; the labels are for people)
            out |= {"from_crs_wkt": self.from_crs_wkt, "to_crs_wkt": self.to_crs_wkt}
        out["parameters"] = params
        if self.model == "bursa-wolf7":
            out["convention"] = self.convention
        lines = self.convention_lines()
        if lines:  # for the reader; "convention" (bursa-wolf7) is what is read
            out["conventions_explained"] = " ".join(lines)
        if self.fit_extent is not None:
            out["fit_extent"] = self.fit_extent
        if self.inverted:
            out["applied"] = "inverse"
        return out

    @classmethod
    def from_dict(cls, d: dict, source: str = "parameter file") -> "Transformation":
        try:
            model = d["model"]
            raw = d["parameters"]
            params = {k: float(v["value"] if isinstance(v, dict) else v) for k, v in raw.items()}
            sds = {k: float(v["std_dev"]) for k, v in raw.items() if isinstance(v, dict) and "std_dev" in v}
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: not a transformation parameter file ({exc!r})") from None
        # A parameter set typed from a report (trial-datum): a unit other than the name's (rotations in radians or
        # seconds of another name, a scale as a ratio) and a 7-parameter set without its rotation convention were
        # read as arc-seconds, ppm and coordinate frame without a word (a sign flip of 3" moves points ~0.1 m)
        for k, v in raw.items():
            unit = v.get("unit") if isinstance(v, dict) else None
            want = k.rsplit("_", 1)[1] if "_" in k else "1"
            # the same unit spelt otherwise is the unit (review 38: "metre" on tx_m, "arc-sec" on rx_arcsec refused)
            if unit is not None and _UNIT_SPELLINGS.get(str(unit).strip().lower(), str(unit)) == want:
                continue
            if unit is not None and str(unit) != want and k in PARAMETER_NAMES.get(model, ()):
                raise InputError(f"{source}: parameter {k} has unit {unit!r}; {k} is read in {want} (convert the "
                                 f"value: 1 rad = {ARCSEC_PER_RAD:.3f} arcsec, a scale ratio 1.0000027 or 2.7e-6 is "
                                 "scale_ppm 2.7)")
        if model == "bursa-wolf7" and "convention" not in d and any(
                params.get(k, 0.0) != 0.0 for k in ("rx_arcsec", "ry_arcsec", "rz_arcsec")):
            raise InputError(f"{source}: a bursa-wolf7 set needs its rotation convention: add \"convention\": "
                             "\"coordinate_frame\" (EPSG 1032/9607) or \"position_vector\" (EPSG 1033/9606, PROJ "
                             "+towgs84); the two differ in the sign of rx, ry, rz (aerotri crs fit writes it)")
        try:
            return cls(
                model,
                params,
                from_crs=str(d.get("from_crs", "")),
                to_crs=str(d.get("to_crs", "")),
                from_crs_wkt=str(d.get("from_crs_wkt") or ""),
                to_crs_wkt=str(d.get("to_crs_wkt") or ""),
                std_devs=sds or None,
                convention=d.get("convention", "coordinate_frame"),
                fit_extent=d.get("fit_extent"),
                inverted=d.get("applied") == "inverse",
            )
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None


def _helmert2d(xy, a, b, tx, ty):
    x, y = xy[:, 0], xy[:, 1]
    return np.column_stack([tx + a * x - b * y, ty + b * x + a * y])


def rotation_cf(rx, ry, rz):
    """Small-angle rotation matrix of the coordinate-frame convention (EPSG 9607)."""
    return np.array([[1.0, rz, -ry], [-rz, 1.0, rx], [ry, -rx, 1.0]])


def bursa_wolf(XYZ, p):
    """p = (tx, ty, tz, rx, ry, rz [rad], m [unitless]), coordinate-frame convention."""
    R = rotation_cf(*p[3:6])
    return p[:3] + (1.0 + p[6]) * (XYZ @ R.T)


def outside_extent(extent: dict | None, xy, margin_fraction: float = 0.1, margin_min_m: float = 100.0):
    """Boolean mask of points outside the fit extent widened by 10 % of its size (at least 100 m)."""
    xy = np.asarray(xy, dtype=float)
    if extent is None:
        return np.zeros(len(xy), dtype=bool)
    mx = max(margin_fraction * (extent["xmax_m"] - extent["xmin_m"]), margin_min_m)
    my = max(margin_fraction * (extent["ymax_m"] - extent["ymin_m"]), margin_min_m)
    return (
        (xy[:, 0] < extent["xmin_m"] - mx)
        | (xy[:, 0] > extent["xmax_m"] + mx)
        | (xy[:, 1] < extent["ymin_m"] - my)
        | (xy[:, 1] > extent["ymax_m"] + my)
    )


HEIGHT_MODELS = ("plane", "quadratic", "tps")
MIN_HEIGHT_POINTS = {"plane": 3, "quadratic": 6, "tps": 3}


def height_design_matrix(dx_km, dy_km, model):
    """Columns 1, dx, dy (plane) [, dx^2, dx dy, dy^2 (quadratic)] of the height anomaly surface, dx, dy in km."""
    one = np.ones_like(dx_km)
    cols = [one, dx_km, dy_km]
    if model == "quadratic":
        cols += [dx_km**2, dx_km * dy_km, dy_km**2]
    return np.column_stack(cols)


@dataclasses.dataclass
class HeightAnomalyModel:
    """zeta(x, y) in metres; ``crs`` names the horizontal CRS of x, y (e.g. ``EPSG:2361``), ``h_crs`` the geographic
    CRS whose ellipsoidal heights h the model was fitted on (e.g. ``EPSG:4326``: GNSS heights on WGS 84); None in
    files written before it was recorded (the operation then takes h on whichever ellipsoid it has them)."""

    model: str
    origin_m: tuple
    coefficients: list | None = None  # plane/quadratic, per km powers
    points_m: list | None = None  # tps: [[x, y, zeta], ...]
    smoothing: float = 0.0
    crs: str | None = None
    h_crs: str | None = None
    hull_m: list | None = None  # [[x, y], ...] counter-clockwise: the convex hull of the fit points (None before)

    def __post_init__(self):
        if self.model not in HEIGHT_MODELS:
            raise InputError(f"unknown height model {self.model!r}; choose one of {', '.join(HEIGHT_MODELS)}")
        self._rbf = None
        if self.hull_m is None and self.points_m is not None:  # a tps file written before hull_m: its points
            self.hull_m = convex_hull_m(np.asarray(self.points_m, dtype=float)[:, :2])

    def beyond_hull_m(self, x_m, y_m) -> np.ndarray | None:
        """Distance (m) of each point from the convex hull of the fit points, 0 inside; None when not recorded."""
        if self.hull_m is None:
            return None
        hull = np.asarray(self.hull_m, dtype=float)
        p = np.column_stack([np.asarray(x_m, dtype=float).ravel(), np.asarray(y_m, dtype=float).ravel()])
        inside = np.ones(len(p), dtype=bool)
        dist = np.full(len(p), np.inf)
        for a, b in zip(hull, np.roll(hull, -1, axis=0)):  # edge by edge: memory of the points only
            ab = b - a
            ap = p - a
            inside &= ab[0] * ap[:, 1] - ab[1] * ap[:, 0] >= 0.0
            t = np.clip((ap @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
            dist = np.minimum(dist, np.hypot(ap[:, 0] - t * ab[0], ap[:, 1] - t * ab[1]))
        return np.where(inside, 0.0, dist)

    def hull_margin_m(self) -> float:
        """How far past its points' hull the model is taken without a warning: 10 % of the hull's largest
        extent, at least 100 m (the parameter sets' rule, ``outside_extent``)."""
        hull = np.asarray(self.hull_m, dtype=float)
        return max(0.1 * float(np.max(np.ptp(hull, axis=0))), 100.0)

    def zeta_m(self, x_m, y_m):
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        dx = (x - self.origin_m[0]) / 1000.0
        dy = (y - self.origin_m[1]) / 1000.0
        if self.model in ("plane", "quadratic"):
            return height_design_matrix(dx.ravel(), dy.ravel(), self.model) @ np.asarray(self.coefficients)
        if self._rbf is None:
            pts = np.asarray(self.points_m, dtype=float)
            self._rbf = thin_plate_spline(pts[:, :2], pts[:, 2], self.origin_m, self.smoothing)
        return self._rbf(np.column_stack([dx.ravel(), dy.ravel()]))

    def normal_height(self, x_m, y_m, h_m):
        """H = h - zeta(x, y)."""
        return np.asarray(h_m, dtype=float) - self.zeta_m(x_m, y_m).reshape(np.shape(h_m))

    def to_dict(self) -> dict:
        d = {"model": self.model, "crs": self.crs, "origin_m": list(map(float, self.origin_m))}
        if self.h_crs is not None:
            import pyproj

            d["h_crs"] = self.h_crs
            d["h_datum"] = pyproj.CRS(self.h_crs).datum.name  # for the reader; h_crs is what is read
        if self.coefficients is not None:
            d["coefficients"] = [float(c) for c in self.coefficients]
            d["coefficient_units"] = "m, m/km, m/km^2 for 1, dx, dy, dx^2, dx dy, dy^2 (dx, dy in km)"
        if self.points_m is not None:
            d["points_m"] = [[float(v) for v in p] for p in self.points_m]
            d["smoothing"] = float(self.smoothing)
        if self.hull_m is not None:
            d["hull_m"] = [[float(v) for v in p] for p in self.hull_m]
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "height model file") -> "HeightAnomalyModel":
        try:
            return cls(
                d["model"],
                tuple(d["origin_m"]),
                coefficients=d.get("coefficients"),
                points_m=d.get("points_m"),
                smoothing=float(d.get("smoothing", 0.0)),
                crs=d.get("crs"),
                h_crs=d.get("h_crs"),
                hull_m=d.get("hull_m"),
            )
        except (KeyError, TypeError) as exc:
            raise InputError(f"{source}: not a height anomaly model file ({exc!r})") from None


def convex_hull_m(xy_m) -> list | None:
    """The convex hull of points (n, 2), counter-clockwise [[x, y], ...]; None when they span no area."""
    from scipy.spatial import ConvexHull, QhullError

    xy = np.asarray(xy_m, dtype=float)
    if len(xy) < 3:
        return None
    try:
        h = ConvexHull(xy)
    except (QhullError, ValueError):
        return None
    return xy[h.vertices].tolist()  # scipy: counter-clockwise for 2-D


def thin_plate_spline(xy_m, zeta_m, origin_m, smoothing):
    """zeta as a thin-plate spline with a linear trend over (x, y) - origin in km; called on (n, 2) km offsets."""
    from scipy.interpolate import RBFInterpolator

    d = (np.asarray(xy_m, dtype=float) - np.asarray(origin_m)) / 1000.0
    return RBFInterpolator(d, zeta_m, kernel="thin_plate_spline", smoothing=smoothing, degree=1)


# ----------------------------------------------------------------------------------------------
# Parameter and height model files (JSON written by ``aerotri crs fit`` / ``fit-heights``)
# ----------------------------------------------------------------------------------------------


def _load_json(path, what: str) -> dict:
    """A JSON object from a file; ``InputError`` naming the file when it is missing, unreadable or not JSON."""
    d = read_json(path, what)
    if not isinstance(d, dict):
        raise InputError(f"{path}: {what} must hold a JSON object")
    return d


def load_transformation(path) -> Transformation:
    """A parameter file of ``aerotri crs fit``."""
    return Transformation.from_dict(_load_json(path, "parameter file"), str(path))


def load_height_model(path) -> HeightAnomalyModel:
    """A height anomaly model file of ``aerotri crs fit-heights``."""
    d = _load_json(path, "height model file")
    if d.get("model") not in HEIGHT_MODELS:
        raise ConfigError(f"{path}: not a height anomaly model file (model {d.get('model')!r}; expected one of "
                          f"{', '.join(HEIGHT_MODELS)})")
    return HeightAnomalyModel.from_dict(d, str(path))
