"""The surface at the cell centres from the nearest return (``lidarctl.rasters.nearest``) on a box building."""

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarctl.rasters.nearest import NearestReturns, first_return_mask, nearest_return_surface

RES_M, N, SPACING_M, ROOF_M = 0.5, 80, 0.75, 10.0


def _box_block(seed: int):
    """Returns on a jittered 0.75 m lattice (the demo's spacing) over a 20 x 12 m box building 10 m high, at an
    angle to the 0.5 m grid; the grid's cell centres and which of them the roof covers (the truth)."""
    rng = np.random.default_rng(seed)
    box = shapely.affinity.rotate(shapely.box(-10, -6, 10, 6), 30 + 10 * seed, origin=(0, 0))
    g = np.arange(-30, 30, SPACING_M)
    gx, gy = np.meshgrid(g, g)
    x = gx.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.13
    y = gy.ravel() + rng.uniform(-0.3, 0.3, gx.size) * SPACING_M + 0.07
    z = np.where(shapely.contains_xy(box, x, y), ROOF_M, 0.0)
    cx, cy = np.meshgrid(-20 + (np.arange(N) + 0.5) * RES_M, 20 - (np.arange(N) + 0.5) * RES_M)
    return box, x, y, z, cx, cy, shapely.contains_xy(box, cx, cy)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_roof_edge_within_a_cell_and_as_wide_as_the_roof(seed):
    box, x, y, z, cx, cy, truth = _box_block(seed)
    surface = nearest_return_surface(x, y, z, x0_m=-20.0, y_top_m=20.0, res_m=RES_M, nrows=N, ncols=N, max_dist_m=5.0)
    assert np.isfinite(surface).all()
    roof = surface > ROOF_M / 2
    wrong = roof != truth
    # every centre on the wrong side of the wall lies within one cell of it
    assert shapely.distance(box.exterior, shapely.points(cx[wrong], cy[wrong])).max() < RES_M
    assert abs(int(roof.sum()) - int(truth.sum())) < 0.03 * truth.sum()


def test_nearest_within_reach_and_ties_take_the_higher_return():
    # centres of a 1 x 3 grid of 1 m cells at x = 0.5, 1.5, 2.5; returns at x = 0.5 (z 1) and x = 2.5 (z 2, 3)
    x, y, z = np.array([0.5, 2.5, 2.5]), np.array([0.5, 0.5, 0.5]), np.array([1.0, 2.0, 3.0])
    s = nearest_return_surface(x, y, z, x0_m=0.0, y_top_m=1.0, res_m=1.0, nrows=1, ncols=3, max_dist_m=1.5)
    assert s.tolist() == [[1.0, 3.0, 3.0]]
    s = nearest_return_surface(x[:1], y[:1], z[:1], x0_m=0.0, y_top_m=1.0, res_m=1.0, nrows=1, ncols=3,
                               max_dist_m=1.5)
    assert s[0, :2].tolist() == [1.0, 1.0] and np.isnan(s[0, 2])


def _brute_force(x, y, z, *, x0_m, y_top_m, res_m, nrows, ncols, max_dist_m):
    """Every cell centre against every return on the grid: the nearest within max_dist_m (not at it), ties the
    highest, NaN where none (the definition the ring search and its scattered first rings must meet)."""
    on = (np.floor((y_top_m - y) / res_m) >= 0) & (np.floor((y_top_m - y) / res_m) < nrows) \
        & (np.floor((x - x0_m) / res_m) >= 0) & (np.floor((x - x0_m) / res_m) < ncols)
    x, y, z = x[on], y[on], z[on]
    out = np.full((nrows, ncols), np.nan, np.float32)
    for i in range(nrows):
        cy = y_top_m - (i + 0.5) * res_m
        for j in range(ncols):
            cx = x0_m + (j + 0.5) * res_m
            d = (x - cx) ** 2 + (y - cy) ** 2
            inside = d < max_dist_m ** 2
            if inside.any():
                best = d[inside].min()
                out[i, j] = z[inside & (d == best)].max()
    return out


grid_kw = st.fixed_dictionaries(dict(
    x0_m=st.sampled_from([-3.0, 0.0, 0.375]), y_top_m=st.sampled_from([2.0, 5.5]),
    res_m=st.sampled_from([0.25, 0.5, 1.0]), nrows=st.integers(1, 9), ncols=st.integers(1, 9),
    max_dist_m=st.sampled_from([0.2, 0.5, 1.0, 1.6, 2.5])))


@settings(max_examples=150, deadline=None)
@given(grid_kw, st.lists(st.tuples(st.integers(-40, 80), st.integers(-40, 80), st.integers(0, 3)), max_size=80))
def test_nearest_equals_brute_force_on_a_lattice(kw, points):
    # returns on a 1/8 m lattice (every coordinate, centre and squared distance exact): on cell edges, equally far
    # from a centre, at exactly the search radius, off the grid; heights tied too
    x, y, z = (np.array([p[k] for p in points], float).reshape(-1) for k in range(3))
    x, y = x / 8 + kw["x0_m"] - 1.0, kw["y_top_m"] - y / 8 + 1.0
    np.testing.assert_array_equal(nearest_return_surface(x, y, z, **kw), _brute_force(x, y, z, **kw))


@settings(max_examples=60, deadline=None)
@given(grid_kw, st.integers(0, 400), st.integers(0, 2**32 - 1))
def test_nearest_equals_brute_force_on_random_points(kw, n, seed):
    rng = np.random.default_rng(seed)
    w, h = kw["ncols"] * kw["res_m"], kw["nrows"] * kw["res_m"]
    x = kw["x0_m"] + rng.uniform(-0.3 * w - 1, 1.3 * w + 1, n)
    y = kw["y_top_m"] - rng.uniform(-0.3 * h - 1, 1.3 * h + 1, n)
    z = rng.normal(0, 10, n)
    np.testing.assert_array_equal(nearest_return_surface(x, y, z, **kw), _brute_force(x, y, z, **kw))


def test_chunks_read_twice_take_the_first_returns_not_noise():
    """``NearestReturns`` over chunks (counted, then added) equals the surface of the first returns that are not
    noise (classes 7, 18) of all of them."""
    rng = np.random.default_rng(7)
    n = 5000
    x, y, z = rng.uniform(0, 30, n), rng.uniform(0, 30, n), rng.uniform(0, 20, n)
    cls = rng.choice(np.array([1, 2, 5, 7, 18], np.uint8), n)
    rn = rng.integers(1, 4, n).astype(np.uint8)
    kw = dict(x0_m=2.0, y_top_m=28.0, res_m=0.5, nrows=50, ncols=40, max_dist_m=2.0)
    near = NearestReturns(**kw)
    chunks = [slice(0, 1700), slice(1700, 1701), slice(1701, n)]
    for s in chunks:
        near.count(x[s], y[s], cls[s], rn[s])
    for s in chunks:
        near.add(x[s], y[s], z[s], cls[s], rn[s])
    keep = first_return_mask(cls, rn)
    assert 0 < keep.sum() < n
    np.testing.assert_array_equal(near.surface(), nearest_return_surface(x[keep], y[keep], z[keep], **kw))
    np.testing.assert_array_equal(near.surface(), _brute_force(x[keep], y[keep], z[keep], **kw))


def test_no_returns_added_gives_no_surface():
    kw = dict(x0_m=0.0, y_top_m=4.0, res_m=1.0, nrows=4, ncols=4, max_dist_m=2.0)
    near = NearestReturns(**kw)
    near.count(np.array([1.5]), np.array([2.5]), np.array([2], np.uint8), np.array([1], np.uint8))  # never added
    assert np.isnan(near.surface()).all()
    assert np.isnan(nearest_return_surface(np.empty(0), np.empty(0), np.empty(0), **kw)).all()
