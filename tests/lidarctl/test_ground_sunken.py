"""The sunken-patch test of the morphological filter (``MorphSettings.sunken_max_area_m2``,
``lidarctl.classify.ground.sunken_patches``) on a synthetic scene with known truth, built as ISPRS samp41's
north-west corner: a ground corridor 12 m wide between the tile edge and a large flat roof, and two short scan
lines of returns 9.5 m below the corridor's ground (multipath), which the noise flags keep when terrain lies at
their height elsewhere. Returns from below the ground are not ground, and must not pull the ground around them
below the surface; a sunken yard larger than a patch is terrain and stays ground.
"""

import numpy as np

from lidarctl.classify import ground

WIDTH_M = 100.0


def _corridor_scene(seed: int, density_per_m2: float = 0.8):
    """x, y, z and the masks truth ground, below-ground returns, corridor ground (samp41-like 1.1 m spacing)."""
    rng = np.random.default_rng(seed)
    n = int(WIDTH_M * WIDTH_M * density_per_m2)
    x, y = rng.uniform(0, WIDTH_M, n), rng.uniform(0, WIDTH_M, n)
    z_ground = 300.0 + 0.02 * y + rng.normal(0, 0.03, n)
    roof = (x > 12.0) & (x < 48.0) & (y > 5.0) & (y < 95.0)
    z = np.where(roof, 316.0 + rng.normal(0, 0.03, n), z_ground)
    py = np.r_[np.arange(40.0, 46.0, 1.5), np.arange(60.0, 66.0, 1.5)]
    px = np.r_[np.full(4, 5.0), np.full(4, 8.0)]
    pz = 300.0 + 0.02 * py - 9.5 + rng.normal(0, 0.03, len(px))
    below = np.r_[np.zeros(n, bool), np.ones(len(px), bool)]
    x, y, z = np.r_[x, px], np.r_[y, py], np.r_[z, pz]
    truth = np.r_[~roof, np.zeros(len(px), bool)]
    return x, y, z, truth, below, (x < 12.0) & truth


def test_returns_from_below_the_ground_are_found_and_the_ground_around_them_kept():
    x, y, z, truth, below, corridor = _corridor_scene(0)
    # The patches and nothing else: the ground returns of the same cells stay.
    found = ground.sunken_patches(x, y, z, 1.5, 2.0, 10.0)
    assert np.array_equal(found, below)
    off = ground.ground_filter(x, y, z, sunken_max_area_m2=0.0)
    # Without the test the patches are ground, and as TIN vertices they pull the corridor's surface down.
    assert off[below].all()
    assert np.mean(off[corridor]) < 0.98
    for area_m2 in (10.0, 40.0):
        on = ground.ground_filter(x, y, z, sunken_max_area_m2=area_m2)
        assert not on[below].any()
        assert on[corridor].all()
        assert np.mean(on[truth]) > 0.999 and not on[~truth & ~below].any()
        # Nothing changes away from the patches.
        far = np.hypot(x - 6.5, y - 53.0) > 30.0
        assert np.array_equal(on[far], off[far])


def test_a_sunken_yard_larger_than_a_patch_stays_ground():
    rng = np.random.default_rng(1)
    n = int(WIDTH_M * WIDTH_M * 0.8)
    x, y = rng.uniform(0, WIDTH_M, n), rng.uniform(0, WIDTH_M, n)
    yard = (np.abs(x - 50.0) < 4.0) & (np.abs(y - 50.0) < 4.0)      # 64 m2, 3 m deep (a sunken court)
    z = 300.0 + 0.01 * x - np.where(yard, 3.0, 0.0) + rng.normal(0, 0.03, n)
    assert not ground.sunken_patches(x, y, z, 1.5, 2.0, 40.0).any()
    g = ground.ground_filter(x, y, z, sunken_max_area_m2=40.0)
    assert g[yard].all()
    assert np.array_equal(g, ground.ground_filter(x, y, z, sunken_max_area_m2=0.0))
