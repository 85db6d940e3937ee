"""Line-map (DLG) accuracy against reference vectors: plan offsets of well-defined points, completeness
and correctness per layer.

* Well-defined points are the corners of the ``buildings`` outlines (vertices whose interior angle differs
  from a straight line by more than ``CORNER_MIN_TURN_DEG``). For each produced corner: the offset vector to
  the nearest point of any reference outline (vertex-to-line), and, when a reference corner lies within
  ``match_m`` and the two are each other's nearest, the corner-to-corner offset. Plan RMS of both.
* Polygon layers (buildings, roads, water): completeness = area of reference covered by the product /
  reference area; correctness = area of product covered by the reference / product area (Heipke et al. 1997
  as areas). Line layers (road_centrelines, contours): the same with lengths inside a buffer of
  ``buffer_m`` around the other set's lines.
* Tolerance: the plan RMS of well-defined map features at the map scale (``aerotri.core.tolerances.feature_limit``:
  1:500-1:2000 GB/T 7931's 0.6 / 0.8 mm on the map; 1:5000 and 1:10000 flat 0.50 m, mountainous 0.75 m, the
  table of ../shared/design/reports.md, unconfirmed and tighter than 1:2000's: the report says so).

Lengths and areas are in the CRS units of the files, reported in metres (``_m``, ``_m2``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from aerotri.core.settings import setting
from aerotri.core.errors import CrsError, InputError, OptionError
from aerotri.core.figures import pyplot, save_png

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

CORNER_MIN_TURN_DEG = 30.0
POLYGON_LAYERS = ("buildings", "roads", "water")
LINE_LAYERS = ("road_centrelines", "contours")
VECTOR_CHECK_VERSION = 3  # the chain's vectors stage stamp: bump when the check's numbers change at the same inputs


@dataclasses.dataclass(frozen=True)
class VectorCheckSettings:
    """``lidarctl check-vectors``: the layers checked, how corners are paired, the tolerance table."""

    layers: tuple = setting((), help="Check only these layers (empty: every layer the two files share).")
    match_m: float = setting(3.0, min=0.0, min_open=True, help="Largest distance (m) of a produced corner from its "
                                                               "reference corner to pair them.")
    buffer_m: float = setting(2.0, min=0.0, min_open=True, help="Buffer (m) around lines for their completeness and "
                                                                "correctness.")
    scale: str = setting("1:10000", help="Map scale of the tolerance table: 1:500, 1:1000, 1:2000 (GB/T 7931's 0.6 mm "
                                        "on the map), 1:5000, 1:10000 (the design table's 0.5 m, unconfirmed) or "
                                        "'ASPRS2023 H<cm>cm V<cm>cm'.")
    terrain: str = setting("flat", help="Terrain class of the tolerance table.")
    within: str | None = setting(None, help="Check only inside the polygons of this file, or 'hull': inside the "
                                            "convex hulls of the reference polygons' blocks (a reference that maps "
                                            "only part of the area; as lidarctl evaluate --within).")


def read_layers(path: Path) -> tuple[dict, object, float]:
    """{layer: list of shapely geometries}, CRS (pyproj), metres per CRS unit of a GeoPackage/GeoJSON."""
    import pyogrio
    import pyproj
    import shapely
    from pyogrio.errors import DataLayerError, DataSourceError
    from pyogrio.raw import read

    from lidarctl.units import units_of

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        names = [str(n) for n, _ in pyogrio.list_layers(path)]
        out, crs = {}, None
        for name in names:
            meta, _, wkb, _ = read(path, layer=name)
            if wkb is None:  # a table without geometries (a CSV read by GDAL): not a vector map layer
                raise InputError(f"{path}: layer {name!r} has no geometries; expected a vector map (.gpkg/.geojson) "
                                 "with layers of the same names as the product's")
            if meta.get("crs") and crs is None:
                crs = pyproj.CRS.from_user_input(meta["crs"])
            out[name] = [g for g in (shapely.from_wkb(b) for b in wkb if b is not None) if g is not None and not g.is_empty]
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise InputError(f"{path}: not a readable vector file ({exc})") from None
    xy_m = units_of(crs, str(path)).xy_m if crs is not None else 1.0
    return out, crs, xy_m


def corners_of(polys: list) -> np.ndarray:
    """(N, 2) vertices of the polygons' rings where the outline turns by more than CORNER_MIN_TURN_DEG."""
    pts = []
    for g in polys:
        for p in getattr(g, "geoms", [g]):
            if p.geom_type != "Polygon":
                continue
            for ring in (p.exterior, *p.interiors):
                xy = np.asarray(ring.coords)[:-1, :2]
                if len(xy) < 3:
                    continue
                a, b = xy - np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0) - xy
                turn = np.degrees(np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(axis=1))))
                pts.append(xy[turn > CORNER_MIN_TURN_DEG])
    return np.vstack(pts) if pts else np.zeros((0, 2))


def _rms(v: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean((v**2).sum(axis=1)))) if len(v) else None


@dataclasses.dataclass(frozen=True)
class CornerOffsets:
    """Offsets (CRS units, east and north per row) of the produced building corners ``corners``: ``to_line`` to the
    nearest reference outline (one per corner; none without a reference), ``to_corner`` to the mutually nearest
    reference corner within the match distance from the corners ``matched_from``; the reference's corner count."""

    corners: np.ndarray
    to_line: np.ndarray
    to_corner: np.ndarray
    matched_from: np.ndarray
    n_reference_corners: int
    # the rigid motion of the map against the reference the pairs were found under (``align_corners``): the map's
    # rotation (deg, counter-clockwise) and its displacement at its corners' centre (CRS units, map - reference),
    # and the largest displacement of a corner by it
    rotation_deg: float = 0.0
    moved: tuple = (0.0, 0.0)
    max_moved: float = 0.0


@dataclasses.dataclass(frozen=True)
class Overlap:
    """Produced and reference features of a layer: their areas (polygons; CRS units squared) or lengths (lines; CRS
    units), and completeness / correctness in per cent of the reference / product matched (None: nothing to match)."""

    reference_size: float
    product_size: float
    completeness_pct: float | None
    correctness_pct: float | None


# Turns the corner pairing starts from besides none (deg): a map turned by a few degrees has its true pairs within
# the pairing distance only near the centre, from which the iterations alone did not always reach the whole turn
# (AHN3 Delft turned 5 deg: 2.39 deg found from 0).
START_TURNS_DEG = (0.0, -2.0, 2.0, -4.0, 4.0, -6.0, 6.0, -8.0, 8.0, -10.0, 10.0)


def align_corners(pc: np.ndarray, rc: np.ndarray, match_m: float, start=(0.0, 0.0), iterations: int = 30):
    """Pairs of produced corners ``pc`` and reference corners ``rc`` (mutually nearest within ``match_m``) found under
    the rigid motion (rotation + translation) that lays the product on the reference: from the translation ``start``
    (reference - product) and each turn of ``START_TURNS_DEG``, pairs are found, the motion fitted to them by least
    squares (2D Kabsch), and again, until the pairs stay the same (iterative closest point); the start that pairs
    the most corners wins (ties: the first, no turn). Returns (index of each pair's produced corner, its reference
    corner, 2x2 rotation, produced centre, reference centre): p -> R (p - cp) + cr."""
    from scipy.spatial import cKDTree

    tree = cKDTree(rc)
    best = None
    for turn in START_TURNS_DEG:
        a = np.radians(turn)
        found = _icp(pc, rc, tree, match_m, np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]),
                     pc.mean(axis=0), pc.mean(axis=0) + np.asarray(start, float), iterations)
        if best is None or len(found[0]) > len(best[0]):
            best = found
    return best


def _mutual_pairs(pc, rc, tree, match_m, rot, cp, cr):
    """The produced corners moved by p -> rot (p - cp) + cr that are mutually nearest to a reference corner within
    ``match_m`` (``tree``: of ``rc``): (their indices, their reference corners' indices)."""
    from scipy.spatial import cKDTree

    moved = (pc - cp) @ rot.T + cr
    d, j = tree.query(moved)
    _, back = cKDTree(moved).query(rc)
    mine = np.flatnonzero((back[j] == np.arange(len(pc))) & (d <= match_m))
    return mine, j[mine]


def _icp(pc, rc, tree, match_m, rot, cp, cr, iterations):
    """``align_corners`` from one start: at most ``iterations`` fits; the pairs under the last motion."""
    last = None
    for k in range(iterations + 1):
        mine, theirs = _mutual_pairs(pc, rc, tree, match_m, rot, cp, cr)
        if len(mine) < 3 or k == iterations or (last is not None and np.array_equal(mine, last)):
            break
        last = mine
        P, Q = pc[mine], rc[theirs]
        cp, cr = P.mean(axis=0), Q.mean(axis=0)
        u, _, vt = np.linalg.svd((P - cp).T @ (Q - cr))
        flip = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))])
        rot = vt.T @ flip @ u.T
    return mine, theirs, rot, cp, cr


def point_offsets(prod: list, ref: list, match_m: float, area=None, start=(0.0, 0.0)) -> CornerOffsets:
    """Offsets (CRS units) of the produced building corners: to the nearest reference outline and to the
    mutually nearest reference corner within ``match_m``. ``area`` (a shapely polygon): only the corners of
    either side within ``match_m`` of it (the outlines keep their own corners: none is made where the area cuts
    them; a hull's vertices are reference corners on its edge, and a produced corner off that edge is an offset
    to measure, not a corner to drop).

    Corners are paired under the map's rigid motion against the reference (``align_corners``, from the translation
    ``start``, reference - product: ``map_offset``'s) and their offsets measured as the map lies: a map moved or
    turned by more than the pairing distance keeps its true pairs and its offsets show the motion. Paired as the map
    lies, such a map kept chance neighbours only, whose offsets the pairing distance bounds (AHN3 Delft's map moved
    16.8 m read 1.64 m, turned 5 deg 1.48 m)."""
    import shapely

    pc, rc = corners_of(prod), corners_of(ref)
    if area is not None:
        grown = area.buffer(match_m)
        pc = pc[shapely.intersects_xy(grown, pc[:, 0], pc[:, 1])]
        rc = rc[shapely.intersects_xy(grown, rc[:, 0], rc[:, 1])]
    none = np.zeros((0, 2))
    if len(pc) == 0 or not ref:
        return CornerOffsets(pc, none, none, none, len(rc))
    bounds = shapely.union_all([g.boundary for g in ref])
    near = shapely.shortest_line(shapely.points(pc), bounds)
    to_line = np.array([np.asarray(ln.coords)[1] - np.asarray(ln.coords)[0] for ln in near])
    if not len(rc):
        return CornerOffsets(pc, to_line, none, none, 0)
    mine, theirs, rot, cp, cr = align_corners(pc, rc, match_m, start)
    motion = (pc - cp) @ rot.T + cr - pc                     # reference - product, per corner
    centre = pc.mean(axis=0)
    at_centre = (centre - cp) @ rot.T + cr - centre
    return CornerOffsets(pc, to_line, rc[theirs] - pc[mine], pc[mine], len(rc),
                         rotation_deg=-float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))),
                         moved=(-float(at_centre[0]), -float(at_centre[1])),
                         max_moved=float(np.hypot(*motion.T).max()))


@dataclasses.dataclass(frozen=True)
class MapOffset:
    """The translation (CRS units, east and north; added to the product) that lays the produced polygons best on the
    reference's, and the share of the reference area they cover at it and as they lie (per cent)."""

    dx: float
    dy: float
    covered_at_offset_pct: float
    covered_as_lies_pct: float


# Cells of the masks map_offset correlates (m), and the most cells of a mask (a larger map gets coarser cells).
OFFSET_CELL_M = 0.5
OFFSET_MAX_CELLS = 4_000_000


def map_offset(prod: list, ref: list, cell: float) -> MapOffset | None:
    """The translation (reference - product) that lays the product's polygons best on the reference's: the peak of
    the cross-correlation of the two layers rasterised on one grid of ``cell`` CRS units (coarser when the grid
    would exceed ``OFFSET_MAX_CELLS``), to a cell. The start of the corner pairing (``align_corners``), which a map
    moved by more than the pairing distance needs. None when either side has no area."""
    import shapely
    from rasterio import features
    from rasterio.transform import from_origin
    from scipy.signal import fftconvolve

    polys = [g for g in list(prod) + list(ref) if "Polygon" in g.geom_type]
    if not prod or not ref or not polys:
        return None
    xmin, ymin, xmax, ymax = shapely.total_bounds(np.asarray(polys, dtype=object))
    cell = max(cell, float(np.sqrt(max((xmax - xmin) * (ymax - ymin), 1e-12) / OFFSET_MAX_CELLS)))
    ncols, nrows = int(np.ceil((xmax - xmin) / cell)) + 1, int(np.ceil((ymax - ymin) / cell)) + 1
    grid = dict(out_shape=(nrows, ncols), transform=from_origin(xmin, ymax, cell, cell), dtype="uint8")
    try:
        P = features.rasterize([g for g in prod if "Polygon" in g.geom_type], **grid).astype(np.float32)
        R = features.rasterize([g for g in ref if "Polygon" in g.geom_type], **grid).astype(np.float32)
    except ValueError:   # no polygon on one side
        return None
    if not P.any() or not R.any():
        return None
    # corr[i, j] = cells of R covered by P moved (i - nrows + 1) rows down and (j - ncols + 1) columns right
    corr = fftconvolve(R, P[::-1, ::-1], mode="full")
    i, j = np.unravel_index(int(np.argmax(corr)), corr.shape)
    area = float(R.sum())
    return MapOffset(dx=(j - ncols + 1) * cell, dy=-(i - nrows + 1) * cell,
                     covered_at_offset_pct=100.0 * float(corr[i, j]) / area,
                     covered_as_lies_pct=100.0 * float(corr[nrows - 1, ncols - 1]) / area)


def area_overlap(prod: list, ref: list) -> Overlap:
    """Polygons: the areas of the union of each side and the share of each covered by the other."""
    import shapely

    P = shapely.union_all(prod) if prod else shapely.Polygon()
    R = shapely.union_all(ref) if ref else shapely.Polygon()
    inter = P.intersection(R).area
    return Overlap(R.area, P.area, 100 * inter / R.area if R.area else None, 100 * inter / P.area if P.area else None)


# Vertices of one window of the line overlap: a union and a buffer of every line of a large layer at once (31,204
# contour lines of the demo's 1 m contours) held 3.8 GB; windows of this many vertices keep it to tens of MB.
_WINDOW_VERTICES = 20_000


def buffer_overlap(prod: list, ref: list, buffer: float, *, window: float | None = None) -> Overlap:
    """Lines: the lengths of each side and the share of each within ``buffer`` (CRS units) of the other.

    Computed window by window (square windows of side ``window``, CRS units; default: about
    ``_WINDOW_VERTICES`` vertices a window): a side's lines clipped to the window, the other side's to the window
    grown by ``buffer``, so memory follows the window, not the layer. Lengths are those of each side's union
    (a line drawn twice counts once)."""
    import shapely

    P = np.asarray(prod, dtype=object) if prod else np.empty(0, dtype=object)
    R = np.asarray(ref, dtype=object) if ref else np.empty(0, dtype=object)
    if not len(P) and not len(R):
        return Overlap(0.0, 0.0, None, None)
    both = np.concatenate([P, R])
    # the windows start off the data's bounds by an odd fraction of the buffer: clip_by_rect drops a line that runs
    # along a window's edge, and map lines at round coordinates (a contour's straight run, a box) would do so
    pad = 0.6180339887 * buffer
    xmin, ymin, xmax, ymax = shapely.total_bounds(both) + np.array([-pad, -pad, pad, pad])
    if window is None:
        n_windows = max(1.0, shapely.get_num_coordinates(both).sum() / _WINDOW_VERTICES)
        window = max(20.0 * buffer, np.sqrt(max((xmax - xmin) * (ymax - ymin), 1e-12) / n_windows))
    nx, ny = max(1, int(np.ceil((xmax - xmin) / window))), max(1, int(np.ceil((ymax - ymin) / window)))
    tree_p, tree_r = shapely.STRtree(P), shapely.STRtree(R)
    lr = lp = matched_ref = matched_prod = 0.0
    for i in range(nx):
        for j in range(ny):
            x0, y0 = xmin + i * window, ymin + j * window
            # lines cross the windows' shared edges at points (one running exactly along an edge would be lost)
            x1 = xmin + (i + 1) * window if i < nx - 1 else xmax
            y1 = ymin + (j + 1) * window if j < ny - 1 else ymax
            r_in, p_in = _clipped_union(R, tree_r, (x0, y0, x1, y1)), _clipped_union(P, tree_p, (x0, y0, x1, y1))
            lr, lp = lr + r_in.length, lp + p_in.length
            grown = (x0 - buffer, y0 - buffer, x1 + buffer, y1 + buffer)
            if r_in.length:
                near_p = _clipped_buffers(P, tree_p, grown, buffer)
                if not near_p.is_empty:
                    matched_ref += r_in.intersection(near_p).length
            if p_in.length:
                near_r = _clipped_buffers(R, tree_r, grown, buffer)
                if not near_r.is_empty:
                    matched_prod += p_in.intersection(near_r).length
    return Overlap(lr, lp, 100 * matched_ref / lr if lr else None, 100 * matched_prod / lp if lp else None)


def _clipped_union(lines: np.ndarray, tree, rect: tuple) -> object:
    """The union of ``lines`` (STRtree ``tree``) clipped to the rectangle ``rect`` = (x0, y0, x1, y1)."""
    import shapely

    hits = tree.query(shapely.box(*rect))
    if not len(hits):
        return shapely.LineString()
    return shapely.union_all(shapely.clip_by_rect(lines[hits], *rect))


def _clipped_buffers(lines: np.ndarray, tree, rect: tuple, buffer: float) -> object:
    """The area within ``buffer`` of ``lines`` (STRtree ``tree``) clipped to the rectangle ``rect``: the union of
    each clipped line's buffer. GEOS buffers the union of a layer's lines (noded into thousands of pieces where
    they cross) 100 times slower (4.3 against 0.04 CPU-s for 60 random-walk lines of 40 vertices) into a polygon
    that differs only in how its arcs are cut into chords (areas in the 4th digit, lengths inside in the 5th)."""
    import shapely

    hits = tree.query(shapely.box(*rect))
    if not len(hits):
        return shapely.Polygon()
    return shapely.union_all(shapely.buffer(shapely.clip_by_rect(lines[hits], *rect), buffer))


# A warning when more than this share of a layer's produced features lies outside the area the reference maps.
OUTSIDE_WARN_PCT = 10.0


def reference_hull(ref: dict, join: float):
    """The area a partial reference maps: the convex hulls of the blocks of its polygons (every polygon layer;
    polygons closer than ``join`` CRS units form one block; ``class_grid.block_hulls``, evaluate's --within hull)
    as one shapely geometry; None when the reference has no polygon."""
    import shapely

    from lidarctl.classify.class_grid import hulls_of_blocks

    polys = [g for geoms in ref.values() for g in geoms if "Polygon" in g.geom_type]
    return shapely.union_all(hulls_of_blocks(polys, join)) if polys else None


def check_area(within: str | None, ref: dict, ref_crs, reference_path, unit: float):
    """The area ``--within`` names (one shapely geometry, CRS units) or None (everywhere): 'hull' (``reference_hull``)
    or the polygons of a vector file in the reference's CRS. OptionError naming --within otherwise."""
    import shapely

    from aerotri.geom.crs.definition import crs_label, same_horizontal
    from lidarctl.classify import class_grid as cg

    if within is None:
        return None
    if within == "hull":
        hull = reference_hull(ref, 1.0 / unit)
        if hull is None:
            raise OptionError(f"--within hull: {reference_path} has no polygons to take the hulls of; give a polygon "
                              "file", param="--within")
        return hull
    if not Path(within).is_file():
        raise OptionError(f"{within}: no such file; expected 'hull' or a polygon file (.gpkg/.geojson)",
                          param="--within")
    area = cg.read_class_polygons(within, all_class=cg.OTHER)
    if area.crs is not None and ref_crs is not None and not same_horizontal(area.crs, ref_crs):
        raise OptionError(f"{within} is in {crs_label(area.crs)} but {reference_path} in {crs_label(ref_crs)}; give "
                          "both in one CRS", param="--within")
    if not area.geometries:
        raise OptionError(f"{within}: no polygons", param="--within")
    return shapely.union_all(area.geometries)


def _inside(geoms: list, area) -> np.ndarray:
    """Whether each feature lies in ``area`` (by a point inside it: ``representative_point``)."""
    import shapely

    if not geoms:
        return np.zeros(0, bool)
    return shapely.contains(area, shapely.point_on_surface(np.asarray(geoms, dtype=object)))


COVERAGE = "coverage"  # the layer of lidarctl vectors saying where the map was made from returns


def _coverage(prod: dict):
    """The union of the product's coverage polygons, or None (a product without that layer: judged everywhere)."""
    import shapely

    geoms = prod.get(COVERAGE) or []
    return shapely.union_all(np.asarray(geoms, dtype=object)) if geoms else None


def _size(geoms: list) -> float:
    """Total area (polygons) or length (lines) of ``geoms``, CRS units."""
    import shapely

    if not geoms:
        return 0.0
    g = np.asarray(geoms, dtype=object)
    return float(np.sum(shapely.area(g) if "Polygon" in geoms[0].geom_type else shapely.length(g)))


def _clip(geoms: list, area) -> list:
    """The parts of ``geoms`` inside ``area`` (features outside it dropped)."""
    import shapely

    if not geoms:
        return []
    cut = shapely.intersection(np.asarray(geoms, dtype=object), area)
    return [g for g in cut if not g.is_empty]


def _bounds(layers: dict, names) -> tuple | None:
    import shapely

    geoms = [g for n in names for g in layers.get(n, ())]
    if not geoms:
        return None
    b = shapely.total_bounds(np.asarray(geoms, dtype=object))
    return tuple(float(v) for v in b) if np.all(np.isfinite(b)) else None


APART_M = 1000.0


def _refuse_apart(prod: dict, ref: dict, layers, product_path, reference_path, pcrs, rcrs, unit: float) -> None:
    """A file without a CRS is taken in the other's (said); an InputError when the compared layers' extents lie more
    than ``APART_M`` apart (``unit``: metres per CRS unit): files in two CRSs, one without its own (trial s94: BGT
    footprints in EPSG:3035 without a CRS tag scored 0 % / 0 % with corner offsets of 4,747 km, exit 0, where
    ``lidarctl evaluate`` refuses the same file)."""
    from aerotri.geom.crs.definition import crs_label

    for path, crs, other, other_crs in ((product_path, pcrs, reference_path, rcrs),
                                        (reference_path, rcrs, product_path, pcrs)):
        if crs is None and other_crs is not None:
            log.warning("%s: has no CRS; taken in %s's, %s", path, other, crs_label(other_crs))
    pb, rb = _bounds(prod, layers), _bounds(ref, layers)
    if pb is None or rb is None:
        return
    m = APART_M / unit   # layers side by side (a road's centre line beside another's) are no CRS mix-up
    if pb[0] > rb[2] + m or rb[0] > pb[2] + m or pb[1] > rb[3] + m or rb[1] > pb[3] + m:
        none = [str(p) for p, c in ((product_path, pcrs), (reference_path, rcrs)) if c is None]
        raise InputError(f"{product_path} and {reference_path} lie apart (layers {', '.join(layers)}: x "
                         f"{pb[0]:.1f} .. {pb[2]:.1f}, y {pb[1]:.1f} .. {pb[3]:.1f} against x {rb[0]:.1f} .. "
                         f"{rb[2]:.1f}, y {rb[1]:.1f} .. {rb[3]:.1f}); are both in one CRS?"
                         + (f" ({', '.join(none)} has no CRS of its own)" if none else ""))


def check_vectors(product_path, reference_path, params: VectorCheckSettings = VectorCheckSettings()) -> VectorCheck:
    """Accuracy of the DLG ``product_path`` against ``reference_path`` (see the module doc; metres): the typed
    record, the JSON document and the buildings' corner offsets. Raises InputError / CrsError / OptionError
    naming the file or option."""
    from aerotri.core.tolerances import TERRAINS, feature_limit
    from aerotri.geom.crs.definition import crs_label, same_horizontal

    for name in ("match_m", "buffer_m"):
        v = getattr(params, name)
        if not (np.isfinite(v) and v > 0):
            raise OptionError(f"must be a positive number of metres, got {v}", param="--" + name[:-2].replace("_", "-"))
    if params.terrain not in TERRAINS:
        raise OptionError(f"{params.terrain!r}: expected one of {', '.join(TERRAINS)}", param="--terrain")
    limit = feature_limit(params.scale, params.terrain)
    tol = limit.limit_m
    prod, pcrs, p_m = read_layers(product_path)
    ref, rcrs, r_m = read_layers(reference_path)
    if pcrs is not None and rcrs is not None and not same_horizontal(pcrs, rcrs):
        raise CrsError(f"{product_path} is in {crs_label(pcrs)} but {reference_path} in {crs_label(rcrs)}; give both "
                       "in one CRS (aerotri crs transform)")
    unit = p_m if pcrs is not None else r_m
    # the product's own coverage layer (lidarctl vectors) is where it was made from returns: not a layer to compare
    cover = _coverage(prod)
    if cover is None and COVERAGE in ref:
        # trial s94: `check-vectors bgt.gpkg --reference v.gpkg` ran without a word, correctness 77 % for 97 %
        log.warning("%s has no %s layer but %s has: the product (lidarctl vectors' output) is the first argument, the "
                    "reference the --reference; swapped?", product_path, COVERAGE, reference_path)
    shared = [n for n in prod if n in ref and n != COVERAGE]
    layers = list(params.layers) or shared
    for n in layers:
        if n not in prod or n not in ref:
            where = product_path if n not in prod else reference_path
            raise OptionError(f"{where}: no layer {n!r} (layers: {', '.join(prod if n not in prod else ref)})",
                              param="--layer")
    if not layers:
        raise InputError(f"{product_path} and {reference_path} share no layer ({product_path}: "
                         f"{', '.join(prod) or 'none'}; {reference_path}: {', '.join(ref) or 'none'}); the layers are "
                         "compared by name (buildings, roads, ...): rename the reference's")
    _refuse_apart(prod, ref, layers, product_path, reference_path, pcrs, rcrs, unit)
    area = check_area(params.within, ref, rcrs or pcrs, reference_path, unit)
    # what the reference maps: with --within, the area given; else the hulls of its polygons' blocks, to tell the
    # user how much of the product it does not cover (counted as false by the correctness)
    mapped = area if area is not None else reference_hull(ref, 1.0 / unit)
    out = {"product": str(product_path), "reference": str(reference_path), "xy_unit_m": unit,
           "map_scale": params.scale, "terrain": params.terrain, "tolerance_feature_rms_xy_m": tol,
           "tolerance_confirmed": limit.confirmed, "tolerance_source": limit.source, "tolerance_note": limit.note or None,
           "match_m": params.match_m, "buffer_m": params.buffer_m, "within": params.within, "layers": {}}
    offsets = None
    for n in layers:
        P, R = prod[n], ref[n]
        outside = None if mapped is None else int((~_inside(P, mapped)).sum())
        if area is not None:
            P, R = _clip(P, area), _clip(R, area)
        ref_outside = None
        if cover is not None:
            # what the reference maps where the product has no returns is not the product's miss
            before = _size(R)
            P, R = _clip(P, cover), _clip(R, cover)
            ref_outside = (before - _size(R), before)
        kind = (P or R)[0].geom_type if (P or R) else "Polygon"
        if "Polygon" in kind:
            r = area_overlap(P, R)
            r = {"reference_area_m2": r.reference_size * unit**2, "product_area_m2": r.product_size * unit**2,
                 "completeness_pct": r.completeness_pct, "correctness_pct": r.correctness_pct,
                 "n_reference": len(R), "n_product": len(P)}
        elif "Line" in kind:
            r = buffer_overlap(P, R, params.buffer_m / unit)
            r = {"reference_length_m": r.reference_size * unit, "product_length_m": r.product_size * unit,
                 "completeness_pct": r.completeness_pct, "correctness_pct": r.correctness_pct,
                 "n_reference": len(R), "n_product": len(P)}
        else:
            r = {"n_reference": len(R), "n_product": len(P)}
        # produced features (by a point inside each) outside the --within area, or, without it, outside the hulls of
        # the reference polygons' blocks (None: a reference without polygons, no hull)
        r["n_product_outside_reference_area"] = outside
        r["pct_product_outside_reference_area"] = (100.0 * outside / len(prod[n]) if outside is not None and prod[n]
                                                   else None)
        r["n_product_total"] = len(prod[n])
        if ref_outside is not None:
            gone, total = ref_outside
            key = "reference_area_outside_coverage_m2" if "Polygon" in kind else "reference_length_outside_coverage_m"
            r[key] = gone * (unit ** 2 if "Polygon" in kind else unit)
            r["pct_reference_outside_coverage"] = 100.0 * gone / total if total else 0.0
        if n == "buildings":
            shift = map_offset(P, R, OFFSET_CELL_M / unit)
            checked = area if cover is None else (cover if area is None else area.intersection(cover))
            off = point_offsets(prod[n], ref[n], params.match_m / unit, checked,
                                (shift.dx, shift.dy) if shift is not None else (0.0, 0.0))
            # the map's rigid motion against the reference (map - reference), which the corner offsets include
            r.update(map_offset_dx_m=off.moved[0] * unit, map_offset_dy_m=off.moved[1] * unit,
                     map_rotation_deg=off.rotation_deg, map_motion_max_m=off.max_moved * unit)
            tl, tc = off.to_line * unit, off.to_corner * unit
            offsets = off
            r.update(n_corners=len(off.corners), n_reference_corners=off.n_reference_corners,
                     n_matched_corners=len(tc), rms_xy_to_line_m=_rms(tl), rms_xy_corner_m=_rms(tc),
                     rms_x_corner_m=float(np.sqrt(np.mean(tc[:, 0] ** 2))) if len(tc) else None,
                     rms_y_corner_m=float(np.sqrt(np.mean(tc[:, 1] ** 2))) if len(tc) else None,
                     mean_dx_corner_m=float(tc[:, 0].mean()) if len(tc) else None,
                     mean_dy_corner_m=float(tc[:, 1].mean()) if len(tc) else None,
                     max_offset_to_line_m=float(np.hypot(*tl.T).max()) if len(tl) else None)
            rms = r["rms_xy_corner_m"]
            r["within_tolerance"] = None if rms is None or tol is None else bool(rms <= tol)
        out["layers"][n] = r
    return VectorCheck(_record_of(out), out, offsets)


def plot_offsets(check: VectorCheck, prod: dict, ref: dict, path, title: str = "") -> Path:
    """Reference (grey) and produced outlines, the corner-to-corner offset vectors exaggerated, with a key."""
    plt = pyplot()

    result = check.document
    unit = result["xy_unit_m"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(15, 7.5), gridspec_kw={"width_ratios": [2, 1]})
    for name, geoms, colour, lw in (("reference", ref.get("buildings", []), "0.6", 2.0),
                                    ("product", prod.get("buildings", []), "firebrick", 0.8)):
        first = True
        for g in geoms:
            for p in getattr(g, "geoms", [g]):
                for ring in (p.exterior, *p.interiors):
                    xy = np.asarray(ring.coords)
                    ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=lw, label=f"{name} outlines" if first else None)
                    first = False
    off = check.offsets
    r = result["layers"].get("buildings", {})
    if off is not None and len(off.to_corner):
        span = max(np.ptp(off.corners[:, 0]), np.ptp(off.corners[:, 1]), 1.0)
        scale = unit / (0.05 * span)  # a 1 m offset is drawn 5 % of the plot wide
        q = ax.quiver(off.matched_from[:, 0], off.matched_from[:, 1], off.to_corner[:, 0],
                      off.to_corner[:, 1], np.hypot(*off.to_corner.T) * unit, cmap="viridis", angles="xy",
                      scale_units="xy", scale=scale, width=0.004)
        ax.quiverkey(q, 0.85, 0.03, 1.0 / unit, "1 m offset", coordinates="axes")
        fig.colorbar(q, ax=ax, shrink=0.6, label="corner offset (m)")
        tc = off.to_corner * unit
        ax2.scatter(tc[:, 0], tc[:, 1], s=10, c="k", label="corner to corner")
        tl = off.to_line * unit
        ax2.scatter(tl[:, 0], tl[:, 1], s=6, c="tab:orange", alpha=0.6, label="corner to outline")
        tol = result.get("tolerance_feature_rms_xy_m")
        if tol:
            ax2.add_patch(plt.Circle((0, 0), tol, fill=False, ls="--", color="tab:blue",
                                     label=f"tolerance {tol:g} m ({result['map_scale']}, {result['terrain']})"))
        lim = max(1.0, float(np.nanmax(np.abs(np.r_[tc.ravel(), tl.ravel()]))) * 1.1)
        ax2.set_xlim(-lim, lim)
        ax2.set_ylim(-lim, lim)
        ax2.axhline(0, color="0.8", lw=0.5)
        ax2.axvline(0, color="0.8", lw=0.5)
        ax2.set_aspect("equal")
        ax2.set_xlabel("dx (m)")
        ax2.set_ylabel("dy (m)")
        ax2.legend(fontsize=8, loc="upper left")
        ax2.set_title(f"corner RMS {r.get('rms_xy_corner_m') or float('nan'):.2f} m (n={r.get('n_matched_corners')}),"
                      f" to outline {r.get('rms_xy_to_line_m') or float('nan'):.2f} m")
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title or "building corners: offsets product -> reference (exaggerated)")
    fig.tight_layout()
    save_png(fig, path, dpi=90)
    return Path(path)


def _unconfirmed(result: dict) -> str:
    """", unconfirmed: <source>" for a limit not checked against its specification's text (older JSON: none)."""
    if result.get("tolerance_confirmed", True):
        return ""
    return f"; the limit is unconfirmed: {result.get('tolerance_source')}"


def format_report(check: VectorCheck, scale_given: bool = True) -> str:
    """The console text; ``scale_given`` False: the map scale is the default, said so beside its tolerance."""
    result = check.document
    tol = result["tolerance_feature_rms_xy_m"]
    within = result.get("within")
    area = "the hulls of the reference polygons' blocks" if within == "hull" else within
    default = "" if scale_given else " (the default scale: --scale for your map's)"
    lines = [f"line-map check: {result['product']} against {result['reference']}"
             + (f", only inside {area} (--within)" if within else ""),
             f"tolerance for well-defined features ({result['map_scale']}{default}, {result['terrain']}): plan RMS "
             f"{tol} m (judged: the corner-to-corner RMS)" + _unconfirmed(result)]
    if result.get("tolerance_note"):
        lines.append(f"  {result['tolerance_note']}")
    if within or any(r.get("pct_reference_outside_coverage") for r in result["layers"].values()):
        # clipping cuts features: the counts below are of the pieces judged, not of the files' features
        lines.append("counts: the features, or their parts, inside the area checked")
    warnings = []
    for n, r in result["layers"].items():
        comp, corr = r.get("completeness_pct"), r.get("correctness_pct")
        s = f"{n:18s} reference {r['n_reference']:5d}  product {r['n_product']:5d}"
        if comp is not None or corr is not None:
            s += f"  completeness {comp or 0:6.2f} %  correctness {corr or 0:6.2f} %"
        lines.append(s)
        if n == "buildings" and r.get("n_corners"):
            f = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
            verdict = ("" if r["within_tolerance"] is None else
                       f" -> {'within' if r['within_tolerance'] else 'NOT within'} tolerance {tol:g} m"
                       + ("" if result.get("tolerance_confirmed", True) else " (unconfirmed limit)"))
            lines.append(f"  corners {r['n_corners']} (reference {r['n_reference_corners']}), matched "
                         f"{r['n_matched_corners']} (mutually nearest, <= {result['match_m']:g} m): plan RMS "
                         f"corner-to-corner {f(r['rms_xy_corner_m'])} m (x {f(r['rms_x_corner_m'])}, "
                         f"y {f(r['rms_y_corner_m'])}; mean dx {f(r['mean_dx_corner_m'])}, "
                         f"dy {f(r['mean_dy_corner_m'])}){verdict}")
            lines.append(f"  corner-to-outline (every corner to the nearest reference outline; not judged): RMS "
                         f"{f(r['rms_xy_to_line_m'])} m, max {f(r['max_offset_to_line_m'])} m")
            if r.get("map_motion_max_m") is not None and r["map_motion_max_m"] > 0.5 * (tol or result["match_m"]):
                dx, dy = r["map_offset_dx_m"], r["map_offset_dy_m"]
                lines.append(f"  the map lies moved against the reference by dx {dx:+.2f}, dy {dy:+.2f} m (at its corners' "
                             f"centre) and turned {r['map_rotation_deg']:+.2f} deg: its corners up to "
                             f"{r['map_motion_max_m']:.2f} m off; corners were paired across that motion and their "
                             "offsets include it")
        gone = r.get("pct_reference_outside_coverage")
        if gone:
            size = r.get("reference_area_outside_coverage_m2")
            size = f"{size:,.0f} m2" if size is not None else f"{r.get('reference_length_outside_coverage_m', 0):,.0f} m"
            lines.append(f"  {size} of the reference's {n} ({gone:.1f} %) lie "
                         f"outside the product's coverage (where it has returns, its layer {COVERAGE}): left out, "
                         "not counted as missed")
        pct = r.get("pct_product_outside_reference_area")
        if pct is not None and r["n_product_outside_reference_area"]:
            k, total = r["n_product_outside_reference_area"], r["n_product_total"]
            if within:
                lines.append(f"  {k} of {total} produced {n} lie outside --within {within}: left out (the parts "
                             "of others inside it checked)")
            elif pct > OUTSIDE_WARN_PCT:
                warnings.append(
                    f"warning: {k} of {total} {n} of {result['product']} ({pct:.0f} %) lie outside the area "
                    f"{result['reference']} maps (the convex hulls of its polygons' blocks): the correctness counts "
                    f"them as false and the corner-to-outline distances include them; --within hull checks only "
                    f"inside it")
    return "\n".join(lines + warnings)


def check_files(product_path, reference_path, params: VectorCheckSettings = VectorCheckSettings(), json_path=None,
                png_path=None) -> VectorCheck:
    """``check_vectors`` + the JSON and the offset plot (atomic), refusing an input as output."""
    from aerotri.core.atomic import refuse_input_as_output, write_text_atomic

    inputs = [product_path, reference_path] + ([params.within] if params.within not in (None, "hull") else [])
    for opt, p in (("--json", json_path), ("--png", png_path)):
        if p is not None:
            refuse_input_as_output(p, inputs, opt)
    result = check_vectors(product_path, reference_path, params)
    if png_path is not None:
        prod, _, _ = read_layers(product_path)
        ref, _, _ = read_layers(reference_path)
        plot_offsets(result, prod, ref, png_path)
    if json_path is not None:
        write_text_atomic(json_path, result.to_json())
    return result


VECTOR_CHECK = "vector check (check-vectors JSON)"


@dataclasses.dataclass(frozen=True)
class BuildingCornerCheck:
    """The buildings layer of a vector check: corners against their reference (metres, per cent)."""

    n_matched_corners: int
    rms_xy_corner_m: float | None
    rms_xy_to_line_m: float | None
    completeness_pct: float | None
    correctness_pct: float | None


@dataclasses.dataclass(frozen=True)
class VectorCheckRecord:
    """What a check-vectors JSON tells the accuracy report."""

    reference: str
    match_m: float
    buildings: BuildingCornerCheck | None  # None: no buildings layer checked


@dataclasses.dataclass(frozen=True, eq=False)
class VectorCheck:
    """``check_vectors`` / ``check_files``: the typed record (what the chain and the accuracy report read), the JSON
    document (``to_json``; the module doc says what it holds) and the buildings' corner offsets (the plot's;
    None without a buildings layer)."""

    record: VectorCheckRecord
    document: dict
    offsets: CornerOffsets | None

    def to_json(self) -> str:
        """The check-vectors JSON's text (``lidarctl check-vectors --json``, the chain's vectors_check.json)."""
        return json.dumps(self.document, indent=2)


def _record_of(d: dict) -> VectorCheckRecord:
    b = (d.get("layers") or {}).get("buildings")
    opt = {k: (None if b.get(k) is None else float(b[k]))
           for k in ("rms_xy_corner_m", "rms_xy_to_line_m", "completeness_pct", "correctness_pct")} if b else {}
    buildings = BuildingCornerCheck(int(b.get("n_matched_corners") or 0), **opt) if b else None
    return VectorCheckRecord(str(d.get("reference", "?")), float(d.get("match_m", 0.0)), buildings)


def read_vector_check(path) -> VectorCheckRecord:
    """A check-vectors JSON as ``check_files`` wrote it; InputError naming the file when it is not one."""
    from aerotri.core.textio import read_record, record_error

    d = read_record(path, VECTOR_CHECK, 1)
    try:
        return _record_of(d)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, VECTOR_CHECK, exc) from None
