"""``lidarctl check-plan`` on a synthetic classified scene with known eave corners, in US survey feet (NY Long
Island, EPSG:2263: the metre conversions are exercised): the offsets of surveyed points shifted by a known amount
come back as the bias in metres, far points are not found, heights give dz; bad input (missing column, points
outside the cloud, CRS mismatch) stops with exit 2 and writes nothing."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from lidarctl.cli.main import main
from lidarctl.checks.plan import read_plan_check

_spec = importlib.util.spec_from_file_location("corners_synth", Path(__file__).with_name("corners_synth.py"))
cs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cs)

E0, N0 = 1_000_000.0, 200_000.0  # state-plane feet: realistic coordinate magnitudes
FT = 1200.0 / 3937.0  # US survey foot in metres
SHIFT = np.array([0.30, -0.20])  # surveyed = true corner - SHIFT, so LiDAR - surveyed = SHIFT


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("plan")
    buildings = cs.default_buildings()
    x, y, z, cls, sid = cs.make_cloud(buildings, seed=3, heading_deg=-20.0)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([E0, N0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(2263))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x / FT + E0, y / FT + N0, z / FT
    las.classification = cls
    las.point_source_id = sid
    las.write(d / "classified.las")
    truth, kinds, bid = cs.truth_corners(buildings)
    pts = truth
    lines = ["id,x,y,z"] + [f"P{k},{(p[0] - SHIFT[0]) / FT + E0:.3f},{(p[1] - SHIFT[1]) / FT + N0:.3f},{p[2] / FT:.3f}"
                            for k, p in enumerate(pts)]
    lines += [f"FAR1,{E0 + 140.0 / FT:.3f},{N0 + 5.0 / FT:.3f},6.0", f"FAR2,{E0 + 5.0 / FT:.3f},{N0 + 135.0 / FT:.3f},6.0"]
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    return d, len(pts)


def test_check_plan_recovers_the_bias_and_counts(scene):
    d, n_true = scene
    r = CliRunner().invoke(main, ["check-plan", str(d / "classified.las"), str(d / "points.csv"), "--radius-m", "1.5",
                                  "--json", str(d / "plan.json"), "--png", str(d / "plan.png")])
    assert r.exit_code == 0, r.output
    res = read_plan_check(d / "plan.json")
    # the reader gives back what was written, to the byte
    assert res.to_json() == (d / "plan.json").read_text()
    assert json.loads((d / "plan.json").read_text())["schema_version"] == 1
    s = res.overall
    assert s.n_points == n_true + 2
    far = {p.id: p.found for p in res.points if p.id.startswith("FAR")}
    assert far == {"FAR1": False, "FAR2": False}
    assert res.units.xy_name == "us-ft" and res.units.xy_m == pytest.approx(FT)
    p0 = res.points[0]  # per-point coordinates stay in the CRS's feet
    assert abs(p0.x - E0) < 200.0 / FT and p0.x > E0
    assert s.n_found >= 0.8 * n_true  # the detector finds most eave corners (issue 4: >= 80 %)
    # the bias is the known shift; the spread is the detector's (< 0.2 m RMS on this scene)
    assert s.mean_dx_m == pytest.approx(SHIFT[0], abs=0.08)
    assert s.mean_dy_m == pytest.approx(SHIFT[1], abs=0.08)
    found = [p for p in res.points if p.found]
    dx = np.array([p.dx_m for p in found]) - SHIFT[0]
    dy = np.array([p.dy_m for p in found]) - SHIFT[1]
    assert np.sqrt(np.mean(dx**2 + dy**2)) < 0.25
    assert s.rms_plan_m == pytest.approx(np.sqrt(np.mean([p.plan_m ** 2 for p in found])))
    assert s.rms_x_m ** 2 + s.rms_y_m ** 2 == pytest.approx(s.rms_plan_m ** 2)
    # flat and gable eaves: the corner's height is the eave's
    assert res.has_z and abs(s.mean_dz_m) < 0.15
    assert s.tolerance_rms_plan_m == 0.5 and s.within_tolerance is True
    assert (d / "plan.png").stat().st_size > 20000
    # the minimum edge is lidarctl corners' default, resolved from the measured spacing, in metres
    assert res.min_edge_m >= 2.0 and res.min_edge_m < 20.0
    assert "RMS x" in r.output and "within tolerance" in r.output
    # the printed summary names the resolved minimum edge (metres, also for this cloud in feet)
    assert f"edges >= {res.min_edge_m:.2f} m" in r.output


def test_min_edge_m_option_and_its_old_spelling_refused(scene):
    """--min-edge-m (as lidarctl corners spells it) sets the edge in metres on a cloud in feet; the old --min-edge
    is gone (issue 40: no compatibility layer before 1.0); it, or 0, stops with exit 2 and nothing written."""
    d, _ = scene
    out = d / "plan_m.json"
    r = CliRunner().invoke(main, ["check-plan", str(d / "classified.las"), str(d / "points.csv"), "--min-edge-m", "3",
                                  "--json", str(out)])
    assert r.exit_code == 0, r.output
    assert read_plan_check(out).min_edge_m == 3.0
    assert "edges >= 3.00 m" in r.output
    for extra, msg in ((["--min-edge", "3"], "No such option '--min-edge'"), (["--min-edge-m", "0"], "--min-edge-m")):
        bad = d / "plan_bad.json"
        r = CliRunner().invoke(main, ["check-plan", str(d / "classified.las"), str(d / "points.csv"), *extra,
                                      "--json", str(bad)])
        assert r.exit_code == 2, r.output
        assert msg in r.output
        assert not bad.exists()


def _bad(scene, csv_text, *extra):
    d, _ = scene
    p = d / "bad.csv"
    p.write_text(csv_text)
    out = d / "bad_out.json"
    r = CliRunner().invoke(main, ["check-plan", str(d / "classified.las"), str(p), "--json", str(out),
                                  "--png", str(d / "bad_out.png"), *extra])
    assert r.exit_code == 2, r.output
    assert not out.exists() and not (d / "bad_out.png").exists()
    assert r.exception is None or isinstance(r.exception, SystemExit)
    return r.output


def test_bad_input_stops_with_exit_2_and_writes_nothing(scene):
    assert "no 'y' column" in _bad(scene, f"id,x,z\nA,{E0 + 10},5\n")
    out = _bad(scene, "id,x,y\nA,10.0,20.0\nB,11.0,21.0\n")  # local coordinates: not in the cloud's area
    assert "none of its 2 points lies within the extent" in out
    out = _bad(scene, f"id,x,y\nA,{E0 + 100},{N0 + 100}\n", "--points-crs", "EPSG:32650")
    assert "EPSG:32650" in out or "UTM zone 50N" in out
    assert "--radius-m" in _bad(scene, f"id,x,y\nA,{E0 + 100},{N0 + 100}\n", "--radius-m", "-1")
