"""Benchmark: the chain's DOM check stage again on a finished ``bench/scale.py`` run -> results/dom_check_bench.json.

The stage (``ortho.check.run_check``: NCC patches of the DOM against the true orthophoto, by 2048 px blocks,
plus the seam misalignment between neighbouring frame orthos) is timed on the run folder's mosaic, frames
and nDSM, its report written outside the run (``--out``, the run folder is not modified), and set beside the
stage's own record in the run's ``work/run_summary.json``: wall and CPU seconds, peak RSS, patches and RMS
then and now. The chain total with the stage re-measured is the run's other stages' wall time plus the new
stage; it is a composite of two runs (the other stages are not re-run) and labelled so in the JSON.

Usage: python bench/dom_check.py [--size full|quarter|eighth] [--run DIR] [--reference TIF]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aerotri.core.resources import measure  # noqa: E402

BLOCKS = Path(os.environ.get("AEROTRI_BENCH_BLOCKS", "/work/bench_blocks"))
SUFFIX = {"full": "", "quarter": "_quarter", "eighth": "_eighth"}


def _summary(report: dict) -> dict:
    d, s = report.get("displacement", {}), report.get("seams") or {}
    return dict(patches=d.get("count"), rms_xy_m=d.get("rms_xy_m"), seam_patches=s.get("patches"),
                seam_rms_px=s.get("rms_px"), seams=len(s.get("per_seam", [])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=list(SUFFIX), default="full")
    ap.add_argument("--run", type=Path, help="the chain's run folder (default: $AEROTRI_BENCH_BLOCKS/scale[_SIZE]_run)")
    ap.add_argument("--reference", type=Path, help="true orthophoto (default: the block's truth/ortho.tif)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "dom_check_bench.json")
    a = ap.parse_args(argv)
    run = a.run or BLOCKS / f"scale{SUFFIX[a.size]}_run"
    reference = a.reference or BLOCKS / f"scale{SUFFIX[a.size]}" / "truth" / "ortho.tif"
    ndsm = run / "lidar_out" / "ndsm.tif"
    for p in (run / "ortho" / "mosaic.tif", reference, ndsm, run / "work" / "run_summary.json"):
        if not p.exists():
            sys.exit(f"{p}: not found (run `python bench/scale.py --size {a.size}` first)")

    from ortho.check import run_check

    chain = json.loads((run / "work" / "run_summary.json").read_text())
    before = next((r for r in chain["stages"] if r["stage"] == "dom_check"), None)
    old_report = json.loads((run / "ortho" / "dom_report.json").read_text())
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp, measure() as usage:
        report = run_check(run, reference_path=reference, ndsm_path=ndsm, out_stem=Path(tmp) / "dom_report")
    now = dict(usage.record(), load_average_start=[round(x, 2) for x in load_start],
               load_average_end=[round(x, 2) for x in os.getloadavg()], **_summary(report))
    others_s = sum(r["seconds"] for r in chain["stages"] if r.get("status") == "done" and r["stage"] != "dom_check")
    entry = dict(run=str(run), reference=str(reference),
                 chain_record=dict(wall_s=before.get("seconds"), cpu_s=before.get("cpu_s"),
                                   peak_rss_mb=before.get("peak_rss_mb"), **_summary(old_report)) if before else None,
                 now=now,
                 composite_chain_wall_min=dict(
                     value=round((others_s + now["wall_s"]) / 60.0, 1),
                     note="the run's other stages (not re-run) plus this dom_check; two runs, not one"))
    results = json.loads(a.out.read_text()) if a.out.exists() else {}
    results[a.size] = entry
    a.out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(entry, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
