"""Exit statuses of the ``drawstring`` command: 0 written, within the profile's fabrication
tolerance and deploying, 1 a bug in drawstring, 2 bad input, 3 written with problems, 4 (only
with ``--strict``) a design that misses a quality target or lists any warning, 130 Ctrl-C."""

from __future__ import annotations

#: A bug in drawstring (:class:`InternalError`): one line, the traceback under ``-v``.
EXIT_INTERNAL = 1
#: Input drawstring refuses (:class:`InputError`): one line naming the problem and the fix.
EXIT_INPUT = 2
#: A written design with problems (listed under ``problems``): it does not deploy in the
#: simulation, its route crosses itself, tiles overlap or interpenetrate, solids are invalid,
#: or a flat, hinge or contact measure is over the profile's ``design.tolerance_mm``.
EXIT_DESIGN = 3
#: Only with ``--strict``: the design was written and has no problems, but misses a quality
#: target (flat edge error or hinge gap over 1e-3 mm, :meth:`Design.layout_misses`, or the
#: fit) or lists any other warning (an unreachable lift point, a loose linkage, the string's
#: friction).
EXIT_WARNINGS = 4
#: Ctrl-C: 128 + SIGINT, as a shell reports a process that SIGINT ended.
EXIT_INTERRUPTED = 130
