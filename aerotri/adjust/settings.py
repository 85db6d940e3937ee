"""The settings of the adjustment stage (``aerotri adjust`` options, ``[adjust]`` in project.toml).

A light module (no solver imports at import time), so that the command line reads the options' types,
choices and defaults from here without loading the adjustment. :func:`for_project` completes the settings
with what the project folder holds, the same way for ``aerotri adjust P`` and for ``aerotri run``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import ClassVar

from aerotri.core.settings import PROJECT_TOML, DEFAULT, Resolved, setting
from aerotri.core.project import LEVER_ARM_MAX_M

GNSS_CORRECTIONS = ("none", "shift", "shift_drift")
# a LiDAR strip's georeferencing error, plan and height (m): lidarctl corners' sigma_strip_xy_m and sigma_strip_z_m
DEFAULT_SURFACE_BIAS_SIGMA_M = 0.03
# the self-calibration of a camera that is the EXIF's nominal one (focal length from EXIF, principal point at the
# centre, no distortion: aerotri.exchange.exif), when none is asked for: a consumer wide-angle lens's radial
# distortion is tens of pixels at the corners (Brighton Beach's FC300S: 60 px), which its tie points determine; the
# focal length only with height control (a DEM or control points), so it is the user's to add
NOMINAL_CAMERA_SELF_CAL = ("pp", "radial")
SELF_CAL_GROUP_NAMES = ("focal", "pp", "radial", "tangential")  # aerotri.adjust.graph.SELF_CAL_GROUPS' keys


@dataclasses.dataclass(frozen=True)
class AdjustSettings:
    """Options of the adjustment (``aerotri adjust``, ``[adjust]`` in project.toml for ``aerotri run``)."""

    SECTION: ClassVar[str] = "adjust"
    gnss_correction: str = setting("none", choices=GNSS_CORRECTIONS,
                                   help="GNSS corrections per strip: none, shift, or shift and drift.")
    gnss_shift_sigma_m: float = setting(0.10, min=0.0, min_open=True,
                                        help="A-priori standard deviation of a strip's GNSS shift, each axis, and of "
                                             "the displacement its drift makes at the strip's ends (m): estimates "
                                             "beyond the limit of 1 % false alarms per block are reported as suspect "
                                             "and the solution as weak.")
    lever_arm_m: tuple[float, float, float] | None = setting(
        None, min=-LEVER_ARM_MAX_M, max=LEVER_ARM_MAX_M,
        help="Antenna offset from the projection centre in the camera frame (m); default project.toml [gnss] "
             "lever_arm_m, else zero.")
    self_calibration: tuple[str, ...] = setting((), choices=SELF_CAL_GROUP_NAMES,
                                                help="Interior orientation groups to estimate.")
    image_sigma_px: float = setting(0.5, min=0.0, min_open=True, help="A-priori image standard deviation (px).")
    image_sigma_from_residuals: bool = setting(
        False, help="Weight the images of the final solve by the standard deviation their residuals show after the "
                    "robust rounds (1.4826 MAD of v / sqrt(r)) instead of image_sigma_px, which then weights the "
                    "robust rounds only: with a wrong a-priori image sigma the GNSS, control and DEM are weighted "
                    "wrongly against the images, and the orientations' sigmas, scaled by a sigma0 the images "
                    "dominate, come out too small or too large (the report says so when sigma0 is outside 0.8-1.25).")
    check: tuple[str, ...] = setting((), help="Control point ids to use as check points.")
    control: tuple[str, ...] = setting((), help="Point ids to use as full control even if marked check.")
    snooping: bool = setting(True, help="Blunder detection (data snooping).")
    alpha: float = setting(1e-4, min=0.0, max=1.0, min_open=True, max_open=True,
                           help="Type I error per coordinate for data snooping.")
    rms_limit_xy_m: float | None = setting(None, min=0.0, min_open=True, help="Plan RMS limit of the control and "
                                           "check points (default: the tolerance table of [qa]).")
    rms_limit_z_m: float | None = setting(None, min=0.0, min_open=True, help="Height RMS limit of the control and "
                                          "check points (default: the tolerance table of [qa]).")
    residual_limit_m: float | None = setting(None, min=0.0, min_open=True, help="Largest ground residual of a "
                                             "control or check point (default: the tolerance table of [qa]).")
    use_gnss: bool = setting(True, help="Use gnss.txt (false: a block adjusted from initial_eo and control alone).")
    initial_eo: Path | None = setting(None, path=True, help="Approximate orientations (EO file: image_id X Y Z omega "
                                                            "phi kappa) of a block without GNSS, whose datum then comes "
                                                            "from control (at least 2 in plan); default for such a "
                                                            "block: from the images (pycolmap on the tie points), "
                                                            "brought into the project CRS by the control points.")
    dem: Path | None = setting(None, path=True, help="DEM (GeoTIFF, project CRS and heights) as surface control: tie "
                                                     "points on the ground observe its height (default: "
                                                     "lidar_out/dem.tif when there, see lidar_surface).")
    surface_sigma_m: float = setting(0.15, min=0.0, min_open=True,
                                     help="Stated precision of the DEM heights (m); the slope adds to it.")
    surface_bias_sigma_m: float | None = setting(
        None, min=0.0, help="Systematic error of the surface control, plan and height (m): a LiDAR strip's "
                            "georeferencing error, shared by all the DEM's (and roof planes') points of a cell of "
                            "surface_bias_cell_m, which the adjustment cannot average away; added to the covariances "
                            "of the orientations, object and check points (not estimated: the solution is the same). "
                            "Default for the project's LiDAR (lidar_out/dem.tif, roof planes): the strip sigmas of "
                            "the roof planes (lidarctl corners), else 0.03 m; for a DEM from elsewhere 0. 0: the "
                            "surface's points taken as independent (formal sigmas: too small by the DEM's "
                            "systematic error).")
    surface_bias_cell_m: float = setting(500.0, min=1.0, help="Width (m) across the flight direction over which the "
                                                              "surface's systematic error is taken as one offset: "
                                                              "about a LiDAR strip's swath.")
    surface_bias_length_m: float = setting(5000.0, min=1.0, help="Length (m) along the flight direction over which "
                                                                 "the surface's systematic error is taken as one "
                                                                 "offset (a LiDAR strip's error holds along it).")
    ndsm: Path | None = setting(None, path=True, help="nDSM (height above ground) that tells tie points on roofs and "
                                                      "trees from those on the ground (default: lidar_out/ndsm.tif "
                                                      "with the LiDAR DEM, else none: robust only).")
    max_ndsm_m: float = setting(1.0, min=0.0, help="Tie points higher than this above the ground (nDSM) get no "
                                                   "surface observation (m).")
    planes: Path | None = setting(None, path=True, help="Roof planes (a lidarctl corners folder with roof_planes.geojson, "
                                                        "or the file) as surface control: tie points on a roof face "
                                                        "observe its plane; needs a DEM (default: "
                                                        "lidar_out/roof_planes.geojson with the LiDAR DEM).")
    plane_sigma_m: float | None = setting(None, min=0.0, min_open=True,
                                          help="LiDAR strip sigma at the roof planes, plan and height (m), added to "
                                               "each plane's fit precision; default the strip sigmas lidarctl corners "
                                               "wrote with the planes ([corners] sigma_strip_xy_m, sigma_strip_z_m).")
    lidar_surface: bool = setting(True, help="Without a DEM given, hold the tie points to the LiDAR stages' DEM "
                                             "(lidar_out/dem.tif, nDSM ndsm.tif) and roof planes "
                                             "(lidar_out/roof_planes.geojson) when the project has them (aerotri "
                                             "adjust and both adjustments of aerotri run).")
    variance_components: bool = setting(False, help="Reweight the observation groups (image, GNSS, control, surface) "
                                                    "by their estimated variance components and solve again; the "
                                                    "components are reported either way.")
    point_covariances: bool = setting(True, help="Standard deviations of every tie point (at/object_points.csv).")
    use_control: bool = setting(True, help="Use control/ (false: tie points and GNSS only, GNSS carries the datum; "
                                           "the first adjustment before the control transfer).")
    refine_approximations: bool = setting(True, help="Refine the attitudes by resection and intersection before "
                                                     "the bundle (with GNSS).")
    leave_one_out: bool = setting(False, help="After the adjustment, adjust again once per control point with that "
                                              "point left out as a check point: at/leave_one_out.json.")
    check_dem: Path | None = setting(None, path=True, help="DEM (GeoTIFF, project CRS and heights) the adjusted tie "
                                                           "points are checked against without holding them to it: "
                                                           "count, median and spread of point - DEM; a median beyond "
                                                           "3 sigma fails the solution, one beyond the height RMS "
                                                           "limit makes it weak (and fails the QA row).")


def _usable_roof_planes(project) -> bool:
    """lidarctl corners wrote roof planes with usable corners (corners.json ``n_usable`` > 0, when it says)."""
    if not project.roof_planes_path.is_file():
        return False
    try:
        summary = json.loads(project.corners_summary_path.read_text()) if project.corners_summary_path.is_file() else {}
    except (OSError, json.JSONDecodeError):
        return False
    return summary.get("n_usable", 1) > 0


def _exif_nominal_camera(project) -> str | None:
    """The name of the project's camera when it is the EXIF's nominal one (``aerotri.exchange.exif``), else None."""
    from aerotri.core.errors import InputError
    from aerotri.geom.camera import Camera

    try:
        cam = Camera.read(project.camera_path)
    except (InputError, OSError, ValueError):
        return None  # no or a bad camera.toml: the adjustment says so
    return cam.name if cam.name.endswith("(EXIF nominal)") else None


def for_project(project, resolved: Resolved, *, first: bool = False, datum_shortfall=None) -> Resolved:
    """The adjustment settings completed from the project folder, the same for ``aerotri adjust P`` and both
    adjustments of ``aerotri run`` (so that a stage run by hand with no options gives what the chain gives):

    - ``lever_arm_m`` not given: project.toml [gnss] lever_arm_m (else zero);
    - ``self_calibration`` not given and the camera the EXIF's nominal one: ``NOMINAL_CAMERA_SELF_CAL``;
    - no DEM given and ``lidar_surface``: the LiDAR stages' DEM, nDSM and roof planes when lidar_out/ has them
      (the roof planes only with usable roof corners);
    - ``first``: the chain's first adjustment, tie points and GNSS only (no control, no GNSS corrections);
    - a GNSS correction not given on the command line that the control cannot carry (too few control points for
      its datum) is not applied: GNSS alone carries the datum, and the note says why (``datum_shortfall(root,
      settings)``: why the control cannot carry the datum, or None; ``aerotri.adjust.pipeline.project_settings``
      passes its own).
    """
    from aerotri.core.settings import COMMAND_LINE

    s = resolved.settings
    if s.lever_arm_m is None:
        source = project.source_of("gnss", "lever_arm_m")
        resolved = resolved.replace("lever_arm_m", project.gnss.lever_arm_m,
                                    f"{PROJECT_TOML} [gnss]" if source == PROJECT_TOML else source)
    if not s.self_calibration and resolved.sources.get("self_calibration", DEFAULT) == DEFAULT:
        name = _exif_nominal_camera(project)
        if name is not None:
            resolved = resolved.replace("self_calibration", NOMINAL_CAMERA_SELF_CAL, DEFAULT,
                                        f"the camera is the EXIF's nominal one ({name}): principal point and radial "
                                        "distortion estimated; the focal length needs height control (add focal with "
                                        "a DEM or control points)")
    if first:
        for path, value in (("use_control", False), ("gnss_correction", "none"), ("check", ()), ("control", ())):
            resolved = resolved.replace(path, value, "aerotri run (first adjustment: tie points and GNSS)")
    s = resolved.settings
    if s.dem is None and s.lidar_surface and project.dem_path.is_file():
        why = "the LiDAR stages' product ([adjust] lidar_surface)"
        resolved = resolved.replace("dem", project.dem_path, DEFAULT, why)
        if s.ndsm is None and project.ndsm_path.is_file():
            resolved = resolved.replace("ndsm", project.ndsm_path, DEFAULT, why)
        if s.planes is None and _usable_roof_planes(project):
            resolved = resolved.replace("planes", project.roof_planes_path, DEFAULT, why)
    s = resolved.settings
    if (datum_shortfall is not None and s.gnss_correction != "none" and s.use_gnss
            and resolved.sources.get("gnss_correction") != COMMAND_LINE
            and project.gnss_path.is_file() and project.tiepoints_path.is_file()):
        short = datum_shortfall(project.root, s)
        if short:
            resolved = resolved.replace("gnss_correction", "none", resolved.sources.get("gnss_correction", DEFAULT),
                                        f"{s.gnss_correction} not applied: {short}; GNSS alone carries the datum")
    s = resolved.settings
    if s.gnss_correction == "none" and s.use_gnss and project.gnss.offset_sigma_m is not None:
        # the solve estimates the flight's one offset (the consumer model): say so where the setting is listed
        note = "; ".join([n for n in (resolved.notes.get("gnss_correction"),) if n] +
                         # (trial s103 F1: "is estimated" where nothing observed it)
                         ["no per-strip correction; one GNSS offset for the flight, estimated where control points "
                          "or a DEM observe it ([gnss] offset_sigma_xy_m, offset_sigma_z_m)"])
        resolved = resolved.replace("gnss_correction", "none", resolved.sources.get("gnss_correction", DEFAULT), note)
    return resolved
