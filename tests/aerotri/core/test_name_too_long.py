"""A name too long for the file system is one line, exit 2 (trial-paths: a legal 247-252 byte name made an OSError
traceback, exit 1: the temporary and lock names added to it)."""

from __future__ import annotations

import errno

from click.testing import CliRunner

from aerotri.cli import main
from aerotri.core.commands import fault_message


def test_the_fault_names_the_file_and_the_limit():
    exc = OSError(errno.ENAMETOOLONG, "File name too long", "/data/x")
    msg = fault_message(exc, "aerotri sim")
    assert msg.startswith("/data/x: a file name too long for the file system") and "shorten the name" in msg


def test_a_sim_into_a_252_byte_name_stops_in_one_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["sim", "--preset", "tiny", "--observations-only", "测区" * 42])
    assert r.exit_code == 2 and "a file name too long" in r.output and "Traceback" not in r.output
