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

from aerotri.geom.crown_disks import TreeCrowns, crown_sub_cells  # noqa: F401  (the disks' geometry, shared with ortho)

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
    first = (np.asarray(return_number) <= 1) & ~np.isin(cls, NOISE_CLASSES)
    veg = np.isin(cls, VEGETATION_CLASSES)
    vf, of = first & veg, first & ~veg
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
                  x0_m: float, y_top_m: float, res_m: float, sub: int = 5) -> np.ndarray:
    """The nearest-return DSM ``nearest_m`` (float32, NaN nodata) with the fitted crowns: each cell within
    ``REACH_M`` of a disk whose nearest first return is not a building's (class 6) stands, where a disk covers one of
    its ``sub`` x ``sub`` sub-cell centres, at least at the crown's height there (the vegetation first return nearest
    its centre: the crown's gaps closed), and where none while its nearest first return is vegetation (the DSM's
    crown beyond the fitted rim), at the height of the first return nearest it that is not vegetation (the ground
    beside the crown). Returns a new array."""
    cls = np.asarray(classification)
    first = (np.asarray(return_number) <= 1) & ~np.isin(cls, NOISE_CLASSES)
    rows, cols, margin_cm, _, _ = crown_sub_cells(crowns, x0_m=x0_m, y_top_m=y_top_m, res_m=res_m,
                                                  shape=nearest_m.shape, sub=sub, reach_m=REACH_M)
    out = np.array(nearest_m, np.float32, copy=True)
    if not len(rows):
        return out
    cx, cy = x0_m + (cols + 0.5) * res_m, y_top_m - (rows + 0.5) * res_m
    fx, fy, fz, fc = (np.asarray(a)[first] for a in (x_m, y_m, z_m, cls))
    _, j = cKDTree(np.column_stack([fx, fy])).query(np.column_stack([cx, cy]))
    near_cls = fc[j]
    veg = np.isin(fc, VEGETATION_CLASSES)
    d, k = cKDTree(np.column_stack([fx[veg], fy[veg]])).query(np.column_stack([cx, cy]),
                                                              distance_upper_bound=CROWN_HEIGHT_RADIUS_M)
    crown_z = np.where(np.isfinite(d), fz[veg][np.minimum(k, max(int(veg.sum()) - 1, 0))], np.nan)
    d, k = cKDTree(np.column_stack([fx[~veg], fy[~veg]])).query(np.column_stack([cx, cy]))
    other_z = fz[~veg][k]
    covered = (margin_cm >= 0).any(axis=(1, 2))
    keep = near_cls != 6
    top = out[rows, cols]
    raise_ = keep & covered & np.isfinite(top)
    out[rows[raise_], cols[raise_]] = np.fmax(top[raise_], crown_z[raise_])
    spill = keep & ~covered & np.isin(near_cls, VEGETATION_CLASSES) & np.isfinite(top)
    out[rows[spill], cols[spill]] = other_z[spill]
    return out


def write_crown_model(paths, nearest_path, outdir) -> tuple[Path, Path]:
    """Fit the trees of classified LAS/LAZ files (``paths``: strips in the CRS of the nearest-return DSM
    ``nearest_path``, every return) and write into ``outdir`` the disks (``CROWNS_FILE``: layer ``crowns``, one
    Polygon of 64 vertices per tree with its centre ``x_m``, ``y_m``, ``radius_m``, ``top_m``, ``base_m``,
    ``returns``, ``circle_fit``; despite the names in the CRS's units, as the DSM) and the occlusion surface
    (``SURFACE_FILE``: ``crown_surface`` of the DSM, on its grid), both atomically; their paths. The fit is made in
    metres (a CRS in feet scaled by its unit; heights taken in the same unit). The block's returns are held in
    memory (about 40 bytes each)."""
    import rasterio
    import shapely

    from aerotri.core.errors import InputError
    from aerotri.core.vector_files import VectorLayer, write_layers
    from aerotri.geom import las as las_io
    from lidarctl import io
    from lidarctl.rasters.products import _file_points, write_cog

    outdir = Path(outdir)
    with rasterio.open(nearest_path) as ds:
        crs, tf = ds.crs, ds.transform
        nearest_m = ds.read(1, masked=True).astype(np.float32).filled(np.nan)
        unit, tags = (ds.units[0] if ds.units else None), ds.tags()
    if crs is None or not crs.is_projected:
        raise InputError(f"{nearest_path}: the crowns are fitted in a projected CRS; the DSM is in "
                         f"{crs.to_string() if crs else 'no CRS'}")
    f = float(crs.linear_units_factor[1])  # CRS unit -> metres
    xs, ys, zs, cls, rn = [], [], [], [], []
    for p in paths:  # in metres, checked as lidarctl rasters reads them (a bad file: InputError naming it)
        _, units = io.resolve_crs_units(p, las_io.read_header(p), None)
        for x, y, z, c, r, _ in _file_points(p, units, io.CHUNK_POINTS):
            xs.append(x), ys.append(y), zs.append(z), cls.append(c), rn.append(r)
    x, y, z, c, r = (np.concatenate(a) for a in (xs, ys, zs, cls, rn))
    crowns = fit_crowns(x, y, z, c, r)
    surface = crown_surface(crowns, x, y, z, c, r, nearest_m * np.float32(f), x0_m=tf.c * f, y_top_m=tf.f * f,
                            res_m=tf.a * f) / np.float32(f)
    crowns = dataclasses.replace(crowns, **{k: getattr(crowns, k) / f
                                            for k in ("x_m", "y_m", "radius_m", "top_m", "base_m")})
    angles = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
    geoms = [shapely.Polygon(np.column_stack([cx + rr * np.cos(angles), cy + rr * np.sin(angles)]))
             for cx, cy, rr in zip(crowns.x_m, crowns.y_m, crowns.radius_m)]
    gpkg = outdir / CROWNS_FILE
    write_layers(gpkg, [VectorLayer("crowns", "Polygon", geoms, {
        "x_m": crowns.x_m, "y_m": crowns.y_m, "radius_m": crowns.radius_m, "top_m": crowns.top_m,
        "base_m": crowns.base_m, "returns": crowns.returns.astype(np.int64),
        "circle_fit": crowns.circle_fit.astype(np.int64)})], crs=crs.to_wkt(), timestamp="2000-01-01T00:00:00.000Z")
    tif = outdir / SURFACE_FILE
    write_cog(tif, surface, tf, crs, unit=unit, tags=tags,
              description="nearest-return DSM with the tree crowns fitted to their returns (lidar_out/crowns.gpkg)")
    return gpkg, tif
