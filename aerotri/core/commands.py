"""The click plumbing every command line shares (``aerotri``, ``lidarctl``, ``ortho``).

- :class:`Group` / :class:`Command`: every command gets ``-v/--verbose``, ``-q/--quiet``, ``--log-file``
  and ``--wait``, logging is configured before it runs (``aerotri.core.log``; third-party warnings and
  notes go to the debug log, not the console), and one handler maps the error hierarchy
  (``aerotri.core.errors``) to a one-line message on stderr and exit code 2: no traceback. A command that
  runs out of memory, out of disk space, into a read-only folder, or whose input vanishes while it runs
  says so in one line with the same exit code (:func:`fault_message`); Ctrl-C exits 130, SIGTERM 143.
- What a command writes (:meth:`Command.writing`): a command with a ``project`` argument holds the
  project's lock (``aerotri.core.lock``: a second command stops, or waits with ``--wait SECONDS``), rolls
  back what a killed command left there (unfinished commits) and sweeps its temporaries, then commits
  everything it writes together (``aerotri.core.atomic.commit_outputs``: all new, or all old when it
  fails). A command writing outputs named by its options (``OUTPUT_PARAMS``: OUT_PATH, OUTDIR, --json,
  ...) does the same for each output (a lock per output, in its folder; the project's lock too when
  the output is inside a project folder). ``aerotri run`` commits stage by stage (``per_stage``).
- :func:`scheduler_options`: ``--scheduler``/``--workers`` for the commands that scale out.
- :func:`positive`, :func:`at_least`, :func:`fraction`, :func:`finite`: click parameter types for
  ranges, so an out-of-range option stops before any work with click's message naming the option.
  The float types also refuse NaN and infinities (``click.FloatRange`` alone lets NaN through: every
  comparison with NaN is false).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import sys
import time
from pathlib import Path

import click

from aerotri.core import log
from aerotri.core.errors import AerotriError, interrupt_of

_logger = logging.getLogger("aerotri")

# parameters (click names) that hold a file or folder a command writes
OUTPUT_PARAMS = ("out_path", "outdir", "output_path", "output", "json_path", "png_path", "out_dir", "out_stem")
# the folders of a project that no command writes (its inputs): not searched for temporaries
PROJECT_INPUT_DIRS = ("images", "lidar", "trajectory")
MAX_WAIT_S = 7 * 24 * 3600.0


def _logging_params() -> list[click.Option]:
    return [
        click.Option(["-v", "--verbose"], count=True, help="More messages (debug details)."),
        click.Option(["-q", "--quiet"], count=True, help="Warnings and errors only; no progress."),
        click.Option(["--log-file"], type=click.Path(dir_okay=False, writable=True),
                     help="Also write every message, with time stamps, to this file."),
        click.Option(["--wait", "wait_s"], type=FiniteFloatRange(0, MAX_WAIT_S), default=0.0, metavar="SECONDS",
                     help="When another command is writing the same project or output, wait up to SECONDS for it "
                          "to finish [default: stop at once, naming it]."),
    ]


def _to_log_file(level: int, message: str) -> None:
    """A record for the --log-file alone (the console has the line from click): an error's or an interruption's
    ERROR line, which the log lacked (a monitor grepping for ERROR found a failed night run's log clean: only a DEBUG
    "error details" traceback; trial s96 M4)."""
    for name in ("aerotri", "ortho", "lidarctl"):  # (log.configure gives each package logger the same file handler)
        lg = logging.getLogger(name)
        files = [h for h in lg.handlers if isinstance(h, logging.FileHandler)]
        if files:
            record = lg.makeRecord(lg.name, level, __file__, 0, message, None, None)
            for h in files:
                h.handle(record)
            return


def report_error(exc: AerotriError) -> None:
    click.echo(exc.user_message(), err=True)
    _to_log_file(logging.ERROR, exc.user_message())
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
        raise KeyboardInterrupt("SIGTERM")  # (said so where the run's stop is recorded: not "Ctrl-C")

    previous = signal.signal(signal.SIGTERM, _term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class _StdoutToClosedPipe:
    """``sys.stdout`` while a command runs: a reader that closed the pipe (``... | head``) no longer stops the
    command. Before, the summary it prints before its outputs are committed raised BrokenPipeError inside the commit,
    and the finished outputs were rolled back (trial-lidar: ``lidarctl contours ... | head -0`` removed c.gpkg). The
    rest of what it prints is dropped (sent to the null device, so the exit-time flush is quiet too)."""

    def __init__(self, stream, text: "_StdoutToClosedPipe | None" = None):
        self._stream = stream
        self._text = text  # the text stream whose ``buffer`` this is (they lose the pipe together)
        self._lost = False

    @property
    def lost(self) -> bool:
        return self._text.lost if self._text is not None else self._lost

    @property
    def buffer(self):
        """The binary stream under it (``sys.stdout.buffer.write``), dropping the same way (review 29)."""
        return _StdoutToClosedPipe(self._stream.buffer, self)

    def _closed(self) -> None:
        if self._text is not None:
            self._text._closed()
            return
        if not self._lost:
            self._lost = True
            _logger.debug("standard output closed by its reader; the rest of the command's summary is dropped")
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, self._stream.fileno())
                os.close(devnull)
            except (OSError, ValueError, AttributeError):  # a stream without a descriptor (a test runner's)
                pass

    def write(self, text):
        if self.lost:
            return len(text)
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed()
            return len(text)

    def flush(self):
        if self.lost:
            return
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def _stdout_survives_closed_pipe():
    """``sys.stdout`` as :class:`_StdoutToClosedPipe` while the command runs; the caller's stream afterwards."""
    previous = sys.stdout
    if previous is None or isinstance(previous, _StdoutToClosedPipe):
        yield
        return
    sys.stdout = _StdoutToClosedPipe(previous)
    try:
        yield
    finally:
        sys.stdout = previous


class GroupedOption(click.Option):
    """An option that ``--help`` lists under its own heading (``group``), after the other options: e.g.
    the parameters of each ground filter of ``lidarctl classify``."""

    def __init__(self, *args, group: str, **kwargs):
        super().__init__(*args, **kwargs)
        self.group = group


class Command(click.Command):
    """A command with the logging options, the error handler and the writing discipline (module docstring).

    ``per_stage``: the command commits its outputs stage by stage itself (``aerotri run``), not as a whole.
    ``outputs``: ``params -> [paths]``, the outputs of a command that names them otherwise than by a parameter
    of ``OUTPUT_PARAMS`` (the last of several arguments, a default next to the input)."""

    def __init__(self, *args, per_stage: bool = False, outputs=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.per_stage = per_stage
        self.outputs = outputs
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

    @contextlib.contextmanager
    def writing(self, ctx, wait_s: float = 0.0):
        """Locks, clean-up of a killed run's leftovers and the commit of the outputs (module docstring)."""
        from aerotri.core.atomic import commit_outputs, remove_leftovers_below
        from aerotri.core.lock import LOCK_NAME, hold_lock

        # what the lock file records: the command line when run from one, else the command's name
        command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) \
            if sys.argv and Path(sys.argv[0]).name == ctx.find_root().info_name else ctx.command_path
        self._writes_to = []  # what a fault without a file name is about (fault_message)
        with contextlib.ExitStack() as stack:
            locked = set()

            def lock_project(root: Path) -> None:
                if root.resolve() in locked:
                    return
                locked.add(root.resolve())
                stack.enter_context(hold_lock(root / LOCK_NAME, command, wait_s, f"project {root}"))
                gone = remove_leftovers_below(root, skip=PROJECT_INPUT_DIRS)
                if gone:
                    _logger.info(f"{root}: removed {len(gone)} temporaries and unfinished outputs of an "
                                 "interrupted run")

            project = ctx.params.get("project")
            if project is not None and Path(project).is_dir():
                root = Path(project)
                self._writes_to.append(root)
                lock_project(root)
                if not self.per_stage:
                    stack.enter_context(commit_outputs(root))
            elif project is not None and not Path(project).exists():
                self._lock_output(stack, Path(project), command, wait_s, lock_project)
            values = [ctx.params.get(name) for name in OUTPUT_PARAMS]
            if self.outputs is not None:
                values += list(self.outputs(ctx.params))
            seen = set()
            for value in values:
                if value is None or str(value) == "" or Path(value).absolute() in seen:
                    continue
                out = Path(value)
                seen.add(out.absolute())
                if project is not None and Path(project).is_dir() and _inside(out, Path(project)):
                    continue
                self._lock_output(stack, out, command, wait_s, lock_project)
            yield

    def _lock_output(self, stack, out: Path, command: str, wait_s: float, lock_project) -> None:
        """The lock, clean-up and commit of one output outside a project argument: a file or folder ``out``."""
        from aerotri.core.atomic import commit_outputs, recover_commits, remove_leftovers, remove_leftovers_below
        from aerotri.core.lock import hold_lock

        self._writes_to.append(out)
        home = _project_above(out)
        if home is not None:
            lock_project(home)
        if out.is_dir() and (out / "project.toml").is_file():
            # an output folder that is a project (`aerotri sim --force P`): under the project's lock too, which a
            # run in it holds (trial-paths: sim replaced P beneath a running `aerotri run P`, which said "done")
            lock_project(out)
        parent = out.parent if str(out.parent) else Path(".")
        existing = next((d for d in (parent, *parent.parents) if d.is_dir()), Path("."))
        stack.enter_context(hold_lock(existing / f".{out.name}.lock", command, wait_s, str(out)))
        if parent.is_dir():
            recover_commits(parent)
            remove_leftovers(parent, names=[out.name])
        # a linked output (a link to a folder or file elsewhere) is written beside its target (``atomic_dir``):
        # what a killed run left there (temporaries, an unfinished commit) is recovered and swept there too
        real = Path(os.path.realpath(out))
        if real.parent.is_dir() and real != Path(os.path.realpath(parent)) / out.name:  # a link, in any folder
            # and under the target's own lock: a run writing the target by its real path (or by another link) holds
            # that one, and its live temporaries must not be swept (review 15)
            stack.enter_context(hold_lock(real.parent / f".{real.name}.lock", command, wait_s, str(real)))
            recover_commits(real.parent)
            remove_leftovers(real.parent, names=[real.name])
        if out.is_dir():
            remove_leftovers_below(out)
        if not self.per_stage:
            stack.enter_context(commit_outputs(parent, prune_below=[out]))

    def invoke(self, ctx):
        verbose = ctx.params.pop("verbose", 0) or 0
        quiet = ctx.params.pop("quiet", 0) or 0
        log_file = ctx.params.pop("log_file", None)
        wait_s = ctx.params.pop("wait_s", 0.0) or 0.0
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
            with _exit_cleanly_on_sigterm(), _stdout_survives_closed_pipe(), log.third_party_quiet(), \
                    log.native_stderr_to_log(ctx.command_path), log.doing(ctx.command_path), self.writing(ctx, wait_s):
                result = super().invoke(ctx)
            _logger.debug("%s finished in %.1f s", ctx.command_path, time.perf_counter() - t0)
            return result
        except AerotriError as exc:
            report_error(exc)
            sys.exit(2)
        except MemoryError:
            message = (f"Error: {ctx.command_path}: out of memory; use a coarser resolution, smaller tiles or "
                       "fewer workers")
            click.echo(message, err=True)
            _to_log_file(logging.ERROR, message)
            sys.exit(2)
        except KeyboardInterrupt as exc:
            _interrupted(ctx, exc)
        except Exception as exc:
            interrupt = interrupt_of(exc)
            if interrupt is not None:
                _interrupted(ctx, interrupt)
            writes_to = getattr(self, "_writes_to", [])
            message = fault_message(exc, getattr(exc, "aerotri_doing", None) or ctx.command_path,
                                    ", ".join(map(str, writes_to)) or None, writes_to)
            if message is None:
                raise
            click.echo(f"Error: {message}", err=True)
            _to_log_file(logging.ERROR, f"Error: {message}")
            _logger.debug("error details", exc_info=exc)
            sys.exit(2)


def _interrupted(ctx, exc: KeyboardInterrupt) -> None:
    click.echo("Interrupted.", err=True)
    # SIGTERM exits 128 + 15 as a shell reports a terminated process, Ctrl-C 130 (trial s96 M4: 130 for both)
    term = "SIGTERM" in exc.args
    _to_log_file(logging.ERROR, f"{ctx.command_path}: interrupted ({'SIGTERM' if term else 'Ctrl-C'})")
    sys.exit(143 if term else 130)


def _inside(path: Path, folder: Path) -> bool:
    try:
        Path(path).resolve().relative_to(Path(folder).resolve())
        return True
    except ValueError:
        return False


def _project_above(path: Path, levels: int = 4) -> Path | None:
    """The project folder (with project.toml) that holds ``path``, looking up to ``levels`` folders up."""
    p = Path(path).absolute().parent
    for d in [p, *p.parents][:levels]:
        if (d / "project.toml").is_file():
            return d
    return None


_IO_LIBRARIES = ("rasterio", "pyogrio", "fiona", "sqlite3", "laspy", "lazrs")  # their errors may be about the disk
SHORT_WRITE = -1  # a write that wrote less than asked (numpy's tofile: "N requested and M written")
_GDAL_FAULTS = (("No space left on device", errno.ENOSPC), ("Free disk space available is", errno.ENOSPC),
                ("Disk quota exceeded", errno.EDQUOT), ("Read-only file system", errno.EROFS),
                ("Permission denied", errno.EACCES), ("No such file or directory", errno.ENOENT),
                ("File too large", errno.EFBIG), ("database or disk is full", errno.ENOSPC),
                (" requested and ", SHORT_WRITE),
                # numpy's tofile of more than 16 MB reserves the space first (posix_fallocate) and says this
                ("Not enough free space to write", errno.ENOSPC),
                # rasterio's write of a window whose GDAL error was not chained (a full disk under a 1 GP mosaic)
                ("Write failed. See previous exception", SHORT_WRITE))


def _fault(exc: BaseException) -> tuple[int, str | None] | None:
    """(errno, path) of an exception that is about the file system (a write that could not be made, a file
    that is not there), looking through the causes of wrapped exceptions; None for anything else."""
    from aerotri.core.atomic import DISK_ERRNOS

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno is not None and (exc.errno in DISK_ERRNOS or exc.errno in (
                errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG)):
            return exc.errno, None if exc.filename is None else str(exc.filename)
        text = str(exc)
        if type(exc).__module__.split(".")[0] in _IO_LIBRARIES or isinstance(exc, OSError):
            for needle, code in _GDAL_FAULTS:
                if needle in text:
                    if code == errno.ENOENT:  # (a file not there is no output being written)
                        return code, _path_in(text, needle)
                    if code == errno.EACCES:
                        # a file it could not open, named by GDAL: an input as often as the output (review 51: a frame
                        # ortho it could not read was blamed on ortho/mosaic.tif)
                        from aerotri.core.atomic import COMMIT_MARKER, TEMP_MARKER

                        named = _path_in(text, needle)
                        if named is not None and not any(m in named for m in (TEMP_MARKER, COMMIT_MARKER)):
                            return code, named
                        return code, getattr(exc, "aerotri_output", None) or named
                    return code, getattr(exc, "aerotri_output", None) or _path_in(text, needle)
        exc = exc.__cause__ or exc.__context__
    return None


def _path_in(text: str, needle: str | None = None) -> str | None:
    """The path a GDAL message names: what stands before ": <needle>" ('sub/y.tif: Permission denied', relative or
    with spaces: review 52), else the first word that looks like an absolute path ('/x/y.tif: No such file ...')."""
    import re

    if needle is not None:
        at = text.find(needle)
        head = text[:at].rstrip() if at > 0 else ""
        if head.endswith(":"):
            line = head[:-1].splitlines()[-1].strip().strip("'\"")
            # (GDAL's own prefix, "TIFFOpen: x.tif", is no part of the path)
            line = re.sub(r"^[A-Za-z_]+\(?\)?: ", "", line)
            if line and ("/" in line or "." in Path(line).name):
                return line
    m = re.search(r"(/[^\s:'\"]+)", text)
    return m.group(1) if m else None


def _space_short(paths) -> tuple[str, str] | None:
    """(path, cause) when the file system of one of ``paths`` is (nearly) full or the process may only write
    small files (``ulimit -f``): the likely reason of a GDAL error on a file GDAL wrote itself (GDAL does not
    report a write that the disk cut short; reading the file back fails)."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    for p in paths:
        p = Path(p).absolute()
        d = next((q for q in (p, *p.parents) if q.is_dir()), None)
        if d is None:
            continue
        if soft != resource.RLIM_INFINITY:
            return str(p), f"the process may write files of at most {soft} bytes (ulimit -f)"
        try:
            st = os.statvfs(d)
        except OSError:
            continue
        if st.f_bavail * st.f_frsize < 1 << 20:
            return str(p), "no space left on device"
    return None


def fault_message(exc: BaseException, doing: str, writes_to: str | None = None, outputs=()) -> str | None:
    """The one-line message of a file-system fault (disk full, read-only, permission, a vanished file) that
    stopped ``doing`` (the command, or ``aerotri run``'s stage); None when ``exc`` is no such fault.
    ``writes_to``: what the command writes, named when the fault does not say which file it is about;
    ``outputs``: its paths, whose file systems are looked at when GDAL failed on a file of its own."""
    from aerotri.core.atomic import DISK_ERRNOS

    fault = _fault(exc)
    if fault is None:
        short = _space_short(outputs) if (type(exc).__module__.split(".")[0] in _IO_LIBRARIES
                                          or isinstance(exc, OSError)) else None
        if short is None:
            return None
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        return f"{short[0]}: {short[1]}; {doing} stopped and its outputs are as they were ({first})"
    code, path = fault
    if code == SHORT_WRITE:
        return (f"{path or writes_to or 'an output'}: a write was cut short (no space left on the device, or a file "
                f"size limit); {doing} stopped and its outputs are as they were")
    where = path or (writes_to if code not in (errno.ENOENT, errno.ENOTDIR, errno.EISDIR) else None) or "a file"
    if code in (errno.ENOENT, errno.ENOTDIR):
        return (f"{where}: file not found while {doing} ran (an input removed or moved while it ran?); "
                "its outputs are as they were")
    if code == errno.EISDIR:
        return f"{where}: is a folder where {doing} expected a file; its outputs are as they were"
    if code == errno.ENAMETOOLONG:
        # (trial-paths: a legal 247-252 byte name made a traceback: the temporary and lock names add to it)
        return (f"{where}: a file name too long for the file system (its limit is 255 bytes a name; {doing} adds up "
                f"to about 40 for its temporary and lock files beside an output): shorten the name; its outputs are "
                "as they were")
    return f"{where}: {DISK_ERRNOS.get(code, 'cannot write')}; {doing} stopped and its outputs are as they were"


class Group(click.Group):
    """A command group whose commands (and sub-groups) are :class:`Command` s."""

    command_class = Command
    group_class = type


class LazyGroup(Group):
    """A group whose subcommands' modules (and what they import: the LiDAR stages, gtsam, matplotlib, ...) are
    imported when that subcommand runs, or when every command is listed (``--help``, ``commands``), not at
    start-up: ``aerotri adjust`` does not wait for the chain's imports, ``lidarctl contours`` not for the
    classifier's. ``lazy``: name -> "module:attribute" of the click command or group."""

    def __init__(self, *args, lazy: dict[str, str], **kwargs):
        self._lazy = dict(lazy)  # name -> "module:attribute"
        super().__init__(*args, **kwargs)

    @property
    def commands(self) -> dict:
        for name in list(self._lazy):
            self._load(name)
        return self._commands

    @commands.setter
    def commands(self, value: dict) -> None:
        self._commands = value

    def _load(self, name: str) -> None:
        import importlib

        spec = self._lazy.get(name)
        if spec is None:  # loaded meanwhile by another thread
            return
        module, attr = spec.split(":")
        self._commands[name] = getattr(importlib.import_module(module), attr)
        self._lazy.pop(name, None)  # after the command is in: a thread asking meanwhile loads it too, never misses it

    def add_command(self, cmd, name=None) -> None:
        name = name or cmd.name
        self._lazy.pop(name, None)
        self._commands[name] = cmd

    def get_command(self, ctx, cmd_name):
        if cmd_name in self._lazy:
            self._load(cmd_name)
        return self._commands.get(cmd_name)

    def list_commands(self, ctx) -> list[str]:
        return sorted(set(self._commands) | set(self._lazy))


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
