"""The GNSS direction check (aerotri.adjust.gnss_direction) on simulated 3 x 6 blocks flown in alternating directions
(tests/aerotri/adjust/test_gnss_direction.py's): false alarms without a lag, and the lag the residuals hold with one
(0.004 and 0.01 s at 70 m/s injected into gnss.txt), with and without the principal point self-calibrated, and
without a lag on the nominal camera (principal point 0.015 mm off along the flight axis, not estimated); seeds 0-19.
Writes bench/results/gnss_direction.json. Run: .venv/bin/python bench/eval_gnss_direction.py (about 20 s)."""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "aerotri" / "adjust"))

import test_gnss_direction as T  # noqa: E402

from aerotri.adjust.gnss_direction import direction_check  # noqa: E402
from aerotri.adjust.pipeline import adjust_project  # noqa: E402
from aerotri.sim.observations import write_block_project, write_truth_observations  # noqa: E402

SEEDS = range(20)


def run(lag_s: float, self_cal: tuple, camera_known: bool = True) -> dict:
    rows = []
    for seed in SEEDS:
        with tempfile.TemporaryDirectory() as d:
            root = write_block_project(T._block(seed, lag_s, camera_known), Path(d) / "b")
            write_truth_observations(root, tie_sigma_px=0.3, n_control=0, n_check=0, points_per_image=60, seed=seed)
            ba = adjust_project(root, dataclasses.replace(T.SETTINGS, self_calibration=self_cal))
        c = direction_check(ba.block, ba.result.state, T.SPEED_MPS, self_calibration=self_cal)
        p = c.pairs[0]
        rows.append({"seed": seed, "lag_s": round(p.lag_s, 5), "lag_sigma_s": round(p.lag_sigma_s, 5),
                     "along_significant": p.along_significant, "across_significant": p.across_significant})
    shown = [r["lag_s"] / lag_s for r in rows] if lag_s else []
    return {"injected_lag_s": lag_s, "self_calibration": list(self_cal), "camera_known": camera_known,
            "alarms": sum(r["along_significant"] or r["across_significant"] for r in rows), "blocks": len(rows),
            "share_of_lag_in_residuals": [round(min(shown), 3), round(sorted(shown)[len(shown) // 2], 3),
                                          round(max(shown), 3)] if shown else None, "rows": rows}


if __name__ == "__main__":
    out = [run(lag, sc) for lag in (0.0, 0.004, 0.01) for sc in ((), ("pp",))] + [run(0.0, (), camera_known=False)]
    for r in out:
        print(r["injected_lag_s"], r["self_calibration"], "camera known" if r["camera_known"] else "nominal camera",
              f"alarms {r['alarms']}/{r['blocks']}",
              "share (min, median, max)", r["share_of_lag_in_residuals"])
    path = Path(__file__).resolve().parent / "results" / "gnss_direction.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=1))
    tmp.replace(path)
