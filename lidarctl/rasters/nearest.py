"""The surface straight down at the cell centres from LiDAR returns: the height of the return nearest each centre.

The LiDAR DSM (``rasters``) keeps the highest return per cell: a cell a roof's edge return touches is all roof,
so roofs come out wider than they are by up to a cell plus the point spacing on the side a return lands. The
return nearest the cell centre puts the step halfway between a roof's last return and the ground's first
(Voronoi), as wide on average as the roof itself; that is what the occlusion test of a true ortho wants (the
simulator's truth DSM is the surface straight down at the centres). A linear TIN of the same returns ramps
across the gap instead and stands every centre in it part way up the wall (more ghosts, measured in
docs/true-ortho.md). Grids north-up: row 0 at ``y_top_m``, columns from ``x0_m``; all lengths in metres.

``lidarctl rasters`` writes it as ``dsm_nearest.tif`` (``FILE``) beside dsm.tif, on its grid: the first returns
(noise excluded, as dsm.tif takes them), the DSM's value where no return lies within ``SEARCH_RADIUS_M`` of a
centre, nodata where the DSM is; the chain's true ortho tests occlusion on it (docs/true-ortho.md).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lidarctl.rasters.cells import NOT_VALID

FILE = "dsm_nearest.tif"
# A centre with no return this near (water, a gap in the strips) takes the DSM's value. Not fitted: half the
# longest TIN edge the bench's surfaces took (bench/eval_true_ortho_dsm_cell.py); at the LiDAR's 0.75-1.1 m
# spacing every centre of the covered ground has a return within 1-2 m, so it decides only the gaps.
SEARCH_RADIUS_M = 5.0


def first_return_mask(cls: np.ndarray, return_number: np.ndarray) -> np.ndarray:
    """The returns the surface takes: first returns (return number 1, as ``io`` sanitises them) not noise."""
    return (np.asarray(return_number) == 1) & ~np.isin(cls, NOT_VALID)


def reach_px(res_m: float) -> int:
    """Cells beyond a grid's edge whose returns can be the nearest to one of its centres (the tiles' buffer)."""
    return int(math.ceil(SEARCH_RADIUS_M / res_m)) + 1


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_in_run(px, py, pz, q0, q1, cx, cy, best, best_z):
    # the points q0 .. q1 (cells next to each other in a row: one run of the sorted points)
    for q in range(q0, q1):
        d = (px[q] - cx) ** 2 + (py[q] - cy) ** 2
        # ties: the higher return (the conservative one for an occlusion test)
        if d < best or (d == best and pz[q] > best_z):
            best, best_z = d, pz[q]
    return best, best_z


@numba.njit(cache=True, nogil=True)
def _nearest_in_buckets(points, start, grid, max_dist):
    # points: (x, y, z) sorted by cell; start: each cell's first point; grid: (x0, y_top, res, nrows, ncols). Ring k
    # of a cell: its top and bottom rows are each one run of points (cells of a row are consecutive), its sides two
    # cells a row.
    px, py, pz = points
    x0, y_top, res, nrows, ncols = grid
    out = np.empty((nrows, ncols), np.float32)
    reach = int(math.ceil(max_dist / res))
    for i in range(nrows):
        cy = y_top - (i + 0.5) * res
        for j in range(ncols):
            cx = x0 + (j + 0.5) * res
            best, best_z = max_dist * max_dist, np.nan
            for k in range(reach + 1):
                # every cell of ring k lies at least (k - 0.5) cells from the centre
                if k > 0 and ((k - 0.5) * res) ** 2 > best:
                    break
                b_lo, b_hi = max(j - k, 0), min(j + k, ncols - 1)
                for side in range(2 if k > 0 else 1):   # the top row, the bottom row (ring 0: the cell)
                    a = i - k if side == 0 else i + k
                    if 0 <= a < nrows:
                        best, best_z = _nearest_in_run(px, py, pz, start[a * ncols + b_lo],
                                                       start[a * ncols + b_hi + 1], cx, cy, best, best_z)
                for a in range(max(i - k + 1, 0), min(i + k, nrows)):
                    for b in (j - k, j + k):
                        if 0 <= b < ncols:
                            c = a * ncols + b
                            best, best_z = _nearest_in_run(px, py, pz, start[c], start[c + 1], cx, cy, best, best_z)
            out[i, j] = best_z
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_of(x, y, grid):
    x0, y_top, res, nrows, ncols = grid
    r = math.floor((y_top - y) / res)
    c = math.floor((x - x0) / res)
    return r * ncols + c if (0 <= r < nrows and 0 <= c < ncols) else -1


@numba.njit(cache=True, nogil=True)
def _bucket_points(x, y, z, grid):
    # the points on the grid sorted by cell (a counting sort, stable) and each cell's first point; the cells'
    # counts go into start[k + 2], so that the scatter's running positions in start[k + 1] end as the starts
    n_cells = grid[3] * grid[4]
    start = np.zeros(n_cells + 2, np.int64)
    for q in range(len(x)):
        k = _cell_of(x[q], y[q], grid)
        if k >= 0:
            start[k + 2] += 1
    for k in range(2, n_cells + 2):
        start[k] += start[k - 1]
    m = start[n_cells + 1]
    px, py, pz = np.empty(m), np.empty(m), np.empty(m)
    for q in range(len(x)):
        k = _cell_of(x[q], y[q], grid)
        if k >= 0:
            i = start[k + 1]
            start[k + 1] += 1
            px[i], py[i], pz[i] = x[q], y[q], z[q]
    return (px, py, pz), start[:n_cells + 1]


def nearest_return_surface(x: np.ndarray, y: np.ndarray, z: np.ndarray, *, x0_m: float, y_top_m: float,
                           res_m: float, nrows: int, ncols: int, max_dist_m: float) -> np.ndarray:
    """Height (z's units, float32) of the return (x, y, z) nearest each cell centre of the grid, NaN where none lies
    within ``max_dist_m``; equally near returns give the highest. Returns off the grid are not used."""
    x, y, z = (np.ascontiguousarray(v, np.float64) for v in (x, y, z))
    grid = (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols))
    points, start = _bucket_points(x, y, z, grid)
    return _nearest_in_buckets(points, start, grid, float(max_dist_m))
