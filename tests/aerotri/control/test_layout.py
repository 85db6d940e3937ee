"""Control layout rule on a synthetic block: 3 strips x 10 frames, nadir DMC-like camera."""

from __future__ import annotations

import numpy as np

from aerotri.geom.camera import BrownCamera
from aerotri.control.layout import LayoutSettings, candidate_tiers, select_control, strips_of_block
from aerotri.geom.rotation import rotation_matrix_opk

CAM = BrownCamera(focal_mm=120.0, pixel_um=96.0, width=1728, height=960)  # long side across track


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
    kind, targets, base = select_control(xy, score, n, camera=CAM, centres_m=centres, Rs=Rs, ground_z_m=310.0,
                                         rule=LayoutSettings(), strip=strip)
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


def test_candidate_tiers():
    n = np.array([3, 3, 2, 2, 3, 3, 1])
    primary = np.array([1, 0, 1, 0, 0, 1, 1], bool)
    roof = np.array(["flat", "flat", "flat", "pitched", "pitched", "pitched", "flat"])
    assert candidate_tiers(n, primary, roof, 3).tolist() == [0, 1, 2, -1, 3, 0, -1]


def test_a_target_without_a_usable_corner_falls_back_in_order_and_keeps_the_others():
    centres, Rs, strip = block()
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(-300, 1550, 3000), rng.uniform(-350, 1250, 3000)])
    n = frames_seeing(xy, 310.0, centres, Rs)
    xy, n = xy[n >= 2], n[n >= 2]
    score = rng.uniform(0.5, 1.0, len(xy))
    _, targets, base = select_control(xy, score, n, camera=CAM, centres_m=centres, Rs=Rs, ground_z_m=310.0, strip=strip)
    t0 = np.array([targets[0].target_x_m, targets[0].target_y_m])
    radius = 1.25 * base
    far = np.hypot(*(xy - t0).T) > radius  # empty the first target's search circle
    xy, score, n = xy[far], score[far], n[far]
    # near the first target: a lower-scored flat corner (3 frames), a usable flat corner in 2 frames, a
    # pitched-roof corner (4 frames), a usable corner in 1 frame (never a candidate)
    near = t0 + np.array([[30.0, 0.0], [10.0, 0.0], [5.0, 0.0], [1.0, 0.0]])
    xy = np.vstack([xy, near])
    score = np.concatenate([score, [0.3, 0.9, 0.4, 1.0]])
    n = np.concatenate([n, [3, 2, 4, 1]])
    primary = np.concatenate([np.ones(len(xy) - 4, bool), [False, True, False, True]])
    roof = np.array(["flat"] * (len(xy) - 4) + ["flat", "flat", "pitched", "flat"])
    L, H, P, one = len(xy) - 4, len(xy) - 3, len(xy) - 2, len(xy) - 1

    def select(keep, fallback=True):
        tier = candidate_tiers(n, primary, roof, 3)
        tier[~keep] = -1
        return select_control(xy, score, n, camera=CAM, centres_m=centres, Rs=Rs, ground_z_m=310.0, strip=strip,
                              tier=tier, check=primary, rule=LayoutSettings(fallback=fallback))

    keep = np.ones(len(xy), bool)
    kind_off, t_off, _ = select(keep, fallback=False)
    assert t_off[0].corner is None and t_off[0].tier is None
    kind, t, _ = select(keep)
    assert (t[0].corner, t[0].tier, t[0].corner_kind, kind[L]) == (L, "lower_score", "full", "full")
    keep[L] = False
    kind, t, _ = select(keep)
    assert (t[0].corner, t[0].tier, t[0].corner_kind, kind[H]) == (H, "height_only", "height", "height")
    keep[H] = False
    kind, t, _ = select(keep)
    assert (t[0].corner, t[0].tier, t[0].corner_kind, kind[P]) == (P, "pitched_roof", "full", "full")
    keep[P] = False
    kind, t, _ = select(keep)
    assert t[0].corner is None
    # the fallbacks never change the other targets; unchosen fallback corners are no check points,
    # a usable corner seen in too few frames still is
    kind, t, _ = select(np.ones(len(xy), bool))
    assert [x.corner for x in t[1:]] == [x.corner for x in t_off[1:]]
    assert all(x.tier == "usable" for x in t[1:])
    assert kind_off[L] == kind_off[P] == "candidate" and kind_off[H] == kind_off[one] == "check"
    assert kind[L] == "full" and np.array_equal(kind == "check", kind_off == "check")
