"""The numba kernels compiled into their cache before the first run (``make install``)."""

from __future__ import annotations

import importlib
import subprocess
import sys
import textwrap

import pytest
from numba.core.dispatcher import Dispatcher

from aerotri.core.precompile import (
    MANIFEST, KernelSignature, _reads_back, loaded_signatures, main, parse_signature, precompile, read_manifest,
    write_manifest,
)

_KERNELS = textwrap.dedent("""
    import collections

    import numba

    Offsets = collections.namedtuple("Offsets", "along_m across_m")

    @numba.njit(cache=True)
    def scaled_sum(values, scale):
        total = 0.0
        for v in values.ravel():
            total += v
        return total * scale

    @numba.njit(cache=True)
    def doubled_sum(values, scale):
        return 2.0 * scaled_sum(values, scale)

    also_scaled_sum = scaled_sum  # an alias: listed once, under the kernel's own name

    def _mean(values):
        return values.mean()

    # a kernel made from a function of another name (as schur.py's serial and parallel variants)
    mean_serial = numba.njit(cache=True)(_mean)

    @numba.njit(cache=True)
    def shifted(values, offsets, pair):
        return values + offsets.along_m + offsets.across_m + pair[1][0]
""")


@pytest.fixture
def kernel_module(tmp_path, monkeypatch):
    """A module of one cached kernel in a folder of its own (its cache beside it), importable here and by the
    worker processes (spawn passes sys.path on)."""
    name = f"kernels_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(_KERNELS)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def _cache_use_in_a_new_process(module: str, folder, call: str) -> str:
    """Call the kernel in a new interpreter; its compile statistics (hits, misses) as text."""
    code = (f"import sys, numpy as np; sys.path.insert(0, {str(folder)!r}); import {module} as m; {call}; "
            "print(sum(m.scaled_sum.stats.cache_hits.values()), sum(m.scaled_sum.stats.cache_misses.values()))")
    return subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.strip()


def test_the_shipped_signatures_name_kernels_that_exist():
    """Every line of numba_signatures.txt names a cached kernel of the toolkit with argument types numba reads:
    a kernel renamed or removed since the file was written fails here (bench/record_numba_signatures.py)."""
    entries = read_manifest(MANIFEST)
    assert len(entries) >= 80
    assert {e.module.split(".")[0] for e in entries} == {"aerotri", "lidarctl", "ortho"}
    for e in entries:
        kernel = getattr(importlib.import_module(e.module), e.function)
        assert isinstance(kernel, Dispatcher), e
        sig = parse_signature(e.signature)
        assert sig and all(type(t).__module__.startswith("numba.core.types") for t in sig), e


def test_precompiled_signatures_are_loaded_from_the_cache_by_a_later_run(kernel_module, tmp_path):
    sigs = ["(Array(float64, 1, 'C', False, aligned=True), float64)",
            "(Array(float32, 2, 'A', False, aligned=True), int64)"]
    # the caller first: scaled_sum's first signature is compiled with it (and cached too)
    entries = [KernelSignature(kernel_module, "doubled_sum", sigs[0])] + \
        [KernelSignature(kernel_module, "scaled_sum", s) for s in sigs]
    stale = [KernelSignature(kernel_module, "renamed_kernel", sigs[0]),
             KernelSignature(kernel_module, "scaled_sum", "(unicode_type, unicode_type)"),
             KernelSignature("no_such_module_here", "kernel", sigs[0])]
    done = precompile(entries + stale, processes=2)
    assert (done.signatures, done.compiled, done.with_callers, done.cached, done.processes) == (6, 2, 1, 0, 2)
    assert len(done.failed) == 3
    assert any("renamed_kernel" in f and "AttributeError" in f for f in done.failed)
    assert any("unicode_type" in f and "TypingError" in f for f in done.failed)
    assert any(f.startswith("no_such_module_here: ModuleNotFoundError") for f in done.failed)
    # a new process calling the kernel with those types loads it, compiles nothing
    assert _cache_use_in_a_new_process(kernel_module, tmp_path, "m.scaled_sum(np.ones(3), 2.0)") == "1 0"
    assert _cache_use_in_a_new_process(
        kernel_module, tmp_path, "m.scaled_sum(np.ones((4, 4), np.float32)[:, :2], 3)") == "1 0"
    # a signature not listed still compiles on its first call
    assert _cache_use_in_a_new_process(kernel_module, tmp_path, "m.scaled_sum(np.ones(3, np.int32), 2.0)") == "0 1"
    again = precompile(entries, processes=1)
    assert (again.compiled, again.cached, again.failed) == (0, 3, ())


def test_the_signatures_a_run_called_are_listed_and_read_back(kernel_module, tmp_path):
    import numpy as np

    module = importlib.import_module(kernel_module)
    module.scaled_sum(np.ones((2, 3)), 1.5)
    module.scaled_sum(np.arange(4, dtype=np.int32), 2)
    module.mean_serial(np.ones(3))
    # a named tuple of the module's own and tuples within tuples
    module.shifted(np.ones(2), module.Offsets(np.zeros(2), 1.0), (1, (np.ones(1, np.float32), 2)))
    found = loaded_signatures((kernel_module,))
    assert sorted((e.module, e.function) for e in found) == [(kernel_module, "mean_serial")] + \
        [(kernel_module, "scaled_sum")] * 2 + [(kernel_module, "shifted")]
    (named,) = [e for e in found if e.function == "shifted"]
    assert f'cls("{kernel_module}:Offsets")' in named.signature
    assert parse_signature(named.signature) == module.shifted.signatures[0]
    assert {parse_signature(e.signature) for e in found if e.function == "scaled_sum"} == \
        set(module.scaled_sum.signatures)
    # a type whose text is no constructor call numba reads back is left out when recording, not an error
    from numba.core import types

    assert _reads_back("(int64, UniTuple(float64, 2))", (types.int64, types.UniTuple(types.float64, 2)))
    assert not _reads_back("(int64,)", (types.int32,))
    assert not _reads_back("(Opaque(a thing),)", (types.Opaque("a thing"),))
    path = tmp_path / "signatures.txt"
    write_manifest(found + found, path, header="two lines\nof header")
    assert path.read_text().startswith("# two lines\n# of header\n")
    assert sorted(read_manifest(path), key=lambda e: e.signature) == sorted(found, key=lambda e: e.signature)


def test_a_manifest_line_not_written_as_expected_is_named(tmp_path, capsys):
    path = tmp_path / "signatures.txt"
    path.write_text("# header\naerotri.x:kernel\t(int64,)\naerotri.x kernel (int64,)\n")
    with pytest.raises(ValueError, match=r"signatures.txt, line 3: expected 'module:function<TAB>\(types\)'"):
        read_manifest(path)
    assert main([str(path)]) == 2
    assert "line 3" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.txt")]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["--processes", "0", str(path)])
    assert exc.value.code == 2
