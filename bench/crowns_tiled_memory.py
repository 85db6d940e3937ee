"""Peak memory of the tree crowns of a block (``lidarctl.rasters.crown_model.write_crown_model``, issue 41/42): the
in-memory fit of the code before tiling (every return of the block and the whole nearest-return DSM held at once;
its module taken from git, ``--before``), one tile (the whole block through the tiled path) and tiles of 500, 200
and 100 m with their halo (``crown_halo_m``), on the demo project's classified strips.

Each way in its own process: wall, CPU seconds, peak RSS (ru_maxrss), the tiles, the most returns a tile held. Each
way's crowns.gpkg and dsm_crowns.tif are compared with the in-memory fit's: the tree attributes and polygons, the
surface's cells and the files' bytes. Writes bench/results/crowns_tiled_memory.json.

``imports``: the process with the modules alone (what every way holds besides its data).

Usage: python bench/crowns_tiled_memory.py --demo PROJECT [--work DIR] [--before COMMIT]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
BEFORE = "3679ef12"  # the branch's base: crown_model.py in memory (main's write_crown_model)
WAYS = (("imports", None), ("before", None), ("one_tile", None), ("tiles_500m", 500.0), ("tiles_200m", 200.0), ("tiles_100m", 100.0))


def child(way: str, tile_m: float | None, demo: Path, out: Path, before: str) -> None:
    import importlib.util
    import resource

    lidar = demo / "lidar_out"
    paths = sorted((lidar / "classified").glob("strip_*.laz"))
    t0, c0 = time.perf_counter(), time.process_time()
    info = {}
    if way == "imports":  # the process alone: the interpreter and the modules the others import
        import rasterio  # noqa: F401
        import shapely  # noqa: F401

        from aerotri.core.vector_files import write_layers  # noqa: F401
        from lidarctl.rasters.crown_model import write_crown_model_run  # noqa: F401
        from lidarctl.rasters.products import _file_points  # noqa: F401
    elif way == "before":
        src = subprocess.run(["git", "-C", str(REPO), "show", f"{before}:lidarctl/rasters/crown_model.py"],
                             check=True, capture_output=True, text=True).stdout
        mod_path = out / "crown_model_before.py"
        mod_path.write_text(src)
        spec = importlib.util.spec_from_file_location("crown_model_before", mod_path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.write_crown_model(paths, lidar / "dsm_nearest.tif", out)
    else:
        from lidarctl.rasters.crown_model import write_crown_model_run

        run = write_crown_model_run(paths, lidar / "dsm_nearest.tif", out, tile_m=tile_m)
        info = {"trees": run.trees, "halo_m": round(run.halo_m, 2), "tiles": run.tiles,
                "max_tile_returns": run.max_tile_returns, "cells_beyond_halo": run.cells_beyond_halo}
    print(json.dumps({"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(time.process_time() - c0, 2),
                      "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1), **info}))


def _outputs(d: Path):
    import rasterio
    from pyogrio import raw

    meta, _, geoms, fields = raw.read(d / "crowns.gpkg")
    with rasterio.open(d / "dsm_crowns.tif") as ds:
        surface = ds.read(1)
    digest = {n: hashlib.sha256((d / n).read_bytes()).hexdigest() for n in ("crowns.gpkg", "dsm_crowns.tif")}
    return dict(zip(meta["fields"], fields)), list(geoms), surface, digest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demo", type=Path, required=True, help="a project made by `aerotri demo` (its lidar_out)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/crowns_tiled_memory"))
    ap.add_argument("--before", default=BEFORE)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        way = a.child[0]
        child(way, dict(WAYS)[way], a.demo, Path(a.child[1]), a.before)
        return
    import laspy

    paths = sorted((a.demo / "lidar_out" / "classified").glob("strip_*.laz"))
    n_points = sum(int(laspy.open(p).header.point_count) for p in paths)
    rows, ref = {}, None
    for way, tile_m in WAYS:
        out = a.work / way
        out.mkdir(parents=True, exist_ok=True)
        r = subprocess.run([sys.executable, __file__, "--demo", str(a.demo), "--before", a.before,
                            "--child", way, str(out)], check=True, capture_output=True, text=True, cwd=REPO)
        row = json.loads(r.stdout.strip().splitlines()[-1])
        if way == "imports":
            rows[way] = row
            continue
        fields, geoms, surface, digest = _outputs(out)
        if ref is None:
            ref = fields, geoms, surface, digest
        row.update({
            "tile_m": tile_m, "trees_in_file": len(fields["x_m"]),
            "attributes_equal_before": len(fields["x_m"]) == len(ref[0]["x_m"]) and all(
                np.array_equal(fields[k], ref[0][k]) for k in ref[0]),
            "polygons_equal_before": geoms == ref[1],
            "surface_cells_differing_from_before": int(np.sum(surface != ref[2])),
            "files_bytes_equal_before": digest == ref[3]})
        rows[way] = row
        print(way, json.dumps(row), flush=True)
    res = {"demo": str(a.demo), "strips": len(paths), "returns": n_points, "before_commit": a.before,
           "ways": rows,
           "above_imports_mib": {w: round(r["peak_rss_mib"] - rows["imports"]["peak_rss_mib"], 1)
                                 for w, r in rows.items() if w != "imports"},
           "peak_ratio_tiles_200m_to_before": round(rows["tiles_200m"]["peak_rss_mib"] / rows["before"]["peak_rss_mib"], 3),
           "note": "peak RSS includes the interpreter and imports (about 200-250 MiB); one machine shared by other "
                   "engineers, each way once in its own process"}
    dest = REPO / "bench" / "results" / "crowns_tiled_memory.json"
    dest.write_text(json.dumps(res, indent=1) + "\n")
    print(dest)


if __name__ == "__main__":
    main()
