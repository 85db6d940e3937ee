"""Horizontal k nearest neighbours on a grid of buckets, giving exactly scipy cKDTree's answer.

``knn_2d(px, py, qx, qy, k, upper_m)`` returns what
``cKDTree(column_stack([px, py])).query(column_stack([qx, qy]), k, distance_upper_bound=upper_m)``
returns (distances in metres, sorted ascending; ``inf`` and index ``len(px)`` where fewer than ``k``
points lie closer than ``upper_m``), at a fraction of its CPU time on LiDAR clouds: the points are
bucketed in square cells sized to hold about ``k`` points in a 5 x 5 block, each query scans rings of
cells around its own until no unscanned cell can hold a closer point, and queries run in cell order
(the cells they read stay in cache). Squared distances are computed as cKDTree computes them
(dx * dx + dy * dy in float64), so distances and neighbour sets agree bit for bit.

Ties: where two candidates lie at exactly the same distance, which of them is nearer (and which one
is the k-th when the (k+1)-th ties with it) is decided by cKDTree's tree walk, not by the distance.
Such queries (their k + 1 nearest distances are not all distinct) are answered by cKDTree itself,
so the result is cKDTree's in every case; on LiDAR coordinates (mm steps) they are rare (the count
is returned for the record).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from scipy.spatial import cKDTree

from lidarctl.grid import cell_order

# Cell edge as a share of the radius holding k + 1 points at the mean density: 0.5 makes a query
# scan 2-3 rings (about 25-49 cells of ~k/12 points each) instead of 1-2 rings of crowded cells.
CELL_SHARE_OF_RADIUS = 0.5
# Queries per call in the callers' chunked loops: the (m, k) distance and index arrays of a chunk
# take about k x 16 MB at k = 17 (272 MB), whatever the tile's size.
QUERY_CHUNK = 1_000_000


class _Buckets(NamedTuple):
    """The points bucketed as the kernel takes them: sorted by cell (sx, sy; ``order``: their original indices),
    each cell's first (``cell_start``), the grid (rows, columns, origin x0, y0 and cell edge, metres)."""

    sx: np.ndarray
    sy: np.ndarray
    order: np.ndarray
    cell_start: np.ndarray
    nrows: int
    ncols: int
    x0: float
    y0: float
    cell_m: float


@numba.njit(cache=True, inline="always")
def _scan(sx, sy, scan, bd, bi, cnt):
    """Offer the (cell-sorted) points (sx, sy) first..last-1 to the sorted buffer (bd, bi) of the kk = len(bd)
    nearest of the query (x, y) (``scan``: (first, last, x, y, ub2), ub2 the squared distance bound); returns the
    new count. Scalars in the tuple, the arrays apart: an array taken out of a tuple costs a reference count
    per call."""
    first, last, x, y, ub2 = scan
    kk = len(bd)
    for s in range(first, last):
        dx = x - sx[s]
        dy = y - sy[s]
        d2 = dx * dx + dy * dy
        if d2 < ub2 and (cnt < kk or d2 < bd[kk - 1]):
            h = min(cnt, kk - 1)
            while h > 0 and bd[h - 1] > d2:
                bd[h] = bd[h - 1]
                bi[h] = bi[h - 1]
                h -= 1
            bd[h] = d2
            bi[h] = s
            if cnt < kk:
                cnt += 1
    return cnt


@numba.njit(cache=True, parallel=True)
def _knn_kernel(buckets, queries, k, kk, ub2):
    """The ``k`` nearest points (squared distance < ``ub2``) of each query, ascending, found among its
    ``kk`` (k or k + 1) nearest. ``buckets`` (``_Buckets``): the points sorted by cell and the cells;
    ``queries``: (qx, qy, qorder: the queries in cell order).

    Returns dist (m, k) (inf where missing), idx (m, k) (len(sx) where missing) and a per-query flag:
    True when two of the kk nearest distances are equal (the order or the set is then cKDTree's
    tie-break, not the distance's)."""
    sx, sy, order, cell_start, nrows, ncols, x0, y0, cell_m = buckets
    qx, qy, qorder = queries
    m = len(qx)
    n = len(sx)
    out_d = np.full((m, k), np.inf)
    out_i = np.full((m, k), n, np.int64)
    tied = np.zeros(m, np.bool_)
    # Queries in cell order, in blocks (one buffer per block): neighbouring queries read the same cells.
    nblocks = (m + 4095) // 4096
    for b in numba.prange(nblocks):
        bd = np.empty(kk)
        bi = np.empty(kk, np.int64)
        for t in range(b * 4096, min(m, (b + 1) * 4096)):
            q = qorder[t]
            x, y = qx[q], qy[q]
            cj = min(max(int(math.floor((x - x0) / cell_m)), 0), ncols - 1)
            ci = min(max(int(math.floor((y - y0) / cell_m)), 0), nrows - 1)
            bd[:] = np.inf
            bi[:] = n
            cnt = 0
            r = 0
            while True:
                jlo, jhi = max(cj - r, 0), min(cj + r, ncols - 1)
                for i in range(max(ci - r, 0), min(ci + r, nrows - 1) + 1):
                    row = i * ncols
                    if i == ci - r or i == ci + r:
                        # a whole row of the ring: its cells are consecutive in the sorted points
                        cnt = _scan(sx, sy, (cell_start[row + jlo], cell_start[row + jhi + 1], x, y, ub2), bd, bi,
                                    cnt)
                    else:
                        if cj - r >= 0:
                            c = row + cj - r
                            cnt = _scan(sx, sy, (cell_start[c], cell_start[c + 1], x, y, ub2), bd, bi, cnt)
                        if r > 0 and cj + r < ncols:
                            c = row + cj + r
                            cnt = _scan(sx, sy, (cell_start[c], cell_start[c + 1], x, y, ub2), bd, bi, cnt)
                # Nearest possible distance of a point outside the scanned block (a micrometre of
                # margin for the rounding of the cell assignment).
                gx = min(x - (x0 + (cj - r) * cell_m), x0 + (cj + r + 1) * cell_m - x)
                gy = min(y - (y0 + (ci - r) * cell_m), y0 + (ci + r + 1) * cell_m - y)
                g = min(gx, gy) - 1e-6
                if g > 0.0:
                    g2 = g * g
                    if g2 >= ub2 or (cnt == kk and bd[kk - 1] <= g2):
                        break
                if ci - r <= 0 and cj - r <= 0 and ci + r >= nrows - 1 and cj + r >= ncols - 1:
                    break
                r += 1
            for h in range(min(cnt, k)):
                out_d[q, h] = math.sqrt(bd[h])
                out_i[q, h] = order[bi[h]]
            for h in range(cnt - 1):
                if bd[h] == bd[h + 1]:
                    tied[q] = True
    return out_d, out_i, tied


class BucketGrid:
    """The points (px, py) bucketed for ``query``; cKDTree's tree of them built only when a query ties."""

    def __init__(self, px, py, k_hint: int = 16):
        self.px = np.ascontiguousarray(px, np.float64)
        self.py = np.ascontiguousarray(py, np.float64)
        n = self.n = len(self.px)
        if n == 0:
            raise ValueError("BucketGrid needs points")
        self.x0, self.y0 = float(self.px.min()), float(self.py.min())
        w = max(float(self.px.max()) - self.x0, 1e-6)
        h = max(float(self.py.max()) - self.y0, 1e-6)
        # Cell edge from the mean density of the points' box; never more cells than points.
        radius_m = math.sqrt((k_hint + 1) * w * h / (math.pi * n))
        self.cell_m = max(CELL_SHARE_OF_RADIUS * radius_m, math.sqrt(w * h / n), 1e-6)
        self.ncols, self.nrows = int(w // self.cell_m) + 1, int(h // self.cell_m) + 1
        self.order, self.cell_start = cell_order(self._cells(self.px, self.py), self.nrows * self.ncols)
        self.sx, self.sy = self.px[self.order], self.py[self.order]
        self._tree = None

    def _cells(self, x, y):
        j = np.clip(np.floor((x - self.x0) / self.cell_m), 0, self.ncols - 1).astype(np.int64)
        i = np.clip(np.floor((y - self.y0) / self.cell_m), 0, self.nrows - 1).astype(np.int64)
        return i * self.ncols + j

    def query(self, qx, qy, k: int, upper_m: float = np.inf):
        """(dist (m, k), idx (m, k), n_tied) as ``cKDTree.query(..., k, distance_upper_bound=upper_m)``
        of the points; ``n_tied``: queries with equal distances among their k + 1 nearest, answered by
        cKDTree."""
        qx, qy = np.ascontiguousarray(qx, np.float64), np.ascontiguousarray(qy, np.float64)
        if k < 1:
            raise ValueError("knn needs k >= 1")
        qorder = cell_order(self._cells(qx, qy), self.nrows * self.ncols)[0]
        ub2 = float(upper_m) * float(upper_m) if np.isfinite(upper_m) else np.inf
        buckets = _Buckets(self.sx, self.sy, self.order, self.cell_start, self.nrows, self.ncols, float(self.x0),
                           float(self.y0), float(self.cell_m))
        dist, nb, tied = _knn_kernel(buckets, (qx, qy, qorder), k, min(k + 1, self.n), ub2)
        t = np.flatnonzero(tied)
        if len(t):
            if self._tree is None:
                self._tree = cKDTree(np.column_stack([self.px, self.py]))
            dt, it = self._tree.query(np.column_stack([qx[t], qy[t]]), k=k, distance_upper_bound=upper_m)
            dist[t], nb[t] = dt.reshape(len(t), k), it.reshape(len(t), k)
        return dist, nb, len(t)


def knn_2d(px, py, qx, qy, k: int, upper_m: float = np.inf):
    """k nearest of the points (px, py) to each query (qx, qy), horizontally: (dist (m, k), idx (m, k),
    n_tied), identical to ``cKDTree(column_stack([px, py])).query(column_stack([qx, qy]), k=k,
    distance_upper_bound=upper_m)``. Coordinates in metres. ``n_tied``: queries with equal distances
    among their k + 1 nearest, answered by cKDTree."""
    return BucketGrid(px, py, k).query(qx, qy, k, upper_m)
