"""A preview of the seamlines over the DOM (``ortho/seamlines_preview.png``, written by ``ortho mosaic`` with its
other outputs): the mosaic reduced to at most ``PREVIEW_MAX_PX`` on its longer side (its overviews, averaged), the
seams between the frames' regions in magenta, the cells no frame sees (nodata inside the block: occluded in every
frame of a true ortho, or over DEM nodata) hatched orange and black, the outside of the block white, and a legend
strip below the image.

Colours: 8- and 16-bit samples stretched linearly from their 0.5th to their 99.5th percentile (inside the block,
all bands together, so colour balance is kept), the range named in the legend: a DMC's 12-bit data in 16-bit samples
would be black divided by 257, and by its bit depth the balanced DOM of 12-bit frames (gains up to 1.05 take it to
4311, 13 bits) was a quarter as bright as the data, dark grey on black; the 8-bit DOM of the same frames
(``--output-bits 8``, mapped from the white level) was as dim shown as it is (review 25); one band as grey. A DOM of
(nearly) one value, whose percentiles collapse, is shown in its samples' full range (``full_range``), not black.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import rasterio
from rasterio.transform import Affine
from rasterio.enums import Resampling

from ortho.grid import north_up_flips
from ortho.unseen import unseen_cells

PREVIEW_MAX_PX = 2000
SEAM_RGB = (255, 0, 255)
HATCH_RGB = ((255, 140, 0), (0, 0, 0))
OUTSIDE_RGB = (255, 255, 255)
LEGEND_PX = 28


def preview_shape(width: int, height: int, max_px: int = PREVIEW_MAX_PX) -> tuple[int, int, int]:
    """(rows, cols, step): the mosaic reduced by an integer ``step`` so that its longer side is at most max_px."""
    step = max(1, math.ceil(max(width, height) / max_px))
    return -(-height // step), -(-width // step), step


def seam_pixels(labels: np.ndarray) -> np.ndarray:
    """Cells whose label (frame index, -1 none) differs from that of the cell to the right or below, both labelled."""
    seam = np.zeros(labels.shape, bool)
    a, b = labels[:, :-1], labels[:, 1:]
    seam[:, :-1] |= (a != b) & (a >= 0) & (b >= 0)
    a, b = labels[:-1, :], labels[1:, :]
    seam[:-1, :] |= (a != b) & (a >= 0) & (b >= 0)
    return seam


STRETCH_PERCENT = (0.5, 99.5)


# Least span of the stretch, a share of the samples' full range (``full_range``): percentiles closer together (a
# uniform block, or one value on more than 99 % of it: lo = hi) would show it black (review 26); the full range then
STRETCH_MIN_SPAN = 1.0 / 64.0  # 4 of the 255 levels of 8-bit samples, 64 of 12-bit's 4095


FULL_SCALES = (2 ** 8, 2 ** 12, 2 ** 13, 2 ** 14, 2 ** 15, 2 ** 16)  # ``full_range`` + 1


def full_range(img: np.ndarray) -> float:
    """The samples' full scale: 255 for 8-bit; for 16-bit that of their bit depth (the least of 12 to 16 bits holding
    the largest sample: 4095 for a DMC's 12-bit data, 8191 for its balanced DOM up to 4311)."""
    if img.dtype == np.uint8:
        return 255.0
    bits = min(16, max(12, int(img.max()).bit_length())) if img.size else 16
    return float(2 ** bits - 1)


def stretch_range(img: np.ndarray, valid: np.ndarray | None = None) -> tuple[float, float]:
    """(low, high): the ``STRETCH_PERCENT`` percentiles of the (bands, h, w) samples on the valid cells; 0 and the
    samples' ``full_range`` when those lie less than ``STRETCH_MIN_SPAN`` of it apart."""
    samples = img[:, valid] if valid is not None and valid.any() else img.reshape(len(img), -1)
    lo, hi = (float(v) for v in np.percentile(samples, STRETCH_PERCENT))
    full = full_range(samples)
    if hi - lo < STRETCH_MIN_SPAN * full:
        return 0.0, full
    return lo, hi


def _to_rgb8(img: np.ndarray, valid: np.ndarray | None = None) -> tuple[np.ndarray, tuple[float, float] | None]:
    """(bands, h, w) samples -> (h, w, 3) uint8 and the stretch of 8- and 16-bit samples (``stretch_range``; None
    for floats, clipped to 0-255)."""
    stretch = None
    if img.dtype in (np.uint8, np.uint16):
        stretch = lo, hi = stretch_range(img, valid)
        scaled = (img.astype(np.float32) - np.float32(lo)) * np.float32(255.0 / (hi - lo))
        img = np.rint(np.clip(scaled, 0, 255)).astype(np.uint8)
    else:
        img = np.clip(img, 0, 255).astype(np.uint8)
    rgb = img[:3] if img.shape[0] >= 3 else np.repeat(img[:1], 3, axis=0)
    return cv2.merge(list(rgb)), stretch  # interleaved (h, w, 3): OpenCV's copy, faster than numpy's transposed one


# (a westing / southing grid is stored south-up: its preview is turned, and says so; new-user trial NGI, EPSG:2051)
TURNED_NOTE = "north up: the grid's rows and columns reversed"


def _labels(stretch: tuple[float, float] | None, bits: int = 16, turned: bool = False) -> list[str]:
    names = ["seamline", "nodata: no frame sees it", "outside the block"]
    if stretch is not None:
        how = ("full range" if stretch[0] == 0 and int(stretch[1]) + 1 in FULL_SCALES else
               f"stretched ({STRETCH_PERCENT[0]:g}-{STRETCH_PERCENT[1]:g} %)")
        # (not "grey": an RGB DOM is shown in its colours, new-user trial s51)
        names.append(f"shown: {bits}-bit samples {stretch[0]:.0f}-{stretch[1]:.0f} {how}")
    return names + ([TURNED_NOTE] if turned else [])


def _legend(width: int, stretch: tuple[float, float] | None = None, bits: int = 16, turned: bool = False) -> np.ndarray:
    """A white strip with the three swatches and their names (RGB), the stretch of ``bits``-bit samples when
    there is one, and ``TURNED_NOTE`` when ``turned``."""
    strip = np.full((LEGEND_PX, width, 3), 255, np.uint8)
    x = 6
    for label, kind in zip(_labels(stretch, bits, turned), ("seam", "hatch", "outside", "note", "note")):
        y0, y1 = 7, LEGEND_PX - 7
        if kind == "seam":
            strip[LEGEND_PX // 2 - 1:LEGEND_PX // 2 + 2, x:x + 16] = SEAM_RGB
        elif kind == "hatch":
            rr, cc = np.mgrid[y0:y1, x:x + 16]
            strip[y0:y1, x:x + 16] = np.where((((rr + cc) // 3) % 2 == 0)[..., None], HATCH_RGB[0], HATCH_RGB[1])
        elif kind == "outside":
            strip[y0:y1, x:x + 16] = OUTSIDE_RGB
            cv2.rectangle(strip, (x, y0), (x + 15, y1 - 1), (0, 0, 0), 1)
        cv2.putText(strip, label, (x + 22, LEGEND_PX - 9), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        x += 22 + cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)[0][0] + 18
    return strip


def legend_width(stretch: tuple[float, float] | None = None, bits: int = 16, turned: bool = False) -> int:
    return 6 + sum(22 + cv2.getTextSize(s, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)[0][0] + 18
                   for s in _labels(stretch, bits, turned))


def render_preview(mosaic_path, labels: np.ndarray, factor: int, max_px: int = PREVIEW_MAX_PX, *,
                   mosaic_size: tuple[int, int] | None = None, footprints=()) -> np.ndarray:
    """The preview image (rows, cols, 3) RGB uint8: ``labels`` is the seam grid (``factor`` mosaic pixels a cell,
    its origin the mosaic's), ``mosaic_path`` the finished mosaic; or, with ``mosaic_size`` (the mosaic's width and
    height), a raster of exactly the preview's size (the mosaic's overview of that size: what reading the mosaic at
    that size reads), read whole. ``footprints``: per frame the ring of the ground it images (mosaic CRS;
    ``FrameEntry.footprint_xy_m``): nodata there is inside the block, as mosaic.json counts it (``ortho.unseen``)."""
    with rasterio.open(mosaic_path) as ds:
        h, w, step = preview_shape(*(mosaic_size or (ds.width, ds.height)), max_px)
        if mosaic_size is not None and (ds.height, ds.width) != (h, w):
            raise ValueError(f"{mosaic_path}: {ds.width} x {ds.height} px, not the preview's {w} x {h}")
        img = ds.read(out_shape=(ds.count, h, w), resampling=Resampling.average)
        ok = ds.read_masks(1, out_shape=(h, w), resampling=Resampling.nearest) > 0
        to_cells = ~(ds.transform @ Affine.scale(ds.width / w, ds.height / h))
        flip_rows, flip_cols = north_up_flips(ds.transform, ds.crs)
    rgb, stretch = _to_rgb8(img, ok)
    # nodata: inside the block (enclosed, or on the ground a frame images: over DEM nodata, occluded) or outside it
    inside = unseen_cells(ok, to_cells, footprints)
    rgb[~ok] = OUTSIDE_RGB
    rr, cc = np.nonzero(inside)
    rgb[rr, cc] = np.where((((rr + cc) // 3) % 2 == 0)[:, None], HATCH_RGB[0], HATCH_RGB[1])
    # the label of every preview pixel: the seam cell holding its centre
    rows = np.minimum(((np.arange(h) + 0.5) * step // factor).astype(np.int64), labels.shape[0] - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * step // factor).astype(np.int64), labels.shape[1] - 1)
    seam = seam_pixels(labels.take(rows, axis=0).take(cols, axis=1))  # labels[np.ix_(rows, cols)], taken faster
    seam = cv2.dilate(seam.view(np.uint8), np.ones((2, 2), np.uint8)).view(bool) & ok
    rgb[seam] = SEAM_RGB
    turned = flip_rows or flip_cols
    rgb = rgb[::-1 if flip_rows else 1, ::-1 if flip_cols else 1]
    bits = 8 * img.dtype.itemsize
    width = max(w, legend_width(stretch, bits, turned))
    out = np.full((h + LEGEND_PX, width, 3), 255, np.uint8)
    out[:h, :w] = rgb
    out[h:] = _legend(width, stretch, bits, turned)
    return out


def write_seamlines_preview(path, mosaic_path, labels: np.ndarray, factor: int, max_px: int = PREVIEW_MAX_PX, *,
                            mosaic_size: tuple[int, int] | None = None, footprints=()) -> None:
    """Write the preview PNG to ``path`` (a work folder's file: the caller moves it into place with the other
    outputs); ``mosaic_size``, ``footprints``: as ``render_preview``."""
    rgb = render_preview(mosaic_path, labels, factor, max_px, mosaic_size=mosaic_size, footprints=footprints)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:  # cv2 returns False only for an unknown extension or an empty image
        raise RuntimeError(f"{path}: PNG encoding failed")
    Path(path).write_bytes(buf.tobytes())
