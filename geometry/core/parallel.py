"""Independent blocks of large numpy work spread over the machine's cores.

NumPy releases the GIL inside its array loops, so blocks of rows whose arithmetic is
independent (each row's result depends on that row alone) run side by side on threads.  The
blocks' results come back in order and each row is computed by the same operations whatever
the number of threads or blocks, so results are bitwise the same on any machine.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing.connection import Connection
from multiprocessing.context import BaseContext
from typing import Any, Protocol, TypeVar

__all__ = [
    "MAX_THREADS",
    "TaskRunner",
    "exit_quietly_on_interrupt",
    "map_blocks",
    "process_pool",
    "sigint_held",
    "task_runner",
    "tasks_on",
    "thread_count",
]

T = TypeVar("T")
R = TypeVar("R")

#: Most worker threads used (the pipeline targets two cores; more gain little on these sizes).
MAX_THREADS = 4

_pool: ThreadPoolExecutor | None = None


def thread_count() -> int:
    """Threads the blocks are spread over: the cores this process may run on, at most
    :data:`MAX_THREADS`."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_THREADS))


def _forget_pool() -> None:
    """In a forked child: the parent's pool threads do not exist there, so start a new pool."""
    global _pool
    _pool = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def map_blocks(work: Callable[[T], R], blocks: Sequence[T]) -> list[R]:
    """``[work(b) for b in blocks]``, the blocks run on worker threads when there are several
    blocks and cores."""
    global _pool
    if len(blocks) < 2 or thread_count() < 2:
        return [work(block) for block in blocks]
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=thread_count(), thread_name_prefix="drawstring")
    return list(_pool.map(work, blocks))


def _exit_interrupted(signum: int, frame: object) -> None:
    os._exit(130)


def exit_quietly_on_interrupt() -> None:
    """Call first in a worker process: Ctrl-C (SIGINT, sent to the whole process group) ends it
    at once and without a traceback.  The parent gets the same signal and reports the
    interruption in one line.  Where SIGINT is ignored (a job started in the background by a
    non-interactive shell), it stays ignored, as in the parent."""
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, _exit_interrupted)
    if hasattr(signal, "pthread_sigmask"):  # forked under sigint_held(): take it now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) back in this thread meanwhile; it takes effect right after.  For
    steps that must not be cut in two (folders renamed in pairs), and around starting a worker
    process, which inherits the mask until :func:`exit_quietly_on_interrupt` unblocks it."""
    if not hasattr(signal, "pthread_sigmask"):  # not POSIX
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def can_fork() -> bool:
    """Whether work may run in a child forked from this process: Linux (forking a process
    that has loaded macOS system frameworks is unsafe), two cores or more, and not a daemonic
    process (a ``multiprocessing`` pool worker may not have children)."""
    return (
        sys.platform.startswith("linux")
        and thread_count() >= 2
        and "fork" in multiprocessing.get_all_start_methods()
        and not multiprocessing.current_process().daemon
    )


class ForkedChild:
    """``target(*args, send)`` run in a child forked from this process (so it starts from a
    copy of this process's state and nothing is pickled on the way in), and ``receive``, the
    end of the pipe whose other end, ``send``, it answers through.  Ctrl-C is held while the
    child starts (:func:`sigint_held`); the child unblocks it."""

    def __init__(
        self,
        target: Callable[..., None],
        args: tuple[Any, ...],
        *,
        daemon: bool = False,
    ) -> None:
        context = multiprocessing.get_context("fork")
        self.receive: Connection
        self.receive, send = context.Pipe(duplex=False)
        self.process = context.Process(target=target, args=(*args, send), daemon=daemon)
        try:
            with sigint_held():  # the child takes Ctrl-C once its quiet exit is set
                self.process.start()
        except BaseException:  # e.g. OSError: the fork was refused
            self.receive.close()
            raise
        finally:
            send.close()

    def stop(self) -> None:
        """End the child (its answer is not needed) and close the pipe."""
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        self.receive.close()


@contextlib.contextmanager
def process_pool(workers: int, context: BaseContext) -> Iterator[ProcessPoolExecutor]:
    """A process pool whose workers exit quietly on Ctrl-C (:func:`exit_quietly_on_interrupt`);
    on an error or an interrupt in the caller the jobs not yet started are dropped rather than
    run to the end."""
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=exit_quietly_on_interrupt
    )
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


class TaskRunner(Protocol):
    """Somewhere else to run independent tasks: a cluster of worker processes, maybe on other
    machines (``drawstring design --scheduler``).  Functions and arguments are pickled there,
    so a function must be a module-level one of the package."""

    def thread_count(self) -> int:
        """Tasks it runs at once."""
        ...

    def starmap(
        self, function: Callable[..., Any], arguments: Sequence[tuple[Any, ...]], *, name: str
    ) -> list[Any]:
        """``[function(*args) for args in arguments]`` there, in order."""
        ...


_runner: TaskRunner | None = None


def task_runner() -> TaskRunner | None:
    """The runner :func:`tasks_on` set, or None: the stages that build per-tile work in worker
    processes (the CAD stage's tile solids) send it there instead."""
    return _runner


@contextlib.contextmanager
def tasks_on(runner: TaskRunner) -> Iterator[None]:
    """Meanwhile the stages' per-tile work runs on ``runner`` (:func:`task_runner`)."""
    global _runner
    previous, _runner = _runner, runner
    try:
        yield
    finally:
        _runner = previous
