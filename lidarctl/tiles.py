"""Tiling with overlap buffers: classification of LAS/LAZ files of any size in bounded memory.

The cloud is cut into square tiles over the header bounds. Every point belongs to exactly one tile
*core* (column ``floor((x - x0) / tile_m)``, row ``floor((y - y0) / tile_m)``, clipped to the grid);
a tile's *buffer* adds the points within ``buffer_m`` of its core (Chebyshev distance, so the
buffered box is the core box grown by ``buffer_m`` on each side). Each tile is classified with its
buffer so that the filters see the neighbourhood of every core point, and only the classes of the
core points are kept.

Units: the tile grid, the tile size and the buffer are in metres; a cloud in a foot CRS is scaled
to metres as it is read (``io.read_cloud``, ``split_into_tiles``, ``classify_tile``) and its records
are copied unchanged, so the output keeps the input's CRS and units.

Several files (``classify_files``: the strips of a block, no merged file): the grid covers the union
of their header bounds, a tile gathers its points from every strip, point indices run over the
strips one after the other, and each strip gets its own classified copy; the set is written
atomically (all outputs or none).

Three passes, memory bounded by the chunk size and the tile size, never by the file or block size:

1. ``split_into_tiles``: stream the input in chunks (LAS 1.2-1.4, LAZ), validate every chunk as
   ``io.read_cloud`` does, and append each tile's points (core + buffer, file order; the fields the
   classifier reads, ``TILE_DTYPE``: 28 bytes a point, raw, no LAS writer) to a temporary file
   ``tile_R_C.pts`` plus their indices in the input file (``tile_R_C.index``, int64).
   Before the tiles are classified, two light passes over the tile files (``water_grid``: each tile counts the
   returns of the cells whose centre lies in its core) give the whole cloud's water grid (``pipeline.WaterGrid``:
   its water cell from the whole cloud's mean point spacing, its origin, the median returns per occupied cell), so
   that every tile judges pulse dropouts on the whole cloud's cells and density and what is water does not depend
   on the tile size (issue 44: a window that a wide river fills had its dropout threshold lowered below the water).
   The same passes give the survey's footprint (its occupied 10 m cells: emptiness beyond it is no gap), the whole
   cloud's level water bodies (from each water cell's lowest, median and highest return) and the land's reflectance
   (the median intensity of each cell's lowest return), for a lake larger than a tile's window (i44-edge).
2. ``classify_tile`` (one executor task per tile, see ``aerotri.core.executor``): read the tile file,
   run ``classify.classify_points`` and write the classes of the core points with their input
   indices (``tile_R_C.classes.npy``, ``tile_R_C.core.npy``). Returns small statistics.
3. ``classify_file`` scatters the tile results into a classes file on disk (1 byte per point,
   memory-mapped) and streams the records copy to write the output (``io.write_classified``: same
   header, VLRs, EVLRs and point records; only the classification changes; atomic).

Tiled vs whole-cloud classes: each tile is classified on the whole cloud's frame (``grid.CloudFrame``, tile-phase):
every grid inside ``classify_points`` lies on the whole cloud's cells (origin: its lowest x, y; ``grid.origin``), and
the pull-push fill of its DEMs on the whole grid's pyramid blocks (``raster_ops.fill_nodata(offset=...)``); the cell
sizes come from the whole cloud's mean point spacing (the water-grid pass gives it), and the ground tolerances from
the whole cloud's noise (``cloud_noise``: two more passes of the ground filter over the tiles give the spread of its
refine residuals and the lifted-ground test's sigma, each point counted in its core tile; the second keeps the
tile's noise codes and ground for its classification; AHN3 Delft in 60 m + 60 m tiles: 19.9 -> 29.7 CPU-s). Before, each tile's grids
started at its window's lowest corner and its spacing and noise were its window's: on AHN3 Delft 9,369 building and
853 ground label flips against the whole cloud with 60 m tiles + 60 m buffer, 6,025 and 251 with 100 m + 100 m,
spread over the whole area; now 9 and 34 (60 m: a small bridge deck, 34 returns 8-12 m from a tile corner, that a
tile takes for ground, and two small clusters of building returns within 30 m of a tile edge; not traced further)
and 1 and 0 (100 m). A whole cloud's classes moved little (the grids of point subsets, such as the ground points,
are now on the cloud's cells too): 13 of 640,510 on AHN3 Delft, 56 of 159,613 over the 7 ISPRS samples. The classes
do not depend on the scheduler or the number of workers (byte-identical output files).

Limits: the tile size comes from the mean density over the header's bounding box, so a cloud that
fills only part of its box (a diagonal strip) gets tiles with more points than planned; a tile
with fewer than 10 points (a stray point off the grid) leaves its core points unclassified (1).

Temporary disk space: about 2.3 x the uncompressed point records (tiles with buffers + the copy),
in a hidden folder next to the output (or ``work_dir``), removed at the end, also on errors.

Resume (``classify_files(resume_dir=...)``, ``classify_file``; the chain's ``work/classify_resume``, ``lidarctl
classify``'s ``OUT.resume`` beside its output): each tile's two result files are hard-linked there as the tile
finishes, under a key of everything they depend on (``_tiles_key_doc``), and a run after a kill or Ctrl-C takes
them back instead of classifying the tile again (pass 1 and 3 run again); the folder goes when the set commits or
by an error.

Tasks take small items (paths and parameters) and exchange data through files, so the same task
graph runs in local threads, local worker processes or on a Dask cluster with a shared file
system; results are gathered in tile order, so the output is byte-identical for every scheduler.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import logging
import math
import shutil
import time
from pathlib import Path

import laspy
import numba
import numpy as np

from aerotri.geom import las
from lidarctl import grid as lidar_grid
from lidarctl import io
from aerotri.core.atomic import atomic_dir, atomic_path, refuse_foreign_contents, refuse_input_as_output, temporary_dir
from aerotri.core.errors import InputError, OptionError, ResourceError
from aerotri.core.executor import local_executor
from aerotri.core.log import counted, progress
from aerotri.core.resume import (ResumeFolder, beside, discard_kept, file_stamp, is_beside, link_or_copy, resumable,
                                 resume_key)
from aerotri.geom.crs.definition import parse_crs
from lidarctl.units import METRE, LengthUnits

logger = logging.getLogger(__name__)

# An inner tile of about this many points (core + buffer) keeps one classification task under about 2 GB of
# memory (``CLASSIFY_BYTES_PER_POINT``; classify_points alone needs about 200 bytes a point), two tasks at a time
# under 4 GB (the dmc strips' 6.5 M + 2.45 M point tiles: 2.68 GB). Dense clouds get smaller cores (and a larger
# buffer overhead) than sparse ones.
DEFAULT_TILE_POINTS = 4_000_000
# The memory of a classification task per point of its tile (buffer included), what the tile-by-tile passes
# (the cloud's noise figures, the classes) hold at their peak: 435-444 bytes measured on the simulator's dmc
# strips (8.45 M points; 760 m tiles of 2.1 M points one and two at a time, anonymous memory sampled every
# 0.2 s; docs/scale-out.md). Under a memory limit the default tiles and the tasks run side by side are chosen
# from it (``tile_points_in_memory``, ``tiles_at_once``): the tasks at once never change the classes, smaller tiles
# a few points (the dmc strips in 2 or 6 tiles: 0 of 8.45 M points; the demo's in 2 or 12: 1 of 4.94 M, 974 before
# the refined ground surface was the whole cloud's choice, ``cloud_noise``).
CLASSIFY_BYTES_PER_POINT = 480
TILE_ROUND_M = 10.0
# Coarse upper limit on the number of tiles (a lying header with absurd bounds must not explode).
MAX_TILES = 1_000_000


def default_buffer_m(method: str = "morph", preset: str | None = None, ground_params=None) -> float:
    """Overlap buffer (m) beyond which a point cannot change the classes of a tile's core points: the
    reach of the ground filter (``lidarctl.classify.ground.GROUND_FILTERS``) with ``preset``; 60 m for the
    default morphological filter, 90 m for the progressive TIN densification."""
    from lidarctl.classify import ground

    return ground.reach_m(method, preset, **(ground_params or {}))


@dataclasses.dataclass(frozen=True)
class TileGrid:
    """Square tiles of ``tile_m`` anchored at (x0_m, y0_m); row index grows with y, column with x.
    All in metres (point coordinates scaled to metres before they are assigned)."""

    x0_m: float
    y0_m: float
    tile_m: float
    buffer_m: float
    nrows: int
    ncols: int

    @property
    def n_tiles(self) -> int:
        return self.nrows * self.ncols

    def core_rc(self, x: np.ndarray, y: np.ndarray):
        """(row, col) of the tile whose core holds each point; points off the grid go to the edge tile."""
        col = np.clip(np.floor((np.asarray(x) - self.x0_m) / self.tile_m), 0, self.ncols - 1).astype(np.int64)
        row = np.clip(np.floor((np.asarray(y) - self.y0_m) / self.tile_m), 0, self.nrows - 1).astype(np.int64)
        return row, col

    def core_box(self, row: int, col: int):
        """(xmin, ymin, xmax, ymax) of a tile core in metres."""
        x0 = self.x0_m + col * self.tile_m
        y0 = self.y0_m + row * self.tile_m
        return x0, y0, x0 + self.tile_m, y0 + self.tile_m

    def assign(self, x: np.ndarray, y: np.ndarray):
        """Tile memberships (core + buffer) of points: (tile_id, point_pos), sorted by tile then position.

        tile_id = row * ncols + col. A point near a core edge also lies in the buffers of the 1..3
        neighbouring tiles (``buffer_m <= tile_m``, so never further than the next tile).
        """
        return self.memberships(x, y)[:2]

    def memberships(self, x: np.ndarray, y: np.ndarray):
        """``assign`` and whether each tile holds the core of any of these points: (tile_id, point_pos,
        has_core), the last a bool per tile id."""
        # contiguous: a strided field of a record array would be a second numba specialisation (compiled
        # again on a fresh clone, about 1 CPU-s)
        return _assign_points(np.ascontiguousarray(x, float), np.ascontiguousarray(y, float), self._layout())

    def core_near(self, x: np.ndarray, y: np.ndarray):
        """(core tile id, near code) of points: the code's bits 1, 2, 4, 8 are ``memberships``' near flags
        (dc-, dc+, dr-, dr+); the point lies in the buffer of the tile (dr, dc) from its own core tile when
        ``near_code_in_buffer_of(code, dr, dc)``: the same memberships as ``assign``, one record a point."""
        return _core_near(np.ascontiguousarray(x, float), np.ascontiguousarray(y, float), self._layout())

    def _layout(self):
        """The grid as its kernels take it: (x0_m, y0_m, tile_m, buffer_m, nrows, ncols)."""
        return (float(self.x0_m), float(self.y0_m), float(self.tile_m), float(self.buffer_m), int(self.nrows),
                int(self.ncols))


def near_code_in_buffer_of(code: int, dr: int, dc: int) -> bool:
    """Whether points of near code ``code`` (``TileGrid.core_near``) belong to the tile (dr, dc) from their core
    tile (``_in_buffer_of``; their own tile: dr = dc = 0)."""
    return not ((dr == -1 and not code & 4) or (dr == 1 and not code & 8)
                or (dc == -1 and not code & 1) or (dc == 1 and not code & 2))


def plan_tiles(header: laspy.LasHeader, tile_size_m: float | None = None, buffer_m: float | None = None,
               method: str = "morph", preset: str | None = None, path="input",
               *, tile_points: int = DEFAULT_TILE_POINTS, units: LengthUnits = METRE, ground_params=None) -> TileGrid:
    """Tile grid (metres) over the header bounds (in the file's ``units``). ``header``: a LAS header, or
    anything with ``mins``, ``maxs`` and ``point_count`` (the union of several strips).

    Default tile size: an inner tile (core + buffer on all sides) of about ``tile_points`` points
    at the file's mean density (header point count over the bounding-box area), adjusted so that
    whole tiles cover the extent, rounded up to 10 m and at least twice the buffer (else the
    buffers would cost more than the cores). Default buffer: ``default_buffer_m``.
    """
    buffer_m = default_buffer_m(method, preset, ground_params) if buffer_m is None else float(buffer_m)
    if not (buffer_m >= 0 and math.isfinite(buffer_m)):
        raise OptionError(f"--buffer-m {buffer_m}: must be a non-negative distance in metres", param="--buffer-m")
    mins, maxs = _bounds_m(header, units)
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()) or (maxs[:2] < mins[:2]).any() or \
            (np.abs(np.concatenate([mins[:2], maxs[:2]])) > io.MAX_ABS_XY_M).any():
        raise InputError(f"{path}: absurd bounds in the LAS header (min {mins.tolist()}, max {maxs.tolist()})")
    width, height = max(maxs[0] - mins[0], 1e-3), max(maxs[1] - mins[1], 1e-3)
    if tile_size_m is None:
        density = header.point_count / (width * height)
        target_m = math.sqrt(tile_points / max(density, 1e-12)) - 2.0 * buffer_m
        # Whole tiles over the extent (no thin slivers of tiles along the far edges).
        target_m = max(target_m, 2.0 * buffer_m, TILE_ROUND_M)
        tile_m = max(width / max(1, round(width / target_m)), height / max(1, round(height / target_m)))
        tile_m = max(TILE_ROUND_M * math.ceil(tile_m / TILE_ROUND_M), 2.0 * buffer_m, TILE_ROUND_M)
    else:
        tile_m = float(tile_size_m)
        if not (tile_m > 0 and math.isfinite(tile_m)):
            raise OptionError(f"--tile-size-m {tile_size_m}: must be a positive size in metres", param="--tile-size-m")
        if buffer_m > tile_m:
            raise OptionError(f"--buffer-m {buffer_m:g} m is larger than the tile size {tile_m:g} m", param="--buffer-m")
    ncols = max(1, math.ceil(width / tile_m))
    nrows = max(1, math.ceil(height / tile_m))
    if ncols * nrows > MAX_TILES:
        raise InputError(f"{path}: {ncols} x {nrows} tiles of {tile_m:g} m; use a larger --tile-size-m")
    return TileGrid(float(mins[0]), float(mins[1]), tile_m, buffer_m, nrows, ncols)


def _bounds_m(header, units: LengthUnits) -> tuple[np.ndarray, np.ndarray]:
    """The header's lowest and highest x, y, z with x and y in metres."""
    mins, maxs = np.array(header.mins, float), np.array(header.maxs, float)
    if not units.is_metric:
        mins[:2], maxs[:2] = units.xy_to_m(mins[:2]), units.xy_to_m(maxs[:2])
    return mins, maxs


def window_share(grid: TileGrid, header, units: LengthUnits = METRE) -> float:
    """The share of the cloud's bounding box that one tile's window (core and buffers) covers at most: the share
    of its points a tile holds at the mean density."""
    mins, maxs = _bounds_m(header, units)
    side = grid.tile_m + 2.0 * grid.buffer_m
    width, height = max(maxs[0] - mins[0], 1e-3), max(maxs[1] - mins[1], 1e-3)
    return min(side, width) * min(side, height) / (width * height)


def classify_memory_points() -> float:
    """Tile points (buffers included) whose classification fits, at ``CLASSIFY_BYTES_PER_POINT``, in what this
    process may still take (``limits.memory_room_bytes``: 90 % of a cgroup's limit, else of the machine's, less what
    it holds); infinite where the system does not say."""
    from aerotri.core.limits import memory_room_bytes

    return max(0.0, memory_room_bytes()) / CLASSIFY_BYTES_PER_POINT


def tile_points_in_memory(workers: int, fit_points: float) -> int:
    """The default tile's points (``plan_tiles``' ``tile_points``): ``DEFAULT_TILE_POINTS``, or fewer when
    ``workers`` tiles of it side by side would not fit in ``fit_points`` (``classify_memory_points``): a batch
    job's or container's memory limit then sets the tiles, as the tiles set the memory. Smaller tiles cost
    buffer overhead, and a few points' classes (see ``CLASSIFY_BYTES_PER_POINT``)."""
    share = fit_points / max(1, int(workers))
    return DEFAULT_TILE_POINTS if share >= DEFAULT_TILE_POINTS else max(1, int(share))


def tiles_at_once(tile_points, workers: int, fit_points: float) -> int:
    """How many tiles are classified side by side: as many of the ``workers`` as the largest tiles (points with
    their buffers) fit in ``fit_points`` together; at least one."""
    largest = sorted((int(n) for n in tile_points), reverse=True)[:max(1, int(workers))]
    return max(1, int(np.searchsorted(np.cumsum(largest), fit_points, side="right")))


@dataclasses.dataclass(frozen=True)
class TileTask:
    """One classification task: small enough to ship to a Dask worker (paths and parameters)."""

    row: int
    col: int
    points_path: str        # TILE_DTYPE records (``split_into_tiles``)
    index_path: str
    classes_path: str
    core_index_path: str
    grid: TileGrid
    params: object          # classify.ClassifySettings
    numba_threads: int = 0  # threads of numba's parallel loops in this task (0: numba's default)
    units: LengthUnits = METRE  # the input's units: tile files hold coordinates in them
    fusion: object = None   # lidarctl.classify.fusion.Fusion: the orthophoto's rules after the LiDAR classes
    # lidarctl.classify.pipeline.WaterGrid: the whole cloud's water cells and density (``water_grid``), so that
    # what is water does not depend on the tile size (issue 44); None: the tile's own
    water_grid: object = None
    # lidarctl.grid.CloudFrame: the whole cloud's grid origin (its lowest x, y) and mean point spacing, so that the
    # tile's grids lie on the whole cloud's cells and its cell sizes do not depend on its window; None: the tile's own
    frame: object = None
    # per-tile resume: the finished tile's classes and core indices are kept in ``resume_dir`` under ``resume_key``
    # (everything they depend on, ``_tiles_key_doc``) until the set commits (aerotri.core.resume)
    resume_dir: str | None = None
    resume_key: str | None = None


# What a tile file holds per point: the fields the classifier reads, coordinates in the input's
# units as the first file's scales and offsets give them (see ``_tile_points``).
TILE_DTYPE = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("return_number", "u1"),
                       ("number_of_returns", "u1"), ("intensity", "<u2")])


def _tile_stem(work_dir: Path, row: int, col: int) -> Path:
    return work_dir / f"tile_{row:04d}_{col:04d}"


def _tile_points(chunk, scales, offsets) -> np.ndarray:
    """The classifier's fields of a chunk as ``TILE_DTYPE`` records. Coordinates are those of the
    integer records in ``scales`` / ``offsets`` (the first file's): a strip with other offsets is
    re-expressed on that integer grid as a merged file would hold it (laspy's rounding), so the
    classes do not depend on which strip a point came from."""
    out = np.empty(len(chunk), TILE_DTYPE)
    same = np.array_equal(chunk.scales, scales) and np.array_equal(chunk.offsets, offsets)
    for k, name in enumerate(("x", "y", "z")):
        v = np.asarray(getattr(chunk, name))
        if not same:
            v = np.round((v - offsets[k]) / scales[k]).astype(np.int32) * scales[k] + offsets[k]
        out[name] = v
    for name in ("return_number", "number_of_returns", "intensity"):
        out[name] = np.asarray(chunk[name])
    return out


@numba.njit(cache=True)
def _in_buffer_of(near, dr, dc):
    """Whether a point with the near flags (dc-, dc+, dr-, dr+) belongs to the tile (dr, dc) from its own
    (its own tile: dr = dc = 0)."""
    return not ((dr == -1 and not near[2]) or (dr == 1 and not near[3])
                or (dc == -1 and not near[0]) or (dc == 1 and not near[1]))


@numba.njit(cache=True)
def _core_near(x, y, layout):
    """``TileGrid.core_near``: the core tile and the near flags of ``_assign_points`` (same arithmetic) as a code;
    ``layout``: ``TileGrid._layout``."""
    x0, y0, tile_m, buffer_m, nrows, ncols = layout
    n = len(x)
    tile = np.empty(n, np.int64)
    code = np.empty(n, np.uint8)
    for k in range(n):
        c = min(max(np.floor((x[k] - x0) / tile_m), 0.0), ncols - 1.0)
        r = min(max(np.floor((y[k] - y0) / tile_m), 0.0), nrows - 1.0)
        ci, ri = int(c), int(r)
        tile[k] = ri * ncols + ci
        fx = x[k] - (x0 + ci * tile_m)
        fy = y[k] - (y0 + ri * tile_m)
        code[k] = ((1 if (fx < buffer_m and ci > 0) else 0) | (2 if (fx >= tile_m - buffer_m and ci < ncols - 1) else 0)
                   | (4 if (fy < buffer_m and ri > 0) else 0) | (8 if (fy >= tile_m - buffer_m and ri < nrows - 1) else 0))
    return tile, code


@numba.njit(cache=True)
def _assign_points(x, y, layout):
    """``TileGrid.memberships`` in one pass: counting sort of the memberships by tile, positions ascending;
    ``layout``: ``TileGrid._layout`` (x0_m, y0_m, tile_m, buffer_m, nrows, ncols)."""
    x0, y0, tile_m, buffer_m, nrows, ncols = layout
    n = len(x)
    row = np.empty(n, np.int64)
    col = np.empty(n, np.int64)
    near = np.empty((n, 4), np.int8)   # dc- dc+ dr- dr+ flags
    count = np.zeros(nrows * ncols + 1, np.int64)
    own = np.zeros(nrows * ncols, np.bool_)
    for k in range(n):
        c = min(max(np.floor((x[k] - x0) / tile_m), 0.0), ncols - 1.0)
        r = min(max(np.floor((y[k] - y0) / tile_m), 0.0), nrows - 1.0)
        ci, ri = int(c), int(r)
        row[k], col[k] = ri, ci
        own[ri * ncols + ci] = True
        fx = x[k] - (x0 + ci * tile_m)
        fy = y[k] - (y0 + ri * tile_m)
        near[k, 0] = fx < buffer_m and ci > 0
        near[k, 1] = fx >= tile_m - buffer_m and ci < ncols - 1
        near[k, 2] = fy < buffer_m and ri > 0
        near[k, 3] = fy >= tile_m - buffer_m and ri < nrows - 1
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                if _in_buffer_of(near[k], dr, dc):
                    count[(ri + dr) * ncols + ci + dc + 1] += 1
    start = np.cumsum(count)
    ids = np.empty(start[-1], np.int64)
    pos = np.empty(start[-1], np.int64)
    fill = start[:-1].copy()
    for k in range(n):
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                if not _in_buffer_of(near[k], dr, dc):
                    continue
                t = (row[k] + dr) * ncols + col[k] + dc
                ids[fill[t]] = t
                pos[fill[t]] = k
                fill[t] += 1
    return ids, pos, own


def split_into_tiles(in_paths, grid: TileGrid, work_dir, params, chunk_points: int = io.CHUNK_POINTS,
                     records_paths=None, *, units: LengthUnits = METRE, withheld: list | None = None,
                     lowest: list | None = None):
    """Pass 1: stream the input file(s) and append each tile's points to its points file (``TILE_DTYPE``);
    list of TileTask.

    ``in_paths``: one LAS/LAZ file or a list of strips (one point format, see ``merge.check_strips``);
    a tile gathers its points from all of them. Point indices run over the strips one after the other
    (a strip's first point follows the previous strip's last). Every chunk is validated (InputError
    naming the file and record for NaN / absurd coordinates; truncated files are reported by
    ``las.iter_chunks``). Tiles without core points get no task. With ``records_paths`` (one per
    file) the raw point records are also copied there in file order (uncompressed), so that writing
    the outputs needs no second decompression of a LAZ input. ``units``: the inputs' linear units
    (points are assigned to tiles in metres; the tile files hold coordinates in these units, on the
    first file's scales and offsets, ``_tile_points``). Records flagged withheld (``las.usable``) go to no
    tile (the records copy keeps them); ``withheld``: a list that gets (point indices, delivered classes) of
    them, for the output to keep. ``lowest``: a list that gets the lowest x and y (m) of the points classified.
    """
    in_paths = [Path(in_paths)] if isinstance(in_paths, (str, Path)) else [Path(q) for q in in_paths]
    work_dir = Path(work_dir)
    headers = [las.read_header(q) for q in in_paths]
    scales, offsets = np.asarray(headers[0].scales, float), np.asarray(headers[0].offsets, float)
    has_core = np.zeros(grid.n_tiles, bool)
    offset = 0
    n_withheld, first_withheld = [0] * len(in_paths), {}
    low_xy = None
    with progress(sum(h.point_count for h in headers), "tiles: split", "pt", unit_scale=True) as bar:
        for k, (in_path, header) in enumerate(zip(in_paths, headers)):
            records = open(records_paths[k], "wb") if records_paths is not None else None
            try:
                for first, chunk in las.iter_file_chunks(in_path, chunk_points, withheld=True):
                    if records is not None:
                        records.write(chunk.array.tobytes())
                    n_read = len(chunk)
                    if (mask := las.usable(chunk)) is not None:
                        if withheld is not None:
                            left = np.flatnonzero(~mask)
                            withheld.append((left + (offset + first),
                                             np.asarray(chunk.classification, np.uint8)[left]))
                        kept = np.flatnonzero(mask)
                        chunk = chunk[mask]
                        n_withheld[k] += n_read - len(kept)
                        first_withheld.setdefault(k, first + int(np.argmin(mask)))
                    else:
                        kept = None
                    x, y = np.asarray(chunk.x), np.asarray(chunk.y)
                    io.validate_xyz(in_path, x, y, np.asarray(chunk.z), first, units)
                    x, y = units.xy_to_m(x), units.xy_to_m(y)
                    if len(x):
                        low = (float(np.min(x)), float(np.min(y)))
                        low_xy = low if low_xy is None else (min(low_xy[0], low[0]), min(low_xy[1], low[1]))
                    ids, pos, own = grid.memberships(x, y)
                    has_core |= own
                    del x, y
                    index = pos if kept is None else kept[pos]
                    points = _tile_points(chunk, scales, offsets)
                    del chunk
                    # Rows of bytes: numpy gathers them ~10x faster than structured records.
                    rows = points.view(np.uint8).reshape(len(points), TILE_DTYPE.itemsize)
                    bounds = np.flatnonzero(np.diff(ids)) + 1
                    for sel_ids, sel_pos, sel_idx in zip(np.split(ids, bounds), np.split(pos, bounds),
                                                         np.split(index, bounds)):
                        tid = int(sel_ids[0])
                        stem = _tile_stem(work_dir, tid // grid.ncols, tid % grid.ncols)
                        with open(stem.with_suffix(".pts"), "ab") as fh:
                            np.take(rows, sel_pos, axis=0).tofile(fh)
                        with open(stem.with_suffix(".index"), "ab") as fh:
                            (sel_idx + (offset + first)).tofile(fh)
                    bar.update(n_read)
            finally:
                if records is not None:
                    records.close()
            if n_withheld[k]:
                las.note_withheld(in_path, n_withheld[k], header.point_count, first_withheld[k])
            offset += header.point_count
    if lowest is not None and low_xy is not None:
        lowest.extend(low_xy)
    tasks = []
    for tid in np.flatnonzero(has_core):
        r, c = divmod(int(tid), grid.ncols)
        stem = _tile_stem(work_dir, r, c)
        tasks.append(TileTask(r, c, str(stem.with_suffix(".pts")), str(stem.with_suffix(".index")),
                              str(stem) + ".classes.npy", str(stem) + ".core.npy", grid, params,
                              units=units))
    return tasks


@contextlib.contextmanager
def _numba_threads(n: int):
    """Limit numba's parallel loops in this thread (numba's setting is thread-local): tasks running
    side by side on a small machine should not each start a thread per core."""
    if n <= 0:
        yield
        return
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        numba.set_num_threads(before)


@dataclasses.dataclass(frozen=True)
class TileResult:
    """What one tile task did: points with the buffer, core points, seconds."""

    row: int
    col: int
    n_points: int
    n_core: int
    seconds: float


def classify_tile(task: TileTask) -> TileResult:
    """Pass 2 (an executor task): classify one tile with its buffer, keep the core points' classes.

    Writes ``classes_path`` (uint8 ASPRS classes) and ``core_index_path`` (int64 point indices in
    the input file), both in input order. Returns small statistics (points, seconds). With
    ``task.resume_dir`` both files (hard links) and the statistics are kept there for a resumed run
    (``_resumed_tile``), the statistics last: a tile is kept whole or not at all.
    """
    result = _classify_tile(task)
    if task.resume_dir and task.resume_key:
        keep = ResumeFolder(Path(task.resume_dir))
        keep.keep(task.classes_path, task.resume_key, ".classes.npy")
        keep.keep(task.core_index_path, task.resume_key, ".core.npy")
        keep.put_text(task.resume_key, ".json", json.dumps(dataclasses.asdict(result)) + "\n")
    return result


def _resumed_tile(task: TileTask) -> TileResult | None:
    """The statistics of ``task``'s tile kept by an earlier, interrupted run (its two files linked to the task's
    paths), or None when none is kept whole."""
    keep = ResumeFolder(Path(task.resume_dir))
    text = keep.get_text(task.resume_key, ".json")
    classes, core = keep.kept(task.resume_key, ".classes.npy"), keep.kept(task.resume_key, ".core.npy")
    if text is None or classes is None or core is None:
        return None
    try:
        result = TileResult(**json.loads(text))
        shapes = {np.load(f, mmap_mode="r").shape for f in (classes, core)}
    except (ValueError, TypeError, OSError):
        return None
    if (result.row, result.col) != (task.row, task.col) or shapes != {(result.n_core,)}:
        return None
    link_or_copy(classes, task.classes_path)
    link_or_copy(core, task.core_index_path)
    return result


def _tiles_key_doc(in_paths, grid: TileGrid, params, units: LengthUnits, fusion) -> dict:
    """What every tile's classes depend on but its place in the grid: the strips in order (name, size,
    modification time: they set the points and their indices), the grid, the settings, the units, the fusion's
    image and rules, the classification rules' version at these settings (``lidarctl.classify.rules_version``:
    tiles kept before a rule changed are not reused) and the toolkit's version (not the scheduler or the chunk size: the classes do
    not depend on them)."""
    import aerotri
    from lidarctl.classify import rules_version

    doc = {"strips": [[Path(q).name, file_stamp(q)] for q in in_paths], "grid": dataclasses.asdict(grid),
           "settings": dataclasses.asdict(params), "units": repr(units), "rules_version": rules_version(params),
           "version": aerotri.__version__}
    if fusion is not None:
        img = fusion.image
        doc["fusion"] = {"image": dataclasses.asdict(img), "rules": dataclasses.asdict(fusion.params),
                         "stamps": [file_stamp(q) for q in (img.path, img.nir_path) if q]}
    return doc


def _classify_tile(task: TileTask) -> TileResult:
    """``classify_tile`` without the keeping for a resumed run."""
    from lidarctl.classify import pipeline as cl

    t0 = time.perf_counter()
    index = np.fromfile(task.index_path, dtype=np.int64)
    x, y, z, rn, nr, intensity, core = _tile_window(task)
    if len(index) != len(x):
        raise RuntimeError(f"{task.points_path}: {len(x)} points but {len(index)} indices")
    water_grid = task.water_grid
    if water_grid is not None:
        water_grid = dataclasses.replace(water_grid, window_m=_window_m(task.grid, task.row, task.col))
    if len(x) >= 10:
        with _numba_threads(task.numba_threads):
            # the noise codes and ground ``cloud_noise`` found in this window with this frame (None: not kept)
            kept = Path(_bare_earth_path(task))
            found = None
            if task.frame is not None and task.frame.ground_noise_m is not None and kept.exists():
                code_ground = np.load(kept)
                found = (code_ground[:, 0].copy(), code_ground[:, 1].astype(bool))
                offsets = Path(_plane_offsets_path(task))
                if offsets.exists():  # the lifted-ground test's plane offsets of that ground (dz, spread)
                    dz_spread = np.load(offsets)
                    found += ((dz_spread[:, 0].copy(), dz_spread[:, 1].copy()),)
            classes = cl.classify_points(x, y, z, rn, nr, intensity, params=task.params, fusion=task.fusion,
                                         water_grid=water_grid, frame=task.frame, bare_earth=found)[core]
    else:
        # Too few points for any neighbourhood statistics (a stray point at the edge of the grid).
        classes = np.full(int(core.sum()), cl.UNCLASSIFIED, np.uint8)
    with atomic_path(task.classes_path) as tmp:
        np.save(tmp, classes)
    with atomic_path(task.core_index_path) as tmp:
        np.save(tmp, index[core])
    return TileResult(task.row, task.col, int(len(x)), int(core.sum()), time.perf_counter() - t0)


def _tile_window(task):
    """A tile's points with its buffer (``task``: its ``points_path``, ``units``, ``grid``, ``row``, ``col``): x, y,
    z (m), return number, number of returns, intensity, and the mask of its core points."""
    rec = np.fromfile(task.points_path, dtype=TILE_DTYPE)
    u = task.units
    x, y, z = (np.ascontiguousarray(rec[f]) for f in ("x", "y", "z"))
    x, y, z = u.xy_to_m(x), u.xy_to_m(y), u.z_to_m(z)
    rn, nr = io.sanitize_returns(rec["return_number"], rec["number_of_returns"])
    intensity = np.ascontiguousarray(rec["intensity"])
    del rec
    row, col = task.grid.core_rc(x, y)
    return x, y, z, rn, nr, intensity, (row == task.row) & (col == task.col)


def core_ground_residuals(task: TileTask, *, figure: str) -> TileResiduals:
    """An executor task of ``cloud_noise``: the residuals (m) of the tile's core points from which the whole
    cloud's noise ``figure`` is taken, as ``classify_points`` finds them in the tile's window with ``task.frame``:
    ``refine_sigma_m``: the ground filter's residuals from its refined surface (``ground.morphological_ground``);
    ``ground_noise_m``: the heights of the ground points above their local planes (``classify.ground_plane_offsets``,
    absolute). Written to ``_residuals_path``; returns their ``TileResiduals``. With ``ground_noise_m``
    (its frame holds the whole cloud's ``refine_sigma_m``), the noise codes and ground the tile's classification
    starts from are kept too (``_bare_earth_path``: ``classify_points(bare_earth=...)`` does not find them again)."""
    from lidarctl.classify import pipeline as cl

    x, y, z, rn, nr, _, core = _tile_window(task)
    res = np.zeros(0)
    share = None
    if len(x) >= 10:
        with _numba_threads(task.numba_threads):
            refine = [] if figure == "refine_sigma_m" else None
            code, is_ground, _, spacing_m = cl.bare_earth(x, y, z, rn, nr, params=task.params, frame=task.frame,
                                                          refine_residuals=refine)
            if refine is not None:
                if refine:
                    at, res, cells = refine[0]
                    res = res[core[at]]
                    share = _core_refine_share(task, cells, core)
            else:
                with atomic_path(_bare_earth_path(task)) as tmp:
                    np.save(tmp, np.column_stack([code, is_ground]).astype(np.uint8))
                ground = np.flatnonzero(is_ground)
                dz, spread = cl.ground_plane_offsets(x, y, z, ground, spacing_m)
                with atomic_path(_plane_offsets_path(task)) as tmp:  # classify_tile's lifted-ground test takes them
                    np.save(tmp, np.column_stack([dz, spread]))
                dz = dz[core[ground]]   # the core's ground points (their neighbours from the window)
                res = np.abs(dz[np.isfinite(dz)])
    with atomic_path(_residuals_path(task)) as tmp:
        np.save(tmp, res)
    return TileResiduals(len(res), float(res.min()) if len(res) else 0.0, float(res.max()) if len(res) else 0.0,
                         share)


@dataclasses.dataclass(frozen=True)
class RefineShare:
    """A tile core's share of what chooses the ground filter's refined surface (``ground.RefineCells``): its first
    ground points, the occupied refinement cells whose centre lies in it (each cell of the whole cloud counted in
    one tile), the choice its window made and the threshold (ground points per cell)."""

    ground_points: int
    cells: int
    dense: bool
    dense_points_per_cell: float


@dataclasses.dataclass(frozen=True)
class TileResiduals:
    """What ``core_ground_residuals`` found in a tile's core (the residuals themselves are in ``_residuals_path``):
    how many (``count``), the lowest and the highest (m), and with ``refine_sigma_m`` the core's ``RefineShare``
    (else None)."""

    count: int
    low_m: float
    high_m: float
    share: RefineShare | None = None


def _core_refine_share(task: TileTask, cells, core: np.ndarray) -> RefineShare:
    """``RefineShare`` of ``task``'s core from its window's ``ground.RefineCells`` (``core``: the window's core
    mask; the window's ground of its core points and of the cells centred in its core is the whole cloud's, the
    buffer being at least the filter's reach)."""
    r0, c0 = cells.offset
    rows, cols = np.divmod(np.asarray(cells.cells, np.int64), int(cells.ncols))
    frame = task.frame
    cx = frame.x0_m + (cols + c0 + 0.5) * cells.cell_m
    cy = frame.y0_m + (rows + r0 + 0.5) * cells.cell_m
    row, col = task.grid.core_rc(cx, cy)
    own = int(np.count_nonzero((row == task.row) & (col == task.col)))
    return RefineShare(int(np.count_nonzero(core[cells.ground])), own, bool(cells.dense),
                       float(cells.dense_points_per_cell))


def _bare_earth_path(task: TileTask) -> str:
    return task.classes_path.removesuffix(".classes.npy") + ".bare_earth.npy"


def _plane_offsets_path(task: TileTask) -> str:
    return task.classes_path.removesuffix(".classes.npy") + ".plane_offsets.npy"


def _residuals_path(task: TileTask) -> str:
    return task.classes_path.removesuffix(".classes.npy") + ".residuals.npy"


def _median_of_files(paths, n: int, low: float, high: float, transform=None) -> float:
    """``np.median`` of the values in the .npy files ``paths`` (``n`` of them, between ``low`` and ``high``; after
    ``transform``), exactly, in memory of one file: a histogram, then the values of the bins holding the middle
    ones."""
    edges = np.linspace(low, high, 4097)

    def values(q):
        v = np.load(q)
        return v if transform is None else transform(v)

    def bin_of(v):
        return np.clip(np.searchsorted(edges, v, side="right") - 1, 0, len(edges) - 2)

    cum = np.cumsum(sum(np.bincount(bin_of(values(q)), minlength=len(edges) - 1) for q in paths))
    middle = []
    for rank in ((n - 1) // 2, n // 2):
        b = int(np.searchsorted(cum, rank, side="right"))
        in_bin = np.sort(np.concatenate([v[bin_of(v) == b] for v in map(values, paths)]))
        middle.append(float(in_bin[rank - (int(cum[b - 1]) if b else 0)]))
    return 0.5 * (middle[0] + middle[1])


def cloud_noise(tasks, frame, params, executor, at_once: int | None = None):
    """``frame`` (``grid.CloudFrame``: the whole cloud's origin and spacing) with the whole cloud's noise figures,
    so that every tile's ground tolerances are those of the whole cloud, whatever the tiling (in a tile's own
    window they were the window's: the lifted-ground sigma 13 to 18 mm on AHN3 Delft's 60 m tiles, the refine
    tolerance 0.100 to 0.103 m): ``refine_sigma_m``, the robust spread of the ground filter's residuals from its
    refined surface (``ground.robust_spread_m``), then, with it, ``ground_noise_m``, the lifted-ground test's and the
    rooftop-object rule's sigma (``classify.ground_noise_m``): each from all the cloud's points, each from the tile whose core holds it
    (``core_ground_residuals``; two passes of the ground filter over the tiles); exact medians in memory of one
    tile. A figure without residuals stays None (the tile's own). Before the refine residuals' spread, the refined
    surface they are taken from is the whole cloud's choice (``refine_dense``: its first ground points per occupied
    refinement cell, each counted in the tile whose core holds it), and a tile whose window chose the other
    surface (a window denser or sparser than the cloud) finds its residuals again: before, the demo's strips in 430 m
    tiles took the grid of means in 6 of 12 windows, the TIN in the others and the whole cloud (its spread 0.0545
    against the whole cloud's 0.0513 m) and 974 points' classes differed from 2 tiles', all over the block."""
    from lidarctl.classify import pipeline as cl

    def residual_files(frame, figure, found=None, only=None):
        todo = [dataclasses.replace(t, frame=frame) for t in tasks]
        found = list(found) if found is not None else [None] * len(todo)
        again = [k for k in range(len(todo)) if only is None or k in only]
        for k, f in zip(again, executor.map(functools.partial(core_ground_residuals, figure=figure),
                                            [todo[k] for k in again], desc=f"tiles: {figure}", unit="tile",
                                            at_once=at_once)):
            found[k] = f
        n = sum(f.count for f in found)
        low = min((f.low_m for f in found if f.count), default=0.0)
        high = max((f.high_m for f in found if f.count), default=0.0)
        return [_residuals_path(t) for t in todo], n, low, high, found

    paths, n, low, high, found = residual_files(frame, "refine_sigma_m")
    shares = [f.share for f in found if f.share is not None]
    if shares and sum(s.cells for s in shares):
        # The refined surface (a grid of means or a TIN) as the whole cloud chooses it: its first ground points per
        # occupied refinement cell. The tiles whose window chose the other surface find their residuals again.
        dense = sum(s.ground_points for s in shares) >= shares[0].dense_points_per_cell * sum(s.cells for s in shares)
        frame = dataclasses.replace(frame, refine_dense=dense)
        other = {k for k, f in enumerate(found) if f.share is not None and f.share.dense != dense}
        if other:
            logger.debug("tiles: %d of %d tiles find their refine residuals again on the whole cloud's %s surface",
                         len(other), len(tasks), "mean" if dense else "TIN")
            paths, n, low, high, found = residual_files(frame, "refine_sigma_m", found, other)
    if n:
        med = _median_of_files(paths, n, low, high)
        spread = max(abs(high - med), abs(med - low))
        frame = dataclasses.replace(frame, refine_sigma_m=1.4826 * _median_of_files(
            paths, n, 0.0, spread, transform=lambda v: np.abs(v - med)))
    if cl.ground_noise_needed(params):
        paths, n, low, high, _ = residual_files(frame, "ground_noise_m")
        if n:
            frame = dataclasses.replace(frame, ground_noise_m=1.4826 * _median_of_files(paths, n, low, high))
    for q in paths:
        Path(q).unlink(missing_ok=True)
    return frame


def _window_m(grid: TileGrid, row: int, col: int):
    """A tile's buffered box (xmin, ymin, xmax, ymax; m), infinite where it has no neighbour (the points beyond
    the grid's outer edges belong to its edge tiles)."""
    x0, y0, x1, y1 = grid.core_box(row, col)
    b = grid.buffer_m
    return (x0 - b if col > 0 else -np.inf, y0 - b if row > 0 else -np.inf,
            x1 + b if col < grid.ncols - 1 else np.inf, y1 + b if row < grid.nrows - 1 else np.inf)


@dataclasses.dataclass(frozen=True)
class CellCountTask:
    """Returns per cell of a grid over the whole cloud (cells of ``cell_m`` from its lowest x, y ``x0_m``,
    ``y0_m``), counted in one tile: the cells whose centre lies in the tile's core (each cell in one tile), from
    the tile's points with their buffer (a cell wholly inside when the buffer is at least half a cell)."""

    row: int
    col: int
    points_path: str
    grid: TileGrid
    units: LengthUnits
    x0_m: float
    y0_m: float
    cell_m: float
    # also return the tile's occupied cells (row, column on the whole grid; the survey's footprint)
    with_cells: bool = False
    # also return the lowest, median and highest return (m) of each of those cells (the whole cloud's level water)
    with_heights: bool = False
    # with ``with_heights``: write the cells and their heights under this folder by level tile (``spool_side``
    # cells; ``level_tiles.spool_cells``) and return none of them (the whole cloud's level bodies, level-wire)
    spool_dir: str | None = None
    spool_side: int = 0


def cell_count_histogram(task: CellCountTask):
    """How many of the tile's cells (``CellCountTask``) hold k returns, k = 0, 1, ... (index 0 stays 0: the
    empty cells are not counted); int64. ``with_cells``: (histogram, (k, 2) int64 row and column of the occupied
    cells on the whole cloud's grid)."""
    rec = np.fromfile(task.points_path, dtype=TILE_DTYPE)
    x, y = task.units.xy_to_m(np.ascontiguousarray(rec["x"])), task.units.xy_to_m(np.ascontiguousarray(rec["y"]))
    z = task.units.z_to_m(np.ascontiguousarray(rec["z"])) if task.with_heights else None
    inten = np.ascontiguousarray(rec["intensity"]) if task.with_heights else None
    del rec
    if not len(x):
        if task.with_heights:
            return np.zeros(1, np.int64), np.zeros((0, 2), np.int64), np.zeros((0, 3)), np.zeros(0)
        return (np.zeros(1, np.int64), np.zeros((0, 2), np.int64)) if task.with_cells else np.zeros(1, np.int64)
    c = task.cell_m
    j = np.floor((x - task.x0_m) / c).astype(np.int64)
    i = np.floor((y - task.y0_m) / c).astype(np.int64)
    del x, y
    i0, j0 = int(i.min()), int(j.min())
    ncols = int(j.max()) - j0 + 1
    counts = np.bincount((i - i0) * ncols + (j - j0))
    cells = np.flatnonzero(counts)
    ci, cj = np.divmod(cells, ncols)
    row, col = task.grid.core_rc(task.x0_m + (cj + j0 + 0.5) * c, task.y0_m + (ci + i0 + 0.5) * c)
    own = (row == task.row) & (col == task.col)
    hist = np.bincount(counts[cells[own]], minlength=1)
    hist[0] = 0
    ij = np.column_stack([ci[own] + i0, cj[own] + j0]).astype(np.int64)
    if task.with_heights:
        flat = (i - i0) * ncols + (j - j0)
        order = np.lexsort((z, flat))
        start = np.r_[0, np.cumsum(counts[cells])[:-1]]
        cnt = counts[cells]
        zs = z[order]
        lo, hi = zs[start], zs[start + cnt - 1]
        med = 0.5 * (zs[start + (cnt - 1) // 2] + zs[start + cnt // 2])
        if task.spool_dir is not None:
            from lidarctl.classify import level_tiles

            level_tiles.spool_cells(task.spool_dir, task.spool_side, (task.row, task.col), ij,
                                    np.column_stack([lo, med, hi])[own])
            # the lowest returns' intensities counted here: no array of the cells to the parent
            return hist.astype(np.int64), ij[:0], np.zeros((0, 3)), np.bincount(inten[order[start]][own].astype(
                np.int64), minlength=1)
        return hist.astype(np.int64), ij, np.column_stack([lo, med, hi])[own], inten[order[start]][own]
    if task.with_cells:
        return hist.astype(np.int64), ij
    return hist.astype(np.int64)


def _median_of_histogram(hist: np.ndarray) -> float:
    """``np.median`` of the values k repeated hist[k] times (0.0 when empty)."""
    n = int(hist.sum())
    if n == 0:
        return 0.0
    cum = np.cumsum(hist)
    lo = int(np.searchsorted(cum, (n - 1) // 2, side="right"))
    hi = int(np.searchsorted(cum, n // 2, side="right"))
    return 0.5 * (lo + hi)


def water_grid(tasks, grid: TileGrid, params, lowest, executor, units: LengthUnits = METRE, work_dir=None):
    """The whole cloud's ``WaterGrid`` from its tiles (before they are classified): the mean point spacing as
    ``grid.mean_spacing_m`` gives it for the whole cloud (occupied 10 m cells from its lowest x, y), the water
    cell from it (``water_cell_m`` or max(1 m, 2 spacings), as ``classify_points`` takes it) and the median
    returns per occupied water cell; two passes over the tile files, each tile counting the cells whose centre
    lies in its core (memory of one tile). With ``water_whole_level_bodies`` the tiles write their water cells
    under ``work_dir`` (the run's scratch; default: beside the first tile's points) by level tile and the level
    bodies are found tile by tile there (``level_tiles.whole_level_bodies_spooled``; the parent holds the tiles'
    summaries, no array per cell); the tiles read their windows' bodies from there (``SpooledLevelBodies``)."""
    from lidarctl.classify import level_tiles
    from lidarctl.classify import pipeline as cl

    x0, y0 = lowest

    def histogram(cell_m, desc, with_cells=False, with_heights=False, keep_heights=True, spool=(None, 0)):
        jobs = [CellCountTask(t.row, t.col, t.points_path, grid, units, x0, y0, cell_m, with_cells, with_heights,
                              *spool) for t in tasks]
        total, cells, heights, lowest_i = np.zeros(1, np.int64), [], [], []
        intensity_hist = np.zeros(1, np.int64)  # without keep_heights: the cells' lowest intensities, counted
        for h in executor.map(cell_count_histogram, jobs, desc=desc, unit="tile"):
            if with_heights:
                h, ij, zz, ii = h
                if keep_heights:
                    heights.append(zz)
                    lowest_i.append(ii)
                else:  # memory of one tile, not of the cloud's cells (spooled: counted by the tile)
                    b = ii if spool[0] is not None else np.bincount(np.asarray(ii, np.int64), minlength=1)
                    if len(b) > len(intensity_hist):
                        b, intensity_hist = intensity_hist, b
                    intensity_hist[:len(b)] += b
            if with_cells or (with_heights and keep_heights):
                h, ij = (h, ij) if with_heights else h
                cells.append(ij)
            if len(h) > len(total):
                h, total = total, h
            total[:len(h)] += h
        if with_heights and not keep_heights:
            return total, intensity_hist
        if with_heights:
            return total, np.concatenate(cells), np.concatenate(heights), np.concatenate(lowest_i)
        return (total, np.concatenate(cells)) if with_cells else total

    occupied, ij = histogram(cl.COVERAGE_CELL_M, "tiles: density", with_cells=True)
    n = int((occupied * np.arange(len(occupied))).sum())
    spacing = float(np.sqrt(int(occupied.sum()) * cl.COVERAGE_CELL_M ** 2 / max(n, 1)))
    c = cl.water_cell_size_m(spacing, params)
    # the survey's footprint on the same 10 m cells, for the water rules' "beyond the coverage" (issue 44)
    occ = np.zeros(tuple(ij.max(axis=0) + 1) if len(ij) else (1, 1), bool)
    occ[ij[:, 0], ij[:, 1]] = True
    wg = cl.WaterGrid(cell_m=float(c), x0_m=float(x0), y0_m=float(y0), median_count=0.0,
                      footprint_10m=cl.survey_footprint(occ), spacing_m=spacing)
    # the water cells: their returns per cell and the lowest return's intensity (the land's reflectance); with the
    # whole cloud's level bodies (``water_whole_level_bodies``) also each cell's lowest, median and highest return
    bodies = params.water_whole_level_bodies and params.level_water_min_area_m2 > 0
    if not bodies:
        hist, intensity_hist = histogram(c, "tiles: water cells", with_heights=True, keep_heights=False)
        return dataclasses.replace(wg, median_count=_median_of_histogram(hist), land_intensity=float(
            _median_of_histogram(intensity_hist)) if intensity_hist.sum() else float("nan"))
    folder = Path(work_dir if work_dir is not None else Path(tasks[0].points_path).parent) / "level_bodies"
    shutil.rmtree(folder, ignore_errors=True)   # (nothing of an earlier call read as a neighbour's)
    folder.mkdir(parents=True)
    side = level_tiles.level_tile_cells(float(c), params)
    hist, intensity_hist = histogram(c, "tiles: water cells", with_heights=True, keep_heights=False,
                                     spool=(str(folder), side))
    wg = dataclasses.replace(wg, median_count=_median_of_histogram(hist), land_intensity=float(
        _median_of_histogram(intensity_hist)) if intensity_hist.sum() else float("nan"))
    store = level_tiles.CellSpool.from_fragments(folder, side)
    ncols = level_tiles.whole_level_bodies_spooled(store, wg, params)
    found = frozenset(t for t in store.tiles if store.get("out_keys", t) is not None)
    return dataclasses.replace(wg, level_bodies=level_tiles.SpooledLevelBodies(ncols, side, str(folder), found))


def _direct_classes(in_paths, crs, params, chunk_points, fusion=None):
    """Classes of a one-tile input in memory (no temporary files): the tiled path with one tile.
    (classes of all files' points one after the other, the records of each file, each file's ``PointCloud.used``,
    the CRS of the first)."""
    from lidarctl.classify import pipeline as cl

    read = [io.read_cloud(q, crs=crs, chunk_points=chunk_points, keep_records=True) for q in in_paths]
    fields = ("x", "y", "z", "return_number", "number_of_returns", "intensity")
    cloud = {f: np.concatenate([getattr(c, f) for c, _ in read]) for f in fields}
    if len(cloud["x"]) < 10:
        raise InputError(f"{in_paths[0]}: only {len(cloud['x'])} points; classification needs at least 10")
    classes = cl.classify_points(*(cloud[f] for f in fields), params=params, fusion=fusion)
    return classes, [r for _, r in read], [c.used for c, _ in read], read[0][0].crs


@dataclasses.dataclass(frozen=True)
class ClassifyRun:
    """What the passes of ``classify_file`` did: tasks, points classified (with buffers, so at least
    the file's count), class counts of the output and seconds per pass (``split_s`` and
    ``tile_cpu_s``, the seconds summed over the tasks, only for a tiled run)."""

    n_tiles: int
    tiled_points: int
    max_tile_points: int
    class_counts: dict[int, int]
    classify_s: float
    write_s: float
    split_s: float | None = None
    tile_cpu_s: float | None = None


@dataclasses.dataclass(frozen=True)
class ClassifyStats:
    """Statistics of ``classify_file`` / ``classify_files``: the points of the ``n_files`` files, the
    tile grid (metres), their units, the passes, total seconds and the CRS (text; None when unknown)."""

    n_points: int
    grid: TileGrid
    units: LengthUnits
    run: ClassifyRun
    seconds: float
    crs: str | None
    n_files: int = 1

    @property
    def buffer_overhead(self) -> float:
        """Points classified (cores + buffers) per point of the file."""
        return self.run.tiled_points / self.n_points


def classify_file(in_path, out_path, crs=None, params=None, *, tile_size_m: float | None = None,
                  buffer_m: float | None = None, executor=None, work_dir=None,
                  chunk_points: int = io.CHUNK_POINTS, fusion=None, resume_dir=None) -> ClassifyStats:
    """Classify a LAS/LAZ file of any size into ``out_path`` (LAS/LAZ by suffix), tile by tile.

    ``crs``: used only when the file has none (never guessed). ``params``: classify.ClassifySettings.
    ``tile_size_m`` / ``buffer_m``: metres, default from ``plan_tiles``; a cloud in feet is classified
    in metres (its CRS's units) and written back unchanged but for the classes. ``executor``: an
    ``aerotri.core.executor.Executor`` (default: local threads). ``work_dir``: parent folder of the
    temporary tile files (default: next to the output); they are removed in any case.
    The output is written atomically: on any error or interrupt no output file is left.
    ``fusion`` (``lidarctl.classify.fusion.Fusion``): fuse each tile's classes with an orthophoto.
    ``resume_dir``: as in ``classify_files`` (a tiled run only).
    Returns statistics: points, tiles, buffer overhead, seconds per pass, class counts.
    """
    in_path, out_path = Path(in_path), Path(out_path)
    refuse_input_as_output(out_path, [in_path], "OUT_PATH")
    with _resumable(resume_dir, out_path) as keep:
        return _classify([in_path], [out_path], crs, params, tile_size_m=tile_size_m, buffer_m=buffer_m,
                         executor=executor, work_parent=Path(work_dir) if work_dir is not None else out_path.parent,
                         tiles_name=out_path.stem, chunk_points=chunk_points, fusion=fusion, resume=keep)


def _resumable(resume_dir, out_path):
    """``aerotri.core.resume.resumable`` over ``resume_dir`` (None: no resume). An error leaves no output of any
    kind, the tiles kept for a resumed run included; an interrupt or a kill keeps them. The chain's work/ goes when
    an error leaves it empty; the folder that holds ``out_path`` and its ``resume.beside`` folder is the user's."""
    if resume_dir is None:
        return contextlib.nullcontext()
    return resumable(resume_dir, remove_empty_parent=not is_beside(resume_dir, out_path))


def classified_names(in_paths, suffix: str | None = None) -> list[str]:
    """File names of the classified strips: each strip's stem with ``suffix`` (".las" / ".laz"; None:
    the strip's own). Two strips with one name are an OptionError naming both."""
    names: dict[str, Path] = {}
    for q in map(Path, in_paths):
        name = q.stem + (suffix if suffix is not None else q.suffix.lower())
        if name in names:
            raise OptionError(f"{q}: its classified strip would be named {name}, like that of {names[name]}; "
                              "rename one of the strips", param="IN_PATHS")
        names[name] = q
    return list(names)


CLASSIFY_RECORD = "classify.json"  # in OUT_DIR: the names classify_files wrote there (provenance for a rerun)
CLASSIFY_RECORD_KIND = "lidarctl classify"


def classified_record_names(out_dir) -> frozenset[str] | None:
    """The file names the record ``CLASSIFY_RECORD`` in ``out_dir`` says ``classify_files`` wrote there; None:
    no such record (a folder written before 2026-12-01, a user's folder, or a file of that name not ours)."""
    try:
        d = json.loads((Path(out_dir) / CLASSIFY_RECORD).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or d.get("kind") != CLASSIFY_RECORD_KIND or not isinstance(d.get("files"), list):
        return None
    return frozenset(str(n) for n in d["files"])


def refuse_replacing_classified(out_dir, names) -> None:
    """OptionError (OUT_DIR) when ``out_dir``, replaced as a whole, holds what ``classify_files`` did not write
    there. With our record (``CLASSIFY_RECORD``): the files it names are ours; without (an output written before
    the record, or a user's folder): only LAS/LAZ named as this run's outputs (``names``, derived from the inputs)
    are, so a user's LAS/LAZ of other names is refused, not deleted (reviewer 14)."""
    recorded = classified_record_names(out_dir) if Path(out_dir).is_dir() else None
    if recorded is not None:
        owned = lambda e: e.is_file() and (e.name == CLASSIFY_RECORD or e.name in recorded)  # noqa: E731
        what = "lidarctl classify"  # its record names what it wrote
    else:
        owned = lambda e: e.is_file() and e.name in names  # noqa: E731
        what = (f"lidarctl classify (the folder has no {CLASSIFY_RECORD}, and only the classified strips named after "
                "this run's inputs are taken for its earlier output)")
    refuse_foreign_contents(out_dir, owned, what, "OUT_DIR")


def classify_files(in_paths, out_dir, crs=None, params=None, *, suffix: str | None = None,
                   tile_size_m: float | None = None, buffer_m: float | None = None, executor=None,
                   work_dir=None, chunk_points: int = io.CHUNK_POINTS, fusion=None, resume_dir=None) -> ClassifyStats:
    """Classify LiDAR strips (LAS/LAZ files) together, without merging them: one classified copy per
    strip in ``out_dir`` (names: ``classified_names``; LAS/LAZ by ``suffix``, default the strip's).

    The tile grid covers the union of the strips' header bounds and a tile gathers its points (core
    and buffer) from every strip, so points in the overlap of two strips are classified with both
    strips' neighbours, as in a merged file. Each output is its strip with new classes (header,
    VLRs, EVLRs and point records copied; ``io.write_classified``). The strips must share one point
    format and one CRS (``merge.check_strips``: InputError / CrsError naming the strip that differs);
    ``crs`` is the CRS of strips without a CRS record (a strip tagged with another CRS is refused).
    ``out_dir`` holds the set and is replaced as a whole, atomically (``atomic_dir``): all outputs
    or none; an input inside it is refused. ``resume_dir``: the tiles an interrupted run of the same strips and
    settings finished are taken from there, the others kept there as they finish (module doc, "Resume"); None: no
    resume. Other parameters as in ``classify_file``.
    """
    from lidarctl.merge import check_strips

    in_paths = [Path(q) for q in in_paths]
    if not in_paths:
        raise InputError("no LAS/LAZ strips to classify")
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(in_paths)  # a strip given twice would count every point twice
    out_dir = Path(out_dir)
    names = classified_names(in_paths, suffix)
    for q in in_paths:
        if out_dir.resolve() == q.resolve() or out_dir.resolve() in q.resolve().parents:
            raise OptionError(f"{q}: the input lies in the output folder {out_dir}, which is replaced as a whole; "
                              "choose another output folder", param="OUT_DIR")
    # the folder is replaced as a whole: a previous run's classified strips may go, a user's other files may not
    refuse_replacing_classified(out_dir, names)
    project_crs = parse_crs(crs, "--crs") if crs is not None and str(crs).strip() else None
    check_strips(in_paths, [las.read_header(q) for q in in_paths], project_crs)
    parent = Path(work_dir) if work_dir is not None else out_dir.parent
    with _resumable(resume_dir, out_dir) as keep, atomic_dir(out_dir) as tmp:
        st = _classify(in_paths, [tmp / name for name in names], crs, params, tile_size_m=tile_size_m,
                       buffer_m=buffer_m, executor=executor, work_parent=parent, tiles_name=out_dir.name,
                       chunk_points=chunk_points, fusion=fusion, resume=keep)
        (tmp / CLASSIFY_RECORD).write_text(json.dumps({"schema_version": 1, "kind": CLASSIFY_RECORD_KIND, "files": names}, indent=2) + "\n")
        return st


def _union_bounds(headers):
    """The strips' headers as one for ``plan_tiles``: the union of their bounds, their summed count."""
    import types

    return types.SimpleNamespace(mins=np.min([h.mins for h in headers], axis=0),
                                 maxs=np.max([h.maxs for h in headers], axis=0),
                                 point_count=sum(h.point_count for h in headers))


def _classify(in_paths, out_paths, crs, params, *, tile_size_m, buffer_m, executor, work_parent, tiles_name,
              chunk_points, fusion=None, resume: ResumeFolder | None = None) -> ClassifyStats:
    """``classify_file`` / ``classify_files``: the files in ``in_paths`` (checked to agree) classified
    together, each written to its ``out_paths`` entry."""
    from lidarctl.classify import pipeline as cl

    t0 = time.perf_counter()
    params = params or cl.ClassifySettings()
    headers = [las.read_header(q) for q in in_paths]
    for q, h in zip(in_paths, headers):
        if h.point_count == 0:
            raise InputError(f"{q}: the file holds no points")
    crs_units = [io.resolve_crs_units(q, h, crs) for q, h in zip(in_paths, headers)]
    resolved, units = crs_units[0]
    for q, (_, u) in zip(in_paths[1:], crs_units[1:]):
        if u != units:
            raise InputError(f"{q}: {u.describe()}, but {in_paths[0]} {units.describe()}; give strips in one unit")
    cl.set_place_units(units)
    name = in_paths[0] if len(in_paths) == 1 else f"{in_paths[0]} (+{len(in_paths) - 1} strips)"
    out_crs = io.record_crs(crs, resolved)
    bounds = headers[0] if len(headers) == 1 else _union_bounds(headers)
    grid = plan_tiles(bounds, tile_size_m, buffer_m, params.ground_method, params.preset, name, units=units,
                      ground_params=params.ground_params)
    side_by_side = _tasks_in_this_memory(executor)
    if tile_size_m is None and side_by_side is not None:
        tile_points = tile_points_in_memory(side_by_side, classify_memory_points())
        smaller = plan_tiles(bounds, None, buffer_m, params.ground_method, params.preset, name, units=units,
                             ground_params=params.ground_params, tile_points=tile_points)
        # only where a tile's window holds less than half the cloud: else the buffers would cost more memory than
        # the smaller cores save (AHN3 Delft's 640 k points at 400 MiB: two windows, each nearly the whole cloud)
        if tile_points < DEFAULT_TILE_POINTS and window_share(smaller, bounds, units) <= 0.5:
            from aerotri.core.limits import format_bytes, usable_memory_bytes

            logger.info("tiles of about %s points with their buffers (default %s): %d side by side fit in the %s "
                        "this process may use", f"{tile_points:,}", f"{DEFAULT_TILE_POINTS:,}", side_by_side,
                        format_bytes(usable_memory_bytes()))
            grid = smaller
    n = int(bounds.point_count)

    def stats(run):
        return ClassifyStats(n_points=n, grid=grid, units=units, run=run, seconds=time.perf_counter() - t0,
                             crs=resolved.to_string() if resolved is not None else None, n_files=len(in_paths))

    if params.keep_classes and fusion is not None:
        raise OptionError("--image: not with --keep-classes (the delivered classes are kept as they are)",
                          param="--image")
    if params.keep_classes:
        runs = [_keep_delivered(q, out, out_crs=out_crs, units=units, chunk_points=chunk_points, t0=t0)
                for q, out in zip(in_paths, out_paths)]
        counts = np.zeros(256, np.int64)
        for r in runs:
            for c, k in r.class_counts.items():
                counts[c] += k
        return stats(dataclasses.replace(runs[0], class_counts=_class_counts(counts),
                                         write_s=sum(r.write_s for r in runs), classify_s=runs[-1].classify_s))
    logger.debug("%s: %d points, %d x %d tiles of %g m + %g m buffer", name, n, grid.nrows, grid.ncols,
                 grid.tile_m, grid.buffer_m)
    try:
        if grid.n_tiles == 1:
            run = _classify_whole(in_paths, out_paths, crs=crs, out_crs=out_crs, params=params,
                                  chunk_points=chunk_points, t0=t0, fusion=fusion)
        else:
            run = _classify_tiled(in_paths, out_paths, out_crs=out_crs, units=units, params=params, grid=grid,
                                  executor=executor, work_parent=work_parent, tiles_name=tiles_name,
                                  chunk_points=chunk_points, t0=t0, fusion=fusion, resume=resume,
                                  tile_size_m=tile_size_m)
    except ResourceError as exc:
        # A grid inside the classifier would not fit: name the file (points spread far apart, e.g.
        # strips of two zones merged under one CRS).
        raise ResourceError(f"{name}: {exc}", param=exc.param) from exc
    return stats(run)


def _tasks_in_this_memory(executor) -> int | None:
    """How many classification tasks share this process's memory at most: its executor's workers (the worker
    processes of a ``local:N`` cluster run under the same limit); None for a remote cluster, whose workers have
    their own memory."""
    executor = executor if executor is not None else local_executor()
    if executor.distributed and not str(executor.scheduler).startswith("local:"):
        return None
    return max(1, int(executor.workers))


def _checked_tiles_at_once(tasks, executor, tile_size_m) -> int | None:
    """``tiles_at_once`` of the split tiles under this process's memory (None: as many as the executor runs); a
    warning when the largest tile alone would not fit (an explicit ``--tile-size-m``, or the smallest tile the
    buffer allows), naming the option."""
    side_by_side = _tasks_in_this_memory(executor)
    if side_by_side is None or not tasks:
        return None
    points = [Path(t.points_path).stat().st_size // TILE_DTYPE.itemsize for t in tasks]
    fit = classify_memory_points()
    k = tiles_at_once(points, side_by_side, fit)
    if max(points) > fit:
        from aerotri.core.limits import format_bytes, usable_memory_bytes

        grid = tasks[0].grid
        logger.warning("the largest tile (%s points with its %g m buffer) may need %s of memory to classify, more "
                       "than this process has left of the %s it may use: it runs alone; %s", f"{max(points):,}",
                       grid.buffer_m, format_bytes(max(points) * CLASSIFY_BYTES_PER_POINT),
                       format_bytes(usable_memory_bytes()),
                       "a smaller --tile-size-m keeps it within" if tile_size_m is not None else
                       "smaller tiles (lidarctl classify --tile-size-m) keep it within where their buffers leave "
                       "them less than half the cloud")
    elif k < min(side_by_side, len(tasks)):
        logger.info("tiles: %d at a time of %d workers (the memory this process may use)", k, side_by_side)
    return k


def _keep_delivered(in_path, out_path, *, out_crs, units, chunk_points, t0) -> ClassifyRun:
    """``classify_file`` with ``keep_classes``: the delivered classes checked (``lidarctl.classify.delivered_classes``)
    and copied to the output as they are."""
    from lidarctl.classify.delivered_classes import check_delivered_classes

    found = check_delivered_classes(in_path, units, chunk_points)
    classes = np.concatenate([np.asarray(c.classification, np.uint8)
                              for _, c in las.iter_file_chunks(in_path, chunk_points, withheld=True)])
    t1 = time.perf_counter()
    io.write_classified(in_path, out_path, classes, crs=out_crs)
    logger.info("%s: delivered classes kept (ground %.1f %% of the points in %.0f %% of the cells)", in_path,
                100 * found.ground_share, 100 * found.ground_cell_share)
    return ClassifyRun(n_tiles=0, tiled_points=0, max_tile_points=0, class_counts=found.class_counts,
                       classify_s=t1 - t0, write_s=time.perf_counter() - t1)


def _class_counts(counts: np.ndarray) -> dict[int, int]:
    return {int(c): int(counts[c]) for c in np.flatnonzero(counts)}


def _classify_whole(in_paths, out_paths, *, crs, out_crs, params, chunk_points, t0, fusion=None) -> ClassifyRun:
    """A one-tile input: classified in memory, each file written from the records kept."""
    classes, records, used, _ = _direct_classes(in_paths, crs, params, chunk_points, fusion)
    t1 = time.perf_counter()
    first = 0
    counts = np.zeros(256, np.int64)
    for q, out, rec, u in zip(in_paths, out_paths, records, used):
        count = sum(len(c) for c in rec) if u is None else int(u.sum())
        part = classes[first:first + count]
        first += count
        if u is not None:  # withheld records keep their delivered class
            full = np.concatenate([np.asarray(c.classification, np.uint8) for c in rec])
            full[u] = part
            part = full
        io.write_classified(q, out, part, crs=out_crs, records=rec)
        counts += np.bincount(part, minlength=256)
    return ClassifyRun(n_tiles=1, tiled_points=len(classes), max_tile_points=len(classes),
                       class_counts=_class_counts(counts),
                       classify_s=t1 - t0, write_s=time.perf_counter() - t1)


def _classify_tiled(in_paths, out_paths, *, out_crs, units, params, grid, executor, work_parent, tiles_name,
                    chunk_points, t0, fusion=None, resume: ResumeFolder | None = None,
                    tile_size_m: float | None = None) -> ClassifyRun:
    """In tiles: split all files (pass 1), classify tiles on the executor (pass 2), scatter the core
    classes into a memory-mapped file and write each output from its records copy (pass 3). ``resume``: the
    tiles an interrupted run of the same inputs and settings finished are taken from there (pass 2 skips them),
    the others kept there as they finish."""
    headers = [las.read_header(q) for q in in_paths]
    n = sum(h.point_count for h in headers)
    if n < 10:
        raise InputError(f"{in_paths[0]}: only {n} points; classification needs at least 10")
    if executor is None:
        executor = local_executor()
    tmp_dir = temporary_dir(work_parent, f"{tiles_name}.tiles")
    try:
        records_paths = [tmp_dir / f"records_{k}.bin" for k in range(len(in_paths))]
        withheld, lowest = [], []
        tasks = split_into_tiles(in_paths, grid, tmp_dir, params, chunk_points, records_paths, units=units,
                                 withheld=withheld, lowest=lowest)
        if fusion is not None:
            tasks = [dataclasses.replace(t, fusion=fusion) for t in tasks]
        resumed = {}
        if resume is not None:
            doc = _tiles_key_doc(in_paths, grid, params, units, fusion)
            tasks = [dataclasses.replace(t, resume_dir=str(resume.path), resume_key=resume_key({**doc, "tile": [
                t.row, t.col]})) for t in tasks]
            resumed = {k: r for k, t in enumerate(tasks) if (r := _resumed_tile(t)) is not None}
            if resumed:
                logger.info(f"tiles: resumed {len(resumed)} of {len(tasks)} tiles an interrupted run finished "
                            f"({resume.path})")
        todo = [t for k, t in enumerate(tasks) if k not in resumed]
        # the ground filter's passes over all the tiles below hold a tile's points as the classification does
        at_once = _checked_tiles_at_once(tasks if todo else [], executor, tile_size_m)
        if lowest and len(tasks) > 1 and todo:
            # what is water is decided on the whole cloud's water cells and density (issue 44); not when every
            # tile is resumed (two passes over the tile files for nothing: the kept tiles' keys do not hold it)
            wg = water_grid(tasks, grid, params, lowest, executor, units, work_dir=tmp_dir)
            frame = lidar_grid.CloudFrame(x0_m=wg.x0_m, y0_m=wg.y0_m, spacing_m=wg.spacing_m)
            frame = cloud_noise(tasks, frame, params, executor, at_once)
            todo = [dataclasses.replace(t, water_grid=wg, frame=frame) for t in todo]
        # Cores per task: tasks run side by side on the executor's workers (on a remote cluster
        # numba keeps its default; the classes do not depend on it).
        per_task = executor.cores_per_task(len(todo), at_once)
        if per_task is not None:
            todo = [dataclasses.replace(t, numba_threads=per_task) for t in todo]
        t1 = time.perf_counter()
        done = iter(executor.map(classify_tile, todo, desc="tiles: classify", unit="tile", at_once=at_once))
        results = [resumed[k] if k in resumed else next(done) for k in range(len(tasks))]
        t2 = time.perf_counter()
        # 0 is no class classify_points assigns: it marks points no tile core claimed.
        classes = np.lib.format.open_memmap(tmp_dir / "classes.npy", mode="w+", dtype=np.uint8, shape=(n,))
        for task in tasks:
            classes[np.load(task.core_index_path)] = np.load(task.classes_path)
        for index, delivered in withheld:  # not classified: the delivered class
            classes[index] = delivered
        classes.flush()
        # withheld records delivered as class 0 (never classified) are no points the tiling missed
        unclassified = np.sort(np.concatenate([i[d == 0] for i, d in withheld])) if withheld else None
        counts = np.zeros(256, np.int64)
        first = 0
        with progress(n, "tiles: write", "pt", unit_scale=True) as bar:
            for q, out, h, rp in zip(in_paths, out_paths, headers, records_paths):
                checked = _CheckedClasses(classes[first:first + h.point_count],
                                          None if unclassified is None else unclassified - first)
                io.write_classified(q, out, checked, crs=out_crs, progress=bar.update,
                                    records=_stored_records(rp, h, chunk_points))
                counts += checked.counts
                first += h.point_count
        del classes
        t3 = time.perf_counter()
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return ClassifyRun(n_tiles=len(tasks), tiled_points=int(sum(r.n_points for r in results)),
                       max_tile_points=int(max(r.n_points for r in results)), class_counts=_class_counts(counts),
                       classify_s=t2 - t1, write_s=t3 - t2, split_s=t1 - t0,
                       tile_cpu_s=float(sum(r.seconds for r in results)))


def _stored_records(path, header: laspy.LasHeader, chunk_points: int):
    """Point-record chunks of the raw copy made in pass 1, read one chunk at a time (plain reads,
    not a memory map: mapped pages would count in the resident memory until the end)."""
    fmt = header.point_format
    with open(path, "rb") as fh:
        for first in range(0, header.point_count, chunk_points):
            count = min(chunk_points, header.point_count - first)
            array = np.fromfile(fh, dtype=fmt.dtype(), count=count)
            if len(array) != count:
                raise RuntimeError(f"{path}: records copy ends at point {first + len(array)}")
            yield laspy.ScaleAwarePointRecord(array, fmt, header.scales, header.offsets)


class _CheckedClasses:
    """Slices of the assembled classes, refusing points that no tile core claimed (class 0)."""

    def __init__(self, classes, zero_ok=None):
        self._classes = classes
        self._zero_ok = zero_ok  # sorted indices whose class 0 is delivered (withheld records)
        self.counts = np.zeros(256, np.int64)

    def __len__(self):
        return len(self._classes)

    def __getitem__(self, sl):
        part = np.asarray(self._classes[sl])
        missing = int((part == 0).sum())
        if missing and self._zero_ok is not None:
            start, stop, _ = sl.indices(len(self._classes))
            missing -= int(np.searchsorted(self._zero_ok, stop) - np.searchsorted(self._zero_ok, start))
        if missing:
            raise RuntimeError(f"tiling left {missing} points without a class")
        self.counts += np.bincount(part, minlength=256)
        return part


# output names that are files of another kind, never the folder a block's strips are written into
_NOT_A_FOLDER_SUFFIXES = (".txt", ".csv", ".xyz", ".pts", ".ply", ".e57", ".tif", ".tiff", ".gpkg", ".geojson",
                          ".json", ".shp", ".zip", ".asc", ".bin", ".dat", ".copc")


def classify_command(in_paths, out_path, keep_classes: bool = False, method: str = "morph", preset: str | None = None,
                     *, crs=None, tile_size_m: float | None = None,
                     buffer_m: float | None = None, work_dir=None, out_format: str | None = None, image_path=None,
                     nir=None, ground_params_file=None, ground_options=None, method_given: bool = True,
                     preset_given: bool = True, scheduler=None, workers=None, resume: bool = True) -> str:
    """``lidarctl classify``: one file (IN_PATH OUT_PATH, a .las/.laz name) or strips into a folder, with the
    ground filter's parameter file and per-parameter options over ``params`` (``ground.resolve_options``:
    ``ground_options`` {(filter, name): value or None}; ``method_given``/``preset_given``: the command line named
    them, so the file's do not count), fused with an orthophoto (``image_path``, ``nir``); ``keep_classes``: the
    delivered classes, checked. The other settings are ``ClassifySettings``' defaults. The finished tiles are kept in
    ``resume.beside(out_path)`` until the output is written, and an interrupted run's are taken from there;
    ``resume`` False: those are removed first (start over). Returns the line the command prints."""
    from aerotri.core.executor import executor_for
    from lidarctl.classify import pipeline as cl
    from lidarctl.classify import ground

    to_folder = len(in_paths) > 1 or Path(out_path).is_dir() or Path(out_path).suffix.lower() not in (".las", ".laz")
    if to_folder and not Path(out_path).exists() and Path(out_path).suffix.lower() in _NOT_A_FOLDER_SUFFIXES:
        # (new-user trial: `classify IN c7.txt` made a folder c7.txt holding the classified cloud)
        raise OptionError(f"{out_path}: a {Path(out_path).suffix} file name; the output is a .las/.laz file (one input) "
                          "or a folder (strips; a name without a file extension)", param="OUT_PATH")
    if not to_folder:
        refuse_input_as_output(out_path, in_paths, "OUT_PATH")
        if out_format is not None:
            raise OptionError("--format: only for an output folder (OUT_PATH names the file and its format)",
                              param="--format")
    method, preset, overrides = ground.resolve_options(method, preset, ground_params_file, ground_options,
                                                       method_given=method_given, preset_given=preset_given)
    params = cl.ClassifySettings(ground_method=method, preset=preset, ground_params=overrides, keep_classes=keep_classes)
    if nir is not None and image_path is None:
        raise OptionError("--nir: only with --image", param="--nir")
    fusion = None
    if image_path is not None:
        from lidarctl.classify import fusion as fu

        refuse_input_as_output(out_path, [image_path, None if nir is None or str(nir).isdigit() else nir], "OUT_PATH")
        cloud_crs, units = io.resolve_crs_units(in_paths[0], las.read_header(in_paths[0]), crs)
        fusion = fu.Fusion(fu.open_image(image_path, nir, cloud_crs, units.xy_m))
    resume_dir = beside(out_path)
    if not resume:
        discard_kept(resume_dir)
    common = dict(crs=crs, params=params, tile_size_m=tile_size_m, buffer_m=buffer_m, work_dir=work_dir, fusion=fusion,
                  resume_dir=resume_dir)
    with executor_for(scheduler, workers) as executor:
        if not keep_classes:   # (after the options' checks, the executor's among them)
            from lidarctl.normalised import warn_if_normalised

            warn_if_normalised(in_paths, crs)
        if to_folder:
            stats = classify_files(in_paths, out_path, executor=executor,
                                   suffix=None if out_format is None else f".{out_format}", **common)
        else:
            stats = classify_file(in_paths[0], out_path, executor=executor, **common)
        described = executor.describe()
    header = las.read_header(in_paths[0])
    names = dict(cl.CLASS_NAMES)
    if io.ROAD_SURFACE not in io.ground_classes(header):
        # delivered class 11 of a file before LAS 1.4 is no road (trial s94: MixedConifer's five canopy returns)
        names[io.ROAD_SURFACE] = f"class 11 (reserved in LAS {header.version})"
    counts = ", ".join(f"{names.get(c, str(c))} {k:,}" for c, k in stats.run.class_counts.items())
    n, dt, u = stats.n_points, stats.seconds, stats.units
    what = f"{out_path}: {n:,} points" + (f" of {counted(stats.n_files, 'strip')}" if to_folder else "")
    reserved = [c for c, k in stats.run.class_counts.items() if k and 13 <= c <= 31]
    if reserved and (header.version.major, header.version.minor) < (1, 4) and not params.keep_classes:
        # trial s94: AHN3 Delft, LAS 1.2, got 963 bridge-deck (17) returns and a high-noise one (18) without a word
        logger.warning(f"{out_path}: classes {', '.join(f'{c} ({names.get(c, c)})' for c in reserved)} are ASPRS "
                       f"LAS 1.4 classes, which LAS {header.version} (the input's version, kept) reserves: its readers "
                       "may show them as reserved")
    if params.keep_classes:
        return f"{what}, the delivered classes kept; {counts}"
    if fusion is not None and nir is None and stats.run.class_counts.get(io.ROAD_SURFACE, 0):
        # trial s96 F1 (HIGH): on Autzen's real orthophoto every road return lay on grass, a gravel bank or beside
        # trees, none on the paved path, and nothing said so; the rule's figures are the simulator's alone
        logger.warning(f"{out_path}: {stats.run.class_counts[io.ROAD_SURFACE]:,} road surface (11) returns from an "
                       "orthophoto without a near-infrared band: dry or winter grass and bare soil that the image "
                       "does not show green pass the road rule as pavement (it is scored on the simulator only, "
                       "docs/lidar-products.md); check the roads against the image, or give --nir")
    if fusion is not None and stats.run.class_counts.get(3, 0):
        # The fusion labels a lawn's ground returns grass (3), a land cover; a DEM of ground classes leaves them out
        # (Autzen: 46 % of the ground returns, the DEM 1.42 ft RMS off them against 0.27 ft), and the roads (11) too
        # where the LAS version reserves 11 (before 1.4: io.ground_classes)
        on_ground = io.ground_classes(header)
        roads = stats.run.class_counts.get(io.ROAD_SURFACE, 0) if io.ROAD_SURFACE not in on_ground else 0
        logger.warning(f"{out_path}: fused with {image_path}: {stats.run.class_counts[3]:,} returns are grass (3), most "
                       "of them on the ground" + (f", and {roads:,} are road surface (11), a class LAS "
                                                  f"{header.version} reserves" if roads else "")
                       + f"; a DEM is made of classes {', '.join(map(str, on_ground))} only (lidarctl rasters), so "
                       "make DEMs, nDSMs and contours from a classification without --image")
    unit_text = "" if u.xy_name == "m" and u.z_name == "m" else \
        f"; coordinates in {u.xy_name}, heights in {u.z_name}, processed in metres"
    return (f"{what} in {dt:.1f} s ({n / dt:,.0f} points/s; {counted(stats.run.n_tiles, 'tile')} of "
            f"{stats.grid.tile_m:g} m + {stats.grid.buffer_m:g} m buffer, {described}{unit_text}); {counts}")
