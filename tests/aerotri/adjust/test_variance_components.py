"""Variance components of the observation groups and the block's geometry modes, against a simulated block
whose true precisions are known and against the covariance of the full (not reduced) normal equations."""

from __future__ import annotations

import dataclasses
import json

import gtsam
import numpy as np
import pytest
import rasterio

from aerotri.adjust import graph as G
from aerotri.adjust.geometry_modes import MODES
from aerotri.adjust.surface import whitened
from aerotri.adjust.pipeline import AdjustSettings, adjust_project, run_adjustment
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations
from tests.aerotri.adjust.test_surface import _terrain_dem

SIGMA_PX = 0.3


@pytest.fixture(scope="module")
def gnss_block(tmp_path_factory):
    # GNSS without shifts, a few control points, a DEM of the true terrain
    block = geometric_block(3, 6, seed=5, gnss_shift_sigma_m=0.0, gnss_drift_sigma_m_per_km=0.0)
    root = write_block_project(block, tmp_path_factory.mktemp("vce") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=4, points_per_image=120, n_check=8, seed=6)
    dem = _terrain_dem(block, root / "dem.tif")
    with rasterio.open(dem, "r+") as ds:  # a LiDAR DEM's noise: 0.10 m per cell
        z = ds.read(1)
        ds.write(z + np.random.default_rng(8).normal(0, 0.10, z.shape).astype(z.dtype), 1)
    return block, root, dem


def test_components_add_up_and_find_the_image_precision(gnss_block):
    _, root, _ = gnss_block
    # stated 1.0 px for rays measured with 0.3 px: the image factor tells
    r = adjust_project(root, AdjustSettings(image_sigma_px=1.0, point_covariances=True)).result
    vc = {c.group: c for c in r.variance_components}
    assert set(vc) == {"image", "gnss", "control"}
    assert sum(c.redundancy for c in vc.values()) == pytest.approx(r.info.dof)
    assert sum(c.sum_squares for c in vc.values()) == pytest.approx(r.info.chi2, rel=1e-6)
    assert vc["image"].factor == pytest.approx(SIGMA_PX / 1.0, rel=0.1)
    assert vc["control"].factor is None  # 4 points: too little redundancy to estimate a factor
    assert 0 < vc["gnss"].redundancy < vc["gnss"].n
    # with image_sigma_from_residuals the final solve already weights the images by their residuals' sigma: the
    # component is then one, and the factor the weights carry is the 0.3
    r = adjust_project(root, AdjustSettings(image_sigma_px=1.0, point_covariances=True,
                                            image_sigma_from_residuals=True)).result
    vc = {c.group: c for c in r.variance_components}
    assert vc["image"].factor == pytest.approx(1.0, abs=0.1)
    assert r.weight_factors["image"] == pytest.approx(SIGMA_PX / 1.0, rel=0.1)


def test_reweighting_finds_the_same_dem_precision_from_any_start(gnss_block):
    """Iterated variance components: the DEM stated at 0.05 m or at 0.5 m (plus the slope term) ends at the
    same sigma of its observations, and the factors of the last solve are all within 5 % of one."""
    _, root, dem = gnss_block
    est = []
    for stated in (0.05, 0.5):
        st = AdjustSettings(image_sigma_px=SIGMA_PX, dem=dem, surface_sigma_m=stated, variance_components=True)
        ba = adjust_project(root, st)
        r = ba.result
        assert all(c.factor is None or abs(c.factor - 1) < 0.05 for c in r.variance_components)
        assert r.weight_factors["image"] == pytest.approx(1.0, abs=0.1)  # the rays' 0.3 px were right
        used = r.surface_use == 1
        est.append(float(np.median(ba.block.surface.observe(r.state.points[used], jacobian=False)[2])))
    assert est[0] == pytest.approx(est[1], rel=0.1)
    assert 0.05 < est[0] < 0.15  # 0.10 m per cell, smoothed by the interpolation, plus what the slope adds


def test_geometry_modes_match_the_full_covariance(gnss_block):
    """The modes' sigmas from the reduced system equal L Q L' with Q the inverse of the full normal matrix
    (every tie point an explicit unknown), and the groups' shares add up to one."""
    _, root, dem = gnss_block
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, dem=dem, surface_sigma_m=0.05))
    r, block = ba.result, ba.block
    modes = {g.mode: g for g in r.geometry}
    assert set(modes) == set(MODES)
    for g in r.geometry:
        assert sum(g.shares.values()) == pytest.approx(1.0, abs=1e-6)
        assert abs(g.shares["priors"]) < 0.01
    # the full normal equations, every point explicit; the surface observations as point priors
    opts = dataclasses.replace(ba.opts, eliminate_tie_points=False)
    gr = G.build_graph(block, opts, r.state, r.obs_active, r.control_active, robust=False)
    values = gr.values
    _, B, _ = whitened(block.surface, r.state.points, block.surface_active)
    for j in np.flatnonzero(np.any(B != 0, axis=1)):
        if values.exists(G.P(j)):
            jf = gtsam.JacobianFactor(G.P(j), B[j][None, :], np.zeros(1), gtsam.noiseModel.Unit.Create(1))
            gr.graph.add(gtsam.LinearContainerFactor(jf, values))
    keys = sorted(values.keys())
    order = gtsam.Ordering()
    for k in keys:
        order.push_back(k)
    H, _ = gr.graph.linearize(values).hessian(order)
    Q = np.linalg.inv(H)
    dims = [6 if gtsam.Symbol(k).chr() == ord("x") else 3 for k in keys]  # poses and points only
    off = dict(zip(keys, np.r_[0, np.cumsum(dims)[:-1]].astype(int)))
    tie = np.unique(block.obs_point[r.obs_active])
    tie = tie[~np.isin(tie, block.control_point)]
    xy = r.state.points[tie, :2]
    c = xy.mean(axis=0)
    rho = np.max(np.linalg.norm(xy - c, axis=1))
    xi, eta = ((xy - c) / rho).T
    r2 = xi**2 + eta**2
    L = np.linalg.pinv(np.column_stack([np.ones(len(tie)), xi, eta, r2 - r2.mean()]))
    iz = np.array([off[G.P(j)] + 2 for j in tie])
    sig = np.sqrt(np.diag(L @ Q[np.ix_(iz, iz)] @ L.T)) * r.sigma0
    for m, name in enumerate(MODES):
        assert modes[name].sigma_m == pytest.approx(sig[m], rel=0.02), name


def test_report_names_a_weak_mode(gnss_block):
    """No control, no DEM: the block's height rests on the GNSS positions and the rays' convergence, sigma about
    6 cm; against a 0.1 m height limit (3 sigma above it) the report calls it weak and says what holds it. With
    the DEM the same block's height is held by the surface and nothing is weak."""
    _, root, dem = gnss_block
    st = AdjustSettings(image_sigma_px=SIGMA_PX, use_control=False, rms_limit_z_m=0.1)
    res = run_adjustment(root, st, html=False)
    rep = json.loads(res.report_path.read_text())
    ks = rep["key_statistics"]
    height = {g["mode"]: g for g in rep["geometry_modes"]}["height"]
    assert "height" in ks["weak_geometry"] and height["weak"] and 3 * height["sigma_m"] > 0.1
    assert "Weak geometry: block height sigma" in ks["message"] and "determined by" in ks["message"]
    assert set(height["shares"]) == {"image", "gnss", "priors"} and height["shares"]["gnss"] > 0.2
    txt = (root / "at" / "report.txt").read_text()
    assert "BLOCK GEOMETRY" in txt and "VARIANCE COMPONENTS" in txt
    res = run_adjustment(root, dataclasses.replace(st, dem=dem, surface_sigma_m=0.1), html=False)
    rep = json.loads(res.report_path.read_text())
    assert rep["key_statistics"]["weak_geometry"] == []
    height = {g["mode"]: g for g in rep["geometry_modes"]}["height"]
    assert height["shares"]["surface"] > 0.5
    assert {g["group"] for g in rep["variance_components"]} == {"image", "gnss", "surface"}


def test_the_report_says_the_sigmas_a_priori_and_as_reweighted(gnss_block):
    """trial s102 txt2 M7: SURFACE CONTROL gave the a-priori sigma beside a normalised RMS of the reweighted one, and
    DATUM named the reweighted GNSS sigmas as project.toml's. Both now give the a-priori sigma, the factor and the
    sigma used, and the normalised RMS is the residuals' in the sigmas used."""
    from aerotri.adjust import report
    from aerotri.core.records import to_record

    block, root, dem = gnss_block
    ba = adjust_project(root, AdjustSettings(image_sigma_px=SIGMA_PX, dem=dem, surface_sigma_m=0.5,
                                             variance_components=True))
    rep = to_record(report.build_report(ba))
    w = ba.result.weight_factors
    sc = rep["surface_control"]
    assert sc["sigma_m"] == 0.5 and sc["sigma_factor"] == pytest.approx(w["surface"], abs=1e-4) and w["surface"] < 0.5
    used = ba.result.surface_use == 1
    e, _, sigma = ba.block.surface.observe(ba.result.state.points[used], jacobian=False)
    assert sc["rms_normalised"] == pytest.approx(np.sqrt(np.mean((e / sigma) ** 2)), rel=1e-3)
    assert np.median(sigma) >= 0.5 * w["surface"]  # the sigmas used: the a-priori one times the factor (+ slope)
    txt = report.format_txt(rep)
    assert (f"sigma 0.500 m (+ slope x half a cell) a priori, x {w['surface']:.3f} by variance components (the whole "
            f"sigma, slope term included): {0.5 * w['surface']:.3f} m on flat ground in the solve and in the norm. "
            "rms") in txt
    gnss = next(n for n in rep["datum"] if n.startswith("GNSS: "))
    apriori = block.gnss_sigma_m  # project.toml [gnss] sigma_xy_m, sigma_z_m (0.05 / 0.08 m)
    assert f"positions weighted with {apriori[0]:.3g} / {apriori[2]:.3g} m a priori (plan / height; " in gnss
    assert f"x {w['gnss']:.3f} by variance components" in gnss and abs(w["gnss"] - 1) > 5e-4
