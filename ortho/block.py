"""Project-level orthorectification: every frame of a block onto one common, snapped output grid.

Inputs (architecture doc): ``camera.toml`` (or ``--camera``), the adjusted EO ``at/eo.txt`` (or
``--eo``, e.g. ``truth/eo.txt``), ``images/<image_id>.tif`` and the DEM ``lidar_out/dem.tif`` (or
``--dem``), all in the project CRS. Outputs in ``ortho/frames/``: ``<image_id>.tif`` (tiled GeoTIFF
with an internal validity mask; occluded pixels are masked in a true ortho) and ``index.json`` (grid,
projection centre and nadir point of each frame, for the mosaic, and the size and sha1 of its file;
``inputs``: the sha256 of the EO file, the camera and the DEM it was made from, so that ``ortho
mosaic``, ``ortho check`` and the QA report refuse frames of an older adjustment, ``stale_frames``).

All frames or none: a run writes into a temporary folder next to ``ortho/frames`` that replaces it only
when every frame and the index are written, so a failed run leaves the previous complete output; a
``--frames`` subset re-run brings the other frames of a compatible earlier run along (hard links).
Consumers check the frame files against the index (``verify_index``) and never mix runs.

Every frame is one Dask task (``_rectify_frame_task`` on a small ``FrameTask``) through
``aerotri.core.executor.Executor``: local threads by default, ``--scheduler local:N`` or a cluster address
to scale out; each task writes its own GeoTIFF atomically and returns its index entry, so the
outputs are byte-identical whichever scheduler runs them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import rasterio
from pyproj import CRS

from aerotri.geom.eo import ExteriorOrientations, read_eo
from aerotri.core.digest import file_sha256
from aerotri.core.errors import InputError
from aerotri.core.log import counted
from aerotri.core.project import Project
from aerotri.core.records import to_record
from aerotri.core.settings import Resolved, settings_of
from aerotri.geom.local_frame import FramesOnEarth
from aerotri.geom.rotation import rotation_matrix_opk
from aerotri.core.atomic import atomic_dir, atomic_path, remove_leftovers, scratch_dir, write_text_atomic
from aerotri.core.resume import ResumeFolder, file_stamp, resumable, resume_key
from aerotri.core.resume import link_or_copy as _link_or_copy
from aerotri.core.errors import OptionError
from aerotri.core.limits import check_allocation, check_grid, usable_cores
from aerotri.core.textio import read_json
from aerotri.geom.crs.definition import linear_unit_m, parse_heights
from aerotri.geom.crs.datum import load_height_model, load_transformation
from aerotri.geom.crs.transform import CrsTransformer, OperationSpec
from ortho.dem import (dem_height_operation, height_range, height_window, open_height_raster, read_height_window,
                       warn_zero_fill)
from aerotri.core.gdal_cache import MiB, stage_block_cache
from ortho.grid import GridToProject, OrthoGrid, nice_resolution, overview_factors, parse_crs, resolve_output_crs
from ortho.rectify import (GROUND_NDSM_M, WINDOWED_FRAME_BYTES, FrameFile, border_pixels, frame_coverage,
                           footprint_polygon_xy, black_corners, declares_nodata, frame_validity, grid_around_footprint,
                           ground_flags, heights_on_grid, rectify_frame)
from ortho.settings import FRAME_COMPRESSION, RectifySettings

# the camera and image readers (aerotri.geom.camera compiles its lens model with numba: 0.3 CPU-s to import)
# are imported by the functions that need them: ``ortho mosaic`` and ``ortho check`` read the index here
if TYPE_CHECKING:
    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.images import ImageFiles
    from ortho.dem import HeightRaster
    from ortho.footprints import FootprintOccluder, OutlineHeights

_log = logging.getLogger(__name__)

# GDAL's block cache during rectify (``aerotri.core.gdal_cache``): the frame blocks the tiles of the frames in
# flight read (a 13,824 px DMC frame read by windows) and the output blocks being compressed; bounded so that
# memory does not grow with the frame
RECTIFY_CACHE_BYTES = 256 * MiB



@contextlib.contextmanager
def _raster_read(path, what: str):
    """Read errors of a height raster (truncated or corrupt data) as an InputError naming it."""
    try:
        yield
    except (rasterio.errors.RasterioIOError, rasterio.errors.WarpOperationError) as exc:
        raise InputError(f"{path}: cannot read the {what} (truncated or corrupt? {exc})") from None


@dataclasses.dataclass
class BlockInputs:
    project: Project
    camera: BrownCamera
    eo: ExteriorOrientations
    eo_path: Path
    images: ImageFiles  # only the frames that will be rectified
    camera_path: Path | None = None  # a camera file given instead of the project's (``--camera``)
    eo_given: bool = False  # ``eo_path`` was given (``--eo``) rather than the project's at/eo.txt

    @property
    def project_crs(self) -> CRS:
        return parse_crs(self.project.crs, f"{self.project.root / 'project.toml'}: [project] crs")


def _check_given_kappa(project, camera, eo, eo_path, frames) -> None:
    """Orientations given with ``--eo`` (another program's, imported/eo.txt) are rectified as they are: a frame whose
    kappa the project's tie points say is off by more than ``KAPPA_LIMIT_DEG`` (180 deg, gon read as degrees) is
    refused by name (``aerotri.geom.eo_check``); before, it was rectified turned about its nadir, unsaid."""
    from aerotri.geom.eo_check import check_kappa, ground_guess_m
    from aerotri.geom.observations import read_image_points

    try:
        ties = read_image_points(project.tiepoints_path)
    except InputError as exc:  # the tie points are no input of the rectification: their check is left out
        _log.info(f"--eo: kappa not checked against the tie points ({exc})")
        return
    check_kappa(eo, camera, ties, ground_guess_m(eo, camera, project.flight.mean_terrain_height_m), str(eo_path),
                frames=frames)


def load_block(root, eo_path=None, camera_path=None, frames=None) -> BlockInputs:
    """Open a project and check that every selected image has an EO (InputError naming what is missing)."""
    from aerotri.geom.camera import orientations_camera
    from aerotri.geom.images import check_frames, find_images

    project = Project.open(root)
    camera, camera_source = orientations_camera(project, eo_path, camera_path)
    eo_given = eo_path is not None
    eo_path = Path(eo_path) if eo_path else project.eo_path
    if not eo_path.exists():
        truth = project.truth_dir / "eo.txt"
        # the simulator's truth only where there is one (docs trial s98 L5: a real block was pointed to truth/)
        raise InputError(f"{eo_path}: exterior orientation not found (run the aerotri adjustment, or pass --eo FILE"
                         + (f", e.g. --eo {truth})" if truth.is_file() else ")"))
    from aerotri.geom.eo import check_block_crs

    # the projection centres checked against the project CRS (another zone's numbers, swapped X/Y)
    eo = read_eo(eo_path, check_block_crs(project.crs, f"{project.config_path} [project] crs"))
    if eo_given:  # (an adjustment's own at/eo.txt is in degrees; an import or another program's may not be)
        from aerotri.geom.eo_check import radians_read_as_degrees

        why = radians_read_as_degrees(eo)
        if why:
            _log.warning(f"{eo_path}: {why}")
    images = find_images(project.images_dir)
    oriented = set(eo.image_id)
    if frames:
        twice = sorted({f for f in frames if frames.count(f) > 1})
        if twice:
            raise OptionError(f"frame(s) {', '.join(twice)} given twice", param="--frames")
        unknown = [f for f in frames if f not in images]
        if unknown:
            raise InputError(f"{project.images_dir}: no image for frame(s) {', '.join(unknown)} given with --frames")
        images = images.select(frames)
    missing = [k for k in images.image_id if k not in oriented]
    if missing and not eo_given and not frames:
        # frames the adjustment left out (a part of the block without a datum) are not rectified
        left = _left_out_by_adjustment(project)
        skipped = [k for k in missing if k in left]
        if skipped:
            _log.warning(f"{counted(len(skipped), 'frame')} the adjustment left out "
                         f"{'is' if len(skipped) == 1 else 'are'} not rectified ({', '.join(skipped[:8])}"
                         f"{' ...' if len(skipped) > 8 else ''}): {left[skipped[0]]}")
            images = images.select([k for k in images.image_id if k not in left])
            missing = [k for k in missing if k not in left]
    if missing:
        raise InputError(f"{eo_path}: no exterior orientation for frame(s) {', '.join(missing[:10])}"
                         f"{' ...' if len(missing) > 10 else ''} (images in {project.images_dir})")
    if not frames:
        # every oriented frame is rectified: one without its image is an error, never a silent gap in the mosaic
        no_image = [k for k in eo.image_id if k not in images]
        if no_image:
            raise InputError(f"{project.images_dir}: no image file of frame(s) {', '.join(no_image[:10])}"
                             f"{' ...' if len(no_image) > 10 else ''} not found (oriented in {eo_path}); restore it, "
                             "or rectify the others with --frames")
    check_frames(images, camera, camera_source)
    if eo_given and project.tiepoints_path.is_file():
        _check_given_kappa(project, camera, eo, eo_path, set(images.image_id))
    return BlockInputs(project, camera, eo, eo_path, images, camera_path=Path(camera_path) if camera_path else None,
                       eo_given=eo_given)


def _left_out_by_adjustment(project: Project) -> dict:
    """Frame id -> reason, for the frames the project's adjustment left out (``at/report.json``
    components.left_out): parts of the block that no tie point connects and that have no datum, and frames with
    no measurement or fewer than 3."""
    path = project.adjustment_report_path
    if not path.is_file():
        return {}
    comp = read_json(path).get("components") or {}
    return {k: lo.get("reason", "") for lo in comp.get("left_out", []) for k in lo.get("images", [])}


def default_resolution(camera: BrownCamera, eo: ExteriorOrientations, ground_height_m, dem_path=None) -> float:
    """The median nadir GSD of the block (ground heights under the nadir points), rounded to a nice value;
    ``dem_path``: the DEM the heights are of, named when the centres lie below it."""
    agl = float(np.median(eo.centre_m[:, 2] - ground_height_m))
    if agl <= 0:
        # (trial s99 lidmut M4: a DEM in feet read as metres was "projection centres are below the DEM", no file)
        raise InputError(f"{dem_path or 'the DEM'}: the projection centres lie below it (median height above ground "
                         f"{agl:.1f} m, DEM {float(np.nanmedian(ground_height_m)):.1f} under the nadir points, centres "
                         f"{float(np.median(eo.centre_m[:, 2])):.1f}): heights in another unit (feet as metres?) or "
                         "another height system than the orientations'?")
    return nice_resolution(camera.gsd_m(float(agl)))


# FRAME_COMPRESSION (ortho.settings): the per-frame GeoTIFF profiles, measured there


def frame_profile(grid: OrthoGrid, bands: int, dtype: str, block_px: int = 512, compression: str = "zstd") -> dict:
    """Per-frame ortho GeoTIFF: tiled 512 px, band interleaved (the tiles arrive as band planes, and
    ZSTD packs single-band blocks about 30 % smaller than pixel-interleaved ones at the same CPU),
    ``FRAME_COMPRESSION[compression]``; GDAL compresses blocks on all cores while the next tiles are
    computed (not with extra samples: ``without_threads_for_extra_samples``). Three bands or more are R, G, B (the
    frames' band order) and the rest unspecified: GDAL's default
    marked a 4th 8-bit band alpha (a DMC's NIR taken as transparency by QGIS and GDAL's tools, in the frames and
    the mosaic, which takes their colours) and 16-bit RGB grey."""
    if compression not in FRAME_COMPRESSION:
        raise InputError(f"unknown frame compression {compression!r}; expected one of {sorted(FRAME_COMPRESSION)}")
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=bands, dtype=dtype, crs=grid.crs,
                   transform=grid.transform, tiled=True, blockxsize=block_px, blockysize=block_px,
                   num_threads="ALL_CPUS", interleave="band", BIGTIFF="IF_SAFER", **FRAME_COMPRESSION[compression])
    if bands >= 3:
        profile.update(photometric="RGB")
    profile = without_threads_for_extra_samples(profile, bands, 3 if bands >= 3 else 1)
    if grid.width < block_px or grid.height < block_px:
        profile.update(tiled=False)
        profile.pop("blockxsize")
        profile.pop("blockysize")
    return profile


def without_threads_for_extra_samples(profile: dict, bands: int, colour_bands: int) -> dict:
    """``profile`` (a GeoTIFF with an internal mask) without GDAL's compression threads (``num_threads``) when the
    file has extra samples (more ``bands`` than its photometric's ``colour_bands``: 1 grey, 3 RGB). GDAL 3.10's
    compression threads copy a file's ExtraSamples into its one-sample mask's blocks and print "ERROR 1: ... Bad value
    N for "ExtraSamples" tag" on a file that is right all the same: 1-2 lines per 4-band NGI frame ortho of 7820 x
    13988 px (0 without the threads, its write 2.74-2.80 s wall against 2.40-2.67 s), 22-27 per 292 MP RGB mosaic
    made grey and then RGB at a 1.5 GiB limit (``ortho.mosaic``)."""
    if bands > colour_bands:
        return {k: v for k, v in profile.items() if k != "num_threads"}
    return profile


def write_frame_ortho(path, ortho: np.ndarray, mask: np.ndarray, grid: OrthoGrid) -> None:
    """A whole frame ortho with its internal validity mask, written atomically."""
    a = ortho if ortho.ndim == 3 else ortho[:, :, None]
    with atomic_path(path) as tmp, rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(tmp, "w", **frame_profile(grid, a.shape[2], a.dtype.name)) as dst:
            dst.write(np.moveaxis(a, -1, 0))
            dst.write_mask(mask)


def operation_tags(operation: dict | None, height_operation: dict | None = None) -> dict:
    """GeoTIFF metadata naming the coordinate operations a product went through (empty for none)."""
    tags = {}
    if operation is not None:
        tags["COORDINATE_OPERATION"] = operation["description"]
        tags["COORDINATE_OPERATION_JSON"] = json.dumps(operation)
    if height_operation is not None:
        tags["HEIGHT_OPERATION_JSON"] = json.dumps(height_operation)
    return tags


def add_overviews(path) -> None:
    """Internal overviews (``overview_factors``, average of the valid samples) of a frame ortho GeoTIFF and of its
    internal mask, compressed as the full resolution; the full-resolution samples are left as they are."""
    from rasterio.enums import Resampling

    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(path, "r+") as ds:
        factors = overview_factors(ds.width, ds.height)
        if factors:
            ds.build_overviews(factors, Resampling.average)


def rectify_frame_to_file(path, image, band_order, camera, C, R, *, heights, grid, interpolation, to_project,
                          occlusion_dsm=None, compression: str = "zstd", threads: int | None = None,
                          tags: dict | None = None, max_view_angle_deg: float = 90.0, occluder=None,
                          sides=None, overviews: bool = False, source_valid=None, ground=None) -> float:
    """Rectify tile by tile straight into a GeoTIFF (the frame ortho is never whole in memory); ``occluder``,
    ``sides``, ``source_valid``, ``ground``: as ``rectify_frame``; ``overviews``: internal overviews too
    (``add_overviews``). Returns the valid fraction of the grid.

    The tiles go into an uncompressed scratch GeoTIFF in a folder beside ``path`` (``scratch_dir``: swept with
    ``path``'s temporaries after a kill; the tile threads compute the next tiles while this thread writes), which
    is then copied into the frame ortho block by block in file order
    (``ordered_copy``): GDAL places a block in the file when its block cache flushes it, and the cache is the
    process's, shared with the other frames' tasks, so a file written straight from the tiles had its blocks in an
    order that changed from run to run (the same samples, other bytes and checksums).
    """
    from rasterio.windows import Window

    bands = 1 if image.ndim == 2 else image.shape[2]
    profile = frame_profile(grid, bands, image.dtype.name, compression=compression)
    path = Path(path)
    # GDAL's block cache is the stage's (``rectify_block``, ``aerotri.core.gdal_cache``): never set here, in a task
    # that runs on a worker thread beside other frames' tasks
    with atomic_path(path) as tmp, scratch_dir(path.parent, path.name) as scratch, \
            rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        raw = scratch / "raw.tif"
        with rasterio.open(raw, "w", **uncompressed(profile)) as dst:
            if tags:
                dst.update_tags(**tags)
            valid = [0]

            def sink(r0, c0, o, m):
                w = Window(c0, r0, m.shape[1], m.shape[0])
                dst.write(o, window=w, indexes=band_order)
                dst.write_mask(m, window=w)
                valid[0] += int(np.count_nonzero(m))

            rectify_frame(image, camera, C, R, heights, grid, interpolation=interpolation, to_project=to_project,
                          occlusion_dsm=occlusion_dsm, sink=sink, sink_bands_first=True, threads=threads,
                          max_view_angle_deg=max_view_angle_deg, occluder=occluder, sides=sides,
                          source_valid=source_valid, ground=ground)
        if overviews:
            add_overviews(raw)
        ordered_copy(raw, tmp, profile)
    return valid[0] / float(grid.width * grid.height)


# the creation options that are no compression: the rest of a frame profile
_UNCOMPRESSED_DROP = ("compress", "predictor", "zstd_level", "zlevel", "jpeg_quality", "num_threads", "max_z_error")


def uncompressed(profile: dict) -> dict:
    """``profile`` without compression (a scratch file or stage: written once, read once)."""
    return {k: v for k, v in profile.items() if k.lower() not in _UNCOMPRESSED_DROP}


def ordered_copy(src, dst, profile: dict) -> None:
    """Copy the GeoTIFF ``src`` (with its internal mask, overviews and tags) into ``dst`` with ``profile``'s creation
    options, every block written in file order (GDAL's ``COPY_SRC_OVERVIEWS``, the cloud-optimised layout: the
    bytes depend on the samples only, not on when a block cache flushed them)."""
    import rasterio.shutil

    skip = ("driver", "width", "height", "count", "dtype", "crs", "transform", "nodata")
    options = {k: v for k, v in profile.items() if k not in skip}
    rasterio.shutil.copy(src, dst, driver="GTiff", COPY_SRC_OVERVIEWS="YES", **options)


RESUME_DIR_NAME = "rectify_resume"  # in work/: the frames a killed or failed rectify finished (``FrameTask``)


@dataclasses.dataclass(frozen=True)
class FrameTask:
    """Everything one frame's rectification needs, small and picklable (paths and numbers), so that it
    runs as a Dask task on any worker that sees the project folder."""

    image_id: str
    image_path: str
    out_path: str
    camera: BrownCamera
    centre_m: tuple
    opk_deg: tuple
    dem_path: str
    project_crs_wkt: str
    output_crs_wkt: str
    res_m: float
    z_range_m: tuple
    interpolation: str = "bilinear"
    dsm_path: str | None = None  # true ortho: rectify on the DSM and mask what it occludes
    compression: str = "zstd"
    threads: int | None = None  # tile threads (None: all cores of the worker)
    operation: OperationSpec | None = None  # project -> output CRS (None: the project CRS itself)
    height_operation: OperationSpec | None = None  # DEM heights -> the project's height system
    max_view_angle_deg: float = 90.0  # cells seen more obliquely than this from the vertical are nodata
    footprints_path: str | None = None  # true ortho: building footprints (walls) in the occlusion test
    # the ground bounds of all the block's frames (project CRS): the footprints' occluder is built once over them and
    # shared by the frames' tasks in a process (``_frame_occluder``); None: built per frame
    occluder_bounds_m: tuple | None = None
    crown_base_path: str | None = None  # true ortho: tree crown bases on the DSM's grid in the occlusion test
    crowns_path: str | None = None  # true ortho: tree crowns fitted to their returns (disks) in the occlusion test
    # true ortho: the DSM of the occlusion test (footprints and crown bases on its grid) when it is not ``dsm_path``,
    # whose heights the ortho is rectified on (e.g. lidar_out/dsm_nearest.tif beside dsm.tif)
    occlusion_dsm_path: str | None = None
    # per-frame resume: the finished frame ortho and its index entry are kept in ``resume_dir`` under ``resume_key``
    # (``_resume_key``: everything the frame ortho depends on) until the stage commits, so that a run killed at
    # frame 2,900 of 3,000 redoes 100 frames, not 3,000
    resume_dir: str | None = None
    resume_key: str | None = None
    overviews: bool = False  # internal overviews in the frame ortho ([rectify] overviews)
    # true ortho: each height raster's heights -> the project's height system, from its own vertical CRS (a DSM in
    # feet beside a DEM in metres); None: its heights are the project's
    dsm_height_operation: OperationSpec | None = None
    occlusion_height_operation: OperationSpec | None = None
    crown_base_height_operation: OperationSpec | None = None
    # the frame declares invalid pixels (a nodata value, mask or alpha: ``ortho.rectify.declares_nodata``), left out of
    # its ortho since the ortho trial of 2026-12-01 (before, its collar was rectified as picture)
    frame_nodata: bool = False


# FrameTask fields left out of the resume key while None (the key of a frame kept by code without them)
_KEY_FIELDS_IF_SET = ("overviews", "dsm_height_operation", "occlusion_height_operation",
                      "crown_base_height_operation", "frame_nodata")


def _frame_image(path, expect_size):
    """The frame and the band (1-based, R, G, B order) of each of its channels: decoded or mapped in memory
    (``read_native``), or, decoded larger than ``WINDOWED_FRAME_BYTES``, a ``FrameFile`` the tiles read by
    windows (a full-size DMC frame: memory set by the tiles, not by its 637 MB)."""
    from aerotri.geom.images import read_native

    with rasterio.open(path) as ds:
        decoded = ds.width * ds.height * ds.count * np.dtype(ds.dtypes[0]).itemsize
        size = (ds.width, ds.height)
    if decoded > WINDOWED_FRAME_BYTES and size == tuple(expect_size):
        frame = FrameFile(path)
        return frame, frame.band_order
    return read_native(path, expect_size)


class FrameMessages(list):
    """What a frame's task has to tell the user, (level name, text) in the order said: handed back in its index
    entry (``messages``) and logged by ``_rectify_into`` frame by frame in the block's order, each frame's as soon
    as it and every frame before it are made, whichever scheduler ran them (the threads' logging came in the order
    they finished; a distributed worker's never reached the console), and again for a frame a resumed run takes
    over."""

    def warning(self, text: str) -> None:
        self.append(("warning", text))

    def info(self, text: str) -> None:
        self.append(("info", text))


class _SaidInOrder:
    """Logs the ``messages`` (``FrameMessages``) of index entries handed over in any order (``take(k, entry)``), in
    the order of k = 0, 1, ...: an entry's as soon as every entry before it has come; taken out of the entries."""

    def __init__(self):
        self._waiting: dict[int, dict] = {}
        self._next = 0

    def take(self, k: int, entry: dict) -> None:
        self._waiting[k] = entry
        while self._next in self._waiting:
            for level, text in self._waiting.pop(self._next).pop("messages", ()):
                getattr(_log, level)(text)
            self._next += 1


def _require_coverage(task: FrameTask, C, R, heights, *, what: str, path, extent, crs,
                      said: FrameMessages) -> float:
    """Share of the frame whose ground the height raster covers (``frame_coverage``): a warning (into ``said``)
    naming the frame and the share left as nodata when it is partial, split into what lies beyond the raster's
    extent and what falls on its nodata cells (Tuniu on ODM's DSM: the warning named the extent alone, while 9.8 %
    of the DSM is nodata inside it); an InputError naming the raster's extent when it covers none."""
    cover = frame_coverage(task.camera, C, R, heights, crs=crs, extent=extent)
    share = cover.covered
    b = extent
    where = f"its extent: X {b[0]:.1f} .. {b[2]:.1f}, Y {b[1]:.1f} .. {b[3]:.1f} in the project CRS"
    if share == 0.0:
        raise InputError(f"{path}: the {what} covers none of frame {task.image_id} ({where}); give a {what} that "
                         f"covers the frame, or leave it out with --frames")
    if share < 1.0:
        parts = [f"{100 * v:.1f} % {t}" for v, t in ((cover.beyond, "beyond its extent"),
                                                      (cover.on_nodata, "on its nodata cells inside it"))
                 if round(100 * v, 1) > 0]
        said.warning(f"frame {task.image_id}: the {what} {path} covers {100 * share:.1f} % of it ({where}); "
                     f"the other {100 * (1 - share):.1f} % ({', '.join(parts) or 'at its edge'}) is nodata in its "
                     "ortho")
    return share


# true ortho with footprints: each cell's height from its own side of the roof outlines (``ortho.footprints.
# outline_heights``: beyond every outline the ground's, within one the roof's), not the DSM's bilinear height part
# way up a wall beside it (docs/true-ortho.md, "Heights from the cell's own side of the roof outline")
HEIGHTS_BY_OUTLINE = True
# ... and with an occlusion test on a surface of its own (the chain's dsm_nearest.tif beside dsm.tif), the outlines
# the heights are taken by are the occluder's: their eave widths from that surface's roof cells, not from the
# heights DSM's (the highest return per cell: roofs wider by up to a cell, so ground beyond the occluder's outline
# was imaged at the roof's height); docs/true-ortho.md, "One roof outline for the heights and the occlusion test"
OUTLINES_OF_THE_OCCLUSION_TEST = True
SHARED_FOOTPRINT_CELLS_MAX = 40_000_000  # a larger window of the block's frames: the footprints rasterised per frame
# (10 bytes a cell kept: 400 MB)
_shared_cells: dict = {}  # the last block's footprints on the DSM grid (key, value); one per process
_shared_cells_lock = threading.Lock()


def _block_footprint_cells(task: FrameTask, project_crs):
    """(x, y of the top-left corner of the DSM window, its cell size, ``FootprintCells`` of the window) over
    ``task.occluder_bounds_m``, rasterised by the first frame's task in a process and kept for the others (the demo:
    0.16 CPU-s once a block, against 0.06 a frame); cells None when the window exceeds
    ``SHARED_FOOTPRINT_CELLS_MAX``."""
    from ortho.footprints import footprint_cells, read_footprints

    occlusion_path = task.occlusion_dsm_path or task.dsm_path
    key = (occlusion_path, task.footprints_path, task.occluder_bounds_m, task.project_crs_wkt,
           *((st.st_size, st.st_mtime_ns) for st in (os.stat(occlusion_path), os.stat(task.footprints_path))))
    with _shared_cells_lock:
        if _shared_cells.get("key") != key:
            with open_height_raster(occlusion_path, project_crs, "DSM") as dsm_ds:
                win = height_window(dsm_ds, task.occluder_bounds_m, margin_m=4 * dsm_ds.transform.a, what="DSM")
                t = dsm_ds.transform
            # the corner as read_height_window puts it
            x_left, y_top = t.c + win.col_off * t.a, t.f + win.row_off * t.e
            cells = None
            if win.width * win.height <= SHARED_FOOTPRINT_CELLS_MAX:
                cells = footprint_cells(x_left, y_top, t.a, (win.height, win.width),
                                        read_footprints(task.footprints_path, project_crs))
            _shared_cells.clear()
            _shared_cells.update(key=key, value=(x_left, y_top, t.a, cells))
        return _shared_cells["value"]


def _frame_occluder(task: FrameTask, surface: HeightRaster, dem: HeightRaster, project_crs,
                    crown_base_m: np.ndarray | None = None,
                    heights: HeightRaster | None = None) -> tuple[FootprintOccluder, OutlineHeights | None]:
    """The footprints' occluder of the frame's DSM window ``surface`` (of the occlusion test; ground: its DEM window
    ``dem`` at the cells), its footprint cells cut from the block's (``_block_footprint_cells``) where that window lies
    inside the block's, else rasterised for the frame: the same occluder either way; and with ``heights`` (the DSM
    window the cells' heights are read from) its ``OutlineHeights`` (``HEIGHTS_BY_OUTLINE``; else None)."""
    from ortho.footprints import footprint_cells, occluder_of_cells, outline_heights, read_footprints, roof_candidates

    def cells_of(window: HeightRaster):
        h, w = window.heights_m.shape
        ground = heights_on_grid(dem, OrthoGrid(project_crs, window.x_left_m, window.y_top_m, window.res_m, w, h))
        shared = _block_footprint_cells(task, project_crs) if task.occluder_bounds_m is not None else None
        if shared is not None and shared[3] is not None and shared[2] == window.res_m:
            x_left, y_top, res, cells = shared
            r0 = int(round((y_top - window.y_top_m) / res))
            c0 = int(round((window.x_left_m - x_left) / res))
            if r0 >= 0 and c0 >= 0 and r0 + h <= cells.label.shape[0] and c0 + w <= cells.label.shape[1]:
                return cells.window(r0, c0, h, w), ground
        return footprint_cells(window.x_left_m, window.y_top_m, window.res_m, (h, w),
                               read_footprints(task.footprints_path, project_crs)), ground

    cells, ground = cells_of(surface)
    candidates = roof_candidates(cells, surface.heights_m, ground, surface.res_m)
    occluder = occluder_of_cells(surface, ground, cells, crown_base_m=crown_base_m, candidates=candidates)
    if heights is None or not HEIGHTS_BY_OUTLINE:
        return occluder, None
    same_window = (heights.heights_m.shape == surface.heights_m.shape and heights.res_m == surface.res_m
                   and heights.x_left_m == surface.x_left_m and heights.y_top_m == surface.y_top_m)
    if not same_window:    # (the chain's dsm.tif and dsm_nearest.tif share one grid: their cells and ground too)
        cells, ground = cells_of(heights)
    own = same_window and heights is not surface and OUTLINES_OF_THE_OCCLUSION_TEST
    # the outlines' surface is the occluder's (the occlusion surface on the same window, or the DSM itself): the
    # occluder's candidates and eave widths, not made again
    shared = candidates if same_window and (own or heights is surface) else None
    return occluder, outline_heights(heights, ground, cells, outline_top_m=surface.heights_m if own else None,
                                     candidates=shared)


_kept_rasters: dict = {}  # path -> (open dataset, its lock) while blocks are rectified in this process
_kept_lock = threading.Lock()
_keeping = [0]  # how many ``rectify_block`` calls of this process keep their height rasters open now


@contextlib.contextmanager
def _rasters_kept_open():
    """The height rasters (DEM, DSM, occlusion DSM, crown bases) the frame tasks of this process read kept open until
    the block is done, so that GDAL's block cache decodes each of their blocks once, not once for every frame window
    that holds it (the demo's 18 windows read each raster about 3 times over: 0.35 CPU-s a raster, opened and
    decoded per frame). Tasks on other processes (a cluster) open them per frame as before."""
    with _kept_lock:
        _keeping[0] += 1
    try:
        yield
    finally:
        with _kept_lock:
            _keeping[0] -= 1
            if _keeping[0] == 0:
                for ds, _ in _kept_rasters.values():
                    ds.close()
                _kept_rasters.clear()


@contextlib.contextmanager
def _height_raster(path, project_crs, what: str):
    """``open_height_raster`` for a frame task: the block's kept-open dataset (``_rasters_kept_open``), held under its
    lock while the task reads it (a dataset is not to be read by two threads at once), else opened and closed here;
    read errors named (``_raster_read``). The same values either way."""
    if not _keeping[0]:
        with open_height_raster(path, project_crs, what) as ds, _raster_read(path, what):
            yield ds
        return
    key = str(path)  # (its CRS checked against the project's when opened; a block's tasks share the project)
    with _kept_lock:
        kept = _kept_rasters.get(key)
        if kept is None:
            kept = _kept_rasters[key] = (open_height_raster(path, project_crs, what), threading.Lock())
    ds, lock = kept
    with lock, _raster_read(path, what):
        yield ds


_CROWNS: dict = {}  # this process's crowns by (path, size, mtime): read once, not per frame
_CROWNS_LOCK = threading.Lock()


def _crowns_of(path: str, project_crs):
    """The crown disks of ``path`` (``ortho.crown_cells.read_crowns``), read once per process and file version."""
    from ortho.crown_cells import read_crowns

    st = Path(path).stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    with _CROWNS_LOCK:  # the frames' threads: one reading, and no entry cleared under another thread
        if key not in _CROWNS:
            _CROWNS.clear()
            _CROWNS[key] = read_crowns(path, project_crs)
        return _CROWNS[key]


def _crown_base(task: FrameTask, heights: HeightRaster, ground_bounds, project_crs) -> np.ndarray | None:
    """The crown bases of ``task.crown_base_path`` (None: none) on the frame's DSM window ``heights``, whose grid the
    raster must share (float32, NaN where none)."""
    if not task.crown_base_path:
        return None
    with _height_raster(task.crown_base_path, project_crs, "crown base") as ds:
        crown = read_height_window(ds, ground_bounds, margin_m=4 * heights.res_m, what="crown base",
                                   frame=task.image_id, height_operation=_built(task.crown_base_height_operation))
    if (crown.heights_m.shape != heights.heights_m.shape or crown.res_m != heights.res_m
            or crown.x_left_m != heights.x_left_m or crown.y_top_m != heights.y_top_m):
        raise InputError(f"{task.crown_base_path}: the crown base raster is not on the DSM's grid "
                         f"({task.occlusion_dsm_path or task.dsm_path}: "
                         f"{heights.res_m:g} m cells); expected the grid of the DSM, e.g. both from lidarctl")
    return crown.heights_m


def _rectify_frame_task(task: FrameTask) -> dict:
    """Rectify one frame into ``task.out_path`` (atomic); returns its index.json entry. With ``task.resume_dir``
    the frame ortho (a hard link) and its entry are kept there for a resumed run (``_resumed_frame``)."""
    entry = _rectify_frame(task)
    if task.resume_dir and task.resume_key:
        keep = ResumeFolder(Path(task.resume_dir))
        keep.keep(task.out_path, task.resume_key, ".tif")
        # written last (the frame is whole), and outside the stage's commit, which a failed run rolls back
        keep.put_text(task.resume_key, ".json", json.dumps(entry) + "\n")
    return entry


def _resume_key(task: FrameTask, inputs: dict) -> str:
    """sha256 (32 hex digits) of what a frame's ortho depends on: the task but where it is written and its
    threads, the camera's parameters, the size and modification time of its image, DEM, DSM, footprints and crown
    bases, the block's inputs (EO, camera, DEM hashes), the rectification's version
    (``ortho.rectify.rectify_version``: of the grid's CRS) and the toolkit's version."""
    import aerotri
    from ortho.rectify import rectify_version

    doc = {}
    for f in dataclasses.fields(task):
        if f.name in ("out_path", "threads", "resume_dir", "resume_key") or (f.name in _KEY_FIELDS_IF_SET
                                                                              and not getattr(task, f.name)):
            continue  # (without them the key of a frame kept before the fields existed)
        v = getattr(task, f.name)
        doc[f.name] = _camera_sha256(v) if f.name == "camera" else repr(v) if dataclasses.is_dataclass(v) else v
    for f in ("image_path", "dem_path", "dsm_path", "footprints_path", "crown_base_path", "occlusion_dsm_path",
              "crowns_path"):
        path = getattr(task, f)
        if path:
            doc[f"{f}_size_mtime"] = file_stamp(path)
    doc["inputs"], doc["version"], doc["rectify_version"] = (inputs, aerotri.__version__,
                                                          rectify_version(task.operation is not None))
    if task.footprints_path:  # the footprints' rules change frame orthos within a version (a run resumed on newer code)
        doc["footprint_rules"] = {"heights_by_outline": HEIGHTS_BY_OUTLINE,
                                  "outlines_of_the_occlusion_test": OUTLINES_OF_THE_OCCLUSION_TEST}
    return resume_key(doc)


def _resumed_frame(task: FrameTask, out_dir: Path) -> dict | None:
    """The index entry of ``task``'s frame kept by an earlier, interrupted run (its ortho linked into
    ``out_dir``), or None when there is none whole."""
    keep = ResumeFolder(Path(task.resume_dir))
    tif, text = keep.kept(task.resume_key, ".tif"), keep.get_text(task.resume_key, ".json")
    if tif is None or text is None:
        return None
    try:
        entry = json.loads(text)
    except ValueError:
        return None
    if not isinstance(entry, dict) or entry.get("size") != tif.stat().st_size:
        return None
    _link_or_copy(tif, out_dir / entry["file"])
    return entry


def _built(spec: OperationSpec | None):
    return spec.build() if spec is not None else None


def _rectify_frame(task: FrameTask) -> dict:
    """``_rectify_frame_task`` without the keeping for a resumed run."""
    project_crs = CRS.from_wkt(task.project_crs_wkt)
    out_crs = CRS.from_wkt(task.output_crs_wkt)
    zlo, zhi = task.z_range_m
    to_project = GridToProject(out_crs, project_crs, operation=task.operation.build() if task.operation else None,
                               z_m=0.5 * (zlo + zhi))
    height_op = task.height_operation.build() if task.height_operation else None
    C = np.asarray(task.centre_m, float)
    R = rotation_matrix_opk(*task.opk_deg)
    ground_bounds = _plane_footprint_bounds(task.camera, C, R, zlo - 5.0, zhi + 5.0, task.image_id, crs=project_crs)
    with _height_raster(task.dem_path, project_crs, "DEM") as dem_ds:
        dem = read_height_window(dem_ds, ground_bounds, margin_m=4 * dem_ds.transform.a, what="DEM", frame=task.image_id,
                                 height_operation=height_op)
        extent = tuple(dem_ds.bounds)
    heights, what, path, heights_op = dem, "DEM", task.dem_path, height_op
    if task.dsm_path:
        with _height_raster(task.dsm_path, project_crs, "DSM") as dsm_ds:
            heights_op = _built(task.dsm_height_operation)
            heights = read_height_window(dsm_ds, ground_bounds, margin_m=4 * dsm_ds.transform.a, what="DSM",
                                         frame=task.image_id, height_operation=heights_op)
            extent, what, path = tuple(dsm_ds.bounds), "DSM", task.dsm_path
    said = FrameMessages()
    covered = _require_coverage(task, C, R, heights, what=what, path=path, extent=extent, crs=project_crs,
                                said=said)
    surface = heights    # of the occlusion test: the DSM itself (the same object: the maps' z-buffer test) or its own
    if task.dsm_path and task.occlusion_dsm_path:
        with _height_raster(task.occlusion_dsm_path, project_crs, "DSM") as occ_ds:
            surface = read_height_window(occ_ds, ground_bounds, margin_m=4 * occ_ds.transform.a, what="DSM",
                                         frame=task.image_id,
                                         height_operation=_built(task.occlusion_height_operation))
    occluder, sides = None, None
    crown = _crown_base(task, surface, ground_bounds, project_crs) if task.dsm_path else None
    if task.dsm_path and task.footprints_path:
        occluder, sides = _frame_occluder(task, surface, dem, project_crs, crown, heights)
    elif crown is not None:
        from ortho.footprints import with_crown_base

        occluder = with_crown_base(None, surface.heights_m, crown)
    if task.dsm_path and task.crowns_path:
        from ortho.crown_cells import with_crown_disks

        crowns = _crowns_of(task.crowns_path, project_crs)
        occ_op = _built(task.occlusion_height_operation if task.occlusion_dsm_path else task.dsm_height_operation)
        if occ_op is not None and len(crowns):  # the crowns' heights are the occlusion DSM's: into the same system
            _, _, top = occ_op.transform(crowns.x_m, crowns.y_m, crowns.top_m)
            _, _, base = occ_op.transform(crowns.x_m, crowns.y_m, crowns.base_m)
            crowns = dataclasses.replace(crowns, top_m=np.asarray(top, np.float64), base_m=np.asarray(base, np.float64))
        occluder = with_crown_disks(occluder, surface.heights_m, surface.x_left_m, surface.y_top_m, surface.res_m,
                                    crowns, own=True)  # (the occluder above is this frame's)
    # the ground the frame images (its border rays on the DEM, as ``frame_grid``): the frame's grid, and (every
    # 4th ray: 16 a side) the ring in index.json by which the mosaic counts the empty cells no frame sees
    # cut to where both the DEM and the rectification's heights reach (beyond either raster the ortho is nodata;
    # the windows end at the rasters' edges)
    within = dem.bounds
    if heights is not dem:
        a, b = within, heights.bounds
        both = (max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3]))
        within = both if both[0] < both[2] and both[1] < both[3] else within
    footprint = footprint_polygon_xy(task.camera, C, R, dem, to_project=to_project, image_id=task.image_id,
                                     per_side=64, partial=True, max_view_angle_deg=task.max_view_angle_deg,
                                     min_cone_radius_m=task.res_m, within_m=within)
    grid = grid_around_footprint(footprint, task.res_m, out_crs)
    image, band_order = _frame_image(task.image_path, (task.camera.width, task.camera.height))
    corners = 0 if task.frame_nodata else black_corners(image)  # (an undeclared collar: warned of by _rectify_into)
    # the frame's own nodata (a collar declared by its nodata value or mask): nodata in its ortho, never in the mosaic
    source_valid = frame_validity(task.image_path, task.interpolation, image, band_order) if task.frame_nodata else None
    if source_valid is not None:
        invalid_share = 1.0 - cv2.countNonZero(source_valid) / source_valid.size
        said.info(f"frame {task.image_id}: {100 * invalid_share:.1f} % of "
                  "its pixels are its own nodata or beside it (its nodata value or mask): nodata in its ortho")
    # continuous surface over the ground alone (the DEM's window); a DSM standing off the DEM: told once for the block
    flags = ground_flags(surface, dem) if task.dsm_path else None
    valid_fraction = rectify_frame_to_file(task.out_path, image, band_order, task.camera, C, R, heights=heights,
                                           grid=grid, interpolation=task.interpolation, to_project=to_project,
                                           occlusion_dsm=surface if task.dsm_path else None, occluder=occluder,
                                           sides=sides, source_valid=source_valid,
                                           ground=flags.cells if flags is not None else None,
                                           compression=task.compression, threads=task.threads,
                                           max_view_angle_deg=task.max_view_angle_deg, overviews=task.overviews,
                                           tags=operation_tags(to_project.record(),
                                                               heights_op.record() if heights_op else None))
    if isinstance(image, FrameFile):
        image.close()
    del image
    if valid_fraction == 0.0 and task.max_view_angle_deg < 90.0:
        said.warning(f"frame {task.image_id}: no ground within {task.max_view_angle_deg:g} deg of the vertical "
                     f"([rectify] max_view_angle_deg): its ortho is empty")
    nadir_x, nadir_y = to_project.to_output(np.array([C[0]]), np.array([C[1]]))
    return {
        "image_id": task.image_id, "file": Path(task.out_path).name, "x_left_m": grid.x_left_m, "y_top_m": grid.y_top_m,
        "width": grid.width, "height": grid.height, "centre_m": [float(v) for v in C],
        "nadir_xy_m": [float(nadir_x[0]), float(nadir_y[0])], "valid_fraction": valid_fraction,
        "height_covered_share": round(covered, 4),
        "footprint_xy_m": np.round(footprint[::4], 2).tolist(),
        **to_record(file_fingerprint(task.out_path)),
        **({"black_corners": corners} if corners else {}),  # (taken out of the index by _rectify_into)
        # (as black_corners)
        **({"ground_stand_off": [round(flags.level_m, 2), round(flags.share, 4), round(flags.level_share, 4)]}
           if flags is not None and flags.stands_off else {}),
        **({"messages": list(said)} if said else {}),  # (said and taken out of the index by _rectify_into)
    }


@dataclasses.dataclass(frozen=True)
class FileFingerprint:
    size: int  # bytes
    sha1: str


def file_fingerprint(path) -> FileFingerprint:
    """``size`` (bytes) and ``sha1`` of a file: what index.json records of every frame ortho, so that a
    consumer can tell a frame file that does not belong to the index (``verify_index``)."""
    import hashlib

    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return FileFingerprint(Path(path).stat().st_size, h.hexdigest())


@dataclasses.dataclass(frozen=True)
class RectifiedFrames:
    """What ``rectify_block`` made: ``ortho/frames/index.json`` (``index_path``; its reader: ``read_index``), the
    output CRS (WKT) and pixel size (metres, or the CRS's unit), and every frame's grid, in frame order."""

    index_path: Path
    crs_wkt: str
    res_m: float
    image_ids: tuple[str, ...]
    grids: tuple[OrthoGrid, ...]
    operation: str | None  # the coordinate operation project -> output CRS applied (its description), None: none

    def grid(self, image_id: str) -> OrthoGrid:
        """The output grid of frame ``image_id`` (KeyError naming the frames there are)."""
        if image_id not in self.image_ids:
            raise KeyError(f"no frame {image_id!r}; there are: {', '.join(self.image_ids)}")
        return self.grids[self.image_ids.index(image_id)]


def _rectified_frames(index: FrameIndex) -> RectifiedFrames:
    op = index.coordinate_operation
    return RectifiedFrames(index.path, index.crs_wkt, index.res_m, index.image_ids, index.grids,
                           op["description"] if op else None)


def rectify_block(root, settings: RectifySettings | Resolved | None = None, *, eo_path=None, camera_path=None,
                  frames=None, executor=None, params=None, heights=None,
                  allow_ballpark: bool = False) -> RectifiedFrames:
    """Rectify the frames of a project into ``ortho/frames/``; the frames and their index.json (``RectifiedFrames``).

    ``settings``: None reads [rectify] of project.toml; a ``Resolved`` (``ortho rectify``, the chain) carries the
    source of every setting into index.json (``settings``). The output CRS (``crs``; default the target CRS
    of ``params``, else the project CRS) is reached by the
    toolkit's coordinate-operation policy: ``params`` is a parameter file of ``aerotri crs fit`` (needed
    for a datum change PROJ does not know rigorously), ``heights`` a height anomaly model (``aerotri crs
    fit-heights``) for a DEM in normal heights, ``allow_ballpark`` accepts PROJ's ballpark operation.
    The operations applied are recorded in index.json and in every frame's GeoTIFF tags.

    One task per frame (``_rectify_frame_task``) on ``executor`` (``aerotri.core.executor.Executor``,
    default: the run's or local threads); every task writes its own GeoTIFF, the index is written
    here in frame order, so the outputs do not depend on the scheduler. ``compression``: one of
    ``FRAME_COMPRESSION``.
    """
    from aerotri.core.executor import local_executor

    resolved = settings_of(settings, RectifySettings, Project.open(root) if settings is None else None)
    s = resolved.settings
    dem_path, res_m, crs, interpolation, true_ortho, dsm_path, compression = (
        s.dem, s.res_m, s.crs, s.interpolation, s.true_ortho, s.dsm, s.compression)
    if not (math.isfinite(s.max_view_angle_deg) and 0.0 < s.max_view_angle_deg <= 90.0):
        raise OptionError(f"{s.max_view_angle_deg!r}: expected an angle from the vertical in (0, 90] degrees",
                          param="--max-view-angle-deg")
    if res_m is not None and not (math.isfinite(res_m) and res_m > 0):
        raise OptionError(f"{res_m!r}: expected a positive pixel size in metres", param="--res-m")
    block = load_block(root, eo_path, camera_path, frames)
    project = block.project
    project_crs = block.project_crs
    if not dem_path:
        dem_path = project.dem_path
        resolved = resolved.replace("dem", dem_path, resolved.sources.get("dem", "default"), "the LiDAR stages' DEM")
    dem_path = Path(dem_path)
    if true_ortho and not dsm_path:
        raise InputError("--true-ortho needs --dsm (the DSM, e.g. lidar_out/dsm.tif)")
    if true_ortho and not dem_path.exists():  # a drone user with a peer's DSM alone meets this first
        raise InputError(f"{dem_path}: DEM not found; the true ortho needs a DEM beside the DSM (the frames' ground "
                         f"extent; with --footprints the ground beneath the eaves): pass --dem, e.g. the DSM itself or "
                         f"the tie points' DEM of `ortho dem {root}` (at/dem.tif)")
    tie_point_dem = project.at_dir / "dem.tif"
    if not dem_path.exists() and dem_path == project.dem_path and tie_point_dem.is_file():
        # (new-user trial 88: a project without LiDAR, after `aerotri run` made at/dem.tif, was told only to run
        # lidarctl or pass --dem)
        raise InputError(f"{dem_path}: DEM not found (the project has no LiDAR DEM); the tie points' DEM that "
                         f"`aerotri run` or `ortho dem` made is {tie_point_dem}: pass --dem {tie_point_dem}, or a DEM "
                         "from elsewhere", param="--dem")
    if not dem_path.exists() and dem_path == project.dem_path:
        # only the project's own DEM gets the hint: a user who typed --dem was told to "pass --dem" (Tuniu trial)
        raise InputError(f"{dem_path}: DEM not found (the LiDAR stages' DEM: run `lidarctl rasters` to produce it, "
                         "or pass --dem)", param="--dem")
    if compression not in FRAME_COMPRESSION:
        raise InputError(f"unknown frame compression {compression!r}; expected one of {sorted(FRAME_COMPRESSION)}")
    transformation = load_transformation(params) if params else None
    height_model = load_height_model(heights) if heights else None
    project_heights = parse_heights(project.info.heights,
                                    f"{project.root / 'project.toml'}: [project] heights")
    dem_ds = open_height_raster(dem_path, project_crs, "DEM")
    with _raster_read(dem_path, "DEM"):
        warn_zero_fill(dem_ds, dem_path, "DEM")
    if true_ortho:
        with open_height_raster(dsm_path, project_crs, "DSM") as dsm_ds, _raster_read(dsm_path, "DSM"):
            if Path(dsm_path).resolve() != Path(dem_path).resolve():
                warn_zero_fill(dsm_ds, dsm_path, "DSM")
    footprints = Path(s.footprints) if s.footprints and true_ortho else None
    if footprints is not None:  # checked whole before any frame is written
        from ortho.footprints import read_footprints

        read_footprints(footprints, project_crs)
    crowns = Path(s.crowns) if s.crowns and true_ortho else None
    if crowns is not None:  # checked whole before any frame is written
        from ortho.crown_cells import read_crowns

        read_crowns(crowns, project_crs)
    crown_base = Path(s.crown_base) if s.crown_base and true_ortho else None
    if crown_base is not None:
        open_height_raster(crown_base, project_crs, "crown base").close()
    occlusion_dsm = Path(s.occlusion_dsm) if s.occlusion_dsm and true_ortho else None
    if occlusion_dsm is not None and occlusion_dsm.resolve() == Path(dsm_path).resolve():
        occlusion_dsm = None      # the DSM itself
    if occlusion_dsm is not None:
        open_height_raster(occlusion_dsm, project_crs, "occlusion DSM").close()
    out_dir = project.ortho_dir / "frames"
    # what a killed earlier run left of its atomic frames folder (.frames.part-*): one rectification per
    # project at a time, so nothing else writes there now
    for gone in remove_leftovers(project.ortho_dir):
        _log.info(f"removed {gone.name}, left by an interrupted run")
    try:
        height_op = dem_height_operation(CRS(dem_ds.crs), project_crs, project_heights, height_model, allow_ballpark,
                                         str(dem_path), model_states_heights=True)
        # every height raster through the operation of its own vertical CRS (a DSM in feet beside a DEM in metres);
        # the DEM's file given again as the DSM is read as the DEM is (--heights converts it once, for both)
        raster_ops = {what: (height_op if path is not None and Path(path).resolve() == Path(dem_path).resolve() else
                             _raster_height_operation(path, project_crs, project_heights, height_model, allow_ballpark))
                      for what, path in (("dsm", dsm_path if true_ortho else None), ("occlusion", occlusion_dsm),
                                         ("crown_base", crown_base))}
        with _raster_read(dem_path, "DEM"):
            zlo, zhi = height_range(dem_ds)
        if height_op is not None:  # the range in the project's height system (and unit), for the footprints
            b = dem_ds.bounds
            _, _, zc = height_op.transform([0.5 * (b.left + b.right)] * 2, [0.5 * (b.bottom + b.top)] * 2, [zlo, zhi])
            zlo, zhi = float(np.min(zc)), float(np.max(zc))
        sel = block.eo.rows(list(block.images.image_id))
        eo_idx = dict(zip(block.images.image_id, sel.tolist()))  # image id -> row of block.eo
        eo_sel = ExteriorOrientations([block.eo.image_id[i] for i in sel], block.eo.centre_m[sel], block.eo.opk_deg[sel])
        with _raster_read(dem_path, "DEM"):
            nadir_z = np.array([np.ma.filled(v.astype(float), np.nan)[0]
                                for v in dem_ds.sample([tuple(p) for p in eo_sel.centre_m[:, :2]], masked=True)])
        if height_op is not None:  # the DEM's heights in the project's system, as the centres' (feet: metres)
            ok = np.isfinite(nadir_z)
            if ok.any():
                _, _, nadir_z[ok] = height_op.transform(eo_sel.centre_m[ok, 0], eo_sel.centre_m[ok, 1], nadir_z[ok])
        nadir_z = np.where(np.isfinite(nadir_z), nadir_z, 0.5 * (zlo + zhi))
        gsd_res = default_resolution(block.camera, eo_sel, nadir_z, dem_path)
        res = gsd_res if res_m is None else float(res_m)
    finally:
        dem_ds.close()
    centre_xy = np.median(eo_sel.centre_m[:, :2], axis=0)
    if crs is None and transformation is not None:
        crs = transformation.to_crs_def
    out_crs = resolve_output_crs(crs, project_crs, centre_xy)
    # the project's own CRS too: `aerotri import` says it once, the orthophotos are where its pixels become ground
    # sizes (a trial user's Web Mercator block ran `aerotri run` without a word: 0.02 of its units a pixel, 1.4 cm)
    _warn_output_scale(project_crs, out_crs, centre_xy, res)
    res_in_m = res * linear_unit_m(out_crs)  # nan for degrees: no comparison
    if res_m is not None and res_in_m < 0.5 * gsd_res:
        _log.warning(f"--res-m {res:g} ({res_in_m:.3g} m) is finer than half the block's ground sample distance "
                     f"({gsd_res:g} m): the orthophotos get {(gsd_res / res_in_m) ** 2:.0f} times the pixels of the "
                     "default resolution without more detail")
    operation = None
    if transformation is not None or out_crs != project_crs:
        operation = CrsTransformer(project_crs, out_crs, params=transformation, allow_ballpark=allow_ballpark)
    executor = executor or local_executor()
    check_frame_sizes(block, eo_idx, zlo, zhi, res, "--res-m" if res_m is not None else None,
                      concurrent=min(len(block.images), max(1, executor.workers)), operation=operation)
    if true_ortho:
        tie_points_off_surface(block, dsm_path, "DSM", project_crs, raster_ops["dsm"], res_in_m)
    else:
        tie_points_off_surface(block, dem_path, "DEM", project_crs, height_op, res_in_m)
    threads = executor.cores_per_task(len(block.images))  # tile threads per frame task (None: all)
    surfaces = {"dsm": dsm_path, "occlusion_dsm": occlusion_dsm} if true_ortho else {}
    inputs = _rectify_inputs_document(block, dem_path, _recorded_inputs(out_dir), surfaces)
    old_index = _compatible_old_index(out_dir, res, out_crs, inputs, frames) if frames else None
    # all frames or none: the frames are written into a temporary folder next to ortho/frames, which
    # replaces it only when every frame and the index are written (a failed run leaves the old output)
    # GDAL's block cache bounded for the whole stage, set here before the frame tasks start on their threads
    resume_dir = project.work_dir / RESUME_DIR_NAME
    # an error (bad input, a bad frame) leaves no output of any kind: the frames kept for a resumed run go too; a kill
    # or Ctrl-C (not an Exception) keeps them; committed: nothing to resume (aerotri.core.resume)
    with resumable(resume_dir):
        with atomic_dir(out_dir) as tmp_dir, stage_block_cache(RECTIFY_CACHE_BYTES), _rasters_kept_open():
            index = _rectify_into(tmp_dir, block, eo_idx, res=res, out_crs=out_crs, project_crs=project_crs,
                                  dem_path=dem_path, zlo=zlo, zhi=zhi, interpolation=interpolation, true_ortho=true_ortho,
                                  dsm_path=dsm_path, compression=compression, threads=threads, operation=operation,
                                  height_op=height_op, raster_ops=raster_ops, executor=executor, inputs=inputs,
                                  max_view_angle_deg=float(s.max_view_angle_deg), footprints=footprints,
                                  crown_base=crown_base, occlusion_dsm=occlusion_dsm, resume_dir=resume_dir,
                                  overviews=s.overviews, crowns=crowns)
            _shared_cells.clear()  # (this process's; the key names the files' sizes and times for the workers')
            if old_index is not None:  # re-run of a subset: the other frames of the earlier run come along
                done = {e["image_id"] for e in index["frames"]}
                keep = [e for e in old_index.document["frames"] if e["image_id"] not in done]
                for e in keep:
                    _link_or_copy(out_dir / e["file"], tmp_dir / e["file"])
                index["frames"] = sorted(keep + index["frames"], key=lambda e: e["image_id"])
            index["settings"] = resolved.record()
            write_text_atomic(tmp_dir / "index.json", json.dumps(index, indent=1) + "\n")
    return _rectified_frames(frame_index(index, out_dir / "index.json"))


def _warn_output_scale(project_crs, out_crs, centre_xy, res: float) -> None:
    """A warning when the output CRS's point scale factor at the block's centre is off 1 by more than
    ``aerotri.geom.crs.definition.GRID_SCALE_LIMIT`` (1 %): a grid far from its central meridian (the demo, lon
    110.5 E, in CGCS2000 GK CM 123E, EPSG:4550: 1.0178, 18 mm per metre) makes pixels and distances that are no
    ground measures, most often a zone chosen by mistake. Names the zone of the block's longitude in the same family
    of grids (``_zone_of_same_family``) and the block's UTM zone; Web Mercator (EPSG:3857, k = 1 / cos(lat): 1.16 at
    30 degrees, 1.74 at 55) is said to be no mapping grid at all. A block more than ``OUTSIDE_AREA_OF_USE_DEG``
    outside the CRS's area of use is warned whatever the scale (a UTM zone one off at 50-60 degrees latitude)."""
    from aerotri.geom.crs.definition import (GRID_SCALE_LIMIT, crs_label, horizontal_crs, point_scale_factor,
                                             utm_zone_label)
    from aerotri.geom.crs.transform import to_own_geodetic

    h = horizontal_crs(out_crs)
    if not h.is_projected or horizontal_crs(project_crs).is_engineering:
        return
    lon, lat, _ = to_own_geodetic(project_crs, np.array([centre_xy[0]]), np.array([centre_xy[1]]), np.array([0.0]))
    lon, lat = float(lon[0]), float(lat[0])
    k = point_scale_factor(h, lon, lat)
    outside_deg = _degrees_outside_area_of_use(h, lon, lat)
    if not np.isfinite(k) or (abs(k - 1.0) <= GRID_SCALE_LIMIT and outside_deg <= OUTSIDE_AREA_OF_USE_DEG):
        return
    utm = utm_zone_label(lon, lat)
    said = (f"the output CRS {crs_label(out_crs)} ({h.name}) has a scale factor of {k:.4f} where the block is "
            f"(lon {lon:.2f}, lat {lat:.2f}): a pixel of {res:g} grid units is {res / k:.4g} m on the ground "
            f"({abs(k - 1.0) * 1000:.1f} mm per metre)")
    if outside_deg > OUTSIDE_AREA_OF_USE_DEG:
        said += (f", and the block lies {outside_deg:.1f} degrees outside its area of use ({h.area_of_use.name}; "
                 "expected where a contract extends one zone over a country, e.g. Denmark in UTM 32, Norway in 33)")
    method = (h.coordinate_operation.method_name if h.coordinate_operation is not None else "").lower()
    if "pseudo mercator" in method or "popular visualisation" in method:
        _log.warning(f"{said}; Web Mercator is a web map's display grid, not a mapping grid for measured products "
                     f"(its scale is 1 / cos(latitude) everywhere): deliver in the contract's grid or the block's "
                     f"UTM zone {utm}")
        return
    own = _zone_of_same_family(h, lon, lat, GRID_SCALE_LIMIT)
    advice = (f"the block's zone in this family of grids is {crs_label(own)} ({own.name})" if own is not None
              else "no grid of the same family and datum covers the block")
    gk3 = ""
    if h.geodetic_crs.datum.name in ("China 2000", "China Geodetic Coordinate System 2000") and 73.0 <= lon <= 136.0:
        gk3 = "; --crs gk3:cgcs2000 takes its 3-degree Gauss-Krueger zone"
    _log.warning(f"{said}; is it the contract's zone? {advice}; the block's UTM zone is {utm}{gk3}")


# a block centre this far outside the output CRS's area of use (PROJ's) is warned whatever the scale: a UTM zone
# off by one is 1.0019 at 50 degrees latitude, inside the scale limit, and still most likely a zone chosen by mistake
OUTSIDE_AREA_OF_USE_DEG = 1.0


def _degrees_outside_area_of_use(h, lon: float, lat: float) -> float:
    """How far (lon, lat) lies outside the area of use of CRS ``h`` in degrees (the larger of the longitude and
    latitude distances; 0 inside it or when the CRS states none). Longitudes compared modulo 360."""
    area = h.area_of_use
    if area is None:
        return 0.0
    width = (area.east - area.west) % 360.0 or 360.0  # an area across the antimeridian has west > east
    east_of_west = (lon - area.west) % 360.0
    dlon = 0.0 if east_of_west <= width else min(east_of_west - width, 360.0 - east_of_west)
    dlat = max(area.south - lat, lat - area.north, 0.0)
    return float(max(dlon, dlat))


def _zone_of_same_family(h, lon: float, lat: float, limit: float):
    """The EPSG projected CRS of the family of ``h`` (the same name but for its numbers: "ETRS89 / UTM zone 33N" ->
    zone 32N, "CGCS2000 / 3-degree Gauss-Kruger CM 123E" -> CM 111E; the same projection method and datum) whose
    scale factor at (lon, lat) is nearest 1 and within ``limit``; None when none is."""
    import re

    import pyproj
    from pyproj.aoi import AreaOfInterest
    from pyproj.enums import PJType

    from aerotri.geom.crs.definition import point_scale_factor

    pattern = re.sub(r"\d+", "#", h.name)
    method = h.coordinate_operation.method_name if h.coordinate_operation is not None else None
    best, best_dk = None, limit
    for info in pyproj.database.query_crs_info(auth_name="EPSG", pj_types=PJType.PROJECTED_CRS,
                                               area_of_interest=AreaOfInterest(lon, lat, lon, lat)):
        if info.deprecated or re.sub(r"\d+", "#", info.name) != pattern:
            continue
        c = pyproj.CRS.from_epsg(int(info.code))
        if c.coordinate_operation is None or c.coordinate_operation.method_name != method or \
                not c.geodetic_crs.equals(h.geodetic_crs, ignore_axis_order=True):
            continue
        dk = abs(point_scale_factor(c, lon, lat) - 1.0)
        if dk <= best_dk:
            best, best_dk = c, dk
    return best


TIE_POINTS_MIN = 20  # tie points on the surface for its offset from the block to be told


def tie_points_off_surface(block: BlockInputs, surface_path, what: str, project_crs, height_op, res_m: float
                           ) -> float | None:
    """The median height of the project's adjusted tie points (at/object_points.csv, 2+ rays) above the surface the
    orthos are rectified on (``surface_path``, its heights through ``height_op``), with a warning when it displaces
    the orthos by more than a pixel (``res_m``) at the frames' corners (the offset times the tangent of the corner's
    view angle): a DEM the block was not oriented on (Brighton Beach's ODM DEM against its GNSS-only block: -3.6 m,
    3 m at the corners, 200 px) gives orthos that look right and stand metres off, and true orthos that cut cars and
    roofs. A DSM ``what``: either way; a DEM: only tie points below it (above it they may stand on roofs and crowns,
    a forest's all of them). None when the EO is not the project's adjustment or fewer than ``TIE_POINTS_MIN``
    points lie on it."""
    from ortho.tie_points import read_tie_points

    project = block.project
    if Path(block.eo_path).resolve() != project.eo_path.resolve() or not project.object_points_path.is_file():
        return None
    try:
        xyz = read_tie_points(project.object_points_path, min_rays=2)
    except InputError:
        return None
    with open_height_raster(surface_path, project_crs, what) as ds, _raster_read(surface_path, what):
        h = np.array([np.nan if np.ma.is_masked(v[0]) else float(v[0])
                      for v in ds.sample([tuple(p) for p in xyz[:, :2]], masked=True)], float)
    on = np.isfinite(h)
    if np.count_nonzero(on) < TIE_POINTS_MIN:
        return None
    if height_op is not None:
        _, _, h[on] = height_op.transform(xyz[on, 0], xyz[on, 1], h[on])
    dz = xyz[on, 2] - h[on]
    offset = float(np.median(dz))
    cam = block.camera
    corner = math.hypot(0.5 * cam.width, 0.5 * cam.height) / cam.focal_px  # tan of the corner's view angle
    if abs(offset) * corner > res_m and (offset < 0 or what == "DSM"):
        nmad = 1.4826 * float(np.median(np.abs(dz - offset)))
        _log.warning(f"the block's tie points (at/object_points.csv, {int(np.count_nonzero(on))} on the {what}) lie "
                     f"{abs(offset):.2f} m {'above' if offset > 0 else 'below'} the {what} {surface_path} (median; "
                     f"NMAD {nmad:.2f} m): the orthos on it stand up to {abs(offset) * corner:.2f} m "
                     f"({abs(offset) * corner / res_m:.0f} px) off toward the frames' corners; orient the block on it "
                     f"(`aerotri adjust {project.root} --dem {surface_path}`, or for `aerotri run` [adjust] dem = "
                     f"\"{Path(surface_path).resolve()}\" in project.toml: surface control) or rectify on the "
                     "surface it was oriented on")
    return offset


def _raster_height_operation(path, project_crs, project_heights, height_model, allow_ballpark):
    """``dem_height_operation`` of the height raster at ``path`` (None: no raster, or its heights are the project's)."""
    if path is None:
        return None
    with open_height_raster(path, project_crs, "DSM") as ds:
        raster_crs = CRS(ds.crs)
    return dem_height_operation(raster_crs, project_crs, project_heights, height_model, allow_ballpark, str(path))


def check_frame_sizes(block: BlockInputs, eo_idx: dict, zlo: float, zhi: float, res: float, option: str | None,
                      *, concurrent: int = 1, operation=None) -> None:
    """``ResourceError`` before any work when a frame ortho at ``res`` cannot be made on this machine: its
    grid (footprint between the lowest and highest DEM height; ``operation``: project -> output CRS)
    beyond a GeoTIFF's size, or the ortho and its validity mask beyond the memory (``concurrent``
    frames at a time)."""
    from aerotri.geom.images import image_layout

    bands, itemsize = image_layout(block.images.path[0])
    to_output = operation.spec().build() if operation is not None else None
    worst = (0.0, "", 0.0, 0.0)
    for image_id in block.images.image_id:
        i = eo_idx[image_id]
        x0, y0, x1, y1 = _plane_footprint_bounds(block.camera, block.eo.centre_m[i], block.eo.rotation(i), zlo, zhi,
                                                 image_id, crs=block.project_crs)
        if to_output is not None:
            xs, ys, _ = to_output.transform([x0, x1, x0, x1], [y0, y0, y1, y1], [zlo] * 4)
            x0, x1, y0, y1 = float(np.min(xs)), float(np.max(xs)), float(np.min(ys)), float(np.max(ys))
        w, h = (x1 - x0) / res + 1, (y1 - y0) / res + 1
        if w * h > worst[0]:
            worst = (w * h, image_id, w, h)
    n_px, image_id, w, h = worst
    what = f"{option} {res:g}: the ortho of frame {image_id} ({w:,.0f} x {h:,.0f} px)" if option else \
        f"the ortho of frame {image_id} at {res:g} m ({w:,.0f} x {h:,.0f} px)"
    check_grid(w, h, what, option)
    check_allocation(n_px * (bands * itemsize + 1) * concurrent,
                     f"{what}, {bands} band(s) of {itemsize} byte(s) and its mask"
                     + (f", {concurrent} frames at a time," if concurrent > 1 else ","), option)


def _warn_ground_stand_off(stand_off: dict, n_frames: int, dsm_path, dem_path) -> None:
    """One warning for the frames whose DSM stands off the DEM (``ortho.rectify.GroundFlags``; ``stand_off``: image id
    -> [level (m), ground share, share at the level]): their true orthos lost the slope masking unsaid."""
    # a datum offset is the block's: in a few frames a level is a crop or flat roofs over most of them (review 37)
    if not stand_off or 2 * len(stand_off) < n_frames:
        if stand_off:
            _log.info(f"{len(stand_off)} of {counted(n_frames, 'frame')} ({', '.join(list(stand_off)[:5])}): most of "
                      "their DSM cells form a level off the DEM (a crop, a meadow or flat roofs?); the others' do "
                      "not: no datum offset")
        return
    ids = list(stand_off)
    level, share, at_level = (float(np.median([v[k] for v in stand_off.values()])) for k in range(3))
    _log.warning(f"{len(ids)} of {counted(n_frames, 'frame')} ({', '.join(ids[:5])}{', ...' if len(ids) > 5 else ''}"
                 f"): the DSM {dsm_path} stands {abs(level):.2f} m {'above' if level > 0 else 'below'} the DEM "
                 f"{dem_path} where the ground should be (median over the frames: {100 * share:.1f} % of the cells "
                 f"within {GROUND_NDSM_M:g} m of the DEM, {100 * at_level:.1f} % within it of {level:+.2f} m): a "
                 "vertical datum offset between DSM and DEM (ellipsoidal against orthometric heights, another geoid or "
                 "epoch)? The true orthos' occlusion test found almost no ground and took every DSM cell for a "
                 "column (no continuous surface on slopes: visible ground on slopes facing away from the camera "
                 "masked); put both in the same heights (gdalwarp, or their CRSs' vertical datums) and rectify again")


def _rectify_into(out_dir: Path, block: BlockInputs, eo_idx, *, res, out_crs, project_crs, dem_path, zlo, zhi,
                  interpolation, true_ortho, dsm_path, compression, threads, operation, height_op, executor,
                  inputs: dict, raster_ops: dict | None = None, max_view_angle_deg: float = 90.0, footprints: Path | None = None,
                  crown_base: Path | None = None, occlusion_dsm: Path | None = None,
                  resume_dir: Path | None = None, overviews: bool = False, crowns: Path | None = None) -> dict:
    """One task per frame writing ``out_dir/<image_id>.tif``; the index of the frames (in frame order). With
    ``resume_dir``: the frames an interrupted run of the same inputs finished are taken from there, the others
    kept there as they finish."""
    ops = raster_ops or {}

    def spec_of(op):
        return op.spec() if op is not None else None

    occluder_bounds = None
    if true_ortho and footprints is not None:  # the frames' ground bounds together, as each task takes its own
        fb = np.array([_plane_footprint_bounds(block.camera, block.eo.centre_m[eo_idx[i]],
                                               block.eo.rotation(eo_idx[i]), zlo - 5.0, zhi + 5.0, i, crs=project_crs)
                       for i, _ in block.images.pairs()])
        occluder_bounds = (float(fb[:, 0].min()), float(fb[:, 1].min()), float(fb[:, 2].max()), float(fb[:, 3].max()))
    tasks = [FrameTask(image_id, str(path), str(out_dir / f"{image_id}.tif"), block.camera,
                       tuple(float(v) for v in block.eo.centre_m[eo_idx[image_id]]),
                       tuple(float(v) for v in block.eo.opk_deg[eo_idx[image_id]]), str(dem_path),
                       project_crs.to_wkt(), out_crs.to_wkt(), res, (zlo, zhi), interpolation,
                       str(dsm_path) if true_ortho else None, compression, threads,
                       operation.spec() if operation is not None else None,
                       height_op.spec() if height_op is not None else None,
                       max_view_angle_deg=max_view_angle_deg,
                       footprints_path=str(footprints) if footprints is not None else None,
                       occluder_bounds_m=occluder_bounds,
                       crown_base_path=str(crown_base) if crown_base is not None else None,
                       occlusion_dsm_path=str(occlusion_dsm) if occlusion_dsm is not None else None,
                       overviews=overviews,
                       crowns_path=str(crowns) if crowns is not None else None,
                       dsm_height_operation=spec_of(ops.get("dsm")) if true_ortho else None,
                       occlusion_height_operation=spec_of(ops.get("occlusion")) if true_ortho else None,
                       crown_base_height_operation=spec_of(ops.get("crown_base")) if true_ortho else None,
                       frame_nodata=declares_nodata(path))
             for image_id, path in block.images.pairs()]
    resumed = {}
    if resume_dir is not None:
        tasks = [dataclasses.replace(t, resume_dir=str(resume_dir), resume_key=_resume_key(t, inputs)) for t in tasks]
        resumed = {t.image_id: e for t in tasks if (e := _resumed_frame(t, out_dir)) is not None}
        if resumed:
            _log.info(f"resumed {len(resumed)} of {len(tasks)} frames an interrupted run finished ({resume_dir})")
    todo = [t for t in tasks if t.image_id not in resumed]
    # each frame's warnings in the block's order, as soon as the frames before it are made too
    said, position = _SaidInOrder(), {t.image_id: k for k, t in enumerate(tasks)}
    for k, t in enumerate(tasks):
        if t.image_id in resumed:
            said.take(k, resumed[t.image_id])
    done = dict(zip((t.image_id for t in todo),
                    executor.map(_rectify_frame_task, todo, desc="rectify", unit="frame",
                                 on_result=lambda k, e: said.take(position[todo[k].image_id], e)) if todo else []))
    entries = [resumed.get(t.image_id) or done[t.image_id] for t in tasks]
    # frames with black corners that declare no nodata (each frame's task looks at its decoded corners)
    collared = [e["image_id"] for e in entries if e.pop("black_corners", 0)]
    if collared:
        one = len(collared) == 1
        _log.warning(f"{counted(len(collared), 'frame')} ({', '.join(collared[:5])}"
                     f"{', ...' if len(collared) > 5 else ''}) {'has' if one else 'have'} a corner black in every band "
                     f"and {'declares' if one else 'declare'} no nodata value or mask: a collar? It was rectified as "
                     "picture (black in the orthos and the mosaic); declare it (rio edit-info --nodata 0 FRAME, or "
                     "gdal_edit.py -a_nodata 0 FRAME) and rectify again")
    _warn_ground_stand_off({e["image_id"]: e.pop("ground_stand_off") for e in entries if "ground_stand_off" in e},
                           len(entries), dsm_path, dem_path)
    root = block.project.root
    return {
        "crs": out_crs.to_wkt(), "crs_name": out_crs.name, "epsg": out_crs.to_epsg(), "res_m": res,
        # files relative to the project folder (trial "overnight" L9: as the caller named them, two runs of one
        # project from two folders wrote two indexes)
        "project_crs": project_crs.to_string(), "dem": _in_project(dem_path, root),
        "eo": _in_project(block.eo_path, root), "true_ortho": bool(true_ortho),
        "dsm": _in_project(dsm_path, root) if dsm_path else None,
        "footprints": _in_project(footprints, root) if footprints is not None else None,
        **({"crown_base": _in_project(crown_base, root)} if crown_base is not None else {}),
        **({"crowns": _in_project(crowns, root)} if crowns is not None else {}),
        **({"occlusion_dsm": _in_project(occlusion_dsm, root)} if occlusion_dsm is not None else {}),
        "interpolation": interpolation,
        "coordinate_operation": operation.record() if operation is not None else None,
        "operation": dataclasses.asdict(operation.spec()) if operation is not None else None,
        "height_operation": height_op.record() if height_op is not None else None,
        **{f"{what}_height_operation": op.record() for what, op in ops.items() if op is not None and true_ortho},
        "inputs": inputs,
        "frames": entries,
    }


def _camera_sha256(camera) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(camera.to_dict(), sort_keys=True).encode()).hexdigest()


def _in_project(path, root: Path) -> str:
    """``path`` relative to the project folder when inside it (the record survives moving the folder)."""
    path = Path(path).absolute()
    try:
        return str(path.relative_to(Path(root).absolute()))
    except ValueError:
        return str(path)


def _rectify_inputs_document(block: BlockInputs, dem_path, earlier: dict | None = None,
                             surfaces: dict | None = None) -> dict:
    """What the frames were made from, for index.json: the EO file (sha256), the camera as used (sha256 of
    its parameters; its file when given with --camera, else the project's choice, see
    ``aerotri.geom.camera.orientations_camera``), the DEM and, of a true ortho, ``surfaces`` (``dsm``, and
    ``occlusion_dsm`` when given; size, modification time, sha256). ``stale_frames`` compares them with the files now.

    A raster's sha256 is taken from ``earlier`` (the ``inputs`` of the index there is now) when that
    recorded the same file with the same size and modification time, which ``stale_frames`` also takes
    for unchanged: a block's DEM runs to gigabytes, seconds of hashing on every run."""
    root = block.project.root

    def raster(key, path) -> dict:
        st = Path(path).stat()
        rec = {"file": _in_project(path, root), "size": st.st_size, "mtime_ns": st.st_mtime_ns}
        before = earlier.get(key) if isinstance(earlier, dict) else None
        if isinstance(before, dict) and all(before.get(k) == v for k, v in rec.items()) \
                and isinstance(before.get("sha256"), str):
            rec["sha256"] = before["sha256"]
        else:
            rec["sha256"] = file_sha256(path)
        return rec

    out = {
        "eo": {"file": _in_project(block.eo_path, root), "given": block.eo_given, "sha256": file_sha256(block.eo_path)},
        "camera": {"file": _in_project(block.camera_path, root) if block.camera_path else None,
                   "sha256": _camera_sha256(block.camera)},
        "dem": raster("dem", dem_path),
    }
    # (trial-rerun: a DSM changed since was not said by ortho mosaic / ortho check, a DEM was)
    out.update({k: raster(k, p) for k, p in (surfaces or {}).items() if p is not None})
    return out


def _recorded_inputs(out_dir: Path) -> dict | None:
    """The ``inputs`` of ``out_dir/index.json`` if it is there and readable, else None (only a hint: an
    unreadable index is replaced by this run, and ``_compatible_old_index`` checks it where it matters)."""
    try:
        index = json.loads((out_dir / "index.json").read_text())
    except (OSError, ValueError):
        return None
    return index.get("inputs") if isinstance(index, dict) else None


def _same_inputs(a, b) -> bool:
    """The same EO, camera and DEM contents (file names and times aside)."""
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return False
    return all(a.get(k, {}).get("sha256") == b[k]["sha256"] for k in ("eo", "camera", "dem"))


def stale_frames(root, index: FrameIndex, *, say_surfaces: bool = True) -> str | None:
    """Why the frames of ``index`` no longer belong to the project's orientation (the EO file or the camera
    changed since ``ortho rectify``, e.g. a re-adjustment wrote a new at/eo.txt), or None when they do.
    A DEM changed since (``say_surfaces``; False: the caller looks at ``surfaces_changed`` itself, which hashes a
    changed surface), and an index written before the inputs were recorded, are logged warnings."""
    project = Project.open(root)
    root, path = project.root, project.frames_index_path
    rec = index.inputs
    if not isinstance(rec, dict):
        _log.warning(f"{path}: written by an earlier version without the hashes of its EO, camera and DEM; the "
                     "frames cannot be checked against the current at/eo.txt (re-run `ortho rectify` to record them)")
        return None

    eo = _recorded_path(root, rec["eo"]["file"])
    if not eo.is_file():
        return f"{path}: the frames were rectified from {eo}, which no longer exists"
    if file_sha256(eo) != rec["eo"]["sha256"]:
        return (f"{path}: the frames were rectified from an older {eo} (the exterior orientation changed since, "
                "e.g. by a new adjustment)")
    cam_file = rec["camera"]["file"]
    from aerotri.geom.camera import orientations_camera

    try:  # read to compare with the recorded one only: not judged again (Camera.from_dict)
        camera, source = orientations_camera(project, eo if rec["eo"].get("given") else None,
                                             _recorded_path(root, cam_file) if cam_file else None, plausible=False)
    except InputError as exc:
        return f"{path}: the camera the frames were rectified with cannot be read now ({exc})"
    if _camera_sha256(camera) != rec["camera"]["sha256"]:
        return f"{path}: the frames were rectified with another camera than {source} (it changed since)"
    # a DEM (or a true ortho's DSM) changed since is said, not refused: the frames stay the last complete output of
    # the orientation (a failed re-run on a new DEM leaves them for the mosaic)
    if say_surfaces:
        say_surfaces_changed(path, surfaces_changed(root, index))
    return None


def say_surfaces_changed(index_path, changed: list[tuple[str, Path]]) -> None:
    """A warning per surface of ``surfaces_changed`` (the frames' index ``index_path`` named)."""
    for what, surface in changed:
        _log.warning(f"{index_path}: the frames were rectified on another {what} than {surface} is now (changed or "
                     f"removed since); re-run `ortho rectify` for orthos on the current {what}")


def _recorded_path(root: Path, f) -> Path:
    """A file the index records: relative to the project folder ``root`` unless absolute."""
    return Path(root) / f if not Path(f).is_absolute() else Path(f)


def surfaces_changed(root, index: FrameIndex) -> list[tuple[str, Path]]:
    """(what, file) of the surfaces the frames of ``index`` were rectified on (DEM, a true ortho's DSM and occlusion
    DSM) that changed or went since (content: size and time, else sha256); [] for an index without the record."""
    rec = index.inputs
    if not isinstance(rec, dict):
        return []
    out = []
    for key, what in (("dem", "DEM"), ("dsm", "DSM"), ("occlusion_dsm", "occlusion DSM")):
        if not isinstance(rec.get(key), dict):  # no DSM (a conventional ortho), or an index before trial-rerun
            continue
        surface = _recorded_path(root, rec[key]["file"])
        st = surface.stat() if surface.is_file() else None
        if st is None or ((st.st_size, st.st_mtime_ns) != (rec[key]["size"], rec[key]["mtime_ns"])
                          and file_sha256(surface) != rec[key]["sha256"]):
            out.append((what, surface))
    return out


def rectified_on(root, index: FrameIndex) -> list[Path]:
    """The surfaces whose heights the frames of ``index`` took: the DEM and a true ortho's DSM (not the occlusion
    DSM, which only hides), as index.json records them; [] for an index without the record."""
    rec = index.inputs if isinstance(index.inputs, dict) else {}
    return [_recorded_path(root, rec[k]["file"]) for k in ("dem", "dsm") if isinstance(rec.get(k), dict)]


def require_current_frames(root, index: FrameIndex, then: str) -> None:
    """``InputError`` when the frames are stale (``stale_frames``), saying to re-run ortho rectify and
    ``then`` (the commands after it, e.g. "`ortho mosaic P`")."""
    why = stale_frames(root, index)
    if why:
        raise InputError(f"{why}; re-run `ortho rectify {root}`, then {then} (a DOM from these frames would show "
                         "the old orientation)")


def _compatible_old_index(out_dir: Path, res: float, out_crs, inputs: dict, frames=()) -> FrameIndex | None:
    """The index of the frames rectified earlier onto the same grid (resolution and CRS), checked against
    its files, or None (no earlier run, or another grid: a subset re-run then replaces them all)."""
    if not (out_dir / "index.json").exists():
        return None
    old = read_index(out_dir.parent.parent)
    # said as a warning: the earlier frames go (hours of rectification on a full-size block), which an operator
    # re-rectifying one frame at another --res-m did not see (an info line: "rectified 1 frames")
    others = len(set(old.image_ids) - set(frames))
    gone = f"{others} other frame ortho{'s' if others != 1 else ''} of the earlier run in {out_dir} " \
           f"{'are' if others != 1 else 'is'} removed; only the frames given with --frames remain (rectify without " \
           "--frames for the whole block)"
    if old.res_m != res or old.crs_wkt != out_crs.to_wkt():
        what = f"pixel {old.res_m:g} -> {res:g}" if old.res_m != res else "another CRS"
        if others:
            _log.warning(f"another grid than the earlier frames' ({what}): the {gone}")
        return None
    if not _same_inputs(old.inputs, inputs):  # the other frames are stale: never brought along
        if others:
            _log.warning(f"the earlier frames were made from another orientation, camera or DEM: the {gone}")
        return None
    verify_index(out_dir, old)
    return old


def _plane_footprint_bounds(camera, C, R, z_lo, z_hi, image_id, *, crs=None):
    """Bounds (project CRS) of the frame footprint between two horizontal planes (to pick the DEM window); ``crs``:
    the project CRS, whose map points the frame sees over the earth (``FramesOnEarth``; None: a Cartesian frame)."""
    frame = FramesOnEarth(crs, C, R)
    x, y = border_pixels(camera, 16)
    d = frame.rays_local(camera, 0, x, y)
    if np.any(d[:, 2] >= -1e-6):
        raise InputError(f"{image_id}: some rays of the frame do not point downwards (check its omega/phi/kappa)")
    pts = []
    for z in (z_lo, z_hi):
        if z >= C[2]:
            raise InputError(f"{image_id}: the projection centre (Z = {C[2]:.1f} m) is below the DEM heights ({z:.1f} m)")
        pts.append(frame.at_height(0, d, z)[:, :2])
    p = np.concatenate(pts)
    return (float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max()))


_INDEX_KEYS = ("crs", "res_m", "frames")
_FRAME_KEYS = ("image_id", "file", "x_left_m", "y_top_m", "width", "height", "nadir_xy_m")


@dataclasses.dataclass(frozen=True)
class FrameEntry:
    """One frame of ``ortho/frames/index.json``: its file (in the frames folder), its output grid (left and top
    edge, pixels), the nadir point in the output CRS, the projection centre in the project CRS (None in indexes
    written before it was recorded), the file's size and SHA-1 (None likewise) and the ground the frame images
    (``footprint_xy_m``: the ring of its border rays on the DEM in the output CRS; None likewise)."""

    image_id: str
    file: str
    x_left_m: float
    y_top_m: float
    width: int
    height: int
    nadir_xy_m: tuple[float, float]
    centre_m: tuple[float, ...] | None = None
    size: int | None = None
    sha1: str | None = None
    footprint_xy_m: tuple[tuple[float, float], ...] | None = None


@dataclasses.dataclass(frozen=True)
class FrameIndex:
    """``ortho/frames/index.json`` read back (``read_index``): the output CRS (WKT) and pixel size (metres, or the
    CRS's unit), the frames in frame order, the project CRS and whether the frames are true orthos, the coordinate
    operations applied (``operation``: the spec ``index_operation`` builds; ``coordinate_operation`` /
    ``height_operation``: their records, as GeoTIFF tags name them), the inputs' hashes (``stale_frames``) and the
    document as written (``document``: what a re-run of a subset carries along and the mosaic's workers read)."""

    path: Path
    crs_wkt: str
    res_m: float
    frames: tuple[FrameEntry, ...]
    project_crs: str | None
    true_ortho: bool
    operation: dict | None
    coordinate_operation: dict | None
    height_operation: dict | None
    inputs: dict | None
    document: dict

    @property
    def image_ids(self) -> tuple[str, ...]:
        return tuple(e.image_id for e in self.frames)

    @property
    def grids(self) -> tuple[OrthoGrid, ...]:
        """Every frame's output grid, in frame order."""
        crs = CRS.from_wkt(self.crs_wkt)
        return tuple(OrthoGrid(crs, e.x_left_m, e.y_top_m, self.res_m, e.width, e.height) for e in self.frames)

    def grid(self, image_id: str) -> OrthoGrid:
        """The output grid of frame ``image_id`` (KeyError naming the frames there are)."""
        if image_id not in self.image_ids:
            raise KeyError(f"no frame {image_id!r} in {self.path}; there are: {', '.join(self.image_ids)}")
        return self.grids[self.image_ids.index(image_id)]


def frame_index(document: dict, path) -> FrameIndex:
    """The ``FrameIndex`` of an index.json document (``path``: the file it is or will be, for messages), its layout
    checked (InputError naming the file and the frame record)."""
    path, index = Path(path), document
    if not isinstance(index, dict) or any(k not in index for k in _INDEX_KEYS) or not isinstance(index["frames"], list):
        raise InputError(f"{path}: not a frame index of ortho rectify (expected keys {', '.join(_INDEX_KEYS)}); "
                         "re-run `ortho rectify`")
    _check_number(path, "res_m", index["res_m"], positive=True)
    for k, e in enumerate(index["frames"]):
        if not isinstance(e, dict) or any(f not in e for f in _FRAME_KEYS):
            raise InputError(f"{path}: frame record {k + 1} lacks {', '.join(f for f in _FRAME_KEYS if f not in e)}; "
                             "re-run `ortho rectify`")
        where = f"frame record {k + 1} ({e['image_id']})"
        for f in ("x_left_m", "y_top_m"):
            _check_number(path, f"{where} {f}", e[f])
        for f in ("width", "height"):
            if not (isinstance(e[f], int) and not isinstance(e[f], bool) and e[f] >= 1):
                raise InputError(f"{path}: {where} {f} = {e[f]!r}: expected a size in pixels; re-run `ortho rectify`")
        if not (isinstance(e["nadir_xy_m"], list) and len(e["nadir_xy_m"]) == 2):
            raise InputError(f"{path}: {where} nadir_xy_m = {e['nadir_xy_m']!r}: expected [x, y]; re-run `ortho rectify`")
        for v in e["nadir_xy_m"]:
            _check_number(path, f"{where} nadir_xy_m", v)
        ring = e.get("footprint_xy_m")
        if ring is not None:
            if not (isinstance(ring, list) and len(ring) >= 3
                    and all(isinstance(p, list) and len(p) == 2 for p in ring)):
                raise InputError(f"{path}: {where} footprint_xy_m: expected a ring of at least 3 [x, y]; "
                                 "re-run `ortho rectify`")
            for p in ring:
                for v in p:
                    _check_number(path, f"{where} footprint_xy_m", v)
    frames = tuple(FrameEntry(e["image_id"], e["file"], e["x_left_m"], e["y_top_m"], e["width"], e["height"],
                              tuple(e["nadir_xy_m"]), tuple(e["centre_m"]) if e.get("centre_m") else None,
                              e.get("size"), e.get("sha1"),
                              tuple(tuple(p) for p in e["footprint_xy_m"]) if e.get("footprint_xy_m") else None)
                   for e in index["frames"])
    return FrameIndex(path, index["crs"], index["res_m"], frames, index.get("project_crs"),
                      bool(index.get("true_ortho")), index.get("operation"), index.get("coordinate_operation"),
                      index.get("height_operation"), index.get("inputs"), index)


def read_index(root) -> FrameIndex:
    """``ortho/frames/index.json`` (the frames of the last complete ``ortho rectify``), its layout checked."""
    path = Path(root) / "ortho" / "frames" / "index.json"
    if not path.exists():
        raise InputError(f"{path}: not found (run `ortho rectify` first)")
    return frame_index(read_json(path, "frame index", hint="run `ortho rectify` first"), path)


def _check_number(path, what: str, v, positive: bool = False) -> None:
    """InputError naming the index and the key unless ``v`` is a finite number (above 0 with ``positive``)."""
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and (v > 0 or not positive)
    if not ok:
        raise InputError(f"{path}: {what} = {v!r}: expected a finite{' positive' if positive else ''} number; "
                         "re-run `ortho rectify`")


def verify_index(frames_dir, index: FrameIndex) -> None:
    """``InputError`` naming the first frame file that is not the one ``index`` records (missing, another
    size or content): frames from different runs must never be mixed. Indexes written before sizes and
    hashes were recorded are checked for the files' presence only."""
    from concurrent.futures import ThreadPoolExecutor

    frames_dir = Path(frames_dir)
    for e in index.frames:
        p = frames_dir / e.file
        if not p.is_file():
            raise InputError(f"{p}: frame ortho listed in {frames_dir / 'index.json'} is missing (re-run ortho rectify)")
        if e.size is not None and p.stat().st_size != e.size:
            raise InputError(f"{p}: {p.stat().st_size} bytes, but {frames_dir / 'index.json'} records {e.size}: the "
                             "frame does not belong to this index (changed or left by another run); re-run ortho rectify")
    with_hash = [e for e in index.frames if e.sha1 is not None]
    with ThreadPoolExecutor(min(8, usable_cores())) as pool:  # hashlib releases the GIL
        got = list(pool.map(lambda e: file_fingerprint(frames_dir / e.file).sha1, with_hash))
    for e, h in zip(with_hash, got):
        if h != e.sha1:
            raise InputError(f"{frames_dir / e.file}: content differs from {frames_dir / 'index.json'} (sha1 {h[:12]}, "
                             f"recorded {e.sha1[:12]}): the frame does not belong to this index (changed or left by "
                             "another run); re-run ortho rectify")


def require_frames_crs(root, crs: str) -> None:
    """``OptionError`` unless the rectified frames are in ``crs`` (an EPSG code or ``gk3:<datum>``)."""
    from aerotri.core.errors import OptionError

    index = read_index(root)
    have = CRS.from_wkt(index.crs_wkt)
    centre = np.median([e.centre_m[:2] for e in index.frames], axis=0)
    want = resolve_output_crs(crs, parse_crs(Project.open(root).crs, "[project] crs"), centre)
    if want != have:
        raise OptionError(f"--crs {crs}: the frames in {Path(root) / 'ortho' / 'frames'} are in {have.name}, not in "
                          f"{want.name}; run `ortho rectify {root} --crs {crs} [--params FILE]` first (the mosaic "
                          "does not resample the frames a second time)", param="--crs")


def index_operation(index: FrameIndex) -> CrsTransformer | None:
    """The coordinate operation from the frames' output CRS back to the project CRS (None when the
    frames are in the project CRS), as recorded by ``rectify_block``."""
    return None if index.operation is None else OperationSpec(**index.operation).build().inverse()
