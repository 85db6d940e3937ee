"""``lidarctl strips``: strip-to-strip differences (``check``) and strip adjustment (``adjust``)."""

from __future__ import annotations

import functools
from pathlib import Path

import click

from aerotri.core.commands import Group
from aerotri.core.settings import click_option, click_type, default_of
from lidarctl.strips.adjust import StripAdjustResult, StripAdjustSettings
from lidarctl.strips.overlap import SurfaceSettings


def surface_options(f):
    """The options of ``SurfaceSettings`` (what counts as a smooth surface), in metres and degrees."""
    for name, decl in reversed([("cell_m", "--cell-m"), ("min_points", "--min-points"), ("max_rms_m", "--max-rms-m"),
                                ("max_multi_fraction", "--max-multi-fraction"), ("edge_tol_m", "--edge-tol-m"),
                                ("max_slope_deg", "--max-slope-deg"), ("max_dz_m", "--max-dz-m")]):
        f = click_option(SurfaceSettings, name, decl)(f)
    return f


def _params(kw: dict) -> SurfaceSettings:
    return SurfaceSettings(**{k: kw.pop(k) for k in [f for f in SurfaceSettings.__dataclass_fields__]})


@click.group(cls=Group, name="strips")
def strips():
    """Strip-to-strip height differences in the overlaps, and strip adjustment."""


@strips.command()
@click.argument("strip_paths", metavar="STRIP...", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@surface_options
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
@click.option("--png/--no-png", default=True, show_default=True, help="Colour maps (PNG) of the differences.")
def check(strip_paths, outdir, crs, png, **kw):
    """Height differences of overlapping strips on smooth single-return surfaces into OUTDIR.

    STRIP...: several LAS/LAZ files (one strip each) or one file whose strips differ in point_source_id.
    Per pair: dz = z(b) - z(a) on common planar cells (mean, RMS, NMAD; binned by scan angle, with the
    relative roll fitted across the track), diff_<a>_<b>.tif (COG) and .png; per strip the same
    statistics; strips.json and index.html. Lengths in metres, also for clouds in feet.
    """
    from lidarctl.strips.check import check_strips

    s = check_strips(strip_paths, outdir, _params(kw), crs=crs, png=png)
    for p in s.pairs:
        d = p.diff
        click.echo(f"{p.b} - {p.a}: {d.n_cells} cells, mean {d.mean_m:+.3f} m, RMS {d.rms_m:.3f} m, "
                   f"NMAD {d.nmad_m:.3f} m" + (f" ({p.different_surface_cells} cells of different surfaces left out)"
                                               if p.different_surface_cells else ""))
    a = s.all_pairs
    click.echo(f"{outdir}: {len(s.pairs)} pairs of {len(s.strips)} strips, RMS {a.rms_m:.3f} m, "
               f"NMAD {a.nmad_m:.3f} m ({s.points:,} points, {s.points_per_s:,.0f} points/s)")


@strips.command()
@click.argument("strip_paths", metavar="STRIP...", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--trajectory", "trajectories", multiple=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Trajectory text file(s) (time_s x y z roll_deg pitch_deg heading_deg; repeatable) covering every "
                   "strip's GPS times: estimates the boresight angles and range offset shared by all strips and a "
                   "shift per strip. Without: a shift and roll/pitch/heading per strip, one strip fixed.")
@click.option("--fixed", default=None, help="Strip held fixed without a trajectory (a strip name as check names it; "
                                            "with --control none by default).")
@click.option("--control", "control", default=None, type=click.Path(dir_okay=False, path_type=Path),
              help="Control points on smooth surfaces (CSV with a header id,x,y,z in the strips' CRS and units; a "
                   "control surface as several points on it): fix the block's datum (absolute height, and position "
                   "across sloped faces).")
@click_option(StripAdjustSettings, "control_sigma_m", "--control-sigma-m")
@click.option("--adjust-max-slope-deg", "adjust_max_slope_deg", type=click_type(StripAdjustSettings, "max_slope_deg"),
              default=default_of(StripAdjustSettings, "max_slope_deg"), show_default=True,
              help="Steepest planar cells the adjustment uses (deg; sloped roofs carry the horizontal information).")
@click_option(StripAdjustSettings, "shift_sigma_m", "--shift-sigma-m")
@surface_options
@click.option("--crs", default=None, help="CRS (EPSG:code) of files without one, or with an unreadable one.")
@click.option("--png/--no-png", default=True, show_default=True, help="Colour maps (PNG) of the differences.")
def adjust(*, strip_paths, outdir, trajectories, fixed, control, control_sigma_m, adjust_max_slope_deg, shift_sigma_m,
           crs,
           png, **kw):
    """Strip adjustment on plane correspondences in the overlaps; corrected strips (only X, Y, Z change) with
    adjust.json (parameters, sigmas, correlations) and the check before and after (check_before/,
    check_after/) into OUTDIR."""
    from lidarctl.strips.adjust import adjust_strips

    settings = StripAdjustSettings(max_slope_deg=adjust_max_slope_deg, fixed=fixed, shift_sigma_m=shift_sigma_m,
                                   control_sigma_m=control_sigma_m)
    s = adjust_strips(strip_paths, outdir, settings, _params(kw), trajectories=trajectories, crs=crs, png=png,
                      control=control)
    click.echo(_adjust_summary(s, outdir))


def _adjust_summary(s: StripAdjustResult, outdir) -> str:
    """What ``lidarctl strips adjust`` prints: the parameters, the control, the strips left out, the check."""
    # the sign first (trial s96 F4: +0.071 printed, the points moved -0.071 m; the convention was in adjust.json only)
    lines = ["parameters: the strips' errors e (the corrected point is p - e: a shift of +0.07 m moves the strip's "
             "points by -0.07 m), +- their sigmas"]
    left = set(s.strips_without_observations)
    for name, p in s.parameters.items():
        unadjusted = name.split(".")[0] in left
        lines.append(f"{name:32s} {p.value:+10.4f} +- {p.sigma:.4f}" + (
            "  (not adjusted: the prior)" if unadjusted else "  (held: not determined)" if name in s.held else ""))
    if s.control is not None:
        c = s.control
        lines.append(f"control: {c.points_used} of {c.points} points on {c.observations} strip planes, mean "
                     f"distance {c.mean_before_m:+.3f} -> {c.mean_after_m:+.3f} m, RMS {c.rms_before_m:.3f} -> "
                     f"{c.rms_after_m:.3f} m")
    if s.fixed_strip:
        lines.append(f"fixed: {s.fixed_strip} (the others are adjusted to it)")
    if s.model == "boresight" and s.control is None:
        # the overlaps hardly tell the range offset from a common height shift: the free adjustment holds the
        # block's mean height instead of letting it follow the range offset's estimate
        lines.append("datum: the block's mean height as flown (no --control: the mean vertical correction over the "
                     "strips' planar cells is held at 0; the overlaps tell the range offset from a common height "
                     "shift only weakly, see its sigma, and cannot tell the block's true height: check it at "
                     "surveyed points with lidarctl check-heights, or adjust with --control)")
    if s.strips_without_observations:
        # their parameters above are the prior's (0 +- sigma): say so rather than let them pass as estimates
        lines.append(f"warning: not adjusted, no planar cell shared with another strip: "
                     f"{', '.join(s.strips_without_observations)} (copied unchanged)")
    b, a = s.check_before, s.check_after
    lines.append(f"{outdir}: {s.model} model, {s.observations} plane observations, sigma0 {s.sigma0:.2f}; "
                 f"strip differences RMS {b.rms_m:.3f} -> {a.rms_m:.3f} m, NMAD {b.nmad_m:.3f} -> "
                 f"{a.nmad_m:.3f} m ({s.points:,} points, {s.points_per_s:,.0f} points/s)")
    return "\n".join(lines)
