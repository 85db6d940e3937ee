"""Benchmark: `lidarctl classify STRIPS... OUTDIR` (the strips of a block classified together by tiles,
no merged file) at two block sizes, beside the cloth-simulation filter on the same points.

Simulated blocks of 200 m scene tiles at 10 points/m^2 are cut into strips along x (one strip per
200 m column, LAZ, each with its own offsets, as a scanner delivers them). Measures, in one run (so
that the shared 2-core machine's load affects all alike; load averages recorded):
* points per second (wall and CPU) of the whole command, read strips -> tiles -> classify -> one
  classified LAZ per strip;
* peak memory (summed RSS of the command and its children, polled every 0.1 s) at both block sizes
  with the same tile size: set by the tile, not by the block;
* the CSF ground filter alone (pip cloth-simulation-filter, in-process) on the smaller block's
  points: speed ratio of our whole command over CSF's filter alone, and both filters' ground errors
  against the simulator truth;
* the smaller block once more with the default tile size (what a user runs: one tile here, no
  buffer classified twice), with its own ratios to CSF.
Writes bench/results/lidar_strips_bench.json.
Run: .venv/bin/python bench/lidar_strips.py [--small 6 --large 18 --tile-size-m 200]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_classify import TILE_M, _layout, make_tile, run_classify  # noqa: E402
from lidar_common import REPO, csf_ground  # noqa: E402

from lidarctl import io, synthetic  # noqa: E402
from lidarctl.checks import classes as evaluate


def make_strips(work: Path, tiles: int, density: float):
    """The scene of ``tiles`` 200 m tiles cut into strips of one 200 m column each; (paths, truth in strip order)."""
    block = work / f"block_{tiles}x200m_{density:g}ppm2.laz"
    truth = make_tile(block, tiles, density)
    folder = work / f"strips_{tiles}"
    done = folder / "truth.npy"
    if done.exists():
        return sorted(folder.glob("strip_*.laz")), np.load(done)
    folder.mkdir(parents=True, exist_ok=True)
    cloud = io.read_cloud(block)
    # the points on the block's last edge belong to the last column (no strip of a few points)
    column = np.minimum(np.floor((cloud.x - cloud.x.min()) / TILE_M).astype(int), _layout(tiles) - 1)
    fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns", "classification")
    paths, truths = [], []
    for k in np.unique(column):
        sel = column == k
        part = io.PointCloud(*(getattr(cloud, f)[sel] for f in fields))
        paths.append(folder / f"strip_{k:03d}.laz")
        synthetic.write_las(paths[-1], part, crs="EPSG:32632")
        truths.append(truth[sel])
    np.save(done, np.concatenate(truths))
    return paths, np.concatenate(truths)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--small", type=int, default=6, help="scene tiles of the smaller block (6: ~2.6 M points)")
    ap.add_argument("--large", type=int, default=18, help="scene tiles of the larger block (18: ~7.7 M points)")
    ap.add_argument("--density", type=float, default=10.0)
    ap.add_argument("--tile-size-m", type=float, default=200.0,
                    help="classification tile size (m), both blocks (200: both blocks are whole tiles, so two "
                         "tiles in flight hold as many points in either)")
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "aerotri_lidar_strips_bench"))
    args = ap.parse_args()
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    runs = {}
    for name, tiles in (("small", args.small), ("large", args.large)):
        paths, truth = make_strips(work, tiles, args.density)
        out = work / f"classified_{name}"
        r = run_classify(paths, out, ["--tile-size-m", f"{args.tile_size_m:g}"])
        n = len(truth)
        pred = np.concatenate([np.asarray(laspy.read(out / p.name).classification) for p in paths])
        keep = ~np.isin(truth, (7, 18))
        r.update(strips=len(paths), points=n, points_per_s=n / r["seconds"], points_per_cpu_s=n / r["cpu_seconds"],
                 ground_filter_errors=dataclasses.asdict(evaluate.filter_errors(pred[keep] == 2, truth[keep] == 2)),
                 correct_vs_truth_pct=100.0 * float(np.mean(pred == truth)))
        runs[name] = r
        print(f"{name}: {len(paths)} strips {n:,} points {r['seconds']:.1f} s {r['points_per_s']:,.0f} points/s "
              f"CPU {r['cpu_seconds']:.1f} s ({r['points_per_cpu_s']:,.0f} points/CPU s) peak RSS "
              f"{r['peak_rss_mb']:.0f} MB load {r['load_average_1min_before_after']}", flush=True)
    # The smaller block as a user runs it (no --tile-size-m: the default plans ~4 M points per tile with
    # its buffer, here one tile, so no buffer is classified twice); its classes differ from the 200 m
    # tiles' by the tiling's grid-origin effect (module docstring of lidarctl.tiles).
    paths, truth = make_strips(work, args.small, args.density)
    r = run_classify(paths, work / "classified_small_default", [])
    pred = np.concatenate([np.asarray(laspy.read(work / "classified_small_default" / p.name).classification)
                           for p in paths])
    keep = ~np.isin(truth, (7, 18))
    r.update(points=len(truth), points_per_s=len(truth) / r["seconds"], points_per_cpu_s=len(truth) / r["cpu_seconds"],
             ground_filter_errors=dataclasses.asdict(evaluate.filter_errors(pred[keep] == 2, truth[keep] == 2)),
             correct_vs_truth_pct=100.0 * float(np.mean(pred == truth)))
    runs["small_default_tiles"] = r
    print(f"small, default tiles: {r['seconds']:.1f} s CPU {r['cpu_seconds']:.1f} s load "
          f"{r['load_average_1min_before_after']}", flush=True)
    # CSF on the smaller block's points (filter only, no reading or writing)
    paths, truth = make_strips(work, args.small, args.density)
    clouds = [io.read_cloud(p) for p in paths]
    xyz = np.column_stack([np.concatenate([getattr(c, a) for c in clouds]) for a in ("x", "y", "z")])
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    g = csf_ground(xyz)
    csf_s, csf_cpu = time.perf_counter() - t0, time.process_time() - c0
    keep = ~np.isin(truth, (7, 18))
    small = runs["small"]
    result = {
        "what": "lidarctl classify STRIPS... OUTDIR (no merged file) at two block sizes, same tile size; CSF filter "
                "alone on the smaller block in the same run",
        "machine_cores": os.cpu_count(), "tile_size_m": args.tile_size_m, "runs": runs,
        "peak_rss_ratio_large_over_small": runs["large"]["peak_rss_mb"] / small["peak_rss_mb"],
        "points_ratio_large_over_small": runs["large"]["points"] / small["points"],
        "csf_seconds": csf_s, "csf_cpu_seconds": csf_cpu, "csf_points_per_s": len(xyz) / csf_s,
        "csf_load_average_1min_before_after": [load0, os.getloadavg()[0]],
        "csf_ground_filter_errors": dataclasses.asdict(evaluate.filter_errors(g[keep], truth[keep] == 2)),
        "speed_ratio_ours_whole_command_over_csf_filter_only_wall": csf_s / small["seconds"],
        "speed_ratio_ours_whole_command_over_csf_filter_only_cpu": csf_cpu / small["cpu_seconds"],
        "speed_ratio_default_tiles_over_csf_filter_only_wall": csf_s / runs["small_default_tiles"]["seconds"],
        "speed_ratio_default_tiles_over_csf_filter_only_cpu": csf_cpu / runs["small_default_tiles"]["cpu_seconds"],
        "note": "the 2-core machine was shared with other developers' jobs (load averages per run): wall times "
                "are inflated, CPU seconds and same-run ratios are the figures to compare",
    }
    print(f"CSF filter alone: {csf_s:.1f} s ({len(xyz) / csf_s:,.0f} points/s), CPU {csf_cpu:.1f} s; ours (whole "
          f"command) {result['speed_ratio_ours_whole_command_over_csf_filter_only_wall']:.2f}x wall, "
          f"{result['speed_ratio_ours_whole_command_over_csf_filter_only_cpu']:.2f}x CPU (default tiles "
          f"{result['speed_ratio_default_tiles_over_csf_filter_only_wall']:.2f}x wall, "
          f"{result['speed_ratio_default_tiles_over_csf_filter_only_cpu']:.2f}x CPU); peak RSS "
          f"{runs['large']['peak_rss_mb']:.0f} / {small['peak_rss_mb']:.0f} MB for "
          f"{result['points_ratio_large_over_small']:.1f}x the points")
    path = REPO / "bench" / "results" / "lidar_strips_bench.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
