"""Control layout rule on a synthetic block: 3 strips x 10 frames, nadir DMC-like camera."""

from __future__ import annotations

import numpy as np

from aerotri.geom.camera import FrameCamera
from aerotri.control.layout import LayoutRule, select_control, strips_of_block
from aerotri.geom.rotation import rotation_matrix_opk

CAM = FrameCamera(focal_mm=120.0, pixel_um=96.0, width=1728, height=960)  # long side across track


def block(n_strips=3, n_frames=10):
    # flying height 450 m: footprint 622 m across, 346 m along; base 138 m (60 %), strip spacing 440 m
    centres, strip = [], []
    for s in range(n_strips):
        for i in range(n_frames):
            x = i * 138.24 if s % 2 == 0 else (n_frames - 1 - i) * 138.24
            centres.append([x, s * 440.0, 760.0])
            strip.append(s)
    centres = np.array(centres)
    kappa = np.where(np.array(strip) % 2 == 0, -90.0, 90.0)
    Rs = rotation_matrix_opk(np.zeros(len(centres)), np.zeros(len(centres)), kappa)
    return centres, Rs, np.array(strip)


def frames_seeing(xy, z, centres, Rs):
    P = np.column_stack([xy, np.full(len(xy), z)])
    n = np.zeros(len(xy), int)
    for c, R in zip(centres, Rs):
        x, y, _ = CAM.project(P, c, R)
        n += CAM.inside(x, y, 10)
    return n


def test_strip_geometry():
    centres, Rs, strip = block()
    strips, origin, u, w = strips_of_block(CAM, centres, Rs, 310.0, strip)
    assert len(strips) == 3
    widths = [st.hi_m - st.lo_m for st in strips]
    np.testing.assert_allclose(widths, 1728 * 0.36, rtol=0.01)
    np.testing.assert_allclose([st.base_m for st in strips], 138.24, rtol=0.01)


def test_full_points_at_strip_edges_every_five_baselines_and_height_points_in_the_middle_strip():
    centres, Rs, strip = block()
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(-300, 1550, 3000), rng.uniform(-350, 1250, 3000)])
    score = rng.uniform(0.5, 1.0, len(xy))
    n = frames_seeing(xy, 310.0, centres, Rs)
    keep = n >= 2
    xy, score, n = xy[keep], score[keep], n[keep]
    kind, targets, base = select_control(xy, score, n, CAM, centres, Rs, 310.0, rule=LayoutRule(), strip=strip)
    # strip length 9 baselines, triple overlap from frame 2 to 9 = 7 baselines -> 2 positions per line;
    # 4 lines (2 outer edges, 2 side overlaps) -> 8 full points; 1 group of 3 strips -> 1 height point
    assert sum(t.kind == "full" for t in targets) == 8
    assert sum(t.kind == "height" for t in targets) == 1
    assert (kind == "full").sum() == 8 and (kind == "height").sum() == 1
    sel = np.isin(kind, ["full", "height"])
    assert np.all(n[sel] >= 3)  # triple overlap
    for t in targets:
        assert t.distance_m is not None and t.distance_m < 1.25 * base
    # side-overlap points lie between the strips, across-track (y) near 220 and 660 m
    ys = sorted(xy[kind == "full", 1])
    assert min(ys) < -100 and max(ys) > 1000
    assert sum(150 < y < 290 for y in ys) == 2 and sum(590 < y < 730 for y in ys) == 2
    # the height point is in the middle strip (y ~ 440 m)
    assert abs(xy[kind == "height", 1][0] - 440.0) < 1.25 * base
    assert (kind == "check").sum() == len(xy) - 9
