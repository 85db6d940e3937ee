"""The focal length held at camera.toml's value is tested against the images where the ground's heights are observed
(s95: a drone camera file's pixel 22 % short, the DEM of its cloud as surface control, "Solution Successful" with the
block 11.8 m high; on the real frames, tests/aerotri/adjust/test_brighton_realdata.py)."""

from __future__ import annotations

import dataclasses
import re

import pytest

from aerotri.adjust.pipeline import adjust_project, project_settings
from aerotri.core.project import Project

# the principal point's block (the trial camera's observation-only block, DEM surface control) and how it is adjusted
from tests.aerotri.adjust.test_held_principal_point import adjust_with_certificate, block  # noqa: F401


def test_a_focal_length_held_10_percent_long_makes_the_solution_weak(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path, focal_mm=55.0)
    test = ba.result.held_focal
    assert test.rejected and test.f_statistic > test.f_limit, test
    truth_px = 50.0 / 55.0 * test.held_px
    assert test.free_px == pytest.approx(truth_px, rel=0.02)  # freed, it goes back to the truth
    message = rec["key_statistics"]["message"]
    assert message.startswith("Solution weak.") and rec["key_statistics"]["focal_held_rejected"]
    assert re.search(r"The focal length held at camera.toml's [0-9.]+ px \(focal_mm = 55, pixel_um = [0-9.]+\) is not "
                     r"what the images give", message)
    assert "or estimate it (self_calibration \"focal\")" in message


def test_the_right_focal_length_held_passes_and_without_ground_heights_it_is_not_tested(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path)
    test = ba.result.held_focal
    assert test is not None and not test.rejected and abs(test.shift) < 0.01, test
    assert "focal length held" not in rec["key_statistics"]["message"]
    # without the DEM and the control points (GNSS alone) the focal length is the flying height's: no test
    settings = dataclasses.replace(project_settings(Project.open(tmp_path / "blk")).settings, self_calibration=(),
                                   use_control=False, gnss_correction="none")
    assert adjust_project(tmp_path / "blk", settings).result.held_focal is None
