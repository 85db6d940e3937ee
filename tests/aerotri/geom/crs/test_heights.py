"""Height anomaly surfaces: plane, quadratic and thin-plate spline; H = h - zeta."""

import json

import numpy as np
import pytest

from aerotri.geom.crs.heights import fit_height_anomaly
from aerotri.geom.crs.datum import HeightAnomalyModel
from aerotri.core.errors import InputError


def _points(n, seed, size_m=20_000.0):
    rng = np.random.default_rng(seed)
    x = 37_450_000.0 + rng.uniform(0, size_m, n)
    y = 3_800_000.0 + rng.uniform(0, size_m, n)
    return x, y


def _zeta_true(x, y):
    """A smooth anomaly surface: -28 m, tilts of a few cm/km, and a curvature."""
    dx, dy = (x - 37_460_000.0) / 1000.0, (y - 3_810_000.0) / 1000.0
    return -28.0 + 0.031 * dx - 0.047 * dy + 0.0009 * dx**2 - 0.0004 * dx * dy + 0.0006 * dy**2


def test_plane_recovers_a_tilted_plane_and_rms_matches_noise():
    x, y = _points(40, 1)
    zeta = -28.0 + 0.00003 * (x - x.mean()) - 0.00005 * (y - y.mean())
    rng = np.random.default_rng(2)
    h = rng.uniform(300, 900, 40)
    H = h - zeta + rng.normal(0, 0.01, 40)
    res = fit_height_anomaly([f"B{i}" for i in range(40)], x, y, h, H, model="plane")
    assert res.sigma0_m == pytest.approx(0.01, rel=0.25)
    assert res.loo_rms_m > res.rms_m  # check-point style residuals are larger than fitted ones
    xq, yq = _points(200, 3)
    zq = -28.0 + 0.00003 * (xq - x.mean()) - 0.00005 * (yq - y.mean())
    assert np.max(np.abs(res.model.zeta_m(xq, yq) - zq)) < 0.02
    # H = h - zeta
    assert res.model.normal_height(xq[:3], yq[:3], [100.0, 200.0, 300.0]) == pytest.approx(
        np.array([100.0, 200.0, 300.0]) - res.model.zeta_m(xq[:3], yq[:3])
    )


def test_quadratic_and_tps_on_a_curved_surface():
    x, y = _points(30, 4)
    h = np.full(30, 500.0)
    H = h - _zeta_true(x, y)
    xq, yq = _points(300, 5, size_m=18_000.0)
    xq, yq = xq + 1000.0, yq + 1000.0  # inside the hull of the points
    truth = _zeta_true(xq, yq)
    quad = fit_height_anomaly(range(30), x, y, h, H, model="quadratic")
    assert quad.rms_m < 1e-9
    assert np.max(np.abs(quad.model.zeta_m(xq, yq) - truth)) < 1e-9
    plane = fit_height_anomaly(range(30), x, y, h, H, model="plane")
    assert plane.rms_m > 0.01  # a plane cannot follow the curvature
    tps = fit_height_anomaly(range(30), x, y, h, H, model="tps")
    assert np.max(np.abs(tps.residuals_m)) < 1e-9  # interpolates
    assert np.isfinite(tps.loo_residuals_m).all() and tps.loo_rms_m < plane.loo_rms_m
    assert np.sqrt(np.mean((tps.model.zeta_m(xq, yq) - truth) ** 2)) < 0.01
    # the model file round trip
    again = HeightAnomalyModel.from_dict(json.loads(tps.to_json()))
    assert np.max(np.abs(again.zeta_m(xq, yq) - tps.model.zeta_m(xq, yq))) < 1e-9


def test_height_fit_bad_input():
    x, y = _points(5, 6)
    h = np.full(5, 500.0)
    with pytest.raises(InputError, match="at least 6 points"):
        fit_height_anomaly(range(5), x, y, h, h - 28, model="quadratic")
    with pytest.raises(InputError, match="duplicate point id '1'"):
        fit_height_anomaly(["1", "2", "1", "4", "5"], x, y, h, h - 28, model="plane")
    with pytest.raises(InputError, match="unknown height model"):
        fit_height_anomaly(range(5), x, y, h, h - 28, model="cubic")
    line_x = np.linspace(0, 1000, 5) + 37_450_000.0
    with pytest.raises(InputError, match="collinear"):
        fit_height_anomaly(range(5), line_x, np.full(5, 3_800_000.0), h, h - 28, model="plane")
