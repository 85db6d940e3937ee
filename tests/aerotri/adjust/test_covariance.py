"""Covariances from the reduced camera system agree with gtsam.Marginals."""

import dataclasses

import gtsam
import numpy as np
import pytest

from aerotri.adjust import graph as G
from aerotri.adjust.covariance import ReducedCovariance, point_covariances
from aerotri.adjust.pipeline import AdjustSettings, prepare_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def test_reduced_covariance_matches_gtsam_marginals(tmp_path):
    block = geometric_block(2, 5, seed=41)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=50, n_check=2, seed=42)
    ctx, st0 = prepare_project(root, AdjustSettings(gnss_correction="shift", image_sigma_px=0.3, self_calibration=("pp", "radial")))
    b, opts = ctx.block, ctx.opts
    act = np.ones(len(b.obs_point), bool)
    gr = G.build_graph(b, opts, st0, act, np.ones(len(b.control_point), bool), robust=False)
    values, _ = G.optimize(gr, opts)
    st = G.state_from_values(values, b, opts, st0, tie=gr.tie)
    gr = G.build_graph(b, opts, st, act, np.ones(len(b.control_point), bool), robust=False)
    rc = ReducedCovariance(gr, values, [G.P(j) for j in range(b.n_points)])  # tie points Schur-eliminated
    # reference: gtsam's marginals of the full graph, every point an unknown
    full = G.build_graph(b, dataclasses.replace(opts, eliminate_tie_points=False), st, act, np.ones(len(b.control_point), bool),
                         robust=False)
    marg = gtsam.Marginals(full.graph, full.values)  # full.values: the solution, with every point
    for i in (0, 4, 9):
        assert np.allclose(rc.marginalCovariance(G.X(i)), marg.marginalCovariance(G.X(i)), rtol=1e-5, atol=1e-12)
    assert np.allclose(rc.marginalCovariance(G.K_KEY), marg.marginalCovariance(G.K_KEY), rtol=1e-5, atol=1e-14)
    cov = point_covariances(b, st, act, opts.image_sigma_px, rc, self_cal=True)
    for j in list(range(0, b.n_points, max(1, b.n_points // 15))) + list(b.control_point):
        ref = marg.marginalCovariance(G.P(j))
        assert np.allclose(cov[j], ref, rtol=2e-3, atol=1e-9 * np.abs(ref).max()), j


@pytest.mark.parametrize("single_thread", [False, True])
def test_inverse_spd_matches_numpy(monkeypatch, single_thread):
    """potrf + potri and the block-wise mirroring of the lower triangle (n > the 2048 mirroring block),
    threaded and in the single-threaded path that large matrices take."""
    from aerotri.adjust import covariance

    if single_thread:
        monkeypatch.setattr(covariance, "_THREADED_LAPACK_MAX_BYTES", 0)
    rng = np.random.default_rng(8)
    A = rng.standard_normal((2600, 200))
    H = A @ A.T + 50.0 * np.eye(2600)
    ref = np.linalg.inv(H)
    inv = covariance._inverse_spd(H.copy())
    assert np.allclose(inv, inv.T, rtol=0, atol=0)
    assert np.allclose(inv, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
