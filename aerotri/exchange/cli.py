"""``aerotri export PROJECT`` / ``aerotri import PROJECT``: the block in the formats other software reads
and writes."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.commands import positive
from aerotri.exchange.import_registry import IMPORT_FORMATS
from aerotri.exchange.registry import DEFAULT_FORMATS, EXPORT_FORMATS


@click.command(cls=Command, name="export", help=(
    "Export the adjusted block of PROJECT (read from at/, control/, camera.toml) for other software: "
    + "; ".join(f"{e.name}: {e.description}" for e in EXPORT_FORMATS.values())))
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.option("--format", "formats", multiple=True, type=click.Choice(list(EXPORT_FORMATS)),
              default=DEFAULT_FORMATS, show_default=True, help="Export format (repeatable).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder [PROJECT/at].")
def export(project, formats, out_dir):
    from aerotri.exchange.registry import export_project

    for path in export_project(project, formats, out_dir):
        click.echo(str(path))


@click.command(cls=Command, name="import", help=(
    "Import other software's cameras, orientations (imported/eo.txt, approximations), positions (gnss.txt: EXIF "
    "GNSS, or with --as-gnss) and control (control/) into PROJECT; imported/imports.json lists every file written: " + "; ".join(f"{i.name} ({i.files}): {i.description}" for i in IMPORT_FORMATS.values())))
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.argument("files", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--format", "format_name", required=True, type=click.Choice(list(IMPORT_FORMATS)),
              help="Format of FILES.")
@click.option("--crs", default=None, help="CRS of FILES when they carry none (e.g. EPSG:32611); converted to the "
                                          "project CRS. For an ODM gcp_list.txt with a 2D header: the header's CRS "
                                          "with the heights' vertical CRS (EPSG:32611+5703: orthometric heights, "
                                          "converted through the geoid grid).")
@click.option("--sigma-xyz-m", "sigma_xyz_m", type=positive(), nargs=3, default=None,
              help="Accuracy (m) of imported positions that come without one.")
@click.option("--as-gnss", is_flag=True, help="Also write the imported camera positions to gnss.txt as GNSS "
                                             "observations (accuracies: --sigma-xyz-m, else the format's own); without "
                                             "it a reconstruction's orientations go to imported/eo.txt only.")
@click.option("--force", is_flag=True, help="Replace project files the import writes (camera.toml, gnss.txt, ...).")
@click.option("--heights-measured", is_flag=True,
              help="Control heights that are all 0 (or all one number) were surveyed: keep them as height control "
                   "(default: taken as not measured, the points become plan-only control).")
def import_(*, project, files, format_name, crs, sigma_xyz_m, as_gnss, force, heights_measured):
    from aerotri.exchange.import_registry import import_files
    from aerotri.exchange.imported import ImportSettings

    options = ImportSettings(crs=crs, sigma_xyz_m=tuple(sigma_xyz_m) if sigma_xyz_m else None, as_gnss=as_gnss,
                            heights_measured=heights_measured)
    for written in import_files(project, format_name, files, options, overwrite=force):
        click.echo(str(written))
