"""Weak geometry: how well the block's shape modes and its self-calibration are determined, and by which observations.

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

A functional may also take the orientations and the calibration (``l = (l_points, l_cameras)``):
``u_cameras = Sigma (l_cameras - W' V^-1 l_points)``, ``u_points = V^-1 l_points - V^-1 W u_cameras``
(``Sigma`` the reduced covariance). With self-calibration the calibration's own functionals (the mean
focal length, the principal point) and two more of the tie points (their mean east and north: the plan
datum) are formed too: their covariances with the modes are what ``determinability`` judges the
self-calibration by (the focal length against the block height, the principal point against the plan
datum), and the focal length, scaled to metres of height at the block's depth, is the ``focal_height``
mode of the report.
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.covariance import PointRays, point_rays
from aerotri.adjust.keys import K_KEY
from aerotri.adjust.surface import whitened
from aerotri.adjust.variance_components import gnss_rows

# displacement fields (x, y exponents of the image coordinates; component 0: x, 1: y) the camera model does not
# hold: the shear (a rolling shutter's line delay while the frame moves across it), the quadratic and the cubic
# terms beyond the radial distortion's (a lens or sensor's residual distortion, a film or sensor not flat)
UNMODELLED_FIELDS = tuple((c, a, b) for c in (0, 1) for a, b in ((0, 1), (1, 0), (2, 0), (1, 1), (0, 2), (3, 0),
                                                                 (2, 1), (1, 2), (0, 3)) if (c, a, b) not in
                          ((0, 1, 0), (1, 0, 1)))
MODES = ("height", "tilt_east", "tilt_north", "bending")
PLAN_MODES = ("shift_east", "shift_north")  # the tie points' mean plan position (with self-calibration only)
CAL_NAMES = ("fx_px", "fy_px", "skew_px", "u0_px", "v0_px", "k1", "k2", "p1", "p2")  # Cal3DS2 order
PRIOR_SHARE = 0.9  # a mode this much determined by GNSS positions and priors is reported as held by them


@dataclasses.dataclass
class GeometryMode:
    mode: str  # one of MODES, or "focal_height"
    sigma_m: float  # a-posteriori standard deviation (x sigma0): the mean height, or the height change at the edge
    radius_m: float  # the block's radius rho (tilts in degrees: atan(sigma / rho))
    shares: dict  # group -> share of the mode's information (image, gnss, control, surface, priors)
    held_by_priors: bool  # GNSS and priors hold >= PRIOR_SHARE of it
    correlation_with_height: float | None = None  # focal_height: the focal length's correlation with the block height
    note: str | None = None  # e.g. that the mode comes from an earlier solve (the focal length fixed since)

    @property
    def sigma_deg(self) -> float:
        return float(np.degrees(np.arctan2(self.sigma_m, self.radius_m)))


@dataclasses.dataclass(frozen=True)
class CalibrationCovariance:
    """The self-calibration's a-posteriori covariance and its coupling to the block's modes (unit weight
    times sigma0^2: px^2, m^2, px m).

    ``cal_cov`` (9, 9) in ``CAL_NAMES`` order; ``cross`` (len(MODES) + len(PLAN_MODES), 9): the covariance of
    each mode (``MODES``, then ``PLAN_MODES``) with each calibration parameter, the ``height`` row the flying
    height's (the tie points' mean height minus the projection centres': the block height where GNSS holds the
    centres); ``mode_var`` the modes' variances (the same row the flying height's); ``focal_shares``: which
    observation groups determine the mean focal length (as the modes' shares); ``depth_m``: the median depth of the
    tie points below the cameras (the focal length's lever on their heights); ``focal_gnss_height_px``,
    ``focal_image_field_px``: how far systematic errors the model does not hold move the focal length
    (``determinability``)."""

    cal_cov: np.ndarray
    cross: np.ndarray
    mode_var: np.ndarray
    focal_shares: dict
    depth_m: float
    # the focal length's change (px) were every GNSS height off by its stated sigma in the pattern that moves it
    # most: sum_i |d f / d z_i| sigma_z_i (a systematic error the independent-noise model averages away)
    focal_gnss_height_px: float = float("nan")
    # the focal length's largest change (px) under one image-wide displacement field the camera model does not hold
    # (``UNMODELLED_FIELDS``), as large as the image residuals' sigma at the frame's edge
    focal_image_field_px: float = float("nan")
    # the principal point against an offset between the GNSS positions and the projection centres fixed in the camera
    # (a lever-arm error, or a time lag along a track flown at one speed), which the solve holds (``gnss_offset``)
    pp_gnss: "PrincipalPointGnss | None" = None

    def correlation(self, mode: str, param: str | tuple) -> float:
        """Correlation of a mode with a calibration parameter, or with the mean of two (``("fx_px", "fy_px")``)."""
        names = (param,) if isinstance(param, str) else tuple(param)
        w = np.zeros(9)
        w[[CAL_NAMES.index(n) for n in names]] = 1.0 / len(names)
        m = (MODES + PLAN_MODES).index(mode)
        var_p = float(w @ self.cal_cov @ w)
        den = np.sqrt(max(var_p, 0.0) * max(float(self.mode_var[m]), 0.0))
        return float(self.cross[m] @ w / den) if den > 0 else float("nan")


def _functionals(block: G.Block, state: G.State, pr: PointRays, plan: bool):
    """(l_points (M, P, 3), block radius) of the modes (``MODES``, then ``PLAN_MODES`` if ``plan``), or
    None with fewer than 10 tie points."""
    tie = pr.used.copy()
    tie[block.control_point] = False
    j = np.flatnonzero(tie)
    if len(j) < 10:
        return None
    xy = state.points[j, :2]
    centre = xy.mean(axis=0)
    rho = float(np.max(np.linalg.norm(xy - centre, axis=1)))
    xi, eta = ((xy - centre) / rho).T
    r2 = xi**2 + eta**2
    M = np.column_stack([np.ones(len(j)), xi, eta, r2 - r2.mean()])
    n_modes = len(MODES) + (len(PLAN_MODES) if plan else 0)
    l_p = np.zeros((n_modes, block.n_points, 3))
    l_p[: len(MODES), j, 2] = np.linalg.pinv(M)  # (4, n_tie): the modes' coefficients from the heights (local up = z)
    if plan:
        l_p[len(MODES), j, 0] = 1.0 / len(j)  # mean east
        l_p[len(MODES) + 1, j, 1] = 1.0 / len(j)  # mean north
    return l_p, rho


def _apply_q(block: G.Block, pr: PointRays, rc, l_p: np.ndarray, l_c: np.ndarray | None = None):
    """``u = Q l`` for functionals with a point part ``l_p`` (M, P, 3) and a camera part ``l_c`` (M, n) in the
    reduced covariance's scalar order: (u_p (M, P, 3), u_c (M, n), l'Q l (M,)), unit weight."""
    n = rc.n
    m_count = len(l_p)
    # a = W' V^-1 l_p, summed over the rays: G_ray' l_point per ray, scattered onto the ray's parameters (the
    # rays chunk by chunk: their Jacobians are not held for all rays at once)
    a = np.zeros((m_count, n))
    for sl in pr.chunks():
        _, _, G, idx = pr.rays(sl)
        Gl = np.einsum("kij,mki->mkj", G, l_p[:, pr.pt[sl]])  # (M, k, 6 or 15)
        for m in range(m_count):
            a[m] += np.bincount(idx.ravel(), Gl[m].ravel(), n)
    rhs = (l_c - a) if l_c is not None else -a
    u_c = rc.multiply(rhs.T).T  # (M, n)
    u_p = np.einsum("pij,mpj->mpi", np.nan_to_num(pr.Vinv), l_p)
    for sl in pr.chunks():
        _, _, G, idx = pr.rays(sl)
        Gu = np.einsum("kij,mkj->mki", G, u_c[:, idx])
        for m in range(m_count):
            for i in range(3):
                u_p[m, :, i] -= np.bincount(pr.pt[sl], Gu[m, :, i], block.n_points)
    var = np.einsum("mpi,mpi->m", l_p, u_p)
    if l_c is not None:
        var = var + np.einsum("mn,mn->m", l_c, u_c)
    return u_p, u_c, var


def _shares(block: G.Block, state: G.State, control_active, pr: PointRays, *, u_p, u_c, var, gnss_change,
            fields_of: int | None = None) -> tuple[dict, np.ndarray | None]:
    """Group -> (M,) share of each functional's information ``u' H_k u / l'Q l`` (``priors``: the rest; ``gnss_change``:
    ``_gnss_change`` of the same ``u``, None without GNSS); and for the
    functional ``fields_of``, per ``UNMODELLED_FIELDS`` field ``g`` the same in every image, its change under ``g``
    (``u' A' W g``) and ``g``'s largest magnitude over the rays (F, 2) (image coordinates: the rays' normalised ones;
    the ratio of the two does not depend on their scale)."""
    share = {}
    share["image"] = np.zeros(len(u_c))
    fields = None if fields_of is None else np.zeros((len(UNMODELLED_FIELDS), 2))
    for sl in pr.chunks():
        Jp, Jc, _, idx = pr.rays(sl)
        d_ray = np.einsum("kai,mki->mka", Jp, u_p[:, pr.pt[sl]]) + np.einsum("kaj,mkj->mka", Jc, u_c[:, idx])
        share["image"] += pr.weight * np.einsum("mka,mka->m", d_ray, d_ray)
        if fields is not None:
            im = pr.im[sl]
            pc = np.einsum("kji,kj->ki", state.R_cv[im], state.points[pr.pt[sl]] - state.centre[im])
            x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
            for f, (c, a, b) in enumerate(UNMODELLED_FIELDS):
                g = x**a * y**b
                fields[f, 0] += pr.weight * float(d_ray[fields_of, :, c] @ g)
                fields[f, 1] = max(fields[f, 1], float(np.max(np.abs(g), initial=0.0)))
    if gnss_change is not None:
        share["gnss"] = _gnss_information(block, gnss_change)
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
    return share, fields


def _held(sh: dict) -> bool:
    return sh.get("gnss", 0.0) + max(sh["priors"], 0.0) >= PRIOR_SHARE


def geometry_modes(block: G.Block, opts: G.SolveSettings, state: G.State, obs_active, control_active, rc,
                   *, sigma0: float, rays: PointRays | None = None, pp_names_offset=None
                   ) -> tuple[list[GeometryMode], CalibrationCovariance | None]:
    """The four modes of the tie points' heights (see the module docstring) at the solution ``state``, and with
    self-calibration its ``CalibrationCovariance`` and the ``focal_height`` mode (when the focal length is
    estimated); ``rc``: the reduced covariance (``covariance.ReducedCovariance``, unit weight); ``rays``: the
    points' ``covariance.point_rays`` when already at hand; ``pp_names_offset``: ``pp_gnss_coupling``'s
    ``names_offset``."""
    self_cal = bool(opts.self_calibration)
    pr = rays if rays is not None else point_rays(block, state, obs_active, opts.image_sigma_px, rc, self_cal)
    fun = _functionals(block, state, pr, plan=self_cal)
    if fun is None:
        return [], None
    l_p, rho = fun
    n_modes = len(l_p)
    l_c = None
    if self_cal:
        # the mean focal length (camera part only), and the flying height: the tie points' mean height minus the
        # projection centres' (pose tangent [omega, v], d centre / d v = R), what a focal length is confounded with
        l_p = np.concatenate([l_p, np.zeros((1,) + l_p.shape[1:]), l_p[:1]])
        l_c = np.zeros((len(l_p), rc.n))
        l_c[-2, rc.offset[K_KEY] + np.array([0, 1])] = 0.5
        l_c[-1, (pr.pose_offset[:, None] + np.arange(3, 6)).ravel()] = -(state.R_cv[:, 2, :] / block.n_images).ravel()
    u_p, u_c, var = _apply_q(block, pr, rc, l_p, l_c)
    # the GNSS positions' change under each functional, once: their information and the focal length's GNSS test
    dg = _gnss_change(block, opts, state, rc, u_c) if block.gnss_local is not None else None
    share, fields = _shares(block, state, control_active, pr, u_p=u_p, u_c=u_c, var=var, gnss_change=dg,
                            fields_of=len(l_p) - 2 if self_cal else None)
    out = []
    for m, name in enumerate(MODES):
        sh = {k: float(v[m]) for k, v in share.items()}
        out.append(GeometryMode(name, float(np.sqrt(var[m])) * sigma0, rho, sh, _held(sh)))
    if not self_cal:
        return out, None
    k0 = rc.offset[K_KEY]
    s2 = sigma0**2
    cal_cov = rc.entries((k0 + np.arange(9))[:, None], (k0 + np.arange(9))[None, :]) * s2
    cross = u_c[:n_modes, k0:k0 + 9] * s2
    mode_var = var[:n_modes] * s2
    # the calibration against the flying height, not the tie points' height alone: with the projection centres
    # held by GNSS (a survey receiver) the two are one; with a consumer receiver's free offset (or no GNSS) the
    # centres move with the datum, and the focal length is confounded with the height above the ground
    cross[0], mode_var[0] = u_c[-1, k0:k0 + 9] * s2, var[-1] * s2
    # the tie points' depth below the cameras: a relative focal change moves their heights by this times it
    k = np.flatnonzero(~np.isin(block.obs_point, block.control_point) & np.asarray(obs_active, bool))
    depth = np.einsum("kji,kj->ki", state.R_cv[block.obs_image[k]],
                      state.points[block.obs_point[k]] - state.centre[block.obs_image[k]])[:, 2]
    gnss_z_px = _gnss_heights(block, dg[-2]) if dg is not None else 0.0
    # an image-wide field as large as the residuals' sigma (sigma0 times the a-priori sigma) where it is largest
    field_px = float(np.max(np.abs(fields[:, 0]) / fields[:, 1])) * sigma0 / np.sqrt(pr.weight)
    cc = CalibrationCovariance(cal_cov, cross, mode_var, {g: float(v[-2]) for g, v in share.items()},
                               float(np.median(depth)) if len(depth) else float("nan"), gnss_z_px, field_px,
                               pp_gnss_coupling(block, opts, state, rc, pr, sigma0=sigma0,
                                                names_offset=pp_names_offset)
                               if "pp" in opts.self_calibration else None)
    if any(g == "focal" for g in opts.self_calibration):
        f = 0.5 * (state.cal[0] + state.cal[1])
        sigma_f = float(np.sqrt(max(var[-2], 0.0))) * sigma0
        out.append(GeometryMode("focal_height", sigma_f / f * cc.depth_m, rho, dict(cc.focal_shares),
                                _held(cc.focal_shares), cc.correlation("height", ("fx_px", "fy_px"))))
    return out, cc


@dataclasses.dataclass(frozen=True)
class PrincipalPointGnss:
    """How the principal point (u0, v0) couples to the GNSS's systematic errors the solve does not estimate or does.

    ``px_per_m`` (2, 2): the principal point's change (px) were every GNSS position off by 1 m along the camera's x
    (image right) or y (image down) axis, ``u' A' W R e`` (``u = Sigma e_pp``): a lever-arm error, or a time lag
    along tracks flown in the camera's y at one speed, both fixed in the camera and so turning with the heading;
    ``offset_correlation`` (2,): the multiple correlation of u0 and of v0 with such an offset (x and y) had the solve
    estimated it (``K' S^-1 K / (Sigma_pp + K' S^-1 K)``, ``S`` the offset's information with the rest free);
    ``shift_correlation`` (2,): with the GNSS shifts the solve estimates (per strip, or one offset; NaN: none);
    ``orientation_correlation`` (2,): the largest correlation with one orientation parameter of one frame;
    ``tie_plan_ms`` (2, 2): the tie points' mean square plan change (m^2) under such an offset ``o`` (m, camera x and
    y) is ``o' tie_plan_ms o``: the whole solution's change ``N^-1 A' W R o`` (the orientations' by the reduced
    covariance, the points' by back-substitution), so the offset's full effect on the ground with the principal point
    taking its share, not only the part a rotation and a translation differ by off the mean height (pp-predictor);
    ``offset_estimate_m``, ``offset_sigma_m`` (2,): such an offset as the block itself would estimate it, one
    Gauss-Newton step from the solution with it added (``S^-1 R' W (g_observed - g_adjusted)``, ``S`` its information
    with the rest free, the Schur complement; sigma x sigma0): where the correlation is under the limit the block
    parts the two, and a significant estimate says the offset is there."""

    px_per_m: np.ndarray
    offset_correlation: np.ndarray
    shift_correlation: np.ndarray
    orientation_correlation: np.ndarray
    tie_plan_ms: np.ndarray = dataclasses.field(default_factory=lambda: np.full((2, 2), np.nan))
    offset_estimate_m: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    offset_sigma_m: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    # (n_shifts, 3, 2): each GNSS shift's (east, north, up, m) regression on the principal point (per px of u0, v0),
    # ``Sigma_sp Sigma_pp^-1``: times the principal point's move, the part of the shift estimate that goes with it
    # (held at its a-priori value, the shifts change by minus that); empty without shifts
    shift_per_pp_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3, 2)))
    # such an offset estimated strip by strip (at-verdicts): (n_strips, 2) estimates and sigmas (m; x sigma0, the
    # GNSS's stated sigmas as independent errors), and ``strip_chi2`` of their disagreement with one offset for all
    # (``strip_dof`` = 2 (strips - 1) degrees of freedom): an offset fixed in the camera is one for every strip, a GNSS
    # error shared along each strip (a shift per strip the solve does not model) is not. Empty / NaN: not formed
    # (one strip, or no offset named)
    strip_offset_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    strip_offset_sigma_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    strip_chi2: float = float("nan")
    strip_dof: int = 0
    # (2 n_strips, 2 n_strips): the per-strip estimates' covariance (m^2, x sigma0^2; strip-major, x then y): they are
    # correlated (the principal point and the orientations take their common part), so their differences, which the
    # chi-square judges, are known better than each, and the one offset (their combination by it) may lie outside them
    strip_offset_cov_m2: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    # the strips' own scatter about one offset (m, camera x and y): a random shift per strip, its standard deviation by
    # the moments of the per-strip estimates (their spread less what their sigmas explain; 0 where they explain it), and
    # the one offset's sigma (m) with it: the GNSS errors shared along each strip as an error of their own
    strip_tau_m: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    offset_sigma_strips_m: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))


def pp_gnss_coupling(block: G.Block, opts: G.SolveSettings, state: G.State, rc, rays: PointRays, *,
                     sigma0: float = 1.0, names_offset=None) -> PrincipalPointGnss | None:
    """``PrincipalPointGnss`` at the solution (``rc`` the unit-weight reduced covariance, ``rays`` the points'
    ``covariance.point_rays``, ``sigma0`` the solve's: the offset estimate's sigma); None without GNSS.
    ``names_offset(pg, cal, cal_apriori, cal_cov) -> bool`` (``determinability.pp_gnss_names_offset``: whether the
    flag names an offset, the one use of ``tie_plan_ms``; the a-priori calibration the block camera's, ``cal_cov``
    the calibration's covariance x sigma0^2): where given and false, ``tie_plan_ms`` (a pass over the rays: 9 CPU-s
    and 365 MB on 10,000 frames) is not formed (NaN)."""
    if block.gnss_local is None:
        return None
    k0 = rc.offset[K_KEY]
    pp = k0 + np.array([3, 4])
    pred, rows = gnss_rows(block, opts, state)
    w = 1.0 / np.asarray(block.gnss_sigma_m, dtype=float) ** 2  # (N, 3)
    grad = np.einsum("nia,ni->a", state.R_cv[:, :, :2], w * (np.asarray(block.gnss_local) - pred))
    # the information between the unknowns and an offset l fixed in the camera: g_i = ... + R_i l (x, y axes)
    b = np.zeros((rc.n, 2))
    h = np.zeros((2, 2))
    for i, row in enumerate(rows):
        WR = w[i][:, None] * state.R_cv[i][:, :2]
        h += state.R_cv[i][:, :2].T @ WR
        for k, J in row:
            b[rc.offset[k]:rc.offset[k] + J.shape[1]] += J.T @ WR
    Sb = rc.multiply(b)
    K = Sb[pp]  # (2 pp, 2 axes)
    S = h - b.T @ Sb
    var_pp = rc.entries(pp, pp)
    try:
        S_inv = np.linalg.inv(S)
        q = np.einsum("ai,ij,aj->a", K, S_inv, K)
        offset_corr = np.sqrt(np.clip(q / (var_pp + q), 0.0, 1.0))
        offset_est, offset_sd = S_inv @ grad, np.sqrt(np.clip(np.diag(S_inv), 0.0, None)) * sigma0
    except np.linalg.LinAlgError:
        offset_corr = np.ones(2)
        offset_est, offset_sd = np.full(2, np.nan), np.full(2, np.inf)
    shift = [k for k in rc.offset if chr(gtsam.Symbol(k).chr()) in "sd"] if opts.gnss_correction != "none" else []
    shift_corr = np.full(2, np.nan)
    if shift:
        idx = np.concatenate([rc.offset[k] + np.arange(rc.dim[k]) for k in shift])
        c = rc.entries(pp[:, None], idx[None, :])
        Css = rc.entries(idx[:, None], idx[None, :])
        r2 = np.einsum("ai,ai->a", c, np.linalg.lstsq(Css, c.T, rcond=None)[0].T) / var_pp
        shift_corr = np.sqrt(np.clip(r2, 0.0, 1.0))
    shift_per_pp = np.zeros((0, 3, 2))
    s_keys = sorted((k for k in shift if chr(gtsam.Symbol(k).chr()) == "s"), key=lambda k: gtsam.Symbol(k).index())
    if s_keys:
        rows = np.stack([rc.offset[k] + np.arange(3) for k in s_keys])  # (n_shifts, 3)
        C_sp = rc.entries(rows[:, :, None], pp[None, None, :])  # (n_shifts, 3, 2)
        try:
            shift_per_pp = C_sp @ np.linalg.inv(rc.entries(pp[:, None], pp[None, :]))
        except np.linalg.LinAlgError:
            shift_per_pp = np.full(C_sp.shape, np.nan)
    poses = (np.asarray(rays.pose_offset)[:, None] + np.arange(6)).ravel()
    cov = rc.entries(pp[:, None], poses[None, :])
    sd = np.sqrt(np.clip(rc.entries(poses, poses), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        orient_corr = np.nanmax(np.abs(cov / (np.sqrt(var_pp)[:, None] * sd[None, :])), axis=1)
    pg = PrincipalPointGnss(K, offset_corr, shift_corr, orient_corr, offset_estimate_m=offset_est,
                            offset_sigma_m=offset_sd, shift_per_pp_m=shift_per_pp)
    k = k0 + np.arange(9)
    cal_args = (state.cal, G.cal_from_camera(block.camera), rc.entries(k[:, None], k[None, :]) * sigma0**2)
    if names_offset is not None and not names_offset(pg, *cal_args):
        return pg
    # an offset named: is it one for every strip (fixed in the camera), or does each strip want its own (GNSS errors
    # shared along a strip)? The same step with one offset per strip (the offset's columns split by strip)
    n_s = block.n_strips
    if n_s >= 2:
        strip = np.asarray(block.strip, dtype=int)
        rows = gnss_rows(block, opts, state)[1]  # (the name was reused for the shifts' rows above)
        bs = np.zeros((rc.n, 2 * n_s))
        hs = np.zeros((2 * n_s, 2 * n_s))
        gs = np.zeros(2 * n_s)
        for i, row in enumerate(rows):
            c = slice(2 * strip[i], 2 * strip[i] + 2)
            WR = w[i][:, None] * state.R_cv[i][:, :2]
            hs[c, c] += state.R_cv[i][:, :2].T @ WR
            gs[c] += WR.T @ (np.asarray(block.gnss_local[i]) - pred[i])
            for key, J in row:
                bs[rc.offset[key]:rc.offset[key] + J.shape[1], c] += J.T @ WR
        Sbs = rc.multiply(bs)
        Ss = hs - bs.T @ Sbs
        try:
            Ss_inv = np.linalg.inv(Ss)
            est_s = Ss_inv @ gs
            one = np.tile(np.eye(2), (n_s, 1))  # (2 n_s, 2): the one offset for all strips
            S1 = one.T @ Ss @ one
            common = np.linalg.solve(S1, one.T @ Ss @ est_s)
            e = est_s - one @ common
            chi2 = float(e @ Ss @ e) / sigma0**2 if sigma0 > 0 else float("nan")
            # a random shift per strip (variance tau^2 per axis) by the moments of the estimates about their plain mean
            C = Ss_inv * sigma0**2
            centre = np.eye(n_s) - 1.0 / n_s
            tau2 = np.array([max(0.0, (float(np.sum((centre @ est_s[a::2]) ** 2))
                                       - float(np.trace(centre @ C[a::2, a::2]))) / (n_s - 1)) for a in range(2)])
            to_one = np.linalg.solve(S1, one.T @ Ss)  # (2, 2 n_s): the one offset from the per-strip estimates
            V = to_one @ C @ to_one.T + (to_one * np.tile(tau2, n_s)) @ to_one.T
            pg = dataclasses.replace(pg, strip_offset_m=est_s.reshape(n_s, 2),
                                     strip_offset_sigma_m=np.sqrt(np.clip(np.diag(C), 0.0, None)).reshape(n_s, 2),
                                     strip_chi2=chi2, strip_dof=2 * (n_s - 1), strip_offset_cov_m2=C,
                                     strip_tau_m=np.sqrt(tau2),
                                     offset_sigma_strips_m=np.sqrt(np.clip(np.diag(V), 0.0, None)))
        except np.linalg.LinAlgError:
            pass
        if names_offset is not None and not names_offset(pg, *cal_args):
            return pg  # the strips explain it: no offset named, no plan effect formed
    return dataclasses.replace(pg, tie_plan_ms=_tie_plan_ms(block, rays, Sb))


def _tie_plan_ms(block: G.Block, pr: PointRays, dc: np.ndarray) -> np.ndarray:
    """(2, 2): ``M`` with the tie points' mean square plan change ``o' M o`` under the orientations' (and
    calibration's) change ``dc o`` (``dc`` (n, 2) in the reduced covariance's scalar order, per unit of ``o``): the
    points follow by back-substitution, ``dp = -V^-1 W dc`` (one pass over the rays, as ``_apply_q``'s)."""
    dp = np.zeros((block.n_points, 2, 2))  # point, east / north, offset axis
    for sl in pr.chunks():
        _, _, G, idx = pr.rays(sl)
        Gu = np.einsum("kij,kja->kia", G[:, :2], dc[idx])  # (k, 2, 2): plan only
        for i in range(2):
            for a in range(2):
                dp[:, i, a] -= np.bincount(pr.pt[sl], Gu[:, i, a], block.n_points)
    tie = pr.used.copy()
    tie[block.control_point] = False
    t = dp[tie]
    return np.einsum("tia,tib->ab", t, t) / max(len(t), 1)


def _gnss_change(block: G.Block, opts: G.SolveSettings, state: G.State, rc, u_c: np.ndarray) -> np.ndarray:
    """(M, N, 3): each GNSS position's change (local east, north, up) under each functional's ``u``."""
    rows = gnss_rows(block, opts, state)[1]
    return np.stack([sum(u_c[:, rc.offset[k]:rc.offset[k] + J.shape[1]] @ J.T for k, J in row) for row in rows], axis=1)


def _gnss_information(block: G.Block, dg: np.ndarray) -> np.ndarray:
    """``u' H_gnss u`` per mode: the GNSS positions' weighted change under each mode's ``u`` (``dg``:
    ``_gnss_change``)."""
    return np.einsum("mni,ni->m", dg * dg, 1.0 / block.gnss_sigma_m**2)


def _gnss_heights(block: G.Block, dg: np.ndarray) -> float:
    """The largest change of the functional of ``u`` were each GNSS height off by up to its sigma (``dg`` (N, 3): the
    GNSS positions' change under ``u``, a row of ``_gnss_change``): the estimate moves by ``u' A' W dy``, for the
    heights ``sum_i dz_i e_i / sigma_i^2`` (``dz`` the height's change under ``u``), at most ``sum_i |dz_i| /
    sigma_i``."""
    dz = dg[:, 2]
    return float(np.sum(np.abs(dz) / block.gnss_sigma_m[:, 2]))
