"""``aerotri control PROJECT``: transfer LiDAR roof-corner control into the frames."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from aerotri.control.settings import ControlSettings
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
              help="Camera file [default: the camera of the orientations: PROJECT/at/camera.toml for PROJECT/at/eo.txt "
                   "(self-calibrated by the adjustment), else PROJECT/camera.toml].")
@click.option("--import-manual", "manual_path", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Manual measurements point_id,image_id,x_px,y_px (same layout as control/image_points.csv); they "
                   "replace the automatic measurement of that corner in that frame.")
@click_option(ControlSettings, "layout.full_spacing_baselines", "--full-spacing-baselines")
@click_option(ControlSettings, "layout.height_every_strips", "--height-every-strips")
@click_option(ControlSettings, "layout.min_frames", "--min-frames")
@click_option(ControlSettings, "layout.fallback", "--fallback/--no-fallback")
@click_option(ControlSettings, "tol_px", "--tol-px")
@click_option(ControlSettings, "measure.eo_sigma_px", "--eo-sigma-px")
@click_option(ControlSettings, "usable_only", "--usable-only/--all-corners")
@click_option(ControlSettings, "checks", "--checks/--no-checks")
@click_option(ControlSettings, "chips", "--chips/--no-chips")
def control(project, corners_path, eo_path, camera_path, manual_path, **_settings_given):
    """Measure LiDAR roof corners in the frames of PROJECT and write control/points.csv + image_points.csv.

    Chain: aerotri match P; aerotri adjust P --no-control (tie points + GNSS); aerotri control P;
    aerotri adjust P (with the transferred control). Settings: the defaults, then project.toml [control], then
    the options given here (control/transfer.json lists each with where it came from).
    """
    from aerotri.control.pipeline import run_control
    from aerotri.core.project import Project
    from aerotri.core.settings import resolve

    settings = resolve(ControlSettings, Project.open(project), click.get_current_context())
    sm = run_control(project, corners_path, eo_path, camera_path, manual_path, settings=settings)
    click.echo(sm.command_line())
    if sm.layout_targets_unfilled:
        log.warning(f"{sm.layout_targets_unfilled} of {sm.layout_targets} layout positions have no "
                    "accepted corner (measure one manually: --import-manual; why: layout_targets in "
                    "control/transfer.json)")
