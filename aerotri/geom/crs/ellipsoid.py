"""Reference ellipsoids and the geodetic <-> geocentric (earth-centred, earth-fixed) conversion.

Conventions: latitude ``lat_deg`` and longitude ``lon_deg`` in degrees (east positive), ellipsoidal
height ``h_m`` above the ellipsoid in metres, geocentric ``X_m, Y_m, Z_m`` in metres with Z along the
rotation axis and X through the Greenwich meridian.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class Ellipsoid:
    """An ellipsoid of revolution given by its semi-major axis and inverse flattening."""

    name: str
    a_m: float
    inv_f: float

    @property
    def f(self) -> float:
        return 1.0 / self.inv_f

    @property
    def b_m(self) -> float:
        return self.a_m * (1.0 - self.f)

    @property
    def e2(self) -> float:
        """First eccentricity squared."""
        return self.f * (2.0 - self.f)

    @property
    def n(self) -> float:
        """Third flattening n = (a - b) / (a + b) = f / (2 - f) (Krueger's series parameter)."""
        return self.f / (2.0 - self.f)

    def prime_vertical_radius_m(self, lat_rad):
        """Radius of curvature in the prime vertical, N = a / sqrt(1 - e2 sin^2(lat)), at latitudes in radians."""
        return self.a_m / np.sqrt(1.0 - self.e2 * np.sin(lat_rad) ** 2)

    def meridian_radius_m(self, lat_rad):
        """Radius of curvature in the meridian, M = a (1 - e2) / (1 - e2 sin^2(lat))^1.5, at latitudes in radians."""
        w2 = 1.0 - self.e2 * np.sin(lat_rad) ** 2
        return self.a_m * (1.0 - self.e2) / w2**1.5

    @classmethod
    def from_crs(cls, crs) -> "Ellipsoid":
        """The ellipsoid of a pyproj CRS (any CRS with a geodetic datum)."""
        ell = crs.ellipsoid
        if ell is None:
            raise ValueError(f"{crs.name}: CRS has no ellipsoid")
        return cls(ell.name, float(ell.semi_major_metre), float(ell.inverse_flattening))


# Ellipsoids of the national and global datums that deliverables in China are asked for.
KRASSOVSKY = Ellipsoid("Krassowsky 1940", 6378245.0, 298.3)  # Beijing 1954
IAG75 = Ellipsoid("IAG 1975", 6378140.0, 298.257)  # Xian 1980
CGCS2000 = Ellipsoid("CGCS2000", 6378137.0, 298.257222101)
GRS80 = Ellipsoid("GRS 1980", 6378137.0, 298.257222101)
WGS84 = Ellipsoid("WGS 84", 6378137.0, 298.257223563)

ELLIPSOIDS = {e.name: e for e in (KRASSOVSKY, IAG75, CGCS2000, GRS80, WGS84)}


def geodetic_to_geocentric(lat_deg, lon_deg, h_m, ellipsoid: Ellipsoid):
    """(lat, lon, h) -> (X, Y, Z) in metres; N is the prime-vertical radius of curvature."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(h_m, dtype=float)
    e2 = ellipsoid.e2
    sin_lat = np.sin(lat)
    N = ellipsoid.prime_vertical_radius_m(lat)
    X = (N + h) * np.cos(lat) * np.cos(lon)
    Y = (N + h) * np.cos(lat) * np.sin(lon)
    Z = (N * (1.0 - e2) + h) * sin_lat
    return X, Y, Z


def geocentric_to_geodetic(X_m, Y_m, Z_m, ellipsoid: Ellipsoid):
    """(X, Y, Z) -> (lat_deg, lon_deg, h_m) by Bowring's start and Newton-free fixed-point refinement.

    Three refinements of the latitude give < 1e-12 rad for points within +-10 km of the ellipsoid.
    """
    X = np.asarray(X_m, dtype=float)
    Y = np.asarray(Y_m, dtype=float)
    Z = np.asarray(Z_m, dtype=float)
    a, b, e2 = ellipsoid.a_m, ellipsoid.b_m, ellipsoid.e2
    ep2 = e2 / (1.0 - e2)
    p = np.hypot(X, Y)
    lon = np.arctan2(Y, X)
    theta = np.arctan2(Z * a, p * b)  # Bowring's parametric-latitude start
    lat = np.arctan2(Z + ep2 * b * np.sin(theta) ** 3, p - e2 * a * np.cos(theta) ** 3)
    for _ in range(3):
        N = ellipsoid.prime_vertical_radius_m(lat)
        h = p / np.cos(lat) - N
        lat = np.arctan2(Z, p * (1.0 - e2 * N / (N + h)))
    N = ellipsoid.prime_vertical_radius_m(lat)
    # p/cos(lat) loses precision near the poles; this form is stable everywhere.
    h = p * np.cos(lat) + Z * np.sin(lat) - a * a / N
    return np.degrees(lat), np.degrees(lon), h


def enu_rotation(lat_deg, lon_deg):
    """Rows are the local east, north, up unit vectors in geocentric axes, shape (..., 3, 3)."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(lat)
    east = np.stack([-so, co, zero], axis=-1)
    north = np.stack([-sl * co, -sl * so, cl], axis=-1)
    up = np.stack([cl * co, cl * so, sl], axis=-1)
    return np.stack([east, north, up], axis=-2)


ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0
