"""Fault injection for tests/test_faults.py (not a test module; loaded by path, also by the kill test's child
processes): creating files below a folder fails (disk full, read-only), the n-th move of a finished temporary
onto an output fails or kills the process, an input is deleted when it is first opened."""

from __future__ import annotations

import contextlib
import errno
import io
import os
import signal
from pathlib import Path

MARKERS = (".part-", ".commit-")


@contextlib.contextmanager
def patched(target, name, value):
    old = getattr(target, name)
    setattr(target, name, value)
    try:
        yield
    finally:
        setattr(target, name, old)


def _under(path, area) -> bool:
    try:
        Path(os.path.abspath(os.fspath(path))).relative_to(Path(area))
        return True
    except (ValueError, TypeError):
        return False


def _ours(path) -> bool:
    """Our own bookkeeping (locks, commit journals): not what a fault case aims at."""
    s = os.fspath(path)
    return s.endswith(".lock") or ".commit-" in s


@contextlib.contextmanager
def creation_fails(area: Path, code: int, skip_ours: bool = True):
    """Creating a file or folder below ``area`` raises OSError(``code``) (disk full: ENOSPC; read-only: EROFS)."""
    real_open, real_io_open, real_mkdir = os.open, io.open, os.mkdir
    hits = []

    def fail(path):
        hits.append(str(path))
        raise OSError(code, os.strerror(code), os.fspath(path))

    def os_open(path, flags, *a, **k):
        if flags & os.O_CREAT and _under(path, area) and not (skip_ours and _ours(path)):
            fail(path)
        return real_open(path, flags, *a, **k)

    def io_open(file, mode="r", *a, **k):
        if isinstance(file, (str, os.PathLike)) and any(c in mode for c in "wax+") and _under(file, area) \
                and not (skip_ours and _ours(file)):
            fail(file)
        return real_io_open(file, mode, *a, **k)

    def mkdir(path, *a, **k):
        if _under(path, area) and not (skip_ours and _ours(path)) and not os.path.isdir(path):
            fail(path)
        return real_mkdir(path, *a, **k)

    import builtins

    with patched(os, "open", os_open), patched(io, "open", io_open), patched(builtins, "open", io_open), \
            patched(os, "mkdir", mkdir):
        yield hits


@contextlib.contextmanager
def output_move_fails(area: Path, n: int, action=None):
    """The ``n``-th move of a finished temporary (``.<name>.part-*``) onto an output below ``area`` raises ENOSPC
    (or runs ``action`` instead: a kill)."""
    real = os.replace
    count = [0]

    def replace(src, dst, *a, **k):
        if ".part-" in os.fspath(src) and _under(dst, area) and not any(m in os.fspath(dst) for m in MARKERS):
            count[0] += 1
            if count[0] == n:
                if action is not None:
                    action()
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(dst))
        return real(src, dst, *a, **k)

    with patched(os, "replace", replace):
        yield count


@contextlib.contextmanager
def creation_kills(area: Path, n: int):
    """The process SIGKILLs itself at the ``n``-th file or folder it creates below ``area`` (not counting locks
    and commit journals)."""
    count = [0]

    def maybe_kill(path):
        if _under(path, area) and not _ours(path):
            count[0] += 1
            if count[0] == n:
                os.kill(os.getpid(), signal.SIGKILL)

    real_open, real_io_open, real_mkdir = os.open, io.open, os.mkdir

    def os_open(path, flags, *a, **k):
        if flags & os.O_CREAT:
            maybe_kill(path)
        return real_open(path, flags, *a, **k)

    def io_open(file, mode="r", *a, **k):
        if isinstance(file, (str, os.PathLike)) and any(c in mode for c in "wax+"):
            maybe_kill(file)
        return real_io_open(file, mode, *a, **k)

    def mkdir(path, *a, **k):
        maybe_kill(path)
        return real_mkdir(path, *a, **k)

    import builtins

    with patched(os, "open", os_open), patched(io, "open", io_open), patched(builtins, "open", io_open), \
            patched(os, "mkdir", mkdir):
        yield count


@contextlib.contextmanager
def vanishes(path: Path):
    """``path`` is deleted when it is first opened (by Python, GDAL through rasterio or pyogrio, laspy, OpenCV or
    PIL)."""
    import builtins

    import cv2
    import laspy
    import PIL.Image
    import pyogrio
    import pyogrio.raw
    import rasterio

    target = os.path.abspath(path)
    gone = []

    def hit(p) -> None:
        if not gone and isinstance(p, (str, os.PathLike)) and os.path.abspath(os.fspath(p)) == target:
            gone.append(target)
            os.unlink(target)

    def wrap(f):
        def g(p, *a, **k):
            hit(p)
            return f(p, *a, **k)
        return g

    with contextlib.ExitStack() as st:
        for mod, name in ((builtins, "open"), (io, "open"), (os, "open"), (rasterio, "open"), (laspy, "open"),
                          (laspy, "read"), (cv2, "imread"), (PIL.Image, "open"), (pyogrio, "list_layers"),
                          (pyogrio, "read_info"), (pyogrio.raw, "read")):
            st.enter_context(patched(mod, name, wrap(getattr(mod, name))))
        yield gone
