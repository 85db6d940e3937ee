"""Reviewer 13: the DOM check's least patch texture (``min_std`` 4 grey levels) was taken in the DOM's own units,
so a 16-bit DOM of low-contrast 12-bit data (200 .. 1220 DN) measured 268 patches where its 8-bit DOM measured 164
(4 DN against 4 of 255 grey levels). It is now 4 of 255 grey levels from black to the DOM's white level."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import rasterio
from click.testing import CliRunner

from ortho.check import dom_white_level
from ortho.cli import main
from tests.shared_builds import write_synthetic_project


def test_8_and_16_bit_doms_of_the_same_block_measure_the_same_patches(tmp_path):
    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    for p in sorted((root / "images").glob("*.tif")):  # 12-bit data, low contrast: 200 .. about 1220 DN
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) * np.float32(4.0) + 200
        cv2.imwrite(str(p), np.clip(np.rint(img), 0, 4095).astype(np.uint16))
    assert CliRunner().invoke(main, ["rectify", str(root)]).exit_code == 0
    counts = {}
    for bits in (16, 8):
        r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi"]
                               + (["--output-bits", "8"] if bits == 8 else []))
        assert r.exit_code == 0, r.output
        with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
            white = dom_white_level(ds, root / "ortho" / "mosaic.tif")[0]
        frames_white = json.loads((root / "ortho" / "mosaic.json").read_text())["white_level"]["value"]
        assert white == (frames_white if bits == 16 else 255.0) and frames_white >= 1023
        out = root / f"check{bits}"
        r = CliRunner().invoke(main, ["check", str(root), "--reference", str(root / "truth" / "ortho.tif"),
                                      "--out", str(out)])
        assert r.exit_code == 0, r.output
        counts[bits] = json.loads(Path(f"{out}.json").read_text())["displacement"]["count"]
    # the same patches up to the 8-bit DOM's rounding at the threshold (163 / 164; before: 268 / 164)
    assert counts[8] > 100 and abs(counts[16] - counts[8]) <= 0.02 * counts[8], counts


def test_a_float_dom_in_0_1_is_checked_at_its_own_white(tmp_path):
    """Review 15: a 0-1 float DOM kept the 8-bit threshold (4 grey levels of 255 in its own units: no patch has that
    much texture), "No usable patches" with exit 0; its white is 1.0 now."""
    from rasterio.transform import from_origin

    rng = np.random.default_rng(1)
    path = tmp_path / "float_dom.tif"
    with rasterio.open(path, "w", driver="GTiff", width=64, height=64, count=1, dtype="float32", crs="EPSG:32649",
                       transform=from_origin(500000, 3400000, 0.5, 0.5)) as ds:
        ds.write(rng.uniform(0.1, 0.9, (1, 64, 64)).astype("float32"))
    with rasterio.open(path) as ds:
        assert dom_white_level(ds, path) == (1.0, "float32 samples in 0-1")
