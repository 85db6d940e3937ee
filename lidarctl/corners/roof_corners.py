"""Roof corners as LiDAR ground control: detection, precision, control score, output files.

A corner is the intersection of two adjacent fitted edges of a regularised roof (eave) outline
(``lidarctl.corners.roof_outline``); its height is the roof plane of the adjacent roof face evaluated at the
corner (``lidarctl.corners.roof_segments``), i.e. the eave height. Standard deviations sx_m, sy_m come from the
edge-line adjustment, sz_m from the plane fit plus the roof slope times the horizontal uncertainty; both
include the strip georeferencing error (``sigma_strip_xy_m``, ``sigma_strip_z_m``).

Reported (corners.csv): corners whose two edges are at least ``min_edge_m`` long (default: max(2 m, 8 point
spacings), ``default_min_edge_m``: density-adaptive, so one default serves 0.3 m and 1 m spacings) and
whose horizontal sigma is below max(0.3 m, 0.4 spacing). The outlines in corners.geojson keep every traced corner.

Score for use as control (0..1, product of factors, each 1 when ideal):
  right angle (interior angle 90 or 270 deg within 10 deg), long edges (shorter edge / min_edge_m),
  well-supported edges (fewest boundary observations / ``SUPPORT_FULL_BINS``, 5), horizontal precision
  (1 / (1 + (s/0.15 m)^2)),
  flat roof (1 for pitched roofs too: an eave corner's plan position is as good, and its height sigma
  sz_m holds the slope times the plan sigma; ``score_flat`` stays in the records), open to the sky (the
  fraction of ``VIEW_SECTORS`` azimuth sectors from which the corner is seen at ``VIEW_OFF_NADIR_DEG`` off
  nadir, past trees and other roofs: ``view_openness``),
  not at the edge of a strip (the corner at least 10 m inside a strip's footprint, else 0.3).
A corner is ``usable`` as control when its score >= ``USABLE_SCORE``, its angle is within 5 deg of a right
angle (or it is a well-determined oblique corner: the angle's sigma from the edge adjustment at most 2.5 deg
and a turn of at least 30 deg; its angle factor is then 1), both edges are at least ``min_edge_m`` long and
end at corners of the outline (not where the edge lines of a neighbour meet off the traced outline) and,
with ``roof="flat"``, its roof is flat.

Units: ``find_roof_corners`` works in metres (every length above, the sigmas and the edge lengths);
``read_strips`` scales clouds in feet to metres and ``RoofCorners.in_crs_units`` writes the corner and outline
coordinates (x, y, z) back in the clouds' CRS units, so corners.csv holds coordinates in the input's
CRS (x, y in its horizontal unit, z in its vertical unit) and sigmas in metres (``_m`` columns);
corners.json names the units (``xy_unit``, ``z_unit``); ``read_corner_summary`` reads it back into the
``CornerControlResult`` ``corner_control`` returns.

Edge directions edge1_deg/edge2_deg are grid bearings (clockwise from grid north) of the incoming and
outgoing edge lines in [0, 180); angle_deg is the interior angle of the roof polygon at the corner.
"""

from __future__ import annotations

import csv
import dataclasses
from typing import ClassVar, Mapping
import io
import json
import logging
import time
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage
from scipy.spatial import cKDTree

from aerotri.core.atomic import committed, refuse_input_as_output, write_text_atomic
from aerotri.core.errors import InputError, OptionError
from aerotri.core.settings import Resolved, setting, settings_of
from aerotri.core.textio import read_record, record_error
from lidarctl import io as las_io
from lidarctl.grid import check_grid
from lidarctl.corners.roof_outline import (
    CORNER_MARGIN_SPACINGS,
    corners_from_edges,
    edge_length_m,
    edge_observations,
    fit_edges,
    regularise_rings,
    reweight_observations,
    trace_rings,
)
from lidarctl.corners.roof_segments import (SCAN_GAP_POINTS, cluster_roofs, effective_spacing_m, point_spacing_m,
                                            segment_planes)
from lidarctl.units import LengthUnits
from aerotri.core.log import track
from aerotri.core.figures import pyplot, save_png

log = logging.getLogger(__name__)

BUILDING = 6
GROUND = 2
NOISE = (7, 18)
USABLE_SCORE = 0.5
# Corners known worse than max(MAX_SIGMA_XY_M, MAX_SIGMA_XY_SPACINGS * spacing) are not reported (small
# roofs, few edge points): their edges are not determined well enough to call the intersection a corner.
MAX_SIGMA_XY_M = 0.3
MAX_SIGMA_XY_SPACINGS = 0.4
FLAT_SLOPE_DEG = 5.0
# Occlusion in the frames: a corner is seen from an azimuth sector when no tree, other roof or object
# more than OCCLUDER_MIN_DZ_M above it rises above the view ray at VIEW_OFF_NADIR_DEG off nadir (a point
# d metres away hides the corner when it stands more than d / tan(VIEW_OFF_NADIR_DEG) above it). 22.5 deg
# is the median off-nadir angle of the rays through a DMC frame (165.9 x 92.2 mm format, f = 120 mm, uniform
# over the format; quartiles 16 and 29.5 deg); the sectors are the directions the frames look from. A
# property of the camera, not fitted to any data set.
VIEW_OFF_NADIR_DEG = 22.5
VIEW_SECTORS = 8
OCCLUDER_MIN_DZ_M = 1.0
OCCLUDER_MIN_POINTS = 3
# Roof-face footprints (roof_planes.geojson) are shrunk by max(FACE_MARGIN_M, FACE_MARGIN_SPACINGS * spacing)
# so that tie points on eaves, ridges and step edges (where a face's plane no longer holds) fall outside.
FACE_MARGIN_M = 1.0
FACE_MARGIN_SPACINGS = 2.0
MIN_FACE_AREA_M2 = 4.0
# Default shortest edge of a reported corner: MIN_EDGE_SPACINGS point spacings, at least MIN_EDGE_FLOOR_M.
# Why 8: an edge of length L = N s is observed in n = N - 3 bins of one spacing (1.5 spacings left out at
# each end, roof_outline.CORNER_MARGIN_SPACINGS) spanning n s; the outermost point of a bin lies uniformly
# 0..s inside the edge (sigma s/sqrt(12)), so a line fitted to them has a direction sigma of
# (s/sqrt(12)) sqrt(12 / (n (n s)^2)) = n^-1.5 rad. N = 8 (n = 5) gives 5.1 deg: the shortest edge whose own
# direction is known to the 5 deg right-angle tolerance of a usable corner (N = 6: 11 deg, a free edge's
# direction then says nothing about the angle); the offset of a snapped edge (direction shared with the
# whole roof) is then known to s/sqrt(12 n) = 0.13 s. Why 2 m: shorter roof edges are dormer cheeks,
# chimney breasts and bay windows, not building corners, however dense the cloud. AHN3 (0.31 m spacing)
# gets 2.5 m, the simulator's demo (0.62 m) 4.9 m (the fixed default was 5 m).
MIN_EDGE_SPACINGS = 8.0
MIN_EDGE_FLOOR_M = 2.0
# The support factor is 1 when an edge has the bins an edge of the default minimum length has (5): the
# precision the edge length rule is built on. (It was 10 bins, i.e. edges of 13 spacings: the edge length
# was scored twice, once by the length factor and once by the support.)
SUPPORT_FULL_BINS = MIN_EDGE_SPACINGS - 2.0 * CORNER_MARGIN_SPACINGS
# A usable corner: a right angle within RIGHT_ANGLE_TOL_DEG, or an oblique corner whose angle is known to
# 2 sigma within that tolerance and where the outline turns by at least MIN_OBLIQUE_TURN_DEG (a flatter
# bend is no point one can identify in the images; the intersection's covariance grows as the lines meet
# at a shallower angle, and the precision factor sees that).
RIGHT_ANGLE_TOL_DEG = 5.0
MIN_OBLIQUE_TURN_DEG = 30.0
ROOF_PLANES_FILE = "roof_planes.geojson"
ROOF_OUTLINES_FILE = "roof_outlines.gpkg"  # the roof outlines as a GeoPackage (QGIS; the true ortho's footprints)
OUTLINES_TIMESTAMP = "2000-01-01T00:00:00.000Z"  # GDAL's time stamp in the GeoPackage: the same data, the same bytes

CSV_COLUMNS = [
    "id", "x", "y", "z", "sx_m", "sy_m", "sz_m", "roof", "building_id",
    "edge1_deg", "edge2_deg", "angle_deg", "support_pts", "score", "usable",
]


# The corners figure's nDSM: at most this many cells a side (a 10 km block at 2.5 m).
FIGURE_CELLS = 4000
# Memory per cell of the strip-footprint grids (masks, closing, distance transform with its
# feature transform) and of the figure's nDSM (maxima, cell centres, nearest ground, result).
MARGIN_BYTES_PER_CELL = 40
NDSM_BYTES_PER_CELL = 96
# The tiled figure's nDSM (float64, filled tile by tile) and its drawing: 96 MB more peak anonymous memory with the
# figure than without on the demo's 3,240 x 2,430 cells (12 bytes a cell; ``NDSM_BYTES_PER_CELL`` refused it at
# 1 GiB as 721 MiB)
FIGURE_BYTES_PER_CELL = 24
MARGIN_CELL_M = 2.0
SCHEMA_VERSION = 1  # corners.json: the layout of ``CornerControlResult.to_json``
# The version of the roof-corner extraction (segments, outlines, corners, their scores and sigmas): the chain's
# corners stamp holds it, so corners extracted by earlier rules are extracted again. Bump it when the corners (or
# roof planes) found at the same settings change. 1: s10-fixes (the algorithm as of main e4b26d8e). 2: the roof work
# scaled by the gap between scan lines in clouds that have one (trial-density F1; clouds of evenly spread points
# give the same corners).
CORNERS_VERSION = 2


@dataclasses.dataclass(frozen=True)
class CornerStats:
    """The numbers of a corner search (``find_roof_corners``' ``stats``; lengths and sigmas in metres): points,
    roofs, outlines, corners traced, reported and usable, the resolved minimum edge and how it was chosen,
    the strip sigmas, the median horizontal sigma of the usable corners, the run time (s) and, by tiles,
    the tiles, tile size and buffer."""

    n_points: int
    n_building_points: int
    point_spacing_m: float | None  # None: no building points
    n_roofs: int
    n_outlines: int
    n_corners_traced: int
    n_corners: int
    n_usable: int
    n_roof_planes: int
    min_edge_m: float | None  # None: no building points to take it from and none given
    min_edge_rule: str
    roof: str
    sigma_strip_xy_m: float
    sigma_strip_z_m: float
    usable_score: float
    median_sxy_usable_m: float | None
    runtime_s: float
    tiles: int | None = None
    tile_m: float | None = None
    buffer_m: float | None = None
    # building points of the roofs roof_outlines.gpkg holds an outline of (None: a record from before stop 114)
    n_outlined_points: int | None = None

    @property
    def outlined_share(self) -> float | None:
        """The share of the building points on the roofs that have an outline (roof_outlines.gpkg): how much of the
        building class the true ortho's footprints from the LiDAR stand for (AHN3 Delft's own classes: 98 %; 95 %
        of the points lie within an outline's polygon, 98.5 % within 0.5 m of one); None when not recorded or no
        building points."""
        if self.n_outlined_points is None or not self.n_building_points:
            return None
        return self.n_outlined_points / self.n_building_points

    @classmethod
    def of_record(cls, d: Mapping) -> "CornerStats":
        """From a record holding its keys (``find_roof_corners``' stats, corners.json)."""
        return cls(**{f.name: d[f.name] for f in dataclasses.fields(cls) if f.name in d})


class NoRoofs(InputError):
    """The cloud gives no roof to take corners from: no building points (ASPRS class 6), or no roof outline traced
    from them. ``lidarctl corners`` stops on it (exit 2, the message); the chain records it in corners.json and goes
    on without LiDAR control, as with no usable corner (docs/chain.md). ``stats``, ``crs``, ``units``: what the
    search found, for corners.json (None from the in-memory ``find_roof_corners``)."""

    def __init__(self, message: str, *, stats: "CornerStats | None" = None, crs=None, units=None):
        super().__init__(message)
        self.stats, self.crs, self.units = stats, crs, units


def no_building_points_message(n_points: int, class_counts) -> str:
    """Why a cloud without building points gives no roof corners. Only a cloud that looks unclassified (every point
    class 0 "never classified" or 1 "unclassified") is told to be classified; a classified one simply holds no
    building (Autzen's trimmed tile, classified by the chain, was told "classify the cloud first").
    ``class_counts``: points per ASPRS class (index = class), noise left out."""
    counts = {c: int(n) for c, n in enumerate(np.asarray(class_counts).tolist()) if n}
    head = f"no building points (ASPRS class {BUILDING}) among {n_points} points"
    if set(counts) <= {0, 1}:
        return (f"{head}, all of them unclassified (class 0 or 1): classify the cloud first (lidarctl classify) - "
                "roof corners need building points")
    classes = ", ".join(f"class {c}: {n}" for c, n in sorted(counts.items()))
    return f"{head} of a classified cloud ({classes}): it holds no building to take roof corners from"


@dataclasses.dataclass(frozen=True)
class CornerControlResult:
    """What the corner stage found (corners.json): the files read (``source``), their CRS and units (None: a
    result written in metres without them), the numbers, the settings with their sources and, when no
    corner is usable as control, why (``no_usable``, one line; else None)."""

    source: str | None
    crs: str | None
    units: LengthUnits | None
    stats: CornerStats
    settings: Mapping | None = None  # ``aerotri.core.settings.Resolved.record()``
    no_usable: str | None = None
    schema_version: int = SCHEMA_VERSION

    @property
    def units_text(self) -> str:
        return self.units.describe() if self.units is not None else "x, y, z in metre"

    def to_json(self) -> str:
        """corners.json's text (the units ahead of the numbers when no corner is usable, after them else)."""
        stats = {k: v for k, v in dataclasses.asdict(self.stats).items()
                 if v is not None or k not in ("tiles", "tile_m", "buffer_m")}
        units = self.units.as_dict() if self.units is not None else {}
        out = {"schema_version": self.schema_version, "source": self.source, "crs": self.crs}
        if self.no_usable is None:
            out.update(**stats, **units)
        else:
            out.update(**units, **stats, no_usable=self.no_usable)
        if self.settings is not None:
            out["settings"] = self.settings
        return json.dumps(out, indent=2) + "\n"


@dataclasses.dataclass(frozen=True)
class RoofCorners:
    """What ``find_roof_corners`` found: the reported corners (rows of ``CSV_COLUMNS`` and their scores), the
    regularised roof outlines, the roof faces (planes with their shrunk footprints) and the numbers.
    ``units``: None while coordinates are in metres (as found); else the CRS units ``in_crs_units`` gave
    the corner, outline and face coordinates (sigmas, edge lengths and spacings stay in metres)."""

    corners: list
    outlines: list
    faces: list
    stats: CornerStats
    units: LengthUnits | None = None

    def in_crs_units(self, units: LengthUnits) -> "RoofCorners":
        """Corner, outline and roof-face coordinates in the CRS units (``lidarctl.units.LengthUnits``: x, y in
        the horizontal unit, z in the vertical unit), from the result in metres."""
        if self.units is not None:
            raise ValueError("the corners are in CRS units already")
        corners = [dict(c, x=float(units.xy_from_m(c["x"])), y=float(units.xy_from_m(c["y"])),
                        z=float(units.z_from_m(c["z"]))) for c in self.corners]
        outlines = [dict(o, rings=[np.asarray(units.xy_from_m(np.asarray(r, float))) for r in o["rings"]])
                    for o in self.outlines]
        return RoofCorners(corners, outlines, _faces_in_crs_units(self.faces, units), self.stats, units)


def _units_of(d: Mapping) -> LengthUnits | None:
    """The units a record names (``LengthUnits.as_dict``' keys), None when it names none."""
    if "xy_unit_m" not in d:
        return None
    return LengthUnits(d["xy_unit_m"], d["z_unit_m"], known=d["xy_unit"] != "file units")


def read_corner_summary(path) -> CornerControlResult:
    """corners.json as the corner stage wrote it (InputError naming the file when it is not one)."""
    what = "corner summary (corners.json)"
    d = read_record(path, what, SCHEMA_VERSION)
    try:
        return CornerControlResult(d["source"], d["crs"], _units_of(d), CornerStats.of_record(d), d.get("settings"),
                                   d.get("no_usable"), d.get("schema_version", SCHEMA_VERSION))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise record_error(path, what, exc) from None


@dataclasses.dataclass(frozen=True)
class CornerFiles:
    """The files ``write_corner_files`` wrote and the summary corners.json holds."""

    csv: Path
    geojson: Path
    planes: Path
    summary_json: Path
    summary: CornerControlResult | None
    outlines: Path | None = None  # roof_outlines.gpkg (None: the corners have no CRS to write it in)


def read_classified_cloud(path, crs=None, require_crs: bool = False) -> las_io.PointCloud:
    """A LAS/LAZ file read by lidarctl.io: x, y, z (metres when the file's CRS is known), classification,
    point_source_id (int64), the CRS (pyproj or None) and the units."""
    c = las_io.read_cloud(path, crs=crs, require_crs=require_crs, point_source_id=True)
    return dataclasses.replace(c, point_source_id=c.point_source_id.astype(np.int64))


@dataclasses.dataclass(frozen=True)
class ClassifiedStrips:
    """Classified strips concatenated (file order): x, y, z in metres, the class, the strip id
    (``point_source_id``, int64), the files' one CRS (pyproj or None) and their units."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    classification: np.ndarray
    point_source_id: np.ndarray
    crs: object
    units: LengthUnits

    def subset(self, keep: np.ndarray) -> "ClassifiedStrips":
        """The points where ``keep`` (a boolean mask or indices)."""
        return dataclasses.replace(self, x=self.x[keep], y=self.y[keep], z=self.z[keep],
                                   classification=self.classification[keep],
                                   point_source_id=self.point_source_id[keep])


def read_strips(paths, crs=None) -> ClassifiedStrips:
    """The classified strips of ``read_classified_cloud`` concatenated (x, y, z in metres), with one
    CRS: a file whose CRS (or units) differs from the first file's is an InputError naming it.
    Files without strip ids (all points of each file share one point_source_id) are told apart by
    their position in ``paths`` (1, 2, ...)."""
    paths = [Path(p) for p in paths]
    clouds = [read_classified_cloud(p, crs=crs, require_crs=True) for p in paths]
    first = clouds[0]
    for p, c in zip(paths[1:], clouds[1:]):
        las_io.require_same_crs(p, c.crs, c.units, (paths[0], first.crs, first.units))
    cat = {k: np.concatenate([getattr(c, k) for c in clouds]) for k in ("x", "y", "z", "classification",
                                                                         "point_source_id")}
    if len(clouds) > 1 and all(len(np.unique(c.point_source_id)) == 1 for c in clouds):
        # one file per strip without strip ids: the file is the strip
        cat["point_source_id"] = np.concatenate([np.full(len(c.x), i + 1) for i, c in enumerate(clouds)])
    return ClassifiedStrips(**cat, crs=first.crs, units=first.units)


def _margin_grid(xy: np.ndarray, cell_m: float, anchor=None):
    """Origin and (rows, cols) of the strip-footprint grid over points ``xy`` (m): a cell of padding
    around them; with ``anchor`` (the origin of the whole cloud's grid, for a tile of it) the origin
    is moved onto that grid's cells, (origin, offset in cells) then tell where."""
    if anchor is None:
        origin, offset = xy.min(axis=0) - cell_m, np.zeros(2, np.int64)
    else:
        origin = np.asarray(anchor, float)
        offset = np.floor((xy.min(axis=0) - origin) / cell_m).astype(np.int64) - 1
    cols, rows = (np.floor((xy.max(axis=0) - origin) / cell_m).astype(np.int64) - offset + 2)
    return origin, (int(rows), int(cols)), offset


def strip_margin_m(xy: np.ndarray, source_id: np.ndarray, query_xy: np.ndarray,
                   cell_m: float = MARGIN_CELL_M, anchor=None) -> np.ndarray:
    """Distance (m) of each query point inside the footprint of the strip that covers it best.

    Footprint of a strip (points sharing a point_source_id) = occupied cells, gaps closed, holes
    (buildings' shadows, water) filled. A cloud without strip ids is one strip. A grid larger than
    the machine's RAM is a ResourceError before it is allocated. ``anchor``: the grid origin of the
    whole cloud when ``xy`` is a tile of it (the same cells; the tile's edge counts as a strip edge).
    """
    origin, shape, offset = _margin_grid(xy, cell_m, anchor)
    check_grid(*shape, cell_m, MARGIN_BYTES_PER_CELL, "strip footprints",
               hint="are the strips far apart (different zones or CRSs)?")
    ij_all = np.floor((xy - origin) / cell_m).astype(np.int64) - offset
    qij = np.clip(np.floor((query_xy - origin) / cell_m).astype(np.int64) - offset, 0, np.array(shape[::-1]) - 1)
    margin = np.zeros(len(query_xy))
    for sid in np.unique(source_id):
        sel = source_id == sid
        if sel.sum() < 100:
            continue
        occ = np.zeros(shape, bool)
        occ[ij_all[sel, 1], ij_all[sel, 0]] = True
        occ = ndimage.binary_closing(occ, iterations=2, border_value=0)
        occ = ndimage.binary_fill_holes(occ)
        dist = ndimage.distance_transform_edt(np.pad(occ, 1))[1:-1, 1:-1] * cell_m
        margin = np.maximum(margin, dist[qij[:, 1], qij[:, 0]] - 0.5 * cell_m)
    return margin


def _bearing_deg(edge) -> float:
    d = edge.direction()
    return float(np.mod(np.degrees(np.arctan2(d[0], d[1])), 180.0))


@dataclasses.dataclass
class _RoofClusters:
    """The cloud without noise, its building points clustered into roofs."""

    xyz: np.ndarray  # (N, 3) m
    cls: np.ndarray
    sid: np.ndarray  # point source (strip) id per point
    n_building_points: int
    spacing_m: float  # point spacing on the roofs
    roof_label: np.ndarray  # roof per point, -1 for none
    n_roofs: int
    margin_anchor: object = None  # strip-footprint grid origin of the whole cloud (tiles), else None
    min_edge_m: float = 5.0  # shortest edge of a reported corner (resolved from the spacing by default)


def default_min_edge_m(spacing_m: float) -> float:
    """The stage's default shortest edge (m): max(MIN_EDGE_FLOOR_M, MIN_EDGE_SPACINGS * spacing) (see there)."""
    if not np.isfinite(spacing_m):
        return 5.0
    return float(max(MIN_EDGE_FLOOR_M, MIN_EDGE_SPACINGS * spacing_m))


def _roof_clusters(x, y, z, classification, point_source_id, *, spacing_m: float | None = None,
                   margin_anchor=None, min_edge_m: float | None = None) -> _RoofClusters:
    """Drop noise, refuse a cloud without building points, cluster the building points into roofs of at
    least ``min_roof_m2(min_edge_m)`` (and 30 points; ``min_edge_m`` None: ``default_min_edge_m`` of the
    spacing). ``spacing_m``: the building points' spacing of the whole cloud when this is a tile of it."""
    xyz = np.column_stack([x, y, z]).astype(float)
    cls = np.asarray(classification)
    keep = ~np.isin(cls, NOISE)
    xyz, cls = xyz[keep], cls[keep]
    if len(xyz):
        # The strip-footprint grid spans all points: refuse an impossible one before the roof work.
        check_grid(*_margin_grid(xyz[:, :2], MARGIN_CELL_M, margin_anchor)[1], MARGIN_CELL_M, MARGIN_BYTES_PER_CELL,
                   "strip footprints", hint="are the strips far apart (different zones or CRSs)?")
    sid = np.zeros(len(xyz), np.int64) if point_source_id is None else np.asarray(point_source_id)[keep]
    is_bldg = cls == BUILDING
    n_bldg = int(is_bldg.sum())
    if n_bldg == 0:
        raise NoRoofs(no_building_points_message(len(xyz), np.bincount(cls.astype(np.int64), minlength=256)))
    bldg_idx = np.flatnonzero(is_bldg)
    if spacing_m is None:
        spacing = point_spacing_m(xyz[bldg_idx, :2])
        spacing = point_spacing_m(xyz[bldg_idx, :2], cell_m=max(2.0, 2.0 * spacing))
        spacing = effective_spacing_m(xyz[bldg_idx, :2], spacing)
    else:
        spacing = spacing_m
    if min_edge_m is None:
        min_edge_m = default_min_edge_m(spacing)
    roof_of_bldg = cluster_roofs(xyz[bldg_idx], link_radius_m=2.0 * spacing, max_step_m=1.0,
                                 min_points=max(30, int(min_roof_m2(min_edge_m) / spacing**2)))
    roof_label = np.full(len(xyz), -1, np.int64)
    roof_label[bldg_idx] = roof_of_bldg
    n_roofs = int(roof_of_bldg.max()) + 1 if (roof_of_bldg >= 0).any() else 0
    return _RoofClusters(xyz, cls, sid, n_bldg, spacing, roof_label, n_roofs, margin_anchor, float(min_edge_m))


def _corner_height(pts, plane_of, planes, roof_tree, xy, cov_xy) -> tuple[float, float, float]:
    """(z, sigma z, slope in degrees) of a corner: on the roof face most of the nearest roof points belong
    to (its height sigma plus the plan sigma through the face's gradient), else the median of those points."""
    _, nb = roof_tree.query(xy, k=min(15, len(pts)))
    ids = plane_of[np.atleast_1d(nb)]
    ids = ids[ids >= 0]
    if len(ids) and planes:
        plane = planes[np.bincount(ids).argmax()]
        zc = float(plane.height_m(*xy))
        grad = float(np.hypot(plane.abc[0], plane.abc[1]))
        s_h2 = 0.5 * np.trace(cov_xy)
        sz = float(np.sqrt(plane.height_sigma_m(*xy) ** 2 + grad**2 * s_h2))
        return zc, sz, plane.slope_deg
    zc = float(np.median(pts[np.atleast_1d(nb), 2]))
    sz = float(np.std(pts[np.atleast_1d(nb), 2]) + 0.1)
    return zc, sz, 90.0


def face_footprint(xy: np.ndarray, spacing_m: float, margin_m: float):
    """The footprint of a roof face's points ``xy`` (m) shrunk inward by ``margin_m``: the largest
    polygon (exterior CCW) of the cells the points occupy (cells of half a spacing, closed over gaps of
    two spacings) whose distance to the face's boundary exceeds the margin; None when
    nothing is left. Eaves, ridges, hips and step edges lie on the boundary of a face, so the shrunk
    footprint keeps tie points off them."""
    from rasterio.transform import Affine
    from rasterio import features
    from shapely.geometry import shape
    from shapely.geometry.polygon import orient

    cell = 0.5 * spacing_m
    pad = 4
    origin = xy.min(axis=0) - pad * cell
    ij = np.floor((xy - origin) / cell).astype(np.int64)
    cols, rows = ij.max(axis=0) + pad + 1
    check_grid(int(rows), int(cols), cell, 16, "a roof face footprint")
    occ = np.zeros((int(rows), int(cols)), bool)
    occ[ij[:, 1], ij[:, 0]] = True
    # closing bridges the gaps between scan lines; holes (courtyards, chimneys, dormers) stay holes
    occ = ndimage.binary_closing(occ, structure=ndimage.generate_binary_structure(2, 2), iterations=2)
    inner = ndimage.distance_transform_edt(occ) * cell > margin_m + 0.5 * cell
    if not inner.any():
        return None
    polys = [shape(g) for g, _ in features.shapes(inner.astype(np.uint8), mask=inner,
                                                   transform=Affine(cell, 0.0, origin[0], 0.0, cell, origin[1]))]
    best = max(polys, key=lambda q: q.area)
    return orient(best.simplify(0.25 * spacing_m), 1.0)


def _roof_faces(pts: np.ndarray, plane_of: np.ndarray, planes: list, r: int, spacing: float) -> list[dict]:
    """The roof faces of roof ``r`` as surface control: plane, footprint of its inliers shrunk by
    ``max(FACE_MARGIN_M, FACE_MARGIN_SPACINGS * spacing)`` (m); faces with less than
    ``MIN_FACE_AREA_M2`` left are dropped."""
    margin = max(FACE_MARGIN_M, FACE_MARGIN_SPACINGS * spacing)
    faces = []
    for i, plane in enumerate(planes):
        m = plane_of == i
        m[m] = np.abs(plane.height_m(pts[m, 0], pts[m, 1]) - pts[m, 2]) < 3.0 * plane.rms_m + 0.02
        if m.sum() < 10:
            continue
        poly = face_footprint(pts[m, :2], spacing, margin)
        if poly is None or poly.area < MIN_FACE_AREA_M2:
            continue
        faces.append(dict(building_id=r, plane=plane, polygon=poly, margin_m=margin))
    return faces


def _one_roof(pts: np.ndarray, r: int, spacing: float) -> tuple[list[dict], dict | None, list[dict]]:
    """(traced corners, outline, faces) of roof ``r`` (its points ``pts``): planes, traced and regularised
    rings, edges fitted to the points on a roof face, corners where the fitted edges meet; the roof
    faces (``_roof_faces``)."""
    # cells of two spacings: smaller cells leave holes in sparse clouds and underestimate the spacing
    s_roof = point_spacing_m(pts[:, :2], cell_m=max(1.0, 2.0 * spacing))
    s_roof = float(np.clip(s_roof, 0.5 * spacing, 2.0 * spacing))
    plane_of, planes = segment_planes(pts, roof_id=r)
    faces = _roof_faces(pts, plane_of, planes, r, s_roof)
    rings = trace_rings(pts[:, :2], s_roof)
    if not rings:
        return [], None, faces
    theta, edge_rings = regularise_rings(rings, s_roof)
    if not edge_rings:
        return [], None, faces
    # Edge evidence from points on a roof face only: fascia and wall points lie on or inside the eave
    # line below the roof and would pull the edge (they still shape the traced outline).
    on_face = np.zeros(len(pts), bool)
    for i_plane, plane in enumerate(planes):
        m = plane_of == i_plane
        on_face[m] = np.abs(plane.height_m(pts[m, 0], pts[m, 1]) - pts[m, 2]) < 3.0 * plane.rms_m + 0.02
    face_xy = pts[on_face, :2] if on_face.sum() >= 10 else pts[:, :2]
    obs = [edge_observations(edges, face_xy, s_roof) for edges in edge_rings]
    fit = fit_edges(theta, edge_rings, obs)
    fit = fit_edges(theta, edge_rings, reweight_observations(edge_rings, obs, fit.sigma0))
    roof_tree = cKDTree(pts[:, :2])
    raw, outline_rings = [], []
    for edges in edge_rings:
        rc = corners_from_edges(edges, fit)
        lengths = np.array([edge_length_m(edges, i) for i in range(len(edges))])
        trace = shapely.LinearRing(rings[edges[0].ring])
        far = shapely.distance(shapely.points(rc.xy), trace) > max(2.0, 4.0 * s_roof)
        outline_rings.append(rc.xy[~far])
        # an edge whose other end is no corner of the roof (its lines meet off the trace) has no known
        # length or end: the corners on it are traced, never usable
        far_start = {id(rc.edge_out[k]): bool(far[k]) for k in range(len(rc.xy))}
        far_end = {id(rc.edge_in[k]): bool(far[k]) for k in range(len(rc.xy))}
        for k in range(len(rc.xy)):
            if far[k]:
                continue  # the fitted edges meet far from the traced outline: not a corner of this roof
            open_edge = far_start.get(id(rc.edge_in[k]), True) or far_end.get(id(rc.edge_out[k]), True)
            i_out = edges.index(rc.edge_out[k])
            l_in, l_out = lengths[i_out - 1], lengths[i_out]
            zc, sz, slope = _corner_height(pts, plane_of, planes, roof_tree, rc.xy[k], rc.cov_xy[k])
            # sigma of the angle between the two edges: 0 between edges of one direction family (right
            # angles by construction), else from the adjusted directions (free edges, two families)
            p1, p2 = rc.edge_in[k].param_phi, rc.edge_out[k].param_phi
            s_angle = float(np.degrees(np.sqrt(max(fit.cov[p1, p1] + fit.cov[p2, p2] - 2.0 * fit.cov[p1, p2], 0.0))))
            raw.append(dict(
                xy=rc.xy[k], cov=rc.cov_xy[k], z=zc, sz=sz,
                roof="flat" if slope < FLAT_SLOPE_DEG else "pitched", building_id=r,
                edge1_deg=_bearing_deg(rc.edge_in[k]), edge2_deg=_bearing_deg(rc.edge_out[k]),
                angle_deg=float(rc.angle_deg[k]), n_in=rc.edge_in[k].n_obs, n_out=rc.edge_out[k].n_obs,
                l_in=float(l_in), l_out=float(l_out), open_edge=open_edge, s_angle_deg=s_angle,
            ))
    roof_types = ["flat" if p.slope_deg < FLAT_SLOPE_DEG else "pitched" for p in planes]
    outline = dict(
        building_id=r, rings=outline_rings, n_points=len(pts), spacing_m=s_roof,
        roof="flat" if roof_types and all(t == "flat" for t in roof_types) else "pitched",
        n_planes=len(planes), sigma0=fit.sigma0, theta_deg=float(np.degrees(fit.theta)),
    )
    return raw, outline, faces


def view_openness(xyz: np.ndarray, cls: np.ndarray, roof_label: np.ndarray, corner_xyz: np.ndarray,
                  building_id: np.ndarray, off_nadir_deg: float = VIEW_OFF_NADIR_DEG,
                  n_sectors: int = VIEW_SECTORS) -> np.ndarray:
    """Fraction of the azimuth sectors from which each corner is seen ``off_nadir_deg`` off nadir (0..1).

    A sector is hidden when at least ``OCCLUDER_MIN_POINTS`` non-ground points of anything but the
    corner's own roof (trees, other roofs) lie in it more than ``OCCLUDER_MIN_DZ_M`` above the corner and
    above the view ray, i.e. more than d / tan(off_nadir) above it at horizontal distance d (m). A crown
    over the corner hides it from every sector; a tree beside it only from the side it stands on, so the
    frames looking from the other sides still see the corner. Coordinates in metres.
    """
    corner_xyz = np.asarray(corner_xyz, float).reshape(-1, 3)
    out = np.ones(len(corner_xyz))
    if not len(corner_xyz):
        return out
    cot = 1.0 / np.tan(np.radians(off_nadir_deg))
    cand = cls != GROUND
    idx_cand = np.flatnonzero(cand)
    tree = cKDTree(xyz[idx_cand, :2])
    # farthest point that can hide a corner: one 40 m above it (a tall tree or building)
    radius = 40.0 / cot
    for k, near in enumerate(tree.query_ball_point(corner_xyz[:, :2], radius)):
        near = idx_cand[np.asarray(near, np.int64)]
        near = near[roof_label[near] != building_id[k]]
        dxy = xyz[near, :2] - corner_xyz[k, :2]
        d = np.hypot(dxy[:, 0], dxy[:, 1])
        dz = xyz[near, 2] - corner_xyz[k, 2]
        hide = (dz > OCCLUDER_MIN_DZ_M) & (dz > d * cot)
        if not hide.any():
            continue
        az = np.arctan2(dxy[hide, 1], dxy[hide, 0])
        sector = np.floor(np.mod(az, 2.0 * np.pi) / (2.0 * np.pi / n_sectors)).astype(np.int64) % n_sectors
        hidden = np.bincount(sector, minlength=n_sectors) >= OCCLUDER_MIN_POINTS
        out[k] = 1.0 - hidden.sum() / n_sectors
    return out


def _score_corners(raw: list[dict], rc: _RoofClusters, *, min_edge_m: float, roof: str, sigma_strip_xy_m: float,
                   sigma_strip_z_m: float) -> None:
    """Add to each traced corner its sigmas with the strip's georeferencing error, its score (product of
    the factors: right angle, edge length, support, precision, flat roof, view openness past trees and
    other roofs, away from the strip edge) and whether it is usable as control."""
    cxy = np.array([c["xy"] for c in raw])
    cz = np.array([c["z"] for c in raw])
    openness = view_openness(rc.xyz, rc.cls, rc.roof_label, np.column_stack([cxy, cz]),
                             np.array([c["building_id"] for c in raw]))
    margin = strip_margin_m(rc.xyz[:, :2], rc.sid, cxy, anchor=rc.margin_anchor)

    for k, c in enumerate(raw):
        sx, sy = np.sqrt(np.diag(c["cov"]) + sigma_strip_xy_m**2)
        c["sz"] = float(np.hypot(c["sz"], sigma_strip_z_m))
        s_h = float(np.sqrt(0.5 * (sx**2 + sy**2)))
        dev = min(abs(c["angle_deg"] - 90.0), abs(c["angle_deg"] - 270.0))
        # an oblique corner (a trapezoid block, a wing at an angle) is a corner like a right-angled one when
        # both edge directions are adjusted well enough that the angle is known (2 sigma within the right
        # angle's 5 deg tolerance) and the outline turns by at least MIN_OBLIQUE_TURN_DEG there
        oblique = (c["s_angle_deg"] <= 0.5 * RIGHT_ANGLE_TOL_DEG
                   and abs(180.0 - c["angle_deg"]) >= MIN_OBLIQUE_TURN_DEG)
        f_angle = 1.0 if oblique else float(np.clip(1.0 - dev / 10.0, 0.0, 1.0))
        f_len = float(np.clip(min(c["l_in"], c["l_out"]) / min_edge_m, 0.0, 1.0))
        f_support = float(np.clip(min(c["n_in"], c["n_out"]) / SUPPORT_FULL_BINS, 0.0, 1.0))
        f_prec = 1.0 / (1.0 + (s_h / 0.15) ** 2)
        f_flat = 1.0  # pitched: the plan position is an eave corner's as well; its height sigma holds the slope
        f_open = float(openness[k])
        f_strip = 1.0 if margin[k] >= 10.0 else 0.3
        score = f_angle * f_len * f_support * f_prec * f_flat * f_open * f_strip
        usable = (
            score >= USABLE_SCORE and (dev <= RIGHT_ANGLE_TOL_DEG or oblique) and min(c["l_in"], c["l_out"]) >= min_edge_m
            and (roof == "any" or c["roof"] == "flat") and not c["open_edge"]
        )
        c.update(sx=float(sx), sy=float(sy), score=float(score), usable=bool(usable),
                 strip_margin_m=float(margin[k]),
                 factors=dict(angle=f_angle, edge_length=f_len, support=f_support, precision=f_prec,
                              flat=f_flat, view_openness=f_open, strip_edge=f_strip))


def _reported_corners(raw: list[dict], min_edge_m: float, spacing: float) -> list[dict]:
    """The corner records (CSV_COLUMNS and the review fields) of the corners between edges of at least
    ``min_edge_m``, located well enough; ids RC00001... by building, best score first."""
    max_sigma = max(MAX_SIGMA_XY_M, MAX_SIGMA_XY_SPACINGS * spacing)
    reported = [c for c in raw if min(c["l_in"], c["l_out"]) >= min_edge_m and max(c["sx"], c["sy"]) <= max_sigma]
    reported.sort(key=lambda c: (c["building_id"], -c["score"]))
    corners = []
    for n, c in enumerate(reported, 1):
        corners.append({
            "id": f"RC{n:05d}", "x": float(c["xy"][0]), "y": float(c["xy"][1]), "z": c["z"],
            "sx_m": c["sx"], "sy_m": c["sy"], "sz_m": c["sz"], "roof": c["roof"], "building_id": c["building_id"],
            "edge1_deg": c["edge1_deg"], "edge2_deg": c["edge2_deg"], "angle_deg": c["angle_deg"],
            "support_pts": int(c["n_in"] + c["n_out"]), "score": c["score"], "usable": int(c["usable"]),
            # not in the CSV; in the GeoJSON for review: why a corner is (not) usable
            "edge1_m": c["l_in"], "edge2_m": c["l_out"], "strip_margin_m": c["strip_margin_m"],
            "open_edge": bool(c["open_edge"]), "angle_sigma_deg": c["s_angle_deg"],
            **{f"score_{k}": v for k, v in c["factors"].items()},
        })
    return corners


def find_roof_corners(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    classification: np.ndarray,
    point_source_id: np.ndarray | None = None,
    *,
    min_edge_m: float | None = None,
    roof: str = "flat",
    sigma_strip_xy_m: float = 0.03,
    sigma_strip_z_m: float = 0.03,
) -> RoofCorners:
    """Corners and regularised outlines of all roofs of a classified cloud (metres).

    ``min_edge_m``: shortest edge of a reported corner; None: ``default_min_edge_m`` of the building
    points' spacing (the resolved value is ``stats["min_edge_m"]``).

    Steps: roofs (clusters of building points) -> per roof: planes, outline, fitted edges, corners ->
    scores -> the corners reported.

    ``sigma_strip_xy_m``, ``sigma_strip_z_m``: georeferencing error of a strip (GNSS/IMU, boresight),
    common to all points of the strip, so no fit over its points reduces it; added in quadrature to the
    fitted corner's standard deviations. Take them from the system's (strip-adjusted) accuracy.

    Returns the ``RoofCorners`` in metres (corners: rows of ``CSV_COLUMNS``; faces: roof planes with their
    shrunk footprints, ``_roof_faces``); raises InputError when the cloud has no building points or no roof could be outlined.
    """
    if roof not in ("flat", "any"):
        raise InputError(f"roof must be 'flat' or 'any', not {roof!r}")
    t_start = time.perf_counter()
    rc = _roof_clusters(x, y, z, classification, point_source_id, min_edge_m=min_edge_m)
    min_edge_auto, min_edge_m = min_edge_m is None, rc.min_edge_m
    raw, outlines, faces = [], [], []  # raw: per corner xy, cov, z, sz, roof type, building, bearings, angle, ...
    for r in track(range(rc.n_roofs), "roof corners", "roofs"):
        roof_raw, outline, roof_faces = _one_roof(rc.xyz[rc.roof_label == r], r, rc.spacing_m)
        raw += roof_raw
        faces += roof_faces
        if outline is not None:
            outlines.append(outline)
    if raw:
        _score_corners(raw, rc, min_edge_m=min_edge_m, roof=roof, sigma_strip_xy_m=sigma_strip_xy_m,
                       sigma_strip_z_m=sigma_strip_z_m)
    return _finish(raw, outlines, faces, n_points=len(rc.xyz), n_building_points=rc.n_building_points,
                   spacing_m=rc.spacing_m, n_roofs=rc.n_roofs, t_start=t_start, min_edge_m=min_edge_m, roof=roof,
                   sigma_strip_xy_m=sigma_strip_xy_m, sigma_strip_z_m=sigma_strip_z_m, min_edge_auto=min_edge_auto)


def min_roof_m2(min_edge_m: float) -> float:
    """Smallest roof searched for corners (m^2): 25 m^2, less when ``min_edge_m`` is below 5 m (a roof of
    min_edge_m x min_edge_m has a corner between two such edges: the corners of small annexes)."""
    return min(25.0, float(min_edge_m) ** 2)


def _finish(raw, outlines, faces, *, n_points, n_building_points, spacing_m, n_roofs, t_start, min_edge_m, roof,
            sigma_strip_xy_m, sigma_strip_z_m, min_edge_auto=False) -> RoofCorners:
    """The reported corners and the stats of the scored corners of all roofs (in roof order)."""
    corners = _reported_corners(raw, min_edge_m, spacing_m) if raw else []
    n_usable = sum(c["usable"] for c in corners)
    stats = CornerStats(**{
        "n_points": int(n_points), "n_building_points": n_building_points, "point_spacing_m": spacing_m,
        "n_roofs": n_roofs, "n_outlines": len(outlines), "n_corners_traced": len(raw),
        "n_corners": len(corners), "n_usable": int(n_usable), "n_roof_planes": len(faces),
        "min_edge_m": min_edge_m,
        "min_edge_rule": (f"max({MIN_EDGE_FLOOR_M:g} m, {MIN_EDGE_SPACINGS:g} point spacings)" if min_edge_auto
                          else "given"),
        "roof": roof,
        "sigma_strip_xy_m": sigma_strip_xy_m, "sigma_strip_z_m": sigma_strip_z_m,
        "usable_score": USABLE_SCORE,
        "median_sxy_usable_m": (
            float(np.median([np.hypot(c["sx_m"], c["sy_m"]) / np.sqrt(2) for c in corners if c["usable"]]))
            if n_usable else None
        ),
        "runtime_s": time.perf_counter() - t_start,
        "n_outlined_points": sum(int(props["n_points"]) for _, props in _outline_features(outlines)),
    })
    if not raw:
        raise NoRoofs(f"no roof outline could be traced from {n_building_points} building points ({n_roofs} roofs of "
                      f"at least {min_roof_m2(min_edge_m):.3g} m^2; point spacing {spacing_m:.2f} m)", stats=stats)
    return RoofCorners(corners, outlines, faces, stats)


# ------------------------------------------------------------------------------------------------ by tiles
# Tiles of the corner stage: a roof is found in the tile whose core holds its reference point (its first
# point in file order), from the tile's points with a buffer larger than the largest roof.
DEFAULT_TILE_M = 500.0
DEFAULT_BUFFER_M = 150.0
# A tile's points with its buffer as the roof search reads them (``_tile_points``, in memory only).
_CORNER_BIN = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8"), ("cls", "u1"), ("core", "u1"), ("file", "u2"),
                        ("sid", "u2"), ("index", "i8")])
# The scratch (``_bin_corner_points``): every non-noise point once, in the file of its core tile and its near code
# (``TileGrid.core_near``: whose buffers hold it), as its LAS file stores it: the integer coordinates (the
# coordinates of ``read_strips`` exactly, with the file's scales, offsets and units), the class, the strip (an
# entry of the (file, point_source_id) pairs) and its number among the file's non-noise points: 19 bytes a point
# (23 when a file holds 2^32 points or more), each written once; a tile takes its buffer from its neighbours'
# files of the codes that reach into it. Before: a 38-byte record of float64 metres per tile holding the point,
# 2.56 copies with 500 m tiles and a 150 m buffer (97 bytes a point, bench/corners_scratch.py).
_SCRATCH_FIELDS = [("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("cls", "u1"), ("strip", "<u2")]
_MAX_STRIPS = 1 << 16
_BUILDING_XY = "building_{}.bin"   # integer (X, Y) int32 of every building point of file k, in file order


def _scratch_dtype(index_dtype) -> np.dtype:
    return np.dtype(_SCRATCH_FIELDS + [("index", index_dtype)])


def _tile_file(work: Path, tid: int, code: int) -> Path:
    return work / f"tile_{tid}_{code}.bin"


@dataclasses.dataclass
class _TiledCloud:
    """The non-noise points of the files binned into scratch files by core tile and near code (``_scratch_dtype``)
    and what the whole cloud's processing needs from all of them."""

    work: Path
    grid: object            # lidarctl.tiles.TileGrid (metres)
    used: np.ndarray        # tiles holding points (core or buffer)
    crs: object
    units: object
    n_points: int           # non-noise points
    n_building: int
    building_min: np.ndarray
    margin_anchor: np.ndarray
    file_is_strip: bool     # several files, each with one point_source_id: the file is the strip
    record: np.dtype        # the scratch records (``_scratch_dtype``)
    parts: frozenset        # (tile, near code) pairs with a scratch file
    scales: np.ndarray      # (files, 3) LAS scales and offsets of each file
    offsets: np.ndarray
    file_base: np.ndarray   # global index of each file's first non-noise point
    strip_file: np.ndarray  # per strip entry: its file and point_source_id
    strip_sid: np.ndarray
    scratch_bytes: int
    class_counts: np.ndarray  # non-noise points per ASPRS class (index = class)


def _mark_used(used: np.ndarray, grid, tid: int, code: int) -> None:
    """The tiles whose core or buffer holds the points of (tile ``tid``, near ``code``)."""
    from lidarctl.tiles import near_code_in_buffer_of

    r, c = divmod(tid, grid.ncols)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if near_code_in_buffer_of(code, dr, dc):
                used[(r + dr) * grid.ncols + c + dc] = True


def _bin_corner_points(paths, crs, work: Path, tile_m: float, buffer_m: float, chunk_points: int) -> _TiledCloud:
    """One streaming pass over the files: their non-noise points into the scratch files (``_scratch_dtype``, by
    core tile and near code, file order), with the index each has in ``read_strips``' concatenation without noise."""
    from aerotri.geom import las
    from lidarctl.tiles import TileGrid

    headers = [las.read_header(p) for p in paths]
    first = None
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    n_occupied = 0.0  # tiles the files can touch, each over its own extent (work goes where the points are)
    for p, h in zip(paths, headers):
        c, u = las_io.resolve_crs_units(p, h, crs)
        if first is None:
            first = (p, c, u)
        else:
            las_io.require_same_crs(p, c, u, first)
        if h.point_count == 0:
            raise InputError(f"{p}: the file holds no points")
        f_lo, f_hi = u.xy_to_m(np.asarray(h.mins[:2], float)), u.xy_to_m(np.asarray(h.maxs[:2], float))
        lo, hi = np.minimum(lo, f_lo), np.maximum(hi, f_hi)
        if np.isfinite(f_lo).all() and np.isfinite(f_hi).all():
            n_occupied += float(np.prod(np.floor(np.maximum(f_hi - f_lo, 0.0) / tile_m) + 2))
    units = first[2]
    names = ", ".join(map(str, paths))
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()) or (np.abs(np.r_[lo, hi]) > las_io.MAX_ABS_XY_M).any():
        raise InputError(f"{names}: absurd bounds in the LAS headers ({lo.tolist()} .. {hi.tolist()})")
    from aerotri.core.limits import check_task_count

    n_cr = np.maximum(np.ceil((hi - lo) / tile_m), 1)
    check_task_count(min(float(n_cr[0] * n_cr[1]), n_occupied), f"{names}: tiles of {tile_m:g} m",
                     "--tile-m", "use a larger --tile-m")
    nc, nr = n_cr.astype(int)
    grid = TileGrid(float(lo[0]), float(lo[1]), float(tile_m), float(buffer_m), int(nr), int(nc))
    used = np.zeros(grid.n_tiles, bool)
    record = _scratch_dtype(np.uint32 if max(h.point_count for h in headers) < 1 << 32 else np.uint64)
    from aerotri.core.limits import check_disk

    # every point once, and the building points' (X, Y) once more when all are building points
    check_disk(sum(h.point_count for h in headers) * (record.itemsize + 8.0), work,
               f"{names}: the corner search's scratch ({record.itemsize} + 8 bytes a point)")
    parts, strips, file_base = set(), {}, []
    index = n_bldg = 0
    class_counts = np.zeros(256, np.int64)
    bmin, amin = np.full(2, np.inf), np.full(2, np.inf)
    one_sid = []
    for k, p in enumerate(paths):
        sids = set()
        file_base.append(index)
        n_file = 0
        for first_rec, chunk in las.iter_file_chunks(p, chunk_points):
            x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            las_io.validate_xyz(p, x, y, z, first_rec, units)
            cls = np.asarray(chunk.classification)
            sid = np.asarray(chunk.point_source_id)
            sids.update(np.unique(sid).tolist())
            keep = ~np.isin(cls, NOISE)
            if not keep.any():
                continue
            rec = np.empty(int(keep.sum()), record)
            for name in ("X", "Y", "Z"):
                rec[name] = np.asarray(chunk[name])[keep]
            rec["cls"] = cls[keep]
            class_counts += np.bincount(rec["cls"], minlength=256)
            sid_values, sid_entry = np.unique(sid[keep], return_inverse=True)
            entries = np.array([strips.setdefault((k, int(s)), len(strips)) for s in sid_values], np.int64)
            if len(strips) > _MAX_STRIPS:
                raise InputError(f"{names}: more than {_MAX_STRIPS} strips (pairs of file and point_source_id)")
            rec["strip"] = entries[sid_entry.ravel()]
            rec["index"] = n_file + np.arange(len(rec))
            n_file += len(rec)
            xm, ym = units.xy_to_m(x[keep]), units.xy_to_m(y[keep])
            amin = np.minimum(amin, [xm.min(), ym.min()])
            b = rec["cls"] == BUILDING
            if b.any():
                n_bldg += int(b.sum())
                bmin = np.minimum(bmin, [xm[b].min(), ym[b].min()])
                # every point lies in one tile's core: the building points once more, for the spacing
                with open(work / _BUILDING_XY.format(k), "ab") as fh:
                    np.column_stack([rec["X"][b], rec["Y"][b]]).tofile(fh)
            tile, code = grid.core_near(xm, ym)
            key = tile * 16 + code
            order = np.argsort(key, kind="stable")  # by tile and code, file order within
            for sel in np.split(order, np.flatnonzero(np.diff(key[order])) + 1):
                tid, c = divmod(int(key[sel[0]]), 16)
                with open(_tile_file(work, tid, c), "ab") as fh:
                    rec[sel].tofile(fh)
                if (tid, c) not in parts:
                    parts.add((tid, c))
                    _mark_used(used, grid, tid, c)
        index += n_file
        one_sid.append(len(sids) == 1)
    pairs = sorted(strips, key=strips.get)
    scratch_bytes = sum(f.stat().st_size for f in work.iterdir())
    log.debug(f"corner scratch: {scratch_bytes / 1e6:.1f} MB for {index} points "
              f"({scratch_bytes / max(index, 1):.1f} bytes a point)")
    return _TiledCloud(work, grid, used, first[1], units, index, n_bldg, bmin, amin - MARGIN_CELL_M,
                       len(paths) > 1 and all(one_sid), record, frozenset(parts),
                       np.array([h.scales for h in headers], float), np.array([h.offsets for h in headers], float),
                       np.array(file_base, np.int64), np.array([f for f, _ in pairs], np.uint16).reshape(-1),
                       np.array([s for _, s in pairs], np.uint16).reshape(-1), scratch_bytes, class_counts)


def _metres(tc: _TiledCloud, raw: np.ndarray, file: np.ndarray, axis: int) -> np.ndarray:
    """Coordinates (m) of integer LAS coordinates ``raw`` of the files ``file`` along ``axis`` (0, 1, 2): laspy's
    X * scale + offset, then the units, so the values equal ``read_strips``' to the bit."""
    v = raw * tc.scales[file, axis] + tc.offsets[file, axis]
    return tc.units.z_to_m(v) if axis == 2 else tc.units.xy_to_m(v)


def _tile_points(tc: _TiledCloud, tid: int) -> np.ndarray:
    """The points of tile ``tid`` with its buffer (``_CORNER_BIN``, in file order, ``core`` 1 for its own): its own
    scratch files and its neighbours' of the near codes that reach into it."""
    from lidarctl.tiles import near_code_in_buffer_of

    g = tc.grid
    r, c = divmod(tid, g.ncols)
    parts, own = [], []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if not (0 <= r + dr < g.nrows and 0 <= c + dc < g.ncols):
                continue
            n = (r + dr) * g.ncols + c + dc
            for code in range(16):
                if (n, code) in tc.parts and near_code_in_buffer_of(code, -dr, -dc):
                    parts.append(np.fromfile(_tile_file(tc.work, n, code), tc.record))
                    own.append(np.full(len(parts[-1]), n == tid))
    raw = np.concatenate(parts)
    del parts
    file = tc.strip_file[raw["strip"]]
    index = tc.file_base[file] + raw["index"].astype(np.int64)
    order = np.argsort(index, kind="stable")
    # field by field: a tile's records are gathered once, not copied whole in between
    rec = np.empty(len(raw), _CORNER_BIN)
    rec["index"] = index[order]
    del index
    file = file[order]
    for axis, name in enumerate(("x", "y", "z")):
        rec[name] = _metres(tc, raw[name.upper()][order], file, axis)
    rec["file"], rec["cls"], rec["core"] = file, raw["cls"][order], np.concatenate(own)[order]
    rec["sid"] = tc.strip_sid[raw["strip"][order]]
    return rec


def _global_spacing_m(tc: _TiledCloud, chunk_points: int = las_io.CHUNK_POINTS) -> float:
    """``point_spacing_m`` of all building points (as ``_roof_clusters`` computes it), from the
    building points' integer (x, y) the binning kept aside (read by chunks, not the tiles again): occupied
    cells anchored at the building points' lowest x, y."""
    def spacing(cell_m):
        cells = []  # occupied cells of each chunk (a cell may hold points of several chunks)
        for k in range(len(tc.file_base)):
            path = tc.work / _BUILDING_XY.format(k)
            if not path.exists():
                continue
            with open(path, "rb") as fh:
                while len(XY := np.fromfile(fh, np.int32, count=2 * chunk_points)):
                    XY = XY.reshape(-1, 2)
                    xy = np.column_stack([_metres(tc, XY[:, 0], k, 0), _metres(tc, XY[:, 1], k, 1)])
                    ij = np.floor((xy - tc.building_min) / cell_m).astype(np.int64)
                    cells.append(np.unique(ij[:, 0] * (1 << 31) + ij[:, 1]))
        n_cells = len(np.unique(np.concatenate(cells)))
        return float(np.sqrt(n_cells * cell_m * cell_m / tc.n_building))

    if tc.n_building < 2:
        return float("nan")
    s = spacing(2.0)
    s = spacing(max(2.0, 2.0 * s))
    # the gap between scan lines from the first chunk of building points of a strip (its points in file order lie
    # together; a strip alone has the gaps that roofs outside the strips' overlaps have)
    for k in range(len(tc.file_base)):
        path = tc.work / _BUILDING_XY.format(k)
        if path.exists():
            XY = np.fromfile(path, np.int32, count=2 * min(chunk_points, SCAN_GAP_POINTS)).reshape(-1, 2)
            if len(XY) >= 5:
                xy = np.column_stack([_metres(tc, XY[:, 0], k, 0), _metres(tc, XY[:, 1], k, 1)])
                return effective_spacing_m(xy, s)
    return s


def _tile_clusters(tc: _TiledCloud, tid: int, spacing_m: float, min_edge_m: float):
    """(points, _RoofClusters) of one tile with its buffer, or None without building points; roofs of at
    least ``min_roof_m2(min_edge_m)``."""
    rec = _tile_points(tc, tid)
    if not (rec["cls"] == BUILDING).any():
        return rec, None
    sid = (rec["file"].astype(np.int64) + 1) if tc.file_is_strip else rec["sid"].astype(np.int64)
    rc = _roof_clusters(rec["x"], rec["y"], rec["z"], rec["cls"], sid, spacing_m=spacing_m,
                        margin_anchor=tc.margin_anchor, min_edge_m=min_edge_m)
    return rec, rc


def _roof_keys(rec: np.ndarray, rc: _RoofClusters):
    """Per roof of a tile: size, index of its first point (the reference point) and whether that point
    lies in the tile's core."""
    lab = rc.roof_label
    size = np.bincount(lab[lab >= 0], minlength=rc.n_roofs)
    first = np.full(rc.n_roofs, np.iinfo(np.int64).max)
    np.minimum.at(first, lab[lab >= 0], rec["index"][lab >= 0])
    pos = np.searchsorted(rec["index"], first.clip(max=rec["index"][-1]))
    return size, first, rec["core"][pos] == 1


def find_roof_corners_tiled(paths, crs=None, *, tile_m: float = DEFAULT_TILE_M, buffer_m: float = DEFAULT_BUFFER_M,
                            min_edge_m: float | None = None, roof: str = "flat", sigma_strip_xy_m: float = 0.03,
                            sigma_strip_z_m: float = 0.03, work_dir=None, chunk_points: int = las_io.CHUNK_POINTS,
                            figure_cells: int = 0, work_name: str = "corners"):
    """``find_roof_corners`` of classified LAS/LAZ files (strips in one CRS) by tiles of ``tile_m`` with a
    ``buffer_m`` border (metres), read straight from the files: memory is set by the tile size.

    The files are streamed once into a scratch folder beside the output (``work_dir``), each point once as its
    file stores it (``_bin_corner_points``: about 20 bytes a point, refused before it starts when the disk has
    not room for 27; removed at the end, also on errors), and a tile takes its buffer from its neighbours'
    scratch files; the spacing of the building points comes from all of them; each tile's building points are clustered into roofs and a roof is kept by the
    tile whose core holds its reference point (its first point in file order), so every roof is found
    once. Roof ids are ranked as in the whole cloud (size, then the reference point), so the result
    equals the whole cloud's when every roof is smaller than the buffer, except the strip margin: a
    tile sees a strip's footprint only within its buffer (clipped there, and a gap in the strip that
    reaches past the buffer is not filled as a hole), so its margin is a lower bound of the whole
    cloud's, equal for the corners the score looks at (10 m from a strip edge) unless such a gap
    (e.g. a lake without returns, larger than the buffer) lies within 10 m of the corner. Returns (result as ``find_roof_corners``, crs, units, figure):
    with ``figure_cells`` > 0 the figure's nDSM (``simple_ndsm`` per tile on a grid of at most that many
    cells a side, and its extent in metres), else None.
    """
    import shutil

    from aerotri.core.atomic import temporary_dir

    if roof not in ("flat", "any"):
        raise InputError(f"roof must be 'flat' or 'any', not {roof!r}")
    if not (0 < buffer_m <= tile_m):
        raise InputError(f"buffer {buffer_m:g} m: must be positive and at most the tile size {tile_m:g} m")
    t_start = time.perf_counter()
    paths = [Path(p) for p in paths]
    names = ", ".join(str(p) for p in paths)
    work = temporary_dir(Path(work_dir) if work_dir is not None else paths[0].parent, work_name)
    try:
        tc = _bin_corner_points(paths, crs, work, tile_m, buffer_m, chunk_points)
        if tc.n_building == 0:
            stats = CornerStats(
                n_points=tc.n_points, n_building_points=0, point_spacing_m=None, n_roofs=0, n_outlines=0,
                n_corners_traced=0, n_corners=0, n_usable=0, n_roof_planes=0, min_edge_m=min_edge_m,
                min_edge_rule="given" if min_edge_m is not None else "none (no building points)", roof=roof,
                sigma_strip_xy_m=sigma_strip_xy_m, sigma_strip_z_m=sigma_strip_z_m, usable_score=USABLE_SCORE,
                median_sxy_usable_m=None, runtime_s=time.perf_counter() - t_start)
            raise NoRoofs(f"{names}: {no_building_points_message(tc.n_points, tc.class_counts)}", stats=stats,
                          crs=tc.crs, units=tc.units)
        spacing = _global_spacing_m(tc, chunk_points)
        min_edge_auto = min_edge_m is None
        if min_edge_auto:
            min_edge_m = default_min_edge_m(spacing)
        # Each tile's roofs; a tile keeps the roofs whose reference point lies in its core, numbered by their
        # key (size, reference point) until all are known, then ranked as cluster_roofs ranks them.
        keys, raw, outlines, faces = [], [], [], []
        fig = None
        tiles = [int(t) for t in np.flatnonzero(tc.used)]
        for tid in track(tiles, "roof corners", "tiles"):
            rec, rc = _tile_clusters(tc, tid, spacing, min_edge_m)
            if figure_cells:
                fig = _figure_tile(fig, rec, tc, tid, spacing, figure_cells)
            if rc is None or rc.n_roofs == 0:
                continue
            size, first, in_core = _roof_keys(rec, rc)
            owned = np.flatnonzero(in_core)
            # scoring tells a corner's own roof from the other points: the tile's other roofs are -1
            to_key = np.full(rc.n_roofs + 1, -1, np.int64)
            to_key[owned] = len(keys) + np.arange(len(owned))
            keys += [(-int(size[r]), int(first[r])) for r in owned]
            tile_raw = []
            for r in owned:
                roof_raw, outline, roof_faces = _one_roof(rc.xyz[rc.roof_label == r], int(to_key[r]), rc.spacing_m)
                tile_raw += roof_raw
                faces += roof_faces
                if outline is not None:
                    outlines.append(outline)
            if tile_raw:
                rc.roof_label = to_key[rc.roof_label]
                _score_corners(tile_raw, rc, min_edge_m=min_edge_m, roof=roof, sigma_strip_xy_m=sigma_strip_xy_m,
                               sigma_strip_z_m=sigma_strip_z_m)
                raw += tile_raw
    finally:
        shutil.rmtree(work, ignore_errors=True)
    # roof ids as the whole cloud's (by size, then reference point); roof order as its loop over roofs
    # (stable sorts: the order within a roof stays)
    rank = np.empty(len(keys), np.int64)
    rank[sorted(range(len(keys)), key=keys.__getitem__)] = np.arange(len(keys))
    for item in (*raw, *outlines, *faces):
        item["building_id"] = int(rank[item["building_id"]])
    for f in faces:
        f["plane"].roof_id = f["building_id"]
    raw.sort(key=lambda c: c["building_id"])
    outlines.sort(key=lambda o: o["building_id"])
    faces.sort(key=lambda f: f["building_id"])
    try:
        result = _finish(raw, outlines, faces, n_points=tc.n_points, n_building_points=tc.n_building,
                         spacing_m=spacing, n_roofs=len(keys), t_start=t_start, min_edge_m=min_edge_m, roof=roof,
                         sigma_strip_xy_m=sigma_strip_xy_m, sigma_strip_z_m=sigma_strip_z_m,
                         min_edge_auto=min_edge_auto)
    except NoRoofs as exc:
        raise NoRoofs(f"{names}: {exc}", stats=exc.stats and dataclasses.replace(
            exc.stats, tiles=len(tiles), tile_m=tile_m, buffer_m=buffer_m), crs=tc.crs, units=tc.units) from None
    except InputError as exc:
        raise InputError(f"{names}: {exc}") from None
    result = dataclasses.replace(result, stats=dataclasses.replace(result.stats, tiles=len(tiles), tile_m=tile_m,
                                                                   buffer_m=buffer_m))
    figure = None
    if fig is not None:
        figure = _crop_to_data(fig["ndsm"], fig["extent"], fig["cell"])
    return result, tc.crs, tc.units, figure


def _crop_to_data(ndsm: np.ndarray, extent, cell_m: float):
    """The figure's nDSM and extent (xmin, xmax, ymin, ymax) cut to the rows and columns holding data:
    the tile grid (whole tiles) reaches beyond the points."""
    rows, cols = np.flatnonzero(np.isfinite(ndsm).any(axis=1)), np.flatnonzero(np.isfinite(ndsm).any(axis=0))
    if not len(rows):
        return ndsm, extent
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    x0, y0 = extent[0], extent[2]
    return ndsm[r0:r1, c0:c1], (x0 + c0 * cell_m, x0 + c1 * cell_m, y0 + r0 * cell_m, y0 + r1 * cell_m)


def _figure_tile(fig, rec, tc: _TiledCloud, tid: int, spacing_m: float, max_cells: int):
    """Add a tile's core cells to the figure's nDSM (``simple_ndsm``: highest point minus the nearest
    ground point, here among the tile's points with its buffer), on a grid over the tiles' extent with
    cells of max(0.5 m, the spacing, extent / ``max_cells``)."""
    g = tc.grid
    if fig is None:
        w, h = g.ncols * g.tile_m, g.nrows * g.tile_m
        cell = max(0.5, spacing_m if np.isfinite(spacing_m) else 0.5, max(w, h) / max_cells)
        shape = (int(np.ceil(h / cell)), int(np.ceil(w / cell)))
        check_grid(*shape, cell, FIGURE_BYTES_PER_CELL, "the corners figure (nDSM)", option="--figure",
                   hint="use --no-figure ([corners] figure = false in a project)")
        fig = {"cell": cell, "ndsm": np.full(shape, np.nan),
               "extent": (g.x0_m, g.x0_m + shape[1] * cell, g.y0_m, g.y0_m + shape[0] * cell)}
    core = rec["core"] == 1
    if not core.any():
        return fig
    cell, ndsm = fig["cell"], fig["ndsm"]
    j = np.clip(np.floor((rec["x"] - g.x0_m) / cell).astype(np.int64), 0, ndsm.shape[1] - 1)
    i = np.clip(np.floor((rec["y"] - g.y0_m) / cell).astype(np.int64), 0, ndsm.shape[0] - 1)
    # on the figure's grid over the tile and its buffer: the highest core point per cell minus the lowest
    # ground point of the nearest cell holding ground (a KD-tree query per cell cost 3.7 CPU-s a tile)
    i0, j0 = int(i.min()), int(j.min())
    shape = (int(i.max()) - i0 + 1, int(j.max()) - j0 + 1)
    i, j = i - i0, j - j0
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (i[core], j[core]), rec["z"][core])
    ground_pt = rec["cls"] == GROUND
    if ground_pt.any():
        base = np.full(shape, np.inf)
        np.minimum.at(base, (i[ground_pt], j[ground_pt]), rec["z"][ground_pt])
        has = np.isfinite(base)
        if not has.all():
            near = ndimage.distance_transform_edt(~has, return_distances=False, return_indices=True)
            base = base[near[0], near[1]]
    else:
        base = np.full(shape, rec["z"].min())
    occupied = np.isfinite(top)
    view = ndsm[i0:i0 + shape[0], j0:j0 + shape[1]]
    view[occupied] = (top - base)[occupied]
    return fig


# ------------------------------------------------------------------------------------------------ output
def corners_csv_text(corners: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for c in corners:
        w.writerow([
            c["id"], f"{c['x']:.3f}", f"{c['y']:.3f}", f"{c['z']:.3f}", f"{c['sx_m']:.3f}", f"{c['sy_m']:.3f}",
            f"{c['sz_m']:.3f}", c["roof"], c["building_id"], f"{c['edge1_deg']:.2f}", f"{c['edge2_deg']:.2f}",
            f"{c['angle_deg']:.2f}", c["support_pts"], f"{c['score']:.3f}", c["usable"],
        ])
    return buf.getvalue()


def valid_outline(rings: list[np.ndarray]) -> dict | None:
    """GeoJSON geometry of a regularised roof outline (rings of corners, the first the exterior) that is valid: the
    fitted edges of a spike or of a courtyard next to the eave may cross (AHN3: 8 of 53 outlines were invalid
    polygons), so the area is rebuilt from the rings' structure (shapely ``make_valid`` "structure": the area the
    exterior encloses less the courtyards; crossings become vertices, lines of no area are dropped). Every corner
    stays where it was (the vertices are the rings' own and the crossings of their edges); None when no area is
    left."""
    closed = [np.vstack([r, r[:1]]) for r in rings]
    poly = shapely.Polygon(closed[0], closed[1:])
    if not poly.is_valid:
        poly = shapely.make_valid(poly, method="structure", keep_collapsed=False)
        parts = [g for g in getattr(poly, "geoms", [poly]) if isinstance(g, shapely.Polygon) and not g.is_empty]
        if not parts:
            return None
        poly = parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
    if poly.is_empty:
        return None
    return json.loads(shapely.to_geojson(shapely.orient_polygons(poly)))  # exteriors CCW, holes CW


def _outline_features(outlines: list[dict]) -> list[tuple[dict, dict]]:
    """(GeoJSON geometry, properties) of each regularised roof outline that keeps an area (``valid_outline``)."""
    out = []
    for o in outlines:
        if not o["rings"] or len(o["rings"][0]) < 3:
            continue  # no exterior ring left
        geometry = valid_outline([np.asarray(r, float).round(3) for r in o["rings"] if len(r) >= 3])
        if geometry is None:
            continue
        props = {k: o[k] for k in ("building_id", "roof", "n_points", "n_planes")}
        props.update(spacing_m=round(o["spacing_m"], 3), sigma0=round(o["sigma0"], 3),
                     theta_deg=round(o["theta_deg"], 3))
        out.append((geometry, props))
    return out


def _corners_geojson_document(corners: list[dict], outlines: list[dict], crs=None) -> dict:
    """Corners (Point) and regularised roof outlines (Polygon or MultiPolygon, valid: ``valid_outline``;
    exteriors CCW, courtyards CW), map CRS."""
    feats = [{"type": "Feature", "geometry": geometry, "properties": {"kind": "roof_outline", **props}}
             for geometry, props in _outline_features(outlines)]
    for c in corners:
        props = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items() if k not in ("x", "y", "z")}
        xyz = [round(c["x"], 3), round(c["y"], 3), round(c["z"], 3)]
        feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": xyz},
                      "properties": {"kind": "roof_corner", **props}})
    out = {"type": "FeatureCollection", "features": feats}
    if crs is not None:
        epsg = crs.to_epsg() if hasattr(crs, "to_epsg") else None
        name = f"urn:ogc:def:crs:EPSG::{epsg}" if epsg else str(crs)
        out["crs"] = {"type": "name", "properties": {"name": name}}  # legacy member: coordinates are projected
    return out


def write_roof_outlines(path, outlines: list[dict], crs) -> Path:
    """The regularised roof outlines as a GeoPackage (layer ``roof_outlines``, MultiPolygon, in ``crs``): the
    eave lines the LiDAR traced, for QGIS and as the true ortho's building footprints when no cadastre is given
    (``ortho rectify --footprints``; the chain's default, ``[rectify] footprints``)."""
    from shapely.geometry import shape

    from aerotri.core.vector_files import VectorLayer, write_layers

    feats = _outline_features(outlines)
    geoms = [shape(g) for g, _ in feats]
    fields = {"building_id": np.array([int(p["building_id"]) for _, p in feats], np.int64),
              "roof": np.array([str(p["roof"]) for _, p in feats], object),
              "n_points": np.array([int(p["n_points"]) for _, p in feats], np.int64),
              "spacing_m": np.array([float(p["spacing_m"]) for _, p in feats], float)}
    note = "regularised roof (eave) outlines of lidarctl corners; building_id as in corners.csv"
    return write_layers(path, [VectorLayer("roof_outlines", "MultiPolygon", geoms, fields, note=note)], crs=crs,
                        timestamp=OUTLINES_TIMESTAMP)


ROOF_PLANE_MODEL = (
    "z = a (x - x0) + b (y - y0) + c: x, y, x0, y0 in xy_unit, z and c in z_unit, a and b in z_unit per xy_unit; "
    "cov_abc_m: covariance of (a, b, c) with x, y, z in metres (a, b in m/m, c in m); height sigma of the fit at "
    "(x, y) in metres: sqrt(j' cov_abc_m j), j = ((x - x0) xy_unit_m, (y - y0) xy_unit_m, 1); sigma_strip_xy_m, "
    "sigma_strip_z_m: georeferencing error of a LiDAR strip, common to all points of a face")


def _crs_member(crs) -> dict | None:
    """The legacy GeoJSON ``crs`` member (coordinates are projected, not WGS 84) of a pyproj CRS."""
    if crs is None:
        return None
    epsg = crs.to_epsg() if hasattr(crs, "to_epsg") else None
    return {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}" if epsg else crs.to_wkt()}}


def roof_planes_geojson(faces: list[dict], units: LengthUnits | None, *, sigma_strip_xy_m: float,
                        sigma_strip_z_m: float, crs=None) -> str:
    """roof_planes.geojson's text (``aerotri.adjust.surface.read_roof_planes`` reads it): one Polygon per roof face (its footprint shrunk inward by ``margin_m``, exterior
    CCW) with the face's plane (``ROOF_PLANE_MODEL``); coordinates in the CRS's units (``units``; None: metres,
    no unit names). ``faces`` as ``RoofCorners.in_crs_units`` gives them; the strip sigmas in metres."""
    feats = []
    for n, f in enumerate(faces, 1):
        rings = [np.asarray(f["rings"][0]).round(3).tolist()] + [np.asarray(r).round(3).tolist() for r in f["rings"][1:]]
        feats.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": rings}, "properties": {
            "kind": "roof_plane", "id": f"RP{n:05d}", "building_id": f["building_id"],
            "x0": round(f["x0"], 3), "y0": round(f["y0"], 3), "a": f["a"], "b": f["b"], "c": round(f["c"], 4),
            "cov_abc_m": np.asarray(f["cov_abc_m"]).tolist(), "rms_m": round(f["rms_m"], 4), "n_points": f["n_points"],
            "slope_deg": round(f["slope_deg"], 3), "margin_m": round(f["margin_m"], 3), "area_m2": round(f["area_m2"], 1),
        }})
    out = {"type": "FeatureCollection", "plane_model": ROOF_PLANE_MODEL,
           "xy_unit_m": units.xy_m if units is not None else 1.0, "z_unit_m": units.z_m if units is not None else 1.0,
           "xy_unit": units.xy_name if units is not None else None, "z_unit": units.z_name if units is not None else None,
           "sigma_strip_xy_m": sigma_strip_xy_m, "sigma_strip_z_m": sigma_strip_z_m, "features": feats}
    member = _crs_member(crs)
    if member is not None:
        out["crs"] = member
    return json.dumps(out)


def _faces_in_crs_units(faces: list[dict], units) -> list[dict]:
    """Roof faces (``_roof_faces``, metres) as ``roof_planes_geojson`` writes them: footprint rings, centroid
    and plane coefficients in the CRS's units; covariance, rms and margin in metres."""
    out = []
    for f in faces:
        pl, poly = f["plane"], f["polygon"]
        rings = [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors]
        k = units.xy_m / units.z_m  # z_unit per xy_unit of a slope of 1 m/m
        out.append(dict(
            building_id=int(f["building_id"]), rings=[np.asarray(units.xy_from_m(r), float) for r in rings],
            x0=float(units.xy_from_m(pl.x0)), y0=float(units.xy_from_m(pl.y0)),
            a=float(pl.abc[0] * k), b=float(pl.abc[1] * k), c=float(units.z_from_m(pl.abc[2])),
            cov_abc_m=np.asarray(pl.cov_abc, float), rms_m=float(pl.rms_m), n_points=int(pl.n_points),
            slope_deg=pl.slope_deg, margin_m=float(f["margin_m"]), area_m2=float(poly.area),
        ))
    return out


def write_corner_files(outdir, result: RoofCorners, crs=None, source: str | None = None, inputs=(),
                       settings_record: dict | None = None) -> CornerFiles:
    """Write corners.csv, corners.geojson, roof_planes.geojson, roof_outlines.gpkg (with a ``crs``) and corners.json
    (summary) atomically; return the paths and the summary.

    ``result``: corners and faces in the CRS's units (``RoofCorners.in_crs_units``; a result in metres without
    units is written as metres). ``inputs``: the input files, which no output may replace. ``settings_record``: the
    settings with their sources (``aerotri.core.settings.Resolved.record``), corners.json ``settings``."""
    outdir = Path(outdir)
    files = CornerFiles(outdir / "corners.csv", outdir / "corners.geojson", outdir / ROOF_PLANES_FILE,
                        outdir / "corners.json", None)
    if crs is not None:
        files = dataclasses.replace(files, outlines=outdir / ROOF_OUTLINES_FILE)
    for p in (files.csv, files.geojson, files.planes, files.summary_json, files.outlines):
        if p is not None:
            refuse_input_as_output(p, inputs, "OUTDIR")
    outdir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(files.csv, corners_csv_text(result.corners))
    write_text_atomic(files.geojson, json.dumps(_corners_geojson_document(result.corners, result.outlines, crs)))
    if files.outlines is not None:
        write_roof_outlines(files.outlines, result.outlines, crs)
    faces = result.faces
    if result.units is None:  # still in metres (find_roof_corners' result as it is)
        from lidarctl.units import METRE

        faces = _faces_in_crs_units(faces, METRE)
    write_text_atomic(files.planes, roof_planes_geojson(
        faces, result.units, sigma_strip_xy_m=result.stats.sigma_strip_xy_m,
        sigma_strip_z_m=result.stats.sigma_strip_z_m, crs=crs))
    summary = CornerControlResult(source, crs.to_string() if crs is not None else None, result.units,
                                  result.stats, settings_record)
    write_text_atomic(files.summary_json, summary.to_json())
    return dataclasses.replace(files, summary=summary)


# ------------------------------------------------------------------------------------------------ figure
def simple_ndsm(xyz: np.ndarray, classification: np.ndarray, cell_m: float = 1.0):
    """Quick nDSM for figures: highest point per cell minus the ground (nearest ground point per cell).
    Coordinates and ``cell_m`` in metres; returns the nDSM (m) and its extent (m)."""
    xy = xyz[:, :2]
    origin = xy.min(axis=0)
    cols, rows = np.floor((xy.max(axis=0) - origin) / cell_m).astype(np.int64) + 1
    check_grid(int(rows), int(cols), cell_m, NDSM_BYTES_PER_CELL, "the corners figure (nDSM)", option="--figure",
               hint="use --no-figure (or are the strips far apart?)")
    ij = np.floor((xy - origin) / cell_m).astype(np.int64)
    shape = tuple(ij.max(axis=0)[::-1] + 1)
    dsm = np.full(shape, -np.inf)
    np.maximum.at(dsm, (ij[:, 1], ij[:, 0]), xyz[:, 2])
    g = classification == GROUND
    cy, cx = np.mgrid[0: shape[0], 0: shape[1]]
    centres = origin + (np.column_stack([cx.ravel(), cy.ravel()]) + 0.5) * cell_m
    if g.sum() > 0:
        _, nn = cKDTree(xy[g]).query(centres)
        ground = xyz[g, 2][nn].reshape(shape)
    else:
        ground = np.full(shape, np.nanmin(xyz[:, 2]))
    ndsm = np.where(np.isfinite(dsm), dsm - ground, np.nan)
    extent = (origin[0], origin[0] + shape[1] * cell_m, origin[1], origin[1] + shape[0] * cell_m)
    return ndsm, extent


def _fill_small_gaps(ndsm: np.ndarray, max_cells: float = 2.0) -> np.ndarray:
    """For display: empty cells within ``max_cells`` of a cell with points take its value (where one strip
    alone covers the ground, scan lines leave empty cells between them that white out the picture into
    grey bands)."""
    empty = ~np.isfinite(ndsm)
    if not empty.any() or empty.all():
        return ndsm
    dist, near = ndimage.distance_transform_edt(empty, return_indices=True)
    return np.where(empty & (dist <= max_cells), ndsm[near[0], near[1]], ndsm)


def plot_corners(path, ndsm, extent, outlines, corners, *, truth_xy=None, reference_polygons=None, title="",
                 window=None, marker_size=4.0, xy_unit: str = "m", vlines=()):
    """Outlines and corners over the nDSM (PNG, matplotlib Agg); truth corners / reference polygons optional.
    ``vlines``: x of vertical lines to draw (e.g. the split of a spatial hold-out).

    ``window``: (xmin, xmax, ymin, ymax) to zoom into; default the whole nDSM extent. Coordinates,
    extent and window in ``xy_unit`` (the axis labels); the nDSM in metres.
    """
    plt = pyplot()

    view = extent if window is None else window
    ndsm = _fill_small_gaps(ndsm)
    fig, ax = plt.subplots(figsize=(10, 10 * (view[3] - view[2]) / max(view[1] - view[0], 1e-9) + 0.5))
    # Cells without a height (water drop-outs, gaps) in a colour of their own: drawn white they read as the
    # tallest roofs of the grey scale.
    cmap = plt.get_cmap("gray").with_extremes(bad="lightsteelblue")
    im = ax.imshow(ndsm, origin="lower", extent=extent, cmap=cmap, vmin=0, vmax=np.nanpercentile(ndsm, 99.5))
    fig.colorbar(im, ax=ax, shrink=0.6, label="nDSM (m)")
    if np.isnan(ndsm).any():
        from matplotlib.patches import Patch

        ax.add_artist(ax.legend(handles=[Patch(color="lightsteelblue", label="no nDSM (no returns)")],
                                loc="lower right", fontsize=8))
    for poly in reference_polygons or []:
        ax.plot(*np.asarray(poly).T, color="tab:cyan", lw=0.8)
    for o in outlines:
        for r in o["rings"]:
            if len(r) >= 3:
                rr = np.vstack([r, r[:1]])
                ax.plot(rr[:, 0], rr[:, 1], color="tab:orange", lw=1.0)
    if truth_xy is not None and len(truth_xy):
        ax.plot(truth_xy[:, 0], truth_xy[:, 1], "+", color="tab:green", ms=2 * marker_size,
                label="truth / reference vertices")
    use = np.array([c["usable"] for c in corners], bool)
    cxy = np.array([[c["x"], c["y"]] for c in corners]).reshape(-1, 2)
    ax.plot(cxy[~use, 0], cxy[~use, 1], "o", mfc="none", color="tab:blue", ms=marker_size, label="corner (not usable)")
    ax.plot(cxy[use, 0], cxy[use, 1], "o", color="tab:red", ms=marker_size, label="usable corner")
    for x in vlines:
        ax.axvline(x, color="tab:purple", lw=1.0, ls="--")
    ax.set_aspect("equal")
    ax.set_xlim(view[0], view[1])
    ax.set_ylim(view[2], view[3])
    ax.ticklabel_format(useOffset=False, style="plain")  # a northing of 3.4 million m, not "3.4095" under "1e6"
    ax.set_xlabel(f"x ({xy_unit})")
    ax.set_ylabel(f"y ({xy_unit})")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    save_png(fig, path, dpi=130)


# ------------------------------------------------------------------------------------------------ the stage
@dataclasses.dataclass(frozen=True)
class CornerSettings:
    """Options of the roof-corner stage (``lidarctl corners``, ``[corners]`` in project.toml)."""

    SECTION: ClassVar[str] = "corners"

    min_edge_m: float | None = setting(None, min=0.5, help="Report corners whose two edges are at least this long "
                                                            "(m); default max(2 m, 8 point spacings) of the roofs' "
                                                            "measured spacing.")
    roof: str = setting("flat", choices=("flat", "any"), help="Roofs whose corners may be marked usable as control.")
    sigma_strip_xy_m: float = setting(0.03, min=0.0, help="Horizontal georeferencing error of a strip, added to "
                                                          "every corner's sx_m, sy_m (m).")
    sigma_strip_z_m: float = setting(0.03, min=0.0, help="Vertical georeferencing error of a strip, added to every "
                                                         "corner's sz_m (m).")
    figure: bool = setting(True, help="Also write corners.png (outlines and corners over the nDSM).")
    tile_m: float = setting(DEFAULT_TILE_M, min=1.0, help="Tile size (m): the files are processed by tiles "
                                                          "(memory set by the tile, not the block).")
    buffer_m: float = setting(DEFAULT_BUFFER_M, min=1.0, help="Overlap buffer around each tile (m): larger than the "
                                                              "largest roof, at most the tile size.")


def _record_no_usable(outdir: Path, summary: CornerControlResult) -> CornerControlResult:
    """corners.json saying why no corner is usable, the corner files (and roof planes) of an earlier run removed."""
    outdir.mkdir(parents=True, exist_ok=True)
    from aerotri.core.atomic import remove_output

    for name in ("corners.csv", "corners.geojson", "corners.png", ROOF_PLANES_FILE, ROOF_OUTLINES_FILE):
        remove_output(outdir / name)  # with corners.json, one commit: all old on a failure
    write_text_atomic(outdir / "corners.json", summary.to_json())
    return summary


@committed(lambda paths, outdir, *a, **k: Path(outdir))
def corner_control(paths, outdir, settings: CornerSettings | Resolved = CornerSettings(), crs=None,
                   record_none: bool = False) -> CornerControlResult:
    """The stage: roof corners of classified LAS/LAZ file(s) (one or more strips in one CRS) as control
    candidates. ``crs``: the CRS of files that have none (never guessed).

    Writes corners.csv, corners.geojson, roof_planes.geojson (the roof faces as surface control), roof_outlines.gpkg
    (the roof outlines: QGIS, the true ortho's footprints), corners.json (summary) and, with ``settings.figure``,
    corners.png into ``outdir`` when at least one corner is usable as control; x, y, z in the files' CRS and units,
    sigmas in metres (every length setting is in metres, also for clouds in feet). Without a usable corner it writes
    nothing, or, with ``record_none`` (the chain, which goes on without LiDAR control), only corners.json saying why
    (``n_usable`` 0; also for a cloud with no roof at all, ``NoRoofs``: no building points, no roof outline, which
    ``lidarctl corners`` is told by that error), and removes the corner files (and roof planes) of an earlier run,
    so that nothing downstream takes stale corners; the chain then adjusts as ``lidarctl corners``' exit code 2
    tells a user to (README), without roof planes. Returns what corners.json holds, with ``no_usable`` the one-line
    reason when no corner is usable (else None).
    """
    paths = [Path(p) for p in paths]
    outdir = Path(outdir)
    resolved = settings_of(settings, CornerSettings)  # a Resolved (lidarctl corners, the chain): with sources
    s = resolved.settings
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(paths)  # a strip given twice would count every point twice
    for name in ("corners.csv", "corners.geojson", "corners.json", "corners.png", ROOF_PLANES_FILE, ROOF_OUTLINES_FILE):
        refuse_input_as_output(outdir / name, paths, "OUTDIR")
    names = ", ".join(str(p) for p in paths)
    if s.buffer_m > s.tile_m:
        raise OptionError(f"buffer {s.buffer_m:g} m is larger than the tile size {s.tile_m:g} m", param="--buffer-m")
    try:
        result, crs_out, units, figure = find_roof_corners_tiled(
            paths, crs=crs, tile_m=s.tile_m, buffer_m=s.buffer_m, min_edge_m=s.min_edge_m, roof=s.roof,
            sigma_strip_xy_m=s.sigma_strip_xy_m, sigma_strip_z_m=s.sigma_strip_z_m,
            work_dir=next(p for p in (outdir, *outdir.parents) if p.is_dir()),
            figure_cells=FIGURE_CELLS if s.figure else 0, work_name=f"{outdir.name}.corners")
    except NoRoofs as exc:  # no roof at all (no building points, no outline): the chain goes on without control
        if not record_none or exc.stats is None:
            raise
        crs_text = exc.crs.to_string() if exc.crs is not None else None
        summary = CornerControlResult(names, crs_text, exc.units, exc.stats, resolved.record(), no_usable=str(exc))
        return _record_no_usable(outdir, summary)
    st = result.stats
    crs_text = crs_out.to_string() if crs_out is not None else None
    if st.n_usable == 0:
        reason = (f"{names}: no usable roof corner ({st.n_corners} corners on {st.n_outlines} roof outlines, "
                  f"none with score >= {st.usable_score} and edges >= {st.min_edge_m:.2f} m"
                  f"{' on a flat roof' if s.roof == 'flat' else ''}; point spacing {st.point_spacing_m:.2f} m)")
        summary = CornerControlResult(names, crs_text, units, st, resolved.record(), no_usable=reason)
        if not record_none:
            return summary
        return _record_no_usable(outdir, summary)
    if s.figure:
        ndsm, extent_m = figure
    out = result.in_crs_units(units)
    files = write_corner_files(outdir, out, crs=crs_out, source=names, inputs=paths, settings_record=resolved.record())
    if s.figure:
        extent = tuple(float(units.xy_from_m(v)) for v in extent_m)
        plot_corners(outdir / "corners.png", ndsm, extent, out.outlines, out.corners,
                     title=f"roof corners: {st.n_usable} usable of {st.n_corners} (edges >= {st.min_edge_m:.2f} m)",
                     xy_unit=units.xy_name)
    return files.summary
