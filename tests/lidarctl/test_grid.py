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


def test_classifier_grid_helpers_equal_scipy():
    from scipy import ndimage

    from lidarctl.classify.pipeline import dilate_square, labelled_median

    rng = np.random.default_rng(3)
    mask = rng.random((120, 90)) < 0.05
    mask[0, :] = mask[:, -1] = True        # cells on the border
    for size in (3, 11):
        np.testing.assert_array_equal(dilate_square(mask, size), ndimage.binary_dilation(mask, np.ones((size, size), bool)))
    labels, n = ndimage.label(rng.random((120, 90)) < 0.4)
    values = np.round(rng.random((120, 90)), 1)     # ties, even and odd counts
    np.testing.assert_array_equal(labelled_median(values, labels, n), ndimage.median(values, labels, np.arange(1, n + 1)))


def test_mean_spacing_from_occupied_cells():
    # 40 x 40 m fully covered at 4 points/m^2 plus a far corner point: 16 + 1 occupied 10 m cells
    g = np.arange(0, 40, 0.5) + 0.25
    x, y = np.meshgrid(g, g)
    x, y = np.r_[x.ravel(), 95.0], np.r_[y.ravel(), 95.0]
    assert grid.mean_spacing_m(x, y) == np.sqrt(17 * 100.0 / len(x))
