"""Opening a DEM GeoTIFF for the terrain products (``lidarctl smooth``, ``hydro-flatten``, ``contours``): the checks
every one of them makes before any work, and the metres per height unit its CRS gives; and writing a product DEM
from its working GeoTIFF."""

from __future__ import annotations

from pathlib import Path


HYDRO_TAG = "HYDRO_FLATTENED"  # lidarctl hydro-flatten's tag on its DEM: lidarctl smooth warns of it

def open_dem(in_path, out_path=None):
    """(open rasterio dataset, metres per height unit) of a north-up DEM with a CRS, one band of finite,
    plausible heights with at least one valid cell and at least 2 x 2 cells (``aerotri.geom.crs.raster_warp.
    open_north_up``); refuses ``out_path`` equal to the input (``OptionError`` naming OUT; None: a check that
    writes no raster) and anything else with an ``InputError`` naming the file. The caller closes the dataset."""
    from aerotri.core.atomic import refuse_input_as_output
    from aerotri.geom.crs.definition import height_unit_m
    from aerotri.geom.crs.raster_warp import open_north_up

    in_path = Path(in_path)
    if out_path is not None:
        refuse_input_as_output(Path(out_path), [in_path], option="OUT")
    src = open_north_up(in_path, "DEM", heights=True)
    try:
        return src, height_unit_m(src.crs.to_wkt())
    except BaseException:
        src.close()
        raise


def write_dem_cog(work, out_path) -> None:
    """The working GeoTIFF ``work`` as a float COG at ``out_path`` (DEFLATE with the float predictor, averaged
    overviews), written atomically: the product DEM of ``smooth`` and ``hydro-flatten``."""
    import rasterio
    from rasterio.shutil import copy as rio_copy

    from aerotri.core.atomic import atomic_path

    with rasterio.open(work) as src, atomic_path(out_path) as dst_path:
        rio_copy(src, dst_path, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average",
                 num_threads="ALL_CPUS")
