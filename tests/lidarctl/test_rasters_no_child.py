"""The rasters stage starts no child process: a child started by vfork then exec (``ctypes.util.find_library``'s
``ldconfig -p``) reports the parent's peak RSS as its own, and ``aerotri.core.resources.measure`` counts a child
that ended during a stage as a worker (the 2 x 2 DMC block's rasters: a 4.50 GB peak recorded as 7.09 GB)."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_freed_memory_kept_starts_no_child_and_sets_glibc_back():
    # in a fresh interpreter: ctypes.util's lookup would not run again once a test before had made it
    code = textwrap.dedent("""
        import sys
        events = []
        sys.addaudithook(lambda ev, args: events.append(ev) if ev in (
            "subprocess.Popen", "os.fork", "os.posix_spawn", "os.exec", "os.system") else None)
        import numpy as np
        from lidarctl.rasters.products import _freed_memory_kept
        with _freed_memory_kept():
            a = np.ones(50_000_000 // 8)  # 50 MB: from the heap while the thresholds are raised
            del a
        assert not events, events
        print("ok")
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr


def _windows_cdll(name, *args, **kwargs):
    # what ctypes.CDLL(None) does on Windows, Python 3.11 (reviewer 10): the rasters stage crashed on it
    raise TypeError("LoadLibrary() argument 1 must be str, not None")


def test_freed_memory_kept_leaves_other_platforms_alone(monkeypatch):
    import ctypes

    import numpy as np

    from lidarctl.rasters.products import _freed_memory_kept

    monkeypatch.setattr(ctypes, "CDLL", _windows_cdll)
    for platform in ("win32", "linux"):  # Windows: not asked; a ctypes that refuses None on Linux: caught
        monkeypatch.setattr(sys, "platform", platform)
        with _freed_memory_kept():
            a = np.ones(1000)
        assert a.sum() == 1000.0
