"""The radial distortion held at camera.toml's values is tested against the images (trial s97 M1: a certificate's K1,
K2 on r in mm typed as the k1, k2 of normalised coordinates, nothing of the true 10 px at a Phase One frame's corner,
read "Solution weak" naming the GNSS, the control and the principal point, never the lens)."""

from __future__ import annotations

import pytest

from tests.aerotri.adjust.test_held_principal_point import CAMERA, adjust_with_certificate, certificate_block

# the principal point's trial camera with a stronger lens: -4.4 px at the corner of its 240 x 320 px frames
K1, K2 = -0.08, 0.02
LENS = tuple(c for c in CAMERA if not c.startswith(("camera.k1=", "camera.k2="))) + (f"camera.k1={K1}",
                                                                                     f"camera.k2={K2}")


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    return certificate_block(tmp_path_factory.mktemp("heldk") / "blk", LENS)


def test_radial_distortion_held_near_zero_makes_the_solution_weak_naming_the_lens(block, tmp_path):
    # the trial's mistake: the mm-based values of the true terms (K1 = k1 / f^2 with f = 50 mm)
    ba, rec = adjust_with_certificate(block, tmp_path, k1=K1 / 50.0**2, k2=K2 / 50.0**4)
    test = ba.result.held_radial
    assert test.rejected and test.f_statistic > test.f_limit and test.corner_shift_px > 3.0, test
    assert test.free[0] == pytest.approx(K1, abs=0.01), test  # freed, k1 goes back to the truth
    message = rec["key_statistics"]["message"]
    assert message.startswith("Solution weak.") and rec["key_statistics"]["radial_held_rejected"]
    assert "The radial distortion held at camera.toml's k1 = -3.2e-05" in message
    assert "k1 = K1 f^2" in message and "self_calibration \"radial\"" in message


def test_the_right_radial_distortion_held_passes(block, tmp_path):
    ba, rec = adjust_with_certificate(block, tmp_path)
    test = ba.result.held_radial
    assert test is not None and not test.rejected and test.corner_shift_px < 1.0, test
    assert not rec["key_statistics"]["radial_held_rejected"]
    assert "radial distortion held" not in rec["key_statistics"]["message"]
