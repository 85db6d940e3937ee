"""What stops the lines of sight that clear the 2.5D surface but that the true ortho masks (issue 42, fill target
99.5 %): per (ground cell, frame) pair where the frame sees the cell (the simulator's ray cast), clears the truth's
straight-down surface (``eval_true_ortho_dsm_cell.surface_clearance``) and masks it in its true ortho, the DSM cell
that stops the march's ray and what it is.

A DOM made by ``bench/eval_true_ortho_dsm_cell.py`` (``--work DIR``, block, spec with footprints) is rectified again
(its images from the simulated project ``--src``) with ``ortho.block._frame_occluder`` wrapped to keep each frame's DSM
window and occluder; the frame masks must equal the DOM's. Each pair's ray (the pixel's centre at the height the true
ortho puts it: by its side of the roof outline, ``ortho.footprints.OutlineHeights``, or the DSM's bilinear height
before those; the point at its own column's top as the march puts it, to the frame's true centre) is walked cell by cell
with the march's own cell test (``ortho.rectify_kernels._cell_blocks``, no block bounds) to the first cell that stops
it: beside an overhang (``halo``), an overhang cell with a sub-cell mask or a whole slab, a crown's slab, a column, or
none (the march stops nothing: the mask comes from the imaging, e.g. the point projected from a height up a wall falls
outside the frame). For the overhang and half-cell blocks (sub-cell walk replayed with the nearest sub-cell's bit 2:
exact for main's rule, the first sub-cell of the nearest-bit walk for the interpolating one) the distance of the first
slab point beyond the simulator's roof outline and whether the ray enters that outline in the cell, and how far above
the eave line.

For a column block, what the truth's straight-down surface is where the ray enters the cell (ground, roof, tree;
within 1.5 m of a roof outline or not), how far the column's top stands above it and how far the entry point lies
beyond the nearest tree crown's rim (the simulator's crowns, horizontally).
The DOM's own settings: its occlusion DSM (made.json), ``+bil`` / ``+hod`` in the spec as in
``eval_true_ortho_dsm_cell.py``; a tall block with the true orientation, the demo with the project's adjusted one
(each ray to the centre the frame was rectified from).

Usage: python bench/true_ortho_fill_blockers.py --work DIR --block tall --src T1 --spec '0.5+fp7+cb' --out FILE
[--key KEY] (scratch under DIR/<block>/blockers_<spec>/).
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import shutil
import sys
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from results_json import store_result  # noqa: E402

from ortho.rectify_kernels import (_cell_stops, _continuous_patch, _dda_step, _dem_height, _next_boundary,  # noqa: E402
                                   _patch_height)


@numba.njit
def first_blocking_cell(X, Y, grid, walls, C, tolerance_m, own_column_m, wall_rise_m, ground, Z=np.nan):
    """The march's ray from (X, Y) at height ``Z`` (NaN: the DSM's bilinear height; its own column's top where that
    lies more than ``own_column_m`` below, unless on continuous surface) to ``C``: the first cell (i, j) ``_cell_stops`` (walls
    beyond a rise of ``wall_rise_m``, continuous surface over the cells ``ground`` alone) says stops it and where
    the ray enters it (s, cells), and (Z, rise, gx, gy, ex, ey); i = -1 for none."""
    dsm, x0, y0, res = grid
    if Z != Z:
        Z = _dem_height(grid, X, Y)
    dh, dw = dsm.shape
    vx, vy = C[0] - X, C[1] - Y
    hd = math.sqrt(vx * vx + vy * vy)
    gx = math.floor((X - x0) / res * 1024.0 + 0.5) / 1024.0
    gy = math.floor((y0 - Y) / res * 1024.0 + 0.5) / 1024.0
    ex, ey = vx / hd, -vy / hd
    j, i = int(math.floor(gx)), int(math.floor(gy))
    a, b = int(math.floor(gy - 0.5)), int(math.floor(gx - 0.5))
    if dsm[i, j] < Z - own_column_m and not (_continuous_patch(dsm, ground, a, b, wall_rise_m) and
                                             Z <= _patch_height(dsm, a, b, gx - b - 0.5, gy - a - 0.5) + own_column_m):
        Z = dsm[i, j]
    rise = (C[2] - Z) / hd * res
    step = (1 if ey > 0 else -1, 1 if ex > 0 else -1)
    between = (1.0 / abs(ex) if abs(ex) > 1e-12 else 1e30, 1.0 / abs(ey) if abs(ey) > 1e-12 else 1e30)
    s, sx, sy, i, j = _dda_step((_next_boundary(gx, ex, j), _next_boundary(gy, ey, i)), between, (i, j), step)
    while i >= 0 and j >= 0 and i < dh and j < dw:
        if _cell_stops(dsm, ground, wall_rise_m, i, j, (Z, rise, gx, gy, ex, ey, tolerance_m), (s, min(sx, sy)), walls):
            return i, j, s, min(sx, sy), Z, rise, gx, gy, ex, ey
        s, sx, sy, i, j = _dda_step((sx, sy), between, (i, j), step)
    return -1, -1, 0.0, 0.0, Z, rise, gx, gy, ex, ey


def main() -> None:
    import shapely

    import eval_true_ortho_occlusion as E
    import ortho.block as B
    from eval_true_ortho_dsm_cell import CLEAR
    from ortho.block import read_index
    from ortho.grid import OrthoGrid
    from ortho.rectify import OWN_COLUMN_M, WALL_SLOPE_DEG, _height_grid, ground_cells
    from ortho.settings import RectifySettings

    from aerotri.sim.scene import KIND_ROOF, KIND_TERRAIN, KIND_TREE

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", default="tall")
    ap.add_argument("--src", type=Path, required=True, help="the simulated project (its images)")
    ap.add_argument("--spec", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--key", default="blockers")
    args = ap.parse_args()
    W = args.work / args.block
    conv, dom = W / "conventional", W / f"true_ortho_dsm_{args.spec}"
    grid = OrthoGrid.union(read_index(conv).grids)
    z = np.load(W / "truth_on_grid.npz")
    ground, vis, foot_nadir = z["ground"], z["vis"], z["foot_nadir"]
    codes = np.load(W / "surface_clearance.npz")["codes"]
    A = W / f"blockers_{args.spec}"
    shutil.rmtree(A, ignore_errors=True)
    shutil.copytree(dom, A, ignore=shutil.ignore_patterns("ortho"))
    shutil.copytree(args.src / "images", A / "images")
    kept, inner = {}, B._frame_occluder

    def keep(task, surface, dem, crs, crown=None, *rest):
        out = inner(task, surface, dem, crs, crown, *rest)
        occ, sides = out if isinstance(out, tuple) else (out, None)  # main's before the heights by side: occ alone
        # the occlusion test's DSM window, the heights' (the DSM's bilinear heights without sides), the centre
        kept[task.image_id] = (surface, occ, sides, rest[0] if rest else surface, np.asarray(task.centre_m, float),
                               ground_cells(surface, dem))
        return out

    made = json.loads((dom / "made.json").read_text())
    tall = args.block.startswith("tall")   # the true orientation; the demo its adjusted one (the project's at/)
    B._frame_occluder = keep
    switches = (B.HEIGHTS_BY_OUTLINE, B.OUTLINES_OF_THE_OCCLUSION_TEST)   # the spec's, as eval_true_ortho_dsm_cell
    B.HEIGHTS_BY_OUTLINE = "bil" not in args.spec.split("+")
    B.OUTLINES_OF_THE_OCCLUSION_TEST = "hod" not in args.spec.split("+")
    crown = A / "lidar_out" / "crown_base.tif"
    B.rectify_block(A, RectifySettings(true_ortho=True, dsm=str(A / "lidar_out" / "dsm.tif"),
                                       footprints=str(A / "truth" / "footprints.gpkg"),
                                       crown_base=str(crown) if crown.exists() else None,
                                       occlusion_dsm=made.get("occlusion_dsm")),
                    **({"eo_path": A / "truth" / "eo.txt", "camera_path": A / "truth" / "camera.toml"} if tall else {}))
    B._frame_occluder = inner
    B.HEIGHTS_BY_OUTLINE, B.OUTLINES_OF_THE_OCCLUSION_TEST = switches
    H, Wd = grid.height, grid.width
    masks, _ = E.frame_masks(A, grid)
    valid = np.stack([E.place((H, Wd), r0, c0, m) for _, r0, c0, m in masks])
    valid_dom = np.stack([E.place((H, Wd), r0, c0, m) for _, r0, c0, m in E.frame_masks(dom, grid)[0]])
    if not (valid == valid_dom).all():
        raise SystemExit(f"{dom}: the frame masks made again differ from the DOM's")
    ids = [m[0] for m in masks]
    sees = vis == E.SEES
    code_nadir = np.zeros((H, Wd), np.uint8)
    for k in range(len(ids)):
        code_nadir[foot_nadir == k] = vis[k][foot_nadir == k]
    seen_other = ground & (foot_nadir >= 0) & (code_nadir >= E.ROOF) & sees.any(0)
    pairs = np.argwhere(seen_other[None] & sees & (codes == CLEAR) & ~valid)
    truth = E.Truth(conv)
    org = np.asarray(truth.origin, float)
    buildings = truth.scene.buildings
    tree = shapely.STRtree([b.outline for b in buildings])
    xs, ys = grid.centres()
    kinds, beyond, never, above = collections.Counter(), collections.defaultdict(list), collections.Counter(), \
        collections.defaultdict(list)
    columns, column_excess, crown_gap = collections.Counter(), collections.defaultdict(list), collections.defaultdict(list)
    crowns = np.array([(c[0], c[1], ac[0]) for c, ac in zip(truth.scene.tree_c, truth.scene.tree_ac)]).reshape(-1, 3)
    for f, r, c in pairs:
        h, occ, sides, hz, C, ground = kept[ids[f]]
        # the point's height as the true ortho puts it: by its side of the roof outline with ``sides``, else the
        # bilinear height of the DSM of the heights (``hz``: dsm.tif where the occlusion test has its own raster)
        p = shapely.Point(float(xs[c]), float(ys[r]))
        within = sides is not None and len(sides.tree.query(p, predicate="intersects")) > 0
        Z = float((hz if sides is None else sides.roof if within else sides.ground).sample(
            np.array([xs[c]]), np.array([ys[r]]))[0])
        walls = (True, occ.base_m, occ.slab_top_m, occ.sub_index, occ.sub_masks, occ.sub) + \
            ((occ.sub_margin_cm,) if hasattr(occ, "sub_margin_cm") else ())  # (main's march: no margins)
        i, j, s_in, s_out, Z, rise, gx, gy, ex, ey = first_blocking_cell(float(xs[c]), float(ys[r]), _height_grid(h),
                                                                         walls, C, 0.3, OWN_COLUMN_M,
                                                                         h.res_m * math.tan(math.radians(WALL_SLOPE_DEG)),
                                                                         ground, Z)
        if i < 0:
            kinds["none"] += 1
            continue
        k, base = int(occ.sub_index[i, j]), float(occ.base_m[i, j])
        kind = ("column" if base == -np.inf else "crown" if k == -2 else "halo" if k <= -3 else
                "overhang_mask" if k >= 0 and not occ.sub_masks[k, 0, 0] & 4 else "overhang_whole")
        kinds[kind] += 1
        if kind == "column":   # what the truth's straight-down surface is where the ray enters the column
            ex_, ey_ = (h.x_left_m + (gx + ex * s_in) * h.res_m - org[0], h.y_top_m - (gy + ey * s_in) * h.res_m - org[1])
            tk, tz, _ = truth.surface(np.array([ex_]), np.array([ey_]))
            what = {KIND_TERRAIN: "ground", KIND_ROOF: "roof", KIND_TREE: "tree"}.get(int(tk[0]), "other")
            q = shapely.points(ex_, ey_)
            d = float(shapely.distance(buildings[int(tree.nearest(q))].outline, q))
            columns[what + (" within 1.5 m of a roof outline" if d <= 1.5 else "")] += 1
            if len(crowns):   # how far beyond the nearest tree crown's rim (horizontally; negative: within it)
                crown_gap[what].append(float((np.hypot(crowns[:, 0] - ex_, crowns[:, 1] - ey_) - crowns[:, 2]).min()))
            column_excess[what].append(float(h.heights_m[i, j]) - org[2] - float(tz[0]))
            continue
        if kind not in ("halo", "overhang_mask", "overhang_whole"):
            continue
        first, s, m = None, s_in, (-3 - k if k <= -3 else k)
        if kind == "overhang_whole":
            first = s_in
        while first is None and s <= s_out:
            a = min(max(int((gy + ey * s - i) * occ.sub), 0), occ.sub - 1)
            b = min(max(int((gx + ex * s - j) * occ.sub), 0), occ.sub - 1)
            first = s if occ.sub_masks[m, a, b] & 2 else None
            s += 0.25 / occ.sub
        if first is None:
            continue

        def at(t):
            return h.x_left_m + (gx + ex * t) * h.res_m - org[0], h.y_top_m - (gy + ey * t) * h.res_m - org[1]

        p = shapely.points(*at(first))
        bld = buildings[int(tree.nearest(p))]
        beyond[kind].append(shapely.distance(bld.outline.exterior, p) * (-1 if shapely.contains(bld.outline, p) else 1))
        (x0, y0), (x1, y1) = at(s_in), at(s_out)
        inter = shapely.intersection(shapely.linestrings([[x0, y0], [x1, y1]]), bld.outline)
        if inter.is_empty:
            never[kind] += 1
            continue
        q = shapely.get_coordinates(inter)
        t = ((q[:, 0] - x0) * (x1 - x0) + (q[:, 1] - y0) * (y1 - y0)) / max(1e-12, (x1 - x0) ** 2 + (y1 - y0) ** 2)
        above[kind].append(Z - org[2] + rise * (s_in + t.min() * (s_out - s_in)) - bld.eave_z_m)
    pct = (5, 25, 50, 75, 95)
    out = {"spec": args.spec, "pairs": int(len(pairs)), "cells": int(len({(r, c) for _, r, c in pairs})),
           "blocking_cell": dict(kinds),
           "column_blocks_by_the_truths_surface_where_the_ray_enters": dict(columns),
           "column_top_above_the_truths_surface_there_m_p5_25_50_75_95": {
               k: np.percentile(v, pct).round(2).tolist() for k, v in column_excess.items()},
           "column_entry_beyond_the_nearest_crowns_rim_m_p5_25_50_75_95": {
               k: np.percentile(v, pct).round(2).tolist() for k, v in crown_gap.items()},
           "column_entry_within_1m_of_a_crowns_rim": {k: int((np.asarray(v) <= 1.0).sum()) for k, v in crown_gap.items()},
           "slab_blocks": {kind: {"replayed": len(beyond[kind]),
                                  "first_slab_point_beyond_true_outline_m_p5_25_50_75_95":
                                      np.percentile(beyond[kind], pct).round(3).tolist(),
                                  "never_enter_true_outline_in_cell": never[kind],
                                  "enter_it_above_eave_line_m_p5_25_50_75_95":
                                      np.percentile(above[kind], pct).round(3).tolist() if above[kind] else None}
                           for kind in beyond},
           "command": f"python bench/true_ortho_fill_blockers.py --work DIR --block {args.block} --src SRC "
                      f"--spec '{args.spec}' --key {args.key}"}
    print(out)
    store_result(args.out, out, key=args.key)
    shutil.rmtree(A, ignore_errors=True)


if __name__ == "__main__":
    main()
