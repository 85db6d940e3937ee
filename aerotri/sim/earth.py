"""The simulated world on the real earth: what a camera over the ellipsoid sees of a scene given in map coordinates.

The scene, the terrain, the LiDAR and the truth rasters are defined in project-CRS coordinates (easting,
northing, ellipsoidal height; scene-local metres are those minus ``origin_map``). A projected CRS is not a
Cartesian frame: its horizontal scale is the projection's scale factor times (R + h) / R, and its heights
are measured along the ellipsoid normal, which turns with the distance (the earth's curvature). A camera sees
along straight lines of a Cartesian frame, so the simulator projects the scene through the same East-North-Up
tangent frame the adjustment uses (``aerotri.geom.local_frame.LocalFrame``): a frame's true attitude ``R_map``
(photogrammetric camera -> grid east, grid north, up at the projection centre; the convention of eo.txt) is
``R_enu = rotation_local_from_map(C) @ R_map`` in that frame.

Per frame, the map -> camera-frame transformation is used as its second-order Taylor expansion at the
projection centre (``FrameEarth``: ``v = A d + Q(d)``, ``d`` the map offset from the centre), taken from
``LocalFrame`` by central differences: the third-order terms are below ``L^3 / R^2``, 0.1 mm for points 2 km
from the camera. That keeps the renderer's per-vertex work a few multiplications (numba) instead of a CRS
transformation. With an engineering (Cartesian) CRS the expansion is the old flat projection exactly.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.rotation import FLIP_YZ

# Step of the central differences (m): the truncation error is ~step^2 / R^3 per m^2 (nil) and the rounding
# error of the ECEF coordinates (1e-9 m) / step^2 (2.5e-14 per m^2: 0.1 um at 2 km).
_STEP_M = 200.0
# quadratic terms: d0^2, d1^2, d2^2, d0 d1, d0 d2, d1 d2
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


@dataclasses.dataclass(frozen=True)
class FrameEarth:
    """Map offsets ``d`` (scene metres from the projection centre, (..., 3)) -> computer-vision camera-frame
    coordinates ``v = A d + Q(d)`` (x right, y down, z along the viewing direction, metres), ``Q`` the quadratic
    terms (``q`` (3, 6): coefficients of d0^2, d1^2, d2^2, d0 d1, d0 d2, d1 d2)."""

    A: np.ndarray  # (3, 3)
    q: np.ndarray  # (3, 6)
    A_inv: np.ndarray  # (3, 3)

    @classmethod
    def flat(cls, R_map) -> "FrameEarth":
        """The flat world: map coordinates taken as a Cartesian frame (``v = (R FLIP_YZ)^T d``)."""
        A = np.ascontiguousarray((np.asarray(R_map, dtype=float) @ FLIP_YZ).T)
        return cls(A, np.zeros((3, 6)), np.ascontiguousarray(A.T))

    def to_camera(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=float)
        v = d @ self.A.T
        if self.q.any():
            v = v + _quad(d) @ self.q.T
        return v

    def to_map(self, v) -> np.ndarray:
        """Camera-frame points -> map offsets (two fixed-point steps: the quadratic terms are < 1e-4 of ``d``,
        so the error is below 1e-8 of it)."""
        v = np.asarray(v, dtype=float)
        d = v @ self.A_inv.T
        if self.q.any():
            for _ in range(2):
                d = (v - _quad(d) @ self.q.T) @ self.A_inv.T
        return d

    def jacobian(self, d) -> np.ndarray:
        """d v / d d at map offsets ``d`` (..., 3) -> (..., 3, 3)."""
        d = np.asarray(d, dtype=float)
        J = np.broadcast_to(self.A, d.shape[:-1] + (3, 3)).copy()
        for k, (i, j) in enumerate(_PAIRS):
            J[..., :, i] += self.q[:, k] * d[..., j, None]
            J[..., :, j] += self.q[:, k] * d[..., i, None]
        return J


def _quad(d):
    return np.stack([d[..., i] * d[..., j] for i, j in _PAIRS], axis=-1)


class SimEarth:
    """The ENU frame of a simulated block (at the scene's centre) and each frame's ``FrameEarth``."""

    def __init__(self, crs, origin_map, centre_local_m):
        self.origin_map = np.asarray(origin_map, dtype=float).reshape(3)
        self.frame = LocalFrame(crs, self.origin_map + np.asarray(centre_local_m, dtype=float))

    @property
    def flat(self) -> bool:
        return self.frame.cartesian_crs

    def rotation_enu(self, centre_m, R_map) -> np.ndarray:
        """Photogrammetric camera -> ENU rotations (N, 3, 3) of frames at scene-local centres (N, 3) whose
        attitudes ``R_map`` (N, 3, 3) refer to the grid axes at the centre (eo.txt)."""
        C = np.atleast_2d(np.asarray(centre_m, dtype=float)) + self.origin_map
        return self.frame.rotation_local_from_map(C) @ np.asarray(R_map, dtype=float).reshape(-1, 3, 3)

    def to_enu(self, points_m) -> np.ndarray:
        """Scene-local points (N, 3) -> ENU metres of the block frame (exact)."""
        return self.frame.to_local(np.atleast_2d(np.asarray(points_m, dtype=float)) + self.origin_map)

    def from_enu(self, enu) -> np.ndarray:
        return self.frame.to_map(enu) - self.origin_map

    def project(self, camera, points_m, centre_m, R_map):
        """Pixel x, y and depth of scene-local points (N, 3) in a frame at ``centre_m`` with attitude ``R_map``
        (exact: through ``LocalFrame``)."""
        return camera.project(self.to_enu(points_m), self.to_enu(centre_m)[0], self.rotation_enu(centre_m, R_map)[0])

    def frame_earth(self, centre_m, R_map) -> FrameEarth:
        """The second-order map -> camera-frame transformation of a frame (module docstring)."""
        if self.flat:
            return FrameEarth.flat(R_map)
        C = np.asarray(centre_m, dtype=float).reshape(3)
        M = self.rotation_enu(C, R_map)[0] @ FLIP_YZ  # camera (cv) -> ENU
        s = _STEP_M
        grid = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
        g = (self.to_enu(C + s * grid) @ M).reshape(3, 3, 3, 3)  # camera frame at the 27 nodes; [i0, i1, i2, xyz]

        def at(off):
            return g[off[0] + 1, off[1] + 1, off[2] + 1]

        e = np.eye(3, dtype=int)
        A = np.empty((3, 3))
        H = np.empty((3, 3, 3))
        for i in range(3):
            A[:, i] = (at(e[i]) - at(-e[i])) / (2 * s)
            H[:, i, i] = (at(e[i]) - 2 * at(0 * e[i]) + at(-e[i])) / s ** 2
            for j in range(i + 1, 3):
                H[:, i, j] = H[:, j, i] = (at(e[i] + e[j]) - at(e[i] - e[j]) - at(e[j] - e[i]) + at(-e[i] - e[j])) / (4 * s ** 2)
        q = np.empty((3, 6))
        for k, (i, j) in enumerate(_PAIRS):
            q[:, k] = 0.5 * H[:, i, i] if i == j else H[:, i, j]
        return FrameEarth(np.ascontiguousarray(A), np.ascontiguousarray(q), np.ascontiguousarray(np.linalg.inv(A)))


@numba.njit(cache=True, inline="always")
def to_camera_nb(A, q, dx, dy, dz):
    """``FrameEarth.to_camera`` of one offset (numba)."""
    p0, p1, p2, p3, p4, p5 = dx * dx, dy * dy, dz * dz, dx * dy, dx * dz, dy * dz
    vx = A[0, 0] * dx + A[0, 1] * dy + A[0, 2] * dz + (q[0, 0] * p0 + q[0, 1] * p1 + q[0, 2] * p2
                                                       + q[0, 3] * p3 + q[0, 4] * p4 + q[0, 5] * p5)
    vy = A[1, 0] * dx + A[1, 1] * dy + A[1, 2] * dz + (q[1, 0] * p0 + q[1, 1] * p1 + q[1, 2] * p2
                                                       + q[1, 3] * p3 + q[1, 4] * p4 + q[1, 5] * p5)
    vz = A[2, 0] * dx + A[2, 1] * dy + A[2, 2] * dz + (q[2, 0] * p0 + q[2, 1] * p1 + q[2, 2] * p2
                                                       + q[2, 3] * p3 + q[2, 4] * p4 + q[2, 5] * p5)
    return vx, vy, vz


@numba.njit(cache=True, inline="always")
def to_map_nb(A_inv, q, vx, vy, vz):
    """``FrameEarth.to_map`` of one camera-frame point (numba), one fixed-point step: the linear inverse is off by
    the quadratic terms (< 0.2 m at 1.5 km), which the step reduces to 2 q d x 0.2 m (< 0.1 mm): enough for the
    texture and shading of a surface point."""
    dx = A_inv[0, 0] * vx + A_inv[0, 1] * vy + A_inv[0, 2] * vz
    dy = A_inv[1, 0] * vx + A_inv[1, 1] * vy + A_inv[1, 2] * vz
    dz = A_inv[2, 0] * vx + A_inv[2, 1] * vy + A_inv[2, 2] * vz
    p0, p1, p2, p3, p4, p5 = dx * dx, dy * dy, dz * dz, dx * dy, dx * dz, dy * dz
    wx = q[0, 0] * p0 + q[0, 1] * p1 + q[0, 2] * p2 + q[0, 3] * p3 + q[0, 4] * p4 + q[0, 5] * p5
    wy = q[1, 0] * p0 + q[1, 1] * p1 + q[1, 2] * p2 + q[1, 3] * p3 + q[1, 4] * p4 + q[1, 5] * p5
    wz = q[2, 0] * p0 + q[2, 1] * p1 + q[2, 2] * p2 + q[2, 3] * p3 + q[2, 4] * p4 + q[2, 5] * p5
    return (dx - (A_inv[0, 0] * wx + A_inv[0, 1] * wy + A_inv[0, 2] * wz),
            dy - (A_inv[1, 0] * wx + A_inv[1, 1] * wy + A_inv[1, 2] * wz),
            dz - (A_inv[2, 0] * wx + A_inv[2, 1] * wy + A_inv[2, 2] * wz))
