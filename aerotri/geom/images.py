"""Frame images: reading (TIFF/JPEG, any size), pyramid levels, and cameras described by EXIF."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from aerotri.geom.camera import FrameCamera
from aerotri.core.errors import InputError

IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png")


def find_images(folder) -> dict[str, Path]:
    """Image id (file stem) -> path for every frame in ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: image folder not found")
    out = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() in IMAGE_SUFFIXES:
            if p.stem in out:
                raise InputError(f"{p}: two images share the id {p.stem!r} ({out[p.stem].name})")
            out[p.stem] = p
    if not out:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return out


def check_frames(images: dict, camera: FrameCamera, camera_source="camera.toml") -> None:
    """Every frame is a readable image file of the camera's size, checked from the file headers before
    any work (a folder, an unreadable file or a frame of another size stops here, naming it)."""
    import warnings

    import rasterio

    for image_id, path in images.items():
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: not a file (image {image_id!r}); expected a TIFF/JPEG/PNG frame")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                with rasterio.open(path) as ds:
                    size = (ds.width, ds.height)
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"{path}: cannot read the image ({exc})") from None
        if size != (camera.width, camera.height):
            raise InputError(f"{path}: image is {size[0]} x {size[1]} px but {camera_source} says "
                             f"{camera.width} x {camera.height} px")


def read_gray(path, expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """8-bit grey image; refuses unreadable files and frames whose size differs from the camera's."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: cannot read the image (not a TIFF/JPEG/PNG, or truncated)")
    if expect_size is not None and (img.shape[1], img.shape[0]) != tuple(expect_size):
        raise InputError(f"{path}: image is {img.shape[1]} x {img.shape[0]} px but the camera says "
                         f"{expect_size[0]} x {expect_size[1]} px")
    return img


def pyramid_level(width: int, height: int, max_dim_px: int) -> int:
    """Smallest level L (image shrunk by 2^L) whose larger side is at most ``max_dim_px``."""
    return max(0, int(math.ceil(math.log2(max(width, height) / max_dim_px)))) if max(width, height) > max_dim_px else 0


def downsample(img: np.ndarray, level: int) -> np.ndarray:
    """Level ``level`` of the image pyramid (area averaging, factor 2^level)."""
    for _ in range(level):
        img = cv2.pyrDown(img)
    return img


def level_to_full(xy_level: np.ndarray, level: int) -> np.ndarray:
    """Pixel coordinates on a pyramid level to full resolution (pixel-centre convention)."""
    s = 2.0**level
    return xy_level * s + (s - 1.0) / 2.0


def camera_from_exif(path, sensor_width_mm: float | None = None) -> FrameCamera:
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
    return FrameCamera(focal_mm=focal_mm, pixel_um=sensor_width_mm * 1000.0 / width, width=width, height=height,
                       name=f"EXIF {Path(path).name}")
