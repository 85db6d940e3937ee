"""A contract CRS's ortho at the project CRS's speed (issue 41): a tile of a Gauss-Krueger grid is affine in the
UTM project's to far below a pixel, so the rectifier fits it per tile, checks the fit against PROJ and takes the
vectorised kernels; where the fit does not hold it falls back to the anchors. Truth: the exact path (PROJ's anchors,
``affine_tiles=False``) on the simulator's block, and PROJ itself."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pyproj import CRS

from aerotri.geom.crs.transform import CrsTransformer
from aerotri.geom.images import read_native
from aerotri.geom.local_frame import CameraOnEarth
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.block import load_block
from ortho.dem import read_height_raster
from ortho.grid import AFFINE_SHARE, GridToProject, OrthoGrid
from ortho.rectify import AnchorGrid, FrameGeometry, _height_grid, fixed_point_maps, frame_grid, rectify_frame
from ortho.rectify_kernels import _backproject_kernel
from tests.shared_builds import write_synthetic_project

FAR_ZONE = CRS.from_epsg(4545)  # CGCS2000 GK CM 108E, 3 degrees west of the UTM 49N project's CM (111E)


@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    root = tmp_path_factory.mktemp("contract_crs") / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=20, seed=7)
    b = load_block(root)
    i = b.eo.row("s01_001")
    C, R = b.eo.centre_m[i], rotation_matrix_opk(*b.eo.opk_deg[i])
    dsm = read_height_raster(root / "truth" / "dsm.tif", b.project_crs, "DSM")
    op = CrsTransformer(b.project_crs, FAR_ZONE, allow_ballpark=True)
    fast = GridToProject(FAR_ZONE, b.project_crs, operation=op)
    exact = GridToProject(FAR_ZONE, b.project_crs, operation=op, affine_tiles=False)
    grid = frame_grid(b.camera, C, R, dsm, 0.1, FAR_ZONE, to_project=exact)
    img, _ = read_native(root / "images" / "s01_001.tif", (b.camera.width, b.camera.height))
    return b, C, R, dsm, img, grid, fast, exact


def _positions(geometry, dsm, tile, anchors):
    ax, ay, s = anchors
    shape = (tile.height, tile.width)
    mx, my, z = np.empty(shape, np.float32), np.empty(shape, np.float32), np.empty(shape, np.float32)
    _backproject_kernel(AnchorGrid(ax, ay, float(s)), _height_grid(dsm), geometry.kernel_frame(), 0.0, (mx, my, z))
    return mx.astype(float), my.astype(float), mx > -1e4


def test_a_far_zones_tiles_are_affine_and_image_every_pixel_where_the_exact_path_does(frame):
    """Tiles of a grid 3 degrees off the project's central meridian: the fit holds (checked against PROJ), the image
    positions through it are those of the exact anchors within 0.01 px, the masks the same but where a position
    lies on the frame's edge (a few pixels in a million), the heights the same."""
    b, C, R, dsm, _, grid, fast, exact = frame
    geometry = FrameGeometry(b.camera, C, R, earth=CameraOnEarth(b.project_crs, C, R))
    worst, compared, edge = 0.0, 0, 0
    for r0 in range(0, grid.height, 512):
        for c0 in range(0, grid.width, 512):
            tile = grid.window(c0, r0, min(512, grid.width - c0), min(512, grid.height - r0))
            fit = fast.affine(tile)
            assert fit is not None and fit.deviation_m <= AFFINE_SHARE * fast.tolerance_m
            # the fit against PROJ at every 16th pixel, not the points it was fitted or checked at
            rows, cols = np.arange(3, tile.height, 16), np.arange(5, tile.width, 16)
            x, y = tile.centres(rows, cols)
            X, Y = exact.exact(*np.meshgrid(x, y))
            r, c = np.meshgrid(rows, cols, indexing="ij")
            dev = np.hypot(fit.x0_m + c * fit.col_dx_m + r * fit.row_dx_m - X,
                           fit.y0_m + c * fit.col_dy_m + r * fit.row_dy_m - Y)
            assert dev.max() < AFFINE_SHARE * fast.tolerance_m
            xa, ya, ok_a = _positions(geometry, dsm, tile, exact.anchors(tile))
            xb, yb, ok_b = _positions(geometry, dsm, tile, fit.anchors(tile.width, tile.height))
            ok = ok_a & ok_b
            edge += int((ok_a != ok_b).sum())
            if ok.any():
                worst = max(worst, float(np.hypot(xa - xb, ya - yb)[ok].max()))
                compared += int(ok.sum())
            m_fast = fixed_point_maps(geometry, dsm, tile, fast)
            m_exact = fixed_point_maps(geometry, dsm, tile, exact)
            edge += int((m_fast[2] != m_exact[2]).sum())
            assert np.allclose(m_fast[3], m_exact[3], atol=1e-4, equal_nan=True)
    assert compared > 500_000 and worst < 0.01 and edge <= 1e-5 * compared


def test_a_true_ortho_in_a_far_zone_is_the_exact_paths(frame):
    """The true ortho (z-buffer and march) through the affine tiles: the same samples where both image a pixel; the
    occlusion masks differ only where the z-buffer of the affine tiles (the project CRS's: the gaps of walls filled)
    nominates hidden points the anchors' z-buffer missed, which the march then masks."""
    b, C, R, dsm, img, grid, fast, exact = frame
    a, ma = rectify_frame(img, b.camera, C, R, dsm, grid, to_project=fast, occlusion_dsm=dsm, tile_px=512)
    e, me = rectify_frame(img, b.camera, C, R, dsm, grid, to_project=exact, occlusion_dsm=dsm, tile_px=512)
    both = (ma > 0) & (me > 0)
    differ = (np.abs(a.astype(int) - e.astype(int)).max(axis=-1) > 1) & both
    assert both.sum() > 500_000 and differ.sum() <= 1e-5 * both.sum()
    only_fast, only_exact = ((ma > 0) & (me == 0)).sum(), ((me > 0) & (ma == 0)).sum()
    assert only_fast <= 1e-5 * both.sum() and only_exact <= 2e-3 * both.sum()


def test_a_grid_the_fit_does_not_hold_for_falls_back_to_the_anchors_at_once(frame):
    """A tile 100 km wide in the far zone (curved in the project's grid by metres) and, with a tolerance a
    thousandth of the default, a frame's tile: no fit; the maps are the exact path's, byte for byte; the check
    costs milliseconds."""
    b, C, R, dsm, _, grid, _, exact = frame
    wide = OrthoGrid(FAR_ZONE, grid.x_left_m - 50_000.0, grid.y_top_m + 50_000.0, 50.0, 2000, 2000)
    assert GridToProject(FAR_ZONE, b.project_crs, operation=exact.operation).affine(wide) is None
    strict = GridToProject(FAR_ZONE, b.project_crs, operation=exact.operation, tolerance_m=1e-6)
    geometry = FrameGeometry(b.camera, C, R, earth=CameraOnEarth(b.project_crs, C, R))
    tile = grid.window(0, 0, 512, 512)
    t = time.perf_counter()
    assert strict.affine(tile) is None
    assert time.perf_counter() - t < 0.05
    got, want = fixed_point_maps(geometry, dsm, tile, strict), fixed_point_maps(geometry, dsm, tile, exact)
    for g, w in zip(got[:3], want[:3]):
        assert np.array_equal(g, w)
