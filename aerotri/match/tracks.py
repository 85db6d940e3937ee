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


def complete_tracks(track: np.ndarray, image: np.ndarray, node: np.ndarray, *, node_xy: list[np.ndarray],
                    node_desc: list[np.ndarray], node_rep: list[np.ndarray], pair_links: list,
                    size_px: tuple[int, int], tol_px: float, k: int = 10, desc_quantile: float = 0.9):
    """Extend tracks into the frames of verified pairs where they have no observation yet.

    A keypoint can be in a third frame and still miss its track: the pair's ratio test saw a look-alike
    there, or mutual nearest neighbours failed. For every verified pair (a, b) and every track seen in a
    but not in b, the track's point is predicted in b from the pair's own verified matches (a homography
    plus the median remaining parallax of its ``k`` nearest verified matches in a, as in
    ``matching.locally_consistent``); a free keypoint of b within ``tol_px`` of the prediction joins the
    track when its descriptor is as close to the track's keypoint in a as the pair's verified matches are
    (within their ``desc_quantile`` distance). Each track gains at most one keypoint per frame, each
    keypoint joins at most one track (the closest descriptor wins), and no keypoint already in a track
    is taken: completion only adds observations, it starts no track and merges none.

    ``node``: the tracks' keypoint rows of ``node_xy[i]`` / ``node_desc[i]`` (the rows of frame i's
    keypoints, full-resolution px and unit-length descriptors); ``node_rep[i]``: for every row the row
    that stands for its place (``coincident``); ``pair_links``: (a, b, (M, 2) verified row pairs).
    Returns the tracks with the new observations (sorted by track, image) and their number."""
    import cv2
    from scipy.spatial import cKDTree

    n_img = len(node_xy)
    if len(track) == 0:
        return track, image, node, 0
    # (track, frame) pairs present, as sorted keys: a dense table would grow with tracks x frames
    seen = np.unique(track.astype(np.int64) * n_img + image)

    def has(key: np.ndarray) -> np.ndarray:
        pos = np.minimum(np.searchsorted(seen, key), len(seen) - 1)
        return seen[pos] == key

    by_image = np.argsort(image, kind="stable")
    bounds = np.searchsorted(image[by_image], np.arange(n_img + 1))
    used = [np.zeros(len(x), bool) for x in node_xy]
    for i in range(n_img):
        used[i][node[by_image[bounds[i]:bounds[i + 1]]]] = True
    trees: dict[int, cKDTree] = {}  # of the last few frames b (pairs come in block order): not one a frame
    W, H = size_px
    prop_t, prop_b, prop_row, prop_d2 = [], [], [], []
    for a_, b_, m_ in pair_links:
        if len(m_) < max(k + 1, 8):
            continue
        for a, b, m in ((a_, b_, m_), (b_, a_, m_[:, ::-1])):
            xa, xb = node_xy[a][m[:, 0]], node_xy[b][m[:, 1]]
            Hab, _ = cv2.findHomography(xa, xb, cv2.LMEDS)
            if Hab is None:
                continue
            d2_ok = np.quantile(np.sum((node_desc[a][m[:, 0]] - node_desc[b][m[:, 1]]) ** 2, axis=1), desc_quantile)
            resid = xb - cv2.perspectiveTransform(xa[None].astype(np.float64), Hab)[0]
            sel = by_image[bounds[a]:bounds[a + 1]]
            sel = sel[~has(track[sel].astype(np.int64) * n_img + b)]
            if len(sel) == 0:
                continue
            pts = node_xy[a][node[sel]]
            pred = cv2.perspectiveTransform(pts[None].astype(np.float64), Hab)[0]
            _, nn = cKDTree(xa).query(pts, k=k)
            pred += np.median(resid[nn], axis=1)
            inside = (pred[:, 0] >= -0.5) & (pred[:, 0] <= W - 0.5) & (pred[:, 1] >= -0.5) & (pred[:, 1] <= H - 0.5)
            sel, pred = sel[inside], pred[inside]
            tree = trees.pop(b, None)
            trees[b] = tree = cKDTree(node_xy[b]) if tree is None else tree
            if len(trees) > 16:
                trees.pop(next(iter(trees)))  # the least recently used
            dist, cand = tree.query(pred, k=4, distance_upper_bound=tol_px)
            ok = np.isfinite(dist)
            q, c = np.nonzero(ok)
            rows_b = cand[q, c]
            rep_b = node_rep[b][rows_b]
            free = ~used[b][rep_b]
            q, rows_b, rep_b = q[free], rows_b[free], rep_b[free]
            d2 = np.sum((node_desc[a][node[sel[q]]] - node_desc[b][rows_b]) ** 2, axis=1)
            good = d2 <= d2_ok
            prop_t.append(track[sel[q[good]]])
            prop_b.append(np.full(int(good.sum()), b))
            prop_row.append(rep_b[good])
            prop_d2.append(d2[good])
    if not prop_t:
        return track, image, node, 0
    t, b, row, d2 = (np.concatenate(x) for x in (prop_t, prop_b, prop_row, prop_d2))
    # best first; one keypoint per (track, frame), one track per keypoint
    order = np.argsort(d2, kind="stable")
    t, b, row = t[order], b[order], row[order]
    _, first = np.unique(t.astype(np.int64) * n_img + b, return_index=True)
    keep = np.zeros(len(t), bool)
    keep[first] = True
    t, b, row = t[keep], b[keep], row[keep]
    # the keypoint's key: frame b's row; sizes differ per frame, so offsets
    offsets = np.concatenate([[0], np.cumsum([len(x) for x in node_xy])])
    d2 = d2[order][keep]
    order = np.argsort(d2, kind="stable")
    t, b, row = t[order], b[order], row[order]
    _, first = np.unique(offsets[b] + row, return_index=True)
    t, b, row = t[first], b[first], row[first]
    track = np.concatenate([track, t])
    image = np.concatenate([image, b])
    node = np.concatenate([node, row])
    order = np.lexsort((image, track))
    return track[order], image[order], node[order], int(len(t))
