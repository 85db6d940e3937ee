"""Tree crown bases from LiDAR returns: per cell the height of the lowest vegetation return of the cell and its
neighbours, for the true ortho's occlusion test (``ortho rectify --crown-base``): a tree cell hides the ground only
between its crown base and its top, so a line of sight beneath a crown reaches the ground.

A laser pulse that enters a crown returns from its top, from within it and from the ground beneath; the lowest
vegetation return in a cell lies at or above the crown's underside there. One cell of 0.5 m holds about half a
return at 0.75 m spacing, so the neighbours within ``NEIGHBOUR_CELLS`` count too (the lowest of them: the crown base
the most conservative, a ray beneath it passes); a cell with fewer than ``MIN_RETURNS`` vegetation returns there has
none (NaN: the cell a solid column, as without crown bases). Grids north-up: row 0 at ``y_top_m``, columns from
``x0_m``; lengths in metres; classes ASPRS (3, 4, 5: low, medium, high vegetation).
"""

from __future__ import annotations

import numba
import numpy as np

VEGETATION_CLASSES = (3, 4, 5)
NEIGHBOUR_CELLS = 1  # the cell and its 8 neighbours
MIN_RETURNS = 3  # vegetation returns among them for a crown base (one is the top alone)


@numba.njit(cache=True)
def _lowest_around(lowest, count, k, min_returns):
    nrows, ncols = lowest.shape
    out = np.full((nrows, ncols), np.nan, np.float32)
    for i in range(nrows):
        for j in range(ncols):
            if count[i, j] == 0:
                continue
            z = np.inf
            n = 0
            for a in range(max(0, i - k), min(nrows, i + k + 1)):
                for b in range(max(0, j - k), min(ncols, j + k + 1)):
                    n += count[a, b]
                    z = min(z, lowest[a, b])
            if n >= min_returns:
                out[i, j] = z
    return out


def crown_base_surface(x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray, classification: np.ndarray, *,
                       x0_m: float, y_top_m: float, res_m: float, shape: tuple[int, int],
                       neighbour_cells: int = NEIGHBOUR_CELLS, min_returns: int = MIN_RETURNS) -> np.ndarray:
    """(rows, cols) float32: per cell with a vegetation return the lowest vegetation return of it and its neighbours
    within ``neighbour_cells`` (NaN: no vegetation return in the cell, or fewer than ``min_returns`` around it)."""
    veg = np.isin(np.asarray(classification), VEGETATION_CLASSES)
    r = np.floor((y_top_m - np.asarray(y_m)[veg]) / res_m).astype(np.int64)
    c = np.floor((np.asarray(x_m)[veg] - x0_m) / res_m).astype(np.int64)
    ok = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    cid = r[ok] * shape[1] + c[ok]
    lowest = np.full(shape[0] * shape[1], np.inf)
    np.minimum.at(lowest, cid, np.asarray(z_m, np.float64)[veg][ok])
    count = np.bincount(cid, minlength=shape[0] * shape[1]).astype(np.int64)
    return _lowest_around(lowest.reshape(shape), count.reshape(shape), int(neighbour_cells), int(min_returns))
