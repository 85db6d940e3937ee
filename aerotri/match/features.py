"""SIFT features with a spatial budget, cached per frame in ``work/features``.

Detection runs on pyramid level L (the image shrunk by 2^L so that its larger side is at most
``max_dim_px``) with a low contrast threshold; then every cell of a ``grid`` over the frame keeps
its strongest keypoints (``budget`` in all), so that texture-poor parts of every frame still get
points. Descriptors are RootSIFT (L1-normalised, square-rooted). Keypoints are stored in
full-resolution pixel coordinates.
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


def extract(img: np.ndarray, p: FeatureSettings) -> Features:
    level = pyramid_level(img.shape[1], img.shape[0], p.max_dim_px)
    return extract_level(downsample(img, level), level, p)


def extract_level(small: np.ndarray, level: int, p: FeatureSettings) -> Features:
    """Features of pyramid level ``level`` of a frame (8-bit grey ``small``), in full-resolution pixels."""
    # precise upscale: OpenCV's default doubling of the image for the first octave puts every keypoint
    # 0.25 px right of and below the image content (x and y); the adjustment takes such an offset of the tie
    # points for a principal-point shift, which LiDAR control and check points, measured without it, then
    # see as plan errors flipping with the flight direction (demo: 0.10 m per strip).
    sift = cv2.SIFT_create(nfeatures=0, contrastThreshold=p.contrast_threshold, enable_precise_upscale=True)
    kps = sift.detect(small, None)
    if not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32), level)
    xy = np.array([k.pt for k in kps])
    resp = np.array([k.response for k in kps])
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
    kps = [kps[k] for k in keep]
    kps, desc = sift.compute(small, kps)
    desc = desc.astype(np.float32)
    desc /= desc.sum(axis=1, keepdims=True) + 1e-7
    desc = np.sqrt(desc)
    xy = level_to_full(np.array([k.pt for k in kps]), level)
    return Features(xy, desc, level)


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
