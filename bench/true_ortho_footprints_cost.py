"""The cost of the true ortho with building footprints against the conventional one and the true ortho without them,
per MP of frame ortho, on the demo's whole block (issue 42: at most 2x the conventional rectify time per MP) ->
a key of bench/results/true_ortho_cost.json (the other keys are kept).

Three ways, each one ``rectify_block`` of every frame of the block (the footprints' occluder is built once a block,
``ortho.block._block_footprint_cells``), in the same process, alternating round by round (conventional, true,
true + footprints, conventional, ...), so that the load of the shared machine falls on all alike:

- conventional: on the DEM (lidar_out/dem.tif), as ``ortho rectify P``;
- true: ``--true-ortho --dsm P/lidar_out/dsm.tif``;
- true + footprints: the same with ``--footprints P/truth/footprints.gpkg`` (the simulator's wall lines,
  ``aerotri.sim.project.write_footprints_gpkg`` of truth/buildings.geojson);
- true + footprints + crowns (``--crowns``): the same with ``--crown-base P/lidar_out/crown_base.tif`` (the LiDAR's
  crown bases from the chain's classified strips, ``eval_true_ortho_dsm_cell.lidar_crown_base``).

CPU is the process's (user + sys of all its threads, ``time.process_time``) per call; one call of each way runs first
and is not counted (numba's compiled-code cache, the imports). Per way: the CPU-s per MP of each round, their median,
and the load average. ``--sha256``: also the sha256 of each frame ortho's decoded samples and mask of the last
true + footprints round (to compare the frames of two commits); ``--sha256-all``: of every way's last round, by way.

Usage: python bench/true_ortho_footprints_cost.py [--demo /work/ref/demo_chain/project] [--work DIR] [--rounds 3]
       [--key footprints_demo] [--out bench/results/true_ortho_cost.json] [--sha256 FILE]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

WAYS = ("conventional", "true_ortho", "true_ortho_footprints")
CROWNS = "true_ortho_footprints_crowns"


def settings(project: Path, way: str):
    from ortho.settings import RectifySettings

    if way == "conventional":
        return RectifySettings()
    crowns = {"crown_base": str(project / "lidar_out" / "crown_base.tif")} if way == CROWNS else {}
    return RectifySettings(true_ortho=True, dsm=str(project / "lidar_out" / "dsm.tif"),
                           footprints=str(project / "truth" / "footprints.gpkg") if "footprints" in way else None,
                           **crowns)


def one_block(project: Path, way: str) -> dict:
    from ortho.block import read_index, rectify_block

    t, c = time.perf_counter(), time.process_time()
    rectify_block(project, settings(project, way))
    cpu, wall = time.process_time() - c, time.perf_counter() - t
    mp = sum(e["width"] * e["height"] for e in read_index(project).document["frames"]) / 1e6
    return {"frame_ortho_mp": round(mp, 2), "cpu_s": round(cpu, 3), "wall_s": round(wall, 3),
            "cpu_s_per_mp": round(cpu / mp, 4), "load_avg_1min": round(os.getloadavg()[0], 2)}


def frame_sha256(project: Path) -> dict:
    import numpy as np
    import rasterio

    out = {}
    for f in sorted((project / "ortho" / "frames").glob("*.tif")):
        with rasterio.open(f) as ds:
            h = hashlib.sha256(np.ascontiguousarray(ds.read()).tobytes())
            h.update(np.ascontiguousarray(ds.read_masks(1)).tobytes())
            out[f.stem] = h.hexdigest()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_footprints_cost")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--key", default="footprints_demo")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_cost.json")
    ap.add_argument("--sha256", type=Path, default=None)
    ap.add_argument("--sha256-all", type=Path, default=None)
    ap.add_argument("--crowns", action="store_true", help="a fourth way: footprints and the LiDAR's crown bases")
    args = ap.parse_args()
    from eval_true_ortho_dsm_cell import lidar_crown_base
    from true_ortho_cost import small_project

    ways = WAYS + ((CROWNS,) if args.crowns else ())

    from aerotri.core.atomic import write_text_atomic
    from aerotri.core.project import Project
    from aerotri.sim.project import write_footprints_gpkg

    projects = {}
    for way in ways:
        p = projects[way] = args.work / way
        small_project(args.demo, p)
        (p / "truth").mkdir()
        write_footprints_gpkg(args.demo / "truth" / "buildings.geojson", p / "truth" / "footprints.gpkg",
                              Project.open(p).crs)
        if way == CROWNS:
            lidar_crown_base(args.demo, False, p / "lidar_out" / "dsm.tif", p / "lidar_out" / "crown_base.tif")
    for way in ways:  # not counted: compiled code, imports
        one_block(projects[way], way)
    runs = {way: [] for way in ways}
    for k in range(args.rounds):
        for way in ways:
            r = one_block(projects[way], way)
            runs[way].append(r)
            print(k, way, r, flush=True)
    out = {"project": str(args.demo), "rounds": args.rounds, "ways": {}}
    for way, rs in runs.items():
        per_mp = sorted(r["cpu_s_per_mp"] for r in rs)
        out["ways"][way] = {"runs": rs, "cpu_s_per_mp_median": per_mp[len(per_mp) // 2]}
    conv = out["ways"]["conventional"]["cpu_s_per_mp_median"]
    out["cpu_per_mp_ratio_to_conventional"] = {way: round(out["ways"][way]["cpu_s_per_mp_median"] / conv, 3)
                                               for way in ways[1:]}
    # the same ratio round by round (each round's three calls ran back to back)
    out["cpu_per_mp_ratio_by_round"] = {way: [round(runs[way][k]["cpu_s_per_mp"] / runs["conventional"][k]["cpu_s_per_mp"], 3)
                                              for k in range(args.rounds)] for way in ways[1:]}
    out["command"] = "python bench/true_ortho_footprints_cost.py " + " ".join(sys.argv[1:])
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    print(json.dumps({k: v for k, v in out.items() if k != "ways"}, indent=1))
    if args.sha256:
        write_text_atomic(args.sha256, json.dumps(frame_sha256(projects["true_ortho_footprints"]), indent=1) + "\n")
    if args.sha256_all:
        write_text_atomic(args.sha256_all, json.dumps({way: frame_sha256(projects[way]) for way in ways}, indent=1)
                          + "\n")
    doc = json.loads(args.out.read_text()) if args.out.exists() else {}
    doc[args.key] = out
    write_text_atomic(args.out, json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.key} into {args.out}")


if __name__ == "__main__":
    main()
