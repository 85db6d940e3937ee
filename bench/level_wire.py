"""The whole cloud's level bodies found tile by tile inside a tiled run (level-wire): the run tiles' workers spool
their water cells by level tile under the run's scratch (``level_tiles.spool_cells``), the parent runs
``level_tiles.whole_level_bodies_spooled`` over the tiles' windows (own and neighbours' files) and the tiles read
their windows' bodies back (``SpooledLevelBodies``). Against the option-on path as it was (the parent collecting
every occupied water cell and running ``pipeline.whole_level_bodies``: here every cell gathered from the spool and
that pass run on them, its bodies written back the same way): body cells and levels that differ, classes that
differ, the parent's tracemalloc peak in the level bodies' pass either way and its CPU; the tiled run's CPU with the
option off and on (``--cpu``). Then the parent's peak against the cell count on synthetic corridors (``--corridors``:
``corridor_cells`` of tests/lidarctl/test_classify_water_level_bodies.py, the store in files) ->
bench/results/level_wire.json.

Sets: the big lake and pond (``big_lake_scene`` with the car park and the forest, as ``eval_water_tiles.py
--big-lake``; 100 m tiles, 40 m buffer), ``small_tiles_lake`` / ``_pond`` (the lake 170 m across of
``test_lake_larger_than_a_tile_and_its_buffer`` in 40 m tiles, 20 m buffer: windows wholly on the water), lidR
Topography, Autzen, AHN3 Delft (100 m tiles, 40 m buffer;
``AEROTRI_SHARED_DATA``), the demo's strips (``--demo PROJECT``, its default tiles).

  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_wire.py --cpu --corridors 2,10,50
  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_wire.py --cpu --sets "" \
      --demo PROJECT --out level_wire_demo.json
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
from test_classify_water_level_bodies import corridor_cells  # noqa: E402
from test_classify_water_tiles import big_lake_scene  # noqa: E402

DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
WIRED = lt.whole_level_bodies_spooled
CALLS: list[dict] = []


def gathered(store):
    cells = np.concatenate([store.get("cells", t) for t in store.tiles])
    heights = np.concatenate([store.get("heights", t) for t in store.tiles])
    return cells, heights


def bodies_of(store):
    keys = [store.get("out_keys", t) for t in store.tiles]
    levels = [store.get("out_level", t) for t in store.tiles]
    keys = np.concatenate([k for k in keys if k is not None] or [np.zeros(0, np.int64)])
    levels = np.concatenate([v for v in levels if v is not None] or [np.zeros(0)])
    o = np.argsort(keys)
    return keys[o], levels[o]


def reference(store, wg, p, footprint=None):
    """The option-on path as it was: every cell in the parent, ``pipeline.whole_level_bodies``; its bodies written
    to the spool as the wired pass writes them (so the tiles read them the same way), compared with the wired
    pass's on the same cells."""
    cells, heights = gathered(store)
    tracemalloc.start()
    t = time.process_time()
    whole = cl.whole_level_bodies(cells, heights, wg, p)
    cpu = time.process_time() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    ncols = whole.ncols if len(whole.keys) else store.box[3] + 1
    # the wired pass on a copy of the spool (in memory), for the bodies' comparison
    mem = lt.CellSpool.from_cells(cells, heights, store.side)
    WIRED(mem, wg, p, footprint)
    keys, levels = bodies_of(mem)
    r, c = np.divmod(whole.keys, ncols)
    for t in store.tiles:
        for name in ("out_keys", "out_level"):
            f = store.folder / f"{name}_{t[0]}_{t[1]}.bin"
            f.unlink(missing_ok=True)
    tile = np.column_stack([r // store.side, c // store.side])
    for tr, tc in (np.unique(tile, axis=0) if len(tile) else []):
        m = (tile[:, 0] == tr) & (tile[:, 1] == tc)
        store.put("out_keys", (int(tr), int(tc)), whole.keys[m])
        store.put("out_level", (int(tr), int(tc)), whole.level_m[m])
    _, ia, ib = np.intersect1d(whole.keys, keys, return_indices=True)
    CALLS.append({"path": "whole", "cells": len(cells), "cpu_s": round(cpu, 2),
                  "peak_bytes_per_cell": round(peak / len(cells), 1), "body_cells": len(whole.keys),
                  "body_cells_wired": len(keys), "cells_differ": int(np.setxor1d(whole.keys, keys).size),
                  "max_level_diff_mm": round(float(np.max(np.abs(whole.level_m[ia] - levels[ib]), initial=0)) * 1e3,
                                             3)})
    return ncols


def wired(store, wg, p, footprint=None):
    tracemalloc.start()
    t = time.process_time()
    ncols = WIRED(store, wg, p, footprint)
    cpu = time.process_time() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    n = sum(len(store.get("cells", t)) for t in store.tiles)
    disk = sum(f.stat().st_size for f in store.folder.glob("*.bin")) if store.folder is not None else 0
    CALLS.append({"path": "wired", "cells": n, "spool_bytes_per_cell": round(disk / max(n, 1), 1),
                  "level_tiles": len(store.tiles), "side_cells": store.side,
                  "cpu_s": round(cpu, 2), "peak_bytes": peak, "peak_bytes_per_cell": round(peak / max(n, 1), 1),
                  "body_cells": len(bodies_of(store)[0])})
    return ncols


def classes(paths, out: Path, params, **tiling):
    t = time.process_time()
    w = time.perf_counter()
    if len(paths) == 1:
        tiles.classify_file(paths[0], out / "out.laz", params=params, **tiling)
        files = [out / "out.laz"]
    else:
        shutil.rmtree(out / "files", ignore_errors=True)
        tiles.classify_files(paths, out / "files", params=params)
        files = sorted((out / "files").glob("*.las"))
    cpu, wall = time.process_time() - t, time.perf_counter() - w
    return np.concatenate([np.asarray(laspy.read(f).classification) for f in files]), round(cpu, 1), round(wall, 1)


def corridors(lengths_km, tmp: Path):
    rows = []
    p = cl.ClassifySettings(water_whole_level_bodies=True)
    for km in lengths_km:
        cells, heights, wg = corridor_cells(km)
        side = lt.level_tile_cells(wg.cell_m, p)
        folder = tmp / f"corridor_{km}"
        folder.mkdir()
        mem = lt.CellSpool.from_cells(cells, heights, side)
        store = lt.CellSpool(side, folder)
        for t in mem.tiles:
            store._add(t, mem.get("cells", t), mem.get("heights", t))
        n = len(cells)
        del mem, cells, heights
        CALLS.clear()
        wired(store, wg, p)
        row = {"set": f"corridor_{km}km", **CALLS[0]}
        print(json.dumps(row), flush=True)
        rows.append(row)
        shutil.rmtree(folder)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path)
    ap.add_argument("--sets", default="big_lake,big_pond,small_tiles_lake,small_tiles_pond,lidr_topography,autzen,"
                                      "ahn3_delft")
    ap.add_argument("--cpu", action="store_true", help="also the run with the option off (CPU)")
    ap.add_argument("--corridors", default="")
    ap.add_argument("--out", default="level_wire.json")
    ap.add_argument("--keep-corridors", action="store_true", help="keep the corridors' rows of the file written")
    a = ap.parse_args()
    on = cl.ClassifySettings(water_whole_level_bodies=True)
    off = cl.ClassifySettings(water_whole_level_bodies=False)
    tmp = Path(tempfile.mkdtemp(prefix="level_wire_", dir=os.environ.get("LEVEL_WIRE_TMP")))
    rows = []
    try:
        tiled = {"tile_size_m": 100.0, "buffer_m": 40.0}
        known = {"autzen": ([DATA / "autzen" / "autzen_trim.laz"], tiled),
                 "ahn3_delft": ([DATA / "ahn3_delft" / "ahn3_cropped_1.laz"], {**tiled, "crs": "EPSG:28992"}),
                 "lidr_topography": ([DATA / "lidr_topography" / "Topography.laz"], tiled)}
        sets = []
        for name in [s for s in a.sets.split(",") if s]:
            if name.startswith("big_"):
                cloud, *_ = big_lake_scene(name[4:])
                src = tmp / f"{name}.laz"
                synthetic.write_las(src, cloud, crs="EPSG:32610")
                sets.append((name, [src], tiled))
            elif name.startswith("small_tiles_"):   # the lake of test_lake_larger_than_a_tile_and_its_buffer
                cloud, *_ = big_lake_scene(name.split("_")[-1], size_m=240.0, radius_m=85.0, density=1.5)
                src = tmp / f"{name}.laz"
                synthetic.write_las(src, cloud, crs="EPSG:32610")
                sets.append((name, [src], {"tile_size_m": 40.0, "buffer_m": 20.0}))
            else:
                sets.append((name, *known[name]))
        if a.demo is not None:
            sets.append(("demo_default_tiles", sorted((a.demo / "lidar").glob("*.las")), {}))
        for name, paths, tiling in sets:
            row = {"set": name}
            c_off = None
            if a.cpu:
                c_off, row["off_cpu_s"], row["off_wall_s"] = classes(paths, tmp, off, **tiling)
            CALLS.clear()
            lt.whole_level_bodies_spooled = reference
            c_ref, row["on_whole_cpu_s"], row["on_whole_wall_s"] = classes(paths, tmp, on, **tiling)
            lt.whole_level_bodies_spooled = wired
            c_wired, row["on_wired_cpu_s"], row["on_wired_wall_s"] = classes(paths, tmp, on, **tiling)
            lt.whole_level_bodies_spooled = WIRED
            row.update(level_bodies=list(CALLS), water_whole=int((c_ref == 9).sum()),
                       water_wired=int((c_wired == 9).sum()), classes_differ=int(np.sum(c_ref != c_wired)))
            if c_off is not None:   # what turning the option on by default changes
                row.update(water_off=int((c_off == 9).sum()), classes_on_differ_from_off=int(np.sum(c_off != c_wired)),
                           changes_off_to_on={f"{a}->{b}": int(n) for (a, b), n in zip(*np.unique(
                               np.column_stack([c_off, c_wired])[c_off != c_wired], axis=0, return_counts=True))})
            print(json.dumps(row), flush=True)
            rows.append(row)
        corr = corridors([float(v) for v in a.corridors.split(",") if v], tmp)
    finally:
        lt.whole_level_bodies_spooled = WIRED
        shutil.rmtree(tmp, ignore_errors=True)
    out = REPO / "bench" / "results" / a.out
    if a.keep_corridors and not corr and out.exists():
        corr = json.loads(out.read_text()).get("corridors", [])
    tmp_out = out.with_suffix(".tmp")
    tmp_out.write_text(json.dumps({"wired_against_whole": rows, "corridors": corr}, indent=1) + "\n")
    tmp_out.replace(out)


if __name__ == "__main__":
    main()
