"""The mosaic's shortcuts give what the plain computation gives: weights over boxes, frames blended from memory,
OpenCV histograms (issue 41: mosaic at the speed of the machine)."""

from __future__ import annotations

import hashlib
import os

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import Affine

import ortho.mosaic as mosaic_mod
from aerotri.core import limits
from ortho.cli import main
from ortho.grid import OrthoGrid
from tests.shared_builds import write_synthetic_project


def _context(factor: int, feather_px: float) -> mosaic_mod._BlendContext:
    grid = OrthoGrid(rasterio.crs.CRS.from_epsg(32649), 0.0, 0.0, 0.5, 10, 10)
    return mosaic_mod._BlendContext([], [], np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.ones((0, 3)),
                                    np.zeros((0, 2)), grid, factor, int(np.ceil(2 * feather_px)) + factor, feather_px, 3,
                                    "uint8", None, (0, 0))


@pytest.mark.parametrize("factor, feather_px", [(3, 8.0), (4, 8.0), (15, 15.0), (4, 2.0)])
def test_weight_boxes_are_the_whole_tile_weights_cut_to_their_support(factor, feather_px):
    """Every labelled frame's weight over its box, put back into the tile, equals the weight computed over the whole
    tile as the blend did before (label mask blurred, interpolated, cut to the tile); zero outside the box."""
    rng = np.random.default_rng(factor)
    ctx = _context(factor, feather_px)
    th, tw = 200, 170
    r0, c0 = 5 * factor + 2, 7 * factor + 1  # a tile off the cell grid
    halo = ctx.halo
    lr = np.arange(r0 - halo, r0 + th + halo) // factor
    lc = np.arange(c0 - halo, c0 + tw + halo) // factor
    rl, cl = int(lr[0]), int(lc[0])
    shape = (int(lr[-1]) + 1 - rl, int(lc[-1]) + 1 - cl)
    # Voronoi-like labels of a few frames, one of them only in the halo's corner, and unlabelled cells
    seeds = rng.uniform(0, 1, (5, 2)) * shape
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]]
    cells = np.argmin([(rr - y) ** 2 + (cc - x) ** 2 for y, x in seeds], axis=0).astype(np.int32)
    cells[:2, :2] = 7
    cells[-3:, :] = -1
    ks = [int(k) for k in np.unique(cells) if k >= 0]
    boxes = mosaic_mod._weight_boxes(ctx, cells, ks, dr=r0 - rl * factor, dc=c0 - cl * factor, lr=lr - rl, lc=lc - cl,
                                     th=th, tw=tw)
    sigma = max(0.5, feather_px / 2.0)
    checked = smaller = 0
    for k, (y0, y1, x0, x1, wt) in zip(ks, boxes):
        if feather_px >= factor:
            up = (cells.shape[1] * factor, cells.shape[0] * factor)
            dr, dc = r0 - rl * factor, c0 - cl * factor
            whole = cv2.resize(cv2.GaussianBlur((cells == k).view(np.uint8).astype(np.float32), (0, 0), sigma / factor),
                               up, interpolation=cv2.INTER_LINEAR)[dr:dr + th, dc:dc + tw]
        else:
            lab = cells[np.ix_(lr - rl, lc - cl)]
            whole = cv2.GaussianBlur((lab == k).view(np.uint8).astype(np.float32), (0, 0),
                                     sigma)[halo:halo + th, halo:halo + tw]
        placed = np.zeros((th, tw), np.float32)
        if wt is not None:
            placed[y0:y1, x0:x1] = wt
            checked += 1
            smaller += (y1 - y0) * (x1 - x0) < th * tw
        else:
            assert not whole.any()
        np.testing.assert_array_equal(placed, whole)
    assert checked >= 3 and smaller >= 2  # boxes smaller than the tile: the reads they save


def test_window_of_a_decoded_frame_is_the_file_window(tmp_path):
    """Windows inside, across the edge of and beyond a frame read from memory equal those read from its file."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (3, 300, 260)).astype(np.uint8)
    mask = np.zeros((300, 260), np.uint8)
    cv2.circle(mask, (130, 150), 120, 255, -1)
    path = tmp_path / "frame.tif"
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(path, "w", driver="GTiff", width=260, height=300, count=3, dtype="uint8", tiled=True,
                           blockxsize=128, blockysize=128, compress="zstd",
                           crs="EPSG:32649", transform=Affine(0.5, 0, 0, 0, -0.5, 0)) as dst:
            dst.write(img * (mask > 0))
            dst.write_mask(mask)
    with rasterio.open(path) as ds:
        decoded = mosaic_mod.read_planar(ds, 0, 0, ds.width, ds.height)
        for win in ((10, 20, 100, 50), (-30, -5, 80, 90), (200, 250, 120, 100), (300, 10, 20, 20), (0, 0, 260, 300)):
            a_img, a_ok = mosaic_mod.window_of(*decoded, *win)
            b_img, b_ok = mosaic_mod.read_planar(ds, *win)
            np.testing.assert_array_equal(a_img, b_img)
            np.testing.assert_array_equal(a_ok, b_ok)
            a_img[:] = 1  # a copy: the decoded frame is not changed through it
        np.testing.assert_array_equal(decoded[0], ds.read())


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_histograms_count_the_valid_samples_as_numpy_does(dtype, monkeypatch):
    rng = np.random.default_rng(5)
    top = np.iinfo(dtype).max
    img = rng.integers(0, top + 1, (3, 240, 310)).astype(dtype)
    img[:, :7] = top
    ok = rng.random((240, 310)) > 0.4
    bits = 8 * np.dtype(dtype).itemsize
    shift = max(0, bits - 10)
    hist = np.zeros((3, (1 << bits) >> shift), np.int64)
    tops = np.zeros(3, np.int64)
    levels, maxima = np.zeros((3, bits), np.int64), np.zeros(3, np.int64)
    mosaic_mod._add_histogram(hist, tops, img, ok, bits=bits, shift=shift, at_levels=levels, max_sample=maxima)
    for b in range(3):
        v = img[b][ok]
        np.testing.assert_array_equal(hist[b], np.bincount(v >> shift, minlength=hist.shape[1]))
        assert tops[b] == np.count_nonzero(v == top) and maxima[b] == v.max()
        assert [levels[b, n - 1] for n in range(1, bits + 1)] == [np.count_nonzero(v == (1 << n) - 1)
                                                                  for n in range(1, bits + 1)]


def _pixels_sha(path) -> str:
    with rasterio.open(path) as ds:
        return hashlib.sha256(ds.read().tobytes() + ds.read_masks(1).tobytes()).hexdigest()


def test_frames_blended_from_memory_give_the_mosaic_read_from_files(tmp_path, monkeypatch):
    """A small block (frames kept decoded after the seam grid) gives the same mosaic, overviews included, as the
    same block read again from the files by windows; so do other tile sizes."""
    root = tmp_path / "block"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=11)
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    shas = []
    for limit, tile in ((mosaic_mod.DECODED_FRAMES_MAX_BYTES, 1024), (0, 1024), (0, 256)):
        monkeypatch.setattr(mosaic_mod, "DECODED_FRAMES_MAX_BYTES", limit)
        r = CliRunner().invoke(main, ["mosaic", str(root), "--tile-px", str(tile)])
        assert r.exit_code == 0, r.output
        with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
            levels = [_pixels_sha(root / "ortho" / "mosaic.tif")]
            for k in range(len(ds.overviews(1))):
                with rasterio.open(root / "ortho" / "mosaic.tif", overview_level=k) as ov:
                    levels.append(hashlib.sha256(ov.read().tobytes()).hexdigest())
        shas.append(levels)
    assert len(shas[0]) >= 2
    assert shas[0] == shas[1]
    # the tile size changes which tiles are read whole, not the full-resolution pixels
    assert shas[2][0] == shas[0][0]


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.skipif(limits._malloc_trim() is None or not os.path.exists("/proc/self/statm"),
                    reason="needs glibc's malloc_trim and /proc")
def test_freed_heap_memory_goes_back_to_the_system():
    """Memory freed below a block still in use stays in the process until release_freed_memory (the mosaic's
    phases end with it)."""
    chunks = [bytearray(64 * 1024) for _ in range(3000)]  # 196 MB of heap chunks, below glibc's mmap threshold
    for c in chunks:
        c[::4096] = b"\x01" * len(c[::4096])  # touched: resident
    last = chunks[-1]  # the top of the heap stays in use, so free() cannot shrink the heap by itself
    del chunks
    before = _rss_bytes()
    limits.release_freed_memory()
    after = _rss_bytes()
    assert before - after > 100e6, (before, after)
    assert last[0] == 1


def test_mixed_boxes_hold_every_set_pixel_once():
    """The boxes of the feather zone are disjoint, inside the tile, and hold every set pixel (seams across the tile,
    along it, two apart in one strip, a lone pixel, the tile's last rows)."""
    h, w = 300, 257
    mask = np.zeros((h, w), bool)
    cv2.line(mask.view(np.uint8), (0, 10), (256, 290), 1, 20)
    cv2.line(mask.view(np.uint8), (200, 0), (200, 299), 1, 9)
    mask[150, 5] = True
    mask[296:, 100:140] = True
    boxes = mosaic_mod._mixed_boxes(mask)
    count = np.zeros((h, w), np.int32)
    for y0, y1, x0, x1 in boxes:
        assert 0 <= y0 < y1 <= h and 0 <= x0 < x1 <= w
        count[y0:y1, x0:x1] += 1
    assert count.max() == 1
    assert count[mask].min() == 1
    assert count.sum() < 0.5 * h * w  # the dense windows stay near the seams
    assert mosaic_mod._mixed_boxes(np.zeros((64, 64), bool)) == []


def test_feather_zone_by_boxes_is_the_blend_over_the_whole_tile(tmp_path, monkeypatch):
    """The feather zone blended in the boxes of ``_mixed_boxes`` gives the mosaic the blend over one box of the whole
    tile gives (the same sums per pixel, in the same frame order)."""
    root = tmp_path / "block"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=12)
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    shas, zones = [], []

    def whole_tile(mask):
        zones.append(int(np.count_nonzero(mask)))
        return [(0, mask.shape[0], 0, mask.shape[1])] if mask.any() else []

    for whole in (False, True):
        if whole:
            monkeypatch.setattr(mosaic_mod, "_mixed_boxes", whole_tile)
        r = CliRunner().invoke(main, ["mosaic", str(root), "--tile-px", "256"])
        assert r.exit_code == 0, r.output
        shas.append(_pixels_sha(root / "ortho" / "mosaic.tif"))
    assert sum(z > 0 for z in zones) >= 3  # tiles with a feather zone
    assert shas[0] == shas[1]


@pytest.mark.parametrize("reach_px", [3.0, 9.0, 22.0, 41.0])
def test_chamfer_by_blocks_rounds_as_the_whole_distance_transform(reach_px):
    """``_chamfer_at`` (the distance transform by blocks round the pixels asked for) gives the pixels within reach the
    distance of OpenCV's transform of the whole array as ``_hole_distance_px`` uses it (rounded to 0.01 px, capped at
    the reach), the others more than the reach; holes sparse, clustered and none."""
    rng = np.random.default_rng(int(reach_px))
    for density in (0.0, 2e-4, 5e-3, 0.05):
        h, w = (int(v) for v in rng.integers(300, 700, 2))
        hole = rng.random((h, w)) < density
        hole = cv2.dilate(hole.view(np.uint8), np.ones((5, 5), np.uint8)) > 0 if density < 1e-3 else hole
        free = (~hole).view(np.uint8)
        rows, cols = rng.integers(0, h, 4000), rng.integers(0, w, 4000)
        whole = cv2.distanceTransform(free, cv2.DIST_L2, 3)[rows, cols]
        got = mosaic_mod._chamfer_at(free, rows, cols, reach_px, block_px=64)

        def as_used(d):
            return np.minimum(np.round(np.minimum(d, np.float32(reach_px + 1)), 2), np.float32(reach_px))

        assert np.array_equal(as_used(got), as_used(whole))
        near = whole <= reach_px
        assert np.allclose(got[near], whole[near], rtol=0, atol=1e-5)
        assert (got[~near] > reach_px).all()
        if density:
            assert near.sum() > 20  # pixels within reach were checked


def test_tile_frame_boxes_are_the_reads_of_the_boxes(tmp_path):
    """A true ortho's frame read once for a tile (``_TileFrame``: masks, holes and their margin found once, samples on
    demand) gives every box of the tile the samples, validity and validity away from holes that reading that box
    (``_hole_margin``, as the blend did before) gives, and the hole pixels ``FrameHoles.pixels`` finds on a read of the
    window; tiles over the frame's edges, a margin of 3 px."""
    from rasterio.windows import Window

    rng = np.random.default_rng(5)
    factor, m_px, fw, fh, fc, fr = 5, 3, 230, 190, 37, 23
    ok = np.zeros((fh, fw), np.uint8)
    cv2.fillPoly(ok, [np.array([[10, 4], [225, 15], [214, 186], [3, 170]], np.int32)], 1)
    for _ in range(25):  # occlusion holes: small blobs inside the footprint
        y, x = int(rng.integers(20, 170)), int(rng.integers(20, 210))
        ok[y:y + int(rng.integers(1, 12)), x:x + int(rng.integers(1, 12))] = 0
    samples = rng.integers(1, 4096, (1, fh, fw)).astype(np.uint16) * ok
    grid = OrthoGrid(rasterio.crs.CRS.from_epsg(32649), 0.0, 0.0, 0.1, fc + fw + 40, fr + fh + 30)
    path = tmp_path / "frame.tif"
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(
            path, "w", driver="GTiff", width=fw, height=fh, count=1, dtype="uint16", tiled=True, blockxsize=64,
            blockysize=64, compress="zstd", transform=Affine(0.1, 0, fc * 0.1, 0, -0.1, -fr * 0.1)) as dst:
        dst.write(samples)
        dst.write_mask(ok * np.uint8(255))
    # the frame's holes as ``_reduce_frame`` finds them (its window on whole seam cells, framed by invalid pixels)
    rc0, cc0 = fr // factor, fc // factor
    h, w = -(-(fr + fh) // factor) - rc0, -(-(fc + fw) // factor) - cc0
    invalid = np.ones((h * factor + 2, w * factor + 2), np.uint8)
    dy, dx = fr - rc0 * factor, fc - cc0 * factor
    invalid[1 + dy:1 + dy + fh, 1 + dx:1 + dx + fw] = ok == 0
    holes = mosaic_mod.find_holes(invalid, factor, (rc0, cc0))
    assert holes is not None
    ctx = mosaic_mod._BlendContext(["f"], [str(path)], np.array([[fc, fr]]), np.array([[fw, fh]]), np.ones((1, 1)),
                                   np.zeros((1, 2)), grid, factor, 20, 8.0, 1, "uint16", None, (0, 0), [holes], m_px)
    readers = mosaic_mod._FrameReaders()
    try:
        checked_near = 0
        for r0, c0, th, tw in [(0, 0, 128, 128), (128, 128, 128, 128), (0, 128, 100, 170), (200, 0, 43, 300),
                               (60, 20, 97, 161)]:
            tf = mosaic_mod._TileFrame(ctx, readers, 0, r0=r0, c0=c0, th=th, tw=tw)
            for _ in range(12):
                y0, x0 = int(rng.integers(0, th - 1)), int(rng.integers(0, tw - 1))
                y1, x1 = int(rng.integers(y0 + 1, th + 1)), int(rng.integers(x0 + 1, tw + 1))
                (img, away), valid = tf.box(y0, y1, x0, x1)
                (ref_img, ref_away), ref_valid = mosaic_mod._hole_margin(ctx, readers, 0, row=r0 + y0, col=c0 + x0,
                                                                          h=y1 - y0, w=x1 - x0)
                assert np.array_equal(img, ref_img) and np.array_equal(valid, ref_valid)
                assert np.array_equal(away, ref_away)
                assert np.array_equal(tf.masks(y0, y1, x0, x1)[0], ref_away)
                checked_near += int(np.count_nonzero(valid & ~away))
                # the hole pixels round the box, as ``_hole_distance_px`` looks at them
                ya, xa, hh, ww = y0 - m_px - 1, x0 - m_px - 1, y1 - y0 + 2 * m_px + 2, x1 - x0 + 2 * m_px + 2
                ref_ok = mosaic_mod.read_planar(readers.get(str(path)), c0 + xa - fc, r0 + ya - fr, ww, hh)[1]
                assert np.array_equal(tf.holes(ya, xa, hh, ww), holes.pixels(ref_ok, r0 + ya, c0 + xa, factor))
        assert checked_near > 500  # boxes with pixels in a hole margin
        with rasterio.open(path) as ds:  # (the samples came from the file)
            assert np.array_equal(ds.read(window=Window(0, 0, fw, fh)), samples)
    finally:
        readers.close()


def test_under_a_memory_limit_the_seam_grid_gets_coarser_cells(tmp_path, monkeypatch, caplog):
    """The frames' cells on the seam grid are sized from what the process may still take, beside the tiles
    (``MOSAIC_BYTES_PER_SEAM_CELL`` each): with room for about a quarter of them the seam cells are twice as wide
    (recorded as ``seam_factor`` in mosaic.json, said in the log) and the mosaic is written; without a limit the
    seam grid is the one it always was. Before, trial 90's 13,084 x 22,315 px DOM was killed at 1 and 1.5 GiB."""
    import json
    import logging

    root = tmp_path / "block"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=11)
    assert CliRunner().invoke(main, ["rectify", str(root)]).exit_code == 0
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    free = json.loads((root / "ortho" / "mosaic.json").read_text())
    index = mosaic_mod.read_index(root)
    frame_px = sum(g.width * g.height for g in index.grids)
    cells = frame_px / free["seam_factor"] ** 2
    monkeypatch.setattr(mosaic_mod, "MIN_SEAM_CELLS", 1000)
    tiles = mosaic_mod._tile_bytes(1024, 8.0, 3, 1) * mosaic_mod._tiles_in_flight(None)
    monkeypatch.setattr(mosaic_mod, "memory_room_bytes",
                        lambda: tiles + cells / 4 * mosaic_mod.MOSAIC_BYTES_PER_SEAM_CELL)
    with caplog.at_level(logging.INFO, logger="ortho.mosaic"):
        r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    limited = json.loads((root / "ortho" / "mosaic.json").read_text())
    assert limited["seam_factor"] in (2 * free["seam_factor"], 2 * free["seam_factor"] + 1)
    assert "without the limit) to fit in the" in caplog.text + r.output
