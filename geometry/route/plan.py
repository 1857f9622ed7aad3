"""Closed minimum-turn string route through the boundary tiles and the lift points (section 5.3).

The route obeys the rules of :mod:`~drawstring.geometry.route.rules` (contact partners, each gap
and tile at most once, no crossing, the split rule) and passes every boundary tile and every lift
gap; :mod:`~drawstring.geometry.route.result` holds the :class:`Route` and its measures.

Objective: the total turn angle, at every gap the angle between the incoming and outgoing
direction through the flat-configuration gap centroids of predecessor, gap and successor (0 for
straight): the exponent of the capstan factor ``exp(mu * total)``.

Solvers.  ``"exact"`` is an integer program (``scipy.optimize.milp``, HiGHS) on the gap graph
whose edges carry their tile: binary edge, node and turn variables, where a turn is a pair of
edges at a gap whose tiles are contact partners there (so only partner-consistent turns exist),
one pass per tile, crossing-pair exclusions, and connectivity cuts added until one cycle
remains; HiGHS proves optimality within a node budget (:data:`MILP_NODE_LIMIT`: work, not
time, bounds every solve, so that the route is the same on every machine).  Large instances use
``"heuristic: boundary-DP + window-MILP"``: a dynamic program over the boundary tiles in their
order along the outer boundary (one step per tile, consecutive tiles partners, short bridges
through interior tiles where two consecutive boundary tiles are not partners) builds the
minimum-turn boundary loop; each lift gap not on it is spliced in by solving the same integer
program on a window (a stretch of the loop plus a corridor to the lift gap) with the rest of the
loop fixed, from the root node's best path (:data:`SPLICE_NODE_LIMITS`), growing the window
until it succeeds.  If the dynamic program's loop reuses a gap or a tile (a ring two
tiles wide), the integer program is solved on the band of tiles next to the boundary instead.
The heuristic's lower bound is ``2 pi`` (a simple closed polygon turns at least once around).

This module holds the solver entry point :func:`plan_route` and the route's assembly from the
solvers' steps.  The integer program is in :mod:`~drawstring.geometry.route.milp` and the loop
builders that call it (boundary DP, band program, lift splicing, whole-instance solve) are in
:mod:`~drawstring.geometry.route.loops`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import DesignError, InternalError
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.route.loops import (
    band_loop_any,
    boundary_loop_dp,
    boundary_tile_order,
    exact_loop,
    splice_lift,
)
from drawstring.geometry.route.milp import NodeBudgetError, RouteRules, Step, turn_angle
from drawstring.geometry.route.result import Route, channel_partner_faults, count_crossings
from drawstring.geometry.route.rules import SplitRule, check_positions, node_labels, route_rules
from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)

__all__ = [
    "EXACT_LIMIT_DEFAULT",
    "MILP_NODE_LIMIT",
    "SPLICE_NODE_LIMITS",
    "SPLICE_WINDOWS",
    "plan_route",
]

#: Largest number of gaps solved by the exact integer program by default.
EXACT_LIMIT_DEFAULT = 40
#: Branch-and-bound nodes of one whole-instance or band integer-program solve (HiGHS
#: ``mip_max_nodes``): a bound on work, not time, so that every machine stops a solve at the
#: same point and draws the same route (``milp.MILP_SAFETY_TIME_S`` is the time's).
MILP_NODE_LIMIT = 10_000
#: Windows tried in turn when splicing a lift gap into the loop: (loop gaps each side of the
#: loop gap nearest to the lift gap, corridor half-width in median gap spacings around the
#: segment to the lift gap).
SPLICE_WINDOWS: tuple[tuple[int, float], ...] = ((3, 2.0), (5, 3.0), (8, 4.5), (12, 6.5))
#: Node budgets of a window's integer program, tried in turn while the window neither yields a
#: path nor is proved to hold none: first the root node alone (with HiGHS's heuristics there),
#: then a few more.  A solve stopped at its budget with a valid path keeps it, not proven
#: optimal.  Most window programs finish at the root, and the largest keep the path found
#: there; a window whose root neither finds a path nor proves that none exists costs its root
#: twice.
SPLICE_NODE_LIMITS: tuple[int, ...] = (1, 16)


def _median_spacing(pos: FloatArray) -> float:
    if len(pos) < 2:
        return 1.0
    d, _ = cKDTree(pos).query(pos, k=2)
    return float(np.median(d[:, 1])) or 1.0


def plan_route(
    linkage: Linkage,
    gap_centroids_flat: ArrayLike,
    lift_gaps: ArrayLike = (),
    *,
    exact_limit: int = EXACT_LIMIT_DEFAULT,
    node_limit: int = MILP_NODE_LIMIT,
    split_rule: SplitRule = "boundary",
) -> Route:
    """Closed minimum-turn route through all boundary tiles and all lift gaps.

    Parameters
    ----------
    linkage : topology.
    gap_centroids_flat : (G, 2) float, mm, gap centroids in the flat configuration.
    lift_gaps : (k,) int, gaps the route must pass (lift points).
    exact_limit : solve the whole instance exactly when it has at most this many gaps;
        otherwise use the heuristic (boundary DP + exact windows around lift points).
    node_limit : branch-and-bound nodes of every whole-instance (or band) integer-program
        solve (the lift windows' are :data:`SPLICE_NODE_LIMITS`).
    split_rule : which crossings of a ``-2`` split gap are allowed (lift gaps are exempt):
        ``"boundary"`` (default, paper "Connecting splits"): only between two boundary tiles, so
        the string never runs into the interior through a gap on a cut; ``"same-component"``:
        also between two interior tiles on the same side of the cut (the string does not cross
        the cut there), which lets detours run along a cut in narrow components.

    Returns
    -------
    Route (``method`` says which solver ran; ``lower_bound_rad`` is the proven bound).  A lift
    gap the rules do not let the route reach is listed in ``lifts_missed`` with the reason in
    ``notes``.

    Raises
    ------
    DesignError
        When no closed route through the boundary tiles satisfies the rules (for instance a part
        of the boundary ring only two tiles wide, where both strands would cross the same gaps).
    """
    pos = check_positions(linkage, gap_centroids_flat)
    lifts = np.unique(np.asarray(lift_gaps, dtype=np.int64))
    if lifts.size and (lifts.min() < 0 or lifts.max() >= linkage.n_gaps):
        raise InternalError(f"lift gaps {lifts.tolist()} are not gap ids 0..{linkage.n_gaps - 1}")
    lift_set = {int(g) for g in lifts}
    rules = route_rules(linkage, lift_set, split_rule)
    cover = {int(t) for t in np.nonzero(linkage.boundary_tile)[0]}
    groups = [
        {int(t) for t in np.nonzero(linkage.tile_component == c)[0]}
        for c in range(linkage.n_components)
    ]
    notes: list[str] = []
    missed: list[int] = []
    for g in sorted(lift_set):
        if g not in rules.gap_tiles:
            missed.append(g)
            notes.append(f"lift gap {g} has no pair of contact partners the string may pass")
    reachable = lift_set - set(missed)
    if linkage.n_gaps <= exact_limit:
        steps, cost, optimal = exact_loop(
            rules, pos, linkage.n_gaps, reachable, cover, groups, node_limit, missed, notes
        )
        method = "exact" if optimal else "heuristic: MILP stopped at its node or time limit"
        bound = cost if optimal else 2 * math.pi
        return _finish(linkage, rules, pos, steps, method, bound, notes, missed)

    steps, method = _boundary_loop(linkage, rules, pos, cover, groups, node_limit, notes)
    spacing = _median_spacing(pos)
    for lift in sorted(reachable):
        if lift in {g for g, _ in steps}:
            continue
        spliced, reason = _splice_in_windows(
            linkage, rules, pos, steps, lift, cover, lift_set, spacing, notes
        )
        if spliced is not None:
            steps = spliced
        else:
            missed.append(lift)
            notes.append(
                f"lift gap {lift} could not be spliced into the route within the largest window"
                f" ({reason})"
            )
    comps = {int(linkage.tile_component[t]) for _, t in steps}
    if len(comps) < linkage.n_components:
        notes.append(f"route visits {len(comps)} of {linkage.n_components} split components")
    return _finish(linkage, rules, pos, steps, method, 2 * math.pi, notes, missed)


def _boundary_loop(
    linkage: Linkage,
    rules: RouteRules,
    pos: FloatArray,
    cover: set[int],
    groups: list[set[int]],
    node_limit: int,
    notes: list[str],
) -> tuple[list[Step], str]:
    """The heuristic's loop through every boundary tile, and the method's name: the boundary
    dynamic program's loop, or where that passes a gap or tile twice or misses a boundary tile
    (or finds none), the band program's (the reason goes to ``notes``)."""
    try:
        steps = boundary_loop_dp(rules, pos, boundary_tile_order(linkage), linkage.boundary_tile)
        gaps = [g for g, _ in steps]
        tiles = [t for _, t in steps]
        if len(set(gaps)) < len(gaps) or len(set(tiles)) < len(tiles):
            raise DesignError("its loop passes a gap or a tile twice")
        if not cover <= set(tiles):
            raise DesignError("its loop misses boundary tiles")
    except DesignError as err:
        notes.append(f"boundary DP failed ({err}); solved the boundary band exactly")
        band = band_loop_any(rules, pos, cover, groups, node_limit, notes)
        return band, "heuristic: band-MILP + window-MILP"
    parts = linkage.tile_component[np.array(tiles, dtype=np.int64)]
    if count_crossings(np.array(gaps, dtype=np.int64), pos, parts):
        # the DP joins its layers by turn cost alone: a loop that crosses itself goes to the
        # band program, which excludes crossing pairs (the DP's loop is kept, and its
        # crossing listed as a problem, only where the band has no loop)
        try:
            band = band_loop_any(rules, pos, cover, groups, node_limit, notes)
        except DesignError as err:
            notes.append(f"the boundary DP's loop crosses itself and the band has none ({err})")
        else:
            notes.append("the boundary DP's loop crossed itself; solved the boundary band exactly")
            return band, "heuristic: band-MILP + window-MILP"
    return steps, "heuristic: boundary-DP + window-MILP"


def _splice_in_windows(
    linkage: Linkage,
    rules: RouteRules,
    pos: FloatArray,
    steps: list[Step],
    lift: int,
    cover: set[int],
    lift_set: set[int],
    spacing: float,
    notes: list[str],
) -> tuple[list[Step] | None, str]:
    """The loop ``steps`` with ``lift`` spliced in, trying the :data:`SPLICE_WINDOWS` from the
    smallest and in each the :data:`SPLICE_NODE_LIMITS` in turn; None and the last reason when
    no window holds a path."""
    reason = ""
    for half_window, corridor in SPLICE_WINDOWS:
        for nodes in SPLICE_NODE_LIMITS:
            try:
                return splice_lift(
                    rules, pos, steps, lift, cover, lift_set, spacing, nodes,
                    half_window, corridor, linkage.tile_component, notes,
                ), reason  # fmt: skip
            except NodeBudgetError as err:  # more nodes may find a path in this window
                reason = str(err)
            except DesignError as err:  # this window holds none: a larger one
                reason = str(err)
                break
    return None, reason


def _side_facing(linkage: Linkage, tile: int, gap: int) -> int:
    sides = linkage.gap_sides[gap]
    hit = sides[sides[:, 0] == tile]
    return int(hit[0, 1]) if len(hit) else -1


def _finish(
    linkage: Linkage,
    rules: RouteRules,
    pos: FloatArray,
    steps: list[Step],
    method: str,
    lower_bound: float | None,
    notes: Sequence[str] = (),
    missed: Sequence[int] = (),
) -> Route:
    """The Route of a cyclic step list; sides come from the contact partners at each gap."""
    r = len(steps)
    gaps = np.array([g for g, _ in steps], dtype=np.int64)
    tiles = np.array([t for _, t in steps], dtype=np.int64)
    enter = -np.ones(r, dtype=np.int64)
    leave = -np.ones(r, dtype=np.int64)
    for k in range(r):
        g, prev, here = int(gaps[k]), int(tiles[k - 1]), int(tiles[k])
        sides = rules.sides.get((g, prev, here))
        if sides is None:  # not partners: keep the sides facing the gap so the fault shows
            sides = (_side_facing(linkage, prev, g), _side_facing(linkage, here, g))
        leave[k - 1], enter[k] = sides
    p = pos[gaps]
    total = float(turn_angle(np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0)).sum()) if r else 0.0
    covered = set(tiles.tolist()) >= set(np.nonzero(linkage.boundary_tile)[0].tolist())
    route = Route(
        gaps=gaps,
        labels=node_labels(linkage)[gaps],
        tiles=tiles,
        enter_side=enter,
        leave_side=leave,
        turn_angle_total_rad=total,
        method=method,
        lower_bound_rad=lower_bound,
        crossings=count_crossings(gaps, pos, linkage.tile_component[tiles]),
        boundary_tiles_covered=bool(covered),
        length_flat_mm=float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum()),
        tiles_passed_once=bool(len(np.unique(tiles)) == r),
        lifts_missed=np.array(sorted(missed), dtype=np.int64),
        notes=tuple(notes),
    )
    faults = channel_partner_faults(route, linkage)
    if faults.size:
        log.warning("string route: %d steps are not contact-partner crossings", faults.size)
    return dataclasses.replace(route, channel_partners_ok=not faults.size)
