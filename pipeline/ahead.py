"""A computation run ahead in a forked child process (Linux, two cores or more).

:class:`Ahead` forks this process; the child computes what the parent would compute, from
a copy of its state, and sends back the result and its stage times through a pipe.  The
layout stage uses it to lay out the first tighter tiling while the first one is laid out
(:attr:`~drawstring.pipeline.policy.LayoutPolicy.retile_ahead`), and to co-optimize without
the conical condition while the conical co-optimizations run
(:attr:`~drawstring.pipeline.policy.LayoutPolicy.co_speculate`); :meth:`Ahead.ready` tells, without
waiting, whether the child is done (its core spare).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Generic, TypeVar, cast

from drawstring.geometry.core import parallel
from drawstring.pipeline.policy import DEFAULT_POLICY
from drawstring.pipeline.record import Progress

logger = logging.getLogger(__name__)

T = TypeVar("T")


class Ahead(Generic[T]):
    """``work(progress)`` run in a forked child process.

    The child starts from a copy of this process (fork), so it computes what ``work``
    would compute here; it sends back the result and its stage times through a pipe.  If the
    child fails or dies, :meth:`result` gives None and the caller does the work itself.
    The child runs ``niceness`` steps nicer than this process
    (:attr:`~drawstring.pipeline.policy.LayoutPolicy.ahead_niceness`).
    """

    def __init__(
        self,
        work: Callable[[Progress], T],
        what: str = "the work done ahead",
        *,
        niceness: int = DEFAULT_POLICY.ahead_niceness,
    ) -> None:
        self._what = what
        self._child = parallel.ForkedChild(_run_ahead, (work, niceness), daemon=True)

    def ready(self) -> bool:
        """Whether the child is done (its result, or its end, is waiting in the pipe): it no
        longer takes a core."""
        try:
            return bool(self._child.receive.poll())
        except (OSError, ValueError):  # closed: collected or cancelled
            return True

    def result(self, progress: Progress) -> T | None:
        """The child's result; the time spent waiting for it is added to ``progress``'s
        stages in proportion to the child's own stage times."""
        start = time.perf_counter()
        try:
            status, payload, timings = self._child.receive.recv()
        except (EOFError, OSError):
            status, payload, timings = "died", "no result", {}
        except BaseException:  # e.g. Ctrl-C while waiting: the child goes too
            self.cancel()
            raise
        self._child.process.join()
        self._child.receive.close()
        if status != "ok":
            logger.warning("%s failed (%s); doing it again here", self._what, payload)
            return None
        progress.absorb(timings, time.perf_counter() - start)
        return cast(T, payload)

    def cancel(self) -> None:
        """Stop the child (its result is not needed)."""
        self._child.stop()


def tag_ahead(record: logging.LogRecord) -> bool:
    """Log filter of :class:`Ahead`'s child: its lines start with ``(ahead)``."""
    if not str(record.msg).startswith("(ahead) "):  # once, however many handlers
        record.msg = f"(ahead) {record.msg}"
    return True


def _run_ahead(work: Callable[[Progress], object], niceness: int, send: Connection) -> None:
    """Body of :class:`Ahead`'s child process."""
    parallel.exit_quietly_on_interrupt()
    with contextlib.suppress(OSError):  # yield to the parent
        os.nice(niceness)

    for handler in logging.getLogger().handlers:  # -v: tell this process's lines apart
        handler.addFilter(tag_ahead)

    progress = Progress(quiet=True)
    try:
        result = work(progress)
        send.send(("ok", result, progress.timings))
    except Exception as exc:  # reported to the parent, which lays the tiling out itself
        send.send(("error", f"{type(exc).__name__}: {exc}", {}))
    finally:
        send.close()
