"""lidarctl.raster_tin: the Delaunay triangulation of the TIN gap fill is a valid triangulation of the convex hull
whose every edge is Delaunay by exact predicates (hence the Delaunay triangulation), Qhull's on points in general
position, and handles the grid's first row and column, whose jitter makes their cells collinear to the last bit."""

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from lidarctl.raster_ops import _jittered_cells
from lidarctl.raster_tin import COLLINEAR, OK, _argsort_keys, _incircle, _insertion_keys, _orient, delaunay_lattice


def _check_delaunay(pts: np.ndarray, tri: np.ndarray) -> None:
    """Counter-clockwise triangles, two per interior edge, covering the hull (area), every interior edge
    locally Delaunay (exact in-circle test of the opposite vertex): then it is the Delaunay triangulation."""
    assert len(tri) and tri.min() >= 0 and tri.max() < len(pts)
    assert len(np.unique(tri)) == len(pts)                               # every point is a vertex
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    assert all(_orient(*a[k], *b[k], *c[k]) > 0 for k in range(len(tri)))
    area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    assert area.sum() == pytest.approx(ConvexHull(pts).volume, rel=1e-9)
    opposite = {}
    for t, (i, j, k) in enumerate(tri):
        for u, v, w in ((i, j, k), (j, k, i), (k, i, j)):
            assert (u, v) not in opposite                                # each directed edge once
            opposite[(u, v)] = w
    for (u, v), w in opposite.items():
        x = opposite.get((v, u))
        if x is not None:    # interior edge u-v between triangles (u, v, w) and (v, u, x)
            assert _incircle(tuple(pts[u]), tuple(pts[v]), tuple(pts[w]), tuple(pts[x])) <= 0


def _lattice(shape, density, seed, row0=0, col0=0):
    rng = np.random.default_rng(seed)
    r, c = np.nonzero(rng.random(shape) < density)
    r, c = r + row0, c + col0
    return _jittered_cells(r, c), r, c


@pytest.mark.parametrize("row0, col0", [(0, 0), (37, 1000)])
def test_lattice_triangulation_is_exactly_delaunay(row0, col0):
    # (0, 0): the grid's first row and column, collinear to the last bit, on the hull
    pts, r, c = _lattice((70, 90), 0.45, 1, row0, col0)
    tri, status = delaunay_lattice(pts, r, c)
    assert status == OK
    _check_delaunay(pts, tri)


def test_equals_qhull_in_general_position():
    rng = np.random.default_rng(5)
    pts = rng.random((3000, 2)) * 100
    cells = np.floor(pts).astype(np.int64)
    tri, status = delaunay_lattice(pts, cells[:, 1], cells[:, 0])
    assert status == OK

    def canon(s):
        s = np.sort(s, axis=1)
        return s[np.lexsort(s.T[::-1])]

    np.testing.assert_array_equal(canon(tri), canon(Delaunay(pts).simplices))


def test_degenerate_inputs():
    line = np.column_stack([np.arange(10.0), 2.0 * np.arange(10.0)])
    assert delaunay_lattice(line, np.arange(10), np.arange(10))[1] == COLLINEAR
    assert delaunay_lattice(line[:2], np.arange(2), np.arange(2))[1] == COLLINEAR
    three = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    tri, status = delaunay_lattice(three, np.array([0, 0, 1]), np.array([0, 1, 0]))
    assert status == OK and sorted(tri[0]) == [0, 1, 2]
    # a row of the grid's first row (collinear) and one point above it
    pts, r, c = _lattice((1, 40), 1.0, 0)
    pts = np.vstack([pts, _jittered_cells(np.array([3]), np.array([17]))])
    tri, status = delaunay_lattice(pts, np.append(r, 3), np.append(c, 17))
    assert status == OK
    _check_delaunay(pts, tri)


def test_tin_fill_only_near_the_needed_cells_is_the_same_there():
    from lidarctl.raster_ops import fill_nodata, fill_nodata_tin

    rng = np.random.default_rng(9)
    rows, cols = np.mgrid[0:150, 0:160]
    a = 300.0 + 0.2 * cols - 0.1 * rows + rng.normal(0, 0.3, rows.shape)
    gaps = rng.random(a.shape) < 0.5
    gaps[60:90, 70:100] = True                     # a building
    a[gaps] = np.nan
    r = 8
    whole = fill_nodata_tin(a, max_radius_px=r, offset=(5, 9))
    needed = (slice(50, 100), slice(60, 110))
    part = fill_nodata_tin(a, max_radius_px=r, offset=(5, 9), needed=needed)
    np.testing.assert_array_equal(part[needed], whole[needed])
    far = np.zeros_like(gaps)
    far[:10, :10] = True                           # beyond 2 r + 3 cells: the pull-push fill
    np.testing.assert_array_equal(part[far], fill_nodata(a)[far])
    assert not np.array_equal(whole[far & gaps], fill_nodata(a)[far & gaps])


def _fill_triangles_reference(filled, gaps, tin, max_radius_px, origin):
    """``raster_ops._fill_triangles`` as plain Python, every triangle's bounding box scanned."""
    pts, z, simplices = tin
    row0, col0 = origin
    done = np.zeros_like(gaps)
    for tri in simplices:
        i0, i1, i2 = sorted(int(i) for i in tri)
        (x0, y0), (x1, y1), (x2, y2) = pts[i0], pts[i1], pts[i2]
        e1x, e1y, e2x, e2y = x1 - x0, y1 - y0, x2 - x0, y2 - y0
        det = e1x * e2y - e1y * e2x
        radius = np.hypot(x1 - x2, y1 - y2) * np.hypot(e2x, e2y) * np.hypot(e1x, e1y) / max(2.0 * abs(det), 1e-12)
        for r in range(max(int(np.ceil(min(y0, y1, y2))) - row0, 0),
                       min(int(np.floor(max(y0, y1, y2))) - row0, gaps.shape[0] - 1) + 1):
            for c in range(max(int(np.ceil(min(x0, x1, x2))) - col0, 0),
                           min(int(np.floor(max(x0, x1, x2))) - col0, gaps.shape[1] - 1) + 1):
                if not gaps[r, c] or done[r, c] or radius > max_radius_px:
                    continue
                dx, dy = (c + col0) - x0, (r + row0) - y0
                l1, l2 = (dx * e2y - dy * e2x) / det, (e1x * dy - e1y * dx) / det
                if min(1.0 - l1 - l2, l1, l2) < -1e-12:
                    continue
                filled[r, c] = (1.0 - l1 - l2) * z[i0] + l1 * z[i1] + l2 * z[i2]
                done[r, c] = True


def test_fill_triangles_passing_over_2x2_triangles_fills_the_same():
    # _fill_triangles skips triangles of three cells of one 2 x 2 block (most of a dense lattice's)
    from lidarctl.raster_ops import _fill_triangles

    rng = np.random.default_rng(11)
    shape, row0, col0 = (60, 70), 40, 1000
    gaps = rng.random(shape) < 0.35
    gaps[20:35, 25:45] = True                                   # a building
    vr, vc = np.nonzero(~gaps)
    pts = _jittered_cells(vr + row0, vc + col0)
    z = rng.normal(100.0, 5.0, len(vr))
    tri, status = delaunay_lattice(pts, vr + row0, vc + col0)
    assert status == OK
    small = np.ptp(pts[tri], axis=1)
    assert ((small[:, 0] < 1.5) & (small[:, 1] < 1.5)).mean() > 0.3    # the case is exercised
    ours, ref = np.full(shape, -1.0), np.full(shape, -1.0)
    _fill_triangles(ours, gaps, (pts, z, tri), 6.0, (row0, col0))
    _fill_triangles_reference(ref, gaps, (pts, z, tri), 6.0, (row0, col0))
    assert (ref[gaps] != -1.0).mean() > 0.5                    # most gap cells filled by a triangle
    np.testing.assert_array_equal(ours, ref)


def test_tin_fill_of_the_needed_cells_certified_as_the_whole_triangulation(monkeypatch):
    # the needed cells' triangles come from the rim cells within TIN_INNER_MARGIN_PX of them, plus the farther
    # ones found in conflict with them (a building across the margin, wide triangles near the survey's edge):
    # the same values as the triangulation of all rim cells within 2 R + 3 cells; without the farther ones
    # some cells would differ
    from lidarctl import raster_ops

    rng = np.random.default_rng(21)
    rows, cols = np.mgrid[0:260, 0:240]
    a = 50.0 + 0.05 * cols + 0.02 * rows + rng.normal(0, 0.2, rows.shape)
    gaps = rng.random(a.shape) < 0.45
    gaps[78:112, 100:134] = True                   # a building across the needed cells' edge and the margin
    gaps[150:210, 170:200] = True
    gaps[:, 225:] = True                           # outside the survey
    a[gaps] = np.nan
    needed = (slice(100, 180), slice(80, 190))
    r = 20
    inserted = []
    bw_insert = raster_ops._bw_insert
    monkeypatch.setattr(raster_ops, "_bw_insert", lambda px, py, seq, mesh: inserted.append(len(seq))
                        or bw_insert(px, py, seq, mesh))
    ours = raster_ops.fill_nodata_tin(a, max_radius_px=r, offset=(3, 7), needed=needed)
    assert len(inserted) >= 2 and sum(inserted[1:]) > 0          # points beyond the margin were inserted
    assert sum(inserted) < 0.5 * np.count_nonzero(~gaps[57:223, 37:233])   # far fewer than all within 2 R + 3
    with monkeypatch.context() as m:
        m.setattr(raster_ops, "_certified_tin", lambda *args: None)
        plain = raster_ops.fill_nodata_tin(a, max_radius_px=r, offset=(3, 7), needed=needed)
    np.testing.assert_array_equal(ours[needed], plain[needed])
    monkeypatch.setattr(raster_ops, "_conflicts_near", lambda *args: 0)
    margin_only = raster_ops.fill_nodata_tin(a, max_radius_px=r, offset=(3, 7), needed=needed)
    assert np.count_nonzero(margin_only[needed] != plain[needed]) > 50


def _hilbert_xy2d(order_bits: int, x: int, y: int) -> int:
    """Wikipedia's xy2d: the Hilbert index of cell (x, y) of a square of 2^order_bits cells, one level at a time."""
    side, d, s = 1 << order_bits, 0, 1 << (order_bits - 1)
    while s > 0:
        rx, ry = int(x & s > 0), int(y & s > 0)
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:
            if rx == 1:
                x, y = side - 1 - x, side - 1 - y
            x, y = y, x
        s >>= 1
    return d


@pytest.mark.parametrize("order_bits", [1, 3, 4, 6, 9, 12])
def test_insertion_order_is_the_hilbert_curve_within_rounds_and_sorted_as_argsort(order_bits):
    rng = np.random.default_rng(order_bits)
    n = 3000
    ix, iy = rng.integers(0, 1 << order_bits, n), rng.integers(0, 1 << order_bits, n)
    keys = _insertion_keys(ix, iy, order_bits)
    hilbert = keys & ((1 << 2 * order_bits) - 1)
    assert [int(h) for h in hilbert] == [_hilbert_xy2d(order_bits, int(x), int(y)) for x, y in zip(ix, iy)]
    rounds = keys >> 2 * order_bits
    assert rounds.min() >= 0 and rounds.max() <= 20 and len(np.unique(rounds)) > 1
    order = _argsort_keys(keys.copy(), 2 * order_bits + 5)
    np.testing.assert_array_equal(order, np.argsort(keys, kind="stable"))
