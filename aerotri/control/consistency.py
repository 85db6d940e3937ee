"""Multi-ray intersection of a corner's image measurements and rejection of inconsistent rays.

A corner measured in k >= 2 frames is intersected in object space (least squares over the rays, in the Cartesian
frame of ``FramesOnEarth``); rays whose reprojection residual exceeds ``tol_px`` are dropped one at a time, worst
first, while three or more remain. With two rays left a residual above the tolerance rejects the corner. The
intersected point is finally compared with the LiDAR corner (type I error ``alpha`` on the
Mahalanobis distance with LiDAR, image and orientation uncertainty): a wrong corner that the frames
agree on (e.g. the foot of the wall instead of the eave) is far from the LiDAR position in height.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.core.quantiles import chi2_isf


def intersect_rays(centres_m, dirs):
    """Least-squares intersection (3,) of rays C_i + s d_i; dirs need not be unit length."""
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    Pm = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = Pm.sum(axis=0)
    b = np.einsum("nij,nj->i", Pm, centres_m)
    return np.linalg.solve(A, b)


def intersection_covariance(point_m, centres_m, dirs, focal_px, sigma_px):
    """Covariance (3, 3) of the intersection for image standard deviation sigma_px (normal equations)."""
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    rng = np.linalg.norm(point_m - centres_m, axis=1)
    m_per_px = rng / focal_px  # ray-normal metres per pixel
    Pm = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    N = np.einsum("nij,n->ij", Pm, 1.0 / (m_per_px * sigma_px) ** 2)
    return np.linalg.pinv(N)


@dataclasses.dataclass
class RayCheck:
    point_m: np.ndarray  # (3,) intersection of the kept rays (NaN when rejected)
    residual_px: np.ndarray  # (k,) reprojection residual of every ray (NaN if none)
    kept: np.ndarray  # (k,) bool
    ok: bool
    reason: str  # "", "too_few_rays", "inconsistent_rays", "lidar_mismatch"
    lidar_diff_m: np.ndarray  # (3,) intersection - LiDAR corner
    mahalanobis: float


def check_rays(camera, frames, images, xy_px, lidar_m, lidar_sigma_m, *, tol_px: float = 1.0, sigma_px: float = 0.3,
               datum_sigma_m: float = 0.2, alpha: float = 1e-3, min_rays: int = 2) -> RayCheck:
    """Intersect the measurements xy_px (k, 2) of one corner in frames ``images`` (k,) of ``frames``
    (``aerotri.geom.local_frame.FramesOnEarth``: rays, intersection and residuals in its Cartesian frame, as a camera
    over the earth sees the corner; the point and its difference from the LiDAR in the project CRS).

    ``sigma_px``: image measurement precision; ``datum_sigma_m``: absolute error of the block's datum
    before control (GNSS-only adjustment), per coordinate; both enter the LiDAR comparison.
    """
    k = len(xy_px)
    nan3 = np.full(3, np.nan)
    if k < min_rays:
        return RayCheck(nan3, np.full(k, np.nan), np.zeros(k, bool), False, "too_few_rays", nan3, float("nan"))
    images = np.asarray(images, dtype=int)
    centres = frames.centres_local[images]
    dirs = np.stack([frames.rays_local(camera, i, xy_px[q : q + 1, 0], xy_px[q : q + 1, 1])[0]
                     for q, i in enumerate(images)])
    kept = np.ones(k, bool)
    while True:
        X = intersect_rays(centres[kept], dirs[kept])
        res = np.array([np.hypot(*(np.array(frames.project_local(camera, i, X[None])[:2]).ravel() - xy_px[q]))
                        for q, i in enumerate(images)])
        worst = np.flatnonzero(kept)[np.argmax(res[kept])]
        if res[worst] <= tol_px:
            break
        if kept.sum() <= max(min_rays, 2):
            X_map = frames.to_map(X)
            return RayCheck(X_map, res, kept, False, "inconsistent_rays", X_map - lidar_m, float("nan"))
        kept[worst] = False
    cov = intersection_covariance(X, centres[kept], dirs[kept], camera.focal_px, sigma_px)
    X_map = frames.to_map(X)
    if not frames.flat:  # the local (ENU metre) covariance on the map axes (scale factor, convergence)
        J = frames.frame.jacobian_map_from_local(X[None])[0]
        cov = J @ cov @ J.T
    cov = cov + np.diag(np.asarray(lidar_sigma_m, float) ** 2 + datum_sigma_m**2)
    diff = X_map - lidar_m
    m2 = float(diff @ np.linalg.solve(cov, diff))
    if m2 > chi2_isf(alpha, 3):
        return RayCheck(X_map, res, kept, False, "lidar_mismatch", diff, float(np.sqrt(m2)))
    return RayCheck(X_map, res, kept, True, "", diff, float(np.sqrt(m2)))
