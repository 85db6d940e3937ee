"""Contours against an analytic surface: levels and vertices on the true heights, closed rings closed, lines cut
at nodata, index flags, no crossings after either smoothing (also where smoothing would make them cross), the
GeoPackage read back with its CRS, feet handled by the CRS, bad input stopped with exit 2."""

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from lidarctl.cli import main
from lidarctl.contours import _tension_1d, crossings, data_footprint, smooth_contours, trace


def _surface(x, y):
    return 30.0 - ((x - 250.0) ** 2 + (y - 200.0) ** 2) / 2000.0 + 3.0 * np.sin(x / 40.0)


def _dem(nodata_band=True):
    rows, cols = np.mgrid[0:400, 0:500] + 0.5
    x, y = cols, 400.0 - rows  # map coordinates of the cell centres (origin 0, 400; 1 m cells)
    z = _surface(x, y)
    if nodata_band:
        z[100:120, 50:450] = np.nan
    return z, from_origin(0.0, 400.0, 1.0, 1.0)


def test_traced_vertices_lie_on_the_surface_and_rings_close():
    z, t = _dem()
    cs = trace(z, t, 1.0, 5)
    assert {c.level for c in cs} == set(np.arange(np.ceil(np.nanmin(z)), np.floor(np.nanmax(z)) + 1))
    errs = np.concatenate([_surface(c.xy[:, 0], c.xy[:, 1]) - c.level for c in cs])
    assert np.sqrt(np.mean(errs ** 2)) < 0.01  # linear interpolation of a smooth 1 m grid
    for c in cs:
        assert c.index == (round(c.level) % 5 == 0)
        if c.closed:
            assert np.array_equal(c.xy[0], c.xy[-1])
        # nothing inside the nodata band (rows 100-120 -> y 280-300, x 50-450), with half a cell of margin
        inside = (c.xy[:, 0] > 50.5) & (c.xy[:, 0] < 449.5) & (c.xy[:, 1] > 280.5) & (c.xy[:, 1] < 299.5)
        assert not inside.any()
    assert any(c.closed for c in cs) and any(not c.closed for c in cs)


@pytest.mark.parametrize("method", ["bspline", "tension"])
def test_smoothing_never_crosses(method):
    z, t = _dem()
    cs = trace(z, t, 1.0, 5)
    sm, fell_back = smooth_contours(cs, method, 1.0)
    assert crossings(sm) == 0
    # a rough surface where heavy smoothing would make neighbouring lines cross: they keep their traced form
    rng = np.random.default_rng(0)
    rough = z[:120, :150] + rng.normal(0.0, 0.1, (120, 150))
    cr = trace(rough, t, 0.5, 5)
    sr, fell = smooth_contours(cr, method, 1.0, tolerance_px=3.0, tension=0.01)
    assert crossings(sr) == 0
    if method == "bspline":
        assert fell > 0  # the fall-back was needed here


def test_tension_spline_limits():
    from scipy.interpolate import CubicSpline

    t = np.array([0.0, 1.0, 2.5, 3.0, 4.2, 5.0])
    v = np.sin(t)
    tt = np.linspace(0.0, 5.0, 101)
    assert np.allclose(_tension_1d(t, v, 1.0, t), v, atol=1e-12)  # interpolates
    assert np.allclose(_tension_1d(t, v, 1e-3, tt), CubicSpline(t, v, bc_type="natural")(tt), atol=1e-6)
    assert np.abs(_tension_1d(t, v, 50.0, tt) - np.interp(tt, t, v)).max() < 0.02  # tends to the polyline


def test_command_geopackage_and_feet(tmp_path):
    from pyogrio import read_info
    from pyogrio.raw import read

    z, t = _dem()
    for name, crs, scale in (("m", "EPSG:32631", 1.0), ("ft", "EPSG:2992", 1200.0 / 3937.0)):
        with rasterio.open(tmp_path / f"dem_{name}.tif", "w", driver="GTiff", width=500, height=400, count=1,
                           dtype="float32", crs=crs, transform=t, nodata=-9999.0) as d:
            d.write(np.where(np.isfinite(z), z / scale, -9999.0).astype("float32"), 1)
        r = CliRunner().invoke(main, ["contours", str(tmp_path / f"dem_{name}.tif"), str(tmp_path / f"c_{name}.gpkg"),
                                      "--interval", "2", "--smooth", "bspline"])
        assert r.exit_code == 0, r.output
        assert (tmp_path / f"c_{name}.png").stat().st_size > 10_000
        info = read_info(tmp_path / f"c_{name}.gpkg", layer="contours")
        assert info["crs"].endswith(crs.split(":")[1]) and info["geometry_type"] == "LineString"
        meta, _, geom, fields = read(tmp_path / f"c_{name}.gpkg", layer="contours")
        elev_m = fields[list(meta["fields"]).index("elevation_m")]
        # a 2 m interval in metres, also for the DEM in feet (levels 6.56 ft apart)
        assert np.allclose(np.diff(np.unique(np.round(elev_m, 6))), 2.0)
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "dem_m.tif"), str(tmp_path / "c.shp"), "--interval", "1"])
    assert r.exit_code == 2 and ".gpkg" in r.output and not (tmp_path / "c.shp").exists()
    (tmp_path / "bad.tif").write_text("no raster")
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "bad.tif"), str(tmp_path / "x.gpkg"), "--interval", "1"])
    assert r.exit_code == 2 and "bad.tif" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.gpkg").exists()


@pytest.mark.parametrize("method", ["bspline", "tension"])
def test_smoothed_lines_stay_inside_the_data(method):
    """lidr_topography's case: domes cut by the raster's edge give open lines that leave the border and come back
    to it a few cells further on; with map coordinates of 10^5..10^6 m they were taken for closed rings (a
    relative tolerance) and smoothed as periodic splines, bulging metres past the border. Plus a nodata hole
    that cuts rings open. Every smoothed vertex must lie within the valid cells (plus half a cell), no crossings."""
    ny, nx, cell = 90, 90, 2.0
    x0, y0 = 273_600.0, 5_274_600.0  # UTM-like origin (lidr_topography's)
    rows, cols = np.mgrid[0:ny, 0:nx] + 0.5
    x, y = x0 + cols * cell, y0 - rows * cell
    z = np.full((ny, nx), 800.3)
    # two low domes (one level each) centred ~10 m inside the east and west borders: the border cuts a cap off
    # their 801 m rings; two higher domes at the south border and in the middle
    for cx, cy, h, r in ((x0 + nx * cell - 10.0, y0 - 40.0, 1.2, 20.0), (x0 + 12.0, y0 - 120.0, 1.2, 20.0),
                         (x0 + 40.0, y0 - ny * cell - 2.0, 8.0, 12.0), (x0 + 90.0, y0 - 90.0, 8.0, 12.0)):
        z += h * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * r ** 2))
    z += 0.1 * np.sin(x / 3.1) * np.cos(y / 2.3)  # wiggles the splines smooth away
    z[40:46, 42:50] = np.nan  # a nodata hole inside the middle dome
    t = from_origin(x0, y0, cell, cell)
    cs = trace(z, t, 1.0, 5)
    border_hits = [c for c in cs if not c.closed and np.hypot(*(c.xy[0] - c.xy[-1])) < 50.0]
    assert border_hits  # the case is reproduced: open lines whose ends lie close together
    valid = np.isfinite(z)
    foot = data_footprint(valid, t)
    assert foot.area == pytest.approx(valid.sum() * cell ** 2)
    sm, _ = smooth_contours(cs, method, cell, tolerance_px=1.0, footprint=foot)
    import shapely

    d = np.concatenate([shapely.distance(shapely.points(c.xy), foot) for c in sm])
    assert d.max() <= 0.5 * cell
    assert crossings(sm) == 0
    for c in sm:
        assert c.closed == bool(np.array_equal(c.xy[0], c.xy[-1]))
