"""Grid operations on height rasters: minimum surfaces, gap filling, bilinear sampling, slope, roughness.

Rasters here are NumPy arrays with row 0 at the *south* edge (row index grows with y) and cell
(i, j) centred at (x0 + (j + 0.5) * cell_m, y0 + (i + 0.5) * cell_m); NaN marks empty cells.
Writers flip rows to the north-up GeoTIFF convention.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numba
import numpy as np
from scipy import ndimage

from lidarctl.grid import GRID_BYTES_PER_CELL, check_grid
from lidarctl.raster_tin import (COLLINEAR, OK, _argsort_keys, _bw_insert, _bw_start, _conflicts_near,
                                 _insertion_keys, _locate_cells, _new_mesh, delaunay_lattice)

log = logging.getLogger(__name__)


@numba.njit(cache=True)
def _cell_extreme(flat, v, ncells, sign):
    out = np.full(ncells, np.nan)
    for k in range(len(flat)):
        c = flat[k]
        if np.isnan(out[c]) or sign * v[k] < sign * out[c]:
            out[c] = v[k]
    return out


def cell_extreme(flat: np.ndarray, values, ncells: int, how: str = "min") -> np.ndarray:
    """Per-cell min or max of ``values`` over flat cell indices ``flat`` (all in 0..ncells-1); NaN
    where no value falls."""
    if how not in ("min", "max"):
        raise ValueError(how)
    return _cell_extreme(np.asarray(flat, np.int64), np.asarray(values, float), ncells, 1.0 if how == "min" else -1.0)


class _CellGrid(NamedTuple):
    """A grid of the module docstring's convention as the numba kernels take it (one argument, not five)."""

    cell_m: float
    x0: float
    y0: float
    nrows: int
    ncols: int


class _GridWindow(NamedTuple):
    """``_bilinear``'s raster: cell size and origin of the whole grid, first row and column of the window
    (floats, as the kernel's arithmetic takes them)."""

    cell_m: float
    x0: float
    y0: float
    row0: float
    col0: float


@numba.njit(cache=True)
def _cell_of(x, y, g):
    """Flat cell of a point in ``_CellGrid`` ``g``, -1 off the grid (or NaN)."""
    jf = np.floor((x - g.x0) / g.cell_m)
    i_f = np.floor((y - g.y0) / g.cell_m)
    if not (jf >= 0 and jf < g.ncols and i_f >= 0 and i_f < g.nrows):
        return -1
    return int(i_f) * g.ncols + int(jf)


@numba.njit(cache=True)
def _cell_extreme_xy(x, y, v, g, sign):
    out = np.full(g.nrows * g.ncols, np.nan)
    for k in range(len(x)):
        c = _cell_of(x[k], y[k], g)
        if c >= 0 and (np.isnan(out[c]) or sign * v[k] < sign * out[c]):
            out[c] = v[k]
    return out


@numba.njit(cache=True)
def _cell_sums(x, y, v, g):
    """Per-cell sum (in point order, as np.bincount adds) and count of ``v``."""
    s = np.zeros(g.nrows * g.ncols)
    n = np.zeros(g.nrows * g.ncols)
    for k in range(len(x)):
        c = _cell_of(x[k], y[k], g)
        if c >= 0:
            s[c] += v[k]
            n[c] += 1.0
    return s, n


def reduce_grid(x, y, values, *, cell_m, x0, y0, nrows, ncols, how: str = "min") -> np.ndarray:
    """Per-cell min / max / mean of ``values``; NaN where no point falls. A grid larger than the
    machine's RAM is a ResourceError before anything is allocated."""
    check_grid(nrows, ncols, cell_m, GRID_BYTES_PER_CELL, "the points' extent",
               hint="are strips far apart (different zones or CRSs) in one cloud?")
    if how not in ("min", "max", "mean"):
        raise ValueError(how)
    x, y, v = np.asarray(x, float), np.asarray(y, float), np.asarray(values, float)
    grid = _CellGrid(float(cell_m), float(x0), float(y0), int(nrows), int(ncols))
    if how == "mean":
        s, n = _cell_sums(x, y, v, grid)
        with np.errstate(invalid="ignore"):
            out = s / n
    else:
        out = _cell_extreme_xy(x, y, v, grid, 1.0 if how == "min" else -1.0)
    return out.reshape(nrows, ncols)


@numba.njit(cache=True, nogil=True, inline="always")
def _mean_of_four(a, w):
    """(value, weight) of a coarser cell from its four children (``a``: the products value * weight of children
    00 01 10 11, ``w``: their weights):
    the weighted mean and 1, or 0 and 0 when no child has a value. One order of the sums for every caller: the
    levels come out the same bits whichever kernel read them."""
    n = (w[0] + w[1]) + (w[2] + w[3])
    if n > 0:
        return ((a[0] + a[1]) + (a[2] + a[3])) / max(n, 1e-12), 1.0
    return 0.0, 0.0


@numba.njit(cache=True, nogil=True)
def _pull(v, w):
    """One level up the pull-push pyramid: the mean of the valid cells of each 2 x 2 block (a grid of
    odd size padded with empty cells), summed as numpy's ``reshape(h, 2, w, 2).sum(axis=(1, 3))``
    does, ``(a00 + a01) + (a10 + a11)``, so the result is bit-identical to the array version."""
    h, wd = v.shape
    hh, ww = (h + 1) // 2, (wd + 1) // 2
    vs = np.empty((hh, ww))
    ws = np.empty((hh, ww))
    for i in range(hh):
        i1 = 2 * i + 1
        for j in range(ww):
            j1 = 2 * j + 1
            a00, a01, a10, a11 = v[2 * i, 2 * j] * w[2 * i, 2 * j], 0.0, 0.0, 0.0
            w00, w01, w10, w11 = w[2 * i, 2 * j], 0.0, 0.0, 0.0
            if j1 < wd:
                a01, w01 = v[2 * i, j1] * w[2 * i, j1], w[2 * i, j1]
            if i1 < h:
                a10, w10 = v[i1, 2 * j] * w[i1, 2 * j], w[i1, 2 * j]
                if j1 < wd:
                    a11, w11 = v[i1, j1] * w[i1, j1], w[i1, j1]
            vs[i, j], ws[i, j] = _mean_of_four((a00, a01, a10, a11), (w00, w01, w10, w11))
    return vs, ws


@numba.njit(cache=True, nogil=True)
def _push(coarse, v, w):
    """One level down: the level's own value where it has one, else its parent's."""
    h, wd = v.shape
    out = np.empty((h, wd))
    for i in range(h):
        for j in range(wd):
            out[i, j] = v[i, j] if w[i, j] > 0 else coarse[i // 2, j // 2]
    return out


@numba.njit(cache=True, nogil=True)
def _finite_count(a):
    n = 0
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            n += np.isfinite(a[i, j])
    return n


@numba.njit(cache=True, nogil=True)
def _pull_nan(a):
    """``_pull`` of the first level, (``np.where(valid, a, 0)``, ``valid``) of ``a`` (NaN: no value), read from
    ``a`` itself: a valid cell's product is ``a * 1.0 == a``, an empty one's ``0.0 * 0.0``, so the sums are the
    same bits without the two window-sized arrays."""
    h, wd = a.shape
    hh, ww = (h + 1) // 2, (wd + 1) // 2
    vs = np.empty((hh, ww))
    ws = np.empty((hh, ww))
    for i in range(hh):
        i1 = 2 * i + 1
        for j in range(ww):
            j1 = 2 * j + 1
            a00, a01, a10, a11 = a[2 * i, 2 * j], 0.0, 0.0, 0.0
            w00, w01, w10, w11 = 1.0, 0.0, 0.0, 0.0
            if not np.isfinite(a00):
                a00, w00 = 0.0, 0.0
            if j1 < wd and np.isfinite(a[2 * i, j1]):
                a01, w01 = a[2 * i, j1], 1.0
            if i1 < h:
                if np.isfinite(a[i1, 2 * j]):
                    a10, w10 = a[i1, 2 * j], 1.0
                if j1 < wd and np.isfinite(a[i1, j1]):
                    a11, w11 = a[i1, j1], 1.0
            vs[i, j], ws[i, j] = _mean_of_four((a00, a01, a10, a11), (w00, w01, w10, w11))
    return vs, ws


@numba.njit(cache=True, nogil=True)
def _push_nan(coarse, a):
    """``_push`` onto the first level: ``a``'s value where it has one, else its parent's."""
    h, wd = a.shape
    out = np.empty((h, wd))
    for i in range(h):
        for j in range(wd):
            out[i, j] = a[i, j] if np.isfinite(a[i, j]) else coarse[i // 2, j // 2]
    return out


def fill_nodata(a: np.ndarray, offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Fill NaN cells by pull-push (pyramid averaging, then coarse-to-fine fill); smooth and O(n). A cell takes
    the mean of the valid cells of the smallest pyramid block around it that holds any (blocks of 2**k cells from
    the grid's first cell). ``offset``: (row, col) of the raster's first cell in a larger grid (a tile's window on
    the whole cloud's grid, ``grid.lattice_offset``): the blocks are then that grid's (empty cells padded before
    the first), so a cell's fill is the whole grid's wherever its block lies inside the window."""
    a = np.ascontiguousarray(a, float)         # one layout, one compilation of the kernels
    if a.ndim == 2 and a.size and (offset[0] or offset[1]):
        block = 1 << max(1, int(np.ceil(np.log2(max(a.shape)))))
        pad_rows, pad_cols = int(offset[0]) % block, int(offset[1]) % block
        if (pad_rows or pad_cols) and not np.isfinite(a).all():
            padded = np.full((a.shape[0] + pad_rows, a.shape[1] + pad_cols), np.nan)
            padded[pad_rows:, pad_cols:] = a
            return fill_nodata(padded)[pad_rows:, pad_cols:]
    if a.ndim != 2 or min(a.shape) == 1:
        return _fill_nodata_levels(a)
    n = _finite_count(a)
    if n == a.size or n == 0:
        return a.copy()
    # the first level read from ``a`` itself (``_pull_nan``, ``_push_nan``): the same bits as the levels of
    # ``_fill_nodata_levels`` without two window-sized arrays (the rasters fill two grids a tile)
    return _push_nan(_pull_push([_pull_nan(a)]), a)


def _fill_nodata_levels(a: np.ndarray) -> np.ndarray:
    """``fill_nodata`` with the first level as (values, weights) arrays (rasters of one row or column)."""
    valid = np.isfinite(a)
    if valid.all() or not valid.any():
        return a.copy()
    return _pull_push([(np.where(valid, a, 0.0), valid.astype(float))])


def _pull_push(levels: list) -> np.ndarray:
    """The pyramid from its first level (values, weights) up to a level without empty cells (or one row or
    column: there empty cells take the level's mean), then filled back down to the first level."""
    while True:
        v, w = levels[-1]
        if (w > 0).all() or min(v.shape) == 1:
            break
        levels.append(_pull(v, w))
    filled, w = levels[-1]
    if not (w > 0).all():
        filled = np.where(w > 0, filled, np.sum(filled * w) / w.sum())
    for v, w in reversed(levels[:-1]):
        filled = _push(filled, v, w)
    return filled


@numba.njit(cache=True, parallel=True)
def _bilinear(a, x, y, w):
    nrows, ncols = a.shape
    out = np.empty(len(x))
    for k in numba.prange(len(x)):
        # fractional cell index of the point in ``_GridWindow`` ``w``, clamped to the cell centres (edge cells
        # extended)
        r = min(max((y[k] - w.y0) / w.cell_m - 0.5 - w.row0, 0.0), nrows - 1.0)
        c = min(max((x[k] - w.x0) / w.cell_m - 0.5 - w.col0, 0.0), ncols - 1.0)
        i, j = min(int(r), nrows - 2) if nrows > 1 else 0, min(int(c), ncols - 2) if ncols > 1 else 0
        fr, fc = r - i, c - j
        i1, j1 = min(i + 1, nrows - 1), min(j + 1, ncols - 1)
        out[k] = ((1.0 - fr) * ((1.0 - fc) * a[i, j] + fc * a[i, j1])
                  + fr * ((1.0 - fc) * a[i1, j] + fc * a[i1, j1]))
    return out


def sample_bilinear(a: np.ndarray, x, y, *, cell_m, x0, y0, row0: int = 0, col0: int = 0) -> np.ndarray:
    """Bilinear interpolation of a filled raster at points (edge cells extended): the values of
    ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``, in a parallel numba loop (about 10x
    faster on 2 cores; the classifier samples its DEMs at every point several times). ``row0``,
    ``col0``: the raster is the window of a larger grid with origin (x0, y0) starting at that cell (tiles)."""
    return _bilinear(np.ascontiguousarray(a, float), np.asarray(x, float), np.asarray(y, float),
                     _GridWindow(float(cell_m), float(x0), float(y0), float(row0), float(col0)))


def slope_tan(a: np.ndarray, cell_m: float) -> np.ndarray:
    """Tangent of the terrain slope (gradient magnitude) of a filled raster; along a side of one cell (a cloud
    narrower than two cells) the slope across it is unknown and taken as 0."""
    a = np.asarray(a, float)
    gy = np.gradient(a, cell_m, axis=0) if a.shape[0] > 1 else np.zeros_like(a)
    gx = np.gradient(a, cell_m, axis=1) if a.shape[1] > 1 else np.zeros_like(a)
    return np.hypot(gx, gy)


def plane_rms(a: np.ndarray, cell_m: float) -> np.ndarray:
    """RMS residual of the least-squares plane in each 3x3 window of a filled raster (m)."""
    k = np.ones((3, 3)) / 9.0
    u = np.array([[-1, 0, 1]] * 3, float) * cell_m      # x offsets (columns)
    v = u.T                                              # y offsets (rows)
    mean = ndimage.correlate(a, k, mode="nearest")
    mean2 = ndimage.correlate(a * a, k, mode="nearest")
    sxz = ndimage.correlate(a, u / 9.0, mode="nearest")
    syz = ndimage.correlate(a, v / 9.0, mode="nearest")
    var_uv = (2.0 / 3.0) * cell_m * cell_m              # mean of u^2 over the window
    resid2 = mean2 - mean ** 2 - sxz ** 2 / var_uv - syz ** 2 / var_uv
    return np.sqrt(np.maximum(resid2, 0.0))


def rimmed_dropouts(occupied: np.ndarray, rim: np.ndarray, blocked: np.ndarray | None = None) -> np.ndarray:
    """Cells that returned no pulse and lie in a region rimmed mostly by ``rim`` cells: the regions of cells
    without a return (not ``occupied``; opened by one cell, so at least three cells wide: a sampling gap is no
    dropout; 8-connected; off the grid's border) where more than half of the cells with returns around them
    are ``rim`` and none ``blocked``. A glass, wet or black roof returns few or no pulses and is seen by its
    rim alone; a scan shadow beside a wall has ground on its other sides."""
    eight = np.ones((3, 3), bool)
    lab, n = ndimage.label(ndimage.binary_opening(~occupied, structure=eight), structure=eight)
    if n == 0:
        return np.zeros(occupied.shape, bool)
    # each cell with returns counted for the empty region beside it (two regions meet at a cell rarely: one of
    # them takes it)
    rim_of = np.where(occupied, ndimage.grey_dilation(lab, footprint=eight), 0)
    total = np.bincount(rim_of.ravel(), minlength=n + 1)
    on_rim = np.bincount(rim_of.ravel(), weights=rim.ravel(), minlength=n + 1)
    keep = 2 * on_rim > total
    if blocked is not None:
        keep &= np.bincount(rim_of.ravel(), weights=blocked.ravel(), minlength=n + 1) == 0
    keep[np.unique(np.r_[lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = False
    keep[0] = False
    return keep[lab]


DEFAULT_TIN_FILL_RADIUS_PX = 64
"""Largest circumradius (cells) of a TIN triangle that fills a DEM gap; gaps needing larger triangles
(open water, survey edges) keep the pull-push fill."""


@numba.njit(cache=True, nogil=True)
def _jittered_cells(rows, cols):
    """(n, 2) (column, row) of the centres of global cells (``rows``, ``cols``), each moved by a fixed
    sub-cell offset (at most 0.005 cell) hashed from its index: cell centres of a regular grid are
    cocircular, so their Delaunay triangulation is not unique; a jitter that depends only on the cell's
    global index makes it unique, and a tile triangulates its part of the grid as the whole grid does.
    (The arithmetic of the array version this replaced, bit for bit.)"""
    out = np.empty((len(rows), 2))
    for k in range(len(rows)):
        h = (np.uint64(rows[k]) * np.uint64(73856093)) ^ (np.uint64(cols[k]) * np.uint64(19349663))
        h = (h * np.uint64(2654435761)) % np.uint64(1 << 32)
        u = float(h) / float(1 << 32)
        v = u * 1024.0
        out[k, 0] = cols[k] + 0.01 * ((v - np.floor(v)) - 0.5)
        out[k, 1] = rows[k] + 0.01 * (u - 0.5)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _fill_triangle(filled, gaps, done, corners, heights, max_radius_px, origin):
    """``_fill_triangles``' work for one triangle: ``corners`` (x0, y0, x1, y1, x2, y2) and ``heights`` (z0, z1,
    z2) of its vertices in increasing index order."""
    x0, y0, x1, y1, x2, y2 = corners
    z0, z1, z2 = heights
    row0, col0 = origin
    nrows, ncols = gaps.shape
    eps = 1e-12
    if max(x0, x1, x2) - min(x0, x1, x2) < 1.5 and max(y0, y1, y2) - min(y0, y1, y2) < 1.5:
        # three corners of one 2 x 2 block of cells (jitter < 0.005 cell): the only other cell centre
        # in its bounding box is the fourth corner, about 0.7 cell outside it; most triangles
        return
    cmin = max(int(np.ceil(min(x0, x1, x2))) - col0, 0)
    cmax = min(int(np.floor(max(x0, x1, x2))) - col0, ncols - 1)
    rmin = max(int(np.ceil(min(y0, y1, y2))) - row0, 0)
    rmax = min(int(np.floor(max(y0, y1, y2))) - row0, nrows - 1)
    e1x, e1y = x1 - x0, y1 - y0
    e2x, e2y = x2 - x0, y2 - y0
    det = e1x * e2y - e1y * e2x
    checked = False          # the circumradius, computed for triangles that hold a gap cell
    for r in range(rmin, rmax + 1):
        for c in range(cmin, cmax + 1):
            if not gaps[r, c] or done[r, c]:
                continue
            if not checked:
                # circumradius R = abc / (4 area)
                a_len = np.hypot(x1 - x2, y1 - y2)
                b_len = np.hypot(e2x, e2y)
                c_len = np.hypot(e1x, e1y)
                if a_len * b_len * c_len / max(2.0 * abs(det), 1e-12) > max_radius_px:
                    return
                checked = True
            dx, dy = (c + col0) - x0, (r + row0) - y0
            l1 = (dx * e2y - dy * e2x) / det
            l2 = (e1x * dy - e1y * dx) / det
            l0 = 1.0 - l1 - l2
            if l0 < -eps or l1 < -eps or l2 < -eps:
                continue
            filled[r, c] = l0 * z0 + l1 * z1 + l2 * z2
            done[r, c] = True


@numba.njit(cache=True, nogil=True)
def _fill_triangles(filled, gaps, tin, max_radius_px, origin):
    """Linear interpolation of the gap cells of ``filled`` inside each triangle of the ``tin`` (pts, z,
    simplices) of circumradius at most ``max_radius_px``: every triangle visits the cell centres of its
    bounding box (scan conversion), instead of a point location per gap cell. ``pts`` are (col, row) in
    global cells, the window's first cell at ``origin`` (row0, col0); a triangle's vertices are taken in
    increasing index order (by global cell), so that a tile computes bit-identical weights. A cell on an edge
    shared by two triangles takes the first."""
    pts, z, simplices = tin
    done = np.zeros_like(gaps)
    for t in range(simplices.shape[0]):
        i0, i1, i2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
        if i0 > i1:
            i0, i1 = i1, i0
        if i1 > i2:
            i1, i2 = i2, i1
        if i0 > i1:
            i0, i1 = i1, i0
        _fill_triangle(filled, gaps, done, (pts[i0, 0], pts[i0, 1], pts[i1, 0], pts[i1, 1], pts[i2, 0], pts[i2, 1]),
                       (z[i0], z[i1], z[i2]), max_radius_px, origin)


@numba.njit(cache=True, nogil=True)
def _fill_mesh(filled, gaps, points, mesh, max_radius_px, origin):
    """``_fill_triangles`` of the real triangles of a ``raster_tin`` mesh in its slot order (``_bw_triangles``'
    order), read in place; ``points``: (x, y, z, index) of the mesh's points, ``index`` their indices in the
    fill's ``pts`` (the vertex order of the weights)."""
    px, py, pz, index = points
    tri, _, _, _, state = mesh
    inf, nt = state[0], state[1]
    done = np.zeros_like(gaps)
    for t in range(nt):
        a, b, c = tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]
        if a == inf or b == inf or c == inf:
            continue
        if index[a] > index[b]:
            a, b = b, a
        if index[b] > index[c]:
            b, c = c, b
        if index[a] > index[b]:
            a, b = b, a
        _fill_triangle(filled, gaps, done, (px[a], py[a], px[b], py[b], px[c], py[c]), (pz[a], pz[b], pz[c]),
                       max_radius_px, origin)


@numba.njit(cache=True, nogil=True)
def _rim_cells(gaps, r_lo, r_hi, c_lo, c_hi):
    """(rows, cols) in row-major order of the cells of rows r_lo..r_hi, cols c_lo..c_hi that are not gaps
    and have a gap within 2 cells (a 5 x 5 square; outside the array is no gap): ``np.nonzero`` of
    ``~gaps & ndimage.maximum_filter(gaps, size=5, mode="constant", cval=False)`` in that window."""
    nrows, ncols = gaps.shape
    g0 = max(r_lo - 2, 0)
    g1 = min(r_hi + 2, nrows)
    near = np.zeros((g1 - g0, c_hi - c_lo), np.bool_)      # a gap within 2 columns
    for i in range(g0, g1):
        last = -3                                           # the last gap column seen
        for j in range(max(c_lo - 2, 0), min(c_hi + 2, ncols)):
            if gaps[i, j]:
                last = j
                for jj in range(max(j - 2, c_lo), min(j, c_hi)):
                    near[i - g0, jj - c_lo] = True
            if c_lo <= j < c_hi and j - last <= 2:
                near[i - g0, j - c_lo] = True
    n = 0
    for i in range(r_lo, r_hi):
        for j in range(c_lo, c_hi):
            if not gaps[i, j]:
                for ii in range(max(i - 2, g0), min(i + 3, g1)):
                    if near[ii - g0, j - c_lo]:
                        n += 1
                        break
    out_r = np.empty(n, np.int64)
    out_c = np.empty(n, np.int64)
    n = 0
    for i in range(r_lo, r_hi):
        for j in range(c_lo, c_hi):
            if not gaps[i, j]:
                for ii in range(max(i - 2, g0), min(i + 3, g1)):
                    if near[ii - g0, j - c_lo]:
                        out_r[n] = i
                        out_c[n] = j
                        n += 1
                        break
    return out_r, out_c


# Cells triangulated beyond the needed cells before the certification (``_certified_tin``): a margin of a few
# cells decides most of them; the points beyond are inserted only where a cell's triangle reaches them.
TIN_INNER_MARGIN_PX = 16


def fill_nodata_tin(a: np.ndarray, max_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX,
                    offset: tuple[int, int] = (0, 0), needed=None) -> np.ndarray:
    """Fill NaN cells by linear interpolation in the Delaunay TIN of the valid cells around the gaps
    (as production DEMs interpolate ground under buildings and sparse canopy ground); cells whose
    triangle has a circumradius above ``max_radius_px`` cells, or that lie outside the TIN, keep the
    pull-push fill (``fill_nodata``).

    Local by construction: a cell's value depends only on valid cells within ``2 * max_radius_px + 2``
    cells, so a window of a larger grid (``offset``: its first cell's (row, col) there) gets the same
    values as the whole grid wherever it has that margin. ``needed``: (row slice, col slice) of the
    cells whose values the caller uses; they get the triangles of the rim cells within that distance
    (``_certified_tin``: most of those far from them are never triangulated); the cells beyond
    that distance keep the pull-push fill, the others between may have either.
    """
    a = np.asarray(a, float)
    filled = fill_nodata(a)
    valid = np.isfinite(a)
    if valid.all() or not valid.any():
        return filled
    gaps = ~valid
    # the vertices of a gap's triangles are the valid cells at its rim: within 2 cells (a 5 x 5 square) of a gap
    rows, cols = slice(0, a.shape[0]), slice(0, a.shape[1])
    if needed is not None:
        m = int(np.ceil(2 * max_radius_px)) + 3
        rows, cols = (slice(max(s.start - m, 0), min(s.stop + m, n)) for s, n in zip(needed, a.shape))
    vr, vc = _rim_cells(gaps, rows.start, rows.stop, cols.start, cols.stop)
    if len(vr) < 3:
        return filled
    gr, gc = vr + offset[0], vc + offset[1]
    pts = _jittered_cells(gr, gc)
    if needed is not None:
        certified = _certified_tin(pts, (gr, gc), gaps, (needed, (rows, cols)), float(max_radius_px), offset)
        if certified is not None:
            mesh, index, px, py = certified
            _fill_mesh(filled, gaps, (px, py, a[vr[index], vc[index]], index), mesh, float(max_radius_px),
                       (offset[0], offset[1]))
            return filled
    simplices, status = delaunay_lattice(pts, gr, gc)
    if status == COLLINEAR:     # all rim cells on one line
        return filled
    if status != OK:            # cannot happen with exact predicates; Qhull gives the same triangles
        from scipy.spatial import Delaunay, QhullError  # only here: its import costs 0.1 CPU-s of the stage

        log.warning("TIN fill: the Delaunay insertion failed on %d cells; using Qhull", len(pts))
        try:
            simplices = Delaunay(pts).simplices
        except QhullError:
            return filled
    _fill_triangles(filled, gaps, (pts, a[vr, vc], simplices), float(max_radius_px), (offset[0], offset[1]))
    return filled


@numba.njit(cache=True, nogil=True)
def _split_inner(gr, gc, bounds):
    """Positions (int32, in order) of the cells (global ``gr``, ``gc``) inside the rows r0..r1 - 1 and columns
    c0..c1 - 1 of ``bounds`` (r0, r1, c0, c1), and of the others."""
    r0, r1, c0, c1 = bounds
    n_in = 0
    for k in range(len(gr)):
        n_in += r0 <= gr[k] < r1 and c0 <= gc[k] < c1
    inside = np.empty(n_in, np.int32)
    outside = np.empty(len(gr) - n_in, np.int32)
    a, b = 0, 0
    for k in range(len(gr)):
        if r0 <= gr[k] < r1 and c0 <= gc[k] < c1:
            inside[a] = k
            a += 1
        else:
            outside[b] = k
            b += 1
    return inside, outside


@numba.njit(cache=True, nogil=True)
def _wanted_cells(gaps, needed, far, open_side, offset):
    """(k, 2) global (row, col), row-major, of the gap cells of the ``needed`` rows and columns (r0, r1, c0,
    c1 of the window) that are not ``far`` (r0, r1, c0, c1: rows at or after r0 and before r1 ... are far
    from the sides that are ``open``: top, bottom, left, right)."""
    n0, n1, m0, m1 = needed
    f0, f1, g0, g1 = far
    top, bottom, left, right = open_side
    count = 0
    for rep in range(2):
        if rep == 1:
            out = np.empty((count, 2), np.int64)
            count = 0
        for i in range(n0, n1):
            row_near = (top and i < f0) or (bottom and i >= f1)
            for j in range(m0, m1):
                if gaps[i, j] and (row_near or (left and j < g0) or (right and j >= g1)):
                    if rep == 1:
                        out[count, 0] = i + offset[0]
                        out[count, 1] = j + offset[1]
                    count += 1
    return out


@numba.njit(cache=True, nogil=True)
def _outer_points(br, bc, first, shape, inner, block):
    """The lookup of ``_conflicts_near``: point index (``first`` + k) at the cells (``br``, ``bc``), -1 at the
    other cells outside ``inner`` (r0, r1, c0, c1; not set inside it), and the summed-area table of the points
    by blocks of ``block`` x ``block`` cells."""
    r0, r1, c0, c1 = inner
    point_at = np.empty(shape, np.int32)
    for i in range(shape[0]):
        if r0 <= i < r1:
            point_at[i, :max(c0, 0)] = -1
            point_at[i, max(c1, 0):] = -1
        else:
            point_at[i, :] = -1
    nb0, nb1 = -(-shape[0] // block), -(-shape[1] // block)
    sat = np.zeros((nb0 + 1, nb1 + 1), np.int64)
    for k in range(len(br)):
        point_at[br[k], bc[k]] = first + k
        sat[br[k] // block + 1, bc[k] // block + 1] += 1
    for i in range(1, nb0 + 1):
        for j in range(1, nb1 + 1):
            sat[i, j] += sat[i - 1, j] + sat[i, j - 1] - sat[i - 1, j - 1]
    return point_at, sat


@numba.njit(cache=True, nogil=True)
def _mesh_points(pts, cells, inner, band):
    """The order of the mesh's points: the cells ``inner`` (positions in ``pts`` and ``cells``: global
    rows, cols) in the order of ``raster_tin._insertion_keys``, then ``band`` as given; returns (index, x, y)
    of the points in that order (``delaunay_lattice``'s order for the inner cells, without its temporaries)."""
    gr, gc = cells
    n_in = len(inner)
    rmin, cmin = gr[inner[0]], gc[inner[0]]
    for k in range(n_in):
        rmin, cmin = min(rmin, gr[inner[k]]), min(cmin, gc[inner[k]])
    ix = np.empty(n_in, np.int64)
    iy = np.empty(n_in, np.int64)
    top = 0
    for k in range(n_in):
        ix[k], iy[k] = gc[inner[k]] - cmin, gr[inner[k]] - rmin
        top = max(top, ix[k], iy[k])
    bits = 0
    while top > 0:
        bits += 1
        top >>= 1
    bits = max(bits, 1)
    order = _argsort_keys(_insertion_keys(ix, iy, bits), 2 * bits + 5)
    n = n_in + len(band)
    index = np.empty(n, np.int32)
    px, py = np.empty(n), np.empty(n)
    for k in range(n):
        q = inner[order[k]] if k < n_in else band[k - n_in]
        index[k] = q
        px[k], py[k] = pts[q, 0], pts[q, 1]
    return index, px, py


def _certified_tin(pts, cells, gaps, regions, max_radius_px: float, offset):
    """The triangulation of the TIN fill that holds the needed gap cells' triangles, made of the rim cells near
    them and only those farther away that can change them. ``pts``, ``cells``: the rim cells of the ``outer``
    region (global rows, cols, row-major), ``regions``: (needed, outer) (row slice, col slice) of the
    window. Returns (mesh, index, x, y): the ``raster_tin`` mesh, the indices in ``pts`` of its points and
    their coordinates (``_fill_mesh``); None when the plain triangulation of all of them is wanted (nothing
    to save, or a degenerate case).

    Why it is the same: the cells within ``TIN_INNER_MARGIN_PX`` of the needed ones are triangulated first;
    then every needed gap cell close enough to the outer rim cells to see them (within 2 R of them, R the fill's
    largest circumradius) is located, and the outer points within 2 R of it and in conflict with its triangle
    (inside its circumcircle; beyond its hull edge) are inserted, until there are none. A triangle whose
    circumradius is at most R and that holds the cell lies within 2 R of it, so its circumcircle is then empty
    of all the rim cells: it is the cell's triangle in their Delaunay triangulation; if that one had a larger
    circumradius (or none held the cell) one of its vertices would still be in conflict. The remaining
    triangles are Delaunay triangles of a subset of the points: they hold the other cells differently, and
    those cells are not used."""
    needed, (rows, cols) = regions
    needed = tuple(slice(max(s.start, 0), min(s.stop, n)) for s, n in zip(needed, gaps.shape))
    margin = TIN_INNER_MARGIN_PX
    reach = 2.0 * max_radius_px
    inner = [(max(s.start - margin, o.start), min(s.stop + margin, o.stop)) for s, o in zip(needed, (rows, cols))]
    # sides of the inner region with outer rim cells beyond them: top, bottom, left, right
    open_side = (inner[0][0] > rows.start, inner[0][1] < rows.stop, inner[1][0] > cols.start, inner[1][1] < cols.stop)
    if not any(open_side):
        return None
    gr, gc = cells
    inner_idx, band_idx = _split_inner(gr, gc, (inner[0][0] + offset[0], inner[0][1] + offset[0],
                                                inner[1][0] + offset[1], inner[1][1] + offset[1]))
    if len(inner_idx) < 3:
        return None
    n_in = len(inner_idx)
    index, px, py = _mesh_points(pts, (gr, gc), inner_idx, band_idx)     # mesh point k: pts[index[k]]
    del inner_idx
    mesh = _new_mesh(len(index))
    seq = np.arange(n_in, dtype=np.int32)
    k0 = _bw_start(px, py, seq, mesh)
    if k0 < 0 or _bw_insert(px, py, np.concatenate((seq[2:k0], seq[k0 + 1:])), mesh) != OK:
        return None
    del seq
    # the needed gap cells within reach of the outer rim cells: near an open side of the inner region
    d = int(np.ceil(reach)) + 1
    wanted = _wanted_cells(gaps, (needed[0].start, needed[0].stop, needed[1].start, needed[1].stop),
                           (inner[0][0] + d, inner[0][1] - d, inner[1][0] + d, inner[1][1] - d), open_side, offset)
    if len(wanted):
        # the outer points by cell of the outer region (-1: none; not set inside the inner region, never read),
        # which are in the mesh, and their count by blocks
        inner_rel = (inner[0][0] - rows.start, inner[0][1] - rows.start, inner[1][0] - cols.start,
                     inner[1][1] - cols.start)
        block = 16
        point_at, sat = _outer_points(gr[band_idx] - offset[0] - rows.start, gc[band_idx] - offset[1] - cols.start,
                                      n_in, (rows.stop - rows.start, cols.stop - cols.start), inner_rel, block)
        inserted = np.zeros(len(index), np.bool_)
        inserted[:n_in] = True
        grid = (point_at, inserted, (rows.start + offset[0], cols.start + offset[1]), inner_rel, sat, block)
        out = np.empty(len(band_idx), np.int32)
        cell_tri = np.empty(len(wanted), np.int32)
        tri_mark = mesh[2]
        while len(wanted):
            if not _locate_cells(px, py, mesh, wanted, cell_tri):
                return None
            # each triangle once, with the bounding box of its cells
            by_tri = np.argsort(cell_tri, kind="stable")
            t_sorted = cell_tri[by_tri]
            starts = np.flatnonzero(np.r_[True, t_sorted[1:] != t_sorted[:-1]])
            cy, cx = wanted[by_tri, 0].astype(float), wanted[by_tri, 1].astype(float)
            boxes = np.column_stack((np.minimum.reduceat(cy, starts), np.maximum.reduceat(cy, starts),
                                     np.minimum.reduceat(cx, starts), np.maximum.reduceat(cx, starts)))
            found = _conflicts_near(px, py, mesh, t_sorted[starts], boxes, grid, reach, out)
            if found == 0:
                break
            stamp = mesh[4][3]
            if _bw_insert(px, py, out[:found].copy(), mesh) != OK:
                return None
            # again only the cells whose triangles the insertions replaced (the others keep theirs, and fewer
            # points are left to conflict with them)
            replaced = tri_mark[cell_tri] > stamp
            wanted, cell_tri = wanted[replaced], cell_tri[replaced]
    return mesh, index, px, py
