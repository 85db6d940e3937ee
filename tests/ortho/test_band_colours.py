"""The colours the frame orthos and the mosaic declare (new-user trial 2026-11-30, ortho operator): bands 1-3 are
R, G, B (the frames' band order), a 4th band (a DMC's NIR) is not alpha. GDAL's defaults marked the 4th band of
8-bit RGBN frames alpha (QGIS and GDAL's tools take it as transparency: the NIR made the DOM see-through) and
16-bit RGB grey; the validity stays the internal mask."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.enums import ColorInterp, MaskFlags

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

RGB = [ColorInterp.red, ColorInterp.green, ColorInterp.blue]


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("band_colours") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=4, seed=9)
    return root


def _frames_as(root, kind: str):
    for f in sorted((root / "images").glob("*.tif")):
        with rasterio.open(f) as ds:
            a, prof = ds.read(), ds.profile
        assert a.dtype == np.uint8 and a.shape[0] == 3
        if kind == "rgbn8":  # a NIR band beside R, G, B, as a 4-band DMC frame holds it
            a = np.concatenate([a, (255 - a[1])[None]])
            prof.update(count=4, photometric="RGB")
        else:  # 12-bit data in 16-bit frames
            a = np.round(a * (4095 / 255)).astype(np.uint16)
            prof.update(dtype="uint16")
        f.unlink()
        with rasterio.open(f, "w", **prof) as out:
            out.write(a)


@pytest.mark.parametrize("kind, bands", [("rgbn8", 4), ("rgb16", 3)])
def test_frame_orthos_and_mosaic_are_rgb_and_a_fourth_band_is_not_alpha(block, tmp_path, kind, bands):
    root = tmp_path / "p"
    shutil.copytree(block, root)
    _frames_as(root, kind)
    for args in (["rectify", str(root)], ["mosaic", str(root)]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    for path in [*sorted((root / "ortho" / "frames").glob("*.tif")), root / "ortho" / "mosaic.tif"]:
        with rasterio.open(path) as ds:
            assert ds.count == bands, path
            assert list(ds.colorinterp[:3]) == RGB, (path, ds.colorinterp)
            assert ColorInterp.alpha not in ds.colorinterp, (path, ds.colorinterp)
            assert ds.mask_flag_enums[0] == [MaskFlags.per_dataset], path
            valid = ds.read_masks(1) > 0
            assert 0.3 < valid.mean() < 1.0
            if bands == 4 and path.name != "mosaic.tif":  # the NIR rectified as a band of its own
                a = ds.read().astype(int)
                assert np.abs(a[3] - (255 - a[1]))[valid].max() <= 1
