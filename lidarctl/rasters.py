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

from pathlib import Path

import numpy as np
import rasterio
from rasterio.io import MemoryFile
from rasterio.shutil import copy as rio_copy
from rasterio.transform import from_origin
from scipy import ndimage

from lidarctl.atomic import atomic_path
from lidarctl.io import PointCloud
from lidarctl.raster_ops import fill_nodata, reduce_grid, sample_bilinear

NODATA = -9999.0
FILES = ("dem.tif", "dsm.tif", "ndsm.tif", "chm.tif", "intensity.tif", "hillshade.png")


def make_grids(cloud: PointCloud, res_m: float, footprint_cells: int = 3) -> dict:
    """Arrays (rows north-up, NaN = nodata) and the GeoTIFF transform of all rasters."""
    x, y, z, cls = cloud.x, cloud.y, cloud.z, cloud.classification
    x0 = np.floor(x.min() / res_m) * res_m
    y0 = np.floor(y.min() / res_m) * res_m
    ncols = int(np.floor((x.max() - x0) / res_m)) + 1
    nrows = int(np.floor((y.max() - y0) / res_m)) + 1
    args = (res_m, x0, y0, nrows, ncols)
    valid = ~np.isin(cls, (7, 18))
    occupied = np.isfinite(reduce_grid(x[valid], y[valid], z[valid], *args, "max"))
    footprint = ndimage.binary_dilation(occupied, np.ones((3, 3), bool), iterations=footprint_cells)
    # Gaps enclosed by data (ponds without returns, shadows behind tall buildings) are interpolated,
    # as production DEMs are: only the outside of the survey stays nodata.
    footprint = ndimage.binary_fill_holes(footprint)

    g = np.isin(cls, (2, 9))
    if not g.any():
        raise ValueError("the cloud has no ground points (class 2): classify it first")
    dem = fill_nodata(reduce_grid(x[g], y[g], z[g], *args, "mean"))
    first = valid & (cloud.return_number == 1)
    dsm = reduce_grid(x[first], y[first], z[first], *args, "max")
    dsm = np.maximum(fill_nodata(np.where(np.isfinite(dsm), dsm, np.nan)), dem)
    veg = np.isin(cls, (4, 5))
    hag = z - sample_bilinear(dem, x, y, *args[:3])
    chm = reduce_grid(x[veg], y[veg], hag[veg], *args, "max") if veg.any() else np.full((nrows, ncols), np.nan)
    chm = np.where(chm > 0, chm, np.nan)
    inten = reduce_grid(x[first], y[first], cloud.intensity[first].astype(float), *args, "mean")
    out = {
        "dem": np.where(footprint, dem, np.nan),
        "dsm": np.where(footprint, dsm, np.nan),
        "chm": chm,
        "intensity": inten,
    }
    out["ndsm"] = out["dsm"] - out["dem"]
    out = {k: v[::-1].astype(np.float32) for k, v in out.items()}   # north-up rows
    out["transform"] = from_origin(x0, y0 + nrows * res_m, res_m, res_m)
    return out


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


def write_rasters(cloud: PointCloud, outdir, res_m: float) -> list[Path]:
    """Write all rasters into ``outdir``; other files there (e.g. the classified cloud) stay.

    Everything is written into a temporary folder first and moved into place only when all files
    are complete, so an error leaves no partial set behind.
    """
    import os
    import shutil
    import tempfile

    if cloud.crs is None:
        raise ValueError("a CRS is needed for the rasters")
    grids = make_grids(cloud, res_m)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".rasters.", dir=outdir))
    try:
        for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
            write_cog(tmp / f"{name}.tif", grids[name], grids["transform"], cloud.crs)
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
