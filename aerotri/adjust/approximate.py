"""Approximate exterior orientations without an IMU, and approximate object points.

Centres from GNSS (minus the lever arm), omega = phi = 0 (near-nadir frames) and kappa from the strip
direction: the mean image motion of tie points between consecutive frames of a strip, compared with
the GNSS base, gives the rotation of the image axes against the ground (so the image may be mounted in
any orientation). Then the attitudes are refined before the bundle by alternating

- intersection of the tie points from the current orientations (points that do not intersect in
  front of the cameras fall back to the mean of their rays' hits on a ground plane), and
- a space resection of every frame's attitude with its centre held at the GNSS position: the rotation
  that best turns the image rays onto the directions centre -> object point (Wahba's problem, solved in
  closed form by SVD, with a robust reweighting against blunders),

so the bundle starts from tilts of a few tenths of a degree instead of the full tilt of the frame.
"""

from __future__ import annotations

import numba
import numpy as np

from aerotri.adjust.check_points import intersect_rays, sum_by_index
from aerotri.adjust.collinearity import pixel_rays
from aerotri.geom.rotation import FLIP_YZ, rotation_matrix_opk

# no ray of a frame camera reaches this many times its height above the ground: nearly parallel rays meet further
# (a re-flown frame beside the frame of its station: up to 1e9 m, trial s97 H2), where no map projection takes them
MAX_REACH_FLYING_HEIGHTS = 10.0


def kappa_from_image_motion(gnss_local, strip, obs_point, obs_image, obs_xy_px) -> np.ndarray:
    """Kappa (deg) per frame from tie-point motion to the next (or previous) frame of its strip."""
    n = len(gnss_local)
    kappa = np.full(n, np.nan)
    # index of each (point, image) measurement for fast lookup
    by_image = [dict() for _ in range(n)]
    for k, (p, i) in enumerate(zip(obs_point, obs_image)):
        by_image[i][int(p)] = k
    for i in range(n):
        same = np.flatnonzero(strip == strip[i])
        pos = np.searchsorted(same, i)
        for j in ([same[pos + 1]] if pos + 1 < len(same) else []) + ([same[pos - 1]] if pos > 0 else []):
            common = set(by_image[i]) & set(by_image[j])
            if len(common) < 3:
                continue
            ki = np.array([by_image[i][p] for p in common])
            kj = np.array([by_image[j][p] for p in common])
            motion = np.median(obs_xy_px[kj] - obs_xy_px[ki], axis=0)
            # photo frame (x right, y up): the camera moves against the image motion
            flight_cam = np.array([-motion[0], motion[1]])
            base = gnss_local[j, :2] - gnss_local[i, :2]
            kappa[i] = np.degrees(np.arctan2(base[1], base[0]) - np.arctan2(flight_cam[1], flight_cam[0]))
            break
    # frames without a usable neighbour: image top facing the flight direction
    for i in np.flatnonzero(np.isnan(kappa)):
        same = np.flatnonzero(strip == strip[i])
        d = gnss_local[same[-1], :2] - gnss_local[same[0], :2] if len(same) > 1 else np.array([0.0, 1.0])
        kappa[i] = np.degrees(np.arctan2(-d[0], d[1]))
    # one kappa per strip (circular median): single-pair estimates scatter by the tilts
    for s in np.unique(strip):
        idx = np.flatnonzero(strip == s)
        ref = np.radians(kappa[idx[0]])
        dev = np.angle(np.exp(1j * (np.radians(kappa[idx]) - ref)))
        kappa[idx] = np.degrees(ref + np.median(dev))
    return (kappa + 180.0) % 360.0 - 180.0


def approximate_orientations(gnss_local, lever_arm_m, strip, obs_point, obs_image, obs_xy_px):
    """(centres (N, 3), R_cv (N, 3, 3)) from GNSS antenna positions and tie-point motion (omega = phi = 0)."""
    kappa = kappa_from_image_motion(gnss_local, strip, obs_point, obs_image, obs_xy_px)
    R = rotation_matrix_opk(np.zeros_like(kappa), np.zeros_like(kappa), kappa)
    centre = gnss_local - np.einsum("nij,j->ni", R, lever_arm_m)
    return centre, R @ FLIP_YZ


def camera_rays(obs_xy_px, cal) -> np.ndarray:
    """Unit ray directions (K, 3) in the camera frame (computer vision axes) of pixels, distortion removed."""
    d = pixel_rays(obs_xy_px, np.broadcast_to(np.eye(3), (len(obs_xy_px), 3, 3)), cal)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def resect_attitudes(centre, R_cv, points, obs_point, obs_image, rays_cam, *, iterations: int = 3):
    """Attitudes (N, 3, 3) by space resection with known projection centres.

    For frame i the camera rays ``d_k`` (unit, camera frame, ``rays_cam``) and the object directions
    ``u_k = (X_k - C_i) / |X_k - C_i|`` satisfy ``u_k = R_cv d_k``: R_cv is the orthogonal Procrustes
    (Kabsch) solution of ``sum w_k u_k d_k^T``. Weights are Huber-like on the angular residual (3 robust
    sigmas), so wrong tie points and badly intersected points do not bend the frame. Frames with fewer
    than 3 usable rays keep ``R_cv``.
    """
    n = len(centre)
    k = np.flatnonzero(np.all(np.isfinite(points[obs_point]), axis=1))
    im = obs_image[k]
    d = rays_cam[k]
    u = points[obs_point[k]] - centre[im]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    R = np.array(R_cv, dtype=float, copy=True)
    w = np.ones(len(k))
    enough = np.bincount(im, minlength=n) >= 3
    grouping = _grouping(im, n)
    for _ in range(iterations):
        B = sum_by_index(im, w[:, None, None] * u[:, :, None] * d[:, None, :], n)
        U, _, Vt = np.linalg.svd(B)
        S = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        S[:, 2, 2] = np.sign(np.linalg.det(U @ Vt))
        R[enough] = (U @ S @ Vt)[enough]
        # angular residuals (rad) and robust weights per frame
        ang = np.linalg.norm(u - np.einsum("kij,kj->ki", R[im], d), axis=1)
        s = 1.4826 * np.maximum(_median_per_group(ang, im, n, grouping)[im], 1e-6)
        w = np.minimum(1.0, 3.0 * s / np.maximum(ang, 1e-12))
    return R


def _median_per_group(values, group, n_groups, grouping=None):
    """Median of ``values`` per group index (lower median for even counts; 0 for empty groups); ``grouping``:
    ``_grouping(group, n_groups)`` when at hand."""
    order, starts, counts = grouping if grouping is not None else _grouping(group, n_groups)
    return _lower_medians(np.asarray(values, dtype=float), order, starts, counts)


def _grouping(group, n_groups):
    """(rows in group order, first row of each group in that order, rows per group)."""
    counts = np.bincount(group, minlength=n_groups)
    return np.argsort(group, kind="stable"), np.r_[0, np.cumsum(counts)[:-1]], counts


@numba.njit(cache=True)
def _lower_medians(values, order, starts, counts):
    """Group by group (``order[starts[g]:starts[g] + counts[g]]``): the lower median (a sort of the group's values
    alone: one sort of all K values by group and value was the cost of the space resection)."""
    med = np.zeros(len(counts))
    for g in range(len(counts)):
        c = counts[g]
        if c > 0:
            v = np.sort(values[order[starts[g]:starts[g] + c]])
            med[g] = v[(c - 1) // 2]
    return med


def _ground_hits(centre, rays_world, obs_point, n_points, ground_height_m):
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ground_height_m - centre[:, 2]) / rays_world[:, 2]
    good = np.isfinite(t) & (t > 0)
    hit = centre + t[:, None] * rays_world
    s = sum_by_index(obs_point[good], hit[good], n_points)
    n = np.bincount(obs_point[good], minlength=n_points)
    pts = s / np.maximum(n, 1)[:, None]
    pts[n == 0] = np.array([centre[:, 0].mean(), centre[:, 1].mean(), ground_height_m])
    return pts


def intersect_points(obs_point, obs_image, obs_xy_px, centre, R_cv, cal, *, n_points, ground_height_m, rays_cam=None):
    """Object points (P, 3) by (linear, least-squares) multi-ray intersection; points that fail (fewer
    than 2 rays, indeterminate, behind a camera or above the lowest camera) take the mean of their rays'
    hits on the ground plane."""
    d_cam = camera_rays(obs_xy_px, cal) if rays_cam is None else rays_cam
    c = centre[obs_image]
    d = np.einsum("kij,kj->ki", R_cv[obs_image], d_cam)
    pts, ok = intersect_rays(c, d, obs_point, n_points)
    ok &= np.bincount(obs_point, minlength=n_points) >= 2
    ok &= np.all(np.isfinite(pts), axis=1)
    ahead = np.einsum("ki,ki->k", np.nan_to_num(pts[obs_point]) - c, d) > 0
    behind = np.bincount(obs_point, weights=(~ahead).astype(float), minlength=n_points) > 0
    ok &= ~behind & (np.nan_to_num(pts[:, 2], nan=np.inf) < centre[:, 2].min())
    reach = np.linalg.norm(np.nan_to_num(pts[obs_point], nan=np.inf) - c, axis=1)
    too_far = reach > MAX_REACH_FLYING_HEIGHTS * np.maximum(np.abs(c[:, 2] - ground_height_m), 1.0)
    ok &= np.bincount(obs_point, weights=too_far.astype(float), minlength=n_points) == 0
    plane = _ground_hits(c, d, obs_point, n_points, ground_height_m)
    return np.where(ok[:, None], pts, plane)


def refine_orientations(gnss_local, lever_arm_m, centre, R_cv, obs_point, obs_image, *, obs_xy_px, cal, n_points,
                        ground_height_m, iterations: int = 3):
    """Alternate space resection (centres from GNSS) and intersection -> (centres, R_cv, points).

    The first points are the ground-plane ones (with omega = phi = 0 a least-squares intersection can put
    points hundreds of metres off); later ones are least-squares multi-ray intersections.
    """
    centre, R = np.array(centre, dtype=float), np.array(R_cv, dtype=float)
    d_cam = camera_rays(obs_xy_px, cal)
    pts = _ground_hits(centre[obs_image], np.einsum("kij,kj->ki", R[obs_image], d_cam), obs_point, n_points, ground_height_m)
    lever_cv = FLIP_YZ @ np.asarray(lever_arm_m, dtype=float)
    for _ in range(iterations):
        R = resect_attitudes(centre, R, pts, obs_point, obs_image, d_cam)
        centre = gnss_local - np.einsum("nij,j->ni", R, lever_cv)
        pts = intersect_points(obs_point, obs_image, obs_xy_px, centre, R, cal, n_points=n_points,
                               ground_height_m=ground_height_m, rays_cam=d_cam)
    return centre, R, pts


def approximate_points(obs_point, obs_image, obs_xy_px, centre, R_cv, cal, *, n_points, ground_height_m):
    """Object points as the mean of their rays' intersections with the plane at ``ground_height_m``.

    With approximate attitudes a least-squares intersection can put points hundreds of metres off;
    the ground plane keeps them within the relief, and the bundle does the rest.
    """
    d = pixel_rays(obs_xy_px, R_cv[obs_image], cal)
    return _ground_hits(centre[obs_image], d, obs_point, n_points, ground_height_m)

