"""What numba compiles in the test suite, and what each compilation costs on a clean clone.

After a ``make test`` in a checkout, numba's in-tree caches (``<package>/__pycache__/*.nbi``) list every kernel
the suite compiled and each signature it was compiled for. This script reads those indexes, then compiles each
(kernel, signature) again in this one process against an empty cache (``NUMBA_CACHE_DIR`` set to a new temporary
folder before numba is imported) and times every compilation with numba's ``numba:compile`` event (exclusive
thread CPU seconds, callees counted once, at the callee: bench/eval_numba_compile.py). The per-kernel table is
what one worker pays to compile the kernel; under pytest-xdist every worker that calls a kernel compiles it
unless another worker has already written it to the cache.

Run (as measured, bench/results/suite_time.json key ``numba_kernels``; TREE is a checkout after `make test`):
  nice -n 10 .venv/bin/python bench/eval_suite_time.py TREE bench/results/suite_time.json
It updates only the ``numba_kernels`` key of OUT.json (the suite timings there were recorded by hand, with
the commands in their ``command`` keys).
"""

from __future__ import annotations

import importlib
import json
import os
import pickle
import re
import sys
import tempfile
import time
from pathlib import Path

os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="numba_empty_")  # before numba is imported

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_numba_compile as enc  # noqa: E402  (the compile-event timer)
from numba.core import event as ev  # noqa: E402

PACKAGES = ("aerotri", "lidarctl", "ortho")
_INDEX = re.compile(r"^(?P<stem>[^.]+)\.(?P<qualname>.+)-(?P<line>\d+)\.py\d+\.nbi$")


def read_indexes(tree: Path) -> list[dict]:
    """Every kernel with its signatures from ``tree``'s in-tree numba cache indexes."""
    import numba

    kernels = []
    for pkg in PACKAGES:
        for nbi in sorted((tree / pkg).rglob("__pycache__/*.nbi")):
            m = _INDEX.match(nbi.name)
            rel = nbi.parent.parent.relative_to(tree) / m["stem"]
            module = ".".join(rel.parts)
            with open(nbi, "rb") as f:
                version = pickle.load(f)
                if version != numba.__version__:
                    continue
                _stamp, overloads = pickle.loads(f.read())
            kernels.append(dict(module=module, qualname=m["qualname"], line=int(m["line"]),
                                signatures=[key[0] for key in overloads]))
    return kernels


def _dispatcher(module: str, qualname: str):
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def main() -> int:
    if len(sys.argv) != 3:
        sys.exit("usage: eval_suite_time.py TREE OUT.json")
    tree, out = Path(sys.argv[1]).resolve(), Path(sys.argv[2])
    kernels = read_indexes(tree)
    ev.register("numba:compile", enc._Timer())
    rows, failed = [], []
    for k in kernels:
        try:
            disp = _dispatcher(k["module"], k["qualname"])
        except (AttributeError, ImportError) as e:
            failed.append(f"{k['module']}.{k['qualname']}: {e}")
            continue
        if not hasattr(disp, "compile"):  # the name is bound to something else now (a wrapper of the same name)
            failed.append(f"{k['module']}.{k['qualname']}: not a numba dispatcher ({type(disp).__name__})")
            continue
        for sig in k["signatures"]:
            n0, t0 = len(enc.records), time.thread_time()
            disp.compile(sig)
            own = [r for r in enc.records[n0:] if r["function"] == f"{k['module']}.{k['qualname']}"]
            rows.append(dict(kernel=f"{k['module']}.{k['qualname']}", signature=str(sig),
                             n_signatures=len(k["signatures"]), inclusive_cpu_s=round(time.thread_time() - t0, 3),
                             exclusive_cpu_s=round(sum(r["exclusive_cpu_s"] for r in own), 3)))
    per_module: dict[str, float] = {}
    for r in enc.records:
        mod = ".".join(r["function"].split(".")[:2])
        per_module[mod] = per_module.get(mod, 0.0) + r["exclusive_cpu_s"]
    table = dict(
        what="numba compilations of the kernels a whole `make test` compiled (read from the checkout's cache "
             "indexes), compiled again one by one in one process against an empty cache; CPU seconds of that "
             "process's thread (exclusive: callees counted once, at the first kernel that needed them)",
        tree=str(tree), kernels=len(kernels),
        signatures=sum(len(k["signatures"]) for k in kernels),
        kernels_with_several_signatures=sorted(f"{k['module']}.{k['qualname']}" for k in kernels
                                               if len(k["signatures"]) > 1),
        compile_cpu_s=round(sum(r["exclusive_cpu_s"] for r in enc.records), 1),
        per_module_exclusive_cpu_s={m: round(s, 2) for m, s in sorted(per_module.items(), key=lambda kv: -kv[1])},
        per_signature=sorted(rows, key=lambda r: -r["exclusive_cpu_s"]),
        not_found=failed,
    )
    doc = json.loads(out.read_text()) if out.is_file() else {}
    doc["numba_kernels"] = table
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(out)
    print(f"{table['kernels']} kernels, {table['signatures']} signatures, "
          f"{table['compile_cpu_s']} CPU-s of compilation")
    for r in table["per_signature"][:25]:
        print(f"{r['exclusive_cpu_s']:8.2f} {r['kernel']} {r['signature'][:80]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
