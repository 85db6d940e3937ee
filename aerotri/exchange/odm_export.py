"""``aerotri export --format odm``: the adjusted block for OpenDroneMap and OpenSfM, in ODM's project layout.

| file | holds |
|---|---|
| ``odm/opensfm/reconstruction.json`` | OpenSfM reconstruction (``aerotri.exchange.opensfm.reconstruction``): the adjusted orientations as shots (rotation/translation world -> camera in the topocentric frame), the self-calibrated camera (``brown``), the adjusted object points, ``reference_lla``; the shots' ``gps_position``/``gps_dop`` from gnss.txt when the project has one, reduced from the antenna to the camera centre by the adjustment's lever arm |
| ``odm/opensfm/reference_lla.json`` | the reference point alone (what OpenSfM datasets older than ``reference_lla`` in the reconstruction read) |
| ``odm/cameras.json`` | the camera, OpenSfM's ``camera_models.json`` layout (ODM's ``--cameras``) |
| ``odm/gcp_list.txt`` | the control points the adjustment used and their measurements it kept (``aerotri.exchange.odm`` documents the layout); none for a block without control |
| ``odm/opensfm/ground_control_points.json`` | the plan-only control only, in OpenSfM's own GCP format (WGS84, normalised image coordinates) without ``altitude`` (OpenSfM: ``has_altitude`` false): gcp_list.txt leaves it out (a warning names the points and says where each file goes). Not the control gcp_list.txt holds: OpenSfM reads both files of its dataset folder and adds them up (``DataSet.load_ground_control_points``: ``gcp + pcs``), and ODM copies ``--gcp`` to ``opensfm/gcp_list.txt``, so a point in both would count twice. Not written without plan-only control. Height-only control is left out of every ODM file (the layouts have no plan-free point), also named in a warning |
| ``odm/gcp_list_check.txt`` | check points and their measurements, gcp_list.txt layout (ODM has no check points: in gcp_list.txt they would become control) |
| ``odm/gcp_list_rejected.txt`` | measurements of control points the adjustment did not use: removed by data snooping (w), of a control point it rejected, or of a point it never had; gcp_list.txt layout, the reason in the extra fields; each also printed as a warning |

The reference point is the adjustment's local-frame origin (``at/report.json``) in WGS84 through the
toolkit's coordinate-operation policy. Shot ids are the frames' file names in ``images/`` (ODM's), else
the image ids. Point colours are a neutral grey (the adjustment keeps none); no ``tracks.csv`` is written.
"""

from __future__ import annotations

import json
import logging

import numpy as np

from aerotri.core.project import Project
from aerotri.core.textio import read_json
from aerotri.exchange import opensfm
from aerotri.exchange.adjusted import AdjustedBlock
from aerotri.exchange.commit import ExportFile
from aerotri.exchange.poses import adjusted_orientations
from aerotri.geom.observations import ImageObservations, read_control_points, read_image_points

log = logging.getLogger(__name__)


def _crs_line(crs_text: str) -> str:
    from aerotri.geom.crs.definition import epsg_code, horizontal_crs, parse_crs

    crs = horizontal_crs(parse_crs(crs_text))
    code = epsg_code(crs)
    return f"EPSG:{code}" if code else crs.to_proj4()


def _gcp_rows(obs: ImageObservations, xyz: dict, names: dict, extras=None, plan_only=frozenset()) -> list[str]:
    """gcp_list.txt lines; the points of ``plan_only`` get geo_z NaN (no height), never their stored 0: only in
    gcp_list_rejected.txt, a listing no ODM reader takes (see ``files``)."""
    rows = []
    for n, (p, i, (x, y)) in enumerate(zip(obs.point_id.astype(str), obs.image_id.astype(str), obs.xy_px)):
        X, Y, Z = xyz[p]
        z = "NaN" if p in plan_only else f"{Z:.4f}"
        rows.append(f"{X:.4f}\t{Y:.4f}\t{z}\t{x:.3f}\t{y:.3f}\t{names.get(i, i)}\t{p}"
                    + (f"\t{extras[n]}" if extras is not None else ""))
    return rows


def control_measurements(block: AdjustedBlock, project: Project):
    """(control measurements kept, check measurements, rejected measurements, their reasons, all control
    coordinates by id, control kinds by id): the file's pixel coordinates (as measured). The other exports leave
    the rejected ones out too (``rejected_pairs``)."""
    empty = ImageObservations(np.zeros(0, object), np.zeros(0, object), np.zeros((0, 2)))
    if not project.control_points_path.is_file():
        return empty, empty, empty, [], {}, {}
    control = read_control_points(project.control_points_path)
    xyz = {str(p): v for p, v in zip(control.id, control.xyz_m)}
    kind = {str(p): str(k) for p, k in zip(control.id, control.kind)}
    if not project.control_image_points_path.is_file():
        return empty, empty, empty, [], xyz, kind
    obs = read_image_points(project.control_image_points_path)
    report = read_json(project.adjustment_report_path, "adjustment report")
    removed = {(r["point_id"], r["image_id"]): r.get("w") for r in report.get("removed_observations", [])}
    rejected_point = {str(r["id"]): r.get("w") for r in report.get("rejected_control", [])}
    used = set(block.control_id.astype(str))
    # check points: those control/points.csv calls so and those the adjustment held back (adjust --check ID,...)
    check = {str(p) for p, k in zip(control.id, control.kind) if k == "check"}
    check |= {str(r["id"]) for r in report.get("check_points", []) if "id" in r}
    images = set(block.image_id)
    pid, iid = obs.point_id.astype(str), obs.image_id.astype(str)
    keep, is_check, reasons, rejected = [], [], [], []
    for k, (p, i) in enumerate(zip(pid, iid)):
        if p not in xyz:
            continue  # a measurement of a point control/points.csv does not have: not control
        if p in check:
            is_check.append(k)
        elif p in used and i in images and (p, i) not in removed:
            keep.append(k)
        else:
            rejected.append(k)
            if (p, i) in removed:
                reasons.append(f"removed by data snooping (w = {removed[(p, i)]})")
            elif p in rejected_point:
                reasons.append(f"control point rejected by the adjustment (w = {rejected_point[p]})")
            elif i not in images:
                reasons.append("image not in the adjustment")
            else:
                reasons.append("point not in the adjustment")
    pick = lambda ks: obs.subset(np.isin(np.arange(len(obs)), ks))  # noqa: E731
    return pick(keep), pick(is_check), pick(rejected), reasons, xyz, kind


def rejected_pairs(block: AdjustedBlock, project: Project, fmt: str) -> set:
    """(point id, image id) of the control measurements the adjustment did not use (``control_measurements``), each
    said in a warning naming the export ``fmt``: written as measurements, a re-adjustment in Metashape or MicMac took
    the blunders back (demo: w 4.29 and 6.83 pinned; trial s96 M1)."""
    _, _, rejected, reasons, _, _ = control_measurements(block, project)
    for p, i, why in zip(rejected.point_id, rejected.image_id, reasons):
        log.warning(f"{fmt} export: measurement of {p} in {i} left out: {why}")
    return set(zip(rejected.point_id.astype(str), rejected.image_id.astype(str)))


def _ground_control_points_json(obs: ImageObservations, ids, xyz: dict, project: Project, block: AdjustedBlock,
                                names: dict, plan_only=frozenset()) -> str:
    """OpenSfM's ground_control_points.json: WGS84 positions through the CRS policy, projections normalised; the
    points of ``plan_only`` without ``altitude`` (OpenSfM reads has_altitude = "altitude" in position)."""
    from aerotri.geom.crs.definition import parse_crs, project_heights, with_heights
    from aerotri.geom.crs.transform import transform_points

    if not ids:
        return json.dumps({"points": []}, indent=2) + "\n"
    lon, lat, h = transform_points(*np.array([xyz[p] for p in ids]).T,
                                   from_crs=with_heights(parse_crs(block.crs), project_heights(project)),
                                   to_crs=parse_crs("EPSG:4979"))
    w, h_px = block.camera.width, block.camera.height
    s = max(w, h_px)
    points = []
    for n, p in enumerate(ids):
        m = obs.point_id.astype(str) == p
        position = {"latitude": float(lat[n]), "longitude": float(lon[n])}
        if p not in plan_only:
            position["altitude"] = float(h[n])
        points.append({"id": p, "position": position,
                       "observations": [{"shot_id": names.get(i, i),
                                         "projection": [(x + 0.5 - w / 2) / s, (y + 0.5 - h_px / 2) / s]}
                                        for i, (x, y) in zip(obs.image_id[m].astype(str), obs.xy_px[m])]})
    return json.dumps({"points": points}, indent=2) + "\n"


def _adjusted_lever_arm_m(project: Project):
    """The lever arm (m, camera frame x right, y up, z up) the adjustment used: its report's setting (a command line's
    --lever-arm-m too), else project.toml [gnss] lever_arm_m."""
    from aerotri.core.textio import read_json

    path = project.adjustment_report_path
    used = ((read_json(path, "adjustment report").get("settings") or {}).get("lever_arm_m") or {}).get("value") \
        if path.is_file() else None
    return tuple(float(v) for v in used) if used is not None else tuple(project.gnss.lever_arm_m)


def files(block: AdjustedBlock, project: Project, image_names: dict | None = None) -> list[ExportFile]:
    """The ODM/OpenSfM files of an adjusted project (see the module docstring)."""
    from aerotri.geom.eo import read_gnss

    names = image_names or {}
    eo, camera = adjusted_orientations(project)
    reference = opensfm.reference_of(project, block.frame.origin_map)
    gnss = read_gnss(project.gnss_path) if project.gnss_path.is_file() else None
    rec = opensfm.reconstruction(eo, camera, project, reference, names,
                                 points=(block.point_id, block.frame.to_map(block.points_local)),
                                 gnss=gnss, gnss_sigma_m=float(project.gnss.sigma_xy_m),
                                 lever_arm_m=_adjusted_lever_arm_m(project))
    cam_id = opensfm.camera_id_of(camera)
    out = [ExportFile("odm/opensfm/reconstruction.json", json.dumps([rec], indent=2) + "\n"),
           ExportFile("odm/opensfm/reference_lla.json", json.dumps(reference, indent=2) + "\n"),
           ExportFile("odm/cameras.json", json.dumps({cam_id: rec["cameras"][cam_id]}, indent=2) + "\n")]
    kept, check, rejected, reasons, xyz, kind = control_measurements(block, project)
    head = _crs_line(block.crs)
    # plan-only control has no height to give (control/points.csv holds 0 there): gcp_list.txt would make it a
    # point at height 0, and no text file can carry it: OpenSfM's reader (opensfm/io.py _read_gcp_list_lines)
    # groups a file's lines into points by (easting, northing, altitude), and with altitude NaN no two lines
    # compare equal, so each measurement would be a GCP of one observation, unused. The JSON, whose points hold
    # their observations and read has_altitude from "altitude" in the position, is its only ODM file. Height-only
    # control has no plan position the layouts could leave out. The JSON holds the plan-only points only: OpenSfM
    # (opensfm/dataset.py load_ground_control_points) returns gcp_list.txt's points plus the JSON's, and ODM copies
    # --gcp to opensfm/gcp_list.txt beside it, so a 3D point in both files would be counted twice.
    pid = kept.point_id.astype(str)
    plan = np.array([kind.get(p) == "horizontal" for p in pid], bool)
    height = np.array([kind.get(p) == "height" for p in pid], bool)
    plan_ids = list(dict.fromkeys(pid[plan]))
    no_z = frozenset(p for p, k in kind.items() if k == "horizontal")
    height_ids = list(dict.fromkeys(pid[height]))
    full = kept.subset(~plan & ~height)
    ids = list(dict.fromkeys(full.point_id.astype(str)))
    if ids:
        out.append(ExportFile("odm/gcp_list.txt", "\n".join([head] + _gcp_rows(full, xyz, names)) + "\n"))
        from aerotri.geom.crs.definition import crs_label, project_heights

        heights = project_heights(project)
        if heights is not None:
            # OpenSfM (io.py _read_gcp_list_lines) takes geo_z as the altitude of a WGS 84 position and places it
            # against reference_lla, whose altitude this export gives as an ellipsoidal height (trial-at2, review 21)
            log.warning(f"odm export: odm/gcp_list.txt holds the project's heights ({crs_label(heights)}, "
                        f"{heights.name}) under a horizontal CRS line, while reference_lla.json and the "
                        "reconstruction are on ellipsoidal heights: OpenSfM reads the control's geo_z as ellipsoidal, "
                        "so in ODM the control would sit the geoid height low; convert geo_z to ellipsoidal heights "
                        "(aerotri crs transform --normal-to-ellipsoidal with a height model, or the geoid) before "
                        "giving it to ODM")
    if plan_ids:
        out.append(ExportFile("odm/opensfm/ground_control_points.json",
                              _ground_control_points_json(kept.subset(plan), plan_ids, xyz, project, block, names,
                                                          frozenset(plan_ids))))
        log.warning(f"odm export: {len(plan_ids)} plan-only control points ({', '.join(plan_ids)}) have no height: "
                    "left out of odm/gcp_list.txt (its layout needs a height: their stored 0 would be taken as one); "
                    "plan-only control goes to OpenSfM through odm/opensfm/ground_control_points.json (without "
                    "altitude: has_altitude false), which holds only them" + (
                        ": OpenSfM adds the points of the JSON to those of gcp_list.txt in its dataset folder, each "
                        "point once. ODM: --gcp odm/gcp_list.txt (ODM copies it to opensfm/gcp_list.txt) and keep the "
                        "JSON in the project's opensfm/ folder; OpenSfM alone: gcp_list.txt and the JSON side by side "
                        "in the dataset folder" if ids else
                        " (no 3D control: no gcp_list.txt). OpenSfM alone: the JSON in the dataset folder, with "
                        "bundle_use_gcp: yes in its config.yaml; ODM writes that setting only with --gcp (a "
                        "gcp_list.txt)"))
    if ids:
        log.info("odm export: ODM takes the control as --gcp odm/gcp_list.txt (OpenSfM alone: gcp_list.txt in "
                 "its dataset folder)")
    if height_ids:
        log.warning(f"odm export: {len(height_ids)} height-only control points ({', '.join(height_ids)}) have no "
                    "plan position: left out of odm/gcp_list.txt and ground_control_points.json (the layouts have "
                    "no height-only point)")
    if not ids and not plan_ids:
        log.warning(f"{project.root}: no control point measurements the adjustment used; no odm/gcp_list.txt "
                    "(the reconstruction is georeferenced by itself)")
    if len(check):
        out.append(ExportFile("odm/gcp_list_check.txt", "\n".join([head] + _gcp_rows(check, xyz, names)) + "\n"))
    if len(rejected):
        out.append(ExportFile("odm/gcp_list_rejected.txt",
                              "\n".join([head] + _gcp_rows(rejected, xyz, names, reasons, no_z)) + "\n"))
        for p, i, why in zip(rejected.point_id, rejected.image_id, reasons):
            log.warning(f"odm export: measurement of {p} in {i} left out of gcp_list.txt: {why} "
                        "(listed in odm/gcp_list_rejected.txt)")
    return out
