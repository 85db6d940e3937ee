"""What a height raster (DEM, DSM) says of itself beyond its CRS, checked before its heights are used: a nodata fill
it does not declare, a height unit its band or tags state, heights above the ground (lidarctl rasters' nDSM and CHM)
where terrain or surface heights are needed. Shared by ``ortho`` and ``lidarctl``'s terrain commands."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import rasterio
from pyproj import CRS

from aerotri.core.errors import InputError
from aerotri.geom.crs.definition import height_unit_m, length_unit_m


# a DEM's cells at exactly 0 are taken for an undeclared fill when its other heights all lie more than this (m)
# above 0: gdalwarp fills what lies beyond its source with 0 and declares no nodata for a float DEM unless told; a
# coast's ground runs down to the sea's 0 (its lowest heights within this), a plateau of 0 beside 400 m does not
ZERO_FILL_GAP_M = 10.0
ZERO_FILL_MIN_SHARE = 0.001  # of the valid cells (a decimated read): fewer zeros are not worth a word


# below 0, the values software writes for "no height" when it declares none (ESRI's and surveyors' -9999, -999, -99;
# a 16-bit DEM's -32767 / -32768): taken for an undeclared fill when they are the raster's lowest value, with the other
# heights more than ``ZERO_FILL_GAP_M`` above. Beyond -1000 m they are refused anyway
# (``aerotri.geom.inputs.check_height_values``); -999 and -99 lie within them and were neither refused nor warned of
# (review 28)
NEGATIVE_FILL_VALUES = (-99.0, -999.0, -9999.0, -99999.0, -32767.0, -32768.0)


@dataclasses.dataclass(frozen=True)
class UndeclaredFill:
    """A height raster's cells that look like an undeclared nodata fill: ``value`` (raster units), their ``share`` of
    the valid cells, the lowest and highest other heights ``lo``, ``hi`` (raster units)."""
    value: float
    share: float
    lo: float
    hi: float


def undeclared_fill(ds, max_cells: int = 1_000_000) -> UndeclaredFill | None:
    """The cells of band 1 of the open height raster ``ds`` that look like an undeclared fill: no nodata value, mask or
    alpha declared, at least ``ZERO_FILL_MIN_SHARE`` of the cells at exactly 0 or at one of ``NEGATIVE_FILL_VALUES``
    (the raster's lowest value), and every other height more than ``ZERO_FILL_GAP_M`` above it (0 with heights below
    0 too: not a DEM of land above sea level); None otherwise. A decimated read, as ``height_range``."""
    from rasterio.enums import MaskFlags

    if ds.mask_flag_enums[0] != [MaskFlags.all_valid]:
        return None
    step = max(1, int(math.ceil(math.sqrt(ds.width * ds.height / max_cells))))
    v = ds.read(1, out_shape=(max(1, ds.height // step), max(1, ds.width // step)),
                resampling=rasterio.enums.Resampling.nearest).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    lowest = float(v.min())
    unit_m = height_unit_m(CRS(ds.crs)) if ds.crs is not None else 1.0
    for value in (0.0, lowest):
        if value != 0.0 and value not in NEGATIVE_FILL_VALUES:
            continue
        fill = v == value
        n = int(np.count_nonzero(fill))
        if n < ZERO_FILL_MIN_SHARE * v.size or n == v.size:
            continue
        other = v[~fill]
        lo, hi = float(other.min()), float(other.max())
        if (lo - value) * unit_m > ZERO_FILL_GAP_M:
            return UndeclaredFill(value, n / v.size, lo, hi)
    return None


# lidarctl rasters' grids of heights above the ground (their band descriptions' starts): no terrain, though heights
ABOVE_GROUND_DESCRIPTIONS = ("CHM:", "nDSM:")


def above_ground_description(src) -> str | None:
    """The band description of an open raster that says it holds heights above the ground (lidarctl rasters' chm.tif,
    ndsm.tif), None for any other raster."""
    desc = (src.descriptions[0] if src.count >= 1 and src.descriptions else None) or ""
    return desc if desc.startswith(ABOVE_GROUND_DESCRIPTIONS) else None


def refuse_above_ground(src, path, needs: str) -> None:
    """InputError when the open raster says it holds heights above the ground (``above_ground_description``) where
    ``needs`` (e.g. "drainage needs a DEM of the ground ...") asks for heights of the terrain or surface (trial s94:
    ``lidarctl drainage chm.tif`` traced streams over the crowns, exit 0; trial s99 lidmut H3: ``ortho rectify --dem
    ndsm.tif`` made frames 8-16 m off, exit 0)."""
    desc = above_ground_description(src)
    if desc is not None:
        raise InputError(f"{path}: holds heights above the ground (its band description {desc!r}), not heights of the "
                         f"terrain; {needs}")


def stated_height_unit_m(src) -> float | None:
    """Metres per height unit the raster states itself (its band's unit type, else a VERTICAL_UNITS tag), None when it
    states none or one not known here."""
    for name in (src.units[0] if src.units else None, src.tags().get("VERTICAL_UNITS")):
        unit_m = length_unit_m(name)
        if unit_m is not None:
            return unit_m
    return None


# the international and the US survey foot (2 ppm apart) are one unit for a raster's heights (a State Plane DEM tagged
# "ft" was refused by ortho rectify, regression trial s99)
SAME_UNIT_REL = 1e-5


def stated_unit_differs(stated_m: float | None, implied_m: float) -> bool:
    """Whether a stated height unit (``stated_height_unit_m``, None: none stated) is another than the CRS's
    ``implied_m`` (metres per unit), beyond ``SAME_UNIT_REL``."""
    return stated_m is not None and abs(stated_m / implied_m - 1.0) >= SAME_UNIT_REL
