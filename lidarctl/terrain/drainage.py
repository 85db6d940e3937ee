"""Drainage network of a DEM (seed 002 §3.3): depressions, D8 flow, accumulation, Strahler streams, watersheds.

Steps, each O(cells) in memory and global by nature (a cell's flow may depend on the whole raster):
1. Depressions (``condition``), by a priority flood from the raster's edge and the cells next to nodata
   (Barnes et al. 2014), cells taken lowest first (ties: first come first served):
   - ``fill``: a cell not above the one it is reached from is raised to the next float64 above it
     (the epsilon variant): no depressions and no flats remain, every cell drains to the edge, and
     flats drain towards their spill point by the shortest path;
   - ``breach``: a cell below the one it is reached from keeps its height and the path it was reached by
     is lowered to the next float64 below it, back to the spill point (carving, Soille 2004): pits are
     drained by cutting through their rim instead of filling them; equal heights are raised by one float64
     step as in ``fill``.
   The conditioned DEM differs from the input by at most the depth filled or carved (plus float64 steps of
   ~1e-13 m); it is float64 and written as such so that others can reproduce the directions.
2. D8 flow direction (``flow_directions``), ESRI codes: 1 E, 2 SE, 4 S, 8 SW, 16 W, 32 NW, 64 N, 128 NE,
   0 none (only a cell with no valid neighbour). The steepest drop per distance (metres, the diagonal
   sqrt(dx^2 + dy^2)) among the valid neighbours; ties go to the first in the order N, NE, E, SE, S, SW,
   W, NW (pysheds' order). A cell on the raster's edge or next to nodata with no lower neighbour flows
   out, to the first missing neighbour in that order across a side (N, E, S, W), else across a corner.
3. Flow accumulation (``accumulate``): the cells (itself included) draining through each cell, in
   topological order; times the cell area in m2 for the area.
4. Streams: cells whose upstream area is at least ``min_area_m2`` (by default from the DEM,
   ``default_min_area``: twice the cells of the longest straight path across its valid data, the most a
   non-converging sheet of flow down a plane can collect, so a stream is where flow converges; the value
   and the rule are printed, and 0 streams come with the largest upstream area found and a threshold that
   would give streams); Strahler order (a source is 1, two
   or more tributaries of the highest order meeting give that order + 1); segments run from a source or
   a confluence to the next confluence or the outlet (ending on it, so the lines connect); lines through
   the cell centres simplified by Douglas-Peucker (tolerance ``simplify_px`` cells).
5. Watersheds: the cells draining first into each segment (sub-catchments) and into each outlet of the
   network (basins); cells that leave the raster without meeting a stream belong to none.

Memory: about 100 bytes per cell at the peak (measured 96 on 4 M cells, fill or breach, by
bench/eval_drainage.py): 1 M cells ~ 100 MB, a 10 x 10 km DEM at 1 m ~ 10 GB; ``BYTES_PER_CELL``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numba
import numpy as np

from aerotri.core.errors import InputError, OptionError
from aerotri.core.figures import pyplot, save_png

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

METHODS = ("fill", "breach")
# default stream threshold: this many times the cells of the longest straight path across the data
STREAM_PATH_FACTOR = 2.0
BYTES_PER_CELL = 100  # peak RSS per cell, measured by bench/eval_drainage.py (96); for the log

# neighbour k: row and column offset, ESRI code; the order is the tie-breaking order
_DR = np.array([-1, -1, 0, 1, 1, 1, 0, -1], dtype=np.int64)
_DC = np.array([0, 1, 1, 1, 0, -1, -1, -1], dtype=np.int64)
ESRI_CODES = np.array([64, 128, 1, 2, 4, 8, 16, 32], dtype=np.uint8)
CODE_NAMES = {1: "E", 2: "SE", 4: "S", 8: "SW", 16: "W", 32: "NW", 64: "N", 128: "NE"}


# ---------------------------------------------------------------------------------------------------------
# conditioning


@numba.njit(cache=True)
def _heap_push(heap, size, entry):
    """Push ``entry`` (key, seq, index) onto the binary min-heap ``heap`` (key, seq, idx arrays; ``size`` entries,
    ordered by key, then seq); returns the new size."""
    key, seq, idx = heap
    k, s, i = entry
    p = size
    key[p], seq[p], idx[p] = k, s, i
    while p > 0:
        q = (p - 1) >> 1
        if key[q] < key[p] or (key[q] == key[p] and seq[q] < seq[p]):
            break
        key[p], key[q] = key[q], key[p]
        seq[p], seq[q] = seq[q], seq[p]
        idx[p], idx[q] = idx[q], idx[p]
        p = q
    return size + 1


@numba.njit(cache=True)
def _heap_pop(heap, size):
    """The index of the least entry of ``heap`` (``_heap_push``), removed: (index, new size)."""
    key, seq, idx = heap
    top = idx[0]
    size -= 1
    key[0], seq[0], idx[0] = key[size], seq[size], idx[size]
    p = 0
    while True:
        a, b = 2 * p + 1, 2 * p + 2
        m = p
        if a < size and (key[a] < key[m] or (key[a] == key[m] and seq[a] < seq[m])):
            m = a
        if b < size and (key[b] < key[m] or (key[b] == key[m] and seq[b] < seq[m])):
            m = b
        if m == p:
            break
        key[p], key[m] = key[m], key[p]
        seq[p], seq[m] = seq[m], seq[p]
        idx[p], idx[m] = idx[m], idx[p]
        p = m
    return top, size


@numba.njit(cache=True)
def _edge_cell(valid, i, j):
    ny, nx = valid.shape
    if i == 0 or j == 0 or i == ny - 1 or j == nx - 1:
        return True
    for k in range(8):
        if not valid[i + _DR[k], j + _DC[k]]:
            return True
    return False


@numba.njit(cache=True)
def _priority_flood(z, valid, breach):
    ny, nx = z.shape
    n = ny * nx
    out = z.copy()
    zf = out.ravel()
    vf = valid.ravel()
    closed = np.zeros(n, dtype=np.bool_)
    parent = np.full(n if breach else 1, -1, dtype=np.int64)
    n_valid = 0
    for c in range(n):
        if vf[c]:
            n_valid += 1
    key = np.empty(n_valid, dtype=np.float64)
    seq = np.empty(n_valid, dtype=np.int64)
    idx = np.empty(n_valid, dtype=np.int64)
    heap = (key, seq, idx)
    size = 0
    counter = 0
    for i in range(ny):
        for j in range(nx):
            c = i * nx + j
            if vf[c] and _edge_cell(valid, i, j):
                closed[c] = True
                size = _heap_push(heap, size, (zf[c], counter, c))
                counter += 1
    changed = 0
    while size > 0:
        c, size = _heap_pop(heap, size)
        zc = zf[c]
        ci, cj = c // nx, c % nx
        for k in range(8):
            i, j = ci + _DR[k], cj + _DC[k]
            if i < 0 or j < 0 or i >= ny or j >= nx:
                continue
            m = i * nx + j
            if not vf[m] or closed[m]:
                continue
            closed[m] = True
            if breach:
                parent[m] = c
            if breach and zf[m] < zc:
                # carve: the path back to the spill point runs strictly downhill from m
                target = zf[m]
                p = c
                while p >= 0:
                    target = np.nextafter(target, -np.inf)
                    if zf[p] <= target:
                        break
                    zf[p] = target
                    changed += 1
                    p = parent[p]
            elif zf[m] <= zc:
                zf[m] = np.nextafter(zc, np.inf)
                changed += 1
            size = _heap_push(heap, size, (zf[m], counter, m))
            counter += 1
    return out, changed


@dataclasses.dataclass(frozen=True)
class Conditioned:
    dem: np.ndarray  # float64, same unit as the input; NaN = nodata
    method: str
    cells_changed: int
    raised_max: float  # largest rise (fill), in the DEM's unit
    lowered_max: float  # largest cut (breach), in the DEM's unit


def condition(dem: np.ndarray, method: str = "fill") -> Conditioned:
    """The DEM (2-D, NaN = nodata) without depressions and flats: ``fill`` or ``breach`` (module doc)."""
    if method not in METHODS:
        raise OptionError(f"depression handling is one of {', '.join(METHODS)}, got {method!r}", param="--fill/--breach")
    z = np.asarray(dem, dtype=np.float64)
    valid = np.isfinite(z)
    out, changed = _priority_flood(np.where(valid, z, 0.0), valid, method == "breach")
    out[~valid] = np.nan
    d = (out - z)[valid]
    return Conditioned(out, method, int(changed), float(max(d.max(initial=0.0), 0.0)), abs(float(min(d.min(initial=0.0), 0.0))))


# ---------------------------------------------------------------------------------------------------------
# D8, accumulation


@numba.njit(cache=True)  # serial: cheap next to the flood, and parallel compiles for seconds
def _d8(z, valid, dx, dy):
    ny, nx = z.shape
    dist = np.array([dy, math.hypot(dx, dy), dx, math.hypot(dx, dy), dy, math.hypot(dx, dy), dx, math.hypot(dx, dy)])
    codes = np.zeros((ny, nx), dtype=np.uint8)
    for i in range(ny):
        for j in range(nx):
            if not valid[i, j]:
                continue
            best = 0.0
            code = 0
            out_k = -1
            for k in range(8):
                a, b = i + _DR[k], j + _DC[k]
                if a < 0 or b < 0 or a >= ny or b >= nx or not valid[a, b]:
                    # out across a side before out across a corner
                    if out_k < 0 or (out_k % 2 == 1 and k % 2 == 0):
                        out_k = k
                    continue
                s = (z[i, j] - z[a, b]) / dist[k]
                if s > best:
                    best = s
                    code = ESRI_CODES[k]
            if code == 0 and out_k >= 0:
                code = ESRI_CODES[out_k]
            codes[i, j] = code
    return codes


@numba.njit(cache=True)
def _downstream(codes, valid):
    """Flat index of the cell each cell drains into; -1: out of the raster, into nodata, or nodata."""
    ny, nx = codes.shape
    lut = np.full(256, -1, dtype=np.int64)
    for k in range(8):
        lut[ESRI_CODES[k]] = k
    down = np.full(ny * nx, -1, dtype=np.int64)
    for i in range(ny):
        for j in range(nx):
            k = lut[codes[i, j]]
            if k < 0:
                continue
            a, b = i + _DR[k], j + _DC[k]
            if 0 <= a < ny and 0 <= b < nx and valid[a, b]:
                down[i * nx + j] = a * nx + b
    return down


@numba.njit(cache=True)
def _topological(down, valid_flat):
    """Valid cells ordered so that every cell comes before the cell it drains into; accumulation (cells)."""
    n = down.size
    indeg = np.zeros(n, dtype=np.uint8)
    n_valid = 0
    for c in range(n):
        if valid_flat[c]:
            n_valid += 1
            if down[c] >= 0:
                indeg[down[c]] += 1
    order = np.empty(n_valid, dtype=np.int64)
    head, tail = 0, 0
    for c in range(n):
        if valid_flat[c] and indeg[c] == 0:
            order[tail] = c
            tail += 1
    acc = np.zeros(n, dtype=np.float64)
    while head < tail:
        c = order[head]
        head += 1
        acc[c] += 1.0
        d = down[c]
        if d >= 0:
            acc[d] += acc[c]
            indeg[d] -= 1
            if indeg[d] == 0:
                order[tail] = d
                tail += 1
    return order[:tail], acc


def flow_directions(dem: np.ndarray, dx_m: float, dy_m: float) -> np.ndarray:
    """D8 ESRI codes (uint8, 0 on nodata) of a conditioned DEM; ``dx_m``, ``dy_m``: cell size in metres (the
    heights' unit only scales all slopes alike as long as it is one unit)."""
    z = np.asarray(dem, dtype=np.float64)
    valid = np.isfinite(z)
    return _d8(np.where(valid, z, 0.0), valid, float(dx_m), float(dy_m))


def accumulate(codes: np.ndarray, valid: np.ndarray):
    """(downstream flat index, topological order, accumulation in cells as a 2-D float64 array, NaN on nodata)."""
    down = _downstream(codes, valid)
    order, acc = _topological(down, valid.ravel())
    if order.size != int(valid.sum()):
        raise RuntimeError("flow directions with a cycle (a bug: conditioning leaves none)")
    acc = acc.reshape(codes.shape)
    acc[~valid] = np.nan
    return down, order, acc


# ---------------------------------------------------------------------------------------------------------
# streams, segments, watersheds


@numba.njit(cache=True)
def _streams(order, down, stream):
    """Strahler order per stream cell, segment id per stream cell, and the segments' cells (flat indices)
    as (vertices, offsets, downstream segment); a segment's last vertex is the next confluence when it has one."""
    n = down.size
    nmax = np.zeros(n, dtype=np.uint8)
    cnt = np.zeros(n, dtype=np.uint8)
    sin = np.zeros(n, dtype=np.uint8)  # stream cells draining into a cell
    strahler = np.zeros(n, dtype=np.uint8)
    n_stream = 0
    for c in order:
        if not stream[c]:
            continue
        n_stream += 1
        s = 1 if nmax[c] == 0 else nmax[c] + (1 if cnt[c] >= 2 else 0)
        strahler[c] = s
        d = down[c]
        if d >= 0 and stream[d]:
            sin[d] += 1
            if s > nmax[d]:
                nmax[d] = s
                cnt[d] = 1
            elif s == nmax[d]:
                cnt[d] += 1
    seg = np.full(n, -1, dtype=np.int64)
    n_heads = 0
    for c in order:
        if stream[c] and sin[c] != 1:
            n_heads += 1
    verts = np.empty(n_stream + n_heads, dtype=np.int64)
    offsets = np.zeros(n_heads + 1, dtype=np.int64)
    nv = 0
    s_id = 0
    for h in order:  # heads in topological order: upstream segments get the lower ids
        if not (stream[h] and sin[h] != 1):
            continue
        c = h
        while True:
            seg[c] = s_id
            verts[nv] = c
            nv += 1
            d = down[c]
            if d < 0:
                break
            if sin[d] != 1:  # a confluence: the line ends on it
                verts[nv] = d
                nv += 1
                break
            c = d
        s_id += 1
        offsets[s_id] = nv
    seg_down = np.full(n_heads, -1, dtype=np.int64)
    for s in range(n_heads):
        last = verts[offsets[s + 1] - 1]
        if seg[last] != s:
            seg_down[s] = seg[last]
    return strahler, seg, verts[:nv], offsets, seg_down


@numba.njit(cache=True)
def _labels(order, down, seg, seg_outlet):
    """Per cell: the segment it drains into first and the outlet segment of its basin (-1: none)."""
    n = down.size
    sub = np.full(n, -1, dtype=np.int64)
    basin = np.full(n, -1, dtype=np.int64)
    for t in range(order.size - 1, -1, -1):  # downstream cells first
        c = order[t]
        if seg[c] >= 0:
            sub[c] = seg[c]
            basin[c] = seg_outlet[seg[c]]
        elif down[c] >= 0:
            sub[c] = sub[down[c]]
            basin[c] = basin[down[c]]
    return sub, basin


@dataclasses.dataclass(frozen=True)
class Network:
    """Stream segments and their watersheds. Lines in map coordinates; lengths and areas in metres."""

    lines: np.ndarray  # shapely LineStrings (simplified), one per segment
    order: np.ndarray  # Strahler order per segment
    length_m: np.ndarray  # of the simplified line
    upstream_area_m2: np.ndarray  # at the segment's last own cell
    downstream: np.ndarray  # the segment it flows into, -1 at an outlet
    outlet: np.ndarray  # the outlet segment of its network
    strahler: np.ndarray  # 2-D uint8, 0 off the streams
    subcatchment: np.ndarray  # 2-D int64 segment id per cell, -1 none
    basin: np.ndarray  # 2-D int64 outlet segment id per cell, -1 none


def stream_network(acc_cells: np.ndarray, down, order, *, transform, cell_area_m2: float, min_area_m2: float,
                   xy_m: float = 1.0, simplify_px: float = 0.5) -> Network:
    """Streams where the upstream area >= ``min_area_m2`` (module doc); ``transform``: the raster's affine (cell
    centres in map units of ``xy_m`` metres)."""
    import shapely

    shape = acc_cells.shape
    stream = (np.nan_to_num(acc_cells, nan=0.0) * cell_area_m2 >= min_area_m2).ravel()
    strahler, seg, verts, offsets, seg_down = _streams(order, down, stream)
    n_seg = seg_down.size
    seg_outlet = np.arange(n_seg)
    # downstream ids are larger (heads in topological order): resolve outlets from the last segment back
    for s in range(n_seg - 1, -1, -1):
        if seg_down[s] >= 0:
            seg_outlet[s] = seg_outlet[seg_down[s]]
    sub, basin = _labels(order, down, seg, seg_outlet)
    rows, cols = np.divmod(verts, shape[1])
    x = transform.c + (cols + 0.5) * transform.a
    y = transform.f + (rows + 0.5) * transform.e
    counts = np.diff(offsets)
    part = np.repeat(np.arange(n_seg), counts)
    single = counts < 2  # a one-cell segment at the raster's edge: a line needs two vertices
    if single.any():
        x = np.insert(x, offsets[1:][single], x[offsets[1:][single] - 1])
        y = np.insert(y, offsets[1:][single], y[offsets[1:][single] - 1])
        part = np.insert(part, offsets[1:][single], part[offsets[1:][single] - 1])
    lines = shapely.linestrings(x, y, indices=part) if n_seg else np.array([], dtype=object)
    if n_seg and simplify_px > 0:
        lines = shapely.simplify(lines, simplify_px * abs(transform.a), preserve_topology=False)
    acc_flat = np.nan_to_num(acc_cells.ravel())
    last_own = np.where(seg[verts[offsets[1:] - 1]] == np.arange(n_seg), verts[offsets[1:] - 1],
                        verts[np.maximum(offsets[1:] - 2, 0)]) if n_seg else np.zeros(0, int)
    first = verts[offsets[:-1]] if n_seg else np.zeros(0, int)
    return Network(lines=lines, order=strahler[first].astype(np.int64),
                   length_m=shapely.length(lines) * xy_m if n_seg else np.zeros(0),
                   upstream_area_m2=acc_flat[last_own] * cell_area_m2, downstream=seg_down, outlet=seg_outlet,
                   strahler=strahler.reshape(shape), subcatchment=sub.reshape(shape), basin=basin.reshape(shape))


def polygons(labels: np.ndarray, transform):
    """(ids, shapely (Multi)Polygons) of the cells of each label >= 0."""
    import shapely
    from rasterio import features

    lab = labels.astype(np.int32)
    ids, geoms = [], []
    for geom, value in features.shapes(lab, mask=lab >= 0, connectivity=4, transform=transform):
        ids.append(int(value))
        geoms.append(shapely.geometry.shape(geom))
    if not ids:
        return np.zeros(0, int), np.array([], dtype=object)
    ids = np.asarray(ids)
    geoms = np.asarray(geoms, dtype=object)
    uniq, inv = np.unique(ids, return_inverse=True)
    out = np.empty(uniq.size, dtype=object)
    for k in range(uniq.size):
        parts = geoms[inv == k]
        out[k] = parts[0] if parts.size == 1 else shapely.MultiPolygon(list(parts))
    return uniq, out


def default_min_area(valid: np.ndarray, cell_area_m2: float) -> tuple[float, str]:
    """(stream threshold m2, the rule with its numbers) of a DEM's valid cells: ``STREAM_PATH_FACTOR`` times
    the longer side of the valid data's bounding box, in cells, times the cell area. A sheet of flow down a
    plane collects one cell per cell of path, at most about that side; a cell collecting twice as much has
    flow converging on it from more than one path: a channel, on a DEM of any size or resolution."""
    rows, cols = np.nonzero(valid.any(axis=1))[0], np.nonzero(valid.any(axis=0))[0]
    side = int(max(rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1)) if rows.size else 0
    cells = STREAM_PATH_FACTOR * side
    area = cells * cell_area_m2
    return area, (f"from the DEM: {STREAM_PATH_FACTOR:g} x the longer side of its valid data ({side} cells) = "
                  f"{cells:g} cells x {cell_area_m2:.4g} m2, more than a sheet of flow down a plane collects")


def _m2(v: float) -> str:
    return f"{v:,.0f}" if v >= 100 else f"{v:.3g}"


def why_no_streams(acc_cells: np.ndarray, valid: np.ndarray, transform, cell_area_m2: float, min_area_m2: float,
                   xy_unit: str) -> str:
    """Why no cell reached ``min_area_m2`` and what to change: the largest upstream area, where, and a
    threshold below it."""
    a = np.where(valid, np.nan_to_num(acc_cells), 0.0)
    k = int(np.argmax(a))
    r, c = divmod(k, a.shape[1])
    top = float(a.flat[k]) * cell_area_m2
    x = transform.c + (c + 0.5) * transform.a
    y = transform.f + (r + 0.5) * transform.e
    edge = float(np.mean(_edge_mask(valid)[valid])) if valid.any() else 0.0
    suggest = float(f"{0.5 * top:.2g}")
    return (f"0 streams: no cell collects the {_m2(min_area_m2)} m2 threshold; the largest upstream area is {_m2(top)} m2 "
            f"({int(a.flat[k])} cells) at x {x:.2f}, y {y:.2f} {xy_unit}; {100 * edge:.0f} % of the valid cells lie on "
            f"the raster's edge or next to nodata (each an outlet). Flow converges nowhere on that scale (no channel "
            f"this size, or nodata gaps cut the flow short); give --min-area-m2 below {_m2(top)} (e.g. {_m2(suggest)}) "
            f"to trace the smaller flow lines")


def _edge_mask(valid: np.ndarray) -> np.ndarray:
    """Valid cells on the raster's edge or with a nodata neighbour (8-connected)."""
    from scipy import ndimage

    inner = ndimage.binary_erosion(valid, structure=np.ones((3, 3), bool), border_value=0)
    return valid & ~inner


# ---------------------------------------------------------------------------------------------------------
# the command


@dataclasses.dataclass(frozen=True)
class DrainageResult:
    outdir: Path
    files: list
    method: str
    cells: int
    valid_cells: int
    cells_changed: int
    raised_max_m: float
    lowered_max_m: float
    segments: int
    max_order: int
    basins: int
    memory_estimate_mb: float
    min_area_m2: float = float("nan")
    min_area_rule: str = ""  # "given (--min-area-m2)" or the DEM's rule with its numbers
    no_streams: str | None = None  # why 0 streams and what to change
    # with --water: the segments cut at its shores and their length through the water (m); None without
    segments_through_water: int | None = None
    length_through_water_m: float | None = None


FILES = ("conditioned.tif", "flowdir.tif", "accum_cells.tif", "accum_m2.tif", "strahler.tif", "drainage.gpkg",
         "drainage.png", "drainage.json")


def _cog(path, array, profile, nodata, unit=None, description=None):
    from lidarctl.rasters.products import write_cog

    write_cog(path, array, profile["transform"], profile["crs"], unit=unit, description=description, nodata=nodata,
              dtype=None)


@dataclasses.dataclass(frozen=True)
class WaterSplit:
    """The streams cut at water polygons (``split_at_water``): per segment its part on land and its part through
    water (shapely, map coordinates; empty where none) and their lengths (m)."""

    land: list
    water: list
    land_m: np.ndarray
    water_m: np.ndarray


def split_at_water(lines, water_polygons, xy_m: float = 1.0) -> WaterSplit:
    """Each stream line cut at the water polygons (``--water``): a stream enters a lake and stops at its shore, and
    its course across the lake (the flow direction over the filled, flattened water surface: straight lines of the
    fill's epsilon gradient, trial s96 F10) is kept apart, so that the network's topology stays."""
    import shapely

    water = shapely.union_all(list(water_polygons)) if len(water_polygons) else shapely.Polygon()
    land = [ln.difference(water) if not water.is_empty else ln for ln in lines]
    wet = [ln.intersection(water) if not water.is_empty else shapely.LineString() for ln in lines]
    return WaterSplit(land, wet, np.array([g.length * xy_m for g in land], float),
                      np.array([g.length * xy_m for g in wet], float))


def _multi(g):
    import shapely

    if g.is_empty:
        return shapely.MultiLineString()
    if g.geom_type == "LineString":
        return shapely.MultiLineString([g])
    if g.geom_type == "MultiLineString":
        return g
    parts = [p for p in getattr(g, "geoms", []) if p.geom_type == "LineString"]  # (a point where a line grazes a shore)
    return shapely.MultiLineString(parts)


def _write_gpkg(path, net: Network, *, sub_ids, sub_geoms, basin_ids, basin_geoms, crs_wkt, cell_area_m2,
                split: WaterSplit | None = None):
    from aerotri.core.vector_files import VectorLayer, write_layers

    seg = np.arange(len(net.lines))
    sub_cells = np.bincount(net.subcatchment[net.subcatchment >= 0], minlength=len(seg))
    basin_cells = np.bincount(net.basin[net.basin >= 0], minlength=len(seg))
    extra = []
    if split is None:
        streams = VectorLayer("streams", "LineString", net.lines,
                              {"segment": seg, "strahler_order": net.order, "length_m": net.length_m,
                               "upstream_area_m2": net.upstream_area_m2, "downstream_segment": net.downstream,
                               "outlet_segment": net.outlet})
    else:
        on_land = np.array([not g.is_empty for g in split.land], bool)
        streams = VectorLayer("streams", "MultiLineString", [_multi(g) for g, k in zip(split.land, on_land) if k],
                              {"segment": seg[on_land], "strahler_order": net.order[on_land],
                               "length_m": split.land_m[on_land], "upstream_area_m2": net.upstream_area_m2[on_land],
                               "downstream_segment": net.downstream[on_land], "outlet_segment": net.outlet[on_land]})
        wet = np.array([not g.is_empty and g.length > 0 for g in split.water], bool)
        extra = [VectorLayer("through_water", "MultiLineString", [_multi(g) for g, k in zip(split.water, wet) if k],
                             {"segment": seg[wet], "strahler_order": net.order[wet], "length_m": split.water_m[wet]})]
    write_layers(path, [
        streams, *extra,
        VectorLayer("watersheds", "MultiPolygon", sub_geoms,
                    {"segment": sub_ids, "strahler_order": net.order[sub_ids],
                     "area_m2": sub_cells[sub_ids] * cell_area_m2}),
        VectorLayer("basins", "MultiPolygon", basin_geoms,
                    {"outlet_segment": basin_ids, "area_m2": basin_cells[basin_ids] * cell_area_m2})], crs=crs_wkt)


def preview_png(dem, transform, net: Network, path, title: str, *, dx_m: float, xy_unit: str = "") -> None:
    """Streams (width and colour by Strahler order) over the DEM's hillshade, with a key and map axes."""
    plt = pyplot()
    import shapely
    from matplotlib.collections import LineCollection

    from lidarctl.rasters.products import hillshade

    hs = hillshade(dem, dx_m)  # slopes from valid cells only: no rim along nodata to trim
    ny, nx = dem.shape
    extent = (transform.c, transform.c + nx * transform.a, transform.f + ny * transform.e, transform.f)
    h_in = min(12.0, 8.0 * ny / max(nx, 1)) + 0.8
    fig, ax = plt.subplots(figsize=(9, h_in))
    ax.imshow(hs, cmap="gray", extent=extent, vmin=-0.2, vmax=1.0)
    orders = net.order
    top = int(orders.max()) if orders.size else 0
    cmap = plt.get_cmap("cool", max(top, 1))
    for o in range(1, top + 1):
        sel = np.flatnonzero(orders == o)
        if not sel.size:
            continue
        segs = [shapely.get_coordinates(net.lines[s]) for s in sel]
        ax.add_collection(LineCollection(segs, colors=[cmap(o - 1)], linewidths=0.6 + 0.7 * (o - 1),
                                         label=f"order {o} ({sel.size})"))
    if top:
        ax.legend(loc="lower right", fontsize=8, title="Strahler", framealpha=0.8)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_title(title, fontsize=10)
    unit = f" ({xy_unit})" if xy_unit else ""  # a DEM in feet: the axes are feet too
    ax.set_xlabel(f"easting{unit}")
    ax.set_ylabel(f"northing{unit}")
    fig.tight_layout()
    save_png(fig, path, dpi=110)


def drainage(dem_path, outdir, min_area_m2: float | None = None, method: str = "fill", simplify_px: float = 0.5,
             png: bool = True, water_path=None, water_layer: str | None = None) -> DrainageResult:
    """All drainage products of a DEM GeoTIFF in OUTDIR (replaced as a whole, all files or none; FILES).

    Heights and cell sizes are taken to metres by the CRS (a DEM in feet works); the conditioned DEM is
    written in the input's height unit (float64), accumulation in cells and in m2. ``min_area_m2`` None: the
    stream threshold from the DEM (``default_min_area``). ``water_path``: water polygons in the DEM's CRS (lidarctl
    vectors' map, ``lidarctl.terrain.hydro.read_water``): the streams end at their shores, their courses through
    the water in a layer of their own (``split_at_water``)."""
    import json

    from aerotri.core.atomic import atomic_dir
    from aerotri.geom.crs.definition import height_unit_m, linear_unit_m, unit_long_name, unit_name
    from aerotri.geom.crs.height_rasters import refuse_above_ground
    from lidarctl.terrain.dem_io import open_dem

    if method not in METHODS:
        raise OptionError(f"depression handling is one of {', '.join(METHODS)}, got {method!r}", param="--fill/--breach")
    if min_area_m2 is not None and not (np.isfinite(min_area_m2) and min_area_m2 > 0):
        raise OptionError(f"the stream threshold must be a positive area in m2, got {min_area_m2}", param="--min-area-m2")
    if not (np.isfinite(simplify_px) and simplify_px >= 0):
        raise OptionError(f"the simplification tolerance is cells >= 0, got {simplify_px}", param="--simplify-px")
    dem_path, outdir = Path(dem_path), Path(outdir)
    if outdir.resolve() in dem_path.resolve().parents:
        raise OptionError(f"{outdir}: OUTDIR holds the input {dem_path} and is replaced as a whole; choose another "
                          "folder", param="OUTDIR")
    if outdir.exists() and (not outdir.is_dir() or any(p.name not in FILES for p in outdir.iterdir())):
        raise OptionError(f"{outdir}: OUTDIR must be a new folder or a previous drainage output (it is replaced as "
                          f"a whole; it holds other files)", param="OUTDIR")
    src, z_m = open_dem(dem_path, outdir / "conditioned.tif", say_unit=True)
    with src:
        refuse_above_ground(src, dem_path, "drainage needs a DEM of the ground (lidarctl rasters' dem.tif)")
        crs = src.crs
        xy_m = linear_unit_m(crs)
        if not np.isfinite(xy_m):
            raise InputError(f"{dem_path}: a DEM in a geographic CRS ({crs}); drainage needs a projected CRS "
                             "(cell sizes in metres or feet)")
        dem = src.read(1, masked=True).astype(np.float64).filled(np.nan)
        transform = src.transform
        profile = dict(driver="GTiff", width=src.width, height=src.height, count=1, crs=crs, transform=transform)
        band_unit = src.units[0] if src.units and src.units[0] else None
    valid = np.isfinite(dem)
    if not valid.any():
        raise InputError(f"{dem_path}: no valid cells (all nodata)")
    dx_m, dy_m = abs(transform.a) * xy_m, abs(transform.e) * xy_m
    cell_area_m2 = dx_m * dy_m
    mem_mb = dem.size * BYTES_PER_CELL / 1e6
    log.info(f"{dem_path}: {dem.shape[1]} x {dem.shape[0]} cells, about {mem_mb:,.0f} MB at the peak")
    if min_area_m2 is None:
        min_area_m2, rule = default_min_area(valid, cell_area_m2)
    else:
        rule = "given (--min-area-m2)"
    log.debug(f"stream threshold {min_area_m2:.4g} m2: {rule}")
    cond = condition(dem * z_m, method)  # metres: the slopes compare heights with distances in metres
    codes = flow_directions(cond.dem, dx_m, dy_m)
    down, order, acc = accumulate(codes, valid)
    net = stream_network(acc, down, order, transform=transform, cell_area_m2=cell_area_m2, min_area_m2=min_area_m2,
                         xy_m=xy_m, simplify_px=simplify_px)
    none = (why_no_streams(acc, valid, transform, cell_area_m2, min_area_m2, unit_long_name(crs))
            if not len(net.lines) else None)
    split = None
    if water_path is not None:
        import pyproj

        from lidarctl.terrain.hydro import read_water

        water, _, _ = read_water(water_path, pyproj.CRS.from_wkt(crs.to_wkt()), water_layer)
        split = split_at_water(list(net.lines), water, xy_m)
    sub_ids, sub_geoms = polygons(net.subcatchment, transform)
    basin_ids, basin_geoms = polygons(net.basin, transform)
    summary = {"dem": str(dem_path), "method": method, "min_area_m2": min_area_m2, "min_area_rule": rule,
               "no_streams": none, "cells": int(dem.size),
               "valid_cells": int(valid.sum()), "cell_area_m2": cell_area_m2,
               "cells_changed": cond.cells_changed, "raised_max_m": cond.raised_max, "lowered_max_m": cond.lowered_max,
               "segments": int(len(net.lines)), "max_strahler_order": int(net.order.max(initial=0)),
               "segments_per_order": {str(o): int((net.order == o).sum()) for o in np.unique(net.order)},
               "basins": int(len(basin_ids)), "stream_length_m": float(net.length_m.sum()),
               "memory_estimate_mb": round(mem_mb, 1),
               "flowdir_codes": {str(k): v for k, v in CODE_NAMES.items()}}
    if split is not None:
        summary.update(water=str(water_path), segments_through_water=int(sum(m > 0 for m in split.water_m)),
                       length_through_water_m=float(split.water_m.sum()),
                       segments_only_in_water=int(sum(g.is_empty for g in split.land)))
    with atomic_dir(outdir) as tmp:
        cdem = np.where(valid, cond.dem / z_m, -9999.0)
        _cog(tmp / "conditioned.tif", cdem, profile, -9999.0, band_unit or unit_long_name(crs),
             f"DEM, depressions {'filled' if method == 'fill' else 'breached'}")
        _cog(tmp / "flowdir.tif", np.where(valid, codes, 255).astype(np.uint8), profile, 255, None,
             "D8 flow direction, ESRI codes 1 E 2 SE 4 S 8 SW 16 W 32 NW 64 N 128 NE")
        _cog(tmp / "accum_cells.tif", np.where(valid, acc, 0).astype(np.uint32), profile, 0, None,
             "flow accumulation, cells (the cell itself included)")
        _cog(tmp / "accum_m2.tif", np.where(valid, acc * cell_area_m2, -1.0), profile, -1.0, "square metre",
             "upstream area, m2")
        _cog(tmp / "strahler.tif", np.where(valid, net.strahler, 255).astype(np.uint8), profile, 255, None,
             "Strahler order of the stream cells, 0 off the streams")
        _write_gpkg(tmp / "drainage.gpkg", net, sub_ids=sub_ids, sub_geoms=sub_geoms, basin_ids=basin_ids,
                    basin_geoms=basin_geoms, crs_wkt=crs.to_wkt(), cell_area_m2=cell_area_m2, split=split)
        if png:
            preview_png(dem * z_m, transform, net, tmp / "drainage.png",
                        f"{dem_path.name}: streams >= {min_area_m2:g} m2 ({method}), {len(net.lines)} segments",
                        dx_m=dx_m, xy_unit=unit_name(crs))
        (tmp / "drainage.json").write_text(json.dumps(summary, indent=2))
        files = sorted(p.name for p in tmp.iterdir())
    log.debug(f"{dem_path} -> {outdir}: {summary}")
    return DrainageResult(outdir, [outdir / f for f in files], method, int(dem.size), int(valid.sum()),
                          cond.cells_changed, cond.raised_max, cond.lowered_max, int(len(net.lines)),
                          int(net.order.max(initial=0)), int(len(basin_ids)), mem_mb, float(min_area_m2), rule, none,
                          summary.get("segments_through_water"), summary.get("length_through_water_m"))
