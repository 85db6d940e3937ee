"""Buildings of lidarctl classify on the AHN3 Delft crop against the BGT footprints, per area and per
object, per quarter of the crop; and the ``lidarctl vectors`` building layer against the footprints.

The BGT (an independent survey of the building walls) is the target reference (issue 44); AHN3's own
class 6 is scored per point elsewhere (bench/eval_ahn3_holdout.py).

Per area: our building class rasterised at 0.5 m (a cell takes the class of its highest non-noise
point, as ``lidarctl evaluate --reference``; a cell without points takes the class of the nearest cell
with points), the footprints rasterised on the same grid (cell centre inside). Cells whose centre lies
within 0.5 m of a footprint outline are ignored (the tolerance band: wall line vs eave, one cell of
rasterisation). Scored inside the convex hulls of the BGT blocks (footprints less than 1 m apart; the
BGT maps every building there), split into the quarters of bench/eval_ahn3_holdout.py (median x / y
of the points). Completeness = building cells found / footprint cells; correctness = building cells
on footprints / building cells.
Per object: a footprint is found when at least half of its cells are building (its quarter: the one
holding its centroid).
Vectors: ``lidarctl vectors`` (library ``map_vectors.extract_vectors``) of the classified crop; a
footprint is found on the map when its centroid lies inside a polygon of the buildings layer. Counted
over the footprints on the crop: centroid inside the crop's extent and LiDAR points within 2 m of it (seventh
round, ``CROP_EDGE_RULE``; before, points within 2 m only, still under "before_crop_edge_rule").

The classification runs with the shipped defaults; with ``--params FILE`` (JSON of ClassifySettings
overrides per quarter, e.g. the ones chosen on the other three quarters by
bench/eval_classify_nested.py --ahn3) each quarter is scored on its own classification; ``--nested`` takes
them from bench/results/classify_nested.json (the nested folds' choices).
Errors by type (key "errors", shipped defaults): false building area by distance from the nearest
footprint and by AHN3's class of the cell's highest point; missed footprint area by our class and AHN3's.
What the false area physically is: bench/eval_buildings_bgt_false.py.
Rule sets (``--rules``, issue 44's discipline): the classification with each set of RULE_SETS (the new
building rules off, then on alone and combined; RULE_NOTES: what each was designed on); for each
held-out quarter the set with the best worst-quarter min(completeness, correctness) on the other
quarters (those with footprints) is chosen, and the held-out quarter is scored once with it (area, objects, vector centroids). Ties go to the earlier (simpler) set.
The rule set the same criterion picks on all quarters is reported beside the one the shipped defaults
are ("chosen_on_all_quarters", "shipped_defaults_set": the shipped defaults must be that pick).
Footprint parts (fourth round; the quarters hold 0 / 8 / 24 / 104 footprints): four parts with about equal
numbers of footprints, decided from the footprints' positions alone before anything is scored (the median x
of the centroids of the footprints the crop covers, then each half at its own median y; ``footprint_parts``).
The shipped defaults per footprint part ("defaults_footprint_parts", vectors "per_footprint_part") and, with
``--rules``, the nested choice on them ("rules_nested_footprint_parts") by two criteria fixed before they were
scored: "area" (as for the quarters) and "area and objects" (the lowest of completeness, correctness and the
share of footprints found over the training parts). In every nested fold the vectors' roof dropouts
(``MapVectorSettings.roof_dropouts``) are chosen too: on when they put more centroids in the buildings layer
on the training parts (the lowest share over them), else off.
Writes bench/results/buildings_bgt.json. Run: nice .venv/bin/python bench/eval_buildings_bgt.py --rules
[--jobs 2] (and/or --nested); ``--rescore``: the nested choices again from the rule sets' scores in that JSON.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import shapely
import shapely.wkb
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results_json import read_results, store_result  # noqa: E402

from lidarctl.classify import class_grid as cg
from lidarctl import io, tiles
from lidarctl.vectors import layers as map_vectors
from lidarctl.classify.pipeline import BUILDING, ClassifySettings

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results" / "buildings_bgt.json"
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
CRS = "EPSG:28992"
CELL_M = 0.5
BAND_M = 0.5
PARTS = ("south-west", "south-east", "north-west", "north-east")
# The building rules of issue 44 (lidarctl.classify.pipeline.ClassifySettings), off and on: planar cores (small
# roofs judged apart from the hedge or crown their segment also holds) with rooftop objects judged by
# steps to roofs only (else a shed is cut as an object standing above its own wall returns), and the
# roof reach (a segment's cells beyond it from a roof cell join only when mostly single-return).
_OFF = {"small_building_planar_cores": False, "rooftop_steps_to_roofs_only": False, "roof_reach_cells": 0,
        "low_growth_max_height_m": 0.0, "pierced_growth_max_fraction": 0.0, "crown_covered_roofs": False,
        # the stop is a default since stop 104; the sets keep their names' meaning (a set has it when named so)
        "pierced_edge_completion": False, "foliage_beyond_roof_reach": False}
_SHEDS = {**_OFF, "small_building_planar_cores": True, "rooftop_steps_to_roofs_only": True}
RULE_SETS = {
    "main (rules off)": _OFF,
    "sheds": {**_OFF, "small_building_planar_cores": True, "rooftop_steps_to_roofs_only": True},
    "sheds + reach 2": {**_OFF, "small_building_planar_cores": True, "rooftop_steps_to_roofs_only": True,
                        "roof_reach_cells": 2},
    "sheds + reach 3": {**_OFF, "small_building_planar_cores": True, "rooftop_steps_to_roofs_only": True,
                        "roof_reach_cells": 3},
    # Low split-pulse growth (low_growth_max_height_m), with and without the shed rules: heights fixed before
    # the run, from a storey's height (about 2.5-3 m) to the 4 m that bounds 90 % of the false area's
    # heights (bench/eval_buildings_bgt_false.py).
    **{f"sheds + low {h:g}": {**_OFF, "small_building_planar_cores": True, "rooftop_steps_to_roofs_only": True,
                              "low_growth_max_height_m": h} for h in (2.5, 3.0, 3.5, 4.0)},
    **{f"low {h:g}": {**_OFF, "low_growth_max_height_m": h} for h in (2.5, 3.0, 3.5, 4.0)},
    # Pierced growth (pierced_growth_max_fraction; third round): alone with the shed rules, and at 0.1 with
    # each low-growth height.
    **{f"sheds + pierced {f:g}": {**_SHEDS, "pierced_growth_max_fraction": f} for f in (0.1, 0.2, 0.3)},
    **{f"sheds + low {h:g} + pierced 0.1": {**_SHEDS, "low_growth_max_height_m": h, "pierced_growth_max_fraction": 0.1}
       for h in (2.5, 3.0, 3.5, 4.0)},
    # Roofs under crowns (crown_covered_roofs; fourth round): alone, with the shed rules, and with the shed rules
    # and the two growth tests the third round's pick held (sets fixed before the run).
    "crowns": {**_OFF, "crown_covered_roofs": True},
    "sheds + crowns": {**_SHEDS, "crown_covered_roofs": True},
    "sheds + crowns + pierced 0.1": {**_SHEDS, "crown_covered_roofs": True, "pierced_growth_max_fraction": 0.1},
    "sheds + crowns + low 3 + pierced 0.1": {**_SHEDS, "crown_covered_roofs": True, "low_growth_max_height_m": 3.0,
                                             "pierced_growth_max_fraction": 0.1},
}
# Fifth round (issue 44, south-west footprint part): the roof edge completion stops at cells the pierced test finds
# letting pulses through (pierced_edge_completion), added to every earlier set with pierced growth; fixed before the
# south-west part was scored with it. Appended last, so a tie goes to the set without it.
RULE_SETS.update({f"{name} + completion stop": {**o, "pierced_edge_completion": True}
                  for name, o in list(RULE_SETS.items()) if o["pierced_growth_max_fraction"] > 0})
# Stop 117 (IGN LiDAR HD Isère's crowns): each connected region of the growth beyond 2 cells of a roof cell leaves when
# it shows foliage (foliage_beyond_roof_reach, the shipped default since); added to every earlier set, appended last
# so that a tie goes to the set without it.
RULE_SETS.update({f"{name} + foliage beyond reach": {**o, "foliage_beyond_roof_reach": True}
                  for name, o in list(RULE_SETS.items())})

# What each rule was designed on (issue 44's discipline: the nested choice is made per held-out quarter,
# but a rule's form was shaped by the data its designer looked at).
RULE_NOTES = {
    "small_building_planar_cores, rooftop_steps_to_roofs_only": "designed looking at the north-east quarter's "
        "missed BGT sheds; thresholds re-used from the small-building rules (6 m2, 0.2, 0.1 m)",
    "roof_reach_cells": "2 cells from the 3x3 plane fit's geometry; 3 tried",
    "low_growth_max_height_m": "designed looking at the false area of the north-west and north-east quarters "
        "(bench/eval_buildings_bgt_false.py: 77 % of it 1.5-4 m above the ground); the split-pulse test re-uses "
        "the roof cells' (max_multi_return_fraction 0.3 at 95 % confidence); heights 2.5-4 m fixed before the "
        "nested run; the sets without the shed rules added after a first run (shed rules x low heights)",
    "pierced_growth_max_fraction": "designed looking at the north-east quarter's false area with the shipped rules "
        "(third round: 69 % of it grown cells of a house's segment, the AHN3-unclassified part of them letting "
        "pulses through to the ground); the share test is the roof cells' score test mirrored (95 %), the glass-roof "
        "exemption re-uses the roof cells' planarity and penetration tests (roof_rms_m); shares 0.1-0.5 and the "
        "combinations with low growth tried on all quarters in a scratch run before this one (in-sample)",
    "pierced_edge_completion": "fifth round: designed looking at the south-west footprint part's false area under its "
        "nested held-out set (bench/eval_buildings_bgt_false_regions.py: a level see-through surface, 2.1-2.4 m up, "
        "beside an extension roof, taken by the roof edge completion: 61 of its 73 building returns); judged on the "
        "south-east, north-west and north-east parts before the south-west was scored (13.5 m2 false, 4.25 m2 found "
        "removed with pierced 0.1); re-uses the pierced-growth test (its share, 95 %); no value tried",
    "crown_covered_roofs": "designed looking at the shipped defaults' missed vector centroids on the whole crop (fourth "
        "round: two BGT sheds, 8 and 21 m2, in the north-east quarter / south-east and south-west footprint parts, flat "
        "at 2.2 m under garden crowns, every pulse ending on them); re-uses building_min_height_m and the small-building "
        "thresholds (6 m2, 0.2, 0.1 m); no value tried other than those",
    "foliage_beyond_roof_reach": "stop 117: designed looking at IGN LiDAR HD Isère's crowns grown into from two "
        "houses (and the cell statistics of Montpellier's); the tests re-use the roof cells' split-pulse share "
        "(max_multi_return_fraction at 95 %), rough_rms_m and roof_rms_m, the 2 cells the roof reach's geometry; no "
        "value tried; this crop not looked at before it was scored",
    "cut_pieces_judged": "stop 108, on in every set (not a switch of the nested choice): designed looking at IGN "
        "LiDAR HD Montpellier's crowns cut off from their roofs by pierced growth; its single-return clause added "
        "after this crop's north-east quarter lost 4 garden sheds without it; thresholds re-used "
        "(building_min_area_m2, roof_min_patch_m2, small_building_max_multi_fraction)",
}


@dataclasses.dataclass(frozen=True)
class Parts:
    """Four spatial parts (order of ``PARTS``): west / east of ``x_split_m``, each half split south / north at its
    own y (the geometric quarters: one y for both halves)."""

    name: str
    x_split_m: float
    y_split_west_m: float
    y_split_east_m: float

    def index(self, x, y) -> np.ndarray:
        x, y = np.asarray(x), np.asarray(y)
        east = x >= self.x_split_m
        return east.astype(int) + 2 * (y >= np.where(east, self.y_split_east_m, self.y_split_west_m)).astype(int)


def quarters(x_split: float, y_split: float) -> Parts:
    """The geometric quarters of bench/eval_ahn3_holdout.py (median x / y of the points)."""
    return Parts("quarters", x_split, y_split, y_split)


def footprint_parts(polys: list, covered: np.ndarray) -> Parts:
    """Parts holding about equal numbers of footprints, from the footprints' positions alone (decided before any
    scoring): the median x of the centroids of the footprints the crop covers, then each half at its median y."""
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])[covered]
    xm = float(np.median(cent[:, 0]))
    east = cent[:, 0] >= xm
    return Parts("footprint parts", xm, float(np.median(cent[~east, 1])), float(np.median(cent[east, 1])))


def covered_footprints(cloud_path: Path, polys: list) -> np.ndarray:
    """Footprints whose centroid has points of the crop within 2 m (the crop covers them)."""
    from scipy.spatial import cKDTree

    c = io.read_cloud(cloud_path, crs=CRS)
    tree = cKDTree(np.column_stack([c.x[::4], c.y[::4]]))
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
    return np.array([len(h) > 0 for h in tree.query_ball_point(cent, 2.0)])


def read_bgt(sqlite_path: Path) -> list:
    con = sqlite3.connect(f"file:{sqlite_path}?mode=ro", uri=True)
    rows = con.execute("SELECT GEOMETRY FROM buildingpart").fetchall()
    con.close()
    return [shapely.wkb.loads(bytes(b)) for (b,) in rows]


def building_raster(classified: Path, grid: cg.ClassGrid) -> tuple[np.ndarray, np.ndarray]:
    """(building mask, has points) on ``grid``: the highest point's class per cell, empty cells filled from
    the nearest cell with points."""
    top = cg.cloud_classes(classified, grid)
    empty = top == cg.IGNORE
    idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
    filled = top[tuple(idx)]
    return filled == BUILDING, ~empty


def score_area(bld: np.ndarray, ref: np.ndarray, scored: np.ndarray) -> dict:
    tp = int(np.sum(bld & ref & scored))
    fn = int(np.sum(~bld & ref & scored))
    fp = int(np.sum(bld & ~ref & scored))
    a = CELL_M * CELL_M
    return {"completeness_pct": 100.0 * tp / max(tp + fn, 1), "correctness_pct": 100.0 * tp / max(tp + fp, 1),
            "footprint_area_m2": (tp + fn) * a, "building_area_m2": (tp + fp) * a, "missed_m2": fn * a,
            "false_m2": fp * a}


def evaluate_quarters(classified_by_part: dict, polys: list, parts: Parts) -> dict:
    """Area and objects per part of ``parts`` (a footprint's part: the one holding its centroid); a part's
    classification from ``classified_by_part`` (else the first)."""
    first = next(iter(classified_by_part.values()))
    grid, _ = cg.cloud_grid(first, CELL_M, CRS)
    ref_polys = cg.ClassPolygons(polys, np.full(len(polys), BUILDING, np.uint8), None, Path("bgt"))
    ref, ids = cg.rasterize_polygons(ref_polys, grid)
    ref = ref == BUILDING
    band = cg.rasterize_mask([shapely.union_all([p.boundary for p in polys]).buffer(BAND_M)], grid)
    hulls = cg.block_hulls(ref_polys)
    in_blocks = cg.rasterize_mask(hulls, grid)
    xc, yc = grid.centres()
    part_cell = parts.index(xc[None, :], yc[:, None])
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
    part_poly = parts.index(cent[:, 0], cent[:, 1])
    out = {}
    rasters = {}
    for k, name in enumerate(PARTS):
        path = classified_by_part.get(name, first)
        if path not in rasters:
            rasters[path] = building_raster(path, grid)
        bld, _ = rasters[path]
        scored = in_blocks & ~band & (part_cell == k)
        area = score_area(bld, ref, scored)
        # per object: share of each footprint's cells that are building
        n_cells = np.bincount(ids.ravel(), minlength=len(polys) + 1)[1:]
        n_bld = np.bincount(ids.ravel(), weights=bld.ravel(), minlength=len(polys) + 1)[1:]
        mine = (part_poly == k) & (n_cells > 0)
        found = mine & (n_bld >= 0.5 * n_cells)
        out[name] = {"area": area, "footprints": int(mine.sum()), "footprints_found": int(found.sum()),
                     "footprints_found_pct": 100.0 * found.sum() / max(mine.sum(), 1),
                     "missed_footprints_m2": sorted(float(polys[i].area) for i in np.flatnonzero(mine & ~found)),
                     "classified_with": str(path.name)}
    return out


def _quarter_of(x, y, x_split: float, y_split: float) -> np.ndarray:
    return quarters(x_split, y_split).index(x, y)


def errors_by_type(classified: Path, laz: Path, polys: list, x_split: float, y_split: float) -> dict:
    """Per quarter: false building area (m2) by distance (m) from the nearest footprint and by AHN3's class
    of the cell; missed footprint area by our class and AHN3's (highest point of the cell, empty cells
    filled from the nearest cell with points); the footprints not found (area, our classes in cells)."""
    grid, _ = cg.cloud_grid(classified, CELL_M, CRS)
    ref_polys = cg.ClassPolygons(polys, np.full(len(polys), BUILDING, np.uint8), None, Path("bgt"))
    ref, ids = cg.rasterize_polygons(ref_polys, grid)
    ref = ref == BUILDING
    band = cg.rasterize_mask([shapely.union_all([p.boundary for p in polys]).buffer(BAND_M)], grid)
    scored = cg.rasterize_mask(cg.block_hulls(ref_polys), grid) & ~band
    xc, yc = grid.centres()
    part = _quarter_of(xc[None, :], yc[:, None], x_split, y_split)

    def filled(path):
        top = cg.cloud_classes(path, grid)
        idx = ndimage.distance_transform_edt(top == cg.IGNORE, return_distances=False, return_indices=True)
        return top[tuple(idx)]

    ours, ahn = filled(classified), filled(laz)
    bld = ours == BUILDING
    dist_m = ndimage.distance_transform_edt(~ref) * CELL_M
    a = CELL_M * CELL_M
    bands = {"0.5-1 m": (0.0, 1.0), "1-1.5 m": (1.0, 1.5), "1.5-3 m": (1.5, 3.0), "over 3 m": (3.0, np.inf)}
    out = {}
    for k, name in enumerate(PARTS):
        s = scored & (part == k)
        fp, fn = bld & ~ref & s, ~bld & ref & s
        if not (ref & s).any():
            continue
        d = dist_m[fp]
        n_cells = np.bincount(ids.ravel(), minlength=len(polys) + 1)[1:]
        n_bld = np.bincount(ids.ravel(), weights=bld.ravel(), minlength=len(polys) + 1)[1:]
        cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
        missed = np.flatnonzero((_quarter_of(cent[:, 0], cent[:, 1], x_split, y_split) == k) & (n_cells > 0)
                                & (n_bld < 0.5 * n_cells))
        out[name] = {
            "false_m2_by_distance_from_footprint": {b: float(((d > lo) & (d <= hi)).sum() * a) for b, (lo, hi) in bands.items()},
            "false_m2_by_ahn3_class": {str(int(v)): float((ahn[fp] == v).sum() * a) for v in np.unique(ahn[fp])},
            "missed_m2_by_our_class": {str(int(v)): float((ours[fn] == v).sum() * a) for v in np.unique(ours[fn])},
            "missed_m2_by_ahn3_class": {str(int(v)): float((ahn[fn] == v).sum() * a) for v in np.unique(ahn[fn])},
            "footprints_not_found": [{"area_m2": round(float(polys[i].area), 2),
                                      "our_classes_cells": {str(int(v)): int(n) for v, n in zip(*np.unique(ours[ids == i + 1], return_counts=True))},
                                      "ahn3_classes_cells": {str(int(v)): int(n) for v, n in zip(*np.unique(ahn[ids == i + 1], return_counts=True))}}
                                     for i in missed],
        }
    return out


# Footprints cut by the crop's edge (issue 44, seventh round; rule fixed before any score was computed with it): the
# map can hold no building beyond the data, so a footprint is on the crop when its centroid lies inside the crop's
# extent (the rectangle of its returns) and has returns within 2 m. The 2 m tolerance was meant for gaps inside the
# crop (a roof that returned no pulse), not for a centroid past the crop's edge; a clipped part's centroid was not
# taken: it moves with the cut, and the cut admits slivers no map can hold (one of 0.7 m2 on this crop).
CROP_EDGE_RULE = ("a footprint is on the crop when its centroid lies inside the crop's extent (the rectangle of its "
                  "returns) and has returns within 2 m (before: returns within 2 m only); fixed before scoring")


def _centroid_counts(inside: np.ndarray, on_crop: np.ndarray, polys: list, cent: np.ndarray, parts: tuple) -> dict:
    out = {"footprints_covered_by_the_crop": int(on_crop.sum()), "centroid_in_building_layer": int((inside & on_crop).sum()),
           "centroid_in_building_layer_pct": 100.0 * float((inside & on_crop).sum()) / max(int(on_crop.sum()), 1),
           "missed_footprint_areas_m2": sorted(float(polys[i].area) for i in np.flatnonzero(on_crop & ~inside))}
    for pp in parts:
        q = pp.index(cent[:, 0], cent[:, 1])
        out[_PER[pp.name]] = {name: {"footprints": int((on_crop & (q == k)).sum()),
                                     "centroid_in_building_layer": int((inside & on_crop & (q == k)).sum())}
                              for k, name in enumerate(PARTS)}
    return out


def vector_centroids(classified: Path, polys: list, out_gpkg: Path, parts: tuple = (), roof_dropouts: bool = True) -> dict:
    """Footprints whose centroid lies in the buildings layer, over the footprints on the crop (``CROP_EDGE_RULE``) and
    per part of each of ``parts`` (keys "per_quarter" for the quarters, "per_footprint_part" for the footprint parts);
    under "before_crop_edge_rule" the same counts over the footprints with returns within 2 m of their centroid."""
    settings = dataclasses.replace(map_vectors.MapVectorSettings(), roof_dropouts=roof_dropouts)
    mv = map_vectors.extract_vectors([classified], out_gpkg, params=settings, crs=CRS)
    layer = next(lay for lay in mv.layers if lay.name == "buildings")
    union = shapely.union_all(layer.geometries) if layer.geometries else shapely.Polygon()
    c = io.read_cloud(classified, crs=CRS)
    from scipy.spatial import cKDTree

    tree = cKDTree(np.column_stack([c.x[::4], c.y[::4]]))
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
    covered = np.array([len(h) > 0 for h in tree.query_ball_point(cent, 2.0)])
    in_extent = ((cent[:, 0] >= c.x.min()) & (cent[:, 0] <= c.x.max()) & (cent[:, 1] >= c.y.min())
                 & (cent[:, 1] <= c.y.max()))
    inside = shapely.contains_xy(union, cent[:, 0], cent[:, 1])
    out = _centroid_counts(inside, covered & in_extent, polys, cent, parts)
    out["building_polygons"] = len(layer.geometries)
    out["crop_edge_rule"] = CROP_EDGE_RULE
    out["before_crop_edge_rule"] = _centroid_counts(inside, covered, polys, cent, parts)
    return out


_PER = {"quarters": "per_quarter", "footprint parts": "per_footprint_part"}


def _worst(part_scores: dict, names) -> float:
    """The lowest of completeness and correctness over the parts ``names`` that hold footprints."""
    vals = [min(part_scores[n]["area"]["completeness_pct"], part_scores[n]["area"]["correctness_pct"])
            for n in names if part_scores[n]["area"]["footprint_area_m2"] > 0]
    return min(vals) if vals else float("nan")


def _score_rule_set(job) -> tuple[str, dict]:
    """One RULE_SETS classification of the crop scored per part of each partition and for the vectors (with and
    without the roof dropouts of the vectors); a pool task."""
    k, name, laz, polys, partitions, tmp = job
    overrides = RULE_SETS[name]
    path = tmp / f"rules_{k}.laz"
    t0 = time.process_time()
    tiles.classify_file(laz, path, crs=CRS, params=dataclasses.replace(ClassifySettings(), **overrides))
    cpu = time.process_time() - t0
    out = {"overrides": overrides, "classify_cpu_s": cpu}
    for pp in partitions:
        out[_KEY[pp.name]] = evaluate_quarters({"x": path}, polys, pp)
    out["vectors"] = vector_centroids(path, polys, tmp / f"rules_{k}.gpkg", partitions)
    out["vectors_roof_dropouts_off"] = vector_centroids(path, polys, tmp / f"rules_{k}.gpkg", partitions, roof_dropouts=False)
    path.unlink()
    print(f"{name}: worst quarter min(completeness, correctness) {_worst(out['quarters'], PARTS):.2f} %, footprint parts "
          f"{_worst(out['footprint_parts'], PARTS):.2f} %; vectors {out['vectors']['centroid_in_building_layer']}"
          f"/{out['vectors']['footprints_covered_by_the_crop']}", flush=True)
    return name, out


_KEY = {"quarters": "quarters", "footprint parts": "footprint_parts"}

# How the training parts choose (issue 44): "area" fixed before the first round; "area and objects" fixed in the
# fourth round before the footprint parts were scored (the held-out part of the quarters had been seen).
CRITERIA = {
    "area": "the lowest of area completeness and correctness over the training parts (those with footprints)",
    "area and objects": "the lowest of area completeness, area correctness and the share of footprints found over "
                        "the training parts",
}


def _worst_of(part_scores: dict, names, criterion: str) -> float:
    if criterion == "area":
        return _worst(part_scores, names)
    vals = [min(part_scores[n]["area"]["completeness_pct"], part_scores[n]["area"]["correctness_pct"],
                part_scores[n]["footprints_found_pct"]) for n in names if part_scores[n]["area"]["footprint_area_m2"] > 0]
    return min(vals) if vals else float("nan")


def _vector_share(v: dict, per: str, names) -> float:
    """The lowest share of footprint centroids in the buildings layer over the parts ``names``."""
    vals = [100.0 * v[per][n]["centroid_in_building_layer"] / v[per][n]["footprints"] for n in names if v[per][n]["footprints"]]
    return min(vals) if vals else float("nan")


def nested_choice(per_set: dict, key: str, criterion: str, order: list | None = None) -> dict:
    """Per held-out part of partition ``key`` ("quarters", "footprint_parts"): the rule set the criterion picks on
    the other parts (ties to the earlier set), then the vectors with or without roof dropouts by the lowest
    training share of centroids in the buildings layer (ties to without: the older map); the held-out part
    scored once (area, objects, vector centroids)."""
    per = "per_quarter" if key == "quarters" else "per_footprint_part"
    first = next(iter(per_set.values()))
    scored = [n for n in PARTS if first[key][n]["area"]["footprint_area_m2"] > 0]
    order = order or list(RULE_SETS)   # ties go to the earlier set
    held = {}
    for name in scored:
        train = [n for n in scored if n != name]
        crit = {s: _worst_of(v[key], train, criterion) for s, v in per_set.items()}
        chosen = max(crit, key=lambda s: (crit[s], -order.index(s)))
        on, off = (_vector_share(per_set[chosen][v], per, train) for v in ("vectors", "vectors_roof_dropouts_off"))
        vkey = "vectors" if on > off else "vectors_roof_dropouts_off"
        # added after the first run (the lowest share ties whenever the worst training part holds no roof that
        # returned no pulse): the centroids on the map summed over the training parts
        on_n, off_n = (sum(per_set[chosen][v][per][n]["centroid_in_building_layer"] for n in train)
                       for v in ("vectors", "vectors_roof_dropouts_off"))
        vkey_total = "vectors" if on_n > off_n else "vectors_roof_dropouts_off"
        q = per_set[chosen][key][name]
        vq = per_set[chosen][vkey][per][name]
        vt = per_set[chosen][vkey_total][per][name]
        held[name] = {"chosen": chosen, "chosen_on": train, "training_worst_pct": crit,
                      "vectors_roof_dropouts": vkey == "vectors", "training_vector_share_pct": {"on": on, "off": off},
                      "area": q["area"], "footprints": q["footprints"], "footprints_found": q["footprints_found"],
                      "footprints_found_pct": q["footprints_found_pct"], "missed_footprints_m2": q["missed_footprints_m2"],
                      "vector_centroids": vq["centroid_in_building_layer"], "vector_footprints": vq["footprints"],
                      "vector_centroids_pct": 100.0 * vq["centroid_in_building_layer"] / max(vq["footprints"], 1),
                      "vectors_roof_dropouts_by_total": vkey_total == "vectors",
                      "training_vector_centroids": {"on": on_n, "off": off_n},
                      "vector_centroids_by_total": vt["centroid_in_building_layer"]}
    crit_all = {s: _worst_of(v[key], scored, criterion) for s, v in per_set.items()}
    pick = max(crit_all, key=lambda s: (crit_all[s], -order.index(s)))
    out = {"criterion": CRITERIA[criterion] + "; ties to the earlier rule set", "held_out": held,
           "chosen_on_all_parts": {"set": pick, "on": scored, "worst_pct": crit_all[pick], "by_set_pct": crit_all}}
    out["vector_choice"] = ("roof dropouts on when the lowest training share of centroids on the map is higher with "
                            "them (fixed before the run; 'vector_centroids'); added after it: when the centroids on "
                            "the map summed over the training parts are more ('vector_centroids_by_total')")
    out["worst_held_out"] = {
        "completeness_pct": min(v["area"]["completeness_pct"] for v in held.values()),
        "correctness_pct": min(v["area"]["correctness_pct"] for v in held.values()),
        "footprints_found_pct": min(v["footprints_found_pct"] for v in held.values()),
        "vector_centroids_pct": min(v["vector_centroids_pct"] for v in held.values())}
    out["held_out_totals"] = {
        "footprints_found": sum(v["footprints_found"] for v in held.values()),
        "footprints": sum(v["footprints"] for v in held.values()),
        "vector_centroids": sum(v["vector_centroids"] for v in held.values()),
        "vector_centroids_by_total": sum(v["vector_centroids_by_total"] for v in held.values()),
        "vector_footprints": sum(v["vector_footprints"] for v in held.values())}
    return out


def rules_nested(laz: Path, polys: list, partitions: tuple, tmp: Path, jobs: int = 1,
                 scored: dict | None = None) -> tuple[dict, dict]:
    """Each RULE_SETS classification scored per part; per held-out part the set chosen on the others, for the
    quarters (criterion "area": as before; "area and objects") and the footprint parts (both criteria).
    ``jobs``: rule sets scored at once (processes; about 1 GB each). ``scored``: the scores of sets done before
    (a results file's "rule_sets"; only the others are classified). Returns (quarters' section, footprint
    parts' section)."""
    scored = scored or {}
    work = [(k, name, laz, polys, partitions, tmp) for k, name in enumerate(RULE_SETS) if name not in scored]
    if jobs > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: the parent has numba's threads running (a fork would copy their locks)
        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            done = dict(pool.map(_score_rule_set, work))
    else:
        done = dict(map(_score_rule_set, work))
    done.update(scored)
    per_set = {name: done[name] for name in RULE_SETS}
    for v in per_set.values():
        for key in _KEY.values():
            for q in v[key].values():
                q.pop("classified_with", None)
    return nested_sections(per_set)


def nested_sections(per_set: dict) -> tuple[dict, dict]:
    """The nested choices from the rule sets' scores: (quarters' section, footprint parts' section)."""
    shipped = next((n for n, o in RULE_SETS.items() if all(getattr(ClassifySettings(), k) == v for k, v in o.items())), None)
    q = nested_choice(per_set, "quarters", "area")
    # the quarters' section keeps its earlier keys ("held_out", "chosen_on_all_quarters", "rule_sets")
    quarters_section = {"criterion": q["criterion"], "rule_notes": RULE_NOTES, "rule_sets": per_set,
                        "held_out": q["held_out"], "worst_held_out": q["worst_held_out"],
                        "held_out_totals": q["held_out_totals"],
                        "chosen_on_all_quarters": q["chosen_on_all_parts"], "shipped_defaults_set": shipped,
                        "criterion_area_and_objects": nested_choice(per_set, "quarters", "area and objects")}
    parts_section = {c: nested_choice(per_set, "footprint_parts", c) for c in CRITERIA}
    parts_section["shipped_defaults_set"] = shipped
    return quarters_section, parts_section


def _print_nested(title: str, section: dict) -> None:
    for name, v in section["held_out"].items():
        a = v["area"]
        print(f"{title}: held out {name} (rules '{v['chosen']}', roof dropouts {'on' if v['vectors_roof_dropouts'] else 'off'}; "
              f"chosen on {', '.join(v['chosen_on'])}): completeness {a['completeness_pct']:.1f} %, correctness "
              f"{a['correctness_pct']:.1f} %; footprints found {v['footprints_found']}/{v['footprints']}; vector centroids "
              f"{v['vector_centroids']}/{v['vector_footprints']}")


def held_out_sets() -> dict:
    """The rule sets of the stored nested choice on the footprint parts: {"shipped defaults": "shipped defaults",
    "<criterion>: held out <part>": the set chosen without that part}."""
    nested = read_results(RESULTS)["rules_nested_footprint_parts"]
    sets = {"shipped defaults": "shipped defaults"}
    for criterion in ("area and objects", "area"):
        for name in PARTS:
            sets[f"{criterion}: held out {name}"] = nested[criterion]["held_out"][name]["chosen"]
    return sets


def clock() -> tuple[float, float, float]:
    """(wall s, CPU s, load average) now: the start of a timed run (``store_timed``)."""
    return time.perf_counter(), time.process_time(), os.getloadavg()[0]


def store_timed(path: Path, result: dict, started: tuple, key: str) -> None:
    """``result`` with its wall and CPU seconds and the load before / after since ``started``, under ``key`` of ``path``."""
    t0, cpu0, load0 = started
    result["seconds"], result["cpu_s"] = time.perf_counter() - t0, time.process_time() - cpu0
    result["load_average_before_after"] = [load0, os.getloadavg()[0]]
    store_result(path, result, key=key)


def nested_with_separation(argv, script: str, laz: Path, polys: list, separate, suffix: str, note: str, key: str,
                           overrides: dict | None = None, applies=None, bases: list | None = None) -> int:
    """A separation applied after the classification as rule sets in the nested choice on the footprint parts (both
    criteria): the sets any fold chose and the shipped defaults' set, each classified, then ``separate(classified,
    out, settings)``, scored as the stored sets (area, objects, vector centroids with and without roof dropouts) and
    appended after them (a tie goes to the set without it) as "<set> + ``suffix``". Writes key ``key`` of RESULTS.
    ``overrides`` (ClassifySettings fields, with ``separate`` None): a classification switch in place of the
    separation, added to each base ``applies(base's overrides)`` accepts (a base the switch cannot change is left
    out: its scores would be the stored set's). ``bases``: these RULE_SETS names in place of the chosen ones."""
    stored = read_results(RESULTS)
    per_set = dict(stored["rules_nested"]["rule_sets"])
    sec = stored["rules_nested_footprint_parts"]
    bases = bases or list(dict.fromkeys([sec["shipped_defaults_set"]] + [v["chosen"] for crit in CRITERIA
                                                                          for v in sec[crit]["held_out"].values()]))
    if applies is not None:
        bases = [b for b in bases if applies(RULE_SETS[b])]
    x_split, y_split = stored["quarters_split_at_m"]
    partitions = (quarters(x_split, y_split), footprint_parts(polys, covered_footprints(laz, polys)))
    started = clock()
    added = []
    with tempfile.TemporaryDirectory(prefix="eval_bgt_nested_separation_") as tmp:
        for j, base in enumerate(bases):
            prm = dataclasses.replace(ClassifySettings(), **{**RULE_SETS[base], **(overrides or {})})
            raw_path, path = Path(tmp) / f"{j}_raw.laz", Path(tmp) / f"{j}.laz"
            tiles.classify_file(laz, raw_path, crs=CRS, params=prm)
            if separate is None:
                raw_path.rename(path)
            else:
                separate(raw_path, path, prm)
                raw_path.unlink()
            name = f"{base} + {suffix}"
            out = {"base": base, "separation": note, "overrides": {**RULE_SETS[base], **(overrides or {})}}
            for pp in partitions:
                out[_KEY[pp.name]] = evaluate_quarters({"x": path}, polys, pp)
            out["vectors"] = vector_centroids(path, polys, Path(tmp) / f"{j}.gpkg", partitions)
            out["vectors_roof_dropouts_off"] = vector_centroids(path, polys, Path(tmp) / f"{j}.gpkg", partitions,
                                                                roof_dropouts=False)
            path.unlink()
            for k in _KEY.values():
                for q in out[k].values():
                    q.pop("classified_with", None)
            per_set[name] = out
            added.append(name)
            print(f"{name}: footprint parts worst {_worst(out['footprint_parts'], PARTS):.2f} %, vectors "
                  f"{out['vectors']['centroid_in_building_layer']}/{out['vectors']['footprints_covered_by_the_crop']}",
                  flush=True)
    order = list(RULE_SETS) + added
    result = {"command": f"{script} " + " ".join(argv),
              "how": "the stored rule sets (rules_nested/rule_sets) and, appended last, the sets any fold chose and the "
                     "shipped defaults' set with the separation (those it can change); nested choice on the footprint "
                     "parts again, both criteria (ties to the earlier set)",
              "added_sets": {n: per_set[n] for n in added}}
    for criterion in CRITERIA:
        result[criterion] = nested_choice(per_set, "footprint_parts", criterion, order=order)
        for name, v in result[criterion]["held_out"].items():
            a = v["area"]
            print(f"{criterion}: held out {name}: '{v['chosen']}' {a['completeness_pct']:.2f} / {a['correctness_pct']:.2f} %, "
                  f"found {v['footprints_found']}/{v['footprints']}, centroids {v['vector_centroids']}/{v['vector_footprints']}")
    store_timed(RESULTS, result, started, key)
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--rescore" in argv:   # the nested choices again from the rule sets' scores of the JSON (no classification)
        result = read_results(RESULTS)
        result["rules_nested"], result["rules_nested_footprint_parts"] = nested_sections(result["rules_nested"]["rule_sets"])
        result["rescored_by"] = "bench/eval_buildings_bgt.py " + " ".join(argv)
        return _finish(result)
    if "--add-rules" in argv:   # only the RULE_SETS not yet in that JSON classified; the nested choices again
        return _add_rules(argv)
    if "--crop-edge-rule" in argv:   # CROP_EDGE_RULE on the stored vector counts; the nested choices again
        return _crop_edge_rescore(argv)
    laz = SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = read_bgt(SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    c = io.read_cloud(laz, crs=CRS)
    x_split, y_split = float(np.median(c.x)), float(np.median(c.y))
    geo = quarters(x_split, y_split)
    # the footprint parts: from the footprints' positions alone, before anything is classified or scored
    covered = covered_footprints(laz, polys)
    fparts = footprint_parts(polys, covered)
    partitions = (geo, fparts)
    per_part = json.loads(Path(argv[argv.index("--params") + 1]).read_text()) if "--params" in argv else {}
    if "--nested" in argv:   # the configurations chosen without each quarter (bench/eval_classify_nested.py --ahn3)
        folds = json.loads((REPO / "bench" / "results" / "classify_nested.json").read_text())["ahn3"]["nested"]["folds"]
        per_part = {name: f["chosen"] for name, f in folds.items()}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="eval_buildings_bgt_") as tmp:
        tmp = Path(tmp)
        default = tmp / "default.laz"
        tiles.classify_file(laz, default, crs=CRS, params=ClassifySettings())
        classified, done = {}, {}
        for name, overrides in per_part.items():
            key = json.dumps(overrides, sort_keys=True)
            if key not in done:
                done[key] = tmp / f"{name}.laz"
                tiles.classify_file(laz, done[key], crs=CRS,
                                    params=dataclasses.replace(ClassifySettings(), **overrides))
            classified[name] = done[key]
        cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])[covered]
        result = {
            "command": "bench/eval_buildings_bgt.py " + " ".join(argv),
            "data": "ahn3_cropped_1.laz (AHN3 Delft crop) vs the 160 BGT footprints (bgt_pand.sqlite)",
            "cell_m": CELL_M, "tolerance_band_m": BAND_M,
            "scored_area": "convex hulls of the BGT footprint blocks, cells within 0.5 m of an outline ignored",
            "quarters_split_at_m": [x_split, y_split],
            "footprint_parts": {
                "how": "the median x of the centroids of the footprints the crop covers (points within 2 m), then each "
                       "half at its own median y; decided from the footprint positions alone before any scoring; "
                       "part names as the quarters' (south-west: the west half's southern part)",
                "x_split_m": fparts.x_split_m, "y_split_west_m": fparts.y_split_west_m,
                "y_split_east_m": fparts.y_split_east_m,
                "covered_footprints_per_part": {n: int((fparts.index(cent[:, 0], cent[:, 1]) == k).sum())
                                                for k, n in enumerate(PARTS)},
                "covered_footprints_per_quarter": {n: int((geo.index(cent[:, 0], cent[:, 1]) == k).sum())
                                                   for k, n in enumerate(PARTS)}},
            "defaults": evaluate_quarters({"default": default}, polys, geo),
            "defaults_footprint_parts": evaluate_quarters({"default": default}, polys, fparts),
            "vectors_defaults": vector_centroids(default, polys, tmp / "vectors.gpkg", partitions),
            "vectors_defaults_roof_dropouts_off": vector_centroids(default, polys, tmp / "vectors.gpkg", partitions,
                                                                   roof_dropouts=False),
            "errors": errors_by_type(default, laz, polys, x_split, y_split),
        }
        for v in (*result["defaults"].values(), *result["defaults_footprint_parts"].values()):
            v.pop("classified_with", None)
        if "--rules" in argv:
            jobs = int(argv[argv.index("--jobs") + 1]) if "--jobs" in argv else 1
            result["rules_nested"], result["rules_nested_footprint_parts"] = rules_nested(laz, polys, partitions, tmp, jobs)
        if classified:
            result["held_out_params"] = per_part
            result["held_out"] = evaluate_quarters(classified, polys, geo)
    result["targets"] = {"completeness_pct": 95.0, "correctness_pct": 95.0, "vector_centroids_pct": 95.0}
    key = "held_out" if "held_out" in result else "defaults"
    q = result[key]
    result["worst_quarter"] = {m: min(v["area"][m] for v in q.values() if v["area"]["footprint_area_m2"] > 0)
                               for m in ("completeness_pct", "correctness_pct")}
    result["worst_footprint_part_defaults"] = {
        m: min(v["area"][m] for v in result["defaults_footprint_parts"].values() if v["area"]["footprint_area_m2"] > 0)
        for m in ("completeness_pct", "correctness_pct")}
    result["targets_met"] = {"area": bool(min(result["worst_quarter"].values()) >= 95.0),
                             "area_footprint_parts_defaults": bool(min(result["worst_footprint_part_defaults"].values()) >= 95.0),
                             "vectors": bool(result["vectors_defaults"]["centroid_in_building_layer_pct"] >= 95.0)}
    result["seconds"] = time.perf_counter() - t0
    for title, sec in (("quarters", q), ("footprint parts", result["defaults_footprint_parts"])):
        for name, v in sec.items():
            a = v["area"]
            print(f"{title} {name}: completeness {a['completeness_pct']:.1f} %, correctness {a['correctness_pct']:.1f} % "
                  f"({a['footprint_area_m2']:.0f} m2 of footprint); footprints found {v['footprints_found']}/{v['footprints']}")
    vd = result["vectors_defaults"]
    print(f"vectors: centroid in the building layer {vd['centroid_in_building_layer']}/"
          f"{vd['footprints_covered_by_the_crop']} ({vd['centroid_in_building_layer_pct']:.1f} %); per footprint part "
          + ", ".join(f"{n} {v['centroid_in_building_layer']}/{v['footprints']}" for n, v in vd["per_footprint_part"].items()))
    return _finish(result)


def _add_rules(argv) -> int:
    result = read_results(RESULTS)
    laz = SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = read_bgt(SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    x_split, y_split = result["quarters_split_at_m"]
    fparts = footprint_parts(polys, covered_footprints(laz, polys))
    jobs = int(argv[argv.index("--jobs") + 1]) if "--jobs" in argv else 1
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="eval_buildings_bgt_") as tmp:
        result["rules_nested"], result["rules_nested_footprint_parts"] = rules_nested(
            laz, polys, (quarters(x_split, y_split), fparts), Path(tmp), jobs, scored=result["rules_nested"]["rule_sets"])
    result["rules_added_by"] = {"command": "bench/eval_buildings_bgt.py " + " ".join(argv),
                                "seconds": time.perf_counter() - t0, "load_average": os.getloadavg()[0]}
    return _finish(result)


def _crop_edge_counts(v: dict, edge: list, polys: list, cent: np.ndarray, partitions: tuple) -> dict:
    """Stored vector counts ``v`` (over the footprints with returns within 2 m of their centroid) over the footprints on
    the crop (``CROP_EDGE_RULE``): the ``edge`` footprints (covered, centroid outside the crop's extent) taken out; one
    was on the map unless its area is among the missed footprints' (areas checked unique)."""
    if "before_crop_edge_rule" in v:
        return v
    out = json.loads(json.dumps(v))
    missed = list(out["missed_footprint_areas_m2"])
    for i in edge:
        hit = [a for a in missed if abs(a - polys[i].area) < 1e-6]
        on_map = not hit
        if hit:
            missed.remove(hit[0])
        out["footprints_covered_by_the_crop"] -= 1
        out["centroid_in_building_layer"] -= int(on_map)
        for pp in partitions:
            q = out[_PER[pp.name]][PARTS[int(pp.index(cent[i, 0], cent[i, 1]))]]
            q["footprints"] -= 1
            q["centroid_in_building_layer"] -= int(on_map)
    out["missed_footprint_areas_m2"] = missed
    out["centroid_in_building_layer_pct"] = 100.0 * out["centroid_in_building_layer"] / max(out["footprints_covered_by_the_crop"], 1)
    out["crop_edge_rule"] = CROP_EDGE_RULE
    out["before_crop_edge_rule"] = {k: v[k] for k in ("footprints_covered_by_the_crop", "centroid_in_building_layer",
                                                      "centroid_in_building_layer_pct", "missed_footprint_areas_m2",
                                                      *(_PER[pp.name] for pp in partitions))}
    return out


def _crop_edge_rescore(argv) -> int:
    """``CROP_EDGE_RULE`` applied to every stored vector count of the results file (the shipped defaults', each rule
    set's, the sixth round's crown-separation sets'); the nested choices made again (the rule sets' choice does not
    use the map; the roof dropouts' does)."""
    result = read_results(RESULTS)
    laz = SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = read_bgt(SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    c = io.read_cloud(laz, crs=CRS)
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
    covered = covered_footprints(laz, polys)
    in_extent = (cent[:, 0] >= c.x.min()) & (cent[:, 0] <= c.x.max()) & (cent[:, 1] >= c.y.min()) & (cent[:, 1] <= c.y.max())
    edge = [int(i) for i in np.flatnonzero(covered & ~in_extent)]
    areas = np.array([p.area for p in polys])
    for i in edge:   # the stored counts name footprints by area only
        if np.sum(np.abs(areas - areas[i]) < 1e-6) != 1:
            raise SystemExit(f"footprint {i}: its area {areas[i]} m2 is not unique among the footprints")
    x_split, y_split = result["quarters_split_at_m"]
    partitions = (quarters(x_split, y_split), footprint_parts(polys, covered))
    for key in ("vectors_defaults", "vectors_defaults_roof_dropouts_off"):
        result[key] = _crop_edge_counts(result[key], edge, polys, cent, partitions)
    per_set = result["rules_nested"]["rule_sets"]
    for v in per_set.values():
        for key in ("vectors", "vectors_roof_dropouts_off"):
            v[key] = _crop_edge_counts(v[key], edge, polys, cent, partitions)
    result["rules_nested"], result["rules_nested_footprint_parts"] = nested_sections(per_set)
    crown = result.get("rules_nested_footprint_parts_crown_returns")
    if crown:
        for v in crown["added_sets"].values():
            for key in ("vectors", "vectors_roof_dropouts_off"):
                v[key] = _crop_edge_counts(v[key], edge, polys, cent, partitions)
        both = {**per_set, **crown["added_sets"]}
        for criterion in CRITERIA:
            crown[criterion] = nested_choice(both, "footprint_parts", criterion, order=list(RULE_SETS) + list(crown["added_sets"]))
    result["crop_edge_rescore"] = {
        "command": "bench/eval_buildings_bgt.py " + " ".join(argv), "rule": CROP_EDGE_RULE,
        "footprints_taken_out": {str(i): {"area_m2": round(float(areas[i]), 2), "centroid_m": [round(float(v), 2) for v in cent[i]],
                                          "beyond_the_crop_m": round(float(cent[i, 0] - c.x.max()), 2)} for i in edge},
        "crop_extent_m": [float(c.x.min()), float(c.y.min()), float(c.x.max()), float(c.y.max())],
        "how": "stored counts rescored (no classification): a taken-out footprint was on the map unless its area is in "
               "the set's missed list; the footprint parts stay those fixed in the fourth round"}
    return _finish(result)


def _finish(result: dict) -> int:
    """The nested sections' targets and summary; the JSON written."""
    if "rules_nested" in result:
        rn, rp = result["rules_nested"], result["rules_nested_footprint_parts"]
        wh = rn["worst_held_out"]
        result["targets_met"]["area_rules_nested"] = bool(min(wh["completeness_pct"], wh["correctness_pct"]) >= 95.0)
        result["targets_met"]["vectors_rules_nested"] = bool(wh["vector_centroids_pct"] >= 95.0)
        for c in CRITERIA:
            w = rp[c]["worst_held_out"]
            result["targets_met"][f"footprint_parts_{c.replace(' ', '_')}"] = {
                "area": bool(min(w["completeness_pct"], w["correctness_pct"]) >= 95.0),
                "objects": bool(w["footprints_found_pct"] >= 95.0), "vectors": bool(w["vector_centroids_pct"] >= 95.0)}
        result["targets_met"]["shipped_defaults_are_the_nested_choice_on_all_quarters"] = \
            rn["shipped_defaults_set"] == rn["chosen_on_all_quarters"]["set"]
        # since stop 104 the defaults are the set "area and objects" picks on all four footprint parts (the criterion
        # and the parts fixed in the fourth round, before the parts were scored)
        result["targets_met"]["shipped_defaults_are_the_choice_on_all_footprint_parts_area_and_objects"] = \
            rp["shipped_defaults_set"] == rp["area and objects"]["chosen_on_all_parts"]["set"]
        print(f"chosen on all quarters: {rn['chosen_on_all_quarters']['set']} "
              f"({rn['chosen_on_all_quarters']['worst_pct']:.2f} %); shipped defaults: {rn['shipped_defaults_set']}")
        _print_nested("quarters, area", rn)
        _print_nested("quarters, area and objects", rn["criterion_area_and_objects"])
        for c in CRITERIA:
            _print_nested(f"footprint parts, {c}", rp[c])
    store_result(RESULTS, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
