"""The rectifier's ground -> image mapping on the earth (issue 42: a full-size DOM 1.9 GSD off with the true
orientations): orientations in a projected CRS mean the ENU frame at the centre (as the adjustment solves and the
simulator renders), so a UTM block's ground must reach the camera through it, not as if easting, northing and
height were Cartesian (400 ppm of scale and (R + h) / R at the presets' origin: 2.3 px at a DMC frame's edge).

Known truth: ``aerotri.geom.local_frame.LocalFrame`` (exact, at the block's centre, as ``aerotri.sim.earth``). The
frame's samples are their own image coordinates (float ramps), so the rectified value of a cell is where the
rectifier sampled the frame for it."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

from aerotri.geom.camera import BrownCamera
from aerotri.geom.local_frame import CameraOnEarth, LocalFrame
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.dem import HeightRaster
from ortho.grid import OrthoGrid
from ortho.rectify import rectify_frame

UTM49 = CRS.from_epsg(32649)
GROUND_Z = 310.0  # the dmc_block preset's flat town, ellipsoidal height
# the DMC's geometry (f 120 mm, 13,824 x 7,680 px at 1,000 m) with pixels 8 times the size: the same ground and
# angles, 0.8 m GSD
CAMERA = BrownCamera(focal_mm=120.0, pixel_um=96.0, width=1728, height=960, ppx_mm=0.10, ppy_mm=-0.06, k1=-4e-3,
                     k2=1e-3, name="dmc/8")
RES = 0.8


def _frame(centre_e_n):
    C = np.array([centre_e_n[0], centre_e_n[1], GROUND_Z + 1000.0])
    R = rotation_matrix_opk(0.4, -0.3, -92.0)
    return C, R


def _exact_positions(C, R, X, Y):
    """Image x, y of ground points through the ENU frame of a block centred 2 km away (not the frame's own)."""
    frame = LocalFrame(UTM49, (C[0] + 2000.0, C[1] - 1000.0, GROUND_Z))
    P = np.stack([X, Y, np.full(X.shape, GROUND_Z)], axis=-1)
    R_enu = frame.rotation_local_from_map(C)[0] @ R
    x, y, _ = CAMERA.project(frame.to_local(P), frame.to_local(C)[0], R_enu)
    return x, y


def _rectified_positions(C, R, earth):
    dem = HeightRaster(np.full((400, 400), GROUND_Z, np.float32), C[0] - 1000.0, C[1] + 1000.0, 5.0, UTM49, "flat DEM")
    grid = OrthoGrid(UTM49, C[0] - 720.0, C[1] + 720.0, RES, 1800, 1800)
    yy, xx = np.mgrid[0:CAMERA.height, 0:CAMERA.width].astype(np.float32)
    ramps = np.ascontiguousarray(np.stack([xx, yy], axis=-1))
    ortho, mask = rectify_frame(ramps, CAMERA, C, R, dem, grid, tile_px=512, earth=earth)
    cols, rows = np.meshgrid(np.arange(grid.width), np.arange(grid.height))
    X = grid.x_left_m + (cols + 0.5) * RES
    Y = grid.y_top_m - (rows + 0.5) * RES
    ok = mask > 0
    # keep a pixel clear of the frame's edge, where the bilinear ramp meets the border
    ok &= (ortho[..., 0] > 1) & (ortho[..., 0] < CAMERA.width - 2) & (ortho[..., 1] > 1) & (ortho[..., 1] < CAMERA.height - 2)
    return ortho[ok, 0], ortho[ok, 1], X[ok], Y[ok]


@pytest.mark.parametrize("centre", [(452464.0, 3407774.0), (500000.0, 3000300.0)])
def test_rectifier_maps_ground_to_the_frame_through_the_earth(centre):
    """At the presets' origin (48 km from zone 49's central meridian) and on the central meridian (scale 0.9996):
    the rectified frame samples every cell where the exact earth puts it (1/32 px maps), the flat mapping up to
    2.3/8 px off, radially (the ground 400 ppm too close to the nadir)."""
    C, R = _frame(centre)
    x, y, X, Y = _rectified_positions(C, R, earth=True)
    assert len(x) > 500_000  # the frame's whole footprint
    xe, ye = _exact_positions(C, R, X, Y)
    err = np.hypot(x - xe, y - ye)
    assert err.max() < 0.05  # cv2.remap's 1/32 px, the 1 mm of the per-tile linearisation
    xf, yf, Xf, Yf = _rectified_positions(C, R, earth=False)
    xe, ye = _exact_positions(C, R, Xf, Yf)
    flat = np.hypot(xf - xe, yf - ye)
    assert flat.max() > 0.25  # the flat world's ~400 ppm at the frame's corners (0.29 px here, 2.3 px full size)
    # radial: the flat mapping samples the frame closer to the principal point than the ground is seen
    cx, cy = CAMERA.cx_px, CAMERA.cy_px
    r_flat, r_true = np.hypot(xf - cx, yf - cy), np.hypot(xe - cx, ye - cy)
    far = r_true > 600
    assert np.all(r_flat[far] < r_true[far])
    assert np.median((r_true[far] - r_flat[far]) / r_true[far]) == pytest.approx(4.0e-4, abs=0.4e-4)


def test_camera_on_earth_is_the_flat_collinearity_in_an_engineering_crs():
    local = CRS.from_wkt('ENGCRS["site",EDATUM["site"],CS[Cartesian,2],AXIS["x",east,ORDER[1],LENGTHUNIT["metre",1]],'
                         'AXIS["y",north,ORDER[2],LENGTHUNIT["metre",1]]]')
    C, R = _frame((1000.0, 2000.0))
    earth = CameraOnEarth(local, C, R)
    assert earth.flat and earth.inv_radius == 0.0
    np.testing.assert_array_equal(earth.M, (R @ np.diag([1.0, -1.0, -1.0])).T)


def test_camera_on_earth_second_order_against_the_exact_transformation():
    """The ray of ``M (dx, dy, earth_dz)`` passes within 1.5 mm of the exact point (``LocalFrame``) up to 1.4 km from
    the centre and 50-1,100 m below it (0.01 px of a DMC frame); the flat collinearity's misses by up to 0.25 m."""
    from aerotri.geom.local_frame import earth_dz

    C, R = _frame((452464.0, 3407774.0))
    earth = CameraOnEarth(UTM49, C, R)
    rng = np.random.default_rng(3)
    d = np.column_stack([rng.uniform(-1000, 1000, 500), rng.uniform(-1000, 1000, 500), rng.uniform(-1100, -50, 500)])
    exact = earth.to_camera(C + d)
    v = np.column_stack([d[:, 0], d[:, 1], earth_dz(d[:, 0], d[:, 1], d[:, 2], earth.inv_radius)]) @ earth.M.T
    # the same direction: the offset across the ray, metres
    u = exact / np.linalg.norm(exact, axis=1, keepdims=True)
    across = v - (v * u).sum(axis=1, keepdims=True) * u
    assert np.linalg.norm(across, axis=1).max() < 1.5e-3
    flat = d @ (R @ np.diag([1.0, -1.0, -1.0]))  # (R FLIP_YZ)^T applied to row vectors
    across_flat = flat - (flat * u).sum(axis=1, keepdims=True) * u
    assert np.linalg.norm(across_flat, axis=1).max() > 0.2  # about 400 ppm of the distance across the ray
