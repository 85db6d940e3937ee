"""False alarms and detections of the GNSS direction check (aerotri.adjust.gnss_direction) on simulated 8 x 25 blocks
(strips alternate east / west, 4 each way) whose GNSS carries a bias per strip (the simulator's own error model:
``gnss_shift_sigma_m``), for each ``gnss_correction``; the check before s11-fixes (the photos' scatter / n, read from
``--old`` a copy of that module) beside the current one (the strips' spread), on the same adjusted blocks, seeds 0-19.
Detections: a lag of 0.01, 0.004, 0.002 s at 70 m/s injected into gnss.txt (0.02 m strip biases, no correction).
Writes bench/results/gnss_direction_strips.json. Run: nice .venv/bin/python bench/eval_gnss_direction_strips.py
[--old path/to/old_gnss_direction.py] (about 15 min on one core)."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from aerotri.adjust.gnss_direction import direction_check
from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SEEDS = range(20)
SPEED_MPS = 70.0
SETTINGS = AdjustSettings(image_sigma_px=0.3, use_control=False, point_covariances=False)


def adjusted(seed: int, bias_m: float, correction: str, lag_s: float = 0.0, strips: int = 8, frames: int = 25):
    b = geometric_block(strips, frames, seed=seed, gnss_shift_sigma_m=bias_m, gnss_drift_sigma_m_per_km=0.0,
                        lever_arm_m=(0.0, 0.0, 0.0))
    b.camera_nominal = b.camera_true
    east = np.asarray(b.strip) % 2 == 0
    b.gnss_local = b.gnss_local + np.outer(np.where(east, 1.0, -1.0) * SPEED_MPS * lag_s, [1.0, 0.0, 0.0])
    # a shift per strip needs control for the datum (4 points, used); its a-priori sigma the biases' (0.01 m at least)
    per_strip = correction in ("shift", "shift_drift")
    st = dataclasses.replace(SETTINGS, gnss_correction=correction, use_control=per_strip,
                             gnss_shift_sigma_m=max(bias_m, 0.01))
    with tempfile.TemporaryDirectory() as d:
        root = write_block_project(b, Path(d) / "b")
        write_truth_observations(root, tie_sigma_px=0.3, n_control=4 if per_strip else 0, n_check=0,
                                 points_per_image=60, seed=seed)
        return adjust_project(root, st), st


def checks(ba, st, old):
    """(old, new) significant, called as build_report calls the check."""
    kw = dict(self_calibration=ba.opts.self_calibration,
              strip_shift_sigma_m=st.gnss_shift_sigma_m if st.gnss_correction in ("shift", "shift_drift") else 0.0)
    new = direction_check(ba.block, ba.result.state, SPEED_MPS, **kw).significant
    return (old.direction_check(ba.block, ba.result.state, SPEED_MPS, **kw).significant if old else None), new


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--old", help="the module before s11-fixes (git show 5af65953:aerotri/adjust/gnss_direction.py)")
    a = ap.parse_args()
    old = None
    if a.old:
        spec = importlib.util.spec_from_file_location("old_gnss_direction", a.old)
        old = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = old  # its dataclasses look their module up
        spec.loader.exec_module(old)
    out = []
    cases = [(bias, corr, 0.0) for bias in (0.0, 0.02, 0.3) for corr in ("none", "offset", "shift", "shift_drift")]
    cases += [(0.02, "none", lag) for lag in (0.01, 0.004, 0.002)]
    for bias, corr, lag in cases:
        res = [checks(*adjusted(seed, bias, corr, lag), old) for seed in SEEDS]
        row = {"strip_bias_sigma_m": bias, "gnss_correction": corr, "lag_s": lag, "blocks": len(res),
               "alarms_before": sum(bool(r[0]) for r in res) if old else None, "alarms_after": sum(r[1] for r in res)}
        print(json.dumps(row), flush=True)
        out.append(row)
    path = Path(__file__).resolve().parent / "results" / "gnss_direction_strips.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"block": "8 x 25, 4 strips each way", "seeds": len(SEEDS), "cases": out}, indent=1))
    tmp.replace(path)


if __name__ == "__main__":
    main()
