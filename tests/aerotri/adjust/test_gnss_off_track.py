"""A GNSS position off its flight line (a wrong fix, the record of another frame) is found on the track, left out of
the adjustment by name, and the block comes out as without it. Before: an 80 m slip of the first frame of a
six-frame block was absorbed (principal point -41.6 mm, check points 9 m off, GNSS residuals 0.02 m)."""

import json
import re

import numpy as np
import pytest

from aerotri.adjust.pipeline import AdjustSettings, adjust_project, write_outputs
from aerotri.geom.strips import track_blunders
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def _track(strips=3, frames=6, base_m=300.0, side_m=900.0, wobble_m=2.0, seed=3):
    """Antenna positions of a block flown east and west in turn (flight order), with a wobble of ``wobble_m``."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(strips):
        x = np.arange(frames) * base_m
        rows += [[xi if s % 2 == 0 else x[-1] - xi, s * side_m, 1000.0] for xi in x]
    return np.array(rows) + rng.normal(0.0, wobble_m, (strips * frames, 3))


def test_a_sound_track_has_no_blunder():
    for seed in range(5):
        assert len(track_blunders(_track(seed=seed), np.full((18, 3), 0.05))) == 0


@pytest.mark.parametrize("offset", [(80.0, 0, 0), (-80.0, 0, 0), (0, 70.0, 0), (0, 0, 70.0), (150.0, 90.0, 0)])
def test_the_blunder_is_the_frame_found_wherever_it_is(offset):
    # every frame, the strips' ends (next to a turn) too: never a sound neighbour instead
    p = _track()
    for k in range(len(p)):
        q = p.copy()
        q[k] += offset
        found = track_blunders(q, np.full((len(q), 3), 0.05))
        assert found.index.tolist() == [k], (k, offset, found)
        np.testing.assert_allclose(found.deviation_m[0], offset, atol=12.0)  # 2 m wobble, extrapolated


def test_two_blunders_and_neighbours_and_a_tolerance_of_the_sigmas():
    p = _track(frames=10)
    q = p.copy()
    q[3] += (90.0, 0, 0)
    q[4] += (0, -90.0, 0)  # neighbours: the second is judged without the first
    assert sorted(track_blunders(q, np.full((len(q), 3), 0.05)).index.tolist()) == [3, 4]
    # a consumer receiver's sigma of 10 m: 80 m is within its 8 sigma
    q = p.copy()
    q[5] += (60.0, 0, 0)
    assert len(track_blunders(q, np.full((len(q), 3), 10.0))) == 0


def test_irregular_tracks_and_short_blocks_are_not_judged():
    rng = np.random.default_rng(5)
    kite = rng.uniform(0, 100, (12, 3))  # a kite's or a hand-flown drone's positions: no line to be off
    assert len(track_blunders(kite)) == 0
    assert len(track_blunders(_track(strips=1, frames=3))) == 0


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    block = geometric_block(3, 5, seed=11)
    root = write_block_project(block, tmp_path_factory.mktemp("offtrack") / "blk")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    return root


def _slipped(src, dst, line: int, offset_m) -> str:
    """A copy of the project ``src`` at ``dst`` with the position on gnss.txt's ``line`` moved by ``offset_m`` (X, Y,
    Z); the frame's id."""
    import shutil

    shutil.copytree(src, dst)
    lines = (dst / "gnss.txt").read_text().splitlines()
    t = lines[line].split()
    lines[line] = " ".join([t[0], *(f"{float(v) + d:.4f}" for v, d in zip(t[1:4], offset_m)), *t[4:]])
    (dst / "gnss.txt").write_text("\n".join(lines) + "\n")
    return t[0]


def _check_errors(ba) -> np.ndarray:
    return np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values()])


def test_the_position_is_left_out_by_name_and_the_block_is_as_without_it(project, tmp_path, caplog):
    clean = adjust_project(project, AdjustSettings(gnss_correction="shift"))
    assert clean.gnss_left_out == ()
    root = tmp_path / "blk"
    iid = _slipped(project, root, 1, (120.0, 0.0, 0.0))  # the first frame, a strip's end
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift"))
    assert [g.image_id for g in ba.gnss_left_out] == [iid]
    assert any(iid in r.message and "off the flight line" in r.message for r in caplog.records)
    # the check points as without the blunder, one GNSS position fewer (RMS X Y Z 0.050 0.017 0.286 m against
    # 0.021 0.004 0.328 m); before, "successful" at sigma0 0.62 with the check heights 49.8 m RMS off
    rms = lambda e: np.sqrt(np.mean(e * e, axis=0))  # noqa: E731
    np.testing.assert_allclose(rms(_check_errors(ba)), rms(_check_errors(clean)), atol=0.06)
    assert abs(ba.result.sigma0 - clean.result.sigma0) < 0.02 * clean.result.sigma0
    i = list(ba.block.image_id).index(iid)
    assert abs(ba.gnss_residual_m[i][0] + 120.0) < 1.0  # its residual shows the slip
    write_outputs(ba, root)
    rep = json.loads((root / "at/report.json").read_text())
    ks = rep["key_statistics"]
    assert [g["image_id"] for g in ks["gnss_left_out"]] == [iid]
    assert re.search(rf"{iid} 1[12]\d\.\d m off", ks["message"]) and "off the flight line" in ks["message"]
    # the photos' GNSS RMS is of the positions observed
    assert rep["parameters"]["rms_photo_position_m"][0] < 0.2
    assert "GNSS left out" in (root / "at/report.txt").read_text()


def test_a_slip_under_the_track_s_tolerance_is_found_by_the_frame_s_rays(tmp_path, caplog):
    """A 10 m slip in height in the middle of a strip (the track's tolerance there: 30 m): the snooping took 86 of the
    frame's 90 rays and kept the frame on its GNSS, check heights 9.2 m RMS off, sigma0 unchanged, the principal point
    blamed. Solved again without the position the frame keeps its rays: the position is left out, named."""
    block = geometric_block(3, 6, seed=11)
    root = write_block_project(block, tmp_path / "clean")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    clean = adjust_project(root, AdjustSettings(gnss_correction="none"))
    assert clean.gnss_left_out == ()
    iid = _slipped(root, tmp_path / "slip", 3, (0.0, 0.0, 10.0))
    import logging

    with caplog.at_level(logging.WARNING):
        ba = adjust_project(tmp_path / "slip", AdjustSettings(gnss_correction="none"))
    assert [g.image_id for g in ba.gnss_left_out] == [iid]
    # the warning names the other cause its rays may mean: another frame's picture (trial s96 M2)
    assert "another frame's picture under this frame's name" in caplog.text
    assert "rays" in ba.gnss_left_out[0].reason
    i = list(ba.block.image_id).index(iid)
    assert abs(ba.gnss_residual_m[i][2] + 10.0) < 0.5
    rms = lambda e: np.sqrt(np.mean(e * e, axis=0))  # noqa: E731
    # 0.072 / 0.189 / 0.483 m against 0.084 / 0.195 / 0.483 without the slip
    np.testing.assert_allclose(rms(_check_errors(ba)), rms(_check_errors(clean)), atol=0.05)
    assert ba.result.obs_active[ba.block.obs_image == i].mean() > 0.8


def test_two_records_swapped_are_both_left_out(tmp_path):
    """Neighbouring frames' records exchanged: the track finds the first (a base off), the rays the second (its frame
    placed 300 m from its tie points lost 78 of 82 rays); the check points as without the swap."""
    block = geometric_block(3, 6, seed=11)
    root = write_block_project(block, tmp_path / "clean")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    clean = adjust_project(root, AdjustSettings(gnss_correction="none"))
    lines = (root / "gnss.txt").read_text().splitlines()
    a, b = lines[3].split(), lines[4].split()
    lines[3], lines[4] = " ".join([a[0], *b[1:]]), " ".join([b[0], *a[1:]])
    import shutil

    shutil.copytree(root, tmp_path / "swap")
    (tmp_path / "swap" / "gnss.txt").write_text("\n".join(lines) + "\n")
    ba = adjust_project(tmp_path / "swap", AdjustSettings(gnss_correction="none"))
    assert sorted(g.image_id for g in ba.gnss_left_out) == sorted([a[0], b[0]])
    rms = lambda e: np.sqrt(np.mean(e * e, axis=0))  # noqa: E731
    np.testing.assert_allclose(rms(_check_errors(ba)), rms(_check_errors(clean)), atol=0.05)


def test_a_slip_a_strip_s_drift_spreads_is_found_by_its_residual(tmp_path):
    """A 2 m slip in height with a shift and drift per strip: the frame keeps its rays, the strip's drift spreads the
    slip (the demo's 15 m: residuals -10.1, +5.4, +3.0 m along the strip). The largest residual (18.7 sigma) is left
    out for a second solve; its frame then lies far from it and every other position within 5 sigma: left out."""
    block = geometric_block(3, 6, seed=11)
    root = write_block_project(block, tmp_path / "clean")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    clean = adjust_project(root, AdjustSettings(gnss_correction="shift_drift"))
    iid = _slipped(root, tmp_path / "slip", 3, (0.0, 0.0, 2.0))
    ba = adjust_project(tmp_path / "slip", AdjustSettings(gnss_correction="shift_drift"))
    assert [g.image_id for g in ba.gnss_left_out] == [iid]
    assert "its rays put the frame" in ba.gnss_left_out[0].reason
    rms = lambda e: np.sqrt(np.mean(e * e, axis=0))  # noqa: E731
    np.testing.assert_allclose(rms(_check_errors(ba)), rms(_check_errors(clean)), atol=0.02)


def test_a_frame_taken_out_of_a_strip_leaves_its_neighbours_sound():
    """Trial s96 M3: after the frame the chain refused was taken out of images/ and gnss.txt (as its message says),
    its neighbour at the strip's start read 121.4 m off its line (the next two extrapolated across the gap) and lost
    its sound position. Every frame of every strip taken out in turn: no blunder. A record of the previous frame's
    position (where a gap's prediction would put it) is still found; beside a gap at a strip's start only the
    extrapolation across it judges the frame (3 q1 - 2 q2: a tolerance of 92 m at a 300 m base, against 30 m), so a
    120 m slip there is found and an 80 m one is not."""
    p = _track(frames=8)
    for k in range(len(p)):
        q = np.delete(p, k, axis=0)
        assert len(track_blunders(q, np.full((len(q), 3), 0.05))) == 0, k
    dup = p.copy()
    dup[3] = dup[2]               # s01_004 given s01_003's record: one base back, where a gap would put it
    assert track_blunders(dup, np.full((len(p), 3), 0.05)).index.tolist() == [3]
    q = np.delete(p, 2, axis=0)   # s01_003 taken out: s01_002 (index 1) starts the strip's gap
    for lateral, found in ((120.0, [1]), (80.0, [])):
        slip = q.copy()
        slip[1] += (0.0, lateral, 0.0)   # a wrong fix beside the gap
        assert track_blunders(slip, np.full((len(q), 3), 0.05)).index.tolist() == found, lateral


def test_a_slip_the_frame_takes_up_is_found_by_its_standardised_residual(tmp_path):
    """Trial s97 H1: a 2 m slip in X (40 of its 0.05 m sigmas) in the middle of a strip of a 1,000-frame block left a
    residual of 0.355 m (7.1 sigma, under the raw residuals' 8) and the frame 1.56 m and 0.196 deg off, "Solution
    Successful": its redundancy is small, its w (residual over sigma times the root of the redundancy) 16.2. Here a
    block of 5 strips of 10 frames (the test needs 50) with a 1 m slip: before, a residual of 0.308 m (6.2 sigma) and
    nothing named (0.5 and 0.8 m the same); the clean block leaves every position in."""
    block = geometric_block(5, 10, seed=11)
    root = write_block_project(block, tmp_path / "clean")
    write_truth_observations(root, n_control=5, points_per_image=120, n_check=6, seed=12)
    clean = adjust_project(root, AdjustSettings(gnss_correction="shift_drift"))
    assert clean.gnss_left_out == ()
    iid = _slipped(root, tmp_path / "slip", 15, (1.0, 0.0, 0.0))  # the 5th frame of the second strip
    ba = adjust_project(tmp_path / "slip", AdjustSettings(gnss_correction="shift_drift"))
    assert [g.image_id for g in ba.gnss_left_out] == [iid]
    assert abs(ba.gnss_left_out[0].deviation_m[0] - 1.0) < 0.2, ba.gnss_left_out
