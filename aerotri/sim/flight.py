"""Flight planning: frame strips with overlaps, true attitudes, GNSS antenna observations, LiDAR lines.

The frames fly east-west strips (x in the local frame). The DMC's long image side lies across
track, so kappa is about -90 deg flying east and +90 deg flying west (the top of the image looks
forward). Strips alternate direction, as flown.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aerotri.geom.camera import BrownCamera
from aerotri.geom.rotation import rotation_matrix_opk
from aerotri.sim.config import Preset, PresetCamera


@dataclasses.dataclass
class FramePlan:
    image_id: list[str]
    strip: np.ndarray  # (N,) 1-based strip number
    centre_m: np.ndarray  # (N, 3) local projection centres
    opk_deg: np.ndarray  # (N, 3) omega phi kappa
    time_s: np.ndarray  # (N,) GPS time of exposure
    antenna_true_m: np.ndarray  # (N, 3) local antenna positions (no error)
    antenna_obs_m: np.ndarray  # (N, 3) observed GNSS positions (noise, shift, drift)
    strip_shift_m: np.ndarray  # (S, 3)
    strip_drift_m_per_s: np.ndarray  # (S, 3)
    strip_t0_s: np.ndarray  # (S,) reference time of each strip's drift


def cameras_from_config(cam: PresetCamera) -> tuple[BrownCamera, BrownCamera]:
    """(true camera, nominal camera) from the ``[camera]`` table."""
    pixel_um = cam.sensor_width_mm * 1000.0 / cam.width
    true = BrownCamera(
        focal_mm=float(cam.focal_mm), pixel_um=pixel_um, width=int(cam.width), height=int(cam.height),
        ppx_mm=float(cam.ppx_mm), ppy_mm=float(cam.ppy_mm), k1=float(cam.k1), k2=float(cam.k2),
        k3=float(cam.k3), p1=float(cam.p1), p2=float(cam.p2), name="DMC-like (true)",
    )
    nominal = BrownCamera(focal_mm=true.focal_mm, pixel_um=pixel_um, width=true.width, height=true.height,
                          name="DMC-like")
    return true, nominal


@dataclasses.dataclass(frozen=True)
class BlockLayout:
    """Footprint, base and strip spacing of the frame block, and the scene that holds it (local metres)."""

    footprint_along_m: float
    footprint_across_m: float
    base_m: float
    strip_spacing_m: float
    width_m: float  # scene size: the block plus a margin on every side
    height_m: float
    margin_m: float


@dataclasses.dataclass(frozen=True)
class LidarLine:
    """One LiDAR flight line: east-west at ``y_m``, ``z_m`` above the local origin."""

    strip: int  # 1-based
    y_m: float
    east: bool  # flown towards +x
    z_m: float
    swath_m: float
    t0_s: float  # GPS time at the start of the line


def block_layout(cfg: Preset) -> BlockLayout:
    """Footprints, base and strip spacing, and the scene size that holds the block with margins."""
    f = cfg.flight
    cam = cfg.camera
    H = f.height_above_ground_m
    along = H * cam.sensor_height_mm / cam.focal_mm
    across = H * cam.sensor_width_mm / cam.focal_mm
    base = (1.0 - f.forward_overlap) * along
    spacing = (1.0 - f.side_overlap) * across
    block_x = (f.frames_per_strip - 1) * base + along
    block_y = (f.strips - 1) * spacing + across
    margin = cfg.scene.margin_m
    return BlockLayout(footprint_along_m=along, footprint_across_m=across, base_m=base, strip_spacing_m=spacing,
                       width_m=block_x + 2 * margin, height_m=block_y + 2 * margin, margin_m=margin)


def plan_frames(cfg: Preset, layout: BlockLayout, rng) -> FramePlan:
    """Frame positions and attitudes along alternating strips, and the GNSS antenna observations with
    per-strip shift and drift and white noise (``rng`` draws in a fixed order: same seed, same plan)."""
    f = cfg.flight
    g = cfg.gnss
    H = f.height_above_ground_m
    ns, nf = int(f.strips), int(f.frames_per_strip)
    margin = layout.margin_m
    ids, strip, C, opk, times = [], [], [], [], []
    tilt_sd = f.max_tilt_deg / 2.5
    kap_sd = f.max_kappa_dev_deg / 3.0
    t_strip0 = []
    for s in range(ns):
        east = s % 2 == 0
        y = margin + layout.footprint_across_m / 2 + s * layout.strip_spacing_m
        xs = margin + layout.footprint_along_m / 2 + np.arange(nf) * layout.base_m
        if not east:
            xs = xs[::-1]
        crab = np.clip(rng.normal(0, kap_sd), -0.6 * f.max_kappa_dev_deg, 0.6 * f.max_kappa_dev_deg)
        t0 = 1000.0 + s * 400.0  # strips flown 400 s apart (turns)
        t_strip0.append(t0 + 0.5 * (nf - 1) * layout.base_m / f.speed_mps)
        for i, x in enumerate(xs):
            ids.append(f"s{s + 1:02d}_{i + 1:03d}")
            strip.append(s + 1)
            C.append((x, y + rng.normal(0, 2.0), H + rng.normal(0, 3.0)))
            om, ph = np.clip(rng.normal(0, tilt_sd, 2), -0.95 * f.max_tilt_deg, 0.95 * f.max_tilt_deg)
            dk = np.clip(crab + rng.normal(0, kap_sd / 2), -0.95 * f.max_kappa_dev_deg, 0.95 * f.max_kappa_dev_deg)
            opk.append((om, ph, (-90.0 if east else 90.0) + dk))
            times.append(t0 + i * layout.base_m / f.speed_mps)
    C = np.array(C)
    opk = np.array(opk)
    times = np.array(times)
    strip = np.array(strip)
    # The drift (crab) angle is relative to the track actually flown, which wanders with the lateral
    # position: heading = track direction + drift. Track from the neighbouring frames (one-sided at the
    # ends), as flight acceptance measures it.
    for s in range(1, ns + 1):
        idx = np.flatnonzero(strip == s)
        if len(idx) < 2:
            continue
        ahead = C[idx[np.minimum(np.arange(len(idx)) + 1, len(idx) - 1)], :2]
        behind = C[idx[np.maximum(np.arange(len(idx)) - 1, 0)], :2]
        d = ahead - behind
        nominal = np.arctan2(0.0, np.sign(d[:, 0]))
        opk[idx, 2] += np.degrees((np.arctan2(d[:, 1], d[:, 0]) - nominal + np.pi) % (2 * np.pi) - np.pi)
    R = rotation_matrix_opk(opk[:, 0], opk[:, 1], opk[:, 2])
    lever = np.asarray(g.lever_arm_m, dtype=float)
    antenna = C + np.einsum("nij,j->ni", R, lever)
    shift = rng.normal(0, g.strip_shift_sigma_m, (ns, 3))
    drift = rng.normal(0, g.drift_sigma_m_per_s, (ns, 3))
    t_ref = np.array(t_strip0)
    err = shift[strip - 1] + drift[strip - 1] * (times - t_ref[strip - 1])[:, None]
    obs = antenna + err + rng.normal(0, g.sigma_m, antenna.shape)
    return FramePlan(ids, strip, C, opk, times, antenna, obs, shift, drift, t_ref)


def lidar_lines(cfg: Preset, layout: BlockLayout) -> list[LidarLine]:
    """Flight lines of the LiDAR: east-west, covering the whole scene with the configured side overlap."""
    L = cfg.lidar
    H = L.height_above_ground_m
    swath = 2.0 * H * math.tan(math.radians(L.fov_deg / 2.0))
    spacing = (1.0 - L.side_overlap) * swath
    Hs = layout.height_m
    n = max(1, int(math.ceil(max(0.0, Hs - swath) / spacing)) + 1)
    y0 = Hs / 2 - (n - 1) * spacing / 2
    lines = []
    for s in range(n):
        lines.append(LidarLine(strip=s + 1, y_m=y0 + s * spacing, east=(s % 2 == 0), z_m=H, swath_m=swath,
                               t0_s=5000.0 + s * 300.0))
    return lines
