"""Points flagged withheld (LAS: "should not be included in processing") on real data: lidR Topography
(``../shared/data/lidr_topography/Topography.laz``) with 200 points (seeded) flagged withheld and lowered 3-20 m, the
trial's reproduction (docs/new-user-trial.md, LiDAR/GIS analyst). Each cloud is classified (``classify_file``) and
gridded (``write_rasters`` at 1 m), in one process:

- ``without``: the file without those 200 points (the truth of what the rule should give);
- ``withheld``: the file with them flagged, read with the rule (``aerotri.geom.las.usable``);
- ``flag_ignored``: the same file with the rule switched off in-process (``usable`` returns None): the old behaviour.

Reported: classes of the other points that differ from ``without``'s, the withheld points' output classes against
their delivered ones, DEM / DSM cells that differ from ``without``'s and the largest difference.
Writes bench/results/withheld_points.json.
Run: .venv/bin/python bench/eval_withheld.py [--work /tmp/withheld]
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
from pathlib import Path

import laspy
import numpy as np
import rasterio

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "lidr_topography" / "Topography.laz"
if not DATA.exists():
    DATA = Path("/work/shared/data/lidr_topography/Topography.laz")
N_WITHHELD, SEED, RES_M = 200, 44, 1.0


def make_pair(work: Path):
    src = laspy.read(DATA)
    x, y = np.asarray(src.x), np.asarray(src.y)
    rng = np.random.default_rng(SEED)
    inner = np.flatnonzero((x > x.min() + 5) & (x < x.max() - 5) & (y > y.min() + 5) & (y < y.max() - 5))
    idx = np.sort(rng.choice(inner, N_WITHHELD, replace=False))
    # LAS 1.4 point format 6 (the withheld flag of formats 0-5 works the same; 6 is what deliveries use now)
    moved = laspy.convert(src, point_format_id=6, file_version="1.4")
    z = np.asarray(moved.z).copy()
    z[idx] -= rng.uniform(3.0, 20.0, len(idx))
    moved.z = z
    flag = np.zeros(len(x), bool)
    flag[idx] = True
    moved.withheld = flag
    moved.write(work / "withheld.laz")
    keep = ~flag
    without = laspy.LasData(moved.header)
    without.points = moved.points[keep]
    without.z = np.asarray(src.z)[keep]
    without.withheld = np.zeros(int(keep.sum()), bool)
    without.write(work / "without.laz")
    return idx, keep


def run(src: Path, out: Path):
    from lidarctl.rasters.products import write_rasters
    from lidarctl.tiles import classify_file

    out.mkdir(parents=True, exist_ok=True)
    classify_file(src, out / "classified.laz")
    write_rasters([out / "classified.laz"], out, RES_M)
    return np.asarray(laspy.read(out / "classified.laz").classification)


def grid_diff(a: Path, b: Path, name: str) -> dict:
    with rasterio.open(a / f"{name}.tif") as ra, rasterio.open(b / f"{name}.tif") as rb:
        assert ra.transform == rb.transform
        x, y = ra.read(1, masked=True).astype(float).filled(np.nan), rb.read(1, masked=True).astype(float).filled(np.nan)
    same = (x == y) | (np.isnan(x) & np.isnan(y))
    d = np.abs(x - y)
    return {"cells_differ": int((~same).sum()), "max_abs_diff_m": float(np.nanmax(d)) if (~same).any() else 0.0}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/withheld"))
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    from aerotri.geom import las

    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    idx, keep = make_pair(args.work)
    delivered = np.asarray(laspy.read(args.work / "withheld.laz").classification)
    cls_without = run(args.work / "without.laz", args.work / "without")
    cls_rule = run(args.work / "withheld.laz", args.work / "withheld")
    rule = las.usable
    las.usable = lambda chunk: None          # the flag ignored: every point used
    try:
        cls_ignored = run(args.work / "withheld.laz", args.work / "flag_ignored")
    finally:
        las.usable = rule
    doc = {"what": __doc__.split("\n\n")[0].replace("\n", " "), "data": str(DATA), "n_points": int(len(keep)),
           "n_withheld": N_WITHHELD, "seed": SEED, "res_m": RES_M}
    for name, cls, folder in (("withheld", cls_rule, "withheld"), ("flag_ignored", cls_ignored, "flag_ignored")):
        doc[name] = {
            "other_points_class_differs": int((cls[keep] != cls_without).sum()),
            "withheld_points_class_changed": int((cls[idx] != delivered[idx]).sum()),
            "withheld_points_classes": {int(k): int(v) for k, v in zip(*np.unique(cls[idx], return_counts=True))},
            "dem": grid_diff(args.work / "without", args.work / folder, "dem"),
            "dsm": grid_diff(args.work / "without", args.work / folder, "dsm"),
        }
    out = REPO / "bench" / "results" / "withheld_points.json"
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
