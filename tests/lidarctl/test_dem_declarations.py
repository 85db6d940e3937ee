"""What a DEM says of itself, read by lidarctl's terrain commands as ortho reads it (trial s99 lidmut): a nodata fill it
does not declare (-999 over a 310-370 m block gave 806 contours from -995 m, a drainage fill raising cells 1,312 m and
a check-heights RMSE of 594 m, exit 0, where ``ortho rectify`` warned), and heights in metres under a grid in feet
(contoured as feet, elevation_m 95 for 311.7 m, no word)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_origin

from lidarctl.cli.main import main

X0, Y0 = 452000.0, 3407400.0


def _dem(path, *, fill=None, nodata=None, crs="EPSG:32649", tags=None):
    """A 120 x 100 cell DEM of 1 m cells, a hill 310-340 m; ``fill``: the value of its eastern fifth (undeclared
    unless ``nodata``)."""
    rows, cols = np.mgrid[0:100, 0:120] + 0.5
    z = 310.0 + 30.0 * np.exp(-((rows - 50.0) ** 2 + (cols - 50.0) ** 2) / 800.0)
    if fill is not None:
        z[:, 96:] = fill
    with rasterio.open(path, "w", driver="GTiff", width=120, height=100, count=1, dtype="float32", crs=crs,
                       transform=from_origin(X0, Y0, 1.0, 1.0), nodata=nodata) as d:
        d.write(z.astype("float32"), 1)
        if tags:
            d.update_tags(**tags)
    return path


@pytest.mark.parametrize("fill, command", [(-999.0, "contours"), (-999.0, "drainage"), (-999.0, "smooth"),
                                           (-999.0, "check-heights"), (-99.0, "contours"), (0.0, "contours"),
                                           (0.0, "check-heights")])
def test_an_undeclared_fill_is_refused_naming_the_dem_and_how_to_declare_it(tmp_path, fill, command):
    dem = _dem(tmp_path / "dem.tif", fill=fill)
    out = tmp_path / "out"
    args = {"contours": ["contours", dem, f"{out}.gpkg", "--interval-m", "5"],
            "drainage": ["drainage", dem, out],
            "smooth": ["smooth", dem, f"{out}.tif"],
            "check-heights": ["check-heights", _points(tmp_path / "p.csv"), "--dem", dem]}[command]
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"{dem}: 20.0 % of the DEM's cells hold exactly {fill:g}" in r.output, r.output
    assert f"-a_nodata {fill:g} {dem}" in r.output
    assert not list(tmp_path.glob("out*"))
    # declared, the same cells are nodata and the command runs
    dem2 = _dem(tmp_path / "declared.tif", fill=fill, nodata=fill)
    args = [str(a).replace(str(dem), str(dem2)) for a in args]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output


def test_ground_at_zero_beside_land_is_read_when_the_dem_declares_its_own_nodata(tmp_path):
    """A cliff coast: the sea at 0, the land above 10 m. Declaring the value the DEM does use for nodata (any) is the
    way to say the zeros are heights: the 0 m contour is drawn."""
    from pyogrio.raw import read

    dem = _dem(tmp_path / "coast.tif", fill=0.0, nodata=-32768.0)
    r = CliRunner().invoke(main, ["contours", str(dem), str(tmp_path / "c.gpkg"), "--interval-m", "10", "--no-png"])
    assert r.exit_code == 0, r.output
    meta, _, _, fields = read(tmp_path / "c.gpkg", layer="contours")
    assert 0.0 in set(fields[list(meta["fields"]).index("elevation")])


def _points(path):
    path.write_text("id,x,y,z\n" + "\n".join(f"P{k},{X0 + 10 + 9 * k},{Y0 - 50},{315.0}" for k in range(8)) + "\n")
    return path


@pytest.mark.parametrize("command", ["contours", "drainage", "smooth"])
def test_heights_taken_in_feet_from_the_grid_are_said_and_a_tag_settles_them(tmp_path, command, caplog):
    """EPSG:2992 (Oregon Lambert, international feet) without a vertical unit: the heights are taken in feet, as LAS
    has it, and said; a VERTICAL_UNITS tag settles it without a word."""
    import logging

    caplog.set_level(logging.WARNING)
    for tags, said in ((None, True), ({"VERTICAL_UNITS": "metre"}, False), ({"VERTICAL_UNITS": "foot"}, False)):
        caplog.clear()
        dem = _dem(tmp_path / f"dem_{said}_{bool(tags)}.tif", crs="EPSG:2992", tags=tags)
        out = tmp_path / f"out_{said}_{tags and tags['VERTICAL_UNITS']}"
        args = {"contours": ["contours", dem, f"{out}.gpkg", "--interval-m", "3.048", "--no-png"],
                "drainage": ["drainage", dem, out], "smooth": ["smooth", dem, f"{out}.tif"]}[command]
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 0, r.output
        text = caplog.text + r.output
        assert ("declares no vertical unit" in text and "gdal_edit.py -mo VERTICAL_UNITS=metre" in text) == said, text


def test_an_integer_dem_in_centimetres_is_asked_about_its_unit(tmp_path):
    """trial s99 lidmut L3: 31,000 (310 m in cm, int32) was refused as "an undeclared nodata value?" alone."""
    path = tmp_path / "cm.tif"
    with rasterio.open(path, "w", driver="GTiff", width=20, height=20, count=1, dtype="int32", crs="EPSG:32649",
                       transform=from_origin(X0, Y0, 1.0, 1.0)) as d:
        d.write(np.full((20, 20), 31000, np.int32), 1)
    r = CliRunner().invoke(main, ["contours", str(path), str(tmp_path / "c.gpkg"), "--interval-m", "1"])
    assert r.exit_code == 2 and "heights in centimetres or millimetres" in r.output, r.output


def test_contours_of_a_chm_say_they_are_not_of_the_terrain(tmp_path, caplog):
    """trial s99 lidmut M6: chm.tif contoured into 452 canopy lines as if terrain, no word."""
    import logging

    caplog.set_level(logging.WARNING)
    path = _dem(tmp_path / "chm.tif")
    with rasterio.open(path, "r+") as d:
        d.set_band_description(1, "CHM: vegetation height above the ground (m)")
    r = CliRunner().invoke(main, ["contours", str(path), str(tmp_path / "c.gpkg"), "--interval-m", "5", "--no-png"])
    assert r.exit_code == 0, r.output
    assert "holds heights above the ground" in caplog.text + r.output
