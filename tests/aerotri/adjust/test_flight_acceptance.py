"""Flight acceptance (aerotri/adjust/flight_acceptance.py) against flights of known geometry."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from aerotri.adjust.flight_acceptance import LIMIT_KEYS, Terrain, flight_acceptance, project_flight_acceptance
from aerotri.core.tolerances import FlightLimits, manned_flight_limits
from aerotri.geom.camera import BrownCamera, read_camera
from aerotri.geom.eo import read_eo

CAM = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=1728, height=960, name="DMC-like")  # long side across


def _block(base_m=40.0, spacing_m=110.0, height_m=1000.0, strips=2, frames=5):
    """A nadir block of east-west strips over flat ground at 0 m (alternating directions, kappa -90/+90)."""
    ids, c, opk, strip = [], [], [], []
    for s in range(strips):
        xs = np.arange(frames) * base_m
        for i, x in enumerate(xs if s % 2 == 0 else xs[::-1]):
            ids.append(f"s{s + 1}_{i + 1:02d}")
            c.append((x, s * spacing_m, height_m))
            opk.append((0.0, 0.0, -90.0 if s % 2 == 0 else 90.0))
            strip.append(s + 1)
    return ids, np.array(c), np.array(opk), np.array(strip)


def test_known_block_overlaps_and_limits():
    ids, c, opk, strip = _block()
    along = 1000.0 * CAM.sensor_mm[1] / CAM.focal_mm  # footprint along track (short side), m
    across = 1000.0 * CAM.sensor_mm[0] / CAM.focal_mm
    fa = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip)
    fwd = [f["forward_overlap_pct"] for f in fa.frames if f["forward_overlap_pct"] is not None]
    assert np.allclose(fwd, 100.0 * (1 - 40.0 / along), atol=0.15)
    assert fa.strips[0]["side_overlap_median_pct"] == pytest.approx(100.0 * (1 - 110.0 / across), abs=0.15)
    assert all(f["tilt_deg"] == 0.0 and f["kappa_deviation_deg"] == 0.0 for f in fa.frames)
    assert all(s["curvature_pct"] == 0.0 for s in fa.strips)
    assert not fa.failed  # 58.3 % forward, 36.3 % side: within 56 % and 13 %


@pytest.mark.parametrize("cross_x_m", [-60.0, 80.0])
def test_a_cross_strip_is_no_neighbour_across_track(cross_x_m):
    """A cross strip (north-south over east-west strips, at the west end or through the middle) was sorted in among
    the parallel strips: at the west end it got a side overlap of its own, 11.7 %, fail, and in the middle it stood
    between two strips as their neighbour (53.9 % of a true 40.4 %, trial-ew). The parallel strips keep the side
    overlaps of the block without it; the cross strip is marked and has none."""
    ids, c, opk, strip = _block(strips=3)
    plain = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip)
    cy = np.arange(-1, 5) * 40.0
    ids_x = ids + [f"x_{i + 1:02d}" for i in range(len(cy))]
    c_x = np.vstack([c, np.column_stack([np.full(len(cy), cross_x_m), cy, np.full(len(cy), 1000.0)])])
    opk_x = np.vstack([opk, np.zeros((len(cy), 3))])
    strip_x = np.concatenate([strip, np.full(len(cy), 4)])
    fa = flight_acceptance(ids_x, c_x, opk_x, CAM, Terrain(0.0), strip_x)
    got = {st["strip"]: st for st in fa.strips}
    assert [got[k]["side_overlap_median_pct"] for k in (1, 2, 3)] == [st["side_overlap_median_pct"]
                                                                       for st in plain.strips]
    assert got[4]["cross_strip"] and got[4]["side_overlap_median_pct"] is None
    assert not any(got[k]["cross_strip"] for k in (1, 2, 3))
    assert not [ch for ch in fa.failed if ch["key"] == "flight_side_overlap_min_pct"]
    assert all(f["side_overlap_pct"] is None for f in fa.frames if f["strip"] == 4)


def test_violations_are_flagged_where_they_happen():
    ids, c, opk, strip = _block()
    opk[2, :2] = (2.0, 2.0)  # tilt acos(cos 2 cos 2) = 2.83 deg
    opk[7, 2] += 8.0  # kappa off the base by 8 deg
    c[3, 2] += 40.0  # 40 m jump in flying height
    c[2, 1] += 8.0  # middle frame of strip 1 off the line: 8 m over 160 m = 5 % curvature
    fa = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip)
    by = {x["key"]: x for x in fa.checks}
    assert by["flight_tilt_max_deg"]["verdict"] == "fail" and by["flight_tilt_max_deg"]["where"] == ids[2]
    assert by["flight_tilt_max_deg"]["value"] == pytest.approx(math.degrees(math.acos(math.cos(math.radians(2)) ** 2)),
                                                                abs=0.01)
    k = by["flight_kappa_max_deg"]
    assert k["verdict"] == "fail" and k["where"] == ids[7] and k["value"] == pytest.approx(8.0, abs=0.01)
    h = by["flight_height_step_max_m"]
    assert h["verdict"] == "fail" and h["value"] == pytest.approx(40.0) and h["n_fail"] == 2  # up and down again
    assert by["flight_height_range_max_m"]["verdict"] == "pass"  # 40 m range < 50 m
    cv = by["flight_curvature_max_pct"]
    assert cv["verdict"] == "fail" and cv["where"] == "strip 1" and cv["value"] == pytest.approx(5.0, abs=0.01)
    # a contract's own limits replace the defaults
    loose = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip, limits={"flight_tilt_max_deg": 3.0})
    assert {x["key"]: x for x in loose.checks}["flight_tilt_max_deg"]["verdict"] == "pass"
    assert loose.limits == {**fa.limits, "flight_tilt_max_deg": 3.0}


def test_the_manned_specification_limits_every_key_and_a_uas_block_none():
    """flight_cn_aerial.toml [general] gives every limit the checks name (thesis section 4.1); a UAS table
    (``flight_limits_apply = false``) none: the values are reported, not judged."""
    spec = manned_flight_limits()
    assert [f.name for f in dataclasses.fields(FlightLimits)] == list(LIMIT_KEYS)
    assert (spec.flight_tilt_max_deg, spec.flight_kappa_max_deg, spec.flight_curvature_max_pct) == (2.0, 7.0, 3.0)
    assert (spec.flight_forward_overlap_min_pct, spec.flight_side_overlap_min_pct) == (56.0, 13.0)
    ids, c, opk, strip = _block()
    uas = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip, limits={"flight_limits_apply": False})
    assert uas.limits == {} and {x["verdict"] for x in uas.checks} == {"not judged"}


def test_terrain_raises_reduce_overlap():
    """Footprints on higher ground are smaller: the overlap drops as the ground rises (same flight)."""
    ids, c, opk, strip = _block()
    low = flight_acceptance(ids, c, opk, CAM, Terrain(0.0), strip)
    high = flight_acceptance(ids, c, opk, CAM, Terrain(400.0), strip)
    along_high = 600.0 * CAM.sensor_mm[1] / CAM.focal_mm
    assert high.frames[0]["forward_overlap_pct"] == pytest.approx(100 * (1 - 40.0 / along_high), abs=0.15)
    assert high.frames[0]["forward_overlap_pct"] < low.frames[0]["forward_overlap_pct"]


def test_simulated_flight_against_its_truth(tiny_project):
    """The simulator's own flight (truth EO, true camera, true DEM): tilts as computed from omega and phi,
    within the preset's limits (the plan clips them at 95 %), forward overlap near the planned 60 %."""
    fa = json.loads((tiny_project / "truth" / "flight_acceptance.json").read_text())
    eo = read_eo(tiny_project / "truth" / "eo.txt")
    tilt = np.degrees(np.arccos(np.cos(np.radians(eo.opk_deg[:, 0])) * np.cos(np.radians(eo.opk_deg[:, 1]))))
    got = {f["image_id"]: f["tilt_deg"] for f in fa["frames"]}
    assert np.allclose([got[i] for i in eo.image_id], tilt, atol=1e-3)
    by = {x["key"]: x for x in fa["checks"]}
    assert by["flight_tilt_max_deg"]["verdict"] == "pass" and by["flight_tilt_max_deg"]["value"] <= 0.95 * 2.0 + 1e-3
    fwd = [f["forward_overlap_pct"] for f in fa["frames"] if f["forward_overlap_pct"] is not None]
    assert 50.0 < np.mean(fwd) < 70.0  # 60 % planned at the mean terrain height; the relief moves it
    # kappa: the plan's crab (kappa - (-90) flying east, - 90 flying west) against the direction of the
    # base to the neighbouring frames (the plan scatters the centres 2 m across track)
    frames = {f["image_id"]: f for f in fa["frames"]}
    for s in {f["strip"] for f in fa["frames"]}:
        ids = sorted(i for i in eo.image_id if frames[i]["strip"] == s)
        c = np.array([eo.centre_m[eo.image_id.index(i)] for i in ids])
        east = c[-1, 0] > c[0, 0]
        for n, iid in enumerate(ids):
            a, b = max(n - 1, 0), min(n + 1, len(ids) - 1)
            turn = np.degrees(np.arctan2(c[b, 1] - c[a, 1], c[b, 0] - c[a, 0])) - (0.0 if east else 180.0)
            crab = eo.opk_deg[eo.image_id.index(iid), 2] - (-90.0 if east else 90.0)
            expect = abs((crab - turn + 180.0) % 360.0 - 180.0)
            assert frames[iid]["kappa_deviation_deg"] == pytest.approx(expect, abs=0.01)
            assert abs(crab) <= 0.95 * 7.0 + 1e-6  # the plan's clip
    # forward overlap: the flat-terrain formula at each pair's height above the DEM under its centres
    cam = read_camera(tiny_project / "truth" / "camera.toml")
    idx = {iid: i for i, iid in enumerate(eo.image_id)}
    diffs = []
    for f in fa["frames"]:
        nxt = [g for g in fa["frames"] if g["strip"] == f["strip"]]
        k = nxt.index(f)
        if f["forward_overlap_pct"] is None:
            continue
        g = nxt[k + 1]
        base = np.linalg.norm(eo.centre_m[idx[g["image_id"]], :2] - eo.centre_m[idx[f["image_id"]], :2])
        agl = (f["height_above_ground_m"] + g["height_above_ground_m"]) / 2
        along = agl * cam.sensor_mm[1] / cam.focal_mm
        diffs.append(f["forward_overlap_pct"] - 100.0 * (1 - base / along))
    assert abs(np.mean(diffs)) < 3.0 and np.max(np.abs(diffs)) < 8.0
    # before the adjustment: GNSS positions with the nominal attitude give the same overlaps within a few %
    pre = project_flight_acceptance(tiny_project)
    assert pre.source.startswith("GNSS")
    assert all(f["tilt_deg"] is None for f in pre.frames)
    pre_fwd = {f["image_id"]: f["forward_overlap_pct"] for f in pre.frames}
    truth_fwd = {f["image_id"]: f["forward_overlap_pct"] for f in fa["frames"]}
    # the true DEM vs the project's mean terrain height (no lidar_out yet), the true vs nominal attitude
    diffs = [abs(pre_fwd[i] - truth_fwd[i]) for i in truth_fwd if truth_fwd[i] is not None and pre_fwd.get(i)]
    assert diffs and max(diffs) < 12.0
