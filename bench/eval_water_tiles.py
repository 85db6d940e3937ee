"""Water classes against the tile size (issue 44, i44-water: a 120 m river in 80 m tiles lost most of its water)
-> bench/results/water_tiles.json.

Each set is classified by ``lidarctl.tiles.classify_file`` whole (one tile) and in tiles of 80 m and 150 m (the
default buffer, the ground filter's reach: 60 m), default settings. Reported per run: water returns, water PA /
UA against the set's reference, and the returns whose class differs from the whole run's (all, and those where
neither class is water: the ground / building / vegetation classes the water fix must not move). References:
lidR Topography's own class 9 (its lakes); Autzen's river, reference (a) the delivered ground inside the
hand-digitised outline and (b) with the dark class-1 single returns on the water's level
(``bench/eval_water_autzen.py``; no fused image here); AHN3 Delft's class 9 (its canals; EPSG:28992 given); the
simulated wide river (120 m wide, 400 m long, falling 0.2 %, 90 % of its pulses lost: the reviewer's case,
``tests/lidarctl/test_classify_water_tiles.py`` has a smaller one) by construction.

The same script runs main's code for the "before" rows: export main's packages and put them first on the path,
  git archive d0d98f70 lidarctl aerotri ortho | tar -x -C /tmp/main_src
  AEROTRI_SHARED_DATA=/work/shared/data PYTHONPATH=/tmp/main_src nice .venv/bin/python bench/eval_water_tiles.py --label main
  AEROTRI_SHARED_DATA=/work/shared/data nice .venv/bin/python bench/eval_water_tiles.py --label branch
(each label's rows are replaced, the other's kept).

``--others``: the sets without water (the 7 ISPRS samples, lidR MixedConifer, laspy Nebraska) classified whole by
the code run, their classes' SHA-256 and water count under ``others_<label>`` (the whole-cloud rule change, the
sloping surface tried where one level holds too, must move nothing there).

``--demo PROJECT``: the demo's four strips (simulated, ponds) classified by ``classify_files`` with the default tiles,
LiDAR only: tiles, water, classes per class and SHA-256 under ``demo_<label>``; the classes are also saved to
/tmp/water_tiles_demo_<label>.npy for counting the returns that differ.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import DATA, REPO  # noqa: E402

import lidarctl  # noqa: E402
from lidarctl import io, synthetic, tiles  # noqa: E402

WATER = 9
TILE_SIZES_M = (80.0, 150.0)


def scores(pred: np.ndarray, truth: np.ndarray) -> dict:
    found = int(np.sum(pred & truth))
    return {"truth": int(truth.sum()), "called": int(pred.sum()), "found": found,
            "pa_pct": round(100.0 * found / truth.sum(), 2) if truth.any() else None,
            "ua_pct": round(100.0 * found / pred.sum(), 2) if pred.any() else None}


def autzen_truths(path: Path) -> dict:
    """Autzen's references (a) and (b), as bench/eval_water_autzen.py makes them."""
    from matplotlib.path import Path as MplPath
    from scipy.spatial import cKDTree

    import eval_water_autzen as ea

    las = laspy.read(path)
    fx, fy = np.asarray(las.x), np.asarray(las.y)
    c = io.read_cloud(path)
    inside = MplPath(ea.outline_ft()).contains_points(np.column_stack([fx, fy]))
    delivered = np.asarray(las.classification)
    ground_in = inside & (delivered == 2)
    gi = np.flatnonzero(ground_in)
    tree = cKDTree(np.column_stack([c.x[gi], c.y[gi]]))
    cand = np.flatnonzero(inside & (delivered == 1) & (np.asarray(las.number_of_returns) == 1))
    near = tree.query_ball_point(np.column_stack([c.x[cand], c.y[cand]]), ea.ON_SURFACE_R_M)
    med = np.array([np.median(c.z[gi[v]]) if len(v) else np.nan for v in near])
    surface_in = ground_in.copy()
    surface_in[cand[np.abs(c.z[cand] - med) <= ea.ON_SURFACE_M]] = True
    return {"a_ground_in_outline": ground_in, "b_surface_in_outline": surface_in}


def wide_river(path: Path) -> dict:
    """The simulated wide river (EPSG:32610): 400 x 300 m, the river 120 m wide across it, its surface falling
    0.2 % along x, 90 % of its pulses lost, the rest dark; banks rising 1 m over 1 m, then 2 %; 3 returns / m2."""
    rng = np.random.default_rng(4)
    length_m, width_m = 400.0, 300.0
    n = int(length_m * width_m * 3.0)
    u, v = rng.uniform(0, length_m, n), rng.uniform(0, width_m, n)
    level = 120.0 - 0.002 * u
    dist = np.maximum(90.0 - v, v - 210.0)
    water = dist <= 0
    keep = ~water | (rng.random(n) < 0.1)
    z = np.where(water, level, level + np.minimum(dist, 1.0) + 0.02 * np.maximum(dist - 1.0, 0.0))
    z = z + rng.normal(0.0, 0.03, n)
    intensity = np.where(water, rng.normal(20.0, 8.0, n), rng.normal(150.0, 30.0, n)).clip(1, 1000)
    k = np.flatnonzero(keep)
    cloud = io.PointCloud(x=500000.0 + u[k], y=4000000.0 + v[k], z=z[k], intensity=intensity[k].astype(np.uint16),
                          return_number=np.ones(len(k), np.uint8), number_of_returns=np.ones(len(k), np.uint8),
                          classification=np.ones(len(k), np.uint8))
    synthetic.write_las(path, cloud, crs="EPSG:32610")
    return {"simulated_water": water[k]}


def _store(key: str, rows: dict) -> None:
    out_path = REPO / "bench" / "results" / "water_tiles.json"
    doc = json.loads(out_path.read_text()) if out_path.is_file() else {}
    doc[key] = rows
    tmp_out = out_path.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(doc, indent=1) + "\n")
    tmp_out.replace(out_path)


def demo(label: str, project: Path) -> int:
    import hashlib

    strips = sorted((project / "lidar").glob("*.las"))
    tmp = Path(tempfile.mkdtemp(prefix="water_tiles_demo_"))
    try:
        t = time.perf_counter()
        st = tiles.classify_files(strips, tmp / "out")
        cls = np.concatenate([np.asarray(laspy.read(f).classification) for f in sorted((tmp / "out").glob("*.las"))])
        seconds = round(time.perf_counter() - t, 1)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    np.save(f"/tmp/water_tiles_demo_{label}.npy", cls)
    rows = {"project": str(project), "points": len(cls), "tiles": st.run.n_tiles, "tile_m": st.grid.tile_m,
            "water": int(np.sum(cls == WATER)), "classes": {int(k): int(v) for k, v in zip(*np.unique(cls,
                                                                                                   return_counts=True))},
            "sha256": hashlib.sha256(cls.tobytes()).hexdigest(), "seconds": seconds}
    print(label, rows, flush=True)
    _store(f"demo_{label}", rows)
    return 0


def others(label: str) -> int:
    import hashlib

    from lidar_common import SAMPLES
    from lidarctl.classify import pipeline as classify

    paths = {**{f"isprs_{k}": DATA / "isprs_filtertest" / f"{k}-utm.laz" for k in SAMPLES},
             "lidr_mixedconifer": DATA / "lidr_mixedconifer" / "MixedConifer.laz",
             "laspy_nebraska": DATA / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las"}
    rows = {}
    for name, path in paths.items():
        c = io.read_cloud(path)
        cls = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
        rows[name] = {"points": len(cls), "water": int(np.sum(cls == WATER)),
                      "sha256": hashlib.sha256(cls.tobytes()).hexdigest()}
        print(label, name, rows[name], flush=True)
    _store(f"others_{label}", rows)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True, help="the code run: main or branch")
    ap.add_argument("--others", action="store_true", help="only the sets without water, whole")
    ap.add_argument("--demo", type=Path, default=None, help="only the demo project's strips")
    args = ap.parse_args()
    if args.others:
        return others(args.label)
    if args.demo is not None:
        return demo(args.label, args.demo)
    t0 = time.perf_counter()
    out_path = REPO / "bench" / "results" / "water_tiles.json"
    doc = json.loads(out_path.read_text()) if out_path.is_file() else {}
    tmp = Path(tempfile.mkdtemp(prefix="water_tiles_"))
    rows = {"code": str(Path(lidarctl.__file__).parent)}
    try:
        river = tmp / "wide_river.laz"
        sets = {"simulated_wide_river": (river, None, lambda: wide_river(river)),
                "lidr_topography": (DATA / "lidr_topography" / "Topography.laz", None, None),
                "autzen": (DATA / "autzen" / "autzen_trim.laz", None, None),
                "ahn3_delft": (DATA / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:28992", None)}
        for name, (src, crs, make) in sets.items():
            truths = make() if make is not None else None
            if not src.is_file():
                rows[name] = f"skipped: {src} absent"
                continue
            if truths is None:
                truths = autzen_truths(src) if name == "autzen" else \
                    {"class_9": np.asarray(laspy.read(src).classification) == WATER}
            runs, row = {}, {}
            for tile_m in (None,) + TILE_SIZES_M:
                key = "whole" if tile_m is None else f"tiles_{tile_m:g}m"
                dst = tmp / f"{name}_{key}.laz"
                t = time.perf_counter()
                st = tiles.classify_file(src, dst, crs=crs, tile_size_m=1e5 if tile_m is None else tile_m)
                cls = np.asarray(laspy.read(dst).classification)
                runs[key] = cls
                r = {"tiles": st.run.n_tiles, "seconds": round(time.perf_counter() - t, 1),
                     "water": int(np.sum(cls == WATER)),
                     **{tn: scores(cls == WATER, tv) for tn, tv in truths.items()}}
                if tile_m is not None:
                    d = cls != runs["whole"]
                    r["differ_from_whole"] = int(d.sum())
                    r["differ_neither_water"] = int(np.sum(d & (cls != WATER) & (runs["whole"] != WATER)))
                row[key] = r
                print(args.label, name, key, r, flush=True)
            rows[name] = row
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    rows["seconds"] = round(time.perf_counter() - t0, 1)
    doc.setdefault("what", __doc__.split("\n\n")[0].replace("\n", " "))
    doc["command"] = "see the docstring of bench/eval_water_tiles.py (run with --label main and --label branch)"
    doc[args.label] = rows
    tmp_out = out_path.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(doc, indent=1) + "\n")
    tmp_out.replace(out_path)
    print("wrote", out_path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
