"""A DOM checked at surveyed points (``ortho check --points``) is reported as such, and points the adjustment used
as control are not taken for independent check points (new-user trial 2026-12-01, ortho operator: the kite's 10
targets measured in its DOM read "displacement on ground patches ... 10 patches" and, in the compliance statement,
"ground patches of the DOM matched to the reference orthophoto (phase correlation)"; all 10 were the AT's control)."""

from __future__ import annotations

import json

from aerotri.qa.report import write_qa_report

PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32649"\n'


def _project(tmp_path, control_ids, point_ids):
    (tmp_path / "project.toml").write_text(PROJECT)
    (tmp_path / "at").mkdir()
    (tmp_path / "ortho").mkdir()
    control = [dict(id=i, kind="full", used=True, status="used") for i in control_ids]
    (tmp_path / "at" / "report.json").write_text(json.dumps(dict(
        project="t", check_rms_m=None, rms_control_ground_m=[0.02, 0.02, 0.03], control_points=control,
        key_statistics=dict(sigma0_um=5.1, sigma0_px=0.425, success=True, message="Solution Successful."))))
    points = [dict(id=i, x_m=0.0, y_m=0.0, x_dom_m=0.03, y_dom_m=0.04, de_m=0.03, dn_m=0.04) for i in point_ids]
    (tmp_path / "ortho" / "dom_report.json").write_text(json.dumps(dict(
        method="surveyed_points", points_file="points.csv", points=points,
        displacement=dict(count=len(points), gsd_m=0.1, rms_xy_m=0.05, rms_xy_gsd=0.5, p95_xy_m=0.05, max_xy_m=0.05))))
    return tmp_path


def test_a_dom_checked_at_the_adjustments_control_is_not_independent(tmp_path):
    ids = [f"T{i}" for i in range(32)]
    p = _project(tmp_path, ids[:20], ids)  # 20 of the 32 points were control
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H10 V10")
    row = rep.check("dom_rms_xy_m")
    assert row.quantity == "displacement at surveyed points, plan RMS"
    assert row.note.startswith("32 points, 0.50 GSD; 20 of them the adjustment's control (T0, T1, T2, ...): not "
                               "independent check points"), row.note
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["counted"] == "surveyed points" and dom["n_points"] == 12  # the independent ones
    assert dom["verdict"] == "not testable", dom
    assert "20 of the 32 surveyed points were the adjustment's control" in dom["why"] + dom["checkpoints_note"]
    assert "phase correlation" not in json.dumps(dom)


def test_a_dom_checked_at_independent_points(tmp_path):
    ids = [f"T{i}" for i in range(32)]
    p = _project(tmp_path, ["C1", "C2"], ids)
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H10 V10")
    row = rep.check("dom_rms_xy_m")
    assert row.quantity == "displacement at surveyed points, plan RMS" and row.note.startswith("32 points, 0.50 GSD")
    assert "control" not in row.note
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["counted"] == "surveyed points" and dom["n_points"] == 32 and dom["verdict"] == "pass", dom
