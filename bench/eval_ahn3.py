"""AHN3 Delft crop: building, ground and water producer's / user's accuracy against the AHN3 classes.

Our classes are mapped onto the AHN3 scheme: 2 -> 2, 6 -> 6, 9 -> 9, everything else -> 1
(AHN3 class 1 holds vegetation and street furniture; 26 civil structures has no counterpart).
The file has no CRS record; EPSG:28992 is given explicitly (as `--crs EPSG:28992`).
Writes bench/results/lidar_ahn3.json. Run: .venv/bin/python bench/eval_ahn3.py
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
from lidar_common import DATA, REPO, warm_up_jit  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate


def main():
    path = DATA / "ahn3_delft" / "ahn3_cropped_1.laz"
    c = io.read_cloud(path, crs="EPSG:28992")
    args = (c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    warm_s, warm_cpu_s = warm_up_jit(classify.classify_points, *args)
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    pred = classify.classify_points(*args)
    seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - c0
    mapped = np.where(np.isin(pred, (2, 6, 9)), pred, 1)
    conf = evaluate.confusion(mapped, c.classification, classes=[1, 2, 6, 9, 26])
    filt = evaluate.filter_errors(pred == 2, c.classification == 2)
    pa, ua = conf.producers_accuracy_pct, conf.users_accuracy_pct
    res = {
        "data": str(path), "points": int(len(c)), "classify_seconds": seconds, "classify_cpu_seconds": cpu_seconds,
        "load_average_before_after": [list(load0), list(os.getloadavg())],
        "warm_up_seconds_50k_points_jit_compile_or_cache_load": [warm_s, warm_cpu_s],
        "building_producers_accuracy_pct": pa["6"], "building_users_accuracy_pct": ua["6"],
        "ground_producers_accuracy_pct": pa["2"], "ground_users_accuracy_pct": ua["2"],
        "water_producers_accuracy_pct": pa["9"], "water_users_accuracy_pct": ua["9"],
        "water_points_truth": int(np.sum(c.classification == 9)), "water_points_pred": int(np.sum(pred == 9)),
        "target_pct": 95.0,
        "target_met": bool(min(pa["6"], ua["6"], pa["2"], ua["2"]) >= 95.0),
        "ground_filter_errors": dataclasses.asdict(filt),
        "confusion_ahn3_scheme": dataclasses.asdict(conf),
        "our_class_counts": {str(k): int(v) for k, v in zip(*np.unique(pred, return_counts=True))},
    }
    print(evaluate.format_confusion(conf, {1: "1 other", 2: "2 ground", 6: "6 building", 9: "9 water",
                                           26: "26 civil"}))
    print(evaluate.format_filter_table({"ahn3": filt}))
    print(f"building PA/UA {pa['6']:.2f} / {ua['6']:.2f} %, ground PA/UA {pa['2']:.2f} / {ua['2']:.2f} %, "
          f"water PA/UA {pa['9']:.2f} / {ua['9'] or 0.0:.2f} %")
    print(f"classify_points {seconds:.2f} s ({cpu_seconds:.2f} CPU s) on {len(c):,} points after a "
          f"{warm_s:.1f} s warm-up (JIT), load {load0[0]:.2f}")
    out = REPO / "bench" / "results" / "lidar_ahn3.json"
    out.write_text(json.dumps(res, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
