"""Shared fixtures: the real reference data folder and simulated projects (generated once per session).

Under pytest-xdist (``make test`` runs ``-n auto``) the workers share the expensive read-only builds: the first
worker that needs one builds it under a file lock in the run's common temporary folder, the others wait for it
and reuse it (:func:`built_once`), so the simulator's kernels are compiled and the tiny block rendered once
per run, not once per worker. The simulated ``tiny`` project is started in a background process as soon as a
worker has collected a test that needs it (:func:`pytest_collection_finish`), so that no core waits for it.

Run as a script, ``python tests/conftest.py NAME OUT DONE`` builds ``SHARED_BUILDS[NAME]`` into OUT and then
creates DONE (the background build)."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest

REPO = Path(__file__).resolve().parents[1]

# Python's default, bytecode cached in __pycache__ next to the sources (as numba caches its kernels): with
# PYTHONDONTWRITEBYTECODE set, each worker compiled and assertion-rewrote every module again at collection (12.7
# CPU-s against 3.9 with the caches), and every command a test starts compiled the modules it imports.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


def shared_data_dir() -> Path:
    return Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")).resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; tests that need it skip with a reason when it is absent."""
    d = shared_data_dir()
    if not d.is_dir():
        pytest.skip(f"real reference data not found at {d} (set AEROTRI_SHARED_DATA)")
    return d


def _run_root(tmp_path_factory) -> Path:
    """The run's folder for what the processes of a run share: under xdist the workers' common temporary root
    (``<basetemp>/popen-gwN`` -> ``<basetemp>``), else this session's ``basetemp``."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """``build(folder)`` once per test run; returns ``folder`` (treat it as read-only).

    Without xdist: a new folder of this session. Under xdist: ``<run's temporary root>/<name>``, shared by the
    workers; the first one builds it under an ``flock`` and then writes ``<name>.done``, the others block on the
    lock and then find it (a folder without ``.done``, of a worker that died while building, is built anew)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        out = tmp_path_factory.mktemp(name) / name
        build(out)
        return out
    from tests.shared_builds import built_once_in  # (not at the top: the background build runs this file alone)

    return built_once_in(_run_root(tmp_path_factory), name, build)


# where the workers' and the background builds' per-kernel numba locks are (the run's common temporary folder)
NUMBA_LOCKS_ENV = "AEROTRI_TEST_NUMBA_LOCKS"
NUMBA_LOCK_WAIT_S = 300.0  # then compile anyway: a wait can never turn into a deadlock


def share_numba_compilations(folder: Path) -> None:
    """Compile each cached numba kernel in one process of the run and load it from numba's cache in the others.

    Patches ``numba``'s ``Dispatcher.compile`` in this process: before compiling a kernel with ``cache=True`` for a
    signature it has not loaded, the process takes an ``flock`` of that kernel in ``folder`` (under the compiler's
    own process lock, so that the threads of one process take them in one order); a process that needs the kernel
    while another compiles it waits, and then numba finds it in the cache (it reads the cache index from disk on
    each load) instead of compiling it a second time. Per kernel, not per signature: the index file of a kernel
    is then also written by one process at a time. Kernels without ``cache=True`` are compiled as before."""
    import fcntl
    import hashlib
    import time

    from numba.core import dispatcher, sigutils
    from numba.core.caching import NullCache
    from numba.core.compiler_lock import global_compiler_lock

    compile_ = dispatcher.Dispatcher.compile
    if getattr(compile_, "shared_by_lock", False):
        return
    folder.mkdir(parents=True, exist_ok=True)
    held: set[str] = set()  # kernels this process holds the lock of (a recursive kernel compiles inside its own)

    def compile(self, sig):
        cache = self._cache
        # the cache's index file names the kernel (numba's private attributes: another numba compiles unshared)
        index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        if (isinstance(cache, NullCache) or not isinstance(index, str)
                or tuple(sigutils.normalize_signature(sig)[0]) in self.overloads):
            return compile_(self, sig)
        key = hashlib.sha1(index.encode()).hexdigest()[:20]
        with global_compiler_lock:
            if key in held:
                return compile_(self, sig)
            with open(folder / f"{key}.lock", "w") as lock:
                deadline = time.monotonic() + NUMBA_LOCK_WAIT_S
                while True:
                    try:
                        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        break
                    except BlockingIOError:
                        if time.monotonic() > deadline:
                            break
                        time.sleep(0.05)
                held.add(key)
                try:  # loads the kernel from the cache when another process has just compiled it
                    return compile_(self, sig)
                finally:
                    held.discard(key)

    compile.shared_by_lock = True
    dispatcher.Dispatcher.compile = compile


def _build_tiny(out: Path) -> None:
    from aerotri.sim import load_preset, simulate

    simulate(load_preset("tiny"), out)


# builds started in the background under xdist: name -> (build, the fixture whose tests need it)
SHARED_BUILDS: dict[str, tuple[Callable[[Path], None], str]] = {"tiny": (_build_tiny, "tiny_project")}
_background: list[subprocess.Popen] = []


def _needs_build(item) -> bool:
    return any(fixture in getattr(item, "fixturenames", ()) for _build, fixture in SHARED_BUILDS.values())


def pytest_collection_modifyitems(session, config, items) -> None:
    """On an xdist worker: within each folder under ``tests/`` (and among the files directly in it), the modules
    with a test that needs a background build (:data:`SHARED_BUILDS`) run after the others, each module's tests
    together and in file order. ``--dist worksteal`` hands each worker a contiguous half of this order: both then
    start with tests that do not wait for ``tiny`` (about 120 and 80 CPU-s of them) while it is built. Every worker
    sorts alike, so their collections stay identical."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    tests = Path(__file__).parent

    def folder(item) -> str:
        rel = item.path.relative_to(tests).parts if item.path.is_relative_to(tests) else item.path.parts
        return rel[0] if len(rel) > 1 else ""

    folder_rank: dict[str, int] = {}
    module_needs: dict[Path, bool] = {}
    module_rank: dict[Path, int] = {}
    for item in items:
        folder_rank.setdefault(folder(item), len(folder_rank))
        module_rank.setdefault(item.path, len(module_rank))
        module_needs[item.path] = module_needs.get(item.path, False) or _needs_build(item)

    def key(item):
        return folder_rank[folder(item)], module_needs[item.path], module_rank[item.path]

    items.sort(key=key)  # stable: file order within a module


_ALL_CORES: set[int] | None = None  # this worker's affinity before pin_worker_to_its_core


def pin_worker_to_its_core() -> None:
    """On an xdist worker with no more workers than cores: run this worker (and the commands it starts) on one core
    of its own.

    Every pool and kernel sizes itself from the process's affinity (:func:`aerotri.core.limits.usable_cores`, numba,
    OpenBLAS, OpenCV), so a worker no longer starts two threads per pool on a machine whose other core is busy
    with the other worker (their switching and spin-waiting took 11 % of the suite's CPU, docs/testing.md)."""
    global _ALL_CORES
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not worker or not count or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    if int(count) > len(cores):  # workers sharing cores: leave the scheduler to spread them
        return
    _ALL_CORES = set(cores)
    os.sched_setaffinity(0, {cores[int(worker.removeprefix("gw")) % len(cores)]})


def pytest_configure(config) -> None:
    """:func:`pin_worker_to_its_core` before the collection imports numba (which sizes its pool at import)."""
    pin_worker_to_its_core()


def pytest_sessionstart(session) -> None:
    """The run's folder for :mod:`tests.shared_builds` (the workers' common temporary root under xdist). On an xdist
    worker: :func:`share_numba_compilations` in it (before the collection, which imports the kernels), also for the
    background builds this worker starts."""
    from tests.shared_builds import SHARED_DIR_ENV

    root = _run_root(session.config._tmp_path_factory)
    os.environ[SHARED_DIR_ENV] = str(root)
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    folder = root / "numba-locks"
    os.environ[NUMBA_LOCKS_ENV] = str(folder)
    share_numba_compilations(folder)


def _freeze_what_is_loaded() -> None:
    """Move every object alive after the collection (the imported libraries, the collected tests) out of Python's
    cyclic garbage collector: they live until the process ends, and each full collection walked all of them again
    (0.3-0.5 s a collection in a worker that has imported numba, scipy, matplotlib, gtsam and dask; docs/testing.md)."""
    import gc

    gc.collect()
    gc.freeze()


def pytest_collection_finish(session) -> None:
    """Freeze what the collection loaded (:func:`_freeze_what_is_loaded`). On an xdist worker: start each of
    ``SHARED_BUILDS`` the collected tests need in a background process.

    The worker takes the build's lock (the one :func:`built_once` takes) and hands it to the process, which holds
    it until it has written ``<name>.done``; a worker whose test needs the build then blocks on the lock while the
    build runs, instead of building it itself while the other worker waits for it with its core idle (95 s of
    one core in the first minutes of a clean-clone run). The other worker finds the lock taken and starts nothing."""
    _freeze_what_is_loaded()
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    import fcntl

    from tests.shared_builds import build_paths

    root = _run_root(session.config._tmp_path_factory)
    for name, (_build, fixture) in SHARED_BUILDS.items():
        if not any(fixture in getattr(item, "fixturenames", ()) for item in session.items):
            continue
        out, lock_path, done = build_paths(root, name)
        with open(lock_path, "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # the other worker started it
                continue
            if done.is_file():
                continue
            with open(root / f"{name}.log", "w") as log:
                proc = subprocess.Popen(
                    [sys.executable, "-P", __file__, name, str(out), str(done)],
                    pass_fds=(lock.fileno(),), stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
                if _ALL_CORES:  # the build may run on any core, not only on this worker's
                    with contextlib.suppress(OSError):
                        os.sched_setaffinity(proc.pid, _ALL_CORES)
                _background.append(proc)
        # our copy of the lock's descriptor is closed: the build process holds the lock alone


def pytest_sessionfinish(session, exitstatus) -> None:
    """Wait for the background builds (a test of the other worker may be waiting for one); a stopped run
    (``-x``, ``--maxfail``, interrupted) kills them."""
    stopped = session.shouldstop or session.shouldfail or exitstatus not in (0, 1)
    for proc in _background:
        if stopped and proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.fixture(scope="session")
def tiny_project(tmp_path_factory) -> Path:
    """A simulated ``tiny`` project (generated once per test run; treat it as read-only)."""
    return built_once(tmp_path_factory, "tiny", _build_tiny)


@pytest.fixture(scope="session")
def build_once(tmp_path_factory) -> Callable[[str, Callable[[Path], None]], Path]:
    """``build_once(name, build)``: :func:`built_once` for fixtures of test modules."""
    return lambda name, build: built_once(tmp_path_factory, name, build)


def _stamp(path: str) -> tuple[int, int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


@pytest.fixture
def linked_copy():
    """``linked_copy(src, dst, copied=None, **copytree_options)``: ``shutil.copytree`` with hard links to the files of
    ``src`` instead of copies, but for the files ``copied(path relative to src)`` names (those the test itself
    writes in place: they are copied). For the read-only workspaces that every case of ``test_bad_input.py`` and
    ``test_faults.py`` copies (13-27 MB a case, 10.6 GB of file writes in a run). A command or a case's setup writing
    in place into a linked file would write into the shared workspace: after the test, every linked file must still
    have the inode, size and modification time it had (the test fails otherwise, naming the files). Where the file
    system refuses a hard link, a copy."""
    linked: list[tuple[str, tuple]] = []

    def copy(src, dst, copied: Callable[[str], bool] | None = None, **options):
        src = os.fspath(src)

        def one(s, d):
            if copied is None or not copied(os.path.relpath(s, src)):
                stamp = _stamp(s)
                try:
                    os.link(s, d)
                except OSError:
                    pass
                else:
                    linked.append((s, stamp))
                    return d
            return shutil.copy2(s, d)

        return shutil.copytree(src, dst, copy_function=one, **options)

    yield copy
    changed = [s for s, stamp in linked if _stamp(s) != stamp]
    assert not changed, f"the test wrote in place into {len(changed)} hard-linked file(s) of the shared workspace " \
                        f"(copy them instead): {changed[:5]}"


if __name__ == "__main__":  # the background build of pytest_collection_finish (the lock is inherited)
    name, out, done = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    if os.environ.get(NUMBA_LOCKS_ENV):
        share_numba_compilations(Path(os.environ[NUMBA_LOCKS_ENV]))
    shutil.rmtree(out, ignore_errors=True)
    SHARED_BUILDS[name][0](out)
    done.touch()
