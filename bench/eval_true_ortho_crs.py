"""The chain's true ortho delivered in a contract CRS against the same in the project CRS (issue 42; our users deliver
in CGCS2000 / Xian 1980 3-degree Gauss-Krueger): the same frames, orientation and LiDAR rasters, rectified with
``ortho rectify --crs`` (the grid of the contract CRS, its maps and z-buffer through ``ortho.grid.GridToProject``) and
without, each way conventional and true ortho (the chain's occlusion test: ``lidar_out/dsm_crowns.tif`` with
``crowns.gpkg``), mosaicked, checked by ``ortho check`` against the simulator's true orthophoto (open ground and
roofs, the reference read through the coordinate operation), and measured against the simulator's geometry by
``bench/eval_true_ortho_fill.py`` (occluded ground filled from a frame that sees it) and
``bench/eval_true_ortho_occlusion.py`` (ghosts, seams on roofs). The truth is ray cast at each DOM cell's centre
taken to the project CRS (``eval_true_ortho_occlusion.Truth.local_xy``).

Usage: python bench/eval_true_ortho_crs.py --demo PROJECT [--crs gk3:cgcs2000] [--work DIR] [--key KEY] [--reuse]
(PROJECT a demo project after ``aerotri run``). Writes bench/results/true_ortho_crs.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from results_json import git_commit, store_result  # noqa: E402

LIDAR_FILES = ("dem.tif", "dsm.tif", "ndsm.tif", "dsm_crowns.tif", "crowns.gpkg")


def copy_demo(src: Path, dst: Path) -> None:
    from eval_true_ortho import copy_project

    copy_project(src, dst, LIDAR_FILES)


def make_dom(project: Path, true_ortho: bool, crs: str | None) -> dict:
    """Rectify (the chain's true ortho, or conventional on the DEM) into ``crs`` (None: the project CRS) and mosaic
    (``eval_true_ortho_occlusion.make_dom``), check against truth/ortho.tif; times and the check's figures."""
    import eval_true_ortho_occlusion as E

    from ortho.block import read_index
    from ortho.check import run_check

    lo = project / "lidar_out"
    made = E.make_dom(project, true_ortho, occlusion_dsm=lo / "dsm_crowns.tif", crowns=lo / "crowns.gpkg", crs=crs)
    rect = {k: round(made["rectify"][k], 2) for k in ("wall_s", "cpu_s", "frame_ortho_mp")}
    rect.update(cpu_s_per_mp=round(made["rectify"]["cpu_s_per_mp"], 4),
                crs=read_index(project).grids[0].crs.to_string())
    check = run_check(project, reference_path=project / "truth" / "ortho.tif", allow_ballpark=crs is not None)
    report = json.loads((project / "ortho" / "dom_report.json").read_text())
    figures = {"open_ground": {k: report["displacement"].get(k) for k in ("count", "rms_xy_m", "median_xy_m")},
               "roofs": None if check.roofs is None else
               {k: (report.get("roofs") or {}).get(k) for k in ("count", "rms_xy_m", "median_xy_m")},
               "roof_corners": check.roof_corners, "reference_operation": report.get("reference_operation")}
    return {"rectify": rect, "mosaic": {k: round(v, 2) for k, v in made["mosaic"].items()}, "check": figures,
            "cells_seen_by_no_frame": made["summary"].get("cells_seen_by_no_frame"),
            "cells_on_objects": made["summary"].get("cells_on_objects")}


def main() -> None:
    import eval_true_ortho_fill as F
    import eval_true_ortho_occlusion as E

    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--demo", type=Path, required=True, help="a demo project after aerotri run")
    ap.add_argument("--crs", default="gk3:cgcs2000", help="the contract CRS (ortho rectify --crs)")
    ap.add_argument("--work", type=Path, default=REPO / "out" / "true_ortho_crs")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "true_ortho_crs.json")
    ap.add_argument("--key", default="demo")
    ap.add_argument("--reuse", action="store_true", help="measure the DOMs an earlier run left in --work")
    args = ap.parse_args()
    out = {"project": str(args.demo), "contract_crs": args.crs, "grids": {}}
    cpu0 = time.process_time()
    for tag, crs in (("project_crs", None), ("contract_crs", args.crs)):
        made = {}
        for way, true_ortho in (("conventional", False), ("true_ortho", True)):
            p = args.work / tag / way
            kept = p / "made.json"
            if args.reuse and kept.exists():
                made[way] = json.loads(kept.read_text())
                continue
            copy_demo(args.demo, p)
            made[way] = make_dom(p, true_ortho, crs)
            kept.write_text(json.dumps(made[way], indent=1, default=str) + "\n")
            print(tag, way, json.dumps(made[way]), flush=True)
        conv = args.work / tag / "conventional"
        grid = OrthoGrid.union(read_index(conv).grids)
        truth = E.Truth(conv)
        kind, ground, roof, vis, foot_nadir, masks = E.truth_on_grid(truth, conv, grid)
        res = {"grid": {"crs": grid.crs.to_string(), "res_m": grid.res_m, "width": grid.width, "height": grid.height},
               "ways": made}
        fill = F.measure_block(args.work, tag, truth=truth, truth_arrays=(kind, ground, roof, vis, foot_nadir))
        res["true_ortho_fill"] = {k: fill[k] for k in ("occluded_in_nadir_most_frame", "seen_by_another_frame",
                                                       "filled_from_a_frame_that_sees", "fill_share", "misses")}
        for way in ("conventional", "true_ortho"):
            m = E.measure_way(args.work / tag / way, truth, grid, kind, ground, roof, vis, foot_nadir, masks)
            res["ways"][way]["ghosts"] = m["ghosts"]
            res["ways"][way]["seams"] = {k: v for k, v in m["seams"].items()
                                         if k not in ("pairs", "roofs_crossed_detail")}
        out["grids"][tag] = res
        print(tag, json.dumps({k: v for k, v in res.items() if k != "ways"}), flush=True)
    out["commit"] = git_commit(REPO)
    out["command"] = "python bench/eval_true_ortho_crs.py " + " ".join(sys.argv[1:])
    out["cpu_s"], out["load_avg_1min_at_end"] = round(time.process_time() - cpu0, 1), os.getloadavg()[0]
    store_result(args.out, out, key=args.key)


if __name__ == "__main__":
    main()
