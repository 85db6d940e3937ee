"""Synthetic classified LiDAR scenes with known roof (eave) corners, for the roof-corner tests.

Not a test module (no ``test_`` prefix): the test files load it by path. A 2.5D scanner: points on
jittered scan lines (spacing ``spacing_m`` along and across, scan direction ``heading_deg``), the height
of the surface below each point (ground plane, flat or gable roofs, a tree), Gaussian noise.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon, box


def _rect(cx, cy, w, h, angle_deg):
    return affinity.rotate(box(cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2), angle_deg, origin=(cx, cy))


def default_buildings():
    """(polygon of the eave outline, roof kind, eave height m, ridge rise m, ridge angle deg)."""
    l_shape = Polygon([(0, 0), (24, 0), (24, 10), (11, 10), (11, 22), (0, 22)])
    l_shape = affinity.translate(affinity.rotate(l_shape, 71.0, origin=(0, 0)), 95.0, 20.0)
    court = _rect(40, 110, 32, 30, 11.0).difference(_rect(40, 110, 13, 12, 11.0))
    return [
        (_rect(30, 30, 22, 13, 0.0), "flat", 9.0, 0.0, 0.0),
        (_rect(70, 62, 16, 26, 33.0), "flat", 12.0, 0.0, 0.0),
        (l_shape, "flat", 7.5, 0.0, 0.0),
        (court, "flat", 15.0, 0.0, 0.0),
        (_rect(112, 95, 12, 19, 50.0), "gable", 6.0, 3.0, 50.0 + 90.0),
        (_rect(128, 40, 14, 12, -24.0), "flat", 5.0, 0.0, 0.0),
        (_rect(80, 120, 6, 6, 20.0), "flat", 4.0, 0.0, 0.0),
    ]


def truth_corners(buildings):
    rows = []
    for b_id, (poly, kind, h, _, _) in enumerate(buildings):
        for ring in [poly.exterior, *poly.interiors]:
            for x, y in np.asarray(ring.coords)[:-1]:
                rows.append((x, y, 2.0 + h, kind, b_id))
    xyz = np.array([(r[0], r[1], r[2]) for r in rows])
    return xyz, [r[3] for r in rows], np.array([r[4] for r in rows])


def surface(x, y, buildings, tree=(45.0, 19.0, 3.5, 14.0)):
    """Height (m) and ASPRS class of the visible surface at (x, y)."""
    z = 2.0 + 0.01 * x + 0.005 * y
    cls = np.full(len(x), 2, np.uint8)
    for poly, kind, h, rise, ridge_deg in buildings:
        inside = shapely.contains_xy(poly, x, y)
        base = 2.0 + 0.01 * x + 0.005 * y
        if kind == "flat":
            zr = base * 0 + 2.0 + h
        else:
            c = np.array(poly.centroid.coords[0])
            a = np.radians(ridge_deg)
            v = np.abs(-(x - c[0]) * np.sin(a) + (y - c[1]) * np.cos(a))
            half = 6.0  # the gable test building is 12 m wide
            zr = 2.0 + h + rise * (1.0 - v / half)
        z = np.where(inside, zr, z)
        cls = np.where(inside, 6, cls)
    tx, ty, tr, th = tree
    in_tree = np.hypot(x - tx, y - ty) < tr
    z = np.where(in_tree, 2.0 + th - 3.0 * (np.hypot(x - tx, y - ty) / tr) ** 2, z)
    cls = np.where(in_tree, 5, cls)
    return z, cls


def scan_points(extent, spacing_m=0.7, heading_deg=17.0, jitter=0.15, seed=0):
    """Jittered scan-line pattern over extent (xmin, xmax, ymin, ymax), random phase."""
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = extent
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    half = 0.5 * np.hypot(xmax - xmin, ymax - ymin) + spacing_m
    u = np.arange(-half, half, spacing_m) + rng.uniform(0, spacing_m)
    v = np.arange(-half, half, spacing_m) + rng.uniform(0, spacing_m)
    uu, vv = np.meshgrid(u, v)
    uu = uu + rng.normal(0, jitter * spacing_m, uu.shape)
    vv = vv + rng.normal(0, jitter * spacing_m, vv.shape)
    a = np.radians(heading_deg)
    x = cx + uu.ravel() * np.cos(a) - vv.ravel() * np.sin(a)
    y = cy + uu.ravel() * np.sin(a) + vv.ravel() * np.cos(a)
    sel = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
    return x[sel], y[sel]


def make_cloud(buildings=None, extent=(0.0, 150.0, 0.0, 140.0), spacing_m=0.7, noise_m=0.05, heading_deg=17.0,
               seed=0, pattern="scan"):
    """x, y, z, classification, point_source_id of a synthetic classified cloud (true xy, noisy xyz)."""
    buildings = default_buildings() if buildings is None else buildings
    rng = np.random.default_rng(seed + 1000)
    if pattern == "scan":
        x, y = scan_points(extent, spacing_m, heading_deg, seed=seed)
    else:
        n = int((extent[1] - extent[0]) * (extent[3] - extent[2]) / spacing_m**2)
        x = rng.uniform(extent[0], extent[1], n)
        y = rng.uniform(extent[2], extent[3], n)
    z, cls = surface(x, y, buildings)
    x = x + rng.normal(0, noise_m, len(x))
    y = y + rng.normal(0, noise_m, len(x))
    z = z + rng.normal(0, noise_m, len(x))
    return x, y, z, cls, np.ones(len(x), np.int64)


def match_corners(found_xy, truth_xy, max_dist_m=1.0):
    """Nearest truth corner for each found corner (index, -1 beyond max_dist_m) and its distance."""
    d = np.hypot(found_xy[:, None, 0] - truth_xy[None, :, 0], found_xy[:, None, 1] - truth_xy[None, :, 1])
    j = d.argmin(axis=1)
    dist = d[np.arange(len(found_xy)), j]
    return np.where(dist <= max_dist_m, j, -1), dist
