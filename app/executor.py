"""Independent tasks run on a Dask cluster: a local one sized to the machine, or one running.

:class:`DaskExecutor` connects a ``dask.distributed`` client to the scheduler at an address
(``dask scheduler`` / ``dask worker ADDRESS``), or starts a local cluster of worker processes,
one per core, one task at a time each.  :meth:`DaskExecutor.run` submits :class:`Task`\\ s and
yields a :class:`TaskEvent` as each starts on a worker and as each ends, in the order they
happen; :meth:`DaskExecutor.map` gives the results of one function over many items in their
order.  Scheduling, placement and rerunning the task of a worker that dies are Dask's: a task
whose worker dies runs again on another one (up to the scheduler's
``distributed.scheduler.allowed-failures``, after which it fails with ``KilledWorker``).

A task's function and arguments are pickled and sent to a worker, so the function must be
importable there (a module-level function of an installed package) and its arguments and result
small enough to send: the workers need the same drawstring, numpy and scipy as the client.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Literal, TypeVar

from drawstring.geometry.core.errors import InputError

T = TypeVar("T")
R = TypeVar("R")

#: Seconds to wait for a scheduler given by address to answer.
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Task:
    """``function(*args)`` to run on a worker; ``key`` names it in events (unique in a run)."""

    key: str
    function: Callable[..., Any]
    args: tuple[Any, ...] = ()


@dataclass(frozen=True)
class TaskEvent:
    """A task ``started`` on ``worker`` (again, if its first worker died), made a ``report``
    there (``result`` is what it sent), ``finished`` there with ``result``, or ``failed``
    (``error`` says why: the function raised, or the cluster gave the task up)."""

    kind: Literal["started", "report", "finished", "failed"]
    task: Task
    worker: str = ""
    result: Any = None
    error: str = ""


def local_worker_count() -> int:
    """Worker processes of a local cluster: one per core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


class DaskExecutor:
    """A Dask client, and the local cluster it started (when not given a scheduler's address).

    Use it as a context manager: the client closes on exit, and a local cluster with it (its
    worker processes end).  ``workers`` sizes the local cluster (default: one process per
    core); it does not apply to a cluster given by address.
    """

    def __init__(
        self, scheduler: str | None = None, workers: int | None = None, *, verbose: bool = False
    ) -> None:
        if scheduler is not None and workers is not None:
            raise InputError(
                "--workers sizes the local cluster and does not apply to --scheduler; start as "
                "many `dask worker` processes as you want on the cluster instead"
            )
        if workers is not None and workers < 1:
            raise InputError(f"--workers must be at least 1 (got {workers})")
        self.scheduler = scheduler
        self.local_workers = workers if workers is not None else local_worker_count()
        self._verbose = verbose
        self._cluster: Any = None
        self._client: Any = None
        self._log_level: int | None = None
        self._lock = threading.Lock()
        self._topic_name: str | None = None
        #: Dask key -> (task, listener) of each task sent and not ended
        self._listening: dict[str, tuple[Task, Callable[[TaskEvent], None]]] = {}

    def __enter__(self) -> DaskExecutor:
        from distributed import Client, LocalCluster

        # Dask's own lines (a local scheduler's, the client's) only where they matter: its
        # warnings with -v, its errors otherwise
        log = logging.getLogger("distributed")
        self._log_level = log.level
        log.setLevel(logging.WARNING if self._verbose else logging.ERROR)
        if self.scheduler is None:
            # one task per process: a design's numpy work is single-threaded (BLAS) or spread
            # over its own threads, so threads sharing a process would only contend for the GIL
            self._cluster = LocalCluster(
                n_workers=self.local_workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                # its web server (health checks) on a free port, not the dashboard's fixed one
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.WARNING if self._verbose else logging.ERROR,
            )
            self._client = Client(self._cluster)
            return self
        try:
            self._client = Client(self.scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, ValueError, TypeError) as exc:
            self.close()
            raise InputError(
                f"cannot reach a Dask scheduler at {self.scheduler} ({exc}); start one with "
                "`dask scheduler` and give the address it prints (tcp://HOST:PORT), or leave out "
                "--scheduler for a local cluster"
            ) from None
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the client, and the local cluster with its worker processes."""
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if client is not None and self._topic_name is not None:
            with contextlib.suppress(Exception):
                client.unsubscribe_topic(self._topic_name)
        self._topic_name = None
        with contextlib.suppress(Exception):  # already gone: nothing to close
            if client is not None:
                client.close()
        with contextlib.suppress(Exception):
            if cluster is not None:
                cluster.close()
        if self._log_level is not None:
            logging.getLogger("distributed").setLevel(self._log_level)
            self._log_level = None

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (only inside the ``with`` block)."""
        if self._client is None:
            raise RuntimeError("the executor is not open: use it in a with block")
        return self._client

    def workers(self) -> dict[str, int]:
        """The cluster's workers now: address -> threads."""
        return dict(self.client.nthreads())

    def describe(self) -> str:
        """Where the tasks run, in a phrase."""
        count = len(self.workers())
        if self.scheduler is None:
            return f"a local cluster of {count} worker process{'es' if count != 1 else ''}"
        return f"the cluster at {self.scheduler} ({count} worker{'s' if count != 1 else ''} now)"

    def _topic(self) -> str:
        """This executor's event topic, subscribed once: tasks' starts and reports come on it
        and go to the listener of their task."""
        if self._topic_name is None:
            self._topic_name = f"drawstring-tasks-{uuid.uuid4().hex[:12]}"

            def heard(event: tuple[float, dict[str, Any]]) -> None:
                message = event[1]
                with self._lock:
                    entry = self._listening.get(message["key"])
                if entry is None:  # ended, cancelled, or another executor's
                    return
                task, listener = entry
                if message["kind"] == "started":
                    listener(TaskEvent("started", task, message["worker"]))
                else:
                    listener(TaskEvent("report", task, message["worker"], message.get("data")))

            self.client.subscribe_topic(self._topic_name, heard)
        return self._topic_name

    def submit(self, task: Task, listener: Callable[[TaskEvent], None]) -> Any:
        """Send one task; ``listener`` gets its events (from Dask's threads): ``started`` (again
        if its worker died), any ``report`` it makes (:func:`report`), then one ``finished`` or
        ``failed``.  Returns the task's future (for :meth:`cancel`)."""
        topic = self._topic()
        key = f"{task.key}-{uuid.uuid4().hex[:12]}"
        with self._lock:
            self._listening[key] = (task, listener)

        def done(future: Any) -> None:
            with self._lock:
                entry = self._listening.pop(key, None)
            if entry is not None:
                listener(_ended(task, future))

        future = self.client.submit(
            _run_task, topic, key, task.function, task.args, key=key, pure=False
        )
        future.add_done_callback(done)
        return future

    def cancel(self, future: Any) -> None:
        """Drop a task: no more events for it; a task running on a worker runs to its end there
        (Dask does not stop a running function), its result unused."""
        with self._lock:
            self._listening.pop(future.key, None)
        with contextlib.suppress(Exception):  # the client may already be closing
            self.client.cancel([future])

    def run(self, tasks: Sequence[Task]) -> Iterator[TaskEvent]:
        """Submit every task and yield their events as they happen, until each has finished or
        failed.  Closing the iterator early (an error, Ctrl-C) cancels the tasks not done."""
        if len({task.key for task in tasks}) != len(tasks):
            raise ValueError("task keys must be unique")
        events: queue.Queue[TaskEvent] = queue.Queue()
        futures = {task.key: self.submit(task, events.put) for task in tasks}
        try:
            while futures:
                try:  # a timeout keeps the wait interruptible (Ctrl-C)
                    event = events.get(timeout=0.5)
                except queue.Empty:
                    continue
                if event.kind in ("finished", "failed"):
                    futures.pop(event.task.key, None)
                yield event
        finally:
            for future in futures.values():
                self.cancel(future)

    def map(self, function: Callable[[T], R], items: Sequence[T], *, name: str = "task") -> list[R]:
        """``[function(item) for item in items]`` on the cluster, in the items' order; raises
        :class:`RuntimeError` naming the first item that failed."""
        return self.starmap(function, [(item,) for item in items], name=name)

    def starmap(
        self,
        function: Callable[..., R],
        arguments: Sequence[tuple[Any, ...]],
        *,
        name: str = "task",
    ) -> list[R]:
        """``[function(*args) for args in arguments]`` on the cluster, in order; raises
        :class:`RuntimeError` naming the first call that failed."""
        tasks = [Task(f"{name}-{i}", function, args) for i, args in enumerate(arguments)]
        results: dict[str, R] = {}
        for event in self.run(tasks):
            if event.kind == "failed":
                raise RuntimeError(f"{event.task.key} failed on the cluster: {event.error}")
            if event.kind == "finished":
                results[event.task.key] = event.result
        return [results[task.key] for task in tasks]

    def thread_count(self) -> int:
        """Tasks the cluster runs at once now (its workers' threads; at least 1)."""
        return max(1, sum(self.workers().values()))


def _ended(task: Task, future: Any) -> TaskEvent:
    """The event of a future that is done: its result, or why there is none."""
    if future.status == "finished":
        worker, result = future.result()
        return TaskEvent("finished", task, worker, result)
    try:
        exc = future.exception()
    except BaseException as cancelled:  # CancelledError: the cluster dropped it
        exc = cancelled
    name = type(exc).__name__
    if name == "KilledWorker":
        why = "its worker died while running it, each time it was tried"
    elif name == "CancelledError":
        why = "the cluster cancelled it (its scheduler restarted or the client lost it)"
    else:
        why = f"{name}: {exc}"
    return TaskEvent("failed", task, error=why)


#: The task running in this thread of a worker: (topic, key), for :func:`report`.
_current = threading.local()


def report(data: Any) -> None:
    """In a task: send ``data`` (small, picklable) to the client, where the task's listener gets
    it as a ``report`` event.  Outside a task it does nothing."""
    where = getattr(_current, "task", None)
    if where is None:
        return
    from distributed import get_worker

    worker = get_worker()
    topic, key = where
    worker.log_event(topic, {"key": key, "kind": "report", "worker": worker.address, "data": data})


def _run_task(
    topic: str, key: str, function: Callable[..., Any], args: tuple[Any, ...]
) -> tuple[str, Any]:
    """On a worker: tell the client the task started here, run it, return (worker, result)."""
    from distributed import get_worker

    worker = get_worker()
    worker.log_event(topic, {"key": key, "kind": "started", "worker": worker.address})
    _current.task = (topic, key)
    try:
        return worker.address, function(*args)
    finally:
        _current.task = None
