"""How often do check points laid out as surveyors lay them out decide the heights (``height_datum.checks_spread``)?
Geometry only (no adjustment): DMC-like blocks of ``strips x frames`` projection centres (970 m between strips, 307 m
between frames), k check points one per cell of a regular grid over the ground the frames cover (the centres'
extent plus half a footprint: 691 m across, 384 m along) or over the centres' extent, or uniform at random over the
centres' extent; 400 draws each. Prints and writes the share that does NOT decide (the verdict then rests on the
control's own rule) at cuts 0.6 / 0.7 / 0.8 (review 38's families).

    python bench/eval_check_layouts.py --out bench/results/check_spread.json
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib

import numpy as np

from aerotri.adjust.height_datum import CHECK_SPREAD_MIN, HeightDatumCheck, _block_axes

CUTS = (0.6, 0.7, 0.8)


def _centres(ns: int, nf: int) -> np.ndarray:
    X, Y = np.meshgrid(np.arange(nf) * 307.0, np.arange(ns) * 970.0)
    return np.column_stack([X.ravel(), Y.ravel()])


def _grid(k: int, lo, hi) -> tuple[int, int]:
    aspect = (hi[0] - lo[0]) / (hi[1] - lo[1])
    return min(((r, math.ceil(k / r)) for r in range(2, k + 1) if math.ceil(k / r) >= 2),
               key=lambda rc: abs(rc[1] / rc[0] - aspect) + (rc[0] * rc[1] - k) * 0.3)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=pathlib.Path, default=None)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    out = {}
    for ns, nf in ((5, 20), (4, 12), (8, 10), (2, 25)):
        g = _centres(ns, nf)
        hd = HeightDatumCheck(1.0, 0.0, 0.0, 1e-4, ("a",), ("b",), **_block_axes(g - g.mean(axis=0)))
        lo, hi = g.min(axis=0) - g.mean(axis=0), g.max(axis=0) - g.mean(axis=0)
        for k in (5, 6, 7, 8):
            row = {}
            for plan in ("cells_over_ground", "cells_over_centres", "uniform_over_centres"):
                a0, b0 = (lo - [384.0, 691.0], hi + [384.0, 691.0]) if plan == "cells_over_ground" else (lo, hi)
                vals = []
                for _ in range(400):
                    if plan == "uniform_over_centres":
                        u = rng.uniform(size=(k, 2))
                    else:
                        r, c = _grid(k, a0, b0)
                        cells = [(i, j) for i in range(r) for j in range(c)]
                        pick = [cells[i] for i in rng.choice(len(cells), k, replace=False)]
                        u = np.array([[(j + rng.uniform()) / c, (i + rng.uniform()) / r] for i, j in pick])
                    vals.append(hd.check_spread(a0 + u * (b0 - a0)))
                vals = np.array(vals)
                row[plan] = {f"not_deciding_at_{cut}": round(float(np.mean(vals < cut)), 3) for cut in CUTS}
                row[plan]["median_spread"] = round(float(np.median(vals)), 3)
            out[f"{ns}x{nf}_k{k}"] = row
            print(f"{ns} x {nf}, {k} check points: " + "  ".join(
                f"{p} " + "/".join(f"{100 * v[f'not_deciding_at_{c}']:.0f}" for c in CUTS) + " %"
                for p, v in row.items()))
    if a.out:
        old = json.loads(a.out.read_text()) if a.out.exists() else {}
        old["layouts"] = dict(cuts=CUTS, shipped_cut=CHECK_SPREAD_MIN, draws=400, blocks=out)
        a.out.write_text(json.dumps(old, indent=1) + "\n")


if __name__ == "__main__":
    main()
