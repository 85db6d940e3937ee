"""The control stage on the earth against the flat collinearity (issue 42) -> bench/results/earth_projections.json.

``aerotri control`` projected the LiDAR corners (UTM easting, northing, height) into the frames as if the map
coordinates were a Cartesian frame, while the first adjustment's orientations mean the ENU frame at each centre: the
predictions 400 ppm too near the nadir at the presets' origin (2.8 px of a full-size DMC frame 700 m from it), and
the multi-ray check's intersection 400 ppm of the flying height too high. Now both go through
``aerotri.geom.local_frame.FramesOnEarth``.

A project that has run the chain up to the final adjustment is copied (its small files; images, lidar_out and truth
linked, read-only), then the chain's ``control`` and ``adjust_final`` stages run on the copy twice in this process
with the same inputs (the first adjustment's orientations and camera): ``flat`` (``FramesOnEarth.cartesian`` in
place of the project CRS: the stage before) and ``earth`` (now). Per variant:
- ``transfer``: control/transfer.json's summary (counts, rejection reasons);
- ``prediction_px``: the predicted image position of every corner measured (from the first adjustment) minus the
  truth image position of the simulator's roof corner at the LiDAR corner (truth/roof_corners.csv within
  ``--match-m``; truth/eo.txt and truth/camera.toml through the earth, as the simulator rendered);
- ``measured_px``: the accepted image measurements minus those truth positions;
- ``rays``: the accepted corners' largest kept residual (px) and their intersection minus the LiDAR corner (m);
- ``adjust_final``: check-point RMS and sigma0 of the final adjustment with that control (each variant's own check
  points: the accepted corners not chosen as control), and ``check_points_common``: the RMS over the check points
  both variants have.

Usage: python bench/eval_control_earth.py --project P --work SCRATCH --key NAME [--truth DIR] [--match-m 0.5]
  demo: --project /work/ref/demo_chain/project --key demo
  full-size: --project /work/bench_blocks/dmc_block_subset_2x2_run --truth /work/bench_blocks/dmc_block_subset_2x2/truth
             --key dmc_2x2
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from bench.results_json import store_result  # noqa: E402

COPIED = ("project.toml", "camera.toml", "gnss.txt", "at", "control", "work/at_first", "reports")
LINKED = ("images", "lidar_out", "lidar", "trajectory")


def prepare(src: Path, dst: Path, truth: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "work").mkdir(parents=True)
    for name in COPIED:
        s = src / name
        if s.is_dir():
            shutil.copytree(s, dst / name)
        elif s.is_file():
            shutil.copy2(s, dst / name)
    for name in LINKED:
        if (src / name).exists():
            os.symlink((src / name).resolve(), dst / name)
    os.symlink(truth.resolve(), dst / "truth")


def _stats(d: np.ndarray) -> dict:
    d = np.asarray(d, float)
    d = d[np.isfinite(d)]
    if not len(d):
        return {"count": 0}
    return {"count": int(len(d)), "median": float(np.median(d)), "rms": float(np.sqrt(np.mean(d ** 2))),
            "p95": float(np.percentile(d, 95)), "max": float(d.max()), "share_over_1px": float(np.mean(d > 1.0))}


def truth_positions(root: Path, crs, match_m: float):
    """{LiDAR corner id: (truth xyz (3,))} for the corners within ``match_m`` of a simulated roof corner, and a
    function giving the truth image position of a map point in a frame (through the earth)."""
    from aerotri.control.corners import read_corners
    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.eo import read_eo
    from aerotri.geom.local_frame import FramesOnEarth
    from scipy.spatial import cKDTree

    with open(root / "truth" / "roof_corners.csv") as f:
        rows = list(csv.DictReader(f))
    T = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    corners = read_corners(root / "lidar_out" / "corners.csv", crs)
    dist, k = cKDTree(T).query(corners.xyz_m)
    truth = {str(c): T[j] for c, d, j in zip(corners.id, dist, k) if d <= match_m}
    eo = read_eo(root / "truth" / "eo.txt", crs)
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    frames = FramesOnEarth(crs, eo.centre_m, eo.rotations())
    row = {iid: i for i, iid in enumerate(eo.image_id)}

    def image_xy(image_id, xyz):
        x, y, _ = frames.project(cam, row[image_id], np.asarray(xyz, float)[None])
        return float(x[0]), float(y[0])

    return truth, image_xy


def run_variant(root: Path, variant: str, truth, image_xy) -> dict:
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain
    from aerotri.control import pipeline as control_pipeline
    from aerotri.core.project import Project
    from aerotri.geom.local_frame import FramesOnEarth

    project = Project.open(root)
    chain = Chain(project, read_options(project))
    captured = {}
    transfer = control_pipeline.transfer_control

    def transfer_capture(*a, **k):
        captured["res"] = transfer(*a, **k)
        return captured["res"]

    def frames_flat(crs, centres, R):  # the stage before: map coordinates as a Cartesian frame
        return FramesOnEarth.cartesian(centres, R)

    with contextlib.ExitStack() as stack:
        stack.callback(setattr, control_pipeline, "transfer_control", transfer)
        control_pipeline.transfer_control = transfer_capture
        if variant == "flat":
            stack.callback(setattr, control_pipeline, "FramesOnEarth", FramesOnEarth)
            control_pipeline.FramesOnEarth = frames_flat
        c0, t0 = time.process_time(), time.perf_counter()
        chain.run_control(root)
        control_cpu, control_wall = time.process_time() - c0, time.perf_counter() - t0
    c0 = time.process_time()
    adj = chain.run_adjust_final(root)
    adjust_cpu = time.process_time() - c0
    report = json.loads((root / "at" / "report.json").read_text())
    check_d = {str(c["id"]): c["d_m"] for c in report.get("check_points", []) if c.get("d_m") is not None}
    res = captured["res"]
    summary = json.loads((root / "control" / "transfer.json").read_text())["summary"]
    pred_err, meas_err, meas_err_control = [], [], []
    kinds = {}
    for k, kind in enumerate(res.kind):
        kinds[str(res.corners.id[k])] = kind
    for (k, i), (px, py) in res.predicted.items():
        cid, iid = str(res.corners.id[k]), res.image_ids[i]
        if cid not in truth:
            continue
        tx, ty = image_xy(iid, truth[cid])
        pred_err.append(np.hypot(px - tx, py - ty))
        m = res.measurements.get((k, i))
        if m is not None and m.ok and k in res.rays and res.rays[k].ok:
            kept = dict(zip(res.rays[k].images, res.rays[k].kept))
            if kept.get(i, False):
                meas_err.append(np.hypot(m.x_px - tx, m.y_px - ty))
                if kinds[cid] in ("full", "height"):
                    meas_err_control.append(meas_err[-1])
    ok = [r for r in res.rays.values() if r.ok]
    worst = np.array([np.max(r.residual_px[r.kept]) for r in ok])
    diff = np.array([r.lidar_diff_m for r in ok]).reshape(-1, 3)
    return {
        "transfer": summary,
        "prediction_px": _stats(pred_err),
        "measured_px": _stats(meas_err),
        "measured_px_control": _stats(meas_err_control),
        "rays": {"accepted": len(ok), "max_kept_residual_px": _stats(worst),
                 "lidar_dz_m": {"mean": float(np.mean(diff[:, 2])), "rms": float(np.sqrt(np.mean(diff[:, 2] ** 2)))},
                 "lidar_dxy_m": {"mean": [float(v) for v in diff[:, :2].mean(axis=0)],
                                 "rms": float(np.sqrt(np.mean(np.sum(diff[:, :2] ** 2, axis=1))))}},
        "adjust_final": {"rms_check_xy_m": adj.rms_check_xy_m, "rms_check_z_m": adj.rms_check_z_m,
                         "sigma0_um": adj.sigma0_um, "control_points": adj.control_points},
        "check_d_m": check_d,
        "cpu_s": {"control": round(control_cpu, 2), "adjust_final": round(adjust_cpu, 2)},
        "wall_s": {"control": round(control_wall, 2)},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, required=True, help="a project the chain ran to adjust_final (read only)")
    ap.add_argument("--work", type=Path, required=True, help="scratch folder (the copy)")
    ap.add_argument("--truth", type=Path, default=None, help="its truth/ folder (default: PROJECT/truth)")
    ap.add_argument("--key", required=True)
    ap.add_argument("--match-m", type=float, default=0.5, help="LiDAR corner -> simulated roof corner distance")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "earth_projections.json")
    args = ap.parse_args()
    from aerotri.core.project import Project

    root = args.work / args.key
    prepare(args.project, root, args.truth or args.project / "truth")
    from aerotri.geom.crs.definition import parse_crs

    crs = parse_crs(Project.open(root).crs, "project crs")
    truth, image_xy = truth_positions(root, crs, args.match_m)
    out = {"project": str(args.project), "truth": str(args.truth or args.project / "truth"), "crs": str(crs),
           "lidar_corners_matched_to_truth": len(truth), "match_m": args.match_m,
           "commit": subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                    text=True).stdout.strip(),
           "command": " ".join(["python", "bench/eval_control_earth.py"] + sys.argv[1:]),
           "load_avg_start": list(os.getloadavg())}
    for variant in ("flat", "earth"):
        out[variant] = run_variant(root, variant, truth, image_xy)
        print(variant, json.dumps({k: out[variant][k] for k in ("prediction_px", "measured_px", "rays",
                                                                 "adjust_final")}), flush=True)
    # the check points both variants have (each variant checks the corners it accepted and did not choose)
    common = sorted(set(out["flat"]["check_d_m"]) & set(out["earth"]["check_d_m"]))
    out["check_points_common"] = {"count": len(common)}
    for variant in ("flat", "earth"):
        check_d = out[variant].pop("check_d_m")
        d = np.array([check_d[p] for p in common], float).reshape(-1, 3)
        out["check_points_common"][variant] = {"rms_xy_m": float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))),
                                               "rms_z_m": float(np.sqrt(np.mean(d[:, 2] ** 2))),
                                               "mean_m": [float(v) for v in d.mean(axis=0)]}
    print("common check points", json.dumps(out["check_points_common"]), flush=True)
    out["load_avg_end"] = list(os.getloadavg())
    store_result(args.out, out, key=args.key, section="control")


if __name__ == "__main__":
    main()
