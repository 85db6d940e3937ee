"""Tracks from pairwise matches: one image point is never two tracks."""

from __future__ import annotations

import numpy as np

from aerotri.match.tracks import build_tracks, coincident, complete_tracks


def test_coincident_keypoints_are_one_node():
    xy = np.array([[10.0, 10.0], [10.2, 10.1], [50.0, 50.0], [10.4, 10.3], [80.0, 5.0]])
    assert coincident(xy).tolist() == [0, 0, 2, 0, 4]


def test_duplicate_keypoints_make_one_track():
    """Image 0 has keypoints 0 and 1 at the same place (two SIFT orientations), each matched to the same
    point of image 1 (keypoints 0 and 1 there, also coincident): one track of two observations."""
    xy0 = np.array([[10.0, 10.0], [10.0, 10.0], [40.0, 40.0]])
    xy1 = np.array([[12.0, 11.0], [12.0, 11.0], [42.0, 41.0]])
    m = np.array([[0, 0], [1, 1], [2, 2]])
    rep0, rep1 = coincident(xy0), coincident(xy1)
    track, image, kp, bad = build_tracks([3, 3], [(0, 1, np.column_stack([rep0[m[:, 0]], rep1[m[:, 1]]]))])
    assert bad == 0 and len(np.unique(track)) == 2 and len(track) == 4
    # without merging, the duplicate keypoints give a second, identical track
    track2, *_ = build_tracks([3, 3], [(0, 1, m)])
    assert len(np.unique(track2)) == 3


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_completion_adds_the_missed_third_observation_only():
    """Three frames of one scene shifted by known offsets. Pair (0, 1) matched every point, pair (0, 2)
    missed points 0-9, which stay two-ray tracks (0, 1). Completion gives each its keypoint in frame 2,
    except: point 0, whose frame-2 keypoint lies 2 px off the prediction (beyond the tolerance); point 1,
    whose frame-2 descriptor is another point's; point 2, whose only keypoint near the prediction already
    belongs to another track (an extra point 60 seen in frames 1 and 2)."""
    rng = np.random.default_rng(3)
    n = 60
    ground = rng.uniform(310, 940, (n, 2))  # inside all three frames
    desc = _unit(rng.random((n, 128)).astype(np.float32))
    shift = np.array([[0.0, 0.0], [-300.0, 4.0], [5.0, -250.0]])
    xy = [ground + s for s in shift]
    d = [_unit(desc + rng.normal(0, 0.01, desc.shape).astype(np.float32)) for _ in range(3)]
    d[2][:10] = d[0][:10]  # the missed points look alike in frames 0 and 2 (closer than the verified matches)
    xy[2][0] += [2.0, 0.0]
    d[2][1] = d[2][30]
    # point 60: in frames 1 and 2 only, its frame-2 keypoint where point 2's prediction falls (0.2 px off)
    xy = [xy[0], np.vstack([xy[1], ground[2] + shift[1] + [40.0, 40.0]]), np.vstack([xy[2], xy[2][2] + [0.2, 0.0]])]
    d = [d[0], np.vstack([d[1], desc[2]]), np.vstack([d[2], desc[2]])]
    xy[2][2] = [-1000.0, -1000.0]  # point 2's own keypoint in frame 2 is lost
    all_ = np.arange(n)
    m01 = np.column_stack([all_, all_])
    m02 = np.column_stack([all_[10:], all_[10:]])
    m12 = np.array([[n, n]])
    links = [(0, 1, m01), (0, 2, m02), (1, 2, m12)]
    sizes = [len(x) for x in xy]
    track, image, kp, bad = build_tracks(sizes, links)
    lengths = np.bincount(track)
    assert bad == 0 and (lengths == 2).sum() == 11 and (lengths == 3).sum() == 50
    reps = [np.arange(s) for s in sizes]
    t2, i2, k2, added = complete_tracks(track, image, kp, node_xy=xy, node_desc=d, node_rep=reps, pair_links=links,
                                        size_px=(1000, 1000), tol_px=0.5)
    assert added == 7
    # every track keeps one keypoint per frame, every keypoint one track
    assert len(np.unique(t2 * 3 + i2)) == len(t2)
    assert len(np.unique(i2 * 1000 + k2)) == len(t2)
    # the points completed got their own keypoint of frame 2
    for p in range(3, 10):
        t = t2[(i2 == 0) & (k2 == p)][0]
        assert k2[(t2 == t) & (i2 == 2)].tolist() == [p]
    for p in (0, 1, 2):
        t = t2[(i2 == 0) & (k2 == p)][0]
        assert (i2[t2 == t]).tolist() == [0, 1]
    # sorted by track, then frame
    assert np.all(np.diff(t2 * 3 + i2) > 0)
