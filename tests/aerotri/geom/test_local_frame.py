"""Local tangent-plane frame and strip detection."""

import numpy as np
import pytest

from aerotri.geom.local_frame import LocalFrame
from aerotri.geom.strips import along_track_km, strips_from_track


def test_local_frame_round_trip_and_axes():
    fr = LocalFrame("EPSG:32649", (420000.0, 3380000.0, 150.0))
    pts = np.array([[420000.0, 3380000.0, 150.0], [423000.0, 3378000.0, 900.0], [418500.0, 3381200.0, -20.0]])
    loc = fr.to_local(pts)
    assert np.allclose(loc[0], 0.0, atol=1e-6)
    assert np.allclose(fr.to_map(loc), pts, atol=1e-6)
    # a point 1 km above the origin (ellipsoidal height) is 1 km up in ENU
    up = fr.to_local([[420000.0, 3380000.0, 1150.0]])[0]
    assert np.allclose(up, [0, 0, 1000.0], atol=1e-6)
    # earth curvature: a point 3 km away at the same height is below the tangent plane by ~d^2 / 2R
    far = fr.to_local([[423000.0, 3380000.0, 150.0]])[0]
    assert abs(far[2] + np.hypot(*far[:2]) ** 2 / (2 * 6.38e6)) < 0.02
    R = fr.rotation_local_from_map(pts)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9)
    # grid convergence east of the central meridian (111 E) in the northern hemisphere: a few tenths of a degree
    gamma = np.degrees(np.arctan2(R[0, 1, 0], R[0, 0, 0]))
    assert 0.05 < abs(gamma) < 2.0


def test_strips_from_track():
    xs = np.arange(6) * 300.0
    pos = np.vstack([np.column_stack([xs, np.zeros(6), np.full(6, 1000.0)]),
                     np.column_stack([xs[::-1], np.full(6, 900.0), np.full(6, 1000.0)]),
                     np.column_stack([xs, np.full(6, 1800.0), np.full(6, 1000.0)])])
    strip = strips_from_track(pos)
    assert strip.tolist() == [0] * 6 + [1] * 6 + [2] * 6
    t = along_track_km(pos, strip)
    assert np.allclose(t[:6], (xs - xs.mean()) / 1000.0)
    assert np.allclose(t[6:12], (xs - xs.mean()) / 1000.0)  # signed along the flight direction


@pytest.mark.parametrize("crs", ["EPSG:32649", "EPSG:4326", "EPSG:2263"])  # UTM metres, degrees, US feet
def test_map_anchors_match_the_exact_conversion(crs):
    """MapAnchors (the solve's map positions without a CRS transformation per iteration) agree with the exact
    LocalFrame.to_map to well below a micrometre for points within the tolerance of their anchors, re-anchor
    the points that moved farther, and give d map / d local."""
    from aerotri.geom.local_frame import MapAnchors

    origin = {"EPSG:32649": (420000.0, 3380000.0, 150.0), "EPSG:4326": (114.2, 30.5, 150.0),
              "EPSG:2263": (990000.0, 200000.0, 30.0)}[crs]
    frame = LocalFrame(crs, origin)
    rng = np.random.default_rng(3)
    p = rng.uniform(-25_000, 25_000, (2000, 3)) * np.array([1, 1, 0.01])
    anchors = MapAnchors(frame, tol_m=1.0)
    m0, J0 = anchors.to_map(p)
    assert anchors.anchored == len(p)
    np.testing.assert_allclose(m0, frame.to_map(p), rtol=0, atol=1e-9)
    moved = p + rng.uniform(-0.99, 0.99, p.shape)
    m1, _ = anchors.to_map(moved)
    assert anchors.anchored == len(p)  # all within the tolerance: no transformation
    exact = frame.to_map(moved)
    # the error in metres on the ground (the map's unit is metres, degrees or feet)
    err_m = np.einsum("nij,nj->ni", np.linalg.inv(J0), m1 - exact)
    assert np.abs(err_m).max() < 1e-6
    far = moved.copy()
    far[:10] += 5.0
    anchors.to_map(far)
    assert anchors.anchored == len(p) + 10
    # a subset by index, and d map / d local against the frame's own
    idx = np.arange(100, 200)
    m2, J2 = anchors.to_map(far[idx], idx)
    exact_J = frame.jacobian_map_from_local(far[idx])
    # the anchor's, up to 1 m away: d map / d local changes by about 1 / R per metre
    np.testing.assert_allclose(J2, exact_J, rtol=0, atol=1e-6 * np.abs(exact_J).max())
    assert not np.isfinite(anchors.to_map(np.full((1, 3), np.nan))[0]).any()
