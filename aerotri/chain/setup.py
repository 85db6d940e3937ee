"""``aerotri init``: a new project folder from a folder of frames (docs/project.md describes the folder).

What it makes, as one folder that appears whole or not at all (``aerotri.core.atomic.atomic_dir``):

- ``images/``: one symbolic link per frame to the frame's file (absolute path), or a copy with ``copy``;
- ``project.toml``: ``[project] name`` and ``crs`` (checked: a projected CRS in metres or feet) and
  ``heights``, the other sections commented out with what they take, and the settings given as
  ``section.key=value`` (``aerotri init --set``; checked as every command checks project.toml) as live sections;
- ``camera.toml``: the camera given (checked, and against the frames' size), else the one the first frame's
  EXIF states (``aerotri.exchange.exif``: DJI's factory calibration, else the nominal focal length and pixel
  size), with a comment saying where it came from; when the EXIF does not say enough, no camera.toml and
  a ``InitResult.camera_missing`` text telling what to write.

It never modifies the frames; the frames must all have one size (one camera).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from aerotri.core.atomic import atomic_dir, move_into, temporary_dir
from aerotri.core.errors import InputError, OptionError

if TYPE_CHECKING:  # geom.images imports OpenCV: the module loads it only to read frames
    from aerotri.geom.images import ImageFiles

PROJECT_TOML = """\
# Project settings (docs/project.md lists every section and key). Written by aerotri init.
[project]
name = "{name}"
crs = "{crs}"            # {crs_name}; gnss.txt, control and every product are in it
heights = "ellipsoidal"  # "ellipsoidal", or a vertical CRS such as "EPSG:3855" (EGM2008) when gnss.txt has such heights

# [gnss]                 # gnss.txt: image_id X Y Z [sX sY sZ], antenna positions in the project CRS
# sigma_xy_m = 0.05      # a-priori accuracy of positions without their own sX sY sZ (m)
# sigma_z_m = 0.1
# lever_arm_m = [0.0, 0.0, 0.0]   # antenna offset from the projection centre, camera frame (x right, y up, z up), m
# offset_sigma_xy_m = 3.0  # a consumer receiver (no RTK): one offset for the flight, a priori (m); not given: none
# offset_sigma_z_m = 5.0   # (sigma_xy_m, sigma_z_m are then between frames, e.g. 0.5; docs/real-blocks.md)

# [control]              # control/points.csv: id,kind,x,y,z,sx_m,sy_m,sz_m and control/image_points.csv
# sigma_xy_m = 0.10
# sigma_z_m = 0.10

# [flight]
# mean_terrain_height_m = 0.0     # the terrain's mean height (m, project heights): footprints of the frames
# speed_mps = 70.0

# [qa]                   # the limits the accuracy report checks against
# map_scale = "1:5000"
# terrain = "flat"
# pdf = true

# Stage sections, each with the keys of its stage's settings (docs/project.md): [strips] [classify]
# [rasters] [corners] [vectors] [match] [adjust] [control] [rectify] [mosaic], e.g.
# [adjust]
# self_calibration = ["pp", "radial"]
# gnss_correction = "shift"
# [rectify]
# dem = "dem.tif"        # a DEM when the project has no LiDAR (relative names: to this folder)
"""

CAMERA_TEMPLATE = """\
# Frame camera interior orientation (docs/project.md#cameratoml). Pixel origin: centre of the top-left
# pixel, x right, y down. Principal point offset from the image centre in photo coordinates (x right, y up).
name = "my camera"
model = "brown"      # brown (radial k1 k2 k3, tangential p1 p2) or pinhole
focal_mm = ...       # calibrated focal length, mm
pixel_um = ...       # pixel size on the sensor, micrometres (sensor width mm * 1000 / width px)
width = {width}        # image size in pixels (of the files in images/)
height = {height}
ppx_mm = 0.0
ppy_mm = 0.0
k1 = 0.0
k2 = 0.0
k3 = 0.0
p1 = 0.0
p2 = 0.0
"""


@dataclasses.dataclass(frozen=True)
class InitResult:
    """What ``init_project`` made."""

    root: Path
    frames: int
    linked: bool  # symbolic links (else copies)
    camera_source: str | None  # where camera.toml came from; None: not written
    camera_missing: str | None  # what to write into camera.toml when it was not written
    notes: tuple[str, ...] = ()
    exif_gnss: bool = False  # the first frame's EXIF/XMP carries a GNSS position (aerotri import --format exif)


def _exif_gnss(path: Path) -> bool:
    from aerotri.exchange.exif import read_frame_metadata

    try:
        m = read_frame_metadata(path)
    except InputError:
        return False
    return None not in (m.lat_deg, m.lon_deg, m.alt_m)


def _frames(images_dir: Path) -> ImageFiles:
    from aerotri.geom.images import find_images

    if not images_dir.is_dir():
        raise OptionError(f"{images_dir}: not a folder of frames", param="--images")
    return find_images(images_dir)


def _sizes(frames: ImageFiles) -> dict[tuple[int, int], list[str]]:
    """Image size (width, height) -> the ids of the frames of that size (from the file headers); a frame cut short
    stops here, named (its camera and GNSS tags may be what is missing)."""
    import rasterio

    from aerotri.geom.images import check_not_truncated

    out: dict[tuple[int, int], list[str]] = {}
    for image_id, path in frames.pairs():
        if not path.is_file():
            raise InputError(f"{path}: not a file (image {image_id!r}); expected a TIFF/JPEG/PNG frame")
        try:
            with rasterio.open(path) as ds:
                size = (ds.width, ds.height)
                dtype, crs = ds.dtypes[0], ds.crs
                check_not_truncated(ds, path)
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"{path}: cannot read the image ({exc})") from None
        if dtype.startswith("float"):  # (new-user trial: ODM's DSM folder linked as a block of 1 frame)
            georef = ", georeferenced" + (f" in EPSG:{crs.to_epsg()}" if crs.to_epsg() else "") if crs else ""
            raise InputError(f"{path}: a {dtype} raster{georef}: heights or other map data, not a camera frame "
                             "(frames hold 8- or 16-bit values); --images takes the folder of the aerial frames")
        out.setdefault(size, []).append(image_id)
    return out


def _camera_text(frames: ImageFiles, size: tuple[int, int], camera_path: Path | None):
    """(camera.toml text or None, source or None, what to do when None, notes)."""
    from aerotri.geom.camera import read_camera

    if camera_path is not None:
        cam = read_camera(camera_path)
        if (cam.width, cam.height) != size:
            raise InputError(f"{camera_path}: a camera of {cam.width} x {cam.height} px, but the frames are "
                             f"{size[0]} x {size[1]} px")
        return Path(camera_path).read_text(encoding="utf-8"), str(camera_path), None, []
    from aerotri.exchange.exif import camera_from_metadata, read_frame_metadata

    first = frames.path[0]
    try:
        cam, notes = camera_from_metadata(read_frame_metadata(first))
    except InputError as exc:
        # the EXIF reader's own "write camera.toml yourself" would say it twice
        reason = str(exc).removesuffix("; write camera.toml yourself")
        hint = (f"no camera from the EXIF of {first.name} ({reason}); write camera.toml with the calibrated camera "
                f"(docs/project.md#cameratoml), or let aerotri import bring it with the orientations "
                f"(--format orthority|patb|colmap|opensfm|metashape; docs/exchange.md):\n"
                + CAMERA_TEMPLATE.format(width=size[0], height=size[1]))
        return None, None, hint, []
    header = (f"# From the EXIF of {first.name} (aerotri init): a nominal or factory camera, not a calibration.\n"
              + "".join(f"# {n}\n" for n in notes))
    return header + cam.to_toml(), f"EXIF of {first.name}", None, list(notes)


def init_project(root, images_dir, crs: str, camera_path=None, copy: bool = False, name: str | None = None,
                 settings: tuple[str, ...] = ()) -> InitResult:
    """Make the project folder ``root`` (module docstring); ``root`` must not exist or be an empty folder.
    ``settings``: ``section.key=value`` items for project.toml (``aerotri.chain.set_settings``). Returns what was
    made."""
    from aerotri.geom.crs.definition import crs_label
    from aerotri.geom.eo import check_block_crs

    from aerotri.core.lock import LOCK_NAME

    root, images_dir = Path(root), Path(images_dir)
    # the command's own lock in an existing empty folder is no content (trial-paths: `aerotri init .` and init into an
    # empty folder were always refused, the lock made before the check)
    if root.exists() and (not root.is_dir() or any(p.name != LOCK_NAME for p in root.iterdir())):
        raise OptionError(f"{root}: exists and is not an empty folder; aerotri init makes a new project "
                          "(choose a new folder name)", param="PROJECT")
    c = check_block_crs(crs, "--crs")
    from aerotri.chain.set_settings import checked_settings

    changes = checked_settings(settings, root)
    frames = _frames(images_dir)
    if _inside(root, images_dir):
        raise OptionError(f"{root}: inside the frames' folder {images_dir}; put the project elsewhere", param="PROJECT")
    sizes = _sizes(frames)
    if len(sizes) > 1:
        parts = "; ".join(f"{w} x {h} px: {', '.join(ids[:3])}{' ...' if len(ids) > 3 else ''}"
                          for (w, h), ids in sorted(sizes.items(), key=lambda kv: -len(kv[1])))
        raise InputError(f"{images_dir}: frames of {len(sizes)} sizes ({parts}); one project holds the frames of "
                         "one camera")
    size = next(iter(sizes))
    camera_text, camera_source, camera_missing, notes = _camera_text(frames, size, camera_path)
    name = name or root.resolve().name  # (`aerotri init .`: the folder's own name, not "")
    # a CRS given as a PROJ string has no name ("unknown"): its projection and datum instead
    crs_name = c.name if c.name not in ("", "unknown") else crs_label(c)
    # a .wkt/.prj named here (read from the current folder) goes into the project, whose commands read project.toml's
    # file names in the project folder (review 47: `--crs grid.prj` made a project every command refused)
    from aerotri.core.crs_files import is_crs_file

    crs_file = Path(str(crs).strip()).expanduser() if is_crs_file(str(crs)) else None
    toml = project_toml(name, crs_file.name if crs_file else crs, crs_name, changes)
    with _project_folder(root) as tmp:
        if crs_file is not None:
            shutil.copyfile(crs_file, tmp / crs_file.name)
        (tmp / "images").mkdir()
        for path in frames.path:
            dst = tmp / "images" / path.name
            if copy:
                shutil.copy2(path, dst)
            else:
                os.symlink(path.resolve(), dst)
        (tmp / "project.toml").write_text(toml, encoding="utf-8")
        if camera_text is not None:
            (tmp / "camera.toml").write_text(camera_text, encoding="utf-8")
    return InitResult(root, len(frames), not copy, camera_source, camera_missing, tuple(notes),
                      _exif_gnss(frames.path[0]))


def project_toml(name: str, crs: str, crs_name: str, changes=()) -> str:
    """project.toml's text: the template with ``[project]`` filled in and the ``--set`` ``changes``
    (``aerotri.chain.set_settings.checked_settings``) written in."""
    from aerotri.chain.set_settings import with_settings

    text = PROJECT_TOML.format(name=name.replace('"', "'"), crs=crs, crs_name=crs_name)
    return with_settings(text, changes, "--set") if changes else text


@contextlib.contextmanager
def _project_folder(root: Path):
    """A temporary folder whose content becomes the project folder ``root`` when the block succeeds: it replaces a
    new ``root`` whole (``atomic_dir``); into an existing empty one (the command's lock in it) its entries move one by
    one under the command's commit, which covers that folder (replacing the folder itself is no change inside it)."""
    if not root.is_dir():
        with atomic_dir(root) as tmp:
            yield tmp
        return
    tmp = temporary_dir(root, "init")
    try:
        yield tmp
        for entry in sorted(tmp.iterdir()):
            move_into(entry, root / entry.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
        return True
    except ValueError:
        return False
