"""The whole cloud's level regions labelled tile by tile (``lidarctl.classify.level_tiles``, level-tiles) against the
labelling of all cells at once, on the water cells a tiled run's parent collects with ``water_whole_level_bodies``
on (each cell's lowest, median and highest return; the run is stopped once they are collected): the same regions
and areas (a one-to-one map of the labels), the same levels (the medians of the regions that span tiles from three
answers of the tiles: ``LEVEL_BINS_M``), what the tiles hand the parent (entries and bytes against the occupied
cells, against the ~150-200 bytes a cell the parent holds today; the exact medians' answers apart), the parent's
join's tracemalloc peak, and CPU of the tiles' labelling and the join against the whole labelling ->
bench/results/level_tiles_regions.json.

Sets: Autzen, AHN3 Delft, lidR Topography (``AEROTRI_SHARED_DATA``), the big lake and pond of
``tests/lidarctl/test_classify_water_tiles.py::big_lake_scene``, the demo's strips (``--demo PROJECT``), synthetic
corridors of 2 / 10 / 50 km (``corridor_cells``: 0.12 / 0.62 / 3.1 M cells); tiles of 100 m (whole-grid cells from
its origin).

Since level-wire the tiles' run no longer calls ``pipeline.whole_level_bodies`` (it finds the bodies tile by tile over
its spooled cells): this bench's hook on that call finds none; ``bench/level_wire.py`` measures the wired run.

  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/level_tiles_regions.py [--demo PROJECT]
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

import numpy as np
from scipy import ndimage

from lidarctl import synthetic, tiles
from lidarctl.classify import level_tiles as lt
from lidarctl.classify import pipeline as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
from test_classify_water_level_bodies import corridor_cells  # noqa: E402
from test_classify_water_tiles import big_lake_scene  # noqa: E402

DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))


class Collected(Exception):
    def __init__(self, args):
        self.args_ = args


def collect(*args):
    raise Collected(args)


def cells_of(paths, tmp: Path, **tiling):
    """(cells, heights, WaterGrid) the parent of a tiled run collects with the option on."""
    p = cl.ClassifySettings(water_whole_level_bodies=True)
    try:
        if len(paths) == 1:
            tiles.classify_file(paths[0], tmp / "out.laz", params=p, **tiling)
        else:
            tiles.classify_files(paths, tmp / "files", params=p)
    except Collected as e:
        return e.args_[:3]
    raise RuntimeError("no whole-cloud level bodies call")


def compare(name, cells, heights, wg, p, tile_m=100.0):
    tol = p.level_water_tol_m
    t = time.process_time()
    med = lt.level_medians(cells, heights, tol)
    r0, c0 = cells.min(axis=0)
    side = max(1, int(round(tile_m / wg.cell_m)))
    # the whole labelling: the sparse pass's components (a dense grid only where the box is small)
    box = int(np.prod(cells.max(axis=0) - cells.min(axis=0) + 1))
    if box <= 60_000_000:
        g = np.full(tuple(cells.max(axis=0) - (r0, c0) + 1), np.nan)
        g[cells[:, 0] - r0, cells[:, 1] - c0] = med
        lab = cl._level_regions(g, tol)[cells[:, 0] - r0, cells[:, 1] - c0]
        del g
    else:
        lab = None
    whole_cpu = time.process_time() - t
    ncols = int(cells[:, 1].max()) + 1
    t = time.process_time()
    split = lt.split_into_tiles(cells, side)
    done = [lt.tile_level_regions(cells[i], heights[i], core, ncols, tol, pos) for pos, i, core in split]
    tile_cpu = time.process_time() - t
    sent = [s for s, _ in done]
    tracemalloc.start()
    t = time.process_time()
    answers = lt.join_tile_regions(iter(sent), positions=[pos for pos, _, _ in split])
    join_cpu = time.process_time() - t
    join_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # the exact medians: the tiles' finer histograms and middle values, the parent's refinement
    mine = [(kept.label, med[i][core][:, None]) for (_, i, core), (_, kept) in zip(split, done)]
    tracemalloc.start()
    t = time.process_time()
    hists = [lt.median_histogram(lab, v, a) for (lab, v), a in zip(mine, answers)]
    exact = lt.refine_medians(answers, hists)
    values = [lt.values_in_median_bins(lab, v, a) for (lab, v), a in zip(mine, exact)]
    exact = lt.exact_levels(exact, values)
    exact_cpu = time.process_time() - t
    exact_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    second = sum(h[0].nbytes + h[1].nbytes for h in hists) + sum(v[0].nbytes + v[1].nbytes for v in values)
    entries = sum(a.size for s in sent for a in vars(s).values() if isinstance(a, np.ndarray))
    nbytes = sum(a.nbytes for s in sent for a in vars(s).values() if isinstance(a, np.ndarray))
    hist = sum(s.hist_bin.size for s in sent)
    row = {"set": name, "cells": len(cells), "cell_m": round(wg.cell_m, 3), "tile_cells": side, "tiles": len(split),
           "sent_entries": int(entries), "sent_histogram_entries": int(hist), "sent_bytes": int(nbytes),
           "sent_bytes_per_cell": round(nbytes / len(cells), 2), "join_peak_mb": round(join_peak / 1e6, 2),
           "join_peak_bytes_per_cell": round(join_peak / len(cells), 2),
           "largest_tile_sent_bytes": int(max(sum(a.nbytes for a in vars(s).values() if isinstance(a, np.ndarray))
                                              for s in sent)),
           "whole_labelling_cpu_s": round(whole_cpu, 2), "tiles_cpu_s": round(tile_cpu, 2),
           "join_cpu_s": round(join_cpu, 2), "exact_medians_sent_bytes": int(second),
           "exact_medians_peak_mb": round(exact_peak / 1e6, 2), "exact_medians_cpu_s": round(exact_cpu, 2)}
    if lab is not None:
        region = np.zeros(len(cells), np.int64)
        area = np.zeros(len(cells), np.int64)
        level = np.full(len(cells), np.nan)
        own = 1 << 40
        for (_, idx, core), (s, kept), ans in zip(split, done, exact):
            k, lb, m = idx[core], kept.label, s.n_spanning
            sp, inner = (lb > 0) & (lb <= m), lb > m
            region[k[sp]], area[k[sp]], level[k[sp]] = ans.region_id[lb[sp]], ans.cells[lb[sp]], ans.level_m[lb[sp]]
            region[k[inner]], area[k[inner]], level[k[inner]] = (own + lb[inner], kept.cells[lb[inner]],
                                                                 kept.level_m[lb[inner]])
            own += 1 << 22
        a = lab > 0
        size = np.bincount(lab)
        big = a & (size[lab] * wg.cell_m ** 2 >= p.level_water_min_area_m2)
        ref = np.r_[np.nan, ndimage.median(med[a], lab[a], np.arange(1, len(size)))]
        pairs = np.unique(np.column_stack([lab[a], region[a]]), axis=0)
        row.update(same_regions=bool(np.array_equal(a, region > 0) and len(pairs) == len(np.unique(lab[a]))
                                     == len(np.unique(region[a]))),
                   same_areas=bool(np.array_equal(area[a], size[lab[a]])),
                   same_levels=bool(np.array_equal(level[a], ref[lab[a]])),
                   big_region_cells=int(big.sum()),
                   spanning_cells=int(np.sum(a & (region < 1 << 40))))
    print(json.dumps(row), flush=True)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path)
    ap.add_argument("--no-real", action="store_true")
    a = ap.parse_args()
    p = cl.ClassifySettings()
    cl.whole_level_bodies = collect
    small = corridor_cells(0.3)
    lt.join_tile_regions([lt.tile_level_regions(small[0][i], small[1][i], core, 10**6, 0.05, pos)[0]
                          for pos, i, core in lt.split_into_tiles(small[0], 70)])   # compiled before measured
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="level_tiles_"))
    try:
        tiled = {"tile_size_m": 100.0, "buffer_m": 40.0}
        sets = []
        if not a.no_real:
            sets = [("autzen", [DATA / "autzen" / "autzen_trim.laz"], tiled),
                    ("ahn3_delft", [DATA / "ahn3_delft" / "ahn3_cropped_1.laz"], {**tiled, "crs": "EPSG:28992"}),
                    ("lidr_topography", [DATA / "lidr_topography" / "Topography.laz"], tiled)]
            for kind in ("lake", "pond"):
                cloud, *_ = big_lake_scene(kind, land_features=False)
                src = tmp / f"{kind}.laz"
                synthetic.write_las(src, cloud, crs="EPSG:32610")
                sets.append((f"big_{kind}_alone", [src], tiled))
            if a.demo is not None:
                sets.append(("demo", sorted((a.demo / "lidar").glob("*.las")), {}))
        for name, paths, tiling in sets:
            rows.append(compare(name, *cells_of(paths, tmp, **tiling), p))
        for km in (2.0, 10.0, 50.0):
            rows.append(compare(f"corridor_{km:g}km", *corridor_cells(km), p))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = REPO / "bench" / "results" / "level_tiles_regions.json"
    tmp_out = out.with_suffix(".tmp")
    tmp_out.write_text(json.dumps({"level_regions_by_tile": rows}, indent=1) + "\n")
    tmp_out.replace(out)


if __name__ == "__main__":
    main()
