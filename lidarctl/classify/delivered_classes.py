"""Vendor-classified LiDAR: keep the delivered ASPRS classes, after checking that they are a classification the
chain can use.

Checked, streaming the file chunk by chunk over a grid of ``CELL_M`` cells (memory set by the block's
extent over the cell, not by the number of points):

- the file is classified: some points are not in class 0 (never classified) or 1 (unclassified);
- ground (class 2) is present: at least ``MIN_GROUND_SHARE`` of the points and in at least
  ``MIN_GROUND_CELLS`` of the cells that hold points (the DEM is interpolated between);
- ground is the lowest surface: in at most ``MAX_BELOW_GROUND_CELLS`` of the cells with ground does a
  point of another class (noise 7 and 18 excepted; records flagged withheld are not read) lie more than ``BELOW_GROUND_M``
  below the cell's lowest ground point (a shifted, inverted or wrongly numbered ground class fails here);
- building (class 6): without it the roof-corner control finds nothing (a warning: rural blocks have
  none); with it, its points stand on average at least ``MIN_BUILDING_HEIGHT_M`` above their cell's
  lowest ground (class 6 used for something else fails).

Coordinates in metres (the file's CRS gives its units; ``lidarctl.units``).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from aerotri.core.errors import InputError
from aerotri.geom import las
from aerotri.core.limits import check_allocation
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)

GROUND, BUILDING = 2, 6
NOISE = (7, 18)
CELL_M = 20.0
MIN_GROUND_SHARE = 0.01
MIN_GROUND_CELLS = 0.5
BELOW_GROUND_M = 2.0
MAX_BELOW_GROUND_CELLS = 0.05
MIN_BUILDING_HEIGHT_M = 1.5


@dataclasses.dataclass
class DeliveredClasses:
    """What the check found: class counts and the shares it judged."""

    n_points: int
    class_counts: dict  # ASPRS class -> points
    ground_share: float
    ground_cell_share: float  # of the cells holding points
    below_ground_cell_share: float  # of the cells with ground
    building_height_m: float | None  # mean height of class 6 above its cell's lowest ground
    warnings: list


def check_delivered_classes(path, units: LengthUnits, chunk_points: int = 2_000_000) -> DeliveredClasses:
    """Check the classes of a LAS/LAZ file (see the module docstring); InputError naming the file and what
    is wrong, else the findings (warnings logged)."""
    header = las.read_header(path)
    n = int(header.point_count)
    x0, y0 = float(units.xy_to_m(header.mins[0])), float(units.xy_to_m(header.mins[1]))
    ncol = int((units.xy_to_m(header.maxs[0]) - x0) // CELL_M) + 1
    nrow = int((units.xy_to_m(header.maxs[1]) - y0) // CELL_M) + 1
    check_allocation(nrow * ncol * 8 * 5, f"{path}: the class check's {CELL_M:g} m grid")
    cells = nrow * ncol
    counts = np.zeros(256, dtype=np.int64)
    occupied = np.zeros(cells, dtype=bool)
    ground_min = np.full(cells, np.inf)
    other_min = np.full(cells, np.inf)
    for _, chunk in las.iter_file_chunks(path, chunk_points):
        c = np.asarray(chunk.classification, dtype=np.uint8)
        cell, z = _cells(chunk, units, x0, y0, ncol, cells)
        counts += np.bincount(c, minlength=256)
        occupied[cell] = True
        g = c == GROUND
        np.minimum.at(ground_min, cell[g], z[g])
        o = ~g & ~np.isin(c, NOISE)
        np.minimum.at(other_min, cell[o], z[o])
    if counts[2:].sum() == 0:
        raise InputError(f"{path}: the points carry no classes (all class 0 or 1): it is not classified; "
                         "classify it (drop the option to keep the delivered classes)")
    n = int(counts.sum())  # the points used (records flagged withheld are left out by the reader)
    ground_share = float(counts[GROUND] / n)
    has_ground = np.isfinite(ground_min)
    ground_cells = float(has_ground.sum() / max(occupied.sum(), 1))
    if ground_share < MIN_GROUND_SHARE or ground_cells < MIN_GROUND_CELLS:
        raise InputError(f"{path}: the delivered ground class (2) holds {ground_share:.1%} of the points and covers "
                         f"{ground_cells:.0%} of the {CELL_M:g} m cells (expected at least {MIN_GROUND_SHARE:.0%} and "
                         f"{MIN_GROUND_CELLS:.0%}); classify the file instead of keeping its classes")
    below = has_ground & (other_min < ground_min - BELOW_GROUND_M)
    below_share = float(below.sum() / has_ground.sum())
    if below_share > MAX_BELOW_GROUND_CELLS:
        k = int(np.flatnonzero(below)[0])
        xe, yn = x0 + (k % ncol + 0.5) * CELL_M, y0 + (k // ncol + 0.5) * CELL_M
        raise InputError(f"{path}: the delivered ground class (2) is not the lowest surface: in {below_share:.0%} of "
                         f"the {CELL_M:g} m cells with ground other points lie more than {BELOW_GROUND_M:g} m below it "
                         f"(first near E {units.xy_from_m(xe):.0f} N {units.xy_from_m(yn):.0f}); classify the file "
                         "instead of keeping its classes")
    warnings = []
    building_h = None
    if counts[BUILDING] == 0:
        warnings.append(f"{path}: no building class (6): the roof-corner control will find no roofs")
    else:
        building_h = _building_height(path, units, chunk_points, ground_min, x0, y0, ncol=ncol, cells=cells)
        if building_h < MIN_BUILDING_HEIGHT_M:
            raise InputError(f"{path}: the delivered building class (6) stands {building_h:.1f} m above the ground on "
                             f"average (expected at least {MIN_BUILDING_HEIGHT_M:g} m): it does not hold buildings; "
                             "classify the file instead of keeping its classes")
    for w in warnings:
        log.warning(w)
    return DeliveredClasses(n, {int(k): int(counts[k]) for k in np.flatnonzero(counts)}, ground_share, ground_cells,
                            below_share, building_h, warnings)


def _cells(chunk, units: LengthUnits, x0: float, y0: float, ncol: int, cells: int, *, mask=None):
    """(cell index, height in metres) of a chunk's points (those of ``mask``) on the ``CELL_M`` grid."""
    x, y, z = (np.asarray(v) if mask is None else np.asarray(v)[mask] for v in (chunk.x, chunk.y, chunk.z))
    x, y, z = units.xy_to_m(x), units.xy_to_m(y), units.z_to_m(z)
    cell = ((y - y0) // CELL_M).astype(np.int64) * ncol + ((x - x0) // CELL_M).astype(np.int64)
    return cell.clip(0, cells - 1), z


def _building_height(path, units, chunk_points, ground_min, x0, y0, *, ncol, cells) -> float:
    """Mean height (m) of the class 6 points above their cell's lowest ground (cells with ground)."""
    total, count = 0.0, 0
    for _, chunk in las.iter_file_chunks(path, chunk_points):
        b = np.asarray(chunk.classification, dtype=np.uint8) == BUILDING
        if not b.any():
            continue
        cell, z = _cells(chunk, units, x0, y0, ncol, cells, mask=b)
        h = z - ground_min[cell]
        ok = np.isfinite(h)
        total += float(h[ok].sum())
        count += int(ok.sum())
    return total / count if count else float("nan")
