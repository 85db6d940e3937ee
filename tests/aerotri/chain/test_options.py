"""Stage options from project.toml, and the inputs of single stages the chain relies on: LiDAR strips
in another CRS, the accuracy report of an empty project, the adjusted camera of an adjustment without
self-calibration, blocks without GNSS (``aerotri adjust --eo``) and cameras with k3."""

from __future__ import annotations

import dataclasses
import json
import shutil
import tomllib

import laspy
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from aerotri.adjust.pipeline import AdjustSettings, adjust_project
from aerotri.geom.camera import BrownCamera
from aerotri.chain.options import STAGE_SECTIONS, ChainSettings, read_stage_sections
from aerotri.cli import main as aerotri_cli
from aerotri.core.errors import ConfigError, CrsError, StageOrderError
from aerotri.geom.eo import ExteriorOrientations, read_eo, write_eo
from aerotri.core.project import Project
from aerotri.sim import load_preset
from aerotri.sim.observations import geometric_block, true_dmc_camera, write_block_project, write_truth_observations
from lidarctl.cli.main import main as lidarctl_cli
from lidarctl.corners.roof_corners import CornerSettings
from lidarctl.merge import merge_las
from lidarctl.rasters.products import RasterSettings

PROJECT = '[project]\nname = "t"\ncrs = "EPSG:32649"\n'


# -- options ------------------------------------------------------------------------------------
def test_defaults_are_the_stage_settings_and_values_are_read_with_their_types(tmp_path):
    assert read_stage_sections(tomllib.loads(PROJECT), "project.toml") == ChainSettings()
    assert ChainSettings().rasters == RasterSettings() and ChainSettings().corners == CornerSettings()
    cfg = tomllib.loads(PROJECT + """
[corners]
roof = "any"
min_edge_m = 4
[adjust]
self_calibration = "pp, radial"
gnss_correction = "shift"
lever_arm_m = [0.1, 0, 1.5]
[control]
sigma_xy_m = 0.1
tol_px = 0.9
[control.layout]
min_frames = 2
[match.sparse]
budget = 800
[rectify]
dem = "../dem.tif"
res_m = 0.25
""")
    o = read_stage_sections(cfg, "project.toml", base_dir=tmp_path)
    assert o.corners == CornerSettings(min_edge_m=4.0, roof="any")
    assert o.adjust.self_calibration == ("pp", "radial") and o.adjust.gnss_correction == "shift"
    assert o.adjust.lever_arm_m == (0.1, 0.0, 1.5)
    assert o.control.tol_px == 0.9 and o.control.layout.min_frames == 2 and o.control.layout.height_every_strips == 3
    assert o.match.sparse.budget == 800 and o.match.sparse.max_dim_px == 3000 and o.match.dense.budget == 10000
    assert o.rectify.dem == tmp_path / "../dem.tif" and o.rectify.res_m == 0.25
    assert o.mosaic == ChainSettings().mosaic


@pytest.mark.parametrize("extra, expected", [
    ('[cornrs]\nroof = "any"\n', "unknown section [cornrs]"),
    ('[corners]\nmin_edge = 4.0\n', "[corners]: unknown key 'min_edge'"),
    ('[corners]\nroof = "pointy"\n', "[corners] roof = 'pointy': expected one of flat, any"),
    ('[corners]\nmin_edge_m = 0.2\n', "[corners] min_edge_m = 0.2: out of range, expected >= 0.5"),
    ('[rasters]\nres_m = 0\n', "[rasters] res_m = 0.0: out of range, expected > 0"),
    ('[adjust]\nself_calibration = ["pp", "radials"]\n', "[adjust] self_calibration = 'radials'"),
    ('[adjust]\ngnss_correction = "drift"\n', "[adjust] gnss_correction = 'drift': expected one of none, shift"),
    ('[adjust]\nalpha = 1.5\n', "[adjust] alpha = 1.5: out of range"),
    ('[match.sparse]\nbudget = "many"\n', "[match.sparse] budget = 'many': expected a whole number"),
    ('[match]\nsparse = 3\n', "[match.sparse]: expected a table"),
    ('[classify]\nground_method = "csf"\n', "[classify] ground_method = 'csf': expected one of morph, ptd"),
    ('[rectify]\ninterpolation = "spline"\n', "[rectify] interpolation = 'spline'"),
    ('[mosaic]\nbalance = "yes"\n', "[mosaic] balance = 'yes': expected true or false"),
    ('[qa]\nterrian = "flat"\n', "[qa]: unknown key 'terrian'"),
    ('rectify = "dem.tif"\n', "[project]: unknown key 'rectify'"),
])
def test_bad_options_stop_the_run_before_any_stage(tmp_path, extra, expected):
    (tmp_path / "project.toml").write_text(PROJECT + extra)
    with pytest.raises(ConfigError) as e:
        read_stage_sections(tomllib.loads(PROJECT + extra), str(tmp_path / "project.toml"))
    assert str(tmp_path / "project.toml") in str(e.value) and expected in str(e.value)
    r = CliRunner().invoke(aerotri_cli, ["run", str(tmp_path)])
    assert r.exit_code == 2 and expected in r.stderr and "project.toml" in r.stderr
    assert not (tmp_path / "work").exists()


def test_the_command_line_and_project_toml_refuse_the_same_values(tmp_path):
    r = CliRunner().invoke(lidarctl_cli, ["corners", str(tmp_path / "x.las"), str(tmp_path), "--min-edge-m", "0.2"])
    assert r.exit_code == 2 and "0.2" in r.stderr and "--min-edge-m" in r.stderr
    r = CliRunner().invoke(lidarctl_cli, ["corners", str(tmp_path / "x.las"), str(tmp_path), "--roof", "pointy"])
    assert r.exit_code == 2 and "'pointy' is not one of 'flat', 'any'" in r.stderr
    assert set(STAGE_SECTIONS) == {"strips", "classify", "rasters", "corners", "vectors", "match", "adjust", "control", "rectify", "mosaic", "dom_check"}


@pytest.mark.parametrize("preset", ["tiny", "demo", "dmc"])
def test_presets_write_valid_stage_options(preset, tmp_path):
    from aerotri.core.settings import sections_toml

    from aerotri.sim.project import rendered_chain_table

    cfg = load_preset(preset)
    text = PROJECT + sections_toml(rendered_chain_table(cfg))
    o = read_stage_sections(tomllib.loads(text), "project.toml")
    assert o.adjust.self_calibration == ("pp", "radial")  # the true camera differs from camera.toml
    assert o.adjust.gnss_correction == "shift_drift"      # the presets' GNSS shifts and drifts per strip


# -- LiDAR strips and their CRS -----------------------------------------------------------------
def _strip(path, epsg, x0=452000.0, n=500, seed=0):
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([x0, 3407000.0, 0.0])
    if epsg:
        header.add_crs(pyproj.CRS.from_epsg(epsg))
    las = laspy.LasData(header)
    las.x = x0 + rng.uniform(0, 100, n)
    las.y = 3407000.0 + rng.uniform(0, 100, n)
    las.z = rng.uniform(300, 310, n)
    las.point_source_id = np.full(n, seed + 1)
    las.write(path)


def test_a_strip_in_another_crs_is_refused_and_one_without_crs_takes_the_project_crs(tmp_path):
    lidar = tmp_path / "lidar"
    lidar.mkdir()
    _strip(lidar / "a.las", 32649, seed=0)
    _strip(lidar / "b.las", None, seed=1)
    out = tmp_path / "merged.las"
    assert merge_las(sorted(lidar.glob("*.las")), out, crs="EPSG:32649") == 1000
    merged = laspy.read(out)
    assert merged.header.parse_crs().to_epsg() == 32649 and set(np.unique(merged.point_source_id)) == {1, 2}
    _strip(lidar / "c.las", 32650, seed=2)  # UTM 50N into a 49N project
    with pytest.raises(CrsError) as e:
        merge_las(sorted(lidar.glob("*.las")), tmp_path / "m2.las", crs="EPSG:32649")
    assert "c.las" in str(e.value) and "EPSG:32650" in str(e.value) and "EPSG:32649" in str(e.value)
    assert not (tmp_path / "m2.las").exists()
    # without a project CRS the strips must agree among themselves
    with pytest.raises(CrsError, match="c.las.*EPSG:32650.*a.las"):
        merge_las(sorted(lidar.glob("*.las")), tmp_path / "m3.las")
    r = CliRunner().invoke(lidarctl_cli, ["merge", *map(str, sorted(lidar.glob("*.las"))), str(tmp_path / "m4.las"),
                                          "--crs", "EPSG:32649"])
    assert r.exit_code == 2 and "c.las" in r.stderr and "EPSG:32650" in r.stderr
    # the chain: its classify stage (the strips together, no merged file) stops with the same message
    (tmp_path / "project.toml").write_text(PROJECT)
    r = CliRunner().invoke(aerotri_cli, ["run", str(tmp_path)])
    assert r.exit_code == 2 and "c.las" in r.stderr and "EPSG:32650" in r.stderr and "EPSG:32649" in r.stderr
    assert not (tmp_path / "lidar_out" / "classified").exists() and not (tmp_path / "work" / "lidar").exists()


# -- the accuracy report ------------------------------------------------------------------------
def test_report_refuses_a_folder_without_project_or_results(tmp_path):
    r = CliRunner().invoke(aerotri_cli, ["report", str(tmp_path)])
    assert r.exit_code == 2 and "project.toml" in r.stderr
    assert not (tmp_path / "reports").exists()
    (tmp_path / "project.toml").write_text(PROJECT)
    r = CliRunner().invoke(aerotri_cli, ["report", str(tmp_path)])
    assert r.exit_code == 2 and "nothing to report yet" in r.stderr and "aerotri adjust" in r.stderr
    assert "None" not in r.stderr and not (tmp_path / "reports").exists()


def test_oriented_camera_is_the_adjustments_camera_file(tmp_path):
    """The camera at/eo.txt belongs to: camera.toml before any adjustment; at/camera.toml after one, named
    self-calibrated only when it differs from the nominal camera."""
    from aerotri.geom.camera import oriented_camera

    (tmp_path / "project.toml").write_text(PROJECT)
    cam = BrownCamera(focal_mm=120.0, pixel_um=12.0, width=1000, height=800, k1=-1e-3)
    (tmp_path / "camera.toml").write_text(cam.to_toml())
    got, source = oriented_camera(Project.open(tmp_path))
    assert got == cam and source.endswith("camera.toml") and "at" not in source.split("/")
    (tmp_path / "at").mkdir()
    (tmp_path / "at" / "camera.toml").write_text("# held fixed\n" + cam.to_toml())
    got, source = oriented_camera(Project.open(tmp_path))
    assert got == cam and source.endswith("at/camera.toml") and "self-calibrated" not in source
    calibrated = dataclasses.replace(cam, focal_mm=120.3, k1=-1.2e-3)
    (tmp_path / "at" / "camera.toml").write_text(calibrated.to_toml())
    got, source = oriented_camera(Project.open(tmp_path))
    assert got == calibrated and "self-calibrated" in source
    # orientations and a report of an adjustment that wrote no camera file: refused, not the nominal camera
    (tmp_path / "at" / "camera.toml").unlink()
    (tmp_path / "at" / "eo.txt").write_text("")
    (tmp_path / "at" / "report.json").write_text("{}")
    with pytest.raises(StageOrderError, match="camera.toml beside it"):
        oriented_camera(Project.open(tmp_path))


def test_control_and_rectify_after_an_adjustment_without_self_calibration(tiny_project, tmp_path):
    """Issue 17: `aerotri adjust P` (no --self-cal), then `aerotri control P` and `ortho rectify P`."""
    from aerotri.sim.evaluate import write_truth_corners_csv
    from ortho.cli import main as ortho_cli

    p = tmp_path / "p"
    shutil.copytree(tiny_project, p, ignore=shutil.ignore_patterns("lidar"))
    run = CliRunner()
    # the tiny preset's [adjust] self-calibrates: the command line turns it off
    for args in (["match", str(p)], ["adjust", str(p), "--no-control", "--self-cal", ""]):
        r = run.invoke(aerotri_cli, args, catch_exceptions=False)
        assert r.exit_code == 0, r.output
    assert json.loads((p / "at" / "report.json").read_text())["self_calibration"] is None
    write_truth_corners_csv(p, p / "lidar_out" / "corners.csv")  # corners from another source
    r = run.invoke(aerotri_cli, ["control", str(p), "--min-frames", "2"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert len((p / "control" / "image_points.csv").read_text().splitlines()) > 10
    r = run.invoke(ortho_cli, ["rectify", str(p), "--dem", str(p / "truth" / "dem.tif")], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert len(json.loads((p / "ortho" / "frames" / "index.json").read_text())["frames"]) == 6


# -- blocks without GNSS, cameras with k3 ---------------------------------------------------------
SIGMA_PX = 0.3


def _truth_centre_errors(block, eo):
    t = block.eo_map()
    idx = [t.image_id.index(i) for i in eo.image_id]
    return eo.centre_m - t.centre_m[idx]


def test_block_without_gnss_is_adjusted_from_approximate_orientations(tmp_path):
    block = geometric_block(2, 5, seed=5)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=100, n_check=8, seed=6)
    (root / "gnss.txt").unlink()
    # without --eo: approximate orientations from the images (pycolmap on the tie points), datum from the control
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--image-sigma-px", str(SIGMA_PX)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "at" / "report.json").read_text())
    assert any("from the images (pycolmap)" in note for note in rep["datum"])
    d = _truth_centre_errors(block, read_eo(root / "at" / "eo.txt"))
    assert np.sqrt(np.mean(d ** 2)) < 0.3
    # approximate orientations given: metres off in position, half a degree in attitude
    t = block.eo_map()
    rng = np.random.default_rng(1)
    approx = ExteriorOrientations(t.image_id, t.centre_m + rng.normal(0, 5.0, t.centre_m.shape),
                                  t.opk_deg + rng.normal(0, 0.5, t.opk_deg.shape))
    write_eo(tmp_path / "initial_eo.txt", approx)
    r = CliRunner().invoke(aerotri_cli, ["adjust", str(root), "--eo", str(tmp_path / "initial_eo.txt"),
                                         "--image-sigma-px", str(SIGMA_PX)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rep = json.loads((root / "at" / "report.json").read_text())
    assert rep["counts"]["control_points"] == 5 and rep["options"]["given_eo_gps"] != "Enabled"
    assert 0.8 < rep["key_statistics"]["sigma0_px"] / SIGMA_PX < 1.2
    d = _truth_centre_errors(block, read_eo(root / "at" / "eo.txt"))
    assert np.sqrt(np.mean(d ** 2)) < 0.3  # the datum from the control points (5 cm survey noise)
    chk = np.array(rep["check_rms_m"])
    assert np.all(chk < [0.15, 0.15, 0.3])


def test_camera_with_k3_is_adjusted_with_k3_held_fixed(tmp_path):
    cam_true = dataclasses.replace(true_dmc_camera(), k3=1.0e-2)  # 16 px at the image corners
    block = geometric_block(2, 5, camera_true=cam_true, seed=7)
    root = write_block_project(block, tmp_path / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=4, points_per_image=100, n_check=8, seed=8)
    settings = AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX, point_covariances=False, snooping=False)
    (root / "camera.toml").write_text(cam_true.to_toml())  # a calibrated camera, k3 included
    ba = adjust_project(root, settings)
    assert 0.8 < ba.result.sigma0 < 1.2
    assert np.sqrt(np.mean(_truth_centre_errors(block, ba.eo_map) ** 2)) < 0.3
    assert ba.camera_adjusted.k3 == cam_true.k3
    # the same camera without its k3: the missing distortion shows in the residuals and the orientations
    (root / "camera.toml").write_text(dataclasses.replace(cam_true, k3=0.0).to_toml())
    ba0 = adjust_project(root, settings)
    assert ba0.result.sigma0 > 2.0 and np.sqrt(np.mean(_truth_centre_errors(block, ba0.eo_map) ** 2)) > 1.0
    # self-calibrating principal point and k1, k2 of the nominal camera, with the known k3 held fixed
    (root / "camera.toml").write_text(dataclasses.replace(cam_true.ideal(), k3=cam_true.k3).to_toml())
    ba2 = adjust_project(root, dataclasses.replace(settings, self_calibration=("pp", "radial"), point_covariances=True))
    r = ba2.result
    assert 0.8 < r.sigma0 < 1.2 and ba2.camera_adjusted.k3 == cam_true.k3
    sd = np.sqrt(np.diag(r.cal_cov))
    assert abs(r.state.cal[5] - cam_true.k1) < 3 * sd[5] and abs(r.state.cal[3] - cam_true.cx_px) < 3 * sd[3]


def test_demo_simulates_again_when_the_project_lacks_the_preset_options(tmp_path):
    from aerotri.chain.run import stale_simulation as _stale_simulation
    from aerotri.core.settings import sections_toml
    from aerotri.sim.project import rendered_chain_table

    cfg = load_preset("demo")
    assert _stale_simulation(tmp_path, cfg) == "no simulated project yet"
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "truth.json").write_text("{}")
    (tmp_path / "project.toml").write_text(PROJECT)  # simulated by an earlier version: no [adjust]
    assert "[adjust] self_calibration" in _stale_simulation(tmp_path, cfg)
    (tmp_path / "project.toml").write_text(PROJECT + sections_toml(cfg.chain))
    # made before the simulator stated the GNSS correction of its errors
    assert "[adjust] gnss_correction" in _stale_simulation(tmp_path, cfg)
    (tmp_path / "project.toml").write_text(PROJECT + sections_toml(rendered_chain_table(cfg)))
    assert _stale_simulation(tmp_path, cfg) is None


def test_merge_refuses_strips_with_and_without_a_crs_record_without_crs(tmp_path):
    """trial-lidar: without --crs, a strip without a CRS record beside a tagged one was merged silently: the merged
    file took the first strip's CRS for both, or had none at all when the untagged strip came first (exit 0)."""
    _strip(tmp_path / "a.las", 32649, seed=0)
    _strip(tmp_path / "b.las", None, seed=1)
    for order in (["a.las", "b.las"], ["b.las", "a.las"]):
        r = CliRunner().invoke(lidarctl_cli, ["merge", *(str(tmp_path / n) for n in order), str(tmp_path / "m.las")])
        assert r.exit_code == 2, r.output
        assert f"{tmp_path / 'b.las'}: the strip has no CRS record" in r.stderr and "EPSG:32649" in r.stderr
        assert "--crs" in r.stderr and not (tmp_path / "m.las").exists()
    r = CliRunner().invoke(lidarctl_cli, ["merge", str(tmp_path / "b.las"), str(tmp_path / "a.las"),
                                          str(tmp_path / "m.las"), "--crs", "EPSG:32649"])
    assert r.exit_code == 0 and laspy.read(tmp_path / "m.las").header.parse_crs().to_epsg() == 32649


def test_merge_refuses_a_strip_beyond_the_first_strips_integer_grid(tmp_path):
    """trial-lidar: a strip whose coordinates do not fit 32-bit integers in the first strip's scales and offsets (the
    merged file's) stopped `lidarctl merge` with laspy's OverflowError and a traceback (exit 1); now exit 2 naming the
    strip, its range and the first strip, nothing written."""
    _strip(tmp_path / "a.las", 32649, seed=0)
    _strip(tmp_path / "b.las", 32649, x0=452000.0 + 2_500_000.0, seed=1)  # 2,500 km: beyond 2^31 mm steps
    r = CliRunner().invoke(lidarctl_cli, ["merge", str(tmp_path / "a.las"), str(tmp_path / "b.las"),
                                          str(tmp_path / "m.las")])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"{tmp_path / 'b.las'}: its coordinates do not fit" in r.stderr and str(tmp_path / "a.las") in r.stderr
    assert "x 2952" in r.stderr and not (tmp_path / "m.las").exists()
