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
(truth/roof_corners.csv) that lie in it, ``ortho.check.measure_roof_patches`` (patches of max(24 m, 48 px),
masked NCC over the valid cells, patches at least 80 % valid; the JSON's top-level run: a phase correlation), pooled
over the frames: RMS and median plan displacement (m, GSD) over the corners each way measured, and over the corner
patches every way measured (the same patches). Also: the share of each frame's cells that orthority fills on the DSM
and our true ortho leaves out as occluded (there orthority shows the surface in front: the roof mapped a second
time).

A full-size DMC frame (``--frames``, the simulator's exact DEM and DSM and true orientation; the project is read
only: its images and truth are linked, not copied) adds the open ground (``--ndsm``: ``ortho.check.
check_against_reference`` against truth/ortho.tif where the nDSM is below 0.5 m) with the displacements fitted as a
radial scale about the frame's nadir (``bench/eval_ortho_earth.py``'s ``radial_fit``, ppm): our rectifier maps the
ground through ``CameraOnEarth``; a rectifier that takes easting, northing and height as a Cartesian frame shows about
400 ppm outwards at the presets' origin.

Usage: python bench/eval_true_ortho_orthority.py [--project /work/ref/demo_chain/project] [--work DIR]
       [--frames ID,..] [--eo REL] [--camera REL] [--dem REL] [--dsm REL] [--res-m M] [--ndsm PATH] [--key KEY]
(REL: relative to the project, or an absolute path: e.g. the orientation and LiDAR rasters of a chain run)
e.g. the DMC frame: --project /work/bench_blocks/dmc_block_subset_2x2 --frames s01_002 --eo truth/eo.txt
--camera truth/camera.toml --dem truth/dem.tif --dsm truth/dsm.tif --res-m 0.1 --ndsm NDSM --key dmc_frame_s01_002
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from bench.results_json import git_commit, store_result  # noqa: E402

WAYS = ("orthority_dem", "orthority_dsm", "ours_conventional_dem", "ours_conventional_dsm", "ours_true_dsm")


def copy_project(src: Path, dst: Path, dem: str, dsm: str) -> None:
    """A project to rectify in: its small files copied, its images and truth linked (read only), the DEM and DSM
    (paths relative to ``src``) linked as lidar_out/dem.tif and dsm.tif."""
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in ("at", "camera.toml", "project.toml"):
        p = src / name
        if p.exists():
            (shutil.copytree if p.is_dir() else shutil.copy2)(p, dst / name)
    for name in ("images", "truth"):
        (dst / name).symlink_to((src / name).resolve(), target_is_directory=True)
    (dst / "lidar_out").mkdir()
    for name, rel in (("dem.tif", dem), ("dsm.tif", dsm)):
        (dst / "lidar_out" / name).symlink_to((src / rel).resolve())


def ours(project: Path, way: str, out: Path, eo=None, camera=None, frames=None, res_m=None) -> tuple[dict, float]:
    """``ortho rectify`` of the frames (``way``: on the DEM, on the DSM, true ortho on the DSM) -> {image id: frame
    ortho}, res."""
    from ortho.block import read_index, rectify_block
    from ortho.settings import RectifySettings

    dem, dsm = str(project / "lidar_out" / "dem.tif"), str(project / "lidar_out" / "dsm.tif")
    settings = {"ours_conventional_dem": RectifySettings(dem=dem, res_m=res_m),
                "ours_conventional_dsm": RectifySettings(dem=dsm, res_m=res_m),
                "ours_true_dsm": RectifySettings(dem=dem, res_m=res_m, true_ortho=True, dsm=dsm)}[way]
    res_m = rectify_block(project, settings, eo_path=eo, camera_path=camera, frames=frames).res_m
    index = read_index(project)
    if out.exists():
        shutil.rmtree(out)
    shutil.move(project / "ortho" / "frames", out)
    return {e.image_id: out / e.file for e in index.frames}, float(res_m)


def orthority_orthos(project: Path, surface: Path, res_m: float, out: Path, eo=None, camera=None,
                     frames=None) -> dict:
    """orthority's ortho of the frames on ``surface``, from our export of the block's orientation and camera."""
    import orthority as oty

    from aerotri.exchange.orthority import texts
    from ortho.block import load_block

    block = load_block(project, eo, camera, frames)
    out.mkdir(parents=True, exist_ok=True)
    for f in texts(block.eo, block.camera, block.project):
        (out / f.path).parent.mkdir(parents=True, exist_ok=True)
        (out / f.path).write_text(f.content)
    made = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cameras = oty.FrameCameras(out / "orthority" / "int_param.yaml", out / "orthority" / "ext_param.csv")
        for iid, src in block.images.pairs():
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


def open_ground(orthos: dict, reference: Path, ndsm: Path, nadir_of: dict) -> dict:
    """Each frame ortho against the reference where the nDSM is below 0.5 m (the DOM check's open-ground row),
    pooled: statistics in GSD and the radial scale about each frame's nadir (ppm, > 0: moved outwards)."""
    from eval_ortho_earth import radial_fit, stats

    from ortho.check import check_against_reference

    rows = []
    for iid, path in sorted(orthos.items()):
        import rasterio

        with rasterio.open(path) as ds:
            t = ds.transform
        pd, _ = check_against_reference(path, reference, ndsm)
        x, y = t.c + (pd.col_px + 0.5) * t.a, t.f + (pd.row_px + 0.5) * t.e
        rows.append((pd.dx_px, pd.dy_px, x, y, np.tile(nadir_of[iid], (len(x), 1)), pd.res_m))
    dx, dy, x, y, nadir = (np.concatenate([r[k] for r in rows]) for k in range(5))
    res_m = rows[0][5]
    return {**stats(dx, dy), "radial_fit": radial_fit(x, y, dx * res_m, -dy * res_m, nadir)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_orthority")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_orthority.json")
    ap.add_argument("--frames", default=None, help="image ids, comma-separated (default: every frame)")
    ap.add_argument("--eo", default=None, help="orientations relative to the project (default: the adjusted, at/)")
    ap.add_argument("--camera", default=None, help="the camera of --eo relative to the project")
    ap.add_argument("--dem", default="lidar_out/dem.tif", help="DEM relative to the project")
    ap.add_argument("--dsm", default="lidar_out/dsm.tif", help="DSM relative to the project")
    ap.add_argument("--res-m", type=float, default=None, help="cell (default: ortho rectify's, the nadir GSD)")
    ap.add_argument("--ndsm", type=Path, default=None, help="nDSM: also measure the open ground and its radial scale")
    ap.add_argument("--key", default=None, help="write this run under KEY of --out, every other key kept "
                                                "(default: the top level)")
    args = ap.parse_args()
    try:
        import orthority  # noqa: F401
    except ImportError:
        raise SystemExit("orthority is not installed (make bench installs it)") from None
    from importlib.metadata import version

    from aerotri.geom.eo import read_eo
    from ortho.check import read_roof_corners

    t0, cpu0 = time.perf_counter(), time.process_time()
    p = args.work / "project"
    copy_project(args.project, p, args.dem, args.dsm)
    eo = p / args.eo if args.eo else None
    camera = p / args.camera if args.camera else None
    frames = args.frames.split(",") if args.frames else None
    orthos, seconds, cpu = {}, {}, {}
    res_m = args.res_m
    for way in ("ours_conventional_dem", "ours_conventional_dsm", "ours_true_dsm"):
        t, c = time.perf_counter(), time.process_time()
        orthos[way], res_m = ours(p, way, args.work / way, eo, camera, frames, res_m)
        seconds[way], cpu[way] = time.perf_counter() - t, time.process_time() - c
    for way, surface in (("orthority_dem", "dem.tif"), ("orthority_dsm", "dsm.tif")):
        t, c = time.perf_counter(), time.process_time()
        orthos[way] = orthority_orthos(p, p / "lidar_out" / surface, res_m, args.work / way, eo, camera, frames)
        seconds[way], cpu[way] = time.perf_counter() - t, time.process_time() - c
    xs, ys = read_roof_corners(p / "truth" / "roof_corners.csv")
    measured = {way: roofs_of(orthos[way], p / "truth" / "ortho.tif", xs, ys) for way in WAYS}
    common = set.intersection(*(set(m["patches"]) for m in measured.values()))
    out = {"project": str(args.project), "frames": len(orthos["ours_true_dsm"]), "gsd_m": res_m,
           "roof_corners": int(len(xs)), "orthority": version("orthority"),
           "eo": args.eo or "at/eo.txt", "camera": args.camera or "(the adjusted camera)", "dem": args.dem,
           "dsm": args.dsm, "ways": {}}
    if frames:
        out["frame_ids"] = frames
    nadir_of = None
    if args.ndsm:
        e = read_eo(eo if eo else p / "at" / "eo.txt")
        nadir_of = {iid: e.centre_m[e.row(iid), :2] for iid in orthos["ours_true_dsm"]}
    for way in WAYS:
        m = measured[way]
        d_all = np.array(list(m["patches"].values())).reshape(-1, 2)
        d_common = np.array([m["patches"][k] for k in sorted(common)]).reshape(-1, 2)
        out["ways"][way] = {"wall_s": round(seconds[way], 2), "cpu_s": round(cpu[way], 2),
                            "corner_patches_in_frames": m["corner_patches"],
                            "not_measured": m["not_measured"], "roofs_measured": statistics(d_all, res_m),
                            "roofs_common_patches": statistics(d_common, res_m)}
        if args.ndsm:
            out["ways"][way]["open_ground"] = open_ground(orthos[way], p / "truth" / "ortho.tif", args.ndsm,
                                                          nadir_of)
        print(way, json.dumps(out["ways"][way]), flush=True)
    out["common_patches"] = len(common)
    out["orthority_dsm_fills_occluded"] = filled_where_occluded(orthos["orthority_dsm"], orthos["ours_true_dsm"],
                                                                orthos["ours_conventional_dsm"])
    print(json.dumps(out["orthority_dsm_fills_occluded"]), flush=True)
    out["command"] = "python bench/eval_true_ortho_orthority.py " + " ".join(sys.argv[1:])
    out["cpu_s"], out["wall_s"] = round(time.process_time() - cpu0, 1), round(time.perf_counter() - t0, 1)
    out["load_avg_1min_at_end"] = os.getloadavg()[0]
    out["commit"] = git_commit(REPO)
    store_result(args.out, out, key=args.key)  # no key: the top level, the other keys kept


if __name__ == "__main__":
    main()
