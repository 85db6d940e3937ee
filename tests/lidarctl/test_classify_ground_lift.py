"""Ground refinement of lidarctl.classify: low objects' last returns leave the ground class, by a
threshold scaled to the measured range noise."""

import numpy as np
from lidarctl import classify


def _terrain_with_low_objects(seed: int, noise_m: float, lift_m: float = 0.15):
    """A 40 x 40 m sloping terrain (5 %) with a gentle wave, 8 points/m2, range noise ``noise_m``,
    and a 0.12 m curb along y = 20 (the side beyond it is a raised pavement: ground); in three
    3 x 6 m patches of low vegetation a third of the last returns stop ``lift_m`` above the ground.
    Returns x, y, z and the truth masks of the lifted points and of the pavement."""
    rng = np.random.default_rng(seed)
    n = 40 * 40 * 8
    x, y = rng.uniform(0, 40, n), rng.uniform(0, 40, n)
    pavement = y > 20.0
    z = 10.0 + 0.05 * x + 0.3 * np.sin(y / 6.0) + 0.12 * pavement + rng.normal(0, noise_m, n)
    lifted = np.zeros(n, bool)
    for x0, y0 in ((5, 5), (20, 30), (30, 10)):
        lifted |= (x > x0) & (x < x0 + 3) & (y > y0) & (y < y0 + 6)
    lifted &= rng.random(n) < 1 / 3
    z[lifted] += lift_m
    return x + 85000.0, y + 447000.0, z, lifted, pavement


def test_low_objects_leave_the_ground_and_the_threshold_follows_the_noise():
    x, y, z, lifted, pavement = _terrain_with_low_objects(seed=1, noise_m=0.02)
    spacing = 1 / np.sqrt(8.0)
    flagged = classify.lifted_ground(x, y, z, np.ones(len(x), bool), spacing, 4.0)
    # 0.15 m = 7.5 sigma of the range noise: most low returns go (the least-squares plane leans on
    # the lifted neighbours too: 70 % here), the terrain (slope, wave) stays; a curb loses only the
    # pavement's edge (a plane fit straddling the step), not the pavement.
    assert flagged[lifted].mean() > 0.6
    assert flagged[~lifted & ~pavement].mean() < 0.005
    assert flagged[~lifted & pavement].mean() < 0.03
    # Same objects in a cloud five times as noisy (0.1 m): 0.15 m is inside the noise, nothing goes.
    x, y, z, lifted, pavement = _terrain_with_low_objects(seed=2, noise_m=0.1)
    flagged = classify.lifted_ground(x, y, z, np.ones(len(x), bool), spacing, 4.0)
    assert flagged.mean() < 0.005
    # Disabled by 0, and only ground points are ever flagged.
    assert not classify.lifted_ground(x, y, z, np.ones(len(x), bool), spacing, 0.0).any()
    half = np.arange(len(x)) % 2 == 0
    assert not classify.lifted_ground(x, y, z, half, spacing, 4.0)[~half].any()
