"""OpenSfM ``reconstruction.json``: import (``aerotri import --format opensfm``) and the writer behind the ODM
export (``aerotri.exchange.odm_export``); OpenSfM's ``ground_control_points.json`` is written there too.

OpenSfM's conventions (its ``doc/source/geometry.rst`` and ``dataset.rst``; ``opensfm/io.py``,
``opensfm/geo.py``; mapillary/OpenSfM at 238744c):

- world frame: topocentric east-north-up at ``reference_lla`` (latitude, longitude in degrees, altitude in
  metres above the WGS84 ellipsoid; in the reconstruction, or ``reference_lla.json`` beside it in older
  datasets). ``geo.ecef_from_topocentric_transform``: ``X_ecef = R_et X_topo + ecef(ref)``, the columns
  of ``R_et`` the east, north and up axes at the reference (WGS84 a = 6378137, b = 6356752.314245);
- shot pose: ``rotation`` (axis-angle, radians) and ``translation`` of world -> camera,
  ``x_cam = R X + t``, camera frame x right, y down, z forward; projection centre ``-R^T t``;
  ``gps_position`` in the topocentric frame, ``gps_dop`` its accuracy (m);
- cameras: coordinates normalised by ``max(width, height)``; ``brown``: OpenCV's k1 k2 p1 p2 k3 on
  x/z, y/z, then ``focal_x * xd + c_x``, ``focal_y * yd + c_y`` (offsets from the image centre);
  ``perspective``: one focal, radial k1 k2, principal point at the centre. Pixels:
  ``s * xn + (w - 1) / 2`` with ``s = max(w, h)``: origin at the centre of the top-left pixel, as ours;
- points: ``{"coordinates": [x, y, z] (topocentric), "color": [r, g, b]}``.

Coordinates go between the topocentric frame and the project CRS through geocentric coordinates:
topocentric <-> ECEF with OpenSfM's own formulas, ECEF <-> project CRS through the toolkit's
coordinate-operation policy (``to_project_crs``; the project's height system included), attitudes
through the rotation between the ECEF axes and the project's grid axes at each centre
(``aerotri.exchange.poses.rotation_to_project``). No map-projection approximation: writing and reading
back reproduces the orientations to 1e-9 m and 1e-9 degrees.

Import: the camera at the size of the frames on disk (the project's ``images/``, else ``images/`` beside
the OpenSfM folder, else the size in the file; normalised coordinates do not change with downsampling),
one focal length (f = (focal_x + focal_y) / 2, noted when they differ); pixel size from the frames'
EXIF, else the project's camera.toml, else nominal; the shots' centres and attitudes ->
``imported/eo.txt`` (approximations). With ``--as-gnss`` the shots' ``gps_position`` (the GNSS the
reconstruction was made with, not its solution) -> ``gnss.txt``, accuracies ``--sigma-xyz-m`` or else
``gps_dop`` in X, Y and Z. ``--crs``: the CRS of ``reference_lla`` (default EPSG:4979, WGS84).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyproj

from aerotri.core.errors import InputError, id_listing
from aerotri.core.project import Project
from aerotri.core.textio import read_json
from aerotri.exchange.imported import ImportedBlock, ImportSettings, positions_as_gnss, to_project_crs
from aerotri.geom.camera import BrownCamera, Camera
from aerotri.geom.crs.ellipsoid import enu_rotation
from aerotri.geom.eo import ExteriorOrientations, GnssPositions
from aerotri.geom.rotation import FLIP_YZ, opk_from_matrix

WGS84_A_M = 6378137.0  # opensfm/geo.py
WGS84_B_M = 6356752.314245

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
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    from aerotri.exchange.exif import pixel_size_mm, read_frame_metadata

    with warnings.catch_warnings():  # frames are not georeferenced rasters; rasterio says so for each
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
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


def read_reconstruction(path) -> tuple[dict, dict, list]:
    """(the reconstruction of most shots, its reference lla, the others' shot names, one list each) of a
    ``reconstruction.json``. OpenSfM writes the largest first; a merged or edited file need not (trial s96 M3: the
    first, of 1 shot, was taken over the other of 3)."""
    path = Path(path)
    doc = read_json(path, "OpenSfM reconstruction")
    if not isinstance(doc, list) or not doc or not all(isinstance(r, dict) for r in doc):
        raise InputError(f"{path}: expected a list of reconstructions (OpenSfM reconstruction.json)")
    size = [len(r["shots"]) if isinstance(r.get("shots"), dict) else 0 for r in doc]
    k = max(range(len(doc)), key=lambda i: (size[i], -i))
    rec = doc[k]
    for key in ("cameras", "shots"):
        if not isinstance(rec.get(key), dict) or not rec[key]:
            raise InputError(f"{path}: reconstruction {k} has no {key!r}")
    ref = rec.get("reference_lla")
    if ref is None and (path.parent / "reference_lla.json").is_file():
        ref = read_json(path.parent / "reference_lla.json", "OpenSfM reference_lla.json")
    if not isinstance(ref, dict):
        raise InputError(f"{path}: no reference_lla (in the reconstruction or reference_lla.json beside it); the "
                         f"topocentric coordinates cannot be placed")
    for key in ("latitude", "longitude", "altitude"):
        _number(ref, key, f"{path} reference_lla")
    others = [sorted(r["shots"]) if isinstance(r.get("shots"), dict) else [] for i, r in enumerate(doc) if i != k]
    return rec, ref, others


# -- the topocentric frame ---------------------------------------------------------------------------

def ecef_from_lla(lat_deg, lon_deg, alt_m) -> np.ndarray:
    """(..., 3) geocentric coordinates of latitude, longitude, ellipsoidal altitude (OpenSfM's ``geo.ecef_from_lla``)."""
    a2, b2 = WGS84_A_M ** 2, WGS84_B_M ** 2
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    L = 1.0 / np.sqrt(a2 * np.cos(lat) ** 2 + b2 * np.sin(lat) ** 2)
    return np.stack([(a2 * L + alt_m) * np.cos(lat) * np.cos(lon), (a2 * L + alt_m) * np.cos(lat) * np.sin(lon),
                     (b2 * L + alt_m) * np.sin(lat)], axis=-1)


def ecef_from_topocentric(ref: dict) -> tuple[np.ndarray, np.ndarray]:
    """(R_et (3, 3), origin (3,)): ``X_ecef = R_et X_topo + origin`` (OpenSfM's ``geo.ecef_from_topocentric_transform``)."""
    R = enu_rotation(ref["latitude"], ref["longitude"]).T  # columns: the east, north, up axes
    return R, ecef_from_lla(ref["latitude"], ref["longitude"], ref["altitude"])


def _geocentric(ref_crs: str, source: str):
    from aerotri.geom.crs.definition import parse_crs
    from aerotri.geom.crs.transform import same_datum_geocentric

    return same_datum_geocentric(parse_crs(ref_crs, source))


def topocentric_to_project(ref: dict, ref_crs: str, project: Project, xyz_topo, R_cv_topo, source: str
                           ) -> tuple[np.ndarray, np.ndarray | None]:
    """(centres (N, 3) in the project CRS, camera -> project-grid rotations (N, 3, 3) in the photogrammetric
    camera frame, or None without ``R_cv_topo``) of topocentric positions and computer-vision camera ->
    topocentric rotations."""
    from aerotri.exchange.poses import rotation_to_project

    R_et, origin = ecef_from_topocentric(ref)
    ecef = np.asarray(xyz_topo, float).reshape(-1, 3) @ R_et.T + origin
    geocentric = _geocentric(ref_crs, source)
    xyz = to_project_crs(ecef, geocentric, project, source)
    if R_cv_topo is None:
        return xyz, None
    R = rotation_to_project(geocentric, project, ecef, source) @ R_et @ np.asarray(R_cv_topo, float) @ FLIP_YZ
    return xyz, R


def project_to_topocentric(ref: dict, project: Project, xyz_map, R_photo_map=None, source: str = "project"
                           ) -> tuple[np.ndarray, np.ndarray | None]:
    """The inverse of :func:`topocentric_to_project` for a WGS84 ``reference_lla``: (topocentric positions,
    computer-vision camera -> topocentric rotations or None)."""
    from aerotri.exchange.poses import rotation_to_project
    from aerotri.geom.crs.definition import project_crs_3d
    from aerotri.geom.crs.transform import transform_points

    R_et, origin = ecef_from_topocentric(ref)
    geocentric = _geocentric(DEFAULT_CRS, source)
    xyz = np.asarray(xyz_map, float).reshape(-1, 3)
    ecef = np.column_stack(transform_points(xyz[:, 0], xyz[:, 1], xyz[:, 2], from_crs=project_crs_3d(project),
                                            to_crs=geocentric))
    topo = (ecef - origin) @ R_et
    if R_photo_map is None:
        return topo, None
    R_grid_from_ecef = rotation_to_project(geocentric, project, ecef, source)
    R = R_et.T @ np.swapaxes(R_grid_from_ecef, -1, -2) @ np.asarray(R_photo_map, float) @ FLIP_YZ
    return topo, R


def reference_of(project: Project, xyz_map) -> dict:
    """``reference_lla`` (WGS84) of a project-CRS point, through the coordinate-operation policy."""
    from aerotri.geom.crs.definition import parse_crs, project_crs_3d
    from aerotri.geom.crs.transform import transform_points

    x, y, z = np.asarray(xyz_map, float).reshape(3)
    lon, lat, alt = transform_points(np.array([x]), np.array([y]), np.array([z]), from_crs=project_crs_3d(project),
                                     to_crs=parse_crs(DEFAULT_CRS))
    return {"latitude": float(lat[0]), "longitude": float(lon[0]), "altitude": float(alt[0])}


# -- import ------------------------------------------------------------------------------------------

def _pixel_size_um(project: Project, block: ImportedBlock, image, path: Path) -> tuple:
    size, pixel_um = _frame_size_and_pixel(image) if image is not None else (None, None)
    if image is None:
        block.notes.append(f"camera: frames not found (the project's images/ or images/ beside {path.parent}); "
                           f"the camera at the size in the file")
    if pixel_um is None and project.camera_path.is_file():
        pixel_um = Camera.read(project.camera_path).pixel_um
        block.notes.append(f"camera: pixel size {pixel_um:g} um from {project.camera_path} (OpenSfM cameras are "
                           "normalised)")
    if pixel_um is None:
        pixel_um = NOMINAL_PIXEL_UM
        block.notes.append(f"camera: pixel size unknown (no EXIF focal plane resolution or focal lengths); nominal "
                           f"{NOMINAL_PIXEL_UM} um (the pixel geometry is exact, millimetre values nominal)")
    return size, pixel_um


# reference_lla within this of whole metres of its UTM grid: ODM's offset (odm_georeferencing/coords.txt), not the
# mean of the frames' GPS that OpenSfM takes as its topocentric origin (a chance within 1 mm: about 1 in 250,000)
WHOLE_METRE_TOL_M = 1e-3


def utm_offset_frame(ref: dict, centres_m: np.ndarray, gps) -> tuple[int, float, float] | None:
    """(EPSG code of the UTM zone, easting and northing of the offset) when the reconstruction is ODM's georeferenced
    one (``opensfm export_geocoords``, written over reconstruction.json, the topocentric kept as
    reconstruction.topocentric.json): reference_lla on whole metres of the zone's grid, and, where the shots carry
    ``gps_position`` (topocentric), their centres nearer it read so than read as topocentric. None: topocentric."""
    lon, lat = float(ref["longitude"]), float(ref["latitude"])
    zone = int(math.floor((lon + 180.0) / 6.0)) % 60 + 1
    epsg = (32600 if lat >= 0 else 32700) + zone
    e0, n0 = pyproj.Transformer.from_crs(4326, epsg, always_xy=True).transform(lon, lat)
    if abs(e0 - round(e0)) > WHOLE_METRE_TOL_M or abs(n0 - round(n0)) > WHOLE_METRE_TOL_M:
        return None
    with_gps = [k for k, g in enumerate(gps) if g is not None]
    if with_gps:
        g_topo = np.array([gps[k] for k in with_gps], float)
        R_et, origin = ecef_from_topocentric(ref)
        lon_g, lat_g, h_g = pyproj.Transformer.from_crs(4978, 4979, always_xy=True).transform(
            *(g_topo @ R_et.T + origin).T)
        e, n = pyproj.Transformer.from_crs(4326, epsg, always_xy=True).transform(lon_g, lat_g)
        g_offset = np.column_stack([np.asarray(e) - round(e0), np.asarray(n) - round(n0), h_g])
        c = np.asarray(centres_m, float)[with_gps]
        if np.median(np.linalg.norm(c - g_offset, axis=1)) >= np.median(np.linalg.norm(c - g_topo, axis=1)):
            return None
    return epsg, float(round(e0)), float(round(n0))


def _reference_on_ellipsoid(ref: dict, crs: str) -> tuple[dict, str]:
    """(reference_lla, its CRS) with the altitude an ellipsoidal height: a ``--crs`` with a vertical datum (EPSG:4326+3855,
    an altitude above the geoid) has it turned into one through PROJ (the geoid grid, refused naming it when absent);
    a CRS that is no latitude, longitude (projected, geocentric) is refused (trial-odm: both were taken silently, the
    geoid's 20 m ignored)."""
    from aerotri.core.errors import OptionError
    from aerotri.geom.crs.definition import horizontal_crs, parse_crs, vertical_crs
    from aerotri.geom.crs.transform import transform_points

    c = parse_crs(crs, "--crs")
    if not horizontal_crs(c).is_geographic:
        raise OptionError(f"{crs}: reference_lla is a latitude, longitude and altitude; expected a geographic CRS (e.g. "
                          "EPSG:4979, or EPSG:4326+3855 for an altitude above the EGM2008 geoid)", param="--crs")
    if not c.is_compound or vertical_crs(c) is None:
        return ref, crs
    lon, lat, h = transform_points(np.array([float(ref["longitude"])]), np.array([float(ref["latitude"])]),
                                   np.array([float(ref["altitude"])]), from_crs=c, to_crs=parse_crs(DEFAULT_CRS))
    return ({"latitude": float(lat[0]), "longitude": float(lon[0]), "altitude": float(h[0])},
            f"{DEFAULT_CRS} (altitude {float(ref['altitude']):g} in {crs}: h {float(h[0]):.3f})")


def read(files, project: Project, options: ImportSettings) -> ImportedBlock:
    """The ``opensfm`` importer (see the module docstring)."""
    if len(files) != 1:
        raise InputError(f"opensfm expects one reconstruction.json, got {len(files)} files")
    path = Path(files[0])
    if path.is_dir():
        path = path / "reconstruction.json"
    rec, ref, others = read_reconstruction(path)
    block = ImportedBlock(source=[str(path)], origin={"camera": path.name, "eo": path.name, "gnss": path.name})
    if others:  # in imports.json and on the console, not only in a log line
        left = [f"{len(o)} shot{'s' if len(o) != 1 else ''} ({id_listing(o)})" for o in others]
        block.notes.append(f"orientations: {path.name} holds {len(others) + 1} reconstructions (OpenSfM could not "
                           f"join the block); the largest imported ({len(rec['shots'])} shots), left out: "
                           + "; ".join(left))
    if len(rec["cameras"]) != 1:
        raise InputError(f"{path}: {len(rec['cameras'])} cameras; the project holds one (import each camera's "
                         f"shots into their own project)")
    cam_id, cam = next(iter(rec["cameras"].items()))
    shot_ids = sorted(rec["shots"])
    size, pixel_um = _pixel_size_um(project, block, _frame_file(project, path, shot_ids), path)
    block.camera, notes = camera_from_opensfm(cam, f"{path} camera {cam_id!r}", size, pixel_um, name=str(cam_id))
    block.notes += notes
    crs = options.crs or DEFAULT_CRS
    source = f"{path} reference_lla ({crs})"
    ref, crs = _reference_on_ellipsoid(ref, crs)
    centres, R_cv, gps, dop = [], [], [], []
    for sid in shot_ids:
        shot = rec["shots"][sid]
        where = f"{path} shot {sid!r}"
        if not isinstance(shot, dict):
            raise InputError(f"{where}: expected an object")
        if shot.get("camera") != cam_id:
            raise InputError(f"{where}: camera {shot.get('camera')!r} is not the reconstruction's camera {cam_id!r}")
        R_wc = rotation_from_axis_angle(_vector(shot, "rotation", where))
        t = _vector(shot, "translation", where)
        centres.append(-R_wc.T @ t)
        R_cv.append(R_wc.T)
        gps.append(_vector(shot, "gps_position", where) if "gps_position" in shot else None)
        dop.append(_number(shot, "gps_dop", where, positive=True) if "gps_dop" in shot else None)
    ids = [Path(s).stem for s in shot_ids]
    offset = utm_offset_frame(ref, np.array(centres), gps)
    if offset is not None:
        # ODM's reconstruction.json after export_geocoords: UTM minus a whole-metre offset (reference_lla), heights
        # ellipsoidal; its gps_position stays topocentric (trial-odm: read as topocentric, the Tuniu shots came in
        # turned 0.856 deg, the grid convergence, and 1.1-2.1 m off their own RTK GNSS)
        from aerotri.exchange.poses import orientations_to_project

        epsg, e0, n0 = offset
        utm = pyproj.CRS.from_epsg(epsg).to_3d()
        block.eo = orientations_to_project(ids, np.array(centres) + [e0, n0, 0.0], np.array(R_cv) @ FLIP_YZ, utm,
                                           project, f"{path} (EPSG:{epsg} minus {e0:.0f}, {n0:.0f})")
        block.notes.append(f"orientations: ODM's georeferenced solution (EPSG:{epsg} minus the offset {e0:.0f}, "
                           f"{n0:.0f} that reference_lla marks, heights above the WGS84 ellipsoid; not OpenSfM's "
                           "topocentric frame: reference_lla lies on whole metres of the grid"
                           + (", and the shots' centres agree with their gps_position so read" if any(
                               g is not None for g in gps) else "") + ")")
    else:
        C_map, R_map = topocentric_to_project(ref, crs, project, np.array(centres), np.array(R_cv), source)
        block.eo = ExteriorOrientations(ids, C_map, np.stack(opk_from_matrix(R_map), axis=-1))
        block.notes.append(f"orientations: OpenSfM's solution (topocentric frame at lat {ref['latitude']:.8f}, lon "
                           f"{ref['longitude']:.8f}, altitude {ref['altitude']:g} taken as {crs})")
    with_gps = [g is not None for g in gps]
    if options.as_gnss:
        if not all(with_gps):
            missing = [s for s, g in zip(shot_ids, with_gps) if not g]
            raise InputError(f"{path}: --as-gnss: shot(s) {', '.join(missing[:10])} have no gps_position")
        gps_map, _ = topocentric_to_project(ref, crs, project, np.array(gps), None, source)
        own = np.array([[d, d, d] for d in dop]) if all(d is not None for d in dop) else None
        block.gnss, block.gnss_holds = positions_as_gnss(ids, gps_map, options=options, project=project,
                                                         what="the shots' gps_position", own_sigma_m=own,
                                                         own_sigma_name="OpenSfM gps_dop (in X, Y and Z)")
    elif any(with_gps):
        d = [v for v in dop if v is not None]
        block.notes.append(f"{sum(with_gps)} shots carry gps_position" + (f" (gps_dop {min(d):.3g}..{max(d):.3g} m)"
                           if d else "") + ": not imported; --as-gnss writes them to gnss.txt")
    return block


# -- export ------------------------------------------------------------------------------------------

def _camera_to_opensfm(camera: Camera) -> dict:
    """OpenSfM's ``brown`` camera of ours (a pinhole: zero coefficients; ``camera_to_json``'s keys)."""
    w, h = camera.width, camera.height
    s = float(max(w, h))
    f = camera.focal_px / s
    k = {c: float(getattr(camera, c, 0.0)) for c in ("k1", "k2", "p1", "p2", "k3")}
    return {"projection_type": "brown", "width": int(w), "height": int(h), "focal_x": f, "focal_y": f,
            "c_x": (camera.cx_px - (w - 1) / 2.0) / s, "c_y": (camera.cy_px - (h - 1) / 2.0) / s, **k}


def camera_id_of(camera: Camera) -> str:
    """The camera's OpenSfM id: its name when it is one (``v2 ...``: imported from OpenSfM/ODM, so ODM's
    ``--cameras`` matches it to the frames' EXIF), else OpenSfM's pattern ``v2 <make> <model> <width>
    <height> <projection> <focal ratio>`` with make ``aerotri`` and our camera name as the model."""
    if camera.name.startswith("v2 "):
        return camera.name
    ratio = str(float(camera.focal_px / max(camera.width, camera.height)))[:6]
    return " ".join(["v2", "aerotri", camera.name.strip() or "camera", str(camera.width), str(camera.height), "brown",
                     ratio]).lower()


def reconstruction(eo: ExteriorOrientations, camera: Camera, project: Project, reference: dict,
                   shot_names: dict | None = None, *, points=None, gnss: GnssPositions | None = None,
                   gnss_sigma_m: float | None = None, lever_arm_m=None) -> dict:
    """One OpenSfM reconstruction (a JSON object): shots of ``eo`` (project CRS), ``camera``, topocentric
    frame at ``reference`` (reference_lla); ``shot_names``: image id -> shot id (the frames' file names);
    ``points``: (ids, (P, 3) project CRS); ``gnss``: the shots' gps_position with gps_dop = its sX (or
    ``gnss_sigma_m``). OpenSfM takes gps_position for the camera centre's prior (``_gps_errors``: optical centre -
    gps): the antenna positions are reduced to the centres by ``lever_arm_m`` (camera frame, x right, y up, z up; the
    adjustment's) turned by each shot's adjusted attitude (trial s100 ex F1: the demo's antennas, 1.46 m above the
    centres, were written as they are)."""
    from scipy.spatial.transform import Rotation

    names = shot_names or {}
    cam_id = camera_id_of(camera)
    topo, R_cv = project_to_topocentric(reference, project, eo.centre_m, eo.rotations(), "orientations")
    R_wc = np.swapaxes(R_cv, -1, -2)
    rotvec = Rotation.from_matrix(R_wc).as_rotvec()
    t = -np.einsum("nij,nj->ni", R_wc, topo)
    gps = {}
    if gnss is not None:
        gi = {k: i for i, k in enumerate(gnss.image_id)}  # the frames with a GNSS position
        g_topo, _ = project_to_topocentric(reference, project, gnss.position_m, None, "gnss.txt")
        arm = FLIP_YZ @ np.asarray(lever_arm_m if lever_arm_m is not None else (0.0, 0.0, 0.0), dtype=float)
        for i, iid in enumerate(eo.image_id):
            if iid in gi:
                k = gi[iid]
                g_topo[k] = g_topo[k] - R_cv[i] @ arm  # antenna = centre + R l
                dop = float(gnss.sigma_m[k, 0]) if gnss.sigma_m is not None else gnss_sigma_m
                gps[iid] = {"gps_position": [float(v) for v in g_topo[k]]} | ({"gps_dop": dop} if dop else {})
    shots = {}
    for i, iid in enumerate(eo.image_id):
        shots[names.get(iid, iid)] = {"rotation": [float(v) for v in rotvec[i]], "translation": [float(v) for v in t[i]],
                                      "camera": cam_id, "orientation": 1, **gps.get(iid, {})}
    rec = {"cameras": {cam_id: _camera_to_opensfm(camera)}, "shots": shots, "points": {}, "biases": {},
           "reference_lla": dict(reference)}
    if points is not None:
        pid, xyz = points
        p_topo, _ = project_to_topocentric(reference, project, xyz, None, "object points")
        rec["points"] = {str(p): {"color": [128.0, 128.0, 128.0], "coordinates": [float(v) for v in c]}
                         for p, c in zip(pid, p_topo)}
    return rec
