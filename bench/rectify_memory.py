"""Peak memory of ``ortho rectify`` on one full-size DMC frame of 16-bit samples (issue 41): the frame read
whole (decoded in memory) against read by windows as the tiles sample it (``ortho.rectify.FrameFile``, what
``ortho rectify`` does for frames decoded larger than ``WINDOWED_FRAME_BYTES``).

A 13,824 x 7,680 px RGB frame of 16-bit samples (12-bit range; a smooth pattern with noise), tiled 512 px
ZSTD as vendors deliver it; f 120 mm, 12 um pixels, 1,000 m above a smooth DEM, slight tilt; output 0.1 m
(``ortho.block.rectify_frame_to_file``: tiled ZSTD-1 + predictor GeoTIFF with its mask). Each way in its
own process: wall, CPU seconds, peak RSS (ru_maxrss). The two frame orthos are compared pixel for pixel.
Writes bench/results/rectify_memory.json.

Usage: python bench/rectify_memory.py [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
W, H = 13824, 7680


def make_frame(path: Path) -> None:
    import rasterio
    from rasterio.windows import Window

    rng = np.random.default_rng(41)
    with rasterio.open(path, "w", driver="GTiff", width=W, height=H, count=3, dtype="uint16", tiled=True,
                       blockxsize=512, blockysize=512, compress="zstd", predictor=2, num_threads="ALL_CPUS") as dst:
        x = np.arange(W, dtype=np.float32)
        for y0 in range(0, H, 512):
            y = np.arange(y0, min(H, y0 + 512), dtype=np.float32)[:, None]
            base = 2000 + 900 * np.sin(x / 97.0) * np.cos(y / 61.0) + 400 * np.sin((x + 2 * y) / 23.0)
            a = np.stack([base + 300 * b for b in range(3)])
            a += rng.normal(0, 20, a.shape).astype(np.float32)
            dst.write(np.clip(a, 0, 4095).astype(np.uint16), window=Window(0, y0, W, len(y)))


def child(way: str, frame: Path, out: Path) -> None:
    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.rotation import rotation_matrix_opk
    from aerotri.core.gdal_cache import stage_block_cache
    from ortho.block import RECTIFY_CACHE_BYTES, rectify_frame_to_file
    from ortho.grid import GridToProject, parse_crs
    from ortho.rectify import FrameFile, frame_grid
    from ortho.synthetic import smooth_dem

    crs = parse_crs("EPSG:32649")
    cam = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=W, height=H)
    C = np.array([500000.0, 3000000.0, 1100.0])
    R = rotation_matrix_opk(0.8, -0.5, 2.0)
    dem = smooth_dem((C[0] - 900, C[1] - 600, C[0] + 900, C[1] + 600), 1.0)
    grid = frame_grid(cam, C, R, dem, 0.1, crs, to_project=GridToProject(crs, crs))
    t0, c0 = time.perf_counter(), time.process_time()
    if way == "whole":
        import rasterio

        with rasterio.open(frame) as ds:
            image = np.ascontiguousarray(np.moveaxis(ds.read(), 0, -1))
    else:
        image = FrameFile(frame)
    with stage_block_cache(RECTIFY_CACHE_BYTES):  # as ``ortho rectify`` sets it for the stage
        valid = rectify_frame_to_file(out, image, [1, 2, 3], cam, C, R, heights=dem, grid=grid,
                                      interpolation="bilinear", to_project=GridToProject(crs, crs))
    import resource

    print(json.dumps({"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(time.process_time() - c0, 2),
                      "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                      "ortho_px": [grid.width, grid.height], "valid_fraction": round(valid, 4)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=REPO / "out" / "rectify_memory")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "rectify_memory.json")
    ap.add_argument("--child", nargs=3)
    a = ap.parse_args()
    if a.child:
        child(a.child[0], Path(a.child[1]), Path(a.child[2]))
        return
    a.work.mkdir(parents=True, exist_ok=True)
    frame = a.work / "dmc16.tif"
    if not frame.exists():
        make_frame(frame)
    res = {"frame": {"px": [W, H], "bands": 3, "dtype": "uint16", "decoded_mb": round(W * H * 3 * 2 / 2 ** 20, 1),
                     "file_mb": round(frame.stat().st_size / 2 ** 20, 1)}}
    for way in ("whole", "windows"):
        p = subprocess.run([sys.executable, __file__, "--child", way, str(frame), str(a.work / f"{way}.tif")],
                           capture_output=True, text=True, check=True)
        res[way] = json.loads(p.stdout.strip().splitlines()[-1])
        print(way, res[way], flush=True)
    import rasterio

    with rasterio.open(a.work / "whole.tif") as x, rasterio.open(a.work / "windows.tif") as y:
        res["identical"] = bool(np.array_equal(x.read(), y.read()) and np.array_equal(x.read_masks(1), y.read_masks(1)))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
