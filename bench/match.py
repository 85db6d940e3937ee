"""Benchmark ``aerotri match`` against pycolmap (extraction + exhaustive, and + spatial matching with the GNSS
positions as pose priors) on the demo block, same session, same number of threads (2).

    python bench/match.py [--demo-project DIR] [--skip-dmc] [--per-frame BLOCK ...] [--per-frame-only]

Prints pairs matched, wall times and their ratio, and the connectivity (connected components of the
verified image graph) of both; then the feature-extraction time of one full-size DMC frame
(13824 x 7680 px) rendered by the simulator. Writes bench/results/bench_match.json.

``--per-frame``: time per frame of ``aerotri match`` (a process of its own, fresh cache) on each block
given (project folders, e.g. the 30- and 300-frame blocks of ``bench/scale.py``; their inputs are linked
into out/bench, never written): wall and CPU seconds of the process and of each phase of the stage
(``phase_seconds`` of at/connectivity.json), per frame and per pair; the fixed cost is what does not grow
with the block: the process start (imports) and the plan and output phases. Kept in
bench/results/bench_match.json under ``per_frame`` (``--per-frame-only``: the rest of the file is kept).
``--skip-dmc`` and a run without ``--per-frame`` keep those entries of the last run that made them.
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
from aerotri.match.features import FeatureSettings, extract  # noqa: E402
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
    terrain = float(pr.flight.mean_terrain_height_m)
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
    for p in (FeatureSettings(), FeatureSettings(max_dim_px=7000, budget=20000, grid=(24, 16), name="full")):
        t = time.perf_counter()
        f = extract(img, p)
        res[p.name] = dict(seconds=round(time.perf_counter() - t, 2), keypoints=len(f.xy_px), pyramid_level=f.level)
    return dict(image=str(img_path.name), size_px=[img.shape[1], img.shape[0]], read_s=round(t_read, 2), **res)


PROJECT_INPUTS = ("project.toml", "camera.toml", "gnss.txt", "images")


def _link_inputs(src: Path, dst: Path) -> None:
    """Hard links of a project's inputs (copies across file systems); matching never writes them."""
    def link(a, b):
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)

    shutil.rmtree(dst, ignore_errors=True)
    dst.mkdir(parents=True)
    for name in PROJECT_INPUTS:
        if (src / name).is_dir():
            shutil.copytree(src / name, dst / name, copy_function=link)
        elif (src / name).exists():
            link(src / name, dst / name)


def per_frame(blocks: list[Path], out: Path) -> dict:
    """``aerotri match`` on each block in a fresh process and cache: seconds per frame, whole and by phase."""
    import resource
    import subprocess

    rows = {}
    for src in blocks:
        run = out / f"per_frame_{src.name}"
        _link_inputs(src, run)
        load = os.getloadavg()
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run([str(Path(sys.executable).parent / "aerotri"), "match", str(run)], check=True)
        wall = time.perf_counter() - t
        ru2 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (ru2.ru_utime - ru.ru_utime) + (ru2.ru_stime - ru.ru_stime)
        rep = json.loads((run / "at" / "connectivity.json").read_text())
        n, pairs, ph = rep["frames"], rep["pairs"], rep["phase_seconds"]
        stage_cpu = sum(c for _, c in ph.values())
        fixed_wall = (wall - rep["seconds"]) + ph["plan"][0] + ph["output"][0]
        fixed_cpu = (cpu - stage_cpu) + ph["plan"][1] + ph["output"][1]
        rows[src.name] = dict(
            frames=n, pairs=pairs, pairs_per_frame=round(pairs / n, 2), load_avg_before=[round(v, 2) for v in load],
            load_avg_after=[round(v, 2) for v in os.getloadavg()], process_wall_s=round(wall, 2),
            process_cpu_s=round(cpu, 2), stage_wall_s=rep["seconds"], phase_seconds=ph,
            wall_s_per_frame=round(wall / n, 3), cpu_s_per_frame=round(cpu / n, 3),
            stage_wall_s_per_frame=round(rep["seconds"] / n, 3),
            fixed_wall_s=round(fixed_wall, 2), fixed_cpu_s=round(fixed_cpu, 2),
            variable_wall_s_per_frame=round((wall - fixed_wall) / n, 3),
            variable_cpu_s_per_frame=round((cpu - fixed_cpu) / n, 3),
            features_cpu_s_per_frame=round(ph["features"][1] / n, 3),
            matching_cpu_s_per_pair=round(ph["matching"][1] / max(pairs, 1), 3),
            tracks_3plus_fraction=rep["tracks_3plus_fraction"], components=rep["components"],
            weak_models=len(rep["weak_models"]))
        r = rows[src.name]
        print(f"{src.name}: {n} frames, {pairs} pairs ({r['pairs_per_frame']}/frame), process {wall:.1f} s wall "
              f"{cpu:.1f} s CPU = {r['wall_s_per_frame']:.3f} / {r['cpu_s_per_frame']:.3f} s per frame; fixed "
              f"{fixed_wall:.1f} s wall {fixed_cpu:.1f} s CPU; without it {r['variable_wall_s_per_frame']:.3f} / "
              f"{r['variable_cpu_s_per_frame']:.3f} s per frame; phases {ph}; load {load[0]:.1f} -> "
              f"{r['load_avg_after'][0]:.1f}", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo-project", type=Path)
    ap.add_argument("--skip-dmc", action="store_true")
    ap.add_argument("--per-frame", type=Path, nargs="+", default=[], metavar="BLOCK")
    ap.add_argument("--per-frame-only", action="store_true")
    args = ap.parse_args()
    out = REPO / "out" / "bench"
    out.mkdir(parents=True, exist_ok=True)
    result = REPO / "bench" / "results" / "bench_match.json"
    if args.per_frame_only:
        res = json.loads(result.read_text()) if result.exists() else {}
        res["per_frame"] = per_frame(args.per_frame, out)
        result.write_text(json.dumps(res, indent=1) + "\n")
        return
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
    if args.per_frame:
        res["per_frame"] = per_frame(args.per_frame, out)
    # what this run did not measure stays as the last run that did left it
    old = json.loads(result.read_text()) if result.exists() else {}
    for key in ("dmc_frame_features", "per_frame"):
        if key not in res and key in old:
            res[key] = old[key]
    (REPO / "bench" / "results").mkdir(exist_ok=True)
    result.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
