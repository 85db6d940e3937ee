"""Interior/exterior orientation conventions: collinearity, distortion, rotations, camera files, the camera
model hierarchy and its registry."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aerotri.geom.camera import (MODELS, SELF_CALIBRATION_GROUPS, BrownCamera, Camera, PinholeCamera,
                                 dmc_camera, read_camera)
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
    cam = BrownCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.02, ppy_mm=-0.01,
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
    cam = BrownCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.1, k1=-4e-3)
    p = tmp_path / "camera.toml"
    p.write_text(cam.to_toml())
    assert BrownCamera.read(p) == cam
    p.write_text('focal_mm = 10000.0\npixel_um = 12.0\nwidth = 13824\nheight = 7680\n')
    with pytest.raises(InputError, match="focal length in millimetres"):
        BrownCamera.read(p)
    p.write_text('focal_mm = 120.0\nwidth = 13824\nheight = 7680\n')
    with pytest.raises(InputError, match="missing pixel_um"):
        BrownCamera.read(p)


@pytest.mark.parametrize("key, value, match", [
    # the focal length in metres: 10 px on a 13824 px side; the adjustment stopped on a singular matrix
    ("focal_mm", "0.12", r"focal_mm = 0.12 is 10 px at pixel_um = 12: a field of view of 179.8 deg .* in metres\? "
                         r"0.12 m = 120 mm"),
    # the principal point in pixels: 900 px = 10.8 mm, outside the 7680 px x 12 um = 92.16 mm high frame
    ("ppy_mm", "-900.0", r"ppy_mm = -900 puts the principal point 977 % of the 7680 px side from the image centre "
                         r"\(limit 25 %, 23.04 mm\); expected the offset from the image centre in mm \(in pixels\?"),
    # 4,000 px on the 13824 px width: 29 %, inside the frame, which passed
    ("ppx_mm", "48.0", r"ppx_mm = 48 puts the principal point 29 % of the 13824 px side from the image centre"),
])
def test_camera_files_in_other_units_are_refused(tmp_path, key, value, match):
    good = {"focal_mm": "120.0", "pixel_um": "12.0", "width": "13824", "height": "7680", "ppx_mm": "0.1",
            "ppy_mm": "-0.2"}
    p = tmp_path / "camera.toml"
    p.write_text("".join(f"{k} = {value if k == key else v}\n" for k, v in good.items()))
    with pytest.raises(InputError, match=match):
        BrownCamera.read(p)
    p.write_text("".join(f"{k} = {v}\n" for k, v in good.items()))
    assert BrownCamera.read(p).focal_px == pytest.approx(10000.0)  # the same file in the keys' units reads


# -- the model hierarchy -------------------------------------------------------------------------------
BROWN = BrownCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.02, ppy_mm=-0.01,
                    k1=-4e-3, k2=1e-3, k3=2e-4, p1=1e-5, p2=-2e-5, name="DMC test")
PINHOLE = PinholeCamera(focal_mm=24, pixel_um=4.5, width=6000, height=4000, ppx_mm=0.05, ppy_mm=0.03, name="pin")


def test_the_models_and_their_names():
    import aerotri.geom.camera as camera_module

    assert not hasattr(camera_module, "FrameCamera")  # no alias: orthority's FrameCamera is a base class
    assert MODELS == {"brown": BrownCamera, "pinhole": PinholeCamera}
    assert issubclass(BrownCamera, Camera) and issubclass(PinholeCamera, Camera)
    assert dmc_camera().MODEL == "brown" and PINHOLE.coefficients == ()
    assert set(SELF_CALIBRATION_GROUPS) == {"focal", "pp", "radial", "tangential"}
    assert set(PinholeCamera.SELF_CAL_GROUPS) == {"focal", "pp"}


@pytest.mark.parametrize("cam", [BROWN, PINHOLE], ids=["brown", "pinhole"])
def test_pixel_ray_pixel_round_trip(cam):
    """pixel -> ray -> ground -> pixel for each model, over the whole frame including its corners."""
    rng = np.random.default_rng(1)
    C = np.array([100.0, -50.0, 900.0])
    R = rotation_matrix_opk(2.0, -1.0, 30.0)
    x = np.r_[rng.uniform(-0.5, cam.width - 0.5, 300), -0.5, cam.width - 0.5]
    y = np.r_[rng.uniform(-0.5, cam.height - 0.5, 300), -0.5, cam.height - 0.5]
    d = cam.rays(x, y, R)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    P = C + d * (-C[2] / d[:, 2])[:, None]
    x2, y2, depth = cam.project(P, C, R)
    assert np.all(depth > 0)
    assert np.abs(x2 - x).max() < 1e-7 and np.abs(y2 - y).max() < 1e-7
    xn, yn = cam.pixel_to_normalized(x, y)
    assert np.abs(np.array(cam.normalized_to_pixel(xn, yn)) - [x, y]).max() < 1e-7


def test_pinhole_is_brown_without_distortion():
    brown = BrownCamera(**{f: getattr(PINHOLE, f) for f in ("focal_mm", "pixel_um", "width", "height", "ppx_mm", "ppy_mm")})
    P = np.array([[10.0, 20.0, 0.0], [-300.0, 150.0, 12.0]])
    C, R = np.array([0.0, 0.0, 500.0]), rotation_matrix_opk(1.0, 2.0, 3.0)
    assert np.array_equal(np.array(PINHOLE.project(P, C, R)), np.array(brown.project(P, C, R)))
    xn, yn = np.array([0.1, -0.3]), np.array([0.2, 0.05])
    assert np.array_equal(np.array(PINHOLE.distort(xn, yn)), [xn, yn])
    assert np.array_equal(PINHOLE.distort_jacobian(xn, yn), np.broadcast_to(np.eye(2), (2, 2, 2)))
    assert PINHOLE.coefficient_jacobian(xn, yn).shape == (2, 2, 0)
    assert np.array_equal(PINHOLE.calibration_vector(), [PINHOLE.focal_px, PINHOLE.focal_px, 0.0, PINHOLE.cx_px,
                                                         PINHOLE.cy_px, 0, 0, 0, 0])


@pytest.mark.parametrize("cam", [BROWN, PINHOLE], ids=["brown", "pinhole"])
def test_camera_files_name_their_model(cam, tmp_path):
    p = tmp_path / "camera.toml"
    p.write_text(cam.to_toml())
    assert f'model = "{cam.MODEL}"' in p.read_text()
    back = Camera.read(p)
    assert type(back) is type(cam) and back == cam
    assert BrownCamera.read(p) == cam  # the file's model decides, whatever class reads it
    assert read_camera(p) == cam and Camera.from_dict(cam.to_dict()) == cam
    with pytest.raises(InputError, match="model = 'fisheye' is not one of"):
        Camera.from_dict({**cam.to_dict(), "model": "fisheye"}, source="cam.toml")


def test_camera_files_without_model_are_brown(tmp_path):
    """Camera files written before the model key existed."""
    p = tmp_path / "camera.toml"
    p.write_text('name = "old"\nfocal_mm = 120.0\npixel_um = 12.0\nwidth = 13824\nheight = 7680\nk1 = -0.004\nk3 = 1e-4\n')
    cam = BrownCamera.read(p)
    assert type(cam) is BrownCamera and cam.k1 == -0.004 and cam.k3 == 1e-4 and cam.p1 == 0.0
    p.write_text('model = "pinhole"\nfocal_mm = 24.0\npixel_um = 4.5\nwidth = 6000\nheight = 4000\nk1 = -0.004\n')
    with pytest.raises(InputError, match=r"unknown keys \['k1'\] for model 'pinhole'"):
        Camera.read(p)


def test_calibration_vector_round_trip():
    """Cal3DS2 values of a camera and back (k3 is not in Cal3DS2: it stays)."""
    cal = BROWN.calibration_vector()
    assert np.allclose(cal[5:], [BROWN.k1, BROWN.k2, BROWN.p1, BROWN.p2], rtol=0, atol=0)
    same = BROWN.from_calibration_vector(cal)
    assert same.focal_mm == pytest.approx(BROWN.focal_mm, rel=1e-15) and same.k3 == BROWN.k3
    back = BROWN.from_calibration_vector(cal + np.array([2.0, 4.0, 0, 1.5, -2.5, 1e-4, 0, 0, 1e-6]))
    assert back.focal_px == pytest.approx(BROWN.focal_px + 3.0)
    assert back.cx_px == pytest.approx(BROWN.cx_px + 1.5) and back.cy_px == pytest.approx(BROWN.cy_px - 2.5)
    assert back.k1 == BROWN.k1 + 1e-4 and back.p2 == BROWN.p2 + 1e-6 and back.k3 == BROWN.k3
    pin = PINHOLE.from_calibration_vector(PINHOLE.calibration_vector() + np.array([1.0, 1.0, 0, 0.5, 0, 0, 0, 0, 0]))
    assert type(pin) is PinholeCamera and pin.cx_px == pytest.approx(PINHOLE.cx_px + 0.5)


def test_calibration_observations_take_k3_off():
    """The measurements the adjustment's Cal3DS2 (no k3) sees: the same rays through the camera without k3."""
    rng = np.random.default_rng(2)
    xy = np.column_stack([rng.uniform(0, BROWN.width - 1, 50), rng.uniform(0, BROWN.height - 1, 50)])
    no_k3 = dataclasses.replace(BROWN, k3=0.0)
    xn, yn = BROWN.pixel_to_normalized(xy[:, 0], xy[:, 1])
    expected = np.column_stack(no_k3.normalized_to_pixel(xn, yn))
    assert np.abs(BROWN.calibration_observations(xy) - expected).max() < 1e-9
    assert no_k3.calibration_observations(xy) is xy and PINHOLE.calibration_observations(xy) is xy


def test_colmap_models():
    name, params = BROWN.colmap_model()
    assert name == "FULL_OPENCV" and len(params) == 12
    assert params[:4] == [BROWN.focal_px, BROWN.focal_px, BROWN.cx_px + 0.5, BROWN.cy_px + 0.5]
    assert params[4:9] == [BROWN.k1, BROWN.k2, BROWN.p1, BROWN.p2, BROWN.k3]
    assert dataclasses.replace(BROWN, k3=0.0).colmap_model()[0] == "OPENCV"
    assert PINHOLE.colmap_model() == ("PINHOLE", [PINHOLE.focal_px, PINHOLE.focal_px, PINHOLE.cx_px + 0.5,
                                                  PINHOLE.cy_px + 0.5])


def test_ideal_keeps_the_model():
    assert BROWN.ideal() == BrownCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, name="DMC test")
    assert type(PINHOLE.ideal()) is PinholeCamera and PINHOLE.ideal().ppx_mm == 0.0


def test_points_beyond_the_lens_fold_do_not_project_into_the_frame():
    """DJI DewarpData-like radial terms (k1 = -0.27) fold 53 deg off the axis: the model's image radius turns back
    there, and a point 61 deg off the axis would land inside the frame. ``project`` gives NaN for it, as for a point behind
    the camera; inside the fold the projection is as before (a round trip through ``rays``)."""
    import math

    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.lens_kernels import distort_points
    from aerotri.geom.rotation import rotation_matrix_opk

    cam = BrownCamera(focal_mm=8.77, pixel_um=9.6, width=684, height=456, k1=-0.267, k2=0.112, k3=-0.0332)
    fold = cam.fold_radius()
    assert math.degrees(math.atan(fold)) == pytest.approx(53.4, abs=0.3)
    # the model does turn back: the distorted radius at r = 1.6 below its value at the fold
    rd = [np.hypot(*distort_points(cam.kernel_params(), np.array([r]), np.array([0.0])))[0] for r in (fold, 1.6)]
    assert rd[1] < rd[0]
    C, R = np.array([0.0, 0.0, 100.0]), rotation_matrix_opk(0.0, 0.0, 0.0)
    far = np.array([[180.0, 0.0, 0.0]])  # 61 deg off the axis: r = 1.8
    x, y, depth = cam.project(far, C, R)
    assert np.isnan(x[0]) and np.isnan(y[0]) and depth[0] > 0
    # without the fold test the model would have put it inside the frame
    xd, _ = distort_points(cam.kernel_params(), np.array([1.8]), np.array([0.0]))
    assert 0 <= cam.focal_px * xd[0] + cam.cx_px <= cam.width - 1
    xs, ys = np.meshgrid(np.linspace(0, cam.width - 1, 7), np.linspace(0, cam.height - 1, 5))
    d = cam.rays(xs.ravel(), ys.ravel(), R)
    P = C + d * (100.0 / -d[:, 2:3])
    x, y, _ = cam.project(P, C, R)
    assert np.allclose(x, xs.ravel(), atol=1e-3) and np.allclose(y, ys.ravel(), atol=1e-3)


def test_a_camera_file_with_a_focal_length_over_a_hundred_sides_is_refused(tmp_path):
    """A pixel size 16 x too small on 1728 px frames (0.6 for 9.6 um): a 200,000 px, 0.5 deg lens. A 600 mm lens on
    an APS-C back (23.5 mm, 6000 px: 25.5 sides), which the former 20 sides refused, reads."""
    p = tmp_path / "camera.toml"
    p.write_text("focal_mm = 120.0\npixel_um = 0.6\nwidth = 1728\nheight = 960\n")
    with pytest.raises(InputError, match=r"focal_mm = 120 is 200000 px at pixel_um = 0.6: a field of view of 0.5 deg "
                                         r"across the 1728 px side, expected a focal length of at most 100 x that side"):
        BrownCamera.read(p)
    p.write_text("focal_mm = 600.0\npixel_um = 3.9167\nwidth = 6000\nheight = 4000\n")
    assert BrownCamera.read(p).focal_px / 6000 == pytest.approx(25.5, abs=0.05)


def test_a_principal_point_over_a_quarter_of_the_side_off_the_centre_is_refused():
    """Exactly half the frame off (COLMAP's cx = 0 read as pixels from the corner) passed the strict "outside the
    frame" test; the limit is now a quarter of the side, real cameras are near 0."""
    for share, refused in ((0.5, True), (0.26, True), (0.24, False), (0.0048, False)):
        cam = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=13824, height=7680, ppy_mm=-share * 7680 * 0.012)
        if refused:
            with pytest.raises(InputError, match=r"ppy_mm = .* puts the principal point .* % of the 7680 px side"):
                cam.check_plausible("camera.toml")
        else:
            cam.check_plausible("camera.toml")


def test_lens_coefficients_that_turn_back_inside_the_frame_are_refused(tmp_path):
    """trial-cam F3: a radial table value in um typed as k1 (-12.5 on a Phase One iXM-100 at 50 mm) folds the lens
    model 9 deg off the axis, inside the frame (corner 29 deg); init and adjust took it and the adjustment ended in a
    LinAlgError traceback. A DJI lens whose model folds just past its corners (k1 = -0.267) still reads."""
    p = tmp_path / "camera.toml"
    p.write_text("focal_mm = 50.0\npixel_um = 3.76\nwidth = 11664\nheight = 8750\nk1 = -12.5\n")
    with pytest.raises(InputError, match=r"camera.toml: the lens coefficients \(k1 = -12.5\) make the lens model turn "
                                         r"back 9\.\d deg off the axis, inside the frame \(its corner 2\d\.\d deg\): "
                                         r"expected coefficients on normalised image coordinates"):
        BrownCamera.read(p)
    p.write_text("focal_mm = 50.0\npixel_um = 3.76\nwidth = 11664\nheight = 8750\nk1 = -0.01\nk2 = 0.005\n")
    assert BrownCamera.read(p).k1 == -0.01
    dji = BrownCamera(focal_mm=8.77, pixel_um=9.6, width=684, height=456, k1=-0.267, k2=0.112, k3=-0.0332)
    assert dji.fold_radius() is not None  # 53 deg, past the corners (test_points_beyond_the_lens_fold_...)
    dji.check_plausible("camera.toml")
