"""Level water joined across a pulse-dropout gap (``level_water_across_dropouts``), against synthetic truth.

The scene (2 returns per m2, 1.5 cm range noise): a lake of 20 m radius that mirrored the pulse away over
its middle (no return within 14 m of its centre) and returned it only in four 45-degree sectors along its
shore (80 m2 each, none a body of 200 m2 on its own; the sectors between returned nothing), in a bed whose
banks rise 8 cm per metre from 10 cm above the water. Beside it: a level car park with an absorbing patch
in its middle (no returns) whose rim is a curb down to the street, and a level forest floor around an
empty patch in a hollow under crowns 15 m up.
"""

from __future__ import annotations

import numpy as np

from lidarctl.classify import pipeline as classify

LAKE_C, LAKE_R, GAP_R = (35.0, 45.0), 20.0, 14.0
PARK = (75.0, 110.0, 10.0, 40.0)          # u0, u1, v0, v1 (m)
FOREST_C, FOREST_R = (92.0, 70.0), 12.0


def scene(seed: int = 3):
    rng = np.random.default_rng(seed)
    n = int(130 * 90 * 2)
    u, v = rng.uniform(0, 130, n), rng.uniform(0, 90, n)
    d_lake = np.hypot(u - LAKE_C[0], v - LAKE_C[1])
    d_forest = np.hypot(u - FOREST_C[0], v - FOREST_C[1])
    z = 100.0 + 0.08 * np.maximum(d_lake - LAKE_R, 0.0) + 0.02 * u + 0.05 * np.sin(v / 7.0)
    lake = d_lake < LAKE_R
    z[lake] = 99.9
    park = (u >= PARK[0]) & (u < PARK[1]) & (v >= PARK[2]) & (v < PARK[3])
    z[park] = 104.0
    street = ~park & (u >= PARK[0] - 3) & (u < PARK[1] + 3) & (v >= PARK[2] - 3) & (v < PARK[3] + 3)
    z[street] = 103.85 + 0.02 * (u[street] - PARK[0])     # 15 cm curb, the street drains
    forest = d_forest < FOREST_R
    z[forest] = 101.0
    z[~forest & (d_forest < FOREST_R + 4)] += 0.5          # the hollow's rim
    z = z + rng.normal(0.0, 0.015, n)
    # What returned nothing: the lake's middle and four of its eight shore sectors, an absorbing patch
    # in the car park (10 x 10 m), a patch of the forest floor (4 m radius).
    sector = (np.degrees(np.arctan2(v - LAKE_C[1], u - LAKE_C[0])) % 360.0) // 45.0
    mirrored = lake & ((d_lake < GAP_R) | (sector % 2 == 1))
    patch = park & (np.abs(u - 92.5) < 5) & (np.abs(v - 25.0) < 5)
    empty = mirrored | patch | (d_forest < 4.0)
    u, v, z, lake, park, forest = u[~empty], v[~empty], z[~empty], lake[~empty], park[~empty], forest[~empty]
    n = len(u)
    # crowns over the forest floor: one crown return per 2 m2
    m = int(np.pi * FOREST_R ** 2 / 2)
    a, r = rng.uniform(0, 2 * np.pi, m), FOREST_R * np.sqrt(rng.uniform(0, 1, m))
    x = np.r_[u, FOREST_C[0] + r * np.cos(a)] + 500000.0
    y = np.r_[v, FOREST_C[1] + r * np.sin(a)] + 5400000.0
    z = np.r_[z, 101.0 + rng.uniform(12, 16, m)]
    ground = np.r_[np.ones(n, bool), np.zeros(m, bool)]
    nr = np.r_[np.ones(n, np.uint8), np.full(m, 2, np.uint8)]
    pad = np.zeros(m, bool)
    return x, y, z, ground, nr, np.r_[lake, pad], np.r_[park, pad], np.r_[forest, pad]


def run(p: classify.ClassifySettings, seed: int = 3):
    x, y, z, ground, nr, lake, park, forest = scene(seed)
    water = classify.level_water(x, y, z, ground, ground, 1 / np.sqrt(2.0), p=p, number_of_returns=nr)
    return water, lake, park, forest


def test_shore_patches_around_a_dropout_gap_are_one_lake():
    for seed in (3, 4):
        water, lake, park, forest = run(classify.ClassifySettings(), seed)
        assert water[lake].mean() >= 0.95, seed          # all four sectors, up to their shore
        assert water[~lake].sum() == 0, seed             # the banks rise above the level: the shore is exact
        assert not water[park].any() and not water[forest].any(), seed


def test_without_the_join_each_patch_is_too_small():
    water, lake, _, _ = run(classify.ClassifySettings(level_water_across_dropouts=False))
    assert not water[lake].any()                          # 4 x 80 m2, each below 200 m2


def test_a_gap_in_a_level_floor_joins_nothing_that_is_not_in_a_bed():
    # The car park around its absorbing patch and the forest floor around its empty patch are level at
    # one height too; the bed rule (curb down) and the open-sky rule (crowns) reject them joined or not.
    water, _, park, forest = run(classify.ClassifySettings(level_water_bank_fraction=0.0))
    assert water[park].mean() > 0.9                       # without the bed rule the car park would be water
    assert not water[forest].any()                        # under crowns, whatever its rim
