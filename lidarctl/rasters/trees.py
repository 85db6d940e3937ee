"""Tree heights from a classified cloud (seed 004): canopy height model, forest stands, tree tops.

Canopy height model (CHM): the height above the ground DEM of the first returns of the vegetation
classes (``veg_classes``, ASPRS 3/4/5) and, at height 0, of the ground and water first returns (2, 9)
that fall between the crowns; the highest of them per cell is a vertex of a Delaunay TIN, and the TIN is
interpolated linearly at the cell centres. Triangles with an edge longer than ``max_edge_m`` are left
out, so gaps without returns (water, buildings, holes in the data) stay NODATA instead of being bridged;
cells below ``min_height_m`` (open ground, low shrubs) are NODATA too, which leaves NODATA wherever
there are no trees. Pit-free (``pit_free``, Khosravipour et al. 2014): first returns from inside a crown
or from the ground below it would cut pits into the crown; the CHM is the highest of that TIN and of
partial TINs of the vegetation returns above 2, 5, 10, 15 ... m, each with the same edge limit, so
within a crown the higher returns bridge the pits while at its edge the partial TINs end. The DEM is the one ``lidarctl rasters`` makes (mean height of the ground and water
points per cell, gaps filled by pull-push), sampled bilinearly at each return.

Stands: connected (8-neighbour) canopy regions of at least ``min_stand_area_m2``, polygonised
(``rasterio.features.shapes``); per stand the area and the mean, median, 90th, 95th percentile and
maximum of its CHM cells. Forest area = the stands' area.

Tree tops: local maxima of the CHM (smoothed by a Gaussian of ``smooth_px`` cells against maxima on
single branches) within a window whose radius grows with the height, ``top_radius_m +
top_radius_per_m * h`` (taller trees have wider crowns: a tall crown holds one top, small trees close
together keep theirs). A top's height is that of the highest return within one cell of it. The defaults
(1 m + 0.05 x h, smoothing 0.5 cells) are the best F-score of detection and commission on the simulator's
scene seed 1 (``bench/eval_trees.py``, scored on seed 2).

Units: every length and height here is in metres (a cloud in feet is scaled when read); the writers
put the CHM, the polygons and the points back in the cloud's CRS and units (``*_m`` fields are metres).
Arrays are north-up (row 0 at the north edge), NaN for NODATA.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numba
import numpy as np
from scipy import ndimage

from aerotri.core.errors import InputError, OptionError
from aerotri.core.settings import setting
from aerotri.core.figures import pyplot, save_png
from lidarctl.grid import GRID_BYTES_PER_CELL, check_grid, lowest_per_cell
from lidarctl.raster_ops import fill_nodata, reduce_grid, sample_bilinear
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

GROUND_CLASSES = (2, 9)
NOISE_CLASSES = (7, 18)
FILES = ("chm.tif", "trees.gpkg", "trees.png", "trees.json")
PERCENTILES = (50, 90, 95)
# height thresholds (m) of the pit-free CHM's partial TINs (Khosravipour et al. 2014)
PIT_FREE_STEPS_M = (2.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 80.0)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TreeSettings:
    """Options of ``lidarctl trees`` (all lengths and heights in metres, also for clouds in feet)."""

    res_m: float = setting(0.5, min=0.0, min_open=True, help="CHM cell size (m).")
    max_edge_m: float = setting(3.0, min=0.0, min_open=True,
                                help="TIN edge-length limit (m): longer triangles (gaps without returns) stay NODATA.")
    min_height_m: float = setting(2.0, min=0.0, help="Canopy below this height is not tree (NODATA) (m).")
    min_stand_area_m2: float = setting(200.0, min=0.0, help="Smallest connected canopy region that is a stand (m2).")
    top_radius_m: float = setting(1.0, min=0.0, help="Tree-top window radius at height 0 (m).")
    top_radius_per_m: float = setting(0.05, min=0.0, help="Tree-top window radius added per metre of height.")
    smooth_px: float = setting(0.5, min=0.0, help="Gaussian sigma (cells) of the CHM the tops are found on (0: none).")
    veg_classes: tuple[int, ...] = setting((3, 4, 5), min=0, max=255,
                                           help="Vegetation classes (comma-separated ASPRS codes).")
    pit_free: bool = setting(True, help="Pit-free CHM: the highest of partial TINs of the returns above 2, 5, 10, "
                                        "15 ... m (each with the edge limit), which bridge the holes first returns "
                                        "through the crowns leave.")

    def validate(self) -> None:
        for name, opt in (("res_m", "--res-m"), ("max_edge_m", "--max-edge-m")):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise OptionError(f"{opt} {v}: must be a positive length in metres", param=opt)
        if self.max_edge_m < self.res_m:
            raise OptionError(f"--max-edge-m {self.max_edge_m:g}: must be at least the cell size (--res-m "
                              f"{self.res_m:g})", param="--max-edge-m")
        for name, opt in (("min_height_m", "--min-height-m"), ("min_stand_area_m2", "--min-stand-area-m2"),
                          ("top_radius_m", "--top-radius-m"), ("top_radius_per_m", "--top-radius-per-m"),
                          ("smooth_px", "--smooth-px")):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise OptionError(f"{opt} {v}: must be a number >= 0", param=opt)
        if not self.veg_classes or any(not 0 <= int(c) <= 255 or int(c) in GROUND_CLASSES + NOISE_CLASSES
                                       for c in self.veg_classes):
            raise OptionError(f"--classes {','.join(map(str, self.veg_classes))}: expected ASPRS codes 0-255 other "
                              f"than ground/water {GROUND_CLASSES} and noise {NOISE_CLASSES}", param="--classes")


@dataclasses.dataclass(frozen=True)
class Grid:
    """Cells of ``res_m`` metres; the north-west corner at (x0, y_top), metres in the cloud's CRS."""

    res_m: float
    x0: float
    y_top: float
    nrows: int
    ncols: int

    def centres(self, rows, cols):
        return self.x0 + (np.asarray(cols) + 0.5) * self.res_m, self.y_top - (np.asarray(rows) + 0.5) * self.res_m


@dataclasses.dataclass
class Stand:
    stand_id: int
    cells: int
    area_m2: float
    mean_height_m: float
    p50_height_m: float
    p90_height_m: float
    p95_height_m: float
    max_height_m: float
    n_tops: int
    geometry: object  # shapely (Multi)Polygon in metres


@dataclasses.dataclass
class TreeTops:
    x: np.ndarray  # metres
    y: np.ndarray
    height_m: np.ndarray
    window_radius_m: np.ndarray
    stand_id: np.ndarray  # 0: in a canopy patch smaller than a stand


@dataclasses.dataclass
class TreeModel:
    grid: Grid
    dem: np.ndarray  # north-up, metres (filled)
    chm: np.ndarray  # north-up, metres, NaN where no trees
    stand_label: np.ndarray  # north-up, 0 outside the stands
    stands: list
    tops: TreeTops
    settings: TreeSettings
    n_points: int
    n_canopy_vertices: int


# --------------------------------------------------------------------------------------------------
# CHM


@numba.njit(cache=True)
def _rasterise_tin(px, py, ph, tri, *, max_edge2, x0, y0, res, nrows, ncols):
    """Linear interpolation of the TIN (px, py, ph; triangles ``tri``) at the centres of a south-up grid,
    triangles with an edge longer than sqrt(max_edge2) left out; NaN where no triangle is kept."""
    out = np.full((nrows, ncols), np.nan)
    for t in range(tri.shape[0]):
        a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
        ax, ay, bx, by, cx, cy = px[a], py[a], px[b], py[b], px[c], py[c]
        if ((ax - bx) ** 2 + (ay - by) ** 2 > max_edge2 or (bx - cx) ** 2 + (by - cy) ** 2 > max_edge2
                or (cx - ax) ** 2 + (cy - ay) ** 2 > max_edge2):
            continue
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if det == 0.0:
            continue
        j0 = max(int(np.ceil((min(ax, bx, cx) - x0) / res - 0.5)), 0)
        j1 = min(int(np.floor((max(ax, bx, cx) - x0) / res - 0.5)), ncols - 1)
        i0 = max(int(np.ceil((min(ay, by, cy) - y0) / res - 0.5)), 0)
        i1 = min(int(np.floor((max(ay, by, cy) - y0) / res - 0.5)), nrows - 1)
        for i in range(i0, i1 + 1):
            qy = y0 + (i + 0.5) * res
            for j in range(j0, j1 + 1):
                qx = x0 + (j + 0.5) * res
                l1 = ((by - cy) * (qx - cx) + (cx - bx) * (qy - cy)) / det
                l2 = ((cy - ay) * (qx - cx) + (ax - cx) * (qy - cy)) / det
                l3 = 1.0 - l1 - l2
                # a cell centre on a shared edge takes the first triangle's value (both give the same)
                if l1 >= -1e-9 and l2 >= -1e-9 and l3 >= -1e-9 and np.isnan(out[i, j]):
                    out[i, j] = l1 * ph[a] + l2 * ph[b] + l3 * ph[c]
    return out


def canopy_model(x, y, z, cls, return_number, settings: TreeSettings, name: str = "the cloud"):
    """(grid, DEM, CHM, highest return per cell, TIN vertices) north-up in metres from points in metres
    (the highest return's height above the DEM, NaN in cells without a first return); ``name`` is the
    input named in errors."""
    from lidarctl.classify.ground import delaunay_2d
    from lidarctl.rasters.products import grid_for_bounds, warn_cells_finer_than_points

    s = settings
    keep = ~np.isin(cls, NOISE_CLASSES)
    x, y, z, cls, rn = x[keep], y[keep], z[keep], cls[keep], return_number[keep]
    ground = np.isin(cls, GROUND_CLASSES)
    if not ground.any():
        raise InputError(f"{name}: no ground points (class 2); run 'lidarctl classify' first")
    veg = np.isin(cls, np.asarray(s.veg_classes))
    if not veg.any():  # an unclassified cloud, or classes that exist nowhere: not "0 stands"
        present = ", ".join(str(int(c)) for c in np.unique(cls))
        raise OptionError(f"{name}: no point of the vegetation classes {','.join(map(str, s.veg_classes))} (the "
                          f"cloud holds classes {present}); classify it first (lidarctl classify) or give the "
                          "classes it uses", param="--classes")
    res, x0, y0, nrows, ncols = grid_for_bounds(x.min(), y.min(), x.max(), y.max(), s.res_m)
    if nrows < 2 or ncols < 2:
        raise InputError(f"{name}: the points span {nrows} x {ncols} cells of {res:g} m; expected at least 2 x 2 "
                         "(one point or one spot, or a --res-m coarser than the cloud)", param="--res-m")
    check_grid(nrows, ncols, res, GRID_BYTES_PER_CELL, f"{name}: the CHM", option="--res-m",
               hint="use a coarser --res-m")
    # trial-forest: 0.05 m cells on Autzen (about 25 M cells) ran 9 minutes without a word
    warn_cells_finer_than_points(len(x), nrows * ncols, res, name)
    dem = fill_nodata(reduce_grid(x[ground], y[ground], z[ground], cell_m=res, x0=x0, y0=y0, nrows=nrows, ncols=ncols,
                                  how="mean"))
    first = (rn <= 1) & (veg | ground)
    if not (first & veg).any():
        log.info("%s: no first returns of the vegetation classes %s", name, s.veg_classes)
    px, py = x[first], y[first]
    h = np.where(veg[first], np.maximum(z[first] - sample_bilinear(dem, px, py, cell_m=res, x0=x0, y0=y0), 0.0), 0.0)
    # the highest return per cell: the canopy's top, a TIN of at most one vertex per cell
    cid = np.floor((py - y0) / res).astype(np.int64) * ncols + np.floor((px - x0) / res).astype(np.int64)
    top = lowest_per_cell(cid, -h)
    px, py, h = px[top], py[top], h[top]
    tin = np.full((nrows, ncols), np.nan)
    for t in (0.0, *PIT_FREE_STEPS_M) if s.pit_free else (0.0,):
        k = h >= t if t > 0 else np.ones(len(h), bool)
        if k.sum() < 3 or np.ptp(px[k]) == 0 or np.ptp(py[k]) == 0:
            break
        tri = delaunay_2d(px[k], py[k]).astype(np.int64)
        tin = np.fmax(tin,
                      _rasterise_tin(px[k] - x0, py[k] - y0, h[k], tri, max_edge2=s.max_edge_m ** 2, x0=0.0, y0=0.0,
                                     res=res, nrows=nrows, ncols=ncols))
    chm = np.where(tin >= max(s.min_height_m, 1e-6), tin, np.nan)
    highest = np.full(nrows * ncols, np.nan)
    highest[cid[top]] = h
    grid = Grid(res, x0, y0 + nrows * res, nrows, ncols)
    return grid, dem[::-1].copy(), chm[::-1].copy(), highest.reshape(nrows, ncols)[::-1].copy(), len(px)


# --------------------------------------------------------------------------------------------------
# Stands and tree tops


def _group_percentiles(label, values, n_groups, qs):
    """Linear-interpolation percentiles ``qs`` (0-100) of ``values`` per ``label`` 1..n_groups: (n_groups, len(qs))."""
    order = np.lexsort((values, label))
    lab, v = label[order], values[order]
    start = np.searchsorted(lab, np.arange(1, n_groups + 1))
    count = np.bincount(lab, minlength=n_groups + 1)[1:]
    out = np.empty((n_groups, len(qs)))
    for k, q in enumerate(qs):
        pos = start + q / 100.0 * (count - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, start + count - 1)
        out[:, k] = v[lo] + (pos - lo) * (v[hi] - v[lo])
    return out


def find_stands(chm: np.ndarray, res_m: float, min_area_m2: float):
    """(label raster, number of stands): 8-connected canopy regions of at least ``min_area_m2``."""
    lab, n = ndimage.label(np.isfinite(chm), np.ones((3, 3), bool))
    if n == 0:
        return lab.astype(np.int32), 0
    area = np.bincount(lab.ravel(), minlength=n + 1) * res_m * res_m
    keep = area >= min_area_m2
    keep[0] = False
    new = np.zeros(n + 1, np.int32)
    new[keep] = np.arange(1, int(keep.sum()) + 1)
    return new[lab], int(keep.sum())


def _disk(r_px: int) -> np.ndarray:
    k = np.arange(-r_px, r_px + 1)
    return (k[:, None] ** 2 + k[None, :] ** 2) <= r_px * r_px + 1e-9


def tree_tops(chm: np.ndarray, grid: Grid, settings: TreeSettings, stand_label: np.ndarray | None = None,
              highest: np.ndarray | None = None) -> TreeTops:
    """Local maxima of the CHM within a height-dependent window (module docstring); a top's height is the
    highest return (``highest``: per cell, else the CHM) within one cell of it."""
    s = settings
    valid = np.isfinite(chm)
    raw = np.where(valid, chm, 0.0)
    if s.smooth_px > max(chm.shape):  # its kernel would outgrow memory and flatten the whole CHM: no tops
        raise OptionError(f"{s.smooth_px:g} cells: a Gaussian wider than the CHM ({chm.shape[0]} x {chm.shape[1]} "
                          "cells) leaves no tree top", param="--smooth-px")
    surf = ndimage.gaussian_filter(raw, s.smooth_px) if s.smooth_px > 0 else raw
    radius_m = s.top_radius_m + s.top_radius_per_m * raw
    # a window that reaches across the CHM from any cell is the whole CHM: capped there, and its maximum is the
    # CHM's (a huge --top-radius-m stays bounded work)
    r_whole = int(np.ceil(np.hypot(*chm.shape)))
    r_px = np.clip(np.rint(np.minimum(radius_m / grid.res_m, r_whole)).astype(np.int64), 1, r_whole)
    is_top = np.zeros(chm.shape, bool)
    for r in np.unique(r_px[valid]):
        # one maximum filter per window size present (a handful): vectorised, no per-cell loop
        here = valid & (r_px == r)
        if r >= r_whole:
            is_top |= here & (surf >= max(float(surf.max()), 0.0))
            continue
        is_top |= here & (surf >= ndimage.maximum_filter(surf, footprint=_disk(int(r)), mode="constant", cval=0.0))
    # a flat top (equal cells) is one tree: one cell per 8-connected group, its highest raw cell
    lab, n = ndimage.label(is_top, np.ones((3, 3), bool))
    if n == 0:
        e = np.zeros(0)
        return TreeTops(e, e, e, e, np.zeros(0, np.int32))
    pos = np.array(ndimage.maximum_position(raw, lab, np.arange(1, n + 1)), dtype=np.int64).reshape(-1, 2)
    rows, cols = pos[:, 0], pos[:, 1]
    # the TIN at a cell centre is below the apex return the crown's height is measured by
    peak = raw if highest is None else np.fmax(raw, np.where(np.isfinite(highest), highest, 0.0))
    height = ndimage.maximum_filter(peak, size=3, mode="constant", cval=0.0)[rows, cols]
    x, y = grid.centres(rows, cols)
    sid = stand_label[rows, cols] if stand_label is not None else np.zeros(n, np.int32)
    order = np.argsort(-height, kind="stable")
    return TreeTops(x[order], y[order], height[order], (s.top_radius_m + s.top_radius_per_m * height)[order],
                    np.asarray(sid, np.int32)[order])


def _stand_polygons(stand_label: np.ndarray, transform) -> dict:
    """stand id -> shapely (Multi)Polygon in the coordinates of ``transform``."""
    import shapely
    from rasterio import features
    from shapely.geometry import shape

    parts: dict[int, list] = {}
    for geom, value in features.shapes(stand_label, mask=stand_label > 0, connectivity=8, transform=transform):
        parts.setdefault(int(value), []).append(shape(geom))
    # GDAL's 8-connected polygons join cells that touch at a corner by a ring that touches itself there, which
    # is not a valid polygon (QGIS flags it, overlay tools fail on it): made valid, the same cells and area
    return {k: _polygonal(shapely.make_valid(v[0] if len(v) == 1 else shapely.union_all(v)))
            for k, v in parts.items()}


def _polygonal(geom):
    """The polygon parts of ``geom`` (``make_valid`` may add the touching corners as points or lines)."""
    import shapely

    if geom.geom_type in ("Polygon", "MultiPolygon"):
        return geom
    return shapely.union_all([g for g in getattr(geom, "geoms", [geom]) if g.geom_type in ("Polygon", "MultiPolygon")])


def tree_model(x, y, z, cls, return_number, settings: TreeSettings | None = None, name: str = "the cloud") -> TreeModel:
    """CHM, stands and tree tops of points in metres (arrays); see the module docstring."""
    from rasterio.transform import from_origin

    s = settings or TreeSettings()
    s.validate()
    x, y, z = (np.asarray(v, float) for v in (x, y, z))
    cls, rn = np.asarray(cls), np.asarray(return_number)
    grid, dem, chm, highest, n_vertices = canopy_model(x, y, z, cls, rn, s, name)
    label, n = find_stands(chm, grid.res_m, s.min_stand_area_m2)
    tops = tree_tops(chm, grid, s, label, highest)
    stands = []
    if n:
        valid = label > 0
        lab, h = label[valid], chm[valid]
        cells = np.bincount(lab, minlength=n + 1)[1:]
        mean = np.bincount(lab, h, minlength=n + 1)[1:] / cells
        hmax = ndimage.maximum(h, lab, np.arange(1, n + 1))
        pct = _group_percentiles(lab, h, n, PERCENTILES)
        n_tops = np.bincount(tops.stand_id, minlength=n + 1)[1:]
        polys = _stand_polygons(label, from_origin(grid.x0, grid.y_top, grid.res_m, grid.res_m))
        for k in range(n):
            stands.append(Stand(k + 1, int(cells[k]), float(cells[k] * grid.res_m ** 2), float(mean[k]),
                                float(pct[k, 0]), float(pct[k, 1]), float(pct[k, 2]), float(hmax[k]),
                                int(n_tops[k]), polys.get(k + 1)))
    return TreeModel(grid, dem, chm, label, stands, tops, s, len(x), n_vertices)


@dataclasses.dataclass(frozen=True)
class ForestHeights:
    """Canopy heights within the stands (``TreesResult.forest_heights``), metres."""

    mean_height_m: float
    p50_height_m: float
    p90_height_m: float
    p95_height_m: float
    max_height_m: float


@dataclasses.dataclass(frozen=True)
class TreesResult:
    """What ``trees_from_files`` made (areas in square metres, heights in metres; trees.json holds more)."""

    stands: int
    forest_area_m2: float
    canopy_area_m2: float
    forest_heights: ForestHeights | None  # None: no stand
    tree_tops: int
    files: tuple[str, ...]


def _summary_document(model: TreeModel) -> dict:
    """The numbers of a tree model as trees.json holds them (metres)."""
    g, chm = model.grid, model.chm
    canopy = np.isfinite(chm)
    in_stand = model.stand_label > 0
    h = chm[in_stand]

    def stats(v):
        if not len(v):
            return None
        p = np.percentile(v, PERCENTILES)
        return {"mean_height_m": float(v.mean()), "p50_height_m": float(p[0]), "p90_height_m": float(p[1]),
                "p95_height_m": float(p[2]), "max_height_m": float(v.max())}

    t = model.tops
    return {
        "settings": dataclasses.asdict(model.settings), "points": model.n_points,
        "canopy_vertices": model.n_canopy_vertices,
        "grid": {"res_m": g.res_m, "rows": g.nrows, "cols": g.ncols},
        "canopy_area_m2": float(canopy.sum() * g.res_m ** 2),
        "forest_area_m2": float(in_stand.sum() * g.res_m ** 2),
        "forest_share_of_grid": float(in_stand.mean()) if in_stand.size else 0.0,
        "stands": len(model.stands), "forest_heights": stats(h),
        "tree_tops": int(len(t.x)), "tree_tops_in_stands": int((t.stand_id > 0).sum()),
        "tree_top_heights": None if not len(t.x) else {
            "mean_height_m": float(t.height_m.mean()), "max_height_m": float(t.height_m.max())},
        "per_stand": [{k: v for k, v in dataclasses.asdict(st).items() if k != "geometry"} for st in model.stands],
    }


# --------------------------------------------------------------------------------------------------
# Files


def _read_clouds(paths, crs):
    """Points of one or more classified LAS/LAZ files in one CRS (x, y, z in metres), its CRS and units."""
    from lidarctl import io

    xs, first = [], None
    for p in paths:
        c = io.read_cloud(p, crs=crs)
        if first is None:
            first = (p, c.crs, c.units)
        else:
            io.require_same_crs(p, c.crs, c.units, first)
        xs.append((c.x, c.y, c.z, c.classification, c.return_number))
    cat = [np.concatenate([a[k] for a in xs]) for k in range(5)]
    return cat, first[1], first[2]


def write_gpkg(model: TreeModel, path, crs_wkt: str, units) -> None:
    """Layers ``stands`` (polygons) and ``tree_tops`` (points) in the cloud's CRS and units."""
    import shapely
    import shapely.affinity

    from aerotri.core.vector_files import VectorLayer, write_layers

    scale = 1.0 / units.xy_m
    st = model.stands
    geoms = [shapely.affinity.scale(s.geometry, scale, scale, origin=(0, 0)) for s in st]
    stands = {"stand_id": np.array([s.stand_id for s in st], np.int32),
              "area_m2": np.array([s.area_m2 for s in st]),
              "n_tops": np.array([s.n_tops for s in st], np.int32),
              **{f: np.array([getattr(s, f) for s in st]) for f in
                 ("mean_height_m", "p50_height_m", "p90_height_m", "p95_height_m", "max_height_m")}}
    t = model.tops
    tops = {"tree_id": np.arange(1, len(t.x) + 1, dtype=np.int32), "height_m": t.height_m,
            "height": units.z_from_m(t.height_m), "window_radius_m": t.window_radius_m,
            "stand_id": t.stand_id.astype(np.int32)}
    write_layers(path, [VectorLayer("stands", "MultiPolygon", geoms, stands),
                        VectorLayer("tree_tops", "Point", shapely.points(units.xy_from_m(t.x), units.xy_from_m(t.y)),
                                    tops)], crs=crs_wkt)


def corner_axis_labels(x0_m: float, y0_m: float, units: LengthUnits) -> tuple[str, str]:
    """Axis labels of a map drawn from its lower-left corner (``x0_m``, ``y0_m``: metres) in the CRS's own unit,
    the corner given in it too: a cloud in feet reads its own easting and distances in feet (new-user trial: "metres
    east of easting 636000.7 ft" beside a chm.tif in feet)."""
    unit = units.xy_name
    return (f"{unit} east of easting {float(units.xy_from_m(x0_m)):.1f} {unit}",
            f"{unit} north of northing {float(units.xy_from_m(y0_m)):.1f} {unit}")


def preview_png(model: TreeModel, path, title: str, *, units: LengthUnits | None = None) -> None:
    """CHM with the stand outlines and the tree tops, in the CRS's units (``units``; metres when None) as chm.tif
    holds them: axes from the lower-left corner, the colour key in the height unit up to the 99.5th percentile (the
    key's arrow and label say where the highest cells are)."""
    plt = pyplot()

    units = units or LengthUnits()
    xy, zu = float(units.xy_m), float(units.z_m)
    g = model.grid
    w_m, h_m = g.ncols * g.res_m, g.nrows * g.res_m
    w, h = w_m / xy, h_m / xy
    chm = model.chm / zu
    fig, ax = plt.subplots(figsize=(9, min(12.0, 8.0 * h / max(w, 1e-9)) + 0.8))
    finite = np.isfinite(chm).any()
    vmax = float(np.nanpercentile(chm, 99.5)) if finite else 1.0
    top = float(np.nanmax(chm)) if finite else vmax
    im = ax.imshow(chm, cmap="viridis", vmin=0, vmax=vmax, extent=(0, w, 0, h), interpolation="nearest")
    clipped = top > vmax * (1 + 1e-6)
    label = f"tree height above ground ({units.z_name})"
    if clipped:  # (trial: a key ending at 15 m beside a summary's 20.6 m said nothing of the cells above it)
        label += f"\nkey to the 99.5th percentile {vmax:.1f}, highest {top:.1f}"
    fig.colorbar(im, ax=ax, shrink=0.8, label=label, extend="max" if clipped else "neither")
    x0, y0 = g.x0, g.y_top - h_m
    for st in model.stands:
        for poly in getattr(st.geometry, "geoms", [st.geometry]):
            xs, ys = poly.exterior.xy
            ax.plot((np.asarray(xs) - x0) / xy, (np.asarray(ys) - y0) / xy, color="k", lw=0.6)
    t = model.tops
    ax.plot((t.x - x0) / xy, (t.y - y0) / xy, "r.", ms=2.5, label=f"{len(t.x)} tree tops")
    ax.set_xlim(0, w)
    ax.set_ylim(0, h)
    ax.set_aspect("equal")
    xlabel, ylabel = corner_axis_labels(x0, y0, units)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


def trees_from_files(in_paths, outdir, settings: TreeSettings | None = None, crs=None) -> TreesResult:
    """``tree_model`` of classified LAS/LAZ file(s) (one CRS) written into ``outdir``: chm.tif (COG, heights in
    the CRS's vertical unit), trees.gpkg (layers stands, tree_tops), trees.png, trees.json. All files appear
    together or none (other files in ``outdir`` stay). Returns the summary (trees.json has it in full)."""
    from rasterio.transform import from_origin

    from aerotri.core.atomic import refuse_input_as_output
    from lidarctl.rasters import products as rs
    from aerotri.geom.crs.definition import length_unit_name

    s = settings or TreeSettings()
    s.validate()
    paths = [Path(p) for p in ([in_paths] if isinstance(in_paths, (str, Path)) else in_paths)]
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    outdir = Path(outdir)
    for f in FILES:
        refuse_input_as_output(outdir / f, paths, "OUTDIR")
    if outdir.exists() and not outdir.is_dir():
        raise OptionError(f"{outdir}: OUTDIR is a file, expected a folder", param="OUTDIR")
    rs.refuse_the_other_chm(outdir, "trees")
    names = ", ".join(map(str, paths))
    (x, y, z, cls, rn), crs_found, units = _read_clouds(paths, crs)
    model = tree_model(x, y, z, cls, rn, s, names)
    result = _summary_document(model)
    result.update(inputs=[str(p) for p in paths], crs=crs_found.to_string() if crs_found else None, **units.as_dict())
    g = model.grid
    transform = from_origin(g.x0 / units.xy_m, g.y_top / units.xy_m, g.res_m / units.xy_m, g.res_m / units.xy_m)
    z_unit = length_unit_name(units.z_m, long=True)
    tags = {"LINEAR_UNITS": length_unit_name(units.xy_m, long=True), "VERTICAL_UNITS": z_unit, "CELL_SIZE_M": f"{g.res_m:g}",
            "MAX_EDGE_M": f"{s.max_edge_m:g}", "MIN_HEIGHT_M": f"{s.min_height_m:g}"}

    def write(tmp: Path) -> None:
        rs.write_cog(tmp / "chm.tif", (model.chm / units.z_m).astype(np.float32), transform, crs_found,
                     unit=z_unit, description=f"CHM: tree height above the DEM ({z_unit}); "
                     f"TIN, edges <= {s.max_edge_m:g} m, >= {s.min_height_m:g} m", tags=tags)
        write_gpkg(model, tmp / "trees.gpkg", crs_found.to_wkt(), units)
        area = result["forest_area_m2"]
        preview_png(model, tmp / "trees.png", f"{paths[0].name}: CHM at {g.res_m:g} m, {len(model.stands)} stands "
                    f"({area / 1e4:.2f} ha), {len(model.tops.x)} tree tops", units=units)
        (tmp / "trees.json").write_text(json.dumps(result, indent=2) + "\n")

    files = tuple(str(p) for p in rs._write_set(outdir, write, FILES, "trees"))
    fh = result["forest_heights"]
    return TreesResult(stands=result["stands"], forest_area_m2=result["forest_area_m2"],
                       canopy_area_m2=result["canopy_area_m2"], forest_heights=ForestHeights(**fh) if fh else None,
                       tree_tops=result["tree_tops"], files=files)
