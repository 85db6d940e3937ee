"""``aerotri adjust PROJECT``: bundle block adjustment with GNSS and ground control."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.adjust.settings import AdjustSettings
from aerotri.core.commands import Command, finite
from aerotri.core.settings import click_option, constraints, field_named


_SELF_CAL = constraints(field_named(AdjustSettings, "self_calibration"))["choices"]


def _self_cal_groups(ctx, param, value):
    """--self-cal: comma-separated parameter groups (AdjustSettings.self_calibration's choices)."""
    groups = tuple(s.strip() for s in (value or "").split(",") if s.strip())
    bad = [g for g in groups if g not in _SELF_CAL]
    if bad:
        raise click.BadParameter(f"{', '.join(bad)}: expected a comma-separated list of {', '.join(_SELF_CAL)}",
                                 ctx=ctx, param=param)
    return value


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False))
@click_option(AdjustSettings, "gnss_correction", "--gnss-correction")
@click.option("--lever-arm", nargs=3, type=finite(), default=None,
              help="Antenna offset from the projection centre in the camera frame (m); default project.toml [gnss] lever_arm_m.")
@click.option("--self-cal", "self_cal", default="", callback=_self_cal_groups,
              help=f"Interior orientation groups to estimate, comma-separated: {', '.join(_SELF_CAL)}.")
@click_option(AdjustSettings, "image_sigma_px", "--image-sigma",
              help="A-priori image standard deviation (px); default project.toml [adjust] image_sigma_px, else 0.5.")
@click.option("--check", "check", multiple=True, help="Use this control point id as a check point (repeatable).")
@click.option("--control", "control", multiple=True, help="Use this point id as full control (repeatable).")
@click.option("--no-snooping", is_flag=True, help="Disable blunder detection.")
@click.option("--no-control", is_flag=True,
              help="Ignore control/ (tie points + GNSS only, e.g. the first adjustment before control transfer).")
@click_option(AdjustSettings, "alpha", "--alpha")
@click.option("--no-html", is_flag=True, help="Skip report.html.")
@click.option("--no-exports", is_flag=True, help="Skip the PATB and COLMAP exports (aerotri export writes them later).")
@click.option("--eo", "initial_eo", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Approximate orientations (image_id X Y Z omega phi kappa) of a block without GNSS, whose datum "
                   "then comes from the control points (at least 2 in plan); default for such a block: from the "
                   "images (pycolmap on the tie points), brought into the project CRS by the control points.")
@click_option(AdjustSettings, "dem", "--dem", type=click.Path(dir_okay=False, path_type=Path),
              help="DEM (GeoTIFF in the project CRS and heights) as surface control: tie points on the ground observe "
                   "its height; default project.toml [adjust] dem, else none.")
@click_option(AdjustSettings, "surface_sigma_m", "--surface-sigma-m")
@click_option(AdjustSettings, "ndsm", "--ndsm", type=click.Path(dir_okay=False, path_type=Path),
              help="nDSM (height above ground) to keep tie points on roofs and trees off the DEM; default project.toml "
                   "[adjust] ndsm, else none.")
@click_option(AdjustSettings, "max_ndsm_m", "--max-ndsm-m")
@click_option(AdjustSettings, "variance_components", "--variance-components/--no-variance-components")
@click_option(AdjustSettings, "planes", "--planes", type=click.Path(path_type=Path),
              help="Roof planes: the lidarctl corners folder (roof_planes.geojson, project CRS) as surface control: tie "
                   "points on a roof face observe its plane (with --dem); default project.toml [adjust] planes, else none.")
@click_option(AdjustSettings, "plane_sigma_m", "--plane-sigma-m")
@click_option(AdjustSettings, "leave_one_out", "--leave-one-out/--no-leave-one-out")
def adjust(project, gnss_correction, lever_arm, self_cal, image_sigma_px, check, control, no_snooping, no_control, alpha,
           no_html, no_exports, initial_eo, dem, surface_sigma_m, ndsm, max_ndsm_m, variance_components, planes,
           plane_sigma_m, leave_one_out):
    """Adjust the block of PROJECT; writes at/eo.txt, at/object_points.csv, at/report.* and exports."""
    from aerotri.adjust.pipeline import run_adjustment
    from aerotri.exchange import export_project

    settings = AdjustSettings(
        gnss_correction=gnss_correction,
        lever_arm_m=tuple(lever_arm) if lever_arm else None,
        self_calibration=tuple(s.strip() for s in self_cal.split(",") if s.strip()),
        image_sigma_px=image_sigma_px,
        check=tuple(check),
        control=tuple(control),
        snooping=not no_snooping,
        use_control=not no_control,
        alpha=alpha,
        initial_eo=initial_eo,
        dem=dem, surface_sigma_m=surface_sigma_m, ndsm=ndsm, max_ndsm_m=max_ndsm_m, planes=planes,
        plane_sigma_m=plane_sigma_m, variance_components=variance_components, leave_one_out=leave_one_out,
    )
    ba, rep = run_adjustment(project, settings, html=not no_html)
    if not no_exports:
        export_project(project)
    k = rep["key_statistics"]
    click.echo(f"sigma0 {k['sigma0_um']} um, {k['iterations']} iterations, dof {k['degrees_of_freedom']}: {k['message']}")
    sc = rep.get("surface_control")
    if sc:
        for name, c in (sc.get("classes") or {"DEM": sc}).items():
            click.echo(f"surface control, {name}: {c['used']} tie points used ({c['rejected']} rejected), point - surface "
                       f"rms {c['rms_m']} m")
    if rep["check_rms_m"]:
        click.echo("check RMS X Y Z (m): " + " ".join(f"{v:.3f}" for v in rep["check_rms_m"]))
    if leave_one_out:
        from aerotri.adjust.leave_one_out import run_leave_one_out

        click.echo(run_leave_one_out(project, settings, full=ba).table())
