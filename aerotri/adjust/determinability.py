"""Can the block determine the self-calibration it was asked for? A rule from the covariance, per group.

A converged solve with a small sigma naught says nothing about whether the focal length or the principal
point were determined by the block or merely moved with something nothing else fixes. Each estimated group
is judged at the solution by two tests (``CalibrationCovariance`` of ``geometry_modes``):

1. **Not determined by the block.**

   - the focal length: over flat ground with near-nadir frames it scales the tie points' depths below the
     cameras, so it is confounded with the flying height; what separates them is the GNSS heights'
     frame-to-frame differences, control points with a height, a DEM, and the perspective of tilts and relief in
     the tie points. Its correlation with the flying height says nothing about which of these determine it (0.999
     on a simulated flat block whose survey GNSS determines it to 0.1 %; 0.72-0.90 on Brighton Beach's 18 drone
     frames, whose estimate came out 21 % off the DEM solution): it is reported, not judged. The focal length is
     judged against the tolerance ``FOCAL_TOLERANCE_FRACTION`` of itself: ``FOCAL_SIGMA_MULTIPLE`` standard
     deviations within it (Brighton: sigma 25 px, 0.88 %; the estimate 21 % off), and within it also the largest
     change of the estimate were every GNSS height off by its stated sigma in the pattern that moves it most (a
     systematic error the independent-noise model averages away) and under one image-wide displacement field of
     the residuals' size the camera model does not hold (shear, quadratic, cubic: the tie points' perspective is
     all that determines it where the other two are weak, and a rolling shutter or a lens's residual distortion
     bends that perspective) (``geometry_modes``: ``focal_gnss_height_px``, ``focal_image_field_px``).
   - the other groups: the partial correlation of the group's parameters with a mode of the tie points, the
     other estimated groups held (the multiple correlation of the mode with the group after the other groups'
     share is taken out), over ``CORRELATION_LIMIT``, while no observation of the ground fixes that mode:
     radial distortion <-> the block height (a drone's wide-angle frames: on Brighton Beach without a DEM
     the radial terms, correlation 0.93-0.96 with the height, took the tie points 2.9 m below the DEM even
     with the focal length held at the DEM solution's value; its correlation with the block's bending, the
     classic dome of a GNSS-only block, is reported, not judged: it is high wherever nothing observes the
     bending, 0.97 on a simulated block flown at two heights, while the bending itself stays small);
     principal point and decentring distortion <-> the tie points' mean plan position (with the projection
     centres fixed by GNSS a principal-point offset is a common rotation of the frames, which moves the
     ground in plan). The height is observed on the ground by control points with a height (full or height
     kind, in use) and by a DEM (surface control); the plan position by control points with plan coordinates.

2. **Too loose to matter.** The group's standard deviation moves the image corner by more than
   ``SIGMA_LIMIT_FRACTION`` of the focal length (that fraction of the flying height on the ground); the focal
   length's own sigma test is the one above.

A group failing either test is **fixed at its a-priori value** (the camera file's), and the block is
solved again without it; the report and the console name the group, the test and its numbers, and the
verdict is weak. Fixed, not refused, for every group: the a-priori camera is what the block would be
adjusted with had the user not asked (a manufacturer's or calibration report's values, or the EXIF
camera from the sensor width), a refusal would leave no result at all, and what was refused stays visible
(the estimate and its sigma in the report). The remaining groups are judged again on the new solution.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.geometry_modes import CAL_NAMES, MODES, PLAN_MODES, CalibrationCovariance
from aerotri.core.quantiles import chi2_isf, chi2_ppf

CORRELATION_LIMIT = 0.9
# the principal point: a move from its a-priori value beyond this many of its standard deviations is a finding where
# an offset between the GNSS positions and the projection centres fixed in the camera (a lever-arm error, a time
# lag) would move it alike (``PrincipalPointGnss.offset_correlation`` over CORRELATION_LIMIT): the block cannot tell
# the camera's principal point from such an offset, with or without control points (small-fixes3: a 0.7 m lag moved
# v0 by 6.8 px, 31 sigma, on a flat simulated block, 32 sigma with 4 full control points; seeds 1-4 without a lag
# or an offset moved 0.1-1.7 sigma; chosen before they were run, not tuned). A flag says the estimate holds any such
# offset (not to be reused as the camera's calibration); it does not make the solution weak (a camera file whose
# principal point is off by a pixel moves it alike: the demo's 1.0 px at 41 sigma). Since pp-predictor the block's
# own estimate of such an offset (one Gauss-Newton step with it added, ``PrincipalPointGnss.offset_estimate_m``)
# decides instead of the correlation: no flag where it rejects the offset the move names, beyond this many of its
# sigmas (the same 5, not tuned); since s18-fixes also a flag wherever that estimate is this many sigmas off zero,
# whatever the move (the same 5 again, not tuned: review 18 proposed it on seeds 0-5 of 60 and 120 m with the camera
# file 5 px off and a lag, and saw 2.9 sigma at most on 52 blocks without a lag; bench/eval_pp_relief.py scores it
# on other seeds and reliefs)
PP_MOVE_SIGMAS = 5.0
# ... but where the ground is not flat the two part: a principal-point offset is a rotation of the bundle, a GNSS
# offset fixed in the camera a translation; they agree at the tie points' mean height only (pp-relief). The flag
# turns the solution weak when the predicted plan effect of the offset named (the tie points' RMS plan change under
# it, the whole solution's change from the normal equations, ``PrincipalPointGnss.tie_plan_ms``; pp-predictor: it
# was offset x half the 5-95 % relief / depth, half the check points' measured change) exceeds this fraction of the
# AT plan RMS limit of the report's tolerance table (``report._key_statistics``): one unmodelled error source may use
# at most a third of the plan error budget (errors add in quadrature: the rest keeps sqrt(8/9) = 94 % of it). Chosen
# by that reasoning before any block was scored, not tuned
PP_RELIEF_PLAN_FRACTION = 1.0 / 3.0
# the per-strip estimates of that offset (``PrincipalPointGnss.strip_offset_m``) disagree with one offset for all strips
# beyond this chi-square tail probability: GNSS errors shared along each strip (shifts per strip the solve does not
# model) are there, and the one offset is judged against its sigma with their scatter (``offset_sigma_strips_m``), not
# the GNSS's stated sigmas alone (at-verdicts; the s18-fixes review found those 3.5-3.9 times too small with 0.3 m
# shifts per strip). The report's rate for the GNSS's per-strip checks (report.GNSS_CORRECTION_ALPHA), not tuned
STRIP_SHIFT_ALPHA = 0.01
SIGMA_LIMIT_FRACTION = 0.01
# the focal length: within this fraction of itself at FOCAL_SIGMA_MULTIPLE standard deviations, and moved by no more
# than that by GNSS heights off by their sigma or by an image-wide error of the residuals' size the camera model does
# not hold (``geometry_modes``: ``focal_gnss_height_px``, ``focal_image_field_px``)
FOCAL_TOLERANCE_FRACTION = 0.01
FOCAL_SIGMA_MULTIPLE = 3.0
# per group: its Cal3DS2 entries' names, and the modes it is judged against by correlation (what observes them;
# the focal length is judged by what determines it instead: ``_focal_reasons``)
GROUP_PARAMETERS = {"focal": ("fx_px", "fy_px"), "pp": ("u0_px", "v0_px"), "radial": ("k1", "k2"),
                    "tangential": ("p1", "p2")}
CONFOUNDED_WITH = {"focal": (), "pp": PLAN_MODES, "tangential": PLAN_MODES, "radial": ("height",)}
# the correlations reported (the bending of radial distortion besides: not judged)
REPORTED_WITH = {"focal": ("height",), "pp": PLAN_MODES, "tangential": PLAN_MODES, "radial": ("height", "bending")}
_MODE_GROUND = {"height": "height", "bending": "height", "tilt_east": "height", "tilt_north": "height",
                "shift_east": "plan", "shift_north": "plan"}
_UNOBSERVED_BY = {"height": "no height control point or DEM", "plan": "no plan control point"}
MODE_NAMES = {"height": "the block height", "bending": "the block's bending", "tilt_east": "the east-west tilt",
              "tilt_north": "the north-south tilt", "shift_east": "the tie points' east position",
              "shift_north": "the tie points' north position"}


@dataclasses.dataclass(frozen=True)
class GroupCheck:
    """The verdict on one self-calibration group at one solution."""

    group: str
    estimate: dict  # parameter -> value at the solution (px, or unitless coefficients)
    apriori: dict  # parameter -> a-priori value
    sigma: dict  # parameter -> a-posteriori standard deviation
    corner_sigma_px: float  # the group's standard deviation as a displacement at the image corner
    corner_sigma_fraction: float  # ... over the focal length
    correlations: dict  # mode -> partial correlation with the group (the other estimated groups held)
    ground_observed: dict  # mode -> whether an observation on the ground fixes it
    determinable: bool
    reason: str | None  # why not (None: determinable)
    # "estimated"; "fixed" (at its a-priori value, solved again without it); "flagged" (estimated and kept, but the
    # block cannot tell it from a GNSS error it does not model: the principal point against a lever arm or time lag;
    # the solution is not weaker for it, the estimate is not a camera calibration to reuse)
    action: str
    sigma_fraction: float | None = None  # focal: its standard deviation over it
    gnss_height_fraction: float | None = None  # focal: its largest change, GNSS heights off by their sigma, over it
    image_field_fraction: float | None = None  # focal: its largest change under an unmodelled image field, over it
    # pp (u0, v0) against the GNSS (``geometry_modes.PrincipalPointGnss``): its change (px) per metre of a GNSS offset
    # along the camera's x / y, its correlation with such an offset (lever arm, time lag) had it been estimated, with
    # the GNSS shifts estimated (None: none), and the largest with one orientation parameter of one frame
    gnss_offset_px_per_m: tuple | None = None
    gnss_offset_correlation: tuple | None = None
    gnss_shift_correlation: tuple | None = None
    orientation_correlation: tuple | None = None
    # pp flagged against a GNSS offset (``pp_gnss_judgement``): the predicted plan effect on the ground (m) of the
    # offsets named (u0's and v0's): the tie points' RMS plan change under them, the whole solution's change (not a
    # relief term: ``relief_plan_m`` until s18-fixes); judged against ``PP_RELIEF_PLAN_FRACTION`` of the plan limit by
    # the report. None: not flagged, or flagged by the correlation with the GNSS shifts only (no offset named)
    gnss_offset_plan_effect_m: float | None = None
    # pp against a GNSS offset fixed in the camera (x, y): the block's own estimate of it (m) and its sigma
    gnss_offset_estimate_m: tuple | None = None
    gnss_offset_estimate_sigma_m: tuple | None = None
    # pp with GNSS shifts: each shift's (east, north, up, m) part that goes with the principal point's move from its
    # a-priori value (``PrincipalPointGnss.shift_per_pp_m`` times the move): the shift it would lose were pp held
    gnss_shift_from_pp_m: tuple | None = None
    # pp flagged where GNSS strip shifts explain the move (``strip_shift_test``; at-verdicts): the per-strip offsets'
    # estimates (m, camera x and y per strip), their sigmas, their chi-square against one offset, its degrees of freedom,
    # the shift per strip's standard deviation and the one offset with its sigma (``_strip_shift_fields``). None: no
    # such finding
    gnss_strip_shifts: dict | None = None


@dataclasses.dataclass(frozen=True)
class GroundObservations:
    """Whether control points in use (or a DEM) observe the ground's heights and plan positions."""

    height: bool
    plan: bool


def ground_observations(block: G.Block, control_active, surface_active=None) -> GroundObservations:
    """Whether control points in use (or a DEM, for the heights) observe the ground's heights and plan positions."""
    active = np.asarray(control_active, dtype=bool)
    rows = np.asarray(block.control_rows)[active] if len(block.control_rows) else np.zeros(0, int)
    surface = block.surface is not None and surface_active is not None and bool(np.any(surface_active))
    return GroundObservations(height=bool(np.any(rows != 2)) or surface, plan=bool(np.any(rows != 1)))


def _partial_correlation(cc: CalibrationCovariance, mode: str, group: list[int], others: list[int]) -> float:
    """Multiple correlation of ``mode`` with the calibration entries ``group``, the entries ``others`` held."""
    m = (MODES + PLAN_MODES).index(mode)
    idx = group + others
    J = np.zeros((len(idx) + 1,) * 2)
    J[0, 0] = cc.mode_var[m]
    J[0, 1:] = J[1:, 0] = cc.cross[m, idx]
    J[1:, 1:] = cc.cal_cov[np.ix_(idx, idx)]
    keep = list(range(len(group) + 1))
    S = J[np.ix_(keep, keep)]
    if others:
        o = list(range(len(group) + 1, len(idx) + 1))
        S = S - J[np.ix_(keep, o)] @ np.linalg.solve(J[np.ix_(o, o)], J[np.ix_(o, keep)])
    c = S[0, 1:]
    if not (S[0, 0] > 0):
        return float("nan")
    r2 = float(c @ np.linalg.lstsq(S[1:, 1:], c, rcond=None)[0] / S[0, 0])
    return float(np.sqrt(np.clip(r2, 0.0, 1.0)))


def _corners(cal: np.ndarray, width: int, height: int) -> np.ndarray:
    """Normalised coordinates (4, 2) of the image corners (pixel centres) relative to the principal point."""
    fx, fy, _, u0, v0 = cal[:5]
    u = np.array([0.0, width - 1.0, 0.0, width - 1.0])
    v = np.array([0.0, 0.0, height - 1.0, height - 1.0])
    return np.column_stack([(u - u0) / fx, (v - v0) / fy])


def corner_sigma_px(group: str, cal: np.ndarray, cal_cov: np.ndarray, width: int, height: int) -> float:
    """The largest standard deviation (px) over the image corners of the displacement the group's parameters
    make (Cal3DS2: x_px = fx (x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)) + u0, likewise y)."""
    idx = [CAL_NAMES.index(p) for p in GROUP_PARAMETERS[group]]
    C = cal_cov[np.ix_(idx, idx)]
    fx, fy = cal[0], cal[1]
    k1, k2, p1, p2 = cal[5], cal[6], cal[7], cal[8]
    worst = 0.0
    for x, y in _corners(cal, width, height):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        if group == "focal":  # d(px) / d(fx, fy)
            J = np.array([[xd, 0.0], [0.0, yd]])
        elif group == "pp":
            J = np.eye(2)
        elif group == "radial":
            J = np.array([[fx * x * r2, fx * x * r2 * r2], [fy * y * r2, fy * y * r2 * r2]])
        else:  # tangential
            J = np.array([[fx * 2 * x * y, fx * (r2 + 2 * x * x)], [fy * (r2 + 2 * y * y), fy * 2 * x * y]])
        worst = max(worst, float(np.sqrt(max(np.trace(J @ C @ J.T), 0.0))))
    return worst


def _focal_reasons(sigma_fraction: float, gnss_fraction: float, field_fraction: float) -> list[str]:
    """Why the block does not determine the focal length within ``FOCAL_TOLERANCE_FRACTION`` (the fractions: its
    standard deviation, its largest change by GNSS heights off by their sigma and by an unmodelled image field, each
    over the focal length)."""
    tol, out = FOCAL_TOLERANCE_FRACTION, []
    k = FOCAL_SIGMA_MULTIPLE
    if not (k * sigma_fraction <= tol):
        out.append(f"{k:g} standard deviations are {100 * k * sigma_fraction:.2f} % of the focal length (limit "
                   f"{100 * tol:g} %)")
    if not (gnss_fraction <= tol):
        out.append(f"GNSS heights off by their sigma move the focal length by up to {100 * gnss_fraction:.2f} % (limit "
                   f"{100 * tol:g} %)")
    if not (field_fraction <= tol):
        out.append(f"an image-wide error as large as the residuals that the camera model does not hold (shear, "
                   f"quadratic, cubic) moves the focal length by up to {100 * field_fraction:.2f} % (limit "
                   f"{100 * tol:g} %)")
    return out


def strip_shift_test(pg) -> np.ndarray | None:
    """The one offset's sigma (m, camera x and y) with the strips' own scatter where the per-strip estimates disagree
    with one offset for all strips beyond ``STRIP_SHIFT_ALPHA`` (GNSS errors shared along the strips), else None (one
    strip, the estimates not formed, or agreeing within the GNSS's noise)."""
    c2, dof = float(getattr(pg, "strip_chi2", float("nan"))), int(getattr(pg, "strip_dof", 0))
    if dof <= 0 or not math.isfinite(c2) or c2 <= float(chi2_isf(STRIP_SHIFT_ALPHA, dof)):
        return None
    sd = np.asarray(pg.offset_sigma_strips_m, dtype=float)
    return np.maximum(sd, np.asarray(pg.offset_sigma_m, dtype=float)) if np.all(np.isfinite(sd)) else None


def _xy(v, fmt: str = ".2f") -> str:
    return f"x {format(float(v[0]), fmt)} y {format(float(v[1]), fmt)}"


def strip_differences(pg) -> tuple[float, np.ndarray, np.ndarray]:
    """The per-strip estimates' largest correlation between two strips on one axis, and each strip's estimate less
    strip 1's with its sigma ((n_strips - 1, 2) each, m): what the chi-square against one offset judges (review 29:
    Brighton's two strips x +1.75 / +0.71 +- 0.33-0.37 m, their difference known to about a tenth of that).
    NaN / empty without the covariance."""
    C = np.asarray(getattr(pg, "strip_offset_cov_m2", np.zeros((0, 0))), dtype=float)
    est = np.asarray(pg.strip_offset_m, dtype=float)
    n = len(est)
    if n < 2 or C.shape != (2 * n, 2 * n):
        return float("nan"), np.zeros((0, 2)), np.zeros((0, 2))
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    r = [abs(C[2 * i + a, 2 * j + a]) / (sd[2 * i + a] * sd[2 * j + a]) for a in range(2) for i in range(n)
         for j in range(i + 1, n) if sd[2 * i + a] > 0 and sd[2 * j + a] > 0]
    d = est[1:] - est[0]
    var = np.array([[C[2 * s + a, 2 * s + a] + C[a, a] - 2 * C[2 * s + a, a] for a in range(2)] for s in range(1, n)])
    return (max(r) if r else float("nan")), d, np.sqrt(np.clip(var, 0.0, None))


def tau_interval(n_strips: int, level: float = 0.9) -> tuple[float, float]:
    """The factors of a shift per strip's standard deviation estimated from ``n_strips`` strips' spread (their moments:
    ``n_strips - 1`` degrees of freedom per axis) that bound it at ``level`` (chi-square; 2 strips: 0.51-16)."""
    k, q = n_strips - 1, (1.0 - level) / 2.0
    return math.sqrt(k / chi2_isf(q, k)), math.sqrt(k / chi2_ppf(q, k))


def _pp_move(cal: np.ndarray, cal_apriori: np.ndarray, cal_cov: np.ndarray, name: str) -> tuple[float, float]:
    """(the principal point's move on ``name``, "u0" or "v0", from its a-priori value, its standard deviation), px."""
    i = CAL_NAMES.index(f"{name}_px")
    return float(cal[i] - cal_apriori[i]), math.sqrt(max(float(cal_cov[i, i]), 0.0))


def _strip_shift_reason(pg, strip_sd: np.ndarray, cal, cal_apriori, cal_cov) -> str:
    """The flag's reason where GNSS strip shifts, not an offset fixed in the camera, explain the principal point's
    move (the per-strip estimates listed, their correlation and differences; the fix an operator has)."""
    est, sd = np.asarray(pg.strip_offset_m), np.asarray(pg.strip_offset_sigma_m)
    per = ", ".join(f"strip {s + 1} x {est[s, 0]:+.2f} y {est[s, 1]:+.2f}" for s in range(min(len(est), 8)))
    r, d, dsd = strip_differences(pg)
    diff = ""
    if len(d):  # review 29: the one offset outside the strips' estimates, and a chi-square beside their sigmas
        diff = (f"; the estimates are correlated (up to {r:.2f}: the principal point and the orientations take their "
                "common part), so their differences are known better than each ("
                + ", ".join(f"strip {s + 2} - strip 1 x {d[s, 0]:+.2f} +- {dsd[s, 0]:.2f} y {d[s, 1]:+.2f} +- "
                            f"{dsd[s, 1]:.2f}" for s in range(min(len(d), 4)))
                + f"{', ...' if len(d) > 4 else ''} m), and one offset for all, their combination weighted by that "
                "correlation, can lie outside them")
    lo, hi = tau_interval(len(est))
    moves = []
    for name in ("u0", "v0"):
        move, sdp = _pp_move(cal, cal_apriori, cal_cov, name)
        if sdp > 0:
            moves.append(f"{name} {move:+.1f} px ({abs(move) / sdp:.0f} standard deviations)")
    return (f"GNSS strip shifts: the block's estimate of a GNSS position offset fixed in the camera differs strip by "
            f"strip ({per}{', ...' if len(est) > 8 else ''} m, each +- {float(np.median(sd)):.2f} m; chi-square "
            f"{pg.strip_chi2:.1f} for {pg.strip_dof} degrees of freedom against one offset for all strips, beyond "
            f"{STRIP_SHIFT_ALPHA:g}{diff}; a shift per strip of {_xy(pg.strip_tau_m)} m standard deviation, from "
            f"the spread of {len(est)} strips: {lo:.2g} to {hi:.2g} times that at 90 %), and one "
            f"offset for all ({_xy(pg.offset_estimate_m, '+.2f')} m) is within {PP_MOVE_SIGMAS:g} of its sigma with "
            f"that scatter ({_xy(strip_sd)} m): GNSS errors shared along each strip that the "
            f"solve does not model explain it, not the camera (a lever arm or time lag beneath them would be within "
            f"that scatter: the block cannot tell); the principal point moved with them ({', '.join(moves)}) and is "
            f"no calibration to reuse. With control points estimate per-strip GNSS shifts ([adjust] "
            f"gnss_correction = \"shift\", or \"shift_drift\"; they need the control for the datum); without, weight "
            f"the GNSS by what it holds over a strip ([gnss] sigma_xy_m, sigma_z_m; a drone's receiver: the EXIF "
            f"import's consumer model); or re-process the trajectory")


def pp_gnss_judgement(pg, cal: np.ndarray, cal_apriori: np.ndarray,
                      cal_cov: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Why the principal point is not determinable against the GNSS (``PrincipalPointGnss`` ``pg``, its
    ``tie_plan_ms`` not used), and the GNSS offsets (m, camera x and y; 0 on an axis where none is named) whose plan
    effect the flag states. Per axis (u0: x, v0: y):

    - correlated over ``CORRELATION_LIMIT`` with the GNSS shifts the solve estimates (per strip: each strip one
      heading, its shift moves its ground as a principal-point offset does). No offset named for it: the shifts take
      any offset fixed in the camera strip by strip, so none is left to move the ground; what the two trade is in
      the principal point's standard deviation (and the points');
    - the block's own estimate of an offset of the GNSS fixed in the camera (lever arm, time lag; the solve holds it;
      ``pg.offset_estimate_m``) over ``PP_MOVE_SIGMAS`` of its sigma off zero: the block finds one, whatever the
      principal point's move says (the move is the lag's share less the camera file's own error: a camera file 5 px
      off hid a 0.7 m lag, review 18); the offset named is the estimate;
    - else the principal point moved over ``PP_MOVE_SIGMAS`` of its standard deviations from its a-priori value, as
      such an offset would move it (``pg.px_per_m``), and the estimate does not reject the offset the move names
      (within ``PP_MOVE_SIGMAS`` of its sigma; or the block gives no estimate, its information singular): it cannot
      tell the two apart; the offset named is the move's.

    The estimate's sigma is the GNSS's stated sigmas' (independent errors); where the per-strip estimates disagree
    with one offset for all strips (``strip_shift_test``: GNSS errors shared along the strips) it is scaled by their
    own scatter first. Where an offset would be named with the stated sigmas and none is with the scaled one, the
    move is the GNSS strip shifts': one reason names them (``_strip_shift_reason``), no offset is named."""
    strip_sd = strip_shift_test(pg)
    out, offset = _pp_gnss_axes(pg, cal, cal_apriori, cal_cov, strip_sd)
    if strip_sd is not None and not offset.any() and _pp_gnss_axes(pg, cal, cal_apriori, cal_cov, None)[1].any():
        out = [t for t in out if "GNSS shifts the solve estimates" in t]
        out.append(_strip_shift_reason(pg, strip_sd, cal, cal_apriori, cal_cov))
    return out, offset


def _pp_gnss_axes(pg, cal: np.ndarray, cal_apriori: np.ndarray, cal_cov: np.ndarray,
                  strip_sd: np.ndarray | None) -> tuple[list[str], np.ndarray]:
    """``pp_gnss_judgement``'s per-axis reasons and offsets; ``strip_sd``: the offset estimate's sigma with the strips'
    scatter (``strip_shift_test``), None: the GNSS's stated sigmas'."""
    out, offset = [], np.zeros(2)
    for a, (name, axis) in enumerate((("u0", "x"), ("v0", "y"))):
        r = float(pg.shift_correlation[a])
        if math.isfinite(r) and r > CORRELATION_LIMIT:
            out.append(f"{name} correlation {r:.3f} with the GNSS shifts the solve estimates (limit "
                       f"{CORRELATION_LIMIT:g}): a shift per strip moves a strip's ground as a principal-point offset "
                       "does (no plan effect stated for it: the shifts take any GNSS offset fixed in the camera strip "
                       "by strip, and what the two trade is in the standard deviations)")
        move, sd = _pp_move(cal, cal_apriori, cal_cov, name)
        r = float(pg.offset_correlation[a])
        k = float(pg.px_per_m[a, a])
        # the block's own estimate of such an offset (one Gauss-Newton step with it added) tests the offset named
        # (pp-predictor, bench/eval_pp_relief.py). Flat ground: sigma 0.8-1.4 m, nothing rejected (as the correlation
        # over the limit flagged before); 120 m of relief under 1,000 m with a 0.7 m lag: correlation 0.69-0.97, under
        # the limit on 7 of 12 seeds; the estimate -0.64 to -0.83 +- 0.04-0.09 m, at most 2.4 sigma from the offset
        # named on any lag block; a camera file 5 px off and no lag there: 0.46-0.60 m named, -0.12 to +0.04 +-
        # 0.04-0.07 m found (10-13 sigma apart): not flagged. With both (s18-fixes) the move names the lag's share less
        # the camera file's error, which the estimate rejects while it finds the lag (8.6-23 sigma off zero)
        moved = sd > 0 and abs(move) > PP_MOVE_SIGMAS * sd and k != 0
        est = float(pg.offset_estimate_m[a])
        est_sd = float(pg.offset_sigma_m[a]) if strip_sd is None else float(strip_sd[a])
        estimated = math.isfinite(est) and math.isfinite(est_sd) and est_sd > 0
        # the estimate's sigma takes the GNSS errors as independent (their stated sigmas): errors shared along a strip
        # (a per-strip shift the solve does not model) make it 3.5-3.9 times too small (review 18), so a finding
        # there is the GNSS's error whichever it is (a real one: 0.3 m shifts moved the check points 0.60 m)
        found = estimated and abs(est) > PP_MOVE_SIGMAS * est_sd
        sigma_src = ("the sigma from the GNSS's stated sigmas as independent errors" if strip_sd is None else
                     "the sigma with the per-strip estimates' scatter (a shift per strip the solve does not model)")
        move_text = (f"{name} moved {move:+.1f} px ({abs(move) / sd:.0f} standard deviations, limit "
                     f"{PP_MOVE_SIGMAS:g}) from its a-priori value, as a GNSS position offset of {move / k:+.2f} m "
                     f"along the camera's {axis} axis would move it ({k:.2f} px per m: a lever-arm error, or a time "
                     "lag along the track)") if sd > 0 and k != 0 else f"{name}"
        if found and sd > 0 and abs(move) < sd:
            # the principal point stayed within its sigma: the finding is the GNSS's, not the camera's (review 22; the
            # Tuniu block on its surface model: v0 +0.08 +- 0.20 px, an offset of +0.12 +- 0.02 m found)
            offset[a] = est
            out.append(f"{name} did not move ({move:+.2f} px, under its standard deviation {sd:.2f} px), but the block "
                       f"finds a GNSS position offset along the camera's {axis} axis (its own estimate {est:+.2f} +- "
                       f"{est_sd:.2f} m, {abs(est) / est_sd:.0f} standard deviations off zero, {sigma_src}; "
                       f"correlation {r:.4f} with it): a finding of the "
                       "GNSS (a lever-arm error, or a time lag along the track), not of the principal point")
        elif found:
            offset[a] = est
            out.append(f"{move_text}, and the block finds such an offset along the camera's {axis} axis (its own "
                       f"estimate {est:+.2f} +- {est_sd:.2f} m, {abs(est) / est_sd:.0f} standard deviations off zero, "
                       f"{sigma_src}; correlation {r:.4f} with it)")
        elif strip_sd is not None:
            # GNSS strip shifts the solve does not model: a move and an estimate within the scatter they make are
            # theirs (the caller names them), not an offset fixed in the camera
            continue
        elif moved and not estimated:
            offset[a] = move / k
            out.append(f"{move_text}, and the block gives no estimate of such an offset (its information with the "
                       f"rest free is singular; correlation {r:.4f} with it)")
        elif moved and abs(est - move / k) <= PP_MOVE_SIGMAS * est_sd:
            offset[a] = move / k
            out.append(f"{move_text}, and the block cannot tell the two apart (its own estimate of such an offset, "
                       f"{est:+.2f} +- {est_sd:.2f} m, fits both it and none; correlation {r:.4f} with such an offset)")
    return out, offset


def pp_gnss_names_offset(pg, cal: np.ndarray, cal_apriori: np.ndarray, cal_cov: np.ndarray) -> bool:
    """Whether ``pp_gnss_judgement`` names an offset: its plan effect is wanted (``geometry_modes.pp_gnss_coupling``
    forms ``tie_plan_ms`` only then; the solve passes this in)."""
    return bool(pp_gnss_judgement(pg, cal, cal_apriori, cal_cov)[1].any())


def _pp_gnss_reasons(pg, cal: np.ndarray, cal_apriori: np.ndarray, cal_cov: np.ndarray) -> tuple[list[str], float]:
    """``pp_gnss_judgement``'s reasons, and the predicted plan effect (m) of the offsets it names on the axes flagged:
    the tie points' RMS plan change under them, ``sqrt(o' pg.tie_plan_ms o)`` (stated after the axis that names it,
    or as its own item when both do); NaN where none is named."""
    out, offset = pp_gnss_judgement(pg, cal, cal_apriori, cal_cov)
    if not offset.any():
        return out, float("nan")
    effect = math.sqrt(max(float(offset @ pg.tie_plan_ms @ offset), 0.0))
    if math.isfinite(effect):
        what = ("the whole solution's change under it, from the normal equations: the ground's error if the offset, "
                "not the camera, moved the principal point")
        if offset.all():
            out.append(f"the two offsets together (x {offset[0]:+.2f} m, y {offset[1]:+.2f} m) move the tie points by "
                       f"{effect:.3f} m RMS in plan ({what})")
        else:
            last = max(i for i, t in enumerate(out) if t.startswith(("u0", "v0")[int(np.flatnonzero(offset)[0])]))
            out[last] += (f"; the offset named, {offset[offset != 0][0]:+.2f} m, moves the tie points by "
                          f"{effect:.3f} m RMS in plan ({what})")
            other = _other_axis_words(pg, cal, cal_apriori, cal_cov, 1 - int(np.flatnonzero(offset)[0]))
            if other:
                out.append(other)
    return out, effect


def _other_axis_words(pg, cal: np.ndarray, cal_apriori: np.ndarray, cal_cov: np.ndarray, a: int) -> str:
    """The principal point's move on the axis ``a`` (0: u0, 1: v0) that names no offset, when it moved over its
    standard deviation: a user who saw u0 move 1.9 px read a flag of v0 alone as a wrong axis (Tuniu trial)."""
    name, axis = (("u0", "x"), ("v0", "y"))[a]
    move, sd = _pp_move(cal, cal_apriori, cal_cov, name)
    if not (sd > 0 and abs(move) > sd):
        return ""
    text = f"{name} moved {move:+.1f} px ({abs(move) / sd:.1f} standard deviations)"
    strip_sd = strip_shift_test(pg)  # the sigma the judgement took (with the strips' scatter where they disagree)
    k, est = float(pg.px_per_m[a, a]), float(pg.offset_estimate_m[a])
    est_sd = float(pg.offset_sigma_m[a] if strip_sd is None else strip_sd[a])
    if k != 0 and math.isfinite(est) and math.isfinite(est_sd) and est_sd > 0:
        text += (f", which a GNSS offset of {move / k:+.2f} m along the camera's {axis} axis would explain; the "
                 f"block's own estimate of one is {est:+.2f} +- {est_sd:.2f} m")
        if abs(est - move / k) > PP_MOVE_SIGMAS * est_sd and abs(est) <= PP_MOVE_SIGMAS * est_sd:
            text += ": no offset there, the move is the camera's own"
    return text


def _strip_shift_fields(pg, flags: list[str]) -> dict | None:
    """``GroupCheck.gnss_strip_shifts`` where the flag names GNSS strip shifts (``_strip_shift_reason``), else None
    (m, camera x and y): the per-strip offsets and their sigmas, the chi-square against one offset and its degrees of
    freedom, the shift per strip's standard deviation (``strip_tau_m``), the one offset and its sigma with it."""
    if not any(t.startswith("GNSS strip shifts") for t in flags):
        return None
    r = lambda v: round(float(v), 4)  # noqa: E731
    return {"strip_offset_m": [[r(x) for x in row] for row in np.asarray(pg.strip_offset_m, dtype=float)],
            "strip_offset_sigma_m": [[r(x) for x in row] for row in np.asarray(pg.strip_offset_sigma_m, dtype=float)],
            "chi2": round(float(pg.strip_chi2), 2), "dof": int(pg.strip_dof),
            "shift_sigma_m": [r(x) for x in pg.strip_tau_m], "offset_m": [r(x) for x in pg.offset_estimate_m],
            "offset_sigma_m": [r(x) for x in strip_shift_test(pg)], "n_strips": len(pg.strip_offset_m)}


def _pp_gnss_fields(pg, pp_move_px: np.ndarray) -> dict:
    """``GroupCheck``'s fields of the principal point against the GNSS (plain tuples, None for NaN); ``pp_move_px``
    (u0, v0) its estimate less its a-priori value."""
    fin = lambda v: tuple(float(x) if math.isfinite(x) else None for x in v)  # noqa: E731
    shifts = fin(pg.shift_correlation) if np.isfinite(pg.shift_correlation).any() else None
    from_pp = (tuple(fin(v) for v in pg.shift_per_pp_m @ np.asarray(pp_move_px, dtype=float))
               if len(pg.shift_per_pp_m) else None)
    return dict(gnss_offset_px_per_m=(float(pg.px_per_m[0, 0]), float(pg.px_per_m[1, 1])),
                gnss_offset_correlation=fin(pg.offset_correlation), gnss_shift_correlation=shifts,
                orientation_correlation=fin(pg.orientation_correlation),
                gnss_offset_estimate_m=fin(pg.offset_estimate_m), gnss_offset_estimate_sigma_m=fin(pg.offset_sigma_m),
                gnss_shift_from_pp_m=from_pp)


def check_groups(cc: CalibrationCovariance, groups, cal: np.ndarray, cal_apriori: np.ndarray, *, width: int,
                 height: int, ground: GroundObservations) -> list[GroupCheck]:
    """The ``GroupCheck`` of every estimated group (``groups``) at a solution with calibration ``cal`` and its
    ``CalibrationCovariance``; ``ground``: ``ground_observations`` of the block."""
    free = {g: [CAL_NAMES.index(p) for p in GROUP_PARAMETERS[g]] for g in groups}
    f = 0.5 * (cal[0] + cal[1])
    out = []
    for g in groups:
        others = [i for h in groups if h != g for i in free[h]]
        corr = {m: _partial_correlation(cc, m, free[g], others) for m in REPORTED_WITH[g]}
        observed = {m: bool(getattr(ground, _MODE_GROUND[m])) for m in corr}
        sig_px = corner_sigma_px(g, cal, cc.cal_cov, width, height)
        frac = sig_px / f
        reasons = []
        for m in CONFOUNDED_WITH[g]:
            r = corr[m]
            if not observed[m] and math.isfinite(r) and r > CORRELATION_LIMIT:
                reasons.append(f"correlation {r:.3f} with {MODE_NAMES[m]} (limit {CORRELATION_LIMIT:g}), which "
                               f"{_UNOBSERVED_BY[_MODE_GROUND[m]]} observes")
        # the principal point against the GNSS's systematic errors, with or without control: the estimate kept
        # (fixed, the offset would go into the frames' attitudes alike) and flagged as a calibration not to reuse;
        # on flat ground not a weakness of the solution (review 12a: the check points with a 0.7 m lag match the
        # block without it within 3 mm, whichever of the two took the offset); with relief the report judges the
        # predicted plan effect (``gnss_offset_plan_effect_m``) against its plan limit (pp-relief, pp-predictor)
        flags, plan_effect_m = (_pp_gnss_reasons(cc.pp_gnss, cal, cal_apriori, cc.cal_cov)
                                if g == "pp" and cc.pp_gnss is not None else ([], float("nan")))
        focal = None
        if g == "focal":  # judged by what determines it (``_focal_reasons``), its sigma test among them
            w = np.zeros(len(CAL_NAMES))
            w[free[g]] = 1.0 / len(free[g])
            focal = (float(np.sqrt(max(w @ cc.cal_cov @ w, 0.0))) / f, cc.focal_gnss_height_px / f,
                     cc.focal_image_field_px / f)
            reasons += _focal_reasons(*focal)
        elif not math.isfinite(frac) or frac > SIGMA_LIMIT_FRACTION:
            reasons.append(f"its standard deviation moves the image corner by {sig_px:.1f} px, {100 * frac:.2f} % of "
                           f"the focal length (limit {100 * SIGMA_LIMIT_FRACTION:g} %)")
        strips = _strip_shift_fields(cc.pp_gnss, flags) if g == "pp" and cc.pp_gnss is not None else None
        names = GROUP_PARAMETERS[g]
        sd = np.sqrt(np.clip(np.diag(cc.cal_cov), 0.0, None))
        out.append(GroupCheck(
            group=g, estimate={n: float(cal[CAL_NAMES.index(n)]) for n in names},
            apriori={n: float(cal_apriori[CAL_NAMES.index(n)]) for n in names},
            sigma={n: float(sd[CAL_NAMES.index(n)]) for n in names}, corner_sigma_px=sig_px,
            corner_sigma_fraction=frac, correlations=corr, ground_observed=observed,
            determinable=not (reasons or flags), reason="; ".join(reasons or flags) or None,
            action="fixed" if reasons else "flagged" if flags else "estimated",
            **(_pp_gnss_fields(cc.pp_gnss, [cal[CAL_NAMES.index(n)] - cal_apriori[CAL_NAMES.index(n)]
                                            for n in ("u0_px", "v0_px")])
               if g == "pp" and cc.pp_gnss is not None else {}),
            **(dict(gnss_offset_plan_effect_m=plan_effect_m) if flags and math.isfinite(plan_effect_m) else {}),
            **(dict(gnss_strip_shifts=strips) if strips else {}),
            **(dict(zip(("sigma_fraction", "gnss_height_fraction", "image_field_fraction"), focal)) if focal else {})))
    return out
