"""The principal point against the GNSS (aerotri.adjust.determinability, small-fixes3) on simulated flat 3 x 6 DMC
blocks flown in alternating directions (tests/aerotri/adjust/test_determinability.py's ``_lag_block``): how often the
principal point is flagged with no lag (the a-priori camera the true one), with a GNSS lag of 0.004 and 0.01 s at
70 m/s (0.28 and 0.7 m along the track, an offset fixed in the camera), GNSS only and with 4 full control points;
seeds 0-19 (the rule's limit, 5 sigma, was set before any of them ran: seeds 0-9 and 10-19 are scored apart).
Writes bench/results/pp_gnss.json. Run: .venv/bin/python bench/eval_pp_gnss.py (about a minute)."""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "aerotri" / "adjust"))

import test_determinability as T  # noqa: E402

SEEDS = range(20)


def run(lag_s: float, n_control: int) -> dict:
    rows = []
    for seed in SEEDS:
        with tempfile.TemporaryDirectory() as d:
            ba = T._lag_block(Path(d), seed, lag_s, n_control)
        pp = {c.group: c for c in ba.calibration_checks}["pp"]
        move = pp.estimate["v0_px"] - pp.apriori["v0_px"]
        rows.append({"seed": seed, "action": pp.action, "v0_move_px": round(move, 3),
                     "v0_move_sigmas": round(move / pp.sigma["v0_px"], 2),
                     "offset_named_m": round(move / pp.gnss_offset_px_per_m[1], 4),
                     "offset_correlation_v0": round(pp.gnss_offset_correlation[1], 5)})
    flagged = lambda rs: sum(r["action"] == "flagged" for r in rs)  # noqa: E731
    return {"injected_lag_s": lag_s, "injected_offset_m": round(T.LAG_SPEED_MPS * lag_s, 3), "control_points": n_control,
            "flagged_seeds_0_9": flagged(rows[:10]), "flagged_seeds_10_19": flagged(rows[10:]), "blocks": len(rows),
            "max_abs_move_sigmas": max(abs(r["v0_move_sigmas"]) for r in rows), "rows": rows}


def main() -> None:
    out = {"cases": [run(lag, n) for n in (0, 4) for lag in (0.0, 0.004, 0.01)]}
    path = Path(__file__).resolve().parent / "results" / "pp_gnss.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    for c in out["cases"]:
        print(f"lag {c['injected_lag_s']} s ({c['injected_offset_m']} m), control {c['control_points']}: flagged "
              f"{c['flagged_seeds_0_9']}/10 + {c['flagged_seeds_10_19']}/10, largest move "
              f"{c['max_abs_move_sigmas']} sigma")


if __name__ == "__main__":
    main()
