"""GDAL's block cache during the stages that write rasters (``aerotri.core.gdal_cache``): ortho rectify, mosaic
and check, the simulator, lidarctl rasters.

The clean-checkout suite hung in tests/ortho/test_block_atomic.py (every thread in a futex wait, rectify
temporaries open): each frame task of ``ortho rectify`` entered ``rasterio.Env(GDAL_CACHEMAX=256)`` on its worker
thread. That is 256 bytes, not MB, and GDAL's cache is one per process: overlapping tasks restored each other's
values, leaving the process at 256 bytes for good, and every block access then made one thread flush the dirty
blocks of GeoTIFFs other threads were writing (GDAL does not support that: corrupt blocks, threads waiting on
each other). These tests pin the cache down, and run the concurrent stages in a child process under a timeout,
so that a deadlock fails the test instead of hanging the suite. The simulator and ``lidarctl rasters`` entered
the same kind of Env per writer and per worker thread (the rasters' COG copies, two threads at a time); they set
it once per stage now, and the tests below check it there too.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.env import get_gdal_config

import aerotri.sim.project
import aerotri.sim.raster
import lidarctl.rasters.products
import ortho.block
import ortho.mosaic
from aerotri.core.executor import Executor
from aerotri.core.gdal_cache import stage_block_cache
from aerotri.sim import load_preset, simulate
from lidarctl import synthetic
from lidarctl.io import PointCloud
from ortho.block import RECTIFY_CACHE_BYTES
from ortho.mosaic import MOSAIC_CACHE_BYTES
from ortho.settings import MosaicSettings
from tests.shared_builds import write_synthetic_project

REPO = Path(__file__).resolve().parents[1]


def cache_max_bytes() -> int:
    return int(get_gdal_config("GDAL_CACHEMAX"))


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("gdal_cache") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=5)
    return root


def test_the_stages_set_the_cache_in_bytes_and_leave_it_as_it_was(block, monkeypatch):
    """Inside every frame task (3 at a time on threads) and every mosaic tile the cache is the stage's size in
    bytes; after each stage it is what it was before (with the cache set per task it was 256 bytes inside and
    stayed at 256 bytes after the stage)."""
    before = cache_max_bytes()
    seen_rectify, seen_mosaic = [], []
    to_file = ortho.block.rectify_frame_to_file
    blend = ortho.mosaic._blend_tile

    def recording_to_file(*args, **kwargs):
        seen_rectify.append(cache_max_bytes())
        out = to_file(*args, **kwargs)
        seen_rectify.append(cache_max_bytes())
        return out

    def recording_blend(*args, **kwargs):
        seen_mosaic.append(cache_max_bytes())
        return blend(*args, **kwargs)

    monkeypatch.setattr(ortho.block, "rectify_frame_to_file", recording_to_file)
    monkeypatch.setattr(ortho.mosaic, "_blend_tile", recording_blend)
    with Executor(workers=3) as ex:
        done = ortho.block.rectify_block(block, executor=ex)
        assert len(done.image_ids) == 6
        assert cache_max_bytes() == before
        ortho.mosaic.mosaic_block(block, MosaicSettings(seams="voronoi", tile_px=256), executor=ex)
    assert cache_max_bytes() == before
    assert len(seen_rectify) == 12 and set(seen_rectify) == {RECTIFY_CACHE_BYTES}
    assert seen_mosaic and set(seen_mosaic) == {MOSAIC_CACHE_BYTES}


def test_a_size_in_megabytes_is_refused():
    with pytest.raises(ValueError, match="bytes"):
        with stage_block_cache(256):
            pass


CHILD = textwrap.dedent("""
    import sys
    import numpy as np, rasterio
    from aerotri.core.executor import Executor
    from ortho.block import rectify_block
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings
    root = sys.argv[1]
    for rnd in range(3):
        with Executor(workers=4) as ex:
            rectify_block(root, executor=ex)
            mosaic_block(root, MosaicSettings(seams="voronoi", tile_px=128), executor=ex)
        with rasterio.open(root + "/ortho/mosaic.tif") as ds:
            a = ds.read()
        print(rnd, int(a.astype(np.int64).sum()), flush=True)
""")


def test_concurrent_rectify_and_mosaic_finish_and_agree(block, tmp_path):
    """Three rounds of rectify (4 frame tasks at a time) and mosaic (4 tile threads, small tiles) in a child
    process that must end within the timeout (a deadlock fails here instead of hanging the suite), each round
    giving the same mosaic, which is the mosaic of a synchronous run (corrupt blocks would differ)."""
    import shutil

    root = tmp_path / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    try:
        r = subprocess.run([sys.executable, "-c", CHILD, str(root)], capture_output=True, text=True, timeout=420,
                           cwd=REPO)
    except subprocess.TimeoutExpired:
        pytest.fail("rectify + mosaic with 4 workers did not finish in 420 s (deadlock?)")
    assert r.returncode == 0, r.stderr[-3000:]
    sums = {line.split()[1] for line in r.stdout.split("\n") if line.strip()}
    assert len(sums) == 1, r.stdout
    with Executor("synchronous") as ex:
        ortho.block.rectify_block(root, executor=ex)
        ortho.mosaic.mosaic_block(root, MosaicSettings(seams="voronoi", tile_px=128), executor=ex)
    with rasterio.open(root / "ortho/mosaic.tif") as ds:
        assert str(int(ds.read().astype(np.int64).sum())) in sums


TILED_FRAMES = ["flight.strips=1", "flight.frames_per_strip=2", "render.tile_px=64", "lidar.pulse_rate_hz=2000.0"]


def test_the_simulator_sets_the_cache_once_for_all_its_writers(tmp_path, monkeypatch):
    """Every frame row rendered into its tiled TIFF and every row of tiles of the truth rasters is written with
    the simulator's cache in bytes; after ``simulate`` the cache is what it was before (set here to a size of
    its own, so that a writer leaving GDAL's default behind shows)."""
    seen_frames, seen_truth = [], []
    submit_rows = aerotri.sim.raster.FrameRenderer.submit_rows
    write_rows = aerotri.sim.project._TileRowWriter.write

    def recording_submit_rows(self, *args, **kwargs):
        seen_frames.append(cache_max_bytes())
        return submit_rows(self, *args, **kwargs)

    def recording_write_rows(self, *args, **kwargs):
        seen_truth.append(cache_max_bytes())
        return write_rows(self, *args, **kwargs)

    monkeypatch.setattr(aerotri.sim.raster.FrameRenderer, "submit_rows", recording_submit_rows)
    monkeypatch.setattr(aerotri.sim.project._TileRowWriter, "write", recording_write_rows)
    with stage_block_cache(300 * 2 ** 20):
        simulate(load_preset("tiny", TILED_FRAMES), tmp_path / "sim")
        assert cache_max_bytes() == 300 * 2 ** 20
    assert len(seen_frames) >= 2 * 4 and set(seen_frames) == {aerotri.sim.project.SIM_CACHE_BYTES}
    # dem, dsm, ortho_nir, classes, ortho: at least one row of tiles each
    assert len(seen_truth) >= 5 and set(seen_truth) == {aerotri.sim.project.SIM_CACHE_BYTES}


def test_lidarctl_rasters_set_the_cache_once_not_per_thread(tmp_path, monkeypatch):
    """The tiled rasters: the windows written on the calling thread and the COG copies and the hillshade on two
    worker threads all see the stage's cache in bytes, and the cache set before the stage is there after it
    (each worker thread entered its own Env with the size before)."""
    cloud, truth = synthetic.synthetic_scene(width_m=120.0, density_per_m2=3.0, seed=3, n_buildings=3, n_trees=20)
    las = tmp_path / "c.las"
    synthetic.write_las(las, PointCloud(cloud.x, cloud.y, cloud.z, cloud.intensity, cloud.return_number,
                                        cloud.number_of_returns, truth), crs="EPSG:32632")
    seen = []

    def recording(name, fn):
        def call(*args, **kwargs):
            seen.append((name, cache_max_bytes()))
            out = fn(*args, **kwargs)
            seen.append((name, cache_max_bytes()))
            return out
        monkeypatch.setattr(lidarctl.rasters.products, name, call)

    for name in ("_tiles_to_gtiffs", "_hillshade_png", "rio_copy"):
        recording(name, getattr(lidarctl.rasters.products, name))
    with stage_block_cache(300 * 2 ** 20):
        lidarctl.rasters.products.write_rasters([las], tmp_path / "out", 1.0, tile_px=48, buffer_px=16)
        assert cache_max_bytes() == 300 * 2 ** 20
    assert {n for n, _ in seen} == {"_tiles_to_gtiffs", "_hillshade_png", "rio_copy"}
    assert len([n for n, _ in seen if n == "rio_copy"]) == 2 * len(lidarctl.rasters.products.RASTERS)
    assert {v for _, v in seen} == {lidarctl.rasters.products.RASTERS_CACHE_BYTES}
