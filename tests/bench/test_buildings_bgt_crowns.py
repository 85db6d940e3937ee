"""bench/eval_buildings_bgt_crowns.py's pulse linking and crown separation on constructed returns (the real-data
run: ``bench/eval_buildings_bgt_crowns.py``, about 1 minute)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from lidarctl.classify.pipeline import BUILDING, GROUND, ClassifySettings

BENCH_SCRIPT = "eval_buildings_bgt_crowns.py"


@pytest.fixture(scope="module")
def crowns(bench_script):
    return bench_script


def test_pulse_ends_follow_return_numbers_of_one_gps_time(crowns):
    # pulses at t = 1 (3 returns), 2 (single), 3 (2 returns), 4 (returns 1 and 3: return 2 lost), stored shuffled
    gps = np.array([3.0, 1.0, 4.0, 1.0, 2.0, 1.0, 3.0, 4.0])
    rn = np.array([2, 3, 3, 1, 1, 2, 1, 1])
    end = crowns.pulse_ends(gps, rn)
    assert end.tolist() == [0, 1, 2, 1, 4, 1, 0, 7]


def _scene():
    """12 x 12 m: ground at 0 m, a 6 x 6 m flat roof 2.5 m up (x, y 3-9 m); a crown 5.5 m up over the roof's west half
    (x 3-6 m: every pulse splits there and ends on the roof) and over the ground west of it (x 0-3 m: the pulses end on
    the ground); the roof's east edge splits pulses too (x 9-9.25 m: first return on the eave, last on the ground).
    Everything above the ground called building (the growth the separation should undo)."""
    rng = np.random.default_rng(7)
    xs, ys = np.meshgrid(np.arange(0.125, 12.0, 0.25), np.arange(0.125, 12.0, 0.25))
    xs, ys = xs.ravel(), ys.ravel()
    rows = []   # x, y, z, class, return number, number of returns, gps time, kind
    for i, (x, y) in enumerate(zip(xs, ys)):
        t = float(i)
        on_roof = 3.0 <= x < 9.0 and 3.0 <= y < 9.0
        crown = x < 6.0 and 3.0 <= y < 9.0
        eave = 9.0 <= x < 9.25 and 3.0 <= y < 9.0
        low_z = 2.5 if on_roof else 0.0
        low_cls = BUILDING if on_roof else GROUND
        if crown:
            rows.append((x, y, 5.5 + rng.normal(0, 0.3), BUILDING, 1, 2, t, "crown over roof" if on_roof else "crown over ground"))
            rows.append((x, y, low_z + rng.normal(0, 0.02), low_cls, 2, 2, t, "roof" if on_roof else "ground"))
        elif eave:
            rows.append((x, y, 2.5 + rng.normal(0, 0.02), BUILDING, 1, 2, t, "eave"))
            rows.append((x, y, rng.normal(0, 0.02), GROUND, 2, 2, t, "ground"))
        else:
            rows.append((x, y, low_z + rng.normal(0, 0.02), low_cls, 1, 1, t, "roof" if on_roof else "ground"))
    x, y, z, cls, rn, nr, gps, kind = (np.array(v) for v in zip(*rows))
    cloud = types.SimpleNamespace(x=x.astype(float), y=y.astype(float), z=z.astype(float), classification=cls.astype(np.uint8),
                                  return_number=rn.astype(np.uint8), number_of_returns=nr.astype(np.uint8))
    grid = types.SimpleNamespace(transform=types.SimpleNamespace(a=0.5, c=0.0, e=-0.5, f=12.0), shape=(24, 24))
    return cloud, grid, gps.astype(float), kind, rn.astype(int)


def test_crown_returns_over_a_roof_not_the_roof_the_eave_or_a_crown_over_the_ground(crowns):
    c, grid, gps, kind, rn = _scene()
    end = crowns.pulse_ends(gps, rn)
    k = crowns.cells(c, grid)
    crown, cell, ended_below = crowns.crown_returns(c, k, end, ClassifySettings())
    over_roof = kind == "crown over roof"
    inner = over_roof & (c.x >= 3.5) & (c.y >= 3.5) & (c.y < 8.5)   # the roof's edge cells are no planar surface
    assert crown[inner].all()
    assert crown[over_roof].mean() >= 50 / 72   # all but the ring of edge cells (22 of the 6 x 12 cells)
    for other in ("roof", "eave", "crown over ground", "ground"):
        assert not crown[kind == other].any(), other
        assert not cell[kind == other].any(), other
    assert (cell >= crown).all() and (ended_below >= crown).all()
    assert ended_below[over_roof].all() and not ended_below[kind == "eave"].any()
    # the top return of every inner crown cell over the roof is a first return of a pulse that ended on our building
    kinds = crowns.top_kind(c, k, end, ClassifySettings())
    r, col = (12.0 - c.y[inner]) // 0.5, c.x[inner] // 0.5
    assert (kinds[r.astype(int), col.astype(int)] == crowns.TOP_KINDS.index("split, ended on our building below")).all()
