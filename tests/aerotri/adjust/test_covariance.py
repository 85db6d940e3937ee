"""Covariances from the reduced camera system agree with gtsam.Marginals."""

import dataclasses

import gtsam
import numpy as np
import pytest
import scipy.sparse

from aerotri.adjust import graph as G
from aerotri.adjust.covariance import ReducedCovariance, dense_covariance, point_covariances
from aerotri.adjust.pipeline import AdjustSettings, prepare_project
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations


def test_reduced_covariance_matches_gtsam_marginals(tmp_path, monkeypatch):
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
    # linearised in chunks of whole points (a 10,000-frame block's rays do not fit at once): the same covariances
    np.testing.assert_allclose(point_covariances(b, st, act, opts.image_sigma_px, rc, self_cal=True, chunk=37), cov,
                               rtol=1e-9, atol=1e-15)
    for j in list(range(0, b.n_points, max(1, b.n_points // 15))) + list(b.control_point):
        ref = marg.marginalCovariance(G.P(j))
        assert np.allclose(cov[j], ref, rtol=2e-3, atol=1e-9 * np.abs(ref).max()), j
    # the modes of the heights, the rays taken in chunks or at once
    from aerotri.adjust import covariance
    from aerotri.adjust.geometry_modes import geometry_modes

    ctrl = np.ones(len(b.control_point), bool)
    whole, _ = geometry_modes(b, opts, st, act, ctrl, rc, sigma0=1.0)
    monkeypatch.setattr(covariance, "RAY_CHUNK", 53)
    chunked, _ = geometry_modes(b, opts, st, act, ctrl, rc, sigma0=1.0)
    for m0, m1 in zip(whole, chunked):
        assert m0.mode == m1.mode and np.isclose(m0.sigma_m, m1.sigma_m, rtol=1e-9)
        assert all(np.isclose(m0.shares[k], m1.shares[k], rtol=1e-7, atol=1e-12) for k in m0.shares)


@pytest.mark.parametrize("single_thread", [False, True])
def test_inverse_spd_matches_numpy(monkeypatch, single_thread):
    """potrf + potri and the block-wise mirroring of the lower triangle (n over two mirroring blocks and a part),
    threaded and in the single-threaded path that large matrices take. The blocks are of 128 rows here (of 2048 in
    use): 2600 rows and the blocks of use took 2.8 s per case, 300 rows 0.03 s."""
    from aerotri.adjust import covariance

    if single_thread:
        monkeypatch.setattr(covariance, "_THREADED_LAPACK_MAX_BYTES", 0)
    monkeypatch.setattr(covariance, "_MIRROR_BLOCK_ROWS", 128)
    rng = np.random.default_rng(8)
    A = rng.standard_normal((300, 40))
    H = A @ A.T + 50.0 * np.eye(300)
    ref = np.linalg.inv(H)
    inv = covariance._inverse_spd(H.copy())
    assert np.allclose(inv, inv.T, rtol=0, atol=0)
    assert np.allclose(inv, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


def test_selected_inverse_equals_the_dense_inverse(tmp_path):
    """Every block the selected inversion computes (poses, image pairs sharing points, GNSS antenna/shift/
    drift and self-calibration keys) and those it computes on demand (images without a common point) equal
    the dense inverse of the reduced normal matrix to 1e-9 (relative to the two variables' sigmas), and so
    do products Sigma b; the block is cut into several blocks (level sets) with a border."""
    block = geometric_block(3, 8, seed=41)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=0.3, n_control=4, points_per_image=50, n_check=2, seed=42)
    ctx, st0 = prepare_project(root, AdjustSettings(gnss_correction="shift_drift", image_sigma_px=0.3,
                                                    self_calibration=("pp", "radial")))
    b, opts = ctx.block, ctx.opts
    act = np.ones(len(b.obs_point), bool)
    gr = G.build_graph(b, opts, st0, act, np.ones(len(b.control_point), bool), robust=False)
    values, _ = G.optimize(gr, opts)
    pk = [G.P(j) for j in range(b.n_points)]
    rc = ReducedCovariance(gr, values, pk, min_block_dim=12)
    assert rc._inv.N >= 4 and rc._inv.m == 9 + 3 + 2 * 3 * 3  # calibration, lever arm, shift and drift of 3 strips
    ref = dense_covariance(gr, values, pk)  # Jacobi-scaled dense inverse: the best dense reference
    s = np.sqrt(np.diag(ref))

    def agree(ka, kb):
        a, c = rc.offset[ka], rc.offset[kb]
        ia, ib = np.arange(a, a + rc.dim[ka]), np.arange(c, c + rc.dim[kb])
        err = np.abs(rc.block(ka, kb) - ref[np.ix_(ia, ib)]) / np.outer(s[ia], s[ib])
        return err.max() < 1e-9

    images = [G.X(i) for i in range(b.n_images)]
    shared = {tuple(sorted({int(i) for i in b.obs_image[b.obs_point == j]})) for j in range(b.n_points)}
    pairs = {(i, k) for imgs in shared for i in imgs for k in imgs}
    for i, k in pairs:
        assert agree(G.X(i), G.X(k)), (i, k)
    border = [G.K_KEY, G.L_KEY] + [G.S(t) for t in range(3)] + [G.D(t) for t in range(3)]
    for kb in border:
        for ka in images + border + [G.A(i) for i in range(b.n_images)]:
            assert agree(ka, kb), (ka, kb)
    far = [(i, k) for i in range(b.n_images) for k in range(b.n_images) if (i, k) not in pairs]
    assert far  # blocks outside the pattern: solves with the factor
    for i, k in far:
        assert agree(G.X(i), G.X(k)), (i, k)
    v = np.random.default_rng(3).standard_normal((rc.n, 4))
    assert np.allclose(rc.multiply(v), ref @ v, rtol=0, atol=1e-9 * np.abs(ref @ v).max())
    assert np.allclose(rc.multiply(v[:, 0]), ref @ v[:, 0], rtol=0, atol=1e-9 * np.abs(ref @ v[:, 0]).max())


@pytest.mark.parametrize("sizes,border", [((5, 7, 3, 6), 4), ((8,), 3), ((4, 4, 4), 0), ((), 5)])
def test_arrow_inverse_on_random_matrices(sizes, border):
    """Block-tridiagonal matrices with a dense border: the diagonal, first off-diagonal and border blocks of the
    inverse, nothing else marked as computed, and solves."""
    from aerotri.adjust.covariance import _ArrowInverse

    rng = np.random.default_rng(len(sizes) + border)
    starts = np.r_[0, np.cumsum(sizes)].astype(int)
    nb = int(starts[-1])
    n = nb + border
    blk = np.r_[np.repeat(np.arange(len(sizes)), sizes), np.full(border, 10**6)]
    coupled = (np.abs(blk[:, None] - blk[None]) <= 1) | (blk[:, None] == 10**6) | (blk[None] == 10**6)
    A = rng.standard_normal((n, n)) * coupled
    H = (A + A.T) * coupled
    H += (np.abs(H).sum(axis=1).max() + 1.0) * np.eye(n)  # diagonally dominant: positive definite
    ref = np.linalg.inv(H)
    inv = _ArrowInverse(scipy.sparse.csr_matrix(H), starts)
    qi, qj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    z, missing = inv.gather(qi, qj)
    assert np.array_equal(missing, ~coupled)
    assert np.allclose(z[~missing], ref[~missing], rtol=0, atol=1e-12)
    B = rng.standard_normal((n, 2))
    assert np.allclose(inv.solve(B), ref @ B, rtol=0, atol=1e-12)


def test_level_blocks_couple_only_neighbours():
    """A 12 x 7 grid of images (each sees its 8 neighbours): blocks of consecutive level sets, edges only within
    a block or between adjacent blocks, every node once; the levels run across the grid's short side."""
    from aerotri.adjust.covariance import _level_blocks

    def grid(rows, cols):
        r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
        r, c = r.ravel(), c.ravel()
        return (np.abs(r[:, None] - r[None]) <= 1) & (np.abs(c[:, None] - c[None]) <= 1)

    edges = grid(12, 7)
    adj = scipy.sparse.csr_matrix(edges.astype(float))
    # and a block in three pieces: a 5 x 3 grid, two images without ties, the 12 x 7 grid
    parts = scipy.sparse.block_diag([grid(5, 3), np.eye(2), edges]).toarray() != 0
    for e in (edges, parts):
        for min_block in (1, 18, 40):
            blocks = _level_blocks(scipy.sparse.csr_matrix(e.astype(float)), np.full(len(e), 6), min_block)
            assert np.array_equal(np.sort(np.concatenate(blocks)), np.arange(len(e)))
            which = np.empty(len(e), int)
            for k, bl in enumerate(blocks):
                which[bl] = k
            i, j = np.nonzero(e)
            assert np.all(np.abs(which[i] - which[j]) <= 1)
            assert all(6 * len(bl) >= min_block for bl in blocks[:-1])
    # from the far row, not from a corner: straight fronts, one per row of 7 (a corner's L-shapes grow to 18)
    assert [len(bl) for bl in _level_blocks(adj, np.full(len(edges), 6), 1)] == [7] * 12
