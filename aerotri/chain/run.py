"""``aerotri run`` and ``aerotri demo`` as library calls: the chain over a project folder (and the embedded
synthetic block), with the scheduler, the summary rows and the closing words."""

from __future__ import annotations

import json
import logging
import typing
from pathlib import Path

from aerotri.core.project import Project
from aerotri.core.settings import Resolved

if typing.TYPE_CHECKING:
    from aerotri.sim.config import Preset

log = logging.getLogger(__name__)


def run_project(project: Project, settings: Resolved | None = None, scheduler=None, workers=None, force: bool = False,
                **inputs) -> list[dict]:
    """Every stage of the chain over ``project`` (resumable); ``settings``: the stage settings with their sources
    (``aerotri.chain.options.read_options``; None: project.toml's). Files named in project.toml are checked
    before the first stage. Returns the summary rows."""
    from aerotri.chain.options import read_options
    from aerotri.chain.runner import run_stages
    from aerotri.chain.stages import Chain
    from aerotri.core.executor import Executor, activate, check_scheduler

    # Refusals before the first stage (bad input: a frame cut short, a LAZ in another CRS, a malformed --scheduler)
    # leave the project as it was, the earlier run's report and summary included: nothing ran, and bad input changes
    # no file (tests/test_bad_input.py; review 51 had them marked, CI 82 caught it)
    check_scheduler(scheduler)
    chain = Chain(project, settings if settings is not None else read_options(project), **inputs)
    chain.check_files()
    stages = chain.stages()
    with Executor(scheduler, workers) as ex, activate(ex):
        log.info(f"tasks run on {ex.describe()}")
        return run_stages(project.root, stages, force=force)


def closing_words(rows: list[dict]) -> str | None:
    """One line when the chain could not make the orthophotos (it ran everything else it could)."""
    for r in rows:
        if r["stage"] == "match" and r["status"] == "skipped":  # a LiDAR-only project: not "after the adjustment"
            return f"the LiDAR stages only: {r['why']}"
        if r["stage"] == "rectify" and r["status"] == "skipped":
            return f"stopped after the adjustment: {r['why']}"
    return None


def stale_simulation(project: Path, cfg: Preset) -> str | None:
    """Why the simulated project must be made (again), or None: missing, or its project.toml lacks the
    stage options the simulator writes for the preset (``aerotri.sim.project.rendered_chain_table``: a project
    simulated by an earlier version)."""
    import tomllib

    from aerotri.sim.project import rendered_chain_table

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

    for section, table in rendered_chain_table(cfg).items():
        why = differs(table, have.get(section) or {}, section)
        if why:
            return why
    return None


def run_demo(outdir: Path, preset: str = "demo", force: bool = False, scheduler=None, workers=None) -> str:
    """The main job on the embedded synthetic block: simulate it (again when stale), run the whole chain with the
    final checks against truth/, write ``summary.txt`` and ``summary.json`` into ``outdir``; returns the table."""
    from aerotri.chain.runner import format_summary
    from aerotri.core.atomic import write_text_atomic
    from aerotri.sim import load_preset, simulate

    outdir = Path(outdir)
    project = outdir / "project"
    cfg = load_preset(preset)
    stale = stale_simulation(project, cfg)
    if stale:
        log.info(f"{project}: {stale}: simulating it")
        simulate(cfg, project, force=True)
    else:
        log.info(f"{project}: simulated project exists, reusing it")
    rows = run_project(Project.open(project), None, scheduler, workers, force,
                       reference_ortho=project / "truth" / "ortho.tif",
                       surveyed_points=project / "truth" / "checkpoints.csv", truth_classes=True)
    table = format_summary(rows)
    write_text_atomic(outdir / "summary.txt", table + "\n")
    write_text_atomic(outdir / "summary.json", json.dumps(rows, indent=1, default=str) + "\n")
    return table
