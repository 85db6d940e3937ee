"""Determinability, not just convergence: on simulated blocks whose truth is known, a self-calibration the block
cannot determine is fixed with a warning and the verdict is not successful; one it can is estimated within its
sigma; a DEM shifted by a known amount fails the tie-vs-DEM check. Also the output's noise: gtsam's
CheiralityException lines counted, not printed; control points without rays not "used"; no standard
deviations for parameters not estimated; no numpy warnings from the report.

The limits (determinability.CORRELATION_LIMIT 0.9, SIGMA_LIMIT_FRACTION 1 %) were looked at on simulator seeds
1 and 2 (correlation of the focal length with the block height: 0.999 flat and GNSS-only, 0.95 with 4 control
points, 0.11 with a DEM); the focal length's (3 sigma within 1 %, and the GNSS heights and an unmodelled image
field moving it by no more) on seeds 1 to 6 of bench/eval_focal_rule.py; the blocks here are drawn with seeds 11
to 14.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import warnings

import numpy as np
import pytest
import rasterio

from aerotri.adjust.pipeline import AdjustSettings, adjust_project, run_adjustment
from aerotri.adjust.report import build_report, format_html, format_txt
from aerotri.core.errors import SolveError
from aerotri.core.records import to_record
from aerotri.geom.camera import dmc_camera, read_camera
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations
from rasterio.transform import from_origin

SIGMA_PX = 0.3
GROUPS = ("focal", "pp", "radial")


def _terrain_dem(block, path, cell_m: float = 10.0):
    """The block's true terrain as a GeoTIFF in the project CRS (the hills' wavelengths are over 1.5 km: 10 m
    cells interpolate them to about a centimetre)."""
    xmin, xmax, ymin, ymax = block.extent_local
    corners = block.frame.to_map(np.array([[xmin, ymin, 0], [xmax, ymax, 0]]))
    x0, y1 = corners[0, 0] - 200, corners[1, 1] + 200
    W, H = int((corners[1, 0] + 200 - x0) / cell_m), int((y1 - (corners[0, 1] - 200)) / cell_m)
    X, Y = np.meshgrid(x0 + (np.arange(W) + 0.5) * cell_m, y1 - (np.arange(H) + 0.5) * cell_m)
    h = np.zeros_like(X)
    for _ in range(4):  # the map height whose local point lies on the terrain
        p = block.frame.to_local(np.column_stack([X.ravel(), Y.ravel(), h.ravel()]))
        h = h + (block.terrain(p[:, 0], p[:, 1]) - p[:, 2]).reshape(h.shape)
    with rasterio.open(path, "w", driver="GTiff", width=W, height=H, count=1, dtype="float32", crs=block.crs,
                       transform=from_origin(x0, y1, cell_m, cell_m), nodata=-9999.0) as ds:
        ds.write(h.astype(np.float32), 1)
    return path


CONSUMER_GNSS = "[gnss]\nsigma_xy_m = 0.5\nsigma_z_m = 0.5\noffset_sigma_xy_m = 3.0\noffset_sigma_z_m = 5.0\n"


def _flat_block(tmp_path_factory, name: str, seed: int, focal_error: float = 0.01, consumer: bool = False):
    """A flat (2 m relief), near-nadir (0.3 degree tilts) block of 3 x 6 frames with GNSS at every frame and no
    GNSS shifts; the a-priori camera's focal length ``focal_error`` long (truth: truth/camera.toml). ``consumer``: the
    GNSS a consumer receiver's (0.3 m per frame and an offset of 2.5 / -2.0 / 3.0 m), project.toml the EXIF import's
    model of it (0.5 m per frame, an offset of 3 / 5 m a priori)."""
    block = geometric_block(3, 6, seed=seed, relief_m=2.0, tilt_sigma_deg=0.3, gnss_shift_sigma_m=0.0,
                            gnss_drift_sigma_m_per_km=0.0, **({"gnss_sigma_m": (0.3, 0.3, 0.3)} if consumer else {}))
    if consumer:
        block.gnss_local = block.gnss_local + np.array([2.5, -2.0, 3.0])
    root = write_block_project(block, tmp_path_factory.mktemp(name) / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=4, points_per_image=150, n_check=4, seed=seed + 1)
    if consumer:
        head, rest = (root / "project.toml").read_text().split("[gnss]\n", 1)
        (root / "project.toml").write_text(head + CONSUMER_GNSS + rest[rest.index("lever_arm_m"):])
    cam = block.camera_nominal
    (root / "camera.toml").write_text(dataclasses.replace(cam, focal_mm=cam.focal_mm * (1 + focal_error)).to_toml())
    return block, root


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    return _flat_block(tmp_path_factory, "flat", 11, consumer=True)


def test_focal_of_a_flat_gnss_only_block_is_fixed_with_a_warning(flat, caplog):
    """A consumer receiver's GNSS, no control, no DEM: the focal length follows the flying height (correlation
    above 0.99) and only the GNSS heights' decimetres and the frames' small tilts separate them: its sigma 0.7 %,
    3 sigma over the 1 % tolerance. It is fixed at its a-priori value with a warning, the block solved without it,
    and the verdict names it instead of "Solution Successful". The radial distortion is fixed too (its partial
    correlation with the flying height 0.96, no height control or DEM), the principal point stays estimated."""
    block, root = flat
    with caplog.at_level(logging.WARNING, logger="aerotri.adjust.pipeline"):
        ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, self_calibration=GROUPS, use_control=False))
    checks = {c.group: c for c in ba.calibration_checks}
    focal = checks["focal"]
    assert not focal.determinable and focal.action == "fixed"
    assert focal.correlations["height"] > 0.99 and not focal.ground_observed["height"]  # reported, not judged
    assert focal.reason.startswith("3 standard deviations are") and 0.005 < focal.sigma_fraction < 0.01
    assert checks["pp"].determinable
    assert checks["radial"].action == "fixed" and "block height" in checks["radial"].reason
    assert ba.opts.self_calibration == ("pp",)
    assert ba.camera_adjusted.focal_px == pytest.approx(ba.camera_apriori.focal_px, abs=0.05)  # held
    assert any("focal fixed at its a-priori value" in r.getMessage() for r in caplog.records)
    rep = to_record(build_report(ba))
    ks = rep["key_statistics"]
    assert ks["verdict"] == "weak" and ks["calibration_fixed"] == ["focal", "radial"] and ks["converged"]
    assert ks["message"].startswith("Solution weak.") and "Solution Successful" not in ks["message"]
    assert "focal fixed at its a-priori value" in ks["message"]
    # the focal/height mode of the solve that tried it, and no standard deviation for what was not estimated
    fh = {g["mode"]: g for g in rep["geometry_modes"]}["focal_height"]
    assert fh["weak"] and abs(fh["correlation_with_height"]) > 0.99
    sd = rep["self_calibration"]["std_dev"]
    assert sd["fx_px"] is None and sd["skew_px"] is None and sd["p1"] is None
    assert sd["u0_px"] > 0 and sd["k1"] is None
    txt = format_txt(rep)
    assert "FIXED at its a-priori value" in txt and "refused estimate" in txt and "over the focal length: sigma" in txt
    html = format_html(rep, ba)
    assert "Determinability" in html and "focal_height" in html
    assert "focal, radial asked for but fixed" in rep["options"]["self_calibration"]


def test_focal_of_a_flat_survey_gnss_block_is_estimated_within_its_sigma(tmp_path_factory):
    """The same flat block with a survey receiver's GNSS (5 / 8 cm) and neither control nor DEM: the focal length
    still follows the flying height (correlation 0.999, fixed by the correlation test before), but the GNSS heights'
    differences (the frames are flown 5 m apart) and the tilts determine it: sigma 0.11 %, GNSS heights off by their
    sigma or an unmodelled image field of the residuals' size move it by 0.1-0.2 %. Estimated, from 1 % off to
    within 3 sigma and 0.3 % of the truth; nothing fixed. The principal point (truth 1.75 / -1.25 px off the a-priori
    camera's) is flagged since small-fixes3 (kept estimated; not a weakness since review 12a): v0 moved 1.4 px, 7
    sigma, which a GNSS offset of 0.14 m fixed in the camera (a lever arm, a time lag) would make alike: the block
    cannot tell the camera's offset from such a GNSS error."""
    block, root = _flat_block(tmp_path_factory, "survey", 13)
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, self_calibration=GROUPS, use_control=False))
    checks = {c.group: c for c in ba.calibration_checks}
    focal = checks["focal"]
    assert focal.correlations["height"] > 0.99 and not focal.ground_observed["height"]
    assert focal.action == "estimated" and checks["radial"].action == "estimated"
    pp = checks["pp"]
    assert pp.action == "flagged" and pp.reason.startswith("v0 moved") and pp.gnss_offset_correlation[1] > 0.99
    true_pp = read_camera(root / "truth" / "camera.toml")
    assert abs(pp.estimate["v0_px"] - true_pp.cy_px) < 3 * pp.sigma["v0_px"]  # right, and kept
    assert ba.opts.self_calibration == GROUPS
    assert 3 * focal.sigma_fraction < 0.01 and focal.gnss_height_fraction < 0.005 and focal.image_field_fraction < 0.005
    true_f = read_camera(root / "truth" / "camera.toml").focal_px
    est, sigma = np.mean(list(focal.estimate.values())), focal.sigma_fraction * np.mean(list(focal.estimate.values()))
    assert abs(est - true_f) < 3 * sigma and abs(est - true_f) < 0.003 * true_f, (est, true_f, sigma)
    assert ba.camera_adjusted.focal_px == pytest.approx(est, rel=1e-9)


def test_focal_with_height_control_is_estimated_within_its_sigma(tmp_path_factory):
    """The same kind of block with 4 full control points: the ground observes the height, the focal length is
    determined (correlation with the height still 0.95, harmless) and recovered from 1 % off to within 3 sigma
    of the truth; nothing is fixed."""
    block, root = _flat_block(tmp_path_factory, "ctrl", 12)
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, self_calibration=GROUPS))
    focal = {c.group: c for c in ba.calibration_checks}["focal"]
    assert focal.determinable and focal.action == "estimated" and focal.ground_observed["height"]
    true_f = read_camera(root / "truth" / "camera.toml").focal_px
    est = np.mean(list(focal.estimate.values()))
    sigma = np.mean(list(focal.sigma.values()))
    assert abs(est - true_f) < 3 * sigma, (est, true_f, sigma)
    assert sigma < 2e-4 * true_f and abs(est - true_f) < 1e-3 * true_f  # from 100 px off to about 1 px
    rep = to_record(build_report(ba))
    assert rep["key_statistics"]["calibration_fixed"] == []
    assert "Self-calibration:" not in rep["key_statistics"]["message"]


@pytest.fixture(scope="module")
def dem_block(tmp_path_factory):
    """A GNSS-only block of a camera without distortion (nothing to self-calibrate: a lens distortion left out
    would move the block height) and the true terrain as a DEM, exact (stated sigma 0.05 m)."""
    block = geometric_block(3, 6, seed=13, camera_true=dmc_camera(), gnss_shift_sigma_m=0.0,
                            gnss_drift_sigma_m_per_km=0.0)
    root = write_block_project(block, tmp_path_factory.mktemp("demchk") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=4, points_per_image=120, n_check=4, seed=14)
    dem = _terrain_dem(block, root / "dem.tif")
    shifted = root / "dem_up.tif"
    with rasterio.open(dem) as src:
        profile, z = src.profile, src.read(1)
    with rasterio.open(shifted, "w", **profile) as dst:
        dst.write(z + np.float32(0.5), 1)
    return root, dem, shifted


def test_tie_points_against_a_dem_shifted_by_half_a_metre_fail(dem_block):
    """The tie points against the true DEM: median within a few centimetres, passed; against the DEM raised by
    0.5 m: median -0.5 m, beyond 3 sigma of the offset (the DEM's stated 0.05 m and the block height's sigma),
    the solution fails: no products, the failed report in work/adjust_failed."""
    root, dem, shifted = dem_block
    st = AdjustSettings(image_sigma_px=SIGMA_PX, use_control=False, surface_sigma_m=0.05)
    res = run_adjustment(root, dataclasses.replace(st, check_dem=dem), html=False)
    rep = json.loads(res.report_path.read_text())
    (d,) = rep["dem_checks"]
    assert d["role"] == "check" and d["n"] > 400 and not d["failed"]
    assert abs(d["median_m"]) < 0.1 and d["limit_m"] == pytest.approx(3 * d["sigma_offset_m"], abs=1e-3)
    assert d["sigma_offset_m"] >= 0.05  # the DEM's stated sigma is part of it
    assert d["height_limit_m"] > abs(d["median_m"]) and not d["beyond_height_limit"]
    # within what the block can see but beyond the height limit: a weakness, said in the line (trial s100 rc F4: NGI
    # without its DEM, 7.9 m below the check DEM, "passed")
    tight = abs(d["median_m"]) / 2
    res = run_adjustment(root, dataclasses.replace(st, check_dem=dem, rms_limit_z_m=tight), html=False)
    rep = json.loads(res.report_path.read_text())
    (d,) = rep["dem_checks"]
    assert not d["failed"] and d["beyond_height_limit"] and rep["key_statistics"]["verdict"] == "weak"
    assert "Check DEM (" in rep["key_statistics"]["message"] and "beyond the height limit" in rep["key_statistics"][
        "message"]
    assert "BEYOND THE HEIGHT LIMIT" in res.report_path.with_suffix(".txt").read_text()
    assert (root / "at" / "eo.txt").is_file()
    before = (root / "at" / "eo.txt").read_text()
    with pytest.raises(SolveError, match=r"Tie points - DEM \(check"):
        run_adjustment(root, dataclasses.replace(st, check_dem=shifted), html=False)
    assert (root / "at" / "eo.txt").read_text() == before  # the earlier products stay
    failed = (root / "work" / "adjust_failed" / "report.txt").read_text()
    assert "Solution failed: Tie points - DEM" in failed and "FAILED (a systematic offset)" in failed
    rj = json.loads((root / "work" / "adjust_failed" / "report.json").read_text())
    (d,) = rj["dem_checks"]
    assert d["failed"] and d["median_m"] == pytest.approx(-0.5, abs=0.1) and abs(d["median_m"]) > d["limit_m"]
    assert rj["key_statistics"]["verdict"] == "failed" and not rj["key_statistics"]["success"]


def test_surface_control_dem_is_reported_too(dem_block):
    """With the DEM as surface control the same numbers are reported (role "surface control") and pass."""
    root, dem, _ = dem_block
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, use_control=False, dem=dem, surface_sigma_m=0.05))
    (d,) = ba.dem_checks
    assert d.role == "surface control" and d.n > 400 and not d.failed and abs(d.median_m) < 0.05
    assert "TIE POINTS VS DEM (surface control" in format_txt(to_record(build_report(ba)))


def test_control_point_without_rays_is_not_used_and_the_report_is_quiet(dem_block, tmp_path):
    """A control point whose image measurements were all removed (by data snooping, or left out with their
    images) is held only by its given coordinates: the report lists it as "no rays", not "used yes", and leaves
    it out of the control count and RMS; plan-only control (every height residual empty) builds the report
    without a numpy warning."""
    import shutil

    root, _, _ = dem_block
    work = tmp_path / "blk"
    shutil.copytree(root, work, ignore=shutil.ignore_patterns("at", "work"))
    shutil.copytree(root / "at", work / "at", ignore=shutil.ignore_patterns("eo.txt", "object_points.csv", "report*"))
    pts = (work / "control" / "points.csv").read_text().splitlines()
    # every control point horizontal only: the height residual columns are all empty
    (work / "control" / "points.csv").write_text("\n".join(
        [pts[0]] + [ln.replace(",full,", ",horizontal,") for ln in pts[1:]]) + "\n")
    ba = adjust_project(work, AdjustSettings(image_sigma_px=SIGMA_PX))
    c = list(ba.control.id).index("gcp01")
    rays = ba.block.obs_point == ba.block.control_point[c]
    assert ba.result.obs_active[rays].sum() >= 2
    ba.result.obs_active[rays] = False  # as data snooping leaves a point whose every ray it removed
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        rep = to_record(build_report(ba))
        txt = format_txt(rep)
        html = format_html(rep, ba)
    assert "no rays" in html
    rows = {r["id"]: r for r in rep["control_points"]}
    assert rows["gcp01"]["rays"] == 0 and rows["gcp01"]["status"] == "no rays" and not rows["gcp01"]["used"]
    assert all(r["used"] and r["rays"] >= 2 for k, r in rows.items() if k != "gcp01")
    assert rep["counts"]["control_points"] == len(rows) - 1
    assert "not used (no active image ray" in txt and "gcp01" in txt
    assert rep["parameters"]["max_ground_residual_m"][2] is None  # no height residual at all: empty, not NaN
    assert rep["parameters"]["rms_control_m"][2] is None


def test_gtsam_cheirality_lines_are_counted_not_printed(capfd):
    """gtsam's GeneralSFMFactor2 prints 'CheiralityException: Landmark p0 behind Camera x0' to C++ std::cout for
    a point behind the camera; inside gtsam_quiet nothing reaches file descriptor 1 and the line is counted;
    other output passes through."""
    import gtsam

    from aerotri.adjust.cpp_output import counting, gtsam_quiet

    K = gtsam.Cal3DS2(1000.0, 1000.0, 0.0, 500.0, 500.0, 0.0, 0.0, 0.0, 0.0)
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.GeneralSFMFactor2Cal3DS2(np.array([500.0, 500.0]), gtsam.noiseModel.Isotropic.Sigma(2, 1.0),
                                         gtsam.symbol("x", 0), gtsam.symbol("p", 0), gtsam.symbol("k", 0)))
    v.insert(gtsam.symbol("x", 0), gtsam.Pose3())
    v.insert(gtsam.symbol("p", 0), np.array([0.0, 0.0, -5.0]))  # behind the camera
    v.insert(gtsam.symbol("k", 0), K)
    capfd.readouterr()
    with counting() as seen:
        with gtsam_quiet():
            g.error(v)
            g.linearize(v)
            print("kept")
    out = capfd.readouterr().out
    assert "Cheirality" not in out and "kept" in out
    assert seen.lines == 2 and seen.pairs == {("p0", "x0")}


def _constructed(sd_px: float, noise_var: float, gnss_px: float, field_px: float):
    """A covariance whose flying height is (fx + fy) / sd_px + (k1 + k2) / 1e-4 plus noise of ``noise_var``
    (each term's variance 1: the focal length's partial correlation with it sqrt(2 / (2 + noise_var)), the focal length
    and the radial distortion together sqrt(4 / (4 + noise_var))); fx and fy ``sd_px`` each; the GNSS heights and
    an unmodelled image field move the focal length by ``gnss_px`` and ``field_px``."""
    from aerotri.adjust.geometry_modes import CAL_NAMES, MODES, PLAN_MODES, CalibrationCovariance

    sd = {"fx_px": sd_px, "fy_px": sd_px, "skew_px": 1.0, "u0_px": 1.0, "v0_px": 1.0, "k1": 1e-4, "k2": 1e-4,
          "p1": 1e-4, "p2": 1e-4}
    cal_cov = np.diag([sd[n] ** 2 for n in CAL_NAMES])
    cross = np.zeros((len(MODES) + len(PLAN_MODES), len(CAL_NAMES)))
    for n in ("fx_px", "fy_px", "k1", "k2"):
        cross[0, CAL_NAMES.index(n)] = sd[n]  # weight 1 / sd times the variance sd^2
    mode_var = np.ones(len(MODES) + len(PLAN_MODES))
    mode_var[0] = 4.0 + noise_var
    return CalibrationCovariance(cal_cov, cross, mode_var, {"image": 1.0}, 40.0, focal_gnss_height_px=gnss_px,
                                 focal_image_field_px=field_px)


def test_the_focal_length_is_judged_by_what_determines_it():
    """Constructed covariances (focal length 2000 px, no height control or DEM). Brighton Beach's 18 frames without a
    DEM: the focal length's sigma 0.88 % of it (corner 0.78 %, under the 1 % the test before asked), its partial
    correlation with the flying height 0.816 and with the radial distortion 0.894 (under that test's 0.9): fixed now,
    3 sigma are 2.65 %. A focal length of 0.1 % sigma that follows the flying height (partial correlation 0.988, fixed
    by the test before) is estimated when GNSS heights off by their sigma and an unmodelled image field move it by
    0.2 % and 0.1 %; fixed when either moves it by 2 %. The radial distortion keeps its correlation test."""
    from aerotri.adjust.determinability import GroundObservations, check_groups

    cal = np.array([2000.0, 2000.0, 0.0, 1000.0, 750.0, 0.0, 0.0, 0.0, 0.0])
    blind = GroundObservations(height=False, plan=False)

    def judge(cc):
        return {c.group: c for c in check_groups(cc, ("focal", "radial"), cal, cal, width=2000, height=1500,
                                                 ground=blind)}

    loose = judge(_constructed(25.0, 1.0, 4.0, 2.0))
    assert loose["focal"].correlations["height"] == pytest.approx(np.sqrt(2 / 3), abs=1e-6)
    assert loose["focal"].corner_sigma_fraction < 0.01
    assert loose["focal"].sigma_fraction == pytest.approx(0.00884, abs=1e-5)
    assert loose["focal"].action == "fixed" and loose["radial"].action == "estimated"
    assert loose["focal"].reason == "3 standard deviations are 2.65 % of the focal length (limit 1 %)"
    tight = judge(_constructed(2.0, 0.05, 4.0, 2.0))
    assert tight["focal"].correlations["height"] > 0.98 and tight["focal"].action == "estimated"
    assert tight["focal"].gnss_height_fraction == pytest.approx(0.002) and tight["focal"].reason is None
    assert tight["radial"].action == "fixed"
    assert tight["radial"].reason.startswith("correlation 0.988 with the block height")
    assert tight["radial"].sigma_fraction is None
    heights = judge(_constructed(2.0, 0.05, 40.0, 2.0))["focal"]
    assert heights.action == "fixed" and heights.reason == (
        "GNSS heights off by their sigma move the focal length by up to 2.00 % (limit 1 %)")
    field = judge(_constructed(2.0, 0.05, 4.0, 40.0))["focal"]
    assert field.action == "fixed" and "image-wide error" in field.reason and "2.00 % (limit 1 %)" in field.reason


LAG_SPEED_MPS, LAG_S = 70.0, 0.01  # 0.7 m along track


def _lag_block(tmp_path, seed: int, lag_s: float, n_control: int = 0, relief_m: float = 2.0,
               n_check: int | None = None, ppy_mm: float = 0.0):
    """A flat (2 m relief, or ``relief_m``), near-nadir 3 x 6 DMC block flown east-west in alternating directions, GNSS
    at every frame without shifts, the a-priori camera the true one (no principal-point error); the GNSS epoch
    ``lag_s`` after the exposure (the positions ahead along the track by 70 m/s x lag: an offset fixed in the camera, as a lever-arm
    error along it); ``n_control`` full control points (as the demo's LiDAR roof corners), ``n_check`` check points
    (10 with control, none without, unless given); ``ppy_mm``: the camera file's principal point that far off the
    true one (y up)."""
    block = geometric_block(3, 6, seed=seed, camera_true=dmc_camera(), relief_m=relief_m, tilt_sigma_deg=0.3,
                            gnss_shift_sigma_m=0.0, gnss_drift_sigma_m_per_km=0.0, lever_arm_m=(0.0, 0.0, 0.0))
    block.camera_nominal = dataclasses.replace(dmc_camera(), ppy_mm=ppy_mm)
    east = np.asarray(block.strip) % 2 == 0
    block.gnss_local = block.gnss_local + np.outer(np.where(east, 1.0, -1.0) * LAG_SPEED_MPS * lag_s, [1.0, 0.0, 0.0])
    root = write_block_project(block, tmp_path / f"lag{seed}_{n_control}_{relief_m:g}_{lag_s:g}_{ppy_mm:g}")
    n_check = (10 if n_control else 0) if n_check is None else n_check
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=n_control, n_check=n_check,
                             points_per_image=100, seed=seed)
    return adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, self_calibration=("pp",),
                                               use_control=n_control > 0 or n_check > 0))


def test_a_principal_point_a_gnss_lag_moved_is_flagged_without_plan_control(tmp_path):
    """small-fixes3: a GNSS/camera time lag (or a lever-arm error along the camera) moves the ground of each flight
    direction as a principal-point offset does (both fixed in the camera, turning with the heading): on a flat
    GNSS-only block the principal point took the 0.7 m lag as 6.8 px (31 sigma) with nothing in the report. It is
    flagged now (kept estimated: an estimate not to reuse as the camera's calibration) with its move, the offset that
    would make it and its correlation with such an offset (0.9998). Not a weakness (review 12a): the ground is the
    same whichever took it; with 4 full control points flagged alike, the check points as without the lag. Blocks
    without a lag raise none."""
    ba = _lag_block(tmp_path, 1, LAG_S)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    assert pp.action == "flagged" and not pp.determinable and ba.opts.self_calibration == ("pp",)
    move = pp.estimate["v0_px"] - pp.apriori["v0_px"]
    assert abs(move) > 20 * pp.sigma["v0_px"]
    # the offset the report names is the injected one (70 m/s x 0.01 s), within 5 %
    assert abs(move / pp.gnss_offset_px_per_m[1]) == pytest.approx(LAG_SPEED_MPS * LAG_S, rel=0.05)
    assert pp.gnss_offset_correlation[1] > 0.99 and pp.gnss_shift_correlation is None
    assert "v0 moved" in pp.reason and "along the camera's y axis" in pp.reason and "correlation 0.999" in pp.reason
    rep = to_record(build_report(ba))
    ks = rep["key_statistics"]
    assert ks["calibration_flagged"] == ["pp"] and ks["calibration_fixed"] == []
    assert "Self-calibration" not in ks["message"]
    txt = format_txt(rep)
    assert "HOLDS ANY GNSS OFFSET FIXED IN THE CAMERA" in txt and "with a GNSS offset fixed in the camera" in txt
    assert "not told from the GNSS: v0 moved" in txt
    # the GNSS direction check's note says how much of such an offset the principal point takes here (a DMC frame's
    # narrow field: all of it; Brighton's drone frames 0.1 %)
    import re

    share = re.search(r"here it takes (\d+) % of such an offset", rep["gnss_directions"]["note"])
    assert share and 95 <= int(share.group(1)) <= 105, rep["gnss_directions"]["note"]
    # the same lag with 4 full control points: the principal point takes it alike (the two are one on flat ground),
    # flagged alike; the ground is the same: the check points as without the lag
    with_lag, without = _lag_block(tmp_path, 1, LAG_S, n_control=4), _lag_block(tmp_path, 1, 0.0, n_control=4)
    assert {c.group: c for c in with_lag.calibration_checks}["pp"].action == "flagged"
    rms = [np.sqrt(np.mean([np.subtract(c["adjusted_m"], c["measured_m"]) ** 2 for c in b.check.values()], axis=0))
           for b in (with_lag, without)]
    assert np.allclose(rms[0], rms[1], atol=0.005), rms
    assert to_record(build_report(with_lag))["key_statistics"]["calibration_flagged"] == ["pp"]
    assert {c.group: c for c in without.calibration_checks}["pp"].action == "estimated"


@pytest.mark.parametrize("seed", [3, 4])
def test_a_block_without_a_gnss_lag_flags_no_principal_point(tmp_path, seed):
    ba = _lag_block(tmp_path, seed, 0.0)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    assert pp.action == "estimated" and pp.gnss_offset_correlation[1] > 0.99  # correlated, but it did not move
    assert all(abs(pp.estimate[k] - pp.apriori[k]) < 3 * pp.sigma[k] for k in pp.estimate)
    # s18-fixes: no offset named, so the plan effect's pass over the rays was not made
    assert np.isnan(ba.result.calibration.pp_gnss.tie_plan_ms).all()


def test_a_flagged_principal_point_is_a_weakness_where_relief_parts_it_from_the_gnss_offset(tmp_path):
    """pp-relief: a principal-point offset is a rotation of the bundle, a GNSS offset fixed in the camera a
    translation: they agree at the tie points' mean height only. Reviewer 13: under 60 m of relief at 1,000 m a 0.7 m
    lag the principal point took worsened the check points. pp-predictor: the flag names the offset's predicted plan
    effect, the tie points' RMS plan change under it from the normal equations (pp-relief's offset x half the relief
    / depth was 0.044 m here against 0.080 m measured; bench/eval_pp_relief.py: measured / predicted 0.82-1.38 over
    12 seeds, was 1.09-4.32), and turns the solution weak where it exceeds a third of the plan limit
    (PP_RELIEF_PLAN_FRACTION, set before scoring): not at 1:5000 (0.35 m / 3), yes with a 0.09 m limit (0.03 m); on
    flat ground (2 m) never (0.004 m)."""
    from aerotri.adjust.determinability import PP_RELIEF_PLAN_FRACTION

    ba, ba0 = _lag_block(tmp_path, 0, LAG_S, relief_m=60.0, n_check=30), _lag_block(tmp_path, 0, 0.0, relief_m=60.0,
                                                                                     n_check=30)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    assert pp.action == "flagged" and "moves the tie points by" in pp.reason
    # measured: the check points' adjusted plan positions with the lag against without it, within 20 % of predicted
    d = np.array([np.subtract(ba.check[i]["adjusted_m"], ba0.check[i]["adjusted_m"])[:2] for i in sorted(ba.check)])
    measured = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    assert 0.8 < measured / pp.gnss_offset_plan_effect_m < 1.2, (measured, pp.gnss_offset_plan_effect_m)
    ks = to_record(build_report(ba))["key_statistics"]  # 1:5000 flat: plan limit 0.35 m
    assert pp.gnss_offset_plan_effect_m < PP_RELIEF_PLAN_FRACTION * 0.35 and ks["calibration_relief_weak"] == []
    assert "holds a GNSS offset" not in ks["message"]
    tight = dataclasses.replace(ba, settings=dataclasses.replace(ba.settings, rms_limit_xy_m=0.09))
    ks = to_record(build_report(tight))["key_statistics"]
    assert ks["verdict"] == "weak" and ks["calibration_relief_weak"] == ["pp"]
    assert (f"pp holds a GNSS offset fixed in the camera that the solve does not model (or the camera's own offset), "
            f"and the offset named moves the ground by about {pp.gnss_offset_plan_effect_m:.3f} m RMS in plan (the tie "
            "points' change under it, from the normal equations), over 0.33 of the plan limit 0.090 m") in ks["message"]
    # flat ground: the same lag, flagged, its predicted effect a few millimetres: no weakness even at the tight limit
    flat = _lag_block(tmp_path, 0, LAG_S)
    fp = {c.group: c for c in flat.calibration_checks}["pp"]
    assert fp.action == "flagged" and fp.gnss_offset_plan_effect_m < 0.01
    assert "the block cannot tell the two apart" in fp.reason
    ks = to_record(build_report(dataclasses.replace(flat, settings=dataclasses.replace(
        flat.settings, rms_limit_xy_m=0.09))))["key_statistics"]
    assert ks["calibration_relief_weak"] == [] and ks["calibration_flagged"] == ["pp"]


def test_the_block_own_offset_estimate_flags_a_principal_point_under_the_correlation_limit(tmp_path):
    """pp-predictor: under 120 m of relief the principal point's correlation with a camera-fixed GNSS offset drops
    under 0.9 (seed 0: 0.887), which left it unflagged though a 0.7 m lag moved the check points by 0.15 m RMS. The
    block's own estimate of such an offset (one Gauss-Newton step with it added: -0.69 +- 0.05 m) does not reject the
    offset the move names (-0.72 m): flagged, and weak at 1:5000 (0.136 m predicted over 0.117 m). The same block
    without a lag but with the camera file's principal point 5 px off: the move names 0.50 m, the block finds
    0.01 +- 0.04 m: the camera's own offset, not flagged."""
    ba = _lag_block(tmp_path, 0, LAG_S, relief_m=120.0, n_check=30)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    assert pp.gnss_offset_correlation[1] < 0.9 and pp.action == "flagged"
    est, sd = pp.gnss_offset_estimate_m[1], pp.gnss_offset_estimate_sigma_m[1]
    assert est == pytest.approx(-LAG_SPEED_MPS * LAG_S, abs=3 * sd) and sd < 0.1
    assert "the block finds such an offset" in pp.reason
    ks = to_record(build_report(ba))["key_statistics"]
    assert ks["calibration_relief_weak"] == ["pp"] and pp.gnss_offset_plan_effect_m > 0.35 / 3
    off = _lag_block(tmp_path, 0, 0.0, relief_m=120.0, n_check=30, ppy_mm=0.06)
    op = {c.group: c for c in off.calibration_checks}["pp"]
    move = op.estimate["v0_px"] - op.apriori["v0_px"]
    assert abs(move) > 20 * op.sigma["v0_px"] and op.action == "estimated" and op.gnss_offset_plan_effect_m is None
    assert abs(op.gnss_offset_estimate_m[1]) < 3 * op.gnss_offset_estimate_sigma_m[1]


def test_a_camera_file_off_does_not_hide_a_gnss_lag_the_block_finds(tmp_path):
    """Review 18: the move the flag judged is the lag's share less the camera file's own error: with the camera file's
    principal point 5 px off (0.06 mm along y) and a 0.7 m lag under 120 m of relief the move named no offset the
    block's estimate agreed with, so nothing was flagged and the check points moved 0.15 m RMS under a "Solution
    Successful" or a weak verdict for other reasons. s18-fixes: the block's own estimate 15 sigma off zero
    (-0.70 +- 0.05 m) flags it whatever the move, and the offset it finds names the plan effect (0.131 m predicted,
    0.146 m measured against the block without lag and camera error): weak at 1:5000 (over 0.117 m)."""
    ba = _lag_block(tmp_path, 0, LAG_S, relief_m=120.0, n_check=30, ppy_mm=0.06)
    ref = _lag_block(tmp_path, 0, 0.0, relief_m=120.0, n_check=30)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    est, sd = pp.gnss_offset_estimate_m[1], pp.gnss_offset_estimate_sigma_m[1]
    assert abs(est) > 10 * sd and est == pytest.approx(-LAG_SPEED_MPS * LAG_S, abs=3 * sd)
    assert pp.action == "flagged" and "the block finds such an offset along the camera's y axis" in pp.reason
    d = np.array([np.subtract(ba.check[i]["adjusted_m"], ref.check[i]["adjusted_m"])[:2] for i in sorted(ba.check)])
    measured = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    assert 0.8 < measured / pp.gnss_offset_plan_effect_m < 1.25, (measured, pp.gnss_offset_plan_effect_m)
    ks = to_record(build_report(ba))["key_statistics"]
    assert ks["verdict"] == "weak" and ks["calibration_relief_weak"] == ["pp"]
    assert "pp holds a GNSS offset fixed in the camera" in ks["message"]


def test_the_principal_point_against_the_gnss_states_what_it_names():
    """Constructed ``PrincipalPointGnss`` (10 px per m, v0 sigma 0.2 px; review 18's finding 3): a singular offset
    information (no estimate) says so, not "+0.00 +- inf m, fits both it and none"; both axes flagged state the two
    offsets' plan effect together, as an item of its own; a flag by the correlation with the GNSS shifts only names no
    offset and says why; an estimate 10 sigma off zero flags whatever the move names (here none)."""
    from aerotri.adjust.determinability import _pp_gnss_reasons
    from aerotri.adjust.geometry_modes import PrincipalPointGnss

    cal = np.array([1e4, 1e4, 0.0, 512.0, 382.0, 0, 0, 0, 0])
    apriori = np.array([1e4, 1e4, 0, 500.0, 390.0, 0, 0, 0, 0])
    cov = np.diag([1.0, 1.0, 1.0, 0.04, 0.04, 1e-8, 1e-8, 1e-8, 1e-8])
    base = dict(px_per_m=np.diag([10.0, 10.0]), offset_correlation=np.array([0.99, 0.99]),
                shift_correlation=np.full(2, np.nan), orientation_correlation=np.array([0.5, 0.5]),
                tie_plan_ms=np.diag([0.01, 0.04]))
    out, effect = _pp_gnss_reasons(PrincipalPointGnss(**base, offset_estimate_m=np.full(2, np.nan),
                                                      offset_sigma_m=np.full(2, np.inf)), cal, apriori, cov)
    assert len(out) == 3 and all("gives no estimate of such an offset" in t for t in out[:2])
    assert "+- inf" not in " ".join(out) and "fits both" not in " ".join(out)
    # u0 +12 px names +1.2 m, v0 -8 px -0.8 m: sqrt(0.01 x 1.44 + 0.04 x 0.64) = 0.200 m, stated once, as its own item
    assert effect == pytest.approx(0.2, abs=1e-3)
    assert out[2].startswith("the two offsets together (x +1.20 m, y -0.80 m)")
    assert "moves the tie points" not in out[0] + out[1]
    shifts = dict(base, shift_correlation=np.array([0.95, 0.2]))
    out, effect = _pp_gnss_reasons(PrincipalPointGnss(**shifts, offset_estimate_m=np.zeros(2),
                                                      offset_sigma_m=np.full(2, 0.01)), cal, cal, cov)
    assert len(out) == 1 and "no plan effect stated for it" in out[0] and np.isnan(effect)
    out, effect = _pp_gnss_reasons(PrincipalPointGnss(**base, offset_estimate_m=np.array([0.0, -0.5]),
                                                      offset_sigma_m=np.full(2, 0.05)), cal, cal, cov)
    # the principal point did not move: the GNSS's finding, not the principal point's (review 22)
    assert len(out) == 1 and out[0].startswith("v0 did not move (+0.00 px, under its standard deviation 0.20 px), "
                                               "but the block finds a GNSS position offset along the camera's y axis")
    assert "a finding of the GNSS" in out[0] and "v0 moved" not in out[0]
    assert effect == pytest.approx(0.1) and "the offset named, -0.50 m, moves the tie points by 0.100 m" in out[0]
    # Tuniu with --self-cal pp: v0 flagged by the GNSS's finding while u0 moved, and the user read a flag of v0 alone
    # as the wrong axis; u0's move is stated, and that the block finds no x offset to explain it
    moved_u0 = cal.copy()
    moved_u0[3] = 510.0  # +2 px from the a-priori 512 is -2 px here: 510 - 512
    out, effect = _pp_gnss_reasons(PrincipalPointGnss(**base, offset_estimate_m=np.array([0.0, -0.5]),
                                                      offset_sigma_m=np.array([0.02, 0.05])), moved_u0, cal, cov)
    assert len(out) == 2 and out[0].startswith("v0 did not move") and effect == pytest.approx(0.1)
    assert out[1] == ("u0 moved -2.0 px (10.0 standard deviations), which a GNSS offset of -0.20 m along the camera's "
                      "x axis would explain; the block's own estimate of one is +0.00 +- 0.02 m: no offset there, the "
                      "move is the camera's own")


def test_per_strip_offsets_that_disagree_name_gnss_strip_shifts_not_the_camera():
    """Constructed ``PrincipalPointGnss`` (at-verdicts, issue 2): v0 moved 8 px (40 sigma), the one offset's estimate
    -0.30 +- 0.05 m (6 sigma with the GNSS's stated sigmas). Per-strip estimates that agree (chi-square 3 for 4): the
    offset is named as before. That disagree (60 for 4, beyond the 1 % limit 13.3): the offset is judged with their
    scatter (y sigma 0.20 m: 1.5 sigma), no offset is named, the reason names the GNSS strip shifts and the fix."""
    from aerotri.adjust.determinability import _pp_gnss_reasons, _strip_shift_fields, strip_shift_test
    from aerotri.adjust.geometry_modes import PrincipalPointGnss

    cal = np.array([1e4, 1e4, 0.0, 500.0, 382.0, 0, 0, 0, 0])
    apriori = np.array([1e4, 1e4, 0, 500.0, 390.0, 0, 0, 0, 0])
    cov = np.diag([1.0, 1.0, 1.0, 0.04, 0.04, 1e-8, 1e-8, 1e-8, 1e-8])
    base = dict(px_per_m=np.diag([10.0, 10.0]), offset_correlation=np.array([0.99, 0.99]),
                shift_correlation=np.full(2, np.nan), orientation_correlation=np.array([0.5, 0.5]),
                tie_plan_ms=np.diag([0.01, 0.04]), offset_estimate_m=np.array([0.0, -0.3]),
                offset_sigma_m=np.full(2, 0.05), strip_offset_m=np.array([[0.1, -0.9], [-0.2, 0.5], [0.1, -0.5]]),
                strip_offset_sigma_m=np.full((3, 2), 0.09), strip_dof=4, strip_tau_m=np.array([0.1, 0.35]),
                offset_sigma_strips_m=np.array([0.05, 0.2]))
    agree = PrincipalPointGnss(**base, strip_chi2=3.0)
    assert strip_shift_test(agree) is None
    out, effect = _pp_gnss_reasons(agree, cal, apriori, cov)
    assert len(out) == 1 and out[0].startswith("v0 moved -8.0 px") and "-0.30 +- 0.05 m" in out[0]
    assert effect == pytest.approx(0.06)
    strips = PrincipalPointGnss(**base, strip_chi2=60.0)
    assert strip_shift_test(strips) == pytest.approx([0.05, 0.2])
    out, effect = _pp_gnss_reasons(strips, cal, apriori, cov)
    assert len(out) == 1 and np.isnan(effect)
    assert out[0].startswith("GNSS strip shifts: the block's estimate of a GNSS position offset fixed in the camera "
                             "differs strip by strip (strip 1 x +0.10 y -0.90, strip 2 x -0.20 y +0.50")
    assert "chi-square 60.0 for 4 degrees of freedom" in out[0] and "not the camera" in out[0]
    assert "a shift per strip of x 0.10 y 0.35 m standard deviation, from the spread of 3 strips: 0.58 to 4.4 times " \
        "that at 90 %" in out[0]
    assert "correlated" not in out[0]  # no covariance given: no differences stated
    assert "one offset for all (x +0.00 y -0.30 m) is within 5 of its sigma with that scatter (x 0.05 y 0.20 m)" \
        in out[0]
    assert "v0 -8.0 px (40 standard deviations)" in out[0] and 'gnss_correction = "shift"' in out[0]
    fields = _strip_shift_fields(strips, out)
    assert fields["chi2"] == 60.0 and fields["dof"] == 4 and fields["strip_offset_m"][1] == [-0.2, 0.5]
    assert fields["shift_sigma_m"] == [0.1, 0.35] and fields["offset_sigma_m"] == [0.05, 0.2]
    assert fields["n_strips"] == 3


def test_correlated_strip_estimates_state_their_differences():
    """Review 29 (Brighton, 2 strips: x +1.75 / +0.71 +- 0.37 / 0.34 m, one offset for all -1.75, chi-square 448 for
    2): strip estimates correlated 0.97 in x have a difference known to 0.09 m, so the chi-square is large beside their
    sigmas and their correlation-weighted combination (the one offset) lies outside them; the reason says so. The
    chi-square recomputed from the difference and its covariance equals the one against one offset (2 strips)."""
    from aerotri.adjust.determinability import _strip_shift_reason, strip_differences, tau_interval
    from aerotri.adjust.geometry_modes import PrincipalPointGnss

    sd = np.array([0.37, 0.33, 0.34, 0.31])  # strip 1 x, y, strip 2 x, y
    R = np.eye(4)
    R[0, 2] = R[2, 0] = 0.97
    R[1, 3] = R[3, 1] = 0.95
    C = R * np.outer(sd, sd)
    est = np.array([1.75, -0.23, 0.71, -0.94])
    one = np.tile(np.eye(2), (2, 1))
    Ci = np.linalg.inv(C)
    common = np.linalg.solve(one.T @ Ci @ one, one.T @ Ci @ est)
    e = est - one @ common
    chi2 = float(e @ Ci @ e)
    pg = PrincipalPointGnss(px_per_m=np.diag([10.0, 10.0]), offset_correlation=np.array([0.99, 0.99]),
                            shift_correlation=np.full(2, np.nan), orientation_correlation=np.array([0.5, 0.5]),
                            offset_estimate_m=common, offset_sigma_m=np.full(2, 0.05),
                            strip_offset_m=est.reshape(2, 2), strip_offset_sigma_m=sd.reshape(2, 2), strip_chi2=chi2,
                            strip_dof=2, strip_offset_cov_m2=C, strip_tau_m=np.array([0.73, 0.5]),
                            offset_sigma_strips_m=np.array([2.5, 2.1]))
    r, d, dsd = strip_differences(pg)
    assert r == pytest.approx(0.97) and d[0] == pytest.approx([-1.04, -0.71])
    assert dsd[0, 0] == pytest.approx(np.sqrt(0.37**2 + 0.34**2 - 2 * 0.97 * 0.37 * 0.34))
    # the chi-square is the differences' (x and y correlated between strips only): sum of (d / sigma)^2 here
    assert chi2 == pytest.approx(float(np.sum((d[0] / dsd[0]) ** 2)), rel=1e-9)
    assert not (min(est[0], est[2]) <= common[0] <= max(est[0], est[2]))  # the one offset outside the two
    assert tau_interval(2) == pytest.approx((0.51, 15.95), abs=0.01)
    cal = np.array([1e4, 1e4, 0.0, 500.0, 382.0, 0, 0, 0, 0])
    text = _strip_shift_reason(pg, np.array([2.5, 2.1]), cal, cal, np.eye(9) * 0.04)
    assert "correlated (up to 0.97" in text and "strip 2 - strip 1 x -1.04 +- 0.09 y -0.71 +- 0.10" in text
    assert "can lie outside them" in text and "from the spread of 2 strips: 0.51 to 16 times that at 90 %" in text
    assert "without, weight the GNSS by what it holds over a strip ([gnss] sigma_xy_m" in text


def test_unmodelled_gnss_strip_shifts_are_named_and_weak(tmp_path):
    """0.3 m GNSS shifts per strip the solve does not model (s18-fixes: flagged 10 / 12 as a camera-fixed offset):
    seed 0 at 120 m of relief, GNSS only, no check points. The per-strip offsets disagree (chi-square 65 for 4), the
    flag names the GNSS strip shifts and no offset fixed in the camera, and the verdict is weak with the fix."""
    block = geometric_block(3, 6, seed=0, camera_true=dmc_camera(), relief_m=120.0, tilt_sigma_deg=0.3,
                            gnss_shift_sigma_m=0.3, gnss_drift_sigma_m_per_km=0.0, lever_arm_m=(0.0, 0.0, 0.0))
    block.camera_nominal = dmc_camera()
    root = write_block_project(block, tmp_path / "shifts")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=0, n_check=0, points_per_image=100, seed=0)
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, self_calibration=("pp",), use_control=False))
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    assert pp.action == "flagged" and pp.gnss_strip_shifts is not None and pp.gnss_offset_plan_effect_m is None
    assert pp.reason.startswith("GNSS strip shifts") and pp.gnss_strip_shifts["chi2"] > 13.3
    ks = to_record(build_report(ba))["key_statistics"]
    assert ks["verdict"] == "weak"
    assert "GNSS strip shifts: the GNSS positions' offsets differ strip by strip" in ks["message"]
    assert "re-process the trajectory" in ks["message"] and "from 3 strips' spread, 0.58 to 4.4 times" in ks["message"]
    # no control: the GNSS weights, not per-strip shifts it has no datum for (review 29)
    assert "weight the GNSS by what it holds over a strip ([gnss] sigma_xy_m" in ks["message"]
    assert "Estimate per-strip GNSS shifts" not in ks["message"]
