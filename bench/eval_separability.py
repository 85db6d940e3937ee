"""Blunders the data snooping cannot localise (``aerotri.adjust.solve.SEPARABLE_RHO``): with the rule (a point
whose flagged ray's test correlates beyond 0.9 with another ray's is left out whole) and without (the ray of the
largest w removed, as before), against the simulator's truth.

Geometric blocks of 3 strips x 6 frames (``tests/aerotri/adjust/test_snooping.py``'s), 0.3 px noise, 3 % of the tie
observations with blunders of 5-50 px in random directions, a control point 3 m off; seeds 41-50 (the rule's 0.9 is
the separability level of the literature, not chosen on these blocks; tests/ use seed 11). Per run: blunders left in
the adjusted points, sound rays removed singly, points left out whole (and how many of them held a blunder), and
the largest distance of an adjusted tie point from the same point adjusted without blunders.

    python bench/eval_separability.py [--out bench/results/separability.json]

(The file's ``block_1000_frames`` entry is a measurement of its own, by hand, kept when the script writes again.)
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aerotri.adjust import solve  # noqa: E402
from aerotri.adjust.pipeline import AdjustSettings, adjust_project  # noqa: E402
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations  # noqa: E402

SEEDS = tuple(range(41, 51))
SETTINGS = AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, self_calibration=("pp", "radial"))


def _run(root: Path, rho: float):
    solve.SEPARABLE_RHO = rho
    return adjust_project(root, SETTINGS)


def _points(ba) -> dict:
    """The adjusted tie points (two rays or more left; control points not)."""
    b, r = ba.block, ba.result
    used = np.bincount(b.obs_point[r.obs_active], minlength=b.n_points) >= 2
    used[b.control_point] = False
    return {str(b.point_id[j]): ba.points_map[j] for j in np.flatnonzero(used)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "separability.json")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    rule = solve.SEPARABLE_RHO
    runs = []
    for seed in SEEDS:
        t = Path(tempfile.mkdtemp())
        clean = write_block_project(geometric_block(3, 6, seed=seed), t / "clean")
        write_truth_observations(clean, tie_sigma_px=0.3, n_control=5, points_per_image=120, n_check=10,
                                 seed=seed + 1)
        reference = _points(_run(clean, rule))
        root = write_block_project(geometric_block(3, 6, seed=seed), t / "blk")
        info = write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=120, n_check=10,
                                        seed=seed + 1, blunder_fraction=0.03, blunder_px_range=(5.0, 50.0),
                                        bad_control_shift_m=3.0)
        bad = {tuple(x) for x in info.tie_blunders}
        for name, rho in (("rule", rule), ("without", float("inf"))):
            ba = _run(root, rho)
            b, r = ba.block, ba.result
            ray = lambda x: (str(b.point_id[b.obs_point[x.obs]]), b.image_id[b.obs_image[x.obs]])  # noqa: E731
            single = {ray(x) for x in r.removed if not x.whole_point}
            whole = {ray(x)[0] for x in r.removed if x.whole_point}
            active = {(str(b.point_id[b.obs_point[k]]), b.image_id[b.obs_image[k]])
                      for k in np.flatnonzero(r.obs_active)}
            pts = _points(ba)
            common = sorted(set(pts) & set(reference))
            d = np.linalg.norm(np.array([pts[p] - reference[p] for p in common]), axis=1)
            runs.append({"seed": seed, "snooping": name, "blunders": len(bad), "blunders_left_in": len(bad & active),
                         "sound_rays_removed_singly": len(single - bad),
                         "points_left_out_whole": len(whole), "of_them_with_a_blunder": len(whole & {p for p, _ in bad}),
                         "points_off_over_0_5_m": int(np.sum(d > 0.5)),
                         "largest_point_off_m": round(float(d.max()), 3)})
            print(json.dumps(runs[-1]), flush=True)
        shutil.rmtree(t, ignore_errors=True)
    summary = {}
    for name in ("rule", "without"):
        rs = [x for x in runs if x["snooping"] == name]
        summary[name] = {k: int(sum(x[k] for x in rs)) for k in ("blunders", "blunders_left_in",
                                                                    "sound_rays_removed_singly", "points_left_out_whole",
                                                                    "of_them_with_a_blunder", "points_off_over_0_5_m")}
        summary[name]["largest_point_off_m"] = max(x["largest_point_off_m"] for x in rs)
    kept = {k: v for k, v in (json.loads(args.out.read_text()) if args.out.is_file() else {}).items()
            if k == "block_1000_frames"}
    args.out.write_text(json.dumps({"separable_rho": rule, "seeds": list(SEEDS), "summary": summary, "runs": runs,
                                    **kept}, indent=1) + "\n")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
