"""Metashape cameras XML: the round trip of orientations, camera, control and marker projections through a
fresh project; Metashape's conventions (pixel corner origin, P1/P2 swapped, chunk transform to geocentric);
bad input."""

from __future__ import annotations

import shutil
from pathlib import Path
import json
import xml.etree.ElementTree as ET

import numpy as np
import pyproj
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


def chunk_centres_geodetic(chunk) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cameras' centres of a Metashape ``<chunk>``, computed here from its transform (not by the importer):
    longitude, latitude (deg) and ellipsoidal height (m) on WGS 84."""
    Rc = np.array(chunk.find("transform/rotation").text.split(), float).reshape(3, 3)
    Tc = np.array(chunk.find("transform/translation").text.split(), float)
    X = np.array([Rc @ np.array(c.text.split(), float).reshape(4, 4)[:3, 3] + Tc
                  for c in chunk.findall("cameras/camera/transform")])
    return pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(*X.T)


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


def test_an_xml_in_the_encoding_its_declaration_states_is_read(exported, tmp_path, fresh_project):
    """Trial-messy F11: a cameras.xml declaring encoding="ISO-8859-1" (legal XML) with a Latin-1 character in a label
    was refused as "not UTF-8 text"; it reads as the UTF-8 file does."""
    root, xml = exported
    text = xml.read_text(encoding="utf-8")
    assert text.startswith("<?xml")
    declared = text.split("?>", 1)
    latin = '<?xml version="1.0" encoding="ISO-8859-1"?>' + declared[1].replace("<chunk", "<!-- Gr\u00fcn -->\n<chunk", 1)
    f = tmp_path / "latin1.xml"
    f.write_bytes(latin.encode("latin-1"))
    a, b = fresh_project(root, tmp_path / "a"), fresh_project(root, tmp_path / "b")
    import_files(a, "metashape", [xml])
    import_files(b, "metashape", [f])
    assert (a / "imported" / "eo.txt").read_text() == (b / "imported" / "eo.txt").read_text()
    # without a declaration a non-UTF-8 byte is still refused by line
    bad = tmp_path / "bad.xml"
    bad.write_bytes(declared[1].replace("<chunk", "<!-- Gr\u00fcn -->\n<chunk", 1).encode("latin-1"))
    with pytest.raises(InputError, match="not UTF-8 text"):
        import_files(fresh_project(root, tmp_path / "c"), "metashape", [bad])


def test_a_geographic_reference_gives_the_same_orientations(exported, tmp_path, fresh_project):
    """Metashape's usual chunk CRS is EPSG:4326: the geocentric chunk transform is the same, only ``<reference>``
    differs. The attitudes came back up to 0.0001 deg off (the grid axes of a geographic CRS by central differences
    of 1 degree; trial-exchange, on the NGI block); now as with the projected reference."""
    import re

    from pyproj import CRS

    root, xml = exported
    text = re.sub(r"<reference>.*?</reference>", "<reference>" + CRS("EPSG:4326").to_wkt("WKT1_GDAL") + "</reference>",
                  xml.read_text(), flags=re.S)
    text = re.sub(r"<markers.*?</markers>|<frames.*?</frames>", "", text, flags=re.S)  # markers: x y in UTM
    geo = tmp_path / "cameras_4326.xml"
    geo.write_text(text)
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "metashape", [geo])
    eo, back = read_eo(Project.open(root).eo_path), read_eo(dst / "imported" / "eo.txt")
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4
    assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-6


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
    lon, lat, h = (v[0] for v in chunk_centres_geodetic(chunk))  # the first camera
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


def _rewrite(xml, out, edit):
    tree = ET.parse(xml)
    edit(tree.getroot().find("chunk"))
    tree.write(out, encoding="unicode")
    return out


def test_component_transforms(exported, tmp_path, fresh_project):
    """Metashape 1.6 and later keep a camera's transform in its component's frame (``component_id``; the
    component's ``<transform>`` X = s R x + T into the chunk), and a 2.x export may hold the georeferencing in the
    component alone (no chunk ``<transform>``): either way the orientations are those of the plain export."""
    from scipy.spatial.transform import Rotation

    root, xml = exported
    eo = read_eo(Project.open(root).eo_path)
    s_k, R_k, T_k = 2.5, Rotation.from_euler("zyx", [40, -15, 70], degrees=True).as_matrix(), np.array([12.0, -30.0, 7.5])

    def into_component(chunk, fold_chunk=False):
        comps = ET.SubElement(chunk, "components", next_id="1", active_id="0")
        tr = ET.SubElement(ET.SubElement(comps, "component", id="0", label="Component 1"), "transform")
        s, R, T = s_k, R_k, T_k
        if fold_chunk:  # the chunk's transform moved into the component: component -> geocentric
            ct = chunk.find("transform")
            Rc = np.array(ct.find("rotation").text.split(), float).reshape(3, 3)
            Tc = np.array(ct.find("translation").text.split(), float)
            s, R, T = s_k, Rc @ R_k, Rc @ T_k + Tc
            chunk.remove(ct)
        ET.SubElement(tr, "rotation").text = " ".join(repr(float(v)) for v in R.ravel())
        ET.SubElement(tr, "translation").text = " ".join(repr(float(v)) for v in T)
        ET.SubElement(tr, "scale").text = repr(float(s))
        for c in chunk.findall("cameras/camera"):
            M = np.array(c.find("transform").text.split(), float).reshape(4, 4)
            M[:3, :3], M[:3, 3] = R_k.T @ M[:3, :3], R_k.T @ (M[:3, 3] - T_k) / s_k  # the camera in the component
            c.set("component_id", "0")
            c.find("transform").text = " ".join(repr(float(v)) for v in M.ravel())

    for fold in (False, True):
        dst = fresh_project(root, tmp_path / f"p{fold}")
        import_files(dst, "metashape", [_rewrite(xml, tmp_path / f"c{fold}.xml", lambda ch: into_component(ch, fold))])
        back = read_eo(dst / "imported" / "eo.txt")
        assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4, fold
        assert np.abs(back.opk_deg - eo.opk_deg).max() < 1e-6, fold

    # a component's transform into an unreferenced chunk (no chunk transform): model coordinates, not geocentric
    def unreferenced(chunk):
        into_component(chunk)
        chunk.remove(chunk.find("transform"))

    dst = fresh_project(root, tmp_path / "u")
    r = CliRunner().invoke(aerotri_cli, ["import", str(dst), "--format", "metashape",
                                         str(_rewrite(xml, tmp_path / "u.xml", unreferenced))])
    assert r.exit_code == 2 and "not georeferenced" in r.output and "Traceback" not in r.output, r.output
    assert not (dst / "imported").exists()


def test_sensor_types_and_calibrations(exported, tmp_path, fresh_project):
    """A fisheye (or spherical, ...) sensor is refused, not read as a frame camera; of an initial and an adjusted
    calibration the adjusted one is the camera, whichever comes first."""
    root, xml = exported
    cam = oriented_camera(Project.open(root))[0]

    def fisheye(chunk):
        chunk.find("sensors/sensor").set("type", "fisheye")

    r = CliRunner().invoke(aerotri_cli, ["import", str(fresh_project(root, tmp_path / "f")), "--format", "metashape",
                                         str(_rewrite(xml, tmp_path / "f.xml", fisheye))])
    assert r.exit_code == 2 and "sensor type 'fisheye' is not supported" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "f" / "camera.toml").exists()

    def initial_first(chunk):
        sensor = chunk.find("sensors/sensor")
        adjusted = sensor.find("calibration")
        initial = ET.fromstring(ET.tostring(adjusted))
        initial.set("class", "initial")
        initial.find("f").text = repr(float(initial.find("f").text) * 1.1)
        sensor.insert(list(sensor).index(adjusted), initial)

    dst = fresh_project(root, tmp_path / "i")
    import_files(dst, "metashape", [_rewrite(xml, tmp_path / "i.xml", initial_first)])
    assert read_camera(dst / "camera.toml").focal_mm == pytest.approx(cam.focal_mm, rel=1e-12)


def test_marker_heights_and_plan_markers(exported, tmp_path, fresh_project):
    """Markers' heights in a compound <reference> (horizontal + EGM96 height) go through its vertical CRS, not
    read as ellipsoidal heights (without the geoid grid: refused, naming the file); markers with x y and no z are
    horizontal control, not dropped."""
    from aerotri.geom.crs.definition import horizontal_crs, parse_crs

    root, xml = exported
    p = Project.open(root)
    mine = read_control_points(p.control_points_path)

    def egm96(chunk):
        wkt = pyproj.CRS.from_user_input(f"EPSG:{horizontal_crs(parse_crs(p.crs)).to_epsg()}+5773").to_wkt()
        chunk.find("reference").text = wkt

    dst = fresh_project(root, tmp_path / "g")
    r = CliRunner().invoke(aerotri_cli, ["import", str(dst), "--format", "metashape",
                                         str(_rewrite(xml, tmp_path / "g.xml", egm96))])
    if r.exit_code == 0:  # the geoid grid is installed: the heights moved by the geoid undulation
        con = read_control_points(dst / "control" / "points.csv")
        full = con.kind != "horizontal"
        assert np.abs(con.xyz_m[full, 2] - mine.xyz_m[full, 2]).min() > 1.0
    else:
        assert r.exit_code == 2 and "g.xml: the markers' coordinates" in r.output and "EGM96" in r.output
        assert "Traceback" not in r.output and not (dst / "control").exists()

    def plan(chunk):
        for m in chunk.findall("markers/marker"):
            r = m.find("reference")
            del r.attrib["z"], r.attrib["sz"]

    dst = fresh_project(root, tmp_path / "h")
    import_files(dst, "metashape", [_rewrite(xml, tmp_path / "h.xml", plan)])
    con = read_control_points(dst / "control" / "points.csv")
    control = mine.kind != "check"  # a check point without z is left out (with a note)
    assert list(con.id) == list(mine.id[control]) and set(con.kind) == {"horizontal"}
    assert np.abs(con.xyz_m[:, :2] - mine.xyz_m[control, :2]).max() < 1e-4


def _with_heights(src, dst, heights='heights = "EPSG:3855"\n'):
    shutil.copytree(src, dst, symlinks=True)
    toml = (dst / "project.toml").read_text()
    assert "heights" not in toml
    (dst / "project.toml").write_text(toml.replace('crs = "EPSG:32649"\n', f'crs = "EPSG:32649"\n{heights}'))
    return dst


def test_orthometric_heights_reach_metashape_as_ellipsoidal(adjusted_tiny, tmp_path, fresh_project, synthetic_geoid):
    """A project with [project] heights = "EPSG:3855" (the NGI block's EGM2008): the export wrote <reference> as the
    horizontal CRS alone and placed the chunk with the EGM2008 heights as ellipsoidal, so Metashape read the block N
    (the geoid undulation, +30 m here) low, unsaid. Now <reference> is the compound CRS (COMPD_CS, as Metashape's own)
    and the chunk transform gives geocentric coordinates with h = H + N; imported back the heights are the project's."""
    root, _ = adjusted_tiny
    p = _with_heights(root, tmp_path / "p")
    out = tmp_path / "out"
    r = CliRunner().invoke(aerotri_cli, ["export", str(p), "--format", "metashape", "--out", str(out)])
    assert r.exit_code == 0, r.output
    chunk = ET.parse(out / "metashape" / "cameras.xml").getroot().find("chunk")
    ref = pyproj.CRS.from_wkt(chunk.find("reference").text)
    assert chunk.find("reference").text.startswith("COMPD_CS[") and ref.sub_crs_list[1].to_epsg() == 3855
    lon, lat, h = chunk_centres_geodetic(chunk)
    eo = read_eo(Project.open(p).eo_path)
    assert np.abs(h - (eo.centre_m[:, 2] + synthetic_geoid(lon, lat))).max() < 1e-3
    assert 30.0 < float(np.mean(h - eo.centre_m[:, 2])) < 31.5
    # imported back into a project with the same heights: the heights are the project's again
    dst = fresh_project(p, tmp_path / "back")
    import_files(dst, "metashape", [out / "metashape" / "cameras.xml"])
    back = read_eo(dst / "imported" / "eo.txt")
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-4 and np.abs(back.opk_deg - eo.opk_deg).max() < 1e-6
    con, mine = read_control_points(dst / "control" / "points.csv"), read_control_points(p / "control" / "points.csv")
    assert np.abs(con.xyz_m - mine.xyz_m).max() < 1e-4
    # into an ellipsoidal project the cameras come with h = H + N
    ell = fresh_project(root, tmp_path / "ell")
    import_files(ell, "metashape", [out / "metashape" / "cameras.xml"])
    assert np.abs(read_eo(ell / "imported" / "eo.txt").centre_m[:, 2] - h).max() < 1e-3


@pytest.mark.parametrize("reference", ["EPSG:4326", "EPSG:32649"])
def test_markers_in_a_2d_reference_are_ellipsoidal_as_the_cameras(adjusted_tiny, tmp_path, fresh_project,
                                                                  synthetic_geoid, reference):
    """Metashape's markers in a 2D <reference> (EPSG::4326, or the project's own horizontal CRS) carry ellipsoidal
    heights, as its cameras' geocentric coordinates do: on an EGM2008-height project both come back in its heights
    (s21 read the markers' z as the project's, a 2D CRS's rule for formats without a convention: the control N,
    +30 m here, above the cameras')."""
    root, _ = adjusted_tiny
    p = _with_heights(root, tmp_path / "p")
    out = tmp_path / "out"
    export_project(p, ["metashape"], out)
    xml = out / "metashape" / "cameras.xml"
    tree = ET.parse(xml)
    chunk = tree.getroot().find("chunk")
    to_ell = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(chunk.find("reference").text),
                                         pyproj.CRS(reference).to_3d(), always_xy=True)
    for r in chunk.findall("markers/marker/reference"):
        if "z" in r.attrib:
            x, y, h = to_ell.transform(*(float(r.get(k)) for k in "xyz"))
            r.set("x", repr(x)), r.set("y", repr(y)), r.set("z", repr(h))
    chunk.find("reference").text = pyproj.CRS(reference).to_wkt("WKT1_GDAL")
    tree.write(xml)
    dst = fresh_project(p, tmp_path / "back")
    import_files(dst, "metashape", [xml])
    eo, back = read_eo(Project.open(p).eo_path), read_eo(dst / "imported" / "eo.txt")
    assert np.abs(back.centre_m - eo.centre_m).max() < 1e-3
    con, mine = read_control_points(dst / "control" / "points.csv"), read_control_points(p / "control" / "points.csv")
    assert np.abs(con.xyz_m - mine.xyz_m).max() < 1e-3  # s21: z 30.0-31.5 m high


def test_orthometric_heights_without_the_geoid_grid(adjusted_tiny, tmp_path):
    """Without the geoid grid the export stops naming it (exit 2, nothing written), rather than place the block N off."""
    from pyproj.datadir import get_data_dir, get_user_data_dir

    if any((d / "us_nga_egm08_25.tif").exists() for d in map(Path, (get_data_dir(), get_user_data_dir()))):
        pytest.skip("the EGM2008 grid is installed here")
    root, _ = adjusted_tiny
    p = _with_heights(root, tmp_path / "p")
    out = tmp_path / "out"
    r = CliRunner().invoke(aerotri_cli, ["export", str(p), "--format", "metashape", "--out", str(out)])
    assert r.exit_code == 2 and "us_nga_egm08_25.tif" in r.output and "Traceback" not in r.output, r.output
    assert not (out / "metashape" / "cameras.xml").exists()
    # trial-exchange: the remedy named --params and --allow-ballpark, which aerotri export does not take
    assert "--params" not in r.output and "--allow-ballpark" not in r.output, r.output
    assert "metashape export" in r.output, r.output
    # every format the grid stops is named in one run (trial s96 L1: one per run)
    r = CliRunner().invoke(aerotri_cli, ["export", str(p), "--format", "metashape", "--format", "odm", "--format",
                                         "kml", "--out", str(out)])
    assert r.exit_code == 2 and "(the same grid stops odm, kml too)" in " ".join(r.output.split()), r.output
    assert not out.exists() or not any(out.rglob("*.*"))


def test_odm_export_of_orthometric_heights_says_gcp_list_is_not_ellipsoidal(adjusted_tiny, tmp_path, synthetic_geoid):
    """Review 21: `export --format odm` of a project with EGM2008 heights writes gcp_list.txt's geo_z as those
    heights under a horizontal CRS line, while reference_lla.json is ellipsoidal: OpenSfM reads geo_z against it, so
    the control sits N (+30 m here) low in ODM. Not converted yet (the ODM import reads such z as the project's
    heights, so export and import change together); said in a warning."""
    root, _ = adjusted_tiny
    p = _with_heights(root, tmp_path / "p")
    out = tmp_path / "out"
    r = CliRunner().invoke(aerotri_cli, ["export", str(p), "--format", "odm", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert (out / "odm" / "gcp_list.txt").is_file()
    assert "the geoid height low" in " ".join(r.output.split()), r.output


def test_a_second_chunk_and_projections_on_unknown_cameras_are_said(exported, tmp_path, fresh_project):
    """Trial s96 M4: a document of two chunks imported the first without a word, and marker projections on a camera
    id not in the chunk were dropped without one (1,052 -> 983). Both said in the import's notes now."""
    import copy

    root, xml = exported
    tree = ET.parse(xml)
    doc = tree.getroot()
    first = doc.find("chunk")
    first.set("label", "east")
    second = copy.deepcopy(first)
    second.set("label", "west")
    doc.append(second)
    loc = next(first.iter("location"))
    loc.set("camera_id", "99")
    two = tmp_path / "two.xml"
    tree.write(two, encoding="unicode")
    dst = fresh_project(root, tmp_path / "p")
    import_files(dst, "metashape", [two])
    notes = json.loads((dst / "imported" / "imports.json").read_text())["imports"][-1]["notes"]
    n = len(first.findall("cameras/camera"))
    assert any(f"holds 2 chunks; the first imported, east ({n} cameras); left out: west ({n} cameras)" in x
               for x in notes), notes
    assert any("1 marker projection on camera ids the chunk does not have (99) left out" in x for x in notes), notes
