"""``aerotri report PROJECT``: the consolidated accuracy report with pass/fail verdicts."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.tolerances import SCALE_TABLES, TERRAINS


@click.command(cls=Command, name="report")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option("--scale", "scale", type=click.Choice(list(SCALE_TABLES)), default=None,
              help="Target map scale (default: [qa] map_scale of project.toml, else 1:5000).")
@click.option("--terrain", type=click.Choice(list(TERRAINS)), default=None,
              help="Terrain class of the tolerance table (default: [qa] terrain, else flat).")
@click.option("--tolerances", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Your own tolerance table (TOML, same layout as aerotri/core/tolerance_tables/*.toml).")
@click.option("--pdf/--no-pdf", default=None, help="Also write reports/report.pdf (default: [qa] pdf).")
def report(project, scale, terrain, tolerances, pdf):
    """LiDAR, control, adjustment and DOM accuracy against the map-scale tolerances:
    reports/index.html, reports/summary.json (and reports/report.pdf)."""
    from aerotri.qa.report import write_qa_report

    rep = write_qa_report(project, tolerances, terrain, scale, pdf)
    for r in rep["checks"]:
        if r["verdict"]:
            click.echo(f"  {r['verdict']:<5} {r['section']}: {r['quantity']} = {r['value']} {r['unit']} "
                       f"(limit {r['limit']})")
    verdict = rep["overall"] or "no verdict (no quantity with a tolerance yet)"
    click.echo(f"{rep['html']}: {verdict} ({rep['passed']} passed, {rep['failed']} failed; "
               f"{rep['map_scale']} {rep['terrain']})")
