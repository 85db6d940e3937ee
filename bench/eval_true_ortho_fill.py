"""Where the occluded ground that the true-ortho mosaic does not fill from a frame that sees it comes from (issue 42,
"fills every occluded cell that another frame sees", target 99.5 %).

Run on the DOMs of ``bench/eval_true_ortho_occlusion.py`` (its ``--work`` folder: ``<block>/conventional`` and
``<block>/true_ortho``), with the same truth: the simulated scene rebuilt and ray cast at every DOM cell
(``Truth``, ``truth_on_grid`` of that script), the occluded ground cells being the ground cells hidden in the
nadir-most frame covering them, and of those the ones another frame sees (first hit the terrain within 0.2 m).

Each of those cells the DOM does not take from a frame that sees it (a *miss*) is put in one class:

- ``empty_every_seeing_frame_masks_it``: the DOM has no value there and every frame that sees the cell has it masked
  (over-masking; the mosaic had nothing to fill it with);
- ``empty_a_seeing_frame_has_it``: the DOM has no value although a frame that sees the cell has it valid (the mosaic
  did not try);
- ``from_a_hiding_frame_while_a_seeing_frame_has_it``: filled from a frame whose mask keeps the cell though the frame
  does not see it, while a frame that sees it has it valid (the choice of frame; split by whether that frame is the
  nadir-most one: its own mask let the hidden cell through);
- ``from_a_hiding_frame_no_seeing_frame_has_it``: filled from a frame that does not see it; no frame that sees it has
  it valid.

For the over-masked ones: how many frames see the cell, and whether the cell lies in a hole of the seeing frame's
mask or in an invalid part joined to its outside.

*Clearance*: a frame sees a cell with clearance r when it also sees the four ground points r metres from the cell's
centre along and across the horizontal direction of the ray (the line of sight shifted by r either way still reaches
the ground): a cell seen by no frame with clearance r is seen only through a sliver narrower than 2r along the edge
of what hides it, where a DSM of cells of 0.5 m, sampled and gridded (the LiDAR DSM: the highest return per cell)
cannot say whether the line of sight passes. The fill share is also given over the cells seen with clearance
r = 0.2 m (half a DOM cell of 0.4 m) and 0.25 m (half a DSM cell) by another frame; the target of the issue counts
every seen cell (``filled_from_a_frame_that_sees_share`` of ``bench/results/true_ortho_occlusion.json``, the same
figure as ``fill_share`` here).

Usage: python bench/eval_true_ortho_fill.py [--work DIR] [--blocks demo,tall] [--out FILE] [--key KEY]
(``DIR`` the ``--work`` of eval_true_ortho_occlusion.py, run first). Writes bench/results/true_ortho_fill.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, read_results, store_result  # noqa: E402

CLEARANCES_M = (0.2, 0.25)


def seen_with_clearance(truth, image_id: str, x: np.ndarray, y: np.ndarray, r_m: float) -> np.ndarray:
    """True where the frame sees all four ground points r_m from (x, y) (local metres) along and across the
    horizontal direction from the point to the frame's projection centre."""
    from eval_true_ortho_occlusion import SEES

    C = truth.centres[image_id]
    dx, dy = C[0] - x, C[1] - y
    n = np.maximum(np.hypot(dx, dy), 1e-9)
    ux, uy = dx / n, dy / n
    ok = np.ones(len(x), bool)
    for ax, ay in ((ux, uy), (-ux, -uy), (-uy, ux), (uy, -ux)):
        px, py = x + r_m * ax, y + r_m * ay
        ok &= truth.visibility(image_id, px, py, truth.scene.terrain_height(px, py)) == SEES
    return ok


WHOLE_CELL_SAMPLES = 5  # per side of a DOM cell: the straight-down rays that say whether all of it is ground


def whole_ground(truth, x: np.ndarray, y: np.ndarray, cell_m: float, n: int = WHOLE_CELL_SAMPLES) -> np.ndarray:
    """True where the straight-down surface is the terrain at all n x n points of the DOM cell of side ``cell_m``
    centred at (x, y) (local metres; points at the centres of its n x n sub-cells): a cell no roof, wall or crown
    enters in plan. A cell whose centre is ground but which a roof edge crosses is a mixed pixel: every frame's sample
    there blends the roof with the ground at the frame's own resolution, and whether its centre is seen is decided
    within a fraction of a cell of the wall."""
    from aerotri.sim.scene import KIND_TERRAIN

    o = (np.arange(n) + 0.5) / n * cell_m - cell_m / 2
    ox, oy = (a.ravel() for a in np.meshgrid(o, o))
    out = np.ones(len(x), bool)
    for a in range(0, len(x), 100_000):
        X, Y = x[a:a + 100_000], y[a:a + 100_000]
        kind, _, _ = truth.surface((X[:, None] + ox).ravel(), (Y[:, None] + oy).ravel())
        out[a:a + 100_000] = (kind.reshape(len(X), -1) == KIND_TERRAIN).all(1)
    return out


def measure_block(work: Path, name: str, *, true_ortho: Path | None = None, truth=None,
                  truth_arrays: tuple | None = None, cells_out: dict | None = None) -> dict:
    """The figures of one block: its DOMs in ``work/name/conventional`` and ``work/name/true_ortho`` (or the true
    ortho project ``true_ortho``); ``truth`` (``Truth``) and ``truth_arrays`` (``truth_on_grid``'s kind, ground,
    roof, vis, foot_nadir) when already made. ``cells_out``: receives the boolean grids ``seen_other`` (occluded
    ground another frame sees), ``miss`` and ``over`` (the misses every seeing frame masks)."""
    import cv2
    import rasterio

    import eval_true_ortho_occlusion as E
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    conv, tru = work / name / "conventional", true_ortho or work / name / "true_ortho"
    grid = OrthoGrid.union(read_index(conv).grids)
    H, W = grid.height, grid.width
    t = time.perf_counter()
    truth = truth or E.Truth(conv)
    if truth_arrays is None:
        kind, ground, roof, vis, foot_nadir, _ = E.truth_on_grid(truth, conv, grid)
    else:
        kind, ground, roof, vis, foot_nadir = truth_arrays
    vis = np.stack(vis)
    ray_cast_s = time.perf_counter() - t
    masks, _ = E.frame_masks(tru, grid)
    ids = [m[0] for m in masks]
    valid = np.stack([E.place((H, W), r0, c0, m) for _, r0, c0, m in masks])
    with rasterio.open(tru / "ortho" / "mosaic.tif") as ds:
        mg = ds.transform
        c0 = int(round((mg.c - grid.x_left_m) / grid.res_m))
        r0 = int(round((grid.y_top_m - mg.f) / grid.res_m))
        dom_valid = E.place((H, W), r0, c0, ds.read_masks(1) > 0)
        samples = ds.read()
        dom = np.stack([E.place_values((H, W), r0, c0, b) for b in samples])
        del samples
    src, _ = E.source_by_value(tru, grid, masks, dom, dom_valid)
    del dom
    sees = vis == E.SEES
    code_nadir = np.zeros((H, W), np.uint8)
    for k in range(len(ids)):
        sel = foot_nadir == k
        code_nadir[sel] = vis[k][sel]
    occl = ground & (foot_nadir >= 0) & (code_nadir >= E.ROOF)
    seen_other = occl & sees.any(0)
    vis_src = np.zeros((H, W), np.uint8)
    for k in range(len(ids)):
        vis_src[src == k] = vis[k][src == k]
    ok = seen_other & dom_valid & (vis_src == E.SEES)
    miss = seen_other & ~ok
    seeing_has_it = (sees & valid).any(0)
    from_nadir = src == foot_nadir
    over = miss & ~dom_valid & ~seeing_has_it
    choice = miss & dom_valid & seeing_has_it
    if cells_out is not None:
        cells_out.update(seen_other=seen_other, miss=miss, over=over)
    # the over-masked cells: in a hole of a seeing frame's mask (enclosed, 4-connected) or in an invalid part joined to
    # the frame's outside
    in_hole = np.zeros((H, W), bool)
    for k in range(len(ids)):
        inv = np.pad((~valid[k]).view(np.uint8), 1, constant_values=1)
        cv2.floodFill(inv, None, (0, 0), 2)
        in_hole |= sees[k] & (inv[1:-1, 1:-1] == 1)
    misses = {
        "cells": int(miss.sum()),
        "empty_every_seeing_frame_masks_it": int(over.sum()),
        "empty_a_seeing_frame_has_it": int((miss & ~dom_valid & seeing_has_it).sum()),
        "from_a_hiding_frame_while_a_seeing_frame_has_it": int(choice.sum()),
        "from_a_hiding_frame_while_a_seeing_frame_has_it_the_nadir_most": int((choice & from_nadir).sum()),
        "from_a_hiding_frame_no_seeing_frame_has_it": int((miss & dom_valid & ~seeing_has_it).sum()),
        "empty_over_masked_frames_that_see_it": {str(n): int(c) for n, c in
                                                  enumerate(np.bincount(sees[:, over].sum(0), minlength=4)) if c},
        "empty_over_masked_in_a_hole_of_a_seeing_frame": int((over & in_hole).sum()),
    }
    # hidden ground the masks keep, for the record (all frames, ground in each frame's footprint)
    hidden = ground[None] & (vis >= E.ROOF)
    masks_out = {"hidden_ground_cells_frame_by_frame": int(hidden.sum()),
                 "hidden_but_valid": int((hidden & valid).sum()),
                 "seen_ground_cells_frame_by_frame": int(sees.sum()),
                 "seen_but_masked": int((sees & ~valid).sum())}
    # clearance of what the frames see, at the occluded cells another frame sees
    cells = np.flatnonzero(seen_other)
    X, Y = truth.local_xy(grid, cells // W, cells % W)
    clear = {}
    for r_m in CLEARANCES_M:
        t = time.perf_counter()
        robust = np.zeros(len(cells), bool)
        for k, image_id in enumerate(ids):
            s = sees[k].ravel()[cells] & ~robust
            if s.any():
                robust[s] = seen_with_clearance(truth, image_id, X[s], Y[s], r_m)
        okc = ok.ravel()[cells]
        overc = over.ravel()[cells]
        clear[f"{r_m:g}"] = {
            "seen_by_another_frame_with_clearance": int(robust.sum()),
            "filled_from_a_frame_that_sees": int((robust & okc).sum()),
            "fill_share": float((robust & okc).sum() / max(1, robust.sum())),
            "misses": int((robust & ~okc).sum()),
            "misses_empty_every_seeing_frame_masks_it": int((robust & overc).sum()),
            "ray_cast_s": round(time.perf_counter() - t, 1)}
    # the same share over the cells that are ground over their whole area (no roof edge crosses them in plan: not a
    # mixed pixel; ``whole_ground``)
    t = time.perf_counter()
    whole = whole_ground(truth, X, Y, grid.res_m)
    okc = ok.ravel()[cells]
    whole_cells = {"samples_per_side": WHOLE_CELL_SAMPLES,
                   "seen_by_another_frame": int(whole.sum()),
                   "filled_from_a_frame_that_sees": int((whole & okc).sum()),
                   "fill_share": float((whole & okc).sum() / max(1, whole.sum())),
                   "misses": int((whole & ~okc).sum()),
                   "misses_in_mixed_cells": int((~whole & ~okc).sum()),
                   "mixed_cells": int((~whole).sum()),
                   "ray_cast_s": round(time.perf_counter() - t, 1)}
    if cells_out is not None:
        w = np.zeros(H * W, bool)
        w[cells] = whole
        cells_out.update(whole_ground=w.reshape(H, W))
    return {"dom_cells": int(H * W), "gsd_m": grid.res_m, "ray_cast_s": round(ray_cast_s, 1),
            "whole_ground_cells": whole_cells,
            "occluded_in_nadir_most_frame": int(occl.sum()),
            "seen_by_another_frame": int(seen_other.sum()),
            "filled_from_a_frame_that_sees": int(ok.sum()),
            "fill_share": float(ok.sum() / max(1, seen_other.sum())),
            "misses": misses, "masks": masks_out, "clearance_m": clear}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_occlusion")
    ap.add_argument("--blocks", default="demo,tall")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    ap.add_argument("--key", default=None,
                    help="write this run under KEY of --out (its blocks merged), every other key kept; "
                         "default: the top-level blocks")
    args = ap.parse_args()
    doc = read_results(args.out)
    out = {"clearances_m": list(CLEARANCES_M),
           "blocks": (doc.get(args.key, {}) if args.key else doc).get("blocks", {})}
    cpu0 = time.process_time()
    for name in args.blocks.split(","):
        out["blocks"][name] = measure_block(args.work, name)
        print(name, json.dumps(out["blocks"][name], indent=1), flush=True)
    out["commit"] = git_commit(REPO)
    out["command"] = "python bench/eval_true_ortho_fill.py " + " ".join(sys.argv[1:])
    out["cpu_s"], out["load_avg_1min_at_end"] = round(time.process_time() - cpu0, 1), os.getloadavg()[0]
    store_result(args.out, out, key=args.key)  # the other keys (earlier runs) stay as they were


if __name__ == "__main__":
    main()
