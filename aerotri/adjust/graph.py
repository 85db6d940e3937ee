"""The bundle block adjustment as a GTSAM factor graph (C++ factors only in the inner loop).

Unknowns (symbols): ``x`` camera poses (gtsam Pose3: computer-vision camera -> local ENU, i.e.
``R_cv = R_opk @ FLIP_YZ`` and the projection centre), ``p`` object points, ``k`` the Cal3DS2
calibration (when self-calibrating), ``a`` GNSS antenna positions, ``l`` the lever arm, ``s``/``d``
per-strip GNSS shift (m) and drift (m/km).

Observation equations and their factors:

- image point: collinearity with Cal3DS2 -> GenericProjectionFactorCal3DS2 (fixed camera) or
  GeneralSFMFactor2Cal3DS2 (self-calibration), isotropic ``image_sigma_px``;
- tie points: not unknowns of the gtsam graph. Each iteration linearises their rays in numba and
  eliminates the points by the Schur complement (``aerotri.adjust.schur``: the reduced camera system of
  Ceres' Schur solvers), hands the reduced blocks to gtsam as HessianFactors next to gtsam's
  linearisation of all other factors, and back-substitutes the point increments after gtsam's
  elimination; a self-calibration's Cal3DS2 unknown is part of that reduced system, and robust solves
  weigh the rays with Huber's kernel there (iteratively reweighted). Control points stay unknowns of the
  graph (they carry priors), and so does every point with ``SolveSettings.eliminate_tie_points`` off;
- GNSS, no correction: ``g = C + R l`` -> GPSFactorArm;
- GNSS with shift/drift: ``a_i = C_i + R_i l`` (ReferenceFrameFactorPoint3Pose3 as a hard constraint)
  and the linear ``g_i = a_i + s_strip + t_i d_strip`` (t = along-track km) -> JacobianFactor in a
  LinearContainerFactor (exact, the equation is linear);
- GNSS with one offset for the flight (``gnss_correction = "offset"``, a consumer receiver): as the shift, with
  one shift ``s`` common to every image (``shift_index``);
- a-priori sigma of the shifts (``Block.gnss_offset_sigma_m``, a receiver's absolute accuracy): a prior
  ``s = 0`` on each shift, so that the shifts carry a datum of that precision without control;
- control point: prior on the object point with its covariance rotated into ENU (a horizontal point
  has a loose height, a height point loose planimetry);
- calibration parameters not estimated: tight priors.

Solution (``optimize``): with Schur-eliminated tie points, Levenberg-Marquardt on the reduced camera
system (pure Gauss-Newton while its steps lower the cost). A block without GNSS has its datum in the
control points alone; with loose control heights its tilt is then held so weakly that the iteration creeps
along it (a rotation is not linear in the unknowns), so a datum step (``aerotri.adjust.datum``: the block
moved by the best-fitting similarity onto its control points) precedes and follows each step.

Degrees of freedom count only real observations: 2 per image point, 3 per GNSS position, the
constrained components of control points; hard constraints add as many equations as unknowns.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import time

import gtsam
import numpy as np

from aerotri.adjust import datum, schur
from aerotri.adjust.cpp_output import gtsam_quiet
from aerotri.adjust import surface as surface_mod
from aerotri.adjust.surface import SurfaceControl
from aerotri.adjust.check_points import intersect
from aerotri.adjust.collinearity import point_jacobian_cv, point_normals, project_cv
from aerotri.adjust.keys import A, D, K_KEY, L_KEY, P, S, X
from aerotri.adjust.settings import GNSS_CORRECTIONS, SELF_CAL_GROUP_NAMES
from aerotri.core.errors import CrsError, InputError, SolveError
from aerotri.geom.camera import SELF_CALIBRATION_GROUPS, Camera
from aerotri.geom.rotation import FLIP_YZ

# every self-calibration group a camera model offers; which Cal3DS2 entries each frees is the camera's
# ``SELF_CAL_GROUPS``
SELF_CAL_GROUPS = SELF_CALIBRATION_GROUPS
log = logging.getLogger(__name__)
# an iteration line at most this often (s): a 10,000-frame block's solve was silent for 1-2.7 min (trial s97 M1)
PROGRESS_S = 20.0
assert tuple(SELF_CAL_GROUPS) == SELF_CAL_GROUP_NAMES  # the light settings module spells them out
LOOSE_SIGMA_M = 1.0e3  # sigma of the unconstrained components of horizontal/height control


@dataclasses.dataclass(kw_only=True)
class Block:
    """Adjustment inputs in the local frame; observations refer to images and points by index."""

    image_id: list[str]
    camera: Camera  # a-priori interior orientation
    point_id: np.ndarray  # (P,) tie and control point ids
    obs_point: np.ndarray  # (K,) int
    obs_image: np.ndarray  # (K,) int
    obs_xy_px: np.ndarray  # (K, 2)
    gnss_local: np.ndarray | None  # (N, 3) antenna positions ENU
    gnss_sigma_m: np.ndarray | None  # (N, 3)
    lever_arm_m: np.ndarray  # (3,) photogrammetric camera frame
    strip: np.ndarray  # (N,) int
    along_km: np.ndarray  # (N,)
    control_point: np.ndarray  # (C,) int, index into points
    control_local: np.ndarray  # (C, 3) given coordinates in ENU
    control_cov_local: np.ndarray  # (C, 3, 3)
    control_rows: np.ndarray  # (C,) number of constrained components (3 full, 2 horizontal, 1 height)
    surface: SurfaceControl | None = None  # the DEM the tie points on the ground are held to
    surface_active: np.ndarray | None = None  # (P,) bool: points whose surface observation is used
    # (3,) ENU a-priori sigma of each GNSS shift (the receiver's absolute accuracy, m); None: shifts unconstrained
    gnss_offset_sigma_m: np.ndarray | None = None

    @property
    def n_images(self):
        return len(self.image_id)

    @property
    def n_points(self):
        return len(self.point_id)

    @property
    def n_strips(self):
        return int(self.strip.max()) + 1 if len(self.strip) else 0

    @property
    def gnss_used(self) -> np.ndarray | None:
        """(N,) the GNSS positions observed (``gnss_observed``)."""
        return None if self.gnss_sigma_m is None else gnss_observed(self.gnss_sigma_m)


def gnss_observed(sigma_m) -> np.ndarray:
    """(N,) which of the positions with sigmas ``sigma_m`` (N, 3) are observed: a position left out (off its flight
    line, or off its frame's rays: ``pipeline.GnssLeftOut``) has an infinite sigma, weight 0, and no factor."""
    return np.all(np.isfinite(np.asarray(sigma_m, dtype=float)), axis=1)


# the solve's GNSS models: the settings' corrections per strip, and one offset for the whole flight (a consumer
# receiver's common error; chosen by project.toml [gnss] offset_sigma_xy_m, not by a correction setting)
GNSS_MODELS = GNSS_CORRECTIONS + ("offset",)


def shift_index(block: Block, correction: str) -> np.ndarray:
    """(N,) the GNSS shift each image's position takes: its strip's, or the flight's one (``offset``)."""
    if correction == "offset":
        return np.zeros(block.n_images, dtype=int)
    return np.asarray(block.strip, dtype=int)


def n_shifts(block: Block, correction: str) -> int:
    """How many GNSS shifts the solve estimates (0 without a correction)."""
    return 0 if correction == "none" else 1 if correction == "offset" else block.n_strips


@dataclasses.dataclass
class SolveSettings:
    image_sigma_px: float = 0.5
    gnss_correction: str = "none"  # GNSS_MODELS: none | shift | shift_drift | offset
    self_calibration: tuple = ()  # subset of SELF_CAL_GROUPS
    huber_k: float = 2.5  # robust kernel threshold in standard deviations
    max_iterations: int = 100
    relative_tolerance: float = 1e-8
    ordering: str = "METIS"  # LM elimination ordering (METIS | COLAMD)
    linear_solver: str = "MULTIFRONTAL_CHOLESKY"  # or SEQUENTIAL_CHOLESKY
    diagonal_damping: bool = False  # gtsam LM (robust, explicit-point solves): Marquardt (diag(H)), not Levenberg (I)
    eliminate_tie_points: bool = True  # Schur-eliminate the tie points (see module docstring)

    def __post_init__(self):
        if self.gnss_correction not in GNSS_MODELS:
            raise InputError(f"GNSS correction {self.gnss_correction!r} is not one of {GNSS_MODELS}")
        bad = sorted(set(self.self_calibration) - set(SELF_CAL_GROUPS))
        if bad:
            raise InputError(f"self-calibration parameters {bad} are not among {sorted(SELF_CAL_GROUPS)}")


@dataclasses.dataclass
class State:
    """Values of the unknowns (local frame)."""

    centre: np.ndarray  # (N, 3)
    R_cv: np.ndarray  # (N, 3, 3) computer-vision camera -> ENU
    points: np.ndarray  # (P, 3)
    cal: np.ndarray  # (9,) fx fy s u0 v0 k1 k2 p1 p2 (pixels, Cal3DS2)
    shift: np.ndarray  # (S, 3)
    drift: np.ndarray  # (S, 3)

    def copy(self) -> "State":
        return State(*(np.array(getattr(self, f.name), copy=True) for f in dataclasses.fields(self)))


def cal_from_camera(cam: Camera) -> np.ndarray:
    """The Cal3DS2 values of a camera (``Camera.calibration_vector``)."""
    return cam.calibration_vector()


def estimated_or_apriori(cal, camera: Camera, groups) -> np.ndarray:
    """Cal3DS2 values ``cal`` (9,) with every entry no group of ``groups`` estimates set back to ``camera``'s own: the
    priors that hold those entries let them move by a fraction of their ``fixed_parameter_sigmas`` (the demo: fx by
    5e-4 px, p1 by -1.3e-7), and a parameter not estimated is written and reported as given (trial s100 exchange
    F3: 120.0000088 mm in at/camera.toml for the 120 mm held)."""
    out = cal_from_camera(camera).astype(float)
    free = ~held_entries(camera, groups)
    out[free] = np.asarray(cal, dtype=float)[free]
    return out


def held_entries(camera: Camera, groups) -> np.ndarray:
    """(9,) bool: the Cal3DS2 entries no self-calibration group of ``groups`` frees (held by priors in the solve);
    InputError for a group the camera's model has not."""
    fixed = np.ones(9, dtype=bool)
    for grp in groups:
        if grp not in camera.SELF_CAL_GROUPS:
            raise InputError(f"self-calibration group {grp!r}: the {camera.MODEL} camera model has only "
                             f"{', '.join(camera.SELF_CAL_GROUPS)}")
        fixed[list(camera.SELF_CAL_GROUPS[grp])] = False
    return fixed


def camera_from_cal(cal, like: Camera) -> Camera:
    """``like`` with the interior orientation of Cal3DS2 values (``Camera.from_calibration_vector``)."""
    return like.from_calibration_vector(cal)


def fixed_parameter_sigmas(cam: Camera, cal, effect_px: float = 0.01) -> np.ndarray:
    """Prior sigmas (9,) that hold calibration parameters which are not estimated: each may move the
    image corner by ``effect_px`` at most. Tighter priors (1e-8) add information of 1e16 to the normal
    equations, which makes the Cholesky factorisation fail at small LM damping (LM then crawls)."""
    r = 0.5 * np.hypot(cam.width, cam.height) / cal[0]  # normalised radius of the corner
    f = cal[0]
    return effect_px * np.array([1 / r, 1 / r, 1 / r, 1.0, 1.0, 1 / (f * r**3), 1 / (f * r**5), 1 / (3 * f * r**2), 1 / (3 * f * r**2)])


def _cal3ds2(cal) -> gtsam.Cal3DS2:
    return gtsam.Cal3DS2(*[float(v) for v in cal])


def _pose(C, R_cv) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.asarray(R_cv, dtype=float)), np.asarray(C, dtype=float))


@dataclasses.dataclass
class TiePoints:
    """Tie points eliminated by the Schur complement: their rays, grouped by point, and coordinates."""

    point: np.ndarray  # (M,) point indices
    pairs: schur.RayPairs  # rays grouped by point and their pairs (observation indices in pairs.obs)
    xy_px: np.ndarray  # (K, 2) measured pixels of the rays, in pairs.obs order
    image: np.ndarray  # (K,) image index of each ray
    coords: np.ndarray  # (M, 3) current coordinates (local frame), updated by the solve
    cal: np.ndarray  # (9,) Cal3DS2 values (fixed, or the start of self-calibration)
    sigma_px: float
    self_cal: bool  # the calibration is the unknown K_KEY
    huber_k: float = 0.0  # > 0: robust solve, Huber's kernel at huber_k standard deviations
    surface: SurfaceControl | None = None  # surface heights of the points with ``surface_active``
    surface_active: np.ndarray | None = None  # (M,) bool
    work: schur.Workspace | None = None  # the reduced system's arrays, reused by every linearisation of these rays
    # (N, 6, 6) the diagonal blocks of the reduced camera system at the solve's last linearisation (unit weight, pose
    # tangent [omega, v]): each orientation's information with the others held, its tie points free
    pose_information: np.ndarray | None = None

    def _surface(self, coords: np.ndarray):
        """Whitened surface observations of the points (``surface.whitened``), zeros without surface."""
        if self.surface is None:
            return np.zeros(len(coords)), np.zeros((len(coords), 3)), 0.0
        return surface_mod.whitened(self.surface, coords, self.surface_active, self.huber_k)

    def _cameras(self, values: gtsam.Values, n_images: int):
        centre, R_cv = orientations_from_values(values, n_images)
        cal = np.asarray(values.atCal3DS2(K_KEY).vector(), dtype=float) if self.self_cal else self.cal
        return centre, R_cv, cal

    def reduced_system(self, values: gtsam.Values, n_images: int, coords: np.ndarray, point_damping: float = 0.0
                       ) -> schur.ReducedSystem:
        """``schur.reduced_camera_system`` at the orientations (and calibration) in ``values`` and the points ``coords``."""
        centre, R_cv, cal = self._cameras(values, n_images)
        pr = self.pairs
        point_r, point_B, _ = self._surface(coords)
        if self.work is None:
            self.work = schur.Workspace.for_rays(len(pr.row), len(pr.start) - 1, n_images, len(pr.images), self.self_cal)
        return schur.ReducedSystem(*schur.reduced_camera_system(
            self.xy_px, self.image, pr.row, pr.start, pr.a, pr.b, pair_block=pr.pair_block, n_blocks=len(pr.images),
            n_images=n_images, centre=centre, R_cv=R_cv, points=coords, cal=cal, inv_sigma=1.0 / self.sigma_px,
            with_cal=self.self_cal, huber_k=self.huber_k, point_r=point_r, point_B=point_B,
            point_damping=float(point_damping),
            work=self.work))

    def updated(self, rs: schur.ReducedSystem, delta: gtsam.VectorValues, n_images: int, coords: np.ndarray) -> np.ndarray:
        """The point coordinates after the back-substitution of the solved increments ``delta``."""
        d_pose = np.array([delta.at(X(i)) for i in range(n_images)])
        d_cal = np.asarray(delta.at(K_KEY), dtype=float) if self.self_cal else np.zeros(9)
        return coords + schur.point_increments(rs.Vinv, rs.b_point, rs.W, rs.Z, self.image, self.pairs.start,
                                               d_pose=d_pose, d_cal=d_cal)

    def sum_of_squares(self, values: gtsam.Values, n_images: int, coords: np.ndarray) -> float:
        centre, R_cv, cal = self._cameras(values, n_images)
        rays = float(schur.sum_of_squares(self.xy_px, self.image, self.pairs.row, centre, R_cv, coords, cal=cal,
                                          inv_sigma=1.0 / self.sigma_px, huber_k=self.huber_k))
        if self.surface is None:
            return rays
        return rays + surface_mod.surface_cost(self.surface, coords, self.surface_active, self.huber_k)


@dataclasses.dataclass
class ControlDatum:
    """Control points that carry the datum alone (no GNSS), for the datum step: point indices, given
    coordinates (local frame) and their covariances, and their rays (pixels, image, row into ``point``)."""

    point: np.ndarray  # (n,)
    given_m: np.ndarray  # (n, 3)
    cov_m2: np.ndarray  # (n, 3, 3)
    xy_px: np.ndarray  # (K, 2)
    image: np.ndarray  # (K,)
    row: np.ndarray  # (K,)
    sigma_px: float


@dataclasses.dataclass
class Graph:
    graph: gtsam.NonlinearFactorGraph  # with ``tie``: every factor except the tie points'
    values: gtsam.Values
    n_equations: int
    n_unknowns: int
    n_images: int
    robust: bool = False
    tie: TiePoints | None = None
    ordering: gtsam.Ordering | None = None  # elimination ordering, when computed here
    datum: ControlDatum | None = None  # with ``tie``: the datum step's control points (blocks without GNSS)

    @property
    def dof(self) -> int:
        return self.n_equations - self.n_unknowns

    def linearize(self, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
        """The linearised normal equations at ``values`` (tie points of ``tie`` at their own coordinates,
        already eliminated)."""
        with gtsam_quiet():
            if self.tie is None:
                return self.graph.linearize(values)
            try:
                return self.linearize_reduced(values, self.tie.coords)[0]
            finally:
                self.tie.work = None  # not held through the covariances that follow (1.4 GB at 6.5 M rays)

    def reduced_cost(self, values: gtsam.Values, coords: np.ndarray) -> float:
        """gtsam's error (half the chi-square; robust graphs: the robust cost) with the tie points of ``tie``
        at ``coords``."""
        with gtsam_quiet():
            return 0.5 * self.tie.sum_of_squares(values, self.n_images, coords) + self.graph.error(values)

    def linearize_reduced(self, values: gtsam.Values, coords: np.ndarray, point_damping: float = 0.0
                          ) -> tuple[gtsam.GaussianFactorGraph, schur.ReducedSystem]:
        """gtsam's linearisation of ``graph`` at ``values`` with the reduced camera system of the tie points
        at ``coords`` added as HessianFactors, and that reduced system (for the back-substitution);
        ``point_damping``: Marquardt's lambda on the points' normal blocks."""
        rs = self.tie.reduced_system(values, self.n_images, coords, point_damping)
        gfg = self.graph.linearize(values)
        gfg.push_back(schur.hessian_factors([X(i) for i in range(self.n_images)], rs, self.tie.pairs.images,
                                            K_KEY if self.tie.self_cal else None))
        return gfg, rs


def _tie_points(block: Block, obs: np.ndarray, state: State, sigma_px: float, self_cal: bool, huber_k: float) -> TiePoints:
    pr = schur.ray_pairs(obs, block.obs_point, block.obs_image, block.n_images)
    if len(pr.obs) == 0:
        raise SolveError("no tie point is left with two or more rays (the approximate orientations put every "
                         "intersection behind the cameras or far off: check the initial EO, --eo, or the GNSS)")
    point = block.obs_point[pr.obs][pr.start[:-1]]
    return TiePoints(point, pr, block.obs_xy_px[pr.obs], block.obs_image[pr.obs].astype(np.int64),
                     np.array(state.points[point], dtype=float), np.asarray(state.cal, dtype=float), float(sigma_px), self_cal,
                     float(huber_k))


def _add_projection_factors(g: gtsam.NonlinearFactorGraph, xy_px, image, point, noise, K) -> None:
    """Collinearity factors: a fixed camera ``K`` (Cal3DS2), or the calibration unknown ``K_KEY`` (K None)."""
    if K is None:
        for uv, i, j in zip(xy_px, image.tolist(), point.tolist()):
            g.add(gtsam.GeneralSFMFactor2Cal3DS2(uv, noise, X(i), P(j), K_KEY))
        return
    for uv, i, j in zip(xy_px, image.tolist(), point.tolist()):
        g.add(gtsam.GenericProjectionFactorCal3DS2(uv, noise, X(i), P(j), K))


# keys of one image or point; every other key (the calibration, the lever arm, a strip's GNSS shift and drift)
# couples to many images
_LOCAL_KEY_CHARS = frozenset(b"xap")


def _tie_ordering(gr: Graph) -> gtsam.Ordering:
    """Elimination ordering of the reduced system: METIS on the orientation adjacency (image pairs sharing a tie
    point) and the keys of every other factor, without the keys that couple to many images (calibration, lever
    arm, GNSS shift and drift per strip), which come last. With those hubs in its graph METIS cut the block
    into poorer parts: on 3,000 frames the elimination took 1.14 s instead of 0.40 s (increments equal to 3e-12)."""
    def local(key):
        return gtsam.Symbol(key).chr() in _LOCAL_KEY_CHARS

    sg = gtsam.SymbolicFactorGraph()
    for i in range(gr.n_images):
        sg.push_factor(X(i))
    for i, j in gr.tie.pairs.images.tolist():
        sg.push_factor(X(i), X(j))
    hubs = {K_KEY} if gr.tie.self_cal else set()
    for n in range(gr.graph.size()):
        keys = list(gr.graph.at(n).keys())
        hubs.update(k for k in keys if not local(k))
        keys = [k for k in keys if local(k)]
        if len(keys) == 1:
            sg.push_factor(keys[0])
        for a, c in itertools.combinations(keys, 2):
            sg.push_factor(a, c)
    ordering = gtsam.Ordering.MetisSymbolicFactorGraph(sg)
    for k in sorted(hubs):
        ordering.push_back(k)
    return ordering


def build_graph(block: Block, opts: SolveSettings, state: State, obs_active, control_active, robust: bool) -> Graph:
    """The factor graph for the active image observations and control points, initialised at ``state``."""
    obs_active = np.asarray(obs_active, dtype=bool)
    control_active = np.asarray(control_active, dtype=bool)
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    self_cal = bool(opts.self_calibration)
    used_points = np.unique(block.obs_point[obs_active])
    n_eq = n_unk = 0
    schur_tie = opts.eliminate_tie_points
    explicit = np.ones(block.n_points, dtype=bool)  # points that are unknowns of the graph
    if schur_tie:
        explicit[:] = False
        explicit[block.control_point[control_active]] = True

    for i in range(block.n_images):
        v.insert(X(i), _pose(state.centre[i], state.R_cv[i]))
    n_unk += 6 * block.n_images
    for j in used_points[explicit[used_points]]:
        v.insert(P(j), np.asarray(state.points[j], dtype=float))
    n_unk += 3 * len(used_points)

    # image observations
    base = gtsam.noiseModel.Isotropic.Sigma(2, opts.image_sigma_px)
    noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(opts.huber_k), base) if robust else base
    idx = np.flatnonzero(obs_active)
    if self_cal:
        v.insert(K_KEY, _cal3ds2(state.cal))
        sig = np.array([200.0, 200.0, 1e-3, 200.0, 200.0, 0.05, 0.05, 0.01, 0.01])  # loose a-priori
        fixed = held_entries(block.camera, opts.self_calibration)
        # the prior is the a-priori camera, wherever this solve starts: a prior re-centred on the state of
        # each rebuild (robust rounds, snooping) would let the parameters held fixed drift by a sigma per round
        apriori = cal_from_camera(block.camera)
        held = fixed_parameter_sigmas(block.camera, apriori)
        sig[fixed] = held[fixed]
        info = np.diag(1.0 / sig**2)
        n_free = int((~fixed).sum())
        if not fixed[0] and not fixed[1]:
            # one focal length (square pixels, camera.toml's focal_mm): fx - fy held at the camera's as a fixed
            # parameter is; free apart, the two took an aspect ratio the written camera has not (NGI: 833.79 / 833.14)
            a = np.zeros(9)
            a[0], a[1] = 1.0, -1.0
            info += np.outer(a, a) / held[0] ** 2
            n_free -= 1
        g.add(gtsam.PriorFactorCal3DS2(K_KEY, _cal3ds2(apriori), gtsam.noiseModel.Gaussian.Information(info)))
        n_unk += n_free
    k = idx[explicit[block.obs_point[idx]]]
    _add_projection_factors(g, block.obs_xy_px[k], block.obs_image[k], block.obs_point[k], noise,
                            None if self_cal else _cal3ds2(state.cal))
    n_eq += 2 * len(idx)

    # GNSS
    lever_cv = FLIP_YZ @ block.lever_arm_m
    if block.gnss_local is not None:
        used = block.gnss_used
        n_eq += 3 * int(used.sum())
        if opts.gnss_correction == "none":
            for i in np.flatnonzero(used):
                g.add(gtsam.GPSFactorArm(X(i), block.gnss_local[i], lever_cv, gtsam.noiseModel.Diagonal.Sigmas(block.gnss_sigma_m[i])))
        else:
            drift = opts.gnss_correction == "shift_drift"
            v.insert(L_KEY, lever_cv)
            g.add(gtsam.PriorFactorPoint3(L_KEY, lever_cv, gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
            n_shift, shift_of = n_shifts(block, opts.gnss_correction), shift_index(block, opts.gnss_correction)
            observed = np.bincount(shift_of[used], minlength=n_shift) > 0
            for s in range(n_shift):
                v.insert(S(s), np.asarray(state.shift[s], dtype=float))
                if not observed[s]:  # every position of the strip left out: its shift (and drift) held at zero
                    g.add(gtsam.PriorFactorPoint3(S(s), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
                    if drift:
                        g.add(gtsam.PriorFactorPoint3(D(s), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
                    n_eq += 3 * (2 if drift else 1)
                if drift:
                    v.insert(D(s), np.asarray(state.drift[s], dtype=float))
                if block.gnss_offset_sigma_m is not None:  # the receiver's absolute accuracy bounds each shift
                    prior = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(block.gnss_offset_sigma_m, dtype=float))
                    g.add(gtsam.PriorFactorPoint3(S(s), np.zeros(3), prior))
                    n_eq += 3
            n_unk += 3 * n_shift * (2 if drift else 1)
            hard = gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)
            I3 = np.eye(3)
            for i in range(block.n_images):
                a = state.centre[i] + state.R_cv[i] @ lever_cv
                v.insert(A(i), a)
                g.add(gtsam.ReferenceFrameFactorPoint3Pose3(L_KEY, X(i), A(i), hard))
                if not used[i]:
                    continue
                s, t = int(shift_of[i]), float(block.along_km[i])
                lin = gtsam.Values()
                lin.insert(A(i), a)
                lin.insert(S(s), np.asarray(state.shift[s], dtype=float))
                pred = a + state.shift[s]
                model = gtsam.noiseModel.Diagonal.Sigmas(block.gnss_sigma_m[i])
                if drift:
                    lin.insert(D(s), np.asarray(state.drift[s], dtype=float))
                    pred = pred + t * state.drift[s]
                    jf = gtsam.JacobianFactor(A(i), I3, S(s), I3, D(s), t * I3, block.gnss_local[i] - pred, model)
                else:
                    jf = gtsam.JacobianFactor(A(i), I3, S(s), I3, block.gnss_local[i] - pred, model)
                g.add(gtsam.LinearContainerFactor(jf, lin))

    # control points
    for c in np.flatnonzero(control_active):
        j = block.control_point[c]
        if not v.exists(P(j)):
            continue
        cov = block.control_cov_local[c]
        model = gtsam.noiseModel.Gaussian.Covariance(cov)
        if robust:
            model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(opts.huber_k), model)
        g.add(gtsam.PriorFactorPoint3(P(j), block.control_local[c], model))
        n_eq += int(block.control_rows[c])
    gr = Graph(g, v, n_eq, n_unk, block.n_images, robust)
    if schur_tie:
        gr.tie = _tie_points(block, idx[~explicit[block.obs_point[idx]]], state, opts.image_sigma_px, self_cal,
                             opts.huber_k if robust else 0.0)
        if block.surface is not None and block.surface_active is not None:
            gr.tie.surface = block.surface.of_points(gr.tie.point)  # each point keeps its roof face
            gr.tie.surface_active = np.asarray(block.surface_active, dtype=bool)[gr.tie.point]
            n_eq += int(gr.tie.surface_active.sum())
            gr.n_equations = n_eq
        gr.ordering = _tie_ordering(gr)
        ctrl = [c for c in np.flatnonzero(control_active) if v.exists(P(block.control_point[c]))]
        if block.gnss_local is None and len(ctrl) >= 3:
            point = block.control_point[ctrl]
            row = np.full(block.n_points, -1)
            row[point] = np.arange(len(point))
            gr.datum = ControlDatum(point, block.control_local[ctrl], block.control_cov_local[ctrl], block.obs_xy_px[k],
                                    block.obs_image[k], row[block.obs_point[k]], float(opts.image_sigma_px))
    return gr


@dataclasses.dataclass
class SolveInfo:
    iterations: int
    chi2: float  # sum of squared standardised residuals (2 x graph error)
    dof: int
    seconds: float
    converged: bool


def _ordered(params, ordering: gtsam.Ordering | None, opts: SolveSettings):
    params.setMaxIterations(opts.max_iterations)
    params.setRelativeErrorTol(opts.relative_tolerance)
    params.setAbsoluteErrorTol(0.0)
    if ordering is not None:
        params.setOrdering(ordering)
    else:
        params.setOrderingType(opts.ordering)
    params.setLinearSolverType(opts.linear_solver)
    return params


def _step_test(cost: float, new_cost: float, tol: float) -> tuple[bool, bool]:
    """Gauss-Newton step test: (accept the step, stop as converged). A step that raises the cost beyond
    the tolerance (or is not finite) is rejected unconverged: Levenberg-Marquardt goes on from the last
    good values. No decrease within the tolerance: at the minimum, keep the old values. A decrease of at
    most ``tol`` (relative): accepted and converged."""
    if not np.isfinite(new_cost) or new_cost > cost * (1.0 + tol):
        return False, False
    if new_cost >= cost:
        return False, True
    return True, cost - new_cost <= tol * cost


def _gauss_newton(gr: Graph, opts: SolveSettings) -> tuple[gtsam.Values, int, bool]:
    """Gauss-Newton steps while each lowers the cost: (last good values, iterations, converged). Stops
    unconverged at the first step that does not, or at a system too ill-conditioned to solve undamped,
    for Levenberg-Marquardt to go on from the last good values."""
    opt = gtsam.GaussNewtonOptimizer(gr.graph, gr.values, _ordered(gtsam.GaussNewtonParams(), gr.ordering, opts))
    good, cost = gr.values, opt.error()
    for it in range(1, opts.max_iterations + 1):
        try:
            opt.iterate()
        except RuntimeError:  # indeterminate without damping
            return good, it - 1, False
        new_cost = opt.error()
        accept, converged = _step_test(cost, new_cost, opts.relative_tolerance)
        if accept:
            good, cost = gtsam.Values(opt.values()), new_cost  # a copy: the optimizer owns what values() refers to
        if converged or not accept:
            return good, it if converged else it - 1, converged
    return good, opts.max_iterations, False


# Marquardt damping of the reduced system, relative to diag(N): first value, floor, and the value at which
# no step lowers the cost (gtsam's LM: 1e-5, 0, 1e5)
LAMBDA_FIRST, LAMBDA_MIN, LAMBDA_MAX = 1e-6, 1e-9, 1e6
# at the iteration limit, a solve whose last step lowered the cost by at most this share of it has converged
LIMIT_RELATIVE_TOLERANCE = 1e-6


def _key_diagonal(gfg: gtsam.GaussianFactorGraph) -> dict:
    """The diagonal of the normal matrix of ``gfg``, per key."""
    diag = {}
    for n in range(gfg.size()):
        f = gfg.at(n)
        d, off = np.diag(f.information()), 0
        for key in f.keys():
            m = 6 if gtsam.Symbol(key).chr() == ord("x") else 9 if key == K_KEY else 3
            diag[key] = diag.get(key, 0.0) + d[off:off + m]
            off += m
    return diag


def _damped(gfg: gtsam.GaussianFactorGraph, diag: dict, lam: float) -> gtsam.GaussianFactorGraph:
    """``gfg`` plus Marquardt's damping ``lam diag(N)`` (as gtsam's LM: diagonal clamped at 1e-6)."""
    out = gtsam.GaussianFactorGraph()
    out.push_back(gfg)
    for key, d in diag.items():
        out.push_back(gtsam.JacobianFactor(key, np.diag(np.sqrt(lam * np.maximum(d, 1e-6))), np.zeros(len(d)),
                                           gtsam.noiseModel.Unit.Create(len(d))))
    return out


def _datum_step(gr: Graph, values: gtsam.Values, coords: np.ndarray, cost: float) -> tuple[gtsam.Values, np.ndarray, float]:
    """The block moved by the similarity that brings its control points, as their rays intersect them,
    closest to their given coordinates (``aerotri.adjust.datum``), if that lowers the cost.

    The fit weighs each point with its given covariance plus its intersection's (image noise); points
    with a single ray or nearly parallel rays only follow. Orientations and tie points move with the
    similarity (their rays do not change); each control point becomes its moved intersection combined
    with its given coordinates (the least-squares estimate from both, linearised)."""
    dc = gr.datum
    centre, R_cv, cal = gr.tie._cameras(values, gr.n_images)
    now = np.array([values.atPoint3(P(j)) for j in dc.point.tolist()])
    meet, _ = intersect(dc.xy_px, dc.row, dc.image, centre, R_cv, cal, n_points=len(now))
    ok = np.all(np.isfinite(meet), axis=1)  # NaN: fewer than two usable rays
    meet[~ok] = now[~ok]
    _, pc = project_cv(meet[dc.row], centre[dc.image], R_cv[dc.image], cal)
    N = point_normals(point_jacobian_cv(pc, R_cv[dc.image], cal), dc.row, len(meet)) / dc.sigma_px**2
    ev = np.linalg.eigvalsh(N)
    ok &= ev[:, 0] > 1e-10 * ev[:, 2]
    if ok.sum() < 3:
        return values, coords, cost
    cov_X = np.linalg.inv(N[ok])
    fit = datum.fit_similarity(meet[ok], dc.given_m[ok], dc.cov_m2[ok] + cov_X)
    if not fit.cost_after < fit.cost_before:
        return values, coords, cost
    sim = fit.similarity
    moved = sim.apply(now)
    Xt = sim.apply(meet[ok])
    cov_t = sim.scale**2 * sim.R @ cov_X @ sim.R.T
    gain = cov_t @ np.linalg.inv(cov_t + dc.cov_m2[ok])
    moved[ok] = Xt + np.einsum("kij,kj->ki", gain, dc.given_m[ok] - Xt)
    centre, R_cv = sim.apply(centre), sim.rotate(R_cv)
    new = gtsam.Values(values)
    for i in range(gr.n_images):
        new.update(X(i), _pose(centre[i], R_cv[i]))
    for j, xyz in zip(dc.point.tolist(), moved):
        new.update(P(j), xyz)
    new_coords = sim.apply(coords)
    new_cost = gr.reduced_cost(new, new_coords)
    return (new, new_coords, new_cost) if new_cost < cost else (values, coords, cost)


def _schur_levenberg_marquardt(gr: Graph, opts: SolveSettings) -> tuple[gtsam.Values, np.ndarray, int, bool, float]:
    """Levenberg-Marquardt on the reduced camera system: (values, tie point coordinates, iterations,
    converged, chi-square).

    Undamped Gauss-Newton steps while they lower the cost (each one elimination of the reduced system);
    when a step does not, or the system cannot be factored undamped, Marquardt damping ``lam diag(N)`` on
    every unknown of the reduced system from then on, raised tenfold until a step lowers the cost and
    lowered tenfold after each success, down to LAMBDA_MIN. With the datum carried by control points alone
    (``gr.datum``), the datum step precedes the first step and follows every step. An iteration is one
    linearisation."""
    tp, n, tol = gr.tie, gr.n_images, opts.relative_tolerance
    values, coords = gr.values, tp.coords
    cost = gr.reduced_cost(values, coords)
    if gr.datum is not None:
        values, coords, cost = _datum_step(gr, values, coords, cost)
    lam, previous = 0.0, np.inf
    t_said = time.perf_counter()
    for it in range(1, opts.max_iterations + 1):
        if time.perf_counter() - t_said > PROGRESS_S:
            log.info(f"  iteration {it}: cost {2.0 * cost:.6g}, damping {lam:.3g}")
            t_said = time.perf_counter()
        gfg, rs = gr.linearize_reduced(values, coords)
        tp.pose_information = np.array(rs.U)  # a copy: the workspace is overwritten by the next linearisation
        diag, failure = None, None
        while True:
            if lam > 0.0 and tp.surface is not None:
                # the points' own problem is nonlinear with a surface: damp their back-substitution too
                gfg, rs = gr.linearize_reduced(values, coords, point_damping=lam)
                diag = None
            if lam > 0.0 and diag is None:
                diag = _key_diagonal(gfg)
            try:
                delta = (_damped(gfg, diag, lam) if lam > 0.0 else gfg).optimize(gr.ordering)
                new_values, new_coords = values.retract(delta), tp.updated(rs, delta, n, coords)
                new_cost, failure = gr.reduced_cost(new_values, new_coords), None
            except RuntimeError as exc:  # indeterminate without (enough) damping
                new_cost, failure = np.inf, exc
            except CrsError as exc:  # the trial step threw a point off the earth (a wild undamped step): damp it
                new_cost, failure = np.inf, exc
            accept, converged = _step_test(cost, new_cost, tol)
            if accept or converged:
                break
            lam = 10.0 * lam if lam > 0.0 else LAMBDA_FIRST
            if lam > LAMBDA_MAX:
                if failure is not None:
                    raise failure
                return values, coords, it - 1, False, 2.0 * cost
        if not accept:  # no lower cost within the tolerance: at the minimum
            return values, coords, it, True, 2.0 * cost
        previous = cost
        values, coords, cost = new_values, new_coords, new_cost
        lam = max(lam / 10.0, LAMBDA_MIN) if lam > 0.0 else 0.0
        if gr.datum is not None:
            values, coords, cost = _datum_step(gr, values, coords, cost)
        if previous - cost <= tol * previous:
            return values, coords, it, True, 2.0 * cost
    # stopped by the iteration limit: converged if the last step no longer lowered the cost noticeably, as the gtsam
    # path judges it (the kite block with 4 of its 10 targets as check points: damped steps along a flat valley, the
    # cost 8624.69 lowered by 7e-8 of it per step, 0.19 over 100 steps, was "Solution failed")
    return values, coords, opts.max_iterations, previous - cost <= LIMIT_RELATIVE_TOLERANCE * previous, 2.0 * cost


def optimize(gr: Graph, opts: SolveSettings) -> tuple[gtsam.Values, SolveInfo]:
    """``_optimize`` with gtsam's console lines captured and counted (``cpp_output``)."""
    with gtsam_quiet():
        return _optimize(gr, opts)


def _optimize(gr: Graph, opts: SolveSettings) -> tuple[gtsam.Values, SolveInfo]:
    """Least squares (robust graphs: Huber M-estimate, iteratively reweighted). With Schur-eliminated tie
    points (``gr.tie``): Levenberg-Marquardt on the reduced camera system, which is Gauss-Newton (the
    classical bundle iteration) while its steps lower the cost; the adjusted tie points are then in
    ``gr.tie.coords`` (``state_from_values(..., tie=gr.tie)``). With explicit points: Gauss-Newton in gtsam
    while its steps lower the cost and gtsam's Levenberg-Marquardt from the last good values when a step
    does not (robust graphs: Levenberg-Marquardt only)."""
    t0 = time.perf_counter()
    it, converged, result, chi2 = 0, False, gr.values, None
    try:
        if gr.tie is not None:
            try:
                result, gr.tie.coords, it, converged, chi2 = _schur_levenberg_marquardt(gr, opts)
            finally:
                gr.tie.work = None  # the solve's arrays (1.4 GB at 6.5 M rays) are not held past it
        else:
            if not gr.robust:
                result, it, converged = _gauss_newton(gr, opts)
            if not converged and it < opts.max_iterations:
                params = _ordered(gtsam.LevenbergMarquardtParams(), gr.ordering, opts)
                params.setMaxIterations(opts.max_iterations - it)
                params.setDiagonalDamping(opts.diagonal_damping)
                opt = gtsam.LevenbergMarquardtOptimizer(gr.graph, result, params)
                result = gtsam.Values(opt.optimize())
                n = int(opt.iterations())
                it += n
                converged = n < params.getMaxIterations()
                if not converged:
                    # stopped by the iteration limit: converged if one more step no longer reduces the error noticeably
                    e0 = opt.error()
                    opt.iterate()
                    converged = e0 - opt.error() <= LIMIT_RELATIVE_TOLERANCE * e0
                    result = gtsam.Values(opt.values())
    except RuntimeError as exc:
        raise SolveError(
            "the adjustment is singular (datum defect: too few control points or GNSS positions for "
            f"the chosen corrections, or images/points without enough rays): {exc}"
        ) from None
    if chi2 is None:
        chi2 = 2.0 * gr.graph.error(result)
    return result, SolveInfo(it, chi2, gr.dof, time.perf_counter() - t0, converged)


def orientations_from_values(values: gtsam.Values, n_images: int) -> tuple[np.ndarray, np.ndarray]:
    """Projection centres (N, 3) and rotations R_cv (N, 3, 3) of the images' poses in ``values``."""
    pose = [values.atPose3(X(i)) for i in range(n_images)]
    return np.array([p.translation() for p in pose]), np.array([p.rotation().matrix() for p in pose])


def state_from_values(values: gtsam.Values, block: Block, opts: SolveSettings, previous: State,
                      tie: TiePoints | None = None) -> State:
    """The unknowns in ``values`` and, given the graph's Schur-eliminated ``tie`` points, their coordinates."""
    st = previous.copy()
    st.centre, st.R_cv = orientations_from_values(values, block.n_images)
    explicit = np.ones(block.n_points, dtype=bool)
    if tie is not None:
        st.points[tie.point] = tie.coords
        explicit[tie.point] = False
    for j in np.flatnonzero(explicit).tolist():
        if values.exists(P(j)):
            st.points[j] = values.atPoint3(P(j))
    if values.exists(K_KEY):
        st.cal = np.asarray(values.atCal3DS2(K_KEY).vector(), dtype=float)
    for s in range(block.n_strips):
        if values.exists(S(s)):
            st.shift[s] = values.atPoint3(S(s))
        if values.exists(D(s)):
            st.drift[s] = values.atPoint3(D(s))
    return st


def image_residuals(block: Block, state: State) -> np.ndarray:
    """Residuals observed - computed (K, 2) in pixels for all observations."""
    uv, _ = project_cv(
        state.points[block.obs_point], state.centre[block.obs_image], state.R_cv[block.obs_image], state.cal
    )
    return block.obs_xy_px - uv

