"""``aerotri control PROJECT``: transfer LiDAR roof-corner control into the frames."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import click

from aerotri.control.settings import ControlSettings, LayoutRule, MeasureSettings
from aerotri.core.commands import Command
from aerotri.core.settings import click_option

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
@click_option(LayoutRule, "full_spacing_baselines", "--full-spacing")
@click_option(LayoutRule, "height_every_strips", "--height-every")
@click_option(LayoutRule, "min_frames", "--min-frames")
@click_option(LayoutRule, "fallback", "--fallback/--no-fallback")
@click_option(ControlSettings, "tol_px", "--tol-px")
@click_option(MeasureSettings, "eo_sigma_px", "--eo-sigma-px")
@click_option(ControlSettings, "usable_only", "--usable-only/--all-corners")
@click.option("--checks/--no-checks", default=True, show_default=True,
              help="Write accepted corners that are not control as check points.")
@click_option(ControlSettings, "chips", "--chips/--no-chips")
def control(project, corners_path, eo_path, camera_path, manual_path, full_spacing_baselines, height_every_strips,
            min_frames, fallback, tol_px, eo_sigma_px, usable_only, checks, chips):
    """Measure LiDAR roof corners in the frames of PROJECT and write control/points.csv + image_points.csv.

    Chain: aerotri match P; aerotri adjust P (tie points + GNSS); aerotri control P;
    aerotri adjust P --gnss-correction shift (with the transferred control).
    """
    from aerotri.control.pipeline import run_control

    s = ControlSettings()
    settings = dataclasses.replace(
        s, measure=dataclasses.replace(s.measure, eo_sigma_px=eo_sigma_px),
        layout=dataclasses.replace(s.layout, full_spacing_baselines=full_spacing_baselines,
                                   height_every_strips=height_every_strips, min_frames=min_frames,
                                   fallback=fallback),
        tol_px=tol_px, usable_only=usable_only, chips=chips,
    )
    sm = run_control(project, corners_path, eo_path, camera_path, manual_path, settings=settings, checks=checks)
    click.echo(
        f"{sm.corners_accepted} of {sm.corners_measured} corners accepted ({sm.measurements_accepted_in_image} of "
        f"{sm.measurements_attempted} image measurements); control {sm.control_full} full + {sm.control_height} "
        f"height, {sm.check_points} check points; rejected corners {sm.corners_rejected}"
    )
    if sm.layout_targets_unfilled:
        log.warning(f"{sm.layout_targets_unfilled} of {sm.layout_targets} layout positions have no "
                    "accepted corner (measure one manually: --import-manual; why: layout_targets in "
                    "control/transfer.json)")
