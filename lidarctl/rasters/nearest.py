"""The surface straight down at the cell centres from LiDAR returns: the height of the return nearest each centre.

The LiDAR DSM (``rasters``) keeps the highest return per cell: a cell a roof's edge return touches is all roof,
so roofs come out wider than they are by up to a cell plus the point spacing on the side a return lands. The
return nearest the cell centre puts the step halfway between a roof's last return and the ground's first
(Voronoi), as wide on average as the roof itself; that is what the occlusion test of a true ortho wants (the
simulator's truth DSM is the surface straight down at the centres). A linear TIN of the same returns ramps
across the gap instead and stands every centre in it part way up the wall (more ghosts, measured in
docs/true-ortho.md). Grids north-up: row 0 at ``y_top_m``, columns from ``x0_m``; all lengths in metres.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def _nearest_in_buckets(points, start, grid, max_dist):
    # points: (x, y, z) sorted by cell; start: each cell's first point; grid: (x0, y_top, res, nrows, ncols)
    px, py, pz = points
    x0, y_top, res, nrows, ncols = grid
    out = np.full((nrows, ncols), np.nan)
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
                for a in range(i - k, i + k + 1):
                    if a < 0 or a >= nrows:
                        continue
                    edge_row = a == i - k or a == i + k
                    for b in range(j - k, j + k + 1):
                        if b < 0 or b >= ncols or not (edge_row or b == j - k or b == j + k):
                            continue
                        c = a * ncols + b
                        for q in range(start[c], start[c + 1]):
                            d = (px[q] - cx) ** 2 + (py[q] - cy) ** 2
                            # ties: the higher return (the conservative one for an occlusion test)
                            if d < best or (d == best and pz[q] > best_z):
                                best, best_z = d, pz[q]
            out[i, j] = best_z
    return out


def nearest_return_surface(x: np.ndarray, y: np.ndarray, z: np.ndarray, *, x0_m: float, y_top_m: float,
                           res_m: float, nrows: int, ncols: int, max_dist_m: float) -> np.ndarray:
    """Height (z's units) of the return (x, y, z) nearest each cell centre of the grid, NaN where none lies within
    ``max_dist_m``; equally near returns give the highest. Returns off the grid are not used."""
    x, y, z = (np.asarray(v, np.float64) for v in (x, y, z))
    r = np.floor((y_top_m - y) / res_m).astype(np.int64)
    c = np.floor((x - x0_m) / res_m).astype(np.int64)
    on = np.flatnonzero((r >= 0) & (r < nrows) & (c >= 0) & (c < ncols))
    cell = r[on] * ncols + c[on]
    order = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[order], np.arange(nrows * ncols + 1))
    pts = on[order]
    return _nearest_in_buckets((x[pts], y[pts], z[pts]), start,
                               (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols)), float(max_dist_m))
