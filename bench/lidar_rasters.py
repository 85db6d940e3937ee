"""Benchmark: rasters and roof corners of classified LiDAR strips by tiles, memory and equality.

Measures (same session; the 2-core machine is shared, so the load average is recorded beside
every timing and CPU seconds are given):
* peak memory against block size: on simulated blocks of side x side scene tiles of 200 m (10
  points/m^2, one strip per column of tiles, classes = truth; default sides 4 and 8: about 6.4 M
  and 25.6 M points, 4 x the area), as subprocesses with their peak RSS (process tree, polled every
  0.05 s with psutil):
  - ``lidarctl rasters`` by tiles (``--tile-px 512 --buffer-px 128``, the same tile at both sizes);
  - the whole-grid path beside it (``write_rasters`` of the strips concatenated in memory, the path
    before tiling: the memory it needed);
  - ``lidarctl corners`` by tiles (``--tile-m 250 --buffer-m 100``);
  - the whole-cloud corners beside it (``read_strips`` + ``find_roof_corners``);
* equality on the simulated demo block (``aerotri sim --preset demo``, its truth-class strips
  ``truth/lidar/*.las``): rasters whole vs by tiles (default tile size; per raster the largest
  difference, the cells that differ, nodata mismatches) and corners whole vs by tiles (default tile
  and buffer: the corners CSV, the roof planes, the strip margins).
Writes bench/results/lidar_rasters_bench.json (after every step).
Run: .venv/bin/python bench/lidar_rasters.py --demo /path/to/demo/truth/lidar [--work /tmp/rasters_bench]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import rasterio

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lidarctl import io, synthetic
from lidarctl.rasters import products as rasters

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import run_peak as _run_peak

TILE_M = 200.0
DENSITY = 10.0
RES_M = 0.5


def make_block(folder: Path, side: int) -> list[Path]:
    """side x side scene tiles of 200 m as ``side`` north-south strips (one LAS per column of tiles)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for c in range(side):
        path = folder / f"strip_{c:02d}.las"
        paths.append(path)
        if path.exists():
            continue
        parts = [synthetic.synthetic_scene(width_m=TILE_M, density_per_m2=DENSITY, n_buildings=8, n_trees=150,
                                           seed=100 * side + k, u0=TILE_M * c, v0=TILE_M * r)
                 for k, r in enumerate(range(side))]
        fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns")
        cloud = io.PointCloud(*[np.concatenate([getattr(p[0], f) for p in parts]) for f in fields],
                              np.concatenate([p[1] for p in parts]))
        synthetic.write_las(path.with_suffix(".part"), cloud, crs="EPSG:32632")
        os.replace(path.with_suffix(".part"), path)
    return paths


def run_peak(cmd: list[str], ok_codes=(0,)) -> dict:
    """``lidar_common.run_peak`` with the end of stdout only (the JSON stays small)."""
    r = _run_peak(cmd, ok_codes)
    r["stdout_tail"] = r.pop("stdout")[-300:]
    return r


def lidarctl(*args: str) -> list[str]:
    return [str(REPO / ".venv" / "bin" / "lidarctl"), *args]


def worker(kind: str, paths: list[Path], out: Path) -> None:
    """The whole paths, run in a subprocess of this script: the memory they need."""
    if kind == "rasters-whole":
        cat = read_concatenated(paths)
        rasters.write_rasters(cat, out, RES_M)
    else:
        from lidarctl.corners import roof_corners as C
        cat = C.read_strips(paths)
        r = C.find_roof_corners(cat.x, cat.y, cat.z, cat.classification, cat.point_source_id)
        print(json.dumps({k: getattr(r.stats, k) for k in ("n_points", "n_roofs", "n_corners", "n_usable")}))


def read_concatenated(paths: list[Path]) -> io.PointCloud:
    clouds = [io.read_cloud(p) for p in paths]
    fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns", "classification")
    cat = io.PointCloud(*[np.concatenate([getattr(c, f) for c in clouds]) for f in fields],
                        crs=clouds[0].crs, units=clouds[0].units)
    return cat


def compare(whole: Path, tiled: Path) -> dict:
    out = {}
    for f in rasters.FILES:
        with rasterio.open(whole / f) as a, rasterio.open(tiled / f) as b:
            A, B = a.read().astype(float), b.read().astype(float)
            same_meta = a.transform == b.transform and a.crs == b.crs and a.tags() == b.tags()
        if f.endswith(".tif"):
            A[A == rasters.NODATA] = np.nan
            B[B == rasters.NODATA] = np.nan
        both = np.isfinite(A) & np.isfinite(B)
        d = np.abs(A - B)[both]
        out[f] = {"cells": int(A.size), "nodata_mismatch": int((np.isfinite(A) != np.isfinite(B)).sum()),
                  "cells_differing": int((d > 0).sum()), "max_abs_diff": float(d.max()) if d.size else 0.0,
                  "same_transform_crs_tags": bool(same_meta)}
    return out


def demo_equality(demo: Path, work: Path) -> dict:
    paths = sorted(demo.glob("*.las")) + sorted(demo.glob("*.laz"))
    cat = read_concatenated(paths)
    res = {"strips": [str(p) for p in paths], "points": len(cat), "res_m": RES_M}
    for name, fn in (("whole", lambda: rasters.write_rasters(cat, work / "demo_whole", RES_M)),
                     ("tiled", lambda: rasters.write_rasters(paths, work / "demo_tiled", RES_M))):
        load = os.getloadavg()
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        res[name] = {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                     "load_average_before": list(load), "load_average_after": list(os.getloadavg())}
    with rasterio.open(work / "demo_whole" / "dem.tif") as ds:
        res["raster_shape"] = list(ds.shape)
    res["tile_px"], res["buffer_px"] = rasters.DEFAULT_TILE_PX, rasters.DEFAULT_BUFFER_PX
    res["difference"] = compare(work / "demo_whole", work / "demo_tiled")
    return res


def corners_equality(demo: Path, work: Path) -> dict:
    from lidarctl.corners import roof_corners as C

    paths = sorted(demo.glob("*.las")) + sorted(demo.glob("*.laz"))
    res = {"tile_m": C.DEFAULT_TILE_M, "buffer_m": C.DEFAULT_BUFFER_M}
    load = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    cat = C.read_strips(paths)
    whole = C.find_roof_corners(cat.x, cat.y, cat.z, cat.classification, cat.point_source_id,
                                roof="any")
    del cat
    res["whole"] = {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                    "load_average_before": list(load), "load_average_after": list(os.getloadavg())}
    load = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    tiled, _, units, _ = C.find_roof_corners_tiled(paths, roof="any", work_dir=work, figure_cells=C.FIGURE_CELLS)
    res["tiled"] = {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                    "tiles": tiled.stats.tiles,
                    "load_average_before": list(load), "load_average_after": list(os.getloadavg())}
    res["stats"] = {k: [getattr(whole.stats, k), getattr(tiled.stats, k)] for k in
                    ("n_points", "n_building_points", "point_spacing_m", "n_roofs", "n_outlines", "n_corners_traced",
                     "n_corners", "n_usable", "n_roof_planes")}
    res["corners_csv_identical"] = C.corners_csv_text(whole.corners) == C.corners_csv_text(tiled.corners)
    res["roof_planes_identical"] = (
        C.roof_planes_geojson(C._faces_in_crs_units(whole.faces, units), None,
                              sigma_strip_xy_m=whole.stats.sigma_strip_xy_m, sigma_strip_z_m=whole.stats.sigma_strip_z_m)
        == C.roof_planes_geojson(C._faces_in_crs_units(tiled.faces, units), None,
                                 sigma_strip_xy_m=tiled.stats.sigma_strip_xy_m, sigma_strip_z_m=tiled.stats.sigma_strip_z_m))
    res["outlines_identical"] = len(whole.outlines) == len(tiled.outlines) and all(
        len(a["rings"]) == len(b["rings"]) and all(np.array_equal(x, y) for x, y in zip(a["rings"], b["rings"]))
        for a, b in zip(whole.outlines, tiled.outlines))
    mw = np.array([c["strip_margin_m"] for c in whole.corners])
    mt = np.array([c["strip_margin_m"] for c in tiled.corners])
    differ = mw != mt
    res["strip_margin"] = {
        "corners_differing": int(differ.sum()), "tiled_above_whole": int((mt > mw).sum()),
        "min_margin_where_differing_m": [float(mw[differ].min()), float(mt[differ].min())] if differ.any() else None,
        "same_side_of_10m": bool(np.array_equal(mw >= 10.0, mt >= 10.0))}
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo", type=Path, help="folder of classified demo strips (truth/lidar)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/rasters_bench"))
    ap.add_argument("--sides", type=int, nargs="+", default=[4, 8], help="blocks of side x side 200 m tiles")
    ap.add_argument("--worker", choices=["rasters-whole", "corners-whole"], help=argparse.SUPPRESS)
    ap.add_argument("paths", nargs="*", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.paths[:-1], args.paths[-1])
        return
    args.work.mkdir(parents=True, exist_ok=True)
    out_json = REPO / "bench" / "results" / "lidar_rasters_bench.json"
    result = {"machine": {"cores": os.cpu_count(), "ram_gib": psutil.virtual_memory().total / 2 ** 30},
              "blocks": []}

    def save():
        out_json.write_text(json.dumps(result, indent=2) + "\n")

    me = [sys.executable, str(Path(__file__).resolve())]
    for side in args.sides:
        paths = make_block(args.work / f"block_{side}", side)
        n = sum(rasters.las.read_header(p).point_count for p in paths)
        ncells = int(side * TILE_M / RES_M) + 1
        row = {"side_m": side * TILE_M, "strips": len(paths), "points": int(n), "raster_cells": [ncells, ncells]}
        out = args.work / f"out_{side}"
        files = [str(p) for p in paths]
        row["rasters_tiled"] = run_peak(lidarctl("rasters", *files, str(out / "tiled"), "--res-m", str(RES_M),
                                                 "--tile-px", "512", "--buffer-px", "128"))
        row["rasters_tiled"]["args"] = "--tile-px 512 --buffer-px 128"
        row["rasters_whole"] = run_peak([*me, "--worker", "rasters-whole", *files, str(out / "whole")])
        row["rasters_tiled_vs_whole"] = compare(out / "whole", out / "tiled")
        # exit 2 (no usable corner, nothing written) still measures the memory
        row["corners_tiled"] = run_peak(lidarctl("corners", *files, str(out / "corners"), "--tile-m", "250",
                                                 "--buffer-m", "100"), ok_codes=(0, 2))
        row["corners_tiled"]["args"] = "--tile-m 250 --buffer-m 100"
        row["corners_whole"] = run_peak([*me, "--worker", "corners-whole", *files, str(out / "unused")])
        shutil.rmtree(out, ignore_errors=True)
        result["blocks"].append(row)
        save()
        print(json.dumps(row, indent=1), flush=True)
    if len(result["blocks"]) >= 2:
        a, b = result["blocks"][0], result["blocks"][-1]
        result["peak_rss_ratio_largest_to_smallest_block"] = {
            k: b[k]["peak_rss_mib"] / a[k]["peak_rss_mib"]
            for k in ("rasters_tiled", "rasters_whole", "corners_tiled", "corners_whole")}
        result["points_ratio"] = b["points"] / a["points"]
        save()
    if args.demo:
        result["demo_rasters"] = demo_equality(args.demo, args.work)
        save()
        print(json.dumps(result["demo_rasters"], indent=1), flush=True)
        result["demo_corners"] = corners_equality(args.demo, args.work)
        save()
        print(json.dumps(result["demo_corners"], indent=1), flush=True)
    print(f"wrote {out_json}")


if __name__ == "__main__":
    main()
