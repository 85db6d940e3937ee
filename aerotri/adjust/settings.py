"""The settings of the adjustment stage (``aerotri adjust`` options, ``[adjust]`` in project.toml).

A light module (no solver imports), so that the command line reads the options' types, choices and
defaults from here without loading the adjustment.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from aerotri.core.settings import setting

GNSS_CORRECTIONS = ("none", "shift", "shift_drift")
SELF_CAL_GROUP_NAMES = ("focal", "pp", "radial", "tangential")  # aerotri.adjust.graph.SELF_CAL_GROUPS' keys


@dataclasses.dataclass
class AdjustSettings:
    """Options of the adjustment (``aerotri adjust``, ``[adjust]`` in project.toml for ``aerotri run``)."""

    gnss_correction: str = setting("none", choices=GNSS_CORRECTIONS,
                                   help="GNSS corrections per strip: none, shift, or shift and drift.")
    lever_arm_m: tuple[float, float, float] | None = setting(
        None, help="Antenna offset from the projection centre in the camera frame (m); default project.toml [gnss] "
                   "lever_arm_m, else zero.")
    self_calibration: tuple[str, ...] = setting((), choices=SELF_CAL_GROUP_NAMES,
                                                help="Interior orientation groups to estimate.")
    image_sigma_px: float | None = setting(None, min=0.0, min_open=True,
                                           help="A-priori image standard deviation (px); default 0.5.")
    check: tuple[str, ...] = setting((), help="Control point ids to use as check points.")
    control: tuple[str, ...] = setting((), help="Point ids to use as full control even if marked check.")
    snooping: bool = setting(True, help="Blunder detection (data snooping).")
    alpha: float = setting(1e-4, min=0.0, max=1.0, min_open=True, max_open=True,
                           help="Type I error per coordinate for data snooping.")
    rms_limit_xy_m: float | None = setting(None, min=0.0, min_open=True)
    rms_limit_z_m: float | None = setting(None, min=0.0, min_open=True)
    residual_limit_m: float | None = setting(None, min=0.0, min_open=True)
    use_gnss: bool = True
    initial_eo: Path | None = setting(None, path=True, help="Approximate orientations (EO file): the start of a block "
                                                            "without GNSS, whose datum then comes from control.")
    dem: Path | None = setting(None, path=True, help="DEM (GeoTIFF, project CRS and heights) as surface control: tie "
                                                     "points on the ground observe its height.")
    surface_sigma_m: float = setting(0.15, min=0.0, min_open=True,
                                     help="Stated precision of the DEM heights (m); the slope adds to it.")
    ndsm: Path | None = setting(None, path=True, help="nDSM (height above ground) that tells tie points on roofs and "
                                                      "trees from those on the ground (default: none, robust only).")
    max_ndsm_m: float = setting(1.0, min=0.0, help="Tie points higher than this above the ground (nDSM) get no "
                                                   "surface observation (m).")
    planes: Path | None = setting(None, path=True, help="Roof planes (a lidarctl corners folder with roof_planes.geojson, "
                                                        "or the file) as surface control: tie points on a roof face "
                                                        "observe its plane; needs a DEM.")
    plane_sigma_m: float | None = setting(None, min=0.0, min_open=True,
                                          help="LiDAR strip sigma at the roof planes, plan and height (m), added to "
                                               "each plane's fit precision; default the strip sigmas lidarctl corners "
                                               "wrote with the planes ([corners] sigma_strip_xy_m, sigma_strip_z_m).")
    lidar_surface: bool = setting(True, help="aerotri run: without [adjust] dem, hold the tie points to the LiDAR "
                                             "stages' DEM (lidar_out/dem.tif, nDSM ndsm.tif) and roof planes "
                                             "(lidar_out/roof_planes.geojson) in both adjustments.")
    variance_components: bool = setting(False, help="Reweight the observation groups (image, GNSS, control, surface) "
                                                    "by their estimated variance components and solve again; the "
                                                    "components are reported either way.")
    point_covariances: bool = True
    use_control: bool = True  # False: ignore control/ (GNSS must carry the datum)
    refine_approximations: bool = True  # resection/intersection of the attitudes before the bundle (GNSS)
    leave_one_out: bool = setting(False, help="After the adjustment, adjust again once per control point with that "
                                              "point left out as a check point: at/leave_one_out.json.")
    check_dem: Path | None = setting(None, path=True, help="DEM (GeoTIFF, project CRS and heights) the adjusted tie "
                                                           "points are checked against without holding them to it: "
                                                           "count, median and spread of point - DEM; a median beyond "
                                                           "3 sigma fails the solution.")
