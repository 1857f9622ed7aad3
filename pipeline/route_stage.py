"""The string route of a design: its lift gaps served, and the deployment check the lift-point
sweep runs on each lift set (paper sections 5.2 and 5.3).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.route.lift import nearby_lift_gaps
from drawstring.geometry.route.plan import plan_route
from drawstring.geometry.route.result import Route
from drawstring.geometry.tiling.linkage import Linkage


@dataclass(frozen=True)
class NamedCheck:
    """A deployment check ``check(lift_gaps) -> bool`` with the name design.json reports."""

    name: str
    check: Callable[[NDArray[np.int64]], bool]

    def __call__(self, lift_gaps: NDArray[np.int64]) -> bool:
        return bool(self.check(lift_gaps))


#: Hops (between gaps that share a tile) a lift point the string cannot reach may move to a
#: gap it can reach.
LIFT_MOVE_HOPS = 2

#: Candidate gaps tried with a new route each (gaps the route already passes cost nothing).
LIFT_MOVE_TRIES = 3


def _route_relaxing_splits(
    linkage: Linkage, flat_gap_xy: NDArray[np.float64], lift_gaps: NDArray[np.int64]
) -> tuple[Route, str | None]:
    route = plan_route(linkage, flat_gap_xy, lift_gaps)
    if len(route.lifts_missed):
        # The paper's rule keeps the string off split gaps except between boundary tiles; in a
        # narrow part that can leave a lift point unreachable.  Passing a split gap between two
        # tiles on the same side of the cut does not cross it.
        relaxed = plan_route(linkage, flat_gap_xy, lift_gaps, split_rule="same-component")
        if len(relaxed.lifts_missed) < len(route.lifts_missed):
            return relaxed, (
                "route: reached every lift point by letting the string pass split gaps "
                "between tiles on the same side of a cut"
                if not len(relaxed.lifts_missed)
                else "route: reached more lift points by letting the string pass split gaps "
                "between tiles on the same side of a cut"
            )
    return route, None


def plan_lift_route(
    linkage: Linkage, flat_gap_xy: NDArray[np.float64], lift_gaps: NDArray[np.int64]
) -> tuple[Route, str | None, NDArray[np.int64]]:
    """The string route through the boundary and the lift gaps, a note on what it had to
    relax, and the lift gaps it serves.

    A lift gap the route cannot reach (a narrow part, where a detour to it would need a gap or
    tile twice) moves to the nearest interior gap of its part within ``LIFT_MOVE_HOPS`` that
    the route passes anyway, or else that a new route reaches: a lift point next to the energy
    peak lifts nearly as well, one the string misses does not lift at all.
    """
    lifts = np.asarray(lift_gaps, dtype=np.int64)
    route, note = _route_relaxing_splits(linkage, flat_gap_xy, lifts)
    moves: list[str] = []
    for gap in route.lifts_missed.tolist():
        used = lifts.tolist()
        options = [
            int(c)
            for c in nearby_lift_gaps(linkage, gap, flat_gap_xy, LIFT_MOVE_HOPS)
            if int(c) not in used
        ]
        passed = set(route.gaps.tolist())
        pick = next((c for c in options if c in passed), None)
        if pick is not None:
            route = replace(route, lifts_missed=route.lifts_missed[route.lifts_missed != gap])
        else:
            for option in options[:LIFT_MOVE_TRIES]:
                trial = np.array([option if g == gap else g for g in used], dtype=np.int64)
                new_route, new_note = _route_relaxing_splits(linkage, flat_gap_xy, trial)
                if option not in new_route.lifts_missed.tolist() and len(
                    new_route.lifts_missed
                ) < len(route.lifts_missed):
                    route, note, pick = new_route, new_note, option
                    break
        if pick is None:
            continue
        lifts = np.array([pick if g == gap else g for g in lifts.tolist()], dtype=np.int64)
        hops = "one tile" if pick in nearby_lift_gaps(linkage, gap, flat_gap_xy, 1) else "two tiles"
        moves.append(f"gap {gap} to gap {pick} ({hops} away)")
    if moves:
        moved = (
            "lift points: the string cannot reach the energy peak's gap under the routing rules, "
            f"so the lift point moved: {'; '.join(moves)}"
        )
        note = f"{note}; {moved}" if note else moved
    return route, note, lifts
