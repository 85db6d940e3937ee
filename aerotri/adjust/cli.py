"""``aerotri adjust PROJECT``: bundle block adjustment with GNSS and ground control."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.adjust.report_record import AdjustmentRecord
from aerotri.adjust.settings import AdjustSettings
from aerotri.core.commands import Command, FiniteFloatRange
from aerotri.core.project import LEVER_ARM_MAX_M
from aerotri.core.settings import click_option


def _point_ids(ctx, param, values):
    """--check / --control given once per point or as a comma-separated list (as --self-cal takes its groups;
    an id holds no comma: control/points.csv is comma-separated)."""
    return tuple(i.strip() for v in values for i in v.split(",") if i.strip())


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False))
@click_option(AdjustSettings, "gnss_correction", "--gnss-correction")
@click_option(AdjustSettings, "lever_arm_m", "--lever-arm-m", nargs=3,
              type=FiniteFloatRange(min=-LEVER_ARM_MAX_M, max=LEVER_ARM_MAX_M), default=None, show_default=False,
              help="Antenna offset from the projection centre in the camera frame (m) (project.toml [adjust] "
                   "lever_arm_m, else [gnss] lever_arm_m, else zero).")
@click_option(AdjustSettings, "self_calibration", "--self-cal")
@click_option(AdjustSettings, "image_sigma_px", "--image-sigma-px")
@click_option(AdjustSettings, "check", "--check", multiple=True, show_default=False, callback=_point_ids,
              help="Use this control point id as a check point (repeatable, or ids separated by commas) (project.toml "
                   "[adjust] check).")
@click_option(AdjustSettings, "control", "--control", multiple=True, show_default=False, callback=_point_ids,
              help="Use this point id as full control (repeatable, or ids separated by commas) (project.toml [adjust] "
                   "control).")
@click_option(AdjustSettings, "snooping", "--snooping/--no-snooping")
@click_option(AdjustSettings, "use_control", "--no-control", flag_value=False, show_default=False,
              help="Ignore control/ (tie points + GNSS only, e.g. the first adjustment before the control transfer; "
                   "project.toml [adjust] use_control = false).")
@click_option(AdjustSettings, "alpha", "--alpha")
@click.option("--no-html", is_flag=True, help="Skip report.html.")
@click.option("--no-exports", is_flag=True, help="Skip the PATB and COLMAP exports (aerotri export writes them later).")
@click_option(AdjustSettings, "initial_eo", "--eo", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click_option(AdjustSettings, "dem", "--dem", type=click.Path(dir_okay=False, path_type=Path))
@click_option(AdjustSettings, "check_dem", "--check-dem", type=click.Path(dir_okay=False, path_type=Path))
@click_option(AdjustSettings, "surface_sigma_m", "--surface-sigma-m")
@click_option(AdjustSettings, "surface_bias_sigma_m", "--surface-bias-sigma-m")
@click_option(AdjustSettings, "ndsm", "--ndsm", type=click.Path(dir_okay=False, path_type=Path))
@click_option(AdjustSettings, "max_ndsm_m", "--max-ndsm-m")
@click_option(AdjustSettings, "lidar_surface", "--lidar-surface/--no-lidar-surface")
@click_option(AdjustSettings, "variance_components", "--variance-components/--no-variance-components")
@click_option(AdjustSettings, "planes", "--planes", type=click.Path(path_type=Path))
@click_option(AdjustSettings, "plane_sigma_m", "--plane-sigma-m")
@click_option(AdjustSettings, "leave_one_out", "--leave-one-out/--no-leave-one-out")
def adjust(project, no_html, no_exports, **_settings):
    """Adjust the block of PROJECT; writes at/eo.txt, at/object_points.csv, at/report.* and exports.

    Settings: the defaults, then project.toml [adjust], then the options given here; without a DEM given the
    LiDAR stages' DEM, nDSM and roof planes of lidar_out/ when they are there ([adjust] lidar_surface), as
    aerotri run does. at/report.json (settings) and report.txt list each setting with where it came from."""
    from aerotri.adjust.pipeline import project_settings, run_adjustment
    from aerotri.core.project import Project
    from aerotri.core.settings import resolve
    from aerotri.exchange import export_project

    p = Project.open(project)
    settings = project_settings(p, resolve(AdjustSettings, p, click.get_current_context()))
    res = run_adjustment(p.root, settings, html=not no_html)
    if not no_exports:
        export_project(p.root)
    click.echo(_summary(res.record))
    if settings.settings.leave_one_out:
        from aerotri.adjust.leave_one_out import run_leave_one_out

        click.echo(run_leave_one_out(p.root, settings.settings, full=res.adjustment).table())


def _summary(rec: AdjustmentRecord) -> str:
    """The lines ``aerotri adjust`` prints: sigma naught, surface control, check RMS."""
    k = rec.key_statistics
    lines = [f"sigma0 {k.sigma0_um} um, {k.iterations} iterations, dof {k.degrees_of_freedom}: {k.message}"]
    lines += [f"surface control, {c.name}: {c.used} tie points used ({c.rejected} rejected), point - surface "
              f"rms {c.rms_m} m" for c in rec.surface_control]
    if rec.check_rms_m:
        lines.append("check RMS X Y Z (m): " + " ".join("-" if v is None else f"{v:.3f}" for v in rec.check_rms_m))
    return "\n".join(lines)
