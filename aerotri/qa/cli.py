"""``aerotri report PROJECT``: the consolidated accuracy report with pass/fail verdicts."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.project import QaSettings
from aerotri.core.settings import click_option
from aerotri.core.tolerances import SCALE_TABLES, TERRAINS


@click.command(cls=Command, name="report")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click_option(QaSettings, "map_scale", "--scale", type=click.Choice(list(SCALE_TABLES)), default=None,
              show_default=False, help="Target map scale (project.toml [qa] map_scale, else 1:5000).")
@click_option(QaSettings, "terrain", "--terrain", type=click.Choice(list(TERRAINS)), default=None, show_default=False,
              help="Terrain class of the tolerance table (project.toml [qa] terrain, else flat).")
@click_option(QaSettings, "tolerances", "--tolerances", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click_option(QaSettings, "pdf", "--pdf/--no-pdf", default=None, show_default=False,
              help="Also write reports/report.pdf (project.toml [qa] pdf, else no).")
def report(project, map_scale, terrain, tolerances, pdf):
    """LiDAR, control, adjustment and DOM accuracy against the map-scale tolerances:
    reports/index.html, reports/summary.json (and reports/report.pdf)."""
    from aerotri.qa.report import write_qa_report

    # an option not given is None: the report takes project.toml [qa], else the default (aerotri.core.tolerances)
    rep = write_qa_report(project, tolerances, terrain, map_scale, pdf)
    for r in rep["checks"]:
        if r["verdict"]:
            click.echo(f"  {r['verdict']:<5} {r['section']}: {r['quantity']} = {r['value']} {r['unit']} "
                       f"(limit {r['limit']})")
    verdict = rep["overall"] or "no verdict (no quantity with a tolerance yet)"
    click.echo(f"{rep['html']}: {verdict} ({rep['passed']} passed, {rep['failed']} failed; "
               f"{rep['map_scale']} {rep['terrain']})")
