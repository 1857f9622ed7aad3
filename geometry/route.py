"""Closed minimum-turn string route through the boundary tiles and the lift points (section 5.3).

The gap graph (paper Fig. 8) lives on the flat configuration: one node per gap, labelled

* ``0`` vertical and ``1`` horizontal gaps (four tiles, not on a split);
* ``-1`` virtual boundary entrances: the linkage's ``boundary`` gaps, the notches where two or
  three boundary tiles meet at an unhinged vertex of the outer boundary.  The paper's entrances
  are "not physical gaps" because its graph only holds four-tile voids; in our topology these
  notches are exactly the places where the void opens to the outside of the structure, so the
  string can come in from outside between two boundary tiles without passing a hinge or sharing a
  void with another strand.  Using them avoids inventing nodes at hinged boundary joints (where
  tiles touch and no string can pass between them);
* ``-2`` split gaps (linkage kind ``split``), on a cut between two components.

Two gaps are adjacent when the string can pass from one to the other through a single tile, i.e.
they share a tile; it then enters that tile through the side face exposed to the first gap and
leaves through the side exposed to the second.

A valid route is a closed cycle (each gap at most once, so no two strands share a void) whose
steps pass every boundary tile and whose nodes include every lift gap, with no two steps crossing
geometrically.  Split rule (paper "Connecting splits"): the string may pass a ``-2`` gap only
where the cut meets the outer boundary (the gap has fewer than four tiles, so every tile around
it is a boundary tile and the string keeps running along the boundary); four-tile split gaps
inside the structure are never used, so the string never enters the interior through a cut.  As
the outer boundary crosses every cut at a boundary split gap, covering all boundary tiles visits
every component and ties each to its neighbours.

Objective: the total turn angle, at every node the angle between the incoming and outgoing
direction through the flat-configuration gap centroids (0 for straight), which is the exponent
of the capstan factor ``exp(mu * total)``.

Solvers: ``"exact"`` is an integer program (``scipy.optimize.milp``, HiGHS): binary edge, node
and turn (pair of edges at a node) variables, tile-choice variables for steps between gaps
sharing two tiles, crossing-pair exclusions, and connectivity cuts added until one cycle
remains; HiGHS proves optimality.  Large instances use ``"heuristic: boundary-DP + window-MILP"``:
a dynamic program over the boundary tiles in their order along the outer boundary builds the
minimum-turn loop that passes them in that order, then each lift point not on it is spliced in
by solving the same integer program exactly on a window (a corridor from the lift gap to the
nearest part of the loop) with the rest of the route fixed.  Its lower bound is ``2 pi`` (a
simple closed polygon turns at least once around).
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import networkx as nx
import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.spatial import cKDTree

from .errors import DesignError, InputError
from .linkage import Linkage

log = logging.getLogger(__name__)

NODE_VERTICAL, NODE_HORIZONTAL, NODE_ENTRANCE, NODE_SPLIT = 0, 1, -1, -2
_LABEL = {
    "vertical": NODE_VERTICAL,
    "horizontal": NODE_HORIZONTAL,
    "boundary": NODE_ENTRANCE,
    "split": NODE_SPLIT,
}

#: Largest number of usable gaps solved by the exact integer program by default.
EXACT_LIMIT_DEFAULT = 40
#: Time limit of one integer-program solve, s.
MILP_TIME_LIMIT_S = 20.0


@dataclass(frozen=True)
class Route:
    """A closed string route on the gap graph.

    Attributes
    ----------
    gaps : (r,) int, the cyclic sequence of gaps (the route closes from the last to the first).
    labels : (r,) int, node label of each gap (0, 1, -1 entrance, -2 split).
    tiles : (r,) int, tile the string passes from ``gaps[k]`` to ``gaps[(k + 1) % r]``.
    enter_side : (r,) int, side (0 bottom, 1 right, 2 top, 3 left) of ``tiles[k]`` facing
        ``gaps[k]``, where the string enters the tile.
    leave_side : (r,) int, side of ``tiles[k]`` facing ``gaps[k + 1]``, where it leaves.
    turn_angle_total_rad : float, sum of the turn angles at all nodes (flat centroids).
    method : ``"exact"`` or ``"heuristic: <name>"``.
    lower_bound_rad : float or None, a proven lower bound on the optimum total turn.
    crossings : int, gaps visited twice plus pairs of route segments that intersect.
    boundary_tiles_covered : bool, measured: every boundary tile is some ``tiles[k]``.
    length_flat_mm : float, polyline length through the flat gap centroids.
    """

    gaps: NDArray[np.int64]
    labels: NDArray[np.int64]
    tiles: NDArray[np.int64]
    enter_side: NDArray[np.int64]
    leave_side: NDArray[np.int64]
    turn_angle_total_rad: float
    method: str
    lower_bound_rad: float | None
    crossings: int
    boundary_tiles_covered: bool
    length_flat_mm: float
    notes: tuple[str, ...] = field(default=())


# --------------------------------------------------------------------------------------------
# gap graph


def node_labels(linkage: Linkage) -> NDArray[np.int64]:
    """(G,) int label of every gap: 0 vertical, 1 horizontal, -1 entrance, -2 split."""
    return np.array([_LABEL[k] for k in linkage.gap_kind], dtype=np.int64)


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
    ``tiles`` (tuple), and edge attribute ``tiles``: the tiles the two gaps share (1 or 2).
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


def _check_positions(linkage: Linkage, positions: ArrayLike) -> NDArray[np.float64]:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[0] != linkage.n_gaps or pos.shape[1] < 2:
        raise InputError(
            f"gap centroids have shape {pos.shape}; pass ({linkage.n_gaps}, 2) flat positions in mm"
        )
    return pos[:, :2]


def usable_gaps(linkage: Linkage, lift_gaps: ArrayLike = ()) -> NDArray[np.bool_]:
    """(G,) bool, gaps the route may pass: all but four-tile split gaps (lift gaps always)."""
    n_tiles = (linkage.gap_sides[:, :, 0] >= 0).sum(axis=1)
    ok = ~((node_labels(linkage) == NODE_SPLIT) & (n_tiles >= 4))
    ok[np.asarray(lift_gaps, dtype=np.int64)] = True
    return np.asarray(ok)


# --------------------------------------------------------------------------------------------
# geometry helpers


def turn_angle(a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]) -> Any:
    """Angle (rad) between directions ``b - a`` and ``c - b``; broadcasts over leading axes."""
    d1, d2 = b - a, c - b
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    dot = (d1 * d2).sum(-1)
    return np.abs(np.arctan2(cross, dot))


def _segments_cross(
    p1: NDArray[np.float64],
    p2: NDArray[np.float64],
    q1: NDArray[np.float64],
    q2: NDArray[np.float64],
    eps: float = 1e-9,
) -> NDArray[np.bool_]:
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


def crossing_edge_pairs(edges: NDArray[np.int64], pos: NDArray[np.float64]) -> NDArray[np.int64]:
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
    hit = ~share & _segments_cross(a[i], b[i], a[j], b[j])
    return np.asarray(pairs[hit], dtype=np.int64)


# --------------------------------------------------------------------------------------------
# the integer program


@dataclass
class _Problem:
    """An instance of the cycle program on a node subset (global gap ids)."""

    nodes: list[int]
    edges: list[tuple[int, int]]
    edge_tiles: list[tuple[int, ...]]
    pos: NDArray[np.float64]
    required: set[int]
    cover: set[int]
    fixed: set[int] = field(default_factory=set)  # edge indices forced into the cycle
    virtual: set[int] = field(default_factory=set)  # edge indices without geometry or tile
    forbid_pairs: list[tuple[int, int]] = field(default_factory=list)  # edge index pairs
    free_turn_nodes: set[int] = field(default_factory=set)  # turns there cost nothing
    banned: set[int] = field(default_factory=set)  # edge indices forced out
    edge_cost: dict[int, float] = field(default_factory=dict)  # extra linear cost per edge


def _solve_cycle(problem: _Problem, time_limit: float) -> tuple[list[int], float, bool]:
    """Minimum-turn single cycle of the program; returns (cycle edge indices, cost, optimal)."""
    edges = problem.edges
    n_e = len(edges)
    node_index = {v: k for k, v in enumerate(problem.nodes)}
    n_v = len(problem.nodes)
    incident: list[list[int]] = [[] for _ in range(n_v)]
    for e, (u, v) in enumerate(edges):
        incident[node_index[u]].append(e)
        incident[node_index[v]].append(e)
    # turn variables: (node, e1, e2)
    turns: list[tuple[int, int, int]] = []
    cost: list[float] = []
    pos = problem.pos
    for k, v in enumerate(problem.nodes):
        inc = incident[k]
        for a in range(len(inc)):
            for b in range(a + 1, len(inc)):
                e1, e2 = inc[a], inc[b]
                turns.append((k, e1, e2))
                if v in problem.free_turn_nodes or e1 in problem.virtual or e2 in problem.virtual:
                    cost.append(0.0)
                else:
                    u = edges[e1][0] if edges[e1][1] == v else edges[e1][1]
                    w = edges[e2][0] if edges[e2][1] == v else edges[e2][1]
                    cost.append(float(turn_angle(pos[u], pos[v], pos[w])))
    # tile choice variables for edges with two candidate tiles
    choice: list[tuple[int, int]] = []
    for e, ts in enumerate(problem.edge_tiles):
        if e not in problem.virtual and len(ts) > 1:
            choice.extend((e, t) for t in ts)
    n_t, n_c = len(turns), len(choice)
    off_y, off_s, off_x = n_e, n_e + n_t, n_e + n_t + n_c
    n_var = off_x + n_v
    rows: list[tuple[dict[int, float], float, float]] = []

    def add(coefs: dict[int, float], lo: float, hi: float) -> None:
        rows.append((coefs, lo, hi))

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
    by_edge: dict[int, list[int]] = {}
    for c_i, (e, _t) in enumerate(choice):
        by_edge.setdefault(e, []).append(c_i)
    for e, cs in by_edge.items():
        c = {off_s + c_i: 1.0 for c_i in cs}
        c[e] = -1.0
        add(c, 0.0, 0.0)
    passing: dict[int, dict[int, float]] = {}
    for e, ts in enumerate(problem.edge_tiles):
        if e in problem.virtual:
            continue
        if len(ts) == 1:
            passing.setdefault(ts[0], {})[e] = 1.0
    for c_i, (_e, t) in enumerate(choice):
        passing.setdefault(t, {})[off_s + c_i] = 1.0
    for t in problem.cover:
        if t not in passing:
            raise DesignError(f"boundary tile {t} cannot be passed by any usable step")
        add(passing[t], 1.0, np.inf)
    for e1, e2 in problem.forbid_pairs:
        add({e1: 1.0, e2: 1.0}, -np.inf, 1.0)

    lb = np.zeros(n_var)
    ub = np.ones(n_var)
    for e in problem.fixed:
        lb[e] = 1.0
    for e in problem.banned:
        ub[e] = 0.0
    for v in problem.required:
        lb[off_x + node_index[v]] = 1.0
    objective = np.zeros(n_var)
    objective[off_y : off_y + n_t] = cost
    for e, c_e in problem.edge_cost.items():
        objective[e] += c_e
    integrality = np.ones(n_var)

    def matrix(rs: list[tuple[dict[int, float], float, float]]) -> LinearConstraint:
        r_idx, c_idx, vals = [], [], []
        for r, (coefs, _lo, _hi) in enumerate(rs):
            for c, v in coefs.items():
                r_idx.append(r)
                c_idx.append(c)
                vals.append(v)
        mat = sp.csr_matrix((vals, (r_idx, c_idx)), shape=(len(rs), n_var))
        return LinearConstraint(mat, np.array([r[1] for r in rs]), np.array([r[2] for r in rs]))

    optimal = True
    for _round in range(500):
        res = milp(
            objective,
            constraints=[matrix(rows)],
            integrality=integrality,
            bounds=Bounds(lb, ub),
            options={"time_limit": time_limit, "disp": False},
        )
        if res.x is None:
            raise DesignError(f"no valid closed string route exists ({res.message})")
        if res.status != 0:
            optimal = False
        z = res.x[:n_e] > 0.5
        cycles = _cycles_of(edges, np.nonzero(z)[0])
        if len(cycles) == 1:
            log.debug("route program: %d rounds, %d variables", _round + 1, n_var)
            return cycles[0], float(res.fun), optimal
        sets = [{u for e in cyc for u in edges[e]} for cyc in cycles]
        for a, s_a in enumerate(sets):
            cut = {e: 1.0 for e, (u, v) in enumerate(edges) if (u in s_a) != (v in s_a)}
            must_leave = bool(problem.required - s_a) or any(
                e not in cycles[a] for e in problem.fixed
            )
            if must_leave:
                for v in s_a:
                    c = dict(cut)
                    c[off_x + node_index[v]] = -2.0
                    add(c, 0.0, np.inf)
            else:
                v0 = min(s_a)
                for b, s_b in enumerate(sets):
                    if b != a:
                        c = dict(cut)
                        c[off_x + node_index[v0]] = -2.0
                        c[off_x + node_index[min(s_b)]] = -2.0
                        add(c, -2.0, np.inf)
    raise DesignError("string route program did not converge to one cycle")


def _cycles_of(edges: list[tuple[int, int]], chosen: NDArray[np.int64]) -> list[list[int]]:
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


def _cycle_nodes(edges: list[tuple[int, int]], cyc: list[int]) -> list[int]:
    """Ordered nodes of a cycle given as ordered edges: node k joins edge k-1 and edge k."""
    if len(cyc) == 1:
        return list(edges[cyc[0]])
    first, second = edges[cyc[0]], edges[cyc[1]]
    start = first[0] if first[0] not in second else first[1]
    nodes = [start]
    cur = start
    for e in cyc:
        u, v = edges[e]
        cur = v if u == cur else u
        nodes.append(cur)
    return nodes[:-1]


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

                def key(t: int, base: float = base, centre: NDArray[np.float64] = centre) -> float:
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


def _boundary_loop_dp(
    graph: nx.Graph, pos: NDArray[np.float64], order: list[int], usable: NDArray[np.bool_]
) -> list[tuple[int, int]]:
    """Minimum-turn closed walk whose steps pass the boundary tiles in ``order``.

    States are directed steps ``(a, b, tile, k)`` passing boundary tile ``order[k]``; a state
    moves on to a step leaving ``b`` through the same tile (``k``) or through the next tile
    (``k + 1``), paying the turn at ``b``.  The walk closes on its first step.  Returns the
    steps as ``(gap, tile)``: the gap the step starts from and the tile it passes.
    """
    n_b = len(order)
    if n_b == 0:
        raise DesignError("the linkage has no boundary tiles to route the string through")
    steps_by_tile: dict[int, list[tuple[int, int]]] = {t: [] for t in order}
    for u, v, data in graph.edges(data=True):
        if not (usable[u] and usable[v]):
            continue
        for t in data["tiles"]:
            if t in steps_by_tile:
                steps_by_tile[t] += [(u, v), (v, u)]
    best_cost, best_path = math.inf, None
    for a0, b0 in steps_by_tile[order[0]]:
        start = (a0, b0, 0)
        dist: dict[tuple[int, int, int], float] = {start: 0.0}
        prev: dict[tuple[int, int, int], tuple[int, int, int]] = {}
        heap: list[tuple[float, tuple[int, int, int]]] = [(0.0, start)]
        goal = (a0, b0, n_b)
        while heap:
            d, s = heapq.heappop(heap)
            if d > dist.get(s, math.inf) or d >= best_cost:
                continue
            if s == goal:
                break
            a, b, k = s
            for kk in (k, k + 1):
                if kk > n_b:
                    continue
                tile = order[kk % n_b]
                for u, c in steps_by_tile[tile]:
                    if u != b or c == a:
                        continue
                    if kk == n_b and (b, c) != (a0, b0):
                        continue
                    ns = (b, c, kk)
                    nd = d + float(turn_angle(pos[a], pos[b], pos[c]))
                    if nd < dist.get(ns, math.inf):
                        dist[ns] = nd
                        prev[ns] = s
                        heapq.heappush(heap, (nd, ns))
        if goal in dist and dist[goal] < best_cost:
            best_cost = dist[goal]
            path = [goal]
            while path[-1] != start:
                path.append(prev[path[-1]])
            best_path = path[::-1][:-1]
    if best_path is None:
        raise DesignError("no closed string loop passes the boundary tiles in order")
    return [(a, order[k % n_b]) for a, _b, k in best_path]


# --------------------------------------------------------------------------------------------
# route assembly


def _build_problem(
    graph: nx.Graph,
    pos: NDArray[np.float64],
    nodes: Sequence[int],
    required: set[int],
    cover: set[int],
) -> _Problem:
    node_set = set(nodes)
    sub = graph.subgraph(node_set)
    edges = sorted((min(u, v), max(u, v)) for u, v in sub.edges())
    tiles = [tuple(sub.edges[u, v]["tiles"]) for u, v in edges]
    arr = np.array(edges, dtype=np.int64).reshape(-1, 2)
    pairs = crossing_edge_pairs(arr, pos)
    return _Problem(
        nodes=sorted(node_set),
        edges=list(edges),
        edge_tiles=tiles,
        pos=pos,
        required=set(required),
        cover=set(cover),
        forbid_pairs=[(int(a), int(b)) for a, b in pairs],
    )


def _assign_tiles(
    graph: nx.Graph, cycle: list[int], cover: set[int], hint: dict[tuple[int, int], int]
) -> list[int]:
    """Pick the tile of every step so that every tile in ``cover`` is passed (bipartite match)."""
    r = len(cycle)
    options = []
    for k in range(r):
        u, v = cycle[k], cycle[(k + 1) % r]
        options.append(tuple(graph.edges[u, v]["tiles"]))
    chosen = [
        hint.get((min(u, v), max(u, v)), opts[0])
        for (u, v), opts in zip(
            ((cycle[k], cycle[(k + 1) % r]) for k in range(r)), options, strict=True
        )
    ]
    chosen = [c if c in o else o[0] for c, o in zip(chosen, options, strict=True)]
    ambiguous = [k for k in range(r) if len(options[k]) > 1]
    if not ambiguous:
        return chosen
    fixed_cover = {chosen[k] for k in range(r) if len(options[k]) == 1}
    need = [t for t in cover if t not in fixed_cover]
    bip = nx.Graph()
    bip.add_nodes_from(("s", k) for k in ambiguous)
    bip.add_nodes_from(("t", t) for t in need)
    for k in ambiguous:
        for t in options[k]:
            if t in need:
                bip.add_edge(("s", k), ("t", t))
    match = nx.bipartite.maximum_matching(bip, top_nodes=[("s", k) for k in ambiguous])
    for k in ambiguous:
        m = match.get(("s", k))
        if m is not None:
            chosen[k] = int(m[1])
    return chosen


def _finish(
    linkage: Linkage,
    graph: nx.Graph,
    pos: NDArray[np.float64],
    cycle: list[int],
    tiles: list[int],
    method: str,
    lower_bound: float | None,
    notes: tuple[str, ...] = (),
) -> Route:
    r = len(cycle)
    gaps = np.array(cycle, dtype=np.int64)
    tl = np.array(tiles, dtype=np.int64)
    nxt = np.roll(gaps, -1)
    enter = np.array([_side_facing(linkage, t, g) for t, g in zip(tl, gaps, strict=True)])
    leave = np.array([_side_facing(linkage, t, g) for t, g in zip(tl, nxt, strict=True)])
    p = pos[gaps]
    total = float(turn_angle(np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0)).sum()) if r else 0.0
    covered = set(tl.tolist()) >= set(np.nonzero(linkage.boundary_tile)[0].tolist())
    return Route(
        gaps=gaps,
        labels=node_labels(linkage)[gaps],
        tiles=tl,
        enter_side=enter.astype(np.int64),
        leave_side=leave.astype(np.int64),
        turn_angle_total_rad=total,
        method=method,
        lower_bound_rad=lower_bound,
        crossings=count_crossings(gaps, pos),
        boundary_tiles_covered=bool(covered),
        length_flat_mm=float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum()),
        notes=notes,
    )


def _side_facing(linkage: Linkage, tile: int, gap: int) -> int:
    sides = linkage.gap_sides[gap]
    hit = sides[sides[:, 0] == tile]
    return int(hit[0, 1]) if len(hit) else -1


def count_crossings(gaps: NDArray[np.int64], pos: NDArray[np.float64]) -> int:
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


def plan_route(
    linkage: Linkage,
    gap_centroids_flat: ArrayLike,
    lift_gaps: ArrayLike = (),
    *,
    exact_limit: int = EXACT_LIMIT_DEFAULT,
    time_limit_s: float = MILP_TIME_LIMIT_S,
) -> Route:
    """Closed minimum-turn route through all boundary tiles and all lift gaps.

    Parameters
    ----------
    linkage : topology.
    gap_centroids_flat : (G, 2) float, mm, gap centroids in the flat configuration.
    lift_gaps : (k,) int, gaps the route must pass (lift points).
    exact_limit : solve the whole instance exactly when it has at most this many usable gaps;
        otherwise use the heuristic (boundary DP + exact windows around lift points).
    time_limit_s : time limit of every integer-program solve.

    Returns
    -------
    Route (``method`` says which solver ran; ``lower_bound_rad`` is the proven bound).
    """
    pos = _check_positions(linkage, gap_centroids_flat)
    lifts = np.unique(np.asarray(lift_gaps, dtype=np.int64))
    if lifts.size and (lifts.min() < 0 or lifts.max() >= linkage.n_gaps):
        raise InputError(f"lift gaps {lifts.tolist()} are not gap ids 0..{linkage.n_gaps - 1}")
    graph = gap_graph(linkage, pos)
    usable = usable_gaps(linkage, lifts)
    cover = set(np.nonzero(linkage.boundary_tile)[0].tolist())
    nodes = [int(g) for g in np.nonzero(usable)[0]]
    if len(nodes) <= exact_limit:
        problem = _build_problem(graph, pos, nodes, set(lifts.tolist()), cover)
        cyc, cost, optimal = _solve_cycle(problem, time_limit_s)
        cycle = _cycle_nodes(problem.edges, cyc)
        tiles = _assign_tiles(graph, cycle, cover, {})
        method = "exact" if optimal else "heuristic: MILP stopped at its time limit"
        return _finish(linkage, graph, pos, cycle, tiles, method, cost if optimal else 2 * math.pi)

    order = boundary_tile_order(linkage)
    steps = _boundary_loop_dp(graph, pos, order, usable)
    cycle = [g for g, _t in steps]
    hint = {}
    for k, (g, t) in enumerate(steps):
        h = cycle[(k + 1) % len(cycle)]
        hint[(min(g, h), max(g, h))] = t
    notes: list[str] = []
    if len(set(cycle)) != len(cycle):
        notes.append("boundary loop revisits a gap")
    for lift in lifts.tolist():
        if lift in cycle:
            continue
        cycle = _splice_lift(graph, pos, cycle, int(lift), usable, cover, time_limit_s)
    tiles = _assign_tiles(graph, cycle, cover, hint)
    return _finish(
        linkage,
        graph,
        pos,
        cycle,
        tiles,
        "heuristic: boundary-DP + window-MILP",
        2 * math.pi,
        tuple(notes),
    )


def _splice_lift(
    graph: nx.Graph,
    pos: NDArray[np.float64],
    cycle: list[int],
    lift: int,
    usable: NDArray[np.bool_],
    cover: set[int],
    time_limit: float,
    half_window: int = 3,
    corridor: float = 1.4,
) -> list[int]:
    """Re-route a window of the cycle so that it passes ``lift``, solving the window exactly.

    The window is the cycle stretch of ``2 half_window + 1`` nodes around the cycle node
    nearest to the lift gap plus every usable gap within ``corridor`` gap spacings of the
    segment from that node to the lift gap.  The rest of the cycle is fixed: the window's path
    joins it at the same two nodes with the same outside turns, and must still pass the boundary
    tiles that the removed stretch passed.
    """
    r = len(cycle)
    d = np.linalg.norm(pos[cycle] - pos[lift], axis=1)
    m = int(np.argmin(d))
    span = min(half_window, (r - 3) // 2)
    idx = [(m + k) % r for k in range(-span - 1, span + 2)]
    p0, q1 = cycle[idx[0]], cycle[idx[-1]]
    inner = [cycle[i] for i in idx[1:-1]]
    outside = set(cycle) - set(inner)
    spacing = float(np.median([np.linalg.norm(pos[u] - pos[v]) for u, v in graph.edges()]))
    a, b = pos[cycle[m]], pos[lift]
    seg = b - a
    all_nodes = np.nonzero(usable)[0]
    rel = pos[all_nodes] - a
    tpar = np.clip((rel @ seg) / max(float(seg @ seg), 1e-12), 0.0, 1.0)
    dist = np.linalg.norm(rel - tpar[:, None] * seg, axis=1)
    window = {int(g) for g in all_nodes[dist <= corridor * spacing]} | set(inner) | {lift}
    window -= outside
    nodes = window | {p0, q1}
    # tiles the removed stretch passed: those not passed by the fixed part
    fixed_tiles: set[int] = set()
    outside_order = [cycle[(idx[-1] + k) % r] for k in range(r - len(idx) + 2)]
    for u, v in zip(outside_order[:-1], outside_order[1:], strict=True):
        ts = graph.edges[u, v]["tiles"]
        if len(ts) == 1:
            fixed_tiles.add(ts[0])
    need = {
        t
        for t in cover
        if t not in fixed_tiles and any(t in graph.nodes[g]["tiles"] for g in window)
    }
    problem = _build_problem(graph, pos, sorted(nodes), {lift}, need)
    # only the two joining edges at p0 and q1, plus a virtual edge closing the loop outside
    keep = []
    for e, (u, v) in enumerate(problem.edges):
        if u in (p0, q1) or v in (p0, q1):
            other = v if u in (p0, q1) else u
            if other not in window:
                continue
        keep.append(e)
    edges = [problem.edges[e] for e in keep]
    tiles = [problem.edge_tiles[e] for e in keep]
    remap = {e: k for k, e in enumerate(keep)}
    forbid = [(remap[x], remap[y]) for x, y in problem.forbid_pairs if x in remap and y in remap]
    # exclude window edges crossing the fixed outside route
    fixed_segments = np.array(list(zip(outside_order[:-1], outside_order[1:], strict=True)))
    if len(fixed_segments) and edges:
        ea = np.array(edges)
        hit = _segments_cross(
            pos[ea[:, 0]][:, None],
            pos[ea[:, 1]][:, None],
            pos[fixed_segments[:, 0]][None],
            pos[fixed_segments[:, 1]][None],
        ).any(axis=1)
        bad = set(np.nonzero(hit)[0].tolist())
    else:
        bad = set()
    edges.append((min(p0, q1), max(p0, q1)))
    tiles.append(())
    virtual = len(edges) - 1
    problem = _Problem(
        nodes=sorted(nodes),
        edges=edges,
        edge_tiles=tiles,
        pos=pos,
        required={lift, p0, q1},
        cover=need,
        fixed={virtual},
        virtual={virtual},
        forbid_pairs=forbid,
        free_turn_nodes=set(),
    )
    # joining edges at p0 and q1: any window edge may join, the turn at p0 / q1 then uses the
    # fixed outside neighbour, so model p0 and q1 as free-turn nodes and add their outside turn
    # as a cost on the joining edges instead.
    problem.free_turn_nodes = {p0, q1}
    pre = cycle[(idx[0] - 1) % r]
    post = cycle[(idx[-1] + 1) % r]
    extra = np.zeros(len(edges))
    for e, (u, v) in enumerate(edges[:-1]):
        if p0 in (u, v):
            w = v if u == p0 else u
            extra[e] += float(turn_angle(pos[pre], pos[p0], pos[w]))
        if q1 in (u, v):
            w = v if u == q1 else u
            extra[e] += float(turn_angle(pos[w], pos[q1], pos[post]))
    problem.banned = bad
    problem.edge_cost = {e: float(c) for e, c in enumerate(extra) if c}
    cyc, _cost, _opt = _solve_cycle(problem, min(time_limit, 5.0))
    path = _cycle_nodes(problem.edges, cyc)
    # rotate so that the path runs p0 ... q1 without the virtual edge
    k = path.index(p0)
    path = path[k:] + path[:k]
    if path[1] == q1:
        path = [path[0]] + path[1:][::-1]
    if path[-1] != q1:
        raise DesignError(f"could not splice lift gap {lift} into the string route")
    start = idx[0]
    rest = [cycle[(start + len(idx) - 1 + k) % r] for k in range(1, r - len(idx) + 1)]
    return path + rest


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
        "closed": True,
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


def draw_route(ax: Any, route: Route, gap_centroids_flat: ArrayLike, lift_points: Any = ()) -> None:
    """Draw the closed route polyline and the lift points on a matplotlib Axes.

    Parameters
    ----------
    ax : matplotlib Axes.
    route : the route.
    gap_centroids_flat : (G, 2) float, mm.
    lift_points : gap ids, or an object with a ``lift_gaps`` attribute (``LiftPoints``).
    """
    pos = np.asarray(gap_centroids_flat, dtype=np.float64)[:, :2]
    gaps = np.append(route.gaps, route.gaps[:1])
    ax.plot(pos[gaps, 0], pos[gaps, 1], "-", color="crimson", lw=1.8, label="string", zorder=4)
    ax.plot(pos[route.gaps, 0], pos[route.gaps, 1], ".", color="crimson", ms=4, zorder=4)
    entr = route.gaps[route.labels == NODE_ENTRANCE]
    ax.plot(
        pos[entr, 0], pos[entr, 1], "o", mfc="none", mec="k", ms=6, label="entrances", zorder=4
    )
    lifts = np.asarray(getattr(lift_points, "lift_gaps", lift_points), dtype=np.int64)
    if lifts.size:
        ax.scatter(
            pos[lifts, 0],
            pos[lifts, 1],
            s=180,
            marker="*",
            c="red",
            edgecolors="black",
            zorder=5,
            label="lift points",
        )
    ax.set_aspect("equal")
