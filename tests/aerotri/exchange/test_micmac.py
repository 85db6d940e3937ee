"""MicMac's control and measurement XML: the round trip through a fresh project (kinds by unused axes and
the check file), bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import InputError
from aerotri.core.project import Project
from aerotri.exchange import export_project, import_files
from aerotri.geom.observations import read_control_points, read_image_points


def test_round_trip(adjusted_tiny, tmp_path, fresh_project):
    root, _ = adjusted_tiny
    out = tmp_path / "exp"
    export_project(root, ["micmac"], out)
    mm = out / "micmac"
    p = Project.open(root)
    mine = read_control_points(p.control_points_path)
    assert (mm / "check.xml").is_file() == ("check" in set(mine.kind))
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "micmac", sorted(mm.glob("*.xml")))
    con = read_control_points(dst / "control" / "points.csv")
    order = {pid: n for n, pid in enumerate(mine.id)}
    k = np.array([order[pid] for pid in con.id])
    assert sorted(con.id) == sorted(mine.id)
    assert list(con.kind) == list(mine.kind[k])
    assert np.abs(con.xyz_m - mine.xyz_m[k]).max() < 1e-4 and np.allclose(con.sigma_m, mine.sigma_m[k])
    obs, raw = read_image_points(dst / "control" / "image_points.csv"), read_image_points(p.control_image_points_path)
    key = {(a, b): xy for a, b, xy in zip(raw.point_id, raw.image_id, raw.xy_px)}
    assert len(obs) == len(raw)
    assert max(np.abs(xy - key[a, b]).max() for a, b, xy in zip(obs.point_id, obs.image_id, obs.xy_px)) < 1e-3


def test_horizontal_and_height_control(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "gcp.xml"
    f.write_text("<Global><DicoAppuisFlottant>"
                 "<OneAppuisDAF><Pt>500000 4100000 10</Pt><NamePt>h</NamePt><Incertitude>0.02 0.02 -1</Incertitude></OneAppuisDAF>"
                 "<OneAppuisDAF><Pt>500100 4100000 11</Pt><NamePt>v</NamePt><Incertitude>-1 -1 0.03</Incertitude></OneAppuisDAF>"
                 "<OneAppuisDAF><Pt>500200 4100000 12</Pt><NamePt>f</NamePt><Incertitude>0.02 0.02 0.03</Incertitude></OneAppuisDAF>"
                 "</DicoAppuisFlottant></Global>")
    import_files(root, "micmac", [f])
    c = read_control_points(root / "control" / "points.csv")
    assert list(c.kind) == ["horizontal", "height", "full"]
    # exported again, the unused axes are -1 again
    from aerotri.exchange.micmac import _gcp_xml

    assert "0.02 0.02 -1" in _gcp_xml(c) and "-1 -1 0.03" in _gcp_xml(c)


@pytest.mark.parametrize("text, match", [
    ("<Global><DicoAppuisFlottant><OneAppuisDAF><Pt>1 2</Pt><NamePt>a</NamePt><Incertitude>1 1 1</Incertitude>"
     "</OneAppuisDAF></DicoAppuisFlottant></Global>", r"point 'a': <Pt> needs 3 numbers"),
    ("<Global><DicoAppuisFlottant><OneAppuisDAF><Pt>1 2 nan</Pt><NamePt>a</NamePt><Incertitude>1 1 1</Incertitude>"
     "</OneAppuisDAF></DicoAppuisFlottant></Global>", "Pt is NaN"),
    ("<Global><DicoAppuisFlottant><OneAppuisDAF><Pt>1 2 3</Pt><NamePt>a</NamePt></OneAppuisDAF>"
     "</DicoAppuisFlottant></Global>", "no <Incertitude>; give --sigma-xyz-m"),
    ("<Global><DicoAppuisFlottant><OneAppuisDAF><Pt>1 2 3</Pt><Incertitude>1 1 1</Incertitude></OneAppuisDAF>"
     "</DicoAppuisFlottant></Global>", r"OneAppuisDAF\[0\]: <NamePt> is missing"),
    ("<SetOfMesureAppuisFlottants><MesureAppuiFlottant1Im><NameIm>a.tif</NameIm><OneMesureAF1I><NamePt>g</NamePt>"
     "<PtIm>1</PtIm></OneMesureAF1I></MesureAppuiFlottant1Im></SetOfMesureAppuisFlottants>", r"image 'a' point 'g': <PtIm> needs 2"),
    ("<Other/>", "neither DicoAppuisFlottant"),
    ("<Global>", "not valid XML"),
])
def test_bad_input(tiny_project, tmp_path, text, match, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "x.xml"
    f.write_text(text)
    with pytest.raises(InputError, match=match):
        import_files(root, "micmac", [f])
    assert not (root / "control").exists()


def test_cli_exit_code(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "x.xml"
    f.write_text("<Other/>")
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "micmac", str(f)])
    assert r.exit_code == 2 and "neither DicoAppuisFlottant" in r.output and "Traceback" not in r.output


def test_incertitude_in_the_coordinates_unit_of_a_feet_project(tmp_path):
    """MicMac has no units: ``Incertitude`` is in the unit of ``Pt``. In a project in US survey feet (EPSG:2227)
    control/points.csv keeps its accuracies in metres (sx_m): the export writes them in feet and the import reads
    feet back into metres (trial-exchange: 0.05 m was written as 0.05 beside coordinates in feet, and a file's 0.1 ft
    read as 0.1 m, the control weighted 3.28 x off either way)."""
    from aerotri.exchange import ImportSettings
    from aerotri.exchange.micmac import _gcp_xml
    from aerotri.geom.observations import ControlPoints

    ft_m = 1200 / 3937
    root = tmp_path / "p"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "p"\ncrs = "EPSG:2227"\n')
    f = tmp_path / "gcp.xml"
    f.write_text("<Global><DicoAppuisFlottant>"
                 "<OneAppuisDAF><Pt>6100000 1950000 100</Pt><NamePt>a</NamePt><Incertitude>0.1 0.1 0.2</Incertitude></OneAppuisDAF>"
                 "<OneAppuisDAF><Pt>6100500 1950000 110</Pt><NamePt>b</NamePt><Incertitude>0.1 0.1 -1</Incertitude></OneAppuisDAF>"
                 "</DicoAppuisFlottant></Global>")
    import_files(root, "micmac", [f], ImportSettings(crs="EPSG:2227"))
    c = read_control_points(root / "control" / "points.csv")
    assert np.allclose(c.sigma_m, np.array([[0.1, 0.1, 0.2], [0.1, 0.1, 0.1]]) * ft_m, atol=1e-4)  # points.csv: 0.1 mm
    xml = _gcp_xml(ControlPoints(np.array(["a"], object), np.array(["full"], object), np.array([[6100000.0, 1950000.0, 100.0]]),
                                 np.array([[0.05, 0.05, 0.1]])), unit_m=(ft_m, ft_m, ft_m))
    written = [float(v) for v in xml.split("<Incertitude>")[1].split("<")[0].split()]
    assert np.allclose(written, np.array([0.05, 0.05, 0.1]) / ft_m, rtol=1e-5)  # written to 6 digits
