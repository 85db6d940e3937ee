"""``lidarctl strips``: strip-to-strip differences (``check``) and strip adjustment (``adjust``)."""

from __future__ import annotations

import functools
from pathlib import Path

import click

from aerotri.core.commands import Group
from aerotri.core.settings import click_option
from lidarctl.strips.overlap import SurfaceParams


def surface_options(f):
    """The options of ``SurfaceParams`` (what counts as a smooth surface), in metres and degrees."""
    for name, decl in reversed([("cell_m", "--cell-m"), ("min_points", "--min-points"), ("max_rms_m", "--max-rms-m"),
                                ("max_multi_fraction", "--max-multi-fraction"), ("edge_tol_m", "--edge-tol-m"),
                                ("max_slope_deg", "--max-slope-deg")]):
        f = click_option(SurfaceParams, name, decl)(f)
    return f


def _params(kw: dict) -> SurfaceParams:
    return SurfaceParams(**{k: kw.pop(k) for k in [f for f in SurfaceParams.__dataclass_fields__]})


@click.group(cls=Group, name="strips")
def strips():
    """Strip-to-strip height differences in the overlaps, and strip adjustment."""


@strips.command()
@click.argument("strip_paths", metavar="STRIP...", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@surface_options
@click.option("--crs", default=None, help="CRS (EPSG:code) of files that have none; never guessed.")
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
    for p in s["pairs"]:
        click.echo(f"{p['b']} - {p['a']}: {p['n_cells']} cells, mean {p['mean_m']:+.3f} m, RMS {p['rms_m']:.3f} m, "
                   f"NMAD {p['nmad_m']:.3f} m")
    a = s["all_pairs"]
    click.echo(f"{outdir}: {len(s['pairs'])} pairs of {len(s['strips'])} strips, RMS {a['rms_m']:.3f} m, "
               f"NMAD {a['nmad_m']:.3f} m ({s['points']:,} points, {s['points_per_s']:,.0f} points/s)")
