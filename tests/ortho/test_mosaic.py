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
from ortho.synthetic import write_synthetic_project


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
    assert sorted(f["properties"]["image_id"] for f in regions) == sorted(info["eo"].image_id)
    assert len(lines) >= 5

    # accuracy on ground patches and misalignment across seams
    r = CliRunner().invoke(main, ["check", str(root), "--reference", str(root / "truth" / "ortho.tif"), "--ndsm",
                                  str(root / "truth" / "ndsm.tif")])
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "ortho" / "dom_report.json").read_text())
    assert rep["displacement"]["count"] > 100
    assert rep["displacement"]["rms_xy_gsd"] < 0.15
    assert rep["seams"]["patches"] > 50
    assert rep["seams"]["rms_px"] < 0.3

    # gain balancing brought the darkened frame back: its gain is about 1 / 0.8 of its neighbours'
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    g = {k: np.mean(v) for k, v in summary["gains"].items()}
    others = np.mean([v for k, v in g.items() if k != "s01_002"])
    assert g["s01_002"] / others == pytest.approx(1.25, abs=0.04)


def test_mosaic_radiometry_follows_truth(block):
    """After balancing, the mosaic's grey level matches the truth orthophoto in every frame region."""
    root, _ = block
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
    st = displacement_statistics(p.de_m, p.dn_m, info["res_m"])
    assert st["rms_xy_gsd"] < 0.2  # every patch, roofs included
