"""The roof outline and tree crowns in the true ortho's occlusion test (issue 42). Constructed, the truth of each line
of sight from the boxes here (a segment sampled every mm), not from the march:

- a box building (walls 10.2 .. 20.6 m, roof 10 m, eave 0.3 m: the roof outline 9.9 .. 20.9 m) on a DSM of 0.5 m
  sampled at the cell centres: the DSM's roof cells reach 21.0 m, 0.1 m beyond the outline on the east. A line of
  sight that crosses the eave's slab height in that last 0.1 m (outside the footprint and beyond the eave) reaches
  the ground; the roof outline (the footprint grown by the eave width the DSM gives) lets it through, the whole
  cell's slab did not;
- a tree crown 5 .. 10 m over a 4 x 4 m square: with its crown base a line of sight beneath the crown reaches the
  ground, one through the crown stays hidden.
"""

from __future__ import annotations

import numpy as np
import shapely
from pyproj import CRS

from lidarctl.rasters.crown_base import crown_base_surface
from ortho.dem import HeightRaster
from ortho.footprints import OVERHANG_SLAB_M, eave_widths_m, footprint_cells, footprint_occluder, with_crown_base
from ortho.rectify import FrameGeometry, occlusion_mask

RES_M = 0.5
N = 80  # cells a side: 40 x 40 m, the top-left corner at (0, 40)
CRS_UTM = CRS.from_epsg(32633)
WALL = (10.2, 10.2, 20.6, 20.6)
EAVE_M = 0.3
ROOF_M = 10.0
CROWN = (28.0, 30.0, 5.0, 32.0, 34.0, 10.0)  # x0 y0 z0 x1 y1 z1 (m)


def _centres():
    c = (np.arange(N) + 0.5) * RES_M
    return np.meshgrid(c, 40.0 - c)


def _building_dsm():
    X, Y = _centres()
    x0, y0, x1, y1 = WALL
    roof = (X > x0 - EAVE_M) & (X < x1 + EAVE_M) & (Y > y0 - EAVE_M) & (Y < y1 + EAVE_M)
    return HeightRaster(np.where(roof, ROOF_M, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM")


def _tree_dsm():
    X, Y = _centres()
    x0, y0, _, x1, y1, z1 = CROWN
    tree = (X > x0) & (X < x1) & (Y > y0) & (Y < y1)
    return HeightRaster(np.where(tree, z1, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM"), tree


def _in_box(q, box):
    x0, y0, z0, x1, y1, z1 = box
    return (q[:, 0] > x0) & (q[:, 0] < x1) & (q[:, 1] > y0) & (q[:, 1] < y1) & (q[:, 2] > z0) & (q[:, 2] < z1)


def _truth_sees(p, centre, boxes) -> bool:
    t = np.linspace(0.0, 1.0, 400_001)
    q = np.asarray(p)[None, :] + t[:, None] * (np.asarray(centre) - np.asarray(p))[None, :]
    return not any(_in_box(q, b)[1:].any() for b in boxes)


def _march(dsm, points, centre, occluder):
    xy = np.array(points)
    AX, AY = np.vstack([xy[:, 0], xy[:, 0]]), np.vstack([xy[:, 1], xy[:, 1]])
    grid = type("Grid", (), {"height": 2, "width": len(xy)})()
    geometry = FrameGeometry(None, np.asarray(centre, float), np.eye(3))
    return occlusion_mask(geometry, dsm, grid, np.zeros((2, len(xy)), np.float32), (AX, AY, 1.0),
                          occluder=occluder)[0]


def test_a_line_of_sight_through_a_roof_edge_cell_beyond_the_eave_is_visible():
    dsm = _building_dsm()
    footprints = np.array([shapely.box(*WALL)], dtype=object)
    ground = np.zeros(dsm.heights_m.shape, np.float32)
    x0, y0, x1, y1 = WALL
    walls = (x0, y0, 0.0, x1, y1, ROOF_M)
    eave = (x0 - EAVE_M, y0 - EAVE_M, ROOF_M - OVERHANG_SLAB_M, x1 + EAVE_M, y1 + EAVE_M, ROOF_M)
    # the eave width the DSM gives: its roof's area outside the walls over their perimeter (the truth 0.3 m)
    cells = footprint_cells(0.0, 40.0, RES_M, dsm.heights_m.shape, footprints)
    taken = (cells.label > 0) & (dsm.heights_m > 2.0)
    assert abs(eave_widths_m(cells, taken, RES_M)[1] - EAVE_M) < 0.03
    # lines of sight north along the east wall, rising 0.97 m a metre: the slab's underside (9.7 m) at y = 15 m
    centre = (20.95, 1005.0, 970.0)
    points = [(20.95, 5.0), (20.85, 5.0)]  # 0.05 m beyond the eave (in the DSM's last roof cell); 0.05 m within
    truth = [_truth_sees((*p, 0.0), centre, [walls, eave]) for p in points]
    assert truth == [True, False]
    occluder = footprint_occluder(dsm, ground, footprints)
    assert list(~_march(dsm, points, centre, occluder)) == truth
    # the whole cell's slab (main's rule before the roof outline) hid the first as well
    whole = occluder.sub_masks.copy()
    whole[:, 0, 0] |= 4
    import dataclasses

    assert _march(dsm, points, centre, dataclasses.replace(occluder, sub_masks=whole)).all()


def test_the_slab_ends_at_the_roof_outline_between_sub_cell_centres():
    """Walls 10.2 .. 20.7 m (east) x 10.2 .. 20.6 m, eave 0.28 m (the width the DSM gives this building): the east
    outline at 20.98 m, inside the sub-cell 20.9 .. 21.0 m whose centre (20.95 m, 0.03 m within the outline) put it
    all in the slab. A line of sight north along the wall 0.01 m beyond the outline reaches the ground; one 0.02 m
    within it stays hidden. The sub-cells' margins interpolated find the outline; the sub-cell whose centre lies
    within it (the rule before) hid both."""
    import dataclasses

    from ortho.footprints import MARGIN_NONE

    wall, eave_m = (10.2, 10.2, 20.7, 20.6), 0.28
    X, Y = _centres()
    x0, y0, x1, y1 = wall
    roof = (X > x0 - eave_m) & (X < x1 + eave_m) & (Y > y0 - eave_m) & (Y < y1 + eave_m)
    dsm = HeightRaster(np.where(roof, ROOF_M, 0.0).astype(np.float32), 0.0, 40.0, RES_M, CRS_UTM, "DSM")
    footprints = np.array([shapely.box(*wall)], dtype=object)
    cells = footprint_cells(0.0, 40.0, RES_M, dsm.heights_m.shape, footprints)
    assert round(eave_widths_m(cells, (cells.label > 0) & (dsm.heights_m > 2.0), RES_M)[1], 2) == eave_m
    walls = (x0, y0, 0.0, x1, y1, ROOF_M)
    eave = (x0 - eave_m, y0 - eave_m, ROOF_M - OVERHANG_SLAB_M, x1 + eave_m, y1 + eave_m, ROOF_M)
    centre = (20.975, 1005.0, 970.0)  # rising 0.97 m a metre: the slab's height (9.7 .. 10 m) at y = 15 m
    points = [(20.99, 5.0), (20.96, 5.0)]
    truth = [_truth_sees((*p, 0.0), centre, [walls, eave]) for p in points]
    assert truth == [True, False]
    occluder = footprint_occluder(dsm, np.zeros(dsm.heights_m.shape, np.float32), footprints)
    assert list(~_march(dsm, points, centre, occluder)) == truth
    nearest = dataclasses.replace(occluder, sub_margin_cm=np.full_like(occluder.sub_margin_cm, MARGIN_NONE))
    assert _march(dsm, points, centre, nearest).all()


def test_a_line_of_sight_beneath_a_crown_base_is_visible_and_one_through_the_crown_hidden():
    dsm, tree = _tree_dsm()
    crown_base = np.where(tree, CROWN[2], np.nan).astype(np.float32)
    # lines of sight rising 1 m a metre to the north across the crown (y 30 .. 34 m)
    centre = (30.0, 1025.5, 1000.0)
    points = [(30.0, 29.5), (30.0, 26.0)]  # beneath the crown base (0.5 .. 4.5 m there); through the crown
    truth = [_truth_sees((*p, 0.0), centre, [CROWN]) for p in points]
    assert truth == [True, False]
    with_crowns = _march(dsm, points, centre, with_crown_base(None, dsm.heights_m, crown_base))
    assert list(~with_crowns) == truth
    assert _march(dsm, points, centre, None).all()  # without crown bases the tree is a solid column
    # with footprints elsewhere: the crown is the same where no footprint reaches
    footprints = np.array([shapely.box(*WALL)], dtype=object)
    occluder = footprint_occluder(dsm, np.zeros(dsm.heights_m.shape, np.float32), footprints, crown_base_m=crown_base)
    assert list(~_march(dsm, points, centre, occluder)) == truth


def test_crown_base_from_lidar_is_the_lowest_vegetation_return_around_a_cell():
    # 3 x 3 cells of 1 m; vegetation returns (class 5) in the centre cell at 9 and 6 m and in the west cell at 7 m;
    # a ground return (class 2) at 0 m in the centre cell; one lone vegetation return in the north-east cell
    x = np.array([1.5, 1.5, 0.5, 1.5, 2.5])
    y = np.array([1.5, 1.4, 1.5, 1.5, 2.5])
    z = np.array([9.0, 6.0, 7.0, 0.0, 8.0])
    cls = np.array([5, 5, 5, 2, 5])
    base = crown_base_surface(x, y, z, cls, x0_m=0.0, y_top_m=3.0, res_m=1.0, shape=(3, 3))
    assert base[1, 1] == 6.0 and base[1, 0] == 6.0  # the lowest of the cell and its neighbours (3 returns)
    assert base[0, 2] == 6.0  # the north-east cell sees the centre's returns too
    assert np.isnan(base[2, 2]) and np.isnan(base[0, 0])  # no vegetation return in the cell
    lone = crown_base_surface(x[4:], y[4:], z[4:], cls[4:], x0_m=0.0, y_top_m=3.0, res_m=1.0, shape=(3, 3))
    assert np.isnan(lone).all()  # one return alone is the top: no crown base


def test_the_march_over_slabs_does_not_depend_on_the_block_bounds():
    """The march skips the DSM blocks a ray passes above (``march_bound``); an overhang's slab stops a ray below its
    top without the tolerance, so the bounds stand over the slabs' tops raised by it: the same answer as a march
    that skips nothing, for 4,000 ground points around the building and the tree."""
    import dataclasses

    from ortho.rectify import march_bound

    dsm = _building_dsm()
    tree_dsm, tree = _tree_dsm()
    dsm = dataclasses.replace(dsm, heights_m=np.maximum(dsm.heights_m, tree_dsm.heights_m))
    crown_base = np.where(tree, CROWN[2], np.nan).astype(np.float32)
    footprints = np.array([shapely.box(*WALL)], dtype=object)
    occluder = footprint_occluder(dsm, np.zeros(dsm.heights_m.shape, np.float32), footprints, crown_base_m=crown_base)
    rng = np.random.default_rng(7)
    xy = rng.uniform(2.0, 38.0, (4000, 2))
    xy = xy[~((xy[:, 0] > 9.5) & (xy[:, 0] < 21.5) & (xy[:, 1] > 9.5) & (xy[:, 1] < 21.5))]
    AX, AY = np.vstack([xy[:, 0], xy[:, 0]]), np.vstack([xy[:, 1], xy[:, 1]])
    grid = type("Grid", (), {"height": 2, "width": len(xy)})()
    heights = np.zeros((2, len(xy)), np.float32)
    bound = march_bound(dsm, occluder=occluder)
    no_skip = dataclasses.replace(bound, max_m=np.inf, block_max_m=np.full_like(bound.block_max_m, np.inf),
                                  coarse_max_m=np.full_like(bound.coarse_max_m, np.inf))
    for centre in [(60.0, 70.0, 120.0), (-30.0, 20.0, 60.0), (20.0, -40.0, 90.0)]:
        geometry = FrameGeometry(None, np.asarray(centre, float), np.eye(3))
        skipping = occlusion_mask(geometry, dsm, grid, heights, (AX, AY, 1.0), occluder=occluder)
        walking = occlusion_mask(geometry, dsm, grid, heights, (AX, AY, 1.0), occluder=occluder, bound=no_skip)
        assert skipping.sum() > 100
        assert (skipping == walking).all()
