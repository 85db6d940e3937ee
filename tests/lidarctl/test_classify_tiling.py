"""Classes do not depend on the tile size when the buffer covers the filters' reach (tile-phase): every tile's
grids lie on the whole cloud's cells (``grid.CloudFrame``), its cell sizes come from the whole cloud's point
spacing and its ground tolerances from the whole cloud's noise (``tiles.cloud_noise``)."""

import laspy
import numpy as np
import pytest

from aerotri.core.executor import Executor
from lidarctl import grid, raster_ops, synthetic, tiles


def test_a_window_denser_or_sparser_than_the_cloud_refines_the_ground_on_the_whole_cloud_s_surface(tmp_path, caplog):
    # The ground filter refines on a grid of mean ground heights where the ground holds at least
    # dense_points_per_cell (3) points per 1 m cell, else on a TIN. A cloud whose western half is thinned to 1.5
    # points/m2 (east 5): the whole cloud takes the means, the western tiles' windows alone would take the TIN, which
    # changed the refine residuals' spread (the whole cloud's ground tolerance) and those tiles' ground: 9 points
    # differed here (the demo's strips in 430 m tiles: 974 of 4.94 M, all over the block). Now the choice is the
    # whole cloud's (``grid.CloudFrame.refine_dense``) and the western tiles find their residuals again on it.
    import dataclasses
    import logging

    cloud, _ = synthetic.synthetic_scene(width_m=200.0, density_per_m2=5.0, seed=5, n_buildings=6, n_trees=40)
    thin = (cloud.x - cloud.x.min() >= 100.0) | (np.random.default_rng(1).random(len(cloud.x)) < 0.3)
    cloud = dataclasses.replace(cloud, **{f.name: getattr(cloud, f.name)[thin] for f in dataclasses.fields(cloud)
                                         if isinstance(getattr(cloud, f.name), np.ndarray)})
    synthetic.write_las(tmp_path / "in.laz", cloud, crs="EPSG:32632")
    whole = tiles.classify_file(tmp_path / "in.laz", tmp_path / "whole.laz")
    with Executor("synchronous") as ex, caplog.at_level(logging.DEBUG, logger="lidarctl.tiles"):
        tiled = tiles.classify_file(tmp_path / "in.laz", tmp_path / "tiled.laz", tile_size_m=70.0, executor=ex)
    assert whole.run.n_tiles == 1 and tiled.run.n_tiles == 9
    assert "3 of 9 tiles find their refine residuals again on the whole cloud's mean surface" in caplog.text
    a = np.asarray(laspy.read(tmp_path / "whole.laz").classification)
    b = np.asarray(laspy.read(tmp_path / "tiled.laz").classification)
    assert np.count_nonzero(a != b) == 0


def test_grids_of_a_window_lie_on_the_whole_cloud_s_cells():
    frame = grid.CloudFrame(x0_m=1000.0, y0_m=2000.0, spacing_m=0.3)
    x, y = np.array([1010.37, 1020.0]), np.array([2003.1, 2010.0])
    assert grid.origin(x, y, 0.7) == (1010.37, 2003.1)          # outside a frame: the points' lowest corner
    with grid.whole_cloud(frame):
        x0, y0 = grid.origin(x, y, 0.7)
        assert x0 == pytest.approx(1000.0 + 14 * 0.7) and y0 == pytest.approx(2000.0 + 4 * 0.7)
        assert grid.lattice_offset(x0, y0, 0.7) == (4, 14)
        assert grid.cloud_spacing_m(x, y) == 0.3
        i, j, *_ = grid.cell_indices(x, y, 0.7)
        np.testing.assert_array_equal(j, np.floor((x - 1000.0) / 0.7) - 14)
        np.testing.assert_array_equal(i, np.floor((y - 2000.0) / 0.7) - 4)


def test_pull_push_fill_of_a_window_is_the_whole_grid_s_inside_its_blocks():
    rng = np.random.default_rng(1)
    whole = rng.normal(size=(64, 64))
    whole[rng.random(whole.shape) < 0.6] = np.nan
    whole[10:30, 20:50] = np.nan                                  # a roof: filled from coarse blocks
    filled = raster_ops.fill_nodata(whole)
    window = raster_ops.fill_nodata(whole[5:, 3:], offset=(5, 3))
    # the blocks of 32 cells wholly inside the window: the same values
    np.testing.assert_array_equal(window[32 - 5:, 32 - 3:], filled[32:, 32:])
    assert not np.array_equal(raster_ops.fill_nodata(whole[5:, 3:])[32 - 5:, 32 - 3:], filled[32:, 32:])


def test_tiles_side_by_side_as_many_as_the_memory_holds():
    # the demo-like case: a 6.5 M and a 2.45 M point tile, memory for 8 M points: one at a time
    assert tiles.tiles_at_once([2_450_351, 6_509_629], 2, 8.0e6) == 1
    assert tiles.tiles_at_once([2_152_380, 2_125_541, 1_704_432], 2, 4.3e6) == 2
    assert tiles.tiles_at_once([100, 90, 80], 4, float("inf")) == 3     # never more than the tiles
    assert tiles.tiles_at_once([5_000_000], 2, 0.0) == 1                 # at least one, whatever the memory
    assert tiles.tile_points_in_memory(2, float("inf")) == tiles.DEFAULT_TILE_POINTS
    assert tiles.tile_points_in_memory(2, 9.0e6) == tiles.DEFAULT_TILE_POINTS
    assert tiles.tile_points_in_memory(2, 3.88e6) == 1_940_000


def test_under_a_memory_limit_the_tiles_shrink_and_run_one_at_a_time_with_the_same_classes(tmp_path, monkeypatch,
                                                                                         caplog):
    """A process allowed memory for 60,000 tile points beside the 50 MB it holds (a batch job's limit, simulated)
    classifies a 100,000-point cloud in small tiles, one at a time, instead of the whole cloud at once (the default
    without a limit), and says so; the classes are the whole cloud's."""
    import logging

    from aerotri.core import limits

    cloud, _ = synthetic.synthetic_scene(width_m=500.0, density_per_m2=0.4, seed=5, n_buildings=12, n_trees=60)
    synthetic.write_las(tmp_path / "in.laz", cloud, crs="EPSG:32632")
    with Executor(workers=2) as ex:
        whole = tiles.classify_file(tmp_path / "in.laz", tmp_path / "whole.laz", executor=ex)
        held = 50e6
        monkeypatch.setattr(limits, "resident_bytes", lambda: int(held))
        monkeypatch.setattr(limits, "usable_memory_bytes",
                            lambda: int((held + 60_000 * tiles.CLASSIFY_BYTES_PER_POINT) / 0.9) + 1)
        with caplog.at_level(logging.INFO, logger="lidarctl.tiles"):
            limited = tiles.classify_file(tmp_path / "in.laz", tmp_path / "limited.laz", executor=ex)
    # about 30,000 points a tile asked for at the mean density: 3 x 3 tiles of 170 m with their 60 m buffers
    assert whole.run.n_tiles == 1 and limited.grid.tile_m == 170.0 and limited.run.n_tiles == 9
    said = caplog.text
    assert "tiles of about 30,000 points with their buffers (default 4,000,000): 2 side by side fit" in said
    # the two largest windows hold more than 60,000 points together: one tile at a time
    assert "tiles: 1 at a time of 2 workers" in said and limited.run.max_tile_points > 30_000
    a = np.asarray(laspy.read(tmp_path / "whole.laz").classification)
    b = np.asarray(laspy.read(tmp_path / "limited.laz").classification)
    assert np.count_nonzero(a != b) == 0


def test_a_small_cloud_under_a_memory_limit_keeps_its_default_tiles(tmp_path, monkeypatch):
    """Tiles whose buffered windows would each hold more than half the cloud save no memory: the default plan stays
    (AHN3 Delft's crop at 400 MiB: two tiles each nearly the whole cloud, where the whole cloud fits)."""
    from aerotri.core import limits

    cloud, _ = synthetic.synthetic_scene(width_m=200.0, density_per_m2=2.5, seed=5, n_buildings=6, n_trees=40)
    synthetic.write_las(tmp_path / "in.laz", cloud, crs="EPSG:32632")
    monkeypatch.setattr(limits, "resident_bytes", lambda: 50_000_000)
    monkeypatch.setattr(limits, "usable_memory_bytes", lambda: 100_000_000)
    with Executor(workers=2) as ex:
        run = tiles.classify_file(tmp_path / "in.laz", tmp_path / "out.laz", executor=ex)
    assert run.run.n_tiles == 1


@pytest.mark.parametrize("cloud_kind", ["returns", "single_returns", "lift_test_off"])
def test_the_rooftop_rule_takes_the_whole_cloud_s_range_noise(tmp_path, monkeypatch, cloud_kind):
    # The rooftop-object rule cuts a roof's objects at steps of 3 sigma of the ground's range noise. It took sigma
    # per window, on a sample of the window's ground: AHN3 Delft in 80 m tiles 0.0104-0.0191 m in its 9 windows
    # against 0.0163 m whole, and 8 building <-> vegetation returns differed from the whole cloud's (2 in 150 m
    # tiles). Now it is the lifted-ground test's figure, which a tile takes from the whole cloud: one value for
    # every window, the whole cloud's; also without return numbers (a photogrammetric or single-return cloud: the
    # lift test judges nothing) and with the lift test off (ground_lift_sigma 0), where a tile fell back to its own.
    # And the classes of the 3 x 3 tiles equal the whole cloud's (200 m x 200 m, 2.5 points/m2, about 100 k points;
    # tiles of 70 m and the default 60 m buffer, the ground filter's reach). Before: 27 points differed
    # (vegetation <-> unclassified at tree edges, a ground point), all over the area: each tile's grids started at
    # its window's lowest corner, its cells were 2 spacings of its window, its ground tolerances its window's noise.
    import dataclasses

    from lidarctl.classify import pipeline

    seen = []
    rooftop_objects = pipeline.rooftop_objects

    def spy(x, y, z, is_building, spacing_m, noise_m, **kw):
        seen.append(noise_m)
        return rooftop_objects(x, y, z, is_building, spacing_m, noise_m, **kw)

    monkeypatch.setattr(pipeline, "rooftop_objects", spy)
    cloud, _ = synthetic.synthetic_scene(width_m=200.0, density_per_m2=2.5, seed=5, n_buildings=6, n_trees=40)
    if cloud_kind == "single_returns":
        cloud = dataclasses.replace(cloud, return_number=np.ones_like(cloud.return_number),
                                    number_of_returns=np.ones_like(cloud.number_of_returns))
    params = pipeline.ClassifySettings(ground_lift_sigma=0.0) if cloud_kind == "lift_test_off" else \
        pipeline.ClassifySettings()
    synthetic.write_las(tmp_path / "in.laz", cloud, crs="EPSG:32632")
    with Executor("synchronous") as ex:
        run_whole = tiles.classify_file(tmp_path / "in.laz", tmp_path / "whole.laz", executor=ex, params=params)
        whole = list(seen)
        seen.clear()
        run_tiled = tiles.classify_file(tmp_path / "in.laz", tmp_path / "tiled.laz", tile_size_m=70.0, executor=ex,
                                        params=params)
    assert run_whole.run.n_tiles == 1 and run_tiled.run.n_tiles == 9 and run_tiled.grid.buffer_m == 60.0
    assert len(whole) == 1 and len(seen) == 9
    assert seen == pytest.approx([whole[0]] * 9, rel=1e-12)
    # the figure is the lifted-ground test's: the ground's robust spread about its local planes (1.4826 MAD)
    assert 0.005 < whole[0] < 0.2
    a = np.asarray(laspy.read(tmp_path / "whole.laz").classification)
    assert np.count_nonzero(a != np.asarray(laspy.read(tmp_path / "tiled.laz").classification)) == 0
