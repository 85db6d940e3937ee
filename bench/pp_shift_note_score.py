"""pp_shift_note (aerotri/adjust/report.py) scored on geometric_block runs (pp + per-strip GNSS shifts, 1-4 strips).

Per run with suspect plan shifts, the truth "the pp's" when the suspect plan shifts' error (estimate - the
simulator's shift, RMS) is at least half their RMS (not the GNSS's) and at least halves in the same adjustment
without pp (the pp's); the old rule is the correlation alone (trial-at), the new one ``pp_shift_note``.
Usage: .venv/bin/python bench/pp_shift_note_score.py SEED... (review 21: PP_SHIFT_SHARE chosen on seeds 1-3, scored
on 4-8); counts per rule and block kind to bench/results/pp_shift_note_score.json (keyed by the seeds)."""

from __future__ import annotations

import json
import logging
import pathlib
import sys
import tempfile

import numpy as np

from aerotri.adjust.determinability import CORRELATION_LIMIT
from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.adjust.report import gnss_correction_check, pp_shift_note
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3
BLOCKS = ((1, 8, 5), (2, 8, 5), (3, 6, 5), (4, 6, 4), (1, 10, 3))  # strips, frames per strip, control points


def main(seeds: list[int]) -> dict:
    logging.disable(logging.WARNING)
    tally: dict[str, list[int]] = {}
    work = tempfile.TemporaryDirectory()
    for seed in seeds:
        for strips, per, n_control in BLOCKS:
            block = geometric_block(strips, per, seed=seed)
            root = write_block_project(block, pathlib.Path(work.name) / f"s{seed}_{strips}x{per}_{n_control}")
            write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=n_control, points_per_image=80,
                                     n_check=6, seed=seed)
            ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX,
                                                     self_calibration=("pp",)))
            gcc = gnss_correction_check(ba)
            c = next(c for c in ba.calibration_checks if c.group == "pp")
            true = block.gnss_shift_m
            sus = [(s, "EN".index(a), v) for s, t, a, v in gcc.suspect if a in "EN" and t == "shift"]
            if not sus:
                continue
            nopp = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX))

            def err(shift):
                return np.sqrt(np.mean([(shift[s - 1][a] - true[s - 1][a]) ** 2 for s, a, _v in sus]))

            rms_v = np.sqrt(np.mean([v ** 2 for _s, _a, v in sus]))
            e_pp = err(ba.result.state.shift)
            label = e_pp >= 0.5 * rms_v and err(nopp.result.state.shift) <= 0.5 * e_pp
            old = any(r is not None and r > CORRELATION_LIMIT for r in c.gnss_shift_correlation)
            new = pp_shift_note(ba, gcc) is not None
            kind = "1 strip" if strips == 1 else "2-4 strips"
            for rule, fired in (("old", old), ("new", new)):
                t = tally.setdefault(f"{rule} {kind}", [0, 0, 0, 0])  # TP FP FN TN
                t[(0 if label else 1) if fired else (2 if label else 3)] += 1
    work.cleanup()
    return {k: dict(zip(("TP", "FP", "FN", "TN"), v)) for k, v in sorted(tally.items())}


if __name__ == "__main__":
    seeds = [int(a) for a in sys.argv[1:]]
    out = main(seeds)
    print("seeds", seeds, json.dumps(out))
    path = pathlib.Path(__file__).parent / "results" / "pp_shift_note_score.json"
    path.parent.mkdir(exist_ok=True)
    done = json.loads(path.read_text()) if path.exists() else {}
    done[" ".join(map(str, seeds))] = out
    tmp_path = path.with_suffix(".json.tmp")
    tmp_path.write_text(json.dumps(done, indent=1) + "\n")
    tmp_path.replace(path)
