"""Control transfer on the simulator ``demo`` preset -> bench/results/control.json.

Chain (no truth used for control): copy of a simulated demo project with matched tie points
(/tmp/simdemo, or simulated + matched here) -> adjust with tie points + GNSS only -> lidarctl corners on
the simulated LiDAR with the truth classes (truth/lidar/*.las; lidarctl has no classify command yet)
-> aerotri control -> adjust with the transferred control (GNSS shift per strip, self-calibration
pp + radial). Evaluated against the truth:
- image measurements of the selected corners (and of all accepted ones) vs the projection of the true
  roof corner with the true orientation and true camera (px);
- counts: corners, measurements, rejection reasons, how many rejected / accepted measurements were
  really wrong (> 1 px from the truth projection);
- check-point RMS of the final adjustment on the simulator's 30 independent check targets (in GSD), and
  on the LiDAR corners kept as check points; for comparison the same targets after the adjustment with
  tie points + GNSS only.

Usage: .venv/bin/python bench/eval_control.py [--demo /tmp/simdemo] [--work /tmp/eval_control]
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.adjust import pipeline as adjust_pipeline  # noqa: E402
from aerotri.geom.observations import ControlPoints  # noqa: E402
from aerotri.geom.camera import BrownCamera  # noqa: E402
from aerotri.geom.eo import read_eo  # noqa: E402
from aerotri.sim.evaluate import truth_roof_corners  # noqa: E402
from aerotri.core.atomic import write_text_atomic  # noqa: E402

VENV = REPO / ".venv" / "bin"


def adjust_without_control(root: Path) -> dict:
    """First adjustment (tie points + GNSS). ``aerotri adjust`` insists on control points today, so the
    library is called with an empty control set (header-only control files)."""
    ctrl = root / "control"
    ctrl.mkdir(exist_ok=True)
    (ctrl / "points.csv").write_text("id,kind,x,y,z,sx_m,sy_m,sz_m\n")
    (ctrl / "image_points.csv").write_text("point_id,image_id,x_px,y_px\n")
    orig = adjust_pipeline.read_control_points

    def read_or_empty(path, *args, **kwargs):
        lines = [ln for ln in Path(path).read_text().splitlines()[1:] if ln.strip()]
        if not lines:
            e = np.zeros((0, 3))
            return ControlPoints(np.array([], dtype=object), np.array([], dtype=object), e, e.copy())
        return orig(path, *args, **kwargs)

    adjust_pipeline.read_control_points = read_or_empty
    try:
        ba = adjust_pipeline.adjust_project(root, adjust_pipeline.AdjustSettings(gnss_correction="none",
                                                                                 self_calibration=("pp", "radial")))
        return adjust_pipeline.write_outputs(ba, root, html=False)
    finally:
        adjust_pipeline.read_control_points = orig


def _truth_frames(root: Path, eo):
    """The true orientations over the earth, as the simulator rendered the frames (issue 42)."""
    from aerotri.core.project import Project
    from aerotri.geom.local_frame import FramesOnEarth

    return FramesOnEarth(Project.open(root).crs, eo.centre_m, eo.rotations())


def truth_projection_errors(root: Path, image_points: Path, points: Path) -> dict:
    """Measured - true image position of every transferred corner observation (px), by kind."""
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    eo = read_eo(root / "truth" / "eo.txt")
    frames = _truth_frames(root, eo)
    t = truth_roof_corners(root)
    kind = {r["id"]: r["kind"] for r in csv.DictReader(open(points))}
    xyz = {r["id"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])]) for r in csv.DictReader(open(points))}
    ix = dict(zip(eo.image_id, range(len(eo.image_id))))  # image id -> row
    out = {}
    for r in csv.DictReader(open(image_points)):
        p = xyz[r["point_id"]]
        d = np.hypot(*(t.xyz_m[:, :2] - p[:2]).T)
        k = int(np.argmin(d))
        if d[k] > 1.5:
            continue  # a LiDAR corner without a true roof corner nearby (not counted)
        i = ix[r["image_id"]]
        x, y, _ = frames.project(cam, i, t.xyz_m[k][None])
        e = np.array([float(r["x_px"]) - x[0], float(r["y_px"]) - y[0]])
        out.setdefault(kind[r["point_id"]], []).append(e)
    return {k: np.array(v) for k, v in out.items()}


def rejected_vs_truth(root: Path, transfer: dict, corners_csv: Path) -> dict:
    """Of the measurements rejected in the image / dropped as inconsistent: how many were really wrong."""
    cam = BrownCamera.read(root / "truth" / "camera.toml")
    eo = read_eo(root / "truth" / "eo.txt")
    frames = _truth_frames(root, eo)
    ix = dict(zip(eo.image_id, range(len(eo.image_id))))  # image id -> row
    t = truth_roof_corners(root)
    lid = {r["id"]: np.array([float(r["x"]), float(r["y"])]) for r in csv.DictReader(open(corners_csv))}
    stats = {}
    for c in transfer["corners"]:
        d = np.hypot(*(t.xyz_m[:, :2] - lid[c["id"]]).T)
        k = int(np.argmin(d))
        for iid, f in c["frames"].items():
            st = f["status"]
            rec = stats.setdefault(st, {"n": 0, "wrong_gt_1px": 0, "right_le_1px": 0, "no_position": 0, "no_truth": 0})
            rec["n"] += 1
            if f["x_px"] is None:
                rec["no_position"] += 1
                continue
            if d[k] > 1.5:
                rec["no_truth"] += 1
                continue
            i = ix[iid]
            x, y, _ = frames.project(cam, i, t.xyz_m[k][None])
            err = float(np.hypot(f["x_px"] - x[0], f["y_px"] - y[0]))
            rec["wrong_gt_1px" if err > 1.0 else "right_le_1px"] += 1
    return stats


def check_rms(ba, ids, gsd_m) -> dict:
    d = np.array([np.subtract(ba.check[p]["adjusted_m"], ba.check[p]["measured_m"]) for p in ids
                  if p in ba.check and np.all(np.isfinite(ba.check[p]["adjusted_m"]))])
    if len(d) == 0:
        return {"check_points": 0}
    rxy = float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))
    rz = float(np.sqrt(np.mean(d[:, 2] ** 2)))
    return {"check_points": int(len(d)), "rms_check_x_m": float(np.sqrt(np.mean(d[:, 0] ** 2))),
            "rms_check_y_m": float(np.sqrt(np.mean(d[:, 1] ** 2))), "rms_check_xy_m": rxy, "rms_check_z_m": rz,
            "rms_check_xy_gsd": rxy / gsd_m, "rms_check_z_gsd": rz / gsd_m}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo", default="/tmp/simdemo", help="simulated demo project with at/tiepoints.csv (read only)")
    ap.add_argument("--work", default="/tmp/eval_control")
    ap.add_argument("--out", default=str(REPO / "bench" / "results" / "control.json"))
    a = ap.parse_args(argv)
    demo, work = Path(a.demo), Path(a.work)
    if work.exists():
        shutil.rmtree(work)
    if not (demo / "at" / "tiepoints.csv").is_file():
        subprocess.run([VENV / "aerotri", "sim", "--preset", "demo", str(work)], check=True)
        subprocess.run([VENV / "aerotri", "match", str(work)], check=True)
    else:
        shutil.copytree(demo, work, ignore=shutil.ignore_patterns("control", "lidar_out"))
    truth = json.loads((work / "truth" / "truth.json").read_text())
    gsd = float(truth["gsd_m"])
    timings = {}

    t0 = time.perf_counter()
    adjust_without_control(work)
    timings["adjust_tie_gnss_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    las = sorted((work / "truth" / "lidar").glob("*.las"))
    subprocess.run([VENV / "lidarctl", "corners", *map(str, las), str(work / "lidar_out"), "--no-figure"], check=True,
                   stderr=subprocess.DEVNULL)
    timings["lidarctl_corners_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    subprocess.run([VENV / "aerotri", "control", str(work)], check=True, stderr=subprocess.DEVNULL)
    timings["control_s"] = time.perf_counter() - t0
    transfer = json.loads((work / "control" / "transfer.json").read_text())
    sm = transfer["summary"]

    errs = truth_projection_errors(work, work / "control" / "image_points.csv", work / "control" / "points.csv")
    sel = np.vstack([errs[k] for k in ("full", "height") if k in errs])
    allacc = np.vstack(list(errs.values()))

    def rms(e):
        return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))

    rej = rejected_vs_truth(work, transfer, work / "lidar_out" / "corners.csv")
    sel_rays = [c["rays"] for c in transfer["corners"] if c["kind"] in ("full", "height")]
    # usable corners the prediction puts into 2+ frames: how many were accepted (measured in 2+ frames)
    in2 = [c for c in transfer["corners"] if sum(f["status"] != "outside_frame" for f in c["frames"].values()) >= 2]
    in2_acc = [c for c in in2 if c["kind"] in ("full", "height", "check")]

    # final adjustment A: as written by aerotri control (LiDAR corners not selected are check points)
    t0 = time.perf_counter()
    settings = adjust_pipeline.AdjustSettings(gnss_correction="shift", self_calibration=("pp", "radial"))
    ba_a = adjust_pipeline.adjust_project(work, settings)
    lidar_checks = [c["id"] for c in transfer["corners"] if c["kind"] == "check"]
    res_lidar = check_rms(ba_a, lidar_checks, gsd)
    # final adjustment B (reported, ISAT report in at/): control only from the transfer, check points = the
    # simulator's independent targets with their true image positions
    ctrl = [ln for ln in (work / "control" / "points.csv").read_text().splitlines()[1:] if ",check," not in ln]
    ctrl_ids = {ln.split(",")[0] for ln in ctrl}
    obs = [ln for ln in (work / "control" / "image_points.csv").read_text().splitlines()[1:] if ln.split(",")[0] in ctrl_ids]
    tgt = list(csv.DictReader(open(work / "truth" / "checkpoints.csv")))
    tobs = (work / "truth" / "checkpoint_image_points.csv").read_text().splitlines()[1:]
    measured = {ln.split(",")[0] for ln in tobs}
    pts = ["id,kind,x,y,z,sx_m,sy_m,sz_m"] + ctrl + [
        f"{r['id']},check,{r['x']},{r['y']},{r['z']},0.01,0.01,0.01" for r in tgt if r["id"] in measured]
    final = work / "final"
    shutil.copytree(work, final, ignore=shutil.ignore_patterns("final", "images", "lidar", "truth", "work", "lidar_out"))
    (final / "images").symlink_to(work / "images")
    write_text_atomic(final / "control" / "points.csv", "\n".join(pts) + "\n")
    write_text_atomic(final / "control" / "image_points.csv", "\n".join(["point_id,image_id,x_px,y_px"] + obs + tobs) + "\n")
    ba_b = adjust_pipeline.adjust_project(final, settings)
    rep = json.loads(adjust_pipeline.write_outputs(ba_b, final, html=True).report_path.read_text())
    timings["adjust_with_control_s"] = time.perf_counter() - t0
    res_targets = check_rms(ba_b, [r["id"] for r in tgt], gsd)
    # baseline: the same check targets after the adjustment with tie points + GNSS only (no control)
    base_dir = work / "baseline"
    shutil.copytree(final, base_dir, ignore=shutil.ignore_patterns("images"), symlinks=True)
    write_text_atomic(base_dir / "control" / "points.csv", "\n".join(["id,kind,x,y,z,sx_m,sy_m,sz_m"] + pts[1 + len(ctrl):]) + "\n")
    write_text_atomic(base_dir / "control" / "image_points.csv", "\n".join(["point_id,image_id,x_px,y_px"] + tobs) + "\n")
    ba_0 = adjust_pipeline.adjust_project(base_dir, adjust_pipeline.AdjustSettings(gnss_correction="none",
                                                                                    self_calibration=("pp", "radial")))
    res_baseline = check_rms(ba_0, [r["id"] for r in tgt], gsd)

    out = {
        "preset": "demo",
        "gsd_m": gsd,
        "classified_input": "truth classes (truth/lidar/*.las); lidarctl has no classify command yet",
        "corners_in_file": sm["corners_in_file"],
        "corners_usable_measured": sm["corners_measured"],
        "corners_accepted": sm["corners_accepted"],
        "control_full": sm["control_full"],
        "control_height": sm["control_height"],
        "check_points_lidar": sm["check_points"],
        "layout_targets": sm["layout_targets"],
        "layout_targets_unfilled": sm["layout_targets_unfilled"],
        "selected_corners": len(sel_rays),
        "selected_measured_in_2plus_frames_pct": 100.0 * float(np.mean(np.array(sel_rays) >= 2)) if sel_rays else 0.0,
        "selected_rays_mean": float(np.mean(sel_rays)) if sel_rays else 0.0,
        "usable_corners_predicted_in_2plus_frames": len(in2),
        "usable_corners_predicted_in_2plus_frames_accepted_pct": 100.0 * len(in2_acc) / max(len(in2), 1),
        "selected_image_rms_px": rms(sel),
        "selected_image_max_px": float(np.max(np.hypot(*sel.T))),
        "selected_image_observations": int(len(sel)),
        "accepted_image_rms_px": rms(allacc),
        "accepted_image_median_px": float(np.median(np.hypot(*allacc.T))),
        "accepted_image_gt_1px": int(np.sum(np.hypot(*allacc.T) > 1.0)),
        "accepted_image_observations": int(len(allacc)),
        "measurements_attempted": sm["measurements_attempted"],
        "measurements_rejected_in_image": sm["measurements_rejected_in_image"],
        "rays_dropped_inconsistent": sm["rays_dropped_inconsistent"],
        "corners_rejected": sm["corners_rejected"],
        "measurement_status_vs_truth": rej,
        "final_check_targets": res_targets,
        "final_check_lidar_corners": res_lidar,
        "baseline_tie_gnss_only_check_targets": res_baseline,
        "final_sigma0_um": rep["key_statistics"]["sigma0_um"],
        "final_report": str(final / "at" / "report.txt"),
        "targets_met": {
            "selected_image_rms_le_0p5_px": rms(sel) <= 0.5,
            "selected_2plus_frames_ge_90pct": bool(sel_rays) and float(np.mean(np.array(sel_rays) >= 2)) >= 0.9,
            "check_xy_le_1_gsd": res_targets.get("rms_check_xy_gsd", 99) <= 1.0,
            "check_z_le_1p5_gsd": res_targets.get("rms_check_z_gsd", 99) <= 1.5,
        },
        "timings_s": timings,
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out, json.dumps(out, indent=1, default=float) + "\n")
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
