"""Field check of LiDAR heights against surveyed points (the production "height check table").

For each surveyed point (X, Y, Z) the cloud's ground height is interpolated from the ground points
(class 2) within ``radius_m`` horizontally: a least-squares plane, inverse-distance weighted
(1/d^2), evaluated at (X, Y); with fewer than 3 points, or points nearly on a line (spread across
it below 0.1 radius), the IDW mean. dz = Z_lidar - Z_surveyed (m).
Statistics: counts per error bin, counts per |dz| bin (seed 004 Tab. 1: <= 0.3, 0.3-0.5, 0.5-1, > 1 m; dz as printed,
to the mm, and on an edge in the bin nearer zero),
mean |dz|, RMSE, mean dz; the same without |dz| > ``exclude_m``; all of it per group.

The DEM raster itself (``dem_path``, ``--dem``) is checked the same way: its bilinear height at each
surveyed point (NaN where one of the four cells around it is nodata), dz_dem = Z_dem - Z_surveyed. The
DEM alone (no cloud) or both side by side.

Groups: a ``group`` column of the points (e.g. open / road / steep), or the vegetation density around
each point from the cloud (``DensityGroups``): the canopy cover is the share of the first returns
(noise excluded) within ``radius_m`` horizontally that lie more than ``canopy_height_m`` above the
ground: the DEM when one is given, else the local ground plane (least squares, 1/d^2 weights) of the
ground points within that radius. open: cover < ``open_below``; sparse: up to ``dense_above``; dense:
above; unknown: no first return in range.

Units: the surveyed points are in the cloud's CRS (x, y in its horizontal unit, z in its vertical
unit). Radius, threshold, bins and every ``_m`` key (dz, mean, RMSE) are metres, also for clouds
in feet; the per-point coordinates (``x``, ``y``, ``z_survey``, ``z_lidar``) are in the CRS's units,
named by ``xy_unit`` and ``z_unit``. A DEM whose file declares no height unit (a 2D CRS, no band unit, no
VERTICAL_UNITS tag) is read in ``--dem-z-unit`` or else in its CRS's horizontal unit, said on the console and in
``dem.z_unit_note`` (and in the report's DEM row when ``dem.z_unit_consequential``: the CRS is not in metres).

The top-level ``overall`` and ``groups`` are the statistics of the surface named by ``overall_surface``: the cloud's
when a cloud was checked, else (``--dem`` alone) the DEM's, the same as ``dem.overall`` and ``dem.groups``.
"""

from __future__ import annotations

import csv
import dataclasses
import io as stringio
import json
import logging
import re
from pathlib import Path

import numpy as np
from pyproj.database import get_units_map
from scipy.spatial import cKDTree

from aerotri.geom import las

from aerotri.core.errors import InputError, OptionError
from aerotri.core.point_ids import refuse_repeated_id, warn_coincident_points
from aerotri.core.textio import read_text
from aerotri.geom.crs.definition import length_unit_name
from lidarctl import io
from lidarctl.units import METRE, LengthUnits

log = logging.getLogger(__name__)

BIN_EDGES_M = (-np.inf, -1.0, -0.5, 0.5, 1.0, 1.5, 2.0, 5.0, np.inf)
ABS_BIN_EDGES_M = (0.3, 0.5, 1.0)
GROUPINGS = ("auto", "column", "density", "none")
DENSITY_ORDER = ("open", "sparse", "dense", "unknown")


@dataclasses.dataclass(frozen=True, kw_only=True)
class DensityGroups:
    """Vegetation density around a surveyed point from the cloud's first returns (module docstring)."""

    radius_m: float = 10.0
    canopy_height_m: float = 2.0
    open_below: float = 0.2
    dense_above: float = 0.6

    def validate(self) -> None:
        if not (np.isfinite(self.radius_m) and self.radius_m > 0):
            raise OptionError(f"--cover-radius-m {self.radius_m}: must be a positive distance in metres",
                              param="--cover-radius-m")
        if not (np.isfinite(self.canopy_height_m) and self.canopy_height_m > 0):
            raise OptionError(f"--canopy-height-m {self.canopy_height_m}: must be a positive height in metres",
                              param="--canopy-height-m")
        if not (0 <= self.open_below <= self.dense_above <= 1):
            raise OptionError(f"--open-below {self.open_below:g} / --dense-above {self.dense_above:g}: expected "
                              "0 <= open-below <= dense-above <= 1 (cover fractions)", param="--dense-above")

    def label(self, cover: np.ndarray) -> list[str]:
        cover = np.asarray(cover, float)
        lab = np.where(cover < self.open_below, "open", np.where(cover <= self.dense_above, "sparse", "dense"))
        return [str(v) for v in np.where(np.isfinite(cover), lab, "unknown")]


# Binning: dz is counted as printed, rounded to the mm (a typed 0.3 m is 0.29999999999999716 after the subtraction:
# printed "+0.300", it was counted "< 0.3"), and a dz on an edge goes to the bin nearer zero on either side, as a
# limit reads "|dz| <= 0.5" (+0.5 was counted in "0.5 .. 1" but -0.5 in "-0.5 .. 0.5"; 5.0 in "> 5"); the labels
# say which end is closed
BIN_RESOLUTION_DECIMALS = 3  # mm, the printed resolution of dz


def _bin_index(values: np.ndarray, edges) -> np.ndarray:
    """The bin (between consecutive ``edges``) of each value rounded to the mm: on an edge, the bin nearer zero."""
    v = np.round(np.asarray(values, float), BIN_RESOLUTION_DECIMALS)
    e = np.asarray(edges, float)
    i = np.where(v < 0, np.searchsorted(e, v, side="right"), np.searchsorted(e, v, side="left")) - 1
    return np.clip(i, 0, len(e) - 2)


def bin_counts(values: np.ndarray, edges) -> np.ndarray:
    """Counts per bin of ``values`` (metres) between ``edges`` (``_bin_index``)."""
    return np.bincount(_bin_index(values, edges), minlength=len(edges) - 1)


def _edge_labels(edges, var: str) -> list[str]:
    """Each bin's range with its closed end: the end nearer zero is open, the other closed ("0.5 < dz <= 1",
    "-1 <= dz < -0.5", "-0.5 <= dz <= 0.5"); a first bin from 0 reads "|dz| <= 0.3"."""
    labels = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        lo_op, hi_op = ("<=" if lo < 0 else "<"), ("<=" if hi > 0 else "<")
        if np.isinf(lo):
            labels.append(f"{var} {hi_op} {hi:g}")
        elif np.isinf(hi):
            labels.append(f"{var} {'>=' if lo < 0 else '>'} {lo:g}")
        elif lo == 0:
            labels.append(f"{var} {hi_op} {hi:g}")
        else:
            labels.append(f"{lo:g} {lo_op} {var} {hi_op} {hi:g}")
    return labels


def bin_labels(edges=BIN_EDGES_M) -> list[str]:
    return _edge_labels(edges, "dz")


@dataclasses.dataclass(frozen=True, eq=False)
class SurveyedPoints:
    """Surveyed points (``read_points_csv``): coordinates in the units of the file (its header's, ``xy_unit`` and
    ``z_unit``: None where it names none, the CRS's), in the CRS's once converted (``in_crs_units``), or in metres
    once scaled (``in_metres``)."""

    ids: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray | None  # None: the file has no z column (``require_z=False``)
    group: tuple[str, ...] | None  # the group column per point, None without one
    xy_unit: str | None = None  # the header's unit suffix of x and y ('m', 'ft', 'us-ft', 'deg'), None: the CRS's
    z_unit: str | None = None   # ... of z
    z_column: str | None = None  # the header's name of the z column (z, h, height_ft, ...)

    def __len__(self) -> int:
        return len(self.x)

    def in_crs_units(self, units: LengthUnits, path) -> "SurveyedPoints":
        """The points in the units of the CRS (``units``) from those the header names (``x_ft``, ``z_usft``): scaled
        by pyproj's metres per unit (the US survey foot 1200/3937 m, the international foot 0.3048 m) over the CRS's;
        InputError naming ``path`` for a unit that no factor converts (degrees against a projected CRS)."""
        scaled = {}
        for axis, unit, crs_m in (("x, y", self.xy_unit, units.xy_m), ("z", self.z_unit, units.z_m)):
            if unit is None or (axis == "z" and self.z is None):
                continue
            unit_m = HEADER_UNIT_M.get(unit)
            if unit_m is None:
                raise InputError(f"{path}: line 1: {axis} in {unit} (the header's '_{unit}'): no factor converts them "
                                 f"to the CRS's {length_unit_name(crs_m)}; transform the points into the CRS first "
                                 "(aerotri crs transform)")
            if unit_m != crs_m:
                scaled[axis] = unit_m / crs_m
        if not scaled:
            return dataclasses.replace(self, xy_unit=None, z_unit=None)
        f_xy, f_z = scaled.get("x, y", 1.0), scaled.get("z", 1.0)
        return dataclasses.replace(self, x=self.x * f_xy, y=self.y * f_xy, z=None if self.z is None else self.z * f_z,
                                   xy_unit=None, z_unit=None)

    def in_metres(self, units: LengthUnits) -> "SurveyedPoints":
        """The points with x, y and z scaled by ``units`` (the CRS's) to metres."""
        return dataclasses.replace(self, x=units.xy_to_m(self.x), y=units.xy_to_m(self.y),
                                   z=units.z_to_m(self.z) if self.z is not None else None)


ID_COLUMNS = ("id", "point", "point_id", "pointid", "point id", "name", "pt", "station")
# a coordinate column's unit suffix (x_ft, easting_usft, z_m; the spellings of ``aerotri crs transform``'s tables)
_UNIT_SUFFIX = re.compile(r"^(?P<base>.+?)_(?P<unit>m|deg|ft|usft|us-ft|us_ft)$", re.IGNORECASE)
# metres per unit of the suffixes that name a length, as pyproj (PROJ's database) gives them
_UNIT_NAMES = {"m": "metre", "ft": "foot", "us-ft": "US survey foot"}
HEADER_UNIT_M = {short: float(get_units_map(category="linear")[name].conv_factor) for short, name in _UNIT_NAMES.items()}
GROUP_COLUMNS = ("group", "landcover", "land_cover", "land cover", "land-cover", "cover", "nva_vva", "lc")


def read_points_csv(path, require_z: bool = True) -> SurveyedPoints:
    """Surveyed points: header with id, x, y, z (case-insensitive; also point/name/pt for the id, e/easting,
    n/northing, h/height/elevation) and an optional land-cover group (any name of ``GROUP_COLUMNS``); without
    ``require_z`` the z column may be missing (``z`` None). Columns are found by name, so a surveyor's P,N,E,Z,D order
    reads as it is."""
    path = Path(path)
    rows = list(csv.reader(stringio.StringIO(read_text(path, "surveyed points table (id,x,y,z[,group])"), newline="")))
    if not rows:
        raise InputError(f"{path}: empty file, expected a header line 'id,x,y,z[,group]'")
    head = [h.strip().lower() for h in rows[0]]
    alias = {"x": ("x", "e", "easting"), "y": ("y", "n", "northing"), "z": ("z", "h", "height", "elevation")}
    col, unit = {}, {}
    for key, names in alias.items():
        found = [k for k, h in enumerate(head) if h in names]
        if not found:  # a unit suffix: x_ft, z_m (converted to the CRS's units by ``in_crs_units``)
            found = [k for k, h in enumerate(head) if (m := _UNIT_SUFFIX.match(h)) and m["base"] in names]
            if found:
                unit[key] = _UNIT_SUFFIX.match(head[found[0]])["unit"].replace("_", "-").replace("usft", "us-ft")
        if not found:
            if key == "z" and not require_z:
                continue
            other = next((name for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars"))
                          if len(rows[0]) == 1 and sep in rows[0][0]), None)
            # (trial s99 lidmut L4: a semicolon file read "no 'x' column in header ['id;x;y;z']")
            raise InputError(f"{path}: line 1: no '{key}' column in header {rows[0]}"
                             + (f": the file is separated by {other}; expected commas (and a decimal point)"
                                if other else ""))
        col[key] = found[0]
    if unit.get("x") != unit.get("y"):
        raise InputError(f"{path}: line 1: x in {unit.get('x') or 'the CRS unit'} but y in "
                         f"{unit.get('y') or 'the CRS unit'} (header {rows[0]}); expected one unit for both")
    # a surveyor's "Point" column: without it the points were numbered 1, 2, ... and the names lost
    col_id = next((head.index(n) for n in ID_COLUMNS if n in head), None)
    # the land cover under any of its usual names (a "landcover" column was read as no groups, and the report then
    # judged forest points as open ground)
    col_group = next((head.index(n) for n in GROUP_COLUMNS if n in head), None)
    ids, xyz, groups, lines = [], [], [], []
    first_line: dict[str, tuple[str, int]] = {}  # point_id_key -> (id as written, line)
    for line_no, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(head):
            raise InputError(f"{path}: line {line_no}: {len(row)} fields, expected {len(head)}")
        try:
            vals = [float(row[col[k]]) for k in ("x", "y", "z") if k in col]
        except ValueError:
            raise InputError(f"{path}: line {line_no}: {'/'.join(col)} not numbers: {row}") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}: line {line_no}: non-finite coordinate: {row}")
        pid = row[col_id].strip() if col_id is not None else str(line_no - 1)
        refuse_repeated_id(first_line, pid, line_no, f"{path}: line {line_no}")
        lines.append(line_no)
        ids.append(pid)
        xyz.append(vals)
        groups.append(row[col_group].strip() if col_group is not None else "")
    if not xyz:
        raise InputError(f"{path}: no surveyed points after the header")
    xyz = np.array(xyz)
    warn_coincident_points(path, ids, lines, xyz[:, 0], xyz[:, 1])
    return SurveyedPoints(tuple(ids), xyz[:, 0], xyz[:, 1], xyz[:, 2] if "z" in col else None,
                          tuple(groups) if col_group is not None else None, unit.get("x"), unit.get("z"),
                          rows[0][col["z"]].strip() if "z" in col else None)


# A plane needs ground points spread in both directions: nearly collinear points (a few returns along a scan
# line in sparse ground) give a plane whose tilt across them is noise, metres off at the surveyed point.
MIN_PLANE_SPREAD = 0.1


def _spread_m(dx, dy) -> float:
    """RMS spread of the points across their main direction (the smaller principal axis, metres)."""
    c = np.cov(np.vstack([dx, dy]), bias=True)
    return float(np.sqrt(max(np.linalg.eigvalsh(c)[0], 0.0)))


def ground_height_at(gx, gy, gz, qx, qy, *, radius_m: float = 5.0, slopes: bool = False):
    """Interpolated ground height at (qx, qy) and the number of ground points used (NaN if none); with
    ``slopes`` also the plane's slopes dz/dx, dz/dy (0 where the IDW mean is used)."""
    tree = cKDTree(np.column_stack([gx, gy]))
    z_out = np.full(len(qx), np.nan)
    n_used = np.zeros(len(qx), int)
    sxy = np.zeros((len(qx), 2))
    for k, nb in enumerate(tree.query_ball_point(np.column_stack([qx, qy]), radius_m)):
        if not nb:
            continue
        nb = np.asarray(nb)
        dx, dy = gx[nb] - qx[k], gy[nb] - qy[k]
        w = 1.0 / np.maximum(dx * dx + dy * dy, 0.01)
        n_used[k] = len(nb)
        if len(nb) >= 3 and _spread_m(dx, dy) >= MIN_PLANE_SPREAD * radius_m:
            a = np.column_stack([np.ones(len(nb)), dx, dy]) * np.sqrt(w)[:, None]
            coef, _, rank, _ = np.linalg.lstsq(a, gz[nb] * np.sqrt(w), rcond=None)
            if rank == 3:
                z_out[k] = coef[0]
                sxy[k] = coef[1:]
                continue
        z_out[k] = np.sum(w * gz[nb]) / np.sum(w)
    return (z_out, n_used, sxy) if slopes else (z_out, n_used)


def canopy_cover(fx, fy, qx, qy, hag_of, density: DensityGroups) -> tuple[np.ndarray, np.ndarray]:
    """(cover fraction, first returns counted) within ``density.radius_m`` of each (qx, qy), from first returns
    (fx, fy); ``hag_of(k, idx)`` gives the heights above ground of returns ``idx`` around point k (metres).
    NaN cover where no return is in range."""
    cover = np.full(len(qx), np.nan)
    n = np.zeros(len(qx), int)
    if len(fx):
        tree = cKDTree(np.column_stack([fx, fy]))
        for k, nb in enumerate(tree.query_ball_point(np.column_stack([qx, qy]), density.radius_m)):
            if not nb:
                continue
            hag = hag_of(k, np.asarray(nb))
            ok = np.isfinite(hag)
            n[k] = int(ok.sum())
            if n[k]:
                cover[k] = float(np.mean(hag[ok] > density.canopy_height_m))
    return cover, n


def dem_heights(dem_path, x, y):
    """Bilinear heights of a DEM GeoTIFF at x, y (its CRS's units), in its height unit; NaN off the DEM and
    next to nodata. Reads the window around the points only. Returns (heights, CRS, metres per height unit)."""
    from rasterio.windows import Window
    from scipy import ndimage

    from lidarctl.terrain.dem_io import open_dem

    x, y = np.asarray(x, float), np.asarray(y, float)
    src, z_m = open_dem(dem_path)
    with src:
        t = src.transform
        col, row = (x - t.c) / t.a - 0.5, (y - t.f) / t.e - 0.5
        inside = (col >= -0.5) & (col <= src.width - 0.5) & (row >= -0.5) & (row <= src.height - 0.5)
        out = np.full(len(x), np.nan)
        if inside.any():
            c0, r0 = max(int(np.floor(col[inside].min())), 0), max(int(np.floor(row[inside].min())), 0)
            c1 = min(int(np.floor(col[inside].max())) + 2, src.width)
            r1 = min(int(np.floor(row[inside].max())) + 2, src.height)
            a = src.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True).astype(float).filled(np.nan)
            # the outer half cell takes the edge cell's value; a nodata neighbour makes the height NaN
            rr = np.clip(row[inside] - r0, 0, a.shape[0] - 1)
            cc = np.clip(col[inside] - c0, 0, a.shape[1] - 1)
            out[inside] = ndimage.map_coordinates(a, [rr, cc], order=1, mode="nearest")
        return out, src.crs, z_m


def abs_bin_labels(edges=ABS_BIN_EDGES_M) -> list[str]:
    return _edge_labels([0.0, *edges, np.inf], "|dz|")


def _stats_document(dz: np.ndarray, exclude_m: float, abs_edges=ABS_BIN_EDGES_M) -> dict:
    """dz statistics (metres) as height_check.json holds them: bins, |dz| bins, all, without |dz| > exclude_m."""
    dz = dz[np.isfinite(dz)]
    counts = bin_counts(dz, BIN_EDGES_M)
    abs_counts = bin_counts(np.abs(dz), [0.0, *abs_edges, np.inf])
    kept = dz[np.round(np.abs(dz), BIN_RESOLUTION_DECIMALS) <= exclude_m]  # as the |dz| bins: as printed
    n = len(dz)

    def block(d):
        return {"n": int(len(d)),
                "mean_dz_m": float(np.mean(d)) if len(d) else None,
                "mean_abs_dz_m": float(np.mean(np.abs(d))) if len(d) else None,
                "rmse_m": float(np.sqrt(np.mean(d * d))) if len(d) else None}

    return {
        "bins": [{"bin_m": lab, "count": int(c), "percent": 100.0 * c / n if n else 0.0}
                 for lab, c in zip(bin_labels(), counts)],
        "abs_bins": [{"abs_dz_m": lab, "count": int(c), "percent": 100.0 * c / n if n else 0.0}
                     for lab, c in zip(abs_bin_labels(abs_edges), abs_counts)],
        "all": block(dz),
        "excluded_beyond_m": exclude_m,
        "without_excluded": block(kept),
    }


def _cloud_check_document(gx, gy, gz, points: SurveyedPoints, *, radius_m: float = 5.0, exclude_m: float = 1.0,
                          units: LengthUnits = METRE) -> dict:
    """dz statistics of surveyed ``points`` against ground points (gx, gy, gz), all in metres, as the cloud's part
    of height_check.json.

    ``units``: the CRS's units, in which the per-point coordinates are reported (the points as read,
    ``read_points_csv``, scaled by ``units`` to metres give ``points``)."""
    z_lidar, n_used = ground_height_at(gx, gy, gz, points.x, points.y, radius_m=radius_m)
    dz = z_lidar - points.z
    xs, ys = units.xy_from_m(np.asarray(points.x)), units.xy_from_m(np.asarray(points.y))
    zs, zl_crs = units.z_from_m(np.asarray(points.z)), units.z_from_m(z_lidar)
    per_point = [{"id": i, "x": float(x), "y": float(y), "z_survey": float(z),
                  "z_lidar": None if not np.isfinite(zl) else float(zl),
                  "dz_m": None if not np.isfinite(d) else float(d), "n_ground": int(nu),
                  "group": (points.group[k] if points.group else None)}
                 for k, (i, x, y, z, zl, d, nu) in enumerate(zip(points.ids, xs, ys, zs, zl_crs, dz, n_used))]
    result = {"radius_m": radius_m, **units.as_dict(), "n_points": len(dz),
              "n_without_ground": int(np.sum(~np.isfinite(dz))),
              "overall": _stats_document(dz, exclude_m), "points": per_point, "groups": {}}
    if points.group:
        result["groups"] = _group_stats_document(dz, points.group, exclude_m)
    return result


def group_order(labels) -> list[str]:
    """The groups present: open, sparse, dense, unknown in that order for density groups, else sorted."""
    present = set(labels)
    if present <= set(DENSITY_ORDER):
        return [g for g in DENSITY_ORDER if g in present]
    return sorted(present)


def _group_stats_document(dz: np.ndarray, labels, exclude_m: float) -> dict:
    """``_stats_document`` per group (``group_order``), as height_check.json holds them, with ``n_points``: the
    group's points, those without a dz (off the data, no ground in range) included (the statistics' n leaves them
    out)."""
    labels_a = np.array(labels)
    return {g: {**_stats_document(dz[labels_a == g], exclude_m), "n_points": int((labels_a == g).sum())}
            for g in group_order(labels)}


def _without_dz(s: dict) -> str:
    """"k of n points without a dz" for a group some of whose points have none, else ""."""
    k = s.get("n_points", s["all"]["n"]) - s["all"]["n"]
    return f"{k} of {s['n_points']} points without a dz (no statistics from them)" if k > 0 else ""


def _near_points(px_m, py_m, radius_m: float):
    """A function (x, y) -> mask of the points within ``radius_m`` of any of (px_m, py_m)."""
    tree = cKDTree(np.column_stack([px_m, py_m]))
    lo = np.array([np.min(px_m), np.min(py_m)]) - radius_m
    hi = np.array([np.max(px_m), np.max(py_m)]) + radius_m

    def near(x, y):
        mask = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        k = np.flatnonzero(mask)
        if len(k):
            d, _ = tree.query(np.column_stack([x[k], y[k]]), distance_upper_bound=radius_m)
            mask[k] = d <= radius_m
        return mask

    return near


def check_heights_file(cloud_paths, points_csv, *, radius_m: float = 5.0, exclude_m: float = 1.0, crs=None,
                       dem_path=None, grouping: str = "auto", density: DensityGroups | None = None,
                       dem_z_unit: str | None = None) -> HeightCheck:
    """Height check of surveyed points (CSV id,x,y,z[,group], in the CRS and units of the cloud, or of the
    DEM without a cloud) against the ground (class 2) of a classified LAS/LAZ file or of several strips
    (one CRS and unit, else an InputError naming the strip; ``crs`` only for files without CRS), and/or
    against the DEM GeoTIFF ``dem_path`` (same horizontal CRS as the cloud).

    ``grouping``: ``column`` (the CSV's group column), ``density`` (open / sparse / dense canopy from the
    cloud's first returns, ``density``), ``none``, or ``auto`` (the column when there is one). The strips are
    read by chunks and only the returns near a surveyed point are kept (memory set by the chunk).

    ``dem_z_unit`` ('m', 'ft', 'us-ft'; ``--dem-z-unit``): the DEM's height unit when the file declares none (no
    vertical CRS, no band unit or VERTICAL_UNITS tag); without it such heights are taken in the CRS's horizontal
    unit, and the console, ``dem.z_unit_note`` and the report's row say so.

    Returns the typed record (what the accuracy report reads back from the file) and the JSON document."""
    doc = _height_check_document(cloud_paths, points_csv, radius_m=radius_m, exclude_m=exclude_m, crs=crs,
                                 dem_path=dem_path, grouping=grouping, density=density, dem_z_unit=dem_z_unit)
    return HeightCheck(_record_of(doc), doc)


@dataclasses.dataclass(frozen=True)
class DemHeightsUnit:
    """The unit the DEM's heights are read in (``unit_m``, metres per unit) and, when the file does not declare it,
    the note that says where it came from (None: declared by the file)."""

    unit_m: float
    note: str | None
    # the CRS's horizontal unit is not the metre: the unit taken for the heights decides the figures (metres under
    # a metric CRS is the usual case: the note stays on the console and in height_check.json, not in the report)
    consequential: bool = False


DEM_Z_UNITS = ("m", "ft", "us-ft")


def _dem_height_unit(dem_path, dem_z_unit: str | None) -> DemHeightsUnit:
    """The DEM's height unit: the file's (vertical CRS, band unit, VERTICAL_UNITS), else ``dem_z_unit``, else the
    CRS's horizontal unit, said on the console and in the note (metres under a feet CRS were read as feet without a
    word: RMSE 0.046 m "meets QL0" for a true 0.150 m that fails QL2). A ``dem_z_unit`` against the file's own is
    refused: the file's statement and the option cannot both be right."""
    from lidarctl.terrain.dem_io import open_dem_unit

    def units(unit_m):  # "international feet (0.3048 m)": a plural for a sentence, the factor for the feet
        name = {"metre": "metres", "foot": "international feet", "US survey foot": "US survey feet"}.get(
            length_unit_name(unit_m, long=True), length_unit_name(unit_m, long=True))
        return name if unit_m == 1.0 else f"{name} ({unit_m:.7g} m)"

    if dem_z_unit is not None and dem_z_unit not in DEM_Z_UNITS:
        raise OptionError(f"--dem-z-unit {dem_z_unit!r}: expected one of {', '.join(DEM_Z_UNITS)}",
                          param="--dem-z-unit")
    src, unit = open_dem_unit(dem_path)
    src.close()
    name = Path(dem_path).name
    given_m = HEADER_UNIT_M[dem_z_unit] if dem_z_unit is not None else None
    if unit.declared:
        if given_m is not None and abs(given_m - unit.unit_m) > 1e-12:
            raise OptionError(f"--dem-z-unit {dem_z_unit}: {dem_path} declares its heights in "
                              f"{units(unit.unit_m)} (its vertical CRS, band unit or "
                              "VERTICAL_UNITS tag); leave the option out, or mend the file", param="--dem-z-unit")
        return DemHeightsUnit(unit.unit_m, None)
    horizontal = units(unit.horizontal_unit_m)
    consequential = unit.horizontal_unit_m != 1.0
    if given_m is not None:
        note = (f"{name} declares no vertical unit: its heights were taken in "
                f"{units(given_m)} as --dem-z-unit {dem_z_unit} states (its CRS is in "
                f"{horizontal})")
        log.info("%s: heights in %s as --dem-z-unit states (the file declares no vertical unit)", dem_path,
                 units(given_m))
        return DemHeightsUnit(given_m, note, consequential)
    if unit.unit_m == 1.0:  # metres under a metric CRS: the usual case, said briefly
        note = f"{name} declares no vertical unit: heights taken in metres, as its CRS's axes"
        log.info("%s", note.replace(name, str(dem_path), 1))
        return DemHeightsUnit(unit.unit_m, note)
    note = (f"{name} declares no vertical unit (no vertical CRS, no VERTICAL_UNITS tag): its heights were taken "
            f"in its CRS's horizontal unit, {horizontal}; if they are in another unit, give check-heights "
            f"--dem-z-unit (m, ft, us-ft) or tag the raster (gdal_edit -mo VERTICAL_UNITS=metre)")
    log.warning("%s", note.replace(name, str(dem_path), 1))
    return DemHeightsUnit(unit.unit_m, note, consequential)


def _height_check_document(cloud_paths, points_csv, *, radius_m, exclude_m, crs, dem_path, grouping,
                           density, dem_z_unit=None) -> dict:
    """height_check.json's content (``check_heights_file``)."""
    if not (np.isfinite(radius_m) and radius_m > 0):
        raise OptionError(f"--radius-m {radius_m}: must be a positive distance in metres", param="--radius-m")
    if not (np.isfinite(exclude_m) and exclude_m > 0):
        raise OptionError(f"--exclude-m {exclude_m}: must be a positive height difference in metres", param="--exclude-m")
    if grouping not in GROUPINGS:
        raise OptionError(f"--groups {grouping!r}: expected one of {', '.join(GROUPINGS)}", param="--groups")
    density = density or DensityGroups()
    density.validate()
    paths = [] if cloud_paths is None else (
        [cloud_paths] if isinstance(cloud_paths, (str, Path)) else list(cloud_paths))
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    if not paths and dem_path is None:
        raise OptionError("nothing to check: give the classified cloud(s) before POINTS_CSV, --dem DEM.tif, or both",
                          param="--dem")
    points = read_points_csv(points_csv)
    if grouping == "auto":
        grouping = "column" if points.group is not None else "none"
    if grouping == "column" and points.group is None:
        raise OptionError(f"--groups column: {points_csv} has no group column (expected one of "
                          f"{', '.join(GROUP_COLUMNS)})", param="--groups")
    if grouping == "density" and not paths:
        raise OptionError("--groups density: the vegetation density comes from the cloud's first returns; give the "
                          "classified cloud(s) before POINTS_CSV", param="--groups")
    with_density = grouping == "density"
    dem_unit = _dem_height_unit(dem_path, dem_z_unit) if dem_path is not None else None
    if paths:
        box, unit = [np.inf, np.inf, -np.inf, -np.inf], ""
        for path, header, _, units in io.checked_headers(paths, crs):
            box = [min(box[0], header.mins[0]), min(box[1], header.mins[1]), max(box[2], header.maxs[0]),
                   max(box[3], header.maxs[1])]
            unit = units.xy_name
            if not units.z_declared and units.z_m != 1.0:
                # as for the DEM (trial-audit F2): heights in metres under a foot CRS are read 3.28 x too small
                # a vertical key beside a WKT record is not read (LAS 1.4: the WKT is the CRS); said so, not "no key"
                # (trial s94, laspy's Nebraska file: its keys hold US feet, the message said it had none)
                why = ("its CRS record, a WKT, is 2D; the GeoTIFF vertical keys beside it are not read, as LAS 1.4 "
                       "makes the WKT the CRS" if las.vertical_keys_beside_wkt(header)
                       else "a 2D CRS, no VerticalUnitsGeoKey")
                log.warning("%s: declares no height unit (%s): its heights are taken in its CRS's horizontal unit, %s; "
                            "if they are metres, give the cloud a compound CRS (aerotri crs transform --to "
                            "'EPSG:<grid>+<vertical>')", path, why, length_unit_name(units.z_m, long=True))
        points = points.in_crs_units(units, points_csv)  # (the strips' one CRS and unit: checked_headers)
        _refuse_points_elsewhere(points, points_csv, box, ", ".join(map(str, paths)), unit)
    elif dem_path is not None:
        from lidarctl.terrain.dem_io import open_dem
        from lidarctl.units import units_of

        src, _ = open_dem(dem_path)
        with src:
            b = src.bounds
        _, dem_crs, _ = dem_heights(dem_path, points.x[:1], points.y[:1])
        points = points.in_crs_units(units_of(dem_crs, source=str(dem_path), vertical_unit_m=dem_unit.unit_m),
                                     points_csv)
        _refuse_points_elsewhere(points, points_csv, [b.left, b.bottom, b.right, b.top], str(dem_path), "CRS units")

    cloud = _read_near(paths, points, radius_m, density.radius_m if with_density else None, crs) if paths else None
    if cloud is not None:
        crs_found, u = cloud["crs"], cloud["units"]
    else:
        from lidarctl.units import units_of

        _, crs_found, _ = dem_heights(dem_path, points.x[:1], points.y[:1])
        u = units_of(crs_found, source=str(dem_path), vertical_unit_m=dem_unit.unit_m)
    points_m = points.in_metres(u)

    z_dem = dz_dem = dem_z_m = None
    if dem_path is not None:
        z_dem, dem_crs, _ = dem_heights(dem_path, points.x, points.y)
        dem_z_m = dem_unit.unit_m
        if cloud is not None and crs_found is not None:
            from aerotri.core.errors import CrsError
            from aerotri.geom.crs.definition import same_horizontal

            if not same_horizontal(dem_crs, crs_found):
                raise CrsError(f"{dem_path}: the DEM's CRS ({dem_crs}) is not the cloud's ({crs_found.name}); "
                               "reproject one of them (aerotri crs warp / transform)")
        dz_dem = z_dem * dem_z_m - points_m.z

    cover = n_first = None
    if with_density:
        fx, fy, fz = cloud["first"]
        if dem_path is not None:
            f_dem, _, _ = dem_heights(dem_path, u.xy_from_m(fx), u.xy_from_m(fy))
            hag = fz - f_dem * dem_z_m

            def hag_of(k, idx):
                return hag[idx]
        else:
            gx, gy, gz = cloud["ground"]
            z0, _, sxy = ground_height_at(gx, gy, gz, points_m.x, points_m.y, radius_m=density.radius_m,
                                          slopes=True)

            def hag_of(k, idx):
                return fz[idx] - (z0[k] + sxy[k, 0] * (fx[idx] - points_m.x[k]) + sxy[k, 1] * (fy[idx] - points_m.y[k]))
        cover, n_first = canopy_cover(fx, fy, points_m.x, points_m.y, hag_of, density)
        points_m = dataclasses.replace(points_m, group=tuple(density.label(cover)))
    elif grouping == "none":
        points_m = dataclasses.replace(points_m, group=None)

    if cloud is not None:
        result = _cloud_check_document(*cloud["ground"], points_m, radius_m=radius_m, exclude_m=exclude_m, units=u)
    else:
        xs, ys, zs = points.x, points.y, points.z
        result = {"radius_m": None, **u.as_dict(), "n_points": len(xs), "n_without_ground": None, "overall": None,
                  "groups": {}, "points": [{"id": i, "x": float(a), "y": float(b), "z_survey": float(c),
                                            "group": points_m.group[k] if points_m.group else None}
                                           for k, (i, a, b, c) in enumerate(zip(points.ids, xs, ys, zs))]}
    result["crs"] = crs_found.to_string() if crs_found is not None else None
    result["grouping"] = grouping
    result["abs_bin_edges_m"] = list(ABS_BIN_EDGES_M)
    if with_density:
        result["density"] = dataclasses.asdict(density)
        for p, c, n in zip(result["points"], cover, n_first):
            p["canopy_cover"] = None if not np.isfinite(c) else float(c)
            p["first_returns"] = int(n)
    if dem_path is not None:
        labels = points_m.group
        # absolute: the report reads it from another working folder than the one the command ran in
        result["dem"] = {"path": str(Path(dem_path).resolve()), "z_unit_m": dem_z_m,
                         "z_unit_note": dem_unit.note, "z_unit_consequential": dem_unit.consequential,
                         "n_points": len(dz_dem),
                         "n_without_dem": int(np.sum(~np.isfinite(dz_dem))),
                         "overall": _stats_document(dz_dem, exclude_m),
                         "groups": _group_stats_document(dz_dem, labels, exclude_m) if labels else {}}
        for p, zd, d in zip(result["points"], z_dem, dz_dem):
            p["z_dem"] = None if not np.isfinite(zd) else float(zd)
            p["dz_dem_m"] = None if not np.isfinite(d) else float(d)
    # which surface the top-level overall / groups are of: the DEM's when it was checked alone (they were null and
    # {} with the figures under dem.overall only: a reader of overall.all.rmse_m, as for a cloud, got nothing)
    result["overall_surface"] = "cloud" if cloud is not None else "dem"
    if cloud is None:
        result["overall"], result["groups"] = result["dem"]["overall"], result["dem"]["groups"]
    # each surface's dz per point (NaN: not checked), the cloud's first
    surfaces = [(what, np.array([np.nan if p.get(key) is None else p[key] for p in result["points"]], float))
                for key, what in (("dz_m", "cloud"), ("dz_dem_m", "DEM")) if key in result["points"][0]]
    if points.z_unit is None:  # the header names no unit (a plain z): the CRS's unit was assumed
        for what, dz in surfaces:
            if slip := unit_slip(dz, points_m.z, u.z_m, points.z_column):
                result["unit_slip"] = {**slip, "surface": what}
                break
    if "unit_slip" not in result:
        for what, dz in surfaces:
            if slip := surface_unit_slip(dz, points_m.z):
                result["surface_unit_slip"] = {**slip, "surface": what}
                break
    if "unit_slip" not in result and "surface_unit_slip" not in result:
        for what, dz in surfaces:
            if offset := constant_offset(dz):
                result["constant_offset"] = {**offset, "surface": what}
                break
    return result


# the surface's heights read in metres when they were (name, factor to metres of what was read): feet, metres read as
# feet (a DEM in metres under a grid in feet that declares no unit), centimetres (an integer DEM)
SURFACE_UNIT_SLIPS = (("feet", las.FOOT_M), ("metres read as feet", 1.0 / las.FOOT_M), ("centimetres", 0.01))


def surface_unit_slip(dz_m: np.ndarray, z_points_m: np.ndarray) -> dict | None:
    """Whether the surface's heights (``dz_m`` + ``z_points_m``, as read, metres) fit the survey if they were in
    another unit (``SURFACE_UNIT_SLIPS``): the median |dz| beyond ``UNIT_SLIP_MIN_M`` and, in that unit, below
    ``UNIT_SLIP_FRACTION`` of it; None otherwise. Trial s99 lidmut M2: a DEM in feet read as metres was "a nearly
    constant +707 m: two height systems (the geoid)", an integer DEM in centimetres RMSE 1,821 m with no word."""
    for unit, factor in SURFACE_UNIT_SLIPS:
        fits = _fits_in_other_unit(dz_m, z_points_m, surface_factor=factor, min_points=3)
        if fits is not None:
            return {"median_abs_dz_m": fits[0], "median_abs_dz_other_unit_m": fits[1], "unit": unit, "factor": factor}
    return None


def _fits_in_other_unit(dz_m: np.ndarray, z_points_m: np.ndarray, *, surface_factor: float = 1.0,
                        points_factor: float = 1.0, min_points: int = 1) -> tuple[float, float] | None:
    """(median |dz|, median |dz| with the surface's heights times ``surface_factor`` and the survey's times
    ``points_factor``) when the first is beyond ``UNIT_SLIP_MIN_M`` and the second below ``UNIT_SLIP_FRACTION`` of it
    (``dz_m``: surface - survey, metres, NaN not checked; at least ``min_points`` checked); None otherwise."""
    ok = np.isfinite(dz_m)
    if np.count_nonzero(ok) < min_points:
        return None
    med = float(np.median(np.abs(dz_m[ok])))
    if med <= UNIT_SLIP_MIN_M:
        return None
    surface = dz_m[ok] + z_points_m[ok]
    med_other = float(np.median(np.abs(surface * surface_factor - z_points_m[ok] * points_factor)))
    return (med, med_other) if med_other < UNIT_SLIP_FRACTION * med else None


def constant_offset(dz_m: np.ndarray) -> dict | None:
    """A height offset common to every point (``dz_m``: surface - survey, metres; NaN: not checked): the median dz
    beyond ``UNIT_SLIP_MIN_M`` and their spread (1.4826 MAD) within ``UNIT_SLIP_FRACTION`` of it, at least 3 points;
    else None. New-user trial s94: heights above ground (a normalised cloud) against elevations gave RMSE 2,149.993 m
    on every point and the report said nothing of why."""
    ok = dz_m[np.isfinite(dz_m)]
    if len(ok) < 3:
        return None
    med = float(np.median(ok))
    spread = 1.4826 * float(np.median(np.abs(ok - med)))
    if abs(med) <= UNIT_SLIP_MIN_M or spread >= UNIT_SLIP_FRACTION * abs(med):
        return None
    return {"median_dz_m": med, "spread_m": spread, "n": int(len(ok))}


# A plain z (no unit in the header) is taken in the CRS's vertical unit. Surveyed heights in metres against a cloud
# in feet (trial: Autzen, EPSG:2994) differed by a median 90 m, every point over 5 m, and nothing said why: when the
# median |dz| exceeds UNIT_SLIP_MIN_M and the heights taken in the other unit (metres for a cloud in feet, feet for
# one in metres) bring it below UNIT_SLIP_FRACTION of it, the report says so and names the header to use.
UNIT_SLIP_MIN_M = 5.0
UNIT_SLIP_FRACTION = 0.1


def unit_slip(dz_m: np.ndarray, z_points_m: np.ndarray, z_unit_m: float, z_column: str | None) -> dict | None:
    """Whether surveyed heights under a header without a unit fit if they were in the other unit: ``dz_m`` (surface -
    survey, metres; NaN: not checked), ``z_points_m`` (the survey's heights as read, metres), ``z_unit_m`` (metres
    per unit of the CRS's heights, the unit assumed). Returns the medians, the unit that fits and the header that
    names it, or None."""
    if z_unit_m == 1.0:  # a metric CRS: were the numbers feet?
        other, factor, suffix = "feet", las.FOOT_M, "ft"
    else:  # a CRS in feet: were they metres?
        other, factor, suffix = "metres", 1.0 / z_unit_m, "m"
    fits = _fits_in_other_unit(dz_m, z_points_m, points_factor=factor)
    if fits is None:
        return None
    med, med_other = fits
    base = z_column or "z"  # (a header without a unit suffix: with one, the heights' unit is not assumed)
    return {"median_abs_dz_m": med, "median_abs_dz_other_unit_m": med_other, "other_unit": other,
            "assumed_unit": length_unit_name(z_unit_m, long=True), "column": z_column or "z",
            "header": f"{base}_{suffix}" + (f" (US survey feet: {base}_usft)" if suffix == "ft" else "")}


def _refuse_points_elsewhere(points, points_csv, box, what: str, unit: str) -> None:
    """InputError when no surveyed point lies within ``box`` (xmin, ymin, xmax, ymax of the clouds or the DEM):
    points of another zone, CRS or unit would otherwise be reported as "no ground" one by one."""
    x, y = np.asarray(points.x, float), np.asarray(points.y, float)
    inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
    if not inside.any():
        raise InputError(f"{points_csv}: none of its {len(x)} points lies within the extent of {what} (x {box[0]:.1f} "
                         f".. {box[2]:.1f}, y {box[1]:.1f} .. {box[3]:.1f} {unit}); the points must be in its CRS and "
                         "units")


def _read_near(paths, points, radius_m: float, density_radius_m: float | None, crs) -> dict:
    """The ground points (class 2, and road surface 11 of a LAS 1.4 file: ``io.ground_classes``) within ``radius_m`` (and ``density_radius_m``) of a surveyed point and, with
    ``density_radius_m``, the first returns (noise excluded) within it; metres. Streamed by chunks."""
    ground, first_returns, first, n_ground = [], [], None, 0
    reach = max(radius_m, density_radius_m or 0.0)
    for path, _, crs_i, units in io.checked_headers(paths, crs):
        if first is None:
            first = (path, crs_i, units)
            near = _near_points(units.xy_to_m(points.x), units.xy_to_m(points.y), reach)
        # ground and road surface (11, in LAS 1.4): where a surveyed point on a road meets the surface; not water
        on_ground = [c for c in io.ground_classes(las.read_header(path)) if c != io.WATER]
        for first_record, chunk in las.iter_file_chunks(path, io.CHUNK_POINTS):
            cx, cy, cz = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            io.validate_xyz(path, cx, cy, cz, first_record, units)
            cls = np.asarray(chunk.classification)
            g = np.isin(cls, on_ground)
            n_ground += int(g.sum())
            gx, gy = units.xy_to_m(cx[g]), units.xy_to_m(cy[g])
            keep = near(gx, gy)
            ground.append((gx[keep], gy[keep], units.z_to_m(cz[g][keep])))
            if density_radius_m is not None:
                rn, _ = io.sanitize_returns(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
                f = (rn <= 1) & ~np.isin(cls, (7, 18))
                fx, fy = units.xy_to_m(cx[f]), units.xy_to_m(cy[f])
                keep = near(fx, fy)
                first_returns.append((fx[keep], fy[keep], units.z_to_m(cz[f][keep])))
    if not n_ground:
        raise InputError(f"{', '.join(map(str, paths))}: no ground points (class 2 or 11); run 'lidarctl classify' first")
    out = {"crs": first[1], "units": first[2],
           "ground": tuple(np.concatenate([gr[k] for gr in ground]) for k in range(3))}
    if density_radius_m is not None:
        out["first"] = tuple(np.concatenate([fr[k] for fr in first_returns]) for k in range(3))
    return out


def _format_block(title: str, s: dict) -> list[str]:
    lines = [title, f"  {'error bin (m)':<20}{'count':>8}{'percent':>10}"]
    for b in s["bins"]:
        lines.append(f"  {b['bin_m']:<20}{b['count']:>8}{b['percent']:>9.1f}%")

    def fmt(v):
        return "-" if v is None else f"{v:.3f}"

    a, w = s["all"], s["without_excluded"]
    lines.append(f"  n = {a['n']}  mean |dz| = {fmt(a['mean_abs_dz_m'])} m  RMSE = {fmt(a['rmse_m'])} m"
                 f"  mean dz = {fmt(a['mean_dz_m'])} m")
    lines.append(f"  without |dz| > {s['excluded_beyond_m']:g} m: n = {w['n']}  mean |dz| = "
                 f"{fmt(w['mean_abs_dz_m'])} m  RMSE = {fmt(w['rmse_m'])} m")
    return lines


def _group_table(title: str, overall: dict, groups: dict) -> list[str]:
    """Seed 004 Tab. 1: per group the share of points in each |dz| bin, mean |dz|, RMSE and the count."""
    labels = [b["abs_dz_m"] for b in overall["abs_bins"]]
    w = max(12, *(len(lab) + 2 for lab in labels))  # the labels state their closed end ("0.3 < |dz| <= 0.5")
    head = f"  {'group':<10}{'n':>6}" + "".join(f"{lab:>{w}}" for lab in labels) + f"{'mean |dz|':>11} {'RMSE':>9}"
    lines = [title + " (|dz| bins in m: percent of points; mean |dz| and RMSE in m)", head]
    for name, s in [*groups.items(), ("all", overall)]:
        a = s["all"]
        fmt = (lambda v: "-" if v is None else f"{v:.3f}")
        bins = ("".join(f"{b['percent']:>{w - 1}.1f}%" for b in s["abs_bins"]) if a["n"]
                else "".join(f"{'-':>{w}}" for _ in s["abs_bins"]))  # no dz: no share of anything
        note = _without_dz(s)
        lines.append(f"  {name:<10}{a['n']:>6}" + bins + f"{fmt(a['mean_abs_dz_m']):>11} {fmt(a['rmse_m']):>9}"
                     + (f"  ({note})" if note else ""))
    return lines


def format_report(check: HeightCheck) -> str:
    """The height check table; statistics in metres, heights in the CRS's vertical unit (named), dz
    in metres and, for a cloud in feet, also in feet."""
    result = check.document
    zu = result.get("z_unit", "m")
    z_unit_m = result.get("z_unit_m", 1.0)
    dem = result.get("dem")
    has_lidar = cloud_checked(result)
    lines = []
    if has_lidar:
        lines += ["LiDAR height check (dz = Z_lidar - Z_surveyed, in metres)",
                  f"search radius {result['radius_m']:g} m, {result['n_points']} points, "
                  f"{result['n_without_ground']} without ground points in range", ""]
        if zu != "m":
            lines[-1:-1] = [f"heights in {zu} (the cloud's vertical unit); dz and statistics in m"]
        lines += _format_block("All points", result["overall"])
        for g, s in result["groups"].items():
            lines += [""] + _format_block(f"Group: {g}" + (f" ({_without_dz(s)})" if _without_dz(s) else ""), s)
    if dem is not None:
        lines += ([""] if lines else []) + [
            f"DEM height check (dz = Z_dem - Z_surveyed, in metres): {dem['path']}, {dem['n_points']} points, "
            f"{dem['n_without_dem']} off the DEM or next to nodata", ""]
        if dem.get("z_unit_note"):  # its heights' unit was not the file's own statement
            lines[-1:-1] = [f"note: {dem['z_unit_note']}"]
        lines += _format_block("All points (DEM)", dem["overall"])
        for g, s in dem["groups"].items():
            lines += [""] + _format_block(f"Group: {g} (DEM" + (f"; {_without_dz(s)})" if _without_dz(s) else ")"), s)
    if result.get("density"):
        d = result["density"]
        lines += ["", f"groups by canopy cover (first returns more than {d['canopy_height_m']:g} m above the ground "
                  f"within {d['radius_m']:g} m): open < {d['open_below']:.0%}, sparse up to {d['dense_above']:.0%}, "
                  "dense above"]
    if has_lidar:
        lines += [""] + _group_table("Ground points by group", result["overall"], result["groups"])
    if dem is not None:
        lines += [""] + _group_table("DEM by group", dem["overall"], dem["groups"])
    head = f"{'id':<12}{'group':<18}{f'z survey ({zu})':>16}"
    if has_lidar:
        head += f" {f'z lidar ({zu})':>16} {'dz (m)':>9}"
        if zu != "m":
            head += f" {f'dz ({zu})':>10}"
    if dem is not None:
        head += f" {'z dem':>12} {'dz dem (m)':>12}"
    lines += ["", head]
    for p in result["points"]:
        line = f"{p['id']:<12}{(p['group'] or ''):<18}{p['z_survey']:>16.3f}"
        if has_lidar:
            zl = "-" if p["z_lidar"] is None else f"{p['z_lidar']:.3f}"
            dz = "-" if p["dz_m"] is None else f"{p['dz_m']:+.3f}"
            # a space between columns: a dz of metres or more filled its column and ran into the next (trial s94)
            line += f" {zl:>16} {dz:>9}"
            if zu != "m":
                line += f" {'-' if p['dz_m'] is None else format(p['dz_m'] / z_unit_m, '+.3f'):>10}"
        if dem is not None:
            line += f" {'-' if p['z_dem'] is None else format(p['z_dem'], '.3f'):>12}"
            line += f" {'-' if p['dz_dem_m'] is None else format(p['dz_dem_m'], '+.3f'):>12}"
        lines.append(line)
    tables = len(lines)  # the warnings below go before the tables (trial s96 F14: read after 40 lines of them)
    if dem is not None and dem["n_points"] and dem["n_without_dem"] > dem["n_points"] / 2:
        # first: points of another grid land km away, and the few left on the DEM read as a height datum's offset
        # (trial s96 F7: CGCS2000 GK CM 111E points on a UTM 49N DEM, 24 of 30 off it, "two height systems")
        lines += ["", f"warning: {dem['n_without_dem']} of {dem['n_points']} points lie off the DEM or next to its "
                  "nodata: are their x, y in another CRS, zone or grid than the DEM's (a Gauss-Kruger zone's "
                  "coordinates on a UTM DEM land kilometres away)? The points must be in the DEM's CRS and units "
                  "(aerotri crs transform); the figures above are of the few that fell on it"]
    offset = result.get("constant_offset")
    if offset:
        lines += ["", f"warning: the {offset['surface']} and the surveyed heights differ by a nearly constant "
                  f"{offset['median_dz_m']:+.3f} m on the {offset['n']} points checked (spread "
                  f"{offset['spread_m']:.3f} m): "
                  "two height systems (ellipsoidal against orthometric heights differ by the geoid, tens of metres; "
                  "another vertical datum), or a cloud of heights above the ground (normalised)? The RMSE measures "
                  "that offset, not the surface's accuracy"]
    sslip = result.get("surface_unit_slip")
    if sslip:
        how = ("give --dem-z-unit, or tag the DEM (gdal_edit.py -mo VERTICAL_UNITS=...)" if sslip["surface"] == "DEM"
               else "give the cloud a CRS whose vertical unit is right (--crs)")
        lines += ["", f"warning: the {sslip['surface']} and the surveyed heights differ by a median |dz| of "
                  f"{sslip['median_abs_dz_m']:.3f} m, but by {sslip['median_abs_dz_other_unit_m']:.3f} m if the "
                  f"{sslip['surface']}'s heights were {sslip['unit']} (x {sslip['factor']:.6g}): its height unit is "
                  f"wrong, not the datum; {how}" + ("" if sslip["unit"] != "centimetres" else
                                                   " (centimetres: convert it, gdal_calc.py --calc \"A*0.01\")")]
    slip = result.get("unit_slip")
    if slip:
        lines += ["", f"warning: the {slip['surface']} and the surveyed heights differ by a median |dz| of "
                  f"{slip['median_abs_dz_m']:.3f} m, but by {slip['median_abs_dz_other_unit_m']:.3f} m if the surveyed "
                  f"heights were {slip['other_unit']}: the header's '{slip['column']}' names no unit, so they were "
                  f"taken in the CRS's ({slip['assumed_unit']}); if they are {slip['other_unit']}, name the column "
                  f"{slip['header']}"]
    warns = [ln for ln in lines[tables:] if ln.startswith("warning: ")]
    if warns:
        lines = warns + [""] + lines[:tables]
    return "\n".join(lines)


HEIGHT_CHECK = "LiDAR height check (height_check.json)"
# the chain's height_check stage stamp: bump when its numbers change at the same inputs (2: the bins count dz as
# printed, an edge in the bin nearer zero, trial-audit F9)
HEIGHT_CHECK_VERSION = 2


@dataclasses.dataclass(frozen=True)
class HeightCheckRecord:
    """What ``height_check.json`` tells the accuracy report and the chain (metres)."""

    n_checked: int | None  # surveyed points with ground in reach (None: the cloud was not checked)
    rmse_m: float | None
    dz_m: tuple[float, ...]  # Z_lidar - Z_surveyed per point with ground in reach
    bins: list | None  # counts per dz bin as written (``_stats_document``)
    groups: dict  # group -> statistics as written
    mean_abs_dz_m: float | None = None
    dem_n_checked: int | None = None  # surveyed points on valid DEM cells (None: no DEM was checked)
    dem_rmse_m: float | None = None
    dem_dz_m: tuple[float, ...] = ()  # Z_dem - Z_surveyed per point on valid DEM cells
    dem_path: str | None = None
    dz_groups: tuple[str | None, ...] = ()  # the group of each dz_m (check-heights --groups), None without one
    dem_dz_groups: tuple[str | None, ...] = ()  # the group of each dem_dz_m
    outside_ids: tuple[str, ...] = ()  # the points without ground in reach (not in dz_m)
    dem_outside_ids: tuple[str, ...] = ()  # the points off the DEM's valid cells (not in dem_dz_m; a DEM checked)
    outside_groups: tuple[str | None, ...] = ()  # the group of each outside_ids point
    dem_outside_groups: tuple[str | None, ...] = ()  # the group of each dem_outside_ids point
    radius_m: float | None = None  # the search radius for ground points (check-heights --radius-m)
    # where the DEM's height unit came from when the file declares none and its CRS is not in metres (the report's
    # row says it)
    dem_z_unit_note: str | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class HeightCheck:
    """The height check (``check_heights_file``): the typed record other stages read, and the JSON document of
    ``height_check.json`` (``to_json``; the module docstring says what its keys hold)."""

    record: HeightCheckRecord
    document: dict

    def to_json(self) -> str:
        """height_check.json's text (``lidarctl check-heights --json``, the chain's lidar_out/height_check.json)."""
        return json.dumps(self.document, indent=2)

    def __eq__(self, other) -> bool:
        return isinstance(other, HeightCheck) and self.document == other.document


def cloud_checked(d: dict) -> bool:
    """Whether height_check.json's top-level overall is the cloud's (of a DEM checked alone it is the DEM's,
    ``overall_surface`` "dem"; files written before that key hold null there)."""
    return d.get("overall") is not None and d.get("overall_surface", "cloud") == "cloud"


def _record_of(d: dict) -> HeightCheckRecord:
    overall = (d.get("overall") or {}) if cloud_checked(d) else {}
    every = overall.get("all") or {}
    dz = tuple(float(p["dz_m"]) for p in d.get("points") or [] if p.get("dz_m") is not None)
    dem = d.get("dem") or {}
    dem_all = (dem.get("overall") or {}).get("all") or {}
    dem_dz = tuple(float(p["dz_dem_m"]) for p in d.get("points") or [] if p.get("dz_dem_m") is not None)
    groups = tuple(p.get("group") for p in d.get("points") or [] if p.get("dz_m") is not None)
    dem_groups = tuple(p.get("group") for p in d.get("points") or [] if p.get("dz_dem_m") is not None)
    return HeightCheckRecord(None if "n" not in every else int(every["n"]),
                             None if every.get("rmse_m") is None else float(every["rmse_m"]), dz,
                             overall.get("bins"), dict(d.get("groups") or {}) if overall else {},
                             None if every.get("mean_abs_dz_m") is None else float(every["mean_abs_dz_m"]),
                             dem_n_checked=None if not dem else int(dem_all.get("n") or 0),
                             dem_rmse_m=None if dem_all.get("rmse_m") is None else float(dem_all["rmse_m"]),
                             dem_dz_m=dem_dz, dem_path=dem.get("path"), dz_groups=groups, dem_dz_groups=dem_groups,
                             outside_ids=tuple(str(p.get("id")) for p in d.get("points") or []
                                               if p.get("dz_m") is None) if every else (),
                             dem_outside_ids=tuple(str(p.get("id")) for p in d.get("points") or []
                                                   if p.get("dz_dem_m") is None) if dem else (),
                             outside_groups=tuple(p.get("group") for p in d.get("points") or []
                                                  if p.get("dz_m") is None) if every else (),
                             dem_outside_groups=tuple(p.get("group") for p in d.get("points") or []
                                                      if p.get("dz_dem_m") is None) if dem else (),
                             radius_m=None if d.get("radius_m") is None else float(d["radius_m"]),
                             dem_z_unit_note=dem.get("z_unit_note") if dem.get("z_unit_consequential") else None)


def read_height_check(path) -> HeightCheckRecord:
    """``height_check.json`` as ``check_heights_file`` wrote it; InputError naming the file when it is not one."""
    from aerotri.core.textio import read_record, record_error

    d = read_record(path, HEIGHT_CHECK, 1)
    try:
        return _record_of(d)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, HEIGHT_CHECK, exc) from None
