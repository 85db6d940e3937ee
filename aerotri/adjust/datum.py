"""The datum step: the whole block moved by a 3D similarity transformation onto its control points.

A similarity of object space (rotation ``R``, translation ``t``, scale ``m`` about a centre ``c``:
``X' = m R (X - c) + c + t``) applied to every projection centre, object point and camera attitude
(``R_cv' = R R_cv``) leaves every image residual unchanged. Without GNSS only the control points fix
these 7 parameters, and with loose control heights (targets whose height is unknown) the block's tilt is
held only weakly: the reduced normal matrix is nearly singular along it, and because a rotation is not
linear in the unknowns, Gauss-Newton and Levenberg-Marquardt creep along that mode (linear convergence,
~0.95 per iteration on the Coal Oil Point kite block). The datum step minimises the control points' prior
cost over the 7 parameters exactly, by themselves, after each step of the bundle; the image rays do not
change, so the bundle cost falls by exactly the control cost's fall.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation


@dataclasses.dataclass
class Similarity:
    """``X' = scale R (X - centre) + centre + t`` (local frame, metres)."""

    R: np.ndarray  # (3, 3)
    t_m: np.ndarray  # (3,)
    scale: float
    centre_m: np.ndarray  # (3,)

    def apply(self, points_m: np.ndarray) -> np.ndarray:
        """Transform points (..., 3)."""
        return self.scale * (np.asarray(points_m) - self.centre_m) @ self.R.T + self.centre_m + self.t_m

    def rotate(self, R_cv: np.ndarray) -> np.ndarray:
        """Transform camera attitudes (..., 3, 3) (camera -> local frame)."""
        return self.R @ np.asarray(R_cv)


@dataclasses.dataclass
class SimilarityFit:
    similarity: Similarity
    cost_before: float  # 1/2 sum of squared whitened discrepancies at the identity
    cost_after: float  # ... after the transformation


def umeyama(src, dst):
    """Similarity ``dst ~ s R src + t`` in the unweighted least-squares sense (Umeyama 1991; 2D or 3D):
    (s, R, t)."""
    ms, md = src.mean(0), dst.mean(0)
    A, B = src - ms, dst - md
    U, S, Vt = np.linalg.svd(B.T @ A / len(src))
    D = np.eye(len(ms))
    D[-1, -1] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / A.var(0).sum()
    return s, R, md - s * R @ ms


def fit_similarity(points_m: np.ndarray, given_m: np.ndarray, cov_m2: np.ndarray) -> SimilarityFit:
    """The similarity that moves ``points_m`` (n >= 3, 3) closest to ``given_m`` (n, 3) in the metric of
    the given coordinates' covariances ``cov_m2`` (n, 3, 3) (anisotropic: loose heights weigh little).

    Least squares over rotation, translation and log-scale about the points' centroid by Levenberg-Marquardt
    with the closed-form Jacobian (the rotation updated on the left, ``R <- exp([d]x) R``), started from the
    identity and from the unweighted closed form (Umeyama); the lower cost wins."""
    P = np.asarray(points_m, dtype=float)
    P0 = np.asarray(given_m, dtype=float)
    W = np.linalg.inv(np.linalg.cholesky(np.asarray(cov_m2, dtype=float)))  # whitening, lower triangular
    c = P.mean(axis=0)
    identity = Similarity(np.eye(3), np.zeros(3), 1.0, c)
    starts = [identity]
    s, R, t = umeyama(P, P0)
    if s > 0:  # X' = s R (X - c) + c + (s R c + t - c)
        starts.append(Similarity(R, s * R @ c + t - c, float(s), c))
    best = min((_levenberg_marquardt(P, P0, W, x) for x in starts), key=lambda f: f[1])
    r0 = _whitened(identity, P, P0, W)
    return SimilarityFit(best[0], 0.5 * float(r0 @ r0), best[1])


def _whitened(sim: Similarity, P: np.ndarray, P0: np.ndarray, W: np.ndarray) -> np.ndarray:
    return np.einsum("kij,kj->ki", W, sim.apply(P) - P0).ravel()


def _levenberg_marquardt(P, P0, W, sim: Similarity, max_iterations: int = 200) -> tuple[Similarity, float]:
    """(the similarity, half its sum of squared whitened residuals) from ``sim`` on. Unknowns: a small rotation
    ``d`` (rad) applied on the left, the translation (m) and the log-scale; the moved point ``u = s R (X - c)``
    changes by ``d x u``, ``dt`` and ``u dlog(s)``."""
    r = _whitened(sim, P, P0, W)
    cost, lam = 0.5 * float(r @ r), 1e-3
    for _ in range(max_iterations):
        u = sim.scale * (P - sim.centre_m) @ sim.R.T
        d_u = np.zeros((len(P), 3, 7))
        d_u[:, :, :3] = -_skew(u)  # d (exp([d]x) u) / dd at 0 = -[u]x
        d_u[:, :, 3:6] = np.eye(3)
        d_u[:, :, 6] = u
        J = np.einsum("kij,kjl->kil", W, d_u).reshape(-1, 7)
        N, g = J.T @ J, J.T @ r
        while True:
            step = np.linalg.solve(N + lam * np.diag(np.diag(N)), -g)
            trial = Similarity(Rotation.from_rotvec(step[:3]).as_matrix() @ sim.R, sim.t_m + step[3:6],
                               sim.scale * float(np.exp(step[6])), sim.centre_m)
            r_trial = _whitened(trial, P, P0, W)
            cost_trial = 0.5 * float(r_trial @ r_trial)
            if cost_trial <= cost or lam > 1e12:
                break
            lam *= 10.0
        if cost_trial > cost:
            break
        done = cost - cost_trial <= 1e-15 * max(cost, 1e-300) or np.abs(step).max() < 1e-15
        sim, r, cost, lam = trial, r_trial, cost_trial, max(lam / 10.0, 1e-12)
        if done:
            break
    return sim, cost


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 3) with ``_skew(a) @ b = a x b``."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out
