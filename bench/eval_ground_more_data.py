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
made (``FETCHED``: lasR's four BC Timber Sales forest tiles and lidR's Megaplot, classes 1/2, no building; test tiles of
IGN's LiDAR HD from three IGNF repositories, ASPRS classes with buildings, water and bridges), each file taken from its
repository at the commit named (``git show COMMIT:PATH > DIR/BASENAME``; nothing is copied into this repository).
Building returns are counted with the shipped defaults and with each later building rule off alone (``RULES_OFF``:
``roof_min_patch_m2 = 0``, the rule before stop 107; ``cut_pieces_judged = false``, before stop 108;
``foliage_beyond_roof_reach = false``, before stop 117); where the labels
hold buildings, building producer's / user's accuracy per point and the high vegetation called building.
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

@dataclasses.dataclass(frozen=True)
class Fetched:
    """Labelled files of a public repository at a commit (``paths``, their git blob sha1s), read from ``--fetched DIR``
    by their base names and scored as one cloud (several adjacent tiles merged); ``bare``: the bare-earth classes,
    ``left_out``: classes that are no returns (IGN's virtual points, 66)."""

    repository: str
    commit: str
    paths: tuple
    blobs: tuple
    what: str
    bare: tuple = (2,)
    left_out: tuple = ()

    def record(self) -> dict:
        return {"repository": self.repository, "commit": self.commit, "paths": list(self.paths),
                "git_blob_sha1": list(self.blobs), "what": self.what, "bare_earth_classes": list(self.bare),
                "classes_left_out": list(self.left_out)}


LASR = ("r-lidar/lasR", "86cb3bde85fb02a4ebdf272f6a251b4f0a21b0c6")
BCTS = ("BC Timber Sales airborne LiDAR, coastal conifer forest on Vancouver Island (EPSG:3005), classes 1/2, up to 4 "
        "returns; lasR (GPL-3)")
# IGN's LiDAR HD (France, EPSG:2154, classes 1-6, 9, 17 and IGN's 64-67; test data of IGN's own tools). Bare earth 2
# and 9 (a DTM's), IGN's virtual points (66, synthetic) left out.
IGN_TOOLS = ("IGNF/ign-pdal-tools", "ccb4819f4c4a8070f0a93fb1e0c43023d261ed3c")
IGN_MODELS = ("IGNF/las-digital-models", "8a94dd67d1c3c1baeb3d62ea33d84dca3e870b46")
IGN_PLUGIN = ("IGNF/pdal-ign-plugin", "651e7dd9c599df3f318a4b4ea47b1ee1973f66c2")
IGN = dict(bare=(2, 9), left_out=(66,))
MONTPELLIER = tuple(f"test/data/test_data_{e}_{n}_LA93_IGN69.laz"
                    for e in (77050, 77055, 77060) for n in (627755, 627760))
FETCHED = {
    **{f"lasr_bcts_{k}": Fetched(*LASR, (f"inst/extdata/bcts/bcts_{k}.laz",), (blob,), BCTS)
       for k, blob in ((1, "70f56f5731995c47fad18defbcd1cb504db04518"),
                       (2, "0b86872ff7b5d63c389ea61d78cf681504cf6c10"),
                       (3, "6c483a7269fc03f340cc04734d51904ccc428480"),
                       (4, "ef48c0f24b223435567c72834117438118e0d1d6"))},
    "lasr_megaplot": Fetched(*LASR, ("inst/extdata/Megaplot.las",), ("c00b535621ae4711e42078a59feafc3f9c4bc9e5",),
                             "lidR's Megaplot: forest plot (EPSG:26917), classes 1/2, heights normalised to the "
                             "ground; lasR (GPL-3)"),
    "ign_montpellier": Fetched(*IGN_TOOLS, MONTPELLIER, (
        "e5f7cb0ece9503320f6249adce4292b0afcab705", "b088feeb7d0c9487871138b185eaf6512feefb23",
        "6d7cc9c5347956041b8216c15affffc8f3c4d11d", "13129bd7271bd84b76b11a18dc4294d9c58b104c",
        "70e61b914118792d1b938a7d1f7fb33bd94d5e76", "ee821759375661b9c647c245bf125ba692e84618"),
        "six adjacent 50 m tiles, city blocks with street trees (27 returns per m2; MIT)", **IGN),
    "ign_larochelle_decimated": Fetched(*IGN_TOOLS, ("test/data/decimated_laz/test_semis_2021_0382_6565_LA93_IGN69_"
                                                     "cropped.laz",), ("d898cb65478cf4d89f875eae22353d46f26aa899",),
                                        "a decimated tile (0.3 returns per m2; MIT)", **IGN),
    "ign_brittany_0292_decimated": Fetched(*IGN_TOOLS,
                                           ("test/data/decimated_laz/test_semis_2023_0292_6833_LA93_IGN69.laz",),
                                           ("ef6b393e92300fd4c38b95c946a86ca90c976b49",), "a decimated tile (MIT)",
                                           **IGN),
    **{f"ign_brittany_{k}_decimated": Fetched(*IGN_MODELS,
                                              (f"test/data/bridge/pointcloud/test_semis_2023_{k}_6802_LA93_IGN69.laz",),
                                              (blob,), "a decimated tile with a bridge (MIT)", **IGN)
       for k, blob in (("0299", "77cfd105d19bd2f981ac796a589a59fd64c66629"),
                       ("0300", "3d1e16dd3a7e51f6a6787d5d5c57d45e9ada0b1e"))},
    "ign_jura_decimated": Fetched(*IGN_TOOLS, ("test/data/check_las/Semis_2022_0906_6665_LA93_IGN69_ok.laz",),
                                  ("884cd9cf3bc17079f59a8739c2304f25bb6014ae",), "a decimated forest tile (MIT)",
                                  **IGN),
    "ign_vienne": Fetched(*IGN_TOOLS, ("test/data/las_with_several_extra_byte_bloc.laz",),
                          ("e1a7ec0c21fdf42c112e8a9a384f118104074433",), "fields and a farm (5.4 returns per m2; MIT)",
                          **IGN),
    "ign_haute_saone": Fetched(*IGN_TOOLS, ("test/data/las_with_origin_dsmMarker.laz",),
                               ("8b91f694aa9d4a3d8439198a40d9d3b2a3746c24",), "a field (MIT)", **IGN),
    **{f"ign_{name}": Fetched(*IGN_PLUGIN, (f"test/data/mnx/input/{file}",), (blob,), what + " (no licence file in the "
                              "repository; LiDAR HD is published under Licence Ouverte 2.0)", **IGN)
       for name, file, blob, what in (
           ("isere_buildings", "bat.laz", "e0061c7027435b51966040ad2a9bd8ff7b138f4f",
            "houses among broadleaf crowns (57 returns per m2)"),
           ("bonifacio_cliffs", "corse.laz", "c25a20d2b2646a9709a8e44e915e565546b29b89",
            "a 48 x 40 m tile of bare sea cliffs and a cove"),
           ("loiret_1", "crop_1.laz", "3478412e1d70f8244bd14236364b749b8b678777", "a 50 m tile (84 returns per m2)"),
           ("loiret_2", "crop_2.laz", "c070343602ab6560cf2e9dd90aadc15aa1aa49d5", "a 50 m tile across a river"),
           ("loiret_3", "crop_3.laz", "d7348b76718f696e096f6b1f5dc70268224706f6", "a 50 m tile of fields"),
           ("yonne_bridge", "pont.laz", "e59fb0623c9d88389659716b9fbca4f7599ef113",
            "a bridge over a river (mostly virtual points, left out)"))},
}


def _merged(paths, left_out: tuple = ()) -> io.PointCloud:
    """The clouds of ``paths`` as one (the first file's CRS), without the returns of the classes ``left_out``."""
    clouds = [io.read_cloud(p) for p in paths]
    fields = ("x", "y", "z", "intensity", "return_number", "number_of_returns", "classification")
    c = io.PointCloud(**{f: np.concatenate([getattr(k, f) for k in clouds]) for f in fields}, crs=clouds[0].crs)
    if left_out:
        keep = ~np.isin(c.classification, left_out)
        c = io.PointCloud(**{f: getattr(c, f)[keep] for f in fields}, crs=c.crs)
    return c


# Building rules added after a set here was scored, each switched off alone in the same run: roof patches (stop 107:
# every roof cell counts toward a segment's roof area), cut pieces (stop 108: a piece of a segment cut off by the
# growth tests keeps the segment's verdict) and foliage beyond a roof's reach (stop 117).
RULES_OFF = {"roof_patches": {"roof_min_patch_m2": 0.0}, "cut_pieces": {"cut_pieces_judged": False},
             "foliage_beyond_reach": {"foliage_beyond_roof_reach": False}}


def _building_scores(called: np.ndarray, truth: np.ndarray) -> dict:
    """Building producer's / user's accuracy per point (%) of the returns ``called`` building against the labels
    ``truth`` (which hold buildings), and the high-vegetation returns called building."""
    tb = truth == classify.BUILDING
    return {"building_pa_pct": 100.0 * float(np.mean(called[tb])),
            "building_ua_pct": 100.0 * float(np.mean(tb[called])) if called.any() else None,
            "high_vegetation_called_building": int(np.sum(called & (truth == classify.HIGH_VEG)))}


def one(path, bare: tuple, rules_off: bool = False, left_out: tuple = ()) -> dict:
    """The figures of the labelled cloud(s) ``path``; ``rules_off``: also each rule of ``RULES_OFF`` off alone."""
    c = _merged(path if isinstance(path, (list, tuple)) else [path], left_out)
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
    pb = pred == classify.BUILDING
    labelled = bool(np.any(truth == classify.BUILDING))
    if labelled:   # per point against the labels
        buildings.update(_building_scores(pb, truth))
        buildings["high_vegetation_called_building"] = [buildings["high_vegetation_called_building"],
                                                        int(np.sum(truth == classify.HIGH_VEG))]
    buildings["bare_earth_called_building"] = int(np.sum(pb & true_ground))
    if rules_off:   # each later building rule off alone, in the same run (RULES_OFF)
        buildings["rules_off"] = {}
        for rule, off in RULES_OFF.items():
            before = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity,
                                              params=dataclasses.replace(classify.ClassifySettings(), **off))
            bb = before == classify.BUILDING
            r = {"settings": off, "building_returns_called": int(bb.sum()),
                 "returns_whose_class_the_rule_changed": int(np.sum(before != pred))}
            if labelled:
                r.update(_building_scores(bb, truth))
            buildings["rules_off"][rule] = r
        # the keys of stop 107 (the roof-patch rule off)
        buildings["building_returns_called_every_roof_cell"] = \
            buildings["rules_off"]["roof_patches"]["building_returns_called"]
        buildings["returns_whose_class_the_rule_changed"] = \
            buildings["rules_off"]["roof_patches"]["returns_whose_class_the_rule_changed"]
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
        out[name] = one(path, bare, rules_off=True)
        _say(name, out[name])
    for name, f in FETCHED.items() if args.fetched else ():
        paths = [args.fetched / Path(p).name for p in f.paths]
        absent = [str(p) for p in paths if not p.is_file()]
        if absent:
            print(f"{name}: {', '.join(absent)} absent, skipped")
            continue
        out[name] = {"source": f.record(), **one(paths, f.bare, rules_off=True, left_out=f.left_out)}
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
          f"{r['building_returns_called']} (rule off: " + ", ".join(
              f"{k} {v['building_returns_called']}" for k, v in r.get("rules_off", {}).items()) + ")")


if __name__ == "__main__":
    main()
