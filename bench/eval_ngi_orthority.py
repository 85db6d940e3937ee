"""The orthority exchange on real DMC frames (issue 22) -> bench/results/ngi_orthority.json + bench/results/ngi_orthority_mosaic.jpg.

Data: ../shared/data/ngi_dmc (4 Z/I DMC frames, the national AT's orientation in orthority's own files
``formats/ngi_int_param.yaml`` + ``ngi_ext_param.geojson`` / ``ngi_xyz_opk.csv`` + ``.prj``, a 24 m SUDEM).
orthority is a bench extra (``make bench`` installs it).

1. ``aerotri import PROJECT --format orthority`` of orthority's files into a fresh NGI project (images and
   DEM linked): the imported orientation against camera_pos_ori.txt (the national AT);
2. ``ortho rectify PROJECT --eo imported/eo.txt --dem dem.tif --res-m RES``: our frame orthos;
3. orthority's ``Ortho`` of each frame from its own files (same DEM, resolution, bilinear resampling,
   pixels aligned on whole multiples of the resolution, as ours): the offset of our ortho against
   orthority's by phase correlation over their common valid area (px of the ortho grid), and the grey-level
   difference there;
4. orthority reads OUR export (``orthority/int_param.yaml``, ``ext_param.csv`` + ``.prj`` written by
   ``aerotri.exchange.orthority.texts`` from the imported orientation) and rectifies: its orthos against
   orthority's own (offset, grey-level difference);
5. ``ortho mosaic PROJECT`` of our frames -> a PNG of the mosaic.

Usage: python bench/eval_ngi_orthority.py [--data ../shared/data/ngi_dmc] [--out out/ngi_orthority] [--res-m 5]
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


from ngi_common import load_ngi  # noqa: E402

ngi = load_ngi()


def _cli(main, args):
    """Run a click command in-process; SystemExit with its code on failure."""
    try:
        main.main(args=[str(a) for a in args], standalone_mode=False)
    except SystemExit as exc:
        if exc.code:
            raise


def _read(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read().astype(np.float64), ds.read_masks(1) > 0, ds.transform, ds.res[0]


def ortho_offset(ours: Path, theirs: Path) -> dict:
    """Offset (dx, dy px; + = our content lies right/below theirs) of two orthos of one frame on grids with
    the same cell size, by phase correlation (cv2.phaseCorrelate, Hann window) over the common valid
    rectangle; and the mean absolute grey-level difference (0-255) over the common valid cells."""
    import cv2

    a, ma, ta, res = _read(ours)
    b, mb, tb, res_b = _read(theirs)
    if abs(res - res_b) > 1e-9:
        raise SystemExit(f"{ours} / {theirs}: different cell sizes {res} / {res_b}")
    left, top = max(ta.c, tb.c), min(ta.f, tb.f)
    right = min(ta.c + a.shape[2] * res, tb.c + b.shape[2] * res)
    bottom = max(ta.f - a.shape[1] * res, tb.f - b.shape[1] * res)
    ca, ra = round((left - ta.c) / res), round((ta.f - top) / res)
    cb, rb = round((left - tb.c) / res), round((tb.f - top) / res)
    if abs((left - ta.c) / res - ca) > 1e-6 or abs((left - tb.c) / res - cb) > 1e-6:
        raise SystemExit(f"{ours} / {theirs}: grids not aligned on whole cells")
    w, h = round((right - left) / res), round((top - bottom) / res)
    ga, gb = a.mean(axis=0)[ra:ra + h, ca:ca + w], b.mean(axis=0)[rb:rb + h, cb:cb + w]
    both = ma[ra:ra + h, ca:ca + w] & mb[rb:rb + h, cb:cb + w]
    rows, cols = np.flatnonzero(both.any(axis=1)), np.flatnonzero(both.any(axis=0))
    sl = np.s_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    pa, pb, m = ga[sl], gb[sl], both[sl]
    pa = np.where(m, pa, pa[m].mean())
    pb = np.where(m, pb, pb[m].mean())
    win = cv2.createHanningWindow((pa.shape[1], pa.shape[0]), cv2.CV_64F)
    (dx, dy), response = cv2.phaseCorrelate(pb, pa, win)
    return {"dx_px": round(float(dx), 4), "dy_px": round(float(dy), 4), "offset_px": round(float(np.hypot(dx, dy)), 4),
            "response": round(float(response), 3), "common_cells": int(m.sum()),
            "mean_abs_grey_diff": round(float(np.abs(pa - pb)[m].mean()), 3),
            "valid_cells_ours": int(ma.sum()), "valid_cells_theirs": int(mb.sum())}


def orthority_orthos(int_param: Path, ext_param: Path, images: dict, dem: Path, res_m: float, out_dir: Path) -> dict:
    """orthority's ortho of every frame from an interior and an exterior parameter file -> {image id: file}."""
    import orthority as oty

    out_dir.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cameras = oty.FrameCameras(int_param, ext_param)
        out = {}
        for iid, src in images.items():
            dst = out_dir / f"{iid}.tif"
            ortho = oty.Ortho(src, dem, cameras.get(src), crs=cameras.crs)
            ortho.process(dst, resolution=(res_m, res_m), interp="bilinear", dem_interp="bilinear", compress="deflate",
                          write_mask=True, build_ovw=False, overwrite=True, aligned_pixels=True)
            out[iid] = dst
    return out


def projection_check(eo, camera, project, out: Path) -> dict:
    """orthority's projection (``FrameCamera.world_to_pixel``) of ground points through cameras read from OUR
    exported files against ours (``Camera.project``), for the NGI camera and for the same camera with a
    principal point offset and Brown distortion (k1 k2 k3 p1 p2), which the NGI files do not exercise: the
    largest difference in pixels over a grid of points at 300 m height seen by every frame."""
    import dataclasses
    import warnings

    import orthority as oty

    from aerotri.exchange.orthority import texts
    from aerotri.geom.camera import BrownCamera

    brown = BrownCamera(**{k: v for k, v in camera.to_dict().items() if k != "model"} | dict(
        ppx_mm=0.35, ppy_mm=-0.6, k1=-0.04, k2=0.012, k3=-0.003, p1=2e-4, p2=-3e-4))
    res = {}
    for name, cam in (("ngi_pinhole", camera), ("brown_with_pp", brown)):
        d = out / name
        for f in texts(eo, cam, project):
            (d / f.path).parent.mkdir(parents=True, exist_ok=True)
            (d / f.path).write_text(f.content)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cams = oty.FrameCameras(d / "orthority" / "int_param.yaml", d / "orthority" / "ext_param.csv")
        worst = 0.0
        for i, iid in enumerate(eo.image_id):
            c = eo.centre_m[i]
            g = np.stack(np.meshgrid(np.linspace(-1500, 1500, 9), np.linspace(-2500, 2500, 9)), -1).reshape(-1, 2)
            xyz = np.column_stack([c[0] + g[:, 0], c[1] + g[:, 1], np.full(len(g), 300.0)])
            x, y, _ = cam.project(xyz, c, eo.rotation(i))
            ok = cam.inside(x, y)
            ji = cams.get(iid).world_to_pixel(xyz[ok].T)
            worst = max(worst, float(np.abs(ji - np.vstack([x[ok], y[ok]])).max()))
        res[name] = {"max_abs_diff_px": worst}
    return res


def mosaic_png(mosaic: Path, png: Path, max_px: int = 1600) -> dict:
    import rasterio
    from PIL import Image

    with rasterio.open(mosaic) as ds:
        step = max(1, int(np.ceil(max(ds.width, ds.height) / max_px)))
        rgb = ds.read([1, 2, 3], out_shape=(3, ds.height // step, ds.width // step))
        mask = ds.read_masks(1, out_shape=(ds.height // step, ds.width // step)) > 0
        size = (ds.width, ds.height)
    img = np.moveaxis(rgb, 0, -1).astype(np.uint8)
    img[~mask] = 255
    png.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(png, quality=85)  # JPEG by the suffix: a photo, a fifth of the PNG
    return {"mosaic_px": list(size), "png": str(png.relative_to(REPO)) if png.is_relative_to(REPO) else str(png)}


def evaluate(data: Path, out: Path, res_m: float, png: Path) -> dict:
    from aerotri.cli import main as aerotri_main
    from aerotri.core.project import Project
    from aerotri.exchange.orthority import texts
    from aerotri.geom.camera import read_camera
    from aerotri.geom.eo import read_eo
    from ortho.cli import main as ortho_main

    fmt = data / "formats"
    if out.exists():
        shutil.rmtree(out)
    root = ngi.build_ngi_project(data, out / "project")
    (root / "camera.toml").unlink()
    (root / "gnss.txt").unlink()
    res = {"data": data.name, "res_m": res_m, "load_average_1min_start": round(os.getloadavg()[0], 2)}
    ref = ngi.read_reference(data)
    # 1. the import, from the GeoJSON (full precision) and from the OPK CSV (3 decimals) into a scratch copy
    _cli(aerotri_main, ["import", root, "--format", "orthority", fmt / "ngi_int_param.yaml", fmt / "ngi_ext_param.geojson"])
    project = Project.open(root)
    eo = read_eo(project.imported_eo_path)
    res["import_geojson_vs_camera_pos_ori"] = ngi.opk_differences(eo.image_id, eo.opk_deg, eo.centre_m, ref)
    csv_root = ngi.build_ngi_project(data, out / "project_csv")
    _cli(aerotri_main, ["import", csv_root, "--format", "orthority", "--force", fmt / "ngi_int_param.yaml",
                        fmt / "ngi_xyz_opk.csv"])
    eo_csv = read_eo(csv_root / "imported" / "eo.txt")
    res["import_csv_vs_camera_pos_ori"] = {k: v for k, v in ngi.opk_differences(
        eo_csv.image_id, eo_csv.opk_deg, eo_csv.centre_m, ref).items() if k != "per_image"}
    camera = read_camera(project.camera_path)
    res["imported_camera"] = camera.to_dict()
    # 2. ours
    t = time.perf_counter()
    _cli(ortho_main, ["rectify", root, "--eo", project.imported_eo_path, "--dem", data / ngi.DEM_FILE, "--res-m", res_m])
    res["ours_rectify_s"] = round(time.perf_counter() - t, 2)
    index = json.loads((project.frames_dir / "index.json").read_text())
    ours = {f["image_id"]: project.frames_dir / f["file"] for f in index["frames"]}
    images = {iid: data / f"{iid}.tif" for iid in eo.image_id}
    # 3. orthority on its own files
    t = time.perf_counter()
    theirs = orthority_orthos(fmt / "ngi_int_param.yaml", fmt / "ngi_ext_param.geojson", images, data / ngi.DEM_FILE,
                              res_m, out / "orthority_own")
    res["orthority_rectify_s"] = round(time.perf_counter() - t, 2)
    res["ours_vs_orthority"] = {iid: ortho_offset(ours[iid], theirs[iid]) for iid in eo.image_id}
    offs = np.array([v["offset_px"] for v in res["ours_vs_orthority"].values()])
    res["ours_vs_orthority_max_offset_px"] = float(offs.max())
    # 4. orthority on our export
    exp = out / "export"
    for f in texts(eo, camera, project):
        (exp / f.path).parent.mkdir(parents=True, exist_ok=True)
        (exp / f.path).write_text(f.content)
    from_ours = orthority_orthos(exp / "orthority" / "int_param.yaml", exp / "orthority" / "ext_param.csv", images,
                                 data / ngi.DEM_FILE, res_m, out / "orthority_from_our_export")
    res["orthority_from_our_export_vs_orthority_own"] = {iid: ortho_offset(from_ours[iid], theirs[iid])
                                                          for iid in eo.image_id}
    res["projection_orthority_from_our_files_vs_ours"] = projection_check(eo, camera, project, out / "projection")
    offs2 = np.array([v["offset_px"] for v in res["orthority_from_our_export_vs_orthority_own"].values()])
    res["orthority_from_our_export_max_offset_px"] = float(offs2.max())
    # 5. the mosaic
    _cli(ortho_main, ["mosaic", root])
    res["mosaic"] = mosaic_png(project.mosaic_path, png)
    res["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    res["pass_offset_le_0p2_px"] = bool(res["ours_vs_orthority_max_offset_px"] <= 0.2)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    shared = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
    ap.add_argument("--data", type=Path, default=shared / "ngi_dmc")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "ngi_orthority")
    ap.add_argument("--res-m", type=float, default=5.0, help="ortho cell size (m); orthority's config for this block: 5")
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "ngi_orthority.json")
    ap.add_argument("--png", type=Path, default=REPO / "bench" / "results" / "ngi_orthority_mosaic.jpg")
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        print(f"skip: {a.data} not found")
        return 0
    try:
        import orthority  # noqa: F401
    except ImportError:
        raise SystemExit("orthority is not installed (make bench installs it)") from None
    res = evaluate(a.data.resolve(), a.out.resolve(), a.res_m, a.png.resolve())
    a.results.write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps({k: v for k, v in res.items() if not isinstance(v, dict)}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
