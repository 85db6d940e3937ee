"""Building rule of lidarctl.classify.pipeline: penetration evidence keeps tree crowns out of the roofs."""

import numpy as np
from lidarctl.classify import pipeline as classify


def _roof_and_crown(seed: int, density_per_m2: float = 10.0, canopy_gap: float = 0.35):
    """A flat 18 x 16 m roof 8 m high and, 6 m beside it, a dome-shaped crown (radius 8 m, base
    6 m, top 10 m above the ground; first returns at the simulator's depth into the crown) that
    passes ``canopy_gap`` of its pulses to the ground as a second return. Returns x, y, z,
    return number, number of returns, truth class (2 ground, 5 high vegetation, 6 building)."""
    rng = np.random.default_rng(seed)
    n = int(60.0 * 40.0 * density_per_m2)
    u, v = rng.uniform(0, 60.0, n), rng.uniform(0, 40.0, n)
    ground_z = 100.0 + 0.02 * u + rng.normal(0, 0.03, n)
    z, truth = ground_z.copy(), np.full(n, 2, np.uint8)
    roof = (u > 6) & (u < 24) & (v > 10) & (v < 26)
    z[roof] = 108.0 + rng.normal(0, 0.03, roof.sum())
    truth[roof] = 6
    d2 = ((u - 40.0) ** 2 + (v - 18.0) ** 2) / 8.0 ** 2
    crown = d2 < 1.0
    z[crown] = ground_z[crown] + 6.0 + 4.0 * np.sqrt(1.0 - d2[crown]) * rng.uniform(0.6, 1.0, crown.sum())
    truth[crown] = 5
    through = crown & (rng.random(n) < canopy_gap)
    k = int(through.sum())
    returns = np.where(through, 2, 1).astype(np.uint8)
    return (np.r_[u, u[through]] + 500000.0, np.r_[v, v[through]] + 5400000.0, np.r_[z, ground_z[through]],
            np.r_[np.ones(n, np.uint8), np.full(k, 2, np.uint8)], np.r_[returns, np.full(k, 2, np.uint8)],
            np.r_[truth, np.full(k, 2, np.uint8)])


def test_multi_return_crown_beside_a_roof_stays_vegetation():
    # With the roof knobs chosen on AHN3 (plane RMS 0.25 m, 10 m2), a cell-by-cell multi-return
    # test let this crown's cells without a multi-return point (18 % of 4-return cells at a 35 %
    # gap) make up a roof: the whole crown became building.
    x, y, z, rn, nr, truth = _roof_and_crown(seed=0)
    cls = classify.classify_points(x, y, z, rn, nr, np.full(len(x), 300, np.uint16))
    assert np.mean(cls[truth == 6] == classify.BUILDING) > 0.99
    assert np.mean(cls[truth == 5] == classify.BUILDING) < 0.01
    # the rest is 1: smooth cells without a multi-return point (the vegetation rule, unchanged)
    assert np.mean(cls[truth == 5] == classify.HIGH_VEG) > 0.8


def _wilson_upper(k, n, z=1.645):
    f = k / n
    return (f + z * z / (2 * n) + z * np.sqrt(f * (1 - f) / n + z * z / (4 * n * n))) / (1 + z * z / n)


def test_fewer_multi_returns_is_the_wilson_bound_below_the_fraction():
    for n in (4, 7, 12, 36, 100):
        k = np.arange(0, n + 1)
        shown = classify.fewer_multi_returns(k, np.full(n + 1, n), 0.3)
        assert np.array_equal(shown, _wilson_upper(k, n) <= 0.3)
    # a roof window of 36 returns without a multi-return point shows it; a crown's 35 % does not,
    # nor does one cell of 4 returns without any, nor an empty window
    assert classify.fewer_multi_returns(np.array([0, 13]), np.array([36, 36]), 0.3).tolist() == [True, False]
    assert not classify.fewer_multi_returns(np.array([0]), np.array([4]), 0.3)[0]
    assert not classify.fewer_multi_returns(np.array([0]), np.array([0]), 0.3)[0]
