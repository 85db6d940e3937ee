"""Trial audit F6: a DOM whose check lost too many textured patches (``ortho.check.UnmatchedPatches.fails``).

- 0.6 m off: the verdict table failed it at 0.6685 m from 585 patches, the compliance section said "RMSE_H not measured
  (0 ground patches) ... not testable" (it dropped the figure when a region lost its patches). It judges the same 585
  patches now and fails the DOM on the unmatched share, as the table does.
- 5 m off: 631 of 633 patches unmatched, the table gave "plan RMS 2.370 m" of 2 false matches as the DOM's error.
  Now it says the DOM failed because the patches did not match, with no figure.
- a search shorter than the limit: not judged in either section (a patch lost beyond it may be within the limit)."""

from __future__ import annotations

import json

import pytest

from aerotri.qa.report import write_qa_report

PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32649"\n'


def _project(tmp_path, *, count, rms_m, gsd_m, per_region):
    """A project whose ortho/dom_report.json is a check against a reference: ``count`` patches matched (plan RMS
    ``rms_m``), ``per_region``: (frame, textured, unmatched) patches."""
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "project.toml").write_text(PROJECT)
    (tmp_path / "ortho").mkdir()
    unmatched = dict(patches=sum(r[2] for r in per_region), textured=sum(r[1] for r in per_region), min_ncc=0.7,
                     search_px=6, regions_by="frame", max_share=0.5, min_region_patches=10,
                     per_region=[dict(name=n, textured=t, unmatched=u) for n, t, u in per_region])
    (tmp_path / "ortho" / "dom_report.json").write_text(json.dumps(dict(
        method="reference_orthophoto", unmatched=unmatched,
        displacement=dict(count=count, gsd_m=gsd_m, rms_xy_m=rms_m, rms_e_m=rms_m * 0.8, rms_n_m=rms_m * 0.6,
                          rms_xy_gsd=rms_m / gsd_m, p95_xy_m=1.2 * rms_m, max_xy_m=1.5 * rms_m))))
    return tmp_path


def _dom_row(rep):
    return [c for c in rep.compliance["checks"] if c["product"] == "DOM"][0]


def test_a_frame_region_unmatched_fails_the_dom_in_both_sections(tmp_path):
    # the auditor's P1f: 47 of 632 unmatched, the 11 patches outside every frame's region all of them
    p = _project(tmp_path, count=585, rms_m=0.6685, gsd_m=0.4,
                 per_region=[("no frame", 11, 11), ("s01_001", 321, 20), ("s01_002", 300, 16)])
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H42.4 V60")
    row = rep.check("dom_rms_xy_m")
    assert row.value == 0.6685 and row.verdict == "fail"
    dom = _dom_row(rep)
    assert dom["verdict"] == "fail" and dom["n_points"] == 585 and dom["measured"] == 0.6685, dom
    assert dom["why"].startswith("failed because the patches did not match: 47 of 632 textured patches (7 %) found "
                                 "no match; 1 frame region more than 50 % unmatched (no frame 11 of 11)"), dom["why"]
    assert "0 ground patches" not in json.dumps(rep.compliance)
    assert [x["verdict"] for x in rep.compliance["products"] if x["product"] == "DOM"] == ["fail"]


def test_a_dom_whose_patches_did_not_match_has_no_figure(tmp_path):
    # the auditor's P1g: 5 m off, 631 of 633 unmatched, 2 false matches at 2.370 m
    p = _project(tmp_path, count=2, rms_m=2.3704, gsd_m=0.4,
                 per_region=[("s01_001", 320, 319), ("s01_002", 313, 312)])
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H42.4 V60")
    row = rep.check("dom_rms_xy_m")
    assert row.value is None and row.verdict == "fail", row
    assert row.note.startswith("failed because the patches did not match: 631 of 633 textured patches (100 %) found "
                               "no match"), row.note
    assert "the 2 that matched are too few to measure the DOM" in row.note and "2.37" not in row.note
    assert not rep.has("dom_p95_xy_m")  # nor a 95th percentile of 2 false matches
    dom = _dom_row(rep)
    assert dom["verdict"] == "fail" and dom.get("measured") is None, dom
    assert dom["why"].startswith("failed because the patches did not match: 631 of 633"), dom["why"]
    assert rep.overall == "fail"


def test_a_search_shorter_than_the_limit_is_not_judged(tmp_path):
    # a 5 cm DOM: the +-6 px search reaches 0.3 m, short of H42.4's 0.424 m: a lost patch may be within the limit
    p = _project(tmp_path, count=585, rms_m=0.05, gsd_m=0.05,
                 per_region=[("no frame", 11, 11), ("s01_001", 621, 36)])
    rep = write_qa_report(p, standard="asprs2023", accuracy_class="H42.4 V60")
    row = rep.check("dom_rms_xy_m")
    assert row.verdict is None and "not judged: the search (+-0.300 m) is shorter than the limit" in row.note
    dom = _dom_row(rep)
    assert dom["verdict"] == "not testable" and dom["measured"] == pytest.approx(0.05), dom
    assert "not judged: the search (+-0.300 m) is shorter than the limit 0.424 m" in dom["why"]
