"""Rasters from a classified cloud: DEM, DSM, nDSM, CHM, intensity (Cloud-Optimized GeoTIFF) and a
hillshade quicklook (PNG).

Grid: cells of ``res_m`` metres aligned to multiples of ``res_m`` metres in the cloud's CRS, north-up.

Units: the grids are computed in metres (clouds in feet are scaled as they are read) and written in
the cloud's CRS and units: in a foot CRS a 1 m cell is 3.2808 ft (3.2808 US survey ft) wide in the
GeoTIFF transform, and heights (dem, dsm, ndsm, chm) are in the CRS's vertical unit. Every GeoTIFF
says so: the band's unit type (``metre``, ``foot``, ``US survey foot``; none for intensity), its
description, and the tags ``LINEAR_UNITS``, ``VERTICAL_UNITS`` and ``CELL_SIZE_M``; intensity.tif has
``QUANTITY=intensity`` instead of ``VERTICAL_UNITS`` (given as a DEM, it is refused).
* dem.tif: mean height of ground (2) and water (9) points per cell; gaps inside the footprint
  filled (pull-push interpolation); nodata outside it.
* dsm.tif: highest first return (noise excluded) per cell, gaps filled as for the DEM; then raised to the highest
  return of any number in the cell, and a cell no return hit to the DEM plus the CHM's fill (``dsm_filled``: a
  tilted pulse's later return from a crown can fall in a cell whose own first returns reached the ground through a
  gap, which the CHM counts): nDSM >= CHM. A building return on a wall (one under an eave: more than
  ``beneath.BENEATH_DZ_M`` below a building return and above a return of any class within
  ``beneath.BENEATH_RADIUS_M``) counts at the roof's height (``beneath``).
* dsm_nearest.tif: height of the first return (noise excluded) nearest each cell centre (``nearest``: the
  surface straight down at the centres, the true ortho's occlusion test), building returns on a wall at the
  roof's height; the DSM's value where none lies within ``nearest.SEARCH_RADIUS_M``; nodata where the DSM is.
* ndsm.tif: dsm - dem.
* chm.tif: highest vegetation (classes 4, 5) height above the DEM per cell; a cell no return hit takes the mean of
  its observed neighbours (a cell seen without trees counts 0); nodata where no trees (and in wider gaps).
* intensity.tif: mean intensity of first returns (nodata where none).
The footprint is the set of cells within ``footprint_cells`` cells of a point.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from typing import ClassVar, NamedTuple
import logging
import sys
from pathlib import Path

import numba
import numpy as np
from rasterio.io import MemoryFile
from rasterio.shutil import copy as rio_copy
from rasterio.transform import from_origin
from scipy import ndimage

from aerotri.geom import las
from lidarctl import io
from aerotri.core.atomic import atomic_path, refuse_input_as_output, temporary_dir
from aerotri.core.resume import ResumeFolder, file_stamp, is_beside, resumable, resume_key
from aerotri.core.errors import InputError, OptionError
from aerotri.core.log import counted
from aerotri.core.gdal_cache import MiB, stage_block_cache
from aerotri.core.settings import setting
from aerotri.core.limits import (cache_bytes, check_allocation, check_task_count, format_bytes, memory_room_bytes,
                                 resident_bytes, usable_memory_bytes)
from aerotri.core.limits import check_disk
from lidarctl.grid import check_grid
from lidarctl.io import PointCloud
from lidarctl.rasters import beneath, nearest
from lidarctl.rasters.cells import LOW_VEGETATION, VEGETATION, CellStats
from lidarctl.raster_ops import DEFAULT_TIN_FILL_RADIUS_PX, fill_nodata, fill_nodata_tin
from aerotri.geom.crs.definition import length_unit_name, parse_crs
from aerotri.geom.crs.raster_warp import INTENSITY_DESCRIPTION, QUANTITY_TAG
from lidarctl.units import METRE, LengthUnits

log = logging.getLogger(__name__)

NODATA = -9999.0
FILES = ("dem.tif", "dsm.tif", "ndsm.tif", "chm.tif", "intensity.tif", "hillshade.png", nearest.FILE)
HEIGHT_GRIDS = ("dem", "dsm", "ndsm", "chm", "dsm_nearest")


@dataclasses.dataclass(frozen=True)
class RasterGrids:
    """The rasters of a cloud (``make_grids``): float32 arrays, rows north-up, NaN = nodata, and the GeoTIFF
    transform; heights (DEM, DSM, nDSM, CHM) and the transform in metres, or in the CRS's units after
    ``in_crs_units``; intensity as the points record it."""

    dem: np.ndarray
    dsm: np.ndarray
    ndsm: np.ndarray
    chm: np.ndarray
    intensity: np.ndarray
    transform: object  # affine.Affine
    dsm_nearest: np.ndarray

    def in_crs_units(self, units: LengthUnits) -> "RasterGrids":
        """The grids in the cloud's units: heights divided by the vertical unit, the transform by the horizontal
        unit (these very grids for metres)."""
        if units.is_metric:
            return self
        heights = {n: (getattr(self, n).astype(float) / units.z_m).astype(np.float32) for n in HEIGHT_GRIDS}
        return dataclasses.replace(self, **heights, transform=_transform_in_units(self.transform, units))
DESCRIPTIONS = {"dem": "DEM: mean height of ground and water points",
                "dsm": "DSM: highest first return, raised to any higher return; wall returns at the roof above",
                "ndsm": "nDSM: DSM - DEM", "chm": "CHM: highest vegetation above the DEM",
                "intensity": INTENSITY_DESCRIPTION,   # (by which a DEM reader refuses it: raster_warp.not_heights)
                "dsm_nearest": "DSM: first return nearest the cell centre"}
# Memory of a tile per cell of its window at the peak of ``_CellSums`` and the TIN fill (per-cell
# records, the pull-push pyramid, the triangulation; measured: 1.07 GB peak RSS with one tile of
# 2304 x 2224 cells at a time, 1.65 GB with two, of which 0.25 GB the process itself). Two tiles are
# computed at once when they fit in half of the RAM.
# (+8: the highest return of any number, ``CellStats.top``; +28: the highest building return and the lowest return,
# and the wall returns' roof, foot and lift held through the second pass, ``beneath``)
RASTER_BYTES_PER_CELL = 196
# Tiles of the rasters of LAS/LAZ files (cells): a 2048 + 2 x 256 cell window needs about 1 GB
# (RASTER_BYTES_PER_CELL); both multiples of 256, so the gap filling's pyramid blocks up to 256
# cells coincide with the whole grid's.
DEFAULT_TILE_PX = 2048
MIN_AUTO_TILE_PX = 256  # the smallest tile chosen for a memory limit (``_tile_px_in_memory``)
DEFAULT_BUFFER_PX = 256


def cell_of_units(res_m: float, units: LengthUnits) -> float:
    """``res_m`` made a whole number of the CRS's horizontal units (or 1/2, 1/4, 1/5, 1/10 of one) when within 10 ppm
    of it (``lidarctl.units.whole_units``): a US survey foot typed as 0.3048006096 m made cells of 0.999999999996 ft
    on an origin off the whole foot (trial-us), which no other 1 ft tile lines up with. Said in the log."""
    from lidarctl.units import whole_units

    whole = whole_units(res_m, units.xy_m)
    if whole is None or whole * units.xy_m == res_m:
        return res_m
    log.info(f"--res-m {res_m:.10g} is {res_m / units.xy_m:.10g} {units.xy_name}: cells of {whole:g} {units.xy_name} "
             f"({whole * units.xy_m:.10g} m)")
    return whole * units.xy_m


def check_res(res_m: float) -> None:
    if not (np.isfinite(res_m) and res_m > 0):
        raise OptionError(f"--res-m {res_m}: must be a positive cell size in metres", param="--res-m")


@dataclasses.dataclass(frozen=True)
class RasterSettings:
    """Options of the raster stage (``[rasters]`` in project.toml; ``lidarctl rasters --res-m``)."""

    SECTION: ClassVar[str] = "rasters"

    res_m: float = setting(0.5, min=0.0, min_open=True, help="Cell size in metres.")


def grid_for_bounds(xmin: float, ymin: float, xmax: float, ymax: float, res_m: float):
    """(res_m, x0, y0, nrows, ncols) of the raster grid covering the bounds, aligned to multiples of res_m."""
    x0 = np.floor(xmin / res_m) * res_m
    y0 = np.floor(ymin / res_m) * res_m
    # the product can round above the bound (AHN3 Delft: 447412.8 / 0.2 = 2237064, times 0.2 = 447412.80000000005):
    # the cell kernels, floor((y - y0) / res_m), then put the lowest points in row -1 (a RuntimeError, new-user trial)
    if np.floor((xmin - x0) / res_m) < 0:
        x0 -= res_m
    if np.floor((ymin - y0) / res_m) < 0:
        y0 -= res_m
    ncols = int(np.floor((xmax - x0) / res_m)) + 1
    nrows = int(np.floor((ymax - y0) / res_m)) + 1
    return res_m, x0, y0, nrows, ncols


# More cells than this per point (cells finer than a tenth of the points' spacing): said before the work starts
CELLS_PER_POINT_WARN = 100


def warn_cells_finer_than_points(n_points: int, n_cells: int, res_m: float, names: str) -> None:
    """A warning when the grid has more than ``CELLS_PER_POINT_WARN`` cells a point over the header bounds: such cells
    measure nothing the points do not (the DEM and DSM interpolate between points), and dsm_nearest searches up to
    its radius from nearly every cell (0.01 m cells on Autzen's 2 points per m2: 617 M cells, hours, started without
    a word; new-user trial)."""
    if n_points <= 0 or n_cells <= CELLS_PER_POINT_WARN * n_points:
        return
    spacing_m = res_m * math.sqrt(n_cells / n_points)
    log.warning(f"{names}: cells of {res_m:g} m on points about {spacing_m:.2g} m apart over the header bounds "
                f"({n_cells:,} cells, {n_cells / n_points:,.0f} a point): the grids interpolate between the points and "
                f"take long; cells of half the points' spacing ({spacing_m / 2:.2g} m) show what they measure "
                "(--res-m)")


class _CellSums:
    """Per-cell sums, counts and maxima, accumulated chunk by chunk (same result as all at once:
    maxima are exact; means are sums over counts, equal up to the summation order).

    ``args``: (res_m, x0, y0, nrows, ncols) of the grid; ``offset``: (row, col) of its first cell in
    a larger grid whose origin is (x0, y0) (a tile window, which may reach beyond that grid). Cell
    indices are always computed from the large grid's origin, so a point falls into the same global
    cell in a tile as in the whole grid. The loops are ``raster_cells``' (numba, one pass a chunk)."""

    def __init__(self, args, offset: tuple[int, int] = (0, 0)):
        self.args = args
        self.offset = offset
        self._stats = CellStats(args[0], args[1], args[2], args[3], args[4], row0=offset[0], col0=offset[1])
        self._beneath = None

    # per-cell arrays (flat): points not noise, sum and count of ground heights, highest first return,
    # sum and count of first-return intensities, highest vegetation above the DEM
    valid_n = property(lambda self: self._stats.valid_n)
    ground_sum = property(lambda self: self._stats.ground_sum)
    ground_n = property(lambda self: self._stats.ground_n)
    dsm = property(lambda self: self._stats.dsm)
    inten_sum = property(lambda self: self._stats.inten_sum)
    inten_n = property(lambda self: self._stats.inten_n)
    chm = property(lambda self: self._stats.chm)

    def add(self, x, y, z, cls, return_number, intensity) -> None:
        """Pass 1: occupancy, ground mean, first-return DSM maximum and mean intensity."""
        self._stats.add(x, y, z, cls, return_number, intensity)

    def add_chm(self, x, y, z, cls, dem) -> None:
        """Pass 2 (after the DEM): highest vegetation height above the DEM per cell."""
        self._stats.add_chm(x, y, z, cls, dem)

    def dem(self, require_ground: bool = True, fill_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX,
            needed=None) -> np.ndarray:
        """Mean ground height per cell; cells without ground (under buildings, sparse ground under
        canopy) from the TIN of the surrounding cells (``fill_nodata_tin``). ``needed``: (row slice,
        col slice) of the cells whose values are used (a tile's core and one cell around it, which the
        CHM's bilinear samples reach); the TIN is then made only within the distance that decides
        them, and the other cells keep the pull-push fill."""
        if require_ground and not self.ground_n.any():
            raise ValueError("the cloud has no ground points (class 2): classify it first")
        shape = self.args[3], self.args[4]
        with np.errstate(invalid="ignore"):
            return fill_nodata_tin((self.ground_sum / self.ground_n).reshape(shape), fill_radius_px, self.offset,
                                   needed=needed)

    def footprint(self, footprint_cells: int) -> np.ndarray:
        """Cells within ``footprint_cells`` cells of a point that is not noise, and the gaps they enclose."""
        occupied = (self.valid_n > 0).reshape(self.args[3], self.args[4])
        # within footprint_cells cells (a 3 x 3 dilation that many times)
        footprint = ndimage.maximum_filter(occupied, size=2 * footprint_cells + 1, mode="constant", cval=False)
        # Gaps enclosed by data (ponds without returns, shadows behind tall buildings) are
        # interpolated, as production DEMs are: only the outside of the survey stays nodata.
        return _fill_holes(footprint)

    def core_grids(self, dem: np.ndarray, footprint_cells: int, core, units: LengthUnits):
        """The rasters of a tile's core (row slice, col slice of the window), north-up float32 with
        NODATA, in the CRS's units (``RasterGrids.in_crs_units`` of ``grids_south_up``'s core, in one loop), and
        the metric DEM with NaN (the hillshade's)."""
        chm = self.chm_gaps_filled()
        dsm_filled = self.dsm_filled(dem, chm)
        out = self._stats.core_grids(self.footprint(footprint_cells), dem, dsm_filled, core, z_m=units.z_m,
                                     metric=units.is_metric, nodata=NODATA, chm=chm.ravel())
        return dict(zip(("dem_m", *RASTERS), out))

    def beneath(self) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
        """(``beneath.wall_span``, ``beneath.lifted_cells``) of the window, rows south to north, once every chunk is
        added (pass 1): the roof above and the foot below each cell's returns, and the height a cell's returns on a
        wall are lifted to (NaN where none is)."""
        if self._beneath is None:
            shape = self.args[3], self.args[4]
            top = self._stats.building_top.reshape(shape)
            span = beneath.wall_span(top, self._stats.bottom.reshape(shape), self.args[0])
            self._beneath = span, beneath.lifted_cells(top, span)
        return self._beneath

    def lifted(self, x, y, z, cls) -> np.ndarray:
        """``z`` with the building returns on a wall lifted to the roof above (``beneath.lift_points``; after pass
        1): the returns the nearest-return DSM takes."""
        res_m, x0, y0 = self.args[:3]
        return beneath.lift_points(x, y, z, cls, self.beneath()[0], x0_m=x0, y0_m=y0, res_m=res_m,
                                   row0=self.offset[0], col0=self.offset[1])

    def dsm_filled(self, dem: np.ndarray, chm_filled: np.ndarray) -> np.ndarray:
        """The DSM per cell (rows south to north; ``dem`` and ``chm_filled``, ``chm_gaps_filled``, the same): the
        highest first return, gaps filled (pull-push), raised to the highest return of any number in the cell, and a
        cell no return hit raised to the DEM plus the CHM's fill there, so that nDSM >= CHM. First returns alone: a
        tilted pulse's later return from a crown falls in a cell whose own first returns reached the ground through
        a gap, and the two fills differ (trial-gis: the demo's CHM above its nDSM by more than 0.5 m in 13,768 of
        80,159 cells, 841 with a vegetation return, by up to 19.15 m). Every return alone: a cell under a crown
        holding only a last return from the ground is a pit that the first returns' fill closes (the demo: 23,364
        cells lower, by up to 20 m). Building returns on a wall count at the height of the roof above them
        (``beneath``: a wall return, one under an eave)."""
        shape = self.args[3], self.args[4]
        lifted = self.beneath()[1]
        filled = np.fmax(fill_nodata(np.fmax(self.dsm.reshape(shape), lifted)),
                         np.fmax(self._stats.top.reshape(shape), lifted))
        empty = (self.valid_n == 0).reshape(shape)
        with np.errstate(invalid="ignore"):
            return np.fmax(filled, np.where(empty & (chm_filled > 0), dem + chm_filled, np.nan))

    def chm_gaps_filled(self) -> np.ndarray:
        """The CHM per cell (rows south to north), a cell without any return taking the mean of its observed
        neighbours (3 x 3; a cell with returns but no tree counts 0), as the DSM fills its gaps: nodata is a cell seen
        without trees, not one no pulse hit (trial-forest: 0.5 m cells at 4.6 returns per m2 left 28 % of a closed
        canopy nodata, a canopy cover of 55 % for 85 %). Wider gaps (a lake, a shadow) stay nodata."""
        nrows, ncols = self.args[3], self.args[4]
        chm = self.chm.reshape(nrows, ncols)
        seen = (self.valid_n > 0).reshape(nrows, ncols)
        height = np.where(seen, np.where(chm > 0, chm, 0.0), 0.0)
        ring = np.ones((3, 3))
        total = ndimage.convolve(height, ring, mode="constant")
        n_seen = ndimage.convolve(seen.astype(float), ring, mode="constant")
        with np.errstate(invalid="ignore", divide="ignore"):
            filled = np.where(~seen & (n_seen > 0), total / n_seen, chm)
        return filled

    def grids_south_up(self, dem: np.ndarray, footprint_cells: int) -> dict:
        """float32 grids, rows south to north (row 0 = the grid's first row)."""
        res_m, x0, y0, nrows, ncols = self.args
        footprint = self.footprint(footprint_cells)
        chm = self.chm_gaps_filled()
        dsm = np.maximum(self.dsm_filled(dem, chm), dem)
        with np.errstate(invalid="ignore"):
            inten = (self.inten_sum / self.inten_n).reshape(nrows, ncols)
        out = {
            "dem": np.where(footprint, dem, np.nan),
            "dsm": np.where(footprint, dsm, np.nan),
            "chm": np.where(chm > 0, chm, np.nan),
            "intensity": inten,
        }
        out["ndsm"] = out["dsm"] - out["dem"]
        return {k: v.astype(np.float32) for k, v in out.items()}

    def nearest_returns(self) -> nearest.NearestReturns:
        """The nearest returns (``dsm_nearest``) of the whole grid, none added yet."""
        res_m, x0, y0, nrows, ncols = self.args
        return nearest.NearestReturns(x0_m=x0, y_top_m=y0 + nrows * res_m, res_m=res_m, nrows=nrows, ncols=ncols,
                                      max_dist_m=nearest.SEARCH_RADIUS_M)

    def grids(self, dem: np.ndarray, footprint_cells: int, near: np.ndarray) -> RasterGrids:
        """The grids north-up; ``near``: the nearest-return surface of the grid (``nearest``, metres, NaN for none)."""
        res_m, x0, y0, nrows, ncols = self.args
        out = {k: v[::-1] for k, v in self.grids_south_up(dem, footprint_cells).items()}   # north-up rows
        out["dsm_nearest"] = np.where(np.isnan(out["dsm"]) | np.isnan(near), out["dsm"], near).astype(np.float32)
        return RasterGrids(**out, transform=from_origin(x0, y0 + nrows * res_m, res_m, res_m))


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """``ndimage.binary_fill_holes``: the background not 4-connected to the array's edge becomes
    foreground (one labelling, instead of a dilation repeated until nothing changes)."""
    labels, n = ndimage.label(~mask)
    if n == 0:
        return mask.copy()
    edge = np.zeros(n + 1, bool)
    for side in (labels[0], labels[-1], labels[:, 0], labels[:, -1]):
        edge[side] = True
    edge[0] = True                      # label 0: the foreground itself
    return mask | ~edge[labels]


def make_grids(cloud: PointCloud, res_m: float, footprint_cells: int = 3,
               dem_fill_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX) -> RasterGrids:
    """All rasters of the cloud in metres (``RasterGrids.in_crs_units`` converts them to the cloud's units).
    ``dem_fill_radius_px``: see ``_CellSums.dem``."""
    check_res(res_m)
    x, y, z, cls = cloud.x, cloud.y, cloud.z, cloud.classification
    args = grid_for_bounds(x.min(), y.min(), x.max(), y.max(), res_m)
    check_grid(args[3], args[4], res_m, RASTER_BYTES_PER_CELL, "rasters", option="--res-m", hint="use a coarser --res-m")
    sums = _CellSums(args)
    sums.add(x, y, z, cls, cloud.return_number, cloud.intensity)
    dem = sums.dem(fill_radius_px=dem_fill_radius_px)
    sums.add_chm(x, y, z, cls, dem)
    near = sums.nearest_returns()
    near.count(x, y, cls, cloud.return_number)
    near.add(x, y, sums.lifted(x, y, z, cls), cls, cloud.return_number)
    return sums.grids(dem, footprint_cells, near.surface())


def _header_bounds(path, header):
    """(mins, maxs) of a LAS header in the file's units, checked: points, finite, ordered."""
    mins, maxs = np.asarray(header.mins, float), np.asarray(header.maxs, float)
    if header.point_count == 0:
        raise InputError(f"{path}: the file holds no points")
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()) or (maxs[:2] < mins[:2]).any():
        raise InputError(f"{path}: absurd bounds in the LAS header (min {mins.tolist()}, max {maxs.tolist()})")
    return mins, maxs


def _file_points(path, units: LengthUnits, chunk_points: int, validate: bool = True):
    """Chunks of a LAS/LAZ file as (x, y, z in metres, class, return number, intensity); with
    ``validate`` every chunk is checked (``io.validate_xyz``, and points outside the header bounds,
    which the grids are made from, are an InputError naming the record)."""
    import laspy

    header = las.read_header(path)
    mins, maxs = _header_bounds(path, header)
    # road surface (11) of a LAS 1.4 file is ground: the DEM's classes (cells.GROUND) take it as class 2
    road_is_ground = io.ROAD_SURFACE in io.ground_classes(header)
    # only the fields read here (LAZ 1.4 point formats 6-10 store the others in layers left compressed)
    fields = (laspy.DecompressionSelection.XY_RETURNS_CHANNEL | laspy.DecompressionSelection.Z
              | laspy.DecompressionSelection.CLASSIFICATION | laspy.DecompressionSelection.INTENSITY)
    for first, chunk in las.iter_file_chunks(path, chunk_points, fields):
        x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
        if validate:
            io.validate_xyz(path, x, y, z, first, units)
            out = (x < mins[0]) | (x > maxs[0]) | (y < mins[1]) | (y > maxs[1])
            if out.any():
                k = int(np.flatnonzero(out)[0])
                raise InputError(f"{path}: point record {first + k} ({x[k]!r}, {y[k]!r}) lies outside the "
                                 f"header bounds {mins[:2].tolist()} .. {maxs[:2].tolist()}")
        rn, _ = io.sanitize_returns(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
        cls = np.asarray(chunk.classification)
        if road_is_ground:
            cls = np.where(cls == io.ROAD_SURFACE, io.GROUND, cls).astype(cls.dtype)
        yield (units.xy_to_m(x), units.xy_to_m(y), units.z_to_m(z), cls, rn, np.asarray(chunk.intensity))


def make_grids_streamed(path, res_m: float, footprint_cells: int = 3, chunk_points: int = io.CHUNK_POINTS,
                        units: LengthUnits = METRE):
    """``make_grids`` of a LAS/LAZ file in two streaming passes over its chunks: memory holds one
    chunk and the whole grids (the reference for the tiled rasters of ``write_rasters``). The grid
    comes from the header bounds (which the LAS specification requires to enclose the points; a
    point outside them is an InputError). ``units``: the file's linear units (the grids are in
    metres). Returns (``RasterGrids``, number of points)."""
    check_res(res_m)
    header = las.read_header(path)
    mins, maxs = _header_bounds(path, header)
    args = grid_for_bounds(units.xy_to_m(mins[0]), units.xy_to_m(mins[1]), units.xy_to_m(maxs[0]),
                           units.xy_to_m(maxs[1]), res_m)
    check_grid(args[3], args[4], res_m, RASTER_BYTES_PER_CELL, f"{path}: rasters over the header bounds",
               option="--res-m", hint="use a coarser --res-m (or check the bounds: strips far apart, a wrong CRS?)")
    sums = _CellSums(args)
    near = sums.nearest_returns()
    for x, y, z, cls, rn, inten in _file_points(path, units, chunk_points):
        sums.add(x, y, z, cls, rn, inten)
        near.count(x, y, cls, rn)
    if not sums.ground_n.any():
        raise InputError(f"{path}: no ground points (class 2); run 'lidarctl classify' first")
    dem = sums.dem()
    for x, y, z, cls, rn, _ in _file_points(path, units, chunk_points, validate=False):
        sums.add_chm(x, y, z, cls, dem)
        near.add(x, y, sums.lifted(x, y, z, cls), cls, rn)
    return sums.grids(dem, footprint_cells, near.surface()), int(header.point_count)


def _transform_in_units(t, units: LengthUnits):
    """A north-up GeoTIFF transform in metres in the CRS's horizontal units."""
    return from_origin(t.c / units.xy_m, t.f / units.xy_m, t.a / units.xy_m, -t.e / units.xy_m)


def write_cog(path, array: np.ndarray, transform, crs, *, unit: str | None = None, description: str | None = None,
              tags: dict | None = None, nodata: float = NODATA, dtype: str | None = "float32") -> None:
    """Single-band Cloud-Optimized GeoTIFF (deflate, internal overviews), float32 with nodata -9999 by
    default; NaN cells of a float array become ``nodata``.

    ``unit``: the band's unit type (e.g. 'metre', 'foot'); ``description``: the band description;
    ``tags``: dataset metadata (e.g. LINEAR_UNITS); ``dtype``: None keeps the array's (codes and counts
    as integers, a conditioned DEM in float64)."""
    array = np.asarray(array)
    is_float = array.dtype.kind == "f"
    data = (np.where(np.isfinite(array), array, nodata) if is_float else array).astype(dtype or array.dtype)
    profile = dict(driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype.name,
                   crs=crs, transform=transform, nodata=nodata)
    with MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(data, 1)
            if unit:
                ds.units = (unit,)
            if description:
                ds.set_band_description(1, description)
            if tags:
                ds.update_tags(**tags)
        with mem.open() as src, atomic_path(path) as tmp:
            rio_copy(src, tmp, driver="COG", compress="DEFLATE", predictor=3 if data.dtype.kind == "f" else 2,
                     overview_resampling="average" if data.dtype.kind == "f" else "nearest")


def hillshade(dem: np.ndarray, res_m: float, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """Hillshade 0..1 of a north-up DEM (NaN cells stay NaN). The slopes come from the valid cells alone
    (``gradient_of_valid``): a NaN neighbour is an edge, as the raster's own."""
    cos_slope, sin_slope, cos_rel, alt = _hillshade_terms(dem, res_m, azimuth_deg, altitude_deg)
    shade = np.sin(alt) * cos_slope + np.cos(alt) * sin_slope * cos_rel
    return np.where(np.isfinite(dem), np.clip(shade, 0.0, 1.0), np.nan)


def gradient_of_valid(z: np.ndarray, step: float, axis: int) -> np.ndarray:
    """dz / d(axis) of a grid with NaN holes, from valid cells only: ``np.gradient``'s central difference where
    both neighbours are valid, else the one-sided difference to the valid one, else 0; NaN on NaN cells. A
    neighbour that is nodata counts as the grid's edge: no slope against a fill value (a hillshade drew a
    bright or dark rim along every nodata edge from that)."""
    g = np.gradient(z, step, axis=axis)         # NaN wherever a neighbour is NaN
    redo = np.isfinite(z) & ~np.isfinite(g)
    if redo.any():                              # the cells along nodata edges only
        zt, gt = np.moveaxis(z, axis, 0), np.moveaxis(g, axis, 0)     # views: writing gt writes g
        at = np.nonzero(np.moveaxis(redo, axis, 0))
        i, rest, n = at[0], at[1:], zt.shape[0]
        here = zt[at]
        ahead = (np.where(i + 1 < n, zt[(np.minimum(i + 1, n - 1), *rest)], np.nan) - here) / step
        behind = (here - np.where(i > 0, zt[(np.maximum(i - 1, 0), *rest)], np.nan)) / step
        gt[at] = np.where(np.isfinite(ahead), ahead, np.where(np.isfinite(behind), behind, 0.0))
    g[~np.isfinite(z)] = np.nan               # np.gradient gives a NaN cell between two valid ones a value
    return g


def _hillshade_terms(dem, res_m, azimuth_deg, altitude_deg):
    """cos and sin of the slope (the DEM's dtype), cos(azimuth - aspect) (float64) and the altitude
    (radians): numpy's ufuncs in the dtypes ``hillshade`` always used, as its float32 results (numpy's
    own SIMD arctan, sin, cos) decide grey levels at their last bit."""
    dz_dy = -gradient_of_valid(dem, res_m, 0)   # rows run north to south
    dz_dx = gradient_of_valid(dem, res_m, 1)
    slope = np.arctan(np.hypot(dz_dx, dz_dy))
    aspect = np.arctan2(-dz_dx, dz_dy)
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    return np.cos(slope), np.sin(slope), np.cos(az - aspect), alt


def hillshade_grey_of_dem(dem: np.ndarray, res_m: float, azimuth_deg: float = 315.0,
                          altitude_deg: float = 45.0) -> np.ndarray:
    """The grey levels (uint8, ``_GREY_LUT``) of ``hillshade(dem, ...)`` as matplotlib's grey colour map gives
    them (NaN black), with the float64 sum, clip, NaN test and grey level in one numba pass instead of eight
    whole-array temporaries."""
    cos_slope, sin_slope, cos_rel, alt = _hillshade_terms(dem, res_m, azimuth_deg, altitude_deg)
    # a contiguous DEM (a window of a larger one is a strided view): numba compiles one signature per dtype
    sun = float(np.sin(alt)), float(np.cos(alt))
    return _shade_grey(np.ascontiguousarray(dem), (cos_slope, sin_slope, cos_rel), sun, _GREY_LUT)


@numba.njit(cache=True, nogil=True)
def _shade_grey(dem, slope_terms, sun, lut):
    # slope_terms: (cos slope, sin slope, cos of azimuth - aspect) per cell; sun: (sin, cos) of its altitude
    cos_slope, sin_slope, cos_rel = slope_terms
    sin_alt, cos_alt = sun
    # numpy's order of operations in float64 (products, then the sum); no fastmath, so no fused multiply-add
    out = np.empty(dem.shape, np.uint8)
    for i in range(dem.shape[0]):
        for j in range(dem.shape[1]):
            g = 0
            if np.isfinite(dem[i, j]):
                shade = sin_alt * np.float64(cos_slope[i, j]) + cos_alt * np.float64(sin_slope[i, j]) * cos_rel[i, j]
                if shade == shade:           # NaN: black, as matplotlib's grey of 0
                    shade = min(max(shade, 0.0), 1.0)
                    g = min(int(shade * 256.0), 255)
            out[i, j] = lut[g]
    return out


# matplotlib's grey colour map as bytes (its table of 256 entries, linspace(0, 1) x 255 truncated), indexed as
# matplotlib indexes a colour map: int(value x 256), 1.0 -> 255 (without importing matplotlib)
_GREY_LUT = (np.linspace(0.0, 1.0, 256) * 255).astype(np.uint8)


def _write_png_grey_as_rgba(path, read_rows, nrows: int, ncols: int, rows_per_read: int = 256) -> None:
    """An RGBA PNG (8 bit, no filter, zlib level 1) of a grey image, streamed: ``read_rows(r0, r1)``
    gives rows r0..r1 (north to south) as uint8, written as (g, g, g, 255): the pixels
    ``matplotlib.pyplot.imsave`` writes for a hillshade with the grey colour map. The hillshade of both the
    tiled and the in-memory rasters. A tenth of the CPU of GDAL's PNG copy, which tries five filters on every
    line (3.4 of 17 CPU-s of the demo's rasters), for a file 2 % larger."""
    import struct
    import zlib

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    comp = zlib.compressobj(1)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", ncols, nrows, 8, 6, 0, 0, 0)))
        for r0 in range(0, nrows, rows_per_read):
            grey = read_rows(r0, min(r0 + rows_per_read, nrows))
            lines = np.empty((grey.shape[0], 1 + 4 * ncols), np.uint8)
            lines[:, 0] = 0                                   # filter type: none
            rgba = lines[:, 1:].reshape(grey.shape[0], ncols, 4)
            rgba[..., :3] = grey[..., None]
            rgba[..., 3] = 255
            data = comp.compress(lines.tobytes())
            if data:
                f.write(chunk(b"IDAT", data))
        f.write(chunk(b"IDAT", comp.flush()))
        f.write(chunk(b"IEND", b""))


def _check_fill_radius(dem_fill_radius_px: float) -> None:
    if not dem_fill_radius_px >= 0:
        raise OptionError(f"--dem-fill-radius-px {dem_fill_radius_px:g}: must be 0 or more cells",
                          param="--dem-fill-radius-px")


def _check_tiling(tile_px: int, buffer_px: int, dem_fill_radius_px: float = 0.0) -> None:
    if tile_px < 1:
        raise OptionError(f"--tile-px {tile_px}: must be a positive number of cells", param="--tile-px")
    if not 0 <= buffer_px <= tile_px:
        # (new-user trial s51: `--tile-px 7` alone was refused as "--buffer-px 256", an option not given: both named)
        raise OptionError(f"--buffer-px {buffer_px}: must be between 0 and the tile size (--tile-px {tile_px} cells); "
                          "give a larger --tile-px or a smaller --buffer-px", param="--buffer-px")
    _check_fill_radius(dem_fill_radius_px)
    if buffer_px < 2 * dem_fill_radius_px + 2:
        log.warning("--buffer-px %d is less than 2 x --dem-fill-radius-px + 2 = %d cells: DEM cells filled "
                    "from gaps near a tile's edge may differ from those of an untiled run",
                    buffer_px, int(2 * dem_fill_radius_px + 2))


# the gap fill's pyramid blocks the default tiles (2048 + 2 x 256 cells) keep aligned with an untiled run's
PYRAMID_ALIGNMENT_PX = DEFAULT_BUFFER_PX


def pyramid_alignment_px(tile_px: int, buffer_px: int) -> int:
    """The largest power of 2 (at most ``PYRAMID_ALIGNMENT_PX``) that divides the tile size and the buffer (cells):
    the pyramid blocks of the pull-push gap fill that tiles share with the whole grid (``_tile_windows``)."""
    a = 1
    while a < PYRAMID_ALIGNMENT_PX and tile_px % (2 * a) == 0 and buffer_px % (2 * a) == 0:
        a *= 2
    return a


def _note_pyramid_alignment(tile_px: int, buffer_px: int) -> None:
    """A warning when the tiles align the gap fill's pyramid to fewer cells than the defaults do. New-user trial
    s94: AHN3 Delft with --tile-px 160 --buffer-px 130 (blocks of 2 cells) had 2,525 DSM cells more than 1 m off
    the untiled run's, by up to 14.6 m (pits under crowns beside the canal, filled from coarser blocks), no word;
    --tile-px 256 --buffer-px 256: every raster equal to the untiled run's."""
    a = pyramid_alignment_px(tile_px, buffer_px)
    if a < PYRAMID_ALIGNMENT_PX:
        log.warning("--tile-px %d and --buffer-px %d are common multiples of %s only: the gap fill's pyramid "
                    "(DSM cells under crowns and beside water, wide DEM gaps) then takes blocks a tile cuts "
                    "differently from an untiled run, and such cells may differ from its by metres; multiples of "
                    "%d cells (the defaults %d and %d) keep them equal", tile_px, buffer_px, counted(a, "cell"),
                    PYRAMID_ALIGNMENT_PX, DEFAULT_TILE_PX, DEFAULT_BUFFER_PX)


@dataclasses.dataclass(frozen=True)
class _Inputs:
    """Classified files in one CRS: paths, CRSs, units, union of their header bounds (m), points."""

    paths: tuple
    crs: object
    surface_crs: object   # the first file's compound CRS when it has one (DEM, DSM), else ``crs``
    units: LengthUnits
    bounds_m: tuple
    n_points: int

    @property
    def names(self) -> str:
        return ", ".join(str(p) for p in self.paths)


def _inputs(paths, crs_arg) -> _Inputs:
    """Headers of the files checked (points, bounds, one CRS and units) and their union bounds."""
    paths = tuple(Path(p) for p in paths)
    if not paths:
        raise InputError("no classified LAS/LAZ file given")
    lo, hi, n, first = np.full(2, np.inf), np.full(2, -np.inf), 0, None
    for p in paths:
        header = las.read_header(p)
        mins, maxs = _header_bounds(p, header)
        crs, units = io.resolve_crs_units(p, header, crs_arg)
        if first is None:
            file_crs = las.header_crs(header)
            surface = file_crs if file_crs is not None and file_crs.is_compound else crs
            if file_crs is None and crs_arg is not None and str(crs_arg).strip():
                # a file without a CRS record takes --crs whole: a compound one keeps its heights' datum on the DEM
                # and DSM (trial-gis F10: `--crs EPSG:7415` wrote RD New alone, NAP dropped without a word)
                given = parse_crs(crs_arg, "--crs")
                surface = given if given.is_compound else crs
            first = (p, crs, units, surface)
        else:
            io.require_same_crs(p, crs, units, first[:3])
        lo = np.minimum(lo, units.xy_to_m(mins[:2]))
        hi = np.maximum(hi, units.xy_to_m(maxs[:2]))
        n += int(header.point_count)
    return _Inputs(paths, first[1], first[3], first[2], (lo[0], lo[1], hi[0], hi[1]), n)


# A tile's binned points: one file per field (``tile_<id>_<field>.bin``), so that its chunks are read back as the
# contiguous arrays the cell kernels take (records cost a copy of every field of every chunk, twice: 0.15-0.3
# CPU-s of the demo's rasters).
_BIN_FIELDS = (("x", "f8"), ("y", "f8"), ("z", "f8"), ("cls", "u1"), ("rn", "u1"), ("intensity", "u2"))
_BLOCK_PX = 512


# Points a chunk of the binning pass: the strips are decompressed a chunk ahead of the binning (``_read_ahead``),
# so the first chunk's decompression and the last one's binning run alone, and the chunk's arrays are fresh
# pages each time. The pass alone on the demo (load 10-12): chunks of 2 M points (a demo strip, 1.1-1.3 M
# points, was one chunk) 1.8-2.5 CPU-s (0.3-0.7 s system), two threads runnable 29-77 % of the time; of 250 k
# 1.6-2.0 CPU-s (0.1-0.3 s system), 74-99 %. The tiles' files are the same bytes whatever the chunks (a tile's
# records in file order).
_BIN_READ_POINTS = 250_000


def _bin_points(inputs: _Inputs, args, grid, work: Path, chunk_points: int) -> np.ndarray:
    """Pass 1: stream every file once and append each tile's points (core + buffer) to its
    files ``tile_<id>_<field>.bin`` (``_BIN_FIELDS``, metres, file order). Tiles are in raster cells: the tile grid's
    coordinates are the global cell indices, so tile membership is exact integer arithmetic and
    agrees with the cell ``_CellSums`` puts a point in. Returns which tiles hold points."""
    from aerotri.core.log import progress

    res_m, x0, y0 = args[:3]
    tile_px, buffer_px = int(grid.tile_m), int(grid.buffer_m)
    lay = _TileLayout(res_m, x0, y0, tile_px, buffer_px, grid.nrows, grid.ncols)
    used = np.zeros(grid.n_tiles, bool)
    n_ground = intensity_max = 0
    per_class = np.zeros(256, np.int64)
    read_points = min(chunk_points, _BIN_READ_POINTS)
    chunks = (c for path in inputs.paths for c in _file_points(path, inputs.units, read_points))
    with progress(inputs.n_points, "rasters: bin points into tiles", "pt", unit_scale=True) as bar:
        for x, y, z, cls, rn, inten in _read_ahead(chunks):
            count = np.zeros(grid.n_tiles + 1, np.int64)
            n_members = _membership_count(x, y, lay, count)
            cols = _ChunkPoints(*(np.empty(n_members, dtype) for _, dtype in _BIN_FIELDS))   # by tile
            # classes contiguous (a strided record field of some files): numba compiles one signature
            n_ground += _gather_columns(cols, count, _ChunkPoints(x, y, z, np.ascontiguousarray(cls), rn, inten), lay)
            per_class += np.bincount(cls, minlength=256)
            intensity_max = max(intensity_max, int(inten.max(initial=0)))
            for tid in np.flatnonzero(count[1:] > count[:-1]):
                used[tid] = True
                for (name, _), col in zip(_BIN_FIELDS, cols):
                    with open(work / f"tile_{tid}_{name}.bin", "ab") as fh:
                        col[count[tid]:count[tid + 1]].tofile(fh)
            bar.update(len(x))
    if n_ground == 0:
        raise InputError(f"{inputs.names}: no ground points (class 2); run 'lidarctl classify' first")
    if intensity_max == 0:
        # trial s99 lidmut L6: a cloud written without intensities gave an intensity.tif of zeros, no word
        log.warning(f"{inputs.names}: every point's intensity is 0 (the file was written without intensities): "
                    "intensity.tif is 0 wherever there are points, not a measurement")
    if not per_class[list(VEGETATION)].any():
        # trial-lidar: AHN3 as delivered (its vegetation in class 1) gave a chm.tif of nodata alone, exit 0, without a
        # word, where `lidarctl trees` refuses the same cloud
        held = ", ".join(str(c) for c in np.flatnonzero(per_class))
        veg = ", ".join(map(str, VEGETATION))
        if per_class[LOW_VEGETATION]:
            # s27: a classified cloud with low vegetation only was told to classify the cloud
            log.warning(f"{inputs.names}: no medium or high vegetation points (classes {veg}; the cloud holds "
                        f"classes {held}): chm.tif is nodata everywhere; class {LOW_VEGETATION}, low vegetation, is "
                        "not a canopy")
        else:
            log.warning(f"{inputs.names}: no vegetation points (classes {veg}; the cloud holds classes {held}): "
                        "chm.tif is nodata everywhere; classify the cloud (lidarctl classify) for a canopy height "
                        "model")
    return used


# The tiles of a point (its own and the 0 to 3 neighbours whose buffer holds it; the tile grid's
# coordinates are global cells, the cells' indices exact floats): scalars only, so that the two loops
# below compile in a fraction of a second (an array per point costs numba reference counting).
class _TileLayout(NamedTuple):
    """The tiles of the binning pass as its kernels take them: cell size and grid origin (m), tile size and
    buffer (cells), tile rows and columns."""

    res_m: float
    x0: float
    y0: float
    tile_px: int
    buffer_px: int
    ntr: int
    ntc: int


class _ChunkPoints(NamedTuple):
    """A chunk of points as ``_gather_columns`` takes and makes it (x, y, z in metres, class, return number,
    intensity)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    cls: np.ndarray
    rn: np.ndarray
    intensity: np.ndarray


@numba.njit(cache=True, nogil=True, inline="always")
def _tile_and_near(x, y, lay):
    """(first row of tiles, last, first col, last) of the tiles of ``_TileLayout`` ``lay`` that hold the point."""
    res_m, x0, y0, tile_px, buffer_px, ntr, ntc = (lay.res_m, lay.x0, lay.y0, lay.tile_px, lay.buffer_px, lay.ntr,
                                                   lay.ntc)
    col = np.floor((x - x0) / res_m)
    row = np.floor((y - y0) / res_m)
    ci = int(min(max(np.floor(col / tile_px), 0.0), ntc - 1.0))
    ri = int(min(max(np.floor(row / tile_px), 0.0), ntr - 1.0))
    fx, fy = col - ci * tile_px, row - ri * tile_px
    c_lo = ci - 1 if (fx < buffer_px and ci > 0) else ci
    c_hi = ci + 1 if (fx >= tile_px - buffer_px and ci < ntc - 1) else ci
    r_lo = ri - 1 if (fy < buffer_px and ri > 0) else ri
    r_hi = ri + 1 if (fy >= tile_px - buffer_px and ri < ntr - 1) else ri
    return r_lo, r_hi, c_lo, c_hi


@numba.njit(cache=True, nogil=True)
def _membership_count(x, y, lay, count):
    """Points per tile (core + buffer) into ``count[1:]``, then turned into the tiles' first record
    (``count[t]`` .. ``count[t + 1]``); returns the number of memberships."""
    ntc = lay.ntc
    for k in range(len(x)):
        r_lo, r_hi, c_lo, c_hi = _tile_and_near(x[k], y[k], lay)
        for r in range(r_lo, r_hi + 1):
            for c in range(c_lo, c_hi + 1):
                count[r * ntc + c + 1] += 1
    for t in range(1, len(count)):
        count[t] += count[t - 1]
    return count[-1]


@numba.njit(cache=True, nogil=True)
def _gather_columns(cols, count, pts, lay):
    """The fields (``_ChunkPoints`` of ``_BIN_FIELDS`` arrays) of the memberships by tile of the chunk ``pts``
    (``_ChunkPoints``), points in order within a tile (the counting sort of ``TileGrid.assign``); returns the
    number of ground (2) and water (9) points."""
    x, y, z, cls, rn, inten = pts.x, pts.y, pts.z, pts.cls, pts.rn, pts.intensity
    ox, oy, oz, ocls, orn, ointen = cols.x, cols.y, cols.z, cols.cls, cols.rn, cols.intensity
    ntc = lay.ntc
    fill = count[:-1].copy()
    n = 0
    for k in range(len(x)):
        r_lo, r_hi, c_lo, c_hi = _tile_and_near(x[k], y[k], lay)
        for r in range(r_lo, r_hi + 1):
            for c in range(c_lo, c_hi + 1):
                t = r * ntc + c
                i = fill[t]
                fill[t] += 1
                ox[i], oy[i], oz[i] = x[k], y[k], z[k]
                ocls[i], orn[i], ointen[i] = cls[k], rn[k], inten[k]
        if cls[k] == 2 or cls[k] == 9:
            n += 1
    return n


def _read_ahead(chunks, depth: int = 1):
    """The items of an iterator, the next one made in a thread while the caller works on the current
    one (LAZ decompression, which releases the GIL, beside the binning); errors are raised in the
    caller, in order. Memory: ``depth`` + 2 chunks."""
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    done = object()

    def produce():
        try:
            for item in chunks:
                while not stop.is_set():
                    try:
                        q.put((item, None), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((done, None))
        except BaseException as exc:   # handed to the caller
            q.put((done, exc))

    thread = threading.Thread(target=produce, name="rasters-read", daemon=True)
    thread.start()
    try:
        while True:
            item, exc = q.get()
            if item is done:
                if exc is not None:
                    raise exc
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():     # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            thread.join(timeout=0.1)


def _bin_chunks(work: Path, tid: int, chunk_points: int):
    """The binned points of tile ``tid`` (``_bin_points``) by chunks of ``chunk_points``: ``_ChunkPoints`` of
    contiguous arrays."""
    with contextlib.ExitStack() as files:
        fhs = [files.enter_context(open(work / f"tile_{tid}_{name}.bin", "rb")) for name, _ in _BIN_FIELDS]
        while True:
            chunk = _ChunkPoints(*(np.fromfile(fh, dtype, count=chunk_points) for fh, (_, dtype) in zip(fhs, _BIN_FIELDS)))
            if not len(chunk.x):
                return
            yield chunk


def _tiled_gtiff(path, shape, transform, crs, *, count: int = 1, dtype: str = "float32", nodata=NODATA,
                 in_memory: bool = False):
    """A working GeoTIFF, uncompressed: written once by windows and read once by the COG copy, so
    compressing it cost 2.3 CPU-s of the demo's rasters and saved only temporary disk space (which
    ``check_disk`` asks for uncompressed anyway). ``in_memory``: a GDAL in-memory raster instead (``MEM``; no
    file is written at ``path``), read by ``_working_raster`` before it is closed."""
    import rasterio

    if in_memory:
        return rasterio.open(path, "w+", driver="MEM", width=shape[1], height=shape[0], count=count, dtype=dtype,
                             crs=crs, transform=transform, nodata=nodata)
    return rasterio.open(path, "w", driver="GTiff", width=shape[1], height=shape[0], count=count, dtype=dtype,
                         crs=crs, transform=transform, nodata=nodata, tiled=True, blockxsize=_BLOCK_PX,
                         blockysize=_BLOCK_PX, bigtiff="IF_SAFER",
                         # blocks never written are not filled in at close (a stopped run of 0.01 m cells on Autzen
                         # spent more than 60 s writing 17 GB of nodata into files it then removed); read as nodata
                         sparse_ok=True)


# The working rasters are held in memory (``_tiled_gtiff``'s ``in_memory``) when all of them take at most this share
# of the RAM: the demo's seven, 212 MB, are then neither written to nor read back from disk (each COG and the
# hillshade read the raster the tiles were written into; 0.04-0.08 CPU-s less a raster, the COGs the same bytes).
# Larger grids keep the files: memory stays set by the tile.
WORKING_IN_MEMORY_SHARE = 1 / 16


def _working_in_memory(total_bytes: int) -> bool:
    ram = usable_memory_bytes()     # 0: the system does not say
    return bool(ram) and total_bytes <= WORKING_IN_MEMORY_SHARE * ram


@contextlib.contextmanager
def _working_raster(ds, path: Path):
    """A working raster of ``_tiles_to_gtiffs`` to read once every tile is written, closed after: an in-memory one
    itself, a GeoTIFF closed (its blocks written out) and opened again for reading."""
    import rasterio

    if ds.driver == "MEM":
        try:
            yield ds
        finally:
            ds.close()
        return
    ds.close()
    with rasterio.open(path) as src:
        yield src


def _tile_windows(grid, nrows: int, ncols: int):
    """(tile id, (row0, col0, rows, cols) of its buffered window clipped to the raster, core slices in
    that window, north-up Window of the core in the raster) of every tile, rows of tiles south to
    north. Clipping keeps the gap filling's pyramid aligned: a window starts at a multiple of the
    tile and buffer sizes or at 0, and ends where the raster ends."""
    from rasterio.windows import Window

    t, b = int(grid.tile_m), int(grid.buffer_m)
    for tid in range(grid.n_tiles):
        r, c = divmod(tid, grid.ncols)
        r_lo, r_hi, c_lo, c_hi = r * t, min((r + 1) * t, nrows), c * t, min((c + 1) * t, ncols)
        row0, col0 = max(r_lo - b, 0), max(c_lo - b, 0)
        rows, cols = min(r_hi + b, nrows) - row0, min(c_hi + b, ncols) - col0
        core = (slice(r_lo - row0, r_hi - row0), slice(c_lo - col0, c_hi - col0))
        yield tid, (row0, col0, rows, cols), core, Window(c_lo, nrows - r_hi, c_hi - c_lo, r_hi - r_lo)


def write_rasters(cloud, outdir, res_m: float, crs=None, *, tile_px: int | None = None,
                  buffer_px: int = DEFAULT_BUFFER_PX, chunk_points: int = io.CHUNK_POINTS,
                  dem_fill_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX, resume_dir=None) -> list[Path]:
    """Write all rasters into ``outdir``; other files there (e.g. the classified cloud) stay.

    ``cloud``: a PointCloud (x, y, z in metres; its ``crs`` and ``units`` say how to write them; whole
    grids in memory), or the path or list of paths of classified LAS/LAZ files (strips in one CRS),
    processed by tiles (``write_rasters_tiled``; ``crs`` is used only for files without a CRS
    record). ``res_m``: cell size in metres. ``dem_fill_radius_px``: DEM cells without ground are
    interpolated in the TIN of the ground cells around them where its triangle's circumradius is at
    most this many cells (under buildings, sparse ground under canopy); wider gaps keep the smooth
    pyramid fill. The rasters are in the cloud's CRS and units (see the
    module docstring). ``tile_px`` None: ``DEFAULT_TILE_PX``, or smaller where the tiles would not fit in the
    memory the process may use (``write_rasters_tiled``). Everything is written into a temporary folder first and
    moved into place only when all files are complete, so an error leaves no partial set behind. ``resume_dir``:
    files only, see ``write_rasters_tiled``.
    """
    check_res(res_m)
    if not isinstance(cloud, PointCloud):
        paths = [cloud] if isinstance(cloud, (str, Path)) else list(cloud)
        from lidarctl.io import check_distinct_clouds

        check_distinct_clouds(paths)  # a strip given twice would count every point twice
        return write_rasters_tiled(paths, outdir, res_m, crs=crs, tile_px=tile_px, buffer_px=buffer_px,
                                   chunk_points=chunk_points, dem_fill_radius_px=dem_fill_radius_px,
                                   resume_dir=resume_dir)
    crs, units = cloud.crs, cloud.units
    if crs is None:
        raise ValueError("a CRS is needed for the rasters")
    res_m = cell_of_units(res_m, units)
    _check_fill_radius(dem_fill_radius_px)
    grids = make_grids(cloud, res_m, dem_fill_radius_px=dem_fill_radius_px)
    # The hillshade needs heights and cell size in one unit: from the metric grids.
    grey = hillshade_grey_of_dem(grids.dem, res_m)
    grids = grids.in_crs_units(units)
    tags = _tags(units, res_m)

    def write(tmp: Path) -> None:
        for name in RASTERS:
            write_cog(tmp / f"{name}.tif", getattr(grids, name), grids.transform, crs, unit=_unit(name, units),
                      description=_description(name, units), tags=_raster_tags(tags, name))
        _write_png_grey_as_rgba(tmp / "hillshade.png", lambda r0, r1: grey[r0:r1], *grey.shape)

    return _write_set(outdir, write)


RASTERS = ("dem", "dsm", "ndsm", "chm", "intensity", "dsm_nearest")


def _tags(units: LengthUnits, res_m: float) -> dict:
    return {"LINEAR_UNITS": length_unit_name(units.xy_m, long=True),
            "VERTICAL_UNITS": length_unit_name(units.z_m, long=True),
            "CELL_SIZE_M": f"{res_m:g}", "CELL_SIZE": f"{res_m / units.xy_m:.10g} {units.xy_name}"}


def _raster_tags(tags: dict, name: str) -> dict:
    """The stage's tags for raster ``name``: VERTICAL_UNITS only on the height grids (intensity is no length), which
    a grid of another quantity replaces by QUANTITY (its name: refused as a DEM, ``raster_warp.not_heights``)."""
    if name in HEIGHT_GRIDS:
        return tags
    return {**{k: v for k, v in tags.items() if k != "VERTICAL_UNITS"}, QUANTITY_TAG: name}


def _unit(name: str, units: LengthUnits) -> str | None:
    return length_unit_name(units.z_m, long=True) if name in HEIGHT_GRIDS else None


def _description(name: str, units: LengthUnits) -> str:
    return DESCRIPTIONS[name] + (f" ({length_unit_name(units.z_m, long=True)})" if name in HEIGHT_GRIDS else "")


def _write_set(outdir, write, files=FILES, name: str = "rasters") -> list[Path]:
    """``write(tmp)`` writes ``files`` into a temporary folder in ``outdir``; then they replace the old set."""
    import os
    import shutil

    from aerotri.core.atomic import commit_outputs, move_into

    outdir = Path(outdir)
    # folders this call creates go again if it fails (a corrupt chunk may only show in a late tile)
    created = [d for d in (outdir, *outdir.parents) if not d.exists()]
    outdir.mkdir(parents=True, exist_ok=True)
    tmp = temporary_dir(outdir, name)
    done = False
    try:
        write(tmp)
        with commit_outputs(outdir):  # all new, or (a failure, a kill) all as before
            for f in files:
                os.chmod(tmp / f, 0o644)
                move_into(tmp / f, outdir / f)
        done = True
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        for d in created if not done else ():   # deepest first; only while empty
            try:
                d.rmdir()
            except OSError:
                break
    return [outdir / f for f in files]


def write_rasters_tiled(paths, outdir, res_m: float, crs=None, *, tile_px: int | None = None,
                        buffer_px: int = DEFAULT_BUFFER_PX, chunk_points: int = io.CHUNK_POINTS,
                        footprint_cells: int = 3, dem_fill_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX,
                        resume_dir=None) -> list[Path]:
    """The rasters of classified LAS/LAZ files (strips in one CRS) by tiles: memory is set by the tile
    size, not by the size of the block.

    The raster grid covers the union of the files' header bounds. It is cut into square tiles of
    ``tile_px`` cells; each tile is computed over its window grown by ``buffer_px`` cells on every
    side (the points there are binned into a temporary file per tile in one pass over the files) and
    only its core is written, by windows, into tiled GeoTIFFs, which are copied block by block into
    COGs (ZSTD level 1, predictor 3); the hillshade is computed by strips of rows of the written DEM as the
    PNG is written.

    Equal to the whole grids (``make_grids``) except where a cell's value comes from further away
    than the buffer: the pull-push gap filling at pyramid levels coarser than the tiles' alignment
    (the tile size and buffer are multiples of 2^k cells: 256 for the defaults), i.e. extrapolated
    cells near the edge of the survey and gaps wider than the buffer, and enclosed gaps wider than
    the buffer (which the whole grid fills and a tile leaves nodata). The DEM's TIN gap fill is
    equal wherever ``buffer_px >= 2 * dem_fill_radius_px + 2``. ``bench/lidar_rasters.py``
    measures the difference and the memory.

    Temporary disk space: 28 bytes per point and buffer copy, plus the uncompressed-size GeoTIFFs
    at worst, in a hidden folder in ``outdir``, removed at the end, also on errors.

    Resume (``resume_dir``: ``lidarctl rasters``' ``OUTDIR.resume`` beside the output folder, the chain's
    ``work/rasters_resume``): each finished tile's grids (its core, the six rasters and the metric DEM, 28 bytes a
    cell, uncompressed) are kept there under a key of everything they depend on (``_tiles_key_doc``) until the set
    is written; a run after a kill or an interrupt writes them into the working rasters instead of computing the
    tile again (the binning pass, the COGs and the hillshade run again). The folder goes when the set is written or
    by an error (``aerotri.core.resume``).
    """
    import rasterio
    from rasterio.transform import from_origin as _from_origin

    from lidarctl.tiles import TileGrid

    check_res(res_m)
    given_tile_px = tile_px
    tile_px = DEFAULT_TILE_PX if tile_px is None else tile_px
    _check_tiling(tile_px, buffer_px, dem_fill_radius_px)
    _note_pyramid_alignment(tile_px, buffer_px)
    if buffer_px < nearest.reach_px(res_m):
        log.warning("--buffer-px %d is less than the %d cells of dsm_nearest's search radius (%g m): its cells near "
                    "a tile's edge may differ from those of an untiled run", buffer_px, nearest.reach_px(res_m),
                    nearest.SEARCH_RADIUS_M)
    outdir = Path(outdir)
    inputs = _inputs(paths, crs)
    for f in FILES:
        refuse_input_as_output(outdir / f, list(inputs.paths), "OUTDIR")
    refuse_the_other_chm(outdir, "rasters")
    units = inputs.units
    res_m = cell_of_units(res_m, units)
    args = grid_for_bounds(*inputs.bounds_m, res_m)
    _, x0, y0, nrows, ncols = args
    if nrows < 2 or ncols < 2:  # a DEM, its slopes and the hillshade need neighbouring cells
        raise InputError(f"{inputs.names}: the points span {nrows} x {ncols} cells (rows x columns) of {res_m:g} m "
                         "(header bounds); expected at least 2 x 2: a cloud of one point or one spot, or a --res-m "
                         "coarser than the cloud", param="--res-m")
    if given_tile_px is None:
        tile_px = _tile_px_in_memory(nrows, ncols, buffer_px)
        if tile_px < DEFAULT_TILE_PX:
            log.info("rasters: tiles of %d cells (default %d) to fit in the %s this process may use", tile_px,
                     DEFAULT_TILE_PX, format_bytes(usable_memory_bytes()))
    need, in_flight, win = _rasters_need(nrows, ncols, tile_px, buffer_px)
    threads = _tile_threads(win[0] * win[1])
    tile_rows, tile_cols = -(-nrows // tile_px), -(-ncols // tile_px)
    cache = cache_bytes(RASTERS_CACHE_BYTES)
    check_allocation(need, f"rasters: {in_flight} tile{'s' if in_flight > 1 else ''} of {win[0]:,} x {win[1]:,} "
                     f"cells of {res_m:g} m (with the buffer), GDAL's block cache of {format_bytes(cache)} and the "
                     f"stage's {format_bytes(RASTERS_FIXED_BYTES)}", "--tile-px",
                     hint="use a smaller --tile-px or --buffer-px")
    ram = usable_memory_bytes()     # 0: the system does not say
    memory_ample = not ram or need + resident_bytes() <= ram / 4
    in_memory = _working_in_memory((len(RASTERS) + 1) * nrows * ncols * 4)
    # the working GeoTIFFs and the COGs, uncompressed float32 at worst (a grid over strips far apart
    # is mostly nodata, but the tiles are still visited and written)
    # (the tiles kept for a resumed run: the grids once more)
    check_disk((2.0 if resume_dir is None else 3.0) * 4 * (len(RASTERS) + 1) * nrows * ncols, outdir,
               f"{inputs.names}: rasters over the header bounds, a grid of {nrows:,} x {ncols:,} cells of {res_m:g} m",
               "--res-m", hint="use a coarser --res-m (or are strips far apart?)")
    check_task_count(tile_rows * tile_cols,
                     f"{inputs.names}: a grid of {nrows:,} x {ncols:,} cells in tiles of {tile_px} cells", "--tile-px",
                     "use a larger --tile-px")
    # (after the refusals: strips far apart are said as such, not as cells finer than their points)
    warn_cells_finer_than_points(inputs.n_points, nrows * ncols, res_m, inputs.names)
    grid = TileGrid(0.0, 0.0, float(tile_px), float(buffer_px), tile_rows, tile_cols)
    transform_m = _from_origin(x0, y0 + nrows * res_m, res_m, res_m)
    transform = transform_m if units.is_metric else _transform_in_units(transform_m, units)
    tags = _tags(units, res_m)
    key_doc = _tiles_key_doc(inputs, args, grid, chunk_points=chunk_points, footprint_cells=footprint_cells,
                             dem_fill_radius_px=dem_fill_radius_px)

    def write(tmp: Path, keep: ResumeFolder | None) -> None:
        work = tmp / "work"
        work.mkdir()
        used = _bin_points(inputs, args, grid, work, chunk_points)
        with contextlib.ExitStack() as working:     # the working GeoTIFFs, closed on errors too
            with rasterio.Env(**_GDAL_THREAD_ENV):
                voids = []
                gtiffs = _tiles_to_gtiffs(inputs, args, grid, used, work, working, transform=transform, tags=tags,
                                          chunk_points=chunk_points, footprint_cells=footprint_cells,
                                          dem_fill_radius_px=dem_fill_radius_px, threads=threads,
                                          in_memory=in_memory, resume=None if keep is None else (keep, key_doc),
                                          voids=voids)
                _say_voids(voids, res_m)

            # Each task closes its working GeoTIFF first: the windows sit in GDAL's block cache (the demo's six
            # working rasters, 181 MB, fit in it) and are written out at the close, so the six closes run two
            # at a time beside the hillshade and the COGs instead of one after the other before them.
            def hillshade_png() -> None:
                with _working_raster(gtiffs["dem_m"], work / "dem_m.tif") as src:
                    _hillshade_png(src, tmp / "hillshade.png", res_m)

            def cog(name: str) -> None:
                with _working_raster(gtiffs[name], work / f"{name}.tif") as src, \
                        atomic_path(tmp / f"{name}.tif") as dst:
                    # ZSTD level 1 (as the ortho mosaic's COGs): the same values as DEFLATE level 1 with 40 %
                    # less CPU (the demo's five COGs 1.95-2.02 -> 1.17-1.26 CPU-s) and files 0.9 % smaller
                    rio_copy(src, dst, driver="COG", compress="ZSTD", predictor=3, level=1,
                             overview_resampling="average", num_threads="ALL_CPUS")

            _run_threads([hillshade_png] + [functools.partial(cog, name) for name in RASTERS])

    # an error leaves no output of any kind, the kept tiles included; an interrupt or a kill keeps them; the folder
    # that holds OUTDIR and its OUTDIR.resume is the user's, the chain's work/ goes when an error leaves it empty
    with resumable(resume_dir, remove_empty_parent=not is_beside(resume_dir, outdir)) \
            if resume_dir is not None else contextlib.nullcontext() as keep, \
            stage_block_cache(RASTERS_CACHE_BYTES), _no_hugepage_advice(), _freed_memory_kept(memory_ample), \
            _older_objects_frozen():
        return _write_set(outdir, lambda tmp: write(tmp, keep))


# The version of the tile grids' algorithm (``_tile_grids``: DEM, DSM, nDSM, CHM, intensity, nearest DSM of a tile):
# the tile resume key and the chain's rasters stamp hold it, so tiles kept (and stages stamped) before a change of
# what a cell gets at the same settings are computed again (the toolkit's version, 0.1.0, never changes with them).
# Bump it when the grids' values change. 1: resume-keys (the algorithm as of main 195def90); 2: CHM cells no return
# hit filled from their neighbours, road surface (11) of LAS 1.4 in the DEM; 3: the DSM raised to a cell's later
# returns and, where no return hit, to the DEM plus the CHM's fill (``dsm_filled``); 4: building returns on a wall
# lifted to the roof above them in the DSM and the nearest-return DSM (``beneath``).
RASTERS_VERSION = 4


def _tiles_key_doc(inputs: _Inputs, args, grid, **settings) -> dict:
    """What every tile's grids depend on but its place in the grid: the files in order (name, size, modification
    time), the raster grid and the tiles, the CRS and units, the settings, the grids' algorithm version
    (``RASTERS_VERSION``) and the toolkit's version (not the threads: the grids do not depend on them)."""
    import aerotri

    return {"files": [[p.name, file_stamp(p)] for p in inputs.paths], "raster": [float(a) for a in args],
            "tiles": dataclasses.asdict(grid), "crs": str(inputs.crs), "surface_crs": str(inputs.surface_crs),
            "units": repr(inputs.units), "settings": settings, "rasters_version": RASTERS_VERSION,
            "version": aerotri.__version__}


# What a kept tile holds (``_keep_tile``): its core's grids of ``_tile_grids`` in this order, one float32 array.
_KEPT_GRIDS = (*RASTERS, "dem_m")


def _keep_tile(keep: ResumeFolder, key: str, grids: dict, work: Path, tid: int) -> None:
    """Keep a finished tile's grids (``_KEPT_GRIDS``, shape (7, rows, cols)) under ``key``: written into the work
    folder one grid after the other (no stacked copy), then linked into the resume folder whole."""
    first = grids[_KEPT_GRIDS[0]]
    part = work / f"tile_{tid}.kept.npy"
    with open(part, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": np.dtype(np.float32).str, "fortran_order": False,
                                                  "shape": (len(_KEPT_GRIDS), *first.shape)})
        for name in _KEPT_GRIDS:
            np.asarray(grids[name], np.float32).tofile(fh)
    keep.keep(part, key, ".npy")
    part.unlink()


def _kept_tile(keep: ResumeFolder, key: str, shape) -> Path | None:
    """The file of a tile kept whole by an interrupted run (``_keep_tile``) for a core of ``shape``, or None."""
    f = keep.kept(key, ".npy")
    if f is None:
        return None
    try:
        a = np.load(f, mmap_mode="r")
    except (ValueError, OSError):
        return None
    return f if a.shape == (len(_KEPT_GRIDS), *shape) and a.dtype == np.float32 else None


def _kept_grids(path: Path) -> dict:
    a = np.load(path)
    return dict(zip(_KEPT_GRIDS, a))


@contextlib.contextmanager
def _older_objects_frozen():
    """Python's cyclic garbage collector leaves the objects made before the tiled rasters alone while they are
    made (``gc.freeze``; ``gc.unfreeze`` after, so they are collected as before). Why: the stage allocates enough
    Python objects (numba's dispatch, rasterio's windows, the threads' futures) for one full collection a run,
    which walked every object of the process (the imports': numba, GDAL, scipy) for 0.12-0.19 s of the demo's
    rasters, to free none of the stage's arrays (they hold no cycles). Left as it is when the caller froze
    objects itself."""
    import gc

    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def _rasters_need(nrows: int, ncols: int, tile_px: int, buffer_px: int) -> tuple[float, int, tuple[int, int]]:
    """Memory of the rasters' tiles (bytes): the tiles in flight (their windows with the buffer; never more than
    the tiles), GDAL's block cache (``stage_block_cache``) and the stage's own part, besides what the process holds;
    with the tiles in flight and a window's rows x columns."""
    win = min(tile_px + 2 * buffer_px, nrows), min(tile_px + 2 * buffer_px, ncols)
    in_flight = min(_tile_threads(win[0] * win[1]), -(-nrows // tile_px) * -(-ncols // tile_px))
    need = (in_flight * float(win[0]) * float(win[1]) * RASTER_BYTES_PER_CELL + cache_bytes(RASTERS_CACHE_BYTES)
            + RASTERS_FIXED_BYTES)
    return need, in_flight, win


def _tile_px_in_memory(nrows: int, ncols: int, buffer_px: int) -> int:
    """The default tile (``DEFAULT_TILE_PX``), halved while its tiles would not fit in 90 % of the memory the
    process may use beside what it holds (as ``check_allocation`` judges), down to ``MIN_AUTO_TILE_PX`` and never
    below the buffer: a batch job's or container's limit sets the tiles. The rasters are those of ``--tile-px`` at the
    size chosen (an untiled run's where the gaps are narrower than the buffer)."""
    tile_px = DEFAULT_TILE_PX
    room = memory_room_bytes()
    while tile_px > max(MIN_AUTO_TILE_PX, buffer_px) and _rasters_need(nrows, ncols, tile_px, buffer_px)[0] > room:
        tile_px //= 2
    return max(tile_px, buffer_px, 1)


@contextlib.contextmanager
def _freed_memory_kept(keep: bool = True):
    """With ``keep``, glibc's allocator keeps freed memory while the tiled rasters are made: arrays up to 1 GiB come
    from the heap instead of fresh ``mmap`` pages, and freed ones stay there for the next tile's arrays. Why: every tile
    allocates window-sized arrays (per-cell records, pull-push pyramid, TIN) that the kernel otherwise zeroes page
    by page at first touch; on the demo's strips 33 % fewer minor page faults, 0.4-0.6 s less system time, 0.2-0.5
    CPU-s less in all (``bench/results/rasters_speed.json`` keys ``i41_rasters6_malloc_env*``), peak RSS +30-60 MB.
    Process-wide: set around the stage, then glibc's own limits once its sliding threshold has grown (32 MiB
    for mmap, 64 MiB for trimming) and the free memory returned (``malloc_trim``). Other C libraries: nothing.
    The C library is the one the process runs on (``CDLL(None)``), not looked up with ``ctypes.util.find_library``:
    that runs ``ldconfig -p`` in a child process, and a child started by vfork then exec reports the parent's peak
    RSS as its own, which the chain's stage record added as a worker's (the 2 x 2 DMC block's rasters: 4.50 GB
    recorded as 7.09). Linux only: glibc's tunables; ``CDLL(None)`` raises TypeError on Windows (Python 3.11).

    Without ``keep`` (memory is short: ``write_rasters_tiled``), the other way: blocks of 1 MiB or more are mapped and
    unmapped, free memory above 1 MiB returned at once. glibc's own sliding thresholds kept about 100 MB of freed chunk
    arrays on the demo's four strips (anonymous memory after binning 291 MB, 197 MB with a 1 MiB trim threshold), which
    a 400 MiB batch job cannot spare."""
    import ctypes

    if not sys.platform.startswith("linux"):
        yield
        return
    try:
        libc = ctypes.CDLL(None)
        mallopt, malloc_trim = libc.mallopt, libc.malloc_trim
    except (OSError, AttributeError, TypeError):  # TypeError: a ctypes that takes no None (Windows) all the same
        yield
        return
    # both set, not short-circuited: a threshold set alone (the other refused) is still put back afterwards
    mmap_bytes, trim_bytes = (1 << 30, 2**31 - 1) if keep else (1 << 20, 1 << 20)
    changed = bool(mallopt(_M_MMAP_THRESHOLD, mmap_bytes)) | bool(mallopt(_M_TRIM_THRESHOLD, trim_bytes))
    try:
        yield
    finally:
        if changed:
            mallopt(_M_MMAP_THRESHOLD, 32 << 20)
            mallopt(_M_TRIM_THRESHOLD, 64 << 20)
            malloc_trim(0)


@contextlib.contextmanager
def _no_hugepage_advice():
    """numpy's transparent-huge-page advice (``madvise(MADV_HUGEPAGE)`` on every array of 4 MiB or more) off
    while the tiled rasters are made. Why: with the kernel's THP mode ``madvise`` (this machine's
    ``/sys/kernel/mm/transparent_hugepage/enabled``) each first touch of such an array zeroes a whole 2 MiB
    page, and the stage allocates and frees window-sized arrays tile after tile; on the demo's strips the
    advice cost 0.7-0.9 s of system time and saved 0.1-0.4 s of user time (``NUMPY_MADVISE_HUGEPAGE=0`` on
    main's code: system 3.0-3.2 -> 2.3 s, 10.1-10.5 -> 9.5-9.9 CPU-s; docs/performance.md). The setting is
    numpy's, process-wide: set from the calling thread around the stage (the tile threads run inside it) and
    restored after."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:       # another numpy: its default
        yield
        return
    before = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(before)


# Threads of the tiled rasters: tiles are computed two at a time (numba and numpy release the GIL;
# memory: two tiles, when they take at most half of the RAM), the COGs and the hillshade written two
# at a time (GDAL releases it).
_THREADS = 2


def _tile_threads(window_cells: int) -> int:
    """``_THREADS`` when that many tiles, GDAL's block cache and what the process holds already take at most half
    the memory it may use, else 1."""
    ram = usable_memory_bytes() or float("inf")  # 0: the system does not say
    need = _THREADS * window_cells * RASTER_BYTES_PER_CELL + cache_bytes(RASTERS_CACHE_BYTES) + resident_bytes()
    return _THREADS if need <= 0.5 * ram else 1


# GDAL's block cache while the tiled rasters are written (windows written, COGs copied): bounded, not 5 % of
# the RAM; one size for the process, set once around the stage from its calling thread
# (``aerotri.core.gdal_cache``), never per thread.
RASTERS_CACHE_BYTES = 256 * MiB
# The stage's memory besides its tiles, GDAL's cache and what the process holds before it starts: numba's kernels
# loaded, 67 -> 136 MB of anonymous memory (``/proc/self/status`` RssAnon) on the demo's four strips. Not counted: the
# COGs written two at a time at the end (+80 MB there over the tiles' peak; how it grows with the raster is not
# measured): a first version counted 192 MiB for both and refused AHN3 Delft's rasters at 400 MiB, which run there.
RASTERS_FIXED_BYTES = 64 * MiB
# GDAL's configuration in every thread (these options are per thread in rasterio): no .aux.xml files; ZSTD
# level 1 for the temporary file in which the COG driver computes the overviews (default 9; the COGs are the
# same bytes, and 1 of 4 CPU-s of the demo's five COGs less).
_GDAL_THREAD_ENV = dict(GDAL_PAM_ENABLED="NO", ZSTD_LEVEL_OVERVIEW="1")


def _run_threads(tasks) -> None:
    """Call every task, ``_THREADS`` at a time, each in its own rasterio Env; the first error is raised
    after the others have stopped."""
    import rasterio
    from concurrent.futures import ThreadPoolExecutor

    def run(task):
        with rasterio.Env(**_GDAL_THREAD_ENV):
            task()

    with ThreadPoolExecutor(_THREADS) as pool:
        futures = [pool.submit(run, t) for t in tasks]
        try:
            for f in futures:
                f.result()
        except BaseException:
            for f in futures:
                f.cancel()
            raise


class _Stopped(Exception):
    """A tile's work given up because the run stops (``_tile_grids``' ``stop``): nothing of it is kept."""


def _tile_grids(inputs: _Inputs, args, tile, work: Path, *, chunk_points: int, footprint_cells: int,
                dem_fill_radius_px: float, keep: tuple[ResumeFolder, str] | None = None, stop: np.ndarray | None = None):
    """The grids of one tile's core from its binned points (``_bin_points``): float32 arrays north-up,
    NODATA for no value, in the CRS's units, the DEM also in metres (``dem_m``). Runs in a worker thread.
    ``keep``: (resume folder, key): the grids are kept there for a resumed run (``_keep_tile``). ``stop``: a
    one-element bool array the calling thread sets when the run stops: the tile is given up (``_Stopped``) at its
    next step, and within the nearest-return search."""
    import os

    stop = np.zeros(1, np.bool_) if stop is None else stop

    def check() -> None:
        if stop[0]:
            raise _Stopped

    res_m, x0, y0 = args[:3]
    tid, (row0, col0, rows, cols), core, _ = tile
    sums = _CellSums((res_m, x0, y0, rows, cols), (row0, col0))
    near, near_core = _tile_nearest_returns(args, tile)    # the returns of dsm_nearest: counted, then sorted
    for ch in _bin_chunks(work, tid, chunk_points):
        sums.add(ch.x, ch.y, ch.z, ch.cls, ch.rn, ch.intensity)
        near.count(ch.x, ch.y, ch.cls, ch.rn)
    grown = tuple(slice(max(c.start - 1, 0), c.stop + 1) for c in core)   # the CHM's bilinear samples
    check()
    dem = sums.dem(require_ground=False, fill_radius_px=dem_fill_radius_px, needed=grown)
    check()
    for ch in _bin_chunks(work, tid, chunk_points):
        sums.add_chm(ch.x, ch.y, ch.z, ch.cls, dem)
        near.add(ch.x, ch.y, sums.lifted(ch.x, ch.y, ch.z, ch.cls), ch.cls, ch.rn)
    check()
    for name, _ in _BIN_FIELDS:
        os.remove(work / f"tile_{tid}_{name}.bin")
    out = sums.core_grids(dem, footprint_cells, core, inputs.units)
    far = _far_from_ground(sums.ground_n.reshape(rows, cols) > 0, core, res_m)
    del sums, dem
    out["dem_m"][~np.isfinite(out["dem_m"])] = NODATA
    valid = out["dem_m"] != NODATA
    # (counts, not grids: ``write`` takes the rasters by name and these are added up there)
    out["void_counts"] = (int(np.count_nonzero(far & valid)), int(np.count_nonzero(valid)))
    out["dsm_nearest"] = _tile_nearest(near, near_core, out["dsm"], inputs.units, stop)
    check()   # (an unfinished surface is not kept)
    if keep is not None:
        _keep_tile(*keep, out, work, tid)
    return out


# a DEM cell farther than this from every cell holding a ground return is interpolated across a void, not measured
# near one: voids at least twice as wide (water, dense canopy, large halls, or ground the vendor left unclassified:
# trial s99 lidmut M1, a 200 x 200 m area TIN-filled, RMS 0.26 m / max 0.72 m off the truth there, no word). Under a
# house or a tree the nearest ground is a few metres away.
VOID_REACH_M = 25.0
VOID_WARN_M2 = 1000.0  # DEM area farther than that (m2) said as a warning, below it as information


def _far_from_ground(ground: np.ndarray, core, res_m: float) -> np.ndarray:
    """Cells of a tile's core (``core``: row, column slices of the window, rows south to north as ``ground``) farther
    than ``VOID_REACH_M`` from every cell of the window holding a ground return; north-up as the core's grids. The
    window's buffer (256 cells by default) holds the ground within reach of every core cell."""
    import cv2

    if not ground.any():
        return np.ones((core[0].stop - core[0].start, core[1].stop - core[1].start), bool)
    dist_px = cv2.distanceTransform((~ground).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    return (dist_px[core] * res_m > VOID_REACH_M)[::-1]


def _tile_nearest_returns(args, tile) -> tuple[nearest.NearestReturns, tuple[slice, slice]]:
    """The nearest returns of a tile: its core grown by ``nearest.reach_px`` cells, clipped to its window (a
    buffer at least that wide holds every return that can be the nearest to a core centre: the whole grid's
    values); and the core's rows and columns in their north-up surface."""
    res_m, x0, y0 = args[:3]
    _, (row0, col0, rows, cols), core, _ = tile
    reach = nearest.reach_px(res_m)
    # the window's rows run south to north from row0 (``_CellSums``)
    r_lo, r_hi = max(core[0].start - reach, 0), min(core[0].stop + reach, rows)
    c_lo, c_hi = max(core[1].start - reach, 0), min(core[1].stop + reach, cols)
    near = nearest.NearestReturns(x0_m=x0 + (col0 + c_lo) * res_m, y_top_m=y0 + (row0 + r_hi) * res_m, res_m=res_m,
                                  nrows=r_hi - r_lo, ncols=c_hi - c_lo, max_dist_m=nearest.SEARCH_RADIUS_M)
    return near, (slice(r_hi - core[0].stop, r_hi - core[0].start), slice(core[1].start - c_lo, core[1].stop - c_lo))


def _tile_nearest(near: nearest.NearestReturns, core: tuple[slice, slice], dsm: np.ndarray,
                  units: LengthUnits, stop: np.ndarray | None = None) -> np.ndarray:
    """dsm_nearest of a tile's core (north-up float32, CRS units, NODATA) from the nearest returns of its grown core
    and the core's place in them (``_tile_nearest_returns``, every chunk added) and its ``dsm`` (the core's, as
    written): the nearest return, else the DSM's value."""
    surface = near.surface(stop)[core]
    if not units.is_metric:   # the arithmetic of ``RasterGrids.in_crs_units``
        surface = (surface.astype(float) / units.z_m).astype(np.float32)
    surface = np.ascontiguousarray(surface)
    fallback = np.isnan(surface)
    fallback |= dsm == NODATA
    surface[fallback] = dsm[fallback]
    return surface


def _tiles_to_gtiffs(inputs: _Inputs, args, grid, used, work: Path, working: contextlib.ExitStack, *, transform,
                     tags, chunk_points: int, footprint_cells: int, dem_fill_radius_px: float, threads: int = 1,
                     in_memory: bool = False, resume: tuple[ResumeFolder, dict] | None = None,
                     voids: list | None = None):
    """Pass 2: each tile's grids from its binned points (``_tile_grids``, ``threads`` tiles at a time,
    at most one more waiting, largest first), the core written by window into tiled GeoTIFFs
    (``work/<name>.tif`` in the CRS's units, ``work/dem_m.tif`` the DEM in metres for the hillshade) as each
    tile is done. ``resume``: (the resume folder, ``_tiles_key_doc``): the tiles kept there are written from it,
    the others kept there as they finish. Returns the working GeoTIFFs, open (``working`` closes them: the caller
    closes each when it copies it). ``voids``: a list each computed tile's (cells far from ground, valid DEM cells)
    is appended to (``_far_from_ground``)."""
    import collections
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    from aerotri.core.log import progress

    res_m, x0, y0, nrows, ncols = args
    units = inputs.units
    tiles = list(_tile_windows(grid, nrows, ncols))
    out = {}
    for name in RASTERS:
        ds = working.enter_context(_tiled_gtiff(work / f"{name}.tif", (nrows, ncols), transform,
                                                 inputs.surface_crs if name in ("dem", "dsm", "dsm_nearest") else inputs.crs,
                                                 in_memory=in_memory))
        if _unit(name, units):
            ds.units = (_unit(name, units),)
        ds.set_band_description(1, _description(name, units))
        ds.update_tags(**_raster_tags(tags, name))
        out[name] = ds
    out["dem_m"] = working.enter_context(_tiled_gtiff(work / "dem_m.tif", (nrows, ncols), transform, inputs.crs,
                                                       in_memory=in_memory))
    with ThreadPoolExecutor(threads) as pool:

        def write(window, grids) -> None:
            for name, ds in out.items():
                ds.write(grids[name], 1, window=window)
            if voids is not None and "void_counts" in grids:  # (a kept tile's are not kept: not counted)
                voids.append(grids["void_counts"])
            bar.update(1)

        # Largest windows first, each tile written as soon as it is done (the working files take windows in
        # any order): no thread waits for an earlier tile while another computes, and the last tiles are the
        # small ones. ``threads`` tiles computing and one queued, so that a thread goes on while the calling
        # thread writes a finished tile.
        todo = collections.deque(sorted((t for t in tiles if used[t[0]]), key=lambda t: -t[1][2] * t[1][3]))
        empty = [t[3] for t in tiles if not used[t[0]]]
        keys, kept = {}, []
        if resume is not None:
            keep, doc = resume
            keys = {t[0]: resume_key({**doc, "tile": t[0]}) for t in todo}
            kept = [(t, f) for t in todo if (f := _kept_tile(keep, keys[t[0]], (t[3].height, t[3].width)))]
            if kept:
                log.info(f"tiles: resumed {len(kept)} of {len(todo)} tiles an interrupted run finished ({keep.path})")
                done_ids = {t[0] for t, _ in kept}
                todo = collections.deque(t for t in todo if t[0] not in done_ids)
                for t, _ in kept:   # their points are not needed
                    for name, _ in _BIN_FIELDS:
                        (work / f"tile_{t[0]}_{name}.bin").unlink(missing_ok=True)
        running = {}
        stop = np.zeros(1, np.bool_)   # set when the run stops: the tiles computing give up (``_tile_grids``)
        with progress(grid.n_tiles, "rasters: tiles", "tile") as bar:
            try:
                while todo or running or empty or kept:
                    while todo and len(running) < threads + 1:
                        tile = todo.popleft()
                        running[pool.submit(_tile_grids, inputs, args, tile, work, chunk_points=chunk_points,
                                            footprint_cells=footprint_cells, dem_fill_radius_px=dem_fill_radius_px,
                                            keep=None if resume is None else (resume[0], keys[tile[0]]),
                                            stop=stop)] = tile
                    if empty:     # tiles without points: nodata, written while the first tiles are computed
                        for window in empty:
                            write(window, {name: np.full((window.height, window.width), NODATA, np.float32)
                                           for name in out})
                        empty = []
                        continue
                    if kept:      # kept by an interrupted run: one at a time, between the computed ones
                        tile, path = kept.pop()
                        write(tile[3], _kept_grids(path))
                        continue
                    done, _ = wait(running, return_when=FIRST_COMPLETED)
                    for future in done:
                        write(running.pop(future)[3], future.result())
            except BaseException:
                stop[0] = True   # (the pool's exit waits for the tiles computing: minutes each at very fine cells)
                for f in running:
                    f.cancel()
                raise
    return out


def _say_voids(voids: list, res_m: float) -> None:
    """A warning when DEM cells lie farther than ``VOID_REACH_M`` from any ground return (``voids``: per computed tile
    its far and valid cells; ``res_m``: the cell in metres, as the grids are computed): their heights are the TIN's
    or the pull-push fill's across a void."""
    far, valid = (sum(v[k] for v in voids) for k in (0, 1))
    if not far or not valid:
        return
    # a few cells (lidR Topography at 1 m: 4) are said as information; a void of 0.1 ha beyond the reach (one about
    # 85 m across) as a warning
    say = log.warning if far * res_m * res_m >= VOID_WARN_M2 else log.info
    say("%s DEM cells (%.2f %% of its valid cells, %.2f ha) lie more than %g m from any ground return: interpolated "
        "across voids (water, dense canopy, large buildings, or ground left unclassified); the DEM there is a guess "
        "from the ground around it, not a measurement", f"{far:,}", 100.0 * far / valid, far * res_m * res_m / 1e4,
        VOID_REACH_M)


def _hillshade_png(src, png_path: Path, res_m: float) -> None:
    """Pass 3: the hillshade PNG of the metric DEM (``src``: an open raster, north-up, NODATA for none), computed
    by strips of rows as the PNG is written, each strip read with a one-row border (clipped to the raster, as
    ``np.gradient`` treats the raster's edges): no working hillshade file."""
    from rasterio.windows import Window

    nrows, ncols = src.height, src.width

    def read_rows(r0: int, r1: int) -> np.ndarray:
        b0, b1 = max(r0 - 1, 0), min(r1 + 1, nrows)
        dem = src.read(1, window=Window(0, b0, ncols, b1 - b0), masked=True).filled(np.nan)
        return hillshade_grey_of_dem(dem, res_m)[r0 - b0: r1 - b0]

    _write_png_grey_as_rgba(png_path, read_rows, nrows, ncols)


def refuse_the_other_chm(outdir: Path, writer: str) -> None:
    """``OptionError`` when ``outdir`` holds the chm.tif of the other command (``writer``: "trees" or "rasters"):
    both write chm.tif, of different models (trees: a pit-free TIN at 0.5 m; rasters: the highest vegetation per
    cell at its --res-m), and one replaced the other without a word, leaving grids that do not line up (trial s96
    F2)."""
    chm = Path(outdir) / "chm.tif"
    if not chm.is_file():
        return
    theirs = [f for f in (("dem.tif", "dsm.tif", "ndsm.tif") if writer == "trees" else ("trees.json", "trees.gpkg"))
              if (Path(outdir) / f).is_file()]
    if theirs:
        other = "rasters" if writer == "trees" else "trees"
        raise OptionError(f"{outdir}: holds the chm.tif of lidarctl {other} (beside {', '.join(theirs)}); lidarctl "
                          f"{writer} writes a chm.tif of another model, which would replace it: give {writer} a "
                          "folder of its own", param="OUTDIR")
