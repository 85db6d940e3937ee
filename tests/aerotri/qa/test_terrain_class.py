"""The terrain class of the DEM beside the tolerance table's (trial-relief F4: a block with 420 m of relief, median
slope 23 deg, judged with the flat limits without a word)."""

import logging
import math

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from aerotri.core.project import Project
from aerotri.qa.report import _terrain_rows
from aerotri.qa.terrain_class import class_of_slope, dem_terrain


def _dem(path, slope_deg: float, cell: float = 1.0, n: int = 400, crs: str = "EPSG:32631", unit: float = 1.0,
         nodata_share: float = 0.0):
    """A plane rising ``slope_deg`` towards +x with 0.3 m of noise (cell in CRS units, heights in them too)."""
    rng = np.random.default_rng(5)
    x = np.arange(n) * cell * unit  # metres
    z = np.tile(x * math.tan(math.radians(slope_deg)), (n, 1)) + rng.normal(0, 0.3, (n, n))
    z = (z / unit).astype("float32")
    if nodata_share:
        z[: int(n * nodata_share)] = -9999.0
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs=crs,
                       transform=from_origin(500000, 5700000, cell, cell), nodata=-9999.0) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.parametrize("slope, expected", [(0.5, "flat"), (4.0, "hilly"), (20.0, "mountainous"),
                                             (35.0, "mountainous")])
def test_the_dem_slope_gives_the_class(tmp_path, slope, expected):
    got = dem_terrain(_dem(tmp_path / "dem.tif", slope, nodata_share=0.3))
    assert got.terrain == expected
    assert got.median_slope_deg == pytest.approx(slope, abs=0.3)
    assert got.cell_m == pytest.approx(10.0)


def test_a_feet_crs_gives_the_same_slope(tmp_path):
    """Cells and heights in US survey feet (EPSG:2992, Oregon Lambert ft): the slope is the metres one."""
    got = dem_terrain(_dem(tmp_path / "dem.tif", 8.0, cell=3.0, crs="EPSG:2992", unit=0.3048006096))
    assert got.terrain == "mountainous" and got.median_slope_deg == pytest.approx(8.0, abs=0.3)


def test_class_bounds():
    assert [class_of_slope(s) for s in (0.0, 1.99, 2.0, 5.99, 6.0, 60.0)] == [
        "flat", "flat", "hilly", "hilly", "mountainous", "mountainous"]


def _project(tmp_path, slope):
    root = tmp_path / "p"
    root.mkdir()
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32631"\n')
    _dem(root / "lidar_out" / "dem.tif", slope)
    return Project.open(root)


def test_a_mountain_block_under_the_flat_limits_is_said_and_warned(tmp_path, caplog):
    project = _project(tmp_path, 20.0)
    with caplog.at_level(logging.WARNING):
        (row,) = _terrain_rows(project, "flat")
    assert (row.id, row.value, row.verdict) == ("terrain_class_dem", "mountainous", None)
    assert "tighter limits" in row.note and "median slope 20.0 deg" in row.note
    assert any("the limits are tighter" in r.message for r in caplog.records)


def test_a_flat_block_under_the_mountainous_limits_fails(tmp_path):
    """The other way is the harmful one: looser limits than the terrain allows pass what fails."""
    (row,) = _terrain_rows(_project(tmp_path, 0.5), "mountainous")
    assert row.verdict == "fail" and 'set [qa] terrain = "flat"' in row.note
    # the class given with --terrain: the advice names the option (trial s96 F8: it named project.toml)
    (row,) = _terrain_rows(Project.open(tmp_path / "p"), "mountainous", given=True)
    assert row.note.endswith("looser than the terrain's: --terrain flat")


def test_the_same_class_is_said_and_no_table_class_no_row(tmp_path):
    project = _project(tmp_path, 4.0)
    (row,) = _terrain_rows(project, "hilly")
    assert row.verdict is None and row.value == "hilly" and "tighter" not in row.note
    assert _terrain_rows(project, None) == []  # an ASPRS table has no terrain class


def test_the_dem_the_adjustment_used_is_classed_without_lidar_out(tmp_path):
    """s95: the NGI block (630 m of relief) adjusted with `adjust --dem` had no lidar_out/dem.tif, and its report
    said "1:10000 flat" with no word: the adjustment's surface-control DEM is classed instead."""
    import json

    root = tmp_path / "p"
    (root / "at").mkdir(parents=True)
    (root / "project.toml").write_text('[project]\nname = "t"\ncrs = "EPSG:32631"\n')
    dem = _dem(tmp_path / "elsewhere" / "dem.tif", 22.0)
    (root / "at" / "report.json").write_text(json.dumps({"surface_control": {"dem": str(dem.resolve())}}))
    (row,) = _terrain_rows(Project.open(root), "flat")
    assert row.value == "mountainous" and "median slope 22.0 deg" in row.note and "dem.tif" in row.note


def test_a_dem_mostly_extended_beyond_its_points_gives_no_class(tmp_path, caplog):
    """Trial s100 rc F7: Tuniu's tie-point DEM (ortho dem), 89 % a flat continuation beyond its points, read "flat,
    median slope 0.0 deg" over 40 m of relief. Its tag says the share: the row says it is not measured and warns of
    nothing; at 40 % extended the class is measured as before."""
    project = _project(tmp_path, 0.5)
    for pct, measured in (("89.1", False), ("40.0", True)):
        with rasterio.open(project.root / "lidar_out" / "dem.tif", "r+") as ds:
            ds.update_tags(CELLS_EXTRAPOLATED_PERCENT=pct)
        with caplog.at_level(logging.WARNING):
            (row,) = _terrain_rows(project, "mountainous")
        if measured:
            assert row.verdict == "fail" and "median slope 0.5 deg" in row.note
        else:
            assert row.value is None and row.verdict is None and not caplog.records
            assert row.note.startswith("not measured: 89 % of dem.tif is a flat continuation beyond its tie points")
