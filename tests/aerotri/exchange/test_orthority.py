"""orthority's parameter files: the round trip through an adjusted project, the NGI block's own orthority
files against the national AT, orthority's interior conventions, and bad input."""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import CrsError, InputError
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files
from aerotri.geom.camera import oriented_camera
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo, read_gnss

_spec = importlib.util.spec_from_file_location("realdata_ngi", Path(__file__).parents[2] / "realdata_ngi.py")
ngi = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("realdata_ngi", ngi)  # dataclasses look their module up
_spec.loader.exec_module(ngi)


def test_round_trip_through_an_adjusted_project(adjusted_tiny, tmp_path, fresh_project):
    root, _ = adjusted_tiny
    out = tmp_path / "exp"
    export_project(root, ["orthority"], out)
    p = Project.open(root)
    eo, cam = read_eo(p.eo_path), oriented_camera(p)[0]
    for ext, as_gnss in (("ext_param.csv", False), ("ext_param.geojson", True)):
        dst = fresh_project(root, tmp_path / ext)
        import_files(dst, "orthority", [out / "orthority" / "int_param.yaml", out / "orthority" / ext],
                     ImportSettings(as_gnss=as_gnss, sigma_xyz_m=(0.1, 0.1, 0.2)))
        q = Project.open(dst)
        back = read_eo(q.imported_eo_path)
        assert back.image_id == eo.image_id
        assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4  # the files keep 0.1 mm
        assert np.abs(back.opk_deg - eo.opk_deg).max() < 2e-7  # and 1e-7 degrees (GeoJSON: 1e-12 rad)
        if as_gnss:  # the camera positions as GNSS only when asked, with the stated accuracies
            g = read_gnss(q.gnss_path)
            assert np.allclose(g.position_m, back.centre_m) and np.allclose(g.sigma_m, [0.1, 0.1, 0.2])
        else:
            assert not q.gnss_path.exists()
        got = read_camera(q.camera_path)
        assert got.MODEL == cam.MODEL and (got.width, got.height) == (cam.width, cam.height)
        for f in got.fields():
            assert getattr(got, f) == pytest.approx(getattr(cam, f), rel=1e-9, abs=1e-12), f
    # the self-calibrated camera (not the nominal one) went out
    assert cam != read_camera(p.camera_path)


def test_interior_conventions(tiny_project, tmp_path, fresh_project):
    """cx, cy: offset of the principal point from the image centre in pixels / max(w, h), y down; focal
    length and sensor in one unit (mm); no sensor_size: focal length / image width."""
    root = fresh_project(tiny_project, tmp_path / "p")
    yaml_path = tmp_path / "int.yaml"
    yaml_path.write_text("cam A:\n  type: brown\n  im_size: [4000, 3000]\n  focal_len: 24.0\n"
                         "  sensor_size: [16.0, 12.0]\n  cx: 0.01\n  cy: -0.02\n  k1: -0.1\n  k2: 0.02\n"
                         "  p1: 0.001\n  p2: -0.002\n  k3: 0.003\n")
    import_files(root, "orthority", [yaml_path])
    cam = read_camera(root / "camera.toml")
    assert cam.pixel_um == pytest.approx(4.0) and cam.focal_px == pytest.approx(6000.0)
    assert cam.cx_px == pytest.approx(1999.5 + 0.01 * 4000)
    assert cam.cy_px == pytest.approx(1499.5 - 0.02 * 4000)
    assert (cam.k1, cam.k2, cam.p1, cam.p2, cam.k3) == (-0.1, 0.02, 0.001, -0.002, 0.003)
    # the flat one-camera layout without sensor_size; a pinhole
    yaml_path.write_text("type: pinhole\nim_size: [640, 480]\nfocal_len: 0.8\n")
    import_files(root, "orthority", [yaml_path], overwrite=True)
    cam = read_camera(root / "camera.toml")
    assert cam.MODEL == "pinhole" and cam.focal_px == pytest.approx(0.8 * 640)
    assert cam.cx_px == pytest.approx(319.5) and cam.cy_px == pytest.approx(239.5)


@pytest.mark.realdata
def test_ngi_orthority_files_are_the_national_at(shared_data, tmp_path):
    """NGI: orthority's files of the block (GeoJSON in radians, full precision; OPK CSV in degrees, 3
    decimals, CRS in the .prj) give the national AT's camera_pos_ori.txt: our angle convention is theirs."""
    data = shared_data / "ngi_dmc"
    fmt = data / "formats"
    ref = ngi.read_reference(data)
    for ext, tol_m, tol_deg in (("ngi_ext_param.geojson", 1e-4, 1e-6), ("ngi_xyz_opk.csv", 5e-4, 5e-4)):
        root = ngi.build_ngi_project(data, tmp_path / ext)
        import_files(root, "orthority", [fmt / "ngi_int_param.yaml", fmt / ext], overwrite=True)
        eo = read_eo(root / "imported" / "eo.txt")
        assert eo.image_id == ref.image_id
        assert np.abs(eo.centre_m - ref.centre_m).max() < tol_m
        assert np.abs(eo.opk_deg - ref.opk_deg).max() < tol_deg
        cam = read_camera(root / "camera.toml")
        assert (cam.MODEL, cam.width, cam.height) == ("pinhole", ngi.WIDTH_PX, ngi.HEIGHT_PX)
        assert cam.focal_mm == ngi.FOCAL_MM and cam.pixel_um == pytest.approx(ngi.PIXEL_UM)
        assert cam.cx_px == pytest.approx((ngi.WIDTH_PX - 1) / 2) and cam.cy_px == pytest.approx((ngi.HEIGHT_PX - 1) / 2)


GOOD_CSV = "filename,x,y,z,omega,phi,kappa\nimg1,500100.0,4100200.0,900.0,0.5,-0.3,90.0\n"


@pytest.mark.parametrize("text, match", [
    ("filename,x,y,z,omega,phi\nimg1,1,2,3,4,5\n", "header lacks kappa"),
    ("filename,x,y,z,omega,phi,kappa\nimg1,500100.0,4100200.0,900.0,0.5,-0.3\n", r":2: expected 7 fields"),
    ("filename,x,y,z,omega,phi,kappa\nimg1,500100.0,nan,900.0,0.5,-0.3,90\n", r":2: y is NaN"),
    ("filename,x,y,z,omega,phi,kappa\nimg1,500100.0,4100200.0,900.0,0.5,-0.3,ninety\n", r":2: kappa = 'ninety'"),
    (GOOD_CSV + "img1.tif,500100.0,4100200.0,900.0,0.5,-0.3,90.0\n", r":3: duplicate image 'img1'"),
])
def test_bad_opk_csv(tiny_project, tmp_path, text, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "ext.csv"
    f.write_text(text)
    with pytest.raises(InputError, match=match):
        import_files(root, "orthority", [f], overwrite=True)
    assert not (root / "imported").exists()


def test_crs_is_required_and_checked(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "ext.csv"
    f.write_text(GOOD_CSV)
    with pytest.raises(CrsError, match="no CRS; put it in ext.prj"):
        import_files(root, "orthority", [f])
    (tmp_path / "ext.prj").write_text("EPSG:999999\n")
    with pytest.raises(CrsError, match="ext.prj"):
        import_files(root, "orthority", [f])
    (tmp_path / "ext.prj").unlink()
    # --crs instead of the sidecar; the project's CRS -> no change
    import_files(root, "orthority", [f], options=ImportSettings(crs=Project.open(root).crs))
    eo = read_eo(root / "imported" / "eo.txt")
    assert np.allclose(eo.centre_m, [[500100.0, 4100200.0, 900.0]]) and np.allclose(eo.opk_deg, [[0.5, -0.3, 90.0]])


def test_crs_given_overrides_a_sidecar_and_says_so(tiny_project, tmp_path, fresh_project, caplog):
    """Trial s96 M7: with a .prj beside the CSV, --crs was dropped without a word (a user overriding a wrong sidecar
    would not notice). --crs is taken and a different sidecar named; the same one says nothing."""
    import logging

    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "ext.csv"
    f.write_text(GOOD_CSV)
    (tmp_path / "ext.prj").write_text("EPSG:32735\n")   # wrong: UTM 35S
    crs = Project.open(root).crs
    with caplog.at_level(logging.WARNING):
        import_files(root, "orthority", [f], options=ImportSettings(crs=crs))
    assert "not its sidecar ext.prj (EPSG:32735" in caplog.text
    assert np.allclose(read_eo(root / "imported" / "eo.txt").centre_m, [[500100.0, 4100200.0, 900.0]])
    caplog.clear()
    (tmp_path / "ext.prj").write_text(f"{crs}\n")
    with caplog.at_level(logging.WARNING):
        import_files(root, "orthority", [f], options=ImportSettings(crs=crs), overwrite=True)
    assert "sidecar" not in caplog.text


def test_other_crs_rotates_onto_the_project_grid(tiny_project, tmp_path, fresh_project):
    """A position and attitude in the neighbouring UTM zone: the centre is transformed and the attitude is
    turned by the grid convergence between the zones (kappa changes, the viewing direction does not)."""
    from aerotri.geom.crs.definition import project_crs
    from aerotri.geom.rotation import rotation_matrix_opk
    from aerotri.geom.crs.transform import transform_points

    root = fresh_project(tiny_project, tmp_path / "p")
    crs = project_crs(Project.open(root))
    zone = crs.to_epsg()
    other = f"EPSG:{zone + 1}"
    x, y, z = 500100.0, 4100200.0, 900.0
    xo, yo, zo = transform_points(np.array([x]), np.array([y]), np.array([z]), from_crs=crs,
                                  to_crs=pyproj.CRS(other))
    f = tmp_path / "ext.csv"
    f.write_text(f"filename,x,y,z,omega,phi,kappa\nimg1,{xo[0]:.4f},{yo[0]:.4f},{zo[0]:.4f},0,0,30\n")
    (tmp_path / "ext.prj").write_text(other)
    import_files(root, "orthority", [f])
    eo = read_eo(root / "imported" / "eo.txt")
    assert np.abs(eo.centre_m[0] - [x, y, z]).max() < 1e-3
    # grid north of the other zone (6 degrees east) is turned clockwise from ours by about 6 sin(lat) deg
    d_kappa = eo.opk_deg[0, 2] - 30.0
    lat = 37.05  # 4100 km north
    assert abs(abs(d_kappa) - 3.0 * np.sin(np.radians(lat)) * 2) < 0.3
    assert abs(eo.opk_deg[0, 0]) < 1e-6 and abs(eo.opk_deg[0, 1]) < 1e-6
    assert np.allclose(rotation_matrix_opk(*eo.opk_deg[0])[:, 2], [0, 0, 1], atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("cam:\n  im_size: [10, 10]\n  focal_len: 1\n", "'type' is missing"),
    ("cam:\n  type: fisheye\n  im_size: [10, 10]\n  focal_len: 1\n", "type 'fisheye' is not one of"),
    ("cam:\n  type: pinhole\n  im_size: [10]\n  focal_len: 1\n", "im_size must be a list of 2"),
    ("cam:\n  type: pinhole\n  im_size: [10, 10]\n  focal_len: .nan\n", "focal_len is NaN"),
    ("cam:\n  type: pinhole\n  im_size: [10, 10]\n  focal_len: 1\n  k1: 0.1\n", r"unsupported key\(s\) \['k1'\]"),
    ("cam:\n  type: opencv\n  im_size: [10, 10]\n  focal_len: 1\n  k4: 0.1\n", r"opencv coefficients \['k4'\]"),
    ("cam:\n  type: brown\n  im_size: [10, 10]\n  focal_len: [1, 2]\n", "different x and y"),
    ("a: [1\n", "not valid YAML"),
])
def test_bad_interior(tiny_project, tmp_path, text, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "int.yaml"
    f.write_text(text)
    with pytest.raises(InputError, match=match):
        import_files(root, "orthority", [f])


def test_interior_in_metres_is_refused_and_nothing_written(tiny_project, tmp_path, fresh_project):
    """focal_len 0.12 with sensor_size in mm (orthority takes them in one unit): a 0.12 mm lens, 1.25 px on a
    1728 px side, was written to camera.toml with exit 0 (the adjustment then stopped with a traceback)."""
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "int.yaml"
    f.write_text("cam:\n  type: brown\n  im_size: [1728, 960]\n  focal_len: 0.12\n  sensor_size: [165.888, 92.16]\n")
    before = sorted(q.relative_to(root) for q in root.rglob("*"))
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "orthority", str(f), "--force"])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "focal_len (focal_mm = 0.12) is 1.25 px at pixel_um = 96" in r.output
    assert "in metres? 0.12 m = 120 mm" in r.output
    assert sorted(q.relative_to(root) for q in root.rglob("*")) == before


def test_focal_length_in_mm_without_sensor_size_is_refused(tiny_project, tmp_path, fresh_project):
    """focal_len 120 (mm) with sensor_size left out reads, by orthority's convention, as normalised by the image
    width: a 207,360 px lens on 1728 px frames (0.48 deg) was written with exit 0 and a note on the pixel size."""
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "int.yaml"
    f.write_text("cam:\n  type: brown\n  im_size: [1728, 960]\n  focal_len: 120.0\n")
    with pytest.raises(InputError, match=r"focal_len 120 without sensor_size is normalised by the image width "
                                         r"\(orthority's convention\): 207360 px"):
        import_files(root, "orthority", [f])
    f.write_text("cam:\n  type: brown\n  im_size: [1728, 960]\n  focal_len: 0.7234\n")  # normalised: read
    import_files(root, "orthority", [f])
    assert read_camera(root / "camera.toml").focal_px == pytest.approx(0.7234 * 1728)


def test_bad_geojson_and_cli_exit_code(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "ext.geojson"
    f.write_text('{"type": "FeatureCollection", "world_crs": "EPSG:32649", "features": '
                 '[{"type": "Feature", "properties": {"filename": "a", "xyz": [1, 2], "opk": [0, 0, 0]}}]}')
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "orthority", str(f)])
    assert r.exit_code == 2 and "features[0]: properties.xyz must be a list of 3 numbers" in r.output
    assert "Traceback" not in r.output
