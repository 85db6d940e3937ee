"""Mosaic, seamlines, gain balancing and true ortho on a synthetic block with box buildings (known truth)."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.warp import reproject
from scipy import ndimage

from ortho.check import check_against_reference, displacement_statistics
from ortho.cli import main
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("ortho_block")
    info = write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=20, seed=7)
    # one frame 20 % darker (exposure difference) for the gain balancing
    p = root / "images" / "s01_002.tif"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), np.clip(np.rint(img * 0.8), 0, 255).astype(np.uint8))
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    return root, info


def _labels_on(path_seams, like):
    with rasterio.open(path_seams) as s:
        lab = np.full(like.shape, -1, np.int32)
        reproject(s.read(1), lab, src_transform=s.transform, src_crs=s.crs, dst_transform=like.transform,
                  dst_crs=s.crs, resampling=rasterio.enums.Resampling.nearest, src_nodata=-1, dst_nodata=-1)
    return lab


def _buildings_cut(root):
    """Buildings (connected nDSM > 2.5 m) that contain more than one frame label."""
    with rasterio.open(root / "truth" / "ndsm.tif") as nd:
        b, n = ndimage.label(nd.read(1) > 2.5)
        lab = _labels_on(root / "ortho" / "seams.tif", nd)
    cut = 0
    for k in range(1, n + 1):
        ls = set(np.unique(lab[b == k])) - {-1}
        cut += len(ls) > 1
    return cut, n


def test_mosaic_is_a_cog_matching_truth_with_seams_around_buildings(block):
    root, info = block
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--no-balance"])
    assert r.exit_code == 0, r.output
    voronoi_cut, n_buildings = _buildings_cut(root)
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    least_cost_cut, _ = _buildings_cut(root)
    assert n_buildings == 20
    assert voronoi_cut >= 4  # the straight Voronoi seams cut buildings ...
    assert least_cost_cut <= 1  # ... the least-cost seams go round them (one straddles the block edge)

    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ds.block_shapes[0] == (512, 512)
        assert ds.overviews(1)
        assert ds.count == 3 and ds.crs.to_epsg() == 32649
        assert 0.7 < (ds.dataset_mask() > 0).mean() < 1.0

    geo = json.loads((root / "ortho" / "seamlines.geojson").read_text())
    regions = [f for f in geo["features"] if f["properties"]["kind"] == "frame_region"]
    lines = [f for f in geo["features"] if f["properties"]["kind"] == "seamline"]
    assert sorted(f["properties"]["image_id"] for f in regions) == sorted(info.eo.image_id)
    assert len(lines) >= 5

    # accuracy on ground patches and misalignment across seams
    r = CliRunner().invoke(main, ["check", str(root), "--reference", str(root / "truth" / "ortho.tif"), "--ndsm",
                                  str(root / "truth" / "ndsm.tif")])
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "ortho" / "dom_report.json").read_text())
    assert rep["displacement"]["count"] > 100
    assert rep["displacement"]["rms_xy_gsd"] < 0.15
    seams = rep["seams"]
    # enough to measure (51 with the flat world's frames, 47 on the earth, before the seams' texture floor 0.5)
    assert seams["patches"] > 25 and seams["min_texture_ratio"] == 0.5
    assert seams["patches"] + seams["one_direction"] + seams["unsettled"] > 40  # those left out counted
    assert seams["rms_px"] < 0.3

    # gain balancing brought the darkened frame back: its gain is about 1 / 0.8 of its neighbours'
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    g = {k: np.mean(v) for k, v in summary["gains"].items()}
    others = np.mean([v for k, v in g.items() if k != "s01_002"])
    assert g["s01_002"] / others == pytest.approx(1.25, abs=0.04)


def test_mosaic_radiometry_follows_truth(block):
    """After balancing, the mosaic's grey level matches the truth orthophoto in every frame region."""
    root, _ = block
    if not (root / "ortho" / "mosaic.tif").exists():  # when run alone (or on another worker than the first test)
        assert CliRunner().invoke(main, ["mosaic", str(root)]).exit_code == 0
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(root / "truth" / "ortho.tif") as t:
        m = ds.read().astype(float).mean(axis=0)
        valid = ds.dataset_mask() > 0
        truth = np.zeros(m.shape)
        reproject(t.read().astype(float).mean(axis=0), truth, src_transform=t.transform, src_crs=t.crs,
                  dst_transform=ds.transform, dst_crs=ds.crs)
        lab = _labels_on(root / "ortho" / "seams.tif", ds)
    ratios = [m[valid & (lab == k)].mean() / truth[valid & (lab == k)].mean() for k in range(6) if (valid & (lab == k)).any()]
    assert max(ratios) / min(ratios) < 1.04


def test_true_ortho_removes_building_lean(block, tmp_path):
    root, info = block
    true_root = tmp_path / "true"
    shutil.copytree(root, true_root, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(true_root), "--true-ortho", "--dsm", str(true_root / "truth" / "dsm.tif")])
    assert r.exit_code == 0, r.output
    with rasterio.open(true_root / "ortho" / "frames" / "s01_001.tif") as ds:
        occluded_or_outside = (ds.dataset_mask() == 0).mean()
    with rasterio.open(root / "ortho" / "frames" / "s01_001.tif") as ds:
        outside = (ds.dataset_mask() == 0).mean()
    assert occluded_or_outside > outside + 0.002  # occluded ground behind buildings is masked
    r = CliRunner().invoke(main, ["mosaic", str(true_root)])
    assert r.exit_code == 0, r.output

    def wrong_on_buildings(mosaic_path):
        with rasterio.open(mosaic_path) as ds, rasterio.open(root / "truth" / "ortho.tif") as t, \
                rasterio.open(root / "truth" / "ndsm.tif") as nd:
            m = ds.read().astype(float)
            valid = ds.dataset_mask() > 0
            truth = np.zeros(m.shape)
            reproject(t.read().astype(float), truth, src_transform=t.transform, src_crs=t.crs,
                      dst_transform=ds.transform, dst_crs=ds.crs)
            h = np.zeros(m.shape[1:])
            reproject(nd.read(1), h, src_transform=nd.transform, src_crs=nd.crs, dst_transform=ds.transform,
                      dst_crs=ds.crs)
        near = ndimage.binary_dilation(h > 2.5, iterations=15) & valid  # roofs and the ground they hide
        return float((np.abs(m - truth).max(axis=0)[near] > 10).mean())

    if not (root / "ortho" / "mosaic.tif").exists():  # when run alone
        assert CliRunner().invoke(main, ["mosaic", str(root)]).exit_code == 0
    standard = wrong_on_buildings(root / "ortho" / "mosaic.tif")
    true = wrong_on_buildings(true_root / "ortho" / "mosaic.tif")
    assert standard > 0.15  # leaning roofs over the ground they hide
    assert true < 0.2 * standard

    p, _ = check_against_reference(true_root / "ortho" / "mosaic.tif", root / "truth" / "ortho.tif", patch_px=32,
                                   search_px=4)
    st = displacement_statistics(p.de_m, p.dn_m, info.res_m)
    assert st.rms_xy_gsd < 0.2  # every patch, roofs included


def test_mosaic_away_from_seams_is_the_frame_through_its_gain(block):
    """Where one frame is labelled all around a pixel (beyond the feather's reach), the mosaic is that
    frame's sample times its gain (a saturated 255 stays 255 whatever the gain); the first overview is the 2 x 2 mean
    of the valid pixels."""
    root, _ = block
    if not (root / "ortho" / "mosaic.json").exists():  # when run alone
        assert CliRunner().invoke(main, ["mosaic", str(root)]).exit_code == 0
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    f = summary["seam_factor"]
    reach = int(np.ceil(2 * summary["feather_px"] / f)) + 2  # cells
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(root / "ortho" / "seams.tif") as s:
        m = ds.read().astype(np.int32)
        valid = ds.read_masks(1) > 0
        x0, y0, res = ds.transform.c, ds.transform.f, ds.transform.a
        cells = s.read(1)
        ov = ds.read(out_shape=(ds.count, (ds.height + 1) // 2, (ds.width + 1) // 2)).astype(np.int32)
    compared = 0
    for k, e in enumerate(index["frames"]):
        own = (cells == k).astype(np.uint8)
        deep = cv2.erode(own, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) > 0
        deep_px = np.repeat(np.repeat(deep, f, 0), f, 1)[:m.shape[1], :m.shape[2]]
        with rasterio.open(root / "ortho" / "frames" / e["file"]) as fr:
            c0, r0 = round((fr.transform.c - x0) / res), round((y0 - fr.transform.f) / res)
            img = fr.read().astype(np.float64)
        sub = deep_px[r0:r0 + img.shape[1], c0:c0 + img.shape[2]]
        if not sub.any():
            continue
        want = np.clip(np.rint(img * np.array(summary["gains"][e["image_id"]])[:, None, None]), 0, 255)
        want[img >= 255] = 255
        got = m[:, r0:r0 + img.shape[1], c0:c0 + img.shape[2]]
        d = np.abs(got - want)[:, sub[:got.shape[1], :got.shape[2]]]
        assert d.max() <= 1 and (d == 0).mean() > 0.99
        compared += d.shape[1]
    assert compared > 0.3 * valid.sum()
    # the first overview: 2 x 2 means of the valid full-resolution pixels
    h2, w2 = m.shape[1] // 2 * 2, m.shape[2] // 2 * 2
    v = valid[:h2, :w2].reshape(h2 // 2, 2, w2 // 2, 2)
    s_ = (m[:, :h2, :w2] * valid[None, :h2, :w2]).reshape(m.shape[0], h2 // 2, 2, w2 // 2, 2).sum(axis=(2, 4))
    n = v.sum(axis=(1, 3))
    full = n == 4
    mean = s_[:, full] / 4.0
    assert np.abs(ov[:, :h2 // 2, :w2 // 2][:, full] - mean).max() <= 1.0


def test_seam_cells_are_valid_where_all_their_pixels_are_and_hold_what_any_pixel_holds():
    """``_cells_reduce`` (the seam grid's validity and a frame's hole cells): AND / OR over every factor x factor cell,
    for factors that are not powers of two and strided inputs (a window of a larger array)."""
    from ortho.mosaic import _cells_reduce

    rng = np.random.default_rng(5)
    for factor, (h, w) in ((2, (5, 7)), (3, (4, 9)), (4, (6, 5)), (15, (3, 4))):
        big = rng.integers(0, 3, (h * factor + 2, w * factor + 2)).astype(np.uint8)
        a = big[1:-1, 1:-1]  # a strided view, as find_holes passes its framed pixels
        cells = a.reshape(h, factor, w, factor)
        ok = (a == 0).view(np.uint8)
        ok[:factor, :factor] = 1  # one cell valid all over
        np.testing.assert_array_equal(_cells_reduce(ok, factor, np.bitwise_and),
                                      ok.reshape(h, factor, w, factor).all(axis=(1, 3)))
        got = _cells_reduce(a, factor, np.bitwise_or)
        np.testing.assert_array_equal(got & 1 > 0, (cells == 1).any(axis=(1, 3)))
        np.testing.assert_array_equal(got & 2 > 0, (cells == 2).any(axis=(1, 3)))


def test_overview_halving_is_the_mean_of_the_valid_samples():
    from ortho.mosaic import halve, overview_factors

    rng = np.random.default_rng(1)
    for dtype, top in ((np.uint8, 255), (np.uint16, 4095)):
        img = rng.integers(0, top + 1, (3, 7, 9)).astype(dtype)
        valid = rng.random((7, 9)) > 0.3
        img[:, ~valid] = 0
        got, ok = halve(img, valid)
        padded = np.pad(img, ((0, 0), (0, 1), (0, 1))).astype(float)
        n = np.pad(valid, ((0, 1), (0, 1))).reshape(4, 2, 5, 2).sum(axis=(1, 3))
        want = np.where(n > 0, np.rint(padded.reshape(3, 4, 2, 5, 2).sum(axis=(2, 4)) / np.maximum(n, 1)), 0)
        assert got.dtype == dtype and got.shape == (3, 4, 5)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(ok, n > 0)
    # levels until the coarsest fits one 512 px block, as GDAL's COG driver makes them
    assert overview_factors(2505, 3661) == [2, 4, 8]
    assert overview_factors(512, 300) == [] and overview_factors(513, 10) == [2]


def test_the_overlaps_masked_mean_is_opencvs_mean_to_the_bit():
    """small-fixes 2: ``_masked_mean`` (cv2.mean, the gains) and ``_masked_mean_std`` (cv2.meanStdDev, the offsets'
    spreads) were twins; the one left gives the gains' means bit for bit as cv2.mean did, so the default gains and
    mosaics keep their bytes (every type ``reduce_frames`` keeps, random masks)."""
    from ortho.mosaic import _RESIZABLE, _masked_mean_std

    rng = np.random.default_rng(3)
    for t in _RESIZABLE:
        for _ in range(20):
            h, w = rng.integers(1, 120, 2)
            a = (rng.random((h, w, 3)) * (200 if np.dtype(t).kind != "f" else 1e5)).astype(t)
            mask = rng.random((h, w)) < rng.random()
            mask[0, 0] = True
            mean, std = _masked_mean_std(a, mask)
            m8 = mask.view(np.uint8)
            assert mean.tolist() == [cv2.mean(np.ascontiguousarray(a[:, :, b]), mask=m8)[0] for b in range(3)], t
            assert np.allclose(std, a[mask].astype(np.float64).std(axis=0), rtol=1e-9, atol=1e-6), t
