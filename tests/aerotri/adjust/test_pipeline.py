"""Bundle adjustment of small geometric blocks against their known truth."""

import json

import numpy as np
import pytest

from aerotri.adjust.pipeline import AdjustSettings, adjust_project, write_outputs
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3


@pytest.fixture(scope="module")
def block_project(tmp_path_factory):
    block = geometric_block(3, 6, seed=3)
    root = write_block_project(block, tmp_path_factory.mktemp("adj") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=120, n_check=12, seed=4)
    return block, root


def _truth_eo(block, ba):
    eo = block.eo_map()
    idx = [eo.image_id.index(i) for i in ba.eo_map.image_id]
    return eo.centre_m[idx], eo.opk_deg[idx]


def test_adjustment_recovers_truth(block_project):
    block, root = block_project
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, self_calibration=("pp", "radial")))
    r = ba.result
    # sigma0 honest: a-priori sigma equals the injected noise
    assert 0.85 < r.sigma0 < 1.15
    assert len(r.removed) < 0.01 * len(r.obs_active)
    C_true, opk_true = _truth_eo(block, ba)
    dC = ba.eo_map.centre_m - C_true
    assert np.sqrt(np.mean(dC**2)) < 0.3
    # standard deviations of the centres explain the errors (normalised RMS near 1)
    z = dC / ba.eo_map.sigma[:, :3]
    assert 0.4 < np.sqrt(np.mean(z**2)) < 2.0
    # check points: accuracy in GSD (0.1 m) and honest precision
    d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values()])
    s = np.array([np.hypot(c["sigma_m"], c["given_sigma_m"]) for c in ba.check.values()])
    assert np.sqrt(np.mean(d[:, :2] ** 2)) < 0.1
    assert np.sqrt(np.mean(d[:, 2] ** 2)) < 0.25
    assert 0.5 < np.sqrt(np.mean((d / s) ** 2)) < 1.6
    # self-calibration: principal point and k1 within 3 standard deviations of the truth
    cam_t = block.camera_true
    sd = np.sqrt(np.diag(r.cal_cov))
    assert abs(r.state.cal[3] - cam_t.cx_px) < 3 * sd[3]
    assert abs(r.state.cal[4] - cam_t.cy_px) < 3 * sd[4]
    assert abs(r.state.cal[5] - cam_t.k1) < 3 * sd[5]
    # GNSS shift per strip recovered (the truth shift, ENU, vs the estimate)
    assert np.sqrt(np.mean((r.state.shift - block.gnss_shift_m) ** 2)) < 0.15


def test_outputs_and_report(block_project):
    block, root = block_project
    # The block's GNSS shifts are drawn with 0.3 m (geometric_block): that is their a-priori sigma. Its true camera
    # has a principal-point offset and radial distortion: without their self-calibration the shifts absorb them
    # (estimates 0.4-0.6 m off the true shifts, 1.2 m at most) and the report rightly says "Solution weak" with the
    # suspect shifts (issue 41; tests/aerotri/adjust/test_gnss_correction_check.py).
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False,
                                             gnss_shift_sigma_m=0.3, self_calibration=("pp", "radial")))
    res = write_outputs(ba, root)
    at = root / "at"
    for f in ("eo.txt", "object_points.csv", "report.txt", "report.json", "report.html"):
        assert (at / f).stat().st_size > 0, f
    assert not (at / "patb").exists()  # exports are the exchange stage's (tests/aerotri/exchange)
    txt = (at / "report.txt").read_text()
    for label in ("PhotoT Triangulation Options", "RMS Control", "RMS Check", "Mean Std Dev Photo Attitude",
                  "Sigma:", "Degrees of Freedom:", "Solution Successful.", "Check points"):
        assert label in txt
    js = json.loads((at / "report.json").read_text())
    assert js["key_statistics"]["sigma0_um"] == res.record.key_statistics.sigma0_um
    # its random strip shifts (N 0.77, -0.61, 0.16 m) are GNSS errors shared within a strip, not a direction effect:
    # judged by the strips' spread (1 degree of freedom: strips 1, 3 against 2) they raise no alarm (judged by the
    # photos' scatter they read 3.1 sigma across the track); the message has no direction finding either way
    p = js["gnss_directions"]["pairs"][0]
    assert js["gnss_directions"]["testable"] and p["separable"] and p["strip_dof"] == 1
    assert not js["key_statistics"]["gnss_direction_flip"]
    assert "flip with the flight direction" not in js["key_statistics"]["message"]
    assert res.report_path == at / "report.json" and res.adjustment is ba
    # its inputs by content, for the accuracy report's "adjustment made from the current inputs" (trial-gis F9)
    import hashlib

    assert set(js["inputs"]) == {"control/points.csv", "control/image_points.csv", "gnss.txt", "at/tiepoints.csv"}
    ties = (at / "tiepoints.csv").read_bytes()
    assert js["inputs"]["at/tiepoints.csv"] == {"size": len(ties), "sha256": hashlib.sha256(ties).hexdigest()}
    assert js["counts"]["images"] == 18 and js["counts"]["check_points"] == 12
    assert js["counts"]["image_observations"] + js["counts"]["removed_observations"] >= len(ba.block.obs_point) - 5
    from aerotri.geom.eo import read_eo

    eo = read_eo(at / "eo.txt")
    assert eo.sigma is not None and len(eo.image_id) == 18


def test_the_camera_of_the_orientations_is_written_beside_them(block_project, tmp_path):
    """at/camera.toml is the self-calibrated camera of at/eo.txt; a project adjusted before that file existed is
    refused by the stages that read it ("adjust again"), and adjusting it again writes the file."""
    import shutil

    from aerotri.core.errors import StageOrderError
    from aerotri.core.project import Project
    from aerotri.geom.camera import oriented_camera

    block, root = block_project
    copy = shutil.copytree(root, tmp_path / "blk")
    ba = adjust_project(copy, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False,
                                             gnss_shift_sigma_m=0.3, self_calibration=("pp", "radial"), snooping=False))
    write_outputs(ba, copy, html=False)
    camera, source = oriented_camera(Project.open(copy))
    assert camera == ba.camera_adjusted and "self-calibrated" in source
    (copy / "at" / "camera.toml").unlink()  # as an adjustment before the file existed left the project
    with pytest.raises(StageOrderError, match="adjust again"):
        oriented_camera(Project.open(copy))
    write_outputs(ba, copy, html=False)
    assert oriented_camera(Project.open(copy))[0] == ba.camera_adjusted


def test_report_limits_follow_the_project_map_scale(block_project, tmp_path):
    """at/report.* takes its RMS and residual limits from the project's [qa] map scale and terrain; without
    [qa] from the table of the block's GSD and platform (aerotri.core.tolerances.choose_table)."""
    import shutil

    block, root = block_project
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False,
                                             snooping=False))
    res = write_outputs(ba, root, html=False)
    rep = json.loads(res.report_path.read_text())
    # no [qa]: a DMC at 1000 m, GSD 10 cm, manned (above 150 m) -> the Chinese table of its GSD, 1:2000 (flat)
    assert rep["parameters"]["rms_limits_m"] == [None, None, 0.4, 0.14]  # plan limit under XY
    assert "Tolerances : 1:2000 flat (cn_1to2000.toml)" in (root / "at" / "report.txt").read_text()
    assert rep["flight_acceptance"] is None or rep["flight_acceptance"]["limits"]["flight_tilt_max_deg"] == 2.0
    copy = tmp_path / "blk"
    shutil.copytree(root, copy)
    with open(copy / "project.toml", "a") as f:
        f.write('\n[qa]\nmap_scale = "1:2000"\nterrain = "hilly"\n')
    res = write_outputs(ba, copy, html=False)
    rep = json.loads(res.report_path.read_text())
    assert rep["parameters"]["rms_limits_m"] == [None, None, 0.8, 0.14]
    assert rep["parameters"]["residual_limits_m"] == [None, None, 1.6, 0.28]
    assert "Tolerances : 1:2000 hilly (cn_1to2000.toml)" in (copy / "at" / "report.txt").read_text()


def test_a_point_without_rays_may_lie_anywhere(block_project, monkeypatch):
    """A tie point whose every ray was rejected keeps whatever value the last solve left it, which on a weak real
    block (Tuniu's 4 oblique frames) was thousands of kilometres away, where no map projection reaches: the
    adjustment stopped with 'EPSG:4328 -> EPSG:32651: point 99 ... could not be transformed'. Such a point is
    left out of the outputs (NaN), and the point precisions are still computed."""
    import dataclasses

    from aerotri.adjust import pipeline

    _, root = block_project
    seen = {}

    def drifted(prepared, result):
        block = prepared.block
        k = next(j for j in range(block.n_points) if j not in set(block.control_point.tolist()))
        points = result.state.points.copy()
        points[k] = [6.4e6, 0.0, -6.4e6]  # local metres: on the far side of the earth, where UTM gives inf
        seen["k"] = k
        state = dataclasses.replace(result.state, points=points)
        return finish(prepared, dataclasses.replace(result, state=state,
                                                    obs_active=result.obs_active & (block.obs_point != k)))

    finish = pipeline.finish
    monkeypatch.setattr(pipeline, "finish", drifted)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX))
    k = seen["k"]
    assert np.isnan(ba.points_map[k]).all()
    others = np.delete(np.arange(len(ba.points_map)), k)
    assert np.isfinite(ba.points_map[others]).all()
    assert np.isfinite(ba.points_sigma_map[others]).all()


def test_the_folded_check_point_table_counts_the_check_points(tmp_path):
    """report.html folds a long check-point table under "N check points": N counted the table's sum and rms rows
    too (the demo: "386 check points" over its 384)."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=60, n_check=45, seed=2)
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False))
    write_outputs(ba, root)
    n = json.loads((root / "at" / "report.json").read_text())["counts"]["check_points"]
    html = (root / "at" / "report.html").read_text()
    assert n > 40 and f"<summary>{n} check points (click to show the table)</summary>" in html


def test_the_removed_observations_table_says_it_is_shortened(block_project, monkeypatch):
    """report.html lists the first REMOVED_SHOWN removed observations under "Removed observations (N)"; its summary
    said "200 removed observations" under the demo's 1787."""
    import aerotri.adjust.report as report

    _, root = block_project
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False,
                                             gnss_shift_sigma_m=0.3, self_calibration=("pp", "radial")))
    rep = json.loads(write_outputs(ba, root).report_path.read_text())
    assert rep["removed_observations"]
    # the small block removes few: its first removal stands for the 60 of a long list (the table's layout only)
    first = rep["removed_observations"][0]
    rep["removed_observations"] = [dict(first, point_id=f"{first['point_id']}_{k}") for k in range(60)]
    n = 60
    monkeypatch.setattr(report, "REMOVED_SHOWN", 41)
    html = report.format_html(rep, ba)
    assert f"<h2>Removed observations ({n})</h2>" in html
    assert f"<summary>41 of the {n} removed observations, in the order of the removal rounds (all: report.txt, " in html
