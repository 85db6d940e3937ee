"""Rotations in the photogrammetric omega-phi-kappa convention.

``R = Rx(omega) @ Ry(phi) @ Rz(kappa)`` rotates camera (image) coordinates into object coordinates:
``P - C = s * R @ p_cam``. The camera frame has x right, y up (towards the top of the image) and z up,
away from the ground, for a nadir frame (Kraus, Photogrammetry vol. 1). With all angles zero the
top of the image faces object +Y (north in a map projection). Angles are in degrees.
"""

from __future__ import annotations

import numpy as np


def rotation_matrix_opk(omega_deg, phi_deg, kappa_deg) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from omega, phi, kappa in degrees (scalars or arrays)."""
    om, ph, ka = (np.radians(np.asarray(a, dtype=float)) for a in (omega_deg, phi_deg, kappa_deg))
    so, co = np.sin(om), np.cos(om)
    sp, cp = np.sin(ph), np.cos(ph)
    sk, ck = np.sin(ka), np.cos(ka)
    R = np.empty(np.broadcast(om, ph, ka).shape + (3, 3))
    R[..., 0, 0] = cp * ck
    R[..., 0, 1] = -cp * sk
    R[..., 0, 2] = sp
    R[..., 1, 0] = co * sk + so * sp * ck
    R[..., 1, 1] = co * ck - so * sp * sk
    R[..., 1, 2] = -so * cp
    R[..., 2, 0] = so * sk - co * sp * ck
    R[..., 2, 1] = so * ck + co * sp * sk
    R[..., 2, 2] = co * cp
    return R


def opk_from_matrix(R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Omega, phi, kappa in degrees from rotation matrices (..., 3, 3); inverse of rotation_matrix_opk."""
    R = np.asarray(R, dtype=float)
    phi = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    omega = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    kappa = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    return np.degrees(omega), np.degrees(phi), np.degrees(kappa)


# The computer-vision camera frame (x right, y down, z forward along the view) is the photogrammetric
# frame with y and z flipped: R_cv = R_opk @ FLIP_YZ. GTSAM, COLMAP and OpenCV use the former.
FLIP_YZ = np.diag([1.0, -1.0, -1.0])
