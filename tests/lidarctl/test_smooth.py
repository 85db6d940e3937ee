"""Anisotropic DEM smoothing against known truth: second order keeps a step (a wall) that a Gaussian of the
same noise reduction blurs; fourth order keeps planes and the creases between them (an embankment) that
second order rounds; windows identical to the whole raster; feet handled by the
CRS; nodata kept; bad options and inputs stopped with exit 2."""

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin
from scipy import ndimage

from lidarctl.cli.main import main
from lidarctl.terrain.smooth import DiffusionSettings, anisotropic_diffusion, gaussian_equivalent_sigma_px

NODATA = -9999.0


def _scene(seed=1, step_m=3.0, noise_m=0.15):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:160, 0:140].astype(float)
    true = 0.03 * x + 0.01 * y + np.where(y >= 80, step_m, 0.0)  # a 3 m embankment along row 80
    return true, true + rng.normal(0.0, noise_m, true.shape)


def _rms(a):
    return float(np.sqrt(np.mean(a ** 2)))


def test_noise_removed_and_step_kept_where_a_gaussian_blurs_it():
    true, noisy = _scene()
    near = np.zeros(true.shape, bool)
    near[76:84] = True  # within 4 cells of the step
    away = np.ones(true.shape, bool)
    away[60:100] = False  # more than 20 cells from it
    away[:10] = away[-10:] = False
    away[:, :10] = away[:, -10:] = False  # and from the raster's border, where a Gaussian reflects
    out = anisotropic_diffusion(noisy, DiffusionSettings(order=2, edge_m=0.5, iterations=20))
    before, after = _rms((noisy - true)[away]), _rms((out - true)[away])
    assert after < 0.4 * before  # at least 60 % of the noise gone away from the step
    assert _rms((out - true)[near]) < 1.1 * _rms((noisy - true)[near])  # the step is not smeared
    # a Gaussian that removes as much noise away from the step smears it
    sigma = next(s for s in np.arange(0.5, 10.0, 0.05)
                 if _rms((ndimage.gaussian_filter(noisy, s) - true)[away]) <= after)
    gauss = ndimage.gaussian_filter(noisy, sigma)
    assert _rms((gauss - true)[near]) > 3.0 * _rms((out - true)[near])


def test_fourth_order_keeps_planes_and_creases():
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:200, 0:120].astype(float)
    # an embankment 2.5 m high: crown 24 cells, sides of 1:3 over 7.5 cells, on a tilted plane
    d = np.abs(y - 100.0)
    true = 0.02 * x + 0.01 * y + np.clip(2.5 - np.maximum(d - 12.0, 0) / 3.0, 0, None)
    noisy = true + rng.normal(0.0, 0.15, true.shape)
    crease = (np.abs(d - 12.0) <= 3) | (np.abs(d - 19.5) <= 3)
    inner = np.zeros(true.shape, bool)
    inner[10:-10, 10:-10] = True
    four = anisotropic_diffusion(noisy, DiffusionSettings())
    two = anisotropic_diffusion(noisy, DiffusionSettings(order=2, edge_m=0.5, iterations=20))
    assert _rms((four - true)[inner]) < 0.3 * _rms((noisy - true)[inner])
    assert _rms((four - true)[inner & crease]) < 0.75 * _rms((two - true)[inner & crease])
    # a tilted plane is a steady state, up to the border and around nodata
    plane = 0.4 * x - 0.3 * y
    plane[50:60, 50:70] = np.nan
    for p in (DiffusionSettings(iterations=50), DiffusionSettings(order=2, edge_m=0.5, iterations=50)):
        out = anisotropic_diffusion(plane, p)
        ok = ~np.isnan(plane)
        assert np.allclose(out[ok], plane[ok], atol=1e-9)


def test_linear_limit_is_a_gaussian():
    # far below the edge height the conductance is 1: the heat equation, a Gaussian of sqrt(2 t) cells
    z = np.zeros((81, 81))
    z[40, 40] = 1e-3
    p = DiffusionSettings(order=2, edge_m=1e3, iterations=40, step=0.2)
    out = anisotropic_diffusion(z, p)
    yy, xx = np.mgrid[0:81, 0:81] - 40
    var = float((out * (xx ** 2)).sum() / out.sum())
    assert var == pytest.approx(gaussian_equivalent_sigma_px(p) ** 2, rel=1e-9)
    assert out.sum() == pytest.approx(1e-3, rel=1e-12)  # volume kept


def test_nodata_is_kept_and_not_diffused_into():
    true, noisy = _scene()
    noisy[20:30, 20:30] = np.nan
    for order in (2, 4):
        out = anisotropic_diffusion(noisy, DiffusionSettings(order=order))
        assert np.isnan(out[20:30, 20:30]).all() and np.isfinite(out[~np.isnan(noisy)]).all()


def _write(path, z, crs="EPSG:32631"):
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=crs, transform=from_origin(500000, 5800000, 1, 1), nodata=NODATA) as d:
        d.write(np.where(np.isfinite(z), z, NODATA).astype("float32"), 1)


def test_command_windows_identical_to_whole_and_feet(tmp_path):
    true, noisy = _scene()
    noisy[5:9, 100:120] = np.nan
    _write(tmp_path / "dem.tif", noisy)
    r1 = CliRunner().invoke(main, ["smooth", str(tmp_path / "dem.tif"), str(tmp_path / "whole.tif"), "--iterations", "20"])
    r2 = CliRunner().invoke(main, ["smooth", str(tmp_path / "dem.tif"), str(tmp_path / "win.tif"), "--window-px", "32",
                                   "--iterations", "20"])
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output + r2.output
    with rasterio.open(tmp_path / "whole.tif") as a, rasterio.open(tmp_path / "win.tif") as b:
        za, zb = a.read(1), b.read(1)
        assert a.crs == b.crs and a.transform == b.transform and a.nodata == NODATA
    assert np.array_equal(za, zb)
    assert (za[5:9, 100:120] == NODATA).all()
    # the same DEM in US survey feet (EPSG:2992, Oregon Lambert ft): the edge height stays 0.5 m
    ft = 1200.0 / 3937.0
    _write(tmp_path / "dem_ft.tif", noisy / ft, crs="EPSG:2992")
    r3 = CliRunner().invoke(main, ["smooth", str(tmp_path / "dem_ft.tif"), str(tmp_path / "ft.tif"), "--iterations", "20"])
    assert r3.exit_code == 0, r3.output
    with rasterio.open(tmp_path / "ft.tif") as c:
        zc = c.read(1)
    ok = za != NODATA
    assert np.allclose(zc[ok] * ft, za[ok], atol=2e-4)


def test_bad_input_and_options(tmp_path):
    (tmp_path / "bad.tif").write_text("not a raster")
    r = CliRunner().invoke(main, ["smooth", str(tmp_path / "bad.tif"), str(tmp_path / "o.tif")])
    assert r.exit_code == 2 and "bad.tif" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o.tif").exists()
    _write(tmp_path / "dem.tif", _scene()[1])
    r = CliRunner().invoke(main, ["smooth", str(tmp_path / "dem.tif"), str(tmp_path / "o.tif"), "--step", "0.1"])
    assert r.exit_code == 2 and "--step" in r.output  # order 4 is stable up to 1/32
    r = CliRunner().invoke(main, ["smooth", str(tmp_path / "dem.tif"), str(tmp_path / "dem.tif")])
    assert r.exit_code == 2 and "input" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.tif", "dem.tif"]
