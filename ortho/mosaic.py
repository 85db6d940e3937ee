"""Mosaic of the per-frame orthos: seamlines, gain balancing, feathering, tiled Cloud-Optimized GeoTIFF.

Steps (``mosaic_block``):

1. Every frame ortho (``ortho/frames``) is reduced by block averaging to the seam grid (``factor``
   mosaic pixels per cell, chosen so that all reduced frames together stay small).
2. Seamlines on the seam grid (``ortho.seamlines``): nearest-nadir Voronoi, then least-cost seams
   avoiding objects of the nDSM and image differences. Written as ``seamlines.geojson`` (one polygon
   per frame plus the seam lines between neighbours) and the label raster ``seams.tif``.
3. Gain balancing: per band, log-gains g_k minimising sum over overlapping pairs of
   n_ij (log m_i + g_i - log m_j - g_j)^2 + lambda sum g_k^2, with m_i the mean of frame i over the
   common overlap (linear least squares).
4. Blending, tile by tile: frame weights are the label masks blurred across the seam (feather width),
   times the frame's validity; where the chosen frame is invalid (outside it, or occluded in a true
   ortho) the nearest-nadir valid frame fills in. Only the frames touching a tile are read.
5. The tiles go into a tiled GeoTIFF with an internal mask, copied to a COG (deflate, 512 px blocks,
   overviews) - memory is bounded by the tile size, not the mosaic size.

The frames are checked against ``ortho/frames/index.json`` first (sizes and hashes), the tile size
against the memory; seams.tif, seamlines.geojson, mosaic.tif and mosaic.json (which records the index
it was made from) are made in a work folder and moved into ``ortho/`` together at the end.

Step 4 runs as Dask tasks, one per output tile (``blend_tile_task`` on a small ``MosaicTile``: a
context file with frames, gains and nadir points, and the tile window; labels are read from
``seams.tif``), in batches of a few tiles per worker whose results this process writes in tile order.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
from pathlib import Path

import cv2
import numpy as np
import rasterio
import rasterio.shutil
from pyproj import CRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.windows import Window

from aerotri.core.errors import InputError, OptionError
from aerotri.core.log import progress
from aerotri.core.atomic import atomic_path, commit_outputs, move_into, scratch_dir, write_text_atomic
from aerotri.core.limits import check_allocation, check_grid, check_task_count
from aerotri.core.project import Project
from aerotri.core.settings import Resolved, settings_of
from aerotri.core.textio import read_json
from ortho.block import (index_grids, index_operation, operation_tags, read_index, require_current_frames,
                         verify_index)
from ortho.grid import OrthoGrid
from ortho.settings import MosaicSettings
from ortho.seamlines import (keep_objects_whole, label_polygons, least_cost_seams, neighbour_pairs, seam_lines,
                             voronoi_labels)

logger = logging.getLogger(__name__)


def read_window(ds, col_off: int, row_off: int, width: int, height: int):
    """Bands (height, width, bands) float32 and validity (bool) of a window that may extend past the raster (zeros)."""
    img = np.zeros((height, width, ds.count), np.float32)
    valid = np.zeros((height, width), bool)
    c0, r0 = max(0, col_off), max(0, row_off)
    c1, r1 = min(ds.width, col_off + width), min(ds.height, row_off + height)
    if c1 > c0 and r1 > r0:
        w = Window(c0, r0, c1 - c0, r1 - r0)
        try:
            img[r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = np.moveaxis(ds.read(window=w), 0, -1)
            valid[r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = ds.read_masks(1, window=w) > 0
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{ds.name}: cannot read the raster (truncated or corrupt? {exc})") from None
    return img, valid


class ReducedFrames:
    """Frames block-averaged onto the seam grid: rgb (float32, h, w, bands), valid (bool), offsets (row, col)."""

    def __init__(self, names, rgb, valid, offsets, factor, seam_transform, shape):
        self.names, self.rgb, self.valid, self.offsets = names, rgb, valid, offsets
        self.factor, self.transform, self.shape = factor, seam_transform, shape

    def gray(self):
        return [a[:, :, :3].mean(axis=2) for a in self.rgb]


def _reduce(a: np.ndarray, f: int, how: str) -> np.ndarray:
    h, w = a.shape[:2]
    a = a.reshape((h // f, f, w // f, f) + a.shape[2:])
    return a.mean(axis=(1, 3)) if how == "mean" else a.min(axis=(1, 3))


def reduce_frames(frames_dir: Path, index: dict, mosaic: OrthoGrid, factor: int) -> ReducedFrames:
    grids = index_grids(index)
    names, rgbs, valids, offsets = [], [], [], []
    for e in index["frames"]:
        g = grids[e["image_id"]]
        c0, r0 = g.offset_in(mosaic)
        # align the frame's window to whole seam-grid cells
        rc0, cc0 = r0 // factor, c0 // factor
        rc1, cc1 = -(-(r0 + g.height) // factor), -(-(c0 + g.width) // factor)
        with _open_frame(frames_dir / e["file"]) as ds:
            a, m = read_window(ds, cc0 * factor - c0, rc0 * factor - r0, (cc1 - cc0) * factor, (rc1 - rc0) * factor)
        names.append(e["image_id"])
        rgbs.append(_reduce(a, factor, "mean"))
        valids.append(_reduce(m, factor, "min").astype(bool))
        offsets.append((rc0, cc0))
    shape = (-(-mosaic.height // factor), -(-mosaic.width // factor))
    t = Affine(mosaic.res_m * factor, 0, mosaic.x_left_m, 0, -mosaic.res_m * factor, mosaic.y_top_m)
    return ReducedFrames(names, rgbs, valids, offsets, factor, t, shape)


def balance_gains(red: ReducedFrames, labels: np.ndarray | None = None, prior_weight: float = 0.1,
                  min_cells: int = 20) -> np.ndarray:
    """Per-frame, per-band multiplicative gains (n_frames, bands) from the means of the pairwise overlaps."""
    n = len(red.names)
    bands = red.rgb[0].shape[2]
    rows, rhs, wts = [], [], []
    for i in range(n):
        for j in range(i + 1, n):
            (ri, ci), (rj, cj) = red.offsets[i], red.offsets[j]
            r0, c0 = max(ri, rj), max(ci, cj)
            r1 = min(ri + red.valid[i].shape[0], rj + red.valid[j].shape[0])
            c1 = min(ci + red.valid[i].shape[1], cj + red.valid[j].shape[1])
            if r1 <= r0 or c1 <= c0:
                continue
            vi = red.valid[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci]
            vj = red.valid[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
            both = vi & vj
            cnt = int(both.sum())
            if cnt < min_cells:
                continue
            mi = red.rgb[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci][both].mean(axis=0)
            mj = red.rgb[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj][both].mean(axis=0)
            row = np.zeros(n)
            row[i], row[j] = 1.0, -1.0
            rows.append(row)
            rhs.append(np.log(np.maximum(mj, 1.0)) - np.log(np.maximum(mi, 1.0)))
            wts.append(math.sqrt(cnt))
    if not rows:
        return np.ones((n, bands))
    A = np.array(rows) * np.array(wts)[:, None]
    b = np.array(rhs) * np.array(wts)[:, None]
    lam = prior_weight * math.sqrt(float(np.mean(np.array(wts) ** 2)))
    A = np.vstack([A, lam * np.eye(n)])
    b = np.vstack([b, np.zeros((n, bands))])
    g, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.exp(g)


def _read_ndsm_on(path, transform, shape, crs, operation=None):
    """The nDSM (project CRS) on the mosaic grid, by maximum; a mosaic in another CRS than the nDSM's
    is mapped back through the index's coordinate operation (``operation``: mosaic CRS -> nDSM CRS)."""
    from rasterio.warp import reproject

    from aerotri.geom.crs import height_unit_m, parse_crs, same_horizontal
    from aerotri.geom.raster_warp import read_on_grid
    from aerotri.geom.transform import CrsTransformer

    out = np.full(shape, np.nan, np.float32)
    if not Path(path).is_file():
        raise InputError(f"{path}: nDSM not found")
    try:
        with rasterio.open(path) as ds:
            if ds.crs is None:
                raise InputError(f"{path}: the nDSM has no CRS")
            if operation is None and same_horizontal(ds.crs, crs):
                reproject(rasterio.band(ds, 1), out, dst_transform=transform, dst_crs=crs, resampling=Resampling.max,
                          dst_nodata=np.nan)
            else:
                a, ok = read_on_grid(ds, transform.c, transform.f, transform.a, shape,
                                     operation or CrsTransformer(crs, ds.crs), bands=[1], maximum=True)
                out = np.where(ok, a[0], np.nan).astype(np.float32)
            # heights above ground in metres (the thresholds are), whatever unit the nDSM's CRS has
            out *= np.float32(height_unit_m(parse_crs(ds.crs.to_wkt(), f"{path} CRS")))
    except (rasterio.errors.RasterioIOError, rasterio.errors.WarpOperationError) as exc:
        raise InputError(f"{path}: cannot read the nDSM (truncated or corrupt? {exc})") from None
    return out


def _check_ndsm(path, index: dict, mosaic) -> None:
    """The nDSM checked before any work: a height raster (``ortho.dem.open_height_raster``: 2 x 2 cells or more,
    one band of finite heights) in the project CRS the frames were rectified from, over the mosaic."""
    from ortho.dem import open_height_raster, require_overlap

    project = index.get("project_crs")
    with open_height_raster(path, CRS.from_user_input(project) if project else None, "nDSM") as ds:
        require_overlap(ds, path, "nDSM", (mosaic.x_left_m, mosaic.y_top_m - mosaic.height * mosaic.res_m,
                                           mosaic.x_left_m + mosaic.width * mosaic.res_m, mosaic.y_top_m),
                        mosaic.crs, "the mosaic")


def _write_labels(path, labels, transform, crs):
    with atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=labels.shape[1], height=labels.shape[0], count=1,
                           dtype="int32", crs=crs, transform=transform, nodata=-1, compress="deflate") as dst:
            dst.write(labels, 1)


def mosaic_block(root, settings: MosaicSettings | Resolved | None = None, *, object_height_m: float = 2.5,
                 max_seam_cells: float = 5e7, end_reach_m: float = 30.0, executor=None) -> dict:
    """``ortho mosaic``: see the module doc. Returns a summary dict.

    ``settings``: None reads [mosaic] of project.toml; a ``Resolved`` (``ortho mosaic``, the chain) carries the
    source of every setting into mosaic.json (``settings``). The output tiles are blended as tasks on
    ``executor`` (``aerotri.core.executor.Executor``, default: local threads); the COG does not depend on the
    scheduler."""
    root = Path(root)
    resolved = settings_of(settings, MosaicSettings, Project.open(root) if settings is None else None)
    s = resolved.settings
    seams, ndsm_path, feather_m, balance, tile_px = s.seams, s.ndsm, s.feather_m, s.balance, s.tile_px
    if not (isinstance(tile_px, int) and tile_px >= MIN_TILE_PX):
        raise OptionError(f"{tile_px!r}: expected a tile size of at least {MIN_TILE_PX} px", param="--tile-px")
    if feather_m is not None and not (math.isfinite(feather_m) and feather_m >= 0):
        raise OptionError(f"{feather_m!r}: expected a feather width >= 0 m", param="--feather-m")
    index = read_index(root)
    frames_dir = root / "ortho" / "frames"
    if not index["frames"]:
        raise InputError(f"{frames_dir / 'index.json'}: no frames")
    verify_index(frames_dir, index)
    require_current_frames(root, index, f"`ortho mosaic {root}`")
    grids = index_grids(index)
    mosaic = OrthoGrid.union(grids.values())
    res = mosaic.res_m
    check_grid(mosaic.width, mosaic.height, f"the mosaic of {len(grids)} frames at {res:g} m")
    feather_px = max(1.0, feather_m / res) if feather_m is not None else 8.0
    bands, itemsize = _frame_layout(frames_dir / index["frames"][0]["file"])
    check_allocation(_tile_bytes(tile_px, feather_px, bands, itemsize) * _tiles_in_flight(executor),
                     f"--tile-px {tile_px}: mosaic tiles of {tile_px} x {tile_px} px (with their halo, {bands} band(s))",
                     "--tile-px")
    if ndsm_path is not None and not Path(ndsm_path).is_file():
        raise InputError(f"{ndsm_path}: nDSM not found (--ndsm)")
    if ndsm_path is None and (root / "lidar_out" / "ndsm.tif").exists():
        ndsm_path = root / "lidar_out" / "ndsm.tif"
    if ndsm_path is not None:
        _check_ndsm(ndsm_path, index, mosaic)
    total_px = sum(g.width * g.height for g in grids.values())
    factor = max(2, int(math.ceil(math.sqrt(total_px / max_seam_cells))))
    red = reduce_frames(frames_dir, index, mosaic, factor)
    crs = mosaic.crs
    nadir = np.array([e["nadir_xy_m"] for e in index["frames"]])
    nadir_rc = np.stack([(mosaic.y_top_m - nadir[:, 1]) / (res * factor) - 0.5,
                         (nadir[:, 0] - mosaic.x_left_m) / (res * factor) - 0.5], axis=1)
    labels = voronoi_labels(red.valid, red.offsets, nadir_rc, red.shape)
    if ndsm_path is None and (root / "lidar_out" / "ndsm.tif").exists():
        ndsm_path = root / "lidar_out" / "ndsm.tif"
        resolved = resolved.replace("ndsm", ndsm_path, resolved.sources.get("ndsm", "default"), "the LiDAR stages' nDSM")
    objects = None
    if ndsm_path is not None:
        nd = _read_ndsm_on(ndsm_path, red.transform, red.shape, crs, index_operation(index))
        objects = np.nan_to_num(nd, nan=0.0) > object_height_m
    if seams == "least-cost":
        # a seam end may slide along the overlap border by up to end_reach_m to get round a building
        labels = least_cost_seams(labels, red.valid, red.offsets, red.gray(), objects,
                                  end_reach_cells=end_reach_m / (res * factor))
        if objects is not None:
            labels = keep_objects_whole(labels, objects, red.valid, red.offsets)
    gains = balance_gains(red) if balance else np.ones((len(red.names), red.rgb[0].shape[2]))
    for name, g in zip(red.names, gains):
        if np.any(np.abs(np.log(g)) > math.log(1.3)):  # beyond exposure differences between frames of one flight
            logger.warning("frame %s needs gains %s to match its neighbours: check its exposure, or how its image "
                           "file stores the bands", name, ", ".join(f"{v:.2f}" for v in g))
    out_dir = root / "ortho"
    # every output is made in a work folder first and moved into ortho/ only when all of them exist:
    # a failed run leaves the previous seams, seamlines, mosaic and summary together
    with scratch_dir(out_dir, "mosaic") as work:
        outputs = _mosaic_outputs(Path(work), root, index, frames_dir, red, labels, gains, mosaic, factor, nadir,
                                  feather_px, tile_px, seams, executor, resolved.record())
        with commit_outputs(out_dir):  # one commit: all four new, or (a failure, a kill) all as before
            for name in ("seams.tif", "seamlines.geojson", "mosaic.tif", "mosaic.json"):
                move_into(Path(work) / name, out_dir / name)
    return outputs


MIN_TILE_PX = 16


def _frame_layout(path) -> tuple[int, int]:
    with _open_frame(path) as ds:
        return ds.count, np.dtype(ds.dtypes[0]).itemsize


def _tile_bytes(tile_px: int, feather_px: float, bands: int, itemsize: int) -> float:
    """Memory of one blended tile with its halo: per pixel the accumulator, fallback and frame window
    (float32 per band), weights, labels and distances (``_blend_tile``), and the output samples."""
    side = tile_px + 2 * (math.ceil(2.0 * feather_px) + 64)
    return side * side * (3 * 4 * bands + 6 * 4) + tile_px * tile_px * (bands * itemsize + 1)


def _tiles_in_flight(executor) -> int:
    """Tiles held at once: the batch ``_write_mosaic`` hands to the executor."""
    from aerotri.core.executor import local_executor

    return max(2, 2 * (executor or local_executor()).workers)


def _open_frame(path):
    """A frame ortho opened for reading; an unreadable file is an InputError naming it."""
    try:
        return rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: cannot read the frame ortho ({exc}); re-run ortho rectify") from None


def _mosaic_outputs(work: Path, root: Path, index, frames_dir, red, labels, gains, mosaic: OrthoGrid, factor, nadir,
                    feather_px, tile_px, seams, executor, settings_record: dict) -> dict:
    """seams.tif, seamlines.geojson, mosaic.tif and mosaic.json into ``work``; returns the summary."""
    crs, res = mosaic.crs, mosaic.res_m
    out_dir = root / "ortho"
    _write_labels(work / "seams.tif", labels, red.transform, crs)
    features = label_polygons(labels, red.transform, red.names)
    for f in features:
        f["properties"]["kind"] = "frame_region"
    lines = seam_lines(labels, red.transform, red.names)
    for f in lines:
        f["properties"]["kind"] = "seamline"
    geo = {"type": "FeatureCollection", "name": "seamlines", "crs_wkt": crs.to_wkt(),
           "crs": {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{crs.to_epsg()}"}} if crs.to_epsg() else None,
           "features": features + lines}
    write_text_atomic(work / "seamlines.geojson", json.dumps(geo) + "\n")
    _write_mosaic(work / "mosaic.tif", frames_dir, index, mosaic, work / "seams.tif", factor, gains, nadir, feather_px,
                  tile_px, executor=executor)
    summary = {"path": str(out_dir / "mosaic.tif"), "width": mosaic.width, "height": mosaic.height,
               "frames": len(red.names), "res_m": res, "seam_factor": factor, "seams": seams, "feather_px": feather_px,
               "index_sha1": index_sha1(root),
               "gains": {n: [float(v) for v in g] for n, g in zip(red.names, gains)},
               "pairs": [[red.names[i], red.names[j]] for i, j in neighbour_pairs(labels)],
               "settings": settings_record}
    write_text_atomic(work / "mosaic.json", json.dumps(summary, indent=1) + "\n")
    return summary


def index_sha1(root) -> str:
    """sha1 of ``ortho/frames/index.json``: the frames a mosaic (its seams) was made from."""
    import hashlib

    return hashlib.sha1((Path(root) / "ortho" / "frames" / "index.json").read_bytes()).hexdigest()


@dataclasses.dataclass(frozen=True)
class MosaicTile:
    """One output tile of the mosaic as a Dask task: the shared context file and the tile's window."""

    context_path: str
    row0: int
    col0: int
    height: int
    width: int


@functools.lru_cache(maxsize=4)
def _load_context(path: str, mtime_ns: int) -> dict:
    """The mosaic context (frames, grids, gains, seam raster path), parsed once per worker process."""
    ctx = json.loads(Path(path).read_text())
    index = ctx["index"]
    ctx["grids"] = index_grids(index)
    ctx["names"] = [e["image_id"] for e in index["frames"]]
    ctx["files"] = {e["image_id"]: Path(ctx["frames_dir"]) / e["file"] for e in index["frames"]}
    m = ctx["mosaic"]
    ctx["mosaic_grid"] = OrthoGrid(CRS.from_wkt(index["crs"]), m["x_left_m"], m["y_top_m"], m["res_m"], m["width"],
                                   m["height"])
    ctx["offsets"] = [ctx["grids"][n].offset_in(ctx["mosaic_grid"]) for n in ctx["names"]]
    ctx["gains"] = np.asarray(ctx["gains"], float)
    ctx["nadir"] = np.asarray(ctx["nadir"], float)
    return ctx


def _labels_at_full_resolution(read_cells, R0, C0, H, W, factor, shape):
    """Seam labels (nearest) of the mosaic pixels R0..R0+H, C0..C0+W; ``read_cells(row, col, h, w)`` reads
    a window of the seam grid of ``shape`` (cells of ``factor`` mosaic pixels)."""
    lr = np.clip(np.arange(R0, R0 + H) // factor, 0, shape[0] - 1)
    lc = np.clip(np.arange(C0, C0 + W) // factor, 0, shape[1] - 1)
    r_lo, c_lo = int(lr.min()), int(lc.min())
    cells = read_cells(r_lo, c_lo, int(lr.max()) + 1 - r_lo, int(lc.max()) + 1 - c_lo)
    return cells[np.ix_(lr - r_lo, lc - c_lo)]


def blend_tile_task(tile: MosaicTile):
    """Blend one output tile from the frame orthos; returns (pixels (h, w, bands) of the frames' dtype,
    validity bool (h, w)). Reads only the seam labels and frame windows it needs."""
    ctx = _load_context(tile.context_path, Path(tile.context_path).stat().st_mtime_ns)
    halo, factor = ctx["halo"], ctx["factor"]
    with rasterio.open(ctx["seams_path"]) as sds:
        def read_cells(r, c, h, w):
            return sds.read(1, window=Window(c, r, w, h))

        lab = _labels_at_full_resolution(read_cells, tile.row0 - halo, tile.col0 - halo, tile.height + 2 * halo,
                                         tile.width + 2 * halo, factor, (sds.height, sds.width))
    out, valid = _blend_tile(tile.row0, tile.col0, tile.height, tile.width, halo, ctx["names"], ctx["files"],
                             ctx["offsets"], ctx["grids"], ctx["mosaic_grid"], lab, ctx["gains"], ctx["nadir"],
                             ctx["feather_px"], ctx["bands"], ctx["dtype"])
    return out.astype(ctx["dtype"]), valid


def _write_mosaic(path, frames_dir, index, mosaic: OrthoGrid, seams_path, factor, gains, nadir, feather_px, tile_px,
                  executor=None):
    """Blend the output tiles as tasks on ``executor`` (batches of a few tiles per worker, written in
    tile order as they come back: memory is bounded by the batch, not the mosaic) into a tiled
    GeoTIFF, then copy that to the COG. ``seams_path``: the label raster already written (the tasks
    read their windows from it)."""
    from aerotri.core.executor import local_executor

    executor = executor or local_executor()
    names = [e["image_id"] for e in index["frames"]]
    files = {e["image_id"]: frames_dir / e["file"] for e in index["frames"]}
    with rasterio.open(files[names[0]]) as ds:
        bands, dtype = ds.count, ds.dtypes[0]
    halo = int(math.ceil(2.0 * feather_px)) + factor
    profile = dict(driver="GTiff", width=mosaic.width, height=mosaic.height, count=bands, dtype=dtype, crs=mosaic.crs,
                   transform=mosaic.transform, tiled=True, blockxsize=512, blockysize=512, compress="deflate",
                   predictor=2, zlevel=1, interleave="pixel", BIGTIFF="IF_SAFER")
    with scratch_dir(path.parent, "mosaic") as tmp_dir, rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        context = {"index": index, "frames_dir": str(Path(frames_dir).resolve()),
                   "mosaic": {"x_left_m": mosaic.x_left_m, "y_top_m": mosaic.y_top_m, "res_m": mosaic.res_m,
                              "width": mosaic.width, "height": mosaic.height},
                   "seams_path": str(Path(seams_path).resolve()), "factor": int(factor), "halo": halo,
                   "gains": np.asarray(gains, float).tolist(), "nadir": np.asarray(nadir, float).tolist(),
                   "feather_px": float(feather_px), "bands": int(bands), "dtype": dtype}
        context_path = (Path(tmp_dir) / "context.json").resolve()
        context_path.write_text(json.dumps(context))
        check_task_count(math.ceil(mosaic.height / tile_px) * math.ceil(mosaic.width / tile_px),
                         f"mosaic of {mosaic.width} x {mosaic.height} px in tiles of {tile_px} px", "--tile-px",
                         "use a larger --tile-px")
        tiles = [MosaicTile(str(context_path), r0, c0, min(tile_px, mosaic.height - r0), min(tile_px, mosaic.width - c0))
                 for r0 in range(0, mosaic.height, tile_px) for c0 in range(0, mosaic.width, tile_px)]
        batch = max(2, 2 * executor.workers)
        stage = Path(tmp_dir) / "stage.tif"
        with rasterio.open(stage, "w", **profile) as dst, \
                progress(len(tiles), "mosaic", "tiles") as bar:
            for i in range(0, len(tiles), batch):
                results = executor.map(blend_tile_task, tiles[i:i + batch], desc="mosaic tiles", unit="tile")
                for t, (out, valid) in zip(tiles[i:i + batch], results):
                    w = Window(t.col0, t.row0, t.width, t.height)
                    dst.write(np.moveaxis(out, -1, 0), window=w)
                    dst.write_mask(np.where(valid, 255, 0).astype(np.uint8), window=w)
                    bar.update(1)
        with rasterio.open(stage, "r+") as dst:  # the COG copy keeps the tags
            dst.update_tags(**operation_tags(index.get("coordinate_operation"), index.get("height_operation")))
        with atomic_path(path) as tmp:
            rasterio.shutil.copy(stage, tmp, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=512, OVERVIEWS="AUTO",
                                 OVERVIEW_RESAMPLING="AVERAGE", BIGTIFF="IF_SAFER", NUM_THREADS="ALL_CPUS")


def _blend_tile(r0, c0, th, tw, halo, names, files, offsets, grids, mosaic, lab, gains, nadir, feather_px,
                bands, dtype):
    """Blend one tile; ``lab``: seam labels of the tile and ``halo`` pixels around it, at full resolution."""
    acc = np.zeros((th, tw, bands), np.float32)
    wsum = np.zeros((th, tw), np.float32)
    fallback_best = np.full((th, tw), np.inf, np.float32)
    fallback = np.zeros((th, tw, bands), np.float32)
    ys = mosaic.y_top_m - (np.arange(r0, r0 + th) + 0.5) * mosaic.res_m
    xs = mosaic.x_left_m + (np.arange(c0, c0 + tw) + 0.5) * mosaic.res_m
    sigma = max(0.5, feather_px / 2.0)
    for k, name in enumerate(names):
        fc, fr = offsets[k]
        g = grids[name]
        if fr >= r0 + th or fr + g.height <= r0 or fc >= c0 + tw or fc + g.width <= c0:
            continue
        with _open_frame(files[name]) as ds:
            img, m = read_window(ds, c0 - fc, r0 - fr, tw, th)
        if not m.any():
            continue
        img *= gains[k][None, None, :]
        own = (lab == k).astype(np.float32)
        if own.any():
            wk = cv2.GaussianBlur(own, (0, 0), sigma)[halo:halo + th, halo:halo + tw] * m
            acc += img * wk[:, :, None]
            wsum += wk
        # nearest-nadir valid frame: fills pixels where the labelled frame is invalid
        d = np.hypot(xs[None, :] - nadir[k, 0], ys[:, None] - nadir[k, 1]).astype(np.float32)
        better = m & (d < fallback_best)
        fallback_best[better] = d[better]
        fallback[better] = img[better]
    valid = np.isfinite(fallback_best)
    out = np.where((wsum > 1e-3)[:, :, None], acc / np.maximum(wsum, 1e-6)[:, :, None], fallback)
    top = float(np.iinfo(dtype).max) if np.issubdtype(np.dtype(dtype), np.integer) else np.inf
    out = np.clip(np.rint(out) if np.isfinite(top) else out, 0, top)
    out[~valid] = 0
    return out, valid


_SEAM_GROUP_PX = 2048  # mosaic pixels: the patches of a seam are read in windows of about this size


def seam_samples(labels: np.ndarray, spacing_cells: int):
    """For each touching pair (i < j) of ``labels`` (-1: none): the cells of i with a 4-neighbour in j,
    in row-major order, every ``spacing_cells``-th; yields ((i, j), (n, 2) array of (row, col))."""
    h, w = labels.shape
    n_labels = int(labels.max()) + 1
    flat = np.arange(h * w, dtype=np.int64).reshape(h, w)
    keys = []
    for a, b, fa in ((labels[:, :-1], labels[:, 1:], flat[:, :-1]), (labels[:, 1:], labels[:, :-1], flat[:, 1:]),
                     (labels[:-1, :], labels[1:, :], flat[:-1, :]), (labels[1:, :], labels[:-1, :], flat[1:, :])):
        m = (a >= 0) & (b >= 0) & (a < b)
        keys.append((a[m].astype(np.int64) * n_labels + b[m]) * (h * w) + fa[m])
    # sorted by pair, then row-major; a cell next to j on two sides counts once
    keys = np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)
    pair, cell = np.divmod(keys, h * w)
    starts = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]]) if len(pair) else np.zeros(0, int)
    for s, e in zip(starts, np.r_[starts[1:], len(pair)]):
        i, j = divmod(int(pair[s]), n_labels)
        c = cell[s:e][::spacing_cells]
        yield (i, j), np.stack(np.divmod(c, w), axis=1)


def seam_misalignment(root, patch_px: int = 32, search_px: int = 4, spacing_cells: int = 4, min_ncc: float = 0.7,
                      ndsm_path=None, max_ndsm_m: float = 0.5) -> dict:
    """Relative displacement of neighbouring frame orthos across each seam (NCC patches on the seam).

    For every seam (pair of frames sharing a boundary in ``ortho/seams.tif``), patches centred on
    seam cells (every ``spacing_cells``) are cut from frame a and matched in frame b; only patches
    valid in both and, with an nDSM, on the ground. Returns per-seam and overall statistics in pixels.
    """
    from ortho.patches import match_patches

    root = Path(root)
    index = read_index(root)
    frames_dir = root / "ortho" / "frames"
    verify_index(frames_dir, index)
    summary_path = root / "ortho" / "mosaic.json"
    if summary_path.exists():
        made_from = read_json(summary_path, "mosaic summary").get("index_sha1")
        if made_from is not None and made_from != index_sha1(root):
            raise InputError(f"{root / 'ortho' / 'seams.tif'}: the seamlines were made from other frames than "
                             f"{frames_dir / 'index.json'} lists (ortho rectify ran again since); re-run ortho mosaic")
    grids = index_grids(index)
    mosaic = OrthoGrid.union(grids.values())
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        labels = ds.read(1)
        factor = int(round(ds.transform.a / mosaic.res_m))
    names = [e["image_id"] for e in index["frames"]]
    if ndsm_path is None and (root / "lidar_out" / "ndsm.tif").exists():
        ndsm_path = root / "lidar_out" / "ndsm.tif"
    to_project = index_operation(index)
    half = patch_px // 2 + search_px
    size = 2 * half
    per_seam, all_d = [], []
    for (i, j), rc in seam_samples(labels, spacing_cells):
        # mosaic pixel of each patch's upper-left corner
        R = ((rc[:, 0] + 0.5) * factor).astype(int) - half
        C = ((rc[:, 1] + 0.5) * factor).astype(int) - half
        ds_list = []
        with _open_frame(frames_dir / f"{names[i]}.tif") as fa, _open_frame(frames_dir / f"{names[j]}.tif") as fb:
            # the patches of one seam are read by groups under one window (one read per frame and group,
            # not one per patch); the nDSM likewise
            group = (R // _SEAM_GROUP_PX) * (1 << 20) + C // _SEAM_GROUP_PX
            for g in np.unique(group):
                sel = np.flatnonzero(group == g)
                r0, c0 = int(R[sel].min()), int(C[sel].min())
                h, w = int(R[sel].max()) - r0 + size, int(C[sel].max()) - c0 + size
                imgs = []
                for k, ds in ((i, fa), (j, fb)):
                    fc, fr = grids[names[k]].offset_in(mosaic)
                    imgs.append(read_window(ds, c0 - fc, r0 - fr, w, h))
                keep = None
                if ndsm_path is not None:
                    t = Affine(mosaic.res_m, 0, mosaic.x_left_m + c0 * mosaic.res_m, 0, -mosaic.res_m,
                               mosaic.y_top_m - r0 * mosaic.res_m)
                    nd = _read_ndsm_on(ndsm_path, t, (h, w), mosaic.crs, to_project)
                    keep = np.nan_to_num(nd, nan=1e9) <= max_ndsm_m
                for s in sel:
                    win = (slice(R[s] - r0, R[s] - r0 + size), slice(C[s] - c0, C[s] - c0 + size))
                    p = match_patches(imgs[0][0][win], imgs[1][0][win], imgs[0][1][win], imgs[1][1][win],
                                      mosaic.res_m, patch_px, patch_px, search_px, min_ncc,
                                      keep=None if keep is None else keep[win])
                    ds_list.extend(np.hypot(p.dx_px, p.dy_px).tolist())
        d = np.array(ds_list)
        all_d.extend(ds_list)
        per_seam.append({"image_a": names[i], "image_b": names[j], "patches": int(len(d)),
                         "rms_px": float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
                         "max_px": float(d.max()) if len(d) else None})
    d = np.array(all_d)
    return {"patch_px": patch_px, "patches": int(len(d)), "rms_px": float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
            "max_px": float(d.max()) if len(d) else None, "per_seam": per_seam}
