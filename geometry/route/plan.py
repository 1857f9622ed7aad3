"""Closed minimum-turn string route through the boundary tiles and the lift points (section 5.3).

Physics.  The string runs inside a tile from one side face to another and, in the assembled
state, passes straight into the neighbouring tile through the contact face the two tiles share.
In the flat state that crossing happens across exactly one gap: two edge-adjacent tiles share a
grid edge that has a hinge at one end and the slit (the gap) at the other, and the string
crosses at the slit end.  So at every gap the string can only pass between *contact partners*:
two tiles whose sides facing the gap are the same grid segment (same two grid vertices).  For a
horizontal gap (sides ``LL.top, LR.top, UR.bottom, UL.bottom``) the partners are (LL, UL) and
(LR, UR); for a vertical gap (LL, LR) and (UL, UR); at a two-tile boundary notch its two tiles;
at a three-tile notch the one pair whose sides face each other.  Across a split the two tiles of
a cut edge are unhinged, so the gaps at *both* ends of their shared segment may serve
(:func:`contact_partners`).

A route is a cyclic sequence of steps ``(gap g_k, tile t_k)``: the string crosses gap ``g_k``
into tile ``t_k``, runs through it and leaves it into gap ``g_{k+1}``.  Valid routes:

* consecutive tiles ``t_{k-1}, t_k`` are contact partners at ``g_k`` (the enter side of ``t_k``
  and the leave side of ``t_{k-1}`` are their shared segment);
* every gap at most once and every tile at most once (two strands in one void or one tile would
  cross or crowd), no two route segments crossing in the flat layout;
* every boundary tile (a tile with a vertex on the outer boundary) and every lift gap is passed;
  every split component is visited, which ties the components together;
* split rule (paper "Connecting splits"): at a ``-2`` split gap the string may only pass between
  two boundary tiles (it runs along the boundary across the cut); it never enters the interior
  through a cut.  A lift gap on a cut is exempt.

The gap graph (paper Fig. 8) has one node per gap labelled ``0`` vertical, ``1`` horizontal,
``-1`` boundary notch (the paper's virtual entrance: where the void opens to the outside) and
``-2`` split gap.  In the contact-partner model the string passes from the boundary ring to the
interior through the shared face of a boundary tile and an interior tile, i.e. across a four-tile
gap; "no gap or tile twice" is what keeps such detours from crossing the ring (paper Fig. 9).

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

This module holds the public side: the route rules (contact partners, gap graph), the solver
entry point :func:`plan_route`, the route's assembly and measurement, JSON and picture.  The
integer program is in :mod:`.route_milp` and the loop builders that call it (boundary DP, band
program, lift splicing, whole-instance solve) are in :mod:`.route_heuristics`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import networkx as nx
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import DesignError, InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.route.loops import (
    _band_loop_any,
    _boundary_loop_dp,
    _exact,
    _splice_lift,
    boundary_tile_order,
)
from drawstring.geometry.route.milp import (
    NodeBudgetError,
    Step,
    _Rules,
    _segments_cross,
    crossing_edge_pairs,
    turn_angle,
)
from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)

__all__ = [
    "EXACT_LIMIT_DEFAULT",
    "MILP_NODE_LIMIT",
    "NODE_ENTRANCE",
    "NODE_HORIZONTAL",
    "NODE_SPLIT",
    "NODE_VERTICAL",
    "SPLICE_NODE_LIMITS",
    "SPLICE_WINDOWS",
    "Route",
    "SplitRule",
    "Step",
    "boundary_tile_order",
    "channel_partner_faults",
    "channel_partners_ok",
    "contact_partners",
    "count_crossings",
    "crossing_edge_pairs",
    "gap_graph",
    "node_labels",
    "plan_route",
    "route_metrics",
    "route_to_json",
    "turn_angle",
]

NODE_VERTICAL, NODE_HORIZONTAL, NODE_ENTRANCE, NODE_SPLIT = 0, 1, -1, -2
_LABEL = {
    "vertical": NODE_VERTICAL,
    "horizontal": NODE_HORIZONTAL,
    "boundary": NODE_ENTRANCE,
    "split": NODE_SPLIT,
}

#: Largest number of gaps solved by the exact integer program by default.
EXACT_LIMIT_DEFAULT = 40
#: Branch-and-bound nodes of one whole-instance or band integer-program solve (HiGHS
#: ``mip_max_nodes``): a bound on work, not time, so that every machine stops a solve at the
#: same point and draws the same route (``route_milp.MILP_SAFETY_TIME_S`` is the time's).
MILP_NODE_LIMIT = 10_000
#: Windows tried in turn when splicing a lift gap into the loop: (loop gaps each side of the
#: loop gap nearest to the lift gap, corridor half-width in median gap spacings around the
#: segment to the lift gap).
SPLICE_WINDOWS: tuple[tuple[int, float], ...] = ((3, 2.0), (5, 3.0), (8, 4.5), (12, 6.5))
#: Node budgets of a window's integer program, tried in turn while the window neither yields a
#: path nor is proved to hold none: first the root node alone (with HiGHS's heuristics there),
#: then a few more.  A solve stopped at its budget with a valid path keeps it, not proven
#: optimal.  Measured on the eight built-ins (200 tiles and the CLI defaults, both hinge
#: strategies; 1600 tiles, dual hinges) and the three scans: all 41 routes are the ones the
#: 5 s time limits per window gave before.  Most window programs finish at the root; the
#: largest (1800-3700 variables: the face scan, the 1600-tile dome and wave) had kept the path
#: found there whether or not they reached the time limit, which they did after 2 to 11 nodes
#: or not, by the machine's speed.  Their route stages took 8.0, 5.1 and 5.1 s, now 7.5, 3.3
#: and 1.8 s.  A window whose root neither finds a path nor proves that none exists costs its
#: root twice (the face scan: 2.8 s, then 3.0 s to prove it).
SPLICE_NODE_LIMITS: tuple[int, ...] = (1, 16)


@dataclass(frozen=True)
class Route:
    """A closed string route.

    Attributes
    ----------
    gaps : (r,) int, the cyclic sequence of gaps (the route closes from the last to the first).
    labels : (r,) int, node label of each gap (0, 1, -1 entrance, -2 split).
    tiles : (r,) int, tile the string passes from ``gaps[k]`` to ``gaps[(k + 1) % r]``.
    enter_side : (r,) int, side (0 bottom, 1 right, 2 top, 3 left) of ``tiles[k]`` by which the
        string enters it from ``gaps[k]``: the segment it shares with ``tiles[k - 1]``.
    leave_side : (r,) int, side of ``tiles[k]`` by which it leaves into ``gaps[k + 1]``: the
        segment it shares with ``tiles[k + 1]``.
    turn_angle_total_rad : float, sum of the turn angles at all nodes (flat centroids).
    method : ``"exact"`` or ``"heuristic: <name>"``.
    lower_bound_rad : float or None, a proven lower bound on the optimum total turn.
    crossings : int, gaps visited twice plus pairs of route segments that intersect.
    boundary_tiles_covered : bool, measured: every boundary tile is some ``tiles[k]``.
    length_flat_mm : float, polyline length through the flat gap centroids.
    channel_partners_ok : bool, measured: every consecutive tile pair are contact partners at
        their gap (:func:`channel_partners_ok`).
    tiles_passed_once : bool, measured: no tile appears twice in ``tiles``.
    lifts_missed : (m,) int, lift gaps the route could not pass (reasons in ``notes``).
    notes : what the solver had to give up or work around.
    """

    gaps: IntArray
    labels: IntArray
    tiles: IntArray
    enter_side: IntArray
    leave_side: IntArray
    turn_angle_total_rad: float
    method: str
    lower_bound_rad: float | None
    crossings: int
    boundary_tiles_covered: bool
    length_flat_mm: float
    channel_partners_ok: bool = True
    tiles_passed_once: bool = True
    lifts_missed: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    notes: tuple[str, ...] = field(default=())


# --------------------------------------------------------------------------------------------
# gap graph and contact partners


def node_labels(linkage: Linkage) -> IntArray:
    """(G,) int label of every gap: 0 vertical, 1 horizontal, -1 entrance, -2 split."""
    return np.array([_LABEL[k] for k in linkage.gap_kind], dtype=np.int64)


def contact_partners(linkage: Linkage) -> IntArray:
    """Tile pairs the string may pass between, per gap.

    Two tiles are contact partners at gap ``g`` when their sides facing ``g`` are the same grid
    segment (the same two grid vertices): the string crosses ``g`` from one tile straight into
    the other through the contact face they share in the assembled state.  Sides facing a gap
    are those listed in ``linkage.gap_sides``; across a split, whose cut edges have no hinge,
    the sides along the cut also face the gaps at both ends of the cut edge.

    Returns
    -------
    (P, 5) int rows ``(gap, tile_a, side_a, tile_b, side_b)`` with ``tile_a < tile_b``, sorted.
    """
    corners = linkage.tile_corners
    rows: set[tuple[int, int, int, int, int]] = set()
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        segs = [
            frozenset((int(corners[t, s]), int(corners[t, (s + 1) % 4]))) for t, s in sides.tolist()
        ]
        for a in range(len(sides)):
            for b in range(a + 1, len(sides)):
                (ta, sa), (tb, sb) = sides[a].tolist(), sides[b].tolist()
                if ta != tb and segs[a] == segs[b]:
                    rows.add((g, ta, sa, tb, sb) if ta < tb else (g, tb, sb, ta, sa))
    if linkage.splits:
        gap_at_vertex = {int(v): g for g, v in enumerate(linkage.gap_vertex.tolist())}
        tile_at_cell = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
        # (side of t, neighbour offset, side of the neighbour)
        for t, (i, j) in enumerate(linkage.tile_cells.tolist()):
            for side, (di, dj), other_side in ((1, (1, 0), 3), (2, (0, 1), 0)):
                u = tile_at_cell.get((i + di, j + dj), -1)
                if u < 0 or not any(s.cuts((i, j), (i + di, j + dj)) for s in linkage.splits):
                    continue
                for v in (corners[t, side], corners[t, (side + 1) % 4]):
                    g = gap_at_vertex.get(int(v), -1)
                    if g >= 0:
                        rows.add(
                            (g, t, side, u, other_side) if t < u else (g, u, other_side, t, side)
                        )
    out = np.array(sorted(rows), dtype=np.int64)
    return out.reshape(-1, 5)


SplitRule = Literal["boundary", "same-component"]


def _rules(linkage: Linkage, lifts: Iterable[int], split_rule: SplitRule = "boundary") -> _Rules:
    rows = contact_partners(linkage)
    lift_set = {int(g) for g in lifts}
    boundary = linkage.boundary_tile
    kinds = linkage.gap_kind
    comp = linkage.tile_component
    sides: dict[tuple[int, int, int], tuple[int, int]] = {}
    allowed: set[tuple[int, int, int]] = set()
    tile_gaps: dict[int, set[int]] = {}
    for g, a, sa, b, sb in rows.tolist():
        sides[(g, a, b)] = (sa, sb)
        sides[(g, b, a)] = (sb, sa)
        if kinds[g] == "split" and g not in lift_set and not (boundary[a] and boundary[b]):
            if split_rule == "boundary" or comp[a] != comp[b]:
                continue  # never into the interior through a cut
        allowed.update(((g, a, b), (g, b, a)))
        tile_gaps.setdefault(a, set()).add(g)
        tile_gaps.setdefault(b, set()).add(g)
    gap_tiles: dict[int, set[int]] = {}
    for t, gs in tile_gaps.items():
        for g in gs:
            gap_tiles.setdefault(g, set()).add(t)
    return _Rules(
        sides=sides,
        allowed=frozenset(allowed),
        tile_gaps={t: tuple(sorted(gs)) for t, gs in tile_gaps.items()},
        gap_tiles={g: tuple(sorted(ts)) for g, ts in gap_tiles.items()},
    )


def _gap_tile_lists(linkage: Linkage) -> list[list[int]]:
    return [[int(t) for t in linkage.gap_tiles(g)] for g in range(linkage.n_gaps)]


def gap_graph(linkage: Linkage, gap_centroids_flat: ArrayLike) -> nx.Graph:
    """The gap graph on the flat configuration.

    Parameters
    ----------
    linkage : topology.
    gap_centroids_flat : (G, 2) float, mm, gap centroids in the flat layout.

    Returns
    -------
    networkx.Graph with node attributes ``label`` (0, 1, -1, -2), ``position`` (2,) and
    ``tiles`` (tuple), and edge attribute ``tiles``: the tiles the two gaps share (1 or 2).  A
    route step ``u -> v`` passes one of the edge's tiles; which consecutive steps may follow
    each other is decided by :func:`contact_partners`.
    """
    pos = _check_positions(linkage, gap_centroids_flat)
    labels = node_labels(linkage)
    tiles = _gap_tile_lists(linkage)
    graph = nx.Graph()
    for g in range(linkage.n_gaps):
        graph.add_node(g, label=int(labels[g]), position=pos[g], tiles=tuple(tiles[g]))
    by_tile: dict[int, list[int]] = {}
    for g, ts in enumerate(tiles):
        for t in ts:
            by_tile.setdefault(t, []).append(g)
    for t, gs in by_tile.items():
        for a in range(len(gs)):
            for b in range(a + 1, len(gs)):
                u, v = sorted((gs[a], gs[b]))
                if graph.has_edge(u, v):
                    graph.edges[u, v]["tiles"] = tuple(sorted({*graph.edges[u, v]["tiles"], t}))
                else:
                    graph.add_edge(u, v, tiles=(t,))
    return graph


def _check_positions(linkage: Linkage, positions: ArrayLike) -> FloatArray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[0] != linkage.n_gaps or pos.shape[1] < 2:
        raise InternalError(
            f"gap centroids have shape {pos.shape}; pass ({linkage.n_gaps}, 2) flat positions in mm"
        )
    return pos[:, :2]


# --------------------------------------------------------------------------------------------
# route assembly


def _side_facing(linkage: Linkage, tile: int, gap: int) -> int:
    sides = linkage.gap_sides[gap]
    hit = sides[sides[:, 0] == tile]
    return int(hit[0, 1]) if len(hit) else -1


def _finish(
    linkage: Linkage,
    rules: _Rules,
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
        crossings=count_crossings(gaps, pos),
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


def channel_partner_faults(route: Route, linkage: Linkage) -> IntArray:
    """Steps ``k`` where the string does not pass straight between contact partners.

    Measured from the route alone: step ``k`` is fine when ``tiles[k - 1] != tiles[k]``, the
    leave side of ``tiles[k - 1]`` and the enter side of ``tiles[k]`` are the same grid segment
    (same two grid vertices, read from ``linkage.tile_corners``), and the gap ``gaps[k]`` sits at
    one end of that segment.

    Returns
    -------
    (f,) int, the faulty step indices (empty when every crossing is a contact-partner crossing).
    """
    r = len(route.gaps)
    if r == 0:
        return np.zeros(0, dtype=np.int64)
    corners = linkage.tile_corners
    prev_t, here_t = np.roll(route.tiles, 1), route.tiles
    out_s, in_s = np.roll(route.leave_side, 1), route.enter_side
    bad_side = (out_s < 0) | (out_s > 3) | (in_s < 0) | (in_s > 3)
    out_s, in_s = np.clip(out_s, 0, 3), np.clip(in_s, 0, 3)
    a0, a1 = corners[prev_t, out_s], corners[prev_t, (out_s + 1) % 4]
    b0, b1 = corners[here_t, in_s], corners[here_t, (in_s + 1) % 4]
    same = ((a0 == b0) & (a1 == b1)) | ((a0 == b1) & (a1 == b0))
    vertex = linkage.gap_vertex[route.gaps]
    at_end = (vertex == a0) | (vertex == a1)
    ok = same & at_end & (prev_t != here_t) & ~bad_side
    return np.asarray(np.nonzero(~ok)[0], dtype=np.int64)


def channel_partners_ok(route: Route, linkage: Linkage) -> bool:
    """Whether every consecutive tile pair of the route are contact partners at their gap."""
    return not channel_partner_faults(route, linkage).size


def count_crossings(gaps: IntArray, pos: FloatArray) -> int:
    """Gaps visited more than once plus pairs of non-adjacent route segments that cross."""
    r = len(gaps)
    repeats = int(r - len(np.unique(gaps)))
    if r < 4:
        return repeats
    a = pos[gaps]
    b = pos[np.roll(gaps, -1)]
    i, j = np.triu_indices(r, k=2)
    keep = ~((i == 0) & (j == r - 1))
    i, j = i[keep], j[keep]
    return repeats + int(_segments_cross(a[i], b[i], a[j], b[j]).sum())


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
    pos = _check_positions(linkage, gap_centroids_flat)
    lifts = np.unique(np.asarray(lift_gaps, dtype=np.int64))
    if lifts.size and (lifts.min() < 0 or lifts.max() >= linkage.n_gaps):
        raise InternalError(f"lift gaps {lifts.tolist()} are not gap ids 0..{linkage.n_gaps - 1}")
    lift_set = {int(g) for g in lifts}
    rules = _rules(linkage, lift_set, split_rule)
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
        steps, cost, optimal = _exact(
            rules, pos, linkage.n_gaps, reachable, cover, groups, node_limit, missed, notes
        )
        method = "exact" if optimal else "heuristic: MILP stopped at its node or time limit"
        bound = cost if optimal else 2 * math.pi
        return _finish(linkage, rules, pos, steps, method, bound, notes, missed)

    method = "heuristic: boundary-DP + window-MILP"
    try:
        steps = _boundary_loop_dp(rules, pos, boundary_tile_order(linkage), linkage.boundary_tile)
        gaps = [g for g, _ in steps]
        tiles = [t for _, t in steps]
        if len(set(gaps)) < len(gaps) or len(set(tiles)) < len(tiles):
            raise DesignError("its loop passes a gap or a tile twice")
        if not cover <= set(tiles):
            raise DesignError("its loop misses boundary tiles")
    except DesignError as err:
        notes.append(f"boundary DP failed ({err}); solved the boundary band exactly")
        method = "heuristic: band-MILP + window-MILP"
        steps = _band_loop_any(rules, pos, cover, groups, node_limit, notes)
    spacing = _median_spacing(pos)
    for lift in sorted(reachable):
        if lift in {g for g, _ in steps}:
            continue
        reason, spliced = "", None
        for half_window, corridor in SPLICE_WINDOWS:
            for nodes in SPLICE_NODE_LIMITS:
                try:
                    spliced = _splice_lift(
                        rules, pos, steps, lift, cover, lift_set, spacing, nodes,
                        half_window, corridor, linkage.tile_component, notes,
                    )  # fmt: skip
                    break
                except NodeBudgetError as err:  # more nodes may find a path in this window
                    reason = str(err)
                except DesignError as err:  # this window holds none: a larger one
                    reason = str(err)
                    break
            if spliced is not None:
                break
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


# --------------------------------------------------------------------------------------------
# metrics, JSON, picture


def route_metrics(
    route: Route,
    linkage: Linkage,
    positions_flat: ArrayLike,
    positions_assembled: ArrayLike | None,
    mu: float,
) -> dict[str, Any]:
    """Measured route metrics for ``design.json``.

    Parameters
    ----------
    route : the route.
    linkage : topology (boundary tiles, components).
    positions_flat : (G, 2) float, mm, flat gap centroids.
    positions_assembled : (G, 3) float, mm, assembled gap positions, or None.
    mu : channel friction coefficient of the profile.

    Returns
    -------
    dict with ``tiles`` (distinct tiles passed), ``boundary_tiles_covered``,
    ``turn_angle_total_rad`` (recomputed), ``crossings`` (recounted), ``capstan_factor``
    ``= exp(mu * total turn)``, ``length_mm {flat, assembled}``, ``components_visited``,
    ``channel_partners_ok`` (every consecutive tile pair are contact partners at their gap,
    measured by :func:`channel_partner_faults`), ``tiles_passed_once``, ``lift_gaps_missed``,
    ``method`` and ``lower_bound_rad``.
    """
    pos = _check_positions(linkage, positions_flat)
    p = pos[route.gaps]
    total = float(turn_angle(np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0)).sum())
    tiles = set(route.tiles.tolist())
    boundary = set(np.nonzero(linkage.boundary_tile)[0].tolist())
    lengths: dict[str, float | None] = {
        "flat": float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())
    }
    if positions_assembled is not None:
        q = np.asarray(positions_assembled, dtype=np.float64)[route.gaps]
        lengths["assembled"] = float(np.linalg.norm(np.roll(q, -1, axis=0) - q, axis=1).sum())
    comps = set(linkage.tile_component[route.tiles].tolist())
    faults = channel_partner_faults(route, linkage)
    return {
        "tiles": len(tiles),
        "gaps": int(len(route.gaps)),
        "boundary_tiles_covered": bool(boundary <= tiles),
        "turn_angle_total_rad": total,
        "crossings": count_crossings(route.gaps, pos),
        "capstan_factor": float(math.exp(mu * total)),
        "length_mm": lengths,
        "components_visited": len(comps),
        "components": linkage.n_components,
        "channel_partners_ok": not faults.size,
        "channel_partner_faults": int(faults.size),
        "tiles_passed_once": bool(len(tiles) == len(route.tiles)),
        "lift_gaps_missed": [int(g) for g in route.lifts_missed],
        "method": route.method,
        "lower_bound_rad": route.lower_bound_rad,
    }


def route_to_json(
    route: Route,
    linkage: Linkage,
    positions_flat: ArrayLike,
    positions_assembled: ArrayLike | None = None,
    lift_gaps: ArrayLike = (),
) -> dict[str, Any]:
    """The ordered route for ``route.json``.

    Every step lists the gap the string is in, its label, the tile it passes next, the side
    faces of that tile it enters and leaves by (0 bottom, 1 right, 2 top, 3 left), and the gap
    position flat (mm) and assembled (mm, when given).  Every lift point lists its gap, its step
    index, the tile and side the string arrives from and the tile and side it departs into; the
    string exits the structure there out of the gap on the top side.
    """
    pos = _check_positions(linkage, positions_flat)
    asm = None if positions_assembled is None else np.asarray(positions_assembled, float)
    r = len(route.gaps)
    steps = []
    for k in range(r):
        g = int(route.gaps[k])
        step: dict[str, Any] = {
            "gap": g,
            "label": int(route.labels[k]),
            "tile": int(route.tiles[k]),
            "enter_side": int(route.enter_side[k]),
            "leave_side": int(route.leave_side[k]),
            "position_flat_mm": [float(c) for c in pos[g]],
        }
        if asm is not None:
            step["position_assembled_mm"] = [float(c) for c in asm[g]]
        steps.append(step)
    lifts: list[dict[str, Any]] = []
    where = {int(g): k for k, g in enumerate(route.gaps)}
    for g in np.asarray(lift_gaps, dtype=np.int64).tolist():
        if int(g) not in where:
            lifts.append({"gap": int(g), "on_route": False})
            continue
        k = where[int(g)]
        lifts.append(
            {
                "gap": int(g),
                "on_route": True,
                "step": k,
                "arrive_tile": int(route.tiles[k - 1]),
                "arrive_side": int(route.leave_side[k - 1]),
                "depart_tile": int(route.tiles[k]),
                "depart_side": int(route.enter_side[k]),
                "exit": "top",
            }
        )
    return {
        # Measured: the wrap from the last step back to the first is a contact-partner crossing.
        "closed": bool(r > 2 and 0 not in channel_partner_faults(route, linkage)),
        "method": route.method,
        "turn_angle_total_rad": route.turn_angle_total_rad,
        "lower_bound_rad": route.lower_bound_rad,
        "crossings": route.crossings,
        "boundary_tiles_covered": route.boundary_tiles_covered,
        "length_flat_mm": route.length_flat_mm,
        "side_names": ["bottom", "right", "top", "left"],
        "steps": steps,
        "lift_points": lifts,
        "notes": list(route.notes),
    }
