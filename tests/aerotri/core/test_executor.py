"""Scale-out: the same tasks on local threads, one at a time, or a local Dask cluster of 2 worker
processes give identical outputs."""

from __future__ import annotations

import json
import shutil
import threading
import time

import pytest

from aerotri.core.executor import Executor, activate, executor_for, local_executor


def _square(x):
    return x * x


def _boxed(x):
    return [x]


def _fail_on_three(x):
    if x == 3:
        raise ValueError("task 3 failed")
    return x


def _fail_from_three(x):
    import time

    time.sleep(0.01 * (10 - x))  # later items finish first
    if x >= 3:
        raise ValueError(f"task {x} failed")
    return x


@pytest.fixture(scope="module")
def cluster():
    with Executor("local:2") as ex:
        yield ex


@pytest.mark.parametrize("scheduler", [None, "synchronous", "cluster"])
def test_results_come_back_in_item_order_and_errors_surface(scheduler, cluster):
    ex = cluster if scheduler == "cluster" else Executor(scheduler)
    assert ex.map(_square, range(20)) == [x * x for x in range(20)]
    assert ex.map(_square, []) == []
    with pytest.raises(ValueError, match="task 3 failed"):
        ex.map(_fail_on_three, range(8))
    # Several failures: always the first failing item in item order, whoever finished first.
    for _ in range(3):
        with pytest.raises(ValueError, match="task 3 failed"):
            ex.map(_fail_from_three, range(10))


@pytest.mark.parametrize("scheduler", [None, "synchronous", "cluster"])
def test_each_result_is_handed_over_in_this_thread_as_its_item_finishes(scheduler, cluster):
    """``on_result(k, result)``: once per item that succeeded, in the calling thread, with the item's index; not for
    a failed item nor for those a failure left unstarted; one item alone (run without dask) as well."""
    import threading

    ex = cluster if scheduler == "cluster" else Executor(scheduler)
    got, here = [], threading.get_ident()

    def take(k, result):
        got.append((k, result, threading.get_ident() == here))

    assert ex.map(_square, range(12), on_result=take) == [x * x for x in range(12)]
    assert sorted(got) == [(k, k * k, True) for k in range(12)]
    # the results returned are the objects handed over (what on_result changes in them stays changed)
    handed = {}
    out = ex.map(_boxed, range(6), on_result=lambda k, r: handed.setdefault(k, r).append("seen"))
    assert all(out[k] is handed[k] for k in range(6)) and out == [[k, "seen"] for k in range(6)]
    got.clear()
    with pytest.raises(ValueError, match="task 3 failed"):
        ex.map(_fail_on_three, range(8), on_result=take)
    assert {k for k, _, _ in got} <= {0, 1, 2, 4, 5, 6, 7} and all(r == k for k, r, _ in got)
    assert all(same for _, _, same in got)
    got.clear()
    assert ex.map(_square, [5], on_result=take) == [25] and got == [(0, 25, True)]


def test_the_run_executor_is_used_by_commands_without_their_own(cluster):
    assert local_executor() is not cluster
    with activate(cluster):
        assert local_executor() is cluster
        with executor_for(None, None) as ex:
            assert ex is cluster
        with executor_for("synchronous", None) as ex:
            assert ex is not cluster
    assert local_executor() is not cluster


def test_bad_scheduler_is_a_clear_error():
    from aerotri.core.errors import InputError

    with pytest.raises(InputError, match="local:N"):
        Executor("local:two")


def test_matching_on_a_two_worker_cluster_equals_the_default_run(tiny_project, tmp_path, cluster):
    from aerotri.match import match_project

    outputs = {}
    for name, ex in (("threads", Executor()), ("cluster", cluster)):
        root = tmp_path / name
        shutil.copytree(tiny_project, root, ignore=shutil.ignore_patterns("truth", "lidar"))
        rep = match_project(root, executor=ex)
        assert rep.feature_cache_hits == 0 and rep.match_cache_hits == 0
        conn = json.loads((root / "at" / "connectivity.json").read_text())
        conn.pop("seconds"), conn.pop("phase_seconds")  # times differ; every result must not
        outputs[name] = ((root / "at" / "tiepoints.csv").read_bytes(), conn)
    assert outputs["threads"][0] == outputs["cluster"][0]
    assert outputs["threads"][1] == outputs["cluster"][1]
    assert outputs["threads"][0].count(b"\n") > 1000


@pytest.mark.parametrize("scheduler, workers, expect", [("local:0", None, "--scheduler"), ("local:-3", None, "--scheduler"),
                                                       ("local:100000", None, "--scheduler"), (None, 100000, "--workers")])
def test_worker_counts_that_would_hang_or_swamp_are_refused(scheduler, workers, expect):
    """local:0 would start a cluster with no worker and wait for one forever; 100000 workers would swamp the
    machine: refused at once, naming the option."""
    import time

    from aerotri.core.errors import OptionError

    t0 = time.monotonic()
    with pytest.raises(OptionError) as e:
        Executor(scheduler, workers)
    assert time.monotonic() - t0 < 5 and e.value.param == expect


def test_scheduler_local_zero_on_the_command_line_exits_2(tmp_path):
    from click.testing import CliRunner

    from lidarctl.cli.main import main

    r = CliRunner().invoke(main, ["classify", str(tmp_path / "in.las"), str(tmp_path / "out.las"), "--scheduler",
                                  "local:0"])
    assert r.exit_code == 2 and "--scheduler" in r.stderr and "Traceback" not in r.stderr


def test_task_counts_are_bounded():
    from aerotri.core.errors import ResourceError
    from aerotri.core.limits import MAX_TASKS, check_task_count

    check_task_count(MAX_TASKS, "a grid", "--tile-px")
    with pytest.raises(ResourceError, match="--tile-px"):
        check_task_count(MAX_TASKS + 1, "a grid", "--tile-px", "use a larger --tile-px")


_STARTED = []  # items whose task began (the fault injection below)
_INTERRUPT_SENT = None  # threading.Event: set once the fault injection has sent its SIGINT


def _slow_write(item) -> int:
    """A task that runs until the interrupt has been sent, 0.3 s more, and then writes its cache file (as features
    or frame orthos do): it is still running when the Ctrl-C arrives, however loaded the machine."""
    import time

    from aerotri.core.atomic import write_text_atomic

    folder, k = item
    _STARTED.append(k)
    _INTERRUPT_SENT.wait(30.0)
    time.sleep(0.3)
    write_text_atomic(folder / f"{k}.txt", "done\n")
    return k


def test_ctrl_c_waits_for_the_running_tasks_before_the_stage_rolls_back(tmp_path):
    """Ctrl-C (SIGINT to the main thread) while two tasks run on the pool's threads: the map stops starting tasks and
    returns (raises) only when the running ones have ended, so their files fall inside the stage's commit and are
    rolled back with it; before, they were written 0.5 s after the roll-back, outside any commit."""
    import signal
    import threading
    import time

    from aerotri.core.atomic import commit_outputs

    global _INTERRUPT_SENT
    out = tmp_path / "out"
    out.mkdir()
    _STARTED.clear()
    _INTERRUPT_SENT = threading.Event()
    main = threading.get_ident()

    def interrupt():
        while len(_STARTED) < 2:
            time.sleep(0.01)
        time.sleep(0.1)
        signal.pthread_kill(main, signal.SIGINT)
        _INTERRUPT_SENT.set()

    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C as in a terminal, whatever the runner
    try:
        with Executor(workers=2) as ex:
            threading.Thread(target=interrupt, daemon=True).start()
            with pytest.raises(KeyboardInterrupt), commit_outputs(out):
                ex.map(_slow_write, [(out, k) for k in range(8)])
            time.sleep(1.0)  # a task still running would write now, after the roll-back
    finally:
        signal.signal(signal.SIGINT, before)
    assert len(_STARTED) == 2, f"no task starts after the interrupt: {_STARTED}"
    assert list(out.iterdir()) == [], "nothing written after the roll-back"


def test_threads_follow_the_cores_the_process_may_run_on():
    """A process pinned to one core (``taskset -c 0``, a batch scheduler's cpuset) runs one thread per pool: its
    executor, the rectify tiles and numba's kernels; the machine's other cores are not its own."""
    import os
    import subprocess
    import sys

    code = ("import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
            "import numba; from aerotri.core.executor import Executor; from aerotri.core.limits import usable_cores; "
            "from ortho.rectify import default_threads; "
            "print(usable_cores(), Executor().workers, Executor().cores_per_task(4), default_threads(), "
            "numba.config.NUMBA_NUM_THREADS)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["1"] * 5
    from aerotri.core.limits import usable_cores

    assert usable_cores() == len(os.sched_getaffinity(0))


_RUNNING = [0, 0]  # tasks running now, the most at once
_RUNNING_LOCK = threading.Lock()


def _count_running(k: int) -> int:
    """A task that notes how many tasks run beside it (module level: the executor runs plain functions)."""
    with _RUNNING_LOCK:
        _RUNNING[0] += 1
        _RUNNING[1] = max(_RUNNING[1], _RUNNING[0])
    time.sleep(0.05)
    with _RUNNING_LOCK:
        _RUNNING[0] -= 1
    return k


@pytest.mark.parametrize("at_once, expect", [(None, 3), (2, 2), (1, 1), (0, 1)])
def test_at_once_bounds_the_tasks_running_together(at_once, expect):
    """``map(..., at_once=k)``: at most k of the executor's 3 threads run tasks at the same time (tasks whose memory
    would not fit side by side), results in item order; the cores each task may use follow the tasks running."""
    _RUNNING[:] = [0, 0]
    with Executor(workers=3) as ex:
        assert ex.map(_count_running, range(9), at_once=at_once) == list(range(9))
        per_task = ex.cores_per_task(9, at_once)
    assert _RUNNING[1] == expect
    from aerotri.core.limits import usable_cores

    assert per_task == max(1, usable_cores() // expect)
