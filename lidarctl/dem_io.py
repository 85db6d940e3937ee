"""Opening a DEM GeoTIFF for the terrain products (``lidarctl smooth``, ``contours``): the checks every one of
them makes before any work, and the metres per height unit its CRS gives."""

from __future__ import annotations

from pathlib import Path

from aerotri.core.errors import InputError


def open_dem(in_path, out_path=None):
    """(open rasterio dataset, metres per height unit) of a north-up, single-band DEM with a CRS; refuses
    ``out_path`` equal to the input (``OptionError`` naming OUT; None: a check that writes no raster) and
    anything else with an ``InputError`` naming the file. The caller closes the dataset."""
    import rasterio

    from aerotri.core.atomic import refuse_input_as_output
    from aerotri.geom.crs import height_unit_m

    in_path = Path(in_path)
    if out_path is not None:
        refuse_input_as_output(Path(out_path), [in_path], option="OUT")
    try:
        src = rasterio.open(in_path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{in_path}: not a readable raster ({exc})") from None
    try:
        if src.count < 1 or src.crs is None:
            raise InputError(f"{in_path}: a DEM needs one band and a CRS (got {src.count} band(s), CRS {src.crs})")
        if abs(src.transform.b) > 1e-12 or abs(src.transform.d) > 1e-12:
            raise InputError(f"{in_path}: rotated rasters are not supported (transform {tuple(src.transform)[:6]})")
        return src, height_unit_m(src.crs.to_wkt())
    except BaseException:
        src.close()
        raise
