"""Rasters through a coordinate operation: anchor-grid mappings and resampling of arrays.

A coordinate operation (``aerotri.geom.crs.transform.CrsTransformer``) is too slow to call per pixel of a
large raster, but it is smooth: ``anchor_grid`` evaluates it on nodes every ``spacing_px`` pixels and
halves the spacing until bilinear interpolation between the nodes reproduces it at the cell centres
within a tolerance (default 1 mm). ``warp_array`` resamples a source array onto a destination grid
through such a mapping (OpenCV remap), keeping nodata; ``height_change`` gives the change of a height
value by the operation (datum shift of ellipsoidal heights, height anomaly), linear in the height.

Grids are north-up: ``x = x_left + (col + 0.5) * res``, ``y = y_top - (row + 0.5) * res``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

RESAMPLING = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC,
              "lanczos": cv2.INTER_LANCZOS4}


def anchor_positions(n: int, spacing: int) -> np.ndarray:
    """Anchor pixel indices 0, s, 2s, ... up to or past the last pixel n-1 (uniform, at least two)."""
    m = max(1, math.ceil((n - 1) / spacing))
    return np.arange(m + 1, dtype=float) * spacing


def anchor_grid(mapping, x_left: float, y_top: float, res: float, width: int, height: int,
                *, spacing_px: int = 256, tolerance: float = 1e-3, affine: bool = False):
    """``mapping(x, y) -> (X, Y)`` (arrays) on anchor nodes every ``spacing_px`` pixels of the grid.

    Returns (AX, AY, spacing_px) with shape (ny, nx); node (i, j) is pixel (row i*s, col j*s). The
    spacing is halved (down to 4 px) until the bilinear interpolation error at the cell centres is at
    most ``tolerance`` (in the units of X, Y); ``affine``: the mapping is known to be affine (one
    cell suffices).
    """
    if affine:
        spacing_px = max(width, height, 1)

    def centres(rows, cols):
        return x_left + (cols + 0.5) * res, y_top - (rows + 0.5) * res

    while True:
        cols = anchor_positions(width, spacing_px)
        rows = anchor_positions(height, spacing_px)
        xs, ys = centres(rows, cols)
        AX, AY = (np.asarray(a, dtype=float) for a in mapping(*np.meshgrid(xs, ys)))
        if affine or spacing_px <= 4:
            return AX, AY, spacing_px
        if AX.shape[0] < 2 or AX.shape[1] < 2:
            return AX, AY, spacing_px
        cc = (cols[:-1] + cols[1:]) / 2.0
        rc = (rows[:-1] + rows[1:]) / 2.0
        EX, EY = (np.asarray(a, dtype=float) for a in mapping(*np.meshgrid(*centres(rc, cc))))
        IX = 0.25 * (AX[:-1, :-1] + AX[1:, :-1] + AX[:-1, 1:] + AX[1:, 1:])
        IY = 0.25 * (AY[:-1, :-1] + AY[1:, :-1] + AY[:-1, 1:] + AY[1:, 1:])
        if float(np.max(np.hypot(EX - IX, EY - IY))) <= tolerance:
            return AX, AY, spacing_px
        spacing_px //= 2


def interpolate_anchors(A: np.ndarray, spacing_px: int, height: int, width: int) -> np.ndarray:
    """Bilinear interpolation of anchor values ``A`` (ny, nx) to every pixel (height, width), float64."""
    rows = np.arange(height) / spacing_px
    cols = np.arange(width) / spacing_px
    i0 = np.minimum(rows.astype(int), A.shape[0] - 2) if A.shape[0] > 1 else np.zeros(height, int)
    j0 = np.minimum(cols.astype(int), A.shape[1] - 2) if A.shape[1] > 1 else np.zeros(width, int)
    fr = (rows - i0)[:, None] if A.shape[0] > 1 else np.zeros((height, 1))
    fc = (cols - j0)[None, :] if A.shape[1] > 1 else np.zeros((1, width))
    i1 = np.minimum(i0 + 1, A.shape[0] - 1)
    j1 = np.minimum(j0 + 1, A.shape[1] - 1)
    top = A[i0][:, j0] * (1 - fc) + A[i0][:, j1] * fc
    bottom = A[i1][:, j0] * (1 - fc) + A[i1][:, j1] * fc
    return top * (1 - fr) + bottom * fr


def warp_array(src: np.ndarray, src_valid: np.ndarray, src_x_left: float, src_y_top: float, src_res: float,
               *, AX: np.ndarray, AY: np.ndarray, spacing_px: int, height: int, width: int,
               resampling: str = "bilinear", exact_taps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``src`` (rows, cols[, bands]) onto a destination grid whose pixel centres map to source
    coordinates through the anchors (AX, AY, spacing) of ``anchor_grid``.

    Returns (dst, valid): a destination pixel is valid where every source pixel the kernel touches is
    valid (nodata never bleeds into the result); ``dst`` holds 0 elsewhere. By default "touches" is the
    kernel's reach around the nearest source pixel (3 x 3 for bilinear); ``exact_taps`` (bilinear only): the
    source pixels the interpolation weights, those of weight ``EXACT_TAPS_MAX_INVALID_WEIGHT`` or less left out (the
    value is the mean of the others by their weights), so a centre on a source centre needs that pixel alone
    (``aerotri crs warp``: the reach rule took a ring of valid cells off every nodata edge, also where only the
    heights' unit changed on the source grid, trial-lidar).
    """
    X = interpolate_anchors(AX, spacing_px, height, width)
    Y = interpolate_anchors(AY, spacing_px, height, width)
    map_x = ((X - src_x_left) / src_res - 0.5).astype(np.float32)
    map_y = ((src_y_top - Y) / src_res - 0.5).astype(np.float32)
    interp = RESAMPLING[resampling]
    work = np.where(src_valid[..., None] if src.ndim == 3 else src_valid, src, 0)
    if work.dtype == np.float64 or work.dtype.kind in "iu" and work.dtype.itemsize > 2:
        work = work.astype(np.float32)
    # the edge cells continue beyond the array: a destination centre in the outer half of an edge cell (still on
    # the source's footprint, and valid below) was blended with a constant 0 there (a DEM's edge 0-61 m low)
    dst = cv2.remap(work, map_x, map_y, interp, borderMode=cv2.BORDER_REPLICATE)
    if dst.ndim == 2 and src.ndim == 3:
        dst = dst[:, :, None]
    if exact_taps and resampling == "bilinear":
        # the valid taps' share of the weight, by the same interpolation as the values
        weight = cv2.remap(src_valid.astype(np.float32), map_x, map_y, interp, borderMode=cv2.BORDER_REPLICATE)
        inside = weight >= 1.0 - EXACT_TAPS_MAX_INVALID_WEIGHT
        # (only where a tap on nodata has weight: elsewhere the values stay those of the reach rule, bit for bit)
        w = np.where(inside & (weight < 1.0 - 1e-6), weight, 1.0).astype(np.float32)
        dst = dst / (w[..., None] if dst.ndim == 3 else w)
    else:
        # validity: nearest neighbour of the mask, eroded by the kernel's reach
        invalid = (~src_valid).astype(np.uint8)
        reach = {"nearest": 0, "bilinear": 1, "cubic": 2, "lanczos": 4}[resampling]
        if reach:
            invalid = cv2.dilate(invalid, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8))
        inside = cv2.remap(1 - invalid, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=0).astype(bool)
    inside &= (map_x >= -0.5) & (map_y >= -0.5) & (map_x <= src.shape[1] - 0.5) & (map_y <= src.shape[0] - 0.5)
    dst[~inside] = 0  # as documented (the replicated border reaches beyond the footprint)
    return cast_to_dtype(dst, src.dtype), inside


# ``exact_taps``: a destination pixel whose bilinear taps on nodata weigh at most this is valid, its value the valid
# taps' mean (float32 positions put a centre on a source centre up to ~1e-4 pixel: the tap beside it had a weight)
EXACT_TAPS_MAX_INVALID_WEIGHT = 1e-3


def cast_to_dtype(a: np.ndarray, dtype) -> np.ndarray:
    """Resampled values in a raster's ``dtype``: floats as they are (no copy when ``a`` has it already),
    integers rounded half to even and clipped to the type's range (no wrap-around)."""
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return a.astype(dt, copy=False)
    info = np.iinfo(dt)
    return np.clip(np.rint(a), info.min, info.max).astype(dt)


def height_change(operation, x, y, z_lo: float, z_hi: float):
    """(dz0, k) with ``Z' - z = dz0 + k * z`` for the operation at points (x, y) (1-D arrays): its change
    of a height value, linear in the height between ``z_lo`` and ``z_hi`` (the residual nonlinearity of
    a datum shift over a few kilometres of height is below a micrometre)."""
    x = np.asarray(x, float).ravel()
    y = np.asarray(y, float).ravel()
    # a block of one height (a hydro-flattened lake): k from a metre above it, not 0 (review 48: a unit change's k is
    # not 0, and the inverse taken through it gave 169.52 ft for 328.08)
    z_hi = z_hi if z_hi > z_lo else z_lo + 1.0
    _, _, z0 = operation.transform(x, y, np.full(x.size, z_lo))
    _, _, z1 = operation.transform(x, y, np.full(x.size, z_hi))
    k = ((z1 - z_hi) - (z0 - z_lo)) / (z_hi - z_lo)
    return (z0 - z_lo) - k * z_lo, k


def source_window(ds, AX: np.ndarray, AY: np.ndarray, margin_px: int = 4):
    """The window (rasterio) of an open north-up dataset that holds the mapped coordinates, or None."""
    from rasterio.windows import Window

    t = ds.transform
    cols = (np.asarray(AX) - t.c) / t.a
    rows = (np.asarray(AY) - t.f) / t.e
    c0 = max(0, int(np.floor(np.nanmin(cols))) - margin_px)
    r0 = max(0, int(np.floor(np.nanmin(rows))) - margin_px)
    c1 = min(ds.width, int(np.ceil(np.nanmax(cols))) + margin_px + 1)
    r1 = min(ds.height, int(np.ceil(np.nanmax(rows))) + margin_px + 1)
    if c1 <= c0 or r1 <= r0:
        return None
    return Window(c0, r0, c1 - c0, r1 - r0)


def _cell_in_source_px(AX: np.ndarray, AY: np.ndarray, spacing_px: int, src_res: float) -> float:
    """The larger side of a destination cell in source pixels, from the mapped anchors (every ``spacing_px``
    destination pixels); 1 where the mapping gives nothing finite."""
    sides = []
    for axis in (0, 1):
        if AX.shape[axis] > 1:
            d = np.hypot(np.diff(AX, axis=axis), np.diff(AY, axis=axis)) / spacing_px
            d = d[np.isfinite(d)]
            if d.size:
                sides.append(float(np.max(d)))
    return max(sides) / src_res if sides else 1.0


def _triangle_prefilter(data: np.ndarray, valid: np.ndarray, cell_px: float):
    """(``read_on_grid``) each band (bands, rows, cols) smoothed by a separable triangle of half-width ``cell_px``
    source pixels (taps at whole pixels, weights normalised), so that a bilinear sample of it at a destination
    centre weights the source pixels of the cell as GDAL's bilinear downsampling does (a 2 x coarser aligned grid:
    1, 3, 3, 1 in both); ``valid`` eroded by the taps' reach (nodata never enters a mean). Unchanged at a cell of
    at most 1.05 source pixels."""
    if not cell_px > 1.05:
        return data, valid
    reach = int(np.ceil(cell_px)) - 1
    taps = np.arange(-reach, reach + 1, dtype=np.float64)
    kernel = np.maximum(0.0, 1.0 - np.abs(taps) / cell_px)
    kernel = (kernel / kernel.sum()).astype(np.float32)
    out = np.stack([cv2.sepFilter2D(b.astype(np.float32), -1, kernel, kernel, borderType=cv2.BORDER_REPLICATE)
                    for b in data])
    if reach:
        invalid = cv2.dilate((~valid).astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8))
        valid = invalid == 0
    return out, valid


def read_on_grid(ds, x_left: float, y_top: float, res: float, shape, operation=None, *, resampling: str = "bilinear",
                 bands=None, maximum: bool = False, tolerance: float = 1e-3, antialias: bool = False,
                 exact_taps: bool = False):
    """Read an open north-up dataset onto a destination grid (``shape`` rows, cols) whose pixel centres
    are mapped into the dataset's CRS by ``operation`` (destination -> dataset, a ``CrsTransformer``;
    None when both are the same CRS). Returns ((bands, rows, cols) float32, valid mask).

    ``maximum``: each destination pixel takes the maximum of the source pixels it covers (a max filter
    of the resolution ratio before resampling; used for nDSMs so that objects are never thinned away).
    ``antialias``: a destination cell wider than a source pixel takes a triangle-weighted mean of the source pixels
    it covers (the kernel widened to the cell, as GDAL's bilinear warp does), not a point sample of four: images
    compared patch by patch (the DOM check's reference) would otherwise alias, the more the coarser the grid.
    ``exact_taps``: as ``warp_array``'s."""
    bands = list(bands or range(1, ds.count + 1))
    rows, cols = shape
    t = ds.transform
    if abs(t.b) > 0 or abs(t.d) > 0 or t.e >= 0:
        from aerotri.core.errors import InputError

        raise InputError(f"{ds.name}: expected a north-up raster (transform {tuple(t)[:6]})")
    if operation is None:
        mapping = lambda x, y: (x, y)  # noqa: E731
        AX, AY, s = anchor_grid(mapping, x_left, y_top, res, cols, rows, affine=True)
    else:
        def mapping(x, y):
            X, Y, _ = operation.transform(np.ravel(x), np.ravel(y))
            return X.reshape(np.shape(x)), Y.reshape(np.shape(x))

        AX, AY, s = anchor_grid(mapping, x_left, y_top, res, cols, rows, tolerance=tolerance)
    out = np.zeros((len(bands), rows, cols), np.float32)
    # the destination cell in source pixels, through the mapping: the two CRSs' units may differ (a DOM grid in
    # metres over an nDSM in degrees, where res / t.a would be a 50000-pixel kernel)
    cell_px = _cell_in_source_px(AX, AY, s, abs(t.a)) if operation is not None else res / abs(t.a)
    # (to 1 %: a projection's scale factor, 1.0004 between UTM and Gauss-Krueger grids, adds no pixel)
    cell_px = float(np.ceil(cell_px - 0.01)) if operation is not None else cell_px
    win = source_window(ds, AX, AY, margin_px=4 + int(np.ceil(cell_px)))
    if win is None:
        return out, np.zeros(shape, bool)
    src = ds.read(bands, window=win, masked=True)
    valid = ~np.ma.getmaskarray(src).any(axis=0)
    data = np.ma.filled(src.astype(np.float32), 0.0)
    if antialias and not maximum:
        data, valid = _triangle_prefilter(data, valid, res / abs(t.a) if operation is None else
                                          _cell_in_source_px(AX, AY, s, abs(t.a)))
    if maximum:
        k = max(1, int(np.ceil(cell_px)))
        if k > 1:
            data = np.stack([cv2.dilate(np.where(valid, b, -np.inf).astype(np.float32), np.ones((k, k), np.uint8))
                             for b in data])
            data[~np.isfinite(data)] = 0.0
    x0 = t.c + win.col_off * t.a
    y0 = t.f + win.row_off * t.e
    dst, ok = warp_array(np.moveaxis(data, 0, -1), valid, x0, y0, abs(t.a), AX=AX, AY=AY, spacing_px=s, height=rows,
                         width=cols, resampling="nearest" if maximum else resampling, exact_taps=exact_taps)
    return np.moveaxis(dst.reshape(rows, cols, -1), -1, 0), ok


# A raster of another quantity than heights (lidarctl rasters' intensity.tif: sensor units, no length) says so by the
# dataset tag QUANTITY (its name: "intensity"); written before the tag, by the band description lidarctl rasters
# gave it. Given as a DEM it was taken for heights (trial: check-heights --dem intensity.tif, RMSE 91.86 m; contours
# of intensity).
QUANTITY_TAG = "QUANTITY"
INTENSITY_DESCRIPTION = "mean intensity of first returns (sensor units)"  # (lidarctl rasters writes it from here)
NOT_HEIGHT_DESCRIPTIONS = {INTENSITY_DESCRIPTION: "intensity"}


def not_heights(ds) -> str | None:
    """What a raster that holds no heights says it holds (``QUANTITY_TAG``, ``NOT_HEIGHT_DESCRIPTIONS``), as a
    phrase for a message; None for a height raster or one that says nothing (a DEM of other software)."""
    quantity = (ds.tags().get(QUANTITY_TAG) or "").strip()
    if quantity and quantity.lower() not in ("height", "heights", "elevation"):
        return f"{quantity} (its {QUANTITY_TAG} tag)"
    desc = ds.descriptions[0] if ds.count >= 1 and ds.descriptions else None
    if desc in NOT_HEIGHT_DESCRIPTIONS:
        return f"{NOT_HEIGHT_DESCRIPTIONS[desc]} (its band description {desc!r})"
    return None


def open_north_up(path, what: str = "raster", *, no_crs_hint: str = "", square: bool = False, heights: bool = False):
    """A rasterio dataset of a georeferenced, north-up raster of at least 2 x 2 cells (square pixels if
    ``square``; one band of numbers if ``heights``); InputError naming the file and ``what`` it should be
    when it is missing, unreadable, has no CRS, is rotated, smaller or (``heights``) holds anything but one
    band of finite, plausible heights with at least one valid cell (``aerotri.geom.inputs``), or says it holds
    another quantity (``not_heights``: lidarctl rasters' intensity.tif)."""
    from pathlib import Path

    import rasterio

    from aerotri.core.errors import InputError
    from aerotri.geom.inputs import check_height_values, check_raster_size

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} not found")
    try:
        ds = rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc})") from None
    problem = None
    t = ds.transform
    if heights and (ds.count != 1 or np.dtype(ds.dtypes[0]).kind not in "iuf"):
        problem = (f"expected one band of heights for the {what}; this file has {ds.count} band(s) of {ds.dtypes[0]} "
                   f"(an orthophoto or a hillshade given as the {what}?)")
    elif heights and (other := not_heights(ds)):
        problem = (f"holds {other}, not heights; expected a height raster for the {what} (lidarctl rasters' "
                   "dem.tif, dsm.tif, ...)")
    elif ds.crs is None:
        problem = f"the {what} has no CRS{no_crs_hint}"
    elif abs(t.b) > 0 or abs(t.d) > 0 or t.e >= 0 or (square and abs(abs(t.a) - abs(t.e)) > 1e-9 * abs(t.a)):
        problem = (f"expected a north-up {what}" + (" with square pixels" if square else "")
                   + f" (transform {tuple(t)[:6]})")
    if problem:
        ds.close()
        raise InputError(f"{path}: {problem}")
    try:
        check_raster_size(ds, path, what)
        if heights:
            from aerotri.geom.crs.definition import height_unit_m, parse_crs

            check_height_values(ds, path, what, height_unit_m(parse_crs(ds.crs.to_wkt(), f"{path} CRS")))
    except rasterio.errors.RasterioIOError as exc:
        ds.close()
        raise InputError(f"{path}: cannot read the {what} (truncated or corrupt? {exc})") from None
    except BaseException:
        ds.close()
        raise
    return ds

