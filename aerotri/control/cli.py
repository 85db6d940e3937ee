"""``aerotri control PROJECT``: transfer LiDAR roof-corner control into the frames."""

from __future__ import annotations

import logging

from pathlib import Path

import click

from aerotri.core.commands import Command

log = logging.getLogger(__name__)



@click.command(cls=Command, name="control")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option("--corners", "corners_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Corner file from lidarctl corners [default: PROJECT/lidar_out/corners.csv].")
@click.option("--eo", "eo_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Orientations of the first adjustment (tie points + GNSS) [default: PROJECT/at/eo.txt].")
@click.option("--camera", "camera_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Camera file [default: self-calibrated camera of PROJECT/at/report.json, else PROJECT/camera.toml].")
@click.option("--import-manual", "manual_path", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Manual measurements point_id,image_id,x_px,y_px (same layout as control/image_points.csv); they "
                   "replace the automatic measurement of that corner in that frame.")
@click.option("--full-spacing", default=5.0, show_default=True, type=click.FloatRange(min=0.5),
              help="Full (XYZ) control every this many baselines along the strip edges.")
@click.option("--height-every", default=3, show_default=True, type=click.IntRange(min=0),
              help="Height points in the middle strip of every this many strips (0: none).")
@click.option("--min-frames", default=3, show_default=True, type=click.IntRange(min=2),
              help="A control point must be measured in at least this many frames (3: triple overlap).")
@click.option("--tol-px", default=0.7, show_default=True, type=click.FloatRange(min=0.05),
              help="Multi-ray reprojection residual tolerance (px).")
@click.option("--eo-sigma-px", default=1.0, show_default=True, type=click.FloatRange(min=0.0),
              help="Orientation uncertainty in the image (px), widens the search window.")
@click.option("--all-corners", is_flag=True, help="Measure all corners, not only those marked usable.")
@click.option("--checks/--no-checks", default=True, show_default=True,
              help="Write accepted corners that are not control as check points.")
@click.option("--chips/--no-chips", default=True, show_default=True, help="Write control/review/ (HTML + chips).")
def control(project, corners_path, eo_path, camera_path, manual_path, full_spacing, height_every, min_frames, tol_px,
            eo_sigma_px, all_corners, checks, chips):
    """Measure LiDAR roof corners in the frames of PROJECT and write control/points.csv + image_points.csv.

    Chain: aerotri match P; aerotri adjust P (tie points + GNSS); aerotri control P;
    aerotri adjust P --gnss-correction shift (with the transferred control).
    """
    from aerotri.control.layout import LayoutRule
    from aerotri.control.measure import MeasureSettings
    from aerotri.control.pipeline import ControlSettings, run_control

    settings = ControlSettings(
        measure=MeasureSettings(eo_sigma_px=eo_sigma_px),
        layout=LayoutRule(full_spacing_baselines=full_spacing, height_every_strips=height_every, min_frames=min_frames),
        tol_px=tol_px, usable_only=not all_corners, chips=chips,
    )
    sm = run_control(project, corners_path, eo_path, camera_path, manual_path, settings, checks=checks)
    click.echo(
        f"{sm['corners_accepted']} of {sm['corners_measured']} corners accepted ({sm['measurements_accepted_in_image']} of "
        f"{sm['measurements_attempted']} image measurements); control {sm['control_full']} full + {sm['control_height']} "
        f"height, {sm['check_points']} check points; rejected corners {sm['corners_rejected']}"
    )
    if sm["layout_targets_unfilled"]:
        log.warning(f"{sm['layout_targets_unfilled']} of {sm['layout_targets']} layout positions have no "
                    "accepted corner (measure one manually: --import-manual)")
