"""Tracks: union-find over (image, keypoint) nodes joined by verified matches.

A track that reaches two different keypoints of the same image is inconsistent (two matches chains
disagree); it is dropped rather than guessed. Keypoints at the same place in one image (SIFT gives a
point one keypoint per dominant orientation) are one node (``coincident``): otherwise each of them
would start its own track and the same image point would be measured twice.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def coincident(xy_px: np.ndarray, tol_px: float = 0.5) -> np.ndarray:
    """For each keypoint the index of the first keypoint within ``tol_px`` of it (itself if none)."""
    from scipy.spatial import cKDTree

    xy_px = np.asarray(xy_px, float)
    rep = np.arange(len(xy_px))
    if len(xy_px) < 2:
        return rep
    for a, b in sorted(cKDTree(xy_px).query_pairs(tol_px)):
        rep[b] = min(rep[b], rep[a])
    return rep[rep]  # chains (c -> b -> a) point at their first member


def build_tracks(n_keypoints: list[int], pair_matches: list[tuple[int, int, np.ndarray]]):
    """Returns (track_id, image, keypoint) arrays of the consistent tracks (length >= 2), and the
    number of inconsistent tracks dropped."""
    offsets = np.concatenate([[0], np.cumsum(n_keypoints)])
    rows, cols = [], []
    for i, j, m in pair_matches:
        if len(m):
            rows.append(offsets[i] + m[:, 0])
            cols.append(offsets[j] + m[:, 1])
    n = int(offsets[-1])
    if not rows:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), 0
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    g = coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
    _, label = connected_components(g, directed=False)
    used = np.zeros(n, bool)
    used[r] = True
    used[c] = True
    nodes = np.flatnonzero(used)
    lab = label[nodes]
    image = np.searchsorted(offsets, nodes, side="right") - 1
    kp = nodes - offsets[image]
    # Inconsistent: the same image appears twice in a track.
    key = lab.astype(np.int64) * (len(n_keypoints) + 1) + image
    uniq, counts = np.unique(key, return_counts=True)
    bad_labels = np.unique(uniq[counts > 1] // (len(n_keypoints) + 1))
    ok = ~np.isin(lab, bad_labels)
    lab, image, kp = lab[ok], image[ok], kp[ok]
    # Renumber tracks 0..T-1 in order of first appearance; keep length >= 2.
    _, inv, cnt = np.unique(lab, return_inverse=True, return_counts=True)
    keep = cnt[inv] >= 2
    _, track = np.unique(lab[keep], return_inverse=True)
    order = np.lexsort((image[keep], track))
    return track[order], image[keep][order], kp[keep][order], int(len(bad_labels))
