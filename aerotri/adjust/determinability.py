"""Can the block determine the self-calibration it was asked for? A rule from the covariance, per group.

A converged solve with a small sigma naught says nothing about whether the focal length or the principal
point were determined by the block or merely moved with something nothing else fixes. Each estimated group
is judged at the solution by two tests (``CalibrationCovariance`` of ``geometry_modes``):

1. **Confounded with a mode nothing on the ground observes.** The partial correlation of the group's
   parameters with a mode of the tie points, the other estimated groups held (the multiple correlation of
   the mode with the group after the other groups' share is taken out), over ``CORRELATION_LIMIT``, while no
   observation of the ground fixes that mode:

   - focal length <-> the block height (flat terrain, near-nadir frames and a datum from GNSS alone:
     the focal length and the flying height above the ground are confounded; only the GNSS heights'
     frame-to-frame differences and the images' tilts separate them, and any error in those goes into
     the focal length; the Brighton Beach drone block: +34 % focal, tie points 10.5 m below the DEM with a
     reported focal sigma of 0.5 %);
   - radial distortion <-> the block height (a drone's wide-angle frames: on Brighton Beach without a DEM
     the radial terms, correlation 0.93-0.96 with the height, took the tie points 2.9 m below the DEM even
     with the focal length held at the DEM solution's value); its correlation with the block's bending (the
     classic dome of a GNSS-only block) is reported, not judged: it is high wherever nothing observes the
     bending (0.97 on a simulated block flown at two heights) while the bending itself stays small;
   - principal point and decentring distortion <-> the tie points' mean plan position (with the projection
     centres fixed by GNSS a principal-point offset is a common rotation of the frames, which moves the
     ground in plan).

   The height and the bending are observed on the ground by control points with a height (full or height
   kind, in use) and by a DEM (surface control); the plan position by control points with plan
   coordinates. With those in the block the correlation is harmless: the ground fixes the mode and the
   parameter through it (4 full control points: correlation 0.95 with the height, focal within 1.5 sigma of
   the truth on simulated blocks).

   Groups that share a mode are also judged together: their joint multiple correlation with it over the
   limit fixes the group of the largest correlation of its own (``_jointly_confounded``; the focal length and
   the radial distortion both scale the image radius, and holding one hides the pair).

2. **Too loose to matter.** The group's standard deviation moves the image corner by more than
   ``SIGMA_LIMIT_FRACTION`` of the focal length (that fraction of the flying height on the ground).

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

CORRELATION_LIMIT = 0.9
SIGMA_LIMIT_FRACTION = 0.01
# per group: its Cal3DS2 entries' names, and the modes it can be confounded with (what observes them)
GROUP_PARAMETERS = {"focal": ("fx_px", "fy_px"), "pp": ("u0_px", "v0_px"), "radial": ("k1", "k2"),
                    "tangential": ("p1", "p2")}
CONFOUNDED_WITH = {"focal": ("height",), "pp": PLAN_MODES, "tangential": PLAN_MODES, "radial": ("height",)}
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
    action: str  # "estimated", or "fixed" (at its a-priori value, solved again without it)


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


def _jointly_confounded(cc: CalibrationCovariance, free: dict, ground: GroundObservations) -> dict:
    """group -> reason, for a mode nothing on the ground observes that the estimated groups *together* follow
    (multiple correlation over ``CORRELATION_LIMIT``) while each passes alone with the others held: the focal
    length and the radial distortion both scale the image radius, so holding one hides what the pair does with
    the block height (Brighton Beach without a DEM: focal | radial 0.72, both together 0.90, the focal length
    21 % off). The group of the largest correlation of its own with the mode is the one fixed."""
    out = {}
    for m in MODES:
        if bool(getattr(ground, _MODE_GROUND[m])):
            continue
        groups = [g for g in free if m in CONFOUNDED_WITH[g]]
        if len(groups) < 2:
            continue
        r = _partial_correlation(cc, m, [i for g in free for i in free[g]], [])
        if not (math.isfinite(r) and r > CORRELATION_LIMIT):
            continue
        alone = {g: _partial_correlation(cc, m, free[g], []) for g in groups}
        g = max(alone, key=lambda k: alone[k] if math.isfinite(alone[k]) else -1.0)
        out[g] = (f"correlation {r:.3f} of the estimated groups together ({', '.join(free)}) with {MODE_NAMES[m]} "
                  f"(limit {CORRELATION_LIMIT:g}; {g} alone {alone[g]:.3f}), which {_UNOBSERVED_BY[_MODE_GROUND[m]]} "
                  f"observes")
    return out


def check_groups(cc: CalibrationCovariance, groups, cal: np.ndarray, cal_apriori: np.ndarray, *, width: int,
                 height: int, ground: GroundObservations) -> list[GroupCheck]:
    """The ``GroupCheck`` of every estimated group (``groups``) at a solution with calibration ``cal`` and its
    ``CalibrationCovariance``; ``ground``: ``ground_observations`` of the block."""
    free = {g: [CAL_NAMES.index(p) for p in GROUP_PARAMETERS[g]] for g in groups}
    f = 0.5 * (cal[0] + cal[1])
    out = []
    joint = _jointly_confounded(cc, free, ground)
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
        if not math.isfinite(frac) or frac > SIGMA_LIMIT_FRACTION:
            reasons.append(f"its standard deviation moves the image corner by {sig_px:.1f} px, {100 * frac:.2f} % of "
                           f"the focal length (limit {100 * SIGMA_LIMIT_FRACTION:g} %)")
        if g in joint and not reasons:
            reasons.append(joint[g])
        names = GROUP_PARAMETERS[g]
        sd = np.sqrt(np.clip(np.diag(cc.cal_cov), 0.0, None))
        out.append(GroupCheck(
            group=g, estimate={n: float(cal[CAL_NAMES.index(n)]) for n in names},
            apriori={n: float(cal_apriori[CAL_NAMES.index(n)]) for n in names},
            sigma={n: float(sd[CAL_NAMES.index(n)]) for n in names}, corner_sigma_px=sig_px,
            corner_sigma_fraction=frac, correlations=corr, ground_observed=observed, determinable=not reasons,
            reason="; ".join(reasons) or None, action="estimated" if not reasons else "fixed"))
    return out
