"""Contours against an analytic surface: levels and vertices on the true heights, closed rings closed, lines cut
at nodata, index flags, no crossings after either smoothing (also where smoothing would make them cross), the
GeoPackage read back with its CRS, feet handled by the CRS, bad input stopped with exit 2."""

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from lidarctl.cli.main import main
from lidarctl.terrain.contours import _tension_1d, crossings, data_footprint, smooth_contours, trace


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
    for name, crs, scale, interval_m in (("m", "EPSG:32631", 1.0, "2"), ("ft", "EPSG:2992", 1200.0 / 3937.0, "0.6096")):
        with rasterio.open(tmp_path / f"dem_{name}.tif", "w", driver="GTiff", width=500, height=400, count=1,
                           dtype="float32", crs=crs, transform=t, nodata=-9999.0) as d:
            d.write(np.where(np.isfinite(z), z / scale, -9999.0).astype("float32"), 1)
        r = CliRunner().invoke(main, ["contours", str(tmp_path / f"dem_{name}.tif"), str(tmp_path / f"c_{name}.gpkg"),
                                      "--interval-m", interval_m, "--smooth", "bspline"])
        assert r.exit_code == 0, r.output
        assert (tmp_path / f"c_{name}.png").stat().st_size > 10_000
        info = read_info(tmp_path / f"c_{name}.gpkg", layer="contours")
        assert info["crs"].endswith(crs.split(":")[1]) and info["geometry_type"] == "LineString"
        meta, _, geom, fields = read(tmp_path / f"c_{name}.gpkg", layer="contours")
        elev = fields[list(meta["fields"]).index("elevation")]
        elev_m = fields[list(meta["fields"]).index("elevation_m")]
        # the interval is traced in the DEM's height unit: levels at whole multiples of 2 m, or of 2 ft (0.6096 m)
        # for the DEM in feet; elevation_m converts with the CRS's unit
        assert np.array_equal(elev, 2.0 * np.round(elev / 2.0)) and np.allclose(np.diff(np.unique(elev)), 2.0)
        assert np.allclose(elev_m, elev * scale)
        assert f"every 2 {name}" in r.output and "the DEM's height unit" in r.output
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "dem_m.tif"), str(tmp_path / "c.shp"), "--interval-m", "1"])
    assert r.exit_code == 2 and ".gpkg" in r.output and not (tmp_path / "c.shp").exists()
    (tmp_path / "bad.tif").write_text("no raster")
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "bad.tif"), str(tmp_path / "x.gpkg"), "--interval-m", "1"])
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


def _feet_dem(path, z_ft, t):
    with rasterio.open(path, "w", driver="GTiff", width=z_ft.shape[1], height=z_ft.shape[0], count=1,
                       dtype="float32", crs="EPSG:2992", transform=t, nodata=-9999.0) as d:  # Oregon Lambert, ft
        d.write(np.where(np.isfinite(z_ft), z_ft, -9999.0).astype("float32"), 1)
    return path


def test_feet_dem_levels_at_whole_feet(tmp_path):
    """Autzen's case (a DEM in feet, 406-435 ft): --interval-m 0.3048 gives levels at whole feet, not at
    binary-noise neighbours of them; every traced vertex lies on its level. The option is in metres, as every
    length option: 1 gives levels 1 m (3.2808399 ft) apart."""
    from pyogrio.raw import read

    z, t = _dem(nodata_band=False)
    z_ft = 406.3 + (z - np.nanmin(z)) * (434.9 - 406.3) / (np.nanmax(z) - np.nanmin(z))
    dem = _feet_dem(tmp_path / "dem_ft.tif", z_ft, t)
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c.gpkg"), "--interval-m", "0.3048",
                                  "--no-png"])
    assert r.exit_code == 0, r.output
    meta, _, _, fields = read(tmp_path / "c.gpkg", layer="contours")
    elev = fields[list(meta["fields"]).index("elevation")]
    assert set(np.unique(elev)) == set(np.arange(407.0, 435.0))  # 407 ... 434 ft, whole feet
    assert "every 1 ft" in r.output and "from 407 to 434 ft" in r.output
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c_m.gpkg"), "--interval-m", "1", "--no-png"])
    assert r.exit_code == 0, r.output
    meta, _, _, fields = read(tmp_path / "c_m.gpkg", layer="contours")
    levels = np.unique(fields[list(meta["fields"]).index("elevation")])
    assert np.allclose(np.diff(levels), 1 / 0.3048, rtol=1e-9) and levels[0] == pytest.approx(124 / 0.3048)
    assert "every 3.28084 ft" in r.output
    # an interval near no whole number of feet is said, with the metres of the nearest (trial s96 F6: a user's
    # "2 ft" as 0.61 m gave levels at 408.268, 410.269 ... without a word), and a run that draws nothing (F12)
    assert "is 3.28084 ft on this DEM: its levels fall at odd heights; for 3 ft give 0.9144 m" in r.output
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c2.gpkg"), "--interval-m", "0.61", "--no-png"])
    assert "for 2 ft give 0.6096 m" in r.output
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "cbig.gpkg"), "--interval-m", "1000",
                                  "--no-png"])
    assert r.exit_code == 0 and "no level every 3280.84 ft lies within the DEM's heights 406.3 .. 434.9 ft" in r.output
    # sub-unit intervals land on their own multiples too (no binary noise: 0.1 x 4071 is 407.1)
    cs = trace(z_ft, t, 0.5, 5)
    assert all(c.level * 2 == round(c.level * 2) for c in cs)


def test_the_international_feet_metres_on_a_us_survey_feet_dem_give_whole_feet(tmp_path):
    """trial-us 4: --interval-m 0.3048 (the help's example) on a DEM in US survey feet traced levels every 0.999998
    ft (1353.997292 where 1354 was meant); within 10 ppm of a whole number of feet the interval is that number."""
    from pyogrio.raw import read

    from lidarctl.terrain.contours import whole_unit_interval

    z, t = _dem(nodata_band=False)
    z_ft = 406.3 + (z - np.nanmin(z)) * (434.9 - 406.3) / (np.nanmax(z) - np.nanmin(z))
    dem = tmp_path / "dem_usft.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=z_ft.shape[1], height=z_ft.shape[0], count=1,
                       dtype="float32", crs="EPSG:2286", transform=t, nodata=-9999.0) as d:  # Washington S, US ft
        d.write(z_ft.astype("float32"), 1)
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c.gpkg"), "--interval-m", "0.3048",
                                  "--no-png"])
    assert r.exit_code == 0, r.output
    meta, _, _, fields = read(tmp_path / "c.gpkg", layer="contours")
    assert set(np.unique(fields[list(meta["fields"]).index("elevation")])) == set(np.arange(407.0, 435.0))
    us_ft, ft = 1200.0 / 3937.0, 0.3048
    assert whole_unit_interval(ft, us_ft) == 1.0 and whole_unit_interval(us_ft, ft) == 1.0
    assert whole_unit_interval(2 * ft, us_ft) == 2.0 and whole_unit_interval(0.1524, us_ft) == 0.5
    assert whole_unit_interval(0.3, ft) == pytest.approx(0.3 / ft)        # 0.98 ft: meant as it is
    assert whole_unit_interval(0.3048, 1.0) == 0.3048                     # a metre DEM keeps its metres


def test_interval_too_fine_for_the_data_is_refused_fast(tmp_path):
    """A millimetre interval would make millions of lines' vertices (the command hung): refused from the data
    before any tracing, naming the option and the smallest interval that fits, exit 2, nothing written."""
    import time

    from lidarctl.terrain.contours import MAX_VERTICES_PER_CELL, check_interval, vertex_count

    z, t = _dem()
    dem = _feet_dem(tmp_path / "dem.tif", z / 0.3048, t)
    t0 = time.perf_counter()
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c.gpkg"), "--interval-m", "0.001"])
    assert time.perf_counter() - t0 < 10.0
    assert r.exit_code == 2 and "--interval-m" in r.output and "ft" in r.output and "at least" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "c.gpkg").exists() and not (tmp_path / "c.png").exists()
    # the count is exact: the vertices traced at an accepted interval
    zz = z[:60, :80]
    for interval in (1.0, 0.25):
        n = vertex_count(zz, interval)
        traced = sum(len(c.xy) - (1 if c.closed else 0) for c in trace(zz, t, interval, 5))
        assert n == pytest.approx(traced, rel=0.01)
    # the suggested interval is accepted
    need = float(r.output.split("at least ")[1].split(" ft")[0])
    valid = np.isfinite(z).sum()
    assert check_interval(z / 0.3048, need) <= MAX_VERTICES_PER_CELL * valid
    # absurd intervals (heights / interval beyond float range) are refused as well, not traced
    from aerotri.core.errors import OptionError

    with pytest.raises(OptionError, match="at least") as e:
        trace(z, t, 1e-310, 5)
    assert e.value.param == "--interval-m"


def test_a_zero_level_reached_from_below_is_written_0(tmp_path):
    """AHN3 Delft (heights NAP, -0.6 to 3.4 m): the command said "from -0 to 3 m"."""
    z, t = _dem(nodata_band=False)
    z_ft = -0.6 + (z - np.nanmin(z)) * 4.0 / (np.nanmax(z) - np.nanmin(z))
    dem = _feet_dem(tmp_path / "dem_ft.tif", z_ft, t)
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c.gpkg"), "--interval-m", "0.3048",
                                  "--no-png"])
    assert r.exit_code == 0, r.output
    assert "from 0 to 3 ft" in r.output and "from -0" not in r.output and " -0 " not in r.output


def test_map_shades_every_valid_cell_up_to_a_hole(tmp_path, monkeypatch):
    """A tilted plane with a nodata hole: the contour map's hillshade covers every valid cell (the map no longer
    trims a cell along nodata) in one grey (no rim: slopes from valid cells only)."""
    from matplotlib.axes import Axes

    r, c = np.mgrid[0:60, 0:60].astype(float)
    z = 100.0 - 0.1 * c - 0.02 * r
    z[25:35, 20:40] = np.nan
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=60, height=60, count=1, dtype="float32",
                       crs="EPSG:32633", transform=from_origin(1000.0, 5000.0, 2.0, 2.0), nodata=-9999.0) as d:
        d.write(np.where(np.isfinite(z), z, -9999.0).astype("float32"), 1)
    drawn, imshow = [], Axes.imshow
    monkeypatch.setattr(Axes, "imshow", lambda ax, a, *args, **kw: (drawn.append(np.asarray(a)), imshow(ax, a, *args, **kw))[1])
    res = CliRunner().invoke(main, ["contours", str(tmp_path / "dem.tif"), str(tmp_path / "c.gpkg"), "--interval-m", "1"])
    assert res.exit_code == 0, res.output
    (hs,) = drawn
    assert np.array_equal(np.isfinite(hs), np.isfinite(z))
    assert np.ptp(hs[np.isfinite(hs)]) < 1e-4  # float32 heights; a grey level is 1/256


def test_a_cell_exactly_at_a_level_gives_no_one_point_line(tmp_path):
    """A DEM cell exactly at a contour level among lower ones (a spot height of 806.0 m in lidR's Topography, AHN3's
    0.0 m): contourpy gives a "line" of one point five times, written as an invalid GeoPackage geometry."""
    import pyogrio.raw
    import shapely

    rows, cols = np.mgrid[0:40, 0:50]
    z = 800.0 + 0.1 * cols + 0.05 * rows
    z[20, 20] = 806.0            # a peak exactly at a level
    t = from_origin(0.0, 40.0, 1.0, 1.0)
    cs = trace(z, t, 1.0, 5)
    assert all(np.ptp(c.xy, axis=0).any() for c in cs)
    assert not [c for c in cs if c.level == 806.0 and np.hypot(*(c.xy[0] - [20.5, 19.5])) < 1e-6]
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32", crs="EPSG:32632",
                       transform=t, nodata=-9999.0) as ds:
        ds.write(z.astype(np.float32), 1)
    r = CliRunner().invoke(main, ["contours", str(path), str(tmp_path / "c.gpkg"), "--interval-m", "1", "--no-png"])
    assert r.exit_code == 0, r.output
    g = shapely.from_wkb(pyogrio.raw.read(tmp_path / "c.gpkg", layer="contours")[2])
    assert len(g) and shapely.is_valid(g).all()


def test_a_geopackage_with_other_layers_is_not_replaced(tmp_path):
    """`contours DEM mine.gpkg` replaced the user's GeoPackage with its other layers (trial-lidar: a 'roads'
    layer gone, exit 0); now refused naming the layers, the file unchanged; its own output is replaced."""
    import shapely
    from pyogrio import list_layers
    from pyogrio.raw import write

    z, t = _dem()
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=500, height=400, count=1, dtype="float32",
                       crs="EPSG:32631", transform=t, nodata=-9999.0) as d:
        d.write(np.where(np.isfinite(z), z, -9999.0).astype("float32"), 1)
    mine = tmp_path / "mine.gpkg"
    write(str(mine), np.array([shapely.to_wkb(shapely.Point(10.0, 20.0))], dtype=object), field_data=[np.array([1])],
          fields=["a"], layer="roads", driver="GPKG", geometry_type="Point", crs="EPSG:32631")
    before = mine.read_bytes()
    run = ["contours", str(tmp_path / "dem.tif"), None, "--interval-m", "2", "--no-png"]
    r = CliRunner().invoke(main, [a if a is not None else str(mine) for a in run])
    assert r.exit_code == 2 and "roads" in r.output and "Traceback" not in r.output
    assert mine.read_bytes() == before
    (tmp_path / "junk.gpkg").write_text("not a GeoPackage")
    r = CliRunner().invoke(main, [a if a is not None else str(tmp_path / "junk.gpkg") for a in run])
    assert r.exit_code == 2 and "not a GeoPackage" in r.output
    for _ in range(2):  # a previous contours file is replaced
        r = CliRunner().invoke(main, [a if a is not None else str(tmp_path / "c.gpkg") for a in run])
        assert r.exit_code == 0, r.output
    assert [str(n) for n, _ in list_layers(tmp_path / "c.gpkg")] == ["contours"]


@pytest.mark.parametrize("crs, z_scale", [("EPSG:2994+5703", 0.3048), ("EPSG:3740+6360", 1 / 0.3048006096)])
def test_map_shades_a_dem_whose_heights_and_grid_differ_in_unit_by_the_true_slopes(tmp_path, monkeypatch, crs,
                                                                                    z_scale):
    """trial-lidar: the contour map's hillshade took the heights in the grid's unit: a DEM of heights in metres on a
    foot grid (EPSG:2994+5703) was shaded 3.28x flatter than the same terrain in feet, one in US feet on a metre grid
    3.28x steeper. Now the map is the same as that of the DEM whose heights are in the grid's unit."""
    from matplotlib.axes import Axes

    z, t = _dem(nodata_band=False)
    drawn, imshow = [], Axes.imshow
    monkeypatch.setattr(Axes, "imshow", lambda ax, a, *args, **kw: (drawn.append(np.asarray(a)), imshow(ax, a, *args, **kw))[1])
    for name, c, values in (("same.tif", crs.split("+")[0], z), ("mixed.tif", crs, z * z_scale)):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=500, height=400, count=1, dtype="float32",
                           crs=c, transform=t, nodata=-9999.0) as d:
            d.write(values.astype("float32"), 1)
        r = CliRunner().invoke(main, ["contours", str(tmp_path / name), str(tmp_path / f"{name}.gpkg"),
                                      "--interval-m", "2"])
        assert r.exit_code == 0, r.output
    same, mixed = drawn
    assert np.ptp(same) > 0.3 and np.allclose(mixed, same, atol=1e-3)


def test_a_reader_that_closes_the_pipe_does_not_undo_the_outputs(tmp_path):
    """``lidarctl contours ... | head -0``: the summary printed before the commit met a closed pipe; the
    BrokenPipeError rolled the finished GeoPackage back (trial-lidar). Now the outputs stand, exit 0."""
    import subprocess
    import sys

    z, t = _dem(nodata_band=False)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=500, height=400, count=1,
                       dtype="float32", crs="EPSG:32631", transform=t) as d:
        d.write(z.astype("float32"), 1)
    code = "from lidarctl.cli.main import main; main()"
    p = subprocess.Popen([sys.executable, "-c", code, "contours", str(tmp_path / "dem.tif"),
                          str(tmp_path / "c.gpkg"), "--interval-m", "1"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before the command prints anything
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert (tmp_path / "c.gpkg").stat().st_size > 10_000 and (tmp_path / "c.png").exists()


def test_geojson_is_refused_for_a_crs_without_an_authority_code(tmp_path):
    """Trial-hydro: Autzen's contours as GeoJSON (Oregon Lambert feet, no code in the file's definition) were written
    without a CRS and read back as WGS 84 lon/lat (by QGIS and by hydro-flatten). Refused, naming the output and
    .gpkg; a CRS with its code writes GeoJSON as before."""
    z, transform = _dem(nodata_band=False)
    own = ("+proj=lcc +lat_0=41.75 +lon_0=-120.5 +lat_1=43 +lat_2=45.5 +x_0=400000 +y_0=0 +ellps=GRS80 "
           "+units=m +no_defs")
    for name, crs in (("own", own), ("epsg", "EPSG:32632")):
        with rasterio.open(tmp_path / f"{name}.tif", "w", driver="GTiff", width=500, height=400, count=1,
                           dtype="float32", crs=crs, transform=transform, nodata=-9999.0) as ds:
            ds.write(z.astype(np.float32), 1)
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "own.tif"), str(tmp_path / "own.geojson"), "--no-png", "--interval-m", "2"])
    assert r.exit_code == 2 and "carries none" in r.output and ".gpkg" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "own.geojson").exists()
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "own.tif"), str(tmp_path / "own.gpkg"), "--no-png", "--interval-m", "2"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "epsg.tif"), str(tmp_path / "epsg.geojson"), "--no-png", "--interval-m", "2"])
    assert r.exit_code == 0 and (tmp_path / "epsg.geojson").is_file(), r.output


def test_a_dem_stating_metres_on_a_foot_grid_is_read_in_metres(tmp_path):
    """Trial-hydro: heights in metres on a 2D foot CRS, the band's unit and VERTICAL_UNITS saying metre, were read as
    feet (contours 'every 1 ft ... 124-132 ft', elevation_m 3.28 x too small). A 2D CRS says nothing of heights: the
    file's own statement decides; without one, the CRS's unit as before."""
    z, transform = _dem(nodata_band=False)
    out = {}
    for name, unit in (("stated", "metre"), ("silent", None)):
        path = tmp_path / f"{name}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=500, height=400, count=1, dtype="float32",
                           crs="EPSG:2994", transform=transform, nodata=-9999.0) as ds:
            ds.write(z.astype(np.float32), 1)
            if unit:
                ds.units = (unit,)
                ds.update_tags(VERTICAL_UNITS=unit)
        r = CliRunner().invoke(main, ["contours", str(path), str(tmp_path / f"{name}.gpkg"), "--no-png",
                                      "--interval-m", "2"])
        assert r.exit_code == 0, r.output
        out[name] = r.output
    assert "every 2 m (the DEM's height unit)" in out["stated"] and "as the file states them" in out["stated"]
    assert "ft (the DEM's height unit)" in out["silent"] and "as the file states them" not in out["silent"]


def test_contours_through_a_cell_exactly_at_a_level_do_not_touch(tmp_path):
    """A DEM cell exactly at a level (the demo's float32 DEM has 231 in an 800 x 800 crop) puts a vertex of every line
    around it on its centre: at a saddle two lines of the level touched there, around a pass one line touched itself.
    Smoothing fell back to those traced lines, and `contours --smooth bspline` stopped with "N contour crossings
    after smoothing" (trial "gis" F6). Now the lines pass a hair from the centre; a pit exactly at a level gives no
    line, as a peak."""
    import shapely

    t = from_origin(0.0, 5.0, 1.0, 1.0)
    r, c = np.mgrid[0:3, 0:3] - 1.0
    saddle = 10.0 + 0.1 * (r * r - c * c) + 0.013 * r * c  # higher to the north and south, 10.0 at the centre
    ring = np.full((5, 5), 12.3)  # a pass of 10.0 between two hollows: one ring round both, twice at the centre
    ring[1:4, 1] = ring[1:4, 3] = 9.4
    ring[1, 2] = ring[3, 2] = 10.6
    ring[2, 2] = 10.0
    for z, centre in ((saddle, (1.5, 3.5)), (ring, (2.5, 2.5))):
        cs = trace(z, t, 1.0, 5)
        assert crossings(cs) == 0
        at = [c for c in cs if c.level == 10.0]
        assert at and all(0.0 < shapely.LineString(c.xy).distance(shapely.Point(centre)) < 1e-5 for c in at)
        for method in ("bspline", "tension"):
            assert crossings(smooth_contours(cs, method, 1.0)[0]) == 0
    pit = np.full((5, 5), 10.5)
    pit[2, 2] = 10.0
    assert trace(pit, t, 1.0, 5) == []
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=3, height=3, count=1, dtype="float32", crs="EPSG:32632",
                       transform=t, nodata=-9999.0) as ds:
        ds.write(saddle.astype(np.float32), 1)
    r = CliRunner().invoke(main, ["contours", str(path), str(tmp_path / "c.gpkg"), "--interval-m", "1",
                                  "--smooth", "bspline", "--no-png"])
    assert r.exit_code == 0, r.output


def test_a_level_grazing_one_cell_makes_no_contour_and_small_rings_keep_their_size():
    """new-user trial on Autzen's DEM in feet: 11 of 540 contours at 428 ft were rings 0.001-0.07 ft across (a cell
    a hair above the level among lower ones), one smoothed by the B-spline to a single point. A ring under a tenth
    of a cell is left out and counted; a ring of a peak a few cells wide stays, smoothed or not, at its size."""
    from lidarctl.terrain.contours import MIN_EXTENT_CELLS, trace_counted

    z = np.full((40, 40), 10.1)
    z[10, 10] = 10.5 + 0.0004  # a hair above the 10.5 level: its ring is 0.002 of a cell across
    rows, cols = np.mgrid[0:40, 0:40]
    z += 2.0 * np.exp(-((rows - 28.0) ** 2 + (cols - 28.0) ** 2) / 4.0)  # a peak rising through 10.5 and 11.5
    t = from_origin(0.0, 40.0, 1.0, 1.0)
    cs, tiny = trace_counted(z, t, 0.5, 5)
    assert tiny == 1 and all(np.ptp(c.xy, axis=0).max() >= MIN_EXTENT_CELLS for c in cs)
    assert sorted(c.level for c in cs) == [10.5, 11.0, 11.5, 12.0]  # the peak's rings (top 12.1)
    assert all(np.hypot(c.xy[:, 0] - 10.5, c.xy[:, 1] - 29.5).min() > 5.0 for c in cs)  # none at the grazed cell
    small = [c for c in cs if c.level == 12.0][0]
    assert MIN_EXTENT_CELLS < np.ptp(small.xy, axis=0).max() < 1.5  # the top's ring: under two cells across
    for method in ("bspline", "tension"):
        sm, _ = smooth_contours(cs, method, 1.0, tolerance_px=2.0)  # a tolerance wider than the small ring
        for a, b in zip(cs, sm):
            assert np.ptp(b.xy, axis=0).max() >= 0.5 * np.ptp(a.xy, axis=0).max()


def test_tension_spline_stays_finite_over_a_segment_far_longer_than_the_median():
    """Autzen's DEM in feet: `--smooth tension` stopped on a traceback (sinh overflowed: one chord thousands of
    times the median one). The spline is written with exp(-x), finite for any chord."""
    from lidarctl.terrain.contours import _tension

    xy = np.vstack([np.column_stack([np.linspace(0.0, 0.05, 51), np.zeros(51)]), [[30.0, 4.0], [31.0, 4.5]]])
    out = _tension(xy, False, 1.0, 0.5)
    assert np.isfinite(out).all() and np.array_equal(out[0], xy[0]) and np.array_equal(out[-1], xy[-1])
    assert np.abs(out[:, 1]).max() < 10.0  # between the vertices' heights, give or take the spline's swing


def test_contours_are_cut_at_the_water_given(tmp_path):
    """Trial s98: 26 contour lines (1,884 ft) ran through Autzen's river, left unflattened as flowing water, and
    ``contours`` had no way to stop them at the shore (``vectors --dem`` had). ``--water``: cut at the polygons'
    outlines, the pieces inside left out, counted; a wrong layer is refused with nothing written."""
    import shapely
    from pyogrio.raw import read

    from aerotri.core.vector_files import VectorLayer, write_layers

    z, t = _dem(nodata_band=False)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=500, height=400, count=1, dtype="float32",
                       crs="EPSG:32631", transform=t, nodata=-9999.0) as d:
        d.write(z.astype("float32"), 1)
    river = shapely.Polygon([(0, 180), (500, 180), (500, 220), (0, 220)])  # a band across the DEM
    write_layers(tmp_path / "water.gpkg", [VectorLayer("water", "Polygon", [river], {"water_z": np.array([20.0])})],
                 crs="EPSG:32631")
    runs = {}
    for name, extra in (("plain", []), ("cut", ["--water", str(tmp_path / "water.gpkg")])):
        r = CliRunner().invoke(main, ["contours", str(tmp_path / "dem.tif"), str(tmp_path / f"{name}.gpkg"),
                                      "--interval-m", "1", "--no-png", *extra])
        assert r.exit_code == 0, r.output
        _, _, wkb, _ = read(tmp_path / f"{name}.gpkg", layer="contours")
        runs[name] = shapely.from_wkb(wkb)
        runs[name + "_out"] = r.output
    inside = lambda lines: sum(g.intersection(river.buffer(-0.5)).length for g in lines)  # noqa: E731
    assert inside(runs["plain"]) > 1000 and inside(runs["cut"]) == 0
    n_cut = sum(1 for g in runs["plain"] if g.intersects(river.buffer(-0.5)))
    assert f"; {n_cut} cut at the water's outlines (--water)" in runs["cut_out"]
    # outside the water the lines are the same
    outside = lambda lines: sum(g.difference(river.buffer(0.5)).length for g in lines)  # noqa: E731
    assert outside(runs["cut"]) == pytest.approx(outside(runs["plain"]), rel=1e-9)
    r = CliRunner().invoke(main, ["contours", str(tmp_path / "dem.tif"), str(tmp_path / "x.gpkg"), "--interval-m", "1",
                                  "--water", str(tmp_path / "water.gpkg"), "--water-layer", "lakes"])
    assert r.exit_code == 2 and "lakes" in r.output and not (tmp_path / "x.gpkg").exists()


def test_rings_the_dem_does_not_resolve_are_left_out_by_the_command(tmp_path):
    """trial s98 L8: 406 of 589 Topography contours at 1 m were closed rings under 10 m long (median 3.3 m), one or two
    cells' heights. By default a closed contour enclosing fewer than 4 cells (2 x 2) is left out and counted; a hill's
    rings enclosing more stay, and open lines stay whatever their length; --min-ring-cells 0 keeps every ring."""
    from pyogrio.raw import read

    from lidarctl.terrain.contours import ring_area

    rows, cols = np.mgrid[0:60, 0:80] + 0.5
    z = 10.0 + 0.05 * cols  # a gentle slope: open lines
    z[20, 20] += 1.2  # one cell above its neighbours: a ring under a cell's area at every level it crosses
    z += 3.0 * np.exp(-((rows - 40.0) ** 2 + (cols - 55.0) ** 2) / 30.0)  # a hill: rings of tens of cells
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=80, height=60, count=1, dtype="float32", crs="EPSG:32631",
                       transform=from_origin(0.0, 60.0, 1.0, 1.0)) as d:
        d.write(z.astype("float32"), 1)
    found = {}
    for args in ([], ["--min-ring-cells", "0"]):
        out = tmp_path / f"c{len(args)}.gpkg"
        r = CliRunner().invoke(main, ["contours", str(path), str(out), "--interval-m", "0.5", "--no-png"] + args)
        assert r.exit_code == 0, r.output
        meta, _, geom, fields = read(out, layer="contours")
        import shapely

        lines = shapely.from_wkb(geom)
        closed = fields[list(meta["fields"]).index("closed")]
        areas = [ring_area(np.asarray(g.coords)) for g, c in zip(lines, closed) if c]
        found[len(args)] = (len(lines), sorted(areas), int(np.sum(~closed.astype(bool))), r.output)
    (n4, areas4, open4, out4), (n0, areas0, open0, out0) = found[0], found[2]
    small = [a for a in areas0 if a < 4.0]
    assert len(small) >= 2 and max(small) < 1.0  # the single cell's rings: under a cell's area
    assert areas4 == [a for a in areas0 if a >= 4.0] and len(areas4) >= 4  # the hill's rings kept (7.5-140 m2)
    assert open4 == open0 > 0 and n0 - n4 == len(small)
    assert f"{len(small)} closed contours enclosing fewer than 4 cells left out" in out4
    assert "closed contours enclosing" not in out0
