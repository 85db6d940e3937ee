"""Import of drone frames' own metadata: EXIF GPS and DJI XMP (``aerotri import --format exif``).

What is read from each image (a JPEG or TIFF; tags through GDAL, which gives the EXIF of JPEGs and of
GDAL-written TIFFs as ``EXIF_*`` items and the XMP packet as the ``xml:XMP`` domain):

- position: DJI XMP ``drone-dji:GpsLatitude``, ``GpsLongtitude`` (DJI's spelling; ``GpsLongitude`` also
  taken), ``AbsoluteAltitude``, else EXIF ``GPSLatitude/Longitude/Altitude`` (degrees, minutes, seconds;
  references N/S, E/W, above/below). Positions are taken as WGS84 lat/lon with the altitude an
  ellipsoidal height (EPSG:4979) unless ``--crs`` names the CRS they are in (e.g. ``EPSG:4326+3855`` when
  the altitudes are EGM2008 heights; DJI states ellipsoidal heights for RTK fixes, consumer drones often
  write heights above the geoid; a 2D ``--crs`` such as ``EPSG:4326`` names no height system and the altitudes
  are taken as ellipsoidal heights too); then converted to the project CRS (``to_project_crs``). The antenna to
  camera offset is not known and not applied.
- accuracy: DJI RTK ``RtkStdLon``, ``RtkStdLat``, ``RtkStdHgt`` (m) -> gnss.txt sX sY sZ (east, north, up
  taken as the grid axes: the meridian convergence mixes sX and sY by less than their difference matters),
  else ``--sigma-xyz-m``, else none in gnss.txt and, when project.toml has no [gnss] section, a consumer
  receiver's model appended to it (``CONSUMER_GNSS``: decimetres between frames, one offset of metres for the
  flight; ``aerotri.adjust.gnss_model``).
- camera: DJI ``DewarpData`` = ``date;fx,fy,cx,cy,k1,k2,p1,p2,k3`` (the factory calibration; fx, fy in
  pixels, cx, cy the principal point's offset from the photo centre in pixels, x right, y down, for the
  full sensor of EXIF ``PixelXDimension`` x ``PixelYDimension``; k1 k2 p1 p2 k3 OpenCV's Brown model on
  normalised coordinates: DJI's manuals, and its camera matrix [fx, 0, W/2 + cx; 0, fy, H/2 + cy] for
  OpenCV ``undistort``). Scaled to the image size on disk (downsampled frames keep the full size in
  EXIF): focal length and offsets in pixels scale, the coefficients do not. Our model has one focal
  length: f = (fx + fy) / 2 (a note gives the difference at the image edge). Without DewarpData the
  nominal camera: EXIF focal length, principal point at the centre, no distortion. Pixel size
  (``pixel_size_mm``): EXIF ``FocalPlaneXResolution`` with its ``FocalPlaneResolutionUnit``, else DJI's
  ``CalibratedFocalLength`` (px) for the EXIF focal length (mm), else the sensor width of the camera's
  make and model (``data/sensor_widths.csv``, sources cited there) over the image's long side, else the
  35 mm equivalent focal length (diagonal; a warning says so: a frame cropped from the sensor, such as the
  16:9 frames of a 4:3 sensor, makes it wrong by the crop: 7 % on the Phantom 3's 4000 x 2250 frames).
- attitude: DJI ``GimbalYawDegree``, ``GimbalPitchDegree``, ``GimbalRollDegree`` (the camera's attitude:
  yaw from true north clockwise, pitch -90 = nadir; Tait-Bryan z-y-x in north-east-down) -> imported/eo.txt
  as omega, phi, kappa (see :func:`opk_from_gimbal`). These are the drone's estimates, degrees off;
  a note says so.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import re
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange.imported import ImportedBlock, ImportSettings, to_project_crs
from aerotri.geom.camera import BrownCamera
from aerotri.geom.eo import ExteriorOrientations, GnssPositions
from aerotri.geom.images import IMAGE_SUFFIXES, check_not_truncated
from aerotri.geom.rotation import FLIP_YZ, opk_from_matrix

log = logging.getLogger(__name__)
# EXIF FocalPlaneResolutionUnit -> mm: 2 inch, 3 cm (EXIF 2.3), 4 mm, 5 um (TIFF/EP, as ExifTool reads them)
FOCAL_PLANE_UNIT_MM = {"2": 25.4, "3": 10.0, "4": 1.0, "5": 0.001}

DEFAULT_CRS = "EPSG:4979"  # WGS84 latitude, longitude, ellipsoidal height
# A consumer drone's GNSS (no RTK, the EXIF states no accuracy), written into project.toml [gnss] by the import:
# sigma_xy_m, sigma_z_m between frames of one flight, and offset_sigma_xy_m, offset_sigma_z_m of the one offset
# common to the flight (its absolute accuracy; aerotri.adjust.gnss_model). Measured on Brighton Beach (DJI FC300S)
# with the ODM cloud's DEM as surface control: GNSS residuals about the estimated offset 0.32 / 0.54 m RMS east /
# north, 0.39 m in height (bench/eval_consumer_gnss.py); the offset's 3 / 5 m a consumer receiver's absolute accuracy.
CONSUMER_GNSS = (0.5, 0.5, 3.0, 5.0)


def consumer_gnss_section() -> str:
    """The [gnss] section of a consumer drone's GNSS (``CONSUMER_GNSS``) for project.toml, with comments."""
    sxy, sz, oxy, oz = CONSUMER_GNSS
    return ("[gnss]  # aerotri import --format exif: the EXIF states no accuracy (no RTK), a consumer receiver's GNSS\n"
            f"sigma_xy_m = {sxy}         # between frames of one flight (m)\n"
            f"sigma_z_m = {sz}\n"
            f"offset_sigma_xy_m = {oxy}  # one offset common to the flight, estimated by the adjustment: the "
            "receiver's absolute accuracy (m)\n"
            f"offset_sigma_z_m = {oz}\n")
DIAGONAL_35MM_MM = math.hypot(36.0, 24.0)

# body (x forward, y right, z down) -> computer-vision camera (x right, y down, z forward): the camera looks
# along the gimbal's forward axis
_BODY_FROM_CV = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclasses.dataclass(kw_only=True)
class FrameMetadata:
    """What one frame's EXIF and XMP say (units in the names; None: not stated)."""

    path: Path
    width: int  # on disk, px
    height: int
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    rtk_sigma_m: tuple[float, float, float] | None = None  # east (lon), north (lat), up
    rtk_flag: int | None = None
    gimbal_ypr_deg: tuple[float, float, float] | None = None
    flight_ypr_deg: tuple[float, float, float] | None = None
    dewarp: tuple[float, ...] | None = None  # fx fy cx cy k1 k2 p1 p2 k3 (px of the full sensor)
    full_size: tuple[int, int] | None = None  # EXIF PixelX/YDimension
    focal_mm: float | None = None
    focal_35mm: float | None = None
    focal_plane_px_per_mm: float | None = None
    calibrated_focal_px: float | None = None
    relative_alt_m: float | None = None  # DJI RelativeAltitude: height above the take-off point
    model: str = ""
    make: str = ""


# -- reading tags ---------------------------------------------------------------------------------------
def _xmp_attributes(xmp: str) -> dict[str, str]:
    """``prefix:Name`` -> value of an XMP packet's attributes and simple elements."""
    out = {k: v for k, v in re.findall(r'([A-Za-z][\w-]*:[A-Za-z]\w*)\s*=\s*"([^"]*)"', xmp)}
    out.update({k: v for k, v, _ in re.findall(r"<([A-Za-z][\w-]*:[A-Za-z]\w*)>([^<]*)</(\1)>", xmp)})
    return out


def read_tags(path) -> tuple[dict[str, str], dict[str, str]]:
    """(EXIF items ``EXIF_*`` as GDAL gives them, XMP attributes) of an image file."""
    import rasterio

    try:
        with rasterio.open(path) as ds:
            check_not_truncated(ds, path)  # cut in its header, a frame's tags are missing, not absent
            exif = {k: v for k, v in ds.tags().items() if k.startswith("EXIF_")}
            xmp = ds.tags(ns="xml:XMP") if "xml:XMP" in (ds.tag_namespaces() or []) else {}
            size = (ds.width, ds.height)
    except (rasterio.errors.RasterioIOError, OSError) as exc:
        raise InputError(f"{path}: cannot read the image ({exc})") from None
    packet = next(iter(xmp.values()), "") if xmp else ""
    exif["_size"] = f"{size[0]} {size[1]}"
    return exif, _xmp_attributes(packet)


def _rationals(text: str, path, tag: str) -> list[float]:
    """GDAL's ``(a) (b) (c)`` rendering of EXIF rationals."""
    vals = re.findall(r"\(([^)]*)\)", text) or text.split()
    try:
        out = [float(v) for v in vals]
    except ValueError:
        raise InputError(f"{path}: EXIF {tag} = {text!r} is not a number") from None
    if not out or not all(math.isfinite(v) for v in out):
        raise InputError(f"{path}: EXIF {tag} = {text!r} is not a finite number")
    return out


def _dms(text: str, ref: str, path, tag: str) -> float:
    v = _rationals(text, path, tag)
    deg = v[0] + (v[1] if len(v) > 1 else 0.0) / 60.0 + (v[2] if len(v) > 2 else 0.0) / 3600.0
    return -deg if ref.strip().upper() in ("S", "W") else deg


def _xmp_float(xmp: dict, key: str, path) -> float | None:
    if key not in xmp:
        return None
    try:
        v = float(xmp[key])
    except ValueError:
        raise InputError(f"{path}: XMP {key} = {xmp[key]!r} is not a number") from None
    if not math.isfinite(v):
        raise InputError(f"{path}: XMP {key} = {xmp[key]!r} is not a finite number")
    return v


def _angles(xmp: dict, prefix: str, path) -> tuple[float, float, float] | None:
    v = [_xmp_float(xmp, f"drone-dji:{prefix}{a}Degree", path) for a in ("Yaw", "Pitch", "Roll")]
    return None if any(a is None for a in v) else (v[0], v[1], v[2])


def _dewarp(text: str, path) -> tuple[float, ...]:
    """``date;fx,fy,cx,cy,k1,k2,p1,p2,k3`` -> the 9 numbers."""
    body = text.split(";", 1)[-1]
    try:
        vals = tuple(float(v) for v in body.split(","))
    except ValueError:
        raise InputError(f"{path}: XMP drone-dji:DewarpData = {text!r}; expected 'date;fx,fy,cx,cy,k1,k2,p1,p2,k3'") from None
    if len(vals) != 9 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{path}: XMP drone-dji:DewarpData has {len(vals)} values; expected 9 finite numbers "
                         f"(date;fx,fy,cx,cy,k1,k2,p1,p2,k3)")
    if vals[0] <= 0 or vals[1] <= 0:
        raise InputError(f"{path}: XMP drone-dji:DewarpData focal lengths fx, fy must be positive, got {vals[:2]}")
    return vals


def read_frame_metadata(path) -> FrameMetadata:
    """The EXIF and DJI XMP of one image (see the module docstring); refuses malformed values naming the tag."""
    path = Path(path)
    exif, xmp = read_tags(path)
    w, h = (int(v) for v in exif.pop("_size").split())
    m = FrameMetadata(path=path, width=w, height=h, model=exif.get("EXIF_Model", xmp.get("tiff:Model", "")).strip(),
                      make=exif.get("EXIF_Make", xmp.get("tiff:Make", "")).strip())
    lat = _xmp_float(xmp, "drone-dji:GpsLatitude", path)
    lon = _xmp_float(xmp, "drone-dji:GpsLongtitude", path)
    if lon is None:
        lon = _xmp_float(xmp, "drone-dji:GpsLongitude", path)
    if lat is None and "EXIF_GPSLatitude" in exif:
        lat = _dms(exif["EXIF_GPSLatitude"], exif.get("EXIF_GPSLatitudeRef", "N"), path, "GPSLatitude")
    if lon is None and "EXIF_GPSLongitude" in exif:
        lon = _dms(exif["EXIF_GPSLongitude"], exif.get("EXIF_GPSLongitudeRef", "E"), path, "GPSLongitude")
    alt = _xmp_float(xmp, "drone-dji:AbsoluteAltitude", path)
    if alt is None and "EXIF_GPSAltitude" in exif:
        alt = _rationals(exif["EXIF_GPSAltitude"], path, "GPSAltitude")[0]
        if exif.get("EXIF_GPSAltitudeRef", "0").strip() in ("1", "0x01"):
            alt = -alt
    if lat is not None and not -90.0 <= lat <= 90.0:
        raise InputError(f"{path}: latitude {lat} is outside -90..90 degrees")
    if lon is not None and not -180.0 <= lon <= 180.0:
        raise InputError(f"{path}: longitude {lon} is outside -180..180 degrees")
    m.lat_deg, m.lon_deg, m.alt_m = lat, lon, alt
    std = [_xmp_float(xmp, f"drone-dji:RtkStd{a}", path) for a in ("Lon", "Lat", "Hgt")]
    if all(s is not None for s in std):
        if min(std) <= 0:
            raise InputError(f"{path}: XMP RtkStdLon/Lat/Hgt must be positive, got {std}")
        m.rtk_sigma_m = (std[0], std[1], std[2])
    flag = _xmp_float(xmp, "drone-dji:RtkFlag", path)
    m.rtk_flag = None if flag is None else int(flag)
    m.gimbal_ypr_deg = _angles(xmp, "Gimbal", path)
    m.flight_ypr_deg = _angles(xmp, "Flight", path)
    if "drone-dji:DewarpData" in xmp:
        m.dewarp = _dewarp(xmp["drone-dji:DewarpData"], path)
    if "EXIF_PixelXDimension" in exif and "EXIF_PixelYDimension" in exif:
        try:
            m.full_size = (int(exif["EXIF_PixelXDimension"]), int(exif["EXIF_PixelYDimension"]))
        except ValueError:
            raise InputError(f"{path}: EXIF PixelXDimension/PixelYDimension are not integers") from None
    if "EXIF_FocalLength" in exif:
        m.focal_mm = _rationals(exif["EXIF_FocalLength"], path, "FocalLength")[0]
    if "EXIF_FocalLengthIn35mmFilm" in exif:
        m.focal_35mm = _rationals(exif["EXIF_FocalLengthIn35mmFilm"], path, "FocalLengthIn35mmFilm")[0] or None
    if "EXIF_FocalPlaneXResolution" in exif:
        per_unit = _rationals(exif["EXIF_FocalPlaneXResolution"], path, "FocalPlaneXResolution")[0]
        unit = exif.get("EXIF_FocalPlaneResolutionUnit", "2").strip()  # EXIF's default: inches
        mm_per_unit = FOCAL_PLANE_UNIT_MM.get(unit)
        if mm_per_unit is None:
            # 1 is "no absolute unit": a resolution per nothing is no pixel size; the next source is taken
            log.warning("%s: EXIF FocalPlaneResolutionUnit %s is not a length (2 inch, 3 cm, 4 mm, 5 um): the "
                        "focal plane resolution is not used", path, unit)
        else:
            m.focal_plane_px_per_mm = per_unit / mm_per_unit or None
    m.calibrated_focal_px = _xmp_float(xmp, "drone-dji:CalibratedFocalLength", path)
    m.relative_alt_m = _xmp_float(xmp, "drone-dji:RelativeAltitude", path)
    return m


# -- conversions ----------------------------------------------------------------------------------------
def opk_from_gimbal(ypr_deg, R_map_from_enu=None) -> np.ndarray:
    """Omega, phi, kappa (deg) of a camera with DJI gimbal yaw, pitch, roll (deg).

    Gimbal angles are Tait-Bryan z-y-x in north-east-down (yaw from north clockwise, pitch up positive,
    -90 = nadir, roll right positive) and rotate the gimbal's body frame (x forward, y right, z down),
    along whose x axis the camera looks with the image's x axis to the right: R_NED<-cam =
    Rz(yaw) Ry(pitch) Rx(roll) @ B with B the body <- computer-vision camera permutation. Then ENU <- NED,
    the grid axes <- ENU (``R_map_from_enu``: the meridian convergence at the camera; identity if None),
    and the photogrammetric camera frame (y, z flipped). A nadir frame with yaw 0 has the top of the image
    to the north: omega = phi = kappa = 0."""
    y, p, r = np.radians(np.asarray(ypr_deg, float))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    R_enu_cv = _ENU_FROM_NED @ Rz @ Ry @ Rx @ _BODY_FROM_CV
    R = (np.eye(3) if R_map_from_enu is None else R_map_from_enu) @ R_enu_cv @ FLIP_YZ
    return np.array(opk_from_matrix(R))


SENSOR_TABLE = Path(__file__).with_name("data") / "sensor_widths.csv"
FROM_35MM = "35 mm equivalent focal length (diagonal)"


def _make_key(make: str) -> str:
    """The first word of an EXIF Make, lower case ("NIKON CORPORATION" -> "nikon")."""
    return (make.strip().split() or [""])[0].lower()


@dataclasses.dataclass(frozen=True)
class SensorWidth:
    """One row of the sensor table: the EXIF make's first word and the model (both lower case), the sensor's
    long side (mm) and where that width comes from (``opensfm`` or ``format``: the CSV's header)."""

    make: str
    model: str
    width_mm: float
    source: str


@dataclasses.dataclass(frozen=True)
class SensorTable:
    """The rows of ``data/sensor_widths.csv``, in file order."""

    rows: tuple[SensorWidth, ...]

    def width_of(self, make: str, model: str) -> SensorWidth | None:
        """The row of a camera's EXIF Make and Model (the make by its first word, case ignored), or None."""
        make, model = _make_key(make), model.strip().lower()
        return next((r for r in self.rows if r.make == make and r.model == model), None)


@functools.lru_cache(maxsize=1)
def sensor_table() -> SensorTable:
    """``data/sensor_widths.csv`` (shipped with the package: a broken row is a bug, not bad input)."""
    import csv

    with open(SENSOR_TABLE, newline="") as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        return SensorTable(tuple(SensorWidth(_make_key(r["make"]), r["model"].strip().lower(),
                                             float(r["sensor_width_mm"]), r["source"]) for r in rows))


def pixel_size_mm(m: FrameMetadata, full_w: int, full_h: int) -> tuple[float, str]:
    """Pixel size (mm) of the full sensor and where it came from (the module docstring's order)."""
    if m.focal_plane_px_per_mm:
        return 1.0 / m.focal_plane_px_per_mm, "EXIF focal plane resolution"
    if m.focal_mm and m.calibrated_focal_px:
        return m.focal_mm / m.calibrated_focal_px, "EXIF focal length / DJI CalibratedFocalLength"
    sensor = sensor_table().width_of(m.make, m.model)
    if sensor is not None:
        width_mm, source = sensor.width_mm, sensor.source
        # the sensor's long side is the frame's long side (frames are cropped across it, e.g. 16:9 from 4:3)
        return width_mm / max(full_w, full_h), (f"sensor width {width_mm:g} mm of the {m.make} {m.model} "
                                                f"(sensor table, {source}) over {max(full_w, full_h)} px")
    if m.focal_mm and m.focal_35mm:
        diag_mm = DIAGONAL_35MM_MM * m.focal_mm / m.focal_35mm
        return diag_mm / math.hypot(full_w, full_h), FROM_35MM
    if not (m.make or m.model or m.focal_mm):
        raise InputError(f"{m.path}: no camera in the EXIF (no focal length, make or model); write camera.toml "
                         "yourself")
    which = (f"the {m.make} {m.model} is not in the sensor table" if (m.make or m.model)
             else "no make or model for the sensor table")
    raise InputError(f"{m.path}: no pixel size: EXIF has no focal plane resolution, {which} ({SENSOR_TABLE.name}), "
                     f"and there is no focal length with a 35 mm equivalent or DJI CalibratedFocalLength; write "
                     f"camera.toml yourself")


def camera_from_metadata(m: FrameMetadata) -> tuple[BrownCamera, list[str]]:
    """The camera of a frame's metadata at its size on disk, and notes (see the module docstring)."""
    full_w, full_h = m.full_size or (m.width, m.height)
    scale = m.width / full_w
    if abs(m.height - full_h * scale) > 1.0:
        raise InputError(f"{m.path}: image is {m.width} x {m.height} px, EXIF says {full_w} x {full_h} px: not one "
                         f"scale (the frame was cropped?); the calibration cannot be scaled")
    pix_full_mm, pix_source = pixel_size_mm(m, full_w, full_h)
    notes = []
    pix_mm = pix_full_mm / scale
    if m.dewarp is not None:
        fx, fy, cx, cy, k1, k2, p1, p2, k3 = m.dewarp
        f_px = 0.5 * (fx + fy)
        # the principal point's offset from the photo centre, in mm, is the same at every scale
        cam = BrownCamera(focal_mm=f_px * pix_full_mm, pixel_um=pix_mm * 1000.0, width=m.width, height=m.height,
                          ppx_mm=cx * pix_full_mm, ppy_mm=-cy * pix_full_mm, k1=k1, k2=k2, k3=k3, p1=p1, p2=p2,
                          name=f"{m.model or 'DJI'} (DJI DewarpData)")
        edge_px = abs(fx - fy) / f_px * (m.height / 2.0)
        notes.append(f"camera: DJI factory calibration (DewarpData) of {full_w} x {full_h} px scaled by {scale:g} to "
                     f"{m.width} x {m.height} px; fx {fx:g} and fy {fy:g} px averaged (one focal length: "
                     f"{edge_px:.2f} px at the top and bottom edges of the frame on disk); pixel size from {pix_source}")
    else:
        if not m.focal_mm:
            raise InputError(f"{m.path}: no EXIF FocalLength and no DJI DewarpData; write camera.toml yourself")
        cam = BrownCamera(focal_mm=m.focal_mm, pixel_um=pix_mm * 1000.0, width=m.width, height=m.height,
                          name=f"{m.model or 'camera'} (EXIF nominal)")
        notes.append(f"camera: nominal from EXIF (focal length {m.focal_mm:g} mm = {cam.focal_px:.1f} px, pixel size "
                     f"{pix_mm * 1000.0:.4g} um from {pix_source}); principal point at the centre, no distortion: "
                     f"self-calibrate in the adjustment (with height control or a DEM for the focal length)")
    if pix_source == FROM_35MM:
        notes.append(f"camera: the pixel size comes from the 35 mm equivalent focal length ({m.focal_35mm:g} mm), "
                     f"which assumes the frame spans the sensor's diagonal: a frame cropped from the sensor (16:9 from "
                     f"4:3) has its focal length in pixels wrong by the crop; the {m.make} {m.model} is not in the "
                     f"sensor table ({SENSOR_TABLE.name}) and the EXIF has no FocalPlaneXResolution")
    return cam, notes


def image_files(files) -> list[Path]:
    """The image files of FILE arguments (a folder stands for its images)."""
    out = []
    for f in files:
        f = Path(f)
        if f.is_dir():
            found = sorted(p for p in f.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"{f}: no images ({', '.join(IMAGE_SUFFIXES)})")
            out += found
        else:
            out.append(f)
    seen = {}
    for p in out:
        if p.stem in seen and seen[p.stem] != p:
            raise InputError(f"{p}: two images share the id {p.stem!r} ({seen[p.stem]})")
        seen[p.stem] = p
    return list(seen.values())


def read(files, project: Project, options: ImportSettings) -> ImportedBlock:
    """The ``exif`` importer: GNSS positions (with RTK accuracies), the camera and the gimbal attitudes of
    image files or folders; frames of which none has a position give the camera alone."""
    paths = image_files(files)
    metas = [read_frame_metadata(p) for p in paths]
    block = ImportedBlock(source=[str(p) for p in paths])
    without = [m.path.name for m in metas if None in (m.lat_deg, m.lon_deg, m.alt_m)]
    if without and len(without) < len(metas):  # some with, some without: which frames is the user's to decide
        raise InputError(f"{metas[0].path.parent}: no GNSS position (EXIF GPS or DJI XMP) in {', '.join(without[:5])}"
                         + (f" and {len(without) - 5} more" if len(without) > 5 else "")
                         + f" of {len(metas)} frames; import the frames with positions, or none of them")
    # one camera: the first frame's; every frame must be of its size and calibration
    cam, notes = camera_from_metadata(metas[0])
    for m in metas[1:]:
        if (m.width, m.height) != (cam.width, cam.height) or m.dewarp != metas[0].dewarp or m.model != metas[0].model:
            raise InputError(f"{m.path}: another camera ({m.model} {m.width} x {m.height} px, calibration "
                             f"{'none' if m.dewarp is None else m.dewarp[:4]}) than {metas[0].path.name}; import "
                             f"each camera's frames into their own project")
    block.camera = cam
    block.notes += notes
    if without:  # a kite, balloon or old camera block: the camera alone (docs/blocks-without-gnss.md)
        block.notes.append(f"positions: none of the {len(metas)} frames has a GNSS position (EXIF GPS or DJI XMP): "
                           "the camera only; the block is oriented from its images and control points")
        return block
    crs = options.crs or DEFAULT_CRS
    lla = np.array([[m.lon_deg, m.lat_deg, m.alt_m] for m in metas])
    # a 2D --crs (EPSG:4326) names no height system: the altitudes are taken as ellipsoidal, as without --crs and as
    # before s21 (DJI states ellipsoidal heights for RTK fixes); a compound --crs names the geoid
    xyz = to_project_crs(lla, crs, project, f"{metas[0].path.parent} (positions, {crs})", ellipsoidal_2d=True)
    if options.crs is None:
        block.notes.append(f"positions: EXIF/XMP latitude, longitude and altitude taken as {DEFAULT_CRS} (WGS84, "
                           f"ellipsoidal heights); give --crs if the altitudes are above the geoid")
    ids = [m.path.stem for m in metas]
    if all(m.rtk_sigma_m is not None for m in metas):
        sigma = np.array([m.rtk_sigma_m for m in metas])
        flags = sorted({m.rtk_flag for m in metas if m.rtk_flag is not None})
        block.notes.append(f"positions: accuracies from DJI RtkStdLon/Lat/Hgt (RtkFlag {flags}; 50 = fixed)")
    elif options.sigma_xyz_m is not None:
        sigma = np.tile(np.asarray(options.sigma_xyz_m, float), (len(metas), 1))
    else:
        sigma = None
    if sigma is None and "gnss" not in project.config:
        # a consumer receiver: its model into project.toml, not the [gnss] defaults (a survey receiver's 0.05 / 0.1 m)
        block.gnss_section = consumer_gnss_section()
        sxy, sz, oxy, oz = CONSUMER_GNSS
        block.notes.append(f"positions: the EXIF states no accuracy (no DJI RTK): {project.config_path.name} [gnss] "
                           f"gets a consumer receiver's model, {sxy:g} / {sz:g} m between frames and one offset for "
                           f"the flight of {oxy:g} / {oz:g} m (plan / height) that the adjustment estimates where "
                           "control points or a DEM observe it; edit them for your receiver, or give --sigma-xyz-m "
                           "for positions of a stated accuracy")
    elif sigma is None and any(project.source_of("gnss", k) != "project.toml" for k in ("sigma_xy_m", "sigma_z_m")):
        g = project.gnss
        block.notes.append(f"positions: the EXIF states no accuracy (no DJI RTK): the adjustment takes [gnss] "
                           f"sigma_xy_m / sigma_z_m ({g.sigma_xy_m:g} / {g.sigma_z_m:g} m); for a consumer drone set "
                           f"them to {CONSUMER_GNSS[0]:g} / {CONSUMER_GNSS[1]:g} and offset_sigma_xy_m / "
                           f"offset_sigma_z_m to {CONSUMER_GNSS[2]:g} / {CONSUMER_GNSS[3]:g} (one offset of the "
                           "flight, metres), or give --sigma-xyz-m")
    if all(m.relative_alt_m is not None for m in metas):
        # the ground at the take-off point, in the project's heights: a terrain height for the frames' footprints
        takeoff_m = float(np.median(xyz[:, 2] - np.array([m.relative_alt_m for m in metas])))
        block.terrain_height_m = takeoff_m
        block.terrain_height_from = ("aerotri import --format exif: the ground at the take-off point, the frames' "
                                     "heights less their DJI RelativeAltitude")
        if project.source_of("flight", "mean_terrain_height_m") != "project.toml":
            block.notes.append(f"flight: the frames' heights above the take-off point (DJI RelativeAltitude) put the "
                               f"ground there at {takeoff_m:.1f} m: {project.config_path.name} gets [flight] "
                               f"mean_terrain_height_m = {takeoff_m:.1f}, with which aerotri match pairs the frames by "
                               "their footprints instead of matching thumbnails of every pair; edit it if the terrain "
                               "lies higher or lower than the take-off point")
    block.gnss = GnssPositions(ids, xyz, sigma)
    if all(m.gimbal_ypr_deg is not None for m in metas):
        from aerotri.geom.local_frame import LocalFrame

        opk = np.array([opk_from_gimbal(m.gimbal_ypr_deg, LocalFrame(project.crs, c).rotation_local_from_map(c[None])[0].T)
                        for m, c in zip(metas, xyz)])
        block.eo = ExteriorOrientations(ids, xyz.copy(), opk)
        block.notes.append("orientations: from the DJI gimbal yaw/pitch/roll (the drone's own estimate, typically "
                           "degrees off; approximations for the adjustment, not results)")
    return block
