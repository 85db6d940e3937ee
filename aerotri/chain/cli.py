"""``aerotri run`` and ``aerotri demo``: the chain over a project folder (and the embedded synthetic block)."""

from __future__ import annotations

import logging

import dataclasses
import json
from pathlib import Path

import click

from aerotri.core.commands import Command, scheduler_options
from aerotri.core.executor import Executor, activate

log = logging.getLogger(__name__)


def _run_chain(project_dir: Path, scheduler, workers, force: bool, keep_lidar_classes: bool = False,
               **inputs) -> list[dict]:
    from aerotri.chain.options import read_options
    from aerotri.chain.runner import run_stages
    from aerotri.chain.stages import Chain
    from aerotri.core.project import Project

    project = Project.open(project_dir)
    options = read_options(project)  # project.toml checked whole before any stage runs
    if keep_lidar_classes:
        options = dataclasses.replace(options, classify=dataclasses.replace(options.classify, keep_classes=True))
    chain = Chain(project, options, **inputs)
    chain.check_files()
    stages = chain.stages()
    with Executor(scheduler, workers) as ex, activate(ex):
        log.info(f"tasks run on {ex.describe()}")
        return run_stages(project.root, stages, force=force)


def _closing_words(rows: list[dict]) -> str | None:
    """One line when the chain could not make the orthophotos (it ran everything else it could)."""
    for r in rows:
        if r["stage"] == "rectify" and r["status"] == "skipped":
            return f"stopped after the adjustment: {r['why']}"
    return None


def _stale_simulation(project: Path, cfg: dict) -> str | None:
    """Why the simulated project must be made (again), or None: missing, or its project.toml lacks the
    stage options the preset gives (a project simulated by an earlier version)."""
    import tomllib

    if not (project / "truth" / "truth.json").is_file() or not (project / "project.toml").is_file():
        return "no simulated project yet"
    have = tomllib.loads((project / "project.toml").read_text())

    def differs(want: dict, got: dict, name: str) -> str | None:
        for key, value in want.items():
            if isinstance(value, dict):
                why = differs(value, got.get(key) or {}, f"{name}.{key}")
                if why:
                    return why
            elif got.get(key) != value:
                return f"project.toml [{name}] {key} is not the preset's {value!r}"
        return None

    for section, table in cfg.get("chain", {}).items():
        why = differs(table, have.get(section) or {}, section)
        if why:
            return why
    return None


@click.command(cls=Command, name="run", per_stage=True)
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.option("--reference", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="Reference orthophoto for the DOM check.")
@click.option("--points", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="Surveyed points (id,x,y,z[,group]) for the LiDAR height check.")
@click.option("--dem", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="DEM for the orthophotos (overrides [rectify] dem; default: the DEM of the LiDAR stages).")
@click.option("--force", is_flag=True, help="Re-run every stage even when it is up to date.")
@click.option("--keep-lidar-classes", is_flag=True,
              help="Keep the classes the LiDAR was delivered with (checked for plausible ground and buildings) "
                   "instead of classifying it; the same as [classify] keep_classes = true.")
@scheduler_options
def run(project, reference, points, dem, force, keep_lidar_classes, scheduler, workers):
    """The whole chain over PROJECT, resumable: a re-run skips stages whose inputs did not change.

    Stage options come from project.toml, one section per stage ([strips], [classify], [rasters], [corners],
    [vectors], [match], [adjust], [control], [rectify], [mosaic]; the keys of each stage's settings). Stages
    the inputs do not allow (no LiDAR, no usable roof corner, no DEM) are left out and the summary says why;
    the line map ([vectors] enabled = true) is optional.
    """
    from aerotri.chain.runner import format_summary

    rows = _run_chain(project, scheduler, workers, force, keep_lidar_classes, reference_ortho=reference,
                      surveyed_points=points, dem=dem)
    click.echo(format_summary(rows))
    last = _closing_words(rows)
    if last:
        log.warning(last)


@click.command(cls=Command, per_stage=True)
@click.argument("outdir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/demo"))
@click.option("--preset", default="demo", show_default=True, help="Simulator preset for the embedded block.")
@click.option("--force", is_flag=True, help="Re-run every stage even when it is up to date.")
@scheduler_options
def demo(outdir, preset, force, scheduler, workers):
    """The main job on the embedded synthetic block: simulate it, then run the whole chain on it.

    Every stage uses only the project's inputs; truth/ is read by the final checks alone (DOM against
    the true orthophoto, LiDAR heights at the surveyed targets, classification against true classes).
    """
    from aerotri.chain.runner import format_summary
    from aerotri.core.atomic import write_text_atomic
    from aerotri.sim import load_preset, simulate

    outdir = Path(outdir)
    project = outdir / "project"
    cfg = load_preset(preset)
    stale = _stale_simulation(project, cfg)
    if stale:
        log.info(f"{project}: {stale}: simulating it")
        simulate(cfg, project, force=True)
    else:
        log.info(f"{project}: simulated project exists, reusing it")
    rows = _run_chain(project, scheduler, workers, force, reference_ortho=project / "truth" / "ortho.tif",
                      surveyed_points=project / "truth" / "checkpoints.csv", truth_classes=True)
    table = format_summary(rows)
    write_text_atomic(outdir / "summary.txt", table + "\n")
    write_text_atomic(outdir / "summary.json", json.dumps(rows, indent=1, default=str) + "\n")
    click.echo(table)


@click.command(cls=Command, name="init")
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--images", "images_dir", required=True, type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="Folder of the frames (TIFF/JPEG/PNG, one camera; the file name without suffix is the image id).")
@click.option("--crs", required=True, help="The project CRS: a projected CRS in metres or feet, e.g. EPSG:32611 "
                                           "(gnss.txt, control and every product are in it).")
@click.option("--camera", "camera_path", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="camera.toml of the calibrated camera [default: from the first frame's EXIF].")
@click.option("--copy", is_flag=True, help="Copy the frames into PROJECT/images [default: symbolic links].")
def init(project, images_dir, crs, camera_path, copy):
    """Make the project folder PROJECT (new, or an empty folder): images/ linking the frames, project.toml
    with [project] crs and the other sections commented, camera.toml from --camera or the EXIF
    (docs/project.md describes the folder and every file)."""
    from aerotri.chain.setup import init_project

    r = init_project(project, images_dir, crs, camera_path, copy=copy)
    click.echo(f"{r.root}: {r.frames} frames {'linked' if r.linked else 'copied'} into images/, project.toml"
               + (f", camera.toml from {r.camera_source}" if r.camera_source else ""))
    if r.camera_missing:
        log.warning(r.camera_missing)
    click.echo("next: gnss.txt (image_id X Y Z [sX sY sZ] in the project CRS; drone frames with GNSS in EXIF: "
               f"aerotri import {r.root} --format exif {r.root / 'images'}), then aerotri run {r.root}")
