"""Strips from the GNSS track: runs of consecutive frames (in image-id order) with a consistent heading."""

from __future__ import annotations

import numpy as np


def strips_from_track(position_m, max_turn_deg: float = 30.0, max_gap_factor: float = 3.0) -> np.ndarray:
    """Strip index (0, 1, ...) per frame for positions (N, 3) given in flight order.

    A new strip starts where the heading between consecutive frames turns by more than
    ``max_turn_deg`` from the strip's heading, or where the base is longer than ``max_gap_factor``
    times the median base.
    """
    p = np.asarray(position_m, dtype=float)
    n = len(p)
    strip = np.zeros(n, dtype=int)
    if n < 2:
        return strip
    d = np.diff(p[:, :2], axis=0)
    base = np.hypot(d[:, 0], d[:, 1])
    heading = np.degrees(np.arctan2(d[:, 0], d[:, 1]))
    median_base = np.median(base[base > 0]) if np.any(base > 0) else 1.0
    s, strip_heading = 0, None
    for i in range(1, n):
        h, gap = heading[i - 1], base[i - 1] > max_gap_factor * median_base
        turn = 0.0 if strip_heading is None else abs((h - strip_heading + 180.0) % 360.0 - 180.0)
        if gap or turn > max_turn_deg:
            s, strip_heading = s + 1, None  # frame i starts a new strip
        elif strip_heading is None:
            strip_heading = h
        strip[i] = s
    return strip


def along_track_km(position_m, strip) -> np.ndarray:
    """Signed distance along each strip from the strip's middle (km), the time proxy for GNSS drift."""
    p = np.asarray(position_m, dtype=float)
    out = np.zeros(len(p))
    for s in np.unique(strip):
        idx = np.flatnonzero(strip == s)
        if len(idx) < 2:
            continue
        q = p[idx, :2]
        d = q[-1] - q[0]
        d = d / (np.linalg.norm(d) or 1.0)
        out[idx] = ((q - q.mean(axis=0)) @ d) / 1000.0
    return out
