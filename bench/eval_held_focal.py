"""The held focal length's test (``aerotri.adjust.held_calibration.held_focal``) against the simulator's truth: how
often a right focal length is flagged, and a wrong one found.

The trial camera's observation-only blocks (``aerotri sim --preset tiny --observations-only``, 300 tie points a frame
at 0.1 px, its Phase One-like camera: tests/aerotri/adjust/test_held_principal_point.py's ``CAMERA``), seeds 11-15,
adjusted with the DEM as surface control and no self-calibration, camera.toml the true camera with focal_mm typed
50 (right), 50.5, 51 and 52.5 (1, 2 and 5 % long). Nothing is chosen here: the test's alpha (0.001) and its 1 %
minimum move are the principal point's and the determinability check's.

    python bench/eval_held_focal.py [--out bench/results/held_focal.json]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aerotri.sim.command import simulate_command  # noqa: E402
from tests.aerotri.adjust.test_held_principal_point import CAMERA, adjust_with_certificate  # noqa: E402

SEEDS = (11, 12, 13, 14, 15)
FOCALS_MM = (50.0, 50.5, 51.0, 52.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "held_focal.json")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    runs = []
    for seed in SEEDS:
        t = Path(tempfile.mkdtemp())
        simulate_command("tiny", t / "blk", seed=seed, observations_only=True, tie_points_per_frame=300,
                         tie_sigma_px=0.1, overrides=CAMERA)
        for f in FOCALS_MM:
            d = t / f"f{f}"
            d.mkdir()
            ba, _ = adjust_with_certificate(t / "blk", d, focal_mm=f)
            h = ba.result.held_focal
            runs.append({"seed": seed, "focal_mm": f, "shift_pct": round(100 * h.shift, 3),
                         "f_statistic": round(h.f_statistic, 2), "f_limit": round(h.f_limit, 2),
                         "flagged": bool(h.rejected)})
            print(json.dumps(runs[-1]), flush=True)
    summary = {f"{f:g}": f"{sum(r['flagged'] for r in runs if r['focal_mm'] == f)} of {len(SEEDS)}" for f in FOCALS_MM}
    args.out.write_text(json.dumps({"flagged_by_focal_mm": summary, "runs": runs}, indent=1) + "\n")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
