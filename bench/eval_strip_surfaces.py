"""Strip check on blocks whose overlaps hold cells of different surfaces: `[strips.surface] max_dz_m` on and off.

A cell can be planar in two strips and still hold two surfaces: a strip looking in under a roof's eave sees the
ground where the other strip sees the roof. Such a cell adds its whole step (tens of metres beside a tall block)
to the pair's RMS, the RMSDz the LiDAR specifications and ``aerotri run``'s QA judge. This runs
``lidarctl.strips.check.analyse`` on each block's LiDAR strips (``lidar/*.laz``, the simulator's ``dmc_block``
subsets and the AHN3 Delft crop) twice in one process: with the rule off (``max_dz_m`` 1e6) and with the default
(1 m from the pair's median), and writes per pair and for all pairs the cells, RMS, NMAD and the cells left out
with the largest of their differences, into bench/results/strip_surfaces.json.

Usage: python bench/eval_strip_surfaces.py [--blocks B/dmc_block_subset_2x2 B/dmc_block_subset_2x4 ...]
       [--no-ahn3] [--out bench/results/strip_surfaces.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lidarctl.strips.check import analyse  # noqa: E402
from lidarctl.strips.overlap import SurfaceSettings, pair_diffs, read_strip_planes  # noqa: E402

BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
OFF_M = 1.0e6  # a departure no step reaches: the rule off


def evaluate(paths: list[Path], crs: str | None) -> dict:
    """Both settings on the strips' planes read once (the rule acts on the pairs, not on the planes)."""
    t0, c0 = time.perf_counter(), time.process_time()
    planes = read_strip_planes(paths, SurfaceSettings(), crs=crs)
    out = {}
    for name, m in (("off", OFF_M), ("default", SurfaceSettings().max_dz_m)):
        params = SurfaceSettings(max_dz_m=m, cell_m=planes.grid.cell_m)
        s = analyse(planes, params, paths).summary
        out[name] = dict(max_dz_m=m, all_pairs=dict(cells=s.all_pairs.n_cells, rms_m=round(s.all_pairs.rms_m, 4),
                                                     nmad_m=round(s.all_pairs.nmad_m, 4)),
                         pairs=[dict(pair=f"{p.a}-{p.b}", cells=p.diff.n_cells, rms_m=round(p.diff.rms_m, 4),
                                     nmad_m=round(p.diff.nmad_m, 4), median_m=round(p.diff.median_m, 4),
                                     different_surface_cells=p.different_surface_cells) for p in s.pairs])
    # the cells the default leaves out: their differences from the pair's median
    off_pairs, _, _ = pair_diffs(planes, SurfaceSettings(max_dz_m=OFF_M))
    steps = [float(d) for p in off_pairs for d in np.sort(np.abs(p.dz_m - np.median(p.dz_m)))[::-1]
             if d > SurfaceSettings().max_dz_m]
    out["left_out_steps_m"] = [round(v, 2) for v in sorted(steps, reverse=True)[:20]]
    out["cell_m"] = planes.grid.cell_m
    out["points"] = int(planes.n_points)
    out["cpu_s"], out["wall_s"] = round(time.process_time() - c0, 1), round(time.perf_counter() - t0, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blocks", nargs="*", type=Path,
                    default=[BLOCKS / f"dmc_block_subset_2x{n}" for n in (2, 4, 6)])
    ap.add_argument("--no-ahn3", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "strip_surfaces.json")
    args = ap.parse_args(argv)
    results = {}
    for b in args.blocks:
        results[b.name] = evaluate(sorted((b / "lidar").glob("*.la[sz]")), None)
        print(b.name, results[b.name]["off"]["all_pairs"], "->", results[b.name]["default"]["all_pairs"], flush=True)
    if not args.no_ahn3:
        p = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data")) / "ahn3_delft" / "ahn3_cropped_1.laz"
        results["ahn3_delft"] = evaluate([p], "EPSG:28992")
        print("ahn3_delft", results["ahn3_delft"]["off"]["all_pairs"], "->", results["ahn3_delft"]["default"]["all_pairs"])
    results["measured_utc"] = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    results["load_avg"] = [round(v, 2) for v in os.getloadavg()]
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
