"""Frame images: finding a project's frames, reading them, pyramid levels, cameras described by EXIF.

The one place that finds and reads frames (``aerotri match``, ``aerotri control``, ``ortho rectify``).
Frames are TIFF/JPEG/PNG files of any size, 8 or 16 bits per sample, one grey band or R, G, B (and
alpha). Readers, all refusing an unreadable file or a frame whose size differs from the camera's
(``expect_size`` = camera width, height in px) with an ``InputError`` naming the file:

- :func:`read_native`: the frame as stored, (rows, cols[, bands]) in its own sample type, with the
  1-based file band of each channel (so that R, G, B can be written without converting the frame);
- :func:`read_rgb`: channels in R, G, B (, alpha) order, in the file's sample type;
- :func:`read_rgb8`: 8-bit R, G, B for measuring and display (other depths stretched min-max, alpha dropped);
- :func:`read_gray`: 8-bit grey (BT.601 luma as OpenCV's decoders compute it).

How a file is read: an uncompressed pixel-interleaved TIFF is memory-mapped (no decoding, no copy;
channels in file order); other files are decoded by OpenCV (channels B, G, R) where it reads the layout
as stored, else through GDAL: OpenCV garbles band-interleaved (planar) 16-bit RGB and reads 3 or 4
samples not tagged RGB as one grey band. JPEG-compressed TIFFs are always decoded by GDAL, as the
readers by windows (``FrameWindows``, ``read_gray_level``, ``ortho.rectify.FrameFile``) decode them:
OpenCV's libjpeg-turbo and the IJG libjpeg 9 of rasterio's GDAL upsample 4:2:0 chroma differently
(``_opencv_reads``), so a frame would have two sets of pixels. Plain JPEG files are decoded by OpenCV
in every reader but ``FrameFile``. EXIF orientation tags are ignored everywhere: pixel
coordinates refer to the grid as stored, the grid whose size ``check_frames`` checks.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings
from pathlib import Path

import cv2
import numpy as np

from aerotri.geom.camera import BrownCamera
from aerotri.core.errors import InputError

_log = logging.getLogger(__name__)

# OpenCV's libtiff does not know the GeoTIFF tags (33550, 33922, 34735-34737, 42112, 42113) and warns on
# stderr for each one at every read of a georeferenced frame, outside the toolkit's logging and -q: a
# block of GeoTIFF frames printed 4-6 lines per frame per read. Its errors still show.
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)

IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png")
# a frame of a given id: the suffixes in this order (upper case as cameras and Windows tools write them)
_ID_SUFFIXES = IMAGE_SUFFIXES + (".TIF", ".JPG")


# -- finding ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ImageFiles:
    """Frames and their files: ``image_id`` (each once) and ``path`` beside them; ``find_images`` gives a
    folder's, sorted by file name."""

    image_id: tuple[str, ...]
    path: tuple[Path, ...]

    def __len__(self) -> int:
        return len(self.image_id)

    def __contains__(self, image_id) -> bool:
        return image_id in self.image_id

    def pairs(self):
        """(image id, path) of every frame, in order."""
        return zip(self.image_id, self.path)

    def path_of(self, image_id: str) -> Path:
        """The file of a frame (KeyError for an id that is not among them)."""
        try:
            return self.path[self.image_id.index(image_id)]
        except ValueError:
            raise KeyError(image_id) from None

    def name_of(self, image_id: str) -> str:
        """The file name of a frame, the id itself for a frame that is not among them (an exporter's shot name)."""
        return self.path_of(image_id).name if image_id in self.image_id else str(image_id)

    def select(self, image_ids) -> "ImageFiles":
        """The frames ``image_ids``, in that order (KeyError for an id that is not among them)."""
        image_ids = tuple(image_ids)
        return ImageFiles(image_ids, tuple(self.path_of(i) for i in image_ids))


def find_images(folder) -> ImageFiles:
    """The frames of ``folder`` (image id: the file stem), sorted by file name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: image folder not found")
    found = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() in IMAGE_SUFFIXES:
            if p.stem in found:
                raise InputError(f"{p}: two images share the id {p.stem!r} ({found[p.stem].name})")
            found[p.stem] = p
    if not found:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return ImageFiles(tuple(found), tuple(found.values()))


def find_image(images_dir, image_id: str) -> Path:
    """The file of one frame: ``images_dir/<image_id>`` with the first suffix that exists."""
    images_dir = Path(images_dir)
    for ext in _ID_SUFFIXES:
        p = images_dir / f"{image_id}{ext}"
        if p.is_file():
            return p
    raise InputError(f"{images_dir}: no image file for image id {image_id!r} (tried {image_id}.tif/.jpg/.png)")


# Frames carry no georeferencing, so rasterio's NotGeoreferencedWarning on opening one says nothing. A
# process-wide filter, not warnings.catch_warnings around the open: frames are read in threads (the
# executor), and catch_warnings is not thread-safe (one thread restoring the filters lets another's leak).
warnings.filterwarnings("ignore", message="Dataset has no geotransform, gcps, or rpcs")


def _open_raster(path):
    """rasterio dataset of an image file."""
    import rasterio

    return rasterio.open(path)


def _tiff_data_end(ds) -> int | None:
    """The byte just past a TIFF's last block of pixels (the largest offset + byte count of each band's first and
    last block), None for other formats or when GDAL does not say. A TIFF written header first (GDAL, rasterio:
    the IFD at byte 8) and cut short by a copy that stopped still opens and reads its first rows: only its block
    table, read here without decoding a pixel, tells that its end is missing."""
    if ds.driver != "GTiff":
        return None
    bh, bw = ds.block_shapes[0]
    last = (-(-ds.width // bw) - 1, -(-ds.height // bh) - 1)
    end = None
    for band in range(1, ds.count + 1):
        for x, y in ((0, 0), last):
            offset = ds.get_tag_item(f"BLOCK_OFFSET_{x}_{y}", "TIFF", bidx=band)
            size = ds.get_tag_item(f"BLOCK_SIZE_{x}_{y}", "TIFF", bidx=band)
            if offset is None or size is None:
                return None
            if int(offset) > 0:  # 0: a sparse (empty) block, not stored
                end = max(end or 0, int(offset) + int(size))
    return end


JPEG_TAIL_BYTES = 4096  # where a JPEG's end-of-image marker is looked for (after it: padding, a maker's trailer)


def _jpeg_ends(path) -> bool:
    """Whether the JPEG file's last ``JPEG_TAIL_BYTES`` hold its end-of-image marker (FF D9: never in the entropy-coded
    data, where an FF byte is followed by 00 or a restart marker)."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        f.seek(max(0, f.tell() - JPEG_TAIL_BYTES))
        return b"\xff\xd9" in f.read()


def check_not_truncated(ds, path) -> None:
    """Refuse a frame cut short (a copy that stopped), naming it: a TIFF whose block table points past the file's end
    (GDAL opens one cut inside its header too, and the EXIF reader then found "no camera in the EXIF": Tuniu trial),
    a JPEG without its end-of-image marker (``_jpeg_ends``)."""
    path = Path(path)
    held = path.stat().st_size
    if ds.driver == "JPEG" and not _jpeg_ends(path):
        # (kite trial: a JPEG cut at 38 % passed init and match, and its frame was lost in the adjustment unnamed)
        raise InputError(f"{path}: truncated: a JPEG ends with its end-of-image marker (FF D9), and this one's last "
                         f"{min(held, JPEG_TAIL_BYTES):,} of {held:,} bytes hold none (a copy that stopped?); copy it "
                         f"again, or take it out of {path.parent.name}/ (and its line out of gnss.txt) to go on "
                         "without it")
    end = _tiff_data_end(ds)
    if end is not None and end > held:
        raise InputError(f"{path}: truncated: its last block of pixels ends at byte {end:,} but the file holds "
                         f"{held:,} bytes (a copy that stopped?); copy it again, or take it out of "
                         f"{path.parent.name}/ (and its line out of gnss.txt) to go on without it")


def check_frames(images: ImageFiles, camera: BrownCamera, camera_source="camera.toml") -> None:
    """Every frame is a readable image file of the camera's size, with the bands and sample type of the
    first frame, checked from the file headers before any work (a folder, an unreadable file, a TIFF cut short, a
    frame of another size, another band count or another bit depth stops here, naming it: the mosaic blends the
    frames band by band in one bit depth)."""
    import rasterio

    first = None  # (path, bands, sample type) of the first frame
    seen = {}  # content fingerprint -> the first frame with it
    for image_id, path in images.pairs():
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: not a file (image {image_id!r}); expected a TIFF/JPEG/PNG frame")
        if path.stat().st_size == 0:  # (trial s96 L7: "not recognized as being in a supported file format")
            raise InputError(f"{path}: an empty file (0 bytes; image {image_id!r}): a copy that never started? "
                             f"Replace it, or take it out of {path.parent.name}/ (and its line out of gnss.txt)")
        _say_if_not_its_format(path)
        try:
            with _open_raster(path) as ds:
                size, layout = (ds.width, ds.height), (ds.count, ds.dtypes[0])
                check_not_truncated(ds, path)
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"{path}: cannot read the image ({exc}); replace it, or take it out of "
                             f"{path.parent.name}/ (and its line out of gnss.txt) to go on without it") from None
        if size != (camera.width, camera.height):
            raise InputError(f"{path}: image is {size[0]} x {size[1]} px but {camera_source} says "
                             f"{camera.width} x {camera.height} px")
        key = content_fingerprint(path)
        if key in seen:
            # (trial s96 H1: a delivery mix-up, one picture under two names, crashed the match in OpenCV)
            raise InputError(f"{path}: the same file content as {seen[key]} (image {image_id!r}): one picture under "
                             "two frame names; put the right picture in place, or take one out of "
                             f"{path.parent.name}/ (and its line out of gnss.txt)")
        seen[key] = path
        if first is None:
            first = (path, *layout)
        elif layout != first[1:]:
            raise InputError(f"{path}: {_layout_text(*layout)}, but {first[0].name} has {_layout_text(*first[1:])}: "
                             "the frames of a block must have the same bands and bit depth (convert this frame, "
                             f"or take it out of {path.parent.name}/ and its line out of gnss.txt)")


_TIFF, _JPEG = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"), (b"\xff\xd8\xff",)  # (classic and Big TIFF)
_MAGIC = {".tif": _TIFF, ".tiff": _TIFF, ".jpg": _JPEG, ".jpeg": _JPEG, ".png": (b"\x89PNG",)}


def _say_if_not_its_format(path: Path) -> None:
    """Warn when a frame's bytes are not of the format its name says (a JPEG renamed .tif: read all the same, but a
    lossy copy where a TIFF was delivered; trial s96 L6)."""
    magic = _MAGIC.get(path.suffix.lower())
    if magic is None:
        return
    with path.open("rb") as f:
        head = f.read(8)
    if not head.startswith(magic):
        kind = next((k for k, m in _MAGIC.items() if head.startswith(m)), None)
        _log.warning(f"{path}: named {path.suffix} but its bytes are "
                     + (f"a {kind.lstrip('.').upper()} file" if kind else "of another format")
                     + ": read as what it is; was it converted (a lossy re-encode) or renamed?")


def content_fingerprint(path, block: int = 1 << 16) -> tuple:
    """(size, sha1 of the first, middle and last ``block`` bytes) of a file: two copies of one picture agree,
    two pictures never do (their pixel data differ within every 64 KB), read in three seeks whatever the frame's size
    (a whole-file hash of 3,000 DMC frames is 600 GB read)."""
    import hashlib

    path = Path(path)
    n = path.stat().st_size
    h = hashlib.sha1()
    with path.open("rb") as f:
        for at in sorted({0, max(0, n // 2 - block // 2), max(0, n - block)}):
            f.seek(at)
            h.update(f.read(block))
    return n, h.hexdigest()


def _layout_text(bands: int, dtype: str) -> str:
    return f"{bands} band{'s' if bands != 1 else ''} of {dtype}"


def image_layout(path) -> tuple[int, int]:
    """(bands, bytes per sample) of an image file, from its header."""
    with _open_raster(path) as ds:
        return ds.count, np.dtype(ds.dtypes[0]).itemsize


# -- reading ----------------------------------------------------------------------------------------
def map_uncompressed_tiff(path):
    """An uncompressed, pixel-interleaved TIFF whose strips or tiles are one contiguous run as a read-only
    np.memmap (rows, cols[, bands]) in the file's band order, or None for any other layout (or a file
    shorter than its header says: the decoders then name the problem).

    Large-format frames usually come as such files: mapping them costs no decoding or copying, the
    pages are read on demand by the resampling (the file is already in the page cache after a copy).
    """
    import rasterio

    try:
        with _open_raster(path) as ds:
            if ds.driver != "GTiff" or ds.compression is not None or len(set(ds.dtypes)) != 1:
                return None
            if ds.count > 1 and ds.interleaving != rasterio.enums.Interleaving.pixel:
                return None
            dtype = np.dtype(ds.dtypes[0])
            if dtype.kind not in "ui":
                return None
            bh, bw = ds.block_shapes[0]
            if bw != ds.width:  # tiled: the blocks are not whole rows
                return None
            nblocks = -(-ds.height // bh)
            first = ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1)
            last = ds.get_tag_item(f"BLOCK_OFFSET_0_{nblocks - 1}", "TIFF", bidx=1)
            if first is None or last is None:
                return None
            row_bytes = ds.width * ds.count * dtype.itemsize
            if int(last) != int(first) + (nblocks - 1) * bh * row_bytes:
                return None
            shape = (ds.height, ds.width) + ((ds.count,) if ds.count > 1 else ())
            end = int(first) + ds.height * row_bytes
        if Path(path).stat().st_size < end:
            return None  # truncated
        with open(path, "rb") as f:
            byte_order = f.read(2)
    except (rasterio.errors.RasterioIOError, OSError):
        return None
    if dtype.itemsize > 1:
        dtype = dtype.newbyteorder("<" if byte_order == b"II" else ">")
    img = np.memmap(path, dtype, "r", int(first), shape)
    return img if dtype.isnative or dtype.itemsize == 1 else None


# TIFF compressions OpenCV's bundled libtiff does not decode: it prints three ERROR lines per frame (outside the
# toolkit's logging) and returns nothing; such frames (ZSTD tiles: the DMC block's) go straight to GDAL
_OPENCV_CANNOT_DECODE = {"zstd", "lerc", "lerc_deflate", "lerc_zstd", "webp", "jxl", "lzma"}


def _opencv_reads(path) -> bool:
    """Whether OpenCV reads this frame, as stored and as the readers by windows (GDAL) decode it. It does not for
    TIFFs compressed as it cannot decode (``_OPENCV_CANNOT_DECODE``), nor for multi-band TIFFs that are
    band-interleaved (16-bit planar RGB comes out garbled: band means of 67-120 DN for 112-152) or not tagged RGB
    (3 or 4 MINISBLACK samples come out as one grey band); those are read through GDAL. Nor for JPEG-compressed
    TIFFs: OpenCV decodes them with libjpeg-turbo, which upsamples 4:2:0 chroma by its triangle ("fancy") filter,
    GDAL (rasterio's wheel) with IJG libjpeg 9, which upsamples it in the IDCT; the same IDCT and colour
    conversion otherwise (grey, 4:4:4 and photometric-RGB JPEG decode the same in both). On the NGI DMC frames
    (YCbCr 4:2:0) 36 % of the pixels differed, by up to 21 DN: GDAL decodes them here too, so that a frame read
    whole and one read by windows (a frame larger than ``ortho.rectify.WINDOWED_FRAME_BYTES``, match's pyramid,
    control's chips) are the same pixels."""
    import rasterio

    if Path(path).suffix.lower() not in (".tif", ".tiff"):
        return True
    try:
        with _open_raster(path) as ds:
            if ds.compression is not None and ds.compression.name.lower() in _OPENCV_CANNOT_DECODE:
                return False
            if "JPEG" in ds.tags(ns="IMAGE_STRUCTURE").get("COMPRESSION", "").upper():  # JPEG, YCbCr JPEG, OJPEG
                return False
            if ds.count == 1:
                return True
            rgb = tuple(ds.colorinterp[:3]) == (rasterio.enums.ColorInterp.red, rasterio.enums.ColorInterp.green,
                                                rasterio.enums.ColorInterp.blue)
            return rgb and ds.count in (3, 4) and ds.interleaving == rasterio.enums.Interleaving.pixel
    except rasterio.errors.RasterioIOError:
        return True  # let the readers name the problem


_GDAL_READ_ROWS = 1024  # rows ``_read_gdal`` decodes at a time (rounded to the file's blocks)


def _read_gdal(path) -> np.ndarray:
    """(rows, cols[, bands]) in file band order, decoded by GDAL into one pixel-interleaved array (as OpenCV gives a
    frame, so the resampling reads it without a copy): GDAL's band-first rows are interleaved a band of rows at a
    time, so memory is the frame and one band of rows, not twice the frame."""
    import rasterio
    from rasterio.windows import Window

    try:
        with _open_raster(path) as ds:
            bands = ds.count
            img = np.empty((ds.height, ds.width) + ((bands,) if bands > 1 else ()), np.dtype(ds.dtypes[0]))
            block_rows = max(1, ds.block_shapes[0][0])
            step = max(block_rows, _GDAL_READ_ROWS // block_rows * block_rows)
            for r0 in range(0, ds.height, step):
                h = min(step, ds.height - r0)
                part = ds.read(window=Window(0, r0, ds.width, h))
                img[r0:r0 + h] = np.moveaxis(part, 0, -1) if bands > 1 else part[0]
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: cannot read the image ({exc})") from None
    return img


def _check_size(path, img: np.ndarray, expect_size) -> None:
    if expect_size is not None and (img.shape[1], img.shape[0]) != tuple(expect_size):
        raise InputError(f"{path}: image is {img.shape[1]} x {img.shape[0]} px but the camera says "
                         f"{expect_size[0]} x {expect_size[1]} px")


def _file_order(img: np.ndarray) -> list[int]:
    return list(range(1, (img.shape[2] if img.ndim == 3 else 1) + 1))


def read_native(path, expect_size: tuple[int, int] | None = None) -> tuple[np.ndarray, list[int]]:
    """A frame as stored, (rows, cols[, bands]), and for each channel its 1-based band in R, G, B order.

    Uncompressed TIFFs are memory-mapped (``map_uncompressed_tiff``, channels in file order R, G, B).
    Otherwise cv2 reads colour frames as B, G, R: the band order lets the ortho be written as R, G, B
    without converting the whole frame. Layouts OpenCV does not read as stored go through GDAL.
    """
    img = map_uncompressed_tiff(path)
    if img is not None:
        order = _file_order(img)
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if _opencv_reads(path) else None
        if img is None:
            img = _read_gdal(path)
            order = _file_order(img)
        elif img.ndim == 3 and img.shape[2] in (3, 4):
            order = [3, 2, 1] if img.shape[2] == 3 else [3, 2, 1, 4]
        else:
            order = _file_order(img)
    _check_size(path, img, expect_size)
    return img, order


def _to_file_order(img: np.ndarray, order: list[int]) -> np.ndarray:
    """Channels in band order 1, 2, 3, ... (R, G, B) from channels in the bands ``order`` names."""
    if img.ndim == 3 and order != list(range(1, img.shape[2] + 1)):
        out = np.empty_like(img)
        out[:, :, [b - 1 for b in order]] = img
        return out
    return img


def read_rgb(path, expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """A frame as (rows, cols[, bands]) in band order R, G, B (, alpha), in the file's sample type."""
    return _to_file_order(*read_native(path, expect_size))


def read_rgb8(path, expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """An 8-bit frame (rows, cols[, 3]) in R, G, B order: alpha dropped, other depths stretched from their
    minimum to their maximum (over all bands) to 0..255."""
    img = read_rgb(path, expect_size)
    if img.ndim == 3 and img.shape[2] >= 3:
        img = img[:, :, :3]
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return np.ascontiguousarray(img)


def _gray8(img: np.ndarray) -> np.ndarray:
    """8-bit grey of R, G, B(, ...) channels in file order, as OpenCV decodes a colour TIFF to grey:
    16-bit samples scaled to 8 bits with rounding, then BT.601 luma in 14-bit fixed point."""
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 2:
        return img
    if img.shape[2] < 3:
        return np.ascontiguousarray(img[:, :, 0])
    r, g, b = (img[:, :, k].astype(np.uint32) for k in range(3))
    return ((b * 1868 + g * 9617 + r * 4899 + (1 << 13)) >> 14).astype(np.uint8)


def read_gray(path, expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """8-bit grey image; refuses unreadable files and frames whose size differs from the camera's."""
    if _opencv_reads(path):
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise InputError(f"{path}: cannot read the image (not a TIFF/JPEG/PNG, or truncated)")
    else:
        img = _gray8(_read_gdal(path))
    _check_size(path, img, expect_size)
    return img


# -- pyramid ----------------------------------------------------------------------------------------
def pyramid_level(width: int, height: int, max_dim_px: int) -> int:
    """Smallest level L (image shrunk by 2^L) whose larger side is at most ``max_dim_px``."""
    return max(0, int(math.ceil(math.log2(max(width, height) / max_dim_px)))) if max(width, height) > max_dim_px else 0


def downsample(img: np.ndarray, level: int) -> np.ndarray:
    """Level ``level`` of the image pyramid (cv2.pyrDown: Gaussian smoothing, every second pixel; factor 2^level)."""
    for _ in range(level):
        img = cv2.pyrDown(img)
    return img


def level_to_full(xy_level: np.ndarray, level: int) -> np.ndarray:
    """Pixel coordinates on a level of ``downsample`` to full resolution (pixel centres at integers).

    cv2.pyrDown keeps the even pixels of the smoothed image: pixel i of a level is pixel 2^level i of the
    frame (an area-averaging pyramid would need + (2^level - 1) / 2)."""
    return xy_level * 2.0**level


# -- a pyramid level read by windows ---------------------------------------------------------------
_LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # BT.601, as _gray8 (in floating point for deep samples)


def _significant_bits(ds, peak: float) -> int:
    """Bits of a deep frame's samples: the TIFF's NBITS tag (12-bit data in 16-bit files, as DMC frames come),
    else those its largest sample needs (at least 8)."""
    nbits = ds.tags(1, "IMAGE_STRUCTURE").get("NBITS")
    if nbits:
        return int(nbits)
    return max(8, int(math.ceil(math.log2(float(peak) + 1.0))))


def read_gray_level(path, level: int, expect_size: tuple[int, int] | None = None,
                    band_rows: int = 1024) -> np.ndarray:
    """8-bit grey of pyramid level ``level`` of a frame (``downsample``), read in bands of rows so that memory
    follows the band, not the frame: a 13824 x 7680 px 16-bit DMC frame costs about 60 MB a band, not 1 GB.

    TIFFs are read through GDAL by windows (any compression: ZSTD tiles too, which OpenCV's libtiff does not
    decode); other files are decoded whole by OpenCV. Each band is read with a margin of ``4 * 2^level`` rows, so
    its level rows equal those of the whole frame's pyramid (bands and margins are multiples of ``2^level``;
    cv2.pyrDown's 5-tap kernel reaches less than ``2 * 2^level`` rows through ``level`` levels). 8-bit frames:
    the same pixels as ``downsample(read_gray(path), level)``. Deeper samples are smoothed in floating point and
    scaled to 8 bits by their significant bits (``_significant_bits``): 12-bit data spans 0..255, not the
    0..15 a shift by 8 bits would leave of it."""
    if Path(path).suffix.lower() not in (".tif", ".tiff"):
        return downsample(read_gray(path, expect_size), level)
    import rasterio
    from rasterio.windows import Window

    try:
        ds = _open_raster(path)
    except (rasterio.errors.RasterioIOError, OSError) as exc:
        raise InputError(f"{path}: cannot read the image ({exc})") from None
    with ds:
        width, height = ds.width, ds.height
        if expect_size is not None and (width, height) != tuple(expect_size):
            raise InputError(f"{path}: image is {width} x {height} px but the camera says "
                             f"{expect_size[0]} x {expect_size[1]} px")
        f = 2**level
        deep = np.dtype(ds.dtypes[0]).itemsize > 1 or np.dtype(ds.dtypes[0]).kind not in "u"
        bands = [1, 2, 3] if ds.count >= 3 else [1]
        margin = 4 * f
        step = max(f, band_rows // f * f)
        parts = []
        for r0 in range(0, height, step):
            r1 = min(height, r0 + step)
            a, b = max(0, r0 - margin), min(height, r1 + margin)
            try:
                block = ds.read(bands, window=Window(0, a, width, b - a))
            except rasterio.errors.RasterioIOError as exc:
                raise InputError(f"{path}: cannot read the image ({exc})") from None
            if deep:
                g = (block[0].astype(np.float32) if len(bands) == 1
                     else np.tensordot(_LUMA, block.astype(np.float32), axes=1))
            else:
                g = _gray8(np.moveaxis(block, 0, -1)) if len(bands) == 3 else block[0]
            del block
            small = downsample(g, level)
            k0 = (r0 - a) // f
            parts.append(small[k0:k0 + (-(-(r1 - r0) // f) if r1 == height else (r1 - r0) // f)])
        small = np.vstack(parts)
        if deep:
            scale = 255.0 / (2.0 ** _significant_bits(ds, small.max(initial=0.0)) - 1.0)
            small = np.clip(np.rint(small * scale), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(small)


class FrameWindows:
    """A frame as ``read_rgb8`` gives it, read by windows on demand: ``shape`` and ``frame[r0:r1, c0:c1]`` (the
    slices numpy takes) read only the tiles under the window, so measuring chips in a 106 MP frame holds a
    few tiles, not the frame. Deep samples (12/16-bit) are scaled by their significant bits
    (``_significant_bits``; the largest sample from a 1/16 decimated read when the file has no NBITS tag) instead
    of ``read_rgb8``'s min-max stretch of the whole frame. Non-TIFF files are decoded whole (``read_rgb8``).
    Not thread-safe (one GDAL dataset); a context manager."""

    def __init__(self, path, expect_size: tuple[int, int] | None = None):
        self.path = Path(path)
        self._ds = self._image = None
        if self.path.suffix.lower() not in (".tif", ".tiff"):
            self._image = read_rgb8(path, expect_size)
            self.shape = self._image.shape
            return
        import rasterio

        try:
            self._ds = ds = _open_raster(path)
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"{path}: cannot read the image ({exc})") from None
        if expect_size is not None and (ds.width, ds.height) != tuple(expect_size):
            ds.close()
            raise InputError(f"{path}: image is {ds.width} x {ds.height} px but the camera says "
                             f"{expect_size[0]} x {expect_size[1]} px")
        self._bands = [1, 2, 3] if ds.count >= 3 else [1]
        self.shape = (ds.height, ds.width) + ((3,) if ds.count >= 3 else ())
        dtype = np.dtype(ds.dtypes[0])
        self._scale = None
        if dtype != np.uint8:
            peak = ds.read(self._bands, out_shape=(len(self._bands), max(1, ds.height // 16), max(1, ds.width // 16))).max()
            self._scale = 255.0 / (2.0 ** _significant_bits(ds, peak) - 1.0)

    def __getitem__(self, key):
        if self._image is not None:
            return self._image[key]
        from rasterio.windows import Window

        key = key if isinstance(key, tuple) else (key,)
        r0, r1, rstep = key[0].indices(self.shape[0])
        c0, c1, cstep = (key[1] if len(key) > 1 else slice(None)).indices(self.shape[1])
        h, w = max(0, r1 - r0), max(0, c1 - c0)
        if h == 0 or w == 0:
            block = np.zeros((len(self._bands), h, w), np.uint8)
        else:
            block = self._ds.read(self._bands, window=Window(c0, r0, w, h))
        if self._scale is not None:
            block = np.clip(np.rint(block.astype(np.float32) * self._scale), 0, 255).astype(np.uint8)
        img = np.moveaxis(block, 0, -1) if len(self._bands) == 3 else block[0]
        return img[::rstep, ::cstep][(slice(None), slice(None)) + key[2:]]

    def close(self) -> None:
        if self._ds is not None:
            self._ds.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# -- cameras from EXIF ------------------------------------------------------------------------------
def camera_from_exif(path, sensor_width_mm: float | None = None) -> BrownCamera:
    """A frame camera from an image's EXIF: focal length (mm) and sensor width (from the focal plane
    resolution tags, or given). Principal point at the centre, no distortion."""
    from PIL import Image

    with Image.open(path) as im:
        width, height = im.size
        exif = im.getexif()
        sub = exif.get_ifd(0x8769)
    focal = sub.get(0x920A)
    if focal is None:
        raise InputError(f"{path}: no FocalLength in EXIF; write a camera.toml instead")
    focal_mm = float(focal)
    if sensor_width_mm is None:
        fpx, unit = sub.get(0xA20E), sub.get(0xA210, 2)
        if not fpx:
            raise InputError(f"{path}: EXIF has no focal plane resolution; give the sensor width in mm")
        per_mm = float(fpx) / {2: 25.4, 3: 10.0, 4: 1.0}.get(int(unit), 25.4)
        sensor_width_mm = width / per_mm
    return BrownCamera(focal_mm=focal_mm, pixel_um=sensor_width_mm * 1000.0 / width, width=width, height=height,
                       name=f"EXIF {Path(path).name}")
