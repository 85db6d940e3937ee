"""Read-only inputs built once per test run and shared by the xdist workers (see ``tests/conftest.py``).

:func:`built_once_in` is the lock protocol of ``conftest.built_once``; :func:`write_synthetic_project` is
``ortho.synthetic.write_synthetic_project`` rendered once per run for each set of options and copied to where the
test asks (every render of the 41 calls in the ortho tests cost 1.4-3.8 CPU-s, most options several times)."""

from __future__ import annotations

import dataclasses
import os
import pickle
import shutil
from pathlib import Path
from typing import Callable

# the run's folder for shared builds (set by tests/conftest.py at session start: the workers' common temporary root)
SHARED_DIR_ENV = "AEROTRI_TEST_SHARED_DIR"


def build_paths(root: Path, name: str) -> tuple[Path, Path, Path]:
    """(the build's folder, its ``flock`` file, the file that says it is done) under ``root``: the names
    :func:`built_once_in` and the background builds of ``tests/conftest.py`` agree on."""
    return root / name, root / f"{name}.lock", root / f"{name}.done"


def built_once_in(root: Path, name: str, build: Callable[[Path], None]) -> Path:
    """``build(root / name)`` once across the processes sharing ``root``; returns that folder (read-only).

    The first process builds it under an ``flock`` of ``<name>.lock`` and then writes ``<name>.done``; the others block
    on the lock and then find it (a folder without ``.done``, of a process that died while building, is built anew)."""
    import fcntl

    out, lock_path, done = build_paths(root, name)
    with open(lock_path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file is closed (or the process dies)
        if not done.is_file():
            shutil.rmtree(out, ignore_errors=True)
            build(out)
            done.touch()
    return out


def write_synthetic_project(root, **options):
    """``ortho.synthetic.write_synthetic_project(root, **options)``, its frames rendered once per test run: the
    project of these options is built in the run's shared folder and copied to ``root`` (a copy of its own, the
    test may change its files); returns its truth with ``root`` set. Outside a run (no shared folder) it renders."""
    from ortho import synthetic

    shared = os.environ.get(SHARED_DIR_ENV)
    if not shared:
        return synthetic.write_synthetic_project(root, **options)

    def build(out: Path) -> None:
        info = synthetic.write_synthetic_project(out / "project", **options)
        (out / "truth.pickle").write_bytes(pickle.dumps(info))

    name = "synthetic_" + "_".join(f"{k}-{options[k]}" for k in sorted(options))
    built = built_once_in(Path(shared), name, build)
    shutil.copytree(built / "project", root, dirs_exist_ok=True)
    return dataclasses.replace(pickle.loads((built / "truth.pickle").read_bytes()), root=Path(root))
