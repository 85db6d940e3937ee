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

``--big-lake`` (i44-edge): a level lake 340 m across in a 480 m square (2 returns / m2; banks 1 m over 1 m, then
2 %), returning the pulse (``lake``) or mirroring 95 % of it away (``pond``), with a dark level car park standing 0.15 m
above its surroundings (50 x 30 m) and a level forest floor 0.3 m below them (50 x 50 m) under crowns (45 % of the
pulses split on a crown 12-18 m up; ``tests/lidarctl/test_classify_water_tiles.py::big_lake_scene``), classified
whole and in 100 m tiles with 20 m and 40 m buffers: water PA / UA against the scene's
truth, the car park's and the forest floor's water returns, the returns whose water class differs from the whole
run's -> ``big_lake_<label>``; ``lake_alone`` / ``pond_alone``: the same without the car park and the forest.

``--edge`` (i44-edge): the survey's coverage mask (``water_survey_coverage``) on and off, with the same code, on lidR
Topography, Autzen, AHN3 Delft (whole, and in 100 m tiles with a 40 m buffer), the ragged-edge scene and with
``--demo PROJECT`` the demo's strips (default tiles): water and bridge-deck returns, the returns whose class
differs between off and on, and where they lie (distance to the nearest cell beyond the coverage) ->
``edge_<label>``.

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


def big_lake(label: str) -> int:
    sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
    from test_classify_water_tiles import big_lake_scene  # noqa: E402

    rows = {}
    tmp = Path(tempfile.mkdtemp(prefix="water_big_lake_"))
    try:
        for kind in ("lake", "pond", "lake_alone", "pond_alone"):
            # "_alone": without the car park and the forest (no split pulses in the cloud)
            cloud, truth, park, forest = big_lake_scene(kind.split("_")[0], land_features="_" not in kind)
            src = tmp / f"{kind}.laz"
            synthetic.write_las(src, cloud, crs="EPSG:32610")
            runs, row = {}, {"points": len(cloud.x), "truth_water": int(truth.sum())}
            for key, tile_m, buffer_m in (("whole", 1e5, None), ("tiles_100m_buffer_40m", 100.0, 40.0),
                                          ("tiles_100m_buffer_20m", 100.0, 20.0)):
                t = time.perf_counter()
                st = tiles.classify_file(src, tmp / f"{kind}_{key}.laz", tile_size_m=tile_m, buffer_m=buffer_m)
                cls = np.asarray(laspy.read(tmp / f"{kind}_{key}.laz").classification)
                runs[key] = cls
                w = cls == WATER
                r = {"tiles": st.run.n_tiles, "seconds": round(time.perf_counter() - t, 1), **scores(w, truth),
                     "car_park_water": int(np.sum(w & park)), "forest_floor_water": int(np.sum(w & forest))}
                if key != "whole":
                    d = w != (runs["whole"] == WATER)
                    r["water_differs_from_whole"] = int(d.sum())
                    # those the noise filter flags in only one of the runs aside (its own tile effect)
                    noise = np.isin(cls, (7, 18)) | np.isin(runs["whole"], (7, 18))
                    r["water_differs_noise_aside"] = int(np.sum(d & ~noise))
                row[key] = r
                print(label, kind, key, r, flush=True)
            rows[kind] = row
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    _store(f"big_lake_{label}", rows)
    return 0


def terraces_at_edge(seed: int = 7):
    """The ragged-edge scene's field (200 x 100 m, 3 returns / m2, the coverage ending in teeth at v = 77.5-80 m for
    u < 170 m) with eight level patches 12 x 14 m (168 m2, each below ``level_water_min_area_m2``) along its
    edge, dark, at one level 0.5 m below the ground around them (v > 60 m): sunken yards or paddies running to the
    survey's edge. Returns (x, y, z, intensity, patch mask)."""
    rng = np.random.default_rng(seed)
    n = 200 * 100 * 3
    u, v = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    z = 100.0 + 0.02 * u + rng.normal(0, 0.02, n)
    tooth = (v > 77.5) & (np.mod(u, 12.0) < 2.5)
    keep = (u > 170) | ((v < 80) & ~tooth)
    patch = (v > 66) & (np.mod(u, 20.0) < 12) & (u < 160)
    z = np.where((v > 60) & (u < 160), 101.0 + rng.normal(0, 0.02, n), z)
    z = np.where(patch, 100.5 + rng.normal(0, 0.015, n), z)
    inten = np.where(patch, rng.normal(20, 5, n), rng.normal(150, 30, n)).clip(1, 1000)
    return u[keep] + 85000.0, v[keep] + 447000.0, z[keep], inten[keep], patch[keep]


def edge(label: str, project: Path | None) -> int:
    """``--edge``: the coverage mask on / off (see the module docstring)."""
    from lidarctl.classify import pipeline as classify

    sys.path.insert(0, str(REPO / "tests" / "lidarctl"))
    from test_classify_bridge import X0, Y0, ragged_edge_scene  # noqa: E402

    rows = {}
    tmp = Path(tempfile.mkdtemp(prefix="water_edge_"))
    on, off = classify.ClassifySettings(), classify.ClassifySettings(water_survey_coverage=False)
    try:
        x, y, z, edge_mask = ragged_edge_scene()
        cloud = io.PointCloud(x=x, y=y, z=z, intensity=np.full(len(x), 100, np.uint16),
                              return_number=np.ones(len(x), np.uint8), number_of_returns=np.ones(len(x), np.uint8),
                              classification=np.ones(len(x), np.uint8))
        ragged = tmp / "ragged_edge.laz"
        synthetic.write_las(ragged, cloud, crs="EPSG:28992")
        x, y, z, inten, patch = terraces_at_edge()
        cloud = io.PointCloud(x=x, y=y, z=z, intensity=inten.astype(np.uint16),
                              return_number=np.ones(len(x), np.uint8), number_of_returns=np.ones(len(x), np.uint8),
                              classification=np.ones(len(x), np.uint8))
        terraces = tmp / "terraces_at_edge.laz"
        synthetic.write_las(terraces, cloud, crs="EPSG:28992")
        sets = {"ragged_edge_scene": (ragged, None, (None, 100.0)),
                "terraces_at_edge_scene": (terraces, None, (None, 100.0)),
                "lidr_topography": (DATA / "lidr_topography" / "Topography.laz", None, (None, 100.0)),
                "autzen": (DATA / "autzen" / "autzen_trim.laz", None, (None, 100.0)),
                "ahn3_delft": (DATA / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:28992", (None, 100.0))}
        for name, (src, crs, sizes) in sets.items():
            if not src.is_file():
                rows[name] = f"skipped: {src} absent"
                continue
            delivered = np.asarray(laspy.read(src).classification)
            row = {}
            for tile_m in sizes:
                key = "whole" if tile_m is None else f"tiles_{tile_m:g}m_buffer_40m"
                cls = {}
                for mode, params in (("off", off), ("on", on)):
                    dst = tmp / f"{name}_{key}_{mode}.laz"
                    tiles.classify_file(src, dst, crs=crs, params=params, tile_size_m=1e5 if tile_m is None else tile_m,
                                        buffer_m=None if tile_m is None else 40.0)
                    cls[mode] = np.asarray(laspy.read(dst).classification)
                d = cls["on"] != cls["off"]
                r = {m: {"water": int(np.sum(c == WATER)), "deck": int(np.sum(c == 17))} for m, c in cls.items()}
                r["differ"] = int(d.sum())
                r["changes"] = {f"{a}->{b}": int(np.sum(d & (cls['off'] == a) & (cls['on'] == b)))
                                for a, b in {(int(a), int(b)) for a, b in zip(cls["off"][d], cls["on"][d])}}
                if name == "ragged_edge_scene":
                    r["edge_ground_deck_off_on"] = [int(np.sum(edge_mask & (cls[m] == 17))) for m in ("off", "on")]
                elif name == "terraces_at_edge_scene":
                    r["patch_returns"] = int(patch.sum())
                    r["patch_water_off_on"] = [int(np.sum(patch & (cls[m] == WATER))) for m in ("off", "on")]
                else:
                    r["delivered_of_changed"] = {int(k): int(v) for k, v in zip(*np.unique(delivered[d],
                                                                                          return_counts=True))}
                    r["deck_by_delivered_off_on"] = {m: {int(k): int(v) for k, v in zip(*np.unique(
                        delivered[cls[m] == 17], return_counts=True))} for m in ("off", "on")}
                row[key] = r
                print(label, name, key, r, flush=True)
            rows[name] = row
        if project is not None:
            strips = sorted((project / "lidar").glob("*.las"))
            cls = {}
            for mode, params in (("off", off), ("on", on)):
                tiles.classify_files(strips, tmp / f"demo_{mode}", params=params)
                cls[mode] = np.concatenate([np.asarray(laspy.read(f).classification)
                                            for f in sorted((tmp / f"demo_{mode}").glob("*.las"))])
            d = cls["on"] != cls["off"]
            rows["demo_default_tiles"] = {**{m: {"water": int(np.sum(c == WATER)), "deck": int(np.sum(c == 17))}
                                             for m, c in cls.items()}, "differ": int(d.sum())}
            print(label, "demo", rows["demo_default_tiles"], flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    _store(f"edge_{label}", rows)
    return 0


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
    ap.add_argument("--big-lake", action="store_true", help="only the lake larger than a tile (i44-edge)")
    ap.add_argument("--edge", action="store_true", help="only the coverage mask on / off (i44-edge)")
    args = ap.parse_args()
    if args.big_lake:
        return big_lake(args.label)
    if args.edge:
        return edge(args.label, args.demo)
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
