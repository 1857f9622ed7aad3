"""The tiling laid out ahead in a forked child process (pipeline/ahead.py)."""

from __future__ import annotations

import multiprocessing
import os
import sys

import pytest

from drawstring.pipeline.ahead import Ahead
from drawstring.pipeline.policy import DEFAULT_POLICY
from drawstring.pipeline.record import Progress

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods(),
    reason="laid out ahead only where processes fork (Linux)",
)


def test_the_child_yields_the_cores_to_the_parent() -> None:
    # Its result is often not needed: it runs at a lower priority than the parent.
    parent = os.nice(0)
    ahead: Ahead[int] = Ahead(lambda progress: os.nice(0))
    assert ahead.result(Progress(quiet=True)) == min(parent + DEFAULT_POLICY.ahead_niceness, 19)
    assert os.nice(0) == parent
    # as nice as the policy says
    gentle: Ahead[int] = Ahead(lambda progress: os.nice(0), niceness=3)
    assert gentle.result(Progress(quiet=True)) == min(parent + 3, 19)


def test_a_child_that_fails_gives_no_result() -> None:
    def fails(progress: Progress) -> int:
        raise RuntimeError("out of memory")

    assert Ahead(fails).result(Progress(quiet=True)) is None


def test_a_child_is_ready_once_its_work_is_done() -> None:
    go = multiprocessing.get_context("fork").Event()  # (inherited by the forked child)

    def waits(progress: Progress) -> int:
        assert go.wait(60.0), "the test never let the child go on"
        return 7

    ahead: Ahead[int] = Ahead(waits)
    assert not ahead.ready()  # still working
    go.set()
    ahead._child.receive.poll(30.0)  # (the test's own wait: the child sends when done)
    assert ahead.ready()
    assert ahead.result(Progress(quiet=True)) == 7
    assert ahead.ready()  # collected: it holds no core
