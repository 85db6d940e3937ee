"""Linear units of a point cloud's CRS: metres, international feet, US survey feet.

Every length lidarctl works with (tile sizes, buffers, radii, cell sizes, height thresholds) is in
metres. A cloud in a foot CRS is scaled to metres once, when it is read (``lidarctl.io``), and its
outputs are scaled back to the CRS's units when they are written (raster transforms and heights,
corner coordinates), so the outputs stay in the input's CRS and units.

Vertical unit: a compound CRS (or a LAS GeoTIFF ``VerticalUnitsGeoKey``) gives its own; a 2D
projected CRS has z in its horizontal unit (the LAS convention). Geographic CRSs (degrees) are
refused: the filters need lengths.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyproj

from aerotri.core.errors import CrsError
from aerotri.geom.crs.definition import crs_label, horizontal_crs, length_unit_name, linear_unit_m, unit_name


@dataclasses.dataclass(frozen=True)
class LengthUnits:
    """Metres per unit of the horizontal axes (``xy_m``) and of heights (``z_m``) of a cloud's CRS.

    ``known`` is False for a file without any CRS read where no CRS is required (``lidarctl
    evaluate``): its coordinates are then taken as they are, in an unknown unit.
    """

    xy_m: float = 1.0
    z_m: float = 1.0
    known: bool = True
    # False: the CRS is 2D and no VerticalUnitsGeoKey says the heights' unit; z is taken in the horizontal unit (the LAS
    # convention), an assumption a check says where it matters (feet). Not compared: the same units either way
    z_declared: bool = dataclasses.field(default=True, compare=False)

    @property
    def xy_name(self) -> str:
        return length_unit_name(self.xy_m) if self.known else "file units"

    @property
    def z_name(self) -> str:
        return length_unit_name(self.z_m) if self.known else "file units"

    @property
    def is_metric(self) -> bool:
        return self.xy_m == 1.0 and self.z_m == 1.0

    def describe(self) -> str:
        if not self.known:
            return "unknown units (no CRS)"
        if self.xy_m == self.z_m:
            return f"x, y, z in {length_unit_name(self.xy_m, long=True)}"
        return f"x, y in {length_unit_name(self.xy_m, long=True)}, z in {length_unit_name(self.z_m, long=True)}"

    def as_dict(self) -> dict:
        """JSON-ready description: unit names and metres per unit."""
        return {"xy_unit": self.xy_name, "z_unit": self.z_name, "xy_unit_m": self.xy_m, "z_unit_m": self.z_m}

    # Scaling: identity (no copy, no rounding) for metres, so metric data take exactly the old path.
    def xy_to_m(self, v):
        return v if self.xy_m == 1.0 else np.asarray(v, float) * self.xy_m

    def z_to_m(self, v):
        return v if self.z_m == 1.0 else np.asarray(v, float) * self.z_m

    def xy_from_m(self, v):
        return v if self.xy_m == 1.0 else np.asarray(v, float) / self.xy_m

    def z_from_m(self, v):
        return v if self.z_m == 1.0 else np.asarray(v, float) / self.z_m


METRE = LengthUnits()
UNKNOWN = LengthUnits(known=False)


def _vertical_unit_m(crs: pyproj.CRS) -> float | None:
    """Metres per unit of the vertical axis of a compound (or 3D) CRS, else None."""
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical and sub.axis_info:
                return float(sub.axis_info[0].unit_conversion_factor)
        return None
    if len(crs.axis_info) == 3:
        factor = crs.axis_info[2].unit_conversion_factor
        # A 3D geographic CRS has ellipsoidal heights in metres; a 3D projected CRS its own unit.
        return float(factor)
    return None


def units_of(crs: pyproj.CRS, source: str = "CRS", vertical_unit_m: float | None = None) -> LengthUnits:
    """The LengthUnits of a projected (or compound projected) CRS; ``CrsError`` naming ``source`` for
    a geographic or geocentric CRS.

    ``vertical_unit_m``: the vertical unit when it comes from elsewhere (a LAS VerticalUnitsGeoKey);
    else the vertical sub-CRS's unit, else (2D CRS) the horizontal unit.
    """
    h = horizontal_crs(crs)
    if h.is_geographic or h.is_geocentric or not h.is_projected:
        raise CrsError(
            f"{source}: {crs_label(crs)} ({h.name}) is a {'geographic' if h.is_geographic else 'non-projected'} CRS "
            f"({unit_name(h) if h.is_geographic else 'no map grid'}); lidarctl needs a projected CRS in metres or "
            "feet: reproject it first (aerotri crs transform)"
        )
    xy_m = linear_unit_m(crs)
    if not (np.isfinite(xy_m) and xy_m > 0):
        raise CrsError(f"{source}: {crs_label(crs)} has no usable linear unit ({xy_m!r} m per unit)")
    declared = vertical_unit_m or _vertical_unit_m(crs)
    z_m = declared or xy_m
    return LengthUnits(float(xy_m), float(z_m), z_declared=bool(declared))


# A length within this share of a whole unit (or of a half, quarter, fifth or tenth of one) of a CRS in feet is
# that: 0.3048 m (the international foot) in US survey feet is 0.999998 ft, and contours were traced at 1353.997292 ft
# where 1354 was meant; 0.3048006096 m (a US survey foot typed to 10 digits) made cells of 0.999999999996 ft (trial-us)
WHOLE_UNIT_SHARE = 1e-5


def whole_units(length_m: float, unit_m: float) -> float | None:
    """``length_m`` in units of ``unit_m`` metres snapped to a whole number of them (or 1/2, 1/4, 1/5, 1/10 of one)
    when within ``WHOLE_UNIT_SHARE`` of it and the unit is not the metre; None otherwise (no snap)."""
    if unit_m == 1.0:
        return None
    value = length_m / unit_m
    for den in (1, 2, 4, 5, 10):
        whole = round(value * den) / den
        if whole > 0 and abs(value - whole) <= WHOLE_UNIT_SHARE * whole:
            return whole
    return None
