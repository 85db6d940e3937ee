"""OpenSfM ``reconstruction.json`` import (``aerotri import --format opensfm``), and OpenSfM's
``ground_control_points.json`` (written by :mod:`aerotri.exchange.odm`).

OpenSfM's conventions (its ``types.py``/``geo.py``, and ``features.normalized_image_coordinates``):

- world frame: topocentric east-north-up at ``reference_lla`` (latitude, longitude, altitude on the WGS84
  ellipsoid), in the reconstruction or in ``reference_lla.json`` beside it;
- shot pose: ``rotation`` (axis-angle, radians) and ``translation`` of world -> camera,
  ``x_cam = R X + t``, camera frame x right, y down, z forward; projection centre ``-R^T t``;
- cameras: coordinates normalised by ``max(width, height)``; ``brown``: OpenCV's k1 k2 p1 p2 k3 on
  x/z, y/z, then ``focal_x * xd + c_x``, ``focal_y * yd + c_y`` (offsets from the image centre);
  ``perspective``: one focal, radial k1 k2, principal point at the centre. Pixels:
  ``s * xn + (w - 1) / 2`` with ``s = max(w, h)``: origin at the centre of the top-left pixel, as ours.

Import: the camera at the size of the frames on disk (the project's ``images/``, else ``images/`` beside
the OpenSfM folder, else the size in the file; normalised coordinates do not change with downsampling),
one focal length (f = (focal_x + focal_y) / 2, noted when they differ); the shots' centres and
attitudes -> ``imported/eo.txt`` and their ``gps_position`` -> ``gnss.txt`` (accuracy ``gps_dop`` when
given), both in the project CRS. The reference point goes to the project CRS through ``to_project_crs``
(``--crs``: the CRS of its latitude, longitude and altitude, default EPSG:4979); the topocentric
coordinates then go to the project CRS through the local ENU frame at that point (the adjustment's
``LocalFrame``: exact, no map-projection approximation), and the attitudes to the grid axes at each
centre.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_json
from aerotri.exchange.imported import ImportedBlock, ImportSettings, to_project_crs
from aerotri.geom.camera import BrownCamera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions
from aerotri.geom.rotation import FLIP_YZ, opk_from_matrix

DEFAULT_CRS = "EPSG:4979"
NOMINAL_PIXEL_UM = 5.0  # when no image tells the pixel size: the geometry in pixels does not depend on it


def _number(d: dict, key: str, where: str, positive: bool = False) -> float:
    if key not in d:
        raise InputError(f"{where}: missing key {key!r}")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        raise InputError(f"{where}: {key} = {v!r}; expected a finite{' positive' if positive else ''} number")
    return float(v)


def _vector(d: dict, key: str, where: str, n: int = 3) -> np.ndarray:
    v = d.get(key)
    if not isinstance(v, list) or len(v) != n:
        raise InputError(f"{where}: {key} = {v!r}; expected a list of {n} numbers")
    try:
        a = np.array(v, float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} = {v!r}; expected a list of {n} numbers") from None
    if not np.all(np.isfinite(a)):
        raise InputError(f"{where}: {key} = {v!r} holds NaN or infinite values")
    return a


def rotation_from_axis_angle(r) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (radians), as OpenSfM's (Rodrigues')."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(r, float)).as_matrix()


def _frame_file(project: Project, recon_path: Path, shot_ids) -> Path | None:
    """A frame of the reconstruction on disk: in the project's images/, else in images/ beside the OpenSfM
    folder (ODM's layout)."""
    from aerotri.geom.images import find_image

    for folder in (project.images_dir, recon_path.parent.parent / "images"):
        if not folder.is_dir():
            continue
        for sid in shot_ids:
            if (folder / sid).is_file():
                return folder / sid
            try:
                return find_image(folder, Path(sid).stem)
            except InputError:
                continue
    return None


def _frame_size_and_pixel(path: Path) -> tuple[tuple[int, int], float | None]:
    """((width, height) px, pixel size in um or None) of a frame file (the pixel size from its EXIF)."""
    from aerotri.exchange.exif import pixel_size_mm, read_frame_metadata

    m = read_frame_metadata(path)
    full_w, full_h = m.full_size or (m.width, m.height)
    try:
        pixel_um = pixel_size_mm(m, full_w, full_h)[0] * 1000.0 * full_w / m.width
    except InputError:
        pixel_um = None
    return (m.width, m.height), pixel_um


def camera_from_opensfm(cam: dict, where: str, size, pixel_um: float, name: str = "OpenSfM camera") -> tuple[BrownCamera, list[str]]:
    """Our camera of an OpenSfM camera (``brown`` or ``perspective``) at ``size`` = (width, height) px."""
    kind = cam.get("projection_type")
    w_file = int(_number(cam, "width", where, positive=True))
    h_file = int(_number(cam, "height", where, positive=True))
    w, h = size or (w_file, h_file)
    if abs(h / w - h_file / w_file) * max(w, h) > 1.0:
        raise InputError(f"{where}: the camera is {w_file} x {h_file} px but the frames are {w} x {h} px (another "
                         f"aspect ratio)")
    s = max(w, h)
    notes = []
    if kind == "brown":
        fx, fy = _number(cam, "focal_x", where, True), _number(cam, "focal_y", where, True)
        k = {c: _number(cam, c, where) for c in ("k1", "k2", "k3", "p1", "p2")}
        cx, cy = _number(cam, "c_x", where), _number(cam, "c_y", where)
        f = 0.5 * (fx + fy)
        if fx != fy:
            notes.append(f"camera: OpenSfM focal_x {fx:.6g} and focal_y {fy:.6g} averaged (one focal length: "
                         f"{abs(fx - fy) / f * h / 2:.2f} px at the top and bottom edges)")
    elif kind == "perspective":
        f = _number(cam, "focal", where, True)
        k = {"k1": _number(cam, "k1", where), "k2": _number(cam, "k2", where)}
        cx = cy = 0.0
    else:
        raise InputError(f"{where}: projection_type {kind!r} is not supported; expected 'brown' or 'perspective'")
    pix_mm = pixel_um / 1000.0
    camera = BrownCamera(focal_mm=f * s * pix_mm, pixel_um=pixel_um, width=int(w), height=int(h),
                         ppx_mm=cx * s * pix_mm, ppy_mm=-cy * s * pix_mm, name=name, **k)
    return camera, notes


def read_reconstruction(path) -> tuple[dict, dict]:
    """(the first reconstruction, its reference lla) of a ``reconstruction.json``."""
    path = Path(path)
    doc = read_json(path, "OpenSfM reconstruction")
    if not isinstance(doc, list) or not doc or not isinstance(doc[0], dict):
        raise InputError(f"{path}: expected a list of reconstructions (OpenSfM reconstruction.json)")
    rec = doc[0]
    for key in ("cameras", "shots"):
        if not isinstance(rec.get(key), dict) or not rec[key]:
            raise InputError(f"{path}: reconstruction 0 has no {key!r}")
    ref = rec.get("reference_lla")
    if ref is None and (path.parent / "reference_lla.json").is_file():
        ref = read_json(path.parent / "reference_lla.json", "OpenSfM reference_lla.json")
    if not isinstance(ref, dict):
        raise InputError(f"{path}: no reference_lla (in the reconstruction or reference_lla.json beside it); the "
                         f"topocentric coordinates cannot be placed")
    for key in ("latitude", "longitude", "altitude"):
        _number(ref, key, f"{path} reference_lla")
    if len(doc) > 1:
        import logging

        logging.getLogger(__name__).warning(f"{path}: {len(doc)} reconstructions; importing the first "
                                            f"({len(rec['shots'])} shots)")
    return rec, ref


def read(files, project: Project, options: ImportSettings) -> ImportedBlock:
    """The ``opensfm`` importer (see the module docstring)."""
    from aerotri.geom.local_frame import LocalFrame

    if len(files) != 1:
        raise InputError(f"opensfm expects one reconstruction.json, got {len(files)} files")
    path = Path(files[0])
    if path.is_dir():
        path = path / "reconstruction.json"
    rec, ref = read_reconstruction(path)
    block = ImportedBlock(source=[str(path)])
    if len(rec["cameras"]) != 1:
        raise InputError(f"{path}: {len(rec['cameras'])} cameras; the project holds one (import each camera's "
                         f"shots into their own project)")
    cam_id, cam = next(iter(rec["cameras"].items()))
    shot_ids = sorted(rec["shots"])
    image = _frame_file(project, path, shot_ids)
    size, pixel_um = _frame_size_and_pixel(image) if image is not None else (None, None)
    if image is None:
        block.notes.append(f"camera: frames not found (the project's images/ or images/ beside {path.parent}); "
                           f"the camera at the size in the file")
    if pixel_um is None:
        pixel_um = NOMINAL_PIXEL_UM
        block.notes.append(f"camera: pixel size unknown (no EXIF focal plane resolution or focal lengths); nominal "
                           f"{NOMINAL_PIXEL_UM} um (the pixel geometry is exact, millimetre values nominal)")
    block.camera, notes = camera_from_opensfm(cam, f"{path} camera {cam_id!r}", size, pixel_um, name=str(cam_id))
    block.notes += notes
    crs = options.crs or DEFAULT_CRS
    ref_map = to_project_crs([[ref["longitude"], ref["latitude"], ref["altitude"]]], crs, project,
                             f"{path} reference_lla ({crs})")[0]
    frame = LocalFrame(project.crs, ref_map)
    centres, R_enu, gps, dop = [], [], [], []
    for sid in shot_ids:
        shot = rec["shots"][sid]
        where = f"{path} shot {sid!r}"
        if not isinstance(shot, dict):
            raise InputError(f"{where}: expected an object")
        if shot.get("camera") != cam_id:
            raise InputError(f"{where}: camera {shot.get('camera')!r} is not the reconstruction's camera {cam_id!r}")
        R_cw = rotation_from_axis_angle(_vector(shot, "rotation", where))
        t = _vector(shot, "translation", where)
        centres.append(-R_cw.T @ t)
        R_enu.append(R_cw.T)
        gps.append(_vector(shot, "gps_position", where) if "gps_position" in shot else None)
        dop.append(_number(shot, "gps_dop", where, positive=True) if "gps_dop" in shot else None)
    C_map = frame.to_map(np.array(centres))
    R_map = np.swapaxes(frame.rotation_local_from_map(C_map), -1, -2) @ np.array(R_enu) @ FLIP_YZ
    ids = [Path(s).stem for s in shot_ids]
    block.eo = ExteriorOrientations(ids, C_map, np.stack(opk_from_matrix(R_map), axis=-1))
    if all(g is not None for g in gps):
        sigma = np.array([[d, d, d] for d in dop]) if all(d is not None for d in dop) else None
        if sigma is None and options.sigma_xyz_m is not None:
            sigma = np.tile(np.asarray(options.sigma_xyz_m, float), (len(ids), 1))
        block.gnss = GnssPositions(ids, frame.to_map(np.array(gps)), sigma)
        if sigma is not None and all(d is not None for d in dop):
            block.notes.append("positions: accuracies = OpenSfM gps_dop (m) in X, Y and Z")
    block.notes.append(f"orientations: OpenSfM's solution (topocentric frame at lat {ref['latitude']:.8f}, lon "
                       f"{ref['longitude']:.8f}, altitude {ref['altitude']:g} taken as {crs})")
    return block
