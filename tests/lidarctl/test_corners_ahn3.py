"""Roof corners on a window of the AHN3 Delft crop against the surveyed BGT footprints (real data).

BGT footprints are wall lines, AHN3 roof outlines are eave lines: offsets of a few decimetres are
expected (bench/eval_corners_ahn3.py reports the whole crop).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidarctl.corners.roof_corners import find_roof_corners, read_classified_cloud

WINDOW = (84880.0, 84990.0, 447480.0, 447600.0)  # the terraced blocks in the middle of the footprint set


@pytest.mark.realdata
def test_ahn3_window_corners_near_bgt_footprint_vertices(shared_data, bgt_footprints):
    d = shared_data / "ahn3_delft"
    c = read_classified_cloud(d / "ahn3_cropped_1.laz")
    x0, x1, y0, y1 = WINDOW
    w = (c.x >= x0) & (c.x < x1) & (c.y >= y0) & (c.y < y1)
    res = find_roof_corners(c.x[w], c.y[w], c.z[w], c.classification[w], c.point_source_id[w],
                            roof="any")
    polys = bgt_footprints
    vertices = np.concatenate([np.asarray(p.exterior.coords)[:-1] for p in polys])
    cxy = np.array([[q["x"], q["y"]] for q in res.corners])
    # corners well inside the window, where BGT has footprints
    inner = (cxy[:, 0] > x0 + 10) & (cxy[:, 0] < x1 - 10) & (cxy[:, 1] > y0 + 10) & (cxy[:, 1] < y1 - 10)
    dist, _ = cKDTree(vertices).query(cxy[inner])
    matched = dist <= 2.0
    assert matched.sum() >= 10
    assert matched.mean() >= 0.7
    assert np.median(dist[matched]) < 0.6
    # corner heights are roof heights, not ground: every corner above the ground at it (the density-adaptive
    # minimum edge, 3.1 m here, also outlines garden sheds: eaves 0.8-1.6 m above the ground), and the
    # usable ones on the houses, 5-20 m above NAP ground
    z = np.array([q["z"] for q in res.corners])
    g = c.classification == 2
    _, nn = cKDTree(np.column_stack([c.x[g], c.y[g]])).query(cxy)
    assert np.all(z - c.z[g][nn] > 0.5)
    use = np.array([q["usable"] for q in res.corners], bool)
    assert use.sum() >= 10 and np.all((z[use] > 2.0) & (z[use] < 30.0))


@pytest.mark.realdata
def test_ahn3_tree_crowns_hide_corners_only_where_they_rise_above_the_view_rays(shared_data, bgt_footprints):
    """The whole crop. Trees in the back gardens: the corner under the crown at (84842, 447563) is hidden
    from every side and not usable; corners with trees on one side stay open from the others; usable
    corners have both edges ending at corners of their outline; those that match a BGT vertex lie at
    most 0.5 m from it in the median (eave overhang included)."""
    d = shared_data / "ahn3_delft"
    c = read_classified_cloud(d / "ahn3_cropped_1.laz")
    res = find_roof_corners(c.x, c.y, c.z, c.classification, c.point_source_id, roof="any")
    corners = res.corners
    under = [q for q in corners if np.hypot(q["x"] - 84842.0, q["y"] - 447563.0) < 1.0]
    assert len(under) >= 1 and all(q["score_view_openness"] == 0.0 and not q["usable"] for q in under)
    openness = np.array([q["score_view_openness"] for q in corners])
    assert np.any((openness > 0.0) & (openness < 1.0))  # partly hidden: trees on some sides only
    # a usable corner's two edges end at corners of its roof outline (edge lengths between them): not the
    # corner at (84874.6, 447520.6), where the edge lines of its neighbours meet off the traced outline
    rings = [np.asarray(r) for o in res.outlines for r in o["rings"]]
    for q in corners:
        if not q["usable"]:
            continue
        ring = next(r for r in rings if np.any(np.hypot(*(r - [q["x"], q["y"]]).T) < 1e-6))
        k = int(np.argmin(np.hypot(*(ring - [q["x"], q["y"]]).T)))
        prev_m, next_m = np.hypot(*(ring[k] - ring[k - 1])), np.hypot(*(ring[(k + 1) % len(ring)] - ring[k]))
        assert abs(prev_m - q["edge1_m"]) < 1e-6 and abs(next_m - q["edge2_m"]) < 1e-6
    polys = bgt_footprints
    vertices = np.concatenate([np.asarray(p.exterior.coords)[:-1] for p in polys])
    usable = np.array([[q["x"], q["y"]] for q in corners if q["usable"]])
    dist, _ = cKDTree(vertices).query(usable)
    assert (dist <= 2.0).sum() >= 5
    assert np.median(dist[dist <= 2.0]) <= 0.5
