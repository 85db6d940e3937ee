"""Rectification and DOM check against synthetic truth: a textured orthophoto on a known smooth DEM,
frames rendered from it by inverse mapping through aerotri.geom.camera (ray-DEM intersection per pixel)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from pyproj import CRS

from aerotri.geom.camera import BrownCamera
from aerotri.geom.rotation import rotation_matrix_opk
from ortho.check import check_against_reference, displacement_statistics, match_patches
from ortho.cli import main
from ortho.grid import GridToProject, OrthoGrid, gk3_zone_crs, resolve_output_crs
from ortho.rectify import frame_grid, rectify_frame
from ortho.synthetic import render_frame, smooth_dem, textured_orthophoto, write_geotiff

UTM49 = CRS.from_epsg(32649)
RES = 0.2


@pytest.fixture(scope="module")
def scene():
    grid = OrthoGrid(UTM49, 500000.0, 3000300.0, RES, 1500, 1200)
    ref = textured_orthophoto(grid.height, grid.width, 3, seed=1)
    b = grid.bounds
    dem = smooth_dem((b[0] - 50, b[1] - 50, b[2] + 50, b[3] + 50), 1.0, amplitude_m=15.0)
    # distortion, principal-point offset and tilt exercise every term of the collinearity
    cam = BrownCamera(focal_mm=14.4, pixel_um=12.0, width=600, height=400, ppx_mm=0.05, ppy_mm=-0.03, k1=-0.04,
                      k2=0.01, p1=1e-4, p2=-5e-5)
    C = np.array([b[0] + 150, b[1] + 120, 400.0])
    R = rotation_matrix_opk(2.0, -1.5, 30.0)
    img, valid = render_frame(ref, grid, dem, cam, C, R)
    assert valid.all()
    return dict(grid=grid, ref=ref, dem=dem, cam=cam, C=C, R=R, img=img)


def test_rectified_frame_matches_truth_orthophoto(scene):
    s = scene
    ortho, mask = rectify_frame(s["img"], s["cam"], s["C"], s["R"], s["dem"], s["grid"], tile_px=256)
    assert 0.15 < (mask > 0).mean() < 0.4
    p = match_patches(ortho, s["ref"], mask > 0, None, res_m=RES)
    st = displacement_statistics(p.de_m, p.dn_m, RES)
    assert st.count > 80
    assert st.rms_xy_gsd < 0.1  # the 0.5 GSD requirement with a wide margin
    assert st.max_xy_gsd < 0.4
    # outside the frame: nodata
    assert np.all(ortho[mask == 0] == 0)


def test_wrong_eo_shows_up_as_displacement_of_the_right_sign(scene):
    s = scene
    ortho, mask = rectify_frame(s["img"], s["cam"], s["C"] + [1.0, 0.0, 0.0], s["R"], s["dem"], s["grid"])
    p = match_patches(ortho, s["ref"], mask > 0, None, res_m=RES, search_px=10)
    st = displacement_statistics(p.de_m, p.dn_m, RES)
    # a camera placed 1 m too far east puts every ground point about 1 m east in the DOM
    assert st.mean_e_m == pytest.approx(1.0, abs=0.06)
    assert abs(st.mean_n_m) < 0.05


def test_ignoring_distortion_is_detected(scene):
    s = scene
    ortho, mask = rectify_frame(s["img"], s["cam"].ideal(), s["C"], s["R"], s["dem"], s["grid"])
    p = match_patches(ortho, s["ref"], mask > 0, None, res_m=RES, search_px=12)
    assert displacement_statistics(p.de_m, p.dn_m, RES).rms_xy_gsd > 1.0


@pytest.mark.parametrize("interpolation", ["cubic", "lanczos"])
def test_other_kernels(scene, interpolation):
    s = scene
    ortho, mask = rectify_frame(s["img"], s["cam"], s["C"], s["R"], s["dem"], s["grid"], interpolation=interpolation)
    p = match_patches(ortho, s["ref"], mask > 0, None, res_m=RES)
    assert displacement_statistics(p.de_m, p.dn_m, RES).rms_xy_gsd < 0.1


def test_output_in_gauss_krueger_zone(scene, tmp_path):
    """Product in CGCS2000 / 3-degree GK CM 111E (EPSG:4546) from a UTM 49N project through a datum parameter
    set, checked after mapping the reference through the same set; without the set, refused."""
    from aerotri.geom.crs.datum import Transformation
    from aerotri.geom.crs.transform import BallparkRefused, CrsTransformer

    s = scene
    gk = CRS.from_epsg(4546)
    with pytest.raises(BallparkRefused):
        GridToProject(gk, UTM49)
    T = Transformation("bursa-wolf7", {"tx_m": 0.41, "ty_m": -0.27, "tz_m": 0.18, "rx_arcsec": 0.012,
                                       "ry_arcsec": -0.008, "rz_arcsec": 0.015, "scale_ppm": 0.021},
                       "EPSG:32649", "EPSG:4546")
    to_project = GridToProject(gk, UTM49, operation=CrsTransformer(UTM49, gk, params=T), z_m=float(np.nanmean(s["dem"].heights_m)))
    assert not to_project.identity
    grid = frame_grid(s["cam"], s["C"], s["R"], s["dem"], RES, gk, to_project=to_project)
    ortho, mask = rectify_frame(s["img"], s["cam"], s["C"], s["R"], s["dem"], grid, to_project=to_project)
    # the anchor grid reproduces the exact transform
    AX, AY, sp = to_project.anchors(grid)
    xs, ys = grid.centres(np.array([0.5 * sp]), np.array([0.5 * sp]))
    ex, ey = to_project.exact(xs, ys)
    assert sp >= 4
    dom = tmp_path / "dom_gk.tif"
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(dom, "w", driver="GTiff", width=grid.width, height=grid.height, count=3, dtype="uint8",
                           crs=gk, transform=grid.transform) as dst:
            dst.write(np.moveaxis(ortho, -1, 0))
            dst.write_mask(mask)
    ref = tmp_path / "ref_utm.tif"
    write_geotiff(ref, s["ref"], s["grid"].x_left_m, s["grid"].y_top_m, RES, UTM49)
    p, _ = check_against_reference(dom, ref, reference_operation=CrsTransformer(gk, UTM49, params=T))
    st = displacement_statistics(p.de_m, p.dn_m, RES)
    assert st.count > 50
    assert st.rms_xy_gsd < 0.2  # includes resampling the reference into the GK grid


def test_gauss_krueger_zone_choice():
    assert gk3_zone_crs(110.6).to_epsg() == 4546  # CGCS2000 CM 111E
    assert gk3_zone_crs(109.4).to_epsg() == 4545  # CM 108E
    assert gk3_zone_crs(111.2, "xian1980").to_epsg() == 2382
    # a block straddling the 109.5E zone boundary gets the single zone nearest its centre
    utm = CRS.from_epsg(32649)
    from pyproj import Transformer

    e, n = Transformer.from_crs("EPSG:4326", utm, always_xy=True).transform(109.6, 30.0)
    assert resolve_output_crs("gk3:cgcs2000", utm, (e, n)).to_epsg() == 4546
    e, n = Transformer.from_crs("EPSG:4326", utm, always_xy=True).transform(109.4, 30.0)
    assert resolve_output_crs("gk3:cgcs2000", utm, (e, n)).to_epsg() == 4545


# -- project level: CLI and clear errors -----------------------------------------------------------

@pytest.fixture(scope="module")
def project(tmp_path_factory):
    from tests.shared_builds import write_synthetic_project

    root = tmp_path_factory.mktemp("ortho_project")
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=0)
    return root


def test_cli_rectify_and_check(project):
    r = CliRunner().invoke(main, ["rectify", str(project)])
    assert r.exit_code == 0, r.output
    frames = sorted((project / "ortho" / "frames").glob("*.tif"))
    assert [f.stem for f in frames] == ["s01_001", "s01_002"]
    r = CliRunner().invoke(main, ["check", str(project), "--dom", str(frames[0]), "--reference",
                                  str(project / "truth" / "ortho.tif")])
    assert r.exit_code == 0, r.output
    import json

    # a frame is not the project's mosaic: its check goes beside it, not into the project's ortho/dom_report.json
    assert not (project / "ortho" / "dom_report.json").exists()
    rep = json.loads((project / "ortho" / "frames" / "s01_001_dom_report.json").read_text())
    assert rep["displacement"]["count"] > 30
    assert rep["displacement"]["rms_xy_gsd"] < 0.1
    assert (project / "ortho" / "frames" / "s01_001_dom_report.png").stat().st_size > 1000


def test_cli_check_points(project, tmp_path):
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,x_dom,y_dom\nA,452100.0,3407100.0,452100.1,3407100.0\nB,452120.0,3407090.0,452120.0,3406089.8\n"
                   .replace("3406089.8", "3407089.8"))
    r = CliRunner().invoke(main, ["rectify", str(project)])
    assert r.exit_code == 0
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["check", str(project), "--dom", str(project / "ortho/frames/s01_001.tif"),
                                  "--points", str(pts), "--out", str(out)])
    assert r.exit_code == 0, r.output
    import json

    rep = json.loads(out.with_suffix(".json").read_text())
    assert rep["displacement"]["rms_xy_m"] == pytest.approx(np.sqrt((0.1 ** 2 + 0.2 ** 2) / 2), abs=1e-6)
    bad = tmp_path / "bad.csv"
    bad.write_text("id,x,y\nA,1,2\n")
    r = CliRunner().invoke(main, ["check", str(project), "--dom", str(project / "ortho/frames/s01_001.tif"),
                                  "--points", str(bad)])
    assert r.exit_code == 2 and "x_dom" in r.output


def test_error_frame_without_eo(project, tmp_path):
    eo = tmp_path / "eo.txt"
    eo.write_text((project / "at" / "eo.txt").read_text().replace("s01_002", "s09_009"))
    r = CliRunner().invoke(main, ["rectify", str(project), "--eo", str(eo)])
    assert r.exit_code == 2
    assert "no exterior orientation for frame(s) s01_002" in r.output


def test_error_dem_crs_mismatch(project, tmp_path):
    with rasterio.open(project / "lidar_out" / "dem.tif") as ds:
        a, t = ds.read(1), ds.transform
    dem = tmp_path / "dem_4547.tif"
    write_geotiff(dem, a, t.c, t.f, t.a, "EPSG:4547")
    r = CliRunner().invoke(main, ["rectify", str(project), "--dem", str(dem)])
    assert r.exit_code == 2
    assert "CRS mismatch" in r.output and "EPSG:4547" in r.output and "EPSG:32649" in r.output


def test_error_dem_does_not_cover_frame(project, tmp_path):
    with rasterio.open(project / "lidar_out" / "dem.tif") as ds:
        a, t = ds.read(1), ds.transform
    dem = tmp_path / "dem_small.tif"
    write_geotiff(dem, a[: a.shape[0] // 3], t.c, t.f, t.a, "EPSG:32649")  # only the northern third
    r = CliRunner().invoke(main, ["rectify", str(project), "--dem", str(dem)])
    assert r.exit_code == 2
    assert "does not cover frame s01_001" in r.output
    assert not (tmp_path / "ortho").exists()


def test_error_missing_dem(project, tmp_path):
    """A mistyped --dem is named as not found, without the advice to "pass --dem" the user already followed
    (Tuniu trial); the project's own DEM, missing, gets that advice."""
    r = CliRunner().invoke(main, ["rectify", str(project), "--dem", str(tmp_path / "nope.tif")])
    assert r.exit_code == 2 and "nope.tif: DEM not found" in r.output
    assert "pass --dem" not in r.output and "lidarctl" not in r.output
    p = tmp_path / "p"
    shutil.copytree(project, p, ignore=shutil.ignore_patterns("ortho", "dem.tif"))
    r = CliRunner().invoke(main, ["rectify", str(p)])
    assert r.exit_code == 2 and "dem.tif: DEM not found" in r.output
    assert "lidarctl rasters" in r.output and "pass --dem" in r.output
    assert not (p / "ortho").exists()


def test_a_true_ortho_without_a_dem_says_it_needs_one(project, tmp_path):
    """Tuniu's trial: a drone block with ODM's DSM alone, `ortho rectify --true-ortho --dsm DSM` said only
    "lidar_out/dem.tif: DEM not found (run `lidarctl` to produce it, or pass --dem)"; now it says that the true ortho
    needs a DEM too and which ones will do, and nothing is written."""
    p = tmp_path / "p"
    shutil.copytree(project, p, ignore=shutil.ignore_patterns("ortho"))
    (p / "lidar_out" / "dem.tif").unlink()
    r = CliRunner().invoke(main, ["rectify", str(p), "--true-ortho", "--dsm", str(p / "truth" / "dsm.tif")])
    assert r.exit_code == 2, r.output
    assert "lidar_out/dem.tif: DEM not found; the true ortho needs a DEM beside the DSM" in r.output
    assert "--dem" in r.output and "ortho dem" in r.output and "Traceback" not in r.output
    assert not (p / "ortho").exists()


def test_heights_on_grid_match_bilinear_dem(scene):
    from ortho.rectify import heights_on_grid

    s = scene
    g = s["grid"].window(100, 100, 300, 200)
    z = heights_on_grid(s["dem"], g)
    xs, ys = g.centres()
    X, Y = np.meshgrid(xs, ys)
    exact = s["dem"].sample(X, Y)
    # 1/32-cell position quantisation of cv2.warpAffine: about a centimetre on this terrain
    assert np.nanmax(np.abs(z - exact)) < 0.02


def test_fast_path_equals_general_kernel(scene):
    """The affine fast path (grid in the project CRS) and the anchor-grid kernel give the same maps."""
    from ortho.rectify import FrameGeometry, fixed_point_maps, image_coordinates

    s = scene
    g = s["grid"].window(200, 150, 512, 400)
    geom = FrameGeometry(s["cam"], s["C"], s["R"])
    mi, mf, mask, _, _ = fixed_point_maps(geom, s["dem"], g)
    mx, my, _, _ = image_coordinates(geom, s["dem"], g)
    x = mi[:, :, 0] + (mf % 32) / 32.0
    y = mi[:, :, 1] + (mf // 32) / 32.0
    ok = mask > 0
    assert ok.sum() > 20000
    assert abs(ok.mean() - (mx > -5e4).mean()) < 1e-3
    both = ok & (mx > -5e4)
    assert np.max(np.abs(x[both] - mx[both])) < 0.05 and np.max(np.abs(y[both] - my[both])) < 0.05


@pytest.mark.parametrize("res_m, tile_px, compact", [(0.1, 256, True), (2.0, 1024, False)])
def test_wide_frame_resampled_from_compact_windows_gives_the_same_pixels(monkeypatch, res_m, tile_px, compact):
    """A 3-band frame with rows of 32 KiB or more (here 11,264 px; the DMC has 13,824) is resampled from a
    copy of the window each tile reads (cv2.remap's vectorised path): the same ortho and mask to the bit
    as from the whole frame, at the frame's edges too; a tile reading wider than that uses the frame."""
    import ortho.rectify as rectify

    cam = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=11264, height=256, ppx_mm=0.1, ppy_mm=-0.06, k1=-4e-3,
                      k2=1e-3, p1=1e-5, p2=-5e-6)
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8)
    assert img.strides[0] >= rectify._REMAP_VECTOR_MAX_STEP
    C = np.array([500000.0, 3000000.0, 400.0])
    R = rotation_matrix_opk(1.0, -0.5, 3.0)
    dem = smooth_dem((C[0] - 300, C[1] - 100, C[0] + 300, C[1] + 100), 2.0, amplitude_m=15.0)
    grid = frame_grid(cam, C, R, dem, res_m, UTM49, to_project=GridToProject(UTM49, UTM49))
    windows = []
    source = rectify.SourceWindow.source

    def counted(self, image, *args, **kw):
        out = source(self, image, *args, **kw)
        windows.append(out is not image)
        return out

    monkeypatch.setattr(rectify.SourceWindow, "source", counted)
    ortho, mask = rectify_frame(img, cam, C, R, dem, grid, tile_px=tile_px)
    assert windows and all(windows) if compact else not any(windows)
    monkeypatch.setattr(rectify, "_REMAP_VECTOR_MAX_STEP", 1 << 40)  # the whole frame for every tile
    ortho_whole, mask_whole = rectify_frame(img, cam, C, R, dem, grid, tile_px=tile_px)
    assert (mask > 0).mean() > 0.1 and ortho[mask > 0].std() > 30  # resampled noise, not zeros
    assert np.array_equal(mask, mask_whole) and np.array_equal(ortho, ortho_whole)
    # the ortho runs from end to end of the strip, so tiles read the frame's first and last columns
    edge = max(1, grid.width // 50)
    assert mask[:, :edge].any() and mask[:, -edge:].any()


def test_one_frame_command_imports_only_what_it_uses(tmp_path):
    """``ortho rectify`` of one frame, as the console script runs it in a fresh interpreter: the frame is
    written, and the command imports neither Dask (one task runs in the command's own thread) nor the
    plotting or other stages' libraries (their import is a fixed cost of every run)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from tests.shared_builds import write_synthetic_project

    repo = Path(__file__).resolve().parents[2]
    write_synthetic_project(tmp_path, strips=1, frames_per_strip=2, buildings=0)
    code = ("import sys; sys.argv[0] = 'ortho'; from ortho.cli import main\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print('imported:' + ','.join(m for m in ('dask', 'distributed', 'matplotlib', 'gtsam', 'laspy', 'sklearn') "
            "if m in sys.modules))")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", code, "rectify", str(tmp_path), "--frames", "s01_002"],
                       capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "imported:"  # none of them
    with rasterio.open(tmp_path / "ortho" / "frames" / "s01_002.tif") as ds:
        assert ds.count == 3 and ds.read_masks(1).any()
