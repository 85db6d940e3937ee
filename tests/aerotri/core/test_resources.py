"""measure(): CPU seconds of the work (not of the process before it), peak RSS of the work alone, children."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from aerotri.core.resources import measure

MB = 1024 * 1024


def _busy(cpu_s: float) -> None:
    t = time.process_time()
    x = 0
    while time.process_time() - t < cpu_s:
        x += 1


def _rss_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS in /proc/self/status")


def test_cpu_seconds_are_the_work_alone():
    # In a fresh interpreter: measure() counts every thread of the process and its live descendants, and an xdist
    # worker may be running a background build of its own meanwhile (1.15 CPU-s measured once for this 0.4)
    busy = "t = time.process_time()\nwhile time.process_time() - t < {}: pass\n"
    code = ("import json, time\nfrom aerotri.core.resources import measure\n" + busy.format(0.3)  # before: not counted
            + "with measure() as u:\n" + "".join("    " + line + "\n" for line in busy.format(0.4).splitlines())
            + "    time.sleep(0.2)\n"  # wall time, no CPU
            + "print(json.dumps([u.cpu_s, u.wall_s]))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    cpu_s, wall_s = json.loads(out.splitlines()[-1])
    assert 0.35 <= cpu_s < 0.6
    assert wall_s >= cpu_s + 0.15


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="high-water marks and resident sets need /proc")
def test_peak_rss_is_the_work_s_and_the_process_s_mark_is_kept():
    big = np.ones(600 * MB // 8)  # a peak before the work ...
    del big
    rss0 = _rss_mb()  # what the process holds anyway (in a full test session, much more than the interpreter)
    with measure() as u:
        small = np.ones(150 * MB // 8)
        time.sleep(0.1)
        del small
    assert u.rss_reset
    # ... is not the work's: the work's peak is what the process held plus its 150 MB, not the 600 MB
    assert 145 <= u.peak_rss_mb - rss0 < 450
    assert u.record()["peak_rss_mb"] == round(u.peak_rss_mb, 1)
    # and the process's own mark still holds the 600 MB: what /usr/bin/time -v and a batch system report for the job
    # (main reset it before every stage, so a chain's job showed its last stage's peak)
    with open("/proc/self/status") as fh:
        hwm = next(int(line.split()[1]) / 1024.0 for line in fh if line.startswith("VmHWM:"))
    assert hwm >= rss0 + 590


def test_a_peak_above_every_earlier_one_is_the_high_water_mark_however_short():
    rss0 = _rss_mb()
    with open("/proc/self/status") as fh:
        hwm0 = next(int(line.split()[1]) / 1024.0 for line in fh if line.startswith("VmHWM:"))
    with measure() as u:
        np.ones(int((hwm0 - rss0 + 300) * MB) // 8).sum()  # above the process's mark, freed at once
    assert u.peak_rss_mb >= hwm0 + 290


def test_a_child_process_counts_in_cpu_and_memory():
    # In a fresh interpreter: the reaped children's peak (getrusage) is the largest child the process
    # ever had, so in a test session an earlier, bigger child would hide this one.
    # (the child is seen alive: it holds its 250 MB for 0.5 CPU-s, longer than the sampling interval)
    child = "import numpy as np, time\na = np.ones(250 * 1024 * 1024 // 8)\nt = time.process_time()\n" \
            "while time.process_time() - t < 0.5: pass"
    code = ("import json, subprocess, sys\nfrom aerotri.core.resources import measure\n"
            "with measure() as u:\n"
            f"    subprocess.run([sys.executable, '-c', {child!r}], check=True)\n"
            "print(json.dumps([u.cpu_s, u.peak_rss_mb, u.workers_peak_rss_mb, u.total_peak_rss_mb]))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    cpu_s, peak_mb, workers_mb, total_mb = json.loads(out.splitlines()[-1])
    assert cpu_s >= 0.5
    if sys.platform.startswith("linux"):
        assert workers_mb >= 250
        assert total_mb == peak_mb + workers_mb


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the high-water marks need Linux /proc")
def test_a_short_helper_process_does_not_count_as_the_parents_memory_again():
    # RUSAGE_CHILDREN's ru_maxrss of a child that forks (or vforks) and execs is this process's peak at the fork
    # (Linux keeps the old address space's mark at exec): counted as a "worker", a stage holding 1 GB that ran
    # `true` reported 2 GB (workers 1,0xx MB before the fix). In a fresh interpreter, as above.
    code = ("import json, subprocess, numpy as np\nfrom aerotri.core.resources import measure\n"
            "with measure() as u:\n"
            "    a = np.ones(1024 * 1024 * 1024 // 8)\n"
            "    subprocess.run(['true'], check=True)\n"
            "    del a\n"
            "print(json.dumps([u.peak_rss_mb, u.workers_peak_rss_mb, u.total_peak_rss_mb]))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    peak_mb, workers_mb, total_mb = json.loads(out.splitlines()[-1])
    assert peak_mb >= 1024
    assert workers_mb < 50, workers_mb  # `true` holds a few hundred KiB, and lives less than a sampling interval
    assert total_mb < 1.1 * peak_mb


def _worker(tmp_path, cpu_s: float, mb: int) -> tuple[subprocess.Popen, object]:
    """A process alive before and after the work (as a Dask worker is), which burns ``cpu_s`` and holds
    ``mb`` MiB only once ``go`` exists, then writes ``done`` and stays alive."""
    go, done, ready = tmp_path / "go", tmp_path / "done", tmp_path / "ready"
    code = ("import numpy as np, os, time, sys\n"
            f"go, done = {str(go)!r}, {str(done)!r}\n"
            f"open({str(ready)!r}, 'w').close()\n"
            "while not os.path.exists(go): time.sleep(0.01)\n"
            f"a = np.ones({mb} * 1024 * 1024 // 8)\n"
            "t = time.process_time()\n"
            f"while time.process_time() - t < {cpu_s}: pass\n"
            "del a\n"
            "open(done, 'w').close()\n"
            "time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", code])
    # started (its interpreter's and NumPy's start-up CPU spent) before the work: on a loaded machine a fixed
    # half second was not enough and the start-up counted as work (CI: 1.11 CPU-s for 0.4)
    deadline = time.monotonic() + 60
    while not ready.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.1)
    return proc, (go, done)


def test_a_live_worker_counts_with_what_it_did_during_the_work(tmp_path):
    proc, (go, done) = _worker(tmp_path, 0.4, 200)
    try:
        deadline = time.monotonic() + 60
        with measure() as u:
            go.touch()
            while not done.exists() and time.monotonic() < deadline:
                time.sleep(0.02)
        assert done.exists()
    finally:
        proc.kill()
        proc.wait()
    # its CPU during the work (not its start-up before), its peak since the reset (the 200 MB, gone again)
    assert 0.35 <= u.cpu_s < 1.0
    if sys.platform.startswith("linux"):
        assert 200 <= u.workers_peak_rss_mb < 400


def test_without_psutil_or_proc_the_lifetime_peak_stands_in(monkeypatch):
    from aerotri.core import resources

    monkeypatch.setattr(resources, "psutil", None)
    monkeypatch.setattr(resources, "_status_mb", lambda pid="self", field="VmHWM": None)
    monkeypatch.setattr(resources, "_hwm_mb", lambda pid="self": None)
    with measure() as u:
        _busy(0.2)
    assert u.cpu_s >= 0.15
    assert not u.rss_reset
    if resources.resource is not None:  # the process's peak since it started: at least its interpreter
        assert u.peak_rss_mb > 10
        assert u.record()["rss_reset"] is False


def test_without_any_memory_source_only_times_are_recorded(monkeypatch):
    from aerotri.core import resources

    monkeypatch.setattr(resources, "psutil", None)
    monkeypatch.setattr(resources, "resource", None)
    monkeypatch.setattr(resources, "_status_mb", lambda pid="self", field="VmHWM": None)
    monkeypatch.setattr(resources, "_hwm_mb", lambda pid="self": None)
    with measure() as u:
        _busy(0.2)
    assert u.peak_rss_mb is None and u.total_peak_rss_mb is None
    assert set(u.record()) == {"wall_s", "cpu_s"} and u.record()["cpu_s"] >= 0.15
