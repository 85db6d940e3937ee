"""True ortho against conventional on the demo block (issue 42): the same frames and orientation rectified on the
DEM and, with ``--true-ortho``, on the LiDAR DSM (lidar_out/dsm.tif), each mosaicked, and measured against the
simulator's true orthophoto (truth/ortho.tif, roofs in place):

- roofs: the displacement of a 24 x 24 m patch centred on every roof corner of truth/roof_corners.csv, DOM
  against the truth resampled onto the DOM grid (cv2.phaseCorrelate with a Hanning window; patches with at least
  80 % of their DOM cells valid, the others set to the patch mean, and a correlation response of at least 0.1),
  RMS and median in metres and DOM pixels (GSD);
- the rectify wall and CPU time of each way (in this process, imports excluded), per MP of frame orthos;
- interior cells left empty: DOM cells inside the convex hull of the valid DOM without a value (the hull also
  takes in some of the block's ragged outer edge);
- the mosaic's report of cells no frame sees (mosaic.json cells_seen_by_no_frame).

Usage: python bench/eval_true_ortho.py [--project /work/ref/demo_chain/project] [--work DIR]
Writes bench/results/true_ortho.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

PATCH_M = 24.0
MIN_RESPONSE = 0.1
MIN_VALID = 0.8  # patches with at least this share of DOM cells with a value (nodata set to the patch mean)


def copy_project(src: Path, dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in ("at", "camera.toml", "images", "project.toml", "truth"):
        p = src / name
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, dst / name)
    (dst / "lidar_out").mkdir()
    for name in ("dem.tif", "dsm.tif", "ndsm.tif"):
        shutil.copy2(src / "lidar_out" / name, dst / "lidar_out" / name)


def make_dom(project: Path, true_ortho: bool) -> dict:
    from aerotri.core.executor import Executor
    from ortho.block import rectify_block
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings, RectifySettings

    settings = RectifySettings(true_ortho=True, dsm=str(project / "lidar_out" / "dsm.tif")) if true_ortho \
        else RectifySettings()
    with Executor() as ex:
        t, c = time.perf_counter(), time.process_time()
        done = rectify_block(project, settings, executor=ex)
        rect = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
        t, c = time.perf_counter(), time.process_time()
        summary = json.loads(mosaic_block(project, MosaicSettings(), executor=ex).summary_path.read_text())
        mos = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    mp = sum(g.width * g.height for g in done.grids) / 1e6
    rect.update(frame_ortho_mp=round(mp, 2), cpu_s_per_mp=rect["cpu_s"] / mp, wall_s_per_mp=rect["wall_s"] / mp)
    return {"rectify": rect, "mosaic": mos, "summary": summary}


def roof_displacements(dom_path: Path, truth_path: Path, corners_csv: Path) -> dict:
    import csv

    import cv2
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    with rasterio.open(dom_path) as dom:
        res = dom.res[0]
        n = int(round(PATCH_M / res))
        win = np.outer(np.hanning(n), np.hanning(n)).astype(np.float32)
        rows = list(csv.DictReader(open(corners_csv)))
        shifts, skipped = [], {"outside_or_invalid": 0, "weak": 0}
        with rasterio.open(truth_path) as truth:
            for row in rows:
                x, y = float(row["x"]), float(row["y"])
                r, c = dom.index(x, y)
                r0, c0 = r - n // 2, c - n // 2
                if r0 < 0 or c0 < 0 or r0 + n > dom.height or c0 + n > dom.width:
                    skipped["outside_or_invalid"] += 1
                    continue
                w = rasterio.windows.Window(c0, r0, n, n)
                a = dom.read(window=w).astype(np.float32)
                ok = dom.read_masks(1, window=w) > 0
                if ok.mean() < MIN_VALID:
                    skipped["outside_or_invalid"] += 1
                    continue
                ref = np.zeros((truth.count, n, n), np.float32)
                reproject(rasterio.band(truth, list(range(1, truth.count + 1))), ref,
                          dst_transform=dom.window_transform(w), dst_crs=dom.crs, resampling=Resampling.average)
                g1 = a[:3].mean(axis=0)
                g1[~ok] = g1[ok].mean()  # nodata (occluded cells no frame sees) neutral: the patch mean
                g2 = ref[:3].mean(axis=0)
                (dx, dy), resp = cv2.phaseCorrelate(g2.astype(np.float64), g1.astype(np.float64), win.astype(np.float64))
                if resp < MIN_RESPONSE:
                    skipped["weak"] += 1
                    continue
                shifts.append((dx * res, -dy * res))  # DOM minus truth, east and north
    d = np.array(shifts).reshape(-1, 2)
    mag = np.hypot(d[:, 0], d[:, 1])
    return {"corners": len(rows), "measured": int(len(d)), "skipped": skipped, "gsd_m": res,
            "rms_m": float(np.sqrt(np.mean(mag ** 2))), "median_m": float(np.median(mag)),
            "rms_gsd": float(np.sqrt(np.mean(mag ** 2)) / res), "median_gsd": float(np.median(mag) / res),
            "p90_m": float(np.percentile(mag, 90)), "mean_dx_m": float(d[:, 0].mean()), "mean_dy_m": float(d[:, 1].mean())}


def interior_empty(dom_path: Path) -> dict:
    import cv2
    import rasterio

    with rasterio.open(dom_path) as ds:
        ok = ds.read_masks(1) > 0
    cnts, _ = cv2.findContours(ok.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = np.zeros(ok.shape, np.uint8)
    cv2.drawContours(hull, [cv2.convexHull(np.concatenate(cnts))], -1, 1, thickness=-1)
    inside = hull > 0
    empty = inside & ~ok
    return {"interior_cells": int(inside.sum()), "empty": int(empty.sum()), "empty_share": float(empty.sum() / inside.sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho.json")
    args = ap.parse_args()
    out = {"project": str(args.project), "patch_m": PATCH_M, "min_response": MIN_RESPONSE, "min_valid": MIN_VALID,
           "ways": {}}
    for way, true_ortho in (("conventional", False), ("true_ortho", True)):
        p = args.work / way
        copy_project(args.project, p)
        made = make_dom(p, true_ortho)
        res = {"rectify": made["rectify"], "mosaic": made["mosaic"],
               "roofs": roof_displacements(p / "ortho" / "mosaic.tif", p / "truth" / "ortho.tif",
                                           p / "truth" / "roof_corners.csv"),
               "interior": interior_empty(p / "ortho" / "mosaic.tif")}
        if "cells_seen_by_no_frame" in made["summary"]:
            res["cells_seen_by_no_frame"] = made["summary"]["cells_seen_by_no_frame"]
        out["ways"][way] = res
        print(way, json.dumps(res, indent=1), flush=True)
    c, t = out["ways"]["conventional"]["rectify"], out["ways"]["true_ortho"]["rectify"]
    out["rectify_cpu_per_mp_ratio"] = t["cpu_s_per_mp"] / c["cpu_s_per_mp"]
    out["rectify_wall_per_mp_ratio"] = t["wall_s_per_mp"] / c["wall_s_per_mp"]
    import subprocess

    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
