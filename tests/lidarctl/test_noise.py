"""Noise and ground filters against a synthetic scene with known truth."""

import numpy as np
from scipy.spatial import Delaunay, cKDTree

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
    # Low outliers are 3-20 m below the terrain. One less than gap_m + slope * radius_m (1 + 0.4 x 5 m) below
    # flat ground is supported by the ground 5 m away (the gap test cannot tell it from a steep slope) and
    # has ground within the isolation cube's 3 m: those few may pass; every one 0.5 m deeper is flagged.
    ground_pts = np.flatnonzero(truth == 2)
    tree = cKDTree(np.column_stack([cloud.x[ground_pts], cloud.y[ground_pts]]))
    _, nearest = tree.query(np.column_stack([cloud.x, cloud.y]))
    depth_m = cloud.z[ground_pts[nearest]] - cloud.z
    deep = outlier & ((truth == 18) | (depth_m > 3.5))
    assert np.all(code[deep] > 0)
    assert np.mean(code[outlier] > 0) >= 0.95
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


def test_isolated_points_match_brute_force_cube_count():
    rng = np.random.default_rng(4)
    # clumps and loners, points on the voxel lattice's planes and a stray far above
    x = 269.7867137638703 + np.r_[rng.uniform(0, 40, 300), 0.0, 2.7, 5.4, 8.1, rng.uniform(0, 40, 5)]
    y = np.r_[rng.uniform(0, 40, 300), 0.0, 0.0, 0.0, 0.0, rng.uniform(0, 40, 5)]
    z = np.r_[rng.uniform(0, 10, 300), 0.0, 0.0, 0.0, 0.0, rng.uniform(200, 300, 5)]
    voxel = 2.7
    near = np.all([np.abs(a[:, None] - a[None, :]) <= 1.5 * voxel for a in (x, y, z)], axis=0)
    for k in (0, 1, 2, 4):
        want = near.sum(axis=1) - 1 < k
        assert k == 0 or 0 < want.sum() < len(x)
        np.testing.assert_array_equal(noise.isolated_points(x, y, z, voxel, k), want)


def test_isolated_points_do_not_depend_on_a_stray_point_or_the_tile():
    """A point 25 m below the scene, or cutting the cloud into tiles, changes no other point's verdict
    (a voxel lattice anchored at the data's minimum moved with both)."""
    cloud, _ = _scene(n_low_outliers=0, n_high_outliers=0, canopy_gap=0.15)
    x, y, z = cloud.x, cloud.y, cloud.z
    base = noise.isolated_points(x, y, z, 1.0)
    assert 0 < base.sum() < len(x)
    for dz in (-25.0, -25.37, 13.9):
        with_stray = noise.isolated_points(np.r_[x, x[7]], np.r_[y, y[7]], np.r_[z, z[7] + dz], 1.0)
        np.testing.assert_array_equal(with_stray[:-1], base)
    # a tile's verdicts equal the whole cloud's away from its edges (1.5 m, the cube's half-edge)
    x0 = x.min() + 61.3
    tile = x >= x0
    inner = x[tile] >= x0 + 1.5
    np.testing.assert_array_equal(noise.isolated_points(x[tile], y[tile], z[tile], 1.0)[inner], base[tile][inner])


def test_high_outlier_clusters_are_removed_tall_mast_kept():
    """Birds / low clouds: groups of 3-9 returns 0.5-2.5 m apart, 90-120 m above the terrain, support each other in
    the single-point gap test; the high cluster test flags them all. A 60 m mast (a return every 1.5 m of its
    height) and a 30 m tree-like column with a 25 m empty band below its crown stay clean."""
    cloud, truth = _scene(n_low_outliers=0, n_high_outliers=0)
    rng = np.random.default_rng(7)
    x0, y0 = cloud.x.min(), cloud.y.min()
    bx, by, bz = [], [], []
    for k in range(12):
        n = int(rng.integers(3, 10))
        cx, cy = x0 + rng.uniform(10, 140), y0 + rng.uniform(10, 140)
        h = rng.uniform(90.0, 120.0)
        bx.append(cx + rng.uniform(-1.5, 1.5, n))
        by.append(cy + rng.uniform(-1.5, 1.5, n))
        bz.append(synthetic.terrain_height(cx - x0, cy - y0) + h + rng.uniform(-1.0, 1.0, n))
    bx, by, bz = np.concatenate(bx), np.concatenate(by), np.concatenate(bz)
    # a mast: returns every 1.5 m up to 60 m; a crown 30-32 m up over 5 m of bole returns near the ground
    mz = np.arange(0.0, 60.0, 1.5)
    mx, my = np.full(len(mz), x0 + 85.0), np.full(len(mz), y0 + 100.0)
    mz = mz + synthetic.terrain_height(85.0, 100.0)
    ang = rng.uniform(0, 2 * np.pi, 15)
    tx = np.r_[x0 + 110 + 2 * np.cos(ang), np.full(3, x0 + 110.0)]
    ty = np.r_[y0 + 110 + 2 * np.sin(ang), np.full(3, y0 + 110.0)]
    tz = np.r_[rng.uniform(30.0, 32.0, 15), 1.0, 3.0, 5.0] + synthetic.terrain_height(110.0, 110.0)
    n0, nb, nm = len(cloud.x), len(bx), len(mx)
    code = noise.detect_noise(np.r_[cloud.x, bx, mx, tx], np.r_[cloud.y, by, my, ty], np.r_[cloud.z, bz, mz, tz])
    assert np.all(code[n0:n0 + nb] == noise.HIGH)
    assert np.all(code[n0 + nb:] == 0)
    assert np.mean(code[:n0] > 0) < 0.001
