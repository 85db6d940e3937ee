"""Roof corners on the simulator ``demo`` preset against the true eave corners.

    .venv/bin/python bench/eval_corners_sim.py [--project out/sim_demo] [--out results] [--classified truth|PATH]

Simulates the demo project into --project if it does not exist (``aerotri sim --preset demo``), runs the
corner detector on the truth-classified strips ``truth/lidar/strip_*.las`` (the classifier's output
can be given instead with --classified), matches the reported corners to ``truth/roof_corners.csv``
(nearest true corner within 1 m) and writes bench/results/corners_sim.json and bench/results/corners_sim.png.

Issue 4 targets: usable corners within 0.20 m RMS horizontally and 0.15 m vertically; >= 80 % of the
true corners of flat-roof buildings of at least 10 x 10 m found; <= 2 % of the reported corners match
no true corner; RMS of the normalised errors (error / reported sigma) between 0.7 and 1.5.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from aerotri.core.atomic import write_text_atomic
from lidarctl.corners.roof_corners import find_roof_corners, plot_corners, read_classified_cloud, simple_ndsm, write_corner_files

REPO = Path(__file__).resolve().parents[1]
MATCH_M = 1.0


def read_truth(path: Path) -> dict:
    rows = list(csv.DictReader(open(path)))
    out = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    for k in ("x", "y", "z", "length_m", "width_m", "angle_deg"):
        if k in out:
            out[k] = out[k].astype(float)
    return out


def rms(a) -> float | None:
    a = np.asarray(a, float)
    return float(np.sqrt(np.mean(a**2))) if a.size else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=REPO / "out" / "sim_demo")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--classified", default="truth", help="'truth' (truth/lidar/*.las) or a classified LAS/LAZ file")
    ap.add_argument("--roof", default="flat", choices=["flat", "any"])
    ap.add_argument("--min-edge-m", type=float, default=None,
                    help="the detector's min_edge_m (default: the stage's default, density-adaptive)")
    args = ap.parse_args()

    if not (args.project / "truth" / "roof_corners.csv").exists():
        subprocess.run([str(Path(sys.executable).with_name("aerotri")), "sim", "--preset", "demo", "--force",
                        str(args.project)], check=True)
    files = sorted((args.project / "truth" / "lidar").glob("strip_*.la[sz]")) if args.classified == "truth" \
        else [Path(args.classified)]
    clouds = [read_classified_cloud(p) for p in files]
    cat = {k: np.concatenate([getattr(c, k) for c in clouds]) for k in ("x", "y", "z", "classification", "point_source_id")}
    if len(clouds) > 1 and len(np.unique(cat["point_source_id"])) < len(clouds):
        cat["point_source_id"] = np.concatenate([np.full(len(c.x), i + 1) for i, c in enumerate(clouds)])

    t0 = time.perf_counter()
    res = find_roof_corners(cat["x"], cat["y"], cat["z"], cat["classification"], cat["point_source_id"],
                            min_edge_m=args.min_edge_m, roof=args.roof)
    runtime = time.perf_counter() - t0
    write_corner_files(REPO / "out" / "corners_sim", res, crs=clouds[0].crs, source=", ".join(map(str, files)))

    truth = read_truth(args.project / "truth" / "roof_corners.csv")
    txy = np.column_stack([truth["x"], truth["y"]])
    corners = res.corners
    cxy = np.array([[c["x"], c["y"]] for c in corners]).reshape(-1, 2)
    cz = np.array([c["z"] for c in corners])
    sig = np.array([[c["sx_m"], c["sy_m"], c["sz_m"]] for c in corners]).reshape(-1, 3)
    usable = np.array([c["usable"] for c in corners], bool)
    d, j = cKDTree(txy).query(cxy)
    matched = d <= MATCH_M
    err = np.column_stack([cxy - txy[j], cz - truth["z"][j]])
    norm = err / sig
    u = usable & matched

    big_flat = (truth["roof"] == "flat") & (np.minimum(truth["length_m"], truth["width_m"]) >= 10.0)
    found = np.zeros(len(txy), bool)
    found[j[matched]] = True
    found_usable = np.zeros(len(txy), bool)
    found_usable[j[u]] = True
    per_roof = {}
    for kind in np.unique(truth["roof"]):
        sel = matched & (truth["roof"][j] == kind)
        sel_u = sel & usable
        per_roof[str(kind)] = {
            "n_truth": int(np.sum(truth["roof"] == kind)),
            "n_found": int(np.sum(found & (truth["roof"] == kind))),
            "n_usable": int(sel_u.sum()),
            "rms_xy_m": rms(np.hypot(err[sel, 0], err[sel, 1])),
            "rms_z_m": rms(err[sel, 2]),
            "rms_xy_usable_m": rms(np.hypot(err[sel_u, 0], err[sel_u, 1])),
        }

    truth_info = json.loads((args.project / "truth" / "truth.json").read_text())
    summary = {
        "dataset": f"simulator project {args.project}, classes from {args.classified}",
        "preset": truth_info.get("preset"),
        "seed": truth_info.get("seed"),
        "lidar_mean_spacing_m": truth_info.get("lidar_mean_spacing_m"),
        "roof": args.roof,
        "min_edge_m": res.stats.min_edge_m,
        "min_edge_rule": res.stats.min_edge_rule,
        "match_radius_m": MATCH_M,
        "n_points": res.stats.n_points,
        "point_spacing_m": res.stats.point_spacing_m,
        "n_truth_corners": int(len(txy)),
        "n_truth_corners_flat_10x10": int(big_flat.sum()),
        "n_corners": len(corners),
        "n_usable": int(usable.sum()),
        "n_usable_matched": int(u.sum()),
        "rms_xy_usable_m": rms(np.hypot(err[u, 0], err[u, 1])),
        "rms_x_usable_m": rms(err[u, 0]),
        "rms_y_usable_m": rms(err[u, 1]),
        "rms_z_usable_m": rms(err[u, 2]),
        "mean_dx_usable_m": float(np.mean(err[u, 0])) if u.any() else None,
        "mean_dy_usable_m": float(np.mean(err[u, 1])) if u.any() else None,
        "mean_dz_usable_m": float(np.mean(err[u, 2])) if u.any() else None,
        "max_dxy_usable_m": float(np.max(np.hypot(err[u, 0], err[u, 1]))) if u.any() else None,
        "normalised_rms_xy_usable": rms(norm[u, :2]),
        "normalised_rms_z_usable": rms(norm[u, 2]),
        "normalised_rms_xyz_usable": rms(norm[u]),
        "median_sxy_usable_m": res.stats.median_sxy_usable_m,
        "rms_xy_all_matched_m": rms(np.hypot(err[matched, 0], err[matched, 1])),
        "rms_z_all_matched_m": rms(err[matched, 2]),
        "normalised_rms_xy_all_matched": rms(norm[matched, :2]),
        "completeness_flat_10x10_pct": float(100.0 * found[big_flat].mean()) if big_flat.any() else None,
        "completeness_flat_10x10_usable_pct": float(100.0 * found_usable[big_flat].mean()) if big_flat.any() else None,
        "completeness_all_pct": float(100.0 * found.mean()),
        "unmatched_pct": float(100.0 * np.mean(~matched)) if len(corners) else None,
        "unmatched_usable_pct": float(100.0 * np.mean(~matched[usable])) if usable.any() else None,
        "duplicate_matches": int(len(j[matched]) - len(np.unique(j[matched]))),
        "per_roof_type": per_roof,
        "runtime_s": runtime,
        "points_per_s": res.stats.n_points / runtime,
        "targets": {"rms_xy_usable_m": 0.20, "rms_z_usable_m": 0.15, "completeness_flat_10x10_pct": 80.0,
                    "unmatched_pct": 2.0, "normalised_rms": [0.7, 1.5]},
    }
    summary["pass"] = bool(
        summary["rms_xy_usable_m"] is not None and summary["rms_xy_usable_m"] <= 0.20
        and summary["rms_z_usable_m"] <= 0.15
        and summary["completeness_flat_10x10_pct"] is not None
        and summary["completeness_flat_10x10_pct"] >= 80.0
        and summary["unmatched_pct"] <= 2.0
        and 0.7 <= summary["normalised_rms_xy_usable"] <= 1.5
        and 0.7 <= summary["normalised_rms_z_usable"] <= 1.5
    )
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out / "corners_sim.json", json.dumps(summary, indent=2) + "\n")
    xyz = np.column_stack([cat["x"], cat["y"], cat["z"]])
    ndsm, extent = simple_ndsm(xyz, cat["classification"], cell_m=1.0)
    def fmt(v):
        return "-" if v is None else f"{v:.3f}"

    title = (f"sim {args.project.name}: {len(corners)} corners ({int(usable.sum())} usable), RMS usable "
             f"{fmt(summary['rms_xy_usable_m'])} m xy, {fmt(summary['rms_z_usable_m'])} m z")
    plot_corners(args.out / "corners_sim.png", ndsm, extent, res.outlines, corners, truth_xy=txy,
                 title=title, marker_size=1.5)
    # a 300 m window around the corner-densest spot, to see outlines and corners
    centre = cxy[np.argmax(cKDTree(cxy).query_ball_point(cxy, 150.0, return_length=True))]
    window = (centre[0] - 150, centre[0] + 150, centre[1] - 150, centre[1] + 150)
    plot_corners(args.out / "corners_sim_zoom.png", ndsm, extent, res.outlines, corners, truth_xy=txy,
                 title=title, window=window, marker_size=4.0)
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
