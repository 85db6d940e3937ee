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
