"""GDAL's block cache during the ortho stages (``ortho.gdal_cache``).

The clean-checkout suite hung in tests/ortho/test_block_atomic.py (every thread in a futex wait, rectify
temporaries open): each frame task of ``ortho rectify`` entered ``rasterio.Env(GDAL_CACHEMAX=256)`` on its worker
thread. That is 256 bytes, not MB, and GDAL's cache is one per process: overlapping tasks restored each other's
values, leaving the process at 256 bytes for good, and every block access then made one thread flush the dirty
blocks of GeoTIFFs other threads were writing (GDAL does not support that: corrupt blocks, threads waiting on
each other). These tests pin the cache down, and run the concurrent stages in a child process under a timeout,
so that a deadlock fails the test instead of hanging the suite.
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

import ortho.block
import ortho.mosaic
from aerotri.core.executor import Executor
from ortho.gdal_cache import MOSAIC_CACHE_BYTES, RECTIFY_CACHE_BYTES, stage_block_cache
from ortho.settings import MosaicSettings
from ortho.synthetic import write_synthetic_project

REPO = Path(__file__).resolve().parents[2]


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
        index = ortho.block.rectify_block(block, executor=ex)
        assert len(index["frames"]) == 6
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
