"""Logging set-up for the command lines, and progress reporting for long work.

The packages log through ``logging.getLogger(__name__)`` and carry only a ``NullHandler``: a script
that imports them decides what is shown. The CLIs call :func:`configure` (``-v``/``-q``/``--log-file``):

- stderr gets INFO and above (``-q``: warnings and errors only; ``-v``: DEBUG), as plain messages,
  warnings prefixed ``warning:``;
- ``--log-file FILE`` gets everything down to DEBUG with time stamps, whatever the stderr level.

:func:`progress` is the one progress reporter: a tqdm bar on a terminal; off a terminal (a batch job,
a log file) a periodic log line ``<what>: 120/1800 frames (6.7 %), 41 s elapsed, ETA 9 min 33 s``
every ``PROGRESS_INTERVAL_S`` seconds and one at the end.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import time

PACKAGES = ("aerotri", "lidarctl", "ortho")
PROGRESS_INTERVAL_S = 30.0  # default; the environment variable AEROTRI_PROGRESS_INTERVAL_S overrides it

_log = logging.getLogger("aerotri.progress")
_HANDLER_TAG = "_aerotri_cli_handler"


class _StderrFormatter(logging.Formatter):
    def format(self, record):
        msg = record.getMessage()
        if record.levelno >= logging.ERROR:
            return f"error: {msg}"
        if record.levelno >= logging.WARNING:
            return f"warning: {msg}"
        return msg


def configure(verbosity: int = 0, log_file=None) -> None:
    """Route the packages' loggers to stderr (level from ``verbosity``: -1 quiet, 0 info, 1+ debug) and
    optionally to ``log_file`` (always DEBUG). Replaces what an earlier call installed."""
    level = logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG
    handlers = []
    h = logging.StreamHandler(sys.stderr)
    h.setLevel(level)
    h.setFormatter(_StderrFormatter())
    handlers.append(h)
    if log_file:
        fh = logging.FileHandler(log_file, encoding="utf-8")
        fh.setLevel(logging.DEBUG)
        fh.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
        handlers.append(fh)
    for name in PACKAGES:
        lg = logging.getLogger(name)
        for old in [x for x in lg.handlers if getattr(x, _HANDLER_TAG, False)]:
            lg.removeHandler(old)
            old.close()
        for x in handlers:
            setattr(x, _HANDLER_TAG, True)
            lg.addHandler(x)
        lg.setLevel(logging.DEBUG if log_file else level)
        lg.propagate = False


_LOG_LINE = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} [A-Z]+ ")


def is_log_file(path) -> bool:
    """True when ``path`` may take log lines: it does not exist, is empty, or starts with a line of our
    file format (``configure``'s time stamp, level, logger). Keeps ``--log-file`` from appending to an
    input given by mistake."""
    try:
        with open(path, "rb") as f:
            head = f.read(200)
    except FileNotFoundError:
        return True
    except OSError:
        return True  # configure() reports what is wrong with it
    return not head or bool(_LOG_LINE.match(head.decode("utf-8", "replace")))


def is_quiet() -> bool:
    return logging.getLogger("aerotri").getEffectiveLevel() > logging.INFO and not any(
        isinstance(h, logging.FileHandler) for h in logging.getLogger("aerotri").handlers)


def _interval_s() -> float:
    text = os.environ.get("AEROTRI_PROGRESS_INTERVAL_S")
    if text is None:
        return PROGRESS_INTERVAL_S
    try:
        value = float(text)
        if value >= 0:
            return value
    except ValueError:
        pass
    _log.warning(f"AEROTRI_PROGRESS_INTERVAL_S={text!r} is not a number of seconds >= 0; using {PROGRESS_INTERVAL_S:g}")
    return PROGRESS_INTERVAL_S


def _duration(s: float) -> str:
    s = int(round(s))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {(s % 3600) // 60} min"


class _LogProgress:
    """The off-terminal progress: a log line every ``interval_s`` and one when done."""

    def __init__(self, total, desc, unit, interval_s):
        self.total, self.desc, self.unit = total, desc, unit
        self.n = 0
        self.t0 = self.last = time.monotonic()
        self.interval_s = interval_s

    def update(self, n=1):
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.interval_s:
            self.last = now
            _log.info(self._line(now))

    def _line(self, now) -> str:
        el = now - self.t0
        if self.total:
            frac = self.n / self.total
            eta = el * (1 - frac) / frac if frac > 0 else float("nan")
            tail = f", ETA {_duration(eta)}" if frac > 0 and self.n < self.total else ""
            return f"{self.desc}: {self.n:,}/{self.total:,} {self.unit} ({100 * frac:.1f} %), {_duration(el)} elapsed{tail}"
        return f"{self.desc}: {self.n:,} {self.unit}, {_duration(el)} elapsed"

    def close(self):
        if self.n and time.monotonic() - self.t0 >= self.interval_s:
            _log.info(self._line(time.monotonic()))

    def set_postfix_str(self, *a, **k):
        pass


@contextlib.contextmanager
def progress(total: int | None, desc: str, unit: str = "", **tqdm_kw):
    """A progress reporter with ``update(n)``: a tqdm bar on a terminal, periodic log lines otherwise,
    nothing with ``-q``."""
    if sys.stderr.isatty() and not is_quiet():
        from tqdm import tqdm

        with tqdm(total=total, desc=desc, unit=unit, leave=False, **tqdm_kw) as bar:
            yield bar
        return
    rep = _LogProgress(total, desc, unit or "items", _interval_s())
    try:
        yield rep
    finally:
        rep.close()


def track(iterable, desc: str, unit: str = "", total: int | None = None):
    """Iterate with :func:`progress` (``total`` defaults to ``len(iterable)``)."""
    if total is None:
        try:
            total = len(iterable)
        except TypeError:
            total = None
    with progress(total, desc, unit) as bar:
        for item in iterable:
            yield item
            bar.update(1)


def track_chunks(chunks, total_points: int, desc: str):
    """Iterate over (first_index, chunk) pairs with :func:`progress` counted in points."""
    with progress(total_points, desc, "points") as bar:
        for first, chunk in chunks:
            yield first, chunk
            bar.update(len(chunk))
