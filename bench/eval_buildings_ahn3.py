"""Buildings of our LiDAR-only classification on the AHN3 Delft crop against the 160 surveyed BGT footprints,
per building and per area, as seed 002 reports them (``lidarctl evaluate --reference``).

    .venv/bin/python bench/eval_buildings_ahn3.py [--out results]

Steps: ``lidarctl classify`` (library: ``tiles.classify_file``, shipped defaults, EPSG:28992) of
ahn3_cropped_1.laz into a temporary folder; the BGT table written as a GeoPackage there (the shared
data stay untouched); ``map_accuracy.evaluate_map`` with every polygon a building, cells of 0.5 m,
50 % overlap, buildings of at least 10 m2. The BGT covers two street blocks of the crop only, so the
scores are taken inside the convex hulls of the footprint blocks (footprints less than 1 m apart;
``--within hull``: 27 blocks), where the BGT maps every building; outside them a building of the
crop has no footprint. Type II (per cent of the non-building area) depends on how much non-building
area that scored area holds (here little: yards and passages next to the houses); completeness and
correctness by area do not.

Nothing is tuned here (the classifier's defaults were chosen on other data: ISPRS, the simulator);
the west and east halves (split at the median x of the footprints) are scored separately as well as
together, to show the spread. For context the
same scores of the AHN3 production classes (class 6) that come with the file.

Measures (``lidarctl.checks.map_accuracy``): per area type I (footprint area not labelled building), type II
(other area labelled building), overall, kappa, completeness/correctness by area; per building
completeness (footprints >= 50 % covered) and correctness (connected building regions >= 50 % on
footprints). BGT footprints are wall lines, LiDAR roofs include eaves: an overhang of a few
decimetres around every roof is type II by construction (a 0.3 m eave on a 10 x 10 m house is 12 %
of its area).

Outline plan accuracy: the vertices of our regularised roof outlines (``lidarctl.corners.roof_corners`` over
``lidarctl.corners.roof_outline``) inside the scored blocks against the outer boundaries of the BGT footprint
blocks: signed distance (positive: outside the footprint, the eave), RMS, mean and RMS about the
mean of the vertices within 2 m (``outline_plan_offsets``).

Writes bench/results/buildings_ahn3.json and bench/results/buildings_ahn3.png (agreement map: found, missed,
false building cells, footprints outlined).
"""

from __future__ import annotations

import argparse
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
from pyogrio.raw import write as write_vector

from lidarctl.classify import class_grid as cg
from lidarctl.corners.roof_corners import find_roof_corners, read_classified_cloud
from lidarctl.checks import map_accuracy as ma
from lidarctl import tiles
from lidarctl.classify.pipeline import ClassifySettings

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
CRS = "EPSG:28992"
MATCH_M = 2.0   # an outline vertex farther than this from every footprint block boundary is not compared


def write_bgt_gpkg(sqlite_path: Path, out: Path) -> list:
    """The BGT footprints (plain WKB in a SpatiaLite-style table) as a GeoPackage layer; returns them."""
    con = sqlite3.connect(f"file:{sqlite_path}?mode=ro", uri=True)
    rows = con.execute("SELECT GEOMETRY FROM buildingpart").fetchall()
    con.close()
    polys = [shapely.wkb.loads(bytes(b)) for (b,) in rows]
    wkb = np.array([shapely.to_wkb(p) for p in polys], dtype=object)
    write_vector(out, wkb, [], [], geometry_type="Polygon", crs=CRS, driver="GPKG")
    return polys


def write_area(geoms: list, out: Path) -> None:
    wkb = np.array([shapely.to_wkb(g) for g in geoms], dtype=object)
    write_vector(out, wkb, [], [], geometry_type="Polygon", crs=CRS, driver="GPKG")


def score(pred: Path, ref: Path, within: str) -> dict:
    params = ma.MapEvalSettings(res_m=0.5, min_overlap=0.5, min_building_m2=10.0, reference_class="building",
                                crs=CRS, within=within)
    r = ma.evaluate_map(pred, ref, params)
    print(ma.format_map_report(r), "\n")
    return json.loads(r.to_json())


def outline_plan_offsets(classified: Path, polys: list, hulls: list) -> dict:
    """Plan offsets of our regularised roof outlines (``lidarctl.corners.roof_corners``, the roof_outline fit) from the BGT:
    for every outline vertex inside the scored blocks, its distance to the nearest outer boundary of the
    footprint blocks (footprints sharing walls joined: a roof shows no party wall), signed positive outside
    the footprints (eave overhang). Vertices within MATCH_M count; RMS, mean (the systematic overhang)
    and the RMS about the mean."""
    cloud = read_classified_cloud(classified, crs=CRS)
    res = find_roof_corners(cloud.x, cloud.y, cloud.z, cloud.classification, cloud.point_source_id,
                            roof="any")
    union = shapely.union_all([p.buffer(0) for p in polys])
    union = union.buffer(0.05, join_style="mitre").buffer(-0.05, join_style="mitre")
    boundary = union.boundary
    area = shapely.union_all(hulls).buffer(MATCH_M)
    xy = np.concatenate([ring for o in res.outlines for ring in o["rings"] if len(ring)])
    pts = shapely.points(xy)
    keep = shapely.contains(area, pts)
    d = shapely.distance(boundary, pts[keep])
    sign = np.where(shapely.contains(union, pts[keep]), -1.0, 1.0)
    near = d <= MATCH_M
    sd = (sign * d)[near]
    out = {"n_outline_vertices_in_blocks": int(keep.sum()), "n_within_match": int(near.sum()), "match_m": MATCH_M,
           "n_roof_outlines": len(res.outlines)}
    if len(sd):
        out.update(rms_m=float(np.sqrt(np.mean(sd ** 2))), mean_signed_m=float(np.mean(sd)),
                   rms_about_mean_m=float(np.std(sd)), median_abs_m=float(np.median(np.abs(sd))),
                   p90_abs_m=float(np.percentile(np.abs(sd), 90)))
    return out


def picture(pred: Path, ref: Path, hulls: list, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    grid, _ = cg.cloud_grid(pred, 0.5, CRS)
    cls = cg.cloud_classes(pred, grid)
    polys = cg.read_class_polygons(ref, all_class="building")
    refc, _ = cg.rasterize_polygons(polys, grid)
    inside = cg.rasterize_mask(hulls, grid) & (cls != cg.IGNORE)
    p, r = cls == 6, refc == 6
    code = np.zeros(grid.shape, np.uint8)           # 0 outside the scored area
    code[inside] = 1                                 # other, agreed
    code[inside & p & r] = 2                         # building found
    code[inside & ~p & r] = 3                        # missed (type I)
    code[inside & p & ~r] = 4                        # false building (type II)
    code[~inside & p] = 5                            # building outside the BGT's blocks (not scored)
    cmap = ListedColormap(["white", "0.85", "tab:green", "tab:red", "tab:blue", "0.6"])
    t = grid.transform
    extent = (t.c, t.c + t.a * grid.shape[1], t.f + t.e * grid.shape[0], t.f)
    fig, ax = plt.subplots(figsize=(9, 10))
    ax.imshow(code, cmap=cmap, vmin=-0.5, vmax=5.5, extent=extent, interpolation="nearest")
    for g in polys.geometries:
        for part in getattr(g, "geoms", [g]):
            xs, ys = part.exterior.xy
            ax.plot(xs, ys, color="k", lw=0.4)
    for h in hulls:
        xs, ys = h.exterior.xy
        ax.plot(xs, ys, color="k", lw=1.0, ls="--")
    ax.legend(handles=[Patch(color=c, label=lab) for c, lab in [
        ("tab:green", "building, found"), ("tab:red", "footprint missed (type I)"),
        ("tab:blue", "building on no footprint (type II)"), ("0.85", "other, agreed"),
        ("0.6", "building outside the scored blocks")]], loc="lower left", fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("E (m, EPSG:28992)")
    ax.set_ylabel("N (m)")
    # 50 m scale bar
    x0, y0 = extent[1] - 70, extent[2] + 10
    ax.plot([x0, x0 + 50], [y0, y0], color="k", lw=3)
    ax.text(x0 + 25, y0 + 3, "50 m", ha="center")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=SHARED / "ahn3_delft")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    laz = args.data / "ahn3_cropped_1.laz"
    if not laz.is_file():
        print(f"no {laz}: set AEROTRI_SHARED_DATA", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="eval_buildings_ahn3_") as tmp:
        tmp = Path(tmp)
        bgt = tmp / "bgt.gpkg"
        polys = write_bgt_gpkg(args.data / "bgt_pand.sqlite", bgt)
        classified = tmp / "classified.laz"
        t0 = time.perf_counter()
        stats = tiles.classify_file(laz, classified, crs=CRS, params=ClassifySettings())
        classify_s = time.perf_counter() - t0
        hulls = cg.block_hulls(cg.read_class_polygons(bgt, all_class="building"))
        # Hold-out-style spread: west and east halves, split at the median x of the footprint centroids
        # (as bench/eval_corners_ahn3.py does); a block belongs to the half its hull's centroid lies in.
        x_split = float(np.median([p.centroid.x for p in polys]))
        block_files = []
        for name, keep in (("west_half", lambda h: h.centroid.x < x_split), ("east_half", lambda h: h.centroid.x >= x_split)):
            f = tmp / f"{name}.gpkg"
            write_area([h for h in hulls if keep(h)], f)
            block_files.append((name, f))
        result = {
            "data": str(laz), "reference": str(args.data / "bgt_pand.sqlite"), "n_footprints": len(polys),
            "cell_m": 0.5, "min_overlap": 0.5, "min_building_m2": 10.0,
            "scored_area": "convex hulls of the BGT footprint blocks (--within hull)",
            "classify_seconds": classify_s, "n_points": stats.n_points,
            "command": "lidarctl classify ahn3_cropped_1.laz classified.laz --crs EPSG:28992; lidarctl evaluate "
                       "classified.laz --reference bgt.gpkg --reference-class building --crs EPSG:28992 --within hull",
            "x_split_m": x_split, "n_blocks": len(hulls),
            "lidar_only": {"all_blocks": score(classified, bgt, "hull")},
            "ahn3_production_classes": {"all_blocks": score(laz, bgt, "hull")},
        }
        for name, f in block_files:
            result["lidar_only"][name] = score(classified, bgt, str(f))
            result["ahn3_production_classes"][name] = score(laz, bgt, str(f))
        result["outline_plan_offsets"] = outline_plan_offsets(classified, polys, hulls)
        print("outline plan offsets:", result["outline_plan_offsets"])
        b = result["lidar_only"]["all_blocks"]["buildings"]
        picture(classified, bgt, hulls, args.out / "buildings_ahn3.png",
                f"AHN3 Delft, lidarctl classify (LiDAR only) vs {len(polys)} BGT footprints, 0.5 m cells: "
                f"type I {b['type_i_error_pct']:.1f} %, type II {b['type_ii_error_pct']:.1f} %, overall "
                f"{b['overall_accuracy_pct']:.1f} %\ncompleteness {b['n_found']}/{b['n_reference']}, correctness "
                f"{b['n_correct']}/{b['n_detected']} (>= 50 % overlap, >= 10 m2)")
    (args.out / "buildings_ahn3.json").write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out / 'buildings_ahn3.json'} and buildings_ahn3.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
