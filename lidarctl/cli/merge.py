"""``lidarctl merge``: LAS/LAZ strips into one file (what ``aerotri run`` does before classifying)."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.log import counted


@click.command(cls=Command, name="merge")
@click.argument("strips", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.argument("out_path", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--crs", default=None,
              help="The project CRS (EPSG:code): strips tagged with another CRS are refused, strips without a CRS "
                   "record are taken to be in it, and OUT_PATH states it. Default: the strips must agree.")
def merge(strips, out_path, crs):
    """Merge the LiDAR STRIPS into OUT_PATH, every point and dimension kept (point_source_id tells the
    strips apart)."""
    from aerotri.geom.crs.definition import parse_crs
    from lidarctl.merge import merge_las

    n = merge_las(strips, out_path, crs=parse_crs(crs, "--crs") if crs else None)
    click.echo(f"{out_path}: {n} points from {counted(len(strips), 'strip')}")
