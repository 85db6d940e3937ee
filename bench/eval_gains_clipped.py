"""offsets-fixes2 item 3 for the default gains: the gains-only balance with and without the cells either frame has at
white or black left out of the overlaps' means (``balance_gains(exclude_clipped=True)``, what ``--offsets`` now does)
-> bench/results/gains_clipped.json.

Per block (a copy of a rectified project, the original never written): ``mosaic_block`` as it is (default gains), then
with ``balance_gains`` given ``exclude_clipped=True``; for both the saturated shares and mean DN of the mosaic
(``eval_mosaic_clipping.saturation``) and the overlap differences through the gains at every ``--step``-th pixel
neither frame has at white (``eval_mosaic_clipping.overlap_differences``: pixel RMS, pair-mean RMS, DN). Nothing tuned.

Usage: python bench/eval_gains_clipped.py NAME=PROJECT [...] [--work DIR] [--step 4]
"""

from __future__ import annotations

import argparse
import functools
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import eval_mosaic_clipping as emc  # noqa: E402

from ortho import mosaic as M  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("blocks", nargs="+", help="NAME=PROJECT (a project with ortho/frames made)")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/offsets-fixes2/gains_clipped"))
    ap.add_argument("--step", type=int, default=4)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "gains_clipped.json")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    results = {"step_px": args.step, "blocks": {}}
    original = M.balance_gains
    for spec in args.blocks:
        name, src = spec.split("=", 1)
        root = args.work / name
        emc.copy_project(Path(src), root)
        block, gains = {"source": src}, {}
        for label, exclude in (("default", False), ("without_clipped_cells", True)):
            M.balance_gains = functools.partial(original, exclude_clipped=exclude)
            try:
                t = time.process_time()
                M.mosaic_block(root)
            finally:
                M.balance_gains = original
            summary = json.loads((root / "ortho" / "mosaic.json").read_text())
            white = summary["white_level"]["value"]
            gains[label] = np.array(list(summary["gains"].values()))
            block[label] = {"cpu_s": round(time.process_time() - t, 1), **emc.saturation(root, white),
                            "gains_min": float(gains[label].min()), "gains_max": float(gains[label].max())}
            print(name, label, json.dumps(block[label]), flush=True)
        block["gains_max_rel_change"] = float(np.abs(gains["without_clipped_cells"] / gains["default"] - 1).max())
        block["overlap_differences"] = emc.overlap_differences(
            root, white, {"no gains": np.ones_like(gains["default"]), **gains}, args.step)
        print(name, "overlaps", json.dumps(block["overlap_differences"]), flush=True)
        results["blocks"][name] = block
        shutil.rmtree(root)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("->", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
