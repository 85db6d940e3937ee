"""Tracks from pairwise matches: one image point is never two tracks."""

from __future__ import annotations

import numpy as np

from aerotri.match.tracks import build_tracks, coincident


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
