"""Output that native libraries print themselves, kept off the terminal.

Native code writes to the process's file descriptors, past Python's ``sys.stdout`` and
``sys.stderr``: scipy's bundled HiGHS prints
``HighsMipSolverData::transformNewIntegerFeasibleSolution tmpSolver.run();`` with C ``printf``
whatever its ``disp`` option says.  :func:`native_output_silenced` points the descriptors at
the null device while such a library runs, unless INFO logging is on (the command line's
``-v``), where solver detail may help.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
from collections.abc import Iterator
from typing import Any

#: Standard output and standard error, as file descriptors.
STDOUT_FD = 1
STDERR_FD = 2


def _flush_c_streams() -> None:
    """Flush C's stdio buffers (what native code printed is written out, or dropped, now)."""
    with contextlib.suppress(OSError, AttributeError):
        libc: Any = ctypes.CDLL(None)
        libc.fflush(None)


@contextlib.contextmanager
def native_output_silenced(fds: tuple[int, ...] = (STDOUT_FD, STDERR_FD)) -> Iterator[None]:
    """File descriptors ``fds`` on the null device meanwhile, C buffers flushed before they
    are put back; left alone with INFO logging on (``-v``).

    Python code that prints meanwhile to the same descriptors is silenced too: keep the block
    to the library call (standard error), or to work that never prints to them (standard
    output, which drawstring's library never writes).
    """
    if logging.getLogger().isEnabledFor(logging.INFO):
        yield
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _flush_c_streams()
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        yield
        return
    saved: list[tuple[int, int]] = []
    try:
        for fd in fds:
            with contextlib.suppress(OSError):
                saved.append((fd, os.dup(fd)))
                os.dup2(devnull, fd)
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        _flush_c_streams()
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)
