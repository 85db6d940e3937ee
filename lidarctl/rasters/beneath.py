"""Building returns beneath a roof (wall returns, returns under the eaves) lifted to the roof above them for the DSMs.

A pulse that passes a roof's edge at a scan angle goes on to the wall below it: under an eave it lands beneath the
roof, on a plain wall it lands on the wall's line; either way a first return at a height between the ground and the
roof, where the surface seen from above is the roof (the eave). The highest first return per cell (dsm.tif) and the
first return nearest a cell's centre (dsm_nearest.tif) then put a strip at the roof's edge metres below it: on the
tall block's LiDAR (20-40 m buildings, eaves of 0.3-0.8 m, a return per 1.3 m2) a quarter of the roof cells 0.5-1 m
inside the roof outline lay more than 1 m below the roof, and a true ortho rectified on it (points under their own
roof, every frame) left 40 % of the roofs' outer metre nodata (trial s105 F1; docs/true-ortho.md "Wall returns").

A building return (class 6) more than ``BENEATH_DZ_M`` below the highest building return of the cells whose centres
lie within ``BENEATH_RADIUS_M`` of its cell's centre takes that height: the surface above it. Ground, vegetation and
other classes are never lifted (ground beside a wall stays where it is: the step stays at the wall); a roof step
of less than ``BENEATH_DZ_M`` within the radius (a pitched roof, a parapet, a rooftop unit) is left. Grids: rows and
columns of a window as ``cells.CellStats`` has them (rows south to north from the window's first cell).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from lidarctl.rasters.cells import BUILDING

# about the LiDAR's point spacing (0.75-1.1 m in the simulator's strips) and the widest eave (0.8 m): a wall return
# has a roof return within it. Not fitted to a block.
BENEATH_RADIUS_M = 1.0
# the height above the ground at which the seamlines and the nDSM's objects begin (``ortho.mosaic``'s
# object_height_m): a pitched roof of 45 deg rises less between two points of cells within the radius (at most
# 1.7 m apart on 0.5 m cells). Not fitted to a block.
BENEATH_DZ_M = 2.5


def roof_above(building_top: np.ndarray, res_m: float) -> np.ndarray:
    """The highest building return of the cells whose centres lie within ``BENEATH_RADIUS_M`` of each cell's centre
    (``building_top``: per cell, NaN for none; the same shape, NaN where none)."""
    r = max(1, int(math.floor(BENEATH_RADIUS_M / res_m + 1e-9)))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    disc = np.hypot(di, dj) * res_m <= BENEATH_RADIUS_M + 1e-9
    top = np.where(np.isnan(building_top), -np.inf, building_top)
    above = ndimage.maximum_filter(top, footprint=disc, mode="constant", cval=-np.inf)
    return np.where(np.isfinite(above), above, np.nan)


def lifted_cells(building_top: np.ndarray, above: np.ndarray) -> np.ndarray:
    """Per cell, the height its building returns beneath a roof are lifted to (``above``, ``roof_above``) where its
    highest building return lies more than ``BENEATH_DZ_M`` below it; NaN elsewhere."""
    with np.errstate(invalid="ignore"):
        return np.where(building_top < above - BENEATH_DZ_M, above, np.nan)


def lift_points(x, y, z, cls, above: np.ndarray, *, x0_m: float, y0_m: float, res_m: float, row0: int = 0,
                col0: int = 0) -> np.ndarray:
    """``z`` (metres) with every building return more than ``BENEATH_DZ_M`` below ``above`` at its cell lifted to
    it; ``above`` on the window of cells from (``row0``, ``col0``) of the grid with origin (``x0_m``, ``y0_m``),
    rows south to north; points off the window are left. A new array only where a point is lifted."""
    z = np.asarray(z)
    building = np.asarray(cls) == BUILDING
    if not building.any():
        return z
    k = np.flatnonzero(building)
    i = np.floor((np.asarray(y)[k] - y0_m) / res_m).astype(np.int64) - row0
    j = np.floor((np.asarray(x)[k] - x0_m) / res_m).astype(np.int64) - col0
    inside = (i >= 0) & (i < above.shape[0]) & (j >= 0) & (j < above.shape[1])
    k, i, j = k[inside], i[inside], j[inside]
    a = above[i, j]
    with np.errstate(invalid="ignore"):
        lift = z[k] < a - BENEATH_DZ_M
    if not lift.any():
        return z
    out = np.array(z, dtype=np.float64)
    out[k[lift]] = a[lift]
    return out
