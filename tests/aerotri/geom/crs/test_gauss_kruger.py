"""Own Gauss-Krueger implementation against pyproj (PROJ), round trips, zone helpers, EPSG codes."""

import numpy as np
import pyproj
import pytest

from aerotri.geom.crs.ellipsoid import (
    CGCS2000,
    IAG75,
    KRASSOVSKY,
    Ellipsoid,
    geocentric_to_geodetic,
    geodetic_to_geocentric,
)
from aerotri.geom.crs.gauss_kruger import (
    GaussKruger,
    central_meridian_deg,
    false_easting_m,
    gauss_kruger_zone,
    gk_epsg,
    zone_3deg,
    zone_6deg,
    zone_for_block,
    zone_from_easting,
)

# zone-prefixed 3-degree (2360, 2361, 4525), CM-named 3-degree (2382, 4546), 6-degree (2333, 4497),
# Beijing 1954 (Krassovsky) 3-degree zone 37 (2413)
CODES = [2360, 2361, 2382, 4525, 4546, 2333, 4497, 2413]


def _sample(gk, n, half_width_deg, seed):
    rng = np.random.default_rng(seed)
    lat = rng.uniform(18.0, 53.0, n)
    lon = gk.central_meridian_deg + rng.uniform(-half_width_deg, half_width_deg, n)
    return lat, lon


@pytest.mark.parametrize("code", CODES)
def test_forward_inverse_agree_with_pyproj_to_1mm(code):
    crs = pyproj.CRS.from_epsg(code)
    gk = GaussKruger.from_crs(crs)
    width = 6 if "3-degree" not in crs.name else 3
    # the whole zone plus 1 degree of overlap on each side
    lat, lon = _sample(gk, 5000, width / 2 + 1.0, seed=code)
    to_grid = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
    E_ref, N_ref = to_grid.transform(lon, lat)
    E, N = gk.forward(lat, lon)
    assert np.max(np.hypot(E - E_ref, N - N_ref)) < 1e-3
    lat_ref, lon_ref = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform(E_ref, N_ref)[::-1]
    lat2, lon2 = gk.inverse(E_ref, N_ref)
    # 1 mm is about 9e-9 degrees of latitude
    assert np.max(np.abs(lat2 - lat_ref)) < 9e-9
    assert np.max(np.abs((lon2 - lon_ref) * np.cos(np.radians(lat_ref)))) < 9e-9
    # round trip grid -> geographic -> grid
    E2, N2 = gk.forward(*gk.inverse(E, N))
    assert np.max(np.hypot(E2 - E, N2 - N)) < 1e-3


def test_from_crs_reads_zone_prefix_and_cm_grids():
    z37 = GaussKruger.from_crs(pyproj.CRS.from_epsg(2361))
    cm111 = GaussKruger.from_crs(pyproj.CRS.from_epsg(2382))
    assert z37.central_meridian_deg == cm111.central_meridian_deg == 111.0
    assert z37.false_easting_m == 37_500_000.0 and cm111.false_easting_m == 500_000.0
    assert z37.ellipsoid.a_m == IAG75.a_m and z37.ellipsoid.inv_f == pytest.approx(IAG75.inv_f)
    E37, N37 = z37.forward(34.2, 110.3)
    E, N = cm111.forward(34.2, 110.3)
    assert E37 - E == pytest.approx(37_000_000.0, abs=1e-6) and N37 == pytest.approx(N, abs=1e-9)
    assert zone_from_easting(E37) == 37
    with pytest.raises(ValueError):
        GaussKruger.from_crs(pyproj.CRS.from_epsg(4326))


def test_zone_helpers():
    assert list(zone_3deg([109.4, 109.6, 111.0, 112.49])) == [36, 37, 37, 37]
    assert list(zone_6deg([107.9, 108.1, 113.9])) == [18, 19, 19]
    assert central_meridian_deg(37, 3) == 111.0 and central_meridian_deg(19, 6) == 111.0
    assert false_easting_m(37, prefixed=True) == 37_500_000.0
    assert false_easting_m(37, prefixed=False) == 500_000.0
    zone, max_off = zone_for_block([109.2, 109.9])
    assert zone == 37 and max_off == pytest.approx(1.8)
    gk = gauss_kruger_zone(KRASSOVSKY, 19, width_deg=6)
    assert gk.central_meridian_deg == 111.0 and gk.false_easting_m == 19_500_000.0
    with pytest.raises(ValueError):
        central_meridian_deg(10, 4)


def test_gk_epsg_codes_match_pyproj_names():
    for datum, zone, width, prefixed, code in [
        ("Xian 1980", 36, 3, True, 2360),
        ("Xian 1980", 37, 3, True, 2361),
        ("Xian 1980", 37, 3, False, 2382),
        ("CGCS2000", 37, 3, True, 4525),
        ("CGCS2000", 37, 3, False, 4546),
        ("CGCS2000", 19, 6, True, 4497),
    ]:
        assert gk_epsg(datum, zone, width, prefixed) == code
        crs = pyproj.CRS.from_epsg(code)
        gk = GaussKruger.from_crs(crs)
        assert gk.central_meridian_deg == central_meridian_deg(zone, width)
        assert gk.false_easting_m == false_easting_m(zone, prefixed)
    with pytest.raises(KeyError):
        gk_epsg("Xian 1980", 99)


def test_point_scale_factor_grows_off_the_central_meridian():
    gk = gauss_kruger_zone(CGCS2000, 37)
    k = gk.point_scale_factor([34.0, 34.0], [111.0, 112.5])
    assert k[0] == pytest.approx(1.0, abs=1e-9)
    # k ~ 1 + y^2 / (2 R^2) = 1.000234 with y ~ 138 km; PROJ's analytic factor for the same grid
    ref = pyproj.Proj(pyproj.CRS.from_epsg(4525)).get_factors(112.5, 34.0).meridional_scale
    assert k[1] == pytest.approx(ref, abs=1e-8)
    assert k[1] == pytest.approx(1.000234, abs=5e-6)


def test_geocentric_round_trip_and_pyproj():
    rng = np.random.default_rng(3)
    lat, lon, h = rng.uniform(-89, 89, 1000), rng.uniform(-180, 180, 1000), rng.uniform(-500, 9000, 1000)
    X, Y, Z = geodetic_to_geocentric(lat, lon, h, CGCS2000)
    ref = pyproj.Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, h)
    wgs = Ellipsoid("WGS 84", 6378137.0, 298.257223563)
    Xw, Yw, Zw = geodetic_to_geocentric(lat, lon, h, wgs)
    assert np.max(np.abs(np.array([Xw, Yw, Zw]) - np.array(ref))) < 1e-6
    lat2, lon2, h2 = geocentric_to_geodetic(X, Y, Z, CGCS2000)
    assert np.max(np.abs(lat2 - lat)) < 1e-10 and np.max(np.abs(h2 - h)) < 1e-5
