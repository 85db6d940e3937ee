"""``ortho dem``: the robust grid of adjusted tie points (outliers out, holes filled, extended to the footprints)."""

from __future__ import annotations

import numpy as np
import pytest

from aerotri.core.errors import InputError, OptionError
from ortho.points_dem import points_dem


def _surface(x, y):
    return 100.0 + 0.05 * x - 0.02 * y + 2.0 * np.sin(x / 40.0)


def test_points_dem_recovers_the_surface_without_its_outliers():
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 200, (20000, 2))
    xy = xy[np.hypot(xy[:, 0] - 100, xy[:, 1] - 100) > 20]  # a hole: no tie points on a pond
    z = _surface(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.05, len(xy))
    bad = rng.choice(len(xy), 200, replace=False)
    z[bad] += rng.choice([-1, 1], 200) * rng.uniform(5, 30, 200)  # wrong matches
    dem = points_dem(np.column_stack([xy, z]), 2.0, bounds=(-20, -20, 220, 220))
    assert dem.n_outliers >= 190 and dem.cells_interpolated > 0 and dem.cells_extrapolated > 0
    h, w = dem.heights_m.shape
    xc = dem.x_left_m + (np.arange(w) + 0.5) * dem.res_m
    yc = dem.y_top_m - (np.arange(h) + 0.5) * dem.res_m
    X, Y = np.meshgrid(xc, yc)
    inside = (X > 2) & (X < 198) & (Y > 2) & (Y < 198)
    err = dem.heights_m - _surface(X, Y)
    assert np.all(np.isfinite(dem.heights_m))
    assert np.sqrt(np.mean(err[inside] ** 2)) < 0.1  # m: cells of 2 m on a 5 % slope, 5 cm noise
    assert np.abs(err[inside]).max() < 0.5  # no outlier survives
    pond = np.hypot(X - 100, Y - 100) < 15
    assert np.abs(err[pond]).max() < 0.5  # interpolated across the hole


def test_points_dem_refuses_what_it_cannot_grid():
    with pytest.raises(InputError, match="too few"):
        points_dem(np.zeros((2, 3)), 1.0)
    with pytest.raises(OptionError, match="positive"):
        points_dem(np.random.default_rng(1).uniform(0, 10, (50, 3)), 0.0)
