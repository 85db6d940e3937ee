"""Delaunay triangulation of the DEM's ground cells for the TIN gap fill (``raster_ops.fill_nodata_tin``).

Bowyer-Watson insertion in numba: the points (distinct cell centres with a fixed sub-cell jitter) are
added in rounds of growing size, each round along a Hilbert curve through the cells (``_insertion_keys``);
each point's cavity (the triangles whose circumcircle holds it; "ghost" triangles with an infinite
vertex stand for the outside of the hull) is found by a walk from the previous point's triangles and
refilled with a fan. About 0.4 CPU-us per point on the demo's ground cells (4.3 M points in 1.8 s)
against about 7 us for Qhull (``scipy.spatial.Delaunay``, which the fill used before).

The Delaunay triangulation of points in general position is unique, so these are Qhull's triangles
wherever Qhull is exact. The orientation and in-circle tests are exact: Shewchuk's error bound decides
in doubles, and the few tests too close to call are evaluated in Python integers. That matters here:
the jitter is affine along the grid's first row and first column, so the points there are collinear
to the last bit. Qhull, whose tests have a tolerance, merges near-cocircular cells and splits them
arbitrarily: in the demo's four tile windows 14 of its 9.55 M triangles are not Delaunay (an opposite
vertex inside the circumcircle, by exact test), and 4 DEM cells under them differ from this fill by up
to 0.044 m.

Triangles: vertex indices in ``tri[3t], tri[3t+1], tri[3t+2]``, counter-clockwise; halfedge ``e``
runs from ``tri[e]`` to the next vertex of its triangle, ``half[e]`` is the opposite halfedge.

A triangulation can be grown (``_new_mesh``, ``_bw_start``, ``_bw_insert``: points added later to the same
mesh) and queried (``_locate_cells``, ``_conflicts_near``): the TIN fill of a tile triangulates the cells near
the ones it needs and adds the farther ones only where they change those (``raster_ops._certified_tin``).
"""

from __future__ import annotations

import numba
import numpy as np

OK, COLLINEAR, UNDECIDED = 0, 1, 2
_MAX_CAVITY = 1 << 16
_INF, _NT, _LAST, _STAMP = 0, 1, 2, 3              # a mesh's state: infinite vertex, triangles, last, stamp
_EPS = 1.1102230246251565e-16                     # 2^-53
_CCW_BOUND = (3.0 + 16.0 * _EPS) * _EPS           # Shewchuk's ccwerrboundA
_ICC_BOUND = (10.0 + 96.0 * _EPS) * _EPS          # iccerrboundA


# Exact predicates, for the tests too close to call in doubles (the jitter of the lattice is affine
# along the grid's first row and column, so points there are collinear to the last bit): doubles are
# dyadic rationals, so the determinants are evaluated exactly in Python integers on a common
# denominator. Rare (a few per thousand points on the grid's edge rows), so numba leaves them to the
# interpreter (object mode) instead of compiling expansion arithmetic (13 s of compilation).
def _as_integers(*values):
    ratios = [float(v).as_integer_ratio() for v in values]
    den = max(d for _, d in ratios)
    return [n * (den // d) for n, d in ratios]


def _sign(v: int) -> int:
    return (v > 0) - (v < 0)


def _orient_exact_py(ax, ay, bx, by, cx, cy) -> int:
    ax, ay, bx, by, cx, cy = _as_integers(ax, ay, bx, by, cx, cy)
    return _sign((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))


def _incircle_exact_py(a, b, c, d) -> int:
    ax, ay, bx, by, cx, cy, dx, dy = _as_integers(*a, *b, *c, *d)
    adx, ady, bdx, bdy, cdx, cdy = ax - dx, ay - dy, bx - dx, by - dy, cx - dx, cy - dy
    return _sign((adx * adx + ady * ady) * (bdx * cdy - cdx * bdy) + (bdx * bdx + bdy * bdy) * (cdx * ady - adx * cdy)
                 + (cdx * cdx + cdy * cdy) * (adx * bdy - bdx * ady))


@numba.njit(cache=True)
def _orient_exact(ax, ay, bx, by, cx, cy):
    with numba.objmode(s="int64"):
        s = _orient_exact_py(ax, ay, bx, by, cx, cy)
    return s


@numba.njit(cache=True)
def _incircle_exact(a, b, c, d):
    with numba.objmode(s="int64"):
        s = _incircle_exact_py(a, b, c, d)
    return s


@numba.njit(cache=True)
def _orient(ax, ay, bx, by, cx, cy):
    """Sign of the turn a -> b -> c: 1 counter-clockwise, -1 clockwise, 0 collinear (exact)."""
    left = (bx - ax) * (cy - ay)
    right = (by - ay) * (cx - ax)
    det = left - right
    if abs(det) > _CCW_BOUND * (abs(left) + abs(right)):
        return 1 if det > 0.0 else -1
    return _orient_exact(ax, ay, bx, by, cx, cy)


@numba.njit(cache=True)
def _incircle(a, b, c, d):
    """1 when d lies inside the circle through the counter-clockwise a, b, c, -1 outside, 0 on it (exact);
    points are (x, y) tuples."""
    ax, ay = a
    bx, by = b
    cx, cy = c
    dx, dy = d
    adx, ady, bdx, bdy, cdx, cdy = ax - dx, ay - dy, bx - dx, by - dy, cx - dx, cy - dy
    bdxcdy, cdxbdy = bdx * cdy, cdx * bdy
    cdxady, adxcdy = cdx * ady, adx * cdy
    adxbdy, bdxady = adx * bdy, bdx * ady
    alift, blift, clift = adx * adx + ady * ady, bdx * bdx + bdy * bdy, cdx * cdx + cdy * cdy
    det = alift * (bdxcdy - cdxbdy) + blift * (cdxady - adxcdy) + clift * (adxbdy - bdxady)
    perm = ((abs(bdxcdy) + abs(cdxbdy)) * alift + (abs(cdxady) + abs(adxcdy)) * blift
            + (abs(adxbdy) + abs(bdxady)) * clift)
    if abs(det) > _ICC_BOUND * perm:
        return 1 if det > 0.0 else -1
    return _incircle_exact(a, b, c, d)


def _hilbert_table(levels: int) -> np.ndarray:
    """Hilbert index digits of ``levels`` levels at once: entry [state, x bits, y bits] = (digits << 2) | next
    state, a state being (swapped << 1) | complemented, the transformation of the remaining lower bits that the
    levels above left (``_insertion_keys``'s rotations, composed: they commute)."""
    table = np.zeros((4, 1 << levels, 1 << levels), np.int64)
    for state in range(4):
        for xb in range(1 << levels):
            for yb in range(1 << levels):
                sw, cp, d = state >> 1, state & 1, 0
                for lev in range(levels - 1, -1, -1):
                    x, y = (xb >> lev) & 1, (yb >> lev) & 1
                    if sw:
                        x, y = y, x
                    if cp:
                        x, y = 1 - x, 1 - y
                    d = (d << 2) | ((3 * x) ^ y)
                    if y == 0:
                        if x == 1:
                            cp ^= 1
                        sw ^= 1
                table[state, xb, yb] = (d << 2) | (sw << 1) | cp
    return table


_HILBERT_LEVELS = 4
_HILBERT = _hilbert_table(_HILBERT_LEVELS)


@numba.njit(cache=True, nogil=True)
def _insertion_keys(ix, iy, order_bits):
    """Sort keys of an insertion order (BRIO, Amenta et al. 2003): each point goes into a round by a
    hash of its cell (round k holds about 7/8 of the points of round k + 1), rounds are inserted from
    the smallest, and within a round along a Hilbert curve through the cells (``ix``, ``iy``:
    non-negative integers < 2^order_bits). Hilbert order alone leaves long slivers along the frontier
    of the inserted part, and each point's cavity holds twice as many triangles. Keys below
    2^(2 order_bits + 5). The Hilbert index is Wikipedia's ``xy2d`` on a square of 2^order_bits cells,
    four levels at a time (``_HILBERT``; the same keys): a square padded by p levels starts with p swaps."""
    n = len(ix)
    keys = np.empty(n, np.int64)
    lv = _HILBERT_LEVELS
    pad = (-order_bits) % lv
    mask = (1 << lv) - 1
    for k in range(n):
        x, y = np.int64(ix[k]), np.int64(iy[k])
        state = (pad & 1) << 1
        d = np.int64(0)
        for shift in range(order_bits + pad - lv, -1, -lv):
            e = _HILBERT[state, (x >> shift) & mask, (y >> shift) & mask]
            d = (d << (2 * lv)) | (e >> 2)
            state = e & 3
        h = (np.uint64(ix[k]) * np.uint64(0x9E3779B97F4A7C15)) ^ (np.uint64(iy[k]) * np.uint64(0xC2B2AE3D27D4EB4F))
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
        zeros = 0                                         # trailing zero bits: P(>= k) = 2^-k
        while zeros < 60 and (h & np.uint64(1)) == np.uint64(0):
            zeros += 1
            h >>= np.uint64(1)
        keys[k] = (np.int64(20 - min(zeros // 3, 20)) << (2 * order_bits)) | d
    return keys


@numba.njit(cache=True, nogil=True)
def _argsort_keys(keys, key_bits):
    """The permutation that sorts non-negative ``keys`` below 2^key_bits (``np.argsort``'s, as int32, for
    distinct keys; stable otherwise): least significant digit radix sort, digits of at most 11 bits (a
    histogram of 2048 counters stays in the L1 cache). Several times faster than numpy's comparison sort
    on the fill's millions of keys. ``keys`` is the work space: overwritten."""
    n = len(keys)
    passes = max((key_bits + 10) // 11, 1)
    width = (key_bits + passes - 1) // passes
    mask = (np.int64(1) << width) - 1
    order = np.arange(n).astype(np.int32)
    src_k = keys
    dst_k = np.empty(n, np.int64)
    dst_o = np.empty(n, np.int32)
    count = np.empty((1 << width) + 1, np.int64)
    for p in range(passes):
        shift = p * width
        count[:] = 0
        for k in range(n):
            count[((src_k[k] >> shift) & mask) + 1] += 1
        for b in range(1 << width):
            count[b + 1] += count[b]
        for k in range(n):
            b = (src_k[k] >> shift) & mask
            j = count[b]
            count[b] = j + 1
            dst_k[j] = src_k[k]
            dst_o[j] = order[k]
        src_k, dst_k = dst_k, src_k
        order, dst_o = dst_o, order
    return order


@numba.njit(cache=True)
def _between(ax, ay, bx, by, x, y):
    """A point collinear with a and b lies strictly between them."""
    if ax != bx:
        return min(ax, bx) < x < max(ax, bx)
    return min(ay, by) < y < max(ay, by)


@numba.njit(cache=True)
def _ghost_last(a, b, c, inf):
    """The vertices of a triangle rotated so that the infinite one (if any) comes last."""
    if a == inf:
        return b, c, a
    if b == inf:
        return c, a, b
    return a, b, c


@numba.njit(cache=True)
def _conflict(tri, inf, pa, pb, pc, p):
    """The point ``p`` lies inside the circumcircle of the triangle ``tri`` (a, b, c) (rotated by
    ``_ghost_last``; its vertices at ``pa``, ``pb``, ``pc``); for a ghost triangle (a, b, inf) over the hull
    edge b -> a: strictly outside that edge, or on it. Points are (x, y) tuples. Scalars only: numba counts
    references to arrays passed to a function."""
    c = tri[2]
    ax, ay = pa
    bx, by = pb
    x, y = p
    if c == inf:
        o = _orient(ax, ay, bx, by, x, y)
        if o != 0:
            return o > 0
        return _between(ax, ay, bx, by, x, y)
    return _incircle(pa, pb, pc, p) > 0


@numba.njit(cache=True, nogil=True)
def _locate(px, py, tri, half, inf, t, x, y, max_steps):
    """The triangle that holds the point (x, y), by a walk from the real triangle ``t``: a real triangle (the
    point inside or on its boundary) or the first ghost crossed (the point strictly outside that hull edge);
    -1 when the walk does not end (cannot happen with exact predicates)."""
    for _ in range(max_steps):
        if tri[3 * t] == inf or tri[3 * t + 1] == inf or tri[3 * t + 2] == inf:
            return t                                    # crossed the hull: this ghost is in conflict
        moved = False
        for k in range(3):
            e = 3 * t + k
            a, b = tri[e], tri[3 * t + (k + 1) % 3]
            if _orient(px[a], py[a], px[b], py[b], x, y) < 0:
                t = half[e] // 3
                moved = True
                break
        if not moved:
            return t
    return -1


@numba.njit(cache=True, nogil=True)
def _bw_start(px, py, seq, mesh):
    """The first triangle of a Bowyer-Watson triangulation of the points ``seq`` (indices into ``px``, ``py``):
    its first two points and the first one off their line, and its three ghosts. Returns the position in
    ``seq`` of that third point, -1 when all points are collinear. ``mesh``: (tri, half, mark, first, state)
    of ``_new_mesh``."""
    tri, half, _, _, state = mesh
    inf = state[_INF]
    k0 = -1
    for k in range(2, len(seq)):
        if _orient(px[seq[0]], py[seq[0]], px[seq[1]], py[seq[1]], px[seq[k]], py[seq[k]]) != 0:
            k0 = k
            break
    if k0 < 0:
        return -1
    a0, b0, c0 = seq[0], seq[1], seq[k0]
    if _orient(px[a0], py[a0], px[b0], py[b0], px[c0], py[c0]) < 0:
        a0, b0 = b0, a0
    # real triangle 0 and its three ghosts over the edges b0->a0, c0->b0, a0->c0
    tri[0], tri[1], tri[2] = a0, b0, c0
    tri[3], tri[4], tri[5] = b0, a0, inf
    tri[6], tri[7], tri[8] = c0, b0, inf
    tri[9], tri[10], tri[11] = a0, c0, inf
    half[0], half[3] = 3, 0
    half[1], half[6] = 6, 1
    half[2], half[9] = 9, 2
    half[4], half[11] = 11, 4          # a0 -> inf  /  inf -> a0
    half[5], half[7] = 7, 5            # inf -> b0  /  b0 -> inf
    half[8], half[10] = 10, 8          # inf -> c0  /  c0 -> inf
    state[_NT] = 4
    state[_LAST] = 0
    return k0


@numba.njit(cache=True, nogil=True)
def _new_mesh(n):
    """Arrays of a triangulation of up to ``n`` points: (tri, half, mark, first, state), ``state``:
    the infinite vertex's index (n), the number of triangles, the last real triangle made, the cavity stamp."""
    max_tri = 2 * n + 2
    state = np.zeros(4, np.int64)
    state[_INF] = n
    return (np.empty(3 * max_tri, np.int32), np.empty(3 * max_tri, np.int32), np.zeros(max_tri, np.int32),
            np.empty(n + 1, np.int32), state)


@numba.njit(cache=True, nogil=True)
def _bw_insert(px, py, seq, mesh):
    """Insert the points ``seq`` (indices into ``px``, ``py``; a spatially coherent order) into the
    triangulation ``mesh`` (``_bw_start``): each point's cavity (the triangles whose circumcircle holds it;
    ghost triangles with an infinite vertex stand for the outside of the hull) is found by a walk from the
    last point's triangles and refilled by a fan. Returns OK or UNDECIDED."""
    tri, half, mark, first, state = mesh
    inf = state[_INF]
    n = len(first) - 1
    max_tri = len(mark)
    nt, last, stamp = state[_NT], state[_LAST], state[_STAMP]
    # fixed buffers (arrays that could be reallocated would cost reference counting on every access)
    cap = min(max_tri, _MAX_CAVITY)
    cavity = np.empty(cap, np.int32)
    bound = np.empty(cap + 2, np.int32)
    ba = np.empty(cap + 2, np.int32)
    bb = np.empty(cap + 2, np.int32)
    bo = np.empty(cap + 2, np.int32)
    status = OK
    for q in range(len(seq)):
        p = seq[q]
        x, y = px[p], py[p]
        stamp += 1
        t = _locate(px, py, tri, half, inf, last, x, y, 4 * n + 8)
        if t < 0:
            status = UNDECIDED
            break
        a, b, c = _ghost_last(tri[3 * t], tri[3 * t + 1], tri[3 * t + 2], inf)
        cc = c if c != inf else a
        if not _conflict((a, b, c), inf, (px[a], py[a]), (px[b], py[b]), (px[cc], py[cc]), (x, y)):
            status = UNDECIDED
            break
        # the cavity: triangles in conflict, connected to t
        nc, nb = 0, 0
        cavity[nc] = t
        nc += 1
        mark[t] = stamp
        head = 0
        while head < nc:
            t = cavity[head]
            head += 1
            for k in range(3):
                e = 3 * t + k
                o = half[e]
                u = o // 3
                if mark[u] == stamp:
                    continue
                in_conflict = False
                if mark[u] != -stamp:
                    a, b, c = _ghost_last(tri[3 * u], tri[3 * u + 1], tri[3 * u + 2], inf)
                    cc = c if c != inf else a
                    in_conflict = _conflict((a, b, c), inf, (px[a], py[a]), (px[b], py[b]), (px[cc], py[cc]), (x, y))
                if in_conflict:
                    mark[u] = stamp
                    if nc == cap:
                        status = UNDECIDED              # a cavity of 2^16 triangles: not a lattice
                        break
                    cavity[nc] = u
                    nc += 1
                else:
                    mark[u] = -stamp
                    if nb == cap + 2:
                        status = UNDECIDED
                        break
                    ba[nb] = tri[e]
                    bb[nb] = tri[3 * t + (k + 1) % 3]
                    bo[nb] = o
                    nb += 1
            if status != OK:
                break
        if status != OK:
            break
        if nb != nc + 2 or nt + 2 > max_tri:
            status = UNDECIDED                         # not a disc: cannot happen with exact predicates
            break
        # refill: a triangle (a, b, p) on every boundary edge a -> b, in the cavity's slots and two new ones
        for j in range(nb):
            s = cavity[j] if j < nc else nt + (j - nc)
            bound[j] = s
            a, b = ba[j], bb[j]
            e = 3 * s
            tri[e], tri[e + 1], tri[e + 2] = a, b, p
            half[e] = bo[j]
            half[bo[j]] = e
            first[a] = s
            if a != inf and b != inf:
                last = s
        nt += 2
        for j in range(nb):
            s = bound[j]
            s2 = first[bb[j]]
            half[3 * s + 1] = 3 * s2 + 2
            half[3 * s2 + 2] = 3 * s + 1
    state[_NT], state[_LAST], state[_STAMP] = nt, last, stamp
    return status


@numba.njit(cache=True, nogil=True)
def _bw_triangles(mesh, index):
    """The real triangles of ``mesh`` (m, 3) int32 as ``index`` of their vertices, in slot order."""
    tri, _, _, _, state = mesh
    inf, nt = state[_INF], state[_NT]
    m = 0
    for t in range(nt):
        if tri[3 * t] != inf and tri[3 * t + 1] != inf and tri[3 * t + 2] != inf:
            m += 1
    out = np.empty((m, 3), np.int32)
    m = 0
    for t in range(nt):
        if tri[3 * t] != inf and tri[3 * t + 1] != inf and tri[3 * t + 2] != inf:
            out[m, 0], out[m, 1], out[m, 2] = index[tri[3 * t]], index[tri[3 * t + 1]], index[tri[3 * t + 2]]
            m += 1
    return out


@numba.njit(cache=True, nogil=True)
def _bowyer_watson(px, py, index):
    """Delaunay triangulation of points given in a spatially coherent order (``_insertion_keys``).
    Returns (triangles (m, 3) int32 counter-clockwise as ``index`` of the vertices, status)."""
    n = len(px)
    empty = np.empty((0, 3), np.int32)
    seq = np.arange(n).astype(np.int32)
    mesh = _new_mesh(n)
    k0 = _bw_start(px, py, seq, mesh)
    if k0 < 0:
        return empty, COLLINEAR
    rest = np.concatenate((seq[2:k0], seq[k0 + 1:]))
    if _bw_insert(px, py, rest, mesh) != OK:
        return empty, UNDECIDED
    return _bw_triangles(mesh, index), OK


def delaunay_lattice(pts: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, int]:
    """Delaunay triangles (m, 3) int32 (indices into ``pts``) of points near the cells (``rows``,
    ``cols``, integers) of a grid, and a status (OK, COLLINEAR: no triangle, UNDECIDED: a failure
    that exact predicates rule out; use another method)."""
    pts = np.asarray(pts, float)
    if len(pts) < 3:
        return np.empty((0, 3), np.int32), COLLINEAR
    r = np.asarray(rows, np.int64) - int(np.min(rows))
    c = np.asarray(cols, np.int64) - int(np.min(cols))
    bits = max(int(max(r.max(), c.max())).bit_length(), 1)
    if bits > 21:
        raise ValueError(f"a grid of {r.max() + 1} x {c.max() + 1} cells: too large for one triangulation")
    order = _argsort_keys(_insertion_keys(c, r, bits), 2 * bits + 5)       # 2^5 > the 21 rounds
    return _bowyer_watson(np.ascontiguousarray(pts[order, 0]), np.ascontiguousarray(pts[order, 1]), order)


@numba.njit(cache=True, nogil=True)
def _circle(ax, ay, bx, by, cx, cy):
    """Centre and radius of the circle through three points (radius inf when they are collinear in doubles)."""
    e1x, e1y, e2x, e2y = bx - ax, by - ay, cx - ax, cy - ay
    det = 2.0 * (e1x * e2y - e1y * e2x)
    if det == 0.0:
        return ax, ay, np.inf
    b2, c2 = e1x * e1x + e1y * e1y, e2x * e2x + e2y * e2y
    ux, uy = (e2y * b2 - e1y * c2) / det, (e1x * c2 - e2x * b2) / det
    return ax + ux, ay + uy, np.hypot(ux, uy)


@numba.njit(cache=True, nogil=True)
def _any_in_box(sat, block, i0, i1, j0, j1):
    """Some point counted in the summed-area table ``sat`` of blocks of ``block`` cells may lie in the
    cells i0..i1, j0..j1 (inclusive, window indices)."""
    b0, b1, c0, c1 = i0 // block, i1 // block + 1, j0 // block, j1 // block + 1
    return sat[b1, c1] - sat[b0, c1] - sat[b1, c0] + sat[b0, c0] > 0


@numba.njit(cache=True, nogil=True)
def _locate_cells(px, py, mesh, cells, cell_tri):
    """The triangle of each cell centre ``cells`` (k, 2) global (row, col), a coherent order, into
    ``cell_tri`` (``_locate``: a ghost when the cell lies outside the hull), each walk from the previous
    cell's triangle (or the real triangle over its ghost's hull edge). False when a walk fails."""
    tri, half, _, first, state = mesh
    inf = state[_INF]
    n = len(first) - 1
    hint = state[_LAST]
    for k in range(len(cells)):
        t = _locate(px, py, tri, half, inf, hint, np.float64(cells[k, 1]), np.float64(cells[k, 0]), 4 * n + 8)
        if t < 0:
            return False
        cell_tri[k] = t
        hint = t
        for e in range(3):
            if tri[3 * t + e] == inf:
                hint = half[3 * t + (e + 1) % 3] // 3
                break
    return True


@numba.njit(cache=True, nogil=True)
def _conflicts_near(px, py, mesh, tris, boxes, grid, reach, out):
    """One round of the certification of a partial triangulation: the points not yet inserted that could
    change the triangles ``tris`` of some cells, those in ``boxes`` (row_lo, row_hi, col_lo, col_hi: the
    bounding box of the cells of each, global cell centres). ``grid``: (point_at, inserted, origin, inner,
    sat, block): ``point_at`` the index in ``px``, ``py`` of the point not in the first triangulation at
    each cell of a window whose first cell is ``origin`` (global (row, col)) (-1: none), ``inserted`` a flag
    per point (set here for those returned), ``inner`` the window's (row0, row1, col0, col1) triangulated
    first (no such point there), ``sat`` the summed-area table of those points by blocks of ``block`` cells.
    A point qualifies when it lies within ``reach`` of the box and inside the circumcircle of the triangle
    (beyond or on the hull edge of a ghost triangle), with a margin for rounding (a point too many does no
    harm). Returns the number of points written to ``out``."""
    tri, _, _, _, state = mesh
    point_at, inserted, origin, inner, sat, block = grid
    row0, col0 = origin
    in_r0, in_r1, in_c0, in_c1 = inner
    inf = state[_INF]
    nrows, ncols = point_at.shape
    m = 0
    for g in range(len(tris)):
        t = tris[g]
        y_lo, y_hi, x_lo, x_hi = boxes[g, 0], boxes[g, 1], boxes[g, 2], boxes[g, 3]
        a, b, c = _ghost_last(tri[3 * t], tri[3 * t + 1], tri[3 * t + 2], inf)
        ghost = c == inf
        r_lo, r_hi, c_lo, c_hi = y_lo - reach, y_hi + reach, x_lo - reach, x_hi + reach
        rad = np.inf
        ccx, ccy = 0.0, 0.0
        if not ghost:
            ccx, ccy, rad = _circle(px[a], py[a], px[b], py[b], px[c], py[c])
            rad = rad * (1.0 + 1e-9) + 1e-6
            if np.isfinite(rad):
                r_lo, r_hi = max(r_lo, ccy - rad), min(r_hi, ccy + rad)
                c_lo, c_hi = max(c_lo, ccx - rad), min(c_hi, ccx + rad)
        i0 = max(int(np.floor(r_lo - 0.01)) - row0, 0)
        i1 = min(int(np.ceil(r_hi + 0.01)) - row0, nrows - 1)
        j0 = max(int(np.floor(c_lo - 0.01)) - col0, 0)
        j1 = min(int(np.ceil(c_hi + 0.01)) - col0, ncols - 1)
        if i0 > i1 or j0 > j1:
            continue
        if in_r0 <= i0 and i1 < in_r1 and in_c0 <= j0 and j1 < in_c1:
            continue                                   # all within the first triangulation
        if not _any_in_box(sat, block, i0, i1, j0, j1):
            continue
        for i in range(i0, i1 + 1):
            # the row's cells outside the inner region: one or two runs of columns
            for seg in range(2):
                if in_r0 <= i < in_r1:
                    s0, s1 = (j0, min(j1, in_c0 - 1)) if seg == 0 else (max(j0, in_c1), j1)
                elif seg == 0:
                    s0, s1 = j0, j1
                else:
                    break
                for j in range(s0, s1 + 1):
                    q = point_at[i, j]
                    if q < 0 or inserted[q]:
                        continue
                    x, y = px[q], py[q]
                    dx = max(x_lo - x, 0.0, x - x_hi)
                    dy = max(y_lo - y, 0.0, y - y_hi)
                    if dx * dx + dy * dy > (reach + 1e-6) ** 2:
                        continue
                    if ghost:
                        det = (px[b] - px[a]) * (y - py[a]) - (py[b] - py[a]) * (x - px[a])
                        if det < -1e-6:
                            continue
                    elif np.isfinite(rad) and (x - ccx) ** 2 + (y - ccy) ** 2 > rad * rad:
                        continue
                    inserted[q] = True
                    out[m] = q
                    m += 1
    return m
