"""The height scan (``aerotri.geom.inputs.check_height_values``) reads float bands without GDAL's mask where that mask
is the nodata value (``_scan_plain``): it must find what the masked read finds, cell for cell, and raise the same
errors (truth: the masked read, forced by ``_plain_nodata`` -> False)."""

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from aerotri.core.errors import InputError
from aerotri.geom import inputs


def _raster(path, a, nodata, dtype="float32", mask=None):
    profile = dict(driver="GTiff", width=a.shape[1], height=a.shape[0], count=1, dtype=dtype, crs="EPSG:32649",
                   transform=Affine(1.0, 0.0, 450000.0, 0.0, -1.0, 3400000.0), nodata=nodata)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(a.astype(dtype), 1)
        if mask is not None:
            ds.write_mask(mask.astype(np.uint8) * 255)
    return path


def _both(path, monkeypatch):
    """(plain, masked): the scan's result or its error message, each way."""
    out = []
    for plain in (True, False):
        inputs._scanned.clear()
        with monkeypatch.context() as m:
            if not plain:
                m.setattr(inputs, "_plain_nodata", lambda ds, band: False)
            with rasterio.open(path) as ds:
                try:
                    out.append(inputs.check_height_values(ds, path, "DEM"))
                except InputError as exc:
                    out.append(str(exc))
    inputs._scanned.clear()
    return out


def _heights(seed=5, shape=(300, 257)):
    return np.random.default_rng(seed).uniform(-20.0, 900.0, shape).astype(np.float32)


@pytest.mark.parametrize("case", ["nodata_out_of_range", "nodata_near", "nodata_in_range", "nodata_in_range_near",
                                  "nodata_zero", "no_nodata_nan", "nodata_nan", "all_nodata", "inf", "too_high",
                                  "float64", "int16", "internal_mask"])
def test_plain_scan_finds_what_the_masked_scan_finds(tmp_path, monkeypatch, case):
    a = _heights()
    a[10:40, 5:60] = -9999.0
    a[100, 100] = np.nan
    nodata, dtype, mask = -9999.0, "float32", None
    if case == "nodata_near":  # within GDAL's tolerance of the nodata value, not equal to it
        a[50, 50] = np.nextafter(np.float32(-9999.0), np.float32(0))
        a[51, 51] = np.nextafter(np.float32(-9999.0), np.float32(-1e9))
    elif case == "nodata_in_range":
        nodata = 5.0
        a[200:210, :] = 5.0
        a[10:40, 5:60] = 7.0
    elif case == "nodata_in_range_near":
        nodata = 5.0
        a[200:210, :] = 5.0
        a[211, 3] = np.nextafter(np.float32(5.0), np.float32(6.0))
        a[10:40, 5:60] = 7.0
    elif case == "nodata_zero":
        nodata = 0.0
        a[200:210, :] = 0.0
        a[10:40, 5:60] = 1.0
    elif case == "no_nodata_nan":
        nodata = None
        a[10:40, 5:60] = np.nan
    elif case == "nodata_nan":
        nodata = float("nan")
        a[10:40, 5:60] = np.nan
    elif case == "all_nodata":
        a[:] = -9999.0
    elif case == "inf":
        a[120, 7] = np.inf
    elif case == "too_high":
        a[250, 200] = 20000.0
    elif case == "float64":
        dtype = "float64"
    elif case == "int16":
        a = np.nan_to_num(a, nan=-9999.0)
        dtype = "int16"
    elif case == "internal_mask":
        nodata = None
        a[10:40, 5:60] = 50000.0  # out of range, but masked by the internal mask
        mask = np.ones(a.shape, bool)
        mask[10:40, 5:60] = False
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        path = _raster(tmp_path / f"{case}.tif", a, nodata, dtype, mask)
    plain, masked = _both(path, monkeypatch)
    assert plain == masked
    if case in ("inf", "too_high", "all_nodata"):
        assert isinstance(plain, str)
    else:
        assert plain.valid_cells > 0


def test_plain_scan_by_blocks_of_rows(tmp_path, monkeypatch):
    """Blocks of a few rows (as a large raster is read): the same totals, and a bad cell in a later block named
    by its row."""
    a = _heights(seed=9, shape=(97, 61))
    a[:30] = -9999.0
    path = _raster(tmp_path / "blocks.tif", a, -9999.0)
    monkeypatch.setattr(inputs, "_SCAN_CELLS", 61 * 7)
    plain, masked = _both(path, monkeypatch)
    assert plain == masked and plain.valid_cells == 67 * 61
    a[90, 13] = -5000.0
    path = _raster(tmp_path / "blocks_bad.tif", a, -9999.0)
    plain, masked = _both(path, monkeypatch)
    assert plain == masked and "(row 90, column 13)" in plain
