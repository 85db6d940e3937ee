"""Scale-out and the fast rectification path: tile threads, per-frame and per-mosaic-tile Dask tasks give
byte-identical outputs on every scheduler; memory-mapped frames rectify as decoded ones; pooled tiles
handed to a sink equal the assembled ortho."""

from __future__ import annotations

import hashlib
import json
import shutil

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from aerotri.core.executor import Executor
from aerotri.geom.images import read_native
from ortho.block import rectify_block
from ortho.cli import main
from ortho.mosaic import mosaic_block
from ortho.settings import MosaicSettings, RectifySettings
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def small_block(tmp_path_factory):
    root = tmp_path_factory.mktemp("ortho_parallel")
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=4, seed=11)
    return root


def _digests(root):
    files = sorted((root / "ortho" / "frames").glob("*.tif")) + [root / "ortho" / "mosaic.tif", root / "ortho" / "seams.tif"]
    d = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in files}
    # the index names the DEM and EO files by their paths, which differ between the copies of the project
    index = (root / "ortho" / "frames" / "index.json").read_text().replace(str(root), "ROOT")
    d["index.json"] = hashlib.sha256(index.encode()).hexdigest()
    return d


def test_outputs_identical_on_every_scheduler(small_block, tmp_path):
    """Frames as Dask tasks (rectify) and output tiles as Dask tasks (mosaic): the same bytes with the
    synchronous scheduler, local threads and a local cluster of 2 worker processes."""
    digests = {}
    for scheduler in ("synchronous", None, "local:2"):
        root = tmp_path / str(scheduler).replace(":", "_")
        shutil.copytree(small_block, root)
        with Executor(scheduler, 2) as ex:
            done = rectify_block(root, executor=ex)
            # small tiles: several mosaic tiles and batches even on this small block
            mosaic_block(root, MosaicSettings(tile_px=256), executor=ex)
        assert len(done.image_ids) == 4 and len(done.grids) == 4
        digests[scheduler] = _digests(root)
    assert len(digests["synchronous"]) == 7
    assert digests["synchronous"] == digests[None] == digests["local:2"]
    with rasterio.open(tmp_path / "synchronous" / "ortho" / "mosaic.tif") as ds:
        assert ds.width > 512 and ds.height > 512  # more than one batch of 256 px tiles
        assert (ds.read_masks(1) > 0).mean() > 0.8


def test_offsets_identical_on_every_scheduler(small_block, tmp_path):
    """The mosaic with offsets (i42-offsets: they and the shadow toe go to the Dask tasks in the context file): the same
    bytes on local threads and as tasks on a local cluster of 2 worker processes."""
    root = tmp_path / "rectified"
    shutil.copytree(small_block, root)
    rectify_block(root)
    digests = {}
    for scheduler in (None, "local:2"):
        copy = tmp_path / str(scheduler).replace(":", "_")
        shutil.copytree(root, copy)
        with Executor(scheduler, 2) as ex:
            mosaic_block(copy, MosaicSettings(tile_px=256, offsets=True), executor=ex)
        assert json.loads((copy / "ortho" / "mosaic.json").read_text())["offsets"] is not None
        digests[scheduler] = hashlib.sha256((copy / "ortho" / "mosaic.tif").read_bytes()).hexdigest()
    assert digests[None] == digests["local:2"]


def test_cli_scheduler_option(small_block, tmp_path):
    root = tmp_path / "cli"
    shutil.copytree(small_block, root)
    r = CliRunner().invoke(main, ["rectify", str(root), "--scheduler", "synchronous", "--frame-compress", "zstd-fast"])
    assert r.exit_code == 0, r.output
    with rasterio.open(root / "ortho" / "frames" / "s01_001.tif") as ds:
        assert ds.compression.name.lower() == "zstd" and ds.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR") is None
        fast = ds.read()
    r = CliRunner().invoke(main, ["rectify", str(root), "--frame-compress", "none"])
    assert r.exit_code == 0, r.output
    with rasterio.open(root / "ortho" / "frames" / "s01_001.tif") as ds:
        assert ds.compression is None and np.array_equal(ds.read(), fast)
    r = CliRunner().invoke(main, ["mosaic", str(root), "--workers", "2", "--tile-px", "512"])
    assert r.exit_code == 0, r.output
    assert (root / "ortho" / "mosaic.tif").exists()
    r = CliRunner().invoke(main, ["rectify", str(root), "--scheduler", "local:x"])
    assert r.exit_code == 2 and "local:N" in r.output


def _first_frame(root, res_m: float):
    """The first frame of ``root`` with its camera, orientation (C, R), DEM and an ortho grid of ``res_m``."""
    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.eo import read_eo
    from ortho.dem import read_height_raster
    from ortho.grid import GridToProject, parse_crs
    from ortho.rectify import frame_grid

    crs = parse_crs("EPSG:32649")
    cam = BrownCamera.read(root / "camera.toml")
    eo = read_eo(root / "at" / "eo.txt")
    dem = read_height_raster(root / "lidar_out" / "dem.tif", crs)
    img, _ = read_native(root / "images" / "s01_001.tif", (cam.width, cam.height))
    C, R = eo.centre_m[0], eo.rotation(0)
    grid = frame_grid(cam, C, R, dem, res_m, crs, to_project=GridToProject(crs, crs))
    return img, cam, C, R, dem, grid, GridToProject(crs, crs)


def test_tile_threads_and_sink_do_not_change_the_ortho(small_block):
    from ortho.rectify import rectify_frame

    img, cam, C, R, dem, grid, _ = _first_frame(small_block, 0.2)
    one, m1 = rectify_frame(img, cam, C, R, dem, grid, tile_px=128, threads=1)
    three, m3 = rectify_frame(img, cam, C, R, dem, grid, tile_px=128, threads=3)
    assert np.array_equal(one, three) and np.array_equal(m1, m3)
    assert 0.3 < (m1 > 0).mean() < 1.0
    # tiles handed to a sink, bands first, from the pooled buffers (reused after the sink returns)
    got = np.zeros((img.shape[2], grid.height, grid.width), img.dtype)
    got_mask = np.zeros((grid.height, grid.width), np.uint8)

    def sink(r0, c0, o, m):
        got[:, r0:r0 + m.shape[0], c0:c0 + m.shape[1]] = o
        got_mask[r0:r0 + m.shape[0], c0:c0 + m.shape[1]] = m

    none, _ = rectify_frame(img, cam, C, R, dem, grid, tile_px=128, threads=2, sink=sink, sink_bands_first=True)
    assert none is None
    assert np.array_equal(np.moveaxis(got, 0, -1), one) and np.array_equal(got_mask, m1)
    # cubic: pixels outside the frame stay 0 also with the pooled, reused buffers
    cub, mc = rectify_frame(img, cam, C, R, dem, grid, interpolation="cubic", tile_px=128, threads=2)
    assert np.all(cub[mc == 0] == 0) and np.array_equal(mc, m1)


def test_a_frame_orthos_bytes_do_not_depend_on_gdals_block_cache(small_block, tmp_path):
    """GDAL places a block in a GeoTIFF when its cache flushes it; the cache is the process's, shared with the other
    frames' tasks, so a frame ortho written straight from its tiles had its blocks in another order whenever the
    cache was fuller (the 2 x 2 DMC block's threads and LocalCluster runs, and a threads run again: other bytes, the
    same samples). Written through ``ordered_copy`` the file is the same bytes under a cache that holds a few
    blocks and one that holds the frame, with the samples and mask of the in-memory rectification."""
    from ortho.block import rectify_frame_to_file
    from ortho.rectify import rectify_frame

    # 6 cm cells: 3 x 4 blocks of 512 px and 3 bands, more than a 1 MiB cache holds
    img, cam, C, R, dem, grid, to_project = _first_frame(small_block, 0.06)
    assert grid.width > 1024 and grid.height > 1024
    digests = []
    for cache_bytes in (2 ** 20, 2 ** 30, 2 ** 20):
        out = tmp_path / f"cache_{cache_bytes}_{len(digests)}.tif"
        with rasterio.Env(GDAL_CACHEMAX=cache_bytes):
            rectify_frame_to_file(out, img, [1, 2, 3], cam, C, R, heights=dem, grid=grid, interpolation="bilinear",
                                  to_project=to_project, tags={"FRAME": "s01_001"}, overviews=True)
        digests.append(hashlib.sha256(out.read_bytes()).hexdigest())
    assert digests[0] == digests[1] == digests[2]
    want, want_mask = rectify_frame(img, cam, C, R, dem, grid)
    with rasterio.open(out) as ds:
        assert np.array_equal(np.moveaxis(ds.read(), 0, -1), want)
        assert np.array_equal(ds.dataset_mask() > 0, want_mask > 0)
        assert ds.tags()["FRAME"] == "s01_001" and ds.overviews(1) and ds.compression.name.lower() == "zstd"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"cache_{c}_{i}.tif" for i, c in
                                                                enumerate((2 ** 20, 2 ** 30, 2 ** 20)))


def test_mapped_and_decoded_frames_give_the_same_ortho(small_block, tmp_path):
    """A frame stored uncompressed (mapped, R, G, B) and LZW (decoded by cv2, B, G, R) rectify alike."""
    from aerotri.geom.camera import BrownCamera

    cam = BrownCamera.read(small_block / "camera.toml")
    img, order = read_native(small_block / "images" / "s01_001.tif", (cam.width, cam.height))
    assert order == [3, 2, 1] and not isinstance(img, np.memmap)
    root = tmp_path / "raw"
    shutil.copytree(small_block, root)
    for f in (root / "images").glob("*.tif"):
        cv2.imwrite(str(f), cv2.imread(str(f), cv2.IMREAD_UNCHANGED), [cv2.IMWRITE_TIFF_COMPRESSION, 1])
    mapped, order = read_native(root / "images" / "s01_001.tif", (cam.width, cam.height))
    assert isinstance(mapped, np.memmap) and order == [1, 2, 3]
    assert np.array_equal(np.asarray(mapped), img[:, :, ::-1])
    rectify_block(root, frames=["s01_001"])
    rectify_block(small_block, frames=["s01_001"])
    with rasterio.open(root / "ortho/frames/s01_001.tif") as a, rasterio.open(small_block / "ortho/frames/s01_001.tif") as b:
        assert np.array_equal(a.read(), b.read()) and np.array_equal(a.read_masks(1), b.read_masks(1))


def test_a_resolution_far_finer_than_the_gsd_is_warned_about(small_block, tmp_path):
    import logging

    class Collect(logging.Handler):
        def emit(self, record):
            messages.append(record.getMessage())

    root = tmp_path / "p"
    shutil.copytree(small_block, root)
    gsd = rectify_block(root, frames=["s01_001"]).res_m  # the default: the GSD
    messages: list[str] = []
    handler = Collect(logging.WARNING)
    logging.getLogger("ortho").addHandler(handler)  # the CLIs' logging set-up may stop propagation
    try:
        rectify_block(root, RectifySettings(res_m=0.2 * gsd), frames=["s01_001"])
        assert any("finer than half the block's ground sample distance" in m for m in messages), messages
        messages.clear()
        rectify_block(root, RectifySettings(res_m=0.8 * gsd), frames=["s01_001"])
        assert not any("ground sample distance" in m for m in messages)
    finally:
        logging.getLogger("ortho").removeHandler(handler)


def test_frames_the_adjustment_left_out_are_not_rectified(tmp_path):
    """A frame without EO stops the stage, unless the project's adjustment left it out (a part of the block
    that no tie point connects and that has no datum): then the others are rectified and it is skipped."""
    import json

    from aerotri.core.errors import InputError
    from ortho.block import load_block

    root = tmp_path / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=3, buildings=2, seed=3)
    eo = root / "at" / "eo.txt"
    lines = eo.read_text().splitlines()
    data = [ln for ln in lines if ln and not ln.startswith("#")]
    dropped = data[-1].split()[0]
    eo.write_text("\n".join(ln for ln in lines if ln != data[-1]) + "\n")
    with pytest.raises(InputError, match=f"no exterior orientation for frame.*{dropped}"):
        load_block(root)
    (root / "at" / "report.json").write_text(json.dumps(
        {"components": {"adjusted": 1, "left_out": [{"images": [dropped], "reason": "no control"}]}}))
    blk = load_block(root)
    assert dropped not in blk.images and len(blk.images) == 2


@pytest.mark.parametrize("compression", ["zstd", "zstd-fast", "none"])
def test_frame_files_hold_the_library_ortho(small_block, tmp_path, compression):
    """Every --frame-compress choice stores exactly the ortho and mask of ``rectify_frame`` in memory (R, G,
    B bands; mask 255 where valid), whatever the writer does to be fast (tiles written while the next
    are computed, compression threads)."""
    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.eo import read_eo
    from aerotri.geom.images import read_rgb
    from ortho.block import _plane_footprint_bounds, read_index
    from ortho.dem import height_range, open_height_raster, read_height_window
    from ortho.grid import parse_crs
    from ortho.rectify import rectify_frame

    root = tmp_path / "p"
    shutil.copytree(small_block, root)
    gsd = rectify_block(root, frames=["s01_002"]).res_m
    # finer than the GSD: a grid of several 512 px blocks and 1024 px compute tiles
    done = rectify_block(root, RectifySettings(res_m=0.55 * gsd, compression=compression), frames=["s01_002"])
    grid = done.grid("s01_002")
    assert grid == read_index(root).grid("s01_002")  # the grid index.json records
    assert grid.width > 1024 and grid.height > 512
    cam = BrownCamera.read(root / "camera.toml")
    eo = read_eo(root / "at" / "eo.txt")
    k = eo.row("s01_002")
    C, R = eo.centre_m[k], eo.rotation(k)
    # the DEM window the stage reads (bilinear heights on the grid depend on the window's origin in the
    # last of cv2's 1/32 cell position bits, so the whole DEM would differ by 1 in a few pixels)
    with open_height_raster(root / "lidar_out" / "dem.tif", parse_crs("EPSG:32649")) as ds:
        zlo, zhi = height_range(ds)
        dem = read_height_window(ds, _plane_footprint_bounds(cam, C, R, zlo - 5.0, zhi + 5.0, "s01_002"),
                                 margin_m=4 * ds.transform.a)
    img = read_rgb(root / "images" / "s01_002.tif", (cam.width, cam.height))
    want, want_mask = rectify_frame(img, cam, C, R, dem, grid)
    with rasterio.open(root / "ortho" / "frames" / "s01_002.tif") as ds:
        assert (ds.width, ds.height, ds.count) == (grid.width, grid.height, 3) and ds.block_shapes[0] == (512, 512)
        got, got_mask = ds.read(), ds.read_masks(1)
        assert all(np.array_equal(ds.read_masks(b), got_mask) for b in (2, 3))
    assert 0.3 < (want_mask > 0).mean() < 1.0
    assert np.array_equal(got_mask, want_mask)
    assert np.array_equal(np.moveaxis(got, 0, -1), want)


def test_frames_read_by_windows_give_the_same_ortho(small_block, tmp_path, monkeypatch):
    """A frame decoded larger than WINDOWED_FRAME_BYTES (a full-size 16-bit DMC frame: 637 MB) is read by
    windows as the tiles sample it, so memory follows the tiles: the same frame orthos as from the frames
    decoded whole, bilinear and cubic (the kernel's reach read around every tile)."""
    import ortho.block as B

    opened = []

    class CountingFrameFile(B.FrameFile):
        def __init__(self, path):
            opened.append(path)
            super().__init__(path)

    for interpolation in ("bilinear", "cubic"):
        whole, windows = tmp_path / f"whole_{interpolation}", tmp_path / f"windows_{interpolation}"
        shutil.copytree(small_block, whole)
        shutil.copytree(small_block, windows)
        rectify_block(whole, RectifySettings(interpolation=interpolation))
        with monkeypatch.context() as m:
            m.setattr(B, "WINDOWED_FRAME_BYTES", 0)
            m.setattr(B, "FrameFile", CountingFrameFile)
            rectify_block(windows, RectifySettings(interpolation=interpolation))
        names = sorted(p.name for p in (whole / "ortho" / "frames").glob("*.tif"))
        assert len(names) == 4
        for name in names:
            with rasterio.open(whole / "ortho" / "frames" / name) as a, \
                    rasterio.open(windows / "ortho" / "frames" / name) as b:
                assert np.array_equal(a.read(), b.read()) and np.array_equal(a.read_masks(1), b.read_masks(1))
                assert 0.3 < (a.read_masks(1) > 0).mean() < 1.0
    assert len(opened) == 8


def test_a_jpeg_ycbcr_frame_read_whole_or_by_windows_gives_the_same_ortho(small_block, tmp_path, monkeypatch):
    """Review 28: a JPEG-compressed YCbCr (4:2:0) TIFF frame, as the NGI DMC frames come, was decoded whole by
    OpenCV (libjpeg-turbo) and by windows by GDAL (IJG libjpeg 9), which upsample the chroma differently: 36-57 % of
    the frame's pixels differed (up to 52 DN), and its two orthos on ~68 % of the valid cells. Both now decode
    through GDAL: the same ortho to the bit, bilinear and cubic."""
    import ortho.block as B

    root = tmp_path / "jpeg"
    shutil.copytree(small_block, root, ignore=shutil.ignore_patterns("ortho"))
    frame = root / "images" / "s01_002.tif"
    with rasterio.open(frame) as ds:
        a, prof = ds.read(), ds.profile
    prof.update(compress="jpeg", photometric="ycbcr", tiled=True, blockxsize=256, blockysize=256)
    frame.unlink()
    with rasterio.open(frame, "w", **prof) as out:
        out.write(a)
    with rasterio.open(frame) as ds:
        decoded = np.moveaxis(ds.read(), 0, -1)
    assert np.array_equal(read_native(frame)[0], decoded)  # whole, as GDAL decodes it by windows
    assert (np.abs(cv2.imread(str(frame))[:, :, ::-1].astype(int) - decoded).max(2) > 0).mean() > 0.05  # not as OpenCV
    for interpolation in ("bilinear", "cubic"):
        whole, windows = tmp_path / f"whole_{interpolation}", tmp_path / f"windows_{interpolation}"
        shutil.copytree(root, whole)
        shutil.copytree(root, windows)
        rectify_block(whole, RectifySettings(interpolation=interpolation), frames=["s01_002"])
        with monkeypatch.context() as m:
            m.setattr(B, "WINDOWED_FRAME_BYTES", 0)
            rectify_block(windows, RectifySettings(interpolation=interpolation), frames=["s01_002"])
        with rasterio.open(whole / "ortho" / "frames" / "s01_002.tif") as x, \
                rasterio.open(windows / "ortho" / "frames" / "s01_002.tif") as y:
            assert 0.3 < (x.read_masks(1) > 0).mean() < 1.0
            assert np.array_equal(x.read(), y.read()) and np.array_equal(x.read_masks(1), y.read_masks(1))


def test_frame_overviews_are_an_option_and_leave_the_full_resolution_as_it_is(small_block, tmp_path):
    """Trial 8: a frame ortho had no overviews (a GIS reads all of it to show it whole). ``[rectify] overviews``
    (``ortho rectify --frame-overviews``) adds internal ones, averaged over the valid samples, with the mask's; the
    full-resolution samples and mask are those of the frame without them. Off by default (bench/frame_overviews.py:
    0.7 x the rectification's CPU on a full-size DMC frame)."""
    from ortho.grid import overview_factors

    plain, with_ovr = tmp_path / "plain", tmp_path / "ovr"
    shutil.copytree(small_block, plain)
    shutil.copytree(small_block, with_ovr)
    res = rectify_block(plain, frames=["s01_002"]).res_m * 0.4  # several 512 px blocks: two levels
    rectify_block(plain, RectifySettings(res_m=res), frames=["s01_002"])
    r = CliRunner().invoke(main, ["rectify", str(with_ovr), "--frames", "s01_002", "--res-m", f"{res!r}",
                                  "--frame-overviews"])
    assert r.exit_code == 0, r.output
    a, b = (p / "ortho" / "frames" / "s01_002.tif" for p in (plain, with_ovr))
    with rasterio.open(a) as x, rasterio.open(b) as y:
        assert x.overviews(1) == [] and y.overviews(1) == overview_factors(y.width, y.height) != []
        assert np.array_equal(x.read(), y.read()) and np.array_equal(x.read_masks(1), y.read_masks(1))
        f = y.overviews(1)[0]
        got = y.read(1, out_shape=(y.height // f, y.width // f))  # from the overview
        got_mask = y.read_masks(1, out_shape=(y.height // f, y.width // f))
        full, valid = x.read(1).astype(float), x.read_masks(1) > 0
    h, w = got.shape
    blocks = (lambda v: v[:h * f, :w * f].reshape(h, f, w, f).sum((1, 3)))
    n = blocks(valid)
    want = blocks(full * valid) / np.maximum(n, 1)
    inside = got_mask > 0
    assert inside.mean() > 0.3 and (n[inside] > 0).all()  # the mask's overview: where any sample is valid
    # the average of the valid samples only (no nodata 0 pulled in at the edge of the ground seen)
    assert np.abs(got[inside] - want[inside]).max() <= 0.5 + 1e-9
    index = json.loads((with_ovr / "ortho" / "frames" / "index.json").read_text())
    assert index["settings"]["overviews"]["value"] is True
