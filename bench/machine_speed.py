"""How fast this machine runs today: a calibration for comparing timings across sessions -> bench/results/machine_speed.json.

The 2-core machine is a virtual one whose speed changes between sessions: on 2026-12-04 ``bench/rasters_speed.py
--baseline-rev 46c14a0`` took 14.0-14.3 CPU-s for the revision and strips that took 8.6-8.9 CPU-s (0.99-1.04 M
points/s) in four sessions before (its key ``round10_lead``); numba 0.67 or 0.68 and numpy 2.3 or 2.4 gave the same
figures that day (docs/testing.md). A wall or CPU time from another session compares only after dividing by the ratio
of these figures; same-session ratios (a peer, a baseline revision) need no calibration.

Three single-threaded loops, each the best of ``--repeat`` (default 5) runs, CPU seconds of the process:

- ``python_loop_s``: 30 M additions in a CPython ``for`` loop (the interpreter);
- ``numpy_s``: 20 sums of a 4 M-element float64 array and 20 element-wise products (memory bandwidth);
- ``numba_s``: a 30 M-step loop of floating-point arithmetic in a numba kernel, compiled before timing (the CPU).

And the steal time the kernel reports over the whole run (``/proc/stat``; a hypervisor that slows the guest without
reporting steal is what the figures catch). Every run is appended under its UTC time with the commit and the
1-minute load average; the file keeps earlier runs.

Run: .venv/bin/python bench/machine_speed.py [--repeat 5] [--out bench/results/machine_speed.json]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import time
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _python_loop() -> int:
    s = 0
    for i in range(30_000_000):
        s += i
    return s


def _numpy_work(a: np.ndarray) -> float:
    s = 0.0
    for _ in range(20):
        s += float(a.sum())
        s += float((a * a)[::4096].sum())
    return s


@numba.njit(cache=False)
def _numba_kernel(n: int) -> float:
    x, s = 0.5, 0.0
    for i in range(n):
        x = x * 1.0000001 + 1e-9
        s += x / (1.0 + i % 7)
    return s


def _best_cpu_s(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return round(best, 3)


def _steal_ticks() -> int | None:
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()
        return int(fields[8])  # cpu user nice system idle iowait irq softirq steal
    except (OSError, IndexError, ValueError):
        return None


def measure(repeat: int) -> dict:
    a = np.random.default_rng(0).random(4_000_000)
    _numba_kernel(10)  # compiled before timing
    steal0, t0 = _steal_ticks(), time.monotonic()
    out = {
        "python_loop_s": _best_cpu_s(_python_loop, repeat),
        "numpy_s": _best_cpu_s(lambda: _numpy_work(a), repeat),
        "numba_s": _best_cpu_s(lambda: _numba_kernel(30_000_000), repeat),
    }
    steal1, wall = _steal_ticks(), time.monotonic() - t0
    ticks = os.sysconf("SC_CLK_TCK")
    out["steal_s"] = None if steal0 is None or steal1 is None else round((steal1 - steal0) / ticks, 2)
    out["wall_s"] = round(wall, 1)
    out["load_1min"] = round(os.getloadavg()[0], 2)
    out["numba"], out["numpy"] = numba.__version__, np.__version__
    try:
        out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short=8", "HEAD"], capture_output=True,
                                       text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        out["commit"] = None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "machine_speed.json")
    args = ap.parse_args()
    run = measure(args.repeat)
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {"what": __doc__.splitlines()[0], "runs": {}}
    doc["runs"][dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")] = run
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(args.out)
    print(json.dumps(run))


if __name__ == "__main__":
    main()
