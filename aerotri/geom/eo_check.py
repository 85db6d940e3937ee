"""Approximate orientations that cannot be right: kappa errors read from the tie points.

A frame's kappa error turns its picture of the ground about its nadir point. Each tie point measured in frames
i and j is put on a level ground (height ``ground_height_m``) through each frame's approximate orientation: g_i, g_j
(map x, y). With kappa errors d_i, d_j (given minus true) and the true ground point P, g = c + R(d) (P - c) for each
frame's centre c (nadir frames, level ground), so over the points they share

    g_j = R(d_j - d_i) g_i + t,    t = c_j + R(d_j) (c_i - c_j) - R(d_j - d_i) c_i:

a 2D rigid fit of g_j on g_i gives d_j - d_i (its rotation) and, through t, d_j itself (the turn of the baseline
c_i - c_j), so a block whose frames are all 180 deg off (the pairs then agree in rotation and stand two bases
apart) is told as well as one frame off. A frame's error is the median over the frames it shares points with.

Errors are said with their likely cause: about 180 deg (the strip's direction, or the camera's x axis taken the
other way), about 90 deg (x and y swapped, a portrait frame), kappa in gon read as degrees (true = 0.9 x given).
Omega and phi errors (e.g. the two swapped) tilt a near-nadir frame by little and are not told here.

Limits chosen on the demo (simulated; truth and adjusted orientations within 0.3 deg, every frame 180 deg off read
177.6-180, gon read 9.2-10.7 on its east-west strips) and checked on the NGI frames (real orientations of another
camera and block, 30 % forward overlap: right frames within 2.1 deg, every frame 180 deg off 174.9-180, gon 19-20 deg
on the frames of kappa near 180).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.core.errors import InputError, id_listing

KAPPA_LIMIT_DEG = 10.0  # a frame whose kappa is off by more is named (right frames: the demo under 0.3 deg, NGI 2.1; with
# 3 deg of kappa noise and 5 m of centre noise within 2.8 deg of their error: the demo, tests/aerotri/geom/test_eo_check.py)
KAPPA_REFUSE_DEG = 30.0  # the adjustment refuses approximations off by more (the demo: 10 deg in every frame solved,
# one frame 180 deg off without GNSS "solved" 1,296 m off at the check points, every frame 180 deg off with GNSS failed)
MIN_COMMON_POINTS = 6  # tie points two frames must share for their pair to count


@dataclasses.dataclass(frozen=True)
class KappaError:
    """One frame's kappa error estimated from the tie points (degrees; given minus true, in (-180, 180])."""

    image_id: str
    kappa_deg: float  # as given
    error_deg: float
    pairs: int  # frames it shares tie points with

    @property
    def cause(self) -> str:
        e, k = abs(self.error_deg), self.kappa_deg
        gon = _wrap(k - 0.9 * k)  # gon read as degrees: given - true = 0.1 x given
        if abs(_wrap(self.error_deg - gon)) < max(2.0, 0.25 * e) and e >= 3.0:
            return "kappa in gon read as degrees?"
        if e > 150.0:
            return "180 deg off: the strip's direction, or the camera's x axis the other way?"
        if 60.0 < e < 120.0:
            return "90 deg off: x and y swapped, or a portrait frame's axes?"
        return "kappa off"


def _wrap(a_deg):
    return (np.asarray(a_deg, float) + 180.0) % 360.0 - 180.0


def _ground(camera, eo, ties, ground_height_m: float):
    """(N, 2) map x, y of every tie measurement on the level ground through its frame's orientation (NaN: a ray
    that does not reach it), and the rows of the measurements' frames in ``eo``."""
    rows = eo.rows(ties.image_id)
    R = eo.rotations()
    g = np.full((len(ties), 2), np.nan)
    for r in np.unique(rows):
        k = rows == r
        d = camera.rays(ties.xy_px[k, 0], ties.xy_px[k, 1], R[r])
        C = eo.centre_m[r]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (ground_height_m - C[2]) / d[:, 2]
        ok = s > 0
        g[np.flatnonzero(k)[ok]] = C[:2] + s[ok, None] * d[ok, :2]
    return g, rows


def kappa_errors(eo, camera, ties, ground_height_m: float) -> list[KappaError]:
    """Every frame's kappa error (those sharing ``MIN_COMMON_POINTS`` tie points with another frame); ``eo`` the
    approximations (project CRS, metres), ``ties`` the measured tie points (``ImageObservations``)."""
    known = set(eo.image_id)
    keep = np.fromiter((i in known for i in ties.image_id.tolist()), bool, count=len(ties))
    ties = type(ties)(ties.point_id[keep], ties.image_id[keep], ties.xy_px[keep])
    g, rows = _ground(camera, eo, ties, ground_height_m)
    ok = np.isfinite(g).all(axis=1)
    g, rows, pid = g[ok], rows[ok], ties.point_id[ok]
    by_frame = {}
    for k in range(len(rows)):
        by_frame.setdefault(int(rows[k]), {})[pid[k]] = g[k]
    frames = sorted(by_frame)
    est: dict[int, list] = {r: [] for r in frames}
    c = eo.centre_m[:, :2]
    for a, i in enumerate(frames):
        for j in frames[a + 1:]:
            common = by_frame[i].keys() & by_frame[j].keys()
            base = c[i] - c[j]
            if len(common) < MIN_COMMON_POINTS or np.hypot(*base) <= 0:
                continue
            common = sorted(common)
            gi = np.array([by_frame[i][p] for p in common])
            gj = np.array([by_frame[j][p] for p in common])
            mi, mj = gi.mean(axis=0), gj.mean(axis=0)
            u, v = gi - mi, gj - mj
            rot = np.arctan2(np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), np.sum(u * v))  # d_j - d_i
            cr, sr = np.cos(rot), np.sin(rot)
            Rr = np.array([[cr, -sr], [sr, cr]])
            t = mj - Rr @ mi
            w = t - c[j] + Rr @ c[i]  # = R(d_j) (c_i - c_j)
            d_j = np.arctan2(w[1], w[0]) - np.arctan2(base[1], base[0])
            est[j].append(np.degrees(d_j))
            est[i].append(np.degrees(d_j - rot))
    out = []
    for r in frames:
        if est[r]:
            e = np.asarray(_wrap(est[r]))
            # the median of angles about the circular mean (errors near 180 deg wrap to -180)
            m = float(np.degrees(np.arctan2(np.sin(np.radians(e)).mean(), np.cos(np.radians(e)).mean())))
            out.append(KappaError(eo.image_id[r], float(eo.opk_deg[r, 2]), float(_wrap(m + np.median(_wrap(e - m)))),
                                  len(e)))
    return out


def ground_guess_m(eo, camera, mean_terrain_m=None) -> float:
    """A level ground below the frames for ``kappa_errors`` (whose turns hardly depend on it: the demo's with the
    ground at 0 m instead of 310 m agree to 0.01 deg): ``mean_terrain_m`` when known, else the centres' median height
    less a flying height from the base between frames at 60 % forward overlap."""
    if mean_terrain_m is not None:
        return float(mean_terrain_m)
    c = np.asarray(eo.centre_m, float)
    d = np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1)
    base = np.median(d[d > 0]) if np.any(d > 0) else 100.0
    return float(np.median(c[:, 2]) - base / 0.4 / (min(camera.width, camera.height) / camera.focal_px))


def kappa_message(bad: list, n_frames: int, source: str) -> str:
    """One line naming the frames of ``bad`` (``KappaError``) by likely cause (at most 5 per cause)."""
    causes = {}
    for e in bad:
        causes.setdefault(e.cause, []).append(e)
    parts = [f"{cause} {id_listing([f'{e.image_id} ({e.kappa_deg:.1f} given, {e.error_deg:+.0f} off)' for e in es], 5)}"
             for cause, es in causes.items()]
    return (f"{source}: the approximate kappa of {len(bad)} of {n_frames} frames is off (their tie points, put on the "
            "ground through them, turn against the neighbours' by the angles given): " + "; ".join(parts)
            + ". Expected omega phi kappa in degrees, photogrammetric (camera x right, y up, z back) against the "
            "project's map axes")


def check_kappa(eo, camera, ties, ground_height_m: float, source: str, limit_deg: float = KAPPA_LIMIT_DEG,
                frames=None) -> list:
    """``InputError`` naming the frames of ``source`` (of ``frames``, None: all) whose kappa is off by more than
    ``limit_deg`` and the likely cause; else the estimates (``kappa_errors``)."""
    errors = kappa_errors(eo, camera, ties, ground_height_m)
    bad = [e for e in errors if abs(e.error_deg) > limit_deg and (frames is None or e.image_id in frames)]
    if bad:
        raise InputError(kappa_message(bad, len(errors), source))
    return errors


# Strips whose headings differ by more fly opposite ways; a camera fixed in the aircraft turns with it, so their
# kappas differ by about 180 deg (crab angles change that by tens of degrees at most). Angles in radians read as
# degrees differ by at most 2 pi "deg" (the NGI block: 3.1 against 179.3 deg in degrees).
OPPOSITE_STRIPS_DEG = 150.0
KAPPA_TURN_MIN_DEG = 90.0


def radians_read_as_degrees(eo) -> str | None:
    """Why the angles of ``eo`` (omega, phi, kappa in degrees as read) look like radians, or None: every angle
    within +-pi (+ 1e-3) and kappa the same, within ``KAPPA_TURN_MIN_DEG``, on strips flown opposite ways
    (``strips_from_track`` of the centres in the file's order; strips of two frames or more). A block without
    opposite strips (one strip, or a drone holding its heading on every line) is not told."""
    from aerotri.geom.strips import strips_from_track

    opk = np.asarray(eo.opk_deg, float)
    if len(opk) < 4 or not np.all(np.abs(opk) <= np.pi + 1e-3):
        return None
    strip = strips_from_track(eo.centre_m)
    heads, kappas = [], []
    for s in np.unique(strip):
        k = np.flatnonzero(strip == s)
        if len(k) < 2:
            continue
        d = eo.centre_m[k[-1], :2] - eo.centre_m[k[0], :2]
        heads.append(np.degrees(np.arctan2(d[0], d[1])))
        kappas.append(float(np.median(opk[k, 2])))
    # every pair of strips: how far apart their headings and their kappas are (deg)
    heads, kappas = np.array(heads), np.array(kappas)
    a, b = np.triu_indices(len(heads), 1)
    head_turn, kappa_turn = np.abs(_wrap(heads[a] - heads[b])), np.abs(_wrap(kappas[a] - kappas[b]))
    opposite = head_turn > OPPOSITE_STRIPS_DEG
    if not opposite.any() or kappa_turn[opposite].max() >= KAPPA_TURN_MIN_DEG:
        return None
    return (f"omega, phi and kappa all within +-{np.pi:.4f}, and kappa differs by at most "
            f"{kappa_turn[opposite].max():.2f} between strips flown opposite ways (headings up to "
            f"{head_turn[opposite].max():.0f} deg apart; a camera turns with the aircraft, its kappa by about 180 "
            f"deg): angles in radians? (x 57.2958 for degrees)")
