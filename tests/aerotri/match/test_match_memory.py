"""Matching memory (issue 41): SIFT by tiles gives the whole level's keypoints and descriptors away from the tiles'
edges and holds a tile's scale space, not the level's; the tracks read descriptors from the cache per frame."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from aerotri.core.resources import measure
from aerotri.match.features import _TILE_ALIGN_PX, _TILE_MARGIN_PX, _tile_edges, _tiles, cached_keypoints, \
    cached_features, extract_level
from aerotri.match.pipeline import _NodeDescriptors
from aerotri.match.settings import FeatureSettings

from tests.aerotri.match.test_features import texture


def test_tile_edges_are_aligned_and_bounded():
    assert _tile_edges(2048, 1792) == [0, 2048]  # fits a tile and its margins: whole
    for n, t in ((2049, 1792), (4000, 1792), (13824, 1792), (3000, 256), (100_000, 2000)):
        e = _tile_edges(n, t)
        assert e[0] == 0 and e[-1] == n and np.all(np.diff(e) > 0)
        assert all(x % _TILE_ALIGN_PX == 0 for x in e[1:-1])
        assert max(np.diff(e)) <= t + _TILE_ALIGN_PX  # a core: the tile size, give or take the alignment
    cores = list(_tiles((700, 1100), 256))
    covered = np.zeros((700, 1100), int)
    for (r0, r1), (c0, c1), (a, b), (c, d) in cores:
        covered[r0:r1, c0:c1] += 1
        assert a == max(0, r0 - _TILE_MARGIN_PX) and d == min(1100, c1 + _TILE_MARGIN_PX)
    assert np.all(covered == 1)  # the cores partition the level


def test_tiles_give_the_whole_levels_keypoints_and_descriptors():
    """Every keypoint is found in one tile only; away from the cores' edges the tiles' keypoints are the whole
    level's, at the same place (to float32 rounding of the tile's offset: 1e-4 px) with the same descriptor."""
    img = texture(500, 800, seed=5)
    all_kp = dict(budget=10**6, grid=(1, 1), contrast_threshold=0.01)
    whole = extract_level(img, 0, FeatureSettings(**all_kp, tile_px=4096))
    tiled = extract_level(img, 0, FeatureSettings(**all_kp, tile_px=192))
    assert len(whole.xy_px) > 3000
    # no keypoint twice (coincident ones of several orientations are distinct rows in both)
    assert abs(len(tiled.xy_px) - len(whole.xy_px)) < 0.05 * len(whole.xy_px)
    edges_x, edges_y = _tile_edges(800, 192)[1:-1], _tile_edges(500, 192)[1:-1]
    assert edges_x and edges_y
    far = ((np.abs(whole.xy_px[:, 0, None] - np.array(edges_x)[None]).min(axis=1) > 48)
           & (np.abs(whole.xy_px[:, 1, None] - np.array(edges_y)[None]).min(axis=1) > 48))
    assert far.mean() > 0.4
    d, nn = cKDTree(tiled.xy_px).query(whole.xy_px[far], k=4)
    # the same position, and among the rows there (one per orientation) the same descriptor
    same = np.zeros(far.sum(), bool)
    for q in range(4):
        at = d[:, q] < 1e-3
        dd = np.abs(tiled.descriptors[np.minimum(nn[:, q], len(tiled.xy_px) - 1)] - whole.descriptors[far]).max(axis=1)
        same |= at & (dd < 1e-6)
    assert same.mean() > 0.995


def test_tiles_bound_sifts_memory():
    """A 2048 x 1536 px level: SIFT's scale space of the whole level is about 230 bytes a pixel, 700 MB; by 512 px
    tiles it is that of a tile and its margins (768 x 768 px: about 140 MB)."""
    img = texture(1536, 2048, seed=7)
    p = FeatureSettings(budget=3000, grid=(8, 6), tile_px=512)
    rss0 = _rss_mb()
    with measure() as use:
        f = extract_level(img, 0, p)
    if not use.rss_reset:
        pytest.skip("the resident memory high-water mark cannot be reset here (not Linux)")
    assert 0.8 * p.budget <= len(f.xy_px) <= p.budget
    assert use.peak_rss_mb - rss0 < 250


def _rss_mb() -> float:
    from pathlib import Path

    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def test_keypoints_leave_descriptors_in_the_cache(tmp_path):
    import cv2

    path = tmp_path / "f.png"
    cv2.imwrite(str(path), texture(300, 400, seed=2))
    p = FeatureSettings(budget=300, grid=(2, 2))
    k = cached_keypoints(path, tmp_path / "cache", p, (400, 300))
    full = cached_features(path, tmp_path / "cache", p, (400, 300))
    assert callable(k.descriptors) and k.level == full.level  # read when asked for, not held
    np.testing.assert_array_equal(k.xy_px, full.xy_px)
    np.testing.assert_array_equal(k.descriptors(), full.descriptors)
    # the tracks' node descriptors: sparse rows, then the dense rows that are no sparse keypoint; a few frames kept
    new = np.zeros(len(full.xy_px), bool)
    new[::3] = True
    nd = _NodeDescriptors([k, k, k], {1: k}, {1: new}, keep=1)
    assert len(nd) == 3
    np.testing.assert_array_equal(nd[0], full.descriptors)
    np.testing.assert_array_equal(nd[1], np.vstack([full.descriptors, full.descriptors[new]]))
    assert list(nd._recent) == [1]


def test_frames_extracted_side_by_side_as_many_as_the_memory_holds(monkeypatch):
    """A full-size DMC frame's sparse features (level 3, 1728 x 960 px, one tile) need about 380 MB, its dense ones
    (level 2, 3456 x 1920 px, tiles of 2176 px) about 970 MB; under a 1 GiB limit beside 300 MB held one frame is
    extracted at a time of two workers (a trial user's `aerotri match` at 1 GiB was killed with two), under 3 GiB
    both workers run (None: the executor's own number)."""
    from aerotri.core import limits
    from aerotri.core.executor import Executor
    from aerotri.match.features import extraction_bytes
    from aerotri.match.pipeline import _frames_at_once
    from aerotri.match.settings import MatchSettings

    sparse = extraction_bytes(13824, 7680, MatchSettings().sparse)
    dense = extraction_bytes(13824, 7680, MatchSettings().dense)
    assert sparse == 1728 * 960 * 231
    assert dense == 3456 * 1920 + 2176 * 1920 * 230
    monkeypatch.setattr(limits, "resident_bytes", lambda: 300 * 2 ** 20)
    with Executor(workers=2) as ex:
        monkeypatch.setattr(limits, "usable_memory_bytes", lambda: 2 ** 30)
        assert _frames_at_once(ex, sparse, "features") == 1
        assert _frames_at_once(ex, dense, "dense features") == 1  # at least one, though it may not fit
        monkeypatch.setattr(limits, "usable_memory_bytes", lambda: 3 * 2 ** 30)
        assert _frames_at_once(ex, sparse, "features") is None
        assert _frames_at_once(ex, dense, "dense features") is None
