"""orthority's parameter files (https://github.com/leftfield-geospatial/orthority): import and export.

Files (orthority 0.7 docs, "file formats"):

- interior parameters, YAML: ``{camera_id: {type, im_size: [w, h], focal_len, sensor_size: [w, h], cx, cy,
  k1 k2 p1 p2 k3}}``. ``type``: ``pinhole`` (no distortion) or ``brown`` (= OpenCV's k1 k2 p1 p2 k3 on
  normalised coordinates, our Brown model); ``opencv`` is read when it uses only those coefficients.
  ``focal_len`` and ``sensor_size`` share one unit, which this module takes as millimetres (orthority's
  examples); without ``sensor_size`` the focal length is normalised by the image width. ``cx``, ``cy``:
  the principal point's offset from the image centre in "normalised image coordinates" (pixels / max(w, h),
  x right, y down): principal point in pixels = ((w - 1) / 2 + cx max(w, h), (h - 1) / 2 + cy max(w, h)),
  pixel origin at the centre of the top-left pixel, as ours.
- exterior parameters, OPK CSV: ``filename,x,y,z,omega,phi,kappa[,camera]`` (world CRS units, degrees),
  its CRS in a ``.prj`` sidecar of the same stem (WKT or PROJ string; else ``--crs``);
- exterior parameters, GeoJSON: a FeatureCollection with ``world_crs`` and one Point feature per image,
  ``properties: {filename, camera, xyz: [x, y, z], opk: [omega, phi, kappa] (radians)}`` and the geometry
  at the camera's longitude/latitude.

orthority's omega phi kappa rotate from the camera frame in the PATB convention (x right, y up, z back) to
world coordinates with R = Rx(omega) Ry(phi) Rz(kappa): our convention (``aerotri.geom.rotation``), so
angles pass unchanged (checked on the NGI block: orthority's ngi_xyz_opk.csv carries the national AT's
camera_pos_ori.txt angles, and orthority's camera projects our object points to our pixels).

Import: camera.toml (one camera) and imported/eo.txt (approximations) in the project CRS; the camera
positions go to gnss.txt only with ``--as-gnss`` (accuracies from ``--sigma-xyz-m``: the files carry none).
Export (``orthority/``): ``int_param.yaml``, ``ext_param.csv`` + ``ext_param.prj`` and ``ext_param.geojson`` of the adjusted orientations (``at/eo.txt``, project CRS, its heights) and the
self-calibrated camera.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError, InputError
from aerotri.core.project import Project
from aerotri.core.textio import read_text
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.imported import ImportedBlock, ImportSettings, positions_as_gnss
from aerotri.exchange.poses import (adjusted_orientations, horizontal_wkt, image_id_of, number,
                                    opk_orientations_to_project)
from aerotri.geom.camera import BrownCamera, Camera, PinholeCamera
from aerotri.geom.eo import ExteriorOrientations

log = logging.getLogger(__name__)

BROWN_KEYS = ("k1", "k2", "p1", "p2", "k3")
# a focal length over this many times the longer side, read from focal_len without sensor_size, is said: a drone or
# aerial lens is 0.5-2 (Tuniu's DJI FC6310R 0.67, the DMC 0.72); focal_len in mm (8.8 on 1728 px frames:
# 15,206 px) reads as 8.8 sides, which the 100-sides limit of Camera.check_plausible passes
NORMALISED_FOCAL_WARN = 4.0
OPTIONAL_KEYS = {"pinhole": ("sensor_size", "cx", "cy"), "brown": ("sensor_size", "cx", "cy") + BROWN_KEYS,
                 "opencv": ("sensor_size", "cx", "cy") + BROWN_KEYS}
OPENCV_EXTRA = ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")  # read only when zero


# -- interior parameters -----------------------------------------------------------------------------

def _pair(value, where: str, key: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise InputError(f"{where}: {key} must be a list of 2 numbers [width, height], got {value!r}")
    return number(value[0], where, key), number(value[1], where, key)


def camera_from_int_param(cam_id: str, p: dict, where: str) -> Camera:
    """Our camera of one camera's interior parameters (see the module docstring)."""
    where = f"{where} camera {cam_id!r}"
    if not isinstance(p, dict):
        raise InputError(f"{where}: expected a mapping of interior parameters, got {p!r}")
    for key in ("type", "im_size", "focal_len"):
        if key not in p:
            raise InputError(f"{where}: '{key}' is missing (expected type, im_size, focal_len[, sensor_size, cx, cy, k1..])")
    kind = str(p["type"]).lower()
    if kind not in OPTIONAL_KEYS:
        raise InputError(f"{where}: type {p['type']!r} is not one of {', '.join(OPTIONAL_KEYS)} (our lens models)")
    unknown = sorted(set(p) - {"type", "im_size", "focal_len", "name"} - set(OPTIONAL_KEYS[kind])
                     - (set(OPENCV_EXTRA) if kind == "opencv" else set()))
    if unknown:
        raise InputError(f"{where}: unsupported key(s) {unknown} for type {kind!r}")
    if kind == "opencv":
        extra = [k for k in OPENCV_EXTRA if k in p and number(p[k], where, k) != 0.0]
        if extra:
            raise InputError(f"{where}: opencv coefficients {extra} are not zero; our Brown model has k1 k2 p1 p2 k3 only")
    w, h = _pair(p["im_size"], where, "im_size")
    if w != int(w) or h != int(h) or w <= 0 or h <= 0:
        raise InputError(f"{where}: im_size must be two positive whole numbers of pixels, got {p['im_size']!r}")
    w, h = int(w), int(h)
    f = p["focal_len"]
    fx, fy = _pair(f, where, "focal_len") if isinstance(f, (list, tuple)) else (number(f, where, "focal_len"),) * 2
    if abs(fx - fy) > 1e-6 * abs(fx):
        raise InputError(f"{where}: focal_len {f!r} has different x and y values; our cameras have one focal length")
    if fx <= 0:
        raise InputError(f"{where}: focal_len must be positive, got {f!r}")
    if "sensor_size" in p:
        sw, sh = _pair(p["sensor_size"], where, "sensor_size")
        if sw <= 0 or sh <= 0:
            raise InputError(f"{where}: sensor_size must be positive, got {p['sensor_size']!r}")
        if abs(sw / w - sh / h) > 1e-6 * sw / w:
            raise InputError(f"{where}: sensor_size / im_size gives non-square pixels ({sw / w:.6g} x {sh / h:.6g}); "
                             "our cameras have square pixels")
        pixel_um, focal_mm = sw / w * 1000.0, fx
    else:
        # focal length normalised by the image width: only the focal length in pixels is known; keep a
        # nominal pixel of 1 um (every result depends on focal_mm / pixel_um only)
        if fx > Camera.MAX_FOCAL_PER_SIDE:
            # focal_len: 120 (mm) with sensor_size left out: a 207,360 px lens on 1728 px frames, written with exit 0
            raise InputError(f"{where}: focal_len {fx:g} without sensor_size is normalised by the image width "
                             f"(orthority's convention): {fx * w:.6g} px, a field of view under "
                             f"{math.degrees(2 * math.atan(0.5 / fx)):.2g} deg; a focal length in mm or pixels needs "
                             "sensor_size in the same unit (mm, or im_size for pixels)")
        pixel_um, focal_mm = 1.0, fx * w / 1000.0
    scale = max(w, h)
    cx, cy = (number(p.get(k, 0.0), where, k) for k in ("cx", "cy"))
    # principal point offset from the image centre: orthority's x right, y down -> our photo frame, y up
    pp = dict(ppx_mm=cx * scale * pixel_um / 1000.0 + 0.0, ppy_mm=-cy * scale * pixel_um / 1000.0 + 0.0)
    geometry = dict(focal_mm=focal_mm, pixel_um=pixel_um, width=w, height=h, name=str(cam_id), **pp)
    try:
        if kind == "pinhole":
            return PinholeCamera(**geometry)
        return BrownCamera(**geometry, **{k: number(p.get(k, 0.0), where, k) for k in BROWN_KEYS})
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def read_int_param(path: Path) -> tuple[dict[str, Camera], set[str]]:
    """(camera id -> camera, ids of cameras without sensor_size) of an interior parameter file (also the
    flat one-camera layout)."""
    import yaml

    try:
        d = yaml.safe_load(read_text(path, "orthority interior parameters (YAML)"))
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})".replace("\n", " ")) from None
    if isinstance(d, dict) and isinstance(d.get("camera"), dict):  # legacy simple-ortho config.yaml
        d = d["camera"]
    if not isinstance(d, dict) or not d:
        raise InputError(f"{path}: expected a mapping camera id -> interior parameters")
    if not isinstance(next(iter(d.values())), dict):  # the flat layout of one camera
        d = {str(d.get("name", "camera")): d}
    cams = {str(k): camera_from_int_param(str(k), v, str(path)) for k, v in d.items()}
    return cams, {str(k) for k, v in d.items() if "sensor_size" not in v}


def _int_param_of(camera: Camera) -> dict:
    """orthority interior parameters of our camera (mm; cx, cy normalised, y down)."""
    scale = max(camera.width, camera.height)
    sw, sh = camera.sensor_mm
    p = {"type": "pinhole" if isinstance(camera, PinholeCamera) else "brown", "im_size": [camera.width, camera.height],
         "focal_len": float(camera.focal_mm), "sensor_size": [float(sw), float(sh)],
         "cx": float((camera.cx_px - (camera.width - 1) / 2.0) / scale),
         "cy": float((camera.cy_px - (camera.height - 1) / 2.0) / scale)}
    if isinstance(camera, BrownCamera):
        p.update({k: float(getattr(camera, k)) for k in BROWN_KEYS})
    elif not isinstance(camera, PinholeCamera):
        raise InputError(f"camera model {camera.MODEL!r} has no orthority equivalent")
    return p


# -- exterior parameters -----------------------------------------------------------------------------

def _prj_crs(csv_path: Path, options: ImportSettings) -> tuple[str, str]:
    """(CRS text, where it came from) of an OPK CSV: ``--crs`` when given (it overrides a wrong sidecar, said
    when the two differ: trial s96 M7, the sidecar used and --crs dropped without a word), else its ``.prj``
    sidecar."""
    prj = csv_path.with_suffix(".prj")
    if prj.is_file():
        text = read_text(prj, "CRS sidecar (.prj)").strip()
        if not text:
            raise CrsError(f"{prj}: empty (expected the CRS of {csv_path.name} as WKT or a PROJ string)")
        if options.crs:
            from aerotri.geom.crs.definition import crs_label, parse_crs

            given, sidecar = parse_crs(options.crs, "--crs"), parse_crs(text, str(prj))
            if given != sidecar:
                log.warning(f"{csv_path}: --crs {crs_label(given)} taken, not its sidecar {prj.name} "
                            f"({crs_label(sidecar)}: {sidecar.name})")
            return options.crs, "--crs"
        return text, str(prj)
    if options.crs:
        return options.crs, "--crs"
    raise CrsError(f"{csv_path}: no CRS; put it in {prj.name} beside the file or give --crs")


def read_opk_csv(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, list]:
    """(image ids, centres (N, 3), omega phi kappa (N, 3) degrees, camera ids) of an OPK CSV (header
    ``filename,x,y,z,omega,phi,kappa[,camera]``, or those seven columns without a header; comma, space,
    tab or semicolon separated, quotes allowed)."""
    text = read_text(path, "orthority OPK CSV")
    lines = [(n, s) for n, s in enumerate(text.splitlines(), start=1) if s.strip()]
    if not lines:
        raise InputError(f"{path}: empty (expected filename,x,y,z,omega,phi,kappa)")
    first = lines[0][1]
    delimiter = next((d for d in ",;\t" if d in first), " ")
    quote = "'" if first.lstrip().startswith("'") else '"'
    rows = [(n, [c.strip() for c in next(csv.reader(io.StringIO(s), delimiter=delimiter, quotechar=quote,
                                                    skipinitialspace=True)) if c.strip() != ""])
            for n, s in lines]
    head = [c.lower() for c in rows[0][1]]
    if "filename" in head:
        rows = rows[1:]
    else:
        head = ["filename", "x", "y", "z", "omega", "phi", "kappa"]
    need = ("filename", "x", "y", "z", "omega", "phi", "kappa")
    missing = [k for k in need if k not in head]
    if missing:
        what = " (lat/lon/roll/pitch/yaw files: convert them with orthority first)" if "latitude" in head or "roll" in head else ""
        raise InputError(f"{path}:{lines[0][0]}: header lacks {', '.join(missing)}; expected {','.join(need)}[,camera]{what}")
    col = {k: head.index(k) for k in head}
    ids, xyz, opk, cams, seen = [], [], [], [], {}
    for n, r in rows:
        where = f"{path}:{n}"
        if len(r) < len(need) or len(r) > len(head):
            raise InputError(f"{where}: expected {len(head)} fields ({','.join(head)}), got {len(r)}")
        iid = image_id_of(r[col["filename"]])
        if iid in seen:
            raise InputError(f"{where}: duplicate image {iid!r} (first on line {seen[iid]})")
        seen[iid] = n
        ids.append(iid)
        xyz.append([number(r[col[k]], where, k) for k in ("x", "y", "z")])
        opk.append([number(r[col[k]], where, k) for k in ("omega", "phi", "kappa")])
        cams.append(r[col["camera"]] if "camera" in col and col["camera"] < len(r) else None)
    if not ids:
        raise InputError(f"{path}: no records (expected filename,x,y,z,omega,phi,kappa)")
    return ids, np.array(xyz), np.array(opk), cams


def read_ext_geojson(path: Path) -> tuple[str, list[str], np.ndarray, np.ndarray, list]:
    """(world CRS, image ids, centres (N, 3), omega phi kappa (N, 3) degrees, camera ids) of an exterior
    parameter GeoJSON."""
    try:
        d = json.loads(read_text(path, "orthority exterior parameters (GeoJSON)"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(d, dict) or d.get("type") != "FeatureCollection" or not isinstance(d.get("features"), list):
        raise InputError(f"{path}: expected a GeoJSON FeatureCollection with world_crs and features")
    if not isinstance(d.get("world_crs"), str):
        raise CrsError(f"{path}: world_crs is missing (expected the CRS of the xyz properties)")
    ids, xyz, opk, cams, seen = [], [], [], [], {}
    for n, feat in enumerate(d["features"]):
        where = f"{path} features[{n}]"
        props = feat.get("properties") if isinstance(feat, dict) else None
        if not isinstance(props, dict):
            raise InputError(f"{where}: no properties (expected filename, camera, xyz, opk)")
        for key in ("filename", "xyz", "opk"):
            if key not in props:
                raise InputError(f"{where}: properties.{key} is missing (expected filename, camera, xyz, opk)")
        for key in ("xyz", "opk"):
            if not isinstance(props[key], list) or len(props[key]) != 3:
                raise InputError(f"{where}: properties.{key} must be a list of 3 numbers, got {props[key]!r}")
        iid = image_id_of(props["filename"])
        if iid in seen:
            raise InputError(f"{where}: duplicate image {iid!r} (first in features[{seen[iid]}])")
        seen[iid] = n
        ids.append(iid)
        xyz.append([number(v, where, f"xyz[{k}]") for k, v in enumerate(props["xyz"])])
        opk.append([np.degrees(number(v, where, f"opk[{k}]")) for k, v in enumerate(props["opk"])])
        cams.append(props.get("camera"))
    if not ids:
        raise InputError(f"{path}: no features")
    return d["world_crs"], ids, np.array(xyz), np.array(opk), cams


# -- the importer and the exporter ------------------------------------------------------------------

def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    """Interior YAML and/or one exterior file (OPK CSV + .prj, or GeoJSON) -> camera, orientations and
    positions in the project CRS."""
    block = ImportedBlock(source=[str(f) for f in files])
    cameras, nominal, exterior = {}, set(), None
    for f in files:
        suffix = f.suffix.lower()
        if suffix in (".yaml", ".yml"):
            cams, no_sensor = read_int_param(f)
            cameras.update(cams)
            nominal |= no_sensor
        elif suffix in (".csv", ".txt"):
            records = read_opk_csv(f)
            exterior = (f, *_prj_crs(f, options), *records)
        elif suffix in (".geojson", ".json"):
            crs, *rest = read_ext_geojson(f)
            exterior = (f, crs, f"{f} world_crs", *rest)
        else:
            raise InputError(f"{f}: not an orthority parameter file (expected .yaml interior, .csv OPK or "
                             ".geojson exterior parameters)")
    used = set()
    if exterior is not None:
        path, crs, crs_source, ids, xyz, opk, cams = exterior
        used = {c for c in cams if c}
        eo = opk_orientations_to_project(ids, xyz, opk, crs, project, crs_source)
        block.eo = eo
        block.origin["eo"] = Path(path).name
        if options.as_gnss:
            block.gnss, block.gnss_holds = positions_as_gnss(ids, eo.centre_m, options=options, project=project,
                                                             what="camera positions of the orthority exterior parameters")
            block.origin["gnss"] = Path(path).name
    if cameras:
        chosen = [c for c in cameras if c in used] or list(cameras)
        if len(chosen) > 1:
            raise InputError(f"{', '.join(block.source)}: {len(chosen)} cameras ({', '.join(chosen)}); a project "
                             "has one camera (import the images of one camera at a time)")
        missing = sorted(used - set(cameras))
        if missing:
            raise InputError(f"{exterior[0]}: camera(s) {missing} are not in the interior parameters "
                             f"({', '.join(cameras)})")
        block.camera = cameras[chosen[0]]
        block.origin["camera"] = next((f.name for f in files if f.suffix.lower() in (".yaml", ".yml")), "")
        if chosen[0] in nominal:
            block.notes.append(f"camera {chosen[0]!r} has no sensor_size: focal length in pixels kept, pixel size "
                               "set to a nominal 1 um (edit camera.toml for the physical sensor)")
            cam = block.camera
            per_side = cam.focal_px / max(cam.width, cam.height)
            if per_side > NORMALISED_FOCAL_WARN:
                fov_deg = math.degrees(2 * math.atan(0.5 / per_side))
                block.notes.append(
                    f"camera {chosen[0]!r}: focal_len {cam.focal_px / cam.width:g} without sensor_size is over the "
                    f"image width (orthority's convention): {cam.focal_px:.6g} px, {per_side:.1f} x the longer side, "
                    f"a field of view of {fov_deg:.1f} deg; if focal_len is in mm, give sensor_size (mm) as well")
    return block


def files(block: AdjustedBlock, project: Project) -> list[ExportFile]:
    """``orthority/int_param.yaml``, ``ext_param.csv`` + ``.prj``, ``ext_param.geojson`` of the adjusted
    orientations (``at/eo.txt``) and camera."""
    eo, camera = adjusted_orientations(project)
    return texts(eo, camera, project)


def texts(eo: ExteriorOrientations, camera: Camera, project: Project, folder: str = "orthority") -> list[ExportFile]:
    """The orthority files of orientations in the project CRS and their camera (paths relative to the output
    folder)."""
    import yaml

    from aerotri.geom.crs.definition import horizontal_crs, parse_crs, project_crs
    from aerotri.geom.crs.transform import transform_points

    cam_id = camera.name or "camera"
    int_text = (f"# orthority interior parameters of {project.name} (aerotri export; focal_len and sensor_size in mm)\n"
                + yaml.safe_dump({cam_id: _int_param_of(camera)}, sort_keys=False, default_flow_style=None))
    rows = ["filename,x,y,z,omega,phi,kappa,camera"]
    for iid, (x, y, z), (o, p, k) in zip(eo.image_id, eo.centre_m, eo.opk_deg):
        rows.append(f"{iid},{x:.4f},{y:.4f},{z:.4f},{o:.7f},{p:.7f},{k:.7f},{cam_id}")
    h = horizontal_crs(project_crs(project))
    lon, lat = transform_points(eo.centre_m[:, 0], eo.centre_m[:, 1], from_crs=h, to_crs=parse_crs("EPSG:4326"))[:2]
    feats = [{"type": "Feature",
              "properties": {"filename": iid, "camera": cam_id, "xyz": [round(float(v), 4) for v in eo.centre_m[i]],
                             "opk": [round(float(v), 12) for v in np.radians(eo.opk_deg[i])]},
              "geometry": {"type": "Point", "coordinates": [float(lon[i]), float(lat[i]), float(eo.centre_m[i, 2])]}}
             for i, iid in enumerate(eo.image_id)]
    geojson = {"type": "FeatureCollection", "world_crs": horizontal_wkt(project), "features": feats}
    return [ExportFile(f"{folder}/int_param.yaml", int_text), ExportFile(f"{folder}/ext_param.csv", "\n".join(rows) + "\n"),
            ExportFile(f"{folder}/ext_param.prj", horizontal_wkt(project) + "\n"),
            ExportFile(f"{folder}/ext_param.geojson", json.dumps(geojson, indent=2) + "\n")]
