"""The adjustment's vectorised collinearity (Cal3DS2) against gtsam and against the Schur kernel's numba
twin: the same lens kernels, so the same numbers."""

import gtsam
import numpy as np

from aerotri.adjust import collinearity as co
from aerotri.adjust import schur

CAL = np.array([10000.0, 10020.0, 0.5, 6912.0, 3840.0, -2e-2, 3e-3, 1e-4, -2e-4])


def _rays(n=60, seed=3):
    rng = np.random.default_rng(seed)
    centre = rng.normal(0, 50, (n, 3)) + [0, 0, 1000]
    R = np.array([gtsam.Rot3.RzRyRx(*rng.normal(0, 0.05, 3)).matrix() @ np.diag([1.0, -1.0, -1.0]) for _ in range(n)])
    pts = rng.uniform(-400, 400, (n, 3)) * [1, 1, 0.05]
    return pts, centre, R


def test_projection_is_gtsams_cal3ds2():
    pts, centre, R = _rays()
    uv, pc = co.project_cv(pts, centre, R, CAL)
    K = gtsam.Cal3DS2(*CAL)
    for k in range(len(pts)):
        cam = gtsam.PinholeCameraCal3DS2(gtsam.Pose3(gtsam.Rot3(R[k]), centre[k]), K)
        assert np.abs(cam.project(pts[k]) - uv[k]).max() < 1e-8
    assert np.all(pc[:, 2] > 0)


def test_pixel_rays_invert_the_projection():
    pts, centre, R = _rays()
    uv, _ = co.project_cv(pts, centre, R, CAL)
    d = co.pixel_rays(uv, R, CAL)
    want = pts - centre
    cos = np.sum(d * want, 1) / np.linalg.norm(d, axis=1) / np.linalg.norm(want, axis=1)
    assert np.abs(1 - cos).max() < 1e-15


def test_numpy_side_equals_the_schur_kernel():
    """Residuals and Jacobians of ``jacobians_cv`` = those of ``schur._ray`` (numba) to 1e-12."""
    pts, centre, R = _rays()
    xy = co.project_cv(pts, centre, R, CAL)[0] + 0.7
    uv, pc = co.project_cv(pts, centre, R, CAL)
    J_point, J_pose, J_cal = co.jacobians_cv(pc, R, CAL, with_cal=True)
    A, B, C, r = np.empty((2, 6)), np.empty((2, 3)), np.empty((2, 9)), np.empty(2)
    for k in range(len(pts)):
        assert schur._ray(xy[k], (centre[k], R[k]), pts[k], (CAL, 1.0, True), (r, A, B, C))
        assert np.abs(r - (xy[k] - uv[k])).max() < 1e-12 * 1e4
        # the kernel differentiates the prediction; its residual is observed - predicted
        assert np.allclose(A, J_pose[k], rtol=1e-12, atol=1e-12 * np.abs(J_pose[k]).max())
        assert np.allclose(B, J_point[k], rtol=1e-12, atol=1e-12 * np.abs(J_point[k]).max())
        assert np.allclose(C, J_cal[k], rtol=1e-12, atol=1e-12 * np.abs(J_cal[k]).max())
