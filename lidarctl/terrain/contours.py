"""Contour lines from a DEM (seed 002 §3.1: interpolate, trace, fit), with optional smoothing.

Tracing: marching squares on the cell centres (contourpy, C++), linear interpolation along the cell
edges, cut cleanly where the DEM has nodata (masked cells); a contour that comes back to its start is
closed. A cell exactly at a level (contourpy counts it below the level) is traced ``LEVEL_NUDGE`` x interval
lower: each of its edges to a higher neighbour would put a vertex on its centre, where two lines (or one twice)
touch; lowered, the lines keep their course and pass a hair from it (``LEVEL_NUDGE`` x interval / the height step to
the neighbour, of a cell: under 1 mm on the demo's DEM at 0.5 m cells), so traced contours never meet.
Levels are whole multiples of the interval. The option gives it in metres, as every length
option (``--interval-m``); it is converted to the DEM's height unit (the unit of its CRS) to 10 significant
digits, so 0.3048 m on a DEM in feet (0.3048006096 m in US survey feet) gives levels at whole feet; every
``index_every``-th level is an index contour.
The work is bounded by the data, not by the interval: before tracing, the number of vertices the levels
would make is counted exactly from the DEM (each level crossing a cell edge is one vertex, so it is the
sum over the edges of |dz| / interval); more than ``MAX_VERTICES_PER_CELL`` per valid cell (adjacent
levels closer than a cell apart on average: not a readable map, and the work would grow without bound as
the interval shrinks) is refused naming the option and the smallest interval that fits.

Smoothing (fit) of each traced line:
- ``bspline``: an approximating cubic B-spline (scipy ``splprep``; periodic for closed lines) whose
  RMS distance from the traced vertices is about ``tolerance_px`` cells, resampled at half-cell steps;
- ``tension``: a spline under tension through the traced vertices (Cline 1974's exponential spline,
  evaluated per coordinate against chord length; ``tension`` 0 is a cubic spline, large values tend to
  the polyline), resampled the same way;
- ``none``: the traced polyline.
A smoothed line that crosses itself or a neighbouring contour (shapely, against the lines of the
levels next to it), or leaves the DEM's valid-data footprint (the union of its valid cells,
``data_footprint``; an approximating spline can cut outside near the border or a nodata edge) falls
back to the traced line, which never crosses and stays on the cell centres: contours stay topologically
valid and inside the data, and how many fell back is reported.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from aerotri.core.errors import OptionError
from aerotri.core.figures import pyplot, save_png

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

SMOOTHING = ("none", "bspline", "tension")
MAX_VERTICES_PER_CELL = 2.0  # contour vertices per valid DEM cell above which an interval is refused
# a contour whose extent is under this share of a cell is a level grazing one cell's height (a cell a hair above the
# level among lower ones rings its centre at that hair), below the DEM's resolution: not drawn. A tenth of the
# resolution, not fitted to a data set (new-user trial, Autzen's DEM in feet, 3.28 ft cells, 2 ft interval: 27 of 540
# lines, the smallest 0.001 ft across at 428 ft, one smoothed to a single point; lidR Topography, 1 m, hydro-flattened:
# 42 of 781)
MIN_EXTENT_CELLS = 0.1
# a closed contour enclosing fewer cells than this is a hill or pit the DEM does not resolve (its ring is drawn by one
# or two cells' heights: a return's noise, a post, a bush the ground filter left), cartographic noise on a map: left
# out by default (``--min-ring-cells``). 2 x 2 cells, not fitted to a data set (trial s98 L8: lidR Topography, 1 m
# DEM, 1 m interval: 406 of 589 contours closed rings under 10 m long, median 3.3 m)
MIN_RING_CELLS = 4.0
LEVEL_NUDGE = 1e-7  # a cell exactly at a level is traced this many intervals lower (below it, as contourpy counts it)


@dataclasses.dataclass(frozen=True)
class Contour:
    level: float  # in the DEM's height unit
    index: bool
    closed: bool
    xy: np.ndarray  # (N, 2) map coordinates; a closed line repeats its first vertex at the end


@dataclasses.dataclass(frozen=True)
class ContourSet:
    contours: list
    interval: float  # in the DEM's height unit
    smoothing: str
    fell_back: int  # smoothed lines replaced by the traced line (a crossing)


def _level_multiples(z, interval) -> np.ndarray:
    """The integers k of the levels k x interval within the DEM's range."""
    lo, hi = np.nanmin(z), np.nanmax(z)
    return np.arange(np.ceil(lo / interval), np.floor(hi / interval) + 1.0)


def _level(k: float, interval: float) -> float:
    """k x interval without the binary noise of the product (0.1 x 3 is 0.3, not 0.30000000000000004)."""
    digits = max(0, 10 - int(np.floor(np.log10(interval))))
    return float(round(k * interval, digits))


def _nice_at_least(v: float) -> float:
    """The smallest 1, 2 or 5 x 10^n not below ``v``."""
    e = 10.0 ** np.floor(np.log10(v))
    return float(next(m * e for m in (1.0, 2.0, 5.0, 10.0) if m * e >= v * (1 - 1e-12)))


def _off_the_levels(z: np.ndarray, interval: float) -> tuple[np.ndarray, np.ndarray]:
    """``z`` (NaN = nodata) with every cell exactly at a level (``_level``, the value traced) lowered by
    ``LEVEL_NUDGE`` x ``interval``, and the mask of those cells."""
    with np.errstate(invalid="ignore"):
        k = np.rint(z / interval)
        near = np.flatnonzero(np.isfinite(z) & (np.abs(z / interval - k) < 1e-6))
    exact = np.zeros(z.shape, bool)
    if near.size:
        ks, inverse = np.unique(k.flat[near], return_inverse=True)
        levels = np.array([_level(kk, interval) for kk in ks])[inverse]
        exact.flat[near[z.flat[near] == levels]] = True
    out = z.copy()
    out[exact] -= LEVEL_NUDGE * interval
    return out, exact


def _at_exact_cells(line: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """``line`` (cell coordinates, centres at i + 0.5) with each vertex nearest the centre of an ``exact`` cell put
    back on that centre: where it is traced without the nudge (``_off_the_levels``)."""
    ij = np.rint(line - 0.5).astype(np.int64)  # (col, row) of the nearest centre
    ny, nx = exact.shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
    snap = np.zeros(len(line), bool)
    snap[inside] = exact[ij[inside, 1], ij[inside, 0]]
    out = line.copy()
    out[snap] = ij[snap] + 0.5
    return out


def vertex_count(dem: np.ndarray, interval: float) -> float:
    """The number of contour vertices the levels k x ``interval`` make on ``dem`` (NaN = nodata): each level
    crossing a cell edge between two valid cell centres is one vertex, so the count is the sum over those
    edges of the number of multiples of the interval between their ends (exact, O(cells))."""
    dem = np.asarray(dem, dtype=np.float64)
    finite = np.isfinite(dem)
    with np.errstate(over="ignore", invalid="ignore"):
        z = dem / interval
    if not np.all(np.isfinite(z[finite])):
        return float("inf")  # heights / interval beyond the float range: unbounded
    n = 0.0
    for a, b in ((z[:, 1:], z[:, :-1]), (z[1:, :], z[:-1, :])):
        ok = np.isfinite(a) & np.isfinite(b)
        lo, hi = np.minimum(a[ok], b[ok]), np.maximum(a[ok], b[ok])
        n += float(np.maximum(np.floor(hi) - np.ceil(lo) + 1.0, 0.0).sum())
    return n if np.isfinite(n) else float("inf")


def check_interval(dem: np.ndarray, interval: float, unit: str = "", option: str = "--interval-m",
                   unit_m: float = 1.0) -> float:
    """The vertex count of ``interval`` (in the DEM's height ``unit`` of ``unit_m`` metres) on ``dem``;
    ``OptionError`` naming ``option`` (a value in metres) when it exceeds ``MAX_VERTICES_PER_CELL`` per valid
    cell, with the smallest interval that fits."""
    valid = int(np.isfinite(dem).sum())
    n = vertex_count(dem, interval)
    limit = MAX_VERTICES_PER_CELL * max(valid, 1)
    if n > limit:
        # the smallest 1-2-5 interval that fits: the count scales about as 1 / interval; start there (or, for
        # an overflowing count, from the relief: the sum of |dz| over the edges per allowed vertex) and step up
        if np.isfinite(n):
            need = _nice_at_least(interval * n / limit)
        else:
            z = np.asarray(dem, dtype=np.float64)
            relief = np.nansum(np.abs(np.diff(z, axis=0))) + np.nansum(np.abs(np.diff(z, axis=1)))
            need = _nice_at_least(max(relief / limit, 1e-9))
        while vertex_count(dem, need) > limit:
            need = _nice_at_least(need * 1.5)
        u = f" {unit}" if unit else ""
        raise OptionError(f"a contour interval of {interval:g}{u} gives about {n:.3g} contour vertices on this DEM of "
                          f"{valid:,} valid cells (more than {MAX_VERTICES_PER_CELL:g} per cell: adjacent levels less "
                          f"than a cell apart); give an interval of at least {need:g}{u} (the DEM's height unit): "
                          f"{option} {need * unit_m:.10g}",
                          param=option)
    return n


def trace(dem: np.ndarray, transform, interval: float, index_every: int = 5, option: str = "--interval-m") -> list:
    """Contours of ``dem`` (2-D, NaN = nodata; heights in any unit, ``interval`` in the same) with map
    coordinates from the affine ``transform`` (cell centres); levels at whole multiples of ``interval``.
    An interval that would make more than ``MAX_VERTICES_PER_CELL`` vertices per valid cell is refused
    (``check_interval``; ``option`` names it) before any tracing. Contours less than ``MIN_EXTENT_CELLS`` of a cell
    across are left out (``trace_counted`` says how many)."""
    return trace_counted(dem, transform, interval, index_every, option)[0]


def trace_counted(dem: np.ndarray, transform, interval: float, index_every: int = 5,
                  option: str = "--interval-m") -> tuple[list, int]:
    """``trace`` and the number of contours left out for being under ``MIN_EXTENT_CELLS`` of a cell across."""
    import contourpy

    z = np.ma.masked_invalid(np.asarray(dem, dtype=np.float64))
    if z.count() == 0:
        return [], 0
    check_interval(z.filled(np.nan), interval, option=option)
    ny, nx = z.shape
    cols, rows = np.arange(nx) + 0.5, np.arange(ny) + 0.5
    off, exact = _off_the_levels(z.filled(np.nan), interval)
    gen = contourpy.contour_generator(cols, rows, np.ma.masked_invalid(off), name="serial",
                                      line_type=contourpy.LineType.Separate, corner_mask=True)
    a, b, c, d, e, f = transform.a, transform.b, transform.c, transform.d, transform.e, transform.f
    out, tiny = [], 0
    for kf in _level_multiples(z.filled(np.nan), interval):
        k, level = int(kf), _level(kf, interval)
        for line in gen.lines(level):
            # a cell exactly at the level among lower (or higher) ones gives a "line" of one point repeated:
            # no contour, and an invalid geometry in a GeoPackage; lowered by the nudge, one among higher ones
            # gives a ring a hair wide around its centre instead: judged where it is traced without the nudge
            if len(line) < 2 or not np.ptp(_at_exact_cells(line, exact) if exact.any() else line, axis=0).any():
                continue
            if np.ptp(line, axis=0).max() < MIN_EXTENT_CELLS:
                tiny += 1
                continue
            # closed in cell coordinates, exactly: contourpy repeats a ring's first point, while an open line
            # from the border back to it may end a fraction of a cell from its start (np.allclose's relative
            # tolerance on map coordinates of 10^5..10^6 m would call ends metres apart the same point)
            closed = len(line) > 3 and bool(np.all(np.abs(line[0] - line[-1]) <= 1e-9))
            x = a * line[:, 0] + b * line[:, 1] + c
            y = d * line[:, 0] + e * line[:, 1] + f
            xy = np.column_stack([x, y])
            out.append(Contour(float(level), index_every > 0 and k % index_every == 0, closed, xy))
    return out, tiny


def ring_area(xy: np.ndarray) -> float:
    """The area a closed line (N, 2; its first vertex repeated at the end) encloses, in its units squared."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * abs(float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1])))


def without_small_rings(contours: list, min_area: float) -> tuple[list, int]:
    """``contours`` without the closed ones enclosing less than ``min_area`` (the map's units squared), and how many
    were left out. Open lines are kept whatever their length (they end at nodata or the DEM's edge)."""
    if min_area <= 0:
        return list(contours), 0
    kept = [c for c in contours if not (c.closed and ring_area(c.xy) < min_area)]
    return kept, len(contours) - len(kept)


def _resample_param(xy, step):
    seg = np.hypot(*np.diff(xy, axis=0).T)
    t = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(np.ceil(t[-1] / step)) + 1, 4)
    return t, np.linspace(0.0, t[-1], n)


def _bspline(xy, closed, tolerance, step):
    from scipy.interpolate import splev, splprep

    pts = xy[:-1] if closed else xy
    if len(pts) < 5:
        return xy
    keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-9])
    pts = pts[keep]
    if len(pts) < 5:
        return xy
    try:
        tck, u = splprep([pts[:, 0], pts[:, 1]], s=len(pts) * tolerance ** 2, per=1 if closed else 0, k=3)
    except (ValueError, TypeError):
        return xy
    _, uu = _resample_param(xy, step)
    uu = np.linspace(0.0, 1.0, len(uu))
    x, y = splev(uu, tck)
    out = np.column_stack([x, y])
    if closed:
        out[-1] = out[0]
    else:
        out[0], out[-1] = xy[0], xy[-1]  # an open line keeps its ends on the nodata edge or the border
    return out


def _sinh_ratio(a, b):
    """sinh(a) / sinh(b) for 0 <= a <= b, b > 0, without overflow (a segment many times the median chord gives
    tau * h in the hundreds: sinh overflows to inf and the spline to NaN; new-user trial, Autzen's DEM in feet)."""
    return np.exp(a - b) * np.expm1(-2.0 * a) / np.expm1(-2.0 * b)


def _tension_1d(t, v, tau, tt):
    """Cline's spline under tension through (t, v), evaluated at tt (natural end conditions)."""
    n = len(t)
    h = np.diff(t)
    x = tau * h
    # second-derivative-like moments M solve a tridiagonal system (Cline 1974, eq. for the exponential spline);
    # tau / sinh(x) and tau cosh(x) / sinh(x) written with exp(-x) and tanh, finite for any x > 0
    alpha = 1.0 / h - tau * 2.0 * np.exp(-x) / -np.expm1(-2.0 * x)
    beta = tau / np.tanh(x) - 1.0 / h
    from scipy.linalg import solve_banded

    ab = np.zeros((3, n))  # the tridiagonal system in banded form: super-, main and sub-diagonal
    rhs = np.zeros(n)
    ab[1, 0] = ab[1, -1] = 1.0  # natural ends: no curvature at the first and last vertex
    ab[1, 1:-1] = beta[:-1] + beta[1:]
    ab[0, 2:] = alpha[1:]
    ab[2, :-2] = alpha[:-1]
    rhs[1:-1] = np.diff(v) [1:] / h[1:] - np.diff(v)[:-1] / h[:-1]
    M = solve_banded((1, 1), ab, rhs * tau ** 2)
    i = np.clip(np.searchsorted(t, tt, side="right") - 1, 0, n - 2)
    hi, a_, b_ = h[i], np.clip(tt - t[i], 0.0, None), np.clip(t[i + 1] - tt, 0.0, None)
    return ((M[i] * _sinh_ratio(tau * b_, tau * hi) + M[i + 1] * _sinh_ratio(tau * a_, tau * hi)) / tau ** 2
            + (v[i] - M[i] / tau ** 2) * b_ / hi + (v[i + 1] - M[i + 1] / tau ** 2) * a_ / hi)


def _tension(xy, closed, tension, step):
    keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 1e-9])
    pts = xy[keep]
    if len(pts) < 4:
        return xy
    t, tt = _resample_param(pts, step)
    tau = max(tension, 1e-3) / max(np.median(np.diff(t)), 1e-9)  # tension per unit chord length
    out = np.column_stack([_tension_1d(t, pts[:, 0], tau, tt), _tension_1d(t, pts[:, 1], tau, tt)])
    out[0], out[-1] = pts[0], pts[-1]
    return out


def data_footprint(valid: np.ndarray, transform):
    """The union of the valid cells (``valid``: 2-D bool) as a shapely (Multi)Polygon in map coordinates."""
    import shapely
    from rasterio import features

    parts = [shapely.geometry.shape(g) for g, v in features.shapes(valid.astype(np.uint8), transform=transform)
             if v == 1]
    return shapely.union_all(parts) if parts else shapely.Polygon()


def smooth_contours(contours: list, method: str, cell: float, tolerance_px: float = 0.5,
                    tension: float = 1.0, footprint=None) -> tuple[list, int]:
    """Smoothed copies of ``contours`` (``method`` in SMOOTHING; ``cell``: the DEM cell size in map units);
    lines whose smoothed form crosses itself or a contour of the same or a neighbouring level, shrinks to under half
    its traced extent (a small ring fitted by its centre), or is not covered by ``footprint`` (shapely geometry,
    ``data_footprint``; None: not checked), keep their traced form. Returns (contours, number that fell back)."""
    if method not in SMOOTHING:
        raise OptionError(f"unknown smoothing {method!r}; expected one of {', '.join(SMOOTHING)}", param="--smooth")
    if method == "none" or not contours:
        return list(contours), 0
    import shapely
    from shapely import LineString

    step = 0.5 * cell
    smoothed = []
    for c in contours:
        xy = (_bspline(c.xy, c.closed, tolerance_px * cell, step) if method == "bspline"
              else _tension(c.xy, c.closed, tension, step))
        smoothed.append(dataclasses.replace(c, xy=xy))
    traced = [LineString(c.xy) for c in contours]
    lines = [LineString(c.xy) for c in smoothed]
    levels = np.array([c.level for c in contours])
    rank = np.searchsorted(np.unique(levels), levels)
    n = len(lines)
    # One pass suffices: traced lines never cross, so a smoothed line that meets neither the traced nor the
    # smoothed form of any line of its own or the neighbouring levels stays clear whichever form those keep.
    ok = np.array([ln.is_simple for ln in lines])
    # a closed line smaller than the tolerance fits it by shrinking to its centre (an approximating spline's RMS
    # distance is met by a point): the smoothed form must keep at least half the traced line's extent
    extent = np.array([[np.ptp(c.xy, axis=0).max(), np.ptp(d.xy, axis=0).max()] for c, d in zip(contours, smoothed)])
    ok &= extent[:, 1] >= 0.5 * extent[:, 0]
    if footprint is not None:
        # a hair of slack: vertices pinned on the footprint's boundary must not fail on rounding
        ok &= shapely.covered_by(lines, shapely.buffer(footprint, 1e-6 * cell, join_style="mitre"))
    tree = shapely.STRtree(lines + traced)
    for i in np.flatnonzero(ok):
        for j in tree.query(lines[i], predicate="intersects"):
            k = int(j) % n
            if k != i and abs(int(rank[k]) - int(rank[i])) <= 1:
                ok[i] = False
                break
    out = [smoothed[i] if ok[i] else contours[i] for i in range(n)]
    return out, int((~ok).sum())


def crossings(contours: list) -> int:
    """Pairs of contours that cross or touch (different lines) plus lines that cross themselves."""
    import shapely
    from shapely import LineString

    lines = [LineString(c.xy) for c in contours]
    bad = sum(0 if ln.is_simple else 1 for ln in lines)
    tree = shapely.STRtree(lines)
    for i, ln in enumerate(lines):
        for j in tree.query(ln, predicate="intersects"):
            if j > i:
                bad += 1
    return bad


def write_contours(cs: ContourSet, path, crs, z_unit_name: str, z_unit_m: float) -> Path:
    """A GeoPackage (or GeoJSON, by the suffix) layer ``contours``: elevation (DEM unit), elevation_m, index,
    closed; written atomically."""
    import shapely

    from aerotri.core.vector_files import VectorLayer, write_layers

    path = Path(path)
    if path.suffix.lower() not in (".gpkg", ".geojson", ".json"):
        raise OptionError(f"{path}: the output must end in .gpkg or .geojson", param="OUT")
    fields = {"elevation": np.array([c.level for c in cs.contours], float),
              "elevation_m": np.array([c.level * z_unit_m for c in cs.contours], float),
              "index": np.array([c.index for c in cs.contours], bool),
              "closed": np.array([c.closed for c in cs.contours], bool)}
    return write_layers(path, [VectorLayer("contours", "LineString", [shapely.LineString(c.xy) for c in cs.contours],
                                           fields)], crs=crs)


def preview_png(cs: ContourSet, dem: np.ndarray, transform, path, title: str = "", xy_unit: str = "", *,
                z_unit_m: float = 1.0, xy_unit_m: float = 1.0) -> Path:
    """Contours (index lines thicker) over the DEM's hillshade; axes in the CRS's unit ``xy_unit`` (ft, m).
    ``z_unit_m``, ``xy_unit_m``: metres per height / grid unit, so that the slopes are true where they differ."""
    plt = pyplot()
    from lidarctl.rasters.products import hillshade

    # slopes from valid cells only: no rim along nodata to trim; in metres over metres (trial-lidar: a DEM of
    # heights in metres on a foot grid was shaded 3.28x flatter than the same DEM in feet, one in US feet on a
    # metre grid 3.28x steeper)
    ratio = z_unit_m / xy_unit_m
    hs = hillshade(dem * ratio if ratio != 1.0 else dem, abs(transform.a))
    ny, nx = dem.shape
    extent = (transform.c, transform.c + nx * transform.a, transform.f + ny * transform.e, transform.f)
    h_in = min(12.0, 8.0 * ny / max(nx, 1)) + 0.8
    fig, ax = plt.subplots(figsize=(9, h_in))
    ax.imshow(hs, cmap="gray", extent=extent, vmin=-0.2, vmax=1.0)
    for c in cs.contours:
        ax.plot(c.xy[:, 0], c.xy[:, 1], color="#8b4513", lw=1.0 if c.index else 0.4)
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_title(title or f"contours every {cs.interval:g} (index every {5 * cs.interval:g}; DEM height unit), "
                          f"{cs.smoothing}")
    unit = f" ({xy_unit})" if xy_unit else ""  # a DEM in feet: the axes are feet too
    ax.set_xlabel(f"easting{unit}")
    ax.set_ylabel(f"northing{unit}")
    fig.tight_layout()
    save_png(fig, path, dpi=110)
    return Path(path)


@dataclasses.dataclass(frozen=True)
class ContoursResult:
    """What ``contours_from_file`` wrote: lines, levels, closed and index lines, the smoothing and the lines kept
    traced to avoid crossings, the crossings left (0), the interval in the DEM's height ``unit`` (metres per unit),
    the lowest and highest level (None without a line), the files (the contours, then the PNG when made) and how many
    contours were left out for being under a tenth of a cell across, and how many closed ones for enclosing fewer than
    ``min_ring_cells`` cells."""

    contours: int
    levels: int
    closed: int
    index_contours: int
    smoothing: str
    fell_back_to_traced: int
    crossings: int
    interval: float
    unit: str
    metres_per_unit: float
    lowest_level: float | None
    highest_level: float | None
    files: tuple[str, ...]
    under_a_tenth_of_a_cell: int = 0  # contours left out: less than ``MIN_EXTENT_CELLS`` of a cell across
    cut_at_water: int = 0  # contours that crossed the water polygons given (``--water``), cut at their outlines
    small_rings: int = 0  # closed contours left out: enclosing fewer than ``min_ring_cells`` cells
    min_ring_cells: float = 0.0


def pieces_outside(lines: list, polygons: list) -> list[tuple[int, object]]:
    """(index of the line, piece) of each shapely line's parts outside the union of ``polygons``, in order: a line
    that misses them whole, and each part of one they cut (a map's contours stop at the shore)."""
    import shapely

    if not polygons:
        return list(enumerate(lines))
    lake = shapely.union_all(polygons)
    shapely.prepare(lake)
    out = []
    for k, line in enumerate(lines):
        if not lake.intersects(line):
            out.append((k, line))
            continue
        out += [(k, piece) for piece in shapely.get_parts(shapely.line_merge(line.difference(lake)))
                if piece.length > 0]
    return out


def cut_at_water(contours: list, polygons: list) -> tuple[list, int]:
    """``contours`` (``Contour``) cut at the water ``polygons`` and their pieces inside left out; with the number
    of contours cut."""
    import shapely

    lines = [shapely.LineString(c.xy) for c in contours]
    kept = pieces_outside(lines, polygons)
    out = [dataclasses.replace(contours[k], closed=bool(piece.is_closed), xy=np.asarray(piece.coords)[:, :2])
           for k, piece in kept]
    whole = {k for k, piece in kept if piece.length == lines[k].length}
    return out, len(contours) - len(whole)


def whole_unit_interval(interval_m: float, unit_m: float) -> float:
    """The contour interval in the DEM's height unit (``unit_m`` metres): ``length_in_units``, snapped to a whole
    number of units (or 1/2, 1/4, 1/5, 1/10 of one) when within ``lidarctl.units.WHOLE_UNIT_SHARE`` of it and the
    unit is not the metre (the foot meant, given in the other foot's metres), said in the log."""
    from aerotri.geom.crs.definition import length_in_units, length_unit_name
    from lidarctl.units import whole_units

    interval = length_in_units(interval_m, unit_m)
    whole = whole_units(interval_m, unit_m)
    if whole is None and abs(unit_m - 1.0) > 1e-9 and interval >= 0.5:
        # (trial s96 F6: a user's "2 ft" as 0.61 m gave contours at 408.268, 410.269 ... ft without a word)
        n = max(1, round(interval))
        log.warning(f"contour interval {interval_m:g} m is {interval:.6g} {length_unit_name(unit_m)} on this DEM: its "
                    f"levels fall at odd heights; for {n} {length_unit_name(unit_m)} give {n * unit_m:.6g} m")
    if whole is None or whole == interval:
        return interval
    log.info(f"contour interval {interval_m:g} m is {interval:.7g} {length_unit_name(unit_m)}: taken as "
             f"{whole:g} {length_unit_name(unit_m)}")
    return whole


def contours_from_file(dem_path, out_path, *, interval_m: float, index_every: int = 5, smoothing: str = "none",
                       tolerance_px: float = 0.5, tension: float = 1.0, png: bool = True, water_path=None,
                       water_layer: str | None = None, min_ring_cells: float = MIN_RING_CELLS) -> ContoursResult:
    """Trace (and smooth) the contours of a DEM GeoTIFF into a GeoPackage/GeoJSON (+ a PNG preview beside it);
    ``interval_m`` in metres, traced in the DEM's height unit (its CRS's: 0.3048 m is 1 ft on a DEM in feet).
    ``water_path``: water polygons (``lidarctl.terrain.hydro.read_water``) the contours are cut at (a river left
    unflattened as flowing water; trial s98: 26 lines, 1,884 ft, through Autzen's river). Closed contours enclosing
    fewer than ``min_ring_cells`` cells are left out (``MIN_RING_CELLS``; 0 keeps them).
    Returns the summary (counts, fall-backs, crossings, the interval in the DEM's unit and that unit)."""
    from aerotri.geom.crs.definition import length_unit_name, linear_unit_m, unit_name
    from aerotri.core.vector_files import refuse_foreign_layers
    from aerotri.geom.crs.height_rasters import above_ground_description
    from lidarctl.terrain.dem_io import open_dem

    if not (np.isfinite(interval_m) and interval_m > 0):
        raise OptionError(f"the contour interval must be a positive number of metres, got {interval_m}",
                          param="--interval-m")
    if not (np.isfinite(min_ring_cells) and min_ring_cells >= 0):
        raise OptionError(f"{min_ring_cells!r}: expected a number of cells >= 0", param="--min-ring-cells")
    dem_path, out_path = Path(dem_path), Path(out_path)
    refuse_foreign_layers(out_path, ("contours",), "lidarctl contours")
    src, z_m = open_dem(dem_path, out_path, say_unit=True)
    interval = whole_unit_interval(interval_m, z_m)
    with src:
        # contours are lines over the whole DEM: it is read whole (a 10 x 10 km DEM at 1 m is 400 MB in float32)
        dem = src.read(1, masked=True).astype(np.float64).filled(np.nan)
        transform, crs = src.transform, src.crs
        desc = above_ground_description(src)
    if desc is not None:  # said, not refused: a canopy's height lines may be wanted
        log.warning(f"{dem_path}: holds heights above the ground (its band description {desc!r}): its contours are "
                    "lines of equal height above the ground, not of the terrain (lidarctl rasters' dem.tif for those)")
    z_unit = length_unit_name(z_m)
    check_interval(dem, interval, z_unit, unit_m=z_m)  # before any work: the interval fits the data
    traced, tiny = trace_counted(dem, transform, interval, index_every)
    traced, small_rings = without_small_rings(traced, min_ring_cells * abs(transform.a * transform.e))
    if not traced and np.isfinite(dem).any():  # (trial s96 F12: an empty file, exit 0, no word)
        log.warning(f"{dem_path}: no level every {interval:g} {z_unit} lies within the DEM's heights "
                    f"{np.nanmin(dem):.6g} .. {np.nanmax(dem):.6g} {z_unit}: {out_path} holds no contour")
    footprint = data_footprint(np.isfinite(dem), transform) if smoothing != "none" else None
    contours, fell_back = smooth_contours(traced, smoothing, abs(transform.a), tolerance_px, tension, footprint)
    n_cross = crossings(contours) if smoothing != "none" else 0  # traced lines of one surface never cross
    if n_cross:
        raise RuntimeError(f"{n_cross} contour crossings after smoothing (a bug: crossing lines fall back)")
    n_cut = 0
    if water_path is not None:
        import pyproj

        from lidarctl.terrain.hydro import read_water

        water, _, _ = read_water(water_path, pyproj.CRS.from_wkt(crs.to_wkt()), water_layer)
        contours, n_cut = cut_at_water(contours, water)
    cs = ContourSet(contours, interval, smoothing, fell_back)
    write_contours(cs, out_path, crs.to_wkt(), unit_name(crs.to_wkt()), z_m)
    written = [str(out_path)]
    xy_m = linear_unit_m(crs) if np.isfinite(linear_unit_m(crs)) else 1.0  # (degrees: the preview as before)
    if png:
        written.append(str(preview_png(cs, dem, transform, out_path.with_suffix(".png"),
                                       f"{dem_path.name}: every {interval:g} {z_unit} (index {index_every * interval:g} "
                                       f"{z_unit}), smoothing {smoothing}", unit_name(crs.to_wkt()),
                                       z_unit_m=z_m, xy_unit_m=xy_m)))
    levels = sorted({c.level for c in contours})
    summary = ContoursResult(
        contours=len(contours), levels=len(levels), closed=sum(c.closed for c in contours),
        index_contours=sum(c.index for c in contours), smoothing=smoothing, fell_back_to_traced=fell_back,
        crossings=n_cross, interval=interval, unit=z_unit, metres_per_unit=z_m,
        lowest_level=levels[0] if levels else None, highest_level=levels[-1] if levels else None, files=tuple(written),
        under_a_tenth_of_a_cell=tiny, cut_at_water=n_cut, small_rings=small_rings, min_ring_cells=min_ring_cells)
    log.debug(f"{dem_path} -> {out_path}: {summary}")
    return summary
