"""Agisoft Metashape cameras XML (``File > Export > Cameras``, "Agisoft XML"): export and import.

Layout written (``metashape/cameras.xml``; the elements Metashape's own export holds for a frame block)::

    <document version="1.5.0"><chunk label=...>
      <sensors><sensor id="0" label=... type="frame">
          <resolution width= height=/> <property name="pixel_width|pixel_height|focal_length" value= (mm)/>
          <calibration type="frame" class="adjusted"><resolution/><f/><cx/><cy/><k1/><k2/><k3/><p1/><p2/></calibration>
      </sensor></sensors>
      <cameras><camera id= sensor_id="0" label=IMAGE_ID><transform>16 numbers</transform></camera>...</cameras>
      <markers><marker id= label=POINT_ID><reference x= y= z= sx= sy= sz= enabled=/></marker>...</markers>
      <frames><frame id="0"><markers><marker marker_id=><location camera_id= pinned="true" x= y=/>...</marker>
      </markers></frame></frames>
      <reference>WKT of the project CRS (compound with [project] heights)</reference>
      <transform><rotation>9</rotation><translation>3</translation><scale>1</scale></transform>
    </chunk></document>

Conventions (Metashape manual, appendix "Camera models"):

- camera ``transform``: 4 x 4 row-major, camera -> chunk coordinates; the camera frame is the
  computer-vision one (x right, y down, z forward, = ours with y and z flipped, ``FLIP_YZ``);
- chunk ``transform``: chunk -> geocentric coordinates of the ``reference`` CRS's datum, X = s R x + T.
  We write the adjustment's local ENU frame as the chunk (R = ENU axes in geocentric, T = its origin,
  s = 1); a local engineering CRS: chunk = its coordinates shifted by the origin;
- pixels: origin at the top-left corner of the image (the centre of the top-left pixel is (0.5, 0.5)):
  ours + 0.5. ``cx``, ``cy``: principal point offset from the image centre in pixels (x right, y down);
  ``f`` in pixels;
- distortion: x' = x (1 + K1 r2 + K2 r4 + K3 r6) + P1 (r2 + 2 x2) + 2 P2 x y, y' = ... + P2 (r2 + 2 y2) +
  2 P1 x y: Metashape's P1 is OpenCV's (our) p2 and its P2 our p1 (swapped here). b1, b2, K4, P3, P4 are
  not in our model (the import refuses non-zero values);
- markers: ``enabled="true"`` = control, ``"false"`` = check point; plan-only (horizontal) control is written
  with x y and no z (its stored 0 is no height; the import reads it back as horizontal), height-only control as
  a marker without reference coordinates (Metashape has no height-only marker), both named in a warning; marker projections:
  the control points' measured pixels (control/image_points.csv, as measured).

Import: the sensor -> camera.toml (a frame sensor only: fisheye, spherical, ... are refused; its adjusted
calibration when it also holds an initial one), the aligned cameras -> imported/eo.txt (approximations), markers
-> control/ (x y without z: horizontal control); the camera positions go to gnss.txt only with ``--as-gnss``
(accuracies from ``--sigma-xyz-m``). A camera with a ``component_id`` is in its component's frame (Metashape 1.6
and later): camera -> component ``<transform>`` -> chunk ``<transform>`` -> geocentric, each X = s R x + T; without
a chunk transform the component's reaches geocentric coordinates. Markers' coordinates go through the whole
``<reference>`` CRS: a compound one's vertical part (e.g. EGM96 height) says what their heights are.

Heights: Metashape's geocentric coordinates carry ellipsoidal heights. With ``[project] heights`` a vertical CRS
(e.g. EPSG:3855, EGM2008) the export writes ``<reference>`` as the compound CRS (``COMPD_CS``: markers' z are
heights of that CRS) and places the chunk with h = H + N through the geoid grid; the import turns the cameras'
ellipsoidal heights into the project's through the same grid. Without the grid both stop naming it (exit 2).
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError, InputError, id_listing
from aerotri.core.project import Project
from aerotri.core.textio import read_xml
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.imported import ImportedBlock, ImportSettings, positions_as_gnss
from aerotri.exchange.poses import adjusted_orientations, image_id_of, number, orientations_to_project
from aerotri.geom.camera import BrownCamera, Camera
from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.observations import ControlPoints, ImageObservations, read_control_points, read_image_points
from aerotri.geom.rotation import FLIP_YZ

log = logging.getLogger(__name__)


def _fmt(v: float) -> str:
    return repr(float(v))


def _chunk_frame(frame: LocalFrame) -> tuple[np.ndarray, np.ndarray]:
    """(R, T): chunk (local ENU) -> geocentric, X = R x + T (LocalFrame: enu = R_f (X - ecef0))."""
    return frame.R.T, frame.ecef0


# -- export ------------------------------------------------------------------------------------------

def _reference_and_ellipsoidal(project: Project, cartesian: bool = False):
    """(the ``<reference>`` CRS, a function (N, 3) project coordinates -> the same with ellipsoidal heights).

    Metashape's chunk transform reaches geocentric coordinates, which it reads through ``<reference>``: with
    ``[project] heights`` a vertical CRS (the NGI block's EGM2008) the reference is the compound CRS (WKT1
    ``COMPD_CS``, as Metashape writes its own) and the chunk frame is placed with the heights made ellipsoidal
    through the geoid (h = H + N): its grid is needed, and without it the export stops naming it. Written before
    with the horizontal CRS alone, the EGM2008 heights were read as ellipsoidal (the block N off, unsaid)."""
    from aerotri.geom.crs.definition import project_crs, project_crs_3d, project_heights
    from aerotri.geom.crs.transform import CrsTransformer

    crs = project_crs(project)
    if project_heights(project) is None or cartesian:  # a local engineering CRS: the chunk is its coordinates
        return crs, lambda xyz: np.asarray(xyz, float)
    compound = project_crs_3d(project)
    operation = CrsTransformer(compound, crs)  # z -> ellipsoidal heights; stops naming a missing geoid grid

    def ellipsoidal_m(xyz):
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        return np.column_stack([xyz[:, :2], operation.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])[2]])

    return compound, ellipsoidal_m


def files(block: AdjustedBlock, project: Project) -> list[ExportFile]:
    eo, camera = adjusted_orientations(project)
    frame = block.frame
    doc = ET.Element("document", version="1.5.0")
    chunk = ET.SubElement(doc, "chunk", label=project.name, enabled="true")
    sensors = ET.SubElement(chunk, "sensors", next_id="1")
    sensor = ET.SubElement(sensors, "sensor", id="0", label=camera.name, type="frame")
    ET.SubElement(sensor, "resolution", width=str(camera.width), height=str(camera.height))
    for name, value in (("pixel_width", camera.pixel_um / 1000), ("pixel_height", camera.pixel_um / 1000),
                        ("focal_length", camera.focal_mm)):
        ET.SubElement(sensor, "property", name=name, value=_fmt(value))
    cal = ET.SubElement(sensor, "calibration", type="frame", **{"class": "adjusted"})
    ET.SubElement(cal, "resolution", width=str(camera.width), height=str(camera.height))
    values = {"f": camera.focal_px, "cx": camera.cx_px - (camera.width - 1) / 2.0,
              "cy": camera.cy_px - (camera.height - 1) / 2.0}
    if isinstance(camera, BrownCamera):
        values |= {"k1": camera.k1, "k2": camera.k2, "k3": camera.k3, "p1": camera.p2, "p2": camera.p1}
    for k, v in values.items():
        ET.SubElement(cal, k).text = _fmt(v)
    cams = ET.SubElement(chunk, "cameras", next_id=str(len(eo)), next_group_id="0")
    reference_crs, ellipsoidal_m = _reference_and_ellipsoidal(project, frame.cartesian_crs)
    centre_local = frame.to_local(ellipsoidal_m(eo.centre_m))
    R_cv = frame.rotation_local_from_map(eo.centre_m) @ eo.rotations() @ FLIP_YZ
    cam_index = {}
    for i, iid in enumerate(eo.image_id):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_cv[i], centre_local[i]
        c = ET.SubElement(cams, "camera", id=str(i), sensor_id="0", label=iid)
        ET.SubElement(c, "transform").text = " ".join(_fmt(v) for v in T.ravel())
        cam_index[iid] = i
    # control and its measurements (as measured: control/image_points.csv)
    control = read_control_points(project.control_points_path) if project.control_points_path.is_file() else None
    if control is not None and len(control):
        markers = ET.SubElement(chunk, "markers", next_id=str(len(control)), next_group_id="0")
        for n, (pid, kind, xyz, sig) in enumerate(zip(control.id, control.kind, control.xyz_m, control.sigma_m)):
            m = ET.SubElement(markers, "marker", id=str(n), label=str(pid), reference="true")
            if kind == "height":  # no plan position to give: a marker without reference coordinates
                continue
            # plan-only control: x y without z (its stored 0 is no height)
            ref = {"x": _fmt(xyz[0]), "y": _fmt(xyz[1]), "z": _fmt(xyz[2]), "sx": _fmt(sig[0]), "sy": _fmt(sig[1]),
                   "sz": _fmt(sig[2]), "enabled": "false" if kind == "check" else "true"}
            if kind == "horizontal":
                del ref["z"], ref["sz"]
            ET.SubElement(m, "reference", ref)
        for what, k in (("plan-only", "horizontal"), ("height-only", "height")):
            ids = [str(p) for p, kk in zip(control.id, control.kind) if kk == k]
            if ids:
                log.warning(f"metashape export: {len(ids)} {what} control points ({', '.join(ids)}) written "
                            + ("with x y and no z" if k == "horizontal" else "as markers without reference "
                               "coordinates (Metashape has no height-only marker)"))
        if project.control_image_points_path.is_file():
            from aerotri.exchange.odm_export import rejected_pairs

            obs = read_image_points(project.control_image_points_path)
            left_out = rejected_pairs(block, project, "metashape")
            marker_of = {str(p): n for n, p in enumerate(control.id)}
            frames = ET.SubElement(chunk, "frames", next_id="1")
            fm = ET.SubElement(ET.SubElement(frames, "frame", id="0"), "markers")
            for pid in control.id:
                ks = [k for k in range(len(obs)) if obs.point_id[k] == pid and obs.image_id[k] in cam_index
                      and (str(pid), str(obs.image_id[k])) not in left_out]
                if not ks:
                    continue
                m = ET.SubElement(fm, "marker", marker_id=str(marker_of[str(pid)]))
                for k in ks:
                    ET.SubElement(m, "location", camera_id=str(cam_index[obs.image_id[k]]), pinned="true",
                                  x=_fmt(obs.xy_px[k, 0] + 0.5), y=_fmt(obs.xy_px[k, 1] + 0.5))
    ET.SubElement(chunk, "reference").text = reference_crs.to_wkt(version="WKT1_GDAL") or reference_crs.to_wkt()
    tr = ET.SubElement(chunk, "transform")
    R, T = _chunk_frame(frame)
    ET.SubElement(tr, "rotation", locked="true").text = " ".join(_fmt(v) for v in R.ravel())
    ET.SubElement(tr, "translation", locked="true").text = " ".join(_fmt(v) for v in T)
    ET.SubElement(tr, "scale", locked="true").text = "1"
    ET.indent(doc)
    return [ExportFile("metashape/cameras.xml",
                       '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(doc, encoding="unicode") + "\n")]


# -- import ------------------------------------------------------------------------------------------

def _numbers(el, n: int, where: str, what: str) -> np.ndarray:
    if el is None or el.text is None:
        raise InputError(f"{where}: <{what}> is missing")
    parts = el.text.split()
    if len(parts) != n:
        raise InputError(f"{where}: <{what}> needs {n} numbers, got {len(parts)}")
    return np.array([number(p, where, what) for p in parts])


def _similarity(tr, where: str) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, T) of a chunk or component ``<transform>``: X = s R x + T (rotation, translation, scale)."""
    R = _numbers(tr.find("rotation"), 9, where, "rotation").reshape(3, 3) if tr.find("rotation") is not None else np.eye(3)
    T = _numbers(tr.find("translation"), 3, where, "translation") if tr.find("translation") is not None else np.zeros(3)
    s = _numbers(tr.find("scale"), 1, where, "scale")[0] if tr.find("scale") is not None else 1.0
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0 or s <= 0:
        raise InputError(f"{where}: rotation and scale are not a rotation and a positive scale")
    return s, R, T


def _attr(el, key: str, where: str) -> float:
    if key not in el.attrib:
        raise InputError(f"{where}: attribute {key} is missing")
    return number(el.attrib[key], where, key)


def _calibration(sensor):
    """The sensor's adjusted calibration (``class="adjusted"``), else its first: a sensor may hold the user's
    initial (pre-calibrated) one too, ``class="initial"``."""
    cals = sensor.findall("calibration")
    adjusted = [c for c in cals if c.get("class") == "adjusted"]
    return (adjusted or cals or [None])[0]


def read_camera_xml(sensor, where: str) -> Camera:
    res = sensor.find("resolution")
    kind = sensor.get("type", "frame")
    if kind != "frame":  # fisheye, spherical, cylindrical, rpc: not a frame camera with Brown distortion
        raise InputError(f"{where}: sensor type {kind!r} is not supported; expected a frame camera (type=\"frame\")")
    cal = _calibration(sensor)
    if cal is not None and cal.get("type", "frame") != "frame":
        raise InputError(f"{where}: calibration type {cal.get('type')!r} is not supported; expected \"frame\"")
    if res is None:
        raise InputError(f"{where}: <resolution> is missing")
    w, h = int(_attr(res, "width", where)), int(_attr(res, "height", where))
    props = {p.get("name"): p.get("value") for p in sensor.findall("property")}
    pixel_mm = number(props["pixel_width"], where, "pixel_width") if "pixel_width" in props else None
    if "pixel_height" in props and pixel_mm and abs(number(props["pixel_height"], where, "pixel_height") - pixel_mm) > 1e-9:
        raise InputError(f"{where}: pixel_width and pixel_height differ; our cameras have square pixels")
    if cal is None:
        raise InputError(f"{where}: no <calibration> (export the cameras after the alignment)")
    vals = {c.tag: number(c.text, where, c.tag) for c in cal if c.tag != "resolution" and c.text is not None}
    if "f" not in vals:
        raise InputError(f"{where}: calibration <f> is missing")
    extra = [k for k in ("b1", "b2", "k4", "p3", "p4") if vals.get(k, 0.0) != 0.0]
    if extra:
        raise InputError(f"{where}: calibration {extra} not zero; our Brown model has f cx cy k1 k2 k3 p1 p2 only")
    cal_res = cal.find("resolution")
    if cal_res is not None and (int(_attr(cal_res, "width", where)), int(_attr(cal_res, "height", where))) != (w, h):
        raise InputError(f"{where}: calibration resolution differs from the sensor's")
    pixel_um = pixel_mm * 1000.0 if pixel_mm else 1.0
    pix = pixel_um / 1000.0
    geometry = dict(focal_mm=vals["f"] * pix, pixel_um=pixel_um, width=w, height=h, name=sensor.get("label", "camera"),
                    ppx_mm=vals.get("cx", 0.0) * pix, ppy_mm=-vals.get("cy", 0.0) * pix)
    coeffs = {"k1": vals.get("k1", 0.0), "k2": vals.get("k2", 0.0), "k3": vals.get("k3", 0.0),
              "p1": vals.get("p2", 0.0), "p2": vals.get("p1", 0.0)}  # Metashape's P1/P2 are swapped against ours
    try:
        return BrownCamera(**geometry, **coeffs)  # Metashape's frame model is Brown's (zeros: a pinhole)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def read(files: list[Path], project: Project, options: ImportSettings) -> ImportedBlock:
    if len(files) != 1 or files[0].suffix.lower() != ".xml":
        raise InputError(f"{', '.join(map(str, files))}: expected one Metashape cameras .xml file")
    path = files[0]
    root = read_xml(path, "Metashape cameras XML")
    chunk = root.find("chunk") if root.tag == "document" else None
    if chunk is None:
        raise InputError(f"{path}: expected <document><chunk>... (Metashape's cameras XML)")
    block = ImportedBlock(source=[str(path)])
    chunks = root.findall("chunk")
    if len(chunks) > 1:  # (trial s96 M4: the first of two imported without a word)
        def named(c):
            n = len(c.findall("cameras/camera") + c.findall("cameras/group/camera"))
            return f"{c.get('label') or 'chunk id=' + str(c.get('id'))!s} ({n} cameras)"
        block.notes.append(f"{path}: holds {len(chunks)} chunks; the first imported, {named(chunks[0])}; left out: "
                           + ", ".join(named(c) for c in chunks[1:]) + " (export each chunk's cameras on its own)")
    sensors = {s.get("id"): s for s in chunk.findall("sensors/sensor")}
    cams = chunk.findall("cameras/camera") + chunk.findall("cameras/group/camera")
    aligned = [c for c in cams if c.find("transform") is not None]
    if not aligned:
        raise InputError(f"{path}: no aligned cameras (no <camera> with a <transform>)")
    if len(aligned) < len(cams):
        k = len(cams) - len(aligned)
        block.notes.append(f"{path}: {k} camera{'s' if k != 1 else ''} without a transform (not aligned) left out")
    used = sorted({c.get("sensor_id") for c in aligned})
    if len(used) != 1 or used[0] not in sensors:
        raise InputError(f"{path}: the aligned cameras use sensors {used}; a project has one camera (and the sensor "
                         "must be in <sensors>)")
    block.camera = read_camera_xml(sensors[used[0]], f"{path} sensor {used[0]}")
    if _calibration(sensors[used[0]]).get("class") == "initial":
        block.notes.append(f"{path} sensor {used[0]}: its initial calibration (the file holds no adjusted one)")
    if block.camera.pixel_um == 1.0 and "pixel_width" not in {p.get("name") for p in sensors[used[0]].findall("property")}:
        block.notes.append("no pixel_width in the sensor: a nominal 1 um pixel (focal length in pixels kept)")
    components = {c.get("id"): _similarity(c.find("transform"), f"{path} component id={c.get('id')}")
                  for c in chunk.findall("components/component") if c.find("transform") is not None}
    ids, centre, R_cv, cam_id = [], [], [], {}
    for c in aligned:
        where = f"{path} camera id={c.get('id')} label={c.get('label')!r}"
        T = _numbers(c.find("transform"), 16, where, "transform").reshape(4, 4)
        R, C = T[:3, :3], T[:3, 3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError(f"{where}: the transform's rotation is not a rotation")
        if c.get("component_id") in components:  # camera -> component -> chunk (Metashape 1.6 and later)
            s_k, R_k, T_k = components[c.get("component_id")]
            R, C = R_k @ R, s_k * R_k @ C + T_k
        iid = image_id_of(c.get("label", ""))
        if iid in cam_id.values():
            raise InputError(f"{where}: duplicate label {iid!r}")
        cam_id[c.get("id")] = iid
        ids.append(iid)
        centre.append(C)
        R_cv.append(R)
    centre, R_cv = np.array(centre), np.array(R_cv)
    # chunk -> world
    ref_el = chunk.find("reference")
    crs_text = ref_el.text.strip() if ref_el is not None and ref_el.text and ref_el.text.strip() else options.crs
    if not crs_text:
        raise CrsError(f"{path}: no <reference> CRS; give --crs")
    tr = chunk.find("transform")
    if tr is None and not components:
        raise CrsError(f"{path}: no chunk <transform>: the block is not georeferenced (reference it in Metashape first)")
    # chunk -> geocentric; without a chunk transform the components' transforms reach geocentric coordinates
    s, Rc, Tc = _similarity(tr, f"{path} chunk transform") if tr is not None else (1.0, np.eye(3), np.zeros(3))
    X = s * centre @ Rc.T + Tc
    R_world = Rc @ R_cv
    from aerotri.geom.crs.definition import (horizontal_crs, parse_crs, project_crs, project_heights, same_horizontal,
                                             with_heights)
    from aerotri.geom.crs.transform import CrsTransformer

    ref_crs = horizontal_crs(parse_crs(crs_text, f"{path} <reference>"))
    frame0 = LocalFrame(ref_crs, [0.0, 0.0, 0.0])
    if tr is None and not frame0.cartesian_crs:
        radius_m = np.linalg.norm(X, axis=1)
        if not np.all((radius_m > 6.30e6) & (radius_m < 6.45e6)):  # the earth's radius, give or take 80 km
            raise CrsError(f"{path}: no chunk <transform>, and the components' transforms do not reach geocentric "
                           f"coordinates (camera centres {radius_m.min():.6g} to {radius_m.max():.6g} m from the "
                           "earth's centre): the block is not georeferenced (reference it in Metashape first)")
    if frame0.cartesian_crs:  # a local engineering CRS: the chunk transform gives its coordinates
        centre_map, R_map = X, R_world @ FLIP_YZ
    else:  # geocentric -> the CRS, through the local frame's own conversion (the inverse of the export)
        mean_map = frame0.to_map(((X.mean(axis=0) - frame0.ecef0) @ frame0.R.T)[None])[0]
        frame = LocalFrame(ref_crs, mean_map)
        centre_map = frame.to_map((X - frame.ecef0) @ frame.R.T)
        R_map = np.transpose(frame.rotation_local_from_map(centre_map), (0, 2, 1)) @ frame.R @ R_world @ FLIP_YZ
    eo_crs = ref_crs
    heights = project_heights(project)
    if heights is not None and not frame0.cartesian_crs:
        # the geocentric centres give ellipsoidal heights; the project's are the vertical CRS's (through its geoid
        # grid; without it the import stops naming it): taken as they are they were N off, unsaid
        to_heights = with_heights(ref_crs, heights)
        try:
            centre_map[:, 2] = CrsTransformer(ref_crs, to_heights).transform(*centre_map.T)[2]
        except CrsError as exc:
            raise type(exc)(f"{path}: the camera centres' ellipsoidal heights -> {heights.name}: {exc}") from None
        eo_crs = ref_crs if same_horizontal(ref_crs, project_crs(project)) else to_heights
    block.eo = orientations_to_project(ids, centre_map, R_map, eo_crs, project, f"{path} <reference>")
    if options.as_gnss:
        block.gnss, block.gnss_holds = positions_as_gnss(ids, block.eo.centre_m, options=options, project=project,
                                                         what="camera positions of Metashape's alignment")
    # markers: control (enabled) and check points, and their projections
    markers = chunk.findall("markers/marker")
    if markers:
        from aerotri.exchange.imported import to_project_crs

        mid, kinds, xyz, sig, label_of, plan_checks = [], [], [], [], {}, []
        for m in markers:
            where = f"{path} marker id={m.get('id')} label={m.get('label')!r}"
            r = m.find("reference")
            if r is None or not {"x", "y"} <= set(r.attrib):
                continue  # a marker without ground coordinates is a tie point here
            label = m.get("label") or m.get("id")
            check, plan = r.get("enabled", "true").lower() == "false", "z" not in r.attrib
            if check and plan:  # control/points.csv's check points carry a height
                plan_checks.append(label)
                continue
            if label in label_of.values():
                raise InputError(f"{where}: duplicate label {label!r}")
            label_of[m.get("id")] = label
            mid.append(label)
            kinds.append("check" if check else "horizontal" if plan else "full")
            xyz.append([_attr(r, "x", where), _attr(r, "y", where), 0.0 if plan else _attr(r, "z", where)])
            if {"sx", "sy", "sz"} <= set(r.attrib) or (plan and {"sx", "sy"} <= set(r.attrib)):
                sig.append([_attr(r, k, where) for k in ("sx", "sy")] + [_attr(r, "sx", where) if plan else
                                                                        _attr(r, "sz", where)])
            elif options.sigma_xyz_m:
                sig.append(list(options.sigma_xyz_m))
            else:
                raise InputError(f"{where}: no sx sy sz; give --sigma-xyz-m")
            if min(sig[-1]) <= 0:
                raise InputError(f"{where}: sx sy sz must be positive")
        if plan_checks:
            block.notes.append(f"{path}: check point(s) {', '.join(plan_checks[:10])} without z left out (a check "
                               "point in control/points.csv has a height)")
        if any(k == "horizontal" for k in kinds):
            block.notes.append(f"{path}: {kinds.count('horizontal')} markers with x y and no z: horizontal control")
        if mid:
            # markers with heights through the full <reference> CRS: a compound one's vertical part says what
            # their heights are (EGM96 heights are not ellipsoidal ones); a 2D one's are ellipsoidal, as the
            # cameras' (Metashape's convention)
            marker_crs = ref_crs if set(kinds) == {"horizontal"} else parse_crs(crs_text, f"{path} <reference>")
            try:
                marker_xyz = to_project_crs(np.array(xyz), marker_crs, project, f"{path} <reference>",
                                            ellipsoidal_2d=True)
            except CrsError as exc:
                raise type(exc)(f"{path}: the markers' coordinates: {exc}") from None
            block.control = ControlPoints(np.array(mid, object), np.array(kinds, object), marker_xyz,
                                          np.array(sig, float))
            pids, iids, xy = [], [], []
            known = {c.get("id") for c in cams}
            unaligned, unknown = 0, {}
            for m in chunk.findall("frames/frame/markers/marker"):
                label = label_of.get(m.get("marker_id"))
                if label is None:
                    continue
                for loc in m.findall("location"):
                    where = f"{path} marker_id={m.get('marker_id')} camera_id={loc.get('camera_id')}"
                    if loc.get("camera_id") not in cam_id:
                        if loc.get("camera_id") in known:
                            unaligned += 1
                        else:
                            unknown[loc.get("camera_id")] = unknown.get(loc.get("camera_id"), 0) + 1
                        continue
                    pids.append(label)
                    iids.append(cam_id[loc.get("camera_id")])
                    xy.append([_attr(loc, "x", where) - 0.5, _attr(loc, "y", where) - 0.5])
            if pids:
                block.image_points = ImageObservations(np.array(pids, object), np.array(iids, object), np.array(xy))
            if unaligned:
                block.notes.append(f"{path}: {unaligned} marker projection{'s' if unaligned != 1 else ''} on cameras "
                                   "without a transform left out")
            if unknown:  # (trial s96 M4: 69 projections dropped without a word)
                k = sum(unknown.values())
                block.notes.append(f"{path}: {k} marker projection{'s' if k != 1 else ''} on camera ids the chunk does "
                                   f"not have ({id_listing(sorted(unknown))}) left out: a file edited or of another "
                                   "chunk?")
    return block
