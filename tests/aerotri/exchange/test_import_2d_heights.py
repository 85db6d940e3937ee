"""A 2D CRS says nothing of its heights: an imported file's z is read in the project's height system whether the
file names the project's CRS or another one (review 21: on an EGM2008-height project a gcp_list.txt with header
EPSG:32649 kept z = H, the same point under a "+proj=tmerc ... +datum=WGS84" header had z taken as ellipsoidal and
lowered by the geoid's N, 15 m, without a word); the reading is said in imports.json either way."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.geom.observations import read_control_points

# one target of the demo block (UTM 49N), H = 338.824 m (EGM2008); the same point on a k = 1 tmerc of lon 111
UTM = ("EPSG:32649", 452503.0842, 3409247.0848)
TMERC = ("+proj=tmerc +lat_0=0 +lon_0=111 +k=1 +x_0=500000 +y_0=0 +datum=WGS84 +units=m +no_defs",
         452484.0778, 3410611.3293)
H_M = 338.824


def _project(root, heights="EPSG:3855"):
    root.mkdir()
    (root / "project.toml").write_text(f'[project]\nname = "p"\ncrs = "EPSG:32649"\nheights = "{heights}"\n')
    return root


def _gcp(path, header, x, y):
    path.write_text(f"{header}\n{x:.4f} {y:.4f} {H_M:.4f} 1654.9 575.6 s02_002.tif RC9\n")
    return path


def _imported(root):
    z = float(read_control_points(root / "control" / "points.csv").xyz_m[0, 2])
    notes = json.loads((root / "imported" / "imports.json").read_text())["imports"][0]["notes"]
    return z, [n for n in notes if "2D CRS" in n]


def test_a_2d_crs_file_keeps_its_z_in_the_project_heights_whatever_its_crs(tmp_path):
    for name, (header, x, y) in (("utm", UTM), ("tmerc", TMERC)):
        root = _project(tmp_path / name)
        r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm",
                                             str(_gcp(tmp_path / f"{name}.txt", header, x, y)),
                                             "--sigma-xyz-m", "0.1", "0.1", "0.1"])
        assert r.exit_code == 0, r.output
        z, said = _imported(root)
        assert abs(z - H_M) < 1e-6, (name, z)
        assert len(said) == 1 and "EGM2008 height" in said[0] and "not converted" in said[0], said
        xy = read_control_points(root / "control" / "points.csv").xyz_m[0, :2]
        assert np.abs(xy - UTM[1:]).max() < 1e-3  # the tmerc point is the UTM one


def test_with_a_geoid_grid_the_tmerc_file_is_not_lowered_by_n(tmp_path):
    """The harm itself needs the geoid (PROJ without it refused the operation): a synthetic linear EGM2008 grid
    (N = 10 + 2 (lon - 110) + 5 (lat - 30) m, 15.02 m here) in a tmp PROJ user directory, a fresh process."""
    import rasterio
    from rasterio.transform import from_origin

    grids = tmp_path / "proj"
    grids.mkdir()
    d = 1 / 24.0
    lon = 109.0 + d * np.arange(73)
    lat = 32.0 - d * np.arange(73)
    n_m = (10 + 2 * (lon[None, :] - 110) + 5 * (lat[:, None] - 30)).astype("float32")
    area = from_origin(109.0 - d / 2, 32.0 + d / 2, d, d)  # the grid's point values as area pixels
    with rasterio.open(grids / "us_nga_egm08_25.tif", "w", driver="GTiff", width=73, height=73, count=1,
                       dtype="float32", crs="EPSG:4979", transform=area) as ds:
        ds.write(n_m, 1)
    root = _project(tmp_path / "tmerc")
    env = dict(os.environ, PROJ_USER_WRITABLE_DIRECTORY=str(grids), PROJ_NETWORK="OFF")
    r = subprocess.run([sys.executable, "-c", "from aerotri.cli import main; main()", "import", str(root),
                        "--format", "odm", str(_gcp(tmp_path / "tmerc.txt", *TMERC)), "--sigma-xyz-m", "0.1", "0.1",
                        "0.1"], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    z, said = _imported(root)
    assert abs(z - H_M) < 1e-6, z  # main: 323.801 (H - N)
    assert len(said) == 1


def test_an_ellipsoidal_project_reads_a_2d_file_as_ellipsoidal_and_says_so(tmp_path):
    root = _project(tmp_path / "ell", heights="ellipsoidal")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(_gcp(tmp_path / "t.txt", *TMERC)),
                                         "--sigma-xyz-m", "0.1", "0.1", "0.1"])
    assert r.exit_code == 0, r.output
    z, said = _imported(root)
    assert abs(z - H_M) < 1e-6 and len(said) == 1 and "(ellipsoidal)" in said[0]


def test_our_own_export_read_back_into_its_project_is_not_warned(tmp_path):
    """exchange-fixes2: the 2D-CRS note for an import whose projection centres are at/eo.txt's (to 1 cm) is dropped;
    a file of another project (no at/eo.txt) or of other heights keeps it."""
    from aerotri.geom.eo import ExteriorOrientations, format_eo

    root = _project(tmp_path / "p", heights="ellipsoidal")
    ids = ["s01_001", "s01_002"]
    centre = np.array([[452252.8226, 3407393.8322, 760.3864], [452373.7895, 3407391.5725, 757.8285]])
    opk = np.array([[0.08, 0.29, -93.9], [-0.05, 0.0, -92.8]])
    (root / "at").mkdir()
    (root / "at" / "eo.txt").write_text(format_eo(ExteriorOrientations(ids, centre, opk)))

    def notes(shift_m):
        csv = tmp_path / "ext_param.csv"
        csv.write_text("filename,x,y,z,omega,phi,kappa\n" + "".join(
            f"{i},{x:.4f},{y:.4f},{z + shift_m:.4f},{o},{p},{k}\n"
            for i, (x, y, z), (o, p, k) in zip(ids, centre, opk)))
        r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "orthority", "--crs", "EPSG:32649",
                                             str(csv), "--force"])
        assert r.exit_code == 0, r.output
        return [n for n in json.loads((root / "imported" / "imports.json").read_text())["imports"][-1]["notes"]
                if "2D CRS" in n]

    assert notes(0.0) == []
    assert len(notes(-20.0)) == 1
