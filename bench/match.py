"""Benchmark ``aerotri match`` against pycolmap (extraction + exhaustive, and + spatial matching with the GNSS
positions as pose priors) on the demo block, same session, same number of threads (2).

    python bench/match.py [--demo-project DIR] [--skip-dmc]

Prints pairs matched, wall times and their ratio, and the connectivity (connected components of the
verified image graph) of both; then the feature-extraction time of one full-size DMC frame
(13824 x 7680 px) rendered by the simulator. Writes results/bench_match.json.
"""

from __future__ import annotations

import argparse
import json
import os
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


THREADS = 2  # ours: the local executor's threads on this 2-core machine; pycolmap: num_threads


def _graph_stats(n_img: int, edges: list[tuple[int, int, np.ndarray]], overlapping: list[tuple[int, int]]) -> dict:
    """Components of the verified graph (pairs with >= 15 inliers), weak models (GNSS-overlapping frame pairs
    with < 15 verified ties) and the share of tie points (union-find tracks over the pair matches) seen in 3+
    frames. ``edges``: (i, j, (M, 2) keypoint index pairs)."""
    from aerotri.match.tracks import build_tracks

    strong = [(i, j) for i, j, m in edges if len(m) >= 15]
    r = [e[0] for e in strong]
    c = [e[1] for e in strong]
    ncomp, _ = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n_img, n_img)), directed=False)
    ties = {(min(i, j), max(i, j)): len(m) for i, j, m in edges}
    weak = [(i, j) for i, j in overlapping if ties.get((i, j), 0) < 15]
    n_kp = np.zeros(n_img, int)
    for i, j, m in edges:
        if len(m):
            n_kp[i] = max(n_kp[i], m[:, 0].max() + 1)
            n_kp[j] = max(n_kp[j], m[:, 1].max() + 1)
    track, _, _, _ = build_tracks(list(n_kp), [(i, j, m) for i, j, m in edges if len(m) >= 15])
    lengths = np.bincount(track) if len(track) else np.zeros(0, int)
    return dict(components=int(ncomp), pairs_with_ties=len(strong), weak_models=len(weak),
                tracks=int(len(lengths)), tracks_3plus_fraction=float((lengths >= 3).mean()) if len(lengths) else 0.0)


def _overlapping(project: Path) -> tuple:
    """Frame ids, the GNSS-overlapping pairs of the flight plan (our candidate pairs) and their largest
    centre distance (m)."""
    from aerotri.core.project import Project
    from aerotri.geom.camera import project_camera
    from aerotri.geom.eo import check_block_crs, read_gnss
    from aerotri.match.pairs import candidate_pairs, plan_block

    pr = Project.open(project)
    gnss = read_gnss(pr.gnss_path, check_block_crs(pr.crs, "project.toml"))
    terrain = float(pr.section("flight")["mean_terrain_height_m"])
    plan = plan_block(list(gnss.image_id), gnss.position_m, project_camera(pr), (0.0, 0.0, 0.0), terrain)
    pairs = [(q.i, q.j) for q in candidate_pairs(plan, MatchSettings().min_overlap)]
    dist = max(float(np.linalg.norm(gnss.position_m[i, :2] - gnss.position_m[j, :2])) for i, j in pairs)
    return list(gnss.image_id), pairs, dist, gnss.position_m


def ours(project: Path, overlapping) -> dict:
    from aerotri.core.executor import Executor

    # A fresh work/ so that nothing comes from the cache.
    shutil.rmtree(project / "work", ignore_errors=True)
    t = time.perf_counter()
    c = time.process_time()
    with Executor("threads", THREADS) as ex:
        rep = match_project(project, MatchSettings(), ex)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    ids = overlapping[0]
    ties = {(ids.index(p.left), ids.index(p.right)): p.ties for p in rep.ties_per_pair}
    weak = [(i, j) for i, j in overlapping[1] if ties.get((i, j), 0) < 15]
    return dict(wall_s=wall, cpu_s=cpu, load_avg=os.getloadavg(), pairs_matched=rep.pairs,
                pairs_with_ties=rep.pairs_with_ties, components=rep.components, weak_models=len(weak),
                weak_models_report=len(rep.weak_models), tracks=rep.tracks, observations=rep.observations,
                tracks_3plus_fraction=rep.tracks_3plus_fraction)


def colmap(project: Path, overlapping, mode: str) -> dict:
    """pycolmap: SIFT extraction (6000 features, as ours) plus exhaustive or spatial matching (GNSS positions
    written as pose priors, max distance = the largest centre distance of our candidate pairs + 10 %)."""
    import pycolmap

    ids, pairs, dist, pos = overlapping
    tmp = Path(tempfile.mkdtemp())
    db = tmp / "db.db"
    t = time.perf_counter()
    c = time.process_time()
    opts = pycolmap.FeatureExtractionOptions()
    opts.sift.max_num_features = 6000
    opts.num_threads = THREADS
    pycolmap.extract_features(db, project / "images", camera_mode=pycolmap.CameraMode.SINGLE,
                              extraction_options=opts, device=pycolmap.Device.cpu)
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = THREADS
    if mode == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    else:
        d = pycolmap.Database.open(db)
        for im in d.read_all_images():
            k = ids.index(Path(im.name).stem)
            prior = pycolmap.PosePrior(position=pos[k], coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN)
            prior.corr_data_id = im.data_id
            d.write_pose_prior(prior)
        d.close()
        so = pycolmap.SpatialPairingOptions()
        so.max_distance = 1.1 * dist
        so.num_threads = THREADS
        pycolmap.match_spatial(db, matching_options=mo, pairing_options=so, device=pycolmap.Device.cpu)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    d = pycolmap.Database.open(db)
    index = {im.image_id: ids.index(Path(im.name).stem) for im in d.read_all_images()}
    pair_ids, geoms = d.read_two_view_geometries()
    edges = []
    for pid, g in zip(pair_ids, geoms):
        a, b = pycolmap.pair_id_to_image_pair(pid)
        i, j = index[a], index[b]
        m = np.asarray(g.inlier_matches, int).reshape(-1, 2)
        edges.append((i, j, m) if i < j else (j, i, m[:, ::-1]))
    n_matched = d.num_matched_image_pairs()
    d.close()
    shutil.rmtree(tmp)
    return dict(wall_s=wall, cpu_s=cpu, load_avg=os.getloadavg(), pairs_matched=int(n_matched),
                **_graph_stats(len(ids), edges, pairs))


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
    shutil.copytree(src, work, ignore=shutil.ignore_patterns("at", "work", "lidar", "truth"))
    ov = _overlapping(work)
    res = dict(threads=THREADS, ours=ours(work, ov))
    for mode in ("spatial", "exhaustive"):
        res[f"pycolmap_{mode}"] = colmap(work, ov, mode)
    best = min(("pycolmap_spatial", "pycolmap_exhaustive"), key=lambda k: res[k]["wall_s"])
    res["pycolmap_faster"] = best
    res["wall_time_ratio_colmap_over_ours"] = res[best]["wall_s"] / res["ours"]["wall_s"]
    res["cpu_time_ratio_colmap_over_ours"] = res[best]["cpu_s"] / res["ours"]["cpu_s"]
    for k in ("ours", "pycolmap_spatial", "pycolmap_exhaustive"):
        r = res[k]
        print(f"{k:20s}: {r['pairs_matched']:4d} pairs matched, {r['wall_s']:7.1f} s wall, {r['cpu_s']:7.1f} s CPU, "
              f"components {r['components']}, weak models {r['weak_models']}, "
              f"3+ frames {100 * r['tracks_3plus_fraction']:.1f} %, load {r['load_avg'][0]:.1f}")
    print(f"pycolmap ({best}) / ours: wall {res['wall_time_ratio_colmap_over_ours']:.2f}, "
          f"CPU {res['cpu_time_ratio_colmap_over_ours']:.2f}")
    if not args.skip_dmc:
        res["dmc_frame_features"] = dmc_frame_extraction(out)
        print("full-size DMC frame features:", json.dumps(res["dmc_frame_features"]))
    (REPO / "results").mkdir(exist_ok=True)
    (REPO / "results" / "bench_match.json").write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
