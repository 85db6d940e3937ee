"""Fixtures of the exchange tests: a small geometric block with known truth, adjusted (with self-calibration)."""

from __future__ import annotations

import pytest

from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3


@pytest.fixture(scope="session")
def adjusted_tiny(tmp_path_factory):
    """(project folder, adjustment) of a 2 x 5 frame block with 5 control and 4 check points, adjusted;
    treat it as read-only (exporters write into a folder of their own)."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path_factory.mktemp("exp") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=80, n_check=4, seed=2)
    ba, _ = run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX,
                                                self_calibration=("pp", "radial")))
    return root, ba
