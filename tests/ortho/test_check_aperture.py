"""The DOM check's texture test (the aperture problem): a patch of stripes shifted along the stripes cannot show the
shift (its NCC peak slides along them) and is left out and counted; a patch of two-dimensional texture is kept and
measures its shift."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyproj import CRS

from ortho.check import check_against_reference, run_check
from ortho.patches import MIN_TEXTURE_RATIO, match_patches, texture_ratio
from ortho.synthetic import textured_orthophoto, write_geotiff

RES = 0.2
SHIFT_ROWS = 3  # the DOM shows the reference's content 3 px further down (south)


def stripes(height: int, width: int, seed: int = 0) -> np.ndarray:
    """Vertical stripes (grey levels vary with the column only, irregularly), uint8."""
    rng = np.random.default_rng(seed)
    profile = np.convolve(rng.normal(128.0, 60.0, width + 8), np.ones(3) / 3.0, mode="same")[4:-4]
    return np.clip(np.tile(profile, (height, 1)), 0, 255).astype(np.uint8)


def shifted_down(a: np.ndarray, rows: int) -> np.ndarray:
    """The content of ``a`` moved ``rows`` px down (the top rows repeat the first row)."""
    return np.concatenate([np.repeat(a[:1], rows, axis=0), a[:-rows]], axis=0)


def pair(ref: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(DOM, reference): the DOM shows ``ref`` shifted down by SHIFT_ROWS; each with its own noise (2 grey levels),
    as two renderings of the ground are never equal."""
    rng = np.random.default_rng(seed)
    noisy = lambda a: np.clip(a + rng.normal(0.0, 2.0, a.shape), 0, 255).astype(np.uint8)
    return noisy(shifted_down(ref.astype(float), SHIFT_ROWS)), noisy(ref.astype(float))


def test_texture_ratio_tells_stripes_from_texture():
    assert texture_ratio(stripes(48, 48)) < 0.01
    assert texture_ratio(stripes(48, 48).T) < 0.01
    assert texture_ratio(textured_orthophoto(48, 48, 1, seed=3)[:, :, 0]) > 0.3
    assert texture_ratio(np.full((48, 48), 100.0)) == 0.0  # no gradient: no direction fixed


def test_stripes_shifted_along_them_are_left_out_texture_is_measured():
    ref = np.concatenate([stripes(200, 200), textured_orthophoto(200, 200, 1, seed=2)[:, :, 0]], axis=1)
    dom, ref = pair(ref, seed=1)
    p = match_patches(dom, ref, res_m=RES)
    on_stripes = p.one_direction_col_px < 200
    assert len(p.one_direction_col_px) >= 9 and on_stripes.all()  # every stripe patch left out, no texture patch
    assert len(p) >= 9 and (p.col_px > 200).all()  # the textured half: kept and measured
    assert np.abs(p.dy_px - SHIFT_ROWS).max() < 0.15
    assert np.abs(p.dx_px).max() < 0.15
    assert p.dn_m.mean() == pytest.approx(-SHIFT_ROWS * RES, abs=0.02)
    # without the test the stripe patches are measured, and their shift along the stripes is the noise's
    q = match_patches(dom, ref, res_m=RES, min_texture_ratio=0.0)
    assert len(q.one_direction_col_px) == 0
    stripe_dy = q.dy_px[q.col_px < 200]
    assert len(stripe_dy) >= 9 and np.sqrt(np.mean((stripe_dy - SHIFT_ROWS) ** 2)) > 2.0


def test_dom_check_counts_the_patches_left_out(tmp_path):
    """Block by block (halos overlap): each patch left out is counted once; the report says how many and why."""
    crs = CRS.from_epsg(32649)
    ref = np.concatenate([stripes(300, 300, seed=4), textured_orthophoto(300, 300, 1, seed=5)[:, :, 0]], axis=1)
    dom, ref = pair(ref, seed=6)
    write_geotiff(tmp_path / "ref.tif", ref, 500000.0, 3000000.0, RES, crs)
    write_geotiff(tmp_path / "dom.tif", dom, 500000.0, 3000000.0, RES, crs)
    p, _ = check_against_reference(tmp_path / "dom.tif", tmp_path / "ref.tif", block_px=128)
    rc = set(zip(p.one_direction_row_px.tolist(), p.one_direction_col_px.tolist()))
    assert len(rc) == len(p.one_direction_row_px) >= 25  # none twice from the blocks' halos
    assert all(c < 300 for _, c in rc) and (p.col_px > 300).all() and len(p) >= 25
    assert np.abs(p.dy_px - SHIFT_ROWS).max() < 0.2

    p, _ = check_against_reference(tmp_path / "dom.tif", tmp_path / "ref.tif")  # one block, as run_check reads it
    (tmp_path / "proj").mkdir()
    rep = run_check(tmp_path / "proj", reference_path=tmp_path / "ref.tif", dom_path=tmp_path / "dom.tif",
                    out_stem=tmp_path / "dom_report")
    doc = json.loads((tmp_path / "dom_report.json").read_text())
    left = doc["left_out_one_direction"]
    assert left["patches"] == rep.one_direction == len(p.one_direction_row_px)
    assert left["min_texture_ratio"] == MIN_TEXTURE_RATIO and "one direction" in left["why"]
    assert left["pct"] == rep.one_direction_pct == pytest.approx(100.0 * left["patches"] / (left["patches"] + len(p)),
                                                                  abs=0.01)
    assert rep.displacement.count == len(p)
    assert rep.displacement.rms_xy_m == pytest.approx(SHIFT_ROWS * RES, abs=0.03)
