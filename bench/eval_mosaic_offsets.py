"""Per-frame gain AND offset balancing (issue 42, i42-offsets): the mosaic with the gains only (main before it, loaded
from git as a separate module) against gains and offsets by least squares (now), in one process ->
bench/results/mosaic_offsets.json.

Blocks (copies of rectified projects: frame orthos, index, project.toml; the originals are never written):

- ``demo``: the demo's frame orthos; scored against the simulator's truth orthophoto (``truth/ortho.tif`` of the
  source project, averaged onto the mosaic's grid): RMS of mosaic - truth over the mosaic's valid pixels, per pixel
  and on 4 m blocks (10 x 10 mosaic pixels: the level, not the registration), with and without the mean bias
  (without: the balance; with: the level as well).
- ``demo_haze``: the same frames with an additive haze of ``--haze-dn`` DN on every other frame (sorted by name: in
  every strip, neighbours differ), the valid samples below white raised and clipped at white (index.json's sizes and
  hashes rewritten); the same truth. The frames' own level is half a haze above the truth's: the prior keeps the
  block's mean offset at 0, so the bias-free RMS is what the balance removes.
- ``brighton``: the Brighton Beach drone frames (no truth): the seams and overlaps only.

Per run: the saturated shares (``eval_mosaic_clipping.saturation``: frames pooled, mosaic, new in every frame: at
white in the mosaic but in no frame covering the pixel) and the same at black (any band 0), the mosaic's mean against
the frames' pooled mean, the gains' and offsets' ranges and means, the roll-off and toe (mosaic.json), the overlap
differences through gains, offsets and curves (``eval_mosaic_brightness.overlap_differences``' measures, every
``--step``-th pixel neither frame has at white or black), and the seam step: along every seamline of seams.tif, the
mosaic's mean on the seam grid ``reach`` cells (beyond the feather) either side, the difference frame i - frame j
averaged per pair of frames; its RMS over pairs (weighted by length) is a step the eye sees, its RMS over cells
includes the texture (on the demo the same cells of the truth give the texture's share).

One parameter was chosen, on demo_haze: the spreads' weight against the means (``SPREAD_WEIGHT`` 0.3 of 0.1 / 0.3 / 1,
the least tone-quarter RMS of the overlaps, 0.3 and 1 within 0.001 DN, the pair-mean RMS breaking the tie; "choice" in
each block's record, Brighton reports it). Set a priori: the
offsets' bound (``OFFSET_MAX_SHARE``, 5 % of white: haze and black levels; the demo's 8 DN haze needs 4 %), the prior
(0.1, the gains'), the toe's knee bound (``TOE_KNEE_MAX``) and the highlight roll-off's (``ROLLOFF_KNEE_MIN``). The
offsets are the mosaic setting ``offsets = true`` (default false: gains only).

Usage: python bench/eval_mosaic_offsets.py --demo PROJECT --brighton PROJECT [--work DIR] [--step 4] [--haze-dn 8]
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from eval_mosaic_brightness import load_at, pooled_mean  # noqa: E402
from eval_mosaic_clipping import copy_project, frames_of, overlap_samples, saturation  # noqa: E402
from ortho import mosaic as mosaic_now  # noqa: E402
from ortho.block import file_fingerprint, read_index  # noqa: E402
from ortho.grid import OrthoGrid  # noqa: E402
from ortho.settings import MosaicSettings  # noqa: E402

GAINS_ONLY = "ecce2d32"  # main before i42-offsets: per-band log-gains, one highlight roll-off


def add_haze(root: Path, haze_dn: int) -> list:
    """Every other frame (sorted by name) of ``root`` with ``haze_dn`` added to its valid samples (clipped at the
    type's maximum), written in place of the copy; index.json's sizes and hashes rewritten. Returns the names."""
    path = root / "ortho" / "frames" / "index.json"
    doc = json.loads(path.read_text())
    hazy = []
    for k, e in enumerate(sorted(doc["frames"], key=lambda e: e["image_id"])):
        if k % 2 == 0:
            continue
        p = root / "ortho" / "frames" / e["file"]
        with rasterio.open(p) as ds:
            a, mask, profile = ds.read(), ds.read_masks(1), ds.profile
        top = np.iinfo(a.dtype).max
        a = np.where(mask[None] > 0, np.minimum(a.astype(np.int64) + haze_dn, top), a).astype(a.dtype)
        p.unlink()
        with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(p, "w", **profile) as ds:
            ds.write(a)
            ds.write_mask(mask)
        fp = file_fingerprint(p)
        e["size"], e["sha1"] = fp.size, fp.sha1
        hazy.append(e["image_id"])
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return hazy


def black(root: Path) -> dict:
    """Shares at black (% of the mosaic's valid pixels, any band 0): the frames pooled, the mosaic, and the mosaic's
    pixels at black in no frame covering them."""
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    with rasterio.open(root / "ortho" / "mosaic.tif") as M:
        mos, ok, mt = M.read(), M.read_masks(1) > 0, M.transform
    blk = (mos == 0).any(0) & ok
    anyf = np.zeros(ok.shape, bool)
    fb = fv = 0
    for _, a, fm, ft in frames_of(root, list(summary["gains"])):
        z = (a == 0).any(0) & fm
        fb += int(z.sum())
        fv += int(fm.sum())
        dc, dr = round((ft.c - mt.c) / mt.a), round((ft.f - mt.f) / mt.e)
        r0, c0 = max(dr, 0), max(dc, 0)
        r1, c1 = min(dr + a.shape[1], ok.shape[0]), min(dc + a.shape[2], ok.shape[1])
        anyf[r0:r1, c0:c1] |= z[r0 - dr:r1 - dr, c0 - dc:c1 - dc]
    n = int(ok.sum())
    return {"frames_pooled_pct": 100 * fb / fv, "mosaic_pct": 100 * float(blk.sum()) / n,
            "new_in_every_frame_pct": 100 * float((blk & ~anyf).sum()) / n}


def through(x: np.ndarray, g: np.ndarray, o: np.ndarray, summary: dict, white: int) -> np.ndarray:
    """Samples (bands, n) float32 through gains and offsets (bands,) and the block's curves (mosaic.json's records),
    as the mosaic's lookup tables."""
    v = x * g[:, None].astype(np.float32) + o[:, None].astype(np.float32)
    if summary.get("highlight_rolloff"):
        mosaic_now.HighlightRolloff(**summary["highlight_rolloff"]).apply(v)
    if summary.get("shadow_toe"):
        mosaic_now.ShadowToe(**summary["shadow_toe"]).apply(v)
    return np.clip(np.rint(v), 0, white)


def overlap_pairs_px(root: Path, names, white: int, step: int) -> list:
    """(i, j, samples of i, samples of j) (bands, n) at every ``step``-th mosaic pixel both frames have valid and
    neither at white or black."""
    return overlap_samples(root, names, white, step, without_black=True)[0]


def overlap_differences(pairs: list, summary: dict, white: int) -> dict:
    """Pixel RMS and pair-mean RMS (DN and % of the overlaps' level) of the differences across every overlap through
    the run's gains, offsets and curves."""
    names = list(summary["gains"])
    g = np.array([summary["gains"][n] for n in names], np.float32)
    offs = summary.get("offsets")
    o = np.array([offs[n] for n in names], np.float32) if offs else np.zeros_like(g)
    sq = cnt = level = 0.0
    means, weights, qsq, qn = [], [], 0.0, 0
    for i, j, xi, xj in pairs:
        vi, vj = through(xi, g[i], o[i], summary, white), through(xj, g[j], o[j], summary, white)
        d = vi - vj
        level += float(vi.sum() + vj.sum()) / 2
        sq += float((d * d).sum())
        cnt += d.size
        means.append(d.mean(axis=1))
        weights.append(d.shape[1])
        # the pair's mean difference in each quarter of its tones (split by the two frames' raw mean, per band): a
        # difference of offset that a gain takes up leaves the darks apart one way and the brights the other
        raw = (xi + xj) / 2
        for b in range(d.shape[0]):
            edges = np.quantile(raw[b], [0.25, 0.5, 0.75])
            q = np.searchsorted(edges, raw[b])
            n_q = np.bincount(q, minlength=4)
            s_q = np.bincount(q, weights=d[b], minlength=4)
            ok = n_q > 0
            qsq += float((s_q[ok] ** 2 / n_q[ok]).sum())  # sum over quarters of n x mean^2
            qn += int(n_q.sum())
    m, w = np.array(means), np.array(weights, float)
    pair_rms = float(np.sqrt((w[:, None] * m * m).sum() / (w.sum() * m.shape[1])))
    rms = float(np.sqrt(sq / cnt))
    return {"pair_quarter_mean_rms_dn": float(np.sqrt(qsq / qn)), "pixel_rms_dn": rms,
            "pixel_rms_pct_of_level": 100 * rms / (level / cnt),
            "pair_mean_rms_dn": pair_rms, "pair_mean_rms_pct_of_level": 100 * pair_rms / (level / cnt),
            "pairs": len(means), "samples": int(cnt)}


def _cells(a: np.ndarray, ok: np.ndarray, f: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """Means (bands, h, w) of ``a`` (bands, H, W) over the valid pixels of every f x f cell, and the cells whose
    pixels are all valid."""
    h, w = shape
    H, W = h * f, w * f
    pa = np.zeros((a.shape[0], H, W), np.float64)
    pm = np.zeros((H, W), bool)
    pa[:, :a.shape[1], :a.shape[2]] = a[:, :H, :W]
    pm[:ok.shape[0], :ok.shape[1]] = ok[:H, :W]
    s = (pa * pm).reshape(a.shape[0], h, f, w, f).sum(axis=(2, 4))
    n = pm.reshape(h, f, w, f).sum(axis=(1, 3))
    return s / np.maximum(n, 1), n == f * f


def seam_steps(root: Path, extra: dict | None = None) -> dict:
    """The seam step (module doc) of the mosaic, and of the rasters ``extra`` (name -> (bands, H, W) on the mosaic's
    grid, e.g. the truth) at the same cells."""
    summary = json.loads((root / "ortho" / "mosaic.json").read_text())
    with rasterio.open(root / "ortho" / "mosaic.tif") as M, rasterio.open(root / "ortho" / "seams.tif") as S:
        mos, ok = M.read().astype(np.float64), M.read_masks(1) > 0
        lab, f = S.read(1), int(round(S.transform.a / M.transform.a))
    reach = int(math.ceil(2 * summary["feather_px"] / f)) + 1  # cells beyond the feather's reach
    rasters = {"mosaic": mos, **(extra or {})}
    cells = {k: _cells(v, ok, f, lab.shape) for k, v in rasters.items()}
    full = cells["mosaic"][1]
    out = {"reach_cells": reach, "cell_px": f}
    for name, (c, _) in cells.items():
        per_pair, all_d = {}, []
        for axis in (0, 1):
            L = np.moveaxis(lab, axis, 0)
            V = np.moveaxis(c, axis + 1, 1)
            F = np.moveaxis(full, axis, 0)
            n = L.shape[0]
            for s in range(reach, n - reach - 1):
                a_lab, b_lab = L[s], L[s + 1]
                # a seam between cells s and s + 1, the same frame `reach` cells back on each side
                sel = (a_lab != b_lab) & (a_lab >= 0) & (b_lab >= 0) & (L[s - reach + 1] == a_lab) & \
                      (L[s + reach] == b_lab) & F[s - reach + 1] & F[s + reach]
                if not sel.any():
                    continue
                d = V[:, s - reach + 1][:, sel] - V[:, s + reach][:, sel]  # (bands, m): side a - side b
                ia, ib = a_lab[sel], b_lab[sel]
                sign = np.where(ia < ib, 1.0, -1.0)
                d = d * sign
                all_d.append(d)
                for p in set(zip(np.minimum(ia, ib).tolist(), np.maximum(ia, ib).tolist())):
                    m = (np.minimum(ia, ib) == p[0]) & (np.maximum(ia, ib) == p[1])
                    acc = per_pair.setdefault(p, [np.zeros(d.shape[0]), 0])
                    acc[0] += d[:, m].sum(axis=1)
                    acc[1] += int(m.sum())
        m = np.array([v[0] / v[1] for v in per_pair.values()])
        w = np.array([v[1] for v in per_pair.values()], float)
        d = np.concatenate(all_d, axis=1)
        out[name] = {"pair_mean_rms_dn": float(np.sqrt((w[:, None] * m * m).sum() / (w.sum() * m.shape[1]))),
                     "cell_rms_dn": float(np.sqrt((d * d).mean())), "pairs": len(per_pair), "cells": int(d.shape[1])}
    return out


def root_res(root: Path) -> float:
    with rasterio.open(root / "ortho" / "mosaic.tif") as M:
        return M.transform.a


def truth_on_mosaic(truth: Path, root: Path) -> np.ndarray:
    """The truth orthophoto (bands, H, W) averaged onto the mosaic's grid."""
    with rasterio.open(root / "ortho" / "mosaic.tif") as M, rasterio.open(truth) as T:
        out = np.zeros((M.count, M.height, M.width), np.float32)
        reproject(T.read().astype(np.float32), out, src_transform=T.transform, src_crs=T.crs, dst_transform=M.transform,
                  dst_crs=M.crs, resampling=Resampling.average)
    return out


def truth_errors(root: Path, truth: np.ndarray, block_px: int = 10) -> dict:
    """RMS of mosaic - truth (DN, all bands) over the mosaic's valid pixels, per pixel and on ``block_px`` blocks,
    with the mean bias and without it."""
    with rasterio.open(root / "ortho" / "mosaic.tif") as M:
        mos, ok = M.read().astype(np.float64), M.read_masks(1) > 0
    ok = ok & (truth.sum(axis=0) > 0)
    d = (mos - truth)[:, ok]
    bias = d.mean(axis=1)
    h, w = ok.shape[0] // block_px, ok.shape[1] // block_px
    bm, bt = _cells(mos, ok, block_px, (h, w)), _cells(truth.astype(np.float64), ok, block_px, (h, w))
    db = (bm[0] - bt[0])[:, bm[1]]
    # per frame the mosaic shows and quarter of the truth's tones (per band), the mean error: how well each frame's
    # tones are matched to the truth's (the level, the gain and the offset), bias of the whole block removed
    with rasterio.open(root / "ortho" / "seams.tif") as S:
        lab, f = S.read(1), int(round(S.transform.a / (root_res(root))))
    labels = np.repeat(np.repeat(lab, f, 0), f, 1)[:ok.shape[0], :ok.shape[1]][ok]
    tq = 0.0
    for b in range(d.shape[0]):
        t = truth[b][ok]
        q = np.searchsorted(np.quantile(t, [0.25, 0.5, 0.75]), t)
        key = labels.astype(np.int64) * 4 + q
        n_k = np.bincount(key[labels >= 0])
        s_k = np.bincount(key[labels >= 0], weights=d[b][labels >= 0] - bias[b])
        okk = n_k > 0
        tq += float((s_k[okk] ** 2 / n_k[okk]).sum()) / float(n_k.sum())
    return {"frame_quarter_mean_rms_unbiased_dn": float(np.sqrt(tq / d.shape[0])),
            "pixel_rms_dn": float(np.sqrt((d * d).mean())),
            "pixel_rms_unbiased_dn": float(np.sqrt(((d - bias[:, None]) ** 2).mean())),
            f"block{block_px}_rms_dn": float(np.sqrt((db * db).mean())),
            f"block{block_px}_rms_unbiased_dn": float(np.sqrt(((db - db.mean(axis=1)[:, None]) ** 2).mean())),
            "bias_dn": [float(b) for b in bias], "pixels": int(ok.sum()), "blocks": int(db.shape[1])}


def choice(root: Path, pairs: list, white: int, weights=(0.1, 0.3, 1.0), shares=(0.05, 1.0)) -> dict:
    """The spreads' weight (``SPREAD_WEIGHT``) and the offsets' bound (``OFFSET_MAX_SHARE``; 1: only the white and black
    bounds) tried on the frames of ``root``: the overlap differences through the gains and offsets alone (no curves),
    gains only first. The weight was chosen on demo_haze (least tone-quarter RMS), Brighton reports it."""
    index = read_index(root)
    mosaic = OrthoGrid.union(index.grids)
    red = mosaic_now.reduce_frames(root / "ortho" / "frames", index, mosaic, max(2, int(round(1.5 / mosaic.res_m))))
    names = red.names

    def measured(g, o):
        s = {"gains": {n: g[k].tolist() for k, n in enumerate(names)},
             "offsets": {n: o[k].tolist() for k, n in enumerate(names)}}
        r = overlap_differences(pairs, s, white)
        return {"pixel_rms_dn": r["pixel_rms_dn"], "pair_mean_rms_dn": r["pair_mean_rms_dn"],
                "pair_quarter_mean_rms_dn": r["pair_quarter_mean_rms_dn"],
                "offsets_min_dn": float(o.min()), "offsets_max_dn": float(o.max())}

    g = mosaic_now.balance_gains(red)
    out = {"gains only": measured(g, np.zeros_like(g))}
    for w in weights:
        for share in shares:
            rad = mosaic_now.balance_gains_offsets(
                red, spread_weight=w,
                bounds=lambda g, o, share=share: mosaic_now.offset_bounds(g, red.histograms(g, o), white, share))
            out[f"spread_weight {w} offset_max_share {share}"] = measured(rad.gains, rad.offsets)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, required=True, help="the demo project (ortho/frames and truth/ortho.tif)")
    ap.add_argument("--brighton", type=Path, help="the Brighton Beach project with ortho/frames")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/i42-offsets/bench"))
    ap.add_argument("--before", default=GAINS_ONLY, help="commit whose ortho/mosaic.py balanced gains only")
    ap.add_argument("--step", type=int, default=4, help="every step-th mosaic pixel for the overlap differences")
    ap.add_argument("--haze-dn", type=int, default=8)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "mosaic_offsets.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args.work.mkdir(parents=True, exist_ok=True)
    variants = (("gains", load_at(args.before, args.work, "gains"), None),
                ("gains+offsets", mosaic_now, MosaicSettings(offsets=True)))
    results = {"gains_only_commit": args.before, "step_px": args.step, "haze_dn": args.haze_dn,
               "spread_weight": mosaic_now.SPREAD_WEIGHT, "offset_max_share": mosaic_now.OFFSET_MAX_SHARE,
               "toe_knee_max": mosaic_now.TOE_KNEE_MAX, "rolloff_knee_min": mosaic_now.ROLLOFF_KNEE_MIN, "blocks": {}}
    blocks = [("demo", args.demo, False), ("demo_haze", args.demo, True)]
    if args.brighton is not None:
        blocks.append(("brighton", args.brighton, False))
    for name, src, haze in blocks:
        root = args.work / name
        copy_project(src, root)
        block = {"source": str(src)}
        if haze:
            block["hazy_frames"] = add_haze(root, args.haze_dn)
        truth = src / "truth" / "ortho.tif"
        pairs = truth_arr = None
        for label, mod, settings in variants:
            t = time.process_time()
            mod.mosaic_block(root, settings)
            cpu = time.process_time() - t
            summary = json.loads((root / "ortho" / "mosaic.json").read_text())
            white = summary["white_level"]["value"]
            names = list(summary["gains"])
            if "frames_pooled_mean_dn" not in block:
                block["frames_pooled_mean_dn"] = pooled_mean(root, names)
                pairs = overlap_pairs_px(root, names, white, args.step)
                block["overlap_differences_no_balance"] = overlap_differences(
                    pairs, {"gains": {n: [1.0] * 3 for n in names}}, white)
            gains = np.array(list(summary["gains"].values()))
            offs = np.array(list(summary["offsets"].values())) if summary.get("offsets") else np.zeros_like(gains)
            sat = saturation(root, white)
            run = {"cpu_s": round(cpu, 2), "white_level": white, "saturated": sat, "black": black(root),
                   "mean_vs_frames_pct": 100 * (sat["mosaic_mean_dn"] / block["frames_pooled_mean_dn"] - 1),
                   "gains_min": float(gains.min()), "gains_max": float(gains.max()),
                   "mean_log_gain": float(np.log(gains).mean()),
                   "offsets_min_dn": float(offs.min()), "offsets_max_dn": float(offs.max()),
                   "mean_offset_dn": float(offs.mean()),
                   "highlight_rolloff": summary.get("highlight_rolloff"), "shadow_toe": summary.get("shadow_toe"),
                   "overlap_differences": overlap_differences(pairs, summary, white)}
            if haze:
                hz = [names.index(n) for n in block["hazy_frames"]]
                clear = [k for k in range(len(names)) if k not in hz]
                run["mean_offset_hazy_minus_clear_dn"] = float(offs[hz].mean() - offs[clear].mean())
            extra = None
            if truth.exists():
                truth_arr = truth_on_mosaic(truth, root) if truth_arr is None else truth_arr
                run["vs_truth"] = truth_errors(root, truth_arr)
                extra = {"truth": truth_arr}
            run["seam_step"] = seam_steps(root, extra)
            block[label] = run
            print(name, label, json.dumps(run), flush=True)
        if name != "demo":
            block["choice"] = choice(root, pairs, white)
            print(name, "choice", json.dumps(block["choice"]), flush=True)
        results["blocks"][name] = block
        shutil.rmtree(root)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("->", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
