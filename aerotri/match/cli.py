"""``aerotri match PROJECT``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from aerotri.core.commands import Command, scheduler_options
from aerotri.core.executor import executor_for
from aerotri.core.settings import click_option, default_of
from aerotri.match.settings import FeatureParams, MatchParams, MatchSettings

_SPARSE = default_of(MatchSettings, "sparse")  # the --budget and --max-dim defaults are the sparse features'


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click_option(FeatureParams, "budget", "--budget", default=_SPARSE.budget)
@click_option(FeatureParams, "max_dim_px", "--max-dim", default=_SPARSE.max_dim_px)
@click_option(MatchParams, "ratio", "--ratio", default=default_of(MatchSettings, "match").ratio)
@click_option(MatchSettings, "min_overlap", "--min-overlap")
@click_option(MatchSettings, "terrain_height_m", "--terrain-height")
@click_option(MatchSettings, "image_top_deg", "--image-top-deg")
@click_option(MatchSettings, "densify", "--densify/--no-densify")
@scheduler_options
def match(project, budget, max_dim_px, ratio, min_overlap, terrain_height_m, image_top_deg, densify, scheduler,
          workers):
    """Automatic tie points: writes at/tiepoints.csv and at/connectivity.{json,png}.

    Settings: project.toml [match] (as ``aerotri run`` reads it), then the options given here."""
    from aerotri.core.project import Project
    from aerotri.core.settings import from_table
    from aerotri.match.pipeline import match_project

    p = Project.open(project)
    s = from_table(MatchSettings, p.section("match"), f"{p.config_path} [match]", base_dir=p.root)
    ctx = click.get_current_context()

    def given(name):
        return ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE

    sparse = {k: v for k, v in (("budget", budget), ("max_dim_px", max_dim_px)) if given(k)}
    top = {k: v for k, v in (("min_overlap", min_overlap), ("terrain_height_m", terrain_height_m),
                             ("image_top_deg", image_top_deg), ("densify", densify)) if given(k)}
    s = dataclasses.replace(s, sparse=dataclasses.replace(s.sparse, **sparse),
                            match=dataclasses.replace(s.match, ratio=ratio) if given("ratio") else s.match, **top)
    with executor_for(scheduler, workers) as ex:
        rep = match_project(project, s, executor=ex)
    click.echo(f"frames {rep.frames}  pairs {rep.pairs}  tracks {rep.tracks}  observations "
               f"{rep.observations}  3+ rays {100 * rep.tracks_3plus_fraction:.1f} %  components "
               f"{rep.components}  weak models {len(rep.weak_models)}")
