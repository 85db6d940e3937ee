"""Smoke tests for false classes on real clouds the classification was never tuned on.

Their own classes are incomplete, so only what the truth can judge is counted:
- ``lidr_topography`` (forested hills, classes 1/2/9): truth-ground points classified water, split
  into those under canopy (a return more than 2 m above within ``CANOPY_RADIUS_M``) and the rest
  (lake rims at the level of a return gap); truth-water points found; truth ground classified
  building.
- ``autzen`` (classes 1/2; class 2 is a thinned ground set): truth-ground points given an object,
  water or noise class (class 1 holds unlabelled ground too, so it is not judged).
- ``laspy_nebraska`` (a 18 x 12 m single-return tile, classes 2-7): vegetation (3/4/5) classified
  building, building producer's and user's accuracy.
Writes results/lidar_false_classes.json. Run: .venv/bin/python bench/eval_false_classes.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO  # noqa: E402

from lidarctl import classify, io  # noqa: E402

CANOPY_RADIUS_M = 2.0
CANOPY_HEIGHT_M = 2.0


def run(path):
    c = io.read_cloud(path)
    pred = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    return c, pred


def under_canopy(c, idx) -> np.ndarray:
    """Mask over ``idx``: a return more than CANOPY_HEIGHT_M above the point within CANOPY_RADIUS_M."""
    tree = cKDTree(np.column_stack([c.x, c.y]))
    near = tree.query_ball_point(np.column_stack([c.x[idx], c.y[idx]]), CANOPY_RADIUS_M)
    return np.array([np.max(c.z[nb]) - c.z[i] > CANOPY_HEIGHT_M for nb, i in zip(near, idx)], bool)


def bridge_decks(pred, truth) -> dict:
    """Bridge-deck (17) points and their true classes: none of these clouds has a bridge in its README."""
    deck = pred == classify.BRIDGE_DECK
    return {"bridge_deck": int(deck.sum()),
            "bridge_deck_truth_class": {str(k): int(v) for k, v in zip(*np.unique(truth[deck], return_counts=True))}}


def topography():
    c, pred = run(DATA / "lidr_topography" / "Topography.laz")
    truth = c.classification
    false_water = np.flatnonzero((truth == 2) & (pred == classify.WATER))
    canopy = under_canopy(c, false_water) if len(false_water) else np.zeros(0, bool)
    water = truth == 9
    return {"points": len(c), "truth_ground": int(np.sum(truth == 2)),
            "ground_as_water": len(false_water),
            "ground_as_water_under_canopy": int(canopy.sum()),
            "ground_as_water_open": int((~canopy).sum()),
            "truth_water": int(water.sum()), "truth_water_found": int(np.sum(water & (pred == classify.WATER))),
            "ground_as_building": int(np.sum((truth == 2) & (pred == classify.BUILDING))),
            **bridge_decks(pred, truth),
            "canopy_definition": f"a return more than {CANOPY_HEIGHT_M} m above within {CANOPY_RADIUS_M} m"}


def autzen():
    c, pred = run(DATA / "autzen" / "autzen_trim.laz")
    g = c.classification == 2
    counts = {str(k): int(v) for k, v in zip(*np.unique(pred[g], return_counts=True))}
    return {"points": len(c), "truth_ground": int(g.sum()), "truth_ground_as_class": counts,
            "truth_ground_as_object_pct": 100.0 * float(np.mean(pred[g] != classify.GROUND)),
            "truth_ground_as_water": int(np.sum(pred[g] == classify.WATER)), **bridge_decks(pred, c.classification)}


def nebraska():
    c, pred = run(DATA / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las")
    truth = c.classification
    veg = np.isin(truth, (3, 4, 5))
    b_true, b_pred = truth == 6, pred == classify.BUILDING
    tp = int(np.sum(b_true & b_pred))
    return {"points": len(c), "single_return_only": bool(np.all(c.number_of_returns == 1)),
            "truth_vegetation": int(veg.sum()), "vegetation_as_building": int(np.sum(veg & b_pred)),
            "vegetation_as_building_pct": 100.0 * float(np.mean(b_pred[veg])),
            "building_producers_accuracy_pct": 100.0 * tp / max(int(b_true.sum()), 1),
            "building_users_accuracy_pct": 100.0 * tp / max(int(b_pred.sum()), 1), **bridge_decks(pred, truth)}


def main():
    out = {"lidr_topography": topography(), "autzen": autzen(), "laspy_nebraska": nebraska(),
           "targets": {"lidr_topography_ground_as_water_under_canopy": 0, "bridge_deck_without_bridge": 0}}
    out["target_met"] = out["lidr_topography"]["ground_as_water_under_canopy"] == 0
    out["bridge_deck_target_met"] = all(out[k]["bridge_deck"] == 0 for k in ("lidr_topography", "autzen", "laspy_nebraska"))
    print(json.dumps(out, indent=2))
    path = REPO / "results" / "lidar_false_classes.json"
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
