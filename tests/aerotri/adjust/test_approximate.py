"""Approximate orientations without an IMU: GNSS centres, kappa from the strip, then space resection and
intersection refine the attitudes before the bundle (blocks with tilts of several degrees)."""

import numpy as np
import pytest

from aerotri.adjust import graph as G
from aerotri.adjust.approximate import camera_rays, resect_attitudes
from aerotri.adjust.pipeline import AdjustSettings, adjust_project, prepare_project
from aerotri.geom.rotation import FLIP_YZ, rotation_matrix_opk
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3


def _angle_deg(Ra, Rb):
    dR = np.einsum("nji,njk->nik", Ra, Rb)
    return np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def test_resection_with_known_centres_recovers_attitude():
    rng = np.random.default_rng(7)
    cal = np.array([8000.0, 8000.0, 0.0, 3000.0, 2000.0, -0.05, 0.01, 1e-4, -2e-4])
    n = 4
    centre = rng.normal(0, 50, (n, 3)) + [0, 0, 1000]
    R_true = rotation_matrix_opk(rng.normal(0, 5, n), rng.normal(0, 5, n), rng.uniform(-180, 180, n)) @ FLIP_YZ
    pts = np.column_stack([rng.uniform(-300, 300, 400), rng.uniform(-300, 300, 400), rng.normal(0, 30, 400)])
    obs_point = np.tile(np.arange(400), n)
    obs_image = np.repeat(np.arange(n), 400)
    xy, _ = G.project_cv(pts[obs_point], centre[obs_image], R_true[obs_image], cal)
    xy[::50] += 40.0  # blunders: the robust weights must keep them out
    R0 = rotation_matrix_opk(np.zeros(n), np.zeros(n), np.zeros(n)) @ FLIP_YZ
    R = resect_attitudes(centre, R0, pts, obs_point, obs_image, camera_rays(xy, cal), iterations=5)
    assert _angle_deg(R_true, R).max() < 1e-3


@pytest.fixture(scope="module")
def tilted_project(tmp_path_factory):
    block = geometric_block(3, 6, seed=3, tilt_sigma_deg=5.0)
    root = write_block_project(block, tmp_path_factory.mktemp("tilt") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=120, n_check=6, seed=4)
    return block, root


def test_refinement_reduces_attitude_errors(tilted_project):
    block, root = tilted_project
    errs, resid = {}, {}
    for refine in (False, True):
        ctx, s0 = prepare_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, refine_approximations=refine))
        b = ctx.block
        idx = [block.image_id.index(i) for i in b.image_id]
        errs[refine] = _angle_deg(block.R_local[idx] @ FLIP_YZ, s0.R_cv)
        resid[refine] = np.median(np.abs(G.image_residuals(b, s0)))
    # tilts of 5 deg (sd) and kappa 1 deg: omega = phi = 0 is ~13 deg off on average; resection/intersection
    # brings it to a few degrees and the image residuals of the start from hundreds of pixels to tens
    assert errs[False].mean() > 8.0
    assert errs[True].mean() < 0.5 * errs[False].mean()
    assert resid[True] < 0.1 * resid[False]


def test_tilted_block_adjusts_to_truth(tilted_project):
    block, root = tilted_project
    ba = adjust_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, self_calibration=("pp", "radial"),
                                             point_covariances=False))
    r = ba.result
    assert r.info.converged
    assert 0.85 < r.sigma0 < 1.15
    eo = block.eo_map()
    idx = [eo.image_id.index(i) for i in ba.eo_map.image_id]
    assert np.sqrt(np.mean((ba.eo_map.centre_m - eo.centre_m[idx]) ** 2)) < 0.3
    d_opk = (ba.eo_map.opk_deg - eo.opk_deg[idx] + 180.0) % 360.0 - 180.0
    assert np.abs(d_opk).max() < 0.05
