"""``aerotri sim``: the truth simulator (``aerotri demo`` and ``aerotri run`` live in aerotri.chain.cli)."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.commands import Command, FiniteFloatRange, finite, fraction


@click.command(cls=Command)
@click.option("--preset", "preset", default="demo", show_default=True,
              help="Preset name (tiny, demo, tall, dmc, dmc_block, scale) or path to a preset .toml file.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override the preset's random seed.")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one preset parameter, e.g. --set flight.side_overlap=0.35 (repeatable).")
@click.option("--force", is_flag=True, help="Replace OUTDIR if it exists.")
@click.option("--observations", is_flag=True,
              help="Also write tie and control observations straight from the truth geometry (at/tiepoints.csv, "
                   "control/*.csv), to test the adjustment without matching or rendering.")
@click.option("--observations-only", is_flag=True,
              help="Write only the block's geometry and observations (tie, control, GNSS) and a DEM of the truth "
                   "terrain (OUTDIR/dem.tif): no images, no LiDAR, so that a block of thousands of frames is made in "
                   "minutes. Its project.toml [adjust] sets the self-calibration and GNSS correction the block's "
                   "errors need: aerotri adjust OUTDIR --dem OUTDIR/dem.tif.")
@click.option("--tie-points-per-frame", type=click.IntRange(1, 10000), default=None,
              help="Tie points (each seen in >= 3 frames) per frame on average; default: the preset's "
                   "observations.tie_points_per_frame (130) with --observations-only, 150 candidates a frame with "
                   "--observations.")
@click.option("--tie-sigma-px", type=FiniteFloatRange(0.0, 10.0), default=None,
              help="Image noise of those observations (default: the preset's observations.tie_sigma_px, 0.3).")
@click.option("--n-control", type=click.IntRange(min=0), default=4, show_default=True, help="Number of full control points.")
@click.option("--blunder-fraction", type=fraction(), default=0.0, show_default=True,
              help="Fraction of tie observations displaced by 5-50 px.")
@click.option("--bad-control-shift-m", type=finite(), default=0.0, show_default=True,
              help="Move the first control point horizontally by this much.")
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
def sim(*, preset, seed, overrides, force, observations, observations_only, tie_points_per_frame, tie_sigma_px,
        n_control, blunder_fraction, bad_control_shift_m, outdir):
    """Simulate a complete project with known truth into OUTDIR."""
    from aerotri.sim.command import simulate_command

    line = simulate_command(preset, outdir, seed=seed, overrides=overrides, force=force, observations=observations,
                            observations_only=observations_only, tie_points_per_frame=tie_points_per_frame,
                            tie_sigma_px=tie_sigma_px, n_control=n_control, blunder_fraction=blunder_fraction,
                            bad_control_shift_m=bad_control_shift_m)
    if line:
        click.echo(line)
