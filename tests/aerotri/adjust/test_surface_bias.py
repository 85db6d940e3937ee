"""The LiDAR's strip errors in the orientations' sigmas (surface_bias): on a simulated block whose DEM carries
LiDAR strip offsets, the reported sigmas contain the truth; taken as independent points, they did not."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import rasterio

from aerotri.adjust import graph as G
from aerotri.adjust.pipeline import adjust_project, project_settings
from aerotri.adjust.report import build_report, format_txt, optimistic_sigmas
from aerotri.adjust.surface_bias import flight_direction
from aerotri.core.project import Project
from aerotri.core.records import to_record
from aerotri.geom.eo import read_eo
from aerotri.sim.command import simulate_command


def _lidar_strip_offsets(dem_path, seed, spacing_m=360.0, swath_m=655.0, sigma_m=0.03):
    """The DEM as LiDAR strips flown east-west make it: each strip offset by its own 3D error (``sigma_m``), a
    cell the mean of the strips over it (to first order in the slope), in place."""
    rng = np.random.default_rng(seed)
    with rasterio.open(dem_path) as ds:
        h = ds.read(1).astype(float)
        nodata, t, profile = ds.nodata, ds.transform, ds.profile
    bad = h == nodata
    hy, hx = np.gradient(np.where(bad, np.median(h[~bad]), h), -t.a, t.a)
    ys = t.f + t.e * (np.arange(h.shape[0]) + 0.5)
    lines = ys.min() - rng.uniform(0, spacing_m) + spacing_m * np.arange(int(np.ptp(ys) / spacing_m) + 3)
    total, count = np.zeros_like(h), np.zeros(len(ys))
    for yl, (dx, dy, dz) in zip(lines, rng.normal(0.0, sigma_m, (len(lines), 3))):
        rows = np.abs(ys - yl) <= swath_m / 2
        total[rows] += dz - hx[rows] * dx - hy[rows] * dy
        count[rows] += 1
    with rasterio.open(dem_path, "w", **profile) as ds:
        ds.write(np.where(bad, nodata, h + total / np.maximum(count, 1)[:, None]).astype(profile["dtype"]), 1)


@pytest.fixture(scope="module")
def biased_block(tmp_path_factory):
    root = tmp_path_factory.mktemp("sbias") / "blk"
    simulate_command("dmc_block", root, seed=202, observations_only=True, tie_points_per_frame=600,
                     overrides=("flight.strips=2", "flight.frames_per_strip=6"))
    _lidar_strip_offsets(root / "dem.tif", seed=203)
    settings = dataclasses.replace(project_settings(Project.open(root)).settings, dem=root / "dem.tif")
    return root, settings


def _normalised_rms(ba, truth_path):
    truth = read_eo(truth_path)
    sel = truth.rows(ba.eo_map.image_id)
    d = np.column_stack([ba.eo_map.centre_m - truth.centre_m[sel],
                         (ba.eo_map.opk_deg - truth.opk_deg[sel] + 180.0) % 360.0 - 180.0])
    return np.sqrt(np.mean((d / ba.eo_map.sigma) ** 2, axis=0))


def test_orientation_sigmas_contain_the_truth_over_a_lidar_dem_with_strip_offsets(biased_block):
    root, settings = biased_block
    # a DEM given from outside the project's LiDAR stages: its systematic error is the user's to state
    formal = adjust_project(root, settings)
    ba = adjust_project(root, dataclasses.replace(settings, surface_bias_sigma_m=0.03))
    # the consider parameter changes the covariances only: the same solution
    np.testing.assert_allclose(ba.eo_map.centre_m, formal.eo_map.centre_m, atol=1e-6)
    assert formal.result.surface_bias is None
    bias = ba.result.surface_bias
    assert bias is not None and bias.sigma_z_m == 0.03 and bias.cells >= 2
    x, y, z, om, ph, ka = _normalised_rms(formal, root / "truth" / "eo.txt")
    # 7,000 DEM points taken as independent: the height and the tilt across the strips known to a few mm and
    # 0.0006 deg, while the DEM's strip offsets move them by cm and 0.002 deg
    assert z > 2.0 and om > 3.0, (z, om)
    nz, nom, nph = _normalised_rms(ba, root / "truth" / "eo.txt")[2:5]
    assert 0.5 < nz < 1.5 and 0.5 < nom < 1.5 and 0.5 < nph < 1.5, (nz, nom, nph)
    # the object points carry it too (their own intersection's 5 cm dominate; the offsets' 3 cm add in quadrature)
    ratio = np.nanmedian(ba.points_sigma_map[:, 2]) / np.nanmedian(formal.points_sigma_map[:, 2])
    assert 1.05 < ratio < 1.4, ratio
    # and the check points (intersected with the orientations' joint covariance; their rays' own 3-5 cm dominate)
    chk = [k for k, c in ba.check.items() if np.isfinite(c["sigma_m"][2])]
    r = np.array([ba.check[k]["sigma_m"][2] / formal.check[k]["sigma_m"][2] for k in chk])
    assert len(r) and r.min() > 1.0 - 1e-9 and np.median(r) > 1.01, r
    # the report says which: considered, or formal
    for adj, considered, words in ((ba, True, "LiDAR strip offsets in the sigmas"), (formal, False, "formal")):
        rec = to_record(build_report(adj))
        assert rec["surface_control"]["systematic"]["considered"] is considered
        assert words in format_txt(rec)


def test_the_sensitivity_is_the_solutions_change_when_the_dem_shifts(biased_block):
    """S = d solution / d offset (one solve with the reduced covariance's factor) against solving again with the
    whole DEM 1 cm higher, from the converged solution: the projection centres rise by what S says."""
    root, settings = biased_block
    ba = adjust_project(root, dataclasses.replace(settings, surface_bias_sigma_m=0.03))
    r = ba.result
    block, opts, state = r.block, r.opts, r.state

    def solve(b):
        gr = G.build_graph(b, opts, state, r.obs_active, r.control_active, robust=False)
        values, _ = G.optimize(gr, opts)
        return G.state_from_values(values, b, opts, state, tie=gr.tie)

    shifted = copy.copy(block)
    shifted.surface = dataclasses.replace(block.surface, dem=dataclasses.replace(block.surface.dem,
                                                                                  z=block.surface.dem.z + 0.01))
    dz = solve(shifted).centre[:, 2] - solve(block).centre[:, 2]
    bias, rc = r.surface_bias, r.marginals
    dv = bias.scaled[:, 2::3].sum(axis=1) / bias.sigma_z_m * 0.01  # every cell 1 cm up
    pose = np.array([rc.offset[G.X(i)] for i in range(block.n_images)])[:, None] + np.arange(3, 6)
    predicted = np.einsum("nij,nj->ni", state.R_cv, dv[pose])[:, 2]  # pose tangent: centre change R v
    assert 0.004 < dz.min() and dz.max() < 0.0101, dz
    np.testing.assert_allclose(predicted, dz, rtol=0.02, atol=2e-5)


def test_optimistic_sigmas_are_a_weakness_of_the_verdict():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(300, 3))
    assert optimistic_sigmas(n) is None
    assert optimistic_sigmas(n * [1.0, 1.0, 1.4]) is None  # beyond the chi-square test, within 1.5
    msg = optimistic_sigmas(n * [1.0, 1.0, 2.5])
    assert msg.startswith("Sigmas too small: the 300 check points") and "beyond 1.5 in Z" in msg
    assert optimistic_sigmas(n[:4] * 5) is None  # too few check points to judge
    # the tie points at their weights: the check points' own measurements named first, not the orientations (trial-ew)
    for sigma0 in (1.02, 0.30):  # (0.30: the trial's tie points at 0.15 px against an a-priori 0.5)
        msg = optimistic_sigmas(n * [1.0, 1.0, 2.5], sigma0=sigma0)
        assert f"sigma0 {sigma0:.2f}" in msg and "check points' own image measurements" in msg
        assert "precision of the orientations and points claims" not in msg
    msg = optimistic_sigmas(n * [1.0, 1.0, 2.5], sigma0=1.6)  # the images do not agree with their weights either
    assert "precision of the orientations and points claims" in msg
    # other findings in the verdict (GNSS shifts, tolerances): the block itself may be off, the general text
    msg = optimistic_sigmas(n * [1.0, 1.0, 2.5], sigma0=0.8, other_findings=True)
    assert "precision of the orientations and points claims" in msg


def test_flight_direction_of_strips_east_west_and_north_south():
    x = np.arange(6) * 300.0
    east = np.column_stack([np.r_[x, x[::-1]], np.r_[np.zeros(6), np.full(6, 900.0)]])
    strip = np.repeat([0, 1], 6)
    assert abs(np.sin(flight_direction(east, strip))) < 1e-9
    assert abs(abs(flight_direction(east[:, ::-1], strip)) - np.pi / 2) < 1e-9
