"""Pulse-dropout water detection (lidarctl.classify.pipeline step 5) against synthetic truth.

The scene: lidarctl.synthetic terrain with one flat-roofed building and a pond. Over the pond 95 %
of the pulses give no return and the rest lie on the flat water level with low intensity; the
banks slope down to the water. Beside the building, on a levelled plot, an occlusion shadow keeps
5 % of its ground returns: a flat, horizontal dropout gap that is not water.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarctl.classify import pipeline as classify
from lidarctl.synthetic import synthetic_scene, terrain_height

X0, Y0 = 500000.0, 5400000.0
POND_C, POND_A, POND_B, BANK_M = (130.0, 125.0), 20.0, 14.0, 6.0
BUILDING = (30.0, 56.0, 30.0, 52.0)            # u0, u1, v0, v1 (m)
SHADOW = (56.0, 60.0, 30.0, 52.0)


def pond_scene() -> dict:
    """Per-point arrays of the pond scene, truth classes, the water level and the shadow mask."""
    cloud, truth = synthetic_scene(width_m=200.0, density_per_m2=4.0, n_buildings=0, n_trees=0,
                                   n_low_outliers=30, n_high_outliers=10, seed=3, x0=X0, y0=Y0)
    rng = np.random.default_rng(7)
    u, v, z = cloud.x - X0, cloud.y - Y0, cloud.z.copy()
    intensity = cloud.intensity.astype(float)
    ground = truth == 2
    # Pond: ellipse distance d (1 at the shore); banks blend down to the level over BANK_M.
    d = np.hypot((u - POND_C[0]) / POND_A, (v - POND_C[1]) / POND_B)
    uu, vv = np.meshgrid(np.linspace(-POND_A, POND_A, 81) + POND_C[0], np.linspace(-POND_B, POND_B, 57) + POND_C[1])
    inside_grid = np.hypot((uu - POND_C[0]) / POND_A, (vv - POND_C[1]) / POND_B) <= 1.0
    level = float(np.percentile(terrain_height(uu[inside_grid], vv[inside_grid]), 20)) - 0.3
    shore_m = (d - 1.0) * min(POND_A, POND_B)
    blend = np.clip(shore_m / BANK_M, 0.0, 1.0)
    bank = ground & (d > 1.0)
    z[bank] = np.minimum(z[bank], level + blend[bank] * (z[bank] - level))
    water = ground & (d <= 1.0)
    keep = ~water | (rng.random(len(z)) < 0.05)
    z[water] = level + rng.normal(0.0, 0.03, water.sum())
    intensity[water] = rng.normal(30.0, 10.0, water.sum()).clip(1, None)
    truth = truth.copy()
    truth[water] = classify.WATER
    # Building (flat roof 10 m up) on a levelled plot, and its occlusion shadow: only 5 % of the
    # ground returns, flat and horizontal like water.
    plot = ground & (u >= BUILDING[0] - 10) & (u < SHADOW[1] + 10) & (v >= BUILDING[2] - 10) & (v < BUILDING[3] + 10)
    z[plot] = terrain_height(43.0, 41.0) + rng.normal(0, 0.03, plot.sum())
    in_b = ground & (u >= BUILDING[0]) & (u < BUILDING[1]) & (v >= BUILDING[2]) & (v < BUILDING[3])
    z[in_b] = terrain_height(43.0, 41.0) + 10.0 + rng.normal(0, 0.03, in_b.sum())
    intensity[in_b] = rng.normal(500, 40, in_b.sum())
    truth[in_b] = classify.BUILDING
    in_s = ground & (u >= SHADOW[0]) & (u < SHADOW[1]) & (v >= SHADOW[2]) & (v < SHADOW[3])
    keep &= ~in_s | (rng.random(len(z)) < 0.05)
    k = np.flatnonzero(keep)
    return dict(x=cloud.x[k], y=cloud.y[k], z=z[k], rn=cloud.return_number[k], nr=cloud.number_of_returns[k],
                intensity=intensity[k].astype(np.uint16), truth=truth[k], level=level,
                shadow=in_s[k])


@pytest.fixture(scope="module")
def scene():
    return pond_scene()


def _accuracy(pred, truth):
    tp = np.sum((pred == classify.WATER) & (truth == classify.WATER))
    return 100.0 * tp / np.sum(truth == classify.WATER), 100.0 * tp / max(np.sum(pred == classify.WATER), 1)


def test_pond_returns_become_water(scene):
    s = scene
    pred = classify.classify_points(s["x"], s["y"], s["z"], s["rn"], s["nr"], s["intensity"])
    producers, users = _accuracy(pred, s["truth"])
    assert np.sum(s["truth"] == classify.WATER) > 100
    assert producers >= 90.0 and users >= 95.0, (producers, users)
    # The shadow's few ground returns stay ground; injected outliers stay noise.
    assert not np.any(pred[s["shadow"]] == classify.WATER)
    assert np.all(np.isin(pred[s["truth"] == 7], (7, 18)))


def test_without_intensity_density_and_level_decide(scene):
    """A cloud without intensity (constant field): dropout, level, banks and shadow tests alone."""
    s = scene
    flat_intensity = np.zeros(len(s["x"]), np.uint16)
    pred = classify.classify_points(s["x"], s["y"], s["z"], s["rn"], s["nr"], flat_intensity)
    producers, users = _accuracy(pred, s["truth"])
    assert producers >= 80.0 and users >= 90.0, (producers, users)
    assert not np.any(pred[s["shadow"]] == classify.WATER)


def test_bright_dropout_gap_is_not_water(scene):
    """The same pond gap with land-bright returns (e.g. a data gap over a flat field) is not water."""
    s = scene
    bright = s["intensity"].copy()
    bright[s["truth"] == classify.WATER] = 300
    pred = classify.classify_points(s["x"], s["y"], s["z"], s["rn"], s["nr"], bright)
    assert not np.any(pred == classify.WATER)


def test_water_level_is_lowest_coherent_surface():
    rng = np.random.default_rng(1)
    water_z = -0.46 + rng.normal(0, 0.015, 30)
    pontoon_z = -0.32 + rng.normal(0, 0.02, 35)         # more returns, 14 cm above the water
    level, sigma_m = classify.water_level(np.concatenate([water_z, pontoon_z]), 0.2)
    assert abs(level + 0.46) < 0.01
    assert sigma_m < 0.03


def test_dropout_under_canopy_is_not_water(scene):
    """Crowns over the west half of the pond gap: the dark, level returns under them are forest floor
    seen through foliage (drop-out under canopy), never water; the open east half stays water."""
    s = scene
    rng = np.random.default_rng(11)
    u, v = s["x"] - X0, s["y"] - Y0
    under = (s["truth"] == classify.WATER) & (u < POND_C[0])
    # A closed canopy, 8-15 m up, at the scene's density over the west half of the pond.
    n_crown = int(4.0 * POND_A * 2 * POND_B)
    cu = POND_C[0] - rng.uniform(0.0, POND_A + 1.0, n_crown)
    cv = POND_C[1] + rng.uniform(-POND_B - 1.0, POND_B + 1.0, n_crown)
    cz = s["level"] + rng.uniform(8.0, 15.0, n_crown)
    x = np.concatenate([s["x"], X0 + cu])
    y = np.concatenate([s["y"], Y0 + cv])
    z = np.concatenate([s["z"], cz])
    rn = np.concatenate([s["rn"], np.ones(len(cu), s["rn"].dtype)])
    nr = np.concatenate([s["nr"], np.full(len(cu), 2, s["nr"].dtype)])
    inten = np.concatenate([s["intensity"], np.full(len(cu), 400, np.uint16)])
    pred = classify.classify_points(x, y, z, rn, nr, inten)[:len(s["x"])]
    assert under.sum() > 40
    assert not np.any(pred[under] == classify.WATER)
    open_water = (s["truth"] == classify.WATER) & (u > POND_C[0] + 3.0)
    assert np.mean(pred[open_water] == classify.WATER) >= 0.8
