"""PATB-style files: the round trip of orientations, camera, control and the control points' image
coordinates through a fresh project; bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange import ImportSettings, export_project, import_files
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.geom.camera import adjusted_camera, read_camera
from aerotri.geom.eo import read_eo
from aerotri.geom.observations import read_control_points, read_image_points


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, _ = adjusted_tiny
    out = tmp_path_factory.mktemp("patb_exp")
    export_project(root, ["patb"], out)
    return root, out / "patb"


def test_round_trip(exported, tmp_path, fresh_project):
    root, patb = exported
    p = Project.open(root)
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "patb", [patb / f"block.{s}" for s in ("ori", "cam", "con", "im")])
    eo, back = read_eo(p.eo_path), read_eo(dst / "imported" / "eo.txt")
    assert back.image_id == eo.image_id
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-7
    got, cam = read_camera(dst / "camera.toml"), adjusted_camera(p)[0]
    assert got == cam  # every field written with repr: exact
    blk = read_adjusted_block(root)
    con = read_control_points(dst / "control" / "points.csv")
    assert list(con.id) == list(blk.control_id) and list(con.kind) == list(blk.control_kind)
    assert np.abs(con.xyz_m - blk.control_xyz_m).max() < 1e-4
    sig = Project.open(root).control_points
    assert np.allclose(con.sigma_m, [sig.sigma_xy_m, sig.sigma_xy_m, sig.sigma_z_m])
    # the control points' measurements, back in pixels: the .im keeps 0.1 um = 0.008 px at 12 um
    obs = read_image_points(dst / "control" / "image_points.csv")
    mine = {(blk.point_id[j], blk.image_id[i]): blk.obs_xy_px[k]
            for k, (i, j) in enumerate(zip(blk.obs_image, blk.obs_point)) if blk.point_id[j] in set(blk.control_id)}
    assert len(obs) == len(mine) > 0
    d = np.array([obs.xy_px[n] - mine[p, i] for n, (p, i) in enumerate(zip(obs.point_id, obs.image_id))])
    assert np.abs(d).max() < 0.01


def test_ori_alone_with_explicit_crs(exported, tmp_path, fresh_project):
    """A .ori alone, its CRS given with --crs (here the project's: nothing changes; another CRS goes through
    the same operation as orthority's, tested there)."""
    root, patb = exported
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "patb", [patb / "block.ori"], ImportSettings(crs=Project.open(root).crs))
    assert np.abs(read_eo(dst / "imported" / "eo.txt").centre_m - read_eo(Project.open(root).eo_path).centre_m).max() < 1e-4


ORI_OK = "a 120.0\n 500000.0 4100000.0 1000.0\n 1 0 0\n 0 1 0\n 0 0 1\n"


@pytest.mark.parametrize("name, text, match", [
    ("b.ori", ORI_OK, "no -99 at the end"),
    ("b.ori", ORI_OK.replace(" 0 0 1\n", " 0 0\n") + "-99\n", r"b.ori:5: expected 3 numbers \(a matrix row\)"),
    ("b.ori", ORI_OK.replace("1000.0", "nan") + "-99\n", r"b.ori:2: Z0 is NaN"),
    ("b.ori", ORI_OK.replace(" 1 0 0\n", " 2 0 0\n") + "-99\n", "is not a rotation"),
    ("b.ori", ORI_OK + ORI_OK + "-99\n", r"b.ori:6: duplicate image 'a'"),
    ("b.ori", "a 120.0\n 1 2 3\n-99\n", "needs 4 more records"),
    ("b.cam", "name x\nfocal_mm 120\n-99\n", "missing pixel_um, width, height"),
    ("b.con", "g1 1 2\n-99\n", r"b.con:1: expected 'point_id X Y Z'"),
    ("b.im", "a\n g1 1.0 2.0\n", "has no -99 at its end"),
    ("b.txt", "x\n", "not a PATB-style file"),
])
def test_bad_input(tiny_project, tmp_path, name, text, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / name
    f.write_text(text)
    extra = []
    if name.endswith(".im"):
        (tmp_path / "c.con").write_text("g1 500000 4100000 10\n-99\n")
        extra = [tmp_path / "c.con"]
    with pytest.raises(InputError, match=match):
        import_files(root, "patb", [f] + extra, ImportSettings(sigma_xyz_m=(0.02, 0.02, 0.03)))
    assert not (root / "imported").exists() and not (root / "control").exists()


def test_control_needs_sigmas_and_cli_exit(tiny_project, tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "x"\ncrs = "EPSG:32649"\n')
    (tmp_path / "c.con").write_text("g1 500000 4100000 10  * height\n-99\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "patb", str(tmp_path / "c.con")])
    assert r.exit_code == 2 and "give --sigma-xyz" in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "patb", "--sigma-xyz", "0.02", "0.02", "0.03",
                                         str(tmp_path / "c.con")])
    assert r.exit_code == 0, r.output
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.kind) == ["height"] and np.allclose(c.sigma_m, [[0.02, 0.02, 0.03]])
