"""Benchmark: `lidarctl classify` on simulated tiles of ~10 and ~20 million points, vs cloth-simulation-filter.

Measures (same run, so that the shared 2-core machine's load affects all of them alike):
* points per second of the whole classify command (read LAZ, tile, noise, ground, classes, write
  LAZ), run as a subprocess, and its peak memory: the summed RSS of the command and all its child
  processes (Dask workers), polled every 0.1 s with psutil;
* memory against file size: tiled (default) on ~10 M and ~20 M points, beside the whole cloud in
  one piece (``--tile-size-m`` larger than the file: the direct path, as before tiling);
* speed-up from 1 to 2 workers: ``--workers 1`` vs ``--workers 2`` (local threads) and
  ``--scheduler local:1`` vs ``local:2`` (Dask distributed worker processes);
* tiled vs whole-cloud classes (fraction of points that differ, and both against the truth),
  beside the classifier's own sensitivity to the phase of its grids (``grid_phase_sensitivity``);
  ground type I / II / total error and outlier flags of the tiled output against the simulator truth;
* CSF (pip cloth-simulation-filter, one parameter set) on the same points: speed ratio and errors;
* both filters on the 7 ISPRS samples (error tables beside the published CSF numbers).
Writes bench/results/lidar_classify_bench.json.
Run: .venv/bin/python bench/lidar_classify.py [--tiles 25 --big-tiles 50] [--skip-csf-tile] [--skip-isprs]
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
from lidar_common import CSF_PUBLISHED, REPO, csf_ground, run_peak

from lidarctl import io, synthetic
from lidarctl.checks import classes as evaluate

TILE_M = 200.0


def _layout(tiles: int) -> int:
    """Columns of a full rectangle of ``tiles`` scene tiles (no empty corners: the density is uniform)."""
    cols = int(np.ceil(np.sqrt(tiles)))
    while tiles % cols:
        cols += 1
    return cols


def make_tile(path: Path, tiles: int, density: float):
    """Simulated scene of tiles x (200 m)^2 at ``density`` points/m^2, LAZ + truth classes (.npy)."""
    truth_path = path.with_suffix(".truth.npy")
    if path.exists() and truth_path.exists():
        return np.load(truth_path)
    side = _layout(tiles)
    parts = [synthetic.synthetic_scene(width_m=TILE_M, density_per_m2=density, n_buildings=8, n_trees=150,
                                       n_low_outliers=200, n_high_outliers=50, seed=k,
                                       u0=TILE_M * (k % side), v0=TILE_M * (k // side)) for k in range(tiles)]
    fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns", "classification")
    cloud = io.PointCloud(*[np.concatenate([getattr(p[0], f) for p in parts]) for f in fields])
    truth = np.concatenate([p[1] for p in parts])
    del parts
    path.parent.mkdir(parents=True, exist_ok=True)
    synthetic.write_las(path, cloud, crs="EPSG:32632")
    np.save(truth_path, truth)
    return truth


def run_classify(inp, out: Path, extra: list[str] = ()) -> dict:
    """Wall seconds, peak RSS of the process tree (MB), CPU seconds and the message of one command.
    ``inp``: a file, or a list of strips (``out`` then a folder)."""
    inputs = [str(q) for q in inp] if isinstance(inp, (list, tuple)) else [str(inp)]
    r = run_peak([str(REPO / ".venv" / "bin" / "lidarctl"), "classify", *inputs, str(out), *extra])
    return {"args": list(extra), "seconds": r["seconds"], "peak_rss_mb": r["peak_rss_mib"],
            "max_single_process_rss_mb": r["max_single_process_rss_mib"], "cpu_seconds": r["cpu_seconds"],
            "load_average_1min_before_after": [r["load_average_before"][0], r["load_average_after"][0]],
            "message": r["stdout"].strip()}


def grid_phase_sensitivity(path: Path, window_m: float = 400.0, cut_m: float = 0.75) -> dict:
    """How much classify_points itself changes when its grids shift (a tile's grids start at the
    tile's lowest coordinates): classes of a ``window_m`` square of the cloud, in one piece and
    with a ``cut_m`` strip removed at its west edge, compared more than 60 m from the cut."""
    from lidarctl.classify import pipeline as cl

    c = io.read_cloud(path)
    x0, y0 = c.x.min(), c.y.min()
    win = (c.x < x0 + window_m) & (c.y < y0 + window_m)
    cut = win & (c.x >= x0 + cut_m)

    def run(m):
        return cl.classify_points(c.x[m], c.y[m], c.z[m], c.return_number[m], c.number_of_returns[m],
                                  c.intensity[m])

    a, b = run(win)[cut[win]], run(cut)
    far = c.x[cut] > x0 + 60.0
    return {"points": int(far.sum()), "window_m": window_m, "cut_m": cut_m,
            "differ_pct": 100.0 * float(np.mean(a[far] != b[far]))}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tiles", type=int, default=25, help="number of 200 m tiles (25 at 10/m^2: ~10.6 M points)")
    ap.add_argument("--big-tiles", type=int, default=50, help="the larger file (50: ~21 M points)")
    ap.add_argument("--density", type=float, default=10.0)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "aerotri_lidar_bench"))
    ap.add_argument("--skip-csf-tile", action="store_true")
    ap.add_argument("--skip-isprs", action="store_true")
    args = ap.parse_args()
    work = Path(args.workdir)
    inp = work / f"sim_{args.tiles}x200m_{args.density:g}ppm2.laz"
    big = work / f"sim_{args.big_tiles}x200m_{args.density:g}ppm2.laz"
    t0 = time.perf_counter()
    truth = make_tile(inp, args.tiles, args.density)
    n_big = len(make_tile(big, args.big_tiles, args.density))
    print(f"tiles: {inp} ({len(truth):,} points), {big} ({n_big:,} points), "
          f"prepared in {time.perf_counter() - t0:.0f} s")
    n = len(truth)

    out = work / "classified.laz"
    one_piece = ["--tile-size-m", "1000000"]
    plan = [("tiled_10m", inp, out, []), ("tiled_20m", big, work / "classified_big.laz", []),
            ("whole_10m", inp, work / "classified_whole.laz", one_piece),
            ("whole_20m", big, work / "classified_whole_big.laz", one_piece),
            ("threads_1_worker", inp, work / "c_w1.laz", ["--workers", "1"]),
            ("threads_2_workers", inp, work / "c_w2.laz", ["--workers", "2"]),
            ("dask_local_1", inp, work / "c_l1.laz", ["--scheduler", "local:1"]),
            ("dask_local_2", inp, work / "c_l2.laz", ["--scheduler", "local:2"])]
    runs = {}
    for name, src, dst, extra in plan:
        r = run_classify(src, dst, extra)
        r["points"] = n if src == inp else n_big
        r["points_per_s"] = r["points"] / r["seconds"]
        r["points_per_cpu_s"] = r["points"] / r["cpu_seconds"]
        runs[name] = r
        print(f"{name:18s} {r['points']:>11,} points {r['seconds']:6.1f} s {r['points_per_s']:>9,.0f} points/s "
              f"CPU {r['cpu_seconds']:6.1f} s peak RSS {r['peak_rss_mb']:6.0f} MB load "
              f"{r['load_average_1min_before_after'][0]:.1f}->{r['load_average_1min_before_after'][1]:.1f}")
    # Byte identity with the default run. (Another engineer may be changing the classifier while
    # this runs: pairs run back to back are compared as well.)
    data = {k: (work / f"c_{k}.laz").read_bytes() for k in ("w1", "w2", "l1", "l2")}
    default = out.read_bytes()
    identical = {k: v == default for k, v in data.items()}
    identical["w1_w2"] = data["w1"] == data["w2"]
    identical["l1_l2"] = data["l1"] == data["l2"]
    identical["w2_l2"] = data["w2"] == data["l2"]
    del data
    whole = np.asarray(laspy.read(work / "classified_whole.laz").classification)
    phase = grid_phase_sensitivity(inp)
    print(f"classifier's own grid-phase sensitivity: {phase['differ_pct']:.3f} % of {phase['points']:,} points")
    main_run = runs["tiled_10m"]
    seconds, peak_mb, cpu_s = main_run["seconds"], main_run["peak_rss_mb"], main_run["cpu_seconds"]
    pred = laspy.read(out).classification
    keep = ~np.isin(truth, (7, 18))
    ours = evaluate.filter_errors(pred[keep] == 2, truth[keep] == 2)
    outlier = np.isin(truth, (7, 18))
    flagged = np.isin(pred, (7, 18))
    result = {
        "tile_points": int(n),
        "tile_area_m2": float(args.tiles * TILE_M * TILE_M),
        "machine_cores": os.cpu_count(),
        "classify_seconds": seconds,
        "classify_points_per_s": n / seconds,
        "classify_peak_rss_mb": peak_mb,
        "classify_cpu_seconds": cpu_s,
        "classify_points_per_cpu_s": n / cpu_s,
        "classify_message": main_run["message"],
        "machine_load_average_1min_before_after": main_run["load_average_1min_before_after"],
        "note": "the 2-core machine was shared with other benchmarks (load averages per run); wall times "
                "are inflated by that contention, CPU seconds are not; peak RSS is the summed RSS of the "
                "command and its child processes",
        "target_points_per_s": 300000,
        "target_peak_rss_mb": 3072,
        # The default configuration (local threads, 2 workers) runs twice (tiled_10m and
        # threads_2_workers): the faster run is the one less disturbed by the other load.
        "classify_points_per_s_best_of_2_default_runs": n / min(seconds, runs["threads_2_workers"]["seconds"]),
        "big_tile_points": int(n_big),
        "big_classify_points_per_s": runs["tiled_20m"]["points_per_s"],
        "big_classify_peak_rss_mb": runs["tiled_20m"]["peak_rss_mb"],
        "peak_rss_ratio_20m_over_10m_tiled": runs["tiled_20m"]["peak_rss_mb"] / peak_mb,
        "peak_rss_ratio_20m_over_10m_whole_cloud": runs["whole_20m"]["peak_rss_mb"] / runs["whole_10m"]["peak_rss_mb"],
        "speedup_threads_2_over_1_workers": runs["threads_1_worker"]["seconds"] / runs["threads_2_workers"]["seconds"],
        "speedup_dask_local_2_over_1_workers": runs["dask_local_1"]["seconds"] / runs["dask_local_2"]["seconds"],
        "speed_ratio_tiled_over_whole_cloud_10m": runs["whole_10m"]["seconds"] / seconds,
        "outputs_identical_to_default_run": identical,
        "tiled_vs_whole_cloud_class_differ_pct": 100.0 * float(np.mean(np.asarray(pred) != whole)),
        "tiled_correct_vs_truth_pct": 100.0 * float(np.mean(np.asarray(pred) == truth)),
        "whole_cloud_correct_vs_truth_pct": 100.0 * float(np.mean(whole == truth)),
        "grid_phase_sensitivity": phase,
        "runs": runs,
        "ground_filter_errors": dataclasses.asdict(ours),
        "outliers_flagged_pct": 100.0 * float(np.mean(flagged[outlier])),
        "false_noise_flags_pct": 100.0 * float(np.mean(flagged[~outlier])),
        "confusion": dataclasses.asdict(evaluate.confusion(pred, truth)),
    }
    print(f"lidarctl classify (tiled, default): {n:,} points in {seconds:.1f} s = {n / seconds:,.0f} points/s, "
          f"{cpu_s:.1f} CPU s, peak RSS {peak_mb:,.0f} MB; 20 M: peak {runs['tiled_20m']['peak_rss_mb']:,.0f} MB; "
          f"whole cloud 10 M / 20 M: {runs['whole_10m']['peak_rss_mb']:,.0f} / "
          f"{runs['whole_20m']['peak_rss_mb']:,.0f} MB")
    print(f"speed-up 1 -> 2 workers: threads {result['speedup_threads_2_over_1_workers']:.2f}, "
          f"dask local {result['speedup_dask_local_2_over_1_workers']:.2f}; identical outputs {identical}; "
          f"tiled vs whole cloud differ {result['tiled_vs_whole_cloud_class_differ_pct']:.3f} %")
    print(evaluate.format_filter_table({"ours": ours}))
    path = REPO / "bench" / "results" / "lidar_classify_bench.json"
    old = json.loads(path.read_text()) if path.exists() else {}

    if not args.skip_csf_tile:
        las = laspy.read(inp)
        xyz = np.column_stack([las.x, las.y, las.z])
        t0 = time.perf_counter()
        g = csf_ground(xyz)
        csf_s = time.perf_counter() - t0
        csf = evaluate.filter_errors(g[keep], truth[keep] == 2)
        result.update({"csf_ground_seconds": csf_s, "csf_points_per_s": n / csf_s,
                       "csf_ground_filter_errors": dataclasses.asdict(csf),
                       "speed_ratio_ours_whole_command_vs_csf_filter_only": csf_s / seconds})
        print(f"CSF (filter only, in-process): {csf_s:.1f} s = {n / csf_s:,.0f} points/s; "
              f"lidarctl whole command is {csf_s / seconds:.1f}x faster")
        print(evaluate.format_filter_table({"csf": csf}))

    # Skipped parts keep the numbers of the last run that measured them, marked as such.
    if args.skip_csf_tile:
        result["previous_run_csf"] = {k: old.get(k, old.get("previous_run_csf", {}).get(k)) for k in (
            "csf_ground_seconds", "csf_points_per_s", "csf_ground_filter_errors",
            "speed_ratio_ours_whole_command_vs_csf_filter_only")}
    if args.skip_isprs:
        result["previous_run_isprs"] = {k: old.get(k, old.get("previous_run_isprs", {}).get(k)) for k in (
            "isprs", "isprs_speed_ratio_csf_over_ours")}
        path.write_text(json.dumps(result, indent=2))
        print(f"wrote {path}")
        return
    # ISPRS tables of both filters, one parameter set each (from bench/eval_isprs.py).
    from eval_isprs import run_method, with_noise

    from lidarctl.classify import ground
    isprs = {"lidarctl_default": run_method("lidarctl_default", with_noise(ground.ground_filter)),
             "csf_raw": run_method("csf_raw", lambda c: csf_ground(np.column_stack([c.x, c.y, c.z]))),
             "csf_after_lidarctl_noise": run_method("csf_after_lidarctl_noise", with_noise(
                 lambda x, y, z: csf_ground(np.column_stack([x, y, z]))))}
    for k, r in isprs.items():
        print(f"\nISPRS {k}: mean total {r['mean']['total_error_pct']:.2f} %, {r['seconds']:.1f} s")
        print(evaluate.format_filter_table({s: evaluate.FilterTest(**v) for s, v in r["samples"].items()},
                                           CSF_PUBLISHED))
    result["isprs"] = isprs
    result["isprs_speed_ratio_csf_over_ours"] = isprs["csf_raw"]["seconds"] / isprs["lidarctl_default"]["seconds"]
    path.write_text(json.dumps(result, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
