"""ODM gcp_list.txt heights above a geoid (leftovers): a header with a vertical CRS ("EPSG:32649+3855") is converted
to the project's heights through PROJ's geoid grid (a synthetic EGM2008 grid, ``synthetic_geoid``); a 2D header
whose heights the user declares orthometric (``--crs EPSG:32649+3855``, the file's horizontal CRS and the heights')
likewise; without the grid the header's heights are refused naming the grid, and a 2D header without --crs keeps
the warning (z taken in the project's heights, not converted)."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from pyproj import Transformer

from aerotri.cli import main as aerotri_cli
from aerotri.geom.observations import read_control_points

X, Y, H_M = 452503.0842, 3409247.0848, 338.824  # a target of the demo block (UTM 49N), H above EGM2008


def _project(root, heights=None):
    root.mkdir()
    extra = f'heights = "{heights}"\n' if heights else ""
    (root / "project.toml").write_text(f'[project]\nname = "p"\ncrs = "EPSG:32649"\n{extra}')
    return root


def _import(root, header, *extra):
    f = root.parent / f"{root.name}_gcp_list.txt"
    f.write_text(f"{header}\n{X:.4f} {Y:.4f} {H_M:.4f} 1654.9 575.6 s02_002.tif RC9\n")
    return CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(f), "--sigma-xyz-m", "0.1",
                                            "0.1", "0.1", *extra])


def _z(root):
    return float(read_control_points(root / "control" / "points.csv").xyz_m[0, 2])


def _n(synthetic_geoid):
    lon, lat = Transformer.from_crs("EPSG:32649", "EPSG:4326", always_xy=True).transform(X, Y)
    return float(synthetic_geoid(lon, lat))


def test_a_header_with_geoid_heights_is_converted_through_the_grid(tmp_path, synthetic_geoid):
    root = _project(tmp_path / "p")
    r = _import(root, "EPSG:32649+3855")
    assert r.exit_code == 0, r.output
    assert _z(root) == pytest.approx(H_M + _n(synthetic_geoid), abs=1e-3)  # h = H + N


def test_heights_declared_orthometric_with_crs_are_converted(tmp_path, synthetic_geoid):
    """A 2D header: z taken in the project's heights, said (and how to declare them); --crs with the header's CRS
    and EGM2008: converted as the compound header; --crs with another horizontal CRS: refused."""
    root = _project(tmp_path / "as_is")
    r = _import(root, "EPSG:32649")
    assert r.exit_code == 0, r.output
    notes = json.loads((root / "imported" / "imports.json").read_text())["imports"][0]["notes"]
    assert _z(root) == pytest.approx(H_M, abs=1e-6) and any("--crs EPSG:32611+5703" in n for n in notes), notes
    root = _project(tmp_path / "declared")
    r = _import(root, "EPSG:32649", "--crs", "EPSG:32649+3855")
    assert r.exit_code == 0, r.output
    assert _z(root) == pytest.approx(H_M + _n(synthetic_geoid), abs=1e-3)
    r = _import(_project(tmp_path / "other"), "EPSG:32649", "--crs", "EPSG:32650+3855")
    assert r.exit_code == 2 and "EPSG:32649+3855" in r.output and "--crs" in r.output, r.output
    # an orthometric project: the declared EGM2008 heights are the project's (no conversion)
    root = _project(tmp_path / "ortho", heights="EPSG:3855")
    assert _import(root, "EPSG:32649", "--crs", "EPSG:32649+3855").exit_code == 0
    assert _z(root) == pytest.approx(H_M, abs=1e-6)


def test_without_the_geoid_grid_orthometric_heights_are_refused_naming_it(tmp_path):
    from pathlib import Path

    from pyproj.datadir import get_data_dir, get_user_data_dir

    if any((d / "us_nga_egm08_25.tif").exists() for d in map(Path, (get_data_dir(), get_user_data_dir()))):
        pytest.skip("the EGM2008 grid is installed here (as test_metashape's test without it)")
    r = _import(_project(tmp_path / "p"), "EPSG:32649", "--crs", "EPSG:32649+3855")
    assert r.exit_code == 2 and "us_nga_egm08_25.tif" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "p" / "control").exists()


def test_a_wgs84_header_takes_orthometric_heights_as_epsg_4326_with_a_vertical_crs(tmp_path, synthetic_geoid):
    """Review 37: the header "WGS84" (read as EPSG:4979, ellipsoidal heights) refused --crs EPSG:4326+3855 and its hint
    named EPSG:4979+3855, which PROJ rejects."""
    lon, lat = Transformer.from_crs("EPSG:32649", "EPSG:4326", always_xy=True).transform(X, Y)
    root = _project(tmp_path / "p")
    f = tmp_path / "gcp_list.txt"
    f.write_text(f"WGS84\n{lon:.9f} {lat:.9f} {H_M:.4f} 1654.9 575.6 s02_002.tif RC9\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(f), "--sigma-xyz-m", "0.1", "0.1",
                                         "0.1", "--crs", "EPSG:4326+3855"])
    assert r.exit_code == 0, r.output
    assert _z(root) == pytest.approx(H_M + _n(synthetic_geoid), abs=1e-3)
    r = CliRunner().invoke(aerotri_cli, ["import", str(_project(tmp_path / "q")), "--format", "odm", str(f),
                                         "--sigma-xyz-m", "0.1", "0.1", "0.1", "--crs", "EPSG:32649+3855"])
    assert r.exit_code == 2 and "EPSG:4326+3855" in r.output and "4979+" not in r.output
