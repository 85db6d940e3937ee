"""CrsTransformer: ballpark refusal, parameter chains, zone straddling blocks, normal heights."""

import numpy as np
import pyproj
import pytest

from aerotri.geom.crs.definition import parse_crs
from aerotri.geom.crs.files import fit_common_points
from aerotri.geom.crs.datum import Transformation, outside_extent
from aerotri.geom.crs.gauss_kruger import GaussKruger
from aerotri.geom.crs.heights import fit_height_anomaly
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, simulate_spatial, write_common_points
from aerotri.geom.crs.transform import BallparkRefused, CrsTransformer, transform_points
from aerotri.core.errors import InputError


@pytest.mark.parametrize("src,dst", [(32649, 2361), (4326, 4610), (4326, 4490), (4610, 4490)])
def test_ballpark_datum_shift_is_refused_unless_accepted(src, dst):
    with pytest.raises(BallparkRefused, match="common points") as exc:
        CrsTransformer(src, dst)
    assert "--allow-ballpark" in str(exc.value) and "no rigorous transformation" in str(exc.value)
    t = CrsTransformer(src, dst, allow_ballpark=True)
    assert t.ballpark and any("BALLPARK" in w for w in t.warnings)


def test_rigorous_operations_are_not_refused():
    # same datum (zone change, unprojection) and a datum pair PROJ has parameters for
    for src, dst in [(2360, 2361), (4610, 2382), (4326, 32649), (4490, 4525), (4214, 4326)]:
        assert not CrsTransformer(src, dst).ballpark
    with pytest.raises(InputError, match="unknown CRS"):
        CrsTransformer(999999, 4326)


def _straddling_block(n, seed):
    """Xian 1980 geographic points over 109.2..109.8 E: the 3-degree zone 36/37 boundary is 109.5 E."""
    rng = np.random.default_rng(seed)
    return rng.uniform(109.2, 109.8, n), rng.uniform(34.0, 34.4, n), rng.uniform(400, 900, n)


def test_block_straddling_zones_36_37_lands_consistently_in_one_zone():
    lon, lat, h = _straddling_block(400, 1)
    gk37 = GaussKruger.from_crs(parse_crs(2361))
    gk36 = GaussKruger.from_crs(parse_crs(2360))
    truth_E, truth_N = gk37.forward(lat, lon)
    # sheets delivered in their own zone: west of 109.5 in zone 36, east in zone 37
    west = lon < 109.5
    E36, N36 = gk36.forward(lat[west], lon[west])
    X, Y, Z = CrsTransformer(2360, 2361).transform(E36, N36, h[west])
    assert np.max(np.hypot(X - truth_E[west], Y - truth_N[west])) < 1e-3
    assert np.all(np.floor(X / 1e6) == 37) and np.allclose(Z, h[west])
    # the same zone change with the own implementation agrees with PROJ
    Xo, Yo = gk37.forward(*gk36.inverse(E36, N36))
    assert np.max(np.hypot(Xo - X, Yo - Y)) < 1e-3
    # a point measured on both sheets (overlap strip) maps to one position in zone 37
    both = np.abs(lon - 109.5) < 0.05
    E36b, N36b = gk36.forward(lat[both], lon[both])
    E37b, N37b = gk37.forward(lat[both], lon[both])
    Xb, Yb, _ = CrsTransformer(2360, 2361).transform(E36b, N36b)
    assert np.max(np.hypot(Xb - E37b, Yb - N37b)) < 1e-3


def test_fitted_parameters_transform_a_straddling_block_into_one_chosen_zone(tmp_path):
    """WGS 84 UTM 49N -> Xian 1980: bursa-wolf7 fitted on common points spread over the block, applied
    to check points on both sides of 109.5 E and output in zone 37 and, alternatively, in zone 36."""
    lon, lat, h = _straddling_block(16, 2)
    noise = 0.01
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon_deg=lon, lat_deg=lat, h_m=h, noise_m=noise,
                                   seed=3)
    path = tmp_path / "cp.csv"
    write_common_points(path, [f"C{i}" for i in range(16)], src, dst)
    params = fit_common_points(path, "bursa-wolf7", 32649, 2361).transformation
    lon_c, lat_c, h_c = _straddling_block(300, 4)
    for zone_epsg in (2361, 2360):
        src_c, _, truth = simulate_spatial(TRUE_BURSA_WOLF7, 32649, zone_epsg, lon_deg=lon_c, lat_deg=lat_c, h_m=h_c)
        t = CrsTransformer(32649, zone_epsg, params=params)
        X, Y, Z = t.transform(src_c[:, 0], src_c[:, 1], src_c[:, 2])
        err = np.hypot(X - truth[:, 0], Y - truth[:, 1])
        # 16 points with 1 cm noise: the expected horizontal prediction error is ~0.55 cm RMS (this
        # realisation is a 1.1 cm one); far from the decimetres to metres of a wrong zone or datum
        assert np.sqrt(np.mean(err**2)) < 2 * noise and err.max() < 4 * noise
        assert np.max(np.abs(Z - truth[:, 2])) < 4 * noise
        assert np.all(np.floor(X / 1e6) == zone_epsg - 2361 + 37)
        # check points beyond the common points' extent (+10 %) are counted as extrapolated
        assert t.n_outside_fit_extent == outside_extent(params.fit_extent, src_c[:, :2]).sum() > 0
    # the same points given in geographic WGS 84 instead of UTM give the same result
    t_geo = CrsTransformer(4326, 2361, params=params)
    Xg, Yg, _ = t_geo.transform(lon_c, lat_c, h_c)
    src_c, _, _ = simulate_spatial(TRUE_BURSA_WOLF7, 32649, 2361, lon_deg=lon_c, lat_deg=lat_c, h_m=h_c)
    X, Y, _ = CrsTransformer(32649, 2361, params=params).transform(*src_c.T)
    assert np.max(np.hypot(Xg - X, Yg - Y)) < 1e-6


def test_plane_parameters_and_heights_in_the_chain():
    # a 4-parameter set from the CGCS2000 CM 111E grid to the Xian 1980 zone-37 grid
    T = Transformation("helmert2d", {"tx_m": 37_000_012.5, "ty_m": -35.2, "scale_ppm": 3.1, "rotation_arcsec": 0.8},
                       "EPSG:4546", "EPSG:2361",
                       fit_extent={"xmin_m": 420_000.0, "ymin_m": 3_760_000.0, "xmax_m": 480_000.0, "ymax_m": 3_820_000.0})
    rng = np.random.default_rng(5)
    E = rng.uniform(430_000, 470_000, 50)
    N = rng.uniform(3_770_000, 3_810_000, 50)
    h = rng.uniform(300, 800, 50)
    # height anomaly model on the target grid: zeta = -30 m + 2 cm/km east
    hx = rng.uniform(37_420_000, 37_480_000, 20)
    hy = rng.uniform(3_760_000, 3_820_000, 20)
    zeta = -30.0 + 0.02 * (hx - 37_450_000) / 1000
    hm = fit_height_anomaly(range(20), hx, hy, np.full(20, 500.0), 500.0 - zeta, model="plane", crs="EPSG:2361").model
    t = CrsTransformer(4546, 2361, params=T, heights=hm)
    X, Y, Z = t.transform(E, N, h)
    ref = T.apply(np.column_stack([E, N]))
    assert np.max(np.abs(np.column_stack([X, Y]) - ref)) < 1e-6
    assert np.max(np.abs(Z - (h - (-30.0 + 0.02 * (X - 37_450_000) / 1000)))) < 1e-6
    # a geographic CGCS2000 input reaches the same grid through a conversion first
    lon, lat = pyproj.Transformer.from_crs(4546, 4490, always_xy=True).transform(E, N)
    Xg, Yg, _ = transform_points(lon, lat, h, from_crs=4490, to_crs=2361, params=T)
    assert np.max(np.hypot(Xg - X, Yg - Y)) < 1e-6
    # points far outside the common points' area are counted and reported
    t.transform(np.array([600_000.0]), np.array([3_790_000.0]), np.array([0.0]))
    assert t.n_outside_fit_extent == 1 and any("outside the area" in w for w in t.warnings)
    # plane models need metre grids
    bad = Transformation("helmert2d", T.parameters, "EPSG:4490", "EPSG:2361")
    with pytest.raises(InputError, match="metre grid"):
        CrsTransformer(4490, 2361, params=bad)


def test_crs_label_describes_an_unnamed_crs():
    """A CRS written as a PROJ string (the NGI data's "Lo25"), or its WKT, is labelled by its projection,
    parameters and datum in messages and the ortho summary, not by PROJ's "unknown"; EPSG codes and named
    CRSs keep their labels."""
    from aerotri.geom.crs.definition import crs_label, parse_crs

    lo25 = "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs +type=crs"
    want = "Transverse Mercator (Longitude of natural origin 25, Scale factor at natural origin 1), World Geodetic System 1984"
    assert crs_label(parse_crs(lo25)) == want
    assert crs_label(parse_crs(parse_crs(lo25).to_wkt())) == want
    assert crs_label(parse_crs("EPSG:32649")) == "EPSG:32649"
    assert crs_label(parse_crs(parse_crs(lo25).to_wkt().replace('"unknown"', '"Lo25"', 1))) == "Lo25"


@pytest.mark.parametrize("lon_deg, lat_deg, label", [
    (-180.0, 10.0, "EPSG:32601"), (180.0, -10.0, "EPSG:32701"), (179.99, 10.0, "EPSG:32660"),
    (181.0, 10.0, "EPSG:32601"), (3.0, 52.0, "EPSG:32631"), (117.0, 30.0, "EPSG:32650"), (-123.0, 44.0, "EPSG:32610")])
def test_utm_zone_label_wraps_at_the_antimeridian(lon_deg, lat_deg, label):
    """Review 16: 180 deg E gave "EPSG:32661" / "EPSG:32761" (UPS North / South), not a UTM zone."""
    from aerotri.geom.crs.definition import utm_zone_label

    assert utm_zone_label(lon_deg, lat_deg) == label
    # the label's zone holds the longitude (PROJ's own area of use)
    area = pyproj.CRS(label).area_of_use
    lon = (lon_deg + 180.0) % 360.0 - 180.0
    assert area.west - 1e-9 <= lon <= area.east + 1e-9


def test_h_datums_of_igs_frames_and_wkt1_names_are_compared_without_a_crash():
    """Review 17: pyproj's TransformerGroup raises IndexError for IGS14 / IGb14 / SIRGAS pairs, which came out as a
    traceback (exit 1); a WKT1 WGS 84 ("World Geodetic System 1984", EPSG datum 6326) was compared by name with
    the ensemble, refused after 17 s. Now: nothing known -> not the same (a clean refusal); the same EPSG datum
    code -> the same datum."""
    from aerotri.geom.crs.transform import compare_h_datums

    utm50 = pyproj.CRS.from_epsg(32650)
    for code in (9018, 9379):  # IGS14, IGb14 (geographic 3D)
        got = compare_h_datums(pyproj.CRS.from_epsg(code), utm50, 111.0, 30.0)
        assert isinstance(got.same, bool)
    wkt1 = pyproj.CRS(utm50.to_wkt("WKT1_GDAL"))
    got = compare_h_datums(pyproj.CRS.from_epsg(4326), wkt1, 111.0, 30.0)
    assert got.same and got.exact


def test_a_frame_pair_pyproj_cannot_list_is_a_clean_crs_error():
    """Review 17: SIRGAS 2000 -> ITRF2014 raised pyproj's IndexError (a traceback); now a CrsError (exit 2)."""
    from aerotri.core.errors import CrsError

    with pytest.raises(CrsError, match="PROJ cannot list the operations"):
        CrsTransformer(pyproj.CRS.from_epsg(31983), pyproj.CRS.from_epsg(7912))
