"""Shared fixtures: the real reference data folder and simulated projects (generated once per session).

Under pytest-xdist (``make test`` runs ``-n auto``) the workers share the expensive read-only builds: the first
worker that needs one builds it under a file lock in the run's common temporary folder, the others wait for it
and reuse it (:func:`built_once`), so the simulator's kernels are compiled and the tiny block rendered once
per run, not once per worker."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("AEROTRI_SHARED_DATA", REPO.parent / "shared" / "data")).resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``; tests that need it skip with a reason when it is absent."""
    d = shared_data_dir()
    if not d.is_dir():
        pytest.skip(f"real reference data not found at {d} (set AEROTRI_SHARED_DATA)")
    return d


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """``build(folder)`` once per test run; returns ``folder`` (treat it as read-only).

    Without xdist: a new folder of this session. Under xdist: ``<run's temporary root>/<name>``, shared by the
    workers; the first one builds it under an ``flock`` and then writes ``<name>.done``, the others block on the
    lock and then find it (a folder without ``.done``, of a worker that died while building, is built anew)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        out = tmp_path_factory.mktemp(name) / name
        build(out)
        return out
    import fcntl

    root = tmp_path_factory.getbasetemp().parent  # <basetemp>/popen-gwN -> <basetemp>, common to the workers
    out, done = root / name, root / f"{name}.done"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file is closed (or the worker dies)
        if not done.is_file():
            shutil.rmtree(out, ignore_errors=True)
            build(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def tiny_project(tmp_path_factory) -> Path:
    """A simulated ``tiny`` project (generated once per test run; treat it as read-only)."""
    from aerotri.sim import load_preset, simulate

    return built_once(tmp_path_factory, "tiny", lambda out: simulate(load_preset("tiny"), out))


@pytest.fixture(scope="session")
def build_once(tmp_path_factory) -> Callable[[str, Callable[[Path], None]], Path]:
    """``build_once(name, build)``: :func:`built_once` for fixtures of test modules."""
    return lambda name, build: built_once(tmp_path_factory, name, build)
