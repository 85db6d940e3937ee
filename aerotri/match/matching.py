"""Pairwise matching: mutual nearest neighbours with Lowe's ratio test, then geometric verification
with the essential matrix (nominal camera, RANSAC seeded for repeatable results). Cached per pair."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from aerotri.geom.camera import FrameCamera
from aerotri.match.features import Features
from aerotri.match.settings import MatchParams
from aerotri.core.atomic import atomic_path


def mutual_ratio_matches(da: np.ndarray, db: np.ndarray, ratio: float) -> np.ndarray:
    """(M, 2) index pairs that are each other's nearest neighbour and pass the ratio test both ways."""
    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), int)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    ab = bf.knnMatch(da, db, k=2)
    ba = bf.knnMatch(db, da, k=2)
    best_ba = np.array([m[0].trainIdx if m[0].distance < ratio * m[1].distance else -1 for m in ba])
    out = []
    for m in ab:
        if m[0].distance < ratio * m[1].distance and best_ba[m[0].trainIdx] == m[0].queryIdx:
            out.append((m[0].queryIdx, m[0].trainIdx))
    return np.array(out, dtype=int).reshape(-1, 2)


def verify(xa: np.ndarray, xb: np.ndarray, camera: FrameCamera, p: MatchParams) -> np.ndarray:
    """Inlier mask of putative correspondences under an essential matrix (RANSAC)."""
    if len(xa) < max(8, p.min_inliers):
        return np.zeros(len(xa), bool)
    na = np.column_stack(camera.pixel_to_normalized(xa[:, 0], xa[:, 1]))
    nb = np.column_stack(camera.pixel_to_normalized(xb[:, 0], xb[:, 1]))
    cv2.setRNGSeed(p.seed)
    E, mask = cv2.findEssentialMat(na, nb, np.eye(3), method=cv2.RANSAC, prob=0.9999,
                                   threshold=p.ransac_px / camera.focal_px, maxIters=5000)
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


def match_pair(fa: Features, fb: Features, camera: FrameCamera, p: MatchParams) -> np.ndarray:
    m = mutual_ratio_matches(fa.descriptors, fb.descriptors, p.ratio)
    if len(m) == 0:
        return m
    ok = verify(fa.xy_px[m[:, 0]], fb.xy_px[m[:, 1]], camera, p)
    m = m[ok]
    if len(m):
        scale = 2.0 ** max(fa.level, fb.level)
        m = m[locally_consistent(fa.xy_px[m[:, 0]], fb.xy_px[m[:, 1]], p.local_px * scale, p.local_k)]
    return m if len(m) >= p.min_inliers else np.zeros((0, 2), int)


def match_cache_path(tag: str, cache_dir: Path, p: MatchParams, feature_key: str) -> Path:
    return cache_dir / f"{tag}.{feature_key}.{p.key()}.npy"


def cached_match(tag: str, fa: Features, fb: Features, camera: FrameCamera, p: MatchParams, *, cache_dir: Path,
                 feature_key: str) -> np.ndarray:
    """Verified matches of a frame pair, from ``cache_dir`` when matched before with the same parameters and
    features (``feature_key``)."""
    f = match_cache_path(tag, cache_dir, p, feature_key)
    if f.exists():
        return np.load(f)
    m = match_pair(fa, fb, camera, p)
    with atomic_path(f) as tmp:
        np.save(tmp, m)
    return m
