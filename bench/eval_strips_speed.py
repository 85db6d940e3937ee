"""Speed and peak memory of `lidarctl strips check` / `adjust` on the >= 20 M point block, this checkout against
an earlier revision (default: the one before the re-gridding of the kept overlap points), and the parameters of
both adjustments compared (the speed-up must not move them beyond noise).

The block is bench/eval_strips.py's (the seed-1 strips with injected errors tiled ``--copies`` times along the
flight lines; made by that script's ``tiled_block`` if missing). Each run is a fresh subprocess (one at a time,
so that its peak RSS, resource.getrusage's ru_maxrss, is its own): the baseline from ``git archive <rev>``
unpacked into the work folder, ours from this checkout. Adjust: the strip model with the default settings
(up to 5 reads, until a step is below 0.1 sigma), as bench/eval_strips.py's speed section.
Writes bench/results/strips_speed.json.
Run: .venv/bin/python bench/eval_strips_speed.py [--baseline-rev 8557c60] [--copies 70] [--work /tmp/eval_strips]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from lidar_common import baseline_tree  # noqa: E402

CHILD = r"""
import json, resource, sys, time, logging
from pathlib import Path
logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s", stream=sys.stderr)
import lidarctl
from lidarctl.strips import adjust as adj
from lidarctl.strips.check import check_strips
what, out, paths = sys.argv[1], Path(sys.argv[2]), [Path(p) for p in sys.argv[3:]]
t0, c0 = time.perf_counter(), time.process_time()
if what == "check":
    s = check_strips(paths, out, png=False)
    res = {}
else:
    s = adj.adjust_strips(paths, out, adj.StripAdjustSettings(), png=False)
    # this checkout returns a StripAdjustResult, a baseline revision before issue 40 a dict of adjust.json
    s = json.loads(s.to_json()) if hasattr(s, "to_json") else s
    res = {k: s[k] for k in ("reads", "observations", "sigma0", "parameters", "check_after", "seconds_read",
                             "seconds_solve", "seconds_write")}
res.update(seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0,
           peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, code=lidarctl.__file__)
print("RESULT " + json.dumps(res))
"""


def run(src: Path, what: str, out: Path, paths) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    load0 = os.getloadavg()[0]
    p = subprocess.run([sys.executable, "-c", CHILD, what, str(out), *map(str, paths)], env=env, text=True, cwd=src,
                       capture_output=True, check=True)
    res = json.loads(next(ln for ln in p.stdout.splitlines() if ln.startswith("RESULT "))[7:])
    res["load_average_1min_before_after"] = [load0, os.getloadavg()[0]]
    res["log"] = [ln for ln in p.stderr.splitlines() if "strip adjustment" in ln]
    assert Path(res["code"]).resolve().is_relative_to(src.resolve()), res["code"]
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline-rev", default="8557c60")
    ap.add_argument("--copies", type=int, default=70)
    ap.add_argument("--work", type=Path, default=Path("/tmp/eval_strips"))
    args = ap.parse_args()
    import eval_strips as ev
    import laspy

    paths = ev.tiled_block(args.work, ev.strips_of(args.work / "seed1_errors_scale"), args.copies)
    n = sum(laspy.open(p).header.point_count for p in paths)
    base = baseline_tree(args.baseline_rev, args.work)
    runs = {}
    for name, src in (("baseline", base), ("ours", REPO)):
        for what in ("check", "adjust"):
            r = run(src, what, args.work / f"speed_{what}_{name}", paths)
            r["points_per_s"] = n / r["seconds"]
            r["points_per_cpu_s"] = n / r["cpu_seconds"]
            runs[f"{what}_{name}"] = r
            print(f"{what} {name}: {r['seconds']:.1f} s ({r['points_per_s']:,.0f} points/s), CPU {r['cpu_seconds']:.1f} s, "
                  f"peak RSS {r['peak_rss_mb']:.0f} MB, load {r['load_average_1min_before_after']}", flush=True)
    a, b = runs["adjust_baseline"], runs["adjust_ours"]
    diff = {k: (b["parameters"][k]["value"] - a["parameters"][k]["value"]) / a["parameters"][k]["sigma"]
            for k in a["parameters"]}
    sig = {k: b["parameters"][k]["sigma"] / a["parameters"][k]["sigma"] - 1.0 for k in a["parameters"]}
    out = {
        "what": "strips check/adjust on the tiled seed-1 block: this checkout against the baseline revision, each "
                "run in its own process (peak RSS its own); adjust = strip model, default settings",
        "baseline_rev": args.baseline_rev, "points": int(n), "strips": len(paths), "copies": args.copies,
        "machine_cores": os.cpu_count(),
        "adjust_speed_ratio_wall": a["seconds"] / b["seconds"], "adjust_speed_ratio_cpu": a["cpu_seconds"] / b["cpu_seconds"],
        "check_speed_ratio_wall": runs["check_baseline"]["seconds"] / runs["check_ours"]["seconds"],
        "adjust_points_per_s_baseline_ours": [a["points_per_s"], b["points_per_s"]],
        "check_points_per_s_baseline_ours": [runs["check_baseline"]["points_per_s"], runs["check_ours"]["points_per_s"]],
        "adjust_peak_rss_mb_baseline_ours": [a["peak_rss_mb"], b["peak_rss_mb"]],
        "reads_baseline_ours": [a["reads"], b["reads"]],
        "parameters_max_abs_difference_in_sigma": max(abs(v) for v in diff.values()),
        "sigmas_max_relative_difference": max(abs(v) for v in sig.values()),
        "check_after_rms_m_baseline_ours": [a["check_after"]["rms_m"], b["check_after"]["rms_m"]],
        "note": "the 2-core machine is shared with other jobs (load averages per run): wall times vary; CPU seconds "
                "and the same-run ratios are the figures to compare",
        "runs": {k: {kk: vv for kk, vv in v.items() if kk != "parameters"} for k, v in runs.items()},
    }
    print(json.dumps({k: v for k, v in out.items() if k != "runs"}, indent=1))
    (REPO / "bench" / "results" / "strips_speed.json").write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
