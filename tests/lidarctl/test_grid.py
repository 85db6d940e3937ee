"""Grid helpers of the classifier against independent references (KD-tree pairs, scipy graphs)."""

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from lidarctl import grid, synthetic


def test_segment_cell_minima_matches_kdtree_pairs_and_scipy_components():
    cloud, _ = synthetic.synthetic_scene(width_m=120.0, density_per_m2=3.0, seed=5)
    # a coarse cell and a fine one (many empty cells: minima far apart, 3-cell reach used fully)
    for cell_m in (2.0, 0.7):
        seg = grid.segment_cell_minima(cloud.x, cloud.y, cloud.z, cell_m, 0.5, 0.8)
        mx, my, mz = cloud.x[seg.lowest], cloud.y[seg.lowest], cloud.z[seg.lowest]
        assert np.array_equal(seg.lowest, grid.lowest_per_cell(seg.cid, cloud.z))
        pairs = cKDTree(np.column_stack([mx, my])).query_pairs(2.5 * cell_m, output_type="ndarray")
        a, b = pairs[:, 0], pairs[:, 1]
        dz = mz[b] - mz[a]
        linked = np.abs(dz) <= 0.5 + 0.8 * np.hypot(mx[a] - mx[b], my[a] - my[b])
        m = len(mx)
        n, label = connected_components(coo_matrix((np.ones(linked.sum()), (a[linked], b[linked])), shape=(m, m)),
                                        directed=False)
        assert n > 1 and np.array_equal(seg.label, label)
        assert np.array_equal(seg.size, np.bincount(label))
        cross = ~linked & (label[a] != label[b])
        want = sorted(zip(a[cross].tolist(), b[cross].tolist(), dz[cross].tolist()))
        assert sorted(zip(seg.ua.tolist(), seg.ub.tolist(), seg.dz.tolist())) == want
