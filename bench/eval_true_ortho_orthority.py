"""Our true ortho on the LiDAR DSM against orthority's conventional ortho of the same frames (issue 42)
-> bench/results/true_ortho_orthority.json.

orthority (the peer, a bench extra: ``make bench`` installs it) rectifies on one surface and has no occlusion handling.
On a copy of the demo (``/work/ref/demo_chain/project``), every frame, the same orientation (at/eo.txt) and camera
(the block's, as ``ortho rectify`` reads it), exported to orthority's own files by ``aerotri.exchange.orthority``,
the same 0.4 m cells on whole multiples of the cell size, bilinear resampling:

- ``orthority_dem``: orthority's ortho on lidar_out/dem.tif (what it is made for);
- ``orthority_dsm``: orthority's ortho on lidar_out/dsm.tif (roofs rectified at their height, occluded ground filled
  with whatever surface is in front of it);
- ``ours_conventional_dem``: ``ortho rectify`` on the DEM;
- ``ours_conventional_dsm``: ``ortho rectify --dem lidar_out/dsm.tif`` (what orthority_dsm is, made by us);
- ``ours_true_dsm``: ``ortho rectify --true-ortho --dsm lidar_out/dsm.tif`` (occluded cells masked).

Roofs: every frame ortho against the simulator's true orthophoto (truth/ortho.tif) at the simulator's roof corners
(truth/roof_corners.csv) that lie in it, ``ortho.check.measure_roof_patches`` (24 m patches, phase correlation,
patches at least 80 % valid), pooled over the frames: RMS and median plan displacement (m, GSD) over the corners each
way measured, and over the corner patches every way measured (the same patches). Also: the share of each frame's
cells that orthority fills on the DSM and our true ortho leaves out as occluded (there orthority shows the surface in
front: the roof mapped a second time).

Usage: python bench/eval_true_ortho_orthority.py [--project /work/ref/demo_chain/project] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

WAYS = ("orthority_dem", "orthority_dsm", "ours_conventional_dem", "ours_conventional_dsm", "ours_true_dsm")


def copy_project(src: Path, dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in ("at", "camera.toml", "images", "project.toml", "truth"):
        p = src / name
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, dst / name)
    (dst / "lidar_out").mkdir()
    for name in ("dem.tif", "dsm.tif"):
        shutil.copy2(src / "lidar_out" / name, dst / "lidar_out" / name)


def ours(project: Path, way: str, out: Path) -> tuple[dict, float]:
    """``ortho rectify`` of every frame (``way``: on the DEM, on the DSM, true ortho on the DSM) -> {image id: frame
    ortho}, res."""
    from ortho.block import read_index, rectify_block
    from ortho.settings import RectifySettings

    dsm = str(project / "lidar_out" / "dsm.tif")
    settings = {"ours_conventional_dem": RectifySettings(), "ours_conventional_dsm": RectifySettings(dem=dsm),
                "ours_true_dsm": RectifySettings(true_ortho=True, dsm=dsm)}[way]
    res_m = rectify_block(project, settings).res_m
    index = read_index(project)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(project / "ortho" / "frames", out)
    return {e.image_id: out / e.file for e in index.frames}, float(res_m)


def orthority_orthos(project: Path, surface: Path, res_m: float, out: Path) -> dict:
    """orthority's ortho of every frame on ``surface``, from our export of the block's orientation and camera."""
    import orthority as oty

    from aerotri.exchange.orthority import texts
    from ortho.block import load_block

    block = load_block(project)
    out.mkdir(parents=True, exist_ok=True)
    for f in texts(block.eo, block.camera, block.project):
        (out / f.path).parent.mkdir(parents=True, exist_ok=True)
        (out / f.path).write_text(f.content)
    made = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cameras = oty.FrameCameras(out / "orthority" / "int_param.yaml", out / "orthority" / "ext_param.csv")
        for iid, src in block.images.items():
            dst = out / f"{iid}.tif"
            ortho = oty.Ortho(src, surface, cameras.get(iid), crs=cameras.crs)
            ortho.process(dst, resolution=(res_m, res_m), interp="bilinear", dem_interp="bilinear", compress="deflate",
                          write_mask=True, build_ovw=False, overwrite=True, aligned_pixels=True)
            made[iid] = dst
    return made


def roofs_of(orthos: dict, truth: Path, xs: np.ndarray, ys: np.ndarray) -> dict:
    """The roof-corner patches of every frame ortho that holds them: {(frame, corner index): (de, dn)}, counts."""
    import rasterio

    from ortho.check import measure_roof_patches

    found, corners, not_measured = {}, 0, 0
    for iid, path in sorted(orthos.items()):
        with rasterio.open(path) as ds:
            b = ds.bounds
        inside = np.flatnonzero((xs > b.left) & (xs < b.right) & (ys > b.bottom) & (ys < b.top))
        if not len(inside):
            continue
        m = measure_roof_patches(path, truth, xs[inside], ys[inside])
        corners += m.corners
        not_measured += m.outside_or_invalid + m.weak
        key = {(round(float(x), 3), round(float(y), 3)): int(k) for k, x, y in zip(inside, xs[inside], ys[inside])}
        for x, y, de, dn in zip(m.x_m, m.y_m, m.de_m, m.dn_m):
            found[(iid, key[(round(float(x), 3), round(float(y), 3))])] = (float(de), float(dn))
    return {"patches": found, "corner_patches": corners, "not_measured": not_measured}


def statistics(d: np.ndarray, res_m: float) -> dict:
    mag = np.hypot(d[:, 0], d[:, 1])
    if not len(mag):
        return {"count": 0}
    return {"count": int(len(mag)), "rms_xy_m": round(float(np.sqrt(np.mean(mag ** 2))), 4),
            "rms_xy_gsd": round(float(np.sqrt(np.mean(mag ** 2)) / res_m), 3),
            "median_xy_m": round(float(np.median(mag)), 4), "median_xy_gsd": round(float(np.median(mag) / res_m), 3),
            "p90_xy_m": round(float(np.percentile(mag, 90)), 4)}


def filled_where_occluded(orthority_dsm: dict, true_dsm: dict, conventional: dict) -> dict:
    """Cells orthority fills on the DSM that our true ortho leaves out as occluded (valid in our conventional ortho on
    the DSM, masked in our true ortho: the same grid), as a share of orthority's valid cells, over the frames."""
    import rasterio
    from rasterio.windows import from_bounds

    filled = valid = 0
    for iid, path in orthority_dsm.items():
        with rasterio.open(path) as o, rasterio.open(true_dsm[iid]) as t, rasterio.open(conventional[iid]) as c:
            ok_o = o.read_masks(1) > 0
            # our frame grids and orthority's are both on whole multiples of the cell size: read ours over its bounds
            w = from_bounds(*o.bounds, transform=t.transform).round_offsets().round_lengths()
            ok_t = t.read_masks(1, window=w, boundless=True) > 0
            ok_c = c.read_masks(1, window=from_bounds(*o.bounds, transform=c.transform).round_offsets().round_lengths(),
                                boundless=True) > 0
        occluded = ok_c & ~ok_t
        filled += int((ok_o & occluded).sum())
        valid += int(ok_o.sum())
    return {"orthority_valid_cells": valid, "cells_we_mask_as_occluded": filled, "share": filled / valid}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_orthority")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_orthority.json")
    args = ap.parse_args()
    try:
        import orthority  # noqa: F401
    except ImportError:
        raise SystemExit("orthority is not installed (make bench installs it)") from None
    from ortho.check import read_roof_corners

    p = args.work / "project"
    copy_project(args.project, p)
    orthos, seconds = {}, {}
    for way in ("ours_conventional_dem", "ours_conventional_dsm", "ours_true_dsm"):
        t = time.perf_counter()
        orthos[way], res_m = ours(p, way, args.work / way)
        seconds[way] = time.perf_counter() - t
    for way, surface in (("orthority_dem", "dem.tif"), ("orthority_dsm", "dsm.tif")):
        t = time.perf_counter()
        orthos[way] = orthority_orthos(p, p / "lidar_out" / surface, res_m, args.work / way)
        seconds[way] = time.perf_counter() - t
    xs, ys = read_roof_corners(p / "truth" / "roof_corners.csv")
    measured = {way: roofs_of(orthos[way], p / "truth" / "ortho.tif", xs, ys) for way in WAYS}
    common = set.intersection(*(set(m["patches"]) for m in measured.values()))
    out = {"project": str(args.project), "frames": len(orthos["ours_true_dsm"]), "gsd_m": res_m,
           "roof_corners": int(len(xs)), "orthority": __import__("orthority").__version__
           if hasattr(__import__("orthority"), "__version__") else None, "ways": {}}
    for way in WAYS:
        m = measured[way]
        d_all = np.array(list(m["patches"].values())).reshape(-1, 2)
        d_common = np.array([m["patches"][k] for k in sorted(common)]).reshape(-1, 2)
        out["ways"][way] = {"wall_s": round(seconds[way], 2), "corner_patches_in_frames": m["corner_patches"],
                            "not_measured": m["not_measured"], "roofs_measured": statistics(d_all, res_m),
                            "roofs_common_patches": statistics(d_common, res_m)}
        print(way, json.dumps(out["ways"][way]), flush=True)
    out["common_patches"] = len(common)
    out["orthority_dsm_fills_occluded"] = filled_where_occluded(orthos["orthority_dsm"], orthos["ours_true_dsm"],
                                                                orthos["ours_conventional_dsm"])
    print(json.dumps(out["orthority_dsm_fills_occluded"]), flush=True)
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(args.out, json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
