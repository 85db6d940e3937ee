"""Compile the numba kernels into their on-disk cache before the first run, on every core.

Every kernel of the toolkit is ``numba.njit(cache=True)``: compiled on its first call, then loaded from the
``__pycache__`` beside its source. On a fresh install that first compilation happens inside the first run, one
kernel after another on one core (``make demo`` on a fresh clone: 3-3.5 of its 6-6.5 min; docs/testing.md).
``make install`` therefore compiles them beforehand, like ``compileall`` does the bytecode: the signatures a
demo run calls (``numba_signatures.txt`` beside this module, ``bench/record_numba_signatures.py`` writes it) are
compiled in worker processes, a module per task, the largest first. A kernel later called with another
signature still compiles on its first call; a stale entry (a kernel renamed, its argument types changed) is
reported and left out, never an error of the install.

The file has one line per signature: ``module:function<TAB>(type, type, ...)`` in numba's own notation (the
``repr`` of ``numba.core.types``, read back in that namespace only; a named tuple's class as ``cls("module:name")``).
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import time
from collections.abc import Iterable
from pathlib import Path

MANIFEST = Path(__file__).with_name("numba_signatures.txt")
PACKAGES = ("aerotri", "lidarctl", "ortho")


@dataclasses.dataclass(frozen=True)
class KernelSignature:
    module: str
    function: str
    signature: str  # "(Array(float64, 2, 'C', False, aligned=True), int64)"

    def line(self) -> str:
        return f"{self.module}:{self.function}\t{self.signature}"


@dataclasses.dataclass(frozen=True)
class PrecompileResult:
    signatures: int  # in the manifest
    compiled: int  # compiled now and written to the cache
    with_callers: int  # compiled meanwhile as a callee of a kernel compiled before it (its cache written too)
    cached: int  # already in the cache
    failed: tuple[str, ...]  # "module:function (sig): why", stale entries
    processes: int
    wall_s: float

    def summary(self) -> str:
        text = (f"numba kernels: {self.compiled} signatures compiled ({self.with_callers} more with their callers), "
                f"{self.cached} already cached, "
                f"{len(self.failed)} left out, {self.processes} processes, {self.wall_s:.1f} s")
        return "\n".join([text] + [f"  left out: {f}" for f in self.failed])


def read_manifest(path: Path = MANIFEST) -> list[KernelSignature]:
    """The signatures of ``path``; ValueError naming the line for one not written as ``module:function<TAB>(...)``."""
    out = []
    for i, raw in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, signature = line.partition("\t")
        module, colon, function = name.partition(":")
        if not sep or not colon or not module or not function or not signature.startswith("("):
            raise ValueError(f"{path}, line {i}: expected 'module:function<TAB>(types)', got {raw!r}")
        out.append(KernelSignature(module, function, signature))
    return out


def write_manifest(entries: Iterable[KernelSignature], path: Path = MANIFEST, header: str = "") -> None:
    """Write ``entries`` sorted, one per line, after ``header`` as comment lines."""
    lines = [f"# {h}".rstrip() for h in header.splitlines()]
    lines += sorted({e.line() for e in entries})
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def loaded_signatures(packages: tuple[str, ...] = PACKAGES) -> list[KernelSignature]:
    """The signatures compiled in this process so far by the cached kernels that ``packages`` define at module
    level (a kernel made inside a function cannot be named again and is left out)."""
    from numba.core.dispatcher import Dispatcher

    out = []
    for name, module in sorted((k, m) for k, m in sys.modules.items() if m is not None):
        if name.split(".")[0] not in packages:
            continue
        # a kernel under several names (``_runs_serial = numba.njit(cache=True)(_runs)`` beside ``_runs``) once,
        # under its own name when the module has it
        names: dict[int, str] = {}
        for attr, value in sorted(vars(module).items()):
            if isinstance(value, Dispatcher) and value.py_func.__module__ == name:
                if id(value) not in names or attr == value.py_func.__name__:
                    names[id(value)] = attr
        for attr in names.values():
            for sig in getattr(module, attr).signatures:
                text = "(" + ", ".join(type_text(t) for t in sig) + ("," if len(sig) == 1 else "") + ")"
                if _reads_back(text, tuple(sig)):  # (a type written otherwise compiles on its first call)
                    out.append(KernelSignature(name, attr, text))
    return out


def _reads_back(text: str, sig: tuple) -> bool:
    try:
        return parse_signature(text) == sig
    except Exception:  # a type whose repr is no constructor call of numba.core.types
        return False


def type_text(t) -> str:
    """``t`` (a numba type) as ``parse_signature`` reads it back: numba's ``repr``, but a named tuple's class as
    ``cls("module:qualname")`` (its repr names the class only) and the types inside tuples written the same way."""
    from numba.core import types

    if isinstance(t, (types.NamedUniTuple, types.NamedTuple)):
        where = f'cls("{t.instance_class.__module__}:{t.instance_class.__qualname__}")'
        if isinstance(t, types.NamedUniTuple):
            return f"NamedUniTuple({type_text(t.dtype)}, {t.count}, {where})"
        return f"NamedTuple(({''.join(type_text(e) + ', ' for e in t.types)}), {where})"
    if isinstance(t, types.UniTuple):
        return f"UniTuple({type_text(t.dtype)}, {t.count})"
    if isinstance(t, types.Tuple):
        return f"Tuple(({''.join(type_text(e) + ', ' for e in t.types)}))"
    return repr(t)


def _named_tuple_class(where: str) -> type:
    """The class ``cls("module:qualname")`` names."""
    module, _, qualname = where.partition(":")
    value = importlib.import_module(module)
    for part in qualname.split("."):
        value = getattr(value, part)
    return value


def parse_signature(text: str) -> tuple:
    """The argument types written in ``text`` (numba's repr of them), read in ``numba.core.types`` only."""
    from numba.core import types

    names = {k: v for k, v in vars(types).items() if not k.startswith("_")}
    names["cls"] = _named_tuple_class
    value = eval(text, {"__builtins__": {}}, names)  # noqa: S307 - our own file, numba's type names only
    return tuple(value) if isinstance(value, tuple) else (value,)


def _compile_module(task: tuple[str, list[tuple[str, str]]]) -> tuple[int, int, int, list[str]]:
    """(a worker) compile the signatures of one module's kernels: (compiled, with their callers, already cached,
    failures)."""
    module_name, items = task
    compiled, with_callers, cached, failed = 0, 0, 0, []
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # (a module removed since the manifest was written)
        return 0, 0, 0, [f"{module_name}: {type(exc).__name__}: {exc}"]
    for function, signature in items:
        where = f"{module_name}:{function} {signature}"
        try:
            kernel = getattr(module, function)
            sig = parse_signature(signature)
            if sig in kernel.overloads:
                with_callers += 1
                continue
            hits = sum(kernel.stats.cache_hits.values())
            kernel.compile(sig)
            if sum(kernel.stats.cache_hits.values()) > hits:
                cached += 1
            else:
                compiled += 1
        except Exception as exc:  # a stale entry: the kernel compiles on its first call instead
            failed.append(f"{where}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    return compiled, with_callers, cached, failed


def precompile(entries: list[KernelSignature], processes: int | None = None) -> PrecompileResult:
    """Compile ``entries`` into the kernels' caches in ``processes`` worker processes (default: one per core), a
    module per task, the modules with most signatures first."""
    from aerotri.core.limits import usable_cores
    from aerotri.core.log import track

    t0 = time.perf_counter()
    by_module: dict[str, list[tuple[str, str]]] = {}
    for e in entries:
        by_module.setdefault(e.module, []).append((e.function, e.signature))
    tasks = sorted(by_module.items(), key=lambda kv: (-len(kv[1]), kv[0]))
    processes = max(1, min(processes or usable_cores(), len(tasks) or 1))
    if processes == 1:
        results = list(track(map(_compile_module, tasks), "numba kernels", "modules", total=len(tasks)))
    else:
        import multiprocessing

        # spawn: a clean interpreter per worker (no threads or numba state inherited from the caller)
        with multiprocessing.get_context("spawn").Pool(processes) as pool:
            results = list(track(pool.imap_unordered(_compile_module, tasks), "numba kernels", "modules",
                                 total=len(tasks)))
    failed = tuple(sorted(f for r in results for f in r[3]))
    return PrecompileResult(signatures=len(entries), compiled=sum(r[0] for r in results),
                            with_callers=sum(r[1] for r in results), cached=sum(r[2] for r in results),
                            failed=failed, processes=processes,
                            wall_s=time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    """``python -m aerotri.core.precompile [--processes N] [MANIFEST]`` (``make install`` runs it)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m aerotri.core.precompile", description=__doc__.splitlines()[0])
    parser.add_argument("manifest", nargs="?", type=Path, default=MANIFEST)
    parser.add_argument("--processes", type=int, default=None, help="worker processes (default: one per core)")
    args = parser.parse_args(argv)
    if args.processes is not None and args.processes < 1:
        parser.error(f"--processes {args.processes}: expected at least 1")
    try:
        entries = read_manifest(args.manifest)
    except (OSError, ValueError) as exc:
        print(f"Error: {exc}", file=sys.stderr)
        return 2
    print(precompile(entries, args.processes).summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
