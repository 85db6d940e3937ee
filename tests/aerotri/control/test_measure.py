"""Corner measurement in synthetic images with a known sub-pixel corner."""

from __future__ import annotations

import numpy as np

from aerotri.control.measure import measure_in_image


def render(polys, size=(80, 80), background=(90, 140, 70), supersample=8, seed=0):
    """Area-sampled RGB image (H, W, 3) of convex polygons [(vertices (K, 2) px, colour)], later ones on top.

    Pixel centres at integer coordinates (x right, y down); texture noise sigma 2 grey values.
    """
    H, W = size
    o = (np.arange(supersample) + 0.5) / supersample - 0.5
    X = np.broadcast_to((np.arange(W)[:, None] + o[None, :])[None, None], (H, supersample, W, supersample))
    Y = np.broadcast_to(np.arange(H)[:, None, None, None] + o[None, :, None, None], (H, supersample, W, supersample))
    img = np.zeros((H, supersample, W, supersample, 3)) + np.asarray(background, float)
    for verts, colour in polys:
        inside = np.ones(X.shape, bool)
        v = np.asarray(verts, float)
        for a, b in zip(v, np.roll(v, -1, axis=0)):
            inside &= (b[0] - a[0]) * (Y - a[1]) - (b[1] - a[1]) * (X - a[0]) >= 0
        img[inside] = colour
    img = img.mean(axis=(1, 3))
    rng = np.random.default_rng(seed)
    return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)


def rect(corner, u, a, b):
    """Rectangle with a corner at ``corner`` spanned by unit u (length a) and its normal (length b)."""
    c, u = np.asarray(corner, float), np.asarray(u, float) / np.linalg.norm(u)
    n = np.array([-u[1], u[0]])
    pts = np.array([c, c + a * u, c + a * u + b * n, c + b * n])
    # counter-clockwise in (x right, y down) for the inside test
    area = np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    return pts if area > 0 else pts[::-1], u, n


def test_corner_measured_to_a_tenth_of_a_pixel():
    corner = np.array([35.37, 41.81])
    pts, u, n = rect(corner, [np.cos(0.3), np.sin(0.3)], 30, 24)
    img = render([(pts, (200, 120, 110))])
    dirs = np.array([u, n])
    m = measure_in_image(img, corner[0] + 1.6, corner[1] - 1.2, dirs, radius_px=5.0)
    assert m.ok, m.reason
    assert np.hypot(m.x_px - corner[0], m.y_px - corner[1]) < 0.1
    assert m.fit_rms_px < 0.2


def test_wall_band_outside_the_eave_is_not_taken_for_the_roof_edge():
    # roof corner at `corner`; a grey wall band (relief displacement) 3 px wide along one roof edge,
    # outside the roof: the eave is the inner of the two parallel edges
    corner = np.array([40.2, 38.6])
    u = np.array([1.0, 0.15]) / np.hypot(1.0, 0.15)
    n = np.array([-u[1], u[0]])
    roof, _, _ = rect(corner, u, 28, 26)
    wall, _, _ = rect(corner - 3.0 * n, u, 28, 3.0)
    img = render([(wall, (150, 150, 150)), (roof, (225, 215, 200))])
    m = measure_in_image(img, corner[0] - 1.0, corner[1] - 1.5, np.array([u, n]), radius_px=5.0)
    assert m.ok, m.reason
    assert np.hypot(m.x_px - corner[0], m.y_px - corner[1]) < 0.25


def test_occluded_corner_is_rejected():
    corner = np.array([38.0, 40.0])
    pts, u, n = rect(corner, [1.0, 0.0], 30, 25)
    # a tree crown (background-like colour) covers the corner and the first 12 px of both edges
    yy, xx = np.mgrid[0:80, 0:80]
    img = render([(pts, (200, 120, 110))]).astype(float)
    crown = np.hypot(xx - corner[0] - 2, yy - corner[1] - 2) < 12
    img[crown] = (60, 110, 50)
    m = measure_in_image(img.astype(np.uint8), corner[0] + 1, corner[1] + 1, np.array([u, n]), radius_px=5.0)
    assert not m.ok
    assert m.reason == "occluded"


def test_corner_outside_the_frame_is_rejected():
    img = render([])
    m = measure_in_image(img, 1.0, 40.0, np.eye(2), radius_px=5.0)
    assert not m.ok and m.reason == "outside_frame"
