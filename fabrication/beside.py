"""Independent writers run beside the caller, each in a forked child process.

A design folder's slow files (the STEP files, the 3MF files, the pictures) do not read each
other: :class:`Beside` writes each in a child process forked from this one, so it inherits
what it writes (the CAD solids, the design's arrays) and nothing is pickled, while the caller
writes the rest.  A child sends back what its writer returned, or the exception it raised,
which :meth:`Beside.results` raises here as the writer would have raised it in this process:
the same exit status and the same one line, never a child's traceback.  A child that ends
without an answer (killed) is an :class:`InternalError` naming its file.

The children run at this process's priority, so that on a busy machine they keep their share
of it.  Where fork is unsafe or unavailable (macOS, Windows, a daemonic process, one core), or
``workers == 1``, each writer runs here when it is started: the same files, one after the
other.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.parallel import can_fork


class _Child(parallel.ForkedChild):
    """One writer's forked process and the pipe its answer comes back through."""

    def __init__(self, what: str, write: Callable[..., object], args: tuple[Any, ...]) -> None:
        self.what = what
        super().__init__(_child, (write, args))

    def answer(self) -> object:
        """What the writer returned; what it raised is raised here."""
        try:
            status, payload = self.receive.recv()
        except (EOFError, OSError):
            status, payload = "died", None
        self.process.join()
        self.receive.close()
        if status == "ok":
            return payload
        if status == "error" and isinstance(payload, BaseException):
            raise payload
        raise InternalError(
            f"the process writing {self.what} ended without finishing it "
            f"(exit code {self.process.exitcode})"
        )


class Beside:
    """Writers started one by one, running in forked children while the caller goes on.

    ``start`` forks a child for ``write(*args)``; ``results`` waits for every writer started
    and gives what each returned, in the order they were started, or raises the first error
    (in that order) after stopping the writers still running; ``stop`` ends them all (their
    folder is about to be removed).  Without fork each writer runs in ``start``.
    """

    def __init__(self, workers: int | None = None) -> None:
        self.forks = workers != 1 and can_fork()
        self._started: list[tuple[bool, object]] = []  # (in a child, its _Child or result)

    def start(self, what: str, write: Callable[..., object], *args: Any) -> None:
        """Write ``what`` (a file name, for the error of a child that died) with
        ``write(*args)``."""
        if not self.forks:
            self._started.append((False, write(*args)))
            return
        self._started.append((True, _Child(what, write, args)))

    def results(self) -> list[object]:
        """What each writer returned, in the order started; raises what one raised."""
        started, self._started = self._started, []
        answers: list[object] = []
        try:
            for index, (forked, item) in enumerate(started):
                answers.append(item.answer() if forked and isinstance(item, _Child) else item)
                started[index] = (False, None)
        except BaseException:
            _stop(started)
            raise
        return answers

    def stop(self) -> None:
        """End the writers still running."""
        started, self._started = self._started, []
        _stop(started)


def _stop(started: list[tuple[bool, object]]) -> None:
    for forked, item in started:
        if forked and isinstance(item, _Child):
            item.stop()


def _child(write: Callable[..., object], args: tuple[Any, ...], send: Connection) -> None:
    """Body of a writing process: the writer's result or exception goes back through
    ``send``; the process ends with status 1 after an exception, without printing it."""
    parallel.exit_quietly_on_interrupt()
    try:
        answer: tuple[str, object] = ("ok", write(*args))
    except Exception as exc:
        answer = ("error", _sendable(exc))
    try:
        try:
            send.send(answer)
        except Exception as exc:  # a result that does not pickle: a bug
            answer = ("error", InternalError(f"{type(exc).__name__}: {exc}"))
            send.send(answer)
    finally:
        send.close()
    if answer[0] != "ok":
        sys.exit(1)


def _sendable(exc: Exception) -> BaseException:
    """``exc`` if it crosses a pipe unchanged (pickles and unpickles to the same type and
    message), else an :class:`InternalError` holding its type and message."""
    exc.__traceback__ = None
    with contextlib.suppress(Exception):
        back = pickle.loads(pickle.dumps(exc))
        if type(back) is type(exc) and str(back) == str(exc):
            return exc
    return InternalError(f"{type(exc).__name__}: {exc}")
