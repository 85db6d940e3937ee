"""bench/eval_buildings_bgt_causes.py's open-structure separation on constructed returns (the real-data run:
``bench/eval_buildings_bgt_causes.py --bgt-layers DIR --nested``, about 12 minutes)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from lidarctl.classify.pipeline import BUILDING, GROUND

BENCH_SCRIPT = "eval_buildings_bgt_causes.py"


@pytest.fixture(scope="module")
def causes(bench_script):
    return bench_script


def _scene(pass_every: int, rough_m: float = 0.0):
    """16 x 16 m, ground at 0 m, four structures called building: a pergola 2.5 m up (x 2-6, y 2-6 m) whose slats stop
    the pulses but every ``pass_every``-th one, which splits and ends on the ground; a closed shed 2.5 m up (x 10-14,
    y 2-6: single returns); a house roof 7 m up (x 2-14, y 10-14) with an extension 2.5 m up joined to it (x 2-6,
    y 8-10) whose every ``pass_every``-th pulse passes too (a glass roof beside a closed one). ``rough_m``: the
    pergola's top scattered by that much (a crown, not a level surface)."""
    rng = np.random.default_rng(3)
    xs, ys = np.meshgrid(np.arange(0.125, 16.0, 0.25), np.arange(0.125, 16.0, 0.25))
    rows = []   # x, y, z, class, return number, number of returns, kind
    for i, (x, y) in enumerate(zip(xs.ravel(), ys.ravel())):
        pergola = 2 <= x < 6 and 2 <= y < 6
        shed = 10 <= x < 14 and 2 <= y < 6
        house = 2 <= x < 14 and 10 <= y < 14
        extension = 2 <= x < 6 and 8 <= y < 10
        if (pergola or extension) and i % pass_every == 0:
            z = 2.5 + (rng.normal(0, rough_m) if pergola else 0.0)
            rows += [(x, y, z, BUILDING, 1, 2, "pergola" if pergola else "extension"), (x, y, 0.0, GROUND, 2, 2, "ground")]
        elif pergola or shed or extension:
            z = 2.5 + (rng.normal(0, rough_m) if pergola else rng.normal(0, 0.02))
            rows.append((x, y, z, BUILDING, 1, 1, "pergola" if pergola else "shed" if shed else "extension"))
        elif house:
            rows.append((x, y, 7.0 + rng.normal(0, 0.02), BUILDING, 1, 1, "house"))
        else:
            rows.append((x, y, rng.normal(0, 0.02), GROUND, 1, 1, "ground"))
    x, y, z, cls, rn, nr, kind = (np.array(v) for v in zip(*rows))
    cloud = types.SimpleNamespace(x=x.astype(float), y=y.astype(float), z=z.astype(float), classification=cls.astype(np.uint8),
                                  return_number=rn.astype(np.uint8), number_of_returns=nr.astype(np.uint8))
    grid = types.SimpleNamespace(transform=types.SimpleNamespace(a=0.5, c=0.0, e=-0.5, f=16.0), shape=(32, 32))
    return cloud, grid, kind


def _taken(causes, pass_every, rough_m=0.0):
    c, grid, kind = _scene(pass_every, rough_m)
    k = causes.cr.cells(c, grid)
    take = causes.open_structures(c, k).ravel()[k.flat] & (c.classification == BUILDING)
    return {name: float(take[kind == name].mean()) for name in ("pergola", "shed", "extension", "house")}


def test_a_level_surface_passing_pulses_alone_is_no_closed_roof(causes):
    # 1 pulse in 3 reaching the ground through the slats: the pergola goes; the shed stops every pulse; the house
    # stands above 4 m. The glass extension passing as many pulses goes too: its low area is its own (the house is
    # not low), and the rule cannot tell a glass roof from slats (the limit it shares with the completion stop)
    taken = _taken(causes, 3)
    assert taken["pergola"] == 1.0 and taken["extension"] == 1.0
    assert taken["shed"] == 0.0 and taken["house"] == 0.0


def test_few_pulses_through_or_a_rough_top_keep_the_building(causes):
    # 1 pulse in 20 (5 %, below the 0.1 share): not shown to pass more than 0.1
    taken = _taken(causes, 20)
    assert taken["pergola"] == 0.0 and taken["extension"] == 0.0
    # a rough top (a crown's, 0.3 m scatter) is no level surface: left to the growth tests
    taken = _taken(causes, 3, rough_m=0.3)
    assert taken["pergola"] == 0.0
