"""``aerotri export PROJECT``: the adjusted block in the formats other software reads."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
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
