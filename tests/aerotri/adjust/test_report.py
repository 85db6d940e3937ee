"""The adjustment report: the ISAT "Parameters and Results" layout and numbers consistent with the
adjustment they report (a small geometric block with check points)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aerotri.adjust import report
from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.core.records import to_record
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


@pytest.fixture(scope="module")
def ba(tmp_path_factory):
    block = geometric_block(2, 5, seed=11)
    root = write_block_project(block, tmp_path_factory.mktemp("rep") / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=6, seed=5)
    return adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3))


def test_numbers_agree_with_the_adjustment(ba):
    rep = to_record(report.build_report(ba))
    json.dumps(rep, allow_nan=False, default=float)  # JSON-ready
    d = np.array([row["d_m"] for row in rep["check_points"]], float)
    assert rep["counts"]["check_points"] == len(ba.check) == len(d) > 0
    assert np.allclose(rep["check_rms_m"], np.sqrt(np.mean(d ** 2, axis=0)), atol=1e-4)
    assert rep["counts"]["image_observations"] == int(ba.result.obs_active.sum())
    r = ba.result
    assert rep["key_statistics"]["sigma0_px"] == pytest.approx(r.sigma0 * 0.3, abs=1e-4)
    assert rep["key_statistics"]["sigma0_um"] == pytest.approx(r.sigma0 * 0.3 * ba.camera_apriori.pixel_um, abs=1e-3)
    tie = rep["image_residuals"]["tie"]
    act = r.obs_active & ~np.isin(ba.block.obs_point, ba.block.control_point)
    assert tie["obs_x"] == int(act.sum())
    assert tie["rms_x_um"] == pytest.approx(np.sqrt(np.mean((r.residual_px[act, 0] * ba.camera_apriori.pixel_um) ** 2)),
                                            abs=1e-3)
    assert rep["local_frame"]["origin_map"] == pytest.approx(list(ba.frame.origin_map))
    assert rep["options"]["gps_shift_drift_correction"].startswith("Enabled (shift")
    assert [p["image_id"] for p in rep["photos"]] == list(ba.eo_map.image_id)


def test_limits_come_from_the_tolerance_table(ba):
    rep = to_record(report.build_report(ba, "1:2000", "hilly"))
    from aerotri.core.tolerances import load_table

    tol = load_table("1:2000", "hilly").limits
    assert rep["parameters"]["rms_limits_m"][:3] == pytest.approx([tol["rms_xy_m"]] * 2 + [tol["rms_z_m"]])
    assert "1:2000 hilly" in rep["options"]["tolerances"]


def test_text_layout_is_isat_then_patb(ba):
    rep = to_record(report.build_report(ba))
    txt = report.format_txt(rep)
    lines = txt.splitlines()
    order = [next(i for i, ln in enumerate(lines) if ln.strip() == h) for h in
             ("PhotoT Triangulation Options", "Parameters", "Key Statistics")]
    assert lines[0].startswith("Photo-T Parameters and Results for Project") and order == sorted(order)
    assert txt.index("Key Statistics") < txt.index("ROOT MEAN SQUARE VALUES")
    assert f"Sigma: {rep['key_statistics']['sigma0_um']:.2f} um" in txt
    html = report.format_html(rep, ba)
    assert html.count("data:image/png;base64,") >= 1 and "Key Statistics" in html



def test_text_says_when_there_are_no_control_or_check_points(ba):
    """The NGI and kite blocks' report.txt printed the control / check table headers with no row under them (the
    HTML leaves the empty tables out): now one line saying there is none; with points the table as before."""
    rep = to_record(report.build_report(ba))
    assert rep["control_points"] and rep["check_points"]
    txt = report.format_txt(rep)
    assert "Control points (residual = adjusted - given" in txt and "Check points (d = adjusted - measured" in txt
    assert "none in the adjustment" not in txt
    txt = report.format_txt({**rep, "control_points": [], "check_points": [], "check_sum_m": None})
    lines = txt.splitlines()
    for head in ("Control points: none in the adjustment", "Check points: none in the adjustment"):
        k = lines.index(head)
        assert not lines[k + 1].split()[:1] == ["id"]  # no header row under it
    assert "Control points (residual" not in txt and "Check points (d =" not in txt

def test_image_pairs_count_shared_points_and_their_residuals(ba):
    """Per pair of frames: the tie points both see, and the RMS of both frames' residuals on them, checked
    against a direct count over the points."""
    rep = to_record(report.build_report(ba))
    b, r = ba.block, ba.result
    tie = r.obs_active & ~np.isin(b.obs_point, b.control_point)
    v_um = r.residual_px * ba.camera_apriori.pixel_um
    by_point = {}
    for k in np.flatnonzero(tie):
        by_point.setdefault(int(b.obs_point[k]), []).append(k)
    expect = {}
    for obs in by_point.values():
        for a in obs:
            for c in obs:
                if b.obs_image[a] < b.obs_image[c]:
                    e = expect.setdefault((b.image_id[b.obs_image[a]], b.image_id[b.obs_image[c]]), [0, 0, 0.0])
                    e[0] += 1
                    e[1] += len(obs) >= 3
                    e[2] += (v_um[a] ** 2).sum() + (v_um[c] ** 2).sum()
    rows = {(x["left"], x["right"]): x for x in rep["image_pairs"]}
    assert set(rows) == set(expect) and len(rows) > 5
    for key, (n, n3, ss) in expect.items():
        assert rows[key]["tie_points"] == n and rows[key]["in_3plus_frames"] == n3
        assert rows[key]["rms_um"] == pytest.approx(np.sqrt(ss / (4 * n)), abs=1e-3)
    counts = [x["tie_points"] for x in rep["image_pairs"]]
    assert counts == sorted(counts)  # weakest first
    assert "Image pairs (" in report.format_txt(rep)


def test_weak_mode_names_its_three_sigma_figure():
    """A mode loosely determined is weak when 3 sigma exceed the height limit; the text gives the 3-sigma
    figure (NGI: 'bending sigma 0.342 m, 3 sigma (1.03 m) above the 1.00 m height limit'), which the bare
    'sigma 0.342 m, 3 sigma above the 1.00 m limit' read as the sigma being three times over the limit."""
    from types import SimpleNamespace

    from aerotri.adjust.report import _weak_modes

    g = SimpleNamespace(mode="bending", sigma_m=0.342, held_by_priors=False, shares={"surface": 0.59, "image": 0.41})
    ok = SimpleNamespace(mode="height", sigma_m=0.2, held_by_priors=False, shares={"surface": 1.0})
    weak = _weak_modes(SimpleNamespace(result=SimpleNamespace(geometry=[g, ok])), 1.0)
    assert [w[0].mode for w in weak] == ["bending"]
    assert weak[0][1] == ("bending sigma 0.342 m, 3 sigma (1.03 m) above the 1.00 m height limit "
                          "(determined by surface 59%, image 41%)")


def test_a_plan_only_point_given_as_check_point_is_no_height_check(tmp_path):
    """``--check`` on a horizontal control point (the kite block's targets: heights 0, not surveyed): its
    height difference was reported (0.59 m RMS over the kite's 4 targets, "check points, height RMS" failed
    against ASPRS's 0.035 m); it is no check, so dZ is None and the height RMS is that of the points surveyed
    in height."""
    from aerotri.adjust.report_record import adjustment_record
    from aerotri.core.project import ControlPointSettings
    from aerotri.qa.compliance import at_checks

    block = geometric_block(2, 5, seed=11)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=6, seed=5)
    path = root / "control" / "points.csv"
    head, *rows = path.read_text().splitlines()
    rows = [",".join([f[0], "horizontal", f[2], f[3], "0.0", *f[5:]]) if f[0] == "gcp05" else ",".join(f)
            for f in (r.split(",") for r in rows)]
    path.write_text("\n".join([head] + rows) + "\n")
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, check=("gcp05",)))
    rep = to_record(report.build_report(ba))
    row = {r["id"]: r for r in rep["check_points"]}
    assert row["gcp05"]["d_m"][2] is None and None not in row["gcp05"]["d_m"][:2]
    assert row["gcp05"]["given_sigma_m"] == pytest.approx([0.03, 0.03, 0.05])  # control/points.csv's, for the QA
    d = np.array([r["d_m"] for r in rep["check_points"]], float)  # None -> NaN
    full = np.array([r["d_m"] for i, r in row.items() if i != "gcp05"], float)
    assert len(full) == 6 and np.isfinite(full).all()
    assert rep["check_rms_m"][2] == pytest.approx(np.sqrt(np.mean(full[:, 2] ** 2)), abs=1e-4)
    assert rep["check_rms_m"][:2] == pytest.approx(list(np.sqrt(np.mean(d[:, :2] ** 2, axis=0))), abs=1e-4)
    assert abs(rep["check_rms_m"][2]) < 1.0  # gcp05's adjusted height minus 0 is the block's terrain height
    assert "gcp05" in report.format_txt(rep) and "gcp05" in report.format_html(rep, ba)
    # every check point plan-only (the kite's): no height figure at all, and the reports say so, not a TypeError
    plan_only = dict(rep, check_rms_m=rep["check_rms_m"][:2] + [None],
                     check_normalised_rms=rep["check_normalised_rms"][:2] + [None])
    assert "normalised check errors (d / sigma), RMS X Y Z: " in report.format_txt(plan_only)
    report.format_html(plan_only, ba)
    rec = adjustment_record(json.loads(json.dumps(rep, default=float)))
    assert len(rec.check_residuals_m) == 7
    cs = at_checks(json.loads(json.dumps(rep, default=float)), ControlPointSettings())
    assert (cs.n_h, cs.n_v) == (7, 6)
    assert cs.rmse_v_m == pytest.approx(np.sqrt(np.mean(full[:, 2] ** 2)), abs=1e-4)
    assert cs.rmse_h_m == pytest.approx(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)), abs=1e-4)


def test_the_verdict_names_control_left_out_by_the_data_snooping(tmp_path):
    """A control point 3 m off is thrown out by the data snooping; the verdict said "Solution Successful." and
    nothing else (the kite block with two targets' labels swapped in one frame: "the last solve did not
    converge", 5 of its 10 targets out, none named)."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=6, points_per_image=80, n_check=4, seed=2,
                             bad_control_shift_m=3.0)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3))
    assert [str(ba.control.id[c]) for c, _ in ba.result.rejected_control] == ["gcp01"]
    ks = to_record(report.build_report(ba))["key_statistics"]
    w = ba.result.rejected_control[0][1]
    assert f"Control left out by the data snooping: 1 of 6 points (gcp01 w = {w:.2f})" in ks["message"]


def test_check_points_given_as_a_comma_separated_list(tmp_path):
    """``--check gcp05,gcp07`` (as ``--self-cal pp,radial`` is given) stopped with "control points
    ['gcp05,gcp07'] are not in the control point file"; now the ids are split, and an unknown one is named alone."""
    from click.testing import CliRunner

    from aerotri.cli import main as aerotri_cli

    block = geometric_block(2, 5, seed=11)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=5, points_per_image=80, n_check=2, seed=5)
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--check", "gcp04,nope", "--image-sigma-px", "0.3"])
    assert r.exit_code == 2 and "['nope']" in r.output, r.output
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--check", "gcp04, gcp05", "--image-sigma-px", "0.3"])
    assert r.exit_code == 0, r.output
    ids = {c["id"] for c in json.loads((root / "at" / "report.json").read_text())["check_points"]}
    assert {"gcp04", "gcp05", "chk01", "chk02"} <= ids
