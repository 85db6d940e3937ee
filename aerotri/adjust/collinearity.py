"""The collinearity equations of the adjustment over arrays (numpy), with GTSAM's Cal3DS2 calibration.

A calibration vector ``cal`` is Cal3DS2's ``[fx fy s u0 v0 k1 k2 p1 p2]`` (pixels): pixel =
``[[fx, s], [0, fy]] @ (xd, yd) + (u0, v0)`` with ``(xd, yd)`` the Brown distortion (k3 = 0) of the
normalised coordinates, computed by the Brown lens kernels of ``aerotri.geom.lens_kernels`` (the same
code the Schur kernel and the camera classes run). Cameras are given per row: centres (K, 3) and
rotations ``R_cv`` (K, 3, 3) from the computer-vision camera frame to the local frame.
"""

from __future__ import annotations

import numpy as np

from aerotri.geom import lens_kernels


def cal3ds2_lens(cal) -> lens_kernels.BrownParams:
    """The Brown lens kernel parameters of Cal3DS2 values (k3 = 0; f, cx, cy are fx, u0, v0: the lens
    kernels use only the coefficients, fy and the skew act here)."""
    return lens_kernels.BrownParams(float(cal[0]), float(cal[3]), float(cal[4]), float(cal[5]), float(cal[6]), 0.0,
                                    float(cal[7]), float(cal[8]))


def _affine(cal) -> np.ndarray:
    """d pixel / d(xd, yd): [[fx, s], [0, fy]]."""
    return np.array([[cal[0], cal[2]], [0.0, cal[1]]])


def project_cv(points, centre, R_cv, cal):
    """Pixel coordinates (K, 2) and camera coordinates (K, 3) of points in cameras (per-row arrays)."""
    pc = np.einsum("kji,kj->ki", R_cv, points - centre)  # R^T (P - C)
    z = pc[:, 2]
    xd, yd = lens_kernels.distort_points(cal3ds2_lens(cal), pc[:, 0] / z, pc[:, 1] / z)
    fx, fy, s, u0, v0 = cal[:5]
    return np.column_stack([fx * xd + s * yd + u0, fy * yd + v0]), pc


def _dpixel_dpc(pc, cal):
    """d(pixel)/d(camera coordinates) (K, 2, 3) with lens distortion."""
    z = pc[:, 2]
    xn, yn = pc[:, 0] / z, pc[:, 1] / z
    Jd = lens_kernels.distort_jacobian_points(cal3ds2_lens(cal), xn, yn)  # d(xd, yd) / d(xn, yn)
    Jn = np.zeros((len(pc), 2, 3))  # d(xn, yn) / d pc
    Jn[:, 0, 0] = 1.0 / z
    Jn[:, 0, 2] = -xn / z
    Jn[:, 1, 1] = 1.0 / z
    Jn[:, 1, 2] = -yn / z
    return _affine(cal) @ Jd @ Jn


def point_jacobian_cv(pc, R_cv, cal):
    """d(pixel)/d(object point) (K, 2, 3)."""
    return _dpixel_dpc(pc, cal) @ np.swapaxes(R_cv, -1, -2)


def point_normals(J_point, point_index, n_points, residual=None):
    """Normal matrices ``sum J^T J`` (n, 3, 3) of each object point from its rays' d(pixel)/d(point)
    (K, 2, 3), unit weights; with ``residual`` (K, 2) also the right-hand sides ``sum J^T v`` (n, 3)."""
    N = np.empty((n_points, 3, 3))
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):  # bincount over products: np.add.at is slow
        N[:, i, j] = N[:, j, i] = np.bincount(point_index, J_point[:, 0, i] * J_point[:, 0, j] + J_point[:, 1, i] * J_point[:, 1, j],
                                              minlength=n_points)
    if residual is None:
        return N
    b = np.column_stack([np.bincount(point_index, J_point[:, 0, i] * residual[:, 0] + J_point[:, 1, i] * residual[:, 1],
                                     minlength=n_points) for i in range(3)])
    return N, b


# Cal3DS2 entries of the Brown lens coefficients (k1 k2 k3 p1 p2): k1 k2 p1 p2 (k3 is not in Cal3DS2)
_CAL3DS2_COEFFICIENTS = [0, 1, 3, 4]


def jacobians_cv(pc, R_cv, cal, with_cal: bool = False):
    """d(pixel)/d(point) (K, 2, 3), d(pixel)/d(pose tangent [omega, v]) (K, 2, 6) and, with ``with_cal``,
    d(pixel)/d(Cal3DS2 [fx fy s u0 v0 k1 k2 p1 p2]) (K, 2, 9); lens distortion included.

    Pose perturbation as in gtsam (right): R -> R Exp(omega), C -> C + R v, so d pc/d omega = [pc]x,
    d pc/d v = -I.
    """
    Jp = _dpixel_dpc(pc, cal)
    J_point = Jp @ np.swapaxes(R_cv, -1, -2)
    skew = np.zeros((len(pc), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -pc[:, 2], pc[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = pc[:, 2], -pc[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -pc[:, 1], pc[:, 0]
    J_pose = np.concatenate([Jp @ skew, -Jp], axis=2)
    if not with_cal:
        return J_point, J_pose
    lens = cal3ds2_lens(cal)
    xn, yn = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    xd, yd = lens_kernels.distort_points(lens, xn, yn)
    Jc = np.zeros((len(pc), 2, 9))
    Jc[:, 0, 0], Jc[:, 0, 2], Jc[:, 0, 3] = xd, yd, 1.0
    Jc[:, 1, 1], Jc[:, 1, 4] = yd, 1.0
    # distortion parameters: d(xd, yd)/d(k1 k2 p1 p2), then through [[fx, s], [0, fy]]
    dD = lens_kernels.coefficient_jacobian_points(lens, xn, yn, 5)[:, :, _CAL3DS2_COEFFICIENTS]
    Jc[:, :, 5:] = _affine(cal) @ dD
    return J_point, J_pose, Jc


def pixel_rays(xy_px, R_cv, cal, iterations: int = 10):
    """Object-space ray directions (K, 3) of pixels for cameras with rotation R_cv and Cal3DS2 values."""
    fx, fy, s, u0, v0 = cal[:5]
    yd = (xy_px[:, 1] - v0) / fy
    xd = (xy_px[:, 0] - u0 - s * yd) / fx
    xn, yn = lens_kernels.undistort_points(cal3ds2_lens(cal), xd, yd, iterations)
    d = np.column_stack([xn, yn, np.ones_like(xn)])
    return np.einsum("kij,kj->ki", R_cv, d)
