"""The ground filters (lidarctl.classify.ground): the registry, and the methods added for the AHN3 and simulator
misses, each against a synthetic scene with known truth.

* a filter registered in a test runs through the whole classification (``classify_file``),
* noise-scaled ground tolerance (kerbs and low vegetation 15-30 cm above precise ground),
* raised-plateau test (a low wide roof the morphological opening cannot lift, here at a tile corner),
* low-outlier scraps at mixed depths under a pond (outliers below outliers),
* roof-edge completion (a lean-to roof sloping down below the building height threshold).
"""

import dataclasses

import numpy as np
import pytest

from aerotri.core.errors import ConfigError, OptionError
from aerotri.core.settings import from_table
from lidarctl import grid, io, synthetic, tiles
from lidarctl.classify import pipeline as classify
from lidarctl.classify import ground
from lidarctl.classify import noise


@dataclasses.dataclass(frozen=True)
class LowestParams:
    cell_m: float = 5.0


def lowest_per_cell_ground(x, y, z, p: LowestParams) -> np.ndarray:
    """A trivial ground filter: the lowest point of each ``cell_m`` cell (cells on multiples of cell_m)."""
    x0, y0 = np.floor(np.min(x) / p.cell_m) * p.cell_m, np.floor(np.min(y) / p.cell_m) * p.cell_m
    ground_mask = np.zeros(len(x), bool)
    ground_mask[grid.lowest_per_cell(grid.cell_ids(x, y, p.cell_m, x0, y0)[0], z)] = True
    return ground_mask


def _cells(x, y, cell_m):
    return np.floor(x / cell_m).astype(np.int64) * 10_000_000 + np.floor(y / cell_m).astype(np.int64)


def test_the_registry_names_the_filters_their_presets_and_reach():
    assert list(ground.GROUND_FILTERS) == ["morph", "ptd", "slope"]
    assert ground.preset_names() == ("urban", "rural", "forest", "mountain")
    assert ground.reach_m() == 60.0 and ground.reach_m("morph", "rural") == 50.0
    assert ground.reach_m("ptd") == 30.0 and ground.reach_m("ptd", "rural", seed_cell_m=40.0) == 60.0
    with pytest.raises(OptionError, match="expected one of morph, ptd, slope") as e:
        classify.ClassifySettings(ground_method="csf")
    assert e.value.param == "--method"


def test_a_registered_filter_runs_through_classify_file(tmp_path, monkeypatch):
    """One registry line makes a new filter usable by the classifier, its settings and the tiling."""
    entry = ground.GroundFilter(LowestParams, lowest_per_cell_ground, reach_m=lambda p: p.cell_m,
                                presets={"coarse": LowestParams(cell_m=10.0)}, help="lowest point per cell")
    monkeypatch.setitem(ground.GROUND_FILTERS, "lowest", entry)
    cloud, _ = synthetic.synthetic_scene(width_m=120.0, density_per_m2=3.0, seed=7, n_low_outliers=0,
                                         n_high_outliers=0)
    synthetic.write_las(tmp_path / "in.las", cloud, crs="EPSG:32632")
    stats = tiles.classify_file(tmp_path / "in.las", tmp_path / "out.las",
                                params=classify.ClassifySettings(ground_method="lowest"))
    assert stats.run.n_tiles == 1 and stats.grid.buffer_m == 5.0       # the filter's reach sets the buffer
    out = io.read_cloud(tmp_path / "out.las")
    cls = out.classification
    cell = _cells(out.x, out.y, 5.0)
    # Ground: the lowest last return of each cell among the points that are not noise, one per cell.
    candidate = ~np.isin(cls, (7, 18)) & (out.return_number >= out.number_of_returns)
    g = np.flatnonzero(cls == 2)
    assert len(np.unique(cell[g])) == len(g)
    order = np.lexsort((out.z[candidate], cell[candidate]))
    lowest = np.flatnonzero(candidate)[order][np.r_[True, np.diff(cell[candidate][order]) != 0]]
    assert set(g) <= set(lowest) and len(g) >= 0.95 * len(lowest)
    # Its preset, tiled: the buffer is the preset's reach (10 m), at most one ground point per 10 m cell.
    stats = tiles.classify_file(tmp_path / "in.las", tmp_path / "tiled.las", tile_size_m=40.0,
                                params=classify.ClassifySettings(ground_method="lowest", preset="coarse"))
    assert stats.run.n_tiles == 9 and stats.grid.buffer_m == 10.0
    tiled = io.read_cloud(tmp_path / "tiled.las")
    cell10 = _cells(tiled.x, tiled.y, 10.0)[tiled.classification == 2]
    assert len(np.unique(cell10)) == len(cell10) >= 0.95 * len(np.unique(_cells(tiled.x, tiled.y, 10.0)))
    # A preset of another filter, or an unregistered filter, is refused naming the option or the key.
    with pytest.raises(OptionError, match="'lowest' ground filter has the presets coarse") as e:
        classify.ClassifySettings(ground_method="lowest", preset="urban")
    assert e.value.param == "--preset"
    monkeypatch.delitem(ground.GROUND_FILTERS, "lowest")
    with pytest.raises(OptionError, match="'lowest': expected one of morph, ptd"):
        classify.ClassifySettings(ground_method="lowest")
    with pytest.raises(ConfigError, match=r"\[classify\] ground_method = 'lowest': expected one of morph, ptd"):
        from_table(classify.ClassifySettings, {"ground_method": "lowest"}, "p.toml [classify]")


def _flat_terrain(rng, width_m, density, sigma_m):
    n = int(width_m * width_m * density)
    x, y = rng.uniform(0, width_m, n), rng.uniform(0, width_m, n)
    z = 10.0 + 0.01 * x + rng.normal(0, sigma_m, n)
    return x, y, z


def test_refine_tolerance_follows_the_sensor_noise():
    rng = np.random.default_rng(0)
    # 4.5 x MAD-sigma, clipped to [0.1, 0.3] m (a few object residuals do not move the MAD).
    res = np.r_[rng.normal(0, 0.02, 5000), rng.uniform(0.1, 0.5, 300)]
    assert 0.1 <= ground.refine_tolerance_m(res, 4.5, 0.1, 0.3) < 0.12
    assert ground.refine_tolerance_m(rng.normal(0, 0.1, 5000), 4.5, 0.1, 0.3) == 0.3
    assert ground.refine_tolerance_m(rng.normal(0, 0.001, 5000), 4.5, 0.1, 0.3) == 0.1


def test_kerbs_and_low_objects_are_not_ground_on_precise_data():
    rng = np.random.default_rng(1)
    x, y, z = _flat_terrain(rng, 120.0, 6.0, 0.02)
    # Kerbs (0.3 m wide lines) and sparse low vegetation: 0.15-0.3 m above the ground.
    k = 360
    kx = np.r_[rng.uniform(10, 110, k), rng.uniform(0, 120, 2000)]
    ky = np.r_[np.where(rng.random(k) < 0.5, 40.0, 80.0) + rng.uniform(0, 0.3, k), rng.uniform(0, 120, 2000)]
    kz = 10.0 + 0.01 * kx + rng.uniform(0.15, 0.3, len(kx))
    g = ground.ground_filter(np.r_[x, kx], np.r_[y, ky], np.r_[z, kz])
    assert np.mean(g[:len(x)]) > 0.99
    assert np.mean(g[len(x):]) < 0.05


def _scene_with_corner_roof(rng, height_m):
    x, y, z = _flat_terrain(rng, 150.0, 4.0, 0.03)
    on_roof = (x < 30.0) & (y < 30.0)          # a flat roof filling the tile corner
    z = np.where(on_roof, 10.0 + 0.01 * x + height_m + rng.normal(0, 0.03, len(x)), z)
    return x, y, z, on_roof


def test_low_wide_roof_at_tile_corner_is_not_ground():
    rng = np.random.default_rng(2)
    x, y, z, on_roof = _scene_with_corner_roof(rng, 3.0)
    # Without the plateau test the opening keeps the roof: 3 m < slope 0.3 x window radius.
    g0 = ground.ground_filter(x, y, z, plateau_min_step_m=0.0)
    assert np.mean(g0[on_roof]) > 0.9
    g = ground.ground_filter(x, y, z)
    assert np.mean(g[on_roof]) < 0.01
    assert np.mean(g[~on_roof]) > 0.99
    # The same with the progressive TIN densification.
    g = ground.ground_filter(x, y, z, method="ptd")
    assert np.mean(g[on_roof]) < 0.01


def test_terrace_levels_of_similar_size_stay_ground():
    rng = np.random.default_rng(3)
    x, y, z = _flat_terrain(rng, 120.0, 3.0, 0.03)
    upper = x < 60.0                            # a 4 m retaining wall splits two terrain levels
    z = np.where(upper, z + 4.0, z)
    g = ground.ground_filter(x, y, z)
    assert np.mean(g[upper]) > 0.98 and np.mean(g[~upper]) > 0.98


def test_pond_outliers_at_mixed_depths_are_flagged():
    cloud, truth = synthetic.synthetic_scene(width_m=150.0, density_per_m2=3.0, seed=4, n_low_outliers=0,
                                             n_high_outliers=0)
    rng = np.random.default_rng(5)
    # A pond: sparse water returns, and more multipath points than water returns below it,
    # 40-110 m deep, every depth supported by another outlier near it.
    k = 60
    px = cloud.x.min() + 60 + rng.uniform(0, 30, k)
    py = cloud.y.min() + 60 + rng.uniform(0, 18, k)
    pz = synthetic.terrain_height(px - 500000.0, py - 5400000.0) - rng.uniform(40, 110, k)
    code = noise.detect_noise(np.r_[cloud.x, px], np.r_[cloud.y, py], np.r_[cloud.z, pz])
    assert np.all(code[-k:] > 0)
    assert np.mean(code[:-k] > 0) < 0.001
    assert np.all(code[:-k][truth == 2] == 0)


def test_roof_edge_completion_follows_the_roof_plane_not_the_tree():
    rng = np.random.default_rng(6)
    n = 6000
    # Roof plane z = 8 - 0.5 u over u in [0, 14] m (it sinks to 1 m above the ground at u = 14),
    # known building points only where u < 6; a tree crown beside the eave for v > 12.
    u, v = rng.uniform(0, 14, n), rng.uniform(0, 12, n)
    zr = 8.0 - 0.5 * u + rng.normal(0, 0.02, n)
    m = 1500
    tu, tv = rng.uniform(0, 14, m), rng.uniform(12.3, 20, m)
    tz = rng.uniform(2.0, 9.0, m)
    x, y, z = np.r_[u, tu], np.r_[v, tv], np.r_[zr, tz]
    is_building = np.r_[u < 6.0, np.zeros(m, bool)]
    candidates = ~is_building
    classify.roof_edge_completion(x, y, z, is_building, candidates, classify.ClassifySettings(edge_iterations=40))
    assert np.mean(is_building[:n]) > 0.97
    assert np.mean(is_building[n:]) < 0.02


def test_a_cloud_narrower_than_two_cells_is_filtered_not_a_traceback():
    """A strip 0.9 m wide (one DEM cell across) ended in numpy.gradient's ValueError (exit 1, traceback); the slope
    across a side of one cell is unknown and taken as 0, the slope along it is the terrain's."""
    from lidarctl.classify.ground import morphological_ground
    from lidarctl.raster_ops import slope_tan

    rng = np.random.default_rng(3)
    y = rng.uniform(0, 200, 400)
    x = rng.uniform(0, 0.9, 400)
    z = 100.0 + 0.05 * y + rng.normal(0, 0.02, 400)
    z[:5] += 6.0                      # a few returns from a crown over the strip
    ground = morphological_ground(x, y, z)
    assert ground[5:].mean() > 0.95 and not ground[:5].any()
    column = (100.0 + 0.05 * np.arange(10.0))[:, None]
    np.testing.assert_allclose(slope_tan(column, 1.0), 0.05)
    np.testing.assert_allclose(slope_tan(column.T, 1.0), 0.05)
