"""``aerotri sim`` and ``aerotri demo``."""

from __future__ import annotations

from pathlib import Path

import click

from aerotri.errors import InputError, exit_on_input_error


@click.command()
@click.option("--preset", "preset", default="demo", show_default=True,
              help="Preset name (tiny, demo, dmc) or path to a preset .toml file.")
@click.option("--seed", type=int, default=None, help="Override the preset's random seed.")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one preset parameter, e.g. --set flight.side_overlap=0.35 (repeatable).")
@click.option("--force", is_flag=True, help="Replace OUTDIR if it exists.")
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path))
@exit_on_input_error
def sim(preset, seed, overrides, force, outdir):
    """Simulate a complete project with known truth into OUTDIR."""
    from aerotri.sim import load_preset, simulate

    cfg = load_preset(preset, overrides)
    if seed is not None:
        cfg["preset"]["seed"] = seed
    simulate(cfg, outdir, force=force, log=lambda m: click.echo(m, err=True))


@click.command()
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/demo"))
@click.option("--preset", default="demo", show_default=True, help="Simulator preset for the embedded block.")
@exit_on_input_error
def demo(outdir, preset):
    """Run the main job on the embedded synthetic block: simulate it, then run every stage that exists."""
    from aerotri.sim import load_preset, simulate

    outdir = Path(outdir)
    project = outdir / "project"
    cfg = load_preset(preset)
    if not (project / "truth" / "truth.json").exists():
        simulate(cfg, project, force=True, log=lambda m: click.echo(m, err=True))
    else:
        click.echo(f"{project}: simulated project exists, reusing it", err=True)
    if not project.is_dir():
        raise InputError(f"{project}: simulation did not produce a project")
    click.echo(f"demo project ready in {project}")
