"""Benchmark: one stage of the chain again on a finished ``bench/scale.py`` run -> bench/results/stage_rerun.json.

After a change to one stage, the whole chain need not run again to see what the stage costs now. The stage
runs on the run folder's own inputs with the project's options, its outputs written into a temporary folder
(the run folder is not modified), and is set beside the stage's record in the run's ``work/run_summary.json``:
wall and CPU seconds, peak RSS, and whether the outputs are the same:

- ``dom_check`` (``ortho.check.run_check``: NCC patches of the DOM against the true orthophoto, by 2048 px
  blocks, plus the seam misalignment between neighbouring frame orthos): patches and RMS then and now;
- ``rasters`` (``lidarctl.rasters.products.write_rasters`` on the classified strips): every raster's cells compared;
- ``corners`` (``lidarctl.corners.roof_corners.corner_control``): corners.csv compared;
- ``classify`` (``lidarctl.tiles.classify_files`` on the strips): points whose class differs from the run's.

The chain total with the stage re-measured is the run's other stages' wall time plus the new stage (plus any
stage re-measured earlier and recorded in the JSON): a composite of runs, labelled so.

Usage: python bench/stage_rerun.py [--stage classify|dom_check|rasters|corners|all] [--size full|quarter|eighth] [--run DIR]
       [--reference TIF]
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


def _dom_check(run: Path, reference: Path, ndsm: Path, tmp: Path) -> dict:
    from ortho.check import run_check
    from ortho.settings import CheckSettings

    run_check(run, CheckSettings(ndsm=ndsm), reference_path=reference, out_stem=tmp / "dom_report")
    return dict(then=_summary(json.loads((run / "ortho" / "dom_report.json").read_text())),
                now=_summary(json.loads((tmp / "dom_report.json").read_text())))


def _options(run: Path):
    from aerotri.chain.options import read_options
    from aerotri.core.project import Project

    project = Project.open(run)
    return project, read_options(project).settings


def _rasters(run: Path, reference: Path, ndsm: Path, tmp: Path) -> dict:
    import numpy as np
    import rasterio

    from lidarctl.rasters.products import write_rasters

    project, options = _options(run)
    written = write_rasters(project.classified_strips(), tmp / "lidar_out", options.rasters.res_m, crs=project.crs)
    differ = []
    for path in written:
        with rasterio.open(path) as a, rasterio.open(run / "lidar_out" / path.name) as b:
            x, y = a.read(), b.read()
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            differ.append(path.name)
    return dict(then={}, now=dict(files=len(written), files_differing_from_the_run=differ))


def _corners(run: Path, reference: Path, ndsm: Path, tmp: Path) -> dict:
    from lidarctl.corners.roof_corners import corner_control

    project, options = _options(run)
    st = corner_control(project.classified_strips(), tmp / "lidar_out", options.corners,
                        record_none=True)
    same = (tmp / "lidar_out" / "corners.csv").read_bytes() == (run / "lidar_out" / "corners.csv").read_bytes()
    return dict(then={}, now=dict(corners=st.stats.n_corners, usable=st.stats.n_usable,
                                  corners_csv_same_as_the_run=same))


def _classify(run: Path, reference: Path, ndsm: Path, tmp: Path) -> dict:
    import laspy
    import numpy as np

    from lidarctl.tiles import classify_files

    project, options = _options(run)
    st = classify_files(project.lidar_strips(), tmp / "classified", crs=project.crs, params=options.classify,
                        suffix=".laz")
    differ = 0
    for ours, theirs in zip(sorted((tmp / "classified").glob("*.laz")), project.classified_strips()):
        with laspy.open(ours) as a, laspy.open(theirs) as b:
            for ca, cb in zip(a.chunk_iterator(5_000_000), b.chunk_iterator(5_000_000)):
                differ += int(np.count_nonzero(np.asarray(ca.classification) != np.asarray(cb.classification)))
    return dict(then={}, now=dict(points=st.n_points, classes_differing_from_the_run=differ))


STAGES = {"classify": _classify, "dom_check": _dom_check, "rasters": _rasters, "corners": _corners}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=list(SUFFIX), default="full")
    ap.add_argument("--run", type=Path, help="the chain's run folder (default: $AEROTRI_BENCH_BLOCKS/scale[_SIZE]_run)")
    ap.add_argument("--reference", type=Path, help="true orthophoto (default: the block's truth/ortho.tif)")
    ap.add_argument("--stage", choices=(*STAGES, "all"), default="all", help="default: all of them, one after the other")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "stage_rerun.json")
    a = ap.parse_args(argv)
    run = a.run or BLOCKS / f"scale{SUFFIX[a.size]}_run"
    reference = a.reference or BLOCKS / f"scale{SUFFIX[a.size]}" / "truth" / "ortho.tif"
    ndsm = run / "lidar_out" / "ndsm.tif"
    for p in (run / "ortho" / "mosaic.tif", run / "lidar_out" / "classified", reference, ndsm,
              run / "work" / "run_summary.json"):
        if not p.exists():
            sys.exit(f"{p}: not found (run `python bench/scale.py --size {a.size}` first)")

    for stage in STAGES if a.stage == "all" else [a.stage]:
        rerun(stage, a.size, run, reference, ndsm, a.out)
    return 0


def rerun(stage: str, size: str, run: Path, reference: Path, ndsm: Path, out: Path) -> None:
    """Run ``stage`` on ``run``'s inputs and record it in ``out`` under ``size``."""
    chain = json.loads((run / "work" / "run_summary.json").read_text())
    before = next((r for r in chain["stages"] if r["stage"] == stage), None)
    results = json.loads(out.read_text()) if out.exists() else {}
    entry = results.setdefault(size, {})
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        with measure() as usage:
            outcome = STAGES[stage](run, reference, ndsm, Path(tmp))
    now = dict(usage.record(), load_average_start=[round(x, 2) for x in load_start],
               load_average_end=[round(x, 2) for x in os.getloadavg()], **outcome["now"])
    entry[stage] = dict(run=str(run), chain_record=dict(wall_s=before.get("seconds"), cpu_s=before.get("cpu_s"),
                                                          peak_rss_mb=before.get("peak_rss_mb"), **outcome["then"])
                          if before else None, now=now)
    # the chain's total with every stage re-measured so far in place of its record
    redone = {k: v["now"]["wall_s"] for k, v in entry.items() if isinstance(v, dict) and "now" in v}
    total_s = sum(redone.get(r["stage"], r["seconds"]) for r in chain["stages"] if r.get("status") == "done")
    entry["composite_chain_wall_min"] = dict(
        value=round(total_s / 60.0, 1), stages_re_measured=sorted(redone),
        note="the run's other stages (not re-run) plus the stages re-measured here: several runs, not one")
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({stage: entry[stage], "composite_chain_wall_min": entry["composite_chain_wall_min"]},
                     indent=2))


if __name__ == "__main__":
    raise SystemExit(main())
