"""JPEG-compressed TIFF frames: which decoders agree, how the NGI frame orthos change, what GDAL costs (jpeg-decode).

Review 28 found that a JPEG-YCbCr TIFF frame decoded whole (OpenCV) and by windows (GDAL) gave other pixels. Since
jpeg-decode every reader decodes JPEG-compressed TIFFs through GDAL (``aerotri.geom.images._opencv_reads``). This
script measures, on real frames and without writing into the repository but this JSON:

1. ``decoders``: each NGI DMC frame (../shared/data/ngi_dmc, JPEG-YCbCr 4:2:0, 256 px tiles) decoded by OpenCV
   (libjpeg-turbo, read whole: main's ``read_native``), GDAL whole and by windows (rasterio's wheel: IJG libjpeg 9),
   Pillow (libtiff + libjpeg-turbo) and each tile's JPEG stream (JPEGTables + tile) decoded as a plain JPEG by
   OpenCV: the share of pixels that differ and the largest difference of every pair against GDAL;
2. ``why``: frame 0182 re-encoded as grey, as photometric-RGB JPEG (no chroma subsampling), as plain JPEG 4:4:4 and
   4:2:0: GDAL against OpenCV (the IDCT and colour conversion agree; 4:2:0 chroma upsampling does not);
3. ``ngi_orthos``: ``ortho rectify`` of the NGI block (orthority's orientation, 5 m) with OpenCV's decode (main),
   GDAL whole (now) and GDAL by windows (``WINDOWED_FRAME_BYTES`` = 0): cells that differ per frame;
4. ``cost``: CPU seconds and peak RSS (VmHWM; and its rise over the imports) of decoding one frame whole, each in
   its own process, OpenCV vs ``read_native`` (GDAL), on a Brighton-sized frame (4000 x 2250, DJI_0018.JPG as a
   JPEG-YCbCr tiled TIFF, quality 90) and a full-size DMC-sized one (13824 x 7680, the same picture resized; frames
   this large are read by windows in rectify anyway): the best of ``--repeat`` runs.

    AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/jpeg_decode.py \\
        --scratch /work/tmp/jpeg-decode/bench

Writes bench/results/jpeg_decode.json.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import rasterio
from rasterio.windows import Window

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
RESULT = REPO / "bench" / "results" / "jpeg_decode.json"
warnings.filterwarnings("ignore")
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _diff(a: np.ndarray, b: np.ndarray) -> dict:
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    d = d.max(-1) if d.ndim == 3 else d
    return {"pixels_differ_pct": round(100.0 * float((d > 0).mean()), 2), "max_dn": int(d.max()),
            "mean_dn": round(float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean()), 3)}


def _gdal_windows(path) -> np.ndarray:
    with rasterio.open(path) as ds:
        out = np.empty((ds.height, ds.width, ds.count), np.uint8)
        for r in range(0, ds.height, 100):  # windows that cut the 256 px tiles
            for c in range(0, ds.width, 77):
                w = Window(c, r, min(77, ds.width - c), min(100, ds.height - r))
                out[r:r + w.height, c:c + w.width] = np.moveaxis(ds.read(window=w), 0, -1)
    return out


def _tiles_as_plain_jpeg(path) -> np.ndarray:
    """Each tile's JPEG stream (the JPEGTables tag's tables + the tile) decoded by cv2.imdecode."""
    from PIL import Image

    with Image.open(path) as im:
        t, (W, H) = im.tag_v2, im.size
        tw, th, offsets, counts, tables = t[322], t[323], t[324], t[325], t.get(347)
    data = Path(path).read_bytes()
    out = np.zeros((H, W, 3), np.uint8)
    nx = -(-W // tw)
    for i, (o, n) in enumerate(zip(offsets, counts)):
        tile = data[o:o + n]
        stream = tables[:-2] + tile[2:] if tables else tile  # the tables end with EOI, the tile starts with SOI
        a = cv2.imdecode(np.frombuffer(stream, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
        r, c = (i // nx) * th, (i % nx) * tw
        h, w = min(th, H - r), min(tw, W - c)
        out[r:r + h, c:c + w] = a[:h, :w]
    return out


def decoders(data: Path) -> dict:
    from PIL import Image

    res = {}
    for f in sorted(data.glob("*_RGB.tif")):
        with rasterio.open(f) as ds:
            gdal = np.moveaxis(ds.read(), 0, -1)
        with Image.open(f) as im:
            pil = np.asarray(im.convert("RGB"))
        res[f.stem] = {"opencv_whole_vs_gdal": _diff(cv2.imread(str(f))[:, :, ::-1], gdal),
                       "gdal_windows_vs_gdal": _diff(_gdal_windows(f), gdal),
                       "pillow_vs_gdal": _diff(pil, gdal),
                       "tiles_as_plain_jpeg_opencv_vs_gdal": _diff(_tiles_as_plain_jpeg(f), gdal),
                       "pillow_vs_opencv_whole": _diff(pil, cv2.imread(str(f))[:, :, ::-1])}
    return res


def why(frame: Path, scratch: Path) -> dict:
    with rasterio.open(frame) as ds:
        a = ds.read()
    prof = dict(driver="GTiff", width=a.shape[2], height=a.shape[1], dtype="uint8", tiled=True, blockxsize=256,
                blockysize=256, compress="jpeg")
    res = {}
    for tag, kw, arr in (("tiff_grey", dict(count=1), a[:1]),
                         ("tiff_photometric_rgb", dict(count=3, photometric="rgb"), a),
                         ("tiff_ycbcr_420", dict(count=3, photometric="ycbcr"), a)):
        p = scratch / f"{tag}.tif"
        with rasterio.open(p, "w", **prof, **kw) as o:
            o.write(arr)
        with rasterio.open(p) as ds:
            g = np.moveaxis(ds.read(), 0, -1)
        c = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        c = c[:, :, None] if c.ndim == 2 else c[:, :, ::-1]
        res[tag] = _diff(c, g)
    rgb = np.moveaxis(a, 0, -1)
    for tag, samp in (("plain_jpeg_444", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444),
                      ("plain_jpeg_420", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420)):
        p = scratch / f"{tag}.jpg"
        cv2.imwrite(str(p), rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 75, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, samp])
        with rasterio.open(p) as ds:
            g = np.moveaxis(ds.read(), 0, -1)
        res[tag] = _diff(cv2.imread(str(p))[:, :, ::-1], g)
    return res


def ngi_orthos(data: Path, scratch: Path) -> dict:
    from click.testing import CliRunner
    from ngi_common import load_ngi

    import aerotri.geom.images as images
    import ortho.block as B
    from aerotri.cli import main as aerotri_main
    from ortho.cli import main as ortho_main

    ngi = load_ngi()
    base = scratch / "ngi"
    shutil.rmtree(base, ignore_errors=True)
    src = ngi.build_ngi_project(data, base / "src")
    fmt = data / "formats"
    r = CliRunner().invoke(aerotri_main, ["import", str(src), "--format", "orthority", str(fmt / "ngi_int_param.yaml"),
                                          str(fmt / "ngi_ext_param.geojson")])
    assert r.exit_code == 0, r.output

    def run(tag, opencv=False, windows=False) -> Path:
        root = base / tag
        shutil.copytree(src, root, symlinks=True)
        reads, limit = images._opencv_reads, B.WINDOWED_FRAME_BYTES
        if opencv:
            images._opencv_reads = lambda path: True  # main's rule for 3-band RGB pixel-interleaved TIFFs
        if windows:
            B.WINDOWED_FRAME_BYTES = 0
        try:
            r = CliRunner().invoke(ortho_main, ["rectify", str(root), "--eo", str(root / "imported" / "eo.txt"),
                                                "--dem", str(data / "dem.tif"), "--res-m", "5"])
            assert r.exit_code == 0, r.output
        finally:
            images._opencv_reads, B.WINDOWED_FRAME_BYTES = reads, limit
        return root / "ortho" / "frames"

    runs = {"opencv_whole_main": run("opencv", opencv=True), "gdal_whole_now": run("whole"),
            "gdal_windows": run("windows", windows=True)}
    res = {}
    for a, b in (("opencv_whole_main", "gdal_windows"), ("gdal_whole_now", "gdal_windows")):
        per = {}
        for f in sorted(runs[a].glob("*.tif")):
            with rasterio.open(f) as x, rasterio.open(runs[b] / f.name) as y:
                A, Bb, ma, mb = x.read(), y.read(), x.read_masks(1) > 0, y.read_masks(1) > 0
            v = ma & mb
            d = np.abs(A.astype(np.int16) - Bb.astype(np.int16))
            per[f.stem] = {"mask_cells_differ": int((ma != mb).sum()), "valid_cells": int(v.sum()),
                           "cells_differ_pct": round(100.0 * float((d.max(0)[v] > 0).mean()), 2),
                           "max_dn": int(d.max(0)[v].max()), "mean_dn": round(float(d[:, v].mean()), 3)}
        res[f"{a}_vs_{b}"] = per
    return res


# peak RSS from VmHWM (this process's memory since exec: ru_maxrss would carry the forking parent's over exec)
_COST = """
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import cv2
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
from aerotri.geom.images import read_native
def hwm_mb():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")) / 1024
path, how = sys.argv[1], sys.argv[2]
base = hwm_mb()
c0 = time.process_time()
img = cv2.imread(path, cv2.IMREAD_UNCHANGED) if how == "opencv" else read_native(path)[0]
print(json.dumps({"cpu_s": time.process_time() - c0, "peak_rss_mb": hwm_mb(), "peak_over_imports_mb": hwm_mb() - base,
                  "frame_mb": img.nbytes / 2**20}))
"""


def cost(brighton: Path, scratch: Path, repeat: int) -> dict:
    img = cv2.imread(str(brighton))[:, :, ::-1]
    prof = dict(driver="GTiff", dtype="uint8", count=3, compress="jpeg", photometric="ycbcr", tiled=True,
                blockxsize=256, blockysize=256, jpeg_quality=90)
    frames = {"brighton_4000x2250": img,
              "dmc_13824x7680": cv2.resize(img, (13824, 7680), interpolation=cv2.INTER_LINEAR)}
    res = {}
    for name, a in frames.items():
        p = scratch / f"{name}.tif"
        with rasterio.open(p, "w", width=a.shape[1], height=a.shape[0], **prof) as o:
            o.write(np.moveaxis(a, -1, 0))
        del a
        res[name] = {}
        for how in ("opencv", "gdal_read_native"):
            env = {**os.environ, "PYTHONPATH": str(REPO)}
            runs = [json.loads(subprocess.run([sys.executable, "-c", _COST, str(p), how], check=True,
                                              capture_output=True, text=True, cwd=REPO, env=env).stdout)
                    for _ in range(repeat)]
            res[name][how] = {"cpu_s": round(min(r["cpu_s"] for r in runs), 3),
                              "peak_rss_mb": round(min(r["peak_rss_mb"] for r in runs), 1),
                              "peak_over_imports_mb": round(min(r["peak_over_imports_mb"] for r in runs), 1),
                              "frame_mb": round(runs[0]["frame_mb"], 1)}
        res[name]["cpu_ratio"] = round(res[name]["gdal_read_native"]["cpu_s"] / res[name]["opencv"]["cpu_s"], 2)
    frames.clear()
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path,
                    default=Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")))
    ap.add_argument("--scratch", type=Path, required=True)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    a.scratch.mkdir(parents=True, exist_ok=True)
    ngi = a.data / "ngi_dmc"
    if not (ngi / "dem.tif").is_file():
        sys.exit(f"{ngi}: NGI DMC frames not found (give --data or AEROTRI_SHARED_DATA)")
    out = {"libraries": {"rasterio": rasterio.__version__, "gdal": rasterio.__gdal_version__, "opencv": cv2.__version__,
                         "opencv_jpeg": "libjpeg-turbo (bundled)",
                         "rasterio_jpeg": "IJG libjpeg 9 (rasterio.libs/libjpeg*.so.9)"},
           "decoders": decoders(ngi), "why": why(ngi / "3324c_2015_1004_05_0182_RGB.tif", a.scratch),
           "ngi_orthos": ngi_orthos(ngi, a.scratch),
           "cost": cost(a.data / "brighton_beach" / "images" / "DJI_0018.JPG", a.scratch, a.repeat),
           "load_average_1min": os.getloadavg()[0]}
    RESULT.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
