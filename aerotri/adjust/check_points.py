"""Multi-ray intersection of object points from image measurements with given orientations.

Used for initial tie-point coordinates, for check points (not in the adjustment: intersected with the
final orientations and compared with their given coordinates) and for the leave-one-out test of control
points. The covariance of an intersected point combines image noise and the joint covariance of the
orientations (and calibration) that observe it: ``Cov = N^-1 s0^2 + G Cov_eo G^T`` with
``G = -N^-1 A^T B`` (A: d pixel / d point, B: d pixel / d pose tangent).
"""

from __future__ import annotations

import numba
import numpy as np

from aerotri.geom.lens_kernels import BrownCoefficients, brown_distort, brown_distort_jacobian
from aerotri.adjust.collinearity import jacobians_cv, pixel_rays, point_jacobian_cv, point_normals, project_cv
from aerotri.adjust.keys import K_KEY, X

__all__ = ["intersect", "intersect_rays", "intersect_with_covariance", "pixel_rays", "ray_leverages", "refine_points",
           "refined_normals", "sum_by_index"]


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


def refine_points(xy_px, point_index, image_index, centre, R_cv, cal, *, points, iterations: int = 5):
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


def refined_normals(xy_px, point_index, image_index, centre, R_cv, cal, *, points, iterations: int = 5):
    """``refine_points`` ray by ray in compiled code, and the points' normal matrices ``sum J'J`` (n, 3, 3) at the
    refined points (``point_normals``, unit weights): (points, normals). The same arithmetic as the numpy
    functions (to rounding), without their (K, 3, 3) arrays of rotations and Jacobians per ray (the surface gate
    of a 6.5 M-ray block: GBs of temporaries per robust round)."""
    pts = np.array(points, dtype=float, copy=True)
    N = np.empty((len(pts), 3, 3))
    b = np.empty((len(pts), 3))
    cal = np.asarray(cal, dtype=float)
    _refine_kernel(np.ascontiguousarray(xy_px, dtype=float),
                   (np.asarray(point_index, dtype=np.int64), np.asarray(image_index, dtype=np.int64)),
                   (np.ascontiguousarray(centre, dtype=float), np.ascontiguousarray(R_cv, dtype=float), cal), pts,
                   (N, b), int(iterations))
    return pts, N


@numba.njit(cache=True, inline="always")
def _ray_point_jacobian(xy, centre, R, point, cal, J):
    """d pixel / d point (2, 3) of one ray into ``J`` (``collinearity.point_jacobian_cv``, no weights); returns its
    residual observed - computed (pixels)."""
    fx, fy, sk, u0, v0, k1, k2, p1, p2 = cal[0], cal[1], cal[2], cal[3], cal[4], cal[5], cal[6], cal[7], cal[8]
    d0, d1, d2 = point[0] - centre[0], point[1] - centre[1], point[2] - centre[2]
    x = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2  # R^T (P - C)
    y = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
    z = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
    xn, yn = x / z, y / z
    lens = BrownCoefficients(k1, k2, 0.0, p1, p2)
    xd, yd = brown_distort(xn, yn, lens)
    a00, a01, a10, a11 = brown_distort_jacobian(xn, yn, lens)
    m00, m01 = fx * a00 + sk * a10, fx * a01 + sk * a11
    m10, m11 = fy * a10, fy * a11
    iz, ux, uy = 1.0 / z, -xn / z, -yn / z  # d(xn, yn) / d pc as in ``collinearity._dpixel_dpc``
    j00, j01, j02 = m00 * iz, m01 * iz, m00 * ux + m01 * uy
    j10, j11, j12 = m10 * iz, m11 * iz, m10 * ux + m11 * uy
    for c in range(3):
        J[0, c] = j00 * R[c, 0] + j01 * R[c, 1] + j02 * R[c, 2]
        J[1, c] = j10 * R[c, 0] + j11 * R[c, 1] + j12 * R[c, 2]
    return xy[0] - (fx * xd + sk * yd + u0), xy[1] - (fy * yd + v0)


@numba.njit(cache=True)
def _normals_kernel(xy, rays, cameras, pts, normals):
    """``point_normals(point_jacobian_cv(...), ..., residual)`` at ``pts``: the upper triangle of ``N`` and ``b``
    (``normals``: (N, b)); ``rays``: each ray's (point, image) indices, ``xy`` its pixel; ``cameras``: the
    images' (centre, R_cv) and the calibration ``cal``."""
    point, image = rays
    centre, R_cv, cal = cameras
    N, b = normals
    N[:] = 0.0
    b[:] = 0.0
    J = np.empty((2, 3))
    for k in range(len(point)):
        j, i = point[k], image[k]
        r0, r1 = _ray_point_jacobian(xy[k], centre[i], R_cv[i], pts[j], cal, J)
        for p in range(3):
            b[j, p] += J[0, p] * r0 + J[1, p] * r1
            for q in range(p, 3):
                N[j, p, q] += J[0, p] * J[0, q] + J[1, p] * J[1, q]


def ray_leverages(point_index, image_index, centre, R_cv, cal, points, *, N_inv) -> np.ndarray:
    """``J N^-1 J'`` per image coordinate (K, 2) of rays with their points' inverse normal matrices ``N_inv``
    (n, 3, 3): the diagonal of each point's hat matrix (``snooping.redundancy_numbers``), ray by ray."""
    H = np.empty((len(point_index), 2))
    _leverage_kernel((np.asarray(point_index, dtype=np.int64), np.asarray(image_index, dtype=np.int64)),
                     (np.ascontiguousarray(centre, dtype=float), np.ascontiguousarray(R_cv, dtype=float),
                      np.asarray(cal, dtype=float)), np.ascontiguousarray(points, dtype=float),
                     np.ascontiguousarray(N_inv, dtype=float), H)
    return H


@numba.njit(cache=True)
def _leverage_kernel(rays, cameras, pts, N_inv, H):
    """``ray_leverages`` into ``H`` (K, 2): ``rays`` (point, image), ``cameras`` (centre, R_cv, cal)."""
    point, image = rays
    centre, R_cv, cal = cameras
    J = np.empty((2, 3))
    xy = np.zeros(2)
    for k in range(len(point)):
        j, i = point[k], image[k]
        _ray_point_jacobian(xy, centre[i], R_cv[i], pts[j], cal, J)
        Q = N_inv[j]
        for a in range(2):
            h = 0.0
            for p in range(3):
                h += J[a, p] * (Q[p, 0] * J[a, 0] + Q[p, 1] * J[a, 1] + Q[p, 2] * J[a, 2])
            H[k, a] = h


@numba.njit(cache=True)
def _refine_kernel(xy, rays, cameras, pts, normals, iterations):
    """Gauss-Newton steps ``(N + 1e-12 I) step = b`` of every point whose ``b`` and coordinates are finite
    (``refine_points``), then ``N`` (full) at the refined points; the arguments of ``_normals_kernel``."""
    N, b = normals
    A = np.empty((3, 4))
    for _ in range(iterations):
        _normals_kernel(xy, rays, cameras, pts, normals)
        for j in range(len(pts)):
            good = True
            for p in range(3):
                good = good and np.isfinite(b[j, p]) and np.isfinite(pts[j, p])
            if not good:
                continue
            for p in range(3):
                for q in range(3):
                    A[p, q] = N[j, min(p, q), max(p, q)] + (1e-12 if p == q else 0.0)
                A[p, 3] = b[j, p]
            if _solve3(A):
                for p in range(3):
                    pts[j, p] += A[p, 3]
    _normals_kernel(xy, rays, cameras, pts, normals)
    for j in range(len(pts)):
        N[j, 1, 0], N[j, 2, 0], N[j, 2, 1] = N[j, 0, 1], N[j, 0, 2], N[j, 1, 2]


@numba.njit(cache=True, inline="always")
def _solve3(A):
    """Gaussian elimination with partial pivoting of the 3 x 4 system ``A`` in place: the solution in ``A[:, 3]``;
    False when singular (LAPACK's gesv, as ``np.linalg.solve``)."""
    for c in range(3):
        piv = c
        for r in range(c + 1, 3):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if A[piv, c] == 0.0:
            return False
        if piv != c:
            for q in range(4):
                A[c, q], A[piv, q] = A[piv, q], A[c, q]
        for r in range(c + 1, 3):
            f = A[r, c] / A[c, c]
            for q in range(c, 4):
                A[r, q] -= f * A[c, q]
    for c in range(2, -1, -1):
        v = A[c, 3]
        for q in range(c + 1, 3):
            v -= A[c, q] * A[q, 3]
        A[c, 3] = v / A[c, c]
    return True


def intersect(xy_px, point_index, image_index, centre, R_cv, cal, *, n_points, iterations: int = 5):
    """Intersect points from their image measurements: linear start, then Gauss-Newton on pixels.

    Returns (points (n, 3) with NaN where fewer than 2 usable rays, rank-ok mask).
    """
    rays = pixel_rays(xy_px, R_cv[image_index], cal)
    pts, ok = intersect_rays(centre[image_index], rays, point_index, n_points)
    pts = refine_points(xy_px, point_index, image_index, centre, R_cv, cal, points=pts, iterations=iterations)
    return pts, ok


def intersect_with_covariance(xy_px, image_index, centre, R_cv, cal, sigma_px, *, marginals=None, self_cal=False):
    """Intersect one point from m measurements and give its covariance (3, 3) in the local frame.

    ``marginals`` (gtsam.Marginals of the final adjustment) adds the uncertainty of the orientations
    (and of the calibration when ``self_cal``) with their correlations; without it, image noise only.
    Returns (point (3,), covariance (3, 3), image residuals (m, 2) px).
    """
    m = len(image_index)
    pts, ok = intersect(xy_px, np.zeros(m, dtype=int), image_index, centre, R_cv, cal, n_points=1)
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
