"""The false building area of the worst held-out footprint part by cause, checked against every BGT layer of the
crop (AHN3 Delft, issue 44, ninth round, branch bgt-correct); and an open-structure separation in the nested choice.

Scoring of bench/eval_buildings_bgt.py (0.5 m cells, the class of a cell's highest return, 0.5 m band ignored, BGT
block hulls, footprint parts). ``--bgt-layers DIR``: the same crop's other BGT layers (``bgt_*.sqlite`` of
tudelft3d/3dfier's example_data/bgt, public; the shared data hold ``bgt_pand.sqlite`` only, byte-identical to that
folder's). Without it the layer causes read 0.

1. Causes (default run): each false cell of each footprint part gets the first cause that applies, in this order:
   * "BGT bridge deck, weir, overigbouwwerk or water": inside a polygon of ``bgt_overbruggingsdeel`` (decks),
     ``bgt_kunstwerkdeel`` (a weir), ``bgt_overigbouwwerk`` (canopies, open sheds) or ``bgt_waterdeel``: an object
     the BGT keeps in another layer than ``pand``;
   * "BGT wall": within 0.5 m (the band) of a ``bgt_scheiding`` wall or quay wall;
   * "roof past the BGT wall line": within 1.5 m of a footprint outline and its top within 0.5 m of the highest
     found roof cell within 1.5 m (the roof, an eave or a low roof joined to it, goes on at its level beyond the wall
     line the BGT maps: README of the shared data);
   * then the region's kind (bench/eval_buildings_bgt_false_regions.py; a region is 8-connected false cells):
     "split pulses" (crowns, hedges, low roofs under crowns), "see-through" (planar, shown at 95 % to pass more than
     0.1 of its pulses to the ground: a pergola, slats), "closed, AHN3 building" (stops the pulses, most cells AHN3
     class 6: a structure the ``pand`` layer does not hold), "other".
   Beside it: the false area on BGT terrain "erf" (private yards), the AHN3-building share. Classifications: the
   shipped defaults and the south-west part's held-out sets (stored nested choices and the completed grid's).
   Figure bench/results/buildings_bgt_causes_south-west.png (false cells by cause over the BGT outlines and walls).
   Also per classification the false and found m2 the open-structure separation (2.) takes per part
   ("open_structures_trade"; design parts south-east, north-west, north-east).
   Writes key "ninth_round_causes" of bench/results/buildings_bgt_false_regions.json.

2. ``--nested``: "open structures" as rule sets in the nested choice on the footprint parts (both criteria). A low
   building area (8-connected cells whose top return is building and wall_min_height_m-4 m above our ground; 4 m the
   low-growth heights' upper end) whose building returns lie on one plane (RMS below roof_rms_m) and which shows, at
   95 %, more than 0.1 of its pulses reaching the ground (last returns of split pulses within wall_min_height_m of
   it over the first returns above it; 0.1 the pierced share of the nested sets) has no closed roof: its building
   returns become class 1. The area is the unit (not a 3 x 3 window as pierced growth): an area joined to a roof
   or extension that stops the pulses keeps it. Applied after the classification to the shipped defaults' set and
   every set a fold chose (stored and completed grid), appended after the 32 stored and 16 grid sets (a tie goes to
   the set without it). Writes key "rules_nested_footprint_parts_open_structures" of bench/results/buildings_bgt.json.
   Designed looking at the south-west false regions (fifth round and this one): the south-west figure is not free
   of it; the folds decide on their training parts.

Run: nice .venv/bin/python bench/eval_buildings_bgt_causes.py --bgt-layers DIR [--nested]
"""

from __future__ import annotations

import dataclasses
import sqlite3
import sys
import tempfile
from pathlib import Path

import numpy as np
import shapely
import shapely.wkb
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as bgt  # noqa: E402
import eval_buildings_bgt_crowns as cr  # noqa: E402
import eval_buildings_bgt_false as bf  # noqa: E402
import eval_buildings_bgt_false_regions as fr  # noqa: E402
from results_json import read_results, store_result  # noqa: E402

from aerotri.core.figures import pyplot, save_png  # noqa: E402
from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify import class_grid as cg  # noqa: E402
from lidarctl.classify.pipeline import BUILDING, ClassifySettings, more_than_fraction  # noqa: E402

CAUSES = ("BGT bridge deck, weir, overigbouwwerk or water", "BGT wall (scheiding) within 0.5 m",
          "roof past the BGT wall line (eave, low roof joined at its level)", "split pulses", "see-through",
          "closed, AHN3 building, no BGT pand", "other")
REGION_CAUSE = {fr.KINDS[2]: 3, fr.KINDS[0]: 4, fr.KINDS[1]: 5, fr.KINDS[3]: 6}
OTHER_LAYERS = {"bgt_overbruggingsdeel.sqlite": "bridgeconstructionelement", "bgt_kunstwerkdeel.sqlite": "kunstwerkdeel",
                "bgt_overigbouwwerk.sqlite": "overigbouwwerk", "bgt_waterdeel.sqlite": "waterdeel"}
ROOF_REACH_M = 1.5     # eval_buildings_bgt_false.py's "roof beside" window (7 cells)
ROOF_LEVEL_M = 0.5     # a band's width: the top at the found roof's level
LOW_M = 4.0            # the low-growth heights' upper end
PASS_FRACTION = 0.1    # the pierced share the nested sets hold
COLOURS = ("k", "blue", "orange", "green", "magenta", "red", "cyan")
FALSE_REGIONS = bgt.REPO / "bench" / "results" / "buildings_bgt_false_regions.json"


def _geoms(path: Path, table: str, where: str = "") -> list:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    out = [shapely.wkb.loads(bytes(g)) for (g,) in con.execute(f"SELECT GEOMETRY FROM {table} {where}")]
    con.close()
    return out


@dataclasses.dataclass(frozen=True)
class Layers:
    """The BGT layers the causes read (empty without ``--bgt-layers``): objects kept in other layers, walls, yards."""

    other: list
    counts: dict
    walls: object
    erf: object


def layers(folder: Path | None) -> Layers:
    if folder is None:
        return Layers([], {}, None, None)
    other, counts = [], {}
    for f, t in OTHER_LAYERS.items():
        g = _geoms(folder / f, t)
        other += g
        counts[f] = len(g)
    walls = _geoms(folder / "bgt_scheiding.sqlite", "scheiding")
    counts["bgt_scheiding.sqlite"] = len(walls)
    erf = _geoms(folder / "bgt_onbegroeidterreindeel.sqlite", "onbegroeidterreindeel", "WHERE bgt_fysiekvoorkomen = 'erf'")
    return Layers(other, counts, shapely.union_all(walls), shapely.union_all(erf))


def causes(s: fr.Scene, k: int, lay: Layers, outlines, p: ClassifySettings) -> tuple[dict, np.ndarray]:
    """Part ``k``'s false area by cause (module docstring, 1.) and (row, col, cause) of its false cells."""
    part, lab = fr.regions(s, k, [], p)
    kind = {i: d["kind"] for i, d in enumerate(part["regions"], 1)}
    rr, cc = np.nonzero(lab > 0)
    xc, yc = s.grid.centres()
    x, y = xc[cc], yc[rr]
    cause = np.array([REGION_CAUSE[kind[v]] for v in lab[rr, cc]], int)
    hag, roof = s.kinds.hag_m[rr, cc], s.kinds.roof_near_m[rr, cc]
    cause[(shapely.distance(shapely.points(x, y), outlines) < ROOF_REACH_M) & (hag >= roof - ROOF_LEVEL_M)] = 2
    if lay.walls is not None:
        cause[shapely.distance(shapely.points(x, y), lay.walls) < bgt.BAND_M] = 1
    for g in lay.other:
        cause[shapely.contains_xy(g, x, y)] = 0
    a = bgt.CELL_M ** 2
    out = {"found_m2": part["found_m2"], "false_m2": part["false_m2"], "correctness_pct": round(part["correctness_pct"], 2),
           "false_m2_by_cause": {c: float((cause == i).sum() * a) for i, c in enumerate(CAUSES)},
           "false_m2_ahn3_building": float((s.kinds.ahn3_class[rr, cc] == BUILDING).sum() * a),
           "false_m2_on_bgt_erf": None if lay.erf is None else float(shapely.contains_xy(lay.erf, x, y).sum() * a),
           "roof_past_wall_line_top_m_median": float(np.median(hag[cause == 2])) if (cause == 2).any() else None}
    return out, np.stack([rr, cc, cause])


def plot(s: fr.Scene, k: int, cells: np.ndarray, polys: list, lay: Layers, path: Path, title: str) -> None:
    plt = pyplot()
    xc, yc = s.grid.centres()
    fig, ax = plt.subplots(figsize=(16, 12))
    r0, c0 = np.nonzero(s.scored & (s.part == k))
    ax.scatter(xc[c0], yc[r0], s=2, c="0.9", marker="s")
    rf, cf = np.nonzero(s.scored & (s.part == k) & s.ref)
    ax.scatter(xc[cf], yc[rf], s=2, c="0.6", marker="s")
    rr, cc, cause = cells
    for i, name in enumerate(CAUSES):
        m = cause == i
        if m.any():
            ax.scatter(xc[cc[m]], yc[rr[m]], s=9, c=COLOURS[i], marker="s", label=f"{name}: {m.sum() * bgt.CELL_M ** 2:g} m2")
    for p in polys:
        ax.plot(*p.exterior.xy, "k-", lw=0.8)
    for g in getattr(lay.walls, "geoms", [lay.walls] if lay.walls is not None else []):
        ax.plot(*(g.exterior.xy if g.geom_type == "Polygon" else g.xy), "b-", lw=0.6)
    ax.set_xlim(xc[c0].min() - 2, xc[c0].max() + 2)
    ax.set_ylim(yc[r0].min() - 2, yc[r0].max() + 2)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=9)
    ax.set_title(title, fontsize=10)
    save_png(fig, path, dpi=60)


def classifications() -> dict:
    """{label: rule set}: the shipped defaults and the south-west part's held-out sets."""
    stored = read_results(bgt.RESULTS)
    out = {"shipped defaults": "shipped defaults"}
    for key, tag in (("rules_nested_footprint_parts", "stored 32 sets"), ("rules_nested_footprint_parts_crowns_grid", "grid completed")):
        for crit in bgt.CRITERIA:
            out[f"held out south-west, '{crit}' ({tag})"] = stored[key][crit]["held_out"]["south-west"]["chosen"]
    return out


def settings_of(name: str) -> ClassifySettings:
    if name == "shipped defaults":
        return ClassifySettings()
    grid = read_results(bgt.RESULTS)["rules_nested_footprint_parts_crowns_grid"]["added_sets"]
    return dataclasses.replace(ClassifySettings(), **(bgt.RULE_SETS[name] if name in bgt.RULE_SETS else grid[name]["overrides"]))


def open_structures(c, k: cr.Cells) -> np.ndarray:
    """Cells of the low building areas with no closed roof (module docstring, 2.); boolean grid of ``k.shape``."""
    p = ClassifySettings()
    top = k.top.ravel()
    hag_top = c.z[top] - k.dem_m
    low = (c.classification[top] == BUILDING) & (hag_top >= p.wall_min_height_m) & (hag_top < LOW_M)
    lab, n = ndimage.label(low.reshape(k.shape), np.ones((3, 3), int))
    pl = lab.ravel()[k.flat]
    on_ground = c.z - k.dem_m[k.flat] <= p.wall_min_height_m
    through = (c.number_of_returns > 1) & (c.return_number == c.number_of_returns) & on_ground
    above = (c.return_number == 1) & ~on_ground
    take = more_than_fraction(np.bincount(pl[through], minlength=n + 1), np.bincount(pl[above], minlength=n + 1), PASS_FRACTION)
    take[0] = False
    b = c.classification == BUILDING
    for r in np.flatnonzero(take):
        m = b & (pl == r)
        if m.sum() < 4:
            take[r] = False
            continue
        A = np.column_stack([c.x[m] - c.x[m].mean(), c.y[m] - c.y[m].mean(), np.ones(int(m.sum()))])
        res = c.z[m] - A @ np.linalg.lstsq(A, c.z[m], rcond=None)[0]
        take[r] = float(np.sqrt(np.mean(res ** 2))) < p.roof_rms_m
    return take[lab]


def open_structures_trade(classified: Path, polys: list, parts: bgt.Parts) -> dict:
    """Per part, the false and found m2 the open-structure separation takes from ``classified`` and the figures after."""
    c = io.read_cloud(classified, crs=bgt.CRS)
    grid, ref, scored = bf.scoring_grid(classified, polys)
    xc, yc = grid.centres()
    k = cr.cells(c, grid)
    base = (c.classification == BUILDING)[k.top]
    return cr.part_figures(base & ~open_structures(c, k), base, ref, scored, parts.index(xc[None, :], yc[:, None]))


def _separated(classified: Path, out: Path, _settings) -> None:
    c = io.read_cloud(classified, crs=bgt.CRS)
    k = cr.cells(c, cg.cloud_grid(classified, bgt.CELL_M, bgt.CRS)[0])
    cls = np.asarray(c.classification).copy()
    cls[open_structures(c, k).ravel()[k.flat] & (cls == BUILDING)] = 1
    io.write_classified(classified, out, cls, crs=None)


def nested_round(argv, laz: Path, polys: list) -> int:
    """The separation in the nested choice (module docstring, 2.), over the 32 stored and 16 grid sets."""
    stored = read_results(bgt.RESULTS)
    grid = stored["rules_nested_footprint_parts_crowns_grid"]
    for name, v in grid["added_sets"].items():   # the grid's sets as bases and in the order (after the 32)
        bgt.RULE_SETS.setdefault(name, v["overrides"])
    sec = stored["rules_nested_footprint_parts"]
    bases = list(dict.fromkeys([sec["shipped_defaults_set"]] + [v["chosen"] for s in (sec, grid) for crit in bgt.CRITERIA
                                                                 for v in s[crit]["held_out"].values()]))
    real_read = bgt.read_results

    def with_grid(path):   # the stored sets' scores with the grid's 16 beside them
        doc = real_read(path)
        doc["rules_nested"]["rule_sets"] = {**doc["rules_nested"]["rule_sets"], **grid["added_sets"]}
        return doc

    bgt.read_results = with_grid
    try:
        return bgt.nested_with_separation(
            argv, "bench/eval_buildings_bgt_causes.py", laz, polys, _separated, "open structures",
            "open structures (bench/eval_buildings_bgt_causes.py), after the classification",
            "rules_nested_footprint_parts_open_structures", bases=bases)
    finally:
        bgt.read_results = real_read


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    folder = Path(argv[argv.index("--bgt-layers") + 1]) if "--bgt-layers" in argv else None
    if "--nested" in argv:
        return nested_round(argv, laz, polys)
    lay = layers(folder)
    parts = bgt.footprint_parts(polys, bgt.covered_footprints(laz, polys))
    outlines = shapely.union_all([p.boundary for p in polys])
    runs = classifications()
    started = bgt.clock()
    result = {"command": "bench/eval_buildings_bgt_causes.py " + " ".join(argv), "causes": list(CAUSES),
              "bgt_layers": {"source": "tudelft3d/3dfier example_data/bgt (the same crop)", "features": lay.counts} if folder else None,
              "classifications": runs, "runs": {}, "open_structures_trade": {}}
    with tempfile.TemporaryDirectory(prefix="eval_bgt_causes_") as tmp:
        done = {}
        for label, name in runs.items():
            if name not in done:
                path = Path(tmp) / f"{len(done)}.laz"
                p = settings_of(name)
                tiles.classify_file(laz, path, crs=bgt.CRS, params=p)
                done[name] = (fr.scene(path, laz, polys, parts), p)
                result["open_structures_trade"][name] = open_structures_trade(path, polys, parts)
                path.unlink()
            s, p = done[name]
            result["runs"][label] = {"rule_set": name}
            for k, pn in enumerate(bgt.PARTS):
                r, cells = causes(s, k, lay, outlines, p)
                result["runs"][label][pn] = r
                print(f"{label} ({name}), {pn}: correctness {r['correctness_pct']} %, false {r['false_m2']} m2: "
                      + ", ".join(f"{c} {v:g}" for c, v in r["false_m2_by_cause"].items()), flush=True)
                if label == "held out south-west, 'area and objects' (stored 32 sets)" and pn == "south-west":
                    png = bgt.REPO / "bench" / "results" / "buildings_bgt_causes_south-west.png"
                    plot(s, k, cells, polys, lay, png, f"south-west footprint part held out ('{name}', chosen on the other "
                         "three parts): false cells by cause; light grey scored, grey BGT pand, blue BGT walls")
                    result["figure"] = png.name
    bgt.store_timed(FALSE_REGIONS, result, started, "ninth_round_causes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
