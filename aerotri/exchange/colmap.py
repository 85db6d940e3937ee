"""COLMAP models: export (text ``colmap/`` and binary ``colmap_bin/``) and import (text or binary).

Export: one camera (OPENCV for a Brown camera, FULL_OPENCV when k3 is not zero, PINHOLE for a pinhole)
with the adjusted interior orientation (at/camera.toml, a known k3 included; the 2D points as measured); poses world-to-camera (computer-vision camera frame: x right, y
down, z forward) in the adjustment's local ENU frame; pixel coordinates shifted by +0.5 (COLMAP's origin
is the corner of the top-left pixel, ours the centre); image names are the image files' names in
``images/`` (with their extension), so COLMAP finds the frames. The binary model is the text model
written by pycolmap (``Reconstruction.write_binary``). Beside each model, ``georef.txt`` says what COLMAP
files cannot::

    # aerotri: the world frame of this COLMAP model
    frame local_enu          # world = ENU tangent plane at origin_map (aerotri.geom.local_frame)
    crs EPSG:32649           # the CRS of origin_map (the rest of the line; with [project] heights a vertical
                             # CRS: the compound CRS's WKT, so an import converts the heights)
    origin_map 500000.000 4100000.000 850.000
    pixel_um 12.0            # the sensor's pixel size (COLMAP cameras are in pixels only)

Import (``aerotri import P --format colmap MODEL_FOLDER`` or its files): cameras -> camera.toml (one
camera; SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV with k4 = k5 = k6 = 0;
fx and fy averaged), images -> imported/eo.txt (approximations) in the project CRS; the projection centres
go to gnss.txt only with ``--as-gnss`` (accuracies from ``--sigma-xyz-m``: COLMAP models carry none). The world frame comes
from ``georef.txt`` (our exports; or written by hand: ``frame local_enu`` + ``crs`` + ``origin_map``),
else the text model's header comment of our older exports, else ``--crs``: a foreign model must be
georeferenced already (e.g. ``colmap model_aligner``), its world coordinates in that CRS (projected, or
geocentric EPSG:4978); a model in an arbitrary frame cannot be imported. Pixel size: ``georef.txt``, else
the project's camera.toml, else a nominal 1 um (focal length in pixels kept; a note says so). Text files
are read here (errors name the file and line); binary files through pycolmap.
"""

from __future__ import annotations

import dataclasses
import re
import tempfile
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError, InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_text
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.imported import ImportedBlock, ImportSettings, positions_as_gnss
from aerotri.exchange.poses import image_id_of, number, orientations_to_project
from aerotri.geom.camera import BrownCamera, PinholeCamera
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.rotation import FLIP_YZ

# model -> names of its PARAMS (COLMAP's src/colmap/sensor/models.h)
MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}
GEOREF = "georef.txt"
_HEADER = re.compile(r"#\s*local ENU frame of the adjustment, origin (\S+) (\S+) (\S+) in (.+)$")


def _quat_wxyz(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (robust near 180 degrees, as for nadir cameras)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return w, x, y, z


def _matrix_of_quat(q, where: str) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, float)
    n = np.linalg.norm(q)
    if not 0.5 < n < 2.0:
        raise InputError(f"{where}: quaternion QW QX QY QZ = {' '.join(f'{v:g}' for v in q)} is not a rotation "
                         "(norm far from 1)")
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


# -- export ------------------------------------------------------------------------------------------

def georef_text(block: AdjustedBlock, crs: str | None = None) -> str:
    """``crs``: the CRS of origin_map with the project's heights (``project_crs_3d``: a compound CRS's WKT when
    ``[project] heights`` is a vertical CRS); default ``block.crs``. With the horizontal CRS alone a model of
    EGM2008 heights imported into an ellipsoidal project stood N low (before trial-exchange)."""
    o = block.frame.origin_map
    return ("# aerotri: the world frame of this COLMAP model (ENU tangent plane at origin_map, aerotri.geom.local_frame)\n"
            "frame local_enu\n"
            f"crs {crs or block.crs}\n"
            f"origin_map {float(o[0])!r} {float(o[1])!r} {float(o[2])!r}\n"  # in full: poses and points hang on it
            f"pixel_um {block.camera.pixel_um!r}\n")


def files(block: AdjustedBlock, image_names: dict | None = None, georef_crs: str | None = None) -> list[ExportFile]:
    """The text model ``colmap/``; ``image_names``: image id -> file name (default: the id); ``georef_crs``: the
    CRS written to georef.txt (``georef_text``)."""
    cam = block.oriented
    # the camera of the orientations with all of its model (a known k3 too: FULL_OPENCV) and the measurements
    # as measured, so that the model fits the image files (COLMAP's PARAMS start fx fy cx cy in every model)
    model, params = cam.colmap_model()
    origin = block.frame.origin_map
    head = f"# local ENU frame of the adjustment, origin {origin[0]:.3f} {origin[1]:.3f} {origin[2]:.3f} in {block.crs}"
    cams = [head, "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"1 {model} {cam.width} {cam.height} " + " ".join(f"{v:.6f}" for v in params[:4])
            + "".join(f" {v:.10g}" for v in params[4:])]
    used = np.unique(block.obs_point)
    pid3 = {int(j): n + 1 for n, j in enumerate(used)}
    imgs = [head, "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    track = {j: [] for j in pid3}
    names = image_names or {}
    by_image = np.argsort(block.obs_image, kind="stable")  # each image's observations in file order, at once
    bounds = np.searchsorted(block.obs_image[by_image], np.arange(len(block.image_id) + 1))
    for i, iid in enumerate(block.image_id):
        Rwc = block.R_cv[i].T
        t = -Rwc @ block.centre_local[i]
        q = _quat_wxyz(Rwc)
        imgs.append(f"{i + 1} " + " ".join(f"{v:.12f}" for v in q) + " " + " ".join(f"{v:.6f}" for v in t)
                    + f" 1 {names.get(iid, iid)}")
        pts = []
        for n, k in enumerate(by_image[bounds[i]:bounds[i + 1]].tolist()):
            j = int(block.obs_point[k])
            pts.append(f"{block.obs_measured_px[k, 0] + 0.5:.3f} {block.obs_measured_px[k, 1] + 0.5:.3f} {pid3[j]}")
            track[j].append(f"{i + 1} {n}")
        imgs.append(" ".join(pts))
    p3 = [head, "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    for j, n in pid3.items():
        X, Y, Z = block.points_local[j]
        p3.append(f"{n} {X:.4f} {Y:.4f} {Z:.4f} 128 128 128 {block.point_rms_px[j]:.4f} " + " ".join(track[j]))
    return [ExportFile("colmap/cameras.txt", "\n".join(cams) + "\n"), ExportFile("colmap/images.txt", "\n".join(imgs) + "\n"),
            ExportFile("colmap/points3D.txt", "\n".join(p3) + "\n"), ExportFile(f"colmap/{GEOREF}", georef_text(block, georef_crs))]


def binary_files(block: AdjustedBlock, image_names: dict | None = None, georef_crs: str | None = None
                 ) -> list[ExportFile]:
    """The binary model ``colmap_bin/`` (the text model written by pycolmap) and its georef.txt."""
    import pycolmap

    out = []
    with tempfile.TemporaryDirectory(prefix="aerotri-colmap-") as tmp:
        txt, bin_ = Path(tmp) / "txt", Path(tmp) / "bin"
        txt.mkdir()
        bin_.mkdir()
        for f in files(block, image_names):
            (txt / Path(f.path).name).write_text(f.content)
        rec = pycolmap.Reconstruction()
        rec.read_text(str(txt))
        rec.write_binary(str(bin_))
        for f in sorted(bin_.iterdir()):
            out.append(ExportFile(f"colmap_bin/{f.name}", f.read_bytes()))
    out.append(ExportFile(f"colmap_bin/{GEOREF}", georef_text(block, georef_crs)))
    return out


# -- import ------------------------------------------------------------------------------------------

def _lines(path: Path):
    for n, line in enumerate(read_text(path, "COLMAP text model").splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            yield n, s


def _read_cameras_txt(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    """camera id -> (model, width, height, params) of ``cameras.txt``."""
    cams = {}
    for n, s in _lines(path):
        where = f"{path}:{n}"
        f = s.split()
        if len(f) < 4:
            raise InputError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {s!r}")
        model = f[1]
        if model not in MODELS:
            raise InputError(f"{where}: camera model {model} is not one of {', '.join(MODELS)}")
        if len(f) != 4 + len(MODELS[model]):
            raise InputError(f"{where}: {model} has {len(MODELS[model])} PARAMS ({' '.join(MODELS[model])}), "
                             f"got {len(f) - 4}")
        try:
            cid, w, h = int(f[0]), int(f[2]), int(f[3])
        except ValueError:
            raise InputError(f"{where}: CAMERA_ID, WIDTH and HEIGHT must be whole numbers, got {s!r}") from None
        if cid in cams:
            raise InputError(f"{where}: duplicate CAMERA_ID {cid}")
        cams[cid] = (model, w, h, [number(v, where, k) for k, v in zip(MODELS[model], f[4:])])
    if not cams:
        raise InputError(f"{path}: no cameras")
    return cams


def _read_images_txt(path: Path) -> list[tuple[str, int, np.ndarray, np.ndarray, str]]:
    """(name, camera id, R world -> camera (3, 3), t (3,), where) per image of ``images.txt`` (every other
    data line: the image line, then its points line, which may be empty)."""
    text = read_text(path, "COLMAP text model")
    out, seen, expect_points = [], {}, False
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s.startswith("#"):
            continue
        if expect_points:  # the POINTS2D line of the image before (not needed for the orientations)
            expect_points = False
            if len(s.split()) % 3:  # X Y POINT3D_ID triples: not the next image's line taken for points
                last = n == len(text.splitlines()) and len(s.split()) > 10
                raise InputError(f"{path}:{n}: expected the POINTS2D line (X Y POINT3D_ID triples, or an empty line) "
                                 f"of the image on line {seen[out[-1][0]]}, got {len(s.split())} fields"
                                 + (", not a multiple of 3 on the file's last line: the file is cut short"
                                    if last else ": each image line of images.txt is followed by its points line"))
            continue
        if not s:
            continue
        where = f"{path}:{n}"
        f = s.split()
        if len(f) < 10:
            raise InputError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {len(f)} fields")
        vals = [number(v, where, k) for k, v in zip(("QW", "QX", "QY", "QZ", "TX", "TY", "TZ"), f[1:8])]
        try:
            cid = int(f[8])
        except ValueError:
            raise InputError(f"{where}: CAMERA_ID {f[8]!r} is not a whole number") from None
        name = " ".join(f[9:])
        if name in seen:
            raise InputError(f"{where}: duplicate image {name!r} (first on line {seen[name]})")
        seen[name] = n
        out.append((name, cid, _matrix_of_quat(vals[:4], where), np.array(vals[4:7]), where))
        expect_points = True
    if not out:
        raise InputError(f"{path}: no images")
    return out


def _read_binary(folder: Path):
    import pycolmap

    rec = pycolmap.Reconstruction()
    try:
        rec.read_binary(str(folder))
    except Exception as exc:  # pycolmap raises RuntimeError/ValueError for unreadable binary models
        sizes = ", ".join(f"{f} {(folder / f).stat().st_size:,} bytes" for f in ("cameras.bin", "images.bin",
                                                                                   "points3D.bin")
                          if (folder / f).is_file())
        raise InputError(f"{folder}: not a readable COLMAP binary model: pycolmap stopped reading it ({exc}); a file "
                         f"cut short or of another COLMAP version? ({sizes or 'no .bin files'})".replace("\n", " "))\
            from None
    cams = {int(cid): (c.model.name, int(c.width), int(c.height), [float(v) for v in c.params])
            for cid, c in rec.cameras.items()}
    for cid, (model, *_r, params) in cams.items():
        if model not in MODELS:
            raise InputError(f"{folder}/cameras.bin: camera {cid}: model {model} is not one of {', '.join(MODELS)}")
        if not all(np.isfinite(params)):
            raise InputError(f"{folder}/cameras.bin: camera {cid}: PARAMS NaN or infinite")
    images = []
    for iid in sorted(rec.reg_image_ids()):
        im = rec.image(iid)
        pose = im.cam_from_world()
        R, t = np.asarray(pose.rotation.matrix(), float), np.asarray(pose.translation, float)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise InputError(f"{folder}/images.bin: image {im.name!r}: pose NaN or infinite")
        images.append((im.name, int(im.camera_id), R, t, f"{folder}/images.bin image {im.name!r}"))
    if not images:
        raise InputError(f"{folder}/images.bin: no registered images")
    return cams, images


@dataclasses.dataclass(frozen=True)
class ColmapGeoref:
    """The world frame of a COLMAP model (``georef.txt``): ``frame`` local_enu (about ``origin_map`` in
    ``crs``, metres) or crs (the model in ``crs`` itself); the sensor's pixel size (um) when known. None:
    not given."""

    frame: str | None = None
    crs: str | None = None
    origin_map: tuple[float, float, float] | None = None
    pixel_um: float | None = None

    @property
    def local_enu(self) -> bool:
        """The model is in a local ENU frame about ``origin_map`` (the default frame)."""
        return (self.frame or "local_enu") == "local_enu" and self.origin_map is not None


def read_georef(folder: Path) -> ColmapGeoref | None:
    """``georef.txt`` of a model folder (frame, crs, origin_map, pixel_um), None when there is none."""
    path = folder / GEOREF
    if not path.is_file():
        return None
    out = {}
    for n, line in enumerate(read_text(path, "COLMAP georeference").splitlines(), start=1):
        s = line.split("#", 1)[0].strip()  # WKT and PROJ strings hold no '#'

        if not s:
            continue
        key, _, value = s.partition(" ")
        where = f"{path}:{n}"
        value = value.strip()
        if key == "frame":
            if value not in ("local_enu", "crs"):
                raise InputError(f"{where}: frame {value!r} is not local_enu or crs")
            out["frame"] = value
        elif key == "crs":
            out["crs"] = value
        elif key == "origin_map":
            v = value.split()
            if len(v) != 3:
                raise InputError(f"{where}: origin_map needs 3 numbers X Y Z, got {len(v)}")
            out["origin_map"] = tuple(number(x, where, "origin_map") for x in v)
        elif key == "pixel_um":
            out["pixel_um"] = number(value, where, "pixel_um")
        else:
            raise InputError(f"{where}: unknown key {key!r} (expected frame, crs, origin_map, pixel_um)")
    if out.get("frame", "local_enu") == "local_enu" and ("crs" not in out or "origin_map" not in out):
        raise InputError(f"{path}: frame local_enu needs crs and origin_map")
    if out.get("frame") == "crs" and "crs" not in out:
        raise InputError(f"{path}: frame crs needs crs")
    return ColmapGeoref(**out)


def _header_georef(folder: Path) -> ColmapGeoref | None:
    """The frame of our older text exports' header comment, or None."""
    for name in ("cameras.txt", "images.txt"):
        p = folder / name
        if p.is_file():
            for line in read_text(p, "COLMAP text model").splitlines()[:3]:
                m = _HEADER.match(line.strip())
                if m:
                    return ColmapGeoref("local_enu", m.group(4).strip(), tuple(float(m.group(k)) for k in (1, 2, 3)))
    return None


def camera_of(cams: dict, images: list, pixel_um: float, where: str):
    """Our camera of the COLMAP camera(s) the images use; PARAMS -> focal, principal point (pixel centre
    origin), Brown coefficients."""
    used = sorted({cid for _, cid, *_r in images})
    missing = [c for c in used if c not in cams]
    if missing:
        raise InputError(f"{where}: images use CAMERA_ID(s) {missing}, which cameras does not have")
    distinct = {(cams[c][0], cams[c][1], cams[c][2], tuple(cams[c][3])) for c in used}
    if len(distinct) > 1:
        raise InputError(f"{where}: the images use {len(distinct)} different cameras; a project has one camera "
                         "(import the images of one camera at a time)")
    model, w, h, params = cams[used[0]]
    p = dict(zip(MODELS[model], params))
    fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
    notes = []
    if abs(fx - fy) > 1e-6 * fx:
        notes.append(f"COLMAP camera {used[0]}: fx {fx:.6f} and fy {fy:.6f} differ; their mean is the focal length")
    if model == "FULL_OPENCV" and any(p[k] for k in ("k4", "k5", "k6")):
        raise InputError(f"{where}: camera {used[0]}: FULL_OPENCV k4 k5 k6 must be zero (our Brown model has k1 k2 k3 "
                         "p1 p2)")
    if fx <= 0 or fy <= 0 or w <= 0 or h <= 0:
        raise InputError(f"{where}: camera {used[0]}: focal length and image size must be positive")
    f_px = 0.5 * (fx + fy)
    pix_mm = pixel_um / 1000.0
    geometry = dict(focal_mm=f_px * pix_mm, pixel_um=pixel_um, width=w, height=h,
                    ppx_mm=(p["cx"] - 0.5 - (w - 1) / 2.0) * pix_mm, ppy_mm=-(p["cy"] - 0.5 - (h - 1) / 2.0) * pix_mm,
                    name=f"colmap camera {used[0]}")
    try:
        if model in ("SIMPLE_PINHOLE", "PINHOLE"):
            cam = PinholeCamera(**geometry)
        else:
            cam = BrownCamera(**geometry, **{k: p.get(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2")})
    except InputError as exc:
        raise InputError(f"{where}: camera {used[0]}: {exc}") from None
    return cam, notes


def _folder_of(files: list[Path]) -> Path:
    folders = {f if f.is_dir() else f.parent for f in files}
    if len(folders) != 1:
        raise InputError(f"{', '.join(map(str, files))}: expected one COLMAP model folder (or files of one folder)")
    return folders.pop()


def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    """A COLMAP model (text or binary; see the module docstring) -> camera, orientations and positions."""
    folder = _folder_of(files)
    block = ImportedBlock(source=[str(folder)])
    if (folder / "cameras.txt").is_file() and (folder / "images.txt").is_file():
        cams, images = _read_cameras_txt(folder / "cameras.txt"), _read_images_txt(folder / "images.txt")
        where = str(folder / "images.txt")
    elif (folder / "cameras.bin").is_file() and (folder / "images.bin").is_file():
        cams, images = _read_binary(folder)
        where = str(folder / "images.bin")
    else:
        raise InputError(f"{folder}: no COLMAP model (expected cameras.txt + images.txt or cameras.bin + images.bin)")
    georef = read_georef(folder)
    # where the frame was read (trial s96 L2: a model without georef.txt named it in its warnings)
    georef_from = f"{folder}/{GEOREF}" if georef is not None else f"{folder}/cameras.txt header"
    georef = georef or _header_georef(folder)
    # pixel size: georef.txt, else the project's camera, else nominal
    if georef is not None and georef.pixel_um is not None:
        pixel_um = georef.pixel_um
    elif project.camera_path.is_file():
        from aerotri.geom.camera import read_camera

        pixel_um = read_camera(project.camera_path).pixel_um
        block.notes.append(f"pixel size {pixel_um} um taken from {project.camera_path} (COLMAP cameras are in pixels)")
    else:
        pixel_um = 1.0
        block.notes.append("no pixel size (COLMAP cameras are in pixels): a nominal 1 um; edit camera.toml for the "
                           "physical sensor")
    block.camera, notes = camera_of(cams, images, pixel_um, where)
    block.notes += notes
    # poses: world -> camera (computer-vision frame) -> centre and photogrammetric camera -> world
    R_wc = np.array([im[2] for im in images])
    t = np.array([im[3] for im in images])
    centre = -np.einsum("nji,nj->ni", R_wc, t)
    R_photo = np.transpose(R_wc, (0, 2, 1)) @ FLIP_YZ
    ids = [image_id_of(im[0]) for im in images]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise InputError(f"{where}: image names {sorted(dup)} give the same image id twice")
    if georef is not None and georef.local_enu:
        frame = LocalFrame(georef.crs, list(georef.origin_map))
        centre_map = frame.to_map(centre)
        R_map = np.transpose(frame.rotation_local_from_map(centre_map), (0, 2, 1)) @ R_photo
        block.eo = orientations_to_project(ids, centre_map, R_map, georef.crs, project, f"{georef_from} crs")
    elif (georef is not None and georef.crs) or options.crs:
        crs = (georef.crs if georef is not None else None) or options.crs
        block.eo = orientations_to_project(ids, centre, R_photo, crs, project,
                                           "--crs" if georef is None else georef_from)
    else:
        raise CrsError(f"{folder}: the model's world frame is unknown; a foreign COLMAP model must be georeferenced "
                       f"(colmap model_aligner) and its CRS given with --crs, or described in {GEOREF}")
    block.origin = {"camera": Path(where).name.replace("images", "cameras"), "eo": Path(where).name}
    if options.as_gnss:
        block.gnss, block.gnss_holds = positions_as_gnss(ids, block.eo.centre_m, options=options, project=project,
                                                         what="projection centres of the COLMAP model")
        block.origin["gnss"] = Path(where).name
    return block
