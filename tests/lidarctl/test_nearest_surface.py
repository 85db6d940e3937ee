"""The surface at the cell centres from the nearest return (``lidarctl.rasters.nearest``) on a box building."""

import numpy as np
import pytest
import shapely

from lidarctl.rasters.nearest import nearest_return_surface

RES_M, N, SPACING_M, ROOF_M = 0.5, 80, 0.75, 10.0


def _box_block(seed: int):
    """Returns on a jittered 0.75 m lattice (the demo's spacing) over a 20 x 12 m box building 10 m high, at an
    angle to the 0.5 m grid; the grid's cell centres and which of them the roof covers (the truth)."""
    rng = np.random.default_rng(seed)
    box = shapely.affinity.rotate(shapely.box(-10, -6, 10, 6), 30 + 10 * seed, origin=(0, 0))
    g = np.arange(-30, 30, SPACING_M)
    gx, gy = np.meshgrid(g, g)
    x = gx.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.13
    y = gy.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.07
    z = np.where(shapely.contains_xy(box, x, y), ROOF_M, 0.0)
    cx, cy = np.meshgrid(-20 + (np.arange(N) + 0.5) * RES_M, 20 - (np.arange(N) + 0.5) * RES_M)
    return box, x, y, z, cx, cy, shapely.contains_xy(box, cx, cy)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_roof_edge_within_a_cell_and_as_wide_as_the_roof(seed):
    box, x, y, z, cx, cy, truth = _box_block(seed)
    surface = nearest_return_surface(x, y, z, x0_m=-20.0, y_top_m=20.0, res_m=RES_M, nrows=N, ncols=N, max_dist_m=5.0)
    assert np.isfinite(surface).all()
    roof = surface > ROOF_M / 2
    wrong = roof != truth
    # every centre on the wrong side of the wall lies within one cell of it
    assert shapely.distance(box.exterior, shapely.points(cx[wrong], cy[wrong])).max() < RES_M
    assert abs(int(roof.sum()) - int(truth.sum())) < 0.03 * truth.sum()


def test_nearest_within_reach_and_ties_take_the_higher_return():
    # centres of a 1 x 3 grid of 1 m cells at x = 0.5, 1.5, 2.5; returns at x = 0.5 (z 1) and x = 2.5 (z 2, 3)
    x, y, z = np.array([0.5, 2.5, 2.5]), np.array([0.5, 0.5, 0.5]), np.array([1.0, 2.0, 3.0])
    s = nearest_return_surface(x, y, z, x0_m=0.0, y_top_m=1.0, res_m=1.0, nrows=1, ncols=3, max_dist_m=1.5)
    assert s.tolist() == [[1.0, 3.0, 3.0]]
    s = nearest_return_surface(x[:1], y[:1], z[:1], x0_m=0.0, y_top_m=1.0, res_m=1.0, nrows=1, ncols=3,
                               max_dist_m=1.5)
    assert s[0, :2].tolist() == [1.0, 1.0] and np.isnan(s[0, 2])
