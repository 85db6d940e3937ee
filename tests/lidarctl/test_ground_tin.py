"""The morphological filter's refinement TIN (issue 41): Bowyer-Watson along the cells gives Qhull's triangles, the
TIN's heights and geometry are the numpy expressions' bit for bit, and the cell order is argsort's."""

import numpy as np
import pytest
from scipy.spatial import QhullError

from lidarctl import grid
from lidarctl.classify import ground


def _lowest_ground(seed: int, n: int = 40_000):
    """The lowest point per 1 m cell of a scan-line-like cloud (mm coordinates, rows of pulses), as the
    refinement takes them: (x, y, z, rows, cols)."""
    rng = np.random.default_rng(seed)
    line = rng.integers(0, 200, n)
    x = np.round(453_000.0 + rng.uniform(0, 150, n), 3)
    y = np.round(5_400_000.0 + line * 0.45 + 0.02 * (x - 453_000.0) + rng.normal(0, 0.01, n), 3)
    z = np.round(100.0 + 0.05 * (x - 453_000.0) + rng.normal(0, 0.05, n), 3)
    cell, nrows, ncols, _, _ = grid.cell_ids(x, y, 1.0)
    low = grid.lowest_per_cell(cell, z)
    return x[low], y[low], z[low], cell[low] // ncols, cell[low] % ncols


def _triangles(simplices) -> set:
    return {tuple(sorted(t)) for t in simplices.tolist()}


def test_delaunay_cells_gives_qhulls_triangles():
    for seed in (1, 2):
        x, y, _, rows, cols = _lowest_ground(seed)
        tri = ground.delaunay_cells(x, y, rows, cols)
        assert len(tri) > 10_000
        assert _triangles(tri) == _triangles(ground.delaunay_2d(x, y))


def test_delaunay_cells_of_collinear_points_fails_as_qhull():
    x = np.arange(5.0)
    with pytest.raises(QhullError):     # Qhull's error, as before the insertion
        ground.delaunay_cells(x, 2.0 * x, np.arange(5), np.arange(5))


def _numpy_tin_heights(vx, vy, vz, simplices, qx, qy):
    """The numpy expressions tin_heights evaluated before its kernel (main at 8cf7c3ef)."""
    s = ground.locate_in_tin(vx, vy, simplices, qx, qy)
    out = np.full(len(qx), np.nan)
    ok = s >= 0
    v = simplices[s[ok]]
    ax, ay, az = vx[v[:, 0]], vy[v[:, 0]], vz[v[:, 0]]
    bx, by, bz = vx[v[:, 1]], vy[v[:, 1]], vz[v[:, 1]]
    cx, cy, cz = vx[v[:, 2]], vy[v[:, 2]], vz[v[:, 2]]
    det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    l1 = ((by - cy) * (qx[ok] - cx) + (cx - bx) * (qy[ok] - cy)) / det
    l2 = ((cy - ay) * (qx[ok] - cx) + (ax - cx) * (qy[ok] - cy)) / det
    out[ok] = l1 * az + l2 * bz + (1.0 - l1 - l2) * cz
    px, py, pz = qx[ok], qy[ok], out[ok]
    vertex_m = np.full(len(qx), np.inf)
    vertex_m[ok] = np.sqrt(np.minimum.reduce([(px - ax) ** 2 + (py - ay) ** 2 + (pz - az) ** 2,
                                              (px - bx) ** 2 + (py - by) ** 2 + (pz - bz) ** 2,
                                              (px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2]))
    ux, uy, uz, wx, wy, wz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    cos_tilt = np.ones(len(qx))
    cos_tilt[ok] = np.abs(nz) / np.maximum(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
    return out, vertex_m, cos_tilt


def test_tin_heights_are_the_numpy_expressions_bit_for_bit():
    x, y, z, rows, cols = _lowest_ground(3)
    tri = ground.delaunay_cells(x, y, rows, cols)
    rng = np.random.default_rng(4)
    qx = np.concatenate([rng.uniform(x.min() - 5, x.max() + 5, 30_000), x[:500]])   # outside the hull and on vertices
    qy = np.concatenate([rng.uniform(y.min() - 5, y.max() + 5, 30_000), y[:500]])
    got = ground.tin_heights(x, y, z, tri, qx, qy, geometry=True)
    want = _numpy_tin_heights(x, y, z, tri, qx, qy)
    assert np.isnan(got[0]).sum() > 100 and np.isfinite(got[0]).sum() > 20_000
    for g, w in zip(got, want):
        assert g.tobytes() == w.tobytes()
    assert ground.tin_heights(x, y, z, tri, qx, qy).tobytes() == want[0].tobytes()


def test_cell_order_is_the_stable_argsort():
    cell = np.random.default_rng(5).integers(0, 997, 50_000)
    order, start = grid.cell_order(cell, 1000)
    assert np.array_equal(order, np.argsort(cell, kind="stable"))
    assert np.array_equal(start, np.searchsorted(cell[order], np.arange(1001)))
