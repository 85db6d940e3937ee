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
"""

from __future__ import annotations

import numba
import numpy as np

OK, COLLINEAR, UNDECIDED = 0, 1, 2
_MAX_CAVITY = 1 << 16
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


@numba.njit(cache=True, nogil=True)
def _insertion_keys(ix, iy, order_bits):
    """Sort keys of an insertion order (BRIO, Amenta et al. 2003): each point goes into a round by a
    hash of its cell (round k holds about 7/8 of the points of round k + 1), rounds are inserted from
    the smallest, and within a round along a Hilbert curve through the cells (``ix``, ``iy``:
    non-negative integers < 2^order_bits). Hilbert order alone leaves long slivers along the frontier
    of the inserted part, and each point's cavity holds twice as many triangles."""
    n = len(ix)
    keys = np.empty(n, np.int64)
    side = np.int64(1) << order_bits
    for k in range(n):
        x, y = np.int64(ix[k]), np.int64(iy[k])
        d = np.int64(0)
        s = side >> 1
        while s > 0:
            rx = 1 if (x & s) > 0 else 0
            ry = 1 if (y & s) > 0 else 0
            d += s * s * ((3 * rx) ^ ry)
            if ry == 0:                                   # rotate the quadrant
                if rx == 1:
                    x = side - 1 - x
                    y = side - 1 - y
                x, y = y, x
            s >>= 1
        h = (np.uint64(ix[k]) * np.uint64(0x9E3779B97F4A7C15)) ^ (np.uint64(iy[k]) * np.uint64(0xC2B2AE3D27D4EB4F))
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
        zeros = 0                                         # trailing zero bits: P(>= k) = 2^-k
        while zeros < 60 and (h & np.uint64(1)) == np.uint64(0):
            zeros += 1
            h >>= np.uint64(1)
        keys[k] = (np.int64(20 - min(zeros // 3, 20)) << 42) | d
    return keys


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
def _bowyer_watson(px, py, index):
    """Delaunay triangulation of points given in a spatially coherent order (``_insertion_keys``):
    each point's cavity (the triangles whose circumcircle holds it; ghost triangles with an infinite
    vertex stand for the outside of the hull) is found by a walk from the last point's triangles and
    refilled by a fan. Returns (triangles (m, 3) int32 counter-clockwise as ``index`` of the vertices,
    status)."""
    n = len(px)
    empty = np.empty((0, 3), np.int32)
    inf = n
    # the first triangle: the first two points and the first point off their line
    c0 = -1
    for k in range(2, n):
        if _orient(px[0], py[0], px[1], py[1], px[k], py[k]) != 0:
            c0 = k
            break
    if c0 < 0:
        return empty, COLLINEAR
    a0, b0 = 0, 1
    if _orient(px[a0], py[a0], px[b0], py[b0], px[c0], py[c0]) < 0:
        a0, b0 = b0, a0
    max_tri = 2 * n + 2
    tri = np.empty(3 * max_tri, np.int32)
    half = np.empty(3 * max_tri, np.int32)
    mark = np.zeros(max_tri, np.int32)
    first = np.empty(n + 1, np.int32)
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
    nt = 4
    # fixed buffers (arrays that could be reallocated would cost reference counting on every access)
    cap = min(max_tri, _MAX_CAVITY)
    cavity = np.empty(cap, np.int32)
    bound = np.empty(cap + 2, np.int32)
    ba = np.empty(cap + 2, np.int32)
    bb = np.empty(cap + 2, np.int32)
    bo = np.empty(cap + 2, np.int32)
    last = 0
    stamp = 0
    for p in range(2, n):
        if p == c0:
            continue
        x, y = px[p], py[p]
        stamp += 1
        # locate: walk from the last real triangle towards the point
        t = last
        for _ in range(4 * n + 8):
            if tri[3 * t] == inf or tri[3 * t + 1] == inf or tri[3 * t + 2] == inf:
                break                                   # crossed the hull: this ghost is in conflict
            moved = False
            for k in range(3):
                e = 3 * t + k
                a, b = tri[e], tri[3 * t + (k + 1) % 3]
                if _orient(px[a], py[a], px[b], py[b], x, y) < 0:
                    t = half[e] // 3
                    moved = True
                    break
            if not moved:
                break
        else:
            return empty, UNDECIDED
        a, b, c = _ghost_last(tri[3 * t], tri[3 * t + 1], tri[3 * t + 2], inf)
        cc = c if c != inf else a
        if not _conflict((a, b, c), inf, (px[a], py[a]), (px[b], py[b]), (px[cc], py[cc]), (x, y)):
            return empty, UNDECIDED
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
                        return empty, UNDECIDED         # a cavity of 2^16 triangles: not a lattice
                    cavity[nc] = u
                    nc += 1
                else:
                    mark[u] = -stamp
                    if nb == cap + 2:
                        return empty, UNDECIDED
                    ba[nb] = tri[e]
                    bb[nb] = tri[3 * t + (k + 1) % 3]
                    bo[nb] = o
                    nb += 1
        if nb != nc + 2:
            return empty, UNDECIDED                    # not a disc: cannot happen with exact predicates
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
    return out, OK


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
    order = np.argsort(_insertion_keys(c, r, bits)).astype(np.int32)
    return _bowyer_watson(np.ascontiguousarray(pts[order, 0]), np.ascontiguousarray(pts[order, 1]), order)
