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
def _nearer(d, z, best, best_z):
    # ties: the higher return (the conservative one for an occlusion test); NaN z (none yet) never wins a tie
    return d < best or (d == best and z > best_z)


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_in_run(pts, run, centre, nearest):
    # the points run = (q0, q1) (cells next to each other in a row: one run of the sorted points) against the
    # nearest so far, (squared distance, z), to the centre (x, y)
    cx, cy = centre
    best, best_z = nearest
    for q in range(run[0], run[1]):
        d = (pts[q, 0] - cx) ** 2 + (pts[q, 1] - cy) ** 2
        if _nearer(d, pts[q, 2], best, best_z):
            best, best_z = d, pts[q, 2]
    return best, best_z


@numba.njit(cache=True, nogil=True)
def _nearest_beyond(pts, start, grid, cell, rings, nearest):
    # rings k0 .. reach (``rings``) of cell (i, j) after the nearer ones gave ``nearest`` (squared distance, z). Ring
    # k: its top and bottom rows are each one run of points (cells of a row are consecutive), its sides two cells a
    # row; every cell of ring k lies at least (k - 0.5) cells from the centre, so the search stops at the first
    # ring that cannot hold a nearer one.
    x0, y_top, res, nrows, ncols = grid
    i, j = cell
    k0, reach = rings
    best, best_z = nearest
    centre = (x0 + (j + 0.5) * res, y_top - (i + 0.5) * res)
    for k in range(k0, reach + 1):
        if k > 0 and ((k - 0.5) * res) ** 2 > best:
            break
        b_lo, b_hi = max(j - k, 0), min(j + k, ncols - 1)
        for side in range(2 if k > 0 else 1):   # the top row, the bottom row (ring 0: the cell)
            a = i - k if side == 0 else i + k
            if 0 <= a < nrows:
                best, best_z = _nearest_in_run(pts, (start[a * ncols + b_lo], start[a * ncols + b_hi + 1]), centre,
                                               (best, best_z))
        for a in range(max(i - k + 1, 0), min(i + k, nrows)):
            for b in (j - k, j + k):
                if 0 <= b < ncols:
                    c = a * ncols + b
                    best, best_z = _nearest_in_run(pts, (start[c], start[c + 1]), centre, (best, best_z))
    return best, best_z


@numba.njit(cache=True, nogil=True, inline="always")
def _any_within(start, grid, i, j, k):
    # whether any point lies in the cells within k rows and columns of cell (i, j): one run a row (the centres in
    # gaps, which find none, ask this instead of searching every ring)
    nrows, ncols = grid[3], grid[4]
    b_lo, b_hi = max(j - k, 0), min(j + k, ncols - 1)
    for a in range(max(i - k, 0), min(i + k + 1, nrows)):
        if start[a * ncols + b_hi + 1] > start[a * ncols + b_lo]:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _nearest_in_buckets(pts, start, grid, max_dist, stop):
    # pts: (x, y, z) rows sorted by cell; start: each cell's first point; grid: (x0, y_top, res, nrows, ncols). The
    # result of the ring search of ``_nearest_beyond`` from ring 0 at every cell, but rings 0 and 1 scattered: the
    # returns of each row of cells, in order, update the nearest of their own cell (ring 0) and of the 8 around it
    # (ring 1) in three rolling rows (one column of padding each side); a row is done once the row below it is,
    # and only its cells without a return within 1.5 cells (a few %) search further. The same candidates as the
    # search from ring 0 (ring 1 only where ring 0 left none within half a cell), so the same nearest return.
    x0, y_top, res, nrows, ncols = grid
    out = np.empty((nrows, ncols), np.float32)
    reach = int(math.ceil(max_dist / res))
    far = max_dist * max_dist
    ring1, ring2 = ((1 - 0.5) * res) ** 2, ((2 - 0.5) * res) ** 2     # the ring search's bounds, the same floats
    cx = np.empty(ncols + 2)
    for j in range(-1, ncols + 1):
        cx[j + 1] = x0 + (j + 0.5) * res
    near0, near0_z = np.full((3, ncols + 2), far), np.full((3, ncols + 2), np.nan)   # ring 0, by row mod 3
    near1, near1_z = np.full((3, ncols + 2), far), np.full((3, ncols + 2), np.nan)   # ring 1
    for a in range(nrows + 1):
        if stop[0]:   # the caller stops (Ctrl-C, SIGTERM): the rows not done are left as they are
            return out
        if a < nrows:
            s = (a + 1) % 3           # row a + 1, last used by row a - 2 (done)
            near0[s], near0_z[s], near1[s], near1_z[s] = far, np.nan, far, np.nan
            cys = (y_top - (a - 1 + 0.5) * res, y_top - (a + 0.5) * res, y_top - (a + 1 + 0.5) * res)
            for j in range(ncols):
                c = a * ncols + j
                for q in range(start[c], start[c + 1]):
                    px, py, pz = pts[q, 0], pts[q, 1], pts[q, 2]
                    for t in range(3):
                        r = (a + 2 + t) % 3          # row a - 1 + t
                        dy2 = (py - cys[t]) ** 2
                        for u in range(3):
                            d = (px - cx[j + u]) ** 2 + dy2
                            if t == 1 and u == 1:
                                if _nearer(d, pz, near0[r, j + 1], near0_z[r, j + 1]):
                                    near0[r, j + 1], near0_z[r, j + 1] = d, pz
                            elif _nearer(d, pz, near1[r, j + u], near1_z[r, j + u]):
                                near1[r, j + u], near1_z[r, j + u] = d, pz
        i = a - 1                      # every return of rows i - 1 .. i + 1 is in: row i is done
        if i < 0:
            continue
        r = i % 3
        for j in range(ncols):
            best, best_z = near0[r, j + 1], near0_z[r, j + 1]
            if reach >= 1 and not ring1 > best:
                if _nearer(near1[r, j + 1], near1_z[r, j + 1], best, best_z):
                    best, best_z = near1[r, j + 1], near1_z[r, j + 1]
                if reach >= 2 and not ring2 > best and _any_within(start, grid, i, j, reach):
                    best, best_z = _nearest_beyond(pts, start, grid, (i, j), (2, reach), (best, best_z))
            out[i, j] = best_z
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_of(x, y, grid):
    x0, y_top, res, nrows, ncols = grid
    r = math.floor((y_top - y) / res)
    c = math.floor((x - x0) / res)
    return r * ncols + c if (0 <= r < nrows and 0 <= c < ncols) else -1


@numba.njit(cache=True, nogil=True, inline="always")
def _takes(cls, return_number):
    # ``first_return_mask`` of one return
    return return_number == 1 and cls != NOT_VALID[0] and cls != NOT_VALID[1]


@numba.njit(cache=True, nogil=True)
def _count_in_cells(chunk, grid, start):
    # the returns the surface takes of a chunk (x, y, z, class, return number) per cell, into start[cell + 2]
    x, y, _, cls, return_number = chunk
    for q in range(len(x)):
        if _takes(cls[q], return_number[q]):
            k = _cell_of(x[q], y[q], grid)
            if k >= 0:
                start[k + 2] += 1


@numba.njit(cache=True, nogil=True)
def _sort_into_cells(chunk, grid, start, pts):
    # the counting sort's scatter (stable) of a chunk (x, y, z, class, return number): start[cell + 1] is the cell's
    # next free row of pts
    x, y, z, cls, return_number = chunk
    for q in range(len(x)):
        if _takes(cls[q], return_number[q]):
            k = _cell_of(x[q], y[q], grid)
            if k >= 0:
                i = start[k + 1]
                start[k + 1] += 1
                pts[i, 0], pts[i, 1], pts[i, 2] = x[q], y[q], z[q]


def _chunk(x, y, z, cls, return_number):
    # one layout, one compilation of the kernels
    c = np.ascontiguousarray
    return c(x, np.float64), c(y, np.float64), c(z, np.float64), c(cls, np.uint8), c(return_number, np.uint8)


class NearestReturns:
    """``nearest_return_surface`` of the returns of chunks of points (``first_return_mask``'s), read twice: every
    chunk ``count``-ed, then the same chunks ``add``-ed in the same order, then ``surface``. Memory: the returns
    taken, 24 bytes each, and 8 bytes a cell (a counting sort by cell); no copy of the chunks is kept."""

    def __init__(self, *, x0_m: float, y_top_m: float, res_m: float, nrows: int, ncols: int, max_dist_m: float):
        self._grid = (float(x0_m), float(y_top_m), float(res_m), int(nrows), int(ncols))
        self._max_dist_m = float(max_dist_m)
        # the cells' counts go into start[k + 2], so that the scatter's running positions in start[k + 1] end as
        # the starts
        self._start = np.zeros(int(nrows) * int(ncols) + 2, np.int64)
        self._pts = None

    def count(self, x, y, cls, return_number) -> None:
        """First pass: a chunk's returns (x, y in metres, class, return number) counted by cell."""
        _count_in_cells(_chunk(x, y, x, cls, return_number), self._grid, self._start)

    def add(self, x, y, z, cls, return_number) -> None:
        """Second pass: the same chunk, its returns (z in metres) sorted into their cells."""
        if self._pts is None:
            np.cumsum(self._start, out=self._start)
            self._pts = np.empty((int(self._start[-1]), 3))
        _sort_into_cells(_chunk(x, y, z, cls, return_number), self._grid, self._start, self._pts)

    def surface(self, stop: np.ndarray | None = None) -> np.ndarray:
        """``nearest_return_surface`` of the returns added (none if no chunk was added). ``stop``: a one-element bool
        array another thread sets to stop the search between rows (the surface is then unfinished): at cells much
        finer than the points' spacing a tile's search takes minutes in one call (0.01 m cells on Autzen's 2 points
        per m2: a SIGTERM waited more than 150 s for it, new-user trial)."""
        stop = np.zeros(1, np.bool_) if stop is None else stop
        if self._pts is None:
            return _nearest_in_buckets(np.empty((0, 3)), np.zeros(len(self._start) - 1, np.int64), self._grid,
                                       self._max_dist_m, stop)
        return _nearest_in_buckets(self._pts, self._start[:-1], self._grid, self._max_dist_m, stop)


def nearest_return_surface(x: np.ndarray, y: np.ndarray, z: np.ndarray, *, x0_m: float, y_top_m: float,
                           res_m: float, nrows: int, ncols: int, max_dist_m: float) -> np.ndarray:
    """Height (z's units, float32) of the return (x, y, z) nearest each cell centre of the grid, NaN where none lies
    within ``max_dist_m``; equally near returns give the highest. Returns off the grid are not used."""
    near = NearestReturns(x0_m=x0_m, y_top_m=y_top_m, res_m=res_m, nrows=nrows, ncols=ncols, max_dist_m=max_dist_m)
    taken, first = np.zeros(len(x), np.uint8), np.ones(len(x), np.uint8)     # every return (not noise, first)
    near.count(x, y, taken, first)
    near.add(x, y, z, taken, first)
    return near.surface()
