"""The control stage's projections of LiDAR corners on the earth (issue 42): orientations in a projected CRS mean the
ENU frame at the centre (as the adjustment solves and the simulator renders), so a corner's predicted image position,
its search window's edge directions and the multi-ray check go through ``FramesOnEarth``, not easting, northing and
height taken as a Cartesian frame (400 ppm at the presets' origin: 2.8 px of a full-size DMC frame 700 m from the
nadir at 0.1 m GSD).

Known truth: ``LocalFrame`` (exact) at a block centre 2 km away, independent of the frame ``FramesOnEarth`` picks."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

from aerotri.control.consistency import check_rays
from aerotri.control.measure import corner_points, predict
from aerotri.geom.camera import BrownCamera
from aerotri.geom.local_frame import FramesOnEarth, LocalFrame
from aerotri.geom.rotation import rotation_matrix_opk

UTM49 = CRS.from_epsg(32649)
GROUND_Z = 310.0
# a full-size Z/I DMC: f 120 mm, 12 um pixels, 13,824 x 7,680 px; 0.1 m GSD 1,000 m above the ground
DMC = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=13824, height=7680, ppx_mm=0.10, ppy_mm=-0.06, k1=-4e-3,
                  k2=1e-3, name="dmc")
ORIGIN = np.array([452464.0, 3407774.0])  # the presets' origin, 48 km from zone 49's central meridian


def _strip(n=3, base_m=280.0):
    """Frames of a strip flown east at 1,000 m over the ground (kappa -90: the frame's long side across the strip)."""
    C = np.array([[ORIGIN[0] + k * base_m, ORIGIN[1], GROUND_Z + 1000.0] for k in range(n)])
    R = rotation_matrix_opk(np.full(n, 0.4), np.full(n, -0.3), np.full(n, -90.5))
    return C, R


def _exact(C, R, P):
    """Image x, y (N,) of map points P (N, 3) in a frame at C, R: through the ENU frame of a block centre 2 km away."""
    frame = LocalFrame(UTM49, (C[0] + 2000.0, C[1] - 1000.0, GROUND_Z))
    R_enu = frame.rotation_local_from_map(C)[0] @ R
    x, y, _ = DMC.project(frame.to_local(P), frame.to_local(C)[0], R_enu)
    return x, y


def _corners_700m(C):
    """Corners of roofs 650-700 m from the nadir of a frame at C, towards the frame's four corners and sides."""
    off = np.array([[250.0, 650.0], [-250.0, -650.0], [250.0, -650.0], [-250.0, 650.0], [0.0, 680.0], [0.0, -650.0]])
    xyz = np.column_stack([C[0] + off[:, 0], C[1] + off[:, 1], np.full(len(off), GROUND_Z + 12.0)])
    edges = np.repeat(np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]), len(off), axis=0)
    sigma = np.tile([0.1, 0.1, 0.05], (len(off), 1))
    return xyz, edges, sigma


def test_predicted_corner_positions_on_the_earth():
    """A full-size DMC frame in UTM: corners 650-700 m from the nadir predicted within 1e-3 px of the exact image
    position (were 2.6-2.7 px off: the flat collinearity, radially inwards); the edge directions within 1e-5 rad."""
    C, R = _strip(1)
    xyz, edges, sigma = _corners_700m(C[0])
    xe, ye = _exact(C[0], R[0], xyz)
    assert np.all(DMC.inside(xe, ye, margin_px=50))
    earth = FramesOnEarth(UTM49, C, R)
    x, y, d, s_px, _ = predict(DMC, earth, 0, corner_points(earth, xyz, edges, sigma))
    after = np.hypot(x - xe, y - ye)
    assert after.max() < 1e-3
    flat = FramesOnEarth.cartesian(C, R)  # the stage before: map coordinates as a Cartesian frame
    xf, yf, df, sf_px, _ = predict(DMC, flat, 0, corner_points(flat, xyz, edges, sigma))
    before = np.hypot(xf - xe, yf - ye)
    assert before.min() > 2.0 and before.max() > 2.5  # 400 ppm of 660-730 m at 0.1 m GSD
    r_true, r_flat = np.hypot(xe - DMC.cx_px, ye - DMC.cy_px), np.hypot(xf - DMC.cx_px, yf - DMC.cy_px)
    assert np.all(r_flat < r_true)  # the ground too near the nadir
    # the image directions of the roof edges (2 m either side of the corner) against the exact ones
    for j in range(2):
        xa, ya = _exact(C[0], R[0], xyz + 2.0 * edges[:, j])
        xb, yb = _exact(C[0], R[0], xyz - 2.0 * edges[:, j])
        de = np.stack([xa - xb, ya - yb], axis=-1)
        de /= np.linalg.norm(de, axis=-1, keepdims=True)
        assert np.abs(d[:, j, 0] * de[:, 1] - d[:, j, 1] * de[:, 0]).max() < 1e-5  # sine of the angle
    np.testing.assert_allclose(s_px, sf_px, rtol=2e-3)  # the window size is not what moved


def test_ray_check_on_the_earth():
    """Three full-size frames measure a corner exactly where the earth puts it (630 m across the strip from the
    nadirs): the check intersects it within 1 mm of the LiDAR corner with residuals below 1e-3 px. The flat
    intersection's rays, each 400 ppm outwards about its own centre, still meet (0.03 px), 0.38 m above the corner:
    a horizontal scale about centres at one height is a vertical one."""
    C, R = _strip(3)
    P = np.array([C[1, 0] + 40.0, C[1, 1] + 630.0, GROUND_Z + 12.0])
    xy = np.array([np.ravel(_exact(C[i], R[i], P[None])) for i in range(3)])
    assert np.all(DMC.inside(xy[:, 0], xy[:, 1], margin_px=50))
    sigma = np.array([0.1, 0.1, 0.05])
    r = check_rays(DMC, FramesOnEarth(UTM49, C, R), np.arange(3), xy, P, sigma)
    assert r.ok and r.kept.all()
    assert np.abs(r.residual_px).max() < 1e-3
    assert np.linalg.norm(r.point_m - P) < 1e-3
    flat = check_rays(DMC, FramesOnEarth.cartesian(C, R), np.arange(3), xy, P, sigma)
    assert 0.3 < flat.lidar_diff_m[2] < 0.45  # 400 ppm of the 990 m below the cameras
    assert np.abs(r.lidar_diff_m).max() < 1e-3


def test_engineering_crs_is_the_flat_collinearity_to_the_bit():
    """In an engineering CRS (and ``cartesian``) the projections are ``Camera.project`` / ``Camera.rays`` of the map
    coordinates themselves, bit for bit."""
    local = CRS.from_wkt('ENGCRS["site",EDATUM["site"],CS[Cartesian,2],AXIS["x",east,ORDER[1],LENGTHUNIT["metre",1]],'
                         'AXIS["y",north,ORDER[2],LENGTHUNIT["metre",1]]]')
    C, R = _strip(2)
    C = C - [ORIGIN[0], ORIGIN[1], 0.0]
    xyz, edges, sigma = _corners_700m(C[0])
    for frames in (FramesOnEarth(local, C, R), FramesOnEarth.cartesian(C, R)):
        assert frames.flat
        for i in range(2):
            np.testing.assert_array_equal(np.array(frames.project(DMC, i, xyz)), np.array(DMC.project(xyz, C[i], R[i])))
            x, y = np.array([10.0, 7000.0]), np.array([20.0, 3000.0])
            d = DMC.rays(x, y, R[i])
            t = (GROUND_Z - C[i, 2]) / d[:, 2]
            flat = np.stack([C[i, 0] + t * d[:, 0], C[i, 1] + t * d[:, 1], np.full(2, GROUND_Z)], axis=-1)
            np.testing.assert_array_equal(frames.at_height(i, frames.rays_local(DMC, i, x, y), GROUND_Z), flat)


@pytest.mark.parametrize("centre", [(452464.0, 3407774.0), (500000.0, 3000300.0)])
def test_rays_at_a_height_land_where_the_camera_sees_them(centre):
    """``FramesOnEarth.at_height``: the map point of a pixel's ray at a map height, projected exactly, is the pixel
    (within 1e-4 px) at the frame's corners and 300 m below the ground too."""
    C = np.array([[centre[0], centre[1], GROUND_Z + 1000.0]])
    R = rotation_matrix_opk(0.4, -0.3, -92.0)[None]
    earth = FramesOnEarth(UTM49, C, R)
    x = np.array([0.0, DMC.width - 1.0, DMC.width - 1.0, 0.0, DMC.width / 2])
    y = np.array([0.0, 0.0, DMC.height - 1.0, DMC.height - 1.0, DMC.height / 2])
    for z in (GROUND_Z, GROUND_Z - 300.0):
        G = earth.at_height(0, earth.rays_local(DMC, 0, x, y), z)
        np.testing.assert_allclose(G[:, 2], z, atol=1e-6)
        xe, ye = _exact(C[0], R[0], G)
        assert np.hypot(xe - x, ye - y).max() < 1e-3
