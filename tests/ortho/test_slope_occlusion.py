"""The true ortho's occlusion test on slopes (issue 42, slope-occlusion): continuous surface occludes as the
bilinear surface the ground points stand on, walls as the DSM's flat-topped columns.

Truth: a fine march (every 2 cm) along each point's line of sight over the same bilinear surface, independent of
the kernels. The scene: a hill of 40 m (a Gaussian of 20 m, slopes up to 50 deg) on a 2 m DSM (a
photogrammetric DSM's cell: 2.4 m of rise per cell at the steepest), the camera 450 m up and 500 m to the west (rays
at about 42 deg): its east slope faces away from the camera, steeper than the rays near its foot of steepest slope
(hidden by itself), less steep elsewhere (seen). The flat-topped columns (main's march) masked the seen part of it
too: a column's top lies up to half the cell's rise (1.2 m) above the surface, more than the march's 0.3 m.
Continuous surface joins the ground alone (``ortho.rectify.ground_cells``, the rectify's DEM): a low object on a
coarse DSM (a car, a hedge: within 60 deg per cell) keeps its columns (review 30).
"""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

import ortho.rectify as rectify
from ortho.dem import HeightRaster
from ortho.rectify import FrameGeometry, ground_cells, occlusion_mask

RES_M = 2.0
N = 100  # cells a side: 200 x 200 m, the top-left corner at (0, 200)
CRS_UTM = CRS.from_epsg(32633)
CENTRE = (-400.0, 100.0, 450.0)


def _hill_dsm() -> HeightRaster:
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 200.0 - c)
    z = 40.0 * np.exp(-((X - 100.0) ** 2 + (Y - 100.0) ** 2) / (2 * 20.0 ** 2))
    return HeightRaster(z.astype(np.float32), 0.0, 200.0, RES_M, CRS_UTM, "DSM")


def _box_dsm() -> HeightRaster:
    """A box building 12 m high on flat ground (cells wholly roof or ground)."""
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 200.0 - c)
    roof = (np.abs(X - 100.0) < 15.0) & (np.abs(Y - 100.0) < 15.0)
    return HeightRaster(np.where(roof, 12.0, 0.0).astype(np.float32), 0.0, 200.0, RES_M, CRS_UTM, "DSM")


def _flat_dem(dsm: HeightRaster) -> HeightRaster:
    """The boxes' ground: flat at 0 m, on the DSM's grid."""
    return HeightRaster(np.zeros_like(dsm.heights_m), dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, "DEM")


def _points(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(50.0, 150.0, n), rng.uniform(50.0, 150.0, n)


def _march(dsm, x, y, z, dem=None):
    """The march's mask; ``dem``: the ground (None: the DSM itself, every cell the ground)."""
    AX, AY = np.vstack([x, x]), np.vstack([y, y])
    grid = type("Grid", (), {"height": 2, "width": len(x)})()
    geometry = FrameGeometry(None, np.asarray(CENTRE, float), np.eye(3))
    heights = np.vstack([z, z]).astype(np.float32)
    ground = ground_cells(dsm, dsm if dem is None else dem)
    return occlusion_mask(geometry, dsm, grid, heights, (AX, AY, 1.0), ground=ground)[0]


def _fine_excess_m(dsm, x, y, z, step_m=0.02):
    """The highest the bilinear surface rises above each line of sight, from 0.05 m beyond its ground point to
    where it leaves the DSM (m; a numpy march, not the kernels)."""
    C = np.asarray(CENTRE)
    d = np.hypot(C[0] - x, C[1] - y)
    worst = np.full(len(x), -np.inf)
    for s in np.arange(0.05, d.max(), step_m):
        t = s / d
        px, py = x + t * (C[0] - x), y + t * (C[1] - y)
        inside = (t < 1.0) & (px > RES_M / 2) & (px < 200.0 - RES_M / 2) & (py > RES_M / 2) & (py < 200.0 - RES_M / 2)
        if not inside.any():
            break
        e = dsm.sample(px, py) - (z + t * (C[2] - z))
        worst = np.where(inside, np.fmax(worst, e), worst)
    return worst


@pytest.fixture(scope="module")
def hill():
    dsm = _hill_dsm()
    x, y = _points()
    z = dsm.sample(x, y)
    return dsm, x, y, z, _fine_excess_m(dsm, x, y, z)


def test_a_slope_facing_away_is_masked_only_where_the_surface_hides_it(hill):
    dsm, x, y, z, excess = hill
    masked = _march(dsm, x, y, z)
    seen, hidden = excess <= 0.0, excess > 0.3  # the march's tolerance
    assert hidden.sum() > 50 and seen.sum() > 2000  # the hill hides part of its east slope, the rest is seen
    assert not (masked & seen).any(), f"{(masked & seen).sum()} seen points masked"
    assert masked[hidden].mean() > 0.97, f"{masked[hidden].sum()} of {hidden.sum()} hidden points masked"


def test_the_flat_topped_columns_masked_the_seen_slope(hill, monkeypatch):
    """The same points with every rise a wall (main's march): seen points of the east slope masked."""
    dsm, x, y, z, excess = hill
    monkeypatch.setattr(rectify, "WALL_SLOPE_DEG", 0.0)
    masked = _march(dsm, x, y, z)
    assert (masked & (excess <= 0.0)).sum() > 100


def test_walls_occlude_as_the_columns(monkeypatch):
    dsm = _box_dsm()
    x, y = _points(seed=1)
    z = dsm.sample(x, y)
    ground = z < 0.01
    masked = _march(dsm, x[ground], y[ground], z[ground], _flat_dem(dsm))
    monkeypatch.setattr(rectify, "WALL_SLOPE_DEG", 0.0)
    columns = _march(dsm, x[ground], y[ground], z[ground], _flat_dem(dsm))
    assert masked.sum() > 100  # the box hides the ground east of it
    np.testing.assert_array_equal(masked, columns)


def test_a_low_object_on_a_coarse_dsm_keeps_its_columns(monkeypatch):
    """A car-sized box, 1.6 m high and 4 m wide, on a 2 m DSM over flat ground: its sides rise 39 deg per cell,
    within ``WALL_SLOPE_DEG``, but it stands on the ground (the DEM) and is no ground itself: its columns occlude.
    Truth: the segment from the ground point to the camera crosses the box's exact volume more than the march's
    tolerance below its top (the ray rises: lowest where it enters the box). As continuous surface (every cell the
    ground, the rule before review 30) about half of that ground was left valid."""
    c = (np.arange(N) + 0.5) * RES_M
    X, Y = np.meshgrid(c, 200.0 - c)
    lo, hi, top_m = 98.0, 102.0, 1.6  # on cell boundaries: cells wholly box or ground
    dsm = HeightRaster(np.where((X > lo) & (X < hi) & (Y > lo) & (Y < hi), top_m, 0.0).astype(np.float32),
                       0.0, 200.0, RES_M, CRS_UTM, "DSM")
    rng = np.random.default_rng(2)
    x, y = rng.uniform(hi, hi + 6.0, 2000), rng.uniform(lo, hi, 2000)  # east of it, away from the camera
    z = np.zeros(len(x))
    C = np.asarray(CENTRE)
    t_in = (hi - x) / (C[0] - x)  # the ray enters the box through its east face (heading west)
    y_in = y + t_in * (C[1] - y)
    hidden = (y_in > lo) & (y_in < hi) & (t_in * C[2] < top_m - 0.3)
    assert hidden.sum() > 300 and (~hidden).sum() > 300
    masked = _march(dsm, x, y, z, _flat_dem(dsm))
    assert masked[hidden].all(), f"{(hidden & ~masked).sum()} of {hidden.sum()} hidden ground points left valid"
    assert not (masked & (t_in * C[2] > top_m)).any()  # rays above the box's top: seen
    ramp = _march(dsm, x, y, z, dsm)  # every cell the ground: the box a ramp
    assert (hidden & ~ramp).sum() > hidden.sum() // 4
    monkeypatch.setattr(rectify, "WALL_SLOPE_DEG", 0.0)
    np.testing.assert_array_equal(masked, _march(dsm, x, y, z, _flat_dem(dsm)))  # exactly the columns


def test_ground_cells_of_the_dem_as_the_dsm_are_all_ground():
    """``--dsm dem.tif``: every cell with a height is the ground (nothing changes); nodata is not."""
    dsm = _hill_dsm()
    assert ground_cells(dsm, dsm).all()
    holed = dsm.heights_m.copy()
    holed[10, 10] = np.nan
    flags = ground_cells(HeightRaster(holed, dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, "DSM"), dsm)
    assert flags[10, 10] == 0 and flags.sum() == flags.size - 1
