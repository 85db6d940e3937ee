"""``aerotri adjust PROJECT``: bundle block adjustment with GNSS and ground control."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command, finite, fraction, positive


def _self_cal_groups(ctx, param, value):
    """--self-cal: comma-separated parameter groups of aerotri.adjust.graph.SELF_CAL_GROUPS."""
    from aerotri.adjust.graph import SELF_CAL_GROUPS

    groups = tuple(s.strip() for s in (value or "").split(",") if s.strip())
    bad = [g for g in groups if g not in SELF_CAL_GROUPS]
    if bad:
        raise click.BadParameter(f"{', '.join(bad)}: expected a comma-separated list of {', '.join(SELF_CAL_GROUPS)}",
                                 ctx=ctx, param=param)
    return value


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False))
@click.option("--gnss-correction", type=click.Choice(["none", "shift", "shift_drift"]), default="none", show_default=True,
              help="GNSS corrections per strip: none, shift, or shift and drift.")
@click.option("--lever-arm", nargs=3, type=finite(), default=None,
              help="Antenna offset from the projection centre in the camera frame (m); default project.toml [gnss] lever_arm_m.")
@click.option("--self-cal", "self_cal", default="", callback=_self_cal_groups,
              help="Comma-separated: focal, pp, radial, tangential.")
@click.option("--image-sigma", type=positive(), default=None,
              help="A-priori image standard deviation (px); default project.toml [adjust] image_sigma_px, else 0.5.")
@click.option("--check", "check", multiple=True, help="Use this control point id as a check point (repeatable).")
@click.option("--control", "control", multiple=True, help="Use this point id as full control (repeatable).")
@click.option("--no-snooping", is_flag=True, help="Disable blunder detection.")
@click.option("--no-control", is_flag=True,
              help="Ignore control/ (tie points + GNSS only, e.g. the first adjustment before control transfer).")
@click.option("--alpha", type=fraction(open_low=True, open_high=True), default=1e-4, show_default=True,
              help="Type I error per coordinate for data snooping, in (0, 1).")
@click.option("--no-html", is_flag=True, help="Skip report.html.")
@click.option("--no-exports", is_flag=True, help="Skip the PATB and COLMAP exports (aerotri export writes them later).")
@click.option("--eo", "initial_eo", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Approximate orientations (image_id X Y Z omega phi kappa): the start of a block without GNSS, "
                   "whose datum then comes from the control points (at least 2 plan and 3 height).")
def adjust(project, gnss_correction, lever_arm, self_cal, image_sigma, check, control, no_snooping, no_control, alpha,
           no_html, no_exports, initial_eo):
    """Adjust the block of PROJECT; writes at/eo.txt, at/object_points.csv, at/report.* and exports."""
    from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
    from aerotri.exchange import export_project

    settings = AdjustSettings(
        gnss_correction=gnss_correction,
        lever_arm_m=tuple(lever_arm) if lever_arm else None,
        self_calibration=tuple(s.strip() for s in self_cal.split(",") if s.strip()),
        image_sigma_px=image_sigma,
        check=tuple(check),
        control=tuple(control),
        snooping=not no_snooping,
        use_control=not no_control,
        alpha=alpha,
        initial_eo=initial_eo,
    )
    _, rep = run_adjustment(project, settings, html=not no_html)
    if not no_exports:
        export_project(project)
    k = rep["key_statistics"]
    click.echo(f"sigma0 {k['sigma0_um']} um, {k['iterations']} iterations, dof {k['degrees_of_freedom']}: {k['message']}")
    if rep["check_rms_m"]:
        click.echo("check RMS X Y Z (m): " + " ".join(f"{v:.3f}" for v in rep["check_rms_m"]))
