"""Block strength: tie points in the 9 von Gruber regions of every stereo model, multi-ray points,
and ties between adjacent strips.

A stereo model is a pair of consecutive frames of a strip. Its overlap area (the intersection of
the two predicted footprints) is divided into 3 x 3 regions along and across the base; a tie point
of the model is a track seen in both frames, located on the ground through the first frame's
approximate orientation.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.geom.camera import BrownCamera
from aerotri.match.pairs import BlockPlan


def model_regions(plan: BlockPlan, camera: BrownCamera, i: int, j: int, xy_i: np.ndarray) -> np.ndarray:
    """Counts (3, 3) of tie points in the von Gruber regions of model (i, j); rows across, columns along."""
    ov = plan.footprints[i].intersection(plan.footprints[j])
    counts = np.zeros((3, 3), int)
    if ov.is_empty or len(xy_i) == 0:
        return counts
    base = plan.centre_m[j, :2] - plan.centre_m[i, :2]
    u = base / (np.linalg.norm(base) or 1.0)
    v = np.array([-u[1], u[0]])
    poly = np.asarray(ov.exterior.coords)
    pu, pv = poly @ u, poly @ v
    g = plan.ground_xy(i, camera, xy_i)
    gu, gv = g @ u, g @ v
    a = np.clip(((gu - pu.min()) / (np.ptp(pu) or 1.0) * 3).astype(int), 0, 2)
    b = np.clip(((gv - pv.min()) / (np.ptp(pv) or 1.0) * 3).astype(int), 0, 2)
    inside = (gu >= pu.min()) & (gu <= pu.max()) & (gv >= pv.min()) & (gv <= pv.max())
    np.add.at(counts, (b[inside], a[inside]), 1)
    return counts


def stereo_models(plan: BlockPlan) -> list[tuple[int, int]]:
    models = []
    for s in np.unique(plan.strip):
        idx = np.flatnonzero(plan.strip == s)
        models.extend((int(a), int(b)) for a, b in zip(idx[:-1], idx[1:]))
    return models


@dataclasses.dataclass
class ModelStrength:
    """Tie points of one stereo model (frames i, j of a strip) in its 3 x 3 von Gruber regions."""

    left: str
    right: str
    i: int
    j: int
    ties: int
    regions: list[list[int]]  # (3, 3) counts: rows across, columns along the base
    weak: bool  # fewer than ``min_per_region`` ties in some region


@dataclasses.dataclass
class StripTies:
    """Tracks shared by two adjacent strips (1-based strip numbers)."""

    strip_a: int
    strip_b: int
    ties: int
    weak: bool  # fewer than ``min_strip_ties``


@dataclasses.dataclass
class BlockStrength:
    models: list[ModelStrength]
    cross_strip: list[StripTies]


def analyse(plan: BlockPlan, camera: BrownCamera, track, image, xy_px, *, min_per_region: int = 3,
            min_strip_ties: int = 20) -> BlockStrength:
    """Per-model region counts, weak models, cross-strip tie counts and weak strip pairs."""
    n_img = len(plan.image_id)
    by_image = [dict() for _ in range(n_img)]
    for k, (t, i) in enumerate(zip(track, image)):
        by_image[i][int(t)] = k
    models = []
    for i, j in stereo_models(plan):
        common = sorted(set(by_image[i]) & set(by_image[j]))
        xy_i = xy_px[[by_image[i][t] for t in common]] if common else np.zeros((0, 2))
        c = model_regions(plan, camera, i, j, xy_i)
        models.append(ModelStrength(left=plan.image_id[i], right=plan.image_id[j], i=i, j=j, ties=len(common),
                                    regions=c.tolist(), weak=bool(c.min() < min_per_region)))
    strips = np.unique(plan.strip)
    track_strips: dict[int, set] = {}
    for t, i in zip(track, image):
        track_strips.setdefault(int(t), set()).add(int(plan.strip[i]))
    cross = []
    for a, b in zip(strips[:-1], strips[1:]):
        n = sum(1 for s in track_strips.values() if a in s and b in s)
        cross.append(StripTies(strip_a=int(a) + 1, strip_b=int(b) + 1, ties=n, weak=n < min_strip_ties))
    return BlockStrength(models, cross)


_ACROSS = ("right", "middle", "left")  # rows of the regions: v points left of the base (frame i -> j)
_ALONG = ("first", "middle", "last")  # columns: along the base, from frame i's side


def _short_regions(m: ModelStrength, min_per_region: int) -> str:
    """Where a weak model lacks ties, in words: whole thirds across or along the base when they are empty, else the
    number of short regions."""
    c = np.asarray(m.regions)
    short = c < min_per_region
    if short.all():
        return f"under {min_per_region} in every region"
    rows = [_ACROSS[r] for r in range(3) if short[r].all()]
    cols = [_ALONG[k] for k in range(3) if short[:, k].all()]
    if rows and len(rows) * 3 == int(short.sum()):
        return f"under {min_per_region} in the {' and '.join(rows)} third{'s' if len(rows) > 1 else ''} across the base"
    if cols and len(cols) * 3 == int(short.sum()):
        return f"under {min_per_region} in the {' and '.join(cols)} third{'s' if len(cols) > 1 else ''} along the base"
    return f"{int(short.sum())} of 9 regions under {min_per_region}"


def weak_model_words(models: list[ModelStrength], densified_models: int, min_per_region: int,
                     show: int = 4) -> list[str]:
    """What the weak models are, which they are, why and what they mean for the adjustment (console lines of
    ``aerotri match``); no lines when none is weak."""
    weak = [m for m in models if m.weak]
    if not weak:
        return []
    lines = [f"{len(weak)} of {len(models)} stereo models (the pairs of consecutive frames of a strip, of all the "
             f"pairs matched) are weak: fewer than {min_per_region} tie points in some of the 9 regions (3 x 3, "
             "along and across the base) of their overlap"
             + (f", after {densified_models} were matched again with dense features" if densified_models else "")
             + ":"]
    lines += [f"  {m.left}-{m.right}: {m.ties} ties, {_short_regions(m, min_per_region)}" for m in weak[:show]]
    if len(weak) > show:
        lines.append(f"  ... and {len(weak) - show} more (at/connectivity.json weak_models, red in connectivity.png)")
    lines.append("  Ties on part of the overlap only determine the two frames' relative orientation (their tilt about "
                 "the base above all) weakly: the adjustment leans on the GNSS, control or a DEM there and may call "
                 "the solution weak. "
                 "Water, snow or uniform fields give no ties; elsewhere add overlap, control or a DEM "
                 "(aerotri adjust --dem) where the regions are empty.")
    return lines
