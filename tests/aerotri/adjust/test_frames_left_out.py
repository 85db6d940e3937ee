"""Frames the adjustment cannot orient (nothing matched over the sea, two measurements only, a part of the block
no tie point reaches) are left out by name, the solution is not "Successful", and the checks that judge the
flight and the cover count them (trial-relief F1, F2, F7)."""

import json

import numpy as np
import pytest

from aerotri.adjust.flight_acceptance import Terrain, in_flight_order, project_flight_acceptance
from aerotri.adjust.pipeline import AdjustSettings, adjust_project, write_outputs
from aerotri.adjust.report_record import adjustment_record
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

BLANK = "s02_003"  # a frame in the middle of the block: every tie and control measurement of it removed
FEW = "s01_002"  # a frame left with two measurements


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    block = geometric_block(3, 5, seed=11)
    root = write_block_project(block, tmp_path_factory.mktemp("left") / "blk")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    # the terrain the flight checks drape the footprints on (the block's terrain is about 0 m)
    with open(root / "project.toml", "a") as f:
        f.write("\n[flight]\nmean_terrain_height_m = 0.0\n")
    return root


def _without(root, path, keep_rows) -> None:
    lines = (root / path).read_text().splitlines()
    (root / path).write_text("\n".join([lines[0]] + [ln for ln in lines[1:] if keep_rows(ln)]) + "\n")


def _edited(project, tmp_path, edit):
    import shutil

    root = tmp_path / "blk"
    shutil.copytree(project, root)
    edit(root)
    return root


def test_a_frame_with_no_measurement_is_left_out_by_name_and_the_solution_is_weak(project, tmp_path, caplog):
    def blank(root):
        for path in ("at/tiepoints.csv", "control/image_points.csv"):
            _without(root, path, lambda ln: f",{BLANK}," not in ln)

    root = _edited(project, tmp_path, blank)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift"))
    # before: the frame dropped out of eo.txt without a word and the rest could be "Solution Successful"
    assert BLANK not in ba.eo_map.image_id and len(ba.eo_map.image_id) == 14
    assert [lo.image_ids for lo in ba.left_out] == [[BLANK]]
    assert "no tie point and no control point" in ba.left_out[0].reason
    assert any(BLANK in r.message and "left out" in r.message for r in caplog.records)
    write_outputs(ba, root)
    rep = json.loads((root / "at/report.json").read_text())
    assert rep["key_statistics"]["verdict"] != "successful"
    assert f"{BLANK}: no tie point and no control point" in rep["key_statistics"]["message"]
    rec = adjustment_record(rep)
    assert [k for k, _ in rec.frames_left_out] == [BLANK]
    # the flight checks of the report hold the frame too, from its GNSS position with a nominal attitude
    frames = {f["image_id"]: f for f in rep["flight_acceptance"]["frames"]}
    assert len(frames) == 15 and frames[BLANK]["tilt_deg"] is None and frames[BLANK]["forward_overlap_pct"] > 0
    assert BLANK in rep["flight_acceptance"]["source"]


def test_a_frame_with_two_measurements_is_left_out_not_the_block_refused(project, tmp_path):
    def two(root):
        lines = (root / "at/tiepoints.csv").read_text().splitlines()
        mine = [ln for ln in lines[1:] if f",{FEW}," in ln]
        keep = set(mine[:2])
        _without(root, "at/tiepoints.csv", lambda ln: f",{FEW}," not in ln or ln in keep)
        _without(root, "control/image_points.csv", lambda ln: f",{FEW}," not in ln)

    root = _edited(project, tmp_path, two)
    # before: "image s01_002 has only 2 tie measurements (need >= 3)", exit 2, nothing adjusted
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift"))
    assert FEW not in ba.eo_map.image_id and len(ba.eo_map.image_id) == 14
    (lo,) = ba.left_out
    assert lo.image_ids == [FEW] and "fewer than the 3 measurements" in lo.reason and f"{FEW} 2 tie + 0 control" in lo.reason
    assert lo.position_map.shape == (1, 3)


def test_the_flight_checks_take_left_out_frames_from_gnss(project, tmp_path):
    """``project_flight_acceptance`` with an eo.txt lacking frames: those from gnss.txt, nominal attitude, so a
    side overlap measured between a strip that was adjusted and one that was not."""
    def eo_of_two_strips(root):
        (root / "at").mkdir(exist_ok=True)
        truth = (root / "truth/eo.txt").read_text().splitlines()
        (root / "at/eo.txt").write_text("\n".join(ln for ln in truth if "s03_" not in ln) + "\n")

    root = _edited(project, tmp_path, eo_of_two_strips)
    terrain = Terrain(0.0, source="test")
    fa = project_flight_acceptance(root, terrain=terrain)
    frames = {f["image_id"]: f for f in fa.frames}
    assert len(frames) == 15
    assert all(frames[k]["tilt_deg"] is None for k in frames if k.startswith("s03_"))
    assert all(frames[k]["tilt_deg"] is not None for k in frames if not k.startswith("s03_"))
    assert len(fa.strips) == 3 and all(st["side_overlap_median_pct"] > 0 for st in fa.strips)
    assert "5 frames the adjustment left out" in fa.source


def test_in_flight_order_keeps_given_attitudes_and_gives_the_others_a_level_one():
    ids, c, opk, measured, strip = in_flight_order(
        ["a2", "a1"], [[10.0, 0, 500], [0.0, 0, 500]], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
        ["a3"], [[20.0, 0, 500]])
    assert ids == ["a1", "a2", "a3"]
    assert measured.tolist() == [True, True, False]
    assert opk[0].tolist() == [4.0, 5.0, 6.0] and opk[1].tolist() == [1.0, 2.0, 3.0]
    # level, image top along the flight (+x): kappa = heading - 90 deg
    assert np.allclose(opk[2], [0.0, 0.0, -90.0])
    assert strip.tolist() == [0, 0, 0]


def test_the_qa_report_judges_the_frames_left_out(project, tmp_path):
    """The consolidated report: a row that fails on frames the adjustment left out (half a block stood only in the
    solution's note, and the DOM's "seen by no frame" share is of the oriented frames' extent); its flight rows
    measure the left-out frames' overlaps too."""
    from aerotri.qa.report import build_qa_report

    def blank(root):
        for path in ("at/tiepoints.csv", "control/image_points.csv"):
            _without(root, path, lambda ln: f",{BLANK}," not in ln)

    root = _edited(project, tmp_path, blank)
    write_outputs(adjust_project(root, AdjustSettings(gnss_correction="shift")), root)
    rep = build_qa_report(root)
    rows = {c.id: c for c in rep.checks}
    row = rows["frames_not_oriented"]
    assert (row.value, row.limit, row.verdict) == (1, 0, "fail")
    assert row.note.startswith(f"{BLANK} (1 of 15): no tie point and no control point")
    assert BLANK in {f["image_id"] for f in rep.flight_acceptance["frames"]}


def test_a_split_blocks_warning_names_the_overlap_that_fails(tmp_path):
    """trial-relief F3: a block split by a 6 % side overlap sent the user to [flight] mean_terrain_height_m; the
    warning of `aerotri match` now gives the flight's overlaps that fail the specification."""
    from aerotri.adjust.flight_acceptance import overlap_shortfall

    # strips spaced for -0.1 of the simulator's side overlap: 4.7 % of the footprints on the terrain
    root = write_block_project(geometric_block(2, 4, side_overlap=-0.1, seed=2), tmp_path / "blk")
    with open(root / "project.toml", "a") as f:
        f.write("\n[flight]\nmean_terrain_height_m = 0.0\n")
    text = overlap_shortfall(root)
    assert "side overlap (median over a strip's frames) is" in text and "against the specification's 13 %" in text
    assert "forward overlap" not in text  # 60 %: passes
    ok = write_block_project(geometric_block(2, 4, side_overlap=0.3, seed=2), tmp_path / "ok")
    with open(ok / "project.toml", "a") as f:
        f.write("\n[flight]\nmean_terrain_height_m = 0.0\n")
    assert overlap_shortfall(ok) == ""


def test_a_check_point_measured_in_a_frame_left_out_is_checked_from_the_others(project, tmp_path):
    """trial s99 atmut M1: a frame of another flight (no tie point) whose image measured a check point made the
    adjustment stop on a KeyError (a traceback, exit 1). The frame is left out; the check point is intersected from
    the frames that were adjusted."""
    rows = (project / "control/image_points.csv").read_text().splitlines()[1:]
    checks = {ln.split(",")[0] for ln in (project / "control/points.csv").read_text().splitlines()[1:]
              if ln.split(",")[1] == "check"}
    seen = {c: [ln.split(",")[1] for ln in rows if ln.split(",")[0] == c] for c in sorted(checks)}
    point = next(c for c, frames in seen.items() if len(frames) >= 3)  # seen by two frames besides
    frame = seen[point][0]

    def orphan(root):
        _without(root, "at/tiepoints.csv", lambda ln: f",{frame}," not in ln)
        _without(root, "control/image_points.csv", lambda ln: f",{frame}," not in ln or ln.split(",")[0] in checks)

    root = _edited(project, tmp_path, orphan)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift"))
    assert [lo.image_ids for lo in ba.left_out] == [[frame]]
    others = sum(1 for ln in rows if ln.split(",")[0] == point and ln.split(",")[1] != frame)
    assert ba.check[point]["rays"] == others >= 2
    assert np.all(np.isfinite(ba.check[point]["adjusted_m"]))
    assert np.abs(np.subtract(ba.check[point]["adjusted_m"], ba.check[point]["measured_m"])).max() < 0.5
