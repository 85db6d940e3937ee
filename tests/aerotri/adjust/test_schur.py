"""Tie points eliminated by the Schur complement give the same adjustment as explicit point unknowns."""

import dataclasses

import gtsam
import numpy as np
import pytest

from aerotri.adjust import graph as G
from aerotri.adjust import schur
from aerotri.adjust.covariance import ReducedCovariance
from aerotri.adjust.pipeline import AdjustSettings, prepare_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def _project(root, correction="none", **kw):
    ctx, st0 = prepare_project(root, AdjustSettings(gnss_correction=correction, image_sigma_px=0.3, **kw))
    return ctx.block, ctx.opts, st0


@pytest.mark.parametrize("correction,self_cal,robust", [("none", (), False), ("shift_drift", (), False),
                                                        ("none", ("pp", "radial"), False), ("none", ("pp",), True)])
def test_schur_tie_points_match_explicit_points(tmp_path, correction, self_cal, robust):
    """Least squares (robust: the Huber M-estimate, 4 % blunders) with Schur-eliminated tie points equals
    gtsam's with explicit points."""
    block = geometric_block(2, 6, seed=51)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=60, n_check=2, seed=52,
                             blunder_fraction=0.04 if robust else 0.0)
    b, opts, st0 = _project(root, correction, self_calibration=self_cal)
    opts = dataclasses.replace(opts, relative_tolerance=1e-12)
    act = np.ones(len(b.obs_point), bool)
    ctrl = np.ones(len(b.control_point), bool)
    solved = {}
    for eliminate in (True, False):
        o = dataclasses.replace(opts, eliminate_tie_points=eliminate)
        gr = G.build_graph(b, o, st0, act, ctrl, robust=robust)
        assert (gr.tie is not None) == eliminate
        values, info = G.optimize(gr, o)
        assert info.converged
        st = G.state_from_values(values, b, o, st0, tie=gr.tie)
        rc = ReducedCovariance(gr, values, [G.P(j) for j in range(b.n_points)])
        solved[eliminate] = (st, info, gr.dof, rc)
    (s1, i1, d1, c1), (s0, i0, d0, c0) = solved[True], solved[False]
    assert d1 == d0
    assert i1.chi2 == pytest.approx(i0.chi2, rel=1e-7)
    assert np.abs(s1.centre - s0.centre).max() < 1e-5  # m
    assert np.abs(s1.R_cv - s0.R_cv).max() < 1e-8
    assert np.nanmax(np.abs(s1.points - s0.points)) < 1e-5  # m, tie and control points
    assert np.allclose(s1.cal, s0.cal, rtol=1e-9, atol=1e-9)
    for key in [G.X(i) for i in range(b.n_images)] + ([G.K_KEY] if self_cal else []):
        ref = c0.marginalCovariance(key)
        assert np.allclose(c1.marginalCovariance(key), ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())


def test_ray_jacobians_match_gtsam_retraction():
    """d(residual)/d(pose tangent), d(residual)/d(point) and d(residual)/d(Cal3DS2) against finite
    differences (the pose through gtsam's Pose3 retraction), with lens distortion."""
    rng = np.random.default_rng(5)
    cal = np.array([10000.0, 10000.0, 0.0, 6912.0, 3840.0, -2e-2, 3e-3, 1e-4, -2e-4])
    R_cv = gtsam.Rot3.RzRyRx(np.pi + 0.02, -0.03, 0.4).matrix()  # looking down
    centre = np.array([10.0, -5.0, 900.0])
    pose = G._pose(centre, R_cv)
    for _ in range(5):
        point = np.array([*rng.uniform(-300, 300, 2), rng.uniform(0, 50)])
        xy = G.project_cv(point[None], centre[None], R_cv[None], cal)[0][0] + rng.normal(0, 2, 2)
        A, B, C, r = np.empty((2, 6)), np.empty((2, 3)), np.empty((2, 9)), np.empty(2)
        assert schur._ray(xy, (centre, R_cv), point, (cal, 1 / 0.5, True), (r, A, B, C))

        def res(p, X, k=cal):
            uv = G.project_cv(X[None], p.translation()[None], p.rotation().matrix()[None], k)[0][0]
            return (xy - uv) / 0.5

        assert np.allclose(r, res(pose, point))
        h = 1e-6
        A_num = np.column_stack([(res(pose.retract(h * e), point) - res(pose.retract(-h * e), point)) / (2 * h) for e in np.eye(6)])
        B_num = np.column_stack([(res(pose, point + h * e) - res(pose, point - h * e)) / (2 * h) for e in np.eye(3)])
        # the Jacobians are of the prediction (residual = observed - predicted)
        assert np.allclose(A, -A_num, rtol=1e-5, atol=1e-3)
        assert np.allclose(B, -B_num, rtol=1e-5, atol=1e-6)
        step = np.array([1e-2, 1e-2, 1e-4, 1e-2, 1e-2, 1e-5, 1e-5, 1e-6, 1e-6])
        C_num = np.column_stack([(res(pose, point, cal + d * e) - res(pose, point, cal - d * e)) / (2 * d)
                                 for d, e in zip(step, np.eye(9))])
        assert np.allclose(C, -C_num, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("self_cal,robust", [((), False), (("focal", "pp", "radial", "tangential"), False),
                                             (("pp", "radial"), True)])
def test_reduced_system_equals_gtsam_elimination_of_the_points(tmp_path, self_cal, robust):
    """The numba Schur complement equals gtsam's own partial elimination of explicit point unknowns (robust:
    of gtsam's Huber-reweighted linearisation; 5 % of the rays are blunders of 5-50 px)."""
    block = geometric_block(2, 5, seed=55)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=2, points_per_image=30, n_check=0, seed=56,
                             blunder_fraction=0.05 if robust else 0.0)
    b, opts, st0 = _project(root, self_calibration=self_cal)
    act = np.ones(len(b.obs_point), bool)
    ctrl = np.zeros(len(b.control_point), bool)  # inactive control points are tie points here
    gr = G.build_graph(b, opts, st0, act, ctrl, robust=robust)
    if robust:
        v = G.image_residuals(b, st0) / opts.image_sigma_px
        assert (np.hypot(v[:, 0], v[:, 1]) > opts.huber_k).mean() > 0.04  # the kernel is at work
        # gtsam's robust error is the cost the step test compares
        explicit_cost = G.build_graph(b, dataclasses.replace(opts, eliminate_tie_points=False), st0, act, ctrl, robust=True)
        assert gr.reduced_cost(gr.values, gr.tie.coords) == pytest.approx(explicit_cost.graph.error(explicit_cost.values), rel=1e-10)
    explicit = G.build_graph(b, dataclasses.replace(opts, eliminate_tie_points=False), st0, act, ctrl, robust=robust)
    keys = gtsam.Ordering()
    for i in range(b.n_images):
        keys.push_back(G.X(i))
    if self_cal:
        keys.push_back(G.K_KEY)
    H_ours, g_ours = gr.linearize(gr.values).hessian(keys)
    full = explicit.graph.linearize(explicit.values)
    points = gtsam.Ordering()
    for j in np.unique(b.obs_point):
        points.push_back(G.P(j))
    _, reduced = full.eliminatePartialMultifrontal(points)
    H_ref, g_ref = reduced.hessian(keys)
    assert np.allclose(H_ours, H_ref, rtol=1e-8, atol=1e-8 * np.abs(H_ref).max())
    assert np.allclose(g_ours, g_ref, rtol=1e-8, atol=1e-8 * np.abs(g_ref).max())


def _robust_self_calibrating_graph(tmp_path):
    """The robust graph, with self-calibration (pp, radial), of a 2 x 6 block with 4 % blunders."""
    block = geometric_block(2, 6, seed=51)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=60, n_check=2, seed=52,
                             blunder_fraction=0.04)
    b, opts, st0 = _project(root, self_calibration=("pp", "radial"))
    return G.build_graph(b, opts, st0, np.ones(len(b.obs_point), bool), np.ones(len(b.control_point), bool),
                         robust=True)


def test_the_parallel_kernels_equal_the_serial_ones(tmp_path, monkeypatch):
    """Large blocks take the Schur kernel, the back-substitution and the ray cost in PARTS runs in parallel: the
    same reduced system, increments and cost as the serial run (to rounding), robust and with self-calibration."""
    gr = _robust_self_calibrating_graph(tmp_path)
    tp = gr.tie
    d_pose = np.random.default_rng(3).normal(0, 1e-4, (gr.n_images, 6))
    d_cal = np.full(9, 1e-3)

    def run():
        rs = tp.reduced_system(gr.values, gr.n_images, tp.coords)
        inc = schur.point_increments(rs.Vinv, rs.b_point, rs.W, rs.Z, tp.image, tp.pairs.start, d_pose=d_pose,
                                     d_cal=d_cal)
        return rs, inc, tp.sum_of_squares(gr.values, gr.n_images, tp.coords)

    serial = run()
    monkeypatch.setattr(schur, "PARALLEL_MIN_RAYS", 0)
    parallel = run()
    for name in ("U", "S_pair", "s", "Vinv", "b_point", "W", "U_cal", "s_cal", "U_image_cal", "Z"):
        a, c = getattr(serial[0], name), getattr(parallel[0], name)
        np.testing.assert_allclose(c, a, rtol=1e-10, atol=1e-10 * max(np.abs(a).max(), 1e-300), err_msg=name)
    assert parallel[0].f == pytest.approx(serial[0].f, rel=1e-12)
    assert parallel[0].rr == pytest.approx(serial[0].rr, rel=1e-12)
    np.testing.assert_allclose(parallel[1], serial[1], rtol=1e-12, atol=1e-15)
    assert parallel[2] == pytest.approx(serial[2], rel=1e-12)


def test_a_reused_workspace_is_overwritten_entry_by_entry(tmp_path):
    """Linearisations reuse the reduced system's arrays (``schur.Workspace``): every entry is written again, also
    those of rays behind their camera and of singular points (zeros), so a workspace full of NaN gives exactly
    what zeroed arrays give."""
    gr = _robust_self_calibrating_graph(tmp_path)
    tp, pr = gr.tie, gr.tie.pairs
    coords = tp.coords.copy()
    coords[0, 2] += 1e4  # above the cameras: every ray of point 0 behind its camera, the point singular
    rays0 = slice(pr.start[0], pr.start[1])

    def linearised(fill):
        w = schur.Workspace.for_rays(len(pr.row), len(pr.start) - 1, gr.n_images, len(pr.images), tp.self_cal)
        for f in dataclasses.fields(w):
            if getattr(w, f.name) is not None:
                getattr(w, f.name).fill(fill)
        tp.work = w
        rs = tp.reduced_system(gr.values, gr.n_images, coords)
        return {f.name: np.array(getattr(rs, f.name), copy=True) for f in dataclasses.fields(rs)}

    zeroed, reused = linearised(0.0), linearised(np.nan)
    assert not zeroed["Vinv"][0].any() and not zeroed["W"][rays0].any()
    for name, a in zeroed.items():
        np.testing.assert_array_equal(reused[name], a, err_msg=name)


def test_a_trial_step_that_throws_a_point_off_the_earth_is_damped_not_fatal(tmp_path):
    """An undamped Gauss-Newton step may throw a weak tie point thousands of km away, where the project CRS
    cannot take it (CrsError from the local frame's ECEF -> map transform): the step is rejected and damped,
    as an indeterminate one is. On the demo with one frame's tie points changed, `aerotri run` stopped with
    "EPSG:4328 -> EPSG:32649: point 34 (1499431.486, 838718.236) could not be transformed rigorously"."""
    from aerotri.core.errors import CrsError

    block = geometric_block(2, 6, seed=51)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=60, n_check=2, seed=52)
    b, opts, st0 = _project(root)
    act, ctrl = np.ones(len(b.obs_point), bool), np.ones(len(b.control_point), bool)
    solved = []
    for wild_first_step in (False, True):
        gr = G.build_graph(b, opts, st0, act, ctrl, robust=False)
        calls = []
        cost = gr.reduced_cost

        def reduced_cost(values, coords, cost=cost, calls=calls, wild=wild_first_step):
            calls.append(1)
            if wild and len(calls) == 2:  # the first trial step
                raise CrsError("EPSG:4328 -> EPSG:32649: point 34 (1499431.486, 838718.236) could not be "
                               "transformed rigorously")
            return cost(values, coords)

        gr.reduced_cost = reduced_cost
        values, info = G.optimize(gr, opts)
        assert info.converged
        solved.append((G.state_from_values(values, b, opts, st0, tie=gr.tie), info))
    (s0, i0), (s1, i1) = solved
    assert i1.chi2 == pytest.approx(i0.chi2, rel=1e-6)
    assert np.abs(s1.centre - s0.centre).max() < 1e-4  # m
