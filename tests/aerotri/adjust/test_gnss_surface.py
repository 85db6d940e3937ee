"""The GNSS heights against the DEM's block height (``aerotri.adjust.gnss_surface``), on simulated blocks of known
truth: a height-system mix-up the frames' tilts take up fails the solution naming it; a right block passes; the
estimate follows the GNSS heights' true common offset."""

from __future__ import annotations

import numpy as np
from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.adjust.report import build_report
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

from tests.aerotri.adjust.test_surface import SIGMA_PX, _terrain_dem


def _block(tmp_path, *, dz_m: float = 0.0, shift_sigma_m: float = 0.0, seed: int = 11, points: int = 120, **layout):
    """A block with GNSS (heights ``dz_m`` off, and per-strip height shifts of ``shift_sigma_m``), no control, its
    terrain as the DEM; ``layout``: ``geometric_block``'s (default 2 x 5 frames at 60 / 30 % overlap)."""
    layout = {"n_strips": 2, "n_frames": 5} | layout
    block = geometric_block(**layout, seed=seed, gnss_shift_sigma_m=shift_sigma_m, gnss_drift_sigma_m_per_km=0.0)
    block.gnss_local[:, :2] -= block.gnss_shift_m[block.strip, :2]  # plan unbiased
    block.gnss_shift_m[:, :2] = 0.0
    block.gnss_local[:, 2] += dz_m
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=0, points_per_image=points, n_check=6, seed=seed + 1)
    return block, root, _terrain_dem(block, root / "dem.tif")


def _settings(dem):
    return AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX, dem=dem, surface_sigma_m=0.05)


def test_gnss_heights_30_m_high_fail_the_solution_naming_the_height_systems(tmp_path):
    """With 60 % overlap the tie points cannot follow the DEM by tilts: they stand 30 m above it, the surface gate
    leaves them out and the tie-point check fails the solution, naming the height systems (the NGI block's 30 %
    overlap let its frames tilt instead: tests/aerotri/adjust/test_ngi_realdata.py)."""
    _, root, dem = _block(tmp_path, dz_m=30.0)
    from click.testing import CliRunner

    from aerotri.cli import main

    r = CliRunner().invoke(main, ["adjust", str(root), "--dem", str(dem)])
    assert r.exit_code != 0 and "Tie points - DEM (surface control" in r.output, r.output
    assert "median +30." in r.output and "another height system than the project's ellipsoidal heights" in r.output
    assert not (root / "at" / "eo.txt").exists()


def test_the_verdict_fails_on_gnss_heights_beyond_the_height_limit_only():
    from aerotri.adjust.dem_check import DemCheck

    d = DemCheck("dem.tif", "surface control", 500, -0.001, 0.5, 0.15, 0.1, 0.18, 0.55, below_n=1,
                 gnss_offset_m=24.7, gnss_offset_limit_m=4.56, heights="EGM2008 height")
    assert not d.failed and d.gnss_significant and d.gnss_beyond(1.0) and not d.gnss_beyond(30.0)
    text = d.gnss_text(1.0)
    assert text.startswith("GNSS heights - DEM (dem.tif): the GNSS heights lie about 24.7 m above the block height")
    assert "the project's EGM2008 height" in text and "offset_sigma_z_m" in text
    small = DemCheck("dem.tif", "surface control", 500, -0.001, 0.5, 0.15, 0.1, 0.18, 0.55, below_n=1,
                     gnss_offset_m=0.25, gnss_offset_limit_m=0.17)
    assert small.gnss_significant and not small.gnss_beyond(1.0)  # a compromise within the limit: the report line


def test_right_gnss_heights_pass_and_a_common_strip_offset_is_estimated(tmp_path):
    block, root, dem = _block(tmp_path, shift_sigma_m=0.3, seed=21)
    ba = adjust_project(root, _settings(dem))
    (d,) = ba.dem_checks
    truth = float(np.mean(block.gnss_shift_m[block.strip, 2]))  # the GNSS heights' common error
    sigma = d.gnss_offset_limit_m / 3.0
    assert abs(d.gnss_offset_m - truth) < 3.0 * sigma + 0.05, (d.gnss_offset_m, truth, sigma)
    ks = build_report(ba).key_statistics
    assert ks["gnss_heights_off_dem"] == []
