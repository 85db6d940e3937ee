"""``aerotri report PROJECT``: the consolidated accuracy report with pass/fail verdicts."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command
from aerotri.core.project import QaSettings
from aerotri.core.settings import click_option
from aerotri.core.tolerances import SCALE_TABLES, TERRAINS
from aerotri.qa.standards import STANDARD_KEYS


@click.command(cls=Command, name="report")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click_option(QaSettings, "standard", "--standard", type=click.Choice([*STANDARD_KEYS, "cn"]), default=None,
              show_default=False)
@click_option(QaSettings, "accuracy_class", "--class", default=None, show_default=False)
@click_option(QaSettings, "map_scale", "--scale", type=click.Choice(list(SCALE_TABLES)), default=None,
              show_default=False)
@click_option(QaSettings, "horizontal_class_cm", "--horizontal-class-cm", default=None, show_default=False)
@click_option(QaSettings, "vertical_class_cm", "--vertical-class-cm", default=None, show_default=False)
@click_option(QaSettings, "terrain", "--terrain", type=click.Choice(list(TERRAINS)), default=None, show_default=False)
@click_option(QaSettings, "tolerances", "--tolerances", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click_option(QaSettings, "pdf", "--pdf/--no-pdf", default=None, show_default=False)
def report(*, project, standard, accuracy_class, map_scale, horizontal_class_cm, vertical_class_cm, terrain, tolerances,
           pdf):
    """LiDAR, control, adjustment and DOM accuracy against the block's tolerance table (named with why it
    was chosen; docs/tolerances.md), and each product's compliance with a standard and class (--standard,
    --class; docs/standards.md): reports/index.html, reports/summary.json (and reports/report.pdf)."""
    from aerotri.qa.report import console_summary, write_qa_report

    # an option not given is None: [qa] of project.toml decides, else the block's GSD and platform
    rep = write_qa_report(project, tolerance_file=tolerances, terrain=terrain, scale=map_scale, pdf=pdf,
                          standard=standard, horizontal_class_cm=horizontal_class_cm,
                          vertical_class_cm=vertical_class_cm, accuracy_class=accuracy_class)
    click.echo(console_summary(rep))


@click.command(cls=Command, name="compare")
@click.argument("project", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.argument("files", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--format", "format_name", required=True, help="Import format of the reference (aerotri import's "
              "--format: orthority, patb, colmap, opensfm, metashape, ...).")
@click.option("--crs", default=None, help="CRS of FILES when they carry none (as aerotri import --crs).")
def compare(project, files, format_name, crs):
    """The adjusted orientations (at/eo.txt) against a reference AT of the same frames, read as aerotri import
    reads it (the project's inputs and at/ untouched): centre and omega/phi/kappa differences per frame, RMS,
    largest, in the adjustment's sigmas; written to PROJECT/reports/eo_comparison.json."""
    from aerotri.qa.eo_comparison import compare_with_reference, summary_lines

    click.echo("\n".join(summary_lines(compare_with_reference(project, format_name, files, crs))))
