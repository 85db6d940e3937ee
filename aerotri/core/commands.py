"""The click plumbing every command line shares (``aerotri``, ``lidarctl``, ``ortho``).

- :class:`Group` / :class:`Command`: every command gets ``-v/--verbose``, ``-q/--quiet`` and
  ``--log-file``, logging is configured before it runs (``aerotri.core.log``), and one handler maps
  the error hierarchy (``aerotri.core.errors``) to a one-line message on stderr and exit code 2: no
  traceback. A command that runs out of memory says so with the same exit code; Ctrl-C exits 130.
- :func:`scheduler_options`: ``--scheduler``/``--workers`` for the commands that scale out.
- :func:`positive`, :func:`at_least`, :func:`fraction`, :func:`finite`: click parameter types for
  ranges, so an out-of-range option stops before any work with click's message naming the option.
  The float types also refuse NaN and infinities (``click.FloatRange`` alone lets NaN through: every
  comparison with NaN is false).
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time

import click

from aerotri.core import log
from aerotri.core.errors import AerotriError

_logger = logging.getLogger("aerotri")


def _logging_params() -> list[click.Option]:
    return [
        click.Option(["-v", "--verbose"], count=True, help="More messages (debug details)."),
        click.Option(["-q", "--quiet"], count=True, help="Warnings and errors only; no progress."),
        click.Option(["--log-file"], type=click.Path(dir_okay=False, writable=True),
                     help="Also write every message, with time stamps, to this file."),
    ]


def report_error(exc: AerotriError) -> None:
    click.echo(exc.user_message(), err=True)
    _logger.debug("error details", exc_info=exc)


@contextlib.contextmanager
def _exit_cleanly_on_sigterm():
    """While the command runs, SIGTERM (a batch system's kill, ``timeout``) ends it as Ctrl-C does: Python
    unwinds, so the atomic writers remove their temporaries instead of leaving ``.<name>.part-*`` behind.
    The caller's handler is back afterwards (a command called in-process, e.g. from a test runner)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers belong to the main thread (a command called from a worker thread)
        return

    def _term(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class GroupedOption(click.Option):
    """An option that ``--help`` lists under its own heading (``group``), after the other options: e.g.
    the parameters of each ground filter of ``lidarctl classify``."""

    def __init__(self, *args, group: str, **kwargs):
        super().__init__(*args, **kwargs)
        self.group = group


class Command(click.Command):
    """A command with the logging options and the error handler (see the module docstring)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.params.extend(_logging_params())

    def format_options(self, ctx, formatter):
        """The options, then each heading of :class:`GroupedOption` s with its options."""
        plain, groups = [], {}
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is not None:
                group = getattr(param, "group", None)
                (groups.setdefault(group, []) if group else plain).append(record)
        for heading, records in [("Options", plain), *groups.items()]:
            if records:
                with formatter.section(heading):
                    formatter.write_dl(records)

    def invoke(self, ctx):
        verbose = ctx.params.pop("verbose", 0) or 0
        quiet = ctx.params.pop("quiet", 0) or 0
        log_file = ctx.params.pop("log_file", None)
        if log_file and not log.is_log_file(log_file):
            click.echo(f"Error: --log-file {log_file}: the file exists and is not a log of this toolkit; "
                       "give a new file name (a log is only ever appended to, never an input overwritten)", err=True)
            sys.exit(2)
        try:
            log.configure(verbose - quiet, log_file)
        except OSError as exc:
            click.echo(f"Error: --log-file {log_file}: cannot write ({exc.strerror})", err=True)
            sys.exit(2)
        t0 = time.perf_counter()
        _logger.debug("%s started with %s", ctx.command_path,
                      ", ".join(f"{k}={v!r}" for k, v in ctx.params.items()) or "no options")
        try:
            with _exit_cleanly_on_sigterm():
                result = super().invoke(ctx)
            _logger.debug("%s finished in %.1f s", ctx.command_path, time.perf_counter() - t0)
            return result
        except AerotriError as exc:
            report_error(exc)
            sys.exit(2)
        except MemoryError:
            click.echo(f"Error: {ctx.command_path}: out of memory; use a coarser resolution, smaller tiles or "
                       "fewer workers", err=True)
            sys.exit(2)
        except KeyboardInterrupt:
            click.echo("Interrupted.", err=True)
            sys.exit(130)


class Group(click.Group):
    """A command group whose commands (and sub-groups) are :class:`Command` s."""

    command_class = Command
    group_class = type


def scheduler_options(f):
    """Click options ``--scheduler`` and ``--workers`` for commands that scale out."""
    f = click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Local worker threads (default: all cores); with --scheduler local:N, N processes.")(f)
    f = click.option("--scheduler", "scheduler", default=None, metavar="ADDRESS",
                     help="Dask scheduler: tcp://host:8786 for a cluster, local:N for N local worker "
                          "processes, synchronous for one task at a time; default local threads.")(f)
    return f


class FiniteFloatRange(click.FloatRange):
    """``click.FloatRange`` that also refuses NaN and infinities."""

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return rv

    def _describe_range(self) -> str:
        if self.min is None and self.max is None:
            return "finite"
        return super()._describe_range()


def finite() -> click.ParamType:
    """Any finite number (no NaN, no infinity)."""
    return FiniteFloatRange()


def positive(kind=float) -> click.ParamType:
    """A number strictly above zero."""
    return FiniteFloatRange(min=0, min_open=True) if kind is float else click.IntRange(min=1)


def at_least(minimum, kind=float) -> click.ParamType:
    return FiniteFloatRange(min=minimum) if kind is float else click.IntRange(min=minimum)


def fraction(open_low: bool = False, open_high: bool = True) -> click.ParamType:
    """A number in [0, 1) (or the given openness)."""
    return FiniteFloatRange(0.0, 1.0, min_open=open_low, max_open=open_high)
