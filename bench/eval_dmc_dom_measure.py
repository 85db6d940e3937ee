"""What a DMC chain's DOM and seam figures are made of: the patches of ``ortho check`` split by the truth's land cover.

``aerotri run`` judges the DOM by two NCC measures against the simulator's truth: the DOM check (48 px patches of
open ground against ``truth/ortho.tif``, ``ortho/dom_report.json``) and the seam misalignment (32 px patches of the
two frame orthos on each seam, ``ortho.mosaic.seam_misalignment``). A patch of road has texture only across the
road: its NCC peak can sit anywhere along it within the search window. This script takes a run folder's patches
and splits them by the class of ``truth/classes.tif`` under each patch centre (11 road, 3 grass, 2 bare ground, 9
water): the DOM check's listed patches (the first 20,000 of ``dom_report.json``), the share above 3 GSD, their
classes and directions (the roads run at 12 and 102 deg from east), the RMS without them; the seams' patches
recomputed as ``seam_misalignment`` does (same windows, nDSM below 0.5 m, NCC >= 0.7), with their positions, split
on / off roads and along a strip / across strips; and the listed patches by the shape of their texture (the
structure tensor's eigenvalue ratio, ``anisotropy``: a road's edges give texture in one direction only). Writes
bench/results/dmc_dom_measure.json under ``--key`` (``--anisotropy-only``: that split added to the key's entry).

Usage: python bench/eval_dmc_dom_measure.py RUN_DIR BLOCK_DIR --key dmc_2x4_cccbc0a
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.results_json import read_results, store_result  # noqa: E402

import ortho.mosaic as M  # noqa: E402
from ortho.grid import OrthoGrid  # noqa: E402
from ortho.patches import match_patches  # noqa: E402

ROAD = 11


class Classes:
    """truth/classes.tif sampled at map points."""

    def __init__(self, path: Path):
        with rasterio.open(path) as ds:
            self.a, self.t = ds.read(1), ds.transform

    def at(self, x, y) -> np.ndarray:
        r, c = rasterio.transform.rowcol(self.t, np.asarray(x), np.asarray(y))
        return self.a[np.clip(r, 0, self.a.shape[0] - 1), np.clip(c, 0, self.a.shape[1] - 1)]


def _rms(d) -> dict:
    d = np.asarray(d, float)
    if not len(d):
        return dict(patches=0)
    return dict(patches=int(len(d)), rms=round(float(np.sqrt(np.mean(d ** 2))), 3), median=round(float(np.median(d)), 3))


def seam_patches(root: Path, classes: Classes, patch_px: int = 32, search_px: int = 4) -> dict:
    """``seam_misalignment``'s patches (px) with the class under each and whether the seam is along a strip."""
    index = M.read_index(root)
    grids = index.grids
    mosaic = OrthoGrid.union(grids)
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        labels = ds.read(1)
        factor = int(round(ds.transform.a / mosaic.res_m))
    names = list(index.image_ids)
    operation = M.index_operation(index)
    half = patch_px // 2 + search_px
    size = 2 * half
    along, road, d = [], [], []
    for (i, j), rc in M.seam_samples(labels, 4):
        R = ((rc[:, 0] + 0.5) * factor).astype(int) - half
        C = ((rc[:, 1] + 0.5) * factor).astype(int) - half
        with M._open_frame(root / "ortho" / "frames" / f"{names[i]}.tif") as fa, \
                M._open_frame(root / "ortho" / "frames" / f"{names[j]}.tif") as fb:
            for r0, c0 in zip(R.tolist(), C.tolist()):
                imgs = [M.read_window(ds, c0 - grids[k].offset_in(mosaic)[0], r0 - grids[k].offset_in(mosaic)[1],
                                      size, size) for k, ds in ((i, fa), (j, fb))]
                t = Affine(mosaic.res_m, 0, mosaic.x_left_m + c0 * mosaic.res_m, 0, -mosaic.res_m,
                           mosaic.y_top_m - r0 * mosaic.res_m)
                nd = M._read_ndsm_on(root / "lidar_out" / "ndsm.tif", t, (size, size), mosaic.crs, operation)
                p = match_patches(imgs[0][0], imgs[1][0], imgs[0][1], imgs[1][1], res_m=mosaic.res_m,
                                  patch_px=patch_px, step_px=patch_px, search_px=search_px, min_ncc=0.7,
                                  keep=np.nan_to_num(nd, nan=1e9) <= 0.5)
                x, y = t * (p.col_px + 0.5, p.row_px + 0.5)
                road.extend((classes.at(x, y) == ROAD).tolist())
                along.extend([names[i][:3] == names[j][:3]] * len(x))  # s01_002: strip 1
                d.extend(np.hypot(p.dx_px, p.dy_px).tolist())
    d, road, along = np.array(d), np.array(road, bool), np.array(along, bool)
    return {k: _rms(d[s]) for k, s in (("all", np.ones(len(d), bool)), ("off_roads", ~road), ("roads", road),
                                       ("along_strip", along), ("across_strips", ~along),
                                       ("along_strip_off_roads", along & ~road),
                                       ("across_strips_off_roads", ~along & ~road))}


def dom_patches(root: Path, classes: Classes) -> dict:
    """The DOM check's listed patches (GSD) by class; those above 3 GSD: share, classes, directions."""
    rep = json.loads((root / "ortho" / "dom_report.json").read_text())
    with rasterio.open(rep["dom"]) as ds:
        T = ds.transform
    P = rep["patches"]
    x, y = T * (np.array([p["col_px"] for p in P]) + 0.5, np.array([p["row_px"] for p in P]) + 0.5)
    k = classes.at(x, y)
    de, dn = np.array([p["de_m"] for p in P]), np.array([p["dn_m"] for p in P])
    d = np.hypot(de, dn) / rep["gsd_m"]
    big = d > 3.0
    u, n = np.unique(k[big], return_counts=True)
    direction = np.degrees(np.arctan2(dn[big], de[big])) % 180.0
    return dict(listed=len(d), total=rep["patches_total"], all=_rms(d), off_roads=_rms(d[k != ROAD]),
                roads=_rms(d[k == ROAD]), without_above_3_gsd=_rms(d[~big]),
                above_3_gsd=dict(patches=int(big.sum()), pct=round(100.0 * big.mean(), 2),
                                 classes={int(a): int(b) for a, b in zip(u, n)},
                                 direction_deg_from_east_mod_180_per_15=np.histogram(direction, bins=12,
                                                                                      range=(0, 180))[0].tolist()))


def anisotropy(root: Path, patch_px: int = 48) -> dict:
    """The DOM check's listed patches by the shape of their texture: the ratio of the small to the large eigenvalue
    of the patch's gradient structure tensor (Sobel, over the DOM patch; 0: texture in one direction only, a road's
    edges; 1: a corner's). Per ratio band the patches, their RMS and share above 3 GSD; and the RMS of the patches at
    or above each threshold (what the DOM check would report with such a test)."""
    import cv2

    rep = json.loads((root / "ortho" / "dom_report.json").read_text())
    P = rep["patches"]
    d = np.hypot([p["de_m"] for p in P], [p["dn_m"] for p in P]) / rep["gsd_m"]
    ratio = np.full(len(P), np.nan)
    half = patch_px // 2
    with rasterio.open(rep["dom"]) as ds:
        for k, p in enumerate(P):
            r0, c0 = int(round(p["row_px"] - (patch_px - 1) / 2.0)), int(round(p["col_px"] - (patch_px - 1) / 2.0))
            a = ds.read(1, window=rasterio.windows.Window(c0, r0, patch_px, patch_px)).astype(np.float32)
            if a.shape != (patch_px, patch_px):
                continue
            gx, gy = cv2.Sobel(a, cv2.CV_32F, 1, 0), cv2.Sobel(a, cv2.CV_32F, 0, 1)
            j = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]], float)
            w = np.linalg.eigvalsh(j)
            ratio[k] = w[0] / w[1] if w[1] > 0 else 0.0
    ok = np.isfinite(ratio)
    bands = [0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 1.01]
    out = dict(patch_px=patch_px, read=int(ok.sum()), bands=[], at_or_above={})
    for lo, hi in zip(bands[:-1], bands[1:]):
        s = ok & (ratio >= lo) & (ratio < hi)
        out["bands"].append(dict(ratio_from=lo, ratio_to=min(hi, 1.0), **_rms(d[s]),
                                 above_3_gsd_pct=round(100.0 * float((d[s] > 3).mean()), 2) if s.any() else None))
    for t in (0.05, 0.1, 0.15, 0.2, 0.3):
        s = ok & (ratio >= t)
        out["at_or_above"][str(t)] = dict(kept_pct=round(100.0 * float(s.sum()) / max(int(ok.sum()), 1), 1), **_rms(d[s]),
                                          above_3_gsd_pct=round(100.0 * float((d[s] > 3).mean()), 2))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("block", type=Path, help="the simulated block (its truth/classes.tif)")
    ap.add_argument("--key", required=True)
    ap.add_argument("--anisotropy-only", action="store_true", help="add the texture-shape split to the key's entry")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "dmc_dom_measure.json")
    args = ap.parse_args(argv)
    classes = Classes(args.block / "truth" / "classes.tif")
    t0 = time.process_time()
    if args.anisotropy_only:  # added to the run's entry
        entry = dict(read_results(args.out).get(args.key, {}), dom_check_anisotropy=anisotropy(args.run_dir))
    else:
        entry = dict(run_dir=str(args.run_dir), dom_check_gsd=dom_patches(args.run_dir, classes),
                     seams_px=seam_patches(args.run_dir, classes), dom_check_anisotropy=anisotropy(args.run_dir),
                     measured_utc=time.strftime("%Y-%m-%d %H:%M", time.gmtime()))
    entry["cpu_s" if not args.anisotropy_only else "anisotropy_cpu_s"] = round(time.process_time() - t0, 1)
    store_result(args.out, entry, key=args.key)
    print(json.dumps(entry, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
