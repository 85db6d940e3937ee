"""The seam grid's per-cell reductions of ``ortho mosaic`` on a project's frame orthos: the OpenCV area averages of float32
indicators (up to i41-mosaic4) against ``ortho.mosaic._cells_reduce`` (uint8 AND / OR over the cells), in one process,
alternately, on every frame's validity as ``_reduce_frame`` and ``find_holes`` see it (the frame's window on whole seam
cells, framed by invalid pixels, its outside flood-filled). Both must give the same cells; CPU seconds of each (one
thread, all frames, best of ``--repeats``) and their ratio.

Usage: python bench/mosaic_cells_speed.py PROJECT [--repeats 7] [--out FILE --label KEY]
(with --out the result goes under ``cells_reduce`` of key ``--label`` of that JSON file, its other keys kept)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import rasterio

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def frame_pixels(root: Path):
    """Per frame (invalid framed (uint8: 0 valid, 1 a hole, 2 joined to the outside), factor, cells (h, w)), as
    ``_reduce_frame`` builds it on the mosaic's seam grid."""
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    index = read_index(root)
    grids = index.grids
    mosaic = OrthoGrid.union(grids)
    total_px = sum(g.width * g.height for g in grids)
    # as ``_mosaic_block`` chooses it (seam_cell_m 1.5, max_seam_cells 5e7)
    factor = max(2, int(round(1.5 / mosaic.res_m)), int(np.ceil(np.sqrt(total_px / 5e7))))
    out = []
    for e, g in zip(index.frames, grids):
        c0, r0 = g.offset_in(mosaic)
        rc0, cc0 = r0 // factor, c0 // factor
        h, w = -(-(r0 + g.height) // factor) - rc0, -(-(c0 + g.width) // factor) - cc0
        with rasterio.open(root / "ortho" / "frames" / e.file) as ds:
            ok = ds.read_masks(1) > 0
        invalid = np.ones((h * factor + 2, w * factor + 2), np.uint8)
        dy, dx = r0 - rc0 * factor, c0 - cc0 * factor
        invalid[1 + dy:1 + dy + g.height, 1 + dx:1 + dx + g.width] = ~ok
        cv2.floodFill(invalid, None, (0, 0), 2)
        out.append((invalid, factor, (h, w)))
    return out


def old_cells(invalid: np.ndarray, factor: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """(valid cells, hole cells) by OpenCV's area average of float32 indicators (the code up to i41-mosaic4)."""
    h, w = shape
    px = invalid[1:-1, 1:-1]
    bad = cv2.resize((px != 0).view(np.uint8).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    valid = bad < 0.5 / float(factor * factor)

    def any_in_cell(mask):
        return cv2.resize(mask.view(np.uint8).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0

    cells = np.where(any_in_cell(px == 1), np.where(any_in_cell(px == 2), 2, 1), 0).astype(np.uint8)
    return valid, cells


def new_cells(invalid: np.ndarray, factor: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """The same by ``_cells_reduce`` (this code)."""
    from ortho.mosaic import _cells_reduce

    px = invalid[1:-1, 1:-1]
    valid = _cells_reduce((px == 0).view(np.uint8), factor, np.bitwise_and).view(bool)
    found = _cells_reduce(px, factor, np.bitwise_or)
    cells = np.where(found & 1, np.where(found & 2, 2, 1), 0).astype(np.uint8)
    return valid, cells


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project", type=Path)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--label")
    a = ap.parse_args()
    frames = frame_pixels(a.project)
    for f in frames:
        (v0, c0), (v1, c1) = old_cells(*f), new_cells(*f)
        if not (np.array_equal(v0, v1) and np.array_equal(c0, c1)):
            raise SystemExit("the two reductions differ")
    best = {"opencv_float32": np.inf, "cells_reduce": np.inf}
    for _ in range(a.repeats):  # alternately
        for name, fn in (("opencv_float32", old_cells), ("cells_reduce", new_cells)):
            t = time.process_time()
            for f in frames:
                fn(*f)
            best[name] = min(best[name], time.process_time() - t)
    res = {"frames": len(frames), "factor": frames[0][1], "pixels": int(sum(f[0].size for f in frames)),
           "repeats": a.repeats, "same_cells": True, **{f"{k}_cpu_s": round(v, 4) for k, v in best.items()},
           "ratio": round(best["opencv_float32"] / best["cells_reduce"], 2),
           "command": "python " + " ".join(sys.argv)}
    print(json.dumps(res, indent=1))
    if a.out:
        from bench.results_json import store_result

        store_result(a.out, res, key="cells_reduce", section=a.label)


if __name__ == "__main__":
    main()
