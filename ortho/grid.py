"""Output ortho grids: CRS, resolution, extent, and the transform to the project CRS.

An ``OrthoGrid`` is a north-up raster in an output CRS: ``x_left_m``/``y_top_m`` are the outer edges
of the top-left pixel, pixel centres are at ``x_left_m + (col + 0.5) * res_m`` and
``y_top_m - (row + 0.5) * res_m``. All per-frame orthos of a block share one origin snapped to
multiples of ``res_m``, so every frame ortho is a window of the mosaic grid (no resampling at mosaic
time).

Exterior orientations and DEMs are in the project CRS. When the product CRS differs (e.g. a
3-degree Gauss-Krueger zone of CGCS2000 or Xian 1980 for a block surveyed in UTM), ``GridToProject``
maps output coordinates to project coordinates with one pyproj Transformer built once; per pixel the
transform is interpolated from an anchor grid whose spacing is halved until the interpolation error
at the cell centres is below a tolerance (default 1 mm on the ground).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pyproj import CRS, Transformer
from rasterio.transform import Affine

from aerotri.core.errors import InputError
from aerotri.geom.crs import parse_crs

# EPSG codes of the 3-degree Gauss-Krueger zones with the central meridian in the code's name
# (zone CM = 75E + 3 * (code - first)), 75E .. 135E.
GK3_FIRST_EPSG = {"cgcs2000": 4534, "xian1980": 2370, "beijing1954": 2422}


def gk3_zone_crs(lon_deg: float, datum: str = "cgcs2000") -> CRS:
    """The 3-degree Gauss-Krueger zone (without zone prefix in the easting) nearest to a longitude.

    A block crossing a zone boundary gets the single zone whose central meridian is nearest to the
    block centre, so the product has one CRS (scale error grows as (dlon)^2 away from the CM).
    """
    first = GK3_FIRST_EPSG.get(datum.lower())
    if first is None:
        raise InputError(f"unknown datum {datum!r} for Gauss-Krueger zones; expected one of {sorted(GK3_FIRST_EPSG)}")
    cm = int(round(lon_deg / 3.0)) * 3
    if not 75 <= cm <= 135:
        raise InputError(f"longitude {lon_deg:.3f} deg is outside the 3-degree GK zones 75E..135E of {datum}")
    return CRS.from_epsg(first + (cm - 75) // 3)


def resolve_output_crs(spec: str | None, project_crs: CRS, centre_xy_m) -> CRS:
    """Output CRS from ``--crs``: None (project CRS), an EPSG/WKT, or ``gk3:<datum>`` (zone by block centre)."""
    if spec is None:
        return project_crs
    if str(spec).lower().startswith("gk3"):
        datum = spec.split(":", 1)[1] if ":" in spec else "cgcs2000"
        to_ll = Transformer.from_crs(project_crs, "EPSG:4326", always_xy=True)
        lon, _ = to_ll.transform(float(centre_xy_m[0]), float(centre_xy_m[1]))
        return gk3_zone_crs(lon, datum)
    return parse_crs(spec, "--crs")


@dataclasses.dataclass(frozen=True)
class OrthoGrid:
    crs: CRS
    x_left_m: float
    y_top_m: float
    res_m: float
    width: int
    height: int

    @property
    def transform(self) -> Affine:
        return Affine(self.res_m, 0.0, self.x_left_m, 0.0, -self.res_m, self.y_top_m)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) in metres of the output CRS."""
        return (self.x_left_m, self.y_top_m - self.height * self.res_m, self.x_left_m + self.width * self.res_m, self.y_top_m)

    def window(self, col0: int, row0: int, width: int, height: int) -> "OrthoGrid":
        """A sub-grid starting at pixel (col0, row0)."""
        return dataclasses.replace(
            self,
            x_left_m=self.x_left_m + col0 * self.res_m,
            y_top_m=self.y_top_m - row0 * self.res_m,
            width=int(width),
            height=int(height),
        )

    def offset_in(self, other: "OrthoGrid") -> tuple[int, int]:
        """(col, row) of this grid's top-left pixel in ``other`` (same resolution and snapping)."""
        c = (self.x_left_m - other.x_left_m) / self.res_m
        r = (other.y_top_m - self.y_top_m) / self.res_m
        ci, ri = int(round(c)), int(round(r))
        if abs(c - ci) > 1e-6 or abs(r - ri) > 1e-6 or abs(self.res_m - other.res_m) > 1e-12:
            raise ValueError("grids are not aligned")
        return ci, ri

    def centres(self, rows=None, cols=None):
        """Pixel-centre coordinates (x_m for cols, y_m for rows) as 1-D arrays."""
        cols = np.arange(self.width) if cols is None else np.asarray(cols, dtype=float)
        rows = np.arange(self.height) if rows is None else np.asarray(rows, dtype=float)
        return self.x_left_m + (cols + 0.5) * self.res_m, self.y_top_m - (rows + 0.5) * self.res_m

    @classmethod
    def snapped(cls, crs: CRS, bounds, res_m: float) -> "OrthoGrid":
        """The grid covering ``bounds`` (left, bottom, right, top) with edges on multiples of res_m."""
        left, bottom, right, top = bounds
        x0 = math.floor(left / res_m) * res_m
        y0 = math.ceil(top / res_m) * res_m
        w = int(math.ceil((right - x0) / res_m))
        h = int(math.ceil((y0 - bottom) / res_m))
        if w <= 0 or h <= 0:
            raise InputError(f"empty ortho grid for bounds {bounds}")
        return cls(crs, x0, y0, float(res_m), w, h)

    @classmethod
    def union(cls, grids) -> "OrthoGrid":
        grids = list(grids)
        res = grids[0].res_m
        b = np.array([g.bounds for g in grids])
        return cls.snapped(grids[0].crs, (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()), res)


def nice_resolution(gsd_m: float) -> float:
    """The value of 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten nearest to a GSD (log scale)."""
    e = 10 ** math.floor(math.log10(gsd_m))
    cands = [m * e for m in (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)]
    return round(float(min(cands, key=lambda c: abs(math.log(c / gsd_m)))), 12)


class GridToProject:
    """Output-grid pixel centres to project-CRS coordinates, via an anchor grid (built once per CRS pair)."""

    def __init__(self, output_crs: CRS, project_crs: CRS, tolerance_m: float = 1e-3):
        self.identity = CRS(output_crs) == CRS(project_crs)
        self.tolerance_m = tolerance_m
        self._tr = None if self.identity else Transformer.from_crs(output_crs, project_crs, always_xy=True)
        self._inv = None if self.identity else Transformer.from_crs(project_crs, output_crs, always_xy=True)

    def exact(self, x_m, y_m):
        if self.identity:
            return np.asarray(x_m, float), np.asarray(y_m, float)
        return self._tr.transform(np.asarray(x_m, float), np.asarray(y_m, float))

    def to_output(self, x_m, y_m):
        if self.identity:
            return np.asarray(x_m, float), np.asarray(y_m, float)
        return self._inv.transform(np.asarray(x_m, float), np.asarray(y_m, float))

    def anchors(self, grid: OrthoGrid, spacing_px: int = 256):
        """Project-CRS coordinates on anchor nodes every ``spacing_px`` pixels, covering the grid.

        Returns (anchor_x_m, anchor_y_m, spacing_px) with shape (ny, nx). The spacing is halved until
        bilinear interpolation between anchors reproduces the exact transform at cell centres within
        ``tolerance_m``; for an identical CRS the mapping is affine and one cell suffices.
        """
        if self.identity:
            spacing_px = max(grid.width, grid.height)
        while True:
            cols = _anchor_positions(grid.width, spacing_px)
            rows = _anchor_positions(grid.height, spacing_px)
            xs, ys = grid.centres(rows, cols)
            X, Y = np.meshgrid(xs, ys)
            AX, AY = self.exact(X, Y)
            AX, AY = np.asarray(AX), np.asarray(AY)
            if self.identity or spacing_px <= 4:
                return AX, AY, spacing_px
            # check at the centres of cells
            cc = (cols[:-1] + cols[1:]) / 2.0 if len(cols) > 1 else cols
            rc = (rows[:-1] + rows[1:]) / 2.0 if len(rows) > 1 else rows
            xc, yc = grid.centres(rc, cc)
            EX, EY = self.exact(*np.meshgrid(xc, yc))
            IX = 0.25 * (AX[:-1, :-1] + AX[1:, :-1] + AX[:-1, 1:] + AX[1:, 1:]) if AX.shape[0] > 1 and AX.shape[1] > 1 else AX
            IY = 0.25 * (AY[:-1, :-1] + AY[1:, :-1] + AY[:-1, 1:] + AY[1:, 1:]) if AY.shape[0] > 1 and AY.shape[1] > 1 else AY
            err = np.hypot(np.asarray(EX) - IX, np.asarray(EY) - IY) if IX.shape == np.shape(EX) else np.zeros(1)
            if float(np.max(err)) <= self.tolerance_m:
                return AX, AY, spacing_px
            spacing_px //= 2


def _anchor_positions(n: int, spacing: int) -> np.ndarray:
    """Anchor pixel indices 0, s, 2s, ... up to or past the last pixel n-1 (uniform, at least two)."""
    m = max(1, math.ceil((n - 1) / spacing))
    return np.arange(m + 1, dtype=float) * spacing
