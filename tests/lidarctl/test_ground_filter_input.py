"""The registry's ground filters refuse coordinates a LAS file cannot hold (trial-api F3): one NaN x crashed the
interpreter (a numba kernel indexed a cell by it: segmentation fault) in `morph` and `ptd`, one NaN z left `slope`
no ground at all (0 of 20,000), no points raised "zero-size array" in `morph`."""

from __future__ import annotations

import numpy as np
import pytest

from lidarctl.classify.ground import GROUND_FILTERS


def _plane(n=400, seed=0):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 40, n), rng.uniform(0, 40, n)
    return x, y, 10.0 + 0.05 * x + rng.normal(0, 0.02, n)


@pytest.mark.parametrize("method", sorted(GROUND_FILTERS))
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_nan_coordinate_is_refused_by_name(method, axis):
    f = GROUND_FILTERS[method]
    xyz = [a.copy() for a in _plane()]
    xyz[axis][17] = np.nan
    with pytest.raises(ValueError, match=f"1 {'xyz'[axis]} coordinates are not finite \\(the first at point 17\\)"):
        f.run(*xyz, f.params())


@pytest.mark.parametrize("method", sorted(GROUND_FILTERS))
def test_no_points_no_ground_and_a_plane_is_ground(method):
    f = GROUND_FILTERS[method]
    empty = np.zeros(0)
    out = f.run(empty, empty, empty, f.params())
    assert out.dtype == bool and out.shape == (0,)
    assert f.run(*_plane(), f.params()).mean() > 0.9
