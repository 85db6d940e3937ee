"""SIFT features with a spatial budget: the budget per grid cell, full-resolution coordinates from a pyramid
level, RootSIFT descriptors and the per-frame cache, on small synthetic images."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from aerotri.core.errors import InputError
from aerotri.match.features import cached_features, extract, features_cache_path
from aerotri.match.settings import FeatureSettings


def texture(h: int, w: int, seed: int = 1) -> np.ndarray:
    """8-bit random blobs (blurred noise): corners and blobs everywhere."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(0.0, 1.0, (h, w)).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min())
    return np.rint(255 * img).astype(np.uint8)


def test_budget_is_spread_over_the_grid():
    """The left half is strongly textured, the right half weakly: every cell still gets its share."""
    img = texture(240, 320)
    img[:, 160:] = (128 + (img[:, 160:].astype(int) - 128) // 6).astype(np.uint8)
    p = FeatureSettings(budget=192, grid=(4, 3), max_dim_px=1000)
    f = extract(img, p)
    assert f.level == 0 and len(f.xy_px) <= p.budget
    col = np.minimum((f.xy_px[:, 0] * 4 / 320).astype(int), 3)
    row = np.minimum((f.xy_px[:, 1] * 3 / 240).astype(int), 2)
    counts = np.bincount(row * 4 + col, minlength=12)
    per_cell = p.budget // 12
    assert counts.max() <= per_cell
    assert counts.min() >= per_cell // 2  # the weak half is not left empty


def test_rootsift_descriptors_are_unit_vectors():
    f = extract(texture(160, 200), FeatureSettings(budget=300, grid=(2, 2)))
    assert f.descriptors.dtype == np.float32 and f.descriptors.shape == (len(f.xy_px), 128)
    assert np.all(f.descriptors >= 0)
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-3)


def test_pyramid_level_keypoints_are_in_full_resolution_pixels():
    """Detected on level 2 (a 4x smaller image), keypoints of a shifted copy move by the full-resolution shift."""
    small = texture(150, 200, seed=3)
    img = cv2.resize(small, (800, 600), interpolation=cv2.INTER_CUBIC)
    shift = (40, 24)  # multiples of 4: the same pixels on level 2
    moved = np.zeros_like(img)
    moved[shift[1]:, shift[0]:] = img[:-shift[1], :-shift[0]]
    p = FeatureSettings(budget=400, grid=(2, 2), max_dim_px=200)
    fa, fb = extract(img, p), extract(moved, p)
    assert fa.level == fb.level == 2
    assert fa.xy_px[:, 0].max() > 600 and fa.xy_px[:, 1].max() > 450  # full-resolution coordinates
    bf = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True)
    m = bf.match(fa.descriptors, fb.descriptors)
    d = np.array([fb.xy_px[x.trainIdx] - fa.xy_px[x.queryIdx] for x in m])
    good = np.hypot(*(d - shift).T) < 2.0
    assert good.sum() >= 30 and good.mean() > 0.5
    assert np.abs(np.median(d[good], axis=0) - shift).max() < 0.3


def test_cache_is_reused_until_the_image_changes(tmp_path):
    path = tmp_path / "f.png"
    cv2.imwrite(str(path), texture(120, 160))
    p = FeatureSettings(budget=200, grid=(2, 2))
    first = cached_features(path, tmp_path / "cache", p, (160, 120))
    cache = features_cache_path(path, tmp_path / "cache", p)
    assert cache.is_file()
    stamp = cache.stat().st_mtime_ns
    again = cached_features(path, tmp_path / "cache", p, (160, 120))
    assert cache.stat().st_mtime_ns == stamp and np.array_equal(again.xy_px, first.xy_px)
    # other parameters: another cache file
    assert features_cache_path(path, tmp_path / "cache", FeatureSettings(budget=300)) != cache
    # a changed image is extracted again
    cv2.imwrite(str(path), texture(120, 160, seed=9))
    os.utime(path, ns=(stamp + 10**9, stamp + 10**9))
    changed = cached_features(path, tmp_path / "cache", p, (160, 120))
    assert not np.array_equal(changed.xy_px, first.xy_px)


def test_a_blank_frame_is_refused_by_name(tmp_path):
    path = tmp_path / "blank.png"
    cv2.imwrite(str(path), np.full((120, 160), 90, np.uint8))
    with pytest.raises(InputError, match="blank.png: no image features"):
        cached_features(path, tmp_path / "cache", FeatureSettings(), (160, 120))
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())  # nothing cached


@pytest.mark.parametrize("max_dim_px, level", [(1000, 0), (200, 3)])
def test_keypoints_sit_on_the_image_content(max_dim_px, level):
    """An image and its copy turned by 180 degrees give the same keypoints (x -> W-1-x, y -> H-1-y): no constant
    offset in image coordinates, which the adjustment would take for a principal-point shift and the LiDAR
    control (measured without it) would then show as plan errors flipping with the flight direction.
    801 x 601 px: the pyramid levels (up to 3) of the turned copy sample the same pixels."""
    img = cv2.resize(texture(150, 200, seed=5), (801, 601), interpolation=cv2.INTER_CUBIC)
    p = FeatureSettings(budget=600, grid=(3, 3), max_dim_px=max_dim_px)
    fa, fb = extract(img, p), extract(img[::-1, ::-1].copy(), p)
    assert fa.level == fb.level == level
    back = np.array([800.0, 600.0]) - fb.xy_px  # the turned copy's keypoints in the image's pixels
    d, j = cKDTree(back).query(fa.xy_px, distance_upper_bound=1.0)
    near = np.isfinite(d)
    assert near.sum() >= 100
    offset = np.median(fa.xy_px[near] - back[j[near]], axis=0) / 2  # half the difference: the offset of one
    assert np.abs(offset).max() < 0.03


def test_matches_without_parallax_give_no_epipolar_geometry_and_no_crash():
    """Trial s96 H1: one picture under two names gave matches at the same pixels, and OpenCV's essential matrix
    asserted (solvePoly), a traceback with exit 1. No inliers now (the pair unverified)."""
    from aerotri.geom.camera import BrownCamera
    from aerotri.match.matching import verify
    from aerotri.match.settings import PairMatchSettings

    cam = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=1728, height=960, name="DMC-like")
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(0, 1728, 400), rng.uniform(0, 960, 400)])
    ok = verify(xy, xy.copy(), cam, PairMatchSettings())
    assert ok.dtype == bool and len(ok) == 400
