"""GNSS residuals by flight direction: the signature of a GNSS/camera time lag or a lever-arm error.

A lag between the exposure and the GNSS epoch given to it shifts every position along the track by ground speed x
lag, with the sign of the heading; a lever-arm (or boresight) error in the body frame moves with the heading too.
In a fixed map axis both flip between opposite flight directions, and a receiver offset common to the flight does
not. So per flight direction (the strips' headings from their first to last frame; strips within 30 deg of one
axis, the two senses paired) the photos' GNSS discrepancies (adjusted antenna minus GNSS, local east / north / up,
metres, before any strip or flight correction of the solve: a per-strip shift would absorb the lag) are resolved
along track (positive: ahead in that direction's own heading) and across track (positive: to its right). The sum
of the two directions' means in their own axes is the part that turns with the heading (a common offset cancels):
tested against its standard error at ``DIRECTION_ALPHA`` two-sided, Bonferroni over the block's tests. GNSS errors
are shared within a strip (a bias per strip: the simulator's default sigma is 0.3 m), so the strips are the
replicates: each direction's mean is its strip means' unweighted average, its variance the strips' spread about it
(pooled over the pair, strips - 2 degrees of freedom, Student's t) / its strips, never below its photos' scatter /
photos (the photos' scatter alone
alarmed on 6 of 20 sound 8 x 25 blocks with 0.02 m strip biases). One strip each way cannot tell a strip's bias
from a direction effect: such a pair is reported as not separable and not tested (nor counted in the Bonferroni
correction). (Were the photos' scatter used,
Student's t with the Welch-Satterthwaite degrees of freedom of the photos judges it.) On simulated blocks (bench/eval_gnss_direction.py, 20 seeds each) it raised no
alarm without a lag and the camera known, and 18 of 20 when camera.toml's principal point was 0.015 mm off along
the flight axis and not estimated: that error flips with the heading as well (a boresight pitch, in effect).

The residuals show only the part of a lag the images resolve: a strip's frames shifted along the track and pitched
by shift / height keep their rays on flat ground, so the adjustment takes much of the offset into the pitch (on a
simulated 3 x 6 DMC block at 1,000 m, 60 m of relief, 0.05 m GNSS: 20-29 % of a lag of 0.004 or 0.01 s at 70 m/s
was left in the residuals, 20 seeds) and nearly all of it into a principal point estimated on the flight axis (the
camera turns with the heading). The lag stated is therefore a lower bound, far below the lag when "pp" is
self-calibrated (the report says so).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.adjust.graph import gnss_observed
from aerotri.adjust.variance_components import antenna_positions
from aerotri.core.quantiles import norm_isf, t_isf

DIRECTION_ALPHA = 0.05  # family-wise false alarm rate of the check (the brief's 95 % level)
AXIS_TOLERANCE_DEG = 30.0  # strips whose headings are within this of one axis (either sense) share it
MIN_PHOTOS = 3  # per direction: fewer give no scatter to judge the mean by


@dataclasses.dataclass(frozen=True)
class DirectionMean:
    """The GNSS discrepancies of one flight direction: mean along / across track (m) with standard errors."""

    heading_deg: float  # mean heading of the direction's strips, from north (local frame), clockwise
    strips: tuple  # 1-based
    n_photos: int
    along_m: float  # + ahead (in this direction's heading): adjusted antenna ahead of the GNSS position
    along_se_m: float
    across_m: float  # + right of the track
    across_se_m: float
    along_scatter_var_m2: float = 0.0  # the photos' scatter's share of along_se_m^2 (n - 1 degrees of freedom)
    across_scatter_var_m2: float = 0.0
    strip_along_m: tuple = ()  # each strip's mean (the replicates: GNSS errors are shared within a strip)
    strip_across_m: tuple = ()


@dataclasses.dataclass(frozen=True)
class DirectionPair:
    """Two opposite directions: the discrepancy that turns with the heading (sum of their own-axis means, m) and its
    standard error; ``lag_s`` when significant and the ground speed is known."""

    forward: DirectionMean
    backward: DirectionMean
    along_turning_m: float  # forward.along + backward.along: 2 x the along-track offset that turns with heading
    along_sigma_m: float
    across_turning_m: float
    across_sigma_m: float
    along_significant: bool
    across_significant: bool
    lag_s: float | None  # the GNSS positions' epoch minus the exposure (s): + the positions taken late
    lag_sigma_s: float | None
    k_along: float = 0.0  # the critical values (standard errors): Student t of the Welch degrees of freedom
    k_across: float = 0.0
    separable: bool = True  # False: one strip each way, a strip's GNSS bias is the direction's mean (not tested)
    strip_dof: int = 0  # degrees of freedom of the strip means' spread (strips - 2; 0: the photos' scatter)


@dataclasses.dataclass(frozen=True)
class DirectionCheck:
    """The check's result: ``testable`` False with ``reason`` (one flight direction, too few photos), else the pairs
    of opposite directions and ``k`` the largest of their critical values (standard errors)."""

    testable: bool
    reason: str
    directions: tuple  # DirectionMean, every direction found
    pairs: tuple  # DirectionPair
    k: float
    speed_mps: float | None
    speed_source: str
    base_m: float  # median spacing of consecutive frames in a strip (m)
    pp_estimated: bool = False  # the principal point self-calibrated: it may take up an along-track flip
    # the share of a GNSS offset fixed in the camera the self-calibrated principal point takes (its px per m times the
    # tie points' depth over the focal length: ``geometry_modes.PrincipalPointGnss``); None: not computed
    pp_share: float | None = None

    def blind_note(self) -> str:
        """Why the along-track test may miss a lag (or understate it): the images absorb it."""
        share = "" if self.pp_share is None else f"; here it takes {100 * self.pp_share:.0f} % of such an offset"
        if self.pp_estimated and (self.pp_share is None or self.pp_share >= 0.5):
            return ("the principal point is self-calibrated: it takes up most of an along-track offset that flips "
                    "with the flight direction (the camera turns with the heading; on simulated blocks 1-4 % of a lag "
                    f"stayed in the residuals{share}), so a lag may be far larger than the residuals show")
        if self.pp_estimated:  # a wide field of view tells the principal point from a rotation: the attitudes take it
            return (f"the principal point is self-calibrated but takes only {100 * self.pp_share:.1f} % of such an "
                    "offset here (the frames' perspective tells it from a rotation of the frame); the residuals show "
                    "the part of an along-track offset the images tell from the photos' pitch: a lag may be larger "
                    "than the residuals say")
        return ("the residuals show only the part of an along-track offset the images tell from the photos' pitch "
                "(on flat ground none of it): a lag may be larger than the residuals say")

    def not_separable(self) -> list[str]:
        """One sentence per pair flown one strip each way (not tested: the verdict is left alone)."""
        return [f"strip {_strips(p.forward)} heading {heading_text(p.forward.heading_deg)} deg against strip "
                f"{_strips(p.backward)} heading {heading_text(p.backward.heading_deg)} deg: a direction effect (time "
                f"lag, lever arm) is not separable from the strips' own GNSS biases with one strip each way (not tested)"
                for p in self.pairs if not p.separable]

    @property
    def significant(self) -> bool:
        return any(p.along_significant or p.across_significant for p in self.pairs)

    def findings(self) -> list[str]:
        """One sentence per significant pair, stating the lag it equals and the alternative."""
        out = []
        for p in self.pairs:
            if not (p.along_significant or p.across_significant):
                continue
            f, b = p.forward, p.backward
            head = (f"GNSS residuals flip with the flight direction (strips {_strips(f)} heading "
                    f"{heading_text(f.heading_deg)} deg against {_strips(b)} heading {heading_text(b.heading_deg)} deg)")
            parts = []
            if p.along_significant:
                ahead = -p.along_turning_m / 2  # GNSS ahead of the adjusted antenna, in each direction's heading
                lag = (f"a time lag of {p.lag_s:+.3f} +- {p.lag_sigma_s:.3f} s (GNSS epoch after the exposure when "
                       f"positive) at {self.speed_mps:.1f} m/s ({self.speed_source})" if p.lag_s is not None else
                       f"a time lag of {ahead:+.3f} m / ground speed ({self.speed_source})")
                parts.append(f"along track {p.along_turning_m:+.3f} +- {p.along_sigma_m:.3f} m "
                             f"({abs(p.along_turning_m) / p.along_sigma_m:.1f} sigma): the GNSS positions "
                             f"{abs(ahead):.3f} m {'ahead of' if ahead > 0 else 'behind'} the projection centres in "
                             f"both directions, {lag}, or a lever-arm error of {ahead:+.3f} m along the camera's "
                             f"flight axis, or a boresight pitch (or principal point) error along it")
            if p.across_significant:
                right = -p.across_turning_m / 2
                parts.append(f"across track {p.across_turning_m:+.3f} +- {p.across_sigma_m:.3f} m "
                             f"({abs(p.across_turning_m) / p.across_sigma_m:.1f} sigma): the GNSS positions "
                             f"{abs(right):.3f} m to the {'right' if right > 0 else 'left'} of the track in both "
                             f"directions, a lever-arm error across the camera (or a boresight roll)")
            out.append(head + ": " + "; ".join(parts) + ". Which of these it is the block cannot tell: check the "
                       "exposure event timing and the lever arm ([gnss] lever_arm_m)"
                       + (f"; {self.blind_note()}." if p.along_significant else "."))
        return out


def _strips(d: DirectionMean) -> str:
    return ", ".join(str(s) for s in d.strips)


def heading_text(heading_deg: float) -> str:
    """A heading in whole degrees, 0-359 (359.6 is "0", not "360")."""
    return f"{round(heading_deg) % 360:d}"


def _heading_deg(v) -> float:
    """Heading of ``v`` (east, north) from north, clockwise, in [0, 360) at 0.1 deg (359.96 was kept as 360.0 and
    shown as "360", trial-ew)."""
    return round(float(np.degrees(np.arctan2(v[0], v[1])) % 360.0), 1) % 360.0


def direction_check(block, state, speed_mps: float | None = None, alpha: float = DIRECTION_ALPHA,
                    self_calibration=(), strip_shift_sigma_m: float = 0.0, pp_share: float | None = None
                    ) -> DirectionCheck | None:
    """``DirectionCheck`` of an adjusted block with GNSS (None without): ``block`` a ``graph.Block`` (positions in
    flight order, local ENU metres), ``state`` the adjusted ``graph.State``; ``speed_mps`` the ground speed
    ([flight] speed_mps; None: the lag is stated per unit speed); ``self_calibration`` the groups estimated
    (``pp_share``: the share of a camera-fixed offset the principal point takes, ``DirectionCheck.pp_share``);
    ``strip_shift_sigma_m`` the a-priori sigma of a strip's GNSS shift when the solve estimates one per strip
    (``gnss_shift_sigma_m``): the strips then differ by such shifts, so a direction's mean varies by it over
    sqrt(its strips) besides the photos' scatter (without it a sound block with 0.05 m shifts was flagged)."""
    g = block.gnss_local
    if g is None:
        return None
    g = np.asarray(g, dtype=float)
    # adjusted antenna minus GNSS without the solve's shift/drift/offset: a per-strip shift would take the lag in
    v = np.asarray(antenna_positions(block, state), dtype=float) - g
    strip = np.asarray(block.strip, dtype=int)
    # a position left out (an infinite sigma) is no evidence of a lag
    sig = getattr(block, "gnss_sigma_m", None)
    used = gnss_observed(sig) if sig is not None else np.ones(len(g), dtype=bool)
    units, bases = [], []
    for s in np.unique(strip):
        idx = np.flatnonzero((strip == s) & used)
        if len(idx) < 2:
            continue
        d = g[idx[-1], :2] - g[idx[0], :2]
        if np.linalg.norm(d) <= 0:
            continue
        units.append((int(s), idx, d / np.linalg.norm(d)))
        bases.extend(np.hypot(*np.diff(g[idx, :2], axis=0).T))
    base_m = float(np.median(bases)) if bases else float("nan")
    speed_source = ("[flight] speed_mps" if speed_mps else
                    f"no ground speed: the project holds no exposure times and no [flight] speed_mps; the frames are "
                    f"{base_m:.1f} m apart, so speed = {base_m:.1f} m / the frame interval")
    # axes: the first strip's heading (either sense) gathers the strips within AXIS_TOLERANCE_DEG of it, and so on
    axes = []  # [reference unit, [(strip, idx, unit, sense)]]
    for s, idx, u in units:
        for ax in axes:
            c = float(u @ ax[0])
            if abs(c) >= math.cos(math.radians(AXIS_TOLERANCE_DEG)):
                ax[1].append((s, idx, u, 1 if c > 0 else -1))
                break
        else:
            axes.append([u, [(s, idx, u, 1)]])

    def mean_of(members) -> DirectionMean | None:
        idx = np.concatenate([m[1] for m in members]) if members else np.zeros(0, dtype=int)
        if len(idx) < MIN_PHOTOS:
            return None
        h = np.mean([m[2] for m in members], axis=0)
        h = h / (np.linalg.norm(h) or 1.0)
        right = np.array([h[1], -h[0]])
        a, c = v[idx, :2] @ h, v[idx, :2] @ right
        n, between = len(idx), strip_shift_sigma_m**2 / len(members)
        va, vc = float(a.var(ddof=1)) / n, float(c.var(ddof=1)) / n
        return DirectionMean(_heading_deg(h), tuple(m[0] + 1 for m in members), n, float(a.mean()),
                             math.sqrt(va + between), float(c.mean()), math.sqrt(vc + between), va, vc,
                             tuple(float((v[m[1], :2] @ h).mean()) for m in members),
                             tuple(float((v[m[1], :2] @ right).mean()) for m in members))

    def by_strips(fw: DirectionMean, bw: DirectionMean):
        """The two means with standard errors from their strips' spread (pooled within each direction, strips - 2
        degrees of freedom), never below the photos' scatter (and the a-priori shifts); None: one strip each way."""
        dof = len(fw.strips) + len(bw.strips) - 2
        if dof < 1:
            return None
        pooled = [sum(float(np.sum((np.asarray(x) - np.mean(x)) ** 2)) for x in (getattr(fw, key), getattr(bw, key)))
                  / dof for key in ("strip_along_m", "strip_across_m")]
        # each mean the strip means' unweighted average, as the strips' spread / strips is its variance (a mean
        # weighted by photos over strips of 60/6/6/6 frames rested on one strip: 14 % false alarms at 5 %)
        out = [dataclasses.replace(d, along_m=float(np.mean(d.strip_along_m)), across_m=float(np.mean(d.strip_across_m)),
                                   along_se_m=max(d.along_se_m, math.sqrt(pooled[0] / len(d.strips))),
                                   across_se_m=max(d.across_se_m, math.sqrt(pooled[1] / len(d.strips))))
               for d in (fw, bw)]
        return out[0], out[1], dof

    def critical(m: int, *parts) -> float:
        """t quantile for the sum's standard error: ``parts`` (scatter variance, photos) of the two means, the strip
        shifts' share known a priori (infinite degrees of freedom)."""
        total = sum(m_.along_se_m**2 if which == "a" else m_.across_se_m**2 for m_, which in parts)
        scatter = [(m_.along_scatter_var_m2 if which == "a" else m_.across_scatter_var_m2, m_.n_photos)
                   for m_, which in parts]
        den = sum(s2 * s2 / (n - 1) for s2, n in scatter)
        dof = total * total / den if den > 0 else float("inf")
        return float(t_isf(alpha / 2 / m, dof)) if math.isfinite(dof) else float(norm_isf(alpha / 2 / m))

    all_directions, raw_pairs = [], []
    for _, members in axes:
        fw = mean_of([m for m in members if m[3] > 0])
        bw = mean_of([m for m in members if m[3] < 0])
        all_directions += [d for d in (fw, bw) if d is not None]
        if fw is not None and bw is not None:
            raw_pairs.append((fw, bw))
    # Bonferroni over the tests made: a pair flown one strip each way is not tested, so it does not count
    n_tests = max(2 * sum(len(fw.strips) + len(bw.strips) > 2 for fw, bw in raw_pairs), 1)
    pairs, directions = [], []
    for fw0, bw0 in raw_pairs:
        # GNSS errors are shared within a strip (a receiver's bias per strip): the strips, not the photos, are the
        # replicates of a direction's mean (the photos' scatter / n alarmed on 6 of 20 sound 8 x 25 blocks with
        # 0.02 m strip biases); one strip each way cannot tell a strip's bias from the direction's
        split = by_strips(fw0, bw0)
        fw, bw, dof = split if split else (fw0, bw0, 0)
        directions += [fw, bw]
        at, asg = fw.along_m + bw.along_m, math.hypot(fw.along_se_m, bw.along_se_m)
        ct, csg = fw.across_m + bw.across_m, math.hypot(fw.across_se_m, bw.across_se_m)
        if split:  # conservative: the strips' spread's degrees of freedom whichever term the floor kept
            ka = kc = float(t_isf(alpha / 2 / n_tests, dof))
        else:
            ka, kc = critical(n_tests, (fw, "a"), (bw, "a")), critical(n_tests, (fw, "c"), (bw, "c"))
        a_sig, c_sig = bool(split) and abs(at) > ka * asg, bool(split) and abs(ct) > kc * csg
        lag = lag_sigma = None
        if speed_mps:
            # adjusted antenna behind the GNSS position by v x lag when the GNSS epoch is lag s after the exposure
            lag, lag_sigma = -at / (2 * speed_mps), asg / (2 * speed_mps)
        pairs.append(DirectionPair(fw, bw, at, asg, ct, csg, bool(a_sig), bool(c_sig), lag, lag_sigma, ka, kc,
                                   bool(split), dof))
    paired = {id(d) for pair in raw_pairs for d in pair}
    directions += [d for d in all_directions if id(d) not in paired]
    k = max([max(p.k_along, p.k_across) for p in pairs], default=float(norm_isf(alpha / 2 / n_tests)))
    if not all_directions:
        reason = "not testable: too few photos with GNSS in a strip"
    elif not pairs:
        reason = ("not testable: one flight direction" if len(all_directions) == 1 or len(axes) == len(all_directions)
                  else "not testable: no two opposite directions with photos enough")
    else:
        reason = ""
    return DirectionCheck(bool(pairs), reason, tuple(directions), tuple(pairs), round(k, 2), speed_mps or None,
                          speed_source, base_m, "pp" in tuple(self_calibration),
                          pp_share if "pp" in tuple(self_calibration) else None)
