"""The terrain class of a block from its DEM, beside the class the tolerance table was chosen for.

The Chinese tolerance tables (GB/T 7930, GB/T 23236, CH/T 1004) hold plan and height limits per terrain class,
and the class is defined by the ground slope: flat below 2 deg, hilly 2-6 deg, mountainous 6-25 deg (and high
mountains above 25 deg, held to the mountainous limits here: ``TERRAINS`` has three classes). The class a
project declares (``[qa] terrain``) is the contract's; the DEM tells the slope of the ground the block covers.
Measured as the median slope over cells of ``CELL_M`` (the DEM averaged to them: the class is a property of the
map sheet, not of the banks of a ditch), within the DEM's valid cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CELL_M = 10.0  # slope over 10 m cells: the relief a 1:2000-1:10000 sheet shows
MAX_SIDE_PX = 4000  # read averaged to at most this many cells a side (memory bounded on a large DEM)
SLOPE_CLASSES_DEG = (("flat", 2.0), ("hilly", 6.0), ("mountainous", math.inf))  # upper bounds
TERRAIN_ORDER = {"flat": 0, "hilly": 1, "mountainous": 2}  # from the tightest limits to the loosest


@dataclass(frozen=True)
class DemTerrain:
    """The terrain class the DEM's slope gives, its median slope (deg), the cell it was measured on (m) and the
    DEM's file."""

    terrain: str
    median_slope_deg: float
    cell_m: float
    path: Path
    # the DEM's share (%) of cells extended beyond its data as a flat continuation (``ortho dem``'s tag,
    # ``ortho.points_dem.EXTRAPOLATED_PERCENT_TAG``); None: not stated (a LiDAR DEM, one from elsewhere)
    extrapolated_pct: float | None = None

    @property
    def mostly_extrapolated(self) -> bool:
        """More than half the DEM a flat continuation: its median slope is that of the filling, near 0 (trial s100 rc
        F7: Tuniu's tie-point DEM, 89 % extended, read "flat, median slope 0.0 deg" over 40 m of relief)."""
        return self.extrapolated_pct is not None and self.extrapolated_pct > 50.0

    def text(self) -> str:
        return (f"median slope {self.median_slope_deg:.1f} deg over {self.cell_m:.0f} m cells of {self.path.name}: "
                f"{self.terrain} (flat below 2, hilly 2-6, mountainous above 6 deg)")


def class_of_slope(slope_deg: float) -> str:
    return next(name for name, upper in SLOPE_CLASSES_DEG if slope_deg < upper)


def dem_terrain(path) -> DemTerrain | None:
    """The terrain class of the DEM ``path`` by its median slope; None when it holds fewer than 9 valid cells at
    ``CELL_M`` or its CRS has no length unit."""
    import rasterio
    from rasterio.enums import Resampling

    from aerotri.core.errors import CrsError
    from aerotri.geom.crs.definition import map_axes_unit_m
    from ortho.points_dem import EXTRAPOLATED_PERCENT_TAG

    path = Path(path)
    with rasterio.open(path) as ds:
        try:
            ux, uy, uz = map_axes_unit_m(ds.crs, str(path)) if ds.crs else (1.0, 1.0, 1.0)
        except CrsError:
            return None
        cell_m = max(abs(ds.transform.a) * ux, abs(ds.transform.e) * uy)
        f = max(1.0, CELL_M / cell_m, max(ds.width, ds.height) / MAX_SIDE_PX)
        shape = (max(1, round(ds.height / f)), max(1, round(ds.width / f)))
        z = ds.read(1, masked=True, out_shape=shape, resampling=Resampling.average).astype(float).filled(np.nan)
        try:
            extrapolated = float(ds.tags().get(EXTRAPOLATED_PERCENT_TAG))
        except (TypeError, ValueError):
            extrapolated = None
        dx_m = abs(ds.transform.a) * ux * ds.width / shape[1]
        dy_m = abs(ds.transform.e) * uy * ds.height / shape[0]
    if z.shape[0] < 3 or z.shape[1] < 3:
        return None
    gy, gx = np.gradient(z * uz, dy_m, dx_m)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    slope = slope[np.isfinite(slope)]
    if slope.size < 9:
        return None
    med = float(np.median(slope))
    return DemTerrain(class_of_slope(med), med, max(dx_m, dy_m), path, extrapolated)
