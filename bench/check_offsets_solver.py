"""offsets-fixes2: the bounded balance (``_bounded_solve``, primal-dual active set on the sparse normal equations) on
synthetic blocks of side x side frames whose frames differ by large offsets (uniform +-40 DN, gains e^N(0, 0.1): most
offsets held at their bounds, as Brighton's 38 of 54), against scipy's trust-region reflective solver run to
convergence (max_iter 5000) on the dense normal equations for the small blocks; the time of the gains alone and with
offsets; bench/results/offsets_solver.json.

    nice .venv/bin/python bench/check_offsets_solver.py --sides 6 10 20 25 32 --reference-max 10
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import ortho.mosaic as om
from ortho.mosaic import (ROLLOFF_HEADROOM, ReducedFrames, balance_gains, balance_gains_offsets, gain_caps,
                          offset_bounds, sample_histogram)


def block(side: int, cell: int = 24, step: int = 16):
    """The synthetic block of offsets_scale.py (review s7): one scene, frames with gains and offsets of their own."""
    rng = np.random.default_rng(0)
    H = step * (side - 1) + cell
    scene = np.clip(110 + 40 * rng.standard_normal((H, H, 3)), 1, 254)
    truth_o = rng.uniform(-40, 40, side * side)
    truth_g = np.exp(rng.normal(0, 0.1, side * side))
    names, rgb, valid, offs = [], [], [], []
    for r in range(side):
        for c in range(side):
            k = r * side + c
            a = scene[r * step:r * step + cell, c * step:c * step + cell] * truth_g[k] + truth_o[k]
            names.append(f"f{k}")
            rgb.append(np.clip(np.rint(a), 0, 255).astype(np.uint8))
            valid.append(np.ones((cell, cell), bool))
            offs.append((r * step, c * step))
    red = ReducedFrames(names, rgb, valid, offs, factor=1, seam_transform=None, shape=(H, H))
    red.sample_histograms = [sample_histogram(np.moveaxis(x, 2, 0), v) for x, v in zip(rgb, valid)]
    return red


def reference_solve(N, u, cap, floor=None, low_rank=None, max_iter=None):
    """The former solver (dense Cholesky, trust-region reflective) run to convergence."""
    from scipy.optimize import lsq_linear

    dense = N.toarray() if hasattr(N, "toarray") else np.array(N, float)
    if low_rank is not None:
        dense = dense + low_rank @ low_rank.T
    chol = np.linalg.cholesky(dense)
    lo = np.full(len(u), -np.inf) if floor is None else np.where(np.isfinite(floor), floor, -np.inf)
    res = lsq_linear(chol.T, np.linalg.solve(chol, u), bounds=(lo, np.where(np.isfinite(cap), cap, np.inf)),
                     method="trf", tol=1e-12, max_iter=5000)
    assert res.status > 0, res.status
    return om.BoundedSolution(np.clip(res.x, lo, cap), True, int(res.nit))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sides", type=int, nargs="+", default=[10, 20, 32])
    ap.add_argument("--reference-max", type=int, default=10, help="largest side compared with the dense solve")
    ap.add_argument("--out", default="bench/results/offsets_solver.json")
    args = ap.parse_args()
    rows = []
    for side in args.sides:
        red = block(side)
        caps = lambda g: gain_caps(red.histograms(g), 3, 255, ROLLOFF_HEADROOM)  # noqa: E731
        bounds = lambda g, o: offset_bounds(g, red.histograms(g, o), 255)  # noqa: E731
        iters = []
        real = om._bounded_solve

        def spy(*a, **k):
            res = real(*a, **k)
            iters.append((res.iterations, res.converged))
            return res

        om._bounded_solve = spy
        try:
            t = time.process_time()
            balance_gains(red, caps=caps)
            t_gains = time.process_time() - t
            t = time.process_time()
            rad = balance_gains_offsets(red, caps=caps, bounds=bounds)
            t_off = time.process_time() - t
        finally:
            om._bounded_solve = real
        lo, hi = bounds(rad.gains, rad.offsets)
        row = {"frames": side * side, "cpu_s_gains_only": round(t_gains, 2), "cpu_s_offsets": round(t_off, 2),
               "active_set_iterations_converged": iters, "offsets_held": int((rad.offset_held != 0).sum()),
               "gains_held": int(rad.gain_held.sum()), "offsets": int(rad.offsets.size),
               "offsets_within_1e-3_dn_of_a_bound": int((np.minimum(np.abs(rad.offsets - lo),
                                                                      np.abs(rad.offsets - hi)) < 1e-3).sum()),
               "outside_bounds_by_1e-6": int(((rad.offsets < lo - 1e-6) | (rad.offsets > hi + 1e-6)).sum())}
        if side <= args.reference_max:
            om._bounded_solve = reference_solve
            try:
                t = time.process_time()
                ref = balance_gains_offsets(red, caps=caps, bounds=bounds)
                row["cpu_s_reference"] = round(time.process_time() - t, 2)
            finally:
                om._bounded_solve = real
            row["max_abs_offset_diff_dn"] = float(np.abs(rad.offsets - ref.offsets).max())
            row["max_rel_gain_diff"] = float(np.abs(rad.gains / ref.gains - 1).max())
            row["reference_offsets_held"] = int((ref.offset_held != 0).sum())
        print(json.dumps(row), flush=True)
        rows.append(row)
    Path(args.out).write_text(json.dumps({"blocks": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
