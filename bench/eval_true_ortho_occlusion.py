"""Occlusion and seamlines of true orthophotos against conventional ones (issue 42, "must show"), on the demo block and
on the tall-building block (preset ``tall``): the same frames and orientation rectified on the DEM and, with
``--true-ortho``, on the DSM, each mosaicked with the default least-cost seams, and both measured against the
simulator's own geometry.

The truth is the simulated scene itself, rebuilt from the preset and seed of ``truth/truth.json`` (checked against
``truth/dem.tif`` and ``truth/dsm.tif``) and ray cast (``aerotri.sim.raycast``) at the centre of every DOM cell:

- surface: a straight-down ray says what the cell is: ground (terrain, roads), roof, tree;
- visibility: for every frame whose footprint holds the cell (the conventional frame ortho has a value there) and
  every ground cell, the ray from the frame's true projection centre (``truth/eo.txt``) to the ground point: the
  frame sees the cell when the first hit is the terrain within 0.2 m of the point, else the roof, wall or tree it
  meets first hides it.

Figures, per block and way (``conventional``, ``true_ortho``):

- roofs: the roof-corner displacement of ``bench/eval_true_ortho.py`` (24 m patches against ``truth/ortho.tif``,
  ``ortho.check.measure_roof_patches``: masked NCC over the valid cells; runs before issue 42's roofs work, a phase
  correlation with nodata set to the patch mean), metres and GSD;
- source frame of each DOM cell, as ``ortho mosaic`` picks it: the seam label's frame where its ortho has a value,
  else the valid frame of the nearest nadir point (cells of the feather zone counted with their label's frame);
- occluded ground: ground cells hidden in the nadir-most frame covering them (nearest nadir point); of those some
  other frame sees, the share the DOM fills from a frame that sees the cell (``filled_from_a_frame_that_sees``),
  and the share it fills at all; those no frame sees, and how many of them the DOM leaves empty;
- ghost pixels: ground cells of the DOM whose source frame does not see the ground there but a roof or wall
  (``building``; the roof texture mapped onto the ground) or a tree crown (``tree``), also counted beyond 1 m of the
  nearest roof cell and beyond one cell of the ground the source frame sees (outside the edge band of a hidden
  area, where the DSM's roof edge, on its grid and interpolated, decides to within about a cell);
- seamlines: DOM cells on a seam (label differs from the right or lower neighbour) whose surface is a roof: count,
  length (count x GSD), separate crossings (8-connected parts) and buildings crossed; per pair of frames, whether a
  ground route existed (the seam's two ends, each snapped to the nearest roof-free overlap cell within 30 m, in one
  8-connected part of the pair's roof-free overlap on the seam grid);
- seam misalignment: ``ortho.mosaic.seam_misalignment`` (NCC of 32 px ground patches of the two frame orthos on the
  seam), px;
- roofs left nodata: the roof cells some frame's footprint covers, by their distance from the roof's outline
  (``roof_nodata_by_depth``: 0-1 m, 1-2 m, deeper), and the share the DOM leaves nodata.

Usage: python bench/eval_true_ortho_occlusion.py [--demo /work/ref/demo_chain/project] [--tall DIR] [--work DIR]
       [--blocks demo,tall] [--chain NAME=DIR] [--key KEY]
The tall block: ``DIR`` made by ``aerotri sim DIR --preset tall`` (simulated when missing); its frames are rectified
with the true orientation and camera (``truth/eo.txt``, ``truth/camera.toml``) on the simulator's DEM and DSM
(``truth/dem.tif``, ``truth/dsm.tif``, nDSM their difference): it has no chain run. The demo uses the chain's
adjusted orientation and LiDAR rasters (``/work/ref/demo_chain``) as ``bench/eval_true_ortho.py``; so does a block
``--chain NAME=DIR`` (e.g. the tall block after ``aerotri run``: the chain's LiDAR rasters and adjusted orientation).
Writes bench/results/true_ortho_occlusion.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, read_results, store_result  # noqa: E402

VISIBLE_TOL_M = 0.2  # the first hit within this of the ground point: the frame sees it
GHOST_MARGIN_M = 1.0  # ghosts also counted beyond this distance from the nearest roof cell
END_REACH_M = 30.0  # seam ends slide along the overlap by up to this (as ortho mosaic's end_reach_m)
CHUNK = 1 << 20

# visibility codes of a ground cell from a frame
NOT_EVALUATED, SEES, ROOF, WALL, TREE, TERRAIN_ELSEWHERE, NOTHING = 0, 1, 2, 3, 4, 5, 6


# ------------------------------------------------------------------------------------------------ block set-up

def copy_demo(src: Path, dst: Path) -> None:
    from eval_true_ortho import copy_project

    copy_project(src, dst)


def copy_tall(src: Path, dst: Path) -> None:
    """The simulated project without a chain run: the truth's DEM, DSM and nDSM as its LiDAR rasters."""
    import rasterio

    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in ("camera.toml", "images", "project.toml", "truth"):
        p = src / name
        (shutil.copytree if p.is_dir() else shutil.copy2)(p, dst / name)
    (dst / "lidar_out").mkdir()
    shutil.copy2(src / "truth" / "dem.tif", dst / "lidar_out" / "dem.tif")
    shutil.copy2(src / "truth" / "dsm.tif", dst / "lidar_out" / "dsm.tif")
    with rasterio.open(src / "truth" / "dem.tif") as a, rasterio.open(src / "truth" / "dsm.tif") as b:
        nd = b.read(1) - a.read(1)
        prof = a.profile
    with rasterio.open(dst / "lidar_out" / "ndsm.tif", "w", **prof) as out:
        out.write(nd.astype(np.float32), 1)


def make_dom(project: Path, true_ortho: bool, eo_path=None, camera_path=None, footprints=None, crown_base=None,
             occlusion_dsm=None, crowns=None, crs=None) -> dict:
    """Rectify (``footprints``: a footprints GeoPackage, ``crown_base``: a crown-base raster, ``occlusion_dsm``: a DSM
    of its own, in the true ortho's occlusion test; ``crs``: the output CRS, PROJ's ballpark operation accepted, as
    ``ortho rectify --crs ... --allow-ballpark``) and mosaic the project; the rectify and mosaic times."""
    from aerotri.core.executor import Executor
    from ortho.block import rectify_block
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings, RectifySettings

    settings = RectifySettings(crs=crs, true_ortho=True, dsm=str(project / "lidar_out" / "dsm.tif"),
                               footprints=str(footprints) if footprints else None,
                               crown_base=str(crown_base) if crown_base else None,
                               occlusion_dsm=str(occlusion_dsm) if occlusion_dsm else None,
                               crowns=str(crowns) if crowns else None) if true_ortho \
        else RectifySettings(crs=crs)
    with Executor() as ex:
        t, c = time.perf_counter(), time.process_time()
        done = rectify_block(project, settings, eo_path=eo_path, camera_path=camera_path, executor=ex,
                             allow_ballpark=crs is not None)
        rect = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
        t, c = time.perf_counter(), time.process_time()
        summary = json.loads(mosaic_block(project, MosaicSettings(), executor=ex).summary_path.read_text())
        mos = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    mp = sum(g.width * g.height for g in done.grids) / 1e6
    rect.update(frame_ortho_mp=round(mp, 2), cpu_s_per_mp=rect["cpu_s"] / mp)
    return {"rectify": rect, "mosaic": mos, "summary": summary}


def remosaic_dom(project: Path) -> dict:
    from aerotri.core.executor import Executor
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings

    with Executor() as ex:
        t, c = time.perf_counter(), time.process_time()
        summary = json.loads(mosaic_block(project, MosaicSettings(), executor=ex).summary_path.read_text())
        mos = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    return {"mosaic": mos, "summary": summary}


# ------------------------------------------------------------------------------------------------ the truth

class Truth:
    """The simulated scene of a project, its origin and the true projection centres."""

    def __init__(self, project: Path, overrides: tuple = ()):
        """``overrides``: the ``--set`` options the block was simulated with (truth.json does not keep them; e.g. a
        DMC subset's ``flight.strips=2``: the scene grows with the flight)."""
        from pyproj import CRS

        from aerotri.core.project import Project
        from aerotri.sim import raycast
        from aerotri.sim.config import load_preset
        from aerotri.sim.flight import block_layout
        from aerotri.sim.scene import build_scene

        info = json.loads((project / "truth" / "truth.json").read_text())
        cfg = load_preset(info["preset"], [*overrides, f"preset.seed={int(info['seed'])}"])
        self.origin = np.array(info["origin_m"], float)
        layout = block_layout(cfg)
        s_scene = np.random.SeedSequence(int(info["seed"])).spawn(4)[0]
        scene_seed = int(np.random.default_rng(s_scene).integers(0, 2**31 - 1))
        self.scene = build_scene(cfg.scene, layout.width_m, layout.height_m, self.origin, scene_seed)
        self.accel = raycast.build_accel(self.scene)
        self.cast_many = raycast.cast_many
        self.crs = CRS.from_user_input(Project.open(project).crs)
        self._check(project)
        self.centres = {}
        for line in (project / "truth" / "eo.txt").read_text().splitlines():
            if line.strip() and not line.startswith("#"):
                f = line.split()
                self.centres[f[0]] = np.array([float(f[1]), float(f[2]), float(f[3])]) - self.origin

    def _check(self, project: Path) -> None:
        """The rebuilt scene is the one the project was simulated from: its terrain and surface at 2,000 cells of
        truth/dem.tif and truth/dsm.tif."""
        import rasterio

        rng = np.random.default_rng(1)
        for name in ("dem.tif", "dsm.tif"):
            with rasterio.open(project / "truth" / name) as ds:
                z = ds.read(1)
                r, c = rng.integers(0, ds.height, 2000), rng.integers(0, ds.width, 2000)
                x, y = rasterio.transform.xy(ds.transform, r, c)
                got = self.surface(np.asarray(x) - self.origin[0], np.asarray(y) - self.origin[1])[1] \
                    if name == "dsm.tif" else self.scene.terrain_height(np.asarray(x) - self.origin[0],
                                                                          np.asarray(y) - self.origin[1])
                err = np.abs(got + self.origin[2] - z[r, c])
                # the DSM is rendered with the trees; a crown's top may differ by a few cm between the two renders
                if np.median(err) > 1e-3 or np.mean(err > 0.05) > 0.01:
                    raise SystemExit(f"{project}/truth/{name}: the rebuilt scene differs (median {np.median(err):.3f} "
                                     "m): the simulator changed since the project was made")

    def local_xy(self, grid, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local scene coordinates (m) of the centres of ``grid``'s cells (``rows``, ``cols``: arrays that broadcast
        together; in the project CRS the results keep their own shapes, a row and a column of the grid stay that): a
        grid in another CRS than the project's (``ortho rectify --crs``) through PROJ's operation between them (the
        ballpark one where PROJ knows none, as ``--allow-ballpark``)."""
        xs, ys = grid.centres(rows, cols)
        if not grid.crs.equals(self.crs):
            from pyproj import Transformer

            xs, ys = (np.ascontiguousarray(a) for a in np.broadcast_arrays(xs, ys))
            xs, ys = Transformer.from_crs(grid.crs, self.crs, always_xy=True).transform(xs, ys)
        return np.asarray(xs) - self.origin[0], np.asarray(ys) - self.origin[1]

    def cast(self, origins: np.ndarray, dirs: np.ndarray):
        t = np.empty(len(dirs))
        kind = np.empty(len(dirs), np.int64)
        obj = np.empty(len(dirs), np.int64)
        for s in range(0, len(dirs), CHUNK):
            o = np.ascontiguousarray(origins[s:s + CHUNK] if origins.ndim == 2 else
                                     np.broadcast_to(origins, (len(dirs[s:s + CHUNK]), 3)))
            a, b, c, _ = self.cast_many(o, np.ascontiguousarray(dirs[s:s + CHUNK]), self.accel, True)
            t[s:s + CHUNK], kind[s:s + CHUNK], obj[s:s + CHUNK] = a, b, c
        return t, kind, obj

    def surface(self, x: np.ndarray, y: np.ndarray):
        """(kind, height, obj) of the first hit of a straight-down ray at local (x, y)."""
        top = float(self.accel[-1]) + 10.0
        o = np.stack([x, y, np.full_like(x, top)], axis=1)
        d = np.tile([0.0, 0.0, -1.0], (len(x), 1))
        t, kind, obj = self.cast(o, d)
        return kind, top - t, obj

    def visibility(self, image_id: str, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Visibility code of ground points (local x, y, z) from a frame's true projection centre."""
        from aerotri.sim.scene import KIND_NONE, KIND_ROOF, KIND_TERRAIN, KIND_TREE, KIND_WALL

        C = self.centres[image_id]
        d = np.stack([x - C[0], y - C[1], z - C[2]], axis=1)
        length = np.linalg.norm(d, axis=1)
        t, kind, _ = self.cast(C, d)
        code = np.full(len(x), NOTHING, np.uint8)
        code[kind == KIND_ROOF] = ROOF
        code[kind == KIND_WALL] = WALL
        code[kind == KIND_TREE] = TREE
        code[kind == KIND_TERRAIN] = TERRAIN_ELSEWHERE
        code[(kind == KIND_TERRAIN) & (t * length >= length - VISIBLE_TOL_M)] = SEES
        code[kind == KIND_NONE] = NOTHING
        return code


# ------------------------------------------------------------------------------------------------ rasters

def frame_masks(project: Path, grid) -> tuple[list, list, np.ndarray]:
    """Per frame of ortho/frames/index.json: (image_id, (row0, col0, mask) on ``grid``), nadir points (F, 2)."""
    import rasterio

    from ortho.block import read_index

    index = read_index(project)
    grids = dict(zip(index.image_ids, index.grids))
    out = []
    for e in index.frames:
        g = grids[e.image_id]
        c0, r0 = g.offset_in(grid)
        with rasterio.open(project / "ortho" / "frames" / e.file) as ds:
            m = ds.read_masks(1) > 0
        out.append((e.image_id, r0, c0, m))
    nadir = np.array([e.nadir_xy_m for e in index.frames], float)
    return out, nadir


def place(shape, r0: int, c0: int, m: np.ndarray) -> np.ndarray:
    """A frame's mask (at row r0, column c0 of a grid of ``shape``) on the whole grid."""
    full = np.zeros(shape, bool)
    H, W = shape
    h, w = m.shape
    a0, b0 = max(0, r0), max(0, c0)
    a1, b1 = min(H, r0 + h), min(W, c0 + w)
    if a1 > a0 and b1 > b0:
        full[a0:a1, b0:b1] = m[a0 - r0:a1 - r0, b0 - c0:b1 - c0]
    return full


def place_values(shape, r0: int, c0: int, a: np.ndarray) -> np.ndarray:
    """An array (at row r0, column c0 of a grid of ``shape``) on the whole grid, zeros elsewhere."""
    full = np.zeros(shape, a.dtype)
    H, W = shape
    h, w = a.shape
    a0, b0 = max(0, r0), max(0, c0)
    a1, b1 = min(H, r0 + h), min(W, c0 + w)
    if a1 > a0 and b1 > b0:
        full[a0:a1, b0:b1] = a[a0 - r0:a1 - r0, b0 - c0:b1 - c0]
    return full


def nadir_most(masks: list, nadir: np.ndarray, grid) -> np.ndarray:
    """Per cell of ``grid``: the index of the valid frame with the nearest nadir point, -1 where none."""
    xs, ys = grid.centres()
    best = np.full((grid.height, grid.width), np.inf, np.float32)
    out = np.full((grid.height, grid.width), -1, np.int32)
    for k, (_, r0, c0, m) in enumerate(masks):
        v = place(out.shape, r0, c0, m)
        d = np.hypot(xs[None, :] - nadir[k, 0], ys[:, None] - nadir[k, 1]).astype(np.float32)
        better = v & (d < best)
        best[better] = d[better]
        out[better] = k
    return out


def seam_labels_on(project: Path, grid) -> tuple[np.ndarray, np.ndarray, object, int]:
    """ortho/seams.tif (frame index per seam cell, -1 none) at the DOM cells of ``grid``; also the seam grid itself
    and its factor."""
    import rasterio

    with rasterio.open(project / "ortho" / "seams.tif") as ds:
        lab = ds.read(1).astype(np.int32)
        t = ds.transform
    f = int(round(t.a / grid.res_m))
    c0 = int(round((grid.x_left_m - t.c) / grid.res_m))
    r0 = int(round((t.f - grid.y_top_m) / grid.res_m))
    rows = np.clip((np.arange(grid.height) + r0) // f, 0, lab.shape[0] - 1)
    cols = np.clip((np.arange(grid.width) + c0) // f, 0, lab.shape[1] - 1)
    return lab[np.ix_(rows, cols)], lab, t, f


def source_by_value(project: Path, grid, masks: list, dom: np.ndarray, dom_valid: np.ndarray):
    """The frame each DOM cell's samples come from, found by value: of the frames with a value there, the one whose
    samples through its gains (mosaic.json, rounded as the mosaic's lookup tables) differ least from the DOM's (sum
    over the bands); -1 where the DOM has none. Also the cells where that difference is 0 (the frame's own samples:
    away from the feather of the seams)."""
    import rasterio

    summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    H, W = dom_valid.shape
    best = np.full((H, W), np.iinfo(np.int32).max, np.int64)
    src = np.full((H, W), -1, np.int32)
    from ortho.block import read_index

    files = {e.image_id: e.file for e in read_index(project).frames}
    top = np.iinfo(dom.dtype).max if np.issubdtype(dom.dtype, np.integer) else None
    for k, (image_id, r0, c0, m) in enumerate(masks):
        gains = summary["gains"][image_id]
        with rasterio.open(project / "ortho" / "frames" / files[image_id]) as ds:
            img = ds.read()
        a0, b0 = max(0, r0), max(0, c0)
        a1, b1 = min(H, r0 + m.shape[0]), min(W, c0 + m.shape[1])
        sub = (slice(a0, a1), slice(b0, b1))
        fsub = (slice(a0 - r0, a1 - r0), slice(b0 - c0, b1 - c0))
        err = np.zeros((a1 - a0, b1 - b0), np.int64)
        for b in range(dom.shape[0]):
            expect = np.rint(img[b][fsub].astype(np.float32) * np.float32(gains[b]))
            if top is not None:
                expect = np.clip(expect, 0, top)
            err += np.abs(dom[b][sub].astype(np.int64) - expect.astype(np.int64))
        ok = m[fsub] & dom_valid[sub] & (err < best[sub])
        best[sub][ok] = err[ok]
        src[sub][ok] = k
    return src, best == 0


def source_frames(labels: np.ndarray, masks: list, nadir_idx_of_valid) -> np.ndarray:
    """The frame each DOM cell is taken from: its label where that frame's ortho has a value, else the valid frame
    of the nearest nadir point (``nadir_idx_of_valid``: that frame per cell, -1 none)."""
    src = np.full(labels.shape, -1, np.int32)
    for k, (_, r0, c0, m) in enumerate(masks):
        v = place(labels.shape, r0, c0, m)
        sel = (labels == k) & v
        src[sel] = k
    rest = src < 0
    src[rest] = nadir_idx_of_valid[rest]
    return src


# ------------------------------------------------------------------------------------------------ measures

def crossings_by_roof(on_roof: np.ndarray, roof: np.ndarray, dom_valid: np.ndarray, masks: list) -> dict:
    """The DOM's seam cells on roofs, per roof they cross: could one frame have taken the whole roof?

    A roof is a 4-connected part of the truth's roof cells (``roof``), judged by its cells in the DOM (``dom_valid``:
    a roof the block's edge cuts, or the DOM's nodata, is one roof, not its pieces); ``masks``: per frame (image_id,
    row, col, its valid cells) on the DOM grid (``frame_masks``; a true ortho's leave out what the frame does not
    see), read in each crossed roof's box only. A roof whose cells in the DOM some frame covers whole could have been
    given to that frame, a seam round it (``..._one_frame_covers_whole``); a roof no single frame covers whole (cut by
    the frames' edges or their occlusion masks) is split by any choice of frames. The per-pair figure
    (``ground_route_existed``) asks the coarser question of the seam grid: is there a roof-free route through the
    pair's overlap between the ends of the pair's seam, whichever part of it crosses."""
    import cv2

    n, parts, stats, _ = cv2.connectedComponentsWithStats(roof.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    crossed = np.unique(parts[on_roof])
    rows = []
    for k in crossed[crossed > 0].tolist():
        x, y, w, h = (int(v) for v in stats[k, :4])
        box = (slice(y, y + h), slice(x, x + w))
        cells = (parts[box] == k) & dom_valid[box]
        whole = [f for f, (_, r0, c0, m) in enumerate(masks)
                 if np.count_nonzero(cells & ~place((h, w), r0 - y, c0 - x, m)) == 0]
        rr, cc = np.nonzero(cells)
        rows.append({"roof_cells": int(cells.sum()), "seam_cells": int((on_roof[box] & cells).sum()),
                     "frames_covering_it_whole": len(whole),
                     "rows_cols": [int(rr.min()) + y, int(rr.max()) + y, int(cc.min()) + x, int(cc.max()) + x]})
    avoidable = [r for r in rows if r["frames_covering_it_whole"] > 0]
    return {"roofs_crossed": len(rows), "roofs_crossed_that_one_frame_covers_whole": len(avoidable),
            "roof_cells_crossed_on_roofs_one_frame_covers_whole": sum(r["seam_cells"] for r in avoidable),
            "roof_cells_crossed_on_roofs_no_frame_covers_whole": sum(r["seam_cells"] for r in rows
                                                                      if not r["frames_covering_it_whole"]),
            "roofs_crossed_detail": rows}


ROOF_DEPTH_BANDS_M = ((0.0, 1.0), (1.0, 2.0), (2.0, float("inf")))


def roof_nodata_by_depth(roof: np.ndarray, covered: np.ndarray, dom_valid: np.ndarray, res_m: float) -> dict:
    """The truth's roof cells a frame's footprint covers, by their distance (m, cell centres) from the nearest cell
    that is not roof, and the share the DOM leaves nodata (trial s105 F1: a true ortho masked the roofs' outer
    metre, 40 % of it on the tall block, where the frames look down on it)."""
    import cv2

    depth = cv2.distanceTransform(roof.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5) * res_m
    out = {}
    for lo, hi in ROOF_DEPTH_BANDS_M:
        band = roof & covered & (depth > lo) & (depth <= hi)
        n = int(band.sum())
        out[f"{lo:g}-{hi:g}m"] = {"cells": n, "nodata": int((band & ~dom_valid).sum()),
                                  "nodata_share": float((band & ~dom_valid).sum() / max(1, n))}
    return out


def measure_way(project: Path, truth: Truth, grid, surface_kind, ground, roof, vis, foot_nadir, conv_masks) -> dict:
    import cv2
    import rasterio

    from ortho.mosaic import seam_misalignment
    from ortho.seamlines import _seam_ends, neighbour_pairs

    masks, nadir = frame_masks(project, grid)
    with rasterio.open(project / "ortho" / "mosaic.tif") as ds:
        mg = ds.transform
        c0 = int(round((mg.c - grid.x_left_m) / grid.res_m))
        r0 = int(round((grid.y_top_m - mg.f) / grid.res_m))
        dom_valid = place((grid.height, grid.width), r0, c0, ds.read_masks(1) > 0)
        samples = ds.read()
        dom = np.zeros((samples.shape[0], grid.height, grid.width), samples.dtype)
        for b in range(samples.shape[0]):
            dom[b] = place_values((grid.height, grid.width), r0, c0, samples[b])
        del samples
    H, W = grid.height, grid.width
    valid_nadir = nadir_most(masks, nadir, grid)
    labels, seam_grid_labels, seam_t, f = seam_labels_on(project, grid)
    # the source frame of each cell by value (the mosaic's rule is not assumed); the rule's reconstruction (label
    # where its frame has a value, else the nearest nadir) is compared with it
    src, exact = source_by_value(project, grid, masks, dom, dom_valid)
    by_rule = source_frames(labels, masks, valid_nadir)
    agree = {"cells_with_a_value": int(dom_valid.sum()),
             "exact_share": float(exact[dom_valid].mean()),
             "label_or_nearest_nadir_rule_share": float((by_rule == src)[dom_valid].mean())}

    # visibility from the source frame, per ground cell
    vis_src = np.zeros((H, W), np.uint8)
    for k in range(len(masks)):
        sel = src == k
        vis_src[sel] = vis[k][sel]
    g_dom = ground & dom_valid
    ghost_bld = g_dom & np.isin(vis_src, (ROOF, WALL))
    ghost_tree = g_dom & (vis_src == TREE)
    # cells within one cell (8-neighbour) of a ground cell their source frame sees: the edge band of a hidden area
    # (the DSM's roof edge, sampled on its grid and interpolated, places the edge of what a frame sees to within
    # about a cell)
    edge = np.zeros((H, W), bool)
    for k in range(len(masks)):
        d = cv2.distanceTransform((vis[k] != SEES).view(np.uint8), cv2.DIST_L2, 3)
        edge |= (src == k) & (d <= 1.5)
    # distance (m) from the nearest roof cell
    dist_roof = cv2.distanceTransform((~roof).view(np.uint8), cv2.DIST_L2, 5) * grid.res_m
    far = dist_roof > GHOST_MARGIN_M
    ghosts = {"ground_cells_in_dom": int(g_dom.sum()),
              "building": int(ghost_bld.sum()), "building_share_of_ground": float(ghost_bld.sum() / max(1, g_dom.sum())),
              "building_area_m2": float(ghost_bld.sum() * grid.res_m ** 2),
              "building_beyond_1m_of_a_roof": int((ghost_bld & far).sum()),
              "building_beyond_one_cell_of_what_the_frame_sees": int((ghost_bld & ~edge).sum()),
              "tree": int(ghost_tree.sum()), "tree_beyond_1m_of_a_roof": int((ghost_tree & far).sum())}

    # occluded ground: hidden in the nadir-most frame covering the cell (footprints of the conventional orthos)
    code_nadir = np.zeros((H, W), np.uint8)
    seen_any = np.zeros((H, W), bool)
    for k in range(len(conv_masks)):
        sel = foot_nadir == k
        code_nadir[sel] = vis[k][sel]
        seen_any |= vis[k] == SEES
    occl = ground & (foot_nadir >= 0) & (code_nadir >= ROOF)
    seen_other = occl & seen_any
    none = occl & ~seen_any
    filled_ok = seen_other & dom_valid & (vis_src == SEES)
    filled_any = seen_other & dom_valid
    occluded = {"ground_cells": int((ground & (foot_nadir >= 0)).sum()),
                "occluded_in_nadir_most_frame": int(occl.sum()),
                "seen_by_another_frame": int(seen_other.sum()),
                "filled_from_a_frame_that_sees": int(filled_ok.sum()),
                "filled_from_a_frame_that_sees_share": float(filled_ok.sum() / max(1, seen_other.sum())),
                "filled_at_all_share": float(filled_any.sum() / max(1, seen_other.sum())),
                # misses whose source frame sees ground within one cell: the edge band of a hidden area
                "not_from_a_frame_that_sees_in_the_edge_band": int((seen_other & dom_valid & ~filled_ok & edge).sum()),
                "filled_from_a_frame_that_sees_or_in_the_edge_band_share": float(
                    (filled_ok | (seen_other & dom_valid & edge)).sum() / max(1, seen_other.sum())),
                "seen_by_no_frame": int(none.sum()),
                "seen_by_no_frame_left_empty": int((none & ~dom_valid).sum()),
                "seen_by_no_frame_filled_with_what_hides_it": int((none & dom_valid).sum())}

    # seamlines against roofs
    seam = np.zeros((H, W), bool)
    a, b = labels[:, :-1], labels[:, 1:]
    seam[:, :-1] |= (a != b) & (a >= 0) & (b >= 0)
    a, b = labels[:-1, :], labels[1:, :]
    seam[:-1, :] |= (a != b) & (a >= 0) & (b >= 0)
    seam &= dom_valid
    on_roof = seam & roof
    n_parts, parts = cv2.connectedComponents(on_roof.view(np.uint8), connectivity=8)
    seams = {"seam_cells": int(seam.sum()), "seam_length_m": float(seam.sum() * grid.res_m),
             "roof_cells_crossed": int(on_roof.sum()), "roof_length_m": float(on_roof.sum() * grid.res_m),
             "roof_crossings": int(n_parts - 1),
             "roof_share_of_seam": float(on_roof.sum() / max(1, seam.sum())),
             "tree_cells_crossed": int((seam & (surface_kind == 4)).sum())}
    seams.update(crossings_by_roof(on_roof, roof, dom_valid, masks))
    # per pair: did a ground route exist? (on the seam grid: roof-free cells of the pair's overlap)
    sh = seam_grid_labels.shape
    roof_seam = np.zeros(sh, bool)
    sr0 = int(round((seam_t.f - grid.y_top_m) / grid.res_m))
    sc0 = int(round((grid.x_left_m - seam_t.c) / grid.res_m))
    rr, cc = np.nonzero(roof)
    roof_seam[np.clip((rr + sr0) // f, 0, sh[0] - 1), np.clip((cc + sc0) // f, 0, sh[1] - 1)] = True
    valid_seam = []
    for _, r0_, c0_, m in masks:
        v = np.zeros(sh, bool)
        rr, cc = np.nonzero(m)
        v[np.clip((rr + r0_ + sr0) // f, 0, sh[0] - 1), np.clip((cc + c0_ + sc0) // f, 0, sh[1] - 1)] = True
        valid_seam.append(v)
    reach = END_REACH_M / (grid.res_m * f)
    pairs_out = []
    lab = seam_grid_labels
    for i, j in neighbour_pairs(lab):
        bnd = np.zeros(sh, bool)
        for (x, y), (xx, yy) in (((lab[:, :-1], lab[:, 1:]), (slice(None), slice(None, -1))),
                                 ((lab[:, 1:], lab[:, :-1]), (slice(None), slice(1, None))),
                                 ((lab[:-1, :], lab[1:, :]), (slice(None, -1), slice(None))),
                                 ((lab[1:, :], lab[:-1, :]), (slice(1, None), slice(None)))):
            bnd[xx, yy] |= (x == i) & (y == j)
        crossed = int((bnd & roof_seam).sum())
        overlap = valid_seam[i] & valid_seam[j]
        free = overlap & ~roof_seam
        ends = _seam_ends(bnd)
        route = None
        if ends is not None and free.any():
            _, comp = cv2.connectedComponents(free.view(np.uint8), connectivity=8)
            fr = np.argwhere(free)
            got = []
            for e in ends:
                d = np.hypot(fr[:, 0] - e[0], fr[:, 1] - e[1])
                near = fr[d <= max(reach, d.min())]
                got.append(set(comp[near[:, 0], near[:, 1]].tolist()))
            route = bool(got[0] & got[1])
        pairs_out.append({"a": masks[i][0], "b": masks[j][0], "seam_cells": int(bnd.sum()),
                          "roof_seam_cells": crossed, "ground_route_existed": route})
    seams["seam_grid_cell_m"] = float(grid.res_m * f)
    seams["pairs"] = pairs_out
    seams["pairs_crossing_roofs"] = sum(p["roof_seam_cells"] > 0 for p in pairs_out)
    seams["pairs_crossing_roofs_where_a_ground_route_existed"] = sum(
        p["roof_seam_cells"] > 0 and bool(p["ground_route_existed"]) for p in pairs_out)
    seams["roof_seam_cells_where_a_ground_route_existed"] = sum(
        p["roof_seam_cells"] for p in pairs_out if p["ground_route_existed"])
    mis = seam_misalignment(project)
    seams["misalignment"] = {k: getattr(mis, k) for k in ("patch_px", "patches", "rms_px", "max_px")}
    return {"source_frame_by_value": agree, "ghosts": ghosts, "occluded_ground": occluded,
            "roofs_nodata_by_depth": roof_nodata_by_depth(roof, foot_nadir >= 0, dom_valid, grid.res_m),
            "seams": seams}


def truth_on_grid(truth: Truth, project: Path, grid):
    """Surface kind (straight-down ray), ground mask, roof mask, and per frame the visibility code of every ground
    cell in its footprint (the conventional frame orthos), the nadir-most covering frame per cell."""
    from aerotri.sim.scene import KIND_ROOF, KIND_TERRAIN

    H, W = grid.height, grid.width
    # (a row and a column in the project CRS, broadcast as before: no grid of indices)
    X, Y = (np.broadcast_to(a, (H, W)).ravel()
            for a in truth.local_xy(grid, np.arange(H)[:, None], np.arange(W)[None, :]))
    kind, _, _ = truth.surface(X, Y)
    kind = kind.reshape(H, W)
    ground = kind == KIND_TERRAIN
    roof = kind == KIND_ROOF
    masks, nadir = frame_masks(project, grid)
    vis = []
    for image_id, r0, c0, m in masks:
        foot = place((H, W), r0, c0, m) & ground
        idx = np.flatnonzero(foot)
        x, y = X[idx], Y[idx]
        z = truth.scene.terrain_height(x, y)
        code = np.zeros(H * W, np.uint8)
        code[idx] = truth.visibility(image_id, x, y, z)
        vis.append(code.reshape(H, W))
    foot_nadir = nadir_most(masks, nadir, grid)
    return kind, ground, roof, vis, foot_nadir, masks


def run_block(name: str, src: Path, work: Path, tall: bool, reuse: bool = False, remosaic: bool = False) -> dict:
    from eval_true_ortho import roof_displacements

    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    out = {"project": str(src), "ways": {}}
    kw = {"eo_path": src / "truth" / "eo.txt", "camera_path": src / "truth" / "camera.toml"} if tall else {}
    out["orientation"] = "truth/eo.txt, truth/camera.toml" if tall else "at/eo.txt (the chain's adjustment)"
    out["dem_dsm"] = "truth/dem.tif, truth/dsm.tif" if tall else "lidar_out/dem.tif, lidar_out/dsm.tif (the chain's)"
    made = {}
    for way, true_ortho in (("conventional", False), ("true_ortho", True)):
        p = work / name / way
        kept = p / "made.json"
        if reuse and kept.exists():  # --reuse: the DOMs of an earlier run of this script (measures only)
            made[way] = json.loads(kept.read_text())
            continue
        if remosaic and kept.exists():  # --remosaic: the frame orthos of an earlier run, mosaicked again
            made[way] = json.loads(kept.read_text())
            made[way].update(remosaic_dom(p))
            kept.write_text(json.dumps(made[way], indent=1, default=str) + "\n")
            print(name, way, "mosaicked again", flush=True)
            continue
        (copy_tall if tall else copy_demo)(src, p)
        made[way] = make_dom(p, true_ortho, **kw)
        kept.write_text(json.dumps(made[way], indent=1, default=str) + "\n")
        print(name, way, "rectified and mosaicked", flush=True)
    conv = work / name / "conventional"
    grid = OrthoGrid.union(read_index(conv).grids)
    t = time.perf_counter()
    truth = Truth(conv)
    kind, ground, roof, vis, foot_nadir, masks = truth_on_grid(truth, conv, grid)
    out["truth"] = {"dom_cells": int(grid.width * grid.height), "gsd_m": grid.res_m,
                    "ground_cells": int(ground.sum()), "roof_cells": int(roof.sum()),
                    "buildings": len(truth.scene.buildings), "ray_cast_s": round(time.perf_counter() - t, 1)}
    print(name, "truth", out["truth"], flush=True)
    for way in ("conventional", "true_ortho"):
        p = work / name / way
        res = {"rectify": made[way]["rectify"], "mosaic": made[way]["mosaic"],
               "roofs": roof_displacements(p / "ortho" / "mosaic.tif", p / "truth" / "ortho.tif",
                                           p / "truth" / "roof_corners.csv"),
               "cells_seen_by_no_frame_mosaic_json": made[way]["summary"].get("cells_seen_by_no_frame")}
        res.update(measure_way(p, truth, grid, kind, ground, roof, vis, foot_nadir, masks))
        out["ways"][way] = res
        print(name, way, json.dumps({k: v for k, v in res.items() if k != "seams"}, indent=1), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--tall", type=Path, default=REPO / "out" / "tall_sim")
    ap.add_argument("--blocks", default="demo,tall")
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_occlusion")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_occlusion.json")
    ap.add_argument("--reuse", action="store_true", help="measure the DOMs an earlier run left in --work")
    ap.add_argument("--remosaic", action="store_true",
                    help="mosaic the frame orthos an earlier run left in --work again, then measure")
    ap.add_argument("--chain", action="append", default=[], metavar="NAME=DIR",
                    help="a block NAME (for --blocks) that is a project the chain ran (aerotri run: at/eo.txt, "
                         "lidar_out/dem.tif, dsm.tif, ndsm.tif), rectified and measured as the demo; repeatable")
    ap.add_argument("--key", default=None,
                    help="write this run under KEY of --out (its blocks merged), every other key kept; "
                         "default: the top-level blocks")
    args = ap.parse_args()
    if "tall" in args.blocks.split(",") and not (args.tall / "truth" / "truth.json").exists():
        subprocess.run([str(Path(sys.executable).with_name("aerotri")), "sim", str(args.tall), "--preset", "tall"],
                       check=True)
    doc = read_results(args.out)
    out = {"visible_tol_m": VISIBLE_TOL_M, "ghost_margin_m": GHOST_MARGIN_M, "end_reach_m": END_REACH_M,
           "blocks": (doc.get(args.key, {}) if args.key else doc).get("blocks", {})}
    cpu0 = time.process_time()
    chains = dict(c.split("=", 1) for c in args.chain)
    for name in args.blocks.split(","):
        src = Path(chains[name]) if name in chains else args.demo if name == "demo" else args.tall
        out["blocks"][name] = run_block(name, src, args.work, tall=name == "tall", reuse=args.reuse,
                                        remosaic=args.remosaic)
    out["commit"] = git_commit(REPO)
    out["command"] = "python bench/eval_true_ortho_occlusion.py " + " ".join(sys.argv[1:])
    out["cpu_s"], out["load_avg_1min_at_end"] = round(time.process_time() - cpu0, 1), os.getloadavg()[0]
    store_result(args.out, out, key=args.key)  # the other keys (earlier runs) stay as they were


if __name__ == "__main__":
    main()
