"""A control point whose image measurements the data snooping removed, every one, is named as left out
(trial-api F2): a height mistyped by 2 m lost both rays, report.json said `rejected_control: []`, the QA report "0
control points rejected", and the control RMS improved; only a line of report.txt said "not used"."""

from __future__ import annotations

import csv
import dataclasses
import json

from aerotri.adjust.pipeline import project_settings, run_adjustment
from aerotri.adjust.report_record import read_adjustment_report
from aerotri.core.project import Project
from aerotri.sim.command import simulate_command


def test_a_mistyped_height_whose_rays_the_snooping_removed_is_left_out_by_name(tmp_path):
    root = tmp_path / "blk"
    simulate_command("tiny", root, seed=7, observations_only=True)
    path = root / "control" / "points.csv"
    rows = list(csv.DictReader(path.open()))
    for r in rows:
        if r["id"] == "gcp03":
            r["z"] = f"{float(r['z']) + 2.0:.4f}"
    with path.open("w") as f:
        f.write(",".join(rows[0]) + "\n" + "".join(",".join(r.values()) + "\n" for r in rows))
    st = dataclasses.replace(project_settings(Project.open(root)).settings, dem=root / "dem.tif")
    rep = json.loads(run_adjustment(root, st, html=False).report_path.read_text())
    row = next(c for c in rep["control_points"] if c["id"] == "gcp03")
    assert row["rays"] == 0 and row["status"] == "rejected"  # was "no rays", not rejected
    assert [c["id"] for c in rep["rejected_control"]] == ["gcp03"] and rep["rejected_control"][0]["w"] > 3.29
    assert "Control left out by the data snooping: 1 of 4 points (gcp03 w = " in rep["key_statistics"]["message"]
    assert read_adjustment_report(root / "at" / "report.json").rejected_control == ("gcp03",)
