"""Building returns beneath a roof (``lidarctl.rasters.beneath``): a wall return under an eave is no longer the DSM
there (trial s105 F1: the true ortho masked the roofs' outer metre, rectified on a DSM metres below the roof)."""

import numpy as np
import pytest

from lidarctl import io
from lidarctl.rasters import beneath, products

GROUND_M, ROOF_M = 100.0, 120.0


def _cloud(with_walls: bool = True) -> io.PointCloud:
    """A flat roof over x, y in [20, 40] at 120 m (building class, a return every 0.9 m, none within 1.2 m of its
    north edge but the eave's outer 0.3 m), the ground at 100 m around it (a return every 0.9 m), a gable roof east
    of it (45 deg, building class), a tree (class 5) with returns at every height; with ``with_walls``, wall
    returns under the north eave (y 38.9-39.6, 105-115 m: pulses at a scan angle under a 1.1 m eave)."""
    rng = np.random.default_rng(4)
    pts = []
    g = np.arange(0.0, 80.0, 0.9)
    gx, gy = np.meshgrid(g, g)
    gx, gy = gx.ravel(), gy.ravel()
    on_roof = (gx > 20) & (gx < 40) & (gy > 20) & (gy < 40)
    gable = (gx > 50) & (gx < 66) & (gy > 20) & (gy < 40)
    tree = np.hypot(gx - 30, gy - 60) < 4
    ground = ~on_roof & ~gable & ~tree
    pts.append((gx[ground], gy[ground], np.full(ground.sum(), GROUND_M), 2))
    roof = on_roof & ((gy < 38.8) | (gy > 39.7))
    pts.append((gx[roof], gy[roof], np.full(roof.sum(), ROOF_M), 6))
    # the gable: ridge along x at y = 30, 45 deg slopes down to 110 m at the eaves
    pts.append((gx[gable], gy[gable], ROOF_M - np.abs(gy[gable] - 30.0), 6))
    for h in (102.0, 106.0, 110.0, 114.0):  # a crown's returns at every height
        pts.append((gx[tree], gy[tree] + 0.2, np.full(tree.sum(), h), 5))
    if with_walls:
        wx = np.arange(20.3, 39.8, 0.45)
        pts.append((wx, rng.uniform(38.9, 39.6, wx.size), rng.uniform(105.0, 115.0, wx.size), 6))
    x = np.concatenate([p[0] for p in pts])
    y = np.concatenate([p[1] for p in pts])
    z = np.concatenate([p[2] for p in pts])
    cls = np.concatenate([np.full(len(p[0]), p[3], np.uint8) for p in pts])
    n = x.size
    ones = np.ones(n, np.uint8)
    return io.PointCloud(x=x, y=y, z=z, intensity=np.full(n, 100, np.uint16), return_number=ones,
                         number_of_returns=ones, classification=cls)


def _at(grids, x, y, name):
    t = grids.transform
    col, row = ~t * (x, y)
    return float(getattr(grids, name)[int(row), int(col)])


@pytest.mark.parametrize("name", ["dsm", "dsm_nearest"])
def test_wall_returns_under_an_eave_are_the_roof_above_them(name):
    grids = products.make_grids(_cloud(), 0.5)
    # the cells under the north eave (wall returns only): the roof, as without the wall returns
    for x in (22.1, 27.6, 31.3, 36.9):
        for y in (39.1, 39.4):
            assert _at(grids, x, y, name) == pytest.approx(ROOF_M, abs=0.01), (name, x, y)
    # the ground beside the eave and the roof's inside: as they are
    for x in (22.1, 31.3):
        assert _at(grids, x, 41.3, name) == pytest.approx(GROUND_M, abs=0.01)
        assert _at(grids, x, 30.2, name) == pytest.approx(ROOF_M, abs=0.01)
    # the gable's slopes (45 deg: 0.5-1.7 m within the radius) and the tree's lower returns are not lifted
    plain = products.make_grids(_cloud(with_walls=False), 0.5)
    t = grids.transform
    gable = (slice(None), slice(int((50.5 - t.c) / t.a), int((65.5 - t.c) / t.a)))
    assert np.array_equal(getattr(grids, name)[gable], getattr(plain, name)[gable])
    tree = _at(grids, 30.0, 60.2, name), _at(plain, 30.0, 60.2, name)
    assert tree[0] == tree[1]


def test_the_lift_takes_building_returns_only():
    above = np.full((4, 4), ROOF_M)
    z = np.array([105.0, 105.0, 119.0, 105.0])
    cls = np.array([6, 2, 6, 5])
    x = y = np.full(4, 1.2)
    out = beneath.lift_points(x, y, z, cls, above, x0_m=0.0, y0_m=0.0, res_m=0.5)
    assert out.tolist() == [ROOF_M, 105.0, 119.0, 105.0]  # 119 m lies within BENEATH_DZ_M of the roof
    top = np.full((5, 5), np.nan)
    top[2, 2] = ROOF_M
    reach = beneath.roof_above(top, 0.5)
    # the cells whose centres lie within 1 m of the roof return's cell centre: 2 cells along a row, 1 diagonally
    assert np.isfinite(reach).sum() == 13 and np.isnan(reach[0, 0]) and reach[2, 0] == ROOF_M
