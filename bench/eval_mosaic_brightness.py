"""Colour that neither clips nor darkens (issue 42, i42-bright): the mosaic's level, saturated share and overlap
differences with the gains as they were before any limit (``--unbounded``: they clip), capped per frame so that no
unsaturated sample reaches white (``--capped``, i42-clip: the block darkens) and now (level kept, a highlight
roll-off after the gains) -> bench/results/mosaic_brightness.json.

Per block (copies of rectified projects: frame orthos, index, project.toml; the originals are never written), in
this process: ``mosaic_block`` of ``ortho/mosaic.py`` at each commit (loaded from git as a separate module), then as it
is now. Per run: the saturated shares of ``eval_mosaic_clipping.saturation`` (the frames pooled, the mosaic, "new in
every frame": at white in the mosaic but in no frame covering the pixel), the mosaic's mean DN against the frames'
pooled mean DN (all bands, every valid pixel of every frame), the gains' range and mean log-gain, the roll-off
(mosaic.json "highlight_rolloff"), and the overlap differences (DN, all bands, every ``--step``-th mosaic pixel
neither frame of the pair has at white): the RMS of the pixel differences between every pair of overlapping frames
through their gains (and roll-off), that RMS in % of the overlaps' mean DN through the gains (a darker block differs
less in DN), and the RMS over pairs of the pair's mean difference (what the balance minimises).
A preview PNG of every mosaic (its overview of about 1500 px) goes to ``--work``/previews.

Nothing here was tuned: the roll-off's knee is 2 (white - 0.5) - the block's largest unsaturated sample through its
gain, never below white / 2 (``ortho.mosaic.ROLLOFF_KNEE_MIN``, set a priori).

Usage: python bench/eval_mosaic_brightness.py BLOCK=PROJECT [BLOCK=PROJECT ...] [--work DIR] [--step 4]
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

import cv2
import numpy as np
import rasterio

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from eval_mosaic_clipping import copy_project, frames_of, overlap_samples, saturation  # noqa: E402
from ortho import mosaic as mosaic_now  # noqa: E402

UNBOUNDED = "53b51bd3"  # before i42-clip: gains from the balance alone (clip)
CAPPED = "126fd31d"  # i42-clip: gains capped at (white - 0.5) / the frame's largest unsaturated sample


def load_at(commit: str, work: Path, name: str):
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{commit}:ortho/mosaic.py"], check=True,
                         capture_output=True, text=True).stdout
    path = work / f"mosaic_{name}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f"ortho._mosaic_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def pooled_mean(root: Path, names) -> float:
    """Mean DN of every valid sample of every frame (all bands)."""
    total = count = 0.0
    for _, a, ok, _ in frames_of(root, names):
        total += float(a[:, ok].sum(dtype=np.float64))
        count += a.shape[0] * float(ok.sum())
    return total / count


def through(x: np.ndarray, g: np.ndarray, rolloff, white: int, top: int) -> np.ndarray:
    """Samples (bands, n) float32 through gains (bands,) and the roll-off (a record, a ``HighlightRolloff`` or None:
    none), as the mosaic's lookup."""
    v = x * g[:, None]
    if rolloff is not None:
        curve = rolloff if isinstance(rolloff, mosaic_now.HighlightRolloff) else mosaic_now.HighlightRolloff(**rolloff)
        curve.apply(v)
    return np.clip(np.rint(v), 0, min(white, top))


def per_frame_rolloffs(root: Path, names, gains: np.ndarray, white: int) -> list:
    """The alternative not taken: a roll-off per frame from its own largest unsaturated sample through its gain (None
    for a frame none of whose unsaturated samples reaches white - 0.5), for the overlap differences only."""
    top_out = (white - 0.5) * (1.0 - 1e-6)
    out = []
    for k, (_, a, ok, _) in enumerate(frames_of(root, names)):
        m = np.array([int(b[ok & (b < white)].max(initial=0)) for b in a], float)
        v = float(np.max(gains[k] * m))
        if v <= top_out:
            out.append(None)
            continue
        top_in = min(v, mosaic_now.ROLLOFF_HEADROOM * top_out)
        out.append(mosaic_now.HighlightRolloff(2 * top_out - top_in, top_in, top_out))
    return out


def overlap_differences(root: Path, names, white: int, runs: dict, step: int) -> dict:
    """Per run (label -> (gains (frames, bands), roll-off record, None, or a list of them per frame)) the pixel RMS
    and the pair-mean RMS of the differences across overlaps (module doc)."""
    pairs, top = overlap_samples(root, names, white, step)
    out = {}
    for label, (gains, rolloff) in runs.items():
        g = np.asarray(gains, np.float32)
        sq = cnt = level = 0.0
        means, weights = [], []
        for i, j, xi, xj in pairs:
            ri, rj = (rolloff[i], rolloff[j]) if isinstance(rolloff, list) else (rolloff, rolloff)
            vi, vj = through(xi, g[i], ri, white, top), through(xj, g[j], rj, white, top)
            d = vi - vj
            level += float(vi.sum() + vj.sum()) / 2
            sq += float((d * d).sum())
            cnt += d.size
            means.append(d.mean(axis=1))
            weights.append(d.shape[1])
        m, w = np.array(means), np.array(weights, float)
        out[label] = {"pixel_rms_dn": float(np.sqrt(sq / cnt)),
                      # the differences scale with the level (a block made 5 % darker differs 5 % less)
                      "pixel_rms_pct_of_level": float(100 * np.sqrt(sq / cnt) / (level / cnt)),
                      "pair_mean_rms_dn": float(np.sqrt((w[:, None] * m * m).sum() / (w.sum() * m.shape[1]))),
                      "pair_mean_rms_pct_of_level": float(100 * np.sqrt((w[:, None] * m * m).sum()
                                                                        / (w.sum() * m.shape[1])) / (level / cnt)),
                      "pairs": len(means), "samples": int(cnt)}
    return out


def preview(root: Path, out: Path, white: int, max_px: int = 1500) -> None:
    """The mosaic's first three bands at about ``max_px`` on the long side, scaled to 8 bits by the white level."""
    with rasterio.open(root / "ortho" / "mosaic.tif") as ds:
        f = max(1, int(np.ceil(max(ds.width, ds.height) / max_px)))
        shape = (min(3, ds.count), max(1, ds.height // f), max(1, ds.width // f))
        a = ds.read(list(range(1, shape[0] + 1)), out_shape=shape).astype(np.float32)
    img = np.clip(np.rint(a * (255.0 / white)), 0, 255).astype(np.uint8)
    cv2.imwrite(str(out), cv2.cvtColor(np.moveaxis(img, 0, -1), cv2.COLOR_RGB2BGR))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("blocks", nargs="+", help="NAME=PROJECT (a project with ortho/frames made)")
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/i42-bright/bench"))
    ap.add_argument("--unbounded", default=UNBOUNDED, help="commit whose ortho/mosaic.py had unbounded gains")
    ap.add_argument("--capped", default=CAPPED, help="commit whose ortho/mosaic.py capped the gains (i42-clip)")
    ap.add_argument("--step", type=int, default=4, help="every step-th mosaic pixel for the overlap differences")
    ap.add_argument("--repeats", type=int, default=1,
                    help="mosaics per variant, in turn (cpu_s: the least of them; the machine's load varies)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "mosaic_brightness.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args.work.mkdir(parents=True, exist_ok=True)
    (args.work / "previews").mkdir(exist_ok=True)
    variants = (("unbounded", load_at(args.unbounded, args.work, "unbounded")),
                ("capped", load_at(args.capped, args.work, "capped")), ("rolloff", mosaic_now))
    results = {"unbounded_commit": args.unbounded, "capped_commit": args.capped, "step_px": args.step,
               "rolloff_knee_min": mosaic_now.ROLLOFF_KNEE_MIN, "blocks": {}}
    for spec in args.blocks:
        name, src = spec.split("=", 1)
        root = args.work / name
        copy_project(Path(src), root)
        block = {"source": src}
        runs = {}
        cpus = {label: [] for label, _ in variants}
        for _ in range(args.repeats - 1):  # the variants in turn, so that a change of load hits them alike
            for label, mod in variants:
                t = time.process_time()
                mod.mosaic_block(root)
                cpus[label].append(time.process_time() - t)
        for label, mod in variants:
            t = time.process_time()
            mod.mosaic_block(root)
            cpu = min(cpus[label] + [time.process_time() - t])
            summary = json.loads((root / "ortho" / "mosaic.json").read_text())
            white = summary["white_level"]["value"]
            names = list(summary["gains"])
            if "frames_pooled_mean_dn" not in block:
                block["frames_pooled_mean_dn"] = pooled_mean(root, names)
            gains = np.array(list(summary["gains"].values()))
            rolloff = summary.get("highlight_rolloff")
            runs[label] = (gains, rolloff)
            sat = saturation(root, white)
            block[label] = {"cpu_s": round(cpu, 2), "repeats": args.repeats, "white_level": white, **sat,
                            "mean_vs_frames_pct": 100 * (sat["mosaic_mean_dn"] / block["frames_pooled_mean_dn"] - 1),
                            "gains_min": float(gains.min()), "gains_max": float(gains.max()),
                            "mean_log_gain": float(np.log(gains).mean()), "highlight_rolloff": rolloff}
            preview(root, args.work / "previews" / f"{name}_{label}.png", white)
            print(name, label, json.dumps(block[label]), flush=True)
        runs = {"no gains": (np.ones_like(runs["rolloff"][0]), None), **runs,
                "rolloff per frame (not taken)": (runs["rolloff"][0],
                                                  per_frame_rolloffs(root, names, runs["rolloff"][0], white))}
        block["overlap_differences"] = overlap_differences(root, names, white, runs, args.step)
        print(name, "overlaps", json.dumps(block["overlap_differences"]), flush=True)
        results["blocks"][name] = block
        shutil.rmtree(root)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("->", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
