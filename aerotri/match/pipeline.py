"""``match_project``: the tie-point stage over a project folder."""

from __future__ import annotations

import logging

import dataclasses
import json
import time

import numpy as np
import rasterio
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from aerotri.geom.camera import project_camera
from aerotri.geom.eo import check_block_crs, read_gnss
from aerotri.core.config import config_number, config_vector
from aerotri.core.errors import InputError
from aerotri.match import features as F
from aerotri.match import matching as M
from aerotri.geom.images import check_frames, find_images
from aerotri.match.pairs import Pair, candidate_pairs, plan_block
from aerotri.match.report import plot_block, track_length_histogram
from aerotri.match.tracks import build_tracks, coincident
from aerotri.match.weak import analyse
from aerotri.core.executor import Executor, local_executor
from aerotri.core.project import Project
from aerotri.core.atomic import write_text_atomic

log = logging.getLogger(__name__)


@dataclasses.dataclass
class MatchSettings:
    sparse: F.FeatureParams = dataclasses.field(default_factory=F.FeatureParams)
    dense: F.FeatureParams = dataclasses.field(
        default_factory=lambda: F.FeatureParams(budget=10000, grid=(20, 12), max_dim_px=4500,
                                                contrast_threshold=0.004, name="dense"))
    match: M.MatchParams = dataclasses.field(default_factory=M.MatchParams)
    dense_ratio: float = 0.9
    min_overlap: float = 0.15
    terrain_height_m: float | None = None
    image_top_deg: float = 0.0
    densify: bool = True
    min_per_region: int = 3
    min_strip_ties: int = 20
    retrieval_min_matches: int = 25


def _terrain_height(project: Project, s: MatchSettings) -> float:
    if s.terrain_height_m is not None:
        return float(s.terrain_height_m)
    h = config_number(project.section("flight"), "mean_terrain_height_m", None,
                      f"{project.root / 'project.toml'} [flight]")
    if h is not None:
        return h
    dem = project.lidar_out_dir / "dem.tif"
    if dem.exists():
        try:
            with rasterio.open(dem) as ds:
                a = ds.read(1, masked=True, out_shape=(1, min(ds.height, 512), min(ds.width, 512)))
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{dem}: cannot read the DEM for the mean terrain height ({exc})") from None
        if a.count() == 0:
            raise InputError(f"{dem}: the DEM has no valid heights")
        return float(a.mean())
    raise InputError(f"{project.root / 'project.toml'}: no terrain height for the footprints: set [flight] "
                     f"mean_terrain_height_m, give --terrain-height, or run lidarctl rasters first")


def _features_task(item) -> bool:
    """Extract (or find cached) the features of one frame; True when they came from the cache."""
    image_path, cache_dir, p, size = item
    hit = F.features_cache_path(image_path, cache_dir, p).exists()
    F.cached_features(image_path, cache_dir, p, size)
    return hit


def _match_task(item) -> tuple[bool, np.ndarray]:
    """Match one frame pair (or read the cached matches); (cache hit, (M, 2) keypoint index pairs)."""
    tag, fa, fb, camera, p, cache_dir = item
    fkey = fa[2].key()
    f = M.match_cache_path(tag, cache_dir, p, fkey)
    if f.exists():  # without reading the two frames' features
        return True, np.load(f)
    return False, M.cached_match(tag, F.cached_features(*fa), F.cached_features(*fb), camera, p, cache_dir, fkey)


def match_project(root, settings: MatchSettings | None = None, executor: Executor | None = None) -> dict:
    """Match the frames of a project; writes ``at/tiepoints.csv`` and the connectivity report.

    Feature extraction (one task per frame) and matching (one task per pair) run on ``executor``
    (default: local threads); the results are cached in ``work/features`` and ``work/matches``."""
    s = settings or MatchSettings()
    t0 = time.perf_counter()
    project = Project.open(root)
    toml = project.root / "project.toml"
    crs = check_block_crs(project.crs, f"{toml} [project] crs")
    camera = project_camera(project)
    images = find_images(project.images_dir)
    cache_f = project.work_dir / "features"
    cache_m = project.work_dir / "matches"
    stats = dict(feature_cache_hits=0, match_cache_hits=0)
    gnss = None
    if project.gnss_path.exists():
        gnss = read_gnss(project.gnss_path, crs)
        missing = sorted(set(images) - set(gnss.image_id))
        if missing:
            raise InputError(f"{project.gnss_path}: no GNSS position for frame(s) {', '.join(missing[:10])}"
                             + (" ..." if len(missing) > 10 else ""))
        no_image = sorted(set(gnss.image_id) - set(images))
        if no_image:
            raise InputError(f"{project.images_dir}: no image file for GNSS record(s) {', '.join(no_image[:10])} "
                             f"of {project.gnss_path}")
        ids = list(gnss.image_id)
        lever = config_vector(project.section("gnss"), "lever_arm_m", (0.0, 0.0, 0.0), 3, f"{toml} [gnss]")
    else:
        ids = sorted(images)
    if len(ids) < 2:
        raise InputError(f"{project.images_dir}: a block of {len(ids)} frame ({', '.join(ids)}); tie points need "
                         "at least 2 overlapping frames")
    terrain_m = _terrain_height(project, s) if gnss is not None else None
    check_frames(images, camera, project.camera_path)
    if gnss is not None:
        plan = plan_block(ids, gnss.position_m, camera, lever, terrain_m, s.image_top_deg)
        pairs = candidate_pairs(plan, s.min_overlap)
    else:
        # No GNSS (e.g. a kite block): find overlapping pairs by matching thumbnails, then match those.
        plan = None
        log.info(f"{project.gnss_path} not found: pairs by thumbnail retrieval")

    ex = executor or local_executor()

    def extract(frames, p: F.FeatureParams, desc: str) -> list:
        """Extract (or find cached) the features of the given frames, one task per frame; their cache keys."""
        items = [(images[ids[i]], cache_f, p, (camera.width, camera.height)) for i in frames]
        stats["feature_cache_hits"] += sum(ex.map(_features_task, items, desc=desc, unit="frame"))
        return items

    def feats(frames, p: F.FeatureParams, desc: str) -> dict:
        """Features of the given frames (index -> Features), extracted as one task per frame."""
        frames = list(frames)
        return {i: F.cached_features(*item) for i, item in zip(frames, extract(frames, p, desc))}

    def match(pairs_ij, fp: F.FeatureParams, p: M.MatchParams, desc: str) -> list:
        """Verified matches of the given frame pairs, one task per pair (features read from the cache)."""
        items = [(f"{ids[i]}__{ids[j]}", (images[ids[i]], cache_f, fp, (camera.width, camera.height)),
                  (images[ids[j]], cache_f, fp, (camera.width, camera.height)), camera, p, cache_m)
                 for i, j in pairs_ij]
        out = ex.map(_match_task, items, desc=desc, unit="pair")
        stats["match_cache_hits"] += sum(hit for hit, _ in out)
        return [m for _, m in out]

    if plan is None:
        thumb = F.FeatureParams(budget=1500, grid=(6, 4), max_dim_px=1000, name="thumb")
        extract(range(len(ids)), thumb, "thumbnails")  # the retrieval tasks read them from the cache
        all_pairs = [(i, j) for i in range(len(ids)) for j in range(i + 1, len(ids))]
        pairs = [Pair(i, j, "retrieved", float(len(m)))
                 for (i, j), m in zip(all_pairs, match(all_pairs, thumb, s.match, "retrieval"))
                 if len(m) >= s.retrieval_min_matches]
    sparse = feats(range(len(ids)), s.sparse, "features")
    sparse = [sparse[i] for i in range(len(ids))]
    matches = {(pr.i, pr.j): ("sparse", m)
               for pr, m in zip(pairs, match([(pr.i, pr.j) for pr in pairs], s.sparse, s.match, "matching"))}
    track, image, xy, n_bad = _tracks(sparse, {}, matches)
    analysis = (analyse(plan, camera, track, image, xy, s.min_per_region, s.min_strip_ties) if plan is not None
                else dict(models=[], cross_strip=[]))

    densified = dict(models=[], strip_pairs=[])
    if s.densify and plan is not None:
        weak_pairs = {(m["i"], m["j"]) for m in analysis["models"] if m["weak"]}
        extra: list[Pair] = []
        for c in analysis["cross_strip"]:
            if c["weak"]:
                densified["strip_pairs"].append([c["strip_a"], c["strip_b"]])
                # Extra cross pairs with a lower overlap threshold between the two strips.
                for pr in candidate_pairs(plan, s.min_overlap / 3.0):
                    if {int(plan.strip[pr.i]) + 1, int(plan.strip[pr.j]) + 1} == {c["strip_a"], c["strip_b"]}:
                        if (pr.i, pr.j) not in matches:
                            pr.kind = "extra"
                            extra.append(pr)
                        weak_pairs.add((pr.i, pr.j))
        if weak_pairs:
            densified["models"] = sorted([ids[i], ids[j]] for i, j in weak_pairs)
            dense = feats(sorted({k for p in weak_pairs for k in p}), s.dense, "dense features")
            dp = dataclasses.replace(s.match, ratio=s.dense_ratio)
            wp = sorted(weak_pairs)
            for (i, j), m in zip(wp, match(wp, s.dense, dp, "densifying")):
                matches[(i, j)] = ("dense", m)
            pairs = pairs + extra
            track, image, xy, n_bad = _tracks(sparse, dense, matches)
            analysis = analyse(plan, camera, track, image, xy, s.min_per_region, s.min_strip_ties)

    # Connectivity of the frames through verified matches.
    ties = [(i, j, len(m)) for (i, j), (_, m) in matches.items()]
    r = [i for i, j, t in ties if t > 0]
    c = [j for i, j, t in ties if t > 0]
    n = len(ids)
    if n > 1 and not r:
        raise InputError(f"{project.images_dir}: no two frames share verified tie points (no overlap at all?)")
    ncomp, comp = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)), directed=False)
    components = [[ids[k] for k in np.flatnonzero(comp == q)] for q in range(ncomp)]

    at = project.at_dir
    at.mkdir(parents=True, exist_ok=True)
    lines = ["point_id,image_id,x_px,y_px"]
    lines += [f"T{t + 1:07d},{ids[i]},{x:.3f},{y:.3f}" for t, i, (x, y) in zip(track, image, xy)]
    write_text_atomic(at / "tiepoints.csv", "\n".join(lines) + "\n")
    lengths = np.bincount(track) if len(track) else np.zeros(0, int)
    kinds = {}
    for pr in pairs:
        kinds[pr.kind] = kinds.get(pr.kind, 0) + 1
    report = dict(
        project=project.name, frames=n, strips=int(len(np.unique(plan.strip))) if plan is not None else 0,
        pairs=len(pairs),
        pairs_by_kind=kinds, pairs_with_ties=int(sum(t > 0 for _, _, t in ties)), components=len(components),
        component_frames=components if len(components) > 1 else [], tracks=int(len(lengths)),
        observations=int(len(track)), inconsistent_tracks_dropped=n_bad,
        tracks_3plus_fraction=float((lengths >= 3).mean()) if len(lengths) else 0.0,
        track_length_histogram=track_length_histogram(track),
        ties_per_pair=[dict(left=ids[i], right=ids[j], ties=t) for i, j, t in ties],
        weak_models=[[m["left"], m["right"]] for m in analysis["models"] if m["weak"]],
        weak_strip_pairs=[[c_["strip_a"], c_["strip_b"]] for c_ in analysis["cross_strip"] if c_["weak"]],
        densified=densified, models=analysis["models"], cross_strip=analysis["cross_strip"],
        terrain_height_m=plan.terrain_height_m if plan is not None else None, seconds=round(time.perf_counter() - t0, 2), **stats,
    )
    write_text_atomic(at / "connectivity.json", json.dumps(report, indent=1) + "\n")
    if plan is not None:
        plot_block(at / "connectivity.png", plan, ties, analysis)
    log.info(f"{n} frames, {len(pairs)} pairs, {report['tracks']} tracks, {report['observations']} observations, "
        f"{len(components)} component(s), {len(report['weak_models'])} weak model(s) -> {at / 'tiepoints.csv'}")
    return report


def _tracks(sparse, dense, matches):
    """Tracks over the union of sparse and dense keypoints (dense ones that repeat a sparse keypoint
    within 0.5 px are merged with it, so one image point never appears twice)."""
    n_img = len(sparse)
    xy_all, dense_map, sparse_map = [], {}, {}
    for i in range(n_img):
        xs = sparse[i].xy_px
        sparse_map[i] = coincident(xs)
        if i in dense:
            xd = dense[i].xy_px
            d, nn = cKDTree(xs).query(xd, distance_upper_bound=0.5) if len(xs) else (np.full(len(xd), np.inf), None)
            same = np.isfinite(d)
            idx = np.empty(len(xd), int)
            idx[same] = sparse_map[i][nn[same]]
            new = xd[~same]
            idx[~same] = len(xs) + coincident(new)  # dense keypoints at one place are one node too
            dense_map[i] = idx
            xy_all.append(np.vstack([xs, new]))
        else:
            xy_all.append(xs)
    pm = []
    for (i, j), (kind, m) in matches.items():
        if len(m) == 0:
            continue
        if kind == "dense":
            m = np.column_stack([dense_map[i][m[:, 0]], dense_map[j][m[:, 1]]])
        else:
            m = np.column_stack([sparse_map[i][m[:, 0]], sparse_map[j][m[:, 1]]])
        pm.append((i, j, m))
    track, image, kp, n_bad = build_tracks([len(x) for x in xy_all], pm)
    xy = np.array([xy_all[i][k] for i, k in zip(image, kp)]).reshape(-1, 2)
    return track, image, xy, n_bad
