"""Rasters from a classified cloud: DEM, DSM, nDSM, CHM, intensity (Cloud-Optimized GeoTIFF) and a
hillshade quicklook (PNG).

Grid: cells of ``res_m`` metres aligned to multiples of ``res_m`` metres in the cloud's CRS, north-up.

Units: the grids are computed in metres (clouds in feet are scaled as they are read) and written in
the cloud's CRS and units: in a foot CRS a 1 m cell is 3.2808 ft (3.2808 US survey ft) wide in the
GeoTIFF transform, and heights (dem, dsm, ndsm, chm) are in the CRS's vertical unit. Every GeoTIFF
says so: the band's unit type (``metre``, ``foot``, ``US survey foot``; none for intensity), its
description, and the tags ``LINEAR_UNITS``, ``VERTICAL_UNITS`` and ``CELL_SIZE_M``.
* dem.tif: mean height of ground (2) and water (9) points per cell; gaps inside the footprint
  filled (pull-push interpolation); nodata outside it.
* dsm.tif: highest first return (noise excluded) per cell; gaps filled as for the DEM.
* ndsm.tif: dsm - dem.
* chm.tif: highest vegetation (classes 4, 5) height above the DEM per cell; nodata where no trees.
* intensity.tif: mean intensity of first returns (nodata where none).
The footprint is the set of cells within ``footprint_cells`` cells of a point.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from rasterio.io import MemoryFile
from rasterio.shutil import copy as rio_copy
from rasterio.transform import from_origin
from scipy import ndimage

from aerotri.geom import las
from lidarctl import io
from aerotri.core.atomic import atomic_path, refuse_input_as_output, temporary_dir
from aerotri.core.errors import InputError, OptionError
from aerotri.core.settings import setting
from lidarctl.grid import check_grid
from lidarctl.io import PointCloud
from lidarctl.raster_ops import fill_nodata, reduce_grid, sample_bilinear
from lidarctl.units import METRE, LengthUnits, long_name

NODATA = -9999.0
FILES = ("dem.tif", "dsm.tif", "ndsm.tif", "chm.tif", "intensity.tif", "hillshade.png")
HEIGHT_GRIDS = ("dem", "dsm", "ndsm", "chm")
DESCRIPTIONS = {"dem": "DEM: mean height of ground and water points", "dsm": "DSM: highest first return",
                "ndsm": "nDSM: DSM - DEM", "chm": "CHM: highest vegetation above the DEM",
                "intensity": "mean intensity of first returns (sensor units)"}
# Memory of the grids per cell at the peak of ``_CellSums`` and ``grids`` (sums, counts, maxima,
# the filled DEM/DSM, the float32 outputs).
RASTER_BYTES_PER_CELL = 160


def check_res(res_m: float) -> None:
    if not (np.isfinite(res_m) and res_m > 0):
        raise OptionError(f"--res {res_m}: must be a positive cell size in metres", param="--res")


@dataclasses.dataclass(frozen=True)
class RasterSettings:
    """Options of the raster stage (``[rasters]`` in project.toml; ``lidarctl rasters --res``)."""

    res_m: float = setting(0.5, min=0.0, min_open=True, help="Cell size in metres.")


def grid_for_bounds(xmin: float, ymin: float, xmax: float, ymax: float, res_m: float):
    """(res_m, x0, y0, nrows, ncols) of the raster grid covering the bounds, aligned to multiples of res_m."""
    x0 = np.floor(xmin / res_m) * res_m
    y0 = np.floor(ymin / res_m) * res_m
    ncols = int(np.floor((xmax - x0) / res_m)) + 1
    nrows = int(np.floor((ymax - y0) / res_m)) + 1
    return res_m, x0, y0, nrows, ncols


class _CellSums:
    """Per-cell sums, counts and maxima, accumulated chunk by chunk (same result as all at once:
    maxima are exact; means are sums over counts, equal up to the summation order)."""

    def __init__(self, args):
        self.args = args
        ncells = args[3] * args[4]
        self.valid_n = np.zeros(ncells, np.int64)
        self.ground_sum = np.zeros(ncells)
        self.ground_n = np.zeros(ncells, np.int64)
        self.dsm = np.full((args[3], args[4]), np.nan)
        self.inten_sum = np.zeros(ncells)
        self.inten_n = np.zeros(ncells, np.int64)
        self.chm = np.full((args[3], args[4]), np.nan)

    def _flat(self, x, y):
        res_m, x0, y0, nrows, ncols = self.args
        j = np.floor((x - x0) / res_m).astype(np.int64)
        i = np.floor((y - y0) / res_m).astype(np.int64)
        return i * ncols + j

    def add(self, x, y, z, cls, return_number, intensity) -> None:
        """Pass 1: occupancy, ground mean, first-return DSM maximum and mean intensity."""
        ncells = len(self.valid_n)
        valid = ~np.isin(cls, (7, 18))
        flat = self._flat(x, y)
        self.valid_n += np.bincount(flat[valid], minlength=ncells)
        g = np.isin(cls, (2, 9))
        self.ground_sum += np.bincount(flat[g], z[g], minlength=ncells)
        self.ground_n += np.bincount(flat[g], minlength=ncells)
        first = valid & (return_number == 1)
        self.dsm = np.fmax(self.dsm, reduce_grid(x[first], y[first], z[first], *self.args, "max"))
        self.inten_sum += np.bincount(flat[first], np.asarray(intensity, float)[first], minlength=ncells)
        self.inten_n += np.bincount(flat[first], minlength=ncells)

    def add_chm(self, x, y, z, cls, dem) -> None:
        """Pass 2 (after the DEM): highest vegetation height above the DEM per cell."""
        veg = np.isin(cls, (4, 5))
        if veg.any():
            hag = z[veg] - sample_bilinear(dem, x[veg], y[veg], *self.args[:3])
            self.chm = np.fmax(self.chm, reduce_grid(x[veg], y[veg], hag, *self.args, "max"))

    def dem(self) -> np.ndarray:
        if not self.ground_n.any():
            raise ValueError("the cloud has no ground points (class 2): classify it first")
        shape = self.args[3], self.args[4]
        with np.errstate(invalid="ignore"):
            return fill_nodata((self.ground_sum / self.ground_n).reshape(shape))

    def grids(self, dem: np.ndarray, footprint_cells: int) -> dict:
        res_m, x0, y0, nrows, ncols = self.args
        occupied = (self.valid_n > 0).reshape(nrows, ncols)
        footprint = ndimage.binary_dilation(occupied, np.ones((3, 3), bool), iterations=footprint_cells)
        # Gaps enclosed by data (ponds without returns, shadows behind tall buildings) are
        # interpolated, as production DEMs are: only the outside of the survey stays nodata.
        footprint = ndimage.binary_fill_holes(footprint)
        dsm = np.maximum(fill_nodata(self.dsm), dem)
        with np.errstate(invalid="ignore"):
            inten = (self.inten_sum / self.inten_n).reshape(nrows, ncols)
        out = {
            "dem": np.where(footprint, dem, np.nan),
            "dsm": np.where(footprint, dsm, np.nan),
            "chm": np.where(self.chm > 0, self.chm, np.nan),
            "intensity": inten,
        }
        out["ndsm"] = out["dsm"] - out["dem"]
        out = {k: v[::-1].astype(np.float32) for k, v in out.items()}   # north-up rows
        out["transform"] = from_origin(x0, y0 + nrows * res_m, res_m, res_m)
        return out


def make_grids(cloud: PointCloud, res_m: float, footprint_cells: int = 3) -> dict:
    """Arrays (rows north-up, NaN = nodata) and the GeoTIFF transform of all rasters, in metres
    (``to_crs_units`` converts them to the cloud's units)."""
    check_res(res_m)
    x, y, z, cls = cloud.x, cloud.y, cloud.z, cloud.classification
    args = grid_for_bounds(x.min(), y.min(), x.max(), y.max(), res_m)
    check_grid(args[3], args[4], res_m, RASTER_BYTES_PER_CELL, "rasters", "--res", "use a coarser --res")
    sums = _CellSums(args)
    sums.add(x, y, z, cls, cloud.return_number, cloud.intensity)
    dem = sums.dem()
    sums.add_chm(x, y, z, cls, dem)
    return sums.grids(dem, footprint_cells)


def make_grids_streamed(path, res_m: float, footprint_cells: int = 3, chunk_points: int = io.CHUNK_POINTS,
                        units: LengthUnits = METRE):
    """``make_grids`` of a LAS/LAZ file in two streaming passes over its chunks: memory holds one
    chunk and the grids, never the whole cloud. The grid comes from the header bounds (which the
    LAS specification requires to enclose the points; a point outside them is an InputError).
    ``units``: the file's linear units (the grids are in metres). Returns (grids, number of points)."""
    check_res(res_m)
    header = las.read_header(path)
    mins, maxs = np.asarray(header.mins, float), np.asarray(header.maxs, float)
    if header.point_count == 0:
        raise InputError(f"{path}: the file holds no points")
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()) or (maxs[:2] < mins[:2]).any():
        raise InputError(f"{path}: absurd bounds in the LAS header (min {mins.tolist()}, max {maxs.tolist()})")
    args = grid_for_bounds(units.xy_to_m(mins[0]), units.xy_to_m(mins[1]), units.xy_to_m(maxs[0]),
                           units.xy_to_m(maxs[1]), res_m)
    check_grid(args[3], args[4], res_m, RASTER_BYTES_PER_CELL, f"{path}: rasters over the header bounds", "--res",
               "use a coarser --res (or check the bounds: strips far apart, a wrong CRS?)")
    sums = _CellSums(args)

    def chunks(validate):
        for first, chunk in las.iter_file_chunks(path, chunk_points):
            x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            if validate:
                io.validate_xyz(path, x, y, z, first, units)
                out = (x < mins[0]) | (x > maxs[0]) | (y < mins[1]) | (y > maxs[1])
                if out.any():
                    k = int(np.flatnonzero(out)[0])
                    raise InputError(f"{path}: point record {first + k} ({x[k]!r}, {y[k]!r}) lies outside the "
                                     f"header bounds {mins[:2].tolist()} .. {maxs[:2].tolist()}")
            yield chunk, units.xy_to_m(x), units.xy_to_m(y), units.z_to_m(z), np.asarray(chunk.classification)

    for chunk, x, y, z, cls in chunks(True):
        rn, _ = io.sanitize_returns(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
        sums.add(x, y, z, cls, rn, np.asarray(chunk.intensity))
    if not sums.ground_n.any():
        raise InputError(f"{path}: no ground points (class 2); run 'lidarctl classify' first")
    dem = sums.dem()
    for chunk, x, y, z, cls in chunks(False):
        sums.add_chm(x, y, z, cls, dem)
    return sums.grids(dem, footprint_cells), int(header.point_count)


def to_crs_units(grids: dict, units: LengthUnits) -> dict:
    """Grids of ``make_grids`` (metres) in the cloud's units: heights divided by the vertical unit,
    the transform by the horizontal unit (the same dict for metres)."""
    if units.is_metric:
        return grids
    out = dict(grids)
    for name in HEIGHT_GRIDS:
        out[name] = (grids[name].astype(float) / units.z_m).astype(np.float32)
    t = grids["transform"]
    out["transform"] = from_origin(t.c / units.xy_m, t.f / units.xy_m, t.a / units.xy_m, -t.e / units.xy_m)
    return out


def write_cog(path, array: np.ndarray, transform, crs, unit: str | None = None, description: str | None = None,
              tags: dict | None = None) -> None:
    """Single-band float32 Cloud-Optimized GeoTIFF (deflate, internal overviews), nodata -9999.

    ``unit``: the band's unit type (e.g. 'metre', 'foot'); ``description``: the band description;
    ``tags``: dataset metadata (e.g. LINEAR_UNITS)."""
    data = np.where(np.isfinite(array), array, NODATA).astype(np.float32)
    profile = dict(driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="float32",
                   crs=crs, transform=transform, nodata=NODATA)
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
            rio_copy(src, tmp, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average")


def hillshade(dem: np.ndarray, res_m: float, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """Hillshade 0..1 of a north-up DEM (NaN cells stay NaN)."""
    filled = np.where(np.isfinite(dem), dem, np.nanmean(dem))
    dz_dy, dz_dx = np.gradient(filled, res_m)
    dz_dy = -dz_dy   # rows run north to south
    slope = np.arctan(np.hypot(dz_dx, dz_dy))
    aspect = np.arctan2(-dz_dx, dz_dy)
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.where(np.isfinite(dem), np.clip(shade, 0.0, 1.0), np.nan)


def write_rasters(cloud, outdir, res_m: float, crs=None) -> list[Path]:
    """Write all rasters into ``outdir``; other files there (e.g. the classified cloud) stay.

    ``cloud``: a PointCloud (x, y, z in metres; its ``crs`` and ``units`` say how to write them), or
    the path of a classified LAS/LAZ file, streamed chunk by chunk (``make_grids_streamed``; ``crs``
    is then used only when the file has no CRS record). ``res_m``: cell size in metres. The rasters
    are in the cloud's CRS and units (see the module docstring). Everything is written into a
    temporary folder first and moved into place only when all files are complete, so an error
    leaves no partial set behind.
    """
    import os
    import shutil

    check_res(res_m)
    outdir = Path(outdir)
    if isinstance(cloud, PointCloud):
        crs, units = cloud.crs, cloud.units
        if crs is None:
            raise ValueError("a CRS is needed for the rasters")
        surface_crs = crs
    else:
        for f in FILES:
            refuse_input_as_output(outdir / f, [cloud], "OUTDIR")
        header = las.read_header(cloud)
        crs, units = io.resolve_crs_units(cloud, header, crs)
        # The DEM and DSM keep a compound CRS's vertical part (their heights' datum and unit), so that
        # ortho and 'crs warp' can bring them into another height system; the rest are relative.
        file_crs = las.header_crs(header)
        surface_crs = file_crs if file_crs is not None and file_crs.is_compound else crs
    grids = make_grids(cloud, res_m) if isinstance(cloud, PointCloud) else \
        make_grids_streamed(cloud, res_m, units=units)[0]
    # The hillshade needs heights and cell size in one unit: from the metric grids.
    hs = hillshade(grids["dem"], res_m)
    grids = to_crs_units(grids, units)
    tags = {"LINEAR_UNITS": long_name(units.xy_m), "VERTICAL_UNITS": long_name(units.z_m),
            "CELL_SIZE_M": f"{res_m:g}", "CELL_SIZE": f"{res_m / units.xy_m:.10g} {units.xy_name}"}
    outdir.mkdir(parents=True, exist_ok=True)
    tmp = temporary_dir(outdir, "rasters")
    try:
        for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
            height = name in HEIGHT_GRIDS
            desc = DESCRIPTIONS[name] + (f" ({long_name(units.z_m)})" if height else "")
            write_cog(tmp / f"{name}.tif", grids[name], grids["transform"], surface_crs if name in ("dem", "dsm") else crs,
                      unit=long_name(units.z_m) if height else None, description=desc, tags=tags)
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        plt.imsave(tmp / "hillshade.png", np.where(np.isfinite(hs), hs, 0.0), cmap="gray", vmin=0, vmax=1)
        for f in FILES:
            os.chmod(tmp / f, 0o644)
            os.replace(tmp / f, outdir / f)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [outdir / f for f in FILES]
