"""A frame's ground footprint on the earth (issue 42): ``frame_grid``, ``footprint_polygon_xy`` and ``covered_share``
intersect the frame's rays with the heights as a camera over the earth sees them (``FramesOnEarth``), as the
rectifier maps the frame. Taken as straight lines of easting, northing and height they miss by the projection's
scale: at the presets' origin (scale 0.99963) 400 ppm too far out, 2.8 px of a full-size DMC frame 700 m from the
nadir; near zone 49's edge (113.98 E, scale 1.0006) 550 ppm short, 0.43 m at the frame's corners, more than the
grid's 2-cell pad.

Known truth: ``LocalFrame`` (exact) at a block centre 2 km away: the footprint's ground points projected into the
frame must be the border pixels they came from."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

from aerotri.geom.camera import BrownCamera
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.dem import HeightRaster
from ortho.grid import GridToProject
from ortho.rectify import border_pixels, covered_share, footprint_polygon_xy, frame_grid, intersect_rays_with_heights

UTM49 = CRS.from_epsg(32649)
GROUND_Z = 310.0
DMC = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=13824, height=7680, ppx_mm=0.10, ppy_mm=-0.06, k1=-4e-3,
                  k2=1e-3, name="dmc")  # full size: 0.1 m GSD 1,000 m above the ground
R = rotation_matrix_opk(0.4, -0.3, -92.0)
PRESETS_ORIGIN = (452464.0, 3407774.0)
ZONE_EDGE = (785000.0, 3407774.0)


def _centre(e_n):
    return np.array([e_n[0], e_n[1], GROUND_Z + 1000.0])


def _dem(C):
    return HeightRaster(np.full((320, 320), GROUND_Z, np.float32), C[0] - 800.0, C[1] + 800.0, 5.0, UTM49, "flat DEM")


def _exact_pixels(C, P):
    frame = LocalFrame(UTM49, (C[0] + 2000.0, C[1] - 1000.0, GROUND_Z))
    R_enu = frame.rotation_local_from_map(C)[0] @ R
    x, y, _ = DMC.project(frame.to_local(P), frame.to_local(C)[0], R_enu)
    return x, y


@pytest.mark.parametrize("where", [PRESETS_ORIGIN, ZONE_EDGE])
def test_footprint_ring_is_where_the_frame_sees_it(where):
    """The ring's ground points, 380-790 m from the nadir, project exactly onto their border pixels (< 1e-3 px); the
    straight rays' ring is 1.5-2.9 px off the frame's view at the presets' origin, 2.1-4.8 px near the zone's edge."""
    C = _centre(where)
    ring = footprint_polygon_xy(DMC, C, R, _dem(C), to_project=GridToProject(UTM49, UTM49), per_side=16)
    x, y = border_pixels(DMC, 16)
    assert np.hypot(ring[:, 0] - C[0], ring[:, 1] - C[1]).max() > 780.0
    xe, ye = _exact_pixels(C, np.column_stack([ring, np.full(len(ring), GROUND_Z)]))
    assert np.hypot(xe - x, ye - y).max() < 1e-3
    flat = intersect_rays_with_heights(DMC, C, R, x, y, _dem(C), z_start_m=GROUND_Z, crs=None)  # the ring before
    xf, yf = _exact_pixels(C, flat)
    before = np.hypot(xf - x, yf - y)
    assert before.min() > 1.4 and before.max() > 2.8
    assert np.hypot(*(flat[:, :2] - ring).T).max() > 0.28


def test_frame_grid_holds_the_whole_footprint_with_its_pad():
    """Near the zone's edge every border pixel's ground lies the 2-cell pad (0.2 m) inside the frame's 0.1 m grid;
    the straight rays' footprint falls up to 0.43 m short of it: ground the frame sees beyond the pad."""
    res = 0.1
    C = _centre(ZONE_EDGE)
    grid = frame_grid(DMC, C, R, _dem(C), res, UTM49, to_project=GridToProject(UTM49, UTM49))
    x, y = border_pixels(DMC)
    ring = intersect_rays_with_heights(DMC, C, R, x, y, _dem(C), z_start_m=GROUND_Z)
    xe, ye = _exact_pixels(C, ring)
    assert np.hypot(xe - x, ye - y).max() < 1e-3
    left, top = grid.x_left_m, grid.y_top_m
    right, bottom = left + grid.width * res, top - grid.height * res
    margin = np.min([ring[:, 0] - left, right - ring[:, 0], top - ring[:, 1], ring[:, 1] - bottom])
    assert margin >= 2 * res - 1e-6
    flat = intersect_rays_with_heights(DMC, C, R, x, y, _dem(C), z_start_m=GROUND_Z, crs=None)
    short = np.max(np.abs(ring[:, :2] - C[:2]), axis=0) - np.max(np.abs(flat[:, :2] - C[:2]), axis=0)
    assert short.max() > 2 * res  # the pad would not have covered the straight rays' shortfall


def test_covered_share_sees_the_dem_edge_where_the_frame_does():
    """Near the zone's edge a DEM ending 0.15 m inside the frame's exact footprint on its east side: the frame's
    lattice rays there miss it (share < 1); the straight rays (0.4 m short) count it as fully covered."""
    C = _centre(ZONE_EDGE)
    dem0 = _dem(C)
    x, y = border_pixels(DMC)
    east = intersect_rays_with_heights(DMC, C, R, x, y, dem0, z_start_m=GROUND_Z)[:, 0].max() - 0.15
    cols = int(np.floor((east - dem0.x_left_m) / dem0.res_m))
    heights = dem0.heights_m.copy()
    heights[:, cols:] = np.nan
    # shifted so that its valid cells end at ``east`` (bilinear heights need the cell centres on both sides)
    dem = HeightRaster(heights, dem0.x_left_m + (east - (dem0.x_left_m + (cols - 0.5) * dem0.res_m)), dem0.y_top_m,
                       dem0.res_m, UTM49, "cut DEM")
    assert covered_share(DMC, C, R, dem, per_side=33) < 1.0
    assert covered_share(DMC, C, R, dem, per_side=33, crs=None) == 1.0


def test_a_partly_covered_frame_s_grid_ends_where_the_heights_do():
    """Tuniu trial: on a DSM ending inside the frames, their grids reached 28-45 m beyond it (rays missing the DSM put
    on its mid plane) and the mosaic counted that margin as 12 % "seen by no frame". A DEM that ends at the nadir's
    easting: the partial grid ends at its edge (plus the 2-cell pad), the frame's east edge is kept, nodata cells
    inside a raster stay in the grid (the mosaic counts them as seen by no frame), and the grid over a whole DEM is
    unchanged."""
    res = 0.5
    C = _centre(PRESETS_ORIGIN)
    dem0 = _dem(C)
    east = HeightRaster(dem0.heights_m[:, 160:].copy(), C[0], dem0.y_top_m, dem0.res_m, UTM49, "east DEM")
    holed = dem0.heights_m.copy()
    holed[:, :160] = np.nan
    holed = HeightRaster(holed, dem0.x_left_m, dem0.y_top_m, dem0.res_m, UTM49, "DEM with nodata in its west")
    kw = dict(to_project=GridToProject(UTM49, UTM49), partial=True)
    whole = frame_grid(DMC, C, R, dem0, res, UTM49, **kw)
    cut = frame_grid(DMC, C, R, east, res, UTM49, **kw)
    assert whole.x_left_m < C[0] - 300.0  # the frame reaches far west of its nadir
    assert C[0] - 2 * res - 1e-6 <= cut.x_left_m <= C[0] - res
    assert cut.x_left_m + cut.width * res == pytest.approx(whole.x_left_m + whole.width * res)
    assert (cut.y_top_m, cut.height) == (whole.y_top_m, whole.height)
    assert frame_grid(DMC, C, R, holed, res, UTM49, **kw) == whole
    assert frame_grid(DMC, C, R, dem0, res, UTM49, to_project=GridToProject(UTM49, UTM49)) == whole
