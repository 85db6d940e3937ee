"""lidarctl strips adjust: recovery of known strip errors, corrected strips that keep every other field, bad input."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarctl.cli.main import main
from lidarctl.strips.adjust import UNDETERMINED_SIGMA, read_strip_adjustment
from lidarctl.strips.check import read_strip_check


def _adjust(paths, out, *args):
    return CliRunner().invoke(main, ["strips", "adjust", *map(str, paths), str(out), *args])


SHIFTS = np.array([[0.0, 0.0, 0.0], [0.05, -0.08, 0.15], [-0.06, 0.04, -0.05]])


@pytest.fixture(scope="module")
def shift_only_block(make_strips):
    return make_strips("strips_shift_only", SHIFTS, extras=True)


@pytest.fixture(scope="module")
def strip_adjusted(shift_only_block, tmp_path_factory):
    out = tmp_path_factory.mktemp("adj") / "out"
    r = _adjust(shift_only_block.paths, out, "--fixed", "strip_1")
    assert r.exit_code == 0, r.output
    assert "fixed: strip_1" in r.output and "not adjusted" not in r.output
    return out, read_strip_adjustment(out / "adjust.json")


def test_strip_model_brings_the_differences_to_the_noise_level(strip_adjusted, clean_block, tmp_path):
    out, s = strip_adjusted
    assert s.check_before.rms_m > 0.1 and s.fixed_strip == "strip_1" and s.model == "strip"
    r = CliRunner().invoke(main, ["strips", "check", *map(str, clean_block.paths), str(tmp_path / "clean")])
    clean = read_strip_check(tmp_path / "clean" / "strips.json").all_pairs
    # the error-free strips show what the range noise alone leaves
    assert s.check_after.rms_m <= 1.2 * clean.rms_m
    p = s.parameters
    # strip 2 was shifted 0.15 m up against strip 1 (fixed), strip 3 0.05 m down; no rotation
    for name, truth in (("strip_2.shift_z_m", 0.15), ("strip_3.shift_z_m", -0.05), ("strip_2.roll_deg", 0.0),
                        ("strip_3.roll_deg", 0.0), ("strip_2.heading_deg", 0.0)):
        assert abs(p[name].value - truth) < 3 * p[name].sigma + 0.01, name
    assert 0.7 < s.sigma0 < 1.5
    # the check after the adjustment, as its strips.json says, is the one adjust.json quotes
    after = read_strip_check(out / "check_after" / "strips.json")
    assert after.all_pairs == s.check_after
    assert s.nmad_definition == after.nmad_definition is not None  # and of one NMAD (small-fixes 4)
    # its strips are the corrected files where they are, not in the temporary folder they were written to
    assert [t.file for t in after.strips] == [str(out / f) for f in s.files] and all(Path(t.file).is_file()
                                                                                   for t in after.strips)
    # the reader gives back what was written, to the byte
    assert s.to_json() == (out / "adjust.json").read_text()
    for name in ("check_before/strips.json", "check_after/strips.json", "check_after/index.html",
                 "check_after/diff_strip_1_strip_2.tif"):
        assert (out / name).is_file()


def test_corrected_strips_keep_every_other_field_bit_for_bit(strip_adjusted, shift_only_block):
    out, _ = strip_adjusted
    for p in shift_only_block.paths:
        a, b = laspy.read(p), laspy.read(out / p.name)
        assert len(a.points) == len(b.points)
        for name in a.point_format.dimension_names:
            if name not in ("X", "Y", "Z"):
                assert np.array_equal(a[name], b[name]), name
        assert [bytes(v.record_data) for v in a.header.vlrs if v.user_id == "test_user"] == \
            [bytes(v.record_data) for v in b.header.vlrs if v.user_id == "test_user"] == [b"\x01\x02\x03"]
        assert [bytes(v.record_data) for v in b.header.evlrs] == [bytes(v.record_data) for v in a.header.evlrs]
        assert np.array_equal(a.header.scales, b.header.scales) and np.array_equal(a.header.offsets, b.header.offsets)
        assert b.header.parse_crs().to_epsg() == 32632
    moved = np.asarray(laspy.read(out / "strip_2.las").z) - np.asarray(laspy.read(shift_only_block.paths[1]).z)
    assert np.median(moved) == pytest.approx(-0.15, abs=0.03)  # strip 2 brought down to strip 1


def test_trajectory_model_recovers_boresight_and_relative_shifts(shifted_block, tmp_path):
    traj = [a for t in shifted_block.trajectories for a in ("--trajectory", str(t))]
    r = _adjust(shifted_block.paths, tmp_path / "out", *traj, "--no-png")
    assert r.exit_code == 0, r.output
    s = read_strip_adjustment(tmp_path / "out" / "adjust.json")
    p = s.parameters
    assert abs(p["boresight_roll_deg"].value - 0.05) < 3 * p["boresight_roll_deg"].sigma
    assert p["boresight_roll_deg"].sigma < 0.01
    shifts = shifted_block.errors.shifts_m
    for k in (2, 3):  # the common shift of all strips is held by the prior only: compare differences to strip 1
        d = p[f"strip_{k}.shift_z_m"].value - p["strip_1.shift_z_m"].value
        assert d == pytest.approx(shifts[k - 1, 2] - shifts[0, 2], abs=0.02)
    assert s.check_after.rms_m < 0.015
    # no control: the block's mean height is the datum, and said
    assert s.datum.startswith("block mean height held") and "datum: the block's mean height as flown" in r.output


def test_trajectory_not_covering_a_strip_is_refused(shifted_block, tmp_path):
    out = tmp_path / "out"
    r = _adjust(shifted_block.paths, out, "--trajectory", str(shifted_block.trajectories[0]))
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "strip_2.las" in r.output and "not covered by any trajectory" in r.output
    assert not out.exists()


def test_malformed_trajectory_line_is_named(shifted_block, tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("# time_s x y z roll_deg pitch_deg heading_deg\n1 2 3 4 5 6 7\n2 3 4 5 six 7 8\n")
    r = _adjust(shifted_block.paths, tmp_path / "out", "--trajectory", str(bad))
    assert r.exit_code == 2 and "bad.txt: line 3" in r.output
    assert not (tmp_path / "out").exists()


def test_trajectory_model_recovers_the_scan_angle_scale(make_strips, tmp_path):
    block = make_strips("strips_scan_scale", [[0.0, 0.0, 0.0], [0.02, -0.03, 0.04], [-0.02, 0.01, -0.03]],
                        boresight_deg=(0.03, -0.02, 0.0), range_offset_m=0.03, scan_angle_scale=3e-3)
    traj = [a for t in block.trajectories for a in ("--trajectory", str(t))]
    r = _adjust(block.paths, tmp_path / "out", *traj, "--no-png")
    assert r.exit_code == 0, r.output
    p = read_strip_adjustment(tmp_path / "out" / "adjust.json").parameters
    k = p["scan_angle_scale"]
    # 3e-3 moves the swath edges (+-20 deg at 120 m) by 13 cm; recovered within 3 sigma, and told from zero
    assert abs(k.value - 3e-3) < 3 * k.sigma and k.sigma < 1e-3
    assert abs(p["boresight_roll_deg"].value - 0.03) < 3 * p["boresight_roll_deg"].sigma


def test_free_sensor_adjustment_holds_the_blocks_mean_height(make_strips, tmp_path):
    """Without control the overlaps hardly tell a range offset from a common height shift: the free adjustment
    holds the block's mean height (the minimum-constraint datum) instead of following the range offset's estimate,
    yet still removes the boresight and the strips' relative shifts."""
    block = make_strips("strips_range_offset", [[0.0, 0.0, 0.0], [0.02, -0.03, 0.06], [-0.02, 0.01, -0.04]],
                        boresight_deg=(0.05, -0.03, 0.04), range_offset_m=0.08)
    traj = [a for t in block.trajectories for a in ("--trajectory", str(t))]
    r = _adjust(block.paths, tmp_path / "out", *traj, "--no-png")
    assert r.exit_code == 0, r.output
    s = read_strip_adjustment(tmp_path / "out" / "adjust.json")
    assert s.datum.startswith("block mean height held") and "datum: the block's mean height" in r.output
    dz = np.concatenate([np.asarray(laspy.read(tmp_path / "out" / p.name).z) - np.asarray(laspy.read(p).z)
                         for p in block.paths])
    # every point's height correction averaged over the block (buildings and trees included): within 5 mm of 0
    assert abs(dz.mean()) < 0.005, dz.mean()  # the old datum (shifts' prior only): +0.169 m
    assert s.check_after.rms_m < 0.015 < s.check_before.rms_m
    p = s.parameters
    assert abs(p["boresight_roll_deg"].value - 0.05) < 3 * p["boresight_roll_deg"].sigma
    # the range offset is still the overlaps' (weak) estimate, not pulled to 0 by the datum
    assert abs(p["range_offset_m"].value - 0.08) < 3 * p["range_offset_m"].sigma
    for k in (2, 3):
        d = p[f"strip_{k}.shift_z_m"].value - p["strip_1.shift_z_m"].value
        assert d == pytest.approx(block.errors.shifts_m[k - 1, 2], abs=0.02)


def test_sensor_parameters_the_overlaps_cannot_determine_are_held(make_strips, tmp_path):
    """Two strips (review3): the free adjustment's range offset came out +2.11 +- 0.75 m against a true 0.08 m, the z
    shifts following it and the open ground further from the truth, said on the console only; trial s98: the heading
    and pitch of two strips with trajectories (+3.35 +- 2.37 deg, -0.73 +- 0.52 deg, correlated -0.99997) were applied
    and moved points up to 19 m. Now held at 0 and said in adjust.json; three strips hold nothing and recover the
    injected roll."""
    block = make_strips("strips_two", [[0.0, 0.0, 0.0], [0.02, -0.03, 0.06], [-0.02, 0.01, -0.04]],
                        boresight_deg=(0.05, -0.03, 0.04), range_offset_m=0.08)
    for n in (2, 3):
        traj = [a for t in block.trajectories[:n] for a in ("--trajectory", str(t))]
        r = _adjust(block.paths[:n], tmp_path / f"out{n}", *traj, "--no-png")
        assert r.exit_code == 0, r.output
        s = read_strip_adjustment(tmp_path / f"out{n}" / "adjust.json")
        if n == 3:
            assert s.held == () and not any("not determined" in w for w in s.warnings)
            assert s.parameters["range_offset_m"].sigma < 0.5
            continue
        assert "range_offset_m" in s.held, s.parameters
        assert all(abs(s.parameters[h].value) < 1e-6 for h in s.held)
        assert any(w.startswith("not determined by the overlaps of 2 strips, held at 0") for w in s.warnings)
        assert "not determined by the overlaps of 2 strips" in r.output and "(held: not determined)" in r.output
        # and on the adjustment's page a QA reader opens (trial s98: adjust.json and the console only)
        page = (tmp_path / f"out{n}" / "index.html").read_text()
        assert "not determined by the overlaps of 2 strips" in page and "held: not determined" in page
        assert 'href="check_after/index.html"' in page and "boresight_roll_deg" in page
        # what is left estimated is within its limit; the roll the one overlap sees is the injected 0.05 deg to
        # 0.0074 (0.0426 +- 0.0014: the held range offset's true 0.08 m goes partly into it)
        assert all(s.parameters[n_].sigma <= lim for n_, lim in UNDETERMINED_SIGMA.items() if n_ not in s.held)
        assert s.parameters["boresight_roll_deg"].value == pytest.approx(0.05, abs=0.01)


def test_a_boresight_the_shift_prior_decides_is_not_passed_as_a_calibration(make_strips, clean_block, tmp_path):
    """trial-strips: one strip 0.5 m off along track, the others exact, flown in alternating directions: the sensor
    model read it as a boresight pitch of 6 sigma (and heading 5 sigma) under the 0.05 m shift prior, moved the exact
    strips 0.1-0.3 m and said nothing. The overlaps alone hardly determine the pitch there (its sigma grows 5x with
    the prior 10x wider): said, in the output and in adjust.json."""
    block = make_strips("strips_along_track", [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    traj = [a for t in block.trajectories for a in ("--trajectory", str(t))]
    r = _adjust(block.paths, tmp_path / "out", *traj, "--no-png")
    assert r.exit_code == 0, r.output
    s = read_strip_adjustment(tmp_path / "out" / "adjust.json")
    pitch = s.parameters["boresight_pitch_deg"]
    assert abs(pitch.value) > 3 * pitch.sigma                  # a "significant" pitch that is not there
    assert any(w.startswith("boresight_pitch_deg ") and "rests on the strips' shift prior" in w for w in s.warnings)
    assert "boresight_roll_deg" not in " ".join(s.warnings)   # the roll is the overlaps' own (across-track slopes)
    # exact strips, the same geometry: nothing significant, nothing said
    traj = [a for t in clean_block.trajectories for a in ("--trajectory", str(t))]
    r = _adjust(clean_block.paths, tmp_path / "clean", *traj, "--no-png")
    assert r.exit_code == 0, r.output
    assert read_strip_adjustment(tmp_path / "clean" / "adjust.json").warnings == ()


def test_a_heading_that_does_not_follow_the_travel_is_refused_with_its_likely_reading(shifted_block, tmp_path):
    """Trial-messy F2, F9: attitudes in radians, or a heading from east, were read as degrees clockwise from north and
    the strip adjustment ran (exit 0, corrections of 0.14-0.18 m in plan for a boresight and scan-angle scale of
    nothing). The heading follows the direction of travel up to the crab angle: refused, naming the reading that fits."""
    import math

    def variant(name, change):
        out = []
        for src in shifted_block.trajectories:
            dst = tmp_path / name / src.name
            dst.parent.mkdir(exist_ok=True)
            lines = [line if line.startswith("#") else " ".join(change(line.split()))
                     for line in src.read_text().splitlines()]
            dst.write_text("\n".join(lines) + "\n")
            out += ["--trajectory", str(dst)]
        return out

    radians = variant("rad", lambda f: f[:4] + [f"{math.radians(float(a)):.9f}" for a in f[4:7]])
    from_east = variant("east", lambda f: f[:6] + [f"{(90.0 - float(f[6])) % 360.0:.6f}"])
    for args, reading in ((radians, "in radians"), (from_east, "from east, anticlockwise")):
        out = tmp_path / "out"
        r = _adjust(shifted_block.paths, out, *args)
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        assert "off the direction of travel" in r.output and f"read {reading}" in r.output, r.output
        assert not out.exists()


def test_a_trajectory_with_a_byte_order_mark_is_read_as_without(shifted_block, tmp_path):
    """Trial-messy F3: a UTF-8 BOM (a Windows export) made the header line data: "line 1: expected 7 numbers"."""
    from lidarctl.strips.trajectory import read_trajectory

    src = shifted_block.trajectories[0]
    bom = tmp_path / src.name
    bom.write_bytes(b"\xef\xbb\xbf" + src.read_bytes().replace(b"\n", b"\r\n"))
    a, b = read_trajectory(src), read_trajectory(bom)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.xyz, b.xyz) and np.array_equal(a.rph_deg, b.rph_deg)


def test_strips_without_a_crs_record_get_the_one_given_and_the_sign_is_said(shift_only_block, tmp_path):
    """Trial s96 F3 / F4: strips adjusted with --crs came out without a CRS record (the next stage refused them);
    the console printed the strips' errors without their sign convention (+0.071 printed, the points moved -0.071)."""
    bare = []
    for p in shift_only_block.paths:
        las = laspy.read(p)
        las.header.vlrs = [v for v in las.header.vlrs if v.user_id != "LASF_Projection"]
        las.header.global_encoding.wkt = False
        q = tmp_path / "in" / p.name
        q.parent.mkdir(exist_ok=True)
        las.write(q)
        assert laspy.read(q).header.parse_crs() is None
        bare.append(q)
    r = _adjust(bare, tmp_path / "out", "--fixed", "strip_1", "--crs", "EPSG:32632")
    assert r.exit_code == 0, r.output
    assert all(laspy.read(tmp_path / "out" / q.name).header.parse_crs().to_epsg() == 32632 for q in bare)
    assert "the corrected point is p - e: a shift of +0.07 m moves the strip's points by -0.07 m" in r.output
