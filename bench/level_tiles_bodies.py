"""The whole cloud's level bodies tile by tile (``level_tiles.whole_level_bodies_tiled``, level-tiles) against the
parent's pass on every occupied cell (``pipeline.whole_level_bodies``, the option ``water_whole_level_bodies``'s
path today): on the water cells each tiled run collects, the bodies' cells that differ and the largest level
difference, the tiles' windows (tiles of 100 m on the whole water grid, a halo of the wall rule's reach), the
number of regions per round (the parent's per-region tables), CPU; then the classes of the tiled run with the
option on, each whole-cloud call made tile by tile, against the run as it is (classes that differ) ->
bench/results/level_tiles_bodies.json.

Sets (100 m tiles, 40 m buffer): Autzen, AHN3 Delft, lidR Topography (``AEROTRI_SHARED_DATA``), the big lake and
pond alone (``tests/lidarctl/test_classify_water_tiles.py::big_lake_scene``), the demo (``--demo PROJECT``, its
default tiles).

Since level-wire the tiles' run no longer calls ``pipeline.whole_level_bodies`` (it finds the bodies tile by tile over
its spooled cells): this bench's hook on that call finds none; ``bench/level_wire.py`` measures the wired run.

  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_tiles_bodies.py [--demo PROJECT]
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
from lidarctl.classify import level_tiles as lt
from lidarctl.classify import pipeline as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
from test_classify_water_tiles import big_lake_scene  # noqa: E402

DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
SPARSE = cl.whole_level_bodies
TILE_M = 100.0
CALLS: list[dict] = []
ROUNDS: list[int] = []


def counted_label_round(*a):
    out = LABEL_ROUND(*a)
    ROUNDS.append(len(out[1]))
    return out


LABEL_ROUND = lt._label_round


def both(cells, heights, wg, p):
    """The whole-cloud call made both ways, compared; the tiled bodies returned."""
    row = {"cells": len(cells)}
    tracemalloc.start()
    t = time.process_time()
    whole = SPARSE(cells, heights, wg, p)
    row["whole_cpu_s"] = round(time.process_time() - t, 2)
    row["whole_peak_bytes_per_cell"] = round(tracemalloc.get_traced_memory()[1] / len(cells), 1)
    tracemalloc.stop()
    ROUNDS.clear()
    t = time.process_time()
    tiled = lt.whole_level_bodies_tiled(cells, heights, wg, p, max(1, int(round(TILE_M / wg.cell_m))))
    row["tiled_cpu_s"] = round(time.process_time() - t, 2)
    row["regions_per_labelling_round"] = list(ROUNDS)
    row["body_cells"] = len(whole.keys)
    row["body_cells_tiled"] = len(tiled.keys)
    row["cells_differ"] = int(np.setxor1d(whole.keys, tiled.keys).size)
    _, ia, ib = np.intersect1d(whole.keys, tiled.keys, return_indices=True)
    row["max_level_diff_mm"] = round(float(np.max(np.abs(whole.level_m[ia] - tiled.level_m[ib]), initial=0)) * 1e3,
                                     3)
    CALLS.append(row)
    return tiled


def classes(paths, out: Path, params, **tiling):
    if len(paths) == 1:
        tiles.classify_file(paths[0], out / "out.laz", params=params, **tiling)
        files = [out / "out.laz"]
    else:
        tiles.classify_files(paths, out / "files", params=params)
        files = sorted((out / "files").glob("*.las"))
    return np.concatenate([np.asarray(laspy.read(f).classification) for f in files])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path)
    a = ap.parse_args()
    lt._label_round = counted_label_round
    on = cl.ClassifySettings(water_whole_level_bodies=True)
    tmp = Path(tempfile.mkdtemp(prefix="level_tiles_bodies_"))
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
            cl.whole_level_bodies = SPARSE
            c_whole = classes(paths, tmp, on, **tiling)
            n0 = len(CALLS)
            cl.whole_level_bodies = both
            c_tiled = classes(paths, tmp, on, **tiling)
            row = {"set": name, "level_bodies": CALLS[n0:], "water_whole": int((c_whole == 9).sum()),
                   "water_tiled": int((c_tiled == 9).sum()), "classes_differ": int(np.sum(c_whole != c_tiled))}
            print(json.dumps(row), flush=True)
            rows.append(row)
    finally:
        cl.whole_level_bodies = SPARSE
        shutil.rmtree(tmp, ignore_errors=True)
    out = REPO / "bench" / "results" / "level_tiles_bodies.json"
    tmp_out = out.with_suffix(".tmp")
    tmp_out.write_text(json.dumps({"tiled_against_whole": rows}, indent=1) + "\n")
    tmp_out.replace(out)


if __name__ == "__main__":
    main()
