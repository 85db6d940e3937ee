"""An adjusted block as the project folder holds it: the input of every exporter.

Read from ``at/eo.txt`` (orientations), ``at/camera.toml`` (the camera they belong to, self-calibrated
or nominal, through ``aerotri.geom.camera.oriented_camera``), ``at/object_points.csv`` (adjusted points,
their kinds and rays), ``at/report.json`` (the local frame's origin, the removed observations),
``at/tiepoints.csv`` and ``control/image_points.csv`` (the measurements; those of points the adjustment
used and did not remove), ``control/points.csv`` and ``camera.toml`` (the a-priori camera). Poses and points are also given in the adjustment's local ENU frame
(``aerotri.geom.local_frame``), where collinearity holds exactly.
"""

from __future__ import annotations

import csv
import dataclasses
import io

import numpy as np

from aerotri.core.errors import InputError, StageOrderError
from aerotri.core.project import Project
from aerotri.core.textio import read_json, read_text
from aerotri.geom.camera import Camera, oriented_camera, project_camera
from aerotri.geom.eo import check_block_crs, read_eo
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.observations import read_control_points, read_image_points
from aerotri.geom.rotation import FLIP_YZ


@dataclasses.dataclass(kw_only=True)
class AdjustedBlock:
    """Orientations, points, measurements and control of an adjusted project (see module docstring)."""

    project_name: str
    crs: str
    frame: LocalFrame
    camera: Camera  # the a-priori camera (camera.toml)
    oriented: Camera  # the camera of the orientations (at/camera.toml), with what Cal3DS2 does not hold (k3)
    cal: np.ndarray  # (9,) interior orientation of at/camera.toml, Cal3DS2 order: fx fy skew u0 v0 k1 k2 p1 p2 (px)
    image_id: list
    centre_local: np.ndarray  # (N, 3) projection centres, ENU
    R_cv: np.ndarray  # (N, 3, 3) computer-vision camera -> ENU
    point_id: np.ndarray  # (P,) adjusted points
    point_kind: np.ndarray  # (P,) tie, full, horizontal, height, rejected_control
    points_local: np.ndarray  # (P, 3) ENU
    point_rms_px: np.ndarray  # (P,) image residual RMS of each point
    obs_point: np.ndarray  # (K,) index into the points
    obs_image: np.ndarray  # (K,) index into the images
    obs_xy_px: np.ndarray  # (K, 2) measured pixel coordinates (a known k3 taken off, as the adjustment saw them)
    obs_measured_px: np.ndarray  # (K, 2) the same measurements as measured (pixels of the image files)
    control_id: np.ndarray  # control points in the adjustment, not rejected
    control_kind: np.ndarray
    control_xyz_m: np.ndarray  # (C, 3) given coordinates, project CRS
    heights_measured: bool = True  # False: relative heights (adjustment report's heights_measured; plan-only control)


def _object_points(path):
    rows = list(csv.DictReader(io.StringIO(read_text(path, "adjusted object points (CSV)"))))
    if not rows or not {"id", "kind", "x", "y", "z", "rms_px"} <= set(rows[0]):
        raise InputError(f"{path}: expected the header id,kind,x,y,z,sx_m,sy_m,sz_m,rays,rms_px of aerotri adjust")
    ids = np.array([r["id"] for r in rows], dtype=object)
    kinds = np.array([r["kind"] for r in rows], dtype=object)
    values = np.empty((len(rows), 4))
    for k, r in enumerate(rows):  # line k + 2 (after the header): a value that is no finite number is named
        for j, key in enumerate(("x", "y", "z", "rms_px")):
            try:
                values[k, j] = float(r[key])
            except (TypeError, ValueError):
                raise InputError(f"{path}:{k + 2}: {key} = {r[key]!r} of point {r['id']!r} is not a number") from None
            if not np.isfinite(values[k, j]):
                raise InputError(f"{path}:{k + 2}: {key} of point {r['id']!r} is NaN or infinite")
    return ids, kinds, values[:, :3], values[:, 3]


def read_adjusted_block(root) -> AdjustedBlock:
    """The adjusted block of a project folder (``StageOrderError`` when it has not been adjusted)."""
    project = Project.open(root)
    for path in (project.eo_path, project.object_points_path, project.adjustment_report_path):
        if not path.is_file():
            raise StageOrderError(f"{path}: not found; run the adjustment first (aerotri adjust {project.root})")
    report = read_json(project.adjustment_report_path, "adjustment report")
    frame_info = report.get("local_frame")
    if not isinstance(frame_info, dict) or "origin_map" not in frame_info:
        raise StageOrderError(f"{project.adjustment_report_path}: no local_frame (written by an older version); "
                              f"adjust the project again (aerotri adjust {project.root})")
    origin = frame_info["origin_map"]
    if not (isinstance(origin, list) and len(origin) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in origin)):
        raise InputError(f"{project.adjustment_report_path}: local_frame origin_map = {origin!r}: expected three finite "
                         f"numbers (X, Y, Z); adjust the project again (aerotri adjust {project.root})")
    frame = LocalFrame(project.crs, frame_info["origin_map"])
    camera = project_camera(project)  # a priori: it prepared the measurements the adjustment saw
    # the orientations' own camera from its file, at full precision (report.json rounds to 8 decimals)
    oriented = oriented_camera(project)[0]
    cal = oriented.calibration_vector()
    # the projection centres checked against the project CRS (another zone's numbers, swapped X/Y)
    eo = read_eo(project.eo_path, check_block_crs(project.crs, f"{project.config_path} [project] crs"))
    centre_local = frame.to_local(eo.centre_m)
    R_cv = frame.rotation_local_from_map(eo.centre_m) @ eo.rotations() @ FLIP_YZ
    ids, kinds, xyz_map, rms = _object_points(project.object_points_path)
    # the measurements the adjustment used: of its points, in its images, not removed by data snooping
    obs = [read_image_points(project.tiepoints_path)]
    if project.control_image_points_path.is_file():
        obs.append(read_image_points(project.control_image_points_path))
    pid = np.concatenate([o.point_id for o in obs]).astype(str)
    iid = np.concatenate([o.image_id for o in obs]).astype(str)
    measured = np.vstack([o.xy_px for o in obs])
    xy = camera.calibration_observations(measured)
    removed = {(r["point_id"], r["image_id"]) for r in report.get("removed_observations", [])}
    point_index = {p: j for j, p in enumerate(ids.astype(str))}
    image_index = {i: n for n, i in enumerate(eo.image_id)}
    keep = np.array([p in point_index and i in image_index and (p, i) not in removed for p, i in zip(pid, iid)], bool)
    # control: the points of control/points.csv the adjustment kept as control
    control = read_control_points(project.control_points_path) if project.control_points_path.is_file() else None
    _refuse_unknown_control_ids(obs[1:], project, control, point_index)
    kind_of = dict(zip(ids.astype(str), kinds))
    if control is not None and len(control):
        used = np.array([kind_of.get(str(c), "") not in ("", "tie", "rejected_control") for c in control.id], bool)
        control_id, control_kind, control_xyz = control.id[used], control.kind[used], control.xyz_m[used]
    else:
        control_id = control_kind = np.zeros(0, object)
        control_xyz = np.zeros((0, 3))
    return AdjustedBlock(
        project_name=project.name, crs=project.crs, frame=frame, camera=camera, oriented=oriented, cal=cal,
        image_id=list(eo.image_id),
        centre_local=centre_local, R_cv=R_cv, point_id=ids, point_kind=kinds, points_local=frame.to_local(xyz_map),
        point_rms_px=rms, obs_point=np.array([point_index[p] for p in pid[keep]], int),
        obs_image=np.array([image_index[i] for i in iid[keep]], int), obs_xy_px=xy[keep],
        obs_measured_px=measured[keep], control_id=control_id,
        control_kind=control_kind, control_xyz_m=control_xyz,
        heights_measured=report.get("heights_measured", True) is not False,
    )


def _refuse_unknown_control_ids(obs, project: Project, control, point_index: dict) -> None:
    """A control measurement of a point that is neither in control/points.csv nor among the adjusted points
    refers to nothing (the file was edited after the adjustment): InputError naming its line, not a silent drop."""
    known = set(point_index) | (set(control.id.astype(str)) if control is not None else set())
    for o in obs:
        for k, p in enumerate(o.point_id.astype(str)):
            if p not in known:
                raise InputError(f"{o.where(k, project.control_image_points_path)}: point '{p}' is neither in "
                                 f"{project.control_points_path} nor among the adjusted points; re-run aerotri "
                                 "control / aerotri adjust")
