"""The principal point held at camera.toml's value is tested against the images (trial-cam F1): a sign flipped on a
small block of two strips flown each way, GNSS only, was absorbed into the frames' kappa (2.45 deg) with "Solution
Successful"."""

from __future__ import annotations

import dataclasses
import re
import shutil

import numpy as np
import pytest

from aerotri.adjust.pipeline import adjust_project, project_settings
from aerotri.adjust.report import build_report
from aerotri.core.project import Project
from aerotri.core.records import to_record
from aerotri.sim.command import simulate_command

# the trial's Phase One-like camera, frames shrunk to 240 x 320 px (portrait), its principal point 0.5 / -0.3 mm
CAMERA = ("camera.focal_mm=50.0", "camera.sensor_width_mm=32.9", "camera.sensor_height_mm=43.857", "camera.width=240",
          "camera.height=320", "camera.ppx_mm=0.5", "camera.ppy_mm=-0.3", "camera.k1=-0.01", "camera.k2=0.005")


def certificate_block(root, camera):
    """A tiny observation-only block of the true camera ``camera`` (--set overrides), 300 tie points a frame at
    0.1 px."""
    simulate_command("tiny", root, seed=11, observations_only=True, tie_points_per_frame=300, tie_sigma_px=0.1,
                     overrides=camera)
    return root


def adjust_with_certificate(root, tmp_path, **typed):
    """A copy of ``root`` adjusted (DEM surface control, no self-calibration) with the simulator's true camera as
    camera.toml, its keys ``typed`` (e.g. ppy_mm=0.3) as a user typed them; (adjustment, report record)."""
    root = shutil.copytree(root, tmp_path / "blk")
    text = (root / "truth" / "camera.toml").read_text()
    for key, value in typed.items():
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    (root / "camera.toml").write_text(text)
    settings = project_settings(Project.open(root)).settings
    settings = dataclasses.replace(settings, self_calibration=(), dem=root / "dem.tif")
    ba = adjust_project(root, settings)
    return ba, to_record(build_report(ba))


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    return certificate_block(tmp_path_factory.mktemp("heldpp") / "blk", CAMERA)


def test_a_principal_point_held_with_its_sign_flipped_makes_the_solution_weak(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path, ppy_mm=0.3)
    test = ba.result.held_pp
    assert test.rejected and test.f_statistic > test.f_limit, test
    # freed, it goes most of the way back to the truth's -0.3 mm
    assert test.held_mm[1] + test.shift_mm[1] == pytest.approx(-0.3, abs=0.1)
    message = rec["key_statistics"]["message"]
    assert message.startswith("Solution weak.") and re.search(
        r"The principal point held at camera.toml's ppx_mm = 0.5, ppy_mm = 0.3 is not what the images give", message)


def test_the_right_principal_point_held_passes(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path)
    test = ba.result.held_pp
    assert test is not None and not test.rejected
    assert "principal point held" not in rec["key_statistics"]["message"]
    assert np.hypot(*test.shift_px) < 1.0
