"""bench/eval_corners_bgt_correctness.py's classes of a usable corner against footprints (``score_usable``), on two
constructed footprints: on a wall, inside beyond 1 m, outside by 1-3 m and beyond 3 m, outside the coverage (not
scored), and a corner not usable (not scored)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import shapely

BENCH_SCRIPT = "eval_corners_bgt_correctness.py"


def _corner(cid, x, y, usable=1):
    return {"id": cid, "x": x, "y": y, "z": 5.0, "sx_m": 0.1, "sy_m": 0.1, "angle_deg": 90.0, "usable": usable}


def test_usable_corners_are_classed_by_their_distance_to_the_nearest_footprint(bench_script):
    polys = [shapely.box(0, 0, 10, 10), shapely.box(20, 0, 30, 10)]
    corners = [_corner("on_vertex", 10.3, 10.3), _corner("on_wall", 25.0, -0.4), _corner("inside", 5.0, 5.0),
               _corner("gap_2m", 12.0, 5.0), _corner("gap_5m", 15.0, 5.0), _corner("beyond_coverage", 50.0, 50.0),
               _corner("not_usable", 15.0, 6.0, usable=0)]
    cls = np.array([6, 6, 2, 2], np.uint8)  # two building returns at the 5 m gap's corner, two ground ones
    ahn3 = SimpleNamespace(x=np.array([15.0, 15.5, 15.0, 40.0]), y=np.array([5.0, 5.0, 4.0, 40.0]),
                           classification=cls)
    r = bench_script.score_usable(corners, polys, ahn3)
    assert r["usable"] == 6 and r["usable_in_bgt_coverage"] == 5
    assert (r["on_a_footprint_boundary"], r["inside_a_footprint_beyond_1m"], r["outside_1_to_3m"],
            r["outside_beyond_3m"]) == (2, 1, 1, 1)
    assert r["outside_every_footprint_pct"] == 40.0
    off = {o["id"]: o for o in r["outside_corners"]}
    assert set(off) == {"gap_2m", "gap_5m"} and off["gap_2m"]["distance_to_footprint_m"] == 2.0
    # the AHN3 returns within 1.5 m of the 5 m gap's corner: two building, one ground
    assert off["gap_5m"]["ahn3_returns_within_1_5m"] == 3 and off["gap_5m"]["ahn3_building_share"] == 0.667
