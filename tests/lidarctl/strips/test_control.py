"""lidarctl strips adjust --control: control points fix the datum the overlaps cannot see."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from lidarctl.cli.main import main
from lidarctl.strips.adjust import read_strip_adjustment

# every strip 0.17-0.25 m high (a common GNSS height error) plus small horizontal shifts
SHIFTS = np.array([[0.02, -0.01, 0.20], [-0.03, 0.02, 0.25], [0.01, 0.03, 0.17]])


@pytest.fixture(scope="module")
def high_block(make_strips):
    return make_strips("strips_high", SHIFTS, boresight_deg=(0.05, 0.0, 0.0))


def _run(block, out, *args, trajectory=False):
    traj = [a for t in block.trajectories for a in ("--trajectory", str(t))] if trajectory else []
    r = CliRunner().invoke(main, ["strips", "adjust", *map(str, block.paths), str(out), *traj, "--no-png", *args])
    assert r.exit_code == 0, r.output
    assert "datum: the block's mean height" not in r.output  # control points hold the datum (test_adjust.py)
    return read_strip_adjustment(out / "adjust.json")


def test_control_recovers_the_common_height_shift_the_overlaps_cannot(high_block, control_csv, tmp_path):
    gcp = str(control_csv(tmp_path / "gcp.csv"))
    # strip model: without control one strip is held fixed, the others come out relative to it
    free = _run(high_block, tmp_path / "free")
    ctl = _run(high_block, tmp_path / "ctl", "--control", gcp)
    assert ctl.fixed_strip is None
    for k in range(3):
        name = f"strip_{k + 1}.shift_z_m"
        q = ctl.parameters[name]
        assert abs(q.value - SHIFTS[k, 2]) < 3 * q.sigma and q.sigma < 0.02, name
        if name in free.parameters:
            p = free.parameters[name]
            assert abs(p.value - SHIFTS[k, 2]) > 3 * p.sigma, name  # the common 0.2 m is not seen
    c = ctl.control
    assert c.points_used >= 10 and c.mean_before_m == pytest.approx(0.2, abs=0.05)
    assert abs(c.mean_after_m) < 0.01 and c.rms_after_m < 0.03
    assert len(c.residuals) == c.observations
    assert ctl.to_json() == (tmp_path / "ctl" / "adjust.json").read_text()
    assert ctl.check_after.rms_m < 0.015  # and the strips still agree with each other
    # sensor model: the shifts' prior holds the block's height (0 m) unless control points move it; a common
    # height shift and the range offset are hardly told apart over flat ground (nadir +-20 deg), so the test
    # is the corrected block's height at the control points
    free = _run(high_block, tmp_path / "free_t", "--control", gcp, "--control-sigma-m", "1000", trajectory=True)
    ctl = _run(high_block, tmp_path / "ctl_t", "--control", gcp, trajectory=True)
    assert free.control.mean_after_m > 0.1
    assert abs(ctl.control.mean_after_m) < 0.01 and ctl.control.rms_after_m < 0.03


@pytest.mark.parametrize("text, message", [
    ("id,x,y,z\ngcp1,500010,5400010,51.0\ngcp2,500020,5400010,abc\n", "gcp.csv: line 3"),
    ("id,x,y\ngcp1,500010,5400010\n", "no 'z' column"),
    ("id,x,y,z\ngcp1,100,200,51.0\n", "none of its 1 control points lies on a smooth surface"),
])
def test_bad_control_file_is_refused(high_block, tmp_path, text, message):
    (tmp_path / "gcp.csv").write_text(text)
    out = tmp_path / "out"
    traj = [a for t in high_block.trajectories for a in ("--trajectory", str(t))]
    r = CliRunner().invoke(main, ["strips", "adjust", *map(str, high_block.paths), str(out), *traj,
                                  "--control", str(tmp_path / "gcp.csv")])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert message in r.output
    assert not out.exists()
