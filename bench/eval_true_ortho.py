"""True ortho against conventional on the demo block (issue 42): the same frames and orientation rectified on the
DEM and, with ``--true-ortho``, on the LiDAR DSM (lidar_out/dsm.tif), each mosaicked, and measured against the
simulator's true orthophoto (truth/ortho.tif, roofs in place):

- roofs: the displacement of a 24 x 24 m patch centred on every roof corner of truth/roof_corners.csv, DOM
  against the truth resampled onto the DOM grid (``ortho.check.measure_roof_patches``: masked NCC over the cells
  valid in both, patches with at least 80 % of their DOM cells valid; until issue 42's roofs work, figures in the
  JSON before it, cv2.phaseCorrelate with the DOM's nodata set to the patch mean), RMS and median in metres and DOM
  pixels (GSD);
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


def copy_project(src: Path, dst: Path, lidar_files: tuple = ("dem.tif", "dsm.tif", "ndsm.tif")) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in ("at", "camera.toml", "images", "project.toml", "truth"):
        p = src / name
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, dst / name)
    (dst / "lidar_out").mkdir()
    for name in lidar_files:
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
    """The DOM check's roof measurement (``ortho.check.measure_roof_patches``: masked NCC over the valid cells since
    issue 42's roofs work; until then a phase correlation with nodata set to the patch mean, in this function) at the
    corners of ``corners_csv``, as a dict of figures."""
    import rasterio

    from ortho.check import measure_roof_patches, read_roof_corners

    with rasterio.open(dom_path) as dom:
        res = dom.res[0]
    xs, ys = read_roof_corners(corners_csv)
    m = measure_roof_patches(dom_path, truth_path, xs, ys, patch_m=PATCH_M)
    d = np.stack([m.de_m, m.dn_m], axis=1)
    mag = np.hypot(d[:, 0], d[:, 1])
    return {"corners": m.corners, "measured": int(len(d)),
            "skipped": {"outside_or_invalid": m.outside_or_invalid, "weak": m.weak}, "gsd_m": res,
            "method": "masked NCC (ortho.check.measure_roof_patches)",
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
    out = {"project": str(args.project), "patch_m": PATCH_M,
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
