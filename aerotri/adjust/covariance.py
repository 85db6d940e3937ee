"""A-posteriori covariances from the reduced camera system (Schur complement), without per-key calls.

The linearised normal equations are reduced by eliminating the object points (GTSAM partial
elimination; Schur-eliminated tie points arrive already reduced). The covariance of that reduced system
(orientations, calibration, GNSS unknowns) is not formed densely (O(n^2) memory, O(n^3) time: 129 s and
2.6 GB for 3,000 images): only the blocks the callers use are computed, by selected inversion
(``ReducedCovariance``). The covariance of an object point then follows from its own normal-equation
block ``V`` and its coupling ``W`` to the orientations it is seen from:
``Cov(X) = V^-1 + V^-1 W Cov(orientations) W^T V^-1`` (exact for the linearised problem).
"""

from __future__ import annotations

import contextlib
import dataclasses

import gtsam
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
from threadpoolctl import threadpool_limits

from aerotri.adjust import graph as G
from aerotri.adjust.collinearity import jacobians_cv, point_jacobian_cv, point_normals, project_cv
from aerotri.adjust.keys import K_KEY, X
from aerotri.adjust.surface import whitened

_DIM = {"x": 6, "k": 9}
# per-image and per-point unknowns stay in the band; every other key (the calibration, the lever arm, a
# strip's GNSS shift and drift) couples to many images and joins the dense border
_BAND_CHARS = frozenset("xap")
MIN_BLOCK_DIM = 240  # level sets are merged into diagonal blocks of at least this many unknowns (BLAS-3 sizes)


class _Joint:
    def __init__(self, cov, keys):
        self._cov, self._keys = cov, keys

    def at(self, ka, kb):
        return self._cov.block(ka, kb)


# OpenBLAS (0.3.30 in the scipy wheel, 0.3.31 in numpy's) crashes with a segmentation fault in its threaded
# Cholesky (potrf_parallel) once the matrix passes about 2 GB: n = 16,000 on this 2-core machine. Its
# single-threaded path does not (potrf + potri checked at n = 20,000 and 24,000). The selected inversion's
# blocks are far smaller, unless the images' graph is nearly complete (every image sees every other).
_THREADED_LAPACK_MAX_BYTES = 1 << 30
# rows of the inverse's lower triangle mirrored into the upper at a time (_inverse_spd)
_MIRROR_BLOCK_ROWS = 2048


def _inverse_spd(H: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite matrix by LAPACK potrf + potri (a quarter of the work of
    inverting the Cholesky factor and multiplying it out); ``H`` is overwritten where LAPACK can."""
    if len(H) == 0:
        return np.zeros((0, 0))
    big = H.nbytes > _THREADED_LAPACK_MAX_BYTES
    a = H.T if H.flags.c_contiguous else H  # the same symmetric matrix in Fortran order: no copy for LAPACK
    with threadpool_limits(1, user_api="blas") if big else contextlib.nullcontext():
        c, info = scipy.linalg.lapack.dpotrf(a, lower=True, overwrite_a=True)
        if info != 0:
            raise np.linalg.LinAlgError(f"reduced normal matrix not positive definite (LAPACK dpotrf info {info})")
        inv, info = scipy.linalg.lapack.dpotri(c, lower=True, overwrite_c=True)
        if info != 0:
            raise np.linalg.LinAlgError(f"reduced normal matrix singular (LAPACK dpotri info {info})")
    # potri fills the lower triangle only: mirror it block by block (an index array of the whole upper
    # triangle would take twice the matrix's memory)
    n, b = len(inv), _MIRROR_BLOCK_ROWS
    for i in range(0, n, b):
        inv[i:i + b, i:i + b] = np.tril(inv[i:i + b, i:i + b]) + np.tril(inv[i:i + b, i:i + b], -1).T
        inv[i:i + b, i + b:] = inv[i + b:, i:i + b].T
    return inv


class _ArrowInverse:
    """Selected inverse of a symmetric positive definite matrix that is block tridiagonal with a dense border:
    diagonal blocks ``A_k`` (rows ``starts[k]:starts[k+1]``), couplings ``B_k = H[k, k+1]`` and
    ``C_k = H[k, border]``, the border (the last ``n - starts[-1]`` rows) coupled to everything.

    Block LDL': ``S_k = A_k - B_{k-1}' S_{k-1}^-1 B_{k-1}``, multipliers ``M_k = B_k' S_k^-1`` and
    ``E_k = C'_k' S_k^-1`` (``C'_k = C_k - M_{k-1} C'_{k-1}``), the border's Schur complement
    ``S_d = D - sum E_k C'_k``. The inverse ``Z`` on the pattern of the factor follows backwards
    (Takahashi et al. 1973; the recursive Green's function of block-tridiagonal matrices):
    ``Z_{k+1,k} = -(Z_{k+1,k+1} M_k + Z_{k+1,d} E_k)``, ``Z_{d,k} = -(Z_{d,k+1} M_k + Z_dd E_k)``,
    ``Z_kk = S_k^-1 - M_k' Z_{k+1,k} - E_k' Z_{d,k}``. Work and memory grow with the number of blocks times
    the cube (square) of their size, not with the cube (square) of ``n``."""

    def __init__(self, H: scipy.sparse.csr_matrix, starts: np.ndarray):
        self.starts = starts = np.asarray(starts, dtype=np.int64)
        N, nb, n = len(starts) - 1, int(starts[-1]), H.shape[0]
        self.N, self.nb, self.m = N, nb, n - nb
        H = H.tocsr()
        border = slice(nb, n)
        Hd = H[:, border].toarray()  # (n, m)
        self.Sinv, self.M, self.E = [], [], []
        Sd = Hd[border].copy()
        M_prev = C_prev = None
        for k in range(N):
            a, b = starts[k], starts[k + 1]
            S = H[a:b, a:b].toarray()
            C = Hd[a:b]
            if k > 0:
                S -= M_prev @ H[starts[k - 1]:a, a:b].toarray()
                C = C - M_prev @ C_prev
            Sinv = _inverse_spd(S)
            E = C.T @ Sinv  # (m, n_k)
            Sd -= E @ C
            M = H[a:b, b:starts[k + 2]].toarray().T @ Sinv if k < N - 1 else None  # (n_{k+1}, n_k)
            self.Sinv.append(Sinv)
            self.M.append(M)
            self.E.append(E)
            M_prev, C_prev = M, C
        self.Zdd = _inverse_spd(Sd)
        # one flat store for the gather, written in place by the backward pass: per block its diagonal block
        # Z_kk, its border rows Z_dk and the sub-diagonal block Z_{k+1,k}, all row-major with the row
        # stride of block k's size; the border's Z_dd last
        size = np.diff(np.r_[starts, n])  # block N: the border
        shapes = {}
        self._diag_base = np.zeros(N + 1, dtype=np.int64)
        self._border_base = np.zeros(N + 1, dtype=np.int64)
        self._sub_base = np.full(N + 1, -1, dtype=np.int64)
        base = 0
        for k in range(N + 1):
            parts = [("diag", (size[k], size[k]))]
            if k < N:
                parts.append(("border", (self.m, size[k])))
                if k < N - 1:
                    parts.append(("sub", (size[k + 1], size[k])))
            for kind, shape in parts:
                getattr(self, f"_{kind}_base")[k] = base
                shapes[kind, k] = (base, shape)
                base += shape[0] * shape[1]
        self._z = np.empty(base)

        def view(kind, k):
            b, shape = shapes[kind, k]
            return self._z[b:b + shape[0] * shape[1]].reshape(shape)

        view("diag", N)[:] = self.Zdd
        # backwards: the diagonal blocks, the first off-diagonal blocks and the border rows of the inverse
        for k in range(N - 1, -1, -1):
            M, E = self.M[k], self.E[k]
            Zd = view("border", k)
            if k == N - 1:
                np.matmul(-self.Zdd, E, out=Zd)
                Z = self.Sinv[k] - E.T @ Zd
            else:
                Zsub = view("sub", k)
                Zsub[:] = -(view("diag", k + 1) @ M + view("border", k + 1).T @ E)
                Zd[:] = -(view("border", k + 1) @ M + self.Zdd @ E)
                Z = self.Sinv[k] - M.T @ Zsub - E.T @ Zd
            Zkk = view("diag", k)
            np.add(Z, Z.T, out=Zkk)
            Zkk *= 0.5
        self._size = size
        self._block_of = np.repeat(np.arange(N + 1), size)
        self._start = np.r_[starts, n]

    def gather(self, qi: np.ndarray, qj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Entries ``Z[qi, qj]`` (permuted indices, same shape) and a mask of those outside the computed
        pattern (their value is undefined)."""
        bi, bj = self._block_of[qi], self._block_of[qj]
        swap = bi < bj  # the store holds the lower block triangle: Z[i, j] = Z[j, i]
        qi, qj = np.where(swap, qj, qi), np.where(swap, qi, qj)
        bi, bj = np.where(swap, bj, bi), np.where(swap, bi, bj)
        base = np.where(bi == bj, self._diag_base[bj], np.where(bi == self.N, self._border_base[bj], self._sub_base[bj]))
        missing = (bi - bj >= 2) & (bi < self.N)
        flat = base + (qi - self._start[bi]) * self._size[bj] + (qj - self._start[bj])
        flat[missing] = 0
        return self._z[flat], missing

    def solve(self, B: np.ndarray) -> np.ndarray:
        """``H^-1 B`` (permuted order; B (n,) or (n, r)) with the block factors."""
        with threadpool_limits(1, user_api="blas"):  # blocks of a few hundred: threads only wait on each other
            return self._solve(B)

    def _solve(self, B: np.ndarray) -> np.ndarray:
        st, N, nb = self.starts, self.N, self.nb
        y = np.array(B, dtype=float, copy=True)
        yd = y[nb:]
        for k in range(N):
            if k > 0:
                y[st[k]:st[k + 1]] -= self.M[k - 1] @ y[st[k - 1]:st[k]]
            yd -= self.E[k] @ y[st[k]:st[k + 1]]
        x = np.empty_like(y)
        x[nb:] = self.Zdd @ yd
        for k in range(N - 1, -1, -1):
            a, b = st[k], st[k + 1]
            x[a:b] = self.Sinv[k] @ y[a:b] - self.E[k].T @ x[nb:]
            if k < N - 1:
                x[a:b] -= self.M[k].T @ x[b:st[k + 2]]
        return x


def _sparse_hessian(graph: gtsam.GaussianFactorGraph, offset: dict, dim: dict, n: int) -> scipy.sparse.csr_matrix:
    """The information matrix of a linear factor graph, sparse, in the scalar order of ``offset``."""
    scalars = {k: offset[k] + np.arange(dim[k]) for k in offset}
    by_size = {}  # factors of equal size: their scalar indices and information matrices, stacked at the end
    for f in range(graph.size()):
        factor = graph.at(f)
        if factor is None:
            continue
        keys = factor.keys()
        idx = scalars[keys[0]] if len(keys) == 1 else np.concatenate([scalars[k] for k in keys])
        idxs, infos = by_size.setdefault(len(idx), ([], []))
        idxs.append(idx)
        infos.append(factor.information())
    rows, cols, vals = [], [], []
    for s, (idxs, infos) in by_size.items():
        idx = np.array(idxs)  # (F, s)
        rows.append(np.repeat(idx, s, axis=1).ravel())
        cols.append(np.tile(idx, (1, s)).ravel())
        vals.append(np.array(infos).ravel())
    if not rows:
        return scipy.sparse.csr_matrix((n, n))
    return scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def _bfs_levels(adj: scipy.sparse.csr_matrix, sources: np.ndarray) -> np.ndarray:
    """Breadth-first distance of every node from the nearest of ``sources`` (inf where unreachable)."""
    n = adj.shape[0]
    if len(sources) == 1:
        return scipy.sparse.csgraph.shortest_path(adj, unweighted=True, directed=False, indices=int(sources[0]))
    hub = scipy.sparse.csr_matrix((np.ones(len(sources)), (sources, np.zeros(len(sources), dtype=np.int64))), shape=(n, 1))
    ext = scipy.sparse.bmat([[adj, hub], [hub.T, None]]).tocsr()  # a virtual node next to every source
    return scipy.sparse.csgraph.shortest_path(ext, unweighted=True, directed=False, indices=n)[:n] - 1.0


def _merge_levels(level_weight: np.ndarray, min_block: int) -> np.ndarray:
    """Block number of each level when consecutive levels are merged until a block weighs ``min_block``."""
    block = np.zeros(len(level_weight), dtype=np.int64)
    k, w = 0, 0
    for i, lw in enumerate(level_weight):
        block[i] = k
        w += lw
        if w >= min_block:
            k, w = k + 1, 0
    return block


def _level_blocks(adj: scipy.sparse.csr_matrix, weight: np.ndarray, min_block: int) -> list[np.ndarray]:
    """The nodes of a graph in consecutive blocks such that edges join only nodes of the same or of adjacent
    blocks: the level sets of a breadth-first search (Cuthill-McKee), merged until a block weighs at least
    ``min_block``. Per connected component the search starts from a pseudo-peripheral node (George & Liu
    1979), or from the whole last level of that node's search when that gives cheaper blocks (sum of their
    weights cubed): in a block of strips longer than wide the far end is one level, and the levels from it
    are straight fronts across the strips instead of the corner's L-shaped ones."""
    n = adj.shape[0]
    level = np.full(n, -1, dtype=np.int64)

    def cost(d, w):
        lw = np.bincount(d.astype(np.int64), weights=w)
        return float(np.sum(np.bincount(_merge_levels(lw, min_block), weights=lw) ** 3))

    n_comp, label = scipy.sparse.csgraph.connected_components(adj, directed=False)
    members = np.split(np.argsort(label, kind="stable"), np.cumsum(np.bincount(label, minlength=n_comp))[:-1])
    top = 0
    for nodes in sorted(members, key=lambda m: m[0]):
        if len(nodes) == 1:
            level[nodes] = top
            top += 1
            continue
        sub = adj[nodes][:, nodes].tocsr() if n_comp > 1 else adj
        degree = np.diff(sub.indptr)
        start, depth, candidates = 0, -1, []
        for _ in range(4):  # a far node of the last level, until the depth stops growing
            d = _bfs_levels(sub, np.array([start]))
            ecc = int(d.max())
            if ecc <= depth:
                break
            depth = ecc
            candidates.append(d)
            far = np.flatnonzero(d == ecc)
            start = int(far[np.argmin(degree[far])])
        candidates.append(_bfs_levels(sub, np.flatnonzero(candidates[-1] == depth)))
        best = min(candidates, key=lambda d: cost(d, weight[nodes]))
        level[nodes] = top + best.astype(np.int64)
        top += int(best.max()) + 1
    order = np.argsort(level, kind="stable")
    bounds = np.r_[0, np.flatnonzero(np.diff(level[order])) + 1, n]
    lw = np.add.reduceat(weight[order], bounds[:-1]) if n else np.zeros(0)
    blk = _merge_levels(lw, min_block)
    return [order[bounds[np.searchsorted(blk, k)]:bounds[np.searchsorted(blk, k, side="right")]]
            for k in range(int(blk.max()) + 1 if n else 0)]


def reduced_system(gr: "G.Graph", values: gtsam.Values, point_keys) -> tuple[gtsam.GaussianFactorGraph, list]:
    """The normal equations linearised at ``values`` with the points ``point_keys`` eliminated (gtsam partial
    elimination; Schur-eliminated tie points arrive already reduced), and their remaining keys, sorted."""
    gfg = gr.linearize(values)
    in_graph = set(gfg.keyVector())
    ordering = gtsam.Ordering()
    for k in point_keys:
        if k in in_graph:
            ordering.push_back(k)
    _, reduced = gfg.eliminatePartialMultifrontal(ordering)
    return reduced, sorted(set(reduced.keyVector()))


def dense_covariance(gr: "G.Graph", values: gtsam.Values, point_keys) -> np.ndarray:
    """The whole covariance by the dense inverse of the Jacobi-scaled reduced normal matrix, in the scalar
    order of ``ReducedCovariance.offset`` (sorted keys): the reference the selected inversion is checked
    against (n x n: O(n^2) memory, O(n^3) time)."""
    reduced, keys = reduced_system(gr, values, point_keys)
    order = gtsam.Ordering()
    for k in keys:
        order.push_back(k)
    H, _ = reduced.hessian(order)
    d = 1.0 / np.sqrt(np.diag(H))
    return _inverse_spd(H * d[:, None] * d[None]) * d[:, None] * d[None]


def _arrow_order(H: scipy.sparse.spmatrix, chars: list, dims: np.ndarray, min_block_dim: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The scalar order that makes ``H`` (keys of symbol ``chars`` and dimension ``dims``, in that order)
    block tridiagonal with a border (``_ArrowInverse``): the band keys by level blocks, then the others; and
    the blocks' first rows."""
    offs = np.r_[0, np.cumsum(dims)[:-1]].astype(np.int64)
    key_of = np.repeat(np.arange(len(dims)), dims)
    Hc = H.tocoo()
    adj = scipy.sparse.csr_matrix((np.ones(Hc.nnz), (key_of[Hc.row], key_of[Hc.col])), shape=(len(dims),) * 2)
    band = np.array([c in _BAND_CHARS for c in chars], dtype=bool)
    bk = np.flatnonzero(band)
    blocks = _level_blocks(adj[bk][:, bk].tocsr(), dims[bk], min_block_dim) if len(bk) else []
    key_order = [bk[b] for b in blocks] + [np.flatnonzero(~band)]
    sizes = [int(dims[ko].sum()) for ko in key_order]
    ko = np.concatenate(key_order)
    perm = np.concatenate([offs[k] + np.arange(dims[k]) for k in ko]) if len(ko) else np.zeros(0, np.int64)
    return perm, np.r_[0, np.cumsum(sizes[:-1])].astype(np.int64)


class ReducedCovariance:
    """Covariance (unit weight) of all variables except the object points, as far as the callers use it.

    Computed (selected inversion of the Jacobi-scaled reduced normal matrix, ``_ArrowInverse``): every
    key's own block, the blocks of keys that share an observation (images that see a common point), the
    border keys (calibration, lever arm, strips' GNSS shift and drift) with every key; anything else on
    demand by solves with the factor. The per-image keys are ordered by the level sets of the image graph
    (``_level_blocks``), which makes the matrix block tridiagonal apart from the border.

    Interface: ``offset``/``dim`` (scalar positions of each key), ``n``, ``block(ka, kb)``,
    ``marginalCovariance``/``jointMarginalCovariance`` (gtsam.Marginals'), ``entries(rows, cols)`` (scalar
    entries), ``multiply(b)`` (``Sigma b`` by a solve, no inverse)."""

    def __init__(self, gr: "G.Graph", values: gtsam.Values, point_keys, min_block_dim: int = MIN_BLOCK_DIM):
        reduced, keys = reduced_system(gr, values, point_keys)
        chars = [chr(gtsam.Symbol(k).chr()) for k in keys]
        dims = np.array([_DIM.get(c, 3) for c in chars], dtype=np.int64)
        self.offset = dict(zip(keys, np.r_[0, np.cumsum(dims)[:-1]].astype(int).tolist()))
        self.dim = dict(zip(keys, dims.tolist()))
        self.n = n = int(dims.sum())
        H = _sparse_hessian(reduced, self.offset, self.dim, n)
        # Jacobi scaling first: tight priors (fixed calibration terms) and metre/radian units differ by
        # many orders of magnitude, which alone would make the Cholesky factorisation fail
        diag = H.diagonal()
        if np.any(diag <= 0):
            raise np.linalg.LinAlgError("reduced normal matrix has a zero or negative diagonal")
        self._d = d = 1.0 / np.sqrt(diag)
        H = scipy.sparse.diags(d) @ H @ scipy.sparse.diags(d)
        self._perm, starts = _arrow_order(H, chars, dims, min_block_dim)
        self._pos = np.empty(n, dtype=np.int64)
        self._pos[self._perm] = np.arange(n)
        with threadpool_limits(1, user_api="blas"):  # blocks of a few hundred: threads only wait on each other
            self._inv = _ArrowInverse(H[self._perm][:, self._perm].tocsr(), starts)

    def entries(self, rows, cols) -> np.ndarray:
        """The covariance entries ``Sigma[rows, cols]`` (scalar indices, broadcast together)."""
        rows, cols = np.broadcast_arrays(np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64))
        qi, qj = self._pos[rows], self._pos[cols]
        z, missing = self._inv.gather(qi, qj)
        if missing.any():  # outside the computed pattern: those columns by solves with the factor
            need = np.unique(qj[missing])
            E = np.zeros((self.n, len(need)))
            E[need, np.arange(len(need))] = 1.0
            Zc = self._inv.solve(E)
            z[missing] = Zc[qi[missing], np.searchsorted(need, qj[missing])]
        return z * self._d[rows] * self._d[cols]

    def block(self, ka, kb) -> np.ndarray:
        a, b = self.offset[ka], self.offset[kb]
        return self.entries((a + np.arange(self.dim[ka]))[:, None], (b + np.arange(self.dim[kb]))[None, :])

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 (gtsam.Marginals interface)
        return self.block(key, key)

    def jointMarginalCovariance(self, keys) -> _Joint:  # noqa: N802
        return _Joint(self, keys)

    def multiply(self, b: np.ndarray) -> np.ndarray:
        """``Sigma b`` (b: (n,) or (n, r) in the scalar order of ``offset``) by solving with the factor."""
        b = np.asarray(b, dtype=float)
        d = self._d if b.ndim == 1 else self._d[:, None]
        x = np.empty_like(b)
        x[self._perm] = self._inv.solve((b * d)[self._perm])
        return x * d


RAY_CHUNK = 200_000  # rays linearised at a time: the per-ray Jacobians of a 10,000-frame block would take gigabytes


@dataclasses.dataclass
class PointRays:
    """The active rays' linearisation around the points, for the points' covariances: point index ``pt`` and
    image ``im`` of each ray (K,), the points' normal blocks ``V`` (P, 3, 3, rays + control + surface, unit
    weight) and their inverses ``Vinv`` (NaN for unused points). Per ray, chunk by chunk (``rays``): d pixel /
    d point ``Jp`` (k, 2, 3), d pixel / d orientation (and calibration) ``Jc`` (k, 2, 6 or 15), ``G = V^-1 W``
    (k, 3, 6 or 15) and ``idx`` the ray's orientation (and calibration) parameters in the reduced covariance
    (k, 6 or 15): recomputed from the solution where they are used, never held for all rays at once."""

    pt: np.ndarray
    im: np.ndarray
    V: np.ndarray
    Vinv: np.ndarray
    used: np.ndarray
    weight: float  # 1 / sigma_px^2
    state: "G.State"
    self_cal: bool
    pose_offset: np.ndarray  # (N,) first scalar of each image's pose in the reduced covariance
    cal_offset: int  # first scalar of the calibration (self_cal)

    def chunks(self, size: int | None = None):
        """Slices of at most ``size`` (``RAY_CHUNK``) rays covering them all."""
        size = size or RAY_CHUNK
        return [slice(a, min(a + size, len(self.pt))) for a in range(0, len(self.pt), size)]

    def rays(self, sl: slice = slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Jp, Jc, G, idx) of the rays ``sl``."""
        st, pt, im = self.state, self.pt[sl], self.im[sl]
        Jp, Jc = _ray_jacobians(st, pt, im, self.self_cal)
        G = np.einsum("kij,kaj,kab->kib", self.Vinv[pt], Jp, Jc) * self.weight  # V^-1 W_k (3 x 6 or 3 x 15)
        idx = self.pose_offset[im][:, None] + np.arange(6)[None]
        if self.self_cal:
            idx = np.concatenate([idx, np.broadcast_to(self.cal_offset + np.arange(9), (len(pt), 9))], axis=1)
        return Jp, Jc, G, idx


def _ray_jacobians(state: "G.State", pt: np.ndarray, im: np.ndarray, self_cal: bool) -> tuple[np.ndarray, np.ndarray]:
    """d pixel / d point (k, 2, 3) and d pixel / d orientation (and calibration) (k, 2, 6 or 15) of rays."""
    _, pc = project_cv(state.points[pt], state.centre[im], state.R_cv[im], state.cal)
    out = jacobians_cv(pc, state.R_cv[im], state.cal, with_cal=self_cal)
    return out[0], (np.concatenate([out[1], out[2]], axis=2) if self_cal else out[1])


def point_rays(block: "G.Block", state: "G.State", obs_active, sigma_px: float, rc: ReducedCovariance,
               self_cal: bool) -> PointRays:
    """``PointRays`` of the active observations at ``state``."""
    k = np.flatnonzero(obs_active)
    pt, im = block.obs_point[k], block.obs_image[k]
    w = 1.0 / sigma_px**2
    V = np.zeros((block.n_points, 3, 3))
    for sl in [slice(a, a + RAY_CHUNK) for a in range(0, len(k), RAY_CHUNK)]:
        _, pc = project_cv(state.points[pt[sl]], state.centre[im[sl]], state.R_cv[im[sl]], state.cal)
        V += w * point_normals(point_jacobian_cv(pc, state.R_cv[im[sl]], state.cal), pt[sl], block.n_points)
    used = np.zeros(block.n_points, dtype=bool)
    used[pt] = True
    for c, j in enumerate(block.control_point):
        if used[j]:
            V[j] += np.linalg.inv(block.control_cov_local[c])
    if block.surface is not None and block.surface_active is not None:
        # a surface observation (height above the DEM) joins its point's normal block, as in the solve
        _, B, _ = whitened(block.surface, state.points, block.surface_active)
        V += np.einsum("pi,pj->pij", B, B)
    Vinv = np.full_like(V, np.nan)
    Vinv[used] = np.linalg.inv(V[used])
    pose_off = np.array([rc.offset[X(i)] for i in range(block.n_images)])
    return PointRays(pt, im, V, Vinv, used, w, state, self_cal, pose_off, rc.offset[K_KEY] if self_cal else -1)


def point_covariances(block: "G.Block", state: "G.State", obs_active, sigma_px: float, rc: ReducedCovariance,
                      self_cal: bool, *, chunk: int = 25_000, rays: PointRays | None = None) -> np.ndarray:
    """Unit-weight covariances (P, 3, 3) of all object points in the local frame (NaN for unused); ``rays``:
    their ``point_rays`` when already at hand. ``Cov(X_j) = V_j^-1 + sum_ab G_a Sigma(a, b) G_b'`` over the
    pairs of rays (a, b) of the point, the orientations' covariance blocks gathered once per image pair; the
    rays are linearised in chunks of whole points (about ``chunk`` rays: some 5 x as many pairs)."""
    pr = rays if rays is not None else point_rays(block, state, obs_active, sigma_px, rc, self_cal)
    pt, Vinv, used = pr.pt, pr.Vinv, pr.used
    order = np.argsort(pt, kind="stable")  # rays point by point
    pts_sorted = pt[order]
    starts = np.r_[0, np.flatnonzero(np.diff(pts_sorted)) + 1]
    counts = np.diff(np.r_[starts, len(order)])
    n_img = block.n_images
    im_sorted = pr.im[order].astype(np.int64)

    def pairs_of(lo: int, hi: int):
        """Every ordered pair (a, b) of rays of the same point among the sorted rays of points lo..hi-1
        (positions in ``order``)."""
        st, cn = starts[lo:hi], counts[lo:hi]
        rep = np.repeat(cn, cn)  # per ray: its point's ray count
        first = np.repeat(st, cn)
        a_idx = np.repeat(np.arange(st[0], st[0] + cn.sum()) if len(st) else np.zeros(0, np.int64), rep)
        b_idx = np.repeat(first, rep) + (np.arange(len(a_idx)) - np.repeat(np.cumsum(rep) - rep, rep))
        return a_idx, b_idx

    # chunks of whole points of about ``chunk`` rays
    bounds = np.searchsorted(np.cumsum(counts), np.arange(chunk, len(order) + chunk, chunk), side="left") + 1
    bounds = np.unique(np.r_[0, np.minimum(bounds, len(counts))])
    # the covariance blocks of the image pairs that share points, gathered once; rays of one image share their
    # parameters' indices
    keys = np.unique(np.concatenate([im_sorted[a] * n_img + im_sorted[b] for a, b in
                                     (pairs_of(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:]))] or [np.zeros(0, np.int64)]))
    d = 6 + (9 if pr.self_cal else 0)
    img_idx = pr.pose_offset[:, None] + np.arange(6)[None]  # (N, 6)
    if pr.self_cal:
        img_idx = np.concatenate([img_idx, np.broadcast_to(pr.cal_offset + np.arange(9), (n_img, 9))], axis=1)
    table = np.empty((len(keys), d, d))
    for s in range(0, len(keys), 20_000):
        ka = keys[s:s + 20_000]
        table[s:s + 20_000] = rc.entries(img_idx[ka // n_img][:, :, None], img_idx[ka % n_img][:, None, :])
    extra = np.zeros((block.n_points, 3, 3))
    with threadpool_limits(1, user_api="blas"):  # numpy's stacked matmul calls BLAS per 3 x 6 matrix
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            a_idx, b_idx = pairs_of(lo, hi)
            r0, r1 = starts[lo], starts[hi] if hi < len(starts) else len(order)
            rays_c = order[r0:r1]
            _, _, Gk, _ = pr.rays(rays_c)  # G of this chunk's rays, in sorted order
            S = table[np.searchsorted(keys, im_sorted[a_idx] * n_img + im_sorted[b_idx])]
            Ga, Gb = Gk[a_idx - r0], Gk[b_idx - r0]
            M = Ga @ S @ Gb.transpose(0, 2, 1)
            p0 = pts_sorted[r0]  # the chunk's points are a run of the sorted point indices
            p1 = pts_sorted[r1 - 1] + 1
            for i in range(3):
                for j in range(3):
                    extra[p0:p1, i, j] += np.bincount(pts_sorted[a_idx] - p0, M[:, i, j], minlength=p1 - p0)
    cov = Vinv + extra
    cov[~used] = np.nan
    return cov
