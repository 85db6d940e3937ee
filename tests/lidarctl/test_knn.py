"""lidarctl.knn: the bucket-grid kNN gives scipy cKDTree's answer exactly (distances, indices, ties)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidarctl.knn import BucketGrid, knn_2d


def _cloud(n, seed, step_m=None, spread_m=100.0):
    rng = np.random.default_rng(seed)
    # scan-line-like clustering: points along lines with jitter, plus a sparse part and a gap
    x = rng.uniform(0.0, spread_m, n)
    y = np.floor(rng.uniform(0.0, spread_m, n) / 0.7) * 0.7 + rng.normal(0.0, 0.05, n)
    keep = ~((x > 40) & (x < 60) & (y > 40) & (y < 60))   # a void (a lake, a roof without ground)
    x, y = x[keep], y[keep]
    if step_m is not None:   # LAS coordinates: integer steps, so equal distances occur
        x, y = np.round(x / step_m) * step_m, np.round(y / step_m) * step_m
    return x + 452000.0, y + 3407000.0


@pytest.mark.parametrize("step_m, k, upper_m", [(None, 13, 3.0), (0.01, 13, 3.0), (0.01, 17, np.inf),
                                                (0.1, 5, 0.5), (None, 1, np.inf)])
def test_same_answer_as_ckdtree(step_m, k, upper_m):
    x, y = _cloud(20000, 1, step_m)
    ref_d, ref_i = cKDTree(np.column_stack([x, y])).query(np.column_stack([x, y]), k=k, distance_upper_bound=upper_m)
    d, i, n_tied = knn_2d(x, y, x, y, k, upper_m)
    ref_d, ref_i = ref_d.reshape(len(x), k), ref_i.reshape(len(x), k)
    np.testing.assert_array_equal(d, ref_d)
    np.testing.assert_array_equal(i, ref_i)
    if step_m == 0.1:
        assert n_tied > 0   # the coarse steps make ties, which cKDTree answered


def test_queries_other_than_the_points_and_chunks():
    x, y = _cloud(30000, 2, 0.001)
    sub = np.arange(0, len(x), 3)
    tree = cKDTree(np.column_stack([x[sub], y[sub]]))
    qx, qy = x[::2], y[::2]
    ref_d, ref_i = tree.query(np.column_stack([qx, qy]), k=17)
    grid = BucketGrid(x[sub], y[sub], 17)
    for a in range(0, len(qx), 4000):   # the callers' chunked loop
        d, i, _ = grid.query(qx[a:a + 4000], qy[a:a + 4000], 17)
        np.testing.assert_array_equal(d, ref_d[a:a + 4000])
        np.testing.assert_array_equal(i, ref_i[a:a + 4000])


def test_fewer_points_than_k_and_far_queries():
    x, y = _cloud(30, 3)
    qx, qy = np.array([x.min() - 50.0, x.max() + 7.0]), np.array([y.mean(), y.max() + 300.0])
    ref_d, ref_i = cKDTree(np.column_stack([x, y])).query(np.column_stack([qx, qy]), k=40)
    d, i, _ = knn_2d(x, y, qx, qy, 40)
    np.testing.assert_array_equal(d, ref_d)
    np.testing.assert_array_equal(i, ref_i)
    ref_d, ref_i = cKDTree(np.column_stack([x, y])).query(np.column_stack([qx, qy]), k=5, distance_upper_bound=60.0)
    d, i, _ = knn_2d(x, y, qx, qy, 5, 60.0)
    np.testing.assert_array_equal(d, ref_d)
    np.testing.assert_array_equal(i, ref_i)
