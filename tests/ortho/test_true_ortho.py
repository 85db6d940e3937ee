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
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("true_ortho") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=20, seed=7)
    return root


@pytest.mark.parametrize("frame", ["s01_001", "s02_002"])
def test_zbuffer_and_march_mask_what_the_march_masks_everywhere(block, frame):
    b = load_block(block)
    i = b.eo.row(frame)
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(block / "truth" / "dsm.tif", b.project_crs, "DSM")
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = frame_grid(b.camera, C, R, dsm, 0.2, b.project_crs, to_project=to_project)
    image, _ = read_native(b.images.path_of(frame), (b.camera.width, b.camera.height))
    _, seen = rectify_frame(image, b.camera, C, R, dsm, grid, occlusion_dsm=dsm, tile_px=256)
    _, imaged = rectify_frame(image, b.camera, C, R, dsm, grid, tile_px=256)
    # the march over every pixel of the grid (what --true-ortho did before the z-buffer)
    _, _, _, z, anchors = fixed_point_maps(FrameGeometry(b.camera, C, R), dsm, grid, to_project)
    occluded = occlusion_mask(FrameGeometry(b.camera, C, R), dsm, grid, z, anchors)
    expected = (imaged > 0) & ~occluded
    assert (occluded & (imaged > 0)).mean() > 0.002  # the buildings hide ground in this frame
    disagree = (seen > 0) != expected
    assert disagree.mean() < 1e-4, f"{disagree.sum()} of {disagree.size} pixels"


def _union_of_frame_masks(root, mosaic_ds):
    """The union of the frame orthos' validity in ``root``/ortho/frames on the mosaic's grid."""
    import rasterio

    union = np.zeros((mosaic_ds.height, mosaic_ds.width), bool)
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    for e in index["frames"]:
        with rasterio.open(root / "ortho" / "frames" / e["file"]) as ds:
            m = ds.read_masks(1) > 0
            c0 = int(round((ds.transform.c - mosaic_ds.transform.c) / mosaic_ds.transform.a))
            r0 = int(round((ds.transform.f - mosaic_ds.transform.f) / mosaic_ds.transform.e))
        rs = slice(max(0, r0), min(union.shape[0], r0 + m.shape[0]))
        cs = slice(max(0, c0), min(union.shape[1], c0 + m.shape[1]))
        union[rs, cs] |= m[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0]
    return union


def test_the_mosaic_counts_the_cells_no_frame_sees(block, tmp_path):
    """Cells no frame sees: the empty cells enclosed by valid ones, and those inside the ground the frames image
    that reach the block's edge (Tuniu's oblique frames lost 40 % of the mosaic to a forest they do not see and
    reported 7.6 %: only the enclosed). Truth for the second: what the conventional orthos of the same frames
    cover (every cell a frame images)."""
    import rasterio
    from scipy import ndimage

    root, conventional = tmp_path / "p", tmp_path / "c"
    for p in (root, conventional):
        shutil.copytree(block, p, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["rectify", str(conventional)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        ok = ds.read_masks(1) > 0
        imaged = _union_of_frame_masks(conventional, ds)
    lab, n = ndimage.label(~ok)
    edge = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))) - {0}
    enclosed = int(np.count_nonzero((lab > 0) & ~np.isin(lab, list(edge))))
    unseen = int(np.count_nonzero(~ok & imaged))
    assert unseen > 1.05 * enclosed  # hidden ground that reaches the block's edge is there to be counted
    assert summary["cells_seen_by_no_frame"] >= enclosed
    assert abs(summary["cells_seen_by_no_frame"] - unseen) <= 0.1 * unseen, (summary["cells_seen_by_no_frame"], unseen)
    assert 0 < summary["share_seen_by_no_frame"] < 0.05
    assert "seen by no frame (occluded in every frame, over DEM nodata, or over the frames' own nodata)" in r.stderr
    # occluded in every frame, not off the surfaces: the DEM and the DSM cover the block
    assert summary["cells_without_heights"] == 0 and len(summary["surfaces_counted"]) == 2
    assert summary["surfaces_cover_every_frame"]  # (every frame under them: they are not read)
    # the conventional mosaic does not count the cells on objects (its nodata is the DEM's or the frames')
    r = CliRunner().invoke(main, ["mosaic", str(conventional), "--ndsm", str(_ndsm(conventional, tmp_path / "c.tif"))])
    assert r.exit_code == 0, r.output
    assert json.loads((conventional / "ortho" / "mosaic.json").read_text())["cells_on_objects"] is None


def _ndsm(root, path):
    """truth/dsm.tif - truth/dem.tif as an nDSM at ``path``."""
    import rasterio

    with rasterio.open(root / "truth" / "dsm.tif") as s, rasterio.open(root / "truth" / "dem.tif") as d:
        assert s.transform == d.transform and s.shape == d.shape
        profile = s.profile
        nd = s.read(1).astype(np.float32) - d.read(1).astype(np.float32)
    profile.update(dtype="float32", nodata=None)
    with rasterio.open(path, "w", **profile) as out:
        out.write(nd, 1)
    return path


def test_a_true_orthos_unseen_cells_on_roofs_are_counted_apart(block, tmp_path):
    """trial s98 M1: a third of the tall block's nodata lay on roofs some frame sees (the LiDAR DSM's roofs reach past
    the walls and the true ortho masks their edges); the warning called all of it occluded. The mosaic counts the
    unseen cells on the nDSM's objects (above 2.5 m) and says so; truth: the same cells counted on the nDSM here."""
    import rasterio

    from ortho.unseen import unseen_cells

    root = tmp_path / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif")])
    assert r.exit_code == 0, r.output
    ndsm = _ndsm(root, tmp_path / "ndsm.tif")
    r = CliRunner().invoke(main, ["mosaic", str(root), "--ndsm", str(ndsm)])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        unseen = unseen_cells(ds.read_masks(1) > 0, ~ds.transform, [e.get("footprint_xy_m") for e in index["frames"]])
        rows, cols = np.nonzero(unseen)
        x, y = ds.transform * (cols + 0.5, rows + 0.5)
    with rasterio.open(ndsm) as nd:
        values = np.array(list(nd.sample(zip(x, y))))[:, 0]
    want = int(np.count_nonzero(values > 2.5))
    assert 0 < want < len(values)
    assert summary["cells_on_objects"] == want
    assert f"{want} of them" in r.stderr and "on the nDSM's roofs and crowns" in r.stderr


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
        # the corners beside the DOM's holes said with the count (trial s98 H1)
        said = roofs_not_measured_said(roofs["not_measured"])
        assert lines[key][1].startswith(f"roofs: {roofs['count']} of {roofs['corners']} corners{said}: RMS "), lines[key]
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
    i = b.eo.row("s02_002")
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(block / "truth" / "dsm.tif", b.project_crs, "DSM")
    to_project = GridToProject(b.project_crs, b.project_crs)
    grid = frame_grid(b.camera, C, R, dsm, 0.2, b.project_crs, to_project=to_project)
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


def test_true_ortho_seams_give_each_frame_one_region_and_the_mosaic_fills_what_its_frame_does_not_see(block, tmp_path):
    """The seams of a true ortho are routed on the cells each frame covers (its occlusion holes filled): one region
    per frame, not an island of another frame round every hole (whose outlines were seams along the walls); the
    cells of a region its frame does not see come from a frame that sees them."""
    import cv2
    import rasterio

    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    root = tmp_path / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    for args in (["rectify", str(root), "--true-ortho", "--dsm", str(root / "truth" / "dsm.tif")],
                 ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    with rasterio.open(root / "ortho" / "seams.tif") as ds:
        labels = ds.read(1)
    present = [k for k in np.unique(labels) if k >= 0]
    assert len(present) == 6
    parts = {int(k): cv2.connectedComponents((labels == k).astype(np.uint8), connectivity=4)[0] - 1 for k in present}
    assert all(n == 1 for n in parts.values()), parts
    # every mosaic cell some frame sees has a value; occluded cells of the labelled frame among them
    index = read_index(root)
    grids = dict(zip(index.image_ids, index.grids))
    mosaic = OrthoGrid.union(grids.values())
    seen_by_any = np.zeros((mosaic.height, mosaic.width), bool)
    hidden_in_label = np.zeros_like(seen_by_any)
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(root / "ortho" / "seams.tif") as s:
        ok = ds.read_masks(1) > 0
        factor = int(round(s.transform.a / ds.res[0]))
    lab_px = np.kron(labels, np.ones((factor, factor), labels.dtype))[:mosaic.height, :mosaic.width]
    for k, e in enumerate(index.frames):
        c0, r0 = grids[e.image_id].offset_in(mosaic)
        with rasterio.open(root / "ortho" / "frames" / e.file) as ds:
            m = ds.read_masks(1) > 0
        win = (slice(r0, r0 + m.shape[0]), slice(c0, c0 + m.shape[1]))
        seen_by_any[win] |= m
        hidden_in_label[win] |= (lab_px[win] == k) & ~m & _filled(m)
    assert hidden_in_label.sum() > 100  # the buildings hide ground inside the frames' regions
    assert ok[seen_by_any].mean() > 0.9999
    assert ok[hidden_in_label & seen_by_any].all()


def _filled(m):
    """A mask with the holes inside it filled."""
    import cv2

    outside = np.pad(~m, 1, constant_values=True).view(np.uint8).copy()
    cv2.floodFill(outside, None, (0, 0), 2)
    return outside[1:-1, 1:-1] != 2


@pytest.fixture(scope="module")
def true_frames(block, tmp_path_factory):
    """True orthos on a DSM whose buildings are one cell smaller than the truth's (a DSM from points places the
    roof edge to within a cell): the frames see a little less occlusion than there is."""
    import cv2
    import rasterio

    root = tmp_path_factory.mktemp("true_frames") / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    with rasterio.open(root / "truth" / "dsm.tif") as d, rasterio.open(root / "truth" / "dem.tif") as e:
        dsm, dem, profile = d.read(1), e.read(1), d.profile
    smaller = dem + cv2.erode(np.maximum(dsm - dem, 0).astype(np.float32), np.ones((3, 3), np.uint8))
    with rasterio.open(root / "dsm_smaller.tif", "w", **profile) as out:
        out.write(smaller.astype(profile["dtype"]), 1)
    r = CliRunner().invoke(main, ["rectify", str(root), "--true-ortho", "--dsm", str(root / "dsm_smaller.tif")])
    assert r.exit_code == 0, r.output
    return root


def _holes(m, ring, mosaic, r0, c0):
    """A frame's holes as the mosaic takes them: its invalid pixels that valid ones enclose or that lie inside its
    footprint ``ring`` one pixel in (occlusion reaching the frame's edge); the frame's first pixel at mosaic row
    ``r0``, column ``c0``."""
    from ortho.mosaic import _inside_footprint

    inside = _inside_footprint(ring, m.shape, mosaic, r0, c0)
    return ~m & (_filled(m) | (inside if inside is not None else False))


def _taken_near_own_holes(root, margin_px):
    """Of the DOM pixels of a frame's region within ``margin_px`` of a hole of that frame (its ortho empty inside
    its footprint) that another frame has away from its own holes: (their count, the share equal to the region's
    frame's samples, the count of those whose source the samples tell (the region's frame's sample differs from
    that of every frame that has the pixel clear), the share of these equal to the region's frame's samples). The
    mosaic is not balanced: a pixel taken from a frame is that frame's sample; but the synthetic frames are
    noise-free renderings of one texture on the true geometry, and two frames often give the very same sample (a
    fifth of these pixels here): such a pixel equals the region's frame's sample whichever frame it was taken from."""
    import cv2
    import rasterio

    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    index = read_index(root)
    grids = dict(zip(index.image_ids, index.grids))
    mosaic = OrthoGrid.union(grids.values())
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds, rasterio.open(root / "ortho" / "seams.tif") as s:
        dom = ds.read()
        labels = s.read(1)
        factor = int(round(s.transform.a / ds.res[0]))
    lab_px = np.kron(labels, np.ones((factor, factor), labels.dtype))[:mosaic.height, :mosaic.width]
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
    frames = []
    for e in index.frames:
        c0, r0 = grids[e.image_id].offset_in(mosaic)
        with rasterio.open(root / "ortho" / "frames" / e.file) as ds:
            img, m = ds.read(), ds.read_masks(1) > 0
        near = cv2.dilate(_holes(m, e.footprint_xy_m, mosaic, r0, c0).astype(np.uint8), disc) > 0
        frames.append((slice(r0, r0 + m.shape[0]), slice(c0, c0 + m.shape[1]), img, m, near))
    clear = np.zeros(lab_px.shape, np.int32)  # frames that have the pixel away from their holes
    for rs, cs, _, m, near in frames:
        clear[rs, cs] += m & ~near
    band_n, same_n, told_n, told_same_n = 0, 0, 0, 0
    for k, (rs, cs, img, m, near) in enumerate(frames):
        band = near & m & (lab_px[rs, cs] == k) & (clear[rs, cs] > 0)
        same = np.all(dom[:, rs, cs] == img, axis=0) & band
        # the band pixels where another frame that has the pixel clear gives the same sample as frame k
        tie = np.zeros_like(band)
        for j, (rs2, cs2, img2, m2, near2) in enumerate(frames):
            r0, r1, c0, c1 = max(rs.start, rs2.start), min(rs.stop, rs2.stop), max(cs.start, cs2.start), \
                min(cs.stop, cs2.stop)
            if j == k or r1 <= r0 or c1 <= c0:
                continue
            a = (slice(r0 - rs.start, r1 - rs.start), slice(c0 - cs.start, c1 - cs.start))
            b = (slice(r0 - rs2.start, r1 - rs2.start), slice(c0 - cs2.start, c1 - cs2.start))
            tie[a] |= np.all(img2[:, b[0], b[1]] == img[:, a[0], a[1]], axis=0) & m2[b] & ~near2[b]
        band_n += int(band.sum())
        same_n += int(same.sum())
        told_n += int((band & ~tie).sum())
        told_same_n += int((same & ~tie).sum())
    return band_n, same_n / max(1, band_n), told_n, told_same_n / max(1, told_n)


def test_the_mosaic_takes_a_true_ortho_frame_away_from_its_holes_where_another_frame_sees(true_frames, tmp_path,
                                                                                          monkeypatch):
    """Ground just beyond a frame's occlusion hole may still show the wall or roof (the DSM places the roof edge to
    within a cell; here the DSM's buildings are a cell too small): the mosaic takes it from a frame that has it away
    from its own holes (``HOLE_MARGIN_M``), and the same bytes on a local cluster of worker processes as on threads
    (the holes travel beside the tiles' context). The ghost pixels this removes are counted against the simulator's
    geometry by bench/eval_true_ortho_occlusion.py."""
    import hashlib

    import ortho.mosaic as om
    from aerotri.core.executor import Executor
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings

    import rasterio

    made = {}
    with rasterio.open(next((true_frames / "ortho" / "frames").glob("*.tif"))) as ds:
        margin_px = om.hole_margin_px(ds.res[0])
    for name, margin, scheduler in (("none", 0.0, None), ("margin", om.HOLE_MARGIN_M, None),
                                    ("margin_cluster", om.HOLE_MARGIN_M, "local:2")):
        root = tmp_path / name
        shutil.copytree(true_frames, root)
        monkeypatch.setattr(om, "HOLE_MARGIN_M", margin)
        with Executor(scheduler, 2) as ex:
            mosaic_block(root, MosaicSettings(tile_px=256, balance=False), executor=ex)
        made[name] = _taken_near_own_holes(root, margin_px) + (
            hashlib.sha256((root / "ortho" / "mosaic.tif").read_bytes()).hexdigest(),)
    assert made["none"][0] > 1000  # pixels near the frames' holes that another frame has clear
    assert made["none"][2] > 0.7 * made["none"][0]  # most of them told apart by their samples
    # of those whose samples tell the source: 99.2 % from the region's frame without the margin, none with it
    # (measured: 0 of 5,326 pixels; seed 11: 95.9 % and 0 of 5,322; since fill3's holes inside the footprint, also
    # occlusion that runs off a frame's edge: 96.6 % and 0 of 4,488). With the holes found on the seam grid, whose
    # partly valid cells at a frame's edge join a hole there to the outside, 1.5 % (seed 11: 6.8 %) came from the
    # region's frame. Counted over all of them, ties included, the share was 21.1 % (seed 11: 21.5 %): the ties, a
    # fifth of the pixels, count as the region's frame's whichever frame gave them; the limit on the pixels told
    # apart is 0.5 % (it was 20 % of all of them, ties included)
    assert made["none"][3] > 0.9 and made["margin"][3] < 0.005, made
    assert made["margin"][4] == made["margin_cluster"][4]


def test_a_pixel_every_frame_has_near_its_holes_comes_from_the_frame_farthest_from_them(true_frames, tmp_path):
    """Where every frame that has a pixel has it within the hole margin of its own holes, the mosaic takes it from
    the frame whose pixel lies farthest from its holes (a frame's mask decides the edge of what it sees to within a
    DSM cell: the nearer its edge, the likelier a ghost), not from the nearest nadir point (main's rule: demo seed 7
    fill 97.71 -> 98.11 %, tree ghosts -18 %, bench/results/true_ortho_fill.json ``fill_causes9``). Checked on the
    pixels whose farthest frame is one alone and whose samples tell it from the others."""
    import cv2
    import rasterio

    import ortho.mosaic as om
    from aerotri.core.executor import Executor
    from ortho.block import read_index
    from ortho.grid import OrthoGrid
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings

    root = tmp_path / "p"
    shutil.copytree(true_frames, root)
    with Executor(None, 2) as ex:
        mosaic_block(root, MosaicSettings(tile_px=256, balance=False), executor=ex)
    index = read_index(root)
    grids = dict(zip(index.image_ids, index.grids))
    mosaic = OrthoGrid.union(grids.values())
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        dom, margin_px = ds.read(), om.hole_margin_px(ds.res[0])
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
    F, (H, W) = len(index.frames), (mosaic.height, mosaic.width)
    dist = np.full((F, H, W), -1.0, np.float32)  # the pixel's distance from the frame's holes, -1: not valid
    away = np.zeros((H, W), bool)  # some frame has the pixel away from its holes
    samples = np.zeros((F, dom.shape[0], H, W), dom.dtype)
    for k, e in enumerate(index.frames):
        c0, r0 = grids[e.image_id].offset_in(mosaic)
        with rasterio.open(root / "ortho" / "frames" / e.file) as ds:
            img, m = ds.read(), ds.read_masks(1) > 0
        hole = _holes(m, e.footprint_xy_m, mosaic, r0, c0)
        d = np.minimum(np.round(cv2.distanceTransform((~hole).view(np.uint8), cv2.DIST_L2, 3), 2), margin_px + 1)
        rs, cs = slice(r0, r0 + m.shape[0]), slice(c0, c0 + m.shape[1])
        dist[k, rs, cs] = np.where(m, d, -1.0)
        away[rs, cs] |= m & (cv2.dilate(hole.view(np.uint8), disc) == 0)
        samples[k, :, rs, cs] = img
    top = dist.max(axis=0)
    farthest = np.argmax(dist, axis=0)
    alone = (dist == top).sum(axis=0) == 1
    band = ~away & ((dist >= 0).sum(axis=0) >= 2) & alone & (top >= 0)
    rr, cc = np.nonzero(band)
    want = samples[farthest[rr, cc], :, rr, cc]
    others = [np.all(samples[j, :, rr, cc] == want, axis=1) & (dist[j, rr, cc] >= 0) & (farthest[rr, cc] != j)
              for j in range(F)]
    told = ~np.any(others, axis=0)  # no other valid frame gives the same sample
    assert told.sum() > 200, told.sum()
    same = np.all(dom[:, rr, cc].T == want, axis=1)
    # measured: 100 % of 2,946 pixels; main's rule (the nearest nadir point) took the farthest frame's in 49.1 %
    assert same[told].mean() > 0.99, (same[told].mean(), told.sum())


def test_the_mosaic_finds_a_frames_holes_pixel_by_pixel():
    """``find_holes``: the invalid pixels a frame's valid pixels enclose (4-connected), also where the hole lies within
    a seam cell of the frame's edge (the seam grid's partly valid cells there join it to the outside) or is smaller
    than a cell; a notch open to the outside is no hole. ``FrameHoles.pixels`` gives them over any mosaic window."""
    from ortho.mosaic import find_holes
    from ortho.seamlines import covered

    factor, (h, w) = 8, (81, 77)  # the frame ortho's size: not whole cells
    m = np.zeros((h, w), bool)
    m[3:78, 5:70] = True  # the frame's valid pixels, its edge inside the first and last cells
    m[5:12, 8:20] = False  # a hole one valid pixel row and two columns in from the edge
    m[30, 40] = False  # a hole of one pixel
    m[20:26, 60:70] = False  # a notch open to the outside: no hole
    m[40:50, 30:31] = False  # a one-pixel-wide slit in the middle
    offset_px = (13, 21)  # the frame's first pixel in the mosaic (row, col)
    (sr, sc) = (offset_px[0] // factor, offset_px[1] // factor)
    ch, cw = -(-(offset_px[0] + h) // factor) - sr, -(-(offset_px[1] + w) // factor) - sc
    invalid = np.ones((ch * factor + 2, cw * factor + 2), np.uint8)
    r, c = offset_px[0] - sr * factor, offset_px[1] - sc * factor
    invalid[1 + r:1 + r + h, 1 + c:1 + c + w] = ~m
    holes = find_holes(invalid, factor, (sr, sc))
    expected = ~m & _filled(m)
    assert expected.sum() == 7 * 12 + 1 + 10
    # the seam grid sees the slit and the single pixel, not the hole at the edge
    px = np.zeros((ch * factor, cw * factor), bool)
    px[r:r + h, c:c + w] = m
    cells_valid = px.reshape(ch, factor, cw, factor).all(axis=(1, 3))
    seam_holes = np.kron(covered(cells_valid) & ~cells_valid, np.ones((factor, factor), bool))[r:r + h, c:c + w] & ~m
    assert not seam_holes[5:12, 8:20].any() and seam_holes[30, 40] and seam_holes[40:50, 30].all()
    assert np.array_equal(holes.pixels(m, *offset_px, factor), expected)
    # any window of the mosaic, also past the frame: the same pixels
    for r0, c0, hh, ww in ((0, 0, 40, 50), (20, 30, 17, 9), (60, 80, 30, 40), (-5, -5, 100, 120)):
        ok = np.zeros((hh, ww), bool)
        want = np.zeros((hh, ww), bool)
        for y in range(hh):
            for x in range(ww):
                fy, fx = r0 + y - offset_px[0], c0 + x - offset_px[1]
                if 0 <= fy < h and 0 <= fx < w:
                    ok[y, x], want[y, x] = m[fy, fx], expected[fy, fx]
        assert np.array_equal(holes.pixels(ok, r0, c0, factor), want), (r0, c0)
    # a frame without holes has none
    invalid = np.ones((ch * factor + 2, cw * factor + 2), np.uint8)
    invalid[1 + r:1 + r + h, 1 + c:1 + c + w] = 0
    assert find_holes(invalid, factor, (sr, sc)) is None


def test_occlusion_that_reaches_the_frames_edge_is_a_hole_inside_its_footprint():
    """An occlusion that reaches the frame ortho's edge is joined to the outside, so valid pixels do not enclose it;
    inside the frame's footprint (``FrameEntry.footprint_xy_m``, one pixel in) it is a hole all the same: the hole
    margin and the farthest-from-holes rule act round it (on the tall seed 20261130 a third of the frames' invalid
    pixels inside their footprints were such occlusion, joined to the outside: docs/true-ortho.md "Occlusion that
    reaches a frame's edge"). Outside the footprint the invalid pixels stay the frame's outside."""
    from pyproj import CRS

    from ortho.grid import OrthoGrid
    from ortho.mosaic import _inside_footprint, find_holes

    factor, (h, w) = 4, (40, 36)
    mosaic = OrthoGrid(CRS.from_epsg(32632), 500000.0, 4000000.0, 0.5, 60, 60)
    offset_px = (8, 12)  # the frame's first pixel in the mosaic (row, col)
    m = np.zeros((h, w), bool)
    m[2:38, 3:33] = True  # the frame's ground: its footprint
    m[10:16, 20:33] = False  # a building's occlusion running off the frame's right edge
    m[25:28, 8:11] = False  # an enclosed hole
    # the footprint ring round the valid rectangle's pixel edges, in the mosaic's CRS
    x0 = mosaic.x_left_m + (offset_px[1] + 3) * mosaic.res_m
    x1 = mosaic.x_left_m + (offset_px[1] + 33) * mosaic.res_m
    y0 = mosaic.y_top_m - (offset_px[0] + 2) * mosaic.res_m
    y1 = mosaic.y_top_m - (offset_px[0] + 38) * mosaic.res_m
    ring = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
    (sr, sc) = (offset_px[0] // factor, offset_px[1] // factor)
    ch, cw = -(-(offset_px[0] + h) // factor) - sr, -(-(offset_px[1] + w) // factor) - sc
    r, c = offset_px[0] - sr * factor, offset_px[1] - sc * factor

    def framed():
        invalid = np.ones((ch * factor + 2, cw * factor + 2), np.uint8)
        invalid[1 + r:1 + r + h, 1 + c:1 + c + w] = ~m
        return invalid

    inside = _inside_footprint(ring, (ch * factor + 2, cw * factor + 2), mosaic, sr * factor - 1, sc * factor - 1)
    got = find_holes(framed(), factor, (sr, sc), inside=inside).pixels(m, *offset_px, factor)
    enclosed = find_holes(framed(), factor, (sr, sc)).pixels(m, *offset_px, factor)  # without the footprint
    assert enclosed.sum() == 9 and not enclosed[10:16, 20:33].any()
    # the occlusion is a hole up to the footprint's edge (its ring on the pixel edges, taken one pixel in); the
    # enclosed hole as before; nothing outside the footprint
    assert got[10:16, 20:32].all() and got[25:28, 8:11].all() and got.sum() in (6 * 12 + 9, 6 * 13 + 9)
    assert not got[:, 33:].any() and not got[:2].any() and not got[38:].any() and not got[:, :3].any()
    assert _inside_footprint(None, (4, 4), mosaic, 0, 0) is None


def test_a_decoded_frames_hole_margin_is_that_of_its_file_windows(true_frames):
    """A frame kept decoded for the blending has its validity away from its holes made once, whole
    (``DecodedFrame.away``): over any mosaic window, also past the frame's edges, the same as the hole margin of the
    window read from the file (``FrameHoles`` at pixel level, dilated with the margin as halo)."""
    import ortho.mosaic as om
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    index = read_index(true_frames)
    frames_dir = true_frames / "ortho" / "frames"
    mosaic = OrthoGrid.union(index.grids)
    factor = 4
    red = om.reduce_frames(frames_dir, index, mosaic, factor, keep_decoded=True)
    holes = om.frame_holes(red)
    assert holes is not None and sum(h is not None for h in holes) >= 3
    ctx = om._context(index, frames_dir, mosaic, factor=factor, halo=20, gains=np.ones((len(holes), 3)),
                      nadir=np.zeros((len(holes), 2)), feather_px=8.0, bands=3, dtype="uint8", read_cells=None,
                      seam_shape=red.shape, holes=holes)
    assert ctx.hole_margin_px >= 1
    from_memory, from_files = om._FrameReaders(red.decoded), om._FrameReaders()
    rng = np.random.default_rng(3)
    checked = 0
    try:
        for k, h in enumerate(holes):
            if h is None:
                continue
            (fc, fr), (w, hh) = ctx.offsets[k], ctx.sizes[k]
            for _ in range(6):
                row, col = int(fr + rng.integers(-40, hh)), int(fc + rng.integers(-40, w))
                size = (int(rng.integers(20, 300)), int(rng.integers(20, 300)))
                (img_a, away_a), ok_a = om._hole_margin(ctx, from_memory, k, row=row, col=col, h=size[0], w=size[1])
                (img_b, away_b), ok_b = om._hole_margin(ctx, from_files, k, row=row, col=col, h=size[0], w=size[1])
                assert np.array_equal(img_a, img_b) and np.array_equal(ok_a, ok_b)
                assert np.array_equal(away_a, away_b), (k, row, col, size)
                checked += int(np.count_nonzero(ok_a & ~away_a))
    finally:
        from_files.close()
    assert checked > 100  # pixels cleared near holes were compared


def roofs_not_measured_said(nm: dict) -> str:
    """The words after a roofs row's corner count for its corners not measured (dom_report.json roofs.not_measured):
    every kind said, so that they add up to the corners (trial s98 H1, trial s100 rc F9)."""
    parts = ([f"{nm['in_nodata']} not measurable: in the DOM's nodata"] if nm.get("in_nodata") else []) + (
        [f"{nm['in_dom_holes']} not measured: 20 % or more of their patch in the DOM's nodata"]
        if nm.get("in_dom_holes") else []) + (
        [f"{nm['outside_or_invalid']} not measured: their patch not whole in the DOM, or the reference's too little "
         "valid"] if nm.get("outside_or_invalid") else []) + (
        [f"{nm['weak']} without a clear match (a weak peak, or one at the search's edge)"] if nm.get("weak") else [])
    return f" ({'; '.join(parts)})" if parts else ""


def test_the_unseen_cells_on_objects_say_a_share_under_one_percent():
    """Trial s113: a block mostly without heights said "18650 of them (0 %) on the nDSM's roofs"; a share under 1 %
    keeps its first significant digit, one of 1 % or more is whole."""
    from ortho.mosaic import on_objects_words

    assert "18650 of them (0.1 %) on the nDSM's roofs" in on_objects_words(18650, 18138878)
    assert "(0.005 %)" in on_objects_words(1, 20000) and "(30 %)" in on_objects_words(41040, 135131)
    assert on_objects_words(0, 100) == "" and on_objects_words(5, 0) == ""
