"""The true-ortho mosaic's misses by cause (issue 42, "fills every occluded cell that another frame sees"): each
occluded ground cell another frame sees that the DOM does not take from a frame that sees it (``eval_true_ortho_fill``'s
*miss*), put in one cause from the simulator's truth:

- ``over_masked`` (the DOM empty there, every frame that sees the cell masks it), by what the straight-down (2.5D)
  view of the scene puts in the seeing frames' lines of sight (``eval_true_ortho_dsm_cell.surface_clearance``, 0.3 m):
  ``eave`` (a roof beyond its walls: no 2.5D surface lets the line through, the footprints' outline may),
  ``crown`` (a tree crown over the line: only a crown with a base lets it through), or a seeing frame clears the 2.5D
  surface (``clears_*``): then by what comes nearest its line of sight (the 2.5D surface highest against the line,
  ``clears_near_building`` / ``clears_near_tree``, and ``clears_occlusion_dsm_nodata``: the occlusion DSM has no
  height at the cell);
- ``choice_of_frame`` (the DOM from a frame that does not see the cell while a seeing frame has it valid) and
  ``hiding_frame_only`` (no seeing frame has it valid), each by what hides the cell in the frame the DOM took it from
  (``_building``: roof or wall, ``_tree``), and whether that frame is the nadir-most one.

Run on the folders of ``bench/eval_true_ortho_dsm_cell.py`` (``--work DIR``, block ``NAME``: its conventional DOM,
truth_on_grid.npz and surface_clearance.npz) for one or more of its true-ortho projects
(``true_ortho_dsm_<spec>``). Usage:

    python bench/eval_true_ortho_fill_causes.py --work DIR --block demo7 --specs 'lidar+occn+fp10+crowns' [--key K]
        [--remosaic-into DIR2 --label +remosaic_NAME [--hole-margin-m M]] [--spacing 'STRIPS/*.laz']

With ``--remosaic-into`` the projects' frame orthos are mosaicked again (copies in DIR2) by the checkout the script
runs from (main's mosaic: the script run from a ``git archive`` of main, with this checkout's venv), the same DOMs'
truth; also the DOM's ghosts and roofs. ``--spacing``: the crown model's point spacing of the block's classified
strips from their box and from occupied cells. Writes bench/results/true_ortho_fill.json key K (``fill_causes`` by
default), block NAME (the 2026-11-30 run: ``fill_causes9``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, read_results, store_result  # noqa: E402


def nearest_approach(truth, image_id: str, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Along the line of sight from ground points (local x, y) to the frame's true projection centre: the kind of the
    2.5D surface other than the terrain where it stands highest against the line (``aerotri.sim.scene`` KIND_*; -1:
    terrain only) and by how much (m, negative: below the line), every ``STEP_M`` horizontally from STEP_M on."""
    from eval_true_ortho_dsm_cell import RAYS_PER_CHUNK, STEP_M

    from aerotri.sim.scene import KIND_TERRAIN

    top = float(truth.accel[-1])
    C = truth.centres[image_id]
    kind_out, excess_out = np.zeros(len(x), np.int64), np.zeros(len(x))
    for a in range(0, len(x), RAYS_PER_CHUNK):
        X, Y = x[a:a + RAYS_PER_CHUNK], y[a:a + RAYS_PER_CHUNK]
        Z = truth.scene.terrain_height(X, Y)
        vx, vy, vz = C[0] - X, C[1] - Y, C[2] - Z
        hd = np.hypot(vx, vy)
        rise = vz / hd
        S = np.arange(1, int(np.ceil((top - Z.min()) / rise.min() / STEP_M)) + 1) * STEP_M
        PX, PY = X[:, None] + vx[:, None] / hd[:, None] * S, Y[:, None] + vy[:, None] / hd[:, None] * S
        kind, zs, _ = truth.surface(PX.ravel(), PY.ravel())
        excess = zs.reshape(PX.shape) - (Z[:, None] + rise[:, None] * S)
        excess[kind.reshape(PX.shape) == KIND_TERRAIN] = -np.inf   # the ground the line leaves: not what it passes
        m = np.argmax(excess, 1)
        rows = np.arange(len(X))
        kind_out[a:a + RAYS_PER_CHUNK] = np.where(np.isfinite(excess[rows, m]), kind.reshape(PX.shape)[rows, m], -1)
        excess_out[a:a + RAYS_PER_CHUNK] = excess[rows, m]
    return kind_out, excess_out


def causes(work: Path, name: str, project: Path) -> dict:
    """The misses of the true-ortho project ``project`` of block ``work/name`` by cause (module docstring)."""
    import cv2
    import rasterio

    import eval_true_ortho_occlusion as E
    from eval_true_ortho_dsm_cell import CLEAR, EAVE, TREE_CROWN, cached_truth
    from eval_true_ortho_fill import measure_block

    from aerotri.sim.scene import KIND_ROOF, KIND_TREE, KIND_WALL
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    conv = work / name / "conventional"
    grid = OrthoGrid.union(read_index(conv).grids)
    H, W = grid.height, grid.width
    kind, ground, roof, vis, foot_nadir = cached_truth(E, work / name, conv, grid)
    truth = E.Truth(conv)
    cells = {}
    fill = measure_block(work, name, true_ortho=project, truth=truth,
                         truth_arrays=(kind, ground, roof, vis, foot_nadir),
                         cells_out=cells)
    vis = np.stack(vis)
    codes = np.load(work / name / "surface_clearance.npz")["codes"]
    masks, _ = E.frame_masks(project, grid)
    ids = [m[0] for m in masks]
    valid = np.stack([E.place((H, W), r0, c0, m) for _, r0, c0, m in masks])
    with rasterio.open(project / "ortho" / "mosaic.tif") as ds:
        mg = ds.transform
        c0 = int(round((mg.c - grid.x_left_m) / grid.res_m))
        r0 = int(round((grid.y_top_m - mg.f) / grid.res_m))
        dom_valid = E.place((H, W), r0, c0, ds.read_masks(1) > 0)
        dom = np.stack([E.place_values((H, W), r0, c0, b) for b in ds.read()])
    src, _ = E.source_by_value(project, grid, masks, dom, dom_valid)
    del dom
    miss, over = cells["miss"], cells["over"]
    sees = vis == E.SEES
    seeing_has_it = (sees & valid).any(0)
    from eval_true_ortho import roof_displacements

    way = E.measure_way(project, None, grid, kind, ground, roof, list(vis), foot_nadir, E.frame_masks(conv, grid)[0])
    roofs = roof_displacements(project / "ortho" / "mosaic.tif", project / "truth" / "ortho.tif",
                               project / "truth" / "roof_corners.csv")
    out = {"fill_share": fill["fill_share"], "seen_by_another_frame": fill["seen_by_another_frame"],
           "filled_from_a_frame_that_sees": fill["filled_from_a_frame_that_sees"],
           "ghosts_building": way["ghosts"]["building"], "ghosts_tree": way["ghosts"]["tree"],
           "ghosts_building_beyond_1m_of_a_roof": way["ghosts"]["building_beyond_1m_of_a_roof"],
           "roofs_rms_gsd": roofs["rms_gsd"], "roofs_median_gsd": roofs["median_gsd"],
           "roof_corners": roofs["measured"],
           "misses": int(miss.sum()),
           # the same share over the cells ground over their whole area (``eval_true_ortho_fill.whole_ground``)
           "whole_ground_cells": fill["whole_ground_cells"]}
    # over-masked: the 2.5D blocker of the seeing frames
    rr, cc = np.nonzero(over)
    seeing = codes[:, rr, cc]
    clear = (seeing == CLEAR).any(0)
    first = np.where(seeing == 255, 255, seeing).min(0)
    out["over_masked"] = int(over.sum())
    out["over_masked_eave"] = int(((first == EAVE) & ~clear).sum())
    out["over_masked_crown"] = int(((first == TREE_CROWN) & ~clear).sum())
    out["over_masked_other_blocker"] = int((~clear).sum()) - out["over_masked_eave"] - out["over_masked_crown"]
    # the clear ones: what comes nearest the line of sight of the first frame that clears it
    k_clear = np.argmax(seeing == CLEAR, 0)
    xs, ys = grid.centres()
    near_kind = np.zeros(len(rr), np.int64)
    near_excess = np.zeros(len(rr))
    for k, image_id in enumerate(ids):
        s = clear & (k_clear == k)
        if s.any():
            near_kind[s], near_excess[s] = nearest_approach(truth, image_id, xs[cc[s]] - truth.origin[0],
                                                            ys[rr[s]] - truth.origin[1])
    occ = json.loads((project / "ortho" / "frames" / "index.json").read_text()).get("occlusion_dsm")
    nodata = np.zeros(len(rr), bool)
    if occ:
        if not Path(occ).is_absolute() and not Path(occ).exists():  # recorded relative to the harness's folder
            occ = work.parent / occ
        with rasterio.open(occ) as ds:
            z = np.array([v[0] for v in ds.sample(zip(xs[cc], ys[rr]))], float)
            nodata = ~np.isfinite(z) | ((z == ds.nodata) if ds.nodata is not None else False)
    building = np.isin(near_kind, (KIND_ROOF, KIND_WALL))
    out["over_masked_clears_occlusion_dsm_nodata"] = int((clear & nodata).sum())
    out["over_masked_clears_near_building"] = int((clear & ~nodata & building).sum())
    out["over_masked_clears_near_tree"] = int((clear & ~nodata & (near_kind == KIND_TREE)).sum())
    out["over_masked_clears_near_other"] = int(clear.sum()) - sum(
        out[f"over_masked_clears_{w}"] for w in ("occlusion_dsm_nodata", "near_building", "near_tree"))
    # the clear ones near the seeing frame's edge: within 2 m of the ground its conventional ortho covers
    conv_masks, _ = E.frame_masks(conv, grid)
    edge = np.zeros(len(rr), bool)
    for k in range(len(ids)):
        s = clear & (k_clear == k)
        if s.any():
            inside = E.place((H, W), *conv_masks[k][1:]).view(np.uint8)
            d = cv2.distanceTransform(np.pad(inside, 1), cv2.DIST_L2, 3)[1:-1, 1:-1] * grid.res_m
            edge[s] = d[rr[s], cc[s]] <= 2.0
    out["over_masked_clears_within_2m_of_the_frames_edge"] = int((clear & edge).sum())
    for what, sel in (("building", building), ("tree", near_kind == KIND_TREE)):
        q = near_excess[clear & ~nodata & sel]  # how far the 2.5D surface stays below the line of sight
        out[f"over_masked_clears_near_{what}_clearance_m_5_50_95"] = (
            [round(-float(v), 3) for v in np.percentile(q, [95, 50, 5])] if len(q) else None)
    # filled from a frame that does not see it: what hides it there
    vis_src = np.zeros((H, W), np.uint8)
    for k in range(len(ids)):
        vis_src[src == k] = vis[k][src == k]
    for what, sel in (("choice_of_frame", miss & dom_valid & seeing_has_it),
                      ("hiding_frame_only", miss & dom_valid & ~seeing_has_it)):
        out[what] = int(sel.sum())
        out[f"{what}_building"] = int((sel & np.isin(vis_src, (E.ROOF, E.WALL))).sum())
        out[f"{what}_tree"] = int((sel & (vis_src == E.TREE)).sum())
        out[f"{what}_the_nadir_most"] = int((sel & (src == foot_nadir)).sum())
    # the choice of frame: how far the pixel taken lies from the frame's mask edge (its nearest invalid pixel), and
    # whether a seeing frame that has it valid has it farther from its own
    sel = miss & dom_valid & seeing_has_it
    d_src = np.zeros((H, W), np.float32)
    d_see = np.full((H, W), -1.0, np.float32)
    for k, (_, fr0, fc0, m) in enumerate(masks):
        d = E.place_values((H, W), fr0, fc0, cv2.distanceTransform(m.view(np.uint8), cv2.DIST_L2, 3) * grid.res_m)
        at = sel & (src == k)
        d_src[at] = d[at]
        at = sel & sees[k] & valid[k]
        d_see[at] = np.maximum(d_see[at], d[at])
    if sel.any():
        out["choice_of_frame_taken_pixel_from_its_mask_edge_m_5_25_50_75_95"] = [
            round(float(v), 2) for v in np.percentile(d_src[sel], [5, 25, 50, 75, 95])]
        out["choice_of_frame_seeing_pixel_from_its_mask_edge_m_5_25_50_75_95"] = [
            round(float(v), 2) for v in np.percentile(d_see[sel], [5, 25, 50, 75, 95])]
        out["choice_of_frame_a_seeing_frame_farther_from_its_edge"] = int((d_see[sel] > d_src[sel]).sum())
    out["empty_a_seeing_frame_has_it"] = int((miss & ~dom_valid & seeing_has_it).sum())
    # the hidden ground a frame keeps valid (ghosts), by what hides it, all frames
    hidden_valid = ground[None] & valid
    out["hidden_but_valid_building"] = int((hidden_valid & np.isin(vis, (E.ROOF, E.WALL))).sum())
    out["hidden_but_valid_tree"] = int((hidden_valid & (vis == E.TREE)).sum())
    out["seen_but_masked"] = int((sees & ~valid).sum())
    return out


def cloud_spacings(pattern: str) -> dict:
    """The point spacing of the first returns of the strips ``pattern`` (a glob) as ``lidarctl.rasters.crown_model``
    takes it (their bounding box's area over their count) and from the area of the cells of 1, 2 and 4 m that hold
    one (a block of separate patches or a corridor inflates the box's, not these)."""
    import glob
    import math

    import laspy

    xs, ys = [], []
    for q in sorted(glob.glob(pattern)):
        las = laspy.read(q)
        first = (np.asarray(las.return_number) <= 1) & ~np.isin(np.asarray(las.classification), (7, 18))
        xs.append(np.asarray(las.x)[first])
        ys.append(np.asarray(las.y)[first])
    x, y = np.concatenate(xs), np.concatenate(ys)
    out = {"first_returns": len(x), "bounding_box_m": math.sqrt(np.ptp(x) * np.ptp(y) / len(x))}
    for c in (1.0, 2.0, 4.0):
        cells = np.unique(np.floor(x / c).astype(np.int64) * (1 << 32) + np.floor(y / c).astype(np.int64))
        out[f"occupied_cells_{c:g}m_m"] = math.sqrt(len(cells) * c * c / len(x))
    return out


def remosaicked(project: Path, into: Path, hole_margin_m: float | None = None) -> Path:
    """A copy of the true-ortho project ``project`` (its frame orthos, truth and settings; not its images) in
    ``into``, mosaicked again with this checkout's mosaic (once: kept when there); ``hole_margin_m``: with that
    ``HOLE_MARGIN_M``."""
    import shutil

    import eval_true_ortho_occlusion as E

    dst = into / project.name
    if not (dst / "remosaic.json").exists():
        shutil.rmtree(dst, ignore_errors=True)
        shutil.copytree(project, dst, ignore=shutil.ignore_patterns("images", "mosaic*", "seam*"), symlinks=True)
        import ortho.mosaic as om

        if hole_margin_m is not None:  # a trial of another hole margin (the mosaic's module constant)
            om.HOLE_MARGIN_M = hole_margin_m
        made = E.remosaic_dom(dst)
        (dst / "remosaic.json").write_text(json.dumps({"mosaic": made["mosaic"], "commit": git_commit(REPO)}) + "\n")
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", required=True)
    ap.add_argument("--specs", default="", help="comma-separated: the true_ortho_dsm_<spec> projects of the block")
    ap.add_argument("--key", default="fill_causes")
    ap.add_argument("--remosaic-into", type=Path, default=None,
                    help="mosaic copies of the projects again in this folder with this checkout's code, then measure")
    ap.add_argument("--hole-margin-m", type=float, default=None, help="with --remosaic-into: the mosaic's hole margin")
    ap.add_argument("--spacing", default=None, help="a glob of the block's classified strips: their point spacings")
    ap.add_argument("--label", default=None, help="the name of the results in the JSON (default: the spec)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    a = ap.parse_args()
    got = {}
    if a.spacing:
        spacing = cloud_spacings(a.spacing)
        print(a.block, "spacing", json.dumps(spacing), flush=True)
        entry = read_results(a.out).get(a.key, {})
        entry.setdefault("crown_spacing", {})[a.block] = spacing
        store_result(a.out, entry, key=a.key)
    for spec in (a.specs.split(",") if a.specs else []):
        project = a.work / a.block / f"true_ortho_dsm_{spec}"
        if a.remosaic_into is not None:
            project = remosaicked(project, a.remosaic_into / a.block, a.hole_margin_m)
        label = f"{spec}{a.label}" if a.label else spec
        got[label] = causes(a.work, a.block, project)
        print(a.block, label, json.dumps(got[label], indent=1), flush=True)
    if not got:
        return
    entry = read_results(a.out).get(a.key, {})
    entry.setdefault("blocks", {}).setdefault(a.block, {}).update(got)
    extra = f" --remosaic-into DIR2 --label '{a.label}'" if a.remosaic_into is not None else ""
    extra += f" --hole-margin-m {a.hole_margin_m:g}" if a.hole_margin_m is not None else ""
    runs = entry.setdefault("commands", {}).setdefault(a.block, [])
    if isinstance(runs, dict):
        runs = entry["commands"][a.block] = [runs]
    runs.append({
        "command": f"python bench/eval_true_ortho_fill_causes.py --work DIR --block {a.block} --specs '{a.specs}' "
                   f"--key {a.key}{extra}", "commit": git_commit(REPO)})
    store_result(a.out, entry, key=a.key)


if __name__ == "__main__":
    main()
