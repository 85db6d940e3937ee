"""The false building area against the BGT footprints region by region, per footprint part (AHN3 Delft, issue 44,
fifth round: the south-west part's correctness), and the correctness against the BGT's own mapping rules.

Scoring of bench/eval_buildings_bgt.py (0.5 m cells, highest return's class, 0.5 m band ignored, BGT block hulls,
footprint parts). A false region: 8-connected false building cells of one part. Per region: its area, the height
of the highest return above our ground (bench/eval_buildings_bgt_false.py's cell kinds), its size (minimum rotated
rectangle of the cells), the returns in its cells by pulse (share of multi-return points, of last returns of split
pulses, of returns within wall_min_height_m of the ground), the plane RMS of its building returns, the median
intensity of its building returns, AHN3's class of its cells, the pulses through to the ground (the last returns of
split pulses on the ground over the first returns above it: pierced growth's measure, summed over the region), and
with ``--bgt-layers DIR`` the BGT terrain part under it (``bgt_onbegroeidterreindeel.sqlite`` etc. of
tudelft3d/3dfier's example_data/bgt, the same crop's BGT; not in the shared data).

Kinds of false region, from the BGT's rules (a BGT ``pand`` is a BAG pand: a building enclosed by walls with a
closed roof; the BGT records a canopy, ``overigbouwwerk`` type ``overkapping``, by the footprints of its posts only,
and sheds that are no pand are not BGT content):
* "see-through surface": planar (building returns' plane RMS below roof_rms_m) and shown (95 %) to let more than
  pierced_growth_max_fraction of its pulses through to the ground (0.1, the nested sets' share, where the set has
  that test off): a pergola, a slatted or translucent canopy, no closed roof;
* "stops the pulses, AHN3 building": at most small_building_max_multi_fraction multi-return points and most cells
  AHN3 class 6: a structure with a closed roof that the BGT does not hold (a garden building, an extension, a
  canopy's roof);
* "split pulses": more multi-return points than that (hedges and crowns grown from a roof, a roof under a crown);
* "other" (AHN3 not building, single returns: walls, vehicles, structures AHN3 leaves unclassified).
Thresholds are the classification's own (ClassifySettings), none fitted here. "Correctness against the BGT's
rules" leaves the first two kinds out of the false area (clearly a bound: a structure with a closed roof the BGT
misses is counted as not mapped by rule, though the BAG might register it); the plain correctness stays the
headline.

Classifications: the shipped defaults, and per part the rule set the nested procedure chose for it held out
(bench/results/buildings_bgt.json, "rules_nested_footprint_parts", criteria "area and objects" and "area"). Figure
bench/results/buildings_bgt_false_regions_south-west.png: the eight largest false regions of the south-west part
under its held-out set by "area and objects" (returns by our class, region cells, BGT outlines; a profile with split pulses marked).
Writes key "fifth_round" of bench/results/buildings_bgt_false_regions.json.
Run: nice .venv/bin/python bench/eval_buildings_bgt_false_regions.py [--bgt-layers DIR]
"""

from __future__ import annotations

import dataclasses
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
import eval_buildings_bgt as bgt  # noqa: E402
import eval_buildings_bgt_false as bf  # noqa: E402
from results_json import read_results, store_result  # noqa: E402

from aerotri.core.figures import pyplot, save_png  # noqa: E402
from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify import class_grid as cg  # noqa: E402
from lidarctl.classify.pipeline import BUILDING, GROUND, ClassifySettings, more_than_fraction  # noqa: E402

COLOURS = {1: "0.6", 2: "sienna", 3: "lightgreen", 4: "limegreen", 5: "darkgreen", 6: "red", 9: "blue"}
KINDS = ("see-through surface", "stops the pulses, AHN3 building", "split pulses", "other")
NOT_MAPPED_BY_RULE = KINDS[:2]
TERRAIN = {"onbegroeidterreindeel": ("onbegroeidterreindeel", "bgt_fysiekvoorkomen"),
           "begroeidterreindeel": ("plantcover", "plus_fysiekvoorkomen")}


def terrain_layers(folder: Path | None) -> list:
    """(polygon, "layer: type") of the BGT terrain parts in ``folder`` (3dfier's example_data/bgt), or []."""
    if folder is None:
        return []
    out = []
    for name, (table, field) in TERRAIN.items():
        con = sqlite3.connect(f"file:{folder / f'bgt_{name}.sqlite'}?mode=ro", uri=True)
        out += [(shapely.wkb.loads(bytes(g)), f"{name}: {v}") for g, v in con.execute(f"SELECT GEOMETRY, {field} FROM {table}")]
        con.close()
    return out


@dataclasses.dataclass(frozen=True)
class Scene:
    """One classification on the scoring grid: the part of each cell, building / footprint / scored masks, the
    cell kinds, the returns with their cell, ground height and AHN3 class."""

    grid: cg.ClassGrid
    part: np.ndarray
    ref: np.ndarray
    bld: np.ndarray
    scored: np.ndarray
    kinds: bf.CellKinds
    cloud: object
    row: np.ndarray
    col: np.ndarray
    hag_m: np.ndarray
    ahn3: np.ndarray


def scene(classified: Path, laz: Path, polys: list, parts: bgt.Parts) -> Scene:
    grid, ref, scored = bf.scoring_grid(classified, polys)
    xc, yc = grid.centres()
    bld = bgt.building_raster(classified, grid)[0]
    c = io.read_cloud(classified, crs=bgt.CRS)
    t, shape = grid.transform, grid.shape
    col = np.clip(np.floor((c.x - t.c) / t.a).astype(int), 0, shape[1] - 1)
    row = np.clip(np.floor((c.y - t.f) / t.e).astype(int), 0, shape[0] - 1)
    flat = row * shape[1] + col
    g = c.classification == GROUND
    n_g = np.bincount(flat[g], minlength=shape[0] * shape[1])
    dem = np.where(n_g > 0, np.bincount(flat[g], c.z[g], minlength=n_g.size) / np.maximum(n_g, 1), np.nan).reshape(shape)
    dem = dem[tuple(ndimage.distance_transform_edt(np.isnan(dem), return_distances=False, return_indices=True))]
    return Scene(grid, parts.index(xc[None, :], yc[:, None]), ref, bld, scored, bf.cell_kinds(classified, laz, grid, bld & ref),
                 c, row, col, c.z - dem[row, col], io.read_cloud(laz, crs=bgt.CRS).classification)


def region_kind(r: dict, p: ClassifySettings) -> str:
    if r["plane_rms_m"] is not None and r["plane_rms_m"] < p.roof_rms_m and r["pierced"]:
        return KINDS[0]
    if r["multi_return_share"] is not None and r["multi_return_share"] <= p.small_building_max_multi_fraction:
        return KINDS[1] if r["ahn3_building_cell_share"] > 0.5 else KINDS[3]
    return KINDS[2] if r["multi_return_share"] is not None else KINDS[3]


def regions(s: Scene, k: int, terrain: list, p: ClassifySettings) -> tuple[dict, np.ndarray]:
    """The false regions of part ``k`` (largest first) and their label raster."""
    c, a = s.cloud, bgt.CELL_M ** 2
    in_part = s.scored & (s.part == k)
    fp, tp = s.bld & ~s.ref & in_part, s.bld & s.ref & in_part
    lab, n = ndimage.label(fp, np.ones((3, 3), int))
    pl = lab[s.row, s.col]
    xc, yc = s.grid.centres()
    level = s.hag_m <= p.wall_min_height_m
    through = (c.number_of_returns > 1) & (c.return_number == c.number_of_returns) & level
    above = (c.return_number == 1) & ~level
    out = []
    for r in range(1, n + 1):
        m = lab == r
        rr, cc = np.nonzero(m)
        pts = pl == r
        bp = pts & (c.classification == BUILDING)
        rect = shapely.MultiPoint(np.column_stack([xc[cc], yc[rr]])).buffer(0.25, cap_style="square").minimum_rotated_rectangle
        e = np.asarray(rect.exterior.coords)
        sides = sorted([float(np.hypot(*(e[1] - e[0]))), float(np.hypot(*(e[2] - e[1])))])
        rms = None
        if bp.sum() >= 4:
            A = np.column_stack([c.x[bp] - c.x[bp].mean(), c.y[bp] - c.y[bp].mean(), np.ones(int(bp.sum()))])
            coef = np.linalg.lstsq(A, c.z[bp], rcond=None)[0]
            rms = float(np.sqrt(np.mean((c.z[bp] - A @ coef) ** 2)))
        nr, rn = c.number_of_returns[pts], c.return_number[pts]
        n_through, n_above = int((through & pts).sum()), int((above & pts).sum())
        cen = (float(xc[cc].mean()), float(yc[rr].mean()))
        terr = {}
        for g, v in terrain:
            inside = int(shapely.contains_xy(g, xc[cc], yc[rr]).sum())
            if inside:
                terr[v] = terr.get(v, 0) + inside
        d = {"area_m2": float(m.sum() * a), "centre_m": [round(cen[0], 2), round(cen[1], 2)],
             "hag_m_median": round(float(np.median(s.kinds.hag_m[m])), 2),
             "width_m": round(sides[0], 2), "length_m": round(sides[1], 2),
             "returns": int(pts.sum()), "building_returns": int(bp.sum()),
             "plane_rms_m": None if rms is None else round(rms, 3),
             "multi_return_share": round(float((nr > 1).mean()), 3) if pts.any() else None,
             "last_of_split_pulse_share": round(float(((nr > 1) & (rn == nr)).mean()), 3) if pts.any() else None,
             "returns_on_the_ground_share": round(float(level[pts].mean()), 3) if pts.any() else None,
             "pulses_through_to_the_ground": [n_through, n_above],
             "pierced": bool(more_than_fraction(n_through, n_above, p.pierced_growth_max_fraction or 0.1)),
             "intensity_median": float(np.median(c.intensity[bp])) if bp.any() else None,
             "ahn3_classes_cells": {str(int(v)): int(nn) for v, nn in zip(*np.unique(s.kinds.ahn3_class[m], return_counts=True))},
             "ahn3_building_cell_share": round(float(np.mean(s.kinds.ahn3_class[m] == BUILDING)), 3),
             "bgt_terrain_cells": terr}
        d["kind"] = region_kind(d, p)
        out.append((d, r))
    out.sort(key=lambda t: -t[0]["area_m2"])
    relabel = np.zeros(n + 1, int)
    for i, (_, r) in enumerate(out, 1):
        relabel[r] = i
    tp_m2, fp_m2 = float(tp.sum() * a), float(fp.sum() * a)
    by_kind = {kd: sum(d["area_m2"] for d, _ in out if d["kind"] == kd) for kd in KINDS}
    not_mapped = sum(by_kind[kd] for kd in NOT_MAPPED_BY_RULE)
    return {"found_m2": tp_m2, "false_m2": fp_m2, "correctness_pct": 100.0 * tp_m2 / max(tp_m2 + fp_m2, 1e-9),
            "false_m2_by_kind": by_kind,
            "correctness_against_the_bgt_rules_pct": 100.0 * tp_m2 / max(tp_m2 + fp_m2 - not_mapped, 1e-9),
            "regions": [d for d, _ in out]}, relabel[lab]


def plot(s: Scene, lab: np.ndarray, regs: list, polys: list, path: Path, title: str) -> None:
    plt = pyplot()
    c = s.cloud
    xc, yc = s.grid.centres()
    show = regs[:8]
    fig, axs = plt.subplots(4, 4, figsize=(24, 24))
    for i, d in enumerate(show):
        ax, ax2 = axs[i // 2, (i % 2) * 2], axs[i // 2, (i % 2) * 2 + 1]
        x0, y0 = d["centre_m"]
        h = 6.0
        m = (np.abs(c.x - x0) < h) & (np.abs(c.y - y0) < h)
        ax.scatter(c.x[m], c.y[m], c=[COLOURS.get(int(v), "k") for v in c.classification[m]], s=6)
        rr, cc = np.nonzero(lab == i + 1)
        ax.scatter(xc[cc], yc[rr], marker="s", facecolors="none", edgecolors="k", s=40, lw=0.6)
        for p in polys:
            ax.plot(*p.exterior.xy, "k-", lw=1.5)
        ax.set_xlim(x0 - h, x0 + h)
        ax.set_ylim(y0 - h, y0 + h)
        ax.set_aspect("equal")
        ax.set_title(f"{i + 1}: {d['area_m2']:g} m2, {d['hag_m_median']} m up, {d['kind']}; multi-return "
                     f"{d['multi_return_share']}, plane RMS {d['plane_rms_m']} m, AHN3 {d['ahn3_classes_cells']}", fontsize=9)
        near = m & (np.hypot(c.x - x0, c.y - y0) < 5.0)
        inreg = near & (lab[s.row, s.col] == i + 1)
        ax2.scatter(c.x[near] - x0, c.z[near], c=[COLOURS.get(int(v), "k") for v in c.classification[near]], s=5)
        ax2.scatter(c.x[inreg] - x0, c.z[inreg], facecolors="none", edgecolors="k", s=14, lw=0.5)
        split = near & (c.number_of_returns > 1)
        ax2.scatter(c.x[split] - x0, c.z[split], marker="x", c="orange", s=10, lw=0.6)
        ax2.set_title("returns within 5 m: east (m from the region's centre) against height; o in the region, "
                      "x split pulse", fontsize=9)
    fig.suptitle(title, y=0.998)
    fig.tight_layout(rect=(0, 0, 1, 0.99))
    save_png(fig, path, dpi=50)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    layers = Path(argv[argv.index("--bgt-layers") + 1]) if "--bgt-layers" in argv else None
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    parts = bgt.footprint_parts(polys, bgt.covered_footprints(laz, polys))
    terrain = terrain_layers(layers)
    nested = read_results(bgt.RESULTS)["rules_nested_footprint_parts"]
    runs = {"defaults": {name: "shipped defaults" for name in bgt.PARTS}}
    for criterion in ("area and objects", "area"):
        runs[f"nested held out, criterion {criterion}"] = {n: nested[criterion]["held_out"][n]["chosen"] for n in bgt.PARTS}
    t0, cpu0, load0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    result = {"command": "bench/eval_buildings_bgt_false_regions.py " + " ".join(argv), "kinds": list(KINDS),
              "not_mapped_by_the_bgt_rules": list(NOT_MAPPED_BY_RULE),
              "bgt_layers": "tudelft3d/3dfier example_data/bgt (the same crop)" if layers else None}
    with tempfile.TemporaryDirectory(prefix="eval_bgt_regions_") as tmp:
        done = {}
        for run, sets in runs.items():
            result[run] = {}
            for k, name in enumerate(bgt.PARTS):
                set_name = sets[name]
                if set_name not in done:
                    overrides = {} if set_name == "shipped defaults" else bgt.RULE_SETS[set_name]
                    path = Path(tmp) / f"{len(done)}.laz"
                    tiles.classify_file(laz, path, crs=bgt.CRS, params=dataclasses.replace(ClassifySettings(), **overrides))
                    done[set_name] = (scene(path, laz, polys, parts), dataclasses.replace(ClassifySettings(), **overrides))
                s, p = done[set_name]
                part, lab = regions(s, k, terrain, p)
                result[run][name] = {"rule_set": set_name, **part}
                if run == "nested held out, criterion area and objects" and name == "south-west":
                    plot(s, lab, part["regions"], polys, bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions_south-west.png",
                         f"south-west footprint part, rule set '{set_name}' (chosen on the other three parts)")
                print(f"{run}, {name} ({set_name}): false {part['false_m2']:.2f} m2 of which "
                      + ", ".join(f"{kd} {v:.2f}" for kd, v in part["false_m2_by_kind"].items())
                      + f"; correctness {part['correctness_pct']:.2f} %, against the BGT's rules "
                      f"{part['correctness_against_the_bgt_rules_pct']:.2f} %", flush=True)
    result["seconds"], result["cpu_s"] = time.perf_counter() - t0, time.process_time() - cpu0
    result["load_average_before_after"] = [load0, os.getloadavg()[0]]
    store_result(bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions.json", result, key="fifth_round")
    return 0


if __name__ == "__main__":
    sys.exit(main())
