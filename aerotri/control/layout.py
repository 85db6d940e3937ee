"""Control point layout: which measured LiDAR corners become control, which stay check points.

Default rule, the production rule for DMC blocks flown with GNSS:
- full (XYZ) control about every ``full_spacing_baselines`` (5) baselines along each strip at the
  strip edges: on the outer edge of the block's first and last strip and in the middle of every side
  overlap (such a point serves both strips);
- extra height points in the middle strip of every ``height_every_strips`` (3) strips, half-way
  between the full points along the strip centre line;
- each point in the triple-overlap zone (measured in at least ``min_frames`` frames; along track the
  targets lie between the second and the second-last frame of the strip);
- for every target the corner nearest to it within ``search_radius_baselines`` is chosen, preferring
  high score and small multi-ray residuals:
  cost = distance / radius + ``score_weight`` * (1 - score) + ``residual_weight`` * max residual / tolerance.
- a target without such a corner falls back, in this order, to the first candidate set (``FALLBACKS``) with
  a corner within reach: corners lidarctl did not mark usable on flat roofs (lower score, shorter edges or
  not quite right-angled) as the target's kind; flat-roof corners measured in only two frames as height
  control; pitched-roof corners in ``min_frames`` frames as the target's kind. Every candidate passed
  the multi-ray and LiDAR checks (``aerotri.control.consistency``); the tier is recorded per target.
All other accepted corners of the usable set are check points.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.control.settings import LayoutSettings
from aerotri.geom.local_frame import FramesOnEarth
from aerotri.geom.strips import strips_from_track


# Candidate sets of a layout target, tried in this order: (name, kind of the chosen corner; None: the
# target's kind). Tier 0 is the rule itself; the others are the fallbacks before a target stays empty.
TIERS = (("usable", None), ("lower_score", None), ("height_only", "height"), ("pitched_roof", None))
FALLBACKS = tuple(name for name, _ in TIERS[1:])


@dataclasses.dataclass
class LayoutTarget:
    """A position of the layout rule (map coordinates) and the corner chosen for it."""

    kind: str  # full | height: the rule's kind of the target
    target_x_m: float
    target_y_m: float
    corner: int | None = None  # index of the chosen corner (None: no eligible corner within the search radius)
    distance_m: float | None = None  # from the target to the chosen corner
    tier: str | None = None  # candidate set the corner came from (``TIERS``), None when empty
    corner_kind: str | None = None  # kind the chosen corner got (full | height)
    search_radius_m: float | None = None
    empty_reason: str | None = None  # why no corner, for the control report (set by the caller)


def empty_target_text(t: dict) -> str:
    """An empty layout target (a ``LayoutTarget`` as a dict, as in control/transfer.json) in one phrase."""
    return f"{t['kind']} target at {t['target_x_m']:.0f} {t['target_y_m']:.0f}: {t.get('empty_reason') or 'no corner'}"


@dataclasses.dataclass
class Strip:
    images: np.ndarray  # frame indices
    centre_across_m: float
    lo_m: float  # ground footprint edges across track (common across axis)
    hi_m: float
    along_first_m: float  # frame centres along track (common along axis), first and last
    along_last_m: float
    base_m: float


def ground_footprints(camera, centres_m, Rs, ground_z_m: float, frames=None) -> np.ndarray:
    """Ground footprint corners (N, 4, 2) of the frames on the horizontal plane Z = ground_z_m; ``frames``: these
    frames over the earth (``aerotri.geom.local_frame.FramesOnEarth``; None: the coordinates of a Cartesian frame)."""
    frames = frames if frames is not None else FramesOnEarth.cartesian(centres_m, Rs)
    w, h = camera.width - 1, camera.height - 1
    px = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    out = np.zeros((len(centres_m), 4, 2))
    for i in range(len(centres_m)):
        out[i] = frames.at_height(i, frames.rays_local(camera, i, px[:, 0], px[:, 1]), ground_z_m)[:, :2]
    return out


def block_axes(centres_m, strip):
    """Common along-track unit vector (of the first strip) and across-track unit vector (2,)."""
    idx = np.flatnonzero(strip == strip.min())
    d = centres_m[idx[-1], :2] - centres_m[idx[0], :2] if len(idx) > 1 else np.array([1.0, 0.0])
    u = d / (np.linalg.norm(d) or 1.0)
    return u, np.array([-u[1], u[0]])


def strips_of_block(camera, centres_m, Rs, ground_z_m: float, strip=None, frames=None):
    """Strip geometry on the common block axes; strips sorted across track (``frames``: ``ground_footprints``)."""
    strip = strips_from_track(centres_m) if strip is None else np.asarray(strip)
    u, w = block_axes(centres_m, strip)
    fp = ground_footprints(camera, centres_m, Rs, ground_z_m, frames)
    origin = centres_m[:, :2].mean(axis=0)
    out = []
    for s in np.unique(strip):
        idx = np.flatnonzero(strip == s)
        along = (centres_m[idx, :2] - origin) @ u
        across_fp = (fp[idx] - origin) @ w
        base = float(np.median(np.abs(np.diff(np.sort(along))))) if len(idx) > 1 else float(np.ptp(across_fp))
        out.append(Strip(idx, float(np.mean((centres_m[idx, :2] - origin) @ w)), float(np.median(across_fp.min(axis=1))),
                         float(np.median(across_fp.max(axis=1))), float(along.min()), float(along.max()), base))
    out.sort(key=lambda st: st.centre_across_m)
    return out, origin, u, w


def layout_targets(strips, rule: LayoutSettings):
    """Target positions (list of (kind, along_m, across_m)) on the common block axes."""
    targets = []
    n = len(strips)

    def along_positions(sts, spacing_base, shift_half=False):
        lo = max(st.along_first_m + st.base_m for st in sts)
        hi = min(st.along_last_m - st.base_m for st in sts)
        base = float(np.mean([st.base_m for st in sts]))
        if hi < lo:
            lo = hi = 0.5 * (lo + hi)
        k = max(1, int(round((hi - lo) / (spacing_base * base))))
        pos = np.linspace(lo, hi, k + 1)
        return 0.5 * (pos[1:] + pos[:-1]) if shift_half else pos

    for i, st in enumerate(strips):
        width = st.hi_m - st.lo_m
        if i == 0:
            for a in along_positions([st], rule.full_spacing_baselines):
                targets.append(("full", a, st.lo_m + rule.edge_inset * width))
        if i == n - 1:
            for a in along_positions([st], rule.full_spacing_baselines):
                targets.append(("full", a, st.hi_m - rule.edge_inset * width))
        if i < n - 1:
            nb = strips[i + 1]
            mid = 0.5 * (st.hi_m + nb.lo_m)
            for a in along_positions([st, nb], rule.full_spacing_baselines):
                targets.append(("full", a, mid))
    if rule.height_every_strips >= 1:
        for g in range(0, n - rule.height_every_strips + 1, rule.height_every_strips):
            st = strips[g + rule.height_every_strips // 2]
            for a in along_positions([st], rule.full_spacing_baselines, shift_half=True):
                targets.append(("height", a, st.centre_across_m))
    return targets


def candidate_tiers(n_frames, primary, roof, min_frames: int) -> np.ndarray:
    """Candidate set (index into ``TIERS``, -1: none) of each accepted corner.

    n_frames (N,): frames the corner was accepted in; primary (N,): the corner belongs to the set the
    stage measures anyway (lidarctl's usable corners and manual ones; every corner with --all-corners);
    roof (N,): "flat" | "pitched". Two frames suffice only for height control (no third ray to expose a
    wrong measurement) and only on flat roofs, whose LiDAR height is the best known (about 0.03 m
    against 0.07 m on pitched eaves, bench/results/corners_sim.json).
    """
    n_frames, primary, flat = np.asarray(n_frames), np.asarray(primary, bool), np.asarray(roof) == "flat"
    tier = np.full(len(n_frames), -1)
    many = n_frames >= min_frames
    tier[many & primary] = 0
    tier[many & ~primary & flat] = 1
    tier[~many & (n_frames >= 2) & flat] = 2
    tier[many & ~primary & ~flat] = 3
    return tier


def select_control(xy_m, score, n_frames, *, camera, centres_m, Rs, ground_z_m, rule: LayoutSettings | None = None,
                   strip=None, residual_ratio=None, tier=None,
                   check=None, frames=None) -> tuple[np.ndarray, list[LayoutTarget], float]:
    """Kind per corner ("full", "height", "check", or "candidate": a fallback corner not chosen), the
    layout targets, the base (m).

    xy_m (N, 2): accepted corners; score (N,); n_frames (N,): frames each corner was accepted in;
    residual_ratio (N,): largest multi-ray residual / tolerance (0..1), None for none; tier (N,): the
    candidate set of each corner (``candidate_tiers``; None: tier 0 for every corner in ``min_frames``
    frames, none for the others); check (N,): corners that are check points when not chosen (None: all); frames:
    the frames over the earth (``ground_footprints``).
    """
    rule = rule or LayoutSettings()
    strips, origin, u, w = strips_of_block(camera, centres_m, Rs, ground_z_m, strip, frames)
    base = float(np.median([st.base_m for st in strips]))
    radius = rule.search_radius_baselines * base
    if tier is None:
        tier = np.where(np.asarray(n_frames) >= rule.min_frames, 0, -1)
    tier = np.asarray(tier)
    free = np.ones(len(xy_m), bool)
    out = []
    for k, a, c in layout_targets(strips, rule):
        t_xy = origin + a * u + c * w
        dist = np.hypot(*(xy_m - t_xy).T) if len(xy_m) else np.zeros(0)
        cost = dist / radius + rule.score_weight * (1.0 - np.clip(score, 0.0, 1.0))
        if residual_ratio is not None:
            cost = cost + rule.residual_weight * np.clip(residual_ratio, 0.0, 1.0)
        reach = free & (dist <= radius)
        rec = LayoutTarget(k, float(t_xy[0]), float(t_xy[1]), search_radius_m=float(radius))
        for t, (name, as_kind) in enumerate(TIERS):
            if t > 0 and not rule.fallback:
                break
            ok = reach & (tier == t)
            if ok.any():
                j = int(np.flatnonzero(ok)[np.argmin(cost[ok])])
                free[j] = False
                rec.corner, rec.distance_m, rec.tier, rec.corner_kind = j, float(dist[j]), name, as_kind or k
                break
        out.append(rec)
    kind = np.where(np.ones(len(xy_m), bool) if check is None else np.asarray(check, bool), "check",
                    "candidate").astype(object)
    for rec in out:
        if rec.corner is not None:
            kind[rec.corner] = rec.corner_kind
    return kind, out, base
