"""Seventh round of issue 44 on the AHN3 Delft crop against the BGT footprints: the south-east footprint part's two
map misses, and returns beneath a low building top whose pulse went on (foliage, not a roof).

1. The misses (shipped defaults; ``misses``): footprint 97 (5.7 m2, under a crown) by its returns at its roof level
   (single returns, first returns of pulses that went on to the ground, others; inner: more than the scoring's
   0.5 m band inside the outline, where no wall is) and footprint 116 (cut by the crop's east edge: its area inside
   the crop's extent, how far its centroid lies beyond the last return). Figure
   bench/results/buildings_bgt_se_misses.png: the returns around each coloured by our class (ground brown,
   vegetation greens, building red), the BGT outlines (black), the buildings layer (magenta), the crop's edge
   (dashed), the footprint's centroid (x).
2. The separation (``foliage_cells``; fixed on the south-east, north-west and north-east parts, the south-west part
   scored once after): a roof stops every pulse, and the returns below a roof's top in its window are its walls',
   which stop the pulse too. A building cell of the scoring grid (0.5 m, its top return building) whose top stands
   less than LOW_M above our ground leaves the building when its 3 x 3 window shows, at 95 % confidence (the
   pierced-growth test, lidarctl.classify.pipeline.more_than_fraction), more than PASS_FRACTION of its returns
   lying between wall_min_height_m above the ground and wall_min_height_m below the cell's top as returns whose
   pulse went on (not the last of their pulse: foliage the pulse entered); a planar top (3 x 3 plane RMS of the top
   returns below roof_rms_m: the pierced test's glass-roof exemption) stays. Applied after the classification (as
   the sixth round's crown separation): the cell's building returns become vegetation. Per part the false and found
   area it takes, and AHN3's per-point building PA / UA, for the shipped defaults and the held-out sets of
   bench/results/buildings_bgt.json.
3. ``--nested``: the separation as rule sets in the nested choice on the footprint parts (both criteria, as the
   sixth round's ``--nested`` of bench/eval_buildings_bgt_crowns.py): the sets any fold chose and the shipped
   defaults' set with the separation, appended after the stored sets (a tie goes to the set without it). Writes key
   "rules_nested_footprint_parts_foliage" of bench/results/buildings_bgt.json.

Writes key "seventh_round" of bench/results/buildings_bgt_false_regions.json (``--misses``: section 1 alone, its
"se_misses").
Run: nice .venv/bin/python bench/eval_buildings_bgt_foliage.py [--nested | --misses]
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as bgt  # noqa: E402
import eval_buildings_bgt_crowns as cr  # noqa: E402
import eval_buildings_bgt_false as bf  # noqa: E402
from results_json import store_result  # noqa: E402

from aerotri.core.figures import pyplot, save_png  # noqa: E402
from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify import class_grid as cg  # noqa: E402
from lidarctl.classify.pipeline import BUILDING, HIGH_VEG, MED_VEG, ClassifySettings, more_than_fraction  # noqa: E402
from lidarctl.raster_ops import plane_rms  # noqa: E402
from lidarctl.vectors import layers as map_vectors  # noqa: E402

DESIGN_PARTS = cr.DESIGN_PARTS
LOW_M = 4.0            # the low-growth heights' upper end (2.5-4 m; second round: 90 % of the false area below it)
PASS_FRACTION = 0.1    # the pierced-growth share the nested sets hold
SE_MISSES = (97, 116)  # the south-east part's footprints off the map (sixth round)
COLOURS = {1: "0.6", 2: "sienna", 3: "lightgreen", 4: "limegreen", 5: "darkgreen", 6: "red", 9: "blue"}


def pass_through_beneath(c, k: cr.Cells) -> tuple[np.ndarray, np.ndarray]:
    """(returns in each cell's 3 x 3 window, those of them between wall_min_height_m above the cell's ground and
    wall_min_height_m below the cell's top return whose pulse went on), per cell of ``k`` (flat arrays)."""
    p = ClassifySettings()
    h, w = k.shape
    topz = c.z[k.top.ravel()]
    row, col = np.divmod(k.flat, w)
    goes_on = np.asarray(c.return_number) < np.asarray(c.number_of_returns)
    n = np.zeros(h * w)
    m = np.zeros(h * w)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, q = row + dr, col + dc
            ok = (r >= 0) & (r < h) & (q >= 0) & (q < w)
            centre = (r * w + q)[ok]
            n += np.bincount(centre, minlength=h * w)
            z = c.z[ok]
            beneath = (z > k.dem_m[centre] + p.wall_min_height_m) & (z < topz[centre] - p.wall_min_height_m) & goes_on[ok]
            m += np.bincount(centre[beneath], minlength=h * w)
    return n, m


def foliage_cells(c, k: cr.Cells) -> np.ndarray:
    """Building cells (top return building) lower than LOW_M whose window shows pulses going on beneath the top
    (module docstring, 2.); planar tops excepted. Boolean grid of ``k.shape``."""
    p = ClassifySettings()
    topz = c.z[k.top.ravel()]
    n, m = pass_through_beneath(c, k)
    planar = plane_rms(topz.reshape(k.shape), 0.5).ravel() < p.roof_rms_m
    low = topz - k.dem_m < LOW_M
    take = (c.classification == BUILDING)[k.top.ravel()] & low & more_than_fraction(m, n, PASS_FRACTION) & ~planar
    return take.reshape(k.shape)


def separated_classes(c, k: cr.Cells) -> np.ndarray:
    """The classes with the building returns of ``foliage_cells`` made vegetation (medium or high by height)."""
    p = ClassifySettings()
    take = foliage_cells(c, k).ravel()[k.flat] & (c.classification == BUILDING)
    cls = np.asarray(c.classification).copy()
    cls[take] = np.where(c.z[take] - k.dem_m[k.flat[take]] > p.medium_veg_max_m, HIGH_VEG, MED_VEG)
    return cls


def analyse(path: Path, laz_class: np.ndarray, polys: list, parts: bgt.Parts) -> dict:
    c = io.read_cloud(path, crs=bgt.CRS)
    grid, ref, scored = bf.scoring_grid(path, polys)
    xc, yc = grid.centres()
    part = parts.index(xc[None, :], yc[:, None])
    k = cr.cells(c, grid)
    b = c.classification == BUILDING
    base = b[k.top]
    cls = separated_classes(c, k)
    isb = cls == BUILDING
    ahn_b = laz_class == BUILDING
    return {"parts": cr.part_figures(isb[k.top], base, ref, scored, part), "returns_changed": int((b & ~isb).sum()),
            "changed_ahn3_building": int((b & ~isb & ahn_b).sum()),
            "ahn3_per_point_building_pa_ua_pct_before": [round(100.0 * float((b & ahn_b).sum() / ahn_b.sum()), 2),
                                                         round(100.0 * float((b & ahn_b).sum() / max(b.sum(), 1)), 2)],
            "ahn3_per_point_building_pa_ua_pct": [round(100.0 * float((isb & ahn_b).sum() / ahn_b.sum()), 2),
                                                  round(100.0 * float((isb & ahn_b).sum() / max(isb.sum(), 1)), 2)]}


def misses(path: Path, laz: Path, polys: list, tmp: Path) -> dict:
    """Footprints 97 and 116 under the shipped defaults (module docstring, 1.), with the figure."""
    p = ClassifySettings()
    c = io.read_cloud(path, crs=bgt.CRS)
    raw = laspy.read(laz)
    end = cr.pulse_ends(np.asarray(raw.gps_time), np.asarray(raw.return_number))
    mv = map_vectors.extract_vectors([path], tmp / "misses.gpkg", params=map_vectors.MapVectorSettings(), crs=bgt.CRS)
    layer = next(lay for lay in mv.layers if lay.name == "buildings").geometries
    union = shapely.union_all(layer) if layer else shapely.Polygon()
    extent = shapely.box(c.x.min(), c.y.min(), c.x.max(), c.y.max())
    out = {}
    for i in SE_MISSES:
        poly = polys[i]
        inn = shapely.contains_xy(poly, c.x, c.y)
        ring = shapely.contains_xy(poly.buffer(4.0).difference(poly.buffer(1.0)), c.x, c.y) & (c.classification == 2)
        ground = float(np.median(c.z[ring]))
        h = c.z - ground
        first = c.return_number == 1
        level = float(np.median(h[inn & first & (h > p.building_min_height_m - 1.0)]))
        at_level = inn & (np.abs(h - level) < 0.15)
        inner = at_level & shapely.contains_xy(poly.buffer(-bgt.BAND_M), c.x, c.y)
        single = c.number_of_returns == 1
        to_ground = (c.return_number == 1) & ~single & (h[end] < p.wall_min_height_m)
        cx, cy = poly.centroid.x, poly.centroid.y
        out[str(i)] = {
            "area_m2": round(float(poly.area), 2), "area_inside_the_crop_m2": round(float(poly.intersection(extent).area), 2),
            "centroid_m": [round(cx, 2), round(cy, 2)],
            "centroid_beyond_the_last_return_m": round(max(cx - float(c.x.max()), 0.0), 2),
            "centroid_on_map": bool(union.contains(shapely.Point(cx, cy))),
            "map_area_on_it_m2": round(float(union.intersection(poly).area), 2),
            "roof_level_above_ground_m": round(level, 2),
            "roof_level_returns": {"all": int(at_level.sum()), "single": int((at_level & single).sum()),
                                   "first of a pulse that went on to the ground": int((at_level & to_ground).sum())},
            "inner_roof_level_returns": {"all": int(inner.sum()), "single": int((inner & single).sum()),
                                         "first of a pulse that went on to the ground": int((inner & to_ground).sum())},
            "our_classes": {str(int(v)): int(n) for v, n in zip(*np.unique(c.classification[inn], return_counts=True))},
            "ahn3_classes": {str(int(v)): int(n) for v, n in zip(*np.unique(np.asarray(raw.classification)[inn],
                                                                            return_counts=True))}}
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(12, 6))
    r = 10.0
    for ax, i in zip(axs, SE_MISSES):
        cx, cy = polys[i].centroid.x, polys[i].centroid.y
        sel = (np.abs(c.x - cx) < r) & (np.abs(c.y - cy) < r)
        for cl, col in COLOURS.items():
            s = sel & (c.classification == cl)
            ax.scatter(c.x[s] - cx, c.y[s] - cy, s=6, c=col, lw=0)
        for geoms, style in ((polys, "k-"), (layer, "m-")):
            for g in geoms:
                if g.distance(shapely.Point(cx, cy)) < 2 * r:
                    for gg in getattr(g, "geoms", [g]):
                        xs, ys = gg.exterior.xy
                        ax.plot(np.asarray(xs) - cx, np.asarray(ys) - cy, style, lw=1.2)
        ax.axvline(float(c.x.max()) - cx, color="k", ls="--", lw=0.8)
        ax.plot(0, 0, "kx", ms=10)
        d = out[str(i)]
        ax.set_title(f"footprint {i}: {d['area_m2']:.1f} m2 ({d['area_inside_the_crop_m2']:.1f} inside the crop)\ninner "
                     f"roof-level returns {d['inner_roof_level_returns']['all']}, "
                     f"{d['inner_roof_level_returns']['first of a pulse that went on to the ground']} went on to the ground",
                     fontsize=8)
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_aspect("equal")
    png = bgt.REPO / "bench" / "results" / "buildings_bgt_se_misses.png"
    save_png(fig, png, dpi=70)
    out["figure"] = png.name
    return out


def _separated(classified: Path, out: Path, _settings) -> None:
    c = io.read_cloud(classified, crs=bgt.CRS)
    k = cr.cells(c, cg.cloud_grid(classified, bgt.CELL_M, bgt.CRS)[0])
    io.write_classified(classified, out, separated_classes(c, k), crs=None)


def nested_round(argv, laz: Path, polys: list) -> int:
    """The separation in the nested choice on the footprint parts (module docstring, 3.)."""
    return bgt.nested_with_separation(
        argv, "bench/eval_buildings_bgt_foliage.py", laz, polys, _separated, "foliage beneath low tops",
        "foliage beneath low tops (bench/eval_buildings_bgt_foliage.py), after the classification",
        "rules_nested_footprint_parts_foliage")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    if "--nested" in argv:
        return nested_round(argv, laz, polys)
    if "--misses" in argv:   # section 1 alone (the figure and key "se_misses" of "seventh_round")
        with tempfile.TemporaryDirectory(prefix="eval_bgt_foliage_") as tmp:
            path = Path(tmp) / "shipped.laz"
            tiles.classify_file(laz, path, crs=bgt.CRS, params=ClassifySettings())
            store_result(bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions.json",
                         misses(path, laz, polys, Path(tmp)), key="se_misses", section="seventh_round")
        return 0
    parts = bgt.footprint_parts(polys, bgt.covered_footprints(laz, polys))
    laz_class = np.asarray(laspy.read(laz).classification)
    sets = bgt.held_out_sets()
    started = bgt.clock()
    result = {"command": "bench/eval_buildings_bgt_foliage.py " + " ".join(argv), "design_parts": list(DESIGN_PARTS),
              "separation": {"low_m": LOW_M, "pass_fraction": PASS_FRACTION, "confidence": "95 % one-sided",
                             "thresholds": "wall_min_height_m, roof_rms_m of ClassifySettings"},
              "classifications": {}, "held_out_sets": sets}
    with tempfile.TemporaryDirectory(prefix="eval_bgt_foliage_") as tmp:
        tmp = Path(tmp)
        for set_name in dict.fromkeys(sets.values()):
            overrides = {} if set_name == "shipped defaults" else bgt.RULE_SETS[set_name]
            path = tmp / f"{len(result['classifications'])}.laz"
            tiles.classify_file(laz, path, crs=bgt.CRS, params=dataclasses.replace(ClassifySettings(), **overrides))
            if set_name == "shipped defaults":
                result["se_misses"] = misses(path, laz, polys, tmp)
                for i in SE_MISSES:
                    print(f"footprint {i}: {result['se_misses'][str(i)]}", flush=True)
            r = result["classifications"][set_name] = analyse(path, laz_class, polys, parts)
            path.unlink()
            for name in (*DESIGN_PARTS, "south-west"):
                f = r["parts"][name]
                print(f"{set_name}, {name}: false -{f['false_m2_removed']:.2f} found -{f['found_m2_removed']:.2f} m2 -> "
                      f"{f['completeness_pct']} / {f['correctness_pct']} %", flush=True)
            print(f"  AHN3 per point PA/UA {r['ahn3_per_point_building_pa_ua_pct_before']} -> "
                  f"{r['ahn3_per_point_building_pa_ua_pct']}", flush=True)
    bgt.store_timed(bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions.json", result, started, "seventh_round")
    return 0


if __name__ == "__main__":
    sys.exit(main())
