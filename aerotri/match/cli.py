"""``aerotri match PROJECT``."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command, scheduler_options
from aerotri.core.settings import click_option
from aerotri.match.settings import MatchSettings


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click_option(MatchSettings, "sparse.budget", "--budget")
@click_option(MatchSettings, "sparse.max_dim_px", "--max-dim-px")
@click_option(MatchSettings, "match.ratio", "--ratio")
@click_option(MatchSettings, "min_overlap", "--min-overlap")
@click_option(MatchSettings, "terrain_height_m", "--terrain-height-m")
@click_option(MatchSettings, "image_top_deg", "--image-top-deg")
@click_option(MatchSettings, "densify", "--densify/--no-densify")
@scheduler_options
def match(project, scheduler, workers, **_settings):
    """Automatic tie points: writes at/tiepoints.csv and at/connectivity.{json,png}.

    Settings: the defaults, then project.toml [match] (as ``aerotri run`` reads it), then the options given
    here; at/connectivity.json lists each with where it came from."""
    from aerotri.core.executor import executor_for
    from aerotri.core.project import Project
    from aerotri.core.settings import resolve
    from aerotri.match.pipeline import match_project

    settings = resolve(MatchSettings, Project.open(project), click.get_current_context())
    with executor_for(scheduler, workers) as ex:
        report = match_project(project, settings, executor=ex)
    click.echo(report.summary_line())
    from aerotri.adjust.flight_acceptance import say_split_block

    say_split_block(project, report.components)
    from aerotri.match.weak import weak_model_words

    for line in weak_model_words(report.models, len(report.densified.models), settings.settings.min_per_region):
        click.echo(line)
