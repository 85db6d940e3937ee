"""Gauss-Krueger (transverse Mercator) projection and the Chinese 3-/6-degree zone system.

The projection uses Krueger's series in the third flattening n to order n^6 (Krueger 1912, in the
form of Karney 2011, "Transverse Mercator with an accuracy of a few nanometers"): it is exact to
well below a millimetre across a 6-degree zone and far beyond, unlike the classical textbook series
in powers of the longitude difference l, which degrade quickly past 3 degrees from the central
meridian.

Axis convention: functions take and return ``easting_m`` (the textbook's y) and ``northing_m`` (the
textbook's x), in that order, like pyproj with ``always_xy=True``. The northing origin is the equator
(false northing 0 in all Chinese grids), the scale factor on the central meridian is 1.

Zones: a 6-degree zone n spans [6(n-1), 6n) degrees east with central meridian 6n - 3; a 3-degree
zone n is centred on 3n and spans [3n - 1.5, 3n + 1.5). Grids come in two flavours: zone-prefixed
false easting (n * 1 000 000 + 500 000 m, e.g. Xian 1980 zone 37 = EPSG:2361) and "CM" grids with a
plain 500 000 m false easting (e.g. EPSG:2382, Xian 1980 3-degree CM 111E).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re

import numpy as np

from aerotri.geom.crs.ellipsoid import Ellipsoid


def _krueger_coefficients(n: float):
    """alpha (forward) and beta (inverse) coefficients of Krueger's series, order n^6."""
    n2, n3, n4, n5, n6 = n**2, n**3, n**4, n**5, n**6
    alpha = (
        n / 2 - 2 * n2 / 3 + 5 * n3 / 16 + 41 * n4 / 180 - 127 * n5 / 288 + 7891 * n6 / 37800,
        13 * n2 / 48 - 3 * n3 / 5 + 557 * n4 / 1440 + 281 * n5 / 630 - 1983433 * n6 / 1935360,
        61 * n3 / 240 - 103 * n4 / 140 + 15061 * n5 / 26880 + 167603 * n6 / 181440,
        49561 * n4 / 161280 - 179 * n5 / 168 + 6601661 * n6 / 7257600,
        34729 * n5 / 80640 - 3418889 * n6 / 1995840,
        212378941 * n6 / 319334400,
    )
    beta = (
        n / 2 - 2 * n2 / 3 + 37 * n3 / 96 - n4 / 360 - 81 * n5 / 512 + 96199 * n6 / 604800,
        n2 / 48 + n3 / 15 - 437 * n4 / 1440 + 46 * n5 / 105 - 1118711 * n6 / 3870720,
        17 * n3 / 480 - 37 * n4 / 840 - 209 * n5 / 4480 + 5569 * n6 / 90720,
        4397 * n4 / 161280 - 11 * n5 / 504 - 830251 * n6 / 7257600,
        4583 * n5 / 161280 - 108847 * n6 / 3991680,
        20648693 * n6 / 638668800,
    )
    return np.array(alpha), np.array(beta)


@dataclasses.dataclass(frozen=True)
class GaussKruger:
    """A transverse Mercator grid: ellipsoid, central meridian, false easting/northing, scale k0."""

    ellipsoid: Ellipsoid
    central_meridian_deg: float
    false_easting_m: float = 500000.0
    false_northing_m: float = 0.0
    k0: float = 1.0

    @functools.cached_property
    def _series(self):
        n = self.ellipsoid.n
        # Rectifying radius A: the meridian arc from equator to pole is A * pi / 2.
        A = self.ellipsoid.a_m / (1 + n) * (1 + n**2 / 4 + n**4 / 64 + n**6 / 256)
        alpha, beta = _krueger_coefficients(n)
        return A, alpha, beta, math.sqrt(self.ellipsoid.e2)

    def forward(self, lat_deg, lon_deg):
        """Geodetic latitude/longitude (degrees) -> (easting_m, northing_m)."""
        A, alpha, _, e = self._series
        lat = np.radians(np.asarray(lat_deg, dtype=float))
        dlon = np.radians(np.asarray(lon_deg, dtype=float) - self.central_meridian_deg)
        # Conformal latitude as tan(chi) = sinh(psi), psi the isometric latitude.
        sin_lat = np.sin(lat)
        tau_c = np.sinh(np.arctanh(sin_lat) - e * np.arctanh(e * sin_lat))
        xi_p = np.arctan2(tau_c, np.cos(dlon))
        eta_p = np.arcsinh(np.sin(dlon) / np.hypot(tau_c, np.cos(dlon)))
        j2 = 2.0 * np.arange(1, 7)
        xi = xi_p + np.sum(alpha * np.sin(j2 * xi_p[..., None]) * np.cosh(j2 * eta_p[..., None]), axis=-1)
        eta = eta_p + np.sum(alpha * np.cos(j2 * xi_p[..., None]) * np.sinh(j2 * eta_p[..., None]), axis=-1)
        easting = self.false_easting_m + self.k0 * A * eta
        northing = self.false_northing_m + self.k0 * A * xi
        return easting, northing

    def inverse(self, easting_m, northing_m):
        """(easting_m, northing_m) -> geodetic (lat_deg, lon_deg)."""
        A, _, beta, e = self._series
        xi = (np.asarray(northing_m, dtype=float) - self.false_northing_m) / (self.k0 * A)
        eta = (np.asarray(easting_m, dtype=float) - self.false_easting_m) / (self.k0 * A)
        j2 = 2.0 * np.arange(1, 7)
        xi_p = xi - np.sum(beta * np.sin(j2 * xi[..., None]) * np.cosh(j2 * eta[..., None]), axis=-1)
        eta_p = eta - np.sum(beta * np.cos(j2 * xi[..., None]) * np.sinh(j2 * eta[..., None]), axis=-1)
        tau_c = np.sin(xi_p) / np.hypot(np.sinh(eta_p), np.cos(xi_p))
        dlon = np.arctan2(np.sinh(eta_p), np.cos(xi_p))
        tau = _conformal_to_geodetic_tan(tau_c, e)
        return np.degrees(np.arctan(tau)), self.central_meridian_deg + np.degrees(dlon)

    def point_scale_factor(self, lat_deg, lon_deg, step_m: float = 1.0):
        """Point scale factor k (grid distance / ellipsoidal distance), by a small east-west step."""
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        N = self.ellipsoid.prime_vertical_radius_m(np.radians(lat))
        dlon_deg = np.degrees(step_m / (N * np.cos(np.radians(lat))))
        e0, n0 = self.forward(lat, lon - dlon_deg / 2)
        e1, n1 = self.forward(lat, lon + dlon_deg / 2)
        return np.hypot(e1 - e0, n1 - n0) / step_m  # conformal: the same in every direction

    @classmethod
    def from_crs(cls, crs) -> "GaussKruger":
        """Build from a pyproj projected CRS using the Transverse Mercator method, in metres."""
        if not crs.is_projected or crs.coordinate_operation is None:
            raise ValueError(f"{crs.name}: not a projected CRS")
        op = crs.coordinate_operation
        if "transverse mercator" not in op.method_name.lower():
            raise ValueError(f"{crs.name}: projection method is {op.method_name}, not Transverse Mercator")
        unit = crs.axis_info[0].unit_conversion_factor
        if abs(unit - 1.0) > 1e-12:
            raise ValueError(f"{crs.name}: grid unit is not the metre")
        p = {param.name.lower(): param.value for param in op.params}
        gk = cls(
            Ellipsoid.from_crs(crs),
            central_meridian_deg=float(p["longitude of natural origin"]),
            false_easting_m=float(p["false easting"]),
            false_northing_m=float(p["false northing"]),
            k0=float(p["scale factor at natural origin"]),
        )
        lat0 = float(p.get("latitude of natural origin", 0.0))
        if lat0 != 0.0:  # northing origin on the parallel lat0 instead of the equator
            _, n0 = gk.forward(lat0, gk.central_meridian_deg)
            gk = dataclasses.replace(gk, false_northing_m=2 * gk.false_northing_m - float(n0))
        return gk


def _conformal_to_geodetic_tan(tau_c, e: float, iterations: int = 5):
    """tan(geodetic latitude) from tan(conformal latitude), Newton's method (Karney 2011, eq. 19-21)."""
    e2m = 1.0 - e * e
    tau = tau_c / e2m
    for _ in range(iterations):
        sigma = np.sinh(e * np.arctanh(e * tau / np.hypot(1.0, tau)))
        tau_c_i = tau * np.hypot(1.0, sigma) - sigma * np.hypot(1.0, tau)
        dtau = (tau_c - tau_c_i) / np.hypot(1.0, tau_c_i) * (1.0 + e2m * tau * tau) / (e2m * np.hypot(1.0, tau))
        tau = tau + dtau
    return tau


# ----------------------------------------------------------------------------------------------
# Zone helpers
# ----------------------------------------------------------------------------------------------


def zone_6deg(lon_deg):
    """6-degree zone number n = floor(L / 6) + 1 for longitudes east of Greenwich."""
    return np.floor(np.asarray(lon_deg, dtype=float) / 6.0).astype(int) + 1


def zone_3deg(lon_deg):
    """3-degree zone number n = floor((L - 1.5) / 3) + 1, i.e. the nearest multiple of 3 degrees."""
    return np.floor((np.asarray(lon_deg, dtype=float) - 1.5) / 3.0).astype(int) + 1


def central_meridian_deg(zone, width_deg: int):
    """Central meridian of a zone: 6n - 3 for 6-degree zones, 3n for 3-degree zones."""
    zone = np.asarray(zone)
    if width_deg == 6:
        return 6.0 * zone - 3.0
    if width_deg == 3:
        return 3.0 * zone
    raise ValueError(f"zone width must be 3 or 6 degrees, not {width_deg}")


def false_easting_m(zone: int, prefixed: bool) -> float:
    """Zone-prefixed false easting n * 1e6 + 500 000 m, or the plain 500 000 m of "CM" grids."""
    return zone * 1_000_000.0 + 500_000.0 if prefixed else 500_000.0


def zone_from_easting(easting_m):
    """The zone number encoded in a zone-prefixed easting (e.g. 37 from 37 512 345.6 m)."""
    return np.floor(np.asarray(easting_m, dtype=float) / 1_000_000.0).astype(int)


def gauss_kruger_zone(ellipsoid: Ellipsoid, zone: int, width_deg: int = 3, prefixed: bool = True) -> GaussKruger:
    return GaussKruger(ellipsoid, float(central_meridian_deg(zone, width_deg)), false_easting_m(zone, prefixed))


def zone_for_block(lon_deg, width_deg: int = 3):
    """The zone whose central meridian is nearest to the block's mid longitude, and the block's
    largest distance from that meridian in degrees (a block straddling a zone boundary is mapped
    into one zone; beyond about 2 degrees (3-degree) or 3.5 degrees (6-degree) the scale error grows)."""
    lon = np.asarray(lon_deg, dtype=float)
    mid = 0.5 * (lon.min() + lon.max())
    zone = int(zone_3deg(mid) if width_deg == 3 else zone_6deg(mid))
    cm = float(central_meridian_deg(zone, width_deg))
    return zone, float(np.max(np.abs(lon - cm)))


_GK_NAME = re.compile(
    r"^(?P<datum>.+?) / (?:(?P<three>3-degree) )?Gauss-Kruger (?:zone (?P<zone>\d+)|CM (?P<cm>\d+)E)$"
)


@functools.lru_cache(maxsize=1)
def _gk_catalogue():
    """{(datum name, width, prefixed, zone): EPSG code} read from the PROJ database by CRS name."""
    from pyproj.database import query_crs_info
    from pyproj.enums import PJType

    out = {}
    for info in query_crs_info(auth_name="EPSG", pj_types=PJType.PROJECTED_CRS):
        m = _GK_NAME.match(info.name)
        if not m or info.deprecated:
            continue
        width = 3 if m["three"] else 6
        if m["zone"]:
            zone, prefixed = int(m["zone"]), True
        else:
            cm = int(m["cm"])
            zone, prefixed = (cm // 3 if width == 3 else (cm + 3) // 6), False
        out[(m["datum"], width, prefixed, zone)] = int(info.code)
    return out


def gk_epsg(datum: str, zone: int, width_deg: int = 3, prefixed: bool = True) -> int:
    """EPSG code of a Chinese Gauss-Krueger grid, e.g. gk_epsg("Xian 1980", 37) == 2361.

    ``datum`` is the name prefix used by EPSG: "Beijing 1954", "Xian 1980", "New Beijing", "CGCS2000".
    """
    key = (datum, width_deg, prefixed, int(zone))
    cat = _gk_catalogue()
    if key not in cat:
        datums = sorted({k[0] for k in cat})
        raise KeyError(f"no EPSG Gauss-Kruger grid for {key}; datums with grids: {', '.join(datums)}")
    return cat[key]
