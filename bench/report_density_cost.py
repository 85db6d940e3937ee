"""What the usgs-lbs density costs a report that does not test it (review1-fixes): every report, under every
standard, counted the first returns of every LiDAR file (decompressing them) for the LBS density row; now only a
standard with a density row (``compliance.DENSITY_STANDARDS``) counts them.

In one process, alternating, best of ``--repeats``: the CPU time of ``write_qa_report`` (default standard, no PDF)
on a copy of a project folder, and of ``lidar_density`` alone (what each such report spent before), and the ratio.
The folder is copied as a tree of symlinks (the report writes reports/ only, replacing links, never the originals).
Writes bench/results/report_density_cost.json.
Run: .venv/bin/python bench/report_density_cost.py [--project /work/demo2/out/demo/project]
[--work /work/tmp/review1-fixes/bench] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path

from aerotri.core.project import Project
from aerotri.qa.compliance import lidar_density
from aerotri.qa.report import write_qa_report

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=Path("/work/demo2/out/demo/project"))
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/review1-fixes/bench"))
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    folder = args.work / "project"
    shutil.rmtree(folder, ignore_errors=True)
    args.work.mkdir(parents=True, exist_ok=True)
    subprocess.run(["cp", "-rs", str(args.project.resolve()), str(folder)], check=True)
    shutil.rmtree(folder / "reports", ignore_errors=True)
    shutil.copytree(args.project / "reports", folder / "reports")  # real files: the report replaces some
    write_qa_report(folder)  # warm-up: imports, caches
    report_s, density_s = [], []
    for _ in range(args.repeats):
        t = time.process_time()
        rep = write_qa_report(folder)
        report_s.append(time.process_time() - t)
        t = time.process_time()
        density = lidar_density(Project.open(folder))
        density_s.append(time.process_time() - t)
    out = dict(what=__doc__.split("\n\n")[0].replace("\n", " "), project=str(args.project), repeats=args.repeats,
               report_default_standard_cpu_s=min(report_s), lidar_density_cpu_s=min(density_s),
               report_before_estimate_cpu_s=min(report_s) + min(density_s),
               before_over_after=(min(report_s) + min(density_s)) / min(report_s),
               density_per_m2=density[0], density_note=density[1],
               compliance_standard=rep.compliance["name"] if rep.compliance else None,
               all_report_cpu_s=report_s, all_density_cpu_s=density_s)
    path = REPO / "bench" / "results" / "report_density_cost.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if not k.startswith("all_")}, indent=1))


if __name__ == "__main__":
    main()
