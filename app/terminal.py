"""The terminal side of the command line: Python warnings raised inside the libraries, and
standard output whose reader has gone (``drawstring profiles | head -1``)."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import warnings
from collections.abc import Iterator
from typing import Any, TextIO

#: Logger that Python warnings raised inside the libraries (numpy, scipy, OCP) go to with -v.
LIBRARY_LOGGER = "drawstring.library"


@contextlib.contextmanager
def library_warnings(verbose: bool) -> Iterator[None]:
    """Python warnings raised while a command runs: one log line each with ``-v``, none
    without.  What a user needs to know about a design is in its own ``warnings`` and
    ``problems``; a library's numerical warning (an overflow in a trial step the solver then
    refuses, a deprecation) is a detail for whoever debugs it.  The previous warning state
    comes back on return (``main`` may be called from a script or a test)."""
    log = logging.getLogger(LIBRARY_LOGGER)

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: object = None,
        line: str | None = None,
    ) -> None:
        log.warning("%s: %s (%s:%d)", category.__name__, message, filename, lineno)

    with warnings.catch_warnings():
        if verbose:
            warnings.simplefilter("default")  # once per place, as Python shows them
            warnings.showwarning = show
        else:
            warnings.simplefilter("ignore")
        yield


class ClosedPipeSafe:
    """Standard output that goes quiet once its reader has gone (``drawstring profiles |
    head -1``): the rest is discarded and the command still ends with its own exit status."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self._gone = False

    def _drop(self) -> None:
        self._gone = True
        with contextlib.suppress(OSError, ValueError):
            # later flushes (also the interpreter's at exit) then write to nowhere
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)

    def write(self, text: str) -> int:
        if not self._gone:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._drop()
        return len(text)

    def flush(self) -> None:
        if not self._gone:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._drop()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextlib.contextmanager
def closed_pipe_safe_stdout() -> Iterator[None]:
    """Standard output as :class:`ClosedPipeSafe` while the block runs."""
    stream = sys.stdout
    sys.stdout = ClosedPipeSafe(stream)
    try:
        yield
    finally:
        sys.stdout.flush()
        sys.stdout = stream
