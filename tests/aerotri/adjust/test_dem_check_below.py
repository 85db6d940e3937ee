"""Tie points left out below the DEM fail the tie points - DEM check (trial-cam F2): a camera whose lens was typed in
other units scattered the points about the DEM both ways (NMAD 3.4 m, 2,088 of 2,342 left out by the gate), the
median stayed inside its limit and the row said "passed"."""

from __future__ import annotations

import pytest

from aerotri.adjust.dem_check import BELOW_SHARE_LIMIT
from tests.aerotri.adjust.test_held_principal_point import adjust_with_certificate, certificate_block

# a 50 mm camera on 240 x 320 px frames with strong barrel distortion (k1 on normalised coordinates)
CAMERA = ("camera.focal_mm=50.0", "camera.sensor_width_mm=32.9", "camera.sensor_height_mm=43.857", "camera.width=240",
          "camera.height=320", "camera.k1=-0.3")


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    return certificate_block(tmp_path_factory.mktemp("belowdem") / "blk", CAMERA)


def test_a_camera_without_its_distortion_puts_the_points_below_the_dem_and_fails(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path, k1=0.0)
    (check,) = ba.dem_checks
    # the median alone passes (it did, and the verdict blamed 13-43 m GNSS strip shifts)
    assert not check.offset_failed and abs(check.median_m) < check.limit_m
    assert check.below_failed and check.below_n > BELOW_SHARE_LIMIT * check.n, check
    ks = rec["key_statistics"]
    assert ks["verdict"] == "failed" and not ks["success"] and ks["dem_check_failed"] == ["surface control"]
    assert "left out by the gate below the DEM" in ks["message"]
    (row,) = rec["dem_checks"]
    assert row["below_failed"] and not row["offset_failed"] and row["below_n"] == check.below_n


def test_the_right_camera_leaves_no_point_below_the_dem(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path)
    (check,) = ba.dem_checks
    assert check.below_n == 0 and not check.failed
    assert rec["key_statistics"]["verdict"] == "successful"
