"""Local Cartesian adjustment frame: East-North-Up tangent plane at the block centre.

The bundle adjustment runs in a Cartesian frame in which the collinearity equations hold exactly;
map-projection coordinates are not such a frame (scale factor, earth curvature). Project-CRS
coordinates ``(x, y, h)`` go to the geocentric frame of the project's OWN datum (a conversion, never a
datum shift: ``aerotri.geom.crs.transform``), then to ENU at the origin. Attitudes given in the project CRS
refer to the grid axes (grid east, grid north, up) at the projection centre; ``rotation_local_from_map``
gives the rotation between those axes and ENU.

Heights: the frame reads the project's heights as ellipsoidal heights. When the project's heights are
normal or orthometric heights ([project] heights), the points sit N (the geoid undulation, at most
about 100 m) off their true place along the normal; within a block that is a translation plus a
scale change of N / R (< 16 ppm), which the round trip map -> local -> map undoes exactly and which
does not bend the bundles. So no geoid grid is needed for the adjustment.
"""

from __future__ import annotations

import functools

import numpy as np

from aerotri.geom.crs.definition import horizontal_crs, parse_crs
from aerotri.geom.crs.ellipsoid import Ellipsoid, enu_rotation, geocentric_to_geodetic
from aerotri.geom.crs.transform import CrsTransformer, same_datum_geocentric
from aerotri.geom.rotation import FLIP_YZ


@functools.lru_cache(maxsize=16)
def _ecef_transformers(crs_wkt: str) -> tuple[CrsTransformer, CrsTransformer]:
    """Project CRS -> the geocentric frame of its own datum, and back: built once per CRS (PROJ's set-up costs
    0.5 s; a frame's footprint and its ortho each make a ``LocalFrame``). pyproj's transformers are thread-safe."""
    crs = parse_crs(crs_wkt, "project crs")
    to_ecef = CrsTransformer(crs, same_datum_geocentric(crs))
    return to_ecef, to_ecef.inverse()


class LocalFrame:
    """Tangent plane (ENU) at ``origin_map`` (x, y, h in the project CRS)."""

    def __init__(self, crs, origin_map):
        self.crs = horizontal_crs(parse_crs(crs, "project crs"))
        self.origin_map = np.asarray(origin_map, dtype=float).reshape(3)
        self.cartesian_crs = not self.crs.is_geographic and self.crs.is_engineering
        if self.cartesian_crs:
            self.R = np.eye(3)
            self.ecef0 = self.origin_map.copy()
            return
        self._to_ecef, self._from_ecef = _ecef_transformers(self.crs.to_wkt())
        self.ecef0 = np.concatenate(self._to_ecef.transform(*self.origin_map[:, None]))
        lat, lon, _ = geocentric_to_geodetic(*self.ecef0, Ellipsoid.from_crs(self.crs))
        self.R = enu_rotation(lat, lon)  # rows: east, north, up in ECEF

    @classmethod
    def at_centre(cls, crs, points_map) -> "LocalFrame":
        """Frame at the centre of the bounding box of ``points_map`` (N, 3), at their mean height."""
        p = np.asarray(points_map, dtype=float)
        centre = np.array([(p[:, 0].min() + p[:, 0].max()) / 2, (p[:, 1].min() + p[:, 1].max()) / 2, p[:, 2].mean()])
        return cls(crs, centre)

    def to_local(self, xyz_map) -> np.ndarray:
        """Project-CRS coordinates (N, 3) -> ENU metres (N, 3)."""
        p = np.atleast_2d(np.asarray(xyz_map, dtype=float))
        if self.cartesian_crs:
            return p - self.origin_map
        ecef = np.stack(self._to_ecef.transform(p[:, 0], p[:, 1], p[:, 2]), axis=-1)
        return (ecef - self.ecef0) @ self.R.T

    def to_map(self, enu) -> np.ndarray:
        """ENU metres (N, 3) -> project-CRS coordinates (N, 3)."""
        e = np.atleast_2d(np.asarray(enu, dtype=float))
        if self.cartesian_crs:
            return e + self.origin_map
        ecef = e @ self.R + self.ecef0
        return np.stack(self._from_ecef.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2]), axis=-1)

    def jacobian_local_from_map(self, xyz_map, step_m: float = 1.0) -> np.ndarray:
        """d(ENU)/d(x, y, h) at each point (N, 3, 3), by central differences of about ``step_m`` metres (in a
        geographic CRS, as Metashape's EPSG:4326 reference, a step in degrees of that length: a step of 1 unit,
        1 degree, turned the axes up to 0.0001 deg before trial-exchange)."""
        p = np.atleast_2d(np.asarray(xyz_map, dtype=float))
        step = np.full(3, float(step_m))
        if self.crs.is_geographic:
            step[:2] = step_m / 111_000.0
        J = np.empty((len(p), 3, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = step[k]
            J[:, :, k] = (self.to_local(p + d) - self.to_local(p - d)) / (2 * step[k])
        return J

    def jacobian_map_from_local(self, enu, step_m: float = 1.0) -> np.ndarray:
        """d(x, y, h)/d(ENU) at each local point (N, 3, 3), by central differences of ``step_m`` metres (whatever
        the map's unit)."""
        p = np.atleast_2d(np.asarray(enu, dtype=float))
        J = np.empty((len(p), 3, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = step_m
            J[:, :, k] = (self.to_map(p + d) - self.to_map(p - d)) / (2 * step_m)
        return J

    def rotation_local_from_map(self, xyz_map) -> np.ndarray:
        """Rotation (N, 3, 3) from grid axes at each point to ENU axes (the scale factor removed)."""
        U, _, Vt = np.linalg.svd(self.jacobian_local_from_map(xyz_map))
        return U @ Vt


class CameraOnEarth:
    """A frame's object -> camera transformation for points in the project CRS: map coordinates (x, y, h) -> ENU at
    the projection centre (``LocalFrame``) -> the computer-vision camera frame (x right, y down, z along the viewing
    direction; metres), the attitude ``R_map`` (photogrammetric camera -> grid east, grid north, up at the centre: the
    convention of eo.txt) turned into ENU by ``rotation_local_from_map``: as the adjustment solves and the simulator
    renders. A projected CRS is not a Cartesian frame: UTM's scale factor and (R + h) / R (400 ppm at the presets'
    origin: 0.28 m 700 m from the nadir), the earth's curvature (0.04 m there) and the horizontal scale changing with
    height (1 / R a metre: 0.11 m there, 1,000 m below the camera).

    To second order in the map offsets d = (dx, dy, dz) from the centre the camera-frame coordinates are
    ``M (dx (1 + dz / R), dy (1 + dz / R), dz - (dx^2 + dy^2) / 2R)``: ``M`` the transformation's Jacobian at the centre
    (scale factor, (R + h) / R, grid convergence, attitude; not a rotation), ``R`` the earth's mean radius of curvature
    there; the other second-order terms (the ellipsoid's two radii, the scale factor's change) leave the ray within
    1.2 mm of the point 1.4 km from the centre (``tests/ortho/test_rectify_earth.py``). The image position is that of ``M (dx, dy, earth_dz(dx, dy, dz, 1 / R))``, whose depth is the
    true one over 1 + dz / R (1.6e-4). A Cartesian (engineering) CRS: ``M = (R_map FLIP_YZ)^T`` and 1 / R = 0, the
    flat collinearity exactly."""

    def __init__(self, crs, centre_map, R_map):
        self.centre_map = np.asarray(centre_map, dtype=float).reshape(3)
        R_map = np.asarray(R_map, dtype=float).reshape(3, 3)
        self.frame = LocalFrame(crs, self.centre_map)
        self.flat = self.frame.cartesian_crs
        R_enu = R_map if self.flat else self.frame.rotation_local_from_map(self.centre_map)[0] @ R_map
        self.M_enu = np.ascontiguousarray((R_enu @ FLIP_YZ).T)  # ENU (origin at the centre) -> camera frame
        if self.flat:
            self.M, self.inv_radius = self.M_enu, 0.0
            return
        self.M = np.ascontiguousarray(self.M_enu @ self.frame.jacobian_local_from_map(self.centre_map[None])[0])
        ell = Ellipsoid.from_crs(self.frame.crs)
        lat = np.radians(geocentric_to_geodetic(*self.frame.ecef0, ell)[0])
        self.inv_radius = float(1.0 / np.sqrt(ell.meridian_radius_m(lat) * ell.prime_vertical_radius_m(lat)))

    def to_camera(self, xyz_map) -> np.ndarray:
        """Camera-frame coordinates (N, 3) of map points (N, 3), exactly (through ``LocalFrame``)."""
        return self.frame.to_local(xyz_map) @ self.M_enu.T


class FramesOnEarth:
    """Frames oriented in the project CRS (eo.txt: projection centres, attitudes ``R_map`` photogrammetric camera ->
    grid east, grid north, up at the centre) as cameras over the earth see map points: the one way every stage projects
    map coordinates into a frame (control prediction, ray checks, footprints). Map points go exactly (``LocalFrame``)
    to the ENU frame ``frame``, where frame i has its centre ``centres_local[i]`` and attitude ``R_local[i]`` =
    ``rotation_local_from_map(C) @ R_map`` and the flat collinearity holds: as the adjustment solves, the simulator
    renders and the rectifier maps (``CameraOnEarth``, its per-frame second-order form, within 1.5 mm). A projected
    CRS is not Cartesian: taking it as one puts the ground 400 ppm too near the nadir at the presets' origin (0.28 m,
    2.8 px of a DMC frame 700 m from it). An engineering (Cartesian) CRS, or ``cartesian``: the map coordinates
    themselves, the flat collinearity to the bit."""

    def __init__(self, crs, centres_map, R_map, frame: LocalFrame | None = None):
        self.centres_map = np.atleast_2d(np.asarray(centres_map, dtype=float))
        self.R_map = np.asarray(R_map, dtype=float).reshape(-1, 3, 3)
        self.frame = frame if frame is not None or crs is None else LocalFrame.at_centre(crs, self.centres_map)
        self.flat = self.frame is None or self.frame.cartesian_crs
        if self.flat:
            self.centres_local, self.R_local = self.centres_map, self.R_map
        else:
            self.centres_local = self.frame.to_local(self.centres_map)
            self.R_local = self.frame.rotation_local_from_map(self.centres_map) @ self.R_map

    @classmethod
    def cartesian(cls, centres_m, R) -> "FramesOnEarth":
        """Frames whose coordinates are those of a Cartesian frame (an engineering CRS, a simulator's local metres)."""
        return cls(None, centres_m, R)

    def to_local(self, xyz_map) -> np.ndarray:
        """Map points (..., 3) -> the Cartesian frame of ``centres_local`` (the same array when ``flat``)."""
        p = np.asarray(xyz_map, dtype=float)
        return p if self.flat else self.frame.to_local(p.reshape(-1, 3)).reshape(p.shape)

    def to_map(self, xyz_local) -> np.ndarray:
        """The inverse of ``to_local``."""
        p = np.asarray(xyz_local, dtype=float)
        return p if self.flat else self.frame.to_map(p.reshape(-1, 3)).reshape(p.shape)

    def project(self, camera, i: int, xyz_map):
        """Pixel x, y and depth (m) of map points (N, 3) in frame ``i`` (``Camera.project``: NaN behind the camera or
        beyond the lens model's fold)."""
        return self.project_local(camera, i, self.to_local(xyz_map))

    def project_local(self, camera, i: int, points_local):
        """``project`` of points already in the Cartesian frame (``to_local``, once for many frames)."""
        return camera.project(points_local, self.centres_local[i], self.R_local[i])

    def rays_local(self, camera, i: int, x_px, y_px) -> np.ndarray:
        """Unit viewing directions (N, 3) of pixels of frame ``i`` in the Cartesian frame (from ``centres_local[i]``)."""
        return camera.rays(x_px, y_px, self.R_local[i])

    def at_height(self, i: int, dirs_local, z_m, iterations: int = 4, tol_m: float = 1e-6) -> np.ndarray:
        """Map points (K, 3) of the rays from frame ``i``'s centre along ``dirs_local`` (K, 3, pointing down) at the map
        height ``z_m`` (scalar or (K,)). On the earth a ray's height above the ellipsoid is not linear along it
        (its curvature: 0.04 m 700 m from the nadir): Newton's method from the flat plane's point, to ``tol_m``."""
        d = np.atleast_2d(np.asarray(dirs_local, dtype=float))
        z = np.broadcast_to(np.asarray(z_m, dtype=float), (len(d),))
        C = self.centres_local[i]
        if self.flat:
            t = (z - C[2]) / d[:, 2]
            return np.stack([C[0] + t * d[:, 0], C[1] + t * d[:, 1], z], axis=-1)
        t = (z - self.centres_map[i, 2]) / d[:, 2]
        for k in range(iterations + 1):
            P = self.frame.to_map(C + t[:, None] * d)
            dz = z - P[:, 2]
            if k == iterations or not np.any(np.abs(dz) > tol_m):
                return P
            t = t + dz / d[:, 2]  # d height / d t is the ray's up component to 1e-4
        return P


class MapAnchors:
    """Project-CRS coordinates of points that move little between calls (the iterations of a solve) without a CRS
    transformation per point and call: each slot keeps an anchor, the local position ``p0`` at which its map
    position ``m0`` and ``d map / d local`` ``J0`` were last computed exactly (``LocalFrame.to_map`` and
    ``jacobian_map_from_local``), and ``to_map`` returns ``m0 + J0 (p - p0)``. A slot whose point lies
    more than ``tol_m`` (any local axis) from its anchor, or has none, is anchored anew at the point.

    Exact to the second-order term of the map projection and the earth's curvature, below ``d^2 / R`` for a
    point ``d`` from its anchor (``R`` the earth's radius): 0.16 um at the default 1 m. Whatever point a slot
    is given, the result is that accurate: the slots only decide which anchor is tried first (``index``: the
    slots of the points, else 0..n-1); the store grows to the largest slot asked for."""

    def __init__(self, frame: LocalFrame, n: int = 0, tol_m: float = 1.0):
        self.frame, self.tol_m = frame, float(tol_m)
        self.p0 = np.full((n, 3), np.nan)
        self.m0 = np.full((n, 3), np.nan)
        self.J0 = np.full((n, 3, 3), np.nan)
        self.anchored = 0  # anchors computed so far (the CRS transformations this store made)

    def _grow(self, n: int) -> None:
        if n <= len(self.p0):
            return
        extra = n - len(self.p0)
        self.p0 = np.concatenate([self.p0, np.full((extra, 3), np.nan)])
        self.m0 = np.concatenate([self.m0, np.full((extra, 3), np.nan)])
        self.J0 = np.concatenate([self.J0, np.full((extra, 3, 3), np.nan)])

    def to_map(self, coords_local, index=None, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """(map coordinates (M, 3), d map / d local (M, 3, 3), None unless ``jacobian``) of local points (M, 3); NaN
        for non-finite points. ``index``: the slot of each point (M,), distinct (default 0..M-1)."""
        p = np.atleast_2d(np.asarray(coords_local, dtype=float))
        idx = np.arange(len(p)) if index is None else np.asarray(index, dtype=np.int64)
        if len(idx):
            self._grow(int(idx.max()) + 1)
        m = np.empty_like(p)
        stale = np.zeros(len(p), dtype=bool)
        # idx contiguous (a caller's index may be a strided view): numba compiles one signature
        from aerotri.geom.local_frame_kernels import _taylor

        _taylor(self.p0, self.m0, self.J0, np.ascontiguousarray(idx), p, tol=self.tol_m, m=m, stale=stale)
        if stale.any():
            k = np.flatnonzero(stale)
            slot = idx[k]
            self.p0[slot], self.m0[slot] = p[k], self.frame.to_map(p[k])
            self.J0[slot] = self.frame.jacobian_map_from_local(p[k])
            m[k] = self.m0[slot]
            self.anchored += len(k)
        return m, (self.J0[idx] if jacobian else None)


def __getattr__(name):
    # the numba kernels live in ``local_frame_kernels``: importing numba costs 0.3 CPU-s, and the commands that
    # only read frames (``ortho mosaic``, ``ortho check``) import this module through ``ortho.rectify``
    if name == "earth_dz":
        from aerotri.geom.local_frame_kernels import earth_dz

        return earth_dz
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
