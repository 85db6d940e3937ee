"""``aerotri crs assign`` (s27-fixes): a LAS/LAZ file whose CRS record is wrong is re-tagged without moving a point;
the refusal of a ``--crs`` that differs from a file's record names it; a WKT1 with TOWGS84 is its own EPSG code."""

import numpy as np
import laspy
import pyproj
import pytest
from click.testing import CliRunner
from laspy.vlrs.known import WktCoordinateSystemVlr

from aerotri.crs.cli import crs
from aerotri.geom import las
from aerotri.geom.crs.definition import same_crs, same_horizontal

# EPSG:28992 as WKT1 with TOWGS84 (what many writers put in LAS 1.4 files): pyproj makes it a "bound" CRS
RD_TOWGS84 = (
    'PROJCS["Amersfoort / RD New",GEOGCS["Amersfoort",DATUM["Amersfoort",SPHEROID["Bessel 1841",6377397.155,'
    '299.1528128,AUTHORITY["EPSG","7004"]],TOWGS84[565.417,50.3319,465.552,-0.398957,0.343988,-1.8774,4.0725],'
    'AUTHORITY["EPSG","6289"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,'
    'AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4289"]],PROJECTION["Oblique_Stereographic"],'
    'PARAMETER["latitude_of_origin",52.15616055555555],PARAMETER["central_meridian",5.38763888888889],'
    'PARAMETER["scale_factor",0.9999079],PARAMETER["false_easting",155000],PARAMETER["false_northing",463000],'
    'UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["X",EAST],AXIS["Y",NORTH]]')


def _run(*args):
    return CliRunner().invoke(crs, [str(a) for a in args])


def _cloud(path, version, fmt, crs=None, wkt=None, extra=False, n=500):
    """Amersfoort / RD New coordinates (Utrecht area), tagged with ``crs`` (or the WKT text ``wkt``)."""
    h = laspy.LasHeader(version=version, point_format=fmt)
    h.scales, h.offsets = [0.01] * 3, [85000.0, 445000.0, 0.0]
    if crs is not None:
        las.add_crs(h, pyproj.CRS(crs))
    if wkt is not None:
        h.vlrs.append(WktCoordinateSystemVlr(wkt))
        h.global_encoding.wkt = True
    if extra:
        h.vlrs.append(laspy.VLR("acme", 7, "flight notes", b"strip 1..12"))
    rng = np.random.default_rng(3)
    d = laspy.LasData(h)
    d.x, d.y, d.z = 85000 + rng.uniform(0, 100, n), 445000 + rng.uniform(0, 100, n), rng.uniform(0, 10, n)
    d.classification = rng.choice([2, 5], n).astype(np.uint8)
    d.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    if extra and version == "1.4":
        from laspy.vlrs.vlrlist import VLRList

        d.evlrs = VLRList([laspy.VLR("acme", 8, "long notes", b"x" * 100)])
    d.write(path)
    return path


@pytest.mark.parametrize("version,fmt,suffix,target", [("1.4", 6, ".las", "EPSG:28992"),
                                                       ("1.4", 6, ".laz", "EPSG:7415"),
                                                       ("1.2", 3, ".las", "EPSG:28992+5709")])
def test_assign_retags_a_wrong_crs_record_without_moving_a_point(tmp_path, version, fmt, suffix, target):
    """trial-lidar's W_wrong_14.las: RD coordinates tagged UTM 31N were refused with --crs EPSG:28992, and the advice
    (crs transform --to EPSG:28992) wrote x = -660,124 with exit 0. assign keeps every record and byte but the CRS."""
    from lidarctl import io

    src = _cloud(tmp_path / f"wrong{suffix}", version, fmt, crs="EPSG:32631", extra=True)
    with pytest.raises(io.CrsError, match="aerotri crs assign"):
        io.read_cloud(src, crs="EPSG:28992")
    out = tmp_path / f"fixed{suffix}"
    r = _run("assign", src, out, "--crs", target)
    assert r.exit_code == 0, r.output
    assert "EPSG:32631 ->" in r.output and "coordinates unchanged" in r.output
    a, b = laspy.read(src), laspy.read(out)
    assert a.points.array.tobytes() == b.points.array.tobytes()
    for k in ("scales", "offsets", "mins", "maxs", "point_count"):
        np.testing.assert_array_equal(getattr(a.header, k), getattr(b.header, k))
    assert same_crs(b.header.parse_crs(), target)
    crs_records = ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoAsciiParamsVlr", "GeoDoubleParamsVlr")
    others = [[(v.user_id, v.record_id, bytes(v.record_data)) for v in x.header.vlrs + list(x.header.evlrs or [])
               if type(v).__name__ not in crs_records] for x in (a, b)]
    assert others[0] == others[1] and others[0]
    cloud = io.read_cloud(out, crs="EPSG:28992")  # the file's record now agrees
    np.testing.assert_allclose(cloud.x, np.asarray(a.x), atol=0)


def test_assign_refuses_a_crs_the_coordinates_cannot_be_in(tmp_path):
    """Only what the CRS cannot hold is refused: RD coordinates are no degrees (EPSG:4326), no Gauss-Krueger zone 3
    eastings (no prefix 3); exit 2, no output. Outside the area of use (RD in UTM 32N, lat 4 deg N) is a warning."""
    src = _cloud(tmp_path / "wrong.las", "1.4", 6, crs="EPSG:32631")
    for target, why in (("EPSG:4326", "not a longitude"), ("EPSG:31467", "zone prefix 3")):
        r = _run("assign", src, tmp_path / "o.las", "--crs", target)
        assert r.exit_code == 2 and r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
        assert str(src) in r.output and why in r.output and "not re-tagged" in r.output
    r = _run("assign", src, tmp_path / "o.csv", "--crs", "EPSG:28992")
    assert r.exit_code == 2 and ".las or .laz" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wrong.las"]
    # RD coordinates read in UTM 32N fall near 4 deg N, 32 deg south of its area: another CRS (review 33; was a warning)
    r = _run("assign", src, tmp_path / "o.las", "--crs", "EPSG:25832")
    assert r.exit_code == 2 and "more than 10 deg outside the area of use of EPSG:25832" in r.output, r.output


@pytest.mark.parametrize("target,lon,lat", [("EPSG:25833", 10.7, 59.9), ("EPSG:25833", 5.3, 60.4),
                                            ("EPSG:25832", 14.9, 51.2), ("EPSG:25831", 7.1, 53.2),
                                            ("EPSG:32633", 19.5, 47.5)])
def test_assign_takes_a_national_grid_past_its_zones_area(tmp_path, target, lon, lat):
    """Review 31: Oslo and Bergen in EPSG:25833 (Norway's grid), Goerlitz in 25832 (Germany's), Groningen in 25831,
    Budapest in 32633 lie 1.5-6.7 deg past the zone's area of use (+1 deg margin) and were refused: re-tagged now,
    the warning names the area of use."""
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", target, always_xy=True).transform(lon, lat)
    h = laspy.LasHeader(version="1.2", point_format=3)
    h.scales, h.offsets = [0.01] * 3, [round(x0, -3), round(y0, -3), 0.0]
    d = laspy.LasData(h)
    d.x, d.y, d.z = x0 + np.arange(20.0), y0 + np.arange(20.0), np.zeros(20)
    d.write(tmp_path / "c.las")
    r = _run("assign", tmp_path / "c.las", tmp_path / "o.las", "--crs", target)
    assert r.exit_code == 0 and f"outside the area of use of {target}" in r.output, r.output
    assert same_crs(laspy.read(tmp_path / "o.las").header.parse_crs(), target)


def test_assign_refuses_a_crs_whose_area_lies_tens_of_degrees_away(tmp_path):
    """Review 33: Oregon coordinates re-tagged as the Swiss grid (22 deg outside its area) were only a warning;
    beyond ``FAR_OUTSIDE_AREA_DEG`` (10 deg) it is another CRS: refused, nothing written."""
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32610", always_xy=True).transform(-123.1, 44.05)
    h = laspy.LasHeader(version="1.2", point_format=3)
    h.scales, h.offsets = [0.01] * 3, [round(x0, -3), round(y0, -3), 0.0]
    d = laspy.LasData(h)
    d.x, d.y, d.z = x0 + np.arange(20.0), y0 + np.arange(20.0), np.zeros(20)
    d.write(tmp_path / "c.las")
    r = _run("assign", tmp_path / "c.las", tmp_path / "o.las", "--crs", "EPSG:2056")
    assert r.exit_code == 2 and "more than 10 deg outside the area of use of EPSG:2056" in r.output, r.output
    assert not (tmp_path / "o.las").exists()
    r = _run("assign", tmp_path / "c.las", tmp_path / "o.las", "--crs", "EPSG:32610")
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("target,lon,lat", [("EPSG:32760", -179.5, -18.0), ("EPSG:32601", 175.0, 60.0),
                                            ("EPSG:26940", 168.0, 53.0), ("EPSG:3338", 165.0, 55.0),
                                            ("EPSG:25833", 30.0, 70.4)])
def test_far_outside_is_measured_across_the_antimeridian_and_shortened_at_high_latitude(target, lon, lat):
    """Review 35: Fiji's Lau group in UTM 60S, 175 E in UTM 1N, the Aleutians west of 180 in Alaska's grids, Vardoe
    in UTM 33 (12 deg of longitude past the zone at 70 N, about 4 of a great circle): warned, not refused."""
    from aerotri.geom.crs.definition import check_coordinates, parse_crs

    crs = parse_crs(target)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    assert check_coordinates(crs, [x], [y], "c.las", outside_area="warn") is not None


@pytest.mark.parametrize("target,lon,lat", [("EPSG:2193", 178.0, -38.66), ("EPSG:3460", 178.44, -18.14)])
def test_a_false_easting_of_whole_millions_is_no_zone_prefix(target, lon, lat):
    """Review 35: NZTM (false easting 1,600,000) at Gisborne and the Fiji Map Grid (2,000,000) at Suva were refused
    as "does not carry the zone prefix"; Gauss-Krueger's prefix is the millions before 500 km, still checked."""
    from aerotri.core.errors import InputError
    from aerotri.geom.crs.definition import check_coordinates, parse_crs

    crs = parse_crs(target)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    assert check_coordinates(crs, [x], [y], "c.las") is None
    with pytest.raises(InputError, match="zone prefix 3"):
        check_coordinates(parse_crs("EPSG:31467"), [500000.0], [5500000.0], "c.las")


def test_check_coordinates_warn_refuses_only_points_the_crs_cannot_hold():
    """``outside_area="warn"``: a northing beyond the pole (UTM 33N, 12,000 km: PROJ takes it to lon -165), a point
    outside the projection's domain (not finite) are refused; Bergen in UTM 33 is the returned warning."""
    from aerotri.core.errors import InputError
    from aerotri.geom.crs.definition import check_coordinates, impossible_in, parse_crs

    utm33 = parse_crs("EPSG:25833")
    assert impossible_in(utm33, [259544.0, -28666.0, -3e6], [6648086.0, 6689498.0, 5e6]) is None
    assert impossible_in(utm33, [259544.0, 500000.0], [6648086.0, 12e6]) == 1
    assert impossible_in(utm33, [4e7], [5e6]) == 0
    for x, y in ((500000.0, 12e6), (4e7, 5e6)):
        with pytest.raises(InputError, match="cannot be a point of EPSG:25833"):
            check_coordinates(utm33, [x], [y], "f", outside_area="warn")
    msg = check_coordinates(utm33, [-28666.0], [6689498.0], "f", outside_area="warn")
    assert msg.startswith("f: point 1: (-28666.000, 6689498.000) lies outside the area of use of EPSG:25833")
    with pytest.raises(InputError, match="outside the area of use"):
        check_coordinates(utm33, [-28666.0], [6689498.0], "f")  # the other commands: refused as before
    assert check_coordinates(utm33, [500000.0], [6.6e6], "f", outside_area="warn") is None


def test_copc_input_is_refused_by_name_and_merge_writes_it_plain(tmp_path):
    """Review 31: a COPC LAZ to crs assign / transform stopped with laspy's NotImplementedError traceback (exit 1);
    refused now (exit 2, no output), naming COPC and lidarctl merge, which writes a plain LAZ of every point."""
    from lidarctl.merge import merge_las

    h = laspy.LasHeader(version="1.4", point_format=6)
    h.scales, h.offsets = [0.01] * 3, [85000.0, 445000.0, 0.0]
    las.add_crs(h, pyproj.CRS(28992))
    h.vlrs.append(laspy.VLR("copc", 1, "copc info", bytes(160)))
    d = laspy.LasData(h)
    d.x, d.y, d.z = 85000 + np.arange(50.0), 445000 + np.arange(50.0), np.zeros(50)
    d.write(tmp_path / "c.copc.laz")
    src = tmp_path / "c.copc.laz"
    assert las.is_copc(las.read_header(src))
    for args in (("assign", src, tmp_path / "o.laz", "--crs", "EPSG:28992"),
                 ("transform", src, tmp_path / "o.laz", "--to", "EPSG:25831")):
        r = _run(*args)
        assert r.exit_code == 2 and r.output.startswith("Error: ") and "a COPC file" in r.output, r.output
        assert "lidarctl merge" in r.output and r.output.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.copc.laz"]
    assert merge_las([src], tmp_path / "plain.laz") == 50
    assert not las.is_copc(las.read_header(tmp_path / "plain.laz"))
    r = _run("assign", tmp_path / "plain.laz", tmp_path / "o.laz", "--crs", "EPSG:28992")
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(laspy.read(tmp_path / "o.laz").x, d.x)


def test_a_wkt1_with_towgs84_is_its_own_epsg_code(tmp_path):
    """s27 (regression of trial-lidar's refusal): RD New as WKT1 with TOWGS84 (pyproj's bound CRS) was refused against
    --crs EPSG:28992, EPSG:7415, its ESRI WKT and PROJJSON, and the other way round."""
    from lidarctl import io

    towgs = _cloud(tmp_path / "towgs.las", "1.4", 6, wkt=RD_TOWGS84)
    assert las.read_header_crs(towgs, las.read_header(towgs)).is_bound
    for given in ("EPSG:28992", "EPSG:7415", pyproj.CRS(28992).to_wkt("WKT1_ESRI"), pyproj.CRS(7415).to_json()):
        assert io.read_cloud(towgs, crs=given).units.xy_m == 1.0
    plain = _cloud(tmp_path / "plain.las", "1.2", 3, crs="EPSG:28992")
    assert len(io.read_cloud(plain, crs=RD_TOWGS84)) == 500
    assert same_horizontal(pyproj.CRS(RD_TOWGS84), "EPSG:7415")
    assert not same_horizontal(pyproj.CRS(RD_TOWGS84), "EPSG:32631")


GK3 = "+proj=tmerc +lat_0=0 +lon_0=9 +k=1 +x_0=3500000 +y_0=0 +ellps=bessel +units=m +no_defs"
UTM32 = "+proj=utm +zone=32 +ellps=GRS80 +units=m"
RD_PROJ = ("+proj=sterea +lat_0=52.15616055555555 +lon_0=5.38763888888889 +k=0.9999079 +x_0=155000 +y_0=463000 "
           "+ellps=bessel +units=m")


@pytest.mark.parametrize("a,b,same", [
    (RD_TOWGS84, "EPSG:28992", True),  # RD New's usual TOWGS84: PROJ moves no point
    # review 31's raster (WKT1 of GDAL, no authority codes): 48.6 m. (With RD_TOWGS84's EPSG codes in it PROJ takes
    # the CRS for EPSG:28992 and ignores any TOWGS84 between the two: same, no move)
    (pyproj.CRS(RD_PROJ + " +towgs84=593.16,26.15,478.54,-6.3239,-0.5008,-5.5487,4.0775").to_wkt("WKT1_GDAL"),
     "EPSG:28992", False),
    (RD_PROJ + " +towgs84=565.417,50.3319,465.552,-0.398957,0.343988,-1.8774,4.0725", "EPSG:28992", True),
    (RD_PROJ + " +towgs84=598.1,73.7,418.2,0.202,0.045,-2.455,6.7", "EPSG:28992", False),  # DHDN's: 45 m
    (UTM32 + " +towgs84=0,0,0", "EPSG:25832", True),
    (UTM32 + " +towgs84=100,100,100", "EPSG:25832", False),  # 86 m
    (GK3 + " +towgs84=598.1,73.7,418.2,0.202,0.045,-2.455,6.7",
     GK3 + " +towgs84=577.326,90.129,463.919,5.137,1.474,5.297,2.4232", False),  # DHDN against MGI: 60 m
])
def test_a_bound_crs_is_its_base_only_when_its_towgs84_moves_no_point(a, b, same):
    """Review 31: same_crs called every bound CRS its base CRS while CrsTransformer applied the TOWGS84 (a raster warp
    kept the grid and cropped the picture 48.6 m off; imports skipped the shift). One rule now: same exactly when
    the transformation CrsTransformer applies moves the points by under BOUND_SAME_M (0.1 m)."""
    from aerotri.geom.crs.definition import BOUND_SAME_M
    from aerotri.geom.crs.transform import CrsTransformer

    assert same_crs(a, b) is same and same_crs(b, a) is same
    src = pyproj.CRS(a)
    base = src.source_crs if src.is_bound else src
    lon, lat = (9.5, 50.0) if "tmerc" in a or "utm" in a else (5.2, 52.1)
    x, y = pyproj.Transformer.from_crs(base.geodetic_crs, base, always_xy=True).transform(lon, lat)
    X, Y, _ = CrsTransformer(a, b, allow_ballpark=True).transform(np.array([x]), np.array([y]), np.array([0.0]))
    moved = float(np.hypot(X[0] - x, Y[0] - y))
    assert (moved < BOUND_SAME_M) is same, moved


def test_refusal_names_a_datum_realisation_and_a_wkt_crs_by_its_name(tmp_path):
    """WGS 84 (G1762) / UTM 32N is no EPSG:32632 (the ensemble): still refused, saying the realisation differs; a
    WKT --crs is named once, by its name, not echoed whole."""
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import UTMConversion

    from aerotri.geom.crs.definition import other_realisation
    from lidarctl import io

    g1762 = ProjectedCRS(UTMConversion(32), name="WGS 84 (G1762) / UTM zone 32N", geodetic_crs=pyproj.CRS(9057))
    assert other_realisation(g1762, "EPSG:32632") == ("World Geodetic System 1984 (G1762)",
                                                      "World Geodetic System 1984 ensemble")
    assert other_realisation("EPSG:32632", "EPSG:32633") is None
    h = laspy.LasHeader(version="1.4", point_format=6)
    h.offsets = [500000.0, 5500000.0, 0.0]
    h.add_crs(pyproj.CRS(32632))
    d = laspy.LasData(h)
    d.x, d.y, d.z = 500000 + np.arange(10.0), 5500000 + np.arange(10.0), np.zeros(10)
    d.write(tmp_path / "u.las")
    with pytest.raises(io.CrsError) as e:
        io.read_cloud(tmp_path / "u.las", crs=g1762.to_wkt())
    msg = str(e.value)
    assert "another datum realisation" in msg and "G1762" in msg and "aerotri crs assign" in msg
    assert "crs transform" in msg and "PROJCRS[" not in msg and msg.count("WGS 84 (G1762) / UTM zone 32N") >= 1
    with pytest.raises(io.CrsError) as e:
        io.resolve_crs_units(tmp_path / "u.las", las.read_header(tmp_path / "u.las"), "EPSG:25832",
                             crs_name="[project] crs")
    msg = str(e.value)
    assert "[project] crs = EPSG:25832 differs" in msg and "[project] crs is itself wrong" in msg


def test_transform_of_a_wrongly_tagged_file_warns_where_its_points_land(tmp_path):
    """s27: the old advice, `crs transform W_wrong_14.las OUT --to EPSG:28992`, wrote x = -660,124 with exit 0 and no
    word; it now warns that the transformed bounds lie outside EPSG:28992's area of use and names crs assign."""
    src = _cloud(tmp_path / "wrong.las", "1.4", 6, crs="EPSG:32631")
    r = _run("transform", src, tmp_path / "t.las", "--to", "EPSG:28992")
    assert r.exit_code == 0, r.output
    assert "outside the area of use of EPSG:28992" in r.output and "aerotri crs assign" in r.output
    fixed = tmp_path / "fixed.las"
    assert _run("assign", src, fixed, "--crs", "EPSG:28992").exit_code == 0
    r = _run("transform", fixed, tmp_path / "t2.las", "--to", "EPSG:25831")
    assert r.exit_code == 0 and "area of use" not in r.output, r.output


def test_a_proj_string_crs_with_heights_is_named_by_its_projection():
    """s95: the NGI project's "+proj=tmerc ..." CRS with EGM2008 heights was named "unknown + EGM2008 height" in
    the export's refusal; now by its projection and datum."""
    from aerotri.geom.crs.definition import height_crs, parse_crs

    c = height_crs(parse_crs("+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"),
                   parse_crs("EPSG:3855"))
    assert "unknown" not in c.name and c.name.startswith("Transverse Mercator") and c.name.endswith(" + EGM2008 height")
    assert height_crs(parse_crs("EPSG:32635"), parse_crs("EPSG:3855")).name == (
        "WGS 84 / UTM zone 35N + EGM2008 height")
