"""The roof outlines the chain now takes as the true ortho's building footprints (``lidar_out/roof_outlines.gpkg`` of
``lidarctl corners``, issue 42) against a real cadastre: AHN3 Delft against the BGT footprints.

    .venv/bin/python bench/eval_roof_outlines_bgt.py [--data ../shared/data/ahn3_delft] [--out results]

The shared crop classified two ways, AHN3's own classes (the file as given) and ``lidarctl classify``'s defaults (run
here in a temporary folder); ``corner_control`` with the stage's defaults writes roof_outlines.gpkg, read back as
``ortho rectify --footprints`` reads it (``ortho.footprints.read_footprints``). Scored inside the BGT's coverage (the
footprints' convex hull and 3 m around each, as ``eval_corners_bgt_correctness.coverage``; the BGT maps only the
crop's central blocks), areas of the unions:

- completeness: the share of the BGT's footprint area the outlines cover; footprints found: at least half covered;
- correctness: the share of the outlines' area on a BGT footprint; the rest split by its distance from every
  footprint: within 1 m (an eave beyond the wall line: BGT footprints are walls at the ground, the LiDAR's outlines
  eaves) or beyond (structures the BGT does not map, or wrong outlines);
- the outlines' vertices' distance to the nearest BGT footprint boundary (median, 90th percentile; vertices within
  3 m of one), and signed (beyond every footprint +, inside one -: how far the walls stand inside the outlines);
- the BGT's building area no outline covers, and how much of it lies within the footprints' overhang reach (1.5 m)
  of an outline: there the true ortho's occlusion test takes a building without an outline for its neighbour's
  eave.

No parameter is chosen. Writes bench/results/roof_outlines_bgt.json.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_corners_bgt_correctness import (COVERAGE_DEFINITION, CRS, DATASET, bgt_crop_inputs,  # noqa: E402
                                          classified_crops, coverage, write_result)

from ortho.footprints import OVERHANG_REACH_M  # noqa: E402

EAVE_BAND_M = 1.0
NEAR_BOUNDARY_M = 3.0


def score_outlines(outlines, polys) -> dict:
    """Completeness and correctness of the outlines' area against the footprints ``polys`` in their coverage."""
    area = coverage(polys)
    bgt = shapely.union_all(polys)
    ours = shapely.intersection(shapely.union_all(outlines), area)
    on = shapely.intersection(ours, bgt).area
    beyond = ours.difference(bgt)
    eave = shapely.intersection(beyond, bgt.buffer(EAVE_BAND_M)).area
    # the BGT's building area no outline covers that lies within the footprints' overhang reach of an outline: there
    # the occlusion test takes a building the LiDAR traced no outline for as that outline's eave (a slab, then
    # nothing beyond the eave width), where ghosts can come through
    missed = shapely.intersection(bgt, area).difference(ours)
    reach = shapely.intersection(missed, shapely.union_all(outlines).buffer(OVERHANG_REACH_M)).area
    covered = [shapely.intersection(p, ours).area / p.area for p in polys]
    boundaries = shapely.MultiLineString([np.asarray(r.coords) for p in polys for r in [p.exterior, *p.interiors]])
    inside = [g for g in outlines if shapely.intersects(g, area)]
    xy = shapely.get_coordinates(shapely.extract_unique_points(np.asarray(inside, object))) if inside \
        else np.zeros((0, 2))  # each vertex once (a ring's closing vertex repeats its first)
    d = shapely.distance(boundaries, shapely.points(xy))
    # signed: + beyond every footprint (an eave outside the wall line), - inside one
    signed = np.where(shapely.contains_xy(bgt, xy[:, 0], xy[:, 1]), -d, d)[d <= NEAR_BOUNDARY_M] if len(xy) else d
    d = d[d <= NEAR_BOUNDARY_M]
    return {
        "outlines_in_coverage": len(inside),
        "bgt_area_m2": round(bgt.area, 1), "outline_area_m2": round(ours.area, 1),
        "completeness_pct": round(100.0 * on / bgt.area, 2),
        "correctness_pct": round(100.0 * on / ours.area, 2) if ours.area else None,
        "beyond_bgt_within_1m_m2": round(eave, 1), "beyond_bgt_farther_m2": round(beyond.area - eave, 1),
        "bgt_area_without_outline_m2": round(missed.area, 1),
        "of_it_within_the_overhang_reach_of_an_outline_m2": round(reach, 1),
        "footprints_found": int(sum(c >= 0.5 for c in covered)), "footprints": len(polys),
        "vertex_to_bgt_boundary_m_median": round(float(np.median(d)), 3) if len(d) else None,
        "vertex_to_bgt_boundary_m_p90": round(float(np.percentile(d, 90)), 3) if len(d) else None,
        "vertices_within_3m": int(len(d)),
        # how far the outlines stand outside the BGT's walls (the walls' inset beneath the LiDAR's eave outline)
        "vertex_beyond_bgt_wall_m_median": round(float(np.median(signed)), 3) if len(signed) else None,
        "vertex_beyond_bgt_wall_m_quartiles": [round(float(q), 3) for q in np.percentile(signed, [25, 75])]
        if len(signed) else None,
        "vertices_beyond_bgt_share": round(float(np.mean(signed > 0)), 3) if len(signed) else None,
    }


def main() -> int:
    args, laz, polys = bgt_crop_inputs(__doc__.splitlines()[0])
    import pyproj

    from lidarctl.corners.roof_corners import CornerSettings, corner_control
    from ortho.footprints import read_footprints as read_outlines

    result = {"dataset": DATASET,
              "definitions": {"coverage": COVERAGE_DEFINITION,
                              "found": "a footprint at least half covered by the outlines",
                              "eave band": f"outline area beyond every footprint within {EAVE_BAND_M:g} m of one"}}
    with tempfile.TemporaryDirectory(prefix="outlines_bgt_") as tmp:
        for name, path in classified_crops(laz, Path(tmp)):
            out = Path(tmp) / name
            corner_control([path], out, CornerSettings(figure=False), crs=CRS)
            outlines = read_outlines(out / "roof_outlines.gpkg", pyproj.CRS(CRS))
            r = result[name] = score_outlines(list(outlines), polys)
            print(f"{name}: {r['outlines_in_coverage']} outlines in the BGT's coverage; completeness "
                  f"{r['completeness_pct']} %, correctness {r['correctness_pct']} % (beyond the BGT: "
                  f"{r['beyond_bgt_within_1m_m2']} m2 within 1 m, {r['beyond_bgt_farther_m2']} m2 farther); "
                  f"{r['footprints_found']} of {r['footprints']} footprints found; vertices to the BGT's walls "
                  f"median {r['vertex_to_bgt_boundary_m_median']} m, 90 % {r['vertex_to_bgt_boundary_m_p90']} m; "
                  f"building area without an outline {r['bgt_area_without_outline_m2']} m2, "
                  f"{r['of_it_within_the_overhang_reach_of_an_outline_m2']} m2 of it within "
                  f"{OVERHANG_REACH_M:g} m of one")
    write_result(args.out, "roof_outlines_bgt.json", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
