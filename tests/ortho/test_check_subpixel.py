"""The DOM check's sub-pixel peak on a slanted road (issue 42, the demo DOM's band of 0.6-1 GSD displacements): a
road's thin edge lines make the NCC surface a narrow ridge along the road; the parabolas through its whole-pixel
samples read a cross-road shift of a fraction of a pixel as up to a pixel along the road. ``refine_shift`` finds the
NCC's peak between the samples."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ortho.patches import MIN_TEXTURE_RATIO, match_patches, refine_shift, texture_ratio

UP = 8  # the scene is drawn 8 x finer than the image, blurred (the camera's point spread) and sampled


def road_image(shift_x_px: float, shift_y_px: float, rows: int = 120, cols: int = 60, slant_deg: float = 10.0,
               blur_px: float = 0.8, seed: int = 0) -> np.ndarray:
    """A road 10 px wide, 10 degrees off north, its edge lines 0.6 px wide and a dashed centre line (4 px of every
    10), over soft ground texture; the scene moved ``shift_x_px`` right and ``shift_y_px`` down; float32 grey."""
    h, w = rows * UP, cols * UP
    y, x = np.mgrid[0:h, 0:w].astype(np.float32) / UP
    x, y = x - shift_x_px, y - shift_y_px
    ground = cv2.GaussianBlur(np.random.default_rng(seed).standard_normal((rows // 4 + 4, cols // 4 + 4))
                              .astype(np.float32), (0, 0), 1.0)
    img = 120.0 + 40.0 * cv2.remap(ground, x / 4 + 2, y / 4 + 2, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    a = math.radians(slant_deg)
    across = (x - (cols / 2 + math.tan(a) * y)) * math.cos(a)
    along = y / math.cos(a) + x * math.sin(a)
    road = np.abs(across) < 5.0
    img[road] = 80.0 + 0.3 * img[road]
    img[np.abs(np.abs(across) - 4.6) < 0.3] = 230.0
    img[(np.abs(across) < 0.35) & (along % 10.0 < 4.0)] = 230.0
    return cv2.GaussianBlur(img, (0, 0), blur_px * UP)[UP // 2::UP, UP // 2::UP]


@pytest.mark.parametrize("shift", [(0.5, -0.375), (-0.375, 0.125), (0.25, 0.0)])
def test_a_slanted_road_measures_its_shift_not_a_slide_along_it(shift):
    ref, dom = road_image(0.0, 0.0), road_image(*shift)
    ratios = [texture_ratio(ref[r:r + 48, 6:54]) for r in range(6, 66, 12)]
    assert MIN_TEXTURE_RATIO < min(ratios) and max(ratios) < 0.2  # kept, as the demo's road patches (0.10-0.16)
    p = match_patches(dom, ref, step_px=12)
    assert len(p) == 6  # every patch along the road measured
    # the parabolas read (0.5, -0.375) as (0.37, -1.13): 0.77 px along the road; (-0.375, 0.125) 0.61 px off
    err = np.hypot(p.dx_px - shift[0], p.dy_px - shift[1])
    assert err.max() < 0.08


def test_refine_shift_finds_the_peak_between_whole_pixels_and_gives_up_at_the_edge():
    ref = road_image(0.0, 0.0, rows=72, cols=72, slant_deg=35.0)
    dom = road_image(0.3, -0.4, rows=72, cols=72, slant_deg=35.0)
    t, window = dom[12:60, 12:60], ref[6:66, 6:66]  # the patch's top-left at (6, 6) in the window unmoved
    x, y = refine_shift(t, window, 6.0, 6.0)
    assert (x, y) == pytest.approx((6.0 - 0.3, 6.0 + 0.4), abs=0.03)
    assert refine_shift(t, window, 6.0, 6.0, max_move_px=0.2) is None  # farther than allowed
    assert refine_shift(t, ref[12:61, 12:61], 0.0, 0.0) is None  # the peak beyond the window's edge
    assert refine_shift(np.full((48, 48), 7.0, np.float32), window, 6.0, 6.0) is None  # nothing to fit


def crop_rows_image(shift_x_px: float, shift_y_px: float, size_px: int = 144, slant_deg: float = 20.0) -> np.ndarray:
    """Crop rows 3 px apart, 20 degrees off the x axis, plants 1.3 px apart along them, over soft ground texture,
    drawn 8 x finer, blurred 0.5 px and averaged into pixels; the scene moved ``shift_x_px`` right and ``shift_y_px``
    down; float32 grey."""
    n = size_px * UP
    y, x = np.mgrid[0:n, 0:n].astype(np.float32) / UP
    x, y = x - shift_x_px, y - shift_y_px
    a = math.radians(slant_deg)
    u, v = x * math.cos(a) + y * math.sin(a), -x * math.sin(a) + y * math.cos(a)
    g = cv2.GaussianBlur(np.random.default_rng(0).standard_normal((size_px // 4 + 8,) * 2).astype(np.float32),
                         (0, 0), 1.0)
    ground = 110.0 + 60.0 * cv2.remap(g, x / 4 + 4, y / 4 + 4, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    img = np.where(((u / 3.0) % 1.0 < 0.45) & ((v / 1.3) % 1.0 < 0.6), 60.0, ground).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 0.5 * UP)
    return img.reshape(size_px, UP, size_px, UP).mean(axis=(1, 3))


@pytest.mark.parametrize("shift", [(-0.45, 0.35), (0.5, 0.5)])
def test_a_periodic_texture_whose_refinement_fails_is_counted_not_measured(shift, monkeypatch):
    # crop rows: the NCC has a peak every row, none single near the whole-pixel one; the refinement leaves (more than
    # 3 px or unsettled) on every patch, and the parabolas it fell back on (before review 20) read 0.7-1.3 px off
    ref, dom = crop_rows_image(0.0, 0.0), crop_rows_image(*shift)
    p = match_patches(dom, ref, step_px=24)
    assert len(p) == 0 and len(p.unsettled_row_px) == len(p.unsettled_col_px) >= 16
    monkeypatch.setattr("ortho.patches.refine_shift", lambda t, w, x0, y0, **k: (x0, y0))  # the parabolas' estimate
    q = match_patches(dom, ref, step_px=24)
    assert len(q) == len(p.unsettled_row_px)
    assert np.hypot(q.dx_px - shift[0], q.dy_px - shift[1]).min() > 0.5


def test_dom_check_reports_the_unsettled_patches(tmp_path):
    """Block by block (halos overlap) each unsettled patch is counted once; dom_report.json says how many and why."""
    import json

    from pyproj import CRS

    from ortho.check import check_against_reference, run_check
    from ortho.synthetic import write_geotiff

    ref, dom = crop_rows_image(0.0, 0.0, size_px=192), crop_rows_image(0.5, 0.5, size_px=192)
    crs = CRS.from_epsg(32649)
    for name, a in (("ref.tif", ref), ("dom.tif", dom)):
        write_geotiff(tmp_path / name, np.clip(np.round(a), 0, 255).astype(np.uint8), 500000.0, 3000000.0, 0.2, crs)
    p, _ = check_against_reference(tmp_path / "dom.tif", tmp_path / "ref.tif", block_px=96)
    rc = set(zip(p.unsettled_row_px.tolist(), p.unsettled_col_px.tolist()))
    assert len(rc) == len(p.unsettled_row_px) >= 9 and len(p) <= 1  # none twice from the blocks' halos
    (tmp_path / "proj").mkdir()
    run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
              out_stem=tmp_path / "dom_report")
    left = json.loads((tmp_path / "dom_report.json").read_text())["left_out_unsettled"]
    q, _ = check_against_reference(tmp_path / "dom.tif", tmp_path / "ref.tif")  # one block, as run_check reads it
    assert left["patches"] == len(q.unsettled_row_px) >= 9 and left["max_refine_px"] == 3.0
    assert left["pct"] == pytest.approx(100.0 * left["patches"] / (left["patches"] + len(q)), abs=0.01)
