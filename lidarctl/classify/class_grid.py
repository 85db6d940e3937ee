"""Class rasters: the land-cover classes of a classified cloud, a class GeoTIFF or class polygons on one
grid, for map-style accuracy (``lidarctl.checks.map_accuracy``).

Classes are ASPRS codes (``MAP_CLASSES``: building 6, tree 5, grass 3, road 11, bare ground 2,
water 9); ``OTHER`` (0) marks "none of the reference's classes" (outside every reference polygon),
``IGNORE`` (255) a cell without a label (nodata, no LiDAR point), which no measure counts.

* A cloud's class raster is the class of the highest point of each cell, noise (7, 18) left out:
  what a map or an orthophoto sees from above (a tree crown over grass is tree).
* A class GeoTIFF holds ASPRS codes in its first band; its nodata is IGNORE.
* Polygons (GeoPackage, GeoJSON, any OGR layer) carry their class in an attribute (an ASPRS code or
  a name of ``MAP_CLASSES``), or all count as one class (e.g. building footprints); a cell belongs to
  a polygon when its centre lies inside it.

Grids are north-up, in the CRS's units (``ClassGrid.transform``); ``cell_m`` is the cell size in
metres (a grid in feet has cells of ``cell_m / 0.3048`` ft).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pyproj
from rasterio.transform import Affine

from aerotri.core.errors import CrsError, InputError
from aerotri.geom import las
from lidarctl import io
from lidarctl.grid import check_grid
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

OTHER, IGNORE = 0, 255
MAP_CLASSES = {6: "building", 5: "tree", 3: "grass", 11: "road", 2: "bare ground", 9: "water"}
CLASS_LABELS = {OTHER: "other", 1: "unclassified", 4: "medium veg", 7: "low noise", 18: "high noise", **MAP_CLASSES}
# ASPRS classes of a classified cloud as map classes unless --map-pred says otherwise: medium
# vegetation (2-5 m above ground in lidarctl classify) is tree, as in the seeds' 1 m grass/tree split.
DEFAULT_CLOUD_MAP = {4: 5}
NOISE = (7, 18)
_NAMES = {**{v: k for k, v in MAP_CLASSES.items()}, "bare": 2, "ground": 2, "low vegetation": 3,
          "high vegetation": 5, "vegetation": 5, "other": OTHER}
# Bytes per cell while a class raster is built from a cloud (height max, class, the evaluation grids).
BYTES_PER_CELL = 24


@dataclasses.dataclass(frozen=True)
class ClassGrid:
    """A north-up grid: ``transform`` in CRS units, ``shape`` (rows, cols), ``cell_m`` in metres."""

    transform: Affine
    shape: tuple[int, int]
    crs: pyproj.CRS | None
    cell_m: float

    @property
    def cell_area_m2(self) -> float:
        return self.cell_m * self.cell_m

    def centres(self):
        """(x of the columns, y of the rows) of the cell centres, CRS units."""
        t = self.transform
        return t.c + t.a * (np.arange(self.shape[1]) + 0.5), t.f + t.e * (np.arange(self.shape[0]) + 0.5)


def class_code(value, where: str) -> int:
    """An ASPRS code (0-254) from an int or a class name (``MAP_CLASSES``, case-insensitive)."""
    if isinstance(value, (int, np.integer)) or (isinstance(value, str) and value.strip().isdigit()):
        code = int(value)
        if 0 <= code < IGNORE:
            return code
    elif isinstance(value, str) and value.strip().lower() in _NAMES:
        return _NAMES[value.strip().lower()]
    raise InputError(f"{where}: class {value!r}: expected an ASPRS code 0-254 or one of "
                     f"{', '.join(sorted(_NAMES))}")


def remap(classes: np.ndarray, mapping: dict) -> np.ndarray:
    """Classes with ``mapping`` (FROM -> TO, applied at once, not chained); IGNORE stays IGNORE."""
    lut = np.arange(256, dtype=np.uint8)
    for a, b in mapping.items():
        if a != IGNORE:
            lut[int(a)] = int(b)
    return lut[classes]


def grid_units(crs: pyproj.CRS | None, source: str) -> float:
    """Metres per CRS unit of a grid (1 without a CRS: coordinates taken as metres)."""
    if crs is None:
        return 1.0
    from lidarctl.units import units_of

    return units_of(crs, source).xy_m


def _grid_for_cloud(bounds, cell_m: float, crs, units: LengthUnits, path) -> ClassGrid:
    step = cell_m / units.xy_m
    x0, y0 = np.floor(bounds[0] / step) * step, np.floor(bounds[1] / step) * step
    ncols = int(np.floor((bounds[2] - x0) / step)) + 1
    nrows = int(np.floor((bounds[3] - y0) / step)) + 1
    check_grid(nrows, ncols, cell_m, BYTES_PER_CELL, f"{path}: class raster over the cloud's bounds", option="--res-m",
               hint="use a coarser --res-m")
    return ClassGrid(Affine(step, 0, x0, 0, -step, y0 + nrows * step), (nrows, ncols), crs, cell_m)


def cloud_grid(paths, cell_m: float, crs=None) -> tuple[ClassGrid, LengthUnits]:
    """The class grid over the union of LAS/LAZ files' header bounds (cells of ``cell_m`` metres aligned to
    multiples of the cell size) and the files' units; ``crs`` (``--crs``) for files without a CRS record.
    The files (strips) must share one CRS."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    lo, hi, first = np.full(2, np.inf), np.full(2, -np.inf), None
    for path in paths:
        header = las.read_header(path)
        resolved, units = io.resolve_crs_units(path, header, crs, require_crs=False)
        mins, maxs = np.asarray(header.mins, float), np.asarray(header.maxs, float)
        if header.point_count == 0 or not (np.isfinite(mins).all() and np.isfinite(maxs).all()):
            raise InputError(f"{path}: no points or absurd header bounds ({mins.tolist()} .. {maxs.tolist()})")
        if first is None:
            first = (path, resolved, units)
        else:
            io.require_same_crs(path, resolved, units, first)
        lo, hi = np.minimum(lo, mins[:2]), np.maximum(hi, maxs[:2])
    _, resolved, units = first
    if not units.known:
        units = LengthUnits()
    return _grid_for_cloud((lo[0], lo[1], hi[0], hi[1]), cell_m, resolved, units, paths[0]), units


def cloud_classes(paths, grid: ClassGrid, chunk_points: int = io.CHUNK_POINTS) -> np.ndarray:
    """uint8 class raster of classified LAS/LAZ files (strips) on ``grid`` (same CRS units as the files):
    the class of the highest non-noise point per cell over all files, IGNORE where none; read chunk by
    chunk."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    nrows, ncols = grid.shape
    top = np.full(nrows * ncols, -np.inf)
    out = np.full(nrows * ncols, IGNORE, np.uint8)
    t = grid.transform
    for path in paths:
        for _, chunk in las.iter_file_chunks(path, chunk_points):
            x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            cls = np.asarray(chunk.classification).astype(np.uint8)
            col = np.floor((x - t.c) / t.a).astype(np.int64)
            row = np.floor((y - t.f) / t.e).astype(np.int64)
            ok = (col >= 0) & (col < ncols) & (row >= 0) & (row < nrows) & ~np.isin(cls, NOISE) & np.isfinite(z)
            flat, z, cls = row[ok] * ncols + col[ok], z[ok], cls[ok]
            # Highest point per cell of this chunk: sort by (cell, z), take each cell's last.
            order = np.lexsort((z, flat))
            flat, z, cls = flat[order], z[order], cls[order]
            last = np.r_[flat[1:] != flat[:-1], True]
            flat, z, cls = flat[last], z[last], cls[last]
            higher = z > top[flat]
            top[flat[higher]] = z[higher]
            out[flat[higher]] = cls[higher]
    return out.reshape(nrows, ncols)


def read_class_raster(path, crs=None) -> tuple[np.ndarray, ClassGrid]:
    """(uint8 classes, grid) of a class GeoTIFF (ASPRS codes in band 1; nodata and values outside 0-254
    -> IGNORE). ``crs`` for a raster without one."""
    import rasterio

    from aerotri.geom.crs.definition import parse_crs

    try:
        src = rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: not a readable raster ({exc})") from None
    with src:
        if abs(src.transform.b) > 1e-12 or abs(src.transform.d) > 1e-12 or src.transform.e >= 0:
            raise InputError(f"{path}: only north-up rasters are supported (transform {tuple(src.transform)[:6]})")
        a = src.read(1, masked=True)
        r_crs = pyproj.CRS.from_wkt(src.crs.to_wkt()) if src.crs is not None else (
            parse_crs(crs, "--crs") if crs else None)
        transform = src.transform
    values = np.asarray(a.filled(0), float)
    bad = np.ma.getmaskarray(a) | ~np.isfinite(values) | (values < 0) | (values >= IGNORE) | (values != np.round(values))
    classes = np.where(bad, IGNORE, values).astype(np.uint8)
    cell_m = abs(transform.a) * grid_units(r_crs, str(path))
    if abs(abs(transform.a) - abs(transform.e)) > 1e-9 * abs(transform.a):
        raise InputError(f"{path}: cells must be square (size {transform.a} x {-transform.e})")
    return classes, ClassGrid(transform, classes.shape, r_crs, cell_m)


def regrid(grid: ClassGrid, cell_m: float) -> ClassGrid:
    """A grid of ``cell_m`` metre cells over the area of ``grid``, from its top-left corner."""
    unit_m = grid.cell_m / abs(grid.transform.a)
    step = cell_m / unit_m
    t = grid.transform
    ncols = max(1, int(np.floor(grid.shape[1] * abs(t.a) / step)))
    nrows = max(1, int(np.floor(grid.shape[0] * abs(t.e) / step)))
    check_grid(nrows, ncols, cell_m, BYTES_PER_CELL, "evaluation grid", option="--res", hint="use a coarser --res-m")
    return ClassGrid(Affine(step, 0, t.c, 0, -step, t.f), (nrows, ncols), grid.crs, cell_m)


def resample_nearest(classes: np.ndarray, src: ClassGrid, dst: ClassGrid) -> np.ndarray:
    """``classes`` on ``src`` sampled at the cell centres of ``dst`` (same CRS); IGNORE outside."""
    xs, ys = dst.centres()
    t = src.transform
    col = np.floor((xs - t.c) / t.a).astype(np.int64)
    row = np.floor((ys - t.f) / t.e).astype(np.int64)
    cok = (col >= 0) & (col < src.shape[1])
    rok = (row >= 0) & (row < src.shape[0])
    out = np.full(dst.shape, IGNORE, np.uint8)
    out[np.ix_(rok, cok)] = classes[np.ix_(row[rok], col[cok])]
    return out


@dataclasses.dataclass
class ClassPolygons:
    """Polygons of a vector layer with their ASPRS class codes, in the layer's CRS."""

    geometries: list
    codes: np.ndarray
    crs: pyproj.CRS | None
    path: Path


def read_class_polygons(path, class_field: str = "class", all_class: str | int | None = None,
                        layer=None) -> ClassPolygons:
    """Polygons of a GeoPackage/GeoJSON layer (pyogrio) and their classes: ``all_class`` for every
    polygon (e.g. 'building' for footprints), else the ``class_field`` attribute (code or name)."""
    import shapely
    from pyogrio.errors import DataSourceError, DataLayerError
    from pyogrio.raw import read

    path = Path(path)
    try:
        meta, _, wkb, fields = read(path, layer=layer)
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise InputError(f"{path}: not a readable vector layer ({exc})") from None
    crs = pyproj.CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    names = [str(f) for f in meta["fields"]]
    if all_class is not None:
        codes = np.full(len(wkb), class_code(all_class, "--reference-class"), np.uint8)
    elif class_field in names:
        col = fields[names.index(class_field)]
        codes = np.array([class_code(v, f"{path}: feature {k + 1}, field {class_field!r}")
                          for k, v in enumerate(col)], np.uint8)
    else:
        raise InputError(f"{path}: no field {class_field!r} (fields: {', '.join(names) or 'none'}); name the class "
                         "field with --class-field or give one class for all polygons with --reference-class")
    geoms, keep = [], []
    for k, blob in enumerate(wkb):
        g = shapely.from_wkb(blob) if blob is not None else None
        if g is None or g.is_empty:
            continue
        if g.geom_type not in ("Polygon", "MultiPolygon"):
            raise InputError(f"{path}: feature {k + 1} is a {g.geom_type}; class references must be polygons")
        geoms.append(g)
        keep.append(k)
    if not geoms:
        raise InputError(f"{path}: no polygons")
    return ClassPolygons(geoms, codes[keep], crs, path)


def rasterize_polygons(polys: ClassPolygons, grid: ClassGrid) -> tuple[np.ndarray, np.ndarray]:
    """(classes, polygon ids) on ``grid``: a cell takes the class and 1-based index of the polygon holding its
    centre (the later polygon where they overlap), OTHER and 0 outside all."""
    from rasterio.features import rasterize

    ids = rasterize(((g, k + 1) for k, g in enumerate(polys.geometries)), out_shape=grid.shape,
                    transform=grid.transform, fill=0, dtype="int32", all_touched=False)
    lut = np.r_[np.uint8(OTHER), polys.codes.astype(np.uint8)]
    return lut[ids], ids


def block_hulls(polys: ClassPolygons, join_m: float = 1.0) -> list:
    """Convex hulls of the blocks of polygons (polygons closer than ``join_m`` CRS units form one block):
    the area a partial reference (footprints of a few blocks) maps completely."""
    return hulls_of_blocks(polys.geometries, join_m)


def hulls_of_blocks(geometries: list, join: float = 1.0) -> list:
    """``block_hulls`` of shapely polygons (``join`` in CRS units; lidarctl check-vectors --within hull too)."""
    import shapely

    union = shapely.union_all([g.buffer(join / 2, join_style="mitre") for g in geometries])
    parts = list(union.geoms) if hasattr(union, "geoms") else [union]
    return [p.convex_hull.buffer(-join / 2, join_style="mitre") for p in parts]


def rasterize_mask(geometries: list, grid: ClassGrid) -> np.ndarray:
    """Boolean raster: cell centres inside any of ``geometries``."""
    from rasterio.features import rasterize

    if not geometries:
        return np.zeros(grid.shape, bool)
    return rasterize(((g, 1) for g in geometries), out_shape=grid.shape, transform=grid.transform, fill=0,
                     dtype="uint8").astype(bool)


def common_crs(a: pyproj.CRS | None, a_name, b: pyproj.CRS | None, b_name) -> pyproj.CRS | None:
    """The CRS two inputs share (one without a CRS takes the other's); CrsError when they differ."""
    from aerotri.geom.crs.definition import crs_label, same_horizontal

    if a is None or b is None:
        return a if b is None else b
    if not same_horizontal(a, b):
        raise CrsError(f"{a_name} is in {crs_label(a)} but {b_name} in {crs_label(b)}; give both in one CRS "
                       "(aerotri crs transform)")
    return a
