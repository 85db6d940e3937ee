"""Checks of input files that every command makes before any work (issue 39): rasters big enough to
interpolate in, height rasters of finite, plausible values with at least one valid cell, and the same
file not given twice. Each raises ``InputError`` naming the file (and band or cell) and what was expected.

Height limits are those of a point cloud's z (``lidarctl.io``): -1000 m .. 10000 m covers every height on
Earth, ellipsoidal or normal, and every height above ground; a value beyond them is an undeclared nodata
value (GDAL's float32 minimum, -9999 without a nodata tag) or a raster in another unit than its CRS says.
NaN is nodata in a floating-point raster whatever its nodata tag says.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError

MIN_CELLS = 2  # per side: bilinear interpolation, slopes, flow directions and contours need a neighbour
MIN_HEIGHT_M, MAX_HEIGHT_M = -1000.0, 10000.0
_SCAN_CELLS = 4_000_000  # cells read at a time by the value scan (16 MB of float32)


def check_raster_size(ds, path, what: str = "raster") -> None:
    """``InputError`` unless the open raster ``ds`` has at least 2 x 2 cells."""
    if ds.width < MIN_CELLS or ds.height < MIN_CELLS:
        raise InputError(f"{path}: the {what} has {ds.height} x {ds.width} cells (rows x columns); expected at least "
                         f"{MIN_CELLS} x {MIN_CELLS} (a single row or column cannot be interpolated)")


@dataclasses.dataclass(frozen=True)
class HeightValues:
    """What a scan of a height band found: valid cells, their range (raster units), cells in all."""

    valid_cells: int
    cells: int
    min: float
    max: float


_scanned: dict = {}  # (path, size, mtime, band) -> HeightValues: a command opening a DEM per task scans it once


def check_height_values(ds, path, what: str = "DEM", unit_m: float = 1.0, band: int = 1) -> HeightValues:
    """Scan band ``band`` of the open raster ``ds`` by blocks of rows: ``InputError`` naming the first cell
    (row, column) that holds an infinity or a value beyond -1000 .. 10000 m (``unit_m``: metres per raster
    unit), and when no cell holds a valid height. Nodata (the raster's value, or NaN) is not a height."""
    path = Path(path)
    try:
        st = os.stat(path)
        key = (str(path.resolve()), st.st_size, st.st_mtime_ns, band)
    except OSError:
        key = None
    if key is not None and key in _scanned:
        return _scanned[key]
    lo_u, hi_u = MIN_HEIGHT_M / unit_m, MAX_HEIGHT_M / unit_m
    rows_per_block = max(1, _SCAN_CELLS // max(ds.width, 1))
    valid = 0
    vmin, vmax = np.inf, -np.inf
    from rasterio.windows import Window

    fast_nodata = _plain_nodata(ds, band)
    for r0 in range(0, ds.height, rows_per_block):
        win = Window(0, r0, ds.width, min(rows_per_block, ds.height - r0))
        if fast_nodata is not False:
            block = _scan_plain(ds.read(band, window=win), fast_nodata, lo_u, hi_u)
            if block is not None:
                n, bmin, bmax = block
                if n:
                    valid += n
                    vmin, vmax = min(vmin, bmin), max(vmax, bmax)
                continue
        # masked by GDAL's mask band (nodata, an internal mask, alpha), or a block the plain scan cannot tell
        a = ds.read(band, window=win, masked=True)
        data = np.ma.getdata(a)
        mask = np.ma.getmaskarray(a)
        if data.dtype.kind == "f":
            mask = mask | np.isnan(data)
            bad = ~mask & (np.isinf(data) | (data < lo_u) | (data > hi_u))
        else:
            bad = ~mask & ((data < lo_u) | (data > hi_u))
        if bad.any():
            i, j = np.argwhere(bad)[0]
            v = float(data[i, j])
            unit = "m" if unit_m == 1.0 else f"units of {unit_m:g} m"
            why = ("an infinity; expected finite heights, or the raster's nodata value where there is none"
                   if np.isinf(v) else
                   f"beyond the heights on Earth ({lo_u:g} .. {hi_u:g} {unit}): an undeclared nodata value? "
                   "(declare it, e.g. gdal_edit.py -a_nodata <value>)" + (
                       # (trial s99 lidmut L3: an integer DEM in centimetres was asked only about nodata)
                       "; or heights in centimetres or millimetres (an integer raster: convert it to metres)"
                       if np.issubdtype(np.dtype(ds.dtypes[band - 1]), np.integer) and hi_u < abs(v) <= 1000 * hi_u
                       else ""))
            raise InputError(f"{path}: band {band}, cell (row {r0 + i}, column {j}) of the {what} holds {v:g}, {why}")
        ok = ~mask
        n = int(ok.sum())
        if n:
            valid += n
            vmin = min(vmin, float(data[ok].min()))
            vmax = max(vmax, float(data[ok].max()))
    if valid == 0:
        nodata = ds.nodatavals[band - 1]
        raise InputError(f"{path}: the {what} has no valid height: all {ds.width * ds.height:,} cells are "
                         + ("NaN" if nodata is None else f"nodata ({nodata:g}) or NaN"))
    out = HeightValues(valid, ds.width * ds.height, vmin, vmax)
    if key is not None:
        _scanned[key] = out
    return out


def _plain_nodata(ds, band: int):
    """The nodata value (None: none) when GDAL's mask of float band ``band`` is its nodata value or nothing, so that a
    plain read with ``_scan_plain`` finds what the masked read finds; False otherwise (an integer band, an internal
    mask, alpha: the masked read)."""
    from rasterio.enums import MaskFlags

    if np.dtype(ds.dtypes[band - 1]).kind != "f":
        return False
    flags = set(ds.mask_flag_enums[band - 1])
    nodata = ds.nodatavals[band - 1]
    if flags == {MaskFlags.all_valid} and nodata is None:
        return None
    if flags == {MaskFlags.nodata} and nodata is not None:
        return None if np.isnan(nodata) else float(nodata)  # NaN is nodata in any case
    return False


def _scan_plain(data: np.ndarray, nodata, lo: float, hi: float):
    """(valid cells, min, max) of a block of a float band read without its mask (``_plain_nodata``), or None when it
    holds a cell that is neither a height within lo .. hi, nor NaN, nor exactly the nodata value (a bad cell, or one
    GDAL's nodata mask may take as nodata by its tolerance): the masked read then decides, as it did alone.

    One pass per test and no gathered copy: the masked scan decoded each block twice (the values and GDAL's mask)
    and copied the valid cells (the demo's nDSM: 0.26 of the mosaic's CPU-s)."""
    import cv2

    inside = (data >= lo) & (data <= hi)  # NaN compares False: not inside
    nd = None if nodata is None else data.dtype.type(nodata)  # as GDAL compares: in the band's type
    if nd is not None and lo <= nd <= hi:
        # a nodata value that is a plausible height: the cells near it are GDAL's to classify (its tolerance)
        if nd != 0 and np.count_nonzero((np.abs(data - nd) <= 1e-5 * abs(nd)) & (data != nd)):
            return None
        inside &= data != nd
    n = int(np.count_nonzero(inside))
    others = np.count_nonzero(np.isnan(data))
    if nd is not None and not (lo <= nd <= hi):
        others += np.count_nonzero(data == nd)
    if n + others != data.size:
        return None
    if not n:
        return 0, np.inf, -np.inf
    if data.ndim == 2 and data.dtype in (np.float32, np.float64):
        vmin, vmax, _, _ = cv2.minMaxLoc(data, mask=inside.view(np.uint8))
        return n, float(data.dtype.type(vmin)), float(data.dtype.type(vmax))
    return n, float(data[inside].min()), float(data[inside].max())


def _fingerprint(path: Path) -> tuple:
    """(size, hash of the first and last 64 KiB): equal for byte copies of one file."""
    size = path.stat().st_size
    h = hashlib.sha1()
    with open(path, "rb") as f:
        h.update(f.read(65536))
        if size > 65536:
            f.seek(max(65536, size - 65536))
            h.update(f.read(65536))
    return size, h.hexdigest()


def check_distinct_files(paths, what: str = "file") -> None:
    """``InputError`` when one file is given twice (the same path, a link to it, or a byte copy under
    another name): its data would count twice (every point of a strip merged, gridded or checked twice)."""
    seen_path: dict = {}
    seen_print: dict = {}
    for p in paths:
        p = Path(p)
        if not p.is_file():
            continue  # missing or a folder: the reader names it
        real = os.path.realpath(p)
        if real in seen_path:
            raise InputError(f"{p}: the same {what} is given twice (as {seen_path[real]} and {p}); give each once")
        seen_path[real] = p
        fp = _fingerprint(p)
        if fp in seen_print:
            raise InputError(f"{p}: a byte copy of {seen_print[fp]} (the same {what} given twice under two names); "
                             "give each once")
        seen_print[fp] = p


MIN_REACH_M = 10_000.0  # beyond any footprint's reach from its projection centre


def check_near_block(x, y, records, source: str, *, block_xy, block_source: str, unit_m: float = 1.0) -> None:
    """``InputError`` naming the first record (``records[i]``, e.g. "line 5 (point RC12)") of ``source`` whose
    x, y lie farther from the block than a frame can see: beyond the bounding box of the projection centres
    ``block_xy`` (N, 2; from ``block_source``) widened by its diagonal, at least 10 km (``unit_m``: metres per
    map unit). Coordinates of another zone or place that the CRS's area of use lets through (a zone's
    neighbour sheet lies within it) would otherwise give "Solution Successful" 300 km off."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    b = np.asarray(block_xy, float).reshape(-1, 2)
    if not len(x) or not len(b):
        return
    lo, hi = b.min(axis=0), b.max(axis=0)
    reach = max(float(np.hypot(*(hi - lo))), MIN_REACH_M / unit_m)
    far = (x < lo[0] - reach) | (x > hi[0] + reach) | (y < lo[1] - reach) | (y > hi[1] + reach)
    if far.any():
        i = int(np.argmax(far))
        d = float(np.hypot(max(lo[0] - x[i], 0.0, x[i] - hi[0]), max(lo[1] - y[i], 0.0, y[i] - hi[1]))) * unit_m
        raise InputError(f"{source}: {records[i]}: ({x[i]:.3f}, {y[i]:.3f}) lies {d / 1000:.1f} km from the block "
                         f"(projection centres of {block_source}: x {lo[0]:.1f} .. {hi[0]:.1f}, y {lo[1]:.1f} .. "
                         f"{hi[1]:.1f}); coordinates of another zone, CRS or place?")
