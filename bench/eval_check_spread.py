"""When do check points decide the heights? The spread rule of ``aerotri.adjust.height_datum.checks_spread``
measured on simulated blocks (review 36): GNSS heights 1 m low, shift_drift, two control heights mistyped (review 32's
block, tests/aerotri/adjust/test_height_datum._project), 20 check points over the block. For each seed the check
points' subsets a user might have: the k nearest gcp01 (a corner cluster), random subsets of 5 and 10, all 20, and
the points within 250 m of the block's diagonal. Per subset: its ``check_spread``, its RMS Z, and the RMS Z of all 20
(the truth here); a subset that says "within the limit" while all 20 say "beyond" would give a wrong "Successful" if
it decided. Writes bench/results/check_spread.json.

    python bench/eval_check_spread.py --seeds 0-11 --out bench/results/check_spread.json
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "aerotri" / "adjust"))

LIMIT_M = 1.0


def _subsets(xy: dict, rng) -> dict:
    g0 = xy["__gcp01"]
    pts = {k: v for k, v in xy.items() if not k.startswith("__")}
    ids = sorted(pts)
    near = sorted(pts, key=lambda k: float(np.hypot(*(pts[k] - g0))))
    out = {f"nearest_gcp01_{k}": near[:k] for k in (3, 5, 8)}
    for n in (5, 10):
        for r in range(3):
            out[f"random_{n}_{r}"] = list(rng.choice(ids, n, replace=False))
    out["all_20"] = ids
    P = np.array([pts[k] for k in ids])
    lo, hi = P.min(axis=0), P.max(axis=0)
    # a surveyor's layout: one point per cell of a regular grid over the check points' area (the nearest to each
    # cell's centre)
    for nx, ny in ((3, 2), (2, 3), (4, 2), (3, 3)):
        pick = []
        for c in (lo + (hi - lo) * [(i + 0.5) / nx, (j + 0.5) / ny] for i in range(nx) for j in range(ny)):
            pick.append(min((q for q in ids if q not in pick), key=lambda q: float(np.hypot(*(pts[q] - c)))))
        out[f"cells_{nx}x{ny}"] = pick
    d = (hi - lo) / np.linalg.norm(hi - lo)
    nrm = np.array([-d[1], d[0]])
    out["diagonal_250m"] = [k for k in ids if abs(float((pts[k] - lo) @ nrm)) < 250.0]
    return out


def main() -> None:
    from test_height_datum import _project

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="0-11")
    ap.add_argument("--out", type=pathlib.Path, default=None)
    ap.add_argument("--key", default=None, help="the JSON key (default seeds_<seeds>)")
    a = ap.parse_args()
    lo, hi = (int(v) for v in a.seeds.split("-"))
    rows = []
    for seed in range(lo, hi + 1):
        rng = np.random.default_rng(seed)
        with tempfile.TemporaryDirectory() as d:
            ba, _ = _project(pathlib.Path(d), low_m=1.0, mistyped=2, correction="shift_drift", shift_m=0.3,
                             typo_m=2.0, seed=seed, shift_sigma_m=0.5, n_check=20)
        hd = ba.result.height_datum
        if hd is None:
            rows.append(dict(seed=seed, height_datum=None))
            continue
        dz = {k: c["adjusted_m"][2] - c["measured_m"][2] for k, c in ba.check.items()}
        xy = {k: np.asarray(c["measured_m"][:2], dtype=float) for k, c in ba.check.items()}
        xy["__gcp01"] = np.asarray(ba.control.xyz_m[list(ba.control.id).index("gcp01"), :2], dtype=float)
        rms_all = float(np.sqrt(np.mean(np.square(list(dz.values())))))
        for name, keep in _subsets(xy, rng).items():
            if len(keep) < 3:
                continue
            rms = float(np.sqrt(np.mean([dz[k] ** 2 for k in keep])))
            spread = hd.check_spread(np.array([xy[k] for k in keep]))
            rows.append(dict(seed=seed, subset=name, n=len(keep), spread=spread,
                             rms_z_m=rms, rms_z_all_m=rms_all, rule_held=hd.held(LIMIT_M),
                             wrong_if_decides=bool(rms <= LIMIT_M < rms_all),
                             right_if_decides=bool((rms <= LIMIT_M) == (rms_all <= LIMIT_M))))
        print(f"seed {seed}: RMS Z all {rms_all:.2f} m, rule held {hd.held(LIMIT_M)}", flush=True)
    res = dict(limit_m=LIMIT_M, seeds=a.seeds, rows=rows)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        old = json.loads(a.out.read_text()) if a.out.exists() else {}
        old[a.key or f"seeds_{a.seeds}"] = res
        a.out.write_text(json.dumps(old, indent=1) + "\n")
    for r in rows:
        if "subset" in r:
            print(f"  seed {r['seed']:2d} {r['subset']:18s} n {r['n']:2d} spread {r['spread']:.2f} "
                  f"RMS Z {r['rms_z_m']:.2f}"
                  f" / all {r['rms_z_all_m']:.2f}{'  WRONG if it decides' if r['wrong_if_decides'] else ''}")


if __name__ == "__main__":
    main()
