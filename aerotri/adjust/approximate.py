"""Approximate exterior orientations without an IMU, and approximate object points.

Centres from GNSS (minus the lever arm), omega = phi = 0 (near-nadir frames) and kappa from the strip
direction: the mean image motion of tie points between consecutive frames of a strip, compared with
the GNSS base, gives the rotation of the image axes against the ground (so the image may be mounted in
any orientation). Object points are intersected from the approximate orientations; the bundle then
refines everything (Levenberg-Marquardt converges from tilts of a few degrees).
"""

from __future__ import annotations

import numpy as np

from aerotri.adjust.check_points import pixel_rays
from aerotri.rotation import FLIP_YZ, rotation_matrix_opk


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
    """(centres (N, 3), R_cv (N, 3, 3)) from GNSS antenna positions and tie-point motion."""
    kappa = kappa_from_image_motion(gnss_local, strip, obs_point, obs_image, obs_xy_px)
    R = rotation_matrix_opk(np.zeros_like(kappa), np.zeros_like(kappa), kappa)
    centre = gnss_local - np.einsum("nij,j->ni", R, lever_arm_m)
    return centre, R @ FLIP_YZ


def approximate_points(obs_point, obs_image, obs_xy_px, centre, R_cv, cal, n_points, ground_height_m):
    """Object points as the mean of their rays' intersections with the plane at ``ground_height_m``.

    With approximate attitudes a least-squares intersection can put points hundreds of metres off;
    the ground plane keeps them within the relief, and the bundle does the rest.
    """
    d = pixel_rays(obs_xy_px, R_cv[obs_image], cal)
    c = centre[obs_image]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ground_height_m - c[:, 2]) / d[:, 2]
    hit = c + t[:, None] * d
    good = np.isfinite(t) & (t > 0)
    s = np.zeros((n_points, 3))
    n = np.zeros(n_points)
    np.add.at(s, obs_point[good], hit[good])
    np.add.at(n, obs_point[good], 1.0)
    pts = s / np.maximum(n, 1.0)[:, None]
    pts[n == 0] = np.array([centre[:, 0].mean(), centre[:, 1].mean(), ground_height_m])
    return pts
