"""What a piece of work cost: wall time, CPU time and peak resident memory (for the chain's stage records
and the benchmarks).

CPU seconds are user + system of this process, of the children it reaped during the work (``os.times``)
and of the worker processes still alive at the end (a Dask ``local:N`` cluster; ``psutil``), less what
those had used before. Peak RSS of the work alone, without resetting any process's high-water mark (a reset,
``clear_refs``, also resets what ``/usr/bin/time -v``, ``wait4`` and a batch system's accounting report for the
whole job: a chain's job then showed its last stage's peak, a third of its rasters'): on Linux, when the mark
(``VmHWM``) rose during the work, the work set it and it is the peak; else the largest resident set read every
``SELF_SAMPLE_S`` during the work (a peak held for less than that may be missed). Other processes are seen
alive: every ``SAMPLE_S`` during the work a thread reads every live descendant, its mark when the mark rose since
the work began (or the descendant began after it), else its resident set; the workers' peak is the largest sum of
one reading (the last reading, at the end, takes the workers still alive). A child that ended during the work
counts with what it was last seen with; one that lived less than ``SAMPLE_S`` (a helper such as ``ldconfig``,
``true``) may not be seen at all. Not ``RUSAGE_CHILDREN``'s ``ru_maxrss``: for a child started by fork or vfork
that then execs, Linux keeps the old address space's high-water mark, which is this process's at the fork, so any
short helper added this process's memory again as a "worker". Elsewhere the process's lifetime peak
(``resource.getrusage``) stands in and ``rss_reset`` is False; without ``resource`` either, no peak (None).
Without ``psutil`` no other process is counted. Sizes in MiB.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

try:
    import psutil
except ImportError:  # pragma: no cover - declared, and a dependency of dask.distributed; still optional here
    psutil = None

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None

_MIB = 1024.0 * 1024.0
SAMPLE_S = 0.2  # how often the live descendants' high-water marks are read during the work (1.6 ms a reading)
SELF_SAMPLE_S = 0.02  # how often this process's resident set is read (about 30 us a reading)


@dataclasses.dataclass
class Usage:
    """The cost of one piece of work (filled in when the ``measure`` block ends)."""

    wall_s: float = 0.0
    cpu_s: float = 0.0  # this process, reaped children and live workers (user + system)
    peak_rss_mb: float | None = None  # this process
    workers_peak_rss_mb: float = 0.0  # sum of the worker processes' peaks (an upper bound of their total)
    rss_reset: bool = False  # peaks are of this work alone (else: since the process started)

    @property
    def total_peak_rss_mb(self) -> float | None:
        """This process plus its workers: an upper bound of the memory the work held at any time."""
        return None if self.peak_rss_mb is None else self.peak_rss_mb + self.workers_peak_rss_mb

    def record(self) -> dict:
        """Rounded numbers for a stamp or a JSON record (keys with units)."""
        out = dict(wall_s=round(self.wall_s, 2), cpu_s=round(self.cpu_s, 2))
        if self.peak_rss_mb is not None:
            out["peak_rss_mb"] = round(self.peak_rss_mb, 1)
            if self.workers_peak_rss_mb:
                out["workers_peak_rss_mb"] = round(self.workers_peak_rss_mb, 1)
            out["rss_reset"] = self.rss_reset
        return out


def _status_mb(pid: int | str = "self", field: str = "VmHWM") -> float | None:
    """A size field of ``/proc/<pid>/status`` (Linux; ``VmHWM``, ``VmRSS``), MiB."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _hwm_mb(pid: int | str = "self") -> float | None:
    """VmHWM of a process (Linux), MiB."""
    return _status_mb(pid, "VmHWM")


def _maxrss_mb(who) -> float | None:
    if resource is None:
        return None
    kb = resource.getrusage(who).ru_maxrss
    return kb / _MIB if sys.platform == "darwin" else kb / 1024.0  # bytes on macOS, KiB elsewhere


def _workers() -> dict:
    """pid -> (process, CPU seconds so far) of every live descendant."""
    if psutil is None:
        return {}
    out = {}
    try:
        kids = psutil.Process().children(recursive=True)
    except psutil.Error:
        return {}
    for p in kids:
        try:
            t = p.cpu_times()
            out[p.pid] = (p, t.user + t.system)
        except psutil.Error:
            continue
    return out


def _cpu_self_and_reaped() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class _Sampler:
    """Reads this process's resident set every ``SELF_SAMPLE_S`` (``self_peak_mb``) and the live descendants every
    ``SAMPLE_S`` in a thread: ``peak_mb`` is the largest sum of one reading, each descendant with its high-water mark
    when that rose above its mark when the work began (``marks_before``; a descendant started since: its mark), else
    with its resident set (a child caught between its fork and its exec would show this process's mark: the window
    is microseconds against ``SAMPLE_S``)."""

    def __init__(self, marks_before: dict | None = None):
        self.peak_mb = 0.0
        self.self_peak_mb = 0.0
        self._before = marks_before or {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="measure-sampler", daemon=True)

    def read_self(self) -> None:
        if (v := _status_mb("self", "VmRSS")) is not None:
            self.self_peak_mb = max(self.self_peak_mb, v)

    def read(self) -> None:
        self.read_self()
        if psutil is None:
            return
        total = 0.0
        try:
            kids = psutil.Process().children(recursive=True)
        except psutil.Error:
            return
        for p in kids:
            v = _hwm_mb(p.pid)
            if v is not None and p.pid in self._before and v <= self._before[p.pid]:
                v = _status_mb(p.pid, "VmRSS")
            if v is not None:
                total += v
        self.peak_mb = max(self.peak_mb, total)

    def _run(self) -> None:
        every = max(1, round(SAMPLE_S / SELF_SAMPLE_S))
        tick = 0
        while not self._stop.wait(SELF_SAMPLE_S):
            tick += 1
            if tick % every == 0:
                self.read()
            else:
                self.read_self()

    def __enter__(self):
        self.read_self()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.read()  # the workers alive at the end, with their whole marks


@contextlib.contextmanager
def measure() -> Iterator[Usage]:
    """``with measure() as usage:`` ... ``usage.wall_s, usage.cpu_s, usage.peak_rss_mb`` afterwards."""
    usage = Usage()
    mark0 = _hwm_mb()
    before = _workers()
    sampler = _Sampler({pid: m for pid in before if (m := _hwm_mb(pid)) is not None})
    cpu0 = _cpu_self_and_reaped()
    t0 = time.perf_counter()
    try:
        with sampler:
            yield usage
    finally:
        usage.wall_s = time.perf_counter() - t0
        after = _workers()
        cpu = _cpu_self_and_reaped() - cpu0
        for pid, (_, c1) in after.items():
            cpu += c1 - before.get(pid, (None, 0.0))[1]
        # a worker reaped during the work counts whole in os.times: take off what it had used before
        cpu -= sum(c0 for pid, (_, c0) in before.items() if pid not in after)
        usage.cpu_s = max(cpu, 0.0)
        mark1 = _hwm_mb() if mark0 is not None else None
        # the mark rose: the work set it; else the work's peak lay below an earlier one: the largest resident set read
        peak = None if mark1 is None else mark1 if mark1 > mark0 else (sampler.self_peak_mb or None)
        usage.rss_reset = peak is not None
        usage.peak_rss_mb = peak if peak is not None else _maxrss_mb(resource.RUSAGE_SELF if resource else None)
        usage.workers_peak_rss_mb = sampler.peak_mb
