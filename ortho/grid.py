"""Output ortho grids: CRS, resolution, extent, and the transform to the project CRS.

An ``OrthoGrid`` is a north-up raster in an output CRS: ``x_left_m``/``y_top_m`` are the outer edges
of the top-left pixel, pixel centres are at ``x_left_m + (col + 0.5) * res_m`` and
``y_top_m - (row + 0.5) * res_m``. All per-frame orthos of a block share one origin snapped to
multiples of ``res_m``, so every frame ortho is a window of the mosaic grid (no resampling at mosaic
time).

Exterior orientations and DEMs are in the project CRS. When the product CRS differs (e.g. a
3-degree Gauss-Krueger zone of CGCS2000 or Xian 1980 for a block surveyed in WGS 84 UTM),
``GridToProject`` maps output coordinates to project coordinates through the toolkit's one
coordinate-operation policy (``aerotri.geom.crs.transform``): a datum change needs the parameter set fitted
from common points (``--params``), PROJ's ballpark operation is refused unless explicitly allowed. The
operation is built once; per pixel it is interpolated from an anchor grid whose spacing is halved
until the interpolation error at the cell centres is below a tolerance (default 1 mm on the ground), or, where a
tile's cell centres are affine in the project CRS within a tenth of that (checked against the operation:
``GridToProject.affine``; two transverse Mercator grids over a tile), the rectifier takes the affine map and the
project CRS's vectorised kernels.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from pyproj import CRS
from rasterio.transform import Affine

from aerotri.core.errors import CrsError, InputError
from aerotri.geom.crs.definition import crs_label, horizontal_crs, linear_unit_m, map_axis_signs, parse_crs
from aerotri.geom.crs.raster_warp import anchor_grid
from aerotri.geom.crs.transform import CrsTransformer

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
        raise CrsError(f"--crs gk3:{datum}: unknown datum for Gauss-Krueger zones; expected one of "
                       f"{', '.join('gk3:' + d for d in sorted(GK3_FIRST_EPSG))}", param="--crs")
    cm = int(round(lon_deg / 3.0)) * 3
    if not 75 <= cm <= 135:
        raise CrsError(f"--crs gk3:{datum}: the block centre at longitude {lon_deg:.3f} deg is outside the 3-degree GK "
                       f"zones 75E..135E of {datum}", param="--crs")
    return CRS.from_epsg(first + (cm - 75) // 3)


def resolve_output_crs(spec: str | None, project_crs: CRS, centre_xy_m, source: str = "--crs") -> CRS:
    """Output CRS from ``--crs``: None (project CRS), an EPSG/WKT, or ``gk3:<datum>`` (zone by block centre).
    ``source``: where the value came from, as errors name it (``aerotri run``: project.toml [rectify] crs).

    Ortho products need a projected CRS in metres (their pixel size is a ground distance)."""
    if spec is None:
        crs = project_crs
    elif str(spec).lower().startswith("gk3"):
        datum = spec.split(":", 1)[1] if ":" in spec else "cgcs2000"
        geographic = horizontal_crs(project_crs).geodetic_crs  # same datum: a conversion, no shift
        lon, _, _ = CrsTransformer(project_crs, geographic).transform(float(centre_xy_m[0]), float(centre_xy_m[1]))
        try:
            crs = gk3_zone_crs(float(lon[0]), datum)
        except CrsError as exc:
            raise CrsError(str(exc).replace("--crs", source, 1), param=source) from None
    else:
        crs = parse_crs(spec, source)
    h = horizontal_crs(crs)
    if not h.is_projected:
        raise CrsError(f"{source} {crs_label(crs)} ({h.name}) is not a projected CRS: ortho products have square "
                       "pixels of a ground size in metres; choose a projected CRS (a UTM or Gauss-Krueger zone) "
                       "and reproject the delivered mosaic afterwards if degrees are required", param=source)
    if abs(linear_unit_m(h) - 1.0) > 1e-12:
        raise CrsError(f"{source} {crs_label(crs)} ({h.name}) has axes in {h.axis_info[0].unit_name}; ortho products "
                       "are written in metre grids", param=source)
    return crs


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


def north_up_flips(transform, crs) -> tuple[bool, bool]:
    """(rows, columns): which of a raster's pixel axes a picture reverses so that north is up and east right. Both for
    a south-oriented grid stored as GDAL stores it (westing / southing, South Africa's Lo grids: row 0 the southern
    edge, column 0 the eastern; ``map_axis_signs``), neither for a north-up grid or without a CRS. Pictures only: the
    raster itself is stored and georeferenced as it is."""
    if crs is None:
        return False, False
    sx, sy = map_axis_signs(crs)
    return bool(transform.e * sy > 0), bool(transform.a * sx < 0)


def nice_resolution(gsd_m: float) -> float:
    """The value of 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten nearest to a GSD (log scale)."""
    e = 10 ** math.floor(math.log10(gsd_m))
    cands = [m * e for m in (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)]
    return round(float(min(cands, key=lambda c: abs(math.log(c / gsd_m)))), 12)


# The share of ``GridToProject.tolerance_m`` an affine tile must hold (0.1 mm of the default 1 mm): on a DSM wall the
# image position follows the ground position through the wall's height ramp (20 m per m for 10 m over a 0.5 m cell),
# so a fit held to 1 mm moved positions there by up to 0.03 px (demo frame s01_002 at 0.4 m, EPSG:4545 and 3857;
# the anchors themselves come within 0.01-0.09 mm of PROJ); at 0.1 mm they move by under 0.01 px
AFFINE_SHARE = 0.1


class GridToProject:
    """Output-grid coordinates to project-CRS coordinates and back (built once per CRS pair).

    ``operation``: the project -> output coordinate operation (``aerotri.geom.crs.transform.CrsTransformer``,
    with a parameter set and height model when the datums differ); None builds PROJ's operation under
    the policy (refused when it would be a ballpark). ``z_m``: the height used for the planimetric
    mapping (a datum change through geocentric coordinates depends on it by rotation x height, under a
    millimetre for 100 m of relief with arc-second rotations); the block's mean terrain height.
    """

    def __init__(self, output_crs: CRS, project_crs: CRS, tolerance_m: float = 1e-3,
                 operation: CrsTransformer | None = None, z_m: float = 0.0, affine_tiles: bool = True):
        self.tolerance_m = tolerance_m
        self.affine_tiles = affine_tiles
        self.z_m = float(z_m)
        self.project_crs = project_crs
        self.identity = CRS(output_crs) == CRS(project_crs) and (operation is None or operation.identity)
        self.operation = None if self.identity else operation or CrsTransformer(project_crs, output_crs)
        self._inverse = None if self.identity else self.operation.inverse()

    def record(self) -> dict | None:
        """The coordinate operation applied (``CrsTransformer.record``), None for the project CRS itself."""
        return None if self.identity else self.operation.record()

    @staticmethod
    def _apply(op: CrsTransformer, x_m, y_m, z_m: float):
        x = np.asarray(x_m, float)
        y = np.asarray(y_m, float)
        X, Y, _ = op.transform(x.ravel(), y.ravel(), np.full(x.size, z_m))
        return X.reshape(x.shape), Y.reshape(x.shape)

    def exact(self, x_m, y_m):
        """Output-grid coordinates -> project coordinates."""
        if self.identity:
            return np.asarray(x_m, float), np.asarray(y_m, float)
        return self._apply(self._inverse, x_m, y_m, self.z_m)

    def to_output(self, x_m, y_m):
        """Project coordinates -> output-grid coordinates."""
        if self.identity:
            return np.asarray(x_m, float), np.asarray(y_m, float)
        return self._apply(self.operation, x_m, y_m, self.z_m)

    def anchors(self, grid: OrthoGrid, spacing_px: int = 256):
        """Project-CRS coordinates on anchor nodes every ``spacing_px`` pixels, covering the grid.

        Returns (anchor_x_m, anchor_y_m, spacing_px) with shape (ny, nx) (``aerotri.geom.crs.raster_warp.
        anchor_grid``: refined until bilinear interpolation between anchors reproduces the exact
        transform at cell centres within ``tolerance_m``; for an identical CRS one cell suffices).
        """
        return anchor_grid(self.exact, grid.x_left_m, grid.y_top_m, grid.res_m, grid.width, grid.height,
                           spacing_px=spacing_px, tolerance=self.tolerance_m, affine=self.identity)

    def affine(self, grid: OrthoGrid, check_px: int = 64) -> "GridAffine | None":
        """The project coordinates of ``grid``'s cell centres as an affine function of (row, col), when one holds
        within ``AFFINE_SHARE`` of ``tolerance_m`` (the anchors' tolerance), else None (and always None with
        ``affine_tiles`` off).

        Fitted (least squares) to the exact transform at 3 x 3 cell centres (corners, edge midpoints, centre), then
        checked at a lattice every ``check_px`` pixels (at least 9 x 9, offset from the fit's points): the largest
        deviation from the exact transform must be within ``AFFINE_SHARE * tolerance_m``. Between two transverse
        Mercator grids over a tile of a hundred metres the map is affine to micrometres (its departure goes as the
        tile's size squared times the distance from the central meridian over the earth's radius squared); a web
        Mercator or a far zone at a coarse pixel fails the check and the caller takes the anchors (``anchors``)."""
        if self.identity:
            return GridAffine(grid.x_left_m + 0.5 * grid.res_m, grid.y_top_m - 0.5 * grid.res_m, grid.res_m, 0.0,
                              0.0, -grid.res_m, 0.0)
        if not self.affine_tiles:
            return None
        h1, w1 = grid.height - 1, grid.width - 1
        r, c = np.meshgrid(np.array([0.0, 0.5, 1.0]) * h1, np.array([0.0, 0.5, 1.0]) * w1, indexing="ij")
        X, Y = self._exact_at(grid, r, c)
        if not (np.isfinite(X).all() and np.isfinite(Y).all()):
            return None
        A = np.column_stack([np.ones(r.size), c.ravel(), r.ravel()])
        (x0, xc, xr), *_ = np.linalg.lstsq(A, X.ravel(), rcond=None)
        (y0, yc, yr), *_ = np.linalg.lstsq(A, Y.ravel(), rcond=None)
        nr = max(9, -(-grid.height // check_px) + 1)
        nc = max(9, -(-grid.width // check_px) + 1)
        # lattice nodes at (k + 0.5) / n of the span: none on the fit's points
        r, c = np.meshgrid((np.arange(nr) + 0.5) / nr * h1, (np.arange(nc) + 0.5) / nc * w1, indexing="ij")
        X, Y = self._exact_at(grid, r, c)
        dev = np.hypot(x0 + xc * c + xr * r - X, y0 + yc * c + yr * r - Y)
        deviation = float(dev.max())
        if not deviation <= AFFINE_SHARE * self.tolerance_m:  # NaN (outside the operation's domain) fails too
            return None
        return GridAffine(float(x0), float(y0), float(xc), float(yc), float(xr), float(yr), deviation)

    def _exact_at(self, grid: OrthoGrid, rows, cols):
        return self.exact(grid.x_left_m + (cols + 0.5) * grid.res_m, grid.y_top_m - (rows + 0.5) * grid.res_m)


class GridAffine(NamedTuple):
    """Project coordinates of an output grid's cell centres, affine in the cell's (row, col): X = x0_m + col *
    col_dx_m + row * row_dx_m, Y = y0_m + col * col_dy_m + row * row_dy_m (m); ``deviation_m``: the largest distance
    from the exact transform where it was checked (``GridToProject.affine``)."""

    x0_m: float
    y0_m: float
    col_dx_m: float
    col_dy_m: float
    row_dx_m: float
    row_dy_m: float
    deviation_m: float

    def anchors(self, width: int, height: int):
        """The anchor grid (``GridToProject.anchors``' form) that reproduces the affine map exactly: 2 x 2 nodes
        ``spacing`` apart (bilinear interpolation of an affine function is that function)."""
        s = max(width, height, 2) - 1
        r, c = np.meshgrid([0.0, s], [0.0, s], indexing="ij")
        return (self.x0_m + c * self.col_dx_m + r * self.row_dx_m, self.y0_m + c * self.col_dy_m + r * self.row_dy_m,
                s)


def overview_factors(width: int, height: int, block_px: int = 512) -> list[int]:
    """Overview decimation factors 2, 4, ... until the coarsest fits one block (GDAL's COG default): the mosaic's
    and the frame orthos' (``[rectify] overviews``)."""
    out, f = [], 2
    while -(-max(width, height) // (f // 2)) > block_px:
        out.append(f)
        f *= 2
    return out
