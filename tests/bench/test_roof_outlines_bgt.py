"""bench/eval_roof_outlines_bgt.py's scores of roof outlines against footprints (``score_outlines``), on constructed
footprints and outlines: an outline half a metre beyond its footprint's walls (an eave), a footprint beside it no
outline covers, one far from it, a shed the footprints do not hold, and an outline beyond the footprints' coverage
(not scored)."""

from __future__ import annotations

import pytest
import shapely

BENCH_SCRIPT = "eval_roof_outlines_bgt.py"


def test_outline_area_is_scored_against_the_footprints_in_their_coverage(bench_script):
    house, neighbour, far = shapely.box(0, 0, 10, 10), shapely.box(11, 0, 21, 10), shapely.box(0, 30, 10, 40)
    eave = house.buffer(0.5, join_style="mitre")  # 11 x 11 m
    shed = shapely.box(14, 18, 16, 20)  # inside the footprints' hull, more than 3 m from every wall
    r = bench_script.score_outlines([eave, shed, shapely.box(100, 100, 110, 110)], [house, neighbour, far])
    assert r["outlines_in_coverage"] == 2 and r["footprints"] == 3 and r["footprints_found"] == 1
    assert r["bgt_area_m2"] == pytest.approx(300.0) and r["completeness_pct"] == pytest.approx(100.0 / 3.0, abs=0.01)
    # beyond the footprints: the eave's 21 m2 within 1 m of the house, the shed's 4 m2 farther
    assert r["beyond_bgt_within_1m_m2"] == pytest.approx(21.0, abs=0.1)
    assert r["beyond_bgt_farther_m2"] == pytest.approx(4.0, abs=0.1)
    assert r["correctness_pct"] == pytest.approx(100.0 * 100.0 / 125.0, abs=0.01)
    # the neighbour and the far footprint have no outline; of them the neighbour's 1 m strip lies within the
    # overhang reach (1.5 m) of the house's outline
    assert r["bgt_area_without_outline_m2"] == pytest.approx(200.0)
    assert r["of_it_within_the_overhang_reach_of_an_outline_m2"] == pytest.approx(10.0, abs=0.1)
    # the eave's four corners 0.71 m from the house's walls; the shed's more than 3 m from any: not counted
    assert r["vertices_within_3m"] == 4 and r["vertex_to_bgt_boundary_m_median"] == pytest.approx(0.707, abs=0.001)
