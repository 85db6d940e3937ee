"""Evaluate the block adjustment on simulated blocks with known truth -> bench/results/adjust.json.

Cases (each: observations straight from the truth geometry, ``aerotri.sim.observations``):

- ``demo``: the simulator ``demo`` preset (generated into a temporary folder unless --demo PATH),
  truth tie observations (600 candidate points per image, >= 3 rays) with 0.3 px noise, truth control
  (8 full control points with the project's survey sigma; the simulator's check targets seen in >= 2
  frames, topped up with random ground points to 30, as check points with 5 mm noise), GNSS shift per strip, self-calibration of principal point and radial
  distortion;
- ``demo_blunders``: the same with 3 % of the tie observations displaced by 5-50 px and one control
  point moved by 3 m;
- ``dmc_geometric`` / ``dmc_geometric_blunders``: a DMC-like geometric block (4 strips x 10 frames,
  GSD 0.1 m) with the same settings.

Reported: sigma0 vs injected noise, check RMS in GSD, normalised check errors, self-calibration
errors in standard deviations, blunder detection rates, run times.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aerotri.adjust.pipeline import AdjustSettings, adjust_project, write_outputs
from aerotri.geom.camera import BrownCamera
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

NOISE_PX = 0.3


def evaluate(root: Path, gsd_m: float, blunders: bool, n_control: int, seed: int) -> dict:
    info = write_truth_observations(
        root, tie_sigma_px=NOISE_PX, n_control=n_control, points_per_image=600, n_check=30, seed=seed,
        blunder_fraction=0.03 if blunders else 0.0, blunder_px_range=(5.0, 50.0), bad_control_shift_m=3.0 if blunders else 0.0,
    )
    t0 = time.perf_counter()
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=NOISE_PX, self_calibration=("pp", "radial")))
    t_adj = time.perf_counter() - t0
    rep = json.loads(write_outputs(ba, root).report_path.read_text())
    r, b = ba.result, ba.block
    cam_true = BrownCamera.read(root / "truth" / "camera.toml")
    sd = np.sqrt(np.diag(r.cal_cov))
    truth_cal = np.array([cam_true.cx_px, cam_true.cy_px, cam_true.k1, cam_true.k2])
    est = r.state.cal[[3, 4, 5, 6]]
    z_cal = (est - truth_cal) / sd[[3, 4, 5, 6]]
    d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values() if np.all(np.isfinite(c["adjusted_m"]))])
    s = np.array([np.hypot(c["sigma_m"], c["given_sigma_m"]) for c in ba.check.values() if np.all(np.isfinite(c["adjusted_m"]))])
    rms_xy = float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1))))
    rms_z = float(np.sqrt(np.mean(d[:, 2] ** 2)))
    out = {
        "images": b.n_images, "tie_observations": info.n_tie_observations, "tie_points": info.n_tie_points,
        "gsd_m": gsd_m, "injected_noise_px": NOISE_PX,
        "sigma0": r.sigma0, "sigma0_um": rep["key_statistics"]["sigma0_um"],
        "injected_noise_um": NOISE_PX * ba.camera_apriori.pixel_um,
        "sigma0_error_pct": 100.0 * (r.sigma0 - 1.0),
        "check_points": int(len(d)),
        "rms_check_x_m": float(np.sqrt(np.mean(d[:, 0] ** 2))), "rms_check_y_m": float(np.sqrt(np.mean(d[:, 1] ** 2))),
        "rms_check_xy_m": rms_xy, "rms_check_z_m": rms_z,
        "rms_check_xy_gsd": rms_xy / gsd_m, "rms_check_z_gsd": rms_z / gsd_m,
        "normalised_check_rms_xyz": np.sqrt(np.mean((d / s) ** 2, axis=0)).tolist(),
        "normalised_check_rms": float(np.sqrt(np.mean((d / s) ** 2))),
        "selfcal_error_in_sd": dict(zip(["u0", "v0", "k1", "k2"], z_cal.tolist())),
        "selfcal_within_3sd": bool(np.all(np.abs(z_cal) < 3)),
        "pp_true_px": [cam_true.cx_px, cam_true.cy_px], "pp_est_px": est[:2].tolist(), "pp_sd_px": sd[[3, 4]].tolist(),
        "k1_true": cam_true.k1, "k1_est": float(est[2]), "k1_sd": float(sd[5]),
        "iterations": int(r.iterations_total), "adjust_s": t_adj, "timings_s": r.timings_s,
    }
    removed = {(str(b.point_id[b.obs_point[x.obs]]), b.image_id[b.obs_image[x.obs]]) for x in r.removed}
    bad = {tuple(x) for x in info.tie_blunders}
    out["removed_observations"] = len(removed)
    if blunders:
        n_good = info.n_tie_observations - len(bad)
        out.update({
            "blunders_injected": len(bad), "blunders_removed": len(bad & removed),
            "blunder_recall_pct": 100.0 * len(bad & removed) / max(len(bad), 1),
            "good_removed": len(removed - bad), "good_removed_pct": 100.0 * len(removed - bad) / n_good,
            "bad_control": info.bad_control, "rejected_control": [str(ba.control.id[c]) for c, _ in r.rejected_control],
        })
        out["bad_control_found"] = out["rejected_control"] == out["bad_control"]
    else:
        out["good_removed_pct"] = 100.0 * len(removed) / info.n_tie_observations
    targets = {
        "sigma0_within_10pct": abs(out["sigma0_error_pct"]) <= 10.0,
        "check_xy_le_0p5_gsd": out["rms_check_xy_gsd"] <= 0.5,
        "check_z_le_1_gsd": out["rms_check_z_gsd"] <= 1.0,
        "selfcal_within_3sd": out["selfcal_within_3sd"],
        "normalised_check_rms_0p7_1p5": 0.7 <= out["normalised_check_rms"] <= 1.5,
    }
    if blunders:
        targets.update({"blunder_recall_ge_95pct": out["blunder_recall_pct"] >= 95.0,
                        "good_removed_lt_1pct": out["good_removed_pct"] < 1.0, "bad_control_found": out["bad_control_found"]})
    out["targets_met"] = targets
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, help="an existing simulator demo project (copied); default: simulate one")
    ap.add_argument("--out", type=Path, default=Path("bench/results/adjust.json"))
    a = ap.parse_args(argv)
    res = {"noise_px": NOISE_PX, "cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        import shutil

        demo = tmp / "demo"
        if a.demo:
            shutil.copytree(a.demo, demo, ignore=shutil.ignore_patterns("images", "lidar", "ortho*", "lidar_out"))
        else:
            from aerotri.sim import load_preset, simulate

            simulate(load_preset("demo"), demo)
        truth = json.loads((demo / "truth" / "truth.json").read_text())
        gsd = float(truth.get("gsd_m", truth.get("gsd", 0.0)))
        for name, bl in (("demo", False), ("demo_blunders", True)):
            res["cases"][name] = evaluate(demo, gsd, bl, n_control=8, seed=5)
            print(name, json.dumps(res["cases"][name]["targets_met"]), file=sys.stderr)
        block = geometric_block(4, 10, seed=7)
        geo = write_block_project(block, tmp / "dmc")
        for name, bl in (("dmc_geometric", False), ("dmc_geometric_blunders", True)):
            res["cases"][name] = evaluate(geo, block.camera_true.gsd_m(block.flying_height_m), bl, n_control=8, seed=8)
            print(name, json.dumps(res["cases"][name]["targets_met"]), file=sys.stderr)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
