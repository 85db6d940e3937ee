"""``aerotri report PROJECT``: the consolidated accuracy report with pass/fail verdicts."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.tolerances import SCALE_TABLES, STANDARDS, TERRAINS


@click.command(cls=Command, name="report")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option("--standard", type=click.Choice(list(STANDARDS)), default=None,
              help="Standard of the tolerance table: asprs2023 (ASPRS 2023 classes, by GSD unless --horizontal-"
                   "class-cm/--vertical-class-cm) or cn (Chinese map-scale tables, by GSD unless --scale). "
                   "Default: [qa] of project.toml, else chosen by the block's GSD and platform.")
@click.option("--scale", "scale", type=click.Choice(list(SCALE_TABLES)), default=None,
              help="Chinese map-scale table (default: [qa] map_scale of project.toml, else by GSD and platform).")
@click.option("--horizontal-class-cm", type=click.FloatRange(min=0, min_open=True), default=None,
              help="ASPRS 2023 horizontal accuracy class (RMSE_H, cm); with --standard asprs2023.")
@click.option("--vertical-class-cm", type=click.FloatRange(min=0, min_open=True), default=None,
              help="ASPRS 2023 vertical accuracy class (RMSE_V, cm); with --standard asprs2023.")
@click.option("--terrain", type=click.Choice(list(TERRAINS)), default=None,
              help="Terrain class of a map-scale table (default: [qa] terrain, else flat; ASPRS has none).")
@click.option("--tolerances", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="Your own tolerance table (TOML, same layout as aerotri/core/tolerance_tables/cn_*.toml).")
@click.option("--pdf/--no-pdf", default=None, help="Also write reports/report.pdf (default: [qa] pdf).")
def report(project, standard, scale, horizontal_class_cm, vertical_class_cm, terrain, tolerances, pdf):
    """LiDAR, control, adjustment and DOM accuracy against the block's tolerance table (named with why it
    was chosen; docs/tolerances.md): reports/index.html, reports/summary.json (and reports/report.pdf)."""
    from aerotri.qa.report import write_qa_report

    rep = write_qa_report(project, tolerances, terrain, scale, pdf, standard, horizontal_class_cm, vertical_class_cm)
    t = rep["table"]
    click.echo(f"tolerances: {t['name']} ({t['file']}); chosen because {t['reason']}")
    if t["unconfirmed"]:
        click.echo(f"  limits not confirmed in their source (marked *): {', '.join(t['unconfirmed'])}")
    for r in rep["checks"]:
        if r["verdict"]:
            star = "*" if r.get("limit_confirmed") is False and r["limit"] is not None else ""
            click.echo(f"  {r['verdict']:<5} {r['section']}: {r['quantity']} = {r['value']} {r['unit']} "
                       f"(limit {r['limit']}{star})")
    verdict = rep["overall"] or "no verdict (no quantity with a tolerance yet)"
    click.echo(f"{rep['html']}: {verdict} ({rep['passed']} passed, {rep['failed']} failed; "
               f"{rep['map_scale']} {rep['terrain']})")
