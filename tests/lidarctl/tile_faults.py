"""Fault injection for the tests of the commands that resume per tile (``lidarctl classify``, ``lidarctl rasters``,
the chain's classify stage): a tile function that stops at a known tile, in process or by SIGKILL of a child."""

from __future__ import annotations

import subprocess
import sys

from aerotri.core.errors import InputError


class Tiles:
    """``function`` (a tile task) counting the tiles it computes; raises ``exc`` at the ``at``-th."""

    def __init__(self, function, at=None, exc=KeyboardInterrupt):
        self.function, self.at, self.exc, self.done = function, at, exc, 0

    def __call__(self, *args, **kwargs):
        if self.done + 1 == self.at:
            raise self.exc("broken on purpose") if self.exc is InputError else self.exc
        self.done += 1
        return self.function(*args, **kwargs)


KILLED = """
import os, signal, sys
from click.testing import CliRunner
import {module} as module
from lidarctl.cli.main import main
compute, done = module.{name}, []

def killed(*args, **kwargs):  # SIGKILL as the {at}th tile starts
    if len(done) == {at} - 1:
        os.kill(os.getpid(), signal.SIGKILL)
    done.append(1)
    return compute(*args, **kwargs)

module.{name} = killed
{setup}
CliRunner().invoke(main, sys.argv[1:])
"""


def killed_at(module: str, name: str, at: int, argv, setup: str = "") -> int:
    """``lidarctl ARGV`` in a child process whose tile function ``module.name`` kills it (SIGKILL) as the ``at``-th
    tile starts (``setup``: more lines run before the command); the child's exit code."""
    code = KILLED.format(module=module, name=name, at=at, setup=setup)
    return subprocess.run([sys.executable, "-c", code, *map(str, argv)], timeout=300).returncode


def check_started_over(r, count: Tiles, n: int, keep, tree: dict, want: dict) -> None:
    """A run with ``--no-resume`` (result ``r``) removed the kept tiles in ``keep``, computed all ``n`` tiles, wrote
    the bytes ``want`` (``tree``: what it wrote) and left no resume folder."""
    assert r.exit_code == 0, r.output
    assert f"{keep}: what an interrupted run kept there removed (--no-resume)" in r.stderr
    assert "resumed" not in r.stderr and count.done == n
    assert tree == want and not keep.exists()
