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


def unseen_without_heights(unseen: np.ndarray, transform, crs, surfaces) -> int:
    """How many of the ``unseen`` cells (``unseen_cells``; the raster's ``transform`` and ``crs``) lie where a surface
    the frames were rectified on has no heights: beyond its extent or on its nodata (read through a nearest-neighbour
    warp onto this grid, one byte a cell). ``surfaces``: the DEM's and a true ortho's DSM's paths; one that cannot be
    opened is left out (the report says what was counted). The rest of the unseen cells are occluded in every frame
    (a true ortho) or on the frames' own nodata."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.vrt import WarpedVRT

    if not unseen.any():
        return 0
    gap = np.zeros(unseen.shape, bool)
    for path in surfaces:
        try:
            with rasterio.open(path) as src, WarpedVRT(src, crs=crs, transform=transform, width=unseen.shape[1],
                                                       height=unseen.shape[0], resampling=Resampling.nearest) as vrt:
                gap |= vrt.read_masks(1) == 0
        except (OSError, rasterio.errors.RasterioError):
            continue
    return int(np.count_nonzero(unseen & gap))
