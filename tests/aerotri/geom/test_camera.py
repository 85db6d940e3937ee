"""Interior/exterior orientation conventions: collinearity, distortion, rotations, camera files."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aerotri.geom.camera import FrameCamera, dmc_camera
from aerotri.core.errors import InputError
from aerotri.geom.rotation import opk_from_matrix, rotation_matrix_opk


def test_nadir_frame_looks_down_with_image_top_north():
    cam = dmc_camera()
    C = np.array([1000.0, 2000.0, 1200.0])
    R = rotation_matrix_opk(0, 0, 0)
    # A point north of the nadir point appears above the image centre (smaller row), east to the right.
    x, y, depth = cam.project(np.array([[1000.0, 2100.0, 0.0], [1100.0, 2000.0, 0.0]]), C, R)
    assert depth[0] == pytest.approx(1200.0)
    assert y[0] < cam.cy_px and x[0] == pytest.approx(cam.cx_px)
    assert x[1] > cam.cx_px and y[1] == pytest.approx(cam.cy_px)
    # Scale: 100 m at 1200 m with f = 10000 px is 833.3 px.
    assert cam.cy_px - y[0] == pytest.approx(100.0 / 1200.0 * cam.focal_px)
    assert cam.gsd_m(1200.0) == pytest.approx(0.12)


@settings(max_examples=50, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-180, 180))
def test_opk_round_trip(omega, phi, kappa):
    R = rotation_matrix_opk(omega, phi, kappa)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    o, p, k = opk_from_matrix(R)
    assert np.allclose([o, p, k], [omega, phi, kappa], atol=1e-9)


def test_project_and_rays_are_inverse_with_distortion():
    cam = FrameCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.02, ppy_mm=-0.01,
                      k1=-4e-3, k2=1e-3, p1=1e-5, p2=-2e-5)
    rng = np.random.default_rng(0)
    C = np.array([0.0, 0.0, 800.0])
    R = rotation_matrix_opk(1.0, -1.5, 93.0)
    x = rng.uniform(0, cam.width - 1, 200)
    y = rng.uniform(0, cam.height - 1, 200)
    d = cam.rays(x, y, R)
    # Intersect with the plane Z = 0 and project back.
    t = -C[2] / d[:, 2]
    P = C + d * t[:, None]
    x2, y2, _ = cam.project(P, C, R)
    assert np.abs(x2 - x).max() < 1e-6 and np.abs(y2 - y).max() < 1e-6


def test_camera_file_round_trip_and_unit_errors(tmp_path):
    cam = FrameCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.1, k1=-4e-3)
    p = tmp_path / "camera.toml"
    p.write_text(cam.to_toml())
    assert FrameCamera.read(p) == cam
    p.write_text('focal_mm = 10000.0\npixel_um = 12.0\nwidth = 13824\nheight = 7680\n')
    with pytest.raises(InputError, match="focal length in millimetres"):
        FrameCamera.read(p)
    p.write_text('focal_mm = 120.0\nwidth = 13824\nheight = 7680\n')
    with pytest.raises(InputError, match="missing pixel_um"):
        FrameCamera.read(p)
