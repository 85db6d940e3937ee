"""Height rasters (DEM, DSM, nDSM) for orthorectification, read from lidarctl GeoTIFFs.

A ``HeightRaster`` holds a north-up float32 grid in the project CRS with NaN for nodata; heights are
sampled bilinearly at pixel centres (``x = x_left + (col + 0.5) * res``).

Heights must be in the project's height system ([project] heights: ellipsoidal by default), the one of
the projection centres. A raster whose CRS is compound is taken by its parts: its horizontal part must
be the project's; when its vertical part is another height system (e.g. EGM2008 heights for an
ellipsoidal project), its heights are converted through the toolkit's coordinate-operation policy
(``dem_height_operation``: a PROJ geoid grid, or a height anomaly model from ``aerotri crs fit-heights``).
A raster without a vertical CRS is taken to be in the project's height system.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS
from rasterio.enums import MaskFlags
from rasterio.windows import Window, from_bounds

from aerotri.core.errors import CrsError, InputError
from aerotri.geom.crs.definition import (crs_label, height_crs, height_unit_m, heights_in_unit, horizontal_crs,
                                         length_unit_name, same_horizontal, vertical_crs)
from aerotri.geom.crs.raster_warp import anchor_grid, height_change, interpolate_anchors, open_north_up
from aerotri.geom.crs.transform import CrsTransformer
from aerotri.geom.crs.height_rasters import (refuse_above_ground, stated_height_unit_m, stated_unit_differs,
                                           undeclared_fill)

_log = logging.getLogger(__name__)


@dataclasses.dataclass
class HeightRaster:
    heights_m: np.ndarray  # (rows, cols) float32, NaN = nodata
    x_left_m: float
    y_top_m: float
    res_m: float
    crs: CRS | None = None
    source: str = "DEM"

    @property
    def bounds(self):
        h, w = self.heights_m.shape
        return (self.x_left_m, self.y_top_m - h * self.res_m, self.x_left_m + w * self.res_m, self.y_top_m)

    def sample(self, x_m, y_m) -> np.ndarray:
        """Bilinear heights at points (NaN outside the raster or next to nodata)."""
        return _bilinear(self.heights_m, self.x_left_m, self.y_top_m, self.res_m, np.asarray(x_m, float), np.asarray(y_m, float))

    def finite_range(self) -> tuple[float, float]:
        v = self.heights_m[np.isfinite(self.heights_m)]
        if v.size == 0:
            raise InputError(f"{self.source}: no valid heights")
        return float(v.min()), float(v.max())


def _bilinear(a, x0, y0, res, x, y):
    h, w = a.shape
    u = (x - x0) / res - 0.5
    v = (y0 - y) / res - 0.5
    # half a pixel beyond the outer centres still belongs to the raster: clamp there
    inside = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    i0 = np.minimum(np.floor(v).astype(int), max(h - 2, 0))
    j0 = np.minimum(np.floor(u).astype(int), max(w - 2, 0))
    fv = v - i0
    fu = u - j0
    i1 = np.minimum(i0 + 1, h - 1)
    j1 = np.minimum(j0 + 1, w - 1)
    z = (a[i0, j0] * (1 - fu) * (1 - fv) + a[i0, j1] * fu * (1 - fv) + a[i1, j0] * (1 - fu) * fv + a[i1, j1] * fu * fv)
    return np.where(inside, z, np.nan)


def open_height_raster(path, project_crs: CRS | None, what: str = "DEM"):
    """Open a height GeoTIFF and check it against the project CRS; returns the rasterio dataset."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: {what} not found")
    if path.is_dir():  # (new-user trial: "DEM not found" for the folder `lidarctl rasters` wrote)
        inside = sorted(p.name for p in path.glob("*.tif"))[:4]
        raise InputError(f"{path}: a folder, expected the {what} GeoTIFF file"
                         + (f" (it holds {', '.join(inside)})" if inside else ""))
    expected = f"; expected the project CRS {project_crs.to_string()}" if project_crs is not None else ""
    ds = open_north_up(path, what, no_crs_hint=expected, square=True, heights=True)
    try:
        if what in ("DEM", "DSM", "occlusion DSM"):
            refuse_above_ground(ds, path, f"the {what} must hold the {'terrain' if what == 'DEM' else 'surface'}'s "
                                          f"heights (lidarctl rasters' {'dem' if what == 'DEM' else 'dsm'}.tif)")
        refuse_stated_height_unit(ds, path, what)
    except InputError:
        ds.close()
        raise
    if project_crs is not None and not same_horizontal(CRS(ds.crs), CRS(project_crs)):
        got = crs_label(CRS(ds.crs))
        ds.close()
        raise CrsError(
            f"{path}: CRS mismatch: {what} is in {got} but the project (project.toml [project] crs) is in "
            f"{crs_label(CRS(project_crs))}; reproject the {what} (aerotri crs warp) or fix project.toml"
        )
    return ds


def refuse_stated_height_unit(ds, path, what: str = "DEM") -> None:
    """InputError when a raster whose CRS is 2D states its heights in another unit than that CRS's (its band's unit
    type or a VERTICAL_UNITS tag, what ``lidarctl check-heights`` asks a user to add): the orthos read heights in the
    CRS's unit (trial s99 lidmut H2: a UTM DEM tagged feet read as metres, exit 0 with the frames off, or "projection
    centres below the DEM"). A compound CRS says both and is converted."""
    crs = CRS(ds.crs)
    if crs.is_compound or len(crs.axis_info) >= 3:
        return
    stated, implied = stated_height_unit_m(ds), height_unit_m(crs)
    if not stated_unit_differs(stated, implied):
        return
    raise InputError(f"{path}: states its height unit as {length_unit_name(stated, long=True)} (its band unit or "
                     f"VERTICAL_UNITS tag) while its CRS, 2D, is in {length_unit_name(implied, long=True)}: the "
                     f"{what}'s heights are read in the CRS's unit; convert them (gdal_calc.py -A {path} --outfile "
                     f"OUT.tif --calc \"A*{stated / implied:.10g}\") or give the {what} a compound CRS whose vertical "
                     f"axis is in {length_unit_name(stated, long=True)}")


def require_overlap(ds, path, what: str, bounds, bounds_crs=None, area: str = "the block") -> None:
    """``InputError`` naming ``path`` unless the open raster ``ds`` overlaps ``bounds`` (xmin, ymin, xmax, ymax in
    ``bounds_crs``; None: the raster's CRS): a raster of another place (another zone's numbers under this
    zone's CRS, a neighbouring sheet) would otherwise be read as all nodata and change nothing."""
    from rasterio.warp import transform_bounds

    b = tuple(float(v) for v in bounds)
    if bounds_crs is not None and not same_horizontal(CRS(ds.crs), CRS(bounds_crs)):
        try:
            b = transform_bounds(rasterio.crs.CRS.from_wkt(CRS(bounds_crs).to_wkt()), ds.crs, *b, densify_pts=21)
        except Exception:  # noqa: BLE001 - no transformation between the two: nothing to compare, the reader decides
            return
    r = ds.bounds
    if not (b[0] < r.right and b[2] > r.left and b[1] < r.top and b[3] > r.bottom):
        raise InputError(f"{path}: the {what} covers none of {area} ({what} bounds "
                         f"{tuple(round(v, 1) for v in r)}, {area} {tuple(round(v, 1) for v in b)} in its CRS); "
                         f"a raster of another place or zone?")


def dem_height_operation(raster_crs, project_crs, project_heights=None, height_model=None,
                         allow_ballpark: bool = False, source: str = "DEM",
                         model_states_heights: bool = False) -> CrsTransformer | None:
    """The operation that brings a height raster's heights into the project's height system, or None.

    ``project_heights``: the project's vertical CRS (None: ellipsoidal heights); ``height_model``: a
    ``HeightAnomalyModel`` relating ellipsoidal and normal heights (used when PROJ has no geoid grid).
    ``model_states_heights``: the model was given for this raster (``ortho rectify --heights``, "for a DEM in
    normal heights"): a raster that declares no vertical CRS (``aerotri crs warp --heights`` writes none) is taken to
    be in normal heights and converted by it, said in the log (trial-site: the option was dropped for such a DEM, the
    DOM 5-14 m off under exit 0). Refuses (``CrsError``) what would be a silent ballpark height change, naming the
    grid to install."""
    vertical = vertical_crs(CRS(raster_crs))
    horizontal = horizontal_crs(CRS(project_crs))
    if vertical is None and height_model is not None and not model_states_heights and project_heights is None:
        _log.warning(f"{source}: declares no vertical CRS: its heights are taken as the project's (ellipsoidal); the "
                     "height model given (--heights) converts the DEM only: a surface in the DEM's normal heights "
                     "needs a vertical CRS of its own (or pass the DEM's file itself)")
    if vertical is None and height_model is not None and model_states_heights:
        if project_heights is not None:
            _log.warning(f"{source}: declares no vertical CRS, so its heights are taken as the project's "
                         f"({project_heights.name}); the height model given is not used")
            return None
        _log.info(f"{source}: declares no vertical CRS; its heights are taken as normal heights and made "
                  "ellipsoidal (the project's) by the height model given (--heights)")
        dst = height_crs(horizontal, None)
        return CrsTransformer(dst, dst, heights=height_model).inverse()
    # the project's heights are in its grid's unit (``with_heights``): EPSG:3855 beside a feet grid is EGM2008 in
    # feet, and a raster of EPSG:3855 in metres there is converted (review 43: taken as the project's, 3.28x)
    ours = None if project_heights is None else heights_in_unit(CRS(project_heights), height_unit_m(horizontal))
    if vertical is None or (ours is not None and vertical == ours):
        return None
    src = height_crs(horizontal, vertical)
    dst = height_crs(horizontal, ours)
    if height_model is not None and project_heights is None:
        # normal heights -> ellipsoidal by h = H + zeta: the model is the inverse of its H = h - zeta
        return CrsTransformer(dst, dst, heights=height_model).inverse()
    try:
        return CrsTransformer(src, dst, allow_ballpark=allow_ballpark)
    except CrsError as exc:
        raise CrsError(f"{source}: heights in {vertical.name} ({crs_label(vertical)}), the project's in "
                       f"{'ellipsoidal heights' if project_heights is None else project_heights.name}: {exc}") from None


def read_height_window(ds, bounds, margin_m: float = 0.0, what: str = "DEM", frame: str | None = None,
                       height_operation: CrsTransformer | None = None) -> HeightRaster:
    """Read the part of an open height raster covering ``bounds`` (project CRS) into a HeightRaster;
    ``height_operation`` (``dem_height_operation``) converts its heights to the project's system."""
    w = height_window(ds, bounds, margin_m, what, frame)
    a = read_heights(ds, w)
    res = ds.transform.a
    x0 = ds.transform.c + w.col_off * res
    y0 = ds.transform.f + w.row_off * ds.transform.e
    if height_operation is not None:
        a = convert_heights(a, x0, y0, res, height_operation)
    return HeightRaster(a, x0, y0, res, CRS(ds.crs), source=f"{ds.name}")


def read_heights(ds, window: Window) -> np.ndarray:
    """Band 1 of ``ds`` in ``window`` as float32, NaN where GDAL's mask says nodata: ``read(masked=True)`` filled with
    NaN. A float raster whose mask is its nodata value (or that has none) is compared here in one pass (GDAL's
    nodata mask: equal to the nodata value in the band's own type, or both NaN); a numpy masked array costs 5-10
    times the read of a frame's window (the true ortho reads two or three a frame). Other masks: GDAL's."""
    flags = list(ds.mask_flag_enums[0])
    dtype = np.dtype(ds.dtypes[0])
    nodata = ds.nodatavals[0]
    if dtype.kind == "f" and flags in ([MaskFlags.all_valid], [MaskFlags.nodata]) and _exact_in(nodata, dtype):
        raw = ds.read(1, window=window)
        a = raw.astype(np.float32, copy=False)
        if flags == [MaskFlags.nodata]:
            a[np.isnan(raw) if np.isnan(nodata) else raw == dtype.type(nodata)] = np.nan
        return a
    return ds.read(1, window=window, masked=True).astype(np.float32).filled(np.nan)


def _exact_in(nodata, dtype: np.dtype) -> bool:
    """``nodata`` (None: none) is a value of the float type ``dtype`` (GDAL compares in the band's type)."""
    if nodata is None or np.isnan(nodata):
        return True
    with np.errstate(over="ignore"):
        return float(dtype.type(nodata)) == nodata


def height_window(ds, bounds, margin_m: float = 0.0, what: str = "DEM", frame: str | None = None) -> Window:
    """The window (whole cells) of an open height raster that ``read_height_window`` reads for ``bounds``."""
    left, bottom, right, top = bounds
    win = from_bounds(left - margin_m, bottom - margin_m, right + margin_m, top + margin_m, ds.transform)
    c0 = max(0, int(math.floor(win.col_off)))
    r0 = max(0, int(math.floor(win.row_off)))
    c1 = min(ds.width, int(math.ceil(win.col_off + win.width)) + 1)
    r1 = min(ds.height, int(math.ceil(win.row_off + win.height)) + 1)
    if c1 <= c0 or r1 <= r0:
        b = ds.bounds
        raise InputError(
            f"{ds.name}: the {what} does not cover "
            f"{'frame ' + frame + ', footprint ' if frame else 'the area '}{tuple(round(v, 1) for v in bounds)} "
            f"(the {what}'s extent: X {b.left:.1f} .. {b.right:.1f}, Y {b.bottom:.1f} .. {b.top:.1f})"
            + (f"; give a {what} that covers the frame, or leave it out with --frames" if frame else "")
        )
    return Window(c0, r0, c1 - c0, r1 - r0)


def convert_heights(heights: np.ndarray, x_left: float, y_top: float, res: float,
                    operation: CrsTransformer) -> np.ndarray:
    """Heights of a north-up grid through ``operation`` (same horizontal CRS on both sides): the change,
    smooth over the grid and linear in the height, is evaluated on anchors and interpolated."""
    v = heights[np.isfinite(heights)]
    if v.size == 0:
        return heights
    zlo, zhi = float(v.min()), float(v.max())
    rows, cols = heights.shape

    def change(x, y):
        dz0, k = height_change(operation, x, y, zlo, zhi)
        return dz0.reshape(np.shape(x)), k.reshape(np.shape(x))

    D0, K, s = anchor_grid(change, x_left, y_top, res, cols, rows, spacing_px=64, tolerance=1e-3)
    dz = interpolate_anchors(D0, s, rows, cols) + interpolate_anchors(K, s, rows, cols) * heights
    return (heights + dz).astype(np.float32)


def read_height_raster(path, project_crs: CRS | None = None, what: str = "DEM") -> HeightRaster:
    with open_height_raster(path, project_crs, what) as ds:
        return read_height_window(ds, ds.bounds, what=what)


def warn_zero_fill(ds, path, what: str = "DEM") -> None:
    """A warning naming ``path`` when its cells at 0, or at a negative fill value (``NEGATIVE_FILL_VALUES``), look
    like an undeclared fill (``undeclared_fill``): the orthos there stand on that height."""
    found = undeclared_fill(ds)
    if found is None:
        return
    v = f"{found.value:g}"
    _log.warning(f"{path}: {100 * found.share:.1f} % of the {what}'s cells hold exactly {v} while its other heights "
                 f"are {found.lo:.6g} .. {found.hi:.6g} and it declares no nodata value: a fill (gdalwarp's beyond its "
                 f"source, a clipped {what})? The orthos there stand on height {v}; declare it (gdal_edit.py "
                 f"-a_nodata {v} {path}, or rio edit-info --nodata {v} {path}) unless it is ground at {v}")


def height_range(ds, max_cells: int = 1_000_000) -> tuple[float, float]:
    """Min and max height of a raster from a decimated read (the footprint search needs only a range)."""
    step = max(1, int(math.ceil(math.sqrt(ds.width * ds.height / max_cells))))
    a = ds.read(1, out_shape=(max(1, ds.height // step), max(1, ds.width // step)), masked=True,
                resampling=rasterio.enums.Resampling.nearest)
    v = a.compressed()
    v = v[np.isfinite(v)]  # NaN is nodata whatever the raster's nodata value is
    if v.size == 0:
        raise InputError(f"{ds.name}: no valid heights")
    return float(v.min()), float(v.max())
