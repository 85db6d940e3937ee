"""Frames read by windows (full-size DMC frames: 106 MP, 12-bit in 16-bit ZSTD tiles): the pyramid level of the
feature detection and the measuring chips equal the whole-frame readers' for 8-bit frames; 12-bit samples span
the 8-bit range."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import rasterio

from aerotri.core.errors import InputError
from aerotri.geom.images import FrameWindows, downsample, read_gray, read_gray_level, read_rgb8

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")


def _texture(h, w, bands, seed=3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 256, (h, w, bands)).astype(np.uint8)
    return cv2.GaussianBlur(a, (0, 0), 1.5).reshape(h, w, bands)


def _write(path, a: np.ndarray, **kw) -> None:
    bands = a.shape[2]
    with rasterio.open(path, "w", driver="GTiff", width=a.shape[1], height=a.shape[0], count=bands,
                       dtype=a.dtype.name, **({"photometric": "RGB"} if bands == 3 else {}), **kw) as dst:
        dst.write(np.moveaxis(a, -1, 0))


@pytest.mark.parametrize("bands", [1, 3])
@pytest.mark.parametrize("h,w", [(203, 157), (256, 320)])
def test_level_by_bands_equals_whole_frame_8bit(tmp_path, bands, h, w):
    path = tmp_path / "f.tif"
    _write(path, _texture(h, w, bands), tiled=True, blockxsize=32, blockysize=32, compress="deflate")
    for level in (0, 1, 3):
        for band_rows in (16, 40, 4096):
            got = read_gray_level(path, level, (w, h), band_rows=band_rows)
            assert np.array_equal(got, downsample(read_gray(path), level))


def test_level_12bit_spans_8bit_range(tmp_path):
    rng = np.random.default_rng(1)
    img = (cv2.GaussianBlur(rng.random((300, 260)).astype(np.float32), (0, 0), 2) * 4095 / 0.6).clip(0, 4095)
    img = img.astype(np.uint16)[:, :, None]
    path = tmp_path / "f.tif"
    _write(path, img, tiled=True, blockxsize=64, blockysize=64, compress="zstd")
    full = downsample(img[:, :, 0].astype(np.float32), 2)
    expect = np.clip(np.rint(full * 255 / 4095), 0, 255).astype(np.uint8)
    for band_rows in (16, 1000):
        assert np.array_equal(read_gray_level(path, 2, band_rows=band_rows), expect)
    with pytest.raises(InputError, match="camera says"):
        read_gray_level(path, 2, (100, 100))


@pytest.mark.parametrize("bands", [1, 3])
def test_frame_windows_equal_read_rgb8_8bit(tmp_path, bands):
    a = _texture(90, 120, bands)
    path = tmp_path / "f.tif"
    _write(path, a, tiled=True, blockxsize=32, blockysize=32)
    whole = read_rgb8(path)
    with FrameWindows(path, (120, 90)) as fw:
        assert fw.shape == whole.shape
        for key in [(slice(0, 10), slice(5, 40)), (slice(80, 200), slice(100, 130)), (slice(30, 31), slice(0, 120))]:
            assert np.array_equal(fw[key], whole[key])
        assert np.array_equal(np.atleast_3d(fw[10:20, 10:20]), np.atleast_3d(whole)[10:20, 10:20])


def test_frame_windows_12bit(tmp_path):
    a = (np.arange(64 * 64).reshape(64, 64, 1) % 4096).astype(np.uint16)
    path = tmp_path / "f.tif"
    _write(path, a, compress="zstd")
    with FrameWindows(path) as fw:
        assert np.array_equal(fw[0:64, 0:64], np.rint(a[:, :, 0].astype(float) * 255 / 4095).astype(np.uint8))


def test_zstd_frames_go_straight_to_gdal(tmp_path, capfd):
    """OpenCV's libtiff cannot decode ZSTD: the readers take GDAL at once (no OpenCV ERROR lines), same pixels."""
    a = (np.arange(40 * 56).reshape(40, 56, 1) % 4096).astype(np.uint16)
    path = tmp_path / "f.tif"
    _write(path, a, tiled=True, blockxsize=16, blockysize=16, compress="zstd")
    from aerotri.geom.images import read_native

    img, order = read_native(path, (56, 40))
    assert np.array_equal(img, a[:, :, 0]) and order == [1]
    assert read_gray(path).shape == (40, 56)
    assert "TIFF_Error" not in capfd.readouterr().err
