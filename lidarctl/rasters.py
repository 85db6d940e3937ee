"""Rasters from a classified cloud: DEM, DSM, nDSM, CHM, intensity (Cloud-Optimized GeoTIFF) and a
hillshade quicklook (PNG).

Grid: cells of ``res_m`` aligned to multiples of ``res_m`` in the cloud's CRS, north-up.
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
import rasterio
from rasterio.io import MemoryFile
from rasterio.shutil import copy as rio_copy
from rasterio.transform import from_origin
from scipy import ndimage

from lidarctl import io
from aerotri.core.atomic import atomic_path, temporary_dir
from aerotri.core.errors import InputError
from aerotri.core.settings import setting
from lidarctl.io import PointCloud
from lidarctl.raster_ops import fill_nodata, reduce_grid, sample_bilinear

NODATA = -9999.0
FILES = ("dem.tif", "dsm.tif", "ndsm.tif", "chm.tif", "intensity.tif", "hillshade.png")


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
    """Arrays (rows north-up, NaN = nodata) and the GeoTIFF transform of all rasters."""
    x, y, z, cls = cloud.x, cloud.y, cloud.z, cloud.classification
    sums = _CellSums(grid_for_bounds(x.min(), y.min(), x.max(), y.max(), res_m))
    sums.add(x, y, z, cls, cloud.return_number, cloud.intensity)
    dem = sums.dem()
    sums.add_chm(x, y, z, cls, dem)
    return sums.grids(dem, footprint_cells)


def make_grids_streamed(path, res_m: float, footprint_cells: int = 3, chunk_points: int = io.CHUNK_POINTS):
    """``make_grids`` of a LAS/LAZ file in two streaming passes over its chunks: memory holds one
    chunk and the grids, never the whole cloud. The grid comes from the header bounds (which the
    LAS specification requires to enclose the points; a point outside them is an InputError).
    Returns (grids, number of points)."""
    header = io.read_header(path)
    mins, maxs = np.asarray(header.mins, float), np.asarray(header.maxs, float)
    if header.point_count == 0:
        raise InputError(f"{path}: the file holds no points")
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()) or (maxs[:2] < mins[:2]).any():
        raise InputError(f"{path}: absurd bounds in the LAS header (min {mins.tolist()}, max {maxs.tolist()})")
    args = grid_for_bounds(mins[0], mins[1], maxs[0], maxs[1], res_m)
    if args[3] * args[4] > 2 ** 31:
        raise InputError(f"{path}: {args[3]} x {args[4]} cells of {res_m:g} m; use a coarser --res")
    sums = _CellSums(args)

    def chunks(validate):
        for first, chunk in io.iter_chunks(path, chunk_points):
            x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            if validate:
                io.validate_xyz(path, x, y, z, first)
                out = (x < mins[0]) | (x > maxs[0]) | (y < mins[1]) | (y > maxs[1])
                if out.any():
                    k = int(np.flatnonzero(out)[0])
                    raise InputError(f"{path}: point record {first + k} ({x[k]!r}, {y[k]!r}) lies outside the "
                                     f"header bounds {mins[:2].tolist()} .. {maxs[:2].tolist()}")
            yield chunk, x, y, z, np.asarray(chunk.classification)

    for chunk, x, y, z, cls in chunks(True):
        rn, _ = io.sanitize_returns(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
        sums.add(x, y, z, cls, rn, np.asarray(chunk.intensity))
    if not sums.ground_n.any():
        raise InputError(f"{path}: no ground points (class 2); run 'lidarctl classify' first")
    dem = sums.dem()
    for chunk, x, y, z, cls in chunks(False):
        sums.add_chm(x, y, z, cls, dem)
    return sums.grids(dem, footprint_cells), int(header.point_count)


def write_cog(path, array: np.ndarray, transform, crs) -> None:
    """Single-band float32 Cloud-Optimized GeoTIFF (deflate, internal overviews), nodata -9999."""
    data = np.where(np.isfinite(array), array, NODATA).astype(np.float32)
    profile = dict(driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="float32",
                   crs=crs, transform=transform, nodata=NODATA)
    with MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(data, 1)
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

    ``cloud``: a PointCloud, or the path of a classified LAS/LAZ file, streamed chunk by chunk
    (``make_grids_streamed``; ``crs`` is then the resolved CRS of the file). Everything is written
    into a temporary folder first and moved into place only when all files are complete, so an
    error leaves no partial set behind.
    """
    import os
    import shutil

    if isinstance(cloud, PointCloud):
        crs = cloud.crs
    if crs is None:
        raise ValueError("a CRS is needed for the rasters")
    grids = make_grids(cloud, res_m) if isinstance(cloud, PointCloud) else make_grids_streamed(cloud, res_m)[0]
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    tmp = temporary_dir(outdir, "rasters")
    try:
        for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
            write_cog(tmp / f"{name}.tif", grids[name], grids["transform"], crs)
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        hs = hillshade(grids["dem"], res_m)
        plt.imsave(tmp / "hillshade.png", np.where(np.isfinite(hs), hs, 0.0), cmap="gray", vmin=0, vmax=1)
        for f in FILES:
            os.chmod(tmp / f, 0o644)
            os.replace(tmp / f, outdir / f)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [outdir / f for f in FILES]
