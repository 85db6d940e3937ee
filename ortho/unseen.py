"""The mosaic's cells no frame sees: cells without a value inside the block, where the block is what the mosaic's
valid cells enclose and the ground the frames image (their footprints). Counted for mosaic.json and the report
(``ortho.mosaic``) and hatched in the seamlines preview (``ortho.seamlines_preview``): the same cells in both."""

from __future__ import annotations

import cv2
import numpy as np


def unseen_cells(valid: np.ndarray, to_cells, footprints=()) -> np.ndarray:
    """(h, w) bool: cells of a mosaic raster read as ``valid`` (h, w) that hold no value but lie inside the block:
    enclosed by valid cells (not connected to the raster's outer edge through empty cells), or inside the ground a
    frame images (``footprints``: per frame its ring (x, y) in the mosaic's CRS, None or empty when not recorded;
    ``to_cells``: the affine from those coordinates to this raster's column, row). The frame orthos leave the last
    cell along their image's edge empty (no sample to interpolate from): the footprints' union is taken one cell in,
    so that the block's outline does not count."""
    empty = np.pad(~valid, 1, constant_values=True).view(np.uint8).copy()
    cv2.floodFill(empty, None, (0, 0), 2)  # the outside: every empty cell reached from the edge
    unseen = empty[1:-1, 1:-1] == 1
    imaged = np.zeros(valid.shape, np.uint8)
    for ring in footprints:
        if ring:
            xy = np.asarray(ring, float)
            col, row = to_cells @ (xy[:, 0], xy[:, 1])
            # fillPoly takes a cell whose centre the ring holds; pixel corners -> centres
            pts = np.round(np.stack([col - 0.5, row - 0.5], axis=-1) * 16).astype(np.int32)
            cv2.fillPoly(imaged, [pts], 1, lineType=cv2.LINE_8, shift=4)
    unseen |= ~valid & (cv2.erode(imaged, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0)
    return unseen


def unseen_without_heights(unseen: np.ndarray, transform, crs, surfaces, max_samples: int = 2_000_000) -> int:
    """How many of the ``unseen`` cells (``unseen_cells``; the raster's ``transform`` and ``crs``) lie where a surface
    the frames were rectified on has no heights: beyond its extent or on its nodata, read at the cells' centres
    (the surface's mask over their bounding box, nearest cell). ``surfaces``: the DEM's and a true ortho's DSM's
    paths; one that cannot be opened is left out. Above ``max_samples`` cells every k-th is read and the count scaled
    (the demo: 149,074 cells in 0.05 s; a warp of the whole surface onto the mosaic's grid took 0.74 s of a 4 s mosaic).
    The rest of the unseen cells are occluded in every frame (a true ortho) or on the frames' own nodata."""
    import math

    import rasterio
    from rasterio.windows import Window

    if not len(surfaces):
        return 0
    rows, cols = np.nonzero(unseen)
    if not len(rows):
        return 0
    step = max(1, math.ceil(len(rows) / max_samples))
    rows, cols = rows[::step], cols[::step]
    x, y = transform * (cols + 0.5, rows + 0.5)
    x, y = np.asarray(x, float), np.asarray(y, float)
    gap = np.zeros(len(rows), bool)
    for path in surfaces:
        try:
            with rasterio.open(path) as src:
                sx, sy = x, y
                if src.crs is not None and crs is not None and src.crs != crs:
                    from pyproj import Transformer

                    sx, sy = Transformer.from_crs(crs, src.crs, always_xy=True).transform(x, y)
                    sx, sy = np.asarray(sx, float), np.asarray(sy, float)
                c, r = ~src.transform * (sx, sy)
                r, c = np.floor(r).astype(np.int64), np.floor(c).astype(np.int64)
                inside = (r >= 0) & (r < src.height) & (c >= 0) & (c < src.width)
                holes = ~inside
                if inside.any():
                    r0, r1, c0, c1 = r[inside].min(), r[inside].max() + 1, c[inside].min(), c[inside].max() + 1
                    m = src.read_masks(1, window=Window(int(c0), int(r0), int(c1 - c0), int(r1 - r0)))
                    holes[inside] = m[r[inside] - r0, c[inside] - c0] == 0
                gap |= holes
        except (OSError, rasterio.errors.RasterioError):
            continue
    return int(np.count_nonzero(gap)) * step
