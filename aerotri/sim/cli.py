"""``aerotri sim``: the truth simulator (``aerotri demo`` and ``aerotri run`` live in aerotri.chain.cli)."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.errors import InputError
from aerotri.core.commands import Command, at_least, finite, fraction


@click.command(cls=Command)
@click.option("--preset", "preset", default="demo", show_default=True,
              help="Preset name (tiny, demo, dmc) or path to a preset .toml file.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override the preset's random seed.")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one preset parameter, e.g. --set flight.side_overlap=0.35 (repeatable).")
@click.option("--force", is_flag=True, help="Replace OUTDIR if it exists.")
@click.option("--observations", is_flag=True,
              help="Also write tie and control observations straight from the truth geometry (at/tiepoints.csv, "
                   "control/*.csv), to test the adjustment without matching or rendering.")
@click.option("--tie-sigma-px", type=at_least(0), default=0.3, show_default=True, help="Image noise of those observations.")
@click.option("--n-control", type=click.IntRange(min=0), default=4, show_default=True, help="Number of full control points.")
@click.option("--blunder-fraction", type=fraction(), default=0.0, show_default=True,
              help="Fraction of tie observations displaced by 5-50 px.")
@click.option("--bad-control-shift-m", type=finite(), default=0.0, show_default=True,
              help="Move the first control point horizontally by this much.")
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
def sim(preset, seed, overrides, force, observations, tie_sigma_px, n_control, blunder_fraction,
        bad_control_shift_m, outdir):
    """Simulate a complete project with known truth into OUTDIR."""
    from aerotri.sim import load_preset, simulate

    cfg = load_preset(preset, overrides)
    if seed is not None:
        cfg["preset"]["seed"] = seed
    if not 0.0 <= blunder_fraction < 1.0:
        raise InputError(f"--blunder-fraction {blunder_fraction}: must be in [0, 1)")
    simulate(cfg, outdir, force=force)
    if observations:
        from aerotri.sim.observations import write_truth_observations

        summary = write_truth_observations(outdir, tie_sigma_px=tie_sigma_px, n_control=n_control,
                                           blunder_fraction=blunder_fraction,
                                           bad_control_shift_m=bad_control_shift_m, seed=cfg["preset"]["seed"])
        click.echo(f"truth observations: {', '.join(f'{k} {v}' for k, v in summary.items() if isinstance(v, (int, float)))}")
