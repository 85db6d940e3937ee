"""The true ortho's cheaper occlusion steps give what the steps they replace gave (issue 42, at most 2x the
conventional rectify per MP): the z-buffer test of a tile in the project CRS without the anchors, the march's bounds
in one pass, the march's hint probes that skip columns below the ray, and the block's height rasters kept open."""

from __future__ import annotations

import hashlib
import json
import shutil
import warnings

import numpy as np
import pytest
import rasterio
from pyproj import CRS

from aerotri.geom.rotation import rotation_matrix_opk
from ortho.block import load_block
from ortho.dem import HeightRaster, read_height_raster
from ortho.footprints import with_crown_base
from ortho.grid import GridToProject, OrthoGrid
from ortho.rectify import (FrameGeometry, fixed_point_maps, frame_grid, frame_zbuffer, heights_on_grid, march_bound,
                           occlusion_mask, zbuffer_occlusion, zbuffer_occlusion_from_maps)
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("occlusion_cost") / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=20, seed=7)
    return root


def _frame(block, frame):
    b = load_block(block)
    i = b.eo.row(frame)
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(block / "truth" / "dsm.tif", b.project_crs, "DSM")
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = frame_grid(b.camera, C, R, dsm, 0.2, b.project_crs, to_project=to_project)
    return FrameGeometry(b.camera, C, R), dsm, grid, to_project


@pytest.mark.parametrize("frame", ["s01_001", "s01_002"])
def test_the_zbuffer_test_in_the_project_crs_marks_what_the_anchors_test_marks(block, frame):
    """The occlusion test on its own surface (``--occlusion-dsm``): the z-buffer holds that surface (lower by up to a
    metre here), the points tested are the ortho's, at the DSM's heights the tile's maps were made at. The test that
    reads their image positions from the maps marks the imaged points the test through the anchors marks, and gives
    the march its hint there. The maps hold positions to 1/32 px (cv2's fixed point): a point rounded onto the border
    of two z-buffer cells may fall in the other cell, and only such points differ."""
    geometry, dsm, grid, to_project = _frame(block, frame)
    rng = np.random.default_rng(3)
    lower = HeightRaster((dsm.heights_m - rng.uniform(0.0, 1.0, dsm.heights_m.shape)).astype(np.float32),
                         dsm.x_left_m, dsm.y_top_m, dsm.res_m, dsm.crs, dsm.source)
    zbuffer = frame_zbuffer(geometry, lower, grid, to_project, 256)
    marked = 0
    for r0, c0 in [(0, 0), (256, 512), (grid.height - 300, grid.width - 300)]:
        tile = grid.window(c0, r0, 300, 300)
        map_int, map_frac, mask, z, anchors = fixed_point_maps(geometry, dsm, tile, to_project)
        expected = zbuffer_occlusion(geometry, zbuffer, z, anchors) & (mask > 0)
        near = np.zeros(z.shape, np.float32)
        got = zbuffer_occlusion_from_maps(geometry, zbuffer, tile, map_int, mask, z, out=np.ones(z.shape, np.bool_),
                                          near_share=near)
        differ = got != expected
        frac = map_frac[differ].astype(np.int64)  # cv2: y index * 32 + x index of the 1/32 px fraction
        position = map_int[differ] + np.column_stack([frac % 32, frac // 32]) / 32.0
        cells = position / zbuffer.cell_px
        assert (np.abs(cells - np.round(cells)).min(axis=1) * zbuffer.cell_px <= 1 / 32).all()
        assert differ.sum() <= 0.01 * max(int(expected.sum()), 1)
        assert (near[got] > 0).all() and (near[got] < 1).all()
        marked += int(got.sum())
    assert marked > 1000


def _block_max_reference(z: np.ndarray, block: int) -> np.ndarray:
    """The highest non-NaN height of each block's cells and the row and column after it (-inf: none)."""
    dh, dw = z.shape
    out = np.full((-(-dh // block), -(-dw // block)), -np.inf, np.float32)
    for bi in range(out.shape[0]):
        for bj in range(out.shape[1]):
            w = z[bi * block:bi * block + block + 1, bj * block:bj * block + block + 1]
            if np.isfinite(w).any() or (w == -np.inf).any():
                out[bi, bj] = np.nanmax(w)
    return out


@pytest.mark.parametrize("shape", [(1, 1), (16, 16), (17, 129), (300, 257)])
def test_the_march_bounds_are_the_highest_heights_each_block_reads(shape):
    """Block maxima by 16 and 128 cells, the slabs' tops raised by the tolerance, NaN left out; the highest of all
    NaN where every cell is."""
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    for nan_share in (0.0, 0.4, 1.0):
        z = rng.normal(20.0, 8.0, shape).astype(np.float32)
        z[rng.random(shape) < nan_share] = np.nan
        slab_top = np.where(rng.random(shape) < 0.1, rng.normal(25.0, 8.0, shape), -np.inf).astype(np.float32)
        occluder = type("Occluder", (), {"slab_top_m": slab_top})()
        for occ, surface in ((None, z), (occluder, np.fmax(z, slab_top + np.float32(0.3)))):
            bound = march_bound(HeightRaster(z, 0.0, 0.0, 0.5, None, "z"), occluder=occ, tolerance_m=0.3)
            assert np.array_equal(bound.block_max_m, _block_max_reference(surface, 16))
            assert np.array_equal(bound.coarse_max_m, _block_max_reference(surface, 128))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all NaN: nanmax warns and gives NaN
                expected = float(np.nanmax(surface))
            assert bound.max_m == expected or (np.isnan(expected) and np.isnan(bound.max_m))


def test_the_march_with_any_hint_gives_the_march_without(block):
    """The hint's walk (from two cells before where the ray meets the hinted depth, then from the start up to there,
    then on) tests every cell once: with the z-buffer's hint, a random one and none, the same points occluded (every
    imaged point a candidate), on the DSM's columns and with slabs (crowns over a third of the cells, their bases a
    random depth under their tops: rays that pass beneath them walk on)."""
    geometry, dsm, grid, to_project = _frame(block, "s01_002")
    map_int, _, mask, z, anchors = fixed_point_maps(geometry, dsm, grid, to_project)
    zbuffer = frame_zbuffer(geometry, dsm, grid, to_project, 256)
    near = np.zeros(z.shape, np.float32)
    zbuffer_occlusion_from_maps(geometry, zbuffer, grid, map_int, mask, z, out=np.zeros(z.shape, np.bool_),
                                near_share=near)
    rng = np.random.default_rng(5)
    top = dsm.heights_m
    crown_base = np.where(rng.random(top.shape) < 0.33, top - rng.uniform(0.0, 15.0, top.shape), np.nan)
    for occluder in (None, with_crown_base(None, top, crown_base.astype(np.float32))):
        none = occlusion_mask(geometry, dsm, grid, z, anchors, occluder=occluder)
        assert (none & (mask > 0)).mean() > 0.002
        # (a random share near 1: the hinted depth a few cells from the point, before and after its occluder)
        for hint in (near, rng.uniform(0.0, 1.0, z.shape).astype(np.float32),
                     rng.uniform(0.97, 1.0, z.shape).astype(np.float32)):
            assert np.array_equal(occlusion_mask(geometry, dsm, grid, z, anchors, near_share=hint, occluder=occluder),
                                  none)


def _sha256_of_frames(root) -> dict:
    out = {}
    for f in sorted((root / "ortho" / "frames").glob("*.tif")):
        with rasterio.open(f) as ds:
            h = hashlib.sha256(ds.read().tobytes())
            h.update(ds.read_masks(1).tobytes())
            out[f.stem] = h.hexdigest()
    return out


def test_the_height_rasters_kept_open_for_the_block_give_the_frames_opened_per_frame(block, tmp_path, monkeypatch):
    """The DEM, DSM and occlusion DSM kept open while the block's frames are rectified (GDAL decodes their blocks
    once): the same frame orthos as each frame opening them itself; closed when the block is done."""
    import contextlib

    import ortho.block
    from ortho.block import rectify_block
    from ortho.settings import RectifySettings

    shutil.copy2(block / "truth" / "dsm.tif", tmp_path / "occlusion.tif")
    opened = []
    inner = ortho.block.open_height_raster

    def counted(path, *a, **k):
        opened.append(str(path))
        return inner(path, *a, **k)

    monkeypatch.setattr(ortho.block, "open_height_raster", counted)
    frames, opens = {}, {}
    for name in ("kept", "per_frame"):
        opened.clear()
        root = tmp_path / name
        shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
        settings = RectifySettings(true_ortho=True, dem=str(root / "truth" / "dem.tif"),
                                   dsm=str(root / "truth" / "dsm.tif"), occlusion_dsm=str(tmp_path / "occlusion.tif"))
        if name == "per_frame":
            monkeypatch.setattr(ortho.block, "_rasters_kept_open", contextlib.nullcontext)
        rectify_block(root, settings)
        assert not ortho.block._kept_rasters
        frames[name] = _sha256_of_frames(root)
        opens[name] = opened.count(str(tmp_path / "occlusion.tif"))
        assert json.loads((root / "ortho" / "frames" / "index.json").read_text())["occlusion_dsm"]
    assert len(frames["kept"]) == 2 and frames["kept"] == frames["per_frame"]
    # the block's check of the file and its vertical CRS's height operation, then once for both frames, or once a frame
    assert opens == {"kept": 3, "per_frame": 4}


def test_the_dsm_given_again_as_the_occlusion_dsm_gives_the_true_ortho_on_the_dsm_alone(block, tmp_path):
    """The occlusion test on its own raster tests the ortho's points, at the DSM's heights the tile's maps were made
    at: given a copy of the DSM as the occlusion DSM, the z-buffer, its test (read from the maps) and the march are
    those of the true ortho on the DSM alone, to the byte. (The test projected every pixel again when the occlusion
    DSM was another raster: 38 of the demo's 21.4 M valid pixels came out otherwise.)"""
    from ortho.block import rectify_block
    from ortho.settings import RectifySettings

    shutil.copy2(block / "truth" / "dsm.tif", tmp_path / "dsm_copy.tif")
    frames = {}
    for name, occlusion in (("alone", None), ("copy", str(tmp_path / "dsm_copy.tif"))):
        root = tmp_path / name
        shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
        rectify_block(root, RectifySettings(true_ortho=True, dem=str(root / "truth" / "dem.tif"),
                                            dsm=str(root / "truth" / "dsm.tif"), occlusion_dsm=occlusion))
        frames[name] = _sha256_of_frames(root)
    assert len(frames["alone"]) == 2 and frames["copy"] == frames["alone"]


def test_the_hints_walk_finds_an_occluder_before_after_and_beyond_the_hinted_depth():
    """A 20 m wall 10-30 cells east of a row of ground points, the camera east of it: every point occluded; with a
    hinted depth 3, 5, 8 or 30 cells from each point (before the wall: the third part of the walk finds it; beyond
    it: the second) and without (``ortho.rectify_kernels._occlusion_kernel``), the same; and with the wall a row of
    crowns from 15 m up (the nearer points' rays pass beneath them), the same."""
    import types

    heights = np.zeros((100, 100), np.float32)
    heights[:, 60:62] = 20.0
    crs = CRS.from_epsg(32649)
    dsm = HeightRaster(heights, 0.0, 50.0, 0.5, crs, "dsm")
    grid = OrthoGrid(crs, 10.0, 30.0, 0.5, 20, 20)  # columns 20 .. 40 of the DSM
    ax, ay = np.meshgrid(10.25 + 0.5 * np.arange(21), 29.75 - 0.5 * np.arange(21))
    anchors = (ax, ay, 1.0)
    geometry = types.SimpleNamespace(centre_m=np.array([130.0, 25.0, 100.0]))
    z = np.zeros((20, 20), np.float32)
    hd_m = 130.0 - ax[:20, :20]
    crowns = with_crown_base(None, heights, np.where(heights > 0, np.float32(15.0), np.float32(np.nan)))
    for occluder in (None, crowns):
        none = occlusion_mask(geometry, dsm, grid, z, anchors, occluder=occluder)
        assert none.all() if occluder is None else 0 < none.sum() < none.size
        for cells in (3.0, 5.0, 8.0, 30.0):
            share = (1.0 - cells * dsm.res_m / hd_m).astype(np.float32)
            assert np.array_equal(occlusion_mask(geometry, dsm, grid, z, anchors, near_share=share,
                                                 occluder=occluder), none)
