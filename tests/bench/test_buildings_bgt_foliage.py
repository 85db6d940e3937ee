"""bench/eval_buildings_bgt_foliage.py's separation on constructed returns (the real-data run:
``bench/eval_buildings_bgt_foliage.py``, a few minutes)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from lidarctl.classify.pipeline import BUILDING, GROUND, MED_VEG

BENCH_SCRIPT = "eval_buildings_bgt_foliage.py"


@pytest.fixture(scope="module")
def foliage(bench_script):
    return bench_script


def _scene():
    """16 x 12 m, ground at 0 m. A 5 x 5 m flat roof 2.5 m up (x 2-7 m, y 3-8 m) with wall returns on its west and
    south walls (single returns at 0.6-2.0 m on the wall lines: a wall stops the pulse). A hedge 1.8-3.8 m high, 1.5 m wide
    (x 9-10.5 m, y 2-10 m) with a rough top: every other pulse splits there (first return on the top, a second inside
    the foliage at 0.7-1.2 m, the last on the ground). Everything above the ground called building."""
    rng = np.random.default_rng(3)
    xs, ys = np.meshgrid(np.arange(0.125, 16.0, 0.25), np.arange(0.125, 12.0, 0.25))
    rows = []   # x, y, z, class, return number, number of returns, kind
    bumps = rng.uniform(0.0, 2.0, (24, 32))   # sd 0.58 m
    for i, (x, y) in enumerate(zip(xs.ravel(), ys.ravel())):
        if 2.0 <= x < 7.0 and 3.0 <= y < 8.0:
            rows.append((x, y, 2.5 + rng.normal(0, 0.02), BUILDING, 1, 1, "roof"))
        elif 9.0 <= x < 10.5 and 2.0 <= y < 10.0:
            # a rough top: twigs and gaps at the scale of a cell (the real ones: 3 x 3 plane RMS 0.58 m, median)
            top = 1.8 + bumps[int(y / 0.5), int(x / 0.5)] + rng.normal(0, 0.05)
            if i % 2:
                rows.append((x, y, top, BUILDING, 1, 3, "hedge"))
                rows.append((x + 0.05, y, rng.uniform(0.7, 1.2), BUILDING, 2, 3, "hedge"))
                rows.append((x + 0.1, y, rng.normal(0, 0.02), GROUND, 3, 3, "ground"))
            else:
                rows.append((x, y, top, BUILDING, 1, 1, "hedge"))
        else:
            rows.append((x, y, rng.normal(0, 0.02), GROUND, 1, 1, "ground"))
    for t in np.arange(3.1, 8.0, 0.25):   # wall returns: the west wall (x 2 m) and the south wall (y 3 m)
        for z in (0.6, 1.1, 1.6, 2.0):
            rows.append((1.98, t, z, BUILDING, 1, 1, "wall"))
            rows.append((t - 1.0, 2.98, z, BUILDING, 1, 1, "wall"))
    x, y, z, cls, rn, nr, kind = (np.array(v) for v in zip(*rows))
    cloud = types.SimpleNamespace(x=x.astype(float), y=y.astype(float), z=z.astype(float),
                                  classification=cls.astype(np.uint8), return_number=rn.astype(np.uint8),
                                  number_of_returns=nr.astype(np.uint8))
    grid = types.SimpleNamespace(transform=types.SimpleNamespace(a=0.5, c=0.0, e=-0.5, f=12.0), shape=(24, 32))
    return cloud, grid, kind


def test_foliage_beneath_a_low_top_leaves_the_building_the_roof_and_its_walls_stay(foliage):
    c, grid, kind = _scene()
    k = foliage.cr.cells(c, grid)
    cls = foliage.separated_classes(c, k)
    hedge = kind == "hedge"
    inner = hedge & (c.y >= 2.5) & (c.y < 9.5)
    assert (cls[inner] == MED_VEG).mean() >= 0.9
    for stays in ("roof", "wall"):
        assert (cls[kind == stays] == BUILDING).all(), stays
    assert (cls[kind == "ground"] == GROUND).all()


def test_a_tall_top_is_not_judged(foliage):
    c, grid, kind = _scene()
    tall = c.z + np.where(kind == "hedge", foliage.LOW_M, 0.0)   # the same hedge standing 4 m higher: a crown
    c.z = tall
    cls = foliage.separated_classes(c, foliage.cr.cells(c, grid))
    assert (cls[kind == "hedge"] == BUILDING).all()
