"""``ortho rectify`` on a height raster that is not what it is given as (trial s99 lidmut): lidarctl rasters' ndsm.tif
as the DEM (accepted, frames 8-16 m off, exit 0), a DEM whose VERTICAL_UNITS tag states feet under a 2D metric CRS
(read as metres: "projection centres are below the DEM" naming no file, or frames off under exit 0). Refused, naming
the file and what to do; nothing written."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("dem_declarations") / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=4, seed=5)
    return root


def _variant(src, dst, *, scale=1.0, description=None, tags=None):
    with rasterio.open(src) as ds:
        a, prof = ds.read(1), ds.profile
    with rasterio.open(dst, "w", **prof) as out:
        out.write((a * np.float32(scale)).astype(a.dtype), 1)
        if description:
            out.set_band_description(1, description)
        if tags:
            out.update_tags(**tags)
    return dst


@pytest.mark.parametrize("case", ["ndsm", "feet_tag", "feet_untagged"])
def test_a_height_raster_that_is_not_the_terrain_in_the_crs_unit_is_refused(block, tmp_path, case):
    root = tmp_path / "p"
    shutil.copytree(block, root, ignore=shutil.ignore_patterns("ortho"))
    dem = root / "lidar_out" / "dem.tif"
    if case == "ndsm":
        given = _variant(dem, tmp_path / "ndsm.tif", scale=0.0, description="nDSM: heights above the ground (m)")
        said = f"{given}: holds heights above the ground (its band description 'nDSM: heights above the ground (m)')"
    elif case == "feet_tag":  # the file states feet (what check-heights asks a user to add), its CRS is 2D metres
        given = _variant(dem, tmp_path / "dem_ft.tif", scale=1 / 0.3048, tags={"VERTICAL_UNITS": "foot"})
        said = f"{given}: states its height unit as foot"
    else:  # nothing said: the centres come out below it, and the message names the file and the likely causes
        given = _variant(dem, tmp_path / "dem_ft.tif", scale=1 / 0.3048 + 2.0)
        said = f"{given}: the projection centres lie below it"
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(given)])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert said in r.output, r.output
    if case == "feet_tag":
        assert "gdal_calc.py" in r.output and "A*0.3048" in r.output
    if case == "feet_untagged":
        assert "feet as metres?" in r.output
    assert not (root / "ortho" / "frames").exists()
    # the same DEM stated in metres is rectified on
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(_variant(dem, tmp_path / "m.tif",
                                                                               tags={"VERTICAL_UNITS": "metre"}))])
    assert r.exit_code == 0, r.output


def test_a_dem_tagged_with_the_other_foot_is_read(block, tmp_path):
    """The international and the US survey foot differ by 2 ppm: a State Plane DEM (US survey feet) tagged "foot" is
    not refused as "another unit" (regression trial s99: the message asked to multiply its heights by 1.000002)."""
    from ortho.dem import refuse_stated_height_unit

    path = tmp_path / "ft.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32", crs="EPSG:2994",
                       transform=rasterio.transform.from_origin(0, 100, 3, 3)) as d:
        d.write(np.full((4, 4), 300.0, np.float32), 1)
        d.update_tags(VERTICAL_UNITS="US survey foot")
    with rasterio.open(path) as ds:
        refuse_stated_height_unit(ds, path)  # EPSG:2994 is in international feet
