"""The view-angle limit of ``ortho rectify`` (``[rectify] max_view_angle_deg``): cells whose ray to the
projection centre is more than the limit from the vertical are nodata, checked cell by cell against the
geometry (cell centre on the DEM, the frame's projection centre); within it the ortho is the unlimited one."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from scipy.ndimage import map_coordinates

from ortho.cli import main
from tests.shared_builds import write_synthetic_project


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("view_angle") / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=0, seed=5)
    r = run("rectify", root, "--max-view-angle-deg", 90)
    assert r.exit_code == 0, r.output
    unlimited = root.parent / "unlimited"
    shutil.copytree(root / "ortho", unlimited)
    return root, unlimited


def _view_angle_deg(path, centre_m, dem_path):
    """The angle from the vertical of each cell's ray to ``centre_m`` (cell centre on the DEM, bilinear)."""
    with rasterio.open(path) as ds:
        t, h, w = ds.transform, ds.height, ds.width
    x = t.c + (np.arange(w) + 0.5) * t.a
    y = t.f + (np.arange(h) + 0.5) * t.e
    with rasterio.open(dem_path) as dem:
        z_grid, dt = dem.read(1).astype(float), dem.transform
    X, Y = np.meshgrid(x, y)
    z = map_coordinates(z_grid, [(Y - dt.f) / dt.e - 0.5, (X - dt.c) / dt.a - 0.5], order=1, mode="nearest")
    return np.degrees(np.arctan2(np.hypot(X - centre_m[0], Y - centre_m[1]), centre_m[2] - z)), t


def test_cells_beyond_the_limit_are_nodata_and_the_rest_unchanged(block, tmp_path):
    root, unlimited = block
    work = tmp_path / "p"
    shutil.copytree(root, work)
    shutil.rmtree(work / "ortho")
    r = run("rectify", work, "--max-view-angle-deg", 8)  # the synthetic frames reach about 12 deg at their corners
    assert r.exit_code == 0, r.output
    index = json.loads((work / "ortho/frames/index.json").read_text())
    assert index["settings"]["max_view_angle_deg"]["value"] == 8
    for frame in index["frames"]:
        path = work / "ortho/frames" / frame["file"]
        angle, t = _view_angle_deg(path, frame["centre_m"], work / index["dem"])
        with rasterio.open(path) as ds:
            a, ok = ds.read(), ds.read_masks(1) > 0
        with rasterio.open(unlimited / "frames" / frame["file"]) as ds:
            b, okb, tb = ds.read(), ds.read_masks(1) > 0, ds.transform
        # the limited grid is cut to the cone: a window of the unlimited one
        dc, dr = round((t.c - tb.c) / t.a), round((t.f - tb.f) / t.e)
        okb, b = okb[dr:dr + ok.shape[0], dc:dc + ok.shape[1]], b[:, dr:dr + ok.shape[0], dc:dc + ok.shape[1]]
        assert okb.shape == ok.shape
        tol_deg = 0.05  # the DEM's bilinear height against the kernel's, at 0.1 % of the distance
        assert np.all(angle[ok] <= 8 + tol_deg)
        inside = okb & (angle < 8 - tol_deg)
        assert np.array_equal(ok & (angle < 8 - tol_deg), inside)
        assert np.array_equal(a[:, inside], b[:, inside])
        assert (okb & (angle > 8 + tol_deg)).sum() > 0.05 * okb.sum()  # the limit did cut the frame


def test_a_limit_beyond_the_frames_field_changes_nothing(block, tmp_path):
    root, unlimited = block
    work = tmp_path / "p"
    shutil.copytree(root, work)
    shutil.rmtree(work / "ortho")
    assert run("rectify", work, "--max-view-angle-deg", 40).exit_code == 0  # the frames reach about 12 deg
    for f in sorted((unlimited / "frames").glob("*.tif")):
        with rasterio.open(f) as ds, rasterio.open(work / "ortho/frames" / f.name) as dn:
            assert ds.transform == dn.transform and ds.shape == dn.shape
            assert np.array_equal(ds.read(), dn.read()) and np.array_equal(ds.read_masks(1), dn.read_masks(1))


@pytest.mark.parametrize("value", ["0", "95", "nan"])
def test_a_bad_limit_is_refused(block, value):
    root, _ = block
    r = run("rectify", root, "--max-view-angle-deg", value)
    assert r.exit_code == 2 and "max-view-angle" in r.output and "Traceback" not in r.output


def test_ground_beyond_the_lens_fold_is_not_rectified_from_the_corners():
    """A DJI DewarpData-like lens (k1 = -0.27) folds at about 53 deg off its axis: past it the model turns back
    and ground far outside the field of view lands inside the frame. Those cells are nodata; every valid cell's
    ray is inside the fold; the ground the frame does see is rectified as before."""
    from pyproj import CRS

    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.lens_kernels import distort_points
    from aerotri.geom.rotation import FLIP_YZ, rotation_matrix_opk
    from ortho.grid import GridToProject, OrthoGrid
    from ortho.rectify import rectify_frame
    from ortho.synthetic import smooth_dem

    utm = CRS.from_epsg(32651)
    cam = BrownCamera(focal_mm=8.77, pixel_um=9.6, width=684, height=456, k1=-0.267, k2=0.112, k3=-0.0332)
    fold = cam.fold_radius()
    assert fold is not None and 1.2 < fold < 1.45
    C = np.array([300000.0, 2730000.0, 250.0])
    R = rotation_matrix_opk(-30.0, 0.0, 0.0)  # 30 deg oblique, as the Tuniu frames
    dem = smooth_dem((C[0] - 700, C[1] - 700, C[0] + 700, C[1] + 700), 2.0, base_m=95.0, amplitude_m=3.0)
    grid = OrthoGrid.snapped(utm, (C[0] - 450, C[1] - 450, C[0] + 450, C[1] + 450), 1.0)
    img = np.full((cam.height, cam.width), 200, np.uint8)
    ortho, mask = rectify_frame(img, cam, C, R, dem, grid, tile_px=128)
    # each cell's ray in the camera frame, from the geometry
    X = grid.x_left_m + (np.arange(grid.width) + 0.5) * grid.res_m
    Y = grid.y_top_m - (np.arange(grid.height) + 0.5) * grid.res_m
    XX, YY = np.meshgrid(X, Y)
    from scipy.ndimage import map_coordinates

    Z = map_coordinates(dem.heights_m.astype(float), [(dem.y_top_m - YY) / dem.res_m - 0.5,
                                                      (XX - dem.x_left_m) / dem.res_m - 0.5], order=1)
    M = (R @ FLIP_YZ).T
    d = np.stack([XX - C[0], YY - C[1], Z - C[2]])
    xc, yc, zc = np.einsum("ij,jhw->ihw", M, d)
    r = np.hypot(xc, yc) / np.where(zc > 0, zc, np.nan)
    valid = mask > 0
    assert valid.sum() > 5000
    assert np.all(r[valid] <= fold * 1.002)
    # the cells the fold would have let in: beyond it, yet their (folded) image position lies inside the frame
    far = (zc > 0) & (r > fold * 1.01)
    xd, yd = distort_points(cam.kernel_params(), (xc / zc)[far], (yc / zc)[far])
    px, py = cam.focal_px * xd + cam.cx_px, cam.focal_px * yd + cam.cy_px
    folded_in = (px >= 0) & (px <= cam.width - 1) & (py >= 0) & (py <= cam.height - 1)
    assert folded_in.sum() > 100  # the test block has such ground, and none of it is rectified
    # inside the fold and inside the frame: rectified
    near = (zc > 0) & (r < fold * 0.99)
    xd, yd = distort_points(cam.kernel_params(), (xc / zc)[near], (yc / zc)[near])
    px, py = cam.focal_px * xd + cam.cx_px, cam.focal_px * yd + cam.cy_px
    inside = (px >= 1) & (px <= cam.width - 2) & (py >= 1) & (py <= cam.height - 2)
    assert valid[near][inside].mean() > 0.999


@pytest.mark.parametrize("output_epsg", [32651, 32650])
def test_no_surface_beyond_the_lens_fold_stands_in_a_true_orthos_zbuffer(output_epsg):
    """The true ortho's z-buffer of a plane holds the plane's depth: no point beyond the lens fold (which the DJI
    model would put inside the frame, nearer than the ground seen there) is written into it, in the project CRS
    (the vectorised scatter) and in another CRS (the anchors' kernel). Before the fold was tested in the kernels
    such points stood in 4,871 of the 4,902 cells of this frame's z-buffer, in front of the ground there. The
    maps image no cell beyond the fold, and the true ortho of the plane is its conventional ortho."""
    import cv2
    from pyproj import CRS

    from aerotri.geom.camera import BrownCamera
    from aerotri.geom.rotation import FLIP_YZ, rotation_matrix_opk
    from ortho.grid import GridToProject, OrthoGrid
    from ortho.rectify import FrameGeometry, fixed_point_maps, frame_zbuffer, rectify_frame
    from ortho.synthetic import smooth_dem

    utm = CRS.from_epsg(32651)
    cam = BrownCamera(focal_mm=8.77, pixel_um=9.6, width=684, height=456, k1=-0.267, k2=0.112, k3=-0.0332)
    fold = cam.fold_radius()
    C = np.array([300000.0, 2730000.0, 250.0])
    R = rotation_matrix_opk(-30.0, 0.0, 0.0)  # 30 deg oblique: ground beyond the fold folds into the frame
    plane_m = 95.0
    dsm = smooth_dem((C[0] - 700, C[1] - 700, C[0] + 700, C[1] + 700), 2.0, base_m=plane_m, amplitude_m=0.0,
                     slope=0.0)
    out_crs = CRS.from_epsg(output_epsg)
    to_project = GridToProject(out_crs, utm)
    ox, oy = to_project.to_output(C[0] + np.array([-450.0, 450.0]), C[1] + np.array([-450.0, 450.0]))
    grid = OrthoGrid.snapped(out_crs, (ox.min(), oy.min(), ox.max(), oy.max()), 1.0)
    geometry = FrameGeometry(cam, C, R)
    zbuffer = frame_zbuffer(geometry, dsm, grid, to_project)
    # the plane's depth along the optical axis through every pixel, the least per z-buffer cell and its 3 x 3
    # cells (the z-buffer keeps the nearest surface of a cell's neighbours)
    yy, xx = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    xn, yn = cam.pixel_to_normalized(xx, yy)
    d = np.stack([xn, yn, np.ones_like(xn)], axis=-1) @ (R @ FLIP_YZ).T
    depth = (plane_m - C[2]) / d[..., 2]
    h, w, cell = zbuffer.depth_m.shape[0], zbuffer.depth_m.shape[1], zbuffer.cell_px
    padded = np.full((h * cell, w * cell), np.inf)
    padded[:cam.height, :cam.width] = depth
    nearest = cv2.erode(padded.reshape(h, cell, w, cell).min(axis=(1, 3)).astype(np.float32), np.ones((3, 3), np.uint8),
                        borderType=cv2.BORDER_REPLICATE)
    seen = np.isfinite(zbuffer.depth_m)
    assert seen.mean() > 0.95
    assert np.all(zbuffer.depth_m[seen] >= 0.999 * nearest[seen])
    # the maps: no cell beyond the fold imaged
    mask = fixed_point_maps(geometry, dsm, grid, to_project)[2]
    Xg, Yg = to_project.exact(*np.meshgrid(grid.x_left_m + (np.arange(grid.width) + 0.5) * grid.res_m,
                                           grid.y_top_m - (np.arange(grid.height) + 0.5) * grid.res_m))
    xc, yc, zc = np.einsum("ij,jhw->ihw", (R @ FLIP_YZ).T,
                           np.stack([Xg - C[0], Yg - C[1], np.full_like(Xg, plane_m - C[2])]))
    r = np.hypot(xc, yc) / np.where(zc > 0, zc, np.nan)
    imaged = mask > 0
    assert imaged.sum() > 5000 and np.all(r[imaged] <= fold * 1.002)
    # the true ortho of a plane (nothing hides anything) is the conventional one
    img = (np.arange(cam.height * cam.width) % 251).astype(np.uint8).reshape(cam.height, cam.width)
    # the flat collinearity, as the geometry above (``FrameGeometry`` without the earth) and the plane's depth
    conventional = rectify_frame(img, cam, C, R, dsm, grid, to_project=to_project, tile_px=128, earth=False)
    true = rectify_frame(img, cam, C, R, dsm, grid, to_project=to_project, tile_px=128, occlusion_dsm=dsm, earth=False)
    assert np.array_equal(conventional[1], true[1]) and np.array_equal(conventional[0], true[0])
    assert np.array_equal(conventional[1] > 0, imaged)
