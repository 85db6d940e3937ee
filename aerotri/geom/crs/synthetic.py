"""Synthetic common points with a known transformation (truth for tests and ``bench/eval_crs.py``).

The parameter sets below have realistic magnitudes but are invented: official WGS 84 <-> Xian 1980
parameters are not public, which is why production estimates them from common points.
"""

from __future__ import annotations

import numpy as np

from aerotri.geom.crs.ellipsoid import Ellipsoid, geocentric_to_geodetic, geodetic_to_geocentric
from aerotri.geom.crs.definition import parse_crs
from aerotri.geom.crs.datum import Transformation
from aerotri.geom.crs.transform import from_own_geodetic

TRUE_BURSA_WOLF7 = {  # WGS 84 -> Xian 1980 style (coordinate frame); invented, realistic size
    "tx_m": -24.3,
    "ty_m": 121.6,
    "tz_m": 76.2,
    "rx_arcsec": 1.27,
    "ry_arcsec": -0.84,
    "rz_arcsec": 2.13,
    "scale_ppm": -3.46,
}
TRUE_HELMERT2D = {"tx_m": -512.37, "ty_m": 1843.91, "scale_ppm": 27.5, "rotation_arcsec": -4.2}


def simulate_spatial(truth: dict, from_epsg, to_epsg, *, lon_deg, lat_deg, h_m, noise_m: float = 0.0,
                     seed: int = 0, model: str = "bursa-wolf7"):
    """Points at (lon, lat, h) on the source datum, in ``from_epsg`` and, through the true spatial
    transformation plus Gaussian noise (``noise_m`` per coordinate in the target grid), in ``to_epsg``.

    Returns (src (n, 3), dst (n, 3), dst_true (n, 3)) in the native units of each CRS (x, y, h);
    the noise is in metres on the ground whatever the units."""
    src_crs, dst_crs = parse_crs(from_epsg), parse_crs(to_epsg)
    lon, lat, h = (np.asarray(a, dtype=float) for a in (lon_deg, lat_deg, h_m))
    sx, sy, sz = from_own_geodetic(src_crs, lon, lat, h)
    XYZ = np.column_stack(geodetic_to_geocentric(lat, lon, h, Ellipsoid.from_crs(src_crs)))
    T = Transformation(model, dict(truth), str(from_epsg), str(to_epsg))
    XYZ_t = T.apply(XYZ)
    lat_t, lon_t, h_t = geocentric_to_geodetic(*XYZ_t.T, Ellipsoid.from_crs(dst_crs))
    dx, dy, dz = from_own_geodetic(dst_crs, lon_t, lat_t, h_t)
    dst_true = np.column_stack([dx, dy, dz])
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, noise_m, dst_true.shape) if noise_m > 0 else np.zeros_like(dst_true)
    if dst_crs.is_geographic:  # metres of noise -> degrees with the radii of curvature M and N
        ell = Ellipsoid.from_crs(dst_crs)
        M = ell.meridian_radius_m(np.radians(lat_t))
        N = ell.prime_vertical_radius_m(np.radians(lat_t))
        noise[:, 0] = np.degrees(noise[:, 0] / (N * np.cos(np.radians(lat_t))))
        noise[:, 1] = np.degrees(noise[:, 1] / M)
    return np.column_stack([sx, sy, sz]), dst_true + noise, dst_true


def simulate_plane(truth: dict, src_xy_m, noise_m: float = 0.0, seed: int = 0, model: str = "helmert2d"):
    """Target grid coordinates from source grid coordinates through a plane model plus noise."""
    T = Transformation(model, dict(truth))
    dst_true = T.apply(np.asarray(src_xy_m, dtype=float))
    rng = np.random.default_rng(seed)
    dst = dst_true + rng.normal(0.0, noise_m, dst_true.shape) if noise_m > 0 else dst_true.copy()
    return dst, dst_true


def write_common_points(path, ids, src, dst) -> None:
    """CSV in the ``crs fit`` layout (with z columns when the arrays have three columns)."""
    src, dst = np.asarray(src), np.asarray(dst)
    z = src.shape[1] == 3
    head = "id,x_from,y_from" + (",z_from" if z else "") + ",x_to,y_to" + (",z_to" if z else "")
    rows = [head]
    for pid, s, d in zip(ids, src, dst):
        rows.append(",".join([str(pid), *(f"{v:.4f}" if abs(v) > 1000 else f"{v:.10f}" for v in (*s, *d))]))
    with open(path, "w") as f:
        f.write("\n".join(rows) + "\n")
