"""The true ortho's march taken apart in place: every ``ortho.rectify.occlusion_mask`` call of one ``rectify_block``
run again on its visible and on its occluded candidates apart (the march's own answer), each with and without the
z-buffer's hint, thread CPU summed per part; and, with ``--against DIR`` (another checkout's packages, e.g. ``git
archive main aerotri lidarctl ortho``), every call run with that code's march kernel too (its CPU, and the points
whose answer differs). The first two calls of each are not counted (numba compiles there).

A project prepared by ``bench/true_ortho_footprints_cost.py`` (its ``--work`` holds one project per way) and the way
to rectify it as (``--way``, e.g. true_ortho_crowns_footprints). Counts are per block; the calls run one at a time.

Usage: python bench/occlusion_march_split.py PROJECT --way WAY [--frames A,B] [--against DIR]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project", type=Path)
    ap.add_argument("--way", required=True)
    ap.add_argument("--frames", default=None)
    ap.add_argument("--against", type=Path, default=None, help="another checkout's packages: its march kernel too")
    args = ap.parse_args()

    import ortho.rectify as R
    import ortho.rectify_kernels as K
    from true_ortho_footprints_cost import settings

    from ortho.block import rectify_block

    kernels = {"this": K._occlusion_kernel}
    if args.against is not None:
        spec = importlib.util.spec_from_file_location("against_kernels", args.against / "ortho" / "rectify_kernels.py")
        other = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(other)
        kernels["against"] = other._occlusion_kernel
    inner = R.occlusion_mask
    lock = threading.Lock()
    cpu: dict = {}
    counts = {"calls": 0, "visible": 0, "occluded": 0, "differ_against": 0}

    def timed(key, *a, **k):
        c = time.thread_time()
        out = inner(*a, **k)
        if counts["calls"] > 2:
            cpu[key] = cpu.get(key, 0.0) + time.thread_time() - c
        return out

    def split(*a, **k):
        with lock:  # one call at a time: the kernels are swapped module-wide
            counts["calls"] += 1
            occ = timed("as_run", *a, **k)
            cand = k.get("candidates")
            if cand is not None:
                for part, sel in (("visible", cand & ~occ), ("occluded", cand & occ)):
                    counts[part] += int(sel.sum())
                    timed(f"{part}_hint", *a, **{**k, "candidates": sel})
                    timed(f"{part}_no_hint", *a, **{**k, "candidates": sel, "near_share": None})
            if "against" in kernels:
                K._occlusion_kernel = kernels["against"]
                try:
                    theirs = timed("against", *a, **k)
                finally:
                    K._occlusion_kernel = kernels["this"]
                counts["differ_against"] += int((theirs != occ).sum())
            return occ

    R.occlusion_mask = split
    rectify_block(args.project, settings(args.project, args.way),
                  frames=args.frames.split(",") if args.frames else None)
    print(json.dumps({"project": str(args.project), "way": args.way, **counts,
                      "thread_cpu_s": {k: round(v, 3) for k, v in sorted(cpu.items())}}, indent=1))


if __name__ == "__main__":
    main()
