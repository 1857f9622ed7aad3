"""The retry search's bisections (:mod:`drawstring.pipeline.retry`) on checks with known
answers: the value quoted passes, is the nearest two-digit one, and the search gives up where
nothing passes or the check budget is spent."""

from __future__ import annotations

from drawstring.pipeline.retry import _search_down, _search_tiles, _search_up


def counting(check):  # type: ignore[no-untyped-def]
    calls: list[float] = []

    def passes(value: float) -> bool | None:
        calls.append(value)
        return check(value)

    return passes, calls


def test_search_up_finds_the_smallest_two_digit_size_that_passes() -> None:
    passes, calls = counting(lambda s: s >= 233.0)
    assert _search_up(passes, 160.0, 450.0) == 240.0  # 233 rounded up to two digits
    assert calls and all(v < 233.0 for v in calls if v != 240.0)  # only failing values below
    # nothing up to the limit passes: no value
    assert _search_up(lambda s: s >= 500.0, 160.0, 450.0) is None
    # the budget spent (None) before any pass: no value quoted
    assert _search_up(lambda s: None, 160.0, 450.0) is None


def test_search_down_finds_the_largest_two_digit_thickness_that_passes() -> None:
    assert _search_down(lambda t: t <= 4.23, 6.0, 3.6) == 4.2
    assert _search_down(lambda t: t <= 3.0, 6.0, 3.6) is None  # not even the floor passes


def test_search_tiles_finds_nearly_the_most_tiles_that_pass() -> None:
    found = _search_tiles(lambda n: n <= 137, 200, 50)
    assert found is not None and found <= 137 and 137 - found <= max(1, found // 20)
    assert _search_tiles(lambda n: n <= 40, 200, 50) is None  # the fewest allowed fails
    assert _search_tiles(lambda n: True, 50, 50) is None  # no fewer tiles to try
