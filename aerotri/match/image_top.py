"""The image top the tie points show, against the flight plan's (trial s97 M3).

The flight plan turns every frame by the flight direction plus ``image_top_deg``, by default from the frame's shape
(``pairs.image_top_from_sensor``: a portrait frame is taken as turned across the flight, as large-format cameras fly
their long side across track). A camera mounted the other way (a medium-format camera turned 90 deg in the aircraft,
its long side along track) gets a plan turned 90 deg from the truth: the GNSS-guided matching then finds about half
the ties (the trial: 59 pairs, 9,788 tracks, 15 of 15 stereo models weak; 75, 15,400 and none weak with
``--image-top-deg 0``) and the report blamed water, snow or uniform ground.

The tie points tell it: a point seen in two neighbouring frames of a strip lies at one ground position, and the plan's
nominal attitude (flat terrain, omega = phi = 0) puts its two image positions near it only when the plan's image top is
right. The module compares the median distance between the two ground positions for the plan's image top and for it
turned by 90, 180 and 270 deg.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aerotri.match.pairs import BlockPlan, flat_ground_xy

MAX_PAIRS = 200  # neighbouring frame pairs looked at (spread over the block)
MAX_POINTS = 300  # common tie points per pair
# a turned image top is named when its ground positions agree this much better than the plan's (a right plan agrees
# to the attitude's and the relief's few per cent of the footprint, a plan 90 deg off to a good part of it)
BETTER_FACTOR = 3.0


@dataclasses.dataclass(frozen=True)
class ImageTopCheck:
    """The plan's image top (deg), the median ground distance (m) of tie points between neighbouring frames of a
    strip for each turn of it (0, 90, 180, 270 deg), the pairs and points compared."""

    plan_deg: float
    misfit_m: dict
    pairs: int
    points: int

    @property
    def best_turn_deg(self) -> float:
        return min(self.misfit_m, key=self.misfit_m.get)

    @property
    def wrong(self) -> bool:
        best = self.best_turn_deg
        return best != 0.0 and self.misfit_m[best] * BETTER_FACTOR < self.misfit_m[0.0]

    def text(self) -> str:
        best = self.best_turn_deg
        deg = (self.plan_deg + best) % 360.0
        return (f"the tie points put the frames' image top at {deg:g} deg from the flight direction, not the "
                f"{self.plan_deg:g} deg of the flight plan (by default from the frame's shape: a portrait frame is "
                f"taken as turned across the flight): over {self.pairs} pairs of neighbouring frames their two ground "
                f"positions agree within {self.misfit_m[best]:.1f} m turned so, {self.misfit_m[0.0]:.1f} m as planned. "
                "Matching guided by the wrong plan finds fewer ties and calls stereo models weak; set [match] "
                f"image_top_deg = {deg:g} in project.toml (aerotri run), or give aerotri match --image-top-deg "
                f"{deg:g}, and run again")


def image_top_check(plan: BlockPlan, camera, track: np.ndarray, image: np.ndarray, xy: np.ndarray
                    ) -> ImageTopCheck | None:
    """The check of the module docstring on tie point observations (``track``, ``image``, ``xy`` (K, 2) px); None
    without neighbouring frames that share points."""
    pairs = []
    for s in np.unique(plan.strip):
        idx = np.flatnonzero(plan.strip == s)
        pairs += list(zip(idx[:-1], idx[1:]))
    if not pairs:
        return None
    if len(pairs) > MAX_PAIRS:
        pairs = [pairs[k] for k in np.linspace(0, len(pairs) - 1, MAX_PAIRS).round().astype(int)]
    turns = (0.0, 90.0, 180.0, 270.0)
    dist = {t: [] for t in turns}
    n_pairs = 0
    # the observations image by image, sorted once (a scan of all of them per pair: 200 x millions on a large block)
    by_image = np.argsort(image, kind="stable")
    bounds = np.searchsorted(image[by_image], np.arange(int(image.max()) + 2 if len(image) else 1))
    for a, b in pairs:
        if max(a, b) + 1 >= len(bounds):
            continue
        in_a, in_b = by_image[bounds[a]:bounds[a + 1]], by_image[bounds[b]:bounds[b + 1]]
        _, ia, ib = np.intersect1d(track[in_a], track[in_b], assume_unique=False, return_indices=True)
        if len(ia) < 5:
            continue
        if len(ia) > MAX_POINTS:
            keep = np.linspace(0, len(ia) - 1, MAX_POINTS).round().astype(int)
            ia, ib = ia[keep], ib[keep]
        xa, xb = xy[in_a[ia]], xy[in_b[ib]]
        n_pairs += 1
        for t in turns:
            ga = flat_ground_xy(plan.centre_m[a], plan.kappa_deg[a] + t, plan.terrain_height_m, camera, xa)
            gb = flat_ground_xy(plan.centre_m[b], plan.kappa_deg[b] + t, plan.terrain_height_m, camera, xb)
            dist[t].append(np.hypot(*(ga - gb).T))
    if not n_pairs:
        return None
    misfit = {t: float(np.median(np.concatenate(dist[t]))) for t in turns}
    return ImageTopCheck(float(plan.image_top_deg), misfit, n_pairs, int(sum(len(d) for d in dist[0.0])))
