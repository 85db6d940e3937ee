"""SIFT features with a spatial budget, cached per frame in ``work/features``.

Detection runs on pyramid level L (the image shrunk by 2^L so that its larger side is at most
``max_dim_px``) with a low contrast threshold; then every cell of a ``grid`` over the frame keeps
its strongest keypoints (``budget`` in all), so that texture-poor parts of every frame still get
points. Descriptors are RootSIFT (L1-normalised, square-rooted). Keypoints are stored in
full-resolution pixel coordinates. SIFT runs on tiles of the level (``tile_px``, ``extract_level``), so that its
scale space follows the tile, not the level.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import rasterio

from aerotri.core.errors import InputError
from aerotri.geom.images import downsample, level_to_full, pyramid_level, read_gray_level
from aerotri.match.settings import FeatureSettings
from aerotri.core.atomic import atomic_path


@dataclasses.dataclass
class Features:
    xy_px: np.ndarray  # (K, 2) float64 full-resolution pixel coordinates
    descriptors: np.ndarray  # (K, 128) float32 RootSIFT
    level: int


@dataclasses.dataclass(frozen=True)
class CachedKeypoints:
    """A frame's cached features with the keypoints in memory and the descriptors left in the cache file (read by
    ``descriptors()`` when needed): a block's tracks hold 16 bytes a keypoint, not 528 (6000 keypoints and
    3 MB of descriptors a frame, 9 GB for 3,000 frames)."""

    xy_px: np.ndarray  # (K, 2) float64 full-resolution pixel coordinates
    level: int
    path: Path  # the features' cache file

    def descriptors(self) -> np.ndarray:
        """(K, 128) float32 RootSIFT, read from the cache file."""
        with np.load(self.path) as z:
            return z["descriptors"]


def extract(img: np.ndarray, p: FeatureSettings) -> Features:
    level = pyramid_level(img.shape[1], img.shape[0], p.max_dim_px)
    return extract_level(downsample(img, level), level, p)


# Tiles: cores (which own the keypoints found in them) with this margin of image around them for the blur kernels,
# orientation windows and descriptors of the keypoints near a core's edge; core edges at multiples of _TILE_ALIGN_PX,
# so that every octave (SIFT's pyramid keeps every second pixel, from the upscaled first octave on) samples the
# same pixels of the level in a tile as in the whole level: keypoints of scale up to about the margin / 10 (the
# descriptor's reach) are the whole level's keypoints with the whole level's descriptors.
_TILE_MARGIN_PX = 128
# SIFT's scale space per pixel of its input (float32 octaves of the doubled image; docs/performance.md, "Matching
# memory": 680 MB for a 2000 x 1500 level, 2.7 GB for 4000 x 3000)
SIFT_BYTES_PER_PX = 230
_TILE_ALIGN_PX = 128


def _tile_edges(n_px: int, tile_px: int) -> list[int]:
    """Core edges along one side of ``n_px`` pixels: one core when the side fits a tile and its margins, else
    ceil(n / tile_px) cores of the same size (the last one smaller) at multiples of ``_TILE_ALIGN_PX``."""
    if n_px <= tile_px + 2 * _TILE_MARGIN_PX:
        return [0, n_px]
    k = -(-n_px // tile_px)
    step = -(-n_px // (k * _TILE_ALIGN_PX)) * _TILE_ALIGN_PX
    return [*range(0, n_px, step), n_px]


def _tiles(shape: tuple[int, int], tile_px: int):
    """(core rows, core cols, tile rows, tile cols) as (start, stop) pairs, row-major."""
    h, w = shape
    ey, ex = _tile_edges(h, tile_px), _tile_edges(w, tile_px)
    for r0, r1 in zip(ey[:-1], ey[1:]):
        for c0, c1 in zip(ex[:-1], ex[1:]):
            yield ((r0, r1), (c0, c1), (max(0, r0 - _TILE_MARGIN_PX), min(h, r1 + _TILE_MARGIN_PX)),
                   (max(0, c0 - _TILE_MARGIN_PX), min(w, c1 + _TILE_MARGIN_PX)))


def extraction_bytes(width_px: int, height_px: int, p: FeatureSettings) -> int:
    """Memory of one frame's feature extraction (bytes): its detection level (8-bit) and the SIFT scale space of
    the largest tile of it (``tile_px`` with its margins, at most the level)."""
    level = pyramid_level(width_px, height_px, p.max_dim_px)
    w, h = -(-int(width_px) // 2 ** level), -(-int(height_px) // 2 ** level)
    side = p.tile_px + 2 * _TILE_MARGIN_PX + _TILE_ALIGN_PX
    return int(w * h + min(w, side) * min(h, side) * SIFT_BYTES_PER_PX)


def extract_level(small: np.ndarray, level: int, p: FeatureSettings) -> Features:
    """Features of pyramid level ``level`` of a frame (8-bit grey ``small``), in full-resolution pixels.

    Detection and descriptors run tile by tile (``p.tile_px``, see ``_tiles``): SIFT's scale space costs about 230
    bytes a pixel of its input (float32 octaves of the doubled image), 2.7 GB for a 12 MP level; a tile holds a
    bounded part of it. A level that fits one tile is detected whole, as before tiles."""
    # precise upscale: OpenCV's default doubling of the image for the first octave puts every keypoint
    # 0.25 px right of and below the image content (x and y); the adjustment takes such an offset of the tie
    # points for a principal-point shift, which LiDAR control and check points, measured without it, then
    # see as plan errors flipping with the flight direction (demo: 0.10 m per strip).
    sift = cv2.SIFT_create(nfeatures=0, contrastThreshold=p.contrast_threshold, enable_precise_upscale=True)
    tiles, kp_tile, xy_parts, resp_parts = [], [], [], []
    for (r0, r1), (c0, c1), (a, b), (c, d) in _tiles(small.shape, p.tile_px):
        img = np.ascontiguousarray(small[a:b, c:d])
        kps = sift.detect(img, None)
        xy = np.array([k.pt for k in kps]).reshape(-1, 2)
        own = (xy[:, 0] + c >= c0) & (xy[:, 0] + c < c1) & (xy[:, 1] + a >= r0) & (xy[:, 1] + a < r1)
        if len(kps) and not own.all():  # the margins' keypoints belong to the neighbouring cores
            kps = [kps[k] for k in np.flatnonzero(own)]
            xy = xy[own]
        tiles.append((a, b, c, d))
        kp_tile.append(kps)
        xy_parts.append(xy + (c, a))
        resp_parts.append(np.array([k.response for k in kps], float))
    xy = np.concatenate(xy_parts)
    if len(xy) == 0:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32), level)
    resp = np.concatenate(resp_parts)
    gx, gy = p.grid
    h, w = small.shape
    cell = (np.minimum((xy[:, 1] * gy / h).astype(int), gy - 1) * gx
            + np.minimum((xy[:, 0] * gx / w).astype(int), gx - 1))
    per_cell = max(1, p.budget // (gx * gy))
    # Strongest per cell: sort by (cell, -response) and keep the first per_cell of each cell.
    order = np.lexsort((-resp, cell))
    c_sorted = cell[order]
    rank = np.arange(len(order)) - np.searchsorted(c_sorted, c_sorted)
    keep = np.sort(order[rank < per_cell])
    starts = np.cumsum([0] + [len(k) for k in kp_tile])
    xy_out, desc_out = [], []
    for t, (a, b, c, d) in enumerate(tiles):
        mine = keep[(keep >= starts[t]) & (keep < starts[t + 1])] - starts[t]
        if len(mine) == 0:
            continue
        kps, desc = sift.compute(np.ascontiguousarray(small[a:b, c:d]), [kp_tile[t][k] for k in mine])
        xy_out.append(np.array([k.pt for k in kps]).reshape(-1, 2) + (c, a))
        desc_out.append(desc)
    desc = np.concatenate(desc_out).astype(np.float32)
    desc /= desc.sum(axis=1, keepdims=True) + 1e-7
    desc = np.sqrt(desc)
    return Features(level_to_full(np.concatenate(xy_out), level), desc, level)


def features_cache_path(image_path: Path, cache_dir: Path, p: FeatureSettings) -> Path:
    return cache_dir / f"{image_path.stem}.{p.name}.{p.key()}.npz"


def cached_features(image_path: Path, cache_dir: Path, p: FeatureSettings, expect_size=None) -> Features:
    """Features of one frame, from the cache when the image file and parameters are unchanged."""
    st = image_path.stat()
    meta = {"size": st.st_size, "mtime_ns": st.st_mtime_ns}
    f = features_cache_path(image_path, cache_dir, p)
    if f.exists():
        with np.load(f) as z:
            if json.loads(str(z["meta"])) == meta:
                return Features(z["xy_px"], z["descriptors"], int(z["level"]))
    # the detection level read by windows (memory follows a band of rows, not the 106 MP frame)
    if expect_size is None:
        try:
            with rasterio.open(image_path) as ds:
                expect_size = (ds.width, ds.height)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{image_path}: cannot read the image ({exc})") from None
    level = pyramid_level(expect_size[0], expect_size[1], p.max_dim_px)
    feats = extract_level(read_gray_level(image_path, level, expect_size), level, p)
    if len(feats.xy_px) == 0:
        raise InputError(f"{image_path}: no image features at all (a blank, uniform or all-black frame?); "
                         "remove the frame from the block (images/ and gnss.txt) or replace it")
    with atomic_path(f) as tmp:
        np.savez(tmp, xy_px=feats.xy_px, descriptors=feats.descriptors, level=feats.level, meta=json.dumps(meta))
    return feats


def cached_keypoints(image_path: Path, cache_dir: Path, p: FeatureSettings, expect_size=None) -> CachedKeypoints:
    """The keypoints of one frame (``CachedKeypoints``: descriptors stay on disk), from the cache as
    ``cached_features`` gives them (extracted first when the cache has none for the image file and parameters)."""
    feats = cached_features(image_path, cache_dir, p, expect_size)
    return CachedKeypoints(feats.xy_px, feats.level, features_cache_path(image_path, cache_dir, p))
