"""Edited seamlines that cross buildings (issue 42, seam-edit-check): the demo's round trip.

On a copy of the demo project (its frames, mosaic and LiDAR rasters; the demo itself is read only):

1. the unedited ``ortho/seamlines.gpkg`` given back (``ortho mosaic P --seamlines same.gpkg``): its crossings
   (mosaic.json ``seam_crossings``), whether any is new, and the mosaic's bytes against the earlier one;
2. one edge moved across a roof: a building of the nDSM (raised > 0.5 m, no CHM, 80-600 m2) inside frame i's polygon
   whose neighbourhood frame j covers, the edit's outline over no other raised cell (nDSM > 0.5 m); the part of i's polygon right of a line through the building's centre, 30 deg
   from north, within the building's box widened by 4 m, given to j. The warning must name i and j; the crossing's
   length is compared with that line's length over the building's cells (nDSM raised, no CHM, sampled every 0.05 m).

Usage: python bench/check_seam_crossings.py [--demo /work/demo7/out/demo/project] [--work DIR]
Writes bench/results/seam_crossings.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _sha1(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()


def _copy(demo: Path, work: Path) -> Path:
    p = work / "project"
    if p.exists():
        shutil.rmtree(p)
    p.mkdir(parents=True)
    for name in ("project.toml", "camera.toml", "gnss.txt", "at", "control", "ortho"):
        src = demo / name
        if src.is_dir():
            shutil.copytree(src, p / name)
        elif src.exists():
            shutil.copy2(src, p / name)
    (p / "lidar_out").mkdir()
    for name in ("dem.tif", "dsm.tif", "ndsm.tif", "chm.tif", "dsm_crowns.tif"):
        if (demo / "lidar_out" / name).exists():
            shutil.copy2(demo / "lidar_out" / name, p / "lidar_out" / name)
    return p


def _run(project: Path, edited: Path, log: list) -> dict:
    from click.testing import CliRunner

    from ortho.cli import main

    t = time.time()
    r = CliRunner().invoke(main, ["mosaic", str(project), "--seamlines", str(edited)])
    if r.exit_code != 0:
        raise SystemExit(r.output)
    s = json.loads((project / "ortho" / "mosaic.json").read_text())
    log.append(r.output)
    return {"wall_s": round(time.time() - t, 1), "tiles": s.get("tiles"), "seam_crossings": s["seam_crossings"],
            "mosaic_sha1": _sha1(project / "ortho" / "mosaic.tif"),
            "warnings_printed": [ln for ln in r.output.splitlines() if "edited seam between" in ln]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--demo", type=Path, default=Path("/work/demo7/out/demo/project"))
    ap.add_argument("--work", type=Path, default=Path("/tmp/seam_crossings_bench"))
    a = ap.parse_args()
    import cv2
    import pyogrio
    import rasterio
    import shapely
    from rasterio import features

    project = _copy(a.demo, a.work)
    out = {"demo": str(a.demo)}
    before = _sha1(project / "ortho" / "mosaic.tif")
    same = a.work / "same.gpkg"
    shutil.copy(project / "ortho" / "seamlines.gpkg", same)
    log: list = []
    out["unedited"] = _run(project, same, log)
    out["unedited"]["mosaic_unchanged"] = out["unedited"]["mosaic_sha1"] == before

    meta, fids, wkb, fields = pyogrio.raw.read(same, return_fids=True)
    names = list(fields[list(meta["fields"]).index("frame")])
    geoms = list(shapely.from_wkb(wkb))
    with rasterio.open(project / "lidar_out" / "ndsm.tif") as ds, \
            rasterio.open(project / "lidar_out" / "chm.tif") as cs:
        nd = ds.read(1, masked=True).filled(0)
        chm = cs.read(1, masked=True).filled(0) if cs.shape == ds.shape else np.zeros_like(nd)
        t = ds.transform
    roof = ((nd > 0.5) & ~(chm > 0.5)).astype(np.uint8)  # raised, no vegetation: the check's "building"
    n, lab, stats, _ = cv2.connectedComponentsWithStats(roof, connectivity=4)
    cell = abs(t.a)

    def valid_of(k):
        with rasterio.open(project / "ortho" / "frames" / f"{names[k]}.tif") as f:
            m = f.read_masks(1)
            # the outlines, holes filled: a true ortho's frame does not see behind buildings, yet its polygon may
            # hold those cells (the check of edited seamlines takes the frame's footprint, holes included)
            shapes = [shapely.Polygon(shapely.geometry.shape(g).exterior)
                      for g, _ in features.shapes(m, mask=m > 0, transform=f.transform)]
        return shapely.union_all(shapes).buffer(-3)

    valid = [valid_of(k) for k in range(len(names))]
    order = np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1
    chosen = None
    for b in order:
        area = stats[b, cv2.CC_STAT_AREA] * cell * cell
        if not 80 <= area <= 600:
            continue
        x, y, w, h = (int(v) for v in stats[b, :4])
        x0, y1 = t * (x, y)
        x1, y0 = t * (x + w, y + h)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        bx = shapely.box(x0, y0, x1, y1)
        th = math.radians(30)
        dx, dy, L = math.sin(th), math.cos(th), 200.0
        far = shapely.Polygon([(cx - dx * L, cy - dy * L), (cx + dx * L, cy + dy * L),
                               (cx + dx * L + dy * L, cy + dy * L - dx * L), (cx - dx * L + dy * L, cy - dy * L - dx * L)])
        region = far.intersection(bx.buffer(4, join_style="mitre"))
        edge = region.boundary
        d = np.arange(0, edge.length, 0.1)
        pts = shapely.line_interpolate_point(edge, d)
        col, row = ~t * (shapely.get_x(pts), shapely.get_y(pts))
        row, col = np.floor(row).astype(int), np.floor(col).astype(int)
        if row.min() < 0 or col.min() < 0 or row.max() >= nd.shape[0] or col.max() >= nd.shape[1]:
            continue
        if np.any((nd[row, col] > 0.5) & (lab[row, col] != b)):
            continue  # the edit's outline would cross another raised object (a tree, a car) too
        for i in range(len(names)):
            if not geoms[i].contains(bx.buffer(1)):
                continue
            for j in range(len(names)):
                if j != i and valid[j].contains(region):
                    chosen = (int(b), i, j, region, (cx, cy), (dx, dy), bx)
                    break
            if chosen:
                break
        if chosen:
            break
    if chosen is None:
        raise SystemExit("no building to move an edge across")
    b, i, j, region, (cx, cy), (dx, dy), bx = chosen
    take = region.intersection(geoms[i])
    moved = list(geoms)
    moved[i], moved[j] = geoms[i].difference(take), geoms[j].union(take)
    moved = [shapely.MultiPolygon([g]) if g.geom_type == "Polygon" else g for g in moved]
    edited = a.work / "edited.gpkg"
    pyogrio.raw.write(str(edited), shapely.to_wkb(np.array(moved, dtype=object)), [np.array(names, dtype=object)],
                      ["frame"], layer="seamlines", driver="GPKG", geometry_type="MultiPolygon", crs=meta["crs"])
    # the drawn line's length over the building's cells (fine sampling on the nDSM's grid)
    line = shapely.LineString([(cx - dx * 200, cy - dy * 200), (cx + dx * 200, cy + dy * 200)]).intersection(
        bx.buffer(4, join_style="mitre"))
    d = np.arange(0, line.length, 0.05) + 0.025
    pts = shapely.line_interpolate_point(line, d)
    col, row = ~t * (shapely.get_x(pts), shapely.get_y(pts))
    on = lab[np.floor(row).astype(int), np.floor(col).astype(int)] == b
    truth_m = float(on.sum() * 0.05)
    out["edited"] = _run(project, edited, log)
    out["edited"]["edit"] = {"frame_from": names[i], "frame_to": names[j], "building_centre": [round(cx, 1), round(cy, 1)],
                             "building_area_m2": float(stats[b, cv2.CC_STAT_AREA] * cell * cell),
                             "line_over_building_m": round(truth_m, 2), "area_moved_m2": round(take.area, 1)}
    pair = [p for p in out["edited"]["seam_crossings"]["pairs"] if {p["frame_a"], p["frame_b"]} == {names[i], names[j]}]
    out["edited"]["pair"] = pair[0] if pair else None
    out["edited"]["warning_names_the_pair"] = any(names[i] in w and names[j] in w
                                                  for w in out["edited"]["seam_crossings"]["warnings"])
    dest = REPO / "bench" / "results" / "seam_crossings.json"
    dest.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out, indent=1)[:6000])


if __name__ == "__main__":
    main()
