"""String route on the gap graph (paper section 5.3): contact partners, validity, optimality."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from drawstring.geometry.core.errors import DesignError
from drawstring.geometry.route.plan import MILP_NODE_LIMIT, SPLICE_NODE_LIMITS, plan_route
from drawstring.geometry.route.result import (
    Route,
    channel_partner_faults,
    count_crossings,
    route_metrics,
    route_to_json,
)
from drawstring.geometry.route.rules import NODE_ENTRANCE, NODE_SPLIT, contact_partners, gap_graph
from drawstring.geometry.tiling.grid import parts_in_place
from drawstring.geometry.tiling.linkage import (
    Linkage,
    Split,
    build_linkage,
    gap_centroids,
    rotating_squares_layout,
)


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


def _check_valid(linkage: Linkage, pos: NDArray[np.float64], route: Route) -> None:
    """Every invariant of a valid route, measured from the route itself."""
    r = len(route.gaps)
    assert len(np.unique(route.gaps)) == r  # each gap once
    assert len(np.unique(route.tiles)) == r  # each tile once
    assert route.tiles_passed_once and route.channel_partners_ok
    assert channel_partner_faults(route, linkage).size == 0
    graph = gap_graph(linkage, pos)
    for k in range(r):  # closed: every consecutive pair (including last -> first) is a step
        u, v = int(route.gaps[k]), int(route.gaps[(k + 1) % r])
        assert graph.has_edge(u, v)
        assert route.tiles[k] in graph.edges[u, v]["tiles"]
    assert set(np.nonzero(linkage.boundary_tile)[0]) <= set(route.tiles.tolist())
    assert route.boundary_tiles_covered and route.crossings == 0
    assert route.turn_angle_total_rad >= 2 * math.pi - 1e-9
    # never into the interior through a cut
    on_split = route.labels == NODE_SPLIT
    prev = np.roll(route.tiles, 1)
    assert np.all(linkage.boundary_tile[route.tiles[on_split]])
    assert np.all(linkage.boundary_tile[prev[on_split]])


# ---- an independent brute force ---------------------------------------------------------------


def _turn(a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]) -> float:
    d1, d2 = b - a, c - b
    cos = float(d1 @ d2) / float(np.linalg.norm(d1) * np.linalg.norm(d2))
    return math.acos(max(-1.0, min(1.0, cos)))


def _proper_cross(
    p1: NDArray[np.float64],
    p2: NDArray[np.float64],
    q1: NDArray[np.float64],
    q2: NDArray[np.float64],
) -> bool:
    def side(a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]) -> int:
        v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return 0 if abs(v) < 1e-9 else (1 if v > 0 else -1)

    return side(q1, q2, p1) * side(q1, q2, p2) < 0 and side(p1, p2, q1) * side(p1, p2, q2) < 0


def _slit_gap(linkage: Linkage, a: int, b: int) -> int:
    """Gap where edge-adjacent tiles a, b may pass the string: the slit end of their edge.

    Worked out from the grid alone: a vertical shared segment has its slit at the end vertex
    with odd ``i + j`` (vertical slit), a horizontal one at the end with even ``i + j``.
    """
    (ia, ja), (ib, jb) = sorted([tuple(linkage.tile_cells[a]), tuple(linkage.tile_cells[b])])
    if ja == jb:  # side by side: segment x = ib, y in [ja, ja + 1]
        ends = [(ib, ja), (ib, ja + 1)]
        want = 1
    else:  # one above the other: segment y = jb, x in [ia, ia + 1]
        ends = [(ia, jb), (ia + 1, jb)]
        want = 0
    i, j = next(e for e in ends if (e[0] + e[1]) % 2 == want)
    return _gap_at(linkage, int(i), int(j))


def _brute_force(linkage: Linkage, pos: NDArray[np.float64], lifts: set[int]) -> float:
    """Minimum turn over all simple tile cycles (edge-adjacent steps, slit-end gaps)."""
    cells = {tuple(c): t for t, c in enumerate(linkage.tile_cells.tolist())}
    n = linkage.n_tiles
    nbr: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for t, (i, j) in enumerate(linkage.tile_cells.tolist()):
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            u = cells.get((i + di, j + dj))
            if u is not None:
                nbr[t].append((u, _slit_gap(linkage, t, u)))
    need = set(np.nonzero(linkage.boundary_tile)[0].tolist())
    best = [math.inf]

    def evaluate(tiles: list[int], gaps: list[int]) -> None:
        # gaps[k] is crossed from tiles[k - 1] into tiles[k]
        r = len(gaps)
        if len(set(gaps)) < r or not need <= set(tiles) or not lifts <= set(gaps):
            return
        total = sum(_turn(pos[gaps[k - 1]], pos[gaps[k]], pos[gaps[(k + 1) % r]]) for k in range(r))
        if total >= best[0] - 1e-12:
            return
        segs = [(pos[gaps[k]], pos[gaps[(k + 1) % r]]) for k in range(r)]
        for a in range(r):
            for b in range(a + 2, r):
                if not (a == 0 and b == r - 1) and _proper_cross(*segs[a], *segs[b]):
                    return
        best[0] = total

    def dfs(tiles: list[int], gaps: list[int]) -> None:
        for u, g in nbr[tiles[-1]]:
            if u == tiles[0] and len(tiles) >= 3:
                evaluate(tiles, [g, *gaps])
            elif u > tiles[0] and u not in tiles and g not in gaps:
                dfs([*tiles, u], [*gaps, g])

    for s in range(n):
        dfs([s], [])
    return best[0]


# ---- tests ------------------------------------------------------------------------------------


def test_contact_partners_follow_the_slit_parity() -> None:
    linkage = build_linkage(np.ones((4, 3), dtype=bool))
    rows = contact_partners(linkage)
    got = {(g, a, b) for g, a, _sa, b, _sb in rows.tolist()}
    want = set()
    cells = {tuple(c): t for t, c in enumerate(linkage.tile_cells.tolist())}
    for t, (i, j) in enumerate(linkage.tile_cells.tolist()):
        for di, dj in ((1, 0), (0, 1)):
            u = cells.get((i + di, j + dj))
            if u is not None:
                want.add((_slit_gap(linkage, t, u), t, u))
    assert got == want
    corners = linkage.tile_corners
    for _g, a, sa, b, sb in rows.tolist():  # the two sides are one grid segment
        assert {corners[a, sa], corners[a, (sa + 1) % 4]} == {
            corners[b, sb],
            corners[b, (sb + 1) % 4],
        }


@pytest.mark.parametrize(
    ("shape", "lift"),
    [((3, 3), None), ((4, 3), None), ((4, 4), None), ((5, 4), None), ((6, 5), (2, 4))],
)
def test_tiny_grids_match_the_brute_force_optimum(
    shape: tuple[int, int], lift: tuple[int, int] | None
) -> None:
    linkage = build_linkage(np.ones(shape, dtype=bool))
    pos = _centroids(linkage)
    lifts = [] if lift is None else [_gap_at(linkage, *lift)]
    route = plan_route(linkage, pos, lifts, exact_limit=200)
    assert route.method == "exact"
    optimum = _brute_force(linkage, pos, set(lifts))
    assert route.turn_angle_total_rad == pytest.approx(optimum, abs=1e-7)
    assert route.lower_bound_rad == pytest.approx(optimum, abs=1e-6)
    _check_valid(linkage, pos, route)
    assert set(lifts) <= set(route.gaps.tolist()) and route.lifts_missed.size == 0


def test_an_unreachable_lift_gap_is_reported_not_faked() -> None:
    # In a 4 x 4 grid the centre gap cannot join a route that also passes all 12 ring tiles.
    linkage = build_linkage(np.ones((4, 4), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 2)
    assert _brute_force(linkage, pos, {lift}) == math.inf
    route = plan_route(linkage, pos, [lift])
    assert route.lifts_missed.tolist() == [lift]
    assert any(str(lift) in n for n in route.notes)
    _check_valid(linkage, pos, route)


def test_an_unreachable_lift_moves_to_the_nearest_gap_the_string_passes() -> None:
    from drawstring.geometry.route.lift import nearby_lift_gaps
    from drawstring.pipeline.route_stage import plan_lift_route

    linkage = build_linkage(np.ones((4, 4), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 2)
    route, note, served = plan_lift_route(linkage, pos, np.array([lift]))
    _check_valid(linkage, pos, route)
    assert route.lifts_missed.size == 0
    (moved,) = served.tolist()
    assert moved != lift and moved in route.gaps.tolist()
    # it is the nearest interior gap one tile away that the route passes
    one_hop = nearby_lift_gaps(linkage, lift, pos, 1).tolist()
    assert moved in one_hop
    passed = [g for g in one_hop if g in route.gaps.tolist()]
    assert moved == passed[0]
    assert note is not None and f"gap {lift} to gap {moved} (one tile away)" in note
    # a reachable lift stays where it is
    route2, note2, served2 = plan_lift_route(linkage, pos, np.array([moved]))
    assert served2.tolist() == [moved] and note2 is None and route2.lifts_missed.size == 0


def test_nearby_lift_gaps_stay_in_the_part_and_are_sorted_by_distance() -> None:
    from drawstring.geometry.route.lift import nearby_lift_gaps

    linkage = build_linkage(np.ones((8, 8), dtype=bool), (Split("x", 4, 0, 8),))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 5, 4)
    near = nearby_lift_gaps(linkage, lift, pos, 2)
    assert near.size and lift not in near.tolist()
    dist = np.linalg.norm(pos[near] - pos[lift], axis=1)
    assert np.all(np.diff(dist) >= 0)
    kinds = {linkage.gap_kind[g] for g in near.tolist()}
    assert kinds <= {"horizontal", "vertical"}
    parts = {int(linkage.tile_component[t]) for g in near.tolist() for t in linkage.gap_tiles(g)}
    assert parts == {int(linkage.tile_component[linkage.gap_tiles(lift)[0]])}
    assert set(nearby_lift_gaps(linkage, lift, pos, 1).tolist()) < set(near.tolist())


@pytest.mark.parametrize("exact_limit", [200, 0])
def test_rectangle_route_is_closed_and_covers_every_boundary_tile(exact_limit: int) -> None:
    linkage = build_linkage(np.ones((7, 5), dtype=bool))
    pos = _centroids(linkage)
    route = plan_route(linkage, pos, exact_limit=exact_limit)
    assert route.method.startswith("exact" if exact_limit else "heuristic")
    _check_valid(linkage, pos, route)


def test_heuristic_matches_exact_on_a_rectangle_with_a_lift_point() -> None:
    linkage = build_linkage(np.ones((8, 7), dtype=bool))
    pos = _centroids(linkage)
    lift = [_gap_at(linkage, 4, 4)]
    exact = plan_route(linkage, pos, lift, exact_limit=1000)
    heur = plan_route(linkage, pos, lift, exact_limit=0)
    for route in (exact, heur):
        _check_valid(linkage, pos, route)
        assert lift[0] in route.gaps.tolist()
    assert exact.method == "exact"
    assert heur.turn_angle_total_rad >= exact.turn_angle_total_rad - 1e-9


def test_heuristic_on_a_larger_grid_with_lift_points_and_a_cropped_shape() -> None:
    cells = np.ones((16, 12), dtype=bool)
    cells[11:, 8:] = False  # an L-shaped crop
    linkage = build_linkage(cells)
    pos = _centroids(linkage)
    lifts = [_gap_at(linkage, 6, 6), _gap_at(linkage, 3, 8)]
    route = plan_route(linkage, pos, lifts, exact_limit=0)
    assert route.method.startswith("heuristic")
    assert set(lifts) <= set(route.gaps.tolist())
    _check_valid(linkage, pos, route)
    assert route.lower_bound_rad == pytest.approx(2 * math.pi)


def test_a_staircase_boundary_is_routed() -> None:
    i, j = np.meshgrid(np.arange(12), np.arange(12), indexing="ij")
    linkage = build_linkage(i + j <= 14)
    pos = _centroids(linkage)
    route = plan_route(linkage, pos, [_gap_at(linkage, 4, 4)], exact_limit=0)
    _check_valid(linkage, pos, route)
    assert route.lifts_missed.size == 0


def test_route_never_enters_the_interior_through_a_split_gap() -> None:
    linkage = build_linkage(np.ones((10, 8), dtype=bool), (Split("x", 5, 0, 8),))
    assert linkage.n_components == 2
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 4)
    for limit in (200, 0):
        route = plan_route(linkage, pos, [lift], exact_limit=limit)
        _check_valid(linkage, pos, route)
        assert (route.labels == NODE_SPLIT).any()  # the loop crosses the cut
        assert set(linkage.tile_component[route.tiles].tolist()) == {0, 1}
        assert lift in route.gaps.tolist()


def test_a_strip_two_tiles_wide_has_no_valid_route() -> None:
    # Both strands of the ring would cross the same interior gaps.
    linkage = build_linkage(np.ones((6, 2), dtype=bool))
    pos = _centroids(linkage)
    for limit in (200, 0):
        with pytest.raises(DesignError):
            plan_route(linkage, pos, exact_limit=limit)


def test_metrics_json_and_the_partner_check() -> None:
    linkage = build_linkage(np.ones((6, 5), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 4)
    route = plan_route(linkage, pos, [lift])
    asm = np.column_stack([pos, np.zeros(len(pos))]) * 0.9
    m = route_metrics(route, linkage, pos, asm, mu=0.3)
    assert m["capstan_factor"] == pytest.approx(math.exp(0.3 * route.turn_angle_total_rad))
    assert m["crossings"] == 0 and m["boundary_tiles_covered"]
    assert m["channel_partners_ok"] and m["tiles_passed_once"] and m["lift_gaps_missed"] == []
    assert m["length_mm"]["assembled"] == pytest.approx(0.9 * m["length_mm"]["flat"])
    doc = route_to_json(route, linkage, pos, asm, [lift])
    assert len(doc["steps"]) == len(route.gaps)
    assert all(0 <= s["enter_side"] <= 3 and 0 <= s["leave_side"] <= 3 for s in doc["steps"])
    assert doc["lift_points"][0]["gap"] == lift and doc["lift_points"][0]["on_route"]
    assert doc["closed"] is True
    # the wrap from the last step to the first is measured: break it and the route is open
    broken = dataclasses.replace(route, tiles=np.roll(route.tiles, 1))
    assert route_to_json(broken, linkage, pos, asm, [lift])["closed"] is False
    labels = gap_graph(linkage, pos).nodes(data="label")
    assert {lab for _, lab in labels} <= {0, 1, NODE_ENTRANCE, NODE_SPLIT}
    # the check measures: a route whose tile sequence skips a partner fails it
    bad = dataclasses.replace(route, enter_side=(route.enter_side + 1) % 4)
    assert not route_metrics(bad, linkage, pos, None, mu=0.3)["channel_partners_ok"]
    assert channel_partner_faults(bad, linkage).size == len(route.gaps)


def test_a_lift_beside_a_cut_is_reached_from_its_own_part() -> None:
    # The cut runs the full height 5 cells from the left edge; the lift gap sits just right of
    # it, nearer the left boundary (part 0) than any loop gap of its own part (1).  A detour
    # from the left would have to cross the cut in the interior: the splice starts from the
    # nearest loop gap in the lift's part instead.
    linkage = build_linkage(np.ones((16, 16), dtype=bool), (Split("x", 5, 0, 16),))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 6, 8)
    tiles = linkage.gap_sides[lift][:, 0]
    assert set(linkage.tile_component[tiles[tiles >= 0]].tolist()) == {1}
    route = plan_route(linkage, pos, [lift], exact_limit=0)
    _check_valid(linkage, pos, route)
    assert route.lifts_missed.size == 0 and lift in route.gaps.tolist()
    assert route.channel_partners_ok and route.tiles_passed_once and route.crossings == 0


def test_a_lift_in_a_narrow_split_strip_needs_the_same_component_rule() -> None:
    # A 3-wide middle strip between two cuts: every other vertical crossing along its edge
    # columns is a split gap, so under the default rule no detour reaches its middle.
    cells = np.ones((11, 12), dtype=bool)
    splits = (Split("x", 4, 0, 12), Split("x", 7, 0, 12))
    linkage = build_linkage(cells, splits)
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 5, 6)
    strict = plan_route(linkage, pos, [lift], exact_limit=0)
    assert strict.lifts_missed.tolist() == [lift]
    _check_valid(linkage, pos, strict)
    relaxed = plan_route(linkage, pos, [lift], exact_limit=0, split_rule="same-component")
    assert relaxed.lifts_missed.size == 0 and lift in relaxed.gaps.tolist()
    assert relaxed.channel_partners_ok and relaxed.tiles_passed_once and relaxed.crossings == 0
    assert relaxed.boundary_tiles_covered


def test_a_split_part_the_route_cannot_reach_is_a_design_problem() -> None:
    # Four cuts box in a middle part that touches no outer boundary: the boundary route never
    # gets there, and the design check must say so (that part would not be pulled).
    from drawstring.pipeline.measure import route_problems

    cells = np.ones((12, 12), dtype=bool)
    splits = (Split("y", 4, 0, 12), Split("y", 8, 0, 12), Split("x", 4, 4, 8), Split("x", 8, 4, 8))
    linkage = build_linkage(cells, splits)
    assert linkage.n_components == 5
    pos = _centroids(linkage)
    route = plan_route(linkage, pos, [], exact_limit=0)
    _check_valid(linkage, pos, route)
    middle = np.flatnonzero((linkage.tile_cells == [5, 5]).all(axis=1))[0]
    inner = int(linkage.tile_component[middle])
    assert inner not in set(linkage.tile_component[route.tiles].tolist())
    problems = route_problems(route, linkage)
    assert len(problems) == 1 and "reaches 4 of 5 split parts" in problems[0]
    # a route through every part has no such problem
    full = build_linkage(cells, splits[:2])
    assert route_problems(plan_route(full, _centroids(full), [], exact_limit=0), full) == []


def test_parts_laid_apart_for_cutting_are_routed_as_they_meet() -> None:
    # Cut layouts spread the parts (here the right part goes left of the other, turned a
    # quarter): gap centroids on the split line then sit between the parts, and the route
    # planned through them crosses itself.  Moved back onto the grid, parts sit side by side
    # and the route is the one of the layout in place.
    linkage = build_linkage(np.ones((10, 8), dtype=bool), (Split("x", 5, 0, 8),))
    in_place = rotating_squares_layout(linkage, 0.5, side=10.0)
    grid_uv = linkage.vertex_ij * 10.0
    right = linkage.tile_component == linkage.tile_component[-1]
    spread = in_place.copy()
    spread[right] = spread[right] @ np.array([[0.0, 1.0], [-1.0, 0.0]]) - [200.0, 0.0]
    spread[~right] += [60.0, 0.0]
    apart = plan_route(linkage, gap_centroids(linkage, spread), [])
    assert apart.crossings > 0
    assert any("crosses itself and the band has none" in n for n in apart.notes)
    placed = parts_in_place(linkage, spread, grid_uv)
    route = plan_route(linkage, gap_centroids(linkage, placed), [])
    expected = plan_route(linkage, gap_centroids(linkage, in_place), [])
    assert route.crossings == 0
    np.testing.assert_array_equal(route.gaps, expected.gaps)
    assert route.turn_angle_total_rad == pytest.approx(expected.turn_angle_total_rad, rel=1e-9)
    # the parts meet again exactly as in the layout in place: one rigid motion away from it
    # (the largest part, here the left one by index, stays where it was cut)
    np.testing.assert_allclose(placed[~right], spread[~right], atol=1e-12)
    src, dst = in_place.reshape(-1, 2), placed.reshape(-1, 2)
    u, _, vt = np.linalg.svd((dst - dst.mean(0)).T @ (src - src.mean(0)))
    rotation = u @ vt
    moved = (src - src.mean(0)) @ rotation.T + dst.mean(0)
    np.testing.assert_allclose(moved, dst, atol=1e-9)
    one = build_linkage(np.ones((4, 4), dtype=bool))
    corners = rotating_squares_layout(one, 0.5, side=10.0) + 100.0
    np.testing.assert_array_equal(parts_in_place(one, corners, one.vertex_ij * 10.0), corners)


def test_a_part_held_by_one_cut_hinge_is_placed_by_the_grid() -> None:
    # a lone tile sticking out of a 6 x 6 block, cut off: one removed hinge cannot fix its
    # turn, so it goes where the grid puts it relative to the block
    cells = np.zeros((7, 6), dtype=bool)
    cells[:6, :] = True
    cells[6, 0] = True
    linkage = build_linkage(cells, (Split("x", 6, 0, 1),))
    assert linkage.n_components == 2
    lone = linkage.tile_component == linkage.tile_component[linkage.tile_cells[:, 0] == 6][0]
    grid_uv = linkage.vertex_ij * 10.0
    in_place = grid_uv[linkage.tile_corners]  # the grid itself, gaps closed
    spread = in_place.copy()
    spread[lone] = spread[lone] @ np.array([[0.0, -1.0], [1.0, 0.0]]).T + [300.0, 40.0]
    spread[~lone] += [-20.0, 5.0]
    placed = parts_in_place(linkage, spread, grid_uv)
    np.testing.assert_allclose(placed[~lone], spread[~lone])
    np.testing.assert_allclose(placed[lone], in_place[lone] + [-20.0, 5.0], atol=1e-9)


def test_an_unreachable_lift_moves_to_a_gap_a_new_route_reaches(monkeypatch: Any) -> None:
    # When no nearby gap lies on the first route, nearby gaps are tried with a new route each.
    # The candidates on the first route are hidden here so that this branch runs; in a 4 x 6
    # grid this lift gap is unreachable and some of its neighbours off the route are not.
    import drawstring.pipeline.route_stage as pipeline
    from drawstring.geometry.route.lift import nearby_lift_gaps

    linkage = build_linkage(np.ones((4, 6), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 2)
    first = plan_route(linkage, pos, [lift])
    assert first.lifts_missed.tolist() == [lift]
    on_first = set(first.gaps.tolist())

    def off_first_route(lk: Linkage, gap: int, p: Any, steps: int) -> NDArray[np.int64]:
        near = nearby_lift_gaps(lk, gap, p, steps).tolist()
        return np.array([g for g in near if g not in on_first], dtype=np.int64)

    monkeypatch.setattr(pipeline, "nearby_lift_gaps", off_first_route)
    route, note, served = pipeline.plan_lift_route(linkage, pos, np.array([lift]))
    (moved,) = served.tolist()
    assert moved != lift and moved not in on_first
    assert moved in off_first_route(linkage, lift, pos, 2)[: pipeline.LIFT_MOVE_TRIES].tolist()
    assert moved in route.gaps.tolist() and route.lifts_missed.size == 0
    _check_valid(linkage, pos, route)
    assert note is not None and f"gap {lift} to gap {moved}" in note


def test_a_lift_no_nearby_gap_serves_stays_missed(monkeypatch: Any) -> None:
    import drawstring.pipeline.route_stage as pipeline

    linkage = build_linkage(np.ones((4, 4), dtype=bool))
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 2, 2)
    monkeypatch.setattr(pipeline, "nearby_lift_gaps", lambda *_: np.zeros(0, dtype=np.int64))
    route, note, served = pipeline.plan_lift_route(linkage, pos, np.array([lift]))
    assert served.tolist() == [lift] and route.lifts_missed.tolist() == [lift] and note is None


def test_every_route_solve_is_bounded_by_nodes_not_by_time(monkeypatch: Any) -> None:
    """The route must not depend on the machine's speed: every integer-program solve gets a node
    budget, and its time limit is only the safety net."""
    from drawstring.geometry.route import milp as route_milp

    seen: list[dict[str, Any]] = []
    real = route_milp.milp

    def recording(*args: Any, **kwargs: Any) -> Any:
        seen.append(dict(kwargs["options"]))  # milp pops the options it reads
        return real(*args, **kwargs)

    monkeypatch.setattr(route_milp, "milp", recording)
    cells = np.ones((16, 12), dtype=bool)
    cells[11:, 8:] = False
    linkage = build_linkage(cells)
    pos = _centroids(linkage)
    route = plan_route(linkage, pos, [_gap_at(linkage, 6, 6)], exact_limit=0)
    small = build_linkage(np.ones((4, 4), dtype=bool))
    exact = plan_route(small, _centroids(small), exact_limit=200)
    assert route.method.startswith("heuristic") and exact.method == "exact"
    assert seen, "no integer program was solved"
    budgets = {options["node_limit"] for options in seen}
    # the lift window's budgets (root first) and the whole instance's
    assert SPLICE_NODE_LIMITS[0] in budgets and MILP_NODE_LIMIT in budgets
    assert budgets <= {*SPLICE_NODE_LIMITS, MILP_NODE_LIMIT}
    for options in seen:
        assert options["time_limit"] == route_milp.MILP_SAFETY_TIME_S


def test_a_window_out_of_nodes_is_tried_with_more_before_it_grows(monkeypatch: Any) -> None:
    """A window whose root node finds no path (and proves none missing) gets the next node
    budget on the same window; a window proved to hold no path is left for a larger one."""
    from drawstring.geometry.route import loops as route_heuristics
    from drawstring.geometry.route.milp import NodeBudgetError

    real = route_heuristics.solve_cycle
    cells = np.ones((16, 12), dtype=bool)
    linkage = build_linkage(cells)
    pos = _centroids(linkage)
    lift = _gap_at(linkage, 6, 6)

    def first_windows_fail(error: type[DesignError]) -> list[tuple[int, int]]:
        calls: list[tuple[int, int]] = []  # (window program size, node budget)

        def solve(problem: Any, rules: Any, pos: Any, node_limit: int, notes: Any) -> Any:
            calls.append((len(problem.edges), node_limit))
            if len(calls) == 1:
                raise error("the first window's root: no route")
            return real(problem, rules, pos, node_limit, notes)

        monkeypatch.setattr(route_heuristics, "solve_cycle", solve)
        route = plan_route(linkage, pos, [lift], exact_limit=0)
        assert lift in route.gaps.tolist()
        _check_valid(linkage, pos, route)
        return calls

    # out of nodes: the same window's program again, with the next budget
    calls = first_windows_fail(NodeBudgetError)
    assert [c[1] for c in calls[:2]] == list(SPLICE_NODE_LIMITS[:2])
    assert calls[0][0] == calls[1][0]
    # proved empty: the next, larger window at the root
    calls = first_windows_fail(DesignError)
    assert [c[1] for c in calls[:2]] == [SPLICE_NODE_LIMITS[0]] * 2
    assert calls[1][0] > calls[0][0]


@pytest.mark.parametrize(
    ("status", "message", "out_of_nodes"),
    [
        (
            4,
            "The HiGHS status code was not recognized. (HiGHS Status 16: Solution limit reached)",
            True,
        ),
        (1, "Time limit reached. (HiGHS Status 13: Time limit reached)", False),
        (
            4,
            "The HiGHS status code was not recognized. (HiGHS Status 8: Unbounded or infeasible)",
            False,
        ),
    ],
)
def test_a_solve_without_a_route_is_out_of_nodes_only_at_the_node_limit(
    monkeypatch: Any, status: int, message: str, out_of_nodes: bool
) -> None:
    """Only HiGHS's node limit asks for more nodes; the safety time limit and other failures
    do not (more nodes would only take longer)."""
    from types import SimpleNamespace

    from drawstring.geometry.route import milp as route_milp
    from drawstring.geometry.route.milp import NodeBudgetError

    def no_route(*args: Any, **kwargs: Any) -> Any:
        return SimpleNamespace(status=status, message=message, x=None, fun=None)

    monkeypatch.setattr(route_milp, "milp", no_route)
    small = build_linkage(np.ones((4, 4), dtype=bool))
    with pytest.raises(DesignError) as caught:
        plan_route(small, _centroids(small), exact_limit=200)
    assert isinstance(caught.value, NodeBudgetError) == out_of_nodes


def test_a_solve_stopped_by_the_safety_time_limit_says_so_once(monkeypatch: Any) -> None:
    """A solve the safety time limit stops (not its node budget) may have ended elsewhere on
    another machine: the route says so in its notes, once however many solves stop, and the
    route it found is kept; without a route the design stops with a plain error, not a call
    for more nodes."""
    from types import SimpleNamespace

    from drawstring.geometry.route import milp as route_milp
    from drawstring.geometry.route.milp import NodeBudgetError

    real = route_milp.milp
    stopped: list[int] = []

    def timed_out(*args: Any, **kwargs: Any) -> Any:
        res = real(*args, **kwargs)
        stopped.append(1)
        return SimpleNamespace(status=1, message="Time limit reached", x=res.x, fun=res.fun)

    cells = np.ones((16, 12), dtype=bool)
    cells[11:, 8:] = False
    linkage = build_linkage(cells)
    pos = _centroids(linkage)
    lifts = [_gap_at(linkage, 6, 6), _gap_at(linkage, 3, 9)]
    plain = plan_route(linkage, pos, lifts, exact_limit=0)
    assert not [n for n in plain.notes if "safety limit" in n]
    monkeypatch.setattr(route_milp, "milp", timed_out)
    route = plan_route(linkage, pos, lifts, exact_limit=0)
    safety = [n for n in route.notes if "safety limit" in n]
    assert len(stopped) >= 2, "one solve is not enough to show the note comes once"
    assert safety == [
        f"a route program stopped at its {route_milp.MILP_SAFETY_TIME_S:g} s safety limit "
        "before its node budget: on another machine the route may differ"
    ]
    assert route.tiles.tolist() == plain.tiles.tolist()
    _check_valid(linkage, pos, route)
    small = build_linkage(np.ones((4, 4), dtype=bool))

    def timed_out_empty(*args: Any, **kwargs: Any) -> Any:
        return SimpleNamespace(status=1, message="Time limit reached", x=None, fun=None)

    monkeypatch.setattr(route_milp, "milp", timed_out_empty)
    with pytest.raises(DesignError, match="Time limit reached") as caught:
        plan_route(small, _centroids(small), exact_limit=200)
    assert not isinstance(caught.value, NodeBudgetError)


def test_segments_of_different_split_parts_never_count_as_crossing() -> None:
    # a square's two diagonals: they cross within one part; in two parts (each segment runs
    # through a tile of its own part, laid apart when cut) they do not
    pos = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    gaps = np.array([0, 1, 2, 3])
    assert count_crossings(gaps, pos) == 1
    assert count_crossings(gaps, pos, np.array([0, 0, 0, 0])) == 1
    assert count_crossings(gaps, pos, np.array([0, 1, 1, 1])) == 0
    # a gap passed twice is a crossing whatever the parts
    assert count_crossings(np.array([0, 1, 2, 0, 3]), pos, np.array([0, 1, 0, 1, 0])) >= 1
