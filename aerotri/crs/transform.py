"""Coordinate transformation between CRSs, built once and applied to arrays.

``CrsTransformer(from_crs, to_crs, params=None, heights=None, allow_ballpark=False)`` chains

1. a PROJ operation from ``from_crs`` into the parameter set's source CRS (a conversion within one
   datum: unprojecting, changing zone),
2. the fitted parameter set (``aerotri.crs.fit.Transformation``): on grid coordinates for the plane
   models, on geocentric XYZ for the spatial models,
3. a PROJ operation from the parameter set's target CRS into ``to_crs``,
4. optionally the height anomaly model: H = h - zeta(x, y).

Without a parameter set, PROJ's own operation is used when it is rigorous (it knows the datum
shift). When PROJ only has a "ballpark" operation (datums differ and the shift is ignored, errors
of metres to hundreds of metres), the transformer refuses unless ``allow_ballpark=True``: the fix
is a parameter set from common points (``aerotri crs fit``).

Heights: ``z`` is in the vertical unit of the CRS: the linear unit of a projected 2D CRS (LAS
convention: feet grids carry feet heights), metres for geographic CRSs; a compound CRS uses its
vertical axis. Ellipsoidal heights follow datum shifts; the height model converts to normal heights.
"""

from __future__ import annotations

import numpy as np
import pyproj
from pyproj.transformer import TransformerGroup

from aerotri.crs.ellipsoid import Ellipsoid, geocentric_to_geodetic, geodetic_to_geocentric
from aerotri.geom.crs import crs_label, horizontal_crs, linear_unit_m, parse_crs
from aerotri.crs.fit import Transformation, outside_extent
from aerotri.crs.heights import HeightAnomalyModel
from aerotri.core.errors import InputError


class BallparkRefused(InputError):
    """PROJ would ignore a datum shift; parameters from common points are needed."""


def z_unit_m(crs: pyproj.CRS) -> float:
    """Metres per height unit as this module reads z for ``crs`` (see module docstring)."""
    if crs.is_compound or len(crs.axis_info) >= 3:
        return 1.0  # PROJ reads z in the CRS's own vertical unit
    f = linear_unit_m(crs)
    return 1.0 if np.isnan(f) else f


def _as_3d(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound or crs.is_geocentric or len(crs.axis_info) >= 3:
        return crs
    return crs.to_3d()


def is_ballpark(transformer: pyproj.Transformer) -> bool:
    text = transformer.description or ""
    ops = transformer.operations or []
    return "ballpark" in text.lower() or any("ballpark" in (op.name or "").lower() for op in ops)


class _ProjLeg:
    """One PROJ operation between two CRSs, z converted to metres around it."""

    def __init__(self, src: pyproj.CRS, dst: pyproj.CRS, allow_ballpark: bool, purpose: str = ""):
        self.src, self.dst = src, dst
        self.identity = src == dst
        self.ballpark = False
        self.notes = []
        if self.identity:
            return
        s3, d3 = _as_3d(src), _as_3d(dst)
        self.z_in, self.z_out = z_unit_m(src), z_unit_m(dst)
        group = TransformerGroup(s3, d3, always_xy=True, allow_ballpark=False)
        if not group.transformers:
            if not allow_ballpark:
                raise BallparkRefused(
                    f"{crs_label(src)} ({src.name}) -> {crs_label(dst)} ({dst.name}){purpose}: PROJ knows no "
                    "rigorous transformation between these datums, only a 'ballpark' one that ignores the datum "
                    "shift (errors of metres to hundreds of metres). Fit parameters from common points known in "
                    "both systems (aerotri crs fit ... --from/--to) and pass them with --params, or accept the "
                    "ballpark result explicitly with --allow-ballpark (allow_ballpark=True)"
                )
            self.ballpark = True
        elif not group.best_available:
            self.notes.append(
                f"{crs_label(src)} -> {crs_label(dst)}: the most accurate PROJ operation needs a grid that is not "
                "installed; a less accurate one is used (pyproj.sync / projsync can fetch grids)"
            )
        self.transformer = pyproj.Transformer.from_crs(s3, d3, always_xy=True, allow_ballpark=self.ballpark)
        if self.ballpark:
            self.notes.append(
                f"{crs_label(src)} -> {crs_label(dst)}: BALLPARK transformation accepted by the user "
                f"({self.transformer.description}); the datum shift is ignored"
            )

    def __call__(self, x, y, z):
        if self.identity:
            return x, y, z
        X, Y, Z = self.transformer.transform(x, y, z * self.z_in, errcheck=False)
        X, Y, Z = (np.asarray(a, dtype=float) for a in (X, Y, Z))
        bad = ~(np.isfinite(X) & np.isfinite(Y) & np.isfinite(Z))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(
                f"{crs_label(self.src)} -> {crs_label(self.dst)}: point {i + 1} ({x[i]:.3f}, {y[i]:.3f}) could not be "
                "transformed rigorously (outside the area of the available operations, or not a valid coordinate)"
            )
        return X, Y, Z / self.z_out


class CrsTransformer:
    """Build once, call ``transform(x, y, z)`` on arrays (see the module docstring)."""

    def __init__(self, from_crs, to_crs, params: Transformation | None = None,
                 heights: HeightAnomalyModel | None = None, allow_ballpark: bool = False):
        self.src = parse_crs(from_crs, "--from")
        self.dst = parse_crs(to_crs, "--to")
        self.params = params
        self.heights = heights
        self.n_outside_fit_extent = 0
        self.n_points = 0
        legs = []
        if params is None:
            legs.append(_ProjLeg(self.src, self.dst, allow_ballpark))
        else:
            p_from = parse_crs(params.from_crs, "parameter file from_crs")
            p_to = parse_crs(params.to_crs, "parameter file to_crs")
            self._p_from, self._p_to = p_from, p_to
            why = " (into the parameter set's source system)"
            if params.spatial:
                self._ell_from = Ellipsoid.from_crs(p_from)
                self._ell_to = Ellipsoid.from_crs(p_to)
                self._geo_from = p_from if p_from.is_geocentric else p_from.geodetic_crs
                self._geo_to = p_to if p_to.is_geocentric else p_to.geodetic_crs
                self._pre_plane = _ProjLeg(self.src, p_from, allow_ballpark, why) if not p_from.is_geocentric else None
                legs.append(_ProjLeg(self.src, self._geo_from, allow_ballpark, why))
                legs.append(_ProjLeg(self._geo_to, self.dst, allow_ballpark, " (from the parameter set's target)"))
            else:
                for c, role in ((p_from, "from_crs"), (p_to, "to_crs")):
                    if not horizontal_crs(c).is_projected or abs(linear_unit_m(c) - 1.0) > 1e-12:
                        raise InputError(f"parameter file {role} {crs_label(c)}: plane models need a metre grid")
                legs.append(_ProjLeg(self.src, p_from, allow_ballpark, why))
                legs.append(_ProjLeg(p_to, self.dst, allow_ballpark, " (from the parameter set's target)"))
        self._legs = legs
        self._height_leg = None
        if heights is not None and heights.crs:
            hcrs = parse_crs(heights.crs, "height model crs")
            if hcrs != self.dst and hcrs != self.src:
                self._height_leg = _ProjLeg(self.dst, hcrs, allow_ballpark=False, purpose=" (height model)")
            self._heights_crs = hcrs
        else:
            self._heights_crs = self.dst
        self.ballpark = any(leg.ballpark for leg in legs)
        self.notes = [n for leg in legs for n in leg.notes]

    @property
    def description(self) -> str:
        parts = [f"{crs_label(self.src)} -> {crs_label(self.dst)}"]
        if self.params is not None:
            parts.append(f"via {self.params.model} ({self.params.from_crs} -> {self.params.to_crs})")
        if self.heights is not None:
            parts.append(f"normal heights by {self.heights.model} height anomaly model")
        return ", ".join(parts)

    def transform(self, x, y, z=None):
        """Arrays in ``from_crs`` (x = easting/longitude) -> arrays in ``to_crs``; z defaults to 0."""
        x = np.atleast_1d(np.asarray(x, dtype=float))
        y = np.atleast_1d(np.asarray(y, dtype=float))
        z = np.zeros_like(x) if z is None else np.atleast_1d(np.asarray(z, dtype=float))
        x_in, y_in = x, y
        self.n_points += len(x)
        if self.params is None:
            X, Y, Z = self._legs[0](x, y, z)
        elif not self.params.spatial:
            a, b, c = self._legs[0](x, y, z)
            self._count_outside(a, b)
            ab = self.params.apply(np.column_stack([a, b]))
            X, Y, Z = self._legs[1](ab[:, 0], ab[:, 1], c)
        else:
            if self.params.fit_extent is not None and self._pre_plane is not None:
                a, b, _ = self._pre_plane(x, y, z)
                self._count_outside(a, b)
            if self._p_from.is_geocentric:
                XYZ = np.column_stack(self._legs[0](x, y, z))
            else:
                lon, lat, h = self._legs[0](x, y, z)
                XYZ = np.column_stack(geodetic_to_geocentric(lat, lon, h, self._ell_from))
            XYZ = self.params.apply(XYZ)
            if self._p_to.is_geocentric:
                X, Y, Z = self._legs[1](XYZ[:, 0], XYZ[:, 1], XYZ[:, 2])
            else:
                lat, lon, h = geocentric_to_geodetic(XYZ[:, 0], XYZ[:, 1], XYZ[:, 2], self._ell_to)
                X, Y, Z = self._legs[1](lon, lat, h)
        if self.heights is not None:
            if self._height_leg is not None:
                hx, hy, _ = self._height_leg(X, Y, np.zeros_like(X))
            elif self._heights_crs == self.src and self._heights_crs != self.dst:
                hx, hy = x_in, y_in
            else:
                hx, hy = X, Y
            Z = Z - self.heights.zeta_m(hx, hy) / z_unit_m(self.dst)
        return X, Y, Z

    def _count_outside(self, a, b):
        if self.params is not None and self.params.fit_extent is not None:
            self.n_outside_fit_extent += int(outside_extent(self.params.fit_extent, np.column_stack([a, b])).sum())

    @property
    def warnings(self) -> list:
        out = list(self.notes)
        if self.n_outside_fit_extent:
            out.append(
                f"{self.n_outside_fit_extent} of {self.n_points} points lie outside the area of the common points "
                "used for the parameters (extrapolation; accuracy unknown there)"
            )
        return out


def transform_points(x, y, z=None, *, from_crs, to_crs, params=None, heights=None, allow_ballpark=False):
    """One-shot convenience: ``CrsTransformer(...).transform(x, y, z)``."""
    return CrsTransformer(from_crs, to_crs, params, heights, allow_ballpark).transform(x, y, z)
