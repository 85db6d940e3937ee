"""The isolation test without a voxel lattice: a cube centred on each point (issue 44, outlier locality).

Why: the 3 x 3 x 3 voxel test anchored its lattice at the data's minimum, so one stray point 25 m below
AHN3 Delft moved every voxel and changed the noise verdict of points 80 m away (and through the ground
filter, 980 classes). The cube of half-edge ``h`` voxels centred on each point has no lattice.

Selection (h, in voxels) on the simulator: ``synthetic_scene`` seeds 11-15 (not the unit test's seed 3),
80 low and 30 high injected outliers each. Rule: no clean point flagged by ``detect_noise`` (the suite's
standing rule that no true ground point of ISPRS becomes noise), then fewest injected outliers missed.
History, stated because it shaped the rule: a first run chose by "missed + flagged" (equal weights): h 1.25
(8 missed, 8 flagged; 1.5: 17 and 0; the old lattice test 14 and 2), which on ISPRS samp11 made one true
ground point noise; the rule above (written before that, in tests/lidarctl/test_classify_realdata.py)
takes precedence, so it is now part of the selection, on the simulator.
Scored with the chosen h, beside the old lattice test (``git show REF:lidarctl/classify/noise.py``), on
real data never used to choose it: the 7 ISPRS samples (ground filter's total error with the defaults,
true ground flagged as noise), AHN3 Delft (a copy of a building point 25 m down: points whose noise code
or class changes elsewhere; 100 m tiles against one piece: isolation verdicts that differ away from the
tile edges; the classes of the whole crop, old test against the cube), and the flagged counts on Autzen, lidR Topography and MixedConifer.
Writes bench/results/isolation_cube.json.
Run: nice .venv/bin/python bench/eval_isolation_cube.py [--old-ref d5ebccc5]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES, module_at  # noqa: E402

from lidarctl import io, synthetic  # noqa: E402
from lidarctl.checks import classes as evaluate  # noqa: E402
from lidarctl.classify import ground, noise  # noqa: E402
from lidarctl.classify import pipeline as classify  # noqa: E402

H_GRID = (1.0, 1.25, 1.5, 1.75, 2.0)
SEEDS = (11, 12, 13, 14, 15)


def synthetic_score(mod):
    """Injected outliers missed and clean points flagged by ``mod.detect_noise`` over the selection seeds."""
    missed = false = 0
    for seed in SEEDS:
        cloud, truth = synthetic.synthetic_scene(width_m=150.0, density_per_m2=3.0, seed=seed,
                                                 n_low_outliers=80, n_high_outliers=30, canopy_gap=0.15)
        code = mod.detect_noise(cloud.x, cloud.y, cloud.z)
        out = np.isin(truth, (7, 18))
        missed += int(np.sum(out & (code == 0)))
        false += int(np.sum(~out & (code > 0)))
    return {"outliers_missed": missed, "outliers": 110 * len(SEEDS), "clean_flagged": false}


def select_h():
    rows = {}
    for h in H_GRID:
        noise.CUBE_HALF_EDGE_VOXELS = h
        rows[h] = synthetic_score(noise)
        print(f"h {h}: {rows[h]}", flush=True)
    best = min(H_GRID, key=lambda h: (rows[h]["clean_flagged"] > 0, rows[h]["outliers_missed"], -h))
    return best, rows


def isprs(mod):
    per = {}
    for s in SAMPLES:
        c = io.read_cloud(DATA / "isprs_filtertest" / f"{s}-utm.laz")
        code = mod.detect_noise(c.x, c.y, c.z)
        keep = code == 0
        g = np.zeros(len(c), bool)
        g[keep] = ground.ground_filter(c.x[keep], c.y[keep], c.z[keep])
        e = evaluate.filter_errors(g, c.classification == 2)
        per[s] = {"total_error_pct": round(e.total_error_pct, 3), "isolated": int(np.sum(code == mod.ISOLATED)),
                  "noise": int(np.sum(code > 0)),
                  "true_ground_as_noise": int(np.sum((code > 0) & (c.classification == 2)))}
    mean = float(np.mean([r["total_error_pct"] for r in per.values()]))
    return {"samples": per, "mean_total_error_pct": round(mean, 3)}


def ahn3(mod):
    c = io.read_cloud(DATA / "ahn3_delft" / "ahn3_cropped_1.laz", crs="EPSG:28992")
    x, y, z = c.x, c.y, c.z
    rn, nr, it = c.return_number, c.number_of_returns, c.intensity
    # the new-user trial's stray: a copy of the building point at (84816.28, 447433.55) 25 m down
    i = int(np.argmin(np.hypot(x - 84816.282, y - 447433.552) + np.abs(z - 25.0 - (-21.632))))
    code0 = mod.detect_noise(x, y, z)
    code1 = mod.detect_noise(np.r_[x, x[i]], np.r_[y, y[i]], np.r_[z, z[i] - 25.0])
    orig = noise.detect_noise
    noise.detect_noise = mod.detect_noise        # the pipeline's noise step, old or new
    try:
        cls0 = classify.classify_points(x, y, z, rn, nr, it)
        cls1 = classify.classify_points(np.r_[x, x[i]], np.r_[y, y[i]], np.r_[z, z[i] - 25.0],
                                        np.r_[rn, rn[i]], np.r_[nr, nr[i]], np.r_[it, it[i]])
    finally:
        noise.detect_noise = orig
    stray = {"stray_flagged": int(code1[-1]), "noise_codes_changed": int(np.sum(code0 != code1[:-1])),
             "classes_changed": int(np.sum(cls0 != cls1[:-1]))}
    voxel = max(2.0, 2.5 * noise.grid.mean_spacing_m(x, y))
    whole = mod.isolated_points(x, y, z, voxel)
    tiled = np.zeros(len(x), bool)
    x0, y0 = np.floor(x.min() / 100) * 100, np.floor(y.min() / 100) * 100
    tx, ty = ((x - x0) // 100).astype(int), ((y - y0) // 100).astype(int)
    inner = np.zeros(len(x), bool)
    for t in np.unique(tx * 1000 + ty):
        m = tx * 1000 + ty == t
        tiled[m] = mod.isolated_points(x[m], y[m], z[m], voxel)
        a, b = t // 1000, t % 1000
        inner[m] = ((x[m] - x0 - a * 100 >= 3 * voxel) & (x0 + (a + 1) * 100 - x[m] >= 3 * voxel)
                    & (y[m] - y0 - b * 100 >= 3 * voxel) & (y0 + (b + 1) * 100 - y[m] >= 3 * voxel))
    tiles = {"voxel_m": round(voxel, 3), "isolated_whole": int(whole.sum()),
             "differ_away_from_tile_edges": int(np.sum((whole != tiled) & inner)), "points_away": int(inner.sum())}
    return {"stray_25m_below": stray, "tiles_100m": tiles}, cls0


def flagged_counts(mod):
    out = {}
    for name, path in (("autzen", DATA / "autzen" / "autzen_trim.laz"),
                       ("lidr_topography", DATA / "lidr_topography" / "Topography.laz"),
                       ("lidr_mixedconifer", DATA / "lidr_mixedconifer" / "MixedConifer.laz")):
        if not path.exists():
            continue
        c = io.read_cloud(path)
        code = mod.detect_noise(c.x, c.y, c.z)
        out[name] = {"points": len(c), "isolated": int(np.sum(code == mod.ISOLATED)), "noise": int(np.sum(code > 0)),
                     "reference_noise_class_7": int(np.sum(c.classification == 7))}
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--old-ref", default="d5ebccc5")
    args = ap.parse_args()
    t0 = time.perf_counter()
    old = module_at(args.old_ref, "lidarctl/classify/noise.py", "noise_lattice", tempfile.mkdtemp())
    best, rows = select_h()
    noise.CUBE_HALF_EDGE_VOXELS = best
    print(f"chosen h = {best}", flush=True)
    result = {"selection": {"data": f"synthetic_scene seeds {SEEDS}, 150 m, 3 pts/m2, 80 low + 30 high outliers",
                            "rule": "no clean point flagged (detect_noise), then fewest outliers missed",
                            "grid": {str(h): r for h, r in rows.items()}, "chosen_half_edge_voxels": best,
                            "lattice_old": synthetic_score(old)},
              "old_reference": args.old_ref}
    classes = {}
    for name, mod in (("lattice_old", old), ("cube", noise)):
        print(name, flush=True)
        result[name] = {"isprs": isprs(mod)}
        print(" isprs", result[name]["isprs"]["mean_total_error_pct"], flush=True)
        result[name]["ahn3"], classes[name] = ahn3(mod)
        print(" ahn3", result[name]["ahn3"], flush=True)
        result[name]["other"] = flagged_counts(mod)
        print(" other", result[name]["other"], flush=True)
    diff = classes["lattice_old"] != classes["cube"]
    result["ahn3_classes_old_vs_cube"] = {"points_differing": int(diff.sum()), "points": int(len(diff))}
    print(" AHN3 classes, old vs cube:", result["ahn3_classes_old_vs_cube"], flush=True)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    result["load_average_after"] = list(os.getloadavg())
    out = REPO / "bench" / "results" / "isolation_cube.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
