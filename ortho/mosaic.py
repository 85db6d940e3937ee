"""Mosaic of the per-frame orthos: seamlines, gain balancing, feathering, tiled Cloud-Optimized GeoTIFF.

Steps (``mosaic_block``):

1. Every frame ortho (``ortho/frames``) is reduced by block averaging to the seam grid (``factor``
   mosaic pixels per cell, chosen so that all reduced frames together stay small), read by strips of
   rows on all cores (memory set by the strip, not the frame).
2. Seamlines on the seam grid (``ortho.seamlines``): nearest-nadir Voronoi, then least-cost seams
   avoiding objects of the nDSM and image differences. Written as ``seamlines.geojson`` (one polygon
   per frame plus the seam lines between neighbours), ``seamlines.gpkg`` (one polygon per frame with its ``frame``
   name, for editing in QGIS: ``ortho.seamlines_gpkg``) and the label raster ``seams.tif``. With edited seamlines
   (``seamlines=``, ``ortho mosaic --seamlines EDITED.gpkg``) their polygons, checked, are the seams; the automatic
   seams are routed all the same, to say where the edited ones cross buildings and trees that they do not
   (``ortho.seam_crossings``: warnings, mosaic.json ``seam_crossings``, ``seam_crossings.gpkg``).
3. Gain (and offset) balancing: by default per band the log-gains of ``balance_gains`` (the pairs' means matched by
   gains alone); with the setting ``offsets`` a gain g_k = e^x_k and an offset o_k (DN, the frames' own bit depth:
   haze, a black level, which a gain cannot remove) per frame, one least squares over all overlapping pairs
   (``balance_gains_offsets``): their means matched (log(g m_i + o) to first order in o) and, weighted by
   ``SPREAD_WEIGHT``, their standard deviations (which an offset does not change), a weak prior towards g 1 and o 0,
   the block's mean log-gain and mean offset held at 0 (its level); normal equations of 2 n unknowns, n frames, not
   n^2 pairs, in memory. An offset is at most ``OFFSET_MAX_SHARE`` of white either way. A highlight roll-off after
   them, one curve for the block (``HighlightRolloff``: identity up to a knee, then a quadratic to white - 0.5), brings
   every unsaturated sample below the white level, a shadow toe (``ShadowToe``, its mirror) every one a negative
   offset would take below 0.5 above it; only a frame whose brightest unsaturated sample would go beyond what the
   roll-off takes is held, by g_k <= log(1.5 (white - 0.5) / that sample) (``gain_caps``), and the offsets by
   ``offset_bounds`` (bounded least squares; a warning per frame and band held). A saturated sample stays at the white
   level whatever the gain, a black one (0) at black whatever the offset (``hold``).
4. Blending, tile by tile (``_blend_tile``): a tile whose seam cells, with the feather's reach around it,
   all belong to one frame is that frame's window through its gains (a lookup table for 8- and 16-bit
   samples); elsewhere the frame weights are the label masks blurred across the seam (feather width),
   times the frame's validity, and where no frame is labelled (at the edge of the block) the
   nearest-nadir valid frame fills in. Only the frames labelled around a tile are read.
5. The tiles go into a tiled stage GeoTIFF (ZSTD level 1) with an internal mask, one file per row of tiles
   (kept in ``work/mosaic_resume`` as it is closed, a hard link, so that a run after a kill or Ctrl-C takes the
   rows it finished instead of blending them again: ``_row_keys``), and their 2 x 2 averages
   of the valid pixels into the first overview; the coarser overviews are halved from the finer ones by
   strips of rows. A VRT joins the stage's rows and its overviews, and GDAL's COG driver copies it into the COG
   (ZSTD level 1 with the horizontal predictor, 512 px blocks, BigTIFF when it may pass 4 GB, the
   overviews as made here): the full resolution is compressed once for the COG, no overview is made
   from it again, and memory is bounded by the tiles, not by the mosaic. With ``[mosaic] output_bits = 8``
   (``--output-bits 8``) each blended tile is mapped to 8 bits as it is written, by one mapping for the block (the
   frames' white level to 255: ``OutputMapping``), recorded in the DOM's tags and mosaic.json ``output``.

Speed (``bench/mosaic_speed.py``, ``bench/results/mosaic_speed*.json``, ``docs/performance.md``): seams and
blending in compiled or vectorised code (OpenCV; scipy's Dijkstra for the seam paths), the tiles on all
cores while this thread writes, no float64 intermediates; a seam tile weights each frame only over the box
its weight reaches and blends its feather zone in dense windows round the seams (``_mixed_boxes``), and the
frames of a small block (``DECODED_FRAMES_MAX_BYTES``) are decoded once, by the seam grid, and blended from
memory, a true ortho's frame with its validity away from its holes made once, whole (``DecodedFrame``); the pixels no
weight reaches are filled by looking the frames up at them (``_fill_nearest``). A frame of a larger block is read from
its file once per tile (``_TileFrame``: its masks, holes and hole margin over the tile's part of its grid; its samples
only when a weight or a filled pixel needs them), whatever boxes of it the weights and the fill use. The tile order,
the tile results and so the files do not depend on the scheduler or the number of threads.

The frames are checked against ``ortho/frames/index.json`` first (sizes and hashes), the tile size
against the memory; seams.tif, seamlines.geojson, seamlines.gpkg, seamlines_preview.png (the seams over the DOM:
``ortho.seamlines_preview``), mosaic.tif and mosaic.json (which records the index it was made from) are made in a
work folder and moved into ``ortho/`` together at the end.

Step 4 runs on local threads (``executor`` None, local threads, synchronous) or, on a Dask cluster, as
Dask tasks, one per output tile (``blend_tile_task`` on a small ``MosaicTile``: a context file with
frames, gains and nadir points, and the tile window; labels are read from ``seams.tif``), in batches of a
few tiles per worker whose results this process writes in tile order.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import json
import logging
import math
import os
import threading
from pathlib import Path

import cv2
import numpy as np
import rasterio
import rasterio.shutil
from pyproj import CRS
from rasterio.enums import ColorInterp, Resampling
from rasterio.transform import Affine
from rasterio.windows import Window

from aerotri.core.errors import InputError, OptionError
from aerotri.core.gdal_cache import MiB, stage_block_cache
from aerotri.core.log import progress
from aerotri.core.atomic import (TEMP_MARKER, annotate_output, atomic_path, commit_outputs, move_into, remove_output,
                                 scratch_dir, write_text_atomic)
from aerotri.core.limits import (check_allocation, check_grid, check_task_count, format_bytes, memory_room_bytes,
                                 release_freed_memory, usable_cores, usable_memory_bytes)
from aerotri.core.project import Project
from aerotri.core.resume import file_stamp, link_or_copy, resumable, resume_key
from aerotri.core.settings import Resolved, settings_of
from aerotri.core.textio import read_json
from ortho.block import (FrameIndex, frame_index, index_operation, operation_tags, read_index, rectified_on,
                         require_current_frames, uncompressed, verify_index, without_threads_for_extra_samples)
from ortho.grid import OrthoGrid, overview_factors
from ortho.settings import MosaicSettings
from ortho.seamlines_gpkg import require_seamlines_file, write_seamlines_gpkg
from ortho.seam_crossings import FILE as CROSSINGS_FILE, CrossingsSummary
from ortho.seamlines_preview import preview_shape, write_seamlines_preview
from ortho.unseen import unseen_cells, unseen_on_objects, unseen_without_heights
from ortho.seamlines import (footprint, frame_regions, import_path_search, keep_objects_whole, label_polygons,
                             least_cost_seams, neighbour_pairs, seam_lines, voronoi_labels)

logger = logging.getLogger(__name__)
RESUME_DIR_NAME = "mosaic_resume"  # in work/: the rows of tiles a killed or interrupted mosaic finished

# GDAL's block cache during mosaic (``aerotri.core.gdal_cache``): the frame blocks a row of tiles reads (frame
# blocks are not aligned with the mosaic tiles, so the next row reads some again) and the stage blocks being
# filled; GDAL's default is 5 % of the RAM
MOSAIC_CACHE_BYTES = 512 * MiB

STAGE_PROFILE = dict(driver="GTiff", tiled=True, blockxsize=512, blockysize=512, compress="zstd", zstd_level=1,
                     predictor=2, interleave="pixel", BIGTIFF="IF_SAFER", num_threads="ALL_CPUS")
# the COG: ZSTD level 1 with the horizontal predictor was the fastest and the smallest of ZSTD 1/3/6/9 (with
# and without predictor) and DEFLATE on the demo mosaic (bench/results/mosaic_speed.json, "codecs")
COG_OPTIONS = dict(driver="COG", COMPRESS="ZSTD", LEVEL=1, PREDICTOR="YES", BLOCKSIZE=512,
                   OVERVIEWS="FORCE_USE_EXISTING", BIGTIFF="IF_SAFER", NUM_THREADS="ALL_CPUS")
STAGE_RAW_MAX_BYTES = 2 ** 30  # stages up to this size stay uncompressed (no compression to undo for the COG)
_OPEN_FRAMES = 32  # frame datasets kept open per thread (tiles in row order need a few at a time)


def read_window(ds, col_off: int, row_off: int, width: int, height: int):
    """Bands (height, width, bands) float32 and validity (bool) of a window that may extend past the raster (zeros)."""
    img, valid = read_planar(ds, col_off, row_off, width, height)
    return np.moveaxis(img, 0, -1).astype(np.float32), valid


def read_planar(ds, col_off: int, row_off: int, width: int, height: int):
    """Bands (bands, height, width) in the raster's own type and validity (bool) of a window that may
    extend past the raster (zeros, invalid there)."""
    c0, r0 = max(0, col_off), max(0, row_off)
    c1, r1 = min(ds.width, col_off + width), min(ds.height, row_off + height)
    try:
        if c0 == col_off and r0 == row_off and c1 == col_off + width and r1 == row_off + height:
            w = Window(c0, r0, width, height)
            return ds.read(window=w), ds.read_masks(1, window=w) > 0
        img = np.zeros((ds.count, height, width), ds.dtypes[0])
        valid = np.zeros((height, width), bool)
        if c1 > c0 and r1 > r0:
            w = Window(c0, r0, c1 - c0, r1 - r0)
            img[:, r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = ds.read(window=w)
            valid[r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = ds.read_masks(1, window=w) > 0
        return img, valid
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{ds.name}: cannot read the raster (truncated or corrupt? {exc})") from None


def window_of(img: np.ndarray, valid: np.ndarray, col_off: int, row_off: int, width: int, height: int):
    """``read_planar`` of a frame decoded in memory (``img`` (bands, h, w), ``valid`` (h, w)): copies of the window,
    zeros and invalid beyond the frame."""
    h, w = valid.shape
    c0, r0 = max(0, col_off), max(0, row_off)
    c1, r1 = min(w, col_off + width), min(h, row_off + height)
    if c0 == col_off and r0 == row_off and c1 == col_off + width and r1 == row_off + height:
        return img[:, r0:r1, c0:c1].copy(), valid[r0:r1, c0:c1].copy()
    out = np.zeros((img.shape[0], height, width), img.dtype)
    if c1 > c0 and r1 > r0:
        out[:, r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = img[:, r0:r1, c0:c1]
    return out, mask_window(valid, col_off, row_off, width, height)


def mask_window(mask: np.ndarray, col_off: int, row_off: int, width: int, height: int) -> np.ndarray:
    """A copy of the window of ``mask`` (h, w; bool), False beyond it."""
    h, w = mask.shape
    c0, r0 = max(0, col_off), max(0, row_off)
    c1, r1 = min(w, col_off + width), min(h, row_off + height)
    if c0 == col_off and r0 == row_off and c1 == col_off + width and r1 == row_off + height:
        return mask[r0:r1, c0:c1].copy()
    ok = np.zeros((height, width), bool)
    if c1 > c0 and r1 > r0:
        ok[r0 - row_off:r1 - row_off, c0 - col_off:c1 - col_off] = mask[r0:r1, c0:c1]
    return ok


# frames are kept decoded from the seam grid's reading to the blending when all of them (samples and validity)
# take at most this much (a drone or demo block: the blend then decodes no frame again); larger blocks are
# read again by windows, memory set by the tiles
DECODED_FRAMES_MAX_BYTES = 256 * 2 ** 20


def decoded_bytes(index: FrameIndex, bands: int, itemsize: int) -> int:
    """Memory of all frames of ``index`` decoded (samples, and two validity bytes per pixel: the frame's own and,
    for a frame with holes, that away from them)."""
    return sum(int(e.width) * int(e.height) * (bands * itemsize + 2) for e in index.frames)


@dataclasses.dataclass(frozen=True)
class DecodedFrame:
    """A frame ortho decoded whole: ``samples`` (bands, h, w), ``valid`` (h, w) bool and, for a frame with holes,
    ``away`` (h, w) bool: valid and not within the hole margin of a hole (``_hole_margin``), else None."""

    samples: np.ndarray
    valid: np.ndarray
    away: np.ndarray | None = None


def _dilated(mask: np.ndarray, radius_px: int) -> np.ndarray:
    """``mask`` (bool) dilated by a disc of ``radius_px`` (OpenCV's ellipse of 2 r + 1 px; nothing beyond the array)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1,) * 2)
    return cv2.dilate(mask.view(np.uint8), kernel).view(bool)


class ReducedFrames:
    """Frames block-averaged onto the seam grid: rgb (h, w, bands; the frames' sample type, float32 for types
    OpenCV does not resize), valid (bool: every pixel of the cell valid), offsets (row, col)."""

    def __init__(self, names, rgb, valid, offsets, *, factor, seam_transform, shape):
        self.names, self.rgb, self.valid, self.offsets = names, rgb, valid, offsets
        self.factor, self.transform, self.shape = factor, seam_transform, shape
        # per frame: its SampleHistogram made while it was read, its DecodedFrame (kept for the blending), or None
        self.sample_histograms = [None] * len(names)
        self.decoded_frames = [None] * len(names)
        self.white_level = WhiteLevel(None, "type")
        self._gray = {}

    def gray_of(self, k: int) -> np.ndarray:
        """Grey values (float32, mean of the first three bands) of frame ``k`` on the seam grid (kept: every
        seam of the frame asks for them)."""
        if k not in self._gray:
            a = self.rgb[k]
            g = a[:, :, 0].astype(np.float32)
            for b in range(1, min(3, a.shape[2])):
                g += a[:, :, b]
            self._gray[k] = g / np.float32(min(3, a.shape[2]))
        return self._gray[k]

    def gray(self):
        return [self.gray_of(k) for k in range(len(self.rgb))]

    def histograms(self, gains: np.ndarray, offsets: np.ndarray | None = None) -> list:
        """Per frame its ``SampleHistogram`` (None for types without one), what ``gain_caps`` reads for ``gains``
        (frames, bands): a frame kept decoded has it made here, and only when one of its gains is above 1 or one of
        its ``offsets`` (frames, bands; None: none) is not 0 (no cap or bound binds the others: None)."""
        out = list(self.sample_histograms)
        for k, frame in enumerate(self.decoded_frames):
            if frame is not None and out[k] is None and (np.any(np.asarray(gains[k]) > 1.0) or (
                    offsets is not None and np.any(np.asarray(offsets[k]) != 0.0))):
                out[k] = self.sample_histograms[k] = sample_histogram(frame.samples, frame.valid)
        return out


_RESIZABLE = (np.uint8, np.uint16, np.int16, np.float32, np.float64)
_HISTOGRAM_TYPES = (np.dtype(np.uint8), np.dtype(np.uint16))


def _cells_reduce(a: np.ndarray, factor: int, op) -> np.ndarray:
    """``op`` (``np.bitwise_and``, ``np.bitwise_or``) over every ``factor`` x ``factor`` cell of ``a`` (uint8, (h * factor,
    w * factor)) -> (h, w) uint8: rows then columns of each cell combined by slices, exact and in uint8 (a float32
    indicator block-averaged by OpenCV took 4 times as long and faulted in a float32 copy of every strip)."""
    rows = a[0::factor].copy()
    for k in range(1, factor):
        op(rows, a[k::factor], out=rows)
    by_cell = rows.reshape(rows.shape[0], -1, factor)
    out = by_cell[:, :, 0].copy()
    for k in range(1, factor):
        op(out, by_cell[:, :, k], out=out)
    return out


def _reduce_frame(path, g: OrthoGrid, mosaic: OrthoGrid, factor: int, *, strip_px: int = 1024, keep_decoded=False,
                  margin_px: int = 0, footprint=None):
    """One frame on the seam grid: (rgb (h, w, bands), valid (h, w), (row, col) of its first cell, histogram,
    decoded, holes), read by strips of whole cells (memory of the samples set by ``strip_px`` rows, not by the
    frame; the holes need one byte per pixel of the frame, two with ``footprint``: review 45, 255 against 127 MB
    on a 132 MP frame ortho); with ``keep_decoded`` the frame is read whole and
    returned as ``decoded`` (``DecodedFrame``; its validity away from the holes cleared ``margin_px`` round them),
    else that is None. ``holes``: ``FrameHoles`` or None (no invalid pixel enclosed by valid ones, nor inside
    ``footprint``, the frame's ring (x, y) on the ground in the mosaic's CRS, one pixel in). Then the bits its
    file states (``_nbits``, None) and its largest valid sample (None where not read: 8-bit or NBITS frames kept
    decoded), for ``white_level``."""
    c0, r0 = g.offset_in(mosaic)
    # align the frame's window to whole seam-grid cells
    rc0, cc0 = r0 // factor, c0 // factor
    rc1, cc1 = -(-(r0 + g.height) // factor), -(-(c0 + g.width) // factor)
    h, w = rc1 - rc0, cc1 - cc0
    with _open_frame(path) as ds:
        dtype = np.dtype(ds.dtypes[0])
        keep = dtype if dtype.type in _RESIZABLE else np.dtype(np.float32)
        rgb = np.empty((h, w, ds.count), keep)
        valid = np.empty((h, w), bool)
        step = max(1, strip_px // factor)
        # per band, the histogram of the valid samples (8- and 16-bit frames: at most 1024 bins, and the count
        # of samples at the type's maximum): what a gain would saturate
        bits = 8 * dtype.itemsize
        shift = max(0, bits - 10)
        # (a frame kept decoded has it made later, and only where a gain may need it: ``ReducedFrames.histograms``)
        hist = np.zeros((ds.count, (1 << bits) >> shift), np.int64) \
            if dtype in _HISTOGRAM_TYPES and not keep_decoded else None
        top_count = np.zeros(ds.count, np.int64)
        at_levels = np.zeros((ds.count, bits), np.int64)
        max_sample = np.zeros(ds.count, np.int64)
        nbits = _nbits(ds)
        decoded = read_planar(ds, 0, 0, ds.width, ds.height) if keep_decoded else None
        # the invalid pixels (1) of the frame's window on whole seam cells, framed by invalid ones: its holes are
        # found on them at pixel level (``find_holes``)
        invalid = np.ones((h * factor + 2, w * factor + 2), np.uint8)
        for s in range(0, h, step):
            n = min(step, h - s)
            win = (cc0 * factor - c0, (rc0 + s) * factor - r0, w * factor, n * factor)
            img, ok = read_planar(ds, *win) if decoded is None else window_of(*decoded, *win)
            if hist is not None:
                _add_histogram(hist, top_count, img, ok, bits=bits, shift=shift, at_levels=at_levels,
                               max_sample=max_sample)
            for b in range(img.shape[0]):
                band = img[b] if img.dtype == keep else img[b].astype(keep)
                rgb[s:s + n, :, b] = cv2.resize(band, (w, n), interpolation=cv2.INTER_AREA)
            # a cell is valid when all its pixels are (the window is whole cells)
            valid[s:s + n] = _cells_reduce(ok.view(np.uint8), factor, np.bitwise_and).view(bool)
            np.logical_not(ok, out=invalid[1 + s * factor:1 + (s + n) * factor, 1:-1].view(bool))
    holes = find_holes(invalid, factor, (rc0, cc0),
                       inside=_inside_footprint(footprint, invalid.shape, mosaic, rc0 * factor - 1, cc0 * factor - 1))
    if decoded is not None:
        away = None
        if holes is not None and margin_px:
            # the frame's validity away from its holes, once for the whole frame (``_hole_margin`` of a window of it
            # is a window of this: a dilation reaches margin_px, the window's halo)
            dy, dx = r0 - rc0 * factor, c0 - cc0 * factor
            hole = invalid[1 + dy:1 + dy + g.height, 1 + dx:1 + dx + g.width] == 1
            away = decoded[1] & ~_dilated(hole, margin_px)
        decoded = DecodedFrame(decoded[0], decoded[1], away)
        if dtype == np.uint16 and nbits is None:  # the white level's default reads the largest sample
            max_sample = _max_samples(decoded.samples, decoded.valid)
    hist = None if hist is None else SampleHistogram(hist, top_count, bits, at_levels, max_sample)
    known = hist is not None or (decoded is not None and dtype == np.uint16 and nbits is None)
    return rgb, valid, (rc0, cc0), hist, decoded, holes, nbits, int(max_sample.max()) if known else None


def _nbits(ds) -> int | None:
    """The bits of a raster's samples its file states (GDAL's IMAGE_STRUCTURE NBITS: a TIFF's BitsPerSample
    below its type's, e.g. 12 for 12-bit data in uint16), else None."""
    v = ds.tags(1, ns="IMAGE_STRUCTURE").get("NBITS")
    try:
        n = int(v) if v is not None else None
    except ValueError:
        return None
    return n if n is not None and 1 <= n < 8 * np.dtype(ds.dtypes[0]).itemsize else None


def _max_samples(img: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The largest valid sample per band of ``img`` (bands, h, w) (0 without any)."""
    mask = np.ascontiguousarray(ok).view(np.uint8)
    if not mask.any():
        return np.zeros(img.shape[0], np.int64)
    return np.array([int(cv2.minMaxLoc(np.ascontiguousarray(img[b]), mask)[1]) for b in range(img.shape[0])],
                    np.int64)


def sample_histogram(img: np.ndarray, ok: np.ndarray) -> SampleHistogram | None:
    """``SampleHistogram`` of the valid samples of ``img`` (bands, h, w); None for types without one."""
    dtype = img.dtype
    if dtype not in _HISTOGRAM_TYPES:
        return None
    bits = 8 * dtype.itemsize
    shift = max(0, bits - 10)
    hist = np.zeros((img.shape[0], (1 << bits) >> shift), np.int64)
    top_count = np.zeros(img.shape[0], np.int64)
    at_levels = np.zeros((img.shape[0], bits), np.int64)
    max_sample = np.zeros(img.shape[0], np.int64)
    _add_histogram(hist, top_count, img, ok, bits=bits, shift=shift, at_levels=at_levels, max_sample=max_sample)
    return SampleHistogram(hist, top_count, bits, at_levels, max_sample)


def _add_histogram(hist: np.ndarray, top_count: np.ndarray, img: np.ndarray, ok: np.ndarray, *, bits: int,
                   shift: int, at_levels: np.ndarray, max_sample: np.ndarray) -> None:
    """Add the valid samples of ``img`` (bands, h, w; 8- or 16-bit) to ``hist`` (bands, bins: value >> shift),
    those at the type's maximum to ``top_count`` (bands,), those at every white level 2^n - 1 (n = 1 .. bits) to
    ``at_levels`` (bands, bits), and raise ``max_sample`` (bands,) to the largest. OpenCV's masked histogram (one
    pass, no gathered copy; its float32 counts are exact below 2^24 samples, more go through numpy)."""
    top = (1 << bits) - 1
    levels = (1 << np.arange(1, bits + 1)) - 1
    if ok.size >= 1 << 24:
        for b in range(img.shape[0]):
            v = img[b][ok]
            counts = np.bincount(v, minlength=top + 1)
            hist[b] += counts.reshape(hist.shape[1], -1).sum(axis=1) if shift else counts
            top_count[b] += counts[top]
            at_levels[b] += counts[levels]
            nz = np.flatnonzero(counts)
            max_sample[b] = max(max_sample[b], nz[-1] if nz.size else 0)
        return
    mask = np.ascontiguousarray(ok).view(np.uint8)
    for b in range(img.shape[0]):
        h = cv2.calcHist([np.ascontiguousarray(img[b])], [0], mask, [top + 1], [0, top + 1]).ravel()
        counts = h.astype(np.int64)
        hist[b] += counts.reshape(hist.shape[1], -1).sum(axis=1) if shift else counts
        top_count[b] += counts[top]
        at_levels[b] += counts[levels]
        nz = np.flatnonzero(counts)
        max_sample[b] = max(max_sample[b], nz[-1] if nz.size else 0)


def reduce_frames(frames_dir: Path, index: FrameIndex, mosaic: OrthoGrid, factor: int,
                  threads: int | None = None, keep_decoded: bool = False) -> ReducedFrames:
    """Every frame of ``index`` on the seam grid of ``factor`` mosaic pixels per cell (frames on ``threads``
    threads, default all cores; GDAL's decoding and OpenCV's averaging release the GIL). With ``keep_decoded``
    the frames read whole are kept in ``decoded`` (frame file path -> ``DecodedFrame``) for the blending."""
    from ortho.rectify import ordered_thread_map

    entries = list(zip(index.frames, index.grids))

    margin = hole_margin_px(mosaic.res_m)

    def one(entry):
        e, grid = entry
        # a true ortho's occlusion inside the frame's footprint is a hole even where it reaches the frame's edge; a
        # conventional ortho's few empty pixels along its image's edge inside the ring are not (its blending as before)
        return _reduce_frame(frames_dir / e.file, grid, mosaic, factor, keep_decoded=keep_decoded, margin_px=margin,
                             footprint=e.footprint_xy_m if index.true_ortho else None)

    names, rgbs, valids, offsets, hists, decoded, holes, frames, nbits, maxima = [], [], [], [], [], {}, [], [], [], []
    with progress(len(entries), "seam grid", "frames") as bar:
        with contextlib.closing(ordered_thread_map(one, entries, threads or usable_cores())) as made:
            for (e, _), (rgb, valid, off, hist, frame, hole, n, top) in zip(entries, made):
                names.append(e.image_id)
                nbits.append(n)
                maxima.append(top)
                holes.append(hole)
                rgbs.append(rgb)
                valids.append(valid)
                offsets.append(off)
                hists.append(hist)
                frames.append(frame)
                if frame is not None:
                    decoded[str(Path(frames_dir) / e.file)] = frame
                bar.update(1)
    shape = (-(-mosaic.height // factor), -(-mosaic.width // factor))
    t = Affine(mosaic.res_m * factor, 0, mosaic.x_left_m, 0, -mosaic.res_m * factor, mosaic.y_top_m)
    red = ReducedFrames(names, rgbs, valids, offsets, factor=factor, seam_transform=t, shape=shape)
    red.sample_histograms = hists
    red.decoded_frames = frames
    red.decoded = decoded
    red.holes = holes
    red.white_level = white_level(rgbs[0].dtype if rgbs else None, nbits, maxima)
    return red


@dataclasses.dataclass(frozen=True)
class SampleHistogram:
    """A frame's valid samples per band: ``counts`` (bands, bins) of value >> (bits - log2 bins), ``top`` (bands,)
    the samples at the type's maximum, ``bits`` the type's."""

    counts: np.ndarray
    top: np.ndarray
    bits: int
    # (bands, bits): the samples at 2^n - 1 for n = 1 .. bits (every white level), and (bands,) the largest sample
    at_levels: np.ndarray | None = None
    max_sample: np.ndarray | None = None

    def saturated(self, band: int, white: int) -> int:
        """The samples of ``band`` at or above ``white`` (the type's maximum, or 2^n - 1 with n >= the bin's bits)."""
        top = (1 << self.bits) - 1
        if white >= top or self.at_levels is None:
            return int(self.top[band])
        n = int(white).bit_length()
        # every sample above 2^n - 1 is in a bin after its own (bins of 2^(bits - log2 bins) <= 2^n values)
        first = (white + 1) // ((1 << self.bits) // self.counts.shape[1])
        return int(self.at_levels[band, n - 1] + self.counts[band, first:].sum())


@dataclasses.dataclass(frozen=True)
class WhiteLevel:
    """The frames' white level: the sample value a saturated sample has (``value``; None for types without one, floats)
    and how it was found (``source``): "NBITS" (the frames' files state their bits), "max sample" (uint16 frames
    without NBITS: the smallest 2^n - 1, n in 10..16, at or above every frame's largest valid sample) or "type"
    (the type's maximum: 8-bit frames)."""

    value: int | None
    source: str
    max_sample: int | None = None

    @property
    def bits(self) -> int | None:
        return None if self.value is None else int(self.value).bit_length()


def white_level(dtype, nbits, max_samples) -> WhiteLevel:
    """The ``WhiteLevel`` of frames of ``dtype`` from each frame's NBITS (None: not stated) and largest valid sample
    (None: not known). 12-bit data in 16-bit frames (the DMC's) saturate at 4095, not 65535: a gain limit or a
    saturated share counted at the type's maximum would see nothing saturated."""
    if dtype is None or np.dtype(dtype) not in _HISTOGRAM_TYPES:
        return WhiteLevel(None, "type")
    top = int(np.iinfo(dtype).max)
    stated = [n for n in nbits if n is not None]
    known = [m for m in max_samples if m is not None]
    biggest = max(known) if known else None
    if stated:
        return WhiteLevel((1 << max(stated)) - 1, "NBITS", biggest)
    if np.dtype(dtype) == np.uint16 and biggest is not None:
        n = min(16, max(10, int(biggest).bit_length()))
        if n < 16:
            logger.info("%d-bit data in 16-bit frames (max sample %d, no NBITS tag): saturation counted at %d", n,
                        biggest, (1 << n) - 1)
        return WhiteLevel((1 << n) - 1, "max sample", biggest)
    return WhiteLevel(top, "type", biggest)


def largest_unsaturated(hist: SampleHistogram, band: int, white: int) -> int | None:
    """The largest valid sample of ``band`` below ``white`` (at most: the top of its histogram bin; the white
    level's own bin, 64 values wide for 16-bit frames, counts as ``white`` - 1 when it holds an unsaturated sample);
    None when every sample is saturated or there is none."""
    width = (1 << hist.bits) // hist.counts.shape[1]  # sample values per bin
    counts = hist.counts[band]
    jw = min(int(white) // width, counts.shape[0] - 1)  # the white level's bin
    # the samples of that bin below the white level: the bin less those at or above it that are in it
    below = int(counts[jw]) - (hist.saturated(band, int(white)) - int(counts[jw + 1:].sum()))
    if below > 0:
        return int(white) - 1 if width > 1 else min(jw, int(white) - 1)
    nz = np.flatnonzero(counts[:jw])
    return None if nz.size == 0 else min(int((nz[-1] + 1) * width - 1), int(white) - 1)


def smallest_unsaturated(hist: SampleHistogram, band: int, white: int) -> int | None:
    """The smallest valid sample of ``band`` above black (0) and below ``white`` (at least: the bottom of its histogram
    bin, and 1; 16-bit bins are 64 values wide, so a frame with samples in the first bin counts as reaching 1); None
    when there is none."""
    width = (1 << hist.bits) // hist.counts.shape[1]
    counts = hist.counts[band]
    jw = min(int(white) // width, counts.shape[0] - 1)
    if width == 1:
        nz = np.flatnonzero(counts[1:jw])
        return None if nz.size == 0 else int(nz[0]) + 1
    nz = np.flatnonzero(counts[:jw + 1])
    return None if nz.size == 0 else max(1, int(nz[0]) * width)


def sample_extremes(histograms, bands: int, white: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(frames, bands) the smallest and the largest unsaturated sample of every frame (``smallest_unsaturated``,
    ``largest_unsaturated``; nan for frames without a histogram or such a sample)."""
    lo = np.full((len(histograms), bands), np.nan)
    hi = np.full((len(histograms), bands), np.nan)
    for k, hist in enumerate(histograms):
        if hist is None:
            continue
        top = (1 << hist.bits) - 1 if white is None else min(int(white), (1 << hist.bits) - 1)
        for b in range(hist.counts.shape[0]):
            m, n = smallest_unsaturated(hist, b, top), largest_unsaturated(hist, b, top)
            lo[k, b] = np.nan if m is None else m
            hi[k, b] = np.nan if n is None or n <= 0 else n
    return lo, hi


def gain_caps(histograms, bands: int, white: int | None = None, headroom: float = 1.0) -> np.ndarray:
    """(frames, bands) the largest gain under which no unsaturated sample of the frame goes beyond ``headroom`` x
    (white - 0.5) (``white``: default the type's maximum): ``headroom`` x (white - 0.5) / its largest unsaturated
    sample (a hair below, for float32 products); with ``headroom`` 1 it rounds to at most white - 1, with
    ``ROLLOFF_HEADROOM`` the highlight roll-off (``HighlightRolloff``) brings it there. inf for frames without a
    histogram (other types, or a frame kept decoded whose gains are all <= 1, which no cap binds: every cap is above
    1)."""
    caps = np.full((len(histograms), bands), np.inf)
    for k, hist in enumerate(histograms):
        if hist is None:
            continue
        top = (1 << hist.bits) - 1 if white is None else min(int(white), (1 << hist.bits) - 1)
        for b in range(hist.counts.shape[0]):
            m = largest_unsaturated(hist, b, top)
            if m is not None and m > 0:
                caps[k, b] = headroom * (top - 0.5) / m * (1.0 - 1e-6)
    return caps


def limit_gains(gains: np.ndarray, histograms, white: int | None = None, headroom: float = 1.0):
    """Gains (n_frames, bands) lowered to ``gain_caps`` (of ``headroom``): no unsaturated sample of a frame goes beyond
    ``headroom`` x (white - 0.5) (``white``: default the type's maximum; ``WhiteLevel``), from the frame's
    ``SampleHistogram`` (None for types without one). Returns (gains, [(frame index, band, gain before, after,
    saturated share of the frame, share the gain before would have saturated without a roll-off)])."""
    out = np.array(gains, float)
    caps = gain_caps(histograms, out.shape[1] if out.ndim == 2 else 0, white, headroom)
    limited = []
    for k, b in zip(*np.nonzero(out > caps)):
        hist = histograms[k]
        limited.append((int(k), int(b), float(out[k, b]), float(caps[k, b]),
                        *_saturated_shares(hist, int(b), float(out[k, b]), white)))
        out[k, b] = caps[k, b]
    return out, limited


# the highlight roll-off's knee is never below this share of the white level (the midtones are never touched): gains
# may take a frame's brightest unsaturated sample up to (2 - this) x white, the roll-off brings it below white; a
# frame that would need more is held there (``gain_caps``). Chosen a priori (a DOM's midtones lie below half of white),
# not on the benches' blocks
ROLLOFF_KNEE_MIN = 0.5
ROLLOFF_HEADROOM = 2.0 - ROLLOFF_KNEE_MIN


@dataclasses.dataclass(frozen=True)
class HighlightRolloff:
    """A soft knee near white after the gains, one curve for every frame and band (an overlap's two frames go through
    the same curve, which is 1-Lipschitz: it never widens their differences; a grey stays grey): a gained value
    v <= ``knee`` is unchanged, one above it becomes knee + d - d^2 / (2 D), d = v - knee clipped to D =
    ``top_in`` - knee (slope 1 at the knee, 0 at ``top_in``, monotone), so that ``top_in`` (the block's largest
    unsaturated sample through its gain) becomes knee + D / 2 = ``top_out`` (white - 0.5, a hair below: it rounds
    below white). ``highlight_rolloff`` sets knee = 2 top_out - top_in, the highest knee of such a curve."""

    knee: float
    top_in: float
    top_out: float

    def apply(self, v: np.ndarray) -> np.ndarray:
        """float32 gained values ``v`` through the roll-off, in place (returned)."""
        high = v > np.float32(self.knee)
        if high.any():
            k, span = np.float32(self.knee), np.float32(self.top_in - self.knee)
            d = np.minimum(v[high] - k, span)
            v[high] = np.minimum(k + d - d * d / (np.float32(2) * span), np.float32(self.top_out))
        return v

    def record(self) -> dict:
        return {"knee": self.knee, "top_in": self.top_in, "top_out": self.top_out}


def highlight_rolloff(gains: np.ndarray, histograms, white: int | None,
                      offsets: np.ndarray | None = None) -> HighlightRolloff | None:
    """The ``HighlightRolloff`` that brings every unsaturated sample of every frame through its gain (``gains``
    (frames, bands)) and offset (``offsets``, DN; None: none) below ``white``: None when none reaches white - 0.5 (or
    there is no white level)."""
    if white is None:
        return None
    gains = np.asarray(gains, float)
    if offsets is not None and np.any(np.asarray(offsets) != 0.0):
        _, hi = sample_extremes(histograms, gains.shape[1], white)
        top_out = (int(white) - 0.5) * (1.0 - 1e-6)
        through = gains * hi + np.asarray(offsets, float)
        top_in = float(np.nanmax(through)) if np.isfinite(through).any() else 0.0
        if top_in <= top_out:
            return None
        top_in = min(top_in, ROLLOFF_HEADROOM * top_out)  # (the bounds on gains and offsets hold them there)
        return HighlightRolloff(2.0 * top_out - top_in, top_in, top_out)
    caps = gain_caps(histograms, gains.shape[1], white)  # (white - 0.5) / the largest unsaturated sample
    top_out = (int(white) - 0.5) * (1.0 - 1e-6)
    ratio = float(np.max(gains / caps)) if gains.size else 0.0
    if ratio <= 1.0:
        return None
    top_in = min(ratio, ROLLOFF_HEADROOM) * top_out  # (the caps hold the gains there)
    return HighlightRolloff(2.0 * top_out - top_in, top_in, top_out)


# the shadow toe's knee is never above this share of the white level: an offset may take a frame's darkest unsaturated
# sample down to 2 x 0.5 - this x white, the toe brings it above 0.5 (it rounds to 1, not to black); a frame that would
# need more is held there (``offset_bounds``). Chosen a priori (haze and black-level differences are a few % of white;
# the midtones and three quarters of the range are never touched), not on the benches' blocks
TOE_KNEE_MAX = 0.25
# an offset is at most this share of the white level either way: haze and black-level differences are a few % of it;
# the larger offsets an affine fit asks between frames whose tones differ otherwise (a tone curve through another
# exposure) would move the block's shadows and level (``docs/true-ortho.md``, bench/results/mosaic_offsets.json)
OFFSET_MAX_SHARE = 0.05
TOE_BOTTOM_OUT = 0.5 + 1.0 / 64  # a hair above 0.5: rounds to 1 (float32 keeps it above 0.5)


@dataclasses.dataclass(frozen=True)
class ShadowToe:
    """A soft toe near black after the gains and offsets, the mirror of ``HighlightRolloff``, one curve for every frame
    and band (1-Lipschitz, monotone): a value v >= ``knee`` is unchanged, one below it becomes knee - d + d^2 / (2 D),
    d = knee - v clipped to D = knee - ``bottom_in``, so that ``bottom_in`` (the block's smallest unsaturated sample
    through its gain and offset, below 0.5) becomes knee - D / 2 = ``bottom_out`` (a hair above 0.5: it rounds to 1,
    not to black); knee = 2 bottom_out - bottom_in."""

    knee: float
    bottom_in: float
    bottom_out: float

    def apply(self, v: np.ndarray) -> np.ndarray:
        """float32 values ``v`` (gained and offset) through the toe, in place (returned)."""
        low = v < np.float32(self.knee)
        if low.any():
            k, span = np.float32(self.knee), np.float32(self.knee - self.bottom_in)
            d = np.minimum(k - v[low], span)
            v[low] = np.maximum(k - d + d * d / (np.float32(2) * span), np.float32(self.bottom_out))
        return v

    def record(self) -> dict:
        return {"knee": self.knee, "bottom_in": self.bottom_in, "bottom_out": self.bottom_out}


def shadow_toe(gains: np.ndarray, offsets: np.ndarray | None, histograms, white: int | None) -> ShadowToe | None:
    """The ``ShadowToe`` that keeps every unsaturated sample (above black, below white) of every frame through its gain
    and offset above 0.5: None when no offset takes one below (or there is no white level)."""
    if white is None or offsets is None or not np.any(np.asarray(offsets) < 0.0):
        return None
    gains = np.asarray(gains, float)
    lo, _ = sample_extremes(histograms, gains.shape[1], white)
    through = gains * lo + np.asarray(offsets, float)
    if not np.isfinite(through).any():
        return None
    bottom_in = float(np.nanmin(through))
    if bottom_in >= TOE_BOTTOM_OUT:
        return None
    bottom_in = max(bottom_in, 2.0 * TOE_BOTTOM_OUT - TOE_KNEE_MAX * int(white))  # (``offset_bounds`` hold it there)
    return ShadowToe(2.0 * TOE_BOTTOM_OUT - bottom_in, bottom_in, TOE_BOTTOM_OUT)


def offset_bounds(gains: np.ndarray, histograms, white: int | None,
                  max_share: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(frames, bands) the least and the largest offset (DN) a frame may take after its gains (``gains``): at most
    ``max_share`` (default ``OFFSET_MAX_SHARE``) x white either way, its darkest unsaturated sample no lower than the
    toe brings above 0.5 (``TOE_KNEE_MAX``), its brightest no higher than the highlight roll-off brings below white
    (``ROLLOFF_HEADROOM``); without a white level (float frames) -inf / inf."""
    gains = np.asarray(gains, float)
    lower, upper = np.full(gains.shape, -np.inf), np.full(gains.shape, np.inf)
    if white is None:
        return lower, upper
    share = OFFSET_MAX_SHARE if max_share is None else max_share
    lower, upper = np.full(gains.shape, -share * int(white)), np.full(gains.shape, share * int(white))
    lo, hi = sample_extremes(histograms, gains.shape[1], white)
    top_out = (int(white) - 0.5) * (1.0 - 1e-6)
    # a hair inside, as ``gain_caps``: float32 products
    up = ROLLOFF_HEADROOM * top_out - gains * hi - 1e-6 * white
    down = 2.0 * TOE_BOTTOM_OUT - TOE_KNEE_MAX * int(white) - gains * lo + 1e-6 * white
    upper = np.where(np.isfinite(up), np.minimum(up, upper), upper)
    lower = np.minimum(np.where(np.isfinite(down), np.maximum(down, lower), lower), upper - 1e-6 * white)
    return lower, upper


def _saturated_shares(hist: SampleHistogram, b: int, gain: float, white: int | None) -> tuple[float, float]:
    """The share of band ``b``'s samples saturated in the frame, and the share at white under ``gain``."""
    top = (1 << hist.bits) - 1 if white is None else min(int(white), (1 << hist.bits) - 1)
    width = (1 << hist.bits) // hist.counts.shape[1]
    total = hist.counts[b].sum()
    if total == 0:
        return 0.0, 0.0
    above = (np.cumsum(hist.counts[b][::-1])[::-1] / total)[:max(1, (top + 1) // width)]
    own = hist.saturated(b, top) / total
    would = float(above[min(len(above) - 1, int(np.ceil((top - 0.5) / gain)) // width)])
    return float(own), max(would, float(own))


def _masked_mean_std(a: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation per band of ``a`` (h, w, bands) where ``mask``: the overlaps' means of the gains and
    their spreads of the offsets (``overlap_pairs``). OpenCV's ``meanStdDev``, whose mean is ``cv2.mean``'s to the bit
    (4,500 random bands of every type OpenCV resizes): the gains are those of before the two were one function."""
    m = np.ascontiguousarray(mask).view(np.uint8)
    if a.dtype.type in _RESIZABLE:  # OpenCV's masked mean and deviation: one pass, no gathered copy
        ms = [cv2.meanStdDev(np.ascontiguousarray(a[:, :, b]), mask=m) for b in range(a.shape[2])]
        return np.array([float(x[0][0, 0]) for x in ms]), np.array([float(x[1][0, 0]) for x in ms])
    v = a[mask].astype(np.float64)  # (``reduce_frames`` keeps only types OpenCV resizes: a direct caller's)
    return v.mean(axis=0), v.std(axis=0)


@dataclasses.dataclass(frozen=True)
class OverlapPairs:
    """The frames' pairwise overlaps on the seam grid: ``pairs`` (p, 2) frame indices i < j, ``cells`` (p,) their common
    valid cells, ``mean`` (p, 2, bands) each frame's mean over them and ``std`` (p, 2, bands) its standard deviation
    (None unless asked for), in the frames' DN."""

    pairs: np.ndarray
    cells: np.ndarray
    mean: np.ndarray
    std: np.ndarray | None

    @property
    def row_weights2(self) -> np.ndarray:
        """(p,) the squared weights of the gains' rows, sqrt(cells)^2 as before i42-offsets (cells itself differs
        from it in the last digits, and so did the gains): the default gains, and mosaic, unchanged."""
        return np.sqrt(self.cells.astype(float)) ** 2

    def normal_matrix(self, n: int, prior_weight: float) -> np.ndarray:
        """Normal matrix of rows sqrt(cells) (x_i - x_j) and the prior rows lam x_k (lam = ``prior_weight`` x the rows'
        RMS weight) over ``n`` frames: the overlaps' Laplacian + lam^2 I (whose solution of any right-hand side from
        the rows sums to 0: the prior keeps the block's mean)."""
        w2 = self.row_weights2
        lam = prior_weight * math.sqrt(float(np.mean(w2)))
        N = lam * lam * np.eye(n)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        np.add.at(N, (i, i), w2)
        np.add.at(N, (j, j), w2)
        np.add.at(N, (i, j), -w2)
        np.add.at(N, (j, i), -w2)
        return N

    def right_hand_side(self, n: int, rhs: np.ndarray) -> np.ndarray:
        """(n, bands) the normal equations' right-hand side of the rows sqrt(cells) (x_i - x_j) = sqrt(cells) ``rhs``
        (p, bands)."""
        w2 = self.row_weights2
        u = np.zeros((n, rhs.shape[1]))
        np.add.at(u, self.pairs[:, 0], w2[:, None] * rhs)
        np.add.at(u, self.pairs[:, 1], -w2[:, None] * rhs)
        return u


def overlap_pairs(red: ReducedFrames, min_cells: int = 20, spread: bool = False,
                  white: float | None = None) -> OverlapPairs | None:
    """``OverlapPairs`` of the frames of ``red`` with at least ``min_cells`` common valid cells (None: no pair);
    ``spread``: with their standard deviations; ``white`` (None: every cell): without the cells either frame has at
    ``white`` or at black (0) in any band (a clipped sample's frame shows neither its gain nor its offset there)."""
    n = len(red.names)
    bands = red.rgb[0].shape[2]
    off = np.array(red.offsets, np.int64).reshape(n, 2)
    size = np.array([v.shape for v in red.valid], np.int64).reshape(n, 2)
    # candidate pairs by their boxes on the seam grid (no n^2 loop in Python for large blocks)
    lo, hi = off, off + size
    cand = np.argwhere(np.triu(np.all((np.maximum(lo[:, None], lo[None]) < np.minimum(hi[:, None], hi[None])), -1), 1))
    pairs, cells, means, stds = [], [], [], []
    for i, j in cand:
        (ri, ci), (rj, cj) = red.offsets[i], red.offsets[j]
        r0, c0 = max(ri, rj), max(ci, cj)
        r1 = min(ri + red.valid[i].shape[0], rj + red.valid[j].shape[0])
        c1 = min(ci + red.valid[i].shape[1], cj + red.valid[j].shape[1])
        vi = red.valid[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci]
        vj = red.valid[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
        both = vi & vj
        ai, aj = red.rgb[i][r0 - ri:r1 - ri, c0 - ci:c1 - ci], red.rgb[j][r0 - rj:r1 - rj, c0 - cj:c1 - cj]
        if white is not None:
            both = both & ~np.any((ai >= white) | (ai <= 0) | (aj >= white) | (aj <= 0), axis=2)
        cnt = int(np.count_nonzero(both))
        if cnt < min_cells:
            continue
        (mi, si), (mj, sj) = _masked_mean_std(ai, both), _masked_mean_std(aj, both)
        if spread:
            stds.append((si, sj))
        pairs.append((i, j))
        cells.append(cnt)
        means.append((mi, mj))
    if not pairs:
        return None
    return OverlapPairs(np.array(pairs, np.int64), np.array(cells, np.int64),
                        np.array(means, float).reshape(-1, 2, bands),
                        np.array(stds, float).reshape(-1, 2, bands) if spread else None)


def level_floor(means: np.ndarray, dtype) -> float:
    """The smallest overlap mean (and deviation) the balance takes the log of: 1 DN for integer samples (as before),
    for float samples one 8-bit step of the block's brightest overlap mean, at most 1 (offsets-fixes2: frames in
    0..1 had every mean floored to 1, every gain 1 and nothing said so; frames in 0..255 or more keep 1)."""
    if np.issubdtype(np.dtype(dtype), np.integer):
        return 1.0
    top = float(np.max(means)) if np.size(means) else 0.0
    return min(1.0, top / 255.0) if top > 0 else 1.0


def _clip_white(red: ReducedFrames) -> float | None:
    """The value of ``red``'s samples at white (its ``white_level``; for 8- and 16-bit frames without one the type's
    maximum), None for float frames (no white: no cell is left out)."""
    if red.white_level.value is not None:
        return float(red.white_level.value)
    dtype = np.dtype(red.rgb[0].dtype) if red.rgb else None
    return float(np.iinfo(dtype).max) if dtype in _HISTOGRAM_TYPES else None


def balance_gains(red: ReducedFrames, labels: np.ndarray | None = None, prior_weight: float = 0.1,
                  min_cells: int = 20, caps=None, return_free: bool = False, exclude_clipped: bool = False):
    """Per-frame, per-band multiplicative gains (n_frames, bands) from the means of the pairwise overlaps: least
    squares on the log-gains, a weak prior towards 1; with ``caps`` (a function of the gains giving (n_frames, bands)
    upper bounds, ``gain_caps``) the least squares under g <= cap (``_bounded_solve``: a frame held at its
    cap, its neighbours follow it down rather than clip its highlights).
    ``return_free``: (gains, the gains without the caps). ``exclude_clipped``: the overlaps without the cells either
    frame has at white or black (as the offsets'; off by default: no clear gain, bench/eval_gains_clipped.py)."""
    n = len(red.names)
    bands = red.rgb[0].shape[2]
    ov = overlap_pairs(red, min_cells, white=_clip_white(red) if exclude_clipped else None)
    if ov is None:
        return (np.ones((n, bands)),) * 2 if return_free else np.ones((n, bands))
    floor_dn = level_floor(ov.mean, red.rgb[0].dtype)
    rhs = np.log(np.maximum(ov.mean[:, 1], floor_dn)) - np.log(np.maximum(ov.mean[:, 0], floor_dn))
    return _solve_log_gains(ov.normal_matrix(n, prior_weight), ov.right_hand_side(n, rhs), caps, return_free)


def _solve_log_gains(N: np.ndarray, u: np.ndarray, caps, return_free: bool):
    """Gains exp(x) of the normal equations N x = u (per band, a column of ``u``), under x <= log caps(gains)."""
    bands = u.shape[1]
    logs = free = np.linalg.solve(N, u)
    if caps is None:
        return (np.exp(logs),) * 2 if return_free else np.exp(logs)
    # the caps of frames kept decoded are known only once their gains are (``ReducedFrames.histograms``): again
    # until no new frame is capped
    c = np.log(np.asarray(caps(np.exp(logs)), float))
    for _ in range(4):
        sols = [_bounded_solve(N, u[:, b], c[:, b]) for b in range(bands)]
        logs = np.stack([s.x for s in sols], axis=1)
        c = np.log(np.asarray(caps(np.exp(logs)), float))
        if np.all(logs <= c + 1e-9):
            break
    for b, s in enumerate(sols):  # once per band, for the solve the gains come from (not once per pass)
        if not s.converged:
            logger.warning(_NOT_CONVERGED, b + 1)
    gains = np.exp(np.minimum(logs, c))
    return (gains, np.exp(free)) if return_free else gains


# the spreads' rows weigh this much against the means' (``balance_gains_offsets``): chosen on the demo with an 8 DN haze
# on every other frame (the overlaps' tone-quarter RMS 0.6538 / 0.6191 / 0.6185 DN at 0.1 / 0.3 / 1: 0.3 and 1 tie, the
# pair-mean RMS 0.286 / 0.292 broke it), reported on Brighton (bench/results/mosaic_offsets.json, "choice")
SPREAD_WEIGHT = 0.3
# a gain within this (relative) of its cap, an offset within this many DN of its bound is held there (offsets-fixes2:
# the bounded solution holds them exactly, ``_bounded_solve``; before, a solver stopped short left held offsets up to
# 2 DN from their bounds, unflagged): far below what a sample's rounding shows (1 DN of 255 is 4e-3)
GAIN_HELD_TOL = 1e-6
OFFSET_HELD_TOL_DN = 1e-3
_NOT_CONVERGED = ("band %d: the bounded colour balance did not converge: its gains (and offsets) are within their "
                  "bounds but not the bounded least squares' solution")


@dataclasses.dataclass(frozen=True)
class FrameRadiometry:
    """Per frame and band the gain and the offset (DN, the frames' own bit depth) that make a sample v the balanced
    g v + o (``gains``, ``offsets``: (frames, bands)), and the gains and offsets the overlaps asked before the
    bounds (``free_gains``, ``free_offsets``); ``gain_held`` (bool (frames, bands)) where the gain is at its cap,
    ``offset_held`` (int8: -1 at its lower bound, 1 at its upper, 0 free)."""

    gains: np.ndarray
    offsets: np.ndarray
    free_gains: np.ndarray
    free_offsets: np.ndarray
    gain_held: np.ndarray
    offset_held: np.ndarray
    converged: np.ndarray | None = None  # (bands,) bool: the bounded solve converged (None: all)


def balance_gains_offsets(red: ReducedFrames, prior_weight: float = 0.1, min_cells: int = 20, caps=None,
                          bounds=None, spread_weight: float | None = None,
                          exclude_clipped: bool = True) -> FrameRadiometry:
    """Per-frame, per-band gain g = e^x and offset o = m p (DN; m the block's mean level) (``FrameRadiometry``) from
    the pairwise overlaps' means m_i and standard deviations s_i (``overlap_pairs``), by one least squares over all
    pairs (not a chain of ratios), per band: for every pair of n_ij common cells, the means
    n_ij (x_i + m p_i / m_i - x_j - m p_j / m_j - log m_j / m_i)^2 (log(g m_i + o) to first order in o) and, weighted by
    ``spread_weight``^2 (default ``SPREAD_WEIGHT``), the deviations n_ij (x_i - x_j - log s_j / s_i)^2 (an offset does
    not change them), a prior lam^2 (x_k^2 + p_k^2) (lam ``prior_weight`` x the rows' RMS weight) and the block's level
    held: sum x = 0, sum p = 0 (heavy rows, which the free solution meets anyway). ``caps`` (a function of the gains:
    (frames, bands) upper bounds, ``gain_caps``) and ``bounds`` (a function of the gains and offsets: (lower, upper)
    (frames, bands) DN, ``offset_bounds``) bound them (``_bounded_solve``): an offset held at its bound
    leaves the rest of its means to the gains. Normal equations of 2 n unknowns (n frames, not n^2 pairs), sparse.
    ``exclude_clipped``: the overlaps without the cells either frame has at white or black (``overlap_pairs``;
    offsets-fixes2: clipping shrank a hazy frame's spread and its means, 12 DN of haze on a bright block read 14.2)."""
    n = len(red.names)
    bands = red.rgb[0].shape[2]
    spread_weight = SPREAD_WEIGHT if spread_weight is None else spread_weight
    ov = overlap_pairs(red, min_cells, spread=True, white=_clip_white(red) if exclude_clipped else None)
    if ov is None:
        one, zero = np.ones((n, bands)), np.zeros((n, bands))
        return FrameRadiometry(one, zero, one, zero, np.zeros((n, bands), bool), np.zeros((n, bands), np.int8))
    i, j = ov.pairs[:, 0], ov.pairs[:, 1]
    w2 = ov.cells.astype(float)
    lam2 = prior_weight * prior_weight * float(np.mean(w2))
    heavy = 1e3 * float(np.sum(w2)) / n
    floor_dn = level_floor(ov.mean, red.rgb[0].dtype)
    level = np.maximum(ov.mean, floor_dn)
    block_level = float(np.mean(level))
    gains, offsets = np.ones((n, bands)), np.zeros((n, bands))
    free_gains, free_offsets = np.ones((n, bands)), np.zeros((n, bands))
    gain_held, offset_held = np.zeros((n, bands), bool), np.zeros((n, bands), np.int8)
    idx = np.stack([i, j, n + i, n + j], axis=1)  # a pair's unknowns: x_i, x_j, p_i, p_j
    # the heavy rows sum x = 0 and sum p = 0 as V V' (V = sqrt(heavy) [1 on x, 1 on p]): N = S + V V', S sparse (a
    # frame's overlaps and its prior: the normal equations of 1,000 frames solved in milliseconds, not dense)
    V = np.zeros((2 * n, 2))
    V[:n, 0] = V[n:, 1] = math.sqrt(heavy)
    converged = np.ones(bands, bool)
    import scipy.sparse as sp

    for b in range(bands):
        mi, mj = level[:, 0, b], level[:, 1, b]
        # the means' row of a pair: x_i - x_j + (m / m_i) p_i - (m / m_j) p_j = log m_j / m_i
        coef = np.stack([np.ones(len(i)), -np.ones(len(i)), block_level / mi, -block_level / mj], axis=1)
        r = np.log(mj) - np.log(mi)
        u = np.zeros(2 * n)
        rows, cols, vals = [np.arange(2 * n)], [np.arange(2 * n)], [np.full(2 * n, lam2)]
        for c1 in range(4):
            np.add.at(u, idx[:, c1], w2 * coef[:, c1] * r)
            for c2 in range(4):
                rows.append(idx[:, c1])
                cols.append(idx[:, c2])
                vals.append(w2 * coef[:, c1] * coef[:, c2])
        # the deviations' row: x_i - x_j = log s_j / s_i
        sr = np.log(np.maximum(ov.std[:, 1, b], floor_dn)) - np.log(np.maximum(ov.std[:, 0, b], floor_dn))
        ws = spread_weight * spread_weight * w2
        rows += [i, j, i, j]
        cols += [i, j, j, i]
        vals += [ws, ws, -ws, -ws]
        np.add.at(u, i, ws * sr)
        np.add.at(u, j, -ws * sr)
        S = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * n, 2 * n))
        sol = _spd_solve(S, V, np.ones(2 * n, bool), u)
        free_gains[:, b], free_offsets[:, b] = np.exp(sol[:n]), block_level * sol[n:]
        # the caps and bounds of frames kept decoded are known once their gains are (``ReducedFrames.histograms``):
        # again until none is passed
        for _ in range(3 if caps is not None or bounds is not None else 0):
            g, o = np.ones((n, bands)), np.zeros((n, bands))
            g[:, b], o[:, b] = np.exp(sol[:n]), block_level * sol[n:]
            cap, floor = np.full(2 * n, np.inf), np.full(2 * n, -np.inf)
            if caps is not None:
                cap[:n] = np.log(np.asarray(caps(g), float)[:, b])
            if bounds is not None:
                lo, hi = bounds(g, o)
                floor[n:], cap[n:] = lo[:, b] / block_level, hi[:, b] / block_level
            if np.all(sol <= cap + 1e-12) and np.all(sol >= floor - 1e-12):
                break
            res = _bounded_solve(S, u, cap, floor, low_rank=V)
            sol, converged[b] = res.x, res.converged
            # held: within GAIN_HELD_TOL (relative) of its cap, OFFSET_HELD_TOL_DN of a bound
            gain_held[:, b] = np.isfinite(cap[:n]) & (cap[:n] - sol[:n] <= GAIN_HELD_TOL)
            offset_held[:, b] = np.where(np.isfinite(floor[n:]) & ((sol[n:] - floor[n:]) * block_level
                                                                   <= OFFSET_HELD_TOL_DN), -1,
                                         np.where(np.isfinite(cap[n:]) & ((cap[n:] - sol[n:]) * block_level
                                                                          <= OFFSET_HELD_TOL_DN), 1, 0))
        gains[:, b], offsets[:, b] = np.exp(sol[:n]), block_level * sol[n:]
    return FrameRadiometry(gains, offsets, free_gains, free_offsets, gain_held, offset_held, converged)


_GAIN_LOWERED = ("frame %s band %d: gain %.4g lowered to %.4g so that no unsaturated sample of the frame goes beyond "
                 "what the highlight roll-off brings below white (the frame's own saturated share %.2f %%; the gain "
                 "would have saturated %.2f %% without the roll-off)")


def held_messages(rad: FrameRadiometry, names) -> list[str]:
    """A warning per frame and band whose gain ``rad`` holds at its cap (``gain_caps``) or whose offset at a bound
    (``offset_bounds``), with the gain and offset the overlaps asked without the bounds (the free fit)."""
    out = [] if rad.converged is None else [_NOT_CONVERGED % (b + 1) for b in np.flatnonzero(~rad.converged)]
    for k, b in zip(*np.nonzero(rad.gain_held | (rad.offset_held != 0))):
        asked = f"the balance asked gain {rad.free_gains[k, b]:.4g}, offset {rad.free_offsets[k, b]:+.2f} DN"
        if rad.gain_held[k, b]:
            out.append(f"frame {names[k]} band {b + 1}: gain {rad.gains[k, b]:.4g} held at its cap ({asked}) so that "
                       f"no unsaturated sample of the frame goes beyond what the highlight roll-off brings below white")
        if rad.offset_held[k, b]:
            out.append(f"frame {names[k]} band {b + 1}: offset {rad.offsets[k, b]:+.2f} DN held at its "
                       f"{'lower' if rad.offset_held[k, b] < 0 else 'upper'} bound ({asked}): an offset is at most "
                       f"{100 * OFFSET_MAX_SHARE:g} % of white either way and takes no unsaturated sample of the frame "
                       f"below what the shadow toe lifts above black nor beyond what the roll-off brings below white")
    return out


@dataclasses.dataclass(frozen=True)
class BoundedSolution:
    """``_bounded_solve``'s solution ``x``, whether the method converged (the bounds it holds stable and every
    multiplier pushing against its bound: the Karush-Kuhn-Tucker conditions to rounding) and its ``iterations``."""

    x: np.ndarray
    converged: bool
    iterations: int


def _spd_solve(N, low_rank, free: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """The solution of (N + V V')[free, free] y = ``rhs`` (N dense or scipy sparse, V = ``low_rank`` (m, k) or None):
    a dense solve, or a sparse LU of N's rows and columns ``free`` and the Woodbury identity for V's k columns (the
    heavy rows of the block's level, which would make N dense)."""
    import scipy.sparse as sp

    if not sp.issparse(N):
        A = N[np.ix_(free, free)]
        if low_rank is not None:
            A = A + low_rank[free] @ low_rank[free].T
        return np.linalg.solve(A, rhs)
    from scipy.sparse.linalg import splu

    lu = splu(sp.csc_matrix(N[free][:, free]))
    y = lu.solve(rhs)
    if low_rank is None:
        return y
    V = low_rank[free]
    Z = lu.solve(np.ascontiguousarray(V))
    return y - Z @ np.linalg.solve(np.eye(V.shape[1]) + V.T @ Z, V.T @ y)


def _bounded_solve(N, u: np.ndarray, cap: np.ndarray, floor: np.ndarray | None = None, low_rank=None,
                   max_iter: int = 200) -> BoundedSolution:
    """argmin x'Mx/2 - u'x subject to ``floor`` <= x <= ``cap`` (None, or a bound not finite: none), M = N + V V'
    positive definite (N dense or scipy sparse: a block's normal equations, V = ``low_rank`` (m, k) or None), by the
    primal-dual active set method (Hintermueller, Ito & Kunisch 2002): the bounds the last solution passes or whose
    multipliers push against them held, the others solved exactly, until the held set no longer changes: then every
    value is within its bounds and every held one's multiplier of the right sign (converged). A held set met before
    (a cycle, possible when M is not an M-matrix) or ``max_iter``: then scipy's trust-region reflective bounded
    least squares, given 20 iterations per unknown. Either way ``converged`` is decided on the returned x by the
    optimality conditions (``_kkt_holds``), not by the method's own stop: the reflective solver's status 2 / 3 say
    only that the cost or x stopped changing (s9-fixes: 1,000 frames, status 2, offsets 0.32 DN off). Replaced
    (offsets-fixes2) the reflective solver alone that stopped at its 100 iterations on blocks of 100 frames and more
    (100 frames: offsets 1.95 DN off) and took 35 s on 400 frames' dense 800 unknowns with offsets."""
    import scipy.sparse as sp

    m = len(u)
    upper = np.where(np.isfinite(cap), cap, np.inf)
    lower = np.full(m, -np.inf) if floor is None else np.where(np.isfinite(floor), floor, -np.inf)
    everything = np.ones(m, bool)
    x = _spd_solve(N, low_rank, everything, u)

    def times(v):  # M v
        out = np.asarray(N @ v).ravel()
        return out if low_rank is None else out + low_rank @ (low_rank.T @ v)

    diag = (N.diagonal() if sp.issparse(N) else np.diag(N)).astype(float)
    if low_rank is not None:
        diag = diag + np.sum(low_rank * low_rank, axis=1)
    if np.all(x <= upper) and np.all(x >= lower):
        return BoundedSolution(x, _kkt_holds(times, diag, u, x, lower, upper), 0)
    up, lo = x > upper, x < lower
    seen, it = set(), 0
    for it in range(1, max_iter + 1):
        seen.add((up.tobytes(), lo.tobytes()))
        x = np.where(up, upper, np.where(lo, lower, 0.0))
        free = ~(up | lo)
        if free.any():
            x[free] = _spd_solve(N, low_rank, free, (u - times(x))[free])
        push = (u - times(x)) / diag  # the multipliers, in x's units: > 0 pushes up, < 0 down
        new_lo = push + (x - lower) < 0
        new_up = (push + (x - upper) > 0) & ~new_lo
        if np.array_equal(new_up, up) and np.array_equal(new_lo, lo):
            return BoundedSolution(x, _kkt_holds(times, diag, u, x, lower, upper), it)
        up, lo = new_up, new_lo
        if (up.tobytes(), lo.tobytes()) in seen:
            break
    from scipy.optimize import lsq_linear

    dense = N.toarray() if sp.issparse(N) else np.array(N, float)
    if low_rank is not None:
        dense += low_rank @ low_rank.T
    chol = np.linalg.cholesky(dense)
    res = lsq_linear(chol.T, np.linalg.solve(chol, u), bounds=(lower, upper), method="trf", tol=1e-12,
                     max_iter=20 * m)
    x = np.clip(res.x, lower, upper)
    return BoundedSolution(x, _kkt_holds(times, diag, u, x, lower, upper), it + int(res.nit))


# the optimality test's tolerance (``_kkt_holds``): the projected step's largest component against the gradient's
# scale, both in x's units. Chosen on /work/tmp/review-s9/pdas.py's 1,020 bounded problems (dense, ill-conditioned to
# 1e8, caps only, block-like sparse + low rank with 1 to 50 frames): the active set's solutions at most 8.4e-10, the
# reflective solver's after a cycle (31 of them, each the optimum to 1e-13 of its cost) at most 5.9e-8; the reflective
# solver stopped short (1,000 frames, status 2, offsets 0.32 DN off: /work/tmp/review-s9/fb.py) 3.0e-3
KKT_REL_TOL = 1e-6


def _kkt_holds(times, diag: np.ndarray, u: np.ndarray, x: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               tol: float = KKT_REL_TOL) -> bool:
    """Whether x is the minimum of x'Mx/2 - u'x in lower <= x <= upper (``times``: v -> M v, ``diag``: M's diagonal)
    by the Karush-Kuhn-Tucker conditions: every value within its bounds, and the projected gradient step
    x - clip(x - g / diag, lower, upper) (g = M x - u; zero where x is free and g = 0 or at a bound g pushes against)
    at most ``tol`` times the gradient's scale in x's units, max (|u| + |M x|) / diag (what rounding in g is relative
    to). The step, not g itself: a value a hair inside the bound its multiplier pushes it to (the reflective solver's
    never reach theirs) counts by that hair, not by its multiplier."""
    if not (np.all(x <= upper) and np.all(x >= lower)):
        return False
    mx = times(x)
    step = x - np.clip(x - (mx - u) / diag, lower, upper)
    scale = max(float(np.max((np.abs(u) + np.abs(mx)) / diag, initial=0.0)), np.finfo(float).tiny)
    return bool(np.max(np.abs(step), initial=0.0) <= tol * scale)


def _read_ndsm_on(path, transform, shape, crs, operation=None, ds=None):
    """The nDSM (project CRS) on the mosaic grid, by maximum; a mosaic in another CRS than the nDSM's
    is mapped back through the index's coordinate operation (``operation``: mosaic CRS -> nDSM CRS). ``ds``: the
    nDSM already open (``_open_checked_ndsm``), read instead of opening ``path`` again."""
    from rasterio.warp import reproject

    from aerotri.geom.crs.definition import height_unit_m, parse_crs, same_horizontal
    from aerotri.geom.crs.raster_warp import read_on_grid
    from aerotri.geom.crs.transform import CrsTransformer

    out = np.full(shape, np.nan, np.float32)
    if ds is None and not Path(path).is_file():
        raise InputError(f"{path}: nDSM not found")
    try:
        with (contextlib.nullcontext(ds) if ds is not None else rasterio.open(path)) as ds:
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


def _open_checked_ndsm(path, index: FrameIndex, mosaic):
    """The nDSM checked before any work: a height raster (``ortho.dem.open_height_raster``: 2 x 2 cells or more,
    one band of finite heights) in the project CRS the frames were rectified from, over the mosaic; returned open
    (the caller closes it)."""
    from ortho.dem import open_height_raster, require_overlap

    project = index.project_crs
    ds = open_height_raster(path, CRS.from_user_input(project) if project else None, "nDSM")
    try:
        require_overlap(ds, path, "nDSM", (mosaic.x_left_m, mosaic.y_top_m - mosaic.height * mosaic.res_m,
                                           mosaic.x_left_m + mosaic.width * mosaic.res_m, mosaic.y_top_m),
                        mosaic.crs, "the mosaic")
    except BaseException:
        ds.close()
        raise
    return ds


def _write_labels(path, labels, transform, crs):
    with atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=labels.shape[1], height=labels.shape[0], count=1,
                           dtype="int32", crs=crs, transform=transform, nodata=-1, compress="deflate") as dst:
            dst.write(labels, 1)


@dataclasses.dataclass(frozen=True)
class MosaicSummary:
    """What ``mosaic_block`` made: the COG (``path``), its size (px) and pixel size, the frames blended, how the seams
    were made, the feather (px), every frame's band gains (name, gains), the cells inside the block no frame sees,
    an edited run's seam crossings, and ``summary_path``, ortho/mosaic.json (the record with the seam pairs, tiles and settings as well)."""

    path: Path
    summary_path: Path
    width_px: int
    height_px: int
    frames: int
    res_m: float
    seams: str
    feather_px: float
    gains: tuple[tuple[str, tuple[float, ...]], ...]
    cells_seen_by_no_frame: int
    area_seen_by_no_frame_m2: float
    share_seen_by_no_frame: float | None = None  # of the block's cells (None: a record written before it was kept)
    seam_crossings: CrossingsSummary | None = None  # an edited run's check (``ortho.seam_crossings``); None: not edited
    # the frames the seams give no cell, so no seamline polygon (``frames_without_cells``; () in a record before it)
    frames_without_cells: tuple[str, ...] = ()
    # of the cells seen by no frame, those where the DEM (or a true ortho's DSM) has no heights, and their share of
    # the block's cells (``ortho.unseen.unseen_without_heights``; None in a record before it was kept)
    cells_without_heights: int | None = None
    share_without_heights: float | None = None
    # of the cells seen by no frame of a true ortho, those on the nDSM's objects (``ortho.unseen.unseen_on_objects``;
    # None: not a true ortho, no nDSM, or a record before it was kept)
    cells_on_objects: int | None = None
    excluded: tuple[str, ...] = ()  # the frames left out ([mosaic] exclude, ``without_frames``)


def _mosaic_summary(doc: dict, summary_path: Path) -> MosaicSummary:
    return MosaicSummary(Path(doc["path"]), summary_path, doc["width"], doc["height"], doc["frames"], doc["res_m"],
                         doc["seams"], doc["feather_px"], tuple((n, tuple(g)) for n, g in doc["gains"].items()),
                         doc["cells_seen_by_no_frame"], doc["area_seen_by_no_frame_m2"],
                         doc.get("share_seen_by_no_frame"),
                         CrossingsSummary.from_record(doc["seam_crossings"]) if doc.get("seam_crossings") else None,
                         tuple(str(n) for n in doc.get("frames_without_cells") or ()),
                         doc.get("cells_without_heights"), doc.get("share_without_heights"),
                         doc.get("cells_on_objects"), tuple(doc.get("excluded") or ()))


def read_mosaic_summary(path) -> MosaicSummary:
    """ortho/mosaic.json as ``mosaic_block`` wrote it; InputError naming the file when it is not one."""
    from aerotri.core.textio import record_error

    doc = read_json(path, "mosaic record (mosaic.json)")
    try:
        return _mosaic_summary(doc, Path(path))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, "mosaic record (mosaic.json)", exc) from None


def mosaic_block(root, settings: MosaicSettings | Resolved | None = None, *, object_height_m: float = 2.5,
                 max_seam_cells: float = 5e7, end_reach_m: float = 30.0, seam_cell_m: float = 1.5,
                 executor=None, seamlines=None, give_sole_gaps: bool = False) -> MosaicSummary:
    """``ortho mosaic``: see the module doc. Returns what it made (``MosaicSummary``).

    ``seamlines``: an edited seamlines GeoPackage (``ortho/seamlines.gpkg`` as a run writes it, edited in QGIS) whose
    polygons replace the seams the run would route (checked first: ``ortho.seamlines_gpkg``); ``give_sole_gaps``
    (the chain re-making an edited mosaic): cells in no polygon that one frame alone sees go to it, with a warning,
    and are listed in mosaic.json (``edited_gaps_given``), instead of being refused as a gap.

    ``settings``: None reads [mosaic] of project.toml; a ``Resolved`` (``ortho mosaic``, the chain) carries the
    source of every setting into mosaic.json (``settings``). The output tiles are blended as tasks on
    ``executor`` (``aerotri.core.executor.Executor``, default: local threads); the COG does not depend on the
    scheduler. GDAL's block cache is ``MOSAIC_CACHE_BYTES`` for the whole stage (set here, before any thread
    of the stage starts: ``aerotri.core.gdal_cache``)."""
    with stage_block_cache(MOSAIC_CACHE_BYTES):
        doc = _mosaic_block(root, settings, object_height_m=object_height_m, max_seam_cells=max_seam_cells,
                            end_reach_m=end_reach_m, seam_cell_m=seam_cell_m, executor=executor, seamlines=seamlines,
                            give_sole_gaps=give_sole_gaps)
    return _mosaic_summary(doc, Path(root) / "ortho" / "mosaic.json")


def _mosaic_block(root, settings, *, object_height_m, max_seam_cells, end_reach_m, seam_cell_m, executor,
                  seamlines=None, give_sole_gaps=False) -> dict:
    root = Path(root)
    timer = _PhaseTimer()
    resolved = settings_of(settings, MosaicSettings, Project.open(root) if settings is None else None)
    s = resolved.settings
    seams, ndsm_path, feather_m, balance, tile_px = s.seams, s.ndsm, s.feather_m, s.balance, s.tile_px
    with_offsets = s.offsets
    if s.output_bits not in (None, 8):
        raise OptionError(f"{s.output_bits!r}: expected 8 (default: the frames' own type)", param="--output-bits")
    if s.output_range != "white-level" and s.output_bits is None:  # (a mapping to 8 bits: without them none)
        raise OptionError(f"--output-range / [mosaic] output_range = {s.output_range} "
                          f"({resolved.sources.get('output_range', 'default')}) maps the DOM to 8 bits: it needs "
                          f"--output-bits 8 / [mosaic] output_bits = 8", param="--output-range")
    if not (isinstance(tile_px, int) and tile_px >= MIN_TILE_PX):
        raise OptionError(f"{tile_px!r}: expected a tile size of at least {MIN_TILE_PX} px", param="--tile-px")
    if feather_m is not None and not (math.isfinite(feather_m) and feather_m >= 0):
        raise OptionError(f"{feather_m!r}: expected a feather width >= 0 m", param="--feather-m")
    if with_offsets and not balance:  # (the offsets are solved with the gains: without the balance neither is)
        raise OptionError(f"--offsets / [mosaic] offsets = true ({resolved.sources.get('offsets', 'default')}) needs "
                          f"the balance, which --no-balance / [mosaic] balance = false "
                          f"({resolved.sources.get('balance', 'default')}) turns off: give one or the other",
                          param="--offsets")
    if seamlines is not None:
        require_seamlines_file(seamlines)
        # absolute in mosaic.json: the chain re-makes an edited mosaic with them from any folder (review 49: a relative
        # name was looked for in the folder `aerotri run` started in, and another file of that name taken)
        seamlines = Path(os.path.abspath(seamlines))
        # the run rewrites ortho/seamlines.gpkg: an edited copy, never the file itself, is its input
        # (and ortho/seamlines.geojson: trial-ortho2's edit of it was read, then overwritten by the run)
        for out in (root / "ortho" / "seamlines.gpkg", root / "ortho" / "seamlines.geojson"):
            if out.exists() and os.path.samefile(out, seamlines):
                raise OptionError(f"{seamlines}: this is a file the mosaic writes (inputs are never modified); edit a "
                                  f"copy of it outside ortho/ (e.g. {root / ('seamlines_edited' + out.suffix)}, "
                                  "as docs/true-ortho.md does) and give that",
                                  param="--seamlines")
    index = read_index(root)
    frames_dir = root / "ortho" / "frames"
    if not index.frames:
        raise InputError(f"{frames_dir / 'index.json'}: no frames")
    verify_index(frames_dir, index)
    require_current_frames(root, index, f"`ortho mosaic {root}`")
    if s.exclude:
        index = without_frames(index, s.exclude, resolved.sources.get("exclude", "default"))
        logger.info("mosaic: %d frame(s) left out (exclude): %s", len(s.exclude), ", ".join(s.exclude))
    grids = index.grids
    mosaic = OrthoGrid.union(grids)
    res = mosaic.res_m
    check_grid(mosaic.width, mosaic.height, f"the mosaic of {len(grids)} frames at {res:g} m")
    feather_px = max(1.0, feather_m / res) if feather_m is not None else 8.0
    bands, itemsize = _frame_layout(frames_dir / index.frames[0].file)
    tiles_bytes = _tile_bytes(tile_px, feather_px, bands, itemsize) * _tiles_in_flight(executor)
    check_allocation(tiles_bytes,
                     f"--tile-px {tile_px}: mosaic tiles of {tile_px} x {tile_px} px (with their halo, {bands} band(s))",
                     "--tile-px")
    if ndsm_path is not None and not Path(ndsm_path).is_file():
        raise InputError(f"{ndsm_path}: nDSM not found (--ndsm)")
    if ndsm_path is None and (root / "lidar_out" / "ndsm.tif").exists():
        ndsm_path = root / "lidar_out" / "ndsm.tif"
        resolved = resolved.replace("ndsm", ndsm_path, resolved.sources.get("ndsm", "default"), "the LiDAR stages' nDSM")
    total_px = sum(g.width * g.height for g in grids)
    # seam cells of about seam_cell_m (buildings and roads are metres wide; finer cells only cost time: the
    # seams took 2.5 of the demo's 6 CPU-s on 0.8 m cells), more where the frames would not fit max_seam_cells
    factor = max(2, int(round(seam_cell_m / res)), int(math.ceil(math.sqrt(total_px / max_seam_cells))))
    # under a memory limit, fewer (coarser) seam cells where the frames' cells would not fit beside the tiles
    fit_cells = max(MIN_SEAM_CELLS, (memory_room_bytes() - tiles_bytes) / MOSAIC_BYTES_PER_SEAM_CELL)
    if fit_cells < total_px / factor ** 2:
        coarser = int(math.ceil(math.sqrt(total_px / fit_cells)))
        logger.info(f"mosaic: seam cells of {res * coarser:g} m ({res * factor:g} m without the limit) to fit in the "
                    f"{format_bytes(usable_memory_bytes())} this process may use")
        factor = coarser
    seam_transform = Affine(res * factor, 0, mosaic.x_left_m, 0, -res * factor, mosaic.y_top_m)
    seam_shape = (-(-mosaic.height // factor), -(-mosaic.width // factor))
    timer.done("checks")
    # the nDSM is checked and read onto the seam grid on a thread while the frames are reduced (both before
    # any output is written; its error is raised before the seams are made)
    # the path search's modules (scipy.sparse.csgraph: 0.2 CPU-s, a fifth of the demo's start-up) are imported on a
    # thread of their own meanwhile; joined before the seams, so that no other thread imports them at the same time
    # and so are the modules the writers of the vector files import (shapely, pyogrio: 0.05 CPU-s), which were imported
    # by this thread before the frames were read
    importer = None
    if seams == "least-cost":  # (an edited run routes them too: the automatic seams its check compares with)
        importer = threading.Thread(target=_import_quietly, args=(_import_seam_modules,), name="mosaic-import",
                                    daemon=True)
        importer.start()
    with _background(_ndsm_objects, ndsm_path, index, mosaic, seam_transform, seam_shape, object_height_m,
                     imports=importer is None) as objects_of:
        # blending on local threads reads the frames kept decoded by the seam grid when they are small
        keep = (executor is None or not executor.distributed) and \
            decoded_bytes(index, bands, itemsize) <= DECODED_FRAMES_MAX_BYTES
        timer.trim = not keep
        red = reduce_frames(frames_dir, index, mosaic, factor, keep_decoded=keep)
        if importer is not None:
            importer.join()
        timer.done("seam grid")
        objects = objects_of()
        timer.done("nDSM")
    nadir = np.array([e.nadir_xy_m for e in index.frames])
    nadir_rc = np.stack([(mosaic.y_top_m - nadir[:, 1]) / (res * factor) - 0.5,
                         (nadir[:, 0] - mosaic.x_left_m) / (res * factor) - 0.5], axis=1)

    def frame_gains():
        bands = red.rgb[0].shape[2]

        white = red.white_level.value

        def caps(g):
            return gain_caps(red.histograms(g), bands, white, ROLLOFF_HEADROOM)

        def bounds(g, o):
            return offset_bounds(g, red.histograms(g, o), white)

        if not balance:
            return np.ones((len(red.names), bands)), None, [], None, None
        if not with_offsets:  # gains only (before i42-offsets): the means matched by log-gains
            gains, free = balance_gains(red, caps=caps, return_free=True)
            _, held = limit_gains(free, red.histograms(free), white=white, headroom=ROLLOFF_HEADROOM)
            return (gains, None, [_GAIN_LOWERED % (red.names[k], b + 1, g0, float(gains[k, b]), 100 * own, 100 * would)
                                  for k, b, g0, _, own, would in held],
                    highlight_rolloff(gains, red.histograms(gains), white), None)
        # colour that neither clips nor darkens: a gain and an offset per frame and band (haze, a black level: what a
        # gain cannot remove) keep the block's level (mean log-gain 0, mean offset 0); the highlight roll-off brings
        # every unsaturated sample below white, the shadow toe above black; only a frame whose brightest unsaturated
        # sample would go beyond what the roll-off takes is held (the least squares under each frame's cap), an
        # offset within its bounds; each frame and band the bounded solution holds is reported with the gain and
        # offset the free fit asked (not the free fit's gains against their caps: its offsets take what they push back)
        rad = balance_gains_offsets(red, caps=caps, bounds=bounds)
        gains, offsets = rad.gains, rad.offsets
        hists = red.histograms(gains, offsets)
        return (gains, offsets, held_messages(rad, red.names),
                highlight_rolloff(gains, hists, white, offsets), shadow_toe(gains, offsets, hists, white))

    # the gains do not depend on the seams: on a thread while this one routes them (OpenCV's masked means and
    # histograms, numpy's solve; the seams are mostly scipy's Dijkstra and numpy)
    with _background(frame_gains, imports=False) as gains_of:
        edited = None
        if seamlines is not None:  # the user's polygons, checked whole before anything is written
            from ortho.seamlines_gpkg import read_edited_seamlines

            edited = read_edited_seamlines(seamlines, red.names, mosaic.crs, labels_shape=red.shape,
                                           transform=red.transform, valid=red.valid, offsets=red.offsets,
                                           excluded=s.exclude, give_sole_gaps=give_sole_gaps)
            for g in edited.gaps_given:
                logger.warning("edited seamlines %s: %d seam cell%s (%.0f m2, %d area(s), the largest around (%.1f, "
                               "%.1f)) in no polygon that frame %s alone sees (its ortho covers more than when the "
                               "seamlines were edited): given to it", seamlines, g.cells, "s" * (g.cells != 1),
                               g.area_m2, g.areas, g.x, g.y, g.frame)
        # the seams are routed on the cells each frame covers, the holes of what it does not see (a true ortho's
        # occlusion) included: one region per frame whose holes the blending fills from the frame of the nearest
        # nadir point that sees them (on the frames' valid cells, every hole became an island of another frame
        # whose outline, along the walls and across the roofs between the streets, was a seam); an edited run
        # routes them as well, as the figure its crossings are compared with (the edited seams are not touched)
        covers = [footprint(v) for v in red.valid]
        labels = voronoi_labels(covers, red.offsets, nadir_rc, red.shape)
        if seams == "least-cost":
            # a seam end may slide along the overlap border by up to end_reach_m to get round a building
            labels = least_cost_seams(labels, covers, red.offsets, gray=red.gray_of, object_mask=objects,
                                      end_reach_cells=end_reach_m / (res * factor), seen=red.valid)
            if objects is not None:
                labels = keep_objects_whole(labels, objects, covers, red.offsets)
        crossings = None
        if edited is not None:
            from ortho.seam_crossings import check_seam_crossings

            crossings = check_seam_crossings(edited.labels, labels, red.transform, red.names, mosaic.crs,
                                             ndsm_path=ndsm_path, operation=index_operation(index),
                                             feature_of_frame=edited.feature_of_frame)
            labels = edited.labels
            seams = f"edited ({edited.path})"
        timer.done("seams")
        gains, offsets, held, rolloff, toe = gains_of()
    for message in held:
        logger.warning(message)
    if crossings is not None and not crossings.checked:
        logger.warning("edited seamlines: %s", crossings.why)
    for message in () if crossings is None else crossings.warnings:
        logger.warning(message)
    if rolloff is not None:
        logger.info("highlight roll-off: gained values above %.1f compressed so that %.1f becomes %.2f (white %d)",
                    rolloff.knee, rolloff.top_in, rolloff.top_out, red.white_level.value)
    if toe is not None:
        logger.info("shadow toe: values below %.2f lifted so that %.2f becomes %.3f (above black)", toe.knee,
                    toe.bottom_in, toe.bottom_out)
    out_map = output_mapping(s.output_bits, red.white_level, s.output_range, red, gains=gains, offsets=offsets,
                             rolloff=rolloff, toe=toe)
    timer.done("gains")
    # edited seamlines: the tiles their change does not reach are taken from the mosaic they were edited on
    previous = previous_mosaic(root, index, red.names, labels, gains=gains, feather_px=feather_px, factor=factor,
                               mosaic=mosaic, rolloff=rolloff, offsets=offsets, toe=toe,
                               output=out_map) if edited is not None else None
    for name, g in zip(red.names, gains):
        if np.any(np.abs(np.log(g)) > math.log(1.3)):  # beyond exposure differences between frames of one flight
            logger.warning("frame %s needs gains %s to match its neighbours: check its exposure, or how its image "
                           "file stores the bands", name, ", ".join(f"{v:.2f}" for v in g))
    out_dir = root / "ortho"
    # every output is made in a work folder first and moved into ortho/ only when all of them exist:
    # a failed run leaves the previous seams, seamlines, mosaic and summary together; the rows of tiles a killed or
    # interrupted run finished are kept in work/mosaic_resume until the commit (an error removes them too)
    with resumable(root / "work" / RESUME_DIR_NAME) as keep, scratch_dir(out_dir, "mosaic") as work:
        outputs = _mosaic_outputs(Path(work), root, index, frames_dir, red=red, labels=labels, gains=gains,
                                  rolloff=rolloff, offsets=offsets, toe=toe,
                                  mosaic=mosaic, factor=factor, nadir=nadir, feather_px=feather_px, tile_px=tile_px,
                                  seams=seams, executor=executor, settings_record=resolved.record(), previous=previous,
                                  resume=keep, output=out_map, crossings=crossings,
                                  gaps_given=edited.gaps_given if edited is not None else (),
                                  objects=(ndsm_path, object_height_m) if ndsm_path is not None else None)
        timer.done("blend and COG")
        with commit_outputs(out_dir):  # one commit: all new, or (a failure, a kill) all as before
            for name in ("seams.tif", "seamlines.geojson", "seamlines.gpkg", "seamlines_preview.png", "mosaic.tif",
                         "mosaic.json"):
                move_into(Path(work) / name, out_dir / name)
            # where the edited seams cross buildings and trees (an edited run with an nDSM); any other run leaves
            # none, so that an earlier edit's crossings are not taken for this run's
            if (Path(work) / CROSSINGS_FILE).exists():
                move_into(Path(work) / CROSSINGS_FILE, out_dir / CROSSINGS_FILE)
            elif (out_dir / CROSSINGS_FILE).exists():
                remove_output(out_dir / CROSSINGS_FILE)
    return outputs


@dataclasses.dataclass(frozen=True)
class OutputMapping:
    """The block's map of the balanced samples (the frames' own bit depth, after gains, offsets, roll-off and toe) to
    the DOM's 8-bit samples (``[mosaic] output_bits = 8``): v8 = clip(rint((v - ``low_dn``) x 255 / (``high_dn`` -
    ``low_dn``)), 0, 255), the same for every pixel of the block (never per frame or tile: a seam or a tile edge would
    show; an edited run's tiles map as a whole run's). ``low_dn`` 0 and ``high_dn`` the frames' white level (4095 for
    12-bit data in 16-bit frames): nothing beyond what the frames saturate is clipped, and a value within half an 8-bit
    step of white (white / 510 DN) rounds to 255. Nodata stays in the mask (a valid black pixel is 0 and valid)."""

    bits: int
    low_dn: float
    high_dn: float
    source: str  # how the range was found: "white level (<its source>)"

    @property
    def scale(self) -> float:
        """8-bit steps per DN of the frames."""
        return 255.0 / (self.high_dn - self.low_dn)

    def apply(self, samples: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(bands, h, w) samples of the frames' type -> uint8, 0 where not ``valid``: a lookup table for 8- and 16-bit
        samples, the same float64 arithmetic for other types (``v8``: the formula's value in float64, rounded half to
        even, numpy's rint: a float32 table, scale rounded to float32 first, rounded some .5 ties the other way)."""
        if samples.dtype in _HISTOGRAM_TYPES:
            out = np.take(self._lut(samples.dtype), samples)
        else:
            out = self.v8(samples.astype(np.float64))
        out[:, ~valid] = 0
        return out

    def v8(self, v: np.ndarray) -> np.ndarray:
        """The formula on float64 values: (v - low_dn) x 255 / (high_dn - low_dn), rounded half to even, clipped."""
        return np.clip(np.rint((v - self.low_dn) * 255.0 / (self.high_dn - self.low_dn)), 0, 255).astype(np.uint8)

    @functools.lru_cache(maxsize=2)
    def _lut(self, dtype) -> np.ndarray:
        return self.v8(np.arange(int(np.iinfo(dtype).max) + 1, dtype=np.float64))

    def record(self) -> dict:
        """mosaic.json's "output" mapping (and what an edited run's earlier mosaic must have been made with)."""
        return {"bits": self.bits, "low_dn": self.low_dn, "high_dn": self.high_dn, "scale": self.scale,
                "from": self.source, "formula": self.formula}

    @property
    def formula(self) -> str:
        return f"v8 = clip(round((v - {self.low_dn:g}) * 255 / {self.high_dn - self.low_dn:g}), 0, 255)"  # half to even

    def tags(self) -> dict:
        """The DOM's metadata tags stating the mapping (GDAL metadata of the COG)."""
        return {"DOM_SAMPLE_MAPPING": self.formula, "DOM_SOURCE_LOW_DN": f"{self.low_dn:g}",
                "DOM_SOURCE_HIGH_DN": f"{self.high_dn:g}", "DOM_SOURCE_RANGE_FROM": self.source}


# the pooled percentiles of ``output_range = "percentiles"``: set a priori (a DOM's darkest and brightest thousandth
# clipped, as a viewer's default stretch does), not tuned on a block
STRETCH_PERCENTILES = (0.1, 99.9)


def output_mapping(bits: int | None, white, range_from: str = "white-level", red=None, *, gains=None, offsets=None,
                   rolloff=None, toe=None) -> OutputMapping | None:
    """The ``OutputMapping`` to ``bits`` (None: the frames' own type, no mapping) from the frames' ``WhiteLevel``
    (``range_from`` "white-level": 0 .. white) or from the pooled ``STRETCH_PERCENTILES`` of the balanced samples
    ("percentiles": ``balanced_percentiles`` of ``red``'s histograms through ``gains``, ``offsets``, ``rolloff`` and
    ``toe``)."""
    if bits is None:
        return None
    if white.value is None:
        raise OptionError(f"--output-bits {bits} / [mosaic] output_bits = {bits}: the frames' samples have no white "
                          f"level (they are floats): expected 8- or 16-bit frames", param="--output-bits")
    if range_from == "percentiles":
        lo, hi = balanced_percentiles(red, gains, offsets, rolloff, toe, white.value, STRETCH_PERCENTILES)
        return OutputMapping(int(bits), lo, hi, f"pooled percentiles {STRETCH_PERCENTILES[0]:g} / "
                                                f"{STRETCH_PERCENTILES[1]:g} of the balanced samples (white level "
                                                f"{white.value}, {white.source})")
    return OutputMapping(int(bits), 0.0, float(white.value), f"white level ({white.source}, {white.bits} bits)")


def balanced_percentiles(red: ReducedFrames, gains, offsets, rolloff, toe, white: int, percentiles) -> tuple:
    """(low, high) DN: the ``percentiles`` (%) of every frame's valid samples, all bands pooled (one mapping: a grey
    stays grey), through its gains (and offsets), the roll-off and the toe, as the blending has them; a saturated
    sample held at white. From the frames' histograms (a frame kept decoded: made here): a bin's samples spread evenly
    over its values (16-bit bins are 64 DN wide), each bin's ends through the frame's transform (monotone), pooled on
    a 1 DN grid; rounded to whole DN."""
    cells = np.zeros(int(white) + 2, np.float64)  # difference array of the pooled density on [0, white]
    for k, hist in enumerate(red.sample_histograms):
        if hist is None and red.decoded_frames[k] is not None:
            hist = sample_histogram(red.decoded_frames[k].samples, red.decoded_frames[k].valid)
        if hist is None:
            raise OptionError(f"frame {red.names[k]}: no histogram of its samples for the percentiles: use "
                              f"output_range = white-level", param="--output-range")
        width = (1 << hist.bits) // hist.counts.shape[1]
        edges = np.minimum(np.arange(hist.counts.shape[1] + 1, dtype=np.float32) * width, np.float32(white + 1))
        for b in range(hist.counts.shape[0]):
            counts = hist.counts[b].astype(np.float64)
            sat = hist.saturated(b, int(white))
            jw = int(white) // width
            counts[jw] = max(0.0, counts[jw] - (sat - counts[jw + 1:].sum()))  # saturated: held at white
            counts[jw + 1:] = 0
            v = edges * np.float32(gains[k, b])
            if offsets is not None:
                v += np.float32(offsets[k, b])
            if rolloff is not None:
                rolloff.apply(v)
            if toe is not None:
                toe.apply(v)
            v = np.clip(v, 0, white)
            a, z = np.floor(v[:-1]).astype(np.int64), np.maximum(np.ceil(v[1:]).astype(np.int64), 1)
            z = np.maximum(z, a + 1)
            dens = counts / (z - a)
            np.add.at(cells, a, dens)
            np.add.at(cells, np.minimum(z, len(cells) - 1), -dens)
            cells[int(white)] += sat
            cells[int(white) + 1] -= sat
    density = np.cumsum(cells)[:-1]
    cdf = np.cumsum(density)
    if cdf[-1] <= 0:
        raise OptionError("the frames have no valid sample for the percentiles", param="--output-range")
    lo, hi = (float(np.searchsorted(cdf, p / 100.0 * cdf[-1])) for p in percentiles)
    if hi <= lo:
        hi = lo + 1.0
    return lo, hi


MIN_TILE_PX = 16
# What a mosaic holds per cell of its frames on the seam grid, through the seams and the tiles (the reduced frames,
# their grey values, the seams' cost grids and labels): the peak anonymous memory less what the process held before,
# over the frames' seam cells: (1,944 - 289) MB / 47 M cells = 35 bytes on NGI's 4 frames upsampled to 7,680 x 13,824
# px (a 13,084 x 22,315 px DOM; sampled every 0.2 s). A memory limit sets the seam grid's cells from it.
MOSAIC_BYTES_PER_SEAM_CELL = 40
MIN_SEAM_CELLS = 1_000_000  # the coarsest seam grid a memory limit chooses (about 1,000 x 1,000 cells)


class _PhaseTimer:
    """Wall and CPU time of the phases of a run, logged at debug level (``-v``); with ``trim`` the end of every phase
    also hands the memory it freed back to the system (``release_freed_memory``). A small block (its frames kept
    decoded) is run without: its phases then reuse the memory freed before them instead of faulting in new pages (the
    demo: 166 k -> 131 k minor page faults, 0.1 CPU-s of system time, peak RSS +60 MB)."""

    def __init__(self, trim: bool = True):
        import time

        self.trim = trim
        self._clock = time
        self._t, self._c = time.perf_counter(), time.process_time()

    def done(self, phase: str) -> None:
        if self.trim:
            release_freed_memory()
        t, c = self._clock.perf_counter(), self._clock.process_time()
        logger.debug("mosaic: %s %.2f s (CPU %.2f s)", phase, t - self._t, c - self._c)
        self._t, self._c = t, c


def _import_quietly(importer) -> None:
    """``importer()`` on a thread: an ImportError is left to the code that needs the modules (it imports them again
    and fails there, with the error handling of its own thread), not printed as a thread's traceback."""
    try:
        importer()
    except ImportError:
        pass


def _import_seam_modules() -> None:
    """The path search's modules (``import_path_search``), then the vector writers' (``_import_vector_modules``)."""
    import_path_search()
    _import_vector_modules()


def _import_vector_modules() -> None:
    """Import what the seamline writer imports (``_write_seamlines``, ``write_seamlines_gpkg``), in this thread."""
    import pyogrio  # noqa: F401
    import pyogrio.raw  # noqa: F401
    import shapely  # noqa: F401
    import shapely.geometry  # noqa: F401
    import shapely.ops  # noqa: F401


@contextlib.contextmanager
def _background(fn, *args, imports: bool = True):
    """Run ``fn(*args)`` on a thread; yields a function that waits for its result (raising its error). ``imports``:
    the vector writers' modules are imported in this thread first (False: they are imported, or being imported by a
    thread that is joined before any writer starts: ``_import_seam_modules``)."""
    from concurrent.futures import ThreadPoolExecutor

    # the modules the background writers import are loaded in this thread first: two threads importing shapely at
    # once can meet it half-initialised (ImportError 'partially initialized module shapely.geometry.base' on the
    # 120-frame DMC block)
    if imports:
        _import_vector_modules()

    with ThreadPoolExecutor(1, thread_name_prefix="mosaic-bg") as pool:
        future = pool.submit(fn, *args)
        try:
            yield future.result
        finally:
            future.cancel()


def _ndsm_objects(ndsm_path, index, mosaic: OrthoGrid, transform, shape, object_height_m: float):
    """Objects (buildings, trees: nDSM above ``object_height_m``) on the seam grid, None without an nDSM; the
    nDSM checked first (``_open_checked_ndsm``)."""
    if ndsm_path is None:
        return None
    # one dataset for the check and the reading: the blocks the check's value scan decoded are taken from GDAL's
    # block cache, not decoded again (the demo's nDSM: 0.2 CPU-s a reading)
    with _open_checked_ndsm(ndsm_path, index, mosaic) as ds:
        nd = _read_ndsm_on(ndsm_path, transform, shape, mosaic.crs, index_operation(index), ds=ds)
    return np.nan_to_num(nd, nan=0.0) > object_height_m


def _frame_layout(path) -> tuple[int, int]:
    with _open_frame(path) as ds:
        return ds.count, np.dtype(ds.dtypes[0]).itemsize


def _tile_bytes(tile_px: int, feather_px: float, bands: int, itemsize: int) -> float:
    """Memory of one blended tile (``_blend_tile``): over the tile and its halo the labels, a label mask and
    its blur (4 bytes each); over the tile the accumulator and a frame's samples as float32 (per band),
    weights, weight sum and distances, four frame windows with their masks, and the output samples."""
    side = tile_px + 2 * (math.ceil(2.0 * feather_px) + 64)
    return side * side * 3 * 4 + tile_px * tile_px * (2 * 4 * bands + 3 * 4 + 4 * (bands * itemsize + 1)
                                                         + bands * itemsize + 1)


def _tiles_in_flight(executor) -> int:
    """Tiles held at once: the batch ``_write_mosaic`` hands to the executor (on local threads, the tiles
    computed ahead of the writer: as many)."""
    from aerotri.core.executor import local_executor

    return max(2, 2 * (executor or local_executor()).workers)


def _open_frame(path):
    """A frame ortho opened for reading; an unreadable file is an InputError naming it."""
    try:
        return rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: cannot read the frame ortho ({exc}); re-run ortho rectify") from None


def _mosaic_outputs(work: Path, root: Path, index, frames_dir, *, red, labels, gains, mosaic: OrthoGrid, factor, nadir,
                    feather_px, tile_px, seams, executor, settings_record: dict, previous=None, resume=None,
                    rolloff=None, offsets=None, toe=None, output=None, crossings=None, objects=None,
                    gaps_given=()) -> dict:
    """seams.tif, seamlines.geojson, seamlines.gpkg, mosaic.tif, seamlines_preview.png and mosaic.json into ``work``;
    returns the summary. ``objects``: (nDSM path, object height in m), whose objects the cells no frame sees of a true
    ortho are counted on (``ortho.unseen.unseen_on_objects``). ``previous``
    (``PreviousMosaic``): the mosaic whose tiles away from changed seams are taken over. ``resume``
    (``ResumeFolder``): the rows of tiles an interrupted run finished (``_write_mosaic``)."""
    crs, res = mosaic.crs, mosaic.res_m
    out_dir = root / "ortho"
    # Dask tasks read the labels from seams.tif; local threads have them in memory, and seams.tif is written with
    # the vector files
    distributed = executor is not None and executor.distributed
    if distributed:
        _write_labels(work / "seams.tif", labels, red.transform, crs)

    # the seamlines over the DOM, reduced to at most 2000 px, for a look before opening the GeoPackage: when that is the
    # size of one of the mosaic's levels (the demo's: its first overview), that level is what the preview reads of
    # the COG (the COG copies the levels as they are), and it is read from the stage's files on a thread while the COG
    # is written; else from the COG, on a thread while this one counts the pairs and the nodata inside the block
    step = preview_shape(mosaic.width, mosaic.height)[2]
    levels = [1] + overview_factors(mosaic.width, mosaic.height)
    footprints = [e.footprint_xy_m for e in index.frames]  # the cells no frame sees: hatched as counted
    early = step in levels

    def stage_preview(level_paths):
        write_seamlines_preview(work / "seamlines_preview.png", level_paths[step], labels, factor,
                                mosaic_size=(mosaic.width, mosaic.height), footprints=footprints)

    # the seamlines' polygons and lines (and seams.tif) on a thread while the tiles are blended and written
    with _background(_write_seamlines, work, labels, red.transform, red.names, crs, not distributed) as vectors:
        tiles = _write_mosaic(work / "mosaic.tif", frames_dir, index, mosaic, seams_path=work / "seams.tif",
                              factor=factor, gains=gains, nadir=nadir, feather_px=feather_px, tile_px=tile_px,
                              executor=executor, labels=labels, previous=previous,
                              decoded=red.decoded, holes=frame_holes(red), during_cog=stage_preview if early else None,
                              white_level=red.white_level.value, resume=resume, rolloff=rolloff, offsets=offsets,
                              toe=toe, output=output)
        with _background(functools.partial(write_seamlines_preview, footprints=footprints),
                         work / "seamlines_preview.png", work / "mosaic.tif", labels, factor,
                         imports=False) if not early else contextlib.nullcontext(lambda: None) as preview:
            pairs = [[red.names[i], red.names[j]] for i, j in neighbour_pairs(labels)]
            surfaces = rectified_on(root, index)
            # every frame's ground fully under the surfaces (index.json's height_covered_share, measured by rectify):
            # no cell lacks heights, and the surfaces are not read (0.35 s of the demo's 3 CPU-s mosaic)
            shares = [f.get("height_covered_share") for f in index.document.get("frames", [])]
            covered = bool(shares) and all(v is not None and v >= 1.0 for v in shares)
            nodata = _interior_nodata(work / "mosaic.tif", res, footprints=footprints,
                                      surfaces=() if covered else surfaces,
                                      objects=objects if index.true_ortho else None)
            nodata["surfaces_counted"] = [str(p.relative_to(root)) if p.is_relative_to(root) else str(p)
                                          for p in surfaces]
            nodata["surfaces_cover_every_frame"] = covered  # (then not read: no cell lacks heights)
            preview()
        vectors()
    summary = {"path": str(out_dir / "mosaic.tif"), "width": mosaic.width, "height": mosaic.height,
               "frames": len(red.names), "res_m": res, "seam_factor": factor, "seams": seams, "feather_px": feather_px,
               "index_sha1": index_sha1(root),
               "gains": {n: [float(v) for v in g] for n, g in zip(red.names, gains)},
               "white_level": _white_level_record(red),
               "offsets": _offsets_record(red.names, offsets),
               "highlight_rolloff": None if rolloff is None else rolloff.record(),
               "shadow_toe": None if toe is None else toe.record(),
               "blend_rules": BLEND_RULES, "pairs": pairs, **nodata, "settings": settings_record}
    # a frame the seams give no cell (the others cover its footprint, nearer nadir or with a cheaper seam) has no
    # seamline polygon: named, so that the frames of the mosaic and the polygons of the layer reconcile (trial-gis F4:
    # 18 frames, 17 polygons, nothing said)
    summary["frames_without_cells"] = frames_without_cells(labels, red.names)
    # the frames of ortho/frames left out by the operator ([mosaic] exclude): not in "frames", no polygon
    summary["excluded"] = sorted((settings_record.get("exclude") or {}).get("value") or ())
    if summary["frames_without_cells"]:
        logger.info("%d of %d frames have no cell of the mosaic (the other frames cover theirs), so no seamline "
                    "polygon: %s", len(summary["frames_without_cells"]), len(red.names),
                    ", ".join(summary["frames_without_cells"]))
    if output is not None:
        summary["output"] = _output_record(output, tiles.pop("output_counts"), summary["white_level"])
        o = summary["output"]
        logger.info("8-bit DOM: %s (%s); %.4f %% of its pixels at 255 (of the blended tiles' %.4f %% at white before "
                    "the mapping, %.4f %% clipped by it), %.4f %% at 0", output.formula, output.source,
                    100 * o["share_at_255"], 100 * (o["blended_share_at_white"] or 0.0),
                    100 * (o["clipped_by_mapping_share"] or 0.0), 100 * o["share_at_0"])
    if gaps_given:  # an edited run re-made by the chain: the cells one frame alone sees, given to it
        summary["edited_gaps_given"] = [g.record() for g in gaps_given]
    if crossings is not None:  # an edited run: where its seams cross buildings and trees (ortho.seam_crossings)
        summary["seam_crossings"] = crossings.record()
        if crossings.checked:
            from ortho.seam_crossings import write_crossings_gpkg

            write_crossings_gpkg(work / CROSSINGS_FILE, crossings, crs)
    if previous is not None:
        summary["tiles"] = tiles
        logger.info("edited seamlines: %d of %d tiles blended, %d taken over from the earlier mosaic%s", tiles["blended"],
                    tiles["total"], tiles["taken_over"], f" ({previous.why_all})" if previous.why_all else "")
        if not tiles["blended"]:  # (trial-ortho2: an edit in a layer not read changed nothing, "edited" unsaid)
            logger.warning("the edited seamlines change no cell of the earlier mosaic's seams: the mosaic is the "
                           "earlier one; was the edit saved in the file (and layer) given?")
    if summary["cells_seen_by_no_frame"]:
        # (two significant digits: "1608 cells (0.00 % of the block)" read as none, new-user trial s51)
        pct = 100 * summary["share_seen_by_no_frame"]
        off = 100 * summary["share_without_heights"]
        # (trial s105 F7: "occluded in every frame of a true ortho" said of a conventional DOM)
        why = ("occluded in every frame, over DEM nodata, or over the frames' own nodata" if index.true_ortho
               else "over DEM nodata or the frames' own nodata")
        logger.warning("%d cells (%s %% of the block) are seen by no frame (%s): nodata in the mosaic; %s %% of the "
                       "block where the surface the frames were rectified on has no heights (%s)%s",
                       summary["cells_seen_by_no_frame"], f"{pct:.2f}" if pct >= 0.1 else f"{pct:.2g}", why,
                       f"{off:.2f}" if off >= 0.1 or off == 0 else f"{off:.2g}",
                       ", ".join(Path(p).name for p in summary["surfaces_counted"]) or "none recorded",
                       on_objects_words(summary["cells_on_objects"], summary["cells_seen_by_no_frame"]))
    write_text_atomic(work / "mosaic.json", json.dumps(summary, indent=1) + "\n")
    return summary


def without_frames(index: FrameIndex, exclude, source: str = "--exclude") -> FrameIndex:
    """``index`` without the frames named in ``exclude`` (image ids), its document too (what Dask tasks read);
    OptionError naming an id that is not a frame, or when none would be left (``source``: where the list came from)."""
    drop = set(exclude)
    unknown = [f for f in exclude if f not in index.image_ids]
    if unknown:
        raise OptionError(f"{', '.join(unknown)} ({source}): not a frame of {index.path} ({len(index.frames)} frames, "
                          f"e.g. {', '.join(index.image_ids[:3])})", param="--exclude")
    keep = tuple(e for e in index.frames if e.image_id not in drop)
    if not keep:
        raise OptionError(f"exclude ({source}) leaves out every frame of {index.path}: nothing to mosaic",
                          param="--exclude")
    document = {**index.document,
                "frames": [f for f in index.document.get("frames", []) if f.get("image_id") not in drop]}
    return dataclasses.replace(index, frames=keep, document=document)


def on_objects_words(on_objects: int | None, unseen: int) -> str:
    """The unseen cells on the nDSM's objects, said after the mosaic's warning and in the report's row ("" for none or
    not counted): a frame looks down on a roof, so these are the true ortho's masks at the objects' edges (the LiDAR
    DSM's roofs reach past the walls), not occlusion (trial s98 M1: a third of the tall block's nodata)."""
    if not on_objects or not unseen:
        return ""
    # (the demo: 46,849 of 149,079, 82 % of them on the truth's roofs and crowns, the rest ground the nDSM's wider
    # roofs cover)
    pct = 100 * on_objects / unseen
    # (a share under 1 % with its first significant digit: a block mostly without heights said "18650 of them (0 %)")
    share = f"{pct:.0f}" if pct >= 1 else f"{pct:.1g}"
    return (f"; {on_objects} of them ({share} %) on the nDSM's roofs and crowns, which frames "
            "look down on: most are the true ortho's masks at the objects' edges (the LiDAR DSM's roofs reach past "
            "the walls), not occlusion (docs/true-ortho.md)")


def frames_without_cells(labels: np.ndarray, names: list) -> list:
    """The names of the frames (``names[k]`` of seam label k; -1: no frame) that no seam cell of ``labels`` holds."""
    used = np.zeros(len(names), bool)
    used[np.unique(labels[labels >= 0])] = True
    return [names[i] for i in np.flatnonzero(~used)]


def _output_record(output: OutputMapping, counts: dict, white_record: dict) -> dict:
    """mosaic.json's "output": the 8-bit mapping (``OutputMapping.record``) and what it clipped, counted on the DOM's
    valid pixels (a pixel with any band at 255, or at 0), beside the frames' largest saturated share: the white-level
    mapping clips nothing more than the frames saturate but the values within half an 8-bit step of white."""
    valid, blended = counts["valid"], counts["blended_valid"]
    shares = [v for v in (white_record.get("saturated_share_frames") or {}).values() if v is not None]
    at_white = counts["blended_at_white"] / blended if blended else None
    at_255 = counts["blended_at_255"] / blended if blended else None
    return {"mapping": output.record(), "valid_pixels": valid,
            "share_at_255": counts["at_255"] / valid if valid else 0.0,
            "share_at_0": counts["at_0"] / valid if valid else 0.0,
            # on the tiles this run blended (all of them but an edited run's taken-over ones): the pixels with a
            # band at white before the mapping (saturated in the frames, held there) and at 255 after it; the
            # difference is what the mapping clipped (rounded up from within white / 510 DN of white)
            "blended_pixels": blended, "blended_share_at_white": at_white, "blended_share_at_255": at_255,
            "clipped_by_mapping_share": None if blended == 0 else at_255 - at_white,
            "frames_saturated_share_max": max(shares) if shares else None}


def _white_level_record(red: ReducedFrames) -> dict:
    """mosaic.json's "white_level": the value saturated samples have (the gain limit counts them there, the mosaic is
    clipped to it), how it was found, the frames' largest sample, and per frame its saturated share (its largest
    band's; for
    the frames with a histogram: None for a frame kept decoded whose gains are all <= 1)."""
    white = red.white_level
    shares = {}
    for name, hist in zip(red.names, red.sample_histograms):
        if hist is None or white.value is None:
            shares[name] = None
            continue
        total = hist.counts.sum(axis=1)
        shares[name] = max(float(hist.saturated(b, white.value) / total[b]) if total[b] else 0.0
                           for b in range(hist.counts.shape[0]))
    return {"value": white.value, "bits": white.bits, "from": white.source, "max_sample": white.max_sample,
            "saturated_share_frames": shares}


def _interior_nodata(path: Path, res_m: float, *, footprints=(), surfaces=(), objects=None,
                     max_cells: float = 6.4e7) -> dict:
    """Cells of the mosaic without a value that lie inside the block: enclosed by valid cells (not connected to
    the mosaic's outer edge), or inside the ground a frame images (``footprints``: per frame its ring (x, y) in the
    mosaic's CRS, ``FrameEntry.footprint_xy_m``; None for an index written before it was recorded). The second
    takes what a true ortho's frames do not see where it reaches the block's edge (a forest hidden from oblique
    frames: Tuniu's mosaic lost 40 % of its cells to it and reported 7.6 %). No frame sees them (occluded in every
    frame, or over DEM nodata). Counted on the mask at full resolution up to ``max_cells`` (64 MB), above it on
    the mask read that large (an overview of a large mosaic, scaled to mosaic cells: the overviews' masks close
    small holes, the count is then low; the demo's at half resolution read 91,268 of 138,797 enclosed cells).
    ``surfaces``: the DEM (and a true ortho's DSM) the frames were rectified on: the unseen cells where one has no
    heights are counted apart (``..._without_heights``; Brighton on its cloud's DEM: 44.7 % of the block), and with
    ``objects`` (a true ortho's nDSM path and object height in m) those on the nDSM's roofs and crowns
    (``..._on_objects``, ``ortho.unseen.unseen_on_objects``; None without)."""
    with rasterio.open(path) as ds:
        step = max(1, int(math.ceil(math.sqrt(ds.width * ds.height / max_cells))))
        shape = (max(1, ds.height // step), max(1, ds.width // step))
        ok = ds.read_masks(1, out_shape=shape, resampling=Resampling.nearest) > 0
        sy, sx = ds.height / shape[0], ds.width / shape[1]
        read_transform, crs = ds.transform @ Affine.scale(sx, sy), ds.crs
    unseen = unseen_cells(ok, ~read_transform, footprints)
    holes = int(np.count_nonzero(unseen))
    block = holes + int(np.count_nonzero(ok))
    off = unseen_without_heights(unseen, read_transform, crs, surfaces)
    on_objects = None
    if objects is not None:
        on = unseen_on_objects(unseen, read_transform, crs, objects[0], objects[1])
        on_objects = None if on is None else int(round(on * sx * sy))
    return {"cells_seen_by_no_frame": int(round(holes * sx * sy)), "share_seen_by_no_frame": holes / max(1, block),
            # (below 10 m2 three significant digits: a 1 cm DOM's 0.035 m2 was stored 0.0, "346 cells, 0 m2",
            # trial s100 rc2 L6)
            "area_seen_by_no_frame_m2": _area_digits(holes * sx * sy * res_m * res_m),
            "cells_without_heights": int(round(off * sx * sy)), "share_without_heights": off / max(1, block),
            "cells_on_objects": on_objects}


def _area_digits(a_m2: float) -> float:
    """An area (m2) as mosaic.json stores it: 0.1 m2 from 10 m2 up, three significant digits below."""
    return round(a_m2, 1) if a_m2 >= 10 else float(f"{a_m2:.3g}")


def _write_seamlines(work: Path, labels, transform, names, crs, write_labels: bool = False) -> None:
    """seamlines.gpkg (``write_seamlines_gpkg``) and seamlines.geojson (one polygon per frame, ``frame_region``, and
    the seam lines between neighbours) in ``work``, from one polygonisation of the labels; with ``write_labels``
    seams.tif first."""
    if write_labels:
        _write_labels(work / "seams.tif", labels, transform, crs)
    regions = frame_regions(labels, transform)
    features = label_polygons(labels, transform, names, regions)
    write_seamlines_gpkg(work / "seamlines.gpkg", labels, transform, names, crs, features)
    for f in features:
        f["properties"]["kind"] = "frame_region"
    lines = seam_lines(labels, transform, names, regions)
    for f in lines:
        f["properties"]["kind"] = "seamline"
    geo = {"type": "FeatureCollection", "name": "seamlines", "crs_wkt": crs.to_wkt(),
           "crs": {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{crs.to_epsg()}"}} if crs.to_epsg() else None,
           "features": features + lines}
    write_text_atomic(work / "seamlines.geojson", json.dumps(geo) + "\n")


def index_sha1(root) -> str:
    """sha1 of ``ortho/frames/index.json``: the frames a mosaic (its seams) was made from."""
    import hashlib

    return hashlib.sha1((Path(root) / "ortho" / "frames" / "index.json").read_bytes()).hexdigest()


def mosaic_older_than_frames(root) -> str | None:
    """Why the project's mosaic is not of the frames in ortho/frames now (None: it is, or there is no mosaic or no
    frames): ``ortho rectify`` run since (by hand: the frames' index.json no longer the one mosaic.json records,
    ``index_sha1``; a mosaic.json written before it was recorded: older than index.json). leftovers2: the accuracy
    report described the earlier mosaic after `ortho rectify` by hand, without a word."""
    root = Path(root)
    index, summary = root / "ortho" / "frames" / "index.json", root / "ortho" / "mosaic.json"
    mosaic = root / "ortho" / "mosaic.tif"
    if not (index.is_file() and summary.is_file() and mosaic.is_file()):
        return None
    try:
        recorded = json.loads(summary.read_text()).get("index_sha1")
    except (OSError, ValueError, AttributeError):
        return None  # (the reader of mosaic.json names it)
    if recorded is not None:
        older = recorded != index_sha1(root)
    else:
        older = summary.stat().st_mtime_ns < index.stat().st_mtime_ns
    if not older:
        return None
    return (f"{mosaic} is older than the frames in {index.parent} (ortho rectify ran since the mosaic was made: its "
            f"{summary.name} records other frames)")


@dataclasses.dataclass(frozen=True)
class MosaicTile:
    """One output tile of the mosaic as a Dask task: the shared context file and the tile's window."""

    context_path: str
    row0: int
    col0: int
    height: int
    width: int


@dataclasses.dataclass
class _BlendContext:
    """What every tile needs: the frames (files, offsets (col, row) and sizes (width, height) in the mosaic,
    gains (frames, bands), nadir points in the output CRS), the mosaic grid, the seam grid (``factor``,
    ``read_cells(row, col, h, w)`` of its label raster of ``seam_shape``), the feather and the sample layout."""

    names: list
    files: list
    offsets: np.ndarray
    sizes: np.ndarray
    gains: np.ndarray
    nadir: np.ndarray
    mosaic: OrthoGrid
    factor: int
    halo: int
    feather_px: float
    bands: int
    dtype: str
    read_cells: object
    seam_shape: tuple
    # per frame: None, or its ``FrameHoles`` for a frame whose ortho has holes (a true ortho's occlusion); its pixels
    # within hole_margin_px of a hole are taken only where no other frame has the pixel away from its holes
    # (``_hole_margin``)
    holes: list | None = None
    hole_margin_px: int = 0
    # the frames' white level (``WhiteLevel.value``; None: the type's maximum)
    white_level: int | None = None
    # after the gains, below the white level (``HighlightRolloff``; None: none)
    rolloff: HighlightRolloff | None = None
    # per frame and band the offset (DN) after the gain (None: none), and the toe that keeps what it darkens above
    # black (``ShadowToe``; None: none)
    dn_offsets: np.ndarray | None = None
    toe: ShadowToe | None = None

    @functools.cached_property
    def white(self) -> int | None:
        """The white level 8- and 16-bit samples are clipped to: ``white_level``, else the type's maximum (None: other
        types)."""
        dt = np.dtype(self.dtype)
        if dt not in _HISTOGRAM_TYPES:  # other types are clipped to their range by ``_to_type``
            return None
        top = int(np.iinfo(dt).max)
        return top if self.white_level is None else min(top, int(self.white_level))

    @functools.cached_property
    def hold(self) -> bool:
        """Whether a saturated sample stays at the white level whatever the gain: for every 8- and 16-bit frame (its
        brightness is unknown; a 255 under a gain of 0.98 became 250 beside a neighbour's 255 before i42-clip, while
        12-bit data in 16-bit frames were already held at 4095)."""
        return self.white is not None

    def offset(self, k: int) -> np.ndarray | None:
        """Frame ``k``'s offsets (bands,) float32, None without offsets."""
        return None if self.dn_offsets is None else self.dn_offsets[k].astype(np.float32)

    @functools.cached_property
    def luts(self):
        """Per frame and band the gain (and offset) as a lookup table for 8- and 16-bit samples (None for other
        types): samples clipped to the white level, and (``hold``) a saturated sample stays at it whatever the gain
        (its brightness is unknown: a gain below 1 turned 4095 into 3836 beside a neighbour's 4095), a black one (0)
        at black whatever the offset."""
        dt = np.dtype(self.dtype)
        if dt not in (np.dtype(np.uint8), np.dtype(np.uint16)):
            return None
        top, white = np.iinfo(dt).max, self.white
        x = np.arange(top + 1, dtype=np.float32)
        luts = []
        for k, row in enumerate(self.gains):
            luts.append([])
            for b, g in enumerate(row):
                v = x * np.float32(g)
                if self.dn_offsets is not None:
                    v += np.float32(self.dn_offsets[k, b])
                if self.rolloff is not None:
                    self.rolloff.apply(v)
                if self.toe is not None:
                    self.toe.apply(v)
                lut = np.clip(np.rint(v), 0, white).astype(dt)
                if self.hold:
                    lut[white:] = white
                    lut[0] = 0
                luts[-1].append(lut)
        return luts


def _context_white(dtype, white_level) -> int | None:
    """``_BlendContext.white`` of frames of ``dtype`` and ``white_level``."""
    dt = np.dtype(dtype)
    if dt not in _HISTOGRAM_TYPES:
        return None
    top = int(np.iinfo(dt).max)
    return top if white_level is None else min(top, int(white_level))


def _context(index, frames_dir, mosaic: OrthoGrid, *, factor, halo, gains, nadir, feather_px, bands, dtype, read_cells,
             seam_shape, holes=None, white_level=None, rolloff=None, dn_offsets=None, toe=None) -> _BlendContext:
    grids = index.grids
    names = list(index.image_ids)
    offsets = np.array([g.offset_in(mosaic) for g in grids], np.int64).reshape(-1, 2)
    sizes = np.array([(g.width, g.height) for g in grids], np.int64).reshape(-1, 2)
    files = [str(Path(frames_dir) / e.file) for e in index.frames]
    return _BlendContext(names, files, offsets, sizes, np.asarray(gains, np.float64), np.asarray(nadir, np.float64),
                         mosaic, int(factor), int(halo), float(feather_px), int(bands), str(dtype), read_cells,
                         tuple(seam_shape), holes if hole_margin_px(mosaic.res_m) else None,
                         hole_margin_px(mosaic.res_m) if holes else 0, white_level, rolloff,
                         None if dn_offsets is None else np.asarray(dn_offsets, np.float64), toe)


@functools.lru_cache(maxsize=4)
def _load_context(path: str, mtime_ns: int) -> _BlendContext:
    """The mosaic context (frames, grids, gains, seam raster path), parsed once per worker process."""
    ctx = json.loads(Path(path).read_text())
    index = frame_index(ctx["index"], ctx["index_path"])
    m = ctx["mosaic"]
    mosaic = OrthoGrid(CRS.from_wkt(index.crs_wkt), m["x_left_m"], m["y_top_m"], m["res_m"], m["width"], m["height"])
    seams_path = ctx["seams_path"]
    with rasterio.open(seams_path) as sds:
        seam_shape = (sds.height, sds.width)

    def read_cells(r, c, h, w):
        with rasterio.open(seams_path) as sds:
            return sds.read(1, window=Window(c, r, w, h))

    holes = None
    if ctx.get("holes_path"):
        with np.load(ctx["holes_path"]) as z:
            holes = [FrameHoles.from_arrays(z, k) for k in range(len(index.frames))]
    return _context(index, ctx["frames_dir"], mosaic, factor=ctx["factor"], halo=ctx["halo"], gains=ctx["gains"],
                    nadir=ctx["nadir"], feather_px=ctx["feather_px"], bands=ctx["bands"], dtype=ctx["dtype"],
                    read_cells=read_cells, seam_shape=seam_shape, holes=holes, white_level=ctx.get("white_level"),
                    rolloff=HighlightRolloff(**ctx["rolloff"]) if ctx.get("rolloff") else None,
                    dn_offsets=ctx.get("offsets"), toe=ShadowToe(**ctx["toe"]) if ctx.get("toe") else None)


class _FrameReaders:
    """Open frame datasets per thread (GDAL handles are not shared between threads), the last
    ``_OPEN_FRAMES`` of each thread kept open; ``close`` closes them all (a later run may find other files
    under the same names)."""

    def __init__(self, decoded: dict | None = None):
        self._local = threading.local()
        self._all = []
        self._lock = threading.Lock()
        self._decoded = decoded or {}

    def window(self, path: str, col_off: int, row_off: int, width: int, height: int):
        """``read_planar`` of frame ``path``: from memory when the frame is kept decoded, else from its file."""
        frame = self._decoded.get(path)
        if frame is not None:
            return window_of(frame.samples, frame.valid, col_off, row_off, width, height)
        return read_planar(self.get(path), col_off, row_off, width, height)

    def mask(self, path: str, col_off: int, row_off: int, width: int, height: int) -> np.ndarray:
        """The validity (bool) of a window of frame ``path`` read from its file (the window within the frame)."""
        try:
            return self.get(path).read_masks(1, window=Window(col_off, row_off, width, height)) > 0
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{path}: cannot read the raster (truncated or corrupt? {exc})") from None

    def samples(self, path: str, col_off: int, row_off: int, width: int, height: int) -> np.ndarray:
        """The samples (bands, h, w) of a window of frame ``path`` read from its file (the window within the frame)."""
        try:
            return self.get(path).read(window=Window(col_off, row_off, width, height))
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{path}: cannot read the raster (truncated or corrupt? {exc})") from None

    def decoded(self, path: str) -> DecodedFrame | None:
        """Frame ``path`` decoded in memory, or None (read from its file)."""
        return self._decoded.get(path)

    def get(self, path: str):
        cache = getattr(self._local, "open", None)
        if cache is None:
            cache = self._local.open = collections.OrderedDict()
        ds = cache.get(path)
        if ds is not None:
            cache.move_to_end(path)
            return ds
        ds = _open_frame(path)
        cache[path] = ds
        with self._lock:
            self._all.append(ds)
        if len(cache) > _OPEN_FRAMES:
            cache.popitem(last=False)[1].close()
        return ds

    def close(self):
        with self._lock:
            for ds in self._all:
                ds.close()
            self._all.clear()


def blend_tile_task(tile: MosaicTile):
    """Blend one tile on a Dask worker; returns (pixels (bands, h, w) of the frames' type, validity bool (h, w))."""
    ctx = _load_context(tile.context_path, Path(tile.context_path).stat().st_mtime_ns)
    readers = _FrameReaders()
    try:
        return _blend_tile(ctx, readers, tile.row0, tile.col0, tile.height, tile.width)
    finally:
        readers.close()


def _apply_gain(ctx: _BlendContext, k: int, img: np.ndarray) -> np.ndarray:
    """Frame ``k``'s samples (bands, h, w) through its gains (and offsets), in the frames' type."""
    luts = ctx.luts
    out = np.empty(img.shape, ctx.dtype)
    for b in range(img.shape[0]):
        if luts is None:
            v = img[b] * np.float32(ctx.gains[k, b])
            if ctx.dn_offsets is not None:
                v += np.float32(ctx.dn_offsets[k, b])
            out[b] = _to_type(v, ctx.dtype)
        elif img.dtype == np.uint8:
            cv2.LUT(img[b], luts[k][b], dst=out[b])
        else:
            np.take(luts[k][b], img[b], out=out[b])
    return out


def _gained(samples: np.ndarray, gain, white: int | None, hold: bool, rolloff=None, offset=None,
            toe=None) -> np.ndarray:
    """float32 ``samples`` x ``gain`` (broadcast) + ``offset`` (broadcast; None: none) as ``_BlendContext.luts`` has
    them before rounding: through ``rolloff`` (``HighlightRolloff``, None: none) and ``toe`` (``ShadowToe``, None:
    none), at most ``white`` (None: unclipped), and with ``hold`` ``white`` where the sample is at or above it, 0 where
    it is 0."""
    v = samples * gain
    if offset is not None:
        v += offset
    if white is None:
        return v
    if rolloff is not None:
        rolloff.apply(v)
    if toe is not None:
        toe.apply(v)
    np.minimum(v, np.float32(white), out=v)
    if hold:
        v[np.broadcast_to(samples >= white, v.shape)] = white
        if offset is not None:
            v[np.broadcast_to(samples <= 0, v.shape)] = 0
    return v


def _gained_weighted(samples: np.ndarray, gain: np.float32, weight: np.ndarray, white: int | None,
                     hold: bool, rolloff=None, offset=None, toe=None) -> np.ndarray:
    """``_gained`` x ``weight`` (float32), in the order the weights were always applied (samples x (weight x gain):
    the same bits wherever nothing is clipped or rolled off; + weight x ``offset``)."""
    if offset is not None:
        return _gained(samples, gain, white, hold, rolloff, offset, toe) * weight
    v = samples * (weight * gain)
    if white is None:
        return v
    clip = gain > 1  # (a gain <= 1 takes no sample above the white level)
    if rolloff is not None:
        g = samples * gain
        high = g > np.float32(rolloff.knee)
        if high.any():
            v[high] = rolloff.apply(g[high]) * weight[high]
        clip = False  # the roll-off brings every gained value below white
    if hold or clip:
        sat = samples * gain > np.float32(white) if clip else samples >= white
        if hold and clip:
            sat |= samples >= white
        if sat.any():
            v[sat] = np.float32(white) * weight[sat]
    return v


def _to_type(a: np.ndarray, dtype) -> np.ndarray:
    """float32 samples rounded and clipped into an integer type (as they are for floats)."""
    dt = np.dtype(dtype)
    if dt.kind in "ui":
        info = np.iinfo(dt)
        return np.clip(np.rint(a), info.min, info.max).astype(dt)
    return a.astype(dt)


def _blend_tile(ctx: _BlendContext, readers, r0: int, c0: int, th: int, tw: int):
    """Blend one tile: (samples (bands, th, tw) of the frames' type, validity bool (th, tw)).

    The seam cells of the tile and ``halo`` pixels around it decide: one frame labelled all over them
    (away from every seam) gives its window through its gains; otherwise every labelled frame's weight
    is its label mask at full resolution blurred by the feather (sigma = feather / 2), times its validity,
    and pixels no weight reaches (no frame labelled there: the edge of the block) take the valid frame of
    the nearest nadir point.

    A frame is read, and its weight computed, only over the box of the tile its weight reaches (the blur's
    support): the tile's other frames are not decoded there (``_weight_boxes``; the same samples as over the
    whole tile)."""
    f, halo = ctx.factor, ctx.halo
    sh, sw = ctx.seam_shape
    lr = np.clip(np.arange(r0 - halo, r0 + th + halo) // f, 0, sh - 1)
    lc = np.clip(np.arange(c0 - halo, c0 + tw + halo) // f, 0, sw - 1)
    rl, cl = int(lr[0]), int(lc[0])
    cells = np.asarray(ctx.read_cells(rl, cl, int(lr[-1]) + 1 - rl, int(lc[-1]) + 1 - cl))
    present = np.flatnonzero(np.bincount(cells.ravel() + 1)) - 1  # the labels there, ascending (-1: none)
    labelled = present[present >= 0]
    fc, fr = ctx.offsets[:, 0], ctx.offsets[:, 1]
    reads = {}
    whole = {}  # frame k read from its file -> ``_TileFrame``
    raw = {}

    def frame(k, y0=0, y1=th, x0=0, x1=tw):
        """Frame k's samples and validity over rows y0:y1, columns x0:x1 of the tile (a frame with holes: valid
        away from them; its validity itself in ``raw``)."""
        key = (k, y0, y1, x0, x1)
        if key not in reads:
            if readers.decoded(ctx.files[k]) is None:
                # read from its file: once for the tile, whatever boxes of it the weights and the fill ask for
                reads[key], raw[key] = tile_frame(k).box(y0, y1, x0, x1)
            elif ctx.holes is not None and ctx.holes[k] is not None:
                reads[key], raw[key] = _hole_margin(ctx, readers, k, row=r0 + y0, col=c0 + x0, h=y1 - y0, w=x1 - x0)
            else:
                reads[key] = readers.window(ctx.files[k], c0 + x0 - int(fc[k]), r0 + y0 - int(fr[k]), x1 - x0,
                                            y1 - y0)
        return reads[key]

    def tile_frame(k):
        """Frame k read from its file for this tile (``_TileFrame``: its masks now, its samples when asked for); None
        for a frame kept decoded."""
        if readers.decoded(ctx.files[k]) is not None:
            return None
        if k not in whole:
            whole[k] = _TileFrame(ctx, readers, k, r0=r0, c0=c0, th=th, tw=tw)
        return whole[k]

    def holes_near(k, row, col, h, w):
        """Frame k's hole pixels over the mosaic window (row, col, h, w) from its tile read (None: not read so)."""
        return whole[k].holes(row - r0, col - c0, h, w) if k in whole else None

    if len(labelled) == 1 and present[0] >= 0:
        k = int(labelled[0])
        img, m = frame(k)
        if m.all():  # labelled cells are valid all over (seam grid validity is the minimum over the cell)
            return _apply_gain(ctx, k, img), m
        # a frame with holes here (a true ortho): its weight is 1 all over the tile, so the blend below would give its
        # samples where it is valid away from them, and fill the rest (``_fill_nearest``)
        out = np.zeros((ctx.bands, th, tw), np.dtype(ctx.dtype))
        np.copyto(out, _apply_gain(ctx, k, img), where=m[None])
        valid = m.copy()
        _fill_nearest(ctx, readers, frame, raw, np.flatnonzero(~m), r0=r0, c0=c0, th=th, tw=tw, out=out, valid=valid,
                      holes_near=holes_near, tile_frame=tile_frame)
        return out, valid
    bands = ctx.bands
    ks = labelled.tolist()
    boxes = _weight_boxes(ctx, cells, ks, dr=r0 - rl * f, dc=c0 - cl * f, lr=lr - rl, lc=lc - cl, th=th, tw=tw)
    out = np.zeros((bands, th, tw), np.dtype(ctx.dtype))
    valid = np.zeros((th, tw), bool)
    one = np.float32(1.0 - 1e-4)
    for k, (y0, y1, x0, x1, wt) in zip(ks, boxes):
        # the weights sum to at most 1 (blurred masks of disjoint labels): where one frame holds all but 1e-4
        # of it the pixel is that frame's sample through its gain, as away from the seams; the blend
        # below only runs in the feather zone
        if wt is None:
            continue
        sel = wt >= one
        rows = np.flatnonzero(sel.any(axis=1))
        if not len(rows):
            continue
        ra, rb = int(rows[0]), int(rows[-1]) + 1
        img, m = frame(k, y0, y1, x0, x1)
        sel = sel[ra:rb] & m[ra:rb]
        np.copyto(out[:, y0 + ra:y0 + rb, x0:x1], _apply_gain(ctx, k, img[:, ra:rb]), where=sel[None])
        valid[y0 + ra:y0 + rb, x0:x1] |= sel
    mixed = ~valid
    if mixed.any():
        # the feather zone, box by box (``_mixed_boxes``: a few dense windows round the seams instead of a gather and
        # scatter of every pixel): per pixel the same sums in the same frame order as over the pixels one by one
        wsum = np.zeros((th, tw), np.float32)
        for ya, yb, xa, xb in _mixed_boxes(mixed):
            acc = np.zeros((bands, yb - ya, xb - xa), np.float32)
            for k, (y0, y1, x0, x1, wt) in zip(ks, boxes):
                iy0, iy1, ix0, ix1 = max(y0, ya), min(y1, yb), max(x0, xa), min(x1, xb)
                if wt is None or iy1 <= iy0 or ix1 <= ix0:
                    continue
                w = wt[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
                if not w.any():  # the weight adds nothing here
                    continue
                img, m = frame(k, y0, y1, x0, x1)
                wk = w * m[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
                wsum[iy0:iy1, ix0:ix1] += wk
                g, o = ctx.gains[k].astype(np.float32), ctx.offset(k)
                for b in range(bands):
                    acc[b, iy0 - ya:iy1 - ya, ix0 - xa:ix1 - xa] += \
                        _gained_weighted(img[b, iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0], g[b], wk, ctx.white,
                                         ctx.hold, ctx.rolloff, None if o is None else o[b], ctx.toe)
            ws = wsum[ya:yb, xa:xb]
            put = mixed[ya:yb, xa:xb] & (ws > 1e-3)
            acc /= np.maximum(ws, 1e-6)
            np.copyto(out[:, ya:yb, xa:xb], _to_type(acc, ctx.dtype), where=put[None])
            valid[ya:yb, xa:xb] |= put
        # pixels of the feather zone no weight reaches (no frame labelled there: the edge of the block; a true ortho's
        # holes and their margin)
        need = np.flatnonzero(mixed & ~(wsum > 1e-3))
        if len(need):
            _fill_nearest(ctx, readers, frame, raw, need, r0=r0, c0=c0, th=th, tw=tw, out=out, valid=valid,
                          holes_near=holes_near, tile_frame=tile_frame)
    return out, valid


def _fill_nearest(ctx: _BlendContext, readers, frame, raw: dict, need: np.ndarray, *, r0: int, c0: int, th: int,
                  tw: int, out: np.ndarray, valid: np.ndarray, holes_near=None, tile_frame=None) -> None:
    """Fill the tile's pixels ``need`` (flat indices; ascending) in ``out`` and ``valid`` from the valid frame of the
    nearest nadir point (distances in float64; of equal ones the first frame), a frame with holes valid away from
    them; pixels every frame has only near its holes from the frame that has them farthest from its holes
    (``_hole_distance_px``), of equal distances the nearest nadir point. ``frame(k, y0,
    y1, x0, x1)``: the tile's reading of frame k (its validity away from holes), ``raw``: the validity of such
    readings of frames with holes. A frame decoded in memory is looked up at the pixels, no window copied; a frame
    read from its file is read over the box of the pixels. ``holes_near(k, row, col, h, w)``: frame k's hole pixels
    over a mosaic window as the tile found them (None: not found, ``_hole_distance_px`` reads the frame);
    ``tile_frame(k)``: frame k's ``_TileFrame`` (None: kept decoded), whose samples are decoded only for a frame that
    fills a pixel."""
    rows, cols = np.divmod(need, tw)
    ya, yb, xa, xb = int(rows[0]), int(rows[-1]) + 1, int(cols.min()), int(cols.max()) + 1
    ys = ctx.mosaic.y_top_m - (r0 + rows + 0.5) * ctx.mosaic.res_m
    xs = ctx.mosaic.x_left_m + (c0 + cols + 0.5) * ctx.mosaic.res_m
    fc, fr = ctx.offsets[:, 0], ctx.offsets[:, 1]
    over = np.flatnonzero((fc < c0 + tw) & (fc + ctx.sizes[:, 0] > c0) & (fr < r0 + th) & (fr + ctx.sizes[:, 1] > r0))
    best = np.full(len(need), np.inf)
    winner = np.full(len(need), -1, np.int64)
    sources = {}

    def has_holes(k):
        return ctx.holes is not None and ctx.holes[k] is not None

    def source(k):
        """(samples (bands, n), validity away from holes (n,), validity (n,): flat arrays of a window of the frame, row
        and column of its first element in the tile, its width)."""
        if k not in sources:
            d = readers.decoded(ctx.files[k])
            if d is not None and (not has_holes(k) or d.away is not None):
                img, away, ok = d.samples, (d.away if has_holes(k) else d.valid), d.valid
                y0, x0 = int(fr[k]) - r0, int(fc[k]) - c0
            else:  # read over the box of the pixels within the frame's grid
                y0, x0 = max(ya, int(fr[k]) - r0), max(xa, int(fc[k]) - c0)
                y1, x1 = min(yb, int(fr[k] + ctx.sizes[k, 1]) - r0), min(xb, int(fc[k] + ctx.sizes[k, 0]) - c0)
                tf = None if tile_frame is None else tile_frame(k)
                if tf is not None:  # its masks now, its samples only if it wins a pixel (``samples_of``)
                    away, ok = tf.masks(y0, y1, x0, x1)
                    img = functools.partial(tf.box, y0, y1, x0, x1)
                else:
                    img, away = frame(k, y0, y1, x0, x1)
                    ok = raw.get((k, y0, y1, x0, x1), away)
                    img = np.ascontiguousarray(img)
                away, ok = np.ascontiguousarray(away), np.ascontiguousarray(ok)
            w = away.shape[1]
            sources[k] = [img.reshape(img.shape[0], -1) if isinstance(img, np.ndarray) else img, away.ravel(),
                          ok.ravel(), y0, x0, w]
        return sources[k]

    def samples_of(src):
        """The flat samples (bands, n) of a source, decoded now if they were left for later."""
        if not isinstance(src[0], np.ndarray):
            img = np.ascontiguousarray(src[0]()[0][0])
            src[0] = img.reshape(img.shape[0], -1)
        return src[0]

    def inside(k):
        """The pixels (indices into ``need``) inside frame k's grid (rows ascending: a range of them)."""
        y0, x0 = int(fr[k]) - r0, int(fc[k]) - c0
        a, b = np.searchsorted(rows, [y0, y0 + int(ctx.sizes[k, 1])])
        c = cols[a:b]
        return a + np.flatnonzero((c >= x0) & (c < x0 + int(ctx.sizes[k, 0])))

    def at(src, sub):
        """Flat positions in ``src``'s arrays of the pixels ``sub``."""
        return (rows[sub] - src[3]) * src[5] + (cols[sub] - src[4])

    def take_nearer(k, sub, away):
        """Frame k where it is valid at the pixels ``sub`` and its nadir point nearer than the best so far."""
        if not len(sub):  # (a frame read from its file is not read for no pixel)
            return
        src = source(k)
        sub = sub[(src[1] if away else src[2]).take(at(src, sub))]
        d = np.hypot(xs[sub] - ctx.nadir[k, 0], ys[sub] - ctx.nadir[k, 1])
        better = d < best[sub]
        sub = sub[better]
        best[sub] = d[better]
        winner[sub] = k

    for k in over.tolist():
        take_nearer(k, inside(k), True)
    got = winner >= 0
    if not got.all():
        # pixels every frame has only near its holes: the valid frame whose pixel lies farthest from its own holes
        # (its mask's edge errs there: ghosts lie within a cell of it), of equal distances the nearest nadir point
        far = np.full(len(need), -1.0)
        for k in over.tolist():
            if has_holes(k):
                sub = inside(k)
                sub = sub[~got[sub]]
                if not len(sub):
                    continue
                src = source(k)
                sub = sub[src[2].take(at(src, sub))]
                if not len(sub):
                    continue
                dh = _hole_distance_px(ctx, readers, k, rows[sub] + r0, cols[sub] + c0,
                                       holes_near=None if holes_near is None else functools.partial(holes_near, k))
                d = np.hypot(xs[sub] - ctx.nadir[k, 0], ys[sub] - ctx.nadir[k, 1])
                better = (dh > far[sub]) | ((dh == far[sub]) & (d < best[sub]))
                sub = sub[better]
                far[sub], best[sub], winner[sub] = dh[better], d[better], k
        got = winner >= 0
    flat_out = out.reshape(out.shape[0], -1)
    for k in np.flatnonzero(np.bincount(winner[got])).tolist():  # the winning frames, ascending
        sub = np.flatnonzero(winner == k)
        src = source(k)
        o = ctx.offset(k)
        fill = _gained(samples_of(src).take(at(src, sub), axis=1), ctx.gains[k].astype(np.float32)[:, None], ctx.white,
                       ctx.hold, ctx.rolloff, None if o is None else o[:, None], ctx.toe)
        flat_out[:, need[sub]] = _to_type(fill, ctx.dtype)
    valid.ravel()[need[got]] = True


# a true ortho's frame is taken this far from its holes only where no other frame has the pixel away from its own:
# the DSM places a roof edge to within about a cell (on its grid, interpolated), so the ground just beyond the
# occluded area of a frame may still show the wall or roof (on the demo, with the LiDAR DSM, most of the ghost pixels
# lay within one cell of what the frame sees: bench/results/true_ortho_occlusion.json)
HOLE_MARGIN_M = 0.8


def hole_margin_px(res_m: float) -> int:
    """``HOLE_MARGIN_M`` in mosaic pixels (at least 1; 0 when it is 0: no margin)."""
    return max(1, int(round(HOLE_MARGIN_M / res_m))) if HOLE_MARGIN_M > 0 else 0


@dataclasses.dataclass(frozen=True)
class FrameHoles:
    """Where a frame's ortho has holes: its invalid pixels that its valid pixels enclose (4-connected: a true ortho's
    occlusion, DEM nodata inside the frame), found at pixel level and kept per seam cell of the frame's window:
    ``cells`` (h, w) uint8, 0 a cell without hole pixels, 1 every invalid pixel of the cell a hole, 2 some of them
    (the holes are then ``partial[partial_index[r, c]]``, (factor, factor) bool); ``offset`` (row, col) of its first
    seam cell in the mosaic's seam grid. The seam grid's own holes (``ortho.seamlines.covered``) miss a hole the
    frame's edge cells, partly valid and so invalid on the seam grid, join to the outside."""

    offset: tuple
    cells: np.ndarray
    partial_index: np.ndarray
    partial: np.ndarray

    def pixels(self, ok: np.ndarray, row: int, col: int, factor: int) -> np.ndarray:
        """The hole pixels (bool) of the mosaic window of ``ok.shape`` at pixel (row, col); ``ok`` the frame's
        validity there. Built over the box of the window's cells with holes (slices, no per-pixel gather: a mosaic
        tile reads every frame over it with this)."""
        h, w = ok.shape
        hole = np.zeros((h, w), bool)
        ch, cw = self.cells.shape
        r0, c0 = max(0, row // factor - self.offset[0]), max(0, col // factor - self.offset[1])
        r1 = min(ch, (row + h - 1) // factor - self.offset[0] + 1)
        c1 = min(cw, (col + w - 1) // factor - self.offset[1] + 1)
        if r1 <= r0 or c1 <= c0:
            return hole
        sub = self.cells[r0:r1, c0:c1]
        rs, cs = np.nonzero(sub)
        if not len(rs):
            return hole
        # the box of the cells with holes, in the window's pixels (y0, x0 its first pixel; may lie before the window)
        ra, rb, ca, cb = int(rs.min()), int(rs.max()) + 1, int(cs.min()), int(cs.max()) + 1
        y0 = (self.offset[0] + r0 + ra) * factor - row
        x0 = (self.offset[1] + c0 + ca) * factor - col
        box = sub[ra:rb, ca:cb]
        all_holes = np.repeat(np.repeat(box == 1, factor, axis=0), factor, axis=1)
        # cells with some of their invalid pixels holes: their bits, all at once (the cells are disjoint from those
        # whose invalid pixels are all holes)
        bits = np.zeros(all_holes.shape, bool)
        ii, jj = np.nonzero(box == 2)
        bits.reshape(rb - ra, factor, cb - ca, factor)[ii, :, jj, :] = \
            self.partial[self.partial_index[r0 + ra + ii, c0 + ca + jj]]
        ya, yb, xa, xb = max(0, y0), min(h, y0 + all_holes.shape[0]), max(0, x0), min(w, x0 + all_holes.shape[1])
        hole[ya:yb, xa:xb] = (all_holes[ya - y0:yb - y0, xa - x0:xb - x0] & ~ok[ya:yb, xa:xb]) \
            | bits[ya - y0:yb - y0, xa - x0:xb - x0]
        return hole

    def _arrays(self, k: int) -> dict:
        """The arrays of frame ``k``'s holes under names ending in ``_k`` (a context file for Dask workers)."""
        return {f"holes_offset_{k}": np.asarray(self.offset), f"holes_cells_{k}": self.cells,
                f"holes_index_{k}": self.partial_index, f"holes_partial_{k}": self.partial}

    @classmethod
    def from_arrays(cls, z, k: int) -> FrameHoles | None:
        if f"holes_cells_{k}" not in z:
            return None
        return cls(tuple(int(v) for v in z[f"holes_offset_{k}"]), z[f"holes_cells_{k}"], z[f"holes_index_{k}"],
                   z[f"holes_partial_{k}"])


def _inside_footprint(ring, shape, mosaic: OrthoGrid, row0: int, col0: int) -> np.ndarray | None:
    """bool ``shape``: the pixels of a window of the mosaic (its first pixel at mosaic row ``row0``, column ``col0``)
    inside a frame's footprint ``ring`` ((x, y) in the mosaic's CRS; None: not recorded, None returned), one pixel in
    (the frame ortho's last pixel along its image's edge may be empty: no sample to interpolate from; as
    ``ortho.unseen``)."""
    if not ring:
        return None
    xy = np.asarray(ring, float)
    col = (xy[:, 0] - mosaic.x_left_m) / mosaic.res_m - col0
    row = (mosaic.y_top_m - xy[:, 1]) / mosaic.res_m - row0
    inside = np.zeros(shape, np.uint8)
    # fillPoly takes a pixel whose centre the ring holds; pixel corners -> centres
    pts = np.round(np.stack([col - 0.5, row - 0.5], axis=-1) * 16).astype(np.int32)
    cv2.fillPoly(inside, [pts], 1, lineType=cv2.LINE_8, shift=4)
    return cv2.erode(inside, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)


def find_holes(invalid: np.ndarray, factor: int, offset, strip_cells: int = 256,
               inside: np.ndarray | None = None) -> FrameHoles | None:
    """The holes of a frame (``FrameHoles``) from ``invalid`` (uint8 (h * factor + 2, w * factor + 2): 1 an invalid
    pixel of its window on whole seam cells, 0 a valid one, framed by 1s; overwritten); None when it has none. An
    invalid pixel is a hole when valid ones enclose it or, with ``inside`` (bool, ``invalid``'s shape: the frame's
    footprint on the ground), when it lies inside the footprint: a true ortho's occlusion that reaches the frame's
    edge is joined to the outside, yet its rim errs as an enclosed one's does."""
    cv2.floodFill(invalid, None, (0, 0), 2)  # the invalid pixels joined to the outside (4-connected) become 2
    if inside is not None:
        invalid[(invalid == 2) & inside] = 1
    if not (invalid == 1).any():  # a conventional ortho: no hole
        return None
    h, w = (invalid.shape[0] - 2) // factor, (invalid.shape[1] - 2) // factor
    px = invalid[1:-1, 1:-1]
    cells = np.zeros((h, w), np.uint8)
    for s in range(0, h, strip_cells):  # by strips of rows
        n = min(strip_cells, h - s)
        # the pixels are 0 (valid), 1 (a hole) or 2 (joined to the outside): OR over a cell sets bit 1 when it has a
        # hole pixel, bit 2 when it has an outside one
        found = _cells_reduce(px[s * factor:(s + n) * factor], factor, np.bitwise_or)
        cells[s:s + n] = np.where(found & 1, np.where(found & 2, 2, 1), 0)
    if not cells.any():
        return None
    rs, cs = np.nonzero(cells == 2)
    partial_index = np.full((h, w), -1, np.int32)
    partial_index[rs, cs] = np.arange(len(rs), dtype=np.int32)
    step = np.arange(factor)
    partial = px[(rs[:, None] * factor + step)[:, :, None], (cs[:, None] * factor + step)[:, None, :]] == 1
    return FrameHoles(tuple(int(v) for v in offset), cells, partial_index, partial)


def frame_holes(red: ReducedFrames) -> list | None:
    """Per frame None, or its ``FrameHoles`` when its ortho has holes; None when no frame has any (a conventional
    ortho: the blending is as before)."""
    holes = getattr(red, "holes", None)
    return holes if holes and any(h is not None for h in holes) else None


def _hole_margin(ctx: _BlendContext, readers, k: int, *, row: int, col: int, h: int, w: int):
    """Frame k's (samples, validity away from its holes) and its validity over the mosaic window (row, col, h, w):
    the hole pixels are those of ``FrameHoles``, found at pixel level; the validity is cleared within
    ``ctx.hole_margin_px`` of them (read with that halo, so that the result does not depend on the window)."""
    m_px = ctx.hole_margin_px
    fc, fr = int(ctx.offsets[k, 0]), int(ctx.offsets[k, 1])
    frame = readers.decoded(ctx.files[k])
    if frame is not None and frame.away is not None:  # the frame's validity away from its holes made once, whole
        img, ok = window_of(frame.samples, frame.valid, col - fc, row - fr, w, h)
        return (img, mask_window(frame.away, col - fc, row - fr, w, h)), ok
    img, ok = readers.window(ctx.files[k], col - m_px - fc, row - m_px - fr, w + 2 * m_px, h + 2 * m_px)
    hole = ctx.holes[k].pixels(ok, row - m_px, col - m_px, ctx.factor)
    inner = (slice(m_px, m_px + h), slice(m_px, m_px + w))
    valid = ok[inner]
    if not hole.any():
        return (img[:, inner[0], inner[1]], valid), valid
    near = cv2.dilate(hole.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * m_px + 1,) * 2))
    return (img[:, inner[0], inner[1]], valid & (near[inner] == 0)), valid


class _TileFrame:
    """A frame read from its file once for a mosaic tile: over the tile's part of the frame's grid, with a halo of
    ``hole_margin_px`` + 1 for a frame with holes (what ``_hole_margin`` and ``_hole_distance_px`` look at around a
    pixel); ``row``, ``col`` its first pixel in the tile. ``valid`` (h, w) bool; for a frame with holes ``hole`` (its
    hole pixels, ``FrameHoles.pixels``) and ``away`` (valid and not within the hole margin of a hole), else None; the
    samples (bands, h, w) decoded only when asked for (a frame the fill looks at may give it no pixel). Every box of the
    tile cut from it has the samples and masks a read of that box alone gives: each is a function of the pixel and of
    the pixels within the margin (a hole pixel of the cells and the pixel's own validity; the margin a dilation by
    ``hole_margin_px``), and beyond the frame's grid nothing is valid or a hole."""

    def __init__(self, ctx: _BlendContext, readers, k: int, *, r0: int, c0: int, th: int, tw: int):
        holes = ctx.holes[k] if ctx.holes is not None else None
        halo = ctx.hole_margin_px + 1 if holes is not None else 0
        fc, fr = int(ctx.offsets[k, 0]), int(ctx.offsets[k, 1])
        fw, fh = int(ctx.sizes[k, 0]), int(ctx.sizes[k, 1])
        # the tile and its halo within the frame's grid, in tile pixels
        ya, yb = max(-halo, fr - r0), min(th + halo, fr + fh - r0)
        xa, xb = max(-halo, fc - c0), min(tw + halo, fc + fw - c0)
        yb, xb = max(ya, yb), max(xa, xb)
        self.row, self.col = ya, xa
        self.reach = (-halo, th + halo, -halo, tw + halo)  # where this read looked (tile pixels)
        self._read = (readers, ctx.files[k], c0 + xa - fc, r0 + ya - fr, xb - xa, yb - ya)
        self._samples = None if yb > ya and xb > xa else np.zeros((ctx.bands, 0, 0), np.dtype(ctx.dtype))
        ok = readers.mask(*self._read[1:]) if self._samples is None else np.zeros((0, 0), bool)
        self.valid, self.hole, self.away = ok, None, None
        if holes is None:
            return
        hole = holes.pixels(ok, r0 + ya, c0 + xa, ctx.factor) if ok.size else ok.copy()
        away = ok
        rows, cols = np.flatnonzero(hole.any(axis=1)), np.flatnonzero(hole.any(axis=0))
        if len(rows):
            # dilated only over the box of the hole pixels and the margin round it: nothing beyond is near a hole
            m_px = ctx.hole_margin_px
            a, b = max(0, int(rows[0]) - m_px), min(hole.shape[0], int(rows[-1]) + 1 + m_px)
            c, d = max(0, int(cols[0]) - m_px), min(hole.shape[1], int(cols[-1]) + 1 + m_px)
            near = cv2.dilate(np.ascontiguousarray(hole[a:b, c:d]).view(np.uint8),
                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * m_px + 1,) * 2))
            away = ok.copy()
            away[a:b, c:d] &= near == 0
        self.hole, self.away = hole, away

    @property
    def samples(self) -> np.ndarray:
        if self._samples is None:
            readers, path, col, row, w, h = self._read
            self._samples = readers.samples(path, col, row, w, h)
        return self._samples

    def masks(self, y0: int, y1: int, x0: int, x1: int):
        """(validity away from holes, validity) over rows y0:y1, columns x0:x1 of the tile (copies)."""
        ok = mask_window(self.valid, x0 - self.col, y0 - self.row, x1 - x0, y1 - y0)
        return (ok if self.away is None else mask_window(self.away, x0 - self.col, y0 - self.row, x1 - x0, y1 - y0)), ok

    def box(self, y0: int, y1: int, x0: int, x1: int):
        """((samples, validity away from holes), validity) over rows y0:y1, columns x0:x1 of the tile (copies)."""
        away, ok = self.masks(y0, y1, x0, x1)
        img = window_of(self.samples, self.valid, x0 - self.col, y0 - self.row, x1 - x0, y1 - y0)[0]
        return (img, away), ok

    def holes(self, y0: int, x0: int, h: int, w: int) -> np.ndarray | None:
        """The hole pixels over h x w tile pixels from (y0, x0) (None: a frame without holes, or the window reaches
        beyond the tile's halo, where this read did not look)."""
        ry0, ry1, rx0, rx1 = self.reach
        if self.hole is None or y0 < ry0 or x0 < rx0 or y0 + h > ry1 or x0 + w > rx1:
            return None
        return mask_window(self.hole, x0 - self.col, y0 - self.row, w, h)


def _hole_distance_px(ctx: _BlendContext, readers, k: int, rows: np.ndarray, cols: np.ndarray,
                      holes_near=None) -> np.ndarray:
    """The distance (px, float32: OpenCV's 3 x 3 L2 mask, to 0.01 px) of the mosaic pixels (``rows``, ``cols``) from
    frame k's nearest hole pixel (``FrameHoles``), seen within ``ctx.hole_margin_px`` + 1 of them (farther: that
    bound). ``holes_near(row, col, h, w)``: the hole pixels of a mosaic window found already (the tile's read of the
    frame), or None (found here)."""
    m_px = ctx.hole_margin_px + 1
    fc, fr = int(ctx.offsets[k, 0]), int(ctx.offsets[k, 1])
    ya, yb, xa, xb = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
    h, w = yb - ya + 2 * m_px, xb - xa + 2 * m_px
    hole = None if holes_near is None else holes_near(ya - m_px, xa - m_px, h, w)
    if hole is None:
        frame = readers.decoded(ctx.files[k])
        if frame is not None:
            ok = mask_window(frame.valid, xa - m_px - fc, ya - m_px - fr, w, h)
        else:
            ok = readers.window(ctx.files[k], xa - m_px - fc, ya - m_px - fr, w, h)[1]
        hole = ctx.holes[k].pixels(ok, ya - m_px, xa - m_px, ctx.factor)
    d = _chamfer_at((~hole).view(np.uint8), rows - ya + m_px, cols - xa + m_px, m_px)
    # (capped before rounding: a window without a hole pixel holds OpenCV's largest distance)
    return np.minimum(np.round(np.minimum(d, np.float32(m_px + 1)), 2), np.float32(m_px)).astype(np.float32)


# OpenCV's 3 x 3 mask for DIST_L2: a step across costs this much (and 1.3693 diagonally), the least per pixel of
# Chebyshev distance
_CHAMFER_STEP = 0.955
# (0.955 n + 1.3693 m) * 1e4 is 50 mod 100 (x.xx5: a rounding boundary at 0.01) only for m = 0 or m >= 50 diagonal steps
_CHAMFER_EXACT_PX = 50 * 1.3693


def _chamfer_at(free: np.ndarray, rows: np.ndarray, cols: np.ndarray, reach_px: float, block_px: int = 128):
    """``cv2.distanceTransform(free, cv2.DIST_L2, 3)[rows, cols]`` (float32) wherever that is at most ``reach_px``
    (elsewhere more than it), computed only round the blocks of ``block_px`` holding the pixels: the 3 x 3 chamfer
    distance to the nearest zero of ``free`` is the length of a path within the box of the two pixels, so a window
    holding every pixel within ``reach_px`` / ``_CHAMFER_STEP`` of a block gives its pixels the same distance as the
    whole array. OpenCV adds the steps in float32, in an order that depends on the window: a distance n a + m b may
    differ in its last bits (a few ulps; the straight ones, m = 0, are summed alike in any window), never by 1e-4, so it
    rounds to 0.01 the same: a value n a + m b with 0 < m < 50 (under ``_CHAMFER_EXACT_PX``) lies at least 1e-4 from a
    rounding boundary. A longer reach is computed over the whole array."""
    h, w = free.shape
    margin = int(reach_px / _CHAMFER_STEP) + 1
    if len(rows) == 0 or reach_px >= _CHAMFER_EXACT_PX or (h <= block_px + 2 * margin and w <= block_px + 2 * margin):
        return cv2.distanceTransform(free, cv2.DIST_L2, 3)[rows, cols]
    out = np.empty(len(rows), np.float32)
    nb = -(-w // block_px)
    block = (rows // block_px) * nb + cols // block_px
    order = np.argsort(block, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(block[order]) != 0])
    for s, e in zip(starts.tolist(), np.r_[starts[1:], len(order)].tolist()):
        idx = order[s:e]
        br, bc = divmod(int(block[idx[0]]), nb)
        y0, x0 = max(0, br * block_px - margin), max(0, bc * block_px - margin)
        y1, x1 = min(h, (br + 1) * block_px + margin), min(w, (bc + 1) * block_px + margin)
        d = cv2.distanceTransform(np.ascontiguousarray(free[y0:y1, x0:x1]), cv2.DIST_L2, 3)
        out[idx] = d[rows[idx] - y0, cols[idx] - x0]
    return out


def _mixed_boxes(mask: np.ndarray, strip_px: int = 64, gap_px: int = 32) -> list:
    """Disjoint boxes (y0, y1, x0, x1) that hold every set pixel of ``mask`` (h, w): per strip of ``strip_px`` rows, the
    runs of columns with a set pixel (runs closer than ``gap_px`` joined), cut to their rows with one."""
    out = []
    h = mask.shape[0]
    for ya in range(0, h, strip_px):
        yb = min(h, ya + strip_px)
        cols = np.flatnonzero(mask[ya:yb].any(axis=0))
        if not len(cols):
            continue
        cut = np.flatnonzero(np.diff(cols) > gap_px)
        for xa, xb in zip(np.r_[cols[0], cols[cut + 1]].tolist(), (np.r_[cols[cut], cols[-1]] + 1).tolist()):
            rows = np.flatnonzero(mask[ya:yb, xa:xb].any(axis=1))
            out.append((ya + int(rows[0]), ya + int(rows[-1]) + 1, xa, xb))
    return out


def _weight_boxes(ctx: _BlendContext, cells: np.ndarray, ks: list, *, dr: int, dc: int, lr: np.ndarray, lc: np.ndarray,
                  th: int, tw: int) -> list:
    """Per labelled frame of ``ks``: (y0, y1, x0, x1, weight (y1 - y0, x1 - x0) float32) over the box of the tile
    where its weight (its label mask in ``cells`` blurred by the feather) is not 0, or (0, 0, 0, 0, None) where it
    is 0 all over the tile. ``dr``, ``dc``: the tile's first pixel in the cells' pixel grid; ``lr``, ``lc``: the cell
    of each pixel of the tile and its halo (row, column of ``cells``).

    With a feather of a seam cell or more the blur runs on the seam grid and is interpolated (bilinear) to the
    pixels (the mask is constant over each cell; a factor^2 smaller blur); a narrower feather is blurred per pixel.
    The bilinear interpolation of a cell box is cut from the interpolation of the cells one cell wider than the box
    on each side (or to the edge of ``cells``): the same values as that of all the cells (a pixel's value depends on
    its two nearest cells per axis)."""
    f = ctx.factor
    sigma = max(0.5, ctx.feather_px / 2.0)
    nothing = (0, 0, 0, 0, None)
    out = []
    if ctx.feather_px >= f:
        n_r, n_c = cells.shape
        for k in ks:
            blur = cv2.GaussianBlur((cells == k).view(np.uint8).astype(np.float32), (0, 0), sigma / f)
            rows, cols = np.flatnonzero(blur.any(axis=1)), np.flatnonzero(blur.any(axis=0))
            if not len(rows):
                out.append(nothing)
                continue
            # pixels (of the cells' pixel grid) whose two nearest cells per axis may be in the support
            a0, a1, b0, b1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
            y0, y1 = max(dr, (a0 - 1) * f), min(dr + th, (a1 + 1) * f)
            x0, x1 = max(dc, (b0 - 1) * f), min(dc + tw, (b1 + 1) * f)
            if y1 <= y0 or x1 <= x0:
                out.append(nothing)
                continue
            s0, s1, t0, t1 = max(0, a0 - 2), min(n_r, a1 + 2), max(0, b0 - 2), min(n_c, b1 + 2)
            up = cv2.resize(np.ascontiguousarray(blur[s0:s1, t0:t1]), ((t1 - t0) * f, (s1 - s0) * f),
                            interpolation=cv2.INTER_LINEAR)
            wt = np.ascontiguousarray(up[y0 - s0 * f:y1 - s0 * f, x0 - t0 * f:x1 - t0 * f])
            out.append((y0 - dr, y1 - dr, x0 - dc, x1 - dc, wt))
        return out
    halo = ctx.halo
    lab = cells[np.ix_(lr, lc)]
    for k in ks:
        w = cv2.GaussianBlur((lab == k).view(np.uint8).astype(np.float32), (0, 0), sigma)[halo:halo + th, halo:halo + tw]
        rows, cols = np.flatnonzero(w.any(axis=1)), np.flatnonzero(w.any(axis=0))
        if not len(rows):
            out.append(nothing)
            continue
        y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        out.append((y0, y1, x0, x1, np.ascontiguousarray(w[y0:y1, x0:x1])))
    return out


def _write_mosaic(path, frames_dir, index, mosaic: OrthoGrid, *, seams_path, factor, gains, nadir, feather_px, tile_px,
                  executor=None, labels=None, previous=None, decoded=None, holes=None, during_cog=None,
                  white_level=None, resume=None, rolloff=None, offsets=None, toe=None, output=None):
    """Blend the output tiles into a tiled stage GeoTIFF and its overviews, then copy those to the COG
    (module doc, step 5). On local threads (or synchronous) the tiles are computed ahead of this thread,
    which writes them in tile order (``labels``: the seam labels in memory, else read from ``seams_path``);
    on a Dask cluster in batches of a few tiles per worker (the tasks read their windows of
    ``seams_path``). Memory is bounded by the tiles in flight, not by the mosaic. ``previous``
    (``PreviousMosaic``, local threads only): tiles whose seam cells and halo did not change are read from it
    instead of blended. ``decoded``: frames already decoded in memory (file path -> ``DecodedFrame``; local
    threads only), read instead of their files. ``holes``: per frame None or its ``FrameHoles``
    (``_BlendContext.holes``). ``during_cog``: a function of the mosaic's levels as the COG copies them (a dict of the files
    by their factor: 1 the stage, 2, 4 ... its overviews), run on a thread while the COG is written. Returns
    the counts of tiles blended and taken over.

    The stage is one GeoTIFF per row of tiles (joined by a VRT): with ``resume`` (``aerotri.core.resume.ResumeFolder``)
    each row, once written, is hard-linked there under a key of everything its tiles depend on (``_row_keys``), and
    the rows an interrupted run kept are linked back instead of blended (their samples read for the overview).

    ``output`` (``OutputMapping``, None: the frames' type): every blended tile mapped to 8 bits as it is made, before
    its overview (a taken-over tile is the earlier mosaic's, made with the same mapping: ``previous_mosaic``); the
    valid pixels at 255 and at 0 counted (``output_counts`` in the result)."""
    from aerotri.core.executor import local_executor
    from ortho.rectify import ordered_thread_map

    executor = executor or local_executor()
    with rasterio.open(Path(frames_dir) / index.frames[0].file) as ds:
        bands, dtype = ds.count, ds.dtypes[0]
        colorinterp = ds.colorinterp
    frames_dtype = dtype  # the blending's; the DOM's is ``dtype``
    if output is not None:
        dtype = "uint8"
    halo = int(math.ceil(2.0 * feather_px)) + factor
    check_task_count(math.ceil(mosaic.height / tile_px) * math.ceil(mosaic.width / tile_px),
                     f"mosaic of {mosaic.width} x {mosaic.height} px in tiles of {tile_px} px", "--tile-px",
                     "use a larger --tile-px")
    levels = overview_factors(mosaic.width, mosaic.height)
    timer = _PhaseTimer(trim=not decoded)
    with scratch_dir(path.parent, "mosaic") as tmp_dir, \
            rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):  # the block cache is the stage's (mosaic_block)
        tmp_dir = Path(tmp_dir)
        if executor.distributed:
            context = {"index": index.document, "index_path": str(index.path),
                       "frames_dir": str(Path(frames_dir).resolve()),
                       "mosaic": {"x_left_m": mosaic.x_left_m, "y_top_m": mosaic.y_top_m, "res_m": mosaic.res_m,
                                  "width": mosaic.width, "height": mosaic.height},
                       "seams_path": str(Path(seams_path).resolve()), "factor": int(factor), "halo": halo,
                       "gains": np.asarray(gains, float).tolist(), "nadir": np.asarray(nadir, float).tolist(),
                       "feather_px": float(feather_px), "bands": int(bands), "dtype": frames_dtype,
                       "white_level": white_level, "rolloff": None if rolloff is None else rolloff.record(),
                       "offsets": None if offsets is None else np.asarray(offsets, float).tolist(),
                       "toe": None if toe is None else toe.record()}
            context_path = (tmp_dir / "context.json").resolve()
            if holes and any(h is not None for h in holes):
                holes_path = (tmp_dir / "context_holes.npz").resolve()
                np.savez(holes_path, **{key: v for k, h in enumerate(holes) if h is not None
                                        for key, v in h._arrays(k).items()})
                context["holes_path"] = str(holes_path)
            context_path.write_text(json.dumps(context))
        else:
            if labels is None:
                with rasterio.open(seams_path) as sds:
                    labels = sds.read(1)
            cells = labels

            def read_cells(r, c, h, w):
                return cells[r:r + h, c:c + w]

            ctx = _context(index, frames_dir, mosaic, factor=factor, halo=halo, gains=gains, nadir=nadir,
                           feather_px=feather_px, bands=bands, dtype=frames_dtype, read_cells=read_cells,
                           seam_shape=labels.shape, holes=holes, white_level=white_level, rolloff=rolloff,
                           dn_offsets=offsets, toe=toe)
        tiles = [(r0, c0, min(tile_px, mosaic.height - r0), min(tile_px, mosaic.width - c0))
                 for r0 in range(0, mosaic.height, tile_px) for c0 in range(0, mosaic.width, tile_px)]
        rows = {r0: tmp_dir / f"stage_{r0:07d}.tif" for r0 in range(0, mosaic.height, tile_px)}
        keys, kept = {}, {}
        if resume is not None:
            keys = _row_keys(index, mosaic, rows, labels=labels, seams_path=seams_path, factor=factor, halo=halo,
                             gains=gains, nadir=nadir, feather_px=feather_px, tile_px=tile_px, bands=bands, dtype=dtype,
                             white_level=white_level, previous=previous, rolloff=rolloff, offsets=offsets, toe=toe,
                             output=output)
            # an 8-bit DOM's kept row needs its blended counts (of the samples before the mapping, which the kept
            # 8-bit row no longer has) for mosaic.json's blended_* figures: a row kept without them is blended again
            kept = {r0: path for r0, path in rows.items()
                    if _resumed_row(resume, keys[r0], path, (min(tile_px, mosaic.height - r0), mosaic.width),
                                    counts=output is not None)}
            if kept:
                k = sum(t[0] in kept for t in tiles)
                logger.info(f"mosaic: resumed {k} of {len(tiles)} tiles an interrupted run finished ({len(kept)} of "
                            f"{len(rows)} rows of tiles, {resume.path})")
        todo = [t for t in tiles if t[0] not in kept]
        stage = tmp_dir / "stage.vrt"  # the rows of tiles as one raster
        counts = {"taken_over": 0}
        shares = {"valid": 0, "at_255": 0, "at_0": 0, "blended_valid": 0, "blended_at_white": 0, "blended_at_255": 0}
        shares_lock = threading.Lock()
        white = _context_white(frames_dtype, white_level)
        row_blended = {r0: [0, 0, 0] for r0 in rows}  # per row of tiles: kept with the row for a resumed run
        for r0 in kept if output is not None else ():  # the kept rows' counts, as the interrupted run counted them
            n = json.loads(resume.kept(keys[r0], BLENDED_COUNTS_SUFFIX).read_text())
            shares["blended_valid"] += n[0]
            shares["blended_at_white"] += n[1]
            shares["blended_at_255"] += n[2]

        def mapped(result, r0):  # a blended tile in the DOM's type; its pixels at white before and at 255 after counted
            if output is None:
                return result
            out, valid = result
            out8 = output.apply(out, valid)
            n = (int(np.count_nonzero(valid)),
                 int(np.count_nonzero((out >= white).any(axis=0) & valid)) if white is not None else 0,
                 int(np.count_nonzero((out8 == 255).any(axis=0) & valid)))
            with shares_lock:
                shares["blended_valid"] += n[0]
                shares["blended_at_white"] += n[1]
                shares["blended_at_255"] += n[2]
                row_blended[r0] = [a + b for a, b in zip(row_blended[r0], n)]
            return out8, valid
        stack = contextlib.ExitStack()
        pyramid = _Pyramid(tmp_dir, mosaic, bands, dtype, levels, per_tile=tile_px % 2 == 0,
                           colorinterp=colorinterp)
        readers = _FrameReaders(None if executor.distributed else decoded)
        made = row = None
        profile = dict(_stage_profile(mosaic, bands, dtype), width=mosaic.width, height=mosaic.height, count=bands,
                       dtype=dtype, crs=mosaic.crs, transform=mosaic.transform)
        try:
            if executor.distributed:
                batch = max(2, 2 * executor.workers)

                def results():
                    for i in range(0, len(todo), batch):
                        part = todo[i:i + batch]
                        yield from map(mapped, executor.map(blend_tile_task, [MosaicTile(str(context_path), *t)
                                                                              for t in part],
                                                            desc="mosaic tiles", unit="tile"), [t[0] for t in part])
                made = results()
            else:
                threads = 1 if executor.scheduler == "synchronous" else max(1, executor.workers)
                if previous is not None and not previous.why_all:
                    old = stack.enter_context(rasterio.open(previous.mosaic_path))
                    lock = threading.Lock()

                    def tile(t):
                        if previous.touched(*t, halo, factor):
                            return mapped(_blend_tile(ctx, readers, *t), t[0])
                        w = Window(t[1], t[0], t[3], t[2])
                        with lock:  # one dataset, read by the tile threads in turn
                            counts["taken_over"] += 1
                            return old.read(window=w), old.read_masks(1, window=w) > 0
                else:
                    def tile(t):
                        return mapped(_blend_tile(ctx, readers, *t), t[0])

                def tile_and_half(t):
                    # the tile's 2 x 2 average for the first overview made on the tile's thread too (OpenCV): the
                    # writing thread only writes
                    out, valid = tile(t)
                    return out, valid, pyramid.halved(out, valid)

                made = ordered_thread_map(tile_and_half, todo, threads)
            with progress(len(tiles), "mosaic", "tiles") as bar:
                row = None
                for r0, c0, th, tw in tiles:
                    if row is None or row.r0 != r0:
                        if row is not None:
                            row.close(blended=row_blended[row.r0] if output is not None else None)
                        t = mosaic.transform
                        row = _StageRow(r0, rows[r0], kept.get(r0), dict(profile, height=th, transform=Affine(
                            t.a, t.b, t.c + t.b * r0, t.d, t.e, t.f + t.e * r0)), colorinterp, resume, keys.get(r0))
                    w = Window(c0, 0, tw, th)
                    if row.src is not None:  # kept: its samples only for the first overview (and the 8-bit counts)
                        if pyramid.first is not None or output is not None:
                            out, valid = row.src.read(window=w), row.src.read_masks(1, window=w) > 0
                            pyramid.add_tile(r0, c0, out, valid)
                    else:
                        out, valid, *half = next(made)
                        row.dst.write(out, window=w)
                        row.dst.write_mask(valid.view(np.uint8) * np.uint8(255), window=w)
                        pyramid.add_tile(r0, c0, out, valid, *half)
                    if output is not None:
                        shares["valid"] += int(np.count_nonzero(valid))
                        shares["at_255"] += int(np.count_nonzero((out == 255).any(axis=0) & valid))
                        shares["at_0"] += int(np.count_nonzero((out == 0).any(axis=0) & valid))
                    bar.update(1)
                row.close(blended=row_blended[row.r0] if output is not None else None)
                row = None
        except BaseException as exc:
            # name the mosaic, not the project (trial-overnight: "d1: a write was cut short ..."): the rows and the
            # overview are written in its work folder beside it (``scratch_dir``), on the same file system
            p = Path(path)
            annotate_output(exc, p.parent.parent / p.name if TEMP_MARKER in p.parent.name else p)
            # the first overview, open for writing, closed now: left to the garbage collector, GDAL flushed it after
            # the error message, its own "_tiffWriteProc: File too large." printed after ours (trial-overnight)
            pyramid.discard()
            raise
        finally:
            if made is not None:  # the tile threads end before their frame datasets are closed
                made.close()
            if row is not None:  # an error: the row is not whole
                row.close(keep=False)
            readers.close()
            stack.close()
        if kept and previous is not None and not previous.why_all and not executor.distributed:
            # the kept rows' tiles were taken over or blended by the interrupted run as by this one: counted the same
            counts["taken_over"] += sum(1 for t in tiles if t[0] in kept and not previous.touched(*t, halo, factor))
        row_parts = [(p, r0, min(tile_px, mosaic.height - r0)) for r0, p in rows.items()]
        write_vrt(stage, row_parts, [], mosaic, bands=bands, dtype=dtype, colorinterp=colorinterp, tags={})
        timer.done("tiles")
        pyramid.finish(stage)
        timer.done("overviews")
        vrt = tmp_dir / "mosaic.vrt"
        write_vrt(vrt, row_parts, pyramid.paths, mosaic, bands=bands, dtype=dtype, colorinterp=colorinterp,
                  tags={**operation_tags(index.coordinate_operation, index.height_operation),
                        **({} if output is None else output.tags())})
        with contextlib.ExitStack() as during:
            waits = during.enter_context(_background(during_cog, {1: stage, **dict(zip(levels, pyramid.paths))},
                                                     imports=False)) if during_cog else None
            with atomic_path(path) as tmp:
                rasterio.shutil.copy(vrt, tmp, **COG_OPTIONS)
            if waits:
                waits()
        timer.done("COG")
    if previous is not None and executor.distributed:
        previous.why_all = "the tiles run as Dask tasks: every tile blended"
    return {"total": len(tiles), "blended": len(tiles) - counts["taken_over"], "taken_over": counts["taken_over"],
            **({"why_all_blended": previous.why_all} if previous is not None and previous.why_all else {}),
            **({} if output is None else {"output_counts": shares})}


class _StageRow:
    """One row of tiles of the stage: written (``dst``), or kept by an interrupted run and linked in (``src``, read
    for the overview); ``close`` keeps a written row for a resumed run (``resume``, under ``key``)."""

    def __init__(self, r0: int, path: Path, kept, profile: dict, colorinterp, resume, key):
        self.r0, self.path, self.resume, self.key = r0, path, resume, key
        self.src = rasterio.open(path) if kept else None
        self.dst = None
        if self.src is None:
            self.dst = rasterio.open(path, "w", **_layout_profile(profile, colorinterp))
            if tuple(self.dst.colorinterp) != tuple(colorinterp):
                self.dst.colorinterp = colorinterp

    def close(self, keep: bool = True, blended=None) -> None:
        """``blended``: an 8-bit DOM's row's blended counts (valid, at white, at 255), kept before the row."""
        if self.src is not None:
            self.src.close()
        if self.dst is not None:
            self.dst.close()
            if keep and self.resume is not None:
                if blended is not None:
                    self.resume.put_text(self.key, BLENDED_COUNTS_SUFFIX, json.dumps([int(v) for v in blended]))
                self.resume.keep(self.path, self.key, ".tif")


def _layout_profile(profile: dict, colorinterp) -> dict:
    """``profile`` (a stage row's or an overview's, with an internal mask) for bands of ``colorinterp``: photometric RGB
    from the start when the first three bands are red, green and blue (created grey with two extra samples and made
    RGB after, trial 90's NGI DOM printed 24 GDAL "Bad value 2 for "ExtraSamples" tag" errors at a 1.5 GiB limit), and
    without GDAL's compression threads when the file has extra samples (``without_threads_for_extra_samples``)."""
    rgb = (ColorInterp.red, ColorInterp.green, ColorInterp.blue)
    if len(colorinterp) >= 3 and tuple(colorinterp)[:3] == rgb:
        return without_threads_for_extra_samples(dict(profile, photometric="RGB"), len(colorinterp), 3)
    return without_threads_for_extra_samples(dict(profile), len(colorinterp), 1)


# The rules by which a tile's samples are blended and filled from the frames, named in the rows' resume keys and in
# mosaic.json: a mosaic made by other rules (the package's version does not move with every change of them) is never
# resumed or taken over by an edited run. Change the name whenever blending, filling or the gains' application changes.
BLEND_RULES = "feather+fill-farthest-from-holes+holes-inside-footprint+rolloff+offsets-toe-black-held/2026-12-01"
# The version of what the blending is given: the frames' gains and offsets (their solve over the overlaps) and the
# seamlines. The chain's mosaic stamp holds it beside ``BLEND_RULES`` (the rows' resume keys hold the gains, offsets
# and seam labels themselves). Bump it when the gains, offsets or seamlines change at the same inputs and settings.
# 1: s10-fixes (the solve and seamlines as of main e4b26d8e).
RADIOMETRY_SEAMS_VERSION = 1


def _row_keys(index, mosaic: OrthoGrid, rows: dict, *, labels, seams_path, factor, halo, gains, nadir, feather_px,
              tile_px, bands, dtype, white_level, previous, rolloff=None, offsets=None, toe=None, output=None) -> dict:
    """Key of each row of tiles (row offset px -> sha256): what its samples depend on, the frame orthos (index.json,
    which holds their sizes and hashes), the seam labels, the gains, nadir points, feather, seam grid, tiles, the
    mosaic's grid and type, the white level, the earlier mosaic an edit takes tiles over from, and the version."""
    import hashlib

    import aerotri

    if labels is None:
        with rasterio.open(seams_path) as sds:
            labels = sds.read(1)
    labels = np.ascontiguousarray(labels)
    doc = {"index_sha1": hashlib.sha1(Path(index.path).read_bytes()).hexdigest(),
           "frames": list(index.image_ids),  # (a run that leaves frames out: the labels number the others)
           "labels": [hashlib.sha256(labels.tobytes()).hexdigest(), list(labels.shape), str(labels.dtype)],
           "gains": np.asarray(gains, float).tolist(), "nadir": np.asarray(nadir, float).tolist(),
           "factor": int(factor), "halo": int(halo), "feather_px": float(feather_px), "tile_px": int(tile_px),
           "grid": [mosaic.x_left_m, mosaic.y_top_m, mosaic.res_m, mosaic.width, mosaic.height, mosaic.crs.to_wkt()],
           "bands": int(bands), "dtype": str(dtype), "white_level": white_level, "version": aerotri.__version__,
           "blend_rules": BLEND_RULES,
           **({} if rolloff is None else {"rolloff": rolloff.record()}),
           **({} if offsets is None else {"offsets": np.asarray(offsets, float).tolist()}),
           **({} if toe is None else {"toe": toe.record()}),
           **({} if output is None else {"output": output.record()}),
           "previous": None if previous is None else [
               file_stamp(previous.mosaic_path) if previous.mosaic_path.is_file() else None,
               hashlib.sha256(np.packbits(previous.changed)).hexdigest(), previous.why_all]}
    return {r0: resume_key({**doc, "row": r0}) for r0 in rows}


BLENDED_COUNTS_SUFFIX = ".blended.json"  # a kept row's blended counts (an 8-bit DOM's mosaic.json blended_*)


def _resumed_row(resume, key: str, path: Path, shape: tuple[int, int], counts: bool = False) -> bool:
    """Link the row kept under ``key`` to ``path`` when it is whole (``shape``: its rows and columns) and, with
    ``counts``, its blended counts were kept with it; False when none is."""
    src = resume.kept(key, ".tif")
    if src is None or (counts and resume.kept(key, BLENDED_COUNTS_SUFFIX) is None):
        return False
    try:
        with rasterio.open(src) as ds:
            ok = (ds.height, ds.width) == shape
    except (rasterio.errors.RasterioError, OSError):
        return False
    if ok:
        link_or_copy(src, path)
    return ok


@dataclasses.dataclass
class PreviousMosaic:
    """The mosaic an edited run starts from (``ortho/mosaic.tif`` of the same frames, gains, feather and seam grid) and
    the seam cells whose label the edit changed; ``why_all``: why every tile is blended all the same."""

    mosaic_path: Path
    changed: np.ndarray  # bool, seam grid
    why_all: str | None = None

    def touched(self, r0: int, c0: int, th: int, tw: int, halo: int, factor: int) -> bool:
        """Whether the tile's seam cells with its halo (those ``_blend_tile`` reads) hold a changed cell."""
        if self.why_all:
            return True
        sh, sw = self.changed.shape
        lr0, lr1 = min(max((r0 - halo) // factor, 0), sh - 1), min(max((r0 + th + halo - 1) // factor, 0), sh - 1)
        lc0, lc1 = min(max((c0 - halo) // factor, 0), sw - 1), min(max((c0 + tw + halo - 1) // factor, 0), sw - 1)
        return bool(self.changed[lr0:lr1 + 1, lc0:lc1 + 1].any())


def previous_mosaic(root: Path, index, names, labels, *, gains, feather_px, factor,
                    mosaic: OrthoGrid, rolloff=None, offsets=None, toe=None, output=None) -> PreviousMosaic:
    """The mosaic in ``ortho/`` when the edited run would blend its tiles the same away from the edit: made from the
    same frames (index.json sha1), with the same gains, highlight roll-off, feather and seam grid by the same
    ``BLEND_RULES``; else every tile is blended (``why_all`` says why)."""
    out = root / "ortho"
    old_path, seams_path, summary_path = out / "mosaic.tif", out / "seams.tif", out / "mosaic.json"
    none = np.ones(labels.shape, bool)
    if not (old_path.is_file() and seams_path.is_file() and summary_path.is_file()):
        return PreviousMosaic(old_path, none, "no earlier mosaic in ortho/")
    old = read_json(summary_path)
    # the rules first: a mosaic of other rules is not the same whatever its gains (which other rules may make
    # differ in their last digits)
    if old.get("blend_rules") != BLEND_RULES:
        return PreviousMosaic(old_path, none, f"the earlier mosaic was blended by other rules "
                                              f"({old.get('blend_rules') or 'before they were named'}; now {BLEND_RULES})")
    same = (old.get("index_sha1") == index_sha1(root) and old.get("seam_factor") == factor
            and old.get("feather_px") == feather_px and (old.get("width"), old.get("height")) == (mosaic.width, mosaic.height)
            and old.get("gains") == {n: [float(v) for v in g] for n, g in zip(names, gains)}
            and old.get("highlight_rolloff") == (None if rolloff is None else rolloff.record())
            and old.get("offsets") == _offsets_record(names, offsets)
            and old.get("shadow_toe") == (None if toe is None else toe.record()))
    if not same:
        return PreviousMosaic(old_path, none, "the earlier mosaic was made from other frames, gains, offsets, "
                                              "highlight roll-off, shadow toe, feather or seam grid")
    # an 8-bit DOM's tiles are taken over only into an 8-bit DOM of the same mapping, a 16-bit DOM's into a 16-bit one
    if (old.get("output") or {}).get("mapping") != (None if output is None else output.record()):
        return PreviousMosaic(old_path, none, "the earlier mosaic's samples were mapped otherwise (output_bits or its "
                                              "mapping differ)")
    with rasterio.open(seams_path) as sds:
        old_labels = sds.read(1)
    if old_labels.shape != labels.shape:
        return PreviousMosaic(old_path, none, "the earlier seam grid differs")
    return PreviousMosaic(old_path, old_labels != labels)


def _offsets_record(names, offsets) -> dict | None:
    """mosaic.json's "offsets": frame name -> its offsets (DN) per band (None: no offsets)."""
    return None if offsets is None else {n: [float(v) for v in o] for n, o in zip(names, offsets)}


def _stage_profile(mosaic: OrthoGrid, bands: int, dtype) -> dict:
    """The stage's GeoTIFF profile: uncompressed while it is small (``STAGE_RAW_MAX_BYTES``), else ZSTD level 1
    with the predictor (a third of the disk for a few ns per pixel)."""
    raw = mosaic.width * mosaic.height * bands * np.dtype(dtype).itemsize
    if raw > STAGE_RAW_MAX_BYTES:
        return dict(STAGE_PROFILE)
    return uncompressed(STAGE_PROFILE)


def halve(img: np.ndarray, valid: np.ndarray):
    """2 x 2 average of the valid samples (bands, h, w; 0 where not valid) -> (bands, ceil(h/2), ceil(w/2)) in
    their type, and the validity (any of the four valid); an odd last row or column averages what it has."""
    b, h, w = img.shape
    h2, w2 = -(-h // 2), -(-w // 2)
    if (h2 * 2, w2 * 2) != (h, w):
        img = np.pad(img, ((0, 0), (0, h2 * 2 - h), (0, w2 * 2 - w)))
        valid = np.pad(valid, ((0, h2 * 2 - h), (0, w2 * 2 - w)))
    count = cv2.resize(valid.view(np.uint8).astype(np.float32), (w2, h2), interpolation=cv2.INTER_AREA)
    ok = count > 0
    inv = np.where(ok, 1.0 / np.maximum(count, 1e-6), 0.0).astype(np.float32)
    out = np.empty((b, h2, w2), img.dtype)
    for k in range(b):
        # invalid samples are 0 (the blended tiles and every level are written so)
        mean = cv2.resize(img[k].astype(np.float32), (w2, h2), interpolation=cv2.INTER_AREA)
        cv2.multiply(mean, inv, dst=mean)
        out[k] = cv2.convertScaleAbs(mean) if img.dtype == np.uint8 else _to_type(mean, img.dtype)
    return out, ok


class _Pyramid:
    """The overviews of the stage, as files ``ovr_<factor>.tif`` (same profile as the stage): the first
    from each tile as it is written (``per_tile``: even tile sizes, whose halves align), the others by
    halving the previous level by strips of rows in ``finish``."""

    STRIP_PX = 512

    def __init__(self, folder: Path, mosaic: OrthoGrid, bands: int, dtype: str, factors: list[int], per_tile: bool,
                 colorinterp=()):
        self.folder, self.mosaic, self.bands, self.dtype = folder, mosaic, bands, dtype
        self.factors = factors
        self.paths = [folder / f"ovr_{f}.tif" for f in factors]
        self.base = _layout_profile(_stage_profile(mosaic, bands, dtype), colorinterp)
        self.first = None
        if factors and per_tile:
            self.first = rasterio.open(self.paths[0], "w", **self._profile(factors[0]))

    def _profile(self, f: int) -> dict:
        m = self.mosaic
        return dict(self.base, width=-(-m.width // f), height=-(-m.height // f), count=self.bands, dtype=self.dtype,
                    crs=m.crs, transform=Affine(m.res_m * f, 0.0, m.x_left_m, 0.0, -m.res_m * f, m.y_top_m))

    def halved(self, out: np.ndarray, valid: np.ndarray):
        """``halve`` of a tile for the first overview (None when the first overview is not made by tiles)."""
        return None if self.first is None else halve(out, valid)

    def add_tile(self, r0: int, c0: int, out: np.ndarray, valid: np.ndarray, halved=None) -> None:
        """The tile's 2 x 2 average into the first overview (``halved``: ``halved(out, valid)``, made already)."""
        if self.first is None:
            return
        h, v = halved if halved is not None else halve(out, valid)
        w = Window(c0 // 2, r0 // 2, h.shape[2], h.shape[1])
        self.first.write(h, window=w)
        self.first.write_mask(v.view(np.uint8) * np.uint8(255), window=w)

    def discard(self) -> None:
        """Close the first overview after an error (its file is the work folder's, removed with it); a write the
        disk cuts short fails again in the close, which adds nothing to the error under way."""
        if self.first is not None:
            with contextlib.suppress(Exception):
                self.first.close()

    def finish(self, stage: Path) -> None:
        start = 0
        if self.first is not None:
            self.first.close()
            start = 1
        for i in range(start, len(self.factors)):
            src = stage if i == 0 else self.paths[i - 1]
            with rasterio.open(src) as s, rasterio.open(self.paths[i], "w", **self._profile(self.factors[i])) as d:
                for r0 in range(0, s.height, self.STRIP_PX):
                    win = Window(0, r0, s.width, min(self.STRIP_PX, s.height - r0))
                    h, v = halve(s.read(window=win), s.read_masks(1, window=win) > 0)
                    w = Window(0, r0 // 2, h.shape[2], h.shape[1])
                    d.write(h, window=w)
                    d.write_mask(v.view(np.uint8) * np.uint8(255), window=w)


_GDAL_TYPES = {"uint8": "Byte", "int8": "Int8", "uint16": "UInt16", "int16": "Int16", "uint32": "UInt32",
               "int32": "Int32", "float32": "Float32", "float64": "Float64"}


def write_vrt(path: Path, full, overviews: list, grid: OrthoGrid, *, bands: int, dtype: str, colorinterp,
              tags: dict) -> None:
    """A VRT of ``full`` (a GeoTIFF with an internal mask, or a list of (path, row offset px, rows) of such files
    of the grid's width, the rows of the raster) declaring ``overviews`` (files of the same bands and mask, finest
    first) as its overviews and its mask's, with the metadata ``tags``: the source the COG driver copies with its
    overviews as they are (``OVERVIEWS=FORCE_USE_EXISTING``)."""
    from xml.sax.saxutils import escape, quoteattr

    t = grid.transform
    gdal_type = _GDAL_TYPES[str(dtype)]

    parts_of = [(full, 0, grid.height)] if isinstance(full, (str, Path)) else list(full)

    def source(band, kind="SimpleSource"):
        return "".join(f'<{kind}><SourceFilename relativeToVRT="1">{escape(Path(name).name)}</SourceFilename>'
                       f'<SourceBand>{band}</SourceBand>'
                       f'<SrcRect xOff="0" yOff="0" xSize="{grid.width}" ySize="{h}"/>'
                       f'<DstRect xOff="0" yOff="{r0}" xSize="{grid.width}" ySize="{h}"/></{kind}>'
                       for name, r0, h in parts_of)

    def overview_list(band):
        return "".join(f'<Overview><SourceFilename relativeToVRT="1">{escape(Path(o).name)}</SourceFilename>'
                       f'<SourceBand>{band}</SourceBand></Overview>' for o in overviews)

    parts = [f'<VRTDataset rasterXSize="{grid.width}" rasterYSize="{grid.height}">',
             f"<SRS>{escape(grid.crs.to_wkt())}</SRS>",
             f"<GeoTransform>{t.c!r}, {t.a!r}, 0.0, {t.f!r}, 0.0, {t.e!r}</GeoTransform>"]
    if tags:
        parts.append("<Metadata>" + "".join(f"<MDI key={quoteattr(k)}>{escape(str(v))}</MDI>" for k, v in tags.items())
                     + "</Metadata>")
    for b in range(1, bands + 1):
        ci = colorinterp[b - 1].name.capitalize() if colorinterp else "Undefined"
        ci = {"Gray": "Gray", "Undefined": "Undefined"}.get(ci, ci)
        parts.append(f'<VRTRasterBand dataType="{gdal_type}" band="{b}"><ColorInterp>{ci}</ColorInterp>'
                     + source(b) + overview_list(b) + "</VRTRasterBand>")
    parts.append('<MaskBand><VRTRasterBand dataType="Byte">' + source("mask,1")
                 + overview_list("mask,1") + "</VRTRasterBand></MaskBand>")
    parts.append("</VRTDataset>")
    Path(path).write_text("\n".join(parts) + "\n")


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


@dataclasses.dataclass(frozen=True)
class SeamPair:
    """One seam's misalignment: the two frames, the patches matched, RMS and largest displacement (px; None
    without patches), and the textured patches (above the texture floor) that found no match (``unmatched``: NCC
    peak below 0.7 or on the edge of the +-4 px search; None: a record written before review 26)."""

    image_a: str
    image_b: str
    patches: int
    rms_px: float | None
    max_px: float | None
    unmatched: int | None = None

    @property
    def textured(self) -> int:
        """The seam's patches above the texture floor that were matched or found no match (unsettled ones aside)."""
        return self.patches + (self.unmatched or 0)

    @property
    def unmatched_share(self) -> float | None:
        """``unmatched`` of ``textured``; None without textured patches or an older record."""
        return self.unmatched / self.textured if self.unmatched is not None and self.textured else None


# Least texture ratio (``ortho.patches.texture_ratio`` of frame b's patch) of a seam patch measured: two frame orthos
# are two aliased renderings of the ground, and a road's or a field's edge lines, broken into steps that move along
# them with each rendering's sub-pixel phase, read as a shift along them that neither frame has. Chosen on the demo
# (d0d98f7, bench/eval_seam_texture.py: each seam patch against (frame a - truth ortho) - (frame b - truth ortho),
# their DOM-check patches' medians within 120 px, 446 patches; the true relative shift 0.028 px RMS): the seam
# reading's error RMS 0.285 / 0.156 / 0.123 / 0.090 / 0.069 / 0.067 px at floors 0.1 / 0.2 / 0.3 / 0.4 / 0.5 / 0.6,
# the patches below 0.5 (208) reading 0.41 px. Scored on the DMC 2 x 4 (run d0d98f7, 1,118 patches, true relative
# shift 0.16 px RMS): error RMS 0.228 -> 0.142 px at 0.1 -> 0.5 (its reading 0.262 -> 0.197 px), 236 left out (21 %)
# reading 0.79 px
SEAM_MIN_TEXTURE_RATIO = 0.5

# Least patches of a seam judged on its own (the QA report's worst-seam row): one frame 1 px off shows on its seams
# only, diluted in the block RMS (demo, review 25: block 0.07 -> 0.25-0.49 px, its seams 0.90-1.12 px), but a seam
# of one or two patches is one or two readings of a few metres of ground. Chosen on the demo (main 6360cc7c, floor
# 0.5, bench/eval_seam_rows.py): seams of at least 5 patches read at most 0.19 px as made, those of a frame read 1 px
# off 0.90-1.12 px (the worst-seam limit, seam_worst_rms_px 0.5 px, between); scored on the DMC 2 x 4 (run 2bfb756):
# at most 0.31 px as made, 16 of 16 one-frame shifts failed, the block RMS passing all 16 (docs/true-ortho.md).
SEAM_MIN_PATCHES = 5

SEAM_SEARCH_PX = 4  # a seam patch's search in frame b, +- px: frames off by more do not match (below)

# Largest share of a seam's textured patches (above the texture floor; seams of at least SEAM_MIN_PATCHES of them)
# that may find no match (NCC peak below 0.7 or on the edge of the search): a frame SEAM_SEARCH_PX or more off does
# not read its shift on its seams, their patches drop out instead (review 26: demo s02_002 moved 4 px, its 6 seams 27
# -> 0 patches, the worst seam 0.19 px and the block 0.065 px: a pass). "Most": as made, 0 % of any seam on the demo
# (main 6360cc7c) and at most 7.4 % on the DMC 2 x 4 (run 2bfb756: s01_001 / s02_004, 4 of 54); one frame moved 4 or
# 6 px in x or 4 px in y: 92-100 % of its seams' patches on the demo (51 of 54 shifts of its 18 frames fail; the
# 3 others move s01_005, which has no seam of 5 textured patches), 85-100 % on the DMC (8 of 8 frames moved 4 px
# fail). Half lies far from both (docs/true-ortho.md review 26).
SEAM_MAX_UNMATCHED_SHARE = 0.5


@dataclasses.dataclass(frozen=True)
class SeamMisalignment:
    """``seam_misalignment``: the patch size (px), the patches of all seams, their RMS and largest displacement
    (px; None without patches) and every seam's (dom_report.json's ``seams`` is ``to_record`` of it); the patches
    left out as textured too little in two directions (``one_direction``: texture ratio below ``min_texture_ratio``,
    ``SEAM_MIN_TEXTURE_RATIO``: roads, field edges) and those whose sub-pixel refinement did not settle
    (``unsettled``); the worst seam (``worst_seam``: largest RMS of the seams of at least ``min_patches`` patches,
    ``SEAM_MIN_PATCHES``; None when no seam has that many); the textured patches that found no match (``unmatched``)
    and the largest share of them a seam may have (``max_unmatched_share``, ``SEAM_MAX_UNMATCHED_SHARE``;
    ``unmatched_seams``)."""

    patch_px: int
    patches: int
    rms_px: float | None
    max_px: float | None
    per_seam: tuple[SeamPair, ...]
    one_direction: int = 0
    min_texture_ratio: float | None = None  # None: a report written before review 20 (the DOM check's 0.1)
    unsettled: int = 0
    min_patches: int | None = None  # None: a report written before review 25 (no worst seam recorded)
    worst_seam: SeamPair | None = None
    unmatched: int | None = None  # None: a report written before review 26 (patches without a match not counted)
    max_unmatched_share: float | None = None  # None: likewise (``SEAM_MAX_UNMATCHED_SHARE`` applies)

    @property
    def examined(self) -> int:
        """Seam patches valid in both frames (and on the ground): measured, or left out by texture, by finding no
        match or by refinement."""
        return self.patches + self.one_direction + self.unsettled + (self.unmatched or 0)

    @property
    def unmatched_limit(self) -> float:
        """The largest unmatched share a seam may have: this record's, else ``SEAM_MAX_UNMATCHED_SHARE``."""
        return self.max_unmatched_share if self.max_unmatched_share is not None else SEAM_MAX_UNMATCHED_SHARE

    def unmatched_seams(self) -> tuple[SeamPair, ...]:
        """The seams of at least ``least_patches`` textured patches more than ``max_unmatched_share``
        (``SEAM_MAX_UNMATCHED_SHARE``) of which found no match, most unmatched first: frames off by more than the
        search (their seams lose their patches instead of reading the shift) or not the same ground there."""
        share = self.unmatched_limit
        seams = (p for p in self.per_seam if p.unmatched is not None and p.textured >= self.least_patches
                 and p.unmatched_share > share)
        return tuple(sorted(seams, key=lambda p: (-p.unmatched_share, -p.unmatched)))

    @property
    def least_patches(self) -> int:
        """A seam's least patches to be judged on its own: this record's, else (an older record)
        ``SEAM_MIN_PATCHES``."""
        return self.min_patches or SEAM_MIN_PATCHES

    def judged(self, min_patches: int | None = None) -> tuple[SeamPair, ...]:
        """The seams of at least ``min_patches`` patches (default ``least_patches``)."""
        n = min_patches or self.least_patches
        return tuple(p for p in self.per_seam if p.patches >= n and p.rms_px is not None)

    def worst(self, min_patches: int | None = None) -> SeamPair | None:
        """The seam of largest RMS among ``judged(min_patches)``; None when none is judged."""
        return max(self.judged(min_patches), key=lambda p: p.rms_px, default=None)

    @classmethod
    def of_record(cls, d: dict) -> "SeamMisalignment":
        """The record ``to_record`` made of it (dom_report.json's ``seams``; keys added since, or left out by a
        hand-made record, missing: None, patches 0)."""
        pair = lambda r: SeamPair(**r)
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{"patch_px": None, "patches": 0, "rms_px": None, "max_px": None,
                      **{k: v for k, v in d.items() if k in names},
                      "per_seam": tuple(pair(r) for r in d.get("per_seam") or ()),
                      "worst_seam": pair(d["worst_seam"]) if d.get("worst_seam") else None})


def seam_misalignment(root, *, patch_px: int = 32, search_px: int = SEAM_SEARCH_PX, spacing_cells: int = 4, min_ncc: float = 0.7,
                      ndsm_path=None, max_ndsm_m: float = 0.5,
                      min_texture_ratio: float = SEAM_MIN_TEXTURE_RATIO,
                      min_patches: int = SEAM_MIN_PATCHES,
                      max_unmatched_share: float = SEAM_MAX_UNMATCHED_SHARE) -> SeamMisalignment:
    """Relative displacement of neighbouring frame orthos across each seam (NCC patches on the seam).

    For every seam (pair of frames sharing a boundary in ``ortho/seams.tif``), patches centred on
    seam cells (every ``spacing_cells``) are cut from frame a and matched in frame b; only patches
    valid in both, textured in two directions (frame b's texture ratio at least ``min_texture_ratio``,
    ``SEAM_MIN_TEXTURE_RATIO``; those left out counted) and, with an nDSM, on the ground. Returns per-seam and
    overall statistics in pixels, and the worst seam of at least ``min_patches`` patches (``SEAM_MIN_PATCHES``).
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
    grids = index.grids  # in frame order, as the labels number the frames
    mosaic = OrthoGrid.union(grids)
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        labels = ds.read(1)
        factor = int(round(ds.transform.a / mosaic.res_m))
    names = list(index.image_ids)
    if ndsm_path is None and (root / "lidar_out" / "ndsm.tif").exists():
        ndsm_path = root / "lidar_out" / "ndsm.tif"
    to_project = index_operation(index)
    half = patch_px // 2 + search_px
    size = 2 * half
    per_seam, all_d, one_direction, unsettled, unmatched = [], [], 0, 0, 0
    for (i, j), rc in seam_samples(labels, spacing_cells):
        # mosaic pixel of each patch's upper-left corner
        R = ((rc[:, 0] + 0.5) * factor).astype(int) - half
        C = ((rc[:, 1] + 0.5) * factor).astype(int) - half
        ds_list, seam_unmatched = [], 0
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
                    fc, fr = grids[k].offset_in(mosaic)
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
                                      res_m=mosaic.res_m, patch_px=patch_px, step_px=patch_px, search_px=search_px,
                                      min_ncc=min_ncc, keep=None if keep is None else keep[win],
                                      min_texture_ratio=min_texture_ratio)
                    ds_list.extend(np.hypot(p.dx_px, p.dy_px).tolist())
                    one_direction += len(p.one_direction_row_px)
                    unsettled += len(p.unsettled_row_px)
                    seam_unmatched += len(p.unmatched_row_px)
        d = np.array(ds_list)
        all_d.extend(ds_list)
        unmatched += seam_unmatched
        per_seam.append(SeamPair(names[i], names[j], int(len(d)), float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
                                 float(d.max()) if len(d) else None, seam_unmatched))
    d = np.array(all_d)
    out = SeamMisalignment(patch_px, int(len(d)), float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
                           float(d.max()) if len(d) else None, tuple(per_seam), one_direction, min_texture_ratio,
                           unsettled, min_patches, None, unmatched, max_unmatched_share)
    return dataclasses.replace(out, worst_seam=out.worst())
