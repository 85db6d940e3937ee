"""Weak geometry: how well the block's shape modes are determined, and by which observations.

A block's tie points can move together in ways the image rays hardly see: all up or down (the height
datum; with fixed projection centres also the convergence of the images), tilted east or north, bent
(a dome). Each mode is a linear functional of the tie points' heights ``f = L h``: the coefficients of
the least-squares surface ``dh = a + b xi + c eta + d (xi^2 + eta^2 - mean)`` fitted to height changes,
with ``xi, eta`` the plan coordinates about the block centre over its radius ``rho`` (so ``b``, ``c``,
``d`` are height changes at the block's edge, metres).

Standard deviation: ``sigma_f^2 = l' Q l`` with ``Q`` the unit-weight covariance of all unknowns (the
points' own blocks and the reduced covariance of the orientations: ``covariance.point_rays``).
Which observations determine it: with ``u = Q l``, group ``k`` contributes ``u' H_k u / sigma_f^2`` of the
mode's information (``H_k`` its normal-equation share; the shares add up to one: ``u' H u = l' u``).
A mode held (almost) only by the GNSS positions or the a-priori values is a datum the images and the
ground control cannot check: the report names it and its standard deviation.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.covariance import PointRays, point_rays
from aerotri.adjust.surface import whitened
from aerotri.adjust.variance_components import gnss_rows

MODES = ("height", "tilt_east", "tilt_north", "bending")
PRIOR_SHARE = 0.9  # a mode this much determined by GNSS positions and priors is reported as held by them


@dataclasses.dataclass
class GeometryMode:
    mode: str  # one of MODES
    sigma_m: float  # a-posteriori standard deviation (x sigma0): the mean height, or the height change at the edge
    radius_m: float  # the block's radius rho (tilts in degrees: atan(sigma / rho))
    shares: dict  # group -> share of the mode's information (image, gnss, control, surface, priors)
    held_by_priors: bool  # GNSS and priors hold >= PRIOR_SHARE of it

    @property
    def sigma_deg(self) -> float:
        return float(np.degrees(np.arctan2(self.sigma_m, self.radius_m)))

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["sigma_deg"] = self.sigma_deg if self.mode.startswith("tilt") else None
        return d


def geometry_modes(block: G.Block, opts: G.SolveSettings, state: G.State, obs_active, control_active, rc,
                   sigma0: float, rays: PointRays | None = None) -> list[GeometryMode]:
    """The four modes of the tie points' heights (see the module docstring) at the solution ``state``;
    ``rc``: the reduced covariance (``covariance.ReducedCovariance``, unit weight); ``rays``: the points'
    ``covariance.point_rays`` when already at hand."""
    pr = rays if rays is not None else point_rays(block, state, obs_active, opts.image_sigma_px, rc,
                                                  bool(opts.self_calibration))
    tie = pr.used.copy()
    tie[block.control_point] = False
    j = np.flatnonzero(tie)
    if len(j) < 10:
        return []
    xy = state.points[j, :2]
    centre = xy.mean(axis=0)
    rho = float(np.max(np.linalg.norm(xy - centre, axis=1)))
    xi, eta = ((xy - centre) / rho).T
    r2 = xi**2 + eta**2
    M = np.column_stack([np.ones(len(j)), xi, eta, r2 - r2.mean()])
    L = np.zeros((4, block.n_points))
    L[:, j] = np.linalg.pinv(M)  # (4, n_tie): the modes' coefficients from the heights (local up = z)
    # u = Q l: camera part u_c = -Sigma a, a = sum over rays of G_ray' l_point; point part u_p = V^-1 l - G u_c
    n = rc.n
    Gz = pr.G[:, 2, :]  # the height row of each ray's V^-1 W
    a = np.array([np.bincount(pr.idx.ravel(), (Gz * L[m, pr.pt][:, None]).ravel(), n) for m in range(4)])
    u_c = -rc.multiply(a.T).T  # (4, n)
    l_p = np.zeros((4, block.n_points, 3))
    l_p[:, :, 2] = L
    u_p = np.einsum("pij,mpj->mpi", np.nan_to_num(pr.Vinv), l_p)
    Gu = np.einsum("kij,mkj->mki", pr.G, u_c[:, pr.idx])
    for m in range(4):
        for i in range(3):
            u_p[m, :, i] -= np.bincount(pr.pt, Gu[m, :, i], block.n_points)
    var = np.einsum("mpi,mpi->m", l_p, u_p)
    # information shares
    share = {}
    d_ray = np.einsum("kai,mki->mka", pr.Jp, u_p[:, pr.pt]) + np.einsum("kaj,mkj->mka", pr.Jc, u_c[:, pr.idx])
    share["image"] = pr.weight * np.einsum("mka,mka->m", d_ray, d_ray)
    if block.gnss_local is not None:
        share["gnss"] = _gnss_information(block, opts, state, rc, u_c)
    ctrl = [c for c in np.flatnonzero(control_active) if pr.used[block.control_point[c]]]
    if ctrl:
        P = np.linalg.inv(block.control_cov_local[ctrl])
        uc = u_p[:, block.control_point[ctrl]]
        share["control"] = np.einsum("mci,cij,mcj->m", uc, P, uc)
    if block.surface is not None and block.surface_active is not None:
        _, B, _ = whitened(block.surface, state.points, block.surface_active)
        share["surface"] = np.sum(np.einsum("pi,mpi->mp", B, u_p) ** 2, axis=1)
    share = {k: v / var for k, v in share.items()}
    share["priors"] = 1.0 - sum(share.values())
    out = []
    for m, name in enumerate(MODES):
        sh = {k: float(v[m]) for k, v in share.items()}
        held = sh.get("gnss", 0.0) + max(sh["priors"], 0.0) >= PRIOR_SHARE
        out.append(GeometryMode(name, float(np.sqrt(var[m])) * sigma0, rho, sh, bool(held)))
    return out


def _gnss_information(block: G.Block, opts: G.SolveSettings, state: G.State, rc, u_c: np.ndarray) -> np.ndarray:
    """``u' H_gnss u`` per mode: the GNSS positions' weighted change under each mode's ``u``."""
    w = 1.0 / block.gnss_sigma_m**2
    out = np.zeros(len(u_c))
    for i, row in enumerate(gnss_rows(block, opts, state)[1]):
        dg = sum(u_c[:, rc.offset[k]:rc.offset[k] + J.shape[1]] @ J.T for k, J in row)
        out += np.sum(dg * dg * w[i], axis=1)
    return out
