"""Consumer GNSS stated honestly: the flight-offset model (project.toml [gnss] offset_sigma_xy_m / offset_sigma_z_m)
against simulator truth and on the Brighton Beach drone block -> bench/results/consumer_gnss.json.

A consumer receiver's positions share an error of metres over a flight and differ among themselves by decimetres.
Three ways to weight them:

- ``survey``: each position with the decimetres, independent (what the [gnss] defaults of 0.05 / 0.1 m, a survey
  receiver's, did with a consumer drone's EXIF, even tighter): the reported datum sigmas are centimetres;
- ``per_frame_metres``: each position with metres (3 / 5 m), independent: the datum's sigma is honest, but the
  baselines between frames are weighted by metres too, so they no longer carry the block's scale;
- ``offset``: the decimetres between frames plus one 3-D offset for the flight, a priori 3 / 5 m (what aerotri
  import --format exif writes now).

``sim``: geometric blocks of the simulator (aerotri.sim.observations.geometric_block, 3 strips x 6 DMC frames at
1000 m, 60 m relief), GNSS = truth + a constant offset (``--offset``, default 2.5 -2.0 3.0 m) + 0.2 m noise per frame
and axis; tie points with 0.3 px noise; no control points. Adjusted without and with the terrain's DEM as surface
control. Per run: the adjusted projection centres' mean error per axis (the datum's error: the frames' own noise
averages out) against their median reported sigma (normalised error, honest within about 2-3); the block-height and
tilt sigmas of the report's BLOCK GEOMETRY; sigma0.

``brighton`` (``--brighton P --dem D``): a project matched from the 18 Brighton frames (aerotri init + import
--format exif + match; its work/ and at/tiepoints.csv are reused, not matched again) adjusted with each model,
without and with the DEM of the block's ODM cloud (``lidarctl classify model.laz`` + ``rasters --res-m 0.5``; a
peer's product from the same EXIF GNSS, not truth) as surface control, ``self_calibration`` as given. Per run:
verdict, sigma0, focal length, block height / tilt sigmas, estimated flight offset, and the tie points' median
height - ODM DEM (a check of the run without the DEM; both come from the same consumer GNSS, so their agreement
is not an absolute accuracy: the data has no ground control).

Usage: python bench/eval_consumer_gnss.py [--seeds 3] [--brighton P --dem DEM.tif --ndsm NDSM.tif]
       [--out /work/tmp/eval_consumer_gnss] [--results bench/results/consumer_gnss.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

NOISE_M = 0.2  # per-frame GNSS noise of the simulated consumer receiver, each axis
OFFSET_SIGMA_M = (3.0, 5.0)  # a priori, plan / height (what the exif import writes)
MODELS = {  # name -> (sigma_xy_m, sigma_z_m, offset_sigma_xy_m, offset_sigma_z_m or None)
    "survey": (NOISE_M, NOISE_M, None, None),
    "per_frame_metres": (3.0, 5.0, None, None),
    "offset": (NOISE_M, NOISE_M) + OFFSET_SIGMA_M,
}


def set_gnss_model(root: Path, sigma_xy_m, sigma_z_m, offset_xy_m=None, offset_z_m=None) -> None:
    """Rewrite project.toml's [gnss] sigmas (and flight offset sigmas): the section replaced or appended."""
    p = root / "project.toml"
    text = re.sub(r"(?ms)^\[gnss\].*?(?=^\[|\Z)", "", p.read_text())
    lever = re.search(r"(?m)^lever_arm_m = .*$", p.read_text())
    sec = f"[gnss]\nsigma_xy_m = {sigma_xy_m}\nsigma_z_m = {sigma_z_m}\n"
    if offset_xy_m is not None:
        sec += f"offset_sigma_xy_m = {offset_xy_m}\noffset_sigma_z_m = {offset_z_m}\n"
    if lever:
        sec += lever.group(0) + "\n"
    p.write_text(text.rstrip() + "\n\n" + sec)


def _modes(ba) -> dict:
    return {g.mode: {"sigma_m": round(g.sigma_m, 4), "sigma_deg": round(g.sigma_deg, 5),
                     "shares": {k: round(v, 3) for k, v in g.shares.items()}} for g in ba.result.geometry or []}


def sim_runs(out: Path, seeds: int, offset_m) -> list[dict]:
    from aerotri.adjust.pipeline import AdjustSettings, adjust_project
    from aerotri.sim.observations import geometric_block, write_block_project, write_terrain_dem, write_truth_observations

    rows = []
    for seed in range(seeds):
        block = geometric_block(3, 6, seed=10 + seed, gnss_sigma_m=(NOISE_M,) * 3, gnss_shift_sigma_m=0.0,
                                gnss_drift_sigma_m_per_km=0.0, lever_arm_m=(0.0, 0.0, 0.0))
        block.gnss_local = block.gnss_local + np.asarray(offset_m, float)
        block.gnss_shift_m[:] = np.asarray(offset_m, float)  # the truth record: the same offset in every strip
        root = write_block_project(block, out / f"sim{seed}")
        write_truth_observations(root, tie_sigma_px=0.3, n_control=0, n_check=0, points_per_image=150, seed=seed)
        dem = write_terrain_dem(block, root / "dem.tif")
        true_c = block.frame.to_map(block.centre_local)
        for model, (sxy, sz, oxy, oz) in MODELS.items():
            set_gnss_model(root, sxy, sz, oxy, oz)
            for with_dem in (False, True):
                st = AdjustSettings(image_sigma_px=0.3, use_control=False,
                                    dem=dem if with_dem else None,
                                    surface_sigma_m=0.05)
                t = time.process_time()
                ba = adjust_project(root, st)
                idx = {k: i for i, k in enumerate(block.image_id)}
                sel = [idx[k] for k in ba.eo_map.image_id]
                err = (ba.eo_map.centre_m - true_c[sel]).mean(axis=0)
                sig = np.median(ba.eo_map.sigma[:, :3], axis=0)
                row = {"seed": seed, "model": model, "dem": with_dem, "sigma0": round(ba.result.sigma0, 3),
                       "datum_error_m": [round(float(v), 3) for v in err],
                       "centre_sigma_m": [round(float(v), 3) for v in sig],
                       "normalised_error": [round(float(v), 2) for v in err / sig],
                       "geometry_modes": _modes(ba), "cpu_s": round(time.process_time() - t, 1)}
                if ba.opts.gnss_correction == "offset":
                    row["offset_estimated_m"] = [round(float(v), 3) for v in ba.result.state.shift[0]]
                rows.append(row)
                print(f"sim seed {seed} {model:17} dem={with_dem!s:5} error {row['datum_error_m']} m, sigma "
                      f"{row['centre_sigma_m']} m -> {row['normalised_error']}; height sigma "
                      f"{row['geometry_modes'].get('height', {}).get('sigma_m')} m", flush=True)
    return rows


def brighton_runs(matched: Path, out: Path, dem: Path, ndsm: Path, self_cal: tuple, models: list[str]) -> list[dict]:
    from aerotri.adjust.pipeline import AdjustSettings, run_adjustment

    sys.path.insert(0, str(REPO / "bench"))
    from eval_brighton import tie_minus_dem

    rows = []
    for model in models:
        sxy, sz, oxy, oz = {"survey_defaults": (0.05, 0.1, None, None), "per_frame_metres": (3.0, 5.0, None, None),
                            "offset": MODELS["offset"]}[model]
        if model == "offset":  # the exif import's values, read from what it writes
            from aerotri.exchange.exif import CONSUMER_GNSS

            sxy, sz, oxy, oz = CONSUMER_GNSS
        for with_dem in (False, True):
            root = out / f"brighton_{model}_{'dem' if with_dem else 'nodem'}"
            shutil.rmtree(root, ignore_errors=True)
            shutil.copytree(matched, root, symlinks=True, ignore=shutil.ignore_patterns("ortho", "reports", "lidar_out"))
            set_gnss_model(root, sxy, sz, oxy, oz)
            st = AdjustSettings(self_calibration=tuple(self_cal) + (("focal",) if with_dem else ()),
                                dem=dem if with_dem else None, ndsm=ndsm if with_dem else None)
            t = time.process_time()
            res = run_adjustment(root, st, html=False)
            ba, rep = res.adjustment, json.loads(res.report_path.read_text())
            ks = rep["key_statistics"]
            row = {"model": model, "gnss_sigma_m": [sxy, sz], "offset_sigma_m": [oxy, oz] if oxy else None,
                   "dem": with_dem, "self_calibration": list(st.self_calibration), "verdict": ks["verdict"],
                   "message": ks["message"], "sigma0": ks["sigma0"], "sigma0_px": ks["sigma0_px"],
                   "focal_px": round(float(ba.camera_adjusted.focal_px), 1),
                   "focal_apriori_px": round(float(ba.camera_apriori.focal_px), 1),
                   "geometry_modes": _modes(ba), "datum": rep["datum"],
                   "gnss_residual_rms_m": [round(float(v), 3) for v in np.sqrt(np.mean(ba.gnss_residual_m ** 2, axis=0))],
                   "tie_minus_odm_dem": tie_minus_dem(root / "at" / "object_points.csv", dem, ndsm),
                   "cpu_s": round(time.process_time() - t, 1)}
            if ba.opts.gnss_correction == "offset":
                row["offset_estimated_m"] = [round(float(v), 3) for v in ba.result.state.shift[0]]
            rows.append(row)
            h = row["geometry_modes"].get("height", {}).get("sigma_m")
            print(f"brighton {model:17} dem={with_dem!s:5} {ks['verdict']}, sigma0 {ks['sigma0']}, focal "
                  f"{row['focal_px']} px, height sigma {h} m, tie - ODM DEM {row['tie_minus_odm_dem']['median_m']} m, "
                  f"offset {row.get('offset_estimated_m')}, {row['cpu_s']} CPU-s", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--offset", type=float, nargs=3, default=(2.5, -2.0, 3.0), help="the simulated GNSS offset (m)")
    ap.add_argument("--brighton", type=Path, default=None, help="a matched Brighton project (at/tiepoints.csv)")
    ap.add_argument("--dem", type=Path, default=None)
    ap.add_argument("--ndsm", type=Path, default=None)
    ap.add_argument("--self-cal", default="pp,radial")
    ap.add_argument("--models", default="survey_defaults,per_frame_metres,offset")
    ap.add_argument("--skip-sim", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("/work/tmp/eval_consumer_gnss"))
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "consumer_gnss.json")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    res = json.loads(args.results.read_text()) if args.results.is_file() else {}
    import os

    res["load_average"] = list(os.getloadavg())
    if not args.skip_sim:
        res["sim"] = {"offset_m": list(args.offset), "noise_m": NOISE_M, "models": MODELS,
                      "runs": sim_runs(args.out, args.seeds, args.offset)}
    if args.brighton is not None:
        res["brighton"] = {"project": str(args.brighton), "dem": str(args.dem),
                           "runs": brighton_runs(args.brighton, args.out, args.dem, args.ndsm,
                                                 tuple(g for g in args.self_cal.split(",") if g),
                                                 args.models.split(","))}
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(res, indent=1) + "\n")
    print(f"-> {args.results}")


if __name__ == "__main__":
    main()
