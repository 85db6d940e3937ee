"""The nearest-return surface with tree crowns no wider than the returns say: for the true ortho's occlusion test.

``dsm_nearest.tif`` (``nearest``) stands each 0.5 m cell whole at the height of the return nearest its centre. At a
crown's rim, where that return is a vegetation return, the whole cell becomes a column of the crown's height although
the crown covers part of it: the march then stops lines of sight that pass beside the crown over the rest of the cell
(issue 42: two thirds of the demo's masked ground that clears the true surface, 0.04-0.60 m beyond a crown's rim).
The returns place the rim between a crown's last vegetation return and the first return beside it (Voronoi), so a
cell lies wholly within the crown where every point of it is nearer a vegetation return than any other; here its
``SUB_CELLS`` x ``SUB_CELLS`` sub-cell centres (``crown_share``, the share of them that are). ``crowns_within_cells``
keeps a vegetation cell a column only where that share reaches ``min_share``; the others take the height of the
nearest return that is not vegetation (the ground or a roof beside the crown), as ``dsm_nearest`` does beyond the
rim (chosen against: it gives up too much crown, docs/true-ortho.md). ``crown_sub_cells`` / ``crown_sub_cells_beside``
give the crown's sub-cells per cell instead (on the crown's own cells / on both sides of the rim, the cells beside
it with a crown return's height), for the march to take the crown over those sub-cells only (``ortho.crown_cells``).
Not written by ``lidarctl rasters`` (the bench makes them from the classified strips). Grids north-up: row 0 at
``y_top_m``, columns from ``x0_m``; lengths in metres; classes ASPRS (``crown_base.VEGETATION_CLASSES``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.ndimage import maximum_filter

from lidarctl.rasters.crown_base import VEGETATION_CLASSES
from lidarctl.rasters.nearest import SEARCH_RADIUS_M, nearest_return_surface

SUB_CELLS = 5  # sub-cell centres per cell side (0.1 m at a 0.5 m cell) at which the crown's cover is tested
WHOLE_CELL = 1.0  # ``min_share``: a column only where the crown covers every sub-cell centre
MOST_OF_THE_CELL = 0.5  # ``min_share``: where it covers at least half of them (chosen on the demo's seed 7)


@numba.njit(cache=True, nogil=True)
def _bucket_points(x, y, z, grid):
    # the points on the grid sorted by cell (a counting sort) and each cell's first point (start, n_cells + 1)
    x0, y_top, res, nrows, ncols = grid
    cell = np.full(len(x), -1, np.int64)
    start = np.zeros(nrows * ncols + 1, np.int64)
    for q in range(len(x)):
        r = math.floor((y_top - y[q]) / res)
        c = math.floor((x[q] - x0) / res)
        if 0 <= r < nrows and 0 <= c < ncols:
            cell[q] = r * ncols + c
            start[cell[q] + 1] += 1
    for k in range(1, len(start)):
        start[k] += start[k - 1]
    at = start[:-1].copy()
    px, py, pz = np.empty(start[-1]), np.empty(start[-1]), np.empty(start[-1])
    for q in range(len(x)):
        if cell[q] >= 0:
            i = at[cell[q]]
            at[cell[q]] += 1
            px[i], py[i], pz[i] = x[q], y[q], z[q]
    return (px, py, pz), start


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_in_run(px, py, pz, q0, q1, cx, cy, best, best_z):
    # the points q0 .. q1 (cells next to each other in a row); ties: the higher z (vegetation)
    for q in range(q0, q1):
        d = (px[q] - cx) ** 2 + (py[q] - cy) ** 2
        if d < best or (d == best and pz[q] > best_z):
            best, best_z = d, pz[q]
    return best, best_z


@numba.njit(cache=True, nogil=True)
def _shares(points, start, grid, cells_i, cells_j, sub, max_dist):
    # per candidate cell the share of its sub-cell centres whose nearest return (z: 1 vegetation, 0 not; ties the
    # higher, vegetation) is vegetation; ring k of a cell lies at least (k - 1) cells from any point of the cell
    px, py, pz = points
    x0, y_top, res, nrows, ncols = grid
    bits = np.zeros(len(cells_i), np.uint32)
    counts = np.zeros(len(cells_i), np.int64)
    reach = int(math.ceil(max_dist / res)) + 1
    for n in range(len(cells_i)):
        i, j = cells_i[n], cells_j[n]
        for u in range(sub):
            cy = y_top - (i + (u + 0.5) / sub) * res
            for v in range(sub):
                cx = x0 + (j + (v + 0.5) / sub) * res
                best, best_z = max_dist * max_dist, 0.0
                for k in range(reach + 1):
                    if k > 1 and ((k - 1) * res) ** 2 > best:
                        break
                    b_lo, b_hi = max(j - k, 0), min(j + k, ncols - 1)
                    for side in range(2 if k > 0 else 1):
                        a = i - k if side == 0 else i + k
                        if 0 <= a < nrows:
                            best, best_z = _nearest_in_run(px, py, pz, start[a * ncols + b_lo],
                                                           start[a * ncols + b_hi + 1], cx, cy, best, best_z)
                    for a in range(max(i - k + 1, 0), min(i + k, nrows)):
                        for b in (j - k, j + k):
                            if 0 <= b < ncols:
                                c = a * ncols + b
                                best, best_z = _nearest_in_run(px, py, pz, start[c], start[c + 1], cx, cy, best,
                                                               best_z)
                if best_z > 0.5:
                    bits[n] |= np.uint32(1) << np.uint32(u * sub + v)
                    counts[n] += 1
    return bits, counts


def crown_share(x: np.ndarray, y: np.ndarray, is_vegetation: np.ndarray, *, x0_m: float, y_top_m: float,
                res_m: float, nrows: int, ncols: int, cells: np.ndarray, sub: int = SUB_CELLS) -> np.ndarray:
    """Per cell of ``cells`` ((N, 2) rows, columns) the share (0..1) of its ``sub`` x ``sub`` sub-cell centres whose
    nearest return (x, y; within ``nearest.SEARCH_RADIUS_M``) is vegetation (``is_vegetation``; equally near: the
    vegetation)."""
    grid = (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols))
    _, counts = _crown_bits(x, y, is_vegetation, grid, cells, sub)
    return (counts / (sub * sub)).astype(np.float32)


def _crown_bits(x, y, is_vegetation, grid, cells, sub):
    x, y = (np.ascontiguousarray(v, np.float64) for v in (x, y))
    points, start = _bucket_points(x, y, np.asarray(is_vegetation, np.float64), grid)
    cells = np.asarray(cells, np.int64).reshape(-1, 2)
    return _shares(points, start, grid, np.ascontiguousarray(cells[:, 0]), np.ascontiguousarray(cells[:, 1]),
                   int(sub), float(SEARCH_RADIUS_M))


def crown_sub_cells(x: np.ndarray, y: np.ndarray, cls: np.ndarray, nearest_m: np.ndarray, *, x0_m: float,
                    y_top_m: float, res_m: float, sub: int = SUB_CELLS) -> np.ndarray:
    """Per cell of the grid of ``nearest_m`` (NaN nodata) whose centre's nearest first return (x, y; classes ``cls``)
    is vegetation and which that crown does not cover whole, the bits (uint32, bit ``u * sub + v``: sub-cell row u
    from the north, column v from the west) of its ``sub`` x ``sub`` sub-cell centres nearer a vegetation return than
    any other; 0 for every other cell (a column or not as ``nearest_m`` has it). For the occlusion test's crowns
    within the cells (``ortho.crown_cells``)."""
    if sub * sub > 32:
        raise ValueError(f"sub {sub}: at most 5 x 5 sub-cells fit a uint32")
    nrows, ncols = nearest_m.shape
    veg = np.isin(np.asarray(cls), VEGETATION_CLASSES)
    kw = {"x0_m": x0_m, "y_top_m": y_top_m, "res_m": res_m, "nrows": nrows, "ncols": ncols}
    at_centre = nearest_return_surface(x, y, veg.astype(np.float64), max_dist_m=SEARCH_RADIUS_M, **kw) > 0.5
    cells = np.argwhere(at_centre & np.isfinite(nearest_m))
    grid = (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols))
    bits, counts = _crown_bits(x, y, veg, grid, cells, sub)
    out = np.zeros((nrows, ncols), np.uint32)
    part = counts < sub * sub
    out[cells[part, 0], cells[part, 1]] = bits[part]
    return out


def crowns_within_cells(x: np.ndarray, y: np.ndarray, z: np.ndarray, cls: np.ndarray, nearest_m: np.ndarray, *,
                        x0_m: float, y_top_m: float, res_m: float, min_share: float,
                        sub: int = SUB_CELLS) -> np.ndarray:
    """``nearest_m`` (the nearest-return surface of the first returns x, y, z of classes ``cls`` on this grid, NaN
    nodata) with each cell whose centre's nearest return is vegetation and whose crown share (``crown_share``) is
    below ``min_share`` at the height of the nearest return that is not vegetation (kept where none lies within
    ``nearest.SEARCH_RADIUS_M``: a crown's inside). float32, the shape of ``nearest_m``."""
    nrows, ncols = nearest_m.shape
    veg = np.isin(np.asarray(cls), VEGETATION_CLASSES)
    kw = {"x0_m": x0_m, "y_top_m": y_top_m, "res_m": res_m, "nrows": nrows, "ncols": ncols}
    at_centre = nearest_return_surface(x, y, veg.astype(np.float64), max_dist_m=SEARCH_RADIUS_M, **kw) > 0.5
    cells = np.argwhere(at_centre & np.isfinite(nearest_m))
    share = crown_share(x, y, veg, cells=cells, sub=sub, **kw)
    other = nearest_return_surface(x[~veg], y[~veg], z[~veg], max_dist_m=SEARCH_RADIUS_M, **kw)
    out = np.array(nearest_m, np.float32)
    low = cells[share < min_share]
    o = other[low[:, 0], low[:, 1]]
    keep = np.isfinite(o)
    out[low[keep, 0], low[keep, 1]] = o[keep]
    return out


def crown_sub_cells_beside(x: np.ndarray, y: np.ndarray, z: np.ndarray, cls: np.ndarray, nearest_m: np.ndarray, *,
                           x0_m: float, y_top_m: float, res_m: float,
                           sub: int = SUB_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """``crown_sub_cells`` on both sides of the rim: also the cells whose centre's nearest first return is not
    vegetation but some of whose sub-cell centres are nearer a vegetation return (the crown reaches into them), with
    the height of the vegetation return nearest the centre as their top (float32, NaN for every other cell); the
    Voronoi rim within the cells on either side, as wide on average as the crown."""
    bits = crown_sub_cells(x, y, cls, nearest_m, x0_m=x0_m, y_top_m=y_top_m, res_m=res_m, sub=sub)
    nrows, ncols = nearest_m.shape
    veg = np.isin(np.asarray(cls), VEGETATION_CLASSES)
    kw = {"x0_m": x0_m, "y_top_m": y_top_m, "res_m": res_m, "nrows": nrows, "ncols": ncols}
    at_centre = nearest_return_surface(x, y, veg.astype(np.float64), max_dist_m=SEARCH_RADIUS_M, **kw) > 0.5
    # the candidates: the cells within a cell of a vegetation return (a crown's sub-cells lie within half the
    # spacing of its returns)
    count = np.zeros((nrows, ncols), np.int32)
    r = np.floor((y_top_m - y[veg]) / res_m).astype(np.int64)
    c = np.floor((x[veg] - x0_m) / res_m).astype(np.int64)
    ok = (r >= 0) & (r < nrows) & (c >= 0) & (c < ncols)
    np.add.at(count, (r[ok], c[ok]), 1)
    near = maximum_filter(count, size=3) > 0
    cells = np.argwhere(near & ~at_centre & np.isfinite(nearest_m))
    grid = (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols))
    b, counts = _crown_bits(x, y, veg, grid, cells, sub)
    some = counts > 0
    bits[cells[some, 0], cells[some, 1]] = b[some]
    top = np.full((nrows, ncols), np.nan, np.float32)
    veg_top = nearest_return_surface(x[veg], y[veg], z[veg], max_dist_m=SEARCH_RADIUS_M, **kw)
    top[cells[some, 0], cells[some, 1]] = veg_top[cells[some, 0], cells[some, 1]]
    return bits, top
