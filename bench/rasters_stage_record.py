"""The chain's rasters stage (``write_rasters`` then ``write_crown_model``, as ``aerotri.chain.stages.run_rasters``)
under the stage record's ``measure()`` on a run's classified strips, once per source tree, each in its own process:
wall and CPU seconds, the process's peak RSS and what ``measure()`` counts as workers' peaks (issue 41: a child
process started during the stage, e.g. ``ctypes.util.find_library``'s ``ldconfig``, reported the parent's RSS as a
worker's) -> bench/results/rasters_stage_record.json.

    git archive d0d98f70 aerotri lidarctl ortho | tar -x -C /work/bench_code/d0d98f7
    nice .venv/bin/python bench/rasters_stage_record.py --run B/dmc_block_subset_2x2_run_d0d98f7 --work SCRATCH \\
        --src before=/work/bench_code/d0d98f7 --src after=. --key dmc_2x2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worker(run: str, out: str, crs: str) -> None:
    from aerotri.core.resources import measure
    from lidarctl.rasters.crown_model import write_crown_model
    from lidarctl.rasters.products import write_rasters

    classified = sorted((Path(run) / "lidar_out" / "classified").glob("*.la[sz]"))
    load0 = os.getloadavg()
    with measure() as u:
        write_rasters(classified, Path(out), 0.5, crs=crs)
        write_crown_model(classified, Path(out) / "dsm_nearest.tif", Path(out))
    print(json.dumps(dict(wall_s=round(u.wall_s, 1), cpu_s=round(u.cpu_s, 1), peak_rss_mb=round(u.peak_rss_mb, 1),
                          workers_peak_rss_mb=round(u.workers_peak_rss_mb, 1), points_files=len(classified),
                          load_1min=[round(load0[0], 2), round(os.getloadavg()[0], 2)])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", required=True, help="a chain's run folder (its lidar_out/classified)")
    ap.add_argument("--work", required=True, help="scratch folder for the rasters")
    ap.add_argument("--src", action="append", required=True, help="NAME=source tree of the package")
    ap.add_argument("--crs", default="EPSG:32649")
    ap.add_argument("--key", required=True)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "rasters_stage_record.json"))
    args = ap.parse_args()
    entry = {}
    for spec in args.src:
        name, src = spec.split("=", 1)
        out = Path(args.work) / name
        r = subprocess.run([sys.executable, __file__, "--worker", args.run, str(out), args.crs], check=True,
                           capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(Path(src).resolve())})
        entry[name] = dict(json.loads(r.stdout.strip().splitlines()[-1]), src=str(Path(src).resolve()))
        print(name, entry[name], flush=True)
    path = Path(args.out)
    results = json.loads(path.read_text()) if path.exists() else {}
    results[args.key] = dict(entry, run=args.run)
    path.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(*sys.argv[2:5])
    else:
        main()
