"""CRSs whose geographic CRS counts longitudes from another prime meridian or in other units (NTF (Paris): grads
from Paris; MGI (Ferro): degrees from Ferro) are compared with their areas of use (Greenwich degrees) in Greenwich
degrees: Paris in the French Lambert II and Innsbruck in the Austrian Ferro zones were refused as outside their own
areas (review 36)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from aerotri.core.errors import InputError
from aerotri.geom.crs.definition import check_coordinates
from aerotri.geom.crs.transform import from_own_geodetic, to_own_geodetic


@pytest.mark.parametrize("code, lon, lat", [(27572, 2.35, 48.85), (31251, 11.39, 47.26), (31281, 11.39, 47.26),
                                            (2154, 2.35, 48.85)])
def test_points_in_their_own_area_pass_and_read_in_greenwich_degrees(code, lon, lat):
    crs = pyproj.CRS.from_epsg(code)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)  # datum shift: metres
    for mode in ("refuse", "warn"):
        assert check_coordinates(crs, np.array([x]), np.array([y]), "points.csv", outside_area=mode) is None
    lon_deg, lat_deg, h = to_own_geodetic(crs, np.array([x]), np.array([y]), np.array([0.0]))
    assert lon_deg[0] == pytest.approx(lon, abs=0.01) and lat_deg[0] == pytest.approx(lat, abs=0.01)
    back = from_own_geodetic(crs, lon_deg, lat_deg, h)
    assert back[0][0] == pytest.approx(x, abs=1e-6) and back[1][0] == pytest.approx(y, abs=1e-6)


def test_a_paris_lambert_point_elsewhere_is_still_refused():
    crs = pyproj.CRS.from_epsg(27572)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(16.0, 48.2)  # Vienna: 8 deg east
    with pytest.raises(InputError, match="outside the area of use of EPSG:27572"):
        check_coordinates(crs, np.array([x]), np.array([y]), "points.csv")


def test_a_custom_grid_without_an_area_refuses_what_it_cannot_hold():
    """A user's own transverse Mercator (no area of use) took a zone-prefixed easting 39,500,000 m (39,000 km east of
    its central meridian) without a word (review 36); its own points pass."""
    crs = pyproj.CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=117 +k=1 +x_0=500000 +y_0=0 +ellps=GRS80 +units=m")
    assert crs.area_of_use is None
    assert check_coordinates(crs, np.array([512_345.0]), np.array([3_400_000.0]), "points.csv") is None
    with pytest.raises(InputError, match="cannot be a point of"):
        check_coordinates(crs, np.array([39_512_345.0]), np.array([3_400_000.0]), "points.csv")


def test_geographic_points_of_ntf_paris_in_grads_pass_in_france():
    """NTF (Paris) geographic (EPSG:4807) counts grads from Paris: Paris itself is (0, 54.2731) there."""
    crs = pyproj.CRS.from_epsg(4807)
    lon_g, lat_g = pyproj.Transformer.from_crs(27572, 4807, always_xy=True).transform(600000.0, 2428000.0)
    assert abs(lon_g) < 0.1 and 54.0 < lat_g < 54.5
    assert check_coordinates(crs, np.array([lon_g]), np.array([lat_g]), "points.csv") is None


def test_a_fitted_7_parameter_set_moves_ntf_paris_lambert_points_where_proj_does(tmp_path):
    """Review 38: the 7-parameter path fed PROJ's grads from Paris to the geocentric conversion as degrees from
    Greenwich: points fitted to 0.7 mm came out 612 km off, exit 0."""
    from click.testing import CliRunner

    from aerotri.crs.cli import crs as crs_cli

    rng = np.random.default_rng(1)
    lon, lat, h = 2.3 + rng.uniform(-0.4, 0.4, 10), 48.8 + rng.uniform(-0.4, 0.4, 10), rng.uniform(50, 150, 10)
    x2, y2 = pyproj.Transformer.from_crs("EPSG:4171", "EPSG:2154", always_xy=True).transform(lon, lat)
    x1, y1 = pyproj.Transformer.from_crs("EPSG:4171", "EPSG:27572", always_xy=True).transform(lon, lat)
    (tmp_path / "common.csv").write_text("id,x_from,y_from,z_from,x_to,y_to,z_to\n" + "".join(
        f"p{i},{x1[i]:.3f},{y1[i]:.3f},{h[i]:.3f},{x2[i]:.3f},{y2[i]:.3f},{h[i]:.3f}\n" for i in range(10)))
    (tmp_path / "pts.csv").write_text("id,x,y,z\n" + "".join(f"p{i},{x1[i]:.3f},{y1[i]:.3f},{h[i]:.3f}\n"
                                                             for i in range(10)))
    r = CliRunner().invoke(crs_cli, ["fit", str(tmp_path / "common.csv"), "--model", "bursa-wolf7", "--from",
                                     "EPSG:27572", "--to", "EPSG:2154", "-o", str(tmp_path / "p.json")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(crs_cli, ["transform", str(tmp_path / "pts.csv"), str(tmp_path / "out.csv"), "--from",
                                     "EPSG:27572", "--to", "EPSG:2154", "--params", str(tmp_path / "p.json")])
    assert r.exit_code == 0, r.output
    out = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert np.allclose(out["x"], x2, atol=0.01) and np.allclose(out["y"], y2, atol=0.01)


def test_the_scale_factor_of_a_ferro_grid_counts_from_its_own_meridian():
    """Review 38: MGI (Ferro) / Austria GK East at Vienna read 1.0211 (21 mm per metre) for 1.0000001."""
    from aerotri.geom.crs.definition import point_scale_factor

    assert point_scale_factor(pyproj.CRS.from_epsg(31253), 16.37, 48.21) == pytest.approx(1.0, abs=1e-6)


def test_a_refusal_names_the_crs_own_axis_directions():
    """Trial-ngi: South Africa's Lo25 (EPSG:2051) is westing, southing; the refusal of a point outside its area said
    'x = easting, y = northing'."""
    crs = pyproj.CRS("EPSG:2051")
    with pytest.raises(InputError, match="in x = westing, y = southing order"):
        check_coordinates(crs, np.array([-55094.5]), np.array([-3727407.0]), "gnss.txt", ["line 1"])
    with pytest.raises(InputError, match="in x = easting, y = northing order"):
        check_coordinates(pyproj.CRS("EPSG:32650"), np.array([5.0e7]), np.array([3.0e6]), "gnss.txt", ["line 1"])


def test_latitude_first_is_named_as_such():
    """Trial-cn / trial-kite: (30.533, 114.954) given for EPSG:4326 read "metres given for a geographic CRS?"; a pair
    that swapped is a longitude and latitude says latitude first; a pair that is neither says metres."""
    with pytest.raises(InputError, match=r"latitude first\? give longitude first"):
        check_coordinates(pyproj.CRS("EPSG:4326"), np.array([30.533]), np.array([114.954]), "ll.csv", ["line 2"])
    with pytest.raises(InputError, match="metres given for a geographic CRS"):
        check_coordinates(pyproj.CRS("EPSG:4326"), np.array([591446.0]), np.array([3379630.0]), "ll.csv", ["line 2"])
