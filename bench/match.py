"""Benchmark ``aerotri match`` against pycolmap's exhaustive matching on the demo block, same session.

    python bench/match.py [--demo-project DIR] [--skip-dmc]

Prints pairs matched, wall times and their ratio, and the connectivity (connected components of the
verified image graph) of both; then the feature-extraction time of one full-size DMC frame
(13824 x 7680 px) rendered by the simulator. Writes results/bench_match.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.match import MatchSettings, match_project  # noqa: E402
from aerotri.match.features import FeatureParams, extract  # noqa: E402
from aerotri.geom.images import read_gray  # noqa: E402
from aerotri.sim import load_preset, simulate  # noqa: E402


def ours(project: Path) -> dict:
    # A fresh work/ so that nothing comes from the cache.
    shutil.rmtree(project / "work", ignore_errors=True)
    t = time.perf_counter()
    rep = match_project(project, MatchSettings())
    return dict(wall_s=time.perf_counter() - t, pairs_matched=rep.pairs, pairs_with_ties=rep.pairs_with_ties,
                components=rep.components, tracks=rep.tracks, observations=rep.observations)


def colmap_exhaustive(project: Path) -> dict:
    import pycolmap

    tmp = Path(tempfile.mkdtemp())
    db = tmp / "db.db"
    t = time.perf_counter()
    opts = pycolmap.FeatureExtractionOptions()
    opts.sift.max_num_features = 6000
    pycolmap.extract_features(db, project / "images", camera_mode=pycolmap.CameraMode.SINGLE,
                              extraction_options=opts, device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(db, device=pycolmap.Device.cpu)
    wall = time.perf_counter() - t
    d = pycolmap.Database.open(db) if hasattr(pycolmap.Database, "open") else pycolmap.Database(str(db))
    n_img = d.num_images()
    pair_ids, geoms = d.read_two_view_geometries()
    edges = []
    for pid, g in zip(pair_ids, geoms):
        if len(g.inlier_matches) >= 15:
            i, j = pycolmap.pair_id_to_image_pair(pid)
            edges.append((i - 1, j - 1))
    n_pairs = n_img * (n_img - 1) // 2
    r = [e[0] for e in edges]
    c = [e[1] for e in edges]
    ncomp, _ = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n_img, n_img)), directed=False)
    d.close()
    shutil.rmtree(tmp)
    return dict(wall_s=wall, pairs_matched=n_pairs, pairs_with_ties=len(edges), components=int(ncomp))


def dmc_frame_extraction(out: Path) -> dict:
    proj = out / "dmc_one_frame"
    if not (proj / "truth" / "truth.json").exists():
        cfg = load_preset("dmc", ["flight.strips=1", "flight.frames_per_strip=2"])
        simulate(cfg, proj, force=True)
    img_path = sorted((proj / "images").glob("*.tif"))[0]
    t = time.perf_counter()
    img = read_gray(img_path)
    t_read = time.perf_counter() - t
    res = {}
    for p in (FeatureParams(), FeatureParams(max_dim_px=7000, budget=20000, grid=(24, 16), name="full")):
        t = time.perf_counter()
        f = extract(img, p)
        res[p.name] = dict(seconds=round(time.perf_counter() - t, 2), keypoints=len(f.xy_px), pyramid_level=f.level)
    return dict(image=str(img_path.name), size_px=[img.shape[1], img.shape[0]], read_s=round(t_read, 2), **res)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo-project", type=Path)
    ap.add_argument("--skip-dmc", action="store_true")
    args = ap.parse_args()
    out = REPO / "out" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    src = args.demo_project or out / "match_demo"
    if not (src / "truth" / "truth.json").exists():
        simulate(load_preset("demo"), src, force=True)
    work = out / "match_demo_copy"
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(src, work, ignore=shutil.ignore_patterns("at", "work"))
    a = ours(work)
    b = colmap_exhaustive(work)
    res = dict(ours=a, pycolmap_exhaustive=b, wall_time_ratio_ours_over_colmap=a["wall_s"] / b["wall_s"])
    print(f"aerotri match : {a['pairs_matched']:4d} pairs matched, {a['wall_s']:7.1f} s, components {a['components']}")
    print(f"pycolmap exh. : {b['pairs_matched']:4d} pairs matched, {b['wall_s']:7.1f} s, components {b['components']}")
    print(f"wall time ratio ours / pycolmap: {res['wall_time_ratio_ours_over_colmap']:.2f}")
    if not args.skip_dmc:
        res["dmc_frame_features"] = dmc_frame_extraction(out)
        print("full-size DMC frame features:", json.dumps(res["dmc_frame_features"]))
    (REPO / "results").mkdir(exist_ok=True)
    (REPO / "results" / "bench_match.json").write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
