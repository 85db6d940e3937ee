"""Crowns over low roofs in the false building area against the BGT (AHN3 Delft, issue 44, sixth round): is there
a return-structure separation that keeps a roof's returns building and a crown's above it vegetation?

Scoring of bench/eval_buildings_bgt.py (0.5 m cells, the class of a cell's highest return, 0.5 m band ignored, BGT
block hulls, footprint parts). Returns are linked into pulses by their GPS time (AHN3: LAS 1.2, point format 1; a
pulse's returns share it, ordered by return number), so each return knows where its pulse ended.

1. What the top return of each false and each found cell is, by its pulse (per footprint part): a single return
   (the pulse stopped there); the first of a split pulse that ended on the ground (within wall_min_height_m:
   a hedge or crown over open ground, an eave beside a wall); one whose pulse ended on a return we call building
   more than roof_rms_m below it (a crown, or an upper roof's edge, over a roof); other split pulses (ended in
   vegetation, or within roof_rms_m: a roof's own edge). Crossed with AHN3's class of the same return (AHN3 labels a
   crown over a roof class 1, issue 44).
2. The separation, fixed on the design parts before the south-west part was scored (its thresholds the
   classification's own, ClassifySettings): "crown returns" are non-last building returns whose 3 x 3 window
   fails the roof cells' split-pulse test (max_multi_return_fraction at 95 %), whose pulse ended more than
   roof_rms_m below on a return we call building lying on its cell's surface of building last returns (within
   small_plane_rms_m) where that surface is planar (3 x 3 plane RMS below small_plane_rms_m): a roof. Variant
   "cell": every building return of such a cell more than roof_rms_m above the roof the crown returns' pulses ended
   on (a crown's single returns too); and the pulse test alone (no planar-roof and window tests). Applied after the
   classification (the pipeline holds no GPS time); the false and
   found area it takes per part and AHN3's per-point building PA / UA.
   The top returns that are single returns (the pulse stopped there): area, the part of it on a planar surface
   (3 x 3 plane RMS of the cells' top returns below roof_rms_m), median height and plane RMS, for the false cells
   AHN3 does and does not call building and for the found cells; and the false and found cells lower than 2.5 / 3 m
   (the low-growth heights of the nested sets) whose top surface is rough (plane RMS of at least rough_rms_m).
3. The ceiling of any crown separation: the false cells whose top return is a pulse ending on our building below
   and which AHN3 does not call building, removed with nothing found lost.

With ``--nested``: the separation as rule sets in the nested choice of bench/eval_buildings_bgt.py (footprint parts,
both criteria): each set any fold chose in the fifth round and the shipped defaults' set, with the crown returns
(section 2) made vegetation after the classification, scored as there (area, objects, vector centroids with and
without roof dropouts) and added after the 32 stored sets (a tie goes to the set without the separation); the
choices made again over all of them. Writes key "rules_nested_footprint_parts_crown_returns" of
bench/results/buildings_bgt.json (the stored sets' section is not changed).

Classifications: the shipped defaults and the held-out rule sets of bench/results/buildings_bgt.json
("rules_nested_footprint_parts", both criteria). Design parts: south-east, north-west, north-east (listed first);
the south-west part scored once with the separation fixed (see the doc for what was tried before).
Writes key "sixth_round_crowns" of bench/results/buildings_bgt_false_regions.json.
Run: nice .venv/bin/python bench/eval_buildings_bgt_crowns.py [--nested]
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as bgt  # noqa: E402
import eval_buildings_bgt_false as bf  # noqa: E402

from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify import class_grid as cg  # noqa: E402
from lidarctl.classify.pipeline import BUILDING, GROUND, HIGH_VEG, MED_VEG, ClassifySettings, fewer_multi_returns  # noqa: E402
from lidarctl.raster_ops import plane_rms  # noqa: E402

DESIGN_PARTS = ("south-east", "north-west", "north-east")
TOP_KINDS = ("single return", "split, ended on the ground", "split, ended on our building below",
             "split, other")


def pulse_ends(gps_time: np.ndarray, return_number: np.ndarray) -> np.ndarray:
    """Index of the last linked return of each return's pulse (returns sharing a GPS time, consecutive return
    numbers); a return with no later return of its pulse is its own end."""
    order = np.lexsort((return_number, gps_time))
    nxt = np.arange(len(gps_time))
    link = (gps_time[order][1:] == gps_time[order][:-1]) & (return_number[order][1:] == return_number[order][:-1] + 1)
    nxt[order[:-1][link]] = order[1:][link]
    end = nxt.copy()
    while True:
        step = nxt[end]
        if np.array_equal(step, end):
            return end
        end = step


@dataclasses.dataclass(frozen=True)
class Cells:
    """A classification on the scoring grid: each return's cell, the index of each cell's top return, the ground
    height per cell (m, mean of our ground returns, empty cells from the nearest)."""

    flat: np.ndarray
    top: np.ndarray
    dem_m: np.ndarray
    shape: tuple


def cells(c, grid) -> Cells:
    t, shape = grid.transform, grid.shape
    flat = (np.clip(np.floor((c.y - t.f) / t.e).astype(int), 0, shape[0] - 1) * shape[1]
            + np.clip(np.floor((c.x - t.c) / t.a).astype(int), 0, shape[1] - 1))
    size = shape[0] * shape[1]
    top = bf.top_returns(flat, c.z, shape)
    g = c.classification == GROUND
    n = np.bincount(flat[g], minlength=size)
    dem = np.where(n > 0, np.bincount(flat[g], c.z[g], minlength=size) / np.maximum(n, 1), np.nan).reshape(shape)
    dem = dem[tuple(ndimage.distance_transform_edt(np.isnan(dem), return_distances=False, return_indices=True))]
    return Cells(flat, top, dem.ravel(), shape)


def top_kind(c, k: Cells, end: np.ndarray, p: ClassifySettings) -> np.ndarray:
    """Index into TOP_KINDS of each cell's top return."""
    i = k.top.ravel()
    e = end[i]
    split = e != i
    on_ground = c.z[e] - k.dem_m[k.flat[e]] <= p.wall_min_height_m
    on_building = (c.classification[e] == BUILDING) & (c.z[e] < c.z[i] - p.roof_rms_m)
    kind = np.where(~split, 0, np.where(on_ground, 1, np.where(on_building, 2, 3)))
    return kind.reshape(k.shape)


def crown_returns(c, k: Cells, end: np.ndarray, p: ClassifySettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(crown returns, the "cell" variant, the pulse test alone): building returns to take out of the building class
    (section 2)."""
    size = k.shape[0] * k.shape[1]
    b = c.classification == BUILDING
    last = c.return_number >= c.number_of_returns
    k3 = np.ones((3, 3), np.int64)
    n3 = ndimage.correlate(np.bincount(k.flat, minlength=size).reshape(k.shape), k3, mode="constant")
    m3 = ndimage.correlate(np.bincount(k.flat[c.number_of_returns > 1], minlength=size).reshape(k.shape), k3,
                           mode="constant")
    roof_like = fewer_multi_returns(m3, n3, p.max_multi_return_fraction).ravel()
    lsm = np.full(size, np.inf)
    np.minimum.at(lsm, k.flat[b & last], c.z[b & last])
    has = np.isfinite(lsm)
    planar = (plane_rms(np.where(has, lsm, k.dem_m).reshape(k.shape), 0.5).ravel() < p.small_plane_rms_m) & has
    fe = k.flat[end]
    on_roof = b[end] & planar[fe] & (np.abs(c.z[end] - lsm[fe]) <= p.small_plane_rms_m)
    ended_below = b & ~last & (end != np.arange(len(end))) & b[end] & (c.z[end] < c.z - p.roof_rms_m)
    crown = ended_below & on_roof & ~roof_like[k.flat]
    roof_z = np.full(size, np.inf)
    np.minimum.at(roof_z, k.flat[crown], c.z[end[crown]])
    cell = b & np.isfinite(roof_z[k.flat]) & (c.z > roof_z[k.flat] + p.roof_rms_m)
    return crown, cell, ended_below


def part_figures(bld, base, ref, scored, part) -> dict:
    out = {}
    for j, name in enumerate(bgt.PARTS):
        s = scored & (part == j)
        tp, fp, fn = (bld & ref & s).sum(), (bld & ~ref & s).sum(), (~bld & ref & s).sum()
        out[name] = {"false_m2_removed": float(((base & ~ref & s).sum() - fp) * 0.25),
                     "found_m2_removed": float(((base & ref & s).sum() - tp) * 0.25),
                     "completeness_pct": round(100.0 * tp / max(tp + fn, 1), 2),
                     "correctness_pct": round(100.0 * tp / max(tp + fp, 1), 2)}
    return out


def analyse(path: Path, laz_class: np.ndarray, end: np.ndarray, polys: list, parts: bgt.Parts, p: ClassifySettings) -> dict:
    c = io.read_cloud(path, crs=bgt.CRS)
    grid, ref, scored = bf.scoring_grid(path, polys)
    xc, yc = grid.centres()
    part = parts.index(xc[None, :], yc[:, None])
    k = cells(c, grid)
    b = c.classification == BUILDING
    base = b[k.top]
    kind = top_kind(c, k, end, p)
    ahn3_bld = (laz_class == BUILDING)[k.top]
    # the surface of the cells' top returns: planar (a roof, a closed structure) or rough (foliage)
    top_rms = plane_rms(c.z[k.top], 0.5)
    top_hag = c.z[k.top] - k.dem_m.reshape(k.shape)
    out = {"top_return_by_pulse": {}, "single_return_tops": {}}
    for j, name in enumerate(bgt.PARTS):
        s = scored & (part == j)
        fig = {}
        for label, m in (("false", base & ~ref & s), ("found", base & ref & s)):
            fig[label] = {kd: {"AHN3 building": float((m & (kind == q) & ahn3_bld).sum() * 0.25),
                               "AHN3 not building": float((m & (kind == q) & ~ahn3_bld).sum() * 0.25)}
                          for q, kd in enumerate(TOP_KINDS)}
        tp, fp = (base & ref & s).sum(), (base & ~ref & s).sum()
        ceiling_fp = fp - (base & ~ref & s & (kind == 2) & ~ahn3_bld).sum()
        fig["correctness_pct"] = round(100.0 * tp / max(tp + fp, 1), 2)
        fig["ceiling_correctness_pct"] = round(100.0 * tp / max(tp + ceiling_fp, 1), 2)
        out["top_return_by_pulse"][name] = fig
        single = {}
        for label, m in (("false, AHN3 not building", base & ~ref & s & (kind == 0) & ~ahn3_bld),
                         ("false, AHN3 building", base & ~ref & s & (kind == 0) & ahn3_bld),
                         ("found", base & ref & s & (kind == 0))):
            single[label] = {"m2": float(m.sum() * 0.25),
                             "planar_m2": float((m & (top_rms < p.roof_rms_m)).sum() * 0.25),
                             "hag_m_median": round(float(np.median(top_hag[m])), 2) if m.any() else None,
                             "top_plane_rms_m_median": round(float(np.median(top_rms[m])), 3) if m.any() else None}
        # low and rough: a hedge's or crown's top that stopped the pulse, by the roughness the classification uses on
        # single-return clouds (rough_rms_m) below the low-growth heights the nested sets hold
        single["low and rough"] = {f"under {h:g} m": {lab: float((m & (top_hag < h) & (top_rms >= p.rough_rms_m)).sum() * 0.25)
                                                     for lab, m in (("false", base & ~ref & s), ("found", base & ref & s))}
                                   for h in (2.5, 3.0)}
        out["single_return_tops"][name] = single
    crown, cell, ended_below = crown_returns(c, k, end, p)
    for label, take in (("crown returns", crown), ("crown returns, cell", cell),
                        ("pulse ended on our building below, no roof tests", ended_below)):
        isb = b & ~take
        tp = (isb & (laz_class == BUILDING)).sum()
        out[label] = {"parts": part_figures(isb[k.top], base, ref, scored, part), "returns_changed": int(take.sum()),
                      "changed_ahn3_building": int((take & (laz_class == BUILDING)).sum()),
                      "ahn3_per_point_building_pa_ua_pct": [round(100.0 * tp / (laz_class == BUILDING).sum(), 2),
                                                            round(100.0 * tp / max(isb.sum(), 1), 2)],
                      "ahn3_per_point_building_pa_ua_pct_before": [
                          round(100.0 * (b & (laz_class == BUILDING)).sum() / (laz_class == BUILDING).sum(), 2),
                          round(100.0 * (b & (laz_class == BUILDING)).sum() / max(b.sum(), 1), 2)]}
    return out


def _separated(classified: Path, out: Path, end: np.ndarray, p: ClassifySettings) -> None:
    """``classified`` with its crown returns (section 2) made vegetation (medium or high by their height), to ``out``."""
    c = io.read_cloud(classified, crs=bgt.CRS)
    grid = cg.cloud_grid(classified, bgt.CELL_M, bgt.CRS)[0]
    k = cells(c, grid)
    crown = crown_returns(c, k, end, p)[0]
    cls = c.classification.copy()
    cls[crown] = np.where(c.z[crown] - k.dem_m[k.flat[crown]] > p.medium_veg_max_m, HIGH_VEG, MED_VEG)
    io.write_classified(classified, out, cls, crs=None)


def nested_round(argv, laz: Path, polys: list, end: np.ndarray) -> int:
    """The separation in the nested choice on the footprint parts (module docstring, ``--nested``)."""
    return bgt.nested_with_separation(
        argv, "bench/eval_buildings_bgt_crowns.py", laz, polys, lambda raw, out, prm: _separated(raw, out, end, prm),
        "crown returns (pulse)", "crown returns (bench/eval_buildings_bgt_crowns.py), after the classification",
        "rules_nested_footprint_parts_crown_returns")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    parts = bgt.footprint_parts(polys, bgt.covered_footprints(laz, polys))
    raw = laspy.read(laz)
    end = pulse_ends(np.asarray(raw.gps_time), np.asarray(raw.return_number))
    laz_class = np.asarray(raw.classification)
    if "--nested" in argv:
        return nested_round(argv, laz, polys, end)
    linked = (np.asarray(raw.return_number) < np.asarray(raw.number_of_returns))
    sets = bgt.held_out_sets()
    started = bgt.clock()
    result = {"command": "bench/eval_buildings_bgt_crowns.py " + " ".join(argv), "top_kinds": list(TOP_KINDS),
              "design_parts": list(DESIGN_PARTS),
              "pulses": {"non_last_returns": int(linked.sum()),
                         "non_last_returns_linked": int((linked & (end != np.arange(len(end)))).sum())},
              "classifications": {}}
    with tempfile.TemporaryDirectory(prefix="eval_bgt_crowns_") as tmp:
        done = {}
        for set_name in dict.fromkeys(sets.values()):
            overrides = {} if set_name == "shipped defaults" else bgt.RULE_SETS[set_name]
            prm = dataclasses.replace(ClassifySettings(), **overrides)
            path = Path(tmp) / f"{len(done)}.laz"
            tiles.classify_file(laz, path, crs=bgt.CRS, params=prm)
            done[set_name] = analyse(path, laz_class, end, polys, parts, prm)
            path.unlink()
            r = done[set_name]
            for name in (*DESIGN_PARTS, "south-west"):
                f = r["top_return_by_pulse"][name]
                cr = r["crown returns"]["parts"][name]
                cc = r["crown returns, cell"]["parts"][name]
                print(f"{set_name}, {name}: correctness {f['correctness_pct']} % (ceiling {f['ceiling_correctness_pct']} %); "
                      f"crown returns: false -{cr['false_m2_removed']:.2f} found -{cr['found_m2_removed']:.2f} m2; cell: "
                      f"false -{cc['false_m2_removed']:.2f} found -{cc['found_m2_removed']:.2f} m2", flush=True)
            print(f"  AHN3 per point PA/UA {r['crown returns']['ahn3_per_point_building_pa_ua_pct_before']} -> "
                  f"{r['crown returns']['ahn3_per_point_building_pa_ua_pct']} / cell "
                  f"{r['crown returns, cell']['ahn3_per_point_building_pa_ua_pct']}", flush=True)
        result["classifications"] = done
        result["held_out_sets"] = sets
    bgt.store_timed(bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions.json", result, started, "sixth_round_crowns")
    return 0


if __name__ == "__main__":
    sys.exit(main())
