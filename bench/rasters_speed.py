"""Speed of the rasters of classified strips (`lidarctl rasters`: DEM, DSM, nDSM, CHM, intensity COGs and
the hillshade) on the demo strips: this checkout against the code before the speed-up (a revision of
main), in one session, and every raster of the two compared.

Each run is a fresh subprocess (one at a time, so that its peak RSS, resource.getrusage's ru_maxrss,
is its own) calling ``lidarctl.rasters.products.write_rasters`` on the strips (what the chain's rasters stage
and the command call; the command adds its imports, about 1.4 CPU-s here): the baseline from
``git archive <rev>`` unpacked into the work folder, ours from this checkout. Before the timed runs
both trees run once on 20 000 points spread over a strip (several tiles), so that numba's compilation
(cached on disk) is not timed. Timed runs alternate baseline, ours, baseline, ours ... (``--repeat``); the figures are the
best of each (the 2-core machine is shared: the load average is recorded beside every run).
Throughput = points of the strips / wall seconds of the call.

Comparison of the last outputs, per raster: cells that differ (nodata in one only counted), largest
absolute difference; the cells of every overview level that differ; the compression and file sizes; the
hillshade PNG's pixels that differ; whether the files are the same bytes (sha256).
``--cold``: before the timed runs, one run of each tree with an empty numba cache (``NUMBA_CACHE_DIR``),
as the first run after a fresh clone: its CPU seconds include numba's compilation.
Writes bench/results/rasters_speed.json; with ``--key NAME`` only that key of it (the others kept).
Records user and system CPU seconds and minor page faults of every run; ``--env-ours``/``--env-baseline``
set environment variables of one side's runs (e.g. NUMPY_MADVISE_HUGEPAGE=0, numpy's huge-page advice off);
``--sample-threads`` adds one run of each tree whose runnable threads are sampled (where the stage leaves a
core idle).
Run: .venv/bin/python bench/rasters_speed.py [--project /work/ref/demo_chain/project] [--baseline-rev a17e529]
     [--repeat 2] [--work /tmp/rasters_speed] [--cold] [--key NAME] [--env-ours NAME=VALUE] [--sample-threads]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from lidar_common import baseline_tree  # noqa: E402
RES_M = 0.5      # the demo's [rasters] res_m

CHILD = r"""
import functools, json, os, resource, sys, threading, time
from pathlib import Path
t0, c0 = time.perf_counter(), time.process_time()
from lidarctl.rasters import products as rasters
out, paths = Path(sys.argv[1]), [Path(p) for p in sys.argv[2:]]
samples, marks = [], []
if os.environ.get("RASTERS_SPEED_SAMPLE"):
    # every 10 ms: how many of this process's threads are runnable (state R: running or waiting for a core)
    def sample():
        me = str(threading.get_native_id())
        while True:
            n = 0
            for t in os.listdir("/proc/self/task"):
                try:
                    n += t != me and open(f"/proc/self/task/{t}/stat").read().rsplit(")", 1)[1].split()[0] == "R"
                except OSError:
                    pass
            samples.append((time.perf_counter(), n))
            time.sleep(0.01)
    threading.Thread(target=sample, daemon=True).start()
    for name in %r:                 # the passes (the same names in the baseline's code)
        def timed(f, name=name):
            @functools.wraps(f)
            def g(*a, **k):
                r, t = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
                try:
                    return f(*a, **k)
                finally:
                    r2 = resource.getrusage(resource.RUSAGE_SELF)
                    marks.append((name, t, time.perf_counter(), r2.ru_utime + r2.ru_stime - r.ru_utime - r.ru_stime))
            return g
        if hasattr(rasters, name):
            setattr(rasters, name, timed(getattr(rasters, name)))
t1, c1, r1 = time.perf_counter(), time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
rasters.write_rasters(paths, out, %r)
t2, c2, r2 = time.perf_counter(), time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
res = dict(seconds=t2 - t1, cpu_seconds=c2 - c1, user_seconds=r2.ru_utime - r1.ru_utime,
           system_seconds=r2.ru_stime - r1.ru_stime, minor_page_faults=r2.ru_minflt - r1.ru_minflt,
           import_seconds=t1 - t0, import_cpu_seconds=c1 - c0, peak_rss_mb=r2.ru_maxrss / 1024.0,
           code=rasters.__file__)
def runnable(a, b):
    ns = [min(n, 2) for t, n in samples if a <= t < b]
    return [sum(n == k for n in ns) / max(len(ns), 1) for k in (0, 1, 2)]
if samples:
    res["runnable_threads_share_0_1_2plus"] = runnable(t1, t2)
    res["passes"] = [dict(name=n, seconds=b - a, cpu_seconds=c, runnable_threads_share_0_1_2plus=runnable(a, b))
                     for n, a, b, c in marks]
print("RESULT " + json.dumps(res))
""" % (("_bin_points", "_tiles_to_gtiffs", "_run_threads"), RES_M)


def run(src: Path, out: Path, paths, numba_cache: Path | None = None, extra_env: dict | None = None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(src), **(extra_env or {}))
    if numba_cache is not None:       # empty: the run compiles every numba function it calls
        shutil.rmtree(numba_cache, ignore_errors=True)
        env["NUMBA_CACHE_DIR"] = str(numba_cache)
    load0 = os.getloadavg()[0]
    p = subprocess.run([sys.executable, "-c", CHILD, str(out), *map(str, paths)], env=env, text=True, cwd=src,
                       capture_output=True)
    if p.returncode:
        raise RuntimeError(f"{src}: rasters failed:\n{p.stderr[-3000:]}")
    res = json.loads(next(ln for ln in p.stdout.splitlines() if ln.startswith("RESULT "))[7:])
    res["load_average_1min_before_after"] = [load0, os.getloadavg()[0]]
    assert Path(res["code"]).resolve().is_relative_to(src.resolve()), res["code"]
    return res


def small_strip(path: Path, out: Path, n: int = 20_000) -> Path:
    """n points spread over a strip (the warm-up run's input): its extent spans several tiles, so that the
    warm-up also compiles what only tiles with neighbours run (the TIN fill's certification)."""
    import laspy

    if not out.exists():
        las = laspy.read(path)
        las.points = las.points[np.arange(0, len(las.points), max(len(las.points) // n, 1))]
        las.write(out)
    return out


def compare(a: Path, b: Path) -> dict:
    """Per raster of two output folders: cells that differ, nodata mismatches, largest difference."""
    import matplotlib.image as mpimg
    import rasterio

    out = {}
    # dsm_nearest.tif: written since the nearest-return surface (a baseline before it has none)
    names = ("dem", "dsm", "ndsm", "chm", "intensity") + (("dsm_nearest",) if all(
        (d / "dsm_nearest.tif").exists() for d in (a, b)) else ())
    for name in names:
        with rasterio.open(a / f"{name}.tif") as fa, rasterio.open(b / f"{name}.tif") as fb:
            assert fa.shape == fb.shape and fa.transform == fb.transform and fa.crs == fb.crs, name
            x, y = fa.read(1, masked=True), fb.read(1, masked=True)
            ma, mb = np.ma.getmaskarray(x), np.ma.getmaskarray(y)
            both = ~ma & ~mb
            d = np.abs(x.data.astype(float) - y.data.astype(float))[both]
            out[name] = dict(cells=int(x.size), differing_cells=int((d > 0).sum() + (ma != mb).sum()),
                             nodata_mismatches=int((ma != mb).sum()), max_abs_difference=float(d.max(initial=0.0)),
                             same_tags=fa.tags() == fb.tags(), same_units=fa.units == fb.units,
                             same_overview_levels=fa.overviews(1) == fb.overviews(1), overview_factors=fa.overviews(1),
                             compression=[str(fa.compression), str(fb.compression)],
                             file_bytes=[(a / f"{name}.tif").stat().st_size, (b / f"{name}.tif").stat().st_size])
        # the overviews' values too (what a viewer shows zoomed out), level by level, nodata included
        levels = range(len(out[name]["overview_factors"]))
        out[name]["overview_cells_differing"] = [overview_cells_differing(a / f"{name}.tif", b / f"{name}.tif", k)
                                                 for k in levels]
    ha, hb = mpimg.imread(a / "hillshade.png"), mpimg.imread(b / "hillshade.png")
    out["hillshade"] = dict(pixels=int(ha.shape[0] * ha.shape[1]),
                            differing_pixels=int((ha != hb).any(axis=-1).sum()))
    for name in names:
        out[name]["same_bytes"] = sha256(a / f"{name}.tif") == sha256(b / f"{name}.tif")
    out["hillshade"]["same_bytes"] = sha256(a / "hillshade.png") == sha256(b / "hillshade.png")
    return out


def overview_cells_differing(a: Path, b: Path, level: int) -> int:
    """Cells of overview ``level`` (0: the first) whose stored values differ (NaN-safe, bit patterns)."""
    import rasterio

    with rasterio.open(a, overview_level=level) as fa, rasterio.open(b, overview_level=level) as fb:
        x, y = fa.read(1), fb.read(1)
    return int((x.view(np.uint32) != y.view(np.uint32)).sum()) if x.shape == y.shape else -1


def sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, default=Path("/work/ref/demo_chain/project"),
                    help="a demo project (aerotri demo): its lidar_out/classified/*.laz")
    ap.add_argument("--baseline-rev", default="a17e529", help="main before the speed-up (issue 41)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--work", type=Path, default=Path("/tmp/rasters_speed"))
    ap.add_argument("--cold", action="store_true", help="also one run of each tree with an empty numba cache")
    ap.add_argument("--key", help="write the results under this key of rasters_speed.json, keeping the others")
    ap.add_argument("--env-baseline", action="append", default=[], metavar="NAME=VALUE",
                    help="an environment variable of the baseline's runs (repeatable), e.g. NUMPY_MADVISE_HUGEPAGE=0")
    ap.add_argument("--env-ours", action="append", default=[], metavar="NAME=VALUE",
                    help="an environment variable of this checkout's runs (repeatable)")
    ap.add_argument("--sample-threads", action="store_true",
                    help="after the timed runs, one more run of each tree sampling its runnable threads every 10 ms "
                         "(the passes' share of time with 0, 1, 2+ threads runnable; its CPU includes the sampler's)")
    args = ap.parse_args()
    envs = {"baseline": dict(e.split("=", 1) for e in args.env_baseline),
            "ours": dict(e.split("=", 1) for e in args.env_ours)}
    import laspy

    paths = sorted((args.project / "lidar_out" / "classified").glob("*.laz"))
    if not paths:
        sys.exit(f"{args.project}: no lidar_out/classified/*.laz (a project made by aerotri demo)")
    n = sum(laspy.open(p).header.point_count for p in paths)
    args.work.mkdir(parents=True, exist_ok=True)
    base = baseline_tree(args.baseline_rev, args.work)
    trees = {"baseline": base, "ours": REPO}
    cold = {}
    if args.cold:
        for name, src in trees.items():
            r = run(src, args.work / f"out_{name}", paths, numba_cache=args.work / f"numba_cache_{name}",
                    extra_env=envs[name])
            r["points_per_s"] = n / r["seconds"]
            r["points_per_cpu_s"] = n / r["cpu_seconds"]
            cold[name] = r
            print(f"{name}, empty numba cache: {r['seconds']:.1f} s, CPU {r['cpu_seconds']:.1f} s, "
                  f"load {r['load_average_1min_before_after']}", flush=True)
    warm = small_strip(paths[0], args.work / "warm_up_spread.laz")
    for name, src in trees.items():
        run(src, args.work / f"warm_{name}", [warm], extra_env=envs[name])
    runs = {name: [] for name in trees}
    for _ in range(args.repeat):
        for name, src in trees.items():
            r = run(src, args.work / f"out_{name}", paths, extra_env=envs[name])
            r["points_per_s"] = n / r["seconds"]
            r["points_per_cpu_s"] = n / r["cpu_seconds"]
            runs[name].append(r)
            print(f"{name}: {r['seconds']:.1f} s ({r['points_per_s']:,.0f} points/s), CPU {r['cpu_seconds']:.1f} s "
                  f"(user {r['user_seconds']:.2f}, sys {r['system_seconds']:.2f}, {r['minor_page_faults']:,} faults), "
                  f"peak RSS {r['peak_rss_mb']:.0f} MB, load {r['load_average_1min_before_after']}", flush=True)
    sampled = {}
    if args.sample_threads:
        for name, src in trees.items():
            r = run(src, args.work / f"sampled_{name}", paths, extra_env=dict(envs[name], RASTERS_SPEED_SAMPLE="1"))
            sampled[name] = r
            print(f"{name}, sampled: {r['seconds']:.1f} s, CPU {r['cpu_seconds']:.1f} s, runnable 0/1/2+ "
                  f"{[round(x, 2) for x in r['runnable_threads_share_0_1_2plus']]}, passes "
                  f"{[(p['name'], round(p['cpu_seconds'], 2), [round(x, 2) for x in p['runnable_threads_share_0_1_2plus']]) for p in r['passes']]}",
                  flush=True)
    best = {k: min(v, key=lambda r: r["seconds"]) for k, v in runs.items()}
    best_cpu = {k: min(r["cpu_seconds"] for r in v) for k, v in runs.items()}
    b, o = best["baseline"], best["ours"]
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    out = {
        "what": "write_rasters (lidarctl rasters) of the demo's classified strips at 0.5 m: this checkout against "
                "the baseline revision, each run in its own process; best of the runs",
        "command": " ".join(["python", "bench/rasters_speed.py", *sys.argv[1:]]),
        "project": str(args.project), "baseline_rev": args.baseline_rev, "ours_rev": head, "points": int(n),
        "strips": len(paths),
        "res_m": RES_M, "machine_cores": os.cpu_count(),
        "points_per_s_baseline_ours": [b["points_per_s"], o["points_per_s"]],
        "speed_ratio_wall": b["seconds"] / o["seconds"],
        "cpu_seconds_baseline_ours": [best_cpu["baseline"], best_cpu["ours"]],
        "speed_ratio_cpu": best_cpu["baseline"] / best_cpu["ours"],
        "points_per_cpu_s_baseline_ours": [n / best_cpu["baseline"], n / best_cpu["ours"]],
        "peak_rss_mb_baseline_ours": [b["peak_rss_mb"], o["peak_rss_mb"]],
        "user_system_seconds_of_best_cpu_run_baseline_ours": [
            [min(v, key=lambda r: r["cpu_seconds"])[k] for k in ("user_seconds", "system_seconds")]
            for v in (runs["baseline"], runs["ours"])],
        "environment_baseline_ours": [envs["baseline"], envs["ours"]],
        "load_average_1min_range": [min(x for v in runs.values() for r in v for x in r["load_average_1min_before_after"]),
                                    max(x for v in runs.values() for r in v for x in r["load_average_1min_before_after"])],
        "comparison_baseline_vs_ours": compare(args.work / "out_baseline", args.work / "out_ours"),
        "note": "the 2-core machine is shared with other jobs (load average per run): wall times vary with it; CPU "
                "seconds and the same-session ratios are the figures to compare. The differing DEM cells: the "
                "baseline's Qhull triangulation is not Delaunay in a few near-cocircular quadrilaterals (its "
                "precision merging); ours is exact (docs/lidar-rasters-speed.md)",
        "runs": runs,
    }
    if cold:
        out["empty_numba_cache"] = {
            "what": "one run of each tree with an empty numba cache (a fresh clone's first run), before the others",
            "cpu_seconds_baseline_ours": [cold["baseline"]["cpu_seconds"], cold["ours"]["cpu_seconds"]],
            "seconds_baseline_ours": [cold["baseline"]["seconds"], cold["ours"]["seconds"]],
            "runs": cold}
    if sampled:
        share = {k: r["runnable_threads_share_0_1_2plus"] for k, r in sampled.items()}
        busy = {k: (v[1] + 2 * v[2]) / max(1e-9, v[1] + v[2]) for k, v in share.items()}
        out["runnable_threads"] = {
            "what": "one more run of each tree, its threads sampled every 10 ms (/proc/self/task/*/stat state R: "
                    "running or waiting for a core): the share of the stage's wall, and of each pass's, with 0, 1 "
                    "and 2 or more threads runnable. With 1, one of the 2 cores has nothing of the stage to do; "
                    "on a loaded machine a thread waiting for a core counts as runnable. mean_cores_busy: the mean of "
                    "min(runnable, 2) over the samples with one or more; idle_machine_seconds_estimate = the tree's "
                    "best CPU s of the timed runs / mean_cores_busy: the stage's wall if every runnable thread had a "
                    "core (an estimate, not a measurement)",
            "runs": sampled,
            "mean_cores_busy_baseline_ours": [busy[k] for k in ("baseline", "ours")],
            "idle_machine_seconds_estimate_baseline_ours": [best_cpu[k] / busy[k] for k in ("baseline", "ours")],
            "idle_machine_points_per_s_estimate_baseline_ours": [n * busy[k] / best_cpu[k] for k in ("baseline", "ours")]}
    print(json.dumps({k: v for k, v in out.items() if k not in ("runs", "empty_numba_cache")}, indent=1))
    path = REPO / "bench" / "results" / "rasters_speed.json"
    if args.key:
        out = dict(json.loads(path.read_text()), **{args.key: out})
    path.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
