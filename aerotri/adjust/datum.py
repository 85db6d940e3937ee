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

    Least squares over rotation vector, translation and log-scale about the points' centroid by
    Levenberg-Marquardt, started from the identity and from the unweighted closed form (Umeyama); the
    lower cost wins."""
    P = np.asarray(points_m, dtype=float)
    P0 = np.asarray(given_m, dtype=float)
    W = np.linalg.inv(np.linalg.cholesky(np.asarray(cov_m2, dtype=float)))  # whitening, lower triangular
    c = P.mean(axis=0)

    def sim(x):
        return Similarity(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:6], float(np.exp(x[6])), c)

    def residual(x):
        return np.einsum("kij,kj->ki", W, sim(x).apply(P) - P0).ravel()

    s, R, t = umeyama(P, P0)
    starts = [np.zeros(7)]
    if s > 0:  # X' = s R (X - c) + c + (s R c + t - c)
        starts.append(np.r_[Rotation.from_matrix(R).as_rotvec(), s * R @ c + t - c, np.log(s)])
    import scipy.optimize  # here: 0.2 s of every adjustment's start for a block without GNSS's datum

    fits = [scipy.optimize.least_squares(residual, x0, method="lm", x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14)
            for x0 in starts]
    best = min(fits, key=lambda f: f.cost)
    r0 = residual(np.zeros(7))
    return SimilarityFit(sim(best.x), 0.5 * float(r0 @ r0), 0.5 * float(best.fun @ best.fun))
