"""Linear units from the CRS (issue 17): a cloud in feet gives the same classes, rasters, height
check, evaluation and roof corners as its metric copy, with outputs in the input's CRS and units."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
from pyproj import CRS
from click.testing import CliRunner

from aerotri.core.errors import CrsError
from lidarctl import io, synthetic
from lidarctl.cli.main import main
from lidarctl.corners.roof_corners import read_corner_summary
from aerotri.geom.las import FOOT_M, US_SURVEY_FOOT_M
from lidarctl.units import LengthUnits, units_of

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)

FT_CRS = "EPSG:2994"        # NAD83(HARN) / Oregon GIC Lambert (ft), Autzen's projection
USFT_CRS = "EPSG:2227"      # NAD83 / California zone 3 (ftUS)
# Scene origin in the metric twin of the foot CRS (metres; near Eugene, Oregon for EPSG:2994).
X0_M, Y0_M = 193000.0, 258000.0


def _run(args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r


def _ok(args):
    r = _run(args)
    assert r.exit_code == 0, r.output
    return r


def _classes(path):
    return np.asarray(laspy.read(path).classification)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """One synthetic scene written in international feet, in US survey feet, and the exact metric
    copy of each (same integer records, scales x unit, the metric twin CRS)."""
    d = tmp_path_factory.mktemp("units")
    cloud, truth = synthetic.synthetic_scene(width_m=160.0, density_per_m2=3.0, seed=5, n_buildings=6,
                                             x0=X0_M, y0=Y0_M)
    out = {"cloud": cloud, "truth": truth, "dir": d}
    for name, crs in (("ft", FT_CRS), ("usft", USFT_CRS)):
        synthetic.write_las(d / f"{name}.laz", cloud, crs=crs)
        synthetic.write_las(d / f"{name}_truth.laz", cloud, classification=truth, crs=crs)
        synthetic.metric_copy(d / f"{name}.laz", d / f"{name}_m.laz")
    return out


def test_units_of_crs():
    assert units_of(pyproj.CRS(FT_CRS)).xy_m == FOOT_M
    u = units_of(pyproj.CRS(USFT_CRS))
    assert u.xy_m == pytest.approx(US_SURVEY_FOOT_M, rel=1e-12) and u.z_m == u.xy_m and u.xy_name == "us-ft"
    assert units_of(pyproj.CRS("EPSG:32632")).is_metric
    # A compound CRS carries its own vertical unit: UTM metres + NAVD88 height in US survey feet.
    comp = units_of(pyproj.CRS("EPSG:32610+6360"))
    assert comp.xy_m == 1.0 and comp.z_m == pytest.approx(US_SURVEY_FOOT_M) and comp.z_name == "us-ft"
    with pytest.raises(CrsError, match="geographic"):
        units_of(pyproj.CRS("EPSG:4326"), "x.laz")


def test_reading_scales_feet_to_metres(scenes):
    d, cloud = scenes["dir"], scenes["cloud"]
    for name, unit in (("ft", FOOT_M), ("usft", US_SURVEY_FOOT_M)):
        c = io.read_cloud(d / f"{name}.laz")
        assert c.units.xy_m == pytest.approx(unit, rel=1e-12)
        # 0.001 ft quantisation: within 0.2 mm of the metric scene
        np.testing.assert_allclose(c.x, cloud.x, atol=2e-4)
        np.testing.assert_allclose(c.z, cloud.z, atol=2e-4)
        m = io.read_cloud(d / f"{name}_m.laz")
        assert m.units.is_metric
        np.testing.assert_allclose(m.x, c.x, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["ft", "usft"])
def test_classify_feet_equals_metric_copy(scenes, name):
    d = scenes["dir"]
    for extra, tag in (([], "one"), (["--tile-size-m", "80", "--buffer-m", "40"], "tiled")):
        r = _ok(["classify", d / f"{name}.laz", d / f"{name}_{tag}.laz", *extra])
        assert "processed in metres" in r.output and ("tiles of 80 m" if extra else "1 tile of 160 m") in r.output, \
            r.output
        _ok(["classify", d / f"{name}_m.laz", d / f"{name}_m_{tag}.laz", *extra])
        a, b = _classes(d / f"{name}_{tag}.laz"), _classes(d / f"{name}_m_{tag}.laz")
        assert np.array_equal(a, b), f"{tag}: {np.mean(a != b) * 100:.3f} % of the points differ"
        # and the classes are right (the same rules as for metric data)
        truth = scenes["truth"]
        assert np.mean(a[truth == 2] == 2) > 0.98 and np.mean(a[truth == 6] == 6) > 0.9
    # the output is the input with new classes: same CRS, same coordinates in feet
    out = laspy.read(d / f"{name}_one.laz")
    src = laspy.read(d / f"{name}.laz")
    assert out.header.parse_crs() == src.header.parse_crs()
    np.testing.assert_array_equal(out.X, src.X)


def test_rasters_in_feet_have_metre_cells_and_say_their_units(scenes):
    d = scenes["dir"]
    _ok(["classify", d / "ft.laz", d / "ft_c.laz"])
    _ok(["classify", d / "ft_m.laz", d / "ft_m_c.laz"])
    _ok(["rasters", d / "ft_c.laz", d / "r_ft", "--res-m", "1"])
    _ok(["rasters", d / "ft_m_c.laz", d / "r_m", "--res-m", "1"])
    for name in ("dem", "dsm", "ndsm", "chm", "intensity"):
        with rasterio.open(d / "r_ft" / f"{name}.tif") as f, rasterio.open(d / "r_m" / f"{name}.tif") as m:
            assert f.res == pytest.approx((1 / FOOT_M, 1 / FOOT_M))       # 1 m cells, 3.2808 ft
            assert m.res == (1.0, 1.0) and f.shape == m.shape
            assert f.transform.c * FOOT_M == pytest.approx(m.transform.c, abs=1e-6)
            assert f.crs.linear_units == "foot" and f.tags()["LINEAR_UNITS"] == "foot"
            assert f.tags()["CELL_SIZE_M"] == "1"
            vf, vm = f.read(1, masked=True), m.read(1, masked=True)
            assert np.array_equal(vf.mask, vm.mask)
            if name == "intensity":  # a count, not a length: no vertical unit in its tags either
                assert f.units == (None,) and np.array_equal(vf, vm)
                assert "VERTICAL_UNITS" not in f.tags() and "VERTICAL_UNITS" not in m.tags()
            else:
                # heights in the CRS's vertical unit (feet), and labelled so
                assert f.units == ("foot",) and m.units == ("metre",) and "foot" in f.descriptions[0]
                assert f.tags()["VERTICAL_UNITS"] == "foot" and m.tags()["VERTICAL_UNITS"] == "metre"
                np.testing.assert_allclose(vf.compressed() * FOOT_M, vm.compressed(), atol=2e-5)
    with rasterio.open(d / "r_ft" / "dem.tif") as f:
        dem = f.read(1, masked=True)
        rows, cols = np.mgrid[0:f.height, 0:f.width]
        xs, ys = rasterio.transform.xy(f.transform, rows.ravel(), cols.ravel())
    # the DEM in feet against the true terrain (metres)
    true_m = synthetic.terrain_height(np.array(xs) * FOOT_M - X0_M, np.array(ys) * FOOT_M - Y0_M).reshape(dem.shape)
    err_m = (dem * FOOT_M - true_m).compressed()
    assert np.sqrt(np.mean(err_m ** 2)) < 0.15


def test_check_heights_in_feet_reports_metres(scenes, tmp_path):
    d = scenes["dir"]
    _ok(["classify", d / "ft.laz", d / "ft_h.laz"])
    rng = np.random.default_rng(0)
    px_m, py_m = X0_M + rng.uniform(10, 150, 20), Y0_M + rng.uniform(10, 150, 20)
    pz_m = synthetic.terrain_height(px_m - X0_M, py_m - Y0_M) - 0.2     # survey 0.2 m below the terrain
    pts = tmp_path / "points_ft.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"P{k},{a / FOOT_M:.4f},{b / FOOT_M:.4f},{c / FOOT_M:.4f}\n"
                                          for k, (a, b, c) in enumerate(zip(px_m, py_m, pz_m))))
    r = _ok(["check-heights", d / "ft_h.laz", pts, "--radius-m", "3", "--json", tmp_path / "hc.json"])
    hc = json.loads((tmp_path / "hc.json").read_text())
    assert hc["radius_m"] == 3 and hc["xy_unit"] == "ft" and hc["z_unit"] == "ft"
    assert hc["overall"]["all"]["mean_dz_m"] == pytest.approx(0.2, abs=0.05)     # metres, not feet
    assert hc["overall"]["bins"][2]["count"] == 20 - hc["n_without_ground"]      # all in -0.5 .. 0.5 m
    p0 = hc["points"][0]
    assert p0["x"] == pytest.approx(px_m[0] / FOOT_M, abs=1e-3) and p0["dz_m"] == pytest.approx(0.2, abs=0.1)
    assert p0["z_lidar"] - p0["z_survey"] == pytest.approx(p0["dz_m"] / FOOT_M, abs=1e-6)
    assert "heights in ft" in r.output and "z survey (ft)" in r.output and "dz (m)" in r.output
    # a 2D foot CRS says nothing of the heights' unit: the feet taken are said (trial-audit F2's cloud half)
    assert "declares no height unit" in r.output and "horizontal unit, foot" in r.output


def test_evaluate_compares_points_in_metres(scenes, tmp_path):
    d = scenes["dir"]
    _ok(["classify", d / "ft.laz", d / "ft_e.laz"])
    r = _ok(["evaluate", d / "ft_e.laz", "--truth", d / "ft_truth.laz", "--json", tmp_path / "e.json"])
    assert json.loads((tmp_path / "e.json").read_text())["filter_test"]["total_error_pct"] < 2.0
    # The truth in the metric copy holds the same points: compared in metres, they match.
    synthetic.metric_copy(d / "ft_truth.laz", tmp_path / "truth_m.laz")
    _ok(["evaluate", d / "ft_e.laz", "--truth", tmp_path / "truth_m.laz"])
    # Points 2 cm apart are not the same points, in feet as in metres.
    cloud = io.read_cloud(d / "ft_truth.laz")
    cloud.x[10] += 0.02
    synthetic.write_las(tmp_path / "moved.laz", cloud, classification=scenes["truth"], crs=FT_CRS)
    r = _run(["evaluate", d / "ft_e.laz", "--truth", tmp_path / "moved.laz"])
    assert r.exit_code == 2 and "point record 10" in r.output and "by 0.020" in r.output, r.output


def _write_corner_las(path, x, y, z, cls, sid, crs):
    units = units_of(pyproj.CRS(crs))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([np.floor(X0_M / units.xy_m), np.floor(Y0_M / units.xy_m), 0.0])
    header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = units.xy_from_m(x + X0_M), units.xy_from_m(y + Y0_M), units.z_from_m(z)
    las.classification = cls
    las.point_source_id = sid
    las.write(path)


def test_corners_in_feet_match_the_metric_copy(tmp_path):
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=3, heading_deg=-20.0)
    _write_corner_las(tmp_path / "c_ft.las", x, y, z, cls, sid, FT_CRS)
    synthetic.metric_copy(tmp_path / "c_ft.las", tmp_path / "c_m.las")
    r = _ok(["corners", tmp_path / "c_ft.las", tmp_path / "out_ft"])
    assert "x, y, z in foot" in r.output
    _ok(["corners", tmp_path / "c_m.las", tmp_path / "out_m", "--no-figure"])
    rf = list(csv.DictReader(open(tmp_path / "out_ft" / "corners.csv")))
    rm = list(csv.DictReader(open(tmp_path / "out_m" / "corners.csv")))
    assert len(rf) == len(rm) >= 15
    for a, b in zip(rf, rm):
        assert float(a["x"]) * FOOT_M == pytest.approx(float(b["x"]), abs=1e-3)
        assert float(a["z"]) * FOOT_M == pytest.approx(float(b["z"]), abs=1e-3)
        assert a["sx_m"] == b["sx_m"] and a["usable"] == b["usable"]           # sigmas in metres
    # the corners are where the truth is (coordinates in feet)
    truth_xyz, _, _ = cs.truth_corners(buildings)
    xy_m = np.array([[float(q["x"]) * FOOT_M - X0_M, float(q["y"]) * FOOT_M - Y0_M] for q in rf])
    j, dist = cs.match_corners(xy_m, truth_xyz[:, :2], max_dist_m=1.0)
    assert np.all(j >= 0)
    summary = read_corner_summary(tmp_path / "out_ft" / "corners.json")
    assert summary.units.xy_name == "ft" and summary.units.z_name == "ft"
    # the default edge length follows the spacing, both in metres (0.7 m nominal: 2.3 ft if it were feet)
    st = summary.stats
    assert 0.5 < st.point_spacing_m < 1.0
    assert st.min_edge_m == pytest.approx(max(2.0, 8.0 * st.point_spacing_m))
    gj = json.loads((tmp_path / "out_ft" / "corners.geojson").read_text())
    pt = next(f for f in gj["features"] if f["properties"]["kind"] == "roof_corner")
    assert pt["geometry"]["coordinates"][0] == pytest.approx(float(rf[0]["x"]), abs=1e-3)


def test_geographic_crs_is_refused(scenes, tmp_path):
    cloud = scenes["cloud"]
    nocrs = tmp_path / "nocrs.las"
    synthetic.write_las(nocrs, cloud, version="1.2")
    for args in (["classify", nocrs, tmp_path / "o.las", "--crs", "EPSG:4326"],
                 ["rasters", nocrs, tmp_path / "r", "--res-m", "1", "--crs", "EPSG:4326"]):
        r = _run(args)
        assert r.exit_code == 2 and "geographic" in r.output and "EPSG:4326" in r.output, r.output


@pytest.mark.realdata
def test_autzen_in_feet_equals_its_metric_copy(shared_data, tmp_path):
    """Autzen (international feet): the same classes as the exact metric copy, 1 m raster cells."""
    src = shared_data / "autzen" / "autzen_trim.laz"
    if not src.is_file():
        pytest.skip(f"{src} not found")
    metric = tmp_path / "autzen_m.laz"
    synthetic.metric_copy(src, metric)
    _ok(["classify", src, tmp_path / "ft.laz"])
    _ok(["classify", metric, tmp_path / "m.laz"])
    a, b = _classes(tmp_path / "ft.laz"), _classes(tmp_path / "m.laz")
    assert np.mean(a != b) * 100 < 0.1, f"{np.mean(a != b) * 100:.3f} % of the points differ"
    assert np.mean(a == 2) > 0.7          # mostly ground (the stadium's surroundings)
    _ok(["rasters", tmp_path / "ft.laz", tmp_path / "r", "--res-m", "1"])
    with rasterio.open(tmp_path / "r" / "dem.tif") as ds:
        assert ds.res == pytest.approx((1 / FOOT_M, 1 / FOOT_M))
        assert ds.units == ("foot",)
        dem = ds.read(1, masked=True)
        # Autzen's ground lies at 400-430 ft (about 125 m): heights stay in feet
        assert 380 < float(np.ma.median(dem)) < 440
        # 1177 x 563 ft = 359 x 172 m: about 360 x 172 cells of 1 m
        assert abs(ds.width - 360) <= 2 and abs(ds.height - 172) <= 2


@pytest.mark.parametrize("version", ["1.2", "1.4"])
def test_compound_crs_option_keeps_its_vertical_unit_in_the_output(scenes, tmp_path, version):
    """--crs with a compound CRS (UTM metres + NAVD88 height in US survey feet) for a file without
    CRS: heights are read as US feet, and the classified output says so (WKT, or for LAS 1.2 the
    GeoTIFF vertical keys)."""
    cloud = scenes["cloud"]
    z_ft = io.PointCloud(**{k: getattr(cloud, k) for k in ("x", "y", "intensity", "return_number",
                                                            "number_of_returns", "classification")},
                         z=cloud.z / US_SURVEY_FOOT_M)          # stored in US feet (write_las: no CRS, as is)
    src = tmp_path / "nocrs.las"
    synthetic.write_las(src, z_ft, version=version)
    c = io.read_cloud(src, crs="EPSG:32610+6360")
    assert c.units.xy_m == 1.0 and c.units.z_m == pytest.approx(US_SURVEY_FOOT_M)
    np.testing.assert_allclose(c.z, cloud.z, atol=1e-3)
    _ok(["classify", src, tmp_path / "out.las", "--crs", "EPSG:32610+6360"])
    out = io.read_cloud(tmp_path / "out.las")
    assert out.units.z_m == pytest.approx(US_SURVEY_FOOT_M) and out.crs.to_epsg() == 32610
    # the same classes as the cloud in metres
    synthetic.write_las(tmp_path / "m.las", cloud, crs="EPSG:32610", version=version)
    _ok(["classify", tmp_path / "m.las", tmp_path / "m_out.las"])
    a, b = _classes(tmp_path / "out.las"), _classes(tmp_path / "m_out.las")
    assert np.mean(a != b) < 0.002, np.mean(a != b)


def test_dem_keeps_the_compound_crs_of_its_cloud(scenes, tmp_path):
    """A cloud in UTM metres + NAVD88 height in US survey feet: the DEM and DSM carry the compound CRS
    (their heights' datum and unit), the relative rasters the horizontal CRS; the same for a cloud without a CRS
    record given the compound CRS with --crs."""
    cloud = scenes["cloud"]
    z_ft = io.PointCloud(**{k: getattr(cloud, k) for k in ("x", "y", "intensity", "return_number",
                                                            "number_of_returns", "classification")},
                         z=cloud.z / US_SURVEY_FOOT_M)
    src = tmp_path / "nocrs.las"
    synthetic.write_las(src, z_ft, version="1.4")
    _ok(["classify", src, tmp_path / "out.las", "--crs", "EPSG:32610+6360"])
    _ok(["rasters", tmp_path / "out.las", tmp_path / "r", "--res-m", "1"])
    # the classified cloud without its CRS record, the compound CRS given with --crs (trial-gis F10: `rasters --crs
    # EPSG:7415` of AHN3's crop wrote RD New alone, the heights' datum dropped without a word)
    import laspy
    from laspy.vlrs.vlrlist import VLRList

    las = laspy.read(tmp_path / "out.las")
    crs_records = ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoAsciiParamsVlr", "GeoDoubleParamsVlr")
    las.header.vlrs = VLRList([v for v in las.header.vlrs if type(v).__name__ not in crs_records])
    las.header.global_encoding.wkt = False
    las.write(tmp_path / "classified_nocrs.las")
    assert io.read_cloud(tmp_path / "classified_nocrs.las", require_crs=False).crs is None
    _ok(["rasters", tmp_path / "classified_nocrs.las", tmp_path / "r2", "--res-m", "1", "--crs", "EPSG:32610+6360"])
    for r in ("r", "r2"):
        with rasterio.open(tmp_path / r / "dem.tif") as dem, rasterio.open(tmp_path / r / "ndsm.tif") as ndsm:
            assert CRS(dem.crs).is_compound and "NAVD88" in CRS(dem.crs).sub_crs_list[1].name
            assert not CRS(ndsm.crs).is_compound and CRS(ndsm.crs).to_epsg() == 32610


def test_check_heights_by_chunks_equals_all_ground_points(scenes, tmp_path, monkeypatch):
    """The strips are read by chunks keeping only ground points near a surveyed point: the same
    heights as interpolating from every ground point of the cloud held in memory."""
    from lidarctl.checks import heights as hc

    d = scenes["dir"]
    _ok(["classify", d / "ft_m.laz", tmp_path / "c.laz"])
    rng = np.random.default_rng(1)
    px, py = X0_M + rng.uniform(-20, 180, 25), Y0_M + rng.uniform(-20, 180, 25)   # some off the cloud
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y,z\n" + "".join(f"P{k},{a:.3f},{b:.3f},50\n" for k, (a, b) in enumerate(zip(px, py))))
    monkeypatch.setattr(io, "CHUNK_POINTS", 7_000)
    streamed = hc.check_heights_file(tmp_path / "c.laz", pts, radius_m=3.0)
    cloud = io.read_cloud(tmp_path / "c.laz")
    g = cloud.classification == 2
    whole = hc._cloud_check_document(cloud.x[g], cloud.y[g], cloud.z[g], hc.read_points_csv(pts), radius_m=3.0)
    streamed = streamed.document
    z_s = np.array([p["z_lidar"] if p["z_lidar"] is not None else np.nan for p in streamed["points"]])
    z_w = np.array([p["z_lidar"] if p["z_lidar"] is not None else np.nan for p in whole["points"]])
    assert np.isnan(z_w).sum() == np.isnan(z_s).sum() > 0 and np.isfinite(z_w).sum() > 15
    np.testing.assert_allclose(z_s, z_w, rtol=0, atol=1e-9)
    assert [p["n_ground"] for p in streamed["points"]] == [p["n_ground"] for p in whole["points"]]


@pytest.mark.parametrize("cloud, header", [
    ("ft_m", ("x_ft", "y_ft", "z_ft")),              # a metric cloud, the points in international feet
    ("ft_m", ("easting_usft", "northing_usft", "h_m")),  # ... in US survey feet, heights in metres
    ("ft", ("x_usft", "y_usft", "z_usft")),          # an international-foot cloud, the points in US survey feet
    ("ft", ("x_m", "y_m", "z_ft")),
])
def test_check_heights_reads_the_units_of_the_points_header(scenes, tmp_path, cloud, header):
    """check-heights refused x_ft,y_ft,z_m ("no 'x' column"): the header's unit suffix is read and the points
    converted to the cloud's CRS units by pyproj's factors. The US survey foot is 2 ppm longer than the
    international foot: 0.4 m at these coordinates (x 633,000 ft), so the reported coordinates tell which one."""
    d = scenes["dir"]
    _ok(["classify", d / f"{cloud}.laz", tmp_path / "c.laz"])
    rng = np.random.default_rng(0)
    px_m, py_m = X0_M + rng.uniform(10, 150, 20), Y0_M + rng.uniform(10, 150, 20)
    pz_m = synthetic.terrain_height(px_m - X0_M, py_m - Y0_M) - 0.2     # survey 0.2 m below the terrain
    unit_m = {"m": 1.0, "ft": FOOT_M, "usft": US_SURVEY_FOOT_M}
    fxy, fz = unit_m[header[0].rsplit("_", 1)[1]], unit_m[header[2].rsplit("_", 1)[1]]
    pts = tmp_path / "points.csv"
    pts.write_text(f"id,{','.join(header)}\n" + "".join(f"P{k},{a / fxy:.4f},{b / fxy:.4f},{c / fz:.4f}\n"
                                                        for k, (a, b, c) in enumerate(zip(px_m, py_m, pz_m))))
    _ok(["check-heights", tmp_path / "c.laz", pts, "--radius-m", "3", "--json", tmp_path / "hc.json"])
    hc = json.loads((tmp_path / "hc.json").read_text())
    crs_m = 1.0 if cloud == "ft_m" else FOOT_M
    assert hc["xy_unit"] == ("m" if cloud == "ft_m" else "ft")
    assert hc["n_without_ground"] < 5 and hc["overall"]["all"]["mean_dz_m"] == pytest.approx(0.2, abs=0.05)
    p0 = hc["points"][0]
    assert p0["x"] == pytest.approx(px_m[0] / crs_m, abs=2e-3) and p0["z_survey"] == pytest.approx(pz_m[0] / crs_m,
                                                                                                   abs=2e-3)


def test_check_heights_refuses_points_in_degrees_against_a_projected_crs(scenes, tmp_path):
    pts = tmp_path / "points.csv"
    pts.write_text("id,x_deg,y_deg,z_m\nP1,-123.07,44.06,120.0\n")
    r = _run(["check-heights", scenes["dir"] / "ft_m.laz", pts, "--json", tmp_path / "hc.json"])
    assert r.exit_code == 2 and "x, y in deg" in r.output and "no factor converts" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "hc.json").exists()


def test_unit_names_are_the_crs_names():
    """``LengthUnits`` names its units with ``aerotri.geom.crs.definition.length_unit_name``: short names as
    ``unit_name`` gives them for a CRS, long names as GDAL and WKT spell them."""
    u = units_of(pyproj.CRS(FT_CRS))
    assert (u.xy_name, u.z_name) == ("ft", "ft") and u.describe() == "x, y, z in foot"
    comp = units_of(pyproj.CRS("EPSG:32610+6360"))
    assert comp.describe() == "x, y in metre, z in US survey foot"
    assert LengthUnits(0.5, 0.5).xy_name == "0.5m" and LengthUnits(0.5, 1.0).describe() == "x, y in 0.5 metre, z in metre"
    assert LengthUnits(known=False).describe() == "unknown units (no CRS)"


def _survey(path, header_z, z_factor, n=20):
    """Surveyed points of the scene 0.2 m below its terrain, x, y in the metric twin's metres scaled by ``xy`` of
    the header, heights written as metres / ``z_factor`` under the column ``header_z``."""
    rng = np.random.default_rng(0)
    px_m, py_m = X0_M + rng.uniform(10, 150, n), Y0_M + rng.uniform(10, 150, n)
    pz_m = synthetic.terrain_height(px_m - X0_M, py_m - Y0_M) - 0.2
    path.write_text(f"id,x_m,y_m,{header_z}\n" + "".join(f"P{k},{a:.4f},{b:.4f},{c / z_factor:.4f}\n"
                                                        for k, (a, b, c) in enumerate(zip(px_m, py_m, pz_m))))
    return path


@pytest.mark.parametrize("cloud, z_factor, header", [("ft", 1.0, "z_m"), ("ft_m", FOOT_M, "z_ft")])
def test_check_heights_says_when_plain_heights_fit_in_the_other_unit(scenes, tmp_path, cloud, z_factor, header):
    """Trial (Autzen, EPSG:2994): surveyed heights in metres under a plain 'z' against a cloud in feet: mean dz
    90.167 m, 100 % over 5 m, no hint. The heights are taken in the CRS's unit as before, and a warning says they
    fit in the other unit (median |dz| 0.2 m, the survey's known offset) and names the header that converts them;
    with that header, the check is right and says nothing. Also the other way: feet under 'z' against metres."""
    d = scenes["dir"]
    c = tmp_path / "c.laz"
    _ok(["classify", d / f"{cloud}.laz", c])
    r = _ok(["check-heights", c, _survey(tmp_path / "plain.csv", "z", z_factor), "--radius-m", "3",
             "--json", tmp_path / "p.json"])
    hc = json.loads((tmp_path / "p.json").read_text())
    assert hc["overall"]["all"]["mean_abs_dz_m"] > 5  # the numbers stand: the CRS's unit is assumed, never guessed
    slip = hc["unit_slip"]
    assert slip["median_abs_dz_other_unit_m"] == pytest.approx(0.2, abs=0.05) and slip["header"].startswith(header)
    # before the tables (trial s96 F14: after them, behind 40 lines of numbers in the wrong unit)
    out = r.output.strip().splitlines()
    k = next(i for i, ln in enumerate(out) if ln.startswith("warning: the cloud and the surveyed heights differ by a "
                                                              "median |dz| of "))
    assert k < next(i for i, ln in enumerate(out) if ln.startswith("LiDAR height check"))
    assert f"name the column {header}" in out[k] and "the header's 'z' names no unit" in out[k]
    r = _ok(["check-heights", c, _survey(tmp_path / "named.csv", header, z_factor), "--radius-m", "3",
             "--json", tmp_path / "n.json"])
    hc = json.loads((tmp_path / "n.json").read_text())
    # no unit slip said (the feet a 2D foot CRS's cloud is taken in are: declares no height unit)
    assert "unit_slip" not in hc and "warning: the cloud and the surveyed heights" not in r.output
    assert hc["overall"]["all"]["mean_dz_m"] == pytest.approx(0.2, abs=0.05)


def test_an_intensity_raster_is_refused_as_a_dem_and_a_dem_in_feet_says_the_unit_slip(scenes, tmp_path):
    """Trial: check-heights --dem r/intensity.tif was accepted (RMSE 91.86 m) and contours traced intensity.
    lidarctl rasters tags its intensity.tif QUANTITY=intensity (heights: VERTICAL_UNITS); a raster tagged so, or
    carrying the band description rasters gave intensity.tif before the tag, is refused as a DEM (exit 2, one
    line naming the file); a DEM of other software without either is read as before. The DEM alone in feet with
    plain metres: the warning names the DEM."""
    from lidarctl.rasters.products import DESCRIPTIONS, write_cog

    d = scenes["dir"]
    _ok(["classify", d / "ft.laz", tmp_path / "c.laz"])
    _ok(["rasters", tmp_path / "c.laz", tmp_path / "r", "--res-m", "1"])
    with rasterio.open(tmp_path / "r" / "intensity.tif") as f, rasterio.open(tmp_path / "r" / "dem.tif") as g:
        assert f.tags()["QUANTITY"] == "intensity" and "QUANTITY" not in g.tags()
        data, profile = f.read(1), dict(crs=f.crs, transform=f.transform)
    pts = _survey(tmp_path / "p.csv", "z_m", 1.0)
    old = tmp_path / "old_intensity.tif"   # written before the tag: the description only
    write_cog(old, data, profile["transform"], profile["crs"], description=DESCRIPTIONS["intensity"])
    foreign = tmp_path / "foreign.tif"     # another program's raster: neither
    write_cog(foreign, data, profile["transform"], profile["crs"])
    for raster, said in ((tmp_path / "r" / "intensity.tif", "holds intensity (its QUANTITY tag)"),
                         (old, "holds intensity (its band description")):
        for args in (["check-heights", pts, "--dem", raster], ["contours", raster, tmp_path / "c.gpkg",
                                                                "--interval-m", "1"]):
            r = _run(args)
            assert r.exit_code == 2 and "Traceback" not in r.output, r.output
            assert len(r.output.strip().splitlines()) == 1
            assert f"{raster}: {said}" in r.output and "expected a height raster for the DEM" in r.output
        assert not (tmp_path / "c.gpkg").exists()
    assert _run(["check-heights", pts, "--dem", foreign]).exit_code == 0
    r = _ok(["check-heights", _survey(tmp_path / "plain.csv", "z", 1.0), "--dem", tmp_path / "r" / "dem.tif"])
    assert "warning: the DEM and the surveyed heights differ" in r.output and "name the column z_m" in r.output


def test_a_us_survey_foot_typed_in_metres_makes_whole_foot_cells(scenes, caplog):
    """--res-m 0.3048006096 (the US survey foot to 10 digits) on a US-ft cloud made cells of 0.999999999996 ft on an
    origin off the whole foot (trial-us): within 10 ppm of a whole foot the cell is one, on a whole-foot origin."""
    import logging

    d = scenes["dir"]
    _ok(["classify", d / "usft.laz", d / "usft_c.laz"])
    with caplog.at_level(logging.INFO, logger="lidarctl.rasters.products"):
        _ok(["rasters", d / "usft_c.laz", d / "r_usft", "--res-m", "0.3048006096"])
    assert "cells of 1 us-ft" in caplog.text
    with rasterio.open(d / "r_usft" / "dem.tif") as f:
        assert f.res == (1.0, 1.0)
        assert f.transform.c == round(f.transform.c) and f.transform.f == round(f.transform.f)
        assert f.tags()["CELL_SIZE"] == "1 us-ft"


def test_classify_notes_name_places_and_heights_in_the_clouds_units():
    """Trial s96 F5: a feet cloud's water note named "x 193918.9 y 258819.9" (its feet in metres: no position in its
    CRS) and the level in metres. In the cloud's units now, metres beside a height in feet; unset: metres."""
    from lidarctl.classify import pipeline as cl
    from lidarctl.units import LengthUnits

    try:
        cl.set_place_units(LengthUnits(0.3048, 0.3048))
        assert cl._place(636216.8 * 0.3048, 849146.5 * 0.3048) == "x 636216.8 y 849146.5 ft"
        assert cl._height(130.47) == "428.05 ft (130.47 m)"
        cl.set_place_units(LengthUnits())
        assert cl._place(10.0, 20.0) == "x 10.0 y 20.0 m" and cl._height(5.0) == "5.00 m"
    finally:
        cl.set_place_units(None)
    assert cl._place(1.0, 2.0) == "x 1.0 y 2.0 m"
