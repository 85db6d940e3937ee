"""Roof corners on the AHN3 Delft crop against the surveyed BGT building footprints.

    .venv/bin/python bench/eval_corners_ahn3.py [--data ../shared/data/ahn3_delft] [--out results]
    .venv/bin/python bench/eval_corners_ahn3.py --laz PATH/ahn3_cropped_2.laz --name crop2

Writes bench/results/corners_ahn3.json, bench/results/corners_ahn3.png (outlines, corners and footprints over
the nDSM), bench/results/corners_ahn3_misses.png (zoomed on the reference vertices with an outline but no corner:
``outline_but_no_corner_detail`` says what the tracing did there) and the corner files themselves under out/corners_ahn3/.

Unseen crop (``--laz PATH --name NAME``): another crop of the same survey that no parameter was ever
chosen on, e.g. ``ahn3_cropped_2.laz`` (tudelft3d/3dfier example_data/ahn3, GPL-3, directly east of
the shared crop; not in ../shared/data, so no test needs it). The same extraction and scoring against
the BGT footprint vertices inside that crop; its figures go into bench/results/corners_ahn3.json under
``unseen_NAME`` (the shared crop's stay as they are; a rerun of the shared crop keeps them) and the
picture into bench/results/corners_ahn3_NAME.png. ``whole_crop_by_reference_set`` sums up each crop with
exact 95 % intervals of the completeness: the reference sets hold a few dozen vertices (crop 2: six
with both edges >= 5 m), so one vertex moves a completeness by 4-17 points.

Reference vertices (issue 21: "footprint vertices of buildings larger than 10 x 10 m"): the BGT splits a
terraced block into houses ("pand" parcels), so a building is a block of footprints sharing walls (their
union, 5 cm closing): party walls between houses are no roof corners a LiDAR can see. Buildings whose
minimum rotated rectangle is at least 10 x 10 m count; of their outer boundary (after a 0.1 m
simplification), inside the LiDAR crop (2 m from its edge) and within 1 m of a LiDAR point:
  ``block_corners`` (the headline since issue 21's review): vertices where the block outline turns by at
  least ``REF_MIN_TURN_DEG`` (30 deg) between two edges of at least ``REF_MIN_EDGE_M`` (3 m) - a real corner
  of the building; shorter BGT edges are porches, bay windows, chimney breasts and the 0.2-1 m jogs between
  the fronts of neighbouring houses, which lie under the eave or are no eave corner (``REFERENCE_DEFINITIONS``
  in the JSON says why, and ``block_corners_edges_ge_2m`` / ``_5m`` show how the figure depends on 3 m);
  ``all``: every vertex turning by at least 10 deg (the issue's literal reading: 421 vertices, half of them
  at edges shorter than 1 m);
  ``edges_ge_min_edge``: both edges at least 5 m (the headline before issue 21's review: 29 vertices);
  ``legacy``: the earliest set (any block size, right angles within 15 deg, edges >= 5 m).
The headline runs the stage's defaults (``min_edge_m`` density-adaptive: max(2 m, 8 point spacings), the
resolved value in the JSON); ``min_edge_sensitivity`` reruns with a fixed 3 m (the reference's edge length,
the earlier bench setting) and 5 m (the stage's fixed default before). ``--min-edge-m`` fixes it.
Completeness: a reference vertex with a (usable) corner within 2 m. Offsets: corner minus BGT vertex
for those matches; BGT footprints are wall lines at ground level, LiDAR roof outlines are eave lines,
so the offset is split along the corner's two roof edges: the component along each edge's outward
normal is the overhang (positive: eave outside the wall), the component along the edge the along-edge
offset. (At a right-angled corner the along-edge offset of one edge is the normal offset of the other:
a uniform overhang o moves the corner by o along both normals, o sqrt(2) in all.)
``why_not_usable``: for each headline reference vertex, the first reason it has no usable corner.

Hold-out: the crop is split at the x median of the ``all`` reference vertices into a west and an east
half; numbers are reported for the whole crop and each half (corners belong to the half their
reference vertex lies in). No parameter of the detector is tuned on this crop (the occlusion view
angle is a property of the frame block, see lidarctl.corners.roof_corners); the halves show the spread.
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import time
from pathlib import Path

import numpy as np
import shapely
import shapely.wkb
from scipy.spatial import cKDTree

from lidarctl.corners.roof_corners import find_roof_corners, plot_corners, read_classified_cloud, simple_ndsm, write_corner_files

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
MATCH_M = 2.0
MIN_BUILDING_M = 10.0  # buildings of at least 10 x 10 m (minimum rotated rectangle)
SIMPLIFY_M = 0.1
EDGE_OF_CROP_M = 2.0
MIN_TURN_DEG = 10.0  # a vertex where the outline turns by less is not a corner (sets all, legacy)
REF_MIN_TURN_DEG = 30.0  # block_corners: a corner of the building, not a bend of the digitised wall
REF_MIN_EDGE_M = 3.0  # block_corners: both edges at the vertex at least this long
LEGACY_MIN_EDGE_M = 5.0  # edges_ge_min_edge, legacy: the stage's default min_edge_m
REFERENCE_DEFINITIONS = {
    "block_corners": (
        "Vertices of the dissolved block outline (union of touching BGT footprints, 5 cm closing: the party walls "
        "between the houses of a terrace are no roof corners), blocks whose minimum rotated rectangle is >= 10 m "
        "on both sides, where the outline turns by >= 30 deg between two edges >= 3 m. Why: BGT edges shorter "
        "than 3 m are porches, bay windows, chimney breasts and the 0.2-1 m jogs between the fronts of "
        "neighbouring houses; they lie under the eave overhang (0.2-0.5 m) or belong to no roof edge, and 3 m is "
        "10 point spacings of AHN3 (0.3 m), about what a fitted edge line needs beyond the rounded corners of "
        "a traced outline. Turns < 30 deg are bends of the digitised wall, not corners. The dependence on 3 m: "
        "block_corners_edges_ge_2m and block_corners_edges_ge_5m."),
    "block_corners_edges_ge_2m": "block_corners with edges >= 2 m (sensitivity)",
    "block_corners_edges_ge_5m": "block_corners with edges >= 5 m (sensitivity)",
    "all": ("every vertex of the dissolved block outlines (blocks >= 10 x 10 m) turning by >= 10 deg: the issue's "
            "literal reading; half of them sit at BGT edges < 1 m (digitising jogs)"),
    "edges_ge_min_edge": "all, with both edges >= 5 m (the headline before issue 21's review: 29 vertices)",
    "legacy": "any block size, both edges >= 5 m, right angles within 15 deg (the earliest set)",
}


def read_footprints(path: Path) -> list:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    rows = con.execute("SELECT GEOMETRY FROM buildingpart").fetchall()
    con.close()
    polys = []
    for (blob,) in rows:
        g = shapely.wkb.loads(bytes(blob))
        polys.extend(list(g.geoms) if g.geom_type == "MultiPolygon" else [g])
    return polys


def footprint_blocks(polys) -> list:
    """Footprints sharing walls joined into blocks (a 5 cm closing)."""
    union = shapely.union_all([p.buffer(0) for p in polys])
    union = union.buffer(0.05, join_style="mitre").buffer(-0.05, join_style="mitre")
    return list(union.geoms) if union.geom_type == "MultiPolygon" else [union]


def _rect_sides_m(g) -> tuple[float, float]:
    xy = np.asarray(g.minimum_rotated_rectangle.exterior.coords)
    a, b = np.hypot(*(xy[1] - xy[0])), np.hypot(*(xy[2] - xy[1]))
    return min(a, b), max(a, b)


def block_vertices(blocks, min_building_m: float = MIN_BUILDING_M):
    """Vertices of the block outlines: (xy (N, 2), shorter adjacent edge (m), interior angle (deg),
    block size ok (>= min_building_m x min_building_m))."""
    xy, short, angle, big = [], [], [], []
    for g in blocks:
        ok = _rect_sides_m(g)[0] >= min_building_m
        g = g.simplify(SIMPLIFY_M)
        for ring in [g.exterior, *g.interiors]:
            pts = np.asarray(ring.coords)[:-1]
            n = len(pts)
            for k in range(n):
                a, p, c = pts[k - 1], pts[k], pts[(k + 1) % n]
                e1, e2 = a - p, c - p
                l1, l2 = np.hypot(*e1), np.hypot(*e2)
                xy.append(p)
                short.append(min(l1, l2))
                angle.append(np.degrees(np.arccos(np.clip(e1 @ e2 / (l1 * l2), -1, 1))))
                big.append(ok)
    return np.array(xy).reshape(-1, 2), np.array(short), np.array(angle), np.array(big, bool)


def offset_stats(d: np.ndarray, histogram: bool = True) -> dict:
    d = np.asarray(d, float)
    if len(d) == 0:
        return {"n": 0}
    out = {
        "n": int(len(d)),
        "median_m": float(np.median(d)),
        "rms_m": float(np.sqrt(np.mean(d**2))),
        "mean_m": float(np.mean(d)),
        "p25_m": float(np.percentile(d, 25)),
        "p75_m": float(np.percentile(d, 75)),
        "p90_m": float(np.percentile(d, 90)),
        "max_m": float(np.max(d)),
    }
    if histogram:
        edges = [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0]
        out["histogram_m"] = {"edges_m": edges, "counts": np.histogram(d, bins=edges)[0].tolist()}
    return out


def corner_edge_frames(corners: list[dict], outlines: list[dict]) -> np.ndarray:
    """(N, 2, 2, 2): per corner and per roof edge (incoming, outgoing) the outward unit normal and the
    unit direction, from the roof outline ring the corner is a vertex of (rings: roof on the left);
    NaN when the corner is not found in its outline."""
    out = np.full((len(corners), 2, 2, 2), np.nan)
    rings = {}
    for o in outlines:
        rings.setdefault(o["building_id"], []).extend(np.asarray(r, float) for r in o["rings"] if len(r) >= 3)
    for i, c in enumerate(corners):
        p = np.array([c["x"], c["y"]])
        for r in rings.get(c["building_id"], []):
            k = np.flatnonzero(np.hypot(*(r - p).T) < 1e-6)
            if not len(k):
                continue
            k = int(k[0])
            for j, (a, b) in enumerate(((r[k - 1], r[k]), (r[k], r[(k + 1) % len(r)]))):
                t = (b - a) / np.hypot(*(b - a))
                out[i, j] = [[t[1], -t[0]], t]  # outward normal: the roof lies on the left
            break
    return out


def match_scores(ref: np.ndarray, corners: list[dict], frames: np.ndarray, usable_only: bool) -> dict:
    """Completeness of the reference vertices ``ref`` and the offsets of their matched corners."""
    if not len(ref):
        return {"n_reference_vertices": 0}
    sel = np.array([bool(c["usable"]) or not usable_only for c in corners], bool)
    cxy = np.array([[c["x"], c["y"]] for c in corners]).reshape(-1, 2)[sel]
    if not len(cxy):
        return {"n_reference_vertices": int(len(ref)), "completeness_pct": 0.0}
    d, j = cKDTree(cxy).query(ref)
    hit = d <= MATCH_M
    delta = cxy[j[hit]] - ref[hit]
    fr = frames[sel][j[hit]]  # (M, 2 edges, normal/direction, 2)
    normal = np.einsum("mi,meki->mek", delta, fr)[:, :, 0].ravel()
    along = np.einsum("mi,meki->mek", delta, fr)[:, :, 1].ravel()
    ok = np.isfinite(normal)
    return {
        "n_reference_vertices": int(len(ref)),
        "n_matched": int(hit.sum()),
        # BGT vertices a few decimetres apart (jogs) can share one corner: how many corners make the matches
        "n_distinct_corners_matched": int(len(np.unique(j[hit]))),
        "completeness_pct": float(100.0 * hit.mean()),
        "offset_xy": offset_stats(d[hit], histogram=False),
        "overhang_normal_signed_median_m": float(np.median(normal[ok])) if ok.any() else None,
        "overhang_normal_abs": offset_stats(np.abs(normal[ok]), histogram=False),
        "outward_pct": float(100.0 * np.mean(normal[ok] > 0)) if ok.any() else None,
        "along_edge_abs": offset_stats(np.abs(along[ok]), histogram=False),
    }


def reference_sets(blocks, xy: np.ndarray) -> tuple[np.ndarray, dict]:
    """Block-outline vertices (N, 2) and the reference sets (name -> mask) inside a crop with points ``xy``."""
    vxy, v_short, v_angle, v_big = block_vertices(blocks)
    # only vertices inside this crop count (2 m from its edge, within 1 m of one of its points)
    lo, hi = xy.min(axis=0) + EDGE_OF_CROP_M, xy.max(axis=0) - EDGE_OF_CROP_M
    in_crop = np.all((vxy >= lo) & (vxy <= hi), axis=1) & (cKDTree(xy).query(vxy, distance_upper_bound=1.0)[0] <= 1.0)
    in_crop &= np.abs(180.0 - v_angle) >= MIN_TURN_DEG
    corner = in_crop & v_big & (np.abs(180.0 - v_angle) >= REF_MIN_TURN_DEG)
    sets = {
        "block_corners": corner & (v_short >= REF_MIN_EDGE_M),
        "block_corners_edges_ge_2m": corner & (v_short >= 2.0),
        "block_corners_edges_ge_5m": corner & (v_short >= 5.0),
        "all": in_crop & v_big,
        "edges_ge_min_edge": in_crop & v_big & (v_short >= LEGACY_MIN_EDGE_M),
        "legacy": in_crop & (v_short >= LEGACY_MIN_EDGE_M) & (np.abs(v_angle - 90.0) <= 15.0),
    }
    return vxy, sets


def score_sets(vxy: np.ndarray, sets: dict, halves: dict, res: dict) -> dict:
    """Completeness and offsets of the corners of ``res`` per reference set and half of the crop."""
    corners = res.corners
    frames = corner_edge_frames(corners, res.outlines)
    scores = {}
    for name, in_set in sets.items():
        scores[name] = {}
        for half, in_half in halves.items():
            ref = vxy[in_set & in_half]
            scores[name][half] = {"any": match_scores(ref, corners, frames, usable_only=False),
                                  "usable": match_scores(ref, corners, frames, usable_only=True)}
        w, e = (scores[name][h]["usable"].get("completeness_pct") for h in ("west", "east"))
        scores[name]["usable_completeness_gap_west_east_pct"] = None if None in (w, e) else float(e - w)
    return scores


def why_not_usable(ref: np.ndarray, res: dict, min_edge_m: float) -> dict:
    """Per reference vertex the first reason it has no usable corner within ``MATCH_M``: no roof outline
    near it, an outline but no reported corner, or the nearest reported corner's failed gate (an edge
    shorter than min_edge_m, an edge ending off the outline, not a right angle, the score and its
    weakest factor)."""
    from collections import Counter

    corners = res.corners
    out = Counter()
    if not len(ref):
        return {}
    cxy = np.array([[c["x"], c["y"]] for c in corners]).reshape(-1, 2)
    use = np.array([bool(c["usable"]) for c in corners], bool)
    d_any, j_any = cKDTree(cxy).query(ref)
    d_use = cKDTree(cxy[use]).query(ref)[0] if use.any() else np.full(len(ref), np.inf)
    rings = [r for o in res.outlines for r in o["rings"] if len(r) >= 3]
    lines = shapely.MultiLineString([np.vstack([r, r[:1]]) for r in rings]) if rings else None
    d_line = shapely.distance(lines, shapely.points(ref)) if lines is not None else np.full(len(ref), np.inf)
    factors = [k for k in corners[0] if k.startswith("score_")] if corners else []
    for k in range(len(ref)):
        if d_use[k] <= MATCH_M:
            out["usable"] += 1
        elif d_any[k] > MATCH_M:
            out["no_outline_within_2m" if d_line[k] > MATCH_M else "outline_but_no_corner"] += 1
        else:
            c = corners[j_any[k]]
            dev = min(abs(c["angle_deg"] - 90.0), abs(c["angle_deg"] - 270.0))
            if min(c["edge1_m"], c["edge2_m"]) < min_edge_m:
                out["edge_shorter_than_min_edge"] += 1
            elif c.get("open_edge"):
                out["edge_ends_off_outline"] += 1
            elif dev > 5.0 and c.get("angle_sigma_deg", np.inf) > 2.5:
                out["not_right_angle_nor_determined_oblique"] += 1
            elif dev > 5.0 and abs(180.0 - c["angle_deg"]) < 30.0:
                out["oblique_turn_below_30deg"] += 1
            else:
                out["score_below_usable:weakest_" + min(factors, key=lambda f: c[f])[6:]] += 1
    return dict(sorted(out.items()))


def outline_but_no_corner(ref: np.ndarray, res: dict, res_short: dict, min_edge_m: float) -> dict:
    """The reference vertices with a roof outline within ``MATCH_M`` but no reported corner, split by what the
    tracing did there, from a second run with min_edge_m 0.5 m (``res_short``, every traced corner that
    passes the sigma gate): a traced corner with an edge shorter than ``min_edge_m`` (the LiDAR edge is
    shorter than the BGT wall: a setback, a porch), or no outline vertex near the vertex at all (the
    regularised outline runs past it: a lower annex merged into the roof, an annex not in the building
    class, a rounded or chamfered corner) - or a traced corner dropped by the sigma gate. With the vertices
    (x, y) for the zoomed figure."""
    corners = res.corners
    cxy = np.array([[c["x"], c["y"]] for c in corners]).reshape(-1, 2)
    d_any = cKDTree(cxy).query(ref)[0] if len(cxy) else np.full(len(ref), np.inf)
    rings = [r for o in res.outlines for r in o["rings"] if len(r) >= 3]
    lines = shapely.MultiLineString([np.vstack([r, r[:1]]) for r in rings]) if rings else None
    d_line = shapely.distance(lines, shapely.points(ref)) if lines is not None else np.full(len(ref), np.inf)
    miss = np.flatnonzero((d_any > MATCH_M) & (d_line <= MATCH_M))
    sxy = np.array([[c["x"], c["y"]] for c in res_short["corners"]]).reshape(-1, 2)
    d_s, j_s = cKDTree(sxy).query(ref[miss]) if len(sxy) else (np.full(len(miss), np.inf), None)
    kinds = {}
    for n, k in enumerate(miss):
        if d_s[n] > MATCH_M:
            kind = "no_outline_vertex_near"
        else:
            c = res_short["corners"][j_s[n]]
            kind = ("traced_corner_edge_shorter_than_min_edge" if min(c["edge1_m"], c["edge2_m"]) < min_edge_m
                    else "traced_corner_dropped_by_sigma_gate")
        kinds.setdefault(kind, []).append([round(float(v), 2) for v in ref[k]])
    return {"counts": {k: len(v) for k, v in sorted(kinds.items())}, "vertices_xy": dict(sorted(kinds.items()))}


def plot_misses(path: Path, cloud, res: dict, polys, detail: dict, half_m: float = 9.0) -> None:
    """Zoomed panels (nDSM, BGT footprints cyan, roof outlines orange, corners as in ``plot_corners``) around
    the ``outline_but_no_corner`` vertices (green +), titled with what the tracing did there."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aerotri.core.atomic import atomic_path

    items = [(kind, xy) for kind, v in detail["vertices_xy"].items() for xy in v][:20]
    if not items:
        return
    xyz = np.column_stack([cloud.x, cloud.y, cloud.z])
    ndsm, ext = simple_ndsm(xyz, cloud.classification, cell_m=0.5)
    cols = 5
    rows = (len(items) + cols - 1) // cols
    fig, axs = plt.subplots(rows, cols, figsize=(3.0 * cols + 1.0, 3.2 * rows + 0.6), squeeze=False,
                            layout="constrained")
    cxy = np.array([[c["x"], c["y"]] for c in res.corners]).reshape(-1, 2)
    use = np.array([bool(c["usable"]) for c in res.corners], bool)
    short = {"no_outline_vertex_near": "no outline vertex", "traced_corner_edge_shorter_than_min_edge": "LiDAR edge short",
             "traced_corner_dropped_by_sigma_gate": "sigma gate"}
    for ax in axs.ravel():
        ax.set_axis_off()
    for ax, (kind, (x, y)) in zip(axs.ravel(), items):
        ax.set_axis_on()
        im = ax.imshow(ndsm, origin="lower", extent=ext, cmap="gray", vmin=0, vmax=15)
        for p in polys:
            ax.plot(*np.asarray(p.exterior.coords).T, color="tab:cyan", lw=0.8)
        for o in res.outlines:
            for r in o["rings"]:
                if len(r) >= 3:
                    rr = np.vstack([r, r[:1]])
                    ax.plot(rr[:, 0], rr[:, 1], color="tab:orange", lw=1.0)
        ax.plot(cxy[~use, 0], cxy[~use, 1], "o", mfc="none", color="tab:blue", ms=4)
        ax.plot(cxy[use, 0], cxy[use, 1], "o", color="tab:red", ms=4)
        ax.plot(x, y, "+", color="tab:green", ms=12, mew=2)
        ax.set_xlim(x - half_m, x + half_m)
        ax.set_ylim(y - half_m, y + half_m)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{short.get(kind, kind)} ({x:.0f}, {y:.0f})", fontsize=8)
    fig.colorbar(im, ax=axs, shrink=0.6, label="nDSM (m)")
    fig.suptitle(f"outline but no corner: BGT vertex (green +), BGT cyan, roof outline orange, corners red "
                 f"(usable) / blue; windows {2 * half_m:g} m", fontsize=10)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def detect(cloud, min_edge_m: float | None) -> tuple[dict, float]:
    t0 = time.perf_counter()
    res = find_roof_corners(cloud.x, cloud.y, cloud.z, cloud.classification, cloud.point_source_id,
                            min_edge_m=min_edge_m, roof="any")
    return res, time.perf_counter() - t0


def evaluate(laz: Path, polys: list, min_edge_m: float, corner_dir: Path, dataset: str) -> tuple[dict, dict]:
    """Corners of one AHN3 crop scored against the BGT footprint vertices inside it: (summary for
    bench/results/corners_ahn3.json, what the figure needs)."""
    import pyproj

    cloud = read_classified_cloud(laz)
    crs = pyproj.CRS.from_epsg(28992)  # the file has no CRS record (README): RD New
    load0 = os.getloadavg()
    res, runtime = detect(cloud, min_edge_m)
    min_edge_given, min_edge_m = min_edge_m, res.stats.min_edge_m
    write_corner_files(corner_dir, res, crs=crs, source=str(laz))

    blocks = footprint_blocks(polys)
    vxy, sets = reference_sets(blocks, np.column_stack([cloud.x, cloud.y]))
    # the split of the earlier figures (median x of the ``all`` vertices), kept so both are comparable
    x_split = float(np.median(vxy[sets["all"], 0]))
    halves = {"whole": np.ones(len(vxy), bool), "west": vxy[:, 0] < x_split, "east": vxy[:, 0] >= x_split}
    scores = score_sets(vxy, sets, halves, res)
    corners = res.corners

    # Every corner near a footprint against the nearest footprint vertex (the earlier, corner-side figure).
    fp_union = shapely.union_all(polys)
    cxy = np.array([[c["x"], c["y"]] for c in corners])
    near_bgt = shapely.distance(fp_union, shapely.points(cxy)) < 3.0
    all_vertices = np.concatenate([np.asarray(r.coords)[:-1] for p in polys for r in [p.exterior, *p.interiors]])
    d_all = cKDTree(all_vertices).query(cxy[near_bgt])[0]
    usable_near = np.array([c["usable"] for c in corners], bool)[near_bgt]

    head = "block_corners"
    main_set = scores[head]
    summary = {
        "dataset": dataset,
        "min_edge_m": min_edge_m,
        "min_edge_rule": res.stats.min_edge_rule,
        "match_radius_m": MATCH_M,
        "min_building_m": MIN_BUILDING_M,
        "x_split_m": x_split,
        "n_points": res.stats.n_points,
        "point_spacing_m": res.stats.point_spacing_m,
        "n_roofs": res.stats.n_roofs,
        "n_roof_outlines": res.stats.n_outlines,
        "n_corners": len(corners),
        "n_usable": int(sum(c["usable"] for c in corners)),
        "n_corners_near_bgt": int(near_bgt.sum()),
        "n_usable_near_bgt": int(usable_near.sum()),
        "n_footprints": len(polys),
        "n_footprint_blocks": len(blocks),
        "n_footprint_blocks_ge_10x10m": int(sum(_rect_sides_m(g)[0] >= MIN_BUILDING_M for g in blocks)),
        "reference_definitions": REFERENCE_DEFINITIONS,
        "n_reference_vertices": {k: int(v.sum()) for k, v in sets.items()},
        "headline": {
            "reference": head,
            **{f"{h}_completeness_pct": main_set[h]["any"].get("completeness_pct") for h in halves},
            **{f"{h}_usable_completeness_pct": main_set[h]["usable"].get("completeness_pct") for h in halves},
            **{f"{h}_usable_offset_median_m": main_set[h]["usable"].get("offset_xy", {}).get("median_m")
               for h in halves},
            **{f"{h}_usable_overhang_signed_median_m": main_set[h]["usable"].get("overhang_normal_signed_median_m")
               for h in halves},
            **{f"{h}_usable_along_edge_abs_median_m": main_set[h]["usable"].get("along_edge_abs", {}).get("median_m")
               for h in halves},
            "old_headline_edges_ge_5m_usable_completeness_pct":
                scores["edges_ge_min_edge"]["whole"]["usable"].get("completeness_pct"),
            "all_vertices_usable_completeness_pct": scores["all"]["whole"]["usable"].get("completeness_pct"),
            "targets": {"usable_completeness_pct": 40.0, "usable_offset_median_m": 0.5},
        },
        "why_not_usable": {h: why_not_usable(vxy[sets[head] & halves[h]], res, min_edge_m) for h in halves},
        "by_reference_set": scores,
        "corners_near_bgt_offset_to_nearest_vertex": {"all": offset_stats(d_all[d_all <= MATCH_M]),
                                                      "usable": offset_stats(d_all[(d_all <= MATCH_M) & usable_near])},
        "median_sxy_usable_m": res.stats.median_sxy_usable_m,
        "runtime_s": runtime,
        "loadavg_1_5_15": list(load0),
        "points_per_s": res.stats.n_points / runtime,
        "note": ("footprints are wall lines, roof corners are eave corners: offsets include the eave overhang "
                 "(overhang_normal: along the roof edges' outward normals)"),
    }
    if min_edge_given is None:
        # sensitivity of the headline to the default edge length: fixed 3 m (the reference's edge length,
        # the earlier bench setting) and 5 m (the stage's fixed default before it became density-adaptive)
        summary["min_edge_sensitivity"] = {}
        for fixed in (REF_MIN_EDGE_M, LEGACY_MIN_EDGE_M):
            res_f, _ = detect(cloud, fixed)
            s_f = score_sets(vxy, sets, halves, res_f)
            summary["min_edge_sensitivity"][f"{fixed:g}"] = {
                "min_edge_m": fixed,
                **{f"{h}_usable_completeness_pct": s_f[head][h]["usable"].get("completeness_pct") for h in halves},
                "whole_usable_offset_median_m": s_f[head]["whole"]["usable"].get("offset_xy", {}).get("median_m"),
                "why_not_usable": why_not_usable(vxy[sets[head]], res_f, fixed)}
    res_short, _ = detect(cloud, 0.5)
    summary["outline_but_no_corner_detail"] = outline_but_no_corner(vxy[sets[head]], res, res_short, min_edge_m)
    figure = {"cloud": cloud, "res": res, "truth_xy": vxy[sets[head]], "x_split": x_split}
    return summary, figure


def clopper_pearson_pct(k: int, n: int, level: float = 0.95) -> list[float] | None:
    """Exact binomial confidence interval (%) of k successes in n trials."""
    from scipy.stats import beta

    if n == 0:
        return None
    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return [100.0 * lo, 100.0 * hi]


def whole_crop_table(scores: dict) -> dict:
    """Per reference set, the whole crop's figures: completeness (any / usable corner, with its exact 95 %
    interval: a few dozen vertices), and for usable corners the median offset, the signed median overhang
    and the median |along-edge| offset."""
    out = {}
    for name, s in scores.items():
        a, u = s["whole"]["any"], s["whole"]["usable"]
        n = a["n_reference_vertices"]
        out[name] = {"n_reference_vertices": n,
                     "completeness_pct": a.get("completeness_pct"),
                     "completeness_ci95_pct": clopper_pearson_pct(a.get("n_matched", 0), n),
                     "usable_completeness_pct": u.get("completeness_pct"),
                     "usable_completeness_ci95_pct": clopper_pearson_pct(u.get("n_matched", 0), n),
                     "n_usable_matched": u.get("n_matched", 0),
                     "n_distinct_usable_corners_matched": u.get("n_distinct_corners_matched", 0),
                     "usable_offset_median_m": u.get("offset_xy", {}).get("median_m"),
                     "usable_overhang_signed_median_m": u.get("overhang_normal_signed_median_m"),
                     "usable_along_edge_abs_median_m": u.get("along_edge_abs", {}).get("median_m")}
    return out


def _num(v, digits: int) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=SHARED / "ahn3_delft")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--min-edge-m", type=float, default=None,
                    help="the detector's min_edge_m (default: the stage's default, density-adaptive)")
    ap.add_argument("--laz", type=Path, default=None,
                    help="another crop of the AHN3 survey, never used for tuning (scored against the same BGT "
                         "footprints; its figures go under 'unseen_<name>', the shared crop's stay as they are)")
    ap.add_argument("--name", default=None, help="with --laz: the crop's name (JSON key unseen_<name>, figure "
                                                 "corners_ahn3_<name>.png)")
    args = ap.parse_args()
    if (args.laz is None) != (args.name is None):
        ap.error("--laz and --name go together")
    if args.name is not None and not args.name.replace("_", "").isalnum():
        ap.error("--name: letters, digits and _ only")

    from aerotri.core.atomic import write_text_atomic

    polys = read_footprints(args.data / "bgt_pand.sqlite")
    json_path = args.out / "corners_ahn3.json"
    previous = json.loads(json_path.read_text()) if json_path.exists() else {}
    if args.laz is None:
        laz, key, stem = args.data / "ahn3_cropped_1.laz", None, "corners_ahn3"
        dataset = "AHN3 Delft crop (ahn3_cropped_1.laz) vs BGT footprints (bgt_pand.sqlite), EPSG:28992"
    else:
        laz, key, stem = args.laz, f"unseen_{args.name}", f"corners_ahn3_{args.name}"
        dataset = (f"AHN3 Delft, unseen crop ({args.laz.name}, never used for tuning) vs BGT footprints "
                   "(bgt_pand.sqlite) inside it, EPSG:28992")
    summary, fig = evaluate(laz, polys, args.min_edge_m, REPO / "out" / stem, dataset)
    summary["whole_crop_by_reference_set"] = whole_crop_table(summary["by_reference_set"])
    if key is None:
        # the unseen crops' figures are kept when the shared crop is rerun
        summary.update({k: v for k, v in previous.items() if k.startswith("unseen_")})
        result = summary
    else:
        if "headline" not in previous:
            raise SystemExit(f"{json_path}: run the shared crop first (no shared-crop figures to keep)")
        summary["source"] = ("tudelft3d/3dfier example_data/ahn3/ahn3_cropped_2.laz (GPL-3; not in ../shared/data)"
                             if args.laz.name == "ahn3_cropped_2.laz" else str(args.laz.name))
        result = {**previous, key: summary}
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(json_path, json.dumps(result, indent=2) + "\n")

    cloud = fig["cloud"]
    xyz = np.column_stack([cloud.x, cloud.y, cloud.z])
    ndsm, extent = simple_ndsm(xyz, cloud.classification, cell_m=0.5)
    h = summary["headline"]
    place = "AHN3 Delft" if key is None else f"AHN3 Delft, unseen {laz.name}"
    plot_corners(
        args.out / f"{stem}.png", ndsm, extent, fig["res"]["outlines"], fig["res"]["corners"],
        truth_xy=fig["truth_xy"], reference_polygons=[np.asarray(p.exterior.coords) for p in polys],
        title=(f"{place}: cyan BGT footprints, + block corners (edges >= {REF_MIN_EDGE_M:g} m, turn >= {REF_MIN_TURN_DEG:g} deg), "
               f"split x = {fig['x_split']:.0f}\nstage defaults (min edge {summary['min_edge_m']:.2f} m): "
               f"usable completeness {_num(h['whole_usable_completeness_pct'], 0)} % "
               f"(west {_num(h['west_usable_completeness_pct'], 0)}, "
               f"east {_num(h['east_usable_completeness_pct'], 0)}), "
               f"median offset {_num(h['whole_usable_offset_median_m'], 2)} m"),
        vlines=[fig["x_split"]],
    )
    plot_misses(args.out / f"{stem}_misses.png", cloud, fig["res"], polys, summary["outline_but_no_corner_detail"])
    print(json.dumps(summary["whole_crop_by_reference_set"], indent=2))
    print(json.dumps(h, indent=2))


if __name__ == "__main__":
    main()
