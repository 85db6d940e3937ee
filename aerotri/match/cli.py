"""``aerotri match PROJECT``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from aerotri.core.commands import Command, at_least, finite, fraction, scheduler_options
from aerotri.core.executor import executor_for


@click.command(cls=Command)
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.option("--budget", type=at_least(100, int), default=6000, show_default=True, help="Keypoints per frame (spatially spread).")
@click.option("--max-dim", type=at_least(64, int), default=3000, show_default=True,
              help="Detect on the pyramid level whose larger side is at most this many pixels.")
@click.option("--ratio", type=fraction(open_low=True, open_high=False), default=0.8, show_default=True,
              help="Lowe ratio test threshold, in (0, 1].")
@click.option("--min-overlap", type=fraction(), default=0.15, show_default=True,
              help="Minimum predicted footprint overlap of a candidate pair (fraction of the smaller footprint).")
@click.option("--terrain-height", type=finite(), default=None,
              help="Mean terrain height (m) for the footprints; default: project.toml [flight] or lidar_out/dem.tif.")
@click.option("--image-top-deg", type=finite(), default=0.0, show_default=True,
              help="Direction of the image top relative to the flight direction (0 = forward).")
@click.option("--no-densify", is_flag=True, help="Do not densify weak models.")
@scheduler_options
def match(project, budget, max_dim, ratio, min_overlap, terrain_height, image_top_deg, no_densify, scheduler, workers):
    """Automatic tie points: writes at/tiepoints.csv and at/connectivity.{json,png}."""
    from aerotri.match import MatchSettings, match_project
    from aerotri.match.features import FeatureParams
    from aerotri.match.matching import MatchParams

    s = MatchSettings(sparse=FeatureParams(budget=budget, max_dim_px=max_dim), match=MatchParams(ratio=ratio),
                      min_overlap=min_overlap, terrain_height_m=terrain_height, image_top_deg=image_top_deg,
                      densify=not no_densify)
    s = dataclasses.replace(s)
    with executor_for(scheduler, workers) as ex:
        rep = match_project(project, s, executor=ex)
    click.echo(f"frames {rep['frames']}  pairs {rep['pairs']}  tracks {rep['tracks']}  observations "
               f"{rep['observations']}  3+ rays {100 * rep['tracks_3plus_fraction']:.1f} %  components "
               f"{rep['components']}  weak models {len(rep['weak_models'])}")
