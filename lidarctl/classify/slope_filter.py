"""Slope-based ground filter (Vosselman 2000, "Slope based filtering of laser altimetry data", IAPRS 33(B3)).

A point is ground when no other point within ``radius_m`` lies lower than it by more than the height difference
the terrain may have over their distance: ``z_p - z_q <= max_slope * d(p, q) + tolerance_m`` for every q. The test
is a grey-scale erosion of the surface with a cone (Vosselman's own formulation): here of the raster of lowest
points (``cell_m``), by repeated 3 x 3 erosions whose weights are ``max_slope`` times the chamfer distance between
cells (at most 8 % longer than the straight one, so the cone is a little more permissive), ``radius_m / cell_m``
times. A point is compared with the erosion at its cell's centre plus ``max_slope`` times a cell diagonal: two
points lie at most that much closer than their cells' centres, so the raster never rejects a point the test on
the points themselves would keep (it keeps objects up to ``tolerance_m + 1.41 * max_slope * cell_m`` high, 0.72 m
at the defaults, where the point test would keep 0.3 m).

What it does not do: steep terrain beyond ``max_slope`` loses its upper side; roof points farther than
``radius_m`` from any lower point, or farther than (roof height - tolerance) / ``max_slope`` from it (24 m for an
8 m roof at the defaults), stay ground. The defaults are Vosselman's kind of values for
open and built-up land (17 degrees, a 20 m reach for roofs up to 40 m wide, 0.3 m for noise and the cell), not
fitted to the reference samples.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from aerotri.core.settings import setting


@dataclasses.dataclass(frozen=True)
class SlopeSettings:
    """Parameters of the slope-based filter (lengths in metres)."""

    cell_m: float = setting(1.0, min=0.05, help="Cell of the lowest-point raster the cone erodes.")
    radius_m: float = setting(20.0, min=0.0, min_open=True, help="How far a lower point is looked for (half the "
                              "widest building that must not stay ground).")
    max_slope: float = setting(0.3, min=0.0, min_open=True, help="Tangent of the steepest terrain kept as ground.")
    tolerance_m: float = setting(0.3, min=0.0, help="Height allowed above the cone: noise and the cell's size.")


def slope_reach_m(p: SlopeSettings) -> float:
    """How far (m) the filter looks from a point: the cone's radius and one cell."""
    return p.radius_m + p.cell_m


def slope_ground(x, y, z, params: SlopeSettings | None = None) -> np.ndarray:
    """Ground mask (bool per point) of points x, y, z (metres)."""
    p = params or SlopeSettings()
    x, y, z = (np.asarray(a, dtype=np.float64) for a in (x, y, z))
    if len(z) == 0:
        return np.zeros(0, dtype=bool)
    col = ((x - x.min()) / p.cell_m).astype(np.int64)
    row = ((y - y.min()) / p.cell_m).astype(np.int64)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    big = float(z.max()) + p.max_slope * (p.radius_m + math.hypot(*shape) * p.cell_m) + 1.0  # an empty cell
    lowest = np.full(shape, big)
    np.minimum.at(lowest, (row, col), z)
    step = p.max_slope * p.cell_m
    weights = -step * np.array([[math.sqrt(2.0), 1.0, math.sqrt(2.0)], [1.0, 0.0, 1.0],
                                [math.sqrt(2.0), 1.0, math.sqrt(2.0)]])
    cone = lowest
    for _ in range(max(1, int(round(p.radius_m / p.cell_m)))):
        # erosion subtracts the structure: min over the 3 x 3 of (cone + step * distance)
        cone = ndimage.grey_erosion(cone, footprint=np.ones((3, 3), bool), structure=weights, mode="nearest")
    return z <= cone[row, col] + p.tolerance_m + p.max_slope * math.sqrt(2.0) * p.cell_m
