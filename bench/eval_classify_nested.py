"""Nested cross-validation of the ground filter (ISPRS) and the classification (AHN3 quarters).

Why: a leave-one-out (LOO) estimate chooses the parameters without the scored sample, but the rules
and the way the parameters are chosen were still shaped by looking at every sample. Here everything
that is chosen is chosen inside the fold, on its training samples only, and the held-out sample is
scored once:

* the configuration: the morphological filter's knobs *and* rule switches (local-surface test on/off,
  TIN angle criterion on/off, raised-plateau test on/off), a grid of ``CONFIG_GRID``;
* the selection procedure that turns training errors into one configuration (``SELECTORS``: lowest
  mean error, lowest mean relative error, lowest mean rank, lowest mean error of the configuration and
  its grid neighbours), chosen by an inner leave-one-out over the training samples.

Outer loop: hold out sample j. Inner loop: for every selector, its LOO error over the training
samples (choose on all but one training sample, score on it); the selector with the lowest inner
error chooses a configuration on all training samples; that configuration is scored on j. The mean
over j is the nested estimate of the error on a new sample. Reported beside it: the plain LOO
(selector "mean" fixed, the habit of the earlier rounds, on the same grid), the shipped defaults
(in-sample: chosen in earlier rounds on these 7 samples) and the grid point best on all 7.

AHN3 (``--ahn3``): the same on the four quarters of the Delft crop, criterion 100 - mean of building
and ground PA and UA (%), grid of bench/eval_ahn3_holdout.py (building and ground knobs).

Per-sample errors of every grid point are cached in $NESTED_CACHE (default <tmp>/aerotri_nested_cache)
so that a rerun does not reclassify.
Writes bench/results/classify_nested.json (both parts kept: a run of one part keeps the other's entry).
Run: nice .venv/bin/python bench/eval_classify_nested.py [--isprs] [--ahn3]
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES, grid_points  # noqa: E402

from lidarctl import grid, io  # noqa: E402
from lidarctl.checks import classes as evaluate
from lidarctl.classify import ground
from lidarctl.classify import noise

CACHE = Path(os.environ.get("NESTED_CACHE", Path(tempfile.gettempdir()) / "aerotri_nested_cache"))
RESULT = REPO / "bench" / "results" / "classify_nested.json"

# Knobs of the morphological filter (physical meaning in lidarctl.classify.ground.MorphSettings) and rule
# switches: surface_height_m None = local-surface test off; refine_angle_deg 0 = TIN angle criterion
# off; plateau False = raised-plateau test off; sunken_max_area_m2 0 = sunken-patch test off (issue 44, third
# round: returns from below the ground left out of the opening, lidarctl.classify.ground.sunken_patches).
CONFIG_GRID = {
    "slope": (0.25, 0.3, 0.35),
    "elevation_scaler": (0.75, 1.0, 1.25),
    "surface_height_m": (None, 0.3, 0.5, 0.8),
    "refine_angle_deg": (0.0, 10.0, 20.0, 30.0),
    "plateau": (False, True),
    "sunken_max_area_m2": (0.0, 10.0, 40.0),
}


# Grid values admissible as a shipped default: those that move no other labelled set by more than 0.2 points
# (bench/eval_ground_sunken.py, bench/results/ground_sunken.json: sunken_max_area_m2 40 lowers AHN3's south-east
# ground PA by 0.20 points, small yards enclosed by roofs taken for sunken patches; 10 moves no set). Chosen on
# the other sets, not on ISPRS; the nested estimate over this grid is reported beside the full grid's.
ADMISSIBLE = {"sunken_max_area_m2": (0.0, 10.0)}


def config_key(cfg: dict) -> str:
    return json.dumps(cfg, sort_keys=True)


def _morph_overrides(cfg: dict) -> dict:
    o = {"slope": cfg["slope"], "elevation_scaler": cfg["elevation_scaler"],
         "refine_angle_deg": cfg["refine_angle_deg"], "sunken_max_area_m2": cfg["sunken_max_area_m2"]}
    if cfg["surface_height_m"] is None:
        o["surface_neighbours"] = 0
    else:
        o["surface_height_m"] = cfg["surface_height_m"]
    return o


def isprs_errors(configs: list[dict]) -> np.ndarray:
    """err[i, j]: total error (%) of configuration i on ISPRS sample j (cached per sample)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    err = np.full((len(configs), len(SAMPLES)), np.nan)
    f = ground.ground_filter_named("morph")
    for j, s in enumerate(SAMPLES):
        path = CACHE / f"isprs_{s}.json"
        cache = json.loads(path.read_text()) if path.exists() else {}
        todo = [cfg for cfg in configs if config_key(cfg) not in cache]
        if todo:
            c = io.read_cloud(DATA / "isprs_filtertest" / f"{s}-utm.laz")
            keep = noise.detect_noise(c.x, c.y, c.z) == 0
            truth = c.classification == 2
            x, y, z = c.x[keep], c.y[keep], c.z[keep]
            cell_m = max(1.0, 1.5 * grid.mean_spacing_m(x, y))
            done = {}
            for cfg in todo:
                base = {k: v for k, v in cfg.items() if k != "plateau"}
                bkey = config_key(base)
                if bkey not in done:   # the plateau test is a post-step: one filter run for both
                    params = f.params_for(None, **_morph_overrides(base))
                    g = np.zeros(len(c), bool)
                    g[keep] = f.run(x, y, z, params)
                    gp = g.copy()
                    if params.plateau_min_step_m > 0 and g[keep].sum() >= 10:
                        gi = np.flatnonzero(keep)[g[keep]]
                        gp[gi[ground.raised_plateaus(c.x[gi], c.y[gi], c.z[gi], cell_m, params.plateau_min_step_m,
                                                     params.plateau_max_area_m2)]] = False
                    done[bkey] = {False: evaluate.filter_errors(g, truth).total_error_pct,
                                  True: evaluate.filter_errors(gp, truth).total_error_pct}
                cache[config_key(cfg)] = done[bkey][cfg["plateau"]]
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(cache))
            tmp.replace(path)
            print(f"{s}: {len(done)} filter runs", flush=True)
        err[:, j] = [cache[config_key(cfg)] for cfg in configs]
    return err


# --- selection procedures: errors of the grid on training samples -> index of one configuration ---

def _neighbours(configs: list[dict], grid_def: dict) -> list[np.ndarray]:
    """Per configuration: indices of itself and the configurations one grid step away in one knob."""
    index = {config_key(c): i for i, c in enumerate(configs)}
    out = []
    for cfg in configs:
        nb = [index[config_key(cfg)]]
        for k, values in grid_def.items():
            if k not in cfg or cfg[k] not in values:
                continue
            p = list(values).index(cfg[k])
            for q in (p - 1, p + 1):
                if 0 <= q < len(values):
                    key = config_key({**cfg, k: values[q]})
                    if key in index:
                        nb.append(index[key])
        out.append(np.array(nb))
    return out


def make_selectors(configs, grid_def):
    nbs = _neighbours(configs, grid_def)

    def mean(e):
        return int(np.argmin(e.mean(axis=1)))

    def relative(e):   # every sample weighs the same however hard it is
        return int(np.argmin((e / np.maximum(e.min(axis=0), 1e-9)).mean(axis=1)))

    def rank(e):
        return int(np.argmin(np.argsort(np.argsort(e, axis=0), axis=0).mean(axis=1)))

    def smoothed(e):   # a flat minimum: the configuration and its one-step neighbours, averaged
        m = e.mean(axis=1)
        return int(np.argmin([m[nb].mean() for nb in nbs]))

    return {"mean": mean, "relative": relative, "rank": rank, "smoothed": smoothed}


def nested_cv(err: np.ndarray, selectors: dict) -> dict:
    """Outer leave-one-out with the selector chosen by an inner leave-one-out (see module doc)."""
    n = err.shape[1]
    folds = []
    for j in range(n):
        train = [k for k in range(n) if k != j]
        inner = {}
        for name, sel in selectors.items():
            sc = []
            for i in train:
                rest = [k for k in train if k != i]
                sc.append(err[sel(err[:, rest]), i])
            inner[name] = float(np.mean(sc))
        best = min(inner, key=lambda k: (inner[k], list(selectors).index(k)))
        chosen = selectors[best](err[:, train])
        folds.append({"held_out": j, "inner_loo_error_by_selector": inner, "selector": best,
                      "chosen": chosen, "held_out_error": float(err[chosen, j])})
    return {"folds": folds, "estimate": float(np.mean([f["held_out_error"] for f in folds]))}


def loo(err: np.ndarray, sel) -> dict:
    n = err.shape[1]
    chosen = [sel(err[:, [k for k in range(n) if k != j]]) for j in range(n)]
    scores = [float(err[i, j]) for j, i in enumerate(chosen)]
    return {"chosen": chosen, "scores": scores, "estimate": float(np.mean(scores))}


def run_isprs() -> dict:
    t0, load0 = time.perf_counter(), os.getloadavg()
    configs = grid_points(CONFIG_GRID)
    err = isprs_errors(configs)
    selectors = make_selectors(configs, CONFIG_GRID)
    nest = nested_cv(err, selectors)
    plain = loo(err, selectors["mean"])
    adm = [i for i, cfg in enumerate(configs) if all(cfg[k] in v for k, v in ADMISSIBLE.items())]
    adm_configs = [configs[i] for i in adm]
    nest_adm = nested_cv(err[adm], make_selectors(adm_configs, {**CONFIG_GRID, **ADMISSIBLE}))
    d = ground.MorphSettings()
    default = {"slope": d.slope, "elevation_scaler": d.elevation_scaler, "surface_height_m": d.surface_height_m,
               "refine_angle_deg": d.refine_angle_deg, "plateau": d.plateau_min_step_m > 0,
               "sunken_max_area_m2": d.sunken_max_area_m2}
    i_def = configs.index(default)
    best_all = int(np.argmin(err.mean(axis=1)))
    out = {
        "data": "ISPRS WG III/3 filter test, the 7 shared samples (../shared/data/isprs_filtertest)",
        "method": "noise flags, then lidarctl.classify.ground morphological filter + TIN refinement (+ raised-plateau "
                  "test), configuration from the grid",
        "grid": {k: list(v) for k, v in CONFIG_GRID.items()},
        "grid_note": "surface_height_m null: local-surface test off; refine_angle_deg 0: TIN angle criterion off; "
                     "plateau: raised-plateau test on/off",
        "n_configurations": len(configs),
        "selectors": {"mean": "lowest mean total error over the training samples",
                      "relative": "lowest mean of total error / the training sample's best total error",
                      "rank": "lowest mean rank over the training samples",
                      "smoothed": "lowest mean total error averaged with the one-step grid neighbours"},
        "nested": {
            "definition": "outer leave-one-sample-out; in each fold the selector is chosen by an inner "
                          "leave-one-out over the 6 training samples, it chooses the configuration on those 6, "
                          "the held-out sample is scored once",
            "estimate_total_error_pct": nest["estimate"],
            "folds": {SAMPLES[f["held_out"]]: {"selector": f["selector"],
                                                "inner_loo_error_by_selector_pct": f["inner_loo_error_by_selector"],
                                                "chosen": configs[f["chosen"]],
                                                "held_out_total_error_pct": f["held_out_error"]}
                      for f in nest["folds"]},
        },
        "nested_admissible_grid": {
            "definition": "the same nested procedure over the grid restricted to the values admissible as a default "
                          "(ADMISSIBLE: no other labelled set moved by more than 0.2 points)",
            "admissible": {k: list(v) for k, v in ADMISSIBLE.items()},
            "estimate_total_error_pct": nest_adm["estimate"],
            "folds": {SAMPLES[f["held_out"]]: {"selector": f["selector"], "chosen": adm_configs[f["chosen"]],
                                                "held_out_total_error_pct": f["held_out_error"]}
                      for f in nest_adm["folds"]},
        },
        "loo_mean_selector": {
            "definition": "configuration of lowest mean total error over the other 6 samples (the earlier "
                          "rounds' leave-one-out, on this grid)",
            "estimate_total_error_pct": plain["estimate"],
            "per_sample_pct": dict(zip(SAMPLES, plain["scores"])),
        },
        "loo_by_selector_pct": {name: loo(err, sel)["estimate"] for name, sel in selectors.items()},
        "shared_set_default": {"config": default, "mean_total_error_pct": float(err[i_def].mean()),
                               "per_sample_pct": dict(zip(SAMPLES, err[i_def].tolist())),
                               "note": "shipped defaults, chosen in earlier rounds on these 7 samples: in-sample"},
        "shared_set_best_on_all_7": {"config": configs[best_all], "mean_total_error_pct": float(err[best_all].mean())},
        "target_nested_max_pct": 3.3,
        "seconds": time.perf_counter() - t0,
        "load_average_before_after": [list(load0), list(os.getloadavg())],
    }
    out["target_met"] = bool(out["nested"]["estimate_total_error_pct"] <= 3.3)
    print(f"ISPRS: nested {nest['estimate']:.2f} % (admissible grid {nest_adm['estimate']:.2f} %), LOO (mean selector) {plain['estimate']:.2f} %, "
          f"defaults in-sample {err[i_def].mean():.2f} %, best on all 7 {err[best_all].mean():.2f} %")
    for s, f in out["nested"]["folds"].items():
        print(f"  {s}: selector {f['selector']}, {f['chosen']} -> {f['held_out_total_error_pct']:.2f} %")
    return out


def main():
    args = sys.argv[1:]
    parts = [a[2:] for a in args if a in ("--isprs", "--ahn3")] or ["isprs", "ahn3"]
    new = {}
    if "isprs" in parts:
        new["isprs"] = run_isprs()
    if "ahn3" in parts:
        from eval_classify_nested_ahn3 import run_ahn3
        new["ahn3"] = run_ahn3(CACHE, nested_cv, loo, make_selectors)
    # read just before writing: a run of the other part may have finished meanwhile
    out = json.loads(RESULT.read_text()) if RESULT.exists() else {}
    out.update(new)
    tmp = RESULT.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=2))
    tmp.replace(RESULT)
    print(f"wrote {RESULT}")


if __name__ == "__main__":
    main()
