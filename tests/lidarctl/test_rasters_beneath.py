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
    of it (45 deg, building class), a lower roof (110 m) against the flat roof's west wall, a tree (class 5) with
    returns at every height; with ``with_walls``, wall returns under the north eave (y 38.9-39.6, 105-115 m: pulses
    at a scan angle under a 1.1 m eave)."""
    rng = np.random.default_rng(4)
    pts = []
    g = np.arange(0.0, 80.0, 0.9)
    gx, gy = np.meshgrid(g, g)
    gx, gy = gx.ravel(), gy.ravel()
    on_roof = (gx > 20) & (gx < 40) & (gy > 20) & (gy < 40)
    gable = (gx > 50) & (gx < 66) & (gy > 20) & (gy < 40)
    tree = np.hypot(gx - 30, gy - 60) < 4
    annex = (gx > 12) & (gx < 20) & (gy > 24) & (gy < 36)
    ground = ~on_roof & ~gable & ~tree & ~annex
    pts.append((gx[ground], gy[ground], np.full(ground.sum(), GROUND_M), 2))
    pts.append((gx[annex], gy[annex], np.full(annex.sum(), 110.0), 6))
    roof = on_roof & ((gy < 38.8) | (gy > 39.7))
    pts.append((gx[roof], gy[roof], np.full(roof.sum(), ROOF_M), 6))
    # the gable: ridge along x at y = 30, 45 deg slopes down to 110 m at the eaves
    pts.append((gx[gable], gy[gable], ROOF_M - np.abs(gy[gable] - 30.0), 6))
    for h in (102.0, 106.0, 110.0, 114.0):  # a crown's returns at every height
        pts.append((gx[tree], gy[tree] + 0.2, np.full(tree.sum(), h), 5))
    if with_walls:
        # a wall is vertical: pulses of several scan lines hit it at one place and different heights
        wx = np.repeat(np.arange(20.3, 39.8, 0.45), 3)
        wz = np.tile([106.0, 110.0, 114.0], wx.size // 3) + rng.uniform(-1.0, 1.0, wx.size)
        pts.append((wx + rng.uniform(-0.05, 0.05, wx.size), rng.uniform(38.9, 39.6, wx.size), wz, 6))
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


def _eave_cells(grids, name) -> np.ndarray:
    """The cells under the north eave (y 39.0-39.5, x 20.5-39.5: wall returns only)."""
    return np.array([_at(grids, x, 39.25, name) for x in np.arange(20.6, 39.5, 0.5)])


@pytest.mark.parametrize("name, least_share", [("dsm", 0.85), ("dsm_nearest", 0.6)])
def test_wall_returns_under_an_eave_are_the_roof_above_them(name, least_share, monkeypatch):
    """The highest return of a cell under the eave is on the wall (something 2.5 m lower beside it): the DSM takes
    the roof there; the nearest-return DSM where the return nearest the centre is one of them (the lowest at a place,
    with nothing 2.5 m below within 1 m, is not: the ground lies beyond the eave)."""
    grids = products.make_grids(_cloud(), 0.5)
    eave = _eave_cells(grids, name)
    assert np.mean(np.abs(eave - ROOF_M) < 0.01) >= least_share, eave
    with monkeypatch.context() as m:  # the same returns without the lift: the wall's heights
        m.setattr(beneath, "BENEATH_DZ_M", 1e9)
        unlifted = _eave_cells(products.make_grids(_cloud(), 0.5), name)
    assert np.mean(np.abs(unlifted - ROOF_M) < 0.01) < 0.1 and np.all(eave >= unlifted)
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
    # the lower roof against the west wall keeps its height up to the wall (the step between the two roofs' returns)
    for x in (18.5, 19.4):
        assert _at(grids, x, 30.2, name) == pytest.approx(110.0, abs=0.01), (name, x)


def test_the_lift_takes_building_returns_on_a_wall_only():
    above, below = np.full((4, 4), ROOF_M), np.full((4, 4), GROUND_M)
    z = np.array([105.0, 105.0, 119.0, 105.0, 101.0])
    cls = np.array([6, 2, 6, 5, 6])
    x = y = np.full(5, 1.2)
    out = beneath.lift_points(x, y, z, cls, (above, below), x0_m=0.0, y0_m=0.0, res_m=0.5)
    # 119 m lies within BENEATH_DZ_M of the roof, 101 m within it of the wall's foot
    assert out.tolist() == [ROOF_M, 105.0, 119.0, 105.0, 101.0]
    # a lower roof beside a higher one's wall: nothing lower beside it, not lifted
    out = beneath.lift_points(x, y, z, cls, (above, np.full((4, 4), 105.0)), x0_m=0.0, y0_m=0.0, res_m=0.5)
    assert out.tolist() == z.tolist()
    top = np.full((5, 5), np.nan)
    top[2, 2] = ROOF_M
    reach, foot = beneath.wall_span(top, np.where(np.isnan(top), np.nan, GROUND_M), 0.5)
    # the cells whose centres lie within 1 m of the roof return's cell centre: 2 cells along a row, 1 diagonally
    assert np.isfinite(reach).sum() == 13 and np.isnan(reach[0, 0]) and reach[2, 0] == ROOF_M
    assert np.array_equal(np.isfinite(foot), np.isfinite(reach)) and foot[2, 0] == GROUND_M
