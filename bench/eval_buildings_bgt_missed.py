"""The BGT footprints whose centroid the ``lidarctl vectors`` building layer missed on the AHN3 Delft crop before the
fourth round (crown_covered_roofs and the vectors' roof_dropouts off), and what each is: per footprint its area,
quarter and footprint part (bench/eval_buildings_bgt.py), our classes and AHN3's of the returns inside it, the
returns on its roof by pulse (single, first / last of a split pulse, heights above the ground ring around it), and
whether the map holds its centroid before and with the fourth round's rules.

Figure bench/results/buildings_bgt_missed.png: per footprint the returns around it coloured by our class with the
fourth round's rules (ground brown, vegetation greens, building red), the BGT outlines (black), the building
polygons before (blue dashed) and with the rules (magenta). Writes bench/results/buildings_bgt_missed.json.
Run: nice .venv/bin/python bench/eval_buildings_bgt_missed.py
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_buildings_bgt as bgt  # noqa: E402

from aerotri.core.figures import pyplot, save_png  # noqa: E402
from lidarctl import io, tiles  # noqa: E402
from lidarctl.classify.pipeline import ClassifySettings  # noqa: E402
from lidarctl.vectors import layers as map_vectors  # noqa: E402

COLOURS = {1: "0.6", 2: "sienna", 3: "lightgreen", 4: "limegreen", 5: "darkgreen", 6: "red", 9: "blue"}


def _layer(classified: Path, gpkg: Path, roof_dropouts: bool) -> list:
    settings = dataclasses.replace(map_vectors.MapVectorSettings(), roof_dropouts=roof_dropouts)
    mv = map_vectors.extract_vectors([classified], gpkg, params=settings, crs=bgt.CRS)
    return next(lay for lay in mv.layers if lay.name == "buildings").geometries


def describe(poly, ours, ahn, inside_before: bool, inside_after: bool) -> dict:
    """What lies inside a footprint: classes, and the returns of its roof level by pulse."""
    inn = shapely.contains_xy(poly, ours.x, ours.y)
    ring = shapely.contains_xy(poly.buffer(4.0).difference(poly.buffer(1.0)), ours.x, ours.y) & (ours.classification == 2)
    ground = float(np.median(ours.z[ring])) if ring.any() else float("nan")
    h = ours.z[inn] - ground
    rn, nr = ours.return_number[inn], ours.number_of_returns[inn]
    first = rn == 1
    level = float(np.median(h[first & (h > 1.0)])) if np.any(first & (h > 1.0)) else float("nan")
    on_roof = np.abs(h - level) < 0.15
    # the footprint's 0.5 m cells holding a return (the crop's edge cuts one footprint)
    xmin, ymin, xmax, ymax = poly.bounds
    gx, gy = np.meshgrid(np.arange(xmin, xmax, 0.5) + 0.25, np.arange(ymin, ymax, 0.5) + 0.25)
    cells = shapely.contains_xy(poly, gx, gy)
    held = np.zeros_like(cells)
    col = ((ours.x[inn] - xmin) / 0.5).astype(int)
    row = ((ours.y[inn] - ymin) / 0.5).astype(int)
    ok = (row < cells.shape[0]) & (col < cells.shape[1])
    held[row[ok], col[ok]] = True
    return {"area_m2": round(float(poly.area), 2), "returns": int(inn.sum()),
            "share_of_cells_with_returns": round(float((held & cells).sum() / max(int(cells.sum()), 1)), 2),
            "our_classes": {str(int(k)): int(n) for k, n in zip(*np.unique(ours.classification[inn], return_counts=True))},
            "ahn3_classes": {str(int(k)): int(n) for k, n in zip(*np.unique(ahn.classification[inn], return_counts=True))},
            "roof_level_above_ground_m": round(level, 2),
            "roof_level_returns": {"single": int(np.sum(on_roof & (nr == 1))),
                                   "first_of_split_pulse": int(np.sum(on_roof & first & (nr > 1))),
                                   "last_of_split_pulse": int(np.sum(on_roof & (rn == nr) & (nr > 1)))},
            "returns_below_roof_level": int(np.sum(h < level - 0.3)), "returns_above_it": int(np.sum(h > level + 0.3)),
            "centroid_on_map_before": inside_before, "centroid_on_map_with_the_rules": inside_after}


def main() -> int:
    laz = bgt.SHARED / "ahn3_delft" / "ahn3_cropped_1.laz"
    polys = bgt.read_bgt(bgt.SHARED / "ahn3_delft" / "bgt_pand.sqlite")
    ahn = io.read_cloud(laz, crs=bgt.CRS)
    covered = bgt.covered_footprints(laz, polys)
    fparts = bgt.footprint_parts(polys, covered)
    geo = bgt.quarters(float(np.median(ahn.x)), float(np.median(ahn.y)))
    cent = np.array([[p.centroid.x, p.centroid.y] for p in polys])
    with tempfile.TemporaryDirectory(prefix="eval_buildings_bgt_missed_") as tmp:
        tmp = Path(tmp)
        before, after = tmp / "before.laz", tmp / "after.laz"
        tiles.classify_file(laz, before, crs=bgt.CRS, params=dataclasses.replace(ClassifySettings(), crown_covered_roofs=False))
        tiles.classify_file(laz, after, crs=bgt.CRS, params=ClassifySettings())
        layer_before = _layer(before, tmp / "b.gpkg", roof_dropouts=False)
        layer_after = _layer(after, tmp / "a.gpkg", roof_dropouts=True)
        ours = io.read_cloud(after, crs=bgt.CRS)
    on_before = shapely.contains_xy(shapely.union_all(layer_before), cent[:, 0], cent[:, 1])
    on_after = shapely.contains_xy(shapely.union_all(layer_after), cent[:, 0], cent[:, 1])
    missed = np.flatnonzero(covered & ~on_before)
    rows = {}
    for i in missed:
        d = describe(polys[i], ours, ahn, bool(on_before[i]), bool(on_after[i]))
        d["quarter"] = bgt.PARTS[int(geo.index(*cent[i]))]
        d["footprint_part"] = bgt.PARTS[int(fparts.index(*cent[i]))]
        d["centroid_m"] = [round(float(v), 2) for v in cent[i]]
        rows[str(int(i))] = d
        print(f"footprint {i}: {d}")
    plt = pyplot()
    ncol = 3
    fig, axs = plt.subplots(int(np.ceil(len(missed) / ncol)), ncol, figsize=(6 * ncol, 6 * int(np.ceil(len(missed) / ncol))),
                            squeeze=False)
    r = 12.0
    for ax, i in zip(axs.ravel(), missed):
        cx, cy = cent[i]
        sel = (np.abs(ours.x - cx) < r) & (np.abs(ours.y - cy) < r)
        for k, col in COLOURS.items():
            s = sel & (ours.classification == k)
            ax.scatter(ours.x[s] - cx, ours.y[s] - cy, s=6, c=col, lw=0)
        for geoms, style in ((polys, "k-"), (layer_before, "b--"), (layer_after, "m-")):
            for g in geoms:
                if g.distance(shapely.Point(cx, cy)) < 2 * r:
                    for gg in getattr(g, "geoms", [g]):
                        xs, ys = gg.exterior.xy
                        ax.plot(np.asarray(xs) - cx, np.asarray(ys) - cy, style, lw=1.2)
        ax.plot(0, 0, "kx", ms=10)
        d = rows[str(int(i))]
        ax.set_title(f"footprint {i}: {d['area_m2']:.1f} m2, part {d['footprint_part']}\n"
                     f"on the map: before {'yes' if d['centroid_on_map_before'] else 'no'}, "
                     f"with the rules {'yes' if d['centroid_on_map_with_the_rules'] else 'no'}", fontsize=9)
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_aspect("equal")
    for ax in axs.ravel()[len(missed):]:
        ax.set_axis_off()
    png = bgt.REPO / "bench" / "results" / "buildings_bgt_missed.png"
    save_png(fig, png, dpi=70)
    result = {"command": "bench/eval_buildings_bgt_missed.py", "footprints_covered": int(covered.sum()),
              "centroids_on_map_before": int((covered & on_before).sum()),
              "centroids_on_map_with_the_rules": int((covered & on_after).sum()), "missed_before": rows,
              "figure": png.name}
    bgt.store_result(bgt.REPO / "bench" / "results" / "buildings_bgt_missed.json", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
