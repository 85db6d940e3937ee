"""Tiny synthetic LiDAR strips with a scanner model and known errors (per-strip shifts, boresight,
range offset), for the tests of ``lidarctl strips``.

The scene: a tilted terrain with gentle hills, gable and flat roofs, and tree crowns (two returns a
pulse). Three strips flown east-west and back at 120 m with a +-20 deg zig-zag scan, ~50 % side
overlap; each has a trajectory file (lidarctl.strips.trajectory format) that carries the strip's
GNSS shift as the points do.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from laspy.vlrs.vlrlist import VLRList

from lidarctl.strips.trajectory import body_to_map, format_trajectory

X0, Y0 = 500000.0, 5400000.0
EPSG = 32632
BUILDINGS = [  # cx, cy, half length (x), half width (y), eave height, roof slope (deg; 0 flat; < 0: ridge along y)
    (40.0, 45.0, 18.0, 11.0, 6.0, 30.0), (100.0, 20.0, 14.0, 10.0, 8.0, 0.0), (110.0, 75.0, 16.0, 12.0, 5.0, 25.0),
    (60.0, 100.0, 12.0, 10.0, 7.0, 35.0), (25.0, -5.0, 10.0, 8.0, 4.0, 0.0), (140.0, 22.0, 12.0, 10.0, 6.0, -35.0),
    (75.0, 20.0, 12.0, 9.0, 5.0, -30.0), (85.0, 70.0, 10.0, 8.0, 5.0, -30.0)]
TREES = [(75.0, 50.0, 6.0), (140.0, 40.0, 5.0), (10.0, 80.0, 5.0)]


def terrain(x, y):
    return 50.0 + 0.02 * x + 0.01 * y + 0.8 * np.sin(x / 30.0) * np.cos(y / 25.0)


def surface(x, y):
    z = terrain(x, y)
    for cx, cy, hl, hw, eave, slope in BUILDINGS:
        inside = (np.abs(x - cx) <= hl) & (np.abs(y - cy) <= hw)
        if slope >= 0:
            roof = terrain(cx, cy) + eave + np.tan(np.radians(slope)) * (hw - np.abs(y - cy))
        else:
            roof = terrain(cx, cy) + eave + np.tan(np.radians(-slope)) * (hl - np.abs(x - cx))
        z = np.where(inside, roof, z)
    return z


@dataclasses.dataclass
class Errors:
    shifts_m: np.ndarray  # (strips, 3)
    boresight_deg: tuple = (0.0, 0.0, 0.0)  # roll, pitch, heading of the scanner in the body frame
    range_offset_m: float = 0.0
    noise_m: float = 0.02
    scan_angle_scale: float = 0.0  # the beam leaves at theta (1 + this), theta the angle read


def scan(path: Path, traj_path: Path, k: int, errors: Errors, seed: int, n_pulses: int = 20000,
         crs_epsg: int = EPSG, extras: bool = False):
    """Strip k (0-based): y = 45 k, east for even k; writes the LAS 1.4 file and its trajectory."""
    rng = np.random.default_rng(seed + 17 * k)
    east = k % 2 == 0
    speed, H, half_fov = 50.0, 120.0, np.radians(20.0)
    t = np.sort(rng.uniform(0.0, 190.0 / speed, n_pulses))
    phase = (20.0 * t) % 1.0
    theta = np.where(phase < 0.5, -1 + 4 * phase, 3 - 4 * phase) * half_fov
    xs = -20.0 + speed * t if east else 170.0 - speed * t
    ys = 45.0 * k + 0.3 * np.sin(t)
    zs = np.full(n_pulses, 55.0 + H)
    roll = np.radians(0.2 * np.sin(0.7 * t + k))
    pitch = np.radians(-0.1 + 0.05 * np.cos(t))
    heading = np.full(n_pulses, np.radians(90.0 if east else 270.0))
    R = body_to_map(roll, pitch, heading)
    u = np.column_stack([np.zeros(n_pulses), np.sin(theta), np.cos(theta)])
    theta_beam = theta * (1.0 + errors.scan_angle_scale)
    u_beam = np.column_stack([np.zeros(n_pulses), np.sin(theta_beam), np.cos(theta_beam)])
    br, bp, bh = np.radians(errors.boresight_deg)
    Rb = body_to_map(np.array(br), np.array(bp), np.array(bh))
    Rb = np.linalg.inv(np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])) @ Rb  # body-to-body (drop NED->ENU)
    d_true = np.einsum("nij,jk,nk->ni", R, Rb, u_beam)
    O = np.column_stack([xs, ys, zs])
    rho = (zs - terrain(xs, ys)) / -d_true[:, 2]
    for _ in range(8):  # the beam meets the height field: fixed point of the range
        P = O + d_true * rho[:, None]
        rho = (zs - surface(P[:, 0], P[:, 1])) / -d_true[:, 2]
    # trees: a crown return and the ground below
    P = O + d_true * rho[:, None]
    crown = np.zeros(n_pulses, bool)
    for cx, cy, r in TREES:
        crown |= np.hypot(P[:, 0] - cx, P[:, 1] - cy) < r
    crown_h = np.where(crown, 8.0 + 3.0 * rng.random(n_pulses), 0.0)
    rho_crown = rho - crown_h / -d_true[:, 2]
    d_nom = np.einsum("nij,nj->ni", R, u)
    shift = np.asarray(errors.shifts_m[k], float)

    def point(r):
        return O + d_nom * (r + errors.range_offset_m + errors.noise_m * rng.standard_normal(n_pulses))[:, None] + shift

    P1, P2 = point(np.where(crown, rho_crown, rho)), point(rho)
    pts = np.concatenate([P1, P2[crown]])
    nret = np.concatenate([np.where(crown, 2, 1), np.full(crown.sum(), 2)])
    rn = np.concatenate([np.ones(n_pulses, int), np.full(crown.sum(), 2)])
    tt = np.concatenate([t, t[crown]]) + 4.0e8 + 1000.0 * k
    ang = np.degrees(np.concatenate([theta, theta[crown]]))
    order = np.argsort(tt, kind="stable")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([X0, Y0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(crs_epsg))
    if extras:
        header.add_extra_dim(laspy.ExtraBytesParams(name="echo_width", type=np.float32))
        header.vlrs.append(laspy.VLR("test_user", 7, "a test VLR", b"\x01\x02\x03"))
    las = laspy.LasData(header)
    las.x, las.y, las.z = X0 + pts[order, 0], Y0 + pts[order, 1], pts[order, 2]
    las.return_number, las.number_of_returns = rn[order], nret[order]
    las.gps_time = tt[order]
    las.scan_angle = np.rint(ang[order] / 0.006).astype(np.int16)
    las.point_source_id = np.full(len(pts), 101 + k, np.uint16)
    las.classification = np.ones(len(pts), np.uint8)
    las.intensity = rng.integers(100, 4000, len(pts)).astype(np.uint16)
    if extras:
        las.echo_width = rng.random(len(pts)).astype(np.float32)
        las.user_data = rng.integers(0, 255, len(pts)).astype(np.uint8)
        las.evlrs = VLRList([laspy.VLR("test_user", 9, "a test EVLR", b"evlr-payload" * 10)])
    las.write(path)
    step = np.unique(np.r_[0:n_pulses:20, n_pulses - 1])
    traj_xyz = O[step] + shift + np.array([X0, Y0, 0.0])
    rph = np.degrees(np.column_stack([roll, pitch, heading]))[step]
    traj_path.write_text(format_trajectory(t[step] + 4.0e8 + 1000.0 * k, traj_xyz, rph))
    return path


@dataclasses.dataclass
class StripBlock:
    paths: list
    trajectories: list
    errors: Errors


def make_block(folder: Path, errors: Errors, seed: int = 3, n_strips: int = 3, **kw) -> StripBlock:
    folder.mkdir(parents=True, exist_ok=True)
    paths, trajs = [], []
    for k in range(n_strips):
        paths.append(scan(folder / f"strip_{k + 1}.las", folder / f"strip_{k + 1}.traj.txt", k, errors, seed, **kw))
        trajs.append(folder / f"strip_{k + 1}.traj.txt")
    return StripBlock(paths, trajs, errors)


@pytest.fixture(scope="session")
def clean_block(tmp_path_factory):
    """No systematic errors: strips agree up to the range noise."""
    return make_block(tmp_path_factory.mktemp("strips_clean"), Errors(np.zeros((3, 3))))


@pytest.fixture(scope="session")
def shifted_block(tmp_path_factory):
    """Per-strip shifts (strip 2 is 0.15 m high) and a boresight roll of 0.05 deg, with extra bytes, VLRs
    and EVLRs."""
    shifts = np.array([[0.0, 0.0, 0.0], [0.05, -0.08, 0.15], [-0.06, 0.04, -0.05]])
    return make_block(tmp_path_factory.mktemp("strips_shifted"), Errors(shifts, (0.05, 0.0, 0.0)), extras=True)


@pytest.fixture(scope="session")
def make_strips(tmp_path_factory):
    """make(name, shifts (3, 3), boresight_deg=(0, 0, 0), range_offset_m=0, scan_angle_scale=0, **scan options)
    -> StripBlock"""
    def make(name, shifts, boresight_deg=(0.0, 0.0, 0.0), range_offset_m=0.0, scan_angle_scale=0.0, **kw):
        errors = Errors(np.asarray(shifts, float), tuple(boresight_deg), range_offset_m,
                        scan_angle_scale=scan_angle_scale)
        return make_block(tmp_path_factory.mktemp(name), errors, **kw)
    return make


def write_control_csv(path: Path, step_m: float = 20.0) -> Path:
    """Control points on open ground (clear of the buildings and tree crowns), at their true heights."""
    x, y = np.meshgrid(np.arange(5.0, 150.0, step_m), np.arange(-30.0, 125.0, step_m))
    x, y = x.ravel(), y.ravel()
    clear = np.ones(len(x), bool)
    for cx, cy, hl, hw, *_ in BUILDINGS:
        clear &= (np.abs(x - cx) > hl + 6.0) | (np.abs(y - cy) > hw + 6.0)
    for cx, cy, r in TREES:
        clear &= np.hypot(x - cx, y - cy) > r + 6.0
    x, y = x[clear], y[clear]
    rows = [f"gcp{i},{X0 + a:.3f},{Y0 + b:.3f},{surface(a, b):.3f}" for i, (a, b) in enumerate(zip(x, y))]
    path.write_text("id,x,y,z\n" + "\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="session")
def control_csv():
    """control_csv(path, step_m=20) -> path: control points of the synthetic scene written to ``path``."""
    return write_control_csv
