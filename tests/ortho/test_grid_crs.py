"""The DOM delivered in a national grid on another datum (CGCS2000 / Xian 1980 3-degree Gauss-Krueger)
from a WGS 84 UTM project: refused without a parameter set, right to the millimetre with one.

Truth: common points generated through known 7-parameter sets (``aerotri.geom.crs.synthetic``), the
parameters fitted from them by ``aerotri crs fit`` as a user would; the ortho's pixel centres are
compared with ``aerotri crs transform --params`` of the same positions, and its content with the
project-CRS ortho of the same frames mapped through the same operation.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from pyproj import CRS

from aerotri.cli import main as aerotri_cli
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, simulate_spatial, write_common_points
from aerotri.geom.crs.raster_warp import interpolate_anchors
from aerotri.geom.crs.transform import OperationSpec
from ortho.cli import main as ortho_cli
from ortho.grid import GridToProject, OrthoGrid

# WGS 84 (at today's epoch) -> CGCS2000: a few decimetres of plate motion since 2000.0; invented, realistic size
TRUE_CGCS2000 = {"tx_m": 0.41, "ty_m": -0.27, "tz_m": 0.18, "rx_arcsec": 0.012, "ry_arcsec": -0.008,
                 "rz_arcsec": 0.015, "scale_ppm": 0.021}
GK_EPSG = {"xian1980": 2382, "cgcs2000": 4546}  # the 3-degree zones with CM 111E (the tiny block is at 110.5E)
TRUTH = {"xian1980": TRUE_BURSA_WOLF7, "cgcs2000": TRUE_CGCS2000}


def _ok(runner, cli, args):
    r = runner.invoke(cli, [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def gk_project(tiny_project, tmp_path_factory):
    """The tiny project with a parameter file per datum, fitted from 16 common points (2 cm noise)."""
    root = tmp_path_factory.mktemp("gk") / "p"
    shutil.copytree(tiny_project, root)
    runner = CliRunner()
    lon, lat = np.meshgrid(np.linspace(110.3, 110.7, 4), np.linspace(30.6, 31.0, 4))
    h = 300.0 + 50.0 * np.random.default_rng(1).random(lon.size)
    params = {}
    for datum, truth in TRUTH.items():
        src, dst, _ = simulate_spatial(truth, "EPSG:32649", f"EPSG:{GK_EPSG[datum]}", lon_deg=lon.ravel(),
                                       lat_deg=lat.ravel(), h_m=h, noise_m=0.02, seed=3)
        common = root / f"common_{datum}.csv"
        write_common_points(common, [f"P{i:02d}" for i in range(len(src))], src, dst)
        params[datum] = root / f"{datum}.json"
        _ok(runner, aerotri_cli, ["crs", "fit", common, "--model", "bursa-wolf7", "--from", "EPSG:32649",
                                  "--to", f"EPSG:{GK_EPSG[datum]}", "-o", params[datum]])
    return root, params


def _rectify(root, *extra):
    return CliRunner().invoke(ortho_cli, ["rectify", str(root), "--eo", str(root / "truth" / "eo.txt"), "--dem",
                                          str(root / "truth" / "dem.tif"), "--res-m", "1", *map(str, extra)])


@pytest.mark.parametrize("datum", ["xian1980", "cgcs2000"])
def test_without_parameters_refused(gk_project, datum):
    root, _ = gk_project
    r = _rectify(root, "--crs", f"gk3:{datum}")
    assert r.exit_code == 2
    assert "ballpark" in r.output and "--params" in r.output and "Traceback" not in r.output
    assert not (root / "ortho" / "frames" / "index.json").exists()


@pytest.mark.parametrize("datum", ["xian1980", "cgcs2000"])
def test_pixel_centres_match_point_transformation(gk_project, datum, tmp_path):
    root, params = gk_project
    r = _rectify(root, "--crs", f"gk3:{datum}", "--params", params[datum])
    assert r.exit_code == 0, r.output
    index = json.loads((root / "ortho" / "frames" / "index.json").read_text())
    assert CRS.from_wkt(index["crs"]).to_epsg() == GK_EPSG[datum]
    op = index["coordinate_operation"]
    assert not op["ballpark"] and [s["step"] for s in op["steps"]] == ["proj", "parameters", "proj"]
    spec = OperationSpec(**index["operation"])
    entry = index["frames"][0]
    with rasterio.open(root / "ortho" / "frames" / entry["file"]) as ds:
        assert "bursa-wolf7" in ds.tags()["COORDINATE_OPERATION"]
        grid = OrthoGrid(CRS.from_wkt(index["crs"]), ds.transform.c, ds.transform.f, ds.transform.a, ds.width, ds.height)
    # the project positions the rectifier used for every pixel centre: its anchor grid, interpolated
    with rasterio.open(root / "truth" / "dem.tif") as dem:
        zlo, zhi = float(dem.read(1).min()), float(dem.read(1).max())
    to_project = GridToProject(grid.crs, CRS.from_epsg(32649), operation=spec.build(), z_m=0.5 * (zlo + zhi))
    AX, AY, s = to_project.anchors(grid)
    X = interpolate_anchors(AX, s, grid.height, grid.width)
    Y = interpolate_anchors(AY, s, grid.height, grid.width)
    xo, yo = grid.centres()
    xo, yo = np.meshgrid(xo, yo)
    pick = (slice(None, None, 7), slice(None, None, 7))
    with rasterio.open(root / "truth" / "dem.tif") as dem:
        z = np.array([v[0] for v in dem.sample(list(zip(X[pick].ravel(), Y[pick].ravel())))])
    pts = tmp_path / "pts.csv"
    pts.write_text("id,x,y,z\n" + "\n".join(f"p{i},{a:.6f},{b:.6f},{c:.4f}"
                                             for i, (a, b, c) in enumerate(zip(X[pick].ravel(), Y[pick].ravel(), z))))
    out = tmp_path / "out.csv"
    _ok(CliRunner(), aerotri_cli, ["crs", "transform", pts, out, "--from", "EPSG:32649", "--to",
                                   f"EPSG:{GK_EPSG[datum]}", "--params", params[datum]])
    rows = [ln.split(",") for ln in out.read_text().splitlines()[1:]]
    got = np.array([[float(r[1]), float(r[2])] for r in rows])
    err = np.hypot(got[:, 0] - xo[pick].ravel(), got[:, 1] - yo[pick].ravel())
    assert len(err) > 500
    assert err.max() < 1e-3, err.max()  # metres


def test_content_matches_project_ortho_through_operation(gk_project, tmp_path):
    """The Xian 1980 GK frame ortho against the UTM frame ortho of the same frame, mapped through the
    same parameter set by ``ortho check --params``: no displacement beyond resampling noise."""
    root, params = gk_project
    assert _rectify(root, "--frames", "s01_002").exit_code == 0
    utm = tmp_path / "utm.tif"
    shutil.copy(root / "ortho" / "frames" / "s01_002.tif", utm)
    assert _rectify(root, "--frames", "s01_002", "--crs", "gk3:xian1980", "--params", params["xian1980"]).exit_code == 0
    r = CliRunner().invoke(ortho_cli, ["check", str(root), "--dom", str(root / "ortho" / "frames" / "s01_002.tif"),
                                       "--reference", str(utm), "--params", str(params["xian1980"]),
                                       "--patch-px", "32", "--out", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["displacement"]["count"] >= 10
    assert rep["displacement"]["rms_xy_gsd"] < 0.05
    # and without the parameters the check refuses to compare across datums
    r = CliRunner().invoke(ortho_cli, ["check", str(root), "--dom", str(root / "ortho" / "frames" / "s01_002.tif"),
                                       "--reference", str(utm), "--out", str(tmp_path / "rep2")])
    assert r.exit_code == 2 and "ballpark" in r.output
