"""Height-normalised clouds: heights above ground (lidR ``normalize_height``, PDAL ``hag_nn`` written to Z, LAStools
``lasheight -replace_z``) given where elevations are expected.

Such a cloud classifies and grids without an error, but its "DEM" is the ground at 0 and its contours, drainage and
spot heights mean nothing (new-user trial s94: lidR's MixedConifer made a DEM of 0.00-1.20 m, 1,077 contours at
0.1 m and 46 streams of Strahler order 2 on a flat plot, exit 0 and no word). The signature is the ground at height
0 everywhere: the lowest return of most 5 m cells lies within ``CELL_TOLERANCE_M`` of 0 and their median within
``MEDIAN_TOLERANCE_M``. Chosen on MixedConifer (0.948 of its cells, median +0.010 m), Topography normalised by its
delivered ground's TIN (0.822, 0.000 m; negative heights kept) and the simulator's scene normalised by its true
terrain (0.879, -0.065 m: ground noise, the lowest of some 50 returns a cell; low outliers 20 m below) against the
real clouds (AHN3 Delft, polder ground -0.6 to +1 m NAP: 0.473, +0.278 m; Topography, Nebraska, the 7 ISPRS
samples: 0.000): a warning, not a refusal, as flat land at its datum's zero can look the same.
"""

from __future__ import annotations

import logging

import laspy
import numpy as np

from aerotri.geom import las
from lidarctl import grid
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)

CELL_M = 5.0
CELL_TOLERANCE_M = 0.3
CELL_SHARE = 0.75
MEDIAN_TOLERANCE_M = 0.15
# only clouds whose lowest return lies this near 0 are read (below: noise under the ground of a normalised cloud)
LOWEST_RANGE_M = (-50.0, CELL_TOLERANCE_M)
SAMPLE_POINTS = 2_000_000
MIN_CELLS = 20


def normalised_heights_note(path, header: laspy.LasHeader, units: LengthUnits,
                            sample_points: int = SAMPLE_POINTS) -> str | None:
    """The warning for a cloud whose heights look normalised (see the module), else None. Reads nothing but the
    header unless the lowest return lies within ``LOWEST_RANGE_M`` of 0; then the first ``sample_points`` records."""
    lo_m = float(header.mins[2]) * units.z_m
    if not (LOWEST_RANGE_M[0] <= lo_m <= LOWEST_RANGE_M[1]) or header.point_count == 0:
        return None
    xs, ys, zs, n = [], [], [], 0
    with las.open_las(path) as reader:
        for _, chunk in las.iter_chunks(reader, path, min(sample_points, 1_000_000)):
            xs.append(np.asarray(chunk.x) * units.xy_m)
            ys.append(np.asarray(chunk.y) * units.xy_m)
            zs.append(np.asarray(chunk.z) * units.z_m)
            n += len(chunk)
            if n >= sample_points:
                break
    if n == 0:
        return None
    z = np.concatenate(zs)
    cells, *_ = grid.cell_ids(np.concatenate(xs), np.concatenate(ys), CELL_M)
    lowest = z[grid.lowest_per_cell(cells, z)]
    share = float(np.mean(np.abs(lowest) <= CELL_TOLERANCE_M))
    median = float(np.median(lowest))
    if len(lowest) < MIN_CELLS or share < CELL_SHARE or abs(median) > MEDIAN_TOLERANCE_M:
        return None
    return (f"{path}: its heights look normalised (heights above the ground, as lidR normalize_height writes them), "
            f"not elevations: the lowest return of {share:.0%} of its {CELL_M:g} m cells lies within "
            f"{CELL_TOLERANCE_M:g} m of height 0 (median {median:+.3f} m). A DEM of it is the ground at 0, not the "
            "terrain (its DSM is then the canopy height), and contours, drainage and spot heights of it mean "
            "nothing: give the cloud with its elevations (before normalisation)")


def warn_if_normalised(paths, crs=None) -> None:
    """Log ``normalised_heights_note`` of the first file of ``paths`` that has one (strips of one block share their
    heights' kind); ``crs``: the ``--crs`` of files without a CRS record."""
    from lidarctl import io

    for path in paths:
        header = las.read_header(path)
        _, units = io.resolve_crs_units(path, header, crs, require_crs=False)
        if not units.known:
            continue
        note = normalised_heights_note(path, header, units)
        if note:
            log.warning(note)
            return
