"""Multi-ray intersection of object points from image measurements with given orientations.

Used for initial tie-point coordinates, for check points (not in the adjustment: intersected with the
final orientations and compared with their given coordinates) and for the leave-one-out test of control
points. The covariance of an intersected point combines image noise and the joint covariance of the
orientations (and calibration) that observe it: ``Cov = N^-1 s0^2 + G Cov_eo G^T`` with
``G = -N^-1 A^T B`` (A: d pixel / d point, B: d pixel / d pose tangent).
"""

from __future__ import annotations

import numpy as np

from aerotri.adjust.collinearity import jacobians_cv, pixel_rays, point_jacobian_cv, point_normals, project_cv
from aerotri.adjust.keys import K_KEY, X

__all__ = ["intersect", "intersect_rays", "intersect_with_covariance", "pixel_rays", "refine_points", "sum_by_index"]


def intersect_rays(centres, directions, point_index, n_points):
    """Least-squares intersection of rays (K, 3)+(K, 3) grouped by point_index -> points (n, 3), rank-ok mask."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    M = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    N = sum_by_index(point_index, M, n_points)
    b = sum_by_index(point_index, np.einsum("kij,kj->ki", M, centres), n_points)
    ok = np.linalg.cond(N) < 1e8
    out = np.full((n_points, 3), np.nan)
    out[ok] = np.linalg.solve(N[ok], b[ok][..., None])[..., 0]
    return out, ok


def sum_by_index(index, values, n):
    """Sums of ``values`` (K, ...) over rows with equal ``index`` -> (n, ...) (np.add.at, but fast)."""
    flat = values.reshape(len(values), -1)
    out = np.empty((n, flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.bincount(index, weights=flat[:, c], minlength=n)
    return out.reshape((n,) + values.shape[1:])


def refine_points(xy_px, point_index, image_index, centre, R_cv, cal, points, iterations: int = 5):
    """Gauss-Newton on the pixels for points (n, 3) with fixed orientations; rows that are not finite stay as
    they are. Returns a new array."""
    pts = np.array(points, dtype=float, copy=True)
    n = len(pts)
    R = R_cv[image_index]
    C = centre[image_index]
    for _ in range(iterations):
        uv, pc = project_cv(pts[point_index], C, R, cal)
        N, b = point_normals(point_jacobian_cv(pc, R, cal), point_index, n, xy_px - uv)
        good = np.all(np.isfinite(b), axis=1) & np.all(np.isfinite(pts), axis=1)
        step = np.linalg.solve(N[good] + 1e-12 * np.eye(3), b[good][..., None])[..., 0]
        pts[good] += step
    return pts


def intersect(xy_px, point_index, image_index, centre, R_cv, cal, n_points, iterations: int = 5):
    """Intersect points from their image measurements: linear start, then Gauss-Newton on pixels.

    Returns (points (n, 3) with NaN where fewer than 2 usable rays, rank-ok mask).
    """
    rays = pixel_rays(xy_px, R_cv[image_index], cal)
    pts, ok = intersect_rays(centre[image_index], rays, point_index, n_points)
    pts = refine_points(xy_px, point_index, image_index, centre, R_cv, cal, pts, iterations)
    return pts, ok


def intersect_with_covariance(xy_px, image_index, centre, R_cv, cal, sigma_px, marginals=None, self_cal=False):
    """Intersect one point from m measurements and give its covariance (3, 3) in the local frame.

    ``marginals`` (gtsam.Marginals of the final adjustment) adds the uncertainty of the orientations
    (and of the calibration when ``self_cal``) with their correlations; without it, image noise only.
    Returns (point (3,), covariance (3, 3), image residuals (m, 2) px).
    """
    m = len(image_index)
    pts, ok = intersect(xy_px, np.zeros(m, dtype=int), image_index, centre, R_cv, cal, 1)
    X0 = pts[0]
    uv, pc = project_cv(np.repeat(X0[None], m, 0), centre[image_index], R_cv[image_index], cal)
    Jp, Jpose = jacobians_cv(pc, R_cv[image_index], cal)
    Amat = Jp.reshape(2 * m, 3)
    Ninv = np.linalg.inv(Amat.T @ Amat)
    cov = Ninv * sigma_px**2
    if marginals is not None:
        imgs = list(dict.fromkeys(int(i) for i in image_index))
        keys = [X(i) for i in imgs] + ([K_KEY] if self_cal else [])
        sizes = [6] * len(imgs) + ([9] if self_cal else [])
        offs = np.concatenate([[0], np.cumsum(sizes)])
        B = np.zeros((2 * m, offs[-1]))
        for r, i in enumerate(image_index):
            c = imgs.index(int(i))
            B[2 * r : 2 * r + 2, offs[c] : offs[c] + 6] = Jpose[r]
        if self_cal:
            B[:, offs[-2] :] = _numeric_cal_jacobian(X0, image_index, centre, R_cv, cal)
        jm = marginals.jointMarginalCovariance(keys)
        Cov_eo = np.zeros((offs[-1], offs[-1]))
        for a, ka in enumerate(keys):
            for b, kb in enumerate(keys):
                Cov_eo[offs[a] : offs[a + 1], offs[b] : offs[b + 1]] = jm.at(ka, kb)
        G = -Ninv @ Amat.T @ B
        cov = cov + G @ Cov_eo @ G.T
    return X0, cov, xy_px - uv


def _numeric_cal_jacobian(X0, image_index, centre, R_cv, cal):
    m = len(image_index)
    J = np.zeros((2 * m, 9))
    steps = np.array([1e-3, 1e-3, 1e-6, 1e-3, 1e-3, 1e-7, 1e-7, 1e-7, 1e-7])
    for q in range(9):
        dc = np.zeros(9)
        dc[q] = steps[q]
        up, _ = project_cv(np.repeat(X0[None], m, 0), centre[image_index], R_cv[image_index], cal + dc)
        dn, _ = project_cv(np.repeat(X0[None], m, 0), centre[image_index], R_cv[image_index], cal - dc)
        J[:, q] = ((up - dn) / (2 * steps[q])).reshape(-1)
    return J
