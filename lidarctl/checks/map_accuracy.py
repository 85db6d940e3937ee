"""Map accuracy of a classification against a reference map, as the seeds report it
(``lidarctl evaluate PRED --reference REF``).

PRED: a classified LAS/LAZ cloud or a class GeoTIFF; REF: a class GeoTIFF or class polygons
(GeoPackage, GeoJSON). Both go onto one grid (``lidarctl.classify.class_grid``: the reference raster's grid,
else the prediction raster's, else ``res_m`` cells over the cloud's bounds) as ASPRS codes of the map
classes (building 6, tree 5, grass 3, road 11, bare ground 2, water 9). Only cells labelled on both
sides count (a cloud's cell without a point, a raster's nodata are left out).

Polygon references: cells outside every polygon are "other" (OTHER, 0: none of the reference's classes),
and predicted classes the reference does not use count as "other" too, so building footprints give a
building / not-building map.

Measures
* Pixel confusion matrix (rows reference, columns prediction) with producer's, user's and overall
  accuracy and Cohen's kappa (``lidarctl.checks.classes.confusion``); counts are cells, areas m^2.
* Buildings per area (seed 002): building = positive; type I = reference building area not found /
  reference building area, type II = area wrongly labelled building / reference non-building area,
  overall = correctly labelled area / evaluated area; kappa; completeness TP/(TP+FN) and correctness
  TP/(TP+FP) by area.
* Buildings per building (by count): reference buildings are the polygons (raster references: the
  8-connected regions of building cells), detected ones are the 8-connected regions of predicted
  building cells; objects with less than ``min_building_m2`` evaluated area are not counted. A
  reference building is found when at least ``min_overlap`` of its area is predicted building
  (completeness = found / reference buildings); a detected building is correct when at least
  ``min_overlap`` of its area is reference building (correctness = correct / detected buildings).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
from scipy import ndimage

from aerotri.core.errors import InputError, OptionError
from aerotri.core.records import to_record
from lidarctl.classify import class_grid as cg
from lidarctl.checks.classes import Confusion, confusion, filter_errors

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BUILDING = 6
RASTER_SUFFIXES = (".tif", ".tiff")
CLOUD_SUFFIXES = (".las", ".laz")
_EIGHT = np.ones((3, 3), bool)


@dataclasses.dataclass(frozen=True)
class MapEvalSettings:
    """Options of ``lidarctl evaluate --reference``.

    ``res_m``: cell size (m; default 0.5 m when neither side is a raster, else the raster's; given with a
    raster, the raster is sampled at the centres of ``res_m`` cells, e.g. to match a sparse cloud); ``min_overlap``: fraction of a building's
    area that must overlap for it to count as found/correct; ``min_building_m2``: smaller objects are
    not counted per building; ``class_field`` / ``reference_class``: the class of reference polygons
    (an attribute, or one class for all); ``map_pred`` / ``map_ref``: class mappings FROM -> TO applied
    after ``class_grid.DEFAULT_CLOUD_MAP`` (clouds) (TO 255: leave the class out); ``crs``: for inputs
    without a CRS; ``within``: evaluate only inside these polygons (a vector file in the same CRS), or
    ``hull``: inside the convex hulls of the reference polygons' blocks (a reference that maps a few
    blocks completely, e.g. footprints of part of the area).
    """

    res_m: float | None = None
    min_overlap: float = 0.5
    min_building_m2: float = 10.0
    class_field: str = "class"
    reference_class: str | None = None
    map_pred: dict = dataclasses.field(default_factory=dict)
    map_ref: dict = dataclasses.field(default_factory=dict)
    crs: str | None = None
    within: str | None = None

    def __post_init__(self):
        if self.res_m is not None and not (np.isfinite(self.res_m) and self.res_m > 0):
            raise OptionError(f"--res-m {self.res_m}: must be a positive cell size in metres", param="--res-m")
        if not 0 < self.min_overlap <= 1:
            raise OptionError(f"--min-overlap {self.min_overlap}: must be in (0, 1]", param="--min-overlap")
        if not (np.isfinite(self.min_building_m2) and self.min_building_m2 >= 0):
            raise OptionError(f"--min-building-m2 {self.min_building_m2}: must be >= 0", param="--min-building-m2")


@dataclasses.dataclass
class BuildingAccuracy:
    """Per-area and per-building building measures (module docstring); percentages, areas in m^2."""

    type_i_error_pct: float
    type_ii_error_pct: float
    overall_accuracy_pct: float
    kappa_pct: float
    completeness_area_pct: float
    correctness_area_pct: float
    reference_area_m2: float
    detected_area_m2: float
    n_reference: int
    n_found: int
    n_detected: int
    n_correct: int
    completeness_count_pct: float
    correctness_count_pct: float
    min_overlap: float
    min_building_m2: float


@dataclasses.dataclass
class MapAccuracy:
    """Result of ``evaluate_map``: the pixel confusion matrix (``evaluate.confusion``) and the
    building measures (None when neither side has a building)."""

    confusion: Confusion
    buildings: BuildingAccuracy | None
    cell_m: float
    n_cells: int
    n_cells_left_out: int
    prediction: str
    reference: str

    def to_json(self) -> str:
        """The --json file's text: the fields, undefined building ratios (no building on a side) as null, and the
        class names."""
        d = dataclasses.asdict(self)
        d["buildings"] = None if self.buildings is None else to_record(self.buildings, finite=True)
        d["class_names"] = {str(c): cg.CLASS_LABELS.get(c, str(c)) for c in self.confusion.classes}
        return json.dumps(d, indent=2)


def _pct(a: float, b: float) -> float:
    return float("nan") if b == 0 else 100.0 * a / b


def _overlaps(labels: np.ndarray, hit: np.ndarray, valid: np.ndarray):
    """(area in cells, cells where ``hit``) per label 1..max, over ``valid`` cells."""
    n = int(labels.max(initial=0))
    lab = labels[valid]
    area = np.bincount(lab, minlength=n + 1)[1:]
    over = np.bincount(lab, weights=hit[valid], minlength=n + 1)[1:]
    return area, over


def building_accuracy(pred: np.ndarray, ref: np.ndarray, valid: np.ndarray, *, cell_area_m2: float,
                      ref_ids: np.ndarray | None = None, min_overlap: float = 0.5,
                      min_building_m2: float = 10.0) -> BuildingAccuracy:
    """Building measures of boolean building rasters ``pred`` and ``ref`` over ``valid`` cells;
    ``ref_ids``: reference building objects (labels > 0, e.g. polygon ids), else the 8-connected
    regions of ``ref``. Cell counts become areas by ``cell_area_m2``."""
    pred, ref, valid = (np.asarray(a, bool) for a in (pred, ref, valid))
    area = filter_errors(pred[valid], ref[valid])
    tp = int(np.sum(pred & ref & valid))
    fn = int(np.sum(~pred & ref & valid))
    fp = int(np.sum(pred & ~ref & valid))
    if ref_ids is None:
        ref_ids, _ = ndimage.label(ref & valid | (~valid & ndimage.binary_closing(ref & valid, _EIGHT)),
                                   structure=_EIGHT)
    else:
        ref_ids = np.where(ref, ref_ids, 0)
    # Unlabelled cells (no LiDAR point) inside a roof must not split it: they join the object they close
    # (a 3x3 closing), its area still counts labelled cells only.
    det_ids, _ = ndimage.label(pred & valid | (~valid & ndimage.binary_closing(pred & valid, _EIGHT)),
                               structure=_EIGHT)
    min_cells = min_building_m2 / cell_area_m2
    r_area, r_hit = _overlaps(ref_ids, pred, valid)
    d_area, d_hit = _overlaps(det_ids, ref, valid)
    r_keep, d_keep = (r_area >= min_cells) & (r_area > 0), (d_area >= min_cells) & (d_area > 0)
    n_found = int(np.sum(r_hit[r_keep] >= min_overlap * r_area[r_keep]))
    n_correct = int(np.sum(d_hit[d_keep] >= min_overlap * d_area[d_keep]))
    return BuildingAccuracy(
        type_i_error_pct=area.type_i_error_pct, type_ii_error_pct=area.type_ii_error_pct,
        overall_accuracy_pct=100.0 - area.total_error_pct, kappa_pct=area.kappa_pct,
        completeness_area_pct=_pct(tp, tp + fn), correctness_area_pct=_pct(tp, tp + fp),
        reference_area_m2=(tp + fn) * cell_area_m2, detected_area_m2=(tp + fp) * cell_area_m2,
        n_reference=int(r_keep.sum()), n_found=n_found, n_detected=int(d_keep.sum()), n_correct=n_correct,
        completeness_count_pct=_pct(n_found, int(r_keep.sum())), correctness_count_pct=_pct(n_correct, int(d_keep.sum())),
        min_overlap=min_overlap, min_building_m2=min_building_m2)


def score_maps(pred: np.ndarray, ref: np.ndarray, cell_area_m2: float, ref_ids: np.ndarray | None = None,
               min_overlap: float = 0.5, min_building_m2: float = 10.0):
    """(Confusion, BuildingAccuracy or None, evaluated cells) of two class rasters on one grid
    (ASPRS codes; IGNORE cells left out)."""
    valid = (pred != cg.IGNORE) & (ref != cg.IGNORE)
    conf = confusion(pred[valid], ref[valid])
    has_building = bool(np.any(ref[valid] == BUILDING) or np.any(pred[valid] == BUILDING))
    bld = building_accuracy(pred == BUILDING, ref == BUILDING, valid, cell_area_m2=cell_area_m2, ref_ids=ref_ids,
                            min_overlap=min_overlap, min_building_m2=min_building_m2) if has_building else None
    return conf, bld, int(valid.sum())


def _kind(path: Path, allowed: tuple, what: str) -> str:
    suffix = path.suffix.lower()
    if suffix in RASTER_SUFFIXES and "raster" in allowed:
        return "raster"
    if suffix in CLOUD_SUFFIXES and "cloud" in allowed:
        return "cloud"
    if suffix in (".gpkg", ".geojson", ".json", ".shp", ".fgb") and "polygons" in allowed:
        return "polygons"
    raise InputError(f"{path}: {what} must be {' or '.join(allowed)} "
                     f"(.tif{', .las/.laz' if 'cloud' in allowed else ''}"
                     f"{', .gpkg/.geojson' if 'polygons' in allowed else ''}), not {suffix or 'no suffix'}")


def evaluate_map(pred_paths, ref_path, params: MapEvalSettings = MapEvalSettings()) -> MapAccuracy:
    """The stage (``lidarctl evaluate PRED... --reference REF``): the prediction (one class raster, or one or
    more classified clouds: strips) and the reference onto one grid, then ``score_maps``."""
    pred_paths = [Path(pred_paths)] if isinstance(pred_paths, (str, Path)) else [Path(q) for q in pred_paths]
    from lidarctl.io import check_distinct_clouds

    check_distinct_clouds(pred_paths)  # a strip given twice would count every point twice
    ref_path = Path(ref_path)
    kinds = {_kind(q, ("cloud", "raster"), "the prediction") for q in pred_paths}
    pk = kinds.pop()
    if kinds or (pk == "raster" and len(pred_paths) > 1):
        raise InputError(f"{pred_paths[0]}: the prediction is one class raster or classified clouds (strips), "
                         "not a mixture")
    rk = _kind(ref_path, ("raster", "polygons"), "--reference")
    for p in (*pred_paths, ref_path):
        if not p.is_file():
            raise InputError(f"{p}: no such file")
    pred_name = str(pred_paths[0]) + (f" (+{len(pred_paths) - 1} strips)" if len(pred_paths) > 1 else "")
    polys = ref_ids = None
    if rk == "raster":
        ref, grid = cg.read_class_raster(ref_path, params.crs)
        if params.res_m is not None:
            fine = grid
            grid = cg.regrid(fine, params.res_m)
            ref = cg.resample_nearest(ref, fine, grid)
    else:
        polys = cg.read_class_polygons(ref_path, params.class_field, params.reference_class)
    res_m = params.res_m or 0.5
    if pk == "cloud":
        if rk == "raster":
            # The reference's grid, in the same CRS (so the same units) as the clouds.
            crs = cg.common_crs(cg.cloud_grid(pred_paths, grid.cell_m, params.crs)[0].crs, pred_paths[0],
                                grid.crs, ref_path)
        else:
            grid, _ = cg.cloud_grid(pred_paths, res_m, params.crs)
            crs = cg.common_crs(grid.crs, pred_paths[0], polys.crs, ref_path)
        pred = cg.remap(cg.cloud_classes(pred_paths, grid), cg.DEFAULT_CLOUD_MAP)
    else:
        pred_r, pgrid = cg.read_class_raster(pred_paths[0], params.crs)
        if rk == "raster":
            crs = cg.common_crs(pgrid.crs, pred_paths[0], grid.crs, ref_path)
            pred = cg.resample_nearest(pred_r, pgrid, grid)
        else:
            crs = cg.common_crs(pgrid.crs, pred_paths[0], polys.crs, ref_path)
            grid, pred = pgrid, pred_r
            if params.res_m is not None:
                grid = cg.regrid(pgrid, params.res_m)
                pred = cg.resample_nearest(pred_r, pgrid, grid)
    grid = dataclasses.replace(grid, crs=crs)
    if polys is not None:
        ref, ref_ids = cg.rasterize_polygons(polys, grid)
        ref_ids = np.where(ref == BUILDING, ref_ids, 0)
    pred, ref = cg.remap(pred, params.map_pred), cg.remap(ref, params.map_ref)
    if params.within is not None:
        ref = np.where(_within_mask(params.within, polys, grid, ref_path), ref, cg.IGNORE).astype(np.uint8)
    if polys is not None:
        # Classes the reference does not map are "other" in the prediction too (footprints: building or not).
        used = np.unique(np.r_[polys.codes, cg.OTHER])
        pred = np.where((pred == cg.IGNORE) | np.isin(pred, used), pred, cg.OTHER).astype(np.uint8)
    labelled = pred != cg.IGNORE
    if not np.any(labelled & (ref != cg.IGNORE)):
        raise InputError(f"{pred_name} and {ref_path} share no labelled cell (do they cover the same area, in one CRS?)")
    conf, bld, n = score_maps(pred, ref, grid.cell_area_m2, ref_ids, params.min_overlap, params.min_building_m2)
    log.debug("%s vs %s: %d cells of %g m", pred_name, ref_path, n, grid.cell_m)  # the summary says it (s95: twice)
    return MapAccuracy(conf, bld, grid.cell_m, n, int(pred.size - n), pred_name, str(ref_path))


def _within_mask(within: str, polys, grid, ref_path) -> np.ndarray:
    """The evaluation area of ``MapEvalSettings.within`` on ``grid``."""
    from aerotri.geom.crs.definition import same_horizontal

    if within == "hull":
        if polys is None:
            raise OptionError(f"--within hull: only for a polygon reference ({ref_path} is a raster)", param="--within")
        return cg.rasterize_mask(cg.block_hulls(polys), grid)
    area = cg.read_class_polygons(within, all_class=cg.OTHER)
    if area.crs is not None and grid.crs is not None and not same_horizontal(area.crs, grid.crs):
        raise OptionError(f"--within {within}: its CRS differs from the evaluation's", param="--within")
    return cg.rasterize_mask(area.geometries, grid)


def format_map_report(result: MapAccuracy) -> str:
    """The confusion matrix with class names and the building measures as a readable table."""
    from lidarctl.checks.classes import format_confusion

    lines = [f"{result.prediction} against {result.reference}: {result.n_cells:,} cells of {result.cell_m:g} m "
             f"({result.n_cells_left_out:,} left out: unlabelled on one side or outside --within)", "",
             format_confusion(result.confusion, cg.CLASS_LABELS)]
    b = result.buildings
    if b is not None:
        lines += ["", "buildings by area:        type I {:6.2f} %   type II {:6.2f} %   overall {:6.2f} %   kappa {:6.2f} %"
                  .format(b.type_i_error_pct, b.type_ii_error_pct, b.overall_accuracy_pct, b.kappa_pct),
                  "                          completeness {:6.2f} %   correctness {:6.2f} %   "
                  "(reference {:,.0f} m2, detected {:,.0f} m2)".format(
                      b.completeness_area_pct, b.correctness_area_pct, b.reference_area_m2, b.detected_area_m2),
                  f"buildings by count (>= {b.min_overlap:.0%} overlap, >= {b.min_building_m2:g} m2): "
                  f"completeness {b.n_found}/{b.n_reference} = {b.completeness_count_pct:.2f} %   "
                  f"correctness {b.n_correct}/{b.n_detected} = {b.correctness_count_pct:.2f} %"]
    return "\n".join(lines)
