"""Loop builders for the string route, on top of the integer program in :mod:`.milp`.

The heuristic for large instances: a dynamic program over the boundary tiles in their order along
the outer boundary builds the minimum-turn boundary loop (:func:`boundary_loop_dp`, with short
bridges through interior tiles, :func:`_bridges`); when that fails the integer program is solved
on the band of tiles next to the boundary (:func:`band_loop_any`); each lift gap not on the loop
is spliced in by solving the integer program on a window around it (:func:`splice_lift`).
Small instances are solved whole by :func:`exact_loop`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drawstring.geometry.core.errors import DesignError
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.route.milp import (
    NodeBudgetError,
    RouteRules,
    Step,
    build_problem,
    cycle_steps,
    reverse_steps,
    segments_cross,
    solve_cycle,
)
from drawstring.geometry.tiling.linkage import Linkage

# --------------------------------------------------------------------------------------------
# heuristic: boundary loop by dynamic programming


def boundary_tile_order(linkage: Linkage) -> list[int]:
    """Boundary tiles in counter-clockwise order along the longest outer boundary loop."""
    corners = linkage.tile_corners
    edge_owner: dict[tuple[int, int], int] = {}
    for t in range(linkage.n_tiles):
        for k in range(4):
            a, b = int(corners[t, k]), int(corners[t, (k + 1) % 4])
            edge_owner[(a, b)] = t
    boundary = {e: t for e, t in edge_owner.items() if (e[1], e[0]) not in edge_owner}
    succ: dict[int, list[tuple[int, int]]] = {}
    for (a, b), t in boundary.items():
        succ.setdefault(a, []).append((b, t))
    tiles_at: dict[int, list[int]] = {}
    for t in range(linkage.n_tiles):
        for k in range(4):
            tiles_at.setdefault(int(corners[t, k]), []).append(t)
    used: set[tuple[int, int]] = set()
    best: list[int] = []
    for a0 in sorted(succ):
        for b0, _t in succ[a0]:
            if (a0, b0) in used:
                continue
            loop: list[tuple[int, int]] = []
            a, b = a0, b0
            while (a, b) not in used:
                used.add((a, b))
                loop.append((a, b))
                nxt = [x for x in succ.get(b, []) if (b, x[0]) not in used]
                if not nxt:
                    break
                a, b = b, nxt[0][0]
            order: list[int] = []
            ij = linkage.vertex_ij
            for a, b in loop:
                t_in = boundary[(a, b)]
                # tiles around vertex a that are not on the incoming or outgoing edge (reflex
                # corners) come before the edge's own tile, ordered by angle about the vertex
                extra = [t for t in tiles_at[a] if t != t_in]
                centre = ij[a].astype(float)
                d = ij[b] - ij[a]
                base = math.atan2(float(d[1]), float(d[0]))

                def key(t: int, base: float = base, centre: FloatArray = centre) -> float:
                    c = linkage.tile_cells[t] + 0.5 - centre
                    return (math.atan2(float(c[1]), float(c[0])) - base) % (2 * math.pi)

                for t in sorted(extra, key=key, reverse=True):
                    if linkage.boundary_tile[t] and t not in order[-3:]:
                        order.append(t)
                if not order or order[-1] != t_in:
                    order.append(t_in)
            seen: set[int] = set()
            dedup = [t for t in order if not (t in seen or seen.add(t))]  # type: ignore[func-returns-value]
            if len(dedup) > len(best):
                best = dedup
    return best


def _turn(pos: FloatArray, a: int, b: int, c: int) -> float:
    """Turn angle (rad) at gap ``b`` between gaps ``a`` and ``c``."""
    d1x, d1y = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1]
    d2x, d2y = pos[c, 0] - pos[b, 0], pos[c, 1] - pos[b, 1]
    return abs(math.atan2(d1x * d2y - d1y * d2x, d1x * d2x + d1y * d2y))


def _bridges(
    rules: RouteRules,
    pos: FloatArray,
    boundary: BoolArray,
    tile: int,
    target: int,
    a: int,
    b: int,
) -> list[tuple[list[Step], int, int, float]]:
    """Paths from the step ``a -> b`` through ``tile`` on through one or two interior tiles.

    Returns ``(steps, previous gap, last gap, turn cost so far)`` for every such path whose last
    tile is a contact partner of ``target`` at the last gap (the turn there is not included).
    """
    out: list[tuple[list[Step], int, int, float]] = []
    for x in rules.gap_tiles.get(b, ()):
        if boundary[x] or (b, tile, x) not in rules.allowed:
            continue
        for c in rules.tile_gaps[x]:
            if c in (a, b):
                continue
            cost = _turn(pos, a, b, c)
            if (c, x, target) in rules.allowed:
                out.append(([(b, x)], b, c, cost))
            for y in rules.gap_tiles.get(c, ()):
                if boundary[y] or y == x or (c, x, y) not in rules.allowed:
                    continue
                for d in rules.tile_gaps[y]:
                    if d not in (a, b, c) and (d, y, target) in rules.allowed:
                        out.append(([(b, x), (c, y)], c, d, cost + _turn(pos, b, c, d)))
    return out


def boundary_loop_dp(
    rules: RouteRules, pos: FloatArray, order: list[int], boundary: BoolArray
) -> list[Step]:
    """Minimum-turn closed loop passing the boundary tiles once each, in ``order``.

    Layer ``k`` holds the directed steps ``a -> b`` through tile ``order[k]``; a step of layer
    ``k`` moves on to a step of layer ``k + 1`` that starts where it ends when the two tiles are
    contact partners there (paying the turn at that gap), or else through a bridge of one or two
    interior tiles.  The cyclic chain is a min-plus matrix product over the layers, for all
    starting steps at once.  Returns the loop's steps ``(gap, tile)``.
    """
    n_b = len(order)
    if n_b < 3:
        raise DesignError(f"only {n_b} boundary tiles: too few for a boundary loop")
    states: list[list[tuple[int, int]]] = []
    for t in order:
        gs = rules.tile_gaps.get(t, ())
        if len(gs) < 2:
            raise DesignError(f"boundary tile {t} has fewer than two gaps the string may use")
        states.append([(a, b) for a in gs for b in gs if a != b])
    mats: list[FloatArray] = []
    bridges: list[dict[tuple[int, int], list[Step]]] = []
    for k in range(n_b):
        tile, nxt = order[k], order[(k + 1) % n_b]
        here, there = states[k], states[(k + 1) % n_b]
        by_entry: dict[int, list[tuple[int, int]]] = {}
        for j, (c, d) in enumerate(there):
            by_entry.setdefault(c, []).append((j, d))
        mat = np.full((len(here), len(there)), np.inf)
        for i, (a, b) in enumerate(here):
            if (b, tile, nxt) in rules.allowed:
                for j, d in by_entry.get(b, []):
                    if d != a:
                        mat[i, j] = _turn(pos, a, b, d)
        bridge: dict[tuple[int, int], list[Step]] = {}
        if not np.isfinite(mat).any():
            for i, (a, b) in enumerate(here):
                for steps, prev, c, cost in _bridges(rules, pos, boundary, tile, nxt, a, b):
                    used = {a, b} | {g for g, _ in steps}
                    for j, d in by_entry.get(c, []):
                        if d in used:
                            continue
                        total = cost + _turn(pos, prev, c, d)
                        if total < mat[i, j]:
                            mat[i, j] = total
                            bridge[(i, j)] = steps
            if not bridge:
                raise DesignError(
                    f"boundary tiles {tile} and {nxt} are not joined by contact partners"
                    " within two interior tiles"
                )
        mats.append(mat)
        bridges.append(bridge)
    n0 = len(states[0])
    dist = np.full((n0, n0), np.inf)
    np.fill_diagonal(dist, 0.0)
    back: list[IntArray] = []
    for mat in mats:
        chain = dist[:, :, None] + mat[None, :, :]
        back.append(np.asarray(chain.argmin(axis=1), dtype=np.int64))
        dist = chain.min(axis=1)
    closing = np.diag(dist)
    s = int(np.argmin(closing))
    if not np.isfinite(closing[s]):
        raise DesignError("no closed string loop passes the boundary tiles in order")
    chosen = [0] * (n_b + 1)
    chosen[n_b] = s
    for k in range(n_b - 1, -1, -1):
        chosen[k] = int(back[k][s, chosen[k + 1]])
    out: list[Step] = []
    for k in range(n_b):
        a, _b = states[k][chosen[k]]
        out.append((a, order[k]))
        out.extend(bridges[k].get((chosen[k], chosen[k + 1]), []))
    return out


def _band_loop(
    rules: RouteRules,
    pos: FloatArray,
    cover: set[int],
    groups: Sequence[set[int]],
    layers: int,
    node_limit: int,
    notes: list[str] | None = None,
) -> tuple[list[Step], float, bool]:
    """The exact program on the boundary tiles and the tiles within ``layers`` steps of them."""
    band = set(cover)
    for _ in range(layers):
        band |= {u for t in band for g in rules.tile_gaps.get(t, ()) for u in rules.gap_tiles[g]}
    nodes = {g for t in band for g in rules.tile_gaps.get(t, ())}
    touched = [grp for grp in groups if grp & band]
    problem = build_problem(rules, pos, nodes, set(), cover, tiles=band, groups=touched)
    cyc, cost, optimal = solve_cycle(problem, rules, pos, node_limit, notes)
    return cycle_steps(problem, cyc), cost, optimal


def _crossing_fixed(
    rules: RouteRules,
    pos: FloatArray,
    edges: list[tuple[int, int]],
    edge_tile: list[int],
    fixed_path: list[int],
    fixed_steps: list[Step],
) -> BoolArray:
    """Which window ``edges`` (through ``edge_tile``) cross the fixed rest of the loop; only
    segments in one split part can cross (see :class:`RouteRules`)."""
    ea = np.array(edges, dtype=np.int64)
    fa = np.array(fixed_path[:-1], dtype=np.int64)
    fb = np.array(fixed_path[1:], dtype=np.int64)
    cross = segments_cross(
        pos[ea[:, 0]][:, None], pos[ea[:, 1]][:, None], pos[fa][None], pos[fb][None]
    )
    if rules.tile_part:
        edge_part = np.array([rules.tile_part.get(t, -1) for t in edge_tile])
        fixed_part = np.array([rules.tile_part.get(t, -1) for _, t in fixed_steps])
        cross &= edge_part[:, None] == fixed_part[None, :]
    return np.asarray(cross.any(axis=1))


def splice_lift(
    rules: RouteRules,
    pos: FloatArray,
    steps: list[Step],
    lift: int,
    cover: set[int],
    lifts: set[int],
    spacing: float,
    node_limit: int,
    half_window: int,
    corridor: float,
    component: IntArray | None = None,
    notes: list[str] | None = None,
) -> list[Step]:
    """Re-route a window of the loop so that it passes ``lift``, solving the window's program
    within ``node_limit`` branch-and-bound nodes.

    The window is the loop stretch of ``2 half_window + 1`` gaps around the loop gap nearest to
    the lift gap plus every gap within ``corridor`` gap spacings of the segment from that gap to
    the lift gap.  With ``component`` (each tile's split part), that loop gap is the nearest
    one where the loop runs through a tile of the lift gap's part: a detour from another part
    would have to cross the cut, which the rules forbid in the interior.

    The rest of the loop is fixed: the window's path joins it at the same two
    gaps ``p0``, ``q1`` (contact partners of the fixed tiles there, paying the turns there), uses
    none of its gaps or tiles, crosses none of its segments, and passes every boundary tile that
    the removed stretch passed.  Raises DesignError when the window holds no such path,
    :class:`~.milp.NodeBudgetError` when its nodes found none (more nodes may).
    """
    r = len(steps)
    cycle = [g for g, _ in steps]
    distance = np.linalg.norm(pos[cycle] - pos[lift], axis=1)
    if component is not None:
        parts = {int(component[t]) for t in rules.gap_tiles.get(lift, ())}
        same = np.array([int(component[t]) in parts for _, t in steps])
        if same.any():
            distance = np.where(same, distance, np.inf)
    m = int(np.argmin(distance))
    span = min(half_window, (r - 3) // 2)
    idx = [(m + k) % r for k in range(-span - 1, span + 2)]
    p0, q1 = cycle[idx[0]], cycle[idx[-1]]
    inner = [cycle[i] for i in idx[1:-1]]
    fixed_steps = [steps[(idx[-1] + k) % r] for k in range(r - len(idx) + 1)]
    fixed_gaps = {g for g, _ in fixed_steps} | {p0}
    fixed_tiles = {t for _, t in fixed_steps}
    pre, t_pre = fixed_steps[-1]
    t_post = fixed_steps[0][1]
    post = fixed_steps[1][0] if len(fixed_steps) > 1 else p0
    a, seg = pos[cycle[m]], pos[lift] - pos[cycle[m]]
    rel = pos - a
    along = np.clip((rel @ seg) / max(float(seg @ seg), 1e-12), 0.0, 1.0)
    near = np.linalg.norm(rel - along[:, None] * seg, axis=1) <= corridor * spacing
    window = ({int(g) for g in np.nonzero(near)[0]} | set(inner) | {lift}) - fixed_gaps
    nodes = window | {p0, q1}
    allowed_tiles = set(rules.tile_gaps) - fixed_tiles
    need = cover - fixed_tiles
    required = {lift, p0, q1} | (lifts & set(inner))
    problem = build_problem(rules, pos, nodes, required, need, tiles=allowed_tiles)
    keep = [e for e, (u, v) in enumerate(problem.edges) if {u, v} != {p0, q1}]
    edges = [problem.edges[e] for e in keep]
    problem.edge_tile = [problem.edge_tile[e] for e in keep]
    remap = {e: k for k, e in enumerate(keep)}
    problem.forbid_pairs = [
        (remap[x], remap[y]) for x, y in problem.forbid_pairs if x in remap and y in remap
    ]
    fixed_path = [g for g, _ in fixed_steps] + [p0]
    if edges:
        hit = _crossing_fixed(rules, pos, edges, problem.edge_tile, fixed_path, fixed_steps)
        problem.banned = {int(e) for e in np.nonzero(hit)[0]}
    extra: dict[int, float] = {}
    for e, (u, v) in enumerate(edges):
        if p0 in (u, v):
            extra[e] = extra.get(e, 0.0) + _turn(pos, pre, p0, v if u == p0 else u)
        if q1 in (u, v):
            extra[e] = extra.get(e, 0.0) + _turn(pos, v if u == q1 else u, q1, post)
    edges.append((min(p0, q1), max(p0, q1)))
    problem.edge_tile.append(-1)
    problem.edges = edges
    problem.fixed = {len(edges) - 1}
    problem.virtual_tile = {p0: t_pre, q1: t_post}
    problem.edge_cost = extra
    problem.flow = True
    cyc, _cost, _optimal = solve_cycle(problem, rules, pos, node_limit, notes)
    loop = cycle_steps(problem, cyc)
    k = next(i for i, (_g, t) in enumerate(loop) if t < 0)
    if loop[k][0] == p0:  # runs q1 ... p0 -> q1: turn it round
        loop = reverse_steps(loop)
        k = next(i for i, (_g, t) in enumerate(loop) if t < 0)
    path = loop[k + 1 :] + loop[:k]
    if not path or path[0][0] != p0 or loop[k][0] != q1:
        raise DesignError(f"could not splice lift gap {lift} into the string route")
    return path + fixed_steps


# --------------------------------------------------------------------------------------------
# band fallback and the whole-instance program


def band_loop_any(
    rules: RouteRules,
    pos: FloatArray,
    cover: set[int],
    groups: Sequence[set[int]],
    node_limit: int,
    notes: list[str] | None = None,
) -> list[Step]:
    """The band program with one, then two, then three layers of interior tiles."""
    err: DesignError | None = None
    for layers in (1, 2, 3):
        try:
            return _band_loop(rules, pos, cover, groups, layers, node_limit, notes)[0]
        except DesignError as e:
            err = e
    raise DesignError(
        "no closed string route passes every boundary tile once under the contact-partner"
        f" rules ({err}); is part of the shape only two tiles wide?"
    )


def exact_loop(
    rules: RouteRules,
    pos: FloatArray,
    n_gaps: int,
    lifts: set[int],
    cover: set[int],
    groups: Sequence[set[int]],
    node_limit: int,
    missed: list[int],
    notes: list[str],
) -> tuple[list[Step], float, bool]:
    """Whole-instance program; lift gaps that make it infeasible (or that no route found
    within its node budget passes) are dropped one by one."""

    def solve(required: set[int]) -> tuple[list[Step], float, bool]:
        problem = build_problem(rules, pos, range(n_gaps), required, cover, groups=groups)
        cyc, cost, optimal = solve_cycle(problem, rules, pos, node_limit, notes)
        return cycle_steps(problem, cyc), cost, optimal

    try:
        return solve(lifts)
    except DesignError:
        if not lifts:
            raise
    base = solve(set())  # raises when even the boundary loop is impossible
    kept: set[int] = set()
    for g in sorted(lifts):
        try:
            base = solve(kept | {g})
            kept.add(g)
        except NodeBudgetError:
            missed.append(g)
            notes.append(
                f"lift gap {g} was left out: the route program found no route through it within"
                f" its budget of {node_limit} branch-and-bound nodes"
            )
        except DesignError:
            missed.append(g)
            notes.append(
                f"lift gap {g} cannot be reached: no valid closed route passes it together with"
                " every boundary tile (contact partners, each gap and tile once, no crossing)"
            )
    return base
