"""Roofs of a dense line-scanner cloud hold together (trial-density F1: at 13 points/m2 the scan lines lay up to
0.74 m apart while roofs were linked over 2 mean spacings, 0.57 m; every roof fell apart into strips of scan lines,
the 'corners' of those pieces lay along the roof edges, median 3.6 m from the true corners, with sigmas of a few
centimetres, and went in as control)."""

import numpy as np

from lidarctl.corners.roof_segments import cluster_roofs, effective_spacing_m, point_spacing_m, scan_line_gap_m


def _scanned_roofs(line_gap_m: float, along_m: float, seed: int = 3):
    """Two flat 20 x 12 m roofs 6 m apart, sampled on scan lines ``line_gap_m`` apart (across y), ``along_m``
    apart along them, with 2 cm of jitter; roof number per point."""
    rng = np.random.default_rng(seed)
    pts, roof = [], []
    for k, x0 in enumerate((0.0, 26.0)):
        ys = np.arange(0.0, 12.0, line_gap_m)
        xs = np.arange(x0, x0 + 20.0, along_m)
        gx, gy = np.meshgrid(xs, ys)
        xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.normal(0, 0.02, (gx.size, 2))
        pts.append(np.column_stack([xy, np.full(len(xy), 10.0 + k)]))
        roof.append(np.full(len(xy), k))
    return np.vstack(pts), np.concatenate(roof)


def test_a_dense_line_scan_keeps_each_roof_whole():
    xyz, truth = _scanned_roofs(line_gap_m=0.7, along_m=0.08)  # 18 points/m2: mean spacing 0.24 m
    spacing = point_spacing_m(xyz[:, :2])
    assert 2.0 * spacing < 0.7  # the rule of 2 spacings does not reach across the lines
    assert len(np.unique(cluster_roofs(xyz, 2.0 * spacing))) > 20  # (before: the pieces of scan lines)
    r = 2.0 * effective_spacing_m(xyz[:, :2], spacing)
    assert 0.65 <= r < 3.0  # across the lines, short of the 6 m between the roofs
    labels = cluster_roofs(xyz, r)
    assert len(np.unique(labels)) == 2
    for k in (0, 1):  # one cluster per roof
        assert len(np.unique(labels[truth == k])) == 1


def test_evenly_spread_points_keep_the_two_spacings():
    """Jittered grid points (no scan lines): the gap is below 2 spacings, so the link radius stays 2 spacings (the
    demo's building points: gap 1.13 m against 2 x 0.617 m; AHN3 Delft 0.47 against 2 x 0.308 m)."""
    rng = np.random.default_rng(1)
    g = np.arange(0.0, 40.0, 0.5)
    gx, gy = np.meshgrid(g, g)
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.2, 0.2, (gx.size, 2))
    spacing = point_spacing_m(xy)
    assert scan_line_gap_m(xy) < 2.5 * spacing
    assert effective_spacing_m(xy, spacing) == spacing
