"""An 8-bit DOM from a 16-bit block when asked (issue 42: "16-bit in, 16-bit out unless asked"): ``ortho mosaic
--output-bits 8`` maps the balanced samples by one block-wide linear mapping (0 .. the frames' white level -> 0 .. 255),
recorded in the DOM's tags and mosaic.json; the 8-bit DOM is the 16-bit DOM mapped by the recorded mapping, its mask
the 16-bit DOM's, and an edited run takes tiles over only from a mosaic of the same mapping."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from ortho.cli import main
from tests.shared_builds import write_synthetic_project

TILE_PX = 128


@pytest.fixture(scope="module")
def block12(tmp_path_factory):
    """A synthetic 2 x 3 block of 12-bit data in 16-bit frames (no NBITS tag), one frame with a saturated middle,
    rectified, and its 16-bit DOM."""
    root = tmp_path_factory.mktemp("dom8") / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    for p in sorted((root / "images").glob("*.tif")):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) * np.float32(4095 / 255)
        if p.stem == "s01_002":
            h, w = img.shape[:2]
            img[h // 3:2 * h // 3, w // 3:2 * w // 3] *= 1.5
        cv2.imwrite(str(p), np.clip(np.rint(img), 0, 4095).astype(np.uint16))
    r = CliRunner().invoke(main, ["rectify", str(root)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--tile-px", str(TILE_PX)])
    assert r.exit_code == 0, r.output
    shutil.copy(root / "ortho/mosaic.tif", root.parent / "mosaic16.tif")
    shutil.copy(root / "ortho/mosaic.json", root.parent / "mosaic16.json")
    return root


def _read(path):
    with rasterio.open(path) as ds:
        return ds.read(), ds.read_masks(1) > 0, ds.tags(), ds.overviews(1), ds.read(out_shape=(
            ds.count, -(-ds.height // 2), -(-ds.width // 2)))


def test_the_8_bit_dom_is_the_16_bit_dom_mapped_by_the_recorded_mapping(block12):
    root = block12
    a16, ok16, tags16, ovr16, _ = _read(root.parent / "mosaic16.tif")
    assert a16.dtype == np.uint16 and "DOM_SAMPLE_MAPPING" not in tags16
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--tile-px", str(TILE_PX),
                                  "--output-bits", "8"])
    assert r.exit_code == 0, r.output
    a8, ok8, tags8, ovr8, half8 = _read(root / "ortho/mosaic.tif")
    summary = json.loads((root / "ortho/mosaic.json").read_text())
    out = summary["output"]
    m = out["mapping"]
    assert (m["bits"], m["low_dn"], m["high_dn"]) == (8, 0.0, 4095.0) and m["from"].startswith("white level")
    assert summary["settings"]["output_bits"] == {"value": 8, "source": "command line"}
    assert tags8["DOM_SAMPLE_MAPPING"] == m["formula"] and float(tags8["DOM_SOURCE_HIGH_DN"]) == 4095
    # the recorded mapping applied to the 16-bit DOM gives the 8-bit DOM (to rounding: here exactly)
    expected = np.clip(np.rint((a16.astype(np.float64) - m["low_dn"]) * 255 / (m["high_dn"] - m["low_dn"])), 0, 255)
    assert a8.dtype == np.uint8
    assert np.array_equal(ok8, ok16)  # nodata stays nodata, in the mask, apart from valid black
    assert np.abs(a8[:, ok8].astype(int) - expected[:, ok8]).max() == 0
    assert not a8[:, ~ok8].any()
    # seams no worse: the largest step between neighbouring pixels, in 8-bit steps, is the 16-bit one's mapped
    for axis in (1, 2):
        both = np.logical_and(np.take(ok8, range(1, ok8.shape[axis - 1]), axis=axis - 1),
                              np.take(ok8, range(ok8.shape[axis - 1] - 1), axis=axis - 1))
        d8 = np.abs(np.diff(a8.astype(int), axis=axis))[:, both]
        d16 = np.abs(np.diff(a16.astype(float), axis=axis))[:, both] * 255 / 4095
        assert np.abs(d8 - d16).max() <= 1.0
    # overviews as before, averaged from the 8-bit samples (within one step of the 16-bit overview mapped)
    assert ovr8 == ovr16
    _, _, _, _, half16 = _read(root.parent / "mosaic16.tif")
    assert np.abs(half8.astype(float) - half16.astype(float) * 255 / 4095).max() <= 1.0
    # clipping counted: the pixels at 255 are the saturated ones (and values within half a step of white)
    sat16 = float((a16 >= 4095).any(axis=0)[ok16].mean())
    near16 = float((a16 >= 4095 - 4095 / 510).any(axis=0)[ok16].mean())
    assert out["share_at_255"] == pytest.approx(float((a8 == 255).any(axis=0)[ok8].mean()))
    assert out["share_at_0"] == pytest.approx(float((a8 == 0).any(axis=0)[ok8].mean()))
    assert sat16 > 0.002 and sat16 <= out["share_at_255"] <= near16
    # the saturated share is the frames' (held at white in the 16-bit DOM) plus what the mapping clipped, stated
    assert out["blended_pixels"] == int(ok16.sum()) and out["blended_share_at_white"] == pytest.approx(sat16)
    assert out["blended_share_at_255"] == pytest.approx(out["share_at_255"])
    assert out["clipped_by_mapping_share"] == pytest.approx(out["share_at_255"] - sat16)
    assert 0 <= out["clipped_by_mapping_share"] < 0.002  # measured 0.106 %: the roll-off's top within 4 DN of white
    # the gains, offsets and seams are those of the 16-bit run (converted at the write)
    old = json.loads((root.parent / "mosaic16.json").read_text())
    assert summary["gains"] == old["gains"] and summary["highlight_rolloff"] == old["highlight_rolloff"]


def test_edited_runs_take_tiles_over_only_from_a_dom_of_the_same_mapping(block12, tmp_path):
    root = tmp_path / "p"
    shutil.copytree(block12, root)
    shutil.copy(block12.parent / "mosaic16.tif", root / "ortho/mosaic.tif")
    shutil.copy(block12.parent / "mosaic16.json", root / "ortho/mosaic.json")
    edited = tmp_path / "same.gpkg"
    shutil.copy(root / "ortho/seamlines.gpkg", edited)
    args = ["mosaic", str(root), "--tile-px", str(TILE_PX), "--seamlines", str(edited), "--output-bits", "8"]
    r = CliRunner().invoke(main, args)  # from a 16-bit DOM: every tile blended and mapped
    assert r.exit_code == 0, r.output
    s = json.loads((root / "ortho/mosaic.json").read_text())
    assert s["tiles"]["taken_over"] == 0 and "mapped otherwise" in s["tiles"]["why_all_blended"]
    first = _read(root / "ortho/mosaic.tif")
    r = CliRunner().invoke(main, args)  # from the 8-bit DOM of the same mapping: every tile taken over, the same
    assert r.exit_code == 0, r.output
    s2 = json.loads((root / "ortho/mosaic.json").read_text())
    assert s2["tiles"]["taken_over"] == s2["tiles"]["total"] and s2["output"]["mapping"] == s["output"]["mapping"]
    # the DOM-wide counts include the taken-over tiles; nothing blended, nothing counted before the mapping
    assert s2["output"]["share_at_255"] == s["output"]["share_at_255"] and s2["output"]["blended_pixels"] == 0
    again = _read(root / "ortho/mosaic.tif")
    assert np.array_equal(again[0], first[0]) and np.array_equal(again[1], first[1])


def test_output_bits_other_than_8_is_refused(block12):
    r = CliRunner().invoke(main, ["mosaic", str(block12), "--output-bits", "12"])
    assert r.exit_code == 2 and "output-bits" in r.output and "Traceback" not in r.output, r.output
    r = CliRunner().invoke(main, ["mosaic", str(block12), "--output-range", "percentiles"])  # without the 8 bits
    assert r.exit_code == 2 and "needs --output-bits 8" in r.output and "Traceback" not in r.output, r.output


def _moved_edge_gpkg(root, out):
    """ortho/seamlines.gpkg with a 10 x 10 m square on a shared edge of two frames' polygons (inside both frames'
    footprints) moved from one to the other, written to ``out``."""
    import pyogrio
    import shapely

    meta, _, wkb, fields = pyogrio.raw.read(root / "ortho/seamlines.gpkg", return_fids=True)
    names = list(fields[list(meta["fields"]).index("frame")])
    geoms = list(shapely.from_wkb(wkb))
    index = json.loads((root / "ortho/frames/index.json").read_text())
    feet = {e["image_id"]: shapely.Polygon(e["footprint_xy_m"]).buffer(-10) for e in index["frames"]}
    for i in range(len(geoms)):
        for j in range(len(geoms)):
            shared = geoms[i].boundary.intersection(geoms[j].boundary)
            if i == j or shared.length < 30:
                continue
            p = shared.interpolate(0.5, normalized=True)
            square = shapely.box(p.x - 5, p.y - 5, p.x + 5, p.y + 5)
            if feet[names[i]].contains(square) and feet[names[j]].contains(square):
                geoms[j] = geoms[j].union(square.intersection(geoms[i]))
                geoms[i] = geoms[i].difference(square)
                geoms = [shapely.MultiPolygon([g]) if g.geom_type == "Polygon" else g for g in geoms]
                pyogrio.raw.write(str(out), shapely.to_wkb(np.array(geoms, dtype=object)),
                                  [np.array(names, dtype=object)], ["frame"], layer="seamlines", driver="GPKG",
                                  geometry_type="MultiPolygon", crs=meta["crs"])
                return
    raise AssertionError("no shared edge of 30 m inside two frames")


def test_an_edited_8_bit_dom_is_the_whole_rebuild_of_it(block12, tmp_path):
    """--seamlines EDITED.gpkg rebuilds only the tiles the edit reaches: with the 8-bit mapping (one for the block, not
    made from the tiles rebuilt) its DOM is the DOM of blending every tile anew."""
    root, full = tmp_path / "p", tmp_path / "full"
    shutil.copytree(block12, root)
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--tile-px", str(TILE_PX),
                                  "--output-bits", "8"])
    assert r.exit_code == 0, r.output
    shutil.copytree(root, full)
    (full / "ortho/mosaic.json").unlink()  # no earlier mosaic to take tiles from
    edited = tmp_path / "edited.gpkg"
    _moved_edge_gpkg(root, edited)
    for p in (root, full):
        r = CliRunner().invoke(main, ["mosaic", str(p), "--tile-px", str(TILE_PX), "--seamlines", str(edited),
                                      "--output-bits", "8"])
        assert r.exit_code == 0, r.output
    s, s_full = (json.loads((p / "ortho/mosaic.json").read_text()) for p in (root, full))
    assert 0 < s["tiles"]["blended"] < s["tiles"]["total"] / 2 and s_full["tiles"]["taken_over"] == 0
    assert s["output"]["mapping"] == s_full["output"]["mapping"]
    a, b = _read(root / "ortho/mosaic.tif"), _read(full / "ortho/mosaic.tif")
    assert a[0].dtype == np.uint8 and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.array_equal(a[4], b[4])  # and the first overview
    assert s["output"]["share_at_255"] == s_full["output"]["share_at_255"]


def test_project_toml_asks_for_the_8_bit_dom(block12, tmp_path):
    """[mosaic] output_bits = 8 in project.toml (as aerotri run reads it) asks for it; another value stops the command
    naming the file, the section and the key."""
    root = tmp_path / "p"
    shutil.copytree(block12, root)
    toml = root / "project.toml"
    text = toml.read_text()
    toml.write_text(text + "\n[mosaic]\noutput_bits = 8\n")
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--tile-px", str(TILE_PX)])
    assert r.exit_code == 0, r.output
    s = json.loads((root / "ortho/mosaic.json").read_text())
    assert s["settings"]["output_bits"] == {"value": 8, "source": "project.toml"}
    assert s["output"]["mapping"]["bits"] == 8
    with rasterio.open(root / "ortho/mosaic.tif") as ds:
        assert ds.dtypes[0] == "uint8"
    toml.write_text(text + "\n[mosaic]\noutput_bits = 16\n")
    r = CliRunner().invoke(main, ["mosaic", str(root)])
    assert r.exit_code == 2 and "output_bits" in r.output and "project.toml" in r.output, r.output


def test_dask_tasks_map_the_tiles_as_local_threads_do(block12, tmp_path):
    """The tiles blended as Dask tasks are mapped by the writer: the same 8-bit DOM as on local threads."""
    from aerotri.core.executor import Executor
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings

    root = tmp_path / "p"
    shutil.copytree(block12, root)
    digests = {}
    for scheduler in (None, "local:2"):
        with Executor(scheduler, 2) as ex:
            mosaic_block(root, MosaicSettings(seams="voronoi", tile_px=256, output_bits=8), executor=ex)
        digests[scheduler] = (_read(root / "ortho/mosaic.tif"), json.loads((root / "ortho/mosaic.json").read_text()))
    (a, s), (b, t) = digests[None], digests["local:2"]
    assert a[0].dtype == np.uint8 and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert s["output"] == t["output"] and s["output"]["blended_pixels"] == int(a[1].sum())



def test_the_percentile_stretch_clips_about_its_share_and_says_so(tmp_path):
    """--output-range percentiles: the balanced samples' pooled 0.1 / 99.9 percentiles (all frames and bands) to 0 .. 255:
    on a 12-bit block whose data span 600 .. 3100 DN (with noise) the 8-bit DOM is the 16-bit DOM mapped by the recorded low and
    high, and what the stretch clips at each end is about its share, stated (the DOM's pixels are not the frames'
    pooled samples: the seams choose one frame of each overlap)."""
    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=2, buildings=0, seed=5)
    rng = np.random.default_rng(5)
    for p in sorted((root / "images").glob("*.tif")):  # smooth tails: sensor noise of 150 DN
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) * np.float32(2500 / 255) + np.float32(600)
        img += rng.normal(0, 150, img.shape).astype(np.float32)
        cv2.imwrite(str(p), np.clip(np.rint(img), 0, 4095).astype(np.uint16))
    for args in (["rectify", str(root)], ["mosaic", str(root), "--seams", "voronoi"]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, r.output
    a16, ok16, *_ = _read(root / "ortho/mosaic.tif")
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--output-bits", "8",
                                  "--output-range", "percentiles"])
    assert r.exit_code == 0, r.output
    a8, ok8, tags, *_ = _read(root / "ortho/mosaic.tif")
    s = json.loads((root / "ortho/mosaic.json").read_text())
    out, m = s["output"], s["output"]["mapping"]
    assert m["from"].startswith("pooled percentiles 0.1 / 99.9") and tags["DOM_SAMPLE_MAPPING"] == m["formula"]
    # near the 16-bit DOM's own pooled 0.1 / 99.9 percentiles (within a 16-bit histogram bin of 64 DN)
    lo16, hi16 = np.percentile(a16[:, ok16], [0.1, 99.9])
    assert 100 <= m["low_dn"] < m["high_dn"] <= 3600, m
    assert abs(m["low_dn"] - lo16) < 64 and abs(m["high_dn"] - hi16) < 64, (m, lo16, hi16)
    expected = np.clip(np.rint((a16.astype(np.float64) - m["low_dn"]) * 255 / (m["high_dn"] - m["low_dn"])), 0, 255)
    assert np.array_equal(ok8, ok16) and np.abs(a8[:, ok8].astype(int) - expected[:, ok8]).max() == 0
    # nothing at white before; at 255 only what the stretch clips, at 0 likewise: each about its 0.1 % of samples
    # (a pixel counts when any of its three bands is clipped: up to about three times that)
    assert out["blended_share_at_white"] == 0 and out["clipped_by_mapping_share"] == out["share_at_255"]
    assert 0.0002 < out["share_at_255"] < 0.004 and 0.0002 < out["share_at_0"] < 0.004
