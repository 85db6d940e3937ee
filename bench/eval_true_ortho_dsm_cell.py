"""Is the true-ortho mosaic's miss of occluded ground the DSM's cell size, and if not, what limits it? (issue 42,
target: 99.5 % of the occluded ground another frame sees filled from a frame that sees it.)

DSM cell: the truth surface is rasterised again at finer cells (straight-down rays at the cell centres, as the
simulator makes ``truth/dsm.tif``; ``Truth.surface`` of ``eval_true_ortho_occlusion.py``) and the same frames are
rectified with ``--true-ortho --dsm`` that raster (the DOM cell unchanged) and mosaicked; measured as
``bench/eval_true_ortho_occlusion.py`` (roofs, ghosts, seams) and ``bench/eval_true_ortho_fill.py`` (fill, misses by
class) do, against the same ray-cast truth (computed once per block, kept in ``DIR/<block>/truth_on_grid.npz``).

The bound of any 2.5D surface (``surface_clearance``): for every frame that sees an occluded ground cell another
frame sees, the truth's straight-down surface (no raster: the exact roof outlines, as fine as the ray caster) is
sampled along the line of sight every 5 cm; the frame "sees the cell over the 2.5D surface" when the surface stays
within the march's 0.3 m tolerance of the ray everywhere. Where it does not (the ray reached the ground in the truth
all the same) the ray passed beneath what stands highest above it: a roof outside its building's wall line (the eave
overhang, ``[scene] eave_m`` of the preset) or a tree crown; no height raster, however fine, can let such a cell
through without letting through the ground the roof hides. The share of cells some seeing frame sees over the 2.5D
surface is the most a 2.5D occlusion test can fill; the misses of each DOM are split the same way.

Usage: python bench/eval_true_ortho_dsm_cell.py --work DIR [--tall PROJECT] [--tall2 PROJECT] [--demo PROJECT]
[--blocks "demo:lidar,0.5,0.1;tall:0.5,0.25,0.2,0.1"] [--out FILE] (block ``tall2``: the tall preset with another
seed, as ``tall``)
Per block the DSMs to try: ``lidar`` the project's lidar_out/dsm.tif (the demo: the chain's LiDAR DSM and adjusted
orientation), ``0.5`` on the tall block truth/dsm.tif, other numbers the truth surface at that cell (m). The tall
block: ``aerotri sim DIR --preset tall``, rectified with the true orientation and camera as in
eval_true_ortho_occlusion.py; the demo: a project made by ``aerotri demo``. ``max``, ``tin``, ``tin_top`` and
``nearest``: DSMs from the block's LiDAR first returns on the grid of its LiDAR DSM (demo) or truth DSM (tall), see
``write_points_dsm`` (the demo's classified strips of the chain, the tall block's simulated strips with their
true classes). A DSM spec ending in ``+fp`` is the same DSM with the simulator's building footprints (the wall
lines of truth/buildings.geojson written as truth/footprints.gpkg, ``aerotri.sim.project.write_footprints_gpkg``) in
the occlusion test (``ortho rectify --footprints``, ``ortho.footprints``), e.g. ``--blocks "tall:0.5,0.5+fp"``;
``+fpl`` the LiDAR's own roof outlines instead (the buildings layer of ``lidarctl vectors`` of the block's classified
strips: the demo's chain, a tall block's simulated strips with their true classes), ``+fpc`` those of ``lidarctl
corners`` (roof_outlines.gpkg: the chain's footprints when [rectify] footprints is not given);
``+fpciNN`` those outlines moved NN cm inwards (the walls beneath the eaves, ``inset_outlines``);
``+fp4``, ``+fp5``, ... the same (names of their own, so that a DOM made with ``+fp`` by earlier code is kept beside it: each DOM's
made.json records the commit that made it). ``+cb``: tree crown bases in the occlusion test (``ortho rectify
--crown-base``): on the tall blocks the truth's (``truth_crown_base``: per cell the lowest underside of the crowns
over it), on the demo the LiDAR's (``lidarctl.rasters.crown_base``: the lowest vegetation return of the cell and its
neighbours, from the chain's classified strips); ``+cbl`` on a tall block the LiDAR's (its simulated strips, true
classes). Blocks ``tall2``, ``tall3``: the tall preset with other seeds (``--tall2``, ``--tall3``), as ``tall``.
``lidarn``: the LiDAR stages' nearest-return DSM (``lidarctl rasters``' dsm_nearest.tif) for the heights and the
occlusion test; ``+occn``: the DSM for the heights, the occlusion test on dsm_nearest.tif (``ortho rectify
--occlusion-dsm``, the chain's default). On the demo these rasters are the chain's (lidar_out/, ``lidar`` its
dsm.tif); on a tall block ``lidarctl rasters`` of its simulated strips with their true classes
(``DIR/<block>/lidar_rasters``, made once; ``lidar`` there is that dsm.tif). ``+bil``: with footprints, each cell's
height the DSM's bilinear one (``ortho.block.HEIGHTS_BY_OUTLINE`` off for that DOM: the rule before heights by side);
``+hod``: with ``+occn`` and footprints, the heights' roof outlines from the heights DSM's roof cells
(``ortho.block.OUTLINES_OF_THE_OCCLUSION_TEST`` off: main's before the outlines of the occlusion test).
``+occc``: with ``+occn``, the occlusion test on dsm_nearest.tif with each tree crown's cell a column only where the
returns say the crown covers the whole cell (``lidarctl.rasters.crown_rim.crowns_within_cells`` of the block's
classified first returns, written to the DOM's lidar_out/dsm_crowns.tif); ``+occcNN`` where it covers NN % of it.
``+occs``: with ``+occn`` and footprints, dsm_nearest's crown cells a column over the sub-cells the crown covers only
(``crown_sub_cells`` to lidar_out/crown_bits.tif, ``ortho.crown_cells.with_crown_sub_cells`` on each frame's
occluder: ``_frame_occluder`` wrapped, a trial, not a rectifier option).
``+occt``: with ``+occn`` and footprints, each tree's crown a disk fitted to its returns (``lidarctl.rasters.crown_model``,
``crown_model_cells`` to lidar_out/crown_model.npz; ``with_crown_model`` on each frame's occluder, a trial): the
occlusion DSM's columns within the disks only, the nearest-return crown beyond them none; ``+occtb`` the same from each
tree's crown base (its lowest vegetation return) up. ``+crowns``: the product's way of the same (``ortho rectify
--occlusion-dsm lidar_out/dsm_crowns.tif --crowns lidar_out/crowns.gpkg``, written by ``block_crown_model``), the
chain's default since.
Writes the key ``--key`` (default ``dsm_cell``) of bench/results/true_ortho_fill.json (the other keys kept).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from results_json import read_results, store_result  # noqa: E402

ROWS_PER_CHUNK = 256


def write_fine_dsm(project: Path, truth, cell_m: float, out: Path) -> float:
    """The truth surface at cells of ``cell_m`` over the extent of truth/dsm.tif; returns the ray-cast seconds."""
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(project / "truth" / "dsm.tif") as ds:
        b, crs = ds.bounds, ds.crs
    nx, ny = int(math.floor((b.right - b.left) / cell_m)), int(math.floor((b.top - b.bottom) / cell_m))
    xs = b.left + (np.arange(nx) + 0.5) * cell_m - truth.origin[0]
    t = time.perf_counter()
    tmp = out.with_suffix(".part.tif")
    with rasterio.open(tmp, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs=crs,
                       transform=from_origin(b.left, b.top, cell_m, cell_m), nodata=-9999.0, tiled=True,
                       blockxsize=256, blockysize=256, compress="deflate", predictor=3) as dst:
        for r0 in range(0, ny, ROWS_PER_CHUNK):
            r1 = min(ny, r0 + ROWS_PER_CHUNK)
            ys = b.top - (np.arange(r0, r1) + 0.5) * cell_m - truth.origin[1]
            X, Y = np.meshgrid(xs, ys)
            _, z, _ = truth.surface(X.ravel(), Y.ravel())
            dst.write((z.reshape(r1 - r0, nx) + truth.origin[2]).astype(np.float32), 1,
                      window=rasterio.windows.Window(0, r0, nx, r1 - r0))
    tmp.replace(out)
    return time.perf_counter() - t


# DSMs made here from the project's LiDAR points (``write_points_dsm``)
POINT_DSMS = ("max", "tin", "tin_top", "nearest")
TIN_TILE_CELLS = 256
TIN_BUFFER_M = 12.0
TIN_MAX_EDGE_M = 10.0  # triangles with a longer edge (gaps in the LiDAR) left to the fallback DSM


def first_returns(las_paths, class_paths=None):
    """x, y, z (m) of the first returns (return number 0 or 1) that are not noise (classes 7, 18), as the LiDAR
    DSM takes them; classes from ``class_paths`` (same point order: the simulator's truth/lidar) when given."""
    import laspy

    xs, ys, zs = [], [], []
    for k, path in enumerate(las_paths):
        las = laspy.read(path)
        cls = np.asarray((laspy.read(class_paths[k]) if class_paths else las).classification)
        keep = (np.asarray(las.return_number) <= 1) & ~np.isin(cls, (7, 18))
        xs.append(np.asarray(las.x)[keep])
        ys.append(np.asarray(las.y)[keep])
        zs.append(np.asarray(las.z)[keep])
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(zs)


def _highest_per_cell(x, y, z, left, top, res, shape):
    """Indices of the highest point per cell of the north-up grid and the flat cells they fall in."""
    r = np.floor((top - y) / res).astype(np.int64)
    c = np.floor((x - left) / res).astype(np.int64)
    ok = np.flatnonzero((r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1]))
    cid = r[ok] * shape[1] + c[ok]
    order = np.lexsort((z[ok], cid))
    last = np.r_[cid[order][1:] != cid[order][:-1], True]
    return ok[order[last]], cid[order[last]]


def write_points_dsm(how: str, x, y, z, like: Path, out: Path) -> dict:
    """A DSM on the grid of ``like`` (a DSM GeoTIFF) from first returns (x, y, z in m): ``max`` the highest
    return per cell (the LiDAR DSM's rule), NaN cells filled by pull-push; ``tin`` the linear interpolation of a
    Delaunay TIN of all the returns at the cell centres (straight down at the centre, as the simulator's truth
    DSM); ``tin_top`` the same of the highest return per cell (one vertex a cell, at the point's own x, y);
    ``nearest`` the return nearest the cell centre (a step halfway between a roof's and the ground's returns).
    TIN cells under no triangle with edges within TIN_MAX_EDGE_M, and centres with no return within half of it,
    take the ``max`` DSM; ``like``'s nodata cells stay nodata. Returns the seconds and counts."""
    import rasterio
    from scipy.spatial import Delaunay

    from lidarctl.raster_ops import fill_nodata
    from lidarctl.rasters.trees import _rasterise_tin

    t = time.perf_counter()
    with rasterio.open(like) as ds:
        prof, tf = ds.profile, ds.transform
        valid = ds.read(1) != ds.nodata
    res, left, top = tf.a, tf.c, tf.f
    shape = valid.shape
    top_idx, cid = _highest_per_cell(x, y, z, left, top, res, shape)
    dsm = np.full(shape[0] * shape[1], np.nan)
    dsm[cid] = z[top_idx]
    dsm = fill_nodata(dsm.reshape(shape))
    n_vertices = 0
    if how == "nearest":
        from lidarctl.rasters.nearest import nearest_return_surface

        near = nearest_return_surface(x, y, z, x0_m=left, y_top_m=top, res_m=res, nrows=shape[0], ncols=shape[1],
                                      max_dist_m=TIN_MAX_EDGE_M / 2)
        dsm = np.where(np.isfinite(near), near, dsm)
    elif how != "max":
        if how == "tin_top":
            x, y, z = x[top_idx], y[top_idx], z[top_idx]
        tin = np.full(shape, np.nan)
        buf = TIN_BUFFER_M
        for r0 in range(0, shape[0], TIN_TILE_CELLS):
            r1 = min(shape[0], r0 + TIN_TILE_CELLS)
            yt, yb = top - r0 * res, top - r1 * res
            rows = np.flatnonzero((y > yb - buf) & (y < yt + buf))
            xr, yr, zr = x[rows], y[rows], z[rows]
            for c0 in range(0, shape[1], TIN_TILE_CELLS):
                c1 = min(shape[1], c0 + TIN_TILE_CELLS)
                xl, xh = left + c0 * res, left + c1 * res
                k = np.flatnonzero((xr > xl - buf) & (xr < xh + buf))
                if len(k) < 3:
                    continue
                px, py = xr[k] - xl, yr[k] - yb
                n_vertices += len(k)
                tri = Delaunay(np.column_stack([px, py])).simplices.astype(np.int64)
                part = _rasterise_tin(px, py, zr[k], tri, max_edge2=TIN_MAX_EDGE_M ** 2, x0=0.0, y0=0.0, res=res,
                                      nrows=r1 - r0, ncols=c1 - c0)
                tin[r0:r1, c0:c1] = part[::-1]
        dsm = np.where(np.isfinite(tin), tin, dsm)
    dsm = np.where(valid, dsm, prof["nodata"]).astype(np.float32)
    prof.update(dtype="float32", compress="deflate", predictor=3)
    tmp = out.with_suffix(".part.tif")
    with rasterio.open(tmp, "w", **prof) as dst:
        dst.write(dsm, 1)
    tmp.replace(out)
    return {"how": how, "points": int(len(x)), "tin_vertices_with_buffers": n_vertices,
            "seconds": round(time.perf_counter() - t, 1)}


# what stands above a line of sight that reaches the ground (``surface_clearance``)
CLEAR, EAVE, ROOF_OVER_WALLS, TREE_CROWN, OTHER = 0, 1, 2, 3, 4
BLOCKERS = {EAVE: "eave_overhang", ROOF_OVER_WALLS: "roof_inside_the_walls", TREE_CROWN: "tree_crown", OTHER: "other"}
STEP_M = 0.05  # along the line of sight, horizontally
RAYS_PER_CHUNK = 2000


def surface_clearance(truth, image_id: str, x: np.ndarray, y: np.ndarray, tolerance_m: float) -> np.ndarray:
    """What a 2.5D surface (the straight-down view of the scene at every point, no raster) puts in the line of sight
    from ground points (local x, y) to the frame's true projection centre: ``CLEAR`` where the surface stays within
    ``tolerance_m`` of the ray everywhere (every STEP_M horizontally, from STEP_M to where the ray is above the
    highest surface), else what the surface is where it stands highest above the ray: a roof outside its building's
    wall line (``EAVE``: the overhang, under which the ray may pass), a roof inside it, a tree crown, other."""
    import shapely

    from aerotri.sim.scene import KIND_ROOF, KIND_TREE

    footprints = {b.building_id: b.footprint for b in truth.scene.buildings}
    top = float(truth.accel[-1])
    C = truth.centres[image_id]
    out = np.zeros(len(x), np.uint8)
    for a in range(0, len(x), RAYS_PER_CHUNK):
        X, Y = x[a:a + RAYS_PER_CHUNK], y[a:a + RAYS_PER_CHUNK]
        Z = truth.scene.terrain_height(X, Y)
        vx, vy, vz = C[0] - X, C[1] - Y, C[2] - Z
        hd = np.hypot(vx, vy)
        rise = vz / hd
        S = np.arange(1, int(np.ceil((top - Z.min()) / rise.min() / STEP_M)) + 1) * STEP_M
        PX, PY = X[:, None] + vx[:, None] / hd[:, None] * S, Y[:, None] + vy[:, None] / hd[:, None] * S
        kind, zs, obj = truth.surface(PX.ravel(), PY.ravel())
        excess = zs.reshape(PX.shape) - (Z[:, None] + rise[:, None] * S)
        m = np.argmax(excess, 1)
        rows = np.arange(len(X))
        blocked = excess[rows, m] > tolerance_m
        k, o = kind.reshape(PX.shape)[rows, m], obj.reshape(PX.shape)[rows, m]
        code = np.where(k == KIND_TREE, TREE_CROWN, OTHER).astype(np.uint8)
        for q in np.flatnonzero(blocked & (k == KIND_ROOF)):
            inside = shapely.contains_xy(footprints[int(o[q])], PX[q, m[q]], PY[q, m[q]])
            code[q] = ROOF_OVER_WALLS if inside else EAVE
        out[a:a + RAYS_PER_CHUNK] = np.where(blocked, code, CLEAR)
    return out


def occluded_seen_by_another(E, ground, vis, foot_nadir) -> np.ndarray:
    """Ground cells hidden in the nadir-most frame covering them that another frame sees (as eval_true_ortho_fill)."""
    code_nadir = np.zeros(ground.shape, np.uint8)
    for k in range(len(vis)):
        sel = foot_nadir == k
        code_nadir[sel] = vis[k][sel]
    return ground & (foot_nadir >= 0) & (code_nadir >= E.ROOF) & (np.stack(vis) == E.SEES).any(0)


def cached_clearance(E, truth, work: Path, grid, ground, vis, foot_nadir, tolerance_m: float = 0.3):
    """``surface_clearance`` of every frame that sees an occluded ground cell another frame sees (codes (F, H, W),
    255 where not evaluated; kept in work/surface_clearance.npz), and what a 2.5D occlusion test could fill at
    best: the share of those cells some seeing frame sees over the 2.5D surface (within ``tolerance_m``, the
    march's)."""
    path = work / "surface_clearance.npz"
    seen_other = occluded_seen_by_another(E, ground, vis, foot_nadir)
    cast_s = None
    if path.exists():
        codes = np.load(path)["codes"]
    else:
        t = time.perf_counter()
        codes = np.full((len(vis),) + ground.shape, 255, np.uint8)
        xs, ys = grid.centres()
        from ortho.block import read_index

        ids = [e.image_id for e in read_index(work / "conventional").frames]
        for k, image_id in enumerate(ids):
            rr, cc = np.nonzero(seen_other & (vis[k] == E.SEES))
            codes[k, rr, cc] = surface_clearance(truth, image_id, xs[cc] - truth.origin[0], ys[rr] - truth.origin[1],
                                                 tolerance_m)
        np.savez_compressed(path, codes=codes)
        cast_s = round(time.perf_counter() - t, 1)
    clear_any = (codes == CLEAR).any(0) & seen_other
    bound = {"tolerance_m": tolerance_m, "step_m": STEP_M,
             "seen_by_another_frame": int(seen_other.sum()),
             "a_seeing_frame_clears_the_2_5d_surface": int(clear_any.sum()),
             "fill_share_at_best": float(clear_any.sum() / max(1, seen_other.sum())),
             "no_seeing_frame_clears_it": misses_by_blocker(codes, vis, seen_other & ~clear_any)}
    if cast_s is not None:  # the ray casts of this run (none when read from the cache)
        bound["ray_cast_s"] = cast_s
    return codes, bound


def misses_by_blocker(codes: np.ndarray, vis, cells: np.ndarray) -> dict:
    """Cells by what the 2.5D surface puts in the lines of sight of the frames that see them: any of them clear,
    else the blocker of the first seeing frame in the order eave, roof, tree, other."""
    seeing = codes[:, cells]
    clear = (seeing == CLEAR).any(0)
    first = np.where(seeing == 255, 255, seeing).min(0)
    out = {"cells": int(cells.sum()), "a_seeing_frame_clears_the_2_5d_surface": int(clear.sum())}
    for code, name in BLOCKERS.items():
        out[name] = int(((first == code) & ~clear).sum())
    return out


def cached_truth(E, work: Path, conv: Path, grid):
    """truth_on_grid of eval_true_ortho_occlusion.py for the block, kept in work/truth_on_grid.npz."""
    path = work / "truth_on_grid.npz"
    if path.exists():
        z = np.load(path)
        return z["kind"], z["ground"], z["roof"], list(z["vis"]), z["foot_nadir"]
    truth = E.Truth(conv)
    kind, ground, roof, vis, foot_nadir, _ = E.truth_on_grid(truth, conv, grid)
    np.savez_compressed(path, kind=kind, ground=ground, roof=roof, vis=np.stack(vis), foot_nadir=foot_nadir)
    return kind, ground, roof, vis, foot_nadir


def block_first_returns(src: Path, tall: bool):
    """The block's LiDAR first returns (``first_returns``): the demo's classified strips of the chain
    (lidar_out/classified), the tall block's simulated strips with their true classes (no chain run)."""
    if tall:
        las = sorted((src / "lidar").glob("*.la[sz]"))
        return first_returns(las, [src / "truth" / "lidar" / q.name for q in las])
    return first_returns(sorted((src / "lidar_out" / "classified").glob("*.la[sz]")))


def truth_crown_base(truth, like: Path, out: Path, sub: int = 5) -> int:
    """The crown base of the simulator's trees (spheroids, no trunks) on the grid of ``like`` (a DSM GeoTIFF): per
    cell the lowest underside of the crowns over it, sampled at ``sub`` x ``sub`` points of the cell (the lowest
    vegetation return a cell could hold), nodata where no crown; returns the cells with a crown base."""
    import rasterio

    with rasterio.open(like) as ds:
        prof, tf, shape = ds.profile, ds.transform, (ds.height, ds.width)
    res, left, top = tf.a, tf.c - truth.origin[0], tf.f - truth.origin[1]
    base = np.full(shape, np.inf)
    off = (np.arange(sub) + 0.5) / sub
    for (cx, cy, cz), (a, c) in zip(truth.scene.tree_c, truth.scene.tree_ac):
        r0, r1 = max(0, int((top - cy - a) / res)), min(shape[0], int((top - cy + a) / res) + 1)
        c0, c1 = max(0, int((cx - a - left) / res)), min(shape[1], int((cx + a - left) / res) + 1)
        if r1 <= r0 or c1 <= c0:
            continue
        ys = top - (np.arange(r0, r1)[:, None] + off[None, :]) * res  # (rows, sub)
        xs = left + (np.arange(c0, c1)[:, None] + off[None, :]) * res
        q = 1.0 - ((xs[None, None, :, :] - cx) ** 2 + (ys[:, :, None, None] - cy) ** 2) / (a * a)
        z = np.where(q > 0, cz - c * np.sqrt(np.maximum(q, 0.0)), np.inf).min(axis=(1, 3))
        base[r0:r1, c0:c1] = np.minimum(base[r0:r1, c0:c1], z)
    nodata = -9999.0
    z = np.where(np.isfinite(base), base + truth.origin[2], nodata).astype(np.float32)
    prof.update(dtype="float32", nodata=nodata, count=1)
    with rasterio.open(out, "w", **prof) as dst:
        dst.write(z, 1)
    return int(np.isfinite(base).sum())


def lidar_crown_base(src: Path, tall: bool, like: Path, out: Path) -> int:
    """``lidarctl.rasters.crown_base.crown_base_surface`` of the block's returns (``block_first_returns``' strips,
    all returns) on the grid of ``like``; returns the cells with a crown base."""
    import laspy
    import rasterio

    from lidarctl.rasters.crown_base import crown_base_surface

    las = sorted((src / "lidar").glob("*.la[sz]")) if tall else sorted((src / "lidar_out" / "classified").glob("*.la[sz]"))
    xs, ys, zs, cls = [], [], [], []
    for k, path in enumerate(las):
        pts = laspy.read(path)
        c = laspy.read(src / "truth" / "lidar" / path.name).classification if tall else pts.classification
        xs.append(np.asarray(pts.x)), ys.append(np.asarray(pts.y)), zs.append(np.asarray(pts.z))
        cls.append(np.asarray(c))
    with rasterio.open(like) as ds:
        prof, tf, shape = ds.profile, ds.transform, (ds.height, ds.width)
    base = crown_base_surface(np.concatenate(xs), np.concatenate(ys), np.concatenate(zs), np.concatenate(cls),
                              x0_m=tf.c, y_top_m=tf.f, res_m=tf.a, shape=shape)
    nodata = -9999.0
    prof.update(dtype="float32", nodata=nodata, count=1)
    with rasterio.open(out, "w", **prof) as dst:
        dst.write(np.where(np.isfinite(base), base, nodata).astype(np.float32), 1)
    return int(np.isfinite(base).sum())


def crowns_within_cells_dsm(src: Path, tall: bool, nearest: Path, out: Path, min_share: float | None,
                            beside: bool = False) -> dict:
    """``lidarctl.rasters.crown_rim.crowns_within_cells`` of ``nearest`` (the block's dsm_nearest.tif) from the first
    returns (noise excluded) of ``block_first_returns``' strips with their classes, written to ``out`` on its grid;
    the cells lowered and the CPU seconds. ``min_share`` None: ``crown_sub_cells`` instead (uint32 bits), the cells
    with bits."""
    import laspy
    import rasterio

    from lidarctl.rasters.crown_rim import crown_sub_cells, crown_sub_cells_beside, crowns_within_cells
    from lidarctl.rasters.nearest import first_return_mask

    t = time.process_time()
    las = sorted((src / "lidar").glob("*.la[sz]") if tall else (src / "lidar_out" / "classified").glob("*.la[sz]"))
    xs, ys, zs, cls = [], [], [], []
    for path in las:
        pts = laspy.read(path)
        c = np.asarray(laspy.read(src / "truth" / "lidar" / path.name).classification if tall else pts.classification)
        keep = first_return_mask(c, np.asarray(pts.return_number))
        xs.append(np.asarray(pts.x)[keep]), ys.append(np.asarray(pts.y)[keep]), zs.append(np.asarray(pts.z)[keep])
        cls.append(c[keep])
    with rasterio.open(nearest) as ds:
        prof, tf = ds.profile, ds.transform
        z = ds.read(1, masked=True).astype(np.float32).filled(np.nan)
    pts = (np.concatenate(xs), np.concatenate(ys), np.concatenate(zs), np.concatenate(cls))
    if min_share is None:
        top = None
        if beside:  # ``+occs2``: the crown's sub-cells in the cells beside its rim too, at a crown return's height
            bits, top = crown_sub_cells_beside(*pts, z, x0_m=tf.c, y_top_m=tf.f, res_m=tf.a)
            with rasterio.open(out.with_name("crown_top.tif"), "w", **prof) as dst:
                dst.write(np.where(np.isfinite(top), top, prof["nodata"]).astype(prof["dtype"]), 1)
        else:
            bits = crown_sub_cells(pts[0], pts[1], pts[3], z, x0_m=tf.c, y_top_m=tf.f, res_m=tf.a)
        prof.update(dtype="uint32", nodata=None)
        with rasterio.open(out, "w", **prof) as dst:
            dst.write(bits, 1)
        return {"path": str(out), "sub_cells": True, "cells_with_bits": int((bits != 0).sum()),
                "cells_raised": int(np.isfinite(top).sum()) if top is not None else 0,
                "top_path": str(out.with_name("crown_top.tif")) if top is not None else None,
                "cpu_s": time.process_time() - t}
    got = crowns_within_cells(*pts, z, x0_m=tf.c, y_top_m=tf.f, res_m=tf.a, min_share=min_share)
    with rasterio.open(out, "w", **prof) as dst:
        dst.write(np.where(np.isfinite(got), got, prof["nodata"]).astype(prof["dtype"]), 1)
    return {"path": str(out), "min_share": min_share, "cells_lowered": int((got != z)[np.isfinite(z)].sum()),
            "cpu_s": time.process_time() - t}


def with_crown_bits(frame_occluder, bits_path: Path, top_path: str | None = None):
    """``ortho.block._frame_occluder`` with ``ortho.crown_cells.with_crown_sub_cells`` of the crown bits raster
    ``bits_path`` (on the occlusion DSM's grid) over the frame's window: the trial of the crowns' sub-cells in the
    march (not an option of the rectifier). ``top_path``: the crown's top in the cells beside its rim (NaN
    elsewhere), where the frame's occluder has a solid column put into the occlusion DSM's window (in place)."""
    import rasterio

    from ortho.crown_cells import with_crown_sub_cells
    from lidarctl.rasters.crown_rim import SUB_CELLS

    with rasterio.open(bits_path) as ds:
        bits, tf = ds.read(1), ds.transform
    tops = None
    if top_path:
        with rasterio.open(top_path) as ds:
            tops = ds.read(1, masked=True).astype(np.float32).filled(np.nan)

    def window_of(raster, surface, fill):
        h, w = surface.heights_m.shape
        r0, c0 = int(round((tf.f - surface.y_top_m) / tf.a)), int(round((surface.x_left_m - tf.c) / tf.a))
        window = np.full((h, w), fill, raster.dtype)
        a0, b0 = max(r0, 0), max(c0, 0)
        a1, b1 = min(r0 + h, raster.shape[0]), min(c0 + w, raster.shape[1])
        if a1 > a0 and b1 > b0:
            window[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = raster[a0:a1, b0:b1]
        return window

    def occluder(task, surface, *rest):
        occ, sides = frame_occluder(task, surface, *rest)
        window = window_of(bits, surface, 0)
        if tops is not None:
            top = window_of(tops, surface, np.nan)
            raise_ = np.isfinite(top) & (window != 0) & (occ.base_m == -np.inf) & (top > surface.heights_m)
            surface.heights_m[raise_] = top[raise_]
        return with_crown_sub_cells(occ, surface.heights_m, window, SUB_CELLS), sides

    return occluder


def crown_model_cells(src: Path, tall: bool, nearest: Path, out: Path, truth=None) -> dict:
    """``lidarctl.rasters.crown_model`` of the block's returns (``block_first_returns``' strips with their classes,
    every return) on the grid of ``nearest`` (the block's dsm_nearest.tif): the trees' disks, tops and crown bases,
    and per cell a disk reaches (within 1 m) the signed distance of its 5 x 5 sub-cell centres within the disks, the
    lowest crown base over it, the height of the vegetation first return nearest its centre (the crown's height
    there) and whether the first return nearest its centre is vegetation or a building's; kept in ``out`` (npz).
    With ``truth`` (the simulator's), each fitted disk against the nearest true crown (its centre within the disk)."""
    import laspy
    import rasterio
    from scipy.spatial import cKDTree

    from lidarctl.rasters.crown_model import VEGETATION_CLASSES, crown_sub_cells, fit_crowns
    from lidarctl.rasters.nearest import first_return_mask

    t = time.process_time()
    las = sorted((src / "lidar").glob("*.la[sz]") if tall else (src / "lidar_out" / "classified").glob("*.la[sz]"))
    xs, ys, zs, cls, rn = [], [], [], [], []
    for path in las:
        pts = laspy.read(path)
        c = np.asarray(laspy.read(src / "truth" / "lidar" / path.name).classification if tall else pts.classification)
        xs.append(np.asarray(pts.x)), ys.append(np.asarray(pts.y)), zs.append(np.asarray(pts.z))
        cls.append(c), rn.append(np.asarray(pts.return_number))
    x, y, z, c, r = (np.concatenate(a) for a in (xs, ys, zs, cls, rn))
    crowns = fit_crowns(x, y, z, c, r)
    with rasterio.open(nearest) as ds:
        tf, shape = ds.transform, (ds.height, ds.width)
    rows, cols, margin_cm, base, top = crown_sub_cells(crowns, x0_m=tf.c, y_top_m=tf.f, res_m=tf.a, shape=shape, sub=5)
    first = first_return_mask(c, r)
    cx, cy = tf.c + (cols + 0.5) * tf.a, tf.f - (rows + 0.5) * tf.a
    _, j = cKDTree(np.column_stack([x[first], y[first]])).query(np.column_stack([cx, cy]))
    near_cls = c[first][j]
    veg = first & np.isin(c, VEGETATION_CLASSES)
    d, k = cKDTree(np.column_stack([x[veg], y[veg]])).query(np.column_stack([cx, cy]), distance_upper_bound=3.0)
    crown_z = np.where(np.isfinite(d), z[veg][np.minimum(k, veg.sum() - 1)], np.nan).astype(np.float32)
    np.savez_compressed(out, rows=rows, cols=cols, margin_cm=margin_cm, base=base, top=top, crown_z=crown_z,
                        near_veg=np.isin(near_cls, VEGETATION_CLASSES), near_building=near_cls == 6,
                        x0=tf.c, y_top=tf.f, res=tf.a)
    got = {"path": str(out), "trees": len(crowns), "circle_fit": int(crowns.circle_fit.sum()),
           "spacing_m": crowns.spacing_m, "cells": int(len(rows)),
           "cells_covered": int((margin_cm >= 0).any(axis=(1, 2)).sum()), "cpu_s": time.process_time() - t}
    if truth is not None:   # each fitted disk against the true crown nearest its centre (trees taller than 2 m)
        tc, ta = np.asarray(truth.scene.tree_c), np.asarray(truth.scene.tree_ac)
        fx, fy = crowns.x_m - truth.origin[0], crowns.y_m - truth.origin[1]
        dd, ii = cKDTree(tc[:, :2]).query(np.column_stack([fx, fy]))
        ok = dd < ta[ii, 0]
        rad_err = crowns.radius_m[ok] - ta[ii[ok], 0]
        base_err = crowns.base_m[ok] - truth.origin[2] - (tc[ii[ok], 2] - ta[ii[ok], 1])
        q = [5, 25, 50, 75, 95]
        got["against_truth"] = {
            "fitted_on_a_true_crown": int(ok.sum()), "true_crowns": int(len(tc)),
            "true_crowns_with_a_fit": int(len(np.unique(ii[ok]))),
            "radius_error_m_percentiles_5_25_50_75_95": np.round(np.percentile(rad_err, q), 3).tolist(),
            "radius_error_m_circle_fit_median": float(np.median(rad_err[crowns.circle_fit[ok]])),
            "centre_error_m_median": float(np.median(dd[ok])),
            "base_above_true_base_m_percentiles_5_25_50_75_95": np.round(np.percentile(base_err, q), 3).tolist()}
    return got


def with_crown_model(frame_occluder, cells_path: Path, use_base: bool, sub: int = 5):
    """``ortho.block._frame_occluder`` with the fitted crowns (``crown_model_cells``) over the frame's window: the
    trial of ``+occt`` / ``+occtb`` (not an option of the rectifier). A solid column of the occlusion DSM a disk
    reaches whose nearest first return is not a building's: covered at some sub-cell centre, a column up to the
    higher of its DSM height and the crown's there over the disks' sub-cells only (the march finds the rim between
    the sub-cell centres, ``sub_margin_cm``); covered at all, the whole cell; ``use_base``: only from the trees'
    crown base up (a slab); covered at none and its nearest return vegetation (the nearest-return DSM's crown
    beyond the fitted rim): it stops no ray. The occlusion DSM's window is raised in place where the crown stands
    higher (the march's bounds)."""
    import dataclasses

    from ortho.footprints import CROWN, FootprintOccluder

    z = np.load(cells_path)
    rows, cols, margin_cm, base = z["rows"], z["cols"], z["margin_cm"], z["base"]
    crown_z, near_veg, near_building = z["crown_z"], z["near_veg"], z["near_building"]
    x0, y_top, res = float(z["x0"]), float(z["y_top"]), float(z["res"])

    def occluder(task, surface, *rest):
        occ, sides = frame_occluder(task, surface, *rest)
        h, w = surface.heights_m.shape
        r0, c0 = int(round((y_top - surface.y_top_m) / res)), int(round((surface.x_left_m - x0) / res))
        if occ is None:
            occ = FootprintOccluder(np.full((h, w), -np.inf, np.float32), np.full((h, w), -np.inf, np.float32),
                                    np.full((h, w), -1, np.int32), np.zeros((0, sub, sub), np.uint8), sub,
                                    np.zeros((0, sub, sub), np.int16))
        if occ.sub != sub and len(occ.sub_masks):
            raise ValueError(f"the occluder's cells have {occ.sub} sub-cells a side, the crowns' {sub}")
        sel = np.flatnonzero((rows >= r0) & (rows < r0 + h) & (cols >= c0) & (cols < c0 + w) & ~near_building)
        rr, cc = rows[sel] - r0, cols[sel] - c0
        solid = occ.base_m[rr, cc] == -np.inf
        sel, rr, cc = sel[solid], rr[solid], cc[solid]
        m = margin_cm[sel]
        n_in = (m >= 0).sum(axis=(1, 2))
        heights = surface.heights_m
        top = heights[rr, cc]
        raised = np.where(n_in > 0, np.fmax(top, crown_z[sel]), top).astype(np.float32)
        heights[rr, cc] = raised
        base_m, slab_top, sub_index = occ.base_m.copy(), occ.slab_top_m.copy(), occ.sub_index.copy()
        spill = (n_in == 0) & near_veg[sel]
        base_m[rr[spill], cc[spill]] = np.inf   # stops nothing: ``_cell_blocks``' slab of the whole cell, none
        slab_top[rr[spill], cc[spill]] = -np.inf
        sub_index[rr[spill], cc[spill]] = -1
        b = base[sel]
        whole = n_in == sub * sub
        if use_base:
            wb = whole & np.isfinite(b) & (b < raised)
            base_m[rr[wb], cc[wb]] = b[wb]
            slab_top[rr[wb], cc[wb]] = raised[wb]
            sub_index[rr[wb], cc[wb]] = CROWN
        part = (n_in > 0) & ~whole
        k0 = len(occ.sub_masks)
        pb = np.where(use_base & np.isfinite(b[part]), b[part], -1e9).astype(np.float32)
        base_m[rr[part], cc[part]] = pb
        # the march takes a column within the tolerance of the ray as passed, a slab's top as it is
        slab_top[rr[part], cc[part]] = raised[part] - np.float32(task_tolerance_m)
        sub_index[rr[part], cc[part]] = k0 + np.arange(int(part.sum()), dtype=np.int32)
        masks = np.where(m[part] >= 0, 2, 0).astype(np.uint8)
        occ = dataclasses.replace(
            occ, base_m=base_m, slab_top_m=slab_top, sub_index=sub_index, sub=sub,
            sub_masks=np.concatenate([occ.sub_masks.reshape(-1, sub, sub), masks]),
            sub_margin_cm=np.concatenate([occ.sub_margin_cm.reshape(-1, sub, sub), m[part]]))
        return occ, sides

    return occluder


task_tolerance_m = 0.3  # the march's tolerance (``ortho.rectify.march_bound``'s default, the true ortho's)


def classified_strips(src: Path, tall: bool, tmp: Path) -> list[Path]:
    """The block's classified strips: the demo's of its chain (lidar_out/classified), a tall block's simulated strips
    with their true classes (copies written into ``tmp``, which the caller removes)."""
    import laspy

    if not tall:
        return sorted((src / "lidar_out" / "classified").glob("*.la[sz]"))
    tmp.mkdir(parents=True, exist_ok=True)
    paths = []
    for q in sorted((src / "lidar").glob("*.la[sz]")):
        las = laspy.read(q)
        las.classification = laspy.read(src / "truth" / "lidar" / q.name).classification
        las.write(tmp / q.name)
        paths.append(tmp / q.name)
    return paths


def block_crown_model(name: str, src: Path, work: Path, tall: bool) -> dict:
    """The product's crowns of the block (``lidarctl.rasters.crown_model.write_crown_model``: crowns.gpkg and
    dsm_crowns.tif, as the chain's rasters stage writes them) into ``work/<name>/crown_model``, made once: from the
    demo's classified strips and dsm_nearest.tif of the chain, a tall block's simulated strips with their true
    classes (classified copies in a temporary folder) and its ``lidar_rasters`` dsm_nearest.tif; paths and CPU s."""
    import shutil

    from lidarctl.rasters.crown_model import write_crown_model

    out = work / name / "crown_model"
    made = out / "made.json"
    if made.exists():
        return json.loads(made.read_text())
    out.mkdir(parents=True, exist_ok=True)
    nearest = lidar_rasters(name, src, work, tall) / "dsm_nearest.tif"
    tmp = work / name / "classified_crowns_tmp"
    paths = classified_strips(src, tall, tmp)
    t, c = time.perf_counter(), time.process_time()
    gpkg, tif = write_crown_model(paths, nearest, out)
    got = {"crowns": str(gpkg), "occlusion_dsm": str(tif), "wall_s": time.perf_counter() - t,
           "cpu_s": time.process_time() - c}
    shutil.rmtree(tmp, ignore_errors=True)
    made.write_text(json.dumps(got, indent=1) + "\n")
    return got


def block_lidar_footprints(name: str, src: Path, work: Path, tall: bool, command: str = "vectors") -> Path:
    """The LiDAR's own regularised roof outlines of the block's classified strips as a one-layer GeoPackage for
    ``--footprints``: ``command`` "vectors" the buildings layer of ``lidarctl vectors`` (``+fpl``), "corners" the
    roof_outlines.gpkg of ``lidarctl corners`` (``+fpc``, what the chain takes when no footprints are given); made
    once into ``work/<name>/lidar_footprints`` (``lidar_corners``): the demo's classified strips of the chain, a tall
    block's simulated strips with their true classes."""
    import shutil

    import pyogrio

    out = work / name / ("lidar_footprints" if command == "vectors" else "lidar_corners")
    gpkg = out / ("buildings.gpkg" if command == "vectors" else "roof_outlines.gpkg")
    if gpkg.exists():
        return gpkg
    out.mkdir(parents=True, exist_ok=True)
    tmp = work / name / f"classified_{command}_tmp"
    paths = classified_strips(src, tall, tmp)
    t = time.perf_counter()
    lidarctl = str(Path(sys.executable).parent / "lidarctl")
    if command == "vectors":
        subprocess.run([lidarctl, "vectors", *map(str, paths), str(out / "vectors.gpkg")], check=True)
        meta, _, wkb, fields = pyogrio.raw.read(str(out / "vectors.gpkg"), layer="buildings")
        pyogrio.raw.write(str(gpkg), wkb, fields, layer="buildings", driver="GPKG", crs=meta["crs"],
                          geometry_type=meta["geometry_type"], fields=meta["fields"])
    else:
        subprocess.run([lidarctl, "corners", *map(str, paths), str(out)], check=True)
        wkb = pyogrio.raw.read(str(gpkg))[2]
    (out / "made.json").write_text(json.dumps({"wall_s": time.perf_counter() - t, "buildings": len(wkb),
                                               "strips": [q.name for q in paths]}, indent=1) + "\n")
    shutil.rmtree(tmp, ignore_errors=True)
    return gpkg


def inset_outlines(src: Path, dst: Path, inset_m: float) -> Path:
    """The polygons of ``src`` moved ``inset_m`` inwards (shapely's negative buffer, mitred corners: a rectangle stays
    one), written to ``dst`` with the same fields; a polygon that vanishes is left out."""
    import pyogrio
    import shapely

    meta, _, wkb, fields = pyogrio.raw.read(str(src))
    geoms = shapely.buffer(shapely.from_wkb(wkb), -inset_m, join_style="mitre")
    keep = ~shapely.is_empty(geoms)
    geoms = shapely.multipolygons([shapely.get_parts(g) for g in geoms[keep]]) if keep.any() else geoms[keep]
    dst.parent.mkdir(parents=True, exist_ok=True)
    pyogrio.raw.write(str(dst), shapely.to_wkb(geoms), [f[keep] for f in fields], layer="roof_outlines",
                      driver="GPKG", crs=meta["crs"], geometry_type="MultiPolygon", fields=meta["fields"])
    return dst


def make_dom(project: Path, eo_path=None, camera_path=None, footprints=None, crown_base=None,
             occlusion_dsm=None, crowns=None) -> dict:
    """The true ortho DOM of ``project`` on its lidar_out/dsm.tif (``footprints``, ``crown_base``, ``occlusion_dsm``:
    in the occlusion test): ``eval_true_ortho_occlusion.make_dom``; the rectify and mosaic times."""
    from eval_true_ortho_occlusion import make_dom as occlusion_make_dom

    return occlusion_make_dom(project, True, eo_path=eo_path, camera_path=camera_path, footprints=footprints,
                              crown_base=crown_base, occlusion_dsm=occlusion_dsm, crowns=crowns)


def lidar_rasters(name: str, src: Path, work: Path, tall: bool) -> Path:
    """The folder of the block's ``lidarctl rasters`` products (dsm.tif, dsm_nearest.tif): the demo's lidar_out; a
    tall block's made once into ``work/<name>/lidar_rasters`` from its simulated strips with their true classes
    (classified copies in a temporary folder); the CPU seconds in ``made.json`` there."""
    if not tall:
        return src / "lidar_out"
    import shutil

    from lidarctl.rasters.products import write_rasters

    out = work / name / "lidar_rasters"
    if (out / "made.json").exists():
        return out
    tmp = work / name / "classified_tmp"
    paths = classified_strips(src, True, tmp)
    t, c = time.perf_counter(), time.process_time()
    write_rasters(paths, out, 0.5)
    made = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "strips": [p.name for p in paths]}
    shutil.rmtree(tmp)
    (out / "made.json").write_text(json.dumps(made, indent=1) + "\n")
    return out


def run_block(name: str, src: Path, work: Path, cells: list[str]) -> dict:
    """The block's conventional DOM, truth and 2.5D bound, then per DSM (``lidar``: the project's
    lidar_out/dsm.tif; ``0.5``: truth/dsm.tif; other numbers: the truth surface at that cell) its true-ortho DOM and
    its figures."""
    import shutil

    import eval_true_ortho_occlusion as E
    from eval_true_ortho import roof_displacements
    from eval_true_ortho_fill import measure_block

    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    tall = name.startswith("tall")
    kw = {"eo_path": src / "truth" / "eo.txt", "camera_path": src / "truth" / "camera.toml"} if tall else {}
    copy = E.copy_tall if tall else E.copy_demo
    conv = work / name / "conventional"
    if not (conv / "made.json").exists():
        copy(src, conv)
        (conv / "made.json").write_text(json.dumps(E.make_dom(conv, False, **kw), indent=1, default=str) + "\n")
    grid = OrthoGrid.union(read_index(conv).grids)
    t = time.perf_counter()
    kind, ground, roof, vis, foot_nadir = cached_truth(E, work / name, conv, grid)
    vis = list(vis)
    print(name, "truth", round(time.perf_counter() - t, 1), "s", flush=True)
    conv_masks = E.frame_masks(conv, grid)[0]
    truth = E.Truth(conv)
    codes, bound = cached_clearance(E, truth, work / name, grid, ground, vis, foot_nadir)
    print(name, "2.5D bound", json.dumps(bound), flush=True)
    results = {}
    points = None
    for spec in cells:
        cell, *flags = spec.split("+")
        footprints = any(f.startswith("fp") for f in flags)
        p = work / name / f"true_ortho_dsm_{spec}"
        made_path = p / "made.json"
        if not made_path.exists():
            copy(src, p)
            fp_path = None
            inset = [f for f in flags if f.startswith("fpci")]
            if "fpl" in flags or "fpc" in flags:  # the LiDAR's own roof outlines as the footprints
                fp_path = block_lidar_footprints(name, src, work, tall, "vectors" if "fpl" in flags else "corners")
            elif inset:  # ``+fpciNN``: the corners stage's roof outlines moved NN cm inwards (walls beneath eaves)
                fp_path = inset_outlines(block_lidar_footprints(name, src, work, tall, "corners"),
                                         p / "lidar_out" / "roof_outlines_inset.gpkg", int(inset[0][4:]) / 100.0)
            elif footprints:
                from aerotri.core.project import Project
                from aerotri.sim.project import write_footprints_gpkg

                fp_path = p / "truth" / "footprints.gpkg"
                write_footprints_gpkg(p / "truth" / "buildings.geojson", fp_path, Project.open(p).crs)
            cast_s = 0.0
            occlusion_dsm = None
            crowns = None
            if cell in ("lidar", "lidarn") or "occn" in flags:
                rasters_dir = lidar_rasters(name, src, work, tall)
                if "occn" in flags:
                    occlusion_dsm = rasters_dir / "dsm_nearest.tif"
                occc = [f for f in flags if f.startswith("occc")]
                if occc:  # ``+occc[NN]``: dsm_nearest's crowns within the cells they cover (min share NN %, 100)
                    share = int(occc[0][4:] or 100) / 100
                    crowns = crowns_within_cells_dsm(src, tall, occlusion_dsm, p / "lidar_out" / "dsm_crowns.tif",
                                                     share)
                    occlusion_dsm = Path(crowns["path"])
                if "occs" in flags or "occs2" in flags:  # dsm_nearest's crowns over their sub-cells in the march
                    crowns = crowns_within_cells_dsm(src, tall, occlusion_dsm, p / "lidar_out" / "crown_bits.tif",
                                                     None, beside="occs2" in flags)
                if "occt" in flags or "occtb" in flags:  # the crowns fitted to each tree's returns
                    crowns = crown_model_cells(src, tall, occlusion_dsm, p / "lidar_out" / "crown_model.npz", truth)
                if "crowns" in flags:  # the product's: lidarctl rasters' crowns.gpkg and dsm_crowns.tif
                    crowns = block_crown_model(name, src, work, tall)
                    occlusion_dsm = Path(crowns["occlusion_dsm"])
                if cell == "lidarn" or (cell == "lidar" and tall):
                    shutil.copy2(rasters_dir / ("dsm_nearest.tif" if cell == "lidarn" else "dsm.tif"),
                                 p / "lidar_out" / "dsm.tif")
            if cell == "0.5" and tall:
                pass  # copy_tall put truth/dsm.tif there
            elif cell in POINT_DSMS:
                if points is None:
                    points = block_first_returns(src, tall)
                like = src / ("truth" if tall else "lidar_out") / "dsm.tif"
                point_dsm = write_points_dsm(cell, *points, like, p / "lidar_out" / "dsm.tif")
            elif cell not in ("lidar", "lidarn"):
                cast_s = write_fine_dsm(src, truth, float(cell), p / "lidar_out" / "dsm.tif")
            crown_path, crown_cells = None, None
            if "cb" in flags or "cbl" in flags:
                crown_path = p / "lidar_out" / "crown_base.tif"
                like = p / "lidar_out" / "dsm.tif"
                crown_cells = (truth_crown_base(truth, like, crown_path) if tall and "cb" in flags
                               else lidar_crown_base(src, tall, like, crown_path))
            import ortho.block as ortho_block

            switches = (ortho_block.HEIGHTS_BY_OUTLINE, ortho_block.OUTLINES_OF_THE_OCCLUSION_TEST)
            ortho_block.HEIGHTS_BY_OUTLINE = "bil" not in flags   # ``+bil``: footprints, heights bilinear (main's before)
            ortho_block.OUTLINES_OF_THE_OCCLUSION_TEST = "hod" not in flags  # ``+hod``: the outlines of the heights DSM
            inner = ortho_block._frame_occluder
            if "occs" in flags or "occs2" in flags:
                ortho_block._frame_occluder = with_crown_bits(inner, Path(crowns["path"]), crowns["top_path"])
            if "occt" in flags or "occtb" in flags:
                ortho_block._frame_occluder = with_crown_model(inner, Path(crowns["path"]), "occtb" in flags)
            try:
                made = make_dom(p, footprints=fp_path, crown_base=crown_path, occlusion_dsm=occlusion_dsm,
                                crowns=crowns["crowns"] if "crowns" in flags else None, **kw)
            finally:
                ortho_block.HEIGHTS_BY_OUTLINE, ortho_block.OUTLINES_OF_THE_OCCLUSION_TEST = switches
                ortho_block._frame_occluder = inner
            made["occlusion_dsm"] = str(occlusion_dsm) if occlusion_dsm else None
            made["dsm_ray_cast_s"] = cast_s
            made["crowns_within_cells"] = crowns
            made["footprints"] = str(fp_path) if fp_path else None
            made["crown_base"] = {"path": str(crown_path), "cells": crown_cells} if crown_path else None
            made["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                                            capture_output=True, text=True).stdout.strip()
            if cell in POINT_DSMS:
                made["point_dsm"] = point_dsm
            made_path.write_text(json.dumps(made, indent=1, default=str) + "\n")
        made = json.loads(made_path.read_text())
        res = {"rectify": made["rectify"], "dsm_ray_cast_s": made["dsm_ray_cast_s"], "point_dsm": made.get("point_dsm"),
               "footprints": made.get("footprints"), "crown_base": made.get("crown_base"),
               "occlusion_dsm": made.get("occlusion_dsm"), "crowns_within_cells": made.get("crowns_within_cells"),
               "made_at_commit": made.get("commit"),
               "roofs": roof_displacements(p / "ortho" / "mosaic.tif", p / "truth" / "ortho.tif",
                                           p / "truth" / "roof_corners.csv")}
        way = E.measure_way(p, None, grid, kind, ground, roof, vis, foot_nadir, conv_masks)
        res["ghosts"] = way["ghosts"]
        res["occluded_ground"] = way["occluded_ground"]
        res["seams"] = {k: v for k, v in way["seams"].items() if k != "pairs"}
        # the fill measure of eval_true_ortho_fill.py on this DOM (its conventional DOM the same)
        got = {}
        res["fill"] = measure_block(work, name, true_ortho=p, truth=truth,
                                    truth_arrays=(kind, ground, roof, vis, foot_nadir), cells_out=got)
        res["misses_by_what_the_2_5d_surface_puts_in_the_line_of_sight"] = {
            which: misses_by_blocker(codes, vis, got[which]) for which in ("miss", "over")}
        results[spec] = res
        print(name, spec, json.dumps({k: v for k, v in res.items() if k != "seams"}, indent=1), flush=True)
        shutil.rmtree(p / "images", ignore_errors=True)
    conv_made = json.loads((conv / "made.json").read_text())
    return {"project": str(src), "surface_2_5d_bound": bound, "conventional_rectify": conv_made["rectify"],
            "dsm": results}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tall", type=Path, default=REPO / "out" / "tall_sim")
    ap.add_argument("--tall2", type=Path, default=None, help="block ``tall2``: the tall preset with another seed")
    ap.add_argument("--tall3", type=Path, default=None, help="block ``tall3``: the tall preset with a third seed")
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_occlusion")
    ap.add_argument("--blocks", default="demo:lidar,0.5,0.1;tall:0.5,0.25,0.2,0.1")
    ap.add_argument("--key", default="dsm_cell", help="the key of the JSON to write (the others kept)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_fill.json")
    args = ap.parse_args()
    key = read_results(args.out).get(args.key, {"blocks": {}})  # its earlier blocks kept, merged
    for spec in args.blocks.split(";"):
        name, cells = spec.split(":")
        src = {"tall": args.tall, "tall2": args.tall2, "tall3": args.tall3}.get(name, args.demo)
        key["blocks"][name] = run_block(name, src, args.work, cells.split(","))
    key["command"] = ("python bench/eval_true_ortho_dsm_cell.py --work DIR --tall DIR --demo DIR "
                      + ("--tall2 DIR " if args.tall2 else "") + ("--tall3 DIR " if args.tall3 else "") +
                      f"--blocks '{args.blocks}' --key {args.key}")
    key["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    for spec in args.blocks.split(";"):   # the command that made each block (a key can be filled block by block)
        key.setdefault("commands", {})[spec.split(":")[0]] = {"command": key["command"], "commit": key["commit"]}
    store_result(args.out, key, key=args.key)


if __name__ == "__main__":
    main()
