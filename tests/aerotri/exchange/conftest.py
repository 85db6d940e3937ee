"""The adjusted tiny block every exchange test exports from: a small geometric block with known truth
(``aerotri.sim.observations.geometric_block``), adjusted with self-calibration (principal point, radial),
so exports read an adjusted project folder and its self-calibrated camera."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from aerotri.adjust.pipeline import AdjustSettings, run_adjustment
from aerotri.core.errors import StageOrderError
from aerotri.exchange.adjusted import read_adjusted_block
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations

SIGMA_PX = 0.3


@pytest.fixture(scope="session")
def adjusted_tiny(tmp_path_factory):
    """(project root, the adjustment's result); treat the folder as read-only."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path_factory.mktemp("exp") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=5, points_per_image=80, n_check=4, seed=2)
    with pytest.raises(StageOrderError):
        read_adjusted_block(root)
    ba = run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX,
                                                self_calibration=("pp", "radial"))).adjustment
    return root, ba


@pytest.fixture
def fresh_project():
    """``fresh_project(src, dst)``: an empty project folder ``dst`` with the project.toml (CRS, heights) of
    ``src``."""

    def make(src, dst):
        dst.mkdir(parents=True)
        shutil.copy(src / "project.toml", dst / "project.toml")
        return dst

    return make


@pytest.fixture(scope="session")
def adjusted_with_rejections(tmp_path_factory):
    """(project root, the adjustment's result) of a tiny block whose control point gcp01 is shifted 3 m (the
    adjustment rejects it) and one measurement of gcp03 is 40 px off (data snooping removes it)."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path_factory.mktemp("rej") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=6, points_per_image=80, n_check=4, seed=2,
                             bad_control_shift_m=3.0)
    path = root / "control" / "image_points.csv"
    head, *rows = path.read_text().splitlines()
    k = next(n for n, r in enumerate(rows) if r.startswith("gcp03,"))
    f = rows[k].split(",")
    f[2] = f"{float(f[2]) + 40.0:.3f}"
    rows[k] = ",".join(f)
    path.write_text("\n".join([head] + rows) + "\n")
    ba = run_adjustment(root, AdjustSettings(gnss_correction="shift", image_sigma_px=SIGMA_PX)).adjustment
    return root, ba


@pytest.fixture(scope="session")
def adjusted_without_control(tmp_path_factory):
    """(project root, the adjustment's result) of a tiny block with GNSS and no control/ folder at all."""
    block = geometric_block(2, 5, seed=7)
    root = write_block_project(block, tmp_path_factory.mktemp("noctl") / "blk")
    write_truth_observations(root, tie_sigma_px=SIGMA_PX, n_control=0, points_per_image=80, n_check=0, seed=2)
    shutil.rmtree(root / "control")
    ba = run_adjustment(root, AdjustSettings(gnss_correction="none", image_sigma_px=SIGMA_PX)).adjustment
    return root, ba


@pytest.fixture
def synthetic_geoid(tmp_path):
    """A made-up EGM2008 grid under EGM2008's file name (N = 30 m + 0.5 m per degree east of 110 E + 0.3 m per degree
    north of 30 N over 100-120 E, 20-40 N: linear, so PROJ's bilinear reading of it is exact) in a PROJ data folder
    of this test only; the function N(lon_deg, lat_deg)."""
    import pyproj
    import rasterio
    from rasterio.transform import from_origin

    from aerotri.geom.crs import transform as crs_transform

    def N(lon_deg, lat_deg):
        return 30.0 + 0.5 * (np.asarray(lon_deg) - 110.0) + 0.3 * (np.asarray(lat_deg) - 30.0)

    step = 0.25
    lon, lat = 100.0 + step * np.arange(81), 40.0 - step * np.arange(81)
    with rasterio.open(tmp_path / "us_nga_egm08_25.tif", "w", driver="GTiff", width=81, height=81, count=1,
                       dtype="float32", crs="EPSG:4326", transform=from_origin(100 - step / 2, 40 + step / 2, step, step)
                       ) as ds:
        ds.write(N(lon[None, :], lat[:, None]).astype("float32"), 1)
    before = pyproj.datadir.get_data_dir()
    pyproj.datadir.append_data_dir(str(tmp_path))
    _seat_datum_ensembles()
    crs_transform._group.cache_clear()  # PROJ's operations were looked up without the grid
    try:
        yield N
    finally:
        pyproj.datadir.set_data_dir(before)
        _seat_datum_ensembles()
        crs_transform._group.cache_clear()


def _seat_datum_ensembles():
    """Right after ``pyproj.datadir`` renewed this thread's PROJ context (empty caches): WGS 84 and ETRS89 from the
    database, so that its cache holds their datum ensembles before anything turns one into a plain datum. Else a CRS
    object made before the renewal (``parse_crs``'s cache keeps them) and identified after it caches the plain datum
    first, and every WGS 84 CRS the worker makes afterwards has it: other WKT (the simulator's LAS files, CI 64 and 65)
    and a realization no longer compared as a member of the ensemble (test_datums_of_h_are_compared_by_what_proj_
    knows_of_them failed after test_exif.py -k "synthetic or a_2d or take_off" in one process)."""
    import pyproj

    pyproj.CRS.from_epsg(4326)
    pyproj.CRS.from_epsg(4258)
