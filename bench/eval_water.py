"""Water on the lidR Topography lakes, thresholds chosen on one half of the cloud and scored on the other
(issue 44), and the water rule's false alarms on the sets without labelled water -> bench/results/water.json.

Truth: the dataset's own classes (Topography.laz class 9, 3,897 returns; class 2 ground; class 1 holds
unlabelled ground, vegetation and shore). Lake outlines are not given: for the per-lake rows only, the water
returns are grouped into lakes by their 2 m cells grown by ``LAKE_REACH_M`` (lakes of at least 20 labelled
returns; the rest and everything farther from the water is "elsewhere").
Every pulse-returning lake surface is class 9, the dropout gaps (no returns) carry no points to score.

Choosing: the water settings of ``lidarctl.classify.pipeline`` on a grid (``GRID``: level patches joined across
a dropout gap ``level_water_across_dropouts`` (False: main's code), the level tolerance
``level_water_tol_m``, the smallest level body ``level_water_min_area_m2``). A grid point is admissible
when it calls no water on land on the sets without labelled water (``no_water_sets``: the 7 ISPRS samples,
laspy's Nebraska tile, lidR MixedConifer; Autzen: its land is outside the river outline digitised from its
orthophoto and a 3 m band around it, ``bench/eval_water_autzen.py``; until i44-water all of Autzen counted as
land, its river included; no labels of Topography are used for this). The bar is main's committed values
before i44-water (126fd31 ``bench/results/water.json``: no water on any of these sets at its admissible grid
points), judged with the rules the grid sets (the one-level rules: ``water_sloping_surface`` off, a rule not on
the grid). The sloping rule's own water on Autzen's land (the same at every grid point) is recorded beside it
(``autzen_land_water_with_sloping_rule``), not allowed for: i44-water had taken the grid's first point, computed
with the new rule, as the bar, which made Autzen's 80 land returns an allowance. Each run
classifies the whole Topography cloud (no labels are used by the classification); it is scored per half.
Halves: the cloud's extent cut at its centre, west/east and south/north. On each half the admissible
grid point with the largest min(PA, UA) is chosen (ties: the earlier grid point, main's values first),
and scored on the other half; both directions of both cuts; per cut also the whole cloud with each
half classified by the settings chosen on the other ("cross-validated"). The same procedure on the
whole cloud (``procedure_on_whole_cloud``) is reported beside the shipped defaults (``defaults``).
Then the shipped defaults on the whole cloud, per lake, and the AHN3 Delft crop's water (class 9).

The demo's four LiDAR strips (``--demo``, 4.9 M simulated returns, a scene with ponds, no classes in the
strips): water returns with the shipped defaults and with the join off (or main's, ``--demo-classes``).

    nice -n 10 .venv/bin/python bench/eval_water.py [--jobs N] [--demo /work/ref/demo_chain/project/lidar | --demo-classes WORK]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.classify import pipeline as classify

# Main's values first in each list: ties go to them.
GRID = {"level_water_across_dropouts": (False, True),
        "level_water_tol_m": (0.05, 0.03, 0.08),
        "level_water_min_area_m2": (200.0, 100.0, 400.0)}
CANOPY_RADIUS_M, CANOPY_HEIGHT_M = 2.0, 2.0   # as bench/eval_false_classes.py
LAKE_REACH_M = 10.0   # per-lake rows: the points within this of a lake's labelled water (cells of 2 m)


def grid_points() -> list[dict]:
    return [dict(zip(GRID, v)) for v in itertools.product(*GRID.values())]


def scores(pred_water: np.ndarray, truth_water: np.ndarray, truth_ground: np.ndarray, mask: np.ndarray) -> dict:
    pw, tw = pred_water & mask, truth_water & mask
    return {"truth_water": int(tw.sum()), "found": int(np.sum(pw & tw)), "called_water": int(pw.sum()),
            "pa_pct": 100.0 * float(np.mean(pred_water[tw])) if tw.any() else None,
            "ua_pct": 100.0 * float(np.mean(truth_water[pw])) if pw.any() else None,
            "truth_ground_called_water": int(np.sum(pw & truth_ground))}


def objective(s: dict) -> float:
    return min(s["pa_pct"] or 0.0, s["ua_pct"] or 0.0)


def lakes(c, truth_water) -> np.ndarray:
    """Lake number of every point (0: none): the 2 m cells holding truth-water returns grown by
    ``LAKE_REACH_M`` and labelled 8-connected (a lake, its shore and its returns across a dropout gap)."""
    cell = 2.0
    ix = ((c.x - c.x.min()) // cell).astype(int)
    iy = ((c.y - c.y.min()) // cell).astype(int)
    occ = np.zeros((iy.max() + 1, ix.max() + 1), bool)
    occ[iy[truth_water], ix[truth_water]] = True
    grown = ndimage.binary_dilation(occ, np.ones((3, 3), bool), int(LAKE_REACH_M / cell))
    lab, _ = ndimage.label(grown, np.ones((3, 3), int))
    return lab[iy, ix]


def under_canopy(c, idx) -> np.ndarray:
    tree = cKDTree(np.column_stack([c.x, c.y]))
    near = tree.query_ball_point(np.column_stack([c.x[idx], c.y[idx]]), CANOPY_RADIUS_M)
    return np.array([np.max(c.z[nb]) - c.z[i] > CANOPY_HEIGHT_M for nb, i in zip(near, idx)], bool)


def classify_cloud(c, **kw) -> np.ndarray:
    p = classify.ClassifySettings(**kw)
    return classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity, params=p)


def pooled(a: dict, b: dict) -> dict:
    """Scores of two disjoint parts together."""
    f, t, cw = a["found"] + b["found"], a["truth_water"] + b["truth_water"], a["called_water"] + b["called_water"]
    return {"truth_water": t, "found": f, "called_water": cw, "pa_pct": 100.0 * f / t if t else None,
            "ua_pct": 100.0 * f / cw if cw else None,
            "truth_ground_called_water": a["truth_ground_called_water"] + b["truth_ground_called_water"]}


def _topography_water(gp: dict) -> np.ndarray:
    c = io.read_cloud(DATA / "lidr_topography" / "Topography.laz")
    return classify_cloud(c, **gp) == classify.WATER


def topography(admissible: list[bool], jobs: int) -> dict:
    c = io.read_cloud(DATA / "lidr_topography" / "Topography.laz")
    truth = c.classification
    tw, tg = truth == classify.WATER, truth == classify.GROUND
    xm, ym = 0.5 * (c.x.min() + c.x.max()), 0.5 * (c.y.min() + c.y.max())
    halves = {"west": c.x < xm, "east": c.x >= xm, "south": c.y < ym, "north": c.y >= ym}
    if jobs > 1:
        with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
            preds = list(pool.map(_topography_water, grid_points()))
    else:
        preds = [_topography_water(gp) for gp in grid_points()]
    runs = []
    for gp, pw in zip(grid_points(), preds):
        runs.append({"settings": gp, **{h: scores(pw, tw, tg, m) for h, m in halves.items()}})
        print(gp, {h: (round(runs[-1][h]["pa_pct"], 1), round(runs[-1][h]["ua_pct"] or 0, 1)) for h in halves})
    ok = [i for i in range(len(runs)) if admissible[i]]

    def choose_on(part) -> int:
        return max(ok, key=lambda i: (objective(part(runs[i])), -i))

    folds, chosen = [], {}
    for choose, score in (("west", "east"), ("east", "west"), ("south", "north"), ("north", "south")):
        best = chosen[choose] = choose_on(lambda r: r[choose])
        folds.append({"chosen_on": choose, "scored_on": score, "settings": runs[best]["settings"],
                      "choosing_half": runs[best][choose], "held_out_half": runs[best][score]})
    cross_validated = {f"{a}/{b}": pooled(runs[chosen[b]][a], runs[chosen[a]][b])
                       for a, b in (("west", "east"), ("south", "north"))}
    whole = choose_on(lambda r: pooled(r["west"], r["east"]))
    defaults = classify.ClassifySettings()
    pred = classify_cloud(c)
    pw = pred == classify.WATER
    lake = lakes(c, tw)
    per_lake = {}
    for k in np.unique(lake[tw]):
        m = lake == k
        if np.sum(tw & m) < 20:
            continue   # a few returns of a brook: counted in "elsewhere" below
        s = scores(pw, tw, tg, m)
        s["level_m"] = round(float(np.median(c.z[tw & m])), 3)
        s["centre_m"] = [round(float(np.mean(c.x[tw & m])), 1), round(float(np.mean(c.y[tw & m])), 1)]
        per_lake[str(int(k))] = s
    rest = ~np.isin(lake, [int(k) for k in per_lake])
    per_lake["elsewhere"] = scores(pw, tw, tg, rest)
    false = np.flatnonzero(tg & pw)
    canopy = under_canopy(c, false) if len(false) else np.zeros(0, bool)
    off = classify_cloud(c, level_water_across_dropouts=False) == classify.WATER
    # Truth ground called water: how far from the labelled water, how far from its level (the median of
    # the labelled water within 30 m): shore returns at the water level, or not.
    wtree = cKDTree(np.column_stack([c.x[tw], c.y[tw]]))
    d_m, _ = wtree.query(np.column_stack([c.x[false], c.y[false]]))
    lvl = np.array([np.median(c.z[tw][nb]) if nb else np.nan
                    for nb in wtree.query_ball_point(np.column_stack([c.x[false], c.y[false]]), 30.0)])
    false_ground = {"distance_to_truth_water_m": dict(zip(("median", "p90", "max"), np.round(
                        np.percentile(d_m, [50, 90, 100]), 2).tolist())),
                    "height_from_water_level_m": dict(zip(("median", "p90", "max"), np.round(
                        np.nanpercentile(np.abs(c.z[false] - lvl), [50, 90, 100]), 3).tolist()))} if len(false) else {}
    return {"truth": "Topography.laz class 9 (the dataset's own classes); halves cut at the extent's centre "
                     f"x {xm:.1f}, y {ym:.1f} (EPSG:2949 metres)",
            "grid": GRID, "objective": "min(PA, UA) on the choosing half",
            "admissible": "no water on land on the sets without labelled water (no_water_sets; Autzen: outside "
                          "its river outline and a 3 m band), main's committed values before i44-water (126fd31), "
                          "with the grid's one-level rules (water_sloping_surface off)",
            "runs": runs, "folds": folds,
            "cross_validated_whole_cloud": cross_validated,
            "procedure_on_whole_cloud": {"settings": runs[whole]["settings"],
                                         "whole_cloud": pooled(runs[whole]["west"], runs[whole]["east"])},
            "defaults": {k: getattr(defaults, k) for k in GRID},
            "defaults_whole_cloud": scores(pw, tw, tg, np.ones(len(c), bool)),
            "defaults_truth_ground_called_water_under_canopy": int(canopy.sum()),
            "defaults_per_lake": per_lake,
            "defaults_truth_ground_called_water": false_ground,
            "rule_off_whole_cloud": scores(off, tw, tg, np.ones(len(c), bool)),
            "predicted_classes_of_truth_water": {str(k): int(v) for k, v in
                                                 zip(*np.unique(pred[tw], return_counts=True))}}


def read(name: str, paths) -> object:
    # AHN3's file has no CRS record (EPSG:28992 given, as bench/eval_ahn3.py does)
    clouds = [io.read_cloud(p, crs="EPSG:28992" if name == "ahn3_delft" else None) for p in paths]
    f = ("x", "y", "z", "return_number", "number_of_returns", "intensity", "classification")
    return type("Cloud", (), {k: np.concatenate([np.asarray(getattr(c, k)) for c in clouds]) for k in f})


def no_water_sets() -> dict:
    sets = {f"isprs_{s}": (DATA / "isprs_filtertest" / f"{s}-utm.laz",) for s in SAMPLES}
    sets.update({"autzen": (DATA / "autzen" / "autzen_trim.laz",),
                 "laspy_nebraska": (DATA / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las",),
                 "lidr_mixedconifer": (DATA / "lidr_mixedconifer" / "MixedConifer.laz",)})
    out = {name: read(name, paths) for name, paths in sets.items() if all(p.is_file() for p in paths)}
    if "autzen" in out:
        import laspy
        from matplotlib.path import Path as MplPath

        from eval_water_autzen import BAND_M, distance_to_outline, outline_ft

        las = laspy.read(sets["autzen"][0])
        fx, fy = np.asarray(las.x), np.asarray(las.y)
        poly = outline_ft()
        river = MplPath(poly).contains_points(np.column_stack([fx, fy]))
        out["autzen"].land = ~river & (distance_to_outline(fx, fy, poly) * 0.3048 > BAND_M)
    return out


_CLOUDS: dict = {}


def _no_water_one(gp: dict) -> dict:
    per = {}
    for name, c in _CLOUDS.items():
        pw = classify_cloud(c, **gp, water_sloping_surface=False) == classify.WATER
        pw &= getattr(c, "land", True)
        per[name] = [int(pw.sum()), int(np.sum(pw & (c.classification == classify.GROUND)))]
    out = {"settings": gp, "water_and_truth_ground_as_water": per}
    if "autzen" in _CLOUDS:
        c = _CLOUDS["autzen"]
        pw = (classify_cloud(c, **gp) == classify.WATER) & c.land
        out["autzen_land_water_with_sloping_rule"] = [int(pw.sum()),
                                                      int(np.sum(pw & (c.classification == classify.GROUND)))]
    return out


def _load_no_water_sets():
    _CLOUDS.update(no_water_sets())


def water_on_no_water_sets(jobs: int) -> list[dict]:
    """Per grid point: returns called water, and truth ground among them, on each set without labelled
    water (``jobs`` processes)."""
    if jobs > 1:
        with ProcessPoolExecutor(jobs, mp_context=get_context("spawn"), initializer=_load_no_water_sets) as pool:
            out = list(pool.map(_no_water_one, grid_points()))
    else:
        _load_no_water_sets()
        out = [_no_water_one(gp) for gp in grid_points()]
    # main's committed values before i44-water (126fd31): no water on any of these sets
    for r in out:
        r["admissible"] = not any(v[0] for v in r["water_and_truth_ground_as_water"].values())
    for r in out:
        print("no-water sets", r["settings"], {k: v for k, v in r["water_and_truth_ground_as_water"].items()
                                                if v[0]} or "none")
    return out


def ahn3() -> dict:
    path = DATA / "ahn3_delft" / "ahn3_cropped_1.laz"
    if not path.is_file():
        return {}
    c = read("ahn3_delft", (path,))
    t = c.classification
    pred, off = classify_cloud(c), classify_cloud(c, level_water_across_dropouts=False)
    all_ = np.ones(len(t), bool)
    return {"defaults": scores(pred == classify.WATER, t == classify.WATER, t == classify.GROUND, all_),
            "join_off": scores(off == classify.WATER, t == classify.WATER, t == classify.GROUND, all_),
            "classes_changed_by_the_join": int(np.sum(pred != off))}


def demo(folder: Path) -> dict:
    c = read("demo", tuple(sorted(folder.glob("*.las"))))
    pred, off = classify_cloud(c), classify_cloud(c, level_water_across_dropouts=False)
    return {"points": len(c.x), "water": int(np.sum(pred == classify.WATER)),
            "water_join_off": int(np.sum(off == classify.WATER)),
            "classes_changed_by_the_join": int(np.sum(pred != off)),
            "truth": "none in the strips (all class 1); the simulated scene has ponds (docs/simulator.md)"}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, default=None, help="folder of the demo's LiDAR strips")
    ap.add_argument("--jobs", type=int, default=1, help="processes for the grid runs")
    ap.add_argument("--demo-classes", type=Path, default=None, help="instead: the --work folder of "
                    "bench/classify_speed.py --only demo (its classes of the demo, main's and this tree's)")
    args = ap.parse_args()
    t0, load0 = time.perf_counter(), os.getloadavg()
    dest = REPO / "bench" / "results" / "water.json"
    old = json.loads(dest.read_text()) if dest.is_file() else {}
    out = {}
    sweep = water_on_no_water_sets(args.jobs)
    out["no_water_sets"] = sweep
    out["lidr_topography"] = topo = topography([r["admissible"] for r in sweep], args.jobs)
    for f in topo["folds"]:
        print(f"chosen on {f['chosen_on']}: {f['settings']} -> {f['scored_on']} PA {f['held_out_half']['pa_pct']:.1f} "
              f"UA {f['held_out_half']['ua_pct']:.1f} (choosing half {objective(f['choosing_half']):.1f})")
    for cut, r in topo["cross_validated_whole_cloud"].items():
        print(f"cross-validated ({cut}): PA {r['pa_pct']:.1f} UA {r['ua_pct']:.1f}")
    print("procedure on the whole cloud:", topo["procedure_on_whole_cloud"]["settings"], "; shipped:", topo["defaults"])
    print("defaults, whole cloud:", topo["defaults_whole_cloud"])
    out["ahn3_delft"] = ahn3()
    print("ahn3:", out["ahn3_delft"])
    if args.demo is not None:
        out["demo"] = demo(args.demo)
        print("demo:", out["demo"])
    elif args.demo_classes is not None and not all((args.demo_classes / f"classes_demo_{v}.npz").is_file()
                                                   for v in ("before", "after")):
        print(f"demo: no classes_demo_before/after.npz in {args.demo_classes}, skipped")
    elif args.demo_classes is not None:
        # bench/classify_speed.py's classes of the demo, main's code (before) and this tree's (after)
        cls = {v: np.load(args.demo_classes / f"classes_demo_{v}.npz")["demo"] for v in ("before", "after")}
        out["demo"] = {"points": len(cls["after"]), "water": int(np.sum(cls["after"] == classify.WATER)),
                       "water_main": int(np.sum(cls["before"] == classify.WATER)),
                       "classes_changed": int(np.sum(cls["after"] != cls["before"])),
                       "source": "bench/classify_speed.py --only demo (classes_demo_before/after.npz)",
                       "truth": "none in the strips (all class 1); the simulated scene has ponds (docs/simulator.md)"}
        print("demo:", out["demo"])
    elif "demo" in old:
        out["demo"] = {**old["demo"], "kept_from": "an earlier run (no --demo / --demo-classes given); this "
                       "branch's demo classes: bench/results/water_sloping.json"} if "kept_from" not in old["demo"] \
            else old["demo"]
    out["seconds"] = time.perf_counter() - t0
    out["load_average_before_after"] = [list(load0), list(os.getloadavg())]
    tmp = dest.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=2))
    tmp.replace(dest)
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
