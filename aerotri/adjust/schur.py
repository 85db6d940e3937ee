"""Tie points eliminated by the Schur complement: the reduced camera system, linearised in numba.

In a bundle with a fixed camera each tie point ``j`` touches only the orientations that see it. With
the whitened collinearity Jacobians ``A_k = d v_k / d pose`` (2 x 6) and ``B_k = d v_k / d point``
(2 x 3) of its rays ``k`` and their residuals ``r_k`` (observed - computed, in standard deviations),
the normal equations are blocked as

    [ U   W ] [d_pose ]   [b_pose ]        U = sum A'A (per image), V_j = sum_k B_k'B_k,
    [ W'  V ] [d_point] = [b_point]        W_k = A_k'B_k, b_pose = sum A'r, b_point_j = sum_k B_k'r_k

and the points are eliminated point by point (``V`` is block diagonal, 3 x 3):

    S = U - W V^-1 W',    s = b_pose - W V^-1 b_point,    d_point_j = V_j^-1 (b_point_j - sum_k W_k' d_pose)

``S`` has a 6 x 6 block on the diagonal per image and one per pair of images sharing a tie point.
These go to gtsam as HessianFactors next to gtsam's own linearisation of every other factor (GNSS,
control points, ...), and gtsam's multifrontal Cholesky solves the whole reduced system. This is
the reduced camera system of Ceres' Schur solvers. The per-ray and per-point arithmetic is compiled
with numba: on the 1000-frame benchmark block (120k points) one linearisation takes 0.15 s here, 0.65 s
in gtsam's SmartProjectionPoseFactor (per-point dynamic allocations), and the elimination of 7,600
HessianFactors 0.05 s instead of 0.38 s for 120,000 per-point ones.

Robust solves weigh each ray by Huber's kernel on its whitened residual norm ``x`` (``w = min(1, k / x)``,
iteratively reweighted at every linearisation, as gtsam linearises a Robust noise model: ``A``, ``B`` and
``r`` scaled by ``sqrt(w)``); their cost is gtsam's robust error, ``rho(x) = x^2 / 2`` for ``x <= k``,
``k (x - k / 2)`` beyond.

Pose increments follow gtsam's Pose3 retraction (right perturbation): ``R -> R Exp(omega)``,
``C -> C + R v`` for the tangent ``[omega, v]``.
"""

from __future__ import annotations

import dataclasses
import types
from typing import NamedTuple

import gtsam
import numba
import numpy as np

from aerotri.geom.lens_kernels import (BrownCoefficients, brown_coefficient_jacobian, brown_distort,
                                       brown_distort_jacobian)


@dataclasses.dataclass
class RayPairs:
    """Tie-point rays grouped by point, and every pair of rays of the same point.

    ``obs`` are observation indices sorted by point; ``row`` the point row (0..M-1) of each, ``start``
    (M + 1) the first ray of each point. Pairs ``(a, b)`` index into ``obs`` with ``image[a] < image[b]``;
    ``pair_block`` is the index of their image pair in ``images`` (-1 when both rays are in one image).
    """

    obs: np.ndarray
    row: np.ndarray
    start: np.ndarray
    a: np.ndarray
    b: np.ndarray
    pair_block: np.ndarray
    images: np.ndarray  # (n_blocks, 2) image pairs i < j


def ray_pairs(obs: np.ndarray, obs_point: np.ndarray, obs_image: np.ndarray, n_images: int) -> RayPairs:
    obs = obs[np.argsort(obs_point[obs], kind="stable")]
    pt, im = obs_point[obs], obs_image[obs]
    row = np.cumsum(np.r_[0, np.diff(pt) != 0]).astype(np.int64)
    start = np.r_[0, np.flatnonzero(np.diff(pt)) + 1, len(obs)].astype(np.int64)
    a_list, b_list = [], []
    off = 1
    while off < len(pt):  # rays of the same point are consecutive: pair each with the one ``off`` further on
        same = np.flatnonzero(pt[:-off] == pt[off:])
        if len(same) == 0:
            break
        a_list.append(same)
        b_list.append(same + off)
        off += 1
    a = np.concatenate(a_list) if a_list else np.zeros(0, dtype=np.int64)
    b = np.concatenate(b_list) if b_list else np.zeros(0, dtype=np.int64)
    swap = im[a] > im[b]
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    order = np.lexsort((b, a))
    a, b = a[order], b[order]
    code = im[a].astype(np.int64) * n_images + im[b]
    pair_code, pair_block = np.unique(code, return_inverse=True)
    images = np.column_stack([pair_code // n_images, pair_code % n_images])
    same_image = images[:, 0] == images[:, 1]
    if same_image.any():  # two rays of one point in one image: their coupling belongs to the image's own block
        keep = np.flatnonzero(~same_image)
        new = np.full(len(images), -1, dtype=np.int64)
        new[keep] = np.arange(len(keep))
        pair_block, images = new[pair_block], images[keep]
    return RayPairs(obs, row, start, a.astype(np.int64), b.astype(np.int64), pair_block.astype(np.int64), images)


PARTS = 2  # runs of points linearised in parallel (the machine's 2 cores); fixed, so results do not depend on threads
PARALLEL_MIN_RAYS = 400_000  # below: one serial run (thread start-up and wake-ups cost more than they save)


@dataclasses.dataclass
class ReducedSystem:
    """What ``reduced_camera_system`` returns, by name."""

    U: np.ndarray
    S_pair: np.ndarray
    s: np.ndarray
    f: float
    rr: float
    Vinv: np.ndarray
    b_point: np.ndarray
    W: np.ndarray
    U_cal: np.ndarray
    s_cal: np.ndarray
    U_image_cal: np.ndarray
    Z: np.ndarray


@dataclasses.dataclass
class Workspace:
    """The arrays ``reduced_camera_system`` fills, kept from one linearisation of a set of rays to the next (one
    workspace per set of rays: ``pair_row`` is theirs)."""

    U: np.ndarray  # (parts, N, 6, 6)
    S_pair: np.ndarray  # (parts, n_blocks, 6, 6)
    s: np.ndarray  # (parts, N, 6)
    U_cal: np.ndarray  # (parts, 9, 9)
    s_cal: np.ndarray  # (parts, 9)
    U_ic: np.ndarray  # (parts, N or 0, 6, 9)
    Vinv: np.ndarray  # (M, 3, 3)
    bp: np.ndarray  # (M, 3)
    W: np.ndarray  # (K, 6, 3)
    Z: np.ndarray  # (M or 0, 9, 3)
    pair_row: np.ndarray | None = None  # the point row of each pair's first ray

    @classmethod
    def for_rays(cls, K: int, M: int, n_images: int, n_blocks: int, with_cal: bool) -> "Workspace":
        """Arrays (not initialised) for ``K`` rays of ``M`` points, in the runs ``reduced_camera_system`` takes."""
        return cls.empty(PARTS if K >= PARALLEL_MIN_RAYS else 1, K, M, n_images, n_blocks, with_cal)

    @classmethod
    def empty(cls, parts: int, K: int, M: int, n_images: int, n_blocks: int, with_cal: bool) -> "Workspace":
        return cls(np.empty((parts, n_images, 6, 6)), np.empty((parts, n_blocks, 6, 6)), np.empty((parts, n_images, 6)),
                   np.empty((parts, 9, 9)), np.empty((parts, 9)), np.empty((parts, n_images if with_cal else 0, 6, 9)),
                   np.empty((M, 3, 3)), np.empty((M, 3)), np.empty((K, 6, 3)), np.empty((M if with_cal else 0, 9, 3)))

    def fits(self, parts: int, K: int, M: int, n_images: int, n_blocks: int, with_cal: bool) -> bool:
        return (self.U.shape[:2] == (parts, n_images) and self.S_pair.shape[1] == n_blocks and len(self.W) == K
                and len(self.Vinv) == M and len(self.Z) == (M if with_cal else 0)
                and self.U_ic.shape[1] == (n_images if with_cal else 0))


@numba.njit(cache=True, inline="always")
def _ray(xy, pose, point, model, out):
    """Whitened residual r (2,) and Jacobians of the prediction A (2, 6) wrt the pose tangent, B (2, 3) wrt
    the point and, ``with_cal``, C (2, 9) wrt Cal3DS2 [fx fy s u0 v0 k1 k2 p1 p2] of one ray (pixel ``xy``,
    ``pose`` (centre, R: camera (cv) to object axes), object ``point``) into ``out`` (r, A, B, C); ``model``:
    (cal, inv_sigma, with_cal). Returns False behind the camera. The lens arithmetic is the Brown model's
    (``aerotri.geom.lens_kernels``)."""
    centre, R = pose
    cal, inv_sigma, with_cal = model
    r, A, B, C = out
    d0, d1, d2 = point[0] - centre[0], point[1] - centre[1], point[2] - centre[2]
    x = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2  # R^T (P - C)
    y = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
    z = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
    if z <= 0.0:
        return False
    fx, fy, s, u0, v0, k1, k2, p1, p2 = cal[0], cal[1], cal[2], cal[3], cal[4], cal[5], cal[6], cal[7], cal[8]
    xn, yn = x / z, y / z
    # Cal3DS2 is the Brown lens without k3
    lens = BrownCoefficients(k1, k2, 0.0, p1, p2)
    xd, yd = brown_distort(xn, yn, lens)
    r[0] = (xy[0] - (fx * xd + s * yd + u0)) * inv_sigma
    r[1] = (xy[1] - (fy * yd + v0)) * inv_sigma
    a00, a01, _, a11 = brown_distort_jacobian(xn, yn, lens)  # d(xd, yd) / d(xn, yn)
    # d pixel / d (xn, yn), whitened
    m00, m01 = (fx * a00 + s * a01) * inv_sigma, (fx * a01 + s * a11) * inv_sigma
    m10, m11 = fy * a01 * inv_sigma, fy * a11 * inv_sigma
    iz = 1.0 / z
    # d pixel / d pc (2 x 3): M @ [[1/z, 0, -xn/z], [0, 1/z, -yn/z]]
    j00, j01, j02 = m00 * iz, m01 * iz, -(m00 * xn + m01 * yn) * iz
    j10, j11, j12 = m10 * iz, m11 * iz, -(m10 * xn + m11 * yn) * iz
    # pose: d pc / d omega = [pc]x, d pc / d v = -I
    A[0, 0] = j01 * z - j02 * y
    A[0, 1] = j02 * x - j00 * z
    A[0, 2] = j00 * y - j01 * x
    A[1, 0] = j11 * z - j12 * y
    A[1, 1] = j12 * x - j10 * z
    A[1, 2] = j10 * y - j11 * x
    A[0, 3], A[0, 4], A[0, 5] = -j00, -j01, -j02
    A[1, 3], A[1, 4], A[1, 5] = -j10, -j11, -j12
    # point: d pc / d P = R^T
    for c in range(3):
        B[0, c] = j00 * R[c, 0] + j01 * R[c, 1] + j02 * R[c, 2]
        B[1, c] = j10 * R[c, 0] + j11 * R[c, 1] + j12 * R[c, 2]
    if with_cal:
        C[0, 0], C[0, 1], C[0, 2], C[0, 3], C[0, 4] = xd * inv_sigma, 0.0, yd * inv_sigma, inv_sigma, 0.0
        C[1, 0], C[1, 1], C[1, 2], C[1, 3], C[1, 4] = 0.0, yd * inv_sigma, 0.0, 0.0, inv_sigma
        # d(xd, yd) / d(k1, k2, p1, p2) (the Brown coefficients k1 k2 k3 p1 p2 but k3), then through
        # [[fx, s], [0, fy]]
        dx, dy = brown_coefficient_jacobian(xn, yn)
        dx0, dy0 = dx[0], dy[0]
        dx1, dy1 = dx[1], dy[1]
        dx2, dy2 = dx[3], dy[3]
        dx3, dy3 = dx[4], dy[4]
        C[0, 5], C[1, 5] = (fx * dx0 + s * dy0) * inv_sigma, fy * dy0 * inv_sigma
        C[0, 6], C[1, 6] = (fx * dx1 + s * dy1) * inv_sigma, fy * dy1 * inv_sigma
        C[0, 7], C[1, 7] = (fx * dx2 + s * dy2) * inv_sigma, fy * dy2 * inv_sigma
        C[0, 8], C[1, 8] = (fx * dx3 + s * dy3) * inv_sigma, fy * dy3 * inv_sigma
    return True


@numba.njit(cache=True, inline="always")
def _huber(r, A, B, C, huber_k, with_cal):
    """Scale one ray's whitened residual and Jacobians by the square root of its Huber weight (huber_k > 0)."""
    x = np.sqrt(r[0] * r[0] + r[1] * r[1])
    if huber_k <= 0.0 or x <= huber_k:
        return
    s = np.sqrt(huber_k / x)
    r[0] *= s
    r[1] *= s
    for a in range(2):
        for p in range(6):
            A[a, p] *= s
        for p in range(3):
            B[a, p] *= s
        if with_cal:
            for p in range(9):
                C[a, p] *= s


@numba.njit(cache=True, inline="always")
def _inverse_sym3(V, Vi):
    """Inverse of a symmetric 3 x 3 matrix given by its upper triangle; False when (nearly) singular."""
    a, b, c, d, e, f = V[0, 0], V[0, 1], V[0, 2], V[1, 1], V[1, 2], V[2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * c00 + b * c01 + c * c02
    if not det > 1e-12 * a * d * f:
        return False
    Vi[0, 0], Vi[0, 1], Vi[0, 2] = c00 / det, c01 / det, c02 / det
    Vi[1, 1], Vi[1, 2], Vi[2, 2] = (a * f - c * c) / det, (b * c - a * e) / det, (a * d - b * b) / det
    Vi[1, 0], Vi[2, 0], Vi[2, 1] = Vi[0, 1], Vi[0, 2], Vi[1, 2]
    return True


class _Rays(NamedTuple):
    """The rays, point by point (``start``: each point's first ray), and their pairs (``ray_pairs``)."""

    xy: np.ndarray  # (K, 2) px
    obs_image: np.ndarray  # (K,)
    start: np.ndarray  # (M + 1,)
    pair_row: np.ndarray  # the point row of each pair's first ray
    pair_a: np.ndarray
    pair_b: np.ndarray
    pair_block: np.ndarray


class _Linearisation(NamedTuple):
    """Where the rays are linearised: orientations, points, calibration, weights, the points' own observations."""

    centre: np.ndarray
    R_cv: np.ndarray
    points: np.ndarray
    cal: np.ndarray
    inv_sigma: float
    with_cal: bool
    huber_k: float
    point_r: np.ndarray
    point_B: np.ndarray
    point_damping: float


class _ImageSums(NamedTuple):
    """The image blocks one run of points adds into (``Workspace`` U, S_pair, s, U_cal, s_cal, U_ic, one run's)."""

    U: np.ndarray
    S_pair: np.ndarray
    s: np.ndarray
    U_cal: np.ndarray
    s_cal: np.ndarray
    U_ic: np.ndarray


class _PointBlocks(NamedTuple):
    """What each point leaves for the back-substitution (``Workspace`` Vinv, bp, W, Z)."""

    Vinv: np.ndarray
    bp: np.ndarray
    W: np.ndarray
    Z: np.ndarray


@numba.njit(cache=True)
def _points_range(j0, j1, rays: _Rays, lin: _Linearisation, sums: _ImageSums, out: _PointBlocks):
    """``reduced_camera_system`` over the points ``j0 .. j1 - 1``: their rays' contributions added into ``U``,
    ``S_pair``, ``s``, ``U_cal``, ``s_cal``, ``U_ic`` (the upper triangle of ``U``), their own ``Vinv``, ``bp``,
    ``W``, ``Z`` written; returns (their part of ``f``, of ``r'r``)."""
    xy, obs_image, start, pair_row, pair_a, pair_b, pair_block = rays
    centre, R_cv, points, cal, inv_sigma, with_cal, huber_k, point_r, point_B, point_damping = lin
    U, S_pair, s, U_cal, s_cal, U_ic = sums
    Vinv, bp, W, Z = out
    m_max = 1
    for j in range(j0, j1):
        m_max = max(m_max, start[j + 1] - start[j])
    A = np.empty((m_max, 2, 6))  # this point's rays
    B = np.empty((m_max, 2, 3))
    r = np.empty((m_max, 2))
    front = np.empty(m_max, dtype=np.bool_)
    Cr = np.zeros((m_max, 2, 9))
    VZ = np.empty((3, 9))
    VW = np.zeros((m_max, 3, 6))  # V^-1 W_k' of this point's rays
    n_pairs = len(pair_a)
    # the next pair: pairs are sorted by their first ray, so a point's pairs are consecutive
    nxt = np.searchsorted(pair_row, j0)
    model = (cal, inv_sigma, with_cal)
    rr = 0.0
    f = 0.0
    V = np.empty((3, 3))
    Vi = np.empty((3, 3))
    vb = np.empty(3)
    for j in range(j0, j1):
        # ``Vinv``, ``bp``, ``W``, ``Z`` may hold the previous linearisation's values (``Workspace``): every entry of
        # this point's is written here, zeros where nothing is added (behind the camera, a singular point)
        V[:] = 0.0
        bp[j, :] = 0.0
        if with_cal:
            Z[j, :, :] = 0.0
        k0 = start[j]
        for k in range(k0, start[j + 1]):
            i, n = obs_image[k], k - k0
            front[n] = _ray(xy[k], (centre[i], R_cv[i]), points[j], model, (r[n], A[n], B[n], Cr[n]))
            if not front[n]:
                W[k, :, :] = 0.0
                continue
            _huber(r[n], A[n], B[n], Cr[n], huber_k, with_cal)
            rr += r[n, 0] * r[n, 0] + r[n, 1] * r[n, 1]
            for p in range(3):
                bp[j, p] += B[n, 0, p] * r[n, 0] + B[n, 1, p] * r[n, 1]
                for q in range(p, 3):
                    V[p, q] += B[n, 0, p] * B[n, 0, q] + B[n, 1, p] * B[n, 1, q]
        rp = point_r[j]
        if rp != 0.0 or point_B[j, 0] != 0.0 or point_B[j, 1] != 0.0 or point_B[j, 2] != 0.0:
            rr += rp * rp
            for p in range(3):
                bp[j, p] += point_B[j, p] * rp
                for q in range(p, 3):
                    V[p, q] += point_B[j, p] * point_B[j, q]
        if point_damping > 0.0:
            for p in range(3):
                V[p, p] *= 1.0 + point_damping
        while nxt < n_pairs and pair_row[nxt] < j:  # the pairs of points before (singular ones)
            nxt += 1
        if not _inverse_sym3(V, Vi):
            # an indeterminate point contributes nothing (its rays stay in the cost, constant)
            Vinv[j, :, :] = 0.0
            for k in range(k0, start[j + 1]):
                W[k, :, :] = 0.0
            continue
        for k in range(k0, start[j + 1]):
            i, n = obs_image[k], k - k0
            if not front[n]:
                continue
            An, Bn, rn = A[n], B[n], r[n]
            for p in range(6):
                s[i, p] += An[0, p] * rn[0] + An[1, p] * rn[1]
                for q in range(p, 6):
                    U[i, p, q] += An[0, p] * An[0, q] + An[1, p] * An[1, q]
                for q in range(3):
                    W[k, p, q] = An[0, p] * Bn[0, q] + An[1, p] * Bn[1, q]
            if with_cal:
                Cn = Cr[n]
                for p in range(9):
                    s_cal[p] += Cn[0, p] * rn[0] + Cn[1, p] * rn[1]
                    for q in range(9):
                        U_cal[p, q] += Cn[0, p] * Cn[0, q] + Cn[1, p] * Cn[1, q]
                    for q in range(3):
                        Z[j, p, q] += Cn[0, p] * Bn[0, q] + Cn[1, p] * Bn[1, q]
                for p in range(6):
                    for q in range(9):
                        U_ic[i, p, q] += An[0, p] * Cn[0, q] + An[1, p] * Cn[1, q]
        Vinv[j] = Vi
        for p in range(3):
            vb[p] = Vi[p, 0] * bp[j, 0] + Vi[p, 1] * bp[j, 1] + Vi[p, 2] * bp[j, 2]
        f -= bp[j, 0] * vb[0] + bp[j, 1] * vb[1] + bp[j, 2] * vb[2]
        if with_cal:
            Zj = Z[j]
            for p in range(3):
                for q in range(9):
                    VZ[p, q] = Vi[p, 0] * Zj[q, 0] + Vi[p, 1] * Zj[q, 1] + Vi[p, 2] * Zj[q, 2]
            for p in range(9):
                s_cal[p] -= Zj[p, 0] * vb[0] + Zj[p, 1] * vb[1] + Zj[p, 2] * vb[2]
                for q in range(9):
                    U_cal[p, q] -= Zj[p, 0] * VZ[0, q] + Zj[p, 1] * VZ[1, q] + Zj[p, 2] * VZ[2, q]
        for k in range(start[j], start[j + 1]):
            i = obs_image[k]
            Wk, VWk = W[k], VW[k - k0]
            for p in range(3):
                for q in range(6):
                    VWk[p, q] = Vi[p, 0] * Wk[q, 0] + Vi[p, 1] * Wk[q, 1] + Vi[p, 2] * Wk[q, 2]
            # diagonal block and right-hand side of this ray's image
            for p in range(6):
                s[i, p] -= Wk[p, 0] * vb[0] + Wk[p, 1] * vb[1] + Wk[p, 2] * vb[2]
                for q in range(p, 6):
                    U[i, p, q] -= Wk[p, 0] * VWk[0, q] + Wk[p, 1] * VWk[1, q] + Wk[p, 2] * VWk[2, q]
                if with_cal:
                    for q in range(9):
                        U_ic[i, p, q] -= Wk[p, 0] * VZ[0, q] + Wk[p, 1] * VZ[1, q] + Wk[p, 2] * VZ[2, q]
        # the off-diagonal blocks, pair by pair of this point's rays
        while nxt < n_pairs and pair_row[nxt] == j:
            _pair_block(nxt, k0, rays, W, VW, sums)
            nxt += 1
    return f + rr, rr




def reduced_camera_system(xy, obs_image, row, start, pair_a, pair_b, *, pair_block, n_blocks, n_images, centre, R_cv,
                          points, cal, inv_sigma, with_cal, huber_k, point_r, point_B, point_damping,
                          work: Workspace | None = None):
    """Linearise the tie-point rays at (orientations, points) and eliminate the points.

    Returns the reduced system ``S`` as diagonal blocks ``U`` (N, 6, 6) and pair blocks ``S_pair``
    (n_blocks, 6, 6) (image i < j of each pair), its right-hand side ``s`` (N, 6), the reduced constant
    ``f = r'r - b_point' V^-1 b_point``, the sum of squared whitened residuals ``r'r``, and what the
    back-substitution needs: ``V^-1`` (M, 3, 3), ``b_point`` (M, 3), ``W`` (K, 6, 3). Rays behind their
    camera contribute nothing; a point whose normal matrix is singular stays where it is (``V^-1`` zero)
    and adds only its residuals (a constant) to the cost.

    ``huber_k`` > 0: each ray weighted by Huber's kernel (iteratively reweighted least squares).

    ``point_r`` (M,), ``point_B`` (M, 3): one more whitened observation per point that involves the point
    alone (a surface height, ``aerotri.adjust.surface``; zeros for none), added to its normal block
    before the elimination.

    ``point_damping`` (Levenberg-Marquardt's lambda, 0 for Gauss-Newton): each point's normal block gets
    ``lambda diag(V_j)`` before the elimination, so that a damped step also damps the points' back-substitution
    (a surface observation makes the points' own problem nonlinear).

    ``work``: the arrays of a previous call on the same rays (``Workspace``), overwritten and returned again: the
    caller must be done with that call's results (a linearisation replaces the last one). Fresh arrays of a
    large block cost their page faults on every linearisation (W alone is 144 bytes per ray: 0.9 GB at 6.5 M rays).

    With ``with_cal`` the calibration (Cal3DS2, 9 parameters shared by all rays) is an unknown too: its
    block ``U_cal`` (9, 9), right-hand side ``s_cal`` (9,), the couplings ``U_image_cal`` (N, 6, 9) and,
    for the back-substitution, ``Z`` (M, 9, 3) = sum over each point's rays of C_k'B_k (else empty).

    Blocks of ``PARALLEL_MIN_RAYS`` rays or more: the points are taken in ``PARTS`` runs of about equal numbers of
    rays, in parallel, each summed into its own copy of the image blocks, the copies added in a fixed order (the
    result does not depend on the number of threads); smaller blocks in one run, serially (no thread start-up).
    """
    parallel = len(row) >= PARALLEL_MIN_RAYS
    parts = PARTS if parallel else 1
    K, M = len(row), len(start) - 1
    if work is None or not work.fits(parts, K, M, n_images, n_blocks, with_cal):
        work = Workspace.for_rays(K, M, n_images, n_blocks, with_cal)
    U, S_pair, s, U_cal, s_cal, U_ic = work.U, work.S_pair, work.s, work.U_cal, work.s_cal, work.U_ic
    for a in (U, S_pair, s, U_cal, s_cal, U_ic):  # sums (image blocks: a few MB); the per-point arrays are overwritten
        a.fill(0.0)
    Vinv, bp, W, Z = work.Vinv, work.bp, work.W, work.Z
    if work.pair_row is None:
        work.pair_row = np.asarray(row)[pair_a].astype(np.int64)
    pair_row = work.pair_row
    bounds = np.minimum(M, np.searchsorted(start, (K * np.arange(parts + 1)) // parts)).astype(np.int64)
    bounds[parts] = M
    f_part, rr_part = (_runs_parallel if parallel else _runs_serial)(
        bounds, _Rays(xy, obs_image, start, pair_row, pair_a, pair_b, pair_block),
        _Linearisation(centre, R_cv, points, cal, inv_sigma, with_cal, huber_k, point_r, point_B, point_damping),
        _ImageSums(U, S_pair, s, U_cal, s_cal, U_ic), _PointBlocks(Vinv, bp, W, Z))
    for t in range(1, parts):  # in a fixed order
        U[0] += U[t]
        S_pair[0] += S_pair[t]
        s[0] += s[t]
        U_cal[0] += U_cal[t]
        s_cal[0] += s_cal[t]
        U_ic[0] += U_ic[t]
    Ut = U[0]
    iu = np.triu_indices(6, 1)
    Ut[:, iu[1], iu[0]] = Ut[:, iu[0], iu[1]]  # the lower triangle from the upper
    f = rr = 0.0
    for t in range(parts):
        f += f_part[t]
        rr += rr_part[t]
    return Ut, S_pair[0], s[0], f, rr, Vinv, bp, W, U_cal[0], s_cal[0], U_ic[0], Z


def _runs(bounds, rays: _Rays, lin: _Linearisation, sums: _ImageSums, out: _PointBlocks):
    """``_points_range`` over the runs of points ``bounds[t] .. bounds[t + 1] - 1``, each into its own copies of
    the image blocks (``sums``: one per run along the first axis); returns each run's part of ``f`` and ``r'r``."""
    parts = len(bounds) - 1
    f_part, rr_part = np.zeros(parts), np.zeros(parts)
    for t in numba.prange(parts):
        f_part[t], rr_part[t] = _points_range(
            bounds[t], bounds[t + 1], rays, lin,
            _ImageSums(sums.U[t], sums.S_pair[t], sums.s[t], sums.U_cal[t], sums.s_cal[t], sums.U_ic[t]), out)
    return f_part, rr_part


def _variant(func, suffix: str):
    """A copy of ``func`` under its own name: numba's cache keeps one compilation per function name (and source
    line), so the serial and the parallel compilation of one body each need a name to be cached under (the
    parallel ones, compiled in every process, took 30 s of CPU of each large adjustment)."""
    copy = types.FunctionType(func.__code__, func.__globals__, f"{func.__name__}{suffix}", func.__defaults__,
                              func.__closure__)
    copy.__qualname__ = f"{func.__qualname__}{suffix}"
    copy.__doc__, copy.__module__ = func.__doc__, func.__module__
    return copy


_runs_serial = numba.njit(cache=True)(_runs)
_runs_parallel = numba.njit(parallel=True, cache=True)(_variant(_runs, "_parallel"))


@numba.njit(cache=True, inline="always")
def _pair_block(n, k0, rays, W, VW, sums):
    """The coupling ``- W_a V^-1 W_b'`` of the rays of pair ``n`` (of ``rays``, ``_Rays``; of one point, its first
    ray ``k0``) into their images' pair block, or into the image's own block when both rays are in one image
    (``sums``: ``_ImageSums`` S_pair and U)."""
    pair_a, pair_b, pair_block, obs_image = rays.pair_a, rays.pair_b, rays.pair_block, rays.obs_image
    S_pair, U = sums.S_pair, sums.U
    ka, kb = pair_a[n], pair_b[n]
    Wa, VWb = W[ka], VW[kb - k0]
    blk = pair_block[n]
    if blk >= 0:
        for p in range(6):
            for q in range(6):
                S_pair[blk, p, q] -= Wa[p, 0] * VWb[0, q] + Wa[p, 1] * VWb[1, q] + Wa[p, 2] * VWb[2, q]
    else:  # both rays in one image: W_a V^-1 W_b' + its transpose on the diagonal block
        i = obs_image[ka]
        for p in range(6):
            for q in range(6):
                v = Wa[p, 0] * VWb[0, q] + Wa[p, 1] * VWb[1, q] + Wa[p, 2] * VWb[2, q]
                if q >= p:
                    U[i, p, q] -= v
                if p >= q:
                    U[i, q, p] -= v


def _point_increments(blocks, obs_image, start, d_pose, d_cal):
    """Back-substitution: ``d_point_j = V_j^-1 (b_point_j - sum_k W_k' d_pose[image_k] - Z_j' d_cal)`` (M, 3)
    (``blocks``: ``_PointBlocks`` Vinv, bp, W, Z; ``Z`` empty without calibration unknowns); the points in
    parallel (each its own)."""
    Vinv, bp, W, Z = blocks
    M = len(start) - 1
    d = np.zeros((M, 3))
    for j in numba.prange(M):
        c = bp[j].copy()
        for k in range(start[j], start[j + 1]):
            dp = d_pose[obs_image[k]]
            for q in range(3):
                for p in range(6):
                    c[q] -= W[k, p, q] * dp[p]
        if len(Z):
            for q in range(3):
                for p in range(9):
                    c[q] -= Z[j, p, q] * d_cal[p]
        for q in range(3):
            d[j, q] = Vinv[j, q, 0] * c[0] + Vinv[j, q, 1] * c[1] + Vinv[j, q, 2] * c[2]
    return d


@numba.njit(cache=True)
def _ray_cost(k0, k1, rays, poses, points, weights):
    """The cost of ``_sum_of_squares`` over the rays ``k0 .. k1 - 1``, in order. A function of its own, not inlined
    into the parallel loop: numba's array analysis of a parallel loop fails on ``_ray``'s tuple of arrays."""
    xy, obs_image, row = rays
    centre, R_cv = poses
    cal, inv_sigma, huber_k = weights
    model = (cal, inv_sigma, False)
    r = np.empty(2)
    out = (r, np.empty((2, 6)), np.empty((2, 3)), np.empty((2, 9)))
    total = 0.0
    for k in range(k0, k1):
        i = obs_image[k]
        if not _ray(xy[k], (centre[i], R_cv[i]), points[row[k]], model, out):
            return np.inf
        x2 = r[0] * r[0] + r[1] * r[1]
        if huber_k > 0.0 and x2 > huber_k * huber_k:
            total += 2.0 * huber_k * np.sqrt(x2) - huber_k * huber_k
        else:
            total += x2
    return total


def _sum_of_squares(rays, poses, points, weights, parts):
    """Sum of the squared whitened residuals of the ``rays`` (xy, obs_image, row: pixel, image, point row) at the
    ``poses`` (centre, R_cv) and ``points`` (behind the camera: infinite); ``weights``: (cal, inv_sigma, huber_k),
    ``huber_k`` > 0: twice Huber's robust cost instead (``x^2`` per ray up to ``k``, ``2 k x - k^2`` beyond). The
    rays in ``PARTS`` runs (in parallel when compiled so), their sums added in order (the result does not depend
    on the number of threads)."""
    K = len(rays[2])
    part = np.zeros(parts)
    for t in numba.prange(parts):
        part[t] = _ray_cost((K * t) // parts, (K * (t + 1)) // parts, rays, poses, points, weights)
    total = 0.0
    for t in range(parts):
        total += part[t]
    return total


_point_increments_serial = numba.njit(cache=True)(_point_increments)
_point_increments_parallel = numba.njit(parallel=True, cache=True)(_variant(_point_increments, "_parallel"))
_sum_of_squares_serial = numba.njit(cache=True)(_sum_of_squares)
_sum_of_squares_parallel = numba.njit(parallel=True, cache=True)(_variant(_sum_of_squares, "_parallel"))


def point_increments(Vinv, bp, W, Z, obs_image, start, *, d_pose, d_cal):
    """``_point_increments``, in parallel for blocks of ``PARALLEL_MIN_RAYS`` rays or more."""
    f = _point_increments_parallel if len(obs_image) >= PARALLEL_MIN_RAYS else _point_increments_serial
    return f(_PointBlocks(Vinv, bp, W, Z), obs_image, start, d_pose, np.require(d_cal, float, "CW"))  # one signature


def sum_of_squares(xy, obs_image, row, centre, R_cv, points, *, cal, inv_sigma, huber_k):
    """``_sum_of_squares``: blocks of ``PARALLEL_MIN_RAYS`` rays or more in ``PARTS`` runs in parallel, smaller ones
    in one."""
    if len(row) >= PARALLEL_MIN_RAYS:
        return _sum_of_squares_parallel((xy, obs_image, row), (centre, R_cv), points, (cal, inv_sigma, huber_k),
                                        PARTS)
    return _sum_of_squares_serial((xy, obs_image, row), (centre, R_cv), points, (cal, inv_sigma, huber_k), 1)


def hessian_factors(keys, rs: ReducedSystem, pair_images, cal_key=None) -> gtsam.GaussianFactorGraph:
    """The reduced camera system as gtsam HessianFactors: one per image (diagonal block, right-hand side,
    the constant on the first) and one per image pair (the off-diagonal block); with ``cal_key`` one for
    the calibration and one per image for its coupling to the calibration. The error of their sum at a
    zero increment is ``f / 2``, gtsam's convention ``(f - 2 d'g + d'G d) / 2``."""
    gfg = gtsam.GaussianFactorGraph()
    z6, zg = np.zeros((6, 6)), np.zeros(6)
    for i, key in enumerate(keys):
        gfg.push_back(gtsam.HessianFactor(key, rs.U[i], rs.s[i], rs.f if i == 0 else 0.0))
    for (i, j), blk in zip(pair_images.tolist(), rs.S_pair):
        gfg.push_back(gtsam.HessianFactor(keys[i], keys[j], z6, blk, zg, z6, zg, 0.0))
    if cal_key is not None:
        gfg.push_back(gtsam.HessianFactor(cal_key, rs.U_cal, rs.s_cal, 0.0))
        z9, zc = np.zeros((9, 9)), np.zeros(9)
        for key, blk in zip(keys, rs.U_image_cal):
            gfg.push_back(gtsam.HessianFactor(key, cal_key, z6, blk, zg, z9, zc, 0.0))
    return gfg
