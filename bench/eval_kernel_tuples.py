"""Same bits, same speed (issue 40): the numba kernels that now take their grid as a NamedTuple
(``lidarctl.raster_ops``: ``_cell_of`` / ``_cell_extreme_xy`` / ``_cell_sums`` behind ``reduce_grid``,
``_bilinear`` behind ``sample_bilinear``; ``lidarctl.rasters.cells``: ``_accumulate`` and ``_chm_max`` behind
``CellStats.add`` / ``add_chm``, the rasters stage's per-point loops; ``lidarctl.rasters.products``: ``_tile_and_near``,
``_membership_count`` and ``_gather_records``, the tiled rasters' binning pass, called the way each side's
``_bin_points`` calls them) against the code before the change.

Each side runs in its own process with ``PYTHONPATH`` set to its code (``--before``: a copy of the package
folders of the earlier commit, e.g. ``git archive 66bff5a lidarctl aerotri ortho | tar -x -C DIR``), on the same
seeded points (10 % outside the grid, some NaN): SHA-256 of every output array and CPU seconds per call (the
median of 7 calls after a warm-up call that compiles or loads the kernels; the sides alternate ``--rounds`` times
and each side's least median is reported, as the machine's load changes).

    python bench/eval_kernel_tuples.py --before DIR [--points 2000000] [--rounds 3] [--only CALL]
        [--json bench/results/kernel_tuples.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _measure(n_points: int, only: list[str] | None = None) -> dict:
    import numpy as np

    from lidarctl.rasters.cells import CellStats
    from lidarctl.raster_ops import reduce_grid, sample_bilinear

    rng = np.random.default_rng(40)
    cell_m, x0, y0, nrows, ncols = 0.5, 1000.0, 2000.0, 900, 1100
    grid = dict(cell_m=cell_m, x0=x0, y0=y0, nrows=nrows, ncols=ncols)
    x = rng.uniform(x0 - 0.05 * ncols * cell_m, x0 + 1.05 * ncols * cell_m, n_points)
    y = rng.uniform(y0 - 0.05 * nrows * cell_m, y0 + 1.05 * nrows * cell_m, n_points)
    z = rng.normal(100.0, 5.0, n_points)
    x[::997] = np.nan
    dem = rng.normal(100.0, 2.0, (nrows, ncols))
    # a window of the grid (rows 100.., cols 200..) and the points inside it, with classes and returns
    inside = (x >= x0 + 200 * cell_m) & (x < x0 + 900 * cell_m) & (y >= y0 + 100 * cell_m) & (y < y0 + 700 * cell_m)
    wx, wy, wz = x[inside], y[inside], z[inside]
    cls = rng.choice(np.array([1, 2, 4, 5, 6, 7, 9], np.uint8), len(wx))
    rn = rng.integers(1, 3, len(wx)).astype(np.uint8)
    inten = rng.integers(0, 4000, len(wx)).astype(np.uint16)

    def binning():
        from lidarctl.rasters import products as rasters

        tile_px, buffer_px, ntr, ntc = 256, 32, 4, 5
        count = np.zeros(ntr * ntc + 1, np.int64)
        if hasattr(rasters, "_gather_columns"):         # fields as columns (i41-rasters7): the same bytes as records
            lay = rasters._TileLayout(cell_m, x0, y0, tile_px, buffer_px, ntr, ntc)
            rec = np.empty(rasters._membership_count(wx, wy, lay, count), [(f, t) for f, t in rasters._BIN_FIELDS])
            cols = rasters._ChunkPoints(*(np.empty(len(rec), t) for _, t in rasters._BIN_FIELDS))
            n = rasters._gather_columns(cols, count, rasters._ChunkPoints(wx, wy, wz, cls, rn, inten), lay)
            for (f, _), col in zip(rasters._BIN_FIELDS, cols):
                rec[f] = col
        elif hasattr(rasters, "_TileLayout"):
            lay = rasters._TileLayout(cell_m, x0, y0, tile_px, buffer_px, ntr, ntc)
            rec = np.empty(rasters._membership_count(wx, wy, lay, count), rasters._BIN_DTYPE)
            n = rasters._gather_records(rec, count, rasters._ChunkPoints(wx, wy, wz, cls, rn, inten), lay)
        else:
            rec = np.empty(rasters._membership_count(wx, wy, cell_m, x0, y0, tile_px, buffer_px, ntr, ntc, count),
                           rasters._BIN_DTYPE)
            n = rasters._gather_records(rec, count, wx, wy, wz, cls, rn, inten, cell_m, x0, y0, tile_px, buffer_px,
                                        ntr, ntc)
        return np.concatenate([np.frombuffer(rec.tobytes(), np.uint8).astype(float), count.astype(float), [n]])

    def cells():
        st = CellStats(cell_m, x0, y0, 600, 700, row0=100, col0=200)
        for part in np.array_split(np.arange(len(wx)), 3):   # three chunks: the per-chunk sums
            st.add(wx[part], wy[part], wz[part], cls[part], rn[part], inten[part])
        st.add_chm(wx, wy, wz, cls, dem[100:700, 200:900])
        return np.concatenate([st._counts.ravel().astype(float), st._sums.ravel(), st.chm])
    calls = {
        "reduce_grid_min": lambda: reduce_grid(x, y, z, **grid, how="min"),
        "reduce_grid_max": lambda: reduce_grid(x, y, z, **grid, how="max"),
        "reduce_grid_mean": lambda: reduce_grid(x, y, z, **grid, how="mean"),
        "sample_bilinear": lambda: sample_bilinear(dem, np.nan_to_num(x, nan=x0), y, cell_m=cell_m, x0=x0, y0=y0),
        "sample_bilinear_window": lambda: sample_bilinear(dem[100:700, 200:900], np.nan_to_num(x, nan=x0), y,
                                                          cell_m=cell_m, x0=x0, y0=y0, row0=100, col0=200),
        "cell_stats_add_and_chm": cells,
        "rasters_binning": binning,
    }
    out = {}
    for name, fn in calls.items():
        if only and name not in only:
            continue
        first = fn()
        cpu = []
        for _ in range(7):
            c0 = time.process_time()
            a = fn()
            cpu.append(time.process_time() - c0)
            assert np.array_equal(a, first, equal_nan=True)
        out[name] = {"sha256": hashlib.sha256(np.ascontiguousarray(first).tobytes()).hexdigest(),
                     "cpu_s_median": float(np.median(cpu)), "cpu_s_all": [round(c, 4) for c in cpu]}
    return out


def _side(code: Path, n_points: int, only: list[str] | None = None) -> dict:
    from lidar_common import measure_on_tree

    return measure_on_tree(code, __file__, ["--points", n_points, *[a for name in only or [] for a in ("--only", name)]])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="folder holding the earlier commit's lidarctl, aerotri, ortho")
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--rounds", type=int, default=3, help="before/after runs, alternating")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--only", action="append", help="measure only this call (repeatable)")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.measure:
        print(json.dumps(_measure(a.points, a.only)))
        return
    if a.before is None:
        ap.error("--before DIR is needed")
    # the sides alternate (the machine's load changes): the least of each side's medians
    from lidar_common import alternate_rounds

    runs = alternate_rounds(a.before, ROOT, a.rounds, lambda code, side, k: _side(code, a.points, a.only))
    before, after = runs["before"][0], runs["after"][0]
    rows = {k: {"identical": all(r[k]["sha256"] == before[k]["sha256"] for side in runs.values() for r in side),
                "cpu_s_before": round(min(r[k]["cpu_s_median"] for r in runs["before"]), 4),
                "cpu_s_after": round(min(r[k]["cpu_s_median"] for r in runs["after"]), 4)}
            for k in before}
    for k, r in rows.items():
        print(f"{k:24s} identical {r['identical']}  CPU {r['cpu_s_before']:.4f} -> {r['cpu_s_after']:.4f} s a call")
    if a.json:
        doc = {"points": a.points, "rounds": a.rounds, "load_average": list(os.getloadavg()), "calls": rows,
               "runs": runs}
        a.json.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
