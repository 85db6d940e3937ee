"""The stages' result records (aerotri.chain.results): the JSON form the stamps and summary.json keep, key by key
and in order, as the stages wrote it before they returned records."""

from __future__ import annotations

import json

from aerotri.chain import results as R
from aerotri.adjust.report_record import adjustment_record
from aerotri.chain.stages import adjustment_result


def test_record_keeps_the_fields_in_order_with_why_and_notes_last():
    r = R.CornersResult(corners=1126, usable=0, notes=("no usable corner",))
    assert json.dumps(r.record()) == '{"corners": 1126, "usable": 0, "notes": ["no usable corner"]}'
    assert R.CornersResult(corners=5, usable=4).record() == {"corners": 5, "usable": 4}
    assert R.StripsResult(why="nothing to compare: one strip").record() == {"why": "nothing to compare: one strip"}
    assert list(R.StripsResult(pairs=3, rms_m=0.0456, nmad_m=0.061).record()) == ["pairs", "rms_m", "nmad_m"]
    assert list(R.StripsResult(model="strip", rms_before_m=0.2, rms_after_m=0.02, sigma0=1.1).record()) == [
        "model", "rms_before_m", "rms_after_m", "sigma0"]


def test_figures_not_measured_are_left_out_but_a_verdict_of_none_is_written():
    assert R.DomCheckResult(rms_xy_m=0.1, count=None).record() == {"rms_xy_m": 0.1}
    assert R.ReportResult(verdict=None, passed=0, failed=0).record() == {"verdict": None, "passed": 0, "failed": 0}


def test_vectors_write_the_check_figures_only_when_checked():
    assert R.VectorsResult(buildings=12, roads=3, notes=("not checked",)).record() == {
        "buildings": 12, "roads": 3, "notes": ["not checked"]}
    checked = R.VectorsResult(buildings=12, roads=3, checked=True, corner_rms_xy_m=None, corners=None).record()
    assert json.dumps(checked) == '{"buildings": 12, "roads": 3, "corner_rms_xy_m": null, "corners": null}'


def test_adjustment_numbers_of_a_report():
    rep = {"key_statistics": {"sigma0_um": 3.2}, "counts": {"control_points": 40}, "check_rms_m": [0.03, 0.04, 0.05]}
    r = adjustment_result(adjustment_record(rep), loo_rms_xy_m=0.061, control_scatter_xy_m=0.044,
                          notes=("datum: control",))
    assert json.dumps(r.record()) == ('{"sigma0_um": 3.2, "control_points": 40, "rms_check_xy_m": 0.05, '
                                      '"rms_check_z_m": 0.05, "loo_rms_xy_m": 0.061, "control_scatter_xy_m": 0.044, '
                                      '"notes": ["datum: control"]}')
    # no check points, no sigma naught: left out (a block adjusted on GNSS alone)
    assert adjustment_result(adjustment_record({"counts": {"control_points": 0},
                                                "check_rms_m": [None, None, None]})).record() == {
        "control_points": 0}
