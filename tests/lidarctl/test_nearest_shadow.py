"""The LiDAR's shadow behind a wall in the occlusion DSM (issue 42): dsm_nearest.tif's cells with no first return
within ``nearest.EMPTY_RADIUS_SPACINGS`` point spacings take the DEM where it is lower; a scan gap inside a roof
(a line of returns missing) keeps the roof."""

import numpy as np
import rasterio

from lidarctl import io, synthetic
from lidarctl.rasters import nearest
from lidarctl.rasters import products as rasters

SPACING_M, ROOF_M = 0.75, 10.0
WALL_X_M, SHADOW_M = 40.0, 3.0   # the building's east wall; the ground the scanner does not see east of it


def _wall_with_shadow():
    """Returns on a 0.75 m lattice over 60 x 60 m: ground (class 2) at 0 m, a 20 x 20 m building (class 6) 10 m
    high, no ground return within 3 m east of its east wall (the shadow), and one line of roof returns missing
    (a scan gap, 1.5 m between the lines beside it)."""
    g = np.arange(0.2, 60.0, SPACING_M)
    gx, gy = np.meshgrid(g, g)
    x, y = gx.ravel(), gy.ravel()
    roof = (x > 20.0) & (x < WALL_X_M) & (y > 20.0) & (y < 40.0)
    shadow = (x >= WALL_X_M) & (x < WALL_X_M + SHADOW_M) & (y > 20.0) & (y < 40.0)
    gap_y = g[np.searchsorted(g, 30.0)]
    keep = ~shadow & ~(roof & (y == gap_y))
    x, y, roof = x[keep], y[keep], roof[keep]
    n = len(x)
    cloud = io.PointCloud(x, y, np.where(roof, ROOF_M, 0.0), np.full(n, 100, np.uint16), np.ones(n, np.uint8),
                          np.ones(n, np.uint8), np.where(roof, 6, 2).astype(np.uint8))
    return cloud, gap_y


def _read(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform


def test_the_shadow_behind_a_wall_takes_the_dem_and_a_roof_scan_gap_keeps_the_roof(tmp_path):
    cloud, gap_y = _wall_with_shadow()
    synthetic.write_las(tmp_path / "strip.las", cloud, crs="EPSG:32632")
    cloud = io.read_cloud(tmp_path / "strip.las")
    # tiled (tiles of 32 m: the shadow crosses a tile edge) and whole: the same dsm_nearest
    rasters.write_rasters([tmp_path / "strip.las"], tmp_path / "tiled", 0.5, tile_px=64, buffer_px=32,
                          dem_fill_radius_px=7)
    rasters.write_rasters(cloud, tmp_path / "whole", 0.5, dem_fill_radius_px=7)
    near, tf = _read(tmp_path / "tiled" / "dsm_nearest.tif")
    np.testing.assert_array_equal(near, _read(tmp_path / "whole" / "dsm_nearest.tif")[0])
    dem = _read(tmp_path / "tiled" / "dem.tif")[0]
    cols, rows = np.meshgrid(np.arange(near.shape[1]), np.arange(near.shape[0]))
    cx, cy = tf.c + (cols + 0.5) * tf.a, tf.f + (rows + 0.5) * tf.e
    inside = (cy > 21.0) & (cy < 39.0)
    # the shadow's half nearest the wall, whose nearest return is the roof's: at the DEM (the ground, 0 m)
    shadow = inside & (cx > WALL_X_M + 1.0) & (cx < WALL_X_M + SHADOW_M / 2)
    assert shadow.sum() >= 30
    assert np.abs(dem[shadow]).max() < 0.01
    np.testing.assert_array_equal(near[shadow], dem[shadow])
    # where the return nearest the centre is the roof's (the surface before the rule)
    first = nearest.nearest_return_surface(cloud.x, cloud.y, cloud.z, x0_m=tf.c, y_top_m=tf.f, res_m=0.5,
                                           nrows=near.shape[0], ncols=near.shape[1], max_dist_m=5.0)
    assert (first[shadow] == ROOF_M).all()
    # the scan gap in the roof (no return within 0.5 m of its centres, but within 1.14 spacings): the roof
    gap = inside & (np.abs(cy - gap_y) < 0.3) & (cx > 21.0) & (cx < WALL_X_M - 1.0)
    assert gap.sum() >= 30
    assert (near[gap] == ROOF_M).all()
    # the roof and the ground the scanner saw: the nearest return's height
    roof = inside & (cx > 21.0) & (cx < WALL_X_M - 0.5)
    assert (near[roof] == ROOF_M).all()
    ground = (cx < 19.0) | (cx > WALL_X_M + SHADOW_M + 0.5)
    assert (near[ground] == 0.0).all()


def test_empty_cells_are_those_farther_than_1_14_spacings():
    # the box's area over the count: a 0.75 m lattice of 80 x 80 returns spans 59.25 m
    spacing = nearest.point_spacing_m((0.0, 59.25, 0.0, 59.25), 80 * 80)
    assert abs(spacing - 0.7406) < 1e-4
    assert nearest.empty_radius_m(spacing) == nearest.EMPTY_RADIUS_SPACINGS * spacing == 1.14 * spacing
    surface = np.array([[10.0, 10.0, 10.0, np.nan, 10.0]], np.float32)
    distance = np.array([[0.9, 0.8, 0.9, 2.0, np.inf]], np.float32)
    dem = np.array([[0.0, 0.0, 12.0, 0.0, np.nan]], np.float32)
    lowered = nearest.empty_at_dem(surface, distance, dem, 0.85)
    # beyond the radius and the DEM lower: lowered; within it, the DEM higher, nodata in either: kept
    assert lowered.tolist() == [[True, False, False, False, False]]
    np.testing.assert_array_equal(surface, np.array([[0.0, 10.0, 10.0, np.nan, 10.0]], np.float32))
