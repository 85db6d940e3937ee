"""Errors shared by all three packages.

``InputError`` is raised for bad user input (a file, line or record that is not what was expected).
The CLIs turn it into a one-line message on stderr and exit code 2, and write no output.
"""

from __future__ import annotations

import functools
import sys

import click


class InputError(ValueError):
    """Bad input: the message names the file, line or record and what was expected."""


def exit_on_input_error(func):
    """Decorate a click command so that ``InputError`` becomes ``Error: ...`` and exit code 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except InputError as exc:
            click.echo(f"Error: {exc}", err=True)
            sys.exit(2)

    return wrapper
