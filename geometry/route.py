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
remains; HiGHS proves optimality.  Large instances use ``"heuristic: boundary-DP +
window-MILP"``: a dynamic program over the boundary tiles in their order along the outer
boundary (one step per tile, consecutive tiles partners, short bridges through interior tiles
where two consecutive boundary tiles are not partners) builds the minimum-turn boundary loop;
each lift gap not on it is spliced in by solving the same integer program exactly on a window (a
stretch of the loop plus a corridor to the lift gap) with the rest of the loop fixed, growing the
window until it succeeds.  If the dynamic program's loop reuses a gap or a tile (a ring two
tiles wide), the integer program is solved on the band of tiles next to the boundary instead.
The heuristic's lower bound is ``2 pi`` (a simple closed polygon turns at least once around).
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

#: Largest number of gaps solved by the exact integer program by default.
EXACT_LIMIT_DEFAULT = 40
#: Time limit of one integer-program solve, s.
MILP_TIME_LIMIT_S = 20.0
#: Windows tried in turn when splicing a lift gap into the loop: (loop gaps each side of the
#: loop gap nearest to the lift gap, corridor half-width in median gap spacings around the
#: segment to the lift gap, time limit of the window's integer program in s).  A window solve
#: that stops at its time limit with a valid path keeps it (not proven optimal).
SPLICE_WINDOWS: tuple[tuple[int, float, float], ...] = (
    (3, 2.0, 1.0),
    (3, 2.0, 5.0),
    (5, 3.0, 5.0),
    (8, 4.5, 5.0),
    (12, 6.5, 5.0),
)

Step = tuple[int, int]  # (gap the string crosses into the tile, tile)


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
    channel_partners_ok: bool = True
    tiles_passed_once: bool = True
    lifts_missed: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    notes: tuple[str, ...] = field(default=())


# --------------------------------------------------------------------------------------------
# gap graph and contact partners


def node_labels(linkage: Linkage) -> NDArray[np.int64]:
    """(G,) int label of every gap: 0 vertical, 1 horizontal, -1 entrance, -2 split."""
    return np.array([_LABEL[k] for k in linkage.gap_kind], dtype=np.int64)


def contact_partners(linkage: Linkage) -> NDArray[np.int64]:
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


@dataclass(frozen=True)
class _Rules:
    """Contact partners and the split rule, indexed for the solvers."""

    sides: dict[tuple[int, int, int], tuple[int, int]]  # (gap, a, b) -> (side of a, side of b)
    allowed: frozenset[tuple[int, int, int]]  # (gap, a, b): the string may pass a -> b at gap
    tile_gaps: dict[int, tuple[int, ...]]  # tile -> gaps where it has an allowed partner
    gap_tiles: dict[int, tuple[int, ...]]  # gap -> tiles with an allowed partner there


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


def _check_positions(linkage: Linkage, positions: ArrayLike) -> NDArray[np.float64]:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[0] != linkage.n_gaps or pos.shape[1] < 2:
        raise InputError(
            f"gap centroids have shape {pos.shape}; pass ({linkage.n_gaps}, 2) flat positions in mm"
        )
    return pos[:, :2]


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


def _build_problem(
    rules: _Rules,
    pos: NDArray[np.float64],
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
    problem.forbid_pairs = _crossing_pairs(edges, pos)
    return problem


def _crossing_pairs(
    edges: list[tuple[int, int]], pos: NDArray[np.float64]
) -> list[tuple[int, int]]:
    """Pairs of edge indices whose segments cross (parallel edges share their geometry)."""
    if len(edges) < 2:
        return []
    geo, inverse = np.unique(np.array(edges, dtype=np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    members: dict[int, list[int]] = {}
    for e, k in enumerate(inverse.tolist()):
        members.setdefault(k, []).append(e)
    out: list[tuple[int, int]] = []
    for a, b in crossing_edge_pairs(geo, pos).tolist():
        out.extend((x, y) for x in members[a] for y in members[b])
    return out


def _solve_cycle(
    problem: _Problem, rules: _Rules, pos: NDArray[np.float64], time_limit: float
) -> tuple[list[int], float, bool]:
    """Minimum-turn single cycle of the program.

    Returns the cycle's edge indices in order, its cost and whether HiGHS proved optimality.
    Raises DesignError when no valid cycle exists.
    """
    edges, edge_tile = problem.edges, problem.edge_tile
    n_e = len(edges)
    node_index = {v: k for k, v in enumerate(problem.nodes)}
    n_v = len(problem.nodes)
    incident: list[list[int]] = [[] for _ in range(n_v)]
    for e, (u, v) in enumerate(edges):
        incident[node_index[u]].append(e)
        incident[node_index[v]].append(e)
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
    n_t = len(turns)
    off_y, off_x = n_e, n_e + n_t
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
    integrality = np.ones(n_var)
    upper = np.ones(n_var)
    if problem.flow and problem.required:
        # single-commodity flow from a required gap to every visited gap: one cycle at once
        off_f, source, cap = n_var, node_index[min(problem.required)], float(n_v - 1)
        n_var += 2 * n_e
        integrality = np.concatenate([integrality, np.zeros(2 * n_e)])
        upper = np.concatenate([upper, np.full(2 * n_e, cap)])
        net: list[dict[int, float]] = [dict() for _ in range(n_v)]
        for e, (u, v) in enumerate(edges):
            add({off_f + 2 * e: 1.0, off_f + 2 * e + 1: 1.0, e: -cap}, -np.inf, 0.0)
            iu, iv = node_index[u], node_index[v]
            net[iv][off_f + 2 * e] = 1.0  # u -> v flows into v
            net[iu][off_f + 2 * e] = -1.0
            net[iu][off_f + 2 * e + 1] = 1.0  # v -> u flows into u
            net[iv][off_f + 2 * e + 1] = -1.0
        for k in range(n_v):
            if k != source:
                coefs = dict(net[k])
                coefs[off_x + k] = -1.0
                add(coefs, 0.0, 0.0)

    lb = np.zeros(n_var)
    ub = upper
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
            # milp status 2: proved infeasible; otherwise a time or iteration limit was hit
            rule = (
                "that passes every boundary tile and each tile and gap at most once between "
                "contact partners without crossing itself"
            )
            if res.status == 2:
                raise DesignError(
                    f"no closed string route exists {rule}; a shape part only one or two tiles "
                    "wide has none: use more tiles (--tiles or --grid)"
                )
            raise DesignError(
                f"no closed string route was found within {time_limit:g} s {rule}; the route "
                "program is too large for its time limit: use fewer tiles (--tiles or --grid)"
            )
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


def _cycle_steps(problem: _Problem, cyc: list[int]) -> list[Step]:
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


def _reverse_steps(steps: list[Step]) -> list[Step]:
    """The same cycle run backwards, starting at the same gap."""
    gaps = [g for g, _ in steps]
    tiles = [t for _, t in steps]
    r = len(steps)
    return [(gaps[-k % r], tiles[(-k - 1) % r]) for k in range(r)]


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


def _turn(pos: NDArray[np.float64], a: int, b: int, c: int) -> float:
    """Turn angle (rad) at gap ``b`` between gaps ``a`` and ``c``."""
    d1x, d1y = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1]
    d2x, d2y = pos[c, 0] - pos[b, 0], pos[c, 1] - pos[b, 1]
    return abs(math.atan2(d1x * d2y - d1y * d2x, d1x * d2x + d1y * d2y))


def _bridges(
    rules: _Rules,
    pos: NDArray[np.float64],
    boundary: NDArray[np.bool_],
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


def _boundary_loop_dp(
    rules: _Rules, pos: NDArray[np.float64], order: list[int], boundary: NDArray[np.bool_]
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
    mats: list[NDArray[np.float64]] = []
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
    back: list[NDArray[np.int64]] = []
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
    rules: _Rules,
    pos: NDArray[np.float64],
    cover: set[int],
    groups: Sequence[set[int]],
    layers: int,
    time_limit: float,
) -> tuple[list[Step], float, bool]:
    """The exact program on the boundary tiles and the tiles within ``layers`` steps of them."""
    band = set(cover)
    for _ in range(layers):
        band |= {u for t in band for g in rules.tile_gaps.get(t, ()) for u in rules.gap_tiles[g]}
    nodes = {g for t in band for g in rules.tile_gaps.get(t, ())}
    touched = [grp for grp in groups if grp & band]
    problem = _build_problem(rules, pos, nodes, set(), cover, tiles=band, groups=touched)
    cyc, cost, optimal = _solve_cycle(problem, rules, pos, time_limit)
    return _cycle_steps(problem, cyc), cost, optimal


def _splice_lift(
    rules: _Rules,
    pos: NDArray[np.float64],
    steps: list[Step],
    lift: int,
    cover: set[int],
    lifts: set[int],
    spacing: float,
    time_limit: float,
    half_window: int,
    corridor: float,
    component: NDArray[np.int64] | None = None,
) -> list[Step]:
    """Re-route a window of the loop so that it passes ``lift``, solving the window exactly.

    The window is the loop stretch of ``2 half_window + 1`` gaps around the loop gap nearest to
    the lift gap plus every gap within ``corridor`` gap spacings of the segment from that gap to
    the lift gap.  With ``component`` (each tile's split part), that loop gap is the nearest
    one where the loop runs through a tile of the lift gap's part: a detour from another part
    would have to cross the cut, which the rules forbid in the interior.

    The rest of the loop is fixed: the window's path joins it at the same two
    gaps ``p0``, ``q1`` (contact partners of the fixed tiles there, paying the turns there), uses
    none of its gaps or tiles, crosses none of its segments, and passes every boundary tile that
    the removed stretch passed.  Raises DesignError when the window holds no such path.
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
    problem = _build_problem(rules, pos, nodes, required, need, tiles=allowed_tiles)
    keep = [e for e, (u, v) in enumerate(problem.edges) if {u, v} != {p0, q1}]
    edges = [problem.edges[e] for e in keep]
    problem.edge_tile = [problem.edge_tile[e] for e in keep]
    remap = {e: k for k, e in enumerate(keep)}
    problem.forbid_pairs = [
        (remap[x], remap[y]) for x, y in problem.forbid_pairs if x in remap and y in remap
    ]
    fixed_path = [g for g, _ in fixed_steps] + [p0]
    if edges:
        ea = np.array(edges, dtype=np.int64)
        fa = np.array(fixed_path[:-1], dtype=np.int64)
        fb = np.array(fixed_path[1:], dtype=np.int64)
        hit = _segments_cross(
            pos[ea[:, 0]][:, None], pos[ea[:, 1]][:, None], pos[fa][None], pos[fb][None]
        ).any(axis=1)
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
    cyc, _cost, _optimal = _solve_cycle(problem, rules, pos, time_limit)
    loop = _cycle_steps(problem, cyc)
    k = next(i for i, (_g, t) in enumerate(loop) if t < 0)
    if loop[k][0] == p0:  # runs q1 ... p0 -> q1: turn it round
        loop = _reverse_steps(loop)
        k = next(i for i, (_g, t) in enumerate(loop) if t < 0)
    path = loop[k + 1 :] + loop[:k]
    if not path or path[0][0] != p0 or loop[k][0] != q1:
        raise DesignError(f"could not splice lift gap {lift} into the string route")
    return path + fixed_steps


# --------------------------------------------------------------------------------------------
# route assembly


def _side_facing(linkage: Linkage, tile: int, gap: int) -> int:
    sides = linkage.gap_sides[gap]
    hit = sides[sides[:, 0] == tile]
    return int(hit[0, 1]) if len(hit) else -1


def _finish(
    linkage: Linkage,
    rules: _Rules,
    pos: NDArray[np.float64],
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


def channel_partner_faults(route: Route, linkage: Linkage) -> NDArray[np.int64]:
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


def _median_spacing(pos: NDArray[np.float64]) -> float:
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
    time_limit_s: float = MILP_TIME_LIMIT_S,
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
    time_limit_s : time limit of every whole-instance integer-program solve.
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
        raise InputError(f"lift gaps {lifts.tolist()} are not gap ids 0..{linkage.n_gaps - 1}")
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
            rules, pos, linkage.n_gaps, reachable, cover, groups, time_limit_s, missed, notes
        )
        method = "exact" if optimal else "heuristic: MILP stopped at its time limit"
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
        steps = _band_loop_any(rules, pos, cover, groups, time_limit_s)
    spacing = _median_spacing(pos)
    for lift in sorted(reachable):
        if lift in {g for g, _ in steps}:
            continue
        reason = ""
        for half_window, corridor, limit in SPLICE_WINDOWS:
            try:
                steps = _splice_lift(
                    rules,
                    pos,
                    steps,
                    lift,
                    cover,
                    lift_set,
                    spacing,
                    min(time_limit_s, limit),
                    half_window,
                    corridor,
                    linkage.tile_component,
                )
                break
            except DesignError as err:
                reason = str(err)
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


def _band_loop_any(
    rules: _Rules,
    pos: NDArray[np.float64],
    cover: set[int],
    groups: Sequence[set[int]],
    time_limit: float,
) -> list[Step]:
    """The band program with one, then two, then three layers of interior tiles."""
    err: DesignError | None = None
    for layers in (1, 2, 3):
        try:
            return _band_loop(rules, pos, cover, groups, layers, time_limit)[0]
        except DesignError as e:
            err = e
    raise DesignError(
        "no closed string route passes every boundary tile once under the contact-partner"
        f" rules ({err}); is part of the shape only two tiles wide?"
    )


def _exact(
    rules: _Rules,
    pos: NDArray[np.float64],
    n_gaps: int,
    lifts: set[int],
    cover: set[int],
    groups: Sequence[set[int]],
    time_limit: float,
    missed: list[int],
    notes: list[str],
) -> tuple[list[Step], float, bool]:
    """Whole-instance program; lift gaps that make it infeasible are dropped one by one."""

    def solve(required: set[int]) -> tuple[list[Step], float, bool]:
        problem = _build_problem(rules, pos, range(n_gaps), required, cover, groups=groups)
        cyc, cost, optimal = _solve_cycle(problem, rules, pos, time_limit)
        return _cycle_steps(problem, cyc), cost, optimal

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
        except DesignError:
            missed.append(g)
            notes.append(
                f"lift gap {g} cannot be reached: no valid closed route passes it together with"
                " every boundary tile (contact partners, each gap and tile once, no crossing)"
            )
    return base


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
    ax.plot(pos[entr, 0], pos[entr, 1], "o", mfc="none", mec="k", ms=6, label="entrances", zorder=4)
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
