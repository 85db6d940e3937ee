"""Same behaviour of the compliance section (issue 40): every judgement of a grid of made-up figures under every
standard, class and terrain, made by two code trees, compared line by line.

The grid: 24 figure sets (AT, DOM and line-map check points with plan RMSE 0.03 / 0.3 / 2.5 m, height RMSE 0.05 /
0.6 m, 10 or 40 check points, their own accuracy unknown or 1 cm; LiDAR NVA, VVA, swath and density derived from
them) and one without figures, judged under asprs2023 (H5 V10, H10 V20, no class), usgs-lbs (QL0-QL3, the default
level, an unknown level), cn-at and thesis (1:500 .. 1:10000, the default scale, an unknown scale), each on the four
terrain classes: the ``Choice`` (or the option error) and the whole ``Compliance`` record of each.

    git archive REV aerotri lidarctl ortho | tar -x -C /tmp/before
    python bench/eval_same_compliance.py --before /tmp/before --json bench/results/RESULT.json [--what TEXT]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def emit() -> None:
    """Print every judgement of the grid (runs on the code tree of ``PYTHONPATH``)."""
    import itertools
    from types import SimpleNamespace

    from aerotri.core.errors import OptionError
    from aerotri.core.tolerances import load_table
    from aerotri.qa.compliance import CheckSet, Figures, LidarFigures, choose, judge

    qa = SimpleNamespace(standard=None, accuracy_class=None, horizontal_class_cm=None, vertical_class_cm=None,
                         map_scale=None, terrain=None)
    table = load_table("1:5000", "flat")
    figs = []
    for h, v, n, cp in itertools.product((0.03, 0.3, 2.5), (0.05, 0.6), (10, 40), (None, 0.01)):
        cs = CheckSet(rmse_h_m=h, rmse_v_m=v, n_h=n, n_v=n, cp_rmse_h_m=cp, cp_rmse_v_m=cp, cp_source="t")
        lf = LidarFigures(nva_rmse_m=v / 3, n_nva=n, vva_p95_m=v, vva_rmse_m=v / 2, n_vva=n // 2, cp_rmse_v_m=cp,
                          swath_rmsdz_m=h / 10, anpd_per_m2=1.0 / h)
        figs.append(Figures(at=cs, dom=cs, line_map=cs, lidar=lf))
    figs.append(Figures(at=CheckSet(), lidar=LidarFigures()))
    cases = ([("asprs2023", c) for c in ("H5 V10", "H10cm V20cm", None)]
             + [("usgs-lbs", c) for c in ("QL0", "ql1", "QL2", "QL3", None, "QL9")]
             + [(s, c) for s in ("cn-at", "thesis") for c in ("1:500", "1:2000", "1:5000", "1:10000", None, "1:3")])
    for std, cls in cases:
        for terrain in ("flat", "hilly", "mountainous", "high_mountain"):
            try:
                choice = choose(std, cls, table, None, qa, terrain)
            except OptionError as exc:
                print("OptionError", std, cls, terrain, exc)
                continue
            print(choice)
            for f in figs:
                print(judge(f, choice))


def side(code: Path) -> list[str]:
    env = dict(os.environ, PYTHONPATH=str(code))
    out = subprocess.run([sys.executable, "-P", __file__, "--emit"], env=env, capture_output=True, text=True,
                         check=True)
    return out.stdout.splitlines()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="folder holding the before side's packages (required)")
    ap.add_argument("--after", type=Path, default=ROOT, help="the after side (default: this checkout)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--what", default="", help="what the two sides are (recorded), e.g. the commits")
    ap.add_argument("--emit", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.emit:
        emit()
        return
    if args.before is None:
        ap.error("--before is required")
    before, after = side(args.before), side(args.after)
    differ = [i for i, (a, b) in enumerate(zip(before, after)) if a != b]
    result = {"what": args.what, "before": str(args.before), "after": str(args.after), "lines_before": len(before),
              "lines_after": len(after), "choices": sum(ln.startswith("Choice(") for ln in after),
              "option_errors": sum(ln.startswith("OptionError") for ln in after),
              "judgements": sum(ln.startswith("Compliance(") for ln in after),
              "identical": before == after, "first_differences": [(i, before[i], after[i]) for i in differ[:5]]}
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
