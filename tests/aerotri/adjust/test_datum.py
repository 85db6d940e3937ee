"""The datum step of blocks whose datum is control points alone (aerotri.adjust.datum, graph._datum_step)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from aerotri.adjust import graph as G
from aerotri.adjust.datum import Similarity, fit_similarity
from aerotri.adjust.pipeline import AdjustSettings, prepare_project
from aerotri.geom.rotation import FLIP_YZ
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def test_fit_similarity_recovers_a_known_transformation():
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-800, 800, 7), rng.uniform(-500, 500, 7), rng.uniform(0, 60, 7)])
    true = Similarity(Rotation.from_euler("xyz", [14.0, -22.0, 35.0], degrees=True).as_matrix(), np.array([3.0, -2.0, 40.0]),
                      1.07, np.zeros(3))
    cov = np.tile(np.diag([0.05, 0.05, 5.0]) ** 2, (7, 1, 1))  # loose heights: anisotropic weights
    fit = fit_similarity(pts, true.apply(pts), cov)
    assert fit.cost_before > 1e6 and fit.cost_after < 1e-16
    assert np.abs(fit.similarity.apply(pts) - true.apply(pts)).max() < 1e-9  # m
    assert np.abs(fit.similarity.R - true.R).max() < 1e-12
    assert fit.similarity.scale == pytest.approx(1.07, rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(rotvec=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), t=st.lists(st.floats(-2e3, 2e3), min_size=3, max_size=3),
       log_scale=st.floats(-0.7, 0.7))
def test_similarity_leaves_image_coordinates_unchanged(rotvec, t, log_scale):
    rng = np.random.default_rng(7)
    centre = np.column_stack([rng.uniform(-500, 500, 5), rng.uniform(-500, 500, 5), np.full(5, 1000.0)])
    R_cv = Rotation.from_rotvec(rng.normal(0, 0.05, (5, 3))).as_matrix() @ FLIP_YZ  # looking down
    points = np.column_stack([rng.uniform(-300, 300, 20), rng.uniform(-300, 300, 20), rng.uniform(0, 50, 20)])
    cal = np.array([10000.0, 10000.0, 0.0, 6912.0, 3840.0, -0.02, 0.003, 1e-4, -2e-4])
    sim = Similarity(Rotation.from_rotvec(rotvec).as_matrix(), np.array(t), float(np.exp(log_scale)), np.array([10.0, 20.0, 30.0]))
    i, j = np.repeat(np.arange(5), 20), np.tile(np.arange(20), 5)
    uv, _ = G.project_cv(points[j], centre[i], R_cv[i], cal)
    uv_moved, _ = G.project_cv(sim.apply(points)[j], sim.apply(centre)[i], sim.rotate(R_cv)[i], cal)
    assert np.abs(uv_moved - uv).max() < 1e-6  # px


def _tilted_control_only_block(tmp_path, sigma_z_m, tilt_deg):
    """A 2 x 6 block without GNSS, control points with loose heights, and a start tilted by ``tilt_deg``
    about the block centre (orientations and points): the mode only the control heights hold."""
    block = geometric_block(2, 6, seed=61)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, control_sigma_m=(0.05, 0.05, sigma_z_m), n_control=5, n_check=0,
                             points_per_image=60, seed=62)
    ctx, st0 = prepare_project(root, AdjustSettings(use_gnss=False, initial_eo=str(root / "truth" / "eo.txt"), image_sigma_px=0.3))
    tilt = Similarity(Rotation.from_rotvec([0.0, np.radians(tilt_deg), 0.0]).as_matrix(), np.zeros(3), 1.0, st0.centre.mean(axis=0))
    start = st0.copy()
    start.centre, start.R_cv, start.points = tilt.apply(st0.centre), tilt.rotate(st0.R_cv), tilt.apply(st0.points)
    return ctx.block, ctx.opts, start


@pytest.mark.parametrize("sigma_z_m,tilt_deg", [(200.0, 10.0), (1000.0, 15.0)])
def test_control_only_block_converges_to_the_minimum(tmp_path, sigma_z_m, tilt_deg):
    b, opts, start = _tilted_control_only_block(tmp_path, sigma_z_m, tilt_deg)
    act, ctrl = np.ones(len(b.obs_point), bool), np.ones(len(b.control_point), bool)
    gr = G.build_graph(b, opts, start, act, ctrl, robust=False)
    assert gr.datum is not None and len(gr.datum.point) == 5
    values, info = G.optimize(gr, opts)
    assert info.converged and info.iterations <= 10
    solved = G.state_from_values(values, b, opts, start, tie=gr.tie)
    # the minimum: Levenberg-Marquardt on the full graph (every point explicit) no longer lowers the cost
    explicit = dataclasses.replace(opts, eliminate_tie_points=False)
    _, check = G.optimize(G.build_graph(b, explicit, solved, act, ctrl, robust=False), explicit)
    assert check.chi2 == pytest.approx(info.chi2, rel=1e-9)
    # without the datum step the same iteration creeps along the tilt: at least three times the
    # iterations, and it still stops above the minimum (a decrease per iteration below the tolerance)
    gr = G.build_graph(b, opts, start, act, ctrl, robust=False)
    gr.datum = None
    _, creep = G.optimize(gr, dataclasses.replace(opts, max_iterations=10 * info.iterations))
    assert creep.iterations >= 3 * info.iterations
    assert creep.chi2 > info.chi2 * (1 + 1e-8)
