"""A-posteriori covariances from the reduced camera system (Schur complement), without per-key calls.

The linearised normal equations are reduced by eliminating the object points (GTSAM partial
elimination; Schur-eliminated tie points arrive already reduced); the reduced system over
orientations, calibration and GNSS unknowns is small enough to invert densely. The covariance of an
object point then follows from its own normal-equation block ``V`` and its coupling ``W`` to the
orientations it is seen from:
``Cov(X) = V^-1 + V^-1 W Cov(orientations) W^T V^-1`` (exact for the linearised problem).
"""

from __future__ import annotations

import contextlib
import dataclasses

import gtsam
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from aerotri.adjust import graph as G
from aerotri.adjust.collinearity import jacobians_cv, point_normals, project_cv
from aerotri.adjust.keys import K_KEY, X
from aerotri.adjust.surface import whitened

_DIM = {"x": 6, "k": 9}


class _Joint:
    def __init__(self, cov, keys):
        self._cov, self._keys = cov, keys

    def at(self, ka, kb):
        return self._cov.block(ka, kb)


# OpenBLAS (0.3.30 in the scipy wheel, 0.3.31 in numpy's) crashes with a segmentation fault in its threaded
# Cholesky (potrf_parallel) once the matrix passes about 2 GB: n = 16,000 on this 2-core machine, a block
# of 2,700 images. Its single-threaded path does not (potrf + potri checked at n = 20,000 and 24,000).
_THREADED_LAPACK_MAX_BYTES = 1 << 30


def _inverse_spd(H: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite matrix by LAPACK potrf + potri (a quarter of the work of
    inverting the Cholesky factor and multiplying it out); ``H`` is overwritten where LAPACK can."""
    big = H.nbytes > _THREADED_LAPACK_MAX_BYTES
    a = H.T if H.flags.c_contiguous else H  # the same symmetric matrix in Fortran order: no copy for LAPACK
    with threadpool_limits(1, user_api="blas") if big else contextlib.nullcontext():
        c, info = scipy.linalg.lapack.dpotrf(a, lower=True, overwrite_a=True)
        if info != 0:
            raise np.linalg.LinAlgError(f"reduced normal matrix not positive definite (LAPACK dpotrf info {info})")
        inv, info = scipy.linalg.lapack.dpotri(c, lower=True, overwrite_c=True)
        if info != 0:
            raise np.linalg.LinAlgError(f"reduced normal matrix singular (LAPACK dpotri info {info})")
    # potri fills the lower triangle only: mirror it block by block (an index array of the whole upper
    # triangle would take twice the matrix's memory)
    n, b = len(inv), 2048
    for i in range(0, n, b):
        inv[i:i + b, i:i + b] = np.tril(inv[i:i + b, i:i + b]) + np.tril(inv[i:i + b, i:i + b], -1).T
        inv[i:i + b, i + b:] = inv[i + b:, i:i + b].T
    return inv


class ReducedCovariance:
    """Joint covariance (unit weight) of all variables except the object points."""

    def __init__(self, gr: "G.Graph", values: gtsam.Values, point_keys):
        gfg = gr.linearize(values)  # Schur-eliminated tie points arrive already reduced
        in_graph = set(gfg.keyVector())
        ordering = gtsam.Ordering()
        for k in point_keys:
            if k in in_graph:
                ordering.push_back(k)
        _, reduced = gfg.eliminatePartialMultifrontal(ordering)
        keys = sorted(set(reduced.keyVector()))
        order = gtsam.Ordering()
        for k in keys:
            order.push_back(k)
        H, _ = reduced.hessian(order)
        dims = [_DIM.get(chr(gtsam.Symbol(k).chr()), 3) for k in keys]
        self.offset = dict(zip(keys, np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int)))
        self.dim = dict(zip(keys, dims))
        # Jacobi scaling first: tight priors (fixed calibration terms) and metre/radian units differ by
        # many orders of magnitude, which alone would make the Cholesky factorisation fail
        d = 1.0 / np.sqrt(np.diag(H))
        H *= d[:, None]
        H *= d[None, :]
        self.Sigma = _inverse_spd(H)
        self.Sigma *= d[:, None]
        self.Sigma *= d[None, :]

    def block(self, ka, kb) -> np.ndarray:
        a, b = self.offset[ka], self.offset[kb]
        return self.Sigma[a : a + self.dim[ka], b : b + self.dim[kb]]

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 (gtsam.Marginals interface)
        return self.block(key, key)

    def jointMarginalCovariance(self, keys) -> _Joint:  # noqa: N802
        return _Joint(self, keys)


@dataclasses.dataclass
class PointRays:
    """The active rays' linearisation around the points, for the points' covariances: point index ``pt``
    and image ``im`` of each ray (K,), d pixel / d point ``Jp`` (K, 2, 3), d pixel / d orientation (and
    calibration) ``Jc`` (K, 2, 6 or 15), the points' normal blocks ``V`` (P, 3, 3, rays + control + surface,
    unit weight) and their inverses ``Vinv`` (NaN for unused points), ``G = V^-1 W`` per ray (K, 3, 6 or 15),
    ``idx`` the ray's orientation (and calibration) parameters in the reduced covariance (K, 6 or 15)."""

    pt: np.ndarray
    im: np.ndarray
    Jp: np.ndarray
    Jc: np.ndarray
    V: np.ndarray
    Vinv: np.ndarray
    used: np.ndarray
    G: np.ndarray
    idx: np.ndarray
    weight: float  # 1 / sigma_px^2


def point_rays(block: "G.Block", state: "G.State", obs_active, sigma_px: float, rc: ReducedCovariance,
               self_cal: bool) -> PointRays:
    """``PointRays`` of the active observations at ``state``."""
    k = np.flatnonzero(obs_active)
    pt, im = block.obs_point[k], block.obs_image[k]
    _, pc = project_cv(state.points[pt], state.centre[im], state.R_cv[im], state.cal)
    out = jacobians_cv(pc, state.R_cv[im], state.cal, with_cal=self_cal)
    Jp, Jc = out[0], out[1]
    if self_cal:
        Jc = np.concatenate([Jc, out[2]], axis=2)
    w = 1.0 / sigma_px**2
    V = w * point_normals(Jp, pt, block.n_points)
    for c, j in enumerate(block.control_point):
        if np.any(pt == j):
            V[j] += np.linalg.inv(block.control_cov_local[c])
    if block.surface is not None and block.surface_active is not None:
        # a surface observation (height above the DEM) joins its point's normal block, as in the solve
        _, B, _ = whitened(block.surface, state.points, block.surface_active)
        V += np.einsum("pi,pj->pij", B, B)
    used = np.zeros(block.n_points, dtype=bool)
    used[pt] = True
    Vinv = np.full_like(V, np.nan)
    Vinv[used] = np.linalg.inv(V[used])
    # G_k = V^-1 W_k for each ray (3 x 6 or 3 x 15)
    Gk = np.einsum("kij,kaj,kab->kib", Vinv[pt], Jp, Jc) * w
    pose_off = np.array([rc.offset[X(i)] for i in range(block.n_images)])
    idx = pose_off[im][:, None] + np.arange(6)[None]
    if self_cal:
        idx = np.concatenate([idx, np.broadcast_to(rc.offset[K_KEY] + np.arange(9), (len(k), 9))], axis=1)
    return PointRays(pt, im, Jp, Jc, V, Vinv, used, Gk, idx, w)


def point_covariances(block: "G.Block", state: "G.State", obs_active, sigma_px: float, rc: ReducedCovariance,
                      self_cal: bool, chunk: int = 100_000, rays: PointRays | None = None) -> np.ndarray:
    """Unit-weight covariances (P, 3, 3) of all object points in the local frame (NaN for unused); ``rays``:
    their ``point_rays`` when already at hand."""
    pr = rays if rays is not None else point_rays(block, state, obs_active, sigma_px, rc, self_cal)
    pt, Gk, idx, Vinv, used = pr.pt, pr.G, pr.idx, pr.Vinv, pr.used
    # all ray pairs (a, b) of the same point
    order = np.argsort(pt, kind="stable")
    pts_sorted = pt[order]
    starts = np.r_[0, np.flatnonzero(np.diff(pts_sorted)) + 1]
    counts = np.diff(np.r_[starts, len(order)])
    rep = np.repeat(counts, counts)  # per ray in sorted order: its point's ray count
    first = np.repeat(starts, counts)
    a_idx = np.repeat(np.arange(len(order)), rep)
    b_idx = np.repeat(first, rep) + (np.arange(len(a_idx)) - np.repeat(np.cumsum(rep) - rep, rep))
    extra = np.zeros((block.n_points, 3, 3))
    for s in range(0, len(a_idx), chunk):
        a = order[a_idx[s : s + chunk]]
        b = order[b_idx[s : s + chunk]]
        S = rc.Sigma[idx[a][:, :, None], idx[b][:, None, :]]
        np.add.at(extra, pt[a], np.einsum("kia,kab,kjb->kij", Gk[a], S, Gk[b]))
    cov = Vinv + extra
    cov[~used] = np.nan
    return cov
