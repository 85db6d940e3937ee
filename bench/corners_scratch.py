"""Scratch disk, peak memory and CPU of the corner stage by tiles (``lidarctl.corners.roof_corners.find_roof_corners_tiled``,
what ``lidarctl corners`` and the chain run), this checkout against an earlier revision (default 087dbcb: float64
records written once per tile holding the point), and their results compared (corners, outlines, roof planes,
figure).

Each run is a fresh subprocess, one at a time, so that its peak RSS (getrusage's ru_maxrss) is its own: the baseline
from ``git archive <rev>`` unpacked into the work folder, ours from this checkout; each is run once on the first
set before anything is measured (numba's caches of the unpacked tree). Scratch: the size of the stage's temporary
folder just before the stage removes it (its files only grow until then); bytes per point are over the binned
(non-noise) points. The figure's nDSM is made as the stage makes it (``FIGURE_CELLS``).

Sets: ``NAME=GLOB[@TILE_M,BUFFER_M][%CRS]`` (default 500 m tiles with a 150 m buffer, the stage's defaults; CRS
for files without one).
Writes bench/results/corners_scratch.json.
Run (issue 41's figures):
  .venv/bin/python bench/corners_scratch.py --work /work/tmp/corners_scratch \\
      --set 'ahn3_tiles=/work/shared/data/ahn3_delft/ahn3_cropped_1.laz@100,60%EPSG:28992' \\
      --set 'ahn3=/work/shared/data/ahn3_delft/ahn3_cropped_1.laz%EPSG:28992' \\
      --set 'demo=DEMO/truth/lidar/strip_*.las' --set 'demo_x4=DEMO_X4/truth/lidar/strip_*.laz'
  (DEMO: ``aerotri sim --preset demo DEMO``; DEMO_X4: the same with ``--set lidar.pulse_rate_hz=280000 --set
  lidar.format='"laz"' --set camera.width=432 --set camera.height=240``, four times the points, small frames; the
  simulator's strips carry its true classes.)
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from lidar_common import baseline_tree  # noqa: E402

CHILD = r"""
import dataclasses, json, resource, shutil, sys, time
from pathlib import Path
import numpy as np
import lidarctl
from lidarctl.corners import roof_corners as C
out, work, tile_m, buffer_m, crs = Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
paths = sys.argv[6:]
scratch = []
real_rmtree = shutil.rmtree
def rmtree(p, *a, **k):
    p = Path(p)
    if p.is_dir() and p.parent == work:
        scratch.append(sum(f.stat().st_size for f in p.rglob("*") if f.is_file()))
    return real_rmtree(p, *a, **k)
shutil.rmtree = rmtree
t0, c0 = time.perf_counter(), time.process_time()
res, crs, units, figure = C.find_roof_corners_tiled(paths, crs=crs or None, tile_m=tile_m, buffer_m=buffer_m,
                                                    work_dir=work, figure_cells=C.FIGURE_CELLS)
seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
assert not list(work.iterdir()), list(work.iterdir())
if isinstance(res, dict):  # the result of a baseline tree before RoofCorners
    planes = json.dumps(C.roof_planes_geojson(C._faces_in_crs_units(res["faces"], units), res["stats"]))
else:
    planes = C.roof_planes_geojson(C._faces_in_crs_units(res.faces, units), None,
                                   sigma_strip_xy_m=res.stats.sigma_strip_xy_m, sigma_strip_z_m=res.stats.sigma_strip_z_m)
    planes = planes if isinstance(planes, str) else json.dumps(planes)  # a tree before the text
    res = {"corners": res.corners, "outlines": res.outlines, "stats": dataclasses.asdict(res.stats)}
outlines = [[np.asarray(r).tolist() for r in o["rings"]] for o in res["outlines"]]
stats = {k: v for k, v in res["stats"].items() if k != "runtime_s"}
np.save(out.with_suffix(".ndsm.npy"), figure[0])
out.write_text(json.dumps({"corners": res["corners"], "csv": C.corners_csv_text(res["corners"]), "planes": planes,
                           "outlines": outlines, "stats": stats, "extent": list(figure[1])}))
print("RESULT " + json.dumps(dict(seconds=seconds, cpu_seconds=cpu, scratch_bytes=max(scratch) if scratch else None,
                                  peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                                  n_points=stats["n_points"], code=lidarctl.__file__)))
"""


def run(src: Path, out: Path, scratch: Path, tile_m: float, buffer_m: float, crs: str, paths) -> dict:
    scratch.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(src))
    load0 = os.getloadavg()[0]
    p = subprocess.run([sys.executable, "-c", CHILD, str(out), str(scratch), str(tile_m), str(buffer_m), crs, *paths],
                       env=env, text=True, cwd=src, capture_output=True)
    if p.returncode:
        raise RuntimeError(f"{src}: exit {p.returncode}: {p.stderr[-3000:]}")
    res = json.loads(next(ln for ln in p.stdout.splitlines() if ln.startswith("RESULT "))[7:])
    assert Path(res["code"]).resolve().is_relative_to(src.resolve()), res["code"]
    res["load_average_1min_before_after"] = [load0, os.getloadavg()[0]]
    res["bytes_per_point"] = res["scratch_bytes"] / res["n_points"]
    return res


def compare(a_path: Path, b_path: Path) -> dict:
    """Baseline (a) against ours (b): corners, their positions and sigmas, outlines, roof planes, figure."""
    a, b = json.loads(a_path.read_text()), json.loads(b_path.read_text())
    ca, cb = a["corners"], b["corners"]
    out = {"corners_baseline_ours": [len(ca), len(cb)],
           "usable_baseline_ours": [sum(c["usable"] for c in ca), sum(c["usable"] for c in cb)],
           "corners_csv_identical": a["csv"] == b["csv"], "roof_planes_identical": a["planes"] == b["planes"],
           "outlines_identical": a["outlines"] == b["outlines"],
           "stats_identical": a["stats"] == b["stats"],
           "review_fields_identical": ca == cb}
    if len(ca) == len(cb) and ca:
        for keys, name in ((("x", "y", "z"), "max_abs_position_difference"),
                           (("sx_m", "sy_m", "sz_m"), "max_abs_sigma_difference_m")):
            out[name] = float(max(abs(p[k] - q[k]) for p, q in zip(ca, cb) for k in keys))
    fa, fb = np.load(a_path.with_suffix(".ndsm.npy")), np.load(b_path.with_suffix(".ndsm.npy"))
    out["figure_identical"] = bool(fa.shape == fb.shape and np.array_equal(fa, fb, equal_nan=True)
                                   and a["extent"] == b["extent"])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline-rev", default="087dbcb")
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--set", dest="sets", action="append", required=True, metavar="NAME=GLOB[@TILE_M,BUFFER_M][%CRS]")
    args = ap.parse_args()
    sets = []
    for spec in args.sets:
        name, rest = spec.split("=", 1)
        rest, _, crs = rest.partition("%")
        pattern, _, tiles = rest.partition("@")
        tile_m, buffer_m = (float(v) for v in tiles.split(",")) if tiles else (500.0, 150.0)
        paths = sorted(glob.glob(pattern))
        if not paths:
            sys.exit(f"--set {spec}: no file matches {pattern}")
        sets.append((name, paths, tile_m, buffer_m, crs))
    base = baseline_tree(args.baseline_rev, args.work)
    scratch = args.work / "scratch"
    trees = (("baseline", base), ("ours", REPO))
    name, paths, tile_m, buffer_m, crs = sets[0]
    for label, src in trees:  # warm-up: numba caches
        run(src, args.work / f"warmup_{label}.json", scratch, tile_m, buffer_m, crs, paths)
    import laspy

    results = {}
    for name, paths, tile_m, buffer_m, crs in sets:
        runs = {}
        for label, src in trees:
            runs[label] = run(src, args.work / f"{name}_{label}.json", scratch, tile_m, buffer_m, crs, paths)
            r = runs[label]
            print(f"{name} {label}: scratch {r['scratch_bytes'] / 1e6:.1f} MB ({r['bytes_per_point']:.1f} B a point), "
                  f"{r['seconds']:.1f} s, CPU {r['cpu_seconds']:.1f} s, peak RSS {r['peak_rss_mb']:.0f} MB", flush=True)
        a, b = runs["baseline"], runs["ours"]
        results[name] = {
            "files": paths, "tile_m": tile_m, "buffer_m": buffer_m, "crs_given": crs or None,
            "points_in_files": int(sum(laspy.open(p).header.point_count for p in paths)),
            "points_binned": b["n_points"],
            "scratch_bytes_baseline_ours": [a["scratch_bytes"], b["scratch_bytes"]],
            "scratch_bytes_per_point_baseline_ours": [round(a["bytes_per_point"], 2), round(b["bytes_per_point"], 2)],
            "scratch_ratio": a["scratch_bytes"] / b["scratch_bytes"],
            "cpu_s_baseline_ours": [a["cpu_seconds"], b["cpu_seconds"]],
            "wall_s_baseline_ours": [a["seconds"], b["seconds"]],
            "peak_rss_mb_baseline_ours": [a["peak_rss_mb"], b["peak_rss_mb"]],
            **compare(args.work / f"{name}_baseline.json", args.work / f"{name}_ours.json"),
            "runs": runs,
        }
        print(json.dumps({k: v for k, v in results[name].items() if k not in ("runs", "files")}), flush=True)
    out = {
        "what": "lidarctl.corners.roof_corners.find_roof_corners_tiled (the corner stage by tiles, with its figure): this checkout "
                "against the baseline revision, each run in its own process; scratch = the stage's temporary folder "
                "at its largest, bytes per binned (non-noise) point",
        "baseline_rev": args.baseline_rev,
        "ours_rev": subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                   text=True).stdout.strip(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine_cores": os.cpu_count(),
        "command": "python bench/corners_scratch.py " + " ".join(sys.argv[1:]),
        "note": "the 2-core machine is shared with other jobs (load averages per run): wall times vary; CPU seconds "
                "and the same-run ratios are the figures to compare",
        "sets": results,
    }
    (REPO / "bench" / "results" / "corners_scratch.json").write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
