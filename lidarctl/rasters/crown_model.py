"""Tree crowns fitted to their LiDAR returns, for the true ortho's occlusion test (issue 42).

The nearest-return DSM places a crown's rim half way between its outermost vegetation return and the first other
return (Voronoi): up to half the point spacing off the true rim, cell by cell, and a pulse that passed through the
crown to the ground (``canopy_first_return_prob`` in the simulator, gaps in a real crown) leaves a pit of ground in
it. Here each tree's crown is a disk fitted to its returns, and the crown stands from the tree's crown base up:

- **trees** (``segment_trees``): the highest vegetation first return per cell (``SEGMENT_RES_M``), one-cell pits
  closed by the highest of their neighbours, smoothed (Gaussian of ``SMOOTH_CELLS``); every cell climbs its steepest
  ascent (3 x 3) to a top; a tree is the cells that reach the same top, and its returns those in its cells;
- **the rim** (``fit_crowns``): a first return that is not vegetation, with a vegetation return within
  ``RIM_PAIR_SPACINGS`` point spacings, is a rim sample at the midpoint of the two for the tree of that vegetation
  return, unless most of the returns around it are vegetation (``PIT_SHARE``: a gap in the crown, not its rim).
  Chosen on the simulator's demo seed 7 (its crowns' radii: median error +0.01 m, against -0.20 m for the
  midpoints of the Delaunay edges between vegetation and other returns, the Voronoi rim, which the crown's gaps
  near the rim pull inwards); the farther returns whose nearest is a rim return push it outwards (a constructed
  scene of vertical pulses: +0.09 to +0.26 m at 0.75 m spacing, ``tests/lidarctl/test_crown_model.py``);
- **the disk**: a circle fitted to a tree's rim samples (Kasa's algebraic fit, once more without the samples more
  than ``TRIM_SPACINGS`` spacings off it) when they span at least ``MIN_ARC_DEG`` around it; else (a tree beside
  another, a bush of few returns) centred on its vegetation first returns' centroid with the median distance of
  its rim samples (or its farthest return plus half a spacing, without samples);
- a tree of fewer than ``MIN_TREE_RETURNS`` vegetation first returns is left out (a stray return, e.g. one the
  classifier took for low vegetation on open ground: the DSM keeps it as it is);
- **the crown base**: the lowest vegetation return of the tree, any return number (a pulse's return from inside
  the crown lies above the crown's underside: the base is at most that low; in the simulator 1.8-2.7 m above it,
  median).

Lengths and heights in metres (``write_crown_model`` scales a CRS in feet); grids north-up (row 0 at ``y_top_m``,
columns from ``x0_m``). Classes ASPRS: vegetation 3, 4, 5; building 6; noise 7, 18. Nothing here is fitted to a
score: the point spacing is the cloud's own (its first returns' area over their count).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from aerotri.geom.crown_disks import (CROWNS_IN_METRES_NOTE, TreeCrowns,  # noqa: F401  (shared with ortho)
                                      crown_sub_cells)

VEGETATION_CLASSES = (3, 4, 5)
NOISE_CLASSES = (7, 18)
SEGMENT_RES_M = 0.5  # the grid the tops are climbed on
SMOOTH_CELLS = 1.0  # Gaussian sigma of the highest returns before climbing (against tops on single branches)
RIM_PAIR_SPACINGS = 2.0  # a non-vegetation return within this many spacings of a vegetation return samples the rim
PIT_SHARE = 0.7  # a rim sample with this share of vegetation returns around it (2 spacings) is a gap in the crown
TRIM_SPACINGS = 1.0  # rim samples further than this off the first circle are dropped before the second fit
MIN_RIM_SAMPLES = 6
MIN_ARC_DEG = 180.0  # the rim samples' angular span around the fitted centre for the circle fit to stand
MIN_TREE_RETURNS = 3  # vegetation first returns a crown needs (fewer: a stray return, left to the DSM)
# The version of the crown model (trees, rims, disks, crown bases and the surface dsm_crowns.tif made of them):
# the chain's rasters stamp holds it beside ``RASTERS_VERSION``. Bump it when crowns.gpkg or dsm_crowns.tif change
# at the same inputs. 1: s10-fixes (the algorithm as of main e4b26d8e).
CROWNS_VERSION = 1


def segment_grid(x_m: np.ndarray, y_m: np.ndarray, res_m: float = SEGMENT_RES_M):
    """The segmentation grid of vegetation first returns (``x_m``, ``y_m``; or their (min x, max x, min y, max y)
    as a 4-tuple of floats in ``x_m``): (x0, y_top, shape), one empty cell beyond the returns on each side."""
    lo_x, hi_x, lo_y, hi_y = (x_m if isinstance(x_m, tuple) else
                              (float(x_m.min()), float(x_m.max()), float(y_m.min()), float(y_m.max())))
    x0, y_top = lo_x - res_m, hi_y + res_m
    rows = int(np.floor((y_top - lo_y) / res_m))
    cols = int(np.floor((hi_x - x0) / res_m))
    return x0, y_top, (rows + 2, cols + 2)


def segment_trees(x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray, res_m: float = SEGMENT_RES_M,
                  smooth_cells: float = SMOOTH_CELLS, *, grid=None, box=None):
    """Tree of each vegetation first return (``x_m``, ``y_m``, ``z_m``): labels (int64, 0 .. n - 1), n, and the
    grid (x0, y_top, res, shape, cell labels: -1 none, first row, first column, top cells) for placing other
    returns. ``grid``: the whole block's (``segment_grid``), ``box``: the window (row0, col0, rows, cols) of it
    segmented here (a tile and its halo; the returns given lie in it): the labels of the cells far enough from the
    window's edges are those of the whole grid. Top cells: flat indices in the window, in the whole grid's order."""
    x0, y_top, gshape = grid if grid is not None else segment_grid(x_m, y_m, res_m)
    rows = np.floor((y_top - y_m) / res_m).astype(np.int64)
    cols = np.floor((x_m - x0) / res_m).astype(np.int64)
    r0, c0, *shape = box if box is not None else (0, 0, *gshape)
    shape = tuple(shape)
    flat = (rows - r0) * shape[1] + (cols - c0)
    high = np.full(shape[0] * shape[1], -np.inf)
    np.maximum.at(high, flat, z_m)
    high = high.reshape(shape)
    has = np.isfinite(high)
    around = ndimage.maximum_filter(np.where(has, high, -np.inf), size=3)
    closed = ndimage.binary_closing(has, np.ones((3, 3), bool)) | has
    filled = np.where(has, high, np.where(closed & np.isfinite(around), around, np.nan))
    valid = np.isfinite(filled)
    if smooth_cells > 0:
        w = ndimage.gaussian_filter(valid.astype(np.float64), smooth_cells)
        s = ndimage.gaussian_filter(np.where(valid, filled, 0.0), smooth_cells)
        surface = np.where(valid, s / np.maximum(w, 1e-12), -np.inf)
    else:
        surface = np.where(valid, filled, -np.inf)
    # steepest ascent within 3 x 3 (the cell itself included: a top points to itself)
    idx = np.arange(shape[0] * shape[1]).reshape(shape)
    best, to = surface.copy(), idx.copy()
    pad_s = np.pad(surface, 1, constant_values=-np.inf)
    pad_i = np.pad(idx, 1, constant_values=-1)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            s = pad_s[1 + dr:1 + dr + shape[0], 1 + dc:1 + dc + shape[1]]
            better = s > best
            best = np.where(better, s, best)
            to = np.where(better, pad_i[1 + dr:1 + dr + shape[0], 1 + dc:1 + dc + shape[1]], to)
    to = to.ravel()
    for _ in range(64):  # pointer jumping: every cell to its top
        nxt = to[to]
        if np.array_equal(nxt, to):
            break
        to = nxt
    tops = np.unique(to[valid.ravel()])
    cell_label = np.full(shape[0] * shape[1], -1, np.int64)
    cell_label[valid.ravel()] = np.searchsorted(tops, to[valid.ravel()])
    return cell_label[flat], len(tops), (x0, y_top, res_m, shape, cell_label.reshape(shape), r0, c0, tops)


def _kasa(px: np.ndarray, py: np.ndarray):
    """Centre and radius of the algebraic (Kasa) least-squares circle through (px, py)."""
    A = np.column_stack([2 * px, 2 * py, np.ones_like(px)])
    sol, *_ = np.linalg.lstsq(A, px * px + py * py, rcond=None)
    cx, cy, k = sol
    return cx, cy, math.sqrt(max(k + cx * cx + cy * cy, 0.0))


def _arc_deg(px, py, cx, cy) -> float:
    """The angular span (deg) of the points around (cx, cy): 360 less the largest gap between them."""
    a = np.sort(np.arctan2(py - cy, px - cx))
    gaps = np.diff(np.concatenate([a, [a[0] + 2 * math.pi]]))
    return float(360.0 - math.degrees(gaps.max()))


def fit_crowns(x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray, classification: np.ndarray,
               return_number: np.ndarray) -> TreeCrowns:
    """The trees of a classified cloud (every return: ``return_number`` 1 the first) as fitted disks, tops and
    crown bases (module docstring)."""
    return _fit_crowns(x_m, y_m, z_m, classification, return_number)[0]


def _first_masks(cls, return_number):
    first = (np.asarray(return_number) <= 1) & ~np.isin(cls, NOISE_CLASSES)
    return first, first & np.isin(cls, VEGETATION_CLASSES)


def _fit_crowns(x_m, y_m, z_m, classification, return_number, *, spacing_m: float | None = None, grid=None,
                box=None):
    """``fit_crowns`` and the top cell of each tree (flat index in ``segment_trees``' window; row, column of the
    whole grid). ``spacing_m``, ``grid``, ``box``: the whole block's spacing and segmentation grid and the
    window of it the returns fill (a tile with its halo); None: of these returns."""
    x_m, y_m, z_m = (np.asarray(a, np.float64) for a in (x_m, y_m, z_m))
    cls = np.asarray(classification)
    first, vf = _first_masks(cls, return_number)
    veg = np.isin(cls, VEGETATION_CLASSES)
    of = first & ~veg
    vx, vy, vz = x_m[vf], y_m[vf], z_m[vf]
    ox, oy = x_m[of], y_m[of]
    e = np.zeros(0)
    empty = (TreeCrowns(e, e, e, e, e, np.zeros(0, np.int64), np.zeros(0, bool), 0.0),
             np.zeros(0, np.int64), np.zeros(0, np.int64))
    if not len(vx) or (spacing_m is None and not len(ox)):  # no trees, or nothing but trees: no rim to fit
        return empty
    if spacing_m is None:
        bx, by = np.ptp(x_m[first]), np.ptp(y_m[first])
        spacing_m = math.sqrt(max(bx * by, 1e-9) / max(int(first.sum()), 1))
    spacing = spacing_m
    label, n, (gx0, gy_top, gres, gshape, cell_label, r0, c0, tops) = segment_trees(vx, vy, vz, grid=grid, box=box)
    # every vegetation return (interior ones too) to the tree of its cell
    va = veg & ~np.isin(cls, NOISE_CLASSES)
    r = np.floor((gy_top - y_m[va]) / gres).astype(np.int64) - r0
    c = np.floor((x_m[va] - gx0) / gres).astype(np.int64) - c0
    ok = (r >= 0) & (r < gshape[0]) & (c >= 0) & (c < gshape[1])
    lab_all = np.full(len(r), -1, np.int64)
    lab_all[ok] = cell_label[r[ok], c[ok]]
    base = np.full(n, np.inf)
    np.minimum.at(base, lab_all[lab_all >= 0], z_m[va][lab_all >= 0])
    top = np.full(n, -np.inf)
    np.maximum.at(top, label, vz)
    base = np.minimum(base, top)
    count = np.bincount(label, minlength=n)
    cxm = np.bincount(label, vx, n) / np.maximum(count, 1)
    cym = np.bincount(label, vy, n) / np.maximum(count, 1)
    far = np.zeros(n)
    np.maximum.at(far, label, np.hypot(vx - cxm[label], vy - cym[label]))
    # rim samples: midpoints of (another first return, the vegetation return nearest it), gaps in the crown left out
    vtree = cKDTree(np.column_stack([vx, vy]))
    d, j = vtree.query(np.column_stack([ox, oy]).reshape(-1, 2), distance_upper_bound=RIM_PAIR_SPACINGS * spacing)
    near = np.isfinite(d)
    qx, qy, j = ox[near], oy[near], j[near]
    around = 2.0 * spacing
    if len(qx):  # (a tile of nothing but trees has no other return)
        nv = np.asarray(vtree.query_ball_point(np.column_stack([qx, qy]), around, return_length=True))
        no = np.asarray(cKDTree(np.column_stack([ox, oy])).query_ball_point(np.column_stack([qx, qy]), around,
                                                                           return_length=True))
    else:
        nv = no = np.zeros(0, np.int64)
    rim = nv < PIT_SHARE * (nv + no)
    mx, my, mt = (0.5 * (qx + vx[j]))[rim], (0.5 * (qy + vy[j]))[rim], label[j][rim]
    order = np.argsort(mt, kind="stable")
    mx, my, mt = mx[order], my[order], mt[order]
    start = np.searchsorted(mt, np.arange(n), "left")
    stop = np.searchsorted(mt, np.arange(n), "right")
    cx, cy, rad = cxm.copy(), cym.copy(), far + 0.5 * spacing
    fitted = np.zeros(n, bool)
    for t in range(n):
        px, py = mx[start[t]:stop[t]], my[start[t]:stop[t]]
        if len(px) >= MIN_RIM_SAMPLES:
            ax, ay, ar = _kasa(px, py)
            keep = np.abs(np.hypot(px - ax, py - ay) - ar) <= TRIM_SPACINGS * spacing
            if keep.sum() >= MIN_RIM_SAMPLES:
                ax, ay, ar = _kasa(px[keep], py[keep])
                if (_arc_deg(px[keep], py[keep], ax, ay) >= MIN_ARC_DEG
                        and math.hypot(ax - cxm[t], ay - cym[t]) <= 0.5 * ar and ar <= far[t] + spacing):
                    cx[t], cy[t], rad[t], fitted[t] = ax, ay, ar, True
                    continue
        if len(px):
            rad[t] = float(np.median(np.hypot(px - cxm[t], py - cym[t])))
    keep = count >= MIN_TREE_RETURNS
    top_r, top_c = np.divmod(tops[keep], gshape[1])
    return (TreeCrowns(cx[keep], cy[keep], rad[keep], top[keep], base[keep], count[keep], fitted[keep], spacing),
            top_r + r0, top_c + c0)


CROWNS_FILE = "crowns.gpkg"
SURFACE_FILE = "dsm_crowns.tif"
REACH_M = 1.0  # cells within this of a disk are the crowns' (the nearest-return DSM's rim lies within half a spacing)
CROWN_HEIGHT_RADIUS_M = 3.0  # the crown's height at a cell: the vegetation first return nearest it within this


def crown_surface(crowns: TreeCrowns, x_m, y_m, z_m, classification, return_number, nearest_m: np.ndarray, *,
                  x0_m: float, y_top_m: float, res_m: float, sub: int = 5, window=None) -> np.ndarray:
    """The nearest-return DSM ``nearest_m`` (float32, NaN nodata) with the fitted crowns: each cell within
    ``REACH_M`` of a disk whose nearest first return is not a building's (class 6) stands, where a disk covers one of
    its ``sub`` x ``sub`` sub-cell centres, at least at the crown's height there (the vegetation first return nearest
    its centre: the crown's gaps closed), and where none while its nearest first return is vegetation (the DSM's
    crown beyond the fitted rim), at the height of the first return nearest it that is not vegetation (the ground
    beside the crown). Returns a new array. ``window``: (row0, col0, rows, cols of the whole grid): ``nearest_m``
    is that window of a larger grid (origin ``x0_m``, ``y_top_m``), the cells as in the whole grid."""
    return _crown_surface(crowns, x_m, y_m, z_m, classification, return_number, nearest_m, x0_m=x0_m,
                          y_top_m=y_top_m, res_m=res_m, sub=sub, window=window)[0]


def _crown_surface(crowns, x_m, y_m, z_m, classification, return_number, nearest_m, *, x0_m, y_top_m, res_m, sub,
                   window=None, sure_m=None):
    """``crown_surface`` and the number of its cells whose nearest return that is not vegetation lies farther than
    ``sure_m`` (per cell: the returns given are all those within it; None: all returns given)."""
    cls = np.asarray(classification)
    first, _ = _first_masks(cls, return_number)
    w_r0, w_c0 = (window[0], window[1]) if window is not None else (0, 0)
    shape = (window[2], window[3]) if window is not None else nearest_m.shape
    rows, cols, margin_cm, _, _ = crown_sub_cells(
        crowns, x0_m=x0_m, y_top_m=y_top_m, res_m=res_m, shape=shape, sub=sub, reach_m=REACH_M,
        window=(w_r0, w_c0, *nearest_m.shape))
    out = np.array(nearest_m, np.float32, copy=True)
    if not len(rows) or not first.any():
        return out, 0
    cx, cy = x0_m + (cols + 0.5) * res_m, y_top_m - (rows + 0.5) * res_m
    fx, fy, fz, fc = (np.asarray(a)[first] for a in (x_m, y_m, z_m, cls))
    _, j = cKDTree(np.column_stack([fx, fy])).query(np.column_stack([cx, cy]))
    near_cls = fc[j]
    veg = np.isin(fc, VEGETATION_CLASSES)
    d, k = cKDTree(np.column_stack([fx[veg], fy[veg]])).query(np.column_stack([cx, cy]),
                                                              distance_upper_bound=CROWN_HEIGHT_RADIUS_M)
    crown_z = np.where(np.isfinite(d), fz[veg][np.minimum(k, max(int(veg.sum()) - 1, 0))], np.nan)
    if (~veg).any():
        d_other, k = cKDTree(np.column_stack([fx[~veg], fy[~veg]])).query(np.column_stack([cx, cy]))
        other_z = fz[~veg][k]
    else:  # (a tile of nothing but trees: no spill, counted below)
        d_other, other_z = np.full(len(cx), np.inf), np.full(len(cx), np.nan)
    covered = (margin_cm >= 0).any(axis=(1, 2))
    keep = near_cls != 6
    rows, cols = rows - w_r0, cols - w_c0
    top = out[rows, cols]
    raise_ = keep & covered & np.isfinite(top)
    out[rows[raise_], cols[raise_]] = np.fmax(top[raise_], crown_z[raise_])
    spill = keep & ~covered & np.isin(near_cls, VEGETATION_CLASSES) & np.isfinite(top)
    out[rows[spill], cols[spill]] = other_z[spill]
    unsure = 0 if sure_m is None else int((spill & ~(d_other <= sure_m)).sum())
    return out, unsure


MAX_CROWN_RADIUS_M = 15.0  # the widest crown a tile's halo holds whole (a tree's returns within 2 radii of its top)
TILE_M = 500.0  # tile side: about 1 M returns with the halo at the demo's density (~3 returns per m2)
_TILE_FIELDS = (("x", "f8"), ("y", "f8"), ("z", "f8"), ("cls", "u1"), ("rn", "u1"))
# Returns read at a time (as ``lidarctl rasters`` bins them): a chunk of ``io.CHUNK_POINTS`` (2 M) set the demo's
# peak at 200 m tiles (481 MiB, of which about 190 the interpreter and its imports), not the tile
_READ_POINTS = 250_000
# GDAL's block cache while the surface is written by windows and copied to the COG (GDAL's default, 5 % of the RAM,
# would hold a full-size block's working raster, 0.7 GB, in memory)
SURFACE_CACHE_BYTES = 64 * 2 ** 20


def crown_halo_m(spacing_m: float) -> float:
    """The halo read around a tile (m): a tree whose top lies in the tile reaches at most ``2 x MAX_CROWN_RADIUS_M``
    from it (a top off the crown's centre); its rim samples take the returns within ``RIM_PAIR_SPACINGS`` spacings
    of it and the gap test those within 2 more; the segmentation's smoothing (4 sigma), pit closing and climbing
    see 3 cells more."""
    return (2.0 * MAX_CROWN_RADIUS_M + (RIM_PAIR_SPACINGS + 2.0) * spacing_m
            + (4.0 * SMOOTH_CELLS + 3.0) * SEGMENT_RES_M)


@dataclasses.dataclass(frozen=True)
class CrownRun:
    """What ``write_crown_model`` did: the outputs, the trees, the tiles (side, halo in metres, how many held
    returns), the most returns a tile read, and the surface's cells whose ground beside a crown lay beyond a
    tile's halo (0: every cell as an untiled run makes it)."""

    crowns_path: Path
    surface_path: Path
    trees: int
    tile_m: float
    halo_m: float
    tiles: int
    max_tile_returns: int
    cells_beyond_halo: int


def write_crown_model(paths, nearest_path, outdir, *, tile_m: float | None = TILE_M) -> tuple[Path, Path]:
    """Fit the trees of classified LAS/LAZ files (``paths``: strips in the CRS of the nearest-return DSM
    ``nearest_path``, every return) and write into ``outdir`` the disks (``CROWNS_FILE``: layer ``crowns``, one
    Polygon of 64 vertices per tree with its centre ``x_m``, ``y_m``, ``radius_m``, ``top_m``, ``base_m``,
    ``returns``, ``circle_fit``; the fields in metres, the polygons in the CRS's units; a CRS not in metres notes
    ``CROWNS_IN_METRES_NOTE`` in the layer's description) and the occlusion surface (``SURFACE_FILE``:
    ``crown_surface`` of the DSM, on its grid, in its height unit), both atomically; their paths. The fit is made in
    metres (lengths by the CRS's unit, heights by the clouds' height unit).

    By tiles of ``tile_m`` metres (None: one tile, the whole block in memory): the returns are binned on disk into
    the tiles with a halo of ``crown_halo_m`` (36 m at the demo's spacing), each tile's trees segmented and
    fitted from its returns and halo and kept when their top lies in the tile, the surface written by the tiles'
    windows of the DSM. The cloud's spacing and the segmentation grid are the block's (a first pass), so a tree
    whose crown lies within the halo is fitted as untiled, bit for bit. Memory: the tile's returns with their halo
    (about 60 bytes each with the segmentation window and k-d trees, measured on the demo) and its window of the
    DSM (``bench/crowns_tiled_memory.py``)."""
    run = write_crown_model_run(paths, nearest_path, outdir, tile_m=tile_m)
    return run.crowns_path, run.surface_path


def write_crown_model_run(paths, nearest_path, outdir, *, tile_m: float | None = TILE_M) -> CrownRun:
    """``write_crown_model``, with what it did (``CrownRun``)."""
    import shutil

    import rasterio
    from rasterio.shutil import copy as rio_copy
    from rasterio.windows import Window

    from aerotri.core.atomic import atomic_path, temporary_dir
    from aerotri.core.errors import InputError
    from aerotri.core.gdal_cache import stage_block_cache
    from aerotri.core.log import progress
    from aerotri.core.vector_files import VectorLayer, write_layers
    from aerotri.geom import las as las_io
    from lidarctl import io
    from lidarctl.rasters.products import NODATA, _file_points

    outdir = Path(outdir)
    try:
        with rasterio.open(nearest_path) as ds:
            crs, tf, dsm_shape = ds.crs, ds.transform, ds.shape
            unit, tags = (ds.units[0] if ds.units else None), ds.tags()
    except rasterio.errors.RasterioIOError as e:
        raise InputError(f"{nearest_path}: not a readable nearest-return DSM ({e})") from None
    if crs is None or not crs.is_projected:
        raise InputError(f"{nearest_path}: the crowns are fitted in a projected CRS; the DSM is in "
                         f"{crs.to_string() if crs else 'no CRS'}")
    f = float(crs.linear_units_factor[1])  # CRS unit -> metres (lengths)
    from aerotri.geom.crs.definition import same_horizontal

    crs_units = [io.resolve_crs_units(p, las_io.read_header(p), None) for p in paths]
    for p, (strip_crs, _) in zip(paths, crs_units):
        if not same_horizontal(strip_crs, crs):
            raise InputError(f"{p}: in {strip_crs.name}, not in the nearest-return DSM's CRS ({crs.to_string()}, "
                             f"{nearest_path})")
    units = [u for _, u in crs_units]
    # heights: the DSM is the clouds' (``lidarctl rasters`` writes it in their height unit), which may differ from
    # the horizontal one (UTM in metres, heights in US feet)
    fz = units[0].z_m if units else f
    if any(u.z_m != fz for u in units):
        raise InputError(f"{paths[0]}: the strips' heights are in different units "
                         f"({sorted({u.z_name for u in units})}); the crowns need one")

    def chunks(validate=True):  # in metres, checked as lidarctl rasters reads them (a bad file: InputError naming it)
        for p, u in zip(paths, units):
            for x, y, z, c, r, _ in _file_points(p, u, min(io.CHUNK_POINTS, _READ_POINTS), validate=validate):
                yield x, y, z, c, r

    # pass 1: the block's spacing (its first returns' box over their count) and segmentation grid
    n_first = n_other = n_all = 0
    box_first, box_veg = [np.inf, -np.inf, np.inf, -np.inf], [np.inf, -np.inf, np.inf, -np.inf]
    for x, y, z, c, r in chunks():
        first, vf = _first_masks(c, r)
        n_all += len(x)
        n_first += int(first.sum())
        n_other += int((first & ~vf).sum())
        for box, m in ((box_first, first), (box_veg, vf)):
            if m.any():
                xs, ys = x[m], y[m]
                box[:] = [min(box[0], xs.min()), max(box[1], xs.max()), min(box[2], ys.min()), max(box[3], ys.max())]
    has_trees = n_first > 0 and n_other > 0 and np.isfinite(box_veg[0])
    spacing = (math.sqrt(max((box_first[1] - box_first[0]) * (box_first[3] - box_first[2]), 1e-9) / n_first)
               if n_first else 0.0)
    res = SEGMENT_RES_M
    gx0, gy_top, gshape = segment_grid(tuple(float(v) for v in box_veg), None, res) if has_trees else (0.0, 0.0, (0, 0))
    halo_m = crown_halo_m(spacing)
    halo = int(math.ceil(halo_m / res))
    tile = max(1, int(round(tile_m / res))) if tile_m is not None else 1 << 40

    def tile_rc(x, y):  # the segmentation cell of each return
        return (np.floor((gy_top - y) / res).astype(np.int64), np.floor((x - gx0) / res).astype(np.int64))

    if has_trees and tile_m is not None:  # the tile files hold each return once, and again in each halo it lies in
        from aerotri.core.limits import check_disk

        spread = ((tile_m + 2 * halo_m) / tile_m) ** 2
        check_disk(n_all * spread * sum(np.dtype(d).itemsize for _, d in _TILE_FIELDS), outdir,
                   "the crown model's tile files", "--tile-m")
    work = temporary_dir(outdir, "crowns-tiles")
    try:
        # pass 2: each tile's returns and halo to its files (file order)
        held: dict[tuple[int, int], int] = {}
        if has_trees:
            for x, y, z, c, r in chunks(validate=False):
                rows, cols = tile_rc(x, y)
                tr_lo, tr_hi = (rows - halo) // tile, (rows + halo) // tile
                tc_lo, tc_hi = (cols - halo) // tile, (cols + halo) // tile
                for tr in range(int(tr_lo.min()), int(tr_hi.max()) + 1):
                    in_r = (tr_lo <= tr) & (tr <= tr_hi)
                    if not in_r.any():
                        continue
                    for tc in range(int(tc_lo.min()), int(tc_hi.max()) + 1):
                        m = in_r & (tc_lo <= tc) & (tc <= tc_hi)
                        if not m.any():
                            continue
                        held[tr, tc] = held.get((tr, tc), 0) + int(m.sum())
                        for (name, dtype), a in zip(_TILE_FIELDS, (x, y, z, c, r)):
                            with open(work / f"tile_{tr}_{tc}_{name}.bin", "ab") as fh:
                                np.ascontiguousarray(a[m], dtype).tofile(fh)

        def tile_points(key):
            if key not in held:
                return tuple(np.zeros(0, d) for _, d in _TILE_FIELDS)
            return tuple(np.fromfile(work / f"tile_{key[0]}_{key[1]}_{name}.bin", d) for name, d in _TILE_FIELDS)

        # pass 3: each tile's trees, kept where their top lies in the tile's core
        parts, keys = [], []
        with progress(len(held), "crowns: fit the trees by tile", "tile") as bar:
            for tr, tc in sorted(held):
                r0, r1 = max(tr * tile - halo, 0), min((tr + 1) * tile + halo, gshape[0])
                c0, c1 = max(tc * tile - halo, 0), min((tc + 1) * tile + halo, gshape[1])
                if r1 > r0 and c1 > c0:
                    crowns, top_r, top_c = _fit_crowns(*tile_points((tr, tc)), spacing_m=spacing,
                                                       grid=(gx0, gy_top, gshape), box=(r0, c0, r1 - r0, c1 - c0))
                    core = (top_r // tile == tr) & (top_c // tile == tc)
                    parts.append([getattr(crowns, k)[core] for k in _CROWN_FIELDS])
                    keys.append(top_r[core] * gshape[1] + top_c[core])
                bar.update(1)
        key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        order = np.argsort(key, kind="stable")  # the untiled order: the tops' cells north to south, west to east
        crowns = TreeCrowns(*(np.concatenate([p[i] for p in parts])[order] if parts else
                              np.zeros(0, np.int64 if k == "returns" else bool if k == "circle_fit" else float)
                              for i, k in enumerate(_CROWN_FIELDS)), spacing if has_trees else 0.0)

        # pass 4: the surface by the tiles' windows of the DSM (a DSM cell to the tile of its centre)
        x0d, ytd, resd = tf.c * f, tf.f * f, tf.a * f
        row_tile = (np.floor((gy_top - (ytd - (np.arange(dsm_shape[0]) + 0.5) * resd)) / res).astype(np.int64)
                    // tile) if has_trees else np.zeros(dsm_shape[0], np.int64)
        col_tile = (np.floor((x0d + (np.arange(dsm_shape[1]) + 0.5) * resd - gx0) / res).astype(np.int64)
                    // tile) if has_trees else np.zeros(dsm_shape[1], np.int64)
        row_runs = _runs(row_tile)
        col_runs = _runs(col_tile)
        reach = REACH_M + 2.0 * resd
        beyond = 0
        working = work / "surface.tif"
        profile = dict(driver="GTiff", width=dsm_shape[1], height=dsm_shape[0], count=1, dtype="float32", crs=crs,
                       transform=tf, nodata=NODATA, tiled=True, blockxsize=512, blockysize=512, bigtiff="IF_SAFER")
        with stage_block_cache(SURFACE_CACHE_BYTES), rasterio.open(nearest_path) as src, \
                rasterio.open(working, "w", **profile) as dst, \
                progress(len(row_runs) * len(col_runs), "crowns: the surface by tile", "tile") as bar:
            for tr, (a0, a1) in row_runs:
                for tc, (b0, b1) in col_runs:
                    win = Window(b0, a0, b1 - b0, a1 - a0)
                    nearest_m = src.read(1, window=win, masked=True).astype(np.float32).filled(np.nan)
                    wx0, wx1 = x0d + b0 * resd, x0d + b1 * resd
                    wy1, wy0 = ytd - a0 * resd, ytd - a1 * resd
                    near = ((crowns.x_m + crowns.radius_m + reach >= wx0) & (crowns.x_m - crowns.radius_m - reach <= wx1)
                            & (crowns.y_m + crowns.radius_m + reach >= wy0)
                            & (crowns.y_m - crowns.radius_m - reach <= wy1))
                    sub_crowns = TreeCrowns(*(getattr(crowns, k)[near] for k in _CROWN_FIELDS), crowns.spacing_m)
                    pts = tile_points((int(tr), int(tc))) if near.any() else tuple(
                        np.zeros(0, d) for _, d in _TILE_FIELDS)
                    out, unsure = _crown_surface(sub_crowns, *pts, nearest_m * np.float32(fz), x0_m=x0d, y_top_m=ytd,
                                                 res_m=resd, sub=5, window=(a0, b0, *dsm_shape),
                                                 sure_m=(halo - 1) * res)
                    beyond += unsure
                    out = out / np.float32(fz)
                    dst.write(np.where(np.isfinite(out), out, NODATA).astype(np.float32), 1, window=win)
                    bar.update(1)
            if unit:
                dst.units = (unit,)
            dst.set_band_description(1, "nearest-return DSM with the tree crowns fitted to their returns "
                                        "(lidar_out/crowns.gpkg)")
            if tags:
                dst.update_tags(**tags)
        if beyond:
            import logging

            logging.getLogger(__name__).warning(
                "crowns: %d cells beside a crown found no ground return within the tiles' halo (%.0f m); their "
                "height is that of the nearest one within it", beyond, halo_m)

        # the fields in metres, as named (a QGIS user reads them so); the polygons in the CRS's units. A file whose
        # CRS is not in metres says so in its description: one without it was written in the CRS's units before
        angles = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
        import shapely

        geoms = [shapely.Polygon(np.column_stack([cx + rr * np.cos(angles), cy + rr * np.sin(angles)]))
                 for cx, cy, rr in zip(crowns.x_m / f, crowns.y_m / f, crowns.radius_m / f)]
        gpkg = outdir / CROWNS_FILE
        write_layers(gpkg, [VectorLayer("crowns", "Polygon", geoms, {
            "x_m": crowns.x_m, "y_m": crowns.y_m, "radius_m": crowns.radius_m, "top_m": crowns.top_m,
            "base_m": crowns.base_m, "returns": crowns.returns.astype(np.int64),
            "circle_fit": crowns.circle_fit.astype(np.int64)},
            note=CROWNS_IN_METRES_NOTE if (f, fz) != (1.0, 1.0) else "")], crs=crs.to_wkt(),
            timestamp="2000-01-01T00:00:00.000Z")
        tif = outdir / SURFACE_FILE
        with stage_block_cache(SURFACE_CACHE_BYTES), rasterio.open(working) as src, \
                atomic_path(tif) as tmp:  # the COG as ``write_cog`` makes it
            rio_copy(src, tmp, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return CrownRun(gpkg, tif, len(crowns), float(tile_m) if tile_m is not None else math.inf, halo_m, len(held),
                    max(held.values(), default=0), beyond)


_CROWN_FIELDS = ("x_m", "y_m", "radius_m", "top_m", "base_m", "returns", "circle_fit")


def _runs(tile_of: np.ndarray):
    """(tile, (start, stop)) of the runs of equal values of a monotonic index array."""
    if not len(tile_of):
        return []
    cut = np.flatnonzero(np.diff(tile_of)) + 1
    starts = np.concatenate([[0], cut])
    stops = np.concatenate([cut, [len(tile_of)]])
    return [(int(tile_of[a]), (int(a), int(b))) for a, b in zip(starts, stops)]
