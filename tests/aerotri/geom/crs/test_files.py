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
