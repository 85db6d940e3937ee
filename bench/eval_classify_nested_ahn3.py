"""AHN3 part of bench/eval_classify_nested.py: nested cross-validation over the four quarters of the Delft crop.

The classification runs on the whole crop (a quarter's buildings need their neighbourhood) for every
configuration; each quarter is scored per point against AHN3's classes as bench/eval_ahn3_holdout.py
does (classes 2, 6, 9 kept, the rest 1). Error of a configuration on a quarter: 100 - the mean of building
and ground PA and UA (%). The grid is bench/eval_ahn3_holdout.py's, factorised in the same way
(building knobs at the default ground knobs, ground knobs at the default building knobs; a combination
takes its building scores from the one and its ground scores from the other), with
``building_min_area_m2`` left at its default to halve the runs (34 classifications).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time

import numpy as np

from eval_ahn3_holdout import GROUND_GRID, GROUND_KEYS, PARTS, criterion, part_of, scores
from lidar_common import DATA, grid_points
from lidarctl import io
from lidarctl.classify import pipeline as classify

BUILDING_GRID = {
    "roof_rms_m": (0.1, 0.15, 0.25),
    "max_multi_return_fraction": (0.2, 0.3, 0.45),
    "grow_multi_return_fraction": (0.5, 0.7, 0.85),
}


def _key(params: dict) -> str:
    return json.dumps(params, sort_keys=True)


def run_ahn3(cache_dir, nested_cv, loo, make_selectors) -> dict:
    t0, load0 = time.perf_counter(), os.getloadavg()
    path = DATA / "ahn3_delft" / "ahn3_cropped_1.laz"
    c = io.read_cloud(path, crs="EPSG:28992")
    truth, part = c.classification, part_of(c.x, c.y)
    d = classify.ClassifySettings()
    default_b = {k: getattr(d, k) for k in BUILDING_GRID}
    default_g = {k: getattr(d, k) for k in GROUND_GRID}
    combos_b, combos_g = grid_points(BUILDING_GRID, default_b), grid_points(GROUND_GRID, default_g)
    cache_path = cache_dir / "ahn3.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}

    def run(params: dict) -> list:
        k = _key(params)
        if k not in cache:
            pred = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity,
                                            params=dataclasses.replace(d, **params))
            cache[k] = [scores(pred[part == q], truth[part == q]) for q in range(4)] + [scores(pred, truth)]
            cache_dir.mkdir(parents=True, exist_ok=True)
            tmp = cache_path.with_suffix(".tmp")
            tmp.write_text(json.dumps(cache))
            tmp.replace(cache_path)
            print(f"AHN3 {params}: whole crop criterion {criterion(cache[k][4]):.2f}", flush=True)
        return cache[k]

    rows_b = [run({**pb, **default_g}) for pb in combos_b]
    rows_g = [run({**default_b, **pg}) if pg["ground_lift_sigma"] or pg == default_g
              else run({**default_b, **pg, "ground_lift_single": default_g["ground_lift_single"]})
              for pg in combos_g]
    configs, table = [], []
    for pb, rb in zip(combos_b, rows_b):
        for pg, rg in zip(combos_g, rows_g):
            configs.append({**pb, **pg})
            table.append([{**rb[q], **{key: rg[q][key] for key in GROUND_KEYS}} for q in range(5)])
    err = np.array([[100.0 - criterion(s) for s in row[:4]] for row in table])
    grid_def = {**BUILDING_GRID, **GROUND_GRID}
    selectors = make_selectors(configs, grid_def)
    nest = nested_cv(err, selectors)
    plain = loo(err, selectors["mean"])
    default = {**default_b, **default_g}
    i_def = configs.index(default)
    best_all = int(np.argmin(np.array([100.0 - criterion(row[4]) for row in table])))
    keys = ("building_pa_pct", "building_ua_pct", "ground_pa_pct", "ground_ua_pct")

    def figures(i, q):
        return {k: table[i][q][k] for k in keys}

    out = {
        "data": f"{path.name} (AHN3 Delft crop, EPSG:28992), {len(c):,} points, quarters at the median x/y",
        "grid": {k: list(v) for k, v in grid_def.items()}, "n_configurations": len(configs),
        "criterion": "error = 100 - mean of building and ground PA and UA (%), per point against AHN3's classes",
        "nested": {
            "estimate_error_pct": nest["estimate"],
            "folds": {PARTS[f["held_out"]]: {"selector": f["selector"], "chosen": configs[f["chosen"]],
                                              "inner_loo_error_by_selector_pct": f["inner_loo_error_by_selector"],
                                              "held_out_error_pct": f["held_out_error"],
                                              "held_out": figures(f["chosen"], f["held_out"])}
                      for f in nest["folds"]},
        },
        "loo_mean_selector": {"estimate_error_pct": plain["estimate"],
                              "per_quarter": {PARTS[q]: {"chosen": configs[i], "error_pct": sc, **figures(i, q)}
                                              for q, (i, sc) in enumerate(zip(plain["chosen"], plain["scores"]))}},
        "defaults": {"config": default, "error_pct": float(err[i_def].mean()),
                     "per_quarter": {PARTS[q]: figures(i_def, q) for q in range(4)},
                     "whole_crop": figures(i_def, 4)},
        "best_on_whole_crop": {"config": configs[best_all], "whole_crop": figures(best_all, 4)},
        "seconds": time.perf_counter() - t0,
        "load_average_before_after": [list(load0), list(os.getloadavg())],
    }
    print(f"AHN3: nested error {nest['estimate']:.2f} %, LOO {plain['estimate']:.2f} %, defaults "
          f"{err[i_def].mean():.2f} % (100 - mean of building/ground PA/UA)")
    for name, f in out["nested"]["folds"].items():
        print(f"  {name}: {f['selector']} -> {f['held_out']}")
    return out
