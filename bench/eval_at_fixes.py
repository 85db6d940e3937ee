"""at-fixes: the adjustment and its verdict in a feet CRS against the same block in metres, and the verdict's common
height offset note on demo runs.

1. The seed-11 geometric block of tests/aerotri/adjust/test_report_units.py (2 strips x 5 frames, 5 control, 6 check
   points) written in EPSG:32649 and copied into the same UTM zone in international feet (coordinates / 0.3048);
   both adjusted (gnss_correction "shift", 0.3 px): control and check residuals in metres, sigma0, verdict, tolerance
   findings, and the accuracy report's (``aerotri report``, 1:2000 flat) AT rows.
2. ``--pair NAME=M,FT``: the reviewer's copy of that block (/work/tmp/review-s1/feet, m/ and ft/) adjusted by
   main's code (``PYTHONPATH=<git archive main>``) and by this branch's: the control held 3.3 x too tightly in feet.
3. ``--demo NAME=PROJECT ...``: adjusted demo copies (their at/report.json as written), whose common height offset
   note, check plan RMS, findings and dropped-point counts are recorded (the lever arm z 1 m off, camera.toml's focal
   length 117 / 123 mm, focal estimated).

    .venv/bin/python bench/eval_at_fixes.py --out bench/results/at_fixes.json \\
        --pair main=/work/tmp/at-fixes/feetmain/m,/work/tmp/at-fixes/feetmain/ft \\
               branch=/work/tmp/at-fixes/feet/m,/work/tmp/at-fixes/feet/ft \\
        --demo lever_z_1m_off=/work/tmp/at-fixes/at_lever_new ...   (an at/ folder or a project)
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.aerotri.adjust.test_report_units import FT, _to_feet  # noqa: E402


def block_pair(work: Path) -> dict:
    from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
    from aerotri.adjust.report_record import read_adjustment_report
    from aerotri.qa.report import build_qa_report
    from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

    m = write_block_project(geometric_block(2, 5, seed=11), work / "m")
    write_truth_observations(m, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=6, seed=5)
    _to_feet(m, work / "ft")
    out = {}
    for u in ("m", "ft"):
        r = run_adjustment(work / u, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3), html=False)
        d = json.loads(r.report_path.read_text())
        f = FT if u == "ft" else 1.0
        ctrl = {c["id"]: [None if x is None else round(x * f, 4) for x in c["residual_m"]] for c in d["control_points"]}
        rec = read_adjustment_report(r.report_path)
        qa = build_qa_report(work / u, scale="1:2000", terrain="flat")
        out[u] = {
            "crs": d["crs"], "sigma0_um": d["key_statistics"]["sigma0_um"],
            "control_residual_m": ctrl, "control_rms_m": [round(x, 4) for x in rec.control_rms_m],
            "check_rms_m": [round(x, 4) for x in rec.check_rms_m], "check_normalised_rms": d["check_normalised_rms"],
            "verdict": d["key_statistics"]["verdict"], "message": d["key_statistics"]["message"],
            "tolerances_exceeded": d["key_statistics"]["tolerances_exceeded"],
            "qa_rows": {c.id: {"value": c.value, "limit": c.limit, "verdict": c.verdict} for c in qa.checks
                        if c.id.startswith(("control_rms", "check_rms", "check_gross", "solution_successful"))},
        }
    a, b = (np.array([v for v in out[u]["control_residual_m"].values()], dtype=float) for u in ("m", "ft"))
    out["largest_control_residual_difference_m"] = round(float(np.nanmax(np.abs(a - b))), 5)
    return out


def demo_run(path: Path) -> dict:
    at = path / "at" if (path / "at" / "report.json").is_file() else path
    d = json.loads((at / "report.json").read_text())
    ks, c = d["key_statistics"], d["counts"]
    msg = ks["message"]
    note = re.search(r"The height shifts of all .*?(?=(Beyond the tolerances|Sigmas too small|$))", msg)
    return {"report": str(at / "report.json"), "check_plan_rms_m": d["parameters"]["rms_check_m"][3],
            "plan_limit_m": d["parameters"]["rms_limits_m"][3],
            "self_calibration": (d.get("self_calibration") or {}).get("estimated", []),
            "common_height_note": note.group(0).strip() if note else None,
            "focal_named_likely": "the focal length is the likely cause" in msg,
            "tolerances_exceeded": ks["tolerances_exceeded"],
            "dropped": {k: c.get(k) for k in ("tie_points_dropped", "tie_points_dropped_single_ray",
                                              "tie_points_dropped_parallel_rays", "observations_unused")}}


def report_pair(m_path: Path, ft_path: Path) -> dict:
    """The same block's at/report.json in metres and in feet (adjusted elsewhere, e.g. by another version of the
    code): residuals and RMS in metres side by side, and the verdicts."""
    out = {}
    for u, p in (("m", m_path), ("ft", ft_path)):
        at = p / "at" if (p / "at" / "report.json").is_file() else p
        d = json.loads((at / "report.json").read_text())
        f = FT if u == "ft" else 1.0
        out[u] = {"report": str(at / "report.json"), "sigma0_um": d["key_statistics"]["sigma0_um"],
                  "control_residual_m": {c["id"]: [None if x is None else round(x * f, 4) for x in c["residual_m"]]
                                         for c in d["control_points"]},
                  "control_rms_m": [round(x * f, 4) for x in d["rms_control_ground_m"]],
                  "check_rms_m": [round(x * f, 4) for x in d["check_rms_m"]],
                  "check_normalised_rms": d["check_normalised_rms"], "verdict": d["key_statistics"]["verdict"],
                  "tolerances_exceeded": d["key_statistics"]["tolerances_exceeded"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench/results/at_fixes.json")
    ap.add_argument("--demo", nargs="*", default=[], help="NAME=PATH of an adjusted demo copy (project or at/)")
    ap.add_argument("--pair", nargs="*", default=[],
                    help="NAME=M_PATH,FT_PATH: one block's reports in metres and feet (e.g. adjusted by main's code)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        res = {"feet_block": block_pair(Path(tmp))}
    res["demo"] = {k: demo_run(Path(v)) for k, v in (s.split("=", 1) for s in a.demo)}
    res["pairs"] = {k: report_pair(*map(Path, v.split(","))) for k, v in (s.split("=", 1) for s in a.pair)}
    Path(a.out).write_text(json.dumps(res, indent=1, default=float) + "\n")
    fb = res["feet_block"]
    print(f"m / ft: check RMS {fb['m']['check_rms_m']} / {fb['ft']['check_rms_m']} m, verdict {fb['m']['verdict']} / "
          f"{fb['ft']['verdict']}, control residuals differ by <= {fb['largest_control_residual_difference_m']} m")
    for k, v in res["demo"].items():
        print(f"{k}: check plan RMS {v['check_plan_rms_m']} m (limit {v['plan_limit_m']}), focal named likely "
              f"{v['focal_named_likely']}, dropped {v['dropped']}")


if __name__ == "__main__":
    main()
