"""Surface control with tie points on vegetation and moving objects: rejected share by class, height bias.

A geometric block (GNSS with per-strip height shifts of 0.5 m sigma, plan unbiased, no control points)
whose tie points are ground points (on the DEM), points on tree crowns and hedges (2-20 m above the
DEM, consistent in every frame) and points on moving cars (3-15 m between exposures, so their rays do
not meet), about 10 % of the points each (aerotri.sim.clutter). The DEM is the block's terrain at 2 m
cells (sigma 0.15 m); the nDSM holds the crowns. Adjusted (production path: adjust_project, robust
rounds with Huber, gate, data snooping) as:

  clean_none       ground ties only, no DEM (what the GNSS alone gives)
  clean_dem        ground ties only, DEM (the reference)
  dirty_none       all ties, no DEM
  dirty_dem_ndsm   all ties, DEM and nDSM (trees flagged by the nDSM)
  dirty_dem        all ties, DEM only (the worst case: the gate and Huber do all the work)

Per class: points and observations, share of points used as surface observation, gated, not
candidates (nDSM), share of observations removed by data snooping, share of points left out of the
adjustment (fewer than two rays left). Results: check points (surveyed, not in the adjustment) height
mean / RMS and plan RMS, the ground tie points against their truth, camera centres against the truth,
and the dirty runs against the clean one (same ground observations: what the clutter moved).
Writes bench/results/surface_robust.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.core.records import to_record
from aerotri.sim.clutter import CLASSES, write_clutter_projects
from aerotri.sim.observations import geometric_block

SIGMA_PX = 0.3
VARIANTS = {  # name: (ties, dem, ndsm)
    "clean_none": ("clean", False, False),
    "clean_dem": ("clean", True, False),
    "dirty_none": ("dirty", False, False),
    "dirty_dem_ndsm": ("dirty", True, True),
    "dirty_dem": ("dirty", True, False),
}


def make_case(tmp: Path, seed: int, strips: int, frames: int, points_per_image: int):
    """The block and its two projects (clean: ground ties only; dirty: all) with the same check points, DEM
    and nDSM; returns (block, ties, {"clean": root, "dirty": root})."""
    block = geometric_block(strips, frames, seed=seed, gnss_shift_sigma_m=0.5, gnss_drift_sigma_m_per_km=0.0)
    block.gnss_local[:, :2] -= block.gnss_shift_m[block.strip, :2]  # heights shifted per strip, plan unbiased
    block.gnss_shift_m[:, :2] = 0.0
    ties, clean, dirty = write_clutter_projects(block, tmp / f"s{seed}", points_per_image=points_per_image,
                                                sigma_px=SIGMA_PX, seed=seed + 1000)
    return block, ties, {"clean": clean, "dirty": dirty}


def run_variant(ties, roots, variant: str):
    return _run(ties, roots, *VARIANTS[variant])


def _run(ties, roots, which, dem, ndsm):
    root = roots[which]
    st = AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, point_covariances=False,
                        dem=root / "dem.tif" if dem else None, ndsm=root / "ndsm.tif" if ndsm else None)
    t0 = time.perf_counter()
    ba = adjust_project(root, st)
    return ba, time.perf_counter() - t0


def _stats(d: np.ndarray) -> dict:
    d = d[np.isfinite(d)]
    return {"n": len(d), "mean_m": float(np.mean(d)), "rms_m": float(np.sqrt(np.mean(d * d)))} if len(d) else {"n": 0}


def by_class(ba, ties) -> dict:
    """Per class: what the adjustment did with the points and their observations."""
    blk, res = ba.block, ba.result
    cls_pt = np.array([ties.point_class.get(p, "control") for p in blk.point_id])
    cls_obs = cls_pt[blk.obs_point]
    snooped = np.zeros(len(blk.obs_point), dtype=bool)
    snooped[[r.obs for r in res.removed]] = True
    rays = np.bincount(blk.obs_point[res.obs_active], minlength=blk.n_points)
    use = res.surface_use if res.surface_use is not None else np.zeros(blk.n_points, dtype=np.int8)
    # adjust_block tests the nDSM once, at the approximate points (metres off in plan): the same test at the
    # adjusted points says how many the nDSM would flag
    flagged = None
    if blk.surface is not None and blk.surface.ndsm is not None:
        flagged = ~blk.surface.candidates(res.state.points)
    out = {}
    for c in CLASSES:
        p, o = cls_pt == c, cls_obs == c
        n_p, n_o = int(p.sum()), int(o.sum())
        # a point whose rays were all removed keeps surface_use 1 (the gate passes a point without rays):
        # used means an observation that acts, on a point still in the solution
        inside = rays[p] >= 2
        out[c] = {
            "points": n_p, "observations": n_o,
            "share_surface_used": float(((use[p] == 1) & inside).mean()) if n_p else None,
            "share_surface_gated": float((use[p] == 2).mean()) if n_p else None,
            "share_not_candidate": float((use[p] == 0).mean()) if n_p else None,
            "share_observations_snooped": float(snooped[o].mean()) if n_o else None,
            "share_observations_inactive": float((~res.obs_active[o]).mean()) if n_o else None,
            "share_points_left_out": float((~inside).mean()) if n_p else None,
            "share_points_in_solution": float(inside.mean()) if n_p else None,
        }
        if flagged is not None:
            out[c]["share_ndsm_flagged_at_adjusted_points"] = float(flagged[p].mean()) if n_p else None
    return out


def accuracy(ba, block, ties) -> dict:
    chk = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values()])
    sig = np.array([c["sigma_m"] for c in ba.check.values()])
    eo_t = block.eo_map()
    idx = [eo_t.image_id.index(i) for i in ba.eo_map.image_id]
    dc = ba.eo_map.centre_m - eo_t.centre_m[idx]
    ids = np.array([p for p in ba.block.point_id if p in ties.ground_truth_local])
    row = {p: j for j, p in enumerate(ba.block.point_id)}
    truth = block.frame.to_map(np.array([ties.ground_truth_local[p] for p in ids]))
    dg = ba.points_map[[row[p] for p in ids]] - truth
    return {
        "check_points": {"height": _stats(chk[:, 2]), "plan_rms_m": float(np.sqrt(np.nanmean(np.sum(chk[:, :2] ** 2, 1)))),
                         "median_sigma_height_m": float(np.nanmedian(sig[:, 2]))},
        "ground_tie_points_height": _stats(dg[:, 2]),
        "centres": {"rms_xyz_m": [float(v) for v in np.sqrt(np.mean(dc**2, 0))], "mean_dz_m": float(dc[:, 2].mean())},
        "sigma0": float(ba.result.sigma0),
    }


def against_clean(ba, clean) -> dict:
    """The same ground tie points and centres of two runs of the same block: what the clutter moved."""
    row = {p: j for j, p in enumerate(clean.block.point_id)}
    ids = [p for p in ba.block.point_id if p in row and str(p).startswith("g")]
    mine = {p: j for j, p in enumerate(ba.block.point_id)}
    d = ba.points_map[[mine[p] for p in ids]] - clean.points_map[[row[p] for p in ids]]
    dc = ba.eo_map.centre_m - clean.eo_map.centre_m
    ch = np.array([np.subtract(ba.check[k]["adjusted_m"], clean.check[k]["adjusted_m"]) for k in ba.check])
    # "small": the clean run's check heights fix their own mean to its standard error, RMS / sqrt(n)
    c = np.array([np.subtract(v["adjusted_m"], v["measured_m"])[2] for v in clean.check.values()])
    c = c[np.isfinite(c)]
    bound = float(np.sqrt(np.mean(c * c) / len(c)))
    return {"bound_check_mean_standard_error_m": bound,
            "ground_tie_points_dz": _stats(d[:, 2]), "check_points_dz": _stats(ch[:, 2]),
            "centres_dz": _stats(dc[:, 2]), "centres_rms_dxy_m": float(np.sqrt(np.mean(np.sum(dc[:, :2] ** 2, 1))))}


def run_seed(tmp: Path, seed: int, strips: int, frames: int, points_per_image: int, variants=tuple(VARIANTS)) -> dict:
    t0 = time.perf_counter()
    block, ties, roots = make_case(tmp, seed, strips, frames, points_per_image)
    out = {"seed": seed, "images": len(block.image_id), "counts": to_record(ties.counts()), "gnss_height_shift_m":
           [float(v) for v in block.gnss_shift_m[:, 2]], "simulate_s": time.perf_counter() - t0, "variants": {}}
    runs = {}
    for v in variants:
        ba, secs = run_variant(ties, roots, v)
        runs[v] = ba
        r = {"adjust_s": secs, **accuracy(ba, block, ties), "classes": by_class(ba, ties)}
        if ba.result.surface is not None:
            r["surface"] = dataclasses.asdict(ba.result.surface)
        if v.startswith("dirty") and "clean_dem" in runs and v != "dirty_none":
            r["against_clean_dem"] = against_clean(ba, runs["clean_dem"])
        if v == "dirty_none" and "clean_none" in runs:
            r["against_clean_none"] = against_clean(ba, runs["clean_none"])
        out["variants"][v] = r
        c = r["check_points"]["height"]
        print(f"seed {seed} {v:15s} {secs:5.1f} s  check dz mean {c['mean_m']:+.3f} rms {c['rms_m']:.3f} m  "
              f"ground ties dz mean {r['ground_tie_points_height']['mean_m']:+.3f}  "
              + "  ".join(f"{k}: used {r['classes'][k]['share_surface_used']:.2f} gated {r['classes'][k]['share_surface_gated']:.2f}"
                          f" snooped {r['classes'][k]['share_observations_snooped']:.2f} out {r['classes'][k]['share_points_left_out']:.2f}" for k in CLASSES
                          if r["classes"][k]["points"]), flush=True)
    return out


def _summary(seeds: list) -> dict:
    """mean / min / max over the seeds of the numbers that matter."""
    def agg(vals):
        vals = [v for v in vals if v is not None]
        return {"mean": float(np.mean(vals)), "min": float(np.min(vals)), "max": float(np.max(vals))} if vals else None

    out = {}
    for v in VARIANTS:
        rs = [s["variants"][v] for s in seeds if v in s["variants"]]
        if not rs:
            continue
        o = {"check_height_mean_m": agg([r["check_points"]["height"]["mean_m"] for r in rs]),
             "check_height_rms_m": agg([r["check_points"]["height"]["rms_m"] for r in rs]),
             "check_plan_rms_m": agg([r["check_points"]["plan_rms_m"] for r in rs]),
             "check_median_sigma_height_m": agg([r["check_points"]["median_sigma_height_m"] for r in rs]),
             "ground_ties_height_mean_m": agg([r["ground_tie_points_height"]["mean_m"] for r in rs]),
             "ground_ties_height_rms_m": agg([r["ground_tie_points_height"]["rms_m"] for r in rs]),
             "centres_mean_dz_m": agg([r["centres"]["mean_dz_m"] for r in rs]),
             "centres_rms_z_m": agg([r["centres"]["rms_xyz_m"][2] for r in rs]),
             "adjust_s": agg([r["adjust_s"] for r in rs])}
        for c in CLASSES:
            if rs[0]["classes"][c]["points"]:
                o[c] = {k: agg([r["classes"][c][k] for r in rs]) for k in rs[0]["classes"][c] if k.startswith("share")}
        for key in ("against_clean_dem", "against_clean_none"):
            if key in rs[0]:
                o[key] = {"bound_check_mean_standard_error_m": agg([r[key]["bound_check_mean_standard_error_m"] for r in rs]),
                          "ground_ties_dz_mean_m": agg([r[key]["ground_tie_points_dz"]["mean_m"] for r in rs]),
                          "ground_ties_dz_rms_m": agg([r[key]["ground_tie_points_dz"]["rms_m"] for r in rs]),
                          "check_dz_mean_m": agg([r[key]["check_points_dz"]["mean_m"] for r in rs]),
                          "centres_dz_mean_m": agg([r[key]["centres_dz"]["mean_m"] for r in rs])}
                # small: on every seed the check heights' mean moved less than the clean mean's standard error
                o[key]["bias_small"] = all(abs(r[key]["check_points_dz"]["mean_m"]) < r[key]["bound_check_mean_standard_error_m"]
                                           and abs(r[key]["ground_tie_points_dz"]["mean_m"]) < r[key]["bound_check_mean_standard_error_m"]
                                           for r in rs)
        out[v] = o
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13])
    ap.add_argument("--strips", type=int, default=4)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--points-per-image", type=int, default=200)
    ap.add_argument("--out", type=Path, default=Path("bench/results/surface_robust.json"))
    a = ap.parse_args(argv)
    seeds = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in a.seeds:
            seeds.append(run_seed(Path(tmp), s, a.strips, a.frames, a.points_per_image))
    res = {"block": {"strips": a.strips, "frames": a.frames, "points_per_image": a.points_per_image, "sigma_px": SIGMA_PX,
                     "gnss": "per-strip height shift 0.5 m sigma, plan unbiased, no control points",
                     "dem": "the terrain at 2 m cells, sigma 0.15 m; nDSM: the tree crowns",
                     "vegetation": "crown domes 3-8 m radius, 3.5-20 m tall (a third in hedgerows), points within 0.8 "
                                   "radius: 2-20 m above the DEM",
                     "moving": "cars 0.3-1.6 m above the ground moving 3-15 m between exposures, matched within one strip "
                               "(>= 2 rays)"},
           "variants": {k: {"ties": t, "dem": d, "ndsm": n} for k, (t, d, n) in VARIANTS.items()},
           "definitions": {
               "share_surface_used": "points with a surface observation in the final solve and >= 2 active rays (the "
                                     "result's surface_use == 1 also marks points whose rays were all removed: the gate "
                                     "passes a point without rays, and SurfaceStats.used/rms_m count them)",
               "share_surface_gated": "candidates the rays-only gate rejected (surface_use == 2)",
               "share_not_candidate": "no surface observation from the start: outside the DEM or, with the nDSM, above "
                                      "max_ndsm_m at the approximate point (surface_use == 0)",
               "share_observations_snooped": "image observations removed by data snooping (result.removed)",
               "share_points_left_out": "points with fewer than 2 active rays at the end (snooped rays, then dropped)",
               "against_clean_dem": "the same ground tie points, check points and centres of the dirty run minus the "
                                    "clean run with the DEM; small = |mean| below bound_check_mean_standard_error_m, "
                                    "the clean run's check-height RMS / sqrt(n)"},
           "summary": _summary(seeds), "seeds": seeds, "load_average_1min": os.getloadavg()[0]}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res["summary"], indent=1))


if __name__ == "__main__":
    main()
