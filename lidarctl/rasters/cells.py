"""Per-cell statistics of a tile's points for the rasters (``rasters._CellSums``), one pass per chunk.

The sums are the ones ``np.bincount`` makes, bit for bit: every chunk's points are summed in their
order into a chunk total starting at 0, which is then added to the running sum (so a cell's mean
does not depend on whether these loops or the array version made it); counts and maxima do not
depend on the order. Cells are in a window of a larger grid: (row, col) = floor((y - y0) / res,
(x - x0) / res) minus the window's first cell (``row0``, ``col0``).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

NOT_VALID = (7, 18)      # noise classes: not in the occupancy, the DSM or the intensity
BUILDING = 6             # building returns: the roofs above wall returns (``beneath``)
GROUND = (2, 9)          # ground and water: the DEM
VEGETATION = (4, 5)      # medium and high vegetation: the CHM
LOW_VEGETATION = 3       # not in the CHM (grass and crops are no canopy)


# columns of the per-cell records (one record per cell: a point touches one or two cache lines, not seven)
_SLOT, _VALID_N, _GROUND_N, _INTEN_N = 0, 1, 2, 3                      # int32 (2^31 points a cell)
_DSM, _GROUND_SUM, _INTEN_SUM, _TOP, _BUILDING_TOP, _BOTTOM = 0, 1, 2, 3, 4, 5   # float64
# columns of a chunk's sums, one row per cell the chunk touches (its slot)
_GROUND_CHUNK, _INTEN_CHUNK = 0, 1


class _Window(NamedTuple):
    """The window as the kernels take it: cell size (m), the larger grid's origin (m), the window's first cell
    and its size in cells."""

    res_m: float
    x0: float
    y0: float
    row0: int
    col0: int
    nrows: int
    ncols: int


class _Returns(NamedTuple):
    """A chunk of points as ``_accumulate`` takes it (x, y, z in metres)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    cls: np.ndarray
    return_number: np.ndarray
    intensity: np.ndarray


class _Classified(NamedTuple):
    """A chunk of points as ``_chm_max`` takes it (x, y, z in metres)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    cls: np.ndarray


@numba.njit(cache=True, nogil=True)
def _accumulate(pts, win, counts, sums, touched, chunk_sums):
    """One chunk (``_Returns``) into the records of the ``_Window`` (``counts``, ``sums``: one row per flat
    cell). Returns the index of the first point off the window, or -1. The chunk's own sums go into rows of
    ``chunk_sums`` (as many as points), one per cell it touches: ``touched[slot]`` is the cell of a slot,
    ``counts[cell, _SLOT]`` its slot if ``touched`` says so (a sparse set: nothing to clear between chunks, and
    two columns fewer per cell of the window than stamps and chunk sums in the records)."""
    x, y, z, cls, rn, inten = pts.x, pts.y, pts.z, pts.cls, pts.return_number, pts.intensity
    res_m, x0, y0, row0, col0, nrows, ncols = win.res_m, win.x0, win.y0, win.row0, win.col0, win.nrows, win.ncols
    nt = 0
    for k in range(len(x)):
        j = np.int64(np.floor((x[k] - x0) / res_m)) - col0
        i = np.int64(np.floor((y[k] - y0) / res_m)) - row0
        if i < 0 or i >= nrows or j < 0 or j >= ncols:
            return k
        c = i * ncols + j
        cl = cls[k]
        ground = cl == 2 or cl == 9
        first = rn[k] == 1
        if cl == 7 or cl == 18:
            continue
        counts[c, _VALID_N] += 1
        if np.isnan(sums[c, _TOP]) or z[k] > sums[c, _TOP]:
            sums[c, _TOP] = z[k]
        if np.isnan(sums[c, _BOTTOM]) or z[k] < sums[c, _BOTTOM]:
            sums[c, _BOTTOM] = z[k]
        if cl == BUILDING and (np.isnan(sums[c, _BUILDING_TOP]) or z[k] > sums[c, _BUILDING_TOP]):
            sums[c, _BUILDING_TOP] = z[k]
        if not (ground or first):
            continue
        s = counts[c, _SLOT]
        if s >= nt or touched[s] != c:
            s = nt                               # the chunk's sums of this cell start at 0
            counts[c, _SLOT] = s
            touched[s] = c
            chunk_sums[s, _GROUND_CHUNK] = 0.0
            chunk_sums[s, _INTEN_CHUNK] = 0.0
            nt += 1
        if ground:
            chunk_sums[s, _GROUND_CHUNK] += z[k]
            counts[c, _GROUND_N] += 1
        if first:
            if np.isnan(sums[c, _DSM]) or z[k] > sums[c, _DSM]:
                sums[c, _DSM] = z[k]
            chunk_sums[s, _INTEN_CHUNK] += float(inten[k])
            counts[c, _INTEN_N] += 1
    for s in range(nt):
        c = touched[s]
        sums[c, _GROUND_SUM] += chunk_sums[s, _GROUND_CHUNK]
        sums[c, _INTEN_SUM] += chunk_sums[s, _INTEN_CHUNK]
    return -1


@numba.njit(cache=True, nogil=True)
def _chm_max(pts, dem, win, chm):
    """Highest height of vegetation points (``_Classified``) above the bilinear DEM per cell of the ``_Window``
    (``chm`` flat, NaN where none), the DEM sampled as ``raster_ops.sample_bilinear`` samples it (the same
    arithmetic). Returns the index of the first point off the window, or -1."""
    x, y, z, cls = pts.x, pts.y, pts.z, pts.cls
    res_m, x0, y0, row0, col0 = win.res_m, win.x0, win.y0, win.row0, win.col0
    nrows, ncols = dem.shape
    r0, c0 = float(row0), float(col0)
    for k in range(len(x)):
        cl = cls[k]
        if cl != 4 and cl != 5:
            continue
        r = min(max((y[k] - y0) / res_m - 0.5 - r0, 0.0), nrows - 1.0)
        c = min(max((x[k] - x0) / res_m - 0.5 - c0, 0.0), ncols - 1.0)
        i = min(int(r), nrows - 2) if nrows > 1 else 0
        j = min(int(c), ncols - 2) if ncols > 1 else 0
        fr, fc = r - i, c - j
        i1, j1 = min(i + 1, nrows - 1), min(j + 1, ncols - 1)
        ground = ((1.0 - fr) * ((1.0 - fc) * dem[i, j] + fc * dem[i, j1])
                  + fr * ((1.0 - fc) * dem[i1, j] + fc * dem[i1, j1]))
        hag = z[k] - ground
        jj = np.int64(np.floor((x[k] - x0) / res_m)) - col0
        ii = np.int64(np.floor((y[k] - y0) / res_m)) - row0
        if ii < 0 or ii >= nrows or jj < 0 or jj >= ncols:
            return k
        cell = ii * ncols + jj
        if np.isnan(chm[cell]) or hag > chm[cell]:
            chm[cell] = hag
    return -1


class CellStats:
    """Running per-cell statistics of a window of ``nrows`` x ``ncols`` cells (flat arrays): points
    not noise per cell (``valid_n``), the sum and count of ground heights (``ground_sum``,
    ``ground_n``), the highest first return (``dsm``, NaN where none), the highest return of any number (``top``,
    NaN where none), the highest building return (``building_top``, NaN where none), the lowest return of any number
    (``bottom``, NaN where none), the sum and count of
    first-return intensities (``inten_sum``, ``inten_n``), the highest vegetation above the DEM
    (``chm``, NaN where none)."""

    def __init__(self, res_m: float, x0: float, y0: float, nrows: int, ncols: int, *, row0: int = 0, col0: int = 0):
        self.res_m, self.x0, self.y0 = float(res_m), float(x0), float(y0)
        self.nrows, self.ncols, self.row0, self.col0 = int(nrows), int(ncols), int(row0), int(col0)
        n = self.nrows * self.ncols
        self._counts = np.zeros((n, 4), np.int32)
        self._sums = np.zeros((n, 6))
        self._sums[:, _DSM] = np.nan
        self._sums[:, _TOP] = np.nan
        self._sums[:, _BUILDING_TOP] = np.nan
        self._sums[:, _BOTTOM] = np.nan
        self.chm = np.full(n, np.nan)

    valid_n = property(lambda self: self._counts[:, _VALID_N])
    ground_n = property(lambda self: self._counts[:, _GROUND_N])
    inten_n = property(lambda self: self._counts[:, _INTEN_N])
    ground_sum = property(lambda self: self._sums[:, _GROUND_SUM])
    inten_sum = property(lambda self: self._sums[:, _INTEN_SUM])
    dsm = property(lambda self: self._sums[:, _DSM])
    top = property(lambda self: self._sums[:, _TOP])
    building_top = property(lambda self: self._sums[:, _BUILDING_TOP])
    bottom = property(lambda self: self._sums[:, _BOTTOM])

    def _window(self) -> _Window:
        return _Window(self.res_m, self.x0, self.y0, self.row0, self.col0, self.nrows, self.ncols)

    def add(self, x, y, z, cls, return_number, intensity) -> None:
        """A chunk of points (x, y, z in metres, class, return number, intensity)."""
        c = np.ascontiguousarray  # one layout, one compilation (record fields and slices were two more of each kernel)
        bad = _accumulate(_Returns(c(x), c(y), c(z), c(cls), c(return_number), c(intensity)), self._window(),
                          self._counts, self._sums, np.empty(len(x), np.int32), np.empty((len(x), 2)))
        if bad >= 0:
            raise RuntimeError("a point lies outside the raster grid")   # a tiling bug, not an input error

    def core_grids(self, footprint: np.ndarray, dem: np.ndarray, dsm_filled: np.ndarray, core, *, z_m: float,
                   metric: bool, nodata: float, chm: np.ndarray | None = None) -> np.ndarray:
        """``_core_grids`` of the window's core (row slice, col slice): (6, rows, cols) float32; ``chm``: the CHM
        per cell to write (default: the cells' own, ``self.chm``)."""
        chm = self.chm if chm is None else np.ascontiguousarray(chm, float)
        return _core_grids((footprint, np.ascontiguousarray(dem, float), np.ascontiguousarray(dsm_filled, float)),
                           (chm, self._counts, self._sums), (core[0].start, core[0].stop, core[1].start,
                                                                  core[1].stop),
                           z_m=float(z_m), metric=bool(metric), nodata=float(nodata))

    def add_chm(self, x, y, z, cls, dem: np.ndarray) -> None:
        """A chunk of points again, once the window's DEM (filled, rows south to north) is known."""
        c = np.ascontiguousarray
        if _chm_max(_Classified(c(x), c(y), c(z), c(cls)), c(dem, float), self._window(), self.chm) >= 0:
            raise RuntimeError("a point lies outside the raster grid")


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _core_grids(surfaces, cells, core, *, z_m, metric, nodata):
    """The float32 grids of a tile's ``core`` (r_lo, r_hi, c_lo, c_hi: window rows r_lo..r_hi, cols
    c_lo..c_hi), rows north to south: DEM in metres with NaN, then DEM, DSM, nDSM, CHM (heights divided by
    ``z_m`` unless ``metric``) and intensity with ``nodata`` for no value. ``surfaces``: the window's
    (footprint, dem, dsm_filled) grids; ``cells``: its (chm, counts, sums) per cell (``CellStats``). The
    arithmetic of the array version: heights in float64, cast to float32, then scaled in float64 and cast
    again."""
    footprint, dem, dsm_filled = surfaces
    chm, counts, sums = cells
    r_lo, r_hi, c_lo, c_hi = core
    ncols = dem.shape[1]
    h, w = r_hi - r_lo, c_hi - c_lo
    out = np.empty((6, h, w), np.float32)
    for i in range(r_lo, r_hi):
        o = h - 1 - (i - r_lo)
        for j in range(c_lo, c_hi):
            c = i * ncols + j
            fp = footprint[i, j]
            d = dem[i, j] if fp else np.nan
            a, b = dsm_filled[i, j], dem[i, j]
            s = np.nan if (np.isnan(a) or np.isnan(b)) else max(a, b)
            if not fp:
                s = np.nan
            v = chm[c]
            heights = (np.float32(d), np.float32(s), np.float32(s - d), np.float32(v if v > 0 else np.nan))
            out[0, o, j - c_lo] = heights[0]
            for k in range(4):
                x = heights[k]
                if not metric:
                    x = np.float32(np.float64(x) / z_m)
                out[1 + k, o, j - c_lo] = x if np.isfinite(x) else nodata
            x = np.float32(sums[c, _INTEN_SUM] / counts[c, _INTEN_N])
            out[5, o, j - c_lo] = x if np.isfinite(x) else nodata
    return out
