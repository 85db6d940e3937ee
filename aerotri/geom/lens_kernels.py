"""Compiled (numba) lens models: the one implementation of each camera model's lens arithmetic.

Every camera model (``aerotri.geom.camera``) has its parameter tuple, a ``typing.NamedTuple`` of floats
that the compiled kernels take (``Camera.kernel_params()``); its first three fields are always
``f`` (focal length, px), ``cx``, ``cy`` (principal point, px, origin at the centre of the top-left
pixel), its lens coefficients follow:

- ``BrownParams(f, cx, cy, k1, k2, k3, p1, p2)``: Brown's radial (k1 k2 k3) and tangential (p1 p2)
  distortion on normalised coordinates, the OpenCV / COLMAP / GTSAM Cal3DS2 convention;
- ``PinholeParams(f, cx, cy)``: no distortion.

Each model implements four scalar kernels on normalised coordinates (x/z, y/z in the computer-vision
camera frame, dimensionless):

- ``distort(params, xn, yn) -> (xd, yd)``;
- ``distort_jacobian(params, xn, yn) -> (a00, a01, a10, a11)``: d(xd, yd) / d(xn, yn);
- ``coefficient_jacobian(params, xn, yn, out)``: d(xd, yd) / d(lens coefficients), into ``out`` (2, n)
  (the self-calibration derivatives; n = 0 for the pinhole);
- ``undistort(params, xd, yd, iterations) -> (xn, yn)``: the inverse of ``distort`` by fixed-point
  iteration.

They are generic functions dispatched on the parameter tuple's type at compile time (``MODEL_KERNELS``:
one entry per model), inlined into the caller (which compiles them with its own flags, e.g. fast-math in
the orthorectification), so a kernel written once against ``to_pixel``/``to_normalised`` serves every
model. The ``*_points`` functions apply them over arrays: the numpy side (``Camera.distort`` ..., the
adjustment's vectorised collinearity) calls those, so no formula exists twice. A new model: its
NamedTuple, its four kernels and one ``MODEL_KERNELS`` entry here, its class in ``aerotri.geom.camera``.

The Brown formulas keep the operation order of gtsam's Cal3DS2 (``1 + k1 r2 + k2 r2^2 + k3 r2^3``), so
the adjustment (Cal3DS2 without k3: ``k3 = 0`` adds exact zeros) gives the same bits as before.

Note numba's cache checks only the source file of a cached function: after editing this module, clear
the ``__pycache__/*.nbi|*.nbc`` files of its callers (schur, collinearity, ortho's rectify/synthetic).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import numba
import numpy as np
from numba.extending import overload


class BrownParams(NamedTuple):
    """Kernel parameters of the Brown camera: focal length and principal point (px), then k1 k2 k3 p1 p2."""

    f: float
    cx: float
    cy: float
    k1: float
    k2: float
    k3: float
    p1: float
    p2: float


class BrownCoefficients(NamedTuple):
    """Brown's lens coefficients alone (radial k1 k2 k3, tangential p1 p2): what the ``brown_*`` kernels read
    (a ``BrownParams`` serves as well, it has the same fields)."""

    k1: float
    k2: float
    k3: float
    p1: float
    p2: float


class PinholeParams(NamedTuple):
    """Kernel parameters of the pinhole camera: focal length and principal point (px)."""

    f: float
    cx: float
    cy: float


# -- Brown -------------------------------------------------------------------------------------------
@numba.njit(cache=True, inline="always")
def _brown_radial(r2, k1, k2, k3):
    return 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2


@numba.njit(cache=True, inline="always")
def brown_distort(xn, yn, c):
    """Distorted normalised coordinates (xd, yd); ``c``: the coefficients (``BrownCoefficients`` or ``BrownParams``)."""
    k1, k2, k3, p1, p2 = c.k1, c.k2, c.k3, c.p1, c.p2
    r2 = xn * xn + yn * yn
    radial = _brown_radial(r2, k1, k2, k3)
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    return xd, yd


@numba.njit(cache=True, inline="always")
def brown_distort_jacobian(xn, yn, c):
    """d(xd, yd) / d(xn, yn) as (a00, a01, a10, a11) (a10 = a01); ``c`` as in ``brown_distort``."""
    k1, k2, k3, p1, p2 = c.k1, c.k2, c.k3, c.p1, c.p2
    r2 = xn * xn + yn * yn
    radial = _brown_radial(r2, k1, k2, k3)
    dr = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2  # d radial / d r2
    a00 = radial + 2.0 * xn * xn * dr + 2.0 * p1 * yn + 6.0 * p2 * xn
    a01 = 2.0 * xn * yn * dr + 2.0 * p1 * xn + 2.0 * p2 * yn
    a11 = radial + 2.0 * yn * yn * dr + 6.0 * p1 * yn + 2.0 * p2 * xn
    return a00, a01, a01, a11


@numba.njit(cache=True, inline="always")
def brown_coefficient_jacobian(xn, yn):
    """d xd / d(k1 k2 k3 p1 p2) and d yd / d(k1 k2 k3 p1 p2) (two 5-tuples; distortion is linear in them)."""
    r2 = xn * xn + yn * yn
    return ((xn * r2, xn * r2 * r2, xn * r2 * r2 * r2, 2.0 * xn * yn, r2 + 2.0 * xn * xn),
            (yn * r2, yn * r2 * r2, yn * r2 * r2 * r2, r2 + 2.0 * yn * yn, 2.0 * xn * yn))


@numba.njit(cache=True, inline="always")
def brown_undistort(xd, yd, c, iterations):
    """Fixed-point iteration ``xn = (xd - tangential) / radial`` (y with the new x): converges for
    photogrammetric lenses (distortion a small fraction of the radius); ``c`` as in ``brown_distort``."""
    k1, k2, k3, p1, p2 = c.k1, c.k2, c.k3, c.p1, c.p2
    xn, yn = xd, yd
    for _ in range(iterations):
        r2 = xn * xn + yn * yn
        radial = _brown_radial(r2, k1, k2, k3)
        xn = (xd - 2.0 * p1 * xn * yn - p2 * (r2 + 2.0 * xn * xn)) / radial
        yn = (yd - p1 * (r2 + 2.0 * yn * yn) - 2.0 * p2 * xn * yn) / radial
    return xn, yn


def _brown_distort(params, xn, yn):
    return brown_distort(xn, yn, params)


def _brown_distort_jacobian(params, xn, yn):
    return brown_distort_jacobian(xn, yn, params)


def _brown_coefficient_jacobian(params, xn, yn, out):
    dx, dy = brown_coefficient_jacobian(xn, yn)
    for c in range(5):
        out[0, c] = dx[c]
        out[1, c] = dy[c]


def _brown_undistort(params, xd, yd, iterations):
    return brown_undistort(xd, yd, params, iterations)


# -- pinhole -----------------------------------------------------------------------------------------
def _pinhole_distort(params, xn, yn):
    return xn, yn


def _pinhole_distort_jacobian(params, xn, yn):
    return 1.0, 0.0, 0.0, 1.0


def _pinhole_coefficient_jacobian(params, xn, yn, out):
    return None


def _pinhole_undistort(params, xd, yd, iterations):
    return xd, yd


# -- the registry and the generic functions ----------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ModelKernels:
    """A model's kernels (plain Python functions of ``(params, ...)``, compiled inline where used) and
    its number of lens coefficients."""

    distort: Callable
    distort_jacobian: Callable
    coefficient_jacobian: Callable
    undistort: Callable
    n_coefficients: int


MODEL_KERNELS: dict[type, ModelKernels] = {
    BrownParams: ModelKernels(_brown_distort, _brown_distort_jacobian, _brown_coefficient_jacobian, _brown_undistort, 5),
    PinholeParams: ModelKernels(_pinhole_distort, _pinhole_distort_jacobian, _pinhole_coefficient_jacobian,
                                _pinhole_undistort, 0),
}


def _kernels(params_type) -> ModelKernels:
    cls = getattr(params_type, "instance_class", None)
    if cls not in MODEL_KERNELS:
        raise TypeError(f"no lens kernels for camera parameters of type {params_type}")
    return MODEL_KERNELS[cls]


def distort(params, xn, yn):
    """Normalised -> distorted normalised coordinates (scalars; compiled code only)."""
    return MODEL_KERNELS[type(params)].distort(params, xn, yn)


def distort_jacobian(params, xn, yn):
    """d(xd, yd) / d(xn, yn) as (a00, a01, a10, a11) (scalars; compiled code only)."""
    return MODEL_KERNELS[type(params)].distort_jacobian(params, xn, yn)


def coefficient_jacobian(params, xn, yn, out):
    """d(xd, yd) / d(lens coefficients) into ``out`` (2, n_coefficients) (compiled code only)."""
    return MODEL_KERNELS[type(params)].coefficient_jacobian(params, xn, yn, out)


def undistort(params, xd, yd, iterations):
    """Distorted -> normalised coordinates by fixed-point iteration (scalars; compiled code only)."""
    return MODEL_KERNELS[type(params)].undistort(params, xd, yd, iterations)


@overload(distort, inline="always")
def _ov_distort(params, xn, yn):
    return _kernels(params).distort


@overload(distort_jacobian, inline="always")
def _ov_distort_jacobian(params, xn, yn):
    return _kernels(params).distort_jacobian


@overload(coefficient_jacobian, inline="always")
def _ov_coefficient_jacobian(params, xn, yn, out):
    return _kernels(params).coefficient_jacobian


@overload(undistort, inline="always")
def _ov_undistort(params, xd, yd, iterations):
    return _kernels(params).undistort


@numba.njit(cache=True, inline="always")
def to_pixel(params, xn, yn):
    """Pixel (x, y) of normalised camera coordinates: distortion, focal length, principal point."""
    xd, yd = distort(params, xn, yn)
    return params.f * xd + params.cx, params.f * yd + params.cy


@numba.njit(cache=True, inline="always")
def to_normalised(params, x, y, iterations):
    """Normalised camera coordinates of a pixel (x, y): the inverse of ``to_pixel``."""
    return undistort(params, (x - params.cx) / params.f, (y - params.cy) / params.f, iterations)


# -- over arrays (the numpy side) --------------------------------------------------------------------
@numba.njit(cache=True)
def distort_points(params, xn, yn):
    """``distort`` over 1-D arrays -> (xd, yd)."""
    xd = np.empty_like(xn)
    yd = np.empty_like(yn)
    for k in range(len(xn)):
        xd[k], yd[k] = distort(params, xn[k], yn[k])
    return xd, yd


@numba.njit(cache=True)
def undistort_points(params, xd, yd, iterations):
    """``undistort`` over 1-D arrays -> (xn, yn)."""
    xn = np.empty_like(xd)
    yn = np.empty_like(yd)
    for k in range(len(xd)):
        xn[k], yn[k] = undistort(params, xd[k], yd[k], iterations)
    return xn, yn


@numba.njit(cache=True)
def distort_jacobian_points(params, xn, yn):
    """``distort_jacobian`` over 1-D arrays -> (K, 2, 2)."""
    J = np.empty((len(xn), 2, 2))
    for k in range(len(xn)):
        J[k, 0, 0], J[k, 0, 1], J[k, 1, 0], J[k, 1, 1] = distort_jacobian(params, xn[k], yn[k])
    return J


@numba.njit(cache=True)
def coefficient_jacobian_points(params, xn, yn, n_coefficients):
    """``coefficient_jacobian`` over 1-D arrays -> (K, 2, n_coefficients)."""
    J = np.zeros((len(xn), 2, n_coefficients))
    for k in range(len(xn)):
        coefficient_jacobian(params, xn[k], yn[k], J[k])
    return J
