"""The rooftop-object rule's range noise against the tiling -> bench/results/rooftop_noise.json (rules 15).

The rule cut a roof's objects at steps of 3 sigma of the ground's range noise, which each tile took from its own
window (a seeded sample of the window's ground, ``classify.range_noise_m``); now it is the lifted-ground test's
``ground_noise_m``, which a tile takes from the whole cloud. Run by the code on the path (``--label``; for the "before"
rows export an older main's packages first on PYTHONPATH, as bench/eval_water_tiles.py says):

- AHN3 Delft (EPSG:28992) classified whole and in 80 m and 150 m tiles (default 60 m buffer): the returns whose class
  differs from the whole run's, by (whole, tiled) class; the rule's noise per window (m);
- its buildings against the BGT footprints per area and per object, per quarter (``eval_buildings_bgt``'s scoring);
- the other shared clouds classified whole (7 ISPRS samples, lidR Topography and MixedConifer, Autzen, laspy
  Nebraska): their classes' SHA-256, to show which whole clouds the rule change moves.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as eb  # noqa: E402
from results_json import git_commit, store_result  # noqa: E402

from aerotri.core.executor import Executor  # noqa: E402
from lidarctl import tiles  # noqa: E402
from lidarctl.classify import pipeline  # noqa: E402

RESULTS = eb.REPO / "bench" / "results" / "rooftop_noise.json"
OTHERS = [*(f"isprs_filtertest/samp{s}-utm.laz" for s in (11, 21, 31, 41, 51, 61, 71)), "lidr_topography/Topography.laz",
          "lidr_mixedconifer/MixedConifer.laz", "autzen/autzen_trim.laz",
          "laspy_nebraska/file_with_both_wkt_and_geotiff_vlrs.las"]


def _classes(path: Path) -> np.ndarray:
    return np.asarray(laspy.read(path).classification)


def _noise_seen():
    """Record the noise (m) the rooftop-object rule is given, per classified window (in this process)."""
    seen, rule = [], pipeline.rooftop_objects

    def spy(x, y, z, is_building, spacing_m, noise_m, **kw):
        seen.append(round(float(noise_m), 5))
        return rule(x, y, z, is_building, spacing_m, noise_m, **kw)

    pipeline.rooftop_objects = spy
    return seen


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True, help="the code run, e.g. before or rules15")
    args = ap.parse_args()
    seen = _noise_seen()
    laz = eb.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    result = {"commit": git_commit(eb.REPO), "ahn3_delft": {}, "others_sha256": {}}
    with tempfile.TemporaryDirectory(prefix="rooftop_noise_") as tmp, Executor("synchronous") as ex:
        tmp = Path(tmp)
        runs = {"whole": None, "tiles_80m": 80.0, "tiles_150m": 150.0}
        for name, size in runs.items():
            seen.clear()
            run = tiles.classify_file(laz, tmp / f"{name}.laz", crs=eb.CRS, tile_size_m=size, executor=ex)
            row = {"tiles": run.run.n_tiles, "rooftop_noise_m": list(seen)}
            if size is not None:
                a, b = _classes(tmp / "whole.laz"), _classes(tmp / f"{name}.laz")
                d = a != b
                row["differ_from_whole"] = int(d.sum())
                row["by_class_whole_tiled"] = {f"{p} -> {q}": n for (p, q), n in
                                               collections.Counter(zip(a[d].tolist(), b[d].tolist())).most_common()}
            result["ahn3_delft"][name] = row
            print(name, row)
        result["ahn3_delft"]["whole_classes_sha256"] = hashlib.sha256(_classes(tmp / "whole.laz").tobytes()).hexdigest()
        polys = eb.read_bgt(eb.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
        x = laspy.read(laz)
        geo = eb.quarters(float(np.median(x.x)), float(np.median(x.y)))
        q = eb.evaluate_quarters({"default": tmp / "whole.laz"}, polys, geo)
        result["ahn3_delft"]["bgt_quarters"] = {
            name: {"completeness_pct": round(v["area"]["completeness_pct"], 3),
                   "correctness_pct": round(v["area"]["correctness_pct"], 3),
                   "footprints_found": v["footprints_found"], "footprints": v["footprints"]}
            for name, v in q.items() if v["area"]["footprint_area_m2"] > 0}
        print(result["ahn3_delft"]["bgt_quarters"])
        for rel in OTHERS:
            out = tmp / "other.laz"
            tiles.classify_file(eb.SHARED / rel, out, executor=ex)
            result["others_sha256"][rel] = hashlib.sha256(_classes(out).tobytes()).hexdigest()
    store_result(RESULTS, result, key=args.label)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
