"""Atomic output: write to a temporary file in the same folder, rename on success.

A crash or an error never leaves a partial output file behind. Every
temporary file and folder these helpers make next to an output is named ``.<name>.part-XXXX[suffix]``
(``TEMP_MARKER``), so that what a killed process left behind can be found and swept (``remove_leftovers``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from aerotri.core.errors import OptionError


TEMP_MARKER = ".part-"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; move it onto ``path`` only if the block succeeds.

    The temporary name keeps the suffix so that libraries choosing a driver by extension work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}{TEMP_MARKER}", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # mkstemp creates 0600 files; give the output the permissions of an ordinary new file.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@contextlib.contextmanager
def atomic_dir(path):
    """Yield a temporary folder next to ``path``; it replaces ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_dir(path.parent, path.name)
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        if path.exists():
            old = path.with_name(f".{path.name}{TEMP_MARKER}old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def temporary_dir(parent, name: str) -> Path:
    """A new temporary folder ``.<name>.part-XXXX`` in ``parent`` (the caller removes it)."""
    Path(parent).mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{name}{TEMP_MARKER}", dir=parent))


@contextlib.contextmanager
def scratch_dir(parent, name: str):
    """``temporary_dir`` for the duration of a block, removed afterwards."""
    tmp = temporary_dir(parent, name)
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_leftovers(folder) -> list[Path]:
    """Delete the temporaries a killed process left in ``folder`` (not below it): files and folders named
    ``.<name>.part-*``. Returns what was removed. Only for folders no other process is writing to."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    gone = sorted(folder.glob(f".*{TEMP_MARKER}*"))
    for q in gone:
        if q.is_dir():
            shutil.rmtree(q, ignore_errors=True)
        else:
            q.unlink(missing_ok=True)
    return gone


def refuse_input_as_output(output, inputs, option: str = "output") -> None:
    """``InputError`` when ``output`` is (or resolves to, through links) one of ``inputs``: a writer must
    never replace what it reads. ``inputs`` may hold None (absent optional inputs)."""
    out = Path(output).resolve()
    for p in inputs:
        if p is None:
            continue
        src = Path(p).resolve()
        if out == src:
            raise OptionError(f"{output}: the output is the input {p} (inputs are never modified; "
                              "choose another output path)", param=option)
