"""LiDAR surface control: tie points on open ground observe the height of the DEM, tie points on roofs
the roof planes of the LiDAR (``lidarctl corners``' roof_planes.geojson).

A tie point ``P`` (local frame) at map position ``(x, y, h) = map(P)`` observes ``h = DEM(x, y)`` (cubic
convolution of the DEM, continuous in height and slope):
the residual ``e = h - DEM(x, y)`` (metres, along the vertical) with the standard deviation

    sigma^2 = sigma_dem^2 + (|grad DEM| * cell / 2)^2

(the DEM's stated precision and what interpolation loses on a slope over half a cell). Its
Jacobian with respect to the point is ``de/dP = (dh/dP) - DEM_x (dx/dP) - DEM_y (dy/dP)``, the rows of
``d map / d local`` at the point. The observation joins each point's 3 x 3 normal block before the
Schur elimination (``schur.reduced_camera_system``), so it costs nothing per image. The map positions and
``d map / d local`` come from per-point anchors (``local_frame.MapAnchors``: the exact conversion where a point
was last more than a metre away, a first-order step from there, < 0.2 um), not from a CRS transformation per
point and iteration.

Which tie point lies on the ground: points where the nDSM (when given) is above ``max_ndsm_m`` are
not candidates (roofs, trees); robust solves weigh the observations with Huber's kernel, and after
every robust round the adjustment (``solve._surface_gate``) keeps those whose height from their rays
alone is within ``gate_sigmas`` of the DEM (cars, low vegetation, DEM gaps are left out). Heights: the DEM must be in the project's horizontal CRS
and height system (its heights are read like the project's, as the local frame reads them).

Roof planes (``RoofPlanes``): a tie point whose map position lies inside the footprint of a roof face
(the face's points' footprint shrunk inward by a margin, so eaves, ridges and step edges are outside)
observes its distance from the face's plane ``Z = a (X - x0) + b (Y - y0) + c`` along the plane's normal,
in metres of the map axes (``map_unit_m``):

    e = (Z - plane(X, Y)) / s,    s = sqrt(1 + a^2 + b^2)
    sigma^2 = (sigma_fit^2 + sigma_strip_z^2 + sigma_strip_xy^2 (a^2 + b^2)) / s^2

``sigma_fit`` the plane's height sigma at the point from the covariance of its fit, ``sigma_strip_*`` the
LiDAR strip's georeferencing error (the one ``lidarctl corners`` added to its corners, written in the
file; ``plane_sigma_m`` overrides both), each projected onto the normal. The Jacobian is that of the
DEM's with the plane's slopes, divided by ``s``: the plane's unit normal in the local frame. A roof point
is a candidate whatever the nDSM says (the nDSM only tells the ground from what stands on it). Which
face a point lies on is decided in ``candidates`` and kept by ``observe`` (so the cost of a solve stays
smooth); the gate decides the candidates again after every robust round where the point's rays alone put
it (not where the surface pulled it: a point at the edge of a face would go in and out), then judges them.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numba
import numpy as np

from aerotri.core.errors import CrsError, InputError
from aerotri.geom.local_frame import LocalFrame, MapAnchors

log = logging.getLogger(__name__)


@dataclasses.dataclass
class HeightGrid:
    """A north-up height raster in memory: ``z[row, col]`` (float32 or float64, NaN = no height), pixel centres at
    ``x0 + (col + 0.5) res``, ``y0 - (row + 0.5) res``."""

    z: np.ndarray
    x0: float
    y0: float
    res: float
    # the positions and result of the last call: a solve samples the same positions twice (the cost of a step, then
    # the linearisation there), and each sample of a large block is a cache miss per point (0.35 us)
    _last: tuple | None = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def sample(self, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height and its gradient (dz/dx, dz/dy) at map positions by cubic convolution (Catmull-Rom, 4 x 4
        cells): the surface and its slope are continuous, so Gauss-Newton steps of the points do not
        stall on the kinks a bilinear surface has at every cell edge. Exact for planes. NaN outside the
        grid or where one of the 16 cells has no height."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        shape = np.broadcast(x, y).shape
        xb, yb = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
        last = self._last
        if last is not None and last[0].shape == xb.shape and np.array_equal(last[0], xb, equal_nan=True) \
                and np.array_equal(last[1], yb, equal_nan=True):
            h, hx, hy = (a.copy() for a in last[2:])
        else:
            z = self.z if self.z.dtype in (np.float32, np.float64) else self.z.astype(float)
            z = np.ascontiguousarray(z)
            # writable x, y (broadcast_to gives read-only views or writable copies): numba compiles one signature
            h, hx, hy = _sample_cubic(z, float(self.x0), float(self.y0), float(self.res),
                                      np.require(xb, requirements="W"), np.require(yb, requirements="W"))
            if len(xb) >= 10_000:  # only large calls are worth keeping
                self._last = (xb.copy(), yb.copy(), h.copy(), hx.copy(), hy.copy())
        return h.reshape(shape), hx.reshape(shape), hy.reshape(shape)


@numba.njit(cache=True)
def _sample_cubic(z, x0, y0, res, x, y):
    """``HeightGrid.sample`` point by point: Catmull-Rom weights of the 4 x 4 cells around each position."""
    n = len(x)
    H, W = z.shape
    h = np.full(n, np.nan)
    hx = np.full(n, np.nan)
    hy = np.full(n, np.nan)
    wu, du, wv, dv = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    for k in range(n):
        u = (x[k] - x0) / res - 0.5
        v = (y0 - y[k]) / res - 0.5
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        c0, r0 = np.floor(u), np.floor(v)
        if not (c0 >= 1 and r0 >= 1 and c0 < W - 2 and r0 < H - 2):
            continue
        _catmull_rom_taps(u - c0, wu, du)
        _catmull_rom_taps(v - r0, wv, dv)
        c, r = int(c0), int(r0)
        s = su = sv = 0.0
        for i in range(4):
            for j in range(4):
                zz = z[r - 1 + i, c - 1 + j]
                s += wv[i] * wu[j] * zz
                su += wv[i] * du[j] * zz
                sv += dv[i] * wu[j] * zz
        if np.isfinite(s):
            h[k], hx[k], hy[k] = s, su / res, -sv / res  # rows run south
    return h, hx, hy


@numba.njit(cache=True, inline="always")
def _catmull_rom_taps(t, w, d):
    t2, t3 = t * t, t * t * t
    w[0], w[1], w[2], w[3] = (-t3 + 2 * t2 - t) / 2, (3 * t3 - 5 * t2 + 2) / 2, (-3 * t3 + 4 * t2 + t) / 2, (t3 - t2) / 2
    d[0], d[1], d[2], d[3] = (-3 * t2 + 4 * t - 1) / 2, (9 * t2 - 10 * t) / 2, (-9 * t2 + 8 * t + 1) / 2, (3 * t2 - 2 * t) / 2


def read_height_grid(path, project_crs, project_heights=None, what: str = "DEM", bounds=None) -> HeightGrid:
    """A height raster in the project's CRS and height system (``bounds`` = (xmin, ymin, xmax, ymax) in
    map units: read only that window, plus a cell). Refuses another horizontal CRS or height system."""
    import rasterio
    from rasterio.windows import from_bounds

    from aerotri.geom.crs.definition import (crs_label, height_unit_m, heights_in_unit, horizontal_crs, parse_crs,
                                             same_horizontal, vertical_crs)
    from aerotri.geom.crs.raster_warp import open_north_up

    path = Path(path)
    with open_north_up(path, what, square=True, heights=True) as ds:
        crs = parse_crs(ds.crs.to_wkt(), f"{path} CRS")
        if not same_horizontal(crs, project_crs):
            raise CrsError(f"{path}: the {what} is in {crs_label(crs)}, the project in {crs_label(project_crs)}; "
                           f"warp it first (aerotri crs warp)")
        dem_v = vertical_crs(crs)
        # the project's heights in its grid's unit (``with_heights``): a DEM of EPSG:3855 in metres beside a feet
        # grid of EPSG:3855 heights is not the project's (review 43: its metres were read as feet); compared as
        # vertical CRSs (same_vertical takes compound ones: given the bare [project] heights it said "same" always)
        ours = (None if project_heights is None else
                heights_in_unit(project_heights, height_unit_m(horizontal_crs(project_crs))))
        to_ours = 1.0  # project height units per DEM height unit
        if dem_v is not None and (ours is None or not dem_v.equals(ours)):
            our_unit_m = float(ours.axis_info[0].unit_conversion_factor) if ours is not None else None
            try:  # the project's height system in another unit: scaled, as ortho's DEM operation converts it
                restated = heights_in_unit(dem_v, our_unit_m, f"{path} vertical CRS") if ours is not None else None
            except CrsError:
                restated = None
            if restated is None or not restated.equals(ours):
                theirs = f"{ours.name} ({crs_label(ours)})" if ours is not None else "ellipsoidal heights"
                raise CrsError(f"{path}: the {what}'s heights are in {dem_v.name} ({crs_label(dem_v)}), the "
                               f"project's in {theirs} ([project] heights): give a {what} in the project's height "
                               "system (another vertical datum is not converted here)")
            # review 48: refused although only the unit differs (EPSG:3855 in metres beside a feet grid's EGM2008
            # in US feet; NAVD88 in feet on a metre project), which ortho converts
            to_ours = float(dem_v.axis_info[0].unit_conversion_factor) / our_unit_m
            log.info(f"{path}: the {what}'s heights ({dem_v.name}) converted to the project's unit (x {to_ours:.9g})")
        if dem_v is None:
            log.info(f"{path}: the {what} declares no vertical CRS; its heights are taken as the project's")
        t = ds.transform
        if bounds is not None:
            xmin, ymin, xmax, ymax = bounds
            pad = 2 * t.a
            win = from_bounds(xmin - pad, ymin - pad, xmax + pad, ymax + pad, t).round_offsets().round_lengths()
            try:
                win = win.intersection(rasterio.windows.Window(0, 0, ds.width, ds.height))
            except rasterio.errors.WindowError:  # (new-user trial s51: a traceback, exit 1)
                b = ds.bounds
                raise InputError(f"{path}: the {what} does not reach the block: it covers x {b.left:.1f} .. "
                                 f"{b.right:.1f}, y {b.bottom:.1f} .. {b.top:.1f}, the window read under the block "
                                 f"x {xmin:.1f} .. {xmax:.1f}, y {ymin:.1f} .. {ymax:.1f} (another area, or "
                                 "positions in other units than the project's CRS?)") from None
        else:
            win = rasterio.windows.Window(0, 0, ds.width, ds.height)
        # heights of a float32 (or 8/16-bit) raster stay float32 (half the memory, nothing lost); a window of more
        # than MAX_GRID_CELLS is read averaged over f x f cells, so memory stays bounded whatever the DEM
        dtype = np.float32 if ds.dtypes[0] in ("float32", "uint8", "int8", "uint16", "int16") else np.float64
        f = max(1, int(np.ceil(np.sqrt(win.width * win.height / MAX_GRID_CELLS))))
        if f > 1:
            from rasterio.enums import Resampling

            shape = (max(1, int(win.height) // f), max(1, int(win.width) // f))
            win = rasterio.windows.Window(win.col_off, win.row_off, shape[1] * f, shape[0] * f)  # whole f x f cells
            log.warning(f"{path}: the {what} window under the block has {int(win.width)} x {int(win.height)} cells; "
                        f"read averaged over {f} x {f} cells ({abs(t.a) * f:g} map units) to stay within "
                        f"{MAX_GRID_CELLS // 1_000_000} M cells")
            a = ds.read(1, window=win, masked=True, out_shape=shape, resampling=Resampling.average)
            res = float(t.a) * f
            wt = ds.window_transform(win)
        else:
            res = float(t.a)
            wt = ds.window_transform(win)
            from rasterio.enums import MaskFlags

            flags = set(ds.mask_flag_enums[0])
            if flags <= {MaskFlags.nodata, MaskFlags.all_valid}:
                # no-data by value (or none): one array, the no-data cells set to NaN in place
                z = ds.read(1, window=win, out_dtype=dtype)
                if ds.nodata is not None and MaskFlags.nodata in flags:
                    z[z == ds.nodata if np.isfinite(ds.nodata) else ~np.isfinite(z)] = np.nan
                if to_ours != 1.0:
                    z *= to_ours
                return HeightGrid(z, float(wt.c), float(wt.f), res)
            a = ds.read(1, window=win, masked=True)
        a = (a if a.dtype == dtype else a.astype(dtype)).filled(np.nan)
    if to_ours != 1.0:
        a = a * np.asarray(to_ours, a.dtype)
    return HeightGrid(a, float(wt.c), float(wt.f), res)


MAX_GRID_CELLS = 400_000_000  # a height raster in memory: 1.6 GB as float32


ROOF_PLANES_FILE = "roof_planes.geojson"  # what lidarctl corners writes next to corners.csv
_PLANE_KEYS = ("x0", "y0", "a", "b", "c", "cov_abc_m")


@dataclasses.dataclass
class RoofPlanes:
    """Roof faces as surface control, in metres of the project's map axes (x, y, z times their units):
    plane ``Z = a (X - x0) + b (Y - y0) + c`` per face (a, b in m/m), ``cov_abc`` (K, 3, 3) its fit's
    covariance (m), the strip sigmas (m) and the footprints (shapely Polygons in map units)."""

    path: Path
    ids: list
    x0: np.ndarray
    y0: np.ndarray
    abc: np.ndarray  # (K, 3)
    cov_abc: np.ndarray  # (K, 3, 3)
    sigma_strip_xy_m: float
    sigma_strip_z_m: float
    footprints: np.ndarray  # (K,) shapely Polygons, map units
    xy_unit_m: float = 1.0  # metres per map unit of the footprints

    def __post_init__(self):
        import shapely

        self._tree = shapely.STRtree(self.footprints)

    def __len__(self) -> int:
        return len(self.ids)

    def face_of(self, x, y) -> np.ndarray:
        """Index of the footprint each map position (map units) lies in, -1 for none (or more than one:
        footprints overlapping in plan are at different heights, the point's face is unclear)."""
        import shapely

        x, y = np.asarray(x, float), np.asarray(y, float)
        out = np.full(len(x), -1, np.int64)
        ok = np.isfinite(x) & np.isfinite(y)
        if not len(self) or not ok.any():
            return out
        idx = np.flatnonzero(ok)
        pt, face = self._tree.query(shapely.points(x[idx], y[idx]), predicate="within")
        hits = np.bincount(pt, minlength=len(idx))
        one = hits[pt] == 1
        out[idx[pt[one]]] = face[one]
        return out


def read_roof_planes(path, project_crs, project_heights=None, plane_sigma_m: float | None = None) -> RoofPlanes:
    """The roof planes of ``path`` (a corners folder with roof_planes.geojson, or the file) for a project in
    ``project_crs`` / ``project_heights``. Refuses a missing file, another CRS or height system, and
    malformed features (InputError naming the file and the feature). ``plane_sigma_m``: the strip sigma
    (plan and height) instead of the file's."""
    import json

    import shapely
    from shapely.geometry import shape

    from aerotri.core.errors import InputError
    from aerotri.geom.crs.definition import crs_label, height_unit_m, linear_unit_m, parse_crs, same_horizontal, same_vertical, \
        vertical_crs

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: not found; expected a lidarctl corners folder with {ROOF_PLANES_FILE} (or the file)")
    f = path / ROOF_PLANES_FILE if path.is_dir() else path
    if not f.is_file():
        raise InputError(f"{f}: no roof planes file (lidarctl corners writes {ROOF_PLANES_FILE} into its output folder)")
    try:
        doc = json.loads(f.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        where = f" line {exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise InputError(f"{f}{where}: not a GeoJSON file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        raise InputError(f"{f}: expected a GeoJSON FeatureCollection of roof planes (lidarctl corners)")
    try:
        name = doc["crs"]["properties"]["name"]
    except (KeyError, TypeError):
        raise CrsError(f"{f}: names no CRS (a 'crs' member); the roof planes must be in the project's CRS, "
                       f"{crs_label(project_crs)}") from None
    crs = parse_crs(name, f"{f} crs")
    if not same_horizontal(crs, project_crs):
        raise CrsError(f"{f}: the roof planes are in {crs_label(crs)}, the project in {crs_label(project_crs)}; "
                       "run lidarctl corners on strips in the project's CRS")
    v = vertical_crs(crs)
    if v is not None and (project_heights is None or not same_vertical(v, project_heights)):
        theirs = crs_label(project_heights) if project_heights is not None else "ellipsoidal heights"
        raise CrsError(f"{f}: the roof planes' heights are in {crs_label(v)}, the project's in {theirs} "
                       "([project] heights)")

    def number(d, key, where, default=None):
        val = d.get(key, default)
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not np.isfinite(val):
            raise InputError(f"{f}: {where}{key} {val!r}: expected a finite number")
        return float(val)

    xy_m = linear_unit_m(crs)
    if "xy_unit_m" in doc and abs(number(doc, "xy_unit_m", "") - xy_m) > 1e-9:
        raise InputError(f"{f}: xy_unit_m {doc['xy_unit_m']} differs from the unit of its CRS ({xy_m:g} m)")
    z_m = number(doc, "z_unit_m", "", height_unit_m(crs))
    if plane_sigma_m is None:
        if doc.get("sigma_strip_xy_m") is None or doc.get("sigma_strip_z_m") is None:
            raise InputError(f"{f}: no sigma_strip_xy_m / sigma_strip_z_m (the LiDAR strips' georeferencing error); "
                             "give --plane-sigma-m")
        s_xy, s_z = number(doc, "sigma_strip_xy_m", ""), number(doc, "sigma_strip_z_m", "")
    else:
        s_xy = s_z = float(plane_sigma_m)
    rows, covs, polys, ids = [], [], [], []
    for k, feat in enumerate(doc["features"], 1):
        props = feat.get("properties") if isinstance(feat, dict) else None
        fid = props.get("id", k) if isinstance(props, dict) else k
        where = f"feature {k} ({fid}): "
        if not isinstance(props, dict) or not isinstance(feat.get("geometry"), dict):
            raise InputError(f"{f}: feature {k}: expected a Feature with geometry and properties")
        if feat["geometry"].get("type") != "Polygon":
            raise InputError(f"{f}: {where}geometry {feat['geometry'].get('type')!r}: expected a Polygon (the face's "
                             "footprint)")
        try:
            poly = shape(feat["geometry"])
        except (ValueError, TypeError, IndexError, AttributeError, shapely.errors.GEOSException) as exc:
            raise InputError(f"{f}: {where}bad Polygon coordinates ({exc})") from None
        if poly.is_empty or not poly.is_valid or not np.isfinite(poly.bounds).all():
            raise InputError(f"{f}: {where}the footprint is not a valid polygon ({shapely.is_valid_reason(poly)})")
        for key in _PLANE_KEYS:
            if key not in props:
                raise InputError(f"{f}: {where}no {key!r}; expected the plane z = a (x - x0) + b (y - y0) + c "
                                 "and cov_abc_m")
        cov = np.asarray(props["cov_abc_m"], dtype=object)
        if cov.shape != (3, 3) or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in cov.ravel()):
            raise InputError(f"{f}: {where}cov_abc_m: expected a 3 x 3 matrix of numbers (m)")
        cov = cov.astype(float)
        if not np.isfinite(cov).all() or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() < -1e-12:
            raise InputError(f"{f}: {where}cov_abc_m is not a covariance matrix (finite, symmetric, not negative)")
        a, b, c = (number(props, key, where) for key in ("a", "b", "c"))
        # to metres: slopes in z units per xy unit, heights in z units
        rows.append((number(props, "x0", where) * xy_m, number(props, "y0", where) * xy_m,
                     a * z_m / xy_m, b * z_m / xy_m, c * z_m))
        covs.append(cov)
        polys.append(poly)
        ids.append(fid)
    if not rows:
        log.warning(f"{f}: no roof planes")
    arr = np.array(rows, float).reshape(-1, 5)
    log.info(f"{f}: {len(rows)} roof planes")
    return RoofPlanes(f, ids, arr[:, 0], arr[:, 1], arr[:, 2:5], np.array(covs, float).reshape(-1, 3, 3), s_xy, s_z,
                      np.array(polys, dtype=object), xy_m)


@dataclasses.dataclass
class SurfaceControl:
    """The DEM (and optionally the nDSM and roof planes) a block's tie points are held to, in the block's
    local frame."""

    dem: HeightGrid
    frame: LocalFrame
    sigma_m: float = 0.15  # stated precision of the DEM heights
    ndsm: HeightGrid | None = None
    max_ndsm_m: float = 1.0  # above this height over the ground a point is on an object
    gate_sigmas: float = 3.0
    sigma_factor: float = 1.0  # the variance component's factor on the stated sigmas (reweighting)
    planes: RoofPlanes | None = None
    map_unit_m: tuple[float, float] = (1.0, 1.0)  # metres per unit of the map's x, y and of its heights
    face: np.ndarray | None = None  # roof face per point (-1: ground), decided by ``candidates``
    # the map positions of the points as the iterations move them, without a CRS transformation per point and
    # iteration (``MapAnchors``, shared by every copy ``of_points`` makes); ``index``: the block's points the
    # coordinates given are (``of_points``), None: all of them in order
    anchors: MapAnchors | None = None
    index: np.ndarray | None = None
    # the surface's systematic error (a LiDAR strip's georeferencing error, m, plan and height), taken as one 3D
    # offset per cell of ``bias_cell_m`` map units: considered in the covariances (``surface_bias``), 0: none
    bias_sigma_xy_m: float = 0.0
    bias_sigma_z_m: float = 0.0
    bias_cell_m: float = 500.0  # across the flight direction (map units)
    bias_length_m: float = 5000.0  # along it
    # (C,) bool per control point of the block: from the same LiDAR (lidarctl corners), its given coordinates
    # carry the same offset
    lidar_control: np.ndarray | None = None

    def __post_init__(self):
        if self.anchors is None:
            self.anchors = MapAnchors(self.frame)

    def _map(self, coords_local: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """(map coordinates, d map / d local or None) of points of the block (``MapAnchors.to_map``)."""
        index = self.index if self.index is not None and len(self.index) == len(coords_local) else None
        return self.anchors.to_map(coords_local, index, jacobian)

    def of_points(self, index: np.ndarray) -> "SurfaceControl":
        """This surface control for the block's points ``index`` (in that order): the roof faces ``candidates``
        decided for them. Whoever observes a subset of the points (the solve's tie points with two rays or more)
        takes this, so that each point keeps its face while it moves."""
        index = np.asarray(index)
        return dataclasses.replace(self, face=None if self.face is None else self.face[index],
                                   index=index if self.index is None else self.index[index])

    def _faces(self, m: np.ndarray) -> np.ndarray:
        """The roof face of each point: as ``candidates`` decided (for the same points, ``of_points``), else
        looked up at the points' positions (any other set of points)."""
        if self.planes is None:
            return np.full(len(m), -1, np.int64)
        if self.face is not None and len(self.face) == len(m):
            return self.face
        return self.planes.face_of(m[:, 0], m[:, 1])

    def observe(self, coords_local: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(e_m, J, sigma_m) for points (M, 3) in the local frame: residual height above the DEM (NaN where
        the DEM has none), for points on a roof face (``face``) the distance above its plane along the normal;
        its Jacobian (M, 3) with respect to the local coordinates (None unless ``jacobian``), its sigma (M,)."""
        p = np.asarray(coords_local, dtype=float)
        m, J_ml = self._map(p, jacobian)
        h, hx, hy = self.dem.sample(m[:, 0], m[:, 1])
        z_u = self.map_unit_m[1]  # heights and their residuals in metres, whatever the map's unit
        e = (m[:, 2] - h) * z_u
        sigma = self.sigma_factor * np.sqrt(self.sigma_m**2 + (np.hypot(hx, hy) * 0.5 * self.dem.res * z_u) ** 2)
        face = self._faces(m)
        roof = np.flatnonzero(face >= 0)
        if len(roof):
            pl, k = self.planes, face[roof]
            xy_m, z_m = self.map_unit_m
            dx, dy = m[roof, 0] * xy_m - pl.x0[k], m[roof, 1] * xy_m - pl.y0[k]
            a, b, c = pl.abc[k].T
            s = np.sqrt(1.0 + a * a + b * b)
            e[roof] = (m[roof, 2] * z_m - (a * dx + b * dy + c)) / s
            j = np.stack([dx, dy, np.ones_like(dx)], axis=1)
            fit2 = np.einsum("ni,nij,nj->n", j, pl.cov_abc[k], j)
            strip2 = pl.sigma_strip_z_m**2 + pl.sigma_strip_xy_m**2 * (a * a + b * b)
            sigma[roof] = self.sigma_factor * np.sqrt(fit2 + strip2) / s
            # slopes per map unit, for the Jacobian below (d map / d local is in map units)
            hx, hy = hx.copy(), hy.copy()
            hx[roof], hy[roof] = a * xy_m / z_m, b * xy_m / z_m
        if not jacobian:
            return e, None, sigma
        # d map / d local (J_ml): the inverse of the frame's Jacobian at the point's anchor
        J = (J_ml[:, 2, :] - hx[:, None] * J_ml[:, 0, :] - hy[:, None] * J_ml[:, 1, :]) * z_u  # metres per metre
        if len(roof):  # metres along the plane's normal: the unit normal in the local frame
            J[roof] /= s[:, None]
        return e, J, sigma

    def offset_partials(self, coords_local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d e / d (dx, dy, dz) (M, 3), map x y (M, 2)) of points (M, 3) in the local frame: how each residual of
        ``observe`` changes when the surface (DEM and roof planes) is offset by (dx, dy, dz) metres along the map
        axes, as a LiDAR strip's georeferencing error offsets it: ``(DEM_x, DEM_y, -1)`` in metres per metre, on a
        roof face ``(a, b, -1) / s`` (the distance along the normal)."""
        p = np.asarray(coords_local, dtype=float)
        m, _ = self._map(p, jacobian=False)
        _, hx, hy = self.dem.sample(m[:, 0], m[:, 1])
        xy_m, z_m = self.map_unit_m
        out = np.column_stack([hx * z_m / xy_m, hy * z_m / xy_m, -np.ones(len(p))])
        face = self._faces(m)
        roof = np.flatnonzero(face >= 0)
        if len(roof):
            a, b, _ = self.planes.abc[face[roof]].T
            out[roof] = np.column_stack([a, b, -np.ones(len(roof))]) / np.sqrt(1.0 + a * a + b * b)[:, None]
        return out, m[:, :2]

    def candidates(self, coords_local: np.ndarray) -> np.ndarray:
        """Points that may lie on the ground (inside the DEM and, with an nDSM, not on an object) or on a roof
        face (inside its footprint, whatever the nDSM says). Decides (and keeps, in ``face``) which face each
        point lies on."""
        p = np.asarray(coords_local, dtype=float)
        m, _ = self._map(p, jacobian=False)
        ok = np.isfinite(self.dem.sample(m[:, 0], m[:, 1])[0])
        if self.ndsm is not None:
            nd = self.ndsm.sample(m[:, 0], m[:, 1])[0]
            ok &= np.isfinite(nd) & (nd * self.map_unit_m[1] <= self.max_ndsm_m)
        if self.planes is None:
            return ok
        self.face = self.planes.face_of(m[:, 0], m[:, 1])
        return ok | (self.face >= 0)

    def off_dem(self, coords_local: np.ndarray) -> np.ndarray:
        """Points outside the DEM or on its nodata (bool per point)."""
        m, _ = self._map(np.asarray(coords_local, dtype=float), jacobian=False)
        return ~np.isfinite(self.dem.sample(m[:, 0], m[:, 1])[0])

    def point_class(self, n_points: int) -> np.ndarray:
        """0 ground (DEM), 1 roof plane, per point of the block (as ``candidates`` decided)."""
        if self.face is None or len(self.face) != n_points:
            return np.zeros(n_points, np.int8)
        return (self.face >= 0).astype(np.int8)

def _robust_cost(x: np.ndarray, huber_k: float) -> float:
    """``sum rho(x)`` of whitened residual sizes: twice Huber's robust cost (``huber_k`` > 0), or x'x."""
    if huber_k > 0:
        return float(np.sum(np.where(x > huber_k, 2 * huber_k * x - huber_k**2, x * x)))
    return float(np.sum(x * x))


def whitened(surface: SurfaceControl, coords_local: np.ndarray, active: np.ndarray, huber_k: float = 0.0):
    """The surface observations of points ``coords_local`` (M, 3) as the Schur kernel takes them: whitened
    residual ``r`` (observed - computed, M) and Jacobian of the prediction ``B`` (M, 3), zero for the inactive
    ones; with ``huber_k`` > 0 scaled by the square root of Huber's weight. Also the cost (``surface_cost``)."""
    e, J, sigma = surface.observe(coords_local)
    use = np.asarray(active, dtype=bool) & np.isfinite(e) & np.isfinite(J).all(axis=1)
    r = np.where(use, -e / sigma, 0.0)
    B = np.where(use[:, None], J / sigma[:, None], 0.0)
    x = np.abs(r)
    cost = _robust_cost(x, huber_k)
    if huber_k > 0:
        big = x > huber_k
        s = np.where(big, np.sqrt(huber_k / np.where(big, x, 1.0)), 1.0)
        r, B = r * s, B * s[:, None]
    return np.ascontiguousarray(r), np.ascontiguousarray(B), cost


def surface_cost(surface: SurfaceControl, coords_local: np.ndarray, active: np.ndarray, huber_k: float = 0.0) -> float:
    """``sum rho(r)`` of the active points' whitened surface residuals (what ``whitened`` adds to the cost),
    without the Jacobian: the cost of every trial step of the solve."""
    e, _, sigma = surface.observe(coords_local, jacobian=False)
    use = np.asarray(active, dtype=bool) & np.isfinite(e)
    return _robust_cost(np.abs(np.where(use, e / sigma, 0.0)), huber_k)


SURFACE_CLASSES = ("ground (DEM)", "roof planes")  # SurfaceControl.point_class 0, 1


@dataclasses.dataclass
class SurfaceStats:
    """What the surface control did, for the report (metres): over all candidates, and per class
    (``classes``: ground (DEM), roof planes; the same keys, residuals height above the DEM and distance
    above the roof plane along its normal)."""

    candidates: int  # tie points inside the DEM (and on the ground by the nDSM) or inside a roof face
    used: int  # in the final solve
    rejected: int  # candidates the gate removed
    rms_m: float | None  # of the used points' residuals (point - surface)
    median_m: float | None
    rms_normalised: float | None  # of the used residuals in their sigmas (about 1 when the sigmas are right)
    sigma_m: float
    max_ndsm_m: float | None
    classes: dict | None = None  # class name -> candidates, used, rejected, rms_m, median_m, rms_normalised
    n_planes: int | None = None  # roof faces read (None: no roof planes)
    plane_sigma_strip_m: tuple[float, float] | None = None  # strip sigma plan, height (m) at the roof planes


def _residual_stats(e: np.ndarray, sigma: np.ndarray, candidates: np.ndarray, active: np.ndarray) -> dict:
    used = active & np.isfinite(e)
    v, w = e[used], e[used] / sigma[used]
    return dict(candidates=int(candidates.sum()), used=int(used.sum()), rejected=int((candidates & ~active).sum()),
                rms_m=float(np.sqrt(np.mean(v * v))) if len(v) else None,
                median_m=float(np.median(v)) if len(v) else None,
                rms_normalised=float(np.sqrt(np.mean(w * w))) if len(w) else None)


def surface_stats(surface: SurfaceControl, coords_local: np.ndarray, candidates: np.ndarray, active: np.ndarray
                  ) -> SurfaceStats:
    e, _, sigma = surface.observe(coords_local, jacobian=False)
    total = _residual_stats(e, sigma, candidates, active)
    classes = n_planes = strip = None
    if surface.planes is not None:
        cls = surface.point_class(len(e))
        classes = {name: _residual_stats(e, sigma, candidates & (cls == k), active & (cls == k))
                   for k, name in enumerate(SURFACE_CLASSES)}
        n_planes = len(surface.planes)
        strip = (surface.planes.sigma_strip_xy_m, surface.planes.sigma_strip_z_m)
    return SurfaceStats(**total, sigma_m=surface.sigma_m, max_ndsm_m=surface.max_ndsm_m if surface.ndsm is not None else None,
                        classes=classes, n_planes=n_planes, plane_sigma_strip_m=strip)
