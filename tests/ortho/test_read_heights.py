"""``ortho.dem.read_heights`` (the height windows the rectifier reads a frame): NaN wherever GDAL's mask says nodata,
as ``read(masked=True)`` filled with NaN, for every kind of height raster a user hands in."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin
from rasterio.windows import Window

from ortho.dem import read_heights


def _raster(path, dtype, nodata, *, internal_mask=False):
    rng = np.random.default_rng(5)
    z = rng.normal(30.0, 10.0, (64, 80))
    if np.dtype(dtype).kind in "iu":
        z = np.clip(z, 1, 120)
    a = z.astype(dtype)
    if nodata is not None:
        with np.errstate(over="ignore", invalid="ignore"):
            a[rng.random(a.shape) < 0.2] = np.asarray(nodata).astype(dtype)
    if np.dtype(dtype).kind == "f":
        a[3, 4] = np.nan  # NaN heights where nodata is a value: NaN whatever the mask
    profile = dict(driver="GTiff", width=80, height=64, count=1, dtype=dtype, crs="EPSG:32649",
                   transform=from_origin(500000.0, 3000000.0, 0.5, 0.5), tiled=True, blockxsize=32, blockysize=32)
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(a, 1)
        if internal_mask:
            m = np.full(a.shape, 255, np.uint8)
            m[10:20, 30:50] = 0
            ds.write_mask(m)
    return path


@pytest.mark.parametrize("dtype, nodata, internal_mask", [
    ("float32", -9999.0, False), ("float32", float("nan"), False), ("float32", None, False),
    ("float64", -32767.0, False), ("float32", -3.4028234663852886e38, False),
    ("float32", 0.1, False),  # not exact in float32: GDAL compares in the band's type
    ("int16", -32768, False), ("uint16", 0, False), ("float32", None, True), ("float32", -9999.0, True)])
def test_the_heights_read_are_nan_where_gdals_mask_says_nodata(tmp_path, dtype, nodata, internal_mask):
    path = _raster(tmp_path / "h.tif", dtype, nodata, internal_mask=internal_mask)
    with rasterio.open(path) as ds:
        for window in (Window(0, 0, 80, 64), Window(7, 5, 41, 33)):
            expected = ds.read(1, window=window, masked=True).astype(np.float32).filled(np.nan)
            got = read_heights(ds, window)
            assert got.dtype == np.float32 and got.shape == expected.shape
            assert np.array_equal(got, expected, equal_nan=True), (dtype, nodata, internal_mask)
            if window.col_off == 0:  # the whole raster: its nodata cells, masked cells and NaN heights
                assert np.isnan(got).any() == (nodata is not None or internal_mask or dtype.startswith("float"))
