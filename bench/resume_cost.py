"""What keeping a stage's finished work for a resumed run costs, and what a resume saves (issue 41)
-> bench/results/resume_cost.json (docs/full-size-block.md, "Resuming the match stage", "Resuming the classify
stage and the mosaic").

On a copy of PROJECT (its images, lidar and trajectory hard-linked: inputs are never written), for
``aerotri match`` (its feature and match caches emptied before every run, so that each run computes) and
``aerotri control``: one uninterrupted run; then runs killed (SIGKILL, or SIGTERM, which ends a command as Ctrl-C
does) once ``work/<stage>_resume`` holds the given share of the frames (match: also of the pairs), each followed by
the re-run. The chain's ``classify`` stage (``--stages classify``: run_stages with force, one tile at a time, so
that a kill falls between tiles and the peak memory stays that of one tile) is killed once the given share of its
tiles is kept; ``ortho mosaic`` (``--stages mosaic``: tiles of 256 px) once the given share of its rows of tiles
is kept. Their uninterrupted runs are also measured without the keeping (``classify_files`` without ``resume_dir``;
the mosaic without its resume folder), the overhead. Each run is a child process: wall seconds, CPU seconds and peak RSS from
``os.wait4``; the re-run's "resumed" lines; its outputs against the uninterrupted run's (byte for byte;
at/connectivity.json but for ``seconds`` and ``phase_seconds``); whether the resume folder is gone after it. Load
averages beside every run.

Usage (nice -n 10 on a shared machine; the runs inherit it):
  python bench/resume_cost.py --project DIR --work SCRATCH [--signal KILL|TERM] [--share 0.5] [--key NAME]
       [--stages match,control|classify|mosaic] [--out bench/results/resume_cost.json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, store_result  # noqa: E402

CMD = "import sys; sys.argv[0] = 'aerotri'; from aerotri.cli import main; sys.exit(main())"
# the chain's classify stage alone (forced), its tiles one at a time (2 numba threads each); NO_KEEP: without the
# keeping for a resumed run (classify_files without resume_dir)
CLASSIFY = """import logging, signal, sys
from pathlib import Path
from aerotri.chain import chain_stages, run_stages
from aerotri.core.executor import Executor, activate
logging.basicConfig(level=logging.INFO, format="%(message)s")
def _term(signum, frame):  # SIGTERM ends the stage as Ctrl-C does, as in `aerotri run` (aerotri.core.commands)
    raise KeyboardInterrupt
signal.signal(signal.SIGTERM, _term)
if sys.argv[2] == "NO_KEEP":
    import lidarctl.tiles as T
    classify_files = T.classify_files
    T.classify_files = lambda *a, resume_dir=None, **k: classify_files(*a, **k)
root = Path(sys.argv[1])
with Executor(None, 1) as ex, activate(ex):
    run_stages(root, [s for s in chain_stages(root) if s.name == "classify"], force=True)
"""
# ``ortho mosaic`` in rows of 256 px tiles (the demo's 3,660 rows of pixels: 15 rows of tiles, each kept as it is
# written); NO_KEEP: without the keeping (the rows are files all the same)
MOSAIC_TILE_PX = 256
MOSAIC = """import contextlib, sys
if sys.argv[2] == "NO_KEEP":
    import ortho.mosaic as M
    M.resumable = lambda folder: contextlib.nullcontext()
sys.argv[0] = "ortho"
from ortho.cli import main
sys.exit(main(["mosaic", sys.argv[1], "--tile-px", sys.argv[3]]))
"""
OUTPUTS = {"match": ["at/tiepoints.csv", "at/connectivity.json", "at/connectivity.png"], "control": ["control"],
           "classify": ["lidar_out/classified"],
           "mosaic": ["ortho/mosaic.tif", "ortho/mosaic.json", "ortho/seams.tif", "ortho/seamlines.geojson",
                      "ortho/seamlines_preview.png", "ortho/seamlines.gpkg"]}


def _files(root: Path, names: list[str]) -> dict:
    out = {}
    for name in names:
        p = root / name
        for f in ([p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())):
            data = f.read_bytes()
            if f.suffix == ".gpkg":  # its rows; gpkg_contents holds the time it was written
                import sqlite3

                with contextlib.closing(sqlite3.connect(f)) as db:
                    data = "\n".join(x for x in db.iterdump() if "gpkg_contents" not in x).encode()
            if f.name == "connectivity.json":  # its times differ from run to run
                doc = json.loads(data)
                data = json.dumps({k: v for k, v in doc.items() if k not in ("seconds", "phase_seconds")}).encode()
            out[str(f.relative_to(root))] = data
    return out


def _fresh(root: Path, stage: str) -> None:
    if stage == "match":
        for name in ("features", "matches"):
            shutil.rmtree(root / "work" / name, ignore_errors=True)


def _run(root: Path, stage: str, kill_at: tuple[str, int] | None = None, sig=signal.SIGKILL, keep_tiles=True) -> dict:
    """One run of the stage; with ``kill_at`` (suffix, count) killed by ``sig`` once the resume folder holds
    ``count`` files of that suffix."""
    keep = root / "work" / f"{stage}_resume"
    log = root.parent / f"{stage}.log"
    t0 = time.perf_counter()
    with open(log, "w") as f:
        how = "KEEP" if keep_tiles else "NO_KEEP"
        args = {"classify": [CLASSIFY, str(root), how], "mosaic": [MOSAIC, str(root), how, str(MOSAIC_TILE_PX)]}.get(
            stage, [CMD, stage, str(root)])
        p = subprocess.Popen([sys.executable, "-c", *args], stdout=f, stderr=subprocess.STDOUT)
    kept_at_kill = None
    while kill_at is not None and p.poll() is None:
        n = sum(1 for q in keep.glob(f"*{kill_at[0]}")) if keep.is_dir() else 0
        if n >= kill_at[1]:
            p.send_signal(sig)
            kept_at_kill = n
            break
        time.sleep(0.02)
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    text = log.read_text()
    return {"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(ru.ru_utime + ru.ru_stime, 2),
            "peak_rss_mb": round(ru.ru_maxrss / 1024, 1), "exit": p.returncode, "kept_at_kill": kept_at_kill,
            "kept_after": len(list(keep.iterdir())) if keep.is_dir() else 0,
            "resumed": [line for line in text.splitlines() if "resumed" in line],
            "load_avg": [round(x, 2) for x in os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True, help="scratch folder (the copy goes there)")
    ap.add_argument("--signal", choices=["KILL", "TERM"], default="KILL")
    ap.add_argument("--share", type=float, default=0.5, help="share of the frames (pairs) kept when killed")
    ap.add_argument("--key", default="demo")
    ap.add_argument("--stages", default="match,control", help="match,control, classify or mosaic")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "resume_cost.json")
    a = ap.parse_args(argv)
    root = a.work / "project"
    if root.exists():
        shutil.rmtree(root)
    inputs = [str(a.project / d) + os.sep for d in ("images", "lidar", "trajectory")]

    def link_inputs(src, dst):  # the frames and point clouds linked; the rest (a lock file, outputs) copied
        return os.link(src, dst) if any(str(src).startswith(d) for d in inputs) else shutil.copy2(src, dst)

    shutil.copytree(a.project, root, copy_function=link_inputs)
    sig = getattr(signal, f"SIG{a.signal}")
    result = {"commit": git_commit(REPO), "project": str(a.project), "signal": a.signal, "share": a.share}
    for stage in a.stages.split(","):
        _fresh(root, stage)
        whole = _run(root, stage)
        assert whole["exit"] == 0, (root.parent / f"{stage}.log").read_text()
        want = _files(root, OUTPUTS[stage])
        rows = {"uninterrupted": whole}
        if stage in ("classify", "mosaic"):
            no_keep = _run(root, stage, keep_tiles=False)
            same = _files(root, OUTPUTS[stage]) == want
            rows["uninterrupted_without_keeping"] = dict(no_keep, outputs_identical=same)
            if stage == "classify":
                tiles = json.loads((root / "work" / "stages" / "classify.json").read_text())["result"]["tiles"]
            else:
                tiles = -(-json.loads((root / "ortho" / "mosaic.json").read_text())["height"] // MOSAIC_TILE_PX)
            result[f"{stage}_units"] = tiles  # classify: tiles; mosaic: rows of tiles
            frames = tiles  # the units a kill counts
            print(f"{stage} uninterrupted {whole['cpu_s']} CPU-s, without keeping {no_keep['cpu_s']} CPU-s")
        if stage == "match":
            conn = json.loads((root / "at" / "connectivity.json").read_text())
            frames, pairs = conn["frames"], conn["pairs"]
            result.update(frames=frames, pairs=pairs)
        points = [({"match": ".npz", "mosaic": ".tif"}.get(stage, ".json"), max(1, round(a.share * frames)))]
        unit = {"match": "frames", "control": "frames", "classify": "tiles", "mosaic": "rows"}[stage]
        if stage == "match":
            points.append((".npy", max(1, round(a.share * pairs))))
        for suffix, count in points:
            _fresh(root, stage)
            killed = _run(root, stage, (suffix, count), sig)
            again = _run(root, stage)
            same = _files(root, OUTPUTS[stage]) == want
            name = f"killed_at_{count}_{'pairs' if suffix == '.npy' else unit}"
            rows[name] = {"killed": killed, "rerun": again, "outputs_identical": same,
                          "resume_folder_gone": not (root / "work" / f"{stage}_resume").exists(),
                          "rerun_cpu_share_of_uninterrupted": round(again["cpu_s"] / whole["cpu_s"], 3)}
            print(f"{stage} {name}: killed at {killed['cpu_s']} CPU-s, re-run {again['cpu_s']} CPU-s "
                  f"(uninterrupted {whole['cpu_s']}), outputs identical {same}, {again['resumed']}")
        result[stage] = rows
    store_result(a.out, result, key=f"{a.key}_{a.signal.lower()}")
    shutil.rmtree(root)
    return 0


if __name__ == "__main__":
    sys.exit(main())
