"""Tiled classification with the whole cloud's level bodies on (``water_whole_level_bodies``), each whole-cloud call
run both ways -- the grid over the bounding box (``pipeline.whole_level_bodies_dense``) and the occupied blocks
(``pipeline.whole_level_bodies``, used) -- and compared bit for bit, with each one's tracemalloc peak and CPU seconds;
the tiled run's water and bridge-deck returns, and those of the same run with the option off (default) and the returns
whose class differs -> bench/results/level_bodies_sparse_tiles.json (level-bodies-sparse).

Sets (100 m tiles, 40 m buffer): Autzen, AHN3 Delft, lidR Topography (``AEROTRI_SHARED_DATA``), and the big-lake
scenes of ``tests/lidarctl/test_classify_water_tiles.py::big_lake_scene`` (a 340 m lake returning the pulse, a pond
mirroring 95 % of it; without the car park and forest).

  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_bodies_sparse_tiles.py [--demo PROJECT]

``--demo PROJECT``: also the demo's four strips (``PROJECT/lidar/*.las``) with ``classify_files``' default tiles.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import laspy
import numpy as np

from lidarctl import synthetic, tiles
from lidarctl.classify import pipeline as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
from test_classify_water_level_bodies import corridor_cells  # noqa: E402
from test_classify_water_tiles import big_lake_scene  # noqa: E402

DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
SPARSE = cl.whole_level_bodies
CALLS: list[dict] = []


def both(cells, heights, wg, p):
    """``whole_level_bodies`` for the tiles: both versions, compared; the sparse one's bodies returned."""
    out, row = {}, {"cells": len(cells), "box_cells": int(np.prod(cells.max(0) - cells.min(0) + 1))}
    for name, fn in (("dense", cl.whole_level_bodies_dense), ("sparse", SPARSE)):
        tracemalloc.start()
        t = time.process_time()
        out[name] = fn(cells, heights, wg, p)
        row[f"{name}_cpu_s"] = round(time.process_time() - t, 2)
        row[f"{name}_peak_mb"] = round(tracemalloc.get_traced_memory()[1] / 1e6, 1)
        tracemalloc.stop()
    d, s = out["dense"], out["sparse"]
    row["body_cells"] = len(s.keys)
    row["same"] = bool(d.ncols == s.ncols and np.array_equal(d.keys, s.keys) and np.array_equal(d.level_m, s.level_m))
    CALLS.append(row)
    return s


def classes(paths, out: Path, params, **tiling):
    """The classes of a tiled run of ``paths`` (one file: ``classify_file``; several: ``classify_files``)."""
    if len(paths) == 1:
        st = tiles.classify_file(paths[0], out / "out.laz", params=params, **tiling)
        files = [out / "out.laz"]
    else:
        st = tiles.classify_files(paths, out / "files", params=params)
        files = sorted((out / "files").glob("*.las"))
    return st, np.concatenate([np.asarray(laspy.read(f).classification) for f in files])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path)
    a = ap.parse_args()
    cl.whole_level_bodies = both
    SPARSE(*corridor_cells(0.3), cl.ClassifySettings())   # compiled before it is measured
    on, off = cl.ClassifySettings(water_whole_level_bodies=True), cl.ClassifySettings()
    tmp = Path(tempfile.mkdtemp(prefix="level_bodies_sparse_"))
    rows = []
    try:
        tiled = {"tile_size_m": 100.0, "buffer_m": 40.0}
        sets = [("autzen", [DATA / "autzen" / "autzen_trim.laz"], tiled),
                ("ahn3_delft", [DATA / "ahn3_delft" / "ahn3_cropped_1.laz"], {**tiled, "crs": "EPSG:28992"}),
                ("lidr_topography", [DATA / "lidr_topography" / "Topography.laz"], tiled)]
        for kind in ("lake", "pond"):
            cloud, *_ = big_lake_scene(kind, land_features=False)
            src = tmp / f"{kind}.laz"
            synthetic.write_las(src, cloud, crs="EPSG:32610")
            sets.append((f"big_{kind}_alone", [src], tiled))
        if a.demo is not None:
            sets.append(("demo_default_tiles", sorted((a.demo / "lidar").glob("*.las")), {}))
        for name, paths, tiling in sets:
            n0, t = len(CALLS), time.perf_counter()
            st, c_on = classes(paths, tmp, on, **tiling)
            row = {"set": name, "tiles": st.run.n_tiles, "seconds_on": round(time.perf_counter() - t, 1),
                   "level_bodies": CALLS[n0:]}
            _, c_off = classes(paths, tmp, off, **tiling)
            for key, c in (("off", c_off), ("on", c_on)):
                row[f"water_{key}"] = int((c == 9).sum())
                row[f"deck_{key}"] = int((c == 17).sum())
            row["classes_differ"] = int(np.sum(c_on != c_off))
            print(json.dumps(row), flush=True)
            rows.append(row)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = REPO / "bench" / "results" / "level_bodies_sparse_tiles.json"
    tmp_out = out.with_suffix(".tmp")
    tmp_out.write_text(json.dumps({"tiles_option_on_and_off": rows}, indent=1) + "\n")
    tmp_out.replace(out)


if __name__ == "__main__":
    main()
