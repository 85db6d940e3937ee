"""CPU of the DOM check (``ortho check``, the chain's dom_check stage) before and after a change, and whether its
report's numbers stayed the same (issue 41, branch domcheck-speed).

Runs ``ortho.check.run_check`` as the chain does (the project's [dom_check] settings, the reference orthophoto
truth/ortho.tif, the report written to a scratch stem: the project is only read) on the demo (``--demo-runs`` times,
the median CPU-s reported) and on a full-size block (``--block``, once), recording the process CPU (every thread:
GDAL's warper and OpenCV run threads), the wall time and the load average around each run. Each run is stored
under ``--label`` in bench/results/dom_check_speed.json (the labels of earlier invocations kept); when the file holds
"before" and "after", every number of their dom_report.json files is compared (the largest difference, the keys that
differ, patch counts identical or not).

The "before" label runs the code of the base commit from a copy of its packages on PYTHONPATH (a shared checkout's
code must not change under a run: docs/full-size-block.md):

    git archive <base> aerotri ortho lidarctl | tar -x -C /work/tmp/domcheck-speed/base
    PYTHONPATH=/work/tmp/domcheck-speed/base nice -n 10 .venv/bin/python bench/dom_check_speed.py --label before ...
    nice -n 10 .venv/bin/python bench/dom_check_speed.py --label after ...
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE / "results" / "dom_check_speed.json"
# keys of dom_report.json that name files or settings, not measurements
NOT_NUMBERS = {"json", "plot", "dom", "reference", "ndsm", "settings", "mosaic_fingerprint", "corners_from"}


def run_once(project: Path, stem: Path, reference: Path | None = None) -> dict:
    """One ``run_check`` of the project's mosaic against truth/ortho.tif (the chain's call): CPU-s of the process
    (every thread), wall s, load averages before and after, the report's path."""
    from ortho.check import run_check

    load0 = os.getloadavg()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    run_check(project, None, reference_path=reference or project / "truth" / "ortho.tif", out_stem=stem)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    return {"cpu_s": round(cpu, 2), "wall_s": round(wall, 2), "load_before": [round(v, 2) for v in load0],
            "load_after": [round(v, 2) for v in os.getloadavg()], "report": str(stem.with_suffix(".json"))}


def numbers(d, path=""):
    """Every number of a dom_report.json document by its key path (lists by index; file names and settings left out)."""
    if isinstance(d, dict):
        for k, v in d.items():
            if k not in NOT_NUMBERS:
                yield from numbers(v, f"{path}.{k}" if path else k)
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from numbers(v, f"{path}[{i}]")
    elif isinstance(d, (int, float)) and not isinstance(d, bool):
        yield path, float(d)
    elif isinstance(d, str):
        yield path, d


def compare(before_path: str, after_path: str) -> dict:
    """The largest difference of the two reports' numbers, the keys that differ (up to 20), counts identical."""
    a = dict(numbers(json.loads(Path(before_path).read_text())))
    b = dict(numbers(json.loads(Path(after_path).read_text())))
    differ, largest = [], 0.0
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            differ.append((k, a.get(k), b.get(k)))
            continue
        if isinstance(a[k], str) or isinstance(b[k], str):
            if a[k] != b[k]:
                differ.append((k, a[k], b[k]))
            continue
        if a[k] != b[k]:
            differ.append((k, a[k], b[k]))
            largest = max(largest, abs(a[k] - b[k]))
    counts = [k for k, _, _ in differ if k.split(".")[-1] in ("count", "patches", "patches_total", "textured",
                                                                "unmatched", "examined", "unsettled", "one_direction",
                                                                "patches_listed", "in_nodata", "weak",
                                                                "outside_or_invalid", "corners")]
    return {"numbers": len(a), "identical": not differ, "largest_difference": largest, "keys_differing": len(differ),
            "counts_identical": not counts, "first_differing": [list(x) for x in differ[:20]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--label", required=True, help="before / after")
    ap.add_argument("--demo", type=Path, help="the demo project (a copy: read only here)")
    ap.add_argument("--demo-runs", type=int, default=3)
    ap.add_argument("--block", type=Path, help="a full-size block's run (read only: the report goes to --scratch)")
    ap.add_argument("--block-reference", type=Path, help="the block's reference orthophoto [<block>/truth/ortho.tif]")
    ap.add_argument("--scratch", type=Path, default=Path("/work/tmp/domcheck-speed"))
    args = ap.parse_args()
    import ortho

    runs = {}
    runs["code"] = str(Path(ortho.__file__).parent)
    runs["commit"] = subprocess.run(["git", "-C", str(HERE), "rev-parse", "HEAD"], capture_output=True,
                                    text=True).stdout.strip()
    if args.demo:
        demo = [run_once(args.demo, args.scratch / f"demo_{args.label}_{k}" / "dom_report")
                for k in range(args.demo_runs)]
        runs["demo"] = {"project": str(args.demo), "runs": demo,
                        "median_cpu_s": statistics.median(r["cpu_s"] for r in demo)}
        print(f"demo {args.label}: CPU-s {[r['cpu_s'] for r in demo]}", flush=True)
    if args.block:
        one = run_once(args.block, args.scratch / f"block_{args.label}" / "dom_report", args.block_reference)
        runs["block"] = {"project": str(args.block), **one}
        print(f"block {args.label}: CPU-s {one['cpu_s']}", flush=True)
    # read again: another invocation (the block's run beside the demo's) may have written since
    rec = json.loads(OUT.read_text()) if OUT.is_file() else {}
    rec.setdefault("runs", {}).setdefault(args.label, {}).update(runs)
    allruns = rec["runs"]
    # each "before..." label against its "after..." (a paired run: both at once, under the same load)
    comparisons = {}
    for label in [k for k in allruns if k.startswith("before") and k.replace("before", "after", 1) in allruns]:
        eq = comparisons.setdefault(label.replace("before", "", 1) or "unpaired", {})
        for what in ("demo", "block"):
            b, a = allruns[label].get(what), allruns[label.replace("before", "after", 1)].get(what)
            if b and a:
                rb = b["runs"][0]["report"] if what == "demo" else b["report"]
                ra = a["runs"][0]["report"] if what == "demo" else a["report"]
                cb = b["median_cpu_s"] if what == "demo" else b["cpu_s"]
                ca = a["median_cpu_s"] if what == "demo" else a["cpu_s"]
                eq[what] = {"cpu_s_before": cb, "cpu_s_after": ca, "speedup": round(cb / ca, 2),
                            "report": compare(rb, ra)}
    if comparisons:
        rec["comparison"] = comparisons
        print(json.dumps({k: {w: {a: b for a, b in v.items() if a != "report"} for w, v in e.items()}
                          for k, e in comparisons.items()}, indent=1))
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps(rec, indent=1) + "\n")


if __name__ == "__main__":
    sys.exit(main())
