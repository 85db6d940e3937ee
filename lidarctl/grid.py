"""Regular 2D/3D grids over point clouds: cell indices, per-cell minima and neighbourhoods.

Cells are square, ``cell_m`` wide, anchored at the lower-left corner (x0, y0) of the cloud; row
index ``i`` grows with y, column index ``j`` with x. All functions are vectorised NumPy.

Part of a larger cloud (a tile's window, ``lidarctl.tiles``) is classified on the whole cloud's cells: within
``whole_cloud(frame)`` (``CloudFrame``: the whole cloud's lowest x, y, mean point spacing and noise) a grid
anchored at its points' lowest x, y (``origin``, and ``cell_indices`` / ``cell_ids`` without an origin) starts at
the corner of the whole cloud's cell holding them, and ``cloud_spacing_m`` is the whole cloud's spacing, so that
the cells, and the cell sizes taken from the spacing, do not depend on how the cloud was cut into tiles.

Grids over a bounding box can be absurdly large when points lie far apart (strips of two UTM zones
under one CRS, a stray point): ``aerotri.core.limits.check_allocation`` compares a grid's memory with the machine's RAM
before it is allocated, and ``cell_ids`` applies it to every grid made here.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import math

import numba
import numpy as np

from aerotri.core.limits import check_allocation

# Per-cell memory of the grids callers of ``cell_ids`` build (a few float64/int64 arrays per cell).
GRID_BYTES_PER_CELL = 48


def check_grid(nrows: int, ncols: int, cell_m: float, bytes_per_cell: float, what: str,
               *, option: str | None = None, hint: str = "") -> None:
    """``check_allocation`` for a grid of ``nrows`` x ``ncols`` cells of ``cell_m`` metres."""
    check_allocation(float(nrows) * float(ncols) * bytes_per_cell,
                     f"{what}: a grid of {nrows:,} x {ncols:,} cells of {cell_m:g} m", option, hint=hint)


@dataclasses.dataclass(frozen=True)
class CloudFrame:
    """What a classification of part of a cloud (a tile's window) takes from the whole cloud: the origin of its
    grids (its lowest x, y; m), its mean point spacing (m, ``mean_spacing_m``: it sets cell sizes), its noise
    figures (the ground tolerances) and the ground filter's choice of refined surface."""

    x0_m: float
    y0_m: float
    spacing_m: float
    # The whole cloud's noise figures, for a tile (None: from the tile's own points): the robust spread (m) of the
    # ground filter's residuals from its refined surface (``ground.refine_tolerance_m``) and the ground's range
    # noise (m, ``classify.ground_noise_m``; the lifted-ground test and the rooftop-object rule). ``tiles.cloud_noise`` gives them.
    refine_sigma_m: float | None = None
    ground_noise_m: float | None = None
    # Whether the ground filter's refinement takes the grid of mean ground heights rather than the TIN (the whole
    # cloud's ground points per occupied refinement cell against ``dense_points_per_cell``; ``tiles.cloud_noise``);
    # None: the points at hand decide (``ground.morphological_ground``).
    refine_dense: bool | None = None

    @classmethod
    def of_points(cls, x, y) -> CloudFrame:
        """The frame of a whole cloud (its points ``x``, ``y``, m)."""
        return cls(float(np.min(x)), float(np.min(y)), mean_spacing_m(x, y))

    def cell_corner(self, x_m: float, y_m: float, cell_m: float) -> tuple[float, float]:
        """The lower-left corner (m) of the cell of the frame's grid of ``cell_m`` cells holding (x_m, y_m)."""
        def corner(v, v0):
            c = v0 + math.floor((v - v0) / cell_m) * cell_m
            return c - cell_m if c > v else c   # (rounding: the point stays in its cell's row / column)
        return corner(x_m, self.x0_m), corner(y_m, self.y0_m)


_WHOLE_CLOUD: contextvars.ContextVar[CloudFrame | None] = contextvars.ContextVar("whole_cloud", default=None)


@contextlib.contextmanager
def whole_cloud(frame: CloudFrame | None):
    """Within this block, grids over points anchor on ``frame``'s cells and ``cloud_spacing_m`` is its spacing
    (None: each set of points its own, as outside)."""
    token = _WHOLE_CLOUD.set(frame)
    try:
        yield frame
    finally:
        _WHOLE_CLOUD.reset(token)


def whole_cloud_frame() -> CloudFrame | None:
    """The frame of the ``whole_cloud`` block this runs in (None: outside one)."""
    return _WHOLE_CLOUD.get()


def origin(x, y, cell_m: float) -> tuple[float, float]:
    """The origin (m) of a grid of ``cell_m`` cells over points ``x``, ``y``: their lowest x, y, or within
    ``whole_cloud`` the corner of the whole cloud's cell holding it."""
    x0, y0 = float(np.min(x)), float(np.min(y))
    frame = _WHOLE_CLOUD.get()
    return (x0, y0) if frame is None else frame.cell_corner(x0, y0, float(cell_m))


def lattice_offset(x0: float, y0: float, cell_m: float) -> tuple[int, int]:
    """(row, col) of a grid's first cell (origin ``x0``, ``y0``, m; from ``origin``) on the whole cloud's grid of
    ``cell_m`` cells within ``whole_cloud`` ((0, 0) outside one): where its pyramids' blocks start
    (``raster_ops.fill_nodata``)."""
    frame = _WHOLE_CLOUD.get()
    if frame is None:
        return 0, 0
    return round((y0 - frame.y0_m) / cell_m), round((x0 - frame.x0_m) / cell_m)


def cloud_spacing_m(x, y) -> float:
    """The mean point spacing (m) of the points ``x``, ``y`` (``mean_spacing_m``), or within ``whole_cloud`` of
    the whole cloud."""
    frame = _WHOLE_CLOUD.get()
    return mean_spacing_m(x, y) if frame is None else frame.spacing_m


@numba.njit(cache=True, parallel=True)
def _floor_div(v, v0, cell_m):
    out = np.empty(len(v), np.int64)
    for k in numba.prange(len(v)):
        out[k] = int(np.floor((v[k] - v0) / cell_m))
    return out


@numba.njit(cache=True, parallel=True)
def _flat_ids(i, j, ncols):
    out = np.empty(len(i), np.int64)
    for k in numba.prange(len(i)):
        out[k] = i[k] * ncols + j[k]
    return out


def cell_indices(x, y, cell_m: float, x0: float | None = None, y0: float | None = None):
    """Return (i, j, nrows, ncols, x0, y0) for points (x, y) in a grid of ``cell_m`` cells (origin x0, y0;
    None: ``origin``)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if x0 is None or y0 is None:
        ox, oy = origin(x, y, cell_m)
        x0 = ox if x0 is None else x0
        y0 = oy if y0 is None else y0
    j = _floor_div(x, x0, float(cell_m))
    i = _floor_div(y, y0, float(cell_m))
    nrows, ncols = int(i.max()) + 1, int(j.max()) + 1
    check_grid(nrows, ncols, cell_m, GRID_BYTES_PER_CELL, "the points' extent",
               hint="are strips far apart (different zones or CRSs) in one cloud?")
    return i, j, nrows, ncols, x0, y0


def cell_ids(x, y, cell_m: float, x0: float | None = None, y0: float | None = None):
    """Flat cell index i * ncols + j per point, and (nrows, ncols, x0, y0)."""
    i, j, nrows, ncols, x0, y0 = cell_indices(x, y, cell_m, x0, y0)
    return _flat_ids(i, j, ncols), nrows, ncols, x0, y0


@dataclasses.dataclass
class MinimaSegments:
    """Segments of cell minima (Sithole & Vosselman's segment connectivity): the lowest point of each
    cell linked to those within 2.5 cells when their height difference is at most ``step + slope * d``."""

    cid: np.ndarray  # (n,) flat cell index of every point
    nrows: int
    ncols: int
    lowest: np.ndarray  # (m,) the lowest point of each occupied cell
    label: np.ndarray  # (m,) segment of each cell minimum
    size: np.ndarray  # (n_segments,) cells per segment
    ua: np.ndarray  # unlinked neighbour pairs (indices into ``lowest``) in different segments
    ub: np.ndarray
    dz: np.ndarray  # height of ub above ua (m)


@numba.njit(cache=True)
def _pairs_within(mx, my, mcell, shape, reach_cells, r2):
    """Pairs (a, b), a < b, of cell minima (one per cell, sorted by cell ``mcell`` of a grid of ``shape``
    (nrows, ncols)) whose squared horizontal distance is at most ``r2``; only cells within ``reach_cells``
    rows/columns can hold such a pair. The half-window (later cells) gives each pair once, with a < b."""
    nrows, ncols = shape
    m = len(mx)
    at = np.full(nrows * ncols, -1, np.int64)
    for k in range(m):
        at[mcell[k]] = k
    count = 0
    for pass_ in range(2):
        if pass_ == 1:
            a_out = np.empty(count, np.int64)
            b_out = np.empty(count, np.int64)
            count = 0
        for a in range(m):
            ci = mcell[a] // ncols
            cj = mcell[a] - ci * ncols
            for di in range(0, reach_cells + 1):
                ii = ci + di
                if ii >= nrows:
                    break
                j_lo = cj + 1 if di == 0 else max(cj - reach_cells, 0)
                j_hi = min(cj + reach_cells, ncols - 1)
                for jj in range(j_lo, j_hi + 1):
                    b = at[ii * ncols + jj]
                    if b < 0:
                        continue
                    dx = mx[a] - mx[b]
                    dy = my[a] - my[b]
                    if dx * dx + dy * dy <= r2:
                        if pass_ == 1:
                            a_out[count] = a
                            b_out[count] = b
                        count += 1
    return a_out, b_out


@numba.njit(cache=True)
def _link_pairs(minima, a, b, step_m, slope):
    """Height of b above a per pair of ``minima`` (mx, my, mz), and whether they link
    (``|dz| <= step_m + slope * d``)."""
    mx, my, mz = minima
    dz = np.empty(len(a))
    linked = np.empty(len(a), np.bool_)
    for e in range(len(a)):
        d = np.hypot(mx[a[e]] - mx[b[e]], my[a[e]] - my[b[e]])
        dz[e] = mz[b[e]] - mz[a[e]]
        linked[e] = np.abs(dz[e]) <= step_m + slope * d
    return dz, linked


@numba.njit(cache=True)
def _find(parent, k):
    root = k
    while parent[root] != root:
        root = parent[root]
    while parent[k] != root:       # path compression
        nxt = parent[k]
        parent[k] = root
        k = nxt
    return root


@numba.njit(cache=True)
def _components(m, a, b):
    """Connected components of the undirected graph (m nodes, edges a-b) by union-find, labelled
    0, 1, ... in the order of each component's lowest node (the labels of scipy's
    ``connected_components``)."""
    parent = np.arange(m)
    for e in range(len(a)):
        ra, rb = _find(parent, a[e]), _find(parent, b[e])
        if ra != rb:
            if ra < rb:
                parent[rb] = ra
            else:
                parent[ra] = rb
    label = np.empty(m, np.int64)
    of_root = np.full(m, -1, np.int64)
    n = 0
    for k in range(m):
        r = _find(parent, k)
        if of_root[r] < 0:
            of_root[r] = n
            n += 1
        label[k] = of_root[r]
    return n, label


def segment_cell_minima(x, y, z, cell_m: float, step_m: float, slope: float) -> MinimaSegments | None:
    """The cell minima linked into segments; None when no two minima are within 2.5 cells.

    Neighbour pairs come from the grid itself (one minimum per cell, so two within 2.5 cells lie at
    most 3 rows/columns apart), the same pairs as a KD-tree's ``query_pairs`` without building one."""
    cid, nrows, ncols, _, _ = cell_ids(x, y, cell_m)
    lowest = lowest_per_cell(cid, z)
    mx, my, mz = x[lowest], y[lowest], z[lowest]
    radius = 2.5 * cell_m
    a, b = _pairs_within(np.asarray(mx, float), np.asarray(my, float), cid[lowest], (nrows, ncols),
                         int(np.ceil(radius / cell_m)), radius * radius)
    if len(a) == 0:
        return None
    dz, linked = _link_pairs((np.asarray(mx, float), np.asarray(my, float), np.asarray(mz, float)), a, b,
                             float(step_m), float(slope))
    m = len(mx)
    ncomp, label = _components(m, a[linked], b[linked])
    size = np.bincount(label, minlength=ncomp)
    ua, ub, dzu = a[~linked], b[~linked], dz[~linked]
    cross = label[ua] != label[ub]
    return MinimaSegments(cid, nrows, ncols, lowest, label, size, ua[cross], ub[cross], dzu[cross])


@numba.njit(cache=True)
def _occupied_cells(x, y, cell_m):
    """Number of ``cell_m`` cells (anchored at the minima, as ``cell_ids``) holding points."""
    x0, y0 = np.min(x), np.min(y)
    ncols = int(np.floor((np.max(x) - x0) / cell_m)) + 1
    nrows = int(np.floor((np.max(y) - y0) / cell_m)) + 1
    seen = np.zeros(nrows * ncols, np.bool_)
    n = 0
    for k in range(len(x)):
        c = int(np.floor((y[k] - y0) / cell_m)) * ncols + int(np.floor((x[k] - x0) / cell_m))
        if not seen[c]:
            seen[c] = True
            n += 1
    return n, nrows, ncols


def mean_spacing_m(x, y, cell_m: float = 10.0) -> float:
    """Mean point spacing sqrt(area/n), area = occupied 10 m cells (ignores empty corners of a tile)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    # the grid's size first (as cell_ids checks it), then one pass marking the occupied cells
    nrows = int(np.floor((np.max(y) - np.min(y)) / cell_m)) + 1
    ncols = int(np.floor((np.max(x) - np.min(x)) / cell_m)) + 1
    check_grid(nrows, ncols, cell_m, GRID_BYTES_PER_CELL, "the points' extent",
               hint="are strips far apart (different zones or CRSs) in one cloud?")
    occupied = _occupied_cells(x, y, float(cell_m))[0]
    return float(np.sqrt(occupied * cell_m * cell_m / max(len(x), 1)))


@numba.njit(cache=True)
def _counting_sort(cell_id, ncells):
    count = np.zeros(ncells + 1, np.int64)
    for c in cell_id:
        count[c + 1] += 1
    start = np.cumsum(count)
    pos = start[:-1].copy()
    order = np.empty(len(cell_id), np.int64)
    for k in range(len(cell_id)):
        c = cell_id[k]
        order[pos[c]] = k
        pos[c] += 1
    return order, start


def cell_order(cell_id: np.ndarray, ncells: int):
    """(order, cell_start): the stable permutation sorting points by cell (``np.argsort(cell_id, kind="stable")``)
    and each cell's first position in it (``ncells + 1`` entries), by one counting sort, O(n + ncells)."""
    return _counting_sort(np.asarray(cell_id, np.int64), int(ncells))


@numba.njit(cache=True)
def _sort_segments(order, start, key):
    for c in range(len(start) - 1):
        a, b = start[c], start[c + 1]
        if b - a > 1:
            seg = order[a:b]
            order[a:b] = seg[np.argsort(key[seg], kind="mergesort")]
    return order


def cell_z_order(cell_id: np.ndarray, z: np.ndarray, descending: bool = False, ncells: int | None = None):
    """Permutation sorting points by cell (counting sort, O(n)), then by z within each cell.

    Returns (order, cell_start): points of cell c are order[cell_start[c]:cell_start[c + 1]].
    """
    cell_id = np.asarray(cell_id, np.int64)
    ncells = int(cell_id.max()) + 1 if ncells is None else ncells
    order, start = _counting_sort(cell_id, ncells)
    key = -np.asarray(z, float) if descending else np.asarray(z, float)
    return _sort_segments(order, start, key), start


@numba.njit(cache=True)
def _argmin_per_cell(cell_id, z, ncells):
    best = np.full(ncells, -1, np.int64)
    for k in range(len(cell_id)):
        c = cell_id[k]
        if best[c] < 0 or z[k] < z[best[c]]:
            best[c] = k
    return best


def lowest_per_cell(cell_id: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Indices of the lowest point in each occupied cell, ordered by cell id (one O(n) pass)."""
    cell_id = np.asarray(cell_id, np.int64)
    best = _argmin_per_cell(cell_id, np.asarray(z, float), int(cell_id.max()) + 1)
    return best[best >= 0]


def neighbour_lookup(ucells: np.ndarray, query_cells: np.ndarray) -> np.ndarray:
    """Position of each ``query_cells`` id in sorted ``ucells``, or -1 when that cell is empty."""
    pos = np.searchsorted(ucells, query_cells)
    pos = np.clip(pos, 0, len(ucells) - 1)
    found = ucells[pos] == query_cells
    return np.where(found, pos, -1)
