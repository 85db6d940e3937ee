"""Dark ground that loses most pulses, on and off the sloping water rule (water-fix)
-> bench/results/water_dark_ground.json.

Synthetic (EPSG:32610, 3 returns/m2, 3 cm noise, intensity 25 on the patch against 150 around it, seeded): a dark
patch whose pulses were mostly lost (wet asphalt, peat) in a field ``rim_m`` above it (a kerb; < 0: the patch
stands above its surroundings). Cases: the review's car park (150 x 40 m at 0.8 %, 10 % of pulses kept), road
(300 x 10 m at 0.6 %, 20 % kept), undulating field (160 x 60 m, +-0.3 m every 80 m, 10 % kept), each with the
rim heights 0.15, -0.1, 0.2, 0.3, 0.5 m for the car park and road (how deep a sunken patch must lie for the bed
test to take it for a river's bed), and a level car park (main's one-level rule) for comparison. No truth water:
every patch return called water is false. Counts of the patch's returns called water with the shipped settings
(``on``) and with ``water_sloping_surface`` off (``off``, main's rule before i44-water).

    nice .venv/bin/python bench/eval_water_dark_ground.py
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import REPO  # noqa: E402

from lidarctl import io, synthetic, tiles  # noqa: E402
from lidarctl.classify import pipeline as classify  # noqa: E402


def patch_cloud(length_m, width_m, surface, keep_share, rim_m, seed):
    rng = np.random.default_rng(seed)
    lt, wt = length_m + 80.0, width_m + 80.0
    n = int(lt * wt * 3.0)
    u, v = rng.uniform(0, lt, n), rng.uniform(0, wt, n)
    patch = (u > 40) & (u < 40 + length_m) & (v > 40) & (v < 40 + width_m)
    z = surface(u) + np.where(patch, 0.0, rim_m) + rng.normal(0, 0.03, n)
    keep = ~patch | (rng.random(n) < keep_share)
    intensity = np.where(patch, rng.normal(25, 8, n), rng.normal(150, 30, n)).clip(1, 1000)
    k = np.flatnonzero(keep)
    cloud = io.PointCloud(x=500000 + u[k], y=5000000 + v[k], z=z[k], intensity=intensity[k].astype(np.uint16),
                          return_number=np.ones(len(k), np.uint8), number_of_returns=np.ones(len(k), np.uint8),
                          classification=np.ones(len(k), np.uint8))
    return cloud, patch[k]


def water_on_patch(work: Path, name: str, cloud, truth, **settings) -> int:
    src = work / f"{name}.laz"
    synthetic.write_las(src, cloud, crs="EPSG:32610")
    out = work / f"out_{name}_{len(settings)}"
    tiles.classify_files([src], out, params=classify.ClassifySettings(**settings))
    cls = np.asarray(laspy.read(next(out.glob("*.laz"))).classification)
    return int(np.sum(cls[truth] == classify.WATER))


def main() -> int:
    cases = []
    for rim in (0.15, -0.1, 0.2, 0.3, 0.5):
        cases.append((f"car_park_0.8pct_rim_{rim:g}m", 150.0, 40.0, lambda u: 100.0 - 0.008 * u, 0.1, rim, 4))
        cases.append((f"road_0.6pct_rim_{rim:g}m", 300.0, 10.0, lambda u: 100.0 - 0.006 * u, 0.2, rim, 4))
    cases.append(("field_undulating_0.3m_80m_rim_0.3m", 160.0, 60.0,
                  lambda u: 100.0 + 0.3 * np.sin(2 * np.pi * u / 80.0), 0.1, 0.3, 5))
    cases.append(("car_park_level_rim_0.15m", 150.0, 40.0, lambda u: np.full(len(u), 100.0), 0.1, 0.15, 4))
    res = {}
    with tempfile.TemporaryDirectory(prefix="water_dark_") as tmp:
        for name, length_m, width_m, surface, keep, rim, seed in cases:
            cloud, truth = patch_cloud(length_m, width_m, surface, keep, rim, seed)
            on = water_on_patch(Path(tmp), name, cloud, truth)
            off = water_on_patch(Path(tmp), name, cloud, truth, water_sloping_surface=False)
            res[name] = {"patch_returns": int(truth.sum()), "water_on": on, "water_off": off}
            print(name, res[name], flush=True)
    out = {"command": "nice .venv/bin/python bench/eval_water_dark_ground.py", "what": __doc__.splitlines()[0],
           "truth": "no water: every patch return called water is false", "cases": res}
    path = REPO / "bench" / "results" / "water_dark_ground.json"
    tmp_path = path.with_suffix(".json.tmp")
    tmp_path.write_text(json.dumps(out, indent=2) + "\n")
    tmp_path.replace(path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
