"""roof_planes.geojson of ``lidarctl corners``: one polygon per roof face, shrunk inside its edges, with the
face's plane; read back by the adjustment (``aerotri.adjust.surface.read_roof_planes``) in metres."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner
from shapely import affinity
from shapely.geometry import shape

from aerotri.adjust.surface import read_roof_planes
from aerotri.core.errors import CrsError, InputError
from lidarctl import synthetic
from lidarctl.cli.main import main
from aerotri.geom.las import FOOT_M

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)
_spec = importlib.util.spec_from_file_location("test_units", Path(__file__).with_name("test_units.py"))
tu = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tu)

UTM = "EPSG:32649"


@pytest.fixture(scope="module")
def planes_dirs(tmp_path_factory):
    """lidarctl corners on the synthetic scene in UTM metres, in international feet and its metric copy."""
    d = tmp_path_factory.mktemp("planes")
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=3, heading_deg=-20.0)
    out = {"buildings": buildings}
    for name, crs in (("utm", UTM), ("ft", tu.FT_CRS)):
        tu._write_corner_las(d / f"{name}.las", x, y, z, cls, sid, crs)
        r = CliRunner().invoke(main, ["corners", str(d / f"{name}.las"), str(d / name), "--no-figure"])
        assert r.exit_code == 0, r.output
        out[name] = d / name
    out["ft_crs_m"] = synthetic.metric_copy(d / "ft.las", d / "ft_m.las")
    r = CliRunner().invoke(main, ["corners", str(d / "ft_m.las"), str(d / "ft_m"), "--no-figure"])
    assert r.exit_code == 0, r.output
    out["ft_m"] = d / "ft_m"
    return out


def test_roof_faces_lie_inside_their_roofs_with_the_roofs_planes(planes_dirs):
    gj = json.loads((planes_dirs["utm"] / "roof_planes.geojson").read_text())
    assert "32649" in gj["crs"]["properties"]["name"] and "z = a (x - x0)" in gj["plane_model"]
    assert gj["xy_unit"] == "m" and gj["sigma_strip_z_m"] == 0.03
    feats = gj["features"]
    # 6 flat roofs (the 6 x 6 m shed keeps a 3 x 3 m face) and the gable's two faces
    assert len(feats) == 8
    slopes = []
    for f in feats:
        p, poly = f["properties"], shape(f["geometry"])
        xy = np.asarray(poly.exterior.coords) - [tu.X0_M, tu.Y0_M]
        z_true, c = cs.surface(xy[:, 0], xy[:, 1], planes_dirs["buildings"])
        z_plane = p["a"] * (xy[:, 0] + tu.X0_M - p["x0"]) + p["b"] * (xy[:, 1] + tu.Y0_M - p["y0"]) + p["c"]
        # every vertex of the footprint on the roof, on the face's plane; the footprint at least the margin
        # (two spacings of the roof's points, about 0.7 m) inside the eaves, less a little for the points' noise
        assert np.all(c == 6) and np.abs(z_plane - z_true).max() < 0.03, p
        assert 1.3 < p["margin_m"] < 1.8
        local = affinity.translate(poly, -tu.X0_M, -tu.Y0_M)
        outside = min(local.difference(b[0].buffer(-p["margin_m"] + 0.3)).area for b in planes_dirs["buildings"])
        assert outside < 0.01, (p, outside)  # m^2: slivers of the simplified outline
        cov = np.asarray(p["cov_abc_m"])
        assert cov.shape == (3, 3) and 0 < np.sqrt(cov[2, 2]) < 0.01 and p["rms_m"] == pytest.approx(0.05, abs=0.01)
        slopes.append(p["slope_deg"])
    assert sorted(slopes)[-2:] == pytest.approx([np.degrees(np.arctan(3 / 6))] * 2, abs=1.0)  # the gable


def test_planes_in_feet_read_back_as_the_metric_copy(planes_dirs):
    ft = read_roof_planes(planes_dirs["ft"], pyproj.CRS(tu.FT_CRS))
    m = read_roof_planes(planes_dirs["ft_m"], planes_dirs["ft_crs_m"])
    gj = json.loads((planes_dirs["ft"] / "roof_planes.geojson").read_text())
    assert gj["xy_unit"] == "ft" and gj["z_unit"] == "ft" and gj["features"][0]["properties"]["rms_m"] < 0.1
    assert len(ft) == len(m) == 8
    # in metres of the map axes: the same planes
    assert np.allclose(ft.x0, m.x0, atol=2e-3) and np.allclose(ft.y0, m.y0, atol=2e-3)
    assert np.allclose(ft.abc, m.abc, atol=2e-3) and np.allclose(ft.cov_abc, m.cov_abc, rtol=0.05, atol=1e-9)
    # the footprints stay in map units (feet) for the lookup of the map positions
    area_ft = np.array([p.area for p in ft.footprints]) * FOOT_M**2
    assert np.allclose(area_ft, [p.area for p in m.footprints], rtol=0.02)
    c = ft.footprints[0].representative_point()
    assert ft.face_of([c.x], [c.y])[0] == 0 and ft.face_of([c.x + 1e5], [c.y])[0] == -1
    assert ft.sigma_strip_z_m == 0.03


def _edit(src: Path, dst: Path, change) -> Path:
    doc = json.loads((src / "roof_planes.geojson").read_text())
    change(doc)
    dst.mkdir()
    (dst / "roof_planes.geojson").write_text(json.dumps(doc, indent=1))
    return dst


def test_bad_roof_planes_files_are_refused(planes_dirs, tmp_path):
    utm = pyproj.CRS(UTM)
    with pytest.raises(CrsError, match=r"utm.*roof_planes.geojson: the roof planes are in EPSG:32649, the project in "
                                       r"EPSG:32650"):
        read_roof_planes(planes_dirs["utm"], pyproj.CRS("EPSG:32650"))
    with pytest.raises(InputError, match="nowhere: not found; expected a lidarctl corners folder"):
        read_roof_planes(tmp_path / "nowhere", utm)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty/roof_planes.geojson: no roof planes file"):
        read_roof_planes(tmp_path / "empty", utm)
    (tmp_path / "text").mkdir()
    (tmp_path / "text" / "roof_planes.geojson").write_text('{"type": "FeatureCollection",\n "features": [,]}')
    with pytest.raises(InputError, match="roof_planes.geojson line 2: not a GeoJSON file"):
        read_roof_planes(tmp_path / "text", utm)

    def feature(k, **kw):
        def change(doc):
            doc["features"][k]["properties"].update(kw.get("props", {}))
            for key in kw.get("drop", ()):
                del doc["features"][k]["properties"][key]
            if "geometry" in kw:
                doc["features"][k]["geometry"] = kw["geometry"]
        return change

    cases = [
        ("nocrs", lambda d: d.pop("crs"), CrsError, "names no CRS"),
        ("noa", feature(2, drop=["a"]), InputError, r"feature 3 \(RP00003\): no 'a'"),
        ("nan", feature(0, props={"c": "high"}), InputError, r"feature 1 \(RP00001\): c 'high': expected a finite number"),
        ("point", feature(1, geometry={"type": "Point", "coordinates": [1, 2]}), InputError,
         r"feature 2 \(RP00002\): geometry 'Point': expected a Polygon"),
        ("cov", feature(0, props={"cov_abc_m": [[1, 0], [0, 1]]}), InputError, "cov_abc_m: expected a 3 x 3 matrix"),
        ("negcov", feature(0, props={"cov_abc_m": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}), InputError,
         "not a covariance matrix"),
        ("nosigma", lambda d: d.pop("sigma_strip_z_m"), InputError, "give --plane-sigma-m"),
    ]
    for name, change, err, msg in cases:
        with pytest.raises(err, match=msg):
            read_roof_planes(_edit(planes_dirs["utm"], tmp_path / name, change), utm)
    # the strip sigma from the option instead of the file
    pl = read_roof_planes(tmp_path / "nosigma", utm, plane_sigma_m=0.05)
    assert pl.sigma_strip_z_m == pl.sigma_strip_xy_m == 0.05


def test_roof_outlines_gpkg_holds_the_traced_outlines_as_footprints_for_the_true_ortho(planes_dirs):
    """roof_outlines.gpkg (issue 42: the true ortho's building footprints where no cadastre is given): the outlines
    of corners.geojson, read by ``ortho rectify --footprints`` in the clouds' CRS, each on its building's eave."""
    from ortho.footprints import read_footprints

    gj = json.loads((planes_dirs["utm"] / "corners.geojson").read_text())
    traced = [shape(f["geometry"]) for f in gj["features"] if f["properties"]["kind"] == "roof_outline"]
    polys = read_footprints(planes_dirs["utm"] / "roof_outlines.gpkg", pyproj.CRS(UTM))
    assert len(polys) == len(traced) == len(planes_dirs["buildings"])
    assert sum(p.symmetric_difference(t).area for p, t in zip(polys, traced)) < 1e-3
    for b in planes_dirs["buildings"]:
        eave = affinity.translate(b[0], tu.X0_M, tu.Y0_M)
        best = min(polys, key=lambda p: p.symmetric_difference(eave).area)
        # the regularised outline on the eave: off by 0.03-0.12 m on average along its perimeter (the area between
        # them over the perimeter), a sixth of the cloud's 0.77 m point spacing at most
        assert best.symmetric_difference(eave).area < 0.2 * eave.length, (best.wkt, eave.wkt)
    # in feet: the coordinates in the clouds' CRS and unit, as corners.csv's
    ft = read_footprints(planes_dirs["ft"] / "roof_outlines.gpkg", pyproj.CRS(tu.FT_CRS))
    assert len(ft) == len(polys)
    assert sum(p.area for p in ft) * FOOT_M**2 == pytest.approx(sum(p.area for p in polys), rel=0.01)


def test_a_run_without_usable_corners_removes_the_roof_outlines_of_an_earlier_one(planes_dirs, tmp_path):
    """The chain's corners stage (``record_none``) finding no usable corner removes every corner file of the run
    before, roof_outlines.gpkg too: the true ortho must not take stale outlines as its footprints."""
    import shutil

    from lidarctl.corners.roof_corners import CornerSettings, corner_control

    out = tmp_path / "lidar_out"
    shutil.copytree(planes_dirs["utm"], out)
    assert (out / "roof_outlines.gpkg").is_file()
    res = corner_control([planes_dirs["utm"].parent / "utm.las"], out, CornerSettings(min_edge_m=100.0, figure=False),
                         record_none=True)
    assert res.no_usable and sorted(p.name for p in out.iterdir()) == ["corners.json"]

