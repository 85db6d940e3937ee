"""Unit tests of the roof-outline pieces: depth calibration, edge adjustment, corner covariance, planes."""

from __future__ import annotations

import numpy as np
import shapely

from lidarctl.corners.roof_outline import (
    Edge,
    EdgeObservations,
    corners_from_edges,
    fit_edges,
    outermost_depth,
    corners_from_edges as _corners,
    edge_observations,
    regularise_rings,
    reweight_observations,
    trace_rings,
)
from lidarctl.corners.roof_segments import cluster_roofs, segment_planes


def _grid(spacing, angle_deg, extent=20.0, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    g = np.arange(-extent, extent, spacing) + rng.uniform(0, spacing)
    u, v = [a.ravel() for a in np.meshgrid(g, g)]
    u = u + rng.normal(0, jitter, u.size)
    v = v + rng.normal(0, jitter, v.size)
    a = np.radians(angle_deg)
    return np.column_stack([u * np.cos(a) - v * np.sin(a), u * np.sin(a) + v * np.cos(a)])


def test_outermost_depth_learns_half_spacing_and_common_error():
    s = 0.7
    # scan lines parallel to the edge: every bin sees the same depth -> error common to the edge
    xy = _grid(s, 0.0)
    xy = xy[np.abs(xy).max(axis=1) < 8.0]
    mean, sd, common = outermost_depth(xy[:, 0], xy[:, 1], s, s)
    assert abs(mean - s / 2) < 0.08
    assert 0.6 * s / np.sqrt(12) < common < 1.4 * s / np.sqrt(12)
    # oblique pattern: depth varies along the edge, the common part is small
    xy = _grid(s, 23.0, jitter=0.1)
    xy = xy[np.abs(xy).max(axis=1) < 8.0]
    mean, sd, common = outermost_depth(xy[:, 0], xy[:, 1], s, s)
    assert abs(mean - s / 2) < 0.1
    assert sd > 0.1 and common < 0.5 * sd


def _square_edges(theta, half=10.0, centre=(100.0, 50.0)):
    edges = []
    for q in range(4):
        phi = theta + q * np.pi / 2
        n = np.array([np.cos(phi), np.sin(phi)])
        edges.append(Edge(0, q, phi, float(n @ np.asarray(centre) + half)))
    return edges


def test_corner_covariance_matches_monte_carlo():
    """Scatter of corners over noisy edge observations equals the propagated covariance."""
    rng = np.random.default_rng(3)
    theta = np.radians(17.0)
    truth = _square_edges(theta)
    no_obs = [EdgeObservations(np.zeros((0, 2)), np.zeros(0))] * 4
    corners_true = corners_from_edges(truth, fit_edges(theta, [truth], [no_obs])).xy
    sigma = 0.1
    xs, covs = [], []
    for _ in range(300):
        edges = _square_edges(theta + rng.normal(0, 0.02))
        obs = []
        for e in truth:
            t = np.linspace(-7, 7, 15)
            p = t[:, None] * e.direction() + (e.d + rng.normal(0, sigma, t.size))[:, None] * e.normal()
            obs.append(EdgeObservations(p, np.full(t.size, sigma)))
        fit = fit_edges(theta, [edges], [obs], min_sigma0=0.0)
        rc = corners_from_edges(edges, fit)
        xs.append(rc.xy)
        covs.append(rc.cov_xy)
    xs = np.array(xs)
    err = xs - corners_true
    assert np.abs(err.mean(axis=0)).max() < 0.02
    emp = np.einsum("nki,nkj->kij", err, err) / len(xs)
    pred = np.mean(covs, axis=0)
    np.testing.assert_allclose(np.sqrt(np.diagonal(emp, axis1=1, axis2=2)),
                               np.sqrt(np.diagonal(pred, axis1=1, axis2=2)), rtol=0.15)
    # right angles, 90 deg interior for a convex square
    assert np.allclose(rc.angle_deg, 90.0)


def test_trace_and_regularise_l_shape():
    poly = shapely.affinity.rotate(shapely.Polygon([(0, 0), (24, 0), (24, 10), (11, 10), (11, 22), (0, 22)]), 31.0)
    xy = _grid(0.7, 5.0, extent=40.0, jitter=0.1)
    xy = xy[shapely.contains_xy(poly, xy[:, 0], xy[:, 1])]
    rings = trace_rings(xy, 0.7)
    theta, edge_rings = regularise_rings(rings, 0.7)
    assert len(edge_rings) == 1 and len(edge_rings[0]) == 6
    assert abs(np.degrees(theta) - 31.0) < 3.0
    assert all(e.q >= 0 for e in edge_rings[0])


def test_clusters_split_at_height_steps_and_planes_of_a_hip_roof():
    xy = _grid(0.7, 10.0, extent=15.0, jitter=0.1, seed=4)
    # two roofs side by side: x < 0 at 10 m, x >= 0 at 14 m (a step of 4 m)
    z = np.where(xy[:, 0] < 0, 10.0, 14.0)
    labels = cluster_roofs(np.column_stack([xy, z]), link_radius_m=1.4)
    assert len(np.unique(labels[labels >= 0])) == 2
    # hip roof 20 x 14 m, 30 deg faces: four planes
    sel = (np.abs(xy[:, 0]) < 10) & (np.abs(xy[:, 1]) < 7)
    x, y = xy[sel, 0], xy[sel, 1]
    t = np.tan(np.radians(30.0))
    z = 20.0 - t * np.maximum(np.abs(y), np.abs(x) - 3.0)
    z += np.random.default_rng(5).normal(0, 0.05, z.size)
    plane_of, planes = segment_planes(np.column_stack([x, y, z]))
    big = [p for p in planes if p.n_points > 40]
    assert len(big) == 4
    assert all(abs(p.slope_deg - 30.0) < 2.0 for p in big)
    assert np.mean(plane_of >= 0) > 0.95


def _staggered_row():
    """A terraced row: four houses (0 deg) whose fronts step back 2 m each, 6 m wide, 20 m deep on the
    right; the back wall runs at 35 deg to them (a street at an angle), 30 m long."""
    a = np.radians(35.0)
    back_end = (24.0 - 30.0 * np.cos(a), 26.0 - 30.0 * np.sin(a))
    return shapely.Polygon([(0, 0), (6, 0), (6, 2), (12, 2), (12, 4), (18, 4), (18, 6), (24, 6), (24, 26), back_end])


def test_second_direction_family_keeps_right_angles_of_staggered_houses():
    poly = _staggered_row()
    xy = _grid(0.3, 7.0, extent=40.0, jitter=0.03, seed=6)
    xy = xy[shapely.contains_xy(poly, xy[:, 0], xy[:, 1])]
    rings = trace_rings(xy, 0.3)
    theta, edge_rings = regularise_rings(rings, 0.3)
    edges = edge_rings[0]
    fams = {e.fam for e in edges if e.q >= 0}
    assert fams == {0, 1}  # the two long walls and the house steps: two families
    obs = [edge_observations(edges, xy, 0.3)]
    fit = fit_edges(theta, edge_rings, obs)
    rc = _corners(edges, fit)
    # every step corner of the houses is a right angle (snapped to one family), and near a true vertex
    true_xy = np.asarray(poly.exterior.coords)[:-1]
    d = np.min(np.hypot(*(rc.xy[:, None, :] - true_xy[None]).transpose(2, 0, 1)), axis=1)
    steps = (rc.xy[:, 1] < 8.5) & (rc.xy[:, 0] > 1.0) & (d < 1.0)
    assert steps.sum() >= 6
    dev = np.minimum(np.abs(rc.angle_deg[steps] - 90.0), np.abs(rc.angle_deg[steps] - 270.0))
    assert np.all(dev < 0.5)
    assert np.median(d[steps]) < 0.25


def test_reweighting_keeps_a_ragged_edge_from_inflating_the_clean_ones():
    """Square roof, three clean edges (sigma 0.05 m) and one ragged edge (scatter 0.5 m and outliers): the
    clean edges' offset sigmas stay near their own precision, the ragged edge's grows."""
    rng = np.random.default_rng(8)
    theta = np.radians(12.0)
    edges = _square_edges(theta)
    obs = []
    for q, e in enumerate(edges):
        t = np.linspace(-8, 8, 40)
        noise = rng.normal(0, 0.5 if q == 0 else 0.05, t.size)
        if q == 0:
            noise[::7] += 3.0  # bins on a dormer or a branch
        p = t[:, None] * e.direction() + (e.d + noise)[:, None] * e.normal()
        obs.append(EdgeObservations(p, np.full(t.size, 0.05)))
    one = fit_edges(theta, [edges], [obs])
    s_one = np.sqrt(np.diag(one.cov))[[e.param_d for e in edges]]
    two = fit_edges(theta, [edges], reweight_observations([edges], [obs], one.sigma0))
    s_two = np.sqrt(np.diag(two.cov))[[e.param_d for e in edges]]
    assert one.sigma0 > 5.0  # one factor for the roof: every edge inflated alike
    assert np.all(s_two[1:] < 0.3 * s_one[1:])  # the clean edges get their own precision back
    assert s_two[0] > 3.0 * s_two[1:].max()
    assert edges[0].n_obs < 40  # the outlying bins are dropped


def test_outlines_in_corners_geojson_are_valid_with_the_corners_where_they_were():
    """AHN3: 8 of 53 regularised roof outlines in corners.geojson were invalid polygons (a courtyard's fitted edges
    crossing the eave, a spike where fitted edges cross); QGIS flags them, overlays fail. Now valid (Polygon or
    MultiPolygon), every vertex a corner of the rings or a crossing of their edges, the corner points untouched."""
    from shapely.geometry import shape

    from lidarctl.corners.roof_corners import _corners_geojson_document

    square = np.array([[0, 0], [20, 0], [20, 20], [0, 20]], float)
    courtyard_out = np.array([[15, 5], [25, 5], [25, 10], [15, 10]], float)[::-1]       # crosses the east eave
    bowtie = np.array([[0, 0], [20, 0], [20, 20], [12, 20], [8, 24], [10, 26], [12, 24], [8, 20], [0, 20]], float)
    outlines = [dict(building_id=k, rings=rings, roof="flat", n_points=100, n_planes=1, spacing_m=0.5, sigma0=1.0,
                     theta_deg=0.0) for k, rings in enumerate([[square, courtyard_out], [bowtie], [square]])]
    corners = [dict(x=20.0, y=20.0, z=10.0, building_id=0, score=0.9)]
    old = [shapely.Polygon(np.vstack([r[0], r[0][:1]]), [np.vstack([h, h[:1]]) for h in r[1:]])
           for r in ([square, courtyard_out], [bowtie])]
    assert not any(g.is_valid for g in old)                       # the shapes the trial found
    doc = _corners_geojson_document(corners, outlines)
    polys = [shape(f["geometry"]) for f in doc["features"] if f["properties"]["kind"] == "roof_outline"]
    assert len(polys) == 3 and all(g.is_valid and g.geom_type in ("Polygon", "MultiPolygon") for g in polys)
    assert shapely.equals(polys[2], shapely.Polygon(square))      # a valid outline as it was
    assert abs(polys[0].area - (400 - 5 * 5)) < 1e-9              # the courtyard's part under the roof is left out
    for g, o in zip(polys, old):
        d = shapely.distance(shapely.points(shapely.get_coordinates(g)), o.boundary)
        assert d.max() < 1e-9                                     # vertices on the rings: nothing moved
    assert [f["geometry"]["coordinates"] for f in doc["features"] if f["properties"]["kind"] == "roof_corner"] == \
        [[20.0, 20.0, 10.0]]
    assert all(shapely.is_ccw(shapely.get_exterior_ring(p)) for g in polys for p in getattr(g, "geoms", [g]))
