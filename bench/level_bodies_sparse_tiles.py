"""Tiled classification with the whole cloud's level bodies on (``water_whole_level_bodies``), each whole-cloud call
run both ways -- the grid over the bounding box (``pipeline.whole_level_bodies_dense``) and the occupied blocks
(``pipeline.whole_level_bodies``, used) -- and compared bit for bit, with each one's tracemalloc peak and CPU seconds;
the tiled run's water and bridge-deck returns -> bench/results/level_bodies_sparse_tiles.json (level-bodies-sparse).

Sets (100 m tiles, 40 m buffer): Autzen, AHN3 Delft, lidR Topography (``AEROTRI_SHARED_DATA``), and the big-lake
scenes of ``tests/lidarctl/test_classify_water_tiles.py::big_lake_scene`` (a 340 m lake returning the pulse, a pond
mirroring 95 % of it; without the car park and forest).

  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_bodies_sparse_tiles.py
"""

from __future__ import annotations

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


def main():
    cl.whole_level_bodies = both
    SPARSE(*corridor_cells(0.3), cl.ClassifySettings())   # compiled before it is measured
    p = cl.ClassifySettings(water_whole_level_bodies=True)
    tmp = Path(tempfile.mkdtemp(prefix="level_bodies_sparse_"))
    rows = []
    try:
        sets = [("autzen", DATA / "autzen" / "autzen_trim.laz", None),
                ("ahn3_delft", DATA / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:28992"),
                ("lidr_topography", DATA / "lidr_topography" / "Topography.laz", None)]
        for kind in ("lake", "pond"):
            cloud, *_ = big_lake_scene(kind, land_features=False)
            src = tmp / f"{kind}.laz"
            synthetic.write_las(src, cloud, crs="EPSG:32610")
            sets.append((f"big_{kind}_alone", src, None))
        for name, path, crs in sets:
            n0, t = len(CALLS), time.perf_counter()
            st = tiles.classify_file(path, tmp / "out.laz", crs=crs, params=p, tile_size_m=100.0, buffer_m=40.0)
            cls = np.asarray(laspy.read(tmp / "out.laz").classification)
            row = {"set": name, "tiles": st.run.n_tiles, "water": int((cls == 9).sum()),
                   "deck": int((cls == 17).sum()), "seconds": round(time.perf_counter() - t, 1),
                   "level_bodies": CALLS[n0:]}
            print(json.dumps(row), flush=True)
            rows.append(row)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = REPO / "bench" / "results" / "level_bodies_sparse_tiles.json"
    tmp_out = out.with_suffix(".tmp")
    tmp_out.write_text(json.dumps({"tiles_100m_buffer_40m_option_on": rows}, indent=1) + "\n")
    tmp_out.replace(out)


if __name__ == "__main__":
    main()
