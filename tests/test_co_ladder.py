"""The co-optimizations of one tiling in turn (pipeline/co_ladder.py), on stand-in runs."""

from __future__ import annotations

import multiprocessing
import sys
import time
from types import SimpleNamespace

import pytest

from drawstring.pipeline import co_ladder
from drawstring.pipeline.co_ladder import CoLadder
from drawstring.pipeline.policy import DEFAULT_POLICY

TOL = co_ladder.FLAT_EDGE_ERROR_TOL_MM
FIRST, RETRY = DEFAULT_POLICY.conical_weights[:2]
#: a test of work run ahead in forked children
FORKS = pytest.mark.skipif(
    not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods(),
    reason="runs ahead only where processes fork",
)


def _runs(errors: dict, joint: frozenset = frozenset(), refused: frozenset = frozenset()):
    """A stand-in co-optimization: ``errors[step]`` is the flat edge error it ends with
    (accepted), ``joint`` the steps refused for their first joint solve, ``refused`` those
    refused otherwise (both hand back that error as the plain layout's).  Returns it and the
    steps it ran."""
    ran: list = []

    def run(step):
        ran.append(step)
        error = errors[step]
        block = {"accepted": step not in joint | refused, "reason": "", "steps": 1}
        if step in joint:
            block.update(reason="the joint solve did not lower it", joint_refused=True)
        elif step in refused:
            block.update(reason="it broke a bound")
        return f"assembled {step}", SimpleNamespace(edge_error_max_mm=error), block, False

    return run, ran


def test_a_design_without_bottom_hinges_is_co_optimized_once() -> None:
    run, ran = _runs({(False, None): 0.5 * TOL})
    assembled, flat, block, skipped, note = CoLadder(run, False, False).run()
    assert ran == [(False, None)] and not note and not skipped
    assert assembled == "assembled (False, None)"


def test_the_weights_are_tried_in_turn_then_without_the_condition() -> None:
    met = {(True, FIRST): 2 * TOL, (True, RETRY): 0.5 * TOL, (False, None): 0.1 * TOL}
    run, ran = _runs(met)
    *_, note = CoLadder(run, True, False).run()
    assert ran == [(True, FIRST), (True, RETRY)] and not note
    missed = {**met, (True, RETRY): 3 * TOL}
    run, ran = _runs(missed)
    assembled, flat, block, skipped, note = CoLadder(run, True, False).run()
    assert ran == [(True, FIRST), (True, RETRY), (False, None)]
    assert flat.edge_error_max_mm == 0.1 * TOL and not skipped
    assert "without the conical condition" in note and f"{3 * TOL:.3g} mm exceeds" in note


def test_a_refused_joint_solve_or_a_far_miss_ends_the_weights() -> None:
    errors = {(True, FIRST): 0.3, (True, RETRY): 0.5 * TOL, (False, None): 0.1 * TOL}
    run, ran = _runs(errors, joint=frozenset({(True, FIRST)}))
    *_, note = CoLadder(run, True, False).run()
    assert ran == [(True, FIRST), (False, None)] and "joint solve" in note
    # a far miss ends them only where the caller gives a bound (a tiling that may be split),
    # and a full run is then owed
    run, ran = _runs(errors)
    _, _, _, skipped, _ = CoLadder(run, True, False).run(far_mm=4 * TOL)
    assert ran == [(True, FIRST), (False, None)] and skipped
    run, ran = _runs(errors)
    _, _, _, skipped, _ = CoLadder(run, True, False).run()
    assert ran == [(True, FIRST), (True, RETRY)] and not skipped
    # a refused run hands back the plain layout, whose error says nothing of how near it came
    run, ran = _runs(errors, refused=frozenset({(True, FIRST)}))
    CoLadder(run, True, False).run(far_mm=4 * TOL)
    assert ran == [(True, FIRST), (True, RETRY)]


def test_a_far_miss_at_the_last_weight_skips_nothing() -> None:
    # every weight was tried: no full run is owed for the tiling
    errors = {(True, FIRST): 2 * TOL, (True, RETRY): 0.5, (False, None): 0.1 * TOL}
    run, ran = _runs(errors)
    _, _, _, skipped, note = CoLadder(run, True, False).run(far_mm=4 * TOL)
    assert ran == [(True, FIRST), (True, RETRY), (False, None)]
    assert not skipped and "without the conical condition" in note


@FORKS
def test_the_run_without_the_condition_is_taken_from_its_child(tmp_path) -> None:
    errors = {(True, FIRST): 2 * TOL, (True, RETRY): 2 * TOL, (False, None): 0.1 * TOL}
    run, ran = _runs(errors)
    assembled, flat, *_ = CoLadder(run, True, True).run()
    assert ran == [(True, FIRST), (True, RETRY)]  # the last one ran in the child
    assert assembled == "assembled (False, None)" and flat.edge_error_max_mm == 0.1 * TOL
    assert multiprocessing.active_children() == []
    # where the first weight meets the targets, the child is stopped, not waited for: a
    # child left to finish would leave its mark
    errors[(True, FIRST)] = 0.5 * TOL
    run, ran = _runs(errors)
    finished = tmp_path / "finished"

    def slow_without(step):
        if not step[0]:
            time.sleep(20.0)
            finished.touch()
        return run(step)

    assembled, *_ = CoLadder(slow_without, True, True).run()
    assert ran == [(True, FIRST)] and assembled == f"assembled {(True, FIRST)}"
    assert multiprocessing.active_children() == [] and not finished.exists()

    # and so it is when the run here fails
    def fails(step):
        if step[0]:
            raise RuntimeError("no memory")
        return slow_without(step)

    with pytest.raises(RuntimeError):
        CoLadder(fails, True, True).run()
    assert multiprocessing.active_children() == [] and not finished.exists()


@FORKS
def test_a_core_freed_during_a_run_starts_the_last_step_ahead_from_then() -> None:
    # Another process (a tiling laid out ahead) held the spare core; once it is done, the
    # polls between rounds start the run without the condition in a child, whose own polls
    # start nothing.
    errors = {(True, FIRST): 2 * TOL, (True, RETRY): 2 * TOL, (False, None): 0.1 * TOL}
    base, ran = _runs(errors)
    freed = {"now": False}
    started: list[list[int]] = []

    def run(step):
        ladder.poll()
        started.append(sorted(ladder._children))
        if step == (True, FIRST):
            freed["now"] = True  # the other process is done during this run
            ladder.poll()
            started.append(sorted(ladder._children))
        assembled, flat, block, skipped = base(step)
        return f"{assembled}, children {sorted(ladder._children)}", flat, block, skipped

    ladder = CoLadder(run, True, False, core_freed=lambda: freed["now"])
    assembled, flat, *_ = ladder.run()
    assert ran == [(True, FIRST), (True, RETRY)]  # the last one ran in the child
    assert started == [[], [2], [2]]  # nothing before the core was freed, then the last step
    # taken from the child, which started no child of its own
    assert assembled == "assembled (False, None), children []"
    assert flat.edge_error_max_mm == 0.1 * TOL
    assert multiprocessing.active_children() == []
    # a core never freed: every step here, in turn
    base, ran = _runs(errors)
    freed["now"] = False
    started.clear()

    def never(step):
        ladder.poll()
        return base(step)

    ladder = CoLadder(never, True, False, core_freed=lambda: False)
    ladder.run()
    assert ran == [(True, FIRST), (True, RETRY), (False, None)]


def test_a_ladder_paused_after_a_miss_goes_on_as_if_it_had_not_paused() -> None:
    # paused after the first weight's miss, with that run's outcome; the next call goes on
    # from the next step, and ends as the ladder run straight through does
    errors = {(True, FIRST): 2 * TOL, (True, RETRY): 3 * TOL, (False, None): 0.1 * TOL}
    run, ran = _runs(errors)
    straight = CoLadder(run, True, False).run()
    run, ran = _runs(errors)
    ladder = CoLadder(run, True, False)
    assembled, flat, *_ = ladder.run(pause_after_miss=True)
    assert ladder.paused and ran == [(True, FIRST)]
    assert flat.edge_error_max_mm == 2 * TOL and f"{2 * TOL:.3g} mm exceeds" in ladder.missed
    assembled, flat, block, skipped, note = ladder.run()
    assert not ladder.paused and ran == [(True, FIRST), (True, RETRY), (False, None)]
    assert (assembled, flat.edge_error_max_mm, block, skipped, note) == (
        straight[0], straight[1].edge_error_max_mm, *straight[2:],
    )  # fmt: skip
    # a far miss pauses too, and the run going on keeps its skipped weights and owed run
    run, ran = _runs({**errors, (True, FIRST): 0.5})
    ladder = CoLadder(run, True, False)
    ladder.run(far_mm=4 * TOL, pause_after_miss=True)
    assert ladder.paused
    *_, skipped, note = ladder.run(far_mm=4 * TOL)
    assert ran == [(True, FIRST), (False, None)] and skipped and "0.5 mm exceeds" in note
    # a first weight that meets the targets ends the ladder: nothing to pause
    run, ran = _runs({**errors, (True, FIRST): 0.5 * TOL})
    ladder = CoLadder(run, True, False)
    ladder.run(pause_after_miss=True)
    assert not ladder.paused and ran == [(True, FIRST)]


@FORKS
def test_a_paused_ladder_keeps_its_child_until_it_goes_on_or_is_cancelled(tmp_path) -> None:
    errors = {(True, FIRST): 2 * TOL, (True, RETRY): 2 * TOL, (False, None): 0.1 * TOL}
    base, ran = _runs(errors)
    finished = tmp_path / "finished"
    go = multiprocessing.get_context("fork").Event()  # (inherited by the forked children)

    def run(step):
        if not step[0]:  # the step run ahead: it ends once let go, and leaves a mark then
            if go.wait(60.0):
                finished.write_text("done")
        return base(step)

    ladder = CoLadder(run, True, True)
    ladder.run(pause_after_miss=True)
    assert ladder.paused and ladder.running_ahead
    assert not finished.exists()  # the child goes on through the pause ...
    go.set()
    assembled, *_ = ladder.run()  # ... and is taken after it
    assert ran == [(True, FIRST), (True, RETRY)]  # the last one ran in the child
    assert assembled == "assembled (False, None)"
    assert finished.read_text() == "done" and multiprocessing.active_children() == []
    finished.unlink()
    go.clear()  # cancelled, the child is never let go to end its step
    base, ran = _runs(errors)
    ladder = CoLadder(run, True, True)
    ladder.run(pause_after_miss=True)
    assert ladder.paused and ladder.running_ahead
    ladder.cancel()
    assert not ladder.running_ahead and multiprocessing.active_children() == []
    assert not finished.exists()
    # a ladder that ran to its end is not run again
    base, ran = _runs({**errors, (True, FIRST): 0.5 * TOL})
    ladder = CoLadder(base, True, False)
    ladder.run()
    with pytest.raises(RuntimeError, match="run to its end"):
        ladder.run()
