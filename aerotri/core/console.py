"""Console-script entry points that end the process without Python's finalization.

A command's outputs are written, closed and committed before its click command returns (``Command.writing``). What
the interpreter does after that (tearing down every imported module: numpy, OpenCV, rasterio, pyproj, scipy, shapely
...) costs 0.17-0.22 CPU-s of an ``ortho mosaic`` run of the demo and changes nothing on disk. ``console_script``
wraps a click group for ``[project.scripts]``: the group runs as click runs it, then what Python's own exit does
before the teardown runs as well: the non-daemon threads are joined (``threading._shutdown``, which also runs
``concurrent.futures``' exit hooks), the ``atexit`` handlers run (logging's shutdown flushes the log file), stdout and
stderr are flushed; then ``os._exit`` with the command's exit status.

The click group itself is untouched: ``CliRunner`` (the tests) runs it inside the test process as before. An
exception other than ``SystemExit`` (click turns every error it handles into one) goes through the interpreter's
normal exit: its traceback, status 1.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading

# the exit status of Python when flushing stdout or stderr at exit fails (e.g. a closed pipe)
FLUSH_FAILED_STATUS = 120


def exit_status(code) -> int:
    """The process exit status of ``sys.exit(code)``: None -> 0, an int -> itself, anything else is printed to
    stderr -> 1."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    try:
        print(code, file=sys.stderr)
    except (OSError, ValueError, AttributeError):
        pass
    return 1


def finish(status: int):
    """End the process with ``status`` after what Python's exit does before its teardown (module doc)."""
    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is not None and threading.current_thread() is threading.main_thread():
        shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):
            status = status or FLUSH_FAILED_STATUS
    os._exit(status)


def console_script(group):
    """A function for ``[project.scripts]`` that runs the click ``group`` (as click does: arguments from
    ``sys.argv``) and then ``finish`` es the process with its exit status."""

    def run():
        try:
            group.main()
        except SystemExit as exc:
            status = exit_status(exc.code)
        else:  # standalone click always raises SystemExit; a group run otherwise ended well
            status = 0
        finish(status)

    run.__doc__ = f"``{getattr(group, 'name', 'command')}`` as a console script (``aerotri.core.console``)."
    return run
