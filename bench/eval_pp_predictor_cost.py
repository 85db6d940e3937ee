"""What pp-predictor adds to an adjustment: ``geometry_modes._tie_plan_ms`` (one pass over the rays: the points'
plan change under a camera-fixed GNSS offset by back-substitution) besides ``pp_gnss_coupling`` (the offset estimate
is a 2 x 2 solve). Two measurements, written to bench/results/pp_predictor_cost.json under their key:

    python bench/eval_pp_predictor_cost.py block B/b300     # B/b300 from: python bench/adjust_scale.py make B/b300
                                                            # --frames 300; 'aerotri adjust B/b300 --dem
                                                            # B/b300/dem.tif --no-exports' in-process, CPU of the
                                                            # pass, of pp_gnss_coupling, geometry_modes and the whole
    python bench/eval_pp_predictor_cost.py synthetic        # the pass alone on a synthetic geometry with the
                                                            # obs_10k block's counts (10,000 frames, 5,270,688 rays,
                                                            # 1,300,000 points): CPU and peak memory
"""

from __future__ import annotations

import json
import resource
import sys
import time
import types
from pathlib import Path

import numpy as np

import aerotri.adjust.geometry_modes as GM

OUT = Path(__file__).resolve().parent / "results" / "pp_predictor_cost.json"


def _timed(fn, times: list):
    def wrapper(*a, **k):
        t = time.process_time()
        out = fn(*a, **k)
        times.append(round(time.process_time() - t, 3))
        return out
    return wrapper


def block(root: str) -> dict:
    import aerotri.adjust.solve as S
    from aerotri.cli import main

    t = {"tie_plan_ms_cpu_s": [], "pp_gnss_coupling_cpu_s": [], "geometry_modes_cpu_s": []}
    rays = []
    tie_plan = GM._tie_plan_ms
    GM._tie_plan_ms = _timed(lambda b, pr, dc: (rays.append(len(pr.pt)), tie_plan(b, pr, dc))[1],
                             t["tie_plan_ms_cpu_s"])
    GM.pp_gnss_coupling = _timed(GM.pp_gnss_coupling, t["pp_gnss_coupling_cpu_s"])
    S.geometry_modes = _timed(S.geometry_modes, t["geometry_modes_cpu_s"])
    t0 = time.process_time()
    try:
        main(["adjust", root, "--dem", str(Path(root) / "dem.tif"), "--no-exports"], standalone_mode=False)
    except SystemExit:
        pass
    return {"block": root, "rays": rays, **t, "adjust_cpu_s": round(time.process_time() - t0, 1)}


def synthetic() -> dict:
    from aerotri.adjust import graph as G
    from aerotri.adjust.covariance import PointRays

    rng = np.random.default_rng(0)
    n, p, k = 10_000, 1_300_000, 5_270_688
    cx, cy = np.meshgrid(np.arange(200) * 300.0, np.arange(50) * 500.0)
    centre = np.column_stack([cx.ravel(), cy.ravel(), np.full(n, 1000.0)])
    R = np.tile(np.diag([1.0, -1.0, -1.0]), (n, 1, 1))  # nadir: camera z down
    im = np.concatenate([np.arange(n), rng.integers(0, n, k - n)])
    pt = np.concatenate([np.arange(p), rng.integers(0, p, k - p)])
    points = np.column_stack([rng.uniform(0, 6e4, (p, 2)), np.zeros(p)])
    points[pt, :2] = centre[im, :2] + rng.uniform(-300, 300, (k, 2))  # under the ray's frame
    cal = np.array([10000.0, 10000.0, 0.0, 6912.0, 3840.0, 0, 0, 0, 0])
    state = G.State(centre, R, points, cal, np.zeros((1, 3)), np.zeros((1, 3)))
    pr = PointRays(pt, im, None, np.tile(np.eye(3) * 1e-3, (p, 1, 1)), np.ones(p, bool), 1 / 0.09, state, True,
                   np.arange(n) * 6, n * 6)
    dc = rng.normal(size=(n * 6 + 9, 2)) * 1e-4
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    t, w = time.process_time(), time.perf_counter()
    GM._tie_plan_ms(types.SimpleNamespace(n_points=p, control_point=np.zeros(0, int)), pr, dc)
    return {"frames": n, "rays": k, "points": p, "cpu_s": round(time.process_time() - t, 1),
            "wall_s": round(time.perf_counter() - w, 1), "peak_rss_mb_before": rss0,
            "peak_rss_mb_after": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def main() -> None:
    res = block(sys.argv[2]) if sys.argv[1] == "block" else synthetic()
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc["block" if sys.argv[1] == "block" else "synthetic_obs10k"] = res
    tmp = OUT.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(OUT)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
