"""Roof corners on the AHN3 Delft crop against the surveyed BGT building footprints.

    .venv/bin/python bench/eval_corners_ahn3.py [--data ../shared/data/ahn3_delft] [--out results]

Writes results/corners_ahn3.json and results/corners_ahn3.png (outlines, corners and footprints over
the nDSM) and the corner files themselves under out/corners_ahn3/.

Matching: every reported corner to the nearest BGT footprint vertex within 2 m. BGT footprints are
wall lines at ground level (and split terraced blocks into houses), LiDAR roof outlines are eave lines,
so the offsets contain the eave overhang (typically 0.2-0.6 m, outward) besides the corner error; the
signed offset along the outward bisector of the corner is reported to show that.
Only corners within 3 m of a footprint are compared (the LiDAR crop is larger than the footprint set).
Completeness is counted over "outline vertices" of the footprints: vertices on the outer boundary of
the union of all footprints (not party walls inside a block) with edges of at least min_edge_m on both
sides and a near-right interior angle - the vertices a roof-outline corner can correspond to.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import time
from pathlib import Path

import numpy as np
import shapely
import shapely.wkb
from scipy.spatial import cKDTree

from lidarctl.corners import find_roof_corners, plot_corners, read_classified_cloud, simple_ndsm, write_corner_files

REPO = Path(__file__).resolve().parents[1]
MATCH_M = 2.0


def read_footprints(path: Path) -> list:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    rows = con.execute("SELECT GEOMETRY FROM buildingpart").fetchall()
    con.close()
    polys = []
    for (blob,) in rows:
        g = shapely.wkb.loads(bytes(blob))
        polys.extend(list(g.geoms) if g.geom_type == "MultiPolygon" else [g])
    return polys


def outline_vertices(polys, min_edge_m: float, max_angle_dev_deg: float = 15.0) -> np.ndarray:
    """Vertices of the outer boundary of the union of footprints that can be roof-outline corners."""
    # a 5 cm closing joins footprints that share a wall
    union = shapely.union_all([p.buffer(0) for p in polys])
    union = union.buffer(0.05, join_style="mitre").buffer(-0.05, join_style="mitre")
    geoms = list(union.geoms) if union.geom_type == "MultiPolygon" else [union]
    out = []
    for g in geoms:
        g = g.simplify(0.1)
        for ring in [g.exterior, *g.interiors]:
            pts = np.asarray(ring.coords)[:-1]
            n = len(pts)
            for k in range(n):
                a, p, c = pts[k - 1], pts[k], pts[(k + 1) % n]
                e1, e2 = a - p, c - p
                l1, l2 = np.hypot(*e1), np.hypot(*e2)
                ang = np.degrees(np.arccos(np.clip(e1 @ e2 / (l1 * l2), -1, 1)))
                if min(l1, l2) >= min_edge_m and abs(ang - 90.0) <= max_angle_dev_deg:
                    out.append(p)
    return np.array(out).reshape(-1, 2)


def offset_stats(d: np.ndarray) -> dict:
    if len(d) == 0:
        return {"n": 0}
    return {
        "n": int(len(d)),
        "median_m": float(np.median(d)),
        "rms_m": float(np.sqrt(np.mean(d**2))),
        "mean_m": float(np.mean(d)),
        "p25_m": float(np.percentile(d, 25)),
        "p75_m": float(np.percentile(d, 75)),
        "p90_m": float(np.percentile(d, 90)),
        "max_m": float(np.max(d)),
        "histogram_m": {
            "edges_m": [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0],
            "counts": np.histogram(d, bins=[0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0])[0].tolist(),
        },
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "ahn3_delft")
    ap.add_argument("--out", type=Path, default=REPO / "results")
    ap.add_argument("--min-edge-m", type=float, default=5.0)
    args = ap.parse_args()

    import pyproj

    cloud = read_classified_cloud(args.data / "ahn3_cropped_1.laz")
    crs = pyproj.CRS.from_epsg(28992)  # the file has no CRS record (README): RD New
    t0 = time.perf_counter()
    res = find_roof_corners(cloud["x"], cloud["y"], cloud["z"], cloud["classification"], cloud["point_source_id"],
                            min_edge_m=args.min_edge_m, roof="any")
    runtime = time.perf_counter() - t0
    write_corner_files(REPO / "out" / "corners_ahn3", res, crs=crs, source=str(args.data / "ahn3_cropped_1.laz"))

    polys = read_footprints(args.data / "bgt_pand.sqlite")
    all_vertices = np.concatenate([np.asarray(r.coords)[:-1] for p in polys for r in [p.exterior, *p.interiors]])
    ref = outline_vertices(polys, args.min_edge_m)
    # Only footprints inside the LiDAR coverage count for completeness.
    xy = np.column_stack([cloud["x"], cloud["y"]])
    cover_tree = cKDTree(xy[::10])
    covered = cover_tree.query(ref, distance_upper_bound=3.0)[0] < 3.0
    ref = ref[covered]

    # Only corners where BGT has footprints (the crop is larger than the footprint set) are compared.
    fp_union = shapely.union_all(polys)
    in_bgt = [c for c in res["corners"] if shapely.distance(fp_union, shapely.Point(c["x"], c["y"])) < 3.0]
    corners = in_bgt
    cxy = np.array([[c["x"], c["y"]] for c in corners])
    usable = np.array([c["usable"] for c in corners], bool)
    # distance to the nearest footprint wall line (ignores where along the wall the corner lies)
    boundary = shapely.union_all([p.boundary for p in polys])
    d_wall = shapely.distance(boundary, shapely.points(cxy))
    tree_all = cKDTree(all_vertices)
    d_all, j_all = tree_all.query(cxy)
    matched = d_all <= MATCH_M
    ref_tree = cKDTree(ref)
    d_ref, _ = cKDTree(cxy).query(ref)
    d_ref_u, _ = cKDTree(cxy[usable]).query(ref) if usable.any() else (np.full(len(ref), np.inf), None)

    # Signed offset along the corner's outward bisector: positive = roof corner outside the footprint
    # vertex (eave overhang). The outward direction: from the roof outline centroid through the corner.
    signed = []
    cent = {o["building_id"]: shapely.Polygon(o["rings"][0]).centroid
            for o in res["outlines"] if len(o["rings"][0]) >= 3}
    for c, d, j in zip(corners, d_all, j_all):
        if d > MATCH_M:
            continue
        g = cent.get(c["building_id"])
        if g is None:
            continue
        out_dir = np.array([c["x"] - g.x, c["y"] - g.y])
        out_dir /= np.linalg.norm(out_dir)
        signed.append(float((np.array([c["x"], c["y"]]) - all_vertices[j]) @ out_dir))
    signed = np.array(signed)

    summary = {
        "dataset": "AHN3 Delft crop (ahn3_cropped_1.laz) vs BGT footprints (bgt_pand.sqlite), EPSG:28992",
        "min_edge_m": args.min_edge_m,
        "match_radius_m": MATCH_M,
        "n_points": res["stats"]["n_points"],
        "point_spacing_m": res["stats"]["point_spacing_m"],
        "n_roof_outlines": res["stats"]["n_outlines"],
        "n_corners": len(res["corners"]),
        "n_usable": int(sum(c["usable"] for c in res["corners"])),
        "n_corners_in_bgt_area": len(corners),
        "n_usable_in_bgt_area": int(usable.sum()),
        "n_footprints": len(polys),
        "n_footprint_outline_vertices": int(len(ref)),
        "completeness_pct": float(100.0 * np.mean(d_ref <= MATCH_M)) if len(ref) else None,
        "completeness_usable_pct": float(100.0 * np.mean(d_ref_u <= MATCH_M)) if len(ref) else None,
        "matched_pct": float(100.0 * matched.mean()) if len(corners) else None,
        "matched_usable_pct": float(100.0 * matched[usable].mean()) if usable.any() else None,
        "offset_all_xy": offset_stats(d_all[matched]),
        "offset_usable_xy": offset_stats(d_all[matched & usable]),
        "distance_to_footprint_wall_all": offset_stats(d_wall[d_wall <= MATCH_M]),
        "signed_outward_offset_median_m": float(np.median(signed)) if len(signed) else None,
        "signed_outward_offset_mean_m": float(np.mean(signed)) if len(signed) else None,
        "fraction_outward_pct": float(100.0 * np.mean(signed > 0)) if len(signed) else None,
        "median_sxy_usable_m": res["stats"]["median_sxy_usable_m"],
        "runtime_s": runtime,
        "points_per_s": res["stats"]["n_points"] / runtime,
        "note": "footprints are wall lines, roof corners are eave corners: the offsets include the eave overhang",
    }
    args.out.mkdir(parents=True, exist_ok=True)
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(args.out / "corners_ahn3.json", json.dumps(summary, indent=2) + "\n")
    xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]])
    ndsm, extent = simple_ndsm(xyz, cloud["classification"], cell_m=0.5)
    plot_corners(
        args.out / "corners_ahn3.png", ndsm, extent, res["outlines"], res["corners"], truth_xy=ref,
        reference_polygons=[np.asarray(p.exterior.coords) for p in polys],
        title=(f"AHN3 Delft: {len(res['corners'])} corners, cyan = BGT footprints, + = footprint outline vertices; "
               f"median offset {summary['offset_all_xy'].get('median_m', float('nan')):.2f} m"),
    )
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
