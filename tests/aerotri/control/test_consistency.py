"""Multi-ray intersection, rejection of inconsistent rays and of corners that disagree with the LiDAR."""

from __future__ import annotations

import numpy as np

from aerotri.geom.camera import BrownCamera
from aerotri.control.consistency import check_rays
from aerotri.geom.local_frame import FramesOnEarth
from aerotri.geom.rotation import rotation_matrix_opk

CAM = BrownCamera(focal_mm=120.0, pixel_um=96.0, width=1728, height=960)


def frames(n=4):
    centres = np.array([[i * 140.0, 0.0, 760.0] for i in range(n)])
    Rs = rotation_matrix_opk(np.zeros(n), np.zeros(n), np.full(n, -90.0))
    return centres, Rs


def observe(P, centres, Rs, noise_px=0.0, seed=1):
    rng = np.random.default_rng(seed)
    xy = np.array([np.array(CAM.project(P[None], c, R)[:2]).ravel() for c, R in zip(centres, Rs)])
    return xy + rng.normal(0, noise_px, xy.shape)


def test_consistent_rays_recover_the_point():
    P = np.array([200.0, 30.0, 320.0])
    c, R = frames()
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), observe(P, c, R, 0.2), P, np.array([0.1, 0.1, 0.05]))
    assert r.ok and r.kept.all()
    assert np.linalg.norm(r.point_m - P) < 0.5
    assert np.all(r.residual_px < 1.0)


def test_one_wrong_ray_of_four_is_dropped():
    P = np.array([200.0, 30.0, 320.0])
    c, R = frames()
    xy = observe(P, c, R, 0.2)
    xy[2] += [3.0, -2.0]
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), xy, P, np.array([0.1, 0.1, 0.05]))
    assert r.ok
    assert r.kept.tolist() == [True, True, False, True]


def test_two_disagreeing_rays_reject_the_corner():
    P = np.array([70.0, 30.0, 320.0])
    c, R = frames(2)
    xy = observe(P, c, R)
    # a shift across the base (image x for kappa = -90 deg) cannot be absorbed by the intersection
    xy[1, 0] += 4.0
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), xy, P, np.array([0.1, 0.1, 0.05]))
    assert not r.ok and r.reason == "inconsistent_rays"
    # a shift along the base (image y) is a parallax: the rays meet, but 4 m off the LiDAR corner in height
    xy = observe(P, c, R)
    xy[1, 1] += 4.0
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), xy, P, np.array([0.1, 0.1, 0.05]))
    assert np.all(r.residual_px < 1e-6)
    assert not r.ok and r.reason == "lidar_mismatch" and abs(r.lidar_diff_m[2]) > 3.0


def test_frames_agreeing_on_the_wrong_point_disagree_with_the_lidar():
    # all frames measured the foot of the wall, 12 m below the eave corner
    P = np.array([200.0, 30.0, 320.0])
    c, R = frames()
    xy = observe(P - [0, 0, 12.0], c, R, 0.2)
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), xy, P, np.array([0.1, 0.1, 0.05]))
    assert not r.ok and r.reason == "lidar_mismatch"
    assert abs(r.lidar_diff_m[2] + 12.0) < 1.0


def test_a_single_ray_is_too_few():
    P = np.array([200.0, 30.0, 320.0])
    c, R = frames(1)
    r = check_rays(CAM, FramesOnEarth.cartesian(c, R), np.arange(len(c)), observe(P, c, R), P, np.array([0.1, 0.1, 0.05]))
    assert not r.ok and r.reason == "too_few_rays"
