"""Classes do not depend on the tile size when the buffer covers the filters' reach (tile-phase): every tile's
grids lie on the whole cloud's cells (``grid.CloudFrame``), its cell sizes come from the whole cloud's point
spacing and its ground tolerances from the whole cloud's noise (``tiles.cloud_noise``)."""

import laspy
import numpy as np
import pytest

from aerotri.core.executor import Executor
from lidarctl import grid, raster_ops, synthetic, tiles


def test_tiled_classes_equal_the_whole_cloud_s(tmp_path):
    # 200 m x 200 m, 2.5 points/m2 (~100 k points); 3 x 3 tiles of 70 m + the default 60 m buffer (the ground
    # filter's reach). Before: 27 points differed (vegetation <-> unclassified at tree edges, a ground point), all
    # over the area: each tile's grids started at its window's lowest corner, its cells were 2 spacings of its
    # window, its ground tolerances its window's noise.
    cloud, _ = synthetic.synthetic_scene(width_m=200.0, density_per_m2=2.5, seed=5, n_buildings=6, n_trees=40)
    synthetic.write_las(tmp_path / "in.laz", cloud, crs="EPSG:32632")
    whole = tiles.classify_file(tmp_path / "in.laz", tmp_path / "whole.laz")
    with Executor("synchronous") as ex:
        tiled = tiles.classify_file(tmp_path / "in.laz", tmp_path / "tiled.laz", tile_size_m=70.0, executor=ex)
    assert whole.run.n_tiles == 1 and tiled.run.n_tiles == 9 and tiled.grid.buffer_m == 60.0
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
