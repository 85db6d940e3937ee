"""One writer per project (aerotri.core.lock): a second command stops naming the first, or waits with --wait; a
lock left by a killed command is taken over (the kernel released its flock) and said to be stale; two real
`aerotri` processes on one project: the second refuses or waits, and the products are valid."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from aerotri.core.lock import LOCK_NAME, BusyError, hold_lock

REPO = Path(__file__).resolve().parents[3]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))

class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.records = []

    def emit(self, record):
        self.records.append(record)


@pytest.fixture
def caplog():
    """The lock's log records (the CLI's logging set-up keeps aerotri's records from pytest's own caplog)."""
    h = _Records()
    lg = logging.getLogger("aerotri.core.lock")
    lg.addHandler(h)
    old = lg.level
    lg.setLevel(logging.DEBUG)
    try:
        yield h
    finally:
        lg.removeHandler(h)
        lg.setLevel(old)


HOLDER = textwrap.dedent("""
    import sys, time
    from aerotri.core.lock import hold_lock
    with hold_lock(sys.argv[1], "holder test", 0.0, "project"):
        print("held", flush=True)
        time.sleep(float(sys.argv[2]))
""")


def _holder(lock: Path, seconds: float) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(lock), str(seconds)], stdout=subprocess.PIPE, text=True,
                         env=ENV)
    assert p.stdout.readline().strip() == "held"
    return p


def test_second_holder_refuses_naming_the_first_then_waits(tmp_path):
    lock = tmp_path / LOCK_NAME
    p = _holder(lock, 60)
    try:
        record = json.loads(lock.read_text())
        assert record["pid"] == p.pid and record["command"] == "holder test"
        with pytest.raises(BusyError) as e:
            with hold_lock(lock, "second", 0.0, "project P"):
                pass
        msg = str(e.value)
        assert f"pid {p.pid}" in msg and "holder test" in msg and "--wait" in msg
        t0 = time.monotonic()
        with pytest.raises(BusyError):
            with hold_lock(lock, "second", 0.6, "project P"):
                pass
        assert 0.5 < time.monotonic() - t0 < 10
    finally:
        p.kill()
        p.wait()


def test_waiting_holder_gets_the_lock_when_the_first_ends(tmp_path, caplog):
    lock = tmp_path / LOCK_NAME
    p = _holder(lock, 1.5)
    t0 = time.monotonic()
    with hold_lock(lock, "second", 60.0, "project P") as stale:
        waited = time.monotonic() - t0
        assert json.loads(lock.read_text())["command"] == "second"
    p.wait()
    assert stale is None and waited > 0.5
    assert any("waiting up to 60 s" in r.getMessage() for r in caplog.records)
    assert not lock.exists()  # removed when released


def test_lock_of_a_killed_holder_is_stale_and_taken_over(tmp_path, caplog):
    lock = tmp_path / LOCK_NAME
    p = _holder(lock, 60)
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert lock.exists()  # the file stays; the kernel released the flock
    with hold_lock(lock, "next", 0.0, "project P") as stale:
        assert stale is not None and stale.pid == p.pid and stale.command == "holder test"
    assert any("stale lock" in r.getMessage() and str(p.pid) in r.getMessage() for r in caplog.records)
    assert not lock.exists()


def test_the_same_process_takes_its_own_lock_again(tmp_path):
    lock = tmp_path / LOCK_NAME
    with hold_lock(lock, "outer"):
        with hold_lock(lock, "inner"):
            assert json.loads(lock.read_text())["command"] == "outer"
        assert lock.exists()
    assert not lock.exists()


# -- two real commands on one project --------------------------------------------------------------

# the window between creating the lock file and locking it (``hold_lock``: os.open, then flock), held open: under
# load it was long enough for a second command started on the file's appearance to take the lock first
SLOW_FLOCK = ("import fcntl, time; _flock = fcntl.flock; "
              "fcntl.flock = lambda fd, op, _f=_flock: (time.sleep({s}), _f(fd, op))[1]; ")


def _aerotri(*args, flock_delay_s: float = 0.0) -> subprocess.Popen:
    code = (SLOW_FLOCK.format(s=flock_delay_s) if flock_delay_s else "") + \
        "import sys; sys.argv[0] = 'aerotri'; from aerotri.cli import main; sys.exit(main())"
    return subprocess.Popen([sys.executable, "-c", code, *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)


def _wait_for(path: Path, proc: subprocess.Popen, timeout_s: float = 120) -> None:
    t0 = time.monotonic()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout_s, f"{path} never appeared"
        time.sleep(0.02)


def _wait_for_holder(lock: Path, proc: subprocess.Popen, timeout_s: float = 120) -> None:
    """Until ``proc`` holds ``lock``: its record (pid) in the file, written just after its flock. The file's
    appearance is not enough: ``hold_lock`` creates it, then locks it, and a command started in between took the
    lock first (the first, without --wait, then refused: "... is writing it; give --wait")."""
    t0 = time.monotonic()
    while True:
        try:
            record = json.loads(lock.read_text())
        except (OSError, ValueError):
            record = {}
        if record.get("pid") == proc.pid:
            return
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout_s, f"{lock} never held by pid {proc.pid}"
        time.sleep(0.02)


@pytest.fixture
def project(tiny_project, tmp_path) -> Path:
    p = tmp_path / "p"
    p.mkdir()
    shutil.copytree(tiny_project / "images", p / "images")
    for name in ("camera.toml", "project.toml", "gnss.txt"):
        shutil.copy(tiny_project / name, p / name)
    return p


def _valid_tiepoints(p: Path) -> int:
    from aerotri.geom.observations import read_image_points

    return len(read_image_points(p / "at" / "tiepoints.csv").point_id)


def test_two_concurrent_commands_second_refuses_first_completes(project):
    from aerotri.cli import main

    first = _aerotri("match", project)
    _wait_for_holder(project / LOCK_NAME, first)
    r = CliRunner().invoke(main, ["match", str(project)])
    out, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert r.exit_code == 2 and "Traceback" not in r.stderr
    line = [s for s in r.stderr.splitlines() if s.startswith("Error:")][0]
    assert f"pid {first.pid}" in line and "match" in line and "--wait" in line
    assert _valid_tiepoints(project) > 100
    assert not (project / LOCK_NAME).exists()
    assert not [q for q in project.rglob(".*") if ".part-" in q.name or ".commit-" in q.name]


def test_two_concurrent_commands_second_waits_with_wait(project):
    from aerotri.cli import main

    first = _aerotri("match", project, flock_delay_s=0.5)
    _wait_for_holder(project / LOCK_NAME, first)
    r = CliRunner().invoke(main, ["match", str(project), "--wait", "600"])
    out, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert r.exit_code == 0, r.output
    assert "waiting up to 600 s" in r.stderr and f"pid {first.pid}" in r.stderr
    assert _valid_tiepoints(project) > 100


def test_killed_command_leaves_a_stale_lock_the_next_one_takes(project):
    from aerotri.cli import main

    first = _aerotri("match", project)
    _wait_for_holder(project / LOCK_NAME, first)
    _wait_for(project / "work", first)  # well into its work
    first.send_signal(signal.SIGKILL)
    first.wait()
    assert (project / LOCK_NAME).exists()
    r = CliRunner().invoke(main, ["match", str(project)])
    assert r.exit_code == 0, r.output
    assert "stale lock" in r.stderr and f"pid {first.pid}" in r.stderr
    assert _valid_tiepoints(project) > 100
    assert not (project / LOCK_NAME).exists()
    assert not [q for q in project.rglob(".*") if ".part-" in q.name or ".commit-" in q.name]
