"""Shared helpers of the LiDAR benches: the ISPRS samples, published CSF numbers, the CSF peer, and
running a command with its wall/CPU time and the peak RSS of its process tree."""

from __future__ import annotations

import io
import itertools
import json
import os
import resource
import subprocess
import sys
import tarfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")).resolve()
SAMPLES = ("samp11", "samp21", "samp31", "samp41", "samp51", "samp61", "samp71")
# Zhang et al. 2016, Remote Sensing 8(6):501, Table 3 (type I / type II / total, %), as quoted in
# ../shared/data/isprs_filtertest/README.md; the search tool did not return the paper's table itself.
CSF_PUBLISHED = {
    "samp11": (7.23, 18.44, 12.01), "samp21": (3.89, 1.78, 3.42), "samp31": (0.96, 2.38, 1.61),
    "samp41": (1.48, 8.78, 5.14), "samp51": (2.67, 4.57, 3.08), "samp61": (0.87, 18.94, 1.49),
    "samp71": (1.61, 37.85, 5.71),
}


def csf_ground(xyz: np.ndarray, cloth_resolution: float = 1.0, rigidness: int = 2,
               class_threshold: float = 0.5, slope_smooth: bool = True) -> np.ndarray:
    """Ground mask from cloth-simulation-filter (pip cloth-simulation-filter), one parameter set."""
    import CSF

    csf = CSF.CSF()
    csf.params.bSloopSmooth = slope_smooth
    csf.params.cloth_resolution = cloth_resolution
    csf.params.rigidness = rigidness
    csf.params.class_threshold = class_threshold
    # CSF wants coordinates near the origin (float precision) and prints progress on stdout.
    local = xyz - xyz.min(axis=0)
    csf.setPointCloud(local)
    ground, non_ground = CSF.VecInt(), CSF.VecInt()
    stdout = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            csf.do_filtering(ground, non_ground, exportCloth=False)
        finally:
            sys.stdout.flush()
            os.dup2(stdout, 1)
            os.close(stdout)
    mask = np.zeros(len(xyz), bool)
    mask[np.array(ground, dtype=np.int64)] = True
    return mask


def warm_up_jit(fn, *arrays, n: int = 50_000):
    """Call ``fn`` once on the first ``n`` points of ``arrays`` (same dtypes as the timed call), so that
    numba's compilation -- about 25 CPU s for the classifier's parallel kernels on a cold cache, i.e. the
    first run after any edit of a lidarctl module -- or its cache load is not timed as classification.
    Returns (wall s, CPU s) of that call."""
    import time

    t0, c0 = time.perf_counter(), time.process_time()
    fn(*(a[:n] for a in arrays))
    return time.perf_counter() - t0, time.process_time() - c0


def tree_rss(proc) -> int:
    """Resident memory (bytes) of a psutil process and all its children."""
    import psutil

    total = 0
    for p in [proc] + proc.children(recursive=True):
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def run_peak(cmd: list[str], ok_codes=(0,)) -> dict:
    """Run ``cmd``; wall and CPU seconds, peak RSS of its process tree (MiB, polled every 50 ms), the
    largest single child's peak (MiB, from getrusage), load averages, the end of its stdout."""
    import psutil

    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ps = psutil.Process(proc.pid)
    peak = [0]

    def poll():
        while proc.poll() is None:
            try:
                peak[0] = max(peak[0], tree_rss(ps))
            except psutil.Error:
                pass
            time.sleep(0.05)

    th = threading.Thread(target=poll, daemon=True)
    th.start()
    stdout, stderr = proc.communicate()
    seconds = time.perf_counter() - t0
    th.join()
    if proc.returncode not in ok_codes:
        raise RuntimeError(f"{cmd[:3]}: exit {proc.returncode}: {stderr[-2000:]}")
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"seconds": seconds, "cpu_seconds": (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime),
            "peak_rss_mib": peak[0] / 2 ** 20, "max_single_process_rss_mib": ru1.ru_maxrss / 1024.0,
            "exit_code": proc.returncode, "stdout": stdout,
            "load_average_before": list(load0), "load_average_after": list(os.getloadavg())}


def grid_points(grid: dict, default: dict | None = None) -> list[dict]:
    """Every combination of a parameter grid ({name: values}) as keyword dicts, in product order;
    ``default`` (a dict of the same names) appended when the grid lacks it."""
    keys = list(grid)
    combos = [dict(zip(keys, values)) for values in itertools.product(*(grid[k] for k in keys))]
    if default is not None and default not in combos:
        combos.append(default)
    return combos


def measure_on_tree(code: Path, script, args, *, env: dict | None = None, cwd=None) -> dict:
    """Run ``script --measure ARGS`` in its own process with the packages of ``code`` first on the path (one side,
    before or after, of a benchmark of two code trees) and return the JSON of the last line it prints; SystemExit
    with the end of its stderr when it fails. ``env``: more environment variables."""
    r = subprocess.run([sys.executable, str(script), "--measure", *map(str, args)], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(code), **(env or {})), cwd=cwd)
    if r.returncode != 0:
        raise SystemExit(f"{code}: the measurement failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def alternate_rounds(before: Path, after: Path, rounds: int, measure) -> dict[str, list[dict]]:
    """``rounds`` rounds of ``measure(code, side, round_index)`` on two code trees, the "before" side first in each
    round, so that a change of the shared machine's load falls on both sides alike; the runs of each side in order."""
    runs = {"before": [], "after": []}
    for k in range(rounds):
        for side, code in (("before", before), ("after", after)):
            runs[side].append(measure(code, side, k))
    return runs


def baseline_tree(rev: str, work: Path) -> Path:
    """The packages (lidarctl, aerotri, ortho) of git revision ``rev``, unpacked once into ``work/baseline_<rev>``:
    the "before" side of a benchmark run in the same session."""
    dst = work / f"baseline_{rev}"
    if not (dst / "lidarctl").is_dir():
        data = subprocess.run(["git", "-C", str(REPO), "archive", rev, "lidarctl", "aerotri", "ortho"],
                              capture_output=True, check=True).stdout
        dst.mkdir(parents=True, exist_ok=True)
        tarfile.open(fileobj=io.BytesIO(data)).extractall(dst)
    return dst


def module_at(rev: str, relpath: str, name: str, tmp: Path):
    """The module ``relpath`` (e.g. ``lidarctl/classify/noise.py``) as it was at git revision ``rev``, imported
    under ``name`` from a copy in the folder ``tmp``: a bench's "before" beside the working tree's "after"."""
    import importlib.util

    src = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:{relpath}"], check=True, capture_output=True,
                         text=True).stdout
    path = Path(tmp) / f"{name}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
