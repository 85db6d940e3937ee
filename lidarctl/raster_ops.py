"""Grid operations on height rasters: minimum surfaces, gap filling, bilinear sampling, slope, roughness.

Rasters here are NumPy arrays with row 0 at the *south* edge (row index grows with y) and cell
(i, j) centred at (x0 + (j + 0.5) * cell_m, y0 + (i + 0.5) * cell_m); NaN marks empty cells.
Writers flip rows to the north-up GeoTIFF convention.
"""

from __future__ import annotations

import logging

import numba
import numpy as np
from scipy import ndimage

from lidarctl.grid import GRID_BYTES_PER_CELL, check_grid
from lidarctl.raster_tin import COLLINEAR, OK, delaunay_lattice

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


@numba.njit(cache=True)
def _cell_of(x, y, cell_m, x0, y0, nrows, ncols):
    """Flat cell of a point, -1 off the grid (or NaN)."""
    jf = np.floor((x - x0) / cell_m)
    i_f = np.floor((y - y0) / cell_m)
    if not (jf >= 0 and jf < ncols and i_f >= 0 and i_f < nrows):
        return -1
    return int(i_f) * ncols + int(jf)


@numba.njit(cache=True)
def _cell_extreme_xy(x, y, v, cell_m, x0, y0, nrows, ncols, sign):
    out = np.full(nrows * ncols, np.nan)
    for k in range(len(x)):
        c = _cell_of(x[k], y[k], cell_m, x0, y0, nrows, ncols)
        if c >= 0 and (np.isnan(out[c]) or sign * v[k] < sign * out[c]):
            out[c] = v[k]
    return out


@numba.njit(cache=True)
def _cell_sums(x, y, v, cell_m, x0, y0, nrows, ncols):
    """Per-cell sum (in point order, as np.bincount adds) and count of ``v``."""
    s = np.zeros(nrows * ncols)
    n = np.zeros(nrows * ncols)
    for k in range(len(x)):
        c = _cell_of(x[k], y[k], cell_m, x0, y0, nrows, ncols)
        if c >= 0:
            s[c] += v[k]
            n[c] += 1.0
    return s, n


def reduce_grid(x, y, values, cell_m, x0, y0, nrows, ncols, how: str = "min") -> np.ndarray:
    """Per-cell min / max / mean of ``values``; NaN where no point falls. A grid larger than the
    machine's RAM is a ResourceError before anything is allocated."""
    check_grid(nrows, ncols, cell_m, GRID_BYTES_PER_CELL, "the points' extent",
               hint="are strips far apart (different zones or CRSs) in one cloud?")
    if how not in ("min", "max", "mean"):
        raise ValueError(how)
    x, y, v = np.asarray(x, float), np.asarray(y, float), np.asarray(values, float)
    if how == "mean":
        s, n = _cell_sums(x, y, v, float(cell_m), float(x0), float(y0), int(nrows), int(ncols))
        with np.errstate(invalid="ignore"):
            out = s / n
    else:
        out = _cell_extreme_xy(x, y, v, float(cell_m), float(x0), float(y0), int(nrows), int(ncols),
                               1.0 if how == "min" else -1.0)
    return out.reshape(nrows, ncols)


def fill_nodata(a: np.ndarray) -> np.ndarray:
    """Fill NaN cells by pull-push (pyramid averaging, then coarse-to-fine fill); smooth and O(n)."""
    a = np.asarray(a, float)
    valid = np.isfinite(a)
    if valid.all() or not valid.any():
        return a.copy()
    levels = [(np.where(valid, a, 0.0), valid.astype(float))]
    while True:
        v, w = levels[-1]
        if (w > 0).all() or min(v.shape) == 1:
            break
        h, wd = (v.shape[0] + 1) // 2 * 2, (v.shape[1] + 1) // 2 * 2
        vp = np.zeros((h, wd)); wp = np.zeros((h, wd))
        vp[:v.shape[0], :v.shape[1]] = v * w
        wp[:v.shape[0], :v.shape[1]] = w
        ws = wp.reshape(h // 2, 2, wd // 2, 2).sum(axis=(1, 3))
        vs = vp.reshape(h // 2, 2, wd // 2, 2).sum(axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            levels.append((np.where(ws > 0, vs / np.maximum(ws, 1e-12), 0.0), (ws > 0).astype(float)))
    filled, _ = levels[-1]
    if not (levels[-1][1] > 0).all():
        filled = np.where(levels[-1][1] > 0, filled, np.sum(filled * levels[-1][1]) / levels[-1][1].sum())
    for v, w in reversed(levels[:-1]):
        up = np.repeat(np.repeat(filled, 2, axis=0), 2, axis=1)[:v.shape[0], :v.shape[1]]
        filled = np.where(w > 0, v, up)
    return filled


@numba.njit(cache=True, parallel=True)
def _bilinear(a, x, y, cell_m, x0, y0, row0, col0):
    nrows, ncols = a.shape
    out = np.empty(len(x))
    for k in numba.prange(len(x)):
        # fractional cell index of the point, clamped to the cell centres (edge cells extended)
        r = min(max((y[k] - y0) / cell_m - 0.5 - row0, 0.0), nrows - 1.0)
        c = min(max((x[k] - x0) / cell_m - 0.5 - col0, 0.0), ncols - 1.0)
        i, j = min(int(r), nrows - 2) if nrows > 1 else 0, min(int(c), ncols - 2) if ncols > 1 else 0
        fr, fc = r - i, c - j
        i1, j1 = min(i + 1, nrows - 1), min(j + 1, ncols - 1)
        out[k] = ((1.0 - fr) * ((1.0 - fc) * a[i, j] + fc * a[i, j1])
                  + fr * ((1.0 - fc) * a[i1, j] + fc * a[i1, j1]))
    return out


def sample_bilinear(a: np.ndarray, x, y, cell_m, x0, y0, row0: int = 0, col0: int = 0) -> np.ndarray:
    """Bilinear interpolation of a filled raster at points (edge cells extended): the values of
    ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``, in a parallel numba loop (about 10x
    faster on 2 cores; the classifier samples its DEMs at every point several times). ``row0``,
    ``col0``: the raster is the window of a larger grid with origin (x0, y0) starting at that cell (tiles)."""
    return _bilinear(np.ascontiguousarray(a, float), np.asarray(x, float), np.asarray(y, float),
                     float(cell_m), float(x0), float(y0), float(row0), float(col0))


def slope_tan(a: np.ndarray, cell_m: float) -> np.ndarray:
    """Tangent of the terrain slope (gradient magnitude) of a filled raster."""
    gy, gx = np.gradient(a, cell_m)
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


DEFAULT_TIN_FILL_RADIUS_PX = 64
"""Largest circumradius (cells) of a TIN triangle that fills a DEM gap; gaps needing larger triangles
(open water, survey edges) keep the pull-push fill."""


def _lattice_jitter(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fixed sub-cell offset per global cell (at most 0.01 cell): cell centres of a regular grid are
    cocircular, so their Delaunay triangulation is not unique; a jitter that depends only on the cell's
    global index makes it unique, and a tile triangulates its part of the grid as the whole grid does."""
    h = (rows.astype(np.uint64) * np.uint64(73856093)) ^ (cols.astype(np.uint64) * np.uint64(19349663))
    h = (h * np.uint64(2654435761)) % np.uint64(1 << 32)
    u = h.astype(float) / float(1 << 32)
    return 0.01 * (u - 0.5), 0.01 * (np.modf(u * 1024.0)[0] - 0.5)



@numba.njit(cache=True)
def _fill_triangles(filled, gaps, pts, z, simplices, max_radius_px, row0, col0):
    """Linear interpolation of the gap cells of ``filled`` inside each triangle of circumradius at most
    ``max_radius_px``: every triangle visits the cell centres of its bounding box (scan conversion),
    instead of a point location per gap cell (Qhull's walk degenerates on a near-regular lattice and
    falls back to a search over all triangles). ``pts`` are (col, row) in global cells, the window's
    first cell at (``row0``, ``col0``). A cell on an edge shared by two triangles takes the first."""
    nrows, ncols = gaps.shape
    done = np.zeros_like(gaps)
    eps = 1e-12
    for t in range(simplices.shape[0]):
        i0, i1, i2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
        x0, y0 = pts[i0, 0], pts[i0, 1]
        e1x, e1y = pts[i1, 0] - x0, pts[i1, 1] - y0
        e2x, e2y = pts[i2, 0] - x0, pts[i2, 1] - y0
        det = e1x * e2y - e1y * e2x
        # circumradius R = abc / (4 area)
        a_len = np.hypot(pts[i1, 0] - pts[i2, 0], pts[i1, 1] - pts[i2, 1])
        b_len = np.hypot(e2x, e2y)
        c_len = np.hypot(e1x, e1y)
        if a_len * b_len * c_len / max(2.0 * abs(det), 1e-12) > max_radius_px:
            continue
        cmin = int(np.ceil(min(x0, pts[i1, 0], pts[i2, 0]))) - col0
        cmax = int(np.floor(max(x0, pts[i1, 0], pts[i2, 0]))) - col0
        rmin = int(np.ceil(min(y0, pts[i1, 1], pts[i2, 1]))) - row0
        rmax = int(np.floor(max(y0, pts[i1, 1], pts[i2, 1]))) - row0
        for r in range(max(rmin, 0), min(rmax, nrows - 1) + 1):
            for c in range(max(cmin, 0), min(cmax, ncols - 1) + 1):
                if not gaps[r, c] or done[r, c]:
                    continue
                dx, dy = (c + col0) - x0, (r + row0) - y0
                l1 = (dx * e2y - dy * e2x) / det
                l2 = (e1x * dy - e1y * dx) / det
                l0 = 1.0 - l1 - l2
                if l0 < -eps or l1 < -eps or l2 < -eps:
                    continue
                filled[r, c] = l0 * z[i0] + l1 * z[i1] + l2 * z[i2]
                done[r, c] = True


def fill_nodata_tin(a: np.ndarray, max_radius_px: float = DEFAULT_TIN_FILL_RADIUS_PX,
                    offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Fill NaN cells by linear interpolation in the Delaunay TIN of the valid cells around the gaps
    (as production DEMs interpolate ground under buildings and sparse canopy ground); cells whose
    triangle has a circumradius above ``max_radius_px`` cells, or that lie outside the TIN, keep the
    pull-push fill (``fill_nodata``).

    Local by construction: a cell's value depends only on valid cells within ``2 * max_radius_px + 2``
    cells, so a window of a larger grid (``offset``: its first cell's (row, col) there) gets the same
    values as the whole grid wherever it has that margin.
    """
    from scipy.spatial import Delaunay, QhullError

    a = np.asarray(a, float)
    filled = fill_nodata(a)
    valid = np.isfinite(a)
    if valid.all() or not valid.any():
        return filled
    gaps = ~valid
    # the vertices of a gap's triangles are the valid cells at its rim
    rim = valid & ndimage.binary_dilation(gaps, np.ones((3, 3), bool), iterations=2)
    vr, vc = np.nonzero(rim)
    if len(vr) < 3:
        return filled
    gr, gc = vr + offset[0], vc + offset[1]
    jr, jc = _lattice_jitter(gr, gc)
    pts = np.column_stack([gc + jc, gr + jr]).astype(float)
    simplices, status = delaunay_lattice(pts, gr, gc)
    if status == COLLINEAR:     # all rim cells on one line
        return filled
    if status != OK:            # cannot happen with exact predicates; Qhull gives the same triangles
        log.warning("TIN fill: the Delaunay insertion failed on %d cells; using Qhull", len(pts))
        try:
            simplices = Delaunay(pts).simplices
        except QhullError:
            return filled
    # vertices in a canonical order (by global cell), so that a tile computes bit-identical weights
    simplices = np.sort(simplices, axis=1)
    _fill_triangles(filled, gaps, pts, a[vr, vc], simplices, float(max_radius_px), offset[0], offset[1])
    return filled
