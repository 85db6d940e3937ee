"""Strips from the GNSS track: runs of consecutive frames (in image-id order) with a consistent heading."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def flight_order(image_ids) -> np.ndarray:
    """The indices that put frames in flight order: image-id order (the order the adjustment and the flight plan
    take them in, whatever the order of gnss.txt's lines)."""
    return np.argsort(np.array(list(image_ids), dtype=object), kind="stable")


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


# A GNSS position off the flight line by more than this share of the block's base (and more than
# TRACK_SIGMAS of its sigma and of the track's own scatter) is a blunder of the track: a wrong fix or record
# (an 80 m slip of the first frame of a six-frame block was absorbed by the adjustment as a 41.6 mm principal
# point, the check points 9 m off; the GNSS residuals stayed at 0.02 m: an end frame has no redundancy).
TRACK_BASE_SHARE = 0.1
TRACK_SIGMAS = 8.0
# a base agrees with another within this share of the frames-either-side tolerance (a margin of 0.4 of it for the
# track's scatter; at a full share, a frame next to a 60 m slip of a DMC block was found instead)
REGULAR_SHARE = 0.6
TRACK_MEDIANS = 5.0  # times the median deviation of the track's positions from their predictions
# a frame is judged from the next or previous two frames only within this many of their base from the position
# they predict: further, it starts another strip (a turn), or it is a gap the strips see
TRACK_STEP_BASES = 1.5


@dataclass(frozen=True)
class TrackBlunders:
    """Positions off their flight line (indices into the positions, in the order they were found) with their
    deviation from the position the neighbouring frames predict (m, (K, 3)), that prediction (m, (K, 3)) and the
    tolerance they exceeded (m, (K,))."""

    index: np.ndarray
    deviation_m: np.ndarray
    predicted_m: np.ndarray
    tolerance_m: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


def _block_base(bases: np.ndarray) -> np.ndarray:
    """The block's base vector (m): the median of the bases turned into one half-plane (strips are flown both ways)."""
    length = np.linalg.norm(bases[:, :2], axis=1)
    if not np.any(length > 0):
        return np.zeros(3)
    # the base of median length sets the half-plane: the longest is a turn between strips
    ref = bases[int(np.argsort(length)[len(length) // 2])]
    sign = np.where(bases[:, :2] @ ref[:2] < 0, -1.0, 1.0)
    return np.median(bases * sign[:, None], axis=0)


def _regular(b, neighbours, block_base, tol_m: float) -> bool:
    """A base ``b`` (m) is regular when a neighbouring base of the track or the block's base (either way) agrees
    with it within ``tol_m``: a prediction from it is then not thrown by a blunder of one of its two frames."""
    for o in neighbours:
        if o is not None and np.linalg.norm(b - o) <= tol_m:
            return True
    return min(np.linalg.norm(b - block_base), np.linalg.norm(b + block_base)) <= tol_m


# the scatter of a prediction from the neighbours' own (white) scatter: the frames either side (1 + 1/4 + 1/4),
# the next or previous two extrapolated (1 + 4 + 1); two bases of the track differ by the latter as well
MID_FACTOR, END_FACTOR = float(np.sqrt(1.5)), float(np.sqrt(6.0))
# across one missing exposure (a frame taken out of the block): the next two extrapolated two bases, 3 q1 - 2 q2
GAP_FACTOR = float(np.sqrt(1.0 + 9.0 + 4.0))


def _predictions(q: np.ndarray, block_base, regular_m: np.ndarray) -> list:
    """Per position, the predictions of it from its regular neighbourhoods: [(position (3,), scatter factor)] from
    the frames either side, the next two and the previous two, each where its base agrees with a neighbouring base
    or the block's within ``regular_m`` (m, (M,)); empty where none is regular (turns, irregular tracks)."""
    m = len(q)
    b = np.diff(q, axis=0)  # b[k] = q[k+1] - q[k]

    def base(k):
        return b[k] if 0 <= k < m - 1 else None

    out = []
    for j in range(m):
        reg, tests = regular_m[j], []
        if 0 < j < m - 1:
            s = (q[j + 1] - q[j - 1]) / 2.0
            if _regular(s, (base(j - 2), base(j + 1)), block_base, reg):
                tests.append((q[j - 1] + s, MID_FACTOR))
        # the next or previous two: only when the frame could be on their line (within TRACK_STEP_BASES of their
        # base from where they put it); the first frame after a turn is far off the last strip's line
        if j + 2 < m and _regular(b[j + 1], (base(j + 2),), block_base, reg):
            t = q[j + 1] - b[j + 1]
            if np.linalg.norm(q[j] - t) <= TRACK_STEP_BASES * np.linalg.norm(b[j + 1]):
                tests.append(_across_a_gap(q[j], t, -b[j + 1], q[j - 1] if j > 0 else None))
        if j >= 2 and _regular(b[j - 2], (base(j - 3),), block_base, reg):
            t = q[j - 1] + b[j - 2]
            if np.linalg.norm(q[j] - t) <= TRACK_STEP_BASES * np.linalg.norm(b[j - 2]):
                tests.append(_across_a_gap(q[j], t, b[j - 2], q[j + 1] if j + 1 < m else None))
        out.append(tests)
    return out


def _across_a_gap(q, t, step, other) -> tuple:
    """(prediction, scatter factor) of an extrapolation ``t`` of a frame at ``q`` from the next or previous two:
    ``t + step`` (one base further on, ``step`` the base pointing from them towards the frame) when the frame lies
    within half a base of it, nearer than to ``t``, and its neighbour on the other side (``other``, None at a strip's
    end) is not within half a base of it: an exposure taken out between them, not a blunder (trial s96 M3: the frame
    before a removed one read 121 m off its line and lost its sound position). A record of that neighbour's position
    stays a blunder."""
    gap, half = t + step, 0.5 * np.linalg.norm(step)
    if np.linalg.norm(q - gap) < min(np.linalg.norm(q - t), half) and (
            other is None or np.linalg.norm(q - other) > half):
        return gap, GAP_FACTOR
    return t, END_FACTOR


def track_blunders(position_m, sigma_m=None, *, base_share: float = TRACK_BASE_SHARE,
                   sigmas: float = TRACK_SIGMAS) -> TrackBlunders:
    """GNSS positions (N, 3), in flight order, off their flight line: data snooping on the track, one position at
    a time, the largest first, each judged against the track without the ones found before.

    A frame's position is predicted from its regular neighbourhoods (the frames either side, or the next or the
    previous two, whose base agrees with a neighbouring base or the block's base) and is a blunder when it is off
    every such prediction by more than its tolerance: ``base_share`` of the block's base, ``sigmas`` times its
    sigma (``sigma_m``, (N, 3) or None), and ``TRACK_MEDIANS`` times the track's median deviation scaled by the
    prediction's own scatter (an extrapolation from two frames scatters twice as much as the mean of the frames
    either side). The reference bases must agree within half an extrapolation's tolerance, so that a sound frame
    next to a blunder is never the one found. Frames at irregular stretches (turns, a kite's or a hand-flown
    drone's track) have no prediction and are not judged.
    """
    p = np.asarray(position_m, dtype=float)
    n = len(p)
    empty = TrackBlunders(np.zeros(0, dtype=int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    if n < 4:
        return empty
    sig = np.zeros(n) if sigma_m is None else np.nan_to_num(np.max(np.asarray(sigma_m, dtype=float), axis=1),
                                                            nan=0.0, posinf=0.0)
    active = np.ones(n, dtype=bool)
    found, devs, preds, tols = [], [], [], []
    while active.sum() >= 4 and len(found) < max(1, n // 10):
        idx = np.flatnonzero(active)
        q = p[idx]
        block_base = _block_base(np.diff(q, axis=0))
        base_m = float(np.linalg.norm(block_base[:2]))
        if base_m <= 0:
            break
        # the tolerance of a prediction from the frames either side (m); an extrapolation's is twice as wide
        coarse = np.maximum(base_share * base_m, sigmas * sig[idx] * MID_FACTOR)
        # reference bases within REGULAR_SHARE of the frames-either-side tolerance: a sound frame next to a blunder
        # is then never the one found (a prediction through the blunder is not regular or off by at most that
        # share of its tolerance: half the blunder for the frames either side, twice it for an extrapolation).
        # Not widened by the track's scatter: one blunder in a short block would widen it to let itself in.
        tests = _predictions(q, block_base, coarse * REGULAR_SHARE)
        normalised = [np.linalg.norm(q[j] - t) / f for j, ts in enumerate(tests) for t, f in ts]
        if not normalised:
            break
        # the track's own scatter: the median normalised deviation (a 3-d distance: about 1.5 sigma of one axis)
        scatter = TRACK_MEDIANS * float(np.median(normalised))

        def tolerance(j, f):
            return max(coarse[j] * f / MID_FACTOR, scatter * f)

        best, ratio = -1, 1.0
        for j, ts in enumerate(tests):
            if ts:  # off only when off every prediction, each by its own tolerance (a sound frame next to a
                # blunder has one prediction clear of it)
                r = min(np.linalg.norm(q[j] - t) / tolerance(j, f) for t, f in ts)
                if r > ratio:
                    best, ratio = j, r
        if best < 0:
            break
        pred = np.median([t for t, _ in tests[best]], axis=0)  # placed at the median: an extrapolation scatters more
        found.append(int(idx[best]))
        devs.append(p[idx[best]] - pred)
        preds.append(pred)
        tols.append(float(min(tolerance(best, f) for _, f in tests[best])))
        active[idx[best]] = False
    if not found:
        return empty
    return TrackBlunders(np.array(found, dtype=int), np.array(devs), np.array(preds), np.array(tols))
