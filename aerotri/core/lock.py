"""One writer at a time: an advisory lock on a project folder (or on an output outside a project).

Every command that writes into a project holds ``PROJECT/.aerotri.lock`` while it runs: an ``flock`` on the
file, which holds the holder's pid, host, command line and start time (JSON). A second command on the same
project stops at once with a message naming the holder, or with ``--wait SECONDS`` waits up to that long
(saying once what it waits for). The lock file is removed when the command ends.

A killed command cannot remove its lock file, but the kernel releases its ``flock`` when the process dies:
the next command takes the lock at once and finds the dead holder's record in the file: it says so (a
stale lock) and goes on; it then rolls back the killed command's unfinished commits and sweeps its
temporaries (``aerotri.core.commands``).

``flock`` locks are per open file; the same process may take the lock of a folder again (a command
calling another in-process): the inner call shares the outer one's lock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path

from aerotri.core.errors import AerotriError

LOCK_NAME = ".aerotri.lock"
POLL_S = 0.2

_log = logging.getLogger(__name__)
_HELD: dict[str, int] = {}  # lock file (absolute) -> how many times this process holds it


class BusyError(AerotriError):
    """Another command is writing the same project (or output) and the lock was not free in time."""


@dataclasses.dataclass(frozen=True)
class Holder:
    """Who holds (or held) a lock: what the lock file says."""

    pid: int | None
    host: str
    command: str
    started: str

    @classmethod
    def read(cls, text: str) -> "Holder | None":
        try:
            d = json.loads(text)
            return cls(int(d["pid"]), str(d.get("host", "?")), str(d.get("command", "?")), str(d.get("started", "?")))
        except (ValueError, KeyError, TypeError):
            return None

    def describe(self) -> str:
        return f"`{self.command}` (pid {self.pid} on {self.host}, started {self.started})"


def _me(command: str) -> str:
    return json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": command,
                       "started": time.strftime("%Y-%m-%d %H:%M:%S")}) + "\n"


def _read(path: Path) -> Holder | None:
    try:
        return Holder.read(path.read_text(encoding="utf-8"))
    except OSError:
        return None


@contextlib.contextmanager
def hold_lock(path, command: str | None = None, wait_s: float = 0.0, what: str | None = None):
    """Hold the advisory lock file ``path`` for the block (see the module docstring).

    ``command``: what the lock file records (default: this process's command line); ``wait_s``: how long
    to wait for another holder (0: stop at once with ``BusyError``); ``what``: the name of the locked thing
    in messages (default: the lock file's folder). Yields the stale ``Holder`` found, if any."""
    import fcntl

    path = Path(os.path.abspath(path))
    key = str(path)
    if _HELD.get(key):
        _HELD[key] += 1
        try:
            yield None
        finally:
            _HELD[key] -= 1
        return
    command = command or " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])
    what = what or str(path.parent)
    deadline = time.monotonic() + max(0.0, wait_s)
    said = False
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            exc.filename = str(path.parent)  # the folder that cannot take it (read-only, full, no permission)
            raise
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = _read(path)
            for _ in range(20):  # the holder writes its record just after taking the lock
                if holder is not None:
                    break
                time.sleep(0.025)
                holder = _read(path)
            who = holder.describe() if holder else "another command"
            if time.monotonic() >= deadline:
                hint = "; give --wait SECONDS to wait for it" if wait_s <= 0 else f" after waiting {wait_s:g} s"
                raise BusyError(f"{what}: {who} is writing it{hint} (one command at a time writes a project)")
            if not said:
                _log.warning(f"{what}: {who} is writing it; waiting up to {wait_s:g} s for it to finish")
                said = True
            time.sleep(POLL_S)
            continue
        # the file may have been removed (and made again) by the holder we waited for: lock the file that
        # is there now, not an unlinked one
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        break
    stale = None
    try:
        with os.fdopen(os.dup(fd), "r+", encoding="utf-8") as f:
            previous = f.read()
            if previous.strip():
                stale = Holder.read(previous)
                _log.warning(f"{what}: a stale lock of {stale.describe() if stale else 'an unknown command'} "
                             "(it ended without releasing it: killed?); taking it over and undoing what it left")
            f.seek(0)
            f.truncate()
            f.write(_me(command))
        _HELD[key] = 1
        yield stale
    finally:
        _HELD.pop(key, None)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)  # while still locked: a waiter then finds the file gone and locks a new one
        os.close(fd)


def lock_path_for(folder) -> Path:
    return Path(folder) / LOCK_NAME
