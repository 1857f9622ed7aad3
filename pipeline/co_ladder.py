"""The co-optimizations of one tiling in turn: conical with each weight, then without.

With bottom hinges the layout stage co-optimizes the assembled top with the flat layout under
the conical condition (each of :attr:`~.policy.LayoutPolicy.conical_weights` in turn) and,
where every weight misses the flat targets, without it.  :class:`CoLadder` runs them in turn
and runs the last one ahead in a forked child where a core is spare
(:attr:`~.policy.LayoutPolicy.co_speculate`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.tolerances import FLAT_EDGE_ERROR_TOL_MM
from drawstring.geometry.flat.layout import FlatResult
from drawstring.pipeline.ahead import Ahead
from drawstring.pipeline.policy import DEFAULT_POLICY, LayoutPolicy
from drawstring.pipeline.record import Progress

logger = logging.getLogger(__name__)

__all__ = ["CoLadder"]

#: One co-optimization of :class:`CoLadder`: conical or not, and the conical weight.
_Step = tuple[bool, float | None]
_Outcome = tuple[AssembledResult, FlatResult, dict[str, Any], bool]


class CoLadder:
    """The co-optimizations of one tiling in turn: with bottom hinges (``conical``) conical
    with each weight of ``policy.conical_weights`` until one meets the flat targets, and if
    none does, without the condition; without bottom hinges only the run without it.

    With ``ahead``, the run without the condition is computed meanwhile in a forked child
    (:class:`~drawstring.pipeline.ahead.Ahead`, which yields the cores to this process),
    and taken from it if it is needed.  Every run depends on the tiling's plain layout alone,
    so the outcome is the one of the runs in turn.  Where the first weight meets the targets
    (most designs) the child is stopped and its work thrown away; where the conical runs miss,
    the wait for the last run is cut by the time they took.  Only the last run goes ahead, so
    that one child has the spare core to itself.  Without ``ahead`` but with
    ``core_freed`` (another process lays out a tiling and holds the spare core), :meth:`poll`,
    called between rounds, starts that child once ``core_freed()`` says the core is spare.
    """

    def __init__(
        self,
        run: Callable[[_Step], _Outcome],
        conical: bool,
        ahead: bool,
        core_freed: Callable[[], bool] | None = None,
        *,
        policy: LayoutPolicy = DEFAULT_POLICY,
    ) -> None:
        self._run = run
        self._policy = policy
        weights = policy.conical_weights
        self.steps: list[_Step] = [(True, w) for w in weights] if conical else []
        self.steps.append((False, None))
        self._ahead = ahead and policy.co_speculate
        self._children: dict[int, Ahead[_Outcome]] = {}
        #: whether a core that another process held (a tiling laid out ahead) is spare now
        self._core_freed = core_freed
        self._current = 0
        #: the step :meth:`run` runs next, and whether a far miss skipped the other weights
        self._next, self._retries_skipped, self._finished = 0, False, False
        #: the last :meth:`run` paused after a miss (``pause_after_miss``)
        self.paused = False
        #: why the last step that missed the flat targets missed them ("" while none has)
        self.missed = ""

    def poll(self) -> None:
        """Between the rounds of a run: once the core another process held is spare
        (``core_freed``), start the last step ahead, as where it was spare from the start (a
        tighter tiling laid out ahead can be done while this tiling's conical runs go on)."""
        if self._ahead or self._core_freed is None or not self._policy.co_speculate:
            return
        if not self._core_freed():
            return
        self._core_freed = None
        self._ahead = True
        self._start_ahead(self._current)

    def run(
        self, far_mm: float | None = None, pause_after_miss: bool = False
    ) -> tuple[AssembledResult, FlatResult, dict[str, Any], bool, str]:
        """The outcome (assembled, flat, co-optimization block, full run owed) and a note
        when the conical condition was given up.  ``far_mm``: a tiling that may still be
        split gives the weights up after a miss by more than that (see
        ``policy.conical_retry_far``).
        With ``pause_after_miss``, a step that misses the flat targets and is not the last
        ends the call with its own outcome and :attr:`paused` set: a later call goes on with
        the next step (the work run ahead meanwhile goes on too), or :meth:`cancel` stops it.
        A ladder runs to its end once: a call after that is refused."""
        if self._finished:
            raise RuntimeError("this co-optimization ladder has run to its end already")
        self.paused = False
        try:
            while True:
                i = self._next
                conical, weight = self.steps[i]
                assembled, flat, block, skipped = self._step(i)
                last = i == len(self.steps) - 1
                if last or (block["accepted"] and flat.edge_error_max_mm <= FLAT_EDGE_ERROR_TOL_MM):
                    break
                self.missed = block["reason"] or (
                    f"its flat edge error {flat.edge_error_max_mm:.3g} mm exceeds "
                    f"{FLAT_EDGE_ERROR_TOL_MM:g} mm"
                )
                logger.info("conical co-optimization (weight %g) missed (%s)", weight, self.missed)
                i, without = i + 1, len(self.steps) - 1
                if block.get("joint_refused") and not self._policy.conical_retry_joint_miss:
                    i = without
                elif (
                    self._policy.conical_retry_far
                    and far_mm is not None
                    and i < without  # a weight is left
                    and block["accepted"]  # (a refused run hands back the plain layout)
                    and flat.edge_error_max_mm > far_mm
                ):
                    # A tiling that may still be split tries no further weight after a miss
                    # this far off (``policy.conical_retry_far``): it is tiled again, and laid
                    # out in full if kept after all.
                    self._retries_skipped, i = True, without
                if i == without:
                    logger.info("conical co-optimization missed (%s): again without", self.missed)
                self._next = i
                if pause_after_miss:
                    self.paused = True
                    return assembled, flat, block, skipped, ""
        except BaseException:
            self.cancel()
            raise
        self.cancel()  # whatever runs ahead is not needed now
        self._finished = True
        note = ""
        if i > 0 and not self.steps[i][0]:  # went without the conical condition
            skipped = skipped or self._retries_skipped
            note = (
                f"co-optimized without the conical condition ({self.missed} with it): the "
                "bottom hinges meet seen from above, and in depth only as the tiles' "
                "thicknesses allow"
            )
        return assembled, flat, block, skipped, note

    @property
    def running_ahead(self) -> bool:
        """Whether a step runs ahead in a child now (it takes a core)."""
        return bool(self._children)

    def cancel(self) -> None:
        """Stop the work run ahead (a paused ladder that is not gone on with)."""
        for child in self._children.values():
            child.cancel()
        self._children.clear()

    def _step(self, i: int) -> _Outcome:
        """Step ``i``: from its child if one computed it, else here (with the last step
        started meanwhile in a child)."""
        for j in [j for j in self._children if j < i]:  # skipped
            self._children.pop(j).cancel()
        child = self._children.get(i)
        if child is not None:
            outcome = child.result(Progress(quiet=True))
            del self._children[i]  # only now: run() stops it if the wait is interrupted
            if outcome is not None:
                return outcome
        self._current = i
        self.poll()
        self._start_ahead(i)
        return self._run(self.steps[i])

    def _start_ahead(self, i: int) -> None:
        """With a spare core, the last step started in a child while step ``i`` runs here."""
        if not self._ahead:
            return
        for j in range(max(i + 1, len(self.steps) - 1), len(self.steps)):
            if j not in self._children:
                what = f"the co-optimization {_step_name(self.steps[j])} run ahead"
                try:
                    self._children[j] = Ahead(
                        self._work(self.steps[j]), what, niceness=self._policy.ahead_niceness
                    )
                except OSError as exc:  # no process to spare (fork refused)
                    logger.warning("could not start %s (%s): running it in turn", what, exc)
                    self._ahead = False

    def _work(self, step: _Step) -> Callable[[Progress], _Outcome]:
        def work(progress: Progress) -> _Outcome:
            # in the child: no children of its own (polls between its rounds find none)
            self._ahead, self._core_freed = False, None
            return self._run(step)

        return work


def _step_name(step: _Step) -> str:
    return f"with conical weight {step[1]:g}" if step[0] else "without the conical condition"
