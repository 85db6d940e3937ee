"""Line-map (DLG) vector layers from a classified cloud: buildings, roads, water, spot heights, contours.

Layers of the GeoPackage (``write_vectors``), all in the cloud's CRS and its units (coordinates and
heights in CRS units, the ``_m`` attributes in metres):

* ``buildings`` (Polygon): regularised roof (eave) outlines of the building points (class 6), traced,
  regularised and edge-fitted as ``lidarctl corners`` does (``corners.find_roof_corners``);
  ``eave_z``: the median height of its corners (each the roof plane at the corner, as in ``corners``),
  without corners the most frequent height (``EAVE_BIN_M`` bins) of the roof points within
  ``max(1.5 m, 2 spacings)`` inside the outline; ``ridge_z``: the ``RIDGE_PERCENTILE`` of all roof points inside it; ``ground_z``: the median of
  the ground points up to 5 m outside it; ``height_m`` = ridge - ground; ``area_m2``, ``roof``.
  Building cells no regularised outline covers (roofs below the outliner's 25 m2, outlines that failed)
  are outlined from their cells (roof ``cells``; pieces of at least ``CELL_BUILDING_MIN_M2``, slivers
  along the regularised outlines removed by an opening of one cell); cells that returned no pulse inside a
  rim of building cells join them (``MapVectorSettings.roof_dropouts``).
* ``roads`` (Polygon): cells of ``cell_m`` holding road points (class 11, e.g. from ``classify --image``),
  closed over gaps of one cell, holes below ``min_area_m2`` filled, pieces below it dropped; the polygon
  edges are the road edges; ``width_m`` is the median width along its centre line.
* ``road_centrelines`` (LineString): the skeleton of the road cells (Zhang-Suen thinning), cut at
  junctions, spurs (a free end, shorter than twice the road width) dropped, merged through junctions
  that are left with two lines, simplified by ``simplify_m``; ``width_m`` = 2 x the median distance
  from the centre line to the road edge (within half a cell), ``length_m``.
* ``water`` (Polygon): cells of water points (class 9) as for roads, with the cells without returns they border
  (water mirrors the pulse away); a gap that runs out of the data's footprint joins by the water rule
  (``lakes_at_edge``: its rim in a bed at the water's level), not by its shape; ``water_z`` the median height of
  its water returns (a polygon without any is no water feature: never a NaN height), ``water_z_range_m`` their 5th
  to 95th percentile range in metres (a lake: centimetres; a river falling along its course: more;
  ``lidarctl hydro-flatten`` leaves such a body as it is).
* ``spot_heights`` (Point): one per ``spot_spacing_m`` square, at the ground cell of the square with the
  flattest neighbourhood (smallest RMS of a plane over 3 x 3 cells) that is at least ``BREAKLINE_CLEAR_M``
  from any cell that is not open ground (buildings, water, trees, data gaps) - off breaklines; open
  ground is ground, road surface and low vegetation (2, 11, 3: fused classifications label grass 3);
  ``z`` the mean of those points in the cell.
* ``contours`` (LineString): copied from ``--contours`` or traced from ``--dem`` (``lidarctl.terrain.contours``).
* ``coverage`` (Polygon): where the map was made from returns: the cells with points, gaps of about two point
  spacings closed, and the water polygons; ``lidarctl check-vectors`` judges a reference only inside it.

Cells and lengths of the parameters are metres whatever the CRS; points are read with
``corners.read_strips`` (metres) and written back in the CRS units.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from aerotri.core.settings import setting
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.figures import pyplot, save_png
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

GROUND, BUILDING, WATER, ROAD = 2, 6, 9, 11
NOISE = (7, 18)
OPEN_GROUND = (GROUND, 3, ROAD)
EAVE_BIN_M = 0.25
RIDGE_PERCENTILE = 99.0
BREAKLINE_CLEAR_M = 3.0
# Building cells outlined when no regularised outline covers them: pieces from this area (m2; a garden shed
# is 5-8 m2 in the BGT of Delft).
CELL_BUILDING_MIN_M2 = 4.0
LAYERS = ("buildings", "roads", "road_centrelines", "water", "spot_heights", "contours", "coverage")
VECTORS_VERSION = 3  # (3: outlines without overlaps) the chain's vectors stage stamp: bump when the line map changes at the same inputs


@dataclasses.dataclass(frozen=True)
class MapVectorSettings:
    """Cell size of the road/water masks, smallest polygon, simplification, spot-height spacing (metres)."""

    cell_m: float = setting(1.0, min=0.0, min_open=True, help="Cell of the road and water masks (m); about the point "
                                                              "spacing or larger.")
    min_area_m2: float = setting(50.0, min=0.0, min_open=True, help="Road and water pieces (and holes in them) smaller "
                                                                    "than this (m2) are dropped (filled).")
    simplify_m: float = setting(0.5, min=0.0, min_open=True, help="Douglas-Peucker tolerance of road/water polygons and "
                                                                  "centre lines (m).")
    spot_spacing_m: float = setting(100.0, min=0.0, min_open=True, help="One spot height per square of this side (m).")
    contour_interval_m: float = setting(1.0, min=0.0, min_open=True, help="--dem: contour interval (m).")
    roof_dropouts: bool = setting(True, help="Empty regions rimmed mostly by building cells join the buildings (a roof "
                                             "that returned no pulse).")


@dataclasses.dataclass
class Layer:
    """One layer: shapely geometries (CRS units) and attribute columns (equal lengths)."""

    name: str
    geometry_type: str
    geometries: list
    fields: dict


@dataclasses.dataclass(frozen=True)
class VectorCounts:
    """Features per layer of the line map; ``roof_spacing_m``: the roof points' mean spacing (m; None without
    buildings); ``contours``: None when no contour layer was made (neither --dem nor --contours); ``road_points``:
    the clouds' road returns (class 11; 0 unless classified with an orthophoto, ``classify --image``)."""

    buildings: int
    roof_spacing_m: float | None
    roads: int
    road_centrelines: int
    water: int
    spot_heights: int
    contours: int | None = None
    road_points: int | None = None


@dataclasses.dataclass
class MapVectors:
    layers: list
    crs: object  # pyproj CRS
    units: object  # lidarctl.units.LengthUnits
    stats: VectorCounts
    extent: tuple[float, float, float, float] | None = None  # the points' xmin, ymin, xmax, ymax (CRS units)


@dataclasses.dataclass(frozen=True)
class VectorsResult:
    """What ``vectors_to_file`` wrote: the features per layer, the units of the coordinates and the files (the
    GeoPackage, then the preview PNG when made)."""

    counts: VectorCounts
    units: LengthUnits
    files: tuple[str, ...]


# ------------------------------------------------------------------------------------------------ masks
def _grid(xy: np.ndarray, cell_m: float, pad: int = 2):
    """Origin (x0 at the west, y0 at the north edge) and shape of a grid of ``cell_m`` over ``xy``."""
    x0 = np.floor(xy[:, 0].min() / cell_m) * cell_m - pad * cell_m
    y0 = np.ceil(xy[:, 1].max() / cell_m) * cell_m + pad * cell_m
    ncols = int(np.ceil((xy[:, 0].max() - x0) / cell_m)) + pad + 1
    nrows = int(np.ceil((y0 - xy[:, 1].min()) / cell_m)) + pad + 1
    return x0, y0, nrows, ncols


def _cells(xy, x0, y0, cell_m, shape):
    col = np.clip(((xy[:, 0] - x0) / cell_m).astype(np.int64), 0, shape[1] - 1)
    row = np.clip(((y0 - xy[:, 1]) / cell_m).astype(np.int64), 0, shape[0] - 1)
    return row, col


def class_mask(xy: np.ndarray, x0, y0, cell_m: float, shape, *, min_area_m2: float, close_cells: int = 1,
               void: np.ndarray | None = None, join: np.ndarray | None = None) -> np.ndarray:
    """Cells holding points ``xy`` (m), closed over gaps of ``close_cells``, small holes filled, small pieces
    dropped. ``void``: cells without any return; the void regions that touch the class's cells (and not the
    grid's border) join it - water gives few returns. ``join``: more cells that join (``lakes_at_edge``)."""
    from scipy import ndimage

    eight = np.ones((3, 3), bool)
    m = np.zeros(shape, bool)
    if len(xy):
        r, c = _cells(xy, x0, y0, cell_m, shape)
        m[r, c] = True
    if void is not None and m.any():
        lab, n = ndimage.label(void, structure=eight)
        touch = np.unique(lab[ndimage.binary_dilation(m, structure=eight) & void])
        border = np.unique(np.r_[lab[0], lab[-1], lab[:, 0], lab[:, -1]])
        joins = np.zeros(n + 1, bool)
        joins[touch] = True
        joins[border] = False
        joins[0] = False
        m |= joins[lab]
    if join is not None:
        m |= join
    if close_cells > 0:
        m = ndimage.binary_closing(np.pad(m, close_cells), structure=eight,
                                   iterations=close_cells)[close_cells:-close_cells, close_cells:-close_cells]
    min_cells = max(1, int(round(min_area_m2 / cell_m**2)))
    holes, n = ndimage.label(~m)
    if n:
        size = np.bincount(holes.ravel())
        border = np.unique(np.r_[holes[0], holes[-1], holes[:, 0], holes[:, -1]])
        small = size < min_cells
        small[0] = False
        small[border] = False
        m |= small[holes]
    lab, n = ndimage.label(m, structure=eight)
    if n:
        size = np.bincount(lab.ravel())
        keep = size >= min_cells
        keep[0] = False
        m = keep[lab]
    return m


# rim cells holding water whose heights give the level beside a bank cell (``lakes_at_edge``): a few metres of
# shore at the mask's cell, enough for a median over single cells' noise, short against a river's fall
LOCAL_LEVEL_CELLS = 8


def lakes_at_edge(void: np.ndarray, occupied: np.ndarray, row: np.ndarray, col: np.ndarray, z: np.ndarray,
                  water: np.ndarray, *, tol_m: float, bank_fraction: float) -> np.ndarray:
    """Cells of the lakes that run out of the data: void regions (no return) inside the data's footprint (the
    convex hull of the cells with returns) that reach its edge - so ``class_mask`` cannot tell them from the
    outside - and hold water by the water rule of ``classify.level_water``: they border water returns, and the
    returns on their rim lie in a bed at the water's level (at least ``bank_fraction`` of the rim cells' lowest
    returns other than water no more than ``tol_m`` below the level beside them; water cannot stand above the ground
    beside it). The level beside a rim cell is the median of the water heights (each cell's median) of its
    ``LOCAL_LEVEL_CELLS`` nearest rim cells holding water, so a river falling along its course keeps its banks (one
    level for the whole rim put Autzen's downstream banks below the upstream water). The outside of an irregular footprint is rimmed by whatever the
    survey's edge crosses, ground below a lake's level included. ``row``, ``col``, ``z``, ``water``: cell,
    height (m) and water flag of each return."""
    from rasterio import features
    from scipy import ndimage
    from scipy.spatial import ConvexHull, QhullError, cKDTree
    import shapely

    out = np.zeros(void.shape, bool)
    if not water.any():
        return out
    occ_r, occ_c = np.nonzero(occupied)
    corners = np.column_stack([np.r_[occ_c, occ_c + 1, occ_c, occ_c + 1], np.r_[occ_r, occ_r, occ_r + 1, occ_r + 1]])
    try:
        hull = ConvexHull(np.unique(corners, axis=0))
    except (QhullError, ValueError):  # data in one row or column: no area to hold a lake
        return out
    footprint = features.rasterize([shapely.Polygon(hull.points[hull.vertices])], out_shape=void.shape,
                                   dtype=np.uint8).astype(bool)
    eight = np.ones((3, 3), bool)
    outside = np.pad(~footprint, 1, constant_values=True)
    at_edge = ndimage.binary_dilation(outside, structure=eight)[1:-1, 1:-1]
    lab, n = ndimage.label(void & footprint, structure=eight)
    if n == 0:
        return out
    edge_ids = np.unique(lab[at_edge & (lab > 0)])
    ncols = void.shape[1]
    flat = row * ncols + col
    # the lowest return of each cell but the water's (the bank), and the water returns' heights by cell
    land = ~water
    order = np.lexsort((z[land], flat[land]))
    lf, lz = flat[land][order], z[land][order]
    first = np.r_[True, lf[1:] != lf[:-1]] if len(lf) else np.zeros(0, bool)
    zmin = np.full(void.size, np.nan)
    zmin[lf[first]] = lz[first]
    wflat, wz = flat[water], z[water]
    water_cells = np.zeros(void.size, bool)
    water_cells[wflat] = True
    water_cells = water_cells.reshape(void.shape)
    # each water cell's median height (cells in ascending order, ``cell_level`` aligned with ``level_cells``)
    order = np.lexsort((wz, wflat))
    sf, sz = wflat[order], wz[order]
    level_cells, starts, counts = np.unique(sf, return_index=True, return_counts=True)
    cell_level = 0.5 * (sz[starts + (counts - 1) // 2] + sz[starts + counts // 2])
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        if k not in edge_ids:
            continue
        # the region's window, one cell wider each side
        r0, r1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, void.shape[0])
        c0, c1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, void.shape[1])
        region = lab[r0:r1, c0:c1] == k
        rim = ndimage.binary_dilation(region, structure=eight) & ~region & occupied[r0:r1, c0:c1]
        if not (rim & water_cells[r0:r1, c0:c1]).any():
            continue
        rr, cc = np.nonzero(rim)
        rim_flat = (rr + r0) * ncols + (cc + c0)
        wet = water_cells.ravel()[rim_flat]
        wet_level = cell_level[np.searchsorted(level_cells, rim_flat[wet])]
        bank = zmin[rim_flat]
        has_bank = np.isfinite(bank)
        if has_bank.any():
            k_near = min(LOCAL_LEVEL_CELLS, int(wet.sum()))
            _, near = cKDTree(np.column_stack([rr[wet], cc[wet]])).query(
                np.column_stack([rr[has_bank], cc[has_bank]]), k=k_near)
            level = np.median(wet_level[near.reshape(int(has_bank.sum()), k_near)], axis=1)
            bed = float(np.mean(bank[has_bank] >= level - tol_m))
        else:
            bed = 1.0
        log.debug("void of %d cells at the data's edge, rim of %d cells: water %.3f-%.3f m, %.0f %% of the rim in "
                  "its bed: %s", region.sum(), len(rim_flat), wet_level.min(), wet_level.max(), 100 * bed,
                  bed >= bank_fraction)
        if bed >= bank_fraction:
            out[r0:r1, c0:c1] |= region
    return out


def without_pinches(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every diagonal-only contact of two cells (a 2 x 2 window holding True on one diagonal, False on
    the other) bridged by one cell. A piece joined through a corner is one piece to ``class_mask`` (eight
    neighbours) but an invalid ring to GIS: made valid it falls apart into parts below the layer's minimum area
    (Autzen's river: 7 pieces of 53 m2 and more came out as 19 polygons, ten of 1-17 m2)."""
    m = mask.copy()
    while True:
        a, b, c, d = m[:-1, :-1], m[:-1, 1:], m[1:, :-1], m[1:, 1:]
        main_diagonal = a & d & ~b & ~c
        anti_diagonal = b & c & ~a & ~d
        if not (main_diagonal.any() or anti_diagonal.any()):
            return m
        m[:-1, 1:] |= main_diagonal
        m[:-1, :-1] |= anti_diagonal


def mask_polygons(mask: np.ndarray, x0, y0, cell_m: float, simplify_m: float) -> list:
    """Polygons (metres) of the True cells of ``mask``, simplified by ``simplify_m``."""
    import shapely
    from rasterio import features
    from rasterio.transform import Affine
    from shapely.geometry import shape

    if not mask.any():
        return []
    tr = Affine(cell_m, 0.0, x0, 0.0, -cell_m, y0)
    polys = [shape(g) for g, v in features.shapes(mask.astype(np.uint8), mask=mask, transform=tr, connectivity=8)]
    out = []
    for p in polys:
        q = shapely.make_valid(p.simplify(simplify_m, preserve_topology=True))
        parts = [g for g in getattr(q, "geoms", [q]) if g.geom_type == "Polygon" and not g.is_empty]
        out += parts
    return out


def _crossing_number(sk: np.ndarray) -> np.ndarray:
    """Branches meeting at each pixel of a skeleton: the 0 -> 1 transitions around its 8 neighbours (a staircase
    pixel has two, like a straight one; an end one; a junction three or more)."""
    p = np.pad(sk, 1).astype(np.int8)
    h, w = sk.shape
    ring = [(0, 1), (0, 2), (1, 2), (2, 2), (2, 1), (2, 0), (1, 0), (0, 0)]  # clockwise from north
    nbrs = [p[r:r + h, c:c + w] for r, c in ring]
    return sum(((nbrs[i] == 0) & (nbrs[(i + 1) % 8] == 1)).astype(np.int8) for i in range(8))


def _skeleton_paths(skel: np.ndarray) -> list:
    """(path as (K, 2) float (row, col), free ends, starts at a junction, ends at one) of a one-pixel skeleton cut at its junctions: each path runs
    between junctions (ending at the centre of the junction's pixels) or free ends (``free ends``: how many of
    its two ends are no junction)."""
    from scipy import ndimage

    sk = skel.astype(bool)
    eight = np.ones((3, 3), bool)
    junction = sk & (_crossing_number(sk) >= 3)
    jlab, nj = ndimage.label(junction, structure=eight)
    jcentre = np.array(ndimage.center_of_mass(junction, jlab, range(1, nj + 1))).reshape(-1, 2)
    # the arms' first pixels touch each other diagonally around a junction: cut them off with it
    runs, n = ndimage.label(sk & ~ndimage.binary_dilation(junction, structure=eight), structure=eight)
    offsets = [(-1, 0), (0, -1), (0, 1), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)]  # 4-neighbours first
    paths = []
    # a walk per run of skeleton pixels: the skeleton is thin (a few pixels per metre of road), not per point
    for k, sl in enumerate(ndimage.find_objects(runs), start=1):
        rr, cc = np.nonzero(runs[sl] == k)
        pix = set(zip((rr + sl[0].start).tolist(), (cc + sl[1].start).tolist()))
        remaining = set(pix)
        # a run with an undetected branch needs more than one walk: walk until every pixel is on a path
        while remaining:
            start = next((q for q in sorted(remaining)
                          if sum((q[0] + a, q[1] + b) in remaining for a, b in offsets) <= 1), min(remaining))
            path = [start]
            remaining.discard(start)
            while True:
                q = path[-1]
                nxt = [(q[0] + a, q[1] + b) for a, b in offsets if (q[0] + a, q[1] + b) in remaining]
                if not nxt:
                    break
                path.append(nxt[0])
                remaining.discard(nxt[0])
            on_path = set(path)
            rc = np.array(path, float)
            free, ends = 0, []
            for end in (path[0], path[-1]):
                r0, c0 = end
                win = jlab[max(r0 - 2, 0):r0 + 3, max(c0 - 2, 0):c0 + 3]
                ids = np.unique(win[win > 0])
                other = [(r0 + a, c0 + b) for a, b in offsets if (r0 + a, c0 + b) in pix and (r0 + a, c0 + b) not in on_path]
                if len(ids):
                    ends.append(jcentre[ids[0] - 1])  # the line reaches the junction's centre, so lines meet there
                elif other:
                    ends.append(np.array(other[0], float))  # a branch of the same run
                else:
                    ends.append(None)
                    free += 1
            if ends[0] is not None:
                rc = np.vstack([ends[0], rc])
            if ends[1] is not None and not (len(path) == 1 and ends[0] is not None
                                            and np.array_equal(ends[0], ends[1])):
                rc = np.vstack([rc, ends[1]])
            paths.append((rc, free, ends[0] is not None, ends[1] is not None))
    return paths


def centrelines(mask: np.ndarray, x0, y0, cell_m: float, simplify_m: float) -> list:
    """(LineString in metres, width_m) of the centre lines of the road cells ``mask``: the thinned mask cut at
    junctions, spurs (a free end, shorter than twice the road width) dropped, the rest merged and simplified."""
    import cv2
    import shapely
    from scipy import ndimage

    if not mask.any():
        return []
    padded = np.pad(mask, 1)
    # Distance from a centre-line cell to the nearest cell outside the road: half the width plus half a cell
    # when the road is an odd number of cells wide, half the width when even (the line then runs along one of
    # the two middle cells); -0.25 cell is the mean of the two, so widths are within half a cell.
    half = ndimage.distance_transform_edt(padded)[1:-1, 1:-1] * cell_m - 0.25 * cell_m
    # a rounded mask thins with fewer spurs from its ragged edges
    smooth = ndimage.binary_opening(padded, structure=np.ones((3, 3), bool), iterations=1)
    skel = cv2.ximgproc.thinning(smooth.astype(np.uint8) * 255, thinningType=cv2.ximgproc.THINNING_ZHANGSUEN) > 0
    skel = skel[1:-1, 1:-1]
    pieces = []
    for _ in range(3):  # dropping spurs makes new free ends (spurs of spurs): prune a few times
        pieces, dropped = [], 0
        for rc, free, j0, j1 in _skeleton_paths(skel):
            ij = np.round(rc).astype(np.int64)
            width = float(2.0 * np.median(half[ij[:, 0], ij[:, 1]]))
            length = float(np.hypot(*np.diff(rc, axis=0).T).sum()) * cell_m
            if free and length < 2.0 * max(width, cell_m):
                inner = ij[int(j0):len(ij) - int(j1)]  # keep the junction a spur hangs from
                skel[inner[:, 0], inner[:, 1]] = False
                dropped += 1
                continue
            pieces.append((rc, width))
        if not dropped:
            break
        # junction pixels of dropped spurs may be left as stubs: re-thin
        skel = cv2.ximgproc.thinning(skel.astype(np.uint8) * 255) > 0
    lines, widths, lengths = [], [], []
    for rc, width in pieces:
        if len(rc) < 2:
            continue
        xy = np.column_stack([x0 + (rc[:, 1] + 0.5) * cell_m, y0 - (rc[:, 0] + 0.5) * cell_m])
        ln = shapely.LineString(xy)
        lines.append(ln)
        widths.append(width)
        lengths.append(ln.length)
    if not lines:
        return []
    merged = shapely.line_merge(shapely.MultiLineString(lines))
    tree = shapely.STRtree(lines)
    out = []
    for m in getattr(merged, "geoms", [merged]):
        # the width of a merged line: its pieces' widths weighted by length
        hit = [i for i in tree.query(m, predicate="intersects") if shapely.length(shapely.intersection(lines[i], m)) > 0]
        w = (float(np.average([widths[i] for i in hit], weights=[lengths[i] for i in hit])) if hit
             else float(np.median(widths)))
        out.append((m.simplify(simplify_m), w))
    return out


# --------------------------------------------------------------------------------------------- buildings
def _roof_dropouts(pts, bxy: np.ndarray, x0, y0, cell_m: float, shape) -> np.ndarray:
    """Cells of the grid (``_grid``) that returned no pulse and belong to a roof: the regions of empty cells
    (no return of any class; opened by one cell, 8-connected, off the grid's border) whose rim (the cells with returns around
    them) is mostly roof - more than half of it building cells and none water. A glass, wet or black roof
    returns few or no pulses and is then seen by its rim alone (AHN3 Delft: two 22 m2 BGT buildings); a
    shadow beside a wall has ground on its other sides, a dropout lake its shore or its water returns."""
    from lidarctl.raster_ops import rimmed_dropouts

    axy = np.column_stack([pts.x, pts.y])
    on = (axy[:, 0] >= x0) & (axy[:, 0] < x0 + shape[1] * cell_m) & (axy[:, 1] <= y0) & (axy[:, 1] > y0 - shape[0] * cell_m)
    occupied = np.zeros(shape, bool)
    occupied[_cells(axy[on], x0, y0, cell_m, shape)] = True
    building = np.zeros(shape, bool)
    building[_cells(bxy, x0, y0, cell_m, shape)] = True
    water = np.zeros(shape, bool)
    w = on & (pts.classification == WATER)
    water[_cells(axy[w], x0, y0, cell_m, shape)] = True
    return rimmed_dropouts(occupied, building, blocked=water)


def building_outlines(pts, spacing_m: float | None = None, roof_dropouts: bool = True) -> tuple[list, list, dict]:
    """(polygons in metres, attribute rows, stats) of the buildings of a cloud (``corners.ClassifiedStrips``, or
    any object with its x, y, z, classification and point_source_id arrays); ``roof_dropouts``: empty regions
    rimmed by roof join the building cells."""
    import shapely
    from shapely.geometry import Polygon

    from lidarctl.corners.roof_corners import find_roof_corners

    cls = pts.classification
    if not (cls == BUILDING).any():
        return [], [], {"n_roofs": 0}
    try:
        # min_edge_m as before the corner stage's density-adaptive default (issue 21): it sets the smallest
        # roof outlined (25 m^2) and the corners the eave heights come from; not re-evaluated for the line map
        res = find_roof_corners(pts.x, pts.y, pts.z, cls, pts.point_source_id, roof="any", min_edge_m=5.0)
    except InputError as exc:
        log.info(f"no building outlines: {exc}")
        return [], [], {"n_roofs": 0}
    is_b, is_g = cls == BUILDING, cls == GROUND
    bxy = np.column_stack([pts.x[is_b], pts.y[is_b]])
    bz = pts.z[is_b]
    gxy = np.column_stack([pts.x[is_g], pts.y[is_g]])
    gz = pts.z[is_g]
    from scipy.spatial import cKDTree

    btree = cKDTree(bxy)
    # eave height: the corners' heights, each the roof plane at the corner (corners.py)
    corner_z: dict = {}
    for c in res.corners:
        corner_z.setdefault(int(c["building_id"]), []).append(float(c["z"]))
    gtree = cKDTree(gxy) if len(gxy) else None
    polys, rows = [], []
    candidates = []
    for o in res.outlines:
        rings = [r for r in o["rings"] if len(r) >= 3]
        if not rings:
            continue
        rings.sort(key=lambda r: -abs(Polygon(r).area))
        shell = Polygon(rings[0])
        holes = [r for r in rings[1:] if shell.contains(Polygon(r).representative_point())]
        poly = shapely.make_valid(Polygon(rings[0], holes))
        if poly.geom_type != "Polygon":
            poly = max(getattr(poly, "geoms", [poly]), key=lambda g: g.area if g.geom_type == "Polygon" else -1)
        if poly.geom_type != "Polygon" or poly.area <= 0:
            continue
        candidates.append((poly, int(o["building_id"]), o["roof"], o["spacing_m"]))
    # Building points no regularised outline covers (roofs below the outliner's smallest, 25 m2, and
    # roofs whose outline failed): the outline of their cells, so that every classified building is on
    # the map (roof "cells": not regularised).
    spacing = float(np.median([cand[3] for cand in candidates])) if candidates else (spacing_m or 1.0)
    cell = max(0.5, spacing)
    x0, y0, nrows, ncols = _grid(bxy, cell)
    void = _roof_dropouts(pts, bxy, x0, y0, cell, (nrows, ncols)) if roof_dropouts else None
    bmask = class_mask(bxy, x0, y0, cell, (nrows, ncols), min_area_m2=CELL_BUILDING_MIN_M2, close_cells=1, void=void)
    candidates = _without_overlaps(candidates)
    covered = shapely.union_all([cand[0] for cand in candidates]) if candidates else None
    next_id = max([cand[1] for cand in candidates], default=0) + 1
    pieces = mask_polygons(bmask, x0, y0, cell, cell)
    if covered is not None and pieces:
        # what the outlines leave of the building cells, without the slivers along their edges (an opening
        # of one cell)
        rest = shapely.make_valid(shapely.union_all(pieces).difference(covered))
        rest = rest.buffer(-cell, join_style="mitre").buffer(cell, join_style="mitre").intersection(rest)
        pieces = [g for g in getattr(rest, "geoms", [rest]) if g.geom_type == "Polygon"]
    for q in pieces:
        if q.is_empty or q.area < CELL_BUILDING_MIN_M2:
            continue
        candidates.append((q, next_id, "cells", spacing))
        next_id += 1
    for poly, building_id, roof, spacing_o in candidates:
        # roof points inside the outline: those within the circumscribed circle, then tested
        c = np.asarray(poly.centroid.coords[0])
        rad = float(np.max(np.hypot(*(np.asarray(poly.exterior.coords) - c).T))) + 0.1
        idx = np.asarray(btree.query_ball_point(c, rad), np.int64)
        idx = idx[shapely.contains_xy(poly, bxy[idx, 0], bxy[idx, 1])] if len(idx) else idx
        if len(idx) < 3:
            continue
        cz = corner_z.get(building_id) if roof != "cells" else None
        if cz is not None:
            eave = float(np.median(cz))
        else:
            # no fitted corner: the most frequent height of the roof points near the outline (the eave rim is
            # level; wall points under it spread over the wall's height, gable ends over the gable's)
            band = max(1.5, 2.0 * spacing_o)
            near = idx[shapely.distance(poly.boundary, shapely.points(bxy[idx])) < band]
            zb = bz[near if len(near) >= 3 else idx]
            bins = np.floor((zb - zb.min()) / EAVE_BIN_M).astype(np.int64)
            top = np.bincount(bins).argmax()
            eave = float(np.median(zb[np.abs(bins - top) <= 1]))
        ridge = float(np.percentile(bz[idx], RIDGE_PERCENTILE))
        ground = float("nan")
        if gtree is not None:
            gi = np.asarray(gtree.query_ball_point(c, rad + 5.0), np.int64)
            if len(gi):
                ring = poly.buffer(5.0).difference(poly)
                gi = gi[shapely.contains_xy(ring, gxy[gi, 0], gxy[gi, 1])]
                if len(gi):
                    ground = float(np.median(gz[gi]))
        polys.append(poly)
        rows.append(dict(building_id=building_id, roof=roof, eave_z=eave, ridge_z=ridge,
                         ground_z=ground, height_m=ridge - ground, area_m2=float(poly.area),
                         n_points=int(len(idx))))
    return polys, rows, dataclasses.asdict(res.stats)


def _without_overlaps(candidates: list) -> list:
    """The regularised outlines (``(polygon, building_id, roof, spacing)``) without overlaps: outlines of neighbouring
    roofs, regularised one by one, overlap where the roofs touch (trial s94, AHN3 Delft: 2 pairs, by 1.0 and 3.1 m2,
    failing a GIS's "must not overlap" rule); the overlap stays with the larger outline, the smaller keeps its largest
    remaining part."""
    import shapely

    if len(candidates) < 2:
        return candidates
    polys = [c[0] for c in candidates]
    tree = shapely.STRtree(polys)
    order = sorted(range(len(polys)), key=lambda k: (-polys[k].area, k))
    rank = {k: r for r, k in enumerate(order)}
    out = list(polys)
    for k in order:
        larger = [j for j in tree.query(polys[k], predicate="intersects") if rank[j] < rank[k]]
        if not larger:
            continue
        rest = shapely.make_valid(polys[k].difference(shapely.union_all([out[j] for j in larger])))
        parts = [g for g in getattr(rest, "geoms", [rest]) if g.geom_type == "Polygon" and g.area > 0]
        out[k] = max(parts, key=lambda g: g.area) if parts else None
    return [(q, *c[1:]) for q, c in zip(out, candidates) if q is not None]


# ------------------------------------------------------------------------------------------- spot heights
def spot_heights(gxy: np.ndarray, gz: np.ndarray, other_xy: np.ndarray, cell_m: float, spacing_m: float):
    """(xy (K, 2), z (K,)) in metres: one spot height per ``spacing_m`` square (see the module doc)."""
    from scipy import ndimage

    from lidarctl.raster_ops import plane_rms

    if len(gxy) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    allxy = np.vstack([gxy, other_xy]) if len(other_xy) else gxy
    x0, y0, nrows, ncols = _grid(allxy, cell_m)
    shape = (nrows, ncols)
    r, c = _cells(gxy, x0, y0, cell_m, shape)
    flat = r * ncols + c
    cnt = np.bincount(flat, minlength=nrows * ncols).reshape(shape)
    zsum = np.bincount(flat, weights=gz, minlength=nrows * ncols).reshape(shape)
    zmean = np.where(cnt > 0, zsum / np.maximum(cnt, 1), np.nan)
    # cells of a sparse cloud without a point of their own are no breakline: close over them
    ground = ndimage.binary_closing(np.pad(cnt > 0, 1), structure=np.ones((3, 3), bool))[1:-1, 1:-1]
    if len(other_xy):
        ro, co = _cells(other_xy, x0, y0, cell_m, shape)
        occupied_other = np.zeros(shape, bool)
        occupied_other[ro, co] = True
        ground &= ~occupied_other  # a cell with a roof, tree or water point over it is no open ground
    clear = ndimage.distance_transform_edt(np.pad(ground, 1))[1:-1, 1:-1] * cell_m > BREAKLINE_CLEAR_M
    rough = plane_rms(np.where(np.isfinite(zmean), zmean, np.nanmedian(zmean)), cell_m)
    ok = clear & np.isfinite(rough) & (cnt > 0)
    rows, cols = np.nonzero(ok)
    if len(rows) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    cx, cy = x0 + (cols + 0.5) * cell_m, y0 - (rows + 0.5) * cell_m
    sq = (np.floor(cx / spacing_m).astype(np.int64), np.floor(cy / spacing_m).astype(np.int64))
    key = (sq[0] - sq[0].min()) * (sq[1].max() - sq[1].min() + 1) + (sq[1] - sq[1].min())
    # flattest cell per square; ties broken by the distance to the square's centre (deterministic)
    dcen = np.hypot(cx - (sq[0] + 0.5) * spacing_m, cy - (sq[1] + 0.5) * spacing_m)
    order = np.lexsort((dcen, rough[rows, cols], key))
    first = order[np.r_[True, np.diff(key[order]) != 0]]
    return np.column_stack([cx[first], cy[first]]), zmean[rows[first], cols[first]]


# ------------------------------------------------------------------------------------------------- main
def _same_crs(path: Path, crs_wkt, cloud_crs) -> None:
    """CrsError naming ``path`` when its CRS differs from the cloud's (never a silent transform)."""
    import pyproj

    from aerotri.geom.crs.definition import crs_label, same_horizontal

    if cloud_crs is None or not crs_wkt:
        return
    crs = pyproj.CRS.from_user_input(crs_wkt)
    if not same_horizontal(crs, cloud_crs):
        raise CrsError(f"{path} is in {crs_label(crs)} but the cloud in {crs_label(cloud_crs)}; give both in one CRS "
                       "(aerotri crs transform)")


def _read_contours(path: Path, cloud_crs, cloud_z_m: float = 1.0) -> Layer:
    """The contour lines of ``path`` (a GeoPackage's ``contours`` layer, else its first), their ``elevation`` in the
    cloud's height unit (``cloud_z_m`` metres) as every other height of the GeoPackage (s27: contours in metres were
    copied beside spot heights in feet). The contours' unit: their ``elevation_m`` (``lidarctl contours`` writes it),
    else the height unit of the file's CRS (a compound CRS's vertical unit, a 2D one's horizontal unit, as for LAS);
    a file with ``elevation`` but neither is refused beside a cloud whose heights are not metres."""
    import shapely
    from pyogrio.errors import DataLayerError, DataSourceError
    from pyogrio.raw import read

    import pyogrio

    from aerotri.geom.crs.definition import height_unit_m, length_unit_name

    try:
        names = [str(n) for n, _ in pyogrio.list_layers(path)]
        # a DLG GeoPackage of an earlier run holds many layers: take its contours
        meta, _, wkb, fields = read(path, layer="contours" if "contours" in names else names[0])
    except (DataSourceError, DataLayerError, OSError, IndexError) as exc:
        raise InputError(f"{path}: not a readable vector layer ({exc})") from None
    _same_crs(path, meta.get("crs"), cloud_crs)
    geoms = [shapely.from_wkb(b) for b in wkb]
    if any(g is None or g.geom_type not in ("LineString", "MultiLineString") for g in geoms):
        raise InputError(f"{path}: contours must be lines")
    cols = {str(n): np.asarray(v) for n, v in zip(meta["fields"], fields)}
    if "elevation" in cols and cloud_crs is not None:
        if "elevation_m" in cols:
            elevation_m, how = np.asarray(cols["elevation_m"], float), "their elevation_m"
        elif meta.get("crs"):
            z_m = height_unit_m(meta["crs"])
            elevation_m, how = np.asarray(cols["elevation"], float) * z_m, \
                f"the height unit of the file's CRS, {length_unit_name(z_m)}"
        elif abs(cloud_z_m - 1.0) > 1e-12:
            raise InputError(f"{path}: the contours' elevation has no unit (no elevation_m field, no CRS) and the "
                             f"cloud's heights are in {length_unit_name(cloud_z_m)}; give contours with a CRS (e.g. "
                             "from lidarctl contours)")
        else:
            elevation_m, how = None, ""
        if elevation_m is not None:
            elevation = elevation_m / cloud_z_m
            given = np.asarray(cols["elevation"], float)
            if np.allclose(elevation, given, rtol=0, atol=1e-6):
                elevation = given  # the same unit: as written (trial s96 F13: 420.0 ft came back 420.00000000000006)
            else:
                log.info("%s: contour elevation in the cloud's height unit (%s), from %s", path,
                         length_unit_name(cloud_z_m), how)
            cols["elevation"], cols["elevation_m"] = elevation, elevation_m
    gtype = "MultiLineString" if any(g.geom_type == "MultiLineString" for g in geoms) else "LineString"
    return Layer("contours", gtype, geoms, cols)


def _dem_contours(path: Path, out_path: Path, interval_m: float, cloud_crs, cloud_z_m: float = 1.0) -> Layer:
    """Contours of the DEM every ``interval_m`` (whole multiples in the DEM's height unit), their ``elevation`` in
    the cloud's height unit (``cloud_z_m`` metres) as every other height of the GeoPackage (trial-lidar: a DEM in
    metres beside a cloud in feet gave contours at 124 beside spot heights at 425, the command saying "(ft)")."""
    import shapely

    from lidarctl.terrain.contours import MIN_RING_CELLS, trace, whole_unit_interval, without_small_rings
    from lidarctl.terrain.dem_io import open_dem

    src, z_m = open_dem(path, out_path)
    with src:
        _same_crs(path, src.crs.to_wkt(), cloud_crs)
        dem = src.read(1, masked=True).astype(np.float64).filled(np.nan)
        transform = src.transform
    # in whole units of the DEM when meant so, said when not (trial s96 F6: Autzen's map contours at 406.824 ft)
    cs = trace(dem, transform, whole_unit_interval(interval_m, z_m), option="--contour-interval-m")
    # the map's contours as lidarctl contours draws them by default: no ring the DEM does not resolve (trial s98 L8)
    cs, _ = without_small_rings(cs, MIN_RING_CELLS * abs(transform.a * transform.e))
    return Layer("contours", "LineString", [shapely.LineString(c.xy) for c in cs],
                 {"elevation": np.array([c.level for c in cs], float) * (z_m / cloud_z_m if z_m != cloud_z_m else 1.0),
                  "elevation_m": np.array([c.level * z_m for c in cs], float),
                  "index": np.array([c.index for c in cs], bool),
                  # as lidarctl contours writes them (trial s94: this layer lacked the field)
                  "closed": np.array([c.closed for c in cs], bool)})


def _outside_water(contours: Layer, water: list) -> Layer:
    """The contour lines cut at the water polygons' outlines, their pieces inside left out: a map's contours stop at
    the shore (the water's level is the water layer's ``water_z``). A DEM that is not hydro-flattened holds the
    water returns' waves and the TIN across the voids (trial-relief F8: the demo's ponds, 186 contour lines, 3,070 m
    of them more than 1 m inside the water at a 0.5 m interval). Each piece a line of its own, with its fields."""
    from lidarctl.terrain.contours import pieces_outside

    if not water or not contours.geometries:
        return contours
    kept = pieces_outside(contours.geometries, water)
    geoms, rows = [g for _, g in kept], [k for k, _ in kept]
    rows = np.array(rows, int)
    fields = {name: np.asarray(v)[rows] for name, v in contours.fields.items()}
    if "closed" in fields:  # a ring cut at the shore is no longer closed
        fields["closed"] = np.array([g.is_closed for g in geoms], bool)
    return Layer(contours.name, contours.geometry_type, geoms, fields)


def _scale_geoms(geoms: list, f: float) -> list:
    import shapely

    if f == 1.0:
        return geoms
    return [shapely.transform(g, lambda a: a * f) for g in geoms]


def extract_vectors(paths, out_path, params: MapVectorSettings = MapVectorSettings(), crs=None, dem=None,
                    contours=None) -> MapVectors:
    """The DLG layers of classified LAS/LAZ ``paths`` (one CRS); see the module doc. ``dem``/``contours``:
    a DEM GeoTIFF to contour or a contour layer to copy (same CRS as the cloud)."""
    import shapely
    from scipy import ndimage

    from lidarctl.corners.roof_corners import read_strips
    from lidarctl.corners.roof_segments import point_spacing_m

    for name in ("cell_m", "min_area_m2", "simplify_m", "spot_spacing_m", "contour_interval_m"):
        v = getattr(params, name)
        if not (np.isfinite(v) and v > 0):
            raise OptionError(f"must be a positive number, got {v}", param="--" + name.replace("_", "-"))
    pts = read_strips(paths, crs=crs)
    units = pts.units
    cls = pts.classification
    keep = ~np.isin(cls, NOISE)
    pts = pts.subset(keep)
    cls = pts.classification
    xy = np.column_stack([pts.x, pts.y])
    if len(xy) == 0:
        raise InputError(f"{', '.join(map(str, paths))}: no points besides noise")
    if not np.isin(cls, (GROUND, BUILDING)).any():
        # trial s94: an unclassified cloud gave a GeoPackage of empty layers, exit 0, where rasters refuses it
        raise InputError(f"{', '.join(map(str, paths))}: no ground (2) or building (6) points, the classes the map is "
                         f"drawn from (the cloud holds {', '.join(map(str, np.unique(cls)))}); run 'lidarctl "
                         "classify' first")
    p = params
    f_xy = 1.0 / units.xy_m  # metres -> CRS units
    f_z = 1.0 / units.z_m
    layers = []

    polys, rows, bstats = building_outlines(pts, roof_dropouts=p.roof_dropouts)
    layers.append(Layer("buildings", "Polygon", _scale_geoms(polys, f_xy), {
        "building_id": np.array([r["building_id"] for r in rows], np.int64),
        "roof": np.array([r["roof"] for r in rows], object),
        "eave_z": np.array([r["eave_z"] for r in rows], float) * f_z,
        "ridge_z": np.array([r["ridge_z"] for r in rows], float) * f_z,
        "ground_z": np.array([r["ground_z"] for r in rows], float) * f_z,
        "height_m": np.array([r["height_m"] for r in rows], float),
        "area_m2": np.array([r["area_m2"] for r in rows], float),
        "n_points": np.array([r["n_points"] for r in rows], np.int64)}))

    x0, y0, nrows, ncols = _grid(xy, p.cell_m)
    from lidarctl.grid import check_grid

    check_grid(nrows, ncols, p.cell_m, 16, "road/water masks", option="--cell-m", hint="use a coarser --cell-m")
    shape = (nrows, ncols)
    # close over gaps of about two point spacings (a mask cell finer than the spacing leaves empty cells)
    spacing = point_spacing_m(xy)
    close = max(1, int(np.ceil(spacing / p.cell_m)))
    r, c = _cells(xy, x0, y0, p.cell_m, shape)
    void_cells = np.ones(shape, bool)
    void_cells[r, c] = False
    void = ndimage.binary_opening(void_cells, structure=np.ones((3, 3), bool), iterations=close)
    road = class_mask(xy[cls == ROAD], x0, y0, p.cell_m, shape, min_area_m2=p.min_area_m2, close_cells=close)
    rpolys = mask_polygons(without_pinches(road), x0, y0, p.cell_m, p.simplify_m)
    lines = centrelines(road, x0, y0, p.cell_m, p.simplify_m)
    ltree = shapely.STRtree([ln for ln, _ in lines]) if lines else None
    rwidth = []
    for q in rpolys:
        hit = ltree.query(q, predicate="intersects") if ltree is not None else []
        rwidth.append(float(np.median([lines[i][1] for i in hit])) if len(hit) else float("nan"))
    layers.append(Layer("roads", "Polygon", _scale_geoms(rpolys, f_xy),
                        {"area_m2": np.array([q.area for q in rpolys], float), "width_m": np.array(rwidth, float)}))
    layers.append(Layer("road_centrelines", "LineString", _scale_geoms([ln for ln, _ in lines], f_xy),
                        {"width_m": np.array([w for _, w in lines], float),
                         "length_m": np.array([ln.length for ln, _ in lines], float)}))

    from lidarctl.classify.pipeline import ClassifySettings

    water_rule = ClassifySettings()
    occupied = ~void_cells
    edge_lakes = lakes_at_edge(void, occupied, r, c, pts.z, cls == WATER, tol_m=water_rule.level_water_tol_m,
                               bank_fraction=water_rule.level_water_bank_fraction)
    wmask = class_mask(xy[cls == WATER], x0, y0, p.cell_m, shape, min_area_m2=p.min_area_m2, close_cells=close,
                       void=void, join=edge_lakes)
    wpolys = mask_polygons(without_pinches(wmask), x0, y0, p.cell_m, p.simplify_m)
    wxy, wz = xy[cls == WATER], pts.z[cls == WATER]
    wlevel, wrange, kept = [], [], []
    for q in wpolys:
        # its water returns; a piece without any (a void joined across the simplified outline) takes those
        # within a cell of it, and none at all means no water level is known: no water feature
        inside = shapely.contains_xy(q, wxy[:, 0], wxy[:, 1]) if len(wxy) else np.zeros(0, bool)
        if not inside.any() and len(wxy):
            inside = shapely.dwithin(q, shapely.points(wxy), p.cell_m)
        if inside.any():
            kept.append(q)
            wlevel.append(float(np.median(wz[inside])))
            lo, hi = np.percentile(wz[inside], [5.0, 95.0])
            wrange.append(float(hi - lo))
    wpolys = kept
    layers.append(Layer("water", "Polygon", _scale_geoms(wpolys, f_xy),
                        {"area_m2": np.array([q.area for q in wpolys], float),
                         "water_z": np.array(wlevel, float) * f_z,
                         "water_z_range_m": np.array(wrange, float)}))

    # open terrain: ground, road surface and grass (a fused classification labels grassland 3)
    is_g = np.isin(cls, OPEN_GROUND)
    sxy, sz = spot_heights(xy[is_g], pts.z[is_g], xy[~is_g], max(p.cell_m, spacing), p.spot_spacing_m)
    layers.append(Layer("spot_heights", "Point", _scale_geoms(list(shapely.points(sxy)) if len(sxy) else [], f_xy),
                        {"z": sz * f_z, "z_m": sz}))

    if contours is not None:
        layers.append(_read_contours(Path(contours), pts.crs, units.z_m))
    elif dem is not None:
        traced = _dem_contours(Path(dem), Path(out_path), p.contour_interval_m, pts.crs, units.z_m)
        layers.append(_outside_water(traced, _scale_geoms(wpolys, f_xy)))
    counts = VectorCounts(buildings=len(polys), roof_spacing_m=bstats.get("point_spacing_m"), roads=len(rpolys),
                          road_centrelines=len(lines), water=len(wpolys), spot_heights=len(sz),
                          contours=len(layers[-1].geometries) if len(layers) == 6 else None,
                          road_points=int(np.count_nonzero(cls == ROAD)))
    # where the map is made: cells with returns (small gaps closed, as the water's void) and the water it maps; a
    # checker leaves a reference's features outside it out (trial-city: BGT past the crop's edge read as missed)
    covered = ndimage.binary_closing(occupied, structure=np.ones((3, 3), bool), iterations=close) | occupied | wmask
    cover = mask_polygons(covered, x0, y0, p.cell_m, p.simplify_m)
    layers.append(Layer("coverage", "Polygon", _scale_geoms(cover, f_xy),
                        {"area_m2": np.array([q.area for q in cover], float)}))
    extent = tuple(float(v) * f_xy for v in (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max()))
    return MapVectors(layers, pts.crs, units, counts, extent)


# every layer ``extract_vectors`` can write (contours only with --dem or --contours)
LAYER_NAMES = ("buildings", "roads", "road_centrelines", "water", "spot_heights", "contours", "coverage")


def write_vectors(mv: MapVectors, path) -> Path:
    """All layers into one GeoPackage, with the CRS on each, written atomically (an empty layer is written
    with its fields, so a reader finds every layer)."""
    from aerotri.core.vector_files import VectorLayer, write_layers

    path = Path(path)
    if path.suffix.lower() != ".gpkg":
        raise OptionError(f"{path}: the output must end in .gpkg", param="OUT")
    return write_layers(path, [VectorLayer(layer.name, layer.geometry_type, layer.geometries, layer.fields)
                               for layer in mv.layers], crs=mv.crs)


def vectors_to_file(paths, out_path, *, params: MapVectorSettings = MapVectorSettings(), crs=None, dem=None,
                    contours=None,
                    image=None, owned: bool = False) -> VectorsResult:
    """``extract_vectors`` + ``write_vectors`` (+ a PNG preview beside OUT over ``image`` when given).
    ``owned``: OUT is a project's own output (the chain's), replaced even when an earlier version wrote it without
    the mark of our GeoPackages (``refuse_foreign_layers``). Returns the summary."""
    from aerotri.core.atomic import refuse_input_as_output

    out_path = Path(out_path)
    inputs = [Path(q) for q in paths] + [Path(q) for q in (dem, contours, image) if q is not None]
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    refuse_input_as_output(out_path, inputs, option="OUT")
    for q in inputs:
        if not q.is_file():
            raise InputError(f"{q}: no such file")
    if out_path.suffix.lower() != ".gpkg":
        raise OptionError(f"{out_path}: the output must end in .gpkg", param="OUT")
    from aerotri.core.vector_files import refuse_foreign_layers

    refuse_foreign_layers(out_path, LAYER_NAMES, "lidarctl vectors", owned=owned)
    if image is not None:
        _check_raster(Path(image))
    mv = extract_vectors(paths, out_path, params, crs=crs, dem=dem, contours=contours)
    if image is not None:
        _image_in_cloud_crs(Path(image), mv.crs)  # before writing: no partial output
    write_vectors(mv, out_path)
    files = [str(out_path)]
    if image is not None:
        files.append(str(preview_png(mv, out_path.with_suffix(".png"), image=image)))
    return VectorsResult(mv.stats, mv.units, tuple(files))


def _image_in_cloud_crs(path: Path, cloud_crs) -> None:
    """OptionError naming --image and both CRSs when the orthophoto's horizontal CRS is not the cloud's (it was
    drawn in its own coordinates and said "does not cover the data")."""
    import pyproj
    import rasterio

    from aerotri.geom.crs.definition import crs_label, same_horizontal

    if cloud_crs is None:
        return
    with rasterio.open(path) as src:
        image_crs = pyproj.CRS.from_user_input(src.crs.to_wkt())
    if not same_horizontal(image_crs, cloud_crs):
        raise OptionError(f"{path} is in {crs_label(image_crs)} but the cloud in {crs_label(cloud_crs)}; give an "
                          "orthophoto in the cloud's CRS (e.g. gdalwarp -t_srs)", param="--image")


def _check_raster(path: Path) -> None:
    import rasterio

    from aerotri.geom.inputs import check_raster_size

    try:
        with rasterio.open(path) as src:
            if src.crs is None:
                raise InputError(f"{path}: the image has no CRS")
            check_raster_size(src, path, "image")
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: not a readable raster ({exc})") from None


STYLE = {"buildings": ("firebrick", 1.0), "roads": ("dimgray", 0.8), "road_centrelines": ("gold", 1.0),
         "water": ("royalblue", 1.0), "contours": ("#8b4513", 0.4), "coverage": ("0.6", 0.5)}


def draw_layers(ax, layers: dict) -> None:
    """Draw ``{name: list of shapely geometries}`` on a matplotlib axes in the DLG colours."""
    for name, geoms in layers.items():
        if name == "spot_heights":
            if geoms:
                xy = np.array([g.coords[0][:2] for g in geoms])
                ax.plot(xy[:, 0], xy[:, 1], "k+", ms=6, label=f"spot heights ({len(geoms)})")
            continue
        colour, lw = STYLE.get(name, ("k", 0.5))
        first = True
        for g in geoms:
            parts = getattr(g, "geoms", [g])
            for part in parts:
                rings = [part.exterior, *part.interiors] if part.geom_type == "Polygon" else [part]
                for ring in rings:
                    xy = np.asarray(ring.coords)
                    ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=lw, label=f"{name} ({len(geoms)})" if first else None)
                    first = False


PREVIEW_MARGIN = 0.05  # of the data's larger side, around it in the preview


def preview_frame(mv: MapVectors) -> tuple[float, float, float, float] | None:
    """The preview's xmin, ymin, xmax, ymax (CRS units): the points' extent and every feature's (contours of a
    larger DEM), with ``PREVIEW_MARGIN`` of the larger side around them; None without either."""
    boxes = [mv.extent] if mv.extent is not None else []
    geoms = [g for ly in mv.layers if ly.name != "coverage" for g in ly.geometries]
    if geoms:
        import shapely

        boxes.append(tuple(shapely.total_bounds(np.asarray(geoms, dtype=object))))
    boxes = [b for b in boxes if np.all(np.isfinite(b))]
    if not boxes:
        return None
    b = np.array(boxes, float)
    x0, y0, x1, y1 = b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()
    m = PREVIEW_MARGIN * max(x1 - x0, y1 - y0, 1e-9)
    return x0 - m, y0 - m, x1 + m, y1 + m


def _image_window(image, frame):
    """The orthophoto's pixels over ``frame`` (at most about 2000 px a side), where they hold data (its mask:
    nodata, alpha or the internal mask; False over its nodata margin) and their bounds; None when it does not cover
    any of it (the whole image without a frame)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.windows import Window, from_bounds

    with rasterio.open(image) as src:
        whole = Window(0, 0, src.width, src.height)
        if frame is None:
            win = whole
        else:
            w = from_bounds(*frame, transform=src.transform)
            c0, r0 = int(np.floor(w.col_off)), int(np.floor(w.row_off))  # whole pixels covering the frame
            win = Window(c0, r0, int(np.ceil(w.col_off + w.width)) - c0, int(np.ceil(w.row_off + w.height)) - r0)
            try:
                win = win.intersection(whole)
            except rasterio.errors.WindowError:
                return None
            if win.width < 1 or win.height < 1:
                return None
        f = max(1, int(np.ceil(max(win.width, win.height) / 2000)))
        n = min(3, src.count)
        shape = (max(1, int(win.height) // f), max(1, int(win.width) // f))
        data = src.read(indexes=list(range(1, n + 1)), window=win, resampling=Resampling.average,
                        out_shape=(n, *shape))
        ok = src.dataset_mask(window=win, out_shape=shape, resampling=Resampling.nearest) > 0
        return data, ok, src.window_bounds(win)


def preview_png(mv: MapVectors, path, image=None, title: str = "") -> Path:
    """The layers over the orthophoto ``image`` (when given), with a legend and axes in CRS units; framed by the
    data (``preview_frame``: the points and the features, with a margin), the orthophoto clipped to the frame (an
    orthophoto larger than the LiDAR framed it before: Autzen's features sat in a corner of an empty map)."""
    plt = pyplot()

    frame = preview_frame(mv)
    # the page takes the frame's shape (a 2:1 strip of data on a square page left half of it blank)
    aspect = 1.0 if frame is None else (frame[3] - frame[1]) / max(frame[2] - frame[0], 1e-9)
    fig, ax = plt.subplots(figsize=(10, float(np.clip(9.0 * aspect + 1.2, 4.0, 12.0))))
    note = ""
    if image is not None:
        got = _image_window(image, frame)
        if got is None:
            note = " (the orthophoto does not cover the data)"
        else:
            data, ok, (left, bottom, right, top) = got
            img = np.moveaxis(data, 0, -1)
            img = img[..., 0] if img.shape[-1] < 3 else img
            if img.dtype != np.uint8:
                scale = float(np.nanpercentile(img[ok], 99)) if ok.any() else 1.0
                img = np.clip(img / max(scale, 1e-9), 0, 1)
            # the nodata margin transparent (the page's white), as the maps elsewhere: drawn, it was a dark grey
            # band (black at alpha 0.6) that read as data; the orthophoto's own pixels at alpha 0.6
            if img.ndim == 2:
                img = np.ma.masked_array(img, ~ok)
            else:
                img = np.dstack([img.astype(float) / (255.0 if img.dtype == np.uint8 else 1.0), ok * 0.6])
            ax.imshow(img, extent=(left, right, bottom, top), cmap="gray", alpha=None if img.ndim == 3 else 0.6)
    draw_layers(ax, {ly.name: ly.geometries for ly in mv.layers})
    if frame is not None:
        ax.set_xlim(frame[0], frame[2])
        ax.set_ylim(frame[1], frame[3])
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel(f"easting ({mv.units.xy_name})")
    ax.set_ylabel(f"northing ({mv.units.xy_name})")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title((title or "DLG layers") + note)
    fig.tight_layout()
    save_png(fig, path, dpi=100)
    return Path(path)
