"""The cores and memory a process may use under cgroup limits (containers, batch jobs): ``aerotri.core.limits``.

The cgroup trees are folders made here with the files the kernel shows (v1, v2, hybrid, a container's own view);
the values are what the kernel documents for them (``cpu.max``, ``cpu.cfs_quota_us`` -1 without a quota,
``memory.limit_in_bytes`` 9223372036854771712 without a limit)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from aerotri.core import limits
from aerotri.core.errors import ResourceError

V1_UNLIMITED = "9223372036854771712"


def _tree(root, files: dict[str, str]):
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text + "\n")
    return root


def test_v2_the_lowest_quota_of_the_cgroup_and_its_ancestors(tmp_path):
    proc = _tree(tmp_path, {"proc/cgroup": "0::/batch.slice/job42"})
    root = _tree(tmp_path / "cg", {"cgroup.controllers": "cpu memory", "cpu.max": "max 100000",
                                   "batch.slice/cpu.max": "400000 100000",
                                   "batch.slice/job42/cpu.max": "150000 100000",
                                   "memory.max": "max", "batch.slice/memory.max": str(2 * 2**30),
                                   "batch.slice/job42/memory.max": "max"})
    assert limits.cgroup_cpu_limit(proc / "proc/cgroup", root) == pytest.approx(1.5)
    assert limits.cgroup_memory_limit(proc / "proc/cgroup", root) == 2 * 2**30  # the parent's limit holds


def test_v2_without_limits_is_none(tmp_path):
    _tree(tmp_path, {"proc/cgroup": "0::/user.slice", "cg/cgroup.controllers": "cpu memory",
                     "cg/user.slice/cpu.max": "max 100000", "cg/user.slice/memory.max": "max"})
    assert limits.cgroup_cpu_limit(tmp_path / "proc/cgroup", tmp_path / "cg") is None
    assert limits.cgroup_memory_limit(tmp_path / "proc/cgroup", tmp_path / "cg") is None


def test_a_container_reads_its_own_cgroup_at_the_root(tmp_path):
    """Docker's private cgroup namespace shows "0::/" and the container's cgroup as /sys/fs/cgroup; without the
    namespace /proc/self/cgroup names the host's path, absent from the container's view: the root is read."""
    root = _tree(tmp_path / "cg", {"cgroup.controllers": "cpu memory", "cpu.max": "200000 100000",
                                   "memory.max": str(8 * 2**30)})
    for line in ("0::/", "0::/system.slice/docker-0123abcd.scope"):
        proc = _tree(tmp_path / "p", {"cgroup": line})
        assert limits.cgroup_cpu_limit(proc / "cgroup", root) == pytest.approx(2.0)
        assert limits.cgroup_memory_limit(proc / "cgroup", root) == 8 * 2**30


def test_v1_cpu_with_cpuacct_and_memory(tmp_path):
    proc = _tree(tmp_path, {"proc/cgroup": "12:memory:/docker/abc\n4:cpu,cpuacct:/docker/abc\n1:name=systemd:/"})
    root = _tree(tmp_path / "cg", {"cpu,cpuacct/cpu.cfs_quota_us": "-1", "cpu,cpuacct/cpu.cfs_period_us": "100000",
                                   "cpu,cpuacct/docker/abc/cpu.cfs_quota_us": "50000",
                                   "cpu,cpuacct/docker/abc/cpu.cfs_period_us": "100000",
                                   "memory/memory.limit_in_bytes": V1_UNLIMITED,
                                   "memory/docker/abc/memory.limit_in_bytes": str(3 * 2**30)})
    assert limits.cgroup_cpu_limit(proc / "proc/cgroup", root) == pytest.approx(0.5)
    assert limits.cgroup_memory_limit(proc / "proc/cgroup", root) == 3 * 2**30


def test_v1_unlimited_and_hybrid_unified(tmp_path):
    """This machine's kind: v1 controllers without limits, an empty unified hierarchy beside them."""
    proc = _tree(tmp_path, {"proc/cgroup": "4:memory:/process_api/b93b\n1:cpu:/\n0::/"})
    root = _tree(tmp_path / "cg", {"cpu/cpu.cfs_quota_us": "-1", "cpu/cpu.cfs_period_us": "100000",
                                   "memory/memory.limit_in_bytes": V1_UNLIMITED,
                                   "memory/process_api/b93b/memory.limit_in_bytes": V1_UNLIMITED,
                                   "unified/cgroup.procs": "1"})
    assert limits.cgroup_cpu_limit(proc / "proc/cgroup", root) is None
    assert limits.cgroup_memory_limit(proc / "proc/cgroup", root) is None
    (root / "unified/cpu.max").write_text("100000 100000\n")  # a quota set in the unified hierarchy counts too
    assert limits.cgroup_cpu_limit(proc / "proc/cgroup", root) == pytest.approx(1.0)


def test_no_cgroup_files_no_limit(tmp_path):
    assert limits.cgroup_cpu_limit(tmp_path / "none", tmp_path / "none") is None
    assert limits.cgroup_memory_limit(tmp_path / "none", tmp_path / "none") is None
    _tree(tmp_path, {"proc/cgroup": "0::/a", "cg/cgroup.controllers": "", "cg/a/cpu.max": "garbage"})
    assert limits.cgroup_cpu_limit(tmp_path / "proc/cgroup", tmp_path / "cg") is None


@pytest.mark.parametrize("quota, expected", [(0.8, 1), (1.0, 1), (1.5, 2), (64.0, None)])
def test_usable_cores_rounds_the_quota_up_and_never_exceeds_the_affinity(monkeypatch, quota, expected):
    affinity = len(os.sched_getaffinity(0))
    monkeypatch.setattr(limits, "_own_cpu_limit", lambda: quota)
    assert limits.usable_cores() == min(affinity, expected or affinity)


def test_a_memory_limit_below_the_machine_s_sets_the_allocation_check(monkeypatch):
    machine = limits.physical_memory_bytes()
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: 2**30)
    assert limits.usable_memory_bytes() == min(machine, 2**30)
    limits.check_allocation(0.5 * 2**30, "half a GiB", held_bytes=0)
    with pytest.raises(ResourceError) as e:
        limits.check_allocation(0.95 * 2**30, "the ortho of frame 7", "--res-m", held_bytes=0)
    assert "the 1.0 GiB this process's cgroup allows" in str(e.value) and "--res-m" in e.value.user_message()
    # what the process holds already counts: half a GiB fits alone, not beside 0.45 GiB held
    with pytest.raises(ResourceError) as e:
        limits.check_allocation(0.5 * 2**30, "half a GiB", held_bytes=0.45 * 2**30)
    assert "besides the 460.8 MiB the process holds already, more than 90% of the 1.0 GiB" in str(e.value)
    # a small grid refused because the process holds most of the memory: its own hint (a coarser grid, strips far
    # apart?) would mislead (trial 90: a 26 MiB grid beside 1.8 GiB held was blamed on "strips far apart")
    with pytest.raises(ResourceError) as e:
        limits.check_allocation(26 * 2**20, "the points' extent: a grid of 775 x 741 cells", "--res-m",
                                hint="are strips far apart?", held_bytes=0.9 * 2**30)
    assert "strips far apart" not in str(e.value)
    assert "it is what the process holds already that leaves too little: give the run more memory" in str(e.value)
    with pytest.raises(ResourceError) as e:  # a large grid keeps its hint
        limits.check_allocation(0.8 * 2**30, "a grid", "--res-m", hint="are strips far apart?", held_bytes=0.2 * 2**30)
    assert "are strips far apart?" in str(e.value)
    assert limits.cache_bytes(256 * 2**20) == 128 * 2**20              # an eighth of the limit
    monkeypatch.setattr(limits, "_own_memory_limit", lambda: None)
    assert limits.usable_memory_bytes() == machine


def test_library_pools_told_the_quota_s_cores_unless_the_user_set_them(monkeypatch):
    monkeypatch.setattr(limits, "_own_cpu_limit", lambda: 0.5)
    env = {"OMP_NUM_THREADS": "3"}
    limits.limit_library_threads(env)
    assert env == {"OMP_NUM_THREADS": "3", "NUMBA_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    monkeypatch.setattr(limits, "_own_cpu_limit", lambda: None)
    env = {}
    limits.limit_library_threads(env)
    assert env == {}


def test_resident_bytes_counts_what_the_process_holds_and_not_its_files(tmp_path):
    """The memory a limit cannot take back: an array written into is counted, a file mapped and read is not (the
    kernel drops its pages under the limit). In a process of its own: in a test worker the heap may hold freed
    memory of earlier tests (an in-process ``lidarctl rasters`` keeps it, ``_freed_memory_kept``), from which the
    array's pages came already resident (a whole suite read 0 bytes held)."""
    code = textwrap.dedent(f"""
        import numpy as np
        from aerotri.core.limits import resident_bytes
        before = resident_bytes()
        a = np.ones(64 * 2**20 // 8)                     # 64 MiB written
        print(resident_bytes() - before)
        a.tofile({str(tmp_path / "f.bin")!r})
        del a
        before = resident_bytes()
        m = np.memmap({str(tmp_path / "f.bin")!r}, dtype=np.float64, mode="r")
        assert float(m.sum()) == 64 * 2**20 // 8         # every page of the file read
        print(resident_bytes() - before)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    held, mapped = (int(v) for v in run.stdout.split()[-2:])
    assert 60 * 2**20 < held < 72 * 2**20, held
    assert mapped < 8 * 2**20, mapped


@pytest.mark.parametrize("keep, kept", [(True, True), (False, False)])
def test_freed_memory_kept_or_given_back(keep, kept):
    """``lidarctl rasters``' allocator setting: with ``keep`` (memory ample) a freed 50 MB array stays in the process
    for the next tile; without (memory short) it is given back at once."""
    code = textwrap.dedent(f"""
        import numpy as np
        from aerotri.core.limits import resident_bytes
        from lidarctl.rasters.products import _freed_memory_kept
        with _freed_memory_kept({keep}):
            before = resident_bytes()
            a = np.ones(50_000_000 // 8)
            del a
            print(resident_bytes() - before)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    held = int(run.stdout.split()[-1])
    assert (held > 45_000_000) == kept, held
