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


def _unseen_centres(unseen: np.ndarray, transform, max_samples: int):
    """The (x, y) centres of the ``unseen`` cells, every k-th above ``max_samples``, and k."""
    import math

    rows, cols = np.nonzero(unseen)
    step = max(1, math.ceil(len(rows) / max_samples)) if len(rows) else 1
    rows, cols = rows[::step], cols[::step]
    x, y = transform * (cols + 0.5, rows + 0.5)
    return np.asarray(x, float), np.asarray(y, float), step


def _surface_at(path, x: np.ndarray, y: np.ndarray, crs, values: bool = False):
    """A height raster's band 1 at the points (x, y) in ``crs`` (nearest cell): (has, value), ``has`` False beyond its
    extent or on its nodata, ``value`` None unless ``values``: metres (its CRS's height unit converted), NaN where not
    ``has``. The band's mask (and values) are read over the points' bounding box only."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(path) as src:
        sx, sy = x, y
        if src.crs is not None and crs is not None and src.crs != crs:
            from pyproj import Transformer

            sx, sy = Transformer.from_crs(crs, src.crs, always_xy=True).transform(x, y)
            sx, sy = np.asarray(sx, float), np.asarray(sy, float)
        c, r = ~src.transform * (sx, sy)
        r, c = np.floor(r).astype(np.int64), np.floor(c).astype(np.int64)
        inside = (r >= 0) & (r < src.height) & (c >= 0) & (c < src.width)
        has = np.zeros(len(x), bool)
        value = np.full(len(x), np.nan) if values else None
        if inside.any():
            r0, r1, c0, c1 = r[inside].min(), r[inside].max() + 1, c[inside].min(), c[inside].max() + 1
            window = Window(int(c0), int(r0), int(c1 - c0), int(r1 - r0))
            ri, ci = r[inside] - r0, c[inside] - c0
            has[inside] = src.read_masks(1, window=window)[ri, ci] > 0
            if values:
                from aerotri.geom.crs.definition import height_unit_m, parse_crs

                unit_m = height_unit_m(parse_crs(src.crs.to_wkt(), f"{path} CRS")) if src.crs is not None else 1.0
                value[inside] = src.read(1, window=window)[ri, ci] * unit_m
                value[~has] = np.nan
    return has, value


def unseen_without_heights(unseen: np.ndarray, transform, crs, surfaces, max_samples: int = 2_000_000) -> int:
    """How many of the ``unseen`` cells (``unseen_cells``; the raster's ``transform`` and ``crs``) lie where a surface
    the frames were rectified on has no heights: beyond its extent or on its nodata, read at the cells' centres
    (the surface's mask over their bounding box, nearest cell). ``surfaces``: the DEM's and a true ortho's DSM's
    paths; one that cannot be opened is left out. Above ``max_samples`` cells every k-th is read and the count scaled
    (the demo: 149,074 cells in 0.05 s; a warp of the whole surface onto the mosaic's grid took 0.74 s of a 4 s mosaic).
    The rest of the unseen cells are occluded in every frame (a true ortho) or on the frames' own nodata."""
    import rasterio

    if not len(surfaces) or not unseen.any():
        return 0
    x, y, step = _unseen_centres(unseen, transform, max_samples)
    gap = np.zeros(len(x), bool)
    for path in surfaces:
        try:
            gap |= ~_surface_at(path, x, y, crs)[0]
        except (OSError, rasterio.errors.RasterioError):
            continue
    return int(np.count_nonzero(gap)) * step


def unseen_on_objects(unseen: np.ndarray, transform, crs, ndsm_path, object_height_m: float,
                      max_samples: int = 2_000_000) -> int | None:
    """How many of the ``unseen`` cells lie on the nDSM's objects (above ``object_height_m``, metres; the nDSM's heights
    in its CRS's height unit): roofs and crowns, which a frame looks down on. In a true ortho most of them are
    masked at the objects' edges where the LiDAR DSM's roofs reach past the walls (trial s98 M1: on the tall block
    224 of 225 sampled nodata cells on the truth's roofs were seen by some frame), not hidden. None when the nDSM
    cannot be read; sampled as ``unseen_without_heights``."""
    import rasterio

    if not unseen.any():
        return 0
    x, y, step = _unseen_centres(unseen, transform, max_samples)
    try:
        _, h = _surface_at(ndsm_path, x, y, crs, values=True)
    except (OSError, rasterio.errors.RasterioError):
        return None
    with np.errstate(invalid="ignore"):
        return int(np.count_nonzero(h > object_height_m)) * step
