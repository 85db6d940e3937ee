"""Checks of an imported block against the project, before anything is written (each failure an
``InputError``/``CrsError``/``OptionError``: exit 2, nothing written).

- **Project CRS**: a photo block needs a projected (or local engineering) CRS; a geographic or geocentric
  project CRS is refused (``aerotri.geom.eo.check_block_crs``). A CRS in feet is accepted: the adjustment
  works in a local metric frame and converts, positions are converted into the project's feet through the
  coordinate-operation policy, accuracies stay in metres (the ``_m`` columns); the console says so. A file
  that carries no CRS is read in the project CRS only when that CRS is in metres: in a project in feet
  ``--crs`` must say whether the file is in metres or feet.
- **Coordinates where the project is**: every imported position must lie in the area of use of the project
  CRS (``aerotri.geom.crs.definition.check_coordinates``: degrees, swapped axes, a far zone); and, where the project
  already has positions (gnss.txt, imported/eo.txt, at/eo.txt, control/points.csv that this import does not
  replace, else the GNSS tags of a few frames in images/), within ``max(50 km, 2 x their extent)`` of them:
  UTM coordinates of a neighbouring zone read in the project's zone land 200-700 km away (6 degrees of
  longitude), inside that zone's area of use, where only the block itself can tell. Files that state their
  CRS are transformed rigorously (``aerotri.geom.crs.transform``) before these checks.
- **Ids**: when ``images/`` holds frames, every image id of the import must be one of them; every measured
  point must be a control point (of the import, else of control/points.csv). Those that are not are named.
- **Camera size**: an imported camera has the size of the frames in ``images/`` (a COLMAP or Metashape
  model made on resized frames is refused at the import, not by ``aerotri match``), and numbers in the units of
  its keys (``Camera.check_plausible``: a focal length in metres, a principal point in pixels are refused).
"""

from __future__ import annotations

import logging

import numpy as np

from aerotri.core.errors import CrsError, InputError, id_listing
from aerotri.core.project import Project
from aerotri.exchange.imported import ImportedBlock
from aerotri.geom.camera import CameraFileFields
from aerotri.geom.crs.definition import GRID_SCALE_LIMIT
from aerotri.geom.eo_check import radians_read_as_degrees

log = logging.getLogger(__name__)

NEAR_M = 50_000.0  # imported positions this far (or twice the project's extent) from the project's: refused
EXIF_FRAMES = 3  # frames whose GNSS tags stand for the project's position when it has no position file
SCALE_LIMIT = GRID_SCALE_LIMIT  # a project CRS whose scale factor at the block is off 1 by more: a note


def check_project_crs(project: Project, block: ImportedBlock) -> list[str]:
    """Refuse a project CRS a photo block cannot use; notes on a CRS in feet (see the module docstring)."""
    from aerotri.geom.crs.definition import crs_label, linear_unit_m, unit_long_name
    from aerotri.geom.eo import check_block_crs

    crs = check_block_crs(project.crs, f"{project.config_path} [project] crs")
    notes = []
    unit = linear_unit_m(crs)
    if abs(unit - 1.0) > 1e-12:
        if block.crs_assumed:
            raise CrsError(f"{', '.join(block.source)}: the files carry no CRS and the project CRS {crs_label(crs)} is "
                           f"in {unit_long_name(crs)}; give the files' CRS with --crs (the project's, {project.crs}, if "
                           f"their coordinates are in {unit_long_name(crs)}; its metric counterpart if in metres)")
        if block.gnss is not None or block.eo is not None or block.control is not None:
            notes.append(f"project CRS {crs_label(crs)} is in {unit_long_name(crs)}: imported positions converted to "
                         f"{unit_long_name(crs)} through the CRS policy; accuracies (the _m columns) stay in metres")
    elif block.crs_assumed:
        notes.append(f"{', '.join(block.source)}: no CRS in the files; coordinates taken in the project CRS "
                     f"{crs_label(crs)} (give --crs if they are in another)")
    return notes


def _imported_positions(block: ImportedBlock) -> list[tuple[str, list, np.ndarray]]:
    """(what, labels, (N, 3) positions) of everything with coordinates in the block."""
    out = []
    if block.eo is not None:
        out.append((f"orientations ({block.source_of('eo')})", list(block.eo.image_id), block.eo.centre_m))
    if block.gnss is not None:
        out.append((f"positions ({block.source_of('gnss')})", list(block.gnss.image_id), block.gnss.position_m))
    if block.control is not None:
        out.append((f"control ({block.source_of('control')})", list(block.control.id), block.control.xyz_m))
    return out


def _project_positions(project: Project, replaced: set) -> tuple[str, np.ndarray] | None:
    """(where from, (N, 2) map positions) the project already has, or None."""
    from aerotri.geom.eo import read_eo, read_gnss
    from aerotri.geom.observations import read_control_points

    readers = ((project.gnss_path, lambda p: read_gnss(p).position_m),
               (project.imported_eo_path, lambda p: read_eo(p).centre_m),
               (project.eo_path, lambda p: read_eo(p).centre_m),
               (project.control_points_path, lambda p: read_control_points(p).xyz_m))
    for path, read in readers:
        if path.is_file() and path not in replaced:
            try:
                return str(path), read(path)[:, :2]
            except InputError:  # another stage's problem; this check has nothing to compare with there
                continue
    return _frame_positions(project)


def _frame_positions(project: Project) -> tuple[str, np.ndarray] | None:
    """The GNSS tags (EXIF/XMP) of the first frames in images/, in the project CRS, or None."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    from aerotri.exchange.exif import read_frame_metadata
    from aerotri.exchange.imported import to_project_crs
    from aerotri.geom.images import IMAGE_SUFFIXES

    if not project.images_dir.is_dir():
        return None
    frames = sorted(p for p in project.images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)[:EXIF_FRAMES]
    lla = []
    for f in frames:
        try:
            with warnings.catch_warnings():  # frames are not georeferenced rasters; rasterio says so for each
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                m = read_frame_metadata(f)
        except InputError:
            continue
        if None not in (m.lat_deg, m.lon_deg, m.alt_m):
            lla.append([m.lon_deg, m.lat_deg, m.alt_m])
    if not lla:
        return None
    try:
        xyz = to_project_crs(np.array(lla), "EPSG:4979", project, "frame GNSS tags")
    except (InputError, CrsError):
        return None
    return f"the GNSS tags of {len(lla)} frame(s) in {project.images_dir}", xyz[:, :2]


def check_positions(project: Project, block: ImportedBlock, replaced: set) -> None:
    """Imported positions in the area of use of the project CRS and near the project's own positions."""
    from aerotri.geom.crs.definition import check_coordinates, crs_label, linear_unit_m, project_crs

    crs = project_crs(project)
    unit_m = linear_unit_m(crs) if not crs.is_engineering else 1.0
    found = _imported_positions(block)
    for what, labels, xyz in found:
        try:
            check_coordinates(crs, xyz[:, 0], xyz[:, 1], f"{what} in {crs_label(crs)}", [f"{x}" for x in labels])
        except InputError as exc:
            if block.crs_assumed:
                raise
            # kite trial: the numbers quoted are in no file (UTM 11N targets converted into a UTM 12N project)
            raise InputError(f"{exc}. These are the file's coordinates converted from the CRS it names (or --crs) "
                             f"into the project CRS {crs_label(crs)}: if the file is right, the project's CRS is of "
                             "another zone or area ([project] crs, set at aerotri init --crs)") from None
    if not found:
        return
    ref = _project_positions(project, replaced)
    if ref is None:
        return
    where, ref_xy = ref
    extent = float(np.hypot(*(ref_xy.max(axis=0) - ref_xy.min(axis=0)))) * unit_m
    limit = max(NEAR_M, 2.0 * extent)
    for what, labels, xyz in found:
        centre = np.median(xyz[:, :2], axis=0)
        d = float(np.min(np.hypot(*(ref_xy - centre).T))) * unit_m
        if d > limit:
            raise InputError(f"{what}: {d / 1000:.0f} km from the project's positions ({where}; their extent "
                             f"{extent / 1000:.1f} km) in {crs_label(crs)}: another zone or CRS? give the files' CRS "
                             f"with --crs, or fix [project] crs")


def _project_frames(project: Project):
    """The frames of the project's images/ (``ImageFiles``), None when it holds none."""
    from aerotri.geom.images import IMAGE_SUFFIXES, find_images

    if not project.images_dir.is_dir() or not any(p.suffix.lower() in IMAGE_SUFFIXES
                                                   for p in project.images_dir.iterdir()):
        return None
    return find_images(project.images_dir)


def check_image_ids(project: Project, block: ImportedBlock, frames=None) -> None:
    """Every image id of the import is a frame in images/ (``frames``: ``_project_frames``; None: images/ holds
    none, nothing to check)."""
    if frames is None:
        return
    for what, ids in (("orientations", None if block.eo is None else block.eo.image_id),
                      ("positions", None if block.gnss is None else block.gnss.image_id),
                      ("control measurements", None if block.image_points is None else block.image_points.image_id)):
        if ids is None:
            continue
        missing = sorted({str(i) for i in ids} - set(frames.image_id))
        if missing:
            field = {"orientations": "eo", "positions": "gnss", "control measurements": "image_points"}[what]
            where = block.source_of(field)
            obs = block.image_points
            if field == "image_points" and obs.line is not None:
                # the first line naming one (trial-kite: a line without its image name read the target as an image)
                k = next(q for q, i in enumerate(obs.image_id) if str(i) in missing)
                where = obs.where(k, where)
            raise InputError(f"{where}: {what} of image(s) {id_listing(missing)} that are not frames "
                             f"in {project.images_dir} ({len(frames)} frames, e.g. "
                             f"{id_listing(sorted(frames.image_id), 3)})")
    if block.image_points is not None and len(block.image_points):
        _check_measurements_in_frames(block, dict(zip(frames.image_id, frames.path)))


def _check_measurements_in_frames(block: ImportedBlock, frame_paths: dict) -> None:
    """Every control measurement lies on its frame; one off it (a typo, another frame's size) is refused naming its
    line (trial-kite: x 9093.79 px in a 4272 px frame was kept until the adjustment dropped it). The frames' size
    from the header of the first frame measured (a project's frames are of one camera, ``check_camera_size``)."""
    import rasterio

    from aerotri.geom.camera import inside_frame

    obs = block.image_points
    images = obs.image_id.astype(str)
    try:
        with rasterio.open(frame_paths[images[0]]) as ds:
            w, h = ds.width, ds.height
    except (KeyError, rasterio.errors.RasterioIOError, OSError):
        return  # an unreadable frame is named where frames are read
    off = ~inside_frame(obs.xy_px[:, 0], obs.xy_px[:, 1], w, h)
    if off.any():
        q = int(np.flatnonzero(off)[0])
        raise InputError(f"{obs.where(q, block.source_of('image_points'))}: point {str(obs.point_id[q])!r} "
                         f"measured at ({obs.xy_px[q, 0]:.2f}, {obs.xy_px[q, 1]:.2f}) px in {str(images[q])!r}, off its "
                         f"{w} x {h} px frame (x -0.5 .. {w - 0.5:g}, y -0.5 .. {h - 0.5:g})")


def check_camera_size(project: Project, block: ImportedBlock) -> None:
    """The imported camera has the size of the frames in images/ (the first frame's header): a model made on
    resized frames would otherwise be written and refused only by ``aerotri match``."""
    import rasterio

    from aerotri.geom.images import IMAGE_SUFFIXES, find_images

    if block.camera is None or not project.images_dir.is_dir() or not any(
            p.suffix.lower() in IMAGE_SUFFIXES for p in project.images_dir.iterdir()):
        return
    path = find_images(project.images_dir).path[0]
    try:
        with rasterio.open(path) as ds:
            w, h = ds.width, ds.height
    except (rasterio.errors.RasterioIOError, OSError):
        return  # an unreadable frame is named where frames are read
    cam = block.camera
    if (w, h) != (cam.width, cam.height):
        raise InputError(f"{block.source_of('camera')}: the camera is {cam.width} x {cam.height} px but the frames in "
                         f"{project.images_dir} are {w} x {h} px ({path.name}): a model of resized frames (its camera "
                         f"scaled by {w / cam.width:.4g} would fit these), or other frames")


def check_point_ids(project: Project, block: ImportedBlock, replaced: set) -> None:
    """Every measured point of the import is a control point: of the import, else of control/points.csv."""
    from aerotri.geom.observations import read_control_points

    if block.image_points is None:
        return
    if block.control is not None:
        known, where = set(map(str, block.control.id)), block.source_of("control")
    elif project.control_points_path.is_file() and project.control_points_path not in replaced:
        known, where = set(map(str, read_control_points(project.control_points_path).id)), str(project.control_points_path)
    else:
        raise InputError(f"{block.source_of('image_points')}: image measurements of points no control file names "
                         f"(import the control points with them, or have {project.control_points_path})")
    missing = sorted({str(p) for p in block.image_points.point_id} - known)
    if missing:
        raise InputError(f"{block.source_of('image_points')}: measurements of point(s) {id_listing(missing)} that are "
                         f"not control points in {where}")


def scale_note(project: Project, block: ImportedBlock) -> list[str]:
    """A note when the project CRS's point scale factor where the imported positions lie is off 1 by more than
    ``SCALE_LIMIT`` (Web Mercator at Brighton Beach: 1.462): its metres are then no ground metres."""
    from aerotri.geom.crs.definition import crs_label, horizontal_crs, point_scale_factor, project_crs, utm_zone_label
    from aerotri.geom.crs.transform import to_own_geodetic

    found = _imported_positions(block)
    crs = project_crs(project)
    if not found or crs.is_engineering or not horizontal_crs(crs).is_projected:
        return []
    xyz = np.median(np.vstack([f[2] for f in found]), axis=0)
    lon, lat, _ = to_own_geodetic(crs, np.array([xyz[0]]), np.array([xyz[1]]), np.array([0.0]))
    k = point_scale_factor(horizontal_crs(crs), lon[0], lat[0])
    if not np.isfinite(k) or abs(k - 1.0) <= SCALE_LIMIT:
        return []
    utm = utm_zone_label(lon[0], lat[0])
    return [f"project CRS {crs_label(crs)} has a scale factor of {k:.3f} where the block is (lat {float(lat[0]):.2f}, "
            f"lon {float(lon[0]):.2f}): a ground metre is {k:.3f} of its units, so pixel sizes (ortho rectify "
            f"--res-m), GSDs and accuracy limits in them are no ground measures; a map grid made for measuring, e.g. "
            f"the block's UTM zone {utm}, keeps it within 0.1 % ([project] crs in {project.config_path.name})"]


def lever_arm_note(project: Project, block: ImportedBlock, centre_priors: bool = False) -> list[str]:
    """A note when ``--as-gnss`` writes projection centres to gnss.txt (a reconstruction's, not its GNSS) and the
    project has a lever arm: the adjustment takes gnss.txt as antenna positions and puts each centre the lever arm
    away (the demo's [0.05, -0.12, 1.45] m: the check heights 1.64 m RMS off, 4 of the 7 control points rejected).
    ``centre_priors``: the positions are the format's priors of the centres (OpenSfM's gps_position, which OpenSfM
    compares with the optical centre; aerotri's export reduces its antennas to them: trial s100 ex F1)."""
    if block.gnss is None or (block.eo is None and not centre_priors):
        return []
    if not centre_priors:
        eo_rows = {i: k for k, i in enumerate(block.eo.image_id)}
        pairs = [(k, eo_rows[i]) for k, i in enumerate(block.gnss.image_id) if i in eo_rows]
        if not pairs or np.abs(block.gnss.position_m[[a for a, _ in pairs]]
                               - block.eo.centre_m[[b for _, b in pairs]]).max() > 1e-3:
            return []  # GNSS positions of the format's own, not the centres
    table = project.stage_table("adjust")
    where = f"{project.config_path.name} [adjust]" if "lever_arm_m" in table else f"{project.config_path.name} [gnss]"
    lever = np.asarray(table.get("lever_arm_m", project.gnss.lever_arm_m), float)
    if not np.any(lever != 0.0):
        return []
    return [f"gnss.txt: the {len(block.gnss.image_id)} positions are projection centres, but {where} lever_arm_m = "
            f"[{', '.join(f'{v:g}' for v in lever)}] m: the adjustment takes gnss.txt as antenna positions and puts "
            f"each centre {float(np.linalg.norm(lever)):.3g} m from them; set lever_arm_m = [0, 0, 0] (or "
            "aerotri adjust --lever-arm-m 0 0 0) for these positions"]


# each format's names for the camera numbers ``Camera.check_plausible`` judges, and its convention (review 21:
# COLMAP's cx, cy = 0, 0 and Metashape's corner values in its centre-offset fields passed, named as ppx_mm)
CAMERA_FILE_FIELDS = {
    "colmap": CameraFileFields("cameras.txt cx, cy", "COLMAP's cx, cy are pixels from the image's top-left corner, "
                               "the centre near width / 2, height / 2", "cameras.txt f (fx, fy)",
                               "COLMAP's focal length is in pixels"),
    "metashape": CameraFileFields("<calibration> cx, cy", "Metashape's cx, cy are the offset from the image centre "
                                  "in pixels (near 0), not the pixel position of the centre", "<calibration> f",
                                  "Metashape's f is in pixels"),
    "orthority": CameraFileFields("cx, cy", "orthority's cx, cy are the offset from the image centre over the longer "
                                  "side (near 0; 0.5 is the frame's edge)", "focal_len",
                                  "orthority's focal_len is in sensor_size's unit (mm), without sensor_size over the "
                                  "image width"),
    "opensfm": CameraFileFields("c_x, c_y", "OpenSfM's c_x, c_y are the offset from the image centre over the longer "
                                "side (near 0)", "focal (focal_x)", "OpenSfM's focal length is over the longer side"),
    "exif": CameraFileFields("DewarpData cx, cy", "DJI's DewarpData cx, cy are the offset from the image centre in "
                             "pixels of the full-size frame (near 0)", "DewarpData fx, fy",
                             "DJI's DewarpData fx, fy are pixels of the full-size frame"),
}


def frames_left_without(project: Project, block: ImportedBlock, frames=None) -> list[str]:
    """The note naming the frames of images/ (``frames``: ``_project_frames``) the import gives no orientation (or
    position): a COLMAP images.txt cut between two images imported 3 of 18 frames without a word (trial s96 M5);
    frames another tool did not orient read the same. [] when every frame has one, or images/ holds none."""
    field, ids = ("eo", block.eo.image_id) if block.eo is not None else (
        ("gnss", block.gnss.image_id) if block.gnss is not None else (None, None))
    if ids is None or frames is None:
        return []
    without = sorted(set(frames.image_id) - {str(i) for i in ids})
    if not without:
        return []
    what = "orientation" if field == "eo" else "position"
    return [f"{block.source_of(field)}: {len(without)} of {len(frames)} frames in {project.images_dir} get no {what} "
            f"from it ({id_listing(without)}): a file cut short, or frames the other program did not orient? They "
            "stay out of the block until they have one"]


def check_import(project: Project, block: ImportedBlock, replaced: set, format_name: str = "") -> list[str]:
    """Every check of the module docstring; returns the notes to print (``replaced``: the project files
    this import writes, which do not stand for the project's position; ``format_name``: the camera's fields named in
    the file's terms, ``CAMERA_FILE_FIELDS``)."""
    notes = check_project_crs(project, block)
    check_positions(project, block, replaced)
    notes += scale_note(project, block)
    frames = _project_frames(project)
    check_image_ids(project, block, frames)
    notes += frames_left_without(project, block, frames)
    if block.camera is not None:
        block.camera.check_plausible(block.source_of("camera"), CAMERA_FILE_FIELDS.get(format_name))
    check_camera_size(project, block)
    check_point_ids(project, block, replaced)
    if block.eo is not None:
        # said, not refused: a drone holding its heading within 3 deg of north on every line looks the same
        # (trial-messy F13: orthority angles in radians imported silently, the orthos then 176 deg off)
        why = radians_read_as_degrees(block.eo)
        if why:
            log.warning(f"{block.source_of('eo')}: {why}")
    return notes + lever_arm_note(project, block, centre_priors=format_name == "opensfm")


def unmeasured_heights(z: np.ndarray) -> str | None:
    """Why the finite heights ``z`` of a control file were not measured (all 0, or all one number), or None."""
    z = np.asarray(z, float)
    z = z[np.isfinite(z)]
    if len(z) == 0:
        return None
    if np.all(z == 0.0):
        return f"all {len(z)} heights are 0"
    if len(z) >= 3 and np.all(z == z[0]):
        return f"all {len(z)} heights are {z[0]:g}"
    return None


def plan_only_when_unmeasured(block, heights_measured: bool, source: str) -> None:
    """Control of any format whose heights nobody measured (all 0, or all one number) becomes plan-only: full
    points horizontal, height points dropped, with a note; ``heights_measured`` (``--heights-measured``) keeps
    them."""
    c = block.control
    if c is None or heights_measured or not len(c):
        return
    has_z = np.isin(c.kind, ["full", "height"])
    why = unmeasured_heights(c.xyz_m[has_z, 2]) if has_z.any() else None
    if why is None:
        return
    from aerotri.geom.observations import ControlPoints

    keep = c.kind != "height"
    kind = np.where(c.kind == "full", "horizontal", c.kind).astype(object)
    xyz = c.xyz_m.copy()
    xyz[has_z, 2] = 0.0
    block.control = ControlPoints(c.id[keep], kind[keep], xyz[keep], c.sigma_m[keep])
    dropped = int((~keep).sum())
    block.notes.append(f"{source}: control {why}: taken as not measured; full points are horizontal control (plan "
                       f"only)" + (f", {dropped} height-only points dropped" if dropped else "")
                       + ". If the heights were surveyed, import again with --heights-measured")
