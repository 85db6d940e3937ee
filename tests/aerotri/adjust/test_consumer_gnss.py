"""A consumer receiver's GNSS (project.toml [gnss] offset_sigma_xy_m / offset_sigma_z_m): one offset of metres common
to the flight plus decimetres between frames. Against simulator truth (a constant offset of 2.5 / -2.0 / 3.0 m and
0.2 m of noise per frame), without control: the reported sigmas of the block's datum must cover its true error; the
same positions weighted as a survey receiver's (decimetres, independent) claim centimetres. With the terrain's DEM
as surface control the height offset is estimated. bench/eval_consumer_gnss.py: more seeds and Brighton Beach."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.adjust.report import build_report
from aerotri.core.records import to_record
from aerotri.sim.observations import geometric_block, write_block_project, write_terrain_dem, write_truth_observations

OFFSET_M = np.array([2.5, -2.0, 3.0])
NOISE_M = 0.2
SETTINGS = AdjustSettings(image_sigma_px=0.3, use_control=False, point_covariances=False)


def _gnss(root, offset: bool) -> None:
    text = (root / "project.toml").read_text()
    head, rest = text.split("[gnss]\n", 1)
    keep = rest[rest.index("lever_arm_m"):]
    sec = f"[gnss]\nsigma_xy_m = {NOISE_M}\nsigma_z_m = {NOISE_M}\n"
    if offset:
        sec += "offset_sigma_xy_m = 3.0\noffset_sigma_z_m = 5.0\n"
    (root / "project.toml").write_text(head + sec + keep)


@pytest.fixture(scope="module")
def consumer_block(tmp_path_factory):
    block = geometric_block(3, 6, seed=10, gnss_sigma_m=(NOISE_M,) * 3, gnss_shift_sigma_m=0.0,
                            gnss_drift_sigma_m_per_km=0.0, lever_arm_m=(0.0, 0.0, 0.0))
    block.gnss_local = block.gnss_local + OFFSET_M  # the consumer receiver's common error
    root = write_block_project(block, tmp_path_factory.mktemp("consumer") / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=0, n_check=0, points_per_image=120, seed=0)
    return block, root, write_terrain_dem(block, root / "dem.tif")


def _datum(ba, block):
    """The adjusted projection centres' mean error (the datum's: the frames' own noise averages out) and their
    median reported sigma, per axis (m)."""
    idx = {k: i for i, k in enumerate(block.image_id)}
    true = block.frame.to_map(block.centre_local)[[idx[k] for k in ba.eo_map.image_id]]
    return (ba.eo_map.centre_m - true).mean(axis=0), np.median(ba.eo_map.sigma[:, :3], axis=0)


def test_the_flight_offset_model_states_metres_where_the_survey_model_claims_centimetres(consumer_block):
    block, root, _ = consumer_block
    _gnss(root, offset=False)
    err, sig = _datum(adjust_project(root, SETTINGS), block)
    assert np.all(np.abs(err / sig) > 10), (err, sig)  # the survey receiver's weights: a centimetre claim, metres off
    _gnss(root, offset=True)
    ba = adjust_project(root, dataclasses.replace(SETTINGS, point_covariances=True))
    err, sig = _datum(ba, block)
    assert np.all(np.abs(err) > 1.5) and np.all(np.abs(err / sig) < 2.5), (err, sig)
    assert sig[0] > 2.5 and sig[2] > 4.0  # the offset's a-priori 3 / 5 m, nothing more from the images
    assert ba.opts.gnss_correction == "offset"
    rep = to_record(build_report(ba))
    modes = {g["mode"]: g for g in rep["geometry_modes"]}
    assert modes["height"]["sigma_m"] > 4.0 and modes["height"]["held_by_priors"]
    assert rep["key_statistics"]["verdict"] == "weak" and "block height held only by" in rep["key_statistics"]["message"]
    note = next(n for n in rep["datum"] if n.startswith("GNSS:"))
    assert "one 3-D offset for the whole flight" in note and "offset_sigma_xy_m" in note and "[gnss] sigma_xy_m" in note
    # the receiver is 2.5 / -2.0 / 3.0 m off and nothing observes it: the offset's prior mean (0) is no estimate
    # (the note read "estimated E -0.00 N +0.00 U +0.00 m")
    assert "estimated E" not in note and "its a-priori value, not a measurement of the receiver" in note
    # the settings block lists gnss_correction = none (no per-strip correction) and says the flight's offset is estimated
    from aerotri.adjust.pipeline import project_settings
    from aerotri.core.project import Project

    resolved = project_settings(Project.open(root))
    assert resolved.settings.gnss_correction == "none"
    assert "one GNSS offset for the flight, estimated where control points or a DEM observe it" in resolved.notes[
        "gnss_correction"]


def test_with_a_dem_the_height_offset_is_estimated(consumer_block):
    block, root, dem = consumer_block
    _gnss(root, offset=True)
    ba = adjust_project(root, dataclasses.replace(SETTINGS, dem=dem, surface_sigma_m=0.05))
    err, sig = _datum(ba, block)
    assert abs(err[2]) < 0.3 and sig[2] < 0.3 and np.all(np.abs(err / sig) < 3.0), (err, sig)
    # the estimated offset (GNSS minus the adjusted antenna, common part) recovers the simulated height offset
    assert ba.result.state.shift[0][2] == pytest.approx(OFFSET_M[2], abs=0.3)
    rep = build_report(ba)
    assert rep.key_statistics["gnss_corrections_suspect"] == []  # 3 m within the 3 / 5 m a priori
    note = next(n for n in to_record(rep)["datum"] if n.startswith("GNSS:"))  # the DEM observes it: estimated
    assert f"estimated E {ba.result.state.shift[0][0]:+.2f}" in note and "not a measurement" not in note


def test_per_strip_shifts_need_no_control_with_the_offset_sigma(consumer_block):
    block, root, _ = consumer_block
    _gnss(root, offset=True)
    ba = adjust_project(root, dataclasses.replace(SETTINGS, gnss_correction="shift"))
    assert ba.opts.gnss_correction == "shift" and ba.result.state.shift.shape == (3, 3)
    err, sig = _datum(ba, block)
    assert np.all(np.abs(err / sig) < 2.5), (err, sig)


def test_a_drift_along_a_strip_is_judged_by_the_between_frame_sigmas(consumer_block, tmp_path):
    """The undetected-drift check of a consumer block (one offset for the flight): the residuals' trend along a strip
    against the positions' own sigmas between frames (0.2 m here), not a survey receiver's gnss_shift_sigma_m. The
    sound block (0.2 m noise about the offset): nothing flagged. Strip 2's east positions drifting by +-1.5 m from
    end to end (3 m, a receiver wandering along the strip): that strip's east trend flagged, the verdict weak with the
    consumer's advice."""
    import shutil

    from aerotri.adjust.report import unmodelled_drift_check
    from aerotri.geom.eo import read_gnss, write_gnss

    _, root, _ = consumer_block
    _gnss(root, offset=True)
    ba = adjust_project(root, SETTINGS)
    udc = unmodelled_drift_check(ba)
    assert udc.trends == () and udc.n == 9 and udc.sigma_axis_m == (NOISE_M,) * 3, udc
    assert "trend along strips" not in build_report(ba).key_statistics["message"]
    p = shutil.copytree(root, tmp_path / "blk")
    g = read_gnss(p / "gnss.txt")
    strip2 = np.flatnonzero([i.startswith("s02") for i in g.image_id])
    pos = g.position_m.copy()
    pos[strip2, 0] += np.linspace(-1.5, 1.5, len(strip2))
    write_gnss(p / "gnss.txt", type(g)(g.image_id, pos, g.sigma_m))
    ba = adjust_project(p, SETTINGS)
    udc = unmodelled_drift_check(ba)
    assert [(s, a) for s, a, _, _ in udc.trends] == [(2, "E")], udc
    assert abs(udc.trends[0][2]) > 0.7  # the tie points hold part of the drift: the residual trend understates it
    ks = build_report(ba).key_statistics
    assert ks["verdict"] == "weak" and "strip 2 E" in ks["message"], ks["message"]
    assert "beyond 0.2 m ([gnss] sigma_xy_m, sigma_z_m" in ks["message"] and 'gnss_correction = "offset"' in ks["message"]
    assert "The receiver wanders along the strips" in ks["message"]


def test_an_offset_beyond_its_a_priori_sigmas_is_suspect_with_plan_and_height(consumer_block, tmp_path):
    """Every GNSS height 20 m too high (the offset's U 23 m, 4.6 of its a-priori 5 m): with the DEM the offset is
    estimated, flagged as suspect, and the message states the plan / height a-priori sigmas (3 / 5 m)."""
    import shutil

    from aerotri.geom.eo import read_gnss, write_gnss

    _, root, dem = consumer_block
    _gnss(root, offset=True)
    p = shutil.copytree(root, tmp_path / "blk")
    g = read_gnss(p / "gnss.txt")
    write_gnss(p / "gnss.txt", type(g)(g.image_id, g.position_m + [0.0, 0.0, 20.0], g.sigma_m))
    ba = adjust_project(p, dataclasses.replace(SETTINGS, dem=p / "dem.tif", surface_sigma_m=0.05))
    ks = build_report(ba).key_statistics
    assert [(s["term"], s["axis"]) for s in ks["gnss_corrections_suspect"]] == [("offset", "U")], ks
    assert ks["gnss_corrections_suspect"][0]["displacement_m"] == pytest.approx(OFFSET_M[2] + 20.0, abs=0.3)
    assert ("a-priori sigmas of 3 / 5 m (plan / height; [gnss] offset_sigma_xy_m, offset_sigma_z_m; 1 % false "
            "alarms over the block's 3 estimates): flight offset U") in ks["message"], ks["message"]
