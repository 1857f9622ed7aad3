"""Exit statuses of the ``drawstring`` command: 0 success, 1 a bug in drawstring, 2 bad input,
3 a design that misses a hard target, 4 a design that misses an accuracy target (or, with
``--strict``, lists any warning), 130 Ctrl-C."""

from __future__ import annotations

#: A bug in drawstring (:class:`InternalError`): one line, the traceback under ``-v``.
EXIT_INTERNAL = 1
#: Input drawstring refuses (:class:`InputError`): one line naming the problem and the fix.
EXIT_INPUT = 2
#: A design that misses a hard target (written, listed under ``problems``), or one that cannot
#: be made at all (:class:`DesignError`, nothing written).
EXIT_DESIGN = 3
#: The design was written and has no problems, but its flat layout misses an accuracy target
#: (flat edge error or hinge gap, seen from above or in depth, over 1e-3 mm,
#: :meth:`Design.layout_misses`); with ``--strict`` also any other warning (the surface
#: distance, a stuck simulation, an unreachable lift point, a loose linkage, the string's
#: friction).
EXIT_WARNINGS = 4
#: Ctrl-C: 128 + SIGINT, as a shell reports a process that SIGINT ended.
EXIT_INTERRUPTED = 130
