"""Tie points eliminated in smart factors give the same adjustment as explicit point unknowns."""

import dataclasses

import numpy as np
import pytest

from aerotri.adjust import graph as G
from aerotri.adjust.covariance import ReducedCovariance
from aerotri.adjust.pipeline import AdjustSettings, prepare_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


@pytest.mark.parametrize("correction", ["none", "shift_drift"])
def test_smart_tie_points_match_explicit_points(tmp_path, correction):
    block = geometric_block(2, 6, seed=51)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=60, n_check=2, seed=52)
    ctx, st0 = prepare_project(root, AdjustSettings(gnss_correction=correction, image_sigma_px=0.3))
    b, opts = ctx["block"], ctx["opts"]
    act = np.ones(len(b.obs_point), bool)
    ctrl = np.ones(len(b.control_point), bool)
    solved = {}
    for smart in (True, False):
        o = dataclasses.replace(opts, eliminate_tie_points=smart)
        gr = G.build_graph(b, o, st0, act, ctrl, robust=False)
        assert (gr.smart is not None) == smart
        values, info = G.optimize(gr, o)
        st = G.state_from_values(values, b, o, st0)
        rc = ReducedCovariance(gr, values, [G.P(j) for j in range(b.n_points)])
        solved[smart] = (st, info, gr.dof, rc)
    (s1, i1, d1, c1), (s0, i0, d0, c0) = solved[True], solved[False]
    assert d1 == d0
    assert i1.chi2 == pytest.approx(i0.chi2, rel=1e-6)
    assert np.abs(s1.centre - s0.centre).max() < 1e-4  # m
    assert np.abs(s1.R_cv - s0.R_cv).max() < 1e-7
    assert np.nanmax(np.abs(s1.points - s0.points)) < 1e-4  # m, tie and control points
    # (smart factors linearise at the triangulated point, not the adjusted one: agreement to 1e-4)
    for i in range(b.n_images):
        ref = c0.marginalCovariance(G.X(i))
        assert np.allclose(c1.marginalCovariance(G.X(i)), ref, rtol=1e-4, atol=1e-4 * np.abs(ref).max())


def test_robust_and_self_calibrating_solves_keep_explicit_points(tmp_path):
    block = geometric_block(2, 4, seed=53)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=40, n_check=0, seed=54)
    ctx, st0 = prepare_project(root, AdjustSettings(image_sigma_px=0.3))
    b, opts = ctx["block"], ctx["opts"]
    act = np.ones(len(b.obs_point), bool)
    ctrl = np.ones(len(b.control_point), bool)
    assert G.build_graph(b, opts, st0, act, ctrl, robust=True).smart is None
    cal = dataclasses.replace(opts, self_calibration=("pp",))
    assert G.build_graph(b, cal, st0, act, ctrl, robust=False).smart is None
