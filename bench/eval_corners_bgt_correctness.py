"""How many roof corners marked usable as control lie on no surveyed building: AHN3 Delft against the BGT footprints.

    .venv/bin/python bench/eval_corners_bgt_correctness.py [--data ../shared/data/ahn3_delft] [--out results]

``bench/eval_corners_ahn3.py`` asks how many of the BGT's building corners get a usable corner (completeness);
this asks the other way (correctness): of the corners ``lidarctl corners`` marks usable, how many lie on no
footprint. A usable corner off every building is LiDAR control that moves the block adjustment silently.

Inputs: the shared crop classified two ways, AHN3's own classes (the file as given) and ``lidarctl classify``'s
defaults (run here in a temporary folder), corners with the stage's defaults (``--roof flat``) and ``--roof any``.
The BGT maps only the crop's central blocks: a corner is scored only inside its coverage (the footprints' convex
hull and 3 m around every footprint). Each usable corner there is put in one class by its distance to the nearest
footprint boundary (the single footprints, not dissolved; footprints are wall lines, the LiDAR's corners eave
corners 0.2-0.5 m outside them): within 1 m of a boundary; inside a footprint, farther than 1 m from its boundary
(a roof step, a courtyard); outside every footprint by 1-3 m; outside by more than 3 m. The last two are what
the BGT cannot account for: structures it does not map (annexes beyond a back wall, garden sheds) or wrong
corners (edge lines extended to a tip that is cut off on the building, a shrub); their ids are listed with what
AHN3's own classes hold within 1.5 m, to be judged on the pictures. No parameter is chosen here.

Writes bench/results/corners_ahn3_correctness.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import shapely
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_corners_ahn3 import REPO, SHARED, read_footprints  # noqa: E402

from lidarctl.corners.roof_corners import find_roof_corners, read_classified_cloud  # noqa: E402

ON_BOUNDARY_M = 1.0  # a corner this close to a footprint boundary is on the building (eave overhang 0.2-0.5 m)
FAR_M = 3.0
COVERAGE_BUFFER_M = 3.0
NEAR_RETURNS_M = 1.5
AHN3_BUILDING, AHN3_GROUND = 6, 2


CRS = "EPSG:28992"  # the crop's (its file declares none)
DATASET = f"AHN3 Delft crop (ahn3_cropped_1.laz) vs BGT footprints (bgt_pand.sqlite), {CRS}"


def classified_crops(laz: Path, tmp: Path) -> list[tuple[str, Path]]:
    """The shared crop classified two ways, (name, file): AHN3's own classes (the file as given) and ``lidarctl
    classify``'s defaults (written into ``tmp``)."""
    from lidarctl.cli.main import main as lidarctl

    ours = Path(tmp) / "ours.laz"
    lidarctl(["classify", str(laz), str(ours), "--crs", CRS], standalone_mode=False)
    return [("ahn3_classes", laz), ("lidarctl_classify", ours)]


COVERAGE_DEFINITION = f"the footprints' convex hull and {COVERAGE_BUFFER_M:g} m around each"


def bgt_crop_inputs(description: str) -> tuple[argparse.Namespace, Path, list]:
    """The command line of the AHN3-against-BGT benches (``--data`` the shared folder, ``--out`` the results
    folder) and their inputs: (arguments, the AHN3 crop, the BGT footprints)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data", type=Path, default=SHARED / "ahn3_delft")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args()
    return args, args.data / "ahn3_cropped_1.laz", read_footprints(args.data / "bgt_pand.sqlite")


def write_result(out_dir: Path, name: str, result: dict) -> None:
    """``result`` as ``out_dir``/``name`` (JSON, atomically)."""
    from aerotri.core.atomic import write_text_atomic

    out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_dir / name, json.dumps(result, indent=2) + "\n")


def coverage(polys) -> shapely.Geometry:
    """Where the BGT can judge a corner: the footprints' convex hull and ``COVERAGE_BUFFER_M`` around each."""
    many = shapely.MultiPolygon(polys)
    return shapely.union(shapely.convex_hull(many), many.buffer(COVERAGE_BUFFER_M))


def score_usable(corners: list[dict], polys, ahn3) -> dict:
    """The usable corners in the BGT's coverage by their distance to the nearest footprint boundary (module text)."""
    boundaries = shapely.MultiLineString([np.asarray(r.coords) for p in polys for r in [p.exterior, *p.interiors]])
    union = shapely.union_all(polys)
    area = coverage(polys)
    tree = cKDTree(np.column_stack([ahn3.x, ahn3.y]))
    use = [c for c in corners if c["usable"]]
    pts = shapely.points(np.array([[c["x"], c["y"]] for c in use]).reshape(-1, 2))
    inside_area = shapely.contains(area, pts)
    d_edge = shapely.distance(boundaries, pts)
    inside = shapely.contains(union, pts)
    counts = {"on_a_footprint_boundary": 0, "inside_a_footprint_beyond_1m": 0, "outside_1_to_3m": 0,
              "outside_beyond_3m": 0}
    off = []
    for c, ok, d, within in zip(use, inside_area, d_edge, inside):
        if not ok:
            continue
        if d <= ON_BOUNDARY_M:
            counts["on_a_footprint_boundary"] += 1
            continue
        if within:
            counts["inside_a_footprint_beyond_1m"] += 1
            continue
        counts["outside_1_to_3m" if d <= FAR_M else "outside_beyond_3m"] += 1
        near = np.asarray(tree.query_ball_point([c["x"], c["y"]], NEAR_RETURNS_M), np.int64)
        cls = ahn3.classification[near]
        off.append({"id": c["id"], "x": round(c["x"], 2), "y": round(c["y"], 2), "z": round(c["z"], 2),
                    "distance_to_footprint_m": round(float(d), 2), "angle_deg": round(c["angle_deg"], 1),
                    "sxy_m": round(float(np.hypot(c["sx_m"], c["sy_m"]) / np.sqrt(2)), 3),
                    "ahn3_returns_within_1_5m": int(len(near)),
                    "ahn3_building_share": round(float(np.mean(cls == AHN3_BUILDING)) if len(near) else 0.0, 3),
                    "ahn3_ground_share": round(float(np.mean(cls == AHN3_GROUND)) if len(near) else 0.0, 3)})
    n = sum(counts.values())
    outside = counts["outside_1_to_3m"] + counts["outside_beyond_3m"]
    sxy = [np.hypot(c["sx_m"], c["sy_m"]) / np.sqrt(2) for c in use]
    return {"usable": len(use), "usable_in_bgt_coverage": n, **counts,
            "outside_every_footprint_pct": round(100.0 * outside / n, 1) if n else None,
            "median_sxy_usable_m": round(float(np.median(sxy)), 3) if sxy else None,
            "outside_corners": off}


def main() -> int:
    args, laz, polys = bgt_crop_inputs(__doc__.splitlines()[0])
    ahn3 = read_classified_cloud(laz, crs=CRS)
    result = {"dataset": DATASET,
              "definitions": {"coverage": COVERAGE_DEFINITION,
                              "on_a_footprint_boundary": f"within {ON_BOUNDARY_M:g} m of a single footprint's ring",
                              "outside": f"outside every footprint, 1-{FAR_M:g} m or beyond {FAR_M:g} m"},
              "n_footprints": len(polys)}
    with tempfile.TemporaryDirectory(prefix="corners_bgt_") as tmp:
        for name, path in classified_crops(laz, Path(tmp)):
            cloud = ahn3 if path == laz else read_classified_cloud(path)
            for roof in ("flat", "any"):
                res = find_roof_corners(cloud.x, cloud.y, cloud.z, cloud.classification, cloud.point_source_id,
                                        roof=roof)
                key = f"{name}_roof_{roof}"
                result[key] = score_usable(res.corners, polys, ahn3)
                r = result[key]
                print(f"{key}: {r['usable']} usable, {r['usable_in_bgt_coverage']} in the BGT's coverage: "
                      f"{r['on_a_footprint_boundary']} on a footprint boundary, {r['inside_a_footprint_beyond_1m']} "
                      f"inside beyond 1 m, {r['outside_1_to_3m']} outside by 1-3 m, {r['outside_beyond_3m']} beyond "
                      f"3 m ({r['outside_every_footprint_pct']} % outside every footprint)")
    write_result(args.out, "corners_ahn3_correctness.json", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
