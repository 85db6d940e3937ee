"""``match_project``: the tie-point stage over a project folder."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import rasterio
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from aerotri.core.atomic import committed, write_text_atomic
from aerotri.core.errors import InputError
from aerotri.core.executor import Executor, local_executor
from aerotri.core.log import counted
from aerotri.core.project import Project
from aerotri.core.resume import ResumeFolder, file_stamp, resumable, resume_key
from aerotri.core.settings import Resolved, settings_of
from aerotri.geom.camera import BrownCamera, project_camera
from aerotri.geom.eo import check_block_crs, read_gnss
from aerotri.geom.images import ImageFiles, check_frames, find_images
from aerotri.geom.strips import flight_order
from aerotri.match import features as F
from aerotri.match import matching as M
from aerotri.match.pairs import BlockPlan, Pair, candidate_pairs, plan_block
from aerotri.match.report import plot_block, plot_pair_graph, track_lengths
from aerotri.match.settings import MatchSettings
from aerotri.match.tracks import build_tracks, coincident, complete_tracks
from aerotri.match.weak import BlockStrength, ModelStrength, StripTies, analyse

log = logging.getLogger(__name__)


@dataclasses.dataclass
class PairTies:
    left: str
    right: str
    ties: int


@dataclasses.dataclass
class Densified:
    """What the densification matched again: frame pairs (weak models and the extra cross-strip pairs) and
    the weakly tied strip pairs (1-based strip numbers)."""

    models: list[list[str]] = dataclasses.field(default_factory=list)
    strip_pairs: list[list[int]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class MatchReport:
    """The numbers of a matching run (``at/connectivity.json``, keys in this order)."""

    project: str
    frames: int
    strips: int
    pairs: int
    pairs_by_kind: dict[str, int]
    pairs_with_ties: int
    components: int
    component_frames: list[list[str]]  # the frames of each component when the block falls apart, else empty
    tracks: int
    observations: int
    inconsistent_tracks_dropped: int
    tracks_3plus_fraction: float
    track_length_histogram: dict[str, int]  # rays -> tracks (``track_lengths``), as connectivity.json keys them
    ties_per_pair: list[PairTies]
    weak_models: list[list[str]]
    weak_strip_pairs: list[list[int]]
    densified: Densified
    models: list[ModelStrength]
    cross_strip: list[StripTies]
    terrain_height_m: float | None
    image_top_deg: float | None  # the flight plan's image top from the flight direction (degrees)
    seconds: float
    # wall and CPU seconds (this process and its threads) of each phase: plan (frames, GNSS, pairs), features,
    # matching, tracks (with completion and the model strength), densify, output (tie points, report, figure)
    phase_seconds: dict[str, list[float]]
    feature_cache_hits: int
    match_cache_hits: int
    settings: dict = dataclasses.field(default_factory=dict)  # path -> value and source (core.settings.Resolved)

    def summary_line(self) -> str:
        return (f"frames {self.frames}  pairs {self.pairs}  tracks {self.tracks}  observations {self.observations}  "
                f"3+ rays {100 * self.tracks_3plus_fraction:.1f} %  components {self.components}  weak models "
                f"{len(self.weak_models)}")


class _PhaseClock:
    """Wall and CPU seconds of consecutive phases: ``lap(name)`` closes the phase that ends now."""

    def __init__(self):
        self.phases: dict[str, list[float]] = {}
        self._wall, self._cpu = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        self.phases[name] = [round(wall - self._wall, 3), round(cpu - self._cpu, 3)]
        self._wall, self._cpu = wall, cpu


def _terrain_height(project: Project, s: MatchSettings, crs=None) -> float | None:
    """The mean terrain height for the footprints: --terrain-height-m, [flight] mean_terrain_height_m, else the
    mean of lidar_out/dem.tif (checked: in the project CRS ``crs``, finite heights, 2 x 2 cells or more);
    None when none of these is there."""
    if s.terrain_height_m is not None:
        return float(s.terrain_height_m)
    h = project.flight.mean_terrain_height_m
    if h is not None:
        return h
    dem = project.lidar_out_dir / "dem.tif"
    if dem.exists():
        from aerotri.geom.crs.definition import crs_label, parse_crs, same_horizontal
        from aerotri.geom.crs.raster_warp import open_north_up

        try:
            with open_north_up(dem, "DEM", heights=True) as ds:
                dem_crs = parse_crs(ds.crs.to_wkt(), f"{dem} CRS")
                if crs is not None and not same_horizontal(dem_crs, crs):
                    raise InputError(f"{dem}: the DEM is in {crs_label(dem_crs)}, the project in "
                                     f"{crs_label(crs)}; warp it first (aerotri crs warp) or give --terrain-height-m")
                a = ds.read(1, masked=True, out_shape=(1, min(ds.height, 512), min(ds.width, 512)))
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{dem}: cannot read the DEM for the mean terrain height ({exc})") from None
        v = np.ma.compressed(a)
        v = v[np.isfinite(v)]
        if v.size == 0:
            raise InputError(f"{dem}: the DEM has no valid heights")
        return float(v.mean())
    return None


RESUME_DIR_NAME = "match_resume"  # in work/: the features and pair matches a killed or interrupted match finished

# what a task found: computed, in the cache of an earlier committed run, or kept by an interrupted one (resumed)
_NEW, _CACHED, _RESUMED = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class _FrameItem:
    """One frame's feature task: its image, the cache, the settings, the expected size (px) and the key of
    everything its features depend on (``_frame_key``) in ``resume``."""

    image_path: Path
    cache_dir: Path
    p: F.FeatureSettings
    size: tuple[int, int]
    key: str
    resume: ResumeFolder | None

    def args(self) -> tuple:
        return self.image_path, self.cache_dir, self.p, self.size


def _frame_key(image_path: Path, p: F.FeatureSettings, size) -> str:
    """Key of a frame's features: the image file (name, size, modification time), the settings (their key holds
    the extraction's version), the frame size and the toolkit's version."""
    import aerotri

    return resume_key({"features": image_path.name, "stamp": file_stamp(image_path), "settings": p.key(),
                       "size": list(size), "version": aerotri.__version__})


def _features_task(item: _FrameItem) -> int:
    """Extract (or find cached or kept) the features of one frame; _NEW, _CACHED or _RESUMED."""
    f = F.features_cache_path(item.image_path, item.cache_dir, item.p)
    # kept: the interrupted run made it (a task it left running may have written the cache file after the roll-back)
    if item.resume is not None and item.resume.kept(item.key, ".npz") is not None:
        hit = _RESUMED
        if not f.exists():
            item.resume.take(item.key, ".npz", f)
    else:
        hit = _CACHED if f.exists() else _NEW
    F.cached_features(*item.args())
    if hit == _NEW and item.resume is not None:
        item.resume.keep(f, item.key, ".npz")
    return hit


def _match_task(item) -> tuple[int, np.ndarray]:
    """Match one frame pair (or read the cached or kept matches); (_NEW, _CACHED or _RESUMED, (M, 2) keypoint
    index pairs)."""
    tag, fa, fb, camera, p, cache_dir, guide, key, resume = item
    # the cache's name holds the features' key and both images' size and time: matches index the keypoints
    fkey = f"{fa.p.key()}-{key[:12]}"
    f = M.match_cache_path(tag, cache_dir, p, fkey, guide is not None)
    if resume is not None and resume.kept(key, ".npy") is not None:  # (as in _features_task)
        if not f.exists():
            resume.take(key, ".npy", f)
        return _RESUMED, np.load(f)
    if f.exists():  # without reading the two frames' features
        return _CACHED, np.load(f)
    m = M.cached_match(tag, F.cached_features(*fa.args()), F.cached_features(*fb.args()), camera, p,
                       cache_dir=cache_dir, feature_key=fkey, guide=guide)
    if resume is not None:
        resume.keep(f, key, ".npy")
    return _NEW, m


def _pair_key(tag: str, fa: _FrameItem, fb: _FrameItem, camera: BrownCamera, p: M.PairMatchSettings,
              guide) -> str:
    """Key of a pair's verified matches: its two frames' feature keys (they hold ``FEATURES_VERSION``), the camera,
    the match settings, the flight plan's guide (None: unguided), the matching's version (``MATCH_VERSION``) and the
    toolkit's version."""
    import aerotri
    from aerotri.match.settings import MATCH_VERSION

    g = None if guide is None else [guide.centre_m.tolist(), guide.kappa_deg.tolist(), guide.terrain_height_m,
                                    guide.footprint_a.wkb_hex, guide.footprint_b.wkb_hex]
    return resume_key({"pair": tag, "a": fa.key, "b": fb.key, "camera": repr(camera), "settings": p.key(),
                       "guide": g, "match_version": MATCH_VERSION, "version": aerotri.__version__})


@dataclasses.dataclass
class _Frames:
    """The frames to match: ids in block order, their files, and their GNSS plan (None without GNSS)."""

    ids: list[str]
    images: ImageFiles
    plan: BlockPlan | None


def _read_frames(project: Project, crs, camera: BrownCamera, s: MatchSettings) -> _Frames:
    """Images and GNSS positions checked against each other and the camera; the flight plan from GNSS."""
    images = find_images(project.images_dir)
    gnss = None
    if project.gnss_path.exists():
        gnss = read_gnss(project.gnss_path, crs)
        missing = sorted(set(images.image_id) - set(gnss.image_id))
        no_image = sorted(set(gnss.image_id) - set(images.image_id))
        if missing:
            # (trial s94: a typo in gnss.txt's id, 05_184 for 05_0184, named the frame alone, not the record)
            spare = f"; its records of no frame: {', '.join(no_image[:10])}" + (" ..." if len(no_image) > 10 else "") \
                + " (a typo in an id?)" if no_image else ""
            raise InputError(f"{project.gnss_path}: no GNSS position for frame(s) {', '.join(missing[:10])}"
                             + (" ..." if len(missing) > 10 else "") + spare)
        if no_image:
            raise InputError(f"{project.images_dir}: no image file for GNSS record(s) {', '.join(no_image[:10])} "
                             f"of {project.gnss_path}" + (" ..." if len(no_image) > 10 else "")
                             + f"; to go on without the frame(s), take their lines out of {project.gnss_path.name}")
        # in flight order, image-id order, as the adjustment takes them: in the file's order a frame whose line was
        # appended (a frame put back, a second day) broke its strip in two and made a stereo model of frames that
        # are not neighbours (trial s97 M5: 16,623 tracks and a weak model, 17,053 and none with the file sorted)
        order = flight_order(gnss.image_id)
        ids = [str(gnss.image_id[i]) for i in order]
        positions_m = np.asarray(gnss.position_m, dtype=float)[order]
        lever = project.gnss.lever_arm_m
    else:
        ids = sorted(images.image_id)
    if len(ids) < 2:
        raise InputError(f"{project.images_dir}: a block of {len(ids)} frame ({', '.join(ids)}); tie points need "
                         "at least 2 overlapping frames")
    terrain_m = _terrain_height(project, s, crs) if gnss is not None else None
    check_frames(images, camera, project.camera_path)
    # GNSS without a terrain height (a drone block's EXIF import): no footprints, pairs by thumbnail retrieval
    plan = (plan_block(ids, positions_m, camera, lever, terrain_m, s.image_top_deg)
            if gnss is not None and terrain_m is not None else None)
    return _Frames(ids, images, plan)


def check_inputs(root, settings: MatchSettings | None = None) -> None:
    """What ``match_project`` checks before any work (project CRS, camera, images against GNSS and the camera),
    without doing it: ``aerotri run`` calls it before its first stage writes anything."""
    project = Project.open(root)
    crs = check_block_crs(project.crs, f"{project.config_path} [project] crs")
    _read_frames(project, crs, project_camera(project), settings or MatchSettings())


class _Matcher:
    """Features (one task per frame) and matches (one task per pair) of a block's frames on an executor,
    cached in ``work/features`` and ``work/matches`` and kept in ``resume`` for a run after an interrupted one;
    counts the cache hits."""

    def __init__(self, project: Project, frames: _Frames, camera: BrownCamera, executor: Executor,
                 resume: ResumeFolder | None = None):
        self.ids, self.images, self.camera, self.ex = frames.ids, frames.images, camera, executor
        self.plan = frames.plan
        self.cache_f = project.work_dir / "features"
        self.cache_m = project.work_dir / "matches"
        self.resume = resume
        self.feature_cache_hits = 0
        self.match_cache_hits = 0
        self._items: dict = {}

    def _item(self, i: int, p: F.FeatureSettings) -> _FrameItem:
        k = (i, p)
        if k not in self._items:
            path = self.images.path_of(self.ids[i])
            size = (self.camera.width, self.camera.height)
            self._items[k] = _FrameItem(path, self.cache_f, p, size, _frame_key(path, p, size), self.resume)
        return self._items[k]

    def _say_resumed(self, keys: list[str], suffix: str, unit: str, desc: str) -> None:
        if self.resume is not None and self.resume.path.is_dir():
            k = sum(self.resume.kept(key, suffix) is not None for key in keys)
            if k:
                log.info(f"{desc}: resumed {k} of {len(keys)} {unit}s an interrupted run finished "
                         f"({self.resume.path})")

    def extract(self, frames, p: F.FeatureSettings, desc: str) -> list[_FrameItem]:
        """Extract (or find cached) the features of the given frames, one task per frame; their items."""
        items = [self._item(i, p) for i in frames]
        self._say_resumed([it.key for it in items], ".npz", "frame", desc)
        at_once = _frames_at_once(self.ex, F.extraction_bytes(self.camera.width, self.camera.height, p), desc)
        self.feature_cache_hits += sum(h == _CACHED for h in self.ex.map(_features_task, items, desc=desc,
                                                                         unit="frame", at_once=at_once))
        return items

    def features(self, frames, p: F.FeatureSettings, desc: str) -> dict:
        """Keypoints of the given frames (index -> CachedKeypoints: descriptors stay in the cache files), extracted
        as one task per frame."""
        frames = list(frames)
        return {i: F.cached_keypoints(*item.args()) for i, item in zip(frames, self.extract(frames, p, desc))}

    def match(self, pairs_ij, fp: F.FeatureSettings, p: M.PairMatchSettings, desc: str) -> list:
        """Verified matches of the given frame pairs, one task per pair (features read from the cache)."""
        items = []
        for i, j in pairs_ij:
            tag, fa, fb = f"{self.ids[i]}__{self.ids[j]}", self._item(i, fp), self._item(j, fp)
            guide = self.plan.guide(i, j, p.guide_margin) if self.plan is not None else None
            items.append((tag, fa, fb, self.camera, p, self.cache_m, guide,
                          _pair_key(tag, fa, fb, self.camera, p, guide), self.resume))
        self._say_resumed([it[7] for it in items], ".npy", "pair", desc)
        out = self.ex.map(_match_task, items, desc=desc, unit="pair")
        self.match_cache_hits += sum(hit == _CACHED for hit, _ in out)
        return [m for _, m in out]


def _frames_at_once(ex, task_bytes: int, desc: str) -> int | None:
    """How many frames' features are extracted side by side in this process: as many of the executor's workers as
    fit, each ``task_bytes``, in 90 % of the memory the process may use beside what it holds (a batch job's or
    container's limit; at least one); None (all the workers) on a cluster or when all fit."""
    from aerotri.core.limits import format_bytes, memory_room_bytes, usable_memory_bytes

    if ex.distributed:  # (a cluster's workers: processes of their own, not held back by map)
        return None
    room = memory_room_bytes()
    if room == math.inf:
        return None
    total = usable_memory_bytes()
    k = max(1, int(room // max(1, task_bytes)))
    if k >= ex.workers:
        return None
    log.info(f"{desc}: {k} frame(s) at a time of {ex.workers} workers (about {format_bytes(task_bytes)} each, "
             f"{format_bytes(total)} this process may use)")
    return k


def _retrieved_pairs(mt: _Matcher, s: MatchSettings) -> list[Pair]:
    """Without GNSS (e.g. a kite block): the frame pairs whose thumbnails match."""
    n = len(mt.ids)
    thumb = F.FeatureSettings(budget=1500, grid=(6, 4), max_dim_px=1000, name="thumb")
    mt.extract(range(n), thumb, "thumbnails")  # the retrieval tasks read them from the cache
    all_pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    return [Pair(i, j, "retrieved", float(len(m)))
            for (i, j), m in zip(all_pairs, mt.match(all_pairs, thumb, s.match, "retrieval"))
            if len(m) >= s.retrieval_min_matches]


@dataclasses.dataclass
class _Ties:
    """Verified matches {(i, j): (feature kind, (M, 2) keypoint index pairs)} and their tracks."""

    matches: dict
    track: np.ndarray
    image: np.ndarray
    xy: np.ndarray
    n_bad: int
    strength: BlockStrength


def _ties(plan: BlockPlan | None, camera: BrownCamera, sparse: list, dense: dict, matches: dict,
          s: MatchSettings) -> _Ties:
    complete_px = s.complete_px * 2.0 ** max(f.level for f in sparse) if s.complete_px > 0 else None
    track, image, xy, n_bad = _tracks(sparse, dense, matches, complete_px, (camera.width, camera.height))
    strength = (analyse(plan, camera, track, image, xy, min_per_region=s.min_per_region,
                        min_strip_ties=s.min_strip_ties) if plan is not None else BlockStrength([], []))
    return _Ties(matches, track, image, xy, n_bad, strength)


def _densify(mt: _Matcher, plan: BlockPlan, sparse: list, ties: _Ties, s: MatchSettings
             ) -> tuple[_Ties, list[Pair], Densified]:
    """Dense features and a looser ratio test on the weak models and between weakly tied strips (extra
    cross-strip pairs at a third of the overlap threshold): the new ties, the extra pairs, what was done."""
    ids = mt.ids
    densified = Densified()
    weak_pairs = {(m.i, m.j) for m in ties.strength.models if m.weak}
    extra: list[Pair] = []
    matches = dict(ties.matches)
    for c in ties.strength.cross_strip:
        if c.weak:
            densified.strip_pairs.append([c.strip_a, c.strip_b])
            # Extra cross pairs with a lower overlap threshold between the two strips.
            for pr in candidate_pairs(plan, s.min_overlap / 3.0):
                if {int(plan.strip[pr.i]) + 1, int(plan.strip[pr.j]) + 1} == {c.strip_a, c.strip_b}:
                    if (pr.i, pr.j) not in matches:
                        pr.kind = "extra"
                        extra.append(pr)
                    weak_pairs.add((pr.i, pr.j))
    if not weak_pairs:
        return ties, [], densified
    densified.models = sorted([ids[i], ids[j]] for i, j in weak_pairs)
    dense = mt.features(sorted({k for p in weak_pairs for k in p}), s.dense, "dense features")
    dp = dataclasses.replace(s.match, ratio=s.dense_ratio)
    wp = sorted(weak_pairs)
    for (i, j), m in zip(wp, mt.match(wp, s.dense, dp, "densifying")):
        matches[(i, j)] = ("dense", m)
    return _ties(plan, mt.camera, sparse, dense, matches, s), extra, densified


def _components(project: Project, ids: list[str], ties_per_pair: list[tuple[int, int, int]]) -> list[list[str]]:
    """The frames of each connected part of the block (frames joined by verified ties)."""
    r = [i for i, j, t in ties_per_pair if t > 0]
    c = [j for i, j, t in ties_per_pair if t > 0]
    n = len(ids)
    if n > 1 and not r:
        # (trial s99 atmut M2: NGI frames stored turned 180 deg matched nothing on the GNSS plan, "no overlap at all?")
        raise InputError(f"{project.images_dir}: no two frames share verified tie points: no overlap at all, frames "
                         "stored turned against the flight plan (a camera mounted the other way: [match] "
                         "image_top_deg = 180, or 90 / 270), or GNSS positions of other frames?")
    ncomp, comp = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)), directed=False)
    return [[ids[k] for k in np.flatnonzero(comp == q)] for q in range(ncomp)]


def _write_tiepoints(path: Path, ids: list[str], ties: _Ties) -> None:
    lines = ["point_id,image_id,x_px,y_px"]
    lines += [f"T{t + 1:07d},{ids[i]},{x:.3f},{y:.3f}" for t, i, (x, y) in zip(ties.track, ties.image, ties.xy)]
    write_text_atomic(path, "\n".join(lines) + "\n")


@committed(lambda root, *a, **k: Project(Path(root), {}).at_dir)
def match_project(root, settings: MatchSettings | Resolved | None = None,
                  executor: Executor | None = None) -> MatchReport:
    """Match the frames of a project; writes ``at/tiepoints.csv`` and the connectivity report.

    ``settings``: None reads [match] of project.toml; a ``Resolved`` (``aerotri match``, the chain) carries the
    source of every setting into the report. Feature extraction (one task per frame) and matching (one task
    per pair) run on ``executor`` (default: local threads); the results are cached in ``work/features`` and
    ``work/matches``, and kept in ``work/match_resume`` until the outputs are written, so that a run after an
    interrupted or killed one computes only what that one did not finish (``aerotri.core.resume``)."""
    t0 = time.perf_counter()
    clock = _PhaseClock()
    project = Project.open(root)
    resolved = settings_of(settings, MatchSettings, project)
    s = resolved.settings
    crs = check_block_crs(project.crs, f"{project.config_path} [project] crs")
    camera = project_camera(project)
    frames = _read_frames(project, crs, camera, s)
    ids, plan = frames.ids, frames.plan
    if plan is not None:
        pairs = candidate_pairs(plan, s.min_overlap)
    elif project.gnss_path.exists():
        n = len(ids)
        log.warning(f"{project.config_path}: no terrain height for the GNSS footprints ([flight] mean_terrain_height_m, "
                    f"--terrain-height-m or lidar_out/dem.tif): pairs by thumbnail retrieval of all {n * (n - 1) // 2} "
                    "pairs, no weak-model analysis or densification")
    else:
        log.info(f"{project.gnss_path} not found: pairs by thumbnail retrieval")
    # what the tasks finish is kept in work/match_resume until the stage's outputs are written (core.resume)
    with resumable(project.work_dir / RESUME_DIR_NAME) as keep:
        mt = _Matcher(project, frames, camera, executor or local_executor(), keep)
        if plan is None:
            pairs = _retrieved_pairs(mt, s)
        clock.lap("plan")
        sparse = mt.features(range(len(ids)), s.sparse, "features")
        sparse = [sparse[i] for i in range(len(ids))]
        clock.lap("features")
        matches = {(pr.i, pr.j): ("sparse", m)
                   for pr, m in zip(pairs, mt.match([(pr.i, pr.j) for pr in pairs], s.sparse, s.match, "matching"))}
        clock.lap("matching")
        ties = _ties(plan, camera, sparse, {}, matches, s)
        clock.lap("tracks")
        if plan is not None:
            from aerotri.match.image_top import image_top_check

            top = image_top_check(plan, camera, ties.track, ties.image, ties.xy)
            if top is not None and top.wrong:
                # said, not refused: a drone holding its heading flies every other strip backwards (Brighton Beach's
                # frames read 180 deg), where the plan's top is right for the strips it is not; a block matched on
                # a wrong plan that falls apart is the adjustment's weakness (components)
                log.warning(f"{project.root}: {top.text()}")
        densified = Densified()
        if s.densify and plan is not None:
            ties, extra, densified = _densify(mt, plan, sparse, ties, s)
            pairs = pairs + extra
        clock.lap("densify")

        ties_per_pair = [(i, j, len(m)) for (i, j), (_, m) in ties.matches.items()]
        components = _components(project, ids, ties_per_pair)
        at = project.at_dir
        at.mkdir(parents=True, exist_ok=True)
        _write_tiepoints(project.tiepoints_path, ids, ties)
        lengths = np.bincount(ties.track) if len(ties.track) else np.zeros(0, int)
        kinds = {}
        for pr in pairs:
            kinds[pr.kind] = kinds.get(pr.kind, 0) + 1
        strength = ties.strength
        hist = track_lengths(ties.track)
        report = MatchReport(
            project=project.name, frames=len(ids), strips=int(len(np.unique(plan.strip))) if plan is not None else 0,
            pairs=len(pairs), pairs_by_kind=kinds, pairs_with_ties=int(sum(t > 0 for _, _, t in ties_per_pair)),
            components=len(components), component_frames=components if len(components) > 1 else [],
            tracks=int(len(lengths)), observations=int(len(ties.track)), inconsistent_tracks_dropped=ties.n_bad,
            tracks_3plus_fraction=float((lengths >= 3).mean()) if len(lengths) else 0.0,
            track_length_histogram={str(n): t for n, t in zip(hist.rays.tolist(), hist.tracks.tolist())},
            ties_per_pair=[PairTies(ids[i], ids[j], t) for i, j, t in ties_per_pair],
            weak_models=[[m.left, m.right] for m in strength.models if m.weak],
            weak_strip_pairs=[[c.strip_a, c.strip_b] for c in strength.cross_strip if c.weak],
            densified=densified, models=strength.models, cross_strip=strength.cross_strip,
            terrain_height_m=plan.terrain_height_m if plan is not None else None,
            image_top_deg=plan.image_top_deg if plan is not None else None,
            seconds=0.0, phase_seconds=clock.phases, feature_cache_hits=mt.feature_cache_hits,
            match_cache_hits=mt.match_cache_hits, settings=resolved.record(),
        )
        if plan is not None:
            plot_block(at / "connectivity.png", plan, ties_per_pair, strength)
        else:
            plot_pair_graph(at / "connectivity.png", ids, ties_per_pair, components)
        clock.lap("output")  # the report's own writing is left out of its numbers (milliseconds)
        report.seconds = round(time.perf_counter() - t0, 2)
        write_text_atomic(project.connectivity_path, json.dumps(dataclasses.asdict(report), indent=1) + "\n")
        log.info(f"{report.frames} frames, {report.pairs} pairs, {report.tracks} tracks, {report.observations} "
                 f"observations, {counted(report.components, 'component')}, "
                 f"{counted(len(report.weak_models), 'weak model')} -> {project.tiepoints_path}")
        if len(components) > 1:  # (new-user trial s51: NGI without its terrain height; only `adjust` said so)
            parts = "; ".join(", ".join(c[:4]) + (f" and {len(c) - 4} more" if len(c) > 4 else "") for c in components)
            log.warning(f"{project.tiepoints_path}: the block falls apart into {len(components)} parts that no tie "
                        f"point connects ({parts}); each is adjusted with a datum of its own, or left out without "
                        "one" + (". Check [flight] mean_terrain_height_m (the pairs are chosen by the footprints on "
                         "it) and at/connectivity.png" if plan is not None else ": at/connectivity.png shows them"))
        return report


def _tracks(sparse, dense, matches, complete_px: float | None = None, size_px=None):
    """Tracks over the union of sparse and dense keypoints (dense ones that repeat a sparse keypoint
    within 0.5 px are merged with it, so one image point never appears twice); with ``complete_px``
    extended into the frames of verified pairs where they were missed (``complete_tracks``, tolerance in
    full-resolution px)."""
    n_img = len(sparse)
    xy_all, rep_all, dense_map, sparse_map, dense_new = [], [], {}, {}, {}
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
            dense_new[i] = ~same
            if complete_px is not None:
                rep_all.append(np.concatenate([sparse_map[i], len(xs) + coincident(new)]))
        else:
            xy_all.append(xs)
            if complete_px is not None:
                rep_all.append(sparse_map[i])
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
    if complete_px is not None:
        desc_all = _NodeDescriptors(sparse, dense, dense_new)
        track, image, kp, n_added = complete_tracks(track, image, kp, node_xy=xy_all, node_desc=desc_all,
                                                    node_rep=rep_all, pair_links=pm, size_px=size_px,
                                                    tol_px=complete_px)
        log.info(f"track completion: {n_added} observations added")
    xy = np.array([xy_all[i][k] for i, k in zip(image, kp)]).reshape(-1, 2)
    return track, image, xy, n_bad


class _NodeDescriptors:
    """The descriptors of every frame's track nodes (its sparse keypoints, then its dense ones that are no sparse
    keypoint), read from the feature cache when a frame is asked for and kept for the last ``keep`` frames: memory
    follows a few frames, not the block."""

    def __init__(self, sparse: list, dense: dict, dense_new: dict, keep: int = 8):
        self.sparse, self.dense, self.dense_new, self.keep = sparse, dense, dense_new, keep
        self._recent: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.sparse)

    def __getitem__(self, i: int) -> np.ndarray:
        d = self._recent.pop(i, None)
        if d is None:
            d = self.sparse[i].descriptors()
            if i in self.dense:
                d = np.vstack([d, self.dense[i].descriptors()[self.dense_new[i]]])
            if len(self._recent) >= self.keep:
                self._recent.pop(next(iter(self._recent)))  # the least recently used
        self._recent[i] = d
        return d
