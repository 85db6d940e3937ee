"""``lidarctl check-plan`` scored on the simulator (true roof corners) and a real-data smoke run on AHN3 (issue 24).

    .venv/bin/python bench/eval_plan_check.py [--project DIR] [--out results]

Simulator: the ``demo`` preset's project (``--project``; default out/demo/project of this checkout or ../main's when it
exists, read only, else out/sim_demo simulated here with ``aerotri sim --preset demo``). The LiDAR is the pipeline's
classified strips ``lidar_out/classified/strip_*.laz`` when present, else the truth-classified strips
``truth/lidar/strip_*.las``; the surveyed points are the simulator's true eave corners
``truth/roof_corners.csv`` (id,x,y,z), so the offsets are the LiDAR corners' true errors (plus corners the
detector does not report, counted as not found). Nothing is chosen here (the command's defaults: radius 2 m,
min edge 5 m), so there is no hold-out: the numbers are scores, not fits. Per roof kind (flat / pitched) too.

AHN3 smoke (../shared/data/ahn3_delft; no CRS record: EPSG:28992 given): the surveyed points are the vertices of
the BGT footprints (bgt_pand.sqlite, blocks of >= 10 x 10 m, vertices where the outline turns by >= 10 deg,
inside the crop; as bench/eval_corners_ahn3.py). BGT footprints are WALL lines, the LiDAR's corners EAVE
corners: the offsets include the roof overhang (a few decimetres outward), so they are not the LiDAR's error.

Writes bench/results/plan_check.json, bench/results/plan_check_sim.png, bench/results/plan_check_ahn3.png.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from aerotri.core.atomic import write_text_atomic
from aerotri.core.records import to_record
from lidarctl.checks.plan import PlanCheckSettings, check_plan_files, plan_stats

REPO = Path(__file__).resolve().parents[1]
# ../shared/data beside the checkout (or beside ../main's, from a worktree under ../wt/)
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA") or next(
    (p for p in (REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data") if p.is_dir()),
    REPO.parent / "shared" / "data"))
# the demo project `make demo` leaves in this checkout or in the main checkout beside the worktrees (read only)
DEMOS = [REPO / "out" / "demo" / "project", REPO.parent.parent / "main" / "out" / "demo" / "project"]


def _ahn3_module():
    spec = importlib.util.spec_from_file_location("eval_corners_ahn3", REPO / "bench" / "eval_corners_ahn3.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["eval_corners_ahn3"] = mod
    spec.loader.exec_module(mod)
    return mod


def _record(stats) -> dict:
    """The statistics as check-plan's JSON writes them."""
    return to_record(stats, exclude=stats.left_out_of_json())


def by_kind(result, kinds: dict) -> dict:
    out = {}
    for kind in sorted(set(kinds.values())):
        rows = [p for p in result.points if kinds.get(p.id) == kind]
        f = [p for p in rows if p.found]
        d = np.array([[p.dx_m, p.dy_m] for p in f]).reshape(-1, 2)
        dz = np.array([p.dz_m for p in f]) if result.has_z else None
        out[kind] = _record(plan_stats(d, dz, len(rows), result.overall.tolerance_rms_plan_m))
    return out


def simulator(project: Path, out: Path, params: PlanCheckSettings) -> dict:
    if not (project / "truth" / "roof_corners.csv").exists():
        subprocess.run([str(Path(sys.executable).with_name("aerotri")), "sim", "--preset", "demo", "--force",
                        str(project)], check=True)
    clouds = sorted((project / "lidar_out" / "classified").glob("strip_*.la[sz]"))
    source = "the pipeline's classification (lidar_out/classified)"
    if not clouds:
        clouds, source = sorted((project / "truth" / "lidar").glob("strip_*.la[sz]")), "the true classes (truth/lidar)"
    truth_csv = project / "truth" / "roof_corners.csv"
    import csv

    kinds = {r["id"]: r["roof"] for r in csv.DictReader(open(truth_csv))}
    t0 = time.perf_counter()
    res = check_plan_files(clouds, truth_csv, params, json_path=None, png_path=out / "plan_check_sim.png")
    runtime = time.perf_counter() - t0
    truth_info = json.loads((project / "truth" / "truth.json").read_text())
    return {"dataset": f"simulator preset {truth_info.get('preset')} seed {truth_info.get('seed')} ({project}), "
                       f"classes from {source}; surveyed points = truth/roof_corners.csv (true eave corners)",
            "hold_out": "none needed: no parameter is chosen here (command defaults)",
            "n_lidar_corners": res.n_lidar_corners, "radius_m": res.radius_m, "min_edge_m": res.min_edge_m,
            "overall": _record(res.overall), "by_roof": by_kind(res, kinds), "runtime_s": runtime}


def ahn3(out: Path, params: PlanCheckSettings) -> dict:
    import laspy

    m = _ahn3_module()
    laz = SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = m.read_footprints(SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    vxy, v_short, v_angle, v_big = m.block_vertices(m.footprint_blocks(polys))
    with laspy.open(laz) as f:
        las = f.read()
    xy = np.column_stack([las.x, las.y])
    lo, hi = xy.min(axis=0) + m.EDGE_OF_CROP_M, xy.max(axis=0) - m.EDGE_OF_CROP_M
    keep = np.all((vxy >= lo) & (vxy <= hi), axis=1) & (cKDTree(xy).query(vxy, distance_upper_bound=1.0)[0] <= 1.0)
    keep &= (np.abs(180.0 - v_angle) >= m.MIN_TURN_DEG) & v_big
    with tempfile.TemporaryDirectory() as tmp:
        csv_path = Path(tmp) / "bgt_vertices.csv"
        csv_path.write_text("id,x,y\n" + "".join(f"V{k},{x:.3f},{y:.3f}\n" for k, (x, y) in enumerate(vxy[keep])))
        t0 = time.perf_counter()
        res = check_plan_files([laz], csv_path, params, crs="EPSG:28992", png_path=out / "plan_check_ahn3.png")
        runtime = time.perf_counter() - t0
    long_edges = v_short[keep] >= res.min_edge_m
    f = [p for p, le in zip(res.points, long_edges) if le and p.found]
    d = np.array([[p.dx_m, p.dy_m] for p in f]).reshape(-1, 2)
    return {"dataset": "AHN3 Delft crop (ahn3_cropped_1.laz, EPSG:28992) vs BGT footprint vertices (bgt_pand.sqlite)",
            "note": "BGT footprints are wall lines, LiDAR corners eave corners: offsets include the roof overhang "
                    "(not the LiDAR's error); a smoke run of the command on real data",
            "n_lidar_corners": res.n_lidar_corners, "radius_m": res.radius_m, "overall": _record(res.overall),
            "vertices_with_edges_ge_min_edge": _record(plan_stats(d, None, int(long_edges.sum()),
                                                                  res.overall.tolerance_rms_plan_m)),
            "runtime_s": runtime}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=next((d for d in DEMOS if d.is_dir()), REPO / "out" / "sim_demo"))
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    params = PlanCheckSettings()
    res = {"command": "lidarctl check-plan CLOUD... POINTS_CSV (defaults: radius 2 m, min edge 5 m, 1:10000 flat)",
           "simulator": simulator(args.project, args.out, params)}
    print(json.dumps(res["simulator"]["overall"], indent=1))
    if (SHARED / "ahn3_delft").is_dir():
        res["ahn3"] = ahn3(args.out, params)
        print(json.dumps(res["ahn3"]["overall"], indent=1))
    write_text_atomic(args.out / "plan_check.json", json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
