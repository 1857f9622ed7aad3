"""Executors: where design jobs run, behind one small interface.

An executor takes :class:`~.job.JobSpec`\\ s (:meth:`Executor.submit`), runs each with
:func:`~.job.run_job` when its turn comes, and tells a listener what happens through
:class:`JobEvent`\\ s: a job started, began a stage, finished.  :class:`ProcessExecutor` runs
each job in a child process of this machine, at most ``max_running`` at once, the others
queued in the order submitted; cancelling a running job ends its process and every process
it started, and a job whose process dies takes nothing else with it.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any, Literal, Protocol

from drawstring.app.studio.job import JobSpec, Outcome, run_job

log = logging.getLogger(__name__)

#: A job's log (its standard output and error, with every stage's time) in its job folder.
LOG_NAME = "log.txt"


@dataclass(frozen=True)
class JobEvent:
    """What happened to a job: ``started``; ``stage`` (with its name and the fraction done);
    ``finished`` (with its outcome)."""

    id: str
    kind: Literal["started", "stage", "finished"]
    stage: str = ""
    progress: float = 0.0
    outcome: Outcome | None = None


Listener = Callable[[JobEvent], None]


class Executor(Protocol):
    """Runs design jobs and reports on them to the listener it was made with.

    Events may come from any thread; each job gets ``started`` before its stages and exactly
    one ``finished`` unless the executor is shut down first.
    """

    #: How many jobs run at once.
    max_running: int

    def submit(self, spec: JobSpec) -> None:
        """Queue a job; it starts when a place is free."""

    def cancel(self, job_id: str) -> bool:
        """Cancel a queued or running job (it finishes as ``cancelled``); False when the
        executor does not hold it."""

    def status(self, job_id: str) -> Literal["queued", "running"] | None:
        """Where a job is, or None when the executor does not hold it."""

    def shutdown(self) -> None:
        """Stop every job without reporting on them, and the executor itself."""


@dataclass
class _Running:
    spec: JobSpec
    process: BaseProcess
    conn: Connection | None
    outcome: Outcome | None = None
    cancelled: bool = False


def default_max_running() -> int:
    """One running job per two cores (a design uses a second core for work run ahead)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, cores // 2)


class ProcessExecutor:
    """Jobs in child processes of this machine (started by a fork server that has loaded the
    pipeline once), at most ``max_running`` at a time."""

    def __init__(self, listener: Listener, max_running: int | None = None) -> None:
        self.max_running = max_running if max_running is not None else default_max_running()
        if self.max_running < 1:
            raise ValueError("an executor runs at least one job at a time")
        self._listener = listener
        self._context = _context()
        self._lock = threading.Lock()
        self._queued: collections.deque[JobSpec] = collections.deque()
        self._running: dict[str, _Running] = {}
        self._stopping = False
        self._closed = False
        self._wake_read, self._wake_write = os.pipe()
        os.set_blocking(self._wake_write, False)
        self._thread = threading.Thread(target=self._watch, name="studio-jobs", daemon=True)
        self._thread.start()

    # -- the interface ---------------------------------------------------------------------

    def submit(self, spec: JobSpec) -> None:
        with self._lock:
            if self._stopping:
                raise RuntimeError("the executor is shut down")
            self._queued.append(spec)
        self._wake()

    def cancel(self, job_id: str) -> bool:
        with self._lock:
            queued = next((s for s in self._queued if s.id == job_id), None)
            if queued is not None:
                self._queued.remove(queued)
            running = self._running.get(job_id)
            if running is not None:
                running.cancelled = True
        if queued is not None:
            self._listener(JobEvent(job_id, "finished", outcome=_cancelled()))
            return True
        if running is None:
            return False
        _kill(running.process)
        return True

    def status(self, job_id: str) -> Literal["queued", "running"] | None:
        with self._lock:
            if job_id in self._running:
                return "running"
            if any(s.id == job_id for s in self._queued):
                return "queued"
        return None

    def shutdown(self) -> None:
        with self._lock:
            self._stopping = True
            self._queued.clear()
            running = list(self._running.values())
        for job in running:
            _kill(job.process)
        self._wake()
        self._thread.join(timeout=10)
        for job in running:
            job.process.join(timeout=5)
        if self._thread.is_alive():  # still busy with a listener: it keeps its pipe
            return
        with self._lock:
            self._closed = True
            os.close(self._wake_read)
            os.close(self._wake_write)

    # -- the watcher thread ----------------------------------------------------------------

    def _wake(self) -> None:
        with self._lock:
            if self._closed:
                return
            with contextlib.suppress(BlockingIOError):  # full: a wake is pending already
                os.write(self._wake_write, b"x")

    def _watch(self) -> None:
        if self._context.get_start_method() == "forkserver":
            from multiprocessing import forkserver

            with contextlib.suppress(OSError):  # start it (and load the pipeline) now
                forkserver.ensure_running()
        while True:
            self._start_queued()
            with self._lock:
                if self._stopping:
                    return
                jobs = list(self._running.values())
            handles: list[Any] = [self._wake_read]
            for job in jobs:
                handles.append(job.process.sentinel)
                if job.conn is not None:
                    handles.append(job.conn)
            ready = wait(handles, timeout=5.0)
            if self._wake_read in ready:
                with contextlib.suppress(OSError):
                    os.read(self._wake_read, 4096)
            for job in jobs:
                if job.conn is not None and job.conn in ready:
                    self._receive(job)
                if job.process.sentinel in ready:
                    self._ended(job)

    def _start_queued(self) -> None:
        while True:
            with self._lock:
                if self._stopping or len(self._running) >= self.max_running or not self._queued:
                    return
                spec = self._queued.popleft()
                receive, send = self._context.Pipe(duplex=False)
                process = self._context.Process(
                    target=_child, args=(spec.to_json(), send), name=f"design-{spec.id}"
                )
                job = _Running(spec, process, receive)
                self._running[spec.id] = job
            self._listener(JobEvent(spec.id, "started"))
            try:
                process.start()
            except OSError as exc:  # no process to be had
                with self._lock:
                    del self._running[spec.id]
                receive.close()
                message = f"internal error: could not start the design's process ({exc})"
                self._listener(JobEvent(spec.id, "finished", outcome=Outcome("failed", 1, message)))
            else:
                if job.cancelled:  # cancelled while it was being started
                    _kill(process)
            finally:
                send.close()

    def _receive(self, job: _Running) -> None:
        conn = job.conn
        assert conn is not None
        try:
            while conn.poll():
                message = conn.recv()
                if message[0] == "stage":
                    _, stage, fraction = message
                    self._listener(JobEvent(job.spec.id, "stage", stage, float(fraction)))
                elif message[0] == "finished":
                    job.outcome = Outcome(*message[1:])
        except (EOFError, OSError):  # the child closed its end: its sentinel follows
            conn.close()
            job.conn = None

    def _ended(self, job: _Running) -> None:
        if job.conn is not None:
            self._receive(job)
            if job.conn is not None:
                job.conn.close()
                job.conn = None
        job.process.join()
        _kill_group(job.process.pid)  # anything the job started and left behind
        with self._lock:
            self._running.pop(job.spec.id, None)
            if self._stopping:
                return
        if job.outcome is not None:
            outcome = job.outcome
        elif job.cancelled:
            outcome = _cancelled()
        else:
            outcome = Outcome("failed", 1, _died(job.process.exitcode))
        self._listener(JobEvent(job.spec.id, "finished", outcome=outcome))


def _context() -> Any:
    """A fork server that has imported the pipeline: a job starts in a fraction of a second
    (no import), from a process with no threads of this server's (fork is not safe here)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["drawstring.app.studio.job"])
    return context


def _cancelled() -> Outcome:
    return Outcome("cancelled", None, "cancelled")


def _died(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            how = f"signal {signal.Signals(-exitcode).name}"
        except ValueError:
            how = f"signal {-exitcode}"
    else:
        how = f"exit code {exitcode}"
    return (
        f"internal error: the design's process ended without a result ({how}); its log may say why"
    )


def _kill_group(pid: int | None) -> None:
    if pid is None or not hasattr(os, "killpg"):
        return
    with contextlib.suppress(OSError):  # no such group: nothing is left
        os.killpg(pid, signal.SIGKILL)


def _kill(process: BaseProcess) -> None:
    """End a job's process and the processes it started (its process group)."""
    _kill_group(process.pid)
    with contextlib.suppress(OSError, ValueError, AttributeError):
        process.kill()


def _child(spec_data: dict[str, Any], send: Connection) -> None:
    """Body of a job's process: its own process group, its output to the job's log."""
    if hasattr(os, "setpgid"):
        os.setpgid(0, 0)
    spec = JobSpec.from_json(spec_data)
    log_fd = os.open(Path(spec.folder) / LOG_NAME, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(log_fd, 1)
    os.dup2(log_fd, 2)
    os.close(log_fd)
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        force=True,
    )

    def report(stage: str, fraction: float) -> None:
        send.send(("stage", stage, fraction))

    outcome = run_job(spec, report)
    log.info("finished: %s (exit status %s): %s", *_fields(outcome))
    send.send(("finished", *_fields(outcome)))
    send.close()
    sys.stdout.flush()
    sys.stderr.flush()


def _fields(outcome: Outcome) -> tuple[str, int | None, str]:
    return outcome.status, outcome.exit_status, outcome.message
