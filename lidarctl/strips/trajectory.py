"""Scanner trajectories as text: one record a line, ``time_s x y z roll_deg pitch_deg heading_deg``.

Format (whitespace or comma separated; ``#`` starts a comment line)::

    # time_s x y z roll_deg pitch_deg heading_deg
    400005000.000 500120.000 5400260.000 620.000 0.0000 0.0000 90.0000

- ``time_s``: the same time scale as the strips' LAS ``gps_time``; strictly increasing.
- ``x y z``: the scanner's origin (where the ranges start) in the strips' CRS and units.
- ``roll pitch heading`` (degrees): the scanner body frame (x forward, y right, z down) to the local
  level frame north-east-down, R = Rz(heading) Ry(pitch) Rx(roll); heading clockwise from grid north
  (90: flying east). Angles are interpolated linearly (heading across 0/360 unwrapped).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.textio import read_text

HEADER = "# time_s x y z roll_deg pitch_deg heading_deg"
# north-east-down to the map frame east-north-up
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclasses.dataclass
class Trajectory:
    """Records in time order; ``xyz`` in metres once read by ``read_trajectories`` with units."""

    t: np.ndarray
    xyz: np.ndarray  # (n, 3)
    rph_deg: np.ndarray  # (n, 3) roll, pitch, heading
    source: str = ""

    def covers(self, t: np.ndarray, tolerance_s: float = 1e-3) -> np.ndarray:
        """Which times lie within the trajectory (up to ``tolerance_s``: times written with fewer decimals)."""
        return (t >= self.t[0] - tolerance_s) & (t <= self.t[-1] + tolerance_s)

    def at(self, t: np.ndarray):
        """(positions (n, 3), body-to-map rotations (n, 3, 3)) at times ``t`` (linear interpolation)."""
        k = np.clip(np.searchsorted(self.t, t) - 1, 0, len(self.t) - 2)
        w = ((t - self.t[k]) / (self.t[k + 1] - self.t[k]))[:, None]
        pos = self.xyz[k] * (1 - w) + self.xyz[k + 1] * w
        ang = np.radians(self.rph_deg[k] * (1 - w) + self.rph_deg[k + 1] * w)
        return pos, body_to_map(ang[:, 0], ang[:, 1], ang[:, 2])


def body_to_map(roll, pitch, heading) -> np.ndarray:
    """(n, 3, 3) rotations body (forward, right, down) -> map (east, north, up), angles in radians."""
    cr, sr, cp, sp, ch, sh = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(heading), np.sin(heading)
    n = np.broadcast(roll, pitch, heading).shape
    R = np.empty(n + (3, 3))
    # Rz(h) Ry(p) Rx(r)
    R[..., 0, 0] = ch * cp
    R[..., 0, 1] = ch * sp * sr - sh * cr
    R[..., 0, 2] = ch * sp * cr + sh * sr
    R[..., 1, 0] = sh * cp
    R[..., 1, 1] = sh * sp * sr + ch * cr
    R[..., 1, 2] = sh * sp * cr - ch * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return NED_TO_ENU @ R


def format_trajectory(t, xyz, rph_deg) -> str:
    lines = [HEADER]
    for ti, p, a in zip(t, xyz, rph_deg):
        lines.append(f"{ti:.6f} {p[0]:.4f} {p[1]:.4f} {p[2]:.4f} {a[0]:.6f} {a[1]:.6f} {a[2]:.6f}")
    return "\n".join(lines) + "\n"


def read_trajectory(path, xy_m: float = 1.0, z_m: float = 1.0) -> Trajectory:
    """One trajectory file; positions scaled to metres by ``xy_m``/``z_m`` (metres per CRS unit).
    InputError naming the file and line for a malformed record or times that do not increase."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: trajectory file not found")
    rows, lines = [], []
    # the shared reader: a UTF-8 BOM (Windows exports) read like every other input file, not as a line of data
    for no, line in enumerate(read_text(path, "trajectory file").splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        try:
            vals = [float(v) for v in parts]
        except ValueError:
            vals = []
        if len(vals) != 7 or not np.all(np.isfinite(vals)):
            raise InputError(f"{path}: line {no}: expected 7 numbers (time_s x y z roll_deg pitch_deg heading_deg), "
                             f"got {s[:80]!r}")
        rows.append(vals)
        lines.append(no)
    if len(rows) < 2:
        raise InputError(f"{path}: {len(rows)} trajectory record(s); expected at least 2")
    a = np.array(rows)
    bad = np.flatnonzero(np.diff(a[:, 0]) <= 0)
    if len(bad):
        raise InputError(f"{path}: line {lines[bad[0] + 1]}: time {a[bad[0] + 1, 0]} does not increase "
                         f"(previous {a[bad[0], 0]})")
    rph = a[:, 4:7].copy()
    xyz = a[:, 1:4] * np.array([xy_m, xy_m, z_m])
    _check_heading(path, a[:, 0], xyz, rph[:, 2])
    rph[:, 2] = np.degrees(np.unwrap(np.radians(rph[:, 2])))
    return Trajectory(a[:, 0], xyz, rph, str(path))


# The heading follows the direction of travel up to the crab angle (tens of degrees at most): a trajectory whose
# heading is off it by more than HEADING_OFF_DEG on most of its moving epochs holds another quantity (radians: 88 deg
# off on an east-west line; a heading from east: 90 deg; trial-messy F2, F9: read as degrees, the strip adjustment
# "improved" the strips by a boresight and scan-angle scale of nothing, corrections 0.14-0.18 m in plan)
HEADING_OFF_DEG = 45.0
MOVING_MPS = 5.0  # epochs slower than this (turns on the ground, hovering) say nothing of the heading
MOVING_EPOCHS_MIN = 10


def _check_heading(path, t, xyz_m, heading_deg) -> None:
    """InputError when the heading is off the direction of travel (clockwise from grid north) by more than
    ``HEADING_OFF_DEG`` on more than half of the epochs moving faster than ``MOVING_MPS``."""
    d = np.diff(xyz_m[:, :2], axis=0)
    speed = np.hypot(d[:, 0], d[:, 1]) / np.diff(t)
    moving = speed > MOVING_MPS
    if moving.sum() < MOVING_EPOCHS_MIN:
        return
    track = np.degrees(np.arctan2(d[:, 0], d[:, 1]))[moving]
    mid = 0.5 * (heading_deg[:-1] + heading_deg[1:])[moving]

    def off_share(h):
        off = np.abs((h - track + 180.0) % 360.0 - 180.0)
        return float(np.mean(off > HEADING_OFF_DEG)), off

    share, off = off_share(mid)
    if share <= 0.5:
        return
    # the readings that would follow the travel, named when one does
    readings = {"in radians": np.degrees(mid), "from east, anticlockwise": 90.0 - mid, "anticlockwise": -mid}
    fits = [name for name, h in readings.items() if off_share(h)[0] <= 0.5]
    hint = f"it follows the travel read {fits[0]}" if fits else "radians, or another axis or direction?"
    raise InputError(f"{path}: the heading is more than {HEADING_OFF_DEG:g} deg off the direction of travel on "
                     f"{100 * share:.0f} % of the {int(moving.sum())} epochs moving faster than {MOVING_MPS:g} m/s "
                     f"(median {float(np.median(off)):.1f} deg off); expected heading_deg in degrees clockwise from "
                     f"grid north (90: flying east): {hint}")


def read_trajectories(paths, xy_m: float = 1.0, z_m: float = 1.0) -> list[Trajectory]:
    return [read_trajectory(p, xy_m, z_m) for p in paths]


def for_times(trajs: list[Trajectory], t: np.ndarray, what: str) -> Trajectory:
    """The trajectory that covers every time of ``t`` (a strip's GPS times); InputError naming ``what`` if
    none does."""
    for tr in trajs:
        if tr.covers(np.array([t.min(), t.max()])).all():
            return tr
    spans = "; ".join(f"{tr.source}: {tr.t[0]:.3f} .. {tr.t[-1]:.3f}" for tr in trajs)
    raise InputError(f"{what}: GPS times {t.min():.3f} .. {t.max():.3f} are not covered by any trajectory ({spans})")
