"""A true ortho's DSM standing off its DEM (a vertical datum offset: a photogrammetric DSM 1-3 m above the LiDAR DEM):
the ground flag (``ortho.rectify.ground_cells``: within ``GROUND_NDSM_M`` of the DEM) found almost no ground and the
occlusion test fell back to the columns unsaid (the slope masking lost). ``ortho.rectify.ground_flags`` tells it (the
1 m band of the nDSM's lowest quarter holding the most cells lies off 0) and ``ortho rectify`` warns once.
Truth: the synthetic block's exact DSM and DEM (``truth/``), the DSM moved by a known offset."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from ortho.dem import HeightRaster
from ortho.rectify import GROUND_NDSM_M, ground_flags
from tests.shared_builds import write_synthetic_project


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("stand_off") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=6, seed=5)
    with rasterio.open(root / "truth" / "dsm.tif") as ds:
        a, prof = ds.read(1).astype(np.float32), ds.profile
    prof.update(dtype="float32")
    for dz_m in (2.0, -1.5):
        with rasterio.open(root / f"dsm_{dz_m:+.1f}.tif", "w", **prof) as out:
            out.write(a + np.float32(dz_m), 1)
    return root


def _flags(root, dz_m):
    def read(name):
        with rasterio.open(root / name) as ds:
            return HeightRaster(ds.read(1).astype(np.float32), ds.bounds.left, ds.bounds.top, ds.res[0], ds.crs, name)

    dsm = read("truth/dsm.tif" if dz_m == 0 else f"dsm_{dz_m:+.1f}.tif")
    return ground_flags(dsm, read("truth/dem.tif"))


@pytest.mark.parametrize("dz_m", [0.0, 2.0, -1.5])
def test_ground_flags_find_the_dsms_offset_from_the_dem(block, dz_m):
    f = _flags(block, dz_m)
    assert f.level_m == pytest.approx(dz_m, abs=0.05)
    assert f.stands_off == (dz_m != 0.0)
    if dz_m:
        assert f.share < 0.01 and f.level_share > 0.5   # the ground is there, the flag misses it
    else:
        assert f.share > 0.5 and abs(f.level_m) < GROUND_NDSM_M


@pytest.mark.parametrize("dz_m", [0.0, 2.0])
def test_rectify_warns_once_when_the_dsm_stands_off_the_dem(block, dz_m):
    dsm = block / ("truth/dsm.tif" if dz_m == 0 else f"dsm_{dz_m:+.1f}.tif")
    r = CliRunner().invoke(main, ["rectify", str(block), "--dem", str(block / "truth" / "dem.tif"), "--true-ortho",
                                  "--dsm", str(dsm), "--frames", "s01_001,s01_002"])
    assert r.exit_code == 0, r.output
    if dz_m == 0.0:
        assert "stands" not in r.stderr, r.stderr
    else:
        assert r.stderr.count("stands 2.00 m above the DEM") == 1, r.stderr
        assert "2 of 2 frames" in r.stderr and "vertical datum offset" in r.stderr, r.stderr


@pytest.mark.parametrize("crop_m, spread_m", [(0.9, 0.1), (2.5, 0.3)])
def test_a_crop_over_most_of_a_frame_is_no_stand_off(crop_m, spread_m):
    """Review 37: wheat at 0.9 m or maize at 2.5 m over 86 % of a correct DSM formed a level off the DEM and was
    warned as a datum offset (following the advice would have moved every roof); the bare tracks between the fields
    lie below that level, which a datum offset leaves empty."""
    from rasterio.crs import CRS

    rng = np.random.default_rng(0)
    n = 1000
    yy, xx = np.mgrid[0:n, 0:n]
    dem = (100.0 + 0.02 * xx).astype(np.float32)
    field = (xx % 200 < 185) & (yy % 200 < 185)
    dsm = dem + np.where(field, crop_m + rng.normal(0, spread_m, (n, n)), 0.0) + rng.normal(0, 0.05, (n, n))
    crs = CRS.from_epsg(32631)
    flags = ground_flags(HeightRaster(dsm.astype(np.float32), 0, n, 1.0, crs, "dsm"),
                         HeightRaster(dem, 0, n, 1.0, crs, "dem"))
    assert flags.level_m > GROUND_NDSM_M and flags.below_share > 0.1
    assert not flags.stands_off
    moved = ground_flags(HeightRaster((dem + 2.0 + rng.normal(0, 0.05, (n, n))).astype(np.float32), 0, n, 1.0, crs,
                                      "dsm"), HeightRaster(dem, 0, n, 1.0, crs, "dem"))
    assert moved.stands_off and moved.below_share < 0.01
