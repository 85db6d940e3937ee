"""``aerotri sim`` and ``aerotri demo``."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.core.errors import InputError
from aerotri.core.commands import Command, scheduler_options
from aerotri.core.executor import Executor, activate


@click.command(cls=Command)
@click.option("--preset", "preset", default="demo", show_default=True,
              help="Preset name (tiny, demo, dmc) or path to a preset .toml file.")
@click.option("--seed", type=int, default=None, help="Override the preset's random seed.")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one preset parameter, e.g. --set flight.side_overlap=0.35 (repeatable).")
@click.option("--force", is_flag=True, help="Replace OUTDIR if it exists.")
@click.option("--observations", is_flag=True,
              help="Also write tie and control observations straight from the truth geometry (at/tiepoints.csv, "
                   "control/*.csv), to test the adjustment without matching or rendering.")
@click.option("--tie-sigma-px", type=float, default=0.3, show_default=True, help="Image noise of those observations.")
@click.option("--n-control", type=int, default=4, show_default=True, help="Number of full control points.")
@click.option("--blunder-fraction", type=float, default=0.0, show_default=True,
              help="Fraction of tie observations displaced by 5-50 px.")
@click.option("--bad-control-shift-m", type=float, default=0.0, show_default=True,
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
    simulate(cfg, outdir, force=force, log=lambda m: click.echo(m, err=True))
    if observations:
        from aerotri.sim.observations import write_truth_observations

        summary = write_truth_observations(outdir, tie_sigma_px=tie_sigma_px, n_control=n_control,
                                           blunder_fraction=blunder_fraction,
                                           bad_control_shift_m=bad_control_shift_m, seed=cfg["preset"]["seed"])
        click.echo(f"truth observations: {', '.join(f'{k} {v}' for k, v in summary.items() if isinstance(v, (int, float)))}",
                   err=True)


@click.command(cls=Command)
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/demo"))
@click.option("--preset", default="demo", show_default=True, help="Simulator preset for the embedded block.")
@click.option("--force", is_flag=True, help="Re-run every stage even when it is up to date.")
@scheduler_options
def demo(outdir, preset, force, scheduler, workers):
    """The main job on the embedded synthetic block: simulate it, then run the whole chain on it.

    Every stage uses only the project's inputs; truth/ is read by the final checks alone (DOM against
    the true orthophoto, LiDAR heights at the surveyed targets, classification against true classes).
    """
    from aerotri.run import chain_stages, format_summary, run_stages
    from aerotri.sim import load_preset, simulate
    from aerotri.core.atomic import write_text_atomic

    outdir = Path(outdir)
    project = outdir / "project"
    if not (project / "truth" / "truth.json").exists():
        simulate(load_preset(preset), project, force=True, log=lambda m: click.echo(m, err=True))
    else:
        click.echo(f"{project}: simulated project exists, reusing it", err=True)
    stages = chain_stages(project, reference_ortho=project / "truth" / "ortho.tif",
                          surveyed_points=project / "truth" / "checkpoints.csv", truth_classes=True)
    with Executor(scheduler, workers) as ex, activate(ex):
        click.echo(f"tasks run on {ex.describe()}", err=True)
        rows = run_stages(project, stages, force=force, log=lambda m: click.echo(m, err=True))
    table = format_summary(rows)
    write_text_atomic(outdir / "summary.txt", table + "\n")
    import json

    write_text_atomic(outdir / "summary.json", json.dumps(rows, indent=1, default=str) + "\n")
    click.echo(table)


@click.command(cls=Command, name="run")
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.option("--reference", type=click.Path(dir_okay=False, path_type=Path), help="Reference orthophoto for the DOM check.")
@click.option("--points", type=click.Path(dir_okay=False, path_type=Path),
              help="Surveyed points (id,x,y,z[,group]) for the LiDAR height check.")
@click.option("--res", "res_m", type=float, default=0.5, show_default=True, help="Elevation raster cell size (m).")
@click.option("--force", is_flag=True, help="Re-run every stage even when it is up to date.")
@scheduler_options
def run(project, reference, points, res_m, force, scheduler, workers):
    """The whole chain over PROJECT, resumable: a re-run skips stages whose inputs did not change."""
    from aerotri.project import Project
    from aerotri.run import chain_stages, format_summary, run_stages

    Project.open(project)
    stages = chain_stages(Path(project), raster_res_m=res_m, reference_ortho=reference, surveyed_points=points)
    with Executor(scheduler, workers) as ex, activate(ex):
        click.echo(f"tasks run on {ex.describe()}", err=True)
        rows = run_stages(Path(project), stages, force=force, log=lambda m: click.echo(m, err=True))
    click.echo(format_summary(rows))
