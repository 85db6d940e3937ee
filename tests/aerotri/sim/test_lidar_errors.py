"""Simulator: LiDAR trajectories and the injected system errors (boresight, range offset)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aerotri.sim import load_preset
from aerotri.sim.flight import LidarLine
from aerotri.sim.lidar import _sweep, trajectory
from aerotri.core.errors import InputError
from lidarctl.strips.trajectory import Trajectory

LINE = LidarLine(strip=1, y_m=100.0, east=True, z_m=500.0, swath_m=364.0, t0_s=5000.0)


def _lidar(**kw):
    return dataclasses.replace(load_preset("tiny").lidar, **kw)


def test_presets_inject_nothing():
    L = _lidar()
    assert L.boresight_error_deg == (0.0, 0.0, 0.0) and L.range_offset_m == 0.0
    assert L.scan_angle_scale_error == 0.0
    sw = _sweep(LINE, L, np.random.default_rng(0), 300.0, 0, 2000)
    assert sw.nominal is None  # the points are computed as before: the presets' output does not move


@pytest.mark.parametrize("east", [True, False])
def test_boresight_roll_turns_the_beam_about_the_flight_direction(east):
    line = LidarLine(1, 100.0, east, 500.0, 364.0, 5000.0)
    sw = _sweep(line, _lidar(boresight_error_deg=(0.05, 0.0, 0.0)), np.random.default_rng(0), 300.0, 0, 2000)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", sw.dirs, sw.nominal), -1, 1)))
    assert np.allclose(angle, 0.05, atol=1e-6)
    axis = np.cross(sw.nominal, sw.dirs)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    # roll: a right-handed turn about the forward axis (x east or west) tips the beam to the right
    assert np.allclose(axis[:, 0], 1.0 if east else -1.0, atol=1e-6)


def test_scan_angle_scale_error_widens_the_beam_angle():
    k = 5e-4
    sw = _sweep(LINE, _lidar(scan_angle_scale_error=k, attitude_noise_deg=0.0), np.random.default_rng(0), 300.0, 0, 2000)
    # flying east, right is -y: the scan angle is atan2(-y, -z) of a direction
    read = np.arctan2(-sw.nominal[:, 1], -sw.nominal[:, 2])
    left = np.arctan2(-sw.dirs[:, 1], -sw.dirs[:, 2])
    assert np.allclose(read, sw.theta, atol=1e-12) and np.allclose(left, sw.theta * (1 + k), atol=1e-12)
    assert np.allclose(sw.dirs[:, 0], 0.0)


def test_trajectory_follows_the_scanner():
    L = _lidar()
    sw = _sweep(LINE, L, np.random.default_rng(0), 300.0, 0, 5000)
    t, xyz, rph = trajectory(LINE, L, 300.0)
    tr = Trajectory(t, xyz, rph)
    tp = LINE.t0_s + sw.t + 4.0e8
    assert tr.covers(tp).all()
    pos, R = tr.at(tp)
    assert np.abs(pos - sw.origins).max() < 1e-3  # the weave of the line, sampled at 50 Hz
    # the nominal beam is the body frame's (0, sin theta, cos theta)
    u = np.column_stack([np.zeros(len(tp)), np.sin(sw.theta), np.cos(sw.theta)])
    d = np.einsum("nij,nj->ni", R, u)
    assert np.abs(d - sw.dirs).max() < 3e-4  # up to the attitude noise (0.003 deg = 5e-5 rad a component)


def test_bad_boresight_setting_is_refused():
    with pytest.raises(InputError, match="boresight_error_deg"):
        load_preset("tiny", ["lidar.boresight_error_deg=[0.1, 0.2]"])
