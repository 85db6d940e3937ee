"""lidarctl.raster_ops: the numba bilinear sampling gives scipy's map_coordinates(order=1, mode="nearest")."""

import numpy as np
import pytest
from scipy import ndimage

from lidarctl.raster_ops import sample_bilinear


@pytest.mark.parametrize("shape", [(30, 40), (1, 5), (5, 1), (1, 1), (2, 2)])
def test_bilinear_sampling_equals_scipy_inside_and_beyond_the_edges(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.normal(size=shape)
    cell_m, x0, y0 = 2.0, 1000.0, 5000.0
    # points inside the grid and up to 3 cells beyond every edge (edge cells extended)
    x = x0 + rng.uniform(-3 * cell_m, (shape[1] + 3) * cell_m, 20000)
    y = y0 + rng.uniform(-3 * cell_m, (shape[0] + 3) * cell_m, 20000)
    ref = ndimage.map_coordinates(a, [(y - y0) / cell_m - 0.5, (x - x0) / cell_m - 0.5], order=1, mode="nearest")
    np.testing.assert_allclose(sample_bilinear(a, x, y, cell_m, x0, y0), ref, rtol=0, atol=1e-12)
    # at a cell centre the cell's value
    i, j = shape[0] - 1, shape[1] - 1
    assert sample_bilinear(a, [x0 + (j + 0.5) * cell_m], [y0 + (i + 0.5) * cell_m], cell_m, x0, y0)[0] == \
        pytest.approx(a[i, j], abs=1e-12)
