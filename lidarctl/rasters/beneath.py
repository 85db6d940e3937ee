"""Building returns beneath a roof (wall returns, returns under the eaves) lifted to the roof above them for the DSMs.

A pulse that passes a roof's edge at a scan angle goes on to the wall below it: under an eave it lands beneath the
roof, on a plain wall it lands on the wall's line; either way a first return at a height between the ground and the
roof, where the surface seen from above is the roof (the eave). The highest first return per cell (dsm.tif) and the
first return nearest a cell's centre (dsm_nearest.tif) then put a strip at the roof's edge metres below it: on the
tall block's LiDAR (20-40 m buildings, eaves of 0.3-0.8 m, a return per 1.3 m2) a quarter of the roof cells 0.5-1 m
inside the roof outline lay more than 1 m below the roof, and a true ortho rectified on it (points under their own
roof, every frame) left 40 % of the roofs' outer metre nodata (trial s105 F1; docs/true-ortho.md "Wall returns").

A building return (class 6) that lies on a wall takes the height of the roof above it: more than ``BENEATH_DZ_M``
below the highest building return and more than ``BENEATH_DZ_M`` above the lowest return of any class among the
cells whose centres lie within ``BENEATH_RADIUS_M`` of its cell's centre (the roof above it, the ground or lower
roof at the wall's foot). A lower roof's returns beside a higher roof's wall have no lower return beside them and
stay (the step stays between the two roofs' returns: on AHN3 Delft a first rule without the lower test lifted rear
annexes a metre out from the main roofs' walls); ground, vegetation and other classes are never lifted; a roof
step of less than ``BENEATH_DZ_M`` within the radius (a pitched roof, a parapet, a rooftop unit) is left. Grids:
rows and columns of a window as ``cells.CellStats`` has them (rows south to north from the window's first cell).
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


def _disc(res_m: float) -> np.ndarray:
    """The cells whose centres lie within ``BENEATH_RADIUS_M`` of a cell's centre (itself at least)."""
    r = max(1, int(math.floor(BENEATH_RADIUS_M / res_m + 1e-9)))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    return np.hypot(di, dj) * res_m <= BENEATH_RADIUS_M + 1e-9


def wall_span(building_top: np.ndarray, bottom: np.ndarray, res_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(above, below): the highest building return and the lowest return of any class of the cells within
    ``BENEATH_RADIUS_M`` of each cell (``building_top``, ``bottom``: per cell, NaN for none; float32, NaN where
    none: a tile's window holds them through its second pass, and the DSMs are float32)."""
    disc = _disc(res_m)
    out = []
    for grid, filt, none in ((building_top, ndimage.maximum_filter, -np.inf), (bottom, ndimage.minimum_filter, np.inf)):
        g = np.asarray(grid, np.float32)
        g = np.where(np.isnan(g), np.float32(none), g)
        g = filt(g, footprint=disc, mode="constant", cval=none)
        g[~np.isfinite(g)] = np.nan
        out.append(g)
    return out[0], out[1]


def _on_wall(z, above, below):
    with np.errstate(invalid="ignore"):
        return (z < above - BENEATH_DZ_M) & (z > below + BENEATH_DZ_M)


def lifted_cells(building_top: np.ndarray, span: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Per cell, the height its highest building return is lifted to (``span``'s above, ``wall_span``) where that
    return lies on a wall; NaN elsewhere."""
    above, below = span
    return np.where(_on_wall(building_top, above, below), above, np.float32(np.nan))


def lift_points(x, y, z, cls, span: tuple[np.ndarray, np.ndarray], *, x0_m: float, y0_m: float, res_m: float,
                row0: int = 0, col0: int = 0) -> np.ndarray:
    """``z`` (metres) with every building return on a wall (``span``, ``wall_span``, at its cell) lifted to the roof
    above it; ``span`` on the window of cells from (``row0``, ``col0``) of the grid with origin (``x0_m``,
    ``y0_m``), rows south to north; points off the window are left. A new array only where a point is lifted."""
    above, below = span
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
    lift = _on_wall(z[k], a, below[i, j])
    if not lift.any():
        return z
    out = np.array(z, dtype=np.float64)
    out[k[lift]] = a[lift]
    return out
