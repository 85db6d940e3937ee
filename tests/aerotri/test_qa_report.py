"""The consolidated accuracy report: verdicts follow the measured numbers and the tolerance table."""

from __future__ import annotations

import json

from aerotri.qa_report import write_qa_report


def _project(tmp_path, check_rms, dom_rms):
    (tmp_path / "at").mkdir()
    (tmp_path / "ortho").mkdir()
    (tmp_path / "at" / "report.json").write_text(json.dumps(dict(
        project="t", check_rms_m=check_rms, rms_control_ground_m=[0.02, 0.02, 0.03],
        key_statistics=dict(sigma0_um=5.1, success=True, message="Solution Successful."))))
    (tmp_path / "ortho" / "dom_report.json").write_text(json.dumps(dict(displacement=dict(rms_xy_m=dom_rms))))
    return tmp_path


def test_verdicts_match_numbers_and_terrain_class(tmp_path):
    p = _project(tmp_path, [0.3, 0.2, 1.5], 0.45)
    rep = write_qa_report(p)
    by = {r["quantity"]: r for r in rep["checks"]}
    plan = by["aerotriangulation check points, plan RMS"]
    assert abs(plan["value"] - (0.3**2 + 0.2**2) ** 0.5) < 1e-4 and plan["limit"] == 0.35 and plan["verdict"] == "fail"
    assert by["aerotriangulation check points, height RMS"]["verdict"] == "fail"  # 1.5 m > 1.0 m (flat)
    assert by["DOM displacement on ground patches, plan RMS"]["verdict"] == "pass"
    assert rep["overall"] == "fail"
    assert (p / "reports" / "index.html").read_text().count("class='fail'") == 2
    # The same numbers pass the mountainous limits (0.50 m plan, 3.0 m height).
    rep = write_qa_report(p, terrain="mountainous")
    assert rep["overall"] == "pass"
    assert json.loads((p / "reports" / "summary.json").read_text())["overall"] == "pass"
