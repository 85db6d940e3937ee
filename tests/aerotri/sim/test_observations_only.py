"""``aerotri sim --observations-only``: a block's geometry, observations and truth-terrain DEM without images or
LiDAR; ``aerotri adjust`` on it recovers the true orientations within the sigmas it reports."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from aerotri.cli import main as aerotri_main
from aerotri.geom.eo import read_eo
from aerotri.sim import load_preset
from aerotri.sim.flight import block_layout
from aerotri.sim.scene import build_scene

FILES = ("project.toml", "camera.toml", "gnss.txt", "dem.tif", "at/tiepoints.csv", "control/points.csv",
         "control/image_points.csv", "truth/eo.txt", "truth/camera.toml", "truth/gnss_truth.toml", "truth/truth.json",
         "truth/flight_acceptance.json")


def _sim(out, *args):
    return CliRunner().invoke(aerotri_main, ["sim", "--observations-only", *args, str(out)])


@pytest.fixture(scope="module")
def demo_block(tmp_path_factory):
    """The demo preset's 3 x 6 frame flight, observations only."""
    out = tmp_path_factory.mktemp("obs") / "demo"
    res = _sim(out, "--preset", "demo")
    assert res.exit_code == 0, res.output
    return out, res.output


def test_block_files_and_tie_points(demo_block):
    out, output = demo_block
    assert f"DEM of the truth terrain: {out / 'dem.tif'}" in output
    for rel in FILES:
        assert (out / rel).is_file(), rel
    assert not (out / "images").exists() and not (out / "lidar").exists()
    truth = json.loads((out / "truth/truth.json").read_text())
    assert truth["frames"] == 18 and truth["observations_only"]
    ties = np.genfromtxt(out / "at/tiepoints.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    points, rays = np.unique(ties["point_id"], return_counts=True)
    # the preset's 130 tie points a frame on average, every one in >= 3 frames (multi-ray tracks)
    assert len(points) == 130 * 18 == truth["tie_points"] and rays.min() >= 3 and rays.mean() > 3.5
    assert len(ties) == truth["tie_observations"]
    per_frame = np.unique(ties["image_id"], return_counts=True)[1]
    assert len(per_frame) == 18 and per_frame.min() > 200  # observations in every frame


def test_dem_is_the_terrain_of_the_full_simulation(tmp_path):
    """The DEM holds the terrain of ``aerotri sim`` of the same preset and flight (same random stream, same
    nodes), sampled at its node spacing."""
    sets = ["flight.frames_per_strip=4"]
    out = tmp_path / "obs"
    res = _sim(out, "--preset", "tiny", "--set", sets[0])
    assert res.exit_code == 0, res.output
    cfg = load_preset("tiny", sets)
    layout = block_layout(cfg)
    seed = int(np.random.default_rng(np.random.SeedSequence(cfg.preset.seed).spawn(4)[0]).integers(0, 2**31 - 1))
    scene = build_scene(cfg.scene, layout.width_m, layout.height_m, np.zeros(3), seed)
    origin = json.loads((out / "truth/truth.json").read_text())["origin_m"]
    with rasterio.open(out / "dem.tif") as ds:
        z = ds.read(1)
        xs = ds.transform.c + (np.arange(0, ds.width, 37) + 0.5) * ds.transform.a
        ys = ds.transform.f + (np.arange(0, ds.height, 41) + 0.5) * ds.transform.e
    X, Y = np.meshgrid(xs - origin[0], ys - origin[1])
    assert np.allclose(z[::41, ::37], scene.terrain_height(X, Y) + origin[2], atol=1e-3)


def test_same_seed_same_observations(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        assert _sim(out, "--preset", "tiny", "--set", "flight.frames_per_strip=4").exit_code == 0
    for rel in ("at/tiepoints.csv", "control/points.csv", "control/image_points.csv", "gnss.txt", "dem.tif"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    c = tmp_path / "c"
    assert _sim(c, "--preset", "tiny", "--set", "flight.frames_per_strip=4", "--seed", "7").exit_code == 0
    assert (a / "at/tiepoints.csv").read_bytes() != (c / "at/tiepoints.csv").read_bytes()


def test_no_multi_ray_overlap_is_refused(tmp_path):
    out = tmp_path / "two"
    res = _sim(out, "--preset", "tiny", "--set", "flight.strips=1", "--set", "flight.frames_per_strip=2")
    assert res.exit_code == 2
    assert "no ground point of the block is seen in 3 frames" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_adjust_recovers_the_true_orientations(demo_block):
    """``aerotri adjust --dem`` on the block, self-calibrating the principal point and radial distortion of the
    true camera and the GNSS strip shifts and drifts: the image noise given (0.3 px) comes back as sigma0, and
    the adjusted orientations differ from the truth by about their reported sigmas."""
    out, _ = demo_block
    res = CliRunner().invoke(aerotri_main, ["adjust", str(out), "--dem", str(out / "dem.tif"), "--self-cal", "pp,radial",
                                            "--gnss-correction", "shift_drift", "--no-html", "--no-exports"])
    assert res.exit_code == 0, res.output
    report = json.loads((out / "at/report.json").read_text())
    assert 0.25 < report["key_statistics"]["sigma0_px"] < 0.35
    adjusted, true = read_eo(out / "at/eo.txt"), read_eo(out / "truth/eo.txt")
    k = true.rows(adjusted.image_id)
    assert len(k) == 18 and adjusted.sigma is not None
    d = np.hstack([adjusted.centre_m - true.centre_m[k], (adjusted.opk_deg - true.opk_deg[k] + 180.0) % 360.0 - 180.0])
    z = d / adjusted.sigma  # X, Y, Z, omega, phi, kappa in units of their reported sigmas
    assert np.all(np.sqrt((z ** 2).mean(axis=0)) < 2.0), np.sqrt((z ** 2).mean(axis=0))
    assert np.abs(z).max() < 4.5
    k1 = report["self_calibration"]["adjusted"]["k1"]
    assert abs(k1 - (-4.0e-3)) < 3 * report["self_calibration"]["std_dev"]["k1"]  # the true camera's k1


def test_project_toml_has_the_adjust_settings_the_truth_needs(tmp_path):
    """project.toml [adjust] names what the block was made with: the true camera's principal point and radial
    distortion (the nominal camera.toml has neither) and a GNSS shift and drift per strip; a preset without
    drift gets shifts alone. ``aerotri adjust OUT --dem OUT/dem.tif`` without options then gives orientations
    within about their reported sigmas (the 3 x 25 frame strips drift by ~0.15 m against a sigma of ~0.02 m:
    with shifts alone Z is 2.3 sigma off in RMS, 5.8 at most)."""
    import tomllib

    out = tmp_path / "obs"
    res = _sim(out, "--preset", "demo", "--set", "flight.frames_per_strip=25")
    assert res.exit_code == 0, res.output
    adjust = tomllib.loads((out / "project.toml").read_text())["adjust"]
    assert adjust["self_calibration"] == ["pp", "radial"] and adjust["gnss_correction"] == "shift_drift"
    res = CliRunner().invoke(aerotri_main, ["adjust", str(out), "--dem", str(out / "dem.tif"), "--no-html",
                                            "--no-exports"])
    assert res.exit_code == 0, res.output
    adjusted, true = read_eo(out / "at/eo.txt"), read_eo(out / "truth/eo.txt")
    k = true.rows(adjusted.image_id)
    assert len(k) == 75
    d = np.hstack([adjusted.centre_m - true.centre_m[k], (adjusted.opk_deg - true.opk_deg[k] + 180.0) % 360.0 - 180.0])
    z = d / adjusted.sigma
    assert np.all(np.sqrt((z ** 2).mean(axis=0)) < 1.6), np.sqrt((z ** 2).mean(axis=0))
    assert np.abs(z).max() < 4.5
    flat = tmp_path / "flat"
    res = _sim(flat, "--preset", "tiny", "--set", "flight.frames_per_strip=4", "--set", "gnss.drift_sigma_m_per_s=0.0")
    assert res.exit_code == 0, res.output
    assert tomllib.loads((flat / "project.toml").read_text())["adjust"]["gnss_correction"] == "shift"


def test_the_projects_terrain_class_is_that_of_its_terrain(demo_block, tmp_path):
    """``[qa] terrain`` of a simulated project is the class of its truth terrain (a 421 m relief block was written
    "flat", and its report then judged a mountain by the flat limits, trial-relief); the demo stays flat."""
    import tomllib

    from aerotri.qa.terrain_class import dem_terrain

    out, _ = demo_block
    assert tomllib.loads((out / "project.toml").read_text())["qa"]["terrain"] == "flat"
    steep = tmp_path / "steep"
    relief = ["scene.steep_band_m=400", "scene.steep_slope_deg=35", "scene.mountain_relief_m=30",
              "scene.steep_start_frac=0.35", "flight.height_above_ground_m=900", "flight.strips=2",
              "flight.frames_per_strip=5"]  # the trial's R1 block
    res = _sim(steep, "--preset", "demo", *[a for s in relief for a in ("--set", s)])
    assert res.exit_code == 0, res.output
    got = dem_terrain(steep / "dem.tif")
    assert got.terrain == "mountainous" and got.median_slope_deg > 6.0
    assert tomllib.loads((steep / "project.toml").read_text())["qa"]["terrain"] == "mountainous"
