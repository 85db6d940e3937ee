"""``lidarctl hydro-flatten``: lakes at one level at or below their shores, rivers left, bad input refused."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
import rasterio
import shapely
from click.testing import CliRunner
from pyogrio.raw import write
from rasterio.transform import from_origin
from shapely.geometry import box

from lidarctl.cli.main import main

X0, Y0, CELL = 500000.0, 5400000.0, 1.0
LAKE = box(X0 + 20, Y0 + 20, X0 + 50, Y0 + 45)
RIVER = box(X0 + 70, Y0 + 5, X0 + 80, Y0 + 95)


def _dem(path, crs="EPSG:32632", slope=0.05):
    """100 x 100 cells of 1 m: terrain rising to the east (``slope`` per m) from 100 m; over the lake the TIN of its
    shores and scattered water returns: 100.6 .. 102.6 m, bumpy; nodata in one corner."""
    rng = np.random.default_rng(2)
    xs, ys = X0 + np.arange(100) + 0.5, Y0 + 100 - (np.arange(100) + 0.5)
    gx, gy = np.meshgrid(xs, ys)
    z = 100.0 + slope * (gx - X0) + 1.0
    inside = shapely.contains_xy(LAKE, gx, gy)
    z[inside] = 100.6 + 2.0 * rng.random(inside.sum())
    z[:5, :5] = -9999.0
    with rasterio.open(path, "w", driver="GTiff", width=100, height=100, count=1, dtype="float32", crs=crs,
                       transform=from_origin(X0, Y0 + 100, CELL, CELL), nodata=-9999.0) as dst:
        dst.write(z.astype("float32"), 1)
    return path


def _water(path, polys, water_z=None, ranges=None, crs="EPSG:32632"):
    fields, names = [np.arange(len(polys))], ["id"]
    if water_z is not None:
        fields.append(np.asarray(water_z, float))
        names.append("water_z")
    if ranges is not None:
        fields.append(np.asarray(ranges, float))
        names.append("water_z_range_m")
    write(path, np.array(shapely.to_wkb(np.array(polys, dtype=object)), dtype=object), field_data=fields, fields=names,
          geometry_type="Polygon", crs=pyproj.CRS(crs).to_wkt(), driver="GPKG", layer="water")
    return path


def test_a_lake_is_flat_at_or_below_its_shore_and_a_river_is_left(tmp_path):
    dem = _dem(tmp_path / "dem.tif")
    # the lake's returns at 101.3 m; its shore (x 18-20 m and 50-52 m: 101.9 .. 103.6 m) lies above: the level is
    # the water's; the river's returns span 1.6 m (falling along its course): left as it is
    water = _water(tmp_path / "map.gpkg", [LAKE, RIVER], water_z=[101.3, 104.0], ranges=[0.08, 1.6])
    r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(tmp_path / "hf.tif"), "--water", str(water)])
    assert r.exit_code == 0, r.output
    assert "1 of 2 water bodies flattened" in r.output
    assert "water 1: 750 m2 at 101.30 m (water returns 101.30, shore 101.9" in r.output
    assert "water 2: 900 m2, left: water returns span 1.60 m (> 0.5 m): flowing water" in r.output
    with rasterio.open(dem) as a, rasterio.open(tmp_path / "hf.tif") as b:
        za, zb = a.read(1), b.read(1)
        assert b.crs == a.crs and b.transform == a.transform and b.nodata == a.nodata
        gx, gy = np.meshgrid(X0 + np.arange(100) + 0.5, Y0 + 100 - (np.arange(100) + 0.5))
        lake = shapely.contains_xy(LAKE, gx, gy)
        assert lake.sum() == 750 and np.all(zb[lake] == np.float32(101.3))
        np.testing.assert_array_equal(zb[~lake], za[~lake])          # the river, the terrain and the nodata


def test_the_level_is_the_shore_where_the_water_returns_lie_above_it_or_are_not_given(tmp_path):
    # a shore at one level: a lake (on the sloping terrain of the other tests its shore falls 1.5 m along it)
    dem = _dem(tmp_path / "dem.tif", slope=0.0)
    with rasterio.open(dem) as src:
        z = src.read(1)
        gx, gy = np.meshgrid(X0 + np.arange(100) + 0.5, Y0 + 100 - (np.arange(100) + 0.5))
        grown = shapely.contains_xy(LAKE.buffer(2.0, join_style="mitre"), gx, gy)
        shore = grown & ~shapely.contains_xy(LAKE, gx, gy)
        want = np.float32(np.percentile(z[shore].astype(float), 5.0))
    for name, water_z in (("above", [103.0]), ("none", None)):
        water = _water(tmp_path / f"{name}.gpkg", [LAKE], water_z=water_z)
        out = tmp_path / f"{name}.tif"
        r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(out), "--water", str(water)])
        assert r.exit_code == 0, r.output
        with rasterio.open(out) as b:
            lake = shapely.contains_xy(LAKE, gx, gy)
            assert np.allclose(b.read(1)[lake], want, atol=1e-4), name


def test_an_outline_without_water_returns_whose_shore_falls_is_left(tmp_path):
    """Trial-hydro: a hand-digitised river (no water_z, no water_z_range_m) was flattened at its lowest shore, the
    channel cut up to 3.1 m. Without the water returns' range the shore tells a river: its thirds' low heights fall by
    more than --max-range-m along it; the outline on the sloping terrain (1.5 m along the lake) is left, and the same
    outline given the returns' range is judged by them."""
    dem = _dem(tmp_path / "dem.tif")
    for name, kw, left in (("digitised", {}, True), ("returns", dict(water_z=[101.3], ranges=[0.08]), False)):
        water = _water(tmp_path / f"{name}.gpkg", [LAKE], **kw)
        r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(tmp_path / f"{name}.tif"), "--water", str(water)])
        assert r.exit_code == 0, r.output
        said = "its shore's low heights fall 1." in r.output and "flowing water, left as it is" in r.output
        assert said is left and ("0 of 1 water bodies flattened" in r.output) is left, (name, r.output)
    r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(tmp_path / "wide.tif"), "--water",
                                  str(tmp_path / "digitised.gpkg"), "--max-range-m", "2"])
    assert r.exit_code == 0 and "1 of 1 water bodies flattened" in r.output, r.output
    # smoothing a flattened DEM moves its flat water again (trial-hydro: 0.5 m contours inside the lakes): said
    r = CliRunner().invoke(main, ["smooth", str(tmp_path / "wide.tif"), str(tmp_path / "wide_s.tif")])
    assert r.exit_code == 0 and "is hydro-flattened" in r.output and "smooth first, then hydro-flatten" in r.output
    with rasterio.open(tmp_path / "wide_s.tif") as ds:
        assert "HYDRO_FLATTENED" not in ds.tags()


def test_a_layer_not_named_water_is_taken_only_when_named_and_feet_are_said(tmp_path):
    """Trial: the BGT building footprints given as --water (one layer, 'pand') were "138 of 160 water bodies
    flattened"; Autzen's levels in feet were printed "at 407.37 m"."""
    dem = _dem(tmp_path / "dem.tif", crs="EPSG:2994")
    meta_crs = "EPSG:2994"
    pand = tmp_path / "pand.gpkg"
    write(pand, np.array(shapely.to_wkb(np.array([LAKE], dtype=object)), dtype=object), field_data=[np.arange(1)],
          fields=["id"], geometry_type="Polygon", crs=pyproj.CRS(meta_crs).to_wkt(), driver="GPKG", layer="pand")
    r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(tmp_path / "a.tif"), "--water", str(pand)])
    assert r.exit_code == 2 and "'pand' is not named water and has no water_z field" in r.output
    assert "--water-layer pand" in r.output and not (tmp_path / "a.tif").exists()
    r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(tmp_path / "a.tif"), "--water", str(pand),
                                  "--water-layer", "pand"])
    assert r.exit_code == 0, r.output
    assert "1 of 1 water bodies flattened" in r.output and " ft (shore " in r.output


@pytest.mark.parametrize("case", ["other_crs", "missing", "out_is_dem", "no_polygons"])
def test_hydro_flatten_bad_input_exit_2_nothing_written(tmp_path, case):
    dem = _dem(tmp_path / "dem.tif")
    out = tmp_path / "hf.tif"
    water = tmp_path / "w.gpkg"
    if case == "other_crs":
        _water(water, [box(5.0, 50.0, 5.1, 50.1)], crs="EPSG:4326")
        want = "EPSG:4326"
    elif case == "missing":
        want = "no such file"
    elif case == "out_is_dem":
        _water(water, [LAKE])
        out = dem
        want = "OUT"
    else:
        write(water, np.array(shapely.to_wkb(np.array([shapely.Point(X0, Y0)], dtype=object)), dtype=object),
              field_data=[np.arange(1)], fields=["id"], geometry_type="Point",
              crs=pyproj.CRS("EPSG:32632").to_wkt(), driver="GPKG", layer="water")
        want = "no polygons"
    before = sorted(p.name for p in tmp_path.iterdir())
    stamp = dem.stat().st_mtime_ns
    r = CliRunner().invoke(main, ["hydro-flatten", str(dem), str(out), "--water", str(water)])
    assert r.exit_code == 2, r.output
    assert want in r.output and "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before and dem.stat().st_mtime_ns == stamp
