"""Ground and water figures on labelled airborne clouds beside ISPRS and AHN3 (issue 44): the lidR
MixedConifer plot (conifer forest, first returns only, normalised heights, classes 1/2) and the lidR
Topography cloud (forested hills with lakes, classes 1/2/9).

Nothing is chosen here: the shipped defaults of ``lidarctl classify`` (and of its ground filter alone,
after the noise flags, as bench/eval_isprs.py runs it). Measures: ISPRS filter-test type I / type II /
total error and kappa (bare earth = truth class 2, plus 9 on Topography: a lake surface is bare earth
for a DTM); water producer's / user's accuracy (Topography); returns called water (MixedConifer has
no water: every one is false; the forest floor under dense crowns is the case). Both sets' ground labels
look thinned (lidR's own classification): most accepted 'objects' lie within centimetres of the labelled
ground, so the type II figure is an upper bound; the share within 0.15 m is reported.

With ``--fetched DIR``, labelled airborne clouds found in public repositories and never looked at while the rules were
made (``FETCHED``: lasR's four BC Timber Sales forest tiles, classes 1/2, and lidR's Megaplot, classes 1/2, normalised
heights), each file taken from its repository at the commit named (``git show COMMIT:PATH > DIR/NAME``; nothing is
copied into this repository). They hold no building: every building return called there is false, and is counted
with the shipped defaults and with ``roof_min_patch_m2 = 0`` (the rule before it).
Writes bench/results/ground_more_data.json. Run: nice .venv/bin/python bench/eval_ground_more_data.py [--fetched DIR]
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate
from lidarctl.classify import ground
from lidarctl.classify import noise
from scipy.spatial import cKDTree  # noqa: E402

SETS = {
    "lidr_mixedconifer": ("lidr_mixedconifer/MixedConifer.laz", (2,)),
    "lidr_topography": ("lidr_topography/Topography.laz", (2, 9)),
}

# name -> (file name in --fetched DIR, repository, commit, path, git blob sha1, what it is)
LASR = ("r-lidar/lasR", "86cb3bde85fb02a4ebdf272f6a251b4f0a21b0c6")
FETCHED = {
    **{f"lasr_bcts_{k}": (f"bcts_{k}.laz", *LASR, f"inst/extdata/bcts/bcts_{k}.laz", blob,
                          "BC Timber Sales airborne LiDAR, coastal conifer forest on Vancouver Island (EPSG:3005), "
                          "classes 1/2, 4 returns; lasR (GPL-3)")
       for k, blob in ((1, "70f56f5731995c47fad18defbcd1cb504db04518"),
                       (2, "0b86872ff7b5d63c389ea61d78cf681504cf6c10"),
                       (3, "6c483a7269fc03f340cc04734d51904ccc428480"),
                       (4, "ef48c0f24b223435567c72834117438118e0d1d6"))},
    "lasr_megaplot": ("Megaplot.las", *LASR, "inst/extdata/Megaplot.las", "c00b535621ae4711e42078a59feafc3f9c4bc9e5",
                      "lidR's Megaplot: forest plot (EPSG:26917), classes 1/2, heights normalised to the ground; lasR "
                      "(GPL-3)"),
}


def one(path: Path, bare: tuple, every_roof_cell: bool = False) -> dict:
    c = io.read_cloud(path)
    truth = c.classification
    true_ground = np.isin(truth, bare)
    t0 = time.perf_counter()
    keep = noise.detect_noise(c.x, c.y, c.z) == 0
    g = np.zeros(len(c), bool)
    g[keep] = ground.ground_filter(c.x[keep], c.y[keep], c.z[keep])
    filt_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    pred = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    cls_s = time.perf_counter() - t0
    buildings = {"building_returns_called": int(np.sum(pred == classify.BUILDING))}
    if every_roof_cell:   # the rule before roof_min_patch_m2: every roof cell counts toward a segment's roof area
        every_cell = dataclasses.replace(classify.ClassifySettings(), roof_min_patch_m2=0.0)
        before = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity,
                                          params=every_cell)
        buildings["building_returns_called_every_roof_cell"] = int(np.sum(before == classify.BUILDING))
        buildings["returns_whose_class_the_rule_changed"] = int(np.sum(before != pred))
    pw, tw = pred == classify.WATER, truth == 9
    out = {"points": len(c), "truth_classes": {str(k): int(v) for k, v in zip(*np.unique(truth, return_counts=True))},
           "ground_filter": dataclasses.asdict(evaluate.filter_errors(g, true_ground)),
           # the pipeline's ground: class 2, and water on the lakes (a DTM's bare earth)
           "classify_pipeline": dataclasses.asdict(evaluate.filter_errors(np.isin(pred, (2, 9)), true_ground)),
           "predicted_classes": {str(k): int(v) for k, v in zip(*np.unique(pred, return_counts=True))},
           "water_predicted": int(pw.sum()), "water_truth": int(tw.sum()),
           "truth_ground_called_water": int(np.sum(pw & (truth == 2))),
           "seconds_filter_classify": [filt_s, cls_s], **buildings}
    # Type II against labels that may be thinned: how far above the labelled bare earth (median of its 3
    # nearest labelled points) the accepted object points lie.
    fp = g & ~true_ground
    if fp.any():
        _, i = cKDTree(np.column_stack([c.x[true_ground], c.y[true_ground]])).query(np.column_stack([c.x[fp], c.y[fp]]), k=3)
        dz = c.z[fp] - np.median(c.z[true_ground][i], axis=1)
        out["ground_filter_type_ii_height_above_labelled_ground_m"] = dict(
            zip(("p25", "median", "p75"), np.percentile(dz, [25, 50, 75]).round(3).tolist()))
        out["ground_filter_type_ii_within_0_15_m_pct"] = 100.0 * float(np.mean(np.abs(dz) <= 0.15))
    if tw.any() and np.any(pw & (truth == 2)):
        # Truth ground called water: how far from the labelled water and how far above its level (the
        # median height of the labelled water within 30 m) -- shore returns at the water level, or not.
        fw = np.flatnonzero(pw & (truth == 2))
        wtree = cKDTree(np.column_stack([c.x[tw], c.y[tw]]))
        d_m, _ = wtree.query(np.column_stack([c.x[fw], c.y[fw]]))
        lvl = np.array([np.median(c.z[tw][nb]) if nb else np.nan
                        for nb in wtree.query_ball_point(np.column_stack([c.x[fw], c.y[fw]]), 30.0)])
        out["truth_ground_called_water_distance_to_water_m"] = dict(
            zip(("median", "p90", "max"), np.round([np.median(d_m), np.percentile(d_m, 90), d_m.max()], 2).tolist()))
        out["truth_ground_called_water_height_above_level_m"] = dict(
            zip(("median", "p90", "max"), np.round(np.nanpercentile(np.abs(c.z[fw] - lvl), [50, 90, 100]), 3).tolist()))
    if tw.any():
        out["water_pa_pct"] = 100.0 * float(np.mean(pw[tw]))
        out["water_ua_pct"] = 100.0 * float(np.mean(tw[pw])) if pw.any() else None
    return out


def main(argv=None):
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fetched", type=Path, help="folder of the FETCHED files (git show COMMIT:PATH > DIR/NAME)")
    args = ap.parse_args(argv)
    t0, load0 = time.perf_counter(), os.getloadavg()
    out = {"definitions": "type I = bare earth rejected / bare earth; type II = objects accepted / objects; total = "
                          "misclassified / all (%); bare earth: class 2 (and 9 on Topography)",
           "params": "shipped defaults, nothing chosen on these sets"}
    for name, (rel, bare) in SETS.items():
        path = DATA / rel
        if not path.is_file():
            print(f"{name}: {path} absent, skipped")
            continue
        out[name] = one(path, bare, every_roof_cell=True)
        _say(name, out[name])
    for name, (file, repo, commit, rel, blob, what) in FETCHED.items() if args.fetched else ():
        path = args.fetched / file
        if not path.is_file():
            print(f"{name}: {path} absent, skipped")
            continue
        out[name] = {"source": {"repository": repo, "commit": commit, "path": rel, "git_blob_sha1": blob,
                                "what": what}, **one(path, (2,), every_roof_cell=True)}
        _say(name, out[name])
    out["seconds"] = time.perf_counter() - t0
    out["load_average_before_after"] = [list(load0), list(os.getloadavg())]
    dest = REPO / "bench" / "results" / "ground_more_data.json"
    dest.write_text(json.dumps(out, indent=2))
    print(f"wrote {dest}")


def _say(name: str, r: dict) -> None:
    print(f"{name}: ground filter total {r['ground_filter']['total_error_pct']:.2f} % (I "
          f"{r['ground_filter']['type_i_error_pct']:.2f}, II {r['ground_filter']['type_ii_error_pct']:.2f}); "
          f"classify total {r['classify_pipeline']['total_error_pct']:.2f} %; water {r['water_predicted']} "
          f"(truth {r['water_truth']}, PA {r.get('water_pa_pct')}, UA {r.get('water_ua_pct')}); building returns "
          f"{r['building_returns_called']} (every roof cell: {r.get('building_returns_called_every_roof_cell')})")


if __name__ == "__main__":
    main()
