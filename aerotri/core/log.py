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
# the loggers of the libraries underneath (and Python's warnings): their notes and warnings are details for
# the debug log (-v, --log-file), not for the console; what matters to the user our code says itself
THIRD_PARTY = ("py.warnings", "rasterio", "fiona", "pyogrio", "distributed", "dask", "numba", "matplotlib", "PIL",
               "pyproj", "shapely", "urllib3", "asyncio", "tornado", "bokeh", "fsspec", "h5py")
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


class _AsDetail(logging.Filter):
    """A library's record (any logger outside ``PACKAGES``; a Python warning too) logged at DEBUG, its own level
    kept in the message: they are details, and a monitor that looks for WARNING or ERROR lines in a log file should
    find ours only (trial "overnight" L4: rasterio's PendingDeprecationWarning 7-11 times a run)."""

    def filter(self, record):
        if record.levelno > logging.DEBUG and record.name.split(".")[0] not in PACKAGES:
            record.msg = f"({record.levelname.lower()} of {record.name}) {record.msg}"
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


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
    for x in handlers:
        setattr(x, _HANDLER_TAG, True)
        x.addFilter(_AsDetail())  # on the handler: a logger's filter would miss its children's records
    for name in PACKAGES:
        lg = logging.getLogger(name)
        for old in [x for x in lg.handlers if getattr(x, _HANDLER_TAG, False)]:
            lg.removeHandler(old)
            old.close()
        for x in handlers:
            lg.addHandler(x)
        lg.setLevel(logging.DEBUG if log_file else level)
        lg.propagate = False
    # third-party loggers: to the log file, and to stderr only with -v (as debug details)
    debug_handlers = [x for x in handlers if isinstance(x, logging.FileHandler) or level <= logging.DEBUG]
    for name in THIRD_PARTY:
        lg = logging.getLogger(name)
        for old in [x for x in lg.handlers if getattr(x, _HANDLER_TAG, False)]:
            lg.removeHandler(old)
        for x in debug_handlers:
            lg.addHandler(x)
        if not debug_handlers:
            null = logging.NullHandler()
            setattr(null, _HANDLER_TAG, True)
            lg.addHandler(null)
        # their INFO and above (their own DEBUG chatter, e.g. numba's compiler, is never worth the cost)
        lg.setLevel(logging.INFO if debug_handlers else logging.WARNING)
        lg.propagate = False


@contextlib.contextmanager
def third_party_quiet():
    """For the block: Python warnings (numpy's RuntimeWarning, rasterio's NotGeoreferencedWarning, ...) go to
    the ``py.warnings`` logger (the debug log, :func:`configure`) instead of stderr, every time they occur
    (not once per place). The warnings machinery is as before afterwards."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        logging.captureWarnings(True)
        try:
            yield
        finally:
            logging.captureWarnings(False)


@contextlib.contextmanager
def native_stderr_to_log(what: str = "native"):
    """For the block: what C/C++ code writes to the process's stderr (file descriptor 2: gtsam's exception
    notes, GDAL's and PROJ's prints) goes to the debug log, one line per record, instead of the console.
    Python's own ``sys.stderr`` (our messages, a traceback of a bug) stays on the console. Does nothing when
    stderr is not the process's descriptor 2 (a test runner capturing it)."""
    try:
        is_fd2 = sys.stderr is not None and sys.stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):
        is_fd2 = False
    if not is_fd2:
        yield
        return
    import tempfile

    sys.stderr.flush()
    saved = os.dup(2)
    console = os.fdopen(os.dup(saved), "w", buffering=1, encoding=getattr(sys.stderr, "encoding", None) or "utf-8",
                        errors="backslashreplace")
    old_stderr = sys.stderr
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        sys.stderr = console  # Python's writes (and our log handler's) still reach the console
        _retarget_handlers(old_stderr, console)
        try:
            yield
        finally:
            try:
                sys.stderr.flush()
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                sys.stderr = old_stderr
                _retarget_handlers(console, old_stderr)
                console.close()
                sink.seek(0)
                lg = logging.getLogger("aerotri.native")
                for line in sink.read().decode("utf-8", "replace").splitlines():
                    if line.strip():
                        lg.debug(f"{what}: {line}")


def _retarget_handlers(old, new) -> None:
    for name in PACKAGES:
        for h in logging.getLogger(name).handlers:
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler) and h.stream is old:
                h.setStream(new)


_DOING: list[str] = []


class _Clock:
    """The clock of what runs now (``doing``): its start, and when a progress line was last logged in it. Every
    phase's progress (``_LogProgress``) inside counts its interval and its elapsed time from this clock, not from the
    phase's own start: a stage made of phases each shorter than the interval (``lidarctl rasters``: 90 s on the
    full-size 2 x 2 block, no line; trial-overnight) still logs a line per interval, and classify's first line says
    the stage's time, its tile split's included (it said "34 s elapsed" 86 s in)."""

    def __init__(self):
        self.t0 = self.last = time.monotonic()


_CLOCKS: list[_Clock] = []


@contextlib.contextmanager
def doing(name: str):
    """Name what runs now (a command, a stage of ``aerotri run``): an exception leaving the block carries
    the innermost name (``aerotri_doing``), so that a message about a vanished file or a full disk says
    where it happened. The block's progress lines count time from its start (``_Clock``)."""
    _DOING.append(name)
    _CLOCKS.append(_Clock())
    try:
        yield
    except BaseException as exc:
        if getattr(exc, "aerotri_doing", None) is None:
            with contextlib.suppress(AttributeError, TypeError):
                exc.aerotri_doing = " ".join(_DOING[:1] + [f"[{n}]" for n in _DOING[1:]])
        raise
    finally:
        _DOING.pop()
        _CLOCKS.pop()


def current_doing() -> str | None:
    return " ".join(_DOING[:1] + [f"[{n}]" for n in _DOING[1:]]) if _DOING else None


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


def counted(n: int, word: str) -> str:
    """``n`` and ``word`` for a message, ``word`` with an s unless ``n`` is 1: "1 tile", "12 tiles"."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _duration(s: float) -> str:
    s = int(round(s))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {(s % 3600) // 60} min"


class _LogProgress:
    """The off-terminal progress: a log line every ``interval_s`` and one when done. Inside ``doing`` (a command,
    a stage) the interval and the elapsed time are the block's (``_Clock``); the ETA is this phase's."""

    def __init__(self, total, desc, unit, interval_s):
        self.total, self.desc, self.unit = total, desc, unit
        self.n = 0
        self.start = time.monotonic()
        self.clock = _CLOCKS[-1] if _CLOCKS else _Clock()
        self.interval_s = interval_s
        self.first = None  # (time, count) when the first items were done
        self.logged_n = None  # the count of the last line logged

    @property
    def t0(self) -> float:
        return self.clock.t0

    def update(self, n=1):
        self.n += n
        now = time.monotonic()
        if self.first is None:
            self.first = (now, self.n)
        if now - self.clock.last >= self.interval_s:
            self.clock.last = now
            self.logged_n = self.n
            _log.info(self._line(now))

    def _line(self, now) -> str:
        el = now - self.clock.t0
        if self.total:
            frac = self.n / self.total
            own = now - self.start
            eta = own * (1 - frac) / frac if frac > 0 else float("nan")
            if self.first is not None and self.n > self.first[1] and now > self.first[0]:
                # the rate after the first items: those carry one-off costs (numba compilation, caches, opening)
                eta = (now - self.first[0]) / (self.n - self.first[1]) * (self.total - self.n)
            tail = f", ETA {_duration(eta)}" if frac > 0 and self.n < self.total else ""
            return f"{self.desc}: {self.n:,}/{self.total:,} {self.unit} ({100 * frac:.1f} %), {_duration(el)} elapsed{tail}"
        return f"{self.desc}: {self.n:,} {self.unit}, {_duration(el)} elapsed"

    def close(self):
        now = time.monotonic()
        # (not again when the last update logged the same count: the stage's clock and the phase's differ)
        if self.n and now - self.start >= self.interval_s and self.logged_n != self.n:
            self.clock.last = now
            _log.info(self._line(now))

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
