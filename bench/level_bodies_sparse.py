"""The whole cloud's level water bodies on the occupied blocks (``pipeline.whole_level_bodies``, level-bodies-sparse)
against the grid over the cloud's bounding box (``pipeline.whole_level_bodies_dense``, i44-edge-fixes; review 15:
69 bytes a cell of the box, ~44 GB for a 50 km diagonal corridor at 1.4 m cells)
-> bench/results/level_bodies_sparse.json.

Scene: ``corridor_cells`` of tests/lidarctl/test_classify_water_level_bodies.py, a corridor 200 m across (along a
row) on the grid's diagonal, 1.414 m cells, with every 400 m a lake returning the pulse, a lake mirroring it but in a
ring of shore patches (the join across a dropout), a lake cut by the corridor's edge (a gap open to beyond the
survey: its shore patches join through it only with the survey's coverage off), a courtyard among roofs, and a level
road creeping along the whole corridor. Per length: cells, bounding-box cells, the tracemalloc peak (bytes) and CPU
seconds of each version, and whether the bodies (cells and levels) are the same to the last bit, with the survey's
coverage on (default) and off; the dense version only up to ``--dense-max-km``.

  nice .venv/bin/python bench/level_bodies_sparse.py            # 2, 5, 10 km dense and sparse; 20, 50 km sparse
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from lidarctl.classify import pipeline as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
from test_classify_water_level_bodies import corridor_cells  # noqa: E402


def measured(fn, *args):
    """(result, tracemalloc peak bytes, CPU s)."""
    tracemalloc.start()
    t = time.process_time()
    out = fn(*args)
    cpu = time.process_time() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, peak, cpu


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths-km", type=float, nargs="+", default=[2, 5, 10, 20, 50])
    ap.add_argument("--dense-max-km", type=float, default=10)
    ap.add_argument("--out", default="bench/results/level_bodies_sparse.json")
    a = ap.parse_args()
    rows = []
    cl.whole_level_bodies(*corridor_cells(0.5), cl.ClassifySettings())   # compiled before it is measured
    for km in a.lengths_km:
        cells, heights, wg = corridor_cells(km)
        box = int(np.prod(cells.max(axis=0) - cells.min(axis=0) + 1))
        for coverage in (True, False):
            p = dataclasses.replace(cl.ClassifySettings(), water_survey_coverage=coverage)
            s, s_peak, s_cpu = measured(cl.whole_level_bodies, cells, heights, wg, p)
            row = {"length_km": km, "coverage": coverage, "cells": len(cells), "box_cells": box,
                   "body_cells": len(s.keys), "sparse_peak_bytes": s_peak, "sparse_cpu_s": round(s_cpu, 2),
                   "sparse_bytes_per_cell": round(s_peak / len(cells), 1)}
            if km <= a.dense_max_km:
                d, d_peak, d_cpu = measured(cl.whole_level_bodies_dense, cells, heights, wg, p)
                row.update(dense_peak_bytes=d_peak, dense_cpu_s=round(d_cpu, 2),
                           dense_bytes_per_box_cell=round(d_peak / box, 1),
                           same=bool(d.ncols == s.ncols and np.array_equal(d.keys, s.keys)
                                     and np.array_equal(d.level_m, s.level_m)))
            print(json.dumps(row), flush=True)
            rows.append(row)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    tmp.replace(out)


if __name__ == "__main__":
    main()
