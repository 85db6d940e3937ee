"""Point lists and LAS/LAZ through CrsTransformer: counts, every point dimension and the CRS record."""

import laspy
import numpy as np
import pyproj
import pytest

from aerotri.geom.crs.files import las_crs, transform_las, transform_point_list
from aerotri.geom.crs.datum import HeightAnomalyModel, Transformation
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7
from aerotri.geom.crs.transform import CrsTransformer
from aerotri.core.errors import InputError

PARAMS = Transformation("bursa-wolf7", TRUE_BURSA_WOLF7, "EPSG:32649", "EPSG:2361")
HEIGHTS = HeightAnomalyModel("plane", (37_450_000.0, 3_800_000.0), coefficients=[-27.5, 0.012, -0.03],
                             crs="EPSG:2361")


def _synthetic_las(path, n=3000, version="1.4", point_format=6, seed=0):
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(version=version, point_format=point_format)
    header.add_extra_dim(laspy.ExtraBytesParams(name="range_m", type=np.float32))
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([400_000.0, 3_780_000.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(32649))
    las = laspy.LasData(header)
    las.x = rng.uniform(440_000, 442_000, n)
    las.y = rng.uniform(3_790_000, 3_792_000, n)
    las.z = rng.uniform(400, 600, n)
    las.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    las.classification = rng.choice([1, 2, 3, 4, 5, 6, 9], n).astype(np.uint8)
    las.return_number = rng.integers(1, 4, n, dtype=np.uint8)
    las.number_of_returns = np.maximum(las.return_number, rng.integers(1, 4, n, dtype=np.uint8))
    las.gps_time = np.sort(rng.uniform(3.0e8, 3.0e8 + 60, n))
    las.user_data = rng.integers(0, 255, n, dtype=np.uint8)
    las.point_source_id = rng.integers(1, 20, n, dtype=np.uint16)
    las.range_m = rng.uniform(500, 900, n).astype(np.float32)
    las.write(path)
    return las


@pytest.mark.parametrize("version,point_format,suffix", [("1.4", 6, ".las"), ("1.2", 3, ".laz")])
def test_las_transform_keeps_every_dimension(tmp_path, version, point_format, suffix):
    src = tmp_path / "strip.las"
    las = _synthetic_las(src, version=version, point_format=point_format)
    out = tmp_path / f"strip_xian80{suffix}"
    t = CrsTransformer(32649, 2361, params=PARAMS, heights=HEIGHTS)
    n = transform_las(src, out, t, chunk_size=700)  # several chunks
    assert n == len(las.points)
    res = laspy.read(out)
    assert res.header.point_count == len(las.points)
    assert res.header.point_format.id == point_format
    for dim in las.point_format.dimension_names:
        if dim not in ("X", "Y", "Z"):
            assert np.array_equal(np.asarray(res[dim]), np.asarray(las[dim])), dim
    X, Y, Z = CrsTransformer(32649, 2361, params=PARAMS, heights=HEIGHTS).transform(las.x, las.y, las.z)
    q = res.header.scales
    assert np.max(np.abs(res.x - X)) <= q[0] / 2 + 1e-9
    assert np.max(np.abs(res.y - Y)) <= q[1] / 2 + 1e-9
    assert np.max(np.abs(res.z - Z)) <= q[2] / 2 + 1e-9
    assert np.all(np.floor(res.x / 1e6) == 37)  # zone-prefixed eastings fit the LAS integers
    assert res.header.parse_crs().to_epsg() == 2361
    names = [type(v).__name__ for v in res.header.vlrs]
    assert names.count("ExtraBytesVlr") == 1 and res.header.generating_software == "aerotri crs transform"
    assert np.allclose(res.header.mins, [res.x.min(), res.y.min(), res.z.min()])
    assert np.allclose(res.header.maxs, [res.x.max(), res.y.max(), res.z.max()])


def test_las_crs_mismatch_and_no_partial_output(tmp_path):
    src = tmp_path / "strip.las"
    _synthetic_las(src, n=100)
    out = tmp_path / "out.las"
    with pytest.raises(InputError, match="not --from EPSG:32650"):
        transform_las(src, out, CrsTransformer(32650, 4326))
    assert not out.exists() and list(tmp_path.iterdir()) == [src]


def test_nebraska_las_feet_to_utm_metres(shared_data, tmp_path):
    src = shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las"
    crs = las_crs(src)
    assert crs.to_epsg(min_confidence=70) == 6880
    out = tmp_path / "nebraska_utm14.laz"
    n = transform_las(src, out, CrsTransformer(crs, 6343), chunk_size=10_000)
    a, b = laspy.read(src), laspy.read(out)
    assert n == len(a.points) == len(b.points) == 25_408
    for dim in a.point_format.dimension_names:
        if dim not in ("X", "Y", "Z"):
            assert np.array_equal(np.asarray(a[dim]), np.asarray(b[dim])), dim
    assert np.array_equal(np.bincount(b.classification), np.bincount(a.classification))
    # the file's own (ESRI) WKT differs from EPSG:6880's definition by ~1e-5 m: compare with the same CRS
    X, Y = pyproj.Transformer.from_crs(crs, 6343, always_xy=True).transform(a.x, a.y)
    assert np.max(np.abs(b.x - X)) <= b.header.scales[0] / 2 + 1e-9
    assert np.max(np.abs(b.y - Y)) <= b.header.scales[1] / 2 + 1e-9
    # heights follow the grid unit: US survey feet -> metres
    assert np.max(np.abs(b.z - a.z * 1200 / 3937)) <= b.header.scales[2] / 2 + 1e-9
    assert b.header.parse_crs().to_epsg() == 6343
    # both old CRS records (WKT and GeoTIFF keys) were replaced by one
    names = [v.__class__.__name__ for v in b.header.vlrs]
    assert names.count("WktCoordinateSystemVlr") == 1 and "GeoKeyDirectoryVlr" not in names


def test_point_lists_csv_and_txt(tmp_path):
    csv_in = tmp_path / "gcp.csv"
    csv_in.write_text(
        "# control points, WGS 84 UTM 49N\n"
        "id,kind,x,y,z,sx\n"
        "G1,full,441000.000,3791000.000,500.000,0.02\n"
        "G2,full,441500.000,3791500.000,520.000,0.02\n"
    )
    out = tmp_path / "gcp_xian.csv"
    t = CrsTransformer(32649, 2361, params=PARAMS, heights=HEIGHTS)
    assert transform_point_list(csv_in, out, t) == 2
    lines = out.read_text().splitlines()
    assert lines[0].startswith("# control points") and lines[1] == "id,kind,x,y,z,sx"
    fields = lines[2].split(",")
    X, Y, Z = CrsTransformer(32649, 2361, params=PARAMS, heights=HEIGHTS).transform([441000.0], [3791000.0], [500.0])
    assert fields[:2] == ["G1", "full"] and fields[5] == "0.02"
    assert float(fields[2]) == pytest.approx(X[0], abs=1e-4) and float(fields[4]) == pytest.approx(Z[0], abs=1e-4)
    txt_in = tmp_path / "gnss.txt"
    txt_in.write_text("IMG_001 441000.0 3791000.0 1500.0 0.05 0.05 0.08\nIMG_002 441500.0 3791000.0 1500.0 0.05 0.05 0.08\n")
    txt_out = tmp_path / "gnss_geo.txt"
    transform_point_list(txt_in, txt_out, CrsTransformer(32649, 4326))
    f = txt_out.read_text().splitlines()[0].split()
    lon, lat = pyproj.Transformer.from_crs(32649, 4326, always_xy=True).transform(441000.0, 3791000.0)
    assert f[0] == "IMG_001" and float(f[1]) == pytest.approx(lon, abs=1e-9) and float(f[2]) == pytest.approx(lat, abs=1e-9)
    assert f[4:] == ["0.05", "0.05", "0.08"]


def test_point_list_bad_records_name_the_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("id,x,y,z\nA,441000,3791000,500\nB,441000,north,500\n")
    with pytest.raises(InputError, match=r"bad.csv: line 3: y = 'north' is not a number"):
        transform_point_list(bad, tmp_path / "o.csv", CrsTransformer(32649, 4326))
    deg = tmp_path / "deg.csv"
    deg.write_text("id,x,y,z\nA,441000,3791000,500\nB,109.3,34.2,500\n")
    with pytest.raises(InputError, match=r"deg.csv: line 3: .*outside the area of use of EPSG:32649"):
        transform_point_list(deg, tmp_path / "o.csv", CrsTransformer(32649, 4326))
    assert not (tmp_path / "o.csv").exists()


def _vertical_keys_copy(src, out, unit_code, size_m=None):
    """A copy of ``src`` whose VerticalUnitsGeoKey (4099) is ``unit_code`` (32767: user-defined, with its size in
    GeogLinearUnitSizeGeoKey (2053) when ``size_m`` is given); every point as it is."""
    import ctypes

    from laspy.vlrs.known import GeoDoubleParamsVlr, GeoKeyEntryStruct

    las = laspy.read(src)
    vlr = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    vlr.geo_keys = [k for k in vlr.geo_keys if k.id not in (4099, 2053)]
    keys = [(4099, 0, unit_code)]
    if size_m is not None:
        doubles = next((v for v in las.header.vlrs if type(v).__name__ == "GeoDoubleParamsVlr"), None)
        if doubles is None:
            doubles = GeoDoubleParamsVlr()
            las.header.vlrs.append(doubles)
        doubles.doubles = list(doubles.doubles) + [ctypes.c_double(size_m)]
        keys.append((2053, 34736, len(doubles.doubles) - 1))
    for key_id, location, value in keys:
        k = GeoKeyEntryStruct()
        k.id, k.tiff_tag_location, k.count, k.value_offset = key_id, location, 1, value
        vlr.geo_keys.append(k)
    vlr.geo_keys.sort(key=lambda k: k.id)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
    las.write(out)
    return out


def _keys_only(src, out):
    """A LAS 1.2 copy of ``src`` with its GeoTIFF keys and without its WKT record (as a LAS 1.2 delivery)."""
    a = laspy.read(src)
    las = laspy.LasData(laspy.LasHeader(version="1.2", point_format=3))
    las.header.scales, las.header.offsets = a.header.scales, a.header.offsets
    las.header.vlrs = [v for v in a.header.vlrs if type(v).__name__ != "WktCoordinateSystemVlr"]
    las.x, las.y, las.z = a.x, a.y, a.z
    las.write(out)
    return out


@pytest.mark.parametrize("unit_code,size_m,vertical", [(9001, None, 5703), (32767, 0.3048, 8228), (9003, None, 6360)])
def test_nebraska_heights_in_the_vertical_units_key(shared_data, tmp_path, unit_code, size_m, vertical):
    """small-fixes2 1: transform_las read z in the grid's unit (US survey feet) whatever VerticalUnitsGeoKey said:
    heights in metres came out 0.3048x, heights in international feet 2 ppm off. The key is read as lidarctl's
    readers read it (a user-defined one sized by 2053); checked against pyproj's compound-CRS transformation
    (Nebraska ft + NAVD88 height in the key's unit -> UTM 14N + NAVD88 height in metres)."""
    # s6-fixes: keys beside a WKT record are not read (the WKT is the CRS): a LAS 1.2 copy keyed alone
    src = _keys_only(_vertical_keys_copy(shared_data / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las",
                                         tmp_path / "keyed.las", unit_code, size_m), tmp_path / "keyed12.las")
    out = tmp_path / "utm14.las"
    crs = las_crs(src)
    transform_las(src, out, CrsTransformer(crs, 26914), chunk_size=10_000)  # the keys' NAD83: no datum shift
    a, b = laspy.read(src), laspy.read(out)
    ref = pyproj.Transformer.from_crs(pyproj.CRS.from_json_dict({"type": "CompoundCRS", "name": "keyed", "components": [
        crs.to_json_dict(), pyproj.CRS.from_epsg(vertical).to_json_dict()]}), pyproj.CRS("EPSG:26914+5703"),
        always_xy=True)
    X, Y, Z = ref.transform(np.asarray(a.x), np.asarray(a.y), np.asarray(a.z))
    q = b.header.scales
    assert np.max(np.abs(b.x - X)) <= q[0] / 2 + 1e-9 and np.max(np.abs(b.y - Y)) <= q[1] / 2 + 1e-9
    assert np.max(np.abs(b.z - Z)) <= q[2] / 2 + 1e-9
    # the output's record: a 2D metre grid, no vertical keys left to say otherwise (heights in its unit, metres)
    from aerotri.geom.las import geokey_vertical_unit_m

    assert geokey_vertical_unit_m(b.header) is None and b.header.parse_crs().to_epsg() == 26914
    from lidarctl.io import resolve_crs_units

    assert resolve_crs_units(out, b.header, None)[1].z_m == 1.0


def test_las_vertical_units_key_unreadable_or_contradicted(tmp_path):
    """A user-defined VerticalUnitsGeoKey without its size is refused naming the file (no output); a compound --from
    states the heights' unit in its place; a GeoTIFF-keyed output of a compound --to gets its vertical keys."""
    from aerotri.geom.las import geokey_vertical_unit_m
    from aerotri.core.errors import CrsError

    plain = tmp_path / "plain.las"
    las = _synthetic_las(plain, n=400, version="1.2", point_format=3)
    bad = _vertical_keys_copy(plain, tmp_path / "nosize.las", 32767)
    out = tmp_path / "out.las"
    with pytest.raises(CrsError, match=r"nosize.las: CRS record present but unreadable \(VerticalUnitsGeoKey \(4099\) "
                                       r"is user-defined \(32767\) but GeogLinearUnitSizeGeoKey \(2053\).*compound CRS"):
        transform_las(bad, out, CrsTransformer(32649, 32650))
    assert not out.exists()
    # heights in international feet: NAVD88 height (ft) over the file's grid -> UTM 50N + NAVD88 height (m)
    n = transform_las(bad, out, CrsTransformer("EPSG:32649+8228", "EPSG:32650+5703"))
    res = laspy.read(out)
    X, Y, Z = pyproj.Transformer.from_crs("EPSG:32649+8228", "EPSG:32650+5703", always_xy=True).transform(
        np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))
    assert n == 400 and np.max(np.abs(res.z - Z)) <= res.header.scales[2] / 2 + 1e-9
    assert np.max(np.abs(res.x - X)) <= res.header.scales[0] / 2 + 1e-9
    assert geokey_vertical_unit_m(res.header) == 1.0
    assert res.header.parse_crs().to_epsg() == 32650
    # a key in feet against a compound --from in metres: refused, not one silently preferred
    feet = _vertical_keys_copy(plain, tmp_path / "feet.las", 9002)
    with pytest.raises(InputError, match=r"feet.las: the file's VerticalUnitsGeoKey \(4099\) gives heights in foot, "
                                         r"--from .* in metre"):
        transform_las(feet, tmp_path / "o2.las", CrsTransformer("EPSG:32649+5703", "EPSG:32650+5703"))
    # the key read on a metre grid: 0.3048 m per height unit
    transform_las(feet, tmp_path / "o3.las", CrsTransformer(32649, 32650))
    o3 = laspy.read(tmp_path / "o3.las")
    assert np.max(np.abs(o3.z - las.z * 0.3048)) <= o3.header.scales[2] / 2 + 1e-9
    assert geokey_vertical_unit_m(o3.header) is None  # the input's key in feet not copied: heights in the grid's metres


def _with_stale_keys(src, out, keys):
    """A copy of LAS 1.4 ``src`` (a WKT record, its WKT bit set) with GeoTIFF keys beside it (``keys``: (id, value)
    pairs, as an older copy left them); every point as it is."""
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

    las = laspy.read(src)
    vlr = GeoKeyDirectoryVlr()
    vlr.geo_keys_header.key_directory_version = 1
    vlr.geo_keys_header.key_revision = 1
    vlr.geo_keys = []
    for key_id, value in keys:
        k = GeoKeyEntryStruct()
        k.id, k.tiff_tag_location, k.count, k.value_offset = key_id, 0, 1, value
        vlr.geo_keys.append(k)
    vlr.geo_keys_header.number_of_keys = len(vlr.geo_keys)
    las.header.vlrs.append(vlr)
    las.write(out)
    return out


def test_a_wkt_record_makes_stale_vertical_units_keys_unread(tmp_path):
    """s6-fixes 3: a LAS 1.4 file with its WKT bit set had its GeoTIFF VerticalUnitsGeoKey (4099) read all the same,
    while its CRS came from the WKT alone: stale keys in US survey feet (4099 = 9003) beside a WKT in metres made
    transform_las and lidarctl read the heights 3.28x wrong. The WKT is the CRS: its vertical keys are not read. Keys
    whose linear unit is not the WKT's are refused (trial s99 lidmut H6: a WKT edited alone, beside keys that were
    right): which record is stale is not guessed; --crs says it."""
    from aerotri.core.errors import CrsError
    from aerotri.geom.las import geokey_vertical_unit_m
    from lidarctl.io import resolve_crs_units

    plain = tmp_path / "plain.las"
    las = _synthetic_las(plain, n=400)
    stale = _with_stale_keys(plain, tmp_path / "stale.las", [(1024, 1), (3072, 32649), (3076, 9003), (4099, 9003)])
    h = laspy.read(stale).header
    assert h.global_encoding.wkt and "GeoKeyDirectoryVlr" in [type(v).__name__ for v in h.vlrs]
    assert geokey_vertical_unit_m(h) is None
    with pytest.raises(CrsError, match=r"CRS records disagree \(its WKT record \(WGS 84 / UTM zone 49N\) states "
                                       r"metre, its GeoTIFF keys ProjLinearUnitsGeoKey 9003 \(US survey foot\)"):
        resolve_crs_units(stale, h, None)
    assert resolve_crs_units(stale, h, "EPSG:32649")[1].z_m == 1.0
    # keys in the WKT's unit beside it are not read either: the vertical unit is the WKT's
    agree = _with_stale_keys(plain, tmp_path / "agree.las", [(1024, 1), (3072, 32649), (3076, 9001), (4099, 9003)])
    assert resolve_crs_units(agree, laspy.read(agree).header, None)[1].z_m == 1.0
    out = tmp_path / "utm50.las"
    transform_las(stale, out, CrsTransformer(32649, 32650))
    res = laspy.read(out)
    X, Y, Z = pyproj.Transformer.from_crs("EPSG:32649", "EPSG:32650", always_xy=True).transform(
        np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))
    assert np.max(np.abs(res.z - las.z)) <= res.header.scales[2] / 2 + 1e-9
    assert np.max(np.abs(res.x - X)) <= res.header.scales[0] / 2 + 1e-9


def test_a_compound_from_over_a_file_in_feet_keeps_the_xy_resolution(tmp_path):
    """s6-fixes 4: the output's XY scale was the input's scaled by the units of the two CRSs' heights for a compound
    CRS (1 for any): Oregon Lambert in feet (0.01 ft) with --from EPSG:2994+6360 to UTM 10N + NAVD88 came out at
    0.01 m, 3.3x coarser than the 0.003 m the input holds; now 0.001 m, as with a 2D --from."""
    rng = np.random.default_rng(4)
    n = 300
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([635_000.0, 848_000.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(2994))
    las = laspy.LasData(header)
    las.x = rng.uniform(636_000, 638_000, n)
    las.y = rng.uniform(849_000, 851_000, n)
    las.z = rng.uniform(400, 500, n)
    src = tmp_path / "feet.las"
    las.write(src)
    las = laspy.read(src)
    for frm, to in (("EPSG:2994+6360", "EPSG:3740+5703"), ("EPSG:2994", "EPSG:3740")):
        out = tmp_path / f"{frm.replace(':', '').replace('+', '_')}.las"
        transform_las(src, out, CrsTransformer(frm, to))
        res = laspy.read(out)
        assert res.header.scales[0] == res.header.scales[1] == pytest.approx(0.001), (frm, res.header.scales)
        X, Y, Z = pyproj.Transformer.from_crs(pyproj.CRS(frm) if "+" in frm else pyproj.CRS(frm).to_3d(),
                                              pyproj.CRS(to) if "+" in to else pyproj.CRS(to).to_3d(),
                                              always_xy=True).transform(np.asarray(las.x), np.asarray(las.y),
                                                                        np.asarray(las.z))
        assert np.max(np.abs(res.x - X)) <= 0.0005 + 1e-9 and np.max(np.abs(res.y - Y)) <= 0.0005 + 1e-9
