"""The compiled lens kernels of each camera model: the textbook formulas, the camera classes' array
methods, inverses and Jacobians (finite differences), and the registry that dispatches them."""

import dataclasses

import numba
import numpy as np
import pytest

from aerotri.geom import lens_kernels as lk
from aerotri.geom.camera import MODELS, BrownCamera, PinholeCamera

BROWN = BrownCamera(focal_mm=120, pixel_um=12, width=13824, height=7680, ppx_mm=0.02, ppy_mm=-0.01,
                    k1=-4e-2, k2=1e-2, k3=2e-3, p1=1e-4, p2=-2e-4)
PINHOLE = PinholeCamera(focal_mm=24, pixel_um=4.5, width=6000, height=4000, ppx_mm=0.05, ppy_mm=0.03)
CAMERAS = pytest.mark.parametrize("cam", [BROWN, PINHOLE], ids=["brown", "pinhole"])


def _normalised(cam, n=400, seed=0):
    """Normalised coordinates over the frame, corners included."""
    rng = np.random.default_rng(seed)
    half_w, half_h = cam.width / 2 / cam.focal_px, cam.height / 2 / cam.focal_px
    xn = np.r_[rng.uniform(-half_w, half_w, n), -half_w, half_w]
    yn = np.r_[rng.uniform(-half_h, half_h, n), half_h, -half_h]
    return xn, yn


# the orthorectification's flags: the kernels are inlined and compiled with the caller's fast-math
@numba.njit(fastmath={"contract", "arcp", "reassoc", "nsz", "afn"})
def _to_pixel_fastmath(params, xn, yn):
    x, y = np.empty_like(xn), np.empty_like(yn)
    for k in range(len(xn)):
        x[k], y[k] = lk.to_pixel(params, xn[k], yn[k])
    return x, y


@numba.njit
def _to_normalised(params, x, y, iterations):
    xn, yn = np.empty_like(x), np.empty_like(y)
    for k in range(len(x)):
        xn[k], yn[k] = lk.to_normalised(params, x[k], y[k], iterations)
    return xn, yn


def test_every_model_has_kernels():
    for cls in MODELS.values():
        cam = cls(focal_mm=50, pixel_um=5, width=100, height=80)
        params = cam.kernel_params()
        assert type(params) in lk.MODEL_KERNELS
        assert params[:3] == (cam.focal_px, cam.cx_px, cam.cy_px)
        assert lk.MODEL_KERNELS[type(params)].n_coefficients == len(cls.COEFFICIENTS) == len(params) - 3


def test_brown_kernel_is_the_textbook_formula():
    xn, yn = _normalised(BROWN)
    k1, k2, k3, p1, p2 = BROWN.coefficients
    r2 = xn**2 + yn**2
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn**2)
    yd = yn * radial + p1 * (r2 + 2 * yn**2) + 2 * p2 * xn * yn
    got = BROWN.distort(xn, yn)
    assert np.abs(got[0] - xd).max() < 1e-15 and np.abs(got[1] - yd).max() < 1e-15
    assert np.abs(xd - xn).max() > 1e-3  # the distortion is not negligible here


@CAMERAS
def test_compiled_kernels_agree_with_the_array_methods(cam):
    """What a compiled kernel computes (ortho: inlined under fast-math) = the camera's array methods."""
    xn, yn = _normalised(cam)
    x, y = cam.normalized_to_pixel(xn, yn)
    xf, yf = _to_pixel_fastmath(cam.kernel_params(), xn, yn)
    assert np.abs(xf - x).max() < 1e-12 * cam.width and np.abs(yf - y).max() < 1e-12 * cam.width
    a, b = cam.pixel_to_normalized(x, y)
    c, d = _to_normalised(cam.kernel_params(), x, y, 20)
    assert np.array_equal(a, c) and np.array_equal(b, d)


@CAMERAS
def test_undistort_inverts_distort(cam):
    xn, yn = _normalised(cam)
    xd, yd = cam.distort(xn, yn)
    xu, yu = cam.undistort(xd, yd)
    assert np.abs(xu - xn).max() < 1e-12 and np.abs(yu - yn).max() < 1e-12


@CAMERAS
def test_distortion_jacobian_matches_finite_differences(cam):
    xn, yn = _normalised(cam, 50)
    J = cam.distort_jacobian(xn, yn)
    h = 1e-6
    for c, (dx, dy) in enumerate(((h, 0.0), (0.0, h))):
        up = np.array(cam.distort(xn + dx, yn + dy))
        dn = np.array(cam.distort(xn - dx, yn - dy))
        assert np.abs(J[:, :, c] - ((up - dn) / (2 * h)).T).max() < 1e-8


@CAMERAS
def test_coefficient_jacobian_matches_finite_differences(cam):
    xn, yn = _normalised(cam, 50)
    J = cam.coefficient_jacobian(xn, yn)
    assert J.shape == (len(xn), 2, len(cam.COEFFICIENTS))
    h = 1e-6
    for c, name in enumerate(cam.COEFFICIENTS):
        v = getattr(cam, name)
        up = np.array(dataclasses.replace(cam, **{name: v + h}).distort(xn, yn))
        dn = np.array(dataclasses.replace(cam, **{name: v - h}).distort(xn, yn))
        assert np.abs(J[:, :, c] - ((up - dn) / (2 * h)).T).max() < 1e-9


def test_unknown_parameter_tuple_is_refused():
    with pytest.raises(Exception, match="no lens kernels"):
        lk.distort_points((1.0, 2.0, 3.0), np.zeros(2), np.zeros(2))
