"""Metashape cameras XML: the round trip of orientations, camera, control and marker projections through a
fresh project; Metashape's conventions (pixel corner origin, P1/P2 swapped, chunk transform to geocentric);
bad input."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from click.testing import CliRunner

from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import CrsError, InputError
from aerotri.core.project import Project
from aerotri.exchange import export_project, import_files
from aerotri.geom.camera import oriented_camera
from aerotri.geom.camera import read_camera
from aerotri.geom.eo import read_eo
from aerotri.geom.observations import read_control_points, read_image_points


@pytest.fixture(scope="module")
def exported(adjusted_tiny, tmp_path_factory):
    root, _ = adjusted_tiny
    out = tmp_path_factory.mktemp("ms_exp")
    export_project(root, ["metashape"], out)
    return root, out / "metashape" / "cameras.xml"


def test_round_trip(exported, tmp_path, fresh_project):
    root, xml = exported
    p = Project.open(root)
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "metashape", [xml])
    eo, back = read_eo(p.eo_path), read_eo(dst / "imported" / "eo.txt")
    assert back.image_id == eo.image_id
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-7
    got, cam = read_camera(dst / "camera.toml"), oriented_camera(p)[0]
    for f in got.fields():
        assert getattr(got, f) == pytest.approx(getattr(cam, f), rel=1e-9, abs=1e-12), f
    con, mine = read_control_points(dst / "control" / "points.csv"), read_control_points(p.control_points_path)
    assert list(con.id) == list(mine.id) and np.abs(con.xyz_m - mine.xyz_m).max() < 1e-4
    assert np.allclose(con.sigma_m, mine.sigma_m)
    assert [k == "check" for k in con.kind] == [k == "check" for k in mine.kind]
    obs, raw = read_image_points(dst / "control" / "image_points.csv"), read_image_points(p.control_image_points_path)
    key = {(a, b): xy for a, b, xy in zip(raw.point_id, raw.image_id, raw.xy_px)}
    assert len(obs) == len(raw) and max(np.abs(xy - key[a, b]).max() for a, b, xy in zip(obs.point_id, obs.image_id, obs.xy_px)) < 1e-3


def test_metashape_conventions(exported):
    """The chunk transform takes a camera to geocentric coordinates at its place (|X| = earth radius + height);
    the calibration's p1/p2 are ours swapped; cx, cy are pixels from the image centre."""
    root, xml = exported
    p = Project.open(root)
    cam = oriented_camera(p)[0]
    chunk = ET.parse(xml).getroot().find("chunk")
    cal = chunk.find("sensors/sensor/calibration")
    assert float(cal.find("p1").text) == cam.p2 and float(cal.find("p2").text) == cam.p1
    assert float(cal.find("cx").text) == pytest.approx(cam.cx_px - (cam.width - 1) / 2)
    Rc = np.array(chunk.find("transform/rotation").text.split(), float).reshape(3, 3)
    Tc = np.array(chunk.find("transform/translation").text.split(), float)
    T = np.array(chunk.find("cameras/camera/transform").text.split(), float).reshape(4, 4)
    X = Rc @ T[:3, 3] + Tc
    import pyproj

    lon, lat, h = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*X)
    e, n = pyproj.Transformer.from_crs("EPSG:4979", p.crs, always_xy=True).transform(lon, lat)
    eo = read_eo(p.eo_path)
    assert np.abs(np.array([e, n, h]) - eo.centre_m[0]).max() < 1e-3


def test_bad_input(tiny_project, tmp_path, fresh_project):
    root = fresh_project(tiny_project, tmp_path / "p")
    f = tmp_path / "c.xml"
    f.write_text("<document><chunk><sensors/>")
    with pytest.raises(InputError, match="not valid XML"):
        import_files(root, "metashape", [f])
    f.write_text('<document><chunk><cameras><camera id="0" sensor_id="0" label="a"/></cameras></chunk></document>')
    with pytest.raises(InputError, match="no aligned cameras"):
        import_files(root, "metashape", [f])
    sensor = ('<sensors><sensor id="0" label="s" type="frame"><resolution width="100" height="80"/>'
              '<property name="pixel_width" value="0.01"/><calibration type="frame"><f>1000</f>{extra}</calibration>'
              '</sensor></sensors>')
    cams = '<cameras><camera id="0" sensor_id="0" label="a"><transform>{t}</transform></camera></cameras>'
    eye = " ".join(map(str, np.eye(4).ravel()))
    f.write_text(f'<document><chunk>{sensor.format(extra="<b1>0.5</b1>")}{cams.format(t=eye)}</chunk></document>')
    with pytest.raises(InputError, match=r"calibration \['b1'\] not zero"):
        import_files(root, "metashape", [f])
    f.write_text(f'<document><chunk>{sensor.format(extra="")}{cams.format(t="1 0 0")}</chunk></document>')
    with pytest.raises(InputError, match="label='a'.*<transform> needs 16 numbers"):
        import_files(root, "metashape", [f])
    f.write_text(f'<document><chunk>{sensor.format(extra="<k1>nan</k1>")}{cams.format(t=eye)}</chunk></document>')
    with pytest.raises(InputError, match="k1 is NaN"):
        import_files(root, "metashape", [f])
    f.write_text(f'<document><chunk>{sensor.format(extra="")}{cams.format(t=eye)}<reference>EPSG:32649</reference>'
                 '</chunk></document>')
    with pytest.raises(CrsError, match="not georeferenced"):
        import_files(root, "metashape", [f])
    f.write_text(f'<document><chunk>{sensor.format(extra="")}{cams.format(t=eye)}<reference>NOT A CRS</reference>'
                 '<transform><rotation>1 0 0 0 1 0 0 0 1</rotation><translation>0 0 0</translation></transform>'
                 '</chunk></document>')
    r = CliRunner().invoke(aerotri_cli, ["import", str(root), "--format", "metashape", str(f)])
    assert r.exit_code == 2 and "<reference>: unknown CRS" in r.output and "Traceback" not in r.output
    assert not (root / "imported").exists()
