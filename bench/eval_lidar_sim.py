"""Simulator `demo` preset: ground filter, outlier flags and DEM accuracy against the truth.

Uses an existing simulated project (``--project``) or simulates one with `aerotri sim --preset demo`.
All strips are classified together (as `lidarctl classify` would a merged file); truth classes come
from truth/lidar/*.las (same point order), the true DEM from truth/dem.tif.
DEM RMSE is computed at the centres of our DEM cells, split into open ground (no truth object point
within the cell and its neighbours) and under canopy (a truth vegetation point above the cell).
Writes bench/results/lidar_sim.json. Run: .venv/bin/python bench/eval_lidar_sim.py [--project DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
from scipy import ndimage

from lidarctl import io
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate
from lidarctl.rasters import products as rasters
from lidarctl.raster_ops import reduce_grid

REPO = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--project", default=None)
    ap.add_argument("--res-m", type=float, default=1.0)
    args = ap.parse_args()
    project = Path(args.project) if args.project else Path(tempfile.gettempdir()) / "aerotri_lidar_sim_demo"
    if not (project / "truth" / "dem.tif").exists():
        subprocess.run([str(REPO / ".venv" / "bin" / "aerotri"), "sim", "--preset", "demo", "--force",
                        str(project)], check=True)
    strips = sorted((project / "lidar").glob("*.las"))
    clouds = [io.read_cloud(s) for s in strips]
    truth = np.concatenate([io.read_cloud(project / "truth" / "lidar" / s.name).classification for s in strips])
    fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns", "classification")
    cloud = io.PointCloud(*[np.concatenate([getattr(c, f) for c in clouds]) for f in fields], crs=clouds[0].crs)
    t0 = time.perf_counter()
    pred = classify.classify_points(cloud.x, cloud.y, cloud.z, cloud.return_number, cloud.number_of_returns,
                                    cloud.intensity)
    seconds = time.perf_counter() - t0
    outlier = np.isin(truth, (7, 18))
    flagged = np.isin(pred, (7, 18))
    keep = ~outlier
    filt = evaluate.filter_errors(np.isin(pred[keep], (2, 9)), np.isin(truth[keep], (2, 9)))
    conf = evaluate.confusion(pred, truth)

    cloud.classification = pred
    grids = rasters.make_grids(cloud, args.res_m)
    dem = grids.dem[::-1]                                  # rows growing with y again
    tr = grids.transform
    nrows, ncols = dem.shape
    x0, y0 = tr.c, tr.f - nrows * args.res_m
    jj, ii = np.meshgrid(np.arange(ncols), np.arange(nrows))
    cx, cy = x0 + (jj + 0.5) * args.res_m, y0 + (ii + 0.5) * args.res_m
    with rasterio.open(project / "truth" / "dem.tif") as ds:
        tdem = ds.read(1, masked=True).filled(np.nan)
        col = (cx - ds.transform.c) / ds.transform.a - 0.5
        row = (cy - ds.transform.f) / ds.transform.e - 0.5
    true_z = ndimage.map_coordinates(tdem, [row.ravel(), col.ravel()], order=1, mode="nearest",
                                     cval=np.nan).reshape(dem.shape)
    grid_kw = dict(cell_m=args.res_m, x0=x0, y0=y0, nrows=nrows, ncols=ncols)
    obj = np.isin(truth, (3, 4, 5, 6))
    veg = np.isin(truth, (3, 4, 5))
    any_obj = np.isfinite(reduce_grid(cloud.x[obj], cloud.y[obj], cloud.z[obj], **grid_kw, how="max"))
    any_veg = np.isfinite(reduce_grid(cloud.x[veg], cloud.y[veg], cloud.z[veg], **grid_kw, how="max"))
    any_ground = np.isfinite(reduce_grid(cloud.x[truth == 2], cloud.y[truth == 2], cloud.z[truth == 2],
                                         **grid_kw, how="max"))
    open_ground = any_ground & ~ndimage.binary_dilation(any_obj, np.ones((3, 3), bool))
    canopy = any_veg & ~ndimage.binary_dilation(np.isfinite(reduce_grid(
        cloud.x[truth == 6], cloud.y[truth == 6], cloud.z[truth == 6], **grid_kw, how="max")), np.ones((3, 3), bool))
    err = dem - true_z
    ok = np.isfinite(err)

    def rmse(mask):
        e = err[mask & ok]
        return float(np.sqrt(np.mean(e ** 2))) if e.size else None

    res = {
        "project": str(project), "points": int(len(pred)), "classify_seconds": seconds,
        "ground_filter_errors": dataclasses.asdict(filt),
        "outliers_injected": int(outlier.sum()),
        "outliers_flagged_pct": 100.0 * float(np.mean(flagged[outlier])),
        "false_noise_flags_pct": 100.0 * float(np.mean(flagged[~outlier])),
        "dem_res_m": args.res_m,
        "dem_rmse_open_m": rmse(open_ground), "dem_cells_open": int((open_ground & ok).sum()),
        "dem_rmse_canopy_m": rmse(canopy), "dem_cells_canopy": int((canopy & ok).sum()),
        "dem_rmse_all_m": rmse(np.ones_like(ok)),
        "dem_p99_abs_error_open_m": float(np.percentile(np.abs(err[open_ground & ok]), 99)),
        "targets": {"type_i_error_pct": 2.0, "type_ii_error_pct": 2.0, "outliers_flagged_pct": 99.0,
                    "false_noise_flags_pct": 0.1, "dem_rmse_open_m": 0.15, "dem_rmse_canopy_m": 0.30},
        "confusion": dataclasses.asdict(conf),
    }
    # Water (9): the ponds' few surviving returns (the simulator drops most water pulses).
    res["water_points_truth"] = int(np.sum(truth == 9))
    res["water_points_pred"] = int(np.sum(pred == 9))
    res["water_producers_accuracy_pct"] = conf.producers_accuracy_pct.get("9")
    res["water_users_accuracy_pct"] = conf.users_accuracy_pct.get("9")
    print(evaluate.format_filter_table({"sim demo": filt}))
    print(evaluate.format_confusion(conf, classify.CLASS_NAMES))
    for k in ("points", "classify_seconds", "outliers_flagged_pct", "false_noise_flags_pct", "dem_rmse_open_m",
              "dem_rmse_canopy_m", "dem_rmse_all_m", "dem_p99_abs_error_open_m", "water_points_truth",
              "water_points_pred", "water_producers_accuracy_pct", "water_users_accuracy_pct"):
        print(f"{k}: {res[k]}")
    path = REPO / "bench" / "results" / "lidar_sim.json"
    path.write_text(json.dumps(res, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
