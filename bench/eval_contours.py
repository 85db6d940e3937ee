"""``lidarctl contours`` against ``gdal_contour`` and against the simulator's true terrain (issue 24).

DEM: the ``demo`` preset's true terrain (seeds 2 and 3; hills, ponds with banks, the 35 degree valley
side) sampled at the centres of 1 m cells over 800 x 1200 m, as a GeoTIFF in UTM. Measured per seed:
- against ``gdal_contour -i 1`` (Debian gdal-bin; ``make bench`` installs it) on the same GeoTIFF, our
  traced lines (no smoothing): the Hausdorff distance per level between the two sets of lines (each
  side densified to 0.25 m) inside the raster inset by one cell (gdal_contour carries the lines on over
  the outer half cells to the raster's edge, ours end at the outermost cell centres: 0.5 cells there),
  the worst level in cells; the number of lines;
- the vertical error of the vertices (traced, B-spline, tension) against the true terrain;
- crossings after each smoothing (shapely; must be 0);
- both commands timed in fresh processes, same run: the speed ratio (wall and CPU).
Writes bench/results/contours.json and bench/results/contours_sim.png (our B-spline contours over the hillshade).
Run: .venv/bin/python bench/eval_contours.py
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.sim import load_preset  # noqa: E402
from aerotri.sim.flight import block_layout  # noqa: E402
from aerotri.sim.scene import build_scene  # noqa: E402

RES_M = 1.0
W_M, H_M = 800.0, 1200.0
X0, Y0 = 500000.0, 4000000.0  # map origin of the scene's (0, 0)


def scene_of(seed):
    cfg = load_preset("demo")
    layout = block_layout(cfg)
    return build_scene(cfg.scene, layout.width_m, layout.height_m, np.zeros(3), seed)


def write_dem(scene, path):
    import rasterio
    from rasterio.transform import from_origin

    nx, ny = int(W_M / RES_M), int(H_M / RES_M)
    x = (np.arange(nx) + 0.5) * RES_M
    y = H_M - (np.arange(ny) + 0.5) * RES_M
    X, Y = np.meshgrid(x, y)
    z = scene.terrain_height(X, Y)
    with rasterio.open(path, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs="EPSG:32633",
                       transform=from_origin(X0, Y0 + H_M, RES_M, RES_M), nodata=-9999.0) as d:
        d.write(z.astype("float32"), 1)


def timed(cmd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"{cmd}: {r.stderr[-800:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def read_lines(path, field):
    from pyogrio.raw import read

    meta, _, geom, fields = read(path)
    import shapely

    lines = shapely.from_wkb(geom)
    level = np.asarray(fields[list(meta["fields"]).index(field)], float)
    return lines, level


def per_level_hausdorff(a_lines, a_level, b_lines, b_level):
    """Per level, inside the raster inset by one cell: gdal_contour continues the lines over the outer half
    cells to the raster's edge, ours end at the outermost cell centres (a convention at the border only)."""
    import shapely

    box = shapely.box(X0 + RES_M, Y0 + RES_M, X0 + W_M - RES_M, Y0 + H_M - RES_M)
    out = {}
    for lev in np.union1d(np.unique(a_level), np.unique(b_level)):
        a = shapely.segmentize(shapely.union_all(a_lines[np.isclose(a_level, lev)]).intersection(box), 0.25)
        b = shapely.segmentize(shapely.union_all(b_lines[np.isclose(b_level, lev)]).intersection(box), 0.25)
        if a.is_empty or b.is_empty:
            out[float(lev)] = None if a.is_empty and b.is_empty else float("inf")
            continue
        out[float(lev)] = float(shapely.hausdorff_distance(a, b))
    return out


def vertical_error(scene, lines, level):
    import shapely

    errs = []
    for ln, lev in zip(lines, level):
        xy = shapely.get_coordinates(ln)
        errs.append(scene.terrain_height(xy[:, 0] - X0, xy[:, 1] - Y0) - lev)
    e = np.concatenate(errs)
    return {"rms_m": float(np.sqrt(np.mean(e ** 2))), "max_abs_m": float(np.abs(e).max()), "vertices": int(e.size)}


def main():
    if shutil.which("gdal_contour") is None:
        sys.exit("gdal_contour not found: run `make bench` (installs Debian gdal-bin)")
    work = Path(tempfile.mkdtemp(prefix="bench_contours_"))
    lidarctl = str(Path(sys.executable).with_name("lidarctl"))
    res = {"res_m": RES_M, "area_m": [W_M, H_M], "load_average_1min_start": os.getloadavg()[0], "seeds": {}}
    try:
        for seed in (2, 3):
            scene = scene_of(seed)
            dem = work / f"dem_{seed}.tif"
            write_dem(scene, dem)
            row = {}
            # warm-up: numba/contourpy caches and the page cache, for both
            timed([lidarctl, "contours", str(dem), str(work / "warm.gpkg"), "--interval-m", "1", "--no-png"])
            timed(["gdal_contour", "-q", "-a", "elev", "-i", "1", str(dem), str(work / "warm_g.gpkg")])
            runs = {"ours": [], "gdal": []}
            for k in range(2):
                for name in ("ours", "gdal"):
                    out = work / f"{name}_{seed}_{k}.gpkg"
                    cmd = ([lidarctl, "contours", str(dem), str(out), "--interval-m", "1", "--no-png"] if name == "ours"
                           else ["gdal_contour", "-q", "-a", "elev", "-i", "1", str(dem), str(out)])
                    runs[name].append(timed(cmd))
            row["timing"] = {n: {"wall_s": min(w for w, _ in r), "cpu_s": min(c for _, c in r)} for n, r in runs.items()}
            row["speed_ratio_gdal_over_ours_wall"] = row["timing"]["gdal"]["wall_s"] / row["timing"]["ours"]["wall_s"]
            row["speed_ratio_gdal_over_ours_cpu"] = row["timing"]["gdal"]["cpu_s"] / row["timing"]["ours"]["cpu_s"]
            ours, ours_lev = read_lines(work / f"ours_{seed}_0.gpkg", "elevation")
            gdal, gdal_lev = read_lines(work / f"gdal_{seed}_0.gpkg", "elev")
            hd = per_level_hausdorff(ours, ours_lev, gdal, gdal_lev)
            finite = [v for v in hd.values() if v is not None and np.isfinite(v)]
            row["vs_gdal"] = {"lines_ours": int(len(ours)), "lines_gdal": int(len(gdal)), "levels": len(hd),
                              "levels_only_one_side": sum(1 for v in hd.values() if v is not None and not np.isfinite(v)),
                              "hausdorff_max_cells": max(finite) / RES_M, "hausdorff_median_cells": float(np.median(finite)) / RES_M}
            row["vertical_error"] = {"traced": vertical_error(scene, ours, ours_lev)}
            for method in ("bspline", "tension"):
                out = work / f"{method}_{seed}.gpkg"
                r = subprocess.run([lidarctl, "contours", str(dem), str(out), "--interval-m", "1", "--smooth", method]
                                   + ([] if seed == 2 and method == "bspline" else ["--no-png"]),
                                   capture_output=True, text=True, check=True)
                lines, lev = read_lines(out, "elevation")
                from lidarctl.terrain.contours import Contour, crossings

                import shapely

                cs = [Contour(float(v), False, False, shapely.get_coordinates(g)) for g, v in zip(lines, lev)]
                row["vertical_error"][method] = vertical_error(scene, lines, lev) | {
                    "crossings": crossings(cs), "message": r.stdout.strip()}
                if seed == 2 and method == "bspline":
                    shutil.copy(out.with_suffix(".png"), REPO / "bench" / "results" / "contours_sim.png")
            res["seeds"][str(seed)] = row
            print(seed, json.dumps(row["vs_gdal"]), json.dumps(row["timing"]), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res["load_average_1min_end"] = os.getloadavg()[0]
    res["summary"] = {
        "hausdorff_max_cells": max(r["vs_gdal"]["hausdorff_max_cells"] for r in res["seeds"].values()),
        "target_hausdorff_cells": 0.5,
        "crossings_after_smoothing": sum(r["vertical_error"][m]["crossings"] for r in res["seeds"].values()
                                         for m in ("bspline", "tension")),
        "speed_ratio_gdal_over_ours_wall": min(r["speed_ratio_gdal_over_ours_wall"] for r in res["seeds"].values()),
    }
    (REPO / "bench" / "results" / "contours.json").write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res["summary"]))


if __name__ == "__main__":
    main()
