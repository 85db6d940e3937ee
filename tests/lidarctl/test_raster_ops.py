"""lidarctl.raster_ops: the numba bilinear sampling gives scipy's map_coordinates(order=1, mode="nearest"); per-cell
reductions equal bincount and per-cell extremes."""

import numpy as np
import pytest
from scipy import ndimage

from lidarctl import raster_ops
from lidarctl.raster_ops import fill_nodata, sample_bilinear
from tests.lidarctl.test_raster_cells import _fill_nodata_arrays  # the array version the numba pull-push replaced


@pytest.mark.parametrize("shape", [(30, 40), (1, 5), (5, 1), (1, 1), (2, 2)])
def test_bilinear_sampling_equals_scipy_inside_and_beyond_the_edges(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.normal(size=shape)
    cell_m, x0, y0 = 2.0, 1000.0, 5000.0
    # points inside the grid and up to 3 cells beyond every edge (edge cells extended)
    x = x0 + rng.uniform(-3 * cell_m, (shape[1] + 3) * cell_m, 20000)
    y = y0 + rng.uniform(-3 * cell_m, (shape[0] + 3) * cell_m, 20000)
    ref = ndimage.map_coordinates(a, [(y - y0) / cell_m - 0.5, (x - x0) / cell_m - 0.5], order=1, mode="nearest")
    np.testing.assert_allclose(sample_bilinear(a, x, y, cell_m=cell_m, x0=x0, y0=y0), ref, rtol=0, atol=1e-12)
    # at a cell centre the cell's value
    i, j = shape[0] - 1, shape[1] - 1
    assert sample_bilinear(a, [x0 + (j + 0.5) * cell_m], [y0 + (i + 0.5) * cell_m], cell_m=cell_m, x0=x0, y0=y0)[0] == \
        pytest.approx(a[i, j], abs=1e-12)


def test_reduce_grid_equals_bincount_and_per_cell_extremes():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(-5, 55, 20_000), rng.uniform(-5, 35, 20_000)   # some points off the grid
    v = rng.normal(10, 3, 20_000)
    hole = (x > 20) & (x < 26) & (y > 10) & (y < 16)       # empty cells: NaN
    x, y, v = x[~hole], y[~hole], v[~hole]
    x[7] = np.nan
    c, x0, y0, nrows, ncols = 1.5, 0.0, 0.0, 20, 30
    grid = dict(cell_m=c, x0=x0, y0=y0, nrows=nrows, ncols=ncols)
    j, i = np.floor((x - x0) / c), np.floor((y - y0) / c)
    ok = (i >= 0) & (i < nrows) & (j >= 0) & (j < ncols)
    flat = (i[ok] * ncols + j[ok]).astype(int)
    n = np.bincount(flat, minlength=nrows * ncols)
    want_mean = np.bincount(flat, v[ok], minlength=nrows * ncols) / np.where(n > 0, n, np.nan)
    np.testing.assert_array_equal(raster_ops.reduce_grid(x, y, v, **grid, how="mean").ravel(), want_mean)
    want_min, want_max = np.full(nrows * ncols, np.nan), np.full(nrows * ncols, np.nan)
    np.fmin.at(want_min, flat, v[ok])
    np.fmax.at(want_max, flat, v[ok])
    np.testing.assert_array_equal(raster_ops.reduce_grid(x, y, v, **grid, how="min").ravel(), want_min)
    np.testing.assert_array_equal(raster_ops.reduce_grid(x, y, v, **grid, how="max").ravel(), want_max)
    assert np.isnan(want_mean).any() and np.isfinite(want_mean).any()


def test_tin_fill_reproduces_a_plane_and_a_window_equals_the_whole():
    """A TIN interpolates a plane: gaps (scattered cells and a 'building' block) in a tilted plane are filled
    to within the vertices' fixed jitter (at most 0.005 cell x the slope); gaps wider than the radius keep the pyramid fill; a window with a margin of
    2 r + 2 cells gets bit-identical values (tiles)."""
    from lidarctl.raster_ops import fill_nodata, fill_nodata_tin

    rows, cols = np.mgrid[0:120, 0:150]
    plane = 10.0 + 0.3 * cols - 0.2 * rows
    a = plane.copy()
    gaps = np.random.default_rng(3).random(a.shape) < 0.4
    gaps[40:60, 50:75] = True                                            # a building, 25 x 20 cells
    a[gaps] = np.nan
    f = fill_nodata_tin(a, max_radius_px=20)
    interior = np.zeros_like(gaps)
    interior[3:-3, 3:-3] = True                                          # inside the TIN's hull
    np.testing.assert_allclose(f[gaps & interior], plane[gaps & interior], atol=0.005 * 0.51)
    assert np.abs(fill_nodata(a) - plane)[40:60, 50:75].max() > 0.5    # the pyramid fill alone is blocky
    # a radius below the building's keeps the pyramid fill in its middle
    small = fill_nodata_tin(a, max_radius_px=3)
    assert small[50, 62] == fill_nodata(a)[50, 62]
    r = 20
    m = 2 * r + 2
    w = fill_nodata_tin(a[10:110, 20:140], max_radius_px=r, offset=(10, 20))
    np.testing.assert_array_equal(w[m:-m, m:-m], fill_nodata_tin(a, max_radius_px=r)[10 + m:110 - m, 20 + m:140 - m])


@pytest.mark.parametrize("shape, share", [((61, 47), 0.3), ((40, 40), 0.97), ((3, 90), 0.5), ((90, 3), 0.05),
                                          ((1, 9), 0.5), ((2, 2), 0.5)])
def test_rim_cells_are_the_valid_cells_within_two_of_a_gap(shape, share):
    # the numba scan equals the array version it replaced (a 5 x 5 maximum filter), whole array and windows
    rng = np.random.default_rng(sum(shape))
    gaps = rng.random(shape) < share
    rim = ~gaps & ndimage.maximum_filter(gaps, size=5, mode="constant", cval=False)
    (r0, r1), (c0, c1) = (sorted(rng.integers(0, n + 1, 2)) for n in shape)
    windows = [(0, shape[0], 0, shape[1]), (r0, r1, c0, c1), (min(1, shape[0]), shape[0], min(2, shape[1]), shape[1]),
               (0, 1, 0, shape[1])]
    for r_lo, r_hi, c_lo, c_hi in windows:
        keep = np.zeros(shape, bool)
        keep[r_lo:r_hi, c_lo:c_hi] = True
        vr, vc = raster_ops._rim_cells(gaps, r_lo, r_hi, c_lo, c_hi)
        er, ec = np.nonzero(rim & keep)
        np.testing.assert_array_equal(vr, er)
        np.testing.assert_array_equal(vc, ec)


def test_pull_push_fill_equals_the_array_version():
    # the numba pull and push (NaN and inf as gaps, odd and thin shapes) give the array version's fill, bit for bit
    rng = np.random.default_rng(5)
    for shape in [(97, 131), (2, 2), (3, 200), (200, 3), (2, 5), (1, 9)]:
        for share in (0.2, 0.9, 0.999):
            a = rng.normal(300, 30, shape)
            a[rng.random(shape) < share] = np.nan
            a[0, 0] = np.inf
            if np.isfinite(a).any():
                f = fill_nodata(a)
                assert np.isfinite(f).all()
                np.testing.assert_array_equal(f, _fill_nodata_arrays(a))


@pytest.mark.parametrize("shape", [(2, 2), (3, 5), (17, 33), (101, 57)])
@pytest.mark.parametrize("empty", [0.01, 0.5, 0.99])
def test_fill_nodata_first_level_from_the_raster_is_the_same_bits(shape, empty):
    # fill_nodata reads its first pyramid level from the raster itself (NaN: no value); the levels as (values,
    # weights) arrays give the same bits, for a contiguous raster and a strided one (a column of records)
    rng = np.random.default_rng(shape[0] * 100 + int(empty * 100))
    records = rng.normal(100.0, 5.0, (shape[0] * shape[1], 5))
    records[rng.random(len(records)) < empty, 2] = np.nan
    strided = records[:, 2].reshape(shape)
    for a in (strided, np.ascontiguousarray(strided)):
        assert fill_nodata(a).tobytes() == raster_ops._fill_nodata_levels(np.asarray(a, float)).tobytes()
