"""No regression from the fourth round's building rule (roofs under crowns, ``crown_covered_roofs``): every
labelled and simulated cloud classified with the shipped defaults and with the rule off, in one process.

Per cloud: the returns whose class differs (from -> to counts) and, where the cloud has labels, what they
are. AHN3 Delft: building and ground PA / UA per point against AHN3's classes per quarter (the reported
per-point figure, scoring of bench/eval_ahn3_holdout.py); lidR Topography: water PA / UA against its class 9
(bench/eval_water.py's truth). The rule runs after the ground filter and needs return numbers: the 7 ISPRS
samples (single returns) must not change, so their nested estimate (bench/eval_classify_nested.py) stands.
The vectors' roof dropouts (``MapVectorSettings.roof_dropouts``) change no class.

Writes bench/results/buildings_bgt_regression.json. Run:
    nice .venv/bin/python bench/eval_buildings_bgt_regress.py [--tiny WORKDIR] [--demo LIDAR_DIR]
``--tiny``: ``aerotri sim --preset tiny`` is simulated into WORKDIR (when not there) and its strips classified;
``--demo``: the demo chain's strips (e.g. /work/ref/demo_chain/project/lidar), each classified alone (demo_<stem>);
``--only demo_strip_01,sim_tiny``: those clouds only, merged into the existing JSON.
``--pair WITH WITHOUT``: two rule sets of bench/eval_buildings_bgt.py's RULE_SETS in place of the defaults and the
crowns rule off (fifth round: a set with the roof edge completion's stop and the same set without it), written
under the key "pair: WITH" (in the per-point keys "defaults" is WITH, "rule_off" WITHOUT); a name ending in
" + dropout rims" is that set with ``ClassifySettings.dropout_roof_rims`` on (eighth round).
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
from eval_ahn3_holdout import part_of, scores, PARTS  # noqa: E402
from results_json import store_result  # noqa: E402

from lidarctl import io  # noqa: E402
from lidarctl.classify import pipeline as classify  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
RULE = {"crown_covered_roofs": False}
RIMS_SUFFIX = " + dropout rims"


def _read(paths, crs=None) -> dict:
    read = [io.read_cloud(p, crs=crs) for p in paths]
    f = ("x", "y", "z", "return_number", "number_of_returns", "intensity", "classification")
    c = {k: np.concatenate([np.asarray(getattr(r, k)) for r in read]) for k in f}
    c["return_number"], c["number_of_returns"] = io.sanitize_returns(c["return_number"], c["number_of_returns"])
    return c


def compare(c: dict, on_params=None, off_params=None) -> tuple[dict, np.ndarray, np.ndarray]:
    """(figures, classes with ``on_params`` (the defaults), classes with ``off_params`` (the rule off)) of one cloud."""
    args = (c["x"], c["y"], c["z"], c["return_number"], c["number_of_returns"], c["intensity"])
    t0 = time.process_time()
    on = classify.classify_points(*args, params=on_params or classify.ClassifySettings())
    cpu_on = time.process_time() - t0
    t0 = time.process_time()
    off = classify.classify_points(*args, params=off_params or dataclasses.replace(classify.ClassifySettings(), **RULE))
    cpu_off = time.process_time() - t0
    ch = on != off
    pairs, n = np.unique(off[ch].astype(int) * 100 + on[ch], return_counts=True)
    out = {"points": int(len(on)), "multi_return_points": int(np.sum(c["number_of_returns"] > 1)),
           "changed": int(ch.sum()),
           "changed_from_to": {f"{p // 100}->{p % 100}": int(k) for p, k in zip(pairs, n)},
           "classify_cpu_s_defaults_rule_off": [round(cpu_on, 2), round(cpu_off, 2)]}
    if ch.any() and "labels" in c:
        u, k = np.unique(c["labels"][ch], return_counts=True)
        out["changed_by_label"] = {str(int(a)): int(b) for a, b in zip(u, k)}
    return out, on, off


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    t0, load0 = time.perf_counter(), os.getloadavg()
    clouds = {f"isprs_{s}": ([SHARED / "isprs_filtertest" / f"{s}-utm.laz"], None, True)
              for s in ("samp11", "samp21", "samp31", "samp41", "samp51", "samp61", "samp71")}
    clouds.update({
        "ahn3_delft": ([SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"], "EPSG:28992", True),
        "lidr_topography": ([SHARED / "lidr_topography" / "Topography.laz"], None, True),
        "lidr_mixedconifer": ([SHARED / "lidr_mixedconifer" / "MixedConifer.laz"], None, True),
        "autzen": ([SHARED / "autzen" / "autzen_trim.laz"], None, True),
        "laspy_nebraska": ([SHARED / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las"], None, False)})
    if "--tiny" in argv:
        from aerotri.sim import load_preset, simulate

        sim = Path(argv[argv.index("--tiny") + 1])
        if not (sim / "lidar").exists():
            simulate(load_preset("tiny"), sim)
        clouds["sim_tiny"] = (sorted((sim / "lidar").glob("*.la[sz]")), None, False)
    if "--demo" in argv:
        # strip by strip (one process holds one strip, as a tile of the chain)
        for f in sorted(Path(argv[argv.index("--demo") + 1]).glob("*.la[sz]")):
            clouds[f"demo_{f.stem}"] = ([f], None, False)
    out = REPO / "bench" / "results" / "buildings_bgt_regression.json"
    result = {"command": "bench/eval_buildings_bgt_regress.py " + " ".join(argv), "rule_off": RULE, "clouds": {}}
    on_params = off_params = None
    if "--pair" in argv:   # two rule sets of eval_buildings_bgt.RULE_SETS (with, without): under their own key
        from eval_buildings_bgt import RULE_SETS

        def settings(name: str) -> classify.ClassifySettings:
            # eighth round: "<set> + dropout rims", the set with ClassifySettings.dropout_roof_rims on
            base = name.removesuffix(RIMS_SUFFIX)
            return dataclasses.replace(classify.ClassifySettings(), **RULE_SETS[base],
                                       **({"dropout_roof_rims": True} if name != base else {}))

        with_set, without_set = argv[argv.index("--pair") + 1: argv.index("--pair") + 3]
        on_params, off_params = (settings(n) for n in (with_set, without_set))
        result = {"command": result["command"], "with": with_set, "without": without_set, "clouds": {}}
    if "--only" in argv:   # these clouds only, merged into the file's others
        only = argv[argv.index("--only") + 1].split(",")
        clouds = {k: v for k, v in clouds.items() if k in only}
        if out.exists():
            old = json.loads(out.read_text())
            result = {**old, "clouds": old["clouds"], "commands_merged": [*old.get("commands_merged", []), result["command"]]}
    for name, (paths, crs, labelled) in clouds.items():
        c = _read(paths, crs)
        if labelled:
            c["labels"] = c["classification"]
        fig, on, off = compare(c, on_params, off_params)
        if name == "ahn3_delft":
            part = part_of(c["x"], c["y"])
            truth = c["classification"]
            for key, cls in (("per_point_defaults", on), ("per_point_rule_off", off)):
                fig[key] = {n: {k: v for k, v in scores(cls[part == i], truth[part == i]).items()
                                if k.startswith(("building", "ground"))} for i, n in enumerate(PARTS)}
                fig[key]["crop"] = {k: v for k, v in scores(cls, truth).items() if k.startswith(("building", "ground"))}
        if name == "lidr_topography":
            water = c["classification"] == classify.WATER
            for key, cls in (("water_defaults", on), ("water_rule_off", off)):
                w = cls == classify.WATER
                fig[key] = {"pa_pct": 100.0 * float((w & water).sum()) / max(int(water.sum()), 1),
                            "ua_pct": 100.0 * float((w & water).sum()) / max(int(w.sum()), 1)}
        result["clouds"][name] = fig
        print(f"{name}: {fig['points']:,} points, {fig['changed']} change {fig['changed_from_to']}", flush=True)
    key = "seconds" if "--only" not in argv else f"seconds_{'_'.join(clouds)}"
    result[key] = time.perf_counter() - t0
    result["load_average_before_after" if "--only" not in argv else f"load_average_{'_'.join(clouds)}"] = \
        [list(load0), list(os.getloadavg())]
    if "--pair" in argv:
        store_result(out, result, key="pair: " + result["with"])
    else:
        store_result(out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
