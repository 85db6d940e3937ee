"""Opening a DEM GeoTIFF for the terrain products (``lidarctl smooth``, ``hydro-flatten``, ``contours``): the checks
every one of them makes before any work, and the metres per height unit its CRS gives; and writing a product DEM
from its working GeoTIFF."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from aerotri.core.errors import InputError

HYDRO_TAG = "HYDRO_FLATTENED"  # lidarctl hydro-flatten's tag on its DEM: lidarctl smooth warns of it


def stated_height_unit_m(src) -> float | None:
    """Metres per height unit the raster states itself (its band's unit type, else a VERTICAL_UNITS tag), None when it
    states none or one not known here."""
    from aerotri.geom.crs.definition import length_unit_m

    for name in (src.units[0] if src.units else None, src.tags().get("VERTICAL_UNITS")):
        unit_m = length_unit_m(name)
        if unit_m is not None:
            return unit_m
    return None


@dataclasses.dataclass(frozen=True)
class DemHeightUnit:
    """Metres per height unit of a DEM (``unit_m``) and whether the file declares it (``declared``: a compound or 3D
    CRS, the band's unit type or a VERTICAL_UNITS tag); False: its CRS is 2D and says nothing of heights, which are
    taken in its horizontal unit (``horizontal_unit_m``, the LAS convention), an assumption."""

    unit_m: float
    declared: bool
    horizontal_unit_m: float


def open_dem(in_path, out_path=None):
    """(open rasterio dataset, metres per height unit) of a north-up DEM with a CRS, one band of finite,
    plausible heights with at least one valid cell and at least 2 x 2 cells (``aerotri.geom.crs.raster_warp.
    open_north_up``); refuses ``out_path`` equal to the input (``OptionError`` naming OUT; None: a check that
    writes no raster) and anything else with an ``InputError`` naming the file. The caller closes the dataset."""
    src, unit = open_dem_unit(in_path, out_path)
    return src, unit.unit_m


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
        from aerotri.geom.crs.definition import length_unit_name, linear_unit_m, parse_crs

        crs = parse_crs(src.crs.to_wkt())
        unit_m = height_unit_m(crs)
        stated = stated_height_unit_m(src)
        vertical_in_crs = crs.is_compound or len(crs.axis_info) >= 3
        if stated is not None and not vertical_in_crs and abs(stated - unit_m) > 1e-9:
            # a 2D CRS says nothing of heights (its horizontal unit is assumed): the file's own statement decides
            # (trial-hydro: metres on a foot grid, tagged metre, read as feet: contours labelled 124-132 ft)
            import logging

            logging.getLogger(__name__).info(
                "%s: heights in %s as the file states them (its CRS is 2D, in %s)", in_path,
                length_unit_name(stated, long=True), length_unit_name(unit_m, long=True))
            unit_m = stated
        return src, DemHeightUnit(float(unit_m), bool(vertical_in_crs or stated is not None),
                                  float(linear_unit_m(crs)))
    except BaseException:
        src.close()
        raise


# lidarctl rasters' grids of heights above the ground (their band descriptions' starts): no terrain, though heights
ABOVE_GROUND_DESCRIPTIONS = ("CHM:", "nDSM:")


def refuse_above_ground(src, path, command: str) -> None:
    """InputError when the raster says it holds heights above the ground (lidarctl rasters' chm.tif, ndsm.tif, by
    their band descriptions), for a ``command`` that needs terrain (trial s94: ``lidarctl drainage chm.tif`` traced
    streams over the crowns, exit 0, where intensity.tif was refused)."""
    desc = (src.descriptions[0] if src.count >= 1 and src.descriptions else None) or ""
    if desc.startswith(ABOVE_GROUND_DESCRIPTIONS):
        raise InputError(f"{path}: holds heights above the ground (its band description {desc!r}), not terrain; "
                         f"{command} needs a DEM of the ground (lidarctl rasters' dem.tif)")


def write_dem_cog(work, out_path) -> None:
    """The working GeoTIFF ``work`` as a float COG at ``out_path`` (DEFLATE with the float predictor, averaged
    overviews), written atomically: the product DEM of ``smooth`` and ``hydro-flatten``."""
    import rasterio
    from rasterio.shutil import copy as rio_copy

    from aerotri.core.atomic import atomic_path

    with rasterio.open(work) as src, atomic_path(out_path) as dst_path:
        rio_copy(src, dst_path, driver="COG", compress="DEFLATE", predictor=3, overview_resampling="average",
                 num_threads="ALL_CPUS")
