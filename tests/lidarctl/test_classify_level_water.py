"""Level water (lidarctl.classify.pipeline.level_water): calm water that returned the pulse, against synthetic truth.

The scene (2 returns per m2, 1.5 cm range noise): a lake whose surface returns every pulse at one level,
in a bed whose banks rise 8 cm per metre; a level car park (same noise, same flatness) whose rim is a
curb down to the street; a level forest floor in a hollow under crowns 15 m up.
"""

from __future__ import annotations

import numpy as np

from lidarctl.classify import pipeline as classify

LAKE_C, LAKE_R = (40.0, 60.0), 20.0
PARK = (75.0, 105.0, 45.0, 75.0)          # u0, u1, v0, v1 (m)
FOREST_C, FOREST_R = (40.0, 15.0), 12.0


def scene(seed: int = 1):
    rng = np.random.default_rng(seed)
    n = int(120 * 90 * 2)
    u, v = rng.uniform(0, 120, n), rng.uniform(0, 90, n)
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
    # crowns over the forest floor: one crown return per 2 m2
    m = int(np.pi * FOREST_R ** 2 / 2)
    a, r = rng.uniform(0, 2 * np.pi, m), FOREST_R * np.sqrt(rng.uniform(0, 1, m))
    cu, cv = FOREST_C[0] + r * np.cos(a), FOREST_C[1] + r * np.sin(a)
    x = np.r_[u, cu] + 500000.0
    y = np.r_[v, cv] + 5400000.0
    z = np.r_[z, 101.0 + rng.uniform(12, 16, m)]
    ground = np.r_[np.ones(n, bool), np.zeros(m, bool)]
    nr = np.r_[np.ones(n, np.uint8), np.full(m, 2, np.uint8)]
    truth = np.r_[lake, np.zeros(m, bool)]
    return x, y, z, ground, nr, truth, np.r_[park, np.zeros(m, bool)], np.r_[forest, np.zeros(m, bool)]


def test_level_lake_is_water_floors_are_not():
    x, y, z, ground, nr, lake, park, forest = scene()
    water = classify.level_water(x, y, z, ground, ground, 1 / np.sqrt(2.0), p=classify.ClassifySettings(),
                                 number_of_returns=nr)
    assert water[lake].mean() >= 0.95                   # the lake, up to its shore
    assert not water[park].any()                        # level, but its rim is a curb down
    assert not water[forest].any()                      # level and in a hollow, but under crowns
    assert water[~lake].sum() == 0                      # the banks rise above the level: the shore is exact


def test_level_water_off_and_too_small():
    x, y, z, ground, nr, lake, _, _ = scene()
    off = classify.ClassifySettings(level_water_min_area_m2=0.0)
    assert not classify.level_water(x, y, z, ground, ground, 0.7, p=off, number_of_returns=nr).any()
    # the lake (1,257 m2) is smaller than a body of 2,000 m2
    big = classify.ClassifySettings(level_water_min_area_m2=2000.0)
    assert not classify.level_water(x, y, z, ground, ground, 0.7, p=big, number_of_returns=nr).any()


def test_the_bed_rule_is_what_rejects_the_car_park():
    x, y, z, ground, nr, lake, park, _ = scene()
    no_bed = classify.ClassifySettings(level_water_bank_fraction=0.0)
    water = classify.level_water(x, y, z, ground, ground, 1 / np.sqrt(2.0), p=no_bed, number_of_returns=nr)
    assert water[park].mean() > 0.9
