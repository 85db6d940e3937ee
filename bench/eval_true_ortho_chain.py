"""The true ortho in the chain, the DOM check's roofs row and an edited-seamline round trip, on the demo (issue 42).

1. The chain's orthophoto stages (``aerotri run``'s rectify, mosaic and dom_check, the chain's own stage code) on a
   copy of the demo project (``/work/ref/demo_chain/project``: LiDAR DSM in lidar_out/) twice, same frames and
   orientation: with the chain's default (true ortho on lidar_out/dsm.tif) and with ``[rectify] true_ortho = false``.
   For each: the stage's wall and CPU time, the DOM check's ground and roofs rows (roofs at the corners of the nDSM's
   buildings, against the simulator's true orthophoto truth/ortho.tif), and ``ortho check --roof-corners
   truth/roof_corners.csv`` (the simulator's own roof corners).
2. Seamlines: the true DOM's ortho/seamlines.gpkg given back unedited (the mosaic must not change) and with one edge
   moved (frame b takes a 10 x 10 m square of its neighbour a's polygon on their shared edge): mosaic tiles (512 px)
   changed by checksum, against the tiles within the feather's reach of the square, and the processing tiles the
   run blended / took over from the earlier mosaic (mosaic.json tiles); five bad edits (unknown frame, overlap, gap,
   polygon beyond its frame, a frame twice) must exit 2 naming the feature and write nothing.

Usage: python bench/eval_true_ortho_chain.py [--project /work/ref/demo_chain/project] [--work DIR]
Writes bench/results/true_ortho_chain.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
BIN = Path(sys.executable).parent
TILE_PX = 512


def copy_project(src: Path, dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("ortho", "reports", "classified"))
    # (lidar/ stays: the chain takes lidar_out/dsm.tif for the true ortho when the project has LiDAR strips)


def ortho_stages(project: Path) -> list[dict]:
    from aerotri.chain.runner import run_stages
    from aerotri.chain.stages import Chain
    from aerotri.chain.options import read_options
    from aerotri.core.project import Project

    p = Project.open(project)
    chain = Chain(p, read_options(p), reference_ortho=project / "truth" / "ortho.tif")
    stages = [s for s in chain.stages() if s.name in ("rectify", "mosaic", "dom_check")]
    notes = []
    rows = run_stages(project, stages, force=True, log=lambda m: notes.append(m))
    return rows, [n for n in notes if "note:" in n]


def check_roof_corners(project: Path, out: Path) -> dict:
    r = subprocess.run([str(BIN / "ortho"), "check", str(project), "--reference", str(project / "truth" / "ortho.tif"),
                        "--roof-corners", str(project / "truth" / "roof_corners.csv"), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rep = json.loads(out.with_suffix(".json").read_text())
    return {"ground": _row(rep["displacement"]), "roofs": _row(rep["roofs"]), "console": r.stdout.strip().splitlines()}


def _row(d: dict) -> dict:
    keys = ("count", "corners", "rms_xy_m", "rms_xy_gsd", "median_xy_m", "median_xy_gsd", "p95_xy_m", "corners_from",
            "not_measured")
    return {k: d[k] for k in keys if k in d}


def tile_sums(path: Path) -> dict:
    import rasterio
    from rasterio.windows import Window

    out = {}
    with rasterio.open(path) as ds:
        for r0 in range(0, ds.height, TILE_PX):
            for c0 in range(0, ds.width, TILE_PX):
                w = Window(c0, r0, min(TILE_PX, ds.width - c0), min(TILE_PX, ds.height - r0))
                out[r0, c0] = hashlib.sha1(ds.read(window=w).tobytes() + ds.read_masks(1, window=w).tobytes()).hexdigest()
    return out


def read_gpkg(path):
    import pyogrio
    import shapely

    meta, fids, wkb, fields = pyogrio.raw.read(path, return_fids=True)
    return meta, list(fids), list(fields[list(meta["fields"]).index("frame")]), list(shapely.from_wkb(wkb))


def write_gpkg(path, names, geoms, crs):
    import pyogrio
    import shapely

    geoms = [shapely.MultiPolygon([g]) if g.geom_type == "Polygon" else g for g in geoms]
    pyogrio.raw.write(str(path), shapely.to_wkb(np.array(geoms, dtype=object)), [np.array(names, dtype=object)],
                      ["frame"], layer="seamlines", driver="GPKG", geometry_type="MultiPolygon", crs=crs)


def mosaic(project: Path, *extra) -> tuple[subprocess.CompletedProcess, float]:
    t = time.perf_counter()
    r = subprocess.run([str(BIN / "ortho"), "mosaic", str(project), *map(str, extra)], capture_output=True, text=True)
    return r, time.perf_counter() - t


def seamline_round_trip(project: Path, work: Path) -> dict:
    import rasterio
    import shapely
    from rasterio import features

    before = tile_sums(project / "ortho" / "mosaic.tif")
    meta, fids, names, geoms = read_gpkg(project / "ortho" / "seamlines.gpkg")
    out = {"frames": len(names), "tiles": len(before), "tile_px": TILE_PX}
    same = work / "unedited.gpkg"
    shutil.copy(project / "ortho" / "seamlines.gpkg", same)
    r, dt = mosaic(project, "--seamlines", same)
    assert r.returncode == 0, r.stderr
    summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    out["unedited"] = {"tiles_changed": sum(before[k] != v for k, v in tile_sums(project / "ortho" / "mosaic.tif").items()),
                       "mosaic_tiles": summary.get("tiles"), "wall_s": round(dt, 1)}
    res = summary["res_m"]
    footprints = {}

    def valid_of(k):
        if k not in footprints:
            with rasterio.open(project / "ortho" / "frames" / f"{names[k]}.tif") as f:
                m = f.read_masks(1, out_shape=(f.height // 4, f.width // 4))
                t = f.transform @ f.transform.scale(f.width / m.shape[1], f.height / m.shape[0])
                shapes = [shapely.geometry.shape(g) for g, v in features.shapes(m, mask=m > 0, transform=t)]
            footprints[k] = shapely.union_all(shapes).buffer(-8 * res)
        return footprints[k]

    moved = square = None
    for i in range(len(geoms)):
        for j in range(len(geoms)):
            if moved is None and i != j:
                shared = geoms[i].boundary.intersection(geoms[j].boundary)
                if shared.length < 30:
                    continue
                p = shared.interpolate(0.5, normalized=True)
                sq = shapely.box(p.x - 5, p.y - 5, p.x + 5, p.y + 5)
                if valid_of(i).contains(sq) and valid_of(j).contains(sq):
                    moved, square = list(geoms), sq
                    moved[i] = geoms[i].difference(sq)
                    moved[j] = geoms[j].union(sq.intersection(geoms[i]))
                    out["moved"] = {"from": names[i], "to": names[j], "square_m": 10.0,
                                    "centre": [round(p.x, 1), round(p.y, 1)]}
    edited = work / "edited.gpkg"
    write_gpkg(edited, names, moved, meta["crs"])
    r, dt = mosaic(project, "--seamlines", edited)
    assert r.returncode == 0, r.stderr
    after = tile_sums(project / "ortho" / "mosaic.tif")
    changed = {k for k in before if before[k] != after[k]}
    summary = json.loads((project / "ortho" / "mosaic.json").read_text())
    with rasterio.open(project / "ortho" / "mosaic.tif") as ds:
        reach = (2 * summary["feather_px"] + summary["seam_factor"] + 2) * res
        x0, y0, x1, y1 = square.buffer(reach).bounds
        c0, r0 = ~ds.transform @ (x0, y1)
        c1, r1 = ~ds.transform @ (x1, y0)
    near = {k for k in before if k[0] < r1 and k[0] + TILE_PX > r0 and k[1] < c1 and k[1] + TILE_PX > c0}
    out["edited"] = {"tiles_changed": len(changed), "tiles_within_reach": len(near),
                     "changed_outside_reach": len(changed - near), "mosaic_tiles": summary.get("tiles"),
                     "wall_s": round(dt, 1)}
    bad = {}
    for edit in ("unknown", "overlap", "gap", "beyond", "twice"):
        n, g = list(names), list(geoms)
        if edit == "unknown":
            n[0] = "no_such_frame"
        elif edit == "overlap":
            other = next(i for i in range(len(g)) if i and g[i].touches(g[0]))
            g[0] = g[0].union(g[other].buffer(-1.0).intersection(g[0].buffer(8.0)))
        elif edit == "gap":
            c = g[0].representative_point()
            g[0] = g[0].difference(shapely.box(c.x - 4, c.y - 4, c.x + 4, c.y + 4))
        elif edit == "beyond":
            g[0] = g[0].union(g[0].envelope.buffer(60.0).difference(shapely.union_all(g[1:])))
        else:
            n, g = n + [n[0]], g + [shapely.box(0, 0, 1, 1)]
        path = work / f"bad_{edit}.gpkg"
        write_gpkg(path, n, g, meta["crs"])
        stamp = {p.name: p.stat().st_mtime_ns for p in (project / "ortho").iterdir()}
        r, dt = mosaic(project, "--seamlines", path)
        bad[edit] = {"exit": r.returncode, "message": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "",
                     "outputs_unchanged": stamp == {p.name: p.stat().st_mtime_ns for p in (project / "ortho").iterdir()},
                     "wall_s": round(dt, 1)}
    out["bad_edits"] = bad
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_chain")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_chain.json")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    out = {"project": str(args.project), "ways": {}}
    for way in ("true_ortho", "conventional"):
        p = args.work / way
        copy_project(args.project, p)
        if way == "conventional":
            with open(p / "project.toml", "a") as f:
                f.write("\n[rectify]\ntrue_ortho = false\n")
        rows, notes = ortho_stages(p)
        res = {"stages": rows, "notes": notes,
               "dom_check": json.loads((p / "ortho" / "dom_report.json").read_text()),
               "roof_corners_check": check_roof_corners(p, args.work / f"{way}_roofs")}
        res["dom_check"] = {"ground": _row(res["dom_check"]["displacement"]), "roofs": _row(res["dom_check"]["roofs"])}
        out["ways"][way] = res
        print(way, json.dumps(res, indent=1, default=str), flush=True)
    out["seamlines"] = seamline_round_trip(args.work / "true_ortho", args.work)
    print(json.dumps(out["seamlines"], indent=1), flush=True)
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    args.out.write_text(json.dumps(out, indent=1, default=str) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
