"""Airborne laser scanner model (Optech ALTM 3100-like) and LAS 1.4 output.

Each strip is flown at constant speed and height; an oscillating mirror sweeps the beam across
track in a zig-zag (triangle wave in scan angle) at ``scan_frequency_hz``; pulses leave at
``pulse_rate_hz``. Every pulse is ray-cast into the scene. Tree crowns are porous: a pulse may
return from the crown surface, from inside the crown and from what lies beneath (ground or roof),
so vegetation gives several returns with the last one on the ground. Most pulses on water give
no return. Range noise, a small per-strip offset (GNSS/IMU error), low outliers (multipath,
50-110 m below the surface, also under trees and in ponds) and high outliers (birds) are added.
Truth classes (ASPRS): 2 ground, 3/4/5 low/medium/high vegetation, 6 building, 7 low noise,
9 water, 18 high noise.

System calibration errors (injected only when asked; zero in the presets, so that their output does
not change): ``boresight_error_deg`` (roll, pitch, heading of the scanner against the IMU in the body
frame x forward, y right, z down: the beam leaves along R_bw Rz(h) Ry(p) Rx(r) u while the points are
computed along R_bw u), ``range_offset_m`` (added to every measured range) and
``scan_angle_scale_error`` k (the mirror's angle encoder reads theta while the beam leaves at
theta (1 + k): the points are computed at the angle read). ``trajectory`` gives
the trajectory records of a strip (lidarctl.strips.trajectory text format), which carry the strip's
GNSS offset as its points do.
"""

from __future__ import annotations

import dataclasses
import datetime
import math

import laspy
import numba
import numpy as np
from laspy.vlrs.known import WktCoordinateSystemVlr

from aerotri.geom.crs.definition import epsg_wkt
from aerotri.sim import raycast, shading
from aerotri.sim.config import PresetLidar
from aerotri.sim.flight import LidarLine
from aerotri.sim.scene import KIND_NONE, KIND_ROOF, KIND_TERRAIN, KIND_TREE, KIND_WALL, WATER, Scene

MAX_RET = 3
# Pulses ray-cast and written at a time: bounds the memory of a strip (about 250 bytes a pulse at the peak)
# whatever its length. Every strip of the tiny, demo and dmc presets is one chunk.
STRIP_CHUNK_PULSES = 3_000_000
GPS_TIME_OFFSET_S = 4.0e8  # LAS gps_time = simulation time + this (adjusted standard GPS time)


@numba.njit(cache=True, parallel=True)
def _pulses(origins, dirs, S, *, u, p_first, p_interior, p_ground):
    """Up to three returns per pulse: (t, kind, obj) arrays (n, 3); t = inf where no return.

    ``u`` (n, 3) are uniform random numbers deciding the canopy behaviour of each pulse.
    """
    n = dirs.shape[0]
    tc = S[13]
    ta = S[14]
    T = np.full((n, MAX_RET), np.inf)
    K = np.zeros((n, MAX_RET), np.int64)
    O = np.full((n, MAX_RET), -1, np.int64)
    for r in numba.prange(n):
        o = origins[r]
        d = dirs[r]
        t, kind, obj, nx, ny, nz = raycast.cast(o, d, S, numba.boolean(True), numba.int64(-1))
        if kind == KIND_NONE:
            continue
        if kind != KIND_TREE:
            T[r, 0] = t
            K[r, 0] = kind
            O[r, 0] = obj
            continue
        k = 0
        if u[r, 0] < p_first:
            T[r, k] = t
            K[r, k] = KIND_TREE
            O[r, k] = obj
            k += 1
            if u[r, 1] < p_interior:
                # Exit of the ray from this crown (second root of the spheroid equation).
                a = ta[obj, 0]
                c = ta[obj, 1]
                sx = (o[0] - tc[obj, 0]) / a
                sy = (o[1] - tc[obj, 1]) / a
                sz = (o[2] - tc[obj, 2]) / c
                ux = d[0] / a
                uy = d[1] / a
                uz = d[2] / c
                A = ux * ux + uy * uy + uz * uz
                B = 2.0 * (sx * ux + sy * uy + sz * uz)
                C = sx * sx + sy * sy + sz * sz - 1.0
                disc = max(B * B - 4.0 * A * C, 0.0)
                t2 = (-B + math.sqrt(disc)) / (2.0 * A)
                frac = 0.25 + 0.5 * u[r, 2]
                if t2 - t > 2.0:  # a return inside the crown needs room to separate from the first
                    T[r, k] = t + frac * (t2 - t)
                    K[r, k] = KIND_TREE
                    O[r, k] = obj
                    k += 1
        if k == 0 or u[r, 2] < p_ground:
            tg, kg, og, nx, ny, nz = raycast.cast(o, d, S, numba.boolean(False), numba.int64(-1))
            if kg != KIND_NONE and (k == 0 or tg - T[r, k - 1] > 1.5):
                T[r, k] = tg
                K[r, k] = kg
                O[r, k] = og
    return T, K, O


def _triangle_wave(phase):
    """-1..1..-1 over one period (phase in cycles); returns value and sign of its slope."""
    p = phase % 1.0
    val = np.where(p < 0.5, -1.0 + 4.0 * p, 3.0 - 4.0 * p)
    rising = p < 0.5
    return val, rising


@dataclasses.dataclass
class _Sweep:
    """The pulses of one strip: emission time, origin and direction, scan angle and mirror direction."""

    t: np.ndarray  # (n,) s since the start of the line
    origins: np.ndarray  # (n, 3) local metres
    dirs: np.ndarray  # (n, 3) unit
    theta: np.ndarray  # (n,) scan angle (rad), positive to the right of the track
    rising: np.ndarray  # (n,) bool: the mirror sweeps towards increasing angle
    nominal: np.ndarray | None = None  # (n, 3) directions the points are computed along (None: ``dirs``)


def strip_pulses(line: LidarLine, L: PresetLidar, width_m: float) -> int:
    """Number of pulses of one strip: the scene width plus half a swath at each end, flown at constant speed."""
    return int((width_m + line.swath_m) / L.speed_mps * L.pulse_rate_hz)


def pulse_chunks(n_pulses: int, chunk_pulses: int | None = None) -> list[tuple[int, int]]:
    """``[i0, i1)`` pulse ranges of at most ``chunk_pulses`` (default ``STRIP_CHUNK_PULSES``) that a strip is
    scanned and written in."""
    chunk_pulses = chunk_pulses or STRIP_CHUNK_PULSES
    return [(i0, min(n_pulses, i0 + chunk_pulses)) for i0 in range(0, max(n_pulses, 1), chunk_pulses)]


def _sweep(line: LidarLine, L: PresetLidar, rng, width_m: float, i0: int = 0, i1: int | None = None) -> _Sweep:
    """Zig-zag pulses ``i0..i1`` of the flight line with attitude noise (draws ``rng`` once: the attitude noise).

    Times, positions and scan angles follow from the pulse index, so a chunk of pulses is the same as that
    part of the whole strip; only the attitude noise depends on how the strip is chunked.
    """
    v = L.speed_mps
    prf = L.pulse_rate_hz
    half_fov = math.radians(L.fov_deg / 2.0)
    # Fly past the scene ends by half a swath so the corners are covered.
    lead = line.swath_m / 2.0
    i1 = strip_pulses(line, L, width_m) if i1 is None else i1
    n = i1 - i0
    t = np.arange(i0, i1) / prf
    x_air = (-lead + v * t) if line.east else (width_m + lead - v * t)
    y_air = line.y_m + 0.5 * np.sin(2 * np.pi * t / 37.0)  # a gentle weave of the flight line
    z_air = np.full(n, line.z_m)
    tri, rising = _triangle_wave(L.scan_frequency_hz * t)
    theta = tri * half_fov
    # Across-track is +y (left) flying east; the scan angle is positive to the right of the track.
    side = -1.0 if line.east else 1.0
    att = np.radians(L.attitude_noise_deg) * rng.standard_normal((n, 2))

    def beam(angle):
        d = np.stack([np.zeros(n), side * np.sin(angle), -np.cos(angle)], axis=1)
        d[:, 0] += att[:, 0]
        d[:, 1] += att[:, 1]
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    dirs = beam(theta)
    origins = np.stack([x_air, y_air, z_air], axis=1)
    rb = boresight_rotation(L)
    k = float(L.scan_angle_scale_error)
    if rb is None and k == 0.0:
        return _Sweep(t, origins, dirs, theta, rising)
    # the beam leaves at the scaled angle, rotated by the boresight error; the points are computed along the
    # nominal direction (the angle read, the IMU's attitude)
    actual = beam(theta * (1.0 + k)) if k != 0.0 else dirs
    if rb is not None:
        bw = body_to_world(line)
        actual = actual @ (bw @ rb @ bw.T).T
    return _Sweep(t, origins, actual, theta, rising, nominal=dirs)


def boresight_rotation(L: PresetLidar) -> np.ndarray | None:
    """Rz(heading) Ry(pitch) Rx(roll) of ``boresight_error_deg`` in the body frame; None when zero (or absent)."""
    r, p, h = np.radians(np.asarray(L.boresight_error_deg, float))
    if r == 0 and p == 0 and h == 0:
        return None
    cr, sr, cp, sp, ch, sh = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(h), np.sin(h)
    return np.array([[ch * cp, ch * sp * sr - sh * cr, ch * sp * cr + sh * sr],
                     [sh * cp, sh * sp * sr + ch * cr, sh * sp * cr - ch * sr],
                     [-sp, cp * sr, cp * cr]])


def body_to_world(line: LidarLine) -> np.ndarray:
    """Columns: the body axes forward, right, down in local east-north-up (level flight along x)."""
    f = 1.0 if line.east else -1.0
    return np.array([[f, 0.0, 0.0], [0.0, -f, 0.0], [0.0, 0.0, -1.0]]).T


def trajectory(line: LidarLine, L: PresetLidar, width_m: float, rate_hz: float = 50.0):
    """(LAS gps_time, scanner positions (n, 3) in local metres, roll/pitch/heading (n, 3) deg) of a strip at
    ``rate_hz``, over the strip's pulses and a second beyond; the positions follow ``_sweep`` (the weave)."""
    v = L.speed_mps
    lead = line.swath_m / 2.0
    t_end = strip_pulses(line, L, width_m) / L.pulse_rate_hz
    t = np.arange(-1.0, t_end + 1.0, 1.0 / rate_hz)
    x = (-lead + v * t) if line.east else (width_m + lead - v * t)
    y = line.y_m + 0.5 * np.sin(2 * np.pi * t / 37.0)
    xyz = np.column_stack([x, y, np.full(len(t), line.z_m)])
    rph = np.column_stack([np.zeros(len(t)), np.zeros(len(t)), np.full(len(t), 90.0 if line.east else 270.0)])
    return line.t0_s + t + GPS_TIME_OFFSET_S, xyz, rph


@dataclasses.dataclass
class _Returns:
    """Up to ``MAX_RET`` returns per pulse: ray parameter, surface kind and object, which ones are recorded,
    and the class of the outliers (7 low, 18 high noise; 0 for the others)."""

    ranges: np.ndarray  # (n, MAX_RET) t along the unit direction (m); inf: no return
    kinds: np.ndarray  # (n, MAX_RET)
    objs: np.ndarray  # (n, MAX_RET)
    valid: np.ndarray  # (n, MAX_RET) bool
    cls_override: np.ndarray  # (n,)


def _water_and_outliers(scene: Scene, sw: _Sweep, T, *, K, O, L: PresetLidar, rng) -> _Returns:
    """Most pulses on water give no return; low outliers (beyond the surface, preferably under trees and
    in ponds) and high outliers (birds) replace the returns of some pulses."""
    n = len(sw.t)
    valid = np.isfinite(T)
    # Water: most pulses give no return.
    first_hit = np.where(valid[:, 0], T[:, 0], 0.0)
    px = sw.origins[:, 0] + sw.dirs[:, 0] * first_hit
    py = sw.origins[:, 1] + sw.dirs[:, 1] * first_hit
    mat = shading.ground_materials(np.ascontiguousarray(px), np.ascontiguousarray(py), shading.ground_index(scene))
    on_water = valid[:, 0] & (K[:, 0] == KIND_TERRAIN) & (mat == WATER)

    # Outliers: low (below the surface along the beam) and high (birds).
    n_low = rng.binomial(n, L.low_outlier_rate)
    n_high = rng.binomial(n, L.high_outlier_rate)
    cand_tree = np.flatnonzero(valid[:, 0] & (K[:, 0] == KIND_TREE))
    cand_water = np.flatnonzero(on_water)
    cand_any = np.flatnonzero(valid[:, 0])
    picks = []
    for cand, share in ((cand_tree, 0.3), (cand_water, 0.2)):
        k = min(len(cand), int(round(share * n_low)))
        if k:
            picks.append(rng.choice(cand, k, replace=False))
    k_rest = n_low - sum(len(p) for p in picks)
    if k_rest > 0 and len(cand_any):
        picks.append(rng.choice(cand_any, k_rest, replace=False))
    low = np.unique(np.concatenate(picks)) if picks else np.zeros(0, int)
    # (both sorted and unique: numpy 2.4's np.unique of millions of distinct integers, which setdiff1d would
    # call, takes seconds)
    rest = np.setdiff1d(cand_any, low, assume_unique=True)
    high = rng.choice(rest, min(n_high, len(cand_any)), replace=False) if n_high else np.zeros(0, int)

    keep_water = rng.random(n) < L.water_return_fraction
    drop = on_water & ~keep_water
    drop[low] = False
    valid[drop] = False

    ranges = T.copy()
    kinds = K.copy()
    objs = O.copy()
    cls_override = np.zeros(n, np.int64)
    dirs = sw.dirs
    # Low outliers: a single return 50-110 m beyond the surface along the beam.
    last = np.where(valid, np.arange(MAX_RET)[None, :], -1).max(axis=1)
    base_t = ranges[low, np.maximum(last[low], 0)]
    ranges[low] = np.inf
    ranges[low, 0] = base_t + rng.uniform(50.0, 110.0, len(low)) / np.maximum(-dirs[low, 2], 0.5)
    valid[low] = False
    valid[low, 0] = True
    cls_override[low] = 7
    # High outliers: a single return 40-300 m above the surface.
    first_t = ranges[high, 0]
    ranges[high] = np.inf
    ranges[high, 0] = first_t - rng.uniform(40.0, 300.0, len(high)) / np.maximum(-dirs[high, 2], 0.5)
    valid[high] = False
    valid[high, 0] = True
    cls_override[high] = 18
    return _Returns(ranges, kinds, objs, valid, cls_override)


def _truth_classes(scene: Scene, P, kind, gm, override) -> np.ndarray:
    """ASPRS class of every point from the surface it hit, its height above the terrain and the outliers."""
    zg = scene.terrain_height(P[:, 0], P[:, 1])
    hag = P[:, 2] - zg
    cls = np.full(len(P), 1, np.uint8)
    cls[kind == KIND_TERRAIN] = 2
    cls[(kind == KIND_TERRAIN) & (gm == WATER)] = 9
    cls[(kind == KIND_ROOF) | (kind == KIND_WALL)] = 6
    veg = kind == KIND_TREE
    cls[veg & (hag < 0.5)] = 3
    cls[veg & (hag >= 0.5) & (hag < 2.0)] = 4
    cls[veg & (hag >= 2.0)] = 5
    cls[override > 0] = override[override > 0]
    return cls


@dataclasses.dataclass(frozen=True)
class ScannedPoints:
    """The returns of a stretch of one strip (``scan_strip``): local metres and the LAS point attributes."""

    xyz: np.ndarray  # (n, 3) local metres
    intensity: np.ndarray  # uint16
    return_number: np.ndarray  # uint8
    number_of_returns: np.ndarray  # uint8
    scan_direction_flag: np.ndarray  # uint8
    edge_of_flight_line: np.ndarray  # uint8
    scan_angle_deg: np.ndarray
    gps_time: np.ndarray  # s, the strip's time
    classification: np.ndarray  # ASPRS classes (truth)
    point_source_id: np.ndarray  # uint16, the strip number


def scan_strip(scene: Scene, accel, line: LidarLine, *, L: PresetLidar, rng, width_m: float, i0: int = 0,
               i1: int | None = None) -> ScannedPoints:
    """Simulate pulses ``i0..i1`` of one strip (default: all of it); returns its points in local metres plus
    truth classes (the fields ``las_record`` writes). Draws ``rng`` in a fixed order per chunk."""
    n_strip = strip_pulses(line, L, width_m)
    i1 = n_strip if i1 is None else i1
    sw = _sweep(line, L, rng, width_m, i0, i1)
    n = len(sw.t)
    u = rng.random((n, 3))
    T, K, O = _pulses(sw.origins, np.ascontiguousarray(sw.dirs), accel, u=u, p_first=L.canopy_first_return_prob,
                      p_interior=L.canopy_interior_return_prob, p_ground=L.canopy_ground_return_prob)
    rt = _water_and_outliers(scene, sw, T, K=K, O=O, L=L, rng=rng)
    valid = rt.valid
    nret = valid.sum(axis=1)
    pulse, ret = np.nonzero(valid)
    # Returns are stored in time order per pulse: compact the valid slots.
    order_in_pulse = np.cumsum(valid, axis=1)[pulse, ret]
    rng_m = rt.ranges[pulse, ret] + rng.normal(0.0, L.range_noise_m, pulse.size)
    offset = float(L.range_offset_m)
    if sw.nominal is None and offset == 0.0:
        P = sw.origins[pulse] + sw.dirs[pulse] * rng_m[:, None]
    else:
        nominal = sw.dirs if sw.nominal is None else sw.nominal
        P = sw.origins[pulse] + nominal[pulse] * (rng_m + offset)[:, None]
    kind = rt.kinds[pulse, ret]
    obj = rt.objs[pulse, ret]
    gm = shading.ground_materials(P[:, 0].copy(), P[:, 1].copy(), shading.ground_index(scene))
    cls = _truth_classes(scene, P, kind, gm, rt.cls_override[pulse])
    # Intensity from a reflectance per surface (1064 nm), incidence and range.
    refl = np.select([kind == KIND_TREE, kind == KIND_ROOF, kind == KIND_WALL, gm == WATER, gm == 2, gm == 3,
                      gm == 5, gm == 6, gm == 1], [0.5, 0.3, 0.25, 0.04, 0.12, 0.6, 0.8, 0.05, 0.35], 0.45)
    refl = np.where(kind == KIND_ROOF, 0.15 + 0.5 * scene.roof_albedo[np.where(kind == KIND_ROOF, obj, 0)].mean(axis=1), refl)
    split = np.where(nret[pulse] > 1, 0.6, 1.0)
    inten = refl * split * (line.z_m / np.maximum(rng_m, 1.0)) ** 2 * 30000.0
    inten *= rng.lognormal(0.0, 0.15, inten.size)
    scan_deg = np.degrees(sw.theta[pulse])
    # Edge of flight line: the last pulse before the mirror turns.
    turn = np.flatnonzero(sw.rising[1:] != sw.rising[:-1])
    edge_pulse = np.zeros(n, bool)
    edge_pulse[turn] = True
    if i1 < n_strip:  # the chunk's last pulse is an edge when the mirror turns before the next chunk's first
        _, rising_next = _triangle_wave(L.scan_frequency_hz * (i1 / L.pulse_rate_hz))
        edge_pulse[-1] = bool(rising_next) != bool(sw.rising[-1])
    edge = edge_pulse[pulse]
    return ScannedPoints(
        xyz=P, intensity=np.clip(inten, 0, 65535).astype(np.uint16), return_number=order_in_pulse.astype(np.uint8),
        number_of_returns=nret[pulse].astype(np.uint8), scan_direction_flag=sw.rising[pulse].astype(np.uint8),
        edge_of_flight_line=edge.astype(np.uint8), scan_angle_deg=scan_deg, gps_time=line.t0_s + sw.t[pulse],
        classification=cls, point_source_id=np.full(pulse.size, line.strip, np.uint16),
    )


def las_header(origin_m, epsg: int, creation_date=datetime.date(2026, 1, 1)) -> laspy.LasHeader:
    """LAS 1.4, point format 6, millimetre scale, CRS (WKT); the same for every chunk of a strip."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(np.asarray(origin_m, dtype=float) / 1000.0) * 1000.0
    # the WKT record add_crs writes, with the text PROJ's database gives in a fresh context: this process's PROJ cache
    # may give the code another (equivalent) definition, and the files other bytes (epsg_wkt)
    header.vlrs.append(WktCoordinateSystemVlr(epsg_wkt(epsg)))
    header.global_encoding.wkt = True
    header.creation_date = creation_date
    header.system_identifier = "aerotri simulator"
    header.generating_software = "aerotri sim"
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    return header


def las_record(header: laspy.LasHeader, pts: ScannedPoints, origin_m, classification=None) -> laspy.LasData:
    """The points of ``scan_strip`` (local metres) as LAS records in the project CRS."""
    las = laspy.LasData(header)
    xyz = pts.xyz + np.asarray(origin_m, dtype=float)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.intensity = pts.intensity
    las.return_number = pts.return_number
    las.number_of_returns = pts.number_of_returns
    las.scan_direction_flag = pts.scan_direction_flag
    las.edge_of_flight_line = pts.edge_of_flight_line
    las.classification = pts.classification if classification is None else classification
    las.scan_angle = np.rint(pts.scan_angle_deg / 0.006).astype(np.int16)
    las.point_source_id = pts.point_source_id
    las.gps_time = pts.gps_time + GPS_TIME_OFFSET_S  # adjusted standard GPS time
    return las

