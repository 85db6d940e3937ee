"""What the sloping-surface water rule (``water_sloping_surface``, i44-water) moves on every labelled set
but Autzen -> bench/results/water_sloping.json.

Each set is classified with the shipped settings twice, the rule on and off (main's water rule), and the
returns whose class differs are counted, with the water PA / UA against the set's own class 9 where it has
one (lidR Topography: the choice set of issue 44's water rules; AHN3 Delft: its canals). Sets: lidR
Topography, the 7 ISPRS samples, AHN3 Delft (EPSG:28992 given, as bench/eval_water.py), lidR MixedConifer,
laspy Nebraska. Where nothing changes, every figure computed from these classes with the shipped settings
(MixedConifer's ground figures, AHN3's and Topography's water layers in bench/eval_water_edge.py) is unchanged
by construction (the ISPRS nested estimate runs the noise and ground filters alone, before any water rule).
Autzen, the set the rule was written for, is scored in
bench/eval_water_autzen.py.

The fusion's water-rim test (``FusionSettings.road_max_water_rim_share``: a road-shaped patch whose rim is
mostly water is not road) acts only where water was found; with ``--demo PROJECT`` the simulated demo's four
strips (4.9 M returns, ponds; no classes in the strips) are classified LiDAR only and fused with the demo's
mosaic, by main's rules (sloping surface off, rim test off) and by this branch's, and the changed returns
counted (``demo`` in the JSON; the sets above are kept from the file when only the demo is run: ``--only-demo``).

    AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/eval_water_sloping.py [--demo PROJECT [--only-demo]]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO, SAMPLES  # noqa: E402
from eval_water import classify_cloud, read  # noqa: E402

from lidarctl.classify import pipeline as classify  # noqa: E402


def sets() -> dict:
    s = {"lidr_topography": (DATA / "lidr_topography" / "Topography.laz",)}
    s.update({f"isprs_{k}": (DATA / "isprs_filtertest" / f"{k}-utm.laz",) for k in SAMPLES})
    s.update({"ahn3_delft": (DATA / "ahn3_delft" / "ahn3_cropped_1.laz",),
              "lidr_mixedconifer": (DATA / "lidr_mixedconifer" / "MixedConifer.laz",),
              "laspy_nebraska": (DATA / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las",)})
    return {k: v for k, v in s.items() if all(p.is_file() for p in v)}


def water_scores(pred_water, truth_water) -> dict:
    found = int(np.sum(pred_water & truth_water))
    return {"truth_water": int(truth_water.sum()), "called_water": int(pred_water.sum()), "found": found,
            "pa_pct": round(100.0 * found / truth_water.sum(), 2) if truth_water.any() else None,
            "ua_pct": round(100.0 * found / pred_water.sum(), 2) if pred_water.any() else None}


def demo(project: Path) -> dict:
    """Classes of the demo's strips changed from main's rules to this branch's, LiDAR only and fused."""
    import laspy

    from lidarctl import tiles
    from lidarctl.classify import class_grid as cg
    from lidarctl.classify import fusion as fu

    strips = sorted((project / "lidar").glob("*.las"))
    grid, units = cg.cloud_grid(strips, 1.0)
    img = fu.open_image(project / "ortho" / "mosaic.tif", None, grid.crs, units.xy_m)
    rules = {"main": (dataclasses.replace(classify.ClassifySettings(), water_sloping_surface=False),
                      fu.FusionSettings(road_max_water_rim_share=1.0)),
             "branch": (classify.ClassifySettings(), fu.FusionSettings())}
    out, tmp = {"points": 0}, Path(tempfile.mkdtemp(prefix="water_demo_"))
    try:
        for mode in ("lidar_only", "fused_rgb"):
            cls = {}
            for rule, (p, fp) in rules.items():
                d = tmp / f"{mode}_{rule}"
                t = time.perf_counter()
                tiles.classify_files(strips, d, params=p, fusion=None if mode == "lidar_only" else fu.Fusion(img, fp))
                cls[rule] = np.concatenate([np.asarray(laspy.read(f).classification) for f in sorted(d.glob("*.las"))])
                print(mode, rule, round(time.perf_counter() - t, 1), "s", flush=True)
                shutil.rmtree(d)
            out["points"] = len(cls["main"])
            out[mode] = {"classes_changed": int(np.sum(cls["main"] != cls["branch"])),
                         **{f"water_{r}": int(np.sum(c == classify.WATER)) for r, c in cls.items()},
                         **{f"road_{r}": int(np.sum(c == fu.ROAD)) for r, c in cls.items()}}
            print(mode, out[mode], flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, default=None, help="the demo project (its lidar/ and ortho/mosaic.tif)")
    ap.add_argument("--only-demo", action="store_true", help="run the demo alone, keep the sets' rows")
    args = ap.parse_args()
    t0 = time.perf_counter()
    path = REPO / "bench" / "results" / "water_sloping.json"
    old = json.loads(path.read_text()) if path.is_file() else {}
    out = old["sets"] if args.only_demo else {}
    for name, paths in ({} if args.only_demo else sets()).items():
        c = read(name, paths)
        on = classify_cloud(c)
        off = classify_cloud(c, water_sloping_surface=False)
        t = np.asarray(c.classification) == classify.WATER
        row = {"points": len(on), "classes_changed": int(np.sum(on != off)),
               "water_on": int(np.sum(on == classify.WATER)), "water_off": int(np.sum(off == classify.WATER))}
        if t.any():
            row["water_rule_on"] = water_scores(on == classify.WATER, t)
            row["water_rule_off"] = water_scores(off == classify.WATER, t)
        out[name] = row
        print(name, row, flush=True)
    res = {"command": "AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/eval_water_sloping.py",
           "what": __doc__.split("\n\n")[1].replace("\n", " "), "sets": out}
    if args.demo is not None:
        res["demo"] = {"project": str(args.demo), **demo(args.demo)}
    elif "demo" in old:
        res["demo"] = old["demo"]   # not re-run
    res["seconds"] = round(time.perf_counter() - t0, 1)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(res, indent=2) + "\n")
    tmp.replace(path)
    print("wrote", path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
