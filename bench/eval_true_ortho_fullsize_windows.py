"""Occluded ground filled and ghosts of true orthos of full-size DMC frames, measured in windows against the
simulator (issue 42 at issue 41's size: the whole-DOM scripts hold the DOM's truth in memory, 266 M cells for the
2 x 2 subset's 4 frames at 0.1 m, and cast about a billion rays).

The frame orthos are those of ``bench/true_ortho_footprints_cost.py --project P --truth T --work DIR`` (its last
round: ``DIR/{conventional,true_ortho,true_ortho_footprints}/ortho/frames``; the chain's LiDAR DSM and adjusted
orientation). ``--all``: windows of ``--window-m`` square tiling the frame orthos' extent (the whole DOM, a window at a
time); else ``--windows`` such windows centred on building footprints drawn with ``--seed`` among those that 2 or
more frames image. In each the truth (``bench/eval_true_ortho_occlusion.py`` ``Truth``: the scene
rebuilt from truth/truth.json and the ``--set`` options the block was simulated with, ray cast) at every DOM cell:
its surface (straight down) and, for the ground cells, whether each frame that images the cell sees it from its
true projection centre. Per way:

- the DOM's source of a cell is taken as the issue asks a mosaic to take it: the most nadir frame (nearest nadir
  point, index.json ``nadir_xy_m``) whose frame ortho has a value there (``ortho mosaic`` also follows its seamlines:
  this is the rule, not the mosaic);
- occluded ground: ground cells that the most nadir frame imaging them does not see; of those some other frame
  sees, the share the rule fills from a frame that sees the cell (``filled_from_a_frame_that_sees``);
- ghosts: ground cells whose source frame does not see the ground but a roof or wall (``building``) or a tree
  (``tree``);
- frame by frame: ground cells a frame images that the truth hides but its mask keeps (``hidden_but_valid``) and
  that the truth sees but its mask drops (``visible_but_masked``).

Usage: python bench/eval_true_ortho_fullsize_windows.py --work DIR --block /work/bench_blocks/dmc_block_subset_2x2
       --set flight.strips=2 --set flight.frames_per_strip=2 [--all | --windows 6 --seed 1] [--window-m 100]
       [--out bench/results/true_ortho_fill.json] [--key dmc_2x2_windows]
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
from results_json import git_commit, store_result  # noqa: E402

WAYS = ("conventional", "true_ortho", "true_ortho_footprints")


def frames_of(work: Path):
    """Per way the frame orthos' (image_id, grid, file) and the nadir points (F, 2), in the same frame order."""
    from ortho.block import read_index

    out, nadir = {}, None
    for way in WAYS:
        index = read_index(work / way)
        out[way] = [(e.image_id, g, work / way / "ortho" / "frames" / e.file)
                    for e, g in zip(index.frames, index.grids)]
        nadir = np.array([e.nadir_xy_m for e in index.frames], float)
    return out, nadir


def window_mask(path: Path, grid, win) -> np.ndarray:
    """The frame ortho's mask (bool) on the window grid ``win`` (False outside the frame ortho)."""
    import rasterio
    from rasterio.windows import Window

    c0, r0 = win.offset_in(grid)
    out = np.zeros((win.height, win.width), bool)
    a0, b0 = max(r0, 0), max(c0, 0)
    a1, b1 = min(r0 + win.height, grid.height), min(c0 + win.width, grid.width)
    if a1 > a0 and b1 > b0:
        with rasterio.open(path) as ds:
            out[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = ds.read_masks(1, window=Window(b0, a0, b1 - b0, a1 - a0)) > 0
    return out


def measure_window(truth, frames: dict, nadir: np.ndarray, win) -> dict:
    from eval_true_ortho_occlusion import ROOF, SEES, TREE, WALL

    from aerotri.sim.scene import KIND_TERRAIN

    H, W = win.height, win.width
    xs, ys = win.centres()
    X = np.broadcast_to(xs[None, :] - truth.origin[0], (H, W)).ravel()
    Y = np.broadcast_to(ys[:, None] - truth.origin[1], (H, W)).ravel()
    kind, _, _ = truth.surface(X, Y)
    ground = kind == KIND_TERRAIN
    F = len(nadir)
    valid = {way: np.stack([window_mask(p, g, win).ravel() for _, g, p in frames[way]]) for way in WAYS}
    imaged = valid["conventional"]  # the frame's footprint on the DEM: every cell the frame images
    code = np.zeros((F, H * W), np.uint8)
    for f, (image_id, _, _) in enumerate(frames["conventional"]):
        idx = np.flatnonzero(ground & imaged[f])
        if idx.size:
            code[f, idx] = truth.visibility(image_id, X[idx], Y[idx], truth.scene.terrain_height(X[idx], Y[idx]))
    # frames by distance of the cell from their nadir points, nearest first
    dist = np.stack([np.hypot(xs[None, :] - nx, ys[:, None] - ny).ravel() for nx, ny in nadir])
    cells = np.arange(H * W)
    nadir_most = np.argmin(np.where(imaged, dist, np.inf), axis=0)
    any_imaged = imaged.any(axis=0)
    sees = code == SEES
    occluded = ground & any_imaged & ~sees[nadir_most, cells]
    seen_elsewhere = occluded & (sees & imaged).any(axis=0)
    out = {"cells": H * W, "ground": int((ground & any_imaged).sum()), "occluded_ground": int(occluded.sum()),
           "occluded_ground_another_frame_sees": int(seen_elsewhere.sum()),
           "occluded_ground_no_frame_sees": int((occluded & ~seen_elsewhere).sum()), "ways": {}}
    for way in WAYS:
        v = valid[way]
        src = np.argmin(np.where(v, dist, np.inf), axis=0)
        has = v.any(axis=0)
        c = np.where(has, code[src, cells], 0)
        g = ground & any_imaged
        out["ways"][way] = {
            "filled_from_a_frame_that_sees": int((seen_elsewhere & has & (c == SEES)).sum()),
            "ghosts_building": int((g & has & np.isin(c, (ROOF, WALL))).sum()),
            "ghosts_tree": int((g & has & (c == TREE)).sum()),
            "ground_left_empty": int((g & ~has).sum()),
            "occluded_no_frame_sees_left_empty": int((occluded & ~seen_elsewhere & ~has).sum()),
            "hidden_but_valid": int((ground & imaged & ~sees & v).sum()),
            "visible_but_masked": int((ground & imaged & sees & ~v).sum()),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", type=Path, required=True, help="the simulated block (its truth/)")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--windows", type=int, default=6)
    ap.add_argument("--all", action="store_true", help="windows tiling the whole extent of the frame orthos")
    ap.add_argument("--window-m", type=float, default=100.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    ap.add_argument("--key", default="dmc_2x2_windows")
    args = ap.parse_args()
    import shapely
    from eval_true_ortho_occlusion import Truth

    t0, c0 = time.perf_counter(), time.process_time()
    truth = Truth(args.block, tuple(args.overrides))
    frames, nadir = frames_of(args.work)
    grids = [g for _, g, _ in frames["conventional"]]
    res = grids[0].res_m
    feats = json.loads((args.block / "truth" / "buildings.geojson").read_text())["features"]
    cx, cy = shapely.get_coordinates(shapely.centroid(np.array(
        [shapely.geometry.shape(f["geometry"]) for f in feats if f["properties"]["part"] == "footprint"]))).T
    n_in = sum(((cx >= g.x_left_m) & (cx <= g.x_left_m + g.width * res) & (cy <= g.y_top_m)
                & (cy >= g.y_top_m - g.height * res)).astype(int) for g in grids)
    half = int(round(0.5 * args.window_m / res))
    ref = grids[0]
    if args.all:  # window corners (col, row in ref) tiling the union of the frame grids
        offs = np.array([g.offset_in(ref) for g in grids])
        ends = offs + np.array([(g.width, g.height) for g in grids])
        corners = [(c, r) for r in range(int(offs[:, 1].min()), int(ends[:, 1].max()), 2 * half)
                   for c in range(int(offs[:, 0].min()), int(ends[:, 0].max()), 2 * half)]
    else:
        pick = np.random.default_rng(args.seed).permutation(np.flatnonzero(n_in >= 2))
        corners, chosen = [], []
        for k in pick:
            if len(corners) == args.windows:
                break
            if any(abs(cx[k] - x) < args.window_m and abs(cy[k] - y) < args.window_m for x, y in chosen):
                continue  # windows apart
            chosen.append((cx[k], cy[k]))
            corners.append((int(round((cx[k] - ref.x_left_m) / res)) - half, int(round((ref.y_top_m - cy[k]) / res)) - half))
    rows, total = [], {}
    for c, r in corners:
        win = ref.window(c, r, 2 * half, 2 * half)
        row = measure_window(truth, frames, nadir, win)
        if row["ground"] == 0:
            continue
        row["centre_xy_m"] = [round(win.x_left_m + half * res, 2), round(win.y_top_m - half * res, 2)]
        rows.append(row)
        print(len(rows), "of", len(corners), json.dumps(row)[:200], flush=True)
        for key, v in row.items():
            if isinstance(v, int):
                total[key] = total.get(key, 0) + v
        for way, d in row["ways"].items():
            tw = total.setdefault("ways", {}).setdefault(way, {})
            for key, v in d.items():
                tw[key] = tw.get(key, 0) + v
    for way, d in total["ways"].items():
        d["filled_share"] = round(d["filled_from_a_frame_that_sees"] / max(1, total["occluded_ground_another_frame_sees"]), 4)
    out = {"block": str(args.block), "work": str(args.work), "overrides": args.overrides, "window_m": args.window_m,
           "all": bool(args.all),
           "res_m": res, "windows": rows, "all_windows": total,
           "cpu_s": round(time.process_time() - c0, 1), "wall_s": round(time.perf_counter() - t0, 1),
           "load_avg_1min": round(os.getloadavg()[0], 2),
           "command": "python bench/eval_true_ortho_fullsize_windows.py " + " ".join(sys.argv[1:]),
           "commit": git_commit(REPO)}
    print(json.dumps(total, indent=1))
    store_result(args.out, out, key=args.key)


if __name__ == "__main__":
    main()
