"""The adjustment procedure: robust solution, data snooping, control-point test, final least squares,
marginal covariances and check points (all in the local frame)."""

from __future__ import annotations

import logging

import dataclasses
import time

import numpy as np
from scipy.spatial.transform import Rotation

from aerotri.adjust import graph as G
from aerotri.adjust import variance_components as vce
from aerotri.adjust.surface import SurfaceStats, surface_stats
from aerotri.core.errors import SolveError
from aerotri.adjust.check_points import intersect, intersect_with_covariance
from aerotri.adjust.cpp_output import counting
from aerotri.adjust import surface_bias as sb
from aerotri.adjust.approximate import MAX_REACH_FLYING_HEIGHTS
from aerotri.adjust.held_calibration import held_focal, held_principal_point, held_radial
from aerotri.adjust.covariance import ReducedCovariance, point_rays
from aerotri.adjust.determinability import ground_observations, pp_gnss_names_offset
from aerotri.adjust.geometry_modes import geometry_modes
from aerotri.adjust.covariance import point_covariances as point_covariances_rcs
from aerotri.adjust.gnss_surface import gnss_surface_offset
from aerotri.adjust.height_datum import height_datum_check
from aerotri.adjust.snooping import (
    critical_value,
    redundancy_numbers,
    robust_sigma0,
    standardised_residuals,
    worst_per_point,
    coordinate_w,
    w_correlations,
)

log = logging.getLogger(__name__)

# A change of the surface gate alone starts another robust round only while it can matter: when at least
# GATE_CHANGE_SHARE of the surface candidates changed sides, or when the round just solved moved some orientation
# parameter by at least UPDATE_SIGMA_FRACTION of its sigma (``orientation_update_sigmas``). Otherwise the rounds go
# on to the snooping with the new gate, and the final solve gates again. Before, a single point at the gate's edge
# kept the rounds going to ``max_rounds``; the effect on the outputs (demo: 0.004 sigma) in docs/performance.md.
GATE_CHANGE_SHARE = 0.01
OFF_DEM_SHARE = 0.2  # of the tie points outside the DEM: warned (the demo 0.1 %, trial-relief F6 37 %)
UPDATE_SIGMA_FRACTION = 0.1
# A flagged ray whose test correlates beyond this with another ray's of the same point (3 rays or more) is not told
# from it: the point is left out whole. Removing the ray of the larger w there was a coin toss (trial-scale H2: a
# 40 px error along the base in one ray of a 3-ray point of one strip; the sound ray went, w 78.8, and the two
# left put the point 17.8 m low with a sigma of 0.20 m, in object_points.csv as adjusted).
SEPARABLE_RHO = 0.9


@dataclasses.dataclass
class Removed:
    obs: int  # index into block observations
    w: float  # standardised residual when removed
    round: int
    # the point left out whole: its worst ray's test correlated beyond SEPARABLE_RHO with another ray's, so the
    # test could not tell which ray was wrong (``snooping.w_correlations``); every active ray of it is listed
    whole_point: bool = False
    blamed: bool = True  # the ray the test named (of a point left out whole: the one of the largest w, not told apart)
    # of a point left out whole: the ray's residual (px) in the round it went; the point is not adjusted after it, so
    # a residual of the final solution would be against its stale position (trial s98: -20 px beside w 3-4)
    residual_px: tuple | None = None


@dataclasses.dataclass
class AdjustmentResult:
    state: G.State
    info: G.SolveInfo
    sigma0: float  # a-posteriori sigma naught (unitless, relative to image_sigma_px)
    obs_active: np.ndarray
    control_active: np.ndarray
    removed: list
    rejected_control: list  # (control index, w)
    residual_px: np.ndarray  # (K, 2), observed - computed
    redundancy: np.ndarray  # (K, 2)
    pose_cov: np.ndarray | None  # (N, 6, 6) pose tangent [omega, v], a posteriori (x sigma0^2)
    point_cov: np.ndarray | None  # (P, 3, 3) local frame, a posteriori
    cal_cov: np.ndarray | None  # (9, 9)
    marginals: object
    iterations_total: int
    timings_s: dict
    surface: SurfaceStats | None = None  # what the surface control did (blocks with a DEM)
    surface_use: np.ndarray | None = None  # (P,) 0 no candidate, 1 used, 2 rejected by the gate
    variance_components: list | None = None  # variance_components.VarianceComponent per group (final weights)
    weight_factors: dict | None = None  # group -> factor its a-priori sigmas were multiplied by (reweighting)
    block: G.Block | None = None  # the block as solved last (its sigmas reweighted by the variance components)
    opts: G.SolveSettings | None = None
    geometry: list | None = None  # geometry_modes.GeometryMode: how well the block's height modes are determined
    calibration: object | None = None  # geometry_modes.CalibrationCovariance (self-calibration only)
    behind_camera: tuple[int, int] = (0, 0)  # gtsam's CheiralityException lines, (point, camera) pairs (cpp_output)
    surface_bias: object | None = None  # surface_bias.SurfaceBias: the surface's systematic error in the covariances
    # height_datum.HeightDatumCheck: the height control the data snooping left in against the GNSS heights (None: no
    # height control left out, or no GNSS)
    height_datum: object | None = None
    # held_calibration.HeldPrincipalPoint: the principal point held at camera.toml's value against the images (None:
    # estimated, or no covariances computed)
    held_pp: object | None = None
    # gnss_surface.GnssSurfaceOffset: the GNSS heights' common offset from the surface control's block height (None:
    # no surface control, no GNSS, or a GNSS correction that takes the offset)
    gnss_surface: object | None = None
    # held_calibration.HeldFocal: the focal length held at camera.toml's value against the images (None: estimated,
    # nothing observes the ground's heights, or no covariances computed)
    held_focal: object | None = None
    # held_calibration.HeldRadial: the radial distortion held at camera.toml's values against the images (None:
    # estimated, a model without it, or no covariances computed)
    held_radial: object | None = None

    def control_left_out(self) -> np.ndarray:
        """Per control point: left out of the block, by the control test (``control_active`` off) or by every one of
        its rays removed (``rejected_control``, ``rays_removed_control``)."""
        out = ~np.asarray(self.control_active, dtype=bool)
        out[[c for c, _ in self.rejected_control]] = True
        return out


def adjust_block(block: G.Block, opts: G.SolveSettings, state0: G.State, **kwargs) -> AdjustmentResult:
    """``_adjust_block`` (the same arguments: snooping, alpha, compute_marginals, point_covariances, max_rounds,
    variance_components, max_vce_iterations), with gtsam's points-behind-a-camera lines counted into the
    result's ``behind_camera`` instead of printed (``cpp_output``)."""
    with counting() as seen:
        result = _adjust_block(block, opts, state0, **kwargs)
    result.behind_camera = (seen.lines, len(seen.pairs))
    if seen.lines:
        log.debug("gtsam found %d point(s) behind a camera during the solve (%d messages)", len(seen.pairs),
                  seen.lines)
    return result


def _adjust_block(
    block: G.Block,
    opts: G.SolveSettings,
    state0: G.State,
    *,
    snooping: bool = True,
    alpha: float = 1e-4,
    compute_marginals: bool = True,
    point_covariances: bool = True,
    max_rounds: int = 15,
    variance_components: bool = False,
    max_vce_iterations: int = 6,
    image_sigma_from_residuals: bool = False,
    control_held_out=(),
) -> AdjustmentResult:
    """Adjust the block; with ``snooping``, remove blunders (image points, then control points). The variance
    components of the observation groups are estimated with the covariances; with ``variance_components``
    the groups are reweighted by them and solved again until every factor is within 5 % of one.
    ``control_held_out`` (control indices; with ``snooping``): points a robust start without them found off (the
    datum's robust similarity of a block without GNSS): the first rejected, so that with few points a wrong one
    cannot bend the block and have the good ones blamed. When the rest has passed its tests, each is tested
    against the block the others hold (``control_test``), the best taken back while it passes, the others
    rejected with their w."""
    t_start = time.perf_counter()
    crit = critical_value(alpha)
    obs_active = np.ones(len(block.obs_point), dtype=bool)
    control_active = np.ones(len(block.control_point), dtype=bool)
    held = [int(c) for c in control_held_out] if snooping else []
    control_active[held] = False
    removed, rejected = [], []
    state = state0.copy()
    iterations = 0
    timings = {"robust_s": 0.0, "final_s": 0.0, "marginals_s": 0.0}

    is_control_obs = np.isin(block.obs_point, block.control_point)

    tested = []  # [(state, active observations, v, r, sigma0)] of the last test: a second one at the same state reuses it

    def residuals_and_redundancy(st):
        # obs_active only ever loses observations: the same count is the same set
        n_active = int(obs_active.sum())
        if tested and tested[0] is st and tested[1] == n_active:
            return tuple(tested[2:])
        v = G.image_residuals(block, st)
        r = redundancy_numbers(block.obs_point, block.obs_image, st.points, st.centre, st.R_cv, st.cal,
                               active=obs_active, point_info=_point_information(block, st, opts.image_sigma_px))
        tested[:] = [st, n_active, v, r, robust_sigma0(v, r, obs_active)]
        return tuple(tested[2:])

    def _not_separable(st, v, r, s0, bad) -> np.ndarray:
        """Points (of 3 rays or more) whose flagged ray's test (its coordinate of the larger w) correlates beyond
        SEPARABLE_RHO with another ray's. (Its other coordinate is no evidence on its own: the robust solution puts
        part of an error along the base into the coordinates across of the ray it blames, 0.8 px on a sound middle
        ray, w above the critical value: taken as naming the ray, a sound ray went again. Trial s98: Brighton's
        T0003580, w 120.7, lost whole where its across coordinate may have named the ray: one point.)"""
        rays = np.bincount(block.obs_point[obs_active], minlength=block.n_points)
        k = np.flatnonzero(bad)
        k = k[(rays[block.obs_point[k]] >= 3) & ~is_control_obs[k]]
        if not len(k):
            return k
        rho = w_correlations(k, block.obs_point, block.obs_image, st.points, st.centre, st.R_cv, st.cal,
                             active=obs_active, point_info=_point_information(block, st, opts.image_sigma_px))
        worse = np.argmax(coordinate_w(v[k], r[k], s0), axis=1)
        return block.obs_point[k[rho[np.arange(len(k)), worse] > SEPARABLE_RHO]]

    def snoop(st, rnd, with_control=True):
        # control-point rays are tested only after the control points themselves: a wrong control
        # coordinate pulls its rays, which would otherwise be removed in its place
        v, r, s0 = residuals_and_redundancy(st)
        w = standardised_residuals(v, r, s0)
        testable = obs_active if with_control else obs_active & ~is_control_obs
        bad = worst_per_point(w, block.obs_point, testable, crit)
        in_whole = np.isin(block.obs_point, _not_separable(st, v, r, s0, bad))
        for k in np.flatnonzero(bad & ~in_whole):
            removed.append(Removed(int(k), float(w[k]), rnd))
        for k in np.flatnonzero(in_whole & obs_active):
            removed.append(Removed(int(k), float(w[k]), rnd, whole_point=True, blamed=bool(bad[k]),
                                   residual_px=(float(v[k, 0]), float(v[k, 1]))))
            bad[k] = True
        obs_active[bad] = False
        _drop_weak_points(block, obs_active)
        return int(bad.sum())

    _drop_weak_points(block, obs_active, state)
    surface_candidates = None
    if block.surface is not None:
        # candidates by the DEM's extent and the nDSM; which of them lie on the ground is decided again
        # after every robust round, as the orientation improves (gate)
        surface_candidates = block.surface.candidates(state.points)
        block.surface_active = surface_candidates.copy()
        log.info(f"surface control: {int(surface_candidates.sum())} of {block.n_points} points are candidates")
        if not surface_candidates.any():  # (review 52: a DEM beside the block read "Solution Successful", unsaid)
            log.warning("surface control: no tie point of the block lies on the surface given (its extent, its nodata "
                        "and the nDSM leave none): the block is adjusted without it")
    def held_out_test(gr, values) -> np.ndarray:
        """w of each held-out control point against the block the active ones hold."""
        out = np.zeros(len(block.control_point), dtype=bool)
        out[held] = True
        return control_test(block, opts, state, obs_active, out, _marginals(gr, values, block, obs_active))

    def take_back(c: int, w: np.ndarray) -> None:
        control_active[c] = True
        held.remove(c)
        log.info(f"control point {block.point_id[block.control_point[c]]} held out at the start: "
                 f"w = {w[c]:.2f} against the others, taken back")

    def settle_held(w: np.ndarray) -> None:
        """No round left to test one against the others with another: each that passes back, the rest rejected
        with their w (never left out without one)."""
        for c in sorted(held, key=lambda c: w[c]):
            if w[c] <= crit:
                take_back(c, w)
            else:
                rejected.append((c, float(w[c])))
        _restart_from_rays(block, state, obs_active, block.control_point[held])  # those left: the rejected
        held.clear()

    rnd = 0
    if snooping:
        while rnd < max_rounds:
            rnd += 1
            t0 = time.perf_counter()
            before = state
            tested.clear()  # a new solution follows: the last test's arrays (170 MB at 5 M rays) are not kept through it
            gr = G.build_graph(block, opts, state, obs_active, control_active, robust=True)
            # robust rounds only need to be close: the next round starts from here, the final one polishes.
            # Huber weights make LM converge linearly (iteratively reweighted), so a tight tolerance would
            # only crawl: 1e-5 in the cost is far below what moves a standardised residual.
            quick = dataclasses.replace(opts, max_iterations=min(opts.max_iterations, 40 if rnd == 1 else 20),
                                        relative_tolerance=max(opts.relative_tolerance, 1e-5))
            values, info = G.optimize(gr, quick)
            if rnd == 1 and not np.isfinite(info.chi2):
                raise SolveError(_start_failure(block, state))
            timings["robust_s"] += time.perf_counter() - t0
            iterations += info.iterations
            state = G.state_from_values(values, block, opts, state, tie=gr.tie)
            log.info(f"robust round {rnd}: {info.iterations} iterations, {obs_active.sum()} observations")
            if rnd == 1 and surface_candidates is not None and surface_candidates.any():
                _warn_off_dem(block, state)
            if surface_candidates is not None:
                surface_candidates, gated = _surface_gate(block, state, obs_active, opts.image_sigma_px)
                changed = int((gated != block.surface_active).sum())
                block.surface_active = gated
                update = orientation_update_sigmas(before, state, gr.tie.pose_information if gr.tie else None)
                log.info(f"robust round {rnd}: {int(gated.sum())} surface observations within "
                         f"{block.surface.gate_sigmas:g} sigma ({changed} changed of {int(surface_candidates.sum())} "
                         f"candidates); largest orientation update {update:.3g} sigma")
                if rnd < max_rounds and another_round_for_the_gate(changed, int(surface_candidates.sum()), update):
                    continue
            if snoop(state, rnd, with_control=False):
                continue
            # control points: leave-one-out intersection against the given coordinates
            if control_active.sum() > 0:
                t0 = time.perf_counter()
                marg = _marginals(gr, values, block, obs_active)
                timings["marginals_s"] += time.perf_counter() - t0
                w = control_test(block, opts, state, obs_active, control_active, marg)
                worst = int(np.argmax(w)) if len(w) else -1
                if worst >= 0 and w[worst] > crit:
                    control_active[worst] = False
                    rejected.append((worst, float(w[worst])))
                    _restart_from_rays(block, state, obs_active, block.control_point[[worst]])
                    continue
            if snoop(state, rnd, with_control=True):
                continue
            if held:
                # the held-out points against the block the others hold: the best back while it passes
                w = held_out_test(gr, values)
                best = min(held, key=lambda c: w[c])
                if w[best] <= crit and rnd < max_rounds:
                    take_back(best, w)
                    continue
                settle_held(w)
            break
        if held and rnd > 0:  # the rounds ran out before the held-out points were tested against the others
            settle_held(held_out_test(gr, values))
    for c in held:  # no robust round at all: nothing to test them against, so they are not held out
        control_active[c] = True
    held.clear()

    image_factor = 1.0
    if image_sigma_from_residuals and rnd > 0:
        opts, image_factor = _image_sigma_from_residuals(opts, *residuals_and_redundancy(state), obs_active)

    # final least squares without the robust kernel; a last snooping check
    _drop_weak_points(block, obs_active, state)
    if surface_candidates is not None:
        surface_candidates, block.surface_active = _surface_gate(block, state, obs_active, opts.image_sigma_px)
    for _ in range(3):
        tested.clear()
        t0 = time.perf_counter()
        gr = G.build_graph(block, opts, state, obs_active, control_active, robust=False)
        values, info = G.optimize(gr, opts)
        timings["final_s"] += time.perf_counter() - t0
        iterations += info.iterations
        log.info(f"final solve: {info.iterations} iterations, {int(obs_active.sum())} observations")
        state = G.state_from_values(values, block, opts, state, tie=gr.tie)
        if not snooping:
            break
        rnd += 1
        if snoop(state, rnd) == 0:
            break
    sigma0 = float(np.sqrt(info.chi2 / info.dof)) if info.dof > 0 else float("nan")
    # the principal point held at camera.toml's value tested against the images (trial-cam: a sign flipped on a
    # small block was absorbed into the frames' kappa, "Solution Successful")
    held_pp = held_principal_point(block, opts, state, info, obs_active, control_active) if compute_marginals else None
    # the focal length held the same way, where the ground's heights tell it from the flying height (s95: a pixel size
    # 22 % short, the block 11.8 m high, "Solution Successful")
    held_f = (held_focal(block, opts, state, info, obs_active, control_active,
                         ground_heights=ground_observations(block, control_active, block.surface_active).height)
              if compute_marginals else None)
    # and the radial distortion (trial s97 M1: a certificate's K on r in mm typed as k: weak, blaming all but the lens)
    held_k = held_radial(block, opts, state, info, obs_active, control_active) if compute_marginals else None

    pose_cov = point_cov = cal_cov = marg = bias = None
    components, factors, geometry, calibration = None, None, None, None
    height_datum = gnss_surface = None
    if compute_marginals:
        t0 = time.perf_counter()
        n_pts = int(np.sum(np.bincount(block.obs_point[obs_active], minlength=block.n_points) >= 2))
        log.info(f"covariances of {block.n_images} frames' orientations and {n_pts} points")
        marg = _marginals(gr, values, block, obs_active)
        if marg is None:
            # an (almost) indeterminate point makes the covariance fail: drop weakly intersected points and
            # re-solve from the current solution
            _drop_weak_points(block, obs_active, state, max_cond=1e4)
            gr = G.build_graph(block, opts, state, obs_active, control_active, robust=False)
            values, info = G.optimize(gr, opts)
            iterations += info.iterations
            state = G.state_from_values(values, block, opts, state, tie=gr.tie)
            marg = _marginals(gr, values, block, obs_active)
            if marg is None:  # (trial s97 M2: a 2,000-frame strip, eo.txt without sigmas and not a word said)
                log.warning("the covariances could not be computed (the reduced normal matrix is too ill-conditioned "
                            "for a Cholesky factor: a block of one long strip, or a weakly held datum): at/eo.txt "
                            "and the report give no standard deviations")
        point_unit = rays = None
        if marg is not None and point_covariances:
            rays, point_unit, components = _point_precision(block, opts, state, obs_active, control_active, marg,
                                                            dof=info.dof)
            factors = {c.group: image_factor if c.group == "image" else 1.0 for c in components}
            for it in range(max_vce_iterations if variance_components else 0):
                if all(c.factor is None or abs(c.factor - 1.0) < 0.05 for c in components):
                    break
                for c in components:
                    if c.factor is not None:
                        factors[c.group] *= c.factor
                block, opts = vce.reweighted(block, opts, components)
                if surface_candidates is not None:
                    surface_candidates, block.surface_active = _surface_gate(block, state, obs_active,
                                                                             opts.image_sigma_px)
                gr = G.build_graph(block, opts, state, obs_active, control_active, robust=False)
                values, info = G.optimize(gr, opts)
                iterations += info.iterations
                state = G.state_from_values(values, block, opts, state, tie=gr.tie)
                marg = _marginals(gr, values, block, obs_active)
                if marg is None:
                    raise SolveError("the covariances failed after reweighting by variance components; "
                                     "adjust without variance-component reweighting")
                rays, point_unit, components = _point_precision(block, opts, state, obs_active, control_active,
                                                                marg, dof=info.dof)
                log.info("variance components, iteration %d: %s", it + 1, ", ".join(
                    f"{c.group} {c.factor:.3f}" for c in components if c.factor is not None))
        sigma0 = float(np.sqrt(info.chi2 / info.dof)) if info.dof > 0 else float("nan")
        s2 = sigma0**2
        if marg is not None:
            pose_cov = np.array([marg.marginalCovariance(G.X(i)) for i in range(block.n_images)]) * s2
            if point_unit is not None:
                point_cov = point_unit * s2
                geometry, calibration = geometry_modes(block, opts, state, obs_active, control_active, marg,
                                                       sigma0=sigma0, rays=rays, pp_names_offset=pp_gnss_names_offset)
            if values.exists(G.K_KEY):
                cal_cov = marg.marginalCovariance(G.K_KEY) * s2
            # the height control the snooping left in against the GNSS heights' plane error (at-verdicts)
            height_datum = height_datum_check(block, opts, state, marg, control_active, sigma0=sigma0, alpha=alpha,
                                              obs_active=obs_active)
            gnss_surface = gnss_surface_offset(block, opts, state, marg, sigma0=sigma0,
                                               obs_active=obs_active, control_active=control_active)
            bias = _surface_bias(block, opts, state, obs_active=obs_active, control_active=control_active, marg=marg,
                                 rays=rays)
            if bias is not None:
                # the surface's systematic error in every covariance reported (the solution stays as it is)
                pose_cov = pose_cov + sb.pose_covariance(bias, marg, block.n_images)
                if point_cov is not None:
                    add = sb.point_covariance(bias, rays or point_rays(block, state, obs_active, opts.image_sigma_px,
                                                                       marg, bool(opts.self_calibration)),
                                              block.n_points)
                    point_cov = point_cov if add is None else point_cov + add
                if cal_cov is not None:
                    cal_cov = cal_cov + sb.key_covariance(bias, marg, G.K_KEY)
                marg = sb.ConsideredCovariance(marg, bias, s2)
        timings["marginals_s"] += time.perf_counter() - t0
    v, r, _ = residuals_and_redundancy(state)
    rejected += rays_removed_control(block, obs_active, control_active, removed, {c for c, _ in rejected})
    timings["total_s"] = time.perf_counter() - t_start
    stats = use = None
    if surface_candidates is not None:
        surface_candidates, block.surface_active = held_by_rays(block, obs_active, surface_candidates,
                                                                block.surface_active)
        stats = surface_stats(block.surface, state.points, surface_candidates, block.surface_active)
        use = np.where(block.surface_active, 1, np.where(surface_candidates, 2, 0)).astype(np.int8)
        rms = "n/a" if stats.rms_m is None else f"{stats.rms_m:.3f} m"
        log.info(f"surface control: {stats.used} points used, {stats.rejected} rejected, height - DEM RMS {rms}")
    return AdjustmentResult(
        state, info, sigma0, obs_active, control_active, removed, rejected, v, r, pose_cov, point_cov, cal_cov, marg,
        iterations, timings, stats, use, components, factors, block, opts, geometry, calibration, surface_bias=bias,
        height_datum=height_datum, held_pp=held_pp, gnss_surface=gnss_surface, held_focal=held_f, held_radial=held_k,
    )


def rays_removed_control(block: G.Block, obs_active, control_active, removed, rejected: set) -> list:
    """(control index, largest w) of the control points kept by the control test whose image measurements the
    snooping removed, every one: such a point is out of the block as surely as one the test rejected (trial-api F2:
    a height mistyped by 2 m lost both its rays, the report said 0 control rejected and its control RMS improved).
    Its coordinates stay in the solve, held by nothing but themselves."""
    return [(c, w) for c, rays, w in _control_that_lost_rays(block, obs_active, control_active, removed)
            if rays == 0 and c not in rejected]


def _control_that_lost_rays(block: G.Block, obs_active, control_active, removed) -> list:
    """(control index, active rays left, largest w of its rays removed) of the control points in the solve that the
    snooping removed rays of."""
    w_of = {}
    for x in removed:
        j = int(block.obs_point[x.obs])
        w_of[j] = max(w_of.get(j, 0.0), float(x.w))
    rays = np.bincount(block.obs_point[np.asarray(obs_active, bool)], minlength=block.n_points)
    return [(c, int(rays[j]), w_of[int(j)]) for c, j in enumerate(block.control_point)
            if control_active[c] and int(j) in w_of]


def one_ray_control(block: G.Block, obs_active, control_active, removed) -> list:
    """(control index, largest w of its rays removed) of the control points in the solve that the snooping left with
    a single ray: a control point with one ray is not checked by the block (its coordinates, if mistyped, pass into
    it unseen), and the ray kept may be the wrong one of those that disagreed."""
    return [(c, w) for c, rays, w in _control_that_lost_rays(block, obs_active, control_active, removed) if rays == 1]


def held_by_rays(block: G.Block, obs_active, *masks) -> tuple:
    """``masks`` (bool over the points) less the points without two active rays: a point the last snooping left
    without rays is in no solve since (its surface observation neither), but the surface gate before it had made it
    a candidate and used (the demo: 16,064 surface points used against the variance components' 16,063)."""
    held = np.bincount(block.obs_point[np.asarray(obs_active, bool)], minlength=block.n_points) >= 2
    return tuple(np.asarray(m, bool) & held for m in masks)


def another_round_for_the_gate(changed: int, candidates: int, update_sigmas: float) -> bool:
    """Whether a change of the surface gate (``changed`` of ``candidates`` points changed sides) after a robust round
    that moved the orientations by ``update_sigmas`` (``orientation_update_sigmas``) calls for another robust round
    before the snooping: yes for any change while ``GATE_CHANGE_SHARE`` of the candidates change or the round moved
    an orientation parameter by ``UPDATE_SIGMA_FRACTION`` of its sigma or more."""
    return changed > 0 and (changed >= GATE_CHANGE_SHARE * candidates or update_sigmas >= UPDATE_SIGMA_FRACTION)


def orientation_update_sigmas(before: G.State, after: G.State, information: np.ndarray | None) -> float:
    """The largest change of any orientation parameter from ``before`` to ``after`` in its conditional sigma: the pose
    tangent ``[omega, v]`` of the change (gtsam's right perturbation, ``R -> R Exp(omega)``, ``C -> C + R v``) in
    units of ``sqrt(diag(information_i^-1))`` (``information`` (N, 6, 6), unit weight: the reduced camera system's
    diagonal blocks, ``TiePoints.pose_information``). These sigmas hold the other orientations fixed, so they are
    smaller than the marginal ones and the figure larger (the stricter test); inf without ``information``."""
    if information is None or len(information) != len(after.centre):
        return float("inf")
    R_rel = np.einsum("nji,njk->nik", before.R_cv, after.R_cv)
    omega = Rotation.from_matrix(R_rel).as_rotvec()
    v = np.einsum("nji,nj->ni", before.R_cv, after.centre - before.centre)
    ok = np.linalg.cond(information) < 1e12
    if not ok.any():
        return float("inf")
    sigma = np.sqrt(np.diagonal(np.linalg.inv(information[ok]), axis1=1, axis2=2))
    return float(np.max(np.abs(np.hstack([omega, v])[ok]) / sigma))


def _point_precision(block: G.Block, opts: G.SolveSettings, state: G.State, obs_active, control_active, marg, *,
                     dof: int):
    """(the rays' linearisation, the points' unit-weight covariances, the groups' variance components) at the
    solution ``state`` with its reduced covariance ``marg``."""
    self_cal = bool(opts.self_calibration)
    rays = point_rays(block, state, obs_active, opts.image_sigma_px, marg, self_cal)
    unit = point_covariances_rcs(block, state, obs_active, opts.image_sigma_px, marg, self_cal, rays=rays)
    return rays, unit, vce.estimate(block, opts, state, obs_active, control_active, marg, point_cov_unit=unit, dof=dof)


# below this the residuals of a simulated block without noise would make the image weights unbounded
MIN_IMAGE_SIGMA_PX = 0.02
MIN_IMAGE_REDUNDANCY = 50.0  # the estimate of the image sigma needs this much redundancy, else the a priori stays


def _image_sigma_from_residuals(opts: G.SolveSettings, v_px, r, sigma_px: float,
                                obs_active) -> tuple[G.SolveSettings, float]:
    """The options with ``image_sigma_px`` set to the robust estimate ``sigma_px`` of the image residuals (one
    variance component, the images', from the last robust round) and the factor on the a-priori sigma; the
    options unchanged (factor 1) when the redundancy is too small or the estimate not finite."""
    redundancy = float(np.nansum(np.where(obs_active[:, None], r, 0.0)))
    if not (np.isfinite(sigma_px) and sigma_px > 0 and redundancy >= MIN_IMAGE_REDUNDANCY):
        return opts, 1.0
    sigma_px = max(sigma_px, MIN_IMAGE_SIGMA_PX)
    factor = sigma_px / opts.image_sigma_px
    log.info(f"image sigma from the robust rounds' residuals: {sigma_px:.3f} px (a priori {opts.image_sigma_px:g} px, "
             f"redundancy {redundancy:.0f}); the final solve weights the images by it")
    return dataclasses.replace(opts, image_sigma_px=sigma_px), factor


def _point_information(block: G.Block, st: G.State, sigma_px: float) -> np.ndarray | None:
    """(P, 3, 3) what a tie point's surface height (the active ones) tells of it, in the rays' unit weight
    (``sigma_px`` squared times the information per m2), as the solve weighs it; None without surface control.
    (A control point's rays are tested after the point itself, against its rays alone: a wrong coordinate pulls
    them, which would otherwise be removed in its place.)"""
    from aerotri.adjust.surface import whitened

    if block.surface is None or block.surface_active is None or not np.any(block.surface_active):
        return None
    _, B, _ = whitened(block.surface, st.points, block.surface_active)
    return np.einsum("pi,pj->pij", B, B) * float(sigma_px) ** 2


def _surface_gate(block: G.Block, state: G.State, obs_active, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(candidates, gated): the points that may lie on the ground or a roof face where their rays alone put them
    (intersected at the current orientations, without the surface; ``SurfaceControl.candidates``), and those
    of them whose height from their rays alone agrees with the surface within ``gate_sigmas`` of the combined
    sigma (the surface's and the intersection's height sigma): a point on a car, a hedge or a roof edge is
    judged by where the images put it, not by where the surface pulled it (judged by its pulled position, a
    point at the edge of a roof face or of an object in the nDSM would go in and out, round after round)."""
    from aerotri.adjust.check_points import refined_normals

    k = np.flatnonzero(obs_active)
    pts, N = refined_normals(block.obs_xy_px[k], block.obs_point[k], block.obs_image[k], state.centre, state.R_cv,
                             state.cal, points=state.points, iterations=3)
    # only points the solve holds (two rays or more, not parallel) are candidates: a point without rays has no
    # height of its own, and with an infinite sigma it would pass the gate and count as used
    rays = np.bincount(block.obs_point[k], minlength=block.n_points)
    ev = np.zeros((block.n_points, 3))
    used = rays >= 2
    ev[used] = np.linalg.eigvalsh(N[used])
    ok = used & (ev[:, 0] > 0) & (ev[:, 2] < 1e10 * ev[:, 0])
    # ... and whose rays alone meet near where the solve holds them (trial s97 H2: "EPSG:4328 -> EPSG:32649: point
    # 1866 (418575418, 167170763) could not be transformed", the run stopped)
    height_m = float(np.median(state.centre[:, 2]) - np.nanmedian(state.points[used, 2])) if used.any() else 0.0
    ok &= np.all(np.isfinite(pts), axis=1) & (np.linalg.norm(np.nan_to_num(pts - state.points, nan=np.inf), axis=1)
                                              <= MAX_REACH_FLYING_HEIGHTS * max(abs(height_m), 1.0))
    pts = np.where(ok[:, None], pts, state.points)
    sz2 = np.full(block.n_points, np.inf)
    sz2[ok] = sigma_px**2 * np.linalg.inv(N[ok])[:, 2, 2]  # local up is the vertical within a block
    candidates = block.surface.candidates(pts) & ok
    e, _, sigma = block.surface.observe(pts, jacobian=False)
    tol = block.surface.gate_sigmas * np.sqrt(sigma**2 + sz2)
    return candidates, candidates & np.isfinite(e) & (np.abs(e) <= tol)


def _restart_from_rays(block: G.Block, state: G.State, obs_active: np.ndarray, points: np.ndarray) -> None:
    """``points`` (indices) restarted at the intersection of their active rays in ``state``, where it is in front of
    every camera that sees them. A control point the snooping leaves out becomes a tie point; its adjusted
    coordinate was held towards a wrong given one, which may lie behind its cameras (a height 1,100 m off), where
    a collinearity factor has no gradient and the next solve starts at an infinite cost."""
    points = np.unique(np.asarray(points, dtype=np.int64))
    if len(points) == 0:
        return
    k = np.flatnonzero(obs_active & np.isin(block.obs_point, points))
    row = np.searchsorted(points, block.obs_point[k])
    meet, _ = intersect(block.obs_xy_px[k], row, block.obs_image[k], state.centre, state.R_cv, state.cal,
                        n_points=len(points))
    depth = np.einsum("kj,kj->k", meet[row] - state.centre[block.obs_image[k]], state.R_cv[block.obs_image[k]][:, :, 2])
    in_front = np.all(np.isfinite(meet), axis=1)
    in_front[row[~(depth > 0.0)]] = False
    state.points[points[in_front]] = meet[in_front]


def _warn_off_dem(block: G.Block, state: G.State) -> None:
    """The tie points outside the DEM or on its nodata, where the first robust round put them (trial-relief F6: a DEM
    over 63 % of the tie points; the solve then failed with a message about the self-calibration and the GNSS, nothing
    about the DEM). Judged on the start values, a 2,000-frame strip's rough start said 39 % where none was (trial s97
    M3)."""
    off = int(block.surface.off_dem(state.points).sum())
    if off > OFF_DEM_SHARE * block.n_points:
        log.warning(f"surface control: {off} of {block.n_points} tie points ({100 * off / block.n_points:.0f} %) "
                    "lie outside the DEM or on its nodata: the DEM covers part of the block, whose other heights "
                    "rest on GNSS and control alone (a DEM cropped, or of another area?)")


def _start_failure(block: G.Block, state: G.State) -> str:
    """Why the solve cannot start: the start values' cost is infinite (tie points behind cameras that see them),
    naming the frames whose start attitude is far from level (trial s97 H2: a re-flown strip beside the frames of its
    stations and a frame taken out: the resection of the start values tilted 11 of 23 frames 57-89 deg, and the run
    stopped on a map projection error, then on a crash. Its cause, found later, was the flying-height guess taking
    the re-flown twins for the base, ``pipeline._flying_height_guess``; tie points joining frames that do not
    overlap do the same)."""
    tilt = np.degrees(np.arccos(np.clip(np.abs(state.R_cv[:, 2, 2]), 0.0, 1.0)))
    bad = np.argsort(-tilt)[:8]
    bad = [i for i in bad if tilt[i] > 20.0]
    frames = ", ".join(f"{block.image_id[i]} {tilt[i]:.0f} deg" for i in bad)
    return ("the adjustment cannot start: at the start values tie points lie behind cameras that see them (the cost "
            "is infinite)" + (f"; the start attitudes of frames tilt from the vertical ({frames}" +
                              (", ..." if (tilt > 20.0).sum() > len(bad) else "") + ")" if bad else "") +
            ": tie points that join frames which do not overlap (matches between near-identical frames, e.g. a "
            "re-flown strip beside the frames of its stations), or GNSS positions of other frames. Look at the tie "
            "points of these frames (at/connectivity.png), match again without the duplicates, or give the start "
            "orientations (--eo)")


MAX_INTERSECTION_COND = 1e5  # a point's normal matrix beyond: rays intersecting below about a third of a degree


def _drop_weak_points(block: G.Block, obs_active, state: G.State | None = None,
                      max_cond: float = MAX_INTERSECTION_COND) -> None:
    """Deactivate tie points that carry no information: a single ray left, or (given ``state``) rays
    so nearly parallel that the point is indeterminate (condition of its normal matrix > ``max_cond``,
    an intersection angle below about a third of a degree)."""
    is_control = np.zeros(block.n_points, dtype=bool)
    is_control[block.control_point] = True
    rays = np.bincount(block.obs_point[obs_active], minlength=block.n_points)
    weak = (rays < 2) & ~is_control
    if state is not None:
        from aerotri.adjust.check_points import refined_normals

        k = np.flatnonzero(obs_active)
        _, N = refined_normals(block.obs_xy_px[k], block.obs_point[k], block.obs_image[k], state.centre, state.R_cv,
                               state.cal, points=state.points, iterations=0)
        used = rays >= 2
        ev = np.zeros((block.n_points, 3))
        ev[used] = np.linalg.eigvalsh(N[used])
        weak |= used & ~is_control & (ev[:, 0] * max_cond < ev[:, 2])
    obs_active &= ~weak[block.obs_point]


def _surface_bias(block: G.Block, opts: G.SolveSettings, state: G.State, *, obs_active, control_active, marg,
                  rays) -> sb.SurfaceBias | None:
    """The surface control's systematic error as a consider parameter (``surface_bias``), or None (no surface, or
    its bias sigmas zero)."""
    sc = block.surface
    if sc is None or block.surface_active is None or not (sc.bias_sigma_xy_m > 0 or sc.bias_sigma_z_m > 0):
        return None
    if rays is None:
        rays = point_rays(block, state, obs_active, opts.image_sigma_px, marg, bool(opts.self_calibration))
    bias = sb.surface_bias(block, state, rays, marg, control_active=control_active, cell_m=sc.bias_cell_m,
                           length_m=sc.bias_length_m,
                           sigma_xy_m=sc.bias_sigma_xy_m, sigma_z_m=sc.bias_sigma_z_m)
    if bias is not None:
        log.info(f"surface bias: {len(bias.point)} surface points in {bias.cells} cells of {bias.cell_m:g} x "
                 f"{bias.length_m:g} map units (across x along the flight), "
                 f"sigma {sc.bias_sigma_xy_m:g} / {sc.bias_sigma_z_m:g} m (plan / height) added to the covariances")
    return bias


def _marginals(gr, values, block, obs_active):
    """Covariances from the reduced camera system, or None when the (robustly weighted) system is too
    ill-conditioned for them."""
    keys = [G.P(j) for j in np.unique(block.obs_point[obs_active])]
    try:
        return ReducedCovariance(gr, values, keys)
    except (RuntimeError, np.linalg.LinAlgError):
        return None


def control_test(block, opts, state, obs_active, control_active, marg) -> np.ndarray:
    """Standardised discrepancy (max over components) between each active control point intersected
    from its images alone and its given coordinates; 0 for points with fewer than 2 rays."""
    w = np.zeros(len(block.control_point))
    for c in np.flatnonzero(control_active):
        j = block.control_point[c]
        k = np.flatnonzero(obs_active & (block.obs_point == j))
        if len(k) < 2:
            continue
        X0, cov, _ = intersect_with_covariance(
            block.obs_xy_px[k], block.obs_image[k], state.centre, state.R_cv, state.cal, opts.image_sigma_px,
            marginals=marg, self_cal=bool(opts.self_calibration),
        )
        d = X0 - block.control_local[c]
        Sigma = cov + block.control_cov_local[c]
        # test in the axes of the given coordinates: whiten with the eigen-decomposition
        evals, evecs = np.linalg.eigh(Sigma)
        z = (evecs.T @ d) / np.sqrt(evals)
        w[c] = float(np.max(np.abs(z[evals < (G.LOOSE_SIGMA_M / 10) ** 2]), initial=0.0))
    return w


def check_point_errors(obs_xy_px, obs_image, obs_point, n_points, state, opts, *, result: AdjustmentResult,
                       alpha: float = 1e-4):
    """Intersect check points with the final orientations: (points (M, 3), covariances (M, 3, 3), rays used (M,))."""
    pts = np.full((n_points, 3), np.nan)
    cov = np.full((n_points, 3, 3), np.nan)
    rays = np.bincount(obs_point, minlength=n_points)
    s0 = result.sigma0 if np.isfinite(result.sigma0) else 1.0
    crit = critical_value(alpha)
    dropped = np.zeros(n_points, dtype=int)
    for j in range(n_points):
        k = np.flatnonzero(obs_point == j)
        while len(k) >= 2:
            X0, C, v = intersect_with_covariance(
                obs_xy_px[k], obs_image[k], state.centre, state.R_cv, state.cal, opts.image_sigma_px,
                marginals=result.marginals, self_cal=bool(opts.self_calibration),
            )
            # a check measurement can be a blunder too: with 3+ rays, drop the worst ray if it fails the test
            # (redundancy of each coordinate about (2m - 3) / 2m)
            w = np.abs(v).max(axis=1) / (opts.image_sigma_px * s0 * np.sqrt((2 * len(k) - 3) / (2 * len(k))))
            if len(k) >= 3 and w.max() > crit:
                k = np.delete(k, int(np.argmax(w)))
                dropped[j] += 1
                continue
            # rays too nearly parallel to intersect (the tie points' condition limit, ``_drop_weak_points``', here on
            # the point's covariance with the orientations'): no position to check
            # (trial s97 H1: a check point left with the two rays of a re-flown strip's frame and the frame of the same
            # station, 0.5 px apart, came 323 m off with sigmas of 20-136 m and made the check RMS 11 m / 16 m)
            ev = np.linalg.eigvalsh(C) if np.all(np.isfinite(C)) else np.array([0.0, 0.0, np.inf])
            if not ev[0] * MAX_INTERSECTION_COND >= ev[2]:
                break
            pts[j] = X0
            cov[j] = C * s0**2
            break
    rays = rays - dropped
    return pts, cov, rays
