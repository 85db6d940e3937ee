"""A DOM checked at surveyed points (``ortho check --points``) is reported as such, and points the adjustment used
as control are not taken for independent check points (new-user trial 2026-12-01, ortho operator: the kite's 10
targets measured in its DOM read "displacement on ground patches ... 10 patches" and, in the compliance statement,
"ground patches of the DOM matched to the reference orthophoto (phase correlation)"; all 10 were the AT's control)."""

from __future__ import annotations

import json

import numpy as np

from aerotri.qa.report import write_qa_report

PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32649"\n'


def _project(tmp_path, control_ids, point_ids, shifts_m=None):
    """``shifts_m``: {id: (de, dn)} of the points measured off by more than the others' (0.03, 0.04) m."""
    shifts_m = shifts_m or {}
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "project.toml").write_text(PROJECT)
    (tmp_path / "at").mkdir()
    (tmp_path / "ortho").mkdir()
    control = [dict(id=i, kind="full", used=True, status="used") for i in control_ids]
    (tmp_path / "at" / "report.json").write_text(json.dumps(dict(
        project="t", check_rms_m=None, rms_control_ground_m=[0.02, 0.02, 0.03], control_points=control,
        key_statistics=dict(sigma0_um=5.1, sigma0_px=0.425, success=True, message="Solution Successful."))))
    de_dn = [shifts_m.get(i, (0.03, 0.04)) for i in point_ids]
    points = [dict(id=i, x_m=0.0, y_m=0.0, x_dom_m=e, y_dom_m=n, de_m=e, dn_m=n) for i, (e, n) in zip(point_ids, de_dn)]
    rms = float(np.sqrt(np.mean([e * e + n * n for e, n in de_dn])))
    (tmp_path / "ortho" / "dom_report.json").write_text(json.dumps(dict(
        method="surveyed_points", points_file="points.csv", points=points,
        displacement=dict(count=len(points), gsd_m=0.1, rms_xy_m=rms, rms_xy_gsd=rms / 0.1, p95_xy_m=rms,
                          max_xy_m=rms))))
    return tmp_path


def test_a_dom_checked_at_the_adjustments_control_is_not_independent(tmp_path):
    ids = [f"T{i}" for i in range(32)]
    p = _project(tmp_path, ids[:20], ids)  # 20 of the 32 points were control
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H10 V10")
    row = rep.check("dom_rms_xy_m")
    assert row.quantity == "displacement at surveyed points, plan RMS"
    assert row.note.startswith("12 points, 0.50 GSD (of the DOM's 0.1 m cell); 20 of the 32 surveyed points left out, "
                               "the adjustment's "
                               "control (T0, T1, T2, ...): not independent check points"), row.note
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["counted"] == "surveyed points" and dom["n_points"] == 12  # the independent ones
    assert dom["verdict"] == "not testable", dom  # (12 of the 30 ASPRS asks for)
    assert "20 of the 32 left out, the adjustment's control (T0, T1" in dom["checkpoints_note"], dom
    assert "phase correlation" not in json.dumps(dom)


def test_the_dom_is_judged_at_its_independent_points(tmp_path):
    """review 28: one control point among 31 made the whole row "not testable": the RMSE is the 30 others'."""
    ids = [f"T{i}" for i in range(31)]
    p = _project(tmp_path, ["T7"], ids, shifts_m={"T7": (3.0, -2.0)})  # the control point far off: not counted
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H10 V10")
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["n_points"] == 30 and dom["verdict"] == "pass", dom
    assert abs(dom["measured"] - 0.05) < 1e-9, dom  # sqrt(0.03² + 0.04²), without T7's 3.6 m
    assert "1 of the 31 left out, the adjustment's control (T7)" in dom["checkpoints_note"], dom
    row = rep.check("dom_rms_xy_m")  # the verdict table judges the same 30 points
    assert row.value == 0.05 and row.note.startswith("30 points") and "1 of the 31 surveyed points left out" in row.note
    # every point the adjustment's control: no figure, never a pass
    rep = write_qa_report(_project(tmp_path / "all", ids, ids), standard="asprs2023", accuracy_class="H10 V10")
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["n_points"] == 0 and dom["verdict"] == "not testable" and dom.get("measured") is None, dom
    assert "31 of the 31 surveyed points were the adjustment's control" in dom["why"] + dom["checkpoints_note"]


def test_point_ids_match_without_case_or_leading_zeros(tmp_path):
    """"GCP06" is the AT's "gcp06", "06" its 6 (a number in at/report.json too); "GCP6" is not "GCP06"."""
    from aerotri.qa.compliance import point_id_key

    assert point_id_key("GCP06") == point_id_key("gcp06") and point_id_key("06") == point_id_key(6) == "6"
    assert point_id_key("GCP6") != point_id_key("GCP06") and point_id_key("000") == "0"
    ids = ["GCP06", "06", "007"] + [f"T{i}" for i in range(30)]
    rep = write_qa_report(_project(tmp_path, ["gcp06", 6, "7"], ids), standard="asprs2023", accuracy_class="H10 V10")
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["n_points"] == 30 and dom["verdict"] == "pass", dom
    assert "3 of the 33 left out, the adjustment's control (GCP06, 06, 007)" in dom["checkpoints_note"], dom


def test_a_dom_checked_at_independent_points(tmp_path):
    ids = [f"T{i}" for i in range(32)]
    p = _project(tmp_path, ["C1", "C2"], ids)
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H10 V10")
    row = rep.check("dom_rms_xy_m")
    assert row.quantity == "displacement at surveyed points, plan RMS" and row.note.startswith("32 points, 0.50 GSD")
    assert "control" not in row.note
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    assert dom["counted"] == "surveyed points" and dom["n_points"] == 32 and dom["verdict"] == "pass", dom


def test_the_verdict_table_judges_the_independent_points_only(tmp_path):
    """Trial audit F1: 6 independent points 0.600 m off and the adjustment's 4 control points at 0 m read "plan RMS
    0.4648 m: pass" (limit 0.50 m, 1:5000) over all 10, the compliance row 0.600 m "fail". Both judge the 6 now; with
    every point the adjustment's control the row is not testable (no figure, never a pass)."""
    ids = [f"C{i}" for i in range(4)] + [f"P{i}" for i in range(6)]
    shifts = {i: (0.0, 0.0) for i in ids[:4]} | {i: (0.6, 0.0) for i in ids[4:]}
    rep = write_qa_report(_project(tmp_path, ids[:4], ids, shifts_m=shifts), scale="1:5000")
    row = rep.check("dom_rms_xy_m")
    assert row.limit == 0.5 and row.value == 0.6 and row.verdict == "fail", row
    assert row.note.startswith("6 points, 6.00 GSD (of the DOM's 0.1 m cell); 4 of the 10 surveyed points left out, "
                               "the adjustment's control "
                               "(C0, C1, C2, ...)"), row.note
    assert rep.check("dom_p95_xy_m").value == 0.6  # of the 6 too
    assert rep.overall == "fail"
    dom = [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]
    # the same 6 points; the compliance section's cn-at limit is 0.5 mm on the map (2.5 m at 1:5000, s95), the
    # verdict table's the design table's 0.5 m, and the row says so
    assert dom["measured"] == row.value and dom["limit"] == 2.5 and dom["verdict"] == "pass", dom
    assert "the verdict table (the design table, cn_1to5000.toml) holds 0.5 m" in dom["checkpoints_note"]
    # every point the adjustment's control: not testable, with the reason
    rep = write_qa_report(_project(tmp_path / "all", ids, ids, shifts_m=shifts), scale="1:5000")
    row = rep.check("dom_rms_xy_m")
    assert row.value is None and row.verdict is None and row.limit == 0.5, row
    assert row.note.startswith("not testable: 10 of the 10 surveyed points left out, the adjustment's control"), row
    assert "dom_rms_xy_m" in rep.not_judged and not rep.has("dom_p95_xy_m")
