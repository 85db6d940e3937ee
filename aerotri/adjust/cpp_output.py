"""gtsam's own console lines, kept off the console and counted.

gtsam's ``GeneralSFMFactor2`` (the collinearity factor of explicit points when self-calibrating) writes
``CheiralityException: Landmark p12 behind Camera x3`` to C++ ``std::cout`` whenever a point lies behind
a camera at the values it is evaluated at (and then contributes a zero Jacobian). Python cannot catch
that: ``gtsam_quiet`` redirects the process's file descriptor 1 to a temporary file while gtsam
evaluates the graph, counts those lines (``CHEIRALITY``), logs them at debug level and passes any other
text on to the real standard output.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import re
import sys
import tempfile
import threading

log = logging.getLogger(__name__)

_LINE = re.compile(r"CheiralityException: Landmark (\S+) (?:moved )?behind [Cc]amera (\S+)")
_LOCK = threading.RLock()
_depth = 0


class CheiralityCount:
    """Points found behind a camera while gtsam evaluated the graph: lines seen and (point, camera) pairs."""

    def __init__(self):
        self.lines = 0
        self.pairs: set[tuple[str, str]] = set()

    def snapshot(self) -> tuple[int, int]:
        return self.lines, len(self.pairs)


CHEIRALITY = CheiralityCount()


def _flush_c_stdout() -> None:
    try:
        ctypes.CDLL(None).fflush(None)  # C stdio buffers (std::cout writes through them)
    except (OSError, AttributeError):  # no libc symbols (not expected on Linux/macOS): nothing buffered to lose
        pass


@contextlib.contextmanager
def gtsam_quiet():
    """Run gtsam calls with their ``std::cout`` lines captured (see the module docstring); reentrant."""
    global _depth
    with _LOCK:
        if _depth:  # already captured by an enclosing call
            _depth += 1
            try:
                yield
            finally:
                _depth -= 1
            return
        try:
            fd = sys.__stdout__.fileno() if sys.__stdout__ is not None else 1
        except (AttributeError, ValueError, OSError):
            fd = 1
        try:
            sys.stdout.flush()
        except (AttributeError, ValueError, OSError):
            pass
        _flush_c_stdout()
        try:
            saved = os.dup(fd)
        except OSError:  # no standard output to redirect: nothing reaches a console either
            yield
            return
        _depth = 1
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), fd)
            try:
                yield
            finally:
                try:
                    sys.stdout.flush()
                except (AttributeError, ValueError, OSError):
                    pass
                _flush_c_stdout()
                os.dup2(saved, fd)
                os.close(saved)
                _depth = 0
                tmp.seek(0)
                text = tmp.read().decode("utf-8", errors="replace")
        _sort(text)


def _sort(text: str) -> None:
    """Count the cheirality lines of captured text; write anything else back to standard output."""
    other = []
    for line in text.splitlines(keepends=True):
        m = _LINE.search(line)
        if m:
            CHEIRALITY.lines += 1
            CHEIRALITY.pairs.add((m.group(1), m.group(2)))
            log.debug("gtsam: %s", line.strip())
        elif line.strip():
            other.append(line)
    if other:
        sys.stdout.write("".join(other))
        sys.stdout.flush()


@contextlib.contextmanager
def counting():
    """A fresh ``CheiralityCount`` for the calls inside (added to the enclosing count afterwards)."""
    global CHEIRALITY
    outer = CHEIRALITY
    inner = CHEIRALITY = CheiralityCount()
    try:
        yield inner
    finally:
        CHEIRALITY = outer
        outer.lines += inner.lines
        outer.pairs |= inner.pairs
