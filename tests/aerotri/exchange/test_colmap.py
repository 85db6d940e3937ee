"""COLMAP models: pycolmap reads our text and binary exports and projects our points where we do; the
round trip through a fresh project; a foreign georeferenced model with --crs; bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import CrsError, InputError
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.exchange.colmap import _quat_wxyz
from aerotri.geom.camera import oriented_camera
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo
from aerotri.geom.rotation import FLIP_YZ, rotation_matrix_opk


def our_projection_px(blk) -> np.ndarray:
    """The adjustment's projection (Cal3DS2: fx fy u0 v0 k1 k2 p1 p2) of every used measurement's point."""
    fx, fy, _, u0, v0 = blk.cal[:5]
    d = np.einsum("kji,kj->ki", blk.R_cv[blk.obs_image], blk.points_local[blk.obs_point] - blk.centre_local[blk.obs_image])
    xd, yd = blk.camera.calibration_camera(blk.cal).distort(d[:, 0] / d[:, 2], d[:, 1] / d[:, 2])
    return np.column_stack([fx * xd + u0, fy * yd + v0])


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, _ = adjusted_tiny
    out = tmp_path_factory.mktemp("colmap_exp")
    export_project(root, ["colmap", "colmap-bin"], out)
    return root, out


@pytest.mark.parametrize("folder", ["colmap", "colmap_bin"])
def test_pycolmap_reprojects_our_points_where_we_do(exported, folder):
    import pycolmap

    root, out = exported
    blk = read_adjusted_block(root)
    rec = pycolmap.Reconstruction(str(out / folder))
    assert rec.num_reg_images() == len(blk.image_id) and rec.num_points3D() == len(np.unique(blk.obs_point))
    by_name = {im.name: im for im in rec.images.values()}
    ours = our_projection_px(blk)
    theirs = np.array([by_name[blk.image_id[i]].project_point(blk.points_local[j]) for i, j in zip(blk.obs_image, blk.obs_point)])
    err = np.abs(theirs - 0.5 - ours)  # COLMAP's pixel origin: the corner of the top-left pixel
    assert err.max() < 0.01, err.max()
    # and the measurements sit in the same places (the residuals are pycolmap's reprojection errors)
    meas = np.array([by_name[blk.image_id[i]].points2D[n].xy for i in range(len(blk.image_id))
                     for n in range(len(by_name[blk.image_id[i]].points2D))])
    assert len(meas) == len(blk.obs_xy_px)


@pytest.mark.parametrize("folder", ["colmap", "colmap_bin"])
def test_round_trip(exported, tmp_path, folder, fresh_project):
    root, out = exported
    p = Project.open(root)
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "colmap", [out / folder])
    eo, back = read_eo(p.eo_path), read_eo(dst / "imported" / "eo.txt")
    assert back.image_id == eo.image_id
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-6
    got, cam = read_camera(dst / "camera.toml"), oriented_camera(p)[0]
    assert got.MODEL == cam.MODEL
    for f in got.fields():
        assert getattr(got, f) == pytest.approx(getattr(cam, f), rel=1e-7, abs=1e-8), f  # 1e-6 px in the file


def test_an_images_txt_cut_between_images_names_the_frames_left_without(exported, tmp_path, fresh_project, caplog):
    """Trial s96 M5: images.txt cut cleanly after 3 of 18 images imported 3 orientations without a word. Said now
    (the count and the frames); the whole file says nothing of it."""
    import logging
    import shutil

    root, out = exported
    cut = tmp_path / "cut"
    shutil.copytree(out / "colmap", cut)
    lines = (cut / "images.txt").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    (cut / "images.txt").write_text("\n".join(head + body[:6]) + "\n")
    import cv2

    ids = read_eo(Project.open(root).eo_path).image_id
    cam = oriented_camera(Project.open(root))[0]

    def with_frames(dst):
        (dst / "images").mkdir()
        for i in ids:  # blank frames of the camera's size: the import reads their names and sizes
            cv2.imwrite(str(dst / "images" / f"{i}.png"), np.zeros((cam.height, cam.width), np.uint8))
        return dst

    with caplog.at_level(logging.WARNING):
        import_files(with_frames(fresh_project(root, tmp_path / "p")), "colmap", [cut])
    n = len(ids)
    assert f"{n - 3} of {n} frames in" in caplog.text and "get no orientation from it" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        import_files(with_frames(fresh_project(root, tmp_path / "q")), "colmap", [out / "colmap"])
    assert "get no orientation" not in caplog.text


def test_a_model_cut_mid_line_or_mid_file_is_named_as_cut(exported, tmp_path, fresh_project):
    """Trial s96 L3: images.txt cut inside a points line read "got 6332 fields" (no word of a cut file); a cut
    images.bin read "not a readable COLMAP binary model (unordered_map::at)". Both say what was cut now."""
    import shutil

    root, out = exported
    for folder, cut in (("colmap", "images.txt"), ("colmap_bin", "images.bin")):
        bad = tmp_path / folder
        shutil.copytree(out / folder, bad)
        data = (bad / cut).read_bytes()
        if cut.endswith(".txt"):
            lines = data.decode().splitlines()
            k = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#")) + 1  # the first points line
            fields = lines[k].split()
            (bad / cut).write_text("\n".join(lines[:k] + [" ".join(fields[:len(fields) - 1])]) + "\n")
            match = r"images.txt:\d+: .*not a multiple of 3 on the file's last line: the file is cut short"
        else:
            (bad / cut).write_bytes(data[:len(data) // 2])
            match = r"not a readable COLMAP binary model: .*cut short or of another COLMAP version\? \(cameras.bin"
        with pytest.raises(InputError, match=match):
            import_files(fresh_project(root, tmp_path / f"p_{folder}"), "colmap", [bad])


def test_older_export_without_georef_uses_the_header(exported, tmp_path, fresh_project):
    root, out = exported
    model = tmp_path / "m"
    shutil.copytree(out / "colmap", model)
    (model / "georef.txt").unlink()
    dst = fresh_project(root, tmp_path / "p")
    shutil.copy(root / "camera.toml", dst / "camera.toml")  # the pixel size comes from the project's camera
    import_files(dst, "colmap", [model / "cameras.txt", model / "images.txt"], overwrite=True)
    back, eo = read_eo(dst / "imported" / "eo.txt"), read_eo(Project.open(root).eo_path)
    assert np.abs(back.centre_m - eo.centre_m).max() < 2e-3  # the header keeps the origin to 1 mm
    notes = json.loads((dst / "imported" / "imports.json").read_text())["imports"][-1]["notes"]
    assert not any("georef.txt" in n for n in notes), notes  # (trial s96 L2: it named the file that is not there)


def _foreign_model(folder, centre, opk_deg, crs_line=None):
    folder.mkdir()
    R_cv = rotation_matrix_opk(*opk_deg) @ FLIP_YZ
    Rwc = R_cv.T
    t = -Rwc @ np.asarray(centre, float)
    q = _quat_wxyz(Rwc)
    (folder / "cameras.txt").write_text("1 SIMPLE_RADIAL 6000 4000 5000.5 3000 2000 -0.05\n")
    (folder / "images.txt").write_text("# a foreign model in map coordinates\n"
                                       f"7 {' '.join(f'{v:.15f}' for v in q)} {' '.join(f'{v:.9f}' for v in t)} 1 dir/IMG_0007.JPG\n"
                                       "\n")
    if crs_line:
        (folder / "georef.txt").write_text(f"frame crs\n{crs_line}\npixel_um 4.0\n")


def test_foreign_model_in_map_coordinates(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    centre, opk = [500123.25, 4100456.5, 1200.75], [1.5, -2.25, 37.0]
    _foreign_model(tmp_path / "m", centre, opk)
    with pytest.raises(CrsError, match="world frame is unknown"):
        import_files(root, "colmap", [tmp_path / "m"])
    import_files(root, "colmap", [tmp_path / "m"], ImportSettings(crs=Project.open(root).crs))
    eo = read_eo(root / "imported" / "eo.txt")
    assert eo.image_id == ["IMG_0007"]
    assert np.abs(eo.centre_m[0] - centre).max() < 1e-4 and np.abs(eo.opk_deg[0] - opk).max() < 1e-6
    cam = read_camera(root / "camera.toml")
    assert cam.MODEL == "brown" and cam.k1 == -0.05 and cam.focal_px == pytest.approx(5000.5)
    assert cam.cx_px == pytest.approx(2999.5) and cam.cy_px == pytest.approx(1999.5)
    # the same model with its frame in georef.txt
    _foreign_model(tmp_path / "m2", centre, opk, crs_line=f"crs {Project.open(root).crs}")
    import_files(root, "colmap", [tmp_path / "m2"], overwrite=True)
    assert read_camera(root / "camera.toml").pixel_um == 4.0


@pytest.mark.parametrize("cameras, images, match", [
    ("1 OPENCV 10 10 1 2 3\n", None, r"cameras.txt:1: OPENCV has 8 PARAMS"),
    ("1 FOV 10 10 1 2 3 4 5\n", None, r"cameras.txt:1: camera model FOV is not one of"),
    ("1 PINHOLE 10 10 100 nan 5 5\n", None, r"cameras.txt:1: fy is NaN"),
    ("1 FULL_OPENCV 10 10 100 100 5 5 0 0 0 0 0 0.1 0 0\n", None, "k4 k5 k6 must be zero"),
    (None, "1 1 0 0 0 0 0 0 1 a.jpg\n\n1 1 0 0 0 0 0 0 1 a.jpg\n\n", r"images.txt:3: duplicate image 'a.jpg'"),
    (None, "1 1 0 0 0 0 0 1 a.jpg\n\n", r"images.txt:1: expected IMAGE_ID QW"),
    (None, "1 9 0 0 0 0 0 0 1 a.jpg\n\n", r"images.txt:1: quaternion .* is not a rotation"),
    (None, "1 1 0 0 0 0 0 0 2 a.jpg\n\n", r"CAMERA_ID\(s\) \[2\]"),
    # a pose-only images.txt without the POINTS2D lines: every other image was taken for points and dropped
    (None, "1 1 0 0 0 0 0 0 1 a.jpg\n2 1 0 0 0 0 0 0 1 b.jpg\n3 1 0 0 0 0 0 0 1 c.jpg\n",
     r"images.txt:2: expected the POINTS2D line .* of the image on line 1, got 10 fields"),
])
def test_bad_text_model(tiny_project, tmp_path, cameras, images, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    m = tmp_path / "m"
    m.mkdir()
    (m / "cameras.txt").write_text(cameras or "1 PINHOLE 10 10 100 100 5 5\n")
    (m / "images.txt").write_text(images or "1 1 0 0 0 0 0 0 1 a.jpg\n\n")
    with pytest.raises(InputError, match=match):
        import_files(root, "colmap", [m], ImportSettings(crs=Project.open(root).crs))
    assert not (root / "imported").exists()


def test_bad_georef_and_cli(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    m = tmp_path / "m"
    m.mkdir()
    (m / "cameras.txt").write_text("1 PINHOLE 10 10 100 100 5 5\n")
    (m / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.jpg\n\n")
    (m / "georef.txt").write_text("frame local_enu\ncrs EPSG:32649\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "colmap", str(m)])
    assert r.exit_code == 2 and "georef.txt: frame local_enu needs crs and origin_map" in r.output
    (m / "georef.txt").unlink()
    (m / "images.txt").unlink()
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "colmap", str(m)])
    assert r.exit_code == 2 and "no COLMAP model" in r.output and "Traceback" not in r.output


def test_foreign_model_in_geocentric_coordinates(adjusted_tiny, tmp_path, fresh_project):
    """A model georeferenced to geocentric (ECEF) coordinates, e.g. by colmap model_aligner, imported with
    --crs EPSG:4978: centres and attitudes come back in the project CRS and grid axes."""
    from aerotri.geom.local_frame import LocalFrame

    root, _ = adjusted_tiny
    p = Project.open(root)
    eo = read_eo(p.eo_path)
    m = tmp_path / "m"
    m.mkdir()
    (m / "cameras.txt").write_text("1 PINHOLE 13824 7680 10000 10000 6912 3840\n")
    lines = []
    for i, iid in enumerate(eo.image_id):
        frame = LocalFrame(p.crs, eo.centre_m[i])  # ENU at the camera: its origin is the centre
        R_ecef = frame.R.T @ frame.rotation_local_from_map(eo.centre_m[i:i + 1])[0] @ eo.rotation(i)
        Rwc = (R_ecef @ FLIP_YZ).T
        t = -Rwc @ frame.ecef0
        q = _quat_wxyz(Rwc)
        lines += [f"{i + 1} {' '.join(f'{v:.15f}' for v in q)} {' '.join(f'{v:.6f}' for v in t)} 1 {iid}.tif", ""]
    (m / "images.txt").write_text("\n".join(lines) + "\n")
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "colmap", [m], ImportSettings(crs="EPSG:4978"))
    back = read_eo(dst / "imported" / "eo.txt")
    assert back.image_id == eo.image_id
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-3
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-6


def test_a_known_k3_is_in_the_exported_camera_and_the_points_as_measured(tmp_path):
    """A camera whose certificate gives k3 (held fixed; Cal3DS2 has none, the adjustment takes it off the
    measurements): COLMAP's model must still describe the image files. It was exported as OPENCV without k3
    and with the k3-shifted measurements: 1.4 px RMS (7 px at the corners) from the lens on the demo's frames."""
    import dataclasses

    import pycolmap

    from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
    from aerotri.geom.observations import read_image_points
    from aerotri.sim.observations import geometric_block, true_dmc_camera, write_block_project, write_truth_observations

    cam = dataclasses.replace(true_dmc_camera(), k3=1.0e-3)  # about 2 px at the corners of a DMC frame
    block = geometric_block(2, 5, seed=7, camera_true=cam)
    block = dataclasses.replace(block, camera_nominal=dataclasses.replace(block.camera_nominal, k3=cam.k3))
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=4, seed=2)
    run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, self_calibration=("pp", "radial")))
    export_project(root, ["colmap"], tmp_path / "out")
    blk = read_adjusted_block(root)
    lens = oriented_camera(Project.open(root))[0]
    assert lens.k3 == cam.k3
    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "colmap"))
    (camera,) = rec.cameras.values()
    assert camera.model.name == "FULL_OPENCV" and camera.params[8] == pytest.approx(cam.k3)
    by_name = {im.name: im for im in rec.images.values()}
    theirs = np.array([by_name[blk.image_id[i]].project_point(blk.points_local[j]) for i, j in zip(blk.obs_image, blk.obs_point)])
    ours = np.array([lens.project(blk.points_local[j], blk.centre_local[i], blk.R_cv[i] @ FLIP_YZ)[:2]
                     for i, j in zip(blk.obs_image, blk.obs_point)])[:, :, 0]
    assert np.abs(theirs - 0.5 - ours).max() < 0.01
    # the 2D points are the measurements of tiepoints.csv, as measured
    tie = read_image_points(root / "at" / "tiepoints.csv")
    measured = {(p, i): xy for p, i, xy in zip(tie.point_id.astype(str), tie.image_id.astype(str), tie.xy_px)}
    pid = {n + 1: str(blk.point_id[j]) for n, j in enumerate(np.unique(blk.obs_point))}  # the export's numbering
    assert sorted(rec.points3D) == sorted(pid)
    got = [(im.points2D[n].xy - 0.5, measured[(pid[int(im.points2D[n].point3D_id)], im.name)])
           for im in rec.images.values() for n in range(len(im.points2D)) if (pid[int(im.points2D[n].point3D_id)], im.name) in measured]
    assert len(got) > 100
    assert max(np.abs(a - b).max() for a, b in got) < 1e-3


@pytest.mark.parametrize("folder", ["colmap", "colmap_bin"])
def test_georef_origin_in_full(exported, folder):
    """The model's world frame is the adjustment's to the micrometre: the origin was written to 0.1 mm, and a
    kite block (21 m above ground, f 5747 px) then reprojected through georef.txt up to 0.017 px off."""
    from aerotri.exchange.colmap import read_georef

    root, out = exported
    origin = np.array(read_georef(out / folder).origin_map)
    assert np.abs(origin - read_adjusted_block(root).frame.origin_map).max() < 1e-6


def test_georef_states_the_project_heights(adjusted_tiny, tmp_path, fresh_project, synthetic_geoid):
    """A project with EGM2008 heights (the NGI block's): georef.txt gave the horizontal CRS alone, so the model
    imported into an ellipsoidal project took H as h, the centres N (+30 m here) low with a warning only, and `aerotri
    compare` of such a model said dZ 0.000 m (trial-exchange). georef.txt's crs is the compound CRS now: back into
    the same heights the centres are the project's, into ellipsoidal ones h = H + N through the geoid grid."""
    import pyproj

    root, _ = adjusted_tiny
    p = tmp_path / "p"
    shutil.copytree(root, p, symlinks=True)
    toml = (p / "project.toml").read_text()
    (p / "project.toml").write_text(toml.replace('crs = "EPSG:32649"\n', 'crs = "EPSG:32649"\nheights = "EPSG:3855"\n'))
    out = tmp_path / "out"
    export_project(p, ["colmap", "colmap-bin"], out)
    eo = read_eo(Project.open(p).eo_path)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32649", "EPSG:4326", always_xy=True).transform(*eo.centre_m[:, :2].T)
    for model in ("colmap", "colmap_bin"):
        same = fresh_project(p, tmp_path / f"same_{model}")
        import_files(same, "colmap", [out / model])
        assert np.abs(read_eo(same / "imported" / "eo.txt").centre_m - eo.centre_m).max() < 1e-4
        ell = fresh_project(root, tmp_path / f"ell_{model}")
        import_files(ell, "colmap", [out / model])
        h = read_eo(ell / "imported" / "eo.txt").centre_m[:, 2]
        assert np.abs(h - (eo.centre_m[:, 2] + synthetic_geoid(lon, lat))).max() < 1e-3
