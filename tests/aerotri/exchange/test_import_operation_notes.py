"""What an import's coordinates go through, said: EPSG's WGS 84 -> NAD83(2011) is a null transformation stated
accurate to 2 m (no ballpark, so the CRS policy takes it), which a user of a NAD83(2011) project (US drone surveys:
EPSG:6344) was not told; the operation notes the policy made (a missing grid: a less accurate operation) never
reached the import's console or imports.json; and a Web Mercator project's metres are no ground metres."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.geom.crs.transform import CrsTransformer
from aerotri.geom.observations import read_control_points

# three targets near Brighton Beach, Duluth (UTM 15N, WGS 84), each measured in two frames
GCP_LIST = ["EPSG:32615",
            "576700.00 5188170.00 160.0 1000.0 900.0 DJI_0018.JPG t1",
            "576700.00 5188170.00 160.0 1200.0 700.0 DJI_0019.JPG t1",
            "576720.00 5188150.00 160.5 2000.0 1100.0 DJI_0018.JPG t2",
            "576720.00 5188150.00 160.5 2200.0 900.0 DJI_0019.JPG t2",
            "576690.00 5188190.00 159.5 3000.0 1500.0 DJI_0018.JPG t3",
            "576690.00 5188190.00 159.5 3200.0 1300.0 DJI_0019.JPG t3"]


def _import(tmp_path, crs):
    root = tmp_path / crs.replace(":", "_")
    root.mkdir()
    (root / "project.toml").write_text(f'[project]\nname = "p"\ncrs = "{crs}"\n')
    gcp = tmp_path / "gcp_list.txt"
    gcp.write_text("\n".join(GCP_LIST) + "\n")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "odm", str(gcp),
                                         "--sigma-xyz-m", "0.02", "0.02", "0.03"])
    assert r.exit_code == 0, r.output
    notes = json.loads((root / "imported" / "imports.json").read_text())["imports"][0]["notes"]
    return root, r.output, notes


def test_a_metre_operation_is_named_where_a_conversion_is_silent():
    coarse = CrsTransformer("EPSG:4979", "EPSG:6344").warnings
    assert len(coarse) == 1 and "NAD83(2011) to WGS 84" in coarse[0] and "stated accurate to 2 m" in coarse[0]
    assert CrsTransformer("EPSG:4979", "EPSG:32615").warnings == []  # WGS 84 to its own UTM zone: a conversion


def test_import_into_a_nad83_2011_project_says_the_operation_is_good_to_2_m(tmp_path):
    root, output, notes = _import(tmp_path, "EPSG:6344")
    said = [n for n in notes if "stated accurate to 2 m" in n]
    assert len(said) == 1 and "gcp_list.txt (CRS EPSG:32615): EPSG:32615 -> EPSG:6344" in said[0] and said[0] in output
    # the points themselves: PROJ's null transformation, the same grid coordinates to 0.1 mm
    got = read_control_points(root / "control" / "points.csv")
    want = {"t1": (576700.0, 5188170.0), "t2": (576720.0, 5188150.0), "t3": (576690.0, 5188190.0)}
    assert np.abs(np.array([want[i] for i in got.id]) - got.xyz_m[:, :2]).max() < 1e-4
    # the same file into a WGS 84 project: no operation, nothing said about one
    _, output, notes = _import(tmp_path, "EPSG:32615")
    assert not [n for n in notes if "accurate to" in n] and "accurate to" not in output


def test_a_web_mercator_project_is_told_its_metres_are_no_ground_metres(tmp_path):
    """EPSG:3857 (a web map's Pseudo-Mercator), which `init` and `import` took without a word: at Duluth (46.84 N) a
    ground metre is 1/cos(46.84 deg) = 1.462 of its metres, so a 0.015 m ortho pixel would be 1.0 cm on the ground."""
    _, output, notes = _import(tmp_path, "EPSG:3857")
    said = [n for n in notes if "scale factor" in n]
    assert len(said) == 1 and "scale factor of 1.462" in said[0] and "EPSG:32615" in said[0] and said[0] in output
    for crs in ("EPSG:32615", "EPSG:6344"):  # survey grids: within 0.1 % of 1, nothing said
        _, output, notes = _import(tmp_path, crs)
        assert not [n for n in notes if "scale factor" in n]
