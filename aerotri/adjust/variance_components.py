"""Variance components of the observation groups: image rays, GNSS positions, control points, surface heights.

For a group ``k`` with a-priori weights ``P_k`` (its stated sigmas) the estimated variance factor is
(Förstner 1979; Koch, *Parameter Estimation*, 3.6)

    s_k^2 = v_k' P_k v_k / r_k,      r_k = n_k - tr(P_k A_k Q_xx A_k')

with ``r_k`` the group's share of the redundancy (its partial redundancies summed; over all groups they add
up to the degrees of freedom). ``s_k`` = 1 when the group's stated sigmas fit its residuals; ``s_k`` = 2 says
its sigmas were half what the data show. Reweighting each group by ``s_k^2`` and solving again
(``solve.adjust_block(variance_components=True)``) iterates to the estimate.

``Q_xx`` comes from the reduced covariance of orientations, GNSS corrections and calibration
(``covariance.ReducedCovariance``) and the points' covariances (``covariance.point_covariances``), both of
unit weight. The image group's redundancy is the remainder: the degrees of freedom less the others'.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.keys import A, D, S, X
from aerotri.geom.rotation import FLIP_YZ

GROUPS = ("image", "gnss", "control", "surface")
MIN_REDUNDANCY = 5.0  # below this a group's factor is too uncertain (about 1/sqrt(2 r): 32 %) to reweight by


@dataclasses.dataclass
class VarianceComponent:
    group: str  # one of GROUPS
    n: int  # observation equations (coordinates)
    redundancy: float  # r_k
    sum_squares: float  # v' P v with the weights used in the solve
    factor: float | None  # s_k = sqrt(v' P v / r_k); None when r_k < MIN_REDUNDANCY (not estimable)


def antenna_positions(block: G.Block, state: G.State) -> np.ndarray:
    """The antenna positions of the adjusted photos (N, 3, local frame): ``C + R l``, no GNSS shift or drift."""
    return state.centre + state.R_cv @ (FLIP_YZ @ block.lever_arm_m)


def adjusted_gnss(block: G.Block, opts: G.SolveSettings, state: G.State) -> np.ndarray:
    """The GNSS positions the solution predicts (N, 3, local frame): ``antenna_positions``, plus the strip's
    shift (the flight's one offset; and drift times the along-track km) when the solve corrects them."""
    pred = antenna_positions(block, state)
    if opts.gnss_correction == "none":
        return pred
    s, t = G.shift_index(block, opts.gnss_correction), np.asarray(block.along_km, dtype=float)
    return pred + state.shift[s] + (t[:, None] * state.drift[s] if opts.gnss_correction == "shift_drift" else 0.0)


def gnss_rows(block: G.Block, opts: G.SolveSettings, state: G.State) -> tuple[np.ndarray, list]:
    """The adjusted GNSS positions (``adjusted_gnss``) and, per image, their Jacobian as ``[(key, J), ...]``
    (J: 3 x the key's dimension): ``g = C + R l`` (no correction; pose tangent [omega, v], right perturbation:
    d g / d omega = -R [l]x, d g / d v = R) or ``g = a + s + t d`` (per-strip shift/drift)."""
    pred = adjusted_gnss(block, opts, state)
    rows = []
    if opts.gnss_correction == "none":
        lever_cv = FLIP_YZ @ block.lever_arm_m
        lx = np.array([[0, -lever_cv[2], lever_cv[1]], [lever_cv[2], 0, -lever_cv[0]], [-lever_cv[1], lever_cv[0], 0]])
        for i in range(block.n_images):
            rows.append([(X(i), np.hstack([-state.R_cv[i] @ lx, state.R_cv[i]]))])
        return pred, rows
    drift = opts.gnss_correction == "shift_drift"
    s, t = G.shift_index(block, opts.gnss_correction), np.asarray(block.along_km, dtype=float)
    eye = np.eye(3)
    for i in range(block.n_images):
        rows.append([(A(i), eye), (S(s[i]), eye)] + ([(D(s[i]), t[i] * eye)] if drift else []))
    return pred, rows


def _position_covariances(rows: list, rc) -> np.ndarray:
    """(N, 3, 3) unit-weight covariance ``J Sigma J'`` of each adjusted GNSS position from its keys' joint block of
    ``rc`` (``gnss_rows``' Jacobians), all images in one gather."""
    idx = np.array([np.concatenate([rc.offset[k] + np.arange(J.shape[1]) for k, J in row]) for row in rows])
    J = np.array([np.hstack([Jk for _, Jk in row]) for row in rows])  # (N, 3, unknowns of a row)
    return J @ rc.entries(idx[:, :, None], idx[:, None, :]) @ J.transpose(0, 2, 1)


def gnss_w_statistics(block: G.Block, opts: G.SolveSettings, state: G.State, rc) -> np.ndarray | None:
    """(N,) Baarda's w of each GNSS position, the largest of its axes: the residual over its sigma times the square
    root of its partial redundancy, ``|e| / (sigma sqrt(1 - w cov))`` with the unit-weight covariance ``rc`` of the
    solution (0 for a position left out or of no redundancy); None without GNSS or covariances. A frame that takes a
    position's error up shows a small residual of small redundancy: a 2 m slip on a 1,000-frame block left 0.355 m
    (7.1 sigma, under the raw residuals' 8) at a redundancy of about 0.2 (trial s97 H1)."""
    if block.gnss_local is None or rc is None:
        return None
    pred, rows = gnss_rows(block, opts, state)
    e = block.gnss_local - pred
    w = 1.0 / block.gnss_sigma_m**2
    r = 1.0 - w * np.diagonal(_position_covariances(rows, rc), axis1=1, axis2=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        stat = np.abs(e) * np.sqrt(w) / np.sqrt(r)
    stat = np.where(np.isfinite(stat) & (r > 1e-6) & np.isfinite(w) & (w > 0), stat, 0.0)
    stat[~np.asarray(block.gnss_used, dtype=bool)] = 0.0
    return stat.max(axis=1)


def estimate(block: G.Block, opts: G.SolveSettings, state: G.State, obs_active, control_active, rc, *, point_cov_unit,
             dof: int) -> list[VarianceComponent]:
    """The variance components of the groups present in the block at the solution ``state`` (final,
    non-robust weights). ``point_cov_unit``: (P, 3, 3) unit-weight point covariances; ``dof``: the solve's
    degrees of freedom."""
    out = []
    v = G.image_residuals(block, state)[obs_active] / opts.image_sigma_px
    n_image = 2 * int(obs_active.sum())
    others = 0.0
    if block.gnss_local is not None:
        pred, rows = gnss_rows(block, opts, state)
        e = block.gnss_local - pred
        w = 1.0 / block.gnss_sigma_m**2  # (N, 3)
        cov = _position_covariances(rows, rc)
        n_used = 3 * int(block.gnss_used.sum())  # a left-out position has weight 0 (graph.Block.gnss_used)
        r = float(n_used - np.einsum("ni,nii->", w, cov))
        out.append(_component("gnss", n_used, r, float(np.sum(e * e * w))))
        others += r
    ctrl = [c for c in np.flatnonzero(control_active) if np.isfinite(point_cov_unit[block.control_point[c]]).all()]
    if ctrl:
        r = ss = 0.0
        n = 0
        for c in ctrl:
            j = block.control_point[c]
            lam, E = np.linalg.eigh(block.control_cov_local[c])
            tight = lam < (G.LOOSE_SIGMA_M / 10) ** 2  # the constrained components (loose ones carry nothing)
            E, lam = E[:, tight], lam[tight]
            d = E.T @ (block.control_local[c] - state.points[j])
            q = np.einsum("ia,ij,ja->a", E, point_cov_unit[j], E)
            r += float(np.sum(1.0 - q / lam))
            ss += float(np.sum(d * d / lam))
            n += int(tight.sum())
        out.append(_component("control", n, r, ss))
        others += r
    if block.surface is not None and block.surface_active is not None:
        act = np.asarray(block.surface_active, dtype=bool) & np.isfinite(point_cov_unit).all(axis=(1, 2))
        if act.any():
            e, J, sigma = block.surface.of_points(np.flatnonzero(act)).observe(state.points[act])
            b = J / sigma[:, None]
            r = float(np.sum(1.0 - np.einsum("pi,pij,pj->p", b, point_cov_unit[act], b)))
            out.append(_component("surface", int(act.sum()), r, float(np.sum((e / sigma) ** 2))))
            others += r
    out.insert(0, _component("image", n_image, float(dof) - others, float(np.sum(v * v))))
    return out


def _component(group: str, n: int, r: float, ss: float) -> VarianceComponent:
    return VarianceComponent(group, n, r, ss, float(np.sqrt(ss / r)) if r >= MIN_REDUNDANCY else None)


def reweighted(block: G.Block, opts: G.SolveSettings,
               components: list[VarianceComponent]) -> tuple[G.Block, G.SolveSettings]:
    """The block and options with each estimable group's sigmas multiplied by its factor."""
    f = {c.group: c.factor for c in components if c.factor is not None}
    changes = {}
    if "gnss" in f:
        changes["gnss_sigma_m"] = block.gnss_sigma_m * f["gnss"]
    if "control" in f:
        changes["control_cov_local"] = block.control_cov_local * f["control"] ** 2
    if "surface" in f:
        changes["surface"] = dataclasses.replace(block.surface, sigma_factor=block.surface.sigma_factor * f["surface"])
    if "image" in f:
        opts = dataclasses.replace(opts, image_sigma_px=opts.image_sigma_px * f["image"])
    return dataclasses.replace(block, **changes), opts
