"""LiDAR classification (``classify_points``) before/after: CPU seconds per M points, peak RSS and the
equality of the classes (issue 41) -> bench/results/classify_speed.json.

"Before" is another source tree of the package (main's code), e.g.
    git -C /work/main archive main aerotri lidarctl | tar -x -C /work/tmp/main_src
"after" this tree. Each (version, cloud) runs in its own process (peak RSS is per process), numba on
one thread (CPU seconds then do not include thread spinning), after a warm-up call on 100,000 of the
cloud's points (numba's compiled-code cache loaded, not timed). The inputs are read once and kept as
.npz in ``--work`` (x, y, z in metres, sanitized returns, intensity: what a tile task passes).

    .venv/bin/python bench/classify_speed.py --before-src /work/tmp/main_src --work /work/tmp/cs \
        --dmc /work/bench_blocks/dmc_block_subset_3x8/lidar --demo /work/ref/demo_chain/project/lidar

Timed clouds: the demo's four strips (all points), a tile-sized crop of DMC strips 1-2 (800 m x their
width: the chain's tiles hold about 4 M points) and 10 M points of DMC strips 1-2 (the peak RSS at
production tile sizes). Equality only (small): the ``tiny`` simulated project, the 7 ISPRS samples,
the AHN3 Delft crop, laspy's Nebraska tile and lidR's Topography (``AEROTRI_SHARED_DATA``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIELDS = ("x", "y", "z", "rn", "nr", "intensity")
# the DMC clouds (strips, easting range in m) of each block: the 3 x 8 subset's strips run 2.8 km east; the
# 2 x 2 subset's 1.24 km (x 452,000-453,236), so its 10 M points are four strips (their overlaps as a tile's)
DMC_CROPS = {"3x8": {"dmc_tile": ((1, 2), (453000.0, 453800.0)), "dmc_10m": ((1, 2), (452000.0, 454100.0))},
             "2x2": {"dmc_tile": ((1, 2), (452200.0, 453000.0)), "dmc_10m": ((1, 2, 3, 4), (452000.0, 453100.0))}}


def _rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(src: str, npz: str, out: str) -> None:
    """Classify the cloud(s) of ``npz`` with the package in ``src``; print a JSON line of figures."""
    sys.path.insert(0, src)
    import numba

    from lidarctl.classify import pipeline as cl

    assert Path(cl.__file__).resolve().is_relative_to(Path(src).resolve()), cl.__file__
    numba.set_num_threads(1)
    data = np.load(npz)
    names = sorted({k.split("/")[0] for k in data.files})
    results = {}
    for name in names:
        arr = [data[f"{name}/{f}"] for f in FIELDS]
        m = min(100_000, len(arr[0]))
        cl.classify_points(*(a[:m] for a in arr))  # warm-up: numba's compiled-code cache
        rss0 = _rss_mb()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        results[name] = cl.classify_points(*arr)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        print(json.dumps({"cloud": name, "points": len(arr[0]), "cpu_s": r1.ru_utime + r1.ru_stime - r0.ru_utime
                          - r0.ru_stime, "wall_s": time.perf_counter() - t0, "rss_before_mb": rss0,
                          "peak_rss_mb": r1.ru_maxrss / 1024.0, "load_1min": os.getloadavg()[0]}), flush=True)
    np.savez(out, **results)


def _cloud(paths, box=None) -> dict:
    from lidarctl import io

    read = [io.read_cloud(p, crs=crs) for p, crs in paths]
    f = ("x", "y", "z", "return_number", "number_of_returns", "intensity")
    c = {k: np.concatenate([np.asarray(getattr(r, k)) for r in read]) for k in f}
    if box is not None:
        m = (c["x"] >= box[0]) & (c["x"] < box[1]) & (c["y"] >= box[2]) & (c["y"] < box[3])
        c = {k: v[m] for k, v in c.items()}
    rn, nr = io.sanitize_returns(c["return_number"], c["number_of_returns"])
    return dict(zip(FIELDS, (c["x"], c["y"], c["z"], rn, nr, c["intensity"])))


def _save(path: Path, clouds: dict) -> None:
    np.savez(path, **{f"{name}/{f}": v for name, c in clouds.items() for f, v in c.items()})


def prepare(args) -> dict[str, Path]:
    """The input .npz files (one per timed cloud, one for the small equality clouds)."""
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    out = {}
    dmc = Path(args.dmc)
    crops = DMC_CROPS[args.dmc_crops]

    def strips(name):
        return [(dmc / f"strip_0{k}.laz", None) for k in crops[name][0]]

    def box(name):
        return (*crops[name][1], -np.inf, np.inf)

    todo = {"demo": lambda: {"demo": _cloud([(p, None) for p in sorted(Path(args.demo).glob("*.las"))])},
            "dmc_tile": lambda: {"dmc_tile": _cloud(strips("dmc_tile"), box("dmc_tile"))},
            "dmc_10m": lambda: {"dmc_10m": _cloud(strips("dmc_10m"), box("dmc_10m"))}}
    for name, make in todo.items():
        if args.only and name not in args.only:
            continue   # not run: not prepared either
        out[name] = work / f"{name}.npz"
        if not out[name].exists():
            _save(out[name], make())
    out["small"] = work / "small.npz"
    if not out["small"].exists() and (not args.only or "small" in args.only):
        from aerotri.sim import load_preset, simulate

        sim = work / "tiny"
        if not sim.exists():
            simulate(load_preset("tiny"), sim)
        small = {"tiny_sim": _cloud([(p, None) for p in sorted((sim / "lidar").glob("*.la[sz]"))])}
        shared = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
        for s in ("samp11", "samp21", "samp31", "samp41", "samp51", "samp61", "samp71"):
            small[f"isprs_{s}"] = _cloud([(shared / "isprs_filtertest" / f"{s}-utm.laz", None)])
        small["ahn3_crop1"] = _cloud([(shared / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:28992")])
        small["nebraska"] = _cloud([(shared / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las", None)])
        small["lidr_topography"] = _cloud([(shared / "lidr_topography" / "Topography.laz", None)])
        _save(out["small"], small)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before-src", required=True, help="source tree of the code before (main)")
    ap.add_argument("--work", required=True, help="scratch folder (inputs as .npz, classes)")
    ap.add_argument("--dmc", default="/work/bench_blocks/dmc_block_subset_3x8/lidar")
    ap.add_argument("--dmc-crops", choices=list(DMC_CROPS), default="3x8",
                    help="the DMC clouds' strips and easting ranges for the block --dmc is of")
    ap.add_argument("--demo", default="/work/ref/demo_chain/project/lidar")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "classify_speed.json"))
    ap.add_argument("--only", nargs="*", help="inputs to run (demo, dmc_tile, dmc_10m, small)")
    ap.add_argument("--change", default="lidarctl.knn bucket-grid kNN, chunked queries",
                    help="what the 'after' tree changes (for the note)")
    args = ap.parse_args()
    inputs = prepare(args)
    work = Path(args.work)
    figures, equal = {}, {}
    for name, npz in inputs.items():
        if args.only and name not in args.only:
            continue
        classes = {}
        for version, src in (("before", args.before_src), ("after", str(ROOT))):
            out = work / f"classes_{name}_{version}.npz"
            run = subprocess.run([sys.executable, __file__, "--worker", src, str(npz), str(out)], check=True,
                                 capture_output=True, text=True, env={**os.environ, "PYTHONPATH": src})
            for line in run.stdout.splitlines():
                if line.startswith("{"):
                    rec = json.loads(line)
                    rec["cpu_s_per_m_points"] = rec["cpu_s"] / rec["points"] * 1e6
                    figures.setdefault(rec["cloud"], {})[version] = rec
                    print(version, json.dumps(rec), flush=True)
            classes[version] = np.load(out)
        for cloud in classes["before"].files:
            a, b = classes["before"][cloud], classes["after"][cloud]
            equal[cloud] = {"points": int(len(a)), "differing": int(np.sum(a != b)), "identical": bool(np.array_equal(a, b))}
            print(cloud, equal[cloud], flush=True)
    path = Path(args.out)
    import fcntl

    lock = open(path.with_suffix(".lock"), "w")  # two runs (--only) may finish together
    fcntl.flock(lock, fcntl.LOCK_EX)
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("figures", {}).update(figures)
    old.setdefault("equality", {}).update(equal)
    old["note"] = (f"classify_points before (main) and after ({args.change}) in "
                   "separate processes, numba on 1 thread, after a warm-up; cpu_s = user + sys; peak_rss_mb = "
                   "the process's maximum resident set (inputs included; rss_before_mb: before the timed call). "
                   "The machine was shared (load_1min).")
    from aerotri.core.atomic import atomic_path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(old, indent=1) + "\n")
    lock.close()
    path.with_suffix(".lock").unlink(missing_ok=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(*sys.argv[2:5])
    else:
        main()
