"""Data snooping: blunders in tie observations and a shifted control point are found and removed."""

import json

import numpy as np

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def test_blunders_removed(tmp_path):
    block = geometric_block(3, 6, seed=11)
    root = write_block_project(block, tmp_path / "blk")
    info = write_truth_observations(
        root, tie_sigma_px=0.3, n_control=5, points_per_image=120, n_check=10, seed=12,
        blunder_fraction=0.03, blunder_px_range=(5.0, 50.0), bad_control_shift_m=3.0,
    )
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, self_calibration=("pp", "radial")))
    r, b = ba.result, ba.block
    removed = {(str(b.point_id[b.obs_point[x.obs]]), b.image_id[b.obs_image[x.obs]]) for x in r.removed}
    bad = {tuple(x) for x in info["tie_blunders"]}
    n_good = info["n_tie_observations"] - len(bad)
    assert len(bad & removed) >= 0.95 * len(bad)
    assert len(removed - bad) < 0.01 * n_good
    # the shifted control point is reported by name and excluded
    assert [str(ba.control.id[c]) for c, _ in r.rejected_control] == info["bad_control"] == ["gcp01"]
    assert 0.85 < r.sigma0 < 1.15
    d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in ba.check.values()])
    assert np.sqrt(np.mean(d[:, :2] ** 2)) < 0.1 and np.sqrt(np.mean(d[:, 2] ** 2)) < 0.25
    assert json.loads((root / "truth" / "observation_blunders.json").read_text())["bad_control"] == ["gcp01"]
