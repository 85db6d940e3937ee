"""Task execution for the scale-out stages (LiDAR tiles, features per frame, matches per pair,
ortho per frame and per mosaic tile).

Every stage hands its independent pieces of work to an :class:`Executor` as ``executor.map(fn, items)``
and gets the results back in the order of ``items``, so the outputs do not depend on which worker ran
which task or when it finished. ``fn`` must be a module-level function (it is pickled for a cluster)
and its items small (paths, ids, parameter objects): tasks read their inputs from and write their
outputs to the project folder, which every worker must see (a shared file system on a cluster).

Schedulers:
- ``None`` (default): Dask's local threaded scheduler in this process, ``workers`` threads
  (default: the cores this process may run on). NumPy, numba, OpenCV and GDAL release the GIL in the hot loops.
  A single task runs in the calling thread, without importing Dask (same result, same errors).
- ``"synchronous"``: one task after the other in this thread (debugging, profiling).
- ``"local:N"``: a Dask distributed cluster of N single-threaded worker processes on this machine.
- ``"tcp://host:8786"`` (any other string): the Dask distributed scheduler at that address.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any, Callable, Iterable

from aerotri.core.errors import OptionError
from aerotri.core.limits import usable_cores
from aerotri.core.log import progress

_log = logging.getLogger(__name__)


class _Failed:
    def __init__(self, exc: BaseException):
        self.exc = exc


_SKIPPED = object()


def _wait_for_running(cond, stopping: list, running: list) -> None:
    """After an interrupt of ``Executor.map``: no more tasks start; wait until the running ones have ended (a
    second Ctrl-C stops the wait)."""
    with cond:
        stopping[0] = True
        if running[0]:
            _log.warning(
                f"interrupted: waiting for the {running[0]} running task(s) to end before the outputs are rolled back "
                "(Ctrl-C again: stop at once)")
        while running[0]:
            cond.wait(0.2)


@contextlib.contextmanager
def _cancelled_when_interrupted(client, futures):
    """On a cluster: an interrupt cancels the tasks not yet run (a worker's running task cannot be stopped from
    here; it ends on its own)."""
    try:
        yield
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(futures)
        raise


def check_scheduler(scheduler: str | None) -> None:
    """OptionError when ``scheduler`` is not written as ``--scheduler`` takes it (synchronous, threads, local:N, a Dask
    scheduler's address): told before any work (``aerotri run`` checks it before the frames), not whether it answers."""
    import re

    from aerotri.core.limits import check_workers

    if scheduler is None or scheduler in ("threads", "synchronous"):
        return
    if scheduler.startswith("local:"):
        try:
            n = int(scheduler.split(":", 1)[1])
        except ValueError:
            raise OptionError(f"--scheduler {scheduler}: expected local:N with N the number of workers", param="--scheduler") from None
        # local:0 would start a cluster without workers and wait for them forever
        check_workers(n, True, "--scheduler")
    elif not re.fullmatch(r"[a-z]+://[^\s/]+:\d+", str(scheduler)):
        raise OptionError(f"--scheduler {scheduler}: expected synchronous, local:N or the address of a Dask "
                          "scheduler such as tcp://host:8786", param="--scheduler")


class Executor:
    """Runs independent tasks locally or on a Dask distributed cluster; use as a context manager."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None):
        from aerotri.core.limits import check_workers

        self.scheduler = scheduler
        if workers is not None:
            check_workers(int(workers), False, "--workers")
        self.workers = workers or usable_cores()
        self._client = None
        self._cluster = None
        if scheduler is None or scheduler in ("threads", "synchronous"):
            return
        try:
            from distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - dask[distributed] is a core dependency
            raise OptionError(f"--scheduler {scheduler}: dask.distributed is not installed ({e})", param="--scheduler") from e
        check_scheduler(scheduler)
        if scheduler.startswith("local:"):
            n = int(scheduler.split(":", 1)[1])
            self._cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                         dashboard_address=None, silence_logs=50)
            self._client = Client(self._cluster)
            self.workers = n
        else:
            try:
                self._client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError, ValueError) as e:
                raise OptionError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({e})", param="--scheduler") from e
            self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                      self._client.scheduler_info()["workers"].values()))

    @property
    def distributed(self) -> bool:
        return self._client is not None

    def cores_per_task(self, n_tasks: int, at_once: int | None = None) -> int | None:
        """Cores for each of ``n_tasks`` tasks (at most ``at_once`` of them running together, see :meth:`map`) so
        that the tasks running at once on this machine share its cores; None on a remote cluster (the worker
        machines' own cores are unknown here)."""
        if self.distributed and not str(self.scheduler).startswith("local:"):
            return None
        running = min(self.workers, n_tasks) if self.distributed or at_once is None else \
            min(self.workers, n_tasks, max(1, at_once))
        return max(1, usable_cores() // max(1, running))

    def describe(self) -> str:
        if self._client is not None:
            if str(self.scheduler).startswith("local:"):  # LocalCluster: processes of one thread each
                return f"dask distributed ({self.scheduler}: {self.workers} worker processes of 1 thread)"
            return f"dask distributed ({self.scheduler}, {self.workers} worker threads)"
        if self.scheduler == "synchronous":
            return "dask synchronous"
        return f"dask local threads ({self.workers})"

    def map(self, fn: Callable, items: Iterable, desc: str = "tasks", unit: str = "task",
            at_once: int | None = None, on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
        """``[fn(item) for item in items]``, run as Dask tasks; results in the order of ``items``.

        ``at_once``: at most this many tasks run together in this process (tasks whose memory would not fit
        side by side under the process's limit); the workers of a distributed cluster are processes with their
        own memory and are not held back.

        ``on_result(k, result)``: called in this thread for each item that succeeded, as it finishes (in the order
        they finish, each once), e.g. to say what a task found while the others still run; the results returned are
        the objects handed over (a cluster's fetched once).

        When tasks fail, the exception of the first failing item in item order is raised (an
        InputError keeps its message), whichever scheduler ran them: after the first failure no
        later item is started, and earlier items still run, so the error a user sees is always the
        same one."""
        items = list(items)
        if not items:
            return []
        if self._client is not None:
            return self._map_distributed(fn, items, desc, unit, on_result)
        if len(items) == 1:
            # one task (e.g. a one-frame ``ortho rectify``): run here, without importing dask (about 0.1 s
            # of a command that takes one); the task gets all the cores either way (cores_per_task)
            with progress(1, desc, unit) as bar:
                out = [fn(items[0])]
                bar.update(1)
            if on_result is not None:
                on_result(0, out[0])
            return out
        import threading

        import dask
        from dask.callbacks import Callback
        from dask.local import get_sync
        from dask.threaded import get as threaded_get

        first_bad = [len(items)]
        stopping, running = [False], [0]  # interrupted in this thread; tasks in progress on the pool
        lock = threading.Condition()

        def guarded(k_item):
            k, item = k_item
            with lock:
                if k > first_bad[0] or stopping[0]:
                    return _SKIPPED
                running[0] += 1
            try:
                return fn(item)
            except BaseException as exc:  # noqa: BLE001 - handed back to the caller below
                with lock:
                    first_bad[0] = min(first_bad[0], k)
                return _Failed(exc)
            finally:
                with lock:
                    running[0] -= 1
                    lock.notify_all()

        tasks = [dask.delayed(guarded, pure=False)((k, item)) for k, item in enumerate(items)]
        index = {t.key: k for k, t in enumerate(tasks)}

        class _Progress(Callback):
            # (dask's local schedulers call it in the thread that computes: this one)
            def _posttask(self, key, result, dsk, state, worker_id):
                bar.update(1)
                if (on_result is not None and key in index and result is not _SKIPPED
                        and not isinstance(result, _Failed)):
                    on_result(index[key], result)

        # the local schedulers as functions, not by name: a name makes dask import distributed (about
        # 0.3 s) to look for a default client, a tenth of what a one-frame ``ortho rectify`` takes
        with progress(len(items), desc, unit) as bar, _Progress():
            threads = self.workers if at_once is None else min(self.workers, max(1, int(at_once)))
            in_this_thread = self.scheduler == "synchronous" or threads == 1
            try:
                if in_this_thread:
                    out = list(dask.compute(*tasks, scheduler=get_sync))
                else:
                    out = list(dask.compute(*tasks, scheduler=threaded_get, num_workers=threads))
            except BaseException:
                # Ctrl-C or SIGTERM in this thread: the pool's threads go on with their tasks, which would write
                # their files after the caller's roll-back (aerotri.core.atomic), outside any commit. No task
                # starts any more, and the running ones end before the interrupt goes on to the roll-back. (Tasks
                # run in this thread have ended with the interrupt: their count may not have been taken down.)
                if not in_this_thread:
                    _wait_for_running(lock, stopping, running)
                raise
        for r in out:
            if isinstance(r, _Failed):
                raise r.exc
        return out

    def _map_distributed(self, fn, items, desc, unit, on_result=None):
        from distributed import as_completed

        futures = self._client.map(fn, items, pure=False)
        index = {f.key: k for k, f in enumerate(futures)}
        first_bad = len(items)
        got = {}  # with on_result: each result as handed over, returned as it is (not fetched again by a gather)
        with progress(len(items), desc, unit) as bar, _cancelled_when_interrupted(self._client, futures):
            for fut in as_completed(futures):
                k = index[fut.key]
                if fut.status == "error" and k < first_bad:
                    first_bad = k
                    for f in futures[k + 1:]:
                        f.cancel()
                elif fut.status == "finished" and on_result is not None:
                    got[k] = fut.result()
                    on_result(k, got[k])
                bar.update(1)
                if all(f.done() for f in futures[:first_bad]) and first_bad < len(items):
                    break
        if first_bad < len(items):
            # an earlier item can be done (failed) before as_completed hands it over: look at all of them
            first_bad = next(k for k, f in enumerate(futures[:first_bad + 1]) if f.status == "error")
            fut = futures[first_bad]
            raise fut.exception().with_traceback(fut.traceback())
        return [got[k] for k in range(len(items))] if on_result is not None else self._client.gather(futures)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_LOCAL = None
_ACTIVE: Executor | None = None


def local_executor() -> Executor:
    """The executor for library calls that were given none: the one a production run made active
    (:func:`activate`), else local threads."""
    global _LOCAL
    if _ACTIVE is not None:
        return _ACTIVE
    if _LOCAL is None:
        _LOCAL = Executor()
    return _LOCAL


@contextlib.contextmanager
def activate(executor: Executor):
    """Make ``executor`` the one every stage of a run uses (one cluster connection for the whole run)."""
    global _ACTIVE
    previous, _ACTIVE = _ACTIVE, executor
    try:
        yield executor
    finally:
        _ACTIVE = previous


@contextlib.contextmanager
def executor_for(scheduler: str | None = None, workers: int | None = None):
    """The executor of a command: a new one for an explicit ``--scheduler``/``--workers``, otherwise
    the run's active one (or local threads)."""
    if scheduler is None and workers is None:
        yield local_executor()
        return
    with Executor(scheduler, workers) as ex:
        yield ex
