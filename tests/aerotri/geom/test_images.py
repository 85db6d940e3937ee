"""Finding and reading frames: every layout production tools write gives the same pixels, in the stored grid."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import rasterio

from aerotri.core.errors import InputError
from aerotri.geom.images import (
    find_image, find_images, map_uncompressed_tiff, read_gray, read_native, read_rgb, read_rgb8,
)

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")  # frames have no georeferencing


def _rgb(dtype, h=37, w=53, bands=3, seed=5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, np.iinfo(dtype).max, (h, w, bands), dtype=dtype)


def _write(path, a: np.ndarray, **kw) -> None:
    """A TIFF through GDAL: (rows, cols, bands) in band order 1, 2, 3, ..."""
    bands = a.shape[2] if a.ndim == 3 else 1
    with rasterio.open(path, "w", driver="GTiff", width=a.shape[1], height=a.shape[0], count=bands,
                       dtype=a.dtype.name, **kw) as dst:
        dst.write(np.moveaxis(a, -1, 0) if a.ndim == 3 else a[None])


@pytest.mark.parametrize("bands,dtype", [(3, np.uint8), (1, np.uint16), (4, np.uint16)])
def test_uncompressed_frames_are_memory_mapped(tmp_path, bands, dtype):
    a = _rgb(dtype, bands=bands)
    a = a if bands > 1 else a[:, :, 0]
    path = tmp_path / "frame.tif"
    _write(path, a, interleave="pixel")
    m = map_uncompressed_tiff(path)
    assert isinstance(m, np.memmap) and m.shape == a.shape and np.array_equal(m, a)
    # compressed or tiled files are decoded instead
    for extra in (dict(compress="lzw"), dict(tiled=True, blockxsize=16, blockysize=16)):
        p2 = tmp_path / "other.tif"
        _write(p2, a, interleave="pixel", **extra)
        assert map_uncompressed_tiff(p2) is None


def test_a_truncated_uncompressed_frame_is_not_mapped_but_refused(tmp_path):
    path = tmp_path / "frame.tif"
    _write(path, _rgb(np.uint8), interleave="pixel")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert map_uncompressed_tiff(path) is None
    with pytest.raises(InputError, match="frame.tif: cannot read the image"):
        read_native(path)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("layout", ["lzw", "raw", "planar", "minisblack"])
def test_every_layout_reads_as_the_same_rgb(tmp_path, dtype, layout):
    """Pixel-interleaved RGB (OpenCV: B, G, R), uncompressed (memory-mapped: R, G, B), band-interleaved RGB and
    three samples tagged MINISBLACK (OpenCV garbles both: read through GDAL) give the same R, G, B and grey."""
    a = _rgb(dtype)
    ref = tmp_path / "ref.tif"
    _write(ref, a, interleave="pixel", photometric="RGB", compress="lzw")
    kw = {"lzw": dict(interleave="pixel", photometric="RGB", compress="lzw"),
          "raw": dict(interleave="pixel", photometric="RGB"),
          "planar": dict(interleave="band", photometric="RGB", compress="lzw"),
          "minisblack": dict(interleave="pixel", photometric="MINISBLACK", compress="lzw")}[layout]
    path = tmp_path / f"{layout}.tif"
    _write(path, a, **kw)
    native, order = read_native(path, (53, 37))
    assert sorted(order) == [1, 2, 3]
    assert np.array_equal(read_rgb(path), a)
    expect8 = a if dtype == np.uint8 else cv2.normalize(a, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    assert np.array_equal(read_rgb8(path), expect8)
    # grey as OpenCV decodes the pixel-interleaved RGB file
    assert np.array_equal(read_gray(path), cv2.imread(str(ref), cv2.IMREAD_GRAYSCALE))


def test_a_jpeg_ycbcr_tiff_reads_as_the_windowed_readers_decode_it(tmp_path, monkeypatch):
    """Review 28: OpenCV (libjpeg-turbo) and GDAL (IJG libjpeg 9) upsample a JPEG's 4:2:0 chroma differently; the
    readers of whole frames decoded a JPEG-YCbCr TIFF by OpenCV, those by windows by GDAL. Every reader now gives
    GDAL's pixels (read a band of rows at a time: a band of 32 rows here, the file's tiles)."""
    import aerotri.geom.images as images
    from aerotri.geom.images import FrameWindows, read_gray_level

    monkeypatch.setattr(images, "_GDAL_READ_ROWS", 40)
    a = cv2.GaussianBlur(_rgb(np.uint8, h=100, w=120), (0, 0), 1.5)
    path = tmp_path / "ycbcr.tif"
    _write(path, a, interleave="pixel", photometric="YCBCR", compress="jpeg", tiled=True, blockxsize=32,
           blockysize=32)
    with rasterio.open(path) as ds:
        gdal = np.moveaxis(ds.read(), 0, -1)
    assert (np.abs(cv2.imread(str(path))[:, :, ::-1].astype(int) - gdal).max(2) > 0).mean() > 0.05  # the two decoders
    native, order = read_native(path, (120, 100))
    assert order == [1, 2, 3] and native.flags.c_contiguous and np.array_equal(native, gdal)
    assert np.array_equal(read_rgb8(path), gdal)
    with FrameWindows(path) as frame:
        assert np.array_equal(frame[10:90, 7:111], gdal[10:90, 7:111])
    assert np.array_equal(read_gray(path), read_gray_level(path, 0))
    assert np.array_equal(read_gray_level(path, 1, band_rows=32), cv2.pyrDown(read_gray(path)))


def test_alpha_is_kept_in_rgb_and_dropped_in_rgb8(tmp_path):
    a = _rgb(np.uint8, bands=4)
    path = tmp_path / "rgba.png"
    cv2.imwrite(str(path), a[:, :, [2, 1, 0, 3]])
    native, order = read_native(path)
    assert order == [3, 2, 1, 4]
    assert np.array_equal(read_rgb(path), a)
    assert np.array_equal(read_rgb8(path), a[:, :, :3])


def test_exif_orientation_is_ignored(tmp_path):
    """A JPEG tagged 'rotate 90' is read in its stored grid (the size the headers and the camera give)."""
    from PIL import Image

    a = np.zeros((40, 64, 3), np.uint8)
    a[:10, :20] = 255  # a bright block at the stored top left
    path = tmp_path / "rot.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(a).save(path, exif=exif, quality=95)
    assert cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).shape == (64, 40)  # what OpenCV does by default
    g = read_gray(path, (64, 40))
    assert g.shape == (40, 64) and g[:10, :20].mean() > 200 and g[20:, 30:].mean() < 30
    assert read_rgb8(path, (64, 40)).shape == (40, 64, 3)


def test_size_and_readability_are_checked(tmp_path):
    path = tmp_path / "f.tif"
    _write(path, _rgb(np.uint8), interleave="pixel", photometric="RGB", compress="lzw")
    for reader in (read_native, read_rgb, read_rgb8, read_gray):
        with pytest.raises(InputError, match=r"f.tif: image is 53 x 37 px but the camera says 60 x 40 px"):
            reader(path, (60, 40))
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"II*\x00garbage")
    for reader in (read_native, read_rgb8, read_gray):
        with pytest.raises(InputError, match="bad.tif: cannot read the image"):
            reader(bad)


def test_frames_are_found_by_id(tmp_path):
    for name in ("a.tif", "b.JPG", "c.png", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    found = find_images(tmp_path)
    assert found.image_id == ("a", "b", "c") and found.path_of("b") == tmp_path / "b.JPG" and "c" in found
    assert found.select(["c", "a"]).path == (tmp_path / "c.png", tmp_path / "a.tif")
    assert (found.name_of("c"), found.name_of("zz")) == ("c.png", "zz")  # an exporter's shot name
    with pytest.raises(KeyError):
        found.select(["zz"])
    assert find_image(tmp_path, "b") == tmp_path / "b.JPG"
    with pytest.raises(InputError, match="no image file for image id 'd'"):
        find_image(tmp_path, "d")
    (tmp_path / "a.jpg").write_bytes(b"")
    with pytest.raises(InputError, match="two images share the id 'a'"):
        find_images(tmp_path)


def test_georeferenced_frames_read_without_opencv_tag_warnings(tmp_path, capfd):
    """A compressed GeoTIFF frame (decoded by OpenCV) reads without libtiff's "Unknown field with tag"
    warnings on stderr for the GeoTIFF tags (4-6 lines per read on the NGI DMC frames before)."""
    from rasterio.transform import from_origin

    rgb = np.random.default_rng(0).integers(0, 255, (3, 64, 48), dtype=np.uint8)
    path = tmp_path / "geo.tif"
    with rasterio.open(path, "w", driver="GTiff", width=48, height=64, count=3, dtype="uint8", crs="EPSG:32649",
                       transform=from_origin(500000, 4000000, 1, 1), photometric="RGB", compress="deflate") as ds:
        ds.write(rgb)
    capfd.readouterr()
    img, _ = read_native(path, (48, 64))
    gray = read_gray(path, (48, 64))
    assert img.shape == (64, 48, 3) and gray.shape == (64, 48)
    assert "TIFF_Warning" not in capfd.readouterr().err


@pytest.mark.parametrize("kw", [dict(tiled=True, blockxsize=64, blockysize=64, compress="zstd"), dict(compress="lzw")])
def test_a_frame_cut_short_after_its_header_is_refused_before_any_work(tmp_path, kw):
    """trial-overnight: a half-copied full-size DMC frame (tiled ZSTD, header first) opened and passed the check;
    the chain ran its LiDAR stages for minutes before a stage read the missing tiles."""
    from types import SimpleNamespace

    from aerotri.geom.images import ImageFiles, check_frames

    a = _rgb(np.uint16, h=300, w=400, bands=1)[:, :, 0]
    paths = []
    for k, name in enumerate(("s01_001.tif", "s01_002.tif")):
        paths.append(tmp_path / name)
        _write(paths[-1], np.roll(a, 7 * k, axis=1), **kw)   # two pictures (one picture twice is refused too)
    camera = SimpleNamespace(width=400, height=300)
    images = ImageFiles(("s01_001", "s01_002"), tuple(paths))
    check_frames(images, camera)  # whole: accepted
    data = paths[1].read_bytes()
    paths[1].write_bytes(data[: len(data) // 2])
    with rasterio.open(paths[1]) as ds:  # the header still opens
        assert ds.width == 400
    with pytest.raises(InputError, match=r"s01_002.tif: truncated: .* but the file holds"):
        check_frames(images, camera)


def test_one_picture_under_two_frame_names_is_refused_naming_both(tmp_path):
    """Trial s96 H1: a delivery mix-up (s02_004's picture copied over s02_003) crashed the match stage in OpenCV
    (solvePoly, exit 1, no frame named). Refused before any work now, naming both files; two pictures pass."""
    import shutil
    from types import SimpleNamespace

    from aerotri.geom.images import ImageFiles, check_frames, content_fingerprint

    a = _rgb(np.uint8, h=300, w=400, bands=3)
    paths = [tmp_path / f"s02_00{k}.tif" for k in (3, 4, 5)]
    for k, p in enumerate(paths):
        _write(p, np.roll(a, 5 * k, axis=1))
    camera = SimpleNamespace(width=400, height=300)
    images = ImageFiles(("s02_003", "s02_004", "s02_005"), tuple(paths))
    check_frames(images, camera)
    shutil.copy(paths[1], paths[2])
    assert content_fingerprint(paths[1]) == content_fingerprint(paths[2]) != content_fingerprint(paths[0])
    with pytest.raises(InputError, match=r"s02_005.tif: the same file content as .*s02_004.tif \(image 's02_005'\)"):
        check_frames(images, camera)


def test_an_empty_frame_and_a_jpeg_named_tif_are_said_as_what_they_are(tmp_path, caplog):
    """Trial s96 L6 / L7: a zero-byte frame read "not recognized as being in a supported file format"; a JPEG renamed
    .tif ran to the end without a word (a lossy copy where a TIFF was delivered)."""
    import logging
    from types import SimpleNamespace

    import cv2

    from aerotri.geom.images import ImageFiles, check_frames

    a = _rgb(np.uint8, h=300, w=400, bands=3)
    ok, jpg = tmp_path / "s01_001.tif", tmp_path / "s01_002.tif"
    _write(ok, a)
    cv2.imwrite(str(tmp_path / "x.jpg"), np.roll(a, 9, axis=1))
    (tmp_path / "x.jpg").rename(jpg)
    camera = SimpleNamespace(width=400, height=300)
    with caplog.at_level(logging.WARNING):
        check_frames(ImageFiles(("s01_001", "s01_002"), (ok, jpg)), camera)
    assert "s01_002.tif: named .tif but its bytes are a JPG file" in caplog.text and "s01_001" not in caplog.text
    empty = tmp_path / "s01_003.tif"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"s01_003.tif: an empty file \(0 bytes; image 's01_003'\)"):
        check_frames(ImageFiles(("s01_001", "s01_003"), (ok, empty)), camera)
