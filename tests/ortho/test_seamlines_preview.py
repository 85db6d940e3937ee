"""The preview of the seamlines over the DOM (``ortho/seamlines_preview.png``, issue 42): written by ``ortho mosaic``
with its other outputs, at most 2000 px, seams in magenta where seams.tif has them, nodata inside the block hatched,
outside white, a legend strip below."""

from __future__ import annotations

import cv2
import numpy as np
import rasterio
from click.testing import CliRunner
from rasterio.transform import Affine

from ortho.cli import main
from ortho.seamlines_preview import _labels, _legend
from ortho.seamlines_preview import (HATCH_RGB, LEGEND_PX, OUTSIDE_RGB, SEAM_RGB, preview_shape, render_preview,
                                     seam_pixels, write_seamlines_preview)
from tests.shared_builds import write_synthetic_project


def _read_png(path):
    return cv2.imread(str(path), cv2.IMREAD_COLOR)[..., ::-1]


def _is(rgb, colour):
    return np.all(rgb == np.array(colour, np.uint8), axis=-1)


def test_ortho_mosaic_writes_the_preview_with_the_seams_where_seams_tif_has_them(tmp_path):
    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=5)
    for args in (["rectify", str(root)], ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    png = _read_png(root / "ortho" / "seamlines_preview.png")
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(root / "ortho" / "seams.tif") as s:
        h, w, step = preview_shape(ds.width, ds.height)
        ok = ds.read_masks(1, out_shape=(h, w)) > 0
        labels = s.read(1)
        factor = int(round(s.transform.a / ds.res[0]))
    assert png.shape[0] == h + LEGEND_PX and png.shape[1] >= w and max(h, w) <= 2000
    img = png[:h, :w]
    # the seams of seams.tif on the preview grid (the seam cell holding each pixel's centre)
    rows = np.minimum(((np.arange(h) + 0.5) * step // factor).astype(int), labels.shape[0] - 1)
    cols = np.minimum(((np.arange(w) + 0.5) * step // factor).astype(int), labels.shape[1] - 1)
    expected = seam_pixels(labels[np.ix_(rows, cols)]) & ok
    drawn = _is(img, SEAM_RGB)
    assert expected.sum() > 50  # 4 frames: several seams
    assert drawn[expected].all()
    # magenta only on the seams (drawn 2 px wide: the expected pixel or its neighbour up or left)
    near = cv2.dilate(expected.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    assert not (drawn & ~near).any()
    # outside the block white; away from the seams the DOM's own samples
    assert _is(img, OUTSIDE_RGB)[~ok].all()
    assert not _is(png[h:], SEAM_RGB).all()  # the legend strip has text and swatches
    # the mosaic writes it from the stage's level of the preview's size while the COG is copied: the same bytes as the
    # preview of the finished COG
    again = tmp_path / "again.png"
    write_seamlines_preview(again, root / "ortho" / "mosaic.tif", labels, factor)
    assert again.read_bytes() == (root / "ortho" / "seamlines_preview.png").read_bytes()


def _write_mosaic(path, valid):
    h, w = valid.shape
    rng = np.random.default_rng(0)
    img = rng.integers(40, 200, (3, h, w), dtype=np.uint8)
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=3, dtype="uint8", crs="EPSG:32649",
                       transform=Affine(0.5, 0.0, 452000.0, 0.0, -0.5, 3407000.0)) as ds:
        ds.write(img)
        ds.write_mask(valid.astype(np.uint8) * 255)


def test_preview_is_reduced_hatches_nodata_inside_and_marks_the_seam(tmp_path):
    # 4400 x 600 px: reduced by 3 to 1467 x 200; a hole inside the block, the left edge outside it
    h, w = 600, 4400
    valid = np.ones((h, w), bool)
    valid[:, :300] = False  # outside the block (reaches the edge)
    valid[240:360, 2900:3300] = False  # no frame sees it (inside)
    _write_mosaic(tmp_path / "m.tif", valid)
    labels = np.zeros((h // 4, w // 4), np.int32)  # seam grid of 4 px cells: frame 0 west, 1 east of x = 2000 px
    labels[:, 500:] = 1
    labels[:, :75] = -1
    rgb = render_preview(tmp_path / "m.tif", labels, 4)
    ph, pw, step = preview_shape(w, h)
    assert (step, ph, pw) == (3, 200, 1467) and rgb.shape == (ph + LEGEND_PX, pw, 3)
    img = rgb[:ph]
    seam_cols = np.flatnonzero(_is(img, SEAM_RGB).all(axis=0))
    assert set(seam_cols) <= {666, 667} and len(seam_cols) >= 1  # x = 2000 px / 3
    hole = img[85:115, 970:1095]
    assert (_is(hole, HATCH_RGB[0]) | _is(hole, HATCH_RGB[1])).all()
    assert _is(hole, HATCH_RGB[0]).mean() > 0.3 and _is(hole, HATCH_RGB[1]).mean() > 0.3
    assert _is(img[:, :95], OUTSIDE_RGB).all()
    assert not _is(img[:, 110:600], SEAM_RGB).any() and not _is(img[:, 110:600], OUTSIDE_RGB).all()


def test_12_bit_data_in_16_bit_samples_fill_the_preview_range():
    """A DMC's 12-bit data in 16-bit samples fills the preview's range (it would be black divided by 257), as does
    full 16-bit data and dim 8-bit data. Invalid cells (their sample says nothing) do not set the stretch."""
    from ortho.seamlines_preview import _to_rgb8, stretch_range

    twelve = np.tile(np.array([[[0, 1024, 2048, 4095]]], np.uint16), 50)
    rgb, stretch = _to_rgb8(twelve)
    assert stretch == (0.0, 4095.0) and rgb[0, :4, 0].tolist() == [0, 64, 128, 255]
    full = np.tile(np.array([[[0, 4095, 40000, 65535]]], np.uint16), 50)
    assert _to_rgb8(full)[0][0, :4, 0].tolist() == [0, 16, 156, 255]
    assert stretch_range(full, valid=np.tile([True, True, False, False], 50)[None]) == (0.0, 4095.0)
    # 8-bit data stretched the same way (review 25: the 8-bit DOM of 12-bit frames, round(v x 255 / 4095), shown as
    # it is, was as dim as the 16-bit one before its stretch)
    eight = np.tile(np.array([[[0, 16, 32, 64]]], np.uint8), 50)
    rgb, stretch = _to_rgb8(eight)
    assert stretch == (0.0, 64.0) and rgb[0, :4, 0].tolist() == [0, 64, 128, 255]


def test_a_dom_of_one_value_is_shown_in_its_full_range_not_black():
    """A uniform DOM, or one value on more than 99 % of it (snow, water, a fill), collapses the percentile stretch
    (lo = hi: everything at that value black, review 26); the samples' full range is used then, and named."""
    from ortho.seamlines_preview import _to_rgb8

    rgb, stretch = _to_rgb8(np.full((3, 40, 50), 120, np.uint8))
    assert stretch == (0.0, 255.0) and (rgb == 120).all()
    mostly = np.full((1, 100, 100), 120, np.uint8)
    mostly[0, 0, :50] = (0, 255) * 25  # 0.5 % of the cells other values
    rgb, stretch = _to_rgb8(mostly)
    assert stretch == (0.0, 255.0) and rgb[50, 50].tolist() == [120] * 3 and rgb[0, 1].tolist() == [255] * 3
    # 16-bit: the full range of the data's bit depth (a DMC's 12 bits: 2000 mid-grey; 13 bits above 4095)
    rgb, stretch = _to_rgb8(np.full((1, 30, 30), 2000, np.uint16))
    assert stretch == (0.0, 4095.0) and (rgb == 125).all()
    assert _to_rgb8(np.full((1, 30, 30), 4311, np.uint16))[1] == (0.0, 8191.0)
    assert _labels((0.0, 255.0), 8)[-1] == "shown: 8-bit samples 0-255 full range"
    # a spread of a few levels is still stretched (the percentiles 4 levels apart or more)
    spread = np.tile(np.arange(110, 130, dtype=np.uint8), (1, 20, 1))
    assert _to_rgb8(spread)[1] == (110.0, 129.0)


def test_balanced_12_bit_dom_is_stretched_not_darkened(tmp_path):
    """The 2 x 2 DMC block's DOM (trial 8): 12-bit frames balanced by gains up to 1.05 reach 4311, more than 12 bits;
    by the fewest bits holding the largest sample (14) the preview was a quarter as bright (median grey 14 of 255,
    the DOM black to the eye). 16-bit samples are now stretched from their 0.5th to 99.5th percentile (the legend
    states the range)."""
    rng = np.random.default_rng(3)
    h, w = 300, 200
    img = np.clip(rng.gamma(6.0, 160.0, (1, h, w)), 160, 4311).astype(np.uint16)  # median about 900, like the DOM
    img[0, :3, :3] = 4311
    valid = np.ones((h, w), bool)
    with rasterio.open(tmp_path / "m.tif", "w", driver="GTiff", width=w, height=h, count=1, dtype="uint16",
                       crs="EPSG:32649", transform=Affine(0.1, 0.0, 452000.0, 0.0, -0.1, 3407000.0)) as ds:
        ds.write(img)
        ds.write_mask(valid.astype(np.uint8) * 255)
    rgb = render_preview(tmp_path / "m.tif", np.zeros((h // 4, w // 4), np.int32), 4)
    grey = rgb[:h, :w, 0]
    lo, hi = np.percentile(img, [0.5, 99.5])
    assert 80 <= np.median(grey) <= 140
    assert (grey[img[0] <= lo] == 0).all() and (grey[img[0] >= hi] == 255).all()
    # the legend names the stretch (more text than a legend without one)
    assert (rgb[h:] < 128).all(axis=-1).sum() > (_legend(w) < 128).all(axis=-1).sum() + 100
    # the same DOM made 8-bit from the white level (--output-bits 8: round(v x 255 / 4095), median about 56) is
    # stretched the same way (review 25: shown as it was, dim), its legend naming its 8-bit range
    img8 = np.clip(np.rint(img.astype(float) * 255 / 4095), 0, 255).astype(np.uint8)  # as the DOM clips
    assert np.median(img8) < 70
    with rasterio.open(tmp_path / "m8.tif", "w", driver="GTiff", width=w, height=h, count=1, dtype="uint8",
                       crs="EPSG:32649", transform=Affine(0.1, 0.0, 452000.0, 0.0, -0.1, 3407000.0)) as ds:
        ds.write(img8)
        ds.write_mask(valid.astype(np.uint8) * 255)
    eight = render_preview(tmp_path / "m8.tif", np.zeros((h // 4, w // 4), np.int32), 4)
    assert 80 <= np.median(eight[:h, :w, 0]) <= 140
    assert np.abs(eight[:h, :w, 0].astype(int) - grey).max() <= 12  # the 16-bit preview's greys, to 8-bit steps
    lo8, hi8 = np.percentile(img8, [0.5, 99.5])
    assert _labels((lo8, hi8), 8)[-1].startswith(f"shown: 8-bit samples {lo8:.0f}-{hi8:.0f} stretched")


def test_the_preview_hatches_the_cells_mosaic_json_counts_as_seen_by_no_frame(tmp_path):
    """A DEM that covers half the block: the frames' ground beyond it is nodata that mosaic.json counts as seen by
    no frame (it lies inside their footprints) and the preview hatches (it was white, "outside the block", where it
    reaches the mosaic's edge: Brighton Beach on its ODM DEM, 59.8 % counted, 0.006 % hatched)."""
    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=0, seed=5)
    dem = root / "lidar_out" / "dem.tif"
    with rasterio.open(dem) as ds:
        a, prof = ds.read(1), ds.profile
    a[:, a.shape[1] // 2:] = np.nan   # the eastern half of the DEM gone
    prof.update(nodata=np.nan)
    dem.unlink()
    with rasterio.open(dem, "w", **prof) as out:
        out.write(a, 1)
    for args in (["rectify", str(root)], ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    summary = __import__("json").loads((root / "ortho" / "mosaic.json").read_text())
    png = _read_png(root / "ortho" / "seamlines_preview.png")
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        h, w, step = preview_shape(ds.width, ds.height)
        res = ds.res[0]
    img = png[:h, :w]
    hatched = _is(img, HATCH_RGB[0]) | _is(img, HATCH_RGB[1])
    hatched_m2 = hatched.sum() * (step * res) ** 2
    counted_m2 = summary["area_seen_by_no_frame_m2"]
    assert summary["share_seen_by_no_frame"] > 0.15   # a large part of the frames' ground has no DEM
    assert abs(hatched_m2 - counted_m2) < 0.05 * counted_m2, (hatched_m2, counted_m2)
    # those cells are where the DEM has no heights (its eastern half), counted apart and judged in the report
    # (Brighton on its cloud's DEM: 44.7 % of the mosaic empty, the report "pass (2 passed)")
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(dem) as d:
        cut_x = d.bounds.left + (a.shape[1] // 2) * d.res[0]
        empty = ds.read_masks(1) == 0
        east = (ds.transform.c + (np.arange(ds.width) + 0.5) * ds.res[0]) > cut_x - 2 * d.res[0]
    # every counted cell lies in the DEM's empty half: at most the empty cells there (the block's part of them)
    assert 0.9 * summary["cells_seen_by_no_frame"] <= summary["cells_without_heights"] \
        <= int(np.count_nonzero(empty[:, east]))
    assert summary["share_without_heights"] > 0.15 and summary["surfaces_counted"] == ["lidar_out/dem.tif"]
    assert summary["surfaces_cover_every_frame"] is False
    assert "of the block where the surface the frames were rectified on has no heights (dem.tif)" in r.stderr
    # a conventional DOM: no occlusion named among the causes (trial s105 F7)
    assert "seen by no frame (over DEM nodata or the frames' own nodata)" in r.stderr and "occluded" not in r.stderr


def test_a_south_oriented_grid_is_previewed_north_up_and_says_so(tmp_path):
    """New-user trial (NGI in Lo25, EPSG:2051, westing / southing): GDAL stores such a DOM with row 0 at its southern
    and column 0 at its eastern edge, and the preview showed it so, south-up, without a word. Turned 180 degrees now,
    the legend says so; a north-up grid's preview is as before."""
    h, w = 300, 400
    valid = np.ones((h, w), bool)
    valid[:60, :80] = False  # a corner outside the block: row 0, column 0 (Lo25: the south-east corner)
    labels = np.zeros((h // 4, w // 4), np.int32)
    pictures = {}
    for crs, x0, y0 in (("EPSG:32649", 452000.0, 3407000.0), ("EPSG:2051", 53130.0, 3735156.0)):
        path = tmp_path / f"{crs[5:]}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="uint8", crs=crs,
                           transform=Affine(0.5, 0.0, x0, 0.0, -0.5, y0)) as ds:
            ds.write(np.full((1, h, w), 120, np.uint8))
            ds.write_mask(valid.astype(np.uint8) * 255)
        pictures[crs] = render_preview(path, labels, 4)
    utm, lo = pictures["EPSG:32649"], pictures["EPSG:2051"]
    assert _is(utm[:60, :80], OUTSIDE_RGB).all() and not _is(utm[h - 60:h, w - 80:w], OUTSIDE_RGB).any()
    assert _is(lo[h - 60:h, w - 80:w], OUTSIDE_RGB).all() and not _is(lo[:60, :80], OUTSIDE_RGB).any()  # south-east
    assert "north up" not in " ".join(_labels(None)) and _labels(None, turned=True)[-1].startswith("north up")
    # the note is written: the legend strip holds more dark text pixels
    assert (lo[h:] < 128).all(axis=-1).sum() > (utm[h:] < 128).all(axis=-1).sum() + 100


def test_cells_without_heights_are_counted_at_their_centres_and_estimated_above_the_sample_cap(tmp_path):
    """``unseen_without_heights``: the unseen cells over a DEM's nodata or beyond it, read at their centres in the
    DEM's own grid (another cell size, another origin); above ``max_samples`` every k-th cell, the count scaled."""
    from ortho.unseen import unseen_without_heights

    dem = tmp_path / "dem.tif"
    z = np.full((100, 120), 10.0, np.float32)
    z[:, 60:] = -9999.0   # the eastern half without heights
    with rasterio.open(dem, "w", driver="GTiff", width=120, height=100, count=1, dtype="float32", crs="EPSG:32649",
                       transform=Affine(1.0, 0.0, 452000.0, 0.0, -1.0, 3407000.0), nodata=-9999.0) as ds:
        ds.write(z, 1)
    # the mosaic's grid: 0.5 m cells, 10 m wider to the east than the DEM (beyond it: no heights either)
    t = Affine(0.5, 0.0, 452000.0, 0.0, -0.5, 3407000.0)
    unseen = np.ones((200, 260), bool)
    x_centre = 452000.0 + (np.arange(260) + 0.5) * 0.5
    want = int(np.count_nonzero(x_centre >= 452060.0)) * 200
    assert unseen_without_heights(unseen, t, "EPSG:32649", [dem]) == want
    est = unseen_without_heights(unseen, t, "EPSG:32649", [dem], max_samples=5_000)
    assert abs(est - want) <= 0.02 * want
    assert unseen_without_heights(unseen, t, "EPSG:32649", []) == 0
