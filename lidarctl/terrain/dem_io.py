"""Opening a DEM GeoTIFF for the terrain products (``lidarctl smooth``, ``hydro-flatten``, ``contours``): the checks
every one of them makes before any work, and the metres per height unit its CRS gives; and writing a product DEM
from its working GeoTIFF."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from aerotri.core.errors import InputError

log = logging.getLogger(__name__)

HYDRO_TAG = "HYDRO_FLATTENED"  # lidarctl hydro-flatten's tag on its DEM: lidarctl smooth warns of it


@dataclasses.dataclass(frozen=True)
class DemHeightUnit:
    """Metres per height unit of a DEM (``unit_m``) and whether the file declares it (``declared``: a compound or 3D
    CRS, the band's unit type or a VERTICAL_UNITS tag); False: its CRS is 2D and says nothing of heights, which are
    taken in its horizontal unit (``horizontal_unit_m``, the LAS convention), an assumption."""

    unit_m: float
    declared: bool
    horizontal_unit_m: float


def open_dem(in_path, out_path=None, say_unit: bool = False):
    """(open rasterio dataset, metres per height unit) of a north-up DEM with a CRS, one band of finite,
    plausible heights with at least one valid cell and at least 2 x 2 cells (``aerotri.geom.crs.raster_warp.
    open_north_up``), no undeclared fill (``refuse_undeclared_fill``); refuses ``out_path`` equal to the input
    (``OptionError`` naming OUT; None: a check that writes no raster) and anything else with an ``InputError`` naming
    the file. ``say_unit``: a warning when the heights' unit is assumed from a CRS in feet (``undeclared_unit_words``).
    The caller closes the dataset."""
    src, unit = open_dem_unit(in_path, out_path)
    words = undeclared_unit_words(in_path, unit) if say_unit else None
    if words:
        log.warning("%s", words)
    return src, unit.unit_m


def undeclared_unit_words(path, unit: "DemHeightUnit") -> str | None:
    """The assumption made when a DEM on a grid in feet declares no height unit (no vertical CRS, band unit or
    VERTICAL_UNITS tag): heights in feet too, as LAS has it; a State Plane grid with NAVD88 metres is common (trial
    s99 lidmut H4: metres under EPSG:2992 contoured as feet, elevation_m 95 for 311.7 m, no word). None when declared
    or metric."""
    from aerotri.geom.crs.definition import length_unit_name

    if unit.declared or abs(unit.horizontal_unit_m - 1.0) < 1e-12:
        return None
    return (f"{path}: declares no vertical unit (no vertical CRS, band unit or VERTICAL_UNITS tag): its heights are "
            f"taken in its CRS's horizontal unit, {length_unit_name(unit.unit_m, long=True)}; if they are metres, tag "
            f"the raster (gdal_edit.py -mo VERTICAL_UNITS=metre {path}) and run again")


def open_dem_unit(in_path, out_path=None):
    """``open_dem`` with the height unit as a ``DemHeightUnit`` (whether the file declares it)."""
    from aerotri.core.atomic import refuse_input_as_output
    from aerotri.geom.crs.definition import height_unit_m
    from aerotri.geom.crs.raster_warp import open_north_up

    in_path = Path(in_path)
    if out_path is not None:
        refuse_input_as_output(Path(out_path), [in_path], option="OUT")
    src = open_north_up(in_path, "DEM", heights=True)
    try:
        refuse_undeclared_fill(src, in_path)
        from aerotri.geom.crs.definition import length_unit_name, linear_unit_m, parse_crs

        crs = parse_crs(src.crs.to_wkt())
        unit_m = height_unit_m(crs)
        from aerotri.geom.crs.height_rasters import stated_height_unit_m, stated_unit_differs

        stated = stated_height_unit_m(src)
        vertical_in_crs = crs.is_compound or len(crs.axis_info) >= 3
        if not vertical_in_crs and stated_unit_differs(stated, unit_m):
            # a 2D CRS says nothing of heights (its horizontal unit is assumed): the file's own statement decides
            # (trial-hydro: metres on a foot grid, tagged metre, read as feet: contours labelled 124-132 ft)
            log.info(
                "%s: heights in %s as the file states them (its CRS is 2D, in %s)", in_path,
                length_unit_name(stated, long=True), length_unit_name(unit_m, long=True))
            unit_m = stated
        return src, DemHeightUnit(float(unit_m), bool(vertical_in_crs or stated is not None),
                                  float(linear_unit_m(crs)))
    except BaseException:
        src.close()
        raise


def refuse_undeclared_fill(src, path) -> None:
    """InputError when the DEM's cells at 0 or at a negative fill value (-99, -999, -9999 ...) look like a nodata value
    it does not declare (``aerotri.geom.crs.height_rasters.undeclared_fill``): its contours, drainage, smoothing and
    height check took them for heights (trial s99 lidmut H1: -999 over a 310-370 m block gave 806 contours from -995 m,
    a drainage fill raising cells 1,312 m, check-heights RMSE 594 m; ``ortho rectify`` warned of the same file)."""
    from aerotri.geom.crs.height_rasters import undeclared_fill

    found = undeclared_fill(src)
    if found is None:
        return
    v = f"{found.value:g}"
    raise InputError(f"{path}: {100 * found.share:.1f} % of the DEM's cells hold exactly {v} while its other heights "
                     f"are {found.lo:.6g} .. {found.hi:.6g} and it declares no nodata value: a fill (gdalwarp's beyond "
                     f"its source, a clipped DEM)? Declare it (gdal_edit.py -a_nodata {v} {path}, or rio edit-info "
                     f"--nodata {v} {path}); if those cells are ground at {v}, declare the nodata value the DEM does "
                     "use (any value it does not hold) and they are read as heights")


def write_dem_cog(work, out_path) -> None:
    """The working GeoTIFF ``work`` as a float COG at ``out_path`` (DEFLATE with the float predictor, averaged
    overviews), written atomically: the product DEM of ``smooth`` and ``hydro-flatten``."""
    import rasterio
    from rasterio.shutil import copy as rio_copy

    from aerotri.core.atomic import atomic_path

    with rasterio.open(work) as src, atomic_path(out_path) as dst_path:
        rio_copy(src, dst_path, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average",
                 num_threads="ALL_CPUS")
