"""The whole cloud's level bodies' wall rule (``pipeline.WALL_BEHIND_M``, level-bodies-sparse; s19-fixes: the lower land
is any return within 50 m but the body's own cells and rim) on synthetic scenes, and its cost on a city of yards
among roofs -> bench/results/level_bodies_walls.json.

Scenes (cells of ``whole_level_bodies``, ``whole_level_bodies_dense`` and, for the quays, the tile's own pass
``level_water`` on three returns a cell):
- quay basins 120 m across (``quay_cells`` of tests/lidarctl/test_classify_water_level_bodies.py, 1.41 m cells),
  quays 2-10 m above the water: banks (a body);
- a level yard 200 m across (2 m cells) in a ring of flat roofs 12 m up, 10 / 20 / 50 / 60 m deep, the street beyond
  1 m above the yard and rising 2 %, at the yard's level, 0.5 m below it: no body (but roofs deeper than 50 m);
- a level quarry floor in 10 m cliffs, the land above flat: a body (a basin in quays by its heights);
- a city 1 km square (1.414 m cells) of 40 m yards among 14 m deep roof rings, streets at the yards' level: the
  tracemalloc peak and CPU seconds of each version (review 19: 489 bytes a cell, 70 % in ``_lowest_land_near``).

  nice .venv/bin/python bench/level_bodies_walls.py
"""

from __future__ import annotations

import json
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from lidarctl.classify import pipeline as cl

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
from test_classify_water_level_bodies import level_water_bodies, quay_cells  # noqa: E402


def water_grid(n: int, c: float) -> cl.WaterGrid:
    occ = np.ones((int(n * c // 10) + 2,) * 2, bool)
    return cl.WaterGrid(cell_m=c, x0_m=0.0, y0_m=0.0, median_count=3.0, footprint_10m=cl.survey_footprint(occ))


def yard(depth: int, beyond, s: int = 200, half: int = 50, ring_z: float = 112.0, c: float = 2.0, seed: int = 3):
    """A level yard (2 ``half`` cells square) at 100 m in a ring ``depth`` cells deep of flat roofs at ``ring_z``;
    ``beyond(d)`` (d: cells beyond the yard) the land outside."""
    rng = np.random.default_rng(seed)
    ii, jj = np.divmod(np.arange(s * s), s)
    d = np.maximum(np.abs(ii - s / 2 + 0.5), np.abs(jj - s / 2 + 0.5)) - half
    lo = np.where(d <= 0, 100.0, beyond(d)) + rng.normal(0, 0.01, s * s)
    span = np.where(d <= 0, rng.uniform(0, 0.03, s * s), rng.uniform(0, 0.2, s * s))
    roof = (d > 0) & (d <= depth)
    lo = np.where(roof, ring_z + rng.normal(0, 0.005, s * s), lo)
    span = np.where(roof, rng.uniform(0, 0.02, s * s), span)
    return np.column_stack([ii, jj]), np.column_stack([lo, lo + span / 2, lo + span]), water_grid(s, c)


def city(km: float, c: float = 1.414):
    n = int(km * 1000 / c)
    rng = np.random.default_rng(0)
    ii, jj = np.divmod(np.arange(n * n), n)
    pitch = int(70 / c)
    a, b = ii % pitch, jj % pitch
    yard_ = (a >= 14) & (a < pitch - 14) & (b >= 14) & (b < pitch - 14)
    roof = ~yard_ & (a >= 4) & (a < pitch - 4) & (b >= 4) & (b < pitch - 4)
    lo = np.where(roof, 112.0, 100.0) + rng.normal(0, 0.01, n * n)
    span = np.where(roof | yard_, rng.uniform(0, 0.03, n * n), rng.uniform(0, 0.1, n * n))
    return np.column_stack([ii, jj]), np.column_stack([lo, lo + span / 2, lo + span]), water_grid(n, c)


def measured(fn, *args):
    tracemalloc.start()
    t = time.process_time()
    out = fn(*args)
    cpu = time.process_time() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, peak, cpu


def main():
    p = cl.ClassifySettings()
    rows = []

    def scene(name, cells, heights, wg, **more):
        s = cl.whole_level_bodies(cells, heights, wg, p)
        d = cl.whole_level_bodies_dense(cells, heights, wg, p)
        row = {"scene": name, "body_cells": len(s.keys), "dense_body_cells": len(d.keys),
               "same": bool(np.array_equal(s.keys, d.keys) and np.array_equal(s.level_m, d.level_m)), **more}
        print(json.dumps(row), flush=True)
        rows.append(row)

    for freeboard_m in (2.0, 3.0, 4.0, 6.0, 10.0):
        cells, heights, wg, basin = quay_cells(freeboard_m)
        tile = len(np.unique(level_water_bodies(cells, heights, wg, p)[1]))
        scene(f"quay basin 120 m, quays {freeboard_m:g} m", cells, heights, wg, basin_cells=basin,
              tile_pass_cells=tile)
    streets = {"street +1 m rising 2 %": lambda depth: lambda d: 101.0 + 0.04 * np.clip(d - depth, 0, None),
               "street at the yard's level": lambda depth: lambda d: 100.0 + 0 * d,
               "street 0.5 m below the yard": lambda depth: lambda d: 99.5 + 0 * d}
    for depth in (5, 10, 25, 30):
        for name, beyond in streets.items():
            scene(f"yard 200 m, roofs 12 m up {2 * depth} m deep, {name}", *yard(depth, beyond(depth)))
    scene("quarry floor 200 m in 10 m cliffs, land above flat", *yard(10, lambda d: 110.0 + 0 * d, ring_z=110.0))
    cells, heights, wg = city(0.1)
    cl.whole_level_bodies(cells, heights, wg, p)   # compiled before it is measured
    cells, heights, wg = city(1.0)
    cost = {"scene": "city 1 km square, 1.414 m cells, 40 m yards among 14 m roof rings, streets at yard level",
            "cells": len(cells)}
    for key, fn in (("sparse", cl.whole_level_bodies), ("dense", cl.whole_level_bodies_dense)):
        bodies, peak, cpu = measured(fn, cells, heights, wg, p)
        cost.update({f"{key}_peak_bytes": peak, f"{key}_bytes_per_cell": round(peak / len(cells), 1),
                     f"{key}_cpu_s": round(cpu, 2), f"{key}_body_cells": len(bodies.keys)})
    print(json.dumps(cost), flush=True)
    out = REPO / "bench" / "results" / "level_bodies_walls.json"
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"scenes": rows, "city_cost": cost}, indent=1) + "\n")
    tmp.replace(out)


if __name__ == "__main__":
    main()
