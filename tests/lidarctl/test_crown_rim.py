"""Tree crowns of the nearest-return surface within the cells they cover (``lidarctl.rasters.crown_rim``)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidarctl.rasters.crown_rim import (MOST_OF_THE_CELL, SUB_CELLS, WHOLE_CELL, crown_sub_cells, crown_sub_cells_beside,
                                       crowns_within_cells)
from lidarctl.rasters.nearest import nearest_return_surface

RES_M, N, SPACING_M, TOP_M = 0.5, 80, 0.75, 12.0
CROWNS = ((0.3, -0.2, 4.0), (-9.1, 7.7, 2.6), (8.4, 9.3, 3.3))  # (x, y, radius) m


def _crown_block(seed: int):
    """First returns on a jittered 0.75 m lattice (the demo's spacing) over three round crowns (class 5, 12 m) on
    the ground (class 2, 0 m); the grid's 0.1 m sample points per cell and which of them a crown covers."""
    rng = np.random.default_rng(seed)
    g = np.arange(-30, 30, SPACING_M)
    gx, gy = np.meshgrid(g, g)
    x = gx.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.13
    y = gy.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.07
    inside = np.zeros(x.size, bool)
    for cx, cy, r in CROWNS:
        inside |= np.hypot(x - cx, y - cy) < r
    off = (np.arange(SUB_CELLS) + 0.5) / SUB_CELLS * RES_M
    sx = -20 + (np.arange(N)[:, None] * RES_M + off).ravel()
    sy = 20 - (np.arange(N)[:, None] * RES_M + off).ravel()
    px, py = np.meshgrid(sx, sy)
    covered = np.zeros(px.shape, bool)
    for cx, cy, r in CROWNS:
        covered |= np.hypot(px - cx, py - cy) < r
    return x, y, np.where(inside, TOP_M, 0.0), np.where(inside, 5, 2), px, py, covered


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_crown_columns_stay_within_the_crowns(seed):
    x, y, z, cls, px, py, covered = _crown_block(seed)
    kw = {"x0_m": -20.0, "y_top_m": 20.0, "res_m": RES_M}
    nearest = nearest_return_surface(x, y, z, nrows=N, ncols=N, max_dist_m=5.0, **kw)
    got = crowns_within_cells(x, y, z, cls, nearest, min_share=WHOLE_CELL, **kw)
    truth_area = covered.sum()

    def spill_and_cover(surface):
        column = np.repeat(np.repeat(surface > TOP_M / 2, SUB_CELLS, 0), SUB_CELLS, 1)
        return (column & ~covered).sum() / truth_area, (column & covered).sum() / truth_area

    main_spill, main_cover = spill_and_cover(nearest)
    spill, cover = spill_and_cover(got)
    # the whole-cell columns of the nearest-return surface spill beyond the crowns (5-6 % of their area); within
    # the cells the returns say the crown covers, about a fifth of that; the crowns' rims give up 10-12 % of them
    assert main_spill > 0.04
    assert spill < 0.3 * main_spill
    assert 0.78 < cover <= main_cover
    # every sub-cell centre of a column is nearer a vegetation return than any other return (the Voronoi rim)
    column = np.repeat(np.repeat(got > TOP_M / 2, SUB_CELLS, 0), SUB_CELLS, 1)
    _, k = cKDTree(np.c_[x, y]).query(np.c_[px[column], py[column]])
    assert (cls[k] == 5).all()
    # cells lowered take the ground's height (the nearest return that is not vegetation); the rest are unchanged
    changed = got != nearest
    assert changed.any() and (got[changed] == 0.0).all() and (nearest[changed] == TOP_M).all()


def test_cells_with_no_other_return_near_keep_the_crown():
    # one crown return and nothing else within reach: the crown's inside, kept
    x, y, z, cls = np.array([0.6]), np.array([0.4]), np.array([TOP_M]), np.array([5])
    nearest = nearest_return_surface(x, y, z, x0_m=0.0, y_top_m=1.0, res_m=RES_M, nrows=2, ncols=2, max_dist_m=5.0)
    got = crowns_within_cells(x, y, z, cls, nearest, x0_m=0.0, y_top_m=1.0, res_m=RES_M, min_share=WHOLE_CELL)
    assert (got == TOP_M).all()


@pytest.mark.parametrize(("ground_m", "column"), [(0.3, False), (0.6, True)])
def test_a_lone_vegetation_return_is_a_column_where_it_is_nearest_to_most_of_the_cell(ground_m, column):
    # a shrub's return at the centre of a 0.5 m cell, ground returns ground_m to its four sides: 0.3 m, it is the
    # nearest return to 9 of the cell's 25 sub-cell centres (the ground's height, though the nearest at the centre);
    # 0.6 m, to all 25 (kept)
    d = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], float) * ground_m
    x, y = 0.75 + d[:, 0], 0.75 + d[:, 1]  # the middle cell of 3 x 3
    z, cls = np.array([3.0, 0.0, 0.0, 0.0, 0.0]), np.array([4, 2, 2, 2, 2])
    kw = {"x0_m": 0.0, "y_top_m": 1.5, "res_m": RES_M}
    nearest = nearest_return_surface(x, y, z, nrows=3, ncols=3, max_dist_m=5.0, **kw)
    assert nearest[1, 1] == 3.0
    got = crowns_within_cells(x, y, z, cls, nearest, min_share=MOST_OF_THE_CELL, **kw)
    assert got[1, 1] == (3.0 if column else 0.0)
    assert (np.delete(got.ravel(), 4) == np.delete(nearest.ravel(), 4)).all()


def test_crown_sub_cells_of_a_lone_return():
    # the shrub's return of the test above, ground 0.3 m around: bits of the 3 x 3 middle sub-cells; 0.6 m: the
    # whole cell, 0 (a column as dsm_nearest has it)
    for ground_m, want in ((0.3, sum(1 << (u * SUB_CELLS + v) for u in (1, 2, 3) for v in (1, 2, 3))), (0.6, 0)):
        d = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], float) * ground_m
        x, y = 0.75 + d[:, 0], 0.75 + d[:, 1]
        z, cls = np.array([3.0, 0.0, 0.0, 0.0, 0.0]), np.array([4, 2, 2, 2, 2])
        kw = {"x0_m": 0.0, "y_top_m": 1.5, "res_m": RES_M}
        nearest = nearest_return_surface(x, y, z, nrows=3, ncols=3, max_dist_m=5.0, **kw)
        bits = crown_sub_cells(x, y, cls, nearest, **kw)
        assert bits[1, 1] == want and (np.delete(bits.ravel(), 4) == 0).all()


def test_crown_sub_cells_beside_the_rim():
    # the shrub's return 0.2 m east of the middle cell's centre, ground returns 0.3 m around it: no centre's nearest
    # return; its sub-cells (within 0.15 m of it) in the middle cell (2 columns x 3 rows) and the eastern one (1 x 3)
    d = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], float) * 0.3
    x, y = 0.95 + d[:, 0], 0.75 + d[:, 1]
    z, cls = np.array([3.0, 0.0, 0.0, 0.0, 0.0]), np.array([4, 2, 2, 2, 2])
    kw = {"x0_m": 0.0, "y_top_m": 1.5, "res_m": RES_M}
    nearest = nearest_return_surface(x, y, z, nrows=3, ncols=3, max_dist_m=5.0, **kw)
    assert (nearest == 0.0).all()
    bits, top = crown_sub_cells_beside(x, y, z, cls, nearest, **kw)
    want = np.zeros((3, 3), np.uint32)
    want[1, 1] = sum(1 << (u * SUB_CELLS + v) for u in (1, 2, 3) for v in (3, 4))
    want[1, 2] = sum(1 << (u * SUB_CELLS) for u in (1, 2, 3))
    assert (bits == want).all()
    assert (top[bits != 0] == 3.0).all() and np.isnan(top[bits == 0]).all()
