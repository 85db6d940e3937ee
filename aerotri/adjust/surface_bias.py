"""The LiDAR's systematic error in the covariances: the surface control's datum as a consider parameter.

A DEM (and roof planes) from airborne LiDAR is offset strip by strip (GNSS/IMU and boresight: a few cm in plan and
height per strip, ``lidarctl corners``' ``sigma_strip_*``). The surface observations of thousands of tie points
share that offset, yet the adjustment weighs them as independent: with 6,500 points of 0.15 m the block's height
comes out known to a millimetre, while it follows the LiDAR's strip offsets of several centimetres (the full-size DMC
block: orientations 5-11 sigmas off in height and omega, issue 41).

Model: the surface is offset by an unknown 3D shift ``b = (dx, dy, dz)`` (map axes, metres), constant over a cell
``cell_m`` across by ``length_m`` along the block's flight direction (about a LiDAR strip's swath across; along, a
strip's error holds for kilometres) and independent between cells, each with the prior sigma of the LiDAR's
georeferencing error (plan ``sigma_xy_m``, height ``sigma_z_m``). Control points that are corners of the same
LiDAR carry the shift of their cell too (their given coordinates move with it). It is not estimated (nothing in the block
separates it from the surface: the solution stays as it is) but considered (Schmidt's consider covariance): the
solution's sensitivity to each cell's shift, ``S_k = d x / d b_k``, adds ``sum_k S_k sigma_k^2 S_k'`` to its
covariance. A surface observation ``e = h - DEM(x, y)`` changes under a shift by ``de/d(dx, dy, dz) = (DEM_x,
DEM_y, -1)`` (a roof plane's distance along its normal: ``(a, b, -1) / s``). With the object points eliminated
(the reduced camera system ``S = U - W V^-1 W'``), the shift enters the orientations' right-hand side as
``n_k = sum_rays G' g_k`` (``G = V^-1 W`` of a ray, ``g_k = B' a_k`` the point's whitened surface Jacobian times
the observation's whitened partial), so ``S_k = S^-1 n_k``: one solve with the reduced covariance's factor for all
cells at once. The object points' own sensitivity adds ``V^-1 g_k`` to the orientations' part.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from aerotri.adjust import graph as G

log = logging.getLogger(__name__)

MAX_SENSITIVITY_ENTRIES = 25_000_000  # reduced unknowns x cell parameters held (200 MB): cells grow beyond that


@dataclasses.dataclass(frozen=True)
class SurfaceBias:
    """The considered surface offsets: ``cells`` cells of ``cell_m`` x ``length_m`` (map units, across x along the
    flight), prior sigmas (m); the surface (and LiDAR control) observations considered (``point`` their block points, ``cell`` their cells, ``g`` (M, 3, 3) their whitened
    point Jacobian times whitened partials); and the reduced unknowns' sensitivity times the sigmas, ``scaled``
    (n, 3 cells): column ``3 c + q`` the change of the solution when cell ``c`` shifts by one sigma along axis
    ``q`` (x, y, z)."""

    cell_m: float  # across the flight
    length_m: float  # along it
    direction_deg: float  # the flight direction, from the map's x axis (local frame, counter-clockwise)
    sigma_xy_m: float
    sigma_z_m: float
    cells: int
    point: np.ndarray
    cell: np.ndarray
    g: np.ndarray
    scaled: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        return np.tile([self.sigma_xy_m, self.sigma_xy_m, self.sigma_z_m], self.cells)

    def block(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The added covariance between the reduced scalars ``a`` and ``b``."""
        return self.scaled[a] @ self.scaled[b].T


def flight_direction(centre: np.ndarray, strip: np.ndarray) -> float:
    """The block's flight direction (radians from the x axis, modulo pi): the principal axis of each strip's
    projection centres, weighted by the strip's length; 0 for a block without a strip of two frames."""
    acc = np.zeros(2)
    for s in np.unique(strip):
        c = centre[strip == s, :2]
        if len(c) < 2:
            continue
        d = c - c.mean(axis=0)
        w, v = np.linalg.eigh(d.T @ d)
        a = 2.0 * np.arctan2(v[1, 1], v[0, 1])  # doubled angle: directions modulo pi add up
        acc += np.sqrt(w[1]) * np.array([np.cos(a), np.sin(a)])
    return 0.5 * float(np.arctan2(acc[1], acc[0])) if np.any(acc) else 0.0


def _cells(xy: np.ndarray, cell_m: float, length_m: float, direction: float, n_unknowns: int
           ) -> tuple[np.ndarray, float, float]:
    """Cell index per map position: cells ``length_m`` along the flight ``direction`` and ``cell_m`` across it
    (grown until the sensitivity fits the memory bound), and the sizes used."""
    c, s = np.cos(direction), np.sin(direction)
    uv = np.column_stack([xy[:, 0] * c + xy[:, 1] * s, -xy[:, 0] * s + xy[:, 1] * c])
    lo = uv.min(axis=0)
    while True:
        ij = np.floor((uv - lo) / np.array([length_m, cell_m])).astype(np.int64)
        key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
        uniq, cell = np.unique(key, return_inverse=True)
        if 3 * len(uniq) * n_unknowns <= MAX_SENSITIVITY_ENTRIES or len(uniq) == 1:
            return cell.ravel(), cell_m, length_m
        cell_m, length_m = cell_m * 1.5, length_m * 1.5


def _observations(block: G.Block, state: G.State, rays, control_active) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The observations that share the surface's offset: (block point (M,), map x y (M, 2), g (M, 3, 3) the
    point's whitened Jacobian times the observation's whitened partials ``d r / d (dx, dy, dz)``). The surface
    observations of the active points, and the control points from the same LiDAR (``lidar_control``) whose given
    coordinates carry the offset: ``r = C^-1/2 (X - given)``, ``given`` moved by ``d local / d map`` times it."""
    sc = block.surface
    held = np.zeros(block.n_points, bool)  # the active control points: unknowns of their own, no surface observation
    held[block.control_point[np.asarray(control_active, bool)]] = True
    pts = np.flatnonzero(np.asarray(block.surface_active, bool) & rays.used & ~held)
    sub = sc.of_points(pts)  # the points' own map anchors and roof faces
    e, J, sigma = sub.observe(state.points[pts])
    partial, xy = sub.offset_partials(state.points[pts])
    ok = np.isfinite(e) & np.isfinite(J).all(axis=1) & np.isfinite(partial).all(axis=1)
    pts, J, sigma, partial, xy = pts[ok], J[ok], sigma[ok], partial[ok], xy[ok]
    g = np.einsum("mi,mq->miq", J / sigma[:, None], partial / sigma[:, None])
    if sc.lidar_control is not None and len(block.control_point):
        c = np.flatnonzero(np.asarray(sc.lidar_control, bool) & np.asarray(control_active, bool))
        c = c[rays.used[block.control_point[c]]]
        if len(c):
            given_map = sc.frame.to_map(block.control_local[c])
            xy_u, z_u = sc.map_unit_m
            J_lm = sc.frame.jacobian_local_from_map(given_map) / np.array([xy_u, xy_u, z_u])[None, None]  # per metre
            g_c = -np.linalg.solve(block.control_cov_local[c], J_lm)  # B' a = C^-1/2' (-C^-1/2 J_lm)
            pts = np.r_[pts, block.control_point[c]]
            xy = np.vstack([xy, given_map[:, :2]])
            g = np.concatenate([g, g_c])
    return pts, xy, g


def surface_bias(block: G.Block, state: G.State, rays, rc, *, control_active, cell_m: float, length_m: float,
                 sigma_xy_m: float, sigma_z_m: float) -> SurfaceBias | None:
    """The consider covariance's factor of the surface control's cell offsets at the solution ``state``
    (``rays``: the points' ``covariance.PointRays``; ``rc``: the ``ReducedCovariance``, unit weight). None when
    the block has no active surface observation."""
    sc = block.surface
    if sc is None or block.surface_active is None or not (sigma_xy_m > 0 or sigma_z_m > 0):
        return None
    pts, xy, g = _observations(block, state, rays, control_active)
    if not len(pts):
        return None
    direction = flight_direction(state.centre, block.strip)  # local frame: within a degree of the map grid
    cell, cell_used, length_used = _cells(xy, cell_m, length_m, direction, rc.n)
    if cell_used > cell_m:
        log.warning(f"surface bias: cells of {cell_used:.0f} x {length_used:.0f} map units instead of {cell_m:.0f} x "
                    f"{length_m:.0f} (memory bound)")
    n_cells = int(cell.max()) + 1
    # per point and cell parameter: a point is in one cell (a control point on the surface twice, maybe in two)
    key = pts * n_cells + cell
    uk, inv = np.unique(key, return_inverse=True)
    g_sum = np.zeros((len(uk), 3, 3))
    np.add.at(g_sum, inv.ravel(), g)
    upt, ucell = uk // n_cells, uk % n_cells
    n = np.zeros((rc.n, 3 * n_cells))
    order = np.argsort(upt, kind="stable")
    first = np.searchsorted(upt[order], rays.pt, side="left")
    last = np.searchsorted(upt[order], rays.pt, side="right")
    k_on = np.flatnonzero(last > first)
    for a in range(0, len(k_on), 100_000):
        k = k_on[a:a + 100_000]
        _, _, Gk, idx = rays.rays(k)
        for extra in range(int((last[k] - first[k]).max())):  # the (rare) second cell of a point
            has = first[k] + extra < last[k]
            e = order[first[k][has] + extra]
            contrib = np.einsum("kia,kiq->kaq", Gk[has], g_sum[e])  # (k, d, 3) = G' g
            cols = 3 * ucell[e][:, None] + np.arange(3)[None]
            np.add.at(n, (idx[has][:, :, None], cols[:, None, :]), contrib)
    bias = SurfaceBias(float(cell_used), float(length_used), float(np.degrees(direction)), float(sigma_xy_m),
                       float(sigma_z_m), n_cells, upt, ucell, g_sum, n)
    return dataclasses.replace(bias, scaled=rc.multiply(n) * bias.sigmas[None])


def pose_covariance(bias: SurfaceBias, rc, n_images: int) -> np.ndarray:
    """The covariance (N, 6, 6) the offsets add to each image's pose (tangent [omega, v], as ``pose_cov``)."""
    idx = np.array([rc.offset[G.X(i)] for i in range(n_images)])[:, None] + np.arange(6)[None]
    S = bias.scaled[idx]  # (N, 6, K)
    return S @ S.transpose(0, 2, 1)


def key_covariance(bias: SurfaceBias, rc, key) -> np.ndarray:
    """The covariance the offsets add to one key's block (e.g. the calibration)."""
    idx = rc.offset[key] + np.arange(rc.dim[key])
    return bias.block(idx, idx)


MAX_POINT_WORK = 2_000_000_000  # rays x cell parameters: beyond, the object points keep their formal covariances


def point_covariance(bias: SurfaceBias, rays, n_points: int) -> np.ndarray | None:
    """The covariance (P, 3, 3) the offsets add to the object points (local frame): their sensitivity is their
    own surface observation's ``V^-1 g`` plus their rays' ``G S_k`` (the orientations' change carried over).
    None for a block too large for it (``MAX_POINT_WORK``)."""
    K = bias.scaled.shape[1]
    if len(rays.pt) * K > MAX_POINT_WORK:
        log.warning(f"surface bias: {len(rays.pt)} rays x {K} cell offsets: the object points' sigmas stay formal")
        return None
    own = np.einsum("mij,mjq->miq", rays.Vinv[bias.point], bias.g)  # V^-1 g, per point and cell
    sig = bias.sigmas
    by_point = np.argsort(bias.point, kind="stable")
    bp = bias.point[by_point]
    out = np.full((n_points, 3, 3), np.nan)
    order = np.argsort(rays.pt, kind="stable")
    pt_sorted = rays.pt[order]
    step = max(1, 10_000_000 // (16 * K))  # rays per chunk: their gathered sensitivities (rays, 6 or 15, K) at 80 MB
    bounds = np.unique(np.r_[np.searchsorted(pt_sorted, pt_sorted[::step]), len(order)])  # whole points per chunk
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        k = order[lo:hi]
        p0, p1 = int(pt_sorted[lo]), int(pt_sorted[hi - 1]) + 1
        _, _, Gk, idx = rays.rays(k)
        D = np.zeros((p1 - p0, 3, K))
        np.add.at(D, rays.pt[k] - p0, np.einsum("kid,kdK->kiK", Gk, bias.scaled[idx]))
        e = by_point[np.searchsorted(bp, p0):np.searchsorted(bp, p1)]  # the chunk's own observations
        for q in range(3):
            col = 3 * bias.cell[e] + q
            np.add.at(D, (bias.point[e] - p0, slice(None), col), own[e, :, q] * sig[col][:, None])
        out[p0:p1] = D @ D.transpose(0, 2, 1)
    return out


class ConsideredCovariance:
    """A ``ReducedCovariance`` with the surface offsets' covariance added (the same interface: ``offset``, ``dim``,
    ``n``, ``entries``, ``block``, ``marginalCovariance``, ``jointMarginalCovariance``, ``multiply``), in its unit
    weight: the callers scale by ``sigma0^2``, so the added part is divided by it (the offsets' sigmas are metres,
    not in the images' unit weight)."""

    def __init__(self, rc, bias: SurfaceBias, sigma0_sq: float):
        self._rc, self._bias = rc, bias
        self._s = bias.scaled / np.sqrt(sigma0_sq if np.isfinite(sigma0_sq) and sigma0_sq > 0 else 1.0)
        self.offset, self.dim, self.n = rc.offset, rc.dim, rc.n

    def entries(self, rows, cols) -> np.ndarray:
        rows, cols = np.broadcast_arrays(np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64))
        return self._rc.entries(rows, cols) + np.einsum("...k,...k->...", self._s[rows], self._s[cols])

    def block(self, ka, kb) -> np.ndarray:
        a, b = self.offset[ka], self.offset[kb]
        return self.entries((a + np.arange(self.dim[ka]))[:, None], (b + np.arange(self.dim[kb]))[None, :])

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 (gtsam.Marginals interface)
        return self.block(key, key)

    def jointMarginalCovariance(self, keys):  # noqa: N802
        return _Joint(self)

    def multiply(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        return self._rc.multiply(b) + self._s @ (self._s.T @ b)


class _Joint:
    def __init__(self, cov):
        self._cov = cov

    def at(self, ka, kb):
        return self._cov.block(ka, kb)
