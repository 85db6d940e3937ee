"""The start values' ground height and the "cameras below the control" refusal (review 21): judged on medians, a
terrain-following block over a slope with its control near the top was refused though every camera flew 300 m above
its own ground; now refused only when the centres lie below the lowest control point, the start values' ground then
from the flying-height guess."""

from __future__ import annotations

import numpy as np
import pytest

from aerotri.adjust.pipeline import start_ground_height_m
from aerotri.core.errors import InputError

FLYING_M = 300.0


def _slope_block():
    """Five strips over a slope rising 1,000 m across them, each frame 300 m above its ground (terrain following);
    the five control points near the top of the slope (850-1,000 m)."""
    ground = np.repeat(np.linspace(0.0, 1000.0, 5), 8) + np.random.default_rng(1).normal(0.0, 5.0, 40)
    return ground, ground + FLYING_M, np.array([850.0, 900.0, 950.0, 980.0, 1000.0])


def test_a_terrain_following_block_with_control_near_the_top_is_not_refused():
    ground, centre_z, control_z = _slope_block()
    assert np.median(centre_z) < np.median(control_z)  # what the medians refused
    z = start_ground_height_m(centre_z, control_z, FLYING_M, "gnss.txt")
    # the flying-height guess: under the centres' median, on the slope
    assert z == pytest.approx(np.median(centre_z) - FLYING_M)
    assert ground.min() < z < ground.max() and z < np.median(centre_z)
    # control around the block's middle: its median, as before
    assert start_ground_height_m(centre_z, control_z - 500.0, FLYING_M, "gnss.txt") == pytest.approx(450.0)


def test_gnss_heights_of_the_ground_or_zero_are_still_refused():
    ground, centre_z, control_z = _slope_block()
    with pytest.raises(InputError, match=r"gnss.txt: the projection centres lie .* below the lowest control point: "
                                         r"heights of the ground"):
        start_ground_height_m(ground[ground < 700.0], control_z, FLYING_M, "gnss.txt")
    with pytest.raises(InputError, match="below the lowest control point"):
        start_ground_height_m(np.zeros(40), control_z, FLYING_M, "the approximate orientations (--eo)")
    # no control with heights: the flying-height guess
    assert start_ground_height_m(np.full(4, 500.0), [], FLYING_M, "gnss.txt") == pytest.approx(200.0)
