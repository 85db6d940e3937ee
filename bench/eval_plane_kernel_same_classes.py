"""Issue 40: the classifier's plane-offset kernel with its own 3 x 3 solve and median (compiles in about 4 instead
of 13 CPU-s) classifies every point as the kernel of an earlier revision (np.linalg.solve, np.median).

    .venv/bin/python bench/eval_plane_kernel_same_classes.py REV [--keep TINY_PROJECT] [--out JSON]

REV: a git revision whose ``lidarctl/classify/pipeline.py`` has the old kernel (e.g. ``main`` before the change).
Classifies (``lidarctl.tiles.classify_files``, default settings) with each kernel and compares the written point
records: the tiny project's strips together (``--keep``: a simulated tiny project; skipped without), Brighton's
ODM cloud (every 4th point), AHN3 Delft and the 7 ISPRS filter-test samples (``$AEROTRI_SHARED_DATA``). Also the
kernel's outputs on 200,000 random neighbourhoods (they differ in the last bits) and its compile CPU-s each way
(run with an empty ``NUMBA_CACHE_DIR`` for the compile times of a fresh clone).
Writes bench/results/plane_kernel_same_classes.json."""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lidar_common import REPO, module_at  # noqa: E402

import lidarctl.classify.pipeline as new  # noqa: E402
from lidarctl import tiles  # noqa: E402


def kernel_outputs(old) -> dict:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(1)
    n = 200_000
    x, y = rng.uniform(0, 50, n), rng.uniform(0, 50, n)
    z = 0.05 * x + 0.02 * y + rng.normal(0, 0.05, n) + (rng.random(n) < 0.1) * rng.uniform(0, 5, n)
    d, nb = cKDTree(np.c_[x, y]).query(np.c_[x, y], 13, distance_upper_bound=1.0)
    nb, d, q = np.minimum(nb[:, 1:], n - 1), d[:, 1:], np.arange(n)
    out = {}
    for way, mod in (("old", old), ("new", new)):
        t = time.process_time()
        out[way] = mod._plane_offsets(x, y, z, q, nb, d, min_points=5, robust=True)
        out[f"{way}_first_call_cpu_s"] = round(time.process_time() - t, 2)
    res = {"n": n, "first_call_cpu_s": {w: out[f"{w}_first_call_cpu_s"] for w in ("old", "new")}}
    for i, name in enumerate(("dz_m", "spread_m")):
        a, b = out["new"][i], out["old"][i]
        res[name] = {"bit_identical": int(np.sum((a == b) | (np.isnan(a) & np.isnan(b)))),
                     "max_abs_difference": float(np.nanmax(np.abs(a - b)))}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rev")
    ap.add_argument("--keep", type=Path, default=None, help="A simulated tiny project (its lidar/*.las).")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "plane_kernel_same_classes.json")
    args = ap.parse_args(argv)
    data = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data"))
    result = {"command": f"NUMBA_CACHE_DIR=<empty> bench/eval_plane_kernel_same_classes.py {args.rev} --keep TINY",
              "clouds": {}}
    with tempfile.TemporaryDirectory(prefix="plane_kernel_") as tmp:
        tmp = Path(tmp)
        old = module_at(args.rev, "lidarctl/classify/pipeline.py", "old_pipeline", tmp)
        result["kernel"] = kernel_outputs(old)
        br = laspy.read(data / "brighton_beach" / "model.laz")
        sub = laspy.LasData(br.header)
        sub.points = br.points[np.arange(0, len(br.points), 4)]
        sub.write(tmp / "brighton4.laz")
        cases = {"brighton_every_4th": ([tmp / "brighton4.laz"], None),
                 "ahn3_delft": ([data / "ahn3_delft" / "ahn3_cropped_1.laz"], "EPSG:28992")}
        if args.keep:
            cases["tiny_strips"] = (sorted((args.keep / "lidar").glob("*.las")), "EPSG:32649")
        for f in sorted((data / "isprs_filtertest").glob("*.laz")):
            cases[f.stem] = ([f], None)
        for name, (files, crs) in cases.items():
            recs = {}
            for way, kernel in (("old", old._plane_offsets_kernel), ("new", new._plane_offsets_kernel)):
                with mock.patch.object(new, "_plane_offsets_kernel", kernel):
                    tiles.classify_files(files, tmp / f"{name}_{way}", crs=crs)
                recs[way] = {p.name: laspy.read(p) for p in sorted((tmp / f"{name}_{way}").glob("*.la[sz]"))}
            same = all(np.array_equal(np.asarray(recs["old"][k].points.array), np.asarray(recs["new"][k].points.array))
                       for k in recs["old"])
            n = sum(len(c.points) for c in recs["old"].values())
            result["clouds"][name] = {"files": len(files), "points": n, "records_identical": bool(same)}
            print(f"{name}: {n} points, point records identical: {same}", flush=True)
    print(json.dumps(result["kernel"]))
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
