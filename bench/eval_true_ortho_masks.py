"""The occlusion masks of ``ortho rectify --true-ortho`` against the simulator's visibility, frame by frame (issue 42).

For every frame of a simulated project, on the frame's own ortho grid: the mask of its true ortho (rectified on
the DSM, occluded pixels masked, as ``ortho rectify --true-ortho --dsm`` makes it, ``ortho.rectify.rectify_frame``)
against the truth: the scene rebuilt from ``truth/truth.json`` and ray cast (``aerotri.sim.raycast``) from the
frame's true projection centre to the terrain point of every ground cell (a cell whose straight-down ray meets the
terrain first): the frame *sees* the cell when that ray's first hit is the terrain within 0.2 m of the point
(as ``bench/eval_true_ortho_occlusion.py``).

Per frame, over the ground cells the frame images (its conventional footprint):

- ``hidden_but_valid``: the truth hides the cell, the mask keeps it (ghosts in the mosaic);
- ``visible_but_masked``: the truth sees it, the mask drops it (fill lost);
- each split by where the cell lies: within one cell (8-neighbour) of ground the frame sees or is hidden from
  (``edge``: the boundary of a hidden area, where a DSM sampled on its grid decides to within about a cell), and
  by its distance from the nearest roof cell;
- ``hidden_but_valid`` split by the step that let it through: the march over every pixel (no z-buffer) hides it
  too (``zbuffer_missed``: the z-buffer did not make it a candidate) or not (``march_missed``).

Usage: python bench/eval_true_ortho_masks.py PROJECT [PROJECT ...] [--truth-orientation] [--columns] [--out FILE]
PROJECT is a simulated project with ``truth/`` (``aerotri sim``); the DSM is ``lidar_out/dsm.tif`` when it exists,
else ``truth/dsm.tif`` (the simulator's exact one, 0.5 m point samples of the surface); the orientation the chain's
``at/eo.txt`` when it exists unless ``--truth-orientation`` (then ``truth/eo.txt`` and ``truth/camera.toml``).
Writes bench/results/true_ortho_masks.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from bench.results_json import git_commit, store_result  # noqa: E402

ROOF_BANDS_M = (1.0, 3.0)  # distance bands from the nearest roof cell


def frame_inputs(project: Path, truth_orientation: bool):
    """The block (camera, orientation) as ``ortho rectify`` loads it."""
    from ortho.block import load_block

    kw = {"eo_path": project / "truth" / "eo.txt", "camera_path": project / "truth" / "camera.toml"} \
        if truth_orientation else {}
    return load_block(project, **kw)


def frame_layers(block, i: int, dsm, dem, res_m: float, columns: bool = False):
    """For frame ``i``: its grid, the imaged mask on the DSM (no occlusion), the true ortho's mask, the z-buffer's
    candidates and the march over every imaged pixel, as booleans on the grid. The march's continuous surface over
    the ground cells of the DSM on the DEM (``ground_cells``, as ``ortho rectify --true-ortho`` passes them);
    ``columns``: none, every DSM cell a column (this bench before 2026-12-01)."""
    from ortho.grid import GridToProject
    from ortho.rectify import (FrameGeometry, fixed_point_maps, frame_grid, frame_zbuffer, ground_cells,
                               occlusion_mask, rectify_frame, zbuffer_occlusion_from_maps)

    image_id = block.eo.image_id[i]
    C = block.eo.centre_m[i]
    R = block.eo.rotation(i)
    cam = block.camera
    crs = block.project_crs
    to_project = GridToProject(crs, crs)
    grid = frame_grid(cam, C, R, dem, res_m, crs, to_project=to_project, image_id=image_id, partial=True)
    image = np.zeros((cam.height, cam.width), np.uint8)
    ground = None if columns else ground_cells(dsm, dem)
    t = time.process_time()
    _, mask = rectify_frame(image, cam, C, R, dsm, grid, occlusion_dsm=dsm, tile_px=max(grid.width, grid.height) + 1,
                            threads=1, ground=ground)
    cpu = time.process_time() - t
    geometry = FrameGeometry(cam, np.asarray(C, float), np.asarray(R, float))
    map_int, _, imaged, z, anchors = fixed_point_maps(geometry, dsm, grid, to_project)
    zb = frame_zbuffer(geometry, dsm, grid, to_project, tile_px=max(grid.width, grid.height) + 1)
    cand = np.zeros(z.shape, bool)
    zbuffer_occlusion_from_maps(geometry, zb, grid, map_int.copy(), imaged, z, out=cand)
    march = occlusion_mask(geometry, dsm, grid, z, anchors, candidates=imaged > 0, ground=ground)
    return image_id, grid, imaged > 0, mask > 0, cand, march, z, cpu


def confusion(truth, image_id: str, grid, imaged, valid, cand, march, z_dsm):
    import cv2

    from eval_true_ortho_occlusion import SEES
    from aerotri.sim.scene import KIND_ROOF, KIND_TERRAIN

    H, W = grid.height, grid.width
    xs, ys = grid.centres()
    X = np.broadcast_to(xs[None, :] - truth.origin[0], (H, W)).ravel()
    Y = np.broadcast_to(ys[:, None] - truth.origin[1], (H, W)).ravel()
    kind, _, _ = truth.surface(X, Y)
    kind = kind.reshape(H, W)
    ground = (kind == KIND_TERRAIN) & imaged
    roof = kind == KIND_ROOF
    idx = np.flatnonzero(ground)
    zt = truth.scene.terrain_height(X[idx], Y[idx])
    code = np.zeros(H * W, np.uint8)
    code[idx] = truth.visibility(image_id, X[idx], Y[idx], zt)
    code = code.reshape(H, W)
    sees = ground & (code == SEES)
    hidden = ground & (code != SEES)
    # within one cell (8-neighbour) of the other state: the boundary of a hidden area
    near_seen = cv2.dilate(sees.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    near_hidden = cv2.dilate(hidden.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    dist_roof = cv2.distanceTransform((~roof).view(np.uint8), cv2.DIST_L2, 5) * grid.res_m
    # the DSM's height at the cell against the terrain's (a ground cell next to a wall: the bilinear DSM is raised)
    zt_full = np.full(H * W, np.nan)
    zt_full[idx] = zt + truth.origin[2]
    raised = (z_dsm.ravel().astype(float) - zt_full > 0.3).reshape(H, W) & ground

    hbv = hidden & valid
    vbm = sees & ~valid

    def split(sel, near_other):
        return {"cells": int(sel.sum()),
                "edge": int((sel & near_other).sum()),
                "dsm_above_terrain_0_3m": int((sel & raised).sum()),
                **{f"within_{b:g}m_of_a_roof": int((sel & (dist_roof <= b)).sum()) for b in ROOF_BANDS_M},
                "deeper": int((sel & ~near_other & (dist_roof > ROOF_BANDS_M[0])).sum())}

    out = {"image_id": image_id, "ground_cells_imaged": int(ground.sum()), "sees": int(sees.sum()),
           "hidden": int(hidden.sum()),
           "hidden_but_valid": split(hbv, near_seen), "visible_but_masked": split(vbm, near_hidden)}
    out["hidden_but_valid"]["zbuffer_missed"] = int((hbv & march).sum())
    out["hidden_but_valid"]["march_missed"] = int((hbv & ~march).sum())
    out["hidden_but_valid_share"] = out["hidden_but_valid"]["cells"] / max(1, out["hidden"])
    out["visible_but_masked_share"] = out["visible_but_masked"]["cells"] / max(1, out["sees"])
    out["march_over_every_pixel"] = {"hidden_but_valid": int((hidden & ~march).sum()),
                                     "visible_but_masked": int((sees & march).sum())}
    out["candidates"] = int(cand.sum())
    return out, {"hbv": hbv, "vbm": vbm, "hidden": hidden, "sees": sees, "roof": roof, "kind": kind}


def run_project(project: Path, truth_orientation: bool, frames=None, keep=None, columns: bool = False) -> dict:
    from eval_true_ortho_occlusion import Truth

    from ortho.block import default_resolution
    from ortho.dem import height_range, open_height_raster, read_height_window

    block = frame_inputs(project, truth_orientation)
    dsm_path = project / "lidar_out" / "dsm.tif"
    if not dsm_path.exists():
        dsm_path = project / "truth" / "dsm.tif"
    dem_path = project / "lidar_out" / "dem.tif"
    if not dem_path.exists():
        dem_path = project / "truth" / "dem.tif"
    with open_height_raster(dem_path, block.project_crs, "DEM") as ds:
        zlo, zhi = height_range(ds)
        nadir_z = np.array([float(v[0]) for v in ds.sample([tuple(p) for p in block.eo.centre_m[:, :2]])])
    res_m = default_resolution(block.camera, block.eo, nadir_z)
    truth = Truth(project)
    out = {"project": str(project), "dsm": str(dsm_path.relative_to(project)),
           "orientation": "truth/eo.txt, truth/camera.toml" if truth_orientation else "at/eo.txt",
           "res_m": res_m, "march": "columns only" if columns else "ground cells of the DSM on the DEM", "frames": []}
    tot = {}
    from ortho.block import _plane_footprint_bounds

    for i, image_id in enumerate(block.eo.image_id):
        if frames and image_id not in frames:
            continue
        C, R = block.eo.centre_m[i], block.eo.rotation(i)
        bounds = _plane_footprint_bounds(block.camera, C, R, zlo - 5.0, zhi + 5.0, image_id)
        with open_height_raster(dsm_path, block.project_crs, "DSM") as ds:
            dsm = read_height_window(ds, bounds, margin_m=4 * ds.transform.a, what="DSM")
        with open_height_raster(dem_path, block.project_crs, "DEM") as ds:
            dem = read_height_window(ds, bounds, margin_m=4 * ds.transform.a, what="DEM")
        image_id, grid, imaged, valid, cand, march, z, cpu = frame_layers(block, i, dsm, dem, res_m, columns)
        row, layers = confusion(truth, image_id, grid, imaged, valid, cand, march, z)
        row["rectify_cpu_s"] = round(cpu, 2)
        if keep is not None:
            keep[image_id] = (grid, layers, valid, march, cand, z, dsm)
        out["frames"].append(row)
        for k in ("ground_cells_imaged", "sees", "hidden"):
            tot[k] = tot.get(k, 0) + row[k]
        for k in ("hidden_but_valid", "visible_but_masked"):
            d = tot.setdefault(k, {})
            for kk, v in row[k].items():
                d[kk] = d.get(kk, 0) + v
        print(image_id, json.dumps({k: row[k] for k in ("hidden", "sees", "hidden_but_valid", "visible_but_masked")}),
              flush=True)
    tot["hidden_but_valid_share"] = tot["hidden_but_valid"]["cells"] / max(1, tot["hidden"])
    tot["visible_but_masked_share"] = tot["visible_but_masked"]["cells"] / max(1, tot["sees"])
    out["all_frames"] = tot
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("projects", type=Path, nargs="+")
    ap.add_argument("--truth-orientation", action="store_true")
    ap.add_argument("--frames", default=None)
    ap.add_argument("--columns", action="store_true", help="no ground cells: every DSM cell a column (as before)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_masks.json")
    ap.add_argument("--key", default=None, help="key of the result in the JSON (default: the project's name)")
    args = ap.parse_args()
    for p in args.projects:
        res = run_project(p, args.truth_orientation, args.frames.split(",") if args.frames else None,
                          columns=args.columns)
        res["commit"] = git_commit(REPO)
        print(p, json.dumps(res["all_frames"], indent=1))
        store_result(args.out, res, key=args.key or p.name)


if __name__ == "__main__":
    main()
