"""Rectify in a contract CRS at the project CRS's speed (issue 41): the affine tiles against the exact anchors.

    .venv/bin/python bench/contract_crs_speed.py PROJECT --crs EPSG:4546 [--crs EPSG:4545 ...] [--frames s01_002]
        [--dsm PATH] [--res-m 0.1] [--name dmc_2x4] [--out bench/results/contract_crs_speed.json]

For each frame and output CRS, over the frame's grid in 1024 px tiles (as ``ortho rectify`` makes them): the image
positions of every pixel (float, ``_backproject_kernel``, at the DSM's heights) through the exact anchor grid
(``GridToProject.anchors``, within 1 mm of PROJ) and through the tile's affine fit (``GridToProject.affine``, checked
against PROJ within a tenth of that, ``AFFINE_SHARE``): max / RMS distance (px); the fit's largest checked deviation
(m); tiles that fell back; the same against PROJ itself at every 8th pixel of every 8th row (the exact path's own
error included: the anchors are interpolated too), ground (mm) and image (px); and the CPU of ``fixed_point_maps``
(process time) with the affine tiles and without them. The end-to-end CPU of ``ortho rectify`` and the orthos'
differences are measured by the commands in docs/full-size-block.md. Results are merged into the JSON under
``--name``.
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

from aerotri.core.atomic import write_text_atomic  # noqa: E402
from aerotri.geom.crs.definition import parse_crs  # noqa: E402
from aerotri.geom.crs.raster_warp import interpolate_anchors  # noqa: E402
from aerotri.geom.crs.transform import CrsTransformer  # noqa: E402
from aerotri.geom.local_frame import CameraOnEarth  # noqa: E402
from aerotri.geom.rotation import rotation_matrix_opk  # noqa: E402
from ortho.block import load_block  # noqa: E402
from ortho.dem import read_height_raster  # noqa: E402
from ortho.grid import GridToProject  # noqa: E402
from ortho.rectify import (AnchorGrid, FrameGeometry, MapBuffers, _height_grid, fixed_point_maps,  # noqa: E402
                           frame_grid)
from ortho.rectify_kernels import _backproject_kernel  # noqa: E402

TILE_PX = 1024
SAMPLE_PX = 8


def positions(geometry, dsm, tile, anchors):
    """Float image positions (x, y; NaN where not imaged) of a tile's pixels through ``anchors``."""
    ax, ay, s = anchors
    shape = (tile.height, tile.width)
    mx, my, z = np.empty(shape, np.float32), np.empty(shape, np.float32), np.empty(shape, np.float32)
    _backproject_kernel(AnchorGrid(ax, ay, float(s)), _height_grid(dsm), geometry.kernel_frame(), 0.0, (mx, my, z))
    bad = mx < -1e4
    return np.where(bad, np.nan, mx.astype(np.float64)), np.where(bad, np.nan, my.astype(np.float64))


def at_nodes(X, Y):
    """An anchor grid that is ``X``, ``Y`` at its nodes (spacing 1: each node one pixel of a sampled grid)."""
    return np.ascontiguousarray(X), np.ascontiguousarray(Y), 1


def against_proj(geometry, dsm, tile, exact, fit):
    """Ground (m) and image (px) distances to PROJ's own positions of every ``SAMPLE_PX``-th pixel of the tile: of the
    exact path's anchors and of the affine fit."""
    rows, cols = np.arange(0, tile.height, SAMPLE_PX), np.arange(0, tile.width, SAMPLE_PX)
    xo, yo = tile.centres(rows, cols)
    xo, yo = np.meshgrid(xo, yo)
    Xt, Yt = exact.exact(xo, yo)
    ax, ay, s = exact.anchors(tile)
    Xa = interpolate_anchors(ax, s, tile.height, tile.width)[::SAMPLE_PX, ::SAMPLE_PX]
    Ya = interpolate_anchors(ay, s, tile.height, tile.width)[::SAMPLE_PX, ::SAMPLE_PX]
    r, c = np.meshgrid(rows, cols, indexing="ij")
    Xf = fit.x0_m + c * fit.col_dx_m + r * fit.row_dx_m
    Yf = fit.y0_m + c * fit.col_dy_m + r * fit.row_dy_m
    sub = tile.window(0, 0, len(cols), len(rows))
    pt = positions(geometry, dsm, sub, at_nodes(Xt, Yt))
    out = {}
    for name, (X, Y) in (("anchors", (Xa, Ya)), ("affine", (Xf, Yf))):
        p = positions(geometry, dsm, sub, at_nodes(X, Y))
        d = np.hypot(p[0] - pt[0], p[1] - pt[1])
        out[name] = (np.hypot(X - Xt, Y - Yt).ravel(), d[np.isfinite(d)])
    return out


def _stats(parts, scale=1.0):
    v = np.concatenate(parts) * scale if parts else np.zeros(0)
    return {"max": float(v.max()), "rms": float(np.sqrt(np.mean(v ** 2)))} if v.size else None


def measure(block, dsm, frame_id: str, crs, res_m: float) -> dict:
    i = block.eo.row(frame_id)
    C, R = block.eo.centre_m[i], rotation_matrix_opk(*block.eo.opk_deg[i])
    op = CrsTransformer(block.project_crs, crs, allow_ballpark=True)
    fast = GridToProject(crs, block.project_crs, operation=op)
    exact = GridToProject(crs, block.project_crs, operation=op, affine_tiles=False)
    geometry = FrameGeometry(block.camera, C, R, earth=CameraOnEarth(block.project_crs, C, R))
    grid = frame_grid(block.camera, C, R, dsm, res_m, crs, to_project=exact)
    tiles = [grid.window(c0, r0, min(TILE_PX, grid.width - c0), min(TILE_PX, grid.height - r0))
             for r0 in range(0, grid.height, TILE_PX) for c0 in range(0, grid.width, TILE_PX)]
    out = {"frame": frame_id, "crs": crs.to_string(), "grid_px": [grid.width, grid.height], "tiles": len(tiles)}
    buffers = MapBuffers(TILE_PX)
    for name, tp in (("exact", exact), ("affine", fast)):
        fixed_point_maps(geometry, dsm, tiles[0], tp, buffers=buffers)  # compiled before the clock
        t = time.process_time()
        for tile in tiles:
            fixed_point_maps(geometry, dsm, tile, tp, buffers=buffers)
        out[f"maps_cpu_s_{name}"] = round(time.process_time() - t, 3)
    worst, sq, n, deviation, fell_back = 0.0, 0.0, 0, 0.0, 0
    to_proj = {"anchors": ([], []), "affine": ([], [])}
    for tile in tiles:
        fit = fast.affine(tile)
        if fit is None:
            fell_back += 1
            continue
        deviation = max(deviation, fit.deviation_m)
        for name, (ground, image) in against_proj(geometry, dsm, tile, exact, fit).items():
            to_proj[name][0].append(ground)
            to_proj[name][1].append(image)
        xa, ya = positions(geometry, dsm, tile, exact.anchors(tile))
        xb, yb = positions(geometry, dsm, tile, fit.anchors(tile.width, tile.height))
        d = np.hypot(xa - xb, ya - yb)
        d = d[np.isfinite(d)]
        if d.size:
            worst = max(worst, float(d.max()))
            sq += float((d ** 2).sum())
            n += d.size
    out.update(tiles_fell_back=fell_back, fit_deviation_max_m=deviation, pixels_compared=n,
               position_diff_max_px=worst, position_diff_rms_px=(sq / n) ** 0.5 if n else None,
               to_proj={name: {"ground_mm": _stats(g, 1000.0), "image_px": _stats(im)}
                        for name, (g, im) in to_proj.items()})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project", type=Path)
    ap.add_argument("--crs", action="append", required=True)
    ap.add_argument("--frames", nargs="+", default=None)
    ap.add_argument("--dsm", type=Path, default=None, help="heights of the maps (default: lidar_out/dsm.tif)")
    ap.add_argument("--res-m", type=float, default=0.1)
    ap.add_argument("--name", default="run")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "contract_crs_speed.json")
    args = ap.parse_args(argv)
    block = load_block(args.project)
    dsm = read_height_raster(args.dsm or args.project / "lidar_out" / "dsm.tif", block.project_crs, "DSM")
    frames = args.frames or list(block.eo.image_ids)[:1]
    rows = [measure(block, dsm, f, parse_crs(c, "--crs"), args.res_m) for f in frames for c in args.crs]
    for r in rows:
        print(json.dumps(r))
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    results[args.name] = {"project": str(args.project), "res_m": args.res_m, "runs": rows}
    write_text_atomic(args.out, json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
