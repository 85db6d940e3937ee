"""Approximate orientations of a block without GNSS, from its images, brought into the project CRS by its control.

1. **Relative orientation** (``relative_orientation``): pycolmap's incremental mapper on the project's own tie
   points (``at/tiepoints.csv``: every frame's measurements become its keypoints, every pair of frames sharing
   tracks a verified match list with its essential matrix). The camera is the project's (focal length and
   principal point held, the distortion refined, so that a lens without calibration does not bend the model).
   Deterministic: seeded RANSAC and mapper, one thread. The result is a model in an arbitrary frame: origin,
   scale and orientation unknown. It is cached in ``work/relative/`` under the hash of the tie points and the
   camera (a re-run, a leave-one-out run, reads it back).
2. **Datum from the control** (``georeference``): the control points are intersected in the model from their
   image measurements and a similarity takes the model onto their given coordinates, found robustly (least
   median of squares over all minimal sets, then a least-squares fit of the points within 2.5 robust sigmas):

   - at least 3 points with plan and height (``full``, not on one line): a 3D similarity (7 parameters);
   - else at least 2 with plan coordinates: the model is levelled first, taking the tie points' mean plane as
     horizontal (the ground under a small block is level on average; a near-nadir kite or drone frame hangs
     several degrees off the vertical), then a 2D similarity gives plan, scale and rotation about the vertical.
     The heights are not measured: height 0 is the plan control points' median ground (or the median offset of
     the height control points, when there are some), their scale that of the plan;
   - else no datum: ``NoDatum`` names what is missing; the model stays in its local frame.

   Before that, each control point's rays are checked against each other in the model (``ray_blunders``), where
   no control pulls them: a measurement that lies far (``ray_limit_px``) from where the point's other rays put it
   in its frame, while those agree, is on another target or under the wrong name; it is left out of the datum and
   of the adjustment, and named. With few targets and no GNSS the control makes the datum, and such a ray, left
   to the adjustment, bends the block towards it until the data snooping blames the good targets (the Coal Oil
   Point kite with gcp04's label on gcp00 in IMG_0031: 6 of 9 good targets out, gcp04 kept).

The result (``ImageApproximations``) holds the approximate exterior orientations in the project CRS, for the
bundle adjustment (``aerotri.adjust.pipeline``), and a statement of the datum for the console and the report.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import itertools
import json
import logging
import math
import os
import sys
from pathlib import Path

import numpy as np

from aerotri.adjust.check_points import intersect
from aerotri.adjust.datum import umeyama
from aerotri.core.atomic import atomic_path, scratch_dir, write_text_atomic
from aerotri.core.errors import InputError
from aerotri.geom.camera import Camera
from aerotri.geom.eo import ExteriorOrientations
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.observations import ControlPoints, ImageObservations
from aerotri.geom.rotation import FLIP_YZ, opk_from_matrix

log = logging.getLogger(__name__)

RELATIVE_VERSION = 2  # part of the cache key: a new version of this code does not read older models
MIN_PAIR_TIES = 15  # fewest common tie points that make a frame pair a match of the mapper
INLIER_SIGMAS = 2.5  # control points within this many robust sigmas of the similarity are used
MAX_MINIMAL_SETS = 20000  # minimal sets tried by the least median of squares (all of them when fewer)
MODEL_PRECISION = 2e-3  # floor of the image model's precision at the control points, a share of the flying height
MIN_IMAGES_DISTORTION = 5  # the mapper's model refines the lens distortion in a last bundle from this many frames


class NoDatum(InputError):
    """Too little control to bring the image model into the project CRS."""


@dataclasses.dataclass(frozen=True)
class RelativeBlock:
    """The block as the images alone orient it: a model frame of arbitrary origin, scale and orientation."""

    image_id: tuple[str, ...]  # registered frames, sorted
    centre: np.ndarray  # (N, 3) projection centres (model units)
    R_cv: np.ndarray  # (N, 3, 3) computer-vision camera axes -> model axes
    cal: np.ndarray  # (9,) Cal3DS2 of the mapper's camera (fx fy s u0 v0 k1 k2 p1 p2, px)
    points: np.ndarray  # (P, 3) the tie points the mapper triangulated (model units)
    unregistered: tuple[str, ...]  # frames the mapper could not orient
    reprojection_px: float  # the mapper's mean reprojection error

    def up(self) -> np.ndarray:
        """Unit normal of the tie points' mean plane, on the cameras' side (model axes)."""
        return level_normal(self.points, self.centre)

    def view_off_up_deg(self) -> float:
        """Angle between the frames' mean viewing direction and the plane normal's opposite (degrees)."""
        view = self.R_cv[:, :, 2].mean(axis=0)
        view /= np.linalg.norm(view)
        return float(np.degrees(np.arccos(np.clip(-view @ self.up(), -1.0, 1.0))))


@dataclasses.dataclass(frozen=True)
class ImageDatum:
    """How the image model was brought into the project CRS."""

    kind: str  # "3d" (similarity on full control) or "plan" (levelled, plan similarity)
    scale: float  # model units -> metres
    R: np.ndarray  # (3, 3) model axes -> local ENU axes
    t_m: np.ndarray  # (3,) local ENU = scale R X + t
    used: tuple[str, ...]  # control points of the similarity
    rejected: tuple[tuple[str, float], ...]  # (id, residual m) of points beyond the robust limit
    residual_m: dict  # id -> residual (plan or 3D length, m) of every intersected control point
    height_m: dict  # id -> height (local ENU, m) of every intersected control point in the transformed model
    not_intersected: tuple[str, ...]  # control points with fewer than 2 usable rays in registered frames
    view_off_vertical_deg: float  # the frames' mean viewing direction from the vertical, after the transform
    height_points: int = 0  # "plan": control points with heights that gave the height offset (0: none)
    left_out_rays: tuple[tuple[str, str, float], ...] = ()  # (point, frame, px off its other rays): ray_blunders

    def apply(self, xyz_model: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(xyz_model) @ self.R.T + self.t_m

    def statement(self) -> str:
        """One paragraph for the console and the report: what the datum rests on."""
        rms = _rms_of(self.residual_m, self.used)
        rej = "; ".join(f"{p} ({r:.2f} m)" for p, r in self.rejected)
        head = (f"approximate orientations from the images (pycolmap), brought into the project CRS by "
                f"{len(self.used)} control points ({'plan' if self.kind == 'plan' else '3D'} RMS {rms:.2f} m)"
                + (f"; left out of that similarity as off by more than {INLIER_SIGMAS:g} robust sigmas: {rej} (with "
                   "the data snooping held out of the adjustment at first, then tested against the block the others "
                   "hold)" if rej else ""))
        if self.left_out_rays:
            head += ("; " + left_out_rays_text(self.left_out_rays))
        if self.kind == "3d":
            return head + "."
        return (head + ". The control has no measured heights: plan, scale and rotation about the vertical come "
                "from it; the vertical is the normal of the tie points' mean plane (the ground taken as level on "
                f"average; the frames' mean viewing direction is {self.view_off_vertical_deg:.1f} deg from it) and "
                + (f"the height offset the median of the {self.height_points} control points with heights, so the "
                   "heights are measured at those points only." if self.height_points else
                   "height 0 is the control points' median ground, so the heights are relative, not measured."))


@dataclasses.dataclass(frozen=True)
class ImageApproximations:
    """Approximate exterior orientations of the registered frames (project CRS) and their datum."""

    eo: ExteriorOrientations
    datum: ImageDatum
    relative: RelativeBlock
    frame: LocalFrame  # the local ENU frame of ``datum``

    def control_heights(self, control: ControlPoints) -> ModelHeights:
        """The heights (project CRS) of the control points intersected in the model (with the mapper's camera),
        in ``control``'s order."""
        ids = [str(pid) for pid in control.id if str(pid) in self.datum.height_m]
        if not ids:
            return ModelHeights()
        xyz = np.array([x for pid, x in zip(control.id, control.xyz_m) if str(pid) in self.datum.height_m], float)
        loc = self.frame.to_local(xyz)
        loc[:, 2] = [self.datum.height_m[i] for i in ids]
        return ModelHeights(tuple(ids), self.frame.to_map(loc)[:, 2].astype(float))


@dataclasses.dataclass(frozen=True)
class ModelHeights:
    """The heights (project CRS, m) the image model gives the control points it intersected: ``point_id`` and
    ``height_m`` beside it (none for a block with GNSS or given orientations)."""

    point_id: tuple[str, ...] = ()
    height_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def heights_of(self, ids) -> np.ndarray:
        """The model height of each of ``ids``, NaN for a point the model did not intersect."""
        row = {pid: k for k, pid in enumerate(self.point_id)}
        return np.array([self.height_m[row[str(i)]] if str(i) in row else np.nan for i in ids], float)


# -- relative orientation -----------------------------------------------------------------------------
def _tracks(ties: ImageObservations, image_ids: list[str]):
    """(image index, keypoint index within its image, track index) of every measurement in ``image_ids``."""
    index = {k: i for i, k in enumerate(image_ids)}
    keep = np.array([i in index for i in ties.image_id], dtype=bool)
    img = np.array([index[i] for i in ties.image_id[keep]], dtype=int)
    _, track = np.unique(ties.point_id[keep].astype(str), return_inverse=True)
    kp = np.zeros(len(img), dtype=int)
    for i in range(len(image_ids)):
        sel = np.flatnonzero(img == i)
        kp[sel] = np.arange(len(sel))
    return keep, img, kp, track


def _pair_matches(img, kp, track) -> dict[tuple[int, int], np.ndarray]:
    """Keypoint index pairs of every frame pair (i < j) that shares tracks."""
    order = np.lexsort((img, track))
    t, i, k = track[order], img[order], kp[order]
    bounds = np.flatnonzero(np.diff(t)) + 1
    pairs: dict[tuple[int, int], list] = {}
    for a, b in zip(np.r_[0, bounds], np.r_[bounds, len(t)]):
        for u, v in itertools.combinations(range(a, b), 2):
            if i[u] != i[v]:  # images sorted within a track: i[u] < i[v]
                pairs.setdefault((int(i[u]), int(i[v])), []).append((k[u], k[v]))
    return {p: np.array(m, dtype=np.uint32) for p, m in sorted(pairs.items())}


def _colmap_camera(cal: np.ndarray, camera: Camera):
    import pycolmap

    # COLMAP's pixel origin is the corner of the top-left pixel (ours its centre): +0.5
    return pycolmap.Camera(model="OPENCV", width=camera.width, height=camera.height,
                           params=[cal[0], cal[1], cal[3] + 0.5, cal[4] + 0.5, *cal[5:9]])


def relative_orientation(ties: ImageObservations, camera: Camera, image_ids: list[str], seed: int = 0,
                         scratch_parent: Path | None = None) -> RelativeBlock:
    """The frames ``image_ids`` oriented from the tie measurements ``ties`` (the camera's pixels) alone by pycolmap's
    incremental mapper; its database goes to a temporary folder in ``scratch_parent`` (default: the system's).
    ``InputError`` when fewer than two frames can be oriented. Deterministic for a given ``seed``."""
    import tempfile

    import pycolmap

    image_ids = sorted(image_ids)
    keep, img, kp, track = _tracks(ties, image_ids)
    xy = camera.calibration_observations(ties.xy_px[keep])
    cal0 = camera.calibration_vector()
    cam = _colmap_camera(cal0, camera)
    pairs = {p: m for p, m in _pair_matches(img, kp, track).items() if len(m) >= MIN_PAIR_TIES}
    if not pairs:
        raise InputError(f"no two frames share {MIN_PAIR_TIES} tie points: the block cannot be oriented from its images "
                         "(run aerotri match; check the overlap)")
    with scratch_dir(scratch_parent or tempfile.gettempdir(), "relative") as tmp, _colmap_log(tmp / "colmap.log"):
        db = pycolmap.Database.open(tmp / "database.db")
        cid = db.write_camera(cam)
        kps = [xy[img == i] + 0.5 for i in range(len(image_ids))]
        for i, name in enumerate(image_ids):
            iid = db.write_image(pycolmap.Image(name=name, camera_id=cid))
            if iid != i + 1:
                raise RuntimeError(f"pycolmap numbered image {name} {iid}, expected {i + 1}")
            db.write_keypoints(iid, kps[i].astype(np.float32))
        tvo = pycolmap.TwoViewGeometryOptions()
        tvo.ransac.random_seed = seed
        tvo.ransac.num_threads = 1
        for (i, j), m in pairs.items():
            db.write_matches(i + 1, j + 1, m)
            tvg = pycolmap.estimate_calibrated_two_view_geometry(cam, kps[i], cam, kps[j], m, tvo)
            db.write_two_view_geometry(i + 1, j + 1, tvg)
        db.close()
        opts = _mapper_options(seed, len(image_ids))
        pycolmap.set_random_seed(seed)
        (tmp / "sparse").mkdir()
        try:
            models = pycolmap.incremental_mapping(tmp / "database.db", tmp, tmp / "sparse", opts)
        except (RuntimeError, ValueError) as exc:  # COLMAP's own checks on a degenerate block
            raise InputError(f"pycolmap could not orient the {len(image_ids)} frames from their tie points: {exc}") from None
        if not models:
            raise InputError(f"pycolmap could not orient any pair of the {len(image_ids)} frames from their tie "
                             "points (too few ties, or too little base between the frames)")
        rec = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
        if rec.num_reg_images() >= MIN_IMAGES_DISTORTION:
            pycolmap.bundle_adjustment(rec, _distortion_options())
    images = sorted(rec.images.values(), key=lambda im: im.name)
    images = [im for im in images if im.has_pose]
    if len(images) < 2:
        raise InputError(f"pycolmap oriented {len(images)} of the {len(image_ids)} frames: too few for a block")
    names = tuple(im.name for im in images)
    cam_r = rec.cameras[images[0].camera_id]
    p = np.asarray(cam_r.params, dtype=float)
    cal = np.array([p[0], p[1], 0.0, p[2] - 0.5, p[3] - 0.5, *p[4:8]])
    R_cv = np.array([im.cam_from_world().rotation.matrix().T for im in images])
    centre = np.array([im.projection_center() for im in images])
    pts = np.array([q.xyz for q in rec.points3D.values()]).reshape(-1, 3)
    return RelativeBlock(names, centre, R_cv, cal, pts, tuple(sorted(set(image_ids) - set(names))),
                         float(rec.compute_mean_reprojection_error()))


@contextlib.contextmanager
def _colmap_log(path: Path):
    """COLMAP's messages (glog, on the process's stderr) into ``path`` while the block runs, then to this module's
    debug log: the console stays quiet."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "wb") as f:
        os.dup2(f.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
    for line in Path(path).read_text(errors="replace").splitlines():
        log.debug(f"pycolmap: {line}")


def _mapper_options(seed: int, n_images: int):
    import pycolmap

    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = 1  # deterministic
    o.random_seed = seed
    o.mapper.random_seed = seed
    o.triangulation.random_seed = seed
    o.extract_colors = False
    o.multiple_models = True
    o.min_model_size = min(3, n_images)
    # our ties are verified already and may be sparse (a few hundred per frame): lower limits than for raw SIFT
    o.mapper.init_min_num_inliers = 50
    o.mapper.abs_pose_min_num_inliers = 15
    # the project's camera held while the frames are added (a flat block cannot tell focal length and principal
    # point from the flying height and the attitudes; distortion from two frames is noise); the distortion is
    # refined in one last bundle (``_distortion_options``), so that an uncalibrated lens does not bend the model
    o.ba_refine_focal_length = False
    o.ba_refine_principal_point = False
    o.ba_refine_extra_params = False
    o.mapper.abs_pose_refine_focal_length = False
    o.mapper.abs_pose_refine_extra_params = False
    return o


def _distortion_options():
    import pycolmap

    o = pycolmap.BundleAdjustmentOptions()
    o.refine_focal_length = False
    o.refine_principal_point = False
    o.refine_extra_params = True
    o.print_summary = False
    o.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY  # the mapper's outliers
    o.ceres.solver_options.num_threads = 1
    return o


def cache_key(ties_path: Path, camera: Camera, seed: int) -> str:
    """The hash of what the relative orientation depends on: the tie points file, the camera, the seed, the code."""
    h = hashlib.sha256(Path(ties_path).read_bytes())
    h.update(json.dumps({"camera": camera.to_dict(), "seed": seed, "version": RELATIVE_VERSION},
                        sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


def cached_relative_orientation(work_dir: Path, ties_path: Path, ties: ImageObservations, camera: Camera,
                                image_ids: list[str], seed: int = 0) -> RelativeBlock:
    """``relative_orientation``, read from ``work_dir/relative/model.npz`` when the tie points and the camera did
    not change (written there otherwise)."""
    key = cache_key(ties_path, camera, seed)
    path = Path(work_dir) / "relative" / "model.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["key"]) == key and list(z["all_images"]) == sorted(image_ids):
                    return RelativeBlock(tuple(z["image_id"].tolist()), z["centre"], z["R_cv"], z["cal"], z["points"],
                                         tuple(z["unregistered"].tolist()), float(z["reprojection_px"]))
        except (OSError, KeyError, ValueError) as exc:  # a damaged cache is made again
            log.debug(f"{path}: not read ({exc}); orienting again")
    rel = relative_orientation(ties, camera, image_ids, seed, scratch_parent=path.parent)
    with _outliving_the_command(path), atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, key=np.array(key), all_images=np.array(sorted(image_ids)), image_id=np.array(rel.image_id),
                     centre=rel.centre, R_cv=rel.R_cv, cal=rel.cal, points=rel.points,
                     unregistered=np.array(rel.unregistered, dtype=str), reprojection_px=rel.reprojection_px)
    return rel


# -- datum --------------------------------------------------------------------------------------------
def level_normal(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Unit normal of the robust mean plane of ``points`` (N, 3), pointing to the side of ``centres``.

    Least squares on the points within 3 robust sigmas of the previous plane (three rounds), so that trees,
    roofs and wrong points do not tilt it."""
    p = np.asarray(points, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        p = np.asarray(centres, dtype=float)  # no points: the cameras' plane (a flight at one height)
    keep = np.ones(len(p), dtype=bool)
    n = np.array([0.0, 0.0, 1.0])
    for _ in range(3):
        c = np.median(p[keep], axis=0)
        _, V = np.linalg.eigh(np.cov((p[keep] - c).T))
        n = V[:, 0]
        d = (p - c) @ n
        s = 1.4826 * np.median(np.abs(d - np.median(d[keep])))
        if s <= 0:
            break
        keep = np.abs(d - np.median(d[keep])) <= 3.0 * s
    if np.mean((np.asarray(centres) - np.median(p, axis=0)) @ n) < 0:
        n = -n
    return n


def rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that turns unit vector ``a`` onto unit vector ``b`` (the shortest one)."""
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


@dataclasses.dataclass(frozen=True)
class RobustSimilarity:
    scale: float
    R: np.ndarray
    t: np.ndarray
    inlier: np.ndarray  # (n,) bool
    residual: np.ndarray  # (n,) lengths of the residual vectors
    sigma: float  # robust sigma of the residual lengths (0 without redundancy)


def robust_similarity(src: np.ndarray, dst: np.ndarray, min_sigma: float = 0.0, min_sigma_src: float = 0.0,
                      seed: int = 0) -> RobustSimilarity:
    """``dst ~ s R src + t`` (2D or 3D) robust to blunders: least median of squares over the minimal sets (pairs
    in 2D, triples in 3D; all of them, or ``MAX_MINIMAL_SETS`` drawn with ``seed``), the median taken over the
    points outside the set; then least squares on the points within ``INLIER_SIGMAS`` robust sigmas of that fit
    (1.4826 x the median residual, at least ``min_sigma`` in ``dst`` units and ``min_sigma_src`` in ``src`` units:
    the precision of the given points and of the model they are fitted to)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    n, dim = src.shape
    m = dim  # points of a minimal set: 2 in plan, 3 in space
    sets = itertools.combinations(range(n), m)
    total = math.comb(n, m)
    if total > MAX_MINIMAL_SETS:
        rng = np.random.default_rng(seed)
        sets = (tuple(rng.choice(n, m, replace=False)) for _ in range(MAX_MINIMAL_SETS))
    best, best_med = None, np.inf
    for idx in sets:
        idx = list(idx)
        a = src[idx] - src[idx].mean(0)
        if np.linalg.svd(a, compute_uv=False)[dim - 2 if dim == 3 else 0] < 1e-9 * max(1.0, np.abs(a).max()):
            continue  # coincident or collinear
        s, R, t = umeyama(src[idx], dst[idx])
        if not s > 0:
            continue
        r = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
        out = np.delete(r, idx)  # the set's own residuals are ~0 whatever the fit
        med = float(np.median(out**2)) if len(out) else 0.0
        if med < best_med:
            best, best_med = (s, R, t), med
    if best is None:
        raise NoDatum("the control points are coincident or on one line in the image model")
    if n > m:
        s, R, t = best
        sigma = max(1.4826 * math.sqrt(best_med), min_sigma, s * min_sigma_src)
        inlier = np.linalg.norm(s * src @ R.T + t - dst, axis=1) <= INLIER_SIGMAS * sigma
        if inlier.sum() >= m:
            s, R, t = umeyama(src[inlier], dst[inlier])
    else:
        sigma, inlier = 0.0, np.ones(n, dtype=bool)
        s, R, t = umeyama(src, dst)
    r = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
    return RobustSimilarity(float(s), R, t, inlier, r, float(sigma))


def _collinear(xy: np.ndarray) -> bool:
    a = np.asarray(xy, float) - np.mean(xy, axis=0)
    sv = np.linalg.svd(a[:, :2], compute_uv=False)
    return len(a) < 3 or sv[1] < 0.05 * sv[0]


def _rms_of(residual: dict, ids) -> float:
    v = [residual[i] for i in ids if i in residual]
    return float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")


def left_out_rays_text(rays) -> str:
    """The sentence that names the control measurements ``ray_blunders`` left out: (point, frame, px) each."""
    return ("control measurements left out before the adjustment, each far from where the point's other rays put "
            "it in the image model (on another target or under the wrong name?): "
            + ", ".join(f"{p} in {i} ({r:,.0f} px)" for p, i, r in rays))


def ray_limit_px(rel: RelativeBlock) -> float:
    """How far (px) a control measurement may lie from the point's other rays in the image model:
    ``INLIER_SIGMAS`` times the model's precision floor (``MODEL_PRECISION`` of the flying height, in pixels of
    the focal length), and at least 10 times the mapper's mean reprojection error."""
    return float(max(INLIER_SIGMAS * MODEL_PRECISION * rel.cal[0], 10.0 * rel.reprojection_px))


def ray_blunders(xy_px, point_index, image_index, rel: RelativeBlock, n_points: int,
                 limit_px: float) -> list[tuple[int, float]]:
    """(index, px off) of the measurements (rows of ``xy_px``, calibration pixels) that are blunders by the image model
    alone: of a point whose rays do not agree (some residual of their intersection above ``limit_px``, or the
    intersection behind a camera), the one ray whose omission leaves the others agreeing (2 or more, in front
    of their cameras) while it lies more than ``limit_px`` from where they put the point. Exactly one such ray, or
    none is named (a point with two rays that disagree cannot say which: the adjustment tests it)."""
    from aerotri.adjust.collinearity import project_cv

    def residuals(k):
        X, _ = intersect(xy_px[k], np.zeros(len(k), dtype=int), image_index[k], rel.centre, rel.R_cv, rel.cal,
                         n_points=1)
        if not np.all(np.isfinite(X[0])):
            return X[0], None
        uv, pc = project_cv(np.repeat(X, len(k), 0), rel.centre[image_index[k]], rel.R_cv[image_index[k]], rel.cal)
        if np.any(pc[:, 2] <= 0):
            return X[0], None
        return X[0], np.linalg.norm(uv - xy_px[k], axis=1)

    bad = []
    for j in range(n_points):
        k = np.flatnonzero(point_index == j)
        if len(k) < 3:
            continue
        _, r = residuals(k)
        if r is not None and r.max() <= limit_px:
            continue
        found = []
        for q in range(len(k)):
            rest = np.delete(k, q)
            X, r = residuals(rest)
            if r is None or r.max() > limit_px:
                continue
            uv, pc = project_cv(X[None], rel.centre[image_index[k[q]]][None], rel.R_cv[image_index[k[q]]][None],
                                rel.cal)
            off = float(np.linalg.norm(uv[0] - xy_px[k[q]])) if pc[0, 2] > 0 else float("inf")
            if off > limit_px:
                found.append((int(k[q]), off))
        if len(found) == 1:
            bad.append(found[0])
    return bad


def is_left_out_ray(obs: ImageObservations, rays) -> np.ndarray:
    """Which measurements of ``obs`` are among ``rays`` ((point, frame, px) of ``control_ray_blunders``)."""
    out = {(p, i) for p, i, _ in rays}
    return np.array([(p, i) in out for p, i in zip(obs.point_id.tolist(), obs.image_id.tolist())], dtype=bool)


def control_ray_blunders(rel: RelativeBlock, control_obs: ImageObservations,
                         camera: Camera) -> tuple[tuple[str, str, float], ...]:
    """(point, frame, px off) of the measurements of ``control_obs`` (the camera's pixels; control and check points)
    in oriented frames that ``ray_blunders`` finds, with ``ray_limit_px``."""
    index = {k: i for i, k in enumerate(rel.image_id)}
    m = np.array([i in index for i in control_obs.image_id], dtype=bool)
    obs = control_obs.subset(m)
    if not len(obs):
        return ()
    _, opt = np.unique(obs.point_id.astype(str), return_inverse=True)
    oim = np.array([index[i] for i in obs.image_id], dtype=int)
    found = ray_blunders(camera.calibration_observations(obs.xy_px), opt, oim, rel, int(opt.max()) + 1,
                         ray_limit_px(rel))
    return tuple((str(obs.point_id[k]), str(obs.image_id[k]), off) for k, off in found)


def georeference(rel: RelativeBlock, control: ControlPoints, control_obs: ImageObservations, camera: Camera,
                 frame: LocalFrame, seed: int = 0) -> ImageDatum:
    """The similarity from the model of ``rel`` into ``frame`` (the project CRS's local ENU frame) by the control
    points (kinds full, horizontal, height; check points are not used). ``control_obs`` in the camera's pixels.
    ``NoDatum`` when the control cannot fix it (fewer than 2 plan points intersected in the model)."""
    left_out = control_ray_blunders(rel, control_obs, camera)  # check points' too: they are left out alike
    if left_out:
        control_obs = control_obs.subset(~is_left_out_ray(control_obs, left_out))
    use = np.isin(control.kind, ["full", "horizontal", "height"])
    control = control.subset(use)
    index = {k: i for i, k in enumerate(rel.image_id)}
    pid = {k: i for i, k in enumerate(control.id)}
    m = np.array([p in pid and i in index for p, i in zip(control_obs.point_id, control_obs.image_id)], dtype=bool)
    obs = control_obs.subset(m)
    opt = np.array([pid[p] for p in obs.point_id], dtype=int)
    oim = np.array([index[i] for i in obs.image_id], dtype=int)
    xy = camera.calibration_observations(obs.xy_px)
    X = np.full((len(control), 3), np.nan)
    if len(obs):
        X, _ = intersect(xy, opt, oim, rel.centre, rel.R_cv, rel.cal, n_points=len(control))
    rays = np.bincount(opt, minlength=len(control))
    ahead = np.ones(len(control), dtype=bool)
    if len(obs):  # in front of every camera that sees it
        depth = np.einsum("kj,kj->k", np.nan_to_num(X[opt]) - rel.centre[oim], rel.R_cv[oim][:, :, 2])
        ahead = np.bincount(opt, weights=(depth <= 0).astype(float), minlength=len(control)) == 0
    ok = (rays >= 2) & np.all(np.isfinite(X), axis=1) & ahead
    not_int = tuple(control.id[~ok].tolist())
    given = frame.to_local(control.xyz_m) if len(control) else np.zeros((0, 3))
    plan = ok & np.isin(control.kind, ["full", "horizontal"])
    full = ok & (control.kind == "full")
    min_sigma = float(np.median(np.linalg.norm(control.sigma_m[:, :2], axis=1))) if len(control) else 0.0
    up = rel.up()
    # the image model is approximate (its camera a nominal one): a floor of its precision, a share of the
    # flying height, so that the robust limit does not take the model's own errors for blunders
    height_model = float(np.median((rel.centre - np.median(rel.points, axis=0)) @ up)) if len(rel.points) else 0.0
    min_model = MODEL_PRECISION * abs(height_model)
    if full.sum() >= 3 and not _collinear(given[full]):
        rs = robust_similarity(X[full], given[full], min_sigma=min_sigma, min_sigma_src=min_model, seed=seed)
        kind, scale, R, t = "3d", rs.scale, rs.R, rs.t
        ids = control.id[full]
        residual = dict(zip(ids.tolist(), rs.residual.tolist()))
        used, rejected = ids[rs.inlier], [(p, r) for p, r, k in zip(ids, rs.residual, rs.inlier) if not k]
    elif plan.sum() >= 2:
        L = rotation_onto(up, np.array([0.0, 0.0, 1.0]))
        a = X @ L.T
        rs = robust_similarity(a[plan, :2], given[plan, :2], min_sigma=min_sigma, min_sigma_src=min_model, seed=seed)
        kind, scale = "plan", rs.scale
        R = np.eye(3)
        R[:2, :2] = rs.R
        R = R @ L
        ids = control.id[plan]
        residual = dict(zip(ids.tolist(), rs.residual.tolist()))
        used = ids[rs.inlier]
        rejected = [(p, r) for p, r, k in zip(ids, rs.residual, rs.inlier) if not k]
        hz = ok & np.isin(control.kind, ["full", "height"])
        z_model = scale * (X @ R.T)[:, 2]
        # height 0 at the plan points' median ground, unless some points have measured heights
        tz = float(np.median(given[hz, 2] - z_model[hz])) if hz.any() else float(-np.median(z_model[np.isin(control.id, used)]))
        t = np.r_[rs.t, tz]
    else:
        n_plan = int(np.isin(control.kind, ["full", "horizontal"]).sum())
        raise NoDatum(
            f"the image model cannot be brought into the project CRS: {int(plan.sum())} control points with plan "
            f"coordinates are intersected in it (need 2 in plan, or 3 with plan and height); {n_plan} in "
            f"control/points.csv" + (f", not intersected (fewer than 2 rays in oriented frames): "
                                     f"{', '.join(not_int[:10])}" if not_int else ""))
    view = (R @ rel.R_cv[:, :, 2].mean(axis=0))
    off = float(np.degrees(np.arccos(np.clip(-view[2] / np.linalg.norm(view), -1.0, 1.0))))
    if kind == "plan":
        off = rel.view_off_up_deg()
    z_local = (scale * X @ R.T + np.asarray(t, float))[:, 2]
    heights = {str(p): float(z) for p, z, k in zip(control.id, z_local, ok) if k}
    n_height = int(hz.sum()) if kind == "plan" else 0
    return ImageDatum(kind, float(scale), R, np.asarray(t, float), tuple(used.tolist()),
                      tuple((str(p), float(r)) for p, r in rejected), residual, heights, not_int, off, n_height,
                      left_out)


def exterior_orientations(rel: RelativeBlock, datum: ImageDatum, frame: LocalFrame) -> ExteriorOrientations:
    """The model's orientations in the project CRS: centres and omega, phi, kappa (grid axes at each centre)."""
    centre_loc = datum.apply(rel.centre)
    centre_map = frame.to_map(centre_loc)
    R_l2m = np.swapaxes(frame.rotation_local_from_map(centre_map), -1, -2)
    R_map = R_l2m @ (datum.R @ rel.R_cv) @ FLIP_YZ
    opk = np.stack(opk_from_matrix(R_map), axis=-1)
    return ExteriorOrientations(list(rel.image_id), centre_map, opk)


def image_approximations(work_dir: Path, ties_path: Path, ties: ImageObservations, camera: Camera,
                         image_ids: list[str], control: ControlPoints, *, control_obs: ImageObservations, crs,
                         seed: int = 0) -> ImageApproximations:
    """Approximate orientations of a block without GNSS: relative orientation (cached in ``work_dir``) and the
    datum from the control (see the module docstring). ``NoDatum`` (an ``InputError``) with too little control,
    after writing the model's orientations in its local frame to ``work_dir/relative/eo_local.txt``."""
    rel = cached_relative_orientation(work_dir, ties_path, ties, camera, image_ids, seed)
    if rel.unregistered:
        log.warning(f"{ties_path}: pycolmap could not orient {len(rel.unregistered)} of {len(image_ids)} frames from "
                    f"their tie points; they are left out: {', '.join(rel.unregistered[:10])}"
                    + (" ..." if len(rel.unregistered) > 10 else ""))
    anchor = control.xyz_m if len(control) else np.zeros((1, 3))
    frame = LocalFrame.at_centre(crs, anchor)
    try:
        datum = georeference(rel, control, control_obs, camera, frame, seed)
    except NoDatum as exc:
        path = Path(work_dir) / "relative" / "eo_local.txt"
        with _outliving_the_command(path):
            _write_local(path, rel)
        raise NoDatum(f"{exc}. The images alone are oriented in a local frame (arbitrary origin, scale and "
                      f"orientation; z along the tie points' mean plane normal): {path}") from None
    return ImageApproximations(exterior_orientations(rel, datum, frame), datum, rel, frame)


def _outliving_the_command(path: Path):
    """A commit of its own for a file of ``work/relative/`` (the cache, the local-frame orientations): kept when
    the command that writes it fails afterwards, where the command's other outputs are rolled back."""
    from aerotri.core.atomic import commit_outputs

    path.parent.mkdir(parents=True, exist_ok=True)
    return commit_outputs(path.parent, join=False)


def _write_local(path: Path, rel: RelativeBlock) -> None:
    """The relative orientation in its local frame (levelled, in model units), as an EO file with a header."""
    L = rotation_onto(rel.up(), np.array([0.0, 0.0, 1.0]))
    C = (rel.centre - np.median(rel.points, axis=0) if len(rel.points) else rel.centre) @ L.T
    opk = np.stack(opk_from_matrix(L @ rel.R_cv @ FLIP_YZ), axis=-1)
    lines = ["# image_id X Y Z omega phi kappa: a LOCAL frame (pycolmap relative orientation of the tie points):",
             "# origin at the tie points' median, z normal to their mean plane, scale arbitrary (model units);",
             "# not the project CRS: control points (2 in plan, or 3 with height) bring it there"]
    lines += [f"{i} {c[0]:.6f} {c[1]:.6f} {c[2]:.6f} {o[0]:.6f} {o[1]:.6f} {o[2]:.6f}" for i, c, o in zip(rel.image_id, C, opk)]
    write_text_atomic(path, "\n".join(lines) + "\n")
