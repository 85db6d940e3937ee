"""Pairwise matching: mutual nearest neighbours with Lowe's ratio test, then geometric verification
with the essential matrix (nominal camera, RANSAC seeded for repeatable results). Cached per pair."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from aerotri.geom.camera import BrownCamera
from aerotri.match.features import Features
from aerotri.match.pairs import PairGuide
from aerotri.match.settings import PairMatchSettings
from aerotri.core.atomic import atomic_path


def _two_nearest(d2: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index of the smallest, the smallest and the second smallest squared distance along ``axis``."""
    i1 = d2.argmin(axis=axis)
    d1 = np.take_along_axis(d2, np.expand_dims(i1, axis), axis).squeeze(axis)
    np.put_along_axis(d2, np.expand_dims(i1, axis), np.inf, axis)
    second = d2.min(axis=axis)
    np.put_along_axis(d2, np.expand_dims(i1, axis), d1[..., None] if axis == 1 else d1[None], axis)
    return i1, d1, second


def mutual_ratio_matches(da: np.ndarray, db: np.ndarray, ratio: float, chunk: int = 2048) -> np.ndarray:
    """(M, 2) index pairs that are each other's nearest neighbour and pass the ratio test both ways.

    Brute force as one BLAS product: squared L2 distances |a|^2 + |b|^2 - 2 a.b in row blocks of
    ``chunk`` descriptors (memory ``chunk * len(db) * 4`` bytes); each block serves both directions
    (nearest and second-nearest of every row, running nearest and second-nearest of every column), so
    the distances are computed once, not twice as with two knnMatch calls. The ratio test compares
    distances (``d1 < ratio * d2``, i.e. squared ``d1^2 < ratio^2 d2^2``). Rows in ``da`` order.
    """
    na, nb = len(da), len(db)
    if na < 2 or nb < 2:
        return np.zeros((0, 2), int)
    da = np.ascontiguousarray(da, np.float32)
    db = np.ascontiguousarray(db, np.float32)
    sq_b = np.einsum("ij,ij->i", db, db)
    sq_a = np.einsum("ij,ij->i", da, da)
    row_i = np.empty(na, np.int64)
    row_ok = np.empty(na, bool)
    col_i = np.full(nb, -1, np.int64)
    col_1 = np.full(nb, np.inf, np.float32)
    col_2 = np.full(nb, np.inf, np.float32)
    r2 = np.float32(ratio * ratio)
    for s in range(0, na, chunk):
        d2 = da[s:s + chunk] @ db.T
        d2 *= -2.0
        d2 += sq_a[s:s + chunk, None]
        d2 += sq_b[None, :]
        np.maximum(d2, 0.0, out=d2)  # rounding of near-identical descriptors
        i1, d1, second = _two_nearest(d2, 1)
        row_i[s:s + chunk] = i1
        row_ok[s:s + chunk] = d1 < r2 * second
        j1, e1, e2 = _two_nearest(d2, 0)   # a one-row block: second nearest inf
        # Merge this block's two nearest with the running two nearest of every column.
        better = e1 < col_1
        col_2 = np.where(better, np.minimum(col_1, e2), np.minimum(col_2, e1))
        col_i = np.where(better, j1 + s, col_i)
        col_1 = np.where(better, e1, col_1)
    col_ok = col_1 < r2 * col_2
    a = np.flatnonzero(row_ok)
    b = row_i[a]
    keep = col_ok[b] & (col_i[b] == a)
    return np.column_stack([a[keep], b[keep]]).astype(int).reshape(-1, 2)


def verify(xa: np.ndarray, xb: np.ndarray, camera: BrownCamera, p: PairMatchSettings) -> np.ndarray:
    """Inlier mask of putative correspondences under an essential matrix (RANSAC)."""
    if len(xa) < max(8, p.min_inliers):
        return np.zeros(len(xa), bool)
    na = np.column_stack(camera.pixel_to_normalized(xa[:, 0], xa[:, 1]))
    nb = np.column_stack(camera.pixel_to_normalized(xb[:, 0], xb[:, 1]))
    cv2.setRNGSeed(p.seed)
    try:
        E, mask = cv2.findEssentialMat(na, nb, np.eye(3), method=cv2.RANSAC, prob=0.9999,
                                       threshold=p.ransac_px / camera.focal_px, maxIters=5000)
    except cv2.error:  # a degenerate sample (no parallax: one picture twice, trial s96 H1): no epipolar geometry
        return np.zeros(len(xa), bool)
    if E is None or mask is None:
        return np.zeros(len(xa), bool)
    return mask.ravel().astype(bool)


def locally_consistent(xa: np.ndarray, xb: np.ndarray, tol_px: float, k: int) -> np.ndarray:
    """Reject matches whose parallax disagrees with their neighbours'.

    The epipolar constraint cannot see a match that slid along its epipolar line, which is what
    repetitive texture (road dashes, roof vents) produces. Relative to a homography of the pair, the
    remaining displacement is parallax from relief, smooth except at roof edges; a match off its
    neighbours' median by more than ``tol_px`` is dropped (a few true roof-edge points go with them).
    """
    n = len(xa)
    if n < k + 1:
        return np.ones(n, bool)
    H, _ = cv2.findHomography(xa, xb, cv2.LMEDS)
    if H is None:
        return np.ones(n, bool)
    pred = cv2.perspectiveTransform(xa[None].astype(np.float64), H)[0]
    r = xb - pred
    _, nn = cKDTree(xa).query(xa, k=k + 1)
    med = np.median(r[nn[:, 1:]], axis=1)
    return np.hypot(*(r - med).T) <= tol_px


def guided_matches(fa: Features, fb: Features, camera: BrownCamera, ratio: float, guide: PairGuide | None
                   ) -> np.ndarray:
    """Mutual ratio-test matches (indices into ``fa``, ``fb``); with a ``guide`` only between the keypoints
    that the flight plan puts in the other frame's (grown) footprint, so that a cross-strip pair with 30 %
    overlap compares a tenth of the descriptor pairs, and the ratio test sees no distractors from
    outside the overlap."""
    if guide is None:
        return mutual_ratio_matches(fa.descriptors, fb.descriptors, ratio)
    ia, ib = (np.flatnonzero(m) for m in guide.in_overlap(camera, fa.xy_px, fb.xy_px))
    m = mutual_ratio_matches(fa.descriptors[ia], fb.descriptors[ib], ratio)
    return np.column_stack([ia[m[:, 0]], ib[m[:, 1]]]).reshape(-1, 2)


def match_pair(fa: Features, fb: Features, camera: BrownCamera, p: PairMatchSettings, guide: PairGuide | None = None
               ) -> np.ndarray:
    """Verified matches of a frame pair: (M, 2) keypoint indices; ``guide``: see ``guided_matches``."""
    m = guided_matches(fa, fb, camera, p.ratio, guide)
    if len(m) == 0:
        return m
    ok = verify(fa.xy_px[m[:, 0]], fb.xy_px[m[:, 1]], camera, p)
    m = m[ok]
    if len(m):
        scale = 2.0 ** max(fa.level, fb.level)
        m = m[locally_consistent(fa.xy_px[m[:, 0]], fb.xy_px[m[:, 1]], p.local_px * scale, p.local_k)]
    return m if len(m) >= p.min_inliers else np.zeros((0, 2), int)


def match_cache_path(tag: str, cache_dir: Path, p: PairMatchSettings, feature_key: str, guided: bool = False) -> Path:
    return cache_dir / f"{tag}.{feature_key}.{p.key()}{'.guided' if guided else ''}.npy"


def cached_match(tag: str, fa: Features, fb: Features, camera: BrownCamera, p: PairMatchSettings, *, cache_dir: Path,
                 feature_key: str, guide: PairGuide | None = None) -> np.ndarray:
    """Verified matches of a frame pair, from ``cache_dir`` when matched before with the same parameters and
    features (``feature_key``)."""
    f = match_cache_path(tag, cache_dir, p, feature_key, guide is not None)
    if f.exists():
        return np.load(f)
    m = match_pair(fa, fb, camera, p, guide)
    with atomic_path(f) as tmp:
        np.save(tmp, m)
    return m
