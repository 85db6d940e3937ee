"""``aerotri run`` and ``aerotri demo``: the chain over a project folder (and the embedded synthetic block)."""

from __future__ import annotations

import json
import logging
import shlex
import sys
import time
from pathlib import Path

import click

from aerotri.chain.options import ChainSettings
from aerotri.core.commands import Command, scheduler_options
from aerotri.core.settings import click_option

log = logging.getLogger(__name__)


def report_verdict(root: Path) -> str | None:
    """The overall verdict of the project's reports/summary.json ("pass", "fail", ...), None without one."""
    from aerotri.core.project import project_paths

    path = project_paths(root).report_summary_path
    try:
        return json.loads(path.read_text()).get("overall") if path.is_file() else None
    except (OSError, ValueError, AttributeError):
        return None


@click.command(cls=Command, name="run", per_stage=True)
@click.argument("project", type=click.Path(file_okay=False, path_type=Path))
@click.option("--reference", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="Reference orthophoto for the DOM check.")
@click.option("--points", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="Surveyed points (id,x,y,z[,group]) for the LiDAR height check.")
@click_option(ChainSettings, "rectify.dem", "--dem", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="DEM for the orthophotos (project.toml [rectify] dem; default: the DEM of the LiDAR stages); "
                   "without LiDAR and [adjust] dem, the adjustment's surface control too.")
@click.option("--force", is_flag=True, help="Re-run every stage even when it is up to date.")
@click_option(ChainSettings, "classify.keep_classes", "--keep-lidar-classes", show_default=False,
              help="Keep the classes the LiDAR was delivered with (checked for plausible ground and buildings) "
                   "instead of classifying it (project.toml [classify] keep_classes).")
@click.option("--strict", is_flag=True, help="Exit 3 when the QA verdict of the report is fail (a cron job or CI sees "
                                             "it; without it the chain exits 0 whatever the verdict, the last line "
                                             "and reports/summary.json say it).")
@scheduler_options
def run(project, reference, points, force, strict, scheduler, workers, **_settings_given):
    """The whole chain over PROJECT, resumable: a re-run skips stages whose inputs did not change.

    Stage settings come from project.toml, one section per stage ([strips], [classify], [rasters], [corners],
    [vectors], [match], [adjust], [control], [rectify], [mosaic], [dom_check]; the keys of each stage's
    settings, docs/settings.md), and the options given here. Stages the inputs do not allow (no LiDAR, no
    usable roof corner, no DEM) are left out and the summary says why; the line map ([vectors] enabled = true)
    is optional.
    """
    from aerotri.chain.options import read_options
    from aerotri.chain.run import closing_words, run_project
    from aerotri.chain.runner import format_summary
    from aerotri.core.project import Project

    p = Project.open(project)
    rows = run_project(p, read_options(p, click.get_current_context()), scheduler, workers, force,
                       reference_ortho=reference, surveyed_points=points)
    click.echo(format_summary(rows))
    if closing_words(rows):
        log.warning(closing_words(rows))
    # one last line a night's log ends with (trial s96 M4: the verdict only inside the report stage's row)
    verdict = report_verdict(p.root)
    click.echo(f"{p.root}: the chain ended {time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime())} UTC; QA verdict "
               f"{verdict or 'none (no report)'}" + (f" ({p.report_index_path})" if verdict else ""))
    if strict and verdict == "fail":
        sys.exit(3)


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
    from aerotri.chain.run import run_demo

    click.echo(run_demo(outdir, preset, force, scheduler, workers))


@click.command(cls=Command, name="init")
@click.argument("project", type=click.Path(path_type=Path))
@click.option("--images", "images_dir", required=True, type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="Folder of the frames (TIFF/JPEG/PNG, one camera; the file name without suffix is the image id).")
@click.option("--crs", required=True, help="The project CRS: a projected CRS in metres or feet, e.g. EPSG:32611 "
                                           "(gnss.txt, control and every product are in it).")
@click.option("--camera", "camera_path", type=click.Path(dir_okay=False, exists=True, path_type=Path), default=None,
              help="camera.toml of the calibrated camera [default: from the first frame's EXIF].")
@click.option("--copy", is_flag=True, help="Copy the frames into PROJECT/images [default: symbolic links].")
@click.option("--set", "settings", multiple=True, metavar="SECTION.KEY=VALUE",
              help="A project.toml setting (TOML syntax, or a bare word), checked as every command checks the file, "
                   "e.g. --set project.heights=EPSG:3855 --set flight.mean_terrain_height_m=411 (repeatable; "
                   "`aerotri settings --markdown` lists every key).")
def init(project, images_dir, crs, camera_path, copy, settings):
    """Make the project folder PROJECT (new, or an empty folder): images/ linking the frames, project.toml
    with [project] crs and the other sections commented, camera.toml from --camera or the EXIF
    (docs/project.md describes the folder and every file)."""
    from aerotri.chain.setup import init_project

    r = init_project(project, images_dir, crs, camera_path, copy=copy, settings=settings)
    # the summary and the next step are progress, not a result: -q silences them (s95)
    log.info(f"{r.root}: {r.frames} frames {'linked' if r.linked else 'copied'} into images/, project.toml"
             + (f", camera.toml from {r.camera_source}" if r.camera_source else ""))
    if r.camera_missing:
        log.warning(r.camera_missing)
    # quoted as a shell needs them, so that the hint can be pasted (trial-paths: a folder with spaces)
    root, images = shlex.quote(str(r.root)), shlex.quote(str(r.root / "images"))
    if r.exif_gnss:
        log.info(f"next: aerotri import {root} --format exif {images} (the frames' GNSS positions into "
                 f"gnss.txt), then aerotri run {root}")
    else:
        log.info("next: gnss.txt (image_id X Y Z [sX sY sZ] in the project CRS), or, for a block without GNSS, "
                 f"control points (aerotri import {root} --format odm gcp_list.txt; docs/blocks-without-gnss.md); "
                 f"then aerotri run {root}")
