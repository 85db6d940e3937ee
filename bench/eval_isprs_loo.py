"""ISPRS filter test: leave-one-sample-out estimate of the ground filter's total error.

The default parameters of the morphological filter were chosen in earlier rounds looking at these
very 7 samples, so their mean total error is a fit, not an accuracy figure. Here the parameters are
chosen from a grid without the sample they are scored on: for each sample, the grid point with the
lowest mean total error over the other six is applied to it. The mean of those seven scores is the
leave-one-out (LOO) estimate; its gap to the in-sample figure (the grid point best over all seven,
and the shipped default) is the over-fitting the habit exposes.

Same path as ``bench/eval_isprs.py`` "lidarctl_default_morph_tin": noise flags first, then
``lidarctl.classify.ground.ground_filter`` (morph + TIN refinement + raised plateaus) on the rest.
Writes bench/results/lidar_isprs_loo.json. Run: .venv/bin/python bench/eval_isprs_loo.py

``--method ptd``: the same for the progressive TIN densification (``ground_filter(method='ptd')``, with
the raised-plateau test) over its own grid; writes bench/results/lidar_isprs_loo_ptd.json.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES, grid_points  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.checks import classes as evaluate
from lidarctl.classify import ground
from lidarctl.classify import noise

# The morphological filter's physical knobs: terrain slope tolerated (tan) by the opening, the first
# ground set's growth of tolerance with slope, the local-surface test's height above the plane of the
# neighbours, and the refinement's angle criterion. (Until session 36 the grid was slope (0.2, 0.3, 0.45),
# elevation_threshold_m (0.2, 0.3, 0.5), elevation_scaler (0.75, 1.0, 1.25), max_window_m (12, 18, 25)
# on the filter without the local-surface test and the angle criterion: default 3.82 %, LOO 3.72 %.)
GRIDS = {
    "morph": {
        "slope": (0.25, 0.3, 0.35),
        "elevation_scaler": (0.75, 1.0, 1.25),
        "surface_height_m": (0.3, 0.5, 0.8),
        "refine_angle_deg": (10.0, 20.0, 30.0),
    },
    # The densification's knobs: the seed cell (larger than the largest building, small enough to put a
    # seed on every ground level), the iteration angle (steep terrain vs objects close to the ground),
    # the seed check's step (walls between ground levels) and how many points join a triangle at once.
    "ptd": {
        "seed_cell_m": (20.0, 30.0, 45.0),
        "max_angle_deg": (18.0, 25.0, 32.0),
        "seed_max_residual_m": (5.0, 8.0),
        "points_per_triangle": (0, 1),
    },
}
RESULTS = {"morph": "lidar_isprs_loo.json", "ptd": "lidar_isprs_loo_ptd.json"}
# ptd runs with every candidate joining at once over a 1.2 m distance band (bench/eval_isprs.py "angle25_all")
FIXED = {"morph": {}, "ptd": {"max_distance_m": 1.2}}


def total_errors(samples, combos, method="morph"):
    """errors[i, j]: total error (%) of grid point i on sample j."""
    err = np.zeros((len(combos), len(samples)))
    for j, s in enumerate(samples):
        c = io.read_cloud(DATA / "isprs_filtertest" / f"{s}-utm.laz")
        keep = noise.detect_noise(c.x, c.y, c.z) == 0
        truth = c.classification == 2
        for i, params in enumerate(combos):
            g = np.zeros(len(c), bool)
            g[keep] = ground.ground_filter(c.x[keep], c.y[keep], c.z[keep], method=method, **FIXED[method], **params)
            err[i, j] = evaluate.filter_errors(g, truth).total_error_pct
        print(f"{s}: {len(combos)} grid points, best {err[:, j].min():.2f} %, worst {err[:, j].max():.2f} %")
    return err


def leave_one_out(err):
    """Per held-out sample: the grid point chosen on the others and its score there."""
    chosen, scores = [], []
    for j in range(err.shape[1]):
        others = np.delete(err, j, axis=1).mean(axis=1)
        i = int(np.argmin(others))
        chosen.append(i)
        scores.append(float(err[i, j]))
    return chosen, scores


def main(method: str = "morph"):
    grid = GRIDS[method]
    default = {k: getattr(ground.ground_filter_named(method).params(), k) for k in grid}
    combos = grid_points(grid, default)
    t0, load0 = time.perf_counter(), os.getloadavg()
    err = total_errors(SAMPLES, combos, method)
    chosen, loo_scores = leave_one_out(err)
    best_all = int(np.argmin(err.mean(axis=1)))
    i_default = combos.index(default)
    loo_mean = float(np.mean(loo_scores))
    in_sample = float(err[best_all].mean())
    out = {
        "data": "ISPRS WG III/3 filter test, the 7 shared samples (../shared/data/isprs_filtertest)",
        "method": f"noise flags, then lidarctl.classify.ground.ground_filter(method={method!r}) with the grid point",
        "fixed_params": FIXED[method],
        "grid": {k: list(v) for k, v in grid.items()},
        "n_grid_points": len(combos),
        "definitions": "total error = misclassified / all points (%); LOO: parameters chosen on the other "
                       "six samples by mean total error, scored on the held-out one",
        "default_params": default,
        "default_total_error_pct": dict(zip(SAMPLES, err[i_default].round(3).tolist())),
        "default_mean_total_error_pct": float(err[i_default].mean()),
        "default_note": "the shipped defaults were chosen in earlier rounds on these 7 samples: in-sample",
        "best_on_all_7_params": combos[best_all],
        "best_on_all_7_mean_total_error_pct": in_sample,
        "loo": {s: {"chosen_params": combos[i], "total_error_pct": sc} for s, i, sc in zip(SAMPLES, chosen, loo_scores)},
        "loo_mean_total_error_pct": loo_mean,
        "loo_gap_vs_best_on_all_7_points": loo_mean - in_sample,
        "loo_gap_vs_default_points": loo_mean - float(err[i_default].mean()),
        "targets": {"shared7_max_pct": 3.3 if method == "morph" else 6.0, "loo_gap_max_points": 0.5},
        "seconds": time.perf_counter() - t0,
        "load_average_before_after": [list(load0), list(os.getloadavg())],
    }
    out["targets_met"] = {"shared7": bool(out["default_mean_total_error_pct"] <= out["targets"]["shared7_max_pct"]),
                          "loo_gap": bool(abs(out["loo_gap_vs_default_points"]) < 0.5)}
    print(f"default {out['default_mean_total_error_pct']:.2f} %, best on all 7 {in_sample:.2f} %, "
          f"leave-one-out {loo_mean:.2f} % (gap {out['loo_gap_vs_best_on_all_7_points']:+.2f} points to the "
          f"best on all 7, {out['loo_gap_vs_default_points']:+.2f} to the default)")
    for s, i, sc in zip(SAMPLES, chosen, loo_scores):
        print(f"  {s}: chosen {combos[i]} -> {sc:.2f} % (default {err[i_default, SAMPLES.index(s)]:.2f} %)")
    path = REPO / "bench" / "results" / RESULTS[method]
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--method") + 1] if "--method" in sys.argv else "morph")
