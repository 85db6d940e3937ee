"""``aerotri import --format opensfm``: the OpenSfM reconstruction of the Tuniu frames imported, and our
projection (imported camera.toml + imported/eo.txt, project CRS) of ground points against OpenSfM's own
(its camera formulas, its topocentric frame), written out here from OpenSfM's documented conventions."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from aerotri.core.errors import InputError
from aerotri.exchange import import_files
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo


def _project(tmp_path, crs="EPSG:32651", name="p"):
    root = tmp_path / name
    root.mkdir()
    (root / "project.toml").write_text(f'[project]\nname = "{name}"\ncrs = "{crs}"\n')
    return root


def _opensfm_pixels(cam, shot, X_topo, w, h):
    """OpenSfM's projection: world (topocentric) -> camera, Brown distortion on x/z, y/z, normalised by
    max(w, h), pixel origin at the centre of the top-left pixel."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    p = X_topo @ R.T + np.array(shot["translation"])
    xn, yn = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    r2 = xn**2 + yn**2
    rad = 1 + r2 * (cam["k1"] + r2 * (cam["k2"] + r2 * cam["k3"]))
    xd = xn * rad + 2 * cam["p1"] * xn * yn + cam["p2"] * (r2 + 2 * xn**2)
    yd = yn * rad + cam["p1"] * (r2 + 2 * yn**2) + 2 * cam["p2"] * xn * yn
    s = max(w, h)
    return (cam["focal_x"] * xd + cam["c_x"]) * s + (w - 1) / 2, (cam["focal_y"] * yd + cam["c_y"]) * s + (h - 1) / 2


def _topocentric(xyz_utm, epsg, ref):
    """Map coordinates -> OpenSfM's topocentric ENU at reference_lla (pyproj to ECEF, then the ENU rotation)."""
    from pyproj import CRS, Transformer

    t = Transformer.from_crs(CRS(epsg).to_3d(), CRS("EPSG:4978"), always_xy=True)
    ecef = np.column_stack(t.transform(*xyz_utm.T))
    ecef0 = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        ref["longitude"], ref["latitude"], ref["altitude"]))
    lat, lon = np.radians(ref["latitude"]), np.radians(ref["longitude"])
    R = np.array([[-np.sin(lon), np.cos(lon), 0], [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                  [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
    return (ecef - ecef0) @ R.T


@pytest.mark.realdata
def test_tuniu_reconstruction_imported_and_reprojected_like_opensfm(shared_data, tmp_path):
    """The reconstruction has no points or tracks; ground points are the ODM surface model's cells inside each
    frame's field of view. ODM's reconstruction.json is its georeferenced one (trial-odm): UTM 51N minus the whole
    metres reference_lla marks, so OpenSfM's projection of a ground point is of its UTM coordinates minus that offset.
    Ours (imported camera and orientation) in UTM coordinates, the same Cartesian grid: exact to eo.txt's 0.1 mm and
    1e-7 degrees; through the adjustment's local ENU frame (earth curvature and the map's scale, 1.00015 here,
    between them): within 0.1 px. (Read as OpenSfM's topocentric frame, the import had turned the shots by the grid
    convergence, 0.856 deg, and put them 1.1-2.1 m off their own RTK GNSS.)"""
    import rasterio

    from aerotri.geom.local_frame import LocalFrame
    from aerotri.geom.rotation import FLIP_YZ

    data = shared_data / "tuniu_drone"
    root = _project(tmp_path)
    shutil.copytree(data / "images", root / "images")
    import_files(root, "opensfm", [data / "opensfm" / "reconstruction.json"])
    rec = json.loads((data / "opensfm" / "reconstruction.json").read_text())[0]
    (cam_json,) = rec["cameras"].values()
    cam = read_camera(root / "camera.toml")
    eo = read_eo(root / "imported" / "eo.txt")
    assert (cam.width, cam.height) == (1368, 912) and cam.pixel_um == pytest.approx(9.6, rel=1e-6)
    assert eo.image_id == sorted(rec["shots"])
    with rasterio.open(data / "odm_dem" / "dsm.tif") as ds:
        z = ds.read(1, masked=True)
        rows, cols = np.mgrid[0:ds.height:7, 0:ds.width:7]
        ok = ~np.ma.getmaskarray(z)[rows, cols]
        xs, ys = rasterio.transform.xy(ds.transform, rows[ok], cols[ok])
        ground = np.column_stack([xs, ys, z[rows, cols][ok].filled(np.nan)])
    import pyproj

    ref = rec["reference_lla"]
    e0, n0 = pyproj.Transformer.from_crs(4326, 32651, always_xy=True).transform(ref["longitude"], ref["latitude"])
    assert abs(e0 - round(e0)) < 1e-6 and abs(n0 - round(n0)) < 1e-6        # the offset: whole metres of the grid
    topo = ground - [round(e0), round(n0), 0.0]
    # the field of view: rays within the undistorted image corners (beyond, the Brown polynomial folds back)
    xc, yc = cam.pixel_to_normalized(np.array([-0.5, cam.width - 0.5] * 2), np.repeat([-0.5, cam.height - 0.5], 2))
    r_max = np.hypot(xc, yc).max()
    local_px, map_px = [], []
    for i, sid in enumerate(eo.image_id):
        u, v = _opensfm_pixels(cam_json, rec["shots"][sid], topo, cam.width, cam.height)
        frame = LocalFrame("EPSG:32651", eo.centre_m[i])
        R_local = frame.rotation_local_from_map(eo.centre_m[[i]])[0] @ eo.rotation(i)
        P = frame.to_local(ground)
        d = P @ (R_local @ FLIP_YZ)
        seen = (d[:, 2] > 0) & (np.hypot(d[:, 0], d[:, 1]) < r_max * d[:, 2]) & cam.inside(u, v)
        assert seen.sum() > 500, sid
        x, y, _ = cam.project(P, np.zeros(3), R_local)
        local_px.append(np.hypot(x - u, y - v)[seen].max())
        x, y, _ = cam.project(ground, eo.centre_m[i], eo.rotation(i))
        map_px.append(np.hypot(x - u, y - v)[seen].max())
    assert max(map_px) < 0.002, map_px
    assert max(local_px) < 0.1, local_px


def _recon(tmp_path, **change):
    rec = {"cameras": {"c": {"projection_type": "brown", "width": 400, "height": 300, "focal_x": 0.8, "focal_y": 0.8,
                             "c_x": 0.01, "c_y": -0.02, "k1": -0.1, "k2": 0.01, "p1": 0.0, "p2": 0.0, "k3": 0.0}},
           "shots": {"a.jpg": {"rotation": [3.1, 0.0, 0.0], "translation": [1.0, 2.0, 100.0], "camera": "c",
                               "gps_position": [1.0, -2.0, 100.0], "gps_dop": 5.0}},
           "reference_lla": {"latitude": 24.68, "longitude": 120.95, "altitude": 50.0}}
    for v in change.values():
        v(rec)
    path = tmp_path / "reconstruction.json"
    path.write_text(json.dumps([rec]))
    return path


def test_synthetic_reconstruction_conventions(tmp_path):
    """A nadir shot (180 degrees about x: camera y down = south, z forward = down) above the reference point:
    omega 0 (or 360), phi 0, kappa = minus the meridian convergence of the grid; centre = the reference point +
    the topocentric offset; the camera at the file's size when no frames are found."""
    from pyproj import Proj, Transformer

    path = _recon(tmp_path, x=lambda r: r["shots"]["a.jpg"].update(rotation=[np.pi, 0.0, 0.0], translation=[0, 0, 100.0]))
    root = _project(tmp_path)
    import_files(root, "opensfm", [path])
    eo = read_eo(root / "imported" / "eo.txt")
    x0, y0, z0 = Transformer.from_crs("EPSG:4979", "EPSG:32651", always_xy=True).transform(120.95, 24.68, 50.0)
    assert np.allclose(eo.centre_m[0], [x0, y0, z0 + 100.0], atol=2e-3)  # 100 m up the normal
    conv = Proj("EPSG:32651").get_factors(120.95, 24.68).meridian_convergence
    om, ph, ka = eo.opk_deg[0]
    assert abs(((om + 180) % 360) - 180) < 1e-6 and abs(ph) < 1e-6 and ka == pytest.approx(conv, abs=1e-5)
    cam = read_camera(root / "camera.toml")
    assert (cam.width, cam.height) == (400, 300) and cam.focal_px == pytest.approx(320.0)
    assert cam.cx_px == pytest.approx(199.5 + 4.0) and cam.cy_px == pytest.approx(149.5 - 8.0)


def test_a_file_of_several_reconstructions_says_so_in_the_import_record(tmp_path):
    """OpenSfM writes one reconstruction per part it could not join: the first is imported and imports.json says
    how many were left out (the warning was a log line only)."""
    path = _recon(tmp_path)
    rec = json.loads(path.read_text())[0]
    other = json.loads(json.dumps(rec))
    other["shots"] = {"b.jpg": other["shots"].pop("a.jpg")}
    path.write_text(json.dumps([rec, other]))
    root = _project(tmp_path)
    import_files(root, "opensfm", [path])
    eo = read_eo(root / "imported" / "eo.txt")
    assert list(eo.image_id) == ["a"]
    notes = json.loads((root / "imported" / "imports.json").read_text())["imports"][-1]["notes"]
    assert any("holds 2 reconstructions" in n and "left out: 1 shot (b.jpg)" in n for n in notes), notes
    # the larger one whatever its place (trial s96 M3: the first, of 1 shot, was taken over one of 3)
    other["shots"]["c.jpg"] = json.loads(json.dumps(other["shots"]["b.jpg"]))
    path.write_text(json.dumps([rec, other]))
    (tmp_path / "2").mkdir()
    root = _project(tmp_path / "2")
    import_files(root, "opensfm", [path])
    assert sorted(read_eo(root / "imported" / "eo.txt").image_id) == ["b", "c"]
    notes = json.loads((root / "imported" / "imports.json").read_text())["imports"][-1]["notes"]
    assert any("the largest imported (2 shots), left out: 1 shot (a.jpg)" in n for n in notes), notes


@pytest.mark.parametrize("change, message", [
    (lambda r: r.pop("reference_lla"), "no reference_lla"),
    (lambda r: r["cameras"]["c"].pop("focal_x"), "missing key 'focal_x'"),
    (lambda r: r["cameras"]["c"].update(projection_type="fisheye"), "projection_type 'fisheye' is not supported"),
    (lambda r: r["shots"]["a.jpg"].update(translation=[1.0, 2.0]), "shot 'a.jpg': translation"),
    (lambda r: r["shots"]["a.jpg"].update(rotation=[1.0, float("nan"), 0.0]), "NaN"),
    (lambda r: r["shots"]["a.jpg"].update(camera="other"), "is not the reconstruction's camera"),
])
def test_bad_reconstructions_are_refused(tmp_path, change, message):
    root = _project(tmp_path)
    with pytest.raises(InputError, match=message):
        import_files(root, "opensfm", [_recon(tmp_path, x=change)])
    assert not (root / "camera.toml").exists()


def test_unknown_reference_crs_is_refused(tmp_path):
    from aerotri.exchange import ImportSettings

    root = _project(tmp_path)
    with pytest.raises(InputError):
        import_files(root, "opensfm", [_recon(tmp_path)], ImportSettings(crs="EPSG:99999"))


def test_a_reference_crs_that_is_no_latitude_longitude_or_needs_a_geoid_is_not_taken_silently(tmp_path):
    """Trial-odm: `--crs EPSG:32651` (projected) and `--crs EPSG:4326+3855` (an altitude above the geoid) were taken
    with the altitude as an ellipsoidal height, exit 0. The first is refused naming --crs; the second turns the
    altitude into an ellipsoidal height through the geoid, or is refused naming the grid PROJ lacks."""
    from aerotri.core.errors import CrsError, OptionError
    from aerotri.exchange import ImportSettings
    from aerotri.geom.eo import read_eo

    root = _project(tmp_path)
    with pytest.raises(OptionError, match="expected a geographic CRS"):
        import_files(root, "opensfm", [_recon(tmp_path)], ImportSettings(crs="EPSG:32651"))
    plain = _project(tmp_path, name="plain")
    import_files(plain, "opensfm", [_recon(tmp_path)], ImportSettings())
    geoid = _project(tmp_path, name="geoid")
    try:
        import_files(geoid, "opensfm", [_recon(tmp_path)], ImportSettings(crs="EPSG:4326+3855"))
    except (CrsError, InputError) as exc:   # the EGM2008 grid not installed: named
        assert "egm08" in str(exc).lower(), exc
    else:   # with the grid: the geoid's 20 m or so between them
        dz = read_eo(geoid / "imported" / "eo.txt").centre_m[:, 2] - read_eo(plain / "imported" / "eo.txt").centre_m[:, 2]
        assert np.all(np.abs(dz) > 5.0), dz
