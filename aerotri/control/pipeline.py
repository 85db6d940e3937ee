"""The ``control`` stage over a project folder: LiDAR corners -> measured control and check points.

Inputs: ``lidar_out/corners.csv`` (``lidarctl corners``), ``at/eo.txt`` (orientations of a first
adjustment with tie points and GNSS), the camera (the self-calibrated one from ``at/report.json``
when present, else ``camera.toml``), ``images/``. Outputs (each written atomically, all after the
whole transfer succeeded): ``control/points.csv``, ``control/image_points.csv``,
``control/transfer.json`` (counts, rejection reasons, per-corner and per-measurement status),
``control/review/review.html`` with ``control/review/chips/``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

from aerotri.control.consistency import check_rays
from aerotri.control.corners import LidarCorners, ManualMeasurements, read_corners, read_manual
from aerotri.control.layout import LayoutTarget, candidate_tiers, empty_target_text, select_control
from aerotri.control.measure import MEASURE_VERSION, Measurement, corner_points, measure_in_image, predict
from aerotri.control.settings import ControlSettings
from aerotri.core.errors import InputError, OptionError
from aerotri.core.log import counted, track
from aerotri.core.atomic import committed
from aerotri.core.project import Project, project_paths
from aerotri.core.resume import file_stamp, resumable, resume_key
from aerotri.core.settings import Resolved, settings_of
from aerotri.geom.camera import BrownCamera, orientations_camera
from aerotri.geom.eo import ExteriorOrientations, read_eo
from aerotri.geom.images import FrameWindows, find_image
from aerotri.geom.local_frame import FramesOnEarth

log = logging.getLogger(__name__)


@dataclasses.dataclass
class TransferResult:
    corners: LidarCorners
    image_ids: list
    measurements: dict  # (corner index, image index) -> Measurement (predicted inside the frame)
    predicted: dict  # (corner index, image index) -> (x_px, y_px)
    rays: dict  # corner index -> RayCheck
    kind: np.ndarray  # per corner: full / height / check / rejected / not_measured
    targets: list[LayoutTarget]  # ``corner``: index into ``corners`` (None: no corner within reach)
    base_m: float
    manual: set  # (corner index, image index) measured manually
    primary: np.ndarray | None = None  # (N,) bool: the set measured anyway (usable + manual); the rest: fallback


@dataclasses.dataclass(frozen=True)
class TransferSummary:
    """Counts and rejection reasons of a control transfer (``summary`` in control/transfer.json)."""

    corners_in_file: int
    corners_measured: int
    measurements_attempted: int
    measurements_accepted_in_image: int
    measurements_rejected_in_image: dict[str, int]  # reason -> count
    rays_dropped_inconsistent: int
    corners_rejected: dict[str, int]  # reason -> count
    too_few_rays_by_cause: dict[str, int]  # in_no_frame / in_one_frame / measured_in_under_two: the corner's
    # predicted position falls in no frame or one frame, or in two or more whose measurements failed
    corners_accepted: int
    corners_measured_fallback: int  # of corners_measured: measured only for empty layout targets
    control_full: int
    control_height: int
    check_points: int
    layout_targets: int
    layout_targets_unfilled: int
    layout_targets_by_tier: dict[str, int]  # candidate set that filled each target (aerotri.control.layout.TIERS)
    selected_rays_min: int
    selected_rays_mean: float
    manual_measurements: int
    base_m: float

    def command_line(self) -> str:
        """The line ``aerotri control`` prints."""
        return (f"{self.corners_accepted} of {self.corners_measured} corners accepted "
                f"({self.measurements_accepted_in_image} of {self.measurements_attempted} image measurements); "
                f"control {self.control_full} full + "
                f"{self.control_height} height, {self.check_points} check points; rejected corners: "
                + (", ".join(f"{k} {n}" for k, n in sorted(self.corners_rejected.items(), key=lambda kv: -kv[1]))
                   or "none"))


@dataclasses.dataclass(frozen=True)
class RejectionRow:
    """One line of the review page's rejection table: ``what`` was rejected (a corner, or one measurement of a
    corner in a frame), the ``reason`` key (control/transfer.json), how many, and what it means."""

    what: str
    reason: str
    count: int
    meaning: str


# What each rejection reason of control/transfer.json means (the review page's table)
CORNER_REJECTIONS = {"too_few_rays": "measured in fewer than two frames",
                     "inconsistent_rays": "the frames' rays do not meet in one point",
                     "lidar_mismatch": "the rays meet away from the LiDAR corner"}
MEASUREMENT_REJECTIONS = {"outside_frame": "the predicted corner lies outside the frame (or too near its edge)",
                          "no_edges": "no roof edges with enough contrast near the prediction",
                          "occluded": "the corner's edges are not seen up to the corner (hidden)",
                          "ambiguous": "another corner-like edge pair in the search window scores almost as well",
                          "poor_edge_fit": "the roof edges fit badly, or the corner lies beyond the search radius"}


def rejection_rows(sm: "TransferSummary") -> tuple[RejectionRow, ...]:
    """The rejected corners (too few rays split by cause) and the rejected image measurements, most first."""
    rows = []
    for reason, n in sorted(sm.corners_rejected.items(), key=lambda kv: -kv[1]):
        rows.append(RejectionRow("corner", reason, n, CORNER_REJECTIONS.get(reason, reason.replace("_", " "))))
        if reason == "too_few_rays":
            rows += [RejectionRow("corner", f"too_few_rays: {cause}", m, f"of those: {TOO_FEW_RAYS_CAUSES[cause]}")
                     for cause, m in sorted(sm.too_few_rays_by_cause.items(), key=lambda kv: -kv[1])]
    rows += [RejectionRow("measurement in a frame", reason, n, MEASUREMENT_REJECTIONS.get(reason, reason.replace("_", " ")))
             for reason, n in sorted(sm.measurements_rejected_in_image.items(), key=lambda kv: -kv[1])]
    return tuple(rows)


@dataclasses.dataclass
class ReviewPage:
    """What ``chips.write_review`` writes: the summary line, the rejection table, a row per corner, the chip PNGs
    by file name."""

    summary: str
    corners: list[dict]
    chips: dict[str, bytes]
    rejections: tuple[RejectionRow, ...] = ()


CONTROL_RESUME_DIR_NAME = "control_resume"  # in work/: the frames' measurements an interrupted transfer finished


def _frame_keys(corners: LidarCorners, camera: BrownCamera, eo: ExteriorOrientations, points, idx: np.ndarray,
                *, images_dir: Path, s: ControlSettings, crs) -> list[str]:
    """Key of each frame's measurements of the corners ``idx`` (``aerotri.core.resume``): the frame's image (name,
    size, modification time) and orientation, the camera, the corners' points in the frames' Cartesian frame and
    roof angles, the measurement settings, the measurement's version (``aerotri.control.measure.MEASURE_VERSION``),
    the CRS and the toolkit's version."""
    import hashlib

    import aerotri

    h = hashlib.sha256()
    for a in (idx, points.xyz, points.along_edges, points.by_sigma, corners.angle_deg[idx]):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    block = {"corners": h.hexdigest(), "camera": repr(camera), "measure": repr(s.measure),
             "crs": crs.to_wkt() if crs is not None else None, "measure_version": MEASURE_VERSION,
             "version": aerotri.__version__}
    keys = []
    for i, iid in enumerate(eo.image_id):
        path = find_image(images_dir, iid)
        keys.append(resume_key({**block, "frame": str(iid), "image": path.name, "stamp": file_stamp(path),
                                "centre_m": eo.centre_m[i].tolist(), "rotation": eo.rotation(i).tolist()}))
    return keys


def _kept_measurements(text: str | None, i: int) -> tuple[dict, dict] | None:
    """The measurements and predictions of frame ``i`` kept as ``_keep_measurements`` wrote them."""
    if text is None:
        return None
    try:
        rows = json.loads(text)
    except ValueError:
        return None
    meas = {(int(r[0]), i): Measurement(*r[3:]) for r in rows}
    pred = {(int(r[0]), i): (r[1], r[2]) for r in rows}
    return meas, pred


def _keep_measurements(resume, key: str, meas: dict, pred: dict) -> None:
    rows = [[k, *pred[(k, i)], *dataclasses.astuple(m)] for (k, i), m in meas.items()]
    resume.put_text(key, ".json", json.dumps(rows))


def _measure_frames(corners: LidarCorners, camera: BrownCamera, *, eo: ExteriorOrientations, frames: FramesOnEarth,
                    images_dir: Path, idx: np.ndarray, manual_k: dict, s: ControlSettings, crs=None,
                    resume=None) -> tuple[dict, dict]:
    """Measurements and predictions {(corner index, image index): ...} of the corners ``idx`` in every frame
    they are predicted in (``frames``: the orientations ``eo`` over the earth), then the manual measurements in place
    of the automatic ones. ``resume`` (``aerotri.core.resume.ResumeFolder``): each frame's measurements are kept
    there as it finishes, and taken from there when an interrupted run kept them (``crs``: the project CRS, in
    their key)."""
    points = corner_points(frames, corners.xyz_m[idx], corners.edge_directions_m()[idx], corners.sigma_m[idx])
    keys = (_frame_keys(corners, camera, eo, points, idx, images_dir=images_dir, s=s, crs=crs)
            if resume is not None else None)
    if resume is not None and resume.path.is_dir():
        k = sum(resume.kept(key, ".json") is not None for key in keys)
        if k:
            log.info(f"control transfer: resumed {k} of {len(keys)} frames an interrupted run finished "
                     f"({resume.path})")
    meas, pred = {}, {}
    for i, iid in enumerate(track(eo.image_id, "control transfer", "frames")):
        kept = _kept_measurements(resume.get_text(keys[i], ".json"), i) if resume is not None else None
        if kept is not None:
            meas.update(kept[0])
            pred.update(kept[1])
            continue
        x, y, d, _, radius = predict(camera, frames, i, points, eo_sigma_px=s.measure.eo_sigma_px,
                                     window_k=s.measure.window_k,
                                     min_radius_px=s.measure.min_radius_px, max_radius_px=s.measure.max_radius_px)
        inside = camera.inside(x, y, margin_px=2.0)
        has_manual = any(i == j for _, j in manual_k)
        if not inside.any() and not has_manual:
            continue
        # windows on demand: the chips of a 106 MP frame, not the frame
        frame_meas, frame_pred = {}, {}
        with FrameWindows(find_image(images_dir, iid), (camera.width, camera.height)) as image:
            for q in np.flatnonzero(inside):
                k = int(idx[q])
                frame_pred[(k, i)] = (float(x[q]), float(y[q]))
                frame_meas[(k, i)] = measure_in_image(image, x[q], y[q], d[q], radius[q], settings=s.measure,
                                                      convex=bool(corners.angle_deg[k] < 180.0))
        meas.update(frame_meas)
        pred.update(frame_pred)
        if resume is not None:
            _keep_measurements(resume, keys[i], frame_meas, frame_pred)
    for (k, i), xy in manual_k.items():
        meas[(k, i)] = Measurement(float(xy[0]), float(xy[1]), True, "manual")
        pred.setdefault((k, i), (float(xy[0]), float(xy[1])))
    return meas, pred


def _check_corners(corners: LidarCorners, camera: BrownCamera, frames: FramesOnEarth, idx: np.ndarray,
                   meas: dict, s: ControlSettings) -> dict:
    """Multi-ray check of every corner in ``idx`` over its accepted image measurements: {corner index: RayCheck}."""
    by_corner: dict[int, list[int]] = {}
    for (k, i), m in meas.items():
        if m.ok:
            by_corner.setdefault(k, []).append(i)
    rays = {}
    for k in idx:
        imgs = sorted(by_corner.get(int(k), []))
        xy = np.array([[meas[(k, i)].x_px, meas[(k, i)].y_px] for i in imgs]).reshape(-1, 2)
        rays[int(k)] = check_rays(camera, frames, imgs, xy, corners.xyz_m[k], corners.sigma_m[k],
                                  tol_px=s.tol_px, sigma_px=s.image_sigma_px, datum_sigma_m=s.datum_sigma_m,
                                  alpha=s.alpha)
        rays[int(k)].images = imgs
    return rays


def _select(corners: LidarCorners, camera: BrownCamera, eo: ExteriorOrientations, primary: np.ndarray, rays: dict,
            *, s: ControlSettings, frames: FramesOnEarth) -> tuple[np.ndarray, list[LayoutTarget], float]:
    """Kind of every corner (full / height / check among the accepted ones of the ``primary`` set,
    candidate for accepted fallback corners not chosen, rejected, not_measured), the layout targets
    (``corner``: index into ``corners``) and the base (m)."""
    measured = np.array(sorted(rays), dtype=int)
    accepted = np.array([k for k in measured if rays[int(k)].ok], dtype=int)
    kind = np.full(len(corners), "not_measured", dtype=object)
    kind[measured] = "rejected"
    targets, base = [], float("nan")
    first = accepted[primary[accepted]] if len(accepted) else accepted
    if len(corners):
        n_frames = np.array([rays[int(k)].kept.sum() for k in accepted], dtype=int)
        # the ground plane of the targets from the accepted primary corners alone (fallback corners must not
        # move the targets); without any, from all primary corners, so the targets can still fall back
        zs = corners.xyz_m[first if len(first) else (np.flatnonzero(primary) if primary.any() else slice(None)), 2]
        ground_z = float(np.median(zs))
        worst = np.array([np.max(rays[int(k)].residual_px[rays[int(k)].kept]) for k in accepted])
        tier = candidate_tiers(n_frames, primary[accepted], corners.roof[accepted], s.layout.min_frames)
        kk, targets, base = select_control(corners.xyz_m[accepted, :2].reshape(-1, 2), corners.score[accepted],
                                           n_frames, camera=camera, centres_m=eo.centre_m, Rs=eo.rotations(),
                                           ground_z_m=ground_z, rule=s.layout, residual_ratio=worst / s.tol_px,
                                           tier=tier, check=primary[accepted], frames=frames)
        kind[accepted] = kk
        targets = [t if t.corner is None else dataclasses.replace(t, corner=int(accepted[t.corner])) for t in targets]
    return kind, targets, base


def _near_unfilled_targets(corners: LidarCorners, targets: list[LayoutTarget], todo: np.ndarray) -> np.ndarray:
    """Indices of the corners in ``todo`` within the search radius of a target the rule itself did not fill
    (no corner, or one from a later fallback tier than those the corners in ``todo`` may give)."""
    near = np.zeros(len(corners), bool)
    for t in targets:
        if t.tier != "usable":
            near |= np.hypot(*(corners.xyz_m[:, :2] - [t.target_x_m, t.target_y_m]).T) <= t.search_radius_m
    return np.flatnonzero(near & todo)


# Why a corner has too few rays: its predicted position falls in no frame, in one frame, or in two or more
# whose measurements failed in all but one (keys of TransferSummary.too_few_rays_by_cause).
TOO_FEW_RAYS_CAUSES = {"in_no_frame": "in no frame", "in_one_frame": "seen in one frame only",
                       "measured_in_under_two": "measured in fewer than two of the frames it is seen in"}


def too_few_rays_cause(frames: Counter, k: int) -> str:
    """The ``TOO_FEW_RAYS_CAUSES`` key of corner ``k``; ``frames``: frames each corner's prediction falls in."""
    return {0: "in_no_frame", 1: "in_one_frame"}.get(frames.get(k, 0), "measured_in_under_two")


def why_empty(res: "TransferResult", t: LayoutTarget, s: ControlSettings) -> str:
    """One line for the control report: why the layout target ``t`` got no corner (counts of the
    corners within its search radius by what became of them)."""
    c = res.corners
    d = np.hypot(*(c.xyz_m[:, :2] - [t.target_x_m, t.target_y_m]).T)
    r = t.search_radius_m
    near = np.flatnonzero(d <= r)
    if not len(near):
        nearest = f" (nearest {d.min():.1f} m away)" if len(d) else ""
        return f"no LiDAR roof corner within {r:.1f} m of the target{nearest}"
    frames = Counter(k for k, _ in res.predicted)
    fate, in_image = Counter(), Counter()
    tier = {}
    acc = [k for k in near if k in res.rays and res.rays[k].ok]
    if acc:
        n = np.array([res.rays[k].kept.sum() for k in acc])
        tier = dict(zip(acc, candidate_tiers(n, res.primary[acc], c.roof[acc], s.layout.min_frames)))
    for k in near:
        k = int(k)
        ray = res.rays.get(k)
        if ray is None:
            fate["not measured (not marked usable" + (")" if s.layout.fallback else "; fallback off)")] += 1
        elif ray.reason == "too_few_rays":
            cause = too_few_rays_cause(frames, k)
            fate[TOO_FEW_RAYS_CAUSES[cause]] += 1
            if cause == "measured_in_under_two":
                in_image.update(m.reason for (kk, _), m in res.measurements.items() if kk == k and not m.ok)
        elif not ray.ok:
            fate[f"rejected by consistency ({ray.reason.replace('_', ' ')})"] += 1
        elif res.kind[k] in ("full", "height"):
            fate["control for another target"] += 1
        elif tier.get(k, -1) < 0:
            fate[f"accepted in {int(ray.kept.sum())} frames only (pitched roof or below {s.layout.min_frames})"] += 1
        elif tier[k] > 0 and not s.layout.fallback:
            fate["a fallback candidate (fallback off)"] += 1
        else:  # cannot happen: an eligible free corner within reach is chosen
            fate["eligible but not chosen"] += 1
    parts = []
    for what, n in fate.most_common():
        if what == TOO_FEW_RAYS_CAUSES["measured_in_under_two"] and in_image:
            what += " (" + ", ".join(f"{reason.replace('_', ' ')} {m}" for reason, m in in_image.most_common(3)) + ")"
        parts.append(f"{n} {what}")
    return f"{counted(len(near), 'LiDAR corner')} within {r:.1f} m: " + "; ".join(parts)


def transfer_control(corners: LidarCorners, camera: BrownCamera, eo: ExteriorOrientations, images_dir,
                     settings: ControlSettings | None = None,
                     manual: ManualMeasurements | None = None, *, crs, resume=None) -> TransferResult:
    """Measure the corners in every frame, check them across frames, select control by the layout rule.

    ``crs``: the project CRS of the corners and orientations, whose map coordinates the frames see over the earth
    (``FramesOnEarth``); None, given explicitly: a Cartesian frame (a folder without project.toml, local metres).

    When a layout target gets no usable corner in ``min_frames`` frames and ``settings.layout.fallback``
    is on, the corners not measured yet (those lidarctl did not mark usable) within its search radius are
    measured and checked the same way, then the selection is repeated with the fallback tiers
    (``aerotri.control.layout``); targets filled by the rule itself keep their corner.
    """
    s = settings or ControlSettings()
    cid = {str(p): k for k, p in enumerate(corners.id)}
    manual_k = {} if manual is None else {(cid[p], int(i)): tuple(xy) for p, i, xy in
                                          zip(manual.point_id, eo.rows(manual.image_id), manual.xy_px)}
    primary = corners.usable.copy() if s.usable_only else np.ones(len(corners), bool)
    primary[[k for k, _ in manual_k]] = True
    idx = np.flatnonzero(primary)
    frames = FramesOnEarth(crs, eo.centre_m, eo.rotations())
    meas, pred = _measure_frames(corners, camera, eo=eo, frames=frames, images_dir=Path(images_dir), idx=idx,
                                 manual_k=manual_k, s=s, crs=crs, resume=resume)
    rays = _check_corners(corners, camera, frames, idx, meas, s)
    kind, targets, base = _select(corners, camera, eo, primary, rays, s=s, frames=frames)
    extra = _near_unfilled_targets(corners, targets, ~primary) if s.layout.fallback else np.zeros(0, int)
    if len(extra):
        log.info(f"{sum(t.tier != 'usable' for t in targets)} layout targets without a usable corner: measuring "
                 f"{len(extra)} more corners near them")
        m2, p2 = _measure_frames(corners, camera, eo=eo, frames=frames, images_dir=Path(images_dir), idx=extra,
                                 manual_k={}, s=s, crs=crs, resume=resume)
        meas.update(m2)
        pred.update(p2)
        rays.update(_check_corners(corners, camera, frames, extra, meas, s))
        kind, targets, base = _select(corners, camera, eo, primary, rays, s=s, frames=frames)
    res = TransferResult(corners, list(eo.image_id), meas, pred, rays, kind, targets, base, set(manual_k), primary)
    res.targets = [t if t.corner is not None else dataclasses.replace(t, empty_reason=why_empty(res, t, s))
                   for t in targets]
    return res


def summary(res: TransferResult) -> TransferSummary:
    """Counts and rejection reasons (machine-readable; also control/transfer.json)."""
    meas_reasons = Counter(m.reason for m in res.measurements.values() if not m.ok)
    ray_reasons = Counter(r.reason for r in res.rays.values() if not r.ok)
    dropped = sum(int((~r.kept & np.isfinite(r.residual_px)).sum()) for r in res.rays.values() if r.ok)
    kinds = Counter(res.kind.tolist())
    sel = [k for k in range(len(res.kind)) if res.kind[k] in ("full", "height")]
    rays_sel = [int(res.rays[k].kept.sum()) for k in sel]
    frames = Counter(k for k, _ in res.predicted)
    causes = Counter(too_few_rays_cause(frames, k) for k, r in res.rays.items() if r.reason == "too_few_rays")
    primary = np.ones(len(res.corners), bool) if res.primary is None else res.primary
    return TransferSummary(
        corners_in_file=len(res.corners),
        corners_measured=len(res.rays),
        measurements_attempted=len(res.measurements),
        measurements_accepted_in_image=sum(m.ok for m in res.measurements.values()),
        measurements_rejected_in_image=dict(sorted(meas_reasons.items())),
        rays_dropped_inconsistent=dropped,
        corners_rejected=dict(sorted(ray_reasons.items())),
        too_few_rays_by_cause=dict(sorted(causes.items())),
        corners_accepted=int(sum(r.ok for r in res.rays.values())),
        corners_measured_fallback=int(sum(not primary[k] for k in res.rays)),
        control_full=kinds.get("full", 0),
        control_height=kinds.get("height", 0),
        check_points=kinds.get("check", 0),
        layout_targets=len(res.targets),
        layout_targets_unfilled=sum(t.corner is None for t in res.targets),
        layout_targets_by_tier=dict(sorted(Counter(t.tier for t in res.targets if t.tier).items())),
        selected_rays_min=min(rays_sel) if rays_sel else 0,
        selected_rays_mean=float(np.mean(rays_sel)) if rays_sel else 0.0,
        manual_measurements=len(res.manual),
        base_m=res.base_m,
    )


@dataclasses.dataclass(frozen=True)
class ControlTexts:
    """The control stage's files as texts: control/points.csv, control/image_points.csv, control/transfer.json."""

    points_csv: str
    image_points_csv: str
    transfer_json: str

    def files(self) -> tuple[tuple[str, str], ...]:
        """(file name in control/, text) of each file."""
        return (("points.csv", self.points_csv), ("image_points.csv", self.image_points_csv),
                ("transfer.json", self.transfer_json))


def output_texts(res: TransferResult, checks: bool = True, settings_record: dict | None = None) -> ControlTexts:
    """control/points.csv, control/image_points.csv and control/transfer.json as texts."""
    c = res.corners
    pts = ["id,kind,x,y,z,sx_m,sy_m,sz_m"]
    obs = ["point_id,image_id,x_px,y_px"]
    per_corner = []
    frames_of: dict[int, list[int]] = {}
    for (kk, i) in res.measurements:
        frames_of.setdefault(kk, []).append(i)
    for k in sorted(res.rays):
        r = res.rays[k]
        rec = {"id": str(c.id[k]), "kind": str(res.kind[k]), "reason": r.reason, "score": float(c.score[k]),
               "fallback": bool(res.primary is not None and not res.primary[k]),
               "rays": int(r.kept.sum()) if r.ok else 0,
               "max_residual_px": float(np.nanmax(r.residual_px[r.kept])) if r.ok else None,
               "lidar_diff_m": [round(float(v), 4) for v in r.lidar_diff_m] if np.all(np.isfinite(r.lidar_diff_m)) else None,
               "frames": {}}
        for i in sorted(frames_of.get(k, [])):
            m = res.measurements[(k, i)]
            j = r.images.index(i) if i in r.images else None
            if j is not None and r.ok and r.kept[j]:
                status = "accepted"
            elif m.reason:
                status = m.reason  # rejected in the image
            elif r.ok or (r.reason == "inconsistent_rays" and not r.kept[j]):
                status = "inconsistent_ray"  # dropped by the multi-ray check
            else:
                status = f"corner_{r.reason}"  # fine in this frame, the corner failed as a whole
            rec["frames"][res.image_ids[i]] = {
                "x_px": None if not np.isfinite(m.x_px) else round(m.x_px, 3),
                "y_px": None if not np.isfinite(m.y_px) else round(m.y_px, 3),
                "status": status,
                "residual_px": round(float(r.residual_px[j]), 3) if j is not None and np.isfinite(r.residual_px[j]) else None,
            }
        per_corner.append(rec)
        if not r.ok or res.kind[k] not in ("full", "height", "check") or (res.kind[k] == "check" and not checks):
            continue
        x, y, z = c.xyz_m[k]
        sx, sy, sz = c.sigma_m[k]
        pts.append(f"{c.id[k]},{res.kind[k]},{x:.4f},{y:.4f},{z:.4f},{sx:.4f},{sy:.4f},{sz:.4f}")
        for j, i in enumerate(r.images):
            if r.kept[j]:
                m = res.measurements[(k, i)]
                obs.append(f"{c.id[k]},{res.image_ids[i]},{m.x_px:.3f},{m.y_px:.3f}")
    targets = [{**dataclasses.asdict(t), "corner": None if t.corner is None else str(c.id[t.corner])}
               for t in res.targets]
    rep = {"summary": dataclasses.asdict(summary(res)), "layout_targets": targets, "corners": per_corner,
           "settings": settings_record}
    return ControlTexts("\n".join(pts) + "\n", "\n".join(obs) + "\n",
                        json.dumps(rep, indent=1, allow_nan=False, default=float))


CONTROL_TRANSFER = "control transfer report (control/transfer.json)"


@dataclasses.dataclass(frozen=True)
class ControlTransferRecord:
    """What ``control/transfer.json`` tells the stages after the control transfer."""

    control_full: int  # accepted as full (X, Y, Z) control points
    control_height: int  # accepted as height control points
    check_points: int
    layout_targets: tuple[LayoutTarget, ...]  # ``corner``: the chosen corner's id (None: empty target)
    summary: dict  # every count of ``TransferSummary`` as written (numbers and reason -> count tables)


def read_control_transfer(path) -> ControlTransferRecord:
    """``control/transfer.json`` as ``run_control`` wrote it; InputError naming the file when it is not one."""
    from aerotri.core.textio import read_record, record_error

    d = read_record(path, CONTROL_TRANSFER, 1)
    try:
        sm = dict(d.get("summary") or {})
        fields = {f.name for f in dataclasses.fields(LayoutTarget)}
        targets = tuple(LayoutTarget(**{k: v for k, v in t.items() if k in fields})
                        for t in d.get("layout_targets") or [])
        return ControlTransferRecord(int(sm.get("control_full", 0)), int(sm.get("control_height", 0)),
                                     int(sm.get("check_points", 0)), targets, sm)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, CONTROL_TRANSFER, exc) from None


def layout_line(res: TransferResult) -> str:
    """The layout targets in one sentence: how many filled, by fallbacks, and why each empty one is empty."""
    n, filled = len(res.targets), [t for t in res.targets if t.corner is not None]
    fb = Counter(t.tier for t in filled if t.tier != "usable")
    line = f"Layout: {len(filled)} of {n} targets filled"
    if fb:
        line += " (fallbacks: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(fb.items())) + ")"
    empty = [empty_target_text(dataclasses.asdict(t)) for t in res.targets if t.corner is None]
    return line + (("; empty: " + "; ".join(empty)) if empty else "") + "."


def _chips(res: TransferResult, image, i: int, klist) -> dict:
    """The review chips of the corners ``klist`` in frame ``i`` (PNG bytes by file name)."""
    from aerotri.control.chips import chip_png

    out = {}
    for k in klist:
        m, r = res.measurements[(k, i)], res.rays[k]
        j = r.images.index(i) if i in r.images else None
        ok = bool(j is not None and r.ok and r.kept[j])
        out[f"{res.corners.id[k]}_{res.image_ids[i]}.png"] = chip_png(image, res.predicted[(k, i)], (m.x_px, m.y_px), ok)
    return out


def review_page(res: TransferResult, images_dir) -> ReviewPage:
    """The review page: selected corners first, then checks, rejected ones."""

    order = {"full": 0, "height": 1, "check": 2, "candidate": 3, "rejected": 4}
    ks = sorted(res.rays, key=lambda k: (order.get(res.kind[k], 4), str(res.corners.id[k])))
    by_image: dict[int, list] = {}
    for (k, i) in res.measurements:
        by_image.setdefault(i, []).append(k)
    chips, rows = {}, {k: [] for k in ks}
    for i, klist in by_image.items():
        with FrameWindows(find_image(images_dir, res.image_ids[i])) as image:
            chips.update(_chips(res, image, i, klist))
        for k in klist:
            m, r = res.measurements[(k, i)], res.rays[k]
            j = r.images.index(i) if i in r.images else None
            ok = bool(j is not None and r.ok and r.kept[j])
            name = f"{res.corners.id[k]}_{res.image_ids[i]}.png"
            res_txt = f", {r.residual_px[j]:.2f} px" if j is not None and np.isfinite(r.residual_px[j]) else ""
            cap = f"{res.image_ids[i]}: " + (f"{m.x_px:.1f}, {m.y_px:.1f}{res_txt}" if np.isfinite(m.x_px) else "-")
            if not ok:
                cap += f" ({m.reason or 'inconsistent'})"
            rows[k].append({"file": name, "size": 132, "caption": cap, "image": res.image_ids[i]})
    corners = []
    for k in ks:
        r = res.rays[k]
        status = res.kind[k] if r.ok else f"rejected: {r.reason}"
        if r.ok:
            status += f", {int(r.kept.sum())} rays, LiDAR diff {np.linalg.norm(r.lidar_diff_m):.2f} m"
        x, y, z = res.corners.xyz_m[k]
        corners.append({"id": res.corners.id[k], "score": f"{res.corners.score[k]:.2f}", "xyz": f"{x:.2f} {y:.2f} {z:.2f}",
                        "status": status, "cls": res.kind[k], "chips": sorted(rows[k], key=lambda c: c["image"])})
    sm = summary(res)
    line = (f"{sm.corners_accepted} of {sm.corners_measured} corners accepted; control: {sm.control_full} full, "
            f"{sm.control_height} height; {sm.check_points} check points; "
            f"{sum(sm.corners_rejected.values())} corners and {sum(sm.measurements_rejected_in_image.values())} "
            f"image measurements rejected (table below). {layout_line(res)}")
    return ReviewPage(line, corners, chips, rejection_rows(sm))


def _block_crs(root):
    """The project CRS the corners and orientations are checked against (None without a project.toml)."""
    from aerotri.geom.eo import check_block_crs

    if not (Path(root) / "project.toml").is_file():
        return None
    project = Project.open(root)
    return check_block_crs(project.crs, f"{project.config_path} [project] crs")


@committed(lambda root, *a, **k: project_paths(root).control_dir)
def run_control(root, corners_path=None, eo_path=None, camera_path=None, manual_path=None, *,
                settings: ControlSettings | Resolved | None = None) -> TransferSummary:
    """The stage: read, transfer, write all outputs atomically; returns the summary.

    Defaults: the corners ``lidar_out/corners.csv``, the orientations ``at/eo.txt``, the camera of
    ``aerotri.geom.camera.orientations_camera`` (at/camera.toml for at/eo.txt, else camera.toml);
    ``manual_path``: manual measurements (``read_manual``). ``settings``: None reads [control] of project.toml
    (a folder without one: the defaults); a ``Resolved`` (``aerotri control``, the chain) carries every
    setting's source into control/transfer.json (``settings``).
    """
    from aerotri.core.atomic import atomic_dir, write_text_atomic

    from aerotri.control.chips import write_review

    paths = project_paths(root)
    if settings is None and not paths.config_path.is_file():
        settings = ControlSettings()
    resolved = settings_of(settings, ControlSettings, Project.open(root) if settings is None else None)
    s = resolved.settings
    if s.measure.eo_sigma_px > s.measure.max_radius_px:
        # the search window stops at max_radius_px: an orientation this uncertain is not measured in, it is refused
        raise OptionError(f"{s.measure.eo_sigma_px:g} px: the orientations' uncertainty exceeds the largest search "
                          f"radius ({s.measure.max_radius_px:g} px); adjust the block first (tie points + GNSS)",
                          param="--eo-sigma-px")
    corners_path = corners_path or paths.corners_path
    eo_path = eo_path or paths.eo_path
    crs = _block_crs(paths.root)
    corners = read_corners(corners_path, crs)
    if not Path(eo_path).exists():
        raise InputError(f"{eo_path}: orientations not found (run the first aerotri adjust, tie points + GNSS, "
                         "or pass --eo FILE)")
    eo = read_eo(eo_path, crs)
    from aerotri.geom.crs.definition import linear_unit_m
    from aerotri.geom.inputs import check_near_block

    # LiDAR corners of another zone or place than the block's frames: refused by name, not "none measured"
    check_near_block(corners.xyz_m[:, 0], corners.xyz_m[:, 1], [f"corner {c}" for c in corners.id], str(corners_path),
                     block_xy=eo.centre_m[:, :2], block_source=str(eo_path),
                     unit_m=linear_unit_m(crs) if crs is not None else 1.0)
    # the camera of these orientations: at/camera.toml only for the project's own at/eo.txt
    camera, _ = orientations_camera(Project.open(paths.root) if camera_path is None else None, eo_path, camera_path)
    manual = (read_manual(manual_path, corners.id, eo.image_id, camera, corners_path, eo_path)
              if manual_path else None)
    # each frame's measurements are kept in work/control_resume until the outputs are written (core.resume)
    with resumable(paths.work_dir / CONTROL_RESUME_DIR_NAME) as keep:
        res = transfer_control(corners, camera, eo, paths.images_dir, s, manual, crs=crs, resume=keep)
        sm = summary(res)
        if sm.corners_accepted == 0:
            raise InputError(f"no corner could be measured consistently in two or more frames ({sm.corners_measured} "
                             f"tried; rejected: {sm.corners_rejected}) - check {eo_path} and the camera")
        texts = output_texts(res, s.checks, resolved.record())
        review = review_page(res, paths.images_dir) if s.chips else None
        if review is not None:
            with atomic_dir(paths.control_dir / "review") as tmp:
                write_review(tmp, paths.root.name, review.summary, review.corners, review.chips, review.rejections)
        for name, text in texts.files():
            write_text_atomic(paths.control_dir / name, text)
    return sm
