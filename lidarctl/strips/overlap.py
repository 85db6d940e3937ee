"""Strips as per-cell planes of smooth single-return surfaces, and the height differences of overlapping strips.

Strips: several files are one strip each (named by the file's stem); a single file is split by its
``point_source_id`` (named ``psid<id>``). Every strip is read chunk by chunk (memory is set by the
occupied cells, not by the points).

Cells: a grid of ``cell_m`` metres aligned to multiples of ``cell_m`` in the strips' CRS (the same cell
ids in every strip). In a cell, a plane z = c + a dx + b dy is fitted by least squares to the strip's
single returns (dx, dy from the cell centre; noise classes 7 and 18 and vegetation classes 3-5 left
out). A cell is *planar* when it holds at least ``min_points`` such returns spread over the cell, the
RMS residual is at most ``max_rms_m``, at most ``max_multi_fraction`` of its returns come from
multi-return pulses (vegetation, edges of roofs), at least two of its four neighbours are planar and
meet it (their planes, extended to this cell's centre, within ``edge_tol_m`` of its own there) and none
is planar but misses it (so cells on roof edges, ridges and steps drop out; a cell across a ridge fails
the RMS test and does not count as a neighbour). Heights are compared at the cell centre, from each strip's plane.

Conventions: x, y, z in metres (clouds in feet are scaled when read); a pair (A, B) is ordered as the
strips are given and its difference is dz = z_B - z_A. Scan angles in degrees, positive to the right of
the flight direction (LAS); the across-track position ``u_m`` is positive to the right as well, from the
strip's centre line (its principal axis, oriented by GPS time).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numba
import numpy as np
import pyproj

from aerotri.core.errors import InputError, OptionError
from aerotri.core.settings import setting
from aerotri.geom import las
from lidarctl import io
from lidarctl.units import LengthUnits

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

NOISE_CLASSES = (7, 18)
VEGETATION_CLASSES = (3, 4, 5)
# per-point sums accumulated per cell: count, dx, dy, dz, dx2, dxdy, dy2, dxdz, dydz, dz2, scan angle, time
_N_SUMS = 12


class NothingToCompare(InputError):
    """The strips are readable but give nothing to compare: one strip only, no two strips overlapping, or
    no smooth surface in the overlaps (a chain leaves the strip check out for these, a command stops)."""


@dataclasses.dataclass(frozen=True)
class SurfaceSettings:
    """What counts as a smooth surface (``lidarctl strips check``/``adjust`` options; lengths in metres)."""

    cell_m: float | None = setting(None, min=0.0, min_open=True,
                                   help="Cell size (m) of the planes and difference rasters (default: about 12 "
                                        "single returns per cell at the strips' density, at least 1 m; a strip "
                                        "under a quarter of the density most points are at is left out of it "
                                        "and reported not compared).")
    min_points: int = setting(6, min=4, help="Single returns a cell needs for its plane.")
    max_rms_m: float = setting(0.10, min=0.0, min_open=True, help="Largest RMS residual of a planar cell (m).")
    max_multi_fraction: float = setting(0.3, min=0.0, max=1.0,
                                        help="Largest share of returns of multi-return pulses in a planar cell.")
    edge_tol_m: float = setting(0.15, min=0.0, min_open=True,
                                help="Largest step between neighbouring cell planes at a cell centre (m).")
    max_slope_deg: float = setting(20.0, min=0.0, max=89.0,
                                   help="Steepest surface the height differences use (deg): on slopes a "
                                        "horizontal offset shows as a height difference.")
    max_dz_m: float = setting(1.0, min=0.0, min_open=True,
                              help="Largest departure (m) of a cell's height difference from its pair's median: "
                                   "beyond it the two strips saw different surfaces there (a roof's eave in one, "
                                   "the ground under it in the other) and the cell is left out (counted).")


@dataclasses.dataclass(frozen=True)
class StripSource:
    name: str
    path: Path
    point_source_id: int | None  # None: the whole file
    # a strip of a file of several: its points and box (x0, y0, x1, y1 in the file's units), for its density (the
    # file's header counts the overlaps' points twice); None: the file's header says
    n_points: int | None = None
    box: tuple[float, float, float, float] | None = None


@dataclasses.dataclass
class CellPlanes:
    """The planar cells of one strip (sorted by cell id); coordinates in metres."""

    source: StripSource
    n_points: int  # points of the strip (all returns)
    ids: np.ndarray  # (m,) global cell ids
    n: np.ndarray  # single returns in the plane
    centroid: np.ndarray  # (m, 3) mean of those returns
    grad: np.ndarray  # (m, 2) dz/dx, dz/dy
    z_centre: np.ndarray  # plane height at the cell centre
    rms_m: np.ndarray
    scan_angle_deg: np.ndarray  # mean scan angle of the cell's returns
    u_m: np.ndarray  # across-track position of the centroid, positive right of the flight direction
    extra: np.ndarray | None = None  # (m, k) per-cell means of caller-defined per-point quantities
    occupied: np.ndarray | None = None  # ids of every cell holding points of the strip
    axis: np.ndarray | None = None  # unit flight direction (x, y)
    centre: np.ndarray | None = None  # (x, y, z) mean of the strip's planar cells

    @property
    def name(self) -> str:
        return self.source.name

    @property
    def slope_deg(self) -> np.ndarray:
        return np.degrees(np.arctan(np.hypot(self.grad[:, 0], self.grad[:, 1])))

    def normals(self) -> np.ndarray:
        n = np.column_stack([-self.grad[:, 0], -self.grad[:, 1], np.ones(len(self.ids))])
        return n / np.linalg.norm(n, axis=1, keepdims=True)


@dataclasses.dataclass
class Grid:
    """Global cell grid: cell (i, j) covers x0 + j cell_m .. and y0 + i cell_m .. (metres); id = i ncols + j."""

    cell_m: float
    x0: float
    y0: float
    nrows: int
    ncols: int

    def centres(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i, j = np.divmod(ids, self.ncols)
        return self.x0 + (j + 0.5) * self.cell_m, self.y0 + (i + 0.5) * self.cell_m


@dataclasses.dataclass
class StripSet:
    strips: list[CellPlanes]
    grid: Grid
    crs: pyproj.CRS | None
    units: LengthUnits
    n_points: int
    z_ref: float | None = None  # height reference of the cell sums (m)
    kept: dict | None = None  # strip name -> KeptPoints (a read with ``keep``)


@dataclasses.dataclass
class PairDiff:
    """Height differences dz = z_B - z_A of two strips on their common smooth cells."""

    a: str
    b: str
    ids: np.ndarray  # common cell ids
    dz_m: np.ndarray
    scan_angle_a_deg: np.ndarray
    scan_angle_b_deg: np.ndarray
    u_a_m: np.ndarray
    u_b_m: np.ndarray
    common_cells: int  # cells both strips hold planes in (any slope)
    apart_cells: int = 0  # common smooth cells left out: different surfaces (``SurfaceSettings.max_dz_m``)


def strip_sources(paths) -> list[StripSource]:
    """Several files: one strip each; one file: a strip per ``point_source_id`` (read from the file)."""
    paths = [Path(p) for p in paths]
    if len(paths) > 1:
        names = [p.stem for p in paths]
        if len(set(names)) < len(names):
            names = [f"{i + 1}_{p.stem}" for i, p in enumerate(paths)]
        return [StripSource(n, p, None) for n, p in zip(names, paths)]
    path = paths[0]
    count: dict[int, int] = {}
    low: dict[int, np.ndarray] = {}  # per point_source_id: the smallest x, y and the largest
    high: dict[int, np.ndarray] = {}
    for _, chunk in las.iter_file_chunks(path, io.CHUNK_POINTS):
        psid = np.asarray(chunk.point_source_id)
        x, y = np.asarray(chunk.x, float), np.asarray(chunk.y, float)
        ids, inv = np.unique(psid, return_inverse=True)
        lo = np.full((len(ids), 2), np.inf)
        hi = np.full((len(ids), 2), -np.inf)
        np.minimum.at(lo, inv, np.column_stack([x, y]))
        np.maximum.at(hi, inv, np.column_stack([x, y]))
        n = np.bincount(inv, minlength=len(ids))
        for k, i in enumerate(ids.tolist()):
            count[i] = count.get(i, 0) + int(n[k])
            low[i], high[i] = np.minimum(low.get(i, lo[k]), lo[k]), np.maximum(high.get(i, hi[k]), hi[k])
    if len(count) < 2:
        raise NothingToCompare(f"{path}: one strip only (point_source_id {sorted(count)}); strip differences need at "
                               "least two overlapping strips: give several files, or one file whose strips differ "
                               "in point_source_id")
    return [StripSource(f"psid{i}", path, int(i), count[i], (*map(float, low[i]), *map(float, high[i])))
            for i in sorted(count)]


def scan_angle_deg(chunk) -> np.ndarray:
    """Scan angle in degrees: LAS 1.4 formats 6-10 store 0.006 degree steps, older ones whole degrees."""
    if chunk.point_format.id >= 6:
        return np.asarray(chunk.scan_angle, float) * 0.006
    return np.asarray(chunk.scan_angle_rank, float)


def _check_crs(sources, crs_arg):
    """(crs, units) shared by every file; InputError naming the first file that differs."""
    first = None
    for path in dict.fromkeys(s.path for s in sources):
        crs, units = io.resolve_crs_units(path, las.read_header(path), crs_arg)
        if first is None:
            first = (path, crs, units)
        else:
            io.require_same_crs(path, crs, units, first)
    return first[1], first[2]


# a strip sparser than this share of the density most points are at (a fragment, a few pulses along a whole
# strip) is left out of the default cell: counted, it would make every other strip's cells more than twice as
# wide (a 50-point strip spanning a full strip's box made them 44 m, and nothing was planar); it is reported
# "not compared" instead
SPARSE_DENSITY_SHARE = 0.25


def _default_cell_m(sources, units: LengthUnits) -> float:
    """About 12 points per cell at the lowest density of the files that are not far sparser than most points
    (``SPARSE_DENSITY_SHARE``), density = points / header box (the boxes overestimate the area of a strip that
    is not axis-aligned: the cell comes out a bit large, never too small; a strip of a file of several by its own
    points and box)."""
    dens = _densities(sources, units)
    ref = _bulk_density(dens)
    kept = {p: d for p, (n, d) in dens.items() if d >= SPARSE_DENSITY_SHARE * ref}
    for p in dens.keys() - kept.keys():
        log.info("%s: %d points, %.3g points/m2 (header box): too sparse to set the default cell size (most points "
                 "at %.3g points/m2)", p, dens[p][0], dens[p][1], ref)
    cell = np.sqrt(12.0 / max(min(kept.values()), 1e-9))
    return float(max(1.0, np.ceil(cell * 2.0) / 2.0))


def _densities(sources, units: LengthUnits) -> dict:
    """Strip -> (points, point density in points per m2 of its box): a file's header box, or a strip's own in a
    file of several (the file's would count its overlaps' points twice: trial-strips, the same four strips merged
    into one file got 4.5 m cells against 5.5 m as four files, and a pooled NMAD 25 % higher)."""
    out = {}
    for s in sources:
        if s.n_points is not None and s.box is not None:
            n, (x0, y0, x1, y1) = s.n_points, s.box
        else:
            h = las.read_header(s.path)
            n, (x0, y0), (x1, y1) = int(h.point_count), np.asarray(h.mins, float)[:2], np.asarray(h.maxs, float)[:2]
        out[s.name] = (int(n), n / max((x1 - x0) * (y1 - y0) * units.xy_m ** 2, 1e-6))
    return out


def _bulk_density(dens: dict) -> float:
    """The density most points are at: the points-weighted median of the files' densities (points per m2)."""
    n = np.array([v[0] for v in dens.values()], float)
    d = np.array([v[1] for v in dens.values()], float)
    order = np.argsort(-d)
    k = int(np.searchsorted(np.cumsum(n[order]), 0.5 * n.sum()))
    return float(d[order][min(k, len(d) - 1)])


def _check_cell(sources, units: LengthUnits, params) -> None:
    """OptionError naming --cell-m when a given cell holds on average fewer points than a plane needs at the
    density most points are at (header boxes): every cell of most strips would be dropped and the strips
    reported as without a smooth surface. A sparser strip (a fragment) does not refuse it: it is reported not
    compared."""
    if params.cell_m is None:
        return
    dens = _bulk_density(_densities(sources, units))
    # the header boxes may overstate a strip's area a few times (a diagonal strip): refused only beyond that
    if 4.0 * dens * params.cell_m ** 2 < params.min_points:
        raise OptionError(f"{params.cell_m:g} m: cells this small hold about {dens * params.cell_m ** 2:.2g} points at "
                          f"the density of most of the strips' points ({dens:.2f} points/m2), fewer than the "
                          f"{params.min_points} a plane needs (--min-points); use at least "
                          f"{np.sqrt(params.min_points / dens):.2g} m", param="--cell-m")


def _grid(sources, units: LengthUnits, cell_m: float) -> Grid:
    mins = np.min([np.asarray(las.read_header(s.path).mins, float) for s in sources], axis=0) * units.xy_m
    maxs = np.max([np.asarray(las.read_header(s.path).maxs, float) for s in sources], axis=0) * units.xy_m
    x0, y0 = np.floor(mins[0] / cell_m) * cell_m - cell_m, np.floor(mins[1] / cell_m) * cell_m - cell_m
    ncols = int(np.ceil((maxs[0] - x0) / cell_m)) + 2
    nrows = int(np.ceil((maxs[1] - y0) / cell_m)) + 2
    return Grid(cell_m, float(x0), float(y0), nrows, ncols)


class _Accumulator:
    """Sparse per-cell sums of one strip, chunk by chunk (reduced once at the end)."""

    def __init__(self, k_extra: int):
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.all_parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.k = _N_SUMS + k_extra
        self.n_points = 0

    def add(self, cell, q, cell_all, multi):
        if len(cell):
            u, inv = np.unique(cell, return_inverse=True)
            sums = np.stack([np.bincount(inv, q[:, k], minlength=len(u)) for k in range(q.shape[1])], axis=1)
            self.parts.append((u, sums))
        if len(cell_all):
            u, inv = np.unique(cell_all, return_inverse=True)
            self.all_parts.append((u, np.stack([np.bincount(inv, minlength=len(u)),
                                                np.bincount(inv, multi, minlength=len(u))], axis=1).astype(float)))

    @staticmethod
    def _reduce(parts, k):
        if not parts:
            return np.zeros(0, np.int64), np.zeros((0, k))
        if len(parts) == 1:
            return parts[0]
        ids = np.concatenate([p[0] for p in parts])
        s = np.concatenate([p[1] for p in parts])
        u, inv = np.unique(ids, return_inverse=True)
        # bincount adds in the parts' order, as np.add.at would, at a tenth of its time
        return u, np.stack([np.bincount(inv, s[:, k], minlength=len(u)) for k in range(s.shape[1])], axis=1)

    def reduce(self):
        return self._reduce(self.parts, self.k), self._reduce(self.all_parts, 2)


@dataclasses.dataclass
class KeepRegion:
    """The cells whose points a read keeps in memory (``KeptPoints``): coarse cells of ``block`` x ``block``
    grid cells, ids i // block * coarse_ncols + j // block of a point's cell (i, j) before any correction."""

    block: int
    coarse_ncols: int
    ids: dict  # strip name -> sorted coarse cell ids
    times: bool = False  # keep the GPS times too (a correction or ``extra`` that needs them)

    def coarse(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return (i // self.block) * self.coarse_ncols + j // self.block


@dataclasses.dataclass
class KeptPoints:
    """The non-noise points of one strip inside its ``KeepRegion``, as read (before any correction): the
    file's integer coordinates (exact, 12 bytes a point; metres by ``scale``, ``offset`` and the units), whether
    a single return (1 byte) and, when asked for, the GPS time (8 bytes)."""

    xyz_int: np.ndarray  # (n, 3) int32 LAS X, Y, Z
    scale: np.ndarray  # (3,)
    offset: np.ndarray  # (3,)
    single: np.ndarray  # (n,) bool: a single return (not of a multi-return pulse, not vegetation)
    gps_time: np.ndarray | None  # (n,) float64 (``KeepRegion.times`` and the file has them)

    def xyz_m(self, units: LengthUnits, k=slice(None)):
        c = self.xyz_int[k] * self.scale + self.offset
        return units.xy_to_m(c[:, 0]), units.xy_to_m(c[:, 1]), units.z_to_m(c[:, 2])


def read_strip_planes(paths, params: SurfaceSettings = SurfaceSettings(), crs=None, *, extra=None, correct=None,
                      grid: Grid | None = None, keep: KeepRegion | None = None, z_ref: float | None = None) -> StripSet:
    """Planar cells of every strip of ``paths`` (see the module docstring); the points themselves, classified,
    are ``lidarctl.corners.roof_corners.read_strips``.

    ``extra(source, chunk, x_m, y_m, z_m) -> (n, k)`` adds caller-defined per-point quantities whose
    per-cell means end up in ``CellPlanes.extra`` (the adjustment's sensor-model derivatives).
    ``correct(source, x_m, y_m, z_m, gps_time) -> (x_m, y_m, z_m)`` moves a strip's points before they are
    binned (the adjustment re-reads the strips with its current correction); ``grid`` and ``z_ref`` reuse
    the cells and height reference of an earlier read. ``keep``: the points inside it are also kept in
    memory (``StripSet.kept``) for ``regrid``."""
    paths = [Path(p) for p in paths]
    headers = {p: las.read_header(p) for p in paths}  # a missing or broken file stops here, naming it
    sources = strip_sources(paths)
    crs_out, units = _check_crs(sources, crs)
    if grid is None:
        _check_cell(sources, units, params)
        grid = _grid(sources, units, params.cell_m or _default_cell_m(sources, units))
    cell_m = grid.cell_m
    accs = {s.name: None for s in sources}
    kept_parts = {s.name: [] for s in sources} if keep is not None else None
    by_path: dict[Path, list[StripSource]] = {}
    for s in sources:
        by_path.setdefault(s.path, []).append(s)
    total = 0
    for path, group in by_path.items():
        header = headers[path]
        for first, chunk in las.iter_file_chunks(path, io.CHUNK_POINTS):
            cx, cy, cz = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            io.validate_xyz(path, cx, cy, cz, first, units)
            x, y, z = units.xy_to_m(cx), units.xy_to_m(cy), units.z_to_m(cz)
            if z_ref is None:
                z_ref = float(np.floor(np.median(z)))
            cls = np.asarray(chunk.classification)
            rn, nr = io.sanitize_returns(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
            psid = np.asarray(chunk.point_source_id)
            ang = scan_angle_deg(chunk)
            has_t = "gps_time" in chunk.point_format.dimension_names
            t = np.asarray(chunk.gps_time, float) if has_t else np.zeros(len(x))
            ok = ~np.isin(cls, NOISE_CLASSES)
            multi = (nr > 1) | np.isin(cls, VEGETATION_CLASSES)
            if keep is not None:  # by the cell a point was read in, before any correction
                coarse = keep.coarse(np.floor((y - grid.y0) / cell_m).astype(np.int64),
                                     np.floor((x - grid.x0) / cell_m).astype(np.int64))
                for s in group:
                    sel = ok if s.point_source_id is None else ok & (psid == s.point_source_id)
                    w = np.flatnonzero(sel)
                    w = w[np.isin(coarse[w], keep.ids[s.name])]
                    kept_parts[s.name].append((np.column_stack([np.asarray(chunk.X)[w], np.asarray(chunk.Y)[w],
                                                                np.asarray(chunk.Z)[w]]).astype(np.int32),
                                               ~multi[w], t[w] if has_t and keep.times else None))
            if correct is not None:
                x, y, z = np.array(x, float), np.array(y, float), np.array(z, float)
                for s in group:
                    k = slice(None) if s.point_source_id is None else np.flatnonzero(psid == s.point_source_id)
                    x[k], y[k], z[k] = correct(s, x[k], y[k], z[k], t[k])
            for s in group:
                sel = ok if s.point_source_id is None else ok & (psid == s.point_source_id)
                if not sel.any():
                    continue
                total += _accumulate(accs, s, chunk, x=x, y=y, z=z, sel=sel, multi=multi, ang=ang, t=t, grid=grid,
                                     z_ref=z_ref, extra=extra)
        if keep is not None:
            for s in group:
                parts = kept_parts[s.name]
                has_t = bool(parts) and parts[0][2] is not None
                kept_parts[s.name] = KeptPoints(
                    np.concatenate([q[0] for q in parts]) if parts else np.zeros((0, 3), np.int32),
                    np.asarray(header.scales, float), np.asarray(header.offsets, float),
                    np.concatenate([q[1] for q in parts]) if parts else np.zeros(0, bool),
                    np.concatenate([q[2] for q in parts]) if has_t else None)
    strips = []
    for s in sources:
        acc = accs[s.name]
        if acc is None:
            raise InputError(f"{s.path}: strip {s.name} holds no points (other than noise)")
        strips.append(_planes(s, acc, grid, params, z_ref))
    log.debug("read %d strips, %d points, cell %g m", len(strips), total, cell_m)
    return StripSet(strips, grid, crs_out, units, total, z_ref, kept_parts)


# the per-chunk sums in numba (``_cell_sums``) index the chunk's box of cells (4 bytes a cell) while it holds at
# most this many cells per point (a strip's chunk is a stretch of its swath, flown in order: about a tenth of a
# cell per point even for a diagonal strip); beyond, the sparse sums (np.unique, bincount)
DENSE_CELLS_PER_POINT = 4.0


@numba.njit(cache=True)
def _cell_sums(x, y, z, *, sel, single, ang, t, ex, x0, y0, cell_m, z_ref, i0, j0, nr, nc):
    """The occupied cells of the box (rows i0.., columns j0.., nr x nc cells) in id order (box indices), the
    sums of ``_N_SUMS`` + k per single return in each, and (count, multi-return count) of every point of
    ``sel``; points added in their order."""
    k = ex.shape[1]
    n = len(x)
    cell = np.empty(n, np.int64)
    idx = np.zeros(nr * nc, np.int32)
    for p in range(n):
        if sel[p]:
            c = (np.int64(np.floor((y[p] - y0) / cell_m)) - i0) * nc + np.int64(np.floor((x[p] - x0) / cell_m)) - j0
            cell[p] = c
            idx[c] = 1
    m = 0
    for c in range(nr * nc):
        if idx[c]:
            idx[c] = m
            m += 1
        else:
            idx[c] = -1
    box = np.empty(m, np.int64)
    S = np.zeros((m, _N_SUMS + k))
    A = np.zeros((m, 2))
    for p in range(n):
        if not sel[p]:
            continue
        c = cell[p]
        r = idx[c]
        box[r] = c
        A[r, 0] += 1.0
        if not single[p]:
            A[r, 1] += 1.0
            continue
        i = c // nc + i0
        j = c % nc + j0
        dx = x[p] - (x0 + (j + 0.5) * cell_m)
        dy = y[p] - (y0 + (i + 0.5) * cell_m)
        dz = z[p] - z_ref
        S[r, 0] += 1.0
        S[r, 1] += dx
        S[r, 2] += dy
        S[r, 3] += dz
        S[r, 4] += dx * dx
        S[r, 5] += dx * dy
        S[r, 6] += dy * dy
        S[r, 7] += dx * dz
        S[r, 8] += dy * dz
        S[r, 9] += dz * dz
        S[r, 10] += ang[p]
        S[r, 11] += t[p]
        for q in range(k):
            S[r, _N_SUMS + q] += ex[p, q]
    return box, S, A


def _accumulate(accs, s, chunk, *, x, y, z, sel, multi, ang, t, grid, z_ref, extra) -> int:
    """Adds the points ``sel`` of strip ``s`` (metres, corrected) to its cell sums; returns their number."""
    cell_m = grid.cell_m
    use = sel & ~multi
    ex = None
    if extra is not None:
        ex = np.asarray(extra(s, chunk, x, y, z, use), float)
    if accs[s.name] is None:
        accs[s.name] = _Accumulator(0 if ex is None else ex.shape[1])
    acc = accs[s.name]
    n = int(sel.sum())
    acc.n_points += n
    w = np.flatnonzero(sel)
    j = np.floor((x[w] - grid.x0) / cell_m).astype(np.int64)
    i = np.floor((y[w] - grid.y0) / cell_m).astype(np.int64)
    i0, j0 = int(i.min()), int(j.min())
    nr, nc = int(i.max()) - i0 + 1, int(j.max()) - j0 + 1
    if nr * nc <= DENSE_CELLS_PER_POINT * len(w) + 4096:
        box, S, A = _cell_sums(x, y, z, sel=sel, single=use, ang=ang, t=np.ascontiguousarray(t),  # one signature
                               ex=ex if ex is not None else np.zeros((len(x), 0)), x0=grid.x0, y0=grid.y0,
                               cell_m=cell_m, z_ref=z_ref, i0=i0, j0=j0, nr=nr, nc=nc)
        ids = (i0 + box // nc) * grid.ncols + j0 + box % nc  # ascending as box
        r = S[:, 0] > 0
        acc.parts.append((ids[r], S[r]))
        acc.all_parts.append((ids, A))
        return n
    cell_sel = i * grid.ncols + j
    u = use[w]
    wu = w[u]
    cell = cell_sel[u]
    dx = x[wu] - (grid.x0 + (j[u] + 0.5) * cell_m)
    dy = y[wu] - (grid.y0 + (i[u] + 0.5) * cell_m)
    dz = z[wu] - z_ref
    q = np.empty((len(wu), acc.k))
    for k, col in enumerate((1.0, dx, dy, dz, dx * dx, dx * dy, dy * dy, dx * dz, dy * dz, dz * dz, ang[wu], t[wu])):
        q[:, k] = col
    if ex is not None:
        q[:, _N_SUMS:] = ex[wu]
    acc.add(cell, q, cell_sel, multi[w].astype(float))
    return n


def regrid(ss: StripSet, params: SurfaceSettings, extra=None, correct=None,
           chunk_points: int = io.CHUNK_POINTS) -> StripSet:
    """The planar cells of the points ``ss.kept`` (a read with ``keep``), moved by ``correct``, on the grid and
    height reference of ``ss``: what ``read_strip_planes`` with that correction gives at every cell whose points and
    4-neighbours' points all lie in the kept region (the caller sizes the region for that). Scan angles are
    not kept (the cells' ``scan_angle_deg`` are 0), nor GPS times unless the region asked for them."""
    units, grid = ss.units, ss.grid
    accs = {s.name: None for s in ss.strips}
    total = 0
    for cp in ss.strips:
        s, kp = cp.source, ss.kept[cp.name]
        for k0 in range(0, len(kp.single), chunk_points):  # bounded memory of the moved coordinates
            k = slice(k0, k0 + chunk_points)
            x, y, z = kp.xyz_m(units, k)
            t = kp.gps_time[k] if kp.gps_time is not None else np.zeros(len(x))
            if correct is not None:
                x, y, z = correct(s, x, y, z, t)
            total += _accumulate(accs, s, _KeptChunk(t), x=x, y=y, z=z, sel=np.ones(len(x), bool), multi=~kp.single[k],
                                 ang=np.zeros(len(x)), t=t, grid=grid, z_ref=ss.z_ref, extra=extra)
        if accs[s.name] is None:  # nothing kept: no cell of this strip in an overlap
            accs[s.name] = _Accumulator(0 if cp.extra is None else cp.extra.shape[1])
    strips = [_planes(cp.source, accs[cp.name], grid, params, ss.z_ref) for cp in ss.strips]
    return StripSet(strips, grid, ss.crs, units, total, ss.z_ref, ss.kept)


@dataclasses.dataclass
class _KeptChunk:
    """What ``extra`` callbacks read of a chunk, for kept points."""

    gps_time: np.ndarray | None


def _planes(source: StripSource, acc: _Accumulator, grid: Grid, params: SurfaceSettings, z_ref: float) -> CellPlanes:
    (ids, S), (ids_all, A) = acc.reduce()
    n = S[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        m = S[:, 1:4] / n[:, None]
        mx, my, mz = m[:, 0], m[:, 1], m[:, 2]
        sxx = S[:, 4] / n - mx * mx
        sxy = S[:, 5] / n - mx * my
        syy = S[:, 6] / n - my * my
        sxz = S[:, 7] / n - mx * mz
        syz = S[:, 8] / n - my * mz
        szz = S[:, 9] / n - mz * mz
        det = sxx * syy - sxy * sxy
        a = (sxz * syy - syz * sxy) / det
        b = (syz * sxx - sxz * sxy) / det
        var = np.maximum(szz - a * sxz - b * syz, 0.0) * n / np.maximum(n - 3, 1)
        c = mz - a * mx - b * my
    rms = np.sqrt(var)
    # the share of multi-return (vegetation) returns among all of the cell's returns
    k = np.searchsorted(ids_all, ids)
    multi_frac = A[k, 1] / np.maximum(A[k, 0], 1)
    spread = (grid.cell_m ** 2 / 12.0) ** 2  # det of points spread evenly over the cell
    planar = (n >= params.min_points) & np.isfinite(rms) & (det > 0.02 * spread) & (rms <= params.max_rms_m) & \
        (multi_frac <= params.max_multi_fraction)
    ids, n, S, a, b, c, rms, m = ids[planar], n[planar], S[planar], a[planar], b[planar], c[planar], rms[planar], m[planar]
    # edges, ridges and steps: no planar 4-neighbour whose plane misses this cell's plane at its centre by more
    # than edge_tol_m (a step, a roof's eave over the ground), and at least two that meet it (not an isolated
    # cell); neighbours that are not planar (a cell across a ridge or an eave) do not count either way, so
    # that the cells of a roof face next to its ridge stay
    h = grid.cell_m
    n_continuous = np.zeros(len(ids), int)
    broken = np.zeros(len(ids), bool)
    for d_id, ddx, ddy in ((1, 1, 0), (-1, -1, 0), (grid.ncols, 0, 1), (-grid.ncols, 0, -1)):
        if len(ids) == 0:
            break
        k = np.minimum(np.searchsorted(ids, ids + d_id), len(ids) - 1)
        found = ids[k] == ids + d_id
        # the neighbour's plane at this cell's centre (dx = -ddx h, dy = -ddy h from its own centre)
        zn = c[k] - a[k] * ddx * h - b[k] * ddy * h
        close = np.abs(zn - c) <= params.edge_tol_m
        n_continuous += found & close
        broken |= found & ~close
    keep = (n_continuous >= 2) & ~broken
    ids, n, S, a, b, c, rms, m = ids[keep], n[keep], S[keep], a[keep], b[keep], c[keep], rms[keep], m[keep]
    xc, yc = grid.centres(ids)
    centroid = np.column_stack([xc + m[:, 0], yc + m[:, 1], z_ref + m[:, 2]])
    ang = S[:, 10] / n
    t = S[:, 11] / n
    extra = S[:, _N_SUMS:] / n[:, None] if S.shape[1] > _N_SUMS else None
    axis, centre, u = _across_track(centroid, n, t)
    return CellPlanes(source, acc.n_points, ids, n, centroid, np.column_stack([a, b]), z_ref + c, rms, ang, u,
                      extra, ids_all, axis, centre)


def _across_track(centroid, w, t):
    """Flight direction (principal axis of the planar cells, oriented by GPS time), the strip's centre and
    the signed across-track position (positive to the right of the flight direction)."""
    if len(centroid) < 2:
        return np.array([1.0, 0.0]), centroid.mean(axis=0) if len(centroid) else np.zeros(3), np.zeros(len(centroid))
    c = np.average(centroid, axis=0, weights=w)
    d = centroid[:, :2] - c[:2]
    cov = (d * w[:, None]).T @ d
    evals, evecs = np.linalg.eigh(cov)
    e = evecs[:, 1]
    along = d @ e
    if np.ptp(t) > 0 and np.cov(along, t)[0, 1] < 0:
        e = -e
    right = np.array([e[1], -e[0]])
    return e, c, d @ right


def pair_diffs(ss: StripSet, params: SurfaceSettings, min_cells: int = 20):
    """(differences of every pair with at least ``min_cells`` common smooth cells of slope at most
    ``max_slope_deg``, {pair: reason} of the pairs left out, number of pairs that overlap at all)."""
    out, skipped, n_overlap = [], {}, 0
    strips = ss.strips
    for ia in range(len(strips)):
        for ib in range(ia + 1, len(strips)):
            A, B = strips[ia], strips[ib]
            if len(np.intersect1d(A.occupied, B.occupied, assume_unique=True)) == 0:
                continue
            n_overlap += 1
            common, ka, kb = np.intersect1d(A.ids, B.ids, assume_unique=True, return_indices=True)
            flat = (A.slope_deg[ka] <= params.max_slope_deg) & (B.slope_deg[kb] <= params.max_slope_deg)
            ka, kb = ka[flat], kb[flat]
            # A cell planar in both strips can still hold two surfaces: a strip looking in under a roof's eave
            # sees the ground where the other sees the roof (a 60 m block's eave: one cell of 60 m was 89 % of a
            # pair's sum of squares in the dmc_block subset). Strip errors shift a pair's differences by
            # decimetres, not metres: cells far from the pair's median are left out and counted.
            dz = B.z_centre[kb] - A.z_centre[ka]
            same = np.abs(dz - np.median(dz)) <= params.max_dz_m if len(dz) else np.ones(0, bool)
            apart = int(len(dz) - same.sum())
            ka, kb = ka[same], kb[same]
            if len(ka) < min_cells:
                skipped[f"{A.name}-{B.name}"] = (f"{len(ka)} common smooth cells (slope <= {params.max_slope_deg:g} "
                                                 f"deg), fewer than {min_cells}")
                continue
            out.append(PairDiff(A.name, B.name, A.ids[ka], dz[same], A.scan_angle_deg[ka],
                                B.scan_angle_deg[kb], A.u_m[ka], B.u_m[kb], len(common), apart))
    return out, skipped, n_overlap


def overlapping_pairs_or_error(ss: StripSet, params: SurfaceSettings, paths, min_cells: int = 20):
    """``pair_diffs`` with the InputErrors a check needs: fewer than two strips, no two strips overlapping,
    no smooth surface in any overlap."""
    names = ", ".join(str(p) for p in dict.fromkeys(str(p) for p in paths))
    if len(ss.strips) < 2:
        raise NothingToCompare(f"{names}: one strip only; strip differences need at least two overlapping strips")
    pairs, skipped, n_overlap = pair_diffs(ss, params, min_cells)
    if n_overlap == 0:
        raise NothingToCompare(f"{names}: no two strips overlap (no cell of {ss.grid.cell_m:g} m holds points of two "
                         "strips); give overlapping strips")
    if not pairs:
        raise NothingToCompare(f"{names}: the overlaps hold no smooth single-return surface (planar cells with at least "
                         f"{params.min_points} single returns, RMS <= {params.max_rms_m:g} m, slope <= "
                         f"{params.max_slope_deg:g} deg, >= {min_cells} cells per pair); "
                         + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    return pairs, skipped
