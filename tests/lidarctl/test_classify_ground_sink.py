"""Sink test of lidarctl.classify.pipeline (``sunken_ground``, ``ground_sink_sigma``): a single return from below
the ground that the filter kept (multipath) is low noise; real depressions (a ditch, a pit, a stream bank, a
street below its pavements and a stair) are surfaces and stay ground."""

import numpy as np
import pytest

from lidarctl.classify import pipeline as classify


def _ground(kind: str, seed: int = 1, noise_m: float = 0.03):
    """A 60 x 60 m ground grid at 1 m spacing (jittered 0.3 m), range noise ``noise_m``: flat, sloping (10 %), or with a
    real depression along x = 30 (a ditch 1 m deep and 2 m wide at its floor, one 0.5 m wide, a pit 3 m deep and
    5 m wide, a stream channel 8 m wide whose banks drop 3 m over 1.5 m, streets 0.15 m below their pavements and
    a five-step stair)."""
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(60.0), np.arange(60.0))
    x = gx.ravel() + rng.uniform(-0.3, 0.3, gx.size)
    y = gy.ravel() + rng.uniform(-0.3, 0.3, gx.size)
    z = 0.1 * x if kind == "slope" else np.zeros_like(x)
    d = np.abs(x - 30.0)
    if kind == "ditch":
        z = z - np.clip(2.0 - d, 0, 1)
    elif kind == "narrow ditch":
        z = z - np.clip(1.5 - 2 * d, 0, 1)
    elif kind == "pit":
        z = z - 3 * np.clip(3.5 - np.hypot(x - 30, y - 30), 0, 1)
    elif kind == "stream bank":
        z = z - 3 * np.clip((5.5 - d) / 1.5, 0, 1)
    elif kind == "kerbs and steps":
        z = z + 0.15 * ((y % 20) > 8) + 0.17 * np.clip(np.floor((x - 40) / 0.3), 0, 5) * (x > 40)
    return x, y, z + rng.normal(0, noise_m, len(z))


def _with_low_returns(x, y, z, depths_m):
    """The ground with one return below it per depth, 0.3 / 0.2 m beside a ground return, 11-13 m apart."""
    ix = []
    for k, _ in enumerate(depths_m):
        ix.append(int(np.argmin(np.hypot(x - (5 + (k % 5) * 11), y - (6 + (k // 5) * 13)))))
    ix = np.array(ix)
    n = len(x)
    return (np.r_[x, x[ix] + 0.3], np.r_[y, y[ix] + 0.2], np.r_[z, z[ix] - np.asarray(depths_m)], n)


@pytest.mark.parametrize("kind", ["flat", "slope"])
def test_single_low_returns_are_found_and_nothing_else(kind):
    depths = [0.5, 1.0, 2.0, 3.0] * 5
    x, y, z, n = _with_low_returns(*_ground(kind), depths)
    flagged = classify.sunken_ground(x, y, z, np.ones(len(x), bool), 1.0, 4.0)
    assert flagged[n:].all()
    assert not flagged[:n].any()
    # off, and only ground points are judged
    assert not classify.sunken_ground(x, y, z, np.ones(len(x), bool), 1.0, 0.0).any()
    not_ground = np.ones(len(x), bool)
    not_ground[n:] = False
    assert not classify.sunken_ground(x, y, z, not_ground, 1.0, 4.0)[n:].any()


@pytest.mark.parametrize("kind", ["ditch", "narrow ditch", "pit", "stream bank", "kerbs and steps"])
def test_real_depressions_stay_ground(kind):
    x, y, z = _ground(kind)
    assert not classify.sunken_ground(x, y, z, np.ones(len(x), bool), 1.0, 4.0).any()


def test_two_low_returns_side_by_side_are_found():
    """A pair of multipath returns 1 m apart, 2 m down: each has the other at its depth, still alone."""
    x, y, z = _ground("flat")
    i = int(np.argmin(np.hypot(x - 20, y - 20)))
    x, y, z = np.r_[x, x[i] + 0.3, x[i] + 1.3], np.r_[y, y[i], y[i]], np.r_[z, z[i] - 2.0, z[i] - 2.1]
    flagged = classify.sunken_ground(x, y, z, np.ones(len(x), bool), 1.0, 4.0)
    assert flagged[-2:].all() and not flagged[:-2].any()


def test_classification_makes_them_low_noise_and_keeps_them_out_of_the_ground():
    depths = [1.0, 2.0, 3.0] * 3
    x, y, z, n = _with_low_returns(*_ground("flat", seed=3), depths)
    on = classify.classify_points(x, y, z, params=classify.ClassifySettings(ground_sink_sigma=6.0))
    off = classify.classify_points(x, y, z, params=classify.ClassifySettings(ground_sink_sigma=0.0))
    assert np.array_equal(off, classify.classify_points(x, y, z))   # off by default
    assert (on[n:] == classify.LOW_NOISE).all()
    assert (off[n:] == classify.GROUND).sum() > 0          # what the test is for: without it some are ground
    assert np.array_equal(on[:n], off[:n])                  # the ground's own returns keep their classes
    # The last of two returns is not judged (ground_sink_single): the pulse's own class decides, as off
    nr = np.r_[np.ones(n, np.uint8), np.full(len(depths), 2, np.uint8)]
    multi = classify.classify_points(x, y, z, nr, nr, params=classify.ClassifySettings(ground_sink_sigma=6.0))
    assert np.array_equal(multi, classify.classify_points(x, y, z, nr, nr))
    assert (multi[n:] == classify.GROUND).sum() > 0


def test_floor_in_metres_and_single_returns_spare_shallow_dips_and_multi_return_ground():
    """0.3 m down is a drain at any sigma with the 0.5 m floor, 1-3 m down is not; a last of several returns is never
    judged when only single returns are (``judged``), but still counts as a neighbour."""
    depths = [0.3, 1.0, 2.0, 3.0] * 3
    x, y, z, n = _with_low_returns(*_ground("flat"), depths)
    ground = np.ones(len(x), bool)
    shallow = np.r_[np.zeros(n, bool), np.array(depths) < 0.5]
    without_floor = classify.sunken_ground(x, y, z, ground, 1.0, 6.0)
    assert without_floor[n:].all()                                   # 0.3 m is 10 sigma of 3 cm noise
    with_floor = classify.sunken_ground(x, y, z, ground, 1.0, 6.0, min_depth_m=0.5)
    assert np.array_equal(with_floor, without_floor & ~shallow)
    single = np.ones(len(x), bool)
    single[n::2] = False                                            # every other low return: a last of several
    judged = classify.sunken_ground(x, y, z, ground, 1.0, 6.0, judged=single)
    assert np.array_equal(judged, without_floor & single)
