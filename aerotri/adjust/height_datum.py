"""Does the height control the data snooping left in still hold the block's heights? (at-verdicts, issue 1)

With GNSS the block's heights are the GNSS's; the control points with a height are what checks them. When the data
snooping leaves some of them out, those left must still be able to see the GNSS heights' systematic error, or the
solution's heights are the GNSS's unchecked (a simulated DMC block over 120 m of relief with its gnss.txt heights
1 m low: 5 of 6 height control left out, the one left 3.8 of its sigmas off and kept, no check points, "Solution
Successful" with the ground 1.16-1.17 m low against a 1 m height limit).

The GNSS heights' systematic error is modelled as a plane over the block, ``dz = a + b xi + c eta`` (``xi, eta``
the GNSS positions' plan coordinates about their centre over the block's radius: ``b``, ``c`` metres at its edge):
a common offset (height datum, antenna height, lever arm) and a tilt (a trajectory's error across the flight), the
datum classical aerial triangulation needs three height points not on a line for. It is added to the solution's
normal equations (one Gauss-Newton step, its Schur complement against everything else: the images, the control
left in, a DEM, the GNSS's own shifts) and gives

- ``corner_sigma_m``: the plane's largest standard deviation at a projection centre (the block's far corners):
  how well what is left determines the GNSS heights' error there (infinite where it cannot: one height point, or
  points on a line);
- ``estimate_m``: the plane's estimate at the same corner, and ``chi2`` of the whole plane against zero.

The heights are not held when the smallest such error the control left would detect (``MDB_SIGMAS`` times
``corner_sigma_m``: the data snooping's own critical value plus the 80 % power quantile, Baarda's minimal
detectable bias) exceeds the height RMS limit, or when the plane itself is significant (``chi2`` beyond the
snooping's alpha, as many degrees of freedom as terms judged): the GNSS heights disagree with the control left.

With a GNSS correction estimated (``gnss_correction`` shift, shift_drift, offset) the GNSS heights' datum error is
the correction's, and the control carries the datum (the geometry modes judge whether it can): only the part of the
plane the correction cannot take is judged (s29-fixes: the offset, and the tilt across parallel strips, are a
shift's; the tilt along them a drift's too). Judged is each direction of the plane of which more than
``SURVIVING_SHARE`` survives the correction (weighted least squares over the GNSS heights); none: no plane. Before,
the plane's offset was the correction's too, the plane singular, and every such block with one control height
left out was "weak" ("one point, or points on a line": 18 of 18 simulated blocks, and the demo with one height
typed 1 m off).

Under a correction per strip (shift, shift_drift) the GNSS heights are free per strip and the control left carries
the heights alone (s32-fixes, review 32): each strip's vertical correction is judged by its standard deviation at the
strip's worse end (``strip_sigma_m``: not held when its MDB exceeds the height limit), and, with more than one point
left out (the data snooping, one blunder at a time, may have left out right ones and kept mistyped ones), so is each
control height kept, by Baarda's internal reliability (at-reliability, review 35): a kept mistyped height would have
been found when its minimal detectable bias ``MDB_i = lambda sigma_i / sqrt(r_i)`` (``sigma_i`` its given height
sigma, ``r_i = 1 - Q_ii / sigma_i^2`` its redundancy number, ``Q_ii`` its adjusted height's unit-weight variance from
the solution's reduced covariance) is within the height limit; one that holds its strip alone (``r_i`` 0.004-0.05,
MDB 1.2-4 m) is not (``kept_mdb_m``, ``kept_unchecked``). Nor are two kept heights mistyped together in one strip,
which its shift and drift take together and the one-at-a-time tests miss whatever each point's MDB (review 35's kept
typos: single MDBs 0.6-1.0 m): the smallest bias of both some test would find (``pair_mdb_m``) must be within
``PAIR_MDB_FACTOR`` times the limit (``pairs_unchecked``). Every kept height and pair so checked, the snooping's
choice stands, whatever the signs of the points out (the sign rule before, ``out_agree``, called "weak" blocks whose
snooping rightly left out two heights typed the same way: review 35). One point out is the snooping's usual find and not
judged so: with 6 control heights under a shift and drift per strip the heights kept have MDBs of 0.7-1.7 m, and
the rule called 18 of 18 such blocks weak whose one mistyped height was rightly left out (s29-fixes' family).
With none or one control height out (any correction; at-noout) a kept height whose MDB exceeds
``ALONE_MDB_FACTOR`` times the limit is one no other observation checks (3 full control under a shift and drift per
strip: MDBs 5-54 m, "Successful" before, the check not run with nothing out), and the heights are unchecked.
``Q`` leaves out a DEM's considered systematic error (``surface_bias``; a DEM only adds redundancy) and a full
control point's plan (heights only); pairs are judged while the covariance between the points is formed
(``JOINT_COLS_MAX``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.adjust import graph as G
from aerotri.adjust.variance_components import gnss_rows
from aerotri.core.quantiles import chi2_isf, norm_isf, norm_ppf

POWER = 0.8  # Baarda's detection power: the minimal detectable bias is (critical value + this quantile) sigmas
# a plane direction of which less survives the GNSS correction is the correction's (a tilt across parallel strips
# under a shift per strip survives at the flight lines' wander over the block's radius, about 1 %; an along-strip
# tilt under one offset at about 50 %): a fixed order-of-magnitude cut between the two, not fitted to any block
SURVIVING_SHARE = 0.1
COLLINEAR_SHARE = 0.05  # control points whose plan spread across their line is below this share of it: on a line
# check points with a height decide the heights instead of the rule only when they spread over the block: their plan
# positions on the block's principal directions, each scaled by the spread of points uniform over the block's extent
# there, must spread at least this much in their narrowest direction (the square root of the smaller eigenvalue of
# that scaled covariance; uniform over the projection centres' area about 1, a line or a corner cluster near 0).
# Chosen on seeds 0-5 of bench/eval_check_spread.py (the smallest cut at which at most one subset reads the block's
# RMS Z less than half while all 20 check points decide in every seed), scored on 6-11 (review 36: a per-axis share
# 0.2 let 3 check points in a corner decide; review 38: scaled by the GNSS positions' standard deviation a 2-strip
# block's evenly spread check points read 0.5-0.58 and never decided)
CHECK_SPREAD_MIN = 0.8
# the kept control heights' covariance between points (``pair_mdb_m``) only while their images' parameters are at
# most this many (100 images of 6: the entries between images that share no point take a solve each); above, each
# point's own variance alone
JOINT_COLS_MAX = 600
# a pair of kept control heights mistyped together is unchecked when the smallest such bias (each) the one-at-a-time
# tests would find exceeds this times the height limit (bench/eval_at_reliability.py, seeds 0-5: 1 called 12 of 16
# blocks whose typos were rightly out weak, 1.5 and 2 none; 2 taken, the fewer false alarms of the tie)
PAIR_MDB_FACTOR = 2.0
# with none or one control height out (the check ran only with some out before at-noout: 3 full control under a shift
# and drift per strip, MDBs 5-54 m, "Successful") a kept height nothing else checks is unchecked when its MDB exceeds
# this times the height limit: a bias there moves about its strip, one of three, a block RMS near the limit at about
# 1.7 times it (as ``PAIR_MDB_FACTOR``). bench/eval_at_noout.py seeds 0-5: the smallest factor at which no block of
# 6 or 12 full control turns weak by it (their MDBs 0.30-1.68 m; 1.5: 6 more, one height out); scored on 6-13
ALONE_MDB_FACTOR = 2.0


def _block_axes(xy: np.ndarray) -> dict:
    """The principal directions of the block's centred plan positions ``xy`` and their half extent along each (None
    and NaN for fewer than 3 positions: no plan extent to measure check points against)."""
    if len(xy) < 3:
        return dict(block_axes=None, block_half_extent_m=(math.nan, math.nan))
    _, _, vt = np.linalg.svd(xy, full_matrices=False)
    on_axes = xy @ vt.T
    return dict(block_axes=tuple(float(v) for v in vt.ravel()),
                block_half_extent_m=tuple(float(v) for v in 0.5 * np.ptp(on_axes, axis=0)))


def mdb_sigmas(alpha: float) -> float:
    """Baarda's lambda: the two-sided critical value of ``alpha`` plus the normal quantile of ``POWER`` (1e-4: 4.73)."""
    return float(norm_isf(alpha / 2.0) + norm_ppf(POWER))


@dataclasses.dataclass(frozen=True)
class HeightDatumCheck:
    """The GNSS heights' plane error (offset, tilt east, tilt north) as the control left in would determine it."""

    corner_sigma_m: float  # its largest standard deviation at a projection centre (inf: not determined)
    corner_estimate_m: float  # its estimate there (the corner of the largest sigma; NaN: not determined)
    chi2: float  # the plane's estimate against zero (3 degrees of freedom; NaN: not determined)
    alpha: float  # the data snooping's type I error
    height_control_left: tuple  # ids of the control points with a height in use
    height_control_out: tuple  # ids of those the data snooping left out
    terms: int = 3  # the plane's terms judged: 3, fewer where a GNSS correction takes the rest
    correction: str = "none"  # the solve's gnss_correction
    layout: str = "spread"  # the height control left in plan: "one point", "on a line", "spread"
    out_dz_m: tuple = ()  # the left-out points' given minus adjusted height (local up, m), as height_control_out
    # each strip's vertical GNSS correction (shift, and drift at the strip's ends) as the solution determines it:
    # (strip 1-based, its largest standard deviation at a strip end, m); empty without a correction per strip
    strip_sigma_m: tuple = ()
    block_axes: tuple | None = None  # the GNSS positions' principal directions in plan (2 x 2 flat, rows unit)
    block_half_extent_m: tuple = (math.nan, math.nan)  # their half extent along each (m)
    # each control height kept: (id, redundancy number of its height, Baarda's minimal detectable bias m); a point
    # without rays is not in the solution and not listed
    kept_mdb_m: tuple = ()
    # each pair of them typed off together (id, id, +1 same way / -1 opposite, the smallest such bias of both the
    # data snooping's one-at-a-time tests would find, m), the worst first
    pair_mdb_m: tuple = ()
    pairs_judged: bool = True  # False: the kept heights' covariance between points not formed (``JOINT_COLS_MAX``)

    def checks_spread(self, xy_m: np.ndarray) -> bool:
        """Do check points at plan positions ``xy_m`` (n, 2; metres) spread over the block: ``check_spread`` at least
        ``CHECK_SPREAD_MIN``? A corridor's check points along it decide; a line or a cluster in a corner does not."""
        return self.check_spread(xy_m) >= CHECK_SPREAD_MIN

    def check_spread(self, xy_m: np.ndarray) -> float:
        """The check points' spread in their narrowest direction, on the block's principal directions (its GNSS
        positions') each scaled by the standard deviation of points uniform over the block's extent there (half
        extent / sqrt 3): the square root of the smaller eigenvalue of that scaled covariance (points uniform over
        the projection centres' area about 1, over the ground the frames cover more; on a line 0; 0 for fewer than 3
        points or a block without a plan extent; a corridor's width taken as at least 1 % of its length)."""
        xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        half = np.asarray(self.block_half_extent_m, dtype=float)
        if len(xy) < 3 or self.block_axes is None or not np.all(np.isfinite(half)) or not half.max() > 0:
            return 0.0
        # a straight corridor has no width to scale by: its narrow side counts as 1 % of its length
        scale = np.maximum(half, 0.01 * half.max()) / math.sqrt(3.0)
        axes = np.asarray(self.block_axes, dtype=float).reshape(2, 2)  # rows: the block's principal directions
        z = ((xy - xy.mean(axis=0)) @ axes.T) / scale
        return float(math.sqrt(max(float(np.linalg.eigvalsh(z.T @ z / len(z))[0]), 0.0)))

    def strips_not_held(self, height_limit_m: float) -> tuple:
        """(strip 1-based, minimal detectable bias m) of the strips whose vertical correction the control left
        would not detect off by the height limit (``mdb_sigmas`` times its sigma at the strip's worse end)."""
        lam = mdb_sigmas(self.alpha)
        return tuple((s, lam * sd) for s, sd in self.strip_sigma_m if lam * sd > height_limit_m)

    def out_agree(self) -> bool:
        """More than one point out, all off the solution the same way: they may hold a datum the GNSS's is not."""
        return len(self.out_dz_m) > 1 and (all(d > 0 for d in self.out_dz_m) or all(d < 0 for d in self.out_dz_m))

    @property
    def mdb_m(self) -> float:
        """The smallest GNSS height error at the block's far corner the control left would detect (m)."""
        return mdb_sigmas(self.alpha) * self.corner_sigma_m

    def disagrees(self) -> bool:
        return math.isfinite(self.chi2) and self.chi2 > float(chi2_isf(self.alpha, self.terms))

    def kept_unchecked(self, height_limit_m: float) -> tuple:
        """Under a GNSS correction per strip (the GNSS heights free per strip: the control left carries the heights
        alone) with more than one control height left out, the control heights kept whose mistyping the data
        snooping would not detect within the height limit: (id, redundancy number, minimal detectable bias m) of
        those whose MDB exceeds it (a kept height that holds its strip alone; the snooping, one blunder at a time,
        may have kept it mistyped and left out right ones). Empty: every kept height is checked, and the points out
        are the snooping's choice, whatever their signs (review 35). With none or one out (any correction), those
        whose MDB exceeds ``ALONE_MDB_FACTOR`` times the limit: heights nothing else checks (at-noout)."""
        if self.judges_alone():
            return tuple(k for k in self.kept_mdb_m if not k[2] <= ALONE_MDB_FACTOR * height_limit_m)
        if not self.judges_kept():
            return ()
        return tuple(k for k in self.kept_mdb_m if not k[2] <= height_limit_m)

    def pairs_unchecked(self, height_limit_m: float) -> tuple:
        """As ``kept_unchecked``, the pairs of kept heights that, mistyped together, the one-at-a-time tests would
        not find within ``PAIR_MDB_FACTOR`` times the height limit: (id, id, +1 same way / -1 opposite, MDB m), the
        worst first (two typos kept in one strip, which its shift and drift take together: review 35)."""
        if not self.judges_kept():
            return ()
        return tuple(k for k in self.pair_mdb_m if not k[3] <= PAIR_MDB_FACTOR * height_limit_m)

    def judges_kept(self) -> bool:
        """The kept heights are judged under a correction per strip with more than one control height out."""
        return self.correction in ("shift", "shift_drift") and len(self.height_control_out) >= 2

    def judges_alone(self) -> bool:
        """The kept heights are judged by ``ALONE_MDB_FACTOR`` with none or one control height out (at-noout)."""
        return len(self.height_control_out) < 2

    def held(self, height_limit_m: float) -> bool:
        return (self.mdb_m <= height_limit_m and not self.disagrees() and not self.strips_not_held(height_limit_m)
                and not self.kept_unchecked(height_limit_m) and not self.pairs_unchecked(height_limit_m))


def height_datum_check(block: G.Block, opts: G.SolveSettings, state: G.State, rc, control_active, *, sigma0: float,
                       alpha: float, obs_active=None) -> HeightDatumCheck | None:
    """``HeightDatumCheck`` at the solution (``rc`` the unit-weight reduced covariance) when the data snooping kept
    some of the control points with a height (all out: the report's own finding); None without GNSS (the control
    alone carries the datum: the geometry modes judge it). With none out only the kept heights' reliability and the
    strips' corrections are judged (at-noout: ``corner_sigma_m`` 0, no plane). Where the GNSS
    correction takes the whole plane (shift_drift over parallel strips) only the strips' corrections are judged
    (``terms`` 0). ``obs_active``: the image observations in use (None: all), for the kept heights' redundancy."""
    if block.gnss_local is None or not len(block.control_rows):
        return None
    rows_kind = np.asarray(block.control_rows)
    active = np.asarray(control_active, dtype=bool)
    with_z = rows_kind != 2  # the constrained components: 3 full, 1 height, 2 plan only
    left, out = with_z & active, with_z & ~active
    if not left.any():
        return None
    ids = [block.point_id[j] for j in block.control_point]
    pred, rows = gnss_rows(block, opts, state)
    w = 1.0 / np.asarray(block.gnss_sigma_m, dtype=float) ** 2
    g = np.asarray(block.gnss_local, dtype=float)
    xy = g[:, :2] - g[:, :2].mean(axis=0)
    rho = max(float(np.max(np.linalg.norm(xy, axis=1))), 1e-9)
    P = np.column_stack([np.ones(len(g)), xy / rho])  # (N, 3): offset, east, north at each GNSS position
    P = beyond_correction(block, opts, P, w[:, 2])
    lo = (tuple(str(ids[c]) for c in np.flatnonzero(left)), tuple(str(ids[c]) for c in np.flatnonzero(out)))
    cl = np.asarray(block.control_local, dtype=float)
    dz = [float(cl[c, 2] - state.points[block.control_point[c]][2]) for c in np.flatnonzero(out)]
    more = dict(terms=P.shape[1], correction=opts.gnss_correction, layout=_layout(cl[np.flatnonzero(left), :2]),
                out_dz_m=tuple(dz), strip_sigma_m=_strip_sigmas(block, opts, rc, sigma0),
                **dict(zip(("kept_mdb_m", "pair_mdb_m", "pairs_judged"),
                           _kept_reliability(block, opts, state, rc, np.flatnonzero(left), obs_active, alpha))),
                **_block_axes(xy))
    if not out.any():  # nothing out: the kept heights' own reliability alone (at-noout), the plane all the control's
        return HeightDatumCheck(0.0, math.nan, math.nan, alpha, *lo, **more)
    if P.shape[1] == 0:  # the correction takes the whole plane: its strips' own sigmas alone
        return HeightDatumCheck(0.0, math.nan, math.nan, alpha, *lo, **more)
    S, grad = plane_normals(rc, P, w[:, 2], g[:, 2] - pred[:, 2], rows)
    # singular where the control left cannot fix the plane (one point, points on a line): relative to h's scale
    ev = np.linalg.eigvalsh(0.5 * (S + S.T))
    if not (ev[0] > 1e-9 * max(ev[-1], 1e-300)):
        return HeightDatumCheck(math.inf, math.nan, math.nan, alpha, *lo, **more)
    S_inv = np.linalg.inv(S)
    est = S_inv @ grad
    sd = np.sqrt(np.clip(np.einsum("na,ab,nb->n", P, S_inv, P), 0.0, None)) * sigma0
    i = int(np.argmax(sd))
    c2 = float(est @ S @ est) / sigma0**2 if sigma0 > 0 else math.nan
    return HeightDatumCheck(float(sd[i]), float(P[i] @ est), c2, alpha, *lo, **more)


def plane_normals(rc, P: np.ndarray, w_z: np.ndarray, misfit_z: np.ndarray, rows) -> tuple[np.ndarray, np.ndarray]:
    """The plane terms ``P`` (N, k) of the GNSS heights' error added to the solution's normal equations: their
    Schur complement against every other unknown (``rc`` the unit-weight reduced covariance, ``rows`` the GNSS
    positions' Jacobians of ``gnss_rows``) and their gradient at the solution (``misfit_z`` GNSS minus adjusted
    height, ``w_z`` its weight): one Gauss-Newton step estimates the terms as ``S^-1 grad``."""
    h = np.einsum("n,na,nb->ab", w_z, P, P)
    grad = P.T @ (w_z * misfit_z)
    b = np.zeros((rc.n, P.shape[1]))
    for i, row in enumerate(rows):
        for k, J in row:
            b[rc.offset[k]:rc.offset[k] + J.shape[1]] += np.outer(J[2], w_z[i] * P[i])
    return h - b.T @ rc.multiply(b), grad


def _kept_heights_cov(block: G.Block, opts: G.SolveSettings, state: G.State, rc, kept, obs_active):
    """(control indices, point ids, Q (m, m), sigma_z (m,)) of the control heights ``kept`` (control indices) that
    have rays: ``Q`` their adjusted heights' joint unit-weight covariance (local up), ``V_i^-1`` of each point's own
    normals (its rays, its given coordinates, a DEM) plus ``sum_ab g_a Sigma(a, b) g_b'`` over their rays' orientation
    (and calibration) parameters from ``rc`` (``g`` the height row of ``V^-1 W``, as ``covariance.point_covariances``
    per point); ``sigma_z`` their given height sigmas (a-priori weights: ``Q`` is at the same). Over
    ``JOINT_COLS_MAX`` orientation parameters in all, only the diagonal (each point's own images: the entries between
    images that see no common point would each take a solve with the factor), NaN between points."""
    from aerotri.adjust.covariance import point_rays

    pts = np.asarray(block.control_point, dtype=int)[kept]
    active = np.ones(len(block.obs_point), dtype=bool) if obs_active is None else np.asarray(obs_active, dtype=bool)
    mask = active & np.isin(block.obs_point, pts)  # only the kept points' rays: their covariances alone are needed
    if not mask.any():
        return kept[:0], (), np.zeros((0, 0)), np.zeros(0)
    pr = point_rays(block, state, mask, opts.image_sigma_px, rc, bool(opts.self_calibration))
    use = pr.used[pts] & np.all(np.isfinite(pr.Vinv[pts].reshape(len(pts), -1)), axis=1)
    kept, pts = np.asarray(kept)[use], pts[use]
    _, _, Gr, idx = pr.rays()
    where = {int(j): n for n, j in enumerate(pts)}
    row = np.array([where.get(int(j), -1) for j in pr.pt], dtype=int)
    Gr, idx, row = Gr[row >= 0], idx[row >= 0], row[row >= 0]
    cols = np.unique(idx)
    H = np.zeros((len(pts), len(cols)))
    np.add.at(H, (np.repeat(row, idx.shape[1]), np.searchsorted(cols, idx).ravel()), Gr[:, 2, :].ravel())
    if len(cols) <= JOINT_COLS_MAX:
        Q = H @ rc.entries(cols[:, None], cols[None, :]) @ H.T
    else:  # each point's own images only (within the covariance's computed pattern); between points unknown
        Q = np.full((len(pts), len(pts)), np.nan)
        for n in range(len(pts)):
            c = np.flatnonzero(H[n])
            Q[n, n] = H[n, c] @ rc.entries(cols[c][:, None], cols[c][None, :]) @ H[n, c]
    Q = Q + np.diag(pr.Vinv[pts, 2, 2])
    # the height's own sigma: a height-only point's loose plan sigma (1 km), rotated into the local frame, leaks into
    # its covariance's up entry (0.29 m for 0.05 m 1.7 km from the centre: review 39); the conditional one does not
    sz = 1.0 / np.sqrt(np.linalg.inv(np.asarray(block.control_cov_local, dtype=float)[kept])[:, 2, 2])
    return kept, tuple(str(block.point_id[j]) for j in pts), 0.5 * (Q + Q.T), sz


def _kept_reliability(block: G.Block, opts: G.SolveSettings, state: G.State, rc, kept, obs_active,
                      alpha: float) -> tuple[tuple, tuple, bool]:
    """Baarda's internal reliability of the control heights ``kept`` (control indices) under the data snooping's
    one-at-a-time tests (``w_k = (P v)_k / sqrt((P Q_v P)_kk)``, ``Q_v = C - Q`` the heights' residual cofactor, ``C``
    their given variances, ``Q`` their adjusted heights' covariance: ``_kept_heights_cov``):

    - each point: (id, ``r = 1 - Q_ii / sigma_i^2`` its redundancy number, ``MDB = lambda sigma_i / sqrt(r)``);
    - each pair typed off together, the same way or opposite: (id, id, +1 or -1, the smallest bias of both that some
      point's test would find with the power of ``lambda``), the worst first (a pair in one strip under a shift and
      drift per strip moves the strip and none of the tests sees it: review 35's kept typos, single MDBs 0.6-1.0 m).

    Infinite where nothing would find it. Heights only: a full control point's plan does not enter. And whether the
    pairs were judged (not over ``JOINT_COLS_MAX``)."""
    kept, ids, Q, sz = _kept_heights_cov(block, opts, state, rc, np.asarray(kept, dtype=int), obs_active)
    if not len(ids):
        return (), (), True
    lam = mdb_sigmas(alpha)
    M = (np.diag(sz**2) - Q) / np.outer(sz**2, sz**2)  # P Q_v P (P diagonal): the tests' statistics' cofactor
    d = np.sqrt(np.clip(np.diag(M), 0.0, None))
    r = 1.0 - np.diag(Q) / sz**2
    single = tuple((i, float(rr), lam * float(s) / math.sqrt(rr) if rr > 0 else math.inf)
                   for i, rr, s in zip(ids, r, sz))
    pairs = []
    if not np.all(np.isfinite(Q)):  # the covariance between points not formed (``JOINT_COLS_MAX``)
        return single, (), False
    with np.errstate(divide="ignore", invalid="ignore"):
        for a in range(len(ids)):
            for b in range(a + 1, len(ids)):
                for sign in (1, -1):
                    ncp = np.abs(M[:, a] + sign * M[:, b]) / d  # each test's non-centrality per metre of the bias
                    best = float(np.nanmax(np.where(d > 0, ncp, 0.0)))
                    pairs.append((ids[a], ids[b], sign, lam / best if best > 0 else math.inf))
    return single, tuple(sorted(pairs, key=lambda t: -t[3])), True


def _strip_sigmas(block: G.Block, opts: G.SolveSettings, rc, sigma0: float) -> tuple:
    """(strip 1-based, m) each strip's vertical GNSS correction's standard deviation at its worse end (the shift's,
    with a drift ``shift + t drift`` at the strip's first and last image, ``t`` along-track km) from the solution's
    covariance ``rc`` (unit weight) times ``sigma0``; () without a correction per strip (review 32: a strip whose
    shift only its a-priori sigma bounds takes the GNSS heights' error unchecked)."""
    if opts.gnss_correction not in ("shift", "shift_drift") or not math.isfinite(sigma0):
        return ()
    from aerotri.adjust.keys import D, S

    drift = opts.gnss_correction == "shift_drift"
    strip = np.asarray(block.strip, dtype=int)
    along = np.asarray(block.along_km, dtype=float)
    out = []
    for s in range(G.n_shifts(block, opts.gnss_correction)):
        if S(s) not in rc.offset:
            continue
        if drift and D(s) in rc.offset:
            t = along[strip == s]
            keys = [(S(s), 2), (D(s), 2)]
            idx = np.array([rc.offset[k] + a for k, a in keys])
            C = rc.entries(idx[:, None], idx[None, :])
            ends = np.array([[1.0, t.min()], [1.0, t.max()]]) if len(t) else np.array([[1.0, 0.0]])
            var = float(np.max(np.einsum("na,ab,nb->n", ends, C, ends)))
        else:
            i = rc.offset[S(s)] + 2
            var = float(rc.entries(np.array([i]), np.array([i]))[0])
        out.append((s + 1, math.sqrt(max(var, 0.0)) * sigma0))
    return tuple(out)


def beyond_correction(block: G.Block, opts: G.SolveSettings, P: np.ndarray, w_z: np.ndarray) -> np.ndarray:
    """The plane's terms ``P`` (N, 3) less what the GNSS correction's height terms take (weighted least squares over
    the GNSS heights), in the directions of which more than ``SURVIVING_SHARE`` survives: (N, k), k <= 3."""
    if opts.gnss_correction == "none":
        return P
    s = G.shift_index(block, opts.gnss_correction)
    C = np.zeros((len(P), G.n_shifts(block, opts.gnss_correction)))
    C[np.arange(len(P)), s] = 1.0
    if opts.gnss_correction == "shift_drift":
        C = np.hstack([C, C * np.asarray(block.along_km, dtype=float)[:, None]])
    r = np.sqrt(w_z)[:, None]
    R = P - C @ np.linalg.lstsq(r * C, r * P, rcond=None)[0]
    # the share of each plane direction v that survives: sqrt(v'R'WR v / v'P'WP v), the generalised eigenvalues
    from scipy.linalg import eigh

    lam, V = eigh((r * R).T @ (r * R), (r * P).T @ (r * P))
    keep = np.sqrt(np.clip(lam, 0.0, None)) > SURVIVING_SHARE
    return R @ V[:, keep]


def _layout(xy: np.ndarray) -> str:
    """The height control left, in plan: "one point", "on a line" (across it less than ``COLLINEAR_SHARE`` of its
    length), or "spread"."""
    if len(xy) < 2:
        return "one point"
    sv = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
    return "on a line" if len(xy) == 2 or sv[1] < COLLINEAR_SHARE * max(sv[0], 1e-300) else "spread"
