"""``aerotri import --format exif``: GNSS positions, DJI RTK accuracies, the DJI factory calibration and gimbal
attitudes from the frames' own EXIF/XMP; checked against the tag text read independently, and against
OpenSfM's solution of the same frames."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.exchange import ImportSettings, import_files
from aerotri.exchange.exif import opk_from_gimbal, read_frame_metadata
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo, read_gnss
from aerotri.geom.rotation import rotation_matrix_opk


def _project(tmp_path, crs, name="p"):
    root = tmp_path / name
    root.mkdir()
    (root / "project.toml").write_text(f'[project]\nname = "{name}"\ncrs = "{crs}"\n')
    return root


def _utm(lon, lat, h, epsg):
    from pyproj import CRS, Transformer

    t = Transformer.from_crs(CRS("EPSG:4979"), CRS(epsg).to_3d(), always_xy=True)
    return np.column_stack(t.transform(lon, lat, h))


def _xmp_values(path) -> dict:
    """drone-dji attributes of the raw XMP packet in the file's bytes (no GDAL, no EXIF library)."""
    data = path.read_bytes()
    packet = data[data.index(b"<x:xmpmeta"):data.index(b"</x:xmpmeta>")].decode()
    return dict(re.findall(r'drone-dji:(\w+)="([^"]*)"', packet))


# -- conventions ----------------------------------------------------------------------------------------
def test_gimbal_angles_to_omega_phi_kappa():
    assert np.allclose(opk_from_gimbal((0.0, -90.0, 0.0)), 0.0, atol=1e-9)  # nadir, top of the image north
    # nadir, flying east: the top of the image faces east, a clockwise turn of the image = kappa -90
    assert np.allclose(opk_from_gimbal((90.0, -90.0, 0.0)), (0.0, 0.0, -90.0), atol=1e-9)
    # pitched 60 degrees down looking north: the view (-z of the photogrammetric camera) 30 degrees off nadir
    R = rotation_matrix_opk(*opk_from_gimbal((0.0, -60.0, 0.0)))
    assert np.allclose(R @ [0, 0, -1.0], [0.0, np.sin(np.radians(30)), -np.cos(np.radians(30))], atol=1e-12)
    # looking east at 60 degrees down: the view turns east, the image's x axis points south
    R = rotation_matrix_opk(*opk_from_gimbal((90.0, -60.0, 0.0)))
    assert np.allclose(R @ [0, 0, -1.0], [np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))], atol=1e-12)
    assert np.allclose(R @ [1.0, 0, 0], [0.0, -1.0, 0.0], atol=1e-12)
    # roll right (right side down) of a camera looking north at the horizon tilts the image's x axis down
    R = rotation_matrix_opk(*opk_from_gimbal((0.0, 0.0, 10.0)))
    assert np.allclose(R @ [0, 0, -1.0], [0.0, 1.0, 0.0], atol=1e-12)
    assert np.allclose(R @ [1.0, 0, 0], [np.cos(np.radians(10)), 0.0, -np.sin(np.radians(10))], atol=1e-12)


# -- real data ------------------------------------------------------------------------------------------
@pytest.mark.realdata
def test_tuniu_exif_xmp_import_equal_to_the_tag_values(shared_data, tmp_path):
    """Tuniu: positions, RTK accuracies and the scaled factory calibration equal the raw XMP text."""
    images = shared_data / "tuniu_drone" / "images"
    root = _project(tmp_path, "EPSG:32651")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(images)])
    assert r.exit_code == 0, r.output
    g = read_gnss(root / "gnss.txt")
    files = sorted(images.glob("*.tif"))
    assert g.image_id == [f.stem for f in files]
    tags = [_xmp_values(f) for f in files]
    lat = np.array([float(t["GpsLatitude"]) for t in tags])
    lon = np.array([float(t["GpsLongtitude"]) for t in tags])
    alt = np.array([float(t["AbsoluteAltitude"]) for t in tags])
    assert np.abs(g.position_m - _utm(lon, lat, alt, "EPSG:32651")).max() < 1e-4  # gnss.txt keeps 0.1 mm
    sig = np.array([[float(t["RtkStdLon"]), float(t["RtkStdLat"]), float(t["RtkStdHgt"])] for t in tags])
    assert np.allclose(g.sigma_m, sig, atol=5e-5)
    # the factory calibration, at the size on disk (1368 x 912 of the 5472 x 3648 px the EXIF states)
    cam = read_camera(root / "camera.toml")
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in tags[0]["DewarpData"].split(";")[1].split(","))
    assert (cam.width, cam.height) == (1368, 912)
    s = 1368 / 5472
    assert cam.focal_px == pytest.approx(0.5 * (fx + fy) * s, rel=1e-9)
    # DJI: principal point = photo centre + (cx, cy) in corner-origin pixels; ours: centre of the top-left pixel
    assert cam.cx_px == pytest.approx((5472 / 2 + cx) * s - 0.5, abs=1e-6)
    assert cam.cy_px == pytest.approx((3648 / 2 + cy) * s - 0.5, abs=1e-6)
    assert (cam.k1, cam.k2, cam.p1, cam.p2, cam.k3) == (k1, k2, p1, p2, k3)
    # the pixel size: the EXIF focal length over DJI's CalibratedFocalLength, on disk four times as large
    assert cam.pixel_um == pytest.approx(8.8 / float(tags[0]["CalibratedFocalLength"]) * 1000 / s, rel=1e-9)


@pytest.mark.realdata
def test_tuniu_gimbal_attitudes_agree_with_opensfm(shared_data, tmp_path):
    """The gimbal angles (the drone's estimate) against OpenSfM's solution of the same frames: the
    conversion's axes and signs are right when they agree to about a degree (one frame pitched 60 degrees
    looking east, the others in the other three directions)."""
    root = _project(tmp_path, "EPSG:32651", "g")
    import_files(root, "exif", [shared_data / "tuniu_drone" / "images"])
    mine = read_eo(root / "imported" / "eo.txt")
    other = _project(tmp_path, "EPSG:32651", "o")
    shutil.copytree(shared_data / "tuniu_drone" / "images", other / "images")
    import_files(other, "opensfm", [shared_data / "tuniu_drone" / "opensfm" / "reconstruction.json"])
    ref = read_eo(other / "imported" / "eo.txt")
    assert mine.image_id == ref.image_id
    R = mine.rotations()
    R0 = ref.rotations()
    angle = np.degrees(np.arccos(np.clip((np.trace(np.swapaxes(R, 1, 2) @ R0, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert angle.max() < 2.0, angle  # measured 0.9-1.2 degrees
    assert np.abs(mine.centre_m - ref.centre_m).max() < 3.0  # OpenSfM's centres vs the GNSS antenna


@pytest.mark.realdata
def test_brighton_exif_positions_and_nominal_camera(shared_data, tmp_path):
    """A Phantom 3 without RTK or DewarpData: positions equal to the README's table of the EXIF, no
    accuracies unless given, a nominal camera from the focal length."""
    import csv

    data = shared_data / "brighton_beach"
    root = _project(tmp_path, "EPSG:32615")
    import_files(root, "exif", [data / "images"], ImportSettings(sigma_xyz_m=(3.0, 3.0, 5.0)))
    g = read_gnss(root / "gnss.txt")
    rows = {r["image"].rsplit(".", 1)[0]: r for r in csv.DictReader(open(data / "exif_positions.csv"))}
    assert g.image_id == sorted(rows)
    lla = np.array([[float(rows[i]["lon"]), float(rows[i]["lat"]), float(rows[i]["abs_alt_m"])] for i in g.image_id])
    d = g.position_m - _utm(lla[:, 0], lla[:, 1], lla[:, 2], "EPSG:32615")
    # the table keeps 8 decimals of a degree (<1 mm); its altitudes are EXIF's (3 decimals), XMP's have 2
    assert np.abs(d[:, :2]).max() < 2e-3 and np.abs(d[:, 2]).max() < 6e-3
    assert np.allclose(g.sigma_m, [3.0, 3.0, 5.0])
    cam = read_camera(root / "camera.toml")
    assert (cam.width, cam.height, cam.focal_mm) == (4000, 2250, 3.61)
    assert cam.k1 == 0.0 and cam.ppx_mm == 0.0


# -- synthetic frames and bad input ---------------------------------------------------------------------
XMP = ('<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF '
       'xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="DJI Meta Data" '
       'xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" {attrs}></rdf:Description></rdf:RDF></x:xmpmeta>')


def _frame(path, exif=None, xmp=None, size=(64, 48)):
    """A small GeoTIFF-less frame with EXIF items (GDAL metadata) and an XMP packet, as the Tuniu frames."""
    import rasterio

    with rasterio.open(path, "w", driver="GTiff", width=size[0], height=size[1], count=1, dtype="uint8") as ds:
        ds.write(np.zeros((1, size[1], size[0]), np.uint8))
        if exif:
            ds.update_tags(**exif)
        if xmp is not None:
            ds.update_tags(ns="xml:XMP", **{"xml:XMP": XMP.format(attrs=" ".join(f'drone-dji:{k}="{v}"' for k, v in xmp.items()))})
    return path


GOOD = dict(GpsLatitude="24.68", GpsLongtitude="120.95", AbsoluteAltitude="+150.5", RtkStdLon="0.02",
            RtkStdLat="0.03", RtkStdHgt="0.05", CalibratedFocalLength="50.0",
            DewarpData="2020-01-01;51.0,50.0,1.5,-2.0,-0.1,0.01,0.001,-0.002,0.003",
            GimbalYawDegree="+10.0", GimbalPitchDegree="-90.0", GimbalRollDegree="+0.0")
EXIF = {"EXIF_FocalLength": "(8.8)", "EXIF_PixelXDimension": "128", "EXIF_PixelYDimension": "96", "EXIF_Model": "TEST"}


def test_synthetic_frames_read_back(tmp_path):
    """Tags written into frames come back: EXIF degrees-minutes-seconds when XMP has no position, the
    calibration scaled by the size on disk."""
    f = _frame(tmp_path / "a.tif", EXIF, GOOD)
    m = read_frame_metadata(f)
    assert (m.lat_deg, m.lon_deg, m.alt_m) == (24.68, 120.95, 150.5)
    assert m.rtk_sigma_m == (0.02, 0.03, 0.05) and m.full_size == (128, 96) and (m.width, m.height) == (64, 48)
    dms = dict(EXIF, EXIF_GPSLatitude="(33) (30) (36)", EXIF_GPSLatitudeRef="S", EXIF_GPSLongitude="(70) (15) (0)",
               EXIF_GPSLongitudeRef="W", EXIF_GPSAltitude="(12.5)", EXIF_GPSAltitudeRef="1")
    m = read_frame_metadata(_frame(tmp_path / "b.tif", dms, {}))
    assert m.lat_deg == pytest.approx(-33.51) and m.lon_deg == pytest.approx(-70.25) and m.alt_m == -12.5
    root = _project(tmp_path, "EPSG:32651")
    (tmp_path / "imgs").mkdir()
    shutil.move(f, tmp_path / "imgs" / "a.tif")
    import_files(root, "exif", [tmp_path / "imgs"])
    cam = read_camera(root / "camera.toml")
    assert cam.focal_px == pytest.approx(50.5 / 2) and cam.cx_px == pytest.approx((64 + 1.5) / 2 - 0.5)
    assert cam.cy_px == pytest.approx((48 - 2.0) / 2 - 0.5)
    # nadir, yaw 10 degrees from true north: kappa -10 degrees from true north, plus the meridian convergence
    from pyproj import Proj

    conv = Proj("EPSG:32651").get_factors(120.95, 24.68).meridian_convergence
    assert read_eo(root / "imported" / "eo.txt").opk_deg[0, 2] == pytest.approx(-10.0 + conv, abs=2e-6)


def test_a_2d_crs_reads_the_altitudes_as_ellipsoidal(tmp_path, synthetic_geoid):
    """``--crs EPSG:4326`` names no height system: the altitudes are ellipsoidal heights (DJI's RTK altitudes are),
    as before s21, converted to the project's EGM2008 heights (s21 took them as the project's: N, 30.9 m here,
    high). A compound --crs still names the geoid."""
    lon, lat = 115.0, 24.68  # over the synthetic grid
    frames = tmp_path / "imgs"
    frames.mkdir()
    _frame(frames / "a.tif", EXIF, dict(GOOD, GpsLongtitude=str(lon), GpsLatitude=str(lat)))
    for crs, z in (("EPSG:4326", 150.5 - float(synthetic_geoid(lon, lat))), ("EPSG:4326+3855", 150.5)):
        root = _project(tmp_path, "EPSG:32650", name=crs.replace(":", "_").replace("+", "_"))
        (root / "project.toml").write_text((root / "project.toml").read_text() + 'heights = "EPSG:3855"\n')
        import_files(root, "exif", [frames], ImportSettings(crs=crs))
        got = read_eo(root / "imported" / "eo.txt").centre_m[0]
        assert got[2] == pytest.approx(z, abs=1e-3), crs
        assert np.abs(got - _utm(lon, lat, got[2], "EPSG:32650")).max() < 1e-3


@pytest.mark.parametrize("change, message", [
    (dict(GOOD, DewarpData="2020-01-01;51.0,50.0,1.5"), "DewarpData has 3 values"),
    (dict(GOOD, DewarpData="2020-01-01;51.0,50.0,nan,1,1,1,1,1,1"), "expected 9 finite numbers"),
    (dict(GOOD, GpsLatitude="north"), "GpsLatitude = 'north' is not a number"),
    (dict(GOOD, GpsLatitude="95.0"), "latitude 95.0 is outside"),
    (dict(GOOD, RtkStdHgt="0"), "must be positive"),
])
def test_bad_tags_are_refused_naming_file_and_tag(tmp_path, change, message):
    root = _project(tmp_path, "EPSG:32651")
    f = _frame(tmp_path / "x.tif", EXIF, change)
    before = sorted(p.name for p in root.rglob("*"))
    with pytest.raises(InputError, match=message) as e:
        import_files(root, "exif", [f])
    assert "x.tif" in str(e.value)
    assert sorted(p.name for p in root.rglob("*")) == before


NO_GNSS = {k: v for k, v in GOOD.items() if not k.startswith(("Gps", "Abs"))}


def test_frames_without_gnss_give_the_camera_alone(tmp_path):
    """A kite block (no frame has a position): camera.toml and nothing else, and the import says so; frames
    with and without positions mixed are refused naming those without."""
    root = _project(tmp_path, "EPSG:32651")
    a, b = _frame(tmp_path / "a.tif", EXIF, NO_GNSS), _frame(tmp_path / "b.tif", EXIF, NO_GNSS)
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(a), str(b)])
    assert r.exit_code == 0, r.output
    assert "none of the 2 frames has a GNSS position" in r.output
    assert (root / "camera.toml").is_file()
    assert not (root / "gnss.txt").exists() and not (root / "imported" / "eo.txt").exists()
    c = _frame(tmp_path / "c.tif", EXIF, GOOD)
    before = sorted(p.name for p in root.rglob("*"))
    with pytest.raises(InputError, match=r"no GNSS position \(EXIF GPS or DJI XMP\) in a.tif, b.tif of 3 frames"):
        import_files(root, "exif", [a, b, c], overwrite=True)
    assert sorted(p.name for p in root.rglob("*")) == before


def test_bad_input_through_the_command(tmp_path):
    root = _project(tmp_path, "EPSG:32651")
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(tmp_path / "empty")])
    assert r.exit_code == 2 and "no images" in r.output and "Traceback" not in r.output
    a = _frame(tmp_path / "a.tif", EXIF, GOOD)
    b = _frame(tmp_path / "b.tif", EXIF, GOOD, size=(32, 24))
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(a), str(b)])
    assert r.exit_code == 2 and "another camera" in r.output
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(a), "--crs", "EPSG:99999"])
    assert r.exit_code == 2 and "Traceback" not in r.output


def test_take_off_height_written_as_the_terrain_height_unless_given(tmp_path):
    """DJI RelativeAltitude: the frames' heights less it put the ground at the take-off point (150.5 - 100.0 =
    50.5 m); the import writes it into project.toml as [flight] mean_terrain_height_m with a comment saying where it
    came from, recorded in imports.json: a [flight] section appended, or the key put under the user's [flight]
    header, every other line kept; a user's mean_terrain_height_m is never replaced."""
    from aerotri.core.project import Project

    (tmp_path / "imgs").mkdir()
    _frame(tmp_path / "imgs" / "a.tif", EXIF, dict(GOOD, RelativeAltitude="+100.0"))
    header = '[project]\nname = "p"\ncrs = "EPSG:32651"\n'
    for name, given in [("none", ""), ("speed", "[flight]  # the plan\nspeed_mps = 12.0\n\n[qa]\npdf = false\n"),
                        ("user", "[flight]\nmean_terrain_height_m = 7.0\n")]:
        root = tmp_path / name
        root.mkdir()
        (root / "project.toml").write_text(header + given)
        r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(tmp_path / "imgs")])
        assert r.exit_code == 0, r.output
        text = (root / "project.toml").read_text()
        project = Project.open(root)
        files = json.loads((root / "imported" / "imports.json").read_text())["imports"][0]["files"]
        if name == "user":
            assert text == header + given and project.flight.mean_terrain_height_m == 7.0
            assert "[flight] mean_terrain_height_m = 7, kept (the import's 50.5 m" in r.output
            assert all(f["path"] != "project.toml" for f in files)
            continue
        assert project.flight.mean_terrain_height_m == pytest.approx(50.5)
        assert re.search(r"(?m)^mean_terrain_height_m = 50\.5  # .*the ground at the take-off point.*RelativeAltitude$",
                         text)
        assert text.startswith(header + given.split("\n")[0])  # the user's lines kept, in their order
        if name == "speed":
            assert project.flight.speed_mps == 12.0 and "[qa]\npdf = false\n" in text
        (f,) = [f for f in files if f["path"] == "project.toml"]
        assert f["holds"].startswith("[flight] mean_terrain_height_m") and "RelativeAltitude" in f["holds"]
        assert "project.toml gets [flight] mean_terrain_height_m = 50.5" in r.output


def test_init_then_import_as_the_init_says(tmp_path):
    """`aerotri init` writes camera.toml from the EXIF and says to run `aerotri import --format exif` next: that
    import keeps the same camera.toml (it is not a replacement) and writes gnss.txt; a camera.toml that differs
    is still refused without --force."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2):
        _frame(frames / f"f{k}.tif", EXIF, dict(GOOD, GpsLatitude=f"24.68{k}"))
    p = tmp_path / "blk"
    r = CliRunner().invoke(aerotri_cli, ["init", str(p), "--images", str(frames), "--crs", "EPSG:32651"])
    assert r.exit_code == 0, r.output
    assert f"aerotri import {p} --format exif" in r.output
    init_camera = (p / "camera.toml").read_text()
    r = CliRunner().invoke(aerotri_cli, ["import", str(p), "--format", "exif", str(p / "images")])
    assert r.exit_code == 0, r.output
    assert "camera.toml: holds this camera already, kept" in r.output
    assert (p / "camera.toml").read_text() == init_camera  # the init's file, with its comment, untouched
    assert read_gnss(p / "gnss.txt").image_id == ["f0", "f1"]
    # another camera in camera.toml: the import would replace it
    (p / "camera.toml").write_text(re.sub(r"(?m)^k1 = .*$", "k1 = 0.01", init_camera))
    (p / "gnss.txt").unlink()
    shutil.rmtree(p / "imported")
    r = CliRunner().invoke(aerotri_cli, ["import", str(p), "--format", "exif", str(p / "images")])
    assert r.exit_code == 2 and r.output.startswith(f"Error: {p / 'camera.toml'}: exists; the import would replace")
    assert not (p / "gnss.txt").exists()


@pytest.mark.realdata
def test_brighton_import_says_the_take_off_height_and_the_missing_accuracy(shared_data, tmp_path):
    """What the user needs next: the ground at the take-off point from DJI's RelativeAltitude, written as [flight]
    mean_terrain_height_m (exif_positions.csv gives abs_alt_m - rel_alt_m = 158.5 m for every frame); positions without RTK accuracies get a consumer receiver's model in project.toml [gnss]
    (decimetres between frames, one offset of metres for the flight), not [gnss]'s aerial defaults."""
    from aerotri.core.project import Project
    from aerotri.exchange.exif import CONSUMER_GNSS

    import csv

    data = shared_data / "brighton_beach"
    rows = list(csv.DictReader(open(data / "exif_positions.csv")))
    takeoff = np.median([float(r["abs_alt_m"]) - float(r["rel_alt_m"]) for r in rows])
    assert takeoff == pytest.approx(158.5, abs=0.05)
    root = _project(tmp_path, "EPSG:32615")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "exif", str(data / "images")])
    assert r.exit_code == 0, r.output
    assert f"[flight] mean_terrain_height_m = {takeoff:.1f}" in r.output
    assert "states no accuracy (no DJI RTK): project.toml [gnss] gets a consumer receiver's model" in r.output
    g = Project.open(root).gnss  # appended to the user's project.toml, every earlier line kept
    assert (g.sigma_xy_m, g.sigma_z_m, g.offset_sigma_xy_m, g.offset_sigma_z_m) == CONSUMER_GNSS
    assert Project.open(root).flight.mean_terrain_height_m == pytest.approx(takeoff, abs=0.05)
    files = json.loads((root / "imported" / "imports.json").read_text())["imports"][0]["files"]
    assert [f["holds"].split(" ", 1)[0] for f in files if f["path"] == "project.toml"] == ["[gnss]", "[flight]"]
    # the sources of a folder of frames in a few words, not 18 file names
    assert "(from 18 files, DJI_0018.JPG ... DJI_0035.JPG)" in r.output
    # stated in project.toml: no note
    (tmp_path / "q").mkdir()
    user = '[project]\ncrs = "EPSG:32615"\n[gnss]\nsigma_xy_m = 3.0\nsigma_z_m = 5.0\n'
    (tmp_path / "q" / "project.toml").write_text(user)
    r = CliRunner().invoke(aerotri_cli, ["import", str(tmp_path / "q"), "--format", "exif", str(data / "images")])
    assert r.exit_code == 0, r.output
    assert "states no accuracy" not in r.output
    # the user's [gnss] untouched; the [flight] terrain height appended after it
    text = (tmp_path / "q" / "project.toml").read_text()
    assert text.startswith(user) and text[len(user):].startswith("\n[flight]\nmean_terrain_height_m = 158.5  #")
