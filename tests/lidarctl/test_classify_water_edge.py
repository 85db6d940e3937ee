"""The survey's edge (issue 44, i44-edge): beyond the cloud's coverage the water grid is as empty as a lake that
mirrors every pulse; that emptiness is no gap that level water is joined across or a bridge deck spans
(``pipeline.survey_footprint``, ``beyond_coverage``, ``ClassifySettings.water_survey_coverage``)."""

from __future__ import annotations

import laspy
import numpy as np

from lidarctl import io, synthetic, tiles
from lidarctl.classify import pipeline as classify


def terraces_at_edge(seed: int = 7):
    """A field (200 x 100 m, 3 returns / m2, rising 2 % along u) whose coverage ends in teeth at v = 77.5-80 m for
    u < 170 m (a cross strip covers u > 170 m), with eight level patches 12 x 14 m (168 m2, each below
    ``level_water_min_area_m2``) along that edge, dark, at one level 0.5 m below the ground around them (v > 60 m):
    sunken yards or paddies running to the survey's edge. Returns (PointCloud, patch mask)."""
    rng = np.random.default_rng(seed)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    z = 100.0 + 0.02 * u + rng.normal(0, 0.02, n)
    tooth = (v > 77.5) & (np.mod(u, 12.0) < 2.5)
    keep = (u > 170) | ((v < 80) & ~tooth)
    patch = (v > 66) & (np.mod(u, 20.0) < 12) & (u < 160)
    z = np.where((v > 60) & (u < 160), 101.0 + rng.normal(0, 0.02, n), z)
    z = np.where(patch, 100.5 + rng.normal(0, 0.015, n), z)
    inten = np.where(patch, rng.normal(20, 5, n), rng.normal(150, 30, n)).clip(1, 1000)
    k = np.flatnonzero(keep)
    cloud = io.PointCloud(x=85000.0 + u[k], y=447000.0 + v[k], z=z[k], intensity=inten[k].astype(np.uint16),
                          return_number=np.ones(len(k), np.uint8), number_of_returns=np.ones(len(k), np.uint8),
                          classification=np.ones(len(k), np.uint8))
    return cloud, patch[k]


def test_level_patches_along_the_survey_edge_are_not_joined_across_the_band_beyond(tmp_path):
    cloud, patch = terraces_at_edge()
    args = (cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns, cloud.intensity)
    off = classify.classify_points(*args, params=classify.ClassifySettings(water_survey_coverage=False))
    # without the mask the band beyond the coverage joins the patches into one "lake" ...
    assert np.mean(off[patch] == classify.WATER) > 0.95
    # ... with it (the default) they stay what they are, whole and in tiles (the tiles' footprint is the cloud's)
    on = classify.classify_points(*args)
    assert not np.any(on == classify.WATER)
    src = tmp_path / "terraces.laz"
    synthetic.write_las(src, cloud, crs="EPSG:28992")
    tiles.classify_file(src, tmp_path / "tiled.laz", tile_size_m=100.0, buffer_m=30.0)
    assert not np.any(np.asarray(laspy.read(tmp_path / "tiled.laz").classification) == classify.WATER)


def test_survey_footprint():
    occ = np.ones((12, 14), bool)
    occ[6:9, 2:6] = False          # a lake that mirrored every pulse, enclosed by its shores
    occ[10, :6] = False            # a canal one cell wide running off the west edge
    occ[:4, 6:] = False            # the band beyond a strip's side along the south edge ...
    occ[3, 9] = True               # ... the last scan lines reaching into it in a tooth
    fp = classify.survey_footprint(occ)
    assert fp[6:9, 2:6].all() and fp[10, :6].all()
    assert not fp[:3, 6:].any() and not fp[3, 6:9].any() and fp[3, 9]
    # the water grid's cells beyond (2 m cells): the band's empty ones, not the lake's or the canal's
    count = np.repeat(np.repeat(occ.astype(int), 5, axis=0), 5, axis=1)
    beyond = classify.beyond_coverage(count, 2.0, 0.0, 0.0, fp, 0.0, 0.0)
    assert beyond[:15, 30:70].all() and not beyond[count > 0].any()
    assert not beyond[30:45, 10:30].any() and not beyond[50:55, :30].any()


def river_across_the_survey(width_m: float, seed: int = 5):
    """A field 300 x 160 m (3 returns / m2) crossed along u by a river ``width_m`` wide whose water returned no pulse,
    running off both ends of the survey, under a 10 m road deck 1.2 m above the quays at u = 140-150 m (ramps 15 m
    long). Returns x, y, z and the deck mask (reviewer 12d's scene)."""
    rng = np.random.default_rng(seed)
    n = 300 * 160 * 3
    u, v = rng.uniform(0, 300, n), rng.uniform(0, 160, n)
    river = (v > 60) & (v < 60 + width_m)
    road = (u > 140) & (u < 150)
    ramp = np.clip(1.0 - np.maximum(45 - v, v - (75 + width_m)) / 15.0, 0.0, 1.0)
    z = rng.normal(0, 0.02, n) + np.where(road, 1.2 * np.where(river, 1.0, np.where((v > 45) & (v < 75 + width_m),
                                                                                      ramp, 0.0)), 0.0)
    keep = ~river | road
    return 85000.0 + u[keep], 447000.0 + v[keep], z[keep], (road & river)[keep]


def test_a_river_crossing_the_survey_is_no_band_beyond_it():
    """A river 30-40 m wide crossing the survey is a channel between its banks, inside the footprint: its deck is
    found with the coverage mask (reviewer 12d: 0.97 -> 0.00 at 30 m); the ragged edge's band beyond stays out
    (the test above)."""
    p = classify.ClassifySettings()
    assert p.water_survey_coverage
    for width_m in (30.0, 40.0):
        x, y, z, deck = river_across_the_survey(width_m)
        found = classify.bridge_decks(x, y, z, np.ones(len(x), bool), np.zeros(len(x), bool), 1 / np.sqrt(3.0), p=p)
        assert found[deck].mean() > 0.9 and found[~deck].sum() < 0.05 * deck.sum()
    # the footprint: the channel is inside but within FOOTPRINT_CHANNEL_CELLS of the cloud's box
    occ = np.ones((16, 30), bool)
    occ[6:10, :] = False
    fp = classify.survey_footprint(occ)
    r = classify.FOOTPRINT_CHANNEL_CELLS
    assert fp[6:10, r:-r].all() and not fp[6:10, :2].any() and not fp[6:10, -2:].any()
