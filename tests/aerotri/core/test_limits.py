"""The cores and memory a process may use under cgroup limits (containers, batch jobs): ``aerotri.core.limits``.

The cgroup trees are folders made here with the files the kernel shows (v1, v2, hybrid, a container's own view);
the values are what the kernel documents for them (``cpu.max``, ``cpu.cfs_quota_us`` -1 without a quota,
``memory.limit_in_bytes`` 9223372036854771712 without a limit)."""

from __future__ import annotations

import os

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
    limits.check_allocation(0.5 * 2**30, "half a GiB")
    with pytest.raises(ResourceError) as e:
        limits.check_allocation(0.9 * 2**30, "the ortho of frame 7", "--res-m")
    assert "the 1.0 GiB this process's cgroup allows" in str(e.value) and "--res-m" in e.value.user_message()
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
