"""String route on the gap graph (paper section 5.3): validity, optimality on tiny grids."""

from __future__ import annotations

import math

import numpy as np
import pytest
from drawstring.geometry.linkage import Linkage, Split, build_linkage, rotating_squares_layout
from drawstring.geometry.route import (
    NODE_ENTRANCE,
    NODE_SPLIT,
    gap_graph,
    plan_route,
    route_metrics,
    route_to_json,
)
from numpy.typing import NDArray


def _centroids(linkage: Linkage, opening: float = 0.5) -> NDArray[np.float64]:
    """Flat gap centroids: mean of the midpoints of the side faces around each gap."""
    corners = rotating_squares_layout(linkage, opening, side=10.0)
    out = []
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        mids = [0.5 * (corners[t, k] + corners[t, (k + 1) % 4]) for t, k in sides]
        out.append(np.mean(mids, axis=0))
    return np.array(out)


def _gap_at(linkage: Linkage, i: int, j: int) -> int:
    ij = linkage.vertex_ij[linkage.gap_vertex]
    return int(np.nonzero((ij[:, 0] == i) & (ij[:, 1] == j))[0][0])


# ---- an independent brute force ---------------------------------------------------------------


def _turn(a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]) -> float:
    d1, d2 = b - a, c - b
    cos = float(d1 @ d2) / (np.linalg.norm(d1) * np.linalg.norm(d2))
    return math.acos(max(-1.0, min(1.0, cos)))


def _proper_cross(p1, p2, q1, q2) -> bool:  # type: ignore[no-untyped-def]
    def side(a, b, c):  # type: ignore[no-untyped-def]
        v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return 0 if abs(v) < 1e-9 else (1 if v > 0 else -1)

    return side(q1, q2, p1) * side(q1, q2, p2) < 0 and side(p1, p2, q1) * side(p1, p2, q2) < 0


def _covers(steps: list[set[int]], need: set[int]) -> bool:
    """Can every needed tile get its own step (each step passes one of its tiles)? Kuhn."""
    owner: dict[int, int] = {}

    def augment(t: int, seen: set[int]) -> bool:
        for s, opts in enumerate(steps):
            if t in opts and s not in seen:
                seen.add(s)
                if s not in owner.values() or augment(
                    next(k for k, v in owner.items() if v == s), seen
                ):
                    owner[t] = s
                    return True
        return False

    return all(augment(t, set()) for t in sorted(need))


def _brute_force(linkage: Linkage, pos: NDArray[np.float64], lifts: set[int]) -> float:
    tiles = [set(linkage.gap_tiles(g).tolist()) for g in range(linkage.n_gaps)]
    n = linkage.n_gaps
    nbr = [[h for h in range(n) if h != g and tiles[g] & tiles[h]] for g in range(n)]
    need = set(np.nonzero(linkage.boundary_tile)[0].tolist())
    best = [math.inf]

    def valid(cyc: list[int]) -> bool:
        if not lifts <= set(cyc):
            return False
        r = len(cyc)
        segs = [(pos[cyc[k]], pos[cyc[(k + 1) % r]]) for k in range(r)]
        for a in range(r):
            for b in range(a + 2, r):
                if a == 0 and b == r - 1:
                    continue
                if _proper_cross(*segs[a], *segs[b]):
                    return False
        steps = [tiles[cyc[k]] & tiles[cyc[(k + 1) % r]] for k in range(r)]
        return _covers(steps, need)

    def dfs(path: list[int], cost: float) -> None:
        if cost >= best[0] - 1e-12:
            return
        last = path[-1]
        for nxt in nbr[last]:
            if nxt == path[0] and len(path) >= 3:
                total = (
                    cost
                    + _turn(pos[path[-2]], pos[last], pos[nxt])
                    + _turn(pos[last], pos[nxt], pos[path[1]])
                )
                if total < best[0] - 1e-12 and valid(path):
                    best[0] = total
            elif nxt > path[0] and nxt not in path:
                add = _turn(pos[path[-2]], pos[last], pos[nxt]) if len(path) >= 2 else 0.0
                dfs([*path, nxt], cost + add)

    for s in range(n):
        dfs([s], 0.0)
    return best[0]


# ---- tests ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("shape", "lift"), [((3, 3), None), ((4, 3), None), ((4, 4), None), ((4, 4), (2, 2))]
)
def test_tiny_grids_match_the_brute_force_optimum(
    shape: tuple[int, int], lift: tuple[int, int] | None
) -> None:
    linkage = build_linkage(np.ones(shape, dtype=bool))
    pos = _centroids(linkage)
    lifts = [] if lift is None else [_gap_at(linkage, *lift)]
    route = plan_route(linkage, pos, lifts)
    assert route.method == "exact"
    optimum = _brute_force(linkage, pos, set(lifts))
    assert route.turn_angle_total_rad == pytest.approx(optimum, abs=1e-7)
    assert route.lower_bound_rad == pytest.approx(optimum, abs=1e-6)
    assert route.crossings == 0 and route.boundary_tiles_covered
    assert set(lifts) <= set(route.gaps.tolist())


@pytest.mark.parametrize("exact_limit", [200, 0])
def test_rectangle_route_is_closed_and_covers_every_boundary_tile(exact_limit: int) -> None:
    linkage = build_linkage(np.ones((7, 5), dtype=bool))
    pos = _centroids(linkage)
    route = plan_route(linkage, pos, exact_limit=exact_limit)
    assert route.method.startswith("exact" if exact_limit else "heuristic")
    r = len(route.gaps)
    assert len(np.unique(route.gaps)) == r
    graph = gap_graph(linkage, pos)
    for k in range(r):  # closed: every consecutive pair (including last -> first) is a step
        u, v = int(route.gaps[k]), int(route.gaps[(k + 1) % r])
        assert graph.has_edge(u, v)
        assert route.tiles[k] in graph.edges[u, v]["tiles"]
    assert set(np.nonzero(linkage.boundary_tile)[0]) <= set(route.tiles.tolist())
    assert route.boundary_tiles_covered and route.crossings == 0
    assert route.turn_angle_total_rad >= 2 * math.pi - 1e-9


def test_heuristic_on_a_larger_grid_with_lift_points_and_a_cropped_shape() -> None:
    cells = np.ones((16, 12), dtype=bool)
    cells[11:, 8:] = False  # an L-shaped crop
    linkage = build_linkage(cells)
    pos = _centroids(linkage)
    lifts = [_gap_at(linkage, 6, 6), _gap_at(linkage, 3, 8)]
    route = plan_route(linkage, pos, lifts, exact_limit=0)
    assert route.method.startswith("heuristic")
    assert set(lifts) <= set(route.gaps.tolist())
    assert route.boundary_tiles_covered and route.crossings == 0
    assert route.lower_bound_rad == pytest.approx(2 * math.pi)


def test_route_never_enters_the_interior_through_a_split_gap() -> None:
    linkage = build_linkage(np.ones((8, 6), dtype=bool), (Split("x", 4, 0, 6),))
    assert linkage.n_components == 2
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 3)
    for limit in (200, 0):
        route = plan_route(linkage, pos, [lift], exact_limit=limit)
        n_tiles = (linkage.gap_sides[route.gaps, :, 0] >= 0).sum(axis=1)
        on_split = route.labels == NODE_SPLIT
        assert on_split.any()  # the loop crosses the cut at the outer boundary
        assert np.all(n_tiles[on_split] < 4)  # never a split gap inside the structure
        assert route.crossings == 0 and route.boundary_tiles_covered
        assert set(linkage.tile_component[route.tiles].tolist()) == {0, 1}


def test_metrics_and_json() -> None:
    linkage = build_linkage(np.ones((4, 4), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 2)
    route = plan_route(linkage, pos, [lift])
    asm = np.column_stack([pos, np.zeros(len(pos))]) * 0.9
    m = route_metrics(route, linkage, pos, asm, mu=0.3)
    assert m["capstan_factor"] == pytest.approx(math.exp(0.3 * route.turn_angle_total_rad))
    assert m["crossings"] == 0 and m["boundary_tiles_covered"]
    assert m["length_mm"]["assembled"] == pytest.approx(0.9 * m["length_mm"]["flat"])
    doc = route_to_json(route, linkage, pos, asm, [lift])
    assert len(doc["steps"]) == len(route.gaps)
    assert all(0 <= s["enter_side"] <= 3 and 0 <= s["leave_side"] <= 3 for s in doc["steps"])
    assert doc["lift_points"][0]["gap"] == lift and doc["lift_points"][0]["on_route"]
    labels = gap_graph(linkage, pos).nodes(data="label")
    assert {lab for _, lab in labels} <= {0, 1, NODE_ENTRANCE, NODE_SPLIT}
