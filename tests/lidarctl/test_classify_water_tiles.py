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

    wg = tiles.water_grid(tasks, grid, p, lowest, local_executor())
    assert (wg.x0_m, wg.y0_m) == (g.x0, g.y0)
    assert wg.cell_m == pytest.approx(g.c, rel=1e-12)
    assert wg.median_count == g.median_count
