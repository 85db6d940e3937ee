"""Simulator: what the ground refinement (``ClassifySettings.ground_lift_sigma``) costs on a scene
whose truth is exact.

Classifies a simulated project's strips together with the refinement off (0) and, at 4 and 6
sigma, judging the last returns of multi-return pulses only, also the single returns against the
larger of sigma and their neighbours' robust spread (``ground_lift_single``, the default), and
every ground point against sigma alone: ground-filter type I / II errors (ground and water against the
rest, outliers left out), building PA/UA and water. The simulator's strips are unadjusted (height
offsets of a few cm between strips), which is what made the all-points variant lift ground.
Writes bench/results/lidar_ground_lift_sim.json.
Run: .venv/bin/python bench/eval_ground_lift_sim.py [--project DIR]   (default: simulates `tiny`)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np

from lidarctl import io
from lidarctl.classify import pipeline as classify
from lidarctl.checks import classes as evaluate

REPO = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=None)
    args = ap.parse_args()
    project = args.project or Path(tempfile.gettempdir()) / "aerotri_ground_lift_sim_tiny"
    if not (project / "truth" / "lidar").exists():
        subprocess.run([str(REPO / ".venv" / "bin" / "aerotri"), "sim", "--preset", "tiny", "--force", "-q",
                        str(project)], check=True)
    strips = sorted((project / "lidar").glob("*.las"))
    clouds = [io.read_cloud(s) for s in strips]
    truth = np.concatenate([io.read_cloud(project / "truth" / "lidar" / s.name).classification for s in strips])

    def cat(field):
        return np.concatenate([getattr(c, field) for c in clouds])

    x, y, z, inten, rn, nr = (cat(f) for f in ("x", "y", "z", "intensity", "return_number", "number_of_returns"))
    runs = {}
    original = classify.lifted_ground
    # (name, sigma, single returns judged against max(sigma, their neighbours' spread) (shipped),
    #  every ground point judged against sigma alone (the variant the guard replaced))
    variants = [("off", 0.0, False, False)]
    for lift in (4.0, 6.0):
        variants += [(f"multi_return_only_{lift:g}", lift, False, False),
                     (f"single_guarded_{lift:g}", lift, True, False),
                     (f"every_ground_point_judged_{lift:g}", lift, False, True)]
    for name, lift, single, every_point in variants:
        def judged(x_, y_, z_, g, sp, s, intercepted=None, k=12, judge_single=True, _all=every_point):
            return original(x_, y_, z_, g, sp, s, np.ones(len(x_), bool) if _all else intercepted, k,
                            judge_single=judge_single)

        with mock.patch.object(classify, "lifted_ground", judged):
            pred = classify.classify_points(x, y, z, rn, nr, inten, params=dataclasses.replace(
                classify.ClassifySettings(), ground_lift_sigma=lift, ground_lift_single=single))
        keep = ~np.isin(truth, (7, 18))
        err = evaluate.filter_errors(np.isin(pred[keep], (2, 9)), np.isin(truth[keep], (2, 9)))
        b, tb = pred == 6, truth == 6
        runs[name] = {"ground_lift_sigma": lift, "ground_lift_single": single,
                      "every_ground_point_judged": every_point, "bridge_deck_points": int((pred == 17).sum()),
                      "type_i_error_pct": err.type_i_error_pct, "type_i_count": int(err.type_i_count),
                      "type_ii_error_pct": err.type_ii_error_pct, "type_ii_count": int(err.type_ii_count),
                      "total_error_pct": err.total_error_pct,
                      "building_pa_pct": float(100 * (b & tb).sum() / max(tb.sum(), 1)),
                      "building_ua_pct": float(100 * (b & tb).sum() / max(b.sum(), 1)),
                      "water_points_pred": int((pred == 9).sum()), "water_points_truth": int((truth == 9).sum())}
        print(name, json.dumps(runs[name]))
    out = {"project": str(project), "points": int(len(x)), "runs": runs}
    dest = REPO / "bench" / "results" / "lidar_ground_lift_sim.json"
    dest.write_text(json.dumps(out, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
