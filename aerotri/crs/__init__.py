"""Datums, projections and heights for deliverables in national grids.

- ``gauss_kruger``: own Gauss-Krueger / transverse Mercator (Krueger n-series) and the Chinese
  3-/6-degree zone helpers (zone numbers, central meridians, zone-prefixed false eastings, EPSG codes).
- ``fit``: helmert2d / affine2d / bursa-wolf7 / translation3 from common points (Gauss-Markov).
- ``heights``: height anomaly surfaces (plane, quadratic, thin-plate spline), H = h - zeta.
- ``transform``: ``CrsTransformer`` built once and applied to arrays; refuses PROJ's ballpark
  operations (datum shift ignored) unless explicitly allowed.
- ``files``: common-point and height-point tables, parameter files, point lists and LAS/LAZ.
"""

from aerotri.geom.ellipsoid import CGCS2000, IAG75, KRASSOVSKY, WGS84, Ellipsoid
from aerotri.geom.crs import parse_crs
from aerotri.crs.fit import FitResult, fit_plane, fit_spatial
from aerotri.crs.gauss_kruger import (
    GaussKruger,
    central_meridian_deg,
    false_easting_m,
    gauss_kruger_zone,
    gk_epsg,
    zone_3deg,
    zone_6deg,
    zone_for_block,
)
from aerotri.crs.heights import fit_height_anomaly
from aerotri.geom.datum import HeightAnomalyModel, Transformation
from aerotri.geom.transform import BallparkRefused, CrsTransformer, transform_points

__all__ = [
    "BallparkRefused",
    "CGCS2000",
    "CrsTransformer",
    "Ellipsoid",
    "FitResult",
    "GaussKruger",
    "HeightAnomalyModel",
    "IAG75",
    "KRASSOVSKY",
    "Transformation",
    "WGS84",
    "central_meridian_deg",
    "false_easting_m",
    "fit_height_anomaly",
    "fit_plane",
    "fit_spatial",
    "gauss_kruger_zone",
    "gk_epsg",
    "parse_crs",
    "transform_points",
    "zone_3deg",
    "zone_6deg",
    "zone_for_block",
]
