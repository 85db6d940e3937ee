"""The DSM raised to a cell's later returns (trial-gis F1): CHM against nDSM, and the DSM against the simulator's
truth DSM in tall canopy (truth height above the truth DEM over 5 m) and on open ground (under 0.2 m), for two
``lidarctl rasters`` outputs of the same classified strips (``--before``: main's code, ``--after``: this code).

Usage: python bench/eval_dsm_later_returns.py --demo DEMO --before DIR --after DIR [--out FILE]
(DEMO: a demo project run through the chain, its lidar_out/classified/*.laz and truth/; DIR: ``lidarctl rasters
DEMO/lidar_out/classified/*.laz DIR --res-m 0.5`` of each code)."""
import argparse
import glob
import json
from pathlib import Path

import laspy
import numpy as np
import rasterio
import rasterio.warp as W

ap = argparse.ArgumentParser()
ap.add_argument("--demo", type=Path, required=True)
ap.add_argument("--before", type=Path, required=True)
ap.add_argument("--after", type=Path, required=True)
ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "dsm_later_returns.json")
args = ap.parse_args()
CLASSIFIED = str(args.demo / "lidar_out" / "classified" / "*.laz")
TRUTH = str(args.demo / "truth") + "/"


def rd(f):
    with rasterio.open(f) as d:
        a = d.read(1).astype("f8")
        return (np.where(a == d.nodata, np.nan, a) if d.nodata is not None else a), d.transform


out = {}
cnt = veg = None
tdsm, tt = rd(TRUTH + "dsm.tif")
tdem, _ = rd(TRUTH + "dem.tif")
for tag, base in (("before", f"{args.before}/"), ("after", f"{args.after}/")):
    dsm, t = rd(base + "dsm.tif")
    ndsm, _ = rd(base + "ndsm.tif")
    chm, _ = rd(base + "chm.tif")
    H, Wd = dsm.shape
    if cnt is None:
        cnt, veg = np.zeros(H * Wd, int), np.zeros(H * Wd, int)
        for f in sorted(glob.glob(CLASSIFIED)):
            las = laspy.read(f)
            x, y, cl = np.asarray(las.x), np.asarray(las.y), np.asarray(las.classification)
            c = np.floor((x - t.c) / t.a).astype(int)
            r = np.floor((y - t.f) / t.e).astype(int)
            ok = (r >= 0) & (r < H) & (c >= 0) & (c < Wd) & (cl != 7) & (cl != 18)
            np.add.at(cnt, r[ok] * Wd + c[ok], 1)
            v = ok & ((cl == 4) | (cl == 5))
            np.add.at(veg, r[v] * Wd + c[v], 1)
        cnt, veg = cnt.reshape(H, Wd), veg.reshape(H, Wd)
    d = chm - ndsm
    rec = {"chm_cells": int(np.isfinite(chm).sum())}
    for lim in (0.001, 0.5, 2.0):
        b = d > lim
        rec[f"chm_above_ndsm_by_{lim}_m"] = {"cells": int(b.sum()), "with_a_vegetation_return": int((b & (veg > 0)).sum()),
                                              "with_no_return": int((b & (cnt == 0)).sum())}
    rec["chm_minus_ndsm_max_m"] = float(np.nanmax(d))
    on = np.full(tdsm.shape, np.nan)
    W.reproject(dsm.astype("f4"), on, src_transform=t, src_crs="EPSG:32649", dst_transform=tt, dst_crs="EPSG:32649",
                src_nodata=np.nan, dst_nodata=np.nan, resampling=W.Resampling.nearest)
    e = on - tdsm
    tall = (tdsm - tdem > 5) & np.isfinite(e)
    rec["tall_canopy_cells"] = int(tall.sum())
    rec["tall_canopy_dsm_over_5_m_low_share"] = float(np.mean(e[tall] < -5))
    rec["tall_canopy_dsm_minus_truth_median_m"] = float(np.median(e[tall]))
    openg = (tdsm - tdem < 0.2) & np.isfinite(e)
    rec["open_ground_dsm_minus_truth_median_m"] = float(np.median(e[openg]))
    rec["open_ground_dsm_over_1_m_high_share"] = float(np.mean(e[openg] > 1))
    out[tag] = rec
out["command"] = f"python bench/eval_dsm_later_returns.py --demo {args.demo} --before {args.before} --after {args.after}"
args.out.write_text(json.dumps(out, indent=1) + "\n")
print(json.dumps(out, indent=1))
