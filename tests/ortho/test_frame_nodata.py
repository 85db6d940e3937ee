"""A frame's own nodata (its nodata value or an internal mask: the black collar of a scanned or rotated frame) is
nodata in its ortho and never reaches the mosaic (new-user trial 2026-12-01, ortho operator: the NGI frames with a
collar declared ``nodata=0`` gave 59,742 black pixels, 3.2 % of the DOM, valid in the mosaic)."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

FILL = (255, 0, 255)  # what lies under the internal mask: magenta, so that any of it in an ortho shows


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    root = tmp_path_factory.mktemp("frame_nodata") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=0, seed=5)
    for f in sorted((root / "images").glob("*.tif")):  # no pixel of the picture itself is the nodata value 0
        with rasterio.open(f, "r+") as ds:
            a = ds.read()
            a[:, (a == 0).all(0)] = 1
            ds.write(a)
    for args in (["rectify", str(root)], ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    return root


def _collar(h: int, w: int) -> np.ndarray:
    """True in the collar: two corner triangles and a strip along the left edge (about 14 % of the frame)."""
    yy, xx = np.mgrid[0:h, 0:w]
    return (xx + yy < 150) | ((w - 1 - xx) + (h - 1 - yy) < 150) | (xx < 25)


def _with_collar(root, how: str) -> None:
    for f in sorted((root / "images").glob("*.tif")):
        with rasterio.open(f) as ds:
            a, prof = ds.read(), ds.profile
        collar = _collar(*a.shape[1:])
        if how in ("nodata", "undeclared", "jpeg"):
            a[:, collar] = 0
            prof.update(nodata=None if how == "undeclared" else 0)
            if how == "jpeg":  # lossy: the collar's pixels beside the picture are no longer all 0
                prof.update(compress="jpeg", photometric="ycbcr", tiled=True, blockxsize=256, blockysize=256)
        else:
            a[:, collar] = np.array(FILL, np.uint8)[:, None]
        f.unlink()
        with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(f, "w", **prof) as out:
            out.write(a)
            if how == "mask":
                out.write_mask(np.where(collar, 0, 255).astype(np.uint8))


@pytest.mark.parametrize("how", ["nodata", "mask"])
def test_a_frames_nodata_is_nodata_in_its_ortho_and_the_mosaic(clean, tmp_path, how):
    root = tmp_path / "p"
    shutil.copytree(clean / "images", root / "images")
    for name in ("project.toml", "camera.toml", "at", "lidar_out"):
        (shutil.copytree if (clean / name).is_dir() else shutil.copy)(clean / name, root / name)
    _with_collar(root, how)
    for args in (["rectify", str(root)], ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    left_out = 0
    for ref in sorted((clean / "ortho" / "frames").glob("*.tif")):
        with rasterio.open(ref) as a, rasterio.open(root / "ortho" / "frames" / ref.name) as b:
            assert a.transform == b.transform and a.shape == b.shape
            va, vb = a.read_masks(1) > 0, b.read_masks(1) > 0
            assert not (vb & ~va).any(), ref.name  # nothing valid that the clean frame's ortho does not have
            # where valid, the same samples as the clean frame's ortho: no collar pixel mixed in by the kernel
            assert np.array_equal(a.read()[:, vb], b.read()[:, vb]), ref.name
            left_out += int((va & ~vb).sum())
            assert 0.05 < (va & ~vb).sum() / va.sum() < 0.3, ref.name  # about the collar's share
    assert left_out > 0
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        m, valid = ds.read(), ds.read_masks(1) > 0
    with rasterio.open(clean / "ortho" / "mosaic.tif") as ds:
        whole, c = ds.read_masks(1) > 0, ds.read()
    # the neighbours fill the collars inside the block; those on its edges see no other frame: nodata
    assert not (valid & ~whole).any() and 0.9 < valid.sum() / whole.sum() < 1.0, valid.sum() / whole.sum()
    fill = np.array((0, 0, 0) if how == "nodata" else FILL)[:, None]

    def like_fill(a, v):
        return int((np.abs(a[:, v].astype(int) - fill) <= 8).all(0).sum())

    assert like_fill(m, valid) <= like_fill(c, whole)  # no more fill-coloured pixels than the picture has


def test_a_collar_not_declared_is_warned_of(clean, tmp_path):
    """Black corners in a frame that declares no nodata: rectified as picture (the frame's values are all there is),
    with a warning naming the frames and how to declare it; the clean block has none."""
    root = tmp_path / "p"
    shutil.copytree(clean / "images", root / "images")
    for name in ("project.toml", "camera.toml", "at", "lidar_out"):
        (shutil.copytree if (clean / name).is_dir() else shutil.copy)(clean / name, root / name)
    _with_collar(root, "undeclared")
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    assert "4 frames (s01_001, s01_002, s02_001, s02_002) have a corner black" in r.stderr, r.stderr
    assert "rio edit-info --nodata 0" in r.stderr
    plain = tmp_path / "q"
    shutil.copytree(clean, plain)
    r = CliRunner().invoke(main, ["rectify", str(plain)])
    assert r.exit_code == 0, r.output
    assert "have a corner black" not in r.stderr


def test_a_jpeg_frames_nodata_value_leaves_no_collar_in_its_ortho(clean, tmp_path):
    """JPEG compression mixes the black collar into the blocks its edge crosses: those collar pixels are no longer 0,
    so valid by the nodata value; the collar is grown by the JPEG block (``_JPEG_BLOCK_PX``) for such frames."""
    root = tmp_path / "p"
    shutil.copytree(clean / "images", root / "images")
    for name in ("project.toml", "camera.toml", "at", "lidar_out"):
        (shutil.copytree if (clean / name).is_dir() else shutil.copy)(clean / name, root / name)
    _with_collar(root, "jpeg")
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    for ref in sorted((clean / "ortho" / "frames").glob("*.tif")):
        with rasterio.open(ref) as a, rasterio.open(root / "ortho" / "frames" / ref.name) as b:
            va, vb = a.read_masks(1) > 0, b.read_masks(1) > 0
            assert not (vb & ~va).any(), ref.name
            darker = (a.read().astype(int) - b.read().astype(int)).max(0)[vb]
            assert darker.max() <= 60, (ref.name, int((darker > 60).sum()))  # JPEG's own error (46 DN), no collar
            assert 0.05 < (va & ~vb).sum() / va.sum() < 0.4, ref.name


def _shadowed_frame(path, how: str) -> tuple[np.ndarray, np.ndarray]:
    """A 240 x 320 px frame with the collar (0, declared by ``nodata=0`` or, "mask", an internal mask) and a shadow
    clipped at 0 inside the picture: one pixel and a 12 x 12 px patch, 0 in every band. Returns (collar, shadow)."""
    rng = np.random.default_rng(3)  # ground: smooth as a photograph's (JPEG leaves the collar 0 but at its edge)
    a = np.stack([cv2.GaussianBlur(rng.uniform(40, 216, (240, 320)), (0, 0), 3) for _ in range(3)]).astype(np.uint8)
    collar = np.zeros((240, 320), bool)
    collar[:, :20] = True  # a strip along the left edge
    collar[np.add.outer(np.arange(240), np.arange(320)) < 40] = True  # and a corner triangle
    shadow = np.zeros_like(collar)
    shadow[120, 200] = True
    shadow[60:72, 100:112] = True
    a[:, collar | shadow] = 0
    prof = dict(driver="GTiff", width=320, height=240, count=3, dtype="uint8", tiled=True, blockxsize=64, blockysize=64)
    if how == "jpeg":
        prof.update(compress="jpeg", photometric="ycbcr", nodata=0)
    elif how == "nodata":
        prof.update(compress="deflate", nodata=0)
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(path, "w", **prof) as out:
        out.write(a)
        if how == "mask":
            out.write_mask(np.where(collar | shadow, 0, 255).astype(np.uint8))
    return collar, shadow


def _near(region: np.ndarray, r: int) -> np.ndarray:
    return cv2.dilate(region.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0


@pytest.mark.parametrize("how", ["nodata", "jpeg", "mask"])
def test_the_nodata_value_inside_the_picture_stays_picture(tmp_path, how):
    """review 28: a nodata value masked every picture pixel holding it, grown by the kernel (+16 px in a JPEG
    frame): one 0 pixel in a shadow made a 35 x 35 px hole, NGI frames darkened gave a mosaic 11 % nodata. Only the
    value's regions touching the frame's edge (a collar) are nodata; an internal mask is taken as it is."""
    from aerotri.geom.images import read_native
    from ortho.rectify import frame_validity

    path = tmp_path / f"{how}.tif"
    collar, shadow = _shadowed_frame(path, how)
    image, order = read_native(path)
    for valid in (frame_validity(path, "bilinear"), frame_validity(path, "bilinear", image, order)):
        invalid = valid == 0
        reach = 1 + (16 if how == "jpeg" else 0)
        assert invalid[collar].all()
        if how == "mask":  # as it is, grown by the kernel's reach
            assert np.array_equal(invalid, _near(collar | shadow, 1))
        else:
            assert not invalid[~_near(collar, reach)].any()  # the collar, grown, and only it
            assert not invalid[shadow].any() and not invalid[_near(shadow, reach) & ~_near(collar, reach)].any()
            if how == "nodata":  # (JPEG leaves the collar's pixels at its edge off 0: grown from the others)
                assert np.array_equal(invalid, _near(collar, 1))


def test_black_corners_are_taken_from_the_decoded_frame(tmp_path):
    """review 28: ``black_corners`` decoded every frame in the main process before the first frame started (285 ms a
    Brighton JPEG, 14 min for 3,000 frames): it now looks at the frame its task decoded, or reads the corners of a
    ``FrameFile`` by windows; the same count either way."""
    from aerotri.geom.images import read_native
    from ortho.rectify import FrameFile, black_corners

    path = tmp_path / "f.tif"
    _shadowed_frame(path, "nodata")  # the collar's strip along the left edge: the two left corners
    frame = FrameFile(path)
    assert black_corners(read_native(path)[0]) == black_corners(frame) == 2
    frame.close()
    assert black_corners(np.full((30, 40, 3), 7, np.uint8)) == 0
