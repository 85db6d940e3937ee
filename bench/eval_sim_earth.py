"""Evaluate the simulator's earth (issue 41) -> bench/results/sim_earth.json.

Two small rendered blocks with check targets; each is simulated, its targets measured in the rendered frames
(centroid of the white disc inside the black ring), tie points matched (``aerotri match``), and adjusted with the
GNSS (a shift per strip) and the targets as control (0.01 m), with the true interior orientation:

- ``tiny_x4``: the tiny preset with 4 x its pixels (1728 x 960 px, 96 um, 0.24 m GSD, 300 m above ground);
- ``dmc_2x4``: the dmc_block preset's geometry (f 120 mm, 1000 m above ground) with 2 strips of 4 frames of
  3456 x 1920 px (48 um, 0.40 m GSD), targets of 3 m radius, thinner LiDAR and 2 m truth rasters.

Reported per block and code (``earth``: this tree; ``flat``: the simulator before issue 41, run from a copy of
its tree with ``--code-root``): the targets' rendered offset from their true image positions (the projection
through the ENU frame, ``aerotri.geom.local_frame``), the adjusted projection centres' height error (mean, RMS,
RMS in units of the reported sigmas), the estimated GNSS shifts, and the frames' rendering cost (CPU s per MP).

Usage:
  python bench/eval_sim_earth.py                         # this tree (``earth``)
  git archive <commit before issue 41> | tar -x -C /tmp/flat
  python bench/eval_sim_earth.py --code-root /tmp/flat --tag flat
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = {
    "tiny_x4": ("tiny", ["camera.width=1728", "camera.height=960"]),
    "dmc_2x4": ("dmc_block", ["camera.width=3456", "camera.height=1920", "flight.strips=2", "flight.frames_per_strip=4",
                              "lidar.pulse_rate_hz=20000", "truth.raster_res_m=2.0", "truth.ortho_res_m=2.0",
                              "scene.target_radius_m=3.0"]),
}
TARGET_SIGMA_M = 0.01


def measured_targets(p: Path, target_radius_m: float, gsd_m: float):
    """(point id, image id, x px, y px) of the targets wholly inside a frame: the brightness-weighted centroid
    inside 1.6 radii of the truth position (tests/aerotri/sim/test_earth.py does the same)."""
    import warnings

    import numpy as np
    import rasterio

    from aerotri.geom.camera import BrownCamera

    cam = BrownCamera.read(p / "truth/camera.toml")
    r_px = target_radius_m / gsd_m
    images, out = {}, []
    for r in csv.DictReader(open(p / "truth/checkpoint_image_points.csv", newline="")):
        if r["image_id"] not in images:  # tiled ZSTD frames (dmc_block) are beyond OpenCV's TIFF reader
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                with rasterio.open(p / "images" / f"{r['image_id']}.tif") as src:
                    images[r["image_id"]] = src.read().astype(float).mean(axis=0)
        img = images[r["image_id"]]
        x0, y0 = float(r["x_px"]), float(r["y_px"])
        half = int(np.ceil(1.5 * r_px)) + 1
        cx, cy = int(round(x0)), int(round(y0))
        if cx - half < 0 or cy - half < 0 or cx + half >= cam.width or cy + half >= cam.height:
            continue
        win = img[cy - half: cy + half + 1, cx - half: cx + half + 1]
        yy, xx = np.mgrid[cy - half: cy + half + 1, cx - half: cx + half + 1]
        inside = (xx - x0) ** 2 + (yy - y0) ** 2 <= (1.6 * r_px) ** 2
        w = np.where(inside, np.clip(win - np.percentile(win[inside], 10), 0, None), 0.0)
        out.append((r["point_id"], r["image_id"], (w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()))
    return out


def true_image_positions(p: Path, obs):
    """The targets' image positions through the ENU frame (the earth), whatever the simulator wrote."""
    import tomllib

    import numpy as np

    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.eo import read_eo
    from aerotri.geom.local_frame import LocalFrame

    eo, cam = read_eo(p / "truth/eo.txt"), BrownCamera.read(p / "truth/camera.toml")
    frame = LocalFrame.at_centre(tomllib.loads((p / "project.toml").read_text())["project"]["crs"], eo.centre_m)
    C, R = frame.to_local(eo.centre_m), frame.rotation_local_from_map(eo.centre_m) @ eo.rotations()
    cps = {r["id"]: [float(r["x"]), float(r["y"]), float(r["z"])] for r in csv.DictReader(open(p / "truth/checkpoints.csv"))}
    idx = dict(zip(eo.image_id, range(len(eo.image_id))))  # image id -> row
    out = []
    for pid, iid, *_ in obs:
        i = idx[iid]
        x, y, _ = cam.project(frame.to_local(np.array([cps[pid]])), C[i], R[i])
        out.append((float(x[0]), float(y[0])))
    return np.array(out)


def run_case(name: str, work: Path) -> dict:
    import numpy as np
    from click.testing import CliRunner

    from aerotri.adjust.pipeline import AdjustSettings, adjust_project
    from aerotri.cli import main as aerotri_main
    from aerotri.geom.eo import read_eo
    from aerotri.sim import load_preset, simulate

    preset, sets = CASES[name]
    cfg = load_preset(preset, sets)
    p = work / name
    phases = {}
    t0 = time.process_time()
    simulate(cfg, p, on_phase=lambda c: phases.__setitem__(c.phase, c))
    sim_cpu = time.process_time() - t0
    truth = json.loads((p / "truth/truth.json").read_text())
    obs = measured_targets(p, float(cfg.scene.target_radius_m), truth["gsd_m"])
    xy = np.array([(x, y) for *_, x, y in obs])
    off = np.hypot(*(xy - true_image_positions(p, obs)).T)
    # the adjustment: GNSS with a shift per strip, the targets as control, matched ties, the true camera
    seen = {pid for pid, *_ in obs}
    pts = [r for r in csv.DictReader(open(p / "truth/checkpoints.csv", newline="")) if r["id"] in seen]
    (p / "control").mkdir(exist_ok=True)
    (p / "control/points.csv").write_text("id,kind,x,y,z,sx_m,sy_m,sz_m\n" + "".join(
        f"{r['id']},full,{r['x']},{r['y']},{r['z']},{TARGET_SIGMA_M},{TARGET_SIGMA_M},{TARGET_SIGMA_M}\n" for r in pts))
    (p / "control/image_points.csv").write_text("point_id,image_id,x_px,y_px\n" + "".join(
        f"{pid},{iid},{x:.4f},{y:.4f}\n" for pid, iid, x, y in obs))
    shutil.copy(p / "truth/camera.toml", p / "camera.toml")
    t0 = time.process_time()
    res = CliRunner().invoke(aerotri_main, ["match", str(p), "--budget", "4000"])
    if res.exit_code != 0:
        raise SystemExit(res.output)
    match_cpu = time.process_time() - t0
    ba = adjust_project(p, AdjustSettings(gnss_correction="shift", point_covariances=False, lidar_surface=False))
    true = read_eo(p / "truth/eo.txt")
    k = true.rows(ba.eo_map.image_id)
    dz = ba.eo_map.centre_m[:, 2] - true.centre_m[k, 2]
    z = dz / ba.eo_map.sigma[:, 2]
    fr = phases["frames"]
    return {
        "preset": preset, "overrides": sets, "frames": truth["frames"], "gsd_m": round(truth["gsd_m"], 4),
        "flying_height_m": truth["flying_height_above_ground_m"],
        "image_px": [truth["image_width_px"], truth["image_height_px"]],
        "target_observations": len(obs),
        "target_offset_from_true_px": {"rms": round(float(np.sqrt((off ** 2).mean())), 4),
                                       "max": round(float(off.max()), 4)},
        "adjustment": {
            "sigma0_px": round(float(ba.result.sigma0 * ba.opts.image_sigma_px), 4),
            "tie_observations": int(len(ba.block.obs_point)),
            "centre_height_error_m": {"mean": round(float(dz.mean()), 4), "rms": round(float(np.sqrt((dz ** 2).mean())), 4),
                                      "min": round(float(dz.min()), 4), "max": round(float(dz.max()), 4)},
            "centre_height_sigma_m_mean": round(float(ba.eo_map.sigma[:, 2].mean()), 4),
            "centre_height_normalised_rms": round(float(np.sqrt((z ** 2).mean())), 2),
            "gnss_shift_m": np.round(ba.result.state.shift, 4).tolist(),
        },
        "cost": {"simulate_cpu_s": round(sim_cpu, 1), "frames_cpu_s": fr.cpu_s,
                 "frames_cpu_s_per_mp": round(fr.cpu_s / fr.megapixels, 4), "match_cpu_s": round(match_cpu, 1),
                 "load_avg_1min": round(os.getloadavg()[0], 2)},
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--code-root", type=Path, help="import aerotri from this tree (the flat-world simulator)")
    ap.add_argument("--tag", default="earth", help="key of this run in bench/results/sim_earth.json (earth | flat)")
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--work", type=Path, help="keep the simulated blocks here (default: a temporary folder)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "sim_earth.json")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(a.code_root or ROOT))
    with tempfile.TemporaryDirectory(dir=a.work) as tmp:
        for name in a.cases:
            r = run_case(name, Path(tmp))
            out = json.loads(a.out.read_text()) if a.out.exists() else {}  # read now: other runs may have written
            out.setdefault(name, {})[a.tag] = r
            print(name, a.tag, json.dumps(r["target_offset_from_true_px"]), json.dumps(r["adjustment"]["centre_height_error_m"]),
                  "normalised", r["adjustment"]["centre_height_normalised_rms"], "frames CPU s/MP", r["cost"]["frames_cpu_s_per_mp"],
                  flush=True)
            a.out.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
