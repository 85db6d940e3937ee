"""The ``adjust`` stage over a project folder: read, validate, adjust in the local frame, convert back.

Inputs: ``camera.toml``, ``gnss.txt`` (antenna positions), ``project.toml`` ([gnss] sigma_xy_m,
sigma_z_m, lever_arm_m; [control] sigmas; optional [adjust] options), ``at/tiepoints.csv``,
``control/points.csv``, ``control/image_points.csv``. Outputs in ``at/``: eo.txt (with standard
deviations), camera.toml (the camera eo.txt belongs to: self-calibrated, or the nominal one held fixed),
object_points.csv and report.txt/json/html, all written only after the whole adjustment succeeded. Exports to other software read these files (``aerotri.exchange``).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from aerotri.adjust import gnss_model, graph as G
from aerotri.adjust.approximate import (
    approximate_orientations,
    approximate_points,
    intersect_points,
    refine_orientations,
)
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.crs.definition import height_unit_m, horizontal_crs, linear_unit_m, project_crs, project_heights
from aerotri.adjust.surface import SurfaceControl, read_height_grid, read_roof_planes
from aerotri.geom.observations import (
    ControlPoints,
    ImageObservations,
    read_control_image_points,
    read_control_points,
    read_image_points,
    validate_references,
)
from aerotri.adjust.level_datum import height_datum, level_result
from aerotri.adjust.relative import ModelHeights
from aerotri.core.records import to_record
from aerotri.adjust.dem_check import tie_dem_check
from aerotri.adjust.determinability import check_groups, ground_observations
from aerotri.adjust.report_record import AdjustmentRecord, adjustment_record, record_inputs
from aerotri.adjust.solve import AdjustmentResult, adjust_block, check_point_errors
from aerotri.adjust.snooping import critical_value
from aerotri.adjust.variance_components import adjusted_gnss
from aerotri.geom.strips import along_track_km, flight_order, strips_from_track, track_blunders
from aerotri.geom.camera import BrownCamera, project_camera
from aerotri.geom.eo import ExteriorOrientations, check_block_crs, read_eo, read_gnss
from aerotri.core.atomic import commit_outputs, committed
from aerotri.core.errors import InputError, OptionError, SolveError
from aerotri.adjust.settings import DEFAULT_SURFACE_BIAS_SIGMA_M, AdjustSettings, for_project
from aerotri.core.project import Project
from aerotri.core.settings import Resolved, resolve, settings_of
from aerotri.geom.rotation import FLIP_YZ, opk_from_matrix


log = logging.getLogger(__name__)

# The version of the adjustment (approximations, the bundle solve, the datum, gross-error handling) the chain's
# adjust_first and adjust_final stamps hold beside ``aerotri.adjust.relative.RELATIVE_VERSION``: orientations
# adjusted by earlier code are adjusted again. Bump it when eo.txt, object_points.csv or the report change at the
# same inputs and settings. 1: s10-fixes (the algorithm as of main e4b26d8e). 2: s11-fixes: at/report.* holds the
# GNSS direction check (gnss-direction, 4dfc338f; judged by the strips' spread since s11-fixes) and the unmodelled
# drift in metres (c03bf566), which stamps of version 1 (since 086020cd) kept as up to date. 3: s13-fixes: the
# direction check's means are the strip means' unweighted average, its Bonferroni count the pairs tested. 4:
# pp-predictor: a principal point against a camera-fixed GNSS offset is flagged by the block's own estimate of the
# offset, its predicted ground effect from the normal equations (the report's verdict may change). 5: at-verdicts: the
# height control the data snooping left in is judged against the GNSS heights (``height_datum``), a principal point's
# flag explained by GNSS strip shifts names them (report.json gains keys; the verdict may turn weak). 6: lead
# 2026-12-02: tie points left out below the DEM fail its check, a control point whose rays were all removed is
# rejected by name, the Parameters figures and limits keep micrometres, object_points.csv's sigmas are metres.
ADJUST_VERSION = 6


@dataclasses.dataclass(kw_only=True)
class BlockAdjustment:
    """Everything the reports and exports need (project CRS where it says _map)."""

    project_name: str
    crs: str
    settings: AdjustSettings
    frame: LocalFrame
    camera_apriori: BrownCamera
    camera_adjusted: BrownCamera
    block: G.Block
    opts: G.SolveSettings
    result: AdjustmentResult
    eo_map: ExteriorOrientations
    points_map: np.ndarray  # (P, 3)
    points_sigma_map: np.ndarray  # (P, 3)
    control: ControlPoints
    control_index_of_point: dict  # point index -> control row
    check: dict  # id -> dict(measured, adjusted, sigma, rays)
    gnss_map: np.ndarray | None
    gnss_residual_m: np.ndarray | None  # (N, 3) adjusted antenna - observed (map axes)
    n_tie_points: int
    check_obs: ImageObservations | None
    components: int = 1
    components_without_control: int = 0  # of those parts, the ones no control point is measured in
    left_out: list = dataclasses.field(default_factory=list)  # LeftOutComponent
    datum_notes: list = dataclasses.field(default_factory=list)  # what the datum rests on (no GNSS), for the report
    # False: no height was measured (plan-only control, no GNSS, no DEM): heights relative to the control's ground
    heights_measured: bool = True
    heights: str | None = None  # the project's height system by name ([project] heights); None: ellipsoidal
    self_calibration_requested: tuple = ()  # the groups asked for (opts.self_calibration: those estimated)
    calibration_checks: list = dataclasses.field(default_factory=list)  # determinability.GroupCheck, every group
    dem_checks: list = dataclasses.field(default_factory=list)  # dem_check.DemCheck: surface control DEM, check DEM
    check_from_lidar: int = 0  # check points that are corners of the project's LiDAR (share its strip offsets)
    control_rays_left_out: tuple = ()  # (point, frame, px): blunders by the image model alone (relative.ray_blunders)
    gnss_left_out: tuple = ()  # GnssLeftOut: positions off their flight line, not observed (weight 0)


def _settings_from_project(project: Project, s: AdjustSettings | None) -> AdjustSettings:
    """The settings of an adjustment: ``s`` (None: the project's, ``project_settings``) with the lever arm of
    project.toml [gnss] when ``s`` gives none; roof planes need a DEM."""
    if s is None:
        s = project_settings(project).settings
    if s.lever_arm_m is None:
        s = dataclasses.replace(s, lever_arm_m=project.gnss.lever_arm_m)
    if s.planes is not None and s.dem is None:
        raise OptionError(f"roof planes {s.planes} without a DEM: the planes hold the tie points on roofs, the DEM "
                          "those on the ground; give --dem (or [adjust] dem) too", param="--planes")
    return s


def project_settings(project: Project, resolved: Resolved | None = None, *, first: bool = False) -> Resolved:
    """The adjustment settings of a project with their sources: ``resolved`` (``aerotri adjust``: [adjust] and the
    command line; None: [adjust] alone) completed from the project folder (``settings.for_project``; ``first``:
    the chain's first adjustment). ``aerotri adjust P`` and ``aerotri run`` both take their settings from here."""
    return for_project(project, resolved if resolved is not None else resolve(AdjustSettings, project), first=first,
                       datum_shortfall=project_datum_shortfall)


def connected_image_components(n_images, obs_point, obs_image) -> list[np.ndarray]:
    """Image index groups connected through common points."""
    n_points = int(obs_point.max()) + 1 if len(obs_point) else 0
    n = n_images + n_points
    m = coo_matrix((np.ones(len(obs_point)), (obs_image, n_images + obs_point)), shape=(n, n))
    _, labels = connected_components(m, directed=False)
    groups = {}
    for i in range(n_images):
        groups.setdefault(labels[i], []).append(i)
    return sorted((np.array(g) for g in groups.values()), key=len, reverse=True)


def datum_shortfall(control: ControlPoints, gnss: bool, correction: str, surface: bool = False,
                    gnss_offset: bool = False) -> str | None:
    """Why the control points cannot fix the datum with (or without) GNSS and its corrections, or None.
    With ``surface`` control (a DEM) the heights of every strip are observed: no height control is needed.
    With ``gnss_offset`` (project.toml [gnss] offset_sigma_xy_m: the shifts' a-priori sigma) the GNSS carries
    the datum to that sigma, which the report states."""
    if gnss and gnss_offset:
        return None
    n_xy = int(np.isin(control.kind, ["full", "horizontal"]).sum())
    n_z = int(np.isin(control.kind, ["full", "height"]).sum())
    if not gnss:
        # 2 plan points fix plan, scale and the rotation about the vertical; with fewer than 3 height points the
        # heights and the tilt are held at those of the approximate orientations (``height_datum``)
        need = (2, 0)
    elif correction == "shift":
        need = (1, 1)
    elif correction == "shift_drift":
        need = (2, 2)
    else:
        return None
    if surface:
        need = (need[0], 0)
    if need == (0, 0):
        return None
    if n_xy < need[0] or n_z < need[1]:
        what = "without GNSS" if not gnss else f"with GNSS {correction.replace('_', ' and ')} corrections per strip"
        needed = " and ".join(f"{n} with {c} coordinates" for n, c in zip(need, ("plan", "height")) if n)
        return (f"too few control points for the datum {what}: need at least {needed}, have {n_xy} with plan and "
                f"{n_z} with height coordinates (control/points.csv)")
    return None


def _is_in(ids: np.ndarray, allowed) -> np.ndarray:
    """``np.isin`` of an object array of ids by a set lookup per element (np.isin compares object arrays element by
    element with every allowed id: measurements x frames)."""
    allowed = set(allowed)
    return np.fromiter(map(allowed.__contains__, np.asarray(ids).tolist()), dtype=bool, count=len(ids))


def check_datum(control: ControlPoints, gnss: bool, correction: str, surface: bool = False,
                gnss_offset: bool = False) -> None:
    msg = datum_shortfall(control, gnss, correction, surface, gnss_offset)
    if msg:
        raise InputError(msg)


def _empty_control():
    return (ControlPoints(np.zeros(0, dtype=object), np.zeros(0, dtype=object), np.zeros((0, 3)), np.zeros((0, 3))),
            ImageObservations(np.zeros(0, dtype=object), np.zeros(0, dtype=object), np.zeros((0, 2))))


def _known_ids(ids, control: ControlPoints, path, option: str) -> list[str]:
    """The ids given with ``option`` as the control file writes them (matched as the report matches ids:
    ``point_id_key``); an ``OptionError`` naming the option, the file, its ids and the nearest to each unknown one
    (kite trial: "control points ['gcp3'] are not in the control point file")."""
    import difflib

    from aerotri.core.point_ids import point_id_key

    written = {point_id_key(i): str(i) for i in control.id.tolist()}
    unknown = [i for i in ids if point_id_key(i) not in written]
    if unknown:
        listed = sorted(written.values())
        near = [f"{u} (nearest: {', '.join(m)})" if (m := difflib.get_close_matches(u, listed, n=1)) else u
                for u in unknown]
        raise OptionError(f"{'; '.join(near)}: not in {path} ({len(listed)} points: {', '.join(listed[:12])}"
                          f"{' ...' if len(listed) > 12 else ''})", param=option)
    return [written[point_id_key(i)] for i in ids]


def read_project_control(project: Project, st: AdjustSettings, crs=None) -> tuple[ControlPoints, ImageObservations]:
    """The control and check points the adjustment uses (``control/``, kinds changed by ``st.check`` and
    ``st.control``), and their image measurements; none with ``st.use_control`` off. ``crs``: the
    project CRS the points are checked against (default: the project's)."""
    if crs is None:
        crs = check_block_crs(project.crs, f"{project.config_path} [project] crs")
    ctrl_path = project.control_points_path
    cobs_path = project.control_image_points_path
    gnss_datum = st.use_gnss and project.gnss_path.exists()
    if not st.use_control and not gnss_datum:
        raise InputError(f"{project.gnss_path}: without control the datum needs GNSS positions")
    if st.use_control and (ctrl_path.exists() or cobs_path.exists() or not gnss_datum):
        control = read_control_points(ctrl_path, crs, hint="run aerotri control first, or --no-control")
        cobs = read_control_image_points(cobs_path, hint="run aerotri control first, or --no-control")
    else:
        # GNSS alone can carry the datum (no corrections per strip): the first adjustment of the
        # chain, before LiDAR control has been transferred. check_datum refuses the other cases.
        control, cobs = _empty_control()
    _refuse_check_and_control(st)
    kinds = {pid: "check" for pid in _known_ids(st.check, control, ctrl_path, "--check")}
    kinds.update({pid: "full" for pid in _known_ids(st.control, control, ctrl_path, "--control")})
    if kinds:
        control = control.with_kinds(kinds)
    return control, cobs


def _refuse_check_and_control(st: AdjustSettings) -> None:
    """An id given as a check point and as control (``--check P --control P``) is refused, not decided by order."""
    both = sorted(set(st.check) & set(st.control))
    if both:
        raise OptionError(f"point(s) {', '.join(both)} given both as --check and as --control; give each once",
                          param="--check")


def _check_control_near_block(control: ControlPoints, positions_map, path, block_path, crs) -> None:
    """Control and check points where a frame of the block can see them (``aerotri.geom.inputs.check_near_block``):
    points of another zone or place are refused by their record, not adjusted into "Solution Successful"."""
    from aerotri.geom.crs.definition import linear_unit_m
    from aerotri.geom.inputs import check_near_block

    if len(control):
        check_near_block(control.xyz_m[:, 0], control.xyz_m[:, 1], [f"point {p}" for p in control.id], str(path),
                         block_xy=np.asarray(positions_map)[:, :2], block_source=str(block_path),
                         unit_m=linear_unit_m(crs))


def project_datum_shortfall(root, settings: AdjustSettings | None = None) -> str | None:
    """``datum_shortfall`` of a project's control for these settings (None: the datum is fixed)."""
    project = Project.open(root)
    st = _settings_from_project(project, settings or AdjustSettings())
    control, _ = read_project_control(project, st)
    return datum_shortfall(control, st.use_gnss and project.gnss_path.exists(), st.gnss_correction, st.dem is not None,
                           project.gnss.offset_sigma_m is not None)


def _check_approximate_kappa(eo0, cam, ties, control, with_gnss: bool, path, mean_terrain_m) -> None:
    """Name the frames of the given approximations (``--eo``) whose kappa the tie points say is off
    (``aerotri.geom.eo_check``): a warning, or an ``InputError`` when the solve cannot mend them: beyond
    ``KAPPA_REFUSE_DEG`` without GNSS (the solve starts from them: the demo's one frame 180 deg off "solved" with
    check points 1,296 m off), or in half the frames or more with GNSS (the resection on the GNSS positions mended one
    frame 180 deg off; every frame so failed). Before, both went to the solve unnamed."""
    from aerotri.geom.eo_check import (KAPPA_LIMIT_DEG, KAPPA_REFUSE_DEG, ground_guess_m, kappa_errors, kappa_message,
                                       radians_read_as_degrees)

    with_height = np.array([k != "horizontal" for k in control.kind], bool) if control is not None else np.zeros(0, bool)
    ground = (float(np.median(control.xyz_m[with_height, 2])) if with_height.any()
              else ground_guess_m(eo0, cam, mean_terrain_m))
    errors = kappa_errors(eo0, cam, ties, ground)
    off = [e for e in errors if abs(e.error_deg) > KAPPA_LIMIT_DEG]
    if not off:
        return
    wrong = [e for e in off if abs(e.error_deg) > KAPPA_REFUSE_DEG]
    message = kappa_message(off, len(errors), str(path))
    radians = radians_read_as_degrees(eo0)
    if radians:  # (trial-messy F8: every frame "x and y swapped?" for angles in radians)
        message = f"{message}; {radians}"
    if wrong and (not with_gnss or 2 * len(wrong) >= len(errors)):
        raise InputError(message + (f"; {len(wrong)} beyond {KAPPA_REFUSE_DEG:g} deg, which the adjustment cannot mend "
                                    + ("in half the block or more" if with_gnss else "without GNSS positions")))
    log.warning(message + ("; the adjustment starts from them" + (" and mends them by resection on the GNSS positions"
                                                                    if with_gnss else "")))


def _initial_orientations(path, image_ids: list | None, crs=None) -> ExteriorOrientations:
    """Approximate orientations for the adjustment; with ``image_ids`` (GNSS) every image must have one."""
    eo0 = read_eo(path, crs)
    if image_ids is not None:
        missing = sorted(set(image_ids) - set(eo0.image_id))
        if missing:
            raise InputError(f"{path}: no approximate orientation for image(s) {', '.join(missing[:10])}"
                             + (" ..." if len(missing) > 10 else "") + " (gnss.txt has them)")
    return eo0


@dataclasses.dataclass
class ProjectInputs:
    """What the adjustment reads from a project folder, checked against each other (project CRS)."""

    project: Project
    settings: AdjustSettings
    camera: BrownCamera
    ties: ImageObservations  # measured, a known k3 taken off
    control: ControlPoints  # every control and check point
    control_obs: ImageObservations  # their measurements, a known k3 taken off
    image_ids: list  # the block's images (GNSS or given orientations), flight order
    approx_position_map: np.ndarray  # (N, 3) GNSS antenna or given projection centres
    gnss: object | None  # GnssPositions
    initial_eo: ExteriorOrientations | None
    gnss_sigma_m: tuple  # (xy, z) default a-priori sigmas of project.toml [gnss]
    datum_notes: list = dataclasses.field(default_factory=list)  # how the approximations got their datum
    model_heights: ModelHeights = dataclasses.field(default_factory=ModelHeights)  # of the control, in the image model
    control_rays_left_out: tuple = ()  # (point, frame, px): blunders by the image model alone (relative.ray_blunders)
    control_held_out: tuple = ()  # ids the datum's robust similarity left out: the adjustment's first rejected
    unoriented: tuple = ()  # frames the images could not orient (no GNSS, no given orientations): left out


@dataclasses.dataclass
class PreparedBlock:
    """The block in the adjustment's local frame, and what turns the result back into the project CRS."""

    project: Project
    settings: AdjustSettings
    frame: LocalFrame
    camera: BrownCamera
    block: G.Block
    opts: G.SolveSettings
    control_used: ControlPoints  # control points in the adjustment (block.control_point order)
    check_points: ControlPoints
    control_obs: ImageObservations
    image_ids: list
    image_index: dict
    gnss_map: np.ndarray | None  # (N, 3) antenna positions, block order
    n_tie_points: int
    components: int = 1  # parts of the block no tie point connects, adjusted together (each with its datum)
    components_without_control: int = 0  # of those parts, the ones no control point is measured in
    left_out: list = dataclasses.field(default_factory=list)  # LeftOutComponent: parts without a datum
    datum_notes: list = dataclasses.field(default_factory=list)  # what the datum rests on (no GNSS)
    level: object | None = None  # level_datum.LevelDatum: plan-only control, heights and tilt by assumption
    check_surface: SurfaceControl | None = None  # the check DEM (settings.check_dem): compared, not observed
    gnss_sigma_source: str = ""  # where the GNSS positions' sigmas came from (gnss_model.sigma_source)
    control_rays_left_out: tuple = ()  # (point, frame, px): blunders by the image model alone (relative.ray_blunders)
    control_held_out: tuple = ()  # ids the datum's robust similarity left out: the adjustment's first rejected
    gnss_left_out: tuple = ()  # GnssLeftOut: positions off their flight line, not observed (weight 0)


UNORIENTED_REASON = ("the images could not orient them (pycolmap's relative orientation registered no pose from their "
                     "tie points: too few or wrong matches, or a damaged image)")


def read_inputs(project: Project, settings: AdjustSettings | None = None) -> ProjectInputs:
    """Read and cross-check the adjustment's inputs (InputError/ConfigError naming file and record)."""
    crs = check_block_crs(project.crs, f"{project.config_path} [project] crs")
    st = _settings_from_project(project, settings)
    gnss_sigma = (project.gnss.sigma_xy_m, project.gnss.sigma_z_m)  # checked when the project was opened
    cam = project_camera(project)
    ties = read_image_points(project.tiepoints_path, hint="run aerotri match first")
    control, cobs = read_project_control(project, st, crs)
    # orientation source: GNSS (with given approximate EO, if any) or given approximate EO alone
    gnss = eo0 = None
    notes, model_heights, rays_out, held_out, unoriented = [], ModelHeights(), (), (), ()
    if st.use_gnss and not project.gnss_path.exists() and ("gnss" in project.config or st.gnss_correction != "none"):
        # trial-scale: gnss.txt deleted, project.toml's [gnss] and gnss_correction = "shift_drift" in place, and the
        # block adjusted without GNSS, "Solution Successful", only report.txt's "Given EO/GPS: Disabled" telling it
        log.warning(f"{project.gnss_path}: not found, though {project.config_path} sets up GNSS ("
                    + ", ".join((["[gnss]"] if "gnss" in project.config else [])
                                + ([f"gnss_correction = {st.gnss_correction!r}"] if st.gnss_correction != "none"
                                   else [])) + "): the block is adjusted without GNSS positions")
    if st.use_gnss and project.gnss_path.exists():
        gnss = read_gnss(project.gnss_path, crs)
        _warn_implausible_gnss_sigmas(project.gnss_path, gnss)
        image_ids, approx_pos_map, block_path = list(gnss.image_id), gnss.position_m, project.gnss_path
        if st.initial_eo:
            eo0 = _initial_orientations(st.initial_eo, image_ids, crs)
    elif st.initial_eo:
        eo0 = _initial_orientations(st.initial_eo, None, crs)
        image_ids, approx_pos_map, block_path = list(eo0.image_id), eo0.centre_m, st.initial_eo
    else:
        # no GNSS, no given orientations: from the images (pycolmap on the tie points) and the control
        ap, ties, control, cobs, note = _image_approximations(project, cam, ties, control, cobs, crs)
        eo0, model_heights, rays_out = ap.eo, ap.control_heights(control), ap.datum.left_out_rays
        held_out = tuple(p for p, _ in ap.datum.rejected)
        unoriented = tuple(ap.relative.unregistered)
        image_ids, approx_pos_map, block_path = list(eo0.image_id), eo0.centre_m, project.tiepoints_path
        notes.append(note)
    _check_control_near_block(control, approx_pos_map, project.control_points_path, block_path, crs)
    validate_references(ties, control, cobs, image_ids, tie_path=project.tiepoints_path,
                        control_path=project.control_points_path, control_obs_path=project.control_image_points_path,
                        camera=cam, block_path=block_path, camera_path=project.camera_path)
    if st.initial_eo and eo0 is not None:
        _check_approximate_kappa(eo0, cam, ties, control, gnss is not None, st.initial_eo,
                                 project.flight.mean_terrain_height_m)
    check_datum(control, gnss is not None, st.gnss_correction, surface=st.dem is not None,
                gnss_offset=project.gnss.offset_sigma_m is not None)
    # a known k3 is taken off the measurements (Cal3DS2 has no k3; the camera keeps it for the outputs)
    ties = ImageObservations(ties.point_id, ties.image_id, cam.calibration_observations(ties.xy_px))
    cobs = ImageObservations(cobs.point_id, cobs.image_id, cam.calibration_observations(cobs.xy_px))
    return ProjectInputs(project=project, settings=st, camera=cam, ties=ties, control=control, control_obs=cobs,
                         image_ids=image_ids, approx_position_map=approx_pos_map, gnss=gnss, initial_eo=eo0,
                         gnss_sigma_m=gnss_sigma, datum_notes=notes, model_heights=model_heights,
                         control_rays_left_out=rays_out, control_held_out=held_out, unoriented=unoriented)


def _image_approximations(project: Project, cam, ties: ImageObservations, control: ControlPoints,
                          cobs: ImageObservations, crs):
    """(``ImageApproximations``, ties, control points and control measurements of the oriented frames, datum
    statement) of a block without GNSS from its images (``aerotri.adjust.relative``); frames the images cannot orient are left
    out, named, and so are control points measured only in them."""
    from aerotri.adjust.relative import image_approximations, is_left_out_ray

    frames = sorted(set(ties.image_id.tolist()) | set(cobs.image_id.tolist()))
    ap = image_approximations(project.work_dir, project.tiepoints_path, ties, cam, frames, control, control_obs=cobs,
                              crs=crs)
    oriented = list(ap.eo.image_id)
    ties = ties.subset(_is_in(ties.image_id, oriented))
    # in oriented frames, and not a blunder by the image model alone (out of the adjustment too)
    kept = _is_in(cobs.image_id, oriented) & ~is_left_out_ray(cobs, ap.datum.left_out_rays)
    lost = set(cobs.point_id[~kept].tolist()) - set(cobs.point_id[kept].tolist())  # measured only in those frames
    cobs = cobs.subset(kept)
    control = control.subset(~np.isin(control.id, sorted(lost)))
    note = ap.datum.statement()
    if ap.relative.unregistered:
        note += f" Frames the images could not orient (left out): {', '.join(ap.relative.unregistered)}."
    (log.warning if ap.datum.kind == "plan" else log.info)(note)
    return ap, ties, control, cobs, note


@dataclasses.dataclass
class _Observations:
    image_ids: list
    order: np.ndarray  # block image -> index in the input image list
    point_id: np.ndarray  # tie point ids, then the control points used
    control_position: dict  # control id -> point index
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray
    n_tie: int
    left_out: list = dataclasses.field(default_factory=list)  # LeftOutComponent: parts of the block without a datum
    components: int = 1  # components of the block adjusted together
    components_without_control: int = 0  # of those, the ones no control point is measured in


def _images(n: int) -> str:
    return f"{n} image" if n == 1 else f"{n} images"


@dataclasses.dataclass
class LeftOutComponent:
    """Images the adjustment leaves out, and why: a part of the block no tie point connects to the rest and that
    has no datum of its own, or images with too few measurements to orient them."""

    image_ids: list
    reason: str
    position_map: np.ndarray | None = None  # (n, 3) their GNSS (or given) positions: the flight checks include them


def _component_datum_gap(inp: ProjectInputs, ctrl_used: ControlPoints, ids: list) -> str | None:
    """Why the images ``ids`` (a component of the block) have no datum of their own, or None: the test the
    whole block gets (``datum_shortfall``) with the control points measured in them."""
    cobs, st = inp.control_obs, inp.settings
    measured = np.unique(cobs.point_id[_is_in(cobs.image_id, ids)])
    ctrl = ctrl_used.subset(np.isin(ctrl_used.id, measured))
    return datum_shortfall(ctrl, inp.gnss is not None, st.gnss_correction, st.dem is not None,
                           inp.project.gnss.offset_sigma_m is not None)


def _observations(inp: ProjectInputs, ctrl_used: ControlPoints, already_left: frozenset = frozenset()) -> _Observations:
    """Images in flight order (those with measurements), points and observation index arrays; drops tie points
    seen once. An image of the block with no measurement at all, or with fewer than 3, is left out, named (a
    frame over open water or cloud: the rest of the block is adjusted, and the adjustment is not "Successful").
    A block that tie points do not connect is adjusted in its components that have a datum (GNSS, control, DEM);
    the others are left out, named. ``already_left``: images a caller left out before."""
    ties, cobs, image_ids = inp.ties, inp.control_obs, inp.image_ids
    order = flight_order(image_ids)
    measured = set(ties.image_id.tolist()) | set(cobs.image_id.tolist())
    # trial-relief F7: an image with no measurement dropped out of the block without a word (no EO, no ortho,
    # "Solution Successful" possible); now a left-out part like a component without a datum
    unmeasured = [image_ids[i] for i in order if image_ids[i] not in measured and image_ids[i] not in already_left]
    if unmeasured:
        blank = LeftOutComponent(unmeasured, "no tie point and no control point measured in them (nothing matched: "
                                             "open water, cloud, a blank or unreadable image?)")
        log.warning(f"{inp.project.tiepoints_path}: {_images(len(unmeasured))} with no measurement left out "
                    f"({', '.join(unmeasured[:8])}{' ...' if len(unmeasured) > 8 else ''}): {blank.reason}")
        ob = _observations(inp, ctrl_used, already_left | frozenset(unmeasured))
        return dataclasses.replace(ob, left_out=[blank] + ob.left_out)
    order = np.array([i for i in order if image_ids[i] in measured], dtype=int)
    image_ids = [image_ids[i] for i in order]
    img_index = {k: i for i, k in enumerate(image_ids)}
    tie_ids, tie_inv = np.unique(ties.point_id.astype(str), return_inverse=True)
    point_id = np.concatenate([tie_ids.astype(object), ctrl_used.id])
    ctrl_pos = {pid: len(tie_ids) + c for c, pid in enumerate(ctrl_used.id)}
    cmask = np.isin(cobs.point_id, ctrl_used.id)
    obs_point = np.concatenate([tie_inv, np.array([ctrl_pos[p] for p in cobs.point_id[cmask]], dtype=int)])
    obs_image = np.fromiter(map(img_index.__getitem__, np.concatenate([ties.image_id, cobs.image_id[cmask]]).tolist()),
                            dtype=int, count=len(ties) + int(cmask.sum()))
    obs_xy = np.vstack([ties.xy_px, cobs.xy_px[cmask]])
    tie_path = inp.project.tiepoints_path
    comps = connected_image_components(len(image_ids), obs_point, obs_image)
    if len(comps) > 1:
        def names(g):
            return ", ".join(image_ids[i] for i in g[:8]) + (" ..." if len(g) > 8 else "")

        gaps = [_component_datum_gap(inp, ctrl_used, [image_ids[i] for i in g]) for g in comps]
        if inp.gnss is None and sum(gap is None for gap in gaps) > 1:
            # without GNSS the datum step moves the whole block onto its control points: one component at a time
            first = next(c for c, gap in enumerate(gaps) if gap is None)
            gaps = [gap if gap is not None or c == first else "a block without GNSS is adjusted one component at a "
                    "time: adjust this one as its own project" for c, gap in enumerate(gaps)]
        if all(gap is not None for gap in gaps):
            desc = "; ".join(f"component {c + 1} ({len(g)} images: {names(g)}): {gap}"
                             for c, (g, gap) in enumerate(zip(comps, gaps)))
            raise InputError(f"{tie_path}: the block is not connected by tie points and no component has a datum, "
                             f"{len(comps)} components: {desc}")
        if any(gap is not None for gap in gaps):
            left = [LeftOutComponent([image_ids[i] for i in g], gap) for g, gap in zip(comps, gaps) if gap is not None]
            for lo in left:
                log.warning(f"{tie_path}: {_images(len(lo.image_ids))} no tie point connects to the rest left out "
                            f"({', '.join(lo.image_ids[:8])}{' ...' if len(lo.image_ids) > 8 else ''}): {lo.reason}")
            return _observations_without(inp, ctrl_used, left, already_left)
        log.warning(f"{tie_path}: the block falls apart into {len(comps)} components that no tie point connects; "
                    "each has a datum of its own and is adjusted")
    rays = np.bincount(obs_point, minlength=len(point_id))
    few = np.flatnonzero(rays[: len(tie_ids)] < 2)
    if len(few):
        keep = ~np.isin(obs_point, few)
        obs_point, obs_image, obs_xy = obs_point[keep], obs_image[keep], obs_xy[keep]
    per_image = np.bincount(obs_image, minlength=len(image_ids))
    if per_image.min() < 3:
        few_ids = [image_ids[i] for i in np.flatnonzero(per_image < 3)]
        n_tie_obs = np.bincount(obs_image[obs_point < len(tie_ids)], minlength=len(image_ids))
        counts = ", ".join(f"{image_ids[i]} {n_tie_obs[i]} tie + {per_image[i] - n_tie_obs[i]} control"
                           for i in np.flatnonzero(per_image < 3)[:8])
        if len(few_ids) == len(image_ids):
            raise InputError(f"{tie_path}, {inp.project.control_image_points_path}: no image has the 3 measurements "
                             f"(tie points seen in 2 images or more, and control) that orient it: {counts}")
        # trial-relief F7: one frame over the sea stopped the whole block ("only 2 tie measurements", which were
        # control); it is left out, named, and the rest adjusted
        weak = LeftOutComponent(few_ids, f"fewer than the 3 measurements that orient an image ({counts})")
        log.warning(f"{tie_path}: {_images(len(few_ids))} left out: {weak.reason}")
        return _observations_without(inp, ctrl_used, [weak], already_left)
    controlled = set(obs_image[obs_point >= len(tie_ids)].tolist())
    return _Observations(image_ids, order, point_id, ctrl_pos, obs_point, obs_image, obs_xy, len(tie_ids),
                         components=len(comps),
                         components_without_control=sum(not controlled.intersection(g.tolist()) for g in comps)
                         if len(comps) > 1 else 0)


def _observations_without(inp: ProjectInputs, ctrl_used: ControlPoints, left: list, already_left: frozenset
                          ) -> _Observations:
    """``_observations`` of the block without the images of ``left`` (LeftOutComponent), which lead its left_out."""
    drop = [k for lo in left for k in lo.image_ids]
    kept = dataclasses.replace(inp, ties=inp.ties.subset(~_is_in(inp.ties.image_id, drop)),
                               control_obs=inp.control_obs.subset(~_is_in(inp.control_obs.image_id, drop)))
    ob = _observations(kept, ctrl_used.subset(np.isin(ctrl_used.id, kept.control_obs.point_id)),
                       already_left | frozenset(drop))
    return dataclasses.replace(ob, left_out=list(left) + ob.left_out)


def _control_priors(frame: LocalFrame, ctrl_used: ControlPoints):
    """Given coordinates (ENU), covariances (loose components of horizontal/height points) and the number
    of constrained components of each control point used."""
    given_loc = frame.to_local(ctrl_used.xyz_m) if len(ctrl_used) else np.zeros((0, 3))
    # the sigmas are metres along the grid axes (sx_m, sy_m, sz_m), whatever the CRS's unit: turned into ENU by the
    # rotation, not by the Jacobian d(ENU m)/d(map unit), which read them in feet in a feet CRS (3.3 x too tight)
    J = frame.rotation_local_from_map(ctrl_used.xyz_m) if len(ctrl_used) else np.zeros((0, 3, 3))
    cov_loc, rows = [], []
    for c in range(len(ctrl_used)):
        sig = ctrl_used.sigma_m[c].copy()
        k = ctrl_used.kind[c]
        if k == "horizontal":
            sig[2] = G.LOOSE_SIGMA_M
        elif k == "height":
            sig[:2] = G.LOOSE_SIGMA_M
        cov_loc.append(J[c] @ np.diag(sig**2) @ J[c].T)
        rows.append({"full": 3, "horizontal": 2, "height": 1}[k])
    return given_loc, np.array(cov_loc).reshape(-1, 3, 3), np.array(rows, dtype=int)


def _approximations(inp: ProjectInputs, frame: LocalFrame, block: G.Block, image_ids: list,
                    start_gnss: np.ndarray | None = None) -> G.State:
    """Start values: GNSS centres + kappa from the strip direction (or the given EO), then alternating
    space resection and intersection refine the attitudes (GNSS, ``refine_approximations``); given EO
    without GNSS: intersection only. ``start_gnss``: the GNSS positions to start from (local, (N, 3)) where some
    are left out (their track's prediction in their place); None: ``block.gnss_local``."""
    st, cam, eo0 = inp.settings, inp.camera, inp.initial_eo
    gl, lever, strip = block.gnss_local if start_gnss is None else start_gnss, block.lever_arm_m, block.strip
    obs_point, obs_image, obs_xy = block.obs_point, block.obs_image, block.obs_xy_px
    cal0 = G.cal_from_camera(cam)
    if eo0 is not None:
        sel = eo0.rows(image_ids)
        centre0 = frame.to_local(eo0.centre_m[sel])
        R0 = frame.rotation_local_from_map(eo0.centre_m[sel]) @ eo0.rotations()[sel] @ FLIP_YZ
    else:
        centre0, R0 = approximate_orientations(gl, lever, strip, obs_point, obs_image, obs_xy)
    given_loc = block.control_local
    has_height = block.control_rows != 2
    # the rays to control points with a height: (frame, control point) of each
    ctrl_of_point = np.full(block.n_points, -1)
    ctrl_of_point[block.control_point[has_height]] = np.arange(int(has_height.sum()))
    ray = ctrl_of_point[obs_point] >= 0
    seen = ControlRays(obs_image[ray], ctrl_of_point[obs_point[ray]], list(image_ids),
                       [str(p) for p in block.point_id[block.control_point[has_height]]])
    ground = start_ground_height_m(centre0[:, 2], given_loc[has_height, 2], _flying_height_guess(centre0, cam),
                                   "gnss.txt" if gl is not None else "the approximate orientations (--eo)", seen)
    n_points = block.n_points
    if gl is not None and st.refine_approximations:
        centre0, R0, pts0 = refine_orientations(gl, lever, centre0, R0, obs_point, obs_image, obs_xy_px=obs_xy,
                                                cal=cal0, n_points=n_points, ground_height_m=ground)
    elif gl is None:
        pts0 = intersect_points(obs_point, obs_image, obs_xy, centre0, R0, cal0, n_points=n_points,
                                ground_height_m=ground)
    else:
        pts0 = approximate_points(obs_point, obs_image, obs_xy, centre0, R0, cal0, n_points=n_points,
                                  ground_height_m=ground)
    for c, j in enumerate(block.control_point):
        if block.control_rows[c] == 3:
            pts0[j] = given_loc[c]
    return G.State(centre0, R0, pts0, cal0, np.zeros((block.n_strips, 3)), np.zeros((block.n_strips, 3)))


def _surface_control(project: Project, st: AdjustSettings, frame: LocalFrame, positions_map: np.ndarray,
                     check: bool = False) -> SurfaceControl:
    """The DEM (and nDSM, roof planes) of the settings, read over the block: the projection centres' extent plus
    a margin of their height (more than the frames can see); ``check``: the check DEM (``check_dem``) with the
    nDSM, without roof planes."""
    crs, heights = project_crs(project), project_heights(project)
    p = np.asarray(positions_map, dtype=float)
    # a frame sees less than its height above the ground around its nadir point; the centres' heights
    # above the datum bound that (a window of the DEM, not the DEM of a whole country)
    margin = float(np.clip(np.abs(p[:, 2]).max(), 500.0, 20_000.0))
    bounds = (p[:, 0].min() - margin, p[:, 1].min() - margin, p[:, 0].max() + margin, p[:, 1].max() + margin)
    path = st.check_dem if check else st.dem
    dem = read_height_grid(path, crs, heights, "DEM", bounds)
    if not np.isfinite(dem.z).any():
        raise InputError(f"{path}: the DEM has no height under the block (extent {bounds[0]:.0f}..{bounds[2]:.0f}, "
                         f"{bounds[1]:.0f}..{bounds[3]:.0f} in the project CRS)")
    ndsm = read_height_grid(st.ndsm, crs, None, "nDSM", bounds) if st.ndsm is not None else None
    planes = read_roof_planes(st.planes, crs, heights, st.plane_sigma_m) if st.planes is not None and not check else None
    # the frame's map heights are in the horizontal CRS's height unit (geom.crs.transform's convention)
    units = (linear_unit_m(crs), height_unit_m(horizontal_crs(crs)))
    bias_xy = bias_z = surface_bias_sigma(project, st, planes)
    if st.surface_bias_sigma_m is None and planes is not None:
        bias_xy, bias_z = planes.sigma_strip_xy_m, planes.sigma_strip_z_m
    measured = measured_strip_sigma(project) if st.surface_bias_sigma_m is None and bias_z > 0 and not check else None
    if measured is not None and measured[0] > MEASURED_STRIP_FACTOR * max(bias_xy, bias_z):
        # trial-density F0: strips 0.6 m apart in height by the strip check, the sigmas computed for 0.03 m strip
        # offsets: orientations 8-10 of their sigmas off, "Solution Successful"
        log.warning(f"surface control: the LiDAR strip check ({measured[1]}) measured the strips' heights "
                    f"{measured[2]:.3f} m RMS apart: their offsets are taken as {measured[0]:.3f} m (plan and height) "
                    f"in the sigmas, not {max(bias_xy, bias_z):.3f} m; adjust the strips (lidarctl strips adjust) "
                    "or state [adjust] surface_bias_sigma_m")
        bias_xy = bias_z = measured[0]
    return SurfaceControl(dem, frame, sigma_m=float(st.surface_sigma_m), ndsm=ndsm, max_ndsm_m=float(st.max_ndsm_m),
                          planes=planes, map_unit_m=units, bias_sigma_xy_m=bias_xy, bias_sigma_z_m=bias_z,
                          bias_cell_m=float(st.surface_bias_cell_m) / units[0],
                          bias_length_m=float(st.surface_bias_length_m) / units[0])


def surface_bias_sigma(project: Project, st: AdjustSettings, planes=None) -> float:
    """The surface control's systematic error (m) the covariances carry: ``surface_bias_sigma_m`` when set; else
    for the project's LiDAR DEM (lidar_out/dem.tif) or roof planes ``DEFAULT_SURFACE_BIAS_SIGMA_M`` (the roof
    planes' own strip sigmas replace it where given), for a DEM from elsewhere none (its systematic error is the
    user's to state: the report calls the sigmas formal)."""
    if st.surface_bias_sigma_m is not None:
        return float(st.surface_bias_sigma_m)
    lidar_dem = st.dem is not None and Path(st.dem).resolve() == project.dem_path.resolve()
    return DEFAULT_SURFACE_BIAS_SIGMA_M if lidar_dem or planes is not None else 0.0


# the strip check's offsets replace the stated ones beyond this factor: from 2 or 3 strips the estimate is rough
# (strips offset by the stated 0.03 m measured 0.026-0.046 m on the demo and the trial-density blocks; 3 times the
# sigma is reached by chance in 3 of 1,000 one-pair blocks), a factor 12 (the trial's 0.375 m) is no chance
MEASURED_STRIP_FACTOR = 3.0


def measured_strip_sigma(project: Project) -> tuple[float, str, float] | None:
    """(sigma of one strip's height offset (m), the file, RMS of the strip pairs' mean height differences (m)) from
    the project's LiDAR strip check (``Project.strips_check_used_path``: after the strip adjustment when there is
    one): two strips with independent offsets of sigma s differ by s sqrt(2). None without a check or a pair it
    compared. (strips.json read as JSON here: the adjustment's layer does not reach lidarctl's reader.)"""
    import json

    path = project.strips_check_used_path
    if not path.is_file():
        return None
    try:
        pairs = json.loads(path.read_text()).get("pairs") or []
        means = np.array([float(q["mean_m"]) for q in pairs if q.get("n_cells") and q.get("mean_m") is not None])
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None  # not a strip check this adjustment can read: the defaults stand
    if not len(means) or not np.isfinite(means).all():
        return None
    rms = float(np.sqrt(np.mean(means**2)))
    return rms / np.sqrt(2.0), str(path.relative_to(project.root)), rms


def _lidar_control(project: Project, control: ControlPoints) -> np.ndarray:
    """Per control point: a corner of the project's LiDAR (lidar_out/corners.csv: the same id within 1 cm), whose
    given coordinates share the LiDAR's strip offsets with its DEM and roof planes."""
    out = np.zeros(len(control.id), bool)
    if not len(control.id) or not project.corners_path.is_file():
        return out
    import csv

    try:
        with open(project.corners_path, newline="") as f:
            corners = {r["id"]: (float(r["x"]), float(r["y"]), float(r["z"])) for r in csv.DictReader(f)}
    except (OSError, KeyError, ValueError, TypeError):
        return out  # not a corners file this adjustment can read: its control is taken as independent
    for c, (pid, xyz) in enumerate(zip(control.id, control.xyz_m)):
        out[c] = pid in corners and bool(np.all(np.abs(np.subtract(corners[pid], xyz)) < 0.01))
    return out


def prepare_project(root, settings: AdjustSettings | None = None) -> tuple[PreparedBlock, G.State]:
    """Read and validate a project; returns the block in the local frame and its approximate state."""
    project = Project.open(root)
    inp = read_inputs(project, settings)
    st = inp.settings
    is_check = inp.control.kind == "check"
    ctrl_used, chk = inp.control.subset(~is_check), inp.control.subset(is_check)
    ob = _observations(inp, ctrl_used)
    row_of = {k: i for i, k in enumerate(inp.image_ids)}
    for lo in ob.left_out:
        lo.position_map = inp.approx_position_map[[row_of[k] for k in lo.image_ids]]
    if inp.unoriented:
        # in the report's left-out parts, which the ortho stages skip by name (kite trial: `ortho rectify` refused
        # the 3 frames pycolmap had dropped, "no exterior orientation", and said nothing of why)
        ob = dataclasses.replace(ob, left_out=[LeftOutComponent(list(inp.unoriented), UNORIENTED_REASON)]
                                 + ob.left_out)
    ctrl_used = ctrl_used.subset(np.isin(ctrl_used.id, list(ob.control_position)))  # without left-out parts'
    approx_pos_map = inp.approx_position_map[ob.order]
    gnss = inp.gnss
    gnss_left = _gnss_off_track(project, gnss, ob) if gnss is not None else ()
    if gnss_left:  # the strips, the local frame and the start values from where the neighbours put those frames
        approx_pos_map = approx_pos_map.copy()
        approx_pos_map[[g.row for g in gnss_left]] = [g.predicted_m for g in gnss_left]
    frame = LocalFrame.at_centre(project.crs, approx_pos_map)
    strip = strips_from_track(approx_pos_map)
    along = along_track_km(frame.to_local(approx_pos_map), strip)
    if gnss is not None:  # GNSS in the local frame; sigmas from gnss.txt or project.toml
        gl = frame.to_local(gnss.position_m[ob.order])
        gs = gnss.sigma_m[ob.order] if gnss.sigma_m is not None else \
            np.tile([inp.gnss_sigma_m[0]] * 2 + [inp.gnss_sigma_m[1]], (len(ob.order), 1))
        if gnss_left:
            gs = np.array(gs, dtype=float)
            gs[[g.row for g in gnss_left]] = np.inf  # not observed: weight 0 (graph.Block.gnss_used)
    else:
        gl = gs = None
    given_loc, cov_loc, rows = _control_priors(frame, ctrl_used)
    block = G.Block(
        image_id=ob.image_ids, camera=inp.camera, point_id=ob.point_id, obs_point=ob.obs_point,
        obs_image=ob.obs_image, obs_xy_px=ob.obs_xy, gnss_local=gl, gnss_sigma_m=gs,
        lever_arm_m=np.asarray(st.lever_arm_m, dtype=float), strip=strip, along_km=along,
        control_point=np.array([ob.control_position[p] for p in ctrl_used.id], dtype=int), control_local=given_loc,
        control_cov_local=cov_loc, control_rows=rows,
    )
    correction = st.gnss_correction if gl is not None else "none"
    if gl is not None and project.gnss.offset_sigma_m is not None:  # a consumer receiver: the flight's offset
        block.gnss_offset_sigma_m = np.array(project.gnss.offset_sigma_m, dtype=float)
        correction = "offset" if correction == "none" else correction
    if st.dem is not None:
        block.surface = _surface_control(project, st, frame, approx_pos_map)
        block.surface.lidar_control = _lidar_control(project, ctrl_used)
    check_surface = _surface_control(project, st, frame, approx_pos_map, check=True) if st.check_dem is not None else None
    opts = G.SolveSettings(
        image_sigma_px=float(st.image_sigma_px), gnss_correction=correction,
        self_calibration=tuple(st.self_calibration),
    )
    start_gnss = None
    if gnss_left:
        start_gnss = gl.copy()
        start_gnss[[g.row for g in gnss_left]] = frame.to_local(np.array([g.predicted_m for g in gnss_left]))
    state0 = _approximations(inp, frame, block, ob.image_ids, start_gnss)
    notes = list(inp.datum_notes)
    model_z = {}
    height_m = inp.model_heights.heights_of(ctrl_used.id)
    for c in np.flatnonzero(np.isfinite(height_m)).tolist():  # the image model's heights, in the local frame
        xyz = ctrl_used.xyz_m[c].copy()
        xyz[2] = height_m[c]
        model_z[c] = float(frame.to_local(xyz[None])[0, 2])
    level = height_datum(block, state0, frame.rotation_local_from_map(ctrl_used.xyz_m) if len(ctrl_used) else None,
                         ctrl_used.sigma_m, model_z)
    if level is not None:
        log.warning(level.note)
        notes.append(level.note)
    prepared = PreparedBlock(
        project=project, settings=st, frame=frame, camera=inp.camera, block=block, opts=opts, control_used=ctrl_used,
        check_points=chk, control_obs=inp.control_obs, image_ids=ob.image_ids,
        image_index={k: i for i, k in enumerate(ob.image_ids)},
        gnss_map=gnss.position_m[ob.order] if gnss is not None else None, n_tie_points=ob.n_tie,
        components=ob.components, components_without_control=ob.components_without_control, left_out=ob.left_out,
        datum_notes=notes, level=level,
        check_surface=check_surface, control_rays_left_out=inp.control_rays_left_out,
        control_held_out=inp.control_held_out, gnss_left_out=gnss_left,
        gnss_sigma_source=gnss_model.sigma_source(project, gnss.sigma_m is not None) if gnss is not None else "",
    )
    return prepared, state0


def adjust_project(root, settings: AdjustSettings | None = None) -> BlockAdjustment:
    """Run the adjustment of a project folder (no files written; see write_outputs)."""
    prepared, state0 = prepare_project(root, settings)
    st = prepared.settings
    requested = tuple(prepared.opts.self_calibration)
    opts, checks, focal_mode = prepared.opts, {}, None
    gnss_rounds = 0 if st.snooping and prepared.block.gnss_local is not None else GNSS_ROUNDS
    while True:
        held = [c for c, pid in enumerate(prepared.control_used.id) if str(pid) in prepared.control_held_out]
        result = adjust_block(prepared.block, opts, state0, snooping=st.snooping, alpha=st.alpha,
                              point_covariances=st.point_covariances, variance_components=st.variance_components,
                              image_sigma_from_residuals=st.image_sigma_from_residuals, control_held_out=held)
        if gnss_rounds < GNSS_ROUNDS:  # a GNSS position the frame's rays disagree with
            gnss_rounds += 1
            confirmed = _gnss_against_rays(prepared, opts, state0, result, held)
            gnss_rounds = gnss_rounds if confirmed else GNSS_ROUNDS
            if confirmed:
                prepared = dataclasses.replace(prepared, block=confirmed[0],
                                               gnss_left_out=prepared.gnss_left_out + confirmed[1])
                continue
        if not opts.self_calibration or result.calibration is None:
            break
        if not (np.isfinite(result.sigma0) and np.isfinite(result.calibration.cal_cov).all()):
            # a solve that diverged (trial-messy: one control height typed in feet, 714 m off, and pp fixed): no
            # covariance to judge the groups by (the check stopped on a LinAlgError traceback); the report says
            # "Solution failed" for the solve that did not converge
            log.warning(f"self-calibration: the solve's covariance is not finite (sigma0 {result.sigma0:g}); the "
                        "determinability of the calibration groups is not checked")
            break
        # the determinability of each estimated group (determinability.py); the groups the block cannot
        # determine are fixed at their a-priori values and the block solved again without them
        solved = result.opts or opts
        ground = ground_observations(result.block or prepared.block, result.control_active,
                                     (result.block or prepared.block).surface_active)
        now = check_groups(result.calibration, solved.self_calibration, result.state.cal,
                           G.cal_from_camera(prepared.camera), width=prepared.camera.width,
                           height=prepared.camera.height, ground=ground)
        checks.update({c.group: c for c in now})
        focal_mode = next((g for g in result.geometry or [] if g.mode == "focal_height"), focal_mode)
        for c in now:
            if c.action == "flagged":
                log.warning(f"self-calibration: {c.group} estimated, but it may hold a GNSS offset fixed in the "
                            f"camera, which this block finds or does not reject (do not reuse the estimate as the "
                            f"camera's calibration): {c.reason}")
        fixed = [c.group for c in now if c.action == "fixed"]
        if not fixed:
            break
        for c in now:
            if c.action == "fixed":
                log.warning(f"self-calibration: {c.group} fixed at its a-priori value, not determinable by this block: "
                            f"{c.reason}")
        opts = dataclasses.replace(opts, self_calibration=tuple(g for g in opts.self_calibration if g not in fixed))
    # the block and options as solved last (weights reweighted by variance components, calibration groups fixed)
    prepared = dataclasses.replace(prepared, block=result.block or prepared.block, opts=result.opts or opts)
    if prepared.level is not None:  # plan-only control: the solution levelled (tie points' mean plane horizontal)
        prepared.datum_notes.append(level_result(prepared.level, prepared.block, result))
    if focal_mode is not None and not any(g.mode == "focal_height" for g in result.geometry or []):
        # the focal length was fixed: its mode as the solve that estimated it found it
        result.geometry = list(result.geometry or []) + [dataclasses.replace(
            focal_mode, note="from the solve that estimated the focal length; fixed since")]
    if prepared.block.gnss_local is not None:  # the GNSS model and where its sigmas came from (DATUM)
        b = prepared.block
        w = (result.weight_factors or {}).get("gnss", 1.0)  # the block's sigmas are the reweighted ones
        prepared.datum_notes.append(gnss_model.statement(
            prepared.opts.gnss_correction, b.gnss_sigma_m / w, prepared.gnss_sigma_source, b.gnss_offset_sigma_m,
            f"{prepared.project.config_path.name} [gnss] offset_sigma_xy_m, offset_sigma_z_m", result.state.shift,
            observed=gnss_model.offset_observed(b), weight_factor=w))
        g = next((c for c in result.variance_components or [] if c.group == "gnss"), None)
        note = gnss_model.unchecked_note(g.redundancy, g.n, b.gnss_sigma_m) if g is not None else None
        if note:
            prepared.datum_notes.append(note)
    ba = finish(prepared, result)
    ba.self_calibration_requested = requested
    ba.calibration_checks = [checks[g] for g in requested if g in checks]
    return ba


# a control point a frame sees lies below it by about the flying height; one closer than this fraction of the flying-
# height guess (or above the frame) counts against the frames' heights. Chosen on the simulator (DMC, 1,000 m, 120 m
# of relief, seeds 0-1: gnss.txt heights 950-1,200 m too low put every ray above its frame or within 172 m below it;
# the right heights every ray 902 m or more below) and review 21's slope (every frame 300 m above its ground): a
# quarter leaves room for peaks up to 3/4 of the flying height and for the guess's 60 % overlap being 40-80 %.
CONTROL_CLEARANCE_FRACTION = 0.25


@dataclasses.dataclass(frozen=True)
class ControlRays:
    """The image measurements of the control points with a height: each one's frame (index into the centres) and
    control point (index into the control heights), with the ids that name them."""

    frame: np.ndarray  # (K,) int
    control: np.ndarray  # (K,) int
    frame_id: list
    control_id: list


def start_ground_height_m(centre_z_m, control_z_m, flying_height_guess_m: float, source: str,
                          seen: ControlRays | None = None) -> float:
    """The ground height (local z, m) the start values intersect the rays at: the control points' median height when
    the centres' median lies above it, else the centres' median less the flying-height guess.

    ``InputError`` when most control points' image measurements (``seen``) lie above the frame that sees them or
    less than ``CONTROL_CLEARANCE_FRACTION`` of the flying-height guess below it: gnss.txt heights of the ground,
    of another height system than the control's, a lever arm with the wrong sign, heights in feet read as metres.
    Judged by the rays, not the block: every camera below the lowest control point (s21) let through heights
    1,100 m too low on a block with 120 m of relief (the data snooping then left out all the control, review 22);
    the centres' and the control's medians (before s21) refused a terrain-following block over a slope with its
    control near the top, every frame 300 m above its ground (review 21). Without ``seen`` (or no ray to a control
    point with a height): refused only when every centre lies below the lowest control point."""
    centre_z = np.asarray(centre_z_m, dtype=float)
    control_z = np.asarray(control_z_m, dtype=float)
    median_z = float(np.median(centre_z))
    if len(control_z) == 0:
        return median_z - flying_height_guess_m
    lowest = float(control_z.min())
    expected = ("; expected each frame above the control points it sees, by about the flying height (heights of the "
                "ground, or of another height system than the control's ([project] heights: ellipsoidal against "
                "orthometric), a lever arm with the wrong sign, or heights in feet read as metres?)")
    if seen is not None and len(seen.frame):
        clearance = centre_z[seen.frame] - control_z[seen.control]
        margin = CONTROL_CLEARANCE_FRACTION * flying_height_guess_m
        close = clearance < margin
        # by control points, not by measurements: one mistyped point seen in half the frames must not refuse the block
        # (the data snooping can leave it out; review 23); a point is close when most of its measurements are
        points = np.unique(seen.control)
        close_point = np.array([2 * int(close[seen.control == c].sum()) > int((seen.control == c).sum())
                                for c in points])
        if 2 * int(close_point.sum()) > len(points) and (int(close_point.sum()) >= 2 or len(points) == 1):
            worst = np.argsort(clearance, kind="stable")[:4]
            median_clearance = float(np.median(clearance))
            named = ", ".join(f"{seen.control_id[seen.control[k]]} {abs(clearance[k]):.1f} m "
                              f"{'above' if clearance[k] < 0 else 'below'} {seen.frame_id[seen.frame[k]]}'s centre"
                              for k in worst)
            raise InputError(f"{source}: {int(close_point.sum())} of {len(points)} control points (by most of their "
                             f"measurements; {int(close.sum())} of {len(close)} measurements) lie "
                             f"above their frame or less than {margin:.0f} m below it ({CONTROL_CLEARANCE_FRACTION:g} "
                             f"of the flying-height guess {flying_height_guess_m:.0f} m; the median one "
                             f"{abs(median_clearance):.1f} m {'above' if median_clearance < 0 else 'below'}): {named}"
                             + expected)
    elif float(centre_z.max()) <= lowest:
        raise InputError(f"{source}: the projection centres lie {lowest - median_z:.1f} m (median; the highest "
                         f"{lowest - float(centre_z.max()):.1f} m) below the lowest control point" + expected)
    ground = float(np.median(control_z))
    return ground if median_z > ground else median_z - flying_height_guess_m


def _flying_height_guess(centre, cam) -> float:
    """Flying height above ground from the base between frames, assuming 60 % forward overlap: the median distance
    of each centre to its nearest other one (not to the next id: frames named against the flight order gave 5,883 m
    for 997 m and a correct block was refused, review 23)."""
    from scipy.spatial import cKDTree

    # one position per station: the heads of a multi-camera rig (or duplicated gnss.txt rows) share theirs, and their
    # nearest other centre at 0 m left the fixed 100 m base (a 2-head drone block at 60 m refused; review 25)
    xy = np.unique(np.asarray(centre, dtype=float)[:, :2], axis=0)
    base = 100.0
    if len(xy) > 1:
        d = cKDTree(xy).query(xy, k=min(5, len(xy)))[0][:, 1:]
        # a strip flown again over the same stations puts each centre beside its twin (centimetres apart): the
        # nearest distances of half the block were that, the base "0.0002 m", the start values' ground at the cameras'
        # height and the start attitudes tilted 60-89 deg (trial s97's second day: "the adjustment cannot start").
        # Nearest distances under a quarter of the stations' typical 4th-nearest (a few bases in any block) are
        # twins, not bases
        near, coarse = d[:, 0], float(np.median(d[:, -1]))
        base = np.median(near[near > 0.25 * coarse]) if np.any(near > 0.25 * coarse) else coarse
    return float(base / 0.4 / (min(cam.width, cam.height) * cam.pixel_um / (cam.focal_mm * 1000.0)))


def pose_to_map(frame: LocalFrame, state: G.State, pose_cov):
    """EO in the project CRS with standard deviations (sX sY sZ m, somega sphi skappa deg)."""
    centre_map = frame.to_map(state.centre)
    R_l2m = np.swapaxes(frame.rotation_local_from_map(centre_map), -1, -2)
    R_opk_local = state.R_cv @ FLIP_YZ
    R_map = R_l2m @ R_opk_local
    opk = np.stack(opk_from_matrix(R_map), axis=-1)
    sigma = None
    if pose_cov is not None:
        sigma = np.zeros((len(opk), 6))
        eps = 1e-7
        for i in range(len(opk)):
            Jr = np.zeros((3, 3))
            for q in range(3):
                w = np.zeros(3)
                w[q] = eps
                Rp = R_l2m[i] @ state.R_cv[i] @ _expm(w) @ FLIP_YZ
                d = np.array(opk_from_matrix(Rp)) - opk[i]
                Jr[:, q] = ((d + 180) % 360 - 180) / eps
            cov_rot = Jr @ pose_cov[i, :3, :3] @ Jr.T
            Rc = R_l2m[i] @ state.R_cv[i]
            cov_c = Rc @ pose_cov[i, 3:, 3:] @ Rc.T
            sigma[i, :3] = np.sqrt(np.diag(cov_c))
            sigma[i, 3:] = np.sqrt(np.diag(cov_rot))
    return centre_map, opk, sigma


def _expm(w):
    th = np.linalg.norm(w)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K


def finish(prepared: PreparedBlock, result: AdjustmentResult) -> BlockAdjustment:
    """Convert an adjustment result to the project CRS and intersect the check points."""
    p = prepared
    st, frame, block, opts = p.settings, p.frame, p.block, p.opts
    chk, cobs, img_index, gnss_map = p.check_points, p.control_obs, p.image_index, p.gnss_map
    state = result.state
    centre_map, opk, eo_sigma = pose_to_map(frame, state, result.pose_cov)
    eo = ExteriorOrientations(list(p.image_ids), centre_map, opk, eo_sigma)
    used = np.zeros(block.n_points, dtype=bool)
    used[block.obs_point[result.obs_active]] = True
    # only the points still observed: one whose rays were all rejected may have drifted anywhere (thousands of
    # km, where no map projection reaches), and is not written
    pts_map = np.full((block.n_points, 3), np.nan)
    pts_map[used] = frame.to_map(state.points[used])
    psig = np.full((block.n_points, 3), np.nan)
    if result.point_cov is not None:
        ref = pts_map[used][:1] if used.any() else frame.to_map(state.centre[:1])
        Jinv = np.linalg.inv(frame.jacobian_local_from_map(ref)[0])
        psig = np.sqrt(np.abs(np.einsum("ij,pjk,ik->pi", Jinv, result.point_cov, Jinv)))
    # check points
    check = {}
    chk_obs = None
    if len(chk):
        # measurements in a frame the adjustment left out (no tie points: a frame of another flight, cloud, water)
        # have no orientation to intersect from (trial s99 atmut M1: KeyError, a traceback, exit 1)
        m = np.isin(cobs.point_id, chk.id) & np.isin(cobs.image_id, list(img_index))
        chk_obs = cobs.subset(m)
        cid = {p: c for c, p in enumerate(chk.id)}
        opi = np.array([cid[p] for p in chk_obs.point_id], dtype=int)
        oim = np.array([img_index[i] for i in chk_obs.image_id], dtype=int)
        P, C, rays = check_point_errors(chk_obs.xy_px, oim, opi, len(chk), state, opts, result=result, alpha=st.alpha)
        Pm = frame.to_map(np.nan_to_num(P))
        Jinv = np.linalg.inv(frame.jacobian_local_from_map(chk.xyz_m))
        surveyed = chk.measured_xyz()
        for c, pid in enumerate(chk.id):
            ok = np.all(np.isfinite(P[c]))
            cov_map = Jinv[c] @ C[c] @ Jinv[c].T if ok else np.full((3, 3), np.nan)
            check[pid] = {
                "measured_m": chk.xyz_m[c].tolist(),
                "adjusted_m": Pm[c].tolist() if ok else [float("nan")] * 3,
                "sigma_m": np.sqrt(np.abs(np.diag(cov_map))).tolist(),
                "given_sigma_m": chk.sigma_m[c].tolist(),
                "surveyed": surveyed[c].tolist(),  # x y z: a plan-only point is no height check
                "rays": int(rays[c]),
            }
    gres = None
    if gnss_map is not None:
        gres = frame.to_map(adjusted_gnss(block, opts, state)) - gnss_map
    dem_checks = _dem_checks(p, result)
    return BlockAdjustment(
        project_name=p.project.name, crs=p.project.crs, settings=st, frame=frame, camera_apriori=p.camera,
        camera_adjusted=G.camera_from_cal(G.estimated_or_apriori(state.cal, p.camera, opts.self_calibration), p.camera),
        block=block, opts=opts, result=result, eo_map=eo,
        points_map=pts_map, points_sigma_map=psig, control=p.control_used,
        control_index_of_point={int(j): c for c, j in enumerate(block.control_point)}, check=check, gnss_map=gnss_map,
        gnss_residual_m=gres, n_tie_points=p.n_tie_points, check_obs=chk_obs, components=p.components,
        components_without_control=p.components_without_control,
        left_out=p.left_out, datum_notes=list(p.datum_notes), heights_measured=p.level is None, dem_checks=dem_checks,
        heights=getattr(project_heights(p.project), "name", None),
        check_from_lidar=int(_lidar_control(p.project, chk).sum()) if len(chk) else 0,
        control_rays_left_out=p.control_rays_left_out, gnss_left_out=p.gnss_left_out,
    )


# a GNSS position's sigma above this (m) is no GNSS accuracy: an orientation file's angles in the sX sY sZ columns
GNSS_SIGMA_IMPLAUSIBLE_M = 10.0


def _warn_implausible_gnss_sigmas(path, gnss) -> None:
    """A warning when gnss.txt's sigmas are tens of metres (trial-ngi: the national AT's omega, phi, kappa taken as sX
    sY sZ, sZ 180.9 m; the heights came out 1.15 m off without a word)."""
    if gnss.sigma_m is None:
        return
    big = np.any(gnss.sigma_m > GNSS_SIGMA_IMPLAUSIBLE_M, axis=1)
    if big.any():
        k = int(np.flatnonzero(big)[0])
        # every sigma a whole-ish number of millimetres a survey receiver states (5 mm .. 1 m): typed in mm
        # (trial-messy F15: 50 50 80 read as metres, check heights 1.23 -> 2.40 m RMS, asked about angles)
        mm = big.all() and bool(np.all((gnss.sigma_m >= 5.0) & (gnss.sigma_m <= 1000.0)))
        hint = ("in millimetres? (gnss.txt sigmas are metres: "
                f"{' '.join(f'{v / 1000.0:g}' for v in gnss.sigma_m[k])} m)" if mm
                else "are these columns an orientation's angles (omega phi kappa)?")
        log.warning(f"{path}: {int(big.sum())} of {len(big)} positions have a sigma above {GNSS_SIGMA_IMPLAUSIBLE_M:g} m "
                    f"(image {gnss.image_id[k]}: {' '.join(f'{v:g}' for v in gnss.sigma_m[k])} m): no GNSS accuracy; "
                    f"{hint} gnss.txt is image_id X Y Z [sX sY sZ]")


@dataclasses.dataclass(frozen=True)
class GnssLeftOut:
    """A GNSS position not observed in the adjustment: off its flight line (``strips.track_blunders``), or off
    where its frame's rays put it (``_gnss_against_rays``). ``deviation_m``: the position minus the prediction."""

    image_id: str
    row: int  # in the block (flight order)
    deviation_m: tuple  # observed - predicted from the neighbouring frames (map axes, the CRS's units)
    predicted_m: tuple  # where the neighbouring frames put it (map)
    tolerance_m: float
    reason: str = "off the flight line"  # or what the frame's rays said (``_gnss_against_rays``)

    def text(self) -> str:
        d = np.asarray(self.deviation_m)
        return (f"{self.image_id} {float(np.linalg.norm(d)):.1f} m off (dX dY dZ "
                f"{' '.join(f'{v:+.1f}' for v in d)}; tolerance {self.tolerance_m:.1f}; {self.reason})")


# a frame with GNSS that lost at least this share of its image observations (and RAYS_LOST_MIN of them) to the data
# snooping: its GNSS position may be what is wrong (a 10 m slip in height of a frame in the middle of a strip of a
# 3 x 6 block, under the track's 30 m: 86 of its 90 rays rejected, the frame on its GNSS, sigma0 unchanged, check
# heights 9.2 m RMS off and the principal point blamed)
RAYS_LOST_SHARE = 0.5
RAYS_LOST_MIN = 10
# confirmed when, solved again without that position, the frame keeps all but this share of its observations and
# its adjusted antenna lies further than GNSS_RAYS_SIGMAS of its sigma from the position
RAYS_KEPT_SHARE = 0.2
GNSS_RAYS_SIGMAS = 8.0
# a position whose residual is the largest (no frame lost its rays) is a blunder only when, solved without it, its
# frame lies this many times further from it (in sigmas) than any other frame from its position: a 15 m slip in
# height on the demo with a shift and drift per strip spread over the strip (residuals -10.1, +5.4, +3.0 m)
GNSS_CLEAR_FACTOR = 3.0
# ... and every other position then within this many sigmas of its frame: the rest of the block fits its GNSS without
# it. With a focal length 2.5 % long the largest residual (14.2 sigma) left out freed its frame 35 sigma away, the
# others still up to 8.1: a model error, not a blunder (the demo's 15 m slip: the others within 1.5)
GNSS_FIT_SIGMAS = 5.0
# the standardised residuals' test on blocks of this many positions or more: on the real drone blocks of 4 and 18
# frames (Tuniu, Brighton Beach) GNSS errors the model does not hold (a time lag, the lever arm, a consumer receiver)
# made sound positions suspects, and with few frames the rays' confirmation cannot tell them from a slip
GNSS_W_MIN_FRAMES = 50
GNSS_ROUNDS = 3  # solves again at most this many times, one suspect (or the frames that lost their rays) a time


def _rays_lost(block: G.Block, result: AdjustmentResult) -> tuple[np.ndarray, np.ndarray]:
    """(observations, observations rejected) per frame; of a tie point left out whole because the test could not
    tell its wrong ray (``Removed.whole_point``) only the ray it named counts: its other rays were not blamed (a
    frame 300 m off took its neighbours' rays in 3-ray points with it, and they became suspects too)."""
    n = np.bincount(block.obs_image, minlength=block.n_images)
    lost = ~result.obs_active
    lost[[x.obs for x in result.removed if not x.blamed]] = False
    return n, np.bincount(block.obs_image[lost], minlength=block.n_images)


def _gnss_w(block: G.Block, opts: G.SolveSettings, result: AdjustmentResult) -> np.ndarray | None:
    """(N,) the GNSS positions' w statistics (``variance_components.gnss_w_statistics``), or None without the
    solution's covariances."""
    from aerotri.adjust.variance_components import gnss_w_statistics

    return None if result.marginals is None else gnss_w_statistics(block, opts, result.state, result.marginals)


def _normalised(off: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(N,) the largest |offset| / sigma of each position's axes (0 where the position is left out)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nan_to_num(np.max(np.abs(off) / sigma, axis=1), nan=0.0, posinf=0.0)


def _gnss_against_rays(prepared: PreparedBlock, opts: G.SolveSettings, state0: G.State, result: AdjustmentResult,
                       held: list) -> tuple | None:
    """(the block without the GNSS positions its frames' rays disagree with, their ``GnssLeftOut``) or None.

    The suspects: the frames that lost most of their rays to the snooping (their GNSS position held them where their
    tie points are not), else the frame whose position's residual is the largest beyond GNSS_RAYS_SIGMAS (a slip a
    strip's shift and drift spread over its neighbours). Solved again with their positions left out, a position is
    wrong when its frame then keeps its rays and lies beyond GNSS_RAYS_SIGMAS from it, and (a residual's suspect)
    GNSS_CLEAR_FACTOR times further than any other position from its frame, every other within GNSS_FIT_SIGMAS: a
    systematic misfit of every position (a lever arm, a time lag, a wrong focal length) is no blunder of one. Else the first solution stands (a frame over water or cloud, wrong
    matches)."""
    block, st = prepared.block, prepared.settings
    sigma_m = np.asarray(block.gnss_sigma_m, dtype=float)
    n, lost = _rays_lost(block, result)
    suspect = np.flatnonzero(block.gnss_used & (lost >= RAYS_LOST_MIN) & (lost >= RAYS_LOST_SHARE * np.maximum(n, 1)))
    by_rays = len(suspect) > 0
    if not by_rays:
        res = _normalised(np.asarray(adjusted_gnss(block, result.opts or opts, result.state)) - block.gnss_local,
                          sigma_m)
        worst = int(np.argmax(res))
        # the standardised residuals too (Baarda's w, at the images' snooping level): a frame that takes up its
        # position's error leaves a small residual of small redundancy (trial s97 H1: a 2 m slip, 0.355 m left, 7.1
        # of its sigmas, under the raw 8; the frame 1.56 m and 0.196 deg off, "Solution Successful")
        # at the images' snooping level for the block's positions together (Bonferroni over their axes: one a
        # block at alpha, where every position at alpha left a sound strip end out on 1 of 40 simulated blocks); only
        # where the raw residuals name no suspect, on blocks large enough for it
        n_used = int(np.sum(block.gnss_used))
        w = (_gnss_w(block, result.opts or opts, result)
             if res[worst] <= GNSS_RAYS_SIGMAS and n_used >= GNSS_W_MIN_FRAMES else None)
        if w is not None and w.max() > critical_value(st.alpha / (3 * n_used)):
            worst = int(np.argmax(w))
            log.info(f"GNSS against the rays: {block.image_id[worst]}'s position w = {w[worst]:.1f} (its residual "
                     f"{res[worst]:.1f} sigma)")
        elif res[worst] <= GNSS_RAYS_SIGMAS:
            return None
        suspect = np.array([worst])
    sigma = sigma_m.copy()
    sigma[suspect] = np.inf
    trial = dataclasses.replace(block, gnss_sigma_m=sigma)
    log.info("GNSS against the rays: " + (
        f"{len(suspect)} frames lost most of their rays (" + ", ".join(
            f"{block.image_id[i]} {lost[i]} of {n[i]}" for i in suspect[:6]) + ")" if by_rays else
        f"{block.image_id[suspect[0]]}'s position {res[suspect[0]]:.1f} sigma off") + "; solved again without")
    again = adjust_block(trial, opts, state0, snooping=st.snooping, alpha=st.alpha, point_covariances=False,
                         variance_components=False, image_sigma_from_residuals=st.image_sigma_from_residuals,
                         control_held_out=held, compute_marginals=False)
    n2, lost2 = _rays_lost(trial, again)
    at_local = np.asarray(adjusted_gnss(trial, again.opts or opts, again.state), dtype=float)
    off = _normalised(at_local - block.gnss_local, sigma_m)
    # every other position within GNSS_FIT_SIGMAS but the largest 1 % of them on a block of 100 frames or more: other
    # slips the block took up do not make this one a model error (trial s97 H1: three slips on 1,000 frames, each
    # suspect "not confirmed", all three kept under "Solution Successful"); a model error moves most positions
    rest = np.sort(_normalised(at_local - block.gnss_local, sigma))[::-1]
    skip = int(0.01 * int(np.sum(block.gnss_used)))  # the others not held to it
    others = float(rest[min(skip, len(rest) - 1)]) if len(rest) else 0.0
    confirmed = [int(i) for i in suspect if lost2[i] <= RAYS_KEPT_SHARE * n2[i] and off[i] > GNSS_RAYS_SIGMAS
                 and (by_rays or (off[i] > GNSS_CLEAR_FACTOR * others and others <= GNSS_FIT_SIGMAS))]
    if not confirmed:
        log.info("GNSS against the rays: not confirmed without the positions; the solution stands")
        return None
    sigma = sigma_m.copy()
    sigma[confirmed] = np.inf
    at_map = prepared.frame.to_map(at_local[confirmed])
    out = tuple(GnssLeftOut(str(block.image_id[i]), i, tuple(float(v) for v in prepared.gnss_map[i] - at),
                            tuple(float(v) for v in at), float(GNSS_RAYS_SIGMAS * np.max(sigma_m[i])),
                            reason=(f"its rays: {lost[i]} of {n[i]} rejected with the position, {lost2[i]} without"
                                    if by_rays else f"its rays put the frame {off[i]:.0f} sigma from it, every other "
                                    f"within {others:.1f}" + (" but the largest 1 %" if skip else "")))
                for i, at in zip(confirmed, at_map))
    what = "positions disagree with their frames' rays" if len(out) > 1 else "position disagrees with its frame's rays"
    log.warning(f"{prepared.project.gnss_path}: {len(out)} {what}, left out of the adjustment (the frames are placed "
                "by their tie points): " + "; ".join(g.text() for g in out[:6]) + ("; ..." if len(out) > 6 else "")
                + ". A wrong fix or a record of another frame, or another frame's picture under this frame's name "
                "(its rays follow the picture: a position that fits its flight line points at the image; trial s96 "
                "M2: s01_001's picture under s02_003's name was taken for a GNSS error 564.5 m off)? Check those "
                "records and images.")
    return dataclasses.replace(block, gnss_sigma_m=sigma), out


def _gnss_off_track(project: Project, gnss, ob) -> tuple:
    """The GNSS positions off their flight line (``GnssLeftOut``), each named in a warning. A wrong fix or record
    at the end of a strip is absorbed by a small block without a trace in the GNSS residuals (an 80 m slip of the
    first of six frames: principal point 41.6 mm, check points 9 m off, residuals 0.02 m): the track is the only
    redundancy such a position has. Left out (weight 0), the frame is placed by its tie points."""
    pos = np.asarray(gnss.position_m[ob.order], dtype=float)
    sig = gnss.sigma_m[ob.order] if gnss.sigma_m is not None else \
        np.tile([project.gnss.sigma_xy_m] * 2 + [project.gnss.sigma_z_m], (len(pos), 1))
    tb = track_blunders(pos, sig)
    out = tuple(GnssLeftOut(str(ob.image_ids[i]), int(i), tuple(float(v) for v in d),
                            tuple(float(v) for v in q), float(t))
                for i, d, q, t in zip(tb.index.tolist(), tb.deviation_m, tb.predicted_m, tb.tolerance_m))
    if out:
        log.warning(f"{project.gnss_path}: {len(out)} of {len(pos)} positions off the flight line the neighbouring "
                    f"frames draw, left out of the adjustment (the frames are placed by their tie points): "
                    + "; ".join(g.text() for g in out[:6]) + ("; ..." if len(out) > 6 else "")
                    + ". A wrong fix or a record of another frame? Check those records.")
    return out


def _dem_checks(p: PreparedBlock, result: AdjustmentResult) -> list:
    """``dem_check.DemCheck`` of the adjusted tie points on the ground against the surface control's DEM (its
    candidates on the ground, gated or not) and against the check DEM (``check_dem``)."""
    block, st = p.block, p.settings
    rays = np.bincount(block.obs_point[result.obs_active], minlength=block.n_points)
    tie = rays >= 2
    tie[block.control_point] = False
    height = next((g.sigma_m for g in result.geometry or [] if g.mode == "height"), None)
    out = []
    if block.surface is not None and result.surface_use is not None:
        ground = tie & (result.surface_use > 0) & (block.surface.point_class(block.n_points) == 0)
        heights = project_heights(p.project)
        out.append(tie_dem_check(block.surface, result.state.points, ground, str(st.dem), "surface control", height,
                                 gated_out=result.surface_use == 2, gnss_offset=result.gnss_surface,
                                 heights=heights.name if heights is not None else "ellipsoidal heights"))
    if p.check_surface is not None:
        ground = tie & p.check_surface.candidates(result.state.points)
        out.append(tie_dem_check(p.check_surface, result.state.points, ground, str(st.check_dem), "check", height))
    return out


def object_points_csv(ba: BlockAdjustment) -> str:
    """``id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px`` for all adjusted points: x, y, z in the project CRS's units, the
    standard deviations in metres (as eo.txt's; a feet project's were feet under "_m", trial-api F5)."""
    from aerotri.adjust.report_record import map_unit_m

    b, r = ba.block, ba.result
    unit = np.asarray(map_unit_m(ba.crs, "the adjustment's CRS"), dtype=float)
    left_out = r.control_left_out()
    act = r.obs_active
    rays = np.bincount(b.obs_point[act], minlength=b.n_points)
    ss = np.bincount(b.obs_point[act], (r.residual_px[act] ** 2).sum(1), minlength=b.n_points)
    rms = np.sqrt(ss / np.maximum(2 * rays, 1))
    kind = np.array(["tie"] * b.n_points, dtype=object)
    for c, j in enumerate(b.control_point):
        kind[j] = "rejected_control" if left_out[c] else ba.control.kind[c]
    lines = ["id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px"]
    for j in np.flatnonzero(rays > 0):
        x, y, z = ba.points_map[j]
        sx, sy, sz = ba.points_sigma_map[j] * unit
        lines.append(f"{b.point_id[j]},{kind[j]},{x:.4f},{y:.4f},{z:.4f},{sx:.4f},{sy:.4f},{sz:.4f},{rays[j]},{rms[j]:.3f}")
    return "\n".join(lines) + "\n"


@dataclasses.dataclass(frozen=True)
class AdjustStageResult:
    """What the adjustment stage leaves: the adjustment, and its report (``report.json``, schema and writer
    ``aerotri.adjust.report``) as the typed record the stages after it read (``report_record``)."""

    adjustment: BlockAdjustment
    record: AdjustmentRecord
    report_path: Path  # report.json as written (with report.txt/html, eo.txt, object_points.csv beside it)


@committed(lambda ba, root, html=True, out_dir=None, settings_record=None, inputs=None:
           Path(out_dir) if out_dir is not None else Project(Path(root), {}).at_dir)
def write_outputs(ba: BlockAdjustment, root, html: bool = True, out_dir=None,
                  settings_record: dict | None = None, inputs: dict | None = None) -> AdjustStageResult:
    """Write at/eo.txt, object_points.csv and report.txt/json/html; returns them as an ``AdjustStageResult``.

    ``out_dir``: another folder than the project's ``at/`` (the chain's first adjustment); ``settings_record``:
    every setting with its source (``core.settings.Resolved.record``), report.json ``settings``; ``inputs``: the
    input files as the adjustment read them (``report_record.record_inputs``, taken before it read them;
    None: taken here), report.json ``inputs``. All texts
    are produced first and written afterwards as one commit (``aerotri.core.atomic.commit_outputs``), so
    an error in any of them (or a kill) leaves all the earlier outputs. A failed solve (not converged, or no finite sigma naught) writes only its
    report, into ``work/adjust_failed/``, and raises ``SolveError``: the earlier outputs stay.
    """
    import json

    from aerotri.adjust import report
    from aerotri.adjust.flight_acceptance import project_terrain
    from aerotri.geom.eo import format_eo
    from aerotri.core.tolerances import qa_settings
    from aerotri.core.atomic import write_text_atomic
    from aerotri.geom.block_scale import project_block_scale

    project = Project.open(root)
    at = Path(out_dir) if out_dir is not None else project.at_dir
    # the limits of the project's table (by its GSD and platform unless [qa] names one), as in reports/
    # the camera of the adjustment before this one (this one's is written below); without at/camera.toml the
    # nominal one: oriented_camera refuses a project adjusted before that file existed, and this is its new adjustment
    camera = None
    if not project.adjusted_camera_path.is_file() and project.camera_path.is_file():
        camera = (project_camera(project), str(project.camera_path))
    # the positions of this adjustment: a block without gnss.txt has no others yet, and its table would fall back to
    # the default 1:5000 while reports/ (after at/eo.txt is written) chooses by the block's GSD (the kite block)
    positions = (ba.eo_map.centre_m, "the adjusted projection centres")
    qa = qa_settings(root, project_block_scale(project, ba.points_map[:, 2], camera=camera, positions=positions))
    built = report.build_report(ba, qa.map_scale, qa.terrain, qa.tolerances,
                                project_terrain(project, dem=ba.settings.dem), speed_mps=project.flight.speed_mps,
                                tolerance_reason=qa.table.reason)
    if settings_record is None:  # a library caller's own settings
        settings_record = settings_of(ba.settings, AdjustSettings).record()
    if inputs is None:  # a library caller's own adjustment: its inputs as they are now
        inputs = record_inputs(project)
    rep = to_record(dataclasses.replace(built, settings=settings_record, inputs=inputs))
    for note in rep["check_blunders"]:  # beside the check table of report.txt, and on the console
        log.warning(note)
    files = {
        "report.txt": report.format_txt(rep),
        "report.json": json.dumps(rep, indent=1, allow_nan=False, default=_json_default),
    }
    if html:
        files["report.html"] = report.format_html(rep, ba)
    if not rep["key_statistics"]["success"]:
        # The orientations of a failed solve are no product: the outputs of an earlier solve stay, the
        # report of this one goes where the user can read why.
        failed = project.work_dir / "adjust_failed"
        with commit_outputs(failed, join=False):  # kept although the command fails (a commit of its own)
            for rel, text in files.items():
                write_text_atomic(failed / rel, text)
        raise SolveError(f"{rep['key_statistics']['message']} sigma naught "
                         f"{rep['key_statistics']['sigma0']}; the report of the failed solve is in {failed} "
                         f"(the earlier outputs in {at} are unchanged)")
    # heights nobody measured (plan-only control, no GNSS or DEM): said where the Z values are (trial-kite)
    relative = () if ba.heights_measured else ("Z relative: no height was measured (plan-only control, no GNSS or "
                                               "DEM); 0 at the control points' median ground (report.txt DATUM)",)
    files.update({"eo.txt": format_eo(ba.eo_map, relative), "object_points.csv": object_points_csv(ba),
                  "camera.toml": _adjusted_camera_toml(ba)})
    for rel, text in files.items():
        write_text_atomic(at / rel, text)
    return AdjustStageResult(adjustment=ba, record=adjustment_record(rep, at / "report.json"),
                             report_path=at / "report.json")


def _adjusted_camera_toml(ba: BlockAdjustment) -> str:
    """at/camera.toml: the camera the orientations of eo.txt belong to (the stages after the adjustment read it
    with ``aerotri.geom.camera.oriented_camera``): the self-calibrated one, or the nominal camera unchanged."""
    groups = tuple(ba.opts.self_calibration)  # the groups estimated (the determinability checks may fix some)
    camera = ba.camera_adjusted if groups else ba.camera_apriori
    why = (f"self-calibrated by aerotri adjust ({', '.join(groups)} estimated)" if groups
           else "the nominal camera.toml, held fixed by aerotri adjust")
    return f"# The camera of eo.txt beside this file: {why}.\n" + camera.to_toml()


def run_adjustment(root, settings: AdjustSettings | Resolved | None = None, out_dir=None,
                   html: bool = True) -> AdjustStageResult:
    """The stage: adjust the project and write its outputs (``write_outputs``); returns the adjustment
    and its report's record. ``aerotri adjust`` and the chain both run this. ``settings``: None, the project's
    (``project_settings``, as ``aerotri adjust P`` without options); a ``Resolved`` carries every setting's source
    into the report."""
    project = Project.open(root)
    resolved = project_settings(project) if settings is None else settings_of(settings, AdjustSettings)
    # the inputs before they are read: one changed during the adjustment differs from the record (the accuracy
    # report's "adjustment made from the current inputs" compares them by content, not by time: F9)
    inputs = record_inputs(project)
    ba = adjust_project(root, resolved.settings)
    return write_outputs(ba, root, html=html, out_dir=out_dir, settings_record=resolved.record(), inputs=inputs)


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))
