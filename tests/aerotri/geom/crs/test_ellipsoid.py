"""Radii of curvature of ``Ellipsoid`` (the one copy the geocentric conversion, Gauss-Krueger's point scale
factor and the synthetic common points use) against closed forms and against the geometry they describe."""

import numpy as np
import pytest

from aerotri.geom.crs.ellipsoid import CGCS2000, IAG75, KRASSOVSKY, WGS84, enu_rotation, geodetic_to_geocentric

ELLIPSOIDS = [WGS84, CGCS2000, IAG75, KRASSOVSKY]


@pytest.mark.parametrize("ell", ELLIPSOIDS, ids=lambda e: e.name)
def test_radii_at_equator_and_pole(ell):
    assert ell.prime_vertical_radius_m(0.0) == pytest.approx(ell.a_m, rel=1e-15)
    assert ell.meridian_radius_m(0.0) == pytest.approx(ell.b_m**2 / ell.a_m, rel=1e-12)  # a (1 - e2) = b^2 / a
    polar = ell.a_m**2 / ell.b_m
    assert ell.prime_vertical_radius_m(np.pi / 2) == pytest.approx(polar, rel=1e-12)
    assert ell.meridian_radius_m(np.pi / 2) == pytest.approx(polar, rel=1e-12)


@pytest.mark.parametrize("ell", ELLIPSOIDS, ids=lambda e: e.name)
def test_radii_describe_the_ellipsoid(ell):
    lat_deg = np.array([-60.0, -12.5, 0.0, 23.4, 34.2, 51.0, 78.0])
    lat = np.radians(lat_deg)
    # N: the point on the ellipsoid at longitude 0 lies N cos(lat) from the axis (the same numbers as the
    # geocentric conversion computes)
    X, _, Z = geodetic_to_geocentric(lat_deg, np.zeros_like(lat_deg), np.zeros_like(lat_deg), ell)
    N = ell.prime_vertical_radius_m(lat)
    np.testing.assert_array_equal(X, N * np.cos(lat) * np.cos(0.0))
    np.testing.assert_allclose(Z, N * (1.0 - ell.e2) * np.sin(lat), rtol=1e-15, atol=1e-9)
    # M: the meridian arc's length per radian of latitude (chord over a 1e-5 rad step, centred)
    d = 1e-5
    X0, _, Z0 = geodetic_to_geocentric(np.degrees(lat - d / 2), 0.0 * lat, 0.0 * lat, ell)
    X1, _, Z1 = geodetic_to_geocentric(np.degrees(lat + d / 2), 0.0 * lat, 0.0 * lat, ell)
    np.testing.assert_allclose(np.hypot(X1 - X0, Z1 - Z0) / d, ell.meridian_radius_m(lat), rtol=1e-9)


def test_enu_rotation_rows_are_the_directions_of_east_north_up():
    """The one ENU rotation (``LocalFrame``, OpenSfM's topocentric frame, the datum fit's residual axes): its rows
    are the directions in which a point moves for a step in longitude, latitude and ellipsoidal height."""
    lat = np.array([-45.0, 0.0, 31.7, 52.3, 70.0])
    lon = np.array([-120.0, 0.0, 109.5, 4.9, 25.0])
    h = np.full(lat.shape, 350.0)
    R = enu_rotation(lat, lon)
    p0 = np.stack(geodetic_to_geocentric(lat, lon, h, WGS84), axis=-1)
    d = 1e-6
    for row, (dlat, dlon, dh) in enumerate([(0, d, 0), (d, 0, 0), (0, 0, 1.0)]):
        step = np.stack(geodetic_to_geocentric(lat + dlat, lon + dlon, h + dh, WGS84), axis=-1) - p0
        np.testing.assert_allclose(R[:, row, :], step / np.linalg.norm(step, axis=1)[:, None], atol=1e-6)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-15)
