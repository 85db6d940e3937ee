"""Per-frame gain AND offset balancing (issue 42, i42-offsets): frames that differ by an additive haze come out of the
mosaic matched in their darks and their brights (a gain alone matches their means only: the darks of the hazy frame
stay brighter, its brights darker), the block's mean offset and mean log-gain stay 0, and no offset makes a sample
saturated at white or black that was not (the shadow toe, the roll-off, black held at black)."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from scipy import ndimage

from ortho.cli import main
from ortho.mosaic import (TOE_BOTTOM_OUT, OverlapPairs, SampleHistogram, ShadowToe, _gained, offset_bounds,
                          sample_histogram, shadow_toe)
from tests.shared_builds import write_synthetic_project

HAZE_DN = 12


def _frames(root):
    out = {}
    for p in sorted((root / "ortho/frames").glob("*.tif")):
        with rasterio.open(p) as ds:
            out[p.stem] = (ds.read().astype(np.float32), ds.read_masks(1) > 0, ds.transform)
    return out


def _through(x, summary, name):
    g = np.array(summary["gains"][name], np.float32)[:, None]
    offs = summary.get("offsets")
    o = np.array(offs[name], np.float32)[:, None] if offs else np.float32(0)
    return np.clip(np.rint(x * g + o), 0, 255)


def tone_differences(root, summary):
    """Per pair of overlapping frame orthos, the mean difference (frame a - frame b, all bands) through the mosaic's
    gains and offsets in the darkest and the brightest quarter of their common pixels (neither at 0 or 255)."""
    frames = _frames(root)
    names = sorted(frames)
    out = {}
    for ia, a in enumerate(names):
        for b in names[ia + 1:]:
            xa, ma, ta = frames[a]
            xb, mb, tb = frames[b]
            dc, dr = round((tb.c - ta.c) / ta.a), round((tb.f - ta.f) / ta.e)  # b's origin in a's pixels
            r0, c0 = max(0, dr), max(0, dc)
            r1, c1 = min(ma.shape[0], dr + mb.shape[0]), min(ma.shape[1], dc + mb.shape[1])
            if r1 - r0 < 50 or c1 - c0 < 50:
                continue
            sa, sb = xa[:, r0:r1, c0:c1], xb[:, r0 - dr:r1 - dr, c0 - dc:c1 - dc]
            ok = ma[r0:r1, c0:c1] & mb[r0 - dr:r1 - dr, c0 - dc:c1 - dc]
            ok &= ~((sa == 0) | (sa == 255) | (sb == 0) | (sb == 255)).any(axis=0)
            if ok.sum() < 5000:
                continue
            va, vb = _through(sa[:, ok], summary, a), _through(sb[:, ok], summary, b)
            raw = (sa[:, ok] + sb[:, ok]).mean(axis=0)
            dark, bright = raw <= np.quantile(raw, 0.25), raw >= np.quantile(raw, 0.75)
            d = (va - vb).mean(axis=0)
            out[(a, b)] = (float(d[dark].mean()), float(d[bright].mean()))
    return out


def test_frames_differing_by_an_offset_come_out_matched(tmp_path):
    """Every other frame of a 2 x 3 block with a haze of 12 DN (its samples + 12, before rectifying): the gains alone
    (before i42-offsets) matched the pairs' means by gains of 0.957 (hazy) and 1.045 (clear), which left a hazy frame's
    darkest quarter up to 1.59 DN brighter and its brightest up to 1.04 DN darker than its clear neighbour's (this
    failed; the synthetic frames' tones are narrow); with an offset per frame and band the hazy frames take about -7.4
    DN and the clear ones +7.4 (hazy - clear 14.95 DN for the true 12; the mean offset 0, gains 0.98-1.02) and the
    quarters match to within 0.23 DN. No pixel of the mosaic at white or black unless a frame covering it is."""
    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    hazy = ["s01_002", "s02_001", "s02_003"]
    for name in hazy:
        p = root / "images" / f"{name}.tif"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.int32)
        cv2.imwrite(str(p), np.clip(img + HAZE_DN, 0, 254).astype(np.uint8))
    assert CliRunner().invoke(main, ["rectify", str(root)]).exit_code == 0
    r = CliRunner().invoke(main, ["mosaic", str(root), "--seams", "voronoi", "--offsets"])
    assert r.exit_code == 0, r.output
    summary = json.loads((root / "ortho/mosaic.json").read_text())
    names = list(summary["gains"])
    offsets = np.array([summary["offsets"][n] for n in names])
    gains = np.array([summary["gains"][n] for n in names])
    is_hazy = np.array([n in hazy for n in names])
    # the haze is found: the hazy frames' offsets 12 DN below the clear ones', the block's mean offset and log-gain 0
    assert offsets[is_hazy].mean() - offsets[~is_hazy].mean() == pytest.approx(-HAZE_DN, abs=4.0)
    assert abs(offsets.mean()) < 1e-6 and abs(np.log(gains).mean()) < 1e-6
    diffs = tone_differences(root, summary)
    mixed = {k: v for k, v in diffs.items() if (k[0] in hazy) != (k[1] in hazy)}
    assert len(mixed) >= 4
    worst = max(max(abs(d), abs(b)) for d, b in mixed.values())
    assert worst < 0.5, mixed
    # no new clipping: at white or black in the mosaic only where a frame covering the pixel is
    with rasterio.open(root / "ortho/mosaic.tif") as ds:
        mos, ok, mt = ds.read(), ds.read_masks(1) > 0, ds.transform
    at_white, at_black = np.zeros(ok.shape, bool), np.zeros(ok.shape, bool)
    for x, m, t in _frames(root).values():
        dc, dr = round((t.c - mt.c) / mt.a), round((t.f - mt.f) / mt.e)
        r0, c0 = max(dr, 0), max(dc, 0)
        r1, c1 = min(dr + m.shape[0], ok.shape[0]), min(dc + m.shape[1], ok.shape[1])
        sub = (slice(r0 - dr, r1 - dr), slice(c0 - dc, c1 - dc))
        at_white[r0:r1, c0:c1] |= (x[:, sub[0], sub[1]] == 255).any(axis=0) & m[sub]
        at_black[r0:r1, c0:c1] |= (x[:, sub[0], sub[1]] == 0).any(axis=0) & m[sub]
    assert not ((mos == 255).any(axis=0) & ok & ~at_white).any()
    assert not ((mos == 0).any(axis=0) & ok & ~at_black).any()


@pytest.mark.parametrize("dtype,white", [(np.uint8, 255), (np.uint16, 4095)])
def test_a_negative_offset_never_takes_a_sample_to_black(dtype, white):
    """A frame whose darkest samples are 1, 2, 3 ... under an offset of -5 % of white: the toe lifts what the offset
    takes below 0.5 (it rounds to 1, not to black), is monotone and the identity above its knee; a black sample (0)
    stays black whatever the offset, a white one white."""
    rng = np.random.default_rng(3)
    img = rng.integers(1, white, size=(3, 60, 60)).astype(dtype)
    img[:, 0, :4] = [0, 1, 2, 3]
    img[:, 1, :2] = [white, white - 1]
    ok = np.ones(img.shape[1:], bool)
    hist = sample_histogram(img, ok)
    assert isinstance(hist, SampleHistogram)
    gains, offsets = np.full((1, 3), 1.0), np.full((1, 3), -0.05 * white)
    lower, upper = offset_bounds(gains, [hist], white)
    assert np.all(lower <= offsets) and np.all(offsets <= upper)
    toe = shadow_toe(gains, offsets, [hist], white)
    assert isinstance(toe, ShadowToe) and toe.bottom_out == TOE_BOTTOM_OUT
    x = np.arange(white + 1, dtype=np.float32)
    v = _gained(x.copy(), np.float32(1.0), white, True, None, np.float32(offsets[0, 0]), toe)
    out = np.rint(v)
    assert out[0] == 0 and out[white] == white
    assert np.all(out[1:white] >= 1) and np.all(np.diff(v[1:white]) >= 0)
    above = x > toe.knee - offsets[0, 0]
    assert np.allclose(v[above & (x < white)], x[above & (x < white)] + offsets[0, 0], atol=1e-3)
    # nothing to lift: no toe
    assert shadow_toe(gains, np.zeros((1, 3)), [hist], white) is None
    assert ShadowToe(**json.loads(json.dumps(toe.record()))) == toe  # mosaic.json, a Dask task's context


def test_offsets_without_the_balance_are_refused(tmp_path):
    """--offsets (or [mosaic] offsets = true) with --no-balance: the offsets are solved with the gains, so there
    would be none (the run went on and mosaic.json recorded offsets null beside settings.offsets true): exit 2
    naming the option and the balance it needs, before any output."""
    root = tmp_path / "p"
    write_synthetic_project(root, strips=1, frames_per_strip=2, buildings=0, seed=11)
    r = CliRunner().invoke(main, ["mosaic", str(root), "--no-balance", "--offsets"])
    assert r.exit_code == 2, r.output
    assert "--offsets" in r.output and "[mosaic] offsets" in r.output and "--no-balance" in r.output
    assert "needs the balance" in r.output and "Traceback" not in r.output
    with open(root / "project.toml", "a") as f:
        f.write("\n[mosaic]\noffsets = true\n")
    r = CliRunner().invoke(main, ["mosaic", str(root), "--no-balance"])
    assert r.exit_code == 2 and "(project.toml)" in r.output, r.output
    assert not (root / "ortho" / "mosaic.tif").exists() and not (root / "ortho" / "mosaic.json").exists()


def test_the_shadow_toe_reaches_every_tile_and_task(tmp_path):
    """A dark block (samples x 0.5 + 2) whose hazy frames (+12 DN) hold a deep shadow of 1..3 DN, and a clear frame
    a patch at black (0): with offsets the hazy frames take negative offsets, which would take the shadow to black;
    the shadow toe lifts it to 1 and more in the mosaic's lookup tables and in a Dask task's context (without it
    there: 897 / 1,097 new black pixels, the review's mutants), so no pixel is black in the mosaic where no frame
    is, the same bytes on local threads and a 2-process cluster, and the clear frame's black (its offset positive)
    stays black."""
    from aerotri.core.executor import Executor
    from ortho.mosaic import mosaic_block
    from ortho.settings import MosaicSettings

    root = tmp_path / "p"
    write_synthetic_project(root, strips=2, frames_per_strip=3, buildings=0, seed=11)
    hazy = ["s01_002", "s02_001", "s02_003"]
    for p in sorted((root / "images").glob("*.tif")):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) * 0.5 + 2  # darkest samples about 2
        h, w = img.shape[:2]
        patch = (slice(h // 2 - 15, h // 2 + 15), slice(w // 2 - 15, w // 2 + 15))
        if p.stem in hazy:
            img += HAZE_DN
            img[patch] = np.random.default_rng(1).integers(1, 4, (30, 30, 3))  # a deep shadow: 1..3 DN
        elif p.stem == "s01_001":
            img[patch] = 0  # black in the frame: stays black
        cv2.imwrite(str(p), np.clip(np.rint(img), 0, 255).astype(np.uint8))
    assert CliRunner().invoke(main, ["rectify", str(root)]).exit_code == 0
    digests = {}
    for scheduler in (None, "local:2"):
        with Executor(scheduler, 2) as ex:
            mosaic_block(root, MosaicSettings(seams="voronoi", tile_px=256, offsets=True), executor=ex)
        digests[scheduler] = (root / "ortho/mosaic.tif").read_bytes()
    assert digests[None] == digests["local:2"]
    summary = json.loads((root / "ortho/mosaic.json").read_text())
    toe = summary["shadow_toe"]
    assert toe is not None and toe["bottom_in"] < 0.5 < toe["bottom_out"] < toe["knee"]
    offsets = summary["offsets"]
    assert max(offsets[n][b] for n in hazy for b in range(3)) < 0 < min(offsets["s01_001"])
    with rasterio.open(root / "ortho/mosaic.tif") as ds:
        mos, ok, mt = ds.read(), ds.read_masks(1) > 0, ds.transform
    at_black = np.zeros(ok.shape, bool)
    shadow = black = 0
    for name, (x, m, t) in _frames(root).items():
        dc, dr = round((t.c - mt.c) / mt.a), round((t.f - mt.f) / mt.e)
        r0, c0 = max(dr, 0), max(dc, 0)
        r1, c1 = min(dr + m.shape[0], ok.shape[0]), min(dc + m.shape[1], ok.shape[1])
        sub = (slice(r0 - dr, r1 - dr), slice(c0 - dc, c1 - dc))
        zero = (x[:, sub[0], sub[1]] == 0).any(axis=0) & m[sub]
        at_black[r0:r1, c0:c1] |= zero
        if name in hazy:  # the shadow's samples in the mosaic: lifted, not black
            deep = (x[:, sub[0], sub[1]] <= 3).all(axis=0) & m[sub]
            shadow += int((deep & ok[r0:r1, c0:c1] & (mos[:, r0:r1, c0:c1] >= 1).all(axis=0)).sum())
        if name == "s01_001":  # the frame's black patch, away from its edge and the seams: black in the mosaic
            inner = ndimage.binary_erosion(zero, iterations=3)
            assert inner.sum() > 100
            black = int((mos[:, r0:r1, c0:c1][:, inner] == 0).all(axis=0).sum())
            assert black == int(inner.sum())
    assert shadow > 100  # (a shadow reaches the mosaic)
    assert not ((mos == 0).any(axis=0) & ok & ~at_black).any()


def test_the_gains_rows_weigh_as_before_the_offsets():
    """The gains' normal equations weigh a pair by sqrt(cells)^2 as before i42-offsets, to the last bit (its cells
    gave the default gains other last digits: an edited run over an earlier mosaic found other gains)."""
    cells = np.array([3, 7, 20, 50, 1234, 98765], np.int64)
    pairs = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [1, 3], [0, 3]], np.int64)
    rhs = np.random.default_rng(2).normal(size=(6, 3))
    ov = OverlapPairs(pairs, cells, np.ones((6, 2, 3)), None)
    w2 = np.array([math.sqrt(c) for c in cells]) ** 2  # the weights of main before i42-offsets
    assert not np.array_equal(w2, cells.astype(float))  # (so that this tells them apart)
    lam = 0.1 * math.sqrt(float(np.mean(w2)))
    n_old = lam * lam * np.eye(4)
    np.add.at(n_old, (pairs[:, 0], pairs[:, 0]), w2)
    np.add.at(n_old, (pairs[:, 1], pairs[:, 1]), w2)
    np.add.at(n_old, (pairs[:, 0], pairs[:, 1]), -w2)
    np.add.at(n_old, (pairs[:, 1], pairs[:, 0]), -w2)
    u_old = np.zeros((4, 3))
    np.add.at(u_old, pairs[:, 0], w2[:, None] * rhs)
    np.add.at(u_old, pairs[:, 1], -w2[:, None] * rhs)
    assert np.array_equal(ov.normal_matrix(4, 0.1), n_old)
    assert np.array_equal(ov.right_hand_side(4, rhs), u_old)
