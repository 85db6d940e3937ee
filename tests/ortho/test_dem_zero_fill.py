"""A DEM whose fill is 0 without a declared nodata value (gdalwarp's output beyond its source, a clipped DEM):
``ortho rectify`` warns, naming the DEM, the share and how to declare it (new-user trial 2026-12-01, ortho operator:
the NGI DEM with its eastern 30 % at 0 and no nodata gave frame orthos standing on height 0 there, 400 m below the
terrain, with no word). A DEM with ground at sea level (a coast: heights running down to 0) is not warned of."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from aerotri.geom.crs.height_rasters import ZERO_FILL_GAP_M, undeclared_fill
from ortho.cli import main
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("zero_fill") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=0, seed=3)
    return root


def _dem(src, dst, east_share: float, nodata=None, offset_m: float = 0.0, fill: float = 0.0):
    with rasterio.open(src) as ds:
        a, prof = ds.read(1), ds.profile
    a = a + np.float32(offset_m)
    a[:, int(a.shape[1] * (1 - east_share)):] = fill
    prof.update(nodata=nodata)
    with rasterio.open(dst, "w", **prof) as out:
        out.write(a, 1)
    return dst


def test_undeclared_zero_fill(block, tmp_path):
    dem = block / "lidar_out/dem.tif"
    with rasterio.open(_dem(dem, tmp_path / "z.tif", 0.3)) as ds:
        f = undeclared_fill(ds)
    assert f.value == 0 and 0.25 < f.share < 0.35 and f.lo > ZERO_FILL_GAP_M and f.hi > f.lo
    with rasterio.open(_dem(dem, tmp_path / "nd.tif", 0.3, nodata=0.0)) as ds:  # declared: nodata, no fill
        assert undeclared_fill(ds) is None
    with rasterio.open(dem) as ds:  # no zero at all
        assert undeclared_fill(ds) is None
    # a coast: the land runs down to the sea's 0 (the lowest other heights within the gap): ground, not fill
    with rasterio.open(dem) as ds:
        base = float(ds.read(1).min())
    with rasterio.open(_dem(dem, tmp_path / "coast.tif", 0.3, offset_m=-base + 0.5)) as ds:
        assert undeclared_fill(ds) is None


def test_rectify_warns_of_a_zero_fill(block, tmp_path):
    root = tmp_path / "p"
    shutil.copytree(block, root)
    dem = _dem(block / "lidar_out/dem.tif", tmp_path / "dem_zero.tif", 0.3)
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(dem)])
    assert r.exit_code == 0, r.output
    assert f"{dem}: " in r.stderr and "hold exactly 0" in r.stderr and "-a_nodata 0" in r.stderr, r.stderr
    r = CliRunner().invoke(main, ["rectify", str(root)])  # the block's own DEM: no such warning
    assert r.exit_code == 0, r.output
    assert "hold exactly 0" not in r.stderr


def test_an_undeclared_negative_fill_is_warned_of(block, tmp_path):
    """review 28: -999 (within -1000 .. 10000 m, so not refused) was neither refused nor warned of; -9999 is refused."""
    dem = block / "lidar_out/dem.tif"
    with rasterio.open(_dem(dem, tmp_path / "m999.tif", 0.3, fill=-999.0)) as ds:
        f = undeclared_fill(ds)
    assert f.value == -999.0 and 0.25 < f.share < 0.35 and f.lo > 0
    with rasterio.open(_dem(dem, tmp_path / "m998.tif", 0.3, fill=-998.0)) as ds:  # not a fill value: ground
        assert undeclared_fill(ds) is None
    with rasterio.open(_dem(dem, tmp_path / "m999nd.tif", 0.3, fill=-999.0, nodata=-999.0)) as ds:  # declared
        assert undeclared_fill(ds) is None
    root = tmp_path / "p"
    shutil.copytree(block, root)
    r = CliRunner().invoke(main, ["rectify", str(root), "--dem", str(tmp_path / "m999.tif")])
    assert r.exit_code == 0, r.output
    assert "hold exactly -999 while" in r.stderr and "-a_nodata -999" in r.stderr, r.stderr
