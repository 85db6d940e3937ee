"""Benchmark: ``aerotri match`` on full-size Z/I DMC frames (13824 x 7680 px, 12-bit in 16-bit ZSTD tiles): wall,
CPU and peak RSS of the command (``/usr/bin/time -v``) and the tie points against the simulator's truth.

The block: bench/sim_dmc.py's subset (default $AEROTRI_BENCH_BLOCKS/dmc_block_subset_3x8, 24 frames; or the whole
block with --block). Its inputs (project.toml, camera.toml, gnss.txt, images/) are hard-linked into a fresh
folder (--work, default /work/tmp/dmc_match) so the features are extracted from the frames, not a cache. Pairs
come from GNSS. The target of issue 41: peak memory under 3 GB whatever the frame size (frames read by windows,
``aerotri.geom.images.read_gray_level``). Tie points: ``aerotri.sim.evaluate.tie_point_errors`` (each track
intersected with the true orientations; residuals in full-resolution pixels).

Writes bench/results/dmc_match.json (one entry per block folder name).

Usage:
  python bench/eval_dmc_match.py
  python bench/eval_dmc_match.py --block /work/bench_blocks/dmc_block --work /work/tmp/dmc_match_full
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(ROOT))

RESULT = ROOT / "bench" / "results" / "dmc_match.json"
BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
LIMIT_PEAK_GB = 3.0


def _time_v(stderr: str) -> dict:
    """Wall, CPU and peak RSS from ``/usr/bin/time -v``."""
    def field(name):
        m = re.search(rf"{re.escape(name)}: (.+)", stderr)
        return m.group(1).strip() if m else None

    wall_s = sum(float(p) * 60 ** k for k, p in enumerate(reversed(field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":"))))
    return dict(wall_s=round(wall_s, 1),
                cpu_s=round(float(field("User time (seconds)")) + float(field("System time (seconds)")), 1),
                peak_rss_mb=round(int(field("Maximum resident set size (kbytes)")) / 1024, 1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--block", type=Path, default=BLOCKS / "dmc_block_subset_3x8")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/dmc_match"))
    args = ap.parse_args()
    from aerotri.sim.evaluate import tie_point_errors

    truth = json.loads((args.block / "truth" / "truth.json").read_text())
    if args.work.exists():
        shutil.rmtree(args.work)
    args.work.mkdir(parents=True)
    for name in ("project.toml", "camera.toml", "gnss.txt"):
        os.link(args.block / name, args.work / name)
    shutil.copytree(args.block / "images", args.work / "images", copy_function=os.link)
    load0 = [round(v, 2) for v in os.getloadavg()]
    p = subprocess.run(["/usr/bin/time", "-v", str(BIN / "aerotri"), "match", str(args.work)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"aerotri match failed ({p.returncode}):\n{p.stderr[-3000:]}")
    usage = _time_v(p.stderr)
    conn = json.loads((args.work / "at" / "connectivity.json").read_text())
    errors = tie_point_errors(args.block, args.work / "at" / "tiepoints.csv")
    frame_mp = truth["image_width_px"] * truth["image_height_px"] / 1e6
    entry = dict(
        block=str(args.block), frames=truth["frames"], image_width_px=truth["image_width_px"],
        image_height_px=truth["image_height_px"], command=f"aerotri match {args.work}", **usage,
        cpu_s_per_frame=round(usage["cpu_s"] / truth["frames"], 2),
        frame_mp_per_cpu_s=round(truth["frames"] * frame_mp / usage["cpu_s"], 1),
        phase_seconds_wall_cpu=conn["phase_seconds"], pairs=conn["pairs"], tracks=conn["tracks"],
        observations=conn["observations"], components=conn["components"], weak_models=len(conn["weak_models"]),
        tie_points_vs_truth={k: (round(v, 4) if isinstance(v, float) else v) for k, v in dataclasses.asdict(errors).items()},
        limit_peak_gb=LIMIT_PEAK_GB, within_limit=usage["peak_rss_mb"] / 1024 < LIMIT_PEAK_GB,
        load_avg_before=load0, load_avg_after=[round(v, 2) for v in os.getloadavg()], cpus=os.cpu_count(),
        measured_utc=time.strftime("%Y-%m-%d %H:%M", time.gmtime()))
    results = json.loads(RESULT.read_text()) if RESULT.exists() else {}
    results[args.block.name] = entry
    RESULT.parent.mkdir(exist_ok=True)
    RESULT.write_text(json.dumps(results, indent=1) + "\n")
    e = entry
    print(f"{e['frames']} frames of {e['image_width_px']} x {e['image_height_px']} px: aerotri match {e['wall_s']} s wall, "
          f"{e['cpu_s']} s CPU ({e['cpu_s_per_frame']} CPU-s a frame), peak RSS {e['peak_rss_mb']:.0f} MB (limit "
          f"{LIMIT_PEAK_GB:.0f} GB: {'within' if e['within_limit'] else 'NOT within'}); {e['pairs']} pairs, {e['tracks']} "
          f"tracks, {e['observations']} observations; against truth: median residual "
          f"{e['tie_points_vs_truth']['median_residual_px']} px, {100 * e['tie_points_vs_truth']['off_fraction']:.1f} % "
          f"off by more than 1 px; load {e['load_avg_before']} -> {e['load_avg_after']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
