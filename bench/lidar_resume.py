"""What a resumed `lidarctl classify` / `lidarctl rasters` saves after a kill, and what keeping the tiles costs
(issue 41) -> bench/results/lidar_resume.json (docs/full-size-block.md, "Resuming lidarctl classify and rasters").

On the demo's strips (PROJECT/lidar/*.las, hard-linked into SCRATCH; `rasters` on PROJECT/lidar_out/classified/*.laz)
each command runs as a child process (wall, CPU seconds and peak RSS from ``os.wait4``), in this order, ``--repeats``
times:

- uninterrupted (the finished tiles kept in OUT.resume as they finish, the folder removed at the end);
- uninterrupted without the keeping (``resume_dir=None`` patched in the child): the keeping's cost;
- killed: a fault-injection hook in the child sends itself SIGKILL once ``--kill-after`` tiles are kept (not a
  timed kill): the tiles another thread was computing are lost, as with a real kill;
- the re-run: its "resumed" line, its outputs' sha256 against the uninterrupted run's, the folder gone after it.

`classify` runs with ``--workers 1`` (one tile at a time: the demo's two tiles side by side peak at 3.4 GB on a
shared machine); `rasters` with its defaults (two tiles at a time) and ``--res-m 0.5`` (the chain's). The demo
has 2 classify tiles and 4 raster tiles at the defaults; ``--classify-tile-size-m`` / ``--tile-px`` give more.

Usage (nice -n 10 on a shared machine; the children inherit it):
  python bench/lidar_resume.py --project DEMO --work SCRATCH [--repeats 2] [--key demo]
       [--commands classify,rasters] [--classify-kill-after 1] [--rasters-kill-after 2]
       [--classify-tile-size-m M] [--tile-px N] [--keeping-only]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, store_result  # noqa: E402

# argv: mode (KEEP, NO_KEEP, KILL), tiles kept before the kill, then the command line
CHILD = """import os, signal, sys, threading
mode, kill_after, args = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
from lidarctl import tiles
from lidarctl.rasters import products
if mode == "NO_KEEP":
    classify_files, write_rasters = tiles.classify_files, products.write_rasters
    tiles.classify_files = lambda *a, resume_dir=None, **k: classify_files(*a, **k)
    products.write_rasters = lambda *a, resume_dir=None, **k: write_rasters(*a, **k)
if mode == "KILL":
    lock, kept = threading.Lock(), [0]

    def counted(f):
        def wrapped(*a, **k):
            out = f(*a, **k)
            with lock:
                kept[0] += 1
                if kept[0] == kill_after:
                    os.kill(os.getpid(), signal.SIGKILL)
            return out
        return wrapped

    tiles.classify_tile = counted(tiles.classify_tile)      # returns once the tile is kept
    products._keep_tile = counted(products._keep_tile)
sys.argv[0] = "lidarctl"
from lidarctl.cli.main import main
main(args)
"""


def _hashes(folder: Path) -> dict:
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(folder.iterdir()) if f.is_file()}


def _run(mode: str, args: list[str], log: Path, kill_after: int = 0) -> dict:
    t0 = time.perf_counter()
    with open(log, "w") as f:
        p = subprocess.Popen([sys.executable, "-c", CHILD, mode, str(kill_after), *args], stdout=f,
                             stderr=subprocess.STDOUT)
    _, status, ru = os.wait4(p.pid, 0)
    text = log.read_text()
    return {"exit": os.waitstatus_to_exitcode(status), "wall_s": round(time.perf_counter() - t0, 2),
            "cpu_s": round(ru.ru_utime + ru.ru_stime, 2), "peak_rss_mb": round(ru.ru_maxrss / 1024, 1),
            "resumed": [line.strip() for line in text.splitlines() if "resumed" in line],
            "load_avg": [round(x, 2) for x in os.getloadavg()]}


def bench_command(name: str, args: list[str], out: Path, kill_after: int, repeats: int, logs: Path,
                  keeping_only: bool = False) -> dict:
    keep = out.with_name(out.name + ".resume")
    rows, want = [], None
    for k in range(repeats):
        whole = _run("KEEP", args, logs / f"{name}_whole.log")
        assert whole["exit"] == 0, (logs / f"{name}_whole.log").read_text()
        got = _hashes(out)
        want = want or got
        whole.update(outputs_identical=got == want, resume_folder_gone=not keep.exists())
        no_keep = _run("NO_KEEP", args, logs / f"{name}_nokeep.log")
        assert no_keep["exit"] == 0, (logs / f"{name}_nokeep.log").read_text()
        no_keep["outputs_identical"] = _hashes(out) == want
        if keeping_only:
            rows.append({"uninterrupted": whole, "uninterrupted_without_keeping": no_keep,
                         "keeping_cpu_s": round(whole["cpu_s"] - no_keep["cpu_s"], 2)})
            print(f"{name} #{k + 1}: uninterrupted {whole['cpu_s']} CPU-s, without keeping {no_keep['cpu_s']}",
                  flush=True)
            continue
        shutil.rmtree(out)
        killed = _run("KILL", args, logs / f"{name}_killed.log", kill_after)
        killed.update(kept=len(list(keep.glob("*.json" if name == "classify" else "*.npy"))) if keep.is_dir() else 0,
                      output_absent=not out.exists() or not _hashes(out))
        again = _run("KEEP", args, logs / f"{name}_rerun.log")
        assert again["exit"] == 0, (logs / f"{name}_rerun.log").read_text()
        again.update(outputs_identical=_hashes(out) == want, resume_folder_gone=not keep.exists())
        row = {"uninterrupted": whole, "uninterrupted_without_keeping": no_keep, "killed": killed, "rerun": again,
               "rerun_cpu_share_of_uninterrupted": round(again["cpu_s"] / whole["cpu_s"], 3),
               "rerun_wall_share_of_uninterrupted": round(again["wall_s"] / whole["wall_s"], 3),
               "keeping_cpu_s": round(whole["cpu_s"] - no_keep["cpu_s"], 2)}
        rows.append(row)
        print(f"{name} #{k + 1}: uninterrupted {whole['cpu_s']} CPU-s {whole['wall_s']} s (without keeping "
              f"{no_keep['cpu_s']}); killed with {killed['kept']} kept at {killed['cpu_s']} CPU-s; re-run "
              f"{again['cpu_s']} CPU-s {again['wall_s']} s ({row['rerun_cpu_share_of_uninterrupted']}), identical "
              f"{again['outputs_identical']}, {again['resumed']}", flush=True)
    best = {k: min(r[k]["cpu_s"] for r in rows) for k in ("uninterrupted", "uninterrupted_without_keeping", "rerun")
            if k in rows[0]}
    return {"args": args, "kill_after_tiles": None if keeping_only else kill_after, "runs": rows, "best_cpu_s": best,
            "best_rerun_cpu_share": round(best["rerun"] / best["uninterrupted"], 3) if "rerun" in best else None,
            "sha256": want}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--project", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--key", default="demo")
    ap.add_argument("--commands", default="classify,rasters")
    ap.add_argument("--classify-kill-after", type=int, default=1)
    ap.add_argument("--rasters-kill-after", type=int, default=2)
    ap.add_argument("--classify-tile-size-m", type=float, default=None)
    ap.add_argument("--tile-px", type=int, default=None, help="lidarctl rasters --tile-px")
    ap.add_argument("--keeping-only", action="store_true",
                    help="only the uninterrupted runs with and without the keeping (its cost), no kill")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "lidar_resume.json")
    a = ap.parse_args(argv)
    work = a.work
    if work.exists():
        shutil.rmtree(work)
    (work / "lidar").mkdir(parents=True)
    (work / "classified_in").mkdir()
    for f in sorted((a.project / "lidar").glob("*.las")):
        os.link(f, work / "lidar" / f.name)
    for f in sorted((a.project / "lidar_out" / "classified").glob("*.laz")):
        os.link(f, work / "classified_in" / f.name)
    result = {"commit": git_commit(REPO), "project": str(a.project), "cpus": os.cpu_count()}
    for name in a.commands.split(","):
        if name == "classify":
            out = work / "classified"
            args = ["classify", *map(str, sorted((work / "lidar").glob("*.las"))), str(out), "--format", "laz",
                    "--crs", "EPSG:32649", "--workers", "1"]
            if a.classify_tile_size_m:
                args += ["--tile-size-m", str(a.classify_tile_size_m)]
            result[name] = bench_command(name, args, out, a.classify_kill_after, a.repeats, work, a.keeping_only)
            chain = _hashes(a.project / "lidar_out" / "classified")
            result[name]["same_as_the_chains_classified_strips"] = chain == result[name]["sha256"]
        else:
            out = work / "r"
            args = ["rasters", *map(str, sorted((work / "classified_in").glob("*.laz"))), str(out), "--res-m", "0.5"]
            if a.tile_px:
                args += ["--tile-px", str(a.tile_px)]
            result[name] = bench_command(name, args, out, a.rasters_kill_after, a.repeats, work, a.keeping_only)
    store_result(a.out, result, key=a.key)
    shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
