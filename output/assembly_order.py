"""The threading order of the assembly guide: where the string comes up out of the top faces
(the lift points, lettered A, B, ...) and the order of the route steps, started at a lift point
so that the string's two ends stand up there.

``assembly.md``, its pictures and the report's assembly steps all take their order from
:func:`plan_guide`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.paths import SIDE_TOP_FACE, lift_path


@dataclass(frozen=True)
class Stop:
    """A lift point of the assembly guide: the string comes up out of a top face and goes back
    down into the next tile's top face.

    Step indices count guide steps (threading order).  ``out_step`` leaves its tile through the
    top face (up the lift bore from side ``out_side``, or ``SIDE_TOP_FACE`` straight), and
    ``in_step`` comes back down into its tile (the bore to side ``in_side``); either is None
    when the route has no such step.  At the ``tails`` stop the string's two ends stand up.
    """

    letter: str
    out_step: int | None
    out_side: int
    in_step: int | None
    in_side: int
    tails: bool


@dataclass(frozen=True)
class Guide:
    """The threading order of the assembly guide.

    ``order[g]`` is the route step (``route.json`` index) threaded as guide step ``g + 1``; the
    closed route is started at a lift point, so that both string ends stand up there.
    ``spare`` lists lift bores ``(tile, side)`` the string does not pass.
    """

    order: list[int]
    stops: list[Stop]
    spare: list[tuple[int, int]]


def plan_guide(steps: NDArray[np.int64], lifts: NDArray[np.int64]) -> Guide:
    """Where the string leaves the top faces, and the threading order starting at one of them.

    A route step may leave or enter through the top face itself (``SIDE_TOP_FACE``), or a lift
    bore ``(tile, side)`` joins the side the step leaves by (entering by, for the next step) to
    the top face: the string goes up out of one tile and back down into the next.
    """
    count = len(steps)
    bores = {(int(t), int(s)) for t, s in lifts}
    used: set[tuple[int, int]] = set()
    raw: list[tuple[int | None, int, int | None, int]] = []
    back_in: set[int] = set()
    for i in range(count):
        j = (i + 1) % count
        _, tile, enter, leave = (int(v) for v in steps[i])
        _, after, after_enter, after_leave = (int(v) for v in steps[j])
        if leave == SIDE_TOP_FACE:
            out_side = SIDE_TOP_FACE
        elif (tile, leave) in bores and count > 1:
            out_side = leave
            used.add((tile, leave))
        else:
            continue
        in_step: int | None = None
        in_side = -1
        if after_enter == SIDE_TOP_FACE:
            in_step, in_side = j, SIDE_TOP_FACE
        elif (after, after_enter) in bores:
            in_step, in_side = j, after_enter
            used.add((after, after_enter))
        if in_step is not None:
            back_in.add(in_step)
        raw.append((i, out_side, in_step, in_side))
    for j in range(count):
        if int(steps[j, 2]) == SIDE_TOP_FACE and j not in back_in:
            raw.append((None, -1, j, SIDE_TOP_FACE))
    starts = sorted(s for _, _, s, _ in raw if s is not None)
    first = 0 if not starts or 0 in starts else starts[0]
    order = [(first + g) % count for g in range(count)]

    def guide_step(index: int | None) -> int | None:
        return None if index is None else (index - first) % count

    moved = [(guide_step(o), out_side, guide_step(s), in_side) for o, out_side, s, in_side in raw]
    moved.sort(key=lambda m: (m[2] != 0, m[0] if m[0] is not None else -1))
    stops = [
        Stop(stop_label(k), o, out_side, s, in_side, tails=s == 0)
        for k, (o, out_side, s, in_side) in enumerate(moved)
    ]
    spare = sorted(bores - used)
    return Guide(order, stops, spare)


def stop_label(index: int) -> str:
    """A, B, ..., Z, AA, AB, ...: the name of stop ``index`` (from 0)."""
    label = ""
    index += 1
    while index:
        index, rest = divmod(index - 1, 26)
        label = chr(ord("A") + rest) + label
    return label


def stop_positions(
    tiles: NDArray[np.float64], steps: NDArray[np.int64], guide: Guide, stop: Stop
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """(3,) float, mm: where the string comes up at ``stop`` and where it goes back down."""
    points: list[NDArray[np.float64] | None] = []
    for index, side, column in ((stop.out_step, stop.out_side, 2), (stop.in_step, stop.in_side, 3)):
        if index is None:
            points.append(None)
            continue
        row = steps[guide.order[index]]
        bore = int(row[column]) if side == SIDE_TOP_FACE else side
        points.append(lift_path(tiles[int(row[1])], bore).arc[2])
    return points[0], points[1]
