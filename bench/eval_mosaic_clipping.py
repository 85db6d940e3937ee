"""Colour that does not clip (issue 42, i42-clip): the mosaic's saturated share against its frames', before and after
the gains were bounded so that no unsaturated sample reaches the white level, and the colour differences across the
overlaps (the balancing must still balance) -> bench/results/mosaic_clipping.json.

Per block (copies of rectified projects: frame orthos, index, project.toml; the originals are never written), in this
process: ``mosaic_block`` of ``ortho/mosaic.py`` as it was at ``--before`` (loaded from git as a separate module:
gains limited to saturate at most 0.1 % of a frame beyond its own, 8-bit saturated samples x gain), then as it is
now. Per run:

- saturated share (% of the mosaic's valid pixels with a band at the white level): the frames pooled (over the
  frames' valid pixels), the labelled frames (the frame ``seams.tif`` labels at each mosaic pixel, at white there),
  the mosaic, "new": mosaic pixels at white whose labelled frame's pixel is not (the trial's count), and "new in every
  frame": at white in the mosaic but in no frame covering the pixel (a feathered blend next to a neighbour's white is
  counted by the first, not by this one); the mosaic's mean DN (the caps lower gains: how much darker);
- overlap differences (DN, all bands, pixels no frame of the pair has at white, every ``--step``-th pixel of the
  mosaic grid): the RMS of the pixel differences between every pair of overlapping frames through their gains (the
  mosaic's lookup: round, clip at white), and the RMS over pairs of the pair's mean difference (what the balance
  minimises), with no gains, the gains before and the gains after.

Nothing here was tuned: the rule has no parameter (the cap is (white - 0.5) / the frame's largest unsaturated sample).

Usage: python bench/eval_mosaic_clipping.py BLOCK=PROJECT [BLOCK=PROJECT ...] [--work DIR] [--step 4]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rasterio

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ortho import mosaic as mosaic_now  # noqa: E402

BEFORE = "53b51bd3"
SKIP = ("truth", "lidar", "images", "reports")  # not read by the mosaic


def load_before(commit: str, work: Path):
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{commit}:ortho/mosaic.py"], check=True,
                         capture_output=True, text=True).stdout
    path = work / "mosaic_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("ortho._mosaic_before", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def copy_project(src: Path, dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=lambda d, names: [n for n in names if Path(d) == src and n in SKIP]
                    + [n for n in names if n in ("mosaic_resume",)])


def frames_of(root: Path, names):
    for name in names:
        with rasterio.open(root / "ortho" / "frames" / f"{name}.tif") as ds:
            yield name, ds.read(), ds.read_masks(1) > 0, ds.transform


def saturation(root: Path, white: int) -> dict:
    """Saturated shares (% of the mosaic's valid pixels, any band at or above ``white``; module doc)."""
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    names = list(summary["gains"])
    with rasterio.open(root / "ortho" / "mosaic.tif") as M, rasterio.open(root / "ortho" / "seams.tif") as S:
        mos, ok, mt = M.read(), M.read_masks(1) > 0, M.transform
        lab, f = S.read(1), int(round(S.transform.a / M.transform.a))
    sat_m = (mos >= white).any(0) & ok
    labels = np.repeat(np.repeat(lab, f, 0), f, 1)[:mos.shape[1], :mos.shape[2]]
    own = np.zeros(ok.shape, bool)  # the labelled frame's pixel is at white
    anyf = np.zeros(ok.shape, bool)  # some frame covering the pixel has it at white
    frames_sat = frames_valid = 0
    for k, (name, a, fm, ft) in enumerate(frames_of(root, names)):
        fsat = (a >= white).any(0) & fm
        frames_sat += int(fsat.sum())
        frames_valid += int(fm.sum())
        dc, dr = round((ft.c - mt.c) / mt.a), round((ft.f - mt.f) / mt.e)
        r0, c0 = max(dr, 0), max(dc, 0)
        r1, c1 = min(dr + a.shape[1], ok.shape[0]), min(dc + a.shape[2], ok.shape[1])
        fs = fsat[r0 - dr:r1 - dr, c0 - dc:c1 - dc]
        own[r0:r1, c0:c1] |= fs & (labels[r0:r1, c0:c1] == k)
        anyf[r0:r1, c0:c1] |= fs
    n = int(ok.sum())
    return {"frames_pooled_pct": 100 * frames_sat / frames_valid,
            "labelled_frames_pct": 100 * float((own & ok).sum()) / n,
            "mosaic_pct": 100 * float(sat_m.sum()) / n,
            "new_pct": 100 * float((sat_m & ~own).sum()) / n,
            "new_in_every_frame_pct": 100 * float((sat_m & ~anyf).sum()) / n,
            "mosaic_valid_px": n, "mosaic_mean_dn": float(mos[:, ok].mean()),
            "mosaic_max_sample": int(mos[:, ok].max())}


def overlap_samples(root: Path, names, white: int, step: int, *, without_black: bool = False) -> tuple[list, int]:
    """(pairs, the frames' type maximum): every pair of overlapping frame orthos of ``root`` as (i, j, samples of i,
    samples of j) (bands, n) float32 at every ``step``-th mosaic pixel both have valid and neither at ``white`` (nor
    at 0 with ``without_black``; pairs sharing fewer than 100 such pixels left out)."""
    with rasterio.open(root / "ortho" / "mosaic.tif") as M:
        mt = M.transform
    grids = []
    for _, a, fm, ft in frames_of(root, names):
        dc, dr = round((ft.c - mt.c) / mt.a), round((ft.f - mt.f) / mt.e)
        # the frame's pixels on mosaic rows/cols that are multiples of step
        r0, c0 = (-dr) % step, (-dc) % step
        sub, ok = a[:, r0::step, c0::step], fm[r0::step, c0::step]
        ok = ok & ~(sub >= white).any(0)
        if without_black:
            ok &= ~(sub == 0).any(0)
        grids.append(((dr + r0) // step, (dc + c0) // step, sub, ok))
    pairs = []
    for i in range(len(grids)):
        ri, ci, ai, oi = grids[i]
        for j in range(i + 1, len(grids)):
            rj, cj, aj, oj = grids[j]
            r0, c0 = max(ri, rj), max(ci, cj)
            r1, c1 = min(ri + oi.shape[0], rj + oj.shape[0]), min(ci + oi.shape[1], cj + oj.shape[1])
            if r1 <= r0 or c1 <= c0:
                continue
            both = oi[r0 - ri:r1 - ri, c0 - ci:c1 - ci] & oj[r0 - rj:r1 - rj, c0 - cj:c1 - cj]
            if both.sum() < 100:
                continue
            pairs.append((i, j, ai[:, r0 - ri:r1 - ri, c0 - ci:c1 - ci][:, both].astype(np.float32),
                          aj[:, r0 - rj:r1 - rj, c0 - cj:c1 - cj][:, both].astype(np.float32)))
    return pairs, int(np.iinfo(grids[0][2].dtype).max)


def overlap_differences(root: Path, white: int, gain_sets: dict, step: int) -> dict:
    """Per gain set the pixel RMS and the pair-mean RMS of the differences across overlaps (module doc)."""
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    names = list(summary["gains"])
    pairs, top = overlap_samples(root, names, white, step)
    out = {}
    for label, gains in gain_sets.items():
        g = np.asarray(gains, np.float32)
        sq = cnt = 0.0
        means, weights = [], []
        for i, j, xi, xj in pairs:
            vi = np.clip(np.rint(xi * g[i][:, None]), 0, min(white, top))
            vj = np.clip(np.rint(xj * g[j][:, None]), 0, min(white, top))
            d = vi - vj
            sq += float((d * d).sum())
            cnt += d.size
            means.append(d.mean(axis=1))
            weights.append(d.shape[1])
        m, w = np.array(means), np.array(weights, float)
        out[label] = {"pixel_rms_dn": float(np.sqrt(sq / cnt)),
                      "pair_mean_rms_dn": float(np.sqrt((w[:, None] * m * m).sum() / (w.sum() * m.shape[1]))),
                      "pairs": len(means), "samples": int(cnt)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("blocks", nargs="+", help="NAME=PROJECT (a project with ortho/frames made)")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/i42-clip/bench"))
    ap.add_argument("--before", default=BEFORE, help="commit whose ortho/mosaic.py is the 'before'")
    ap.add_argument("--step", type=int, default=4, help="every step-th mosaic pixel for the overlap differences")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "mosaic_clipping.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args.work.mkdir(parents=True, exist_ok=True)
    before = load_before(args.before, args.work)
    results = {"before_commit": args.before, "step_px": args.step, "blocks": {}}
    for spec in args.blocks:
        name, src = spec.split("=", 1)
        root = args.work / name
        copy_project(Path(src), root)
        block = {"source": src}
        gains = {}
        for label, mod in (("before", before), ("after", mosaic_now)):
            t = time.process_time()
            mod.mosaic_block(root)
            summary = json.loads((root / "ortho" / "mosaic.json").read_text())
            white = summary["white_level"]["value"]
            gains[label] = list(summary["gains"].values())
            block[label] = {"cpu_s": round(time.process_time() - t, 1), "white_level": white,
                            **saturation(root, white),
                            "gains_min": float(np.min(gains[label])), "gains_max": float(np.max(gains[label]))}
            print(name, label, json.dumps(block[label]), flush=True)
        gain_sets = {"no gains": np.ones_like(np.array(gains["after"])), "before": gains["before"],
                     "after": gains["after"]}
        block["overlap_differences"] = overlap_differences(root, white, gain_sets, args.step)
        print(name, "overlaps", json.dumps(block["overlap_differences"]), flush=True)
        results["blocks"][name] = block
        shutil.rmtree(root)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("->", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
