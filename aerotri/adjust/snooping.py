"""Blunder detection: data snooping on standardised residuals (Baarda), after a robust (Huber) solution.

Standardised residual of an image coordinate: ``w = v / (sigma0 * sqrt(r))`` with the redundancy
number ``r`` (diagonal of Q_vv Q_ll^-1). ``r`` is computed per object point with the orientations held
fixed (``r = 1 - diag(A (A^T A)^-1 A^T)`` over the point's rays): orientations are determined by
hundreds of observations, so the point's own geometry dominates (a 2-ray point has r ~ 0 along the
epipolar line, where a blunder cannot be seen). ``sigma0`` is a robust a-posteriori estimate (MAD).
Each round removes at most the worst observation of each point whose ``|w|`` exceeds the critical
value (type I error ``alpha`` per coordinate), then the block is solved again.
"""

from __future__ import annotations

import numpy as np

from aerotri.adjust.check_points import ray_leverages, refined_normals
from aerotri.core.quantiles import norm_isf


def critical_value(alpha: float = 1e-4) -> float:
    """Two-sided normal quantile for a type I error ``alpha`` per coordinate (1e-4 -> 3.89)."""
    return float(norm_isf(alpha / 2.0))


def redundancy_numbers(obs_point, obs_image, points, centre, R_cv, cal, *, active, point_info=None) -> np.ndarray:
    """Redundancy numbers (K, 2) of image coordinates, orientations held fixed; NaN for inactive rows.
    ``point_info``: (P, 3, 3) the points' other observations (a surface height) as information in the rays' unit
    weight (the image sigma, px, squared times the information per m2): a point the
    DEM holds in height has parallaxes its rays alone would not check (trial-scale: without it a DEM-controlled
    block of 0 blunders lost 0.6 % of its rays, 605 of 104,425, to the test; 23 without the DEM)."""
    r = np.full((len(obs_point), 2), np.nan)
    k = np.flatnonzero(active)
    if len(k) == 0:
        return r
    # the rays' Jacobians in compiled code, ray by ray (numpy's (K, 2, 3) and (K, 3, 3) arrays: GBs at 6.5 M rays)
    _, N = refined_normals(np.zeros((len(k), 2)), obs_point[k], obs_image[k], centre, R_cv, cal, points=points,
                           iterations=0)
    if point_info is not None:
        N = N + point_info
    det_ok = np.abs(np.linalg.det(N)) > 0
    Ninv = np.zeros_like(N)
    Ninv[det_ok] = np.linalg.inv(N[det_ok])
    H = ray_leverages(obs_point[k], obs_image[k], centre, R_cv, cal, points, N_inv=Ninv)
    r[k] = np.clip(1.0 - H, 0.0, 1.0)
    return r


def robust_sigma0(v_px, r, active) -> float:
    """Robust a-posteriori standard deviation of unit weight in pixels (1.4826 MAD of v / sqrt(r))."""
    m = active[:, None] & (r > 0.05)
    z = (v_px / np.sqrt(np.where(r > 0, r, np.nan)))[m]
    return float(1.4826 * np.median(np.abs(z))) if len(z) else float("nan")


def standardised_residuals(v_px, r, sigma0_px) -> np.ndarray:
    """|w| per observation (K,): the larger of the two coordinates; 0 where r is ~0 (not testable)."""
    return np.max(coordinate_w(v_px, r, sigma0_px), axis=1)


def coordinate_w(v_px, r, sigma0_px) -> np.ndarray:
    """|w| per image coordinate (K, 2); 0 where r is ~0 (not testable)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.abs(v_px) / (sigma0_px * np.sqrt(r))
    return np.nan_to_num(np.where(r > 0.02, w, 0.0), nan=0.0)


def worst_per_point(w, obs_point, active, critical: float) -> np.ndarray:
    """Mask of observations to remove: the worst of each point, if above ``critical``."""
    cand = np.flatnonzero(active & (w > critical))
    if len(cand) == 0:
        return np.zeros(len(w), dtype=bool)
    order = cand[np.lexsort((-w[cand], obs_point[cand]))]
    first = np.r_[True, obs_point[order][1:] != obs_point[order][:-1]]
    out = np.zeros(len(w), dtype=bool)
    out[order[first]] = True
    return out


def w_correlations(flagged, obs_point, obs_image, points, centre, R_cv, cal, *, active,
                   point_info=None) -> np.ndarray:
    """(len(flagged), 2): per image coordinate of each flagged ray, the largest |correlation| between its test and
    the test of any coordinate of another active ray of the same point, orientations held fixed:
    ``rho = Q_vv[a, b] / sqrt(Q_vv[a, a] Q_vv[b, b])`` with ``Q_vv = I - A N^-1 A'`` over the point's rays (and
    its ``point_info``). Near one, a blunder in either ray gives both the same w (Foerstner's separability): that
    coordinate's test cannot tell which ray is wrong, e.g. the coordinate along the base in a 3-ray point of one
    strip, which has one redundancy in that direction (the one across it has two)."""
    from aerotri.adjust.check_points import _ray_point_jacobian

    out = np.zeros((len(flagged), 2))
    order = np.argsort(obs_point, kind="stable")
    starts = np.searchsorted(obs_point[order], np.arange(len(points) + 1))
    cal = np.asarray(cal, dtype=float)
    xy = np.zeros(2)
    for n, k in enumerate(flagged):
        p = obs_point[k]
        rays = order[starts[p]:starts[p + 1]]
        rays = rays[active[rays]]
        if len(rays) < 2:
            continue
        A = np.empty((2 * len(rays), 3))
        J = np.empty((2, 3))
        for i, ray in enumerate(rays):
            _ray_point_jacobian(xy, centre[obs_image[ray]], R_cv[obs_image[ray]], points[p], cal, J)
            A[2 * i:2 * i + 2] = J
        N = A.T @ A + (point_info[p] if point_info is not None else 0.0)
        try:
            Q = np.eye(len(A)) - A @ np.linalg.solve(N, A.T)
        except np.linalg.LinAlgError:
            continue
        i = int(np.flatnonzero(rays == k)[0])
        d = np.sqrt(np.clip(np.diag(Q), 1e-12, None))
        rho = np.abs(Q[2 * i:2 * i + 2]) / (d[2 * i:2 * i + 2, None] * d[None, :])
        rho[:, 2 * i:2 * i + 2] = 0.0
        out[n] = rho.max(axis=1)
    return out
