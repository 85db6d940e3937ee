"""``lidarctl strips adjust``: strip adjustment by least squares on plane correspondences in the overlaps.

Observations: every planar cell (``overlap``; slopes up to ``max_slope_deg``, roofs included: sloped
surfaces carry the horizontal information) that two strips share gives one point-to-plane distance,
y = n . (c_A - c_B), with n the mean unit normal of the two cell planes and c the centroids of each
strip's single returns in the cell, and sigma^2 = rms_A^2 / n_A + rms_B^2 / n_B (+ 3 mm^2 for the
surface's own roughness). Model: the points of a strip are displaced by e(p) = J(p) theta (the error
``theta`` describes); y = n . (e_A - e_B). Solved by iteratively reweighted least squares with Huber
weights (k = 1.5 robust sigmas: vegetation left in a cell, moving cars, changes between the flights).
Parameter covariance: the M-estimator's sandwich A^-1 B A^-1 (Huber 1981, 7.6), A the normal matrix of
the observations within the Huber threshold (psi' = 1; those beyond carry no information on the
slope of the fit) plus the priors, B the sum of the outer products of the weighted residual scores,
scaled by m / (m - K), plus the priors: sigma0^2 N^-1 of the reweighted normals leaves out the
efficiency Huber loses on Gaussian noise (about 13 % of the observations beyond 1.5 sigma) and comes
out about 6 % too small (Monte Carlo on the simulator's geometry: normalised RMS 1.07 against 0.99).
Corrected points: p - e(p). The strips are then read again with the correction so far and the
least squares repeated (``estimate``: noisy cell slopes times a large relative horizontal displacement
bias the horizontal parameters, errors in variables; the bias goes with the displacement).
Control points (``--control``, lidarctl.strips.control) add point-to-plane distances to single strips.

Models (``theta`` and J, all in metres and radians; reported in metres and degrees):
- ``strip`` (no trajectory): per strip a shift t (x, y, z) and a small rotation (roll about the flight
  direction, pitch about the right-hand axis, heading about the downward axis) about the strip's
  centre c: e = t + w x (p - c). The datum: one strip held fixed (``fixed``; default the strip with
  the most planar cells; none with control points), plus a weak prior (10 m, 1 deg) on every parameter so that directions the
  surfaces cannot see (e.g. a horizontal shift over flat ground only) stay solvable, with a large sigma.
- ``boresight`` (with the trajectory of every strip): the boresight angles (roll, pitch, heading of the
  scanner in the body frame x forward, y right, z down), a range offset and a scan-angle scale shared by
  all strips, and per strip a shift (the GNSS error) with the prior sigma ``shift_sigma_m``. The datum
  without control points: the block's mean height, i.e. the mean vertical correction over the strips' planar
  cells held at zero (a minimum constraint, ``MEAN_HEIGHT_SIGMA_M``): the overlaps hardly tell a range offset
  from a common height shift (over flat ground both move every strip up alike), so left to the shifts' prior
  the block's height followed the range offset's poorly determined estimate (a simulated block 0.18 m low
  after the adjustment, 0.06 m before). The z shifts' prior then holds only their deviations from their mean
  (kept whole it would pull the range offset to 0 along that unseen direction): every estimable quantity
  (boresight, range offset, scan-angle scale, relative shifts) is the former datum's, only the common height
  differs. With control points they hold the height (the shifts' full prior as before). For a point p with scanner position P and body-to-map rotation R at
  its GPS time, b = R^T (p - P), scan angle theta = atan2(b_right, b_down):
  e = R (b x w) + dr R b/|b| - k theta |b| R (0, cos theta, -sin theta) + t, i.e. the beam left rotated by
  the boresight error w, at theta (1 + k) where theta was read, and the range was measured dr too long.

``adjust_strips`` returns a ``StripAdjustResult``, what adjust.json holds (``read_strip_adjustment`` reads it back).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Mapping

import laspy
import numpy as np
from threadpoolctl import threadpool_limits

from aerotri.core.atomic import atomic_dir, refuse_input_as_output
from aerotri.core.records import to_record
from aerotri.core.errors import InputError, OptionError, SolveError
from aerotri.core.textio import read_record, record_error
from aerotri.core.settings import setting
from aerotri.geom import las
from lidarctl import io
from lidarctl.strips import check as chk
from lidarctl.strips import control as ctl
from lidarctl.strips import overlap as ov
from lidarctl.strips import trajectory as tj

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

SURFACE_ROUGHNESS_M = 0.003
WEAK_SHIFT_M = 10.0
WEAK_ANGLE_DEG = 1.0
# a step below this many standard deviations in every parameter ends the re-reads (cells gained and lost
# between reads leave a jitter of a few mm at the swath edges, a tenth of a sigma or less)
STEP_TOL_SIGMA = 0.1
# re-gridding the kept points is exact while no point moves further than the largest move at a planar cell
# when they were kept plus this (the models are smooth: a 0.05 deg rotation changes a move by 0.9 m per km)
REACH_MARGIN_M = 1.0
N_SENSOR = 5  # boresight roll, pitch, heading, range offset, scan-angle scale
# sigma of the free adjustment's minimum constraint (the mean vertical correction over the planar cells is 0):
# a hundredth of a millimetre, far below any observation's (millimetres): the constraint holds to 1e-5 m
MEAN_HEIGHT_SIGMA_M = 1e-5
STRIP_ADJUST_VERSION = 2  # the chain's strips stage stamp: bump when the corrected strips change at the same inputs
DATUM_MEAN_HEIGHT = "block mean height held (mean vertical correction 0 over the strips' planar cells)"
DATUM_CONTROL = "control points"


@dataclasses.dataclass(frozen=True)
class StripAdjustSettings:
    """Options of ``lidarctl strips adjust`` (lengths in metres, angles in degrees)."""

    max_slope_deg: float = setting(60.0, min=0.0, max=85.0,
                                   help="Steepest planar cells used as observations (deg).")
    fixed: str | None = setting(None, help="Strip held fixed (strip model; default: the one with most planar cells).")
    shift_sigma_m: float = setting(0.05, min=0.0, min_open=True,
                                   help="Prior sigma of each strip's shift (m; with a trajectory; without control "
                                        "the block's mean height is the datum).")
    control_sigma_m: float = setting(0.02, min=0.0, min_open=True,
                                     help="Sigma of a control point's height on its surface (m).")
    huber_k: float = setting(1.5, min=0.5, help="Huber threshold in robust sigmas.")
    iterations: int = setting(10, min=1, help="Reweighting iterations.")
    relinearise: int = setting(5, min=1, help="Reads of the strips: after the first, each re-read with the "
                                              "correction so far, until a step is below 0.1 sigma.")


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A parameter's value and standard deviation, in the unit its name ends in (degrees for ``_deg``)."""

    value: float
    sigma: float


@dataclasses.dataclass(frozen=True)
class Correlation:
    """The correlation coefficient ``r`` of the parameters ``a`` and ``b``."""

    a: str
    b: str
    r: float


@dataclasses.dataclass(frozen=True)
class ParameterReport:
    """The parameters with their sigmas (by name, ``Model.names`` order), the correlation matrix (rounded to 4
    digits) and the correlations of |r| >= 0.5 between different parameters, strongest first."""

    parameters: Mapping[str, Estimate]
    correlation_matrix: tuple[tuple[float, ...], ...]
    strong_correlations: tuple[Correlation, ...]


@dataclasses.dataclass(frozen=True)
class ControlResidual:
    """A control point's distance above the plane of a strip before and after the correction (metres)."""

    id: str
    strip: str
    before_m: float
    after_m: float


@dataclasses.dataclass(frozen=True)
class ControlSummary:
    """The control points' distances to their strips' planes before and after the correction (metres)."""

    file: str
    points: int
    points_used: int
    observations: int
    mean_before_m: float
    mean_after_m: float
    rms_before_m: float
    rms_after_m: float
    residuals: tuple[ControlResidual, ...]


@dataclasses.dataclass(frozen=True)
class StripAdjustResult:
    """What ``lidarctl strips adjust`` did (adjust.json): the model (``strip`` or ``boresight``), the strip held
    fixed, the observations, sigma0, the parameters with sigmas and correlations, the strip differences before
    and after (``check_before``/``check_after``: all pairs, metres), the corrected files' names, the times (s)
    and, with control points, their distances before and after."""

    model: str
    fixed_strip: str | None
    settings: StripAdjustSettings
    cell_m: float
    points: int
    strips: tuple[str, ...]
    observations: int
    reads: int
    observations_per_pair: Mapping[str, int]  # "a-b" (or "strip-control") -> plane observations
    downweighted: int
    sigma0: float
    strips_without_observations: tuple[str, ...]  # their parameters stay at the prior (not corrected)
    plane_distance_rms_before_m: float
    plane_distance_rms_after_m: float
    parameters: Mapping[str, Estimate]
    correlation_matrix: tuple[tuple[float, ...], ...]
    strong_correlations: tuple[Correlation, ...]
    check_before: chk.DiffStats
    check_after: chk.DiffStats
    files: tuple[str, ...]
    seconds: float
    points_per_s: float
    seconds_read: float
    seconds_solve: float
    seconds_write: float
    control: ControlSummary | None = None
    # what holds the block's position: the fixed strip, the control points, or the block's mean height
    datum: str = ""
    # sensor parameters significant only through the shifts' prior (``prior_bound_warnings``), said as warnings
    warnings: tuple[str, ...] = ()
    # sensor parameters the overlaps did not determine, held at 0 (``undetermined_sensor``)
    held: tuple[str, ...] = ()
    # the parameters' sign (trial-strips found it by experiment)
    convention: str = ("the parameters are the strips' errors e(p) (shift_*: the strip lies that far off, in metres; "
                       "angles in degrees): each corrected point is p - e(p)")
    schema_version: int = chk.SCHEMA_VERSION
    # what check_before's and check_after's NMAD are (the strip check's, ``chk.NMAD_DEFINITION``); None: an
    # adjust.json written before it was said
    nmad_definition: str | None = chk.NMAD_DEFINITION

    def to_json(self) -> str:
        """adjust.json's text."""
        out = {"schema_version": self.schema_version}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ("schema_version", "control") or (f.name == "nmad_definition" and v is None):
                continue
            if f.name == "settings":
                v = dataclasses.asdict(v)
            elif f.name == "parameters":
                v = {n: dataclasses.asdict(e) for n, e in v.items()}
            elif f.name in ("check_before", "check_after"):
                v = to_record(v, drop_none=True)
            elif isinstance(v, tuple):
                v = [dataclasses.asdict(x) if dataclasses.is_dataclass(x) else
                     (list(x) if isinstance(x, tuple) else x) for x in v]
            out[f.name] = v
        if self.control is not None:
            out["control"] = dataclasses.asdict(self.control)
        return json.dumps(out, indent=2) + "\n"


def read_strip_adjustment(path) -> StripAdjustResult:
    """adjust.json as ``adjust_strips`` wrote it (InputError naming the file when it is not one)."""
    path = Path(path)
    what = "strip adjustment (adjust.json)"
    d = read_record(path, what, chk.SCHEMA_VERSION)
    try:
        c = d.get("control")
        control = None if c is None else ControlSummary(**{**c, "residuals": tuple(
            ControlResidual(**r) for r in c["residuals"])})
        fields = {f.name for f in dataclasses.fields(StripAdjustResult)}
        return StripAdjustResult(**{**{k: v for k, v in d.items() if k in fields},
                                    "settings": StripAdjustSettings(**d["settings"]),
                                    "strips": tuple(d["strips"]),
                                    "strips_without_observations": tuple(d["strips_without_observations"]),
                                    "parameters": {n: Estimate(**e) for n, e in d["parameters"].items()},
                                    "correlation_matrix": tuple(tuple(r) for r in d["correlation_matrix"]),
                                    "strong_correlations": tuple(Correlation(**c) for c in d["strong_correlations"]),
                                    "check_before": chk.DiffStats.of_record(d["check_before"]),
                                    "check_after": chk.DiffStats.of_record(d["check_after"]),
                                    "files": tuple(d["files"]), "control": control,
                                    "warnings": tuple(d.get("warnings") or ()), "held": tuple(d.get("held") or ()),
                                    "nmad_definition": d.get("nmad_definition")})
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, what, exc) from None


@dataclasses.dataclass
class Model:
    """Parameter names, the strips' effect Jacobians at their planar cells, and the prior sigmas."""

    kind: str
    names: list[str]
    prior_sigma: np.ndarray  # (K,) inf: no prior
    jac: dict  # strip name -> ((m, 3, k) effect Jacobians at the planar cells' centroids, their k columns of K)
    local: object  # callable(strip name, x, y, z (m), gps time) -> ((n, 3, k) Jacobians, the k columns)
    jac_of: object  # callable(StripSet) -> ``jac`` of the planar cells of a re-read of the strips
    displace: object = None  # callable(strip name, x, y, z, t, theta) -> (n, 3) J theta without forming J

    def apply(self, name, x, y, z, t=None) -> np.ndarray:
        """(n, 3, K) Jacobians of single points of strip ``name``."""
        Jl, cols = self.local(name, x, y, z, t)
        J = np.zeros((len(x), 3, len(self.names)))
        J[:, :, cols] = Jl
        return J

    def displacement(self, name, x, y, z, t, theta: np.ndarray, *, block: int = 200_000) -> np.ndarray:
        """(n, 3) e(p) = J(p) theta of points of strip ``name`` (only the strip's own columns are formed)."""
        if self.displace is not None:
            return self.displace(name, x, y, z, t, theta)
        e = np.zeros((len(x), 3))
        for k0 in range(0, len(x), block):  # bounded memory of the (n, 3, k) Jacobians
            i = slice(k0, k0 + block)
            Jl, cols = self.local(name, x[i], y[i], z[i], None if t is None else t[i])
            e[i] = Jl @ theta[cols]
        return e

    def correction(self, theta: np.ndarray):
        """``read_strip_planes``' ``correct`` callback: the points of a strip moved by -e(p) = -J(p) theta."""
        def correct(source, x, y, z, t):
            e = self.displacement(source.name, x, y, z, t, theta)
            return np.asarray(x, float) - e[:, 0], np.asarray(y, float) - e[:, 1], np.asarray(z, float) - e[:, 2]
        return correct


def _cross_matrix(b: np.ndarray) -> np.ndarray:
    """(n, 3, 3) [b]x so that [b]x w = b x w."""
    z = np.zeros(len(b))
    return np.stack([np.stack([z, -b[:, 2], b[:, 1]], 1), np.stack([b[:, 2], z, -b[:, 0]], 1),
                     np.stack([-b[:, 1], b[:, 0], z], 1)], 1)


def strip_model(ss: ov.StripSet, fixed: str | None, controlled: bool = False) -> Model:
    """Per-strip shift and rotation about the strip centre; ``fixed`` has no parameters (default: the strip
    with the most planar cells; none when ``controlled``: the control points hold the datum)."""
    names_s = [s.name for s in ss.strips]
    if fixed is None and not controlled:
        fixed = max(ss.strips, key=lambda s: len(s.ids)).name
    elif fixed is not None and fixed not in names_s:
        raise OptionError(f"--fixed {fixed}: not a strip of this block ({', '.join(names_s)})", param="--fixed")
    free = [s for s in ss.strips if s.name != fixed]
    K = 6 * len(free)
    names, prior = [], []
    for s in free:
        names += [f"{s.name}.{k}" for k in ("shift_x_m", "shift_y_m", "shift_z_m", "roll_deg", "pitch_deg", "heading_deg")]
        prior += [WEAK_SHIFT_M] * 3 + [np.radians(WEAK_ANGLE_DEG)] * 3
    col = {s.name: 6 * i for i, s in enumerate(free)}
    frames = {}
    for s in ss.strips:
        f = np.array([s.axis[0], s.axis[1], 0.0])
        frames[s.name] = (np.array([f, [f[1], -f[0], 0.0], [0.0, 0.0, -1.0]]), s.centre.copy())

    def local(name, x, y, z, t=None):
        if name not in col:
            return np.zeros((len(x), 3, 0)), np.zeros(0, int)
        J = np.zeros((len(x), 3, 6))
        axes, c = frames[name]
        q = np.column_stack([x, y, z]) - c
        J[:, [0, 1, 2], [0, 1, 2]] = 1.0
        for a in range(3):  # w x q for a unit rotation about each body axis
            J[:, :, 3 + a] = np.cross(axes[a], q)
        return J, np.arange(col[name], col[name] + 6)

    def displace(name, x, y, z, t, theta):
        if name not in col:
            return np.zeros((len(x), 3))
        th = theta[col[name]:col[name] + 6]
        axes, c = frames[name]
        w = axes.T @ th[3:]  # the rotation vector: sum of the body axes' angles
        return th[:3] + np.cross(w, np.column_stack([x, y, z]) - c)

    model = Model("strip", names, np.array(prior), {}, local, None, displace)
    model.jac_of = lambda ss_: {s.name: local(s.name, *s.centroid.T) for s in ss_.strips}
    model.jac = model.jac_of(ss)
    return model


def boresight_extra(trajs: list[tj.Trajectory]):
    """The ``read_strip_planes`` callback of the boresight model: per point the 15 entries of R [b]x, R b/|b| and
    the scan-angle scale column (the effect Jacobians of the boresight angles, the range offset and the
    scan-angle scale). InputError when a strip's GPS times are not covered by a trajectory."""
    chosen = {}

    def extra(source, chunk, x, y, z, use):
        out = np.zeros((len(x), 3 * N_SENSOR))
        if not use.any():
            return out
        t = np.asarray(chunk.gps_time, float)[use]
        if source.name not in chosen:
            chosen[source.name] = tj.for_times(trajs, t, f"{source.path} (strip {source.name})")
        tr = chosen[source.name]
        if not tr.covers(t).all():
            bad = t[~tr.covers(t)]
            raise InputError(f"{source.path} (strip {source.name}): GPS times {bad.min():.3f} .. {bad.max():.3f} lie "
                             f"outside its trajectory {tr.source} ({tr.t[0]:.3f} .. {tr.t[-1]:.3f})")
        _check_ranges(tr, t, x[use], y[use], z[use], f"{source.path} (strip {source.name})")
        out[use] = _sensor_jacobian(tr, t, x[use], y[use], z[use]).reshape(-1, 3 * N_SENSOR)
        return out

    return extra, chosen


MAX_RANGE_M = 20_000.0  # beyond any airborne scanner's range (a few km): the trajectory is of another place


def _check_ranges(tr: tj.Trajectory, t, x, y, z, what: str) -> None:
    """InputError when the trajectory positions at the points' GPS times lie farther from the points than any
    scanner reaches: a trajectory in another zone, CRS or unit than the strip."""
    P, _ = tr.at(t)
    rho = float(np.median(np.linalg.norm(np.column_stack([x, y, z]) - P, axis=1)))
    if not rho <= MAX_RANGE_M:
        raise InputError(f"{tr.source}: its positions lie {rho / 1000:.1f} km (median) from the points of {what} at "
                         f"their GPS times, beyond any scanner's range ({MAX_RANGE_M / 1000:g} km); a trajectory in "
                         "another zone, CRS or unit than the strip?")


def _sensor_jacobian(tr: tj.Trajectory, t, x, y, z) -> np.ndarray:
    """(n, 3, 5): effect of the boresight angles (rad), the range offset (m) and the scan-angle scale k
    (dimensionless: the beam left at theta (1 + k), theta the angle read) on points at times t. The scan
    angle theta = atan2(right, down) of the body-frame beam b; the beam turned by k theta about the forward
    axis leaves the point at |b| k theta R (0, cos theta, -sin theta) from where it was computed."""
    P, R = tr.at(t)
    v = np.column_stack([x, y, z]) - P
    b = np.einsum("nji,nj->ni", R, v)
    rho = np.linalg.norm(v, axis=1)
    theta = np.arctan2(b[:, 1], b[:, 2])
    J = np.empty((len(t), 3, N_SENSOR))
    J[:, :, :3] = R @ _cross_matrix(b)
    J[:, :, 3] = v / rho[:, None]
    turn = np.column_stack([np.zeros(len(t)), np.cos(theta), -np.sin(theta)])
    J[:, :, 4] = -(rho * theta)[:, None] * np.einsum("nij,nj->ni", R, turn)
    return J


def boresight_model(ss: ov.StripSet, chosen: dict, shift_sigma_m: float) -> Model:
    S = len(ss.strips)
    names = ["boresight_roll_deg", "boresight_pitch_deg", "boresight_heading_deg", "range_offset_m",
             "scan_angle_scale"]
    for s in ss.strips:
        names += [f"{s.name}.shift_x_m", f"{s.name}.shift_y_m", f"{s.name}.shift_z_m"]
    prior = np.array([np.inf] * N_SENSOR + [shift_sigma_m] * (3 * S))
    col = {s.name: N_SENSOR + 3 * i for i, s in enumerate(ss.strips)}

    def place(name, J4):
        J = np.zeros((len(J4), 3, N_SENSOR + 3))
        J[:, :, :N_SENSOR] = J4
        J[:, [0, 1, 2], [N_SENSOR, N_SENSOR + 1, N_SENSOR + 2]] = 1.0
        return J, np.r_[np.arange(N_SENSOR), np.arange(col[name], col[name] + 3)]

    def jac_of(ss_):
        return {s.name: place(s.name, s.extra.reshape(-1, 3, N_SENSOR)) for s in ss_.strips}

    def local(name, x, y, z, t):
        J = np.zeros((len(x), 3, N_SENSOR + 3))
        J[:, :, :N_SENSOR] = _sensor_jacobian(chosen[name], t, x, y, z)
        J[:, [0, 1, 2], [N_SENSOR, N_SENSOR + 1, N_SENSOR + 2]] = 1.0
        return J, np.r_[np.arange(N_SENSOR), np.arange(col[name], col[name] + 3)]

    return Model("boresight", names, prior, jac_of(ss), local, jac_of)


@dataclasses.dataclass
class Observations:
    G: np.ndarray  # (m, K)
    y: np.ndarray  # (m,)
    sigma: np.ndarray  # (m,)
    pair: np.ndarray  # (m,) pair index
    pairs: list[tuple[str, str]]  # (strip, "control") for the control observations of a strip
    control: ctl.ControlObservations | None = None  # the last rows of G, y, sigma


def observations(ss: ov.StripSet, model: Model, max_slope_deg: float, control: ctl.ControlPoints | None = None,
                 control_sigma_m: float = 0.02) -> Observations:
    """The overlaps' plane distances, then those of the control points (``lidarctl.strips.control``)."""
    obs = _overlap_observations(ss, model, max_slope_deg)
    if control is None:
        return obs
    co = ctl.control_observations(ss, control, control_sigma_m, max_slope_deg)
    G = np.zeros((len(co.y), obs.G.shape[1]))
    pair = np.zeros(len(co.y), int)
    pairs = list(obs.pairs)
    for si, s in enumerate(ss.strips):
        m = co.strip == si
        if m.any():
            J, cols = model.jac[s.name]
            G[np.ix_(np.flatnonzero(m), cols)] = np.einsum("ij,ijk->ik", co.normal[m], J[co.cell[m]])
            pair[m] = len(pairs)
            pairs.append((s.name, "control"))
    return Observations(np.vstack([obs.G, G]), np.concatenate([obs.y, co.y]), np.concatenate([obs.sigma, co.sigma]),
                        np.concatenate([obs.pair, pair]), pairs, co)


def _overlap_observations(ss: ov.StripSet, model: Model, max_slope_deg: float) -> Observations:
    Gs, ys, ss_, ps, names = [], [], [], [], []
    for ia, A in enumerate(ss.strips):
        for B in ss.strips[ia + 1:]:
            common, ka, kb = np.intersect1d(A.ids, B.ids, assume_unique=True, return_indices=True)
            ok = (A.slope_deg[ka] <= max_slope_deg) & (B.slope_deg[kb] <= max_slope_deg)
            ka, kb = ka[ok], kb[ok]
            if len(ka) == 0:
                continue
            n = A.normals()[ka] + B.normals()[kb]
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            ys.append(np.einsum("ij,ij->i", n, A.centroid[ka] - B.centroid[kb]))
            (JA, ca), (JB, cb) = model.jac[A.name], model.jac[B.name]
            G = np.zeros((len(ka), len(model.names)))
            G[:, ca] += np.einsum("ij,ijk->ik", n, JA[ka])
            G[:, cb] -= np.einsum("ij,ijk->ik", n, JB[kb])
            Gs.append(G)
            ss_.append(np.sqrt(A.rms_m[ka] ** 2 / A.n[ka] + B.rms_m[kb] ** 2 / B.n[kb] + SURFACE_ROUGHNESS_M ** 2))
            ps.append(np.full(len(ka), len(names)))
            names.append((A.name, B.name))
    if not Gs:
        raise InputError("no two strips share a planar cell: nothing to adjust")
    return Observations(np.concatenate(Gs), np.concatenate(ys), np.concatenate(ss_), np.concatenate(ps), names)


@dataclasses.dataclass
class Solution:
    theta: np.ndarray
    cov: np.ndarray
    sigma0: float
    weights: np.ndarray
    residual_before_rms_m: float
    residual_after_rms_m: float
    downweighted: int
    # per parameter: its sigma with the priors PRIOR_WIDENING times wider over its sigma with them (1: the
    # overlaps alone determine it; large: the priors do, e.g. a boresight pitch the shifts' prior decides)
    prior_reliance: np.ndarray | None = None


# the priors' sigmas widened by this factor to see what the overlaps alone determine (``Solution.prior_reliance``)
PRIOR_WIDENING = 10.0
# a sensor parameter whose sigma grows by more than this with the priors widened rests on them: significant with
# them (beyond 3 sigma), it is said, not carried as a calibration (trial-strips: one strip moved 0.5 m along track
# read as a 6-sigma boresight pitch)
PRIOR_RELIANCE_MAX = 3.0
# A sensor parameter whose sigma exceeds its limit is not determined by the strips' overlaps: it is held at zero and
# the block adjusted again without it, and said. Two strips with trajectories (trial s98): heading +3.35 +- 2.37 deg
# and pitch -0.73 +- 0.52 deg (correlated -0.99997) from exact strips, applied, moved points up to 19 m (33 m with
# an injected 0.04 deg heading) while the strip differences read 0.021 -> 0.022 m. Three strips of the same block:
# sigmas 0.0003 / 0.0037 / 0.0109 deg, 0.19 m, 0.0002. The limits are far above what a boresight calibration
# carries (hundredths of a degree) and the range offset's sigma of two strips (0.75-2 m; review3: +2.11 +- 0.75 m
# against a true 0.08 m, the z shifts following it, the open ground 0.063 -> 0.097 m RMSE from the truth while the
# strip differences fell 0.063 -> 0.010 m; it was warned on the console only).
UNDETERMINED_SIGMA = {"boresight_roll_deg": 0.1, "boresight_pitch_deg": 0.1, "boresight_heading_deg": 0.1,
                      "range_offset_m": 0.5, "scan_angle_scale": 1e-3}
HELD_SIGMA = 1e-9  # the prior sigma (radians, metres, scale) that holds an undetermined parameter at zero


def solve(obs: Observations, model: Model, huber_k: float = 1.5, iterations: int = 10,
          theta0: np.ndarray | None = None, mean_height: np.ndarray | None = None) -> Solution:
    """IRLS with Huber weights; the sandwich covariance (module docstring); sigma0 from the weighted residuals,
    priors included. ``theta0``: the correction the observations were made with (strips re-read with it):
    the solution is theta0 plus the step the observations ask for, the priors apply to the total.
    ``mean_height`` (K,): the row of the mean vertical correction (``mean_height_row``), held at zero for the
    total like a prior (sigma ``MEAN_HEIGHT_SIGMA_M``; in the normals and both halves of the sandwich)."""
    # G is tall and thin (m x a few dozen): one BLAS thread does G^T G in milliseconds; two threads on a loaded
    # machine wait on each other up to 100x longer (0.3 s against 3 ms for 40 k x 18), most of adjust's time
    with threadpool_limits(1, user_api="blas"):
        return _solve(obs, model, huber_k, iterations, theta0, mean_height)


def _solve(obs: Observations, model: Model, huber_k: float, iterations: int, theta0: np.ndarray | None,
           mean_height: np.ndarray | None = None) -> Solution:
    K = obs.G.shape[1]
    theta0 = np.zeros(K) if theta0 is None else np.asarray(theta0, float)
    has_prior = np.isfinite(model.prior_sigma)
    P = np.where(has_prior, 1.0 / np.where(has_prior, model.prior_sigma, 1.0) ** 2, 0.0)
    # the priors' normal matrix (diagonal) and right-hand side (at step = 0)
    Pp = np.diag(P)
    Pm = Pp
    if mean_height is not None:
        # the mean height takes the place of the z shifts' prior as the datum: their prior holds only their
        # deviations from their (prior-weighted) mean, else it would pull the range offset to 0 along the
        # direction the overlaps cannot see (range offset up, every strip down alike)
        zc = np.array([i for i, n in enumerate(model.names) if n.endswith(".shift_z_m")], int)
        pz = P[zc]
        Pp = Pp.copy()
        Pp[np.ix_(zc, zc)] = np.diag(pz) - np.outer(pz, pz) / pz.sum()
        g = np.asarray(mean_height, float) / MEAN_HEIGHT_SIGMA_M
        Pm = Pp + np.outer(g, g)
    Pr = -Pm @ theta0
    w = np.ones(len(obs.y))
    Gn, yn = obs.G / obs.sigma[:, None], obs.y / obs.sigma
    step = np.zeros(K)
    for _ in range(iterations):
        N = (Gn * w[:, None]).T @ Gn + Pm
        try:
            step = np.linalg.solve(N, (Gn * w[:, None]).T @ yn + Pr)
        except np.linalg.LinAlgError:
            raise SolveError("the normal equations are singular: the overlaps do not determine the parameters") from None
        r = yn - Gn @ step
        s = max(chk.NMAD_K * np.median(np.abs(r)), 1e-9)
        a = np.abs(r) / (huber_k * s)
        w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
    theta = theta0 + step
    r = yn - Gn @ step
    dof = max(len(r) - K + int(has_prior.sum()), 1)
    sigma0 = float(np.sqrt((np.sum(w * r ** 2) + theta @ Pp @ theta) / dof))
    s = max(chk.NMAD_K * np.median(np.abs(r)), 1e-9)
    inside = np.abs(r) <= huber_k * s
    A = Gn[inside].T @ Gn[inside] + Pm
    g = Gn * (w * r)[:, None]  # psi of the standardised residuals, times s
    B = g.T @ g * len(r) / max(len(r) - K, 1) + Pm
    try:
        Ainv = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        raise SolveError("the normal equations are singular: the overlaps do not determine the parameters") from None
    cov = Ainv @ B @ Ainv
    rm = obs.y - obs.G @ step
    # the same normals with the priors (not the datum's mean height) PRIOR_WIDENING times wider
    wide = A - Pp * (1.0 - 1.0 / PRIOR_WIDENING ** 2)
    try:
        reliance = np.sqrt(np.maximum(np.diag(np.linalg.inv(wide)), 0.0) / np.diag(Ainv))
    except np.linalg.LinAlgError:
        reliance = np.full(K, np.inf)
    return Solution(theta, cov, sigma0, w, float(np.sqrt(np.mean(obs.y ** 2))),
                    float(np.sqrt(np.mean(rm ** 2))), int(np.sum(w < 1.0)), reliance)


def prior_bound_warnings(model: Model, sol: Solution, shift_sigma_m: float) -> tuple[str, ...]:
    """The sensor parameters (boresight, range offset, scan-angle scale) beyond 3 sigma whose sigma grows more than
    ``PRIOR_RELIANCE_MAX`` times with the priors widened: the shifts' prior, not the overlaps, decides them. Strips
    flown in opposite directions over flat ground show a boresight pitch as along-track shifts of alternate strips
    (and the heading partly so): one strip 0.5 m off along track read as a 6-sigma pitch and a 5-sigma heading, and
    moved the three right strips 0.1-0.3 m (trial-strips)."""
    if sol.prior_reliance is None or model.kind != "boresight":
        return ()
    out = []
    sd = np.sqrt(np.diag(sol.cov))
    for k, name in enumerate(model.names):
        if np.isfinite(model.prior_sigma[k]) or not sd[k] > 0:
            continue
        z, rel = abs(sol.theta[k]) / sd[k], float(sol.prior_reliance[k])
        if z > 3.0 and rel > PRIOR_RELIANCE_MAX:
            v, e = _report_value(name, sol.theta[k]), _report_value(name, sd[k])
            out.append(f"{name} {v:+.4f} +- {e:.4f} ({z:.1f} sigma) rests on the strips' shift prior "
                       f"(--shift-sigma-m {shift_sigma_m:g} m): with the prior {PRIOR_WIDENING:g} x wider its sigma "
                       f"is {rel:.1f} x larger ({e * rel:.4f}); the overlaps hardly tell it from strip shifts "
                       f"({_LIKE_SHIFTS.get(name, 'it moves the strips as their shifts do')}), so a strip off by "
                       "more than the prior comes out as this parameter. Carry it to other flights only if the GNSS "
                       "is known within the prior; look for a strip's offset in check_before/ (strips.json), "
                       "or adjust with --control or a cross strip")
    return tuple(out)


# how each sensor parameter looks like strip shifts (trial s98 L7: the pitch's words were said of every parameter)
_LIKE_SHIFTS = {
    "boresight_pitch_deg": "a pitch is an along-track shift of strips flown in opposite directions",
    "boresight_heading_deg": "a heading turns each strip's swath, an along-track shift growing across it",
    "boresight_roll_deg": "a roll tilts each swath, a height shift growing across it",
    "range_offset_m": "a range offset moves every strip up or down alike, as a common height shift",
    "scan_angle_scale": "a scan-angle scale widens each swath, a height shift growing towards its edges"}


def undetermined_sensor(model: Model, sol: Solution) -> list[int]:
    """Indices of the sensor parameters (no prior) whose sigma exceeds ``UNDETERMINED_SIGMA``."""
    if model.kind != "boresight":
        return []
    sd = np.sqrt(np.maximum(np.diag(sol.cov), 0.0))
    return [k for k, name in enumerate(model.names) if name in UNDETERMINED_SIGMA and not np.isfinite(
        model.prior_sigma[k]) and _report_value(name, sd[k]) > UNDETERMINED_SIGMA[name]]


def held_text(model: Model, sol: Solution, held: list[int], adjusted_strips: int) -> str:
    """The warning for the parameters ``undetermined_sensor`` found, with their estimates before they were held."""
    sd = np.sqrt(np.maximum(np.diag(sol.cov), 0.0))
    what = ", ".join(f"{model.names[k]} {_report_value(model.names[k], sol.theta[k]):+.4f} +- "
                     f"{_report_value(model.names[k], sd[k]):.4f} (limit {UNDETERMINED_SIGMA[model.names[k]]:g})"
                     for k in held)
    return (f"not determined by the overlaps of {adjusted_strips} strips, held at 0 (the strips' shifts take what "
            f"they would have): {what}. Applied, such an estimate moves points by metres while the strip "
            "differences shrink; add a strip flown the other way or across, or adjust with --control")


def _report_value(name: str, v: float) -> float:
    return float(np.degrees(v)) if name.endswith("_deg") else float(v)


def parameter_report(model: Model, sol: Solution) -> ParameterReport:
    sd = np.sqrt(np.diag(sol.cov))
    corr = sol.cov / np.outer(sd, sd)
    params = {n: Estimate(_report_value(n, v), _report_value(n, s)) for n, v, s in zip(model.names, sol.theta, sd)}
    # the strongest correlations (|r| >= 0.5) between different parameters
    strong = []
    iu = np.triu_indices(len(sd), 1)
    for i, j in zip(*iu):
        if abs(corr[i, j]) >= 0.5:
            strong.append(Correlation(model.names[i], model.names[j], float(corr[i, j])))
    strong.sort(key=lambda c: -abs(c.r))
    return ParameterReport(params, tuple(tuple(r) for r in np.round(corr, 4).tolist()), tuple(strong))


def write_corrected(ss: ov.StripSet, model: Model, theta: np.ndarray, folder: Path,
                    chunk_points: int = io.CHUNK_POINTS, crs=None) -> list[Path]:
    """Every input file with corrected X, Y, Z (p - e(p)) into ``folder``, everything else kept: header
    fields, VLRs, EVLRs, point records (the coordinates re-quantised in the file's own scales and offsets); ``crs``
    (pyproj) recorded in a file without a CRS record."""
    units = ss.units
    by_path: dict[Path, list[ov.StripSource]] = {}
    for s in ss.strips:
        by_path.setdefault(s.source.path, []).append(s.source)
    out = []
    for path, sources in by_path.items():
        header = las.read_header(path)
        out_header = io.output_header(header, crs)
        dst = folder / path.name
        with laspy.open(dst, mode="w", header=out_header, do_compress=path.suffix.lower() == ".laz") as w:
            for _, chunk in las.iter_file_chunks(path, chunk_points, withheld=True):  # a copy: every record
                x, y, z = units.xy_to_m(np.asarray(chunk.x)), units.xy_to_m(np.asarray(chunk.y)), units.z_to_m(
                    np.asarray(chunk.z))
                x, y, z = np.array(x, float), np.array(y, float), np.array(z, float)
                t = np.asarray(chunk.gps_time, float) if "gps_time" in chunk.point_format.dimension_names else None
                psid = np.asarray(chunk.point_source_id)
                for s in sources:
                    i = np.flatnonzero(psid == s.point_source_id) if s.point_source_id is not None else \
                        np.arange(len(x))
                    e = model.displacement(s.name, x[i], y[i], z[i], None if t is None else t[i], theta)
                    x[i] -= e[:, 0]
                    y[i] -= e[:, 1]
                    z[i] -= e[:, 2]
                chunk.x, chunk.y, chunk.z = units.xy_from_m(x), units.xy_from_m(y), units.z_from_m(z)
                w.write_points(chunk)
            io.write_evlrs(w, out_header)
        out.append(dst)
    return out


def _reach_m(model: Model, theta: np.ndarray) -> float:
    """Largest displacement |J theta| (m) at the planar cells of the read ``model.jac`` was formed on."""
    return max((float(np.max(np.linalg.norm(J @ theta[c], axis=1), initial=0.0)) for J, c in model.jac.values()),
               default=0.0)


def keep_region(ss: ov.StripSet, reach_m: float, times: bool = False) -> ov.KeepRegion:
    """The cells (as read, before any correction) of each strip within D = 2 ceil(reach / cell) + 3 cells of a
    cell another strip occupies: once every point moves by at most ``reach_m``, a cell two strips share, and
    its 4-neighbours, only hold points of that region (D: both strips' moves, the neighbour, one cell of slack
    for the floor). Coarse cells of D x D cells, kept with their 8 neighbours: at least D cells around.
    ``times``: keep the GPS times as well (the sensor model's correction needs them)."""
    grid = ss.grid
    d = 2 * int(np.ceil(reach_m / grid.cell_m)) + 3
    cn = grid.ncols // d + 2
    coarse = {}
    for s in ss.strips:
        i, j = np.divmod(s.occupied, grid.ncols)
        coarse[s.name] = np.unique((i // d) * cn + j // d)
    offsets = np.array([di * cn + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)])
    ids = {}
    for s in ss.strips:
        others = [coarse[o.name] for o in ss.strips if o.name != s.name]
        other = np.unique(np.concatenate(others)) if others else np.zeros(0, np.int64)
        ids[s.name] = np.intersect1d(np.unique((other[:, None] + offsets).ravel()), coarse[s.name])
    return ov.KeepRegion(d, cn, ids, times)


def estimate(paths, ss: ov.StripSet, model: Model, settings: StripAdjustSettings, read_params, *, crs, extra,
             control: ctl.ControlPoints | None = None):
    """Least squares on the planes of ``ss``, then again on the strips re-read with the correction so far,
    until a step is below ``STEP_TOL_SIGMA`` standard deviations in every parameter (at most
    ``settings.relinearise`` reads).

    Why re-read: the horizontal part of e reaches the observations through the surface slope, which the
    model takes from the fitted cell planes. Their slope noise multiplies the strips' relative horizontal
    displacement (0.5 m across track for a 0.03 deg boresight roll, east against west strips, at 500 m)
    into residuals that correlate with the fitted slope: errors in variables, shrinking the horizontal
    relative shifts the gentle slopes see (the neighbours' across-track shift of a strip seen only over
    gentle terrain came out 2-4 sigma off). Once the strips are corrected that displacement, and with it
    the bias, is gone.

    The files are read at most twice: the first re-read also keeps the points of the overlaps (and a margin
    for the correction's move, ``keep_region``: ``REACH_MARGIN_M`` beyond the largest move at a planar cell)
    in memory, and later reads re-grid those (``overlap.regrid``): the same planes in every shared cell, at
    a fraction of the time. A later correction that moves a planar cell further than the margin reads the
    files again. The sensor model without control holds the block's mean height (``mean_height_row`` of the
    first read's planar cells, the same row on every read). Returns (solution, observations of the first and
    of the last read, reads)."""
    theta = np.zeros(len(model.names))
    mh = mean_height_row(model) if model.kind == "boresight" and control is None else None
    obs = first = observations(ss, model, settings.max_slope_deg, control, settings.control_sigma_m)
    sol = solve(obs, model, settings.huber_k, settings.iterations, mean_height=mh)
    before_rms = sol.residual_before_rms_m
    passes = 1
    kept, kept_reach = None, 0.0
    while passes < settings.relinearise:
        step = sol.theta - theta
        moved = max(float(np.max(np.abs(J @ step[c]), initial=0.0)) for J, c in model.jac.values())
        rel = float(np.max(np.abs(step) / np.sqrt(np.diag(sol.cov))))
        log.info("strip adjustment pass %d: largest step at a planar cell %.4f m, %.2f sigma", passes, moved, rel)
        if rel < STEP_TOL_SIGMA:
            break
        theta = sol.theta
        reach = _reach_m(model, theta)
        if kept is not None and reach <= kept_reach:
            ss_i = ov.regrid(kept, read_params, extra=extra, correct=model.correction(theta))
        else:
            keep = None
            if passes + 1 < settings.relinearise:  # another read may follow: keep the overlaps' points
                kept_reach = reach + REACH_MARGIN_M
                keep = keep_region(ss, kept_reach, times=model.kind == "boresight")
            ss_i = ov.read_strip_planes(paths, read_params, crs, extra=extra, correct=model.correction(theta),
                                        grid=ss.grid, keep=keep, z_ref=ss.z_ref)
            kept = ss_i if keep is not None else None
            if kept is not None:
                log.info("strip adjustment: %d points of the overlaps kept for re-gridding (within %.2f m of them: "
                         "the largest correction so far %.3f m and a margin)",
                         sum(len(k.single) for k in kept.kept.values()), kept_reach, reach)
        model.jac = {}  # not the old and the new at once
        model.jac = model.jac_of(ss_i)
        obs = observations(ss_i, model, settings.max_slope_deg, control, settings.control_sigma_m)
        sol = solve(obs, model, settings.huber_k, settings.iterations, theta0=theta, mean_height=mh)
        passes += 1
    sol.residual_before_rms_m = before_rms
    return sol, first, obs, passes


def mean_height_row(model: Model) -> np.ndarray:
    """(K,) g with g theta the mean vertical correction (m) over every planar cell of every strip (``model.jac``:
    the cells' effect Jacobians), each cell one sample of the block's surface."""
    g = np.zeros(len(model.names))
    n = 0
    for J, cols in model.jac.values():
        g[cols] += J[:, 2, :].sum(axis=0)
        n += len(J)
    return g / max(n, 1)


def control_summary(cps: ctl.ControlPoints, ss: ov.StripSet, first: Observations, theta: np.ndarray) -> ControlSummary:
    """The control points' distances above their strips' planes before and after the correction (the
    first read's observations and the linear model; metres)."""
    co = first.control
    k0 = len(first.y) - len(co.y)
    after = co.y - first.G[k0:] @ theta
    rows = tuple(ControlResidual(cps.ids[p], ss.strips[s].name, float(b), float(a))
                 for p, s, b, a in zip(co.point, co.strip, co.y, after))
    return ControlSummary(str(cps.path), len(cps.ids), int(len(np.unique(co.point))), int(len(co.y)),
                          float(co.y.mean()), float(after.mean()), float(np.sqrt(np.mean(co.y ** 2))),
                          float(np.sqrt(np.mean(after ** 2))), rows)


def adjust_strips(paths, outdir, settings: StripAdjustSettings = StripAdjustSettings(),
                  surface: ov.SurfaceSettings = ov.SurfaceSettings(), *, trajectories=(), crs=None, png: bool = True,
                  control=None, option: str | None = "OUTDIR") -> StripAdjustResult:
    """The stage: estimate, write the corrected strips and the check before and after into OUTDIR
    (``<strip files>``, ``adjust.json``, ``check_before/``, ``check_after/``). Returns what adjust.json holds.
    ``option``: what a refusal names (None: the folder only, the chain's)."""
    t0 = time.perf_counter()
    paths = [Path(p) for p in paths]
    outdir = Path(outdir)
    refuse_input_as_output(outdir, paths, option)
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    for p in paths:
        refuse_input_as_output(outdir / p.name, paths, option)
    chk.refuse_replacing(outdir, paths, option)
    if len({p.name for p in paths}) < len(paths):
        raise InputError("strips with the same file name: the corrected strips are written under their names")
    # the check's slope limit for the reports; the adjustment reads steeper cells too
    read_params = dataclasses.replace(surface, max_slope_deg=max(surface.max_slope_deg, settings.max_slope_deg))
    extra, chosen = (None, {})
    resolved, units = io.resolve_crs_units(paths[0], las.read_header(paths[0]), crs)
    # the CRS record a strip without one gets, as classify's: the corrected strips had none, and the next stage refused
    # them (trial s96 F3)
    out_crs = io.record_crs(crs, resolved)
    cps = ctl.read_control(control, units) if control is not None else None
    if trajectories:
        trajs = tj.read_trajectories(trajectories, units.xy_m, units.z_m)
        extra, chosen = boresight_extra(trajs)
    ss = ov.read_strip_planes(paths, read_params, crs, extra=extra)
    before = chk.analyse(ss, surface, paths)
    t_read = time.perf_counter()
    model = boresight_model(ss, chosen, settings.shift_sigma_m) if trajectories else \
        strip_model(ss, settings.fixed, controlled=cps is not None)
    sol, first, obs, passes = estimate(paths, ss, model, settings, read_params, crs=crs, extra=extra, control=cps)
    warnings = []
    held = undetermined_sensor(model, sol)
    if held:
        adjusted = len({s for pair in obs.pairs for s in pair if s != "control"})
        warnings.append(held_text(model, sol, held, adjusted))
        log.info("strip adjustment: %s held at 0, adjusted again", ", ".join(model.names[k] for k in held))
        model.prior_sigma = model.prior_sigma.copy()
        model.prior_sigma[held] = HELD_SIGMA
        model.jac = model.jac_of(ss)
        sol, first, obs, passes = estimate(paths, ss, model, settings, read_params, crs=crs, extra=extra,
                                           control=cps)
    model.jac = {}  # the cells' Jacobians are not needed any more
    t_solve = time.perf_counter()
    with atomic_dir(outdir) as tmp:
        corrected = write_corrected(ss, model, sol.theta, tmp, crs=out_crs)
        t_write = time.perf_counter()
        ss_after = ov.read_strip_planes(corrected, surface, crs)
        after = chk.analyse(ss_after, surface, corrected)
        # the corrected strips as they are found after the commit: in OUTDIR, not in the temporary folder
        after.summary = dataclasses.replace(after.summary, strips=tuple(
            dataclasses.replace(t, file=str(outdir / Path(t.file).name)) for t in after.summary.strips))
        vmax = chk.colour_limit_m(before.pairs)
        for name, res in (("check_before", before), ("check_after", after)):
            (tmp / name).mkdir()
            chk.write_outputs(res, tmp / name, f"Strip differences {name.split('_')[1]} adjustment", vmax, png)
            (tmp / name / "strips.json").write_text(res.summary.to_json())
        dt = time.perf_counter() - t0
        report = parameter_report(model, sol)
        fixed = settings.fixed if model.kind == "strip" else None
        if model.kind == "strip" and settings.fixed is None:
            fixed = next((s.name for s in ss.strips if not any(n.startswith(f"{s.name}.") for n in model.names)), None)
        datum = DATUM_CONTROL if cps is not None else (f"strip {fixed} fixed" if fixed else DATUM_MEAN_HEIGHT)
        summary = StripAdjustResult(
            model=model.kind, fixed_strip=fixed, settings=settings, cell_m=ss.grid.cell_m, points=ss.n_points,
            strips=tuple(s.name for s in ss.strips), observations=int(len(obs.y)), reads=passes,
            observations_per_pair={f"{a}-{b}": int(np.sum(obs.pair == i)) for i, (a, b) in enumerate(obs.pairs)},
            downweighted=sol.downweighted, sigma0=sol.sigma0,
            # strips that share no planar cell with another: their parameters stay at the prior (not corrected)
            strips_without_observations=tuple(s.name for s in ss.strips
                                              if not any(s.name in pair for pair in obs.pairs)),
            plane_distance_rms_before_m=sol.residual_before_rms_m,
            plane_distance_rms_after_m=sol.residual_after_rms_m,
            **{f.name: getattr(report, f.name) for f in dataclasses.fields(ParameterReport)},
            check_before=before.summary.all_pairs, check_after=after.summary.all_pairs,
            files=tuple(p.name for p in corrected),
            seconds=dt, points_per_s=ss.n_points / dt,
            seconds_read=t_read - t0, seconds_solve=t_solve - t_read, seconds_write=t_write - t_solve,
            control=control_summary(cps, ss, first, sol.theta) if cps is not None else None, datum=datum,
            warnings=tuple(warnings) + prior_bound_warnings(model, sol, settings.shift_sigma_m),
            held=tuple(model.names[k] for k in held))
        for text in summary.warnings:
            log.warning(text)
        (tmp / "adjust.json").write_text(summary.to_json())
        from aerotri.core.pages import render

        # the calibration for a QA reader beside the two checks' pages (trial s98: adjust.json and the console only)
        (tmp / "index.html").write_text(render("strips_adjust.html.j2", package="lidarctl", s=summary))
    return summary
