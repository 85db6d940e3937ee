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


@pytest.mark.parametrize("model,n", [("plane", 3), ("quadratic", 6), ("tps", 3)])
def test_the_minimum_number_of_points_fits_and_says_no_check_is_left(model, n):
    """Trial s96 F2: exactly the minimum (3 levelled points on a small site) ended in a traceback (NaN into the
    model file's JSON); now the model is written, its leave-one-out figures null, and the warning says why."""
    x, y = _points(n, 7)
    zeta = _zeta_true(x, y)
    h = np.full(n, 500.0)
    res = fit_height_anomaly([f"L{i}" for i in range(n)], x, y, h, h - zeta, model=model)
    d = json.loads(res.to_json())
    assert d["loo_rms_m"] is None and all(r["loo_residual_m"] is None for r in d["residuals"])
    assert any(w.startswith(f"no redundancy: {n} points is the minimum for {model}") for w in res.warnings)
    np.testing.assert_allclose(res.model.zeta_m(x, y), zeta, atol=1e-6)


def test_a_levelled_point_the_others_place_elsewhere_is_named():
    """Trial s96 F6: one normal height 0.25 m off among 9 points fitting to 2-3 cm went without a word (crs fit names
    such a point). Over 200 simulated sets of 9 points (2 cm noise): a 0.25 m blunder named (alone) in most, a clean
    set flagged in few (Student's t of r - 1 at 0.001 per point: about 1 % of sets of 9; 400 sets measured 0.75 %
    false, 91.5 % found)."""
    false_sets, found = 0, 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        x, y = 37_450_000.0 + rng.uniform(0, 20_000, 9), 3_800_000.0 + rng.uniform(0, 20_000, 9)
        zeta = -12.0 + 0.00002 * (x - x.mean())
        h = rng.uniform(40, 120, 9)
        H = h - zeta + rng.normal(0, 0.02, 9)
        ids = [f"G{i + 1}" for i in range(9)]
        false_sets += any("blunder" in w for w in fit_height_anomaly(ids, x, y, h, H, model="plane").warnings)
        H[2] += 0.25
        named = [w for w in fit_height_anomaly(ids, x, y, h, H, model="plane").warnings if "blunder" in w]
        found += named == [w for w in named if w.startswith("point G3 lies 0.") and "(height anomaly)" in w] != []
    assert false_sets <= 5 and found >= 170, (false_sets, found)
