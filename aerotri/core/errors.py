"""The error hierarchy of all three packages (layer 1: imports nothing of ours).

Every error a user can cause or mend derives from :class:`AerotriError`. The command-line handler
(``aerotri.core.commands``) prints it as one line on stderr and exits with code 2, without a traceback
and after the command's atomic writes have left no partial output. Anything else escaping a command
is a bug and keeps its traceback.

- :class:`InputError`: a file, line or record that is not what was expected (the message names it).
  - :class:`OptionError`: an option value out of range or inconsistent (``param`` names the option).
  - :class:`ConfigError`: ``project.toml`` or another configuration file (names the file and key).
  - :class:`CrsError`: an unknown CRS or a coordinate operation that would be wrong (ballpark datum).
  - :class:`ResourceError`: the requested work exceeds what this machine can hold (names the option).
  - :class:`StageOrderError`: a stage's input product does not exist yet (names the stage to run first).
- :class:`SolveError`: the data are valid but the adjustment cannot be solved (singular or divergent);
  not an input error, reported as "Adjustment failed".
"""

from __future__ import annotations


def id_listing(ids, shown: int = 10) -> str:
    """Ids for a one-line message: the first ``shown``, then "and N more" (a one-strip block's 214 unmeasured control
    points made a 2,400-character line)."""
    ids = [str(i) for i in ids]
    return ", ".join(ids[:shown]) + (f" and {len(ids) - shown} more" if len(ids) > shown else "")


class AerotriError(Exception):
    """Base of the errors a command reports as one line and exit code 2."""

    label = "Error"

    def __init__(self, message: str = "", *, param: str | None = None):
        super().__init__(message)
        self.param = param

    def user_message(self) -> str:
        msg = str(self)
        if self.param and self.param not in msg:
            msg = f"{self.param}: {msg}"
        return f"{self.label}: {msg}"


class InputError(AerotriError, ValueError):
    """Bad input: the message names the file, line or record (or the option) and what was expected."""


class OptionError(InputError):
    """An option value out of range or inconsistent with another (``param``: the option, e.g. ``--res-m``)."""


class ConfigError(InputError):
    """A configuration file (``project.toml``, a parameter or tolerance file) with a missing, unknown or bad key."""


class CrsError(InputError):
    """An unknown CRS, or a coordinate operation the toolkit refuses (e.g. PROJ's ballpark datum shift)."""


class ResourceError(InputError):
    """The requested work needs more memory or disk than this machine has (checked before allocating)."""


class StageOrderError(InputError):
    """A stage was run before the stage that makes its input."""


class SolveError(AerotriError):
    """The observations are valid but the adjustment cannot be solved (singular, no datum, divergent)."""

    label = "Adjustment failed"


def interrupt_of(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or SIGTERM, raised as one) behind ``exc``: itself, or one in its chain of causes and contexts
    (numba's compiled functions wrap it in a SystemError "returned a result with an exception set": trial s97 M4, a
    chained traceback and exit 1 for a Ctrl-C); None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
