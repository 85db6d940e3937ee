"""Ground refinement of lidarctl.classify.pipeline: the last returns of low vegetation leave the ground
class, by a threshold scaled to the measured range noise; single returns are judged against their
neighbours' robust spread too, so a strip offset does not lift them but a low object does."""

import numpy as np
from lidarctl.classify import pipeline as classify


def _terrain_with_low_vegetation(seed: int, noise_m: float, lift_m: float = 0.2):
    """A 40 x 40 m sloping terrain (5 %) with a gentle wave, 8 points/m2, range noise ``noise_m``,
    and a 0.12 m curb along y = 20 (the side beyond it is a raised pavement: ground); in three
    3 x 6 m patches of low vegetation a third of the pulses return twice, the last return
    ``lift_m`` above the ground. The strip over x > 20 lies 0.1 m higher than the rest (an
    unadjusted strip offset; single returns). Returns x, y, z, the multi-return mask and the truth
    masks of the lifted points and of the pavement."""
    rng = np.random.default_rng(seed)
    n = 40 * 40 * 8
    x, y = rng.uniform(0, 40, n), rng.uniform(0, 40, n)
    pavement = y > 20.0
    z = 10.0 + 0.05 * x + 0.3 * np.sin(y / 6.0) + 0.12 * pavement + rng.normal(0, noise_m, n)
    # the strips overlap over 15 < x < 25: half the points there come from the higher strip
    z += 0.1 * ((x > 25) | ((x > 15) & (rng.random(n) < 0.5)))
    lifted = np.zeros(n, bool)
    for x0, y0 in ((5, 5), (20, 30), (30, 10)):
        lifted |= (x > x0) & (x < x0 + 3) & (y > y0) & (y < y0 + 6)
    lifted &= rng.random(n) < 1 / 3
    z[lifted] += lift_m
    return x + 85000.0, y + 447000.0, z, lifted.copy(), lifted, pavement


def test_low_vegetation_leaves_the_ground_and_the_threshold_follows_the_noise():
    x, y, z, multi, lifted, pavement = _terrain_with_low_vegetation(seed=1, noise_m=0.02)
    spacing = 1 / np.sqrt(8.0)
    everything = np.ones(len(x), bool)
    flagged = classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=multi, judge_single=False)
    # 0.2 m = 10 sigma of the range noise (5 with the strip offset in the spread): most low returns go (the least-squares plane leans on
    # the lifted neighbours too), nothing else does: not the terrain (slope, wave), not the
    # pavement beyond the curb, not the higher strip's points in the overlap (single returns).
    assert flagged[lifted].mean() > 0.6
    assert not flagged[~lifted].any()
    # Single returns judged too (the default), against their neighbours' spread: the same low
    # returns, and of the bare earth at most 0.1 % (on the strip and curb edges, where the
    # neighbours' plane bends).
    guarded = classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=multi)
    assert guarded[lifted].mean() >= flagged[lifted].mean()
    assert guarded[~lifted].sum() <= 0.001 * (~lifted).sum()
    # Judged as if every point were intercepted, the strip overlap would lose points (more than
    # all the rest of the terrain): the multi-return condition is what keeps them.
    anyway = classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=everything, judge_single=False)
    overlap = (x > 85015) & (x < 85025)
    assert anyway[~lifted & overlap].sum() > max(5, anyway[~lifted & ~overlap].sum())
    assert anyway[~lifted].sum() > max(1, guarded[~lifted].sum())
    # Same vegetation in a cloud five times as noisy (0.1 m): 0.2 m is inside the noise.
    x, y, z, multi, lifted, pavement = _terrain_with_low_vegetation(seed=2, noise_m=0.1)
    flagged = classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=multi)
    assert flagged[lifted].mean() < 0.1
    # Disabled by 0 or without return numbers, and only ground points are ever flagged.
    assert not classify.lifted_ground(x, y, z, everything, spacing, 0.0, intercepted=multi).any()
    assert not classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=None).any()
    half = np.arange(len(x)) % 2 == 0
    assert not classify.lifted_ground(x, y, z, half, spacing, 4.0, intercepted=everything)[~half].any()


def test_single_return_low_objects_leave_the_ground_only_when_single_returns_are_judged():
    # The same low returns, every pulse returning once (sparse low shrubs). Against their
    # neighbours' spread (a third of the patch is lifted, so the spread is wide) fewer go than
    # as last returns of multi-return pulses, but some do, and the bare earth stays.
    x, y, z, _, lifted, _ = _terrain_with_low_vegetation(seed=3, noise_m=0.02)
    spacing = 1 / np.sqrt(8.0)
    everything = np.ones(len(x), bool)
    single = np.zeros(len(x), bool)
    judged = classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=single)
    assert judged[lifted].mean() > 0.1
    assert judged[~lifted].sum() <= 0.001 * (~lifted).sum()
    assert not classify.lifted_ground(x, y, z, everything, spacing, 4.0, intercepted=single, judge_single=False).any()


def test_the_plane_kernels_small_solve_and_median_equal_numpys():
    """The plane offsets' 3 x 3 solve and median (numba helpers that compile in a fraction of a second, instead
    of numba's LAPACK binding and quickselect) against np.linalg.solve and np.median."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        uv = rng.normal(0, 2.0, (12, 2))
        g = np.c_[uv, np.ones(12)]
        a, b = g.T @ g + 1e-9 * np.eye(3), g.T @ rng.normal(0, 1, 12)
        assert np.allclose(classify._solve3(a.copy(), b.copy()), np.linalg.solve(a, b), rtol=1e-12, atol=1e-12)
    a = np.array([[0.0, 2.0, 1.0], [1.0, 1.0, 0.0], [3.0, 0.0, 1.0]])  # a zero first pivot: rows are swapped
    assert np.allclose(classify._solve3(a.copy(), np.array([1.0, 2.0, 3.0])), np.linalg.solve(a, [1.0, 2.0, 3.0]))
    for n in (1, 2, 5, 6, 12):
        v = rng.normal(0, 1, n)
        assert classify._median_small(v.copy()) == np.median(v)
