"""Water does not depend on the tile size (issue 44, i44-water): a river wider than a tile with its buffer and
a lake across a tile corner get the same water returns classified whole as in small tiles
(``lidarctl.tiles``: the tiles take the whole cloud's water cells and density, ``pipeline.WaterGrid``), and the
other classes stay what they were."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from lidarctl import io, synthetic, tiles
from lidarctl.classify import pipeline as classify

SIZE_M = 200.0


def scene(kind: str, seed: int = 5):
    """(PointCloud, truth water mask) on a 200 m square, 3 returns / m2 of dark water and bright land whose
    banks rise 1 m over 1 m, then 2 %. ``river``: 120 m wide across the square, falling 0.2 % along x, 95 % of
    its pulses lost; ``lake``: a calm lake of 60 m radius around the middle (the corner of four 100 m tiles) that
    returns the pulse, level to 1.5 cm; ``pond``: the same lake mirroring 95 % of the pulses away."""
    rng = np.random.default_rng(seed)
    n = int(SIZE_M * SIZE_M * 3.0)
    u, v = rng.uniform(0, SIZE_M, n), rng.uniform(0, SIZE_M, n)
    if kind == "river":
        level = 120.0 - 0.002 * u
        dist = np.maximum(40.0 - v, v - 160.0)
    else:
        level = np.full(n, 120.0)
        dist = np.hypot(u - SIZE_M / 2, v - SIZE_M / 2) - 60.0
    water = dist <= 0
    keep_share, noise = (1.0, 0.015) if kind == "lake" else (0.05, 0.03)
    keep = ~water | (rng.random(n) < keep_share)
    z = np.where(water, level, level + np.minimum(dist, 1.0) + 0.02 * np.maximum(dist - 1.0, 0.0))
    z = z + rng.normal(0.0, noise, n)
    intensity = np.where(water, rng.normal(20.0, 8.0, n), rng.normal(150.0, 30.0, n)).clip(1, 1000)
    k = np.flatnonzero(keep)
    cloud = io.PointCloud(x=500000.0 + u[k], y=4000000.0 + v[k], z=z[k], intensity=intensity[k].astype(np.uint16),
                          return_number=np.ones(len(k), np.uint8), number_of_returns=np.ones(len(k), np.uint8),
                          classification=np.ones(len(k), np.uint8))
    return cloud, water[k]


def big_lake_scene(kind: str, seed: int = 5, size_m: float = 480.0, radius_m: float = 170.0, density: float = 2.0,
                   land_features: bool = True):
    """(PointCloud, truth water, car park, forest floor): a level lake of ``radius_m`` in the middle of a square of
    ``size_m`` (``density`` returns / m2; banks 1 m over 1 m, then 2 %), returning the pulse (``lake``, level to
    1.5 cm) or mirroring 95 % of it away (``pond``); in two corners a dark level car park 0.15 m above its
    surroundings (50 x 30 m) and a level forest floor 0.3 m below them (50 x 50 m) under crowns (45 % of the
    pulses split on a crown 12-18 m up); ``land_features`` False: without those two (single returns only).
    ``bench/eval_water_tiles.py --big-lake`` runs the 340 m lake."""
    rng = np.random.default_rng(seed)
    n = int(size_m * size_m * density)
    u, v = rng.uniform(0, size_m, n), rng.uniform(0, size_m, n)
    dist = np.hypot(u - size_m / 2, v - size_m / 2) - radius_m
    water = dist <= 0
    keep_share, noise = (1.0, 0.015) if kind == "lake" else (0.05, 0.03)
    keep = ~water | (rng.random(n) < keep_share)
    land = 120.0 + np.minimum(dist, 1.0) + 0.02 * np.maximum(dist - 1.0, 0.0)
    park = (u > 0.02 * size_m) & (u < 0.02 * size_m + 50) & (v > 0.02 * size_m) & (v < 0.02 * size_m + 30)
    forest = (u > 0.98 * size_m - 50) & (u < 0.98 * size_m) & (v > 0.02 * size_m) & (v < 0.02 * size_m + 50)
    if not land_features:
        park[:] = False
        forest[:] = False
    z = np.where(water, 120.0, land)
    if land_features:
        z = np.where(park, float(np.median(land[park])) + 0.15, z)
        z = np.where(forest, float(np.median(land[forest])) - 0.3, z)
    z = z + rng.normal(0.0, noise, n)
    intensity = np.where(water | park, rng.normal(20.0, 8.0, n), rng.normal(150.0, 30.0, n)).clip(1, 1000)
    crown = forest & (rng.random(n) < 0.45)
    k, c = np.flatnonzero(keep), np.flatnonzero(crown)
    nr = np.r_[np.where(crown[k], 2, 1), np.full(len(c), 2)].astype(np.uint8)
    rn = np.r_[np.where(crown[k], 2, 1), np.ones(len(c))].astype(np.uint8)
    cloud = io.PointCloud(x=500000.0 + np.r_[u[k], u[c]], y=4000000.0 + np.r_[v[k], v[c]],
                          z=np.r_[z[k], z[c] + rng.uniform(12.0, 18.0, len(c))],
                          intensity=np.r_[intensity[k], rng.normal(90.0, 20.0, len(c)).clip(1, 1000)].astype(np.uint16),
                          return_number=rn, number_of_returns=nr, classification=np.ones(len(k) + len(c), np.uint8))
    pad = np.zeros(len(c), bool)
    return cloud, np.r_[water[k], pad], np.r_[park[k], pad], np.r_[forest[k], pad]


@pytest.mark.parametrize("kind", ["lake", "pond"])
def test_lake_larger_than_a_tile_and_its_buffer(tmp_path, kind):
    """A lake 170 m across in 40 m tiles with a 20 m buffer: the middle tiles' windows lie wholly on the water (no
    bank, no land to measure the darkness against). Their level regions take the whole cloud's level bodies
    (``pipeline.whole_level_bodies``) and the darkness the whole cloud's land (``WaterGrid.land_intensity``);
    before i44-edge the level lake lost 10 % of its returns in tiles (the 340 m bench lake: 20,151 of 182,381). The
    whole cloud's level bodies are an option (``water_whole_level_bodies``, off from review 15 -- the parent held
    every cell -- until level-wire found them tile by tile over the tiles' spooled cells: on by default)."""
    assert classify.ClassifySettings().water_whole_level_bodies
    cloud, truth, park, forest = big_lake_scene(kind, size_m=240.0, radius_m=85.0, density=1.5)
    src = tmp_path / f"{kind}.laz"
    synthetic.write_las(src, cloud, crs="EPSG:32610")
    whole_cls = classify.classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns,
                                         cloud.intensity)
    whole = whole_cls == classify.WATER
    tiles.classify_file(src, tmp_path / "tiled.laz", params=classify.ClassifySettings(water_whole_level_bodies=True),
                        tile_size_m=40.0, buffer_m=20.0)
    tiled_cls = np.asarray(laspy.read(tmp_path / "tiled.laz").classification)
    tiled = tiled_cls == classify.WATER
    for w in (whole, tiled):
        assert np.mean(w[truth]) >= 0.95 and np.mean(truth[w]) >= 0.95, (w[truth].mean(), truth[w].mean())
        assert not w[park].any() and not w[forest].any()
    # the returns the noise filter flags in one run and not in the other (its own tile effect: 22 of the pond's
    # 28 differing returns) aside
    noise = np.isin(whole_cls, (7, 18)) | np.isin(tiled_cls, (7, 18))
    assert np.sum((whole != tiled) & ~noise) <= 0.01 * truth.sum(), (whole.sum(), tiled.sum())


@pytest.mark.parametrize("kind, tile_m, buffer_m", [("river", 60.0, 30.0), ("lake", 100.0, 40.0),
                                                    ("pond", 100.0, 40.0)])
def test_water_does_not_depend_on_the_tile_size(tmp_path, kind, tile_m, buffer_m):
    cloud, truth = scene(kind)
    src = tmp_path / f"{kind}.laz"
    synthetic.write_las(src, cloud, crs="EPSG:32610")
    whole = classify.classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns,
                                     cloud.intensity)
    stats = tiles.classify_file(src, tmp_path / "tiled.laz", tile_size_m=tile_m, buffer_m=buffer_m)
    assert stats.run.n_tiles == (16 if kind == "river" else 4)   # the lakes: across the corner of four tiles
    tiled = np.asarray(laspy.read(tmp_path / "tiled.laz").classification)
    w_whole, w_tiled = whole == classify.WATER, tiled == classify.WATER
    # the whole cloud finds the water ...
    assert np.mean(w_whole[truth]) >= 0.95 and np.mean(truth[w_whole]) >= 0.95, (w_whole[truth].mean(),
                                                                                  truth[w_whole].mean())
    # ... and the tiles the same returns (a few at the tile edges may differ, as other classes do)
    assert np.sum(w_whole != w_tiled) <= 0.01 * truth.sum(), (w_whole.sum(), w_tiled.sum())
    other = (whole != tiled) & ~w_whole & ~w_tiled
    assert other.sum() <= 0.001 * len(whole), other.sum()


def test_water_grid_of_the_tiles_is_the_whole_clouds(tmp_path):
    """``tiles.water_grid``: the cell, origin and median returns per cell that ``dropout_grid`` takes for the
    whole cloud."""
    cloud, _ = scene("river")
    src = tmp_path / "river.laz"
    synthetic.write_las(src, cloud, crs="EPSG:32610")
    las = laspy.read(src)
    x, y = np.asarray(las.x), np.asarray(las.y)
    p = classify.ClassifySettings()
    spacing = classify.grid.mean_spacing_m(x, y)
    g = classify.dropout_grid(x, y, np.zeros(len(x), bool), spacing, p)
    with laspy.open(src) as f:
        grid = tiles.plan_tiles(f.header, tile_size_m=60.0, buffer_m=30.0)
    lowest = []
    tasks = tiles.split_into_tiles([src], grid, tmp_path, p, lowest=lowest)
    from aerotri.core.executor import local_executor

    p = classify.ClassifySettings(water_whole_level_bodies=False)
    wg = tiles.water_grid(tasks, grid, p, lowest, local_executor())
    # the land's reflectance without the cells spooled as with them (the level bodies' option, the default)
    with_bodies = tiles.water_grid(tasks, grid, classify.ClassifySettings(), lowest, local_executor())
    assert np.isfinite(wg.land_intensity) and wg.land_intensity == with_bodies.land_intensity
    assert wg.level_bodies is None and with_bodies.level_bodies is not None
    assert (wg.x0_m, wg.y0_m) == (g.x0, g.y0)
    assert wg.cell_m == pytest.approx(g.c, rel=1e-12)
    assert wg.median_count == g.median_count
    # the survey's footprint (i44-edge): the tiles' 10 m cells are the whole cloud's
    assert np.array_equal(wg.footprint_10m, classify.survey_footprint(classify.occupied_10m(x, y, g.x0, g.y0)))
