"""What internal overviews cost in a frame ortho ([rectify] overviews, ortho.block.add_overviews).

Copies each given frame ortho (read only) into a scratch folder, adds the overviews there and measures the CPU
seconds (this process, GDAL's threads included), the file size before and after, and checks that the full
resolution samples and the mask are unchanged. The frame's rectification cost beside it is the rectify stage's
CPU seconds per frame from the project's stamp (work/stages/rectify.json) of the run that made the frames.

    .venv/bin/python bench/frame_overviews.py --scratch /work/tmp/frame_overviews \\
        /work/demo_clone5/out/demo/project /work/bench_blocks/dmc_block_subset_2x4_run_i41scale3:s01_001

Each argument is a project folder (every frame of ortho/frames) or PROJECT:IMAGE_ID (that frame only). Writes
bench/results/frame_overviews.json.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np
import rasterio

from ortho.block import add_overviews

RESULT = Path(__file__).parent / "results" / "frame_overviews.json"


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def same_full_resolution(a, b) -> bool:
    with rasterio.open(a) as x, rasterio.open(b) as y:
        return all(np.array_equal(x.read(i), y.read(i)) for i in range(1, x.count + 1)) and \
            np.array_equal(x.read_masks(1), y.read_masks(1))


def one_project(arg: str, scratch: Path) -> dict:
    root, _, image_id = arg.partition(":")
    frames = sorted((Path(root) / "ortho" / "frames").glob(f"{image_id or '*'}.tif"))
    stamp = json.loads((Path(root) / "work" / "stages" / "rectify.json").read_text())
    rectify_cpu_per_frame = stamp["usage"]["cpu_s"] / stamp["result"]["frames"]
    rows = []
    for f in frames:
        out = scratch / f"{Path(root).name}_{f.name}"
        shutil.copy(f, out)
        t, c = time.perf_counter(), cpu_s()
        add_overviews(out)
        wall, cpu = time.perf_counter() - t, cpu_s() - c
        with rasterio.open(out) as ds:
            rows.append(dict(frame=f.name, width=ds.width, height=ds.height, bands=ds.count, dtype=ds.dtypes[0],
                             overviews=ds.overviews(1), cpu_s=round(cpu, 3), wall_s=round(wall, 3),
                             mb_before=round(f.stat().st_size / 1e6, 2), mb_after=round(out.stat().st_size / 1e6, 2),
                             full_resolution_unchanged=same_full_resolution(f, out)))
        out.unlink()
    cpu = sum(r["cpu_s"] for r in rows) / len(rows)
    return dict(project=root, frames=rows, overview_cpu_s_per_frame=round(cpu, 3),
                rectify_cpu_s_per_frame=round(rectify_cpu_per_frame, 3),
                rectify_stamp=dict(cpu_s=stamp["usage"]["cpu_s"], frames=stamp["result"]["frames"]),
                ratio_overviews_to_rectify=round(cpu / rectify_cpu_per_frame, 3),
                size_ratio=round(sum(r["mb_after"] for r in rows) / sum(r["mb_before"] for r in rows), 3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("projects", nargs="+")
    ap.add_argument("--scratch", type=Path, required=True)
    a = ap.parse_args()
    a.scratch.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()
    out = dict(blocks=[one_project(p, a.scratch) for p in a.projects], load_avg_start=load, load_avg_end=os.getloadavg(),
               gdal=rasterio.__gdal_version__)
    for b in out["blocks"]:
        print(f"{b['project']}: {len(b['frames'])} frames, overviews {b['overview_cpu_s_per_frame']} CPU-s per frame, "
              f"rectify {b['rectify_cpu_s_per_frame']} (ratio {b['ratio_overviews_to_rectify']}), size x{b['size_ratio']}, "
              f"full resolution unchanged: {all(r['full_resolution_unchanged'] for r in b['frames'])}")
    print(f"load average {load} -> {out['load_avg_end']}")
    RESULT.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
