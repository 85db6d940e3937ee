"""Benchmark: speed-up of the scale-out stages from 1 to 2 Dask workers, with identical outputs.

Runs the stages that are split into Dask tasks - LiDAR classification (tiles with buffers), tie points
(features per frame, matching per pair), ortho rectification (per frame) and the mosaic (per output
tile) - on the embedded demo block, each with ``--scheduler local:1`` and ``--scheduler local:2`` (a
local Dask distributed cluster of 1 or 2 single-threaded worker processes; cluster start-up is
included in the times). Every run starts from the same inputs in a fresh folder; the outputs of the two
runs are compared byte for byte. Writes bench/results/scaleout_bench.json.

Usage: python bench/scaleout.py [--project out/demo/project]   (default: runs `aerotri demo` first
when that project has not been through the chain yet).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _sha(p: Path, root: Path | None = None) -> str:
    data = p.read_bytes()
    if root is not None and p.suffix in (".json", ".geojson"):
        data = data.replace(str(root).encode(), b"ROOT")  # index files hold absolute paths
    return hashlib.sha1(data).hexdigest()


def _run(args, env=None) -> float:
    t = time.perf_counter()
    subprocess.run([str(a) for a in args], check=True, stdout=subprocess.DEVNULL, env=env)
    return time.perf_counter() - t


def _copy(src: Path, dst: Path, parts) -> None:
    for part in parts:
        s = src / part
        if s.is_dir():
            shutil.copytree(s, dst / part)
        else:
            (dst / part).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(s, dst / part)


def stages(project: Path):
    """(name, inputs to copy, command for a workdir and scheduler, outputs to compare)."""
    lo = "lidar_out"
    return [
        # the strips together, no merged file: one classified LAZ per strip
        ("classify", ["lidar"],
         lambda w, s: [BIN / "lidarctl", "classify", *sorted((w / "lidar").glob("*.la[sz]")), w / lo / "classified",
                       "--format", "laz", "--scheduler", s],
         [f"{lo}/classified/{p.stem}.laz" for p in sorted((project / "lidar").glob("*.la[sz]"))]),
        ("match", ["images", "gnss.txt", "camera.toml", "project.toml"],
         lambda w, s: [BIN / "aerotri", "match", w, "--scheduler", s],
         ["at/tiepoints.csv"]),
        ("rectify", ["images", "gnss.txt", "camera.toml", "project.toml", "at", f"{lo}/dem.tif"],
         lambda w, s: [BIN / "ortho", "rectify", w, "--dem", w / lo / "dem.tif", "--scheduler", s],
         ["ortho/frames/index.json"]),
        ("mosaic", ["images", "gnss.txt", "camera.toml", "project.toml", "at", lo, "ortho/frames"],
         lambda w, s: [BIN / "ortho", "mosaic", w, "--scheduler", s],
         ["ortho/mosaic.tif", "ortho/seamlines.geojson"]),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=ROOT / "out" / "demo" / "project")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "scaleout_bench.json")
    ap.add_argument("--only", nargs="*", default=None, help="stage names to run")
    a = ap.parse_args()
    if not (a.project / "ortho" / "frames" / "index.json").exists():
        subprocess.run([BIN / "aerotri", "demo", a.project.parent], check=True)
    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OPENCV_FOR_THREADS_NUM="1",
               GDAL_NUM_THREADS="1")
    result = dict(cpus=os.cpu_count(), load_average_start=os.getloadavg()[0], project=str(a.project),
                  note="local Dask cluster of N single-threaded worker processes; start-up included; "
                       "OpenCV/OMP/numba/BLAS/GDAL threads pinned to 1 per worker, so N workers use N cores", stages={})
    with tempfile.TemporaryDirectory(prefix="aerotri_scaleout_") as tmp:
        for name, parts, cmd, outputs in stages(a.project):
            if a.only and name not in a.only:
                continue
            row = {}
            digests = {}
            for n in (1, 2):
                w = Path(tmp) / f"{name}_{n}"
                _copy(a.project, w, parts)
                row[f"seconds_{n}_worker{'s' if n > 1 else ''}"] = round(_run(cmd(w, f"local:{n}"), env), 2)
                digests[n] = {o: _sha(w / o, w) for o in outputs}
                if name == "rectify":  # per-frame orthos listed in the index
                    digests[n].update({f.name: _sha(f) for f in sorted((w / "ortho" / "frames").glob("*.tif"))})
                shutil.rmtree(w)
            row["speedup"] = round(row["seconds_1_worker"] / row["seconds_2_workers"], 2)
            row["identical_outputs"] = digests[1] == digests[2]
            row["files_compared"] = len(digests[1])
            result["stages"][name] = row
            print(f"{name:<9} 1 worker {row['seconds_1_worker']:7.1f} s   2 workers {row['seconds_2_workers']:7.1f} s   "
                  f"speed-up {row['speedup']:.2f}x   identical outputs: {row['identical_outputs']}", flush=True)
    result["load_average_end"] = os.getloadavg()[0]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"-> {a.out}")


if __name__ == "__main__":
    main()
