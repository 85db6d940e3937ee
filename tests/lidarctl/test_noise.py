"""Noise and ground filters against a synthetic scene with known truth."""

import numpy as np
from scipy.spatial import Delaunay

from lidarctl import synthetic
from lidarctl.checks import classes as evaluate
from lidarctl.classify import ground
from lidarctl.classify import noise


def _scene(seed=3, **kw):
    return synthetic.synthetic_scene(width_m=150.0, density_per_m2=3.0, seed=seed, **kw)


def test_noise_flags_injected_outliers_and_keeps_canopy_ground():
    cloud, truth = _scene(n_low_outliers=80, n_high_outliers=30, canopy_gap=0.15)
    code = noise.detect_noise(cloud.x, cloud.y, cloud.z)
    outlier = np.isin(truth, (7, 18))
    assert np.mean(code[outlier] > 0) >= 0.99
    assert np.mean(code[~outlier] > 0) < 0.001
    # Sparse last returns on the ground under the crowns must survive.
    under_canopy = (truth == 2) & (cloud.number_of_returns == 2)
    assert under_canopy.sum() > 100
    assert np.all(code[under_canopy] == 0)
    low = code == noise.LOW
    assert np.all(truth[low] == 7)


def test_low_outlier_cluster_is_removed():
    cloud, truth = _scene(n_low_outliers=0, n_high_outliers=0)
    rng = np.random.default_rng(1)
    k = 40   # a patch of multipath points 20 m below a 10 m x 10 m area
    cx, cy = cloud.x.min() + 70 + rng.uniform(0, 10, k), cloud.y.min() + 20 + rng.uniform(0, 10, k)
    cz = synthetic.terrain_height(cx - cloud.x.min(), cy - cloud.y.min()) - 20 + rng.normal(0, 0.3, k)
    code = noise.detect_noise(np.r_[cloud.x, cx], np.r_[cloud.y, cy], np.r_[cloud.z, cz])
    assert np.all(code[-k:] == noise.LOW)
    assert np.mean(code[:-k] > 0) < 0.001


def test_morphological_ground_type_i_ii_below_2pct():
    cloud, truth = _scene()
    keep = ~np.isin(truth, (7, 18))
    g = ground.ground_filter(cloud.x[keep], cloud.y[keep], cloud.z[keep])
    err = evaluate.filter_errors(g, truth[keep] == 2)
    assert err.type_i_error_pct < 2.0
    assert err.type_ii_error_pct < 2.0


def test_ptd_ground_on_synthetic_scene():
    cloud, truth = _scene()
    keep = ~np.isin(truth, (7, 18))
    g = ground.ground_filter(cloud.x[keep], cloud.y[keep], cloud.z[keep], method="ptd", preset="urban")
    err = evaluate.filter_errors(g, truth[keep] == 2)
    assert err.type_i_error_pct < 3.0
    assert err.type_ii_error_pct < 3.0


def test_locate_in_tin_matches_scipy_and_interpolates_planes_exactly():
    rng = np.random.default_rng(0)
    vx, vy = rng.uniform(0, 100, 300), rng.uniform(0, 100, 300)
    tri = Delaunay(np.column_stack([vx, vy]))
    qx, qy = rng.uniform(-5, 105, 2000), rng.uniform(-5, 105, 2000)
    s_ref = tri.find_simplex(np.column_stack([qx, qy]))
    s = ground.locate_in_tin(vx, vy, tri.simplices, qx, qy)
    assert np.array_equal(s >= 0, s_ref >= 0)
    vz = 5.0 + 0.1 * vx - 0.2 * vy
    zq = ground.tin_heights(vx, vy, vz, tri.simplices, qx, qy)
    ok = s >= 0
    np.testing.assert_allclose(zq[ok], 5.0 + 0.1 * qx[ok] - 0.2 * qy[ok], atol=1e-9)
    assert np.all(np.isnan(zq[~ok]))


def test_isolated_points_dense_and_sparse_voxel_counts_match_brute_force(monkeypatch):
    rng = np.random.default_rng(4)
    # clumps and loners; points exactly at the minima: at this x0 and voxel the division rounds the
    # minimum's voxel index down to 0 (the box must still reach the voxel above it)
    x0 = 269.7867137638703
    x = x0 + np.r_[rng.uniform(0, 40, 300), 0.0, 2.0, 40.0, rng.uniform(0, 40, 5)]
    y = np.r_[rng.uniform(0, 40, 300), 0.0, 0.0, 0.0, rng.uniform(0, 40, 5)]
    z = np.r_[rng.uniform(0, 10, 300), 0.0, 0.0, 10.0, rng.uniform(200, 300, 5)]
    voxel = 2.7
    v = [np.floor((a - (a.min() - voxel)) / voxel) for a in (x, y, z)]
    near = np.all([np.abs(a[:, None] - a[None, :]) <= 1 for a in v], axis=0)
    assert v[0][300] == 0 and v[0][301] == 1
    for k in (1, 2):
        want = near.sum(axis=1) - 1 < k
        assert 0 < want.sum() < len(x)
        dense = noise.isolated_points(x, y, z, voxel, k)
        with monkeypatch.context() as m:
            m.setattr(noise, "DENSE_VOXELS", 0)
            sparse = noise.isolated_points(x, y, z, voxel, k)
        np.testing.assert_array_equal(dense, want)
        np.testing.assert_array_equal(sparse, want)
