"""Write a simulated project folder with its truth (the layout is described in the README).

Randomness: one seed per preset; independent streams for the scene, the flight, every frame and
every LiDAR strip (numpy SeedSequence spawning), so the same seed gives the same bytes.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
import warnings
from pathlib import Path

import cv2
import laspy
import numpy as np
import rasterio
import rasterio.windows
from rasterio.transform import from_origin

from aerotri.geom.eo import ExteriorOrientations, GnssPositions, format_eo, write_gnss
from aerotri.core.errors import InputError
from aerotri.geom.rotation import rotation_matrix_opk
from aerotri.sim import landcover, raster, raycast, render
from aerotri.sim.config import Preset, checked_preset
from aerotri.sim.earth import SimEarth
from aerotri.sim.flight import block_layout, cameras_from_config, lidar_lines, plan_frames
from aerotri.sim.lidar import las_header, las_record, pulse_chunks, scan_strip, strip_pulses, trajectory
from lidarctl.strips.trajectory import format_trajectory
from aerotri.sim.scene import build_scene
from aerotri.core.atomic import atomic_dir
from aerotri.core.gdal_cache import MiB, stage_block_cache
from aerotri.core.log import track
from aerotri.core.resources import measure
from aerotri.core.settings import sections_toml

log = logging.getLogger(__name__)


# Truth rasters: rows rendered at a time (about this many pixels, at most 512 rows), in 256 px tiles.
_BLOCK_PX = 4_000_000
_TILE_PX = 256
# GDAL's block cache while the project is written (frames and truth rasters written by rows of tiles): bounded,
# not 5 % of the RAM; set once around ``simulate`` from its calling thread (``aerotri.core.gdal_cache``)
SIM_CACHE_BYTES = 256 * MiB


def _block_rows(width: int) -> int:
    return int(max(16, min(512, _BLOCK_PX // max(width, 1))))


def _compression(name: str) -> dict:
    """GDAL creation options of a compression (``zstd`` at level 1 with the horizontal predictor: fast enough for
    gigapixel truth rasters; ``deflate`` as before)."""
    if name == "zstd":
        return dict(compress="zstd", zstd_level=1, predictor=2, num_threads="ALL_CPUS")
    return dict(compress=name)


def _write_geotiff(path: Path, width: int, height: int, *, bands: int, dtype, transform, epsg: int, rows, nodata=None,
                   block_rows: int | None = None, compress: str = "deflate"):
    """Tiled, compressed GeoTIFF with overviews-friendly 256 px blocks, written ``block_rows`` rows at a time:
    ``rows(r0, r1)`` gives rows r0..r1 as (r1 - r0, width[, bands]), so a raster of any size is made in
    bounded memory (progress with ETA for rasters of more than ``_BLOCK_PX`` x 64 pixels)."""
    block_rows = block_rows or _block_rows(width)
    profile = dict(driver="GTiff", width=width, height=height, count=bands, dtype=np.dtype(dtype).name,
                   crs=f"EPSG:{epsg}", transform=transform, tiled=True, blockxsize=_TILE_PX, blockysize=_TILE_PX,
                   nodata=nodata, bigtiff="IF_SAFER", **_compression(compress))
    if bands == 3 and np.dtype(dtype) == np.uint8:
        profile["photometric"] = "RGB"
    with rasterio.open(path, "w", **profile) as dst:
        out = _TileRowWriter(dst, dtype)
        starts = range(0, height, block_rows)
        if width * height > 64 * _BLOCK_PX:
            starts = track(starts, f"{path.parent.name}/{path.name}", "row blocks")
        for r0 in starts:
            out.write(rows(r0, min(height, r0 + block_rows)))
        out.close()


class _TileRowWriter:
    """Rows of a tiled raster open for writing (``dst``), written a whole row of tiles at a time: rows given in
    smaller blocks are held until their row of tiles is complete. (A row of tiles written in parts is
    compressed and written again for each part, the earlier copies left in the file: 70 % larger.)"""

    def __init__(self, dst, dtype, band: int | None = None):
        self.dst, self.dtype, self.band = dst, dtype, band
        self.tile_rows = dst.block_shapes[0][0]
        self.pending: list[np.ndarray] = []
        self.row = 0  # first row not written yet

    def write(self, data: np.ndarray) -> None:
        """The next rows, (rows, cols[, bands])."""
        self.pending.append(data)
        end = self.row + sum(len(a) for a in self.pending)
        if end >= self.dst.height:
            self._flush(end - self.row)
        elif end // self.tile_rows > self.row // self.tile_rows:  # up to the last whole row of tiles held
            self._flush((end // self.tile_rows) * self.tile_rows - self.row)

    def close(self) -> None:
        if self.pending:
            self._flush(sum(len(a) for a in self.pending))

    def _flush(self, n: int) -> None:
        data = self.pending[0] if len(self.pending) == 1 else np.concatenate(self.pending)
        self.pending = [data[n:]] if n < len(data) else []
        arr = data[:n].astype(self.dtype, copy=False)
        window = rasterio.windows.Window(0, self.row, self.dst.width, len(arr))
        if self.band is not None:
            self.dst.write(arr, self.band, window=window)
        else:
            self.dst.write(arr[None] if arr.ndim == 2 else np.moveaxis(arr, 2, 0), window=window)
        self.row += len(arr)


def _open_geotiff(path: Path, width: int, height: int, *, dtype, transform, epsg: int, nodata=None,
                  compress: str = "deflate"):
    """A single-band GeoTIFF open for writing by windows, with ``_write_geotiff``'s layout."""
    return rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=1, dtype=np.dtype(dtype).name,
                         crs=f"EPSG:{epsg}", transform=transform, tiled=True, blockxsize=_TILE_PX, blockysize=_TILE_PX,
                         nodata=nodata, bigtiff="IF_SAFER", **_compression(compress))


def _csv(path: Path, header: list[str], rows) -> None:
    lines = [",".join(header)]
    for r in rows:
        lines.append(",".join(v if isinstance(v, str) else (f"{v:.4f}" if isinstance(v, float) else str(v)) for v in r))
    path.write_text("\n".join(lines) + "\n")


@dataclasses.dataclass
class SimTruth:
    """The summary of a simulated project (``truth/truth.json``): the block, the scene, the LiDAR."""

    preset: str
    seed: int
    crs: str
    origin_m: list[float]  # project-CRS coordinates (E, N, h) of the local scene origin
    scene_width_m: float
    scene_height_m: float
    flying_height_above_ground_m: float
    gsd_m: float
    frames: int
    strips: int
    frames_per_strip: int
    image_width_px: int
    image_height_px: int
    pixel_um: float
    base_m: float
    strip_spacing_m: float
    buildings: int
    roof_corners: int
    trees: int
    check_targets: int
    check_image_points: int
    lidar_strips: int
    lidar_points: int
    lidar_class_counts: dict[int, int]  # ASPRS class -> points (truth classes)
    lidar_strip_offsets_m: list[list[float]]  # per strip: the X, Y, Z offset added to its points
    lidar_boresight_error_deg: list[float]  # roll, pitch, heading of the scanner against the IMU (injected)
    lidar_range_offset_m: float  # added to every measured range (injected)
    lidar_scan_angle_scale_error: float  # the beam leaves at theta (1 + this) where theta is read (injected)
    lidar_mean_spacing_m: float
    steep_band_y_m: list[float]  # northing of the start and end of the steep valley side
    max_slope_deg: float


@dataclasses.dataclass(frozen=True)
class PhaseCost:
    """What one phase of ``simulate`` cost (``aerotri.core.resources.measure``) and what it made."""

    phase: str  # scene, frames, lidar, truth_rasters, other
    wall_s: float
    cpu_s: float
    peak_rss_mb: float | None  # this process during the phase
    frames: int = 0
    megapixels: float = 0.0  # frame pixels (frames) or raster pixels (truth_rasters)
    points: int = 0  # LiDAR points (one copy: lidar/ and truth/lidar/ hold the same points)
    pulses: int = 0


@dataclasses.dataclass
class _LidarSummary:
    lines: int
    points: int
    strip_offsets_m: list[list[float]]
    class_counts: dict[int, int]


@dataclasses.dataclass
class _CheckTargets:
    xyz_m: np.ndarray  # (C, 3) local metres
    image_points: int  # observations of the targets in the frames


def refuse_to_replace(outdir: Path, force: bool) -> None:
    """``InputError`` unless ``outdir`` is absent, empty, or (with ``force``) a dataset the simulator made (its
    ``truth/`` folder): --force deleted any folder, a real project's gnss.txt, at/ and ortho/ with it (trial-paths)."""
    from aerotri.core.lock import LOCK_NAME

    if not outdir.exists():
        return
    if not outdir.is_dir():
        raise InputError(f"{outdir}: exists and is not a folder")
    content = [p for p in outdir.iterdir() if p.name != LOCK_NAME]
    if not content:
        return
    if not force:
        raise InputError(f"{outdir}: output folder exists and is not empty (use --force to replace it)")
    if not (outdir / "truth").is_dir():
        raise InputError(f"{outdir}: holds no truth/ folder, so no dataset aerotri sim made; --force replaces only "
                         "those: remove the folder yourself or choose another OUTDIR")


def simulate(cfg: Preset, outdir, force: bool = False, on_phase=None) -> SimTruth:
    """Generate the project described by preset ``cfg`` into ``outdir``; returns the truth summary.

    ``on_phase``: called with a ``PhaseCost`` after each phase (scene, frames, lidar, truth_rasters, other).
    """
    cfg = checked_preset(cfg)
    outdir = Path(outdir)
    refuse_to_replace(outdir, force)
    t_start = time.perf_counter()
    seed = int(cfg.preset.seed)
    ss = np.random.SeedSequence(seed)
    s_scene, s_flight, s_frames, s_lidar = ss.spawn(4)
    epsg = int(cfg.crs.epsg)
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])

    on_phase = on_phase or (lambda cost: None)

    def done(phase, usage, **made):
        on_phase(PhaseCost(phase, round(usage.wall_s, 2), round(usage.cpu_s, 2),
                           None if usage.peak_rss_mb is None else round(usage.peak_rss_mb, 1), **made))

    layout = block_layout(cfg)
    with measure() as usage:
        scene_seed = int(np.random.default_rng(s_scene).integers(0, 2**31 - 1))
        scene = build_scene(cfg.scene, layout.width_m, layout.height_m, origin, scene_seed)
        accel = raycast.build_accel(scene)
        plan = plan_frames(cfg, layout, np.random.default_rng(s_flight))
        cam_true, cam_nominal = cameras_from_config(cfg.camera)
        _check_plan(plan, scene, cfg)
        look = raster.SceneLook(scene, texture_fine_m(cfg, cam_true))
        earth = sim_earth(cfg, layout)
    done("scene", usage)
    log.info(f"scene {layout.width_m:.0f} x {layout.height_m:.0f} m: {len(scene.buildings)} buildings, "
             f"{len(scene.tree_c)} trees, {len(scene.roads)} roads, {len(scene.ponds)} ponds, {len(scene.targets)} targets "
             f"({usage.wall_s:.1f} s)")

    with atomic_dir(outdir) as tmp, stage_block_cache(SIM_CACHE_BYTES):
        for sub in ("images", "lidar", "trajectory", "truth", "truth/lidar"):
            (tmp / sub).mkdir(parents=True, exist_ok=True)
        n_frames = len(plan.image_id)
        with measure() as usage:
            gains = _render_frames(tmp / "images", cfg, look=look, plan=plan, cam_true=cam_true, s_frames=s_frames,
                                   earth=earth)
        done("frames", usage, frames=n_frames, megapixels=n_frames * cam_true.width * cam_true.height / 1e6)
        log.info(f"rendered {n_frames} frames of {cam_true.width} x {cam_true.height} px in {usage.wall_s:.1f} s")
        planned = lidar_plan(cfg)
        log.info(f"LiDAR planned: {planned.strips} strips, {planned.pulses} pulses over {planned.scene_km2} km2")
        with measure() as usage:
            lidar = _scan_lidar(tmp, cfg, layout=layout, scene=scene, accel=accel, origin=origin, epsg=epsg,
                                s_lidar=s_lidar)
        done("lidar", usage, points=int(lidar.points), pulses=int(planned.pulses))
        log.info(f"scanned {lidar.lines} LiDAR strips, {lidar.points} points in {usage.wall_s:.1f} s")
        with measure() as usage:
            megapixels = _write_truth_rasters(tmp / "truth", cfg, layout, look, origin, epsg)
        done("truth_rasters", usage, megapixels=megapixels)
        with measure() as usage:
            _write_project_files(tmp, cfg, plan=plan, cam_true=cam_true, cam_nominal=cam_nominal, origin=origin,
                                 epsg=epsg, gains=gains, dem=tmp / "truth" / "dem.tif")
            corners = scene.roof_corners()
            _write_truth_corners(tmp / "truth", scene, corners, origin, epsg)
            write_footprints_gpkg(tmp / "truth" / "buildings.geojson", tmp / "truth" / "footprints.gpkg",
                                  f"EPSG:{epsg}")
            targets = _write_check_targets(tmp / "truth", scene=scene, accel=accel, plan=plan, cam_true=cam_true,
                                           origin=origin, earth=earth)
            _write_flight_acceptance(tmp / "truth", cfg, plan, cam_true, origin)
        done("other", usage)
        truth = SimTruth(
            preset=cfg.preset.name, seed=seed, crs=f"EPSG:{epsg}", origin_m=origin.tolist(),
            scene_width_m=layout.width_m, scene_height_m=layout.height_m,
            flying_height_above_ground_m=cfg.flight.height_above_ground_m,
            gsd_m=cam_true.gsd_m(cfg.flight.height_above_ground_m),
            frames=len(plan.image_id), strips=int(cfg.flight.strips),
            frames_per_strip=int(cfg.flight.frames_per_strip),
            image_width_px=cam_true.width, image_height_px=cam_true.height, pixel_um=cam_true.pixel_um,
            base_m=layout.base_m, strip_spacing_m=layout.strip_spacing_m,
            buildings=len(scene.buildings), roof_corners=len(corners), trees=int(len(scene.tree_c)),
            check_targets=int(len(targets.xyz_m)), check_image_points=targets.image_points,
            lidar_strips=lidar.lines, lidar_points=int(lidar.points), lidar_class_counts=lidar.class_counts,
            lidar_strip_offsets_m=lidar.strip_offsets_m,
            lidar_boresight_error_deg=[float(v) for v in cfg.lidar.boresight_error_deg],
            lidar_range_offset_m=float(cfg.lidar.range_offset_m),
            lidar_scan_angle_scale_error=float(cfg.lidar.scan_angle_scale_error),
            lidar_mean_spacing_m=_mean_spacing(cfg.lidar),
            steep_band_y_m=[scene.steep_band_y_m[0] + origin[1], scene.steep_band_y_m[1] + origin[1]],
            max_slope_deg=_max_slope_deg(scene),
        )
        truth_record = dataclasses.asdict(truth)
        (tmp / "truth" / "truth.json").write_text(json.dumps(truth_record, indent=2, sort_keys=True) + "\n")
        (tmp / "README.txt").write_text(_README.format(**truth_record))
    log.info(f"wrote {outdir} in {time.perf_counter() - t_start:.1f} s")
    return truth


def sim_earth(cfg: Preset, layout) -> SimEarth:
    """The earth of a preset's world: its CRS, with the ENU frame at the scene's centre (``aerotri.sim.earth``)."""
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    return SimEarth(f"EPSG:{int(cfg.crs.epsg)}", origin, [layout.width_m / 2, layout.height_m / 2, 0.0])


def texture_fine_m(cfg: Preset, cam_true) -> float:
    """Finest texture scale of the scene (``[render] texture_fine_m``, default the nominal GSD): the scene's
    texture has structure down to this size, so a finer GSD sees finer ground texture."""
    v = cfg.render.texture_fine_m
    return float(v) if v else float(cam_true.gsd_m(cfg.flight.height_above_ground_m))


@dataclasses.dataclass(frozen=True)
class FrameLayout:
    """How frames are written: sample depth, bands and TIFF layout."""

    bits: int  # 8 or 12
    dtype: str  # "uint8" or "uint16"
    tile_px: int  # 0: strips written by OpenCV
    bands: int  # 3 (RGB) or 1 (pan)
    compress: str


def frame_layout(cfg: Preset) -> FrameLayout:
    """The frame layout from ``[render]`` (``bits`` 8 or 12, ``bands`` rgb or pan, ``tile_px``, ``compress``)."""
    r = cfg.render
    bits = int(r.bits)
    tile = int(r.tile_px)
    return FrameLayout(bits=bits, dtype="uint8" if bits == 8 else "uint16", tile_px=tile,
                       bands=1 if r.bands == "pan" else 3,
                       compress=str(r.compress) if tile else "lzw (OpenCV)")


def _render_frames(images_dir: Path, cfg: Preset, *, look, plan, cam_true, s_frames, earth: SimEarth) -> list[float]:
    """Render, expose and write every frame (``images_dir/<image_id>.tif``) as seen on ``earth``; the exposure
    gain of each.

    Frames with ``[render] tile_px`` are written as tiled TIFFs (pixel-interleaved RGB, ``compress``) a tile row
    at a time, so a frame of any size is made in bounded memory; others whole, by OpenCV, as before.
    """
    rcfg = cfg.render
    fl = frame_layout(cfg)
    renderer = raster.FrameRenderer(look.scene, cam_true, look.fine_m, samples=int(rcfg.samples), bits=fl.bits,
                                    look=look, bands=fl.bands)
    frame_seeds = s_frames.spawn(len(plan.image_id))
    gains = []

    def frames():  # (path, set-up, exposure) of each frame, set up when drawn
        for i in track(range(len(plan.image_id)), "frames"):
            frng = np.random.default_rng(frame_seeds[i])
            gain = float(np.exp(frng.normal(0.0, rcfg.exposure_sigma)))
            gains.append(gain)
            expo = dict(gain=gain, vignetting=rcfg.vignetting, noise_dn=rcfg.noise_dn,
                        noise_seed=int(frng.integers(0, 2**32)))
            R = rotation_matrix_opk(*plan.opk_deg[i])
            frame = renderer.setup(plan.centre_m[i], R, earth.frame_earth(plan.centre_m[i], R))
            yield images_dir / f"{plan.image_id[i]}.tif", frame, expo

    if fl.tile_px:
        _write_tiled_frames(frames(), renderer, fl)
    else:
        for path, frame, expo in frames():
            img, _ = renderer.render_rows(frame, 0, cam_true.height, **expo)
            cv2.imwrite(str(path), img[:, :, ::-1] if img.shape[2] == 3 else img[:, :, 0])
    return gains


def _write_tiled_frame(path: Path, renderer, frame, expo: dict, fl: FrameLayout) -> None:
    """One frame as a tiled TIFF (``_write_tiled_frames``)."""
    _write_tiled_frames([(path, frame, expo)], renderer, fl)


def _write_tiled_frames(frames, renderer, fl: FrameLayout) -> None:
    """Frames ``(path, set-up, exposure)`` as tiled TIFFs (pixel-interleaved R, G, B, or one panchromatic band;
    no georeferencing, as cameras deliver), rendered and written one row of tiles at a time.

    A row of tiles is rendered (``renderer.submit_rows``: on the renderer's threads) while the one before it is
    written on this thread, and the next frame's set-up and first row while a frame's last tiles are compressed
    at its close, so the cores are not idle between the rows (memory: one row of tiles more). All GDAL calls are
    made on this thread (the stage's block cache, ``aerotri.core.gdal_cache``)."""
    cam = renderer.camera
    tile = fl.tile_px
    profile = dict(driver="GTiff", width=cam.width, height=cam.height, count=fl.bands, dtype=fl.dtype, tiled=True,
                   blockxsize=tile, blockysize=tile, photometric="RGB" if fl.bands == 3 else "MINISBLACK",
                   interleave="pixel", bigtiff="IF_SAFER")
    if fl.compress != "none":
        profile.update(_compression(fl.compress))
    # rows of tiles in frame order: (path, r0, r1, set-up, exposure); a frame is set up when its first is drawn
    rows = ((path, r0, min(cam.height, r0 + tile), frame, expo) for path, frame, expo in frames
            for r0 in range(0, cam.height, tile))
    cur = next(rows, None)
    pending = None if cur is None else renderer.submit_rows(cur[3], cur[1], cur[2], **cur[4])
    dst = None
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=rasterio.errors.NotGeoreferencedWarning)
            while cur is not None:
                path, r0, r1, _, _ = cur
                nxt = next(rows, None)  # a new frame is set up here, while this row renders
                pixels, _ = pending.result()
                if nxt is not None:
                    pending = renderer.submit_rows(nxt[3], nxt[1], nxt[2], **nxt[4])
                if r0 == 0:
                    dst = rasterio.open(path, "w", **profile)
                dst.write(np.moveaxis(pixels, 2, 0), window=rasterio.windows.Window(0, r0, cam.width, r1 - r0))
                if r1 == cam.height:
                    dst.close()  # its last tiles compressed while the next frame's first row renders
                    dst = None
                cur = nxt
    finally:
        if dst is not None:
            dst.close()


@dataclasses.dataclass(frozen=True)
class LidarPlan:
    """What the preset's LiDAR will be, before any scanning: strips, pulses (each gives 0 to 3 points: none
    off the scene or on most water, several in trees: 0.5 points a pulse on tiny, 0.6 on demo), scene area."""

    strips: int
    pulses: int
    scene_km2: float


def lidar_plan(cfg: Preset) -> LidarPlan:
    """The preset's ``LidarPlan``."""
    layout = block_layout(cfg)
    lines = lidar_lines(cfg, layout)
    return LidarPlan(strips=len(lines), pulses=sum(strip_pulses(line, cfg.lidar, layout.width_m) for line in lines),
                     scene_km2=round(layout.width_m * layout.height_m / 1e6, 3))


def _scan_lidar(tmp: Path, cfg: Preset, *, layout, scene, accel, origin, epsg: int, s_lidar) -> _LidarSummary:
    """Scan every LiDAR strip: ``lidar/`` unclassified with a per-strip offset, ``truth/lidar/`` the same points
    with their true classes."""
    L = cfg.lidar
    lines = lidar_lines(cfg, layout)
    strip_seeds = s_lidar.spawn(len(lines))
    ext = L.format
    n_points = 0
    strip_offsets = []
    class_counts: dict[int, int] = {}
    for line, sseed in track(list(zip(lines, strip_seeds)), "LiDAR strips"):
        lrng = np.random.default_rng(sseed)
        chunks = pulse_chunks(strip_pulses(line, L, layout.width_m))
        # A strip of one chunk draws its offset after its points (the order the presets' published results
        # were made with); a longer one draws it first, so every chunk is written as soon as it is scanned.
        off = lrng.normal(0.0, L.strip_offset_sigma_m, 3) if len(chunks) > 1 else None
        name = f"strip_{line.strip:02d}.{ext}"
        rec_header = las_header(origin, epsg)  # the writers keep their own headers' counts and bounds
        with (laspy.open(tmp / "lidar" / name, mode="w", header=las_header(origin, epsg)) as obs_las,
              laspy.open(tmp / "truth" / "lidar" / name, mode="w", header=las_header(origin, epsg)) as truth_las):
            for i0, i1 in chunks:
                pts = scan_strip(scene, accel, line, L=L, rng=lrng, width_m=layout.width_m, i0=i0, i1=i1)
                if off is None:
                    off = lrng.normal(0.0, L.strip_offset_sigma_m, 3)
                pts = dataclasses.replace(pts, xyz=pts.xyz + off)
                n = len(pts.xyz)
                obs_las.write_points(las_record(rec_header, pts, origin, np.ones(n, np.uint8)).points)
                truth_las.write_points(las_record(rec_header, pts, origin).points)
                n_points += n
                for c, k in zip(*np.unique(pts.classification, return_counts=True)):
                    class_counts[int(c)] = class_counts.get(int(c), 0) + int(k)
                del pts
        strip_offsets.append(off.tolist())
        # the trajectory holds the GNSS error of its strip as the points do
        t, xyz, rph = trajectory(line, L, layout.width_m)
        (tmp / "trajectory" / f"strip_{line.strip:02d}.txt").write_text(format_trajectory(t, xyz + origin + off, rph))
    return _LidarSummary(len(lines), n_points, strip_offsets, class_counts)


def _write_project_files(tmp: Path, cfg: Preset, *, plan, cam_true, cam_nominal, origin, epsg: int, gains,
                         dem: Path, chain: dict | None = None) -> None:
    """project.toml, camera.toml, gnss.txt and the flight truth (truth/eo.txt, camera.toml, gnss_truth.toml,
    frames.csv). ``chain``: the stage sections of project.toml (default: the preset's ``[chain]``). ``[qa] terrain``
    is the class of the truth terrain ``dem`` (GB/T 7930 by its median slope, ``aerotri.qa.terrain_class``), as
    a contract over that ground would state it (a 421 m relief block was written "flat", trial-relief)."""
    from aerotri.qa.terrain_class import dem_terrain

    got = dem_terrain(dem)
    terrain = got.terrain if got is not None else "flat"  # (a DEM of fewer than 9 cells of 10 m)
    g = cfg.gnss
    (tmp / "camera.toml").write_text(cam_nominal.to_toml())
    (tmp / "truth" / "camera.toml").write_text(cam_true.to_toml())
    n = len(plan.image_id)
    sig = np.tile([g.sigma_xy_m, g.sigma_xy_m, g.sigma_z_m], (n, 1))
    write_gnss(tmp / "gnss.txt", GnssPositions(plan.image_id, plan.antenna_obs_m + origin, sig))
    eo = ExteriorOrientations(plan.image_id, plan.centre_m + origin, plan.opk_deg)
    (tmp / "truth" / "eo.txt").write_text(format_eo(eo))
    lever = ", ".join(f"{v}" for v in g.lever_arm_m)
    (tmp / "project.toml").write_text(
        f'[project]\nname = "{cfg.preset.name}"\ncrs = "EPSG:{epsg}"\nheights = "ellipsoidal"\n\n'
        f'[camera]\nfile = "camera.toml"\n\n'
        f"[gnss]\n# antenna positions in gnss.txt; lever arm = antenna in the camera frame (x right, y up, z up)\n"
        f"sigma_xy_m = {g.sigma_xy_m}\nsigma_z_m = {g.sigma_z_m}\nlever_arm_m = [{lever}]\n\n"
        f"[control]\nsigma_xy_m = 0.10\nsigma_z_m = 0.10\n\n"
        f"[flight]\n# from the flight plan: mean terrain height (m, ellipsoidal) and speed\n"
        f"mean_terrain_height_m = {origin[2]}\nspeed_mps = {cfg.flight.speed_mps}\n\n"
        f"[qa]\n# tolerance table of the accuracy report (aerotri report): map scale, terrain class, PDF copy\n"
        f'map_scale = "1:5000"\nterrain = "{terrain}"\npdf = true\n'
        + sections_toml(rendered_chain_table(cfg) if chain is None else chain)
    )
    (tmp / "truth" / "gnss_truth.toml").write_text(
        f"lever_arm_m = [{lever}]\n"
        + "".join(
            f"\n[[strip]]\nstrip = {s + 1}\nshift_m = [{', '.join(f'{v:.4f}' for v in plan.strip_shift_m[s])}]\n"
            f"drift_m_per_s = [{', '.join(f'{v:.6f}' for v in plan.strip_drift_m_per_s[s])}]\n"
            f"t_ref_s = {plan.strip_t0_s[s]:.3f}\n"
            for s in range(len(plan.strip_shift_m))
        )
    )
    flight_rows = [(iid, int(plan.strip[i]), float(plan.time_s[i]), round(gains[i], 5))
                   for i, iid in enumerate(plan.image_id)]
    _csv(tmp / "truth" / "frames.csv", ["image_id", "strip", "gps_time_s", "exposure_gain"], flight_rows)


def rendered_chain_table(cfg: Preset) -> dict:
    """The preset's stage sections with [adjust] stating the GNSS correction per strip its antenna errors need
    (``gnss_correction_of``; a ``gnss_correction`` the preset or ``--set`` gives is kept) and, when its GNSS has
    shifts or drifts, the a-priori sigma they are drawn with (``gnss_shift_sigma_m``)."""
    chain = {k: dict(v) for k, v in cfg.chain.items()}
    adjust = chain.get("adjust", {})
    chain["adjust"] = {**adjust, "gnss_correction": adjust.get("gnss_correction", gnss_correction_of(cfg))}
    if gnss_correction_of(cfg) != "none":
        chain["adjust"]["gnss_shift_sigma_m"] = gnss_shift_sigma_m(cfg)
    return chain


def _write_truth_corners(truth_dir: Path, scene, corners: list[dict], origin, epsg: int) -> None:
    """truth/roof_corners.csv (every eave outline corner) and truth/buildings.geojson (in EPSG:``epsg``)."""
    _csv(truth_dir / "roof_corners.csv",
         ["id", "x", "y", "z", "roof", "building_id", "shape", "angle_deg", "length_m", "width_m"],
         [(f"RC{k + 1:05d}", c["x"] + origin[0], c["y"] + origin[1], c["z"] + origin[2], c["roof"],
           c["building_id"], c["shape"], round(c["angle_deg"], 2), round(c["length_m"], 2), round(c["width_m"], 2))
          for k, c in enumerate(corners)])
    _write_buildings_geojson(truth_dir / "buildings.geojson", scene, origin, epsg)


def _write_check_targets(truth_dir: Path, *, scene, accel, plan, cam_true, origin, earth: SimEarth) -> _CheckTargets:
    """truth/checkpoints.csv (the painted targets) and truth/checkpoint_image_points.csv (their true image
    positions, on ``earth``, in every frame that sees the whole target)."""
    tgt = np.column_stack([scene.targets[:, :2], scene.target_z]) if len(scene.targets) else np.zeros((0, 3))
    _csv(truth_dir / "checkpoints.csv", ["id", "x", "y", "z", "kind"],
         [(f"CP{k + 1:03d}", p[0] + origin[0], p[1] + origin[1], p[2] + origin[2], "target") for k, p in enumerate(tgt)])
    img_rows = []
    for i, iid in enumerate(plan.image_id):
        if not len(tgt):
            break
        R = rotation_matrix_opk(*plan.opk_deg[i])
        x, y, depth = earth.project(cam_true, tgt, plan.centre_m[i], R)
        ok = cam_true.inside(x, y, margin_px=2.0) & (depth > 0)
        # A target counts as seen only when all of it, out to its black ring, is unoccluded.
        for a in np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False):
            rim = tgt.copy()
            rim[:, 0] += 1.8 * scene.targets[:, 2] * np.cos(a)
            rim[:, 1] += 1.8 * scene.targets[:, 2] * np.sin(a)
            rim[:, 2] = scene.terrain_height(rim[:, 0], rim[:, 1]) + 0.02
            ok &= render.visible(accel, plan.centre_m[i], rim)
        ok &= render.visible(accel, plan.centre_m[i], tgt + [0.0, 0.0, 0.02])
        for k in np.flatnonzero(ok):
            img_rows.append((f"CP{k + 1:03d}", iid, float(x[k]), float(y[k])))
    _csv(truth_dir / "checkpoint_image_points.csv", ["point_id", "image_id", "x_px", "y_px"], img_rows)
    return _CheckTargets(tgt, len(img_rows))


def _write_truth_rasters(truth_dir: Path, cfg: Preset, layout, look, origin, epsg: int) -> float:
    """truth/dem.tif and truth/dsm.tif (``[truth] raster_res_m``), truth/ortho.tif (``ortho_res_m``; R, G, B,
    or one band, the mean of R, G and B, for panchromatic frames) and on its grid the land-cover truth
    (``aerotri.sim.landcover``): truth/ortho_nir.tif (near-infrared band) and truth/classes.tif (ASPRS classes
    building, tree, grass, road, bare ground, water; nodata 255). The surface, ortho and classes are the
    straight-down view of the scene (``raster.ortho_render``) at pixel centres; ``[truth] compress`` (default
    deflate). Returns the megapixels of the DEM, DSM and ortho grids."""
    scene = look.scene
    compress = str(cfg.truth.compress)
    res = cfg.truth.raster_res_m
    nx, ny = int(math.floor(layout.width_m / res)), int(math.floor(layout.height_m / res))
    xs = (np.arange(nx) + 0.5) * res
    transform = from_origin(origin[0], origin[1] + layout.height_m, res, res)

    def grid(step, cols, r0, r1):
        return np.meshgrid(cols, layout.height_m - (np.arange(r0, r1) + 0.5) * step)

    def dem_rows(r0, r1):
        X, Y = grid(res, xs, r0, r1)
        return scene.terrain_height(X, Y) + origin[2]

    def dsm_rows(r0, r1):
        z, _, _ = raster.ortho_render(look, 0.0, layout.height_m, res, r0=r0, r1=r1, ncols=nx, shade=False)
        return z + origin[2]

    _write_geotiff(truth_dir / "dem.tif", nx, ny, bands=1, dtype=np.float32, transform=transform, epsg=epsg,
                   rows=dem_rows, nodata=-9999.0, compress=compress)
    _write_geotiff(truth_dir / "dsm.tif", nx, ny, bands=1, dtype=np.float32, transform=transform, epsg=epsg,
                   rows=dsm_rows, nodata=-9999.0, compress=compress)
    ores = cfg.truth.ortho_res_m
    onx, ony = int(math.floor(layout.width_m / ores)), int(math.floor(layout.height_m / ores))
    oxs = (np.arange(onx) + 0.5) * ores

    otransform = from_origin(origin[0], origin[1] + layout.height_m, ores, ores)
    # The land-cover truth (extra files beside ortho.tif, from the same view).
    with _open_geotiff(truth_dir / "ortho_nir.tif", onx, ony, dtype=np.uint8, transform=otransform, epsg=epsg,
                       compress=compress) as nir_dst, \
            _open_geotiff(truth_dir / "classes.tif", onx, ony, dtype=np.uint8, transform=otransform, epsg=epsg,
                          nodata=landcover.NODATA,
                          compress=compress) as cls_dst:
        nir_out, cls_out = _TileRowWriter(nir_dst, np.uint8, band=1), _TileRowWriter(cls_dst, np.uint8, band=1)

        def ortho_rows(r0, r1):
            OX, OY = grid(ores, oxs, r0, r1)
            _, rad, ids = raster.ortho_render(look, 0.0, layout.height_m, ores, r0=r0, r1=r1, ncols=onx)
            classes, nir = landcover.classes_and_nir(ids.ravel(), rad.reshape(-1, 3), OX.ravel(), OY.ravel(), scene)
            nir_out.write(raster.tone8(nir.reshape(OX.shape)[..., None])[..., 0])
            cls_out.write(classes.reshape(OX.shape))
            if ortho_bands == 1:  # as the frames' panchromatic band: the mean of the radiance
                return raster.tone8(((rad[..., 0] + rad[..., 1]) + rad[..., 2]) / np.float32(3.0))
            return raster.tone8(rad)

        ortho_bands = frame_layout(cfg).bands
        _write_geotiff(truth_dir / "ortho.tif", onx, ony, bands=ortho_bands, dtype=np.uint8, transform=otransform,
                       epsg=epsg, rows=ortho_rows, compress=compress)
        nir_out.close()
        cls_out.close()
    return (2 * nx * ny + onx * ony) / 1e6


def _mean_spacing(L):
    """Nominal single-strip point spacing 1/sqrt(density) from the scanner settings."""
    swath = 2.0 * L.height_above_ground_m * math.tan(math.radians(L.fov_deg / 2.0))
    density = L.pulse_rate_hz / (L.speed_mps * swath)
    return round(1.0 / math.sqrt(density), 3)


def _max_slope_deg(scene) -> float:
    gy, gx = np.gradient(scene.terrain_z, scene.terrain_res_m)
    return round(float(np.degrees(np.arctan(np.hypot(gx, gy))).max()), 1)


def _write_flight_acceptance(truth_dir: Path, cfg: Preset, plan, cam_true, origin, dem: Path | None = None) -> None:
    """truth/flight_acceptance.json: the flown block's acceptance checks (the same library the reports
    use) on the true orientations and the true DEM (``dem``, default truth/dem.tif), held to the preset's
    tilt and kappa limits."""
    from aerotri.adjust.flight_acceptance import Terrain, flight_acceptance

    f = cfg.flight
    limits = {"flight_tilt_max_deg": f.max_tilt_deg, "flight_kappa_max_deg": f.max_kappa_dev_deg}
    dem = dem or truth_dir / "dem.tif"
    fa = flight_acceptance(plan.image_id, plan.centre_m + origin, plan.opk_deg, cam_true,
                           Terrain.from_dem(dem, float(origin[2]), source=f"{dem.parent.name}/{dem.name}"),
                           plan.strip, limits=limits)
    for c in fa.failed:
        log.warning(f"flight acceptance: {c['quantity']} {c['value']} {c['unit']} at {c['where']} "
                    f"(limit {c['limit']})")
    (truth_dir / "flight_acceptance.json").write_text(json.dumps(dataclasses.asdict(fa), indent=1) + "\n")


def _check_plan(plan, scene, cfg):
    """Refuse plans whose cameras do not clear the scene (validated presets should never hit this)."""
    z_top = float(scene.terrain_z.max())
    if len(scene.tri_v):
        z_top = max(z_top, float(scene.tri_v[:, :, 2].max()))
    low = plan.centre_m[:, 2].min()
    if low <= z_top + 20.0:
        raise InputError(f"flight.height_above_ground_m = {cfg.flight.height_above_ground_m}: cameras at "
                         f"{low:.0f} m do not clear the highest point of the scene ({z_top:.0f} m)")


def _write_buildings_geojson(path, scene, origin, epsg: int):
    feats = []
    for b in scene.buildings:
        for name, poly in (("footprint", b.footprint), ("roof_outline", b.outline)):
            rings = [[[x + origin[0], y + origin[1]] for x, y in ring.coords]
                     for ring in [poly.exterior] + list(poly.interiors)]
            feats.append(dict(type="Feature", geometry=dict(type="Polygon", coordinates=rings),
                              properties=dict(building_id=b.building_id, part=name, roof=b.roof, shape=b.shape,
                                              eave_z_m=round(b.eave_z_m + origin[2], 3),
                                              ridge_z_m=round(b.ridge_z_m + origin[2], 3))))
    # the legacy crs member: the coordinates are the project's grid, not RFC 7946's WGS 84 (GDAL and QGIS honour it;
    # without it they read UTM metres as degrees)
    crs = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}"}}
    path.write_text(json.dumps(dict(type="FeatureCollection", crs=crs, features=feats)) + "\n")


def write_footprints_gpkg(buildings_geojson, out, crs: str) -> int:
    """The buildings' wall lines (part "footprint" of ``truth/buildings.geojson``) as a
    GeoPackage in ``crs`` (the project's): layer ``footprints``, one Polygon per building with its ``building_id``,
    the cadastral footprints ``ortho rectify --true-ortho --footprints`` takes (stand-ins for BGT or OSM buildings).
    Written atomically; returns the number of footprints."""
    import shapely

    from aerotri.core.vector_files import VectorLayer, write_layers

    feats = [f for f in json.loads(Path(buildings_geojson).read_text())["features"]
             if f["properties"].get("part") == "footprint"]
    geoms = [shapely.geometry.shape(f["geometry"]) for f in feats]
    ids = np.array([int(f["properties"]["building_id"]) for f in feats], np.int64)
    # GDAL stamps the GeoPackage with the time of writing: a fixed stamp keeps the same seed's files the same bytes
    write_layers(out, [VectorLayer("footprints", "Polygon", geoms, {"building_id": ids})], crs=crs,
                 timestamp="2000-01-01T00:00:00.000Z")
    return len(feats)


_README = """Simulated project "{preset}" (aerotri sim, seed {seed}), CRS {crs}, ellipsoidal heights.

project.toml camera.toml gnss.txt   project settings, nominal camera, GNSS antenna positions (with errors)
images/                             {frames} frames, {image_width_px} x {image_height_px} px, GSD {gsd_m:.3f} m
lidar/                              {lidar_strips} LAS strips, {lidar_points} points, unclassified
trajectory/                         strip_NN.txt: each strip's scanner trajectory (time_s x y z roll_deg
                                    pitch_deg heading_deg; lidarctl strips adjust --trajectory)
truth/                              the truth: eo.txt, camera.toml (true interior orientation), dem.tif,
                                    dsm.tif, ortho.tif, lidar/ (true classes, same point order),
                                    roof_corners.csv, buildings.geojson, footprints.gpkg (the
                                    wall lines), checkpoints.csv,
                                    checkpoint_image_points.csv, gnss_truth.toml, frames.csv, truth.json,
                                    flight_acceptance.json
"""


# ----------------------------------------------------------------------------------------------
# Observations only: the block's geometry and its observations, no images, no LiDAR

# Terrain nodes of an observations-only block at most: a larger block gets a coarser truth terrain (a 10,000
# frame demo block, 24 x 22 km, is made at 4.6 m instead of 1 m).
OBS_MAX_TERRAIN_NODES = 25_000_000


@dataclasses.dataclass
class ObservationsBlock:
    """What ``simulate_observations`` made: the block, the observations and where the DEM is."""

    frames: int
    strips: int
    scene_width_m: float
    scene_height_m: float
    terrain_res_m: float
    dem_path: str
    tie_points: int
    tie_observations: int
    control_points: int
    check_points: int
    control_observations: int


def observations_terrain(cfg: Preset, layout, seed: int):
    """The truth terrain of an observations-only block (terrain and ponds of ``build_scene``, same random
    stream; no roads, buildings or trees), at ``terrain_res_m`` or coarser so that it has at most
    ``OBS_MAX_TERRAIN_NODES`` nodes. Returns a ``Scene`` holding the terrain only."""
    from aerotri.sim.scene import Scene, _ponds, build_terrain, scene_counts

    sc = scene_counts(cfg.scene, layout.width_m, layout.height_m)
    res = max(float(sc.terrain_res_m), math.sqrt(layout.width_m * layout.height_m / OBS_MAX_TERRAIN_NODES))
    sc = dataclasses.replace(sc, terrain_res_m=res)
    rng = np.random.default_rng(seed)
    z, steep = build_terrain(sc, layout.width_m, layout.height_m, rng)
    ponds, z, _ = _ponds(sc, z, res, layout.width_m, steep, rng)
    return Scene(layout.width_m, layout.height_m, np.zeros(3), res, z, np.zeros((0, 3, 3)), np.zeros(0, np.int32),
                 np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 5)), ponds, np.zeros((0, 3)),
                 np.zeros(0), [], np.zeros((0, 3)), seed, steep)


def _truth_adjust_table(cfg: Preset, cam_true, cam_nominal) -> dict:
    """The [adjust] settings the truth of a simulated block needs: the self-calibration groups in which the
    true camera differs from the nominal camera.toml (``BrownCamera.SELF_CAL_GROUPS``: pp, radial k1 k2, ...),
    and the GNSS correction per strip that models the antenna errors the preset draws (a drift per strip:
    ``shift_drift``; a shift alone: ``shift``; neither: ``none``)."""
    true, nominal = cam_true.calibration_vector(), cam_nominal.calibration_vector()
    groups = [g for g, idx in cam_true.SELF_CAL_GROUPS.items()
              if not np.allclose(true[list(idx)], nominal[list(idx)], rtol=0.0, atol=1e-12)]
    correction = gnss_correction_of(cfg)
    out = {"self_calibration": groups, "gnss_correction": correction}
    if correction != "none":
        out["gnss_shift_sigma_m"] = gnss_shift_sigma_m(cfg)
    return out


def gnss_correction_of(cfg: Preset) -> str:
    """The GNSS correction per strip (``[adjust] gnss_correction``) that models the antenna errors the preset
    draws: a drift per strip: ``shift_drift``; a shift alone: ``shift``; neither: ``none``."""
    g = cfg.gnss
    return ("shift_drift" if float(g.drift_sigma_m_per_s) > 0.0
            else "shift" if float(g.strip_shift_sigma_m) > 0.0 else "none")


def gnss_shift_sigma_m(cfg: Preset) -> float:
    """The a-priori sigma of a strip's GNSS shift and of its drift's displacement at the strip ends (``[adjust]
    gnss_shift_sigma_m``) that the preset's GNSS errors are drawn with: the larger of the shift sigma and the
    drift sigma times half a strip's flying time (the drift runs from the strip's middle)."""
    g, f = cfg.gnss, cfg.flight
    half_s = 0.5 * (int(f.frames_per_strip) - 1) * block_layout(cfg).base_m / float(f.speed_mps)
    return round(max(float(g.strip_shift_sigma_m), float(g.drift_sigma_m_per_s) * half_s), 3)


def _observations_chain_table(cfg: Preset, cam_true, cam_nominal) -> dict:
    """The preset's stage sections with [adjust] set to what the block's observations need
    (``_truth_adjust_table``): ``aerotri adjust OUT --dem OUT/dem.tif`` without options models the
    errors the block was made with. (The preset's own [chain.adjust] is that of the rendered chain, whose
    first adjustment runs before any control exists.)"""
    chain = {k: dict(v) for k, v in cfg.chain.items()}
    chain["adjust"] = {**chain.get("adjust", {}), **_truth_adjust_table(cfg, cam_true, cam_nominal)}
    return chain


def simulate_observations(cfg: Preset, outdir, force: bool = False, *, tie_sigma_px: float | None = None,
                          tie_points_per_frame: int | None = None, n_control: int = 4, blunder_fraction: float = 0.0,
                          bad_control_shift_m: float = 0.0) -> ObservationsBlock:
    """A block of any size with its tie, control and GNSS observations and a DEM of the truth terrain, from the
    truth geometry alone (no rendering, no LiDAR): project.toml, camera.toml, gnss.txt, dem.tif (the truth
    terrain sampled at its node spacing: the DEM to give ``aerotri adjust --dem``), at/tiepoints.csv,
    control/points.csv, control/image_points.csv and truth/ (eo.txt, camera.toml, gnss_truth.toml,
    frames.csv, truth.json, flight_acceptance.json, observation_blunders.json).

    The flight and the terrain are those of the preset (``simulate`` makes the same terrain for a block of
    at most ``OBS_MAX_TERRAIN_NODES`` terrain nodes); image observations by the collinearity equations of the
    true camera (``observations.write_truth_observations``) with Gaussian noise ``tie_sigma_px``, tie points on
    the truth terrain (about ``tie_points_per_frame`` per frame, each seen in >= 3 frames); both default to
    the preset's ``[observations]`` (``config.PresetObservations``).
    """
    from aerotri.sim.observations import write_truth_observations

    cfg = checked_preset(cfg)
    outdir = Path(outdir)
    refuse_to_replace(outdir, force)
    t_start = time.perf_counter()
    tie_sigma_px = cfg.observations.tie_sigma_px if tie_sigma_px is None else tie_sigma_px
    tie_points_per_frame = (cfg.observations.tie_points_per_frame if tie_points_per_frame is None
                            else tie_points_per_frame)
    seed = int(cfg.preset.seed)
    s_scene, s_flight, _, _ = np.random.SeedSequence(seed).spawn(4)
    epsg = int(cfg.crs.epsg)
    origin = np.array([cfg.crs.origin_e_m, cfg.crs.origin_n_m, cfg.crs.base_height_m])
    layout = block_layout(cfg)
    scene_seed = int(np.random.default_rng(s_scene).integers(0, 2**31 - 1))
    terrain = observations_terrain(cfg, layout, scene_seed)
    plan = plan_frames(cfg, layout, np.random.default_rng(s_flight))
    cam_true, cam_nominal = cameras_from_config(cfg.camera)
    _check_plan(plan, terrain, cfg)
    log.info(f"block of {len(plan.image_id)} frames over {layout.width_m / 1000:.1f} x {layout.height_m / 1000:.1f} km, "
             f"truth terrain at {terrain.terrain_res_m:.2f} m")
    with atomic_dir(outdir) as tmp, stage_block_cache(SIM_CACHE_BYTES):
        (tmp / "truth").mkdir(parents=True, exist_ok=True)
        res = terrain.terrain_res_m
        nx, ny = int(math.floor(layout.width_m / res)), int(math.floor(layout.height_m / res))
        xs = (np.arange(nx) + 0.5) * res

        def dem_rows(r0, r1):
            X, Y = np.meshgrid(xs, layout.height_m - (np.arange(r0, r1) + 0.5) * res)
            return terrain.terrain_height(X, Y) + origin[2]

        _write_geotiff(tmp / "dem.tif", nx, ny, bands=1, dtype=np.float32,
                       transform=from_origin(origin[0], origin[1] + layout.height_m, res, res), epsg=epsg,
                       rows=dem_rows, nodata=-9999.0, compress=str(cfg.truth.compress))
        _write_project_files(tmp, cfg, plan=plan, cam_true=cam_true, cam_nominal=cam_nominal, origin=origin, epsg=epsg,
                             gains=[1.0] * len(plan.image_id),
                             chain=_observations_chain_table(cfg, cam_true, cam_nominal), dem=tmp / "dem.tif")
        _write_flight_acceptance(tmp / "truth", cfg, plan, cam_true, origin, dem=tmp / "dem.tif")
        summary = write_truth_observations(tmp, tie_sigma_px=tie_sigma_px, n_control=n_control,
                                           blunder_fraction=blunder_fraction, bad_control_shift_m=bad_control_shift_m,
                                           seed=seed, tie_points_per_frame=tie_points_per_frame,
                                           dem=tmp / "dem.tif", interpolation="bilinear")
        block = ObservationsBlock(
            frames=len(plan.image_id), strips=int(cfg.flight.strips), scene_width_m=layout.width_m,
            scene_height_m=layout.height_m, terrain_res_m=res, dem_path=str(outdir / "dem.tif"),
            tie_points=summary.n_tie_points, tie_observations=summary.n_tie_observations,
            control_points=summary.n_control, check_points=summary.n_check,
            control_observations=summary.n_control_observations)
        truth = dict(preset=cfg.preset.name, seed=seed, crs=f"EPSG:{epsg}", origin_m=origin.tolist(),
                     observations_only=True, gsd_m=cam_true.gsd_m(cfg.flight.height_above_ground_m),
                     flying_height_above_ground_m=cfg.flight.height_above_ground_m,
                     frames_per_strip=int(cfg.flight.frames_per_strip), image_width_px=cam_true.width,
                     image_height_px=cam_true.height, pixel_um=cam_true.pixel_um, base_m=layout.base_m,
                     strip_spacing_m=layout.strip_spacing_m, **dataclasses.asdict(block))
        (tmp / "truth" / "truth.json").write_text(json.dumps(truth, indent=2, sort_keys=True) + "\n")
        (tmp / "README.txt").write_text(_README_OBS.format(**truth))
    log.info(f"wrote {outdir} in {time.perf_counter() - t_start:.1f} s")
    return block


_README_OBS = """Simulated block "{preset}" (aerotri sim --observations-only, seed {seed}), CRS {crs}, ellipsoidal heights.
No images and no LiDAR: the observations come straight from the truth geometry.

project.toml camera.toml gnss.txt   project settings, nominal camera, GNSS antenna positions (with errors)
dem.tif                             the truth terrain at {terrain_res_m:.2f} m (aerotri adjust --dem dem.tif)
at/tiepoints.csv                    {tie_observations} image observations of {tie_points} tie points
control/                            points.csv ({control_points} control, {check_points} check points), image_points.csv
truth/                              eo.txt, camera.toml (true interior orientation), gnss_truth.toml, frames.csv,
                                    truth.json, flight_acceptance.json, observation_blunders.json
{frames} frames of {image_width_px} x {image_height_px} px in {strips} strips, GSD {gsd_m:.3f} m.
"""
