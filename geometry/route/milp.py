"""The integer program behind the string route: one minimum-turn closed cycle on the gap graph.

A problem instance (:class:`_Problem`) has one node per gap and one edge per step between two
gaps through a tile; :func:`solve_cycle` solves it with ``scipy.optimize.milp`` (HiGHS), with
binary edge, node and turn variables, one pass per tile, crossing-pair exclusions and
connectivity cuts added until one cycle remains.  The geometric helpers the program needs (turn
angles and segment crossings in the flat layout) live here too.  Which steps are allowed comes
from :class:`RouteRules`, built by :func:`drawstring.geometry.route.rules.route_rules`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import DesignError
from drawstring.geometry.core.native import native_output_silenced
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray

log = logging.getLogger(__name__)

Step = tuple[int, int]  # (gap the string crosses into the tile, tile)

#: Wall-clock safety net of one integer-program solve, s.  The solves are bounded by
#: branch-and-bound nodes (HiGHS ``mip_max_nodes``, the callers' ``node_limit``), which stop
#: them at the same point on every machine; a bound on time would stop the largest programs at
#: a point that depends on the machine's speed and load, and so change their routes.  A solve
#: this limit stops keeps its best route and says so in the route's notes.
MILP_SAFETY_TIME_S = 60.0


class NodeBudgetError(DesignError):
    """No closed route was found within the node budget, and none was proved not to exist:
    more nodes may find one."""


@dataclass(frozen=True)
class RouteRules:
    """Contact partners and the split rule, indexed for the solvers."""

    sides: dict[tuple[int, int, int], tuple[int, int]]  # (gap, a, b) -> (side of a, side of b)
    allowed: frozenset[tuple[int, int, int]]  # (gap, a, b): the string may pass a -> b at gap
    tile_gaps: dict[int, tuple[int, ...]]  # tile -> gaps where it has an allowed partner
    gap_tiles: dict[int, tuple[int, ...]]  # gap -> tiles with an allowed partner there
    #: tile -> its split part: route segments in different parts never cross (the parts lie
    #: apart flat and in different places assembled), so only same-part pairs are excluded
    tile_part: dict[int, int] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# geometry helpers


def turn_angle(a: FloatArray, b: FloatArray, c: FloatArray) -> Any:
    """Angle (rad) between directions ``b - a`` and ``c - b``; broadcasts over leading axes."""
    d1, d2 = b - a, c - b
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    dot = (d1 * d2).sum(-1)
    return np.abs(np.arctan2(cross, dot))


def segments_cross(
    p1: FloatArray,
    p2: FloatArray,
    q1: FloatArray,
    q2: FloatArray,
    eps: float = 1e-9,
) -> BoolArray:
    """Proper intersection of segment pairs (shared endpoints and touching do not count)."""

    def orient(a: Any, b: Any, c: Any) -> Any:
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (
            c[..., 0] - a[..., 0]
        )

    scale = np.maximum(np.linalg.norm(p2 - p1, axis=-1), np.linalg.norm(q2 - q1, axis=-1)) ** 2
    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    tol = eps * scale
    return np.asarray(
        (((d1 > tol) & (d2 < -tol)) | ((d1 < -tol) & (d2 > tol)))
        & (((d3 > tol) & (d4 < -tol)) | ((d3 < -tol) & (d4 > tol)))
    )


def crossing_edge_pairs(edges: IntArray, pos: FloatArray) -> IntArray:
    """(c, 2) indices of edge pairs whose straight segments cross properly."""
    if len(edges) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    a, b = pos[edges[:, 0]], pos[edges[:, 1]]
    mid = 0.5 * (a + b)
    reach = float(np.linalg.norm(b - a, axis=1).max())
    pairs = cKDTree(mid).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    share = (
        (edges[i, 0] == edges[j, 0])
        | (edges[i, 0] == edges[j, 1])
        | (edges[i, 1] == edges[j, 0])
        | (edges[i, 1] == edges[j, 1])
    )
    hit = ~share & segments_cross(a[i], b[i], a[j], b[j])
    return np.asarray(pairs[hit], dtype=np.int64)


# --------------------------------------------------------------------------------------------
# the integer program


@dataclass
class _Problem:
    """An instance of the cycle program: gap nodes, tile-carrying edges (global ids)."""

    nodes: list[int]
    edges: list[tuple[int, int]]  # (u, v) with u < v
    edge_tile: list[int]  # tile the step passes; -1 for the virtual edge
    required: set[int]  # gaps that must be visited
    cover: set[int]  # tiles that must be passed
    groups: list[set[int]] = field(default_factory=list)  # tile sets passed at least once
    fixed: set[int] = field(default_factory=set)  # edge indices forced into the cycle
    banned: set[int] = field(default_factory=set)  # edge indices forced out
    forbid_pairs: list[tuple[int, int]] = field(default_factory=list)  # crossing edge pairs
    edge_cost: dict[int, float] = field(default_factory=dict)  # extra linear cost per edge
    virtual_tile: dict[int, int] = field(default_factory=dict)  # node -> tile beyond the virtual
    flow: bool = False  # add a single-commodity flow keeping the visited gaps connected


def build_problem(
    rules: RouteRules,
    pos: FloatArray,
    nodes: Iterable[int],
    required: set[int],
    cover: set[int],
    tiles: set[int] | None = None,
    groups: Sequence[set[int]] = (),
) -> _Problem:
    """Every step ``(u, v, tile)`` between two of ``nodes`` through an allowed tile."""
    node_set = {int(g) for g in nodes}
    cand: set[int] = set()
    for g in node_set:
        cand.update(rules.gap_tiles.get(g, ()))
    if tiles is not None:
        cand &= tiles
    edges: list[tuple[int, int]] = []
    edge_tile: list[int] = []
    for t in sorted(cand):
        gs = [g for g in rules.tile_gaps[t] if g in node_set]
        for a in range(len(gs)):
            for b in range(a + 1, len(gs)):
                edges.append((gs[a], gs[b]))
                edge_tile.append(t)
    problem = _Problem(
        nodes=sorted(node_set),
        edges=edges,
        edge_tile=edge_tile,
        required=set(required),
        cover=set(cover),
        groups=[set(s) for s in groups],
    )
    problem.forbid_pairs = _crossing_pairs(
        edges, pos, [rules.tile_part.get(t, -1) for t in edge_tile]
    )
    return problem


def _crossing_pairs(
    edges: list[tuple[int, int]], pos: FloatArray, parts: Sequence[int] | None = None
) -> list[tuple[int, int]]:
    """Pairs of edge indices whose segments cross (parallel edges share their geometry); with
    ``parts`` (each edge's split part) only pairs in one part."""
    if len(edges) < 2:
        return []
    geo, inverse = np.unique(np.array(edges, dtype=np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    members: dict[int, list[int]] = {}
    for e, k in enumerate(inverse.tolist()):
        members.setdefault(k, []).append(e)
    out: list[tuple[int, int]] = []
    for a, b in crossing_edge_pairs(geo, pos).tolist():
        out.extend(
            (x, y) for x in members[a] for y in members[b] if parts is None or parts[x] == parts[y]
        )
    return out


def solve_cycle(
    problem: _Problem,
    rules: RouteRules,
    pos: FloatArray,
    node_limit: int,
    notes: list[str] | None = None,
) -> tuple[list[int], float, bool]:
    """Minimum-turn single cycle of the program, each solve bounded by ``node_limit``
    branch-and-bound nodes (1: the root only, with HiGHS's heuristics there).

    Returns the cycle's edge indices in order, its cost and whether HiGHS proved optimality.
    Raises :class:`NodeBudgetError` when none was found within the nodes, DesignError when none
    exists or none was found otherwise.  A solve stopped by :data:`MILP_SAFETY_TIME_S`, with a
    cycle or without, adds a note (once) to ``notes``.
    """
    program = _cycle_program(problem, rules, pos)
    edges = problem.edges
    n_e = len(edges)
    optimal = True
    for _round in range(500):
        # HiGHS prints some of its progress with C printf, whatever disp says
        with native_output_silenced():
            res = milp(
                program.objective,
                constraints=[program.matrix()],
                integrality=program.integrality,
                bounds=Bounds(program.lb, program.ub),
                options={
                    "node_limit": node_limit,
                    "time_limit": MILP_SAFETY_TIME_S,
                    "disp": False,
                },
            )
        # milp's status 1: the time (or an iteration) limit; 4 with HiGHS's "solution limit":
        # the node limit
        timed_out = res.status == 1
        out_of_nodes = res.status == 4 and "Solution limit" in str(res.message)
        if timed_out and notes is not None:
            note = (
                f"a route program stopped at its {MILP_SAFETY_TIME_S:g} s safety limit before "
                "its node budget: on another machine the route may differ"
            )
            if note not in notes:
                notes.append(note)
        if res.x is None:
            raise _no_route(res, out_of_nodes, node_limit)
        if res.status != 0:
            optimal = False
        z = res.x[:n_e] > 0.5
        cycles = _cycles_of(edges, np.nonzero(z)[0])
        if len(cycles) == 1:
            log.debug("route program: %d rounds, %d variables", _round + 1, program.n_var)
            return cycles[0], float(res.fun), optimal
        _add_connectivity_cuts(program, problem, cycles)
    raise DesignError("string route program did not converge to one cycle")


@dataclass
class _Program:
    """The cycle program's constraint rows (sparse: ``({variable: coefficient}, lo, hi)``),
    variable bounds, integrality and objective.

    Variables: edges ``[0, n_e)``, turns from ``off_y``, nodes from ``off_x`` (then, with a flow,
    two flow variables per edge)."""

    n_var: int
    off_y: int
    off_x: int
    node_index: dict[int, int]
    rows: list[tuple[dict[int, float], float, float]] = field(default_factory=list)
    integrality: FloatArray = field(default_factory=lambda: np.zeros(0))
    lb: FloatArray = field(default_factory=lambda: np.zeros(0))
    ub: FloatArray = field(default_factory=lambda: np.zeros(0))
    objective: FloatArray = field(default_factory=lambda: np.zeros(0))

    def add(self, coefs: dict[int, float], lo: float, hi: float) -> None:
        self.rows.append((coefs, lo, hi))

    def matrix(self) -> LinearConstraint:
        r_idx, c_idx, vals = [], [], []
        for r, (coefs, _lo, _hi) in enumerate(self.rows):
            for c, v in coefs.items():
                r_idx.append(r)
                c_idx.append(c)
                vals.append(v)
        mat = sp.csr_matrix((vals, (r_idx, c_idx)), shape=(len(self.rows), self.n_var))
        return LinearConstraint(
            mat, np.array([r[1] for r in self.rows]), np.array([r[2] for r in self.rows])
        )


def _turns(
    problem: _Problem, rules: RouteRules, pos: FloatArray, incident: list[list[int]]
) -> tuple[list[tuple[int, int, int]], list[float]]:
    """Every turn ``(node index, edge, edge)`` at a gap whose two tiles are contact partners
    there, and its cost: the turn angle (0 next to the virtual edge)."""
    edges, edge_tile = problem.edges, problem.edge_tile
    turns: list[tuple[int, int, int]] = []
    cost: list[float] = []
    for k, v in enumerate(problem.nodes):
        inc = incident[k]
        for a in range(len(inc)):
            for b in range(a + 1, len(inc)):
                e1, e2 = inc[a], inc[b]
                t1 = edge_tile[e1] if edge_tile[e1] >= 0 else problem.virtual_tile.get(v, -1)
                t2 = edge_tile[e2] if edge_tile[e2] >= 0 else problem.virtual_tile.get(v, -1)
                if (v, t1, t2) not in rules.allowed:
                    continue  # not contact partners here (or the same tile)
                turns.append((k, e1, e2))
                if edge_tile[e1] < 0 or edge_tile[e2] < 0:
                    cost.append(0.0)
                else:
                    u = edges[e1][0] if edges[e1][1] == v else edges[e1][1]
                    w = edges[e2][0] if edges[e2][1] == v else edges[e2][1]
                    cost.append(float(turn_angle(pos[u], pos[v], pos[w])))
    return turns, cost


def _cycle_program(problem: _Problem, rules: RouteRules, pos: FloatArray) -> _Program:
    """The program's rows before any connectivity cut: degree and turn rows per node, one
    pass per tile, the tile groups, the crossing pairs and (``problem.flow``) the flow."""
    edges, edge_tile = problem.edges, problem.edge_tile
    n_e = len(edges)
    node_index = {v: k for k, v in enumerate(problem.nodes)}
    n_v = len(problem.nodes)
    incident: list[list[int]] = [[] for _ in range(n_v)]
    for e, (u, v) in enumerate(edges):
        incident[node_index[u]].append(e)
        incident[node_index[v]].append(e)
    turns, cost = _turns(problem, rules, pos, incident)
    n_t = len(turns)
    program = _Program(n_var=n_e + n_t + n_v, off_y=n_e, off_x=n_e + n_t, node_index=node_index)
    off_y, off_x, add = program.off_y, program.off_x, program.add
    turns_at_edge: list[dict[int, list[int]]] = [dict() for _ in range(n_v)]
    for t, (k, e1, e2) in enumerate(turns):
        turns_at_edge[k].setdefault(e1, []).append(t)
        turns_at_edge[k].setdefault(e2, []).append(t)
    for k in range(n_v):
        coefs = {e: 1.0 for e in incident[k]}
        coefs[off_x + k] = -2.0
        add(coefs, 0.0, 0.0)
        for e in incident[k]:
            c = {off_y + t: 1.0 for t in turns_at_edge[k].get(e, [])}
            c[e] = -1.0
            add(c, 0.0, 0.0)
    passing: dict[int, dict[int, float]] = {}
    for e, t in enumerate(edge_tile):
        if t >= 0:
            passing.setdefault(t, {})[e] = 1.0
    for t, coefs in passing.items():
        add(coefs, 1.0 if t in problem.cover else 0.0, 1.0)  # every tile at most once
    for t in problem.cover:
        if t not in passing:
            raise DesignError(f"tile {t} cannot be passed by any step allowed by the route rules")
    for group in problem.groups:
        coefs = {e: 1.0 for t in group for e in passing.get(t, {})}
        if not coefs:
            raise DesignError(f"no allowed step passes any of tiles {sorted(group)[:5]}...")
        add(coefs, 1.0, np.inf)
    for e1, e2 in problem.forbid_pairs:
        add({e1: 1.0, e2: 1.0}, -np.inf, 1.0)
    program.integrality = np.ones(program.n_var)
    program.ub = np.ones(program.n_var)
    if problem.flow and problem.required:
        _add_flow(program, problem, n_v)
    program.lb = np.zeros(program.n_var)
    for e in problem.fixed:
        program.lb[e] = 1.0
    for e in problem.banned:
        program.ub[e] = 0.0
    for v in problem.required:
        program.lb[off_x + node_index[v]] = 1.0
    program.objective = np.zeros(program.n_var)
    program.objective[off_y : off_y + n_t] = cost
    for e, c_e in problem.edge_cost.items():
        program.objective[e] += c_e
    return program


def _add_flow(program: _Program, problem: _Problem, n_v: int) -> None:
    """A single-commodity flow from a required gap to every visited gap: one cycle at once."""
    edges, node_index = problem.edges, program.node_index
    n_e = len(edges)
    off_f, source, cap = program.n_var, node_index[min(problem.required)], float(n_v - 1)
    program.n_var += 2 * n_e
    program.integrality = np.concatenate([program.integrality, np.zeros(2 * n_e)])
    program.ub = np.concatenate([program.ub, np.full(2 * n_e, cap)])
    net: list[dict[int, float]] = [dict() for _ in range(n_v)]
    for e, (u, v) in enumerate(edges):
        program.add({off_f + 2 * e: 1.0, off_f + 2 * e + 1: 1.0, e: -cap}, -np.inf, 0.0)
        iu, iv = node_index[u], node_index[v]
        net[iv][off_f + 2 * e] = 1.0  # u -> v flows into v
        net[iu][off_f + 2 * e] = -1.0
        net[iu][off_f + 2 * e + 1] = 1.0  # v -> u flows into u
        net[iv][off_f + 2 * e + 1] = -1.0
    for k in range(n_v):
        if k != source:
            coefs = dict(net[k])
            coefs[program.off_x + k] = -1.0
            program.add(coefs, 0.0, 0.0)


def _no_route(res: Any, out_of_nodes: bool, node_limit: int) -> DesignError:
    """The error of a solve that returned no cycle: proved infeasible, out of nodes
    (:class:`NodeBudgetError`), or stopped by the safety time limit or a solver failure."""
    rule = (
        "that passes every boundary tile and each tile and gap at most once between "
        "contact partners without crossing itself"
    )
    if res.status == 2:  # proved infeasible
        return DesignError(
            f"no closed string route exists {rule}; a shape part only one or two tiles "
            "wide has none: use more tiles (--tiles or --grid)"
        )
    too_large = "the route program is too large: use fewer tiles (--tiles or --grid)"
    if out_of_nodes:
        return NodeBudgetError(
            f"no closed string route was found within {node_limit} branch-and-bound "
            f"nodes {rule}; {too_large}"
        )
    # the safety time limit (more nodes would take longer still) or a solver failure
    return DesignError(
        f"no closed string route was found {rule} (HiGHS: {res.message}); {too_large}"
    )


def _add_connectivity_cuts(program: _Program, problem: _Problem, cycles: list[list[int]]) -> None:
    """Cuts that forbid each of several disjoint ``cycles`` on its own: a cycle that must reach
    beyond its gaps (a required gap, fixed edge, cover tile or group outside it) has every
    visited gap of it joined to the outside; otherwise it may not coexist with another one."""
    edges, edge_tile = problem.edges, problem.edge_tile
    off_x, node_index = program.off_x, program.node_index
    sets = [{u for e in cyc for u in edges[e]} for cyc in cycles]
    for a, s_a in enumerate(sets):
        cut = {e: 1.0 for e, (u, v) in enumerate(edges) if (u in s_a) != (v in s_a)}
        inside_tiles = {edge_tile[e] for e, (u, v) in enumerate(edges) if u in s_a and v in s_a}
        must_leave = (
            bool(problem.required - s_a)
            or any(not set(edges[e]) <= s_a for e in problem.fixed)
            or bool(problem.cover - inside_tiles)
            or any(not (g & inside_tiles) for g in problem.groups)
        )
        if must_leave:
            for v in s_a:
                c = dict(cut)
                c[off_x + node_index[v]] = -2.0
                program.add(c, 0.0, np.inf)
        else:
            v0 = min(s_a)
            for b, s_b in enumerate(sets):
                if b != a:
                    c = dict(cut)
                    c[off_x + node_index[v0]] = -2.0
                    c[off_x + node_index[min(s_b)]] = -2.0
                    program.add(c, -2.0, np.inf)


def _cycles_of(edges: list[tuple[int, int]], chosen: IntArray) -> list[list[int]]:
    """Split a 2-regular edge set into cycles, each as an ordered list of edge indices."""
    at: dict[int, list[int]] = {}
    for e in chosen:
        for v in edges[e]:
            at.setdefault(v, []).append(int(e))
    seen: set[int] = set()
    cycles: list[list[int]] = []
    for e0 in chosen:
        if int(e0) in seen:
            continue
        cyc = [int(e0)]
        seen.add(int(e0))
        start, cur = edges[e0]
        while cur != start:
            nxt = [e for e in at[cur] if e not in seen]
            if not nxt:
                break
            e = nxt[0]
            seen.add(e)
            cyc.append(e)
            u, v = edges[e]
            cur = v if u == cur else u
        cycles.append(cyc)
    return cycles


def cycle_steps(problem: _Problem, cyc: list[int]) -> list[Step]:
    """Steps ``(gap, tile)`` of a cycle given as ordered edges (virtual edge tile -1)."""
    edges = problem.edges
    u0, v0 = edges[cyc[0]]
    start = u0
    if len(cyc) > 1 and u0 in edges[cyc[1]] and v0 not in edges[cyc[1]]:
        start = v0
    steps: list[Step] = []
    cur = start
    for e in cyc:
        u, v = edges[e]
        steps.append((cur, problem.edge_tile[e]))
        cur = v if u == cur else u
    return steps


def reverse_steps(steps: list[Step]) -> list[Step]:
    """The same cycle run backwards, starting at the same gap."""
    gaps = [g for g, _ in steps]
    tiles = [t for _, t in steps]
    r = len(steps)
    return [(gaps[-k % r], tiles[(-k - 1) % r]) for k in range(r)]
