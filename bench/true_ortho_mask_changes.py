"""Where two true-ortho rules' frame masks differ, against the simulator's truth (issue 42): for two DOMs of one block
made by ``bench/eval_true_ortho_dsm_cell.py`` (``--work DIR``, the block, two specs), the ground cells (truth) each
frame's mask turns valid or masked from the first rule to the second, split by whether the frame sees the ground there
(the truth's ray cast) or a roof or wall hides it, and each set's distance to the simulator's roof outlines
(truth/buildings.geojson part ``roof_outline``, of ``--src``); and the roof cells (truth) it turns valid or masked.

Usage: python bench/true_ortho_mask_changes.py --work DIR --block tall --src T1 --before '0.5+fp7+cb'
--after '0.5+fp8+cb' --out FILE --key KEY
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from results_json import store_result  # noqa: E402


def main() -> None:
    import shapely

    import eval_true_ortho_occlusion as E
    from ortho.block import read_index
    from ortho.grid import OrthoGrid

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--block", default="tall")
    ap.add_argument("--src", type=Path, required=True, help="the simulated project (truth/buildings.geojson)")
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--key", default="mask_changes")
    args = ap.parse_args()
    W = args.work / args.block
    grid = OrthoGrid.union(read_index(W / "conventional").grids)
    z = np.load(W / "truth_on_grid.npz")
    vis, ground, roof = z["vis"], z["ground"], z["roof"]
    before, _ = E.frame_masks(W / f"true_ortho_dsm_{args.before}", grid)
    after, _ = E.frame_masks(W / f"true_ortho_dsm_{args.after}", grid)
    doc = json.loads((args.src / "truth" / "buildings.geojson").read_text())
    outlines = shapely.union_all([shapely.geometry.shape(f["geometry"]) for f in doc["features"]
                                  if f["properties"]["part"] == "roof_outline"]).boundary
    found: dict = {}
    roofs = {"roof_newly_valid": 0, "roof_newly_masked": 0}
    shape = (grid.height, grid.width)
    for k in range(len(before)):
        a, b = E.place(shape, *before[k][1:]), E.place(shape, *after[k][1:])
        roofs["roof_newly_valid"] += int((roof & ~a & b).sum())
        roofs["roof_newly_masked"] += int((roof & a & ~b).sum())
        hidden, seen = np.isin(vis[k], (E.ROOF, E.WALL)), vis[k] == E.SEES
        for name, sel in (("hidden_newly_valid", ~a & b & hidden), ("hidden_newly_masked", a & ~b & hidden),
                          ("seen_newly_valid", ~a & b & seen), ("seen_newly_masked", a & ~b & seen)):
            r, c = np.nonzero(ground & sel)
            x, y = grid.x_left_m + (c + 0.5) * grid.res_m, grid.y_top_m - (r + 0.5) * grid.res_m
            found.setdefault(name, []).append(shapely.distance(outlines, shapely.points(x, y)))
    out = {"before": args.before, "after": args.after, "dom_cell_m": grid.res_m,
           "command": f"python bench/true_ortho_mask_changes.py --work DIR --block {args.block} --src SRC "
                      f"--before '{args.before}' --after '{args.after}' --key {args.key}",
           "roof_cells_frame_by_frame": roofs}
    for name, d in found.items():
        d = np.concatenate(d)
        out[name] = {"cells_frame_by_frame": int(len(d)), "within_0_05_m_of_the_roof_outline": int((d <= 0.05).sum()),
                     "distance_to_the_roof_outline_m_p50_95": np.percentile(d, [50, 95]).round(3).tolist()
                     if len(d) else None}
    print(json.dumps(out, indent=1))
    store_result(args.out, out, key=args.key)


if __name__ == "__main__":
    main()
