"""True-ortho occlusion (issue 42): the frame's z-buffer picks the candidates, the march along the ray decides;
the result is the march's over every pixel, at the cost of the z-buffer. The mosaic reports the cells no frame
sees."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.geom.images import read_native
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.block import load_block
from ortho.cli import main
from ortho.dem import read_height_raster
from ortho.grid import GridToProject
from ortho.rectify import FrameGeometry, fixed_point_maps, frame_grid, occlusion_mask, rectify_frame
from ortho.synthetic import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("true_ortho") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=20, seed=7)
    return root


@pytest.mark.parametrize("frame", ["s01_001", "s02_002"])
def test_zbuffer_and_march_mask_what_the_march_masks_everywhere(block, frame):
    b = load_block(block)
    i = b.eo.index()[frame]
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(block / "truth" / "dsm.tif", b.project_crs, "DSM")
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = frame_grid(b.camera, C, R, dsm, 0.2, b.project_crs, to_project)
    image, _ = read_native(b.images[frame], (b.camera.width, b.camera.height))
    _, seen = rectify_frame(image, b.camera, C, R, dsm, grid, occlusion_dsm=dsm, tile_px=256)
    _, imaged = rectify_frame(image, b.camera, C, R, dsm, grid, tile_px=256)
    # the march over every pixel of the grid (what --true-ortho did before the z-buffer)
    _, _, _, z, anchors = fixed_point_maps(FrameGeometry(b.camera, C, R), dsm, grid, to_project)
    occluded = occlusion_mask(FrameGeometry(b.camera, C, R), dsm, grid, z, anchors)
    expected = (imaged > 0) & ~occluded
    assert (occluded & (imaged > 0)).mean() > 0.002  # the buildings hide ground in this frame
    disagree = (seen > 0) != expected
    assert disagree.mean() < 1e-4, f"{disagree.sum()} of {disagree.size} pixels"


def test_the_mosaic_counts_the_cells_no_frame_sees(block, tmp_path):
    root = tmp_path / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    import rasterio

    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        ok = ds.read_masks(1) > 0
    # the count is that of the empty cells enclosed by valid ones (here without decimation: a small mosaic)
    from scipy import ndimage

    lab, n = ndimage.label(~ok)
    edge = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))) - {0}
    enclosed = int(np.count_nonzero((lab > 0) & ~np.isin(lab, list(edge))))
    assert summary["cells_seen_by_no_frame"] == enclosed
    assert summary["share_seen_by_no_frame"] < 0.01
    if enclosed:
        assert "seen by no frame" in r.stderr


def test_the_dom_check_measures_roofs_against_the_true_orthophoto(block, tmp_path):
    """The DOM check's roofs row (issue 42): the same frames rectified on the DEM and, true ortho, on the DSM, each
    checked against the true orthophoto at the truth's roof corners and at the corners of the nDSM's buildings."""
    reports, lines = {}, {}
    for way, extra in (("conventional", []), ("true", ["--true-ortho", "--dsm", "truth/dsm.tif"])):
        root = tmp_path / way
        shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
        extra = [str(root / a) if a.endswith(".tif") else a for a in extra]
        for args in (["rectify", str(root)] + extra, ["mosaic", str(root)]):
            r = CliRunner().invoke(main, args)
            assert r.exit_code == 0, r.output
        # the truth's true orthophoto as a reference of its own (no roof_corners.csv beside it): the nDSM's corners
        shutil.copy(root / "truth" / "ortho.tif", root / "reference.tif")
        for corners in ("truth", "nDSM"):
            args = ["check", str(root), "--reference", str(root / ("truth/ortho.tif" if corners == "truth" else "reference.tif"))]
            if corners == "truth":
                args += ["--roof-corners", str(root / "truth" / "roof_corners.csv")]
            r = CliRunner().invoke(main, args)
            assert r.exit_code == 0, r.output
            lines[way, corners] = r.stdout.splitlines()
            reports[way, corners] = json.loads((root / "ortho" / "dom_report.json").read_text())
    for key, rep in reports.items():
        roofs = rep["roofs"]
        assert roofs["count"] >= 0.6 * roofs["corners"], (key, roofs["not_measured"])
        assert lines[key][1].startswith(f"roofs: {roofs['count']} of {roofs['corners']} corners: RMS "), lines[key]
        # open ground is in place either way (only the roofs move)
        assert rep["displacement"]["count"] > 100 and rep["displacement"]["rms_xy_gsd"] < 0.25, key
    assert reports["true", "truth"]["roofs"]["corners"] == 80  # 20 box buildings
    assert 60 <= reports["true", "nDSM"]["roofs"]["corners"] <= 100  # found in the nDSM (80 on this block)
    assert "roof_corners.csv" in reports["true", "truth"]["roofs"]["corners_from"]
    assert reports["true", "nDSM"]["roofs"]["corners_from"].startswith("nDSM ")
    # the simulator's true orthophoto as the reference without --roof-corners: the truth's corners beside it, said so
    root = tmp_path / "true"
    r = CliRunner().invoke(main, ["check", str(root), "--reference", str(root / "truth" / "ortho.tif"), "--out",
                                  str(tmp_path / "default")])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "default.json").read_text())
    assert rep["roofs"] == reports["true", "truth"]["roofs"] | {"corners_from": str(root / "truth" / "roof_corners.csv")}
    assert "simulator's roof corners" in rep["settings"]["roof_corners"]["note"]
    for corners in ("truth", "nDSM"):
        true, conv = reports["true", corners]["roofs"], reports["conventional", corners]["roofs"]
        # the synthetic roofs carry the ground's texture (no roof-like contrast), so the patches see mostly texture:
        # medians measured (seeds 7 and 11) 0.06 / 0.21 and 0.06 / 0.17 GSD; RMS is carried by single patches
        assert true["median_xy_gsd"] < 0.15, (corners, true)
        assert conv["median_xy_gsd"] > 2 * true["median_xy_gsd"], (corners, conv["median_xy_gsd"], true["median_xy_gsd"])


def test_the_march_jumping_over_dsm_blocks_gives_the_step_by_step_result(block):
    """The march jumps over the DSM blocks its ray passes above (``march_bound``) and tries first where the z-buffer's
    nearer surface is: the same sample positions, so the same occlusion as stepping cell by cell, on every pixel."""
    from ortho.rectify import MarchBound, march_bound

    b = load_block(block)
    i = b.eo.index()["s02_002"]
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(block / "truth" / "dsm.tif", b.project_crs, "DSM")
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = frame_grid(b.camera, C, R, dsm, 0.2, b.project_crs, to_project)
    geometry = FrameGeometry(b.camera, C, R)
    _, _, mask, z, anchors = fixed_point_maps(geometry, dsm, grid, to_project)
    bound = march_bound(dsm)
    stepwise = MarchBound(bound.max_m, np.full_like(bound.block_max_m, np.inf), bound.block,
                          np.full_like(bound.coarse_max_m, np.inf), bound.coarse)
    jumping = occlusion_mask(geometry, dsm, grid, z, anchors, bound=bound)
    assert (jumping & (mask > 0)).mean() > 0.002
    assert np.array_equal(jumping, occlusion_mask(geometry, dsm, grid, z, anchors, bound=stepwise))
    # a wrong hint (every point told its nearer surface is half way) changes nothing either
    half = np.full(z.shape, 0.5, np.float32)
    assert np.array_equal(jumping, occlusion_mask(geometry, dsm, grid, z, anchors, bound=bound, near_share=half))
