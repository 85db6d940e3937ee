"""``ortho rectify --true-ortho --dsm DSM --occlusion-dsm SURFACE`` (issue 42): the ortho on the DSM's heights, its
occlusion test on another surface (the chain's: lidarctl rasters' dsm_nearest.tif beside dsm.tif)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("occlusion_dsm") / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=20, seed=7)
    return root


def _frames(root):
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    out = {}
    for e in index["frames"]:
        with rasterio.open(root / "ortho" / "frames" / e["file"]) as ds:
            out[e["image_id"]] = (ds.read(), ds.read_masks(1) > 0, ds.transform)
    return index, out


def _rectify(block, tmp_path, name, *args):
    root = tmp_path / name
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dem", str(root / "truth" / "dem.tif"),
                                  "--dsm", str(root / "truth" / "dsm.tif"), *(a.format(root=root) for a in args)])
    assert r.exit_code == 0, r.output
    return _frames(root)


def test_the_occlusion_test_takes_its_own_surface_and_the_heights_stay_the_dsms(block, tmp_path):
    index, dsm = _rectify(block, tmp_path, "dsm")
    assert "occlusion_dsm" not in index
    # the DSM itself given again: the same frame orthos, byte for byte
    _, same = _rectify(block, tmp_path, "same", "--occlusion-dsm", "{root}/truth/dsm.tif")
    for k, (img, m, tf) in dsm.items():
        assert np.array_equal(img, same[k][0]) and np.array_equal(m, same[k][1]) and tf == same[k][2]
    # a copy of the DSM in another file: the occlusion test reads it apart from the heights, the same masks
    shutil.copy2(block / "truth" / "dsm.tif", tmp_path / "copy.tif")
    index, copy = _rectify(block, tmp_path, "copy", "--occlusion-dsm", str(tmp_path / "copy.tif"))
    assert index["occlusion_dsm"] == str(tmp_path / "copy.tif")
    for k, (img, m, tf) in dsm.items():
        assert tf == copy[k][2] and (m != copy[k][1]).mean() < 1e-3, (m != copy[k][1]).mean()
        both = m & copy[k][1]
        assert np.array_equal(img[:, both], copy[k][0][:, both])
    # the ground as the occlusion surface: nothing stands in a line of sight, every pixel the DSM hides is back;
    # its samples where the DSM's test keeps them are the same (the heights are the DSM's, not the ground's)
    index, ground = _rectify(block, tmp_path, "ground", "--occlusion-dsm", str(block / "truth" / "dem.tif"))
    for k, (img, m, tf) in dsm.items():
        g_img, g_m, g_tf = ground[k]
        assert g_tf == tf and (g_m & ~m).sum() > 0.01 * m.sum() and not (m & ~g_m).any()
        assert np.array_equal(img[:, m], g_img[:, m])


def test_crowns_change_nothing_where_no_disk_lies_and_a_bad_file_is_refused(block, tmp_path):
    """``--crowns`` (lidarctl rasters' crowns.gpkg): a crown beyond every frame's DSM window leaves the frame orthos
    byte for byte; a crowns file in another CRS stops the command before any frame (exit 2, naming the file)."""
    import shapely

    from aerotri.core.project import Project
    from aerotri.core.vector_files import VectorLayer, write_layers

    crs = Project.open(block).crs
    with rasterio.open(block / "truth" / "dsm.tif") as ds:
        far_x, far_y = ds.bounds.right + 500.0, ds.bounds.top + 500.0
    fields = {"x_m": np.array([far_x]), "y_m": np.array([far_y]), "radius_m": np.array([3.0]),
              "top_m": np.array([20.0]), "base_m": np.array([5.0])}
    disk = [shapely.Point(far_x, far_y).buffer(3.0)]
    write_layers(tmp_path / "far.gpkg", [VectorLayer("crowns", "Polygon", disk, fields)], crs=crs)
    _, plain = _rectify(block, tmp_path, "plain")
    index, far = _rectify(block, tmp_path, "far", "--crowns", str(tmp_path / "far.gpkg"))
    assert index["crowns"] == str(tmp_path / "far.gpkg")
    for k, (img, m, tf) in plain.items():
        assert np.array_equal(img, far[k][0]) and np.array_equal(m, far[k][1]) and tf == far[k][2]
    write_layers(tmp_path / "wgs.gpkg", [VectorLayer("crowns", "Polygon", disk, fields)], crs="EPSG:4326")
    root = tmp_path / "bad"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dem", str(root / "truth" / "dem.tif"),
                                  "--dsm", str(root / "truth" / "dsm.tif"), "--crowns", str(tmp_path / "wgs.gpkg")])
    assert r.exit_code == 2 and "wgs.gpkg: the crowns are in" in r.output and "Traceback" not in r.output
    assert not (root / "ortho" / "frames").exists()
