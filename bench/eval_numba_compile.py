"""Numba's compilation per function in one run of the aerotri CLI (e.g. ``demo --force`` on a simulated demo
project): every compilation (not a cache load) timed by numba's ``numba:compile`` event, exclusive thread
CPU seconds (nested compilations of callees counted once, at the callee), with its signature, so a function
compiled for two signatures shows twice. Run it with an empty ``NUMBA_CACHE_DIR`` for a fresh clone's first
run. Writes the records and a summary (total, per function, per top-level kernel, per module) to JSON.

Run (as measured, bench/results/numba_compile_demo.json):
  cp -a /work/ref/demo_chain /tmp/demo && mkdir -p /tmp/nb && rm -rf /tmp/nb/*
  NUMBA_CACHE_DIR=/tmp/nb /usr/bin/time -v .venv/bin/python bench/eval_numba_compile.py \
      bench/results/numba_compile_demo.json -- demo --force /tmp/demo
(``/usr/bin/time`` gives the run's user + sys CPU seconds, recorded by hand in the JSON's ``run`` key.)
"""

from __future__ import annotations

import atexit
import collections
import json
import sys
import threading
import time

from numba.core import event as ev

_local = threading.local()
_lock = threading.Lock()
records: list[dict] = []


class _Timer(ev.Listener):
    def on_start(self, event):
        stack = getattr(_local, "stack", None)
        if stack is None:
            stack = _local.stack = []
        stack.append([time.thread_time(), 0.0])

    def on_end(self, event):
        stack = _local.stack
        t0, children = stack.pop()
        inclusive = time.thread_time() - t0
        if stack:
            stack[-1][1] += inclusive
        data = event.data or {}
        func = getattr(data.get("dispatcher"), "py_func", None)
        name = f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', '?')}"
        with _lock:
            records.append(dict(function=name, args=str(data.get("args")), exclusive_cpu_s=inclusive - children,
                                inclusive_cpu_s=inclusive, nested=bool(stack)))


def summary(recs: list[dict]) -> dict:
    per_function = collections.defaultdict(lambda: [0.0, 0])
    top = collections.Counter()
    module = collections.Counter()
    for r in recs:
        per_function[r["function"]][0] += r["exclusive_cpu_s"]
        per_function[r["function"]][1] += 1
        if not r["nested"]:
            top[r["function"]] += r["inclusive_cpu_s"]
            module[".".join(r["function"].split(".")[:2])] += r["inclusive_cpu_s"]
    return {
        "compilations": len(recs),
        "compile_cpu_s": sum(r["exclusive_cpu_s"] for r in recs),
        "per_function_exclusive_cpu_s_count": dict(sorted(per_function.items(), key=lambda kv: -kv[1][0])),
        "per_top_level_kernel_inclusive_cpu_s": dict(top.most_common()),
        "per_module_inclusive_cpu_s": dict(module.most_common()),
        "user_functions_compiled_more_than_once": sorted(
            f for f, (_, n) in per_function.items() if n > 1 and not f.startswith("numba.")),
    }


def main() -> int:
    if len(sys.argv) < 3 or sys.argv[2] != "--":
        sys.exit("usage: eval_numba_compile.py OUT.json -- <aerotri arguments>")
    out = sys.argv[1]
    ev.register("numba:compile", _Timer())

    def dump() -> None:
        with open(out, "w") as f:
            json.dump(dict(command=["aerotri", *sys.argv[3:]], summary=summary(records), records=records), f, indent=1)

    atexit.register(dump)
    from aerotri.cli import main as cli

    sys.argv = ["aerotri", *sys.argv[3:]]
    return cli()


if __name__ == "__main__":
    sys.exit(main())
