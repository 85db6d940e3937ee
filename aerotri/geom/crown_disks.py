"""Tree crowns as disks (a fitted rim per tree, its top and crown base) and the grid cells they cover, shared by
``lidarctl.rasters.crown_model`` (which fits them to LiDAR returns) and ``ortho.crown_cells`` (which puts them in the
true ortho's occlusion test). Lengths and heights in metres or the CRS's unit, as given; grids north-up (row 0 at
``y_top_m``, columns from ``x0_m``).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

# crowns.gpkg (``lidarctl.rasters.crown_model.write_crown_model``) holds its fields x_m, y_m, radius_m, top_m, base_m
# in metres (lengths by the CRS's horizontal unit, heights by the clouds' height unit); a file in a CRS whose lengths
# or heights are not metres says so with this note in its layer's description. Such a file without it was written
# before (main up to 2026-12-01) and holds them in the CRS's units (``ortho.crown_cells.read_crowns`` reads both).
CROWNS_IN_METRES_NOTE = "crowns: x_m, y_m, radius_m, top_m, base_m in metres"


@dataclasses.dataclass(frozen=True)
class TreeCrowns:
    """One entry per tree: the crown's disk (centre ``x_m``, ``y_m``, ``radius_m``), its ``top_m`` (highest
    vegetation first return), ``base_m`` (lowest vegetation return, any return number), the vegetation first
    returns it holds (``returns``), ``circle_fit`` (the circle fitted to its rim samples; False: centroid and median
    distance), and ``spacing_m`` (the cloud's first-return spacing)."""

    x_m: np.ndarray
    y_m: np.ndarray
    radius_m: np.ndarray
    top_m: np.ndarray
    base_m: np.ndarray
    returns: np.ndarray
    circle_fit: np.ndarray
    spacing_m: float

    def __len__(self) -> int:
        return len(self.x_m)


def crown_sub_cells(crowns: TreeCrowns, *, x0_m: float, y_top_m: float, res_m: float, shape: tuple[int, int],
                    sub: int, reach_m: float = 1.0, window: tuple[int, int, int, int] | None = None):
    """The cells a crown's disk reaches within ``reach_m``: rows, cols (int64), per cell the signed distance (cm,
    int16, positive inside) of its ``sub`` x ``sub`` sub-cell centres within the union of the disks (rows from the
    north, columns from the west), the lowest crown base and the highest top of the trees whose disks cover a
    sub-cell centre of it (NaN: none). ``window``: (row0, col0, rows, cols) of the grid, the only cells given (rows
    and columns still of the whole grid; a window's cells as in the whole grid, bit for bit). Each tree's box of
    cells (its disk grown by ``reach_m``, truncated to whole cells) from the trees' arrays at once; the sub-cells'
    distances in one compiled pass over the boxes (``_disk_margins``: the ortho's frames call this once a frame, a
    numpy pass per tree cost 0.25 CPU-s a demo block)."""
    w_r0, w_c0, w_rows, w_cols = window if window is not None else (0, 0, *shape)
    cx, cy, r = (np.asarray(a, np.float64) for a in (crowns.x_m, crowns.y_m, crowns.radius_m))
    # int(): toward zero, as the boxes were always cut
    r0 = np.maximum(w_r0, np.trunc((y_top_m - cy - r - reach_m) / res_m).astype(np.int64))
    r1 = np.minimum(w_r0 + w_rows, np.trunc((y_top_m - cy + r + reach_m) / res_m).astype(np.int64) + 1)
    c0 = np.maximum(w_c0, np.trunc((cx - r - reach_m - x0_m) / res_m).astype(np.int64))
    c1 = np.minimum(w_c0 + w_cols, np.trunc((cx + r + reach_m - x0_m) / res_m).astype(np.int64) + 1)
    trees = np.flatnonzero((r1 > r0) & (c1 > c0))
    if not len(trees):
        e = np.zeros(0, np.int64)
        return e, e, np.zeros((0, sub, sub), np.int16), np.zeros(0, np.float32), np.zeros(0, np.float32)
    flat, margins, bases, tops = _disk_margins(trees, r0, r1, c0, c1, cx, cy, r,
                                               np.asarray(crowns.base_m, np.float64),
                                               np.asarray(crowns.top_m, np.float64), float(x0_m), float(y_top_m),
                                               float(res_m), int(sub), int(shape[1]))
    cells, cm, base, top = _union_of_disks(flat, np.argsort(flat, kind="stable"), margins, bases, tops)
    rows, cols = np.divmod(cells, shape[1])
    return (rows, cols, cm, np.where(np.isfinite(base), base, np.nan).astype(np.float32),
            np.where(np.isfinite(top), top, np.nan).astype(np.float32))


@numba.njit(cache=True, nogil=True)
def _disk_margins(trees, r0, r1, c0, c1, cx, cy, radius, base_m, top_m, x0_m, y_top_m, res_m, sub, cols):
    """For each tree of ``trees`` (in that order), each cell of its box (rows ``r0`` .. ``r1``, columns ``c0`` ..
    ``c1``, row-major): the cell's flat index (row * ``cols`` + column), the signed distances (m, float64) of its
    sub-cell centres within the disk, the tree's crown base where one of them rounds to 0 cm or more (+inf else)
    and its top (-inf else); the arithmetic of the numpy expressions it replaced, operation for operation."""
    n = 0
    for t in trees:
        n += (r1[t] - r0[t]) * (c1[t] - c0[t])
    flat = np.empty(n, np.int64)
    margins = np.empty((n, sub, sub), np.float64)
    bases = np.empty(n, np.float64)
    tops = np.empty(n, np.float64)
    off = (np.arange(sub) + 0.5) / sub
    k = 0
    for t in trees:
        for i in range(r0[t], r1[t]):
            for j in range(c0[t], c1[t]):
                covers = False
                for a in range(sub):
                    y = y_top_m - (i + off[a]) * res_m
                    for b in range(sub):
                        x = x0_m + (j + off[b]) * res_m
                        m = radius[t] - np.hypot(x - cx[t], y - cy[t])
                        margins[k, a, b] = m
                        if np.rint(m * 100.0) >= 0:
                            covers = True
                flat[k] = i * cols + j
                bases[k] = base_m[t] if covers else np.inf
                tops[k] = top_m[t] if covers else -np.inf
                k += 1
    return flat, margins, bases, tops


@numba.njit(cache=True, nogil=True)
def _union_of_disks(flat, order, margins, bases, tops):
    """Per distinct cell of ``flat`` (ascending; ``order`` sorts it) the largest of its entries' ``margins`` (the
    union of the disks) in cm (rounded half to even, within +-32000, int16), the lowest of their ``bases`` and the
    highest of their ``tops``."""
    n = len(flat)
    distinct = 0
    for q in range(n):
        if q == 0 or flat[order[q]] != flat[order[q - 1]]:
            distinct += 1
    sub = margins.shape[1]
    cells = np.empty(distinct, np.int64)
    margin = np.empty((distinct, sub, sub), np.float64)
    base = np.empty(distinct, np.float64)
    top = np.empty(distinct, np.float64)
    k = -1
    for q in range(n):
        e = order[q]
        if q == 0 or flat[e] != cells[k]:
            k += 1
            cells[k] = flat[e]
            margin[k] = margins[e]
            base[k] = bases[e]
            top[k] = tops[e]
            continue
        for a in range(sub):
            for b in range(sub):
                if margins[e, a, b] > margin[k, a, b]:
                    margin[k, a, b] = margins[e, a, b]
        base[k] = min(base[k], bases[e])
        top[k] = max(top[k], tops[e])
    cm = np.empty((distinct, sub, sub), np.int16)
    for k in range(distinct):
        for a in range(sub):
            for b in range(sub):
                cm[k, a, b] = np.int16(min(max(np.rint(margin[k, a, b] * 100.0), -32000.0), 32000.0))
    return cells, cm, base, top
