"""Print clearance at hinges (cad/clearance.py): known answers on hand-built tile pairs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drawstring.cad.checks import clearances, to_manifold
from drawstring.cad.clearance import (
    MAX_DEEP_RELIEF_SHARE,
    MAX_RELIEF_SHARE,
    THIN_RELIEF_SHARE,
    hinge_reliefs,
    separating_normal,
)
from drawstring.cad.features import trim_tool
from drawstring.cad.hinge_pins import KeepOut
from drawstring.cad.tiles import relieved_tile_solid, tile_solid


def _square(corner: np.ndarray, first: float, side: float, low: float, high: float) -> np.ndarray:
    """(8, 3) box tile: a square of ``side`` with corner 0 at ``corner`` (xy), its sides from
    there at angles ``first`` and ``first + 90`` deg (counter-clockwise), z from low to high."""
    u = np.array([math.cos(math.radians(first)), math.sin(math.radians(first))])
    v = np.array([-u[1], u[0]])
    ring = np.array([corner, corner + side * u, corner + side * (u + v), corner + side * v])
    top = np.column_stack([ring, np.full(4, high)])
    bottom = np.column_stack([ring, np.full(4, low)])
    return np.vstack([top, bottom])


def _hinged_pair(theta_deg: float, side: float = 10.0, thickness: float = 6.0) -> np.ndarray:
    """Two square box tiles hinged at their corner 0 (the origin), their facing sides
    ``theta_deg`` apart across the +x axis: tile 0 above it, tile 1 below."""
    origin = np.zeros(2)
    above = _square(origin, 0.5 * theta_deg, side, 0.0, thickness)
    below = _square(origin, -0.5 * theta_deg - 90.0, side, 0.0, thickness)
    return np.stack([above, below])


def _relieved(tiles: np.ndarray, clearance: float, side: str = "top") -> list:
    reliefs = hinge_reliefs(tiles, np.array([[0, 0, 1, 0]]), [side], clearance)
    return [relieved_tile_solid(t, reliefs.cuts.get(i, [])) for i, t in enumerate(tiles)]


@pytest.mark.parametrize("theta", [12.0, 30.0])
def test_relief_cuts_the_hand_computed_sliver(theta: float) -> None:
    # Square boxes hinged at a corner, their sides theta apart: the plane between them is the
    # x axis's vertical plane, and the part of each square within c of it is the triangle of
    # the hinge and the points on its two sides at c / sin(theta/2) and c / cos(theta/2),
    # of area c^2 / sin(theta) (a right angle between them).
    tiles = _hinged_pair(theta)
    clearance, thickness = 0.4, 6.0
    c = 0.5 * clearance
    before = [tile_solid(t).volume for t in tiles]
    after = [s.volume for s in _relieved(tiles, clearance)]
    expected = thickness * c * c / math.sin(math.radians(theta))
    for b, a in zip(before, after, strict=True):
        assert b - a == pytest.approx(expected, rel=1e-6)


def test_relieved_tiles_keep_the_clearance_apart_and_plain_ones_touch() -> None:
    tiles = _hinged_pair(12.0)
    plain = clearances([tile_solid(t) for t in tiles], 1.0)
    assert plain.min_distance == pytest.approx(0.0, abs=1e-6)
    relieved = clearances(_relieved(tiles, 0.4), 1.0)
    assert relieved.min_distance == pytest.approx(0.4, abs=1e-4)


def test_tiles_whose_edges_at_the_hinge_lean_apart_are_relieved_along_them() -> None:
    # Tile 1 turned 4 deg about the horizontal line through the hinge (the x axis): its edge
    # under the hinge leans away from tile 0's, which is vertical (a hinge laid out on the top
    # faces, with the bottoms parting).  The relief follows both
    # edges down the whole thickness, and the tiles stay the clearance apart everywhere.
    tiles = _hinged_pair(12.0)
    tilt = math.radians(-4.0)
    turn = np.array(
        [[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]]
    )
    top = np.array([0.0, 0.0, 6.0])
    tiles[:, :, 2] -= 6.0  # hinge at the top corners, at z = 0
    tiles[1] = tiles[1] @ turn.T
    tiles += top
    relieved = clearances(_relieved(tiles, 0.4), 1.0)
    assert relieved.min_distance >= 0.4 - 1e-4
    mesh = to_manifold(_relieved(tiles, 0.4)[0])
    assert mesh.volume() > 0.99 * tile_solid(tiles[0]).volume


def test_separating_normal_known_answers() -> None:
    # two fans in the plane, 20 deg apart around +x and 100 deg apart around -x: the line is
    # the x axis, turned so that both gaps keep the same angle (half of the narrower one)
    a = np.array([[math.cos(math.radians(d)), math.sin(math.radians(d))] for d in (10, 60, 130)])
    b = a * np.array([1.0, -1.0])
    normal, angle = separating_normal(a, b)
    np.testing.assert_allclose(normal, [0.0, 1.0], atol=1e-7)
    assert math.degrees(angle) == pytest.approx(10.0, abs=1e-6)
    # sets that cross: the best plane leaves a negative angle
    crossed = separating_normal(a, np.vstack([b, [[1.0, 0.3]]]))
    assert crossed is not None and crossed[1] < 0


def test_tiles_that_overlap_below_the_hinge_cut_one_tile_clear_of_the_other() -> None:
    # Frustums widening downwards (bottoms 1.15 times their tops) hinged at their top
    # corners: below the hinge they overlap (the pairs the top strategy trims), so no plane
    # through the hinge parts them with a thin cut.  One tile is cut a whole clearance beyond
    # the other's side face at the hinge; the other stays whole.
    tiles = _hinged_pair(12.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 1.15 * (tile[4:, :2] - centre)
    plain = [tile_solid(t) for t in tiles]
    overlap = to_manifold(plain[0]) ^ to_manifold(plain[1])
    assert overlap.volume() > 0.01
    reliefs = hinge_reliefs(tiles, np.array([[0, 0, 1, 0]]), ["top"], 0.4)
    assert reliefs.one_sided == 1 and not reliefs.skipped
    assert reliefs.reach_max_mm == 0.0 and reliefs.one_sided_reach_mm > 0.4
    assert sum(len(v) for v in reliefs.cuts.values()) == 1
    solids = _relieved(tiles, 0.4)
    assert clearances(solids, 1.0).min_distance >= 0.4 - 1e-4
    volumes = [s.volume / p.volume for s, p in zip(solids, plain, strict=True)]
    assert sorted(volumes)[1] == pytest.approx(1.0)  # one tile whole
    assert sorted(volumes)[0] > 1.0 - MAX_RELIEF_SHARE


@pytest.mark.parametrize(("side", "relieved"), [(4.0, True), (3.0, False)])
def test_small_overlapping_tiles_are_relieved_up_to_the_largest_share(
    side: float, relieved: bool
) -> None:
    # Small frustums overlapping below the hinge: the least relief of the 4 mm pair (one tile
    # cut a whole clearance clear of the other) takes 7.5 % of a tile, over the share where
    # the first way found is taken, and is made: the two print 0.4 mm apart.  The 3 mm pair
    # widening 1.3 times needs more than MAX_RELIEF_SHARE and is left joined, named.
    tiles = _hinged_pair(12.0, side)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + (1.15 if relieved else 1.3) * (tile[4:, :2] - centre)
    reliefs = hinge_reliefs(tiles, np.array([[0, 0, 1, 0]]), ["top"], 0.4)
    assert (reliefs.skipped == ()) is relieved
    if not relieved:
        return
    assert THIN_RELIEF_SHARE < reliefs.share_max <= MAX_RELIEF_SHARE
    solids = _relieved(tiles, 0.4)
    assert clearances(solids, 1.0).min_distance >= 0.4 - 1e-4
    plain = [tile_solid(t) for t in tiles]
    volumes = [s.volume / p.volume for s, p in zip(solids, plain, strict=True)]
    assert min(volumes) == pytest.approx(1.0 - reliefs.share_max, abs=1e-3)


def test_a_deep_relief_is_made_where_it_clears_the_tiles_features() -> None:
    # The 3 mm pair above, whose least relief cuts more than MAX_RELIEF_SHARE: given what
    # each tile holds (a ball, standing for a channel or strip), the relief is made where its
    # plane leaves the ball a wall clear, and the tiles then print 0.4 mm apart; a ball that
    # the cut would open leaves the hinge unrelieved.
    tiles = _hinged_pair(12.0, 3.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 1.3 * (tile[4:, :2] - centre)
    hinge = np.array([[0, 0, 1, 0]])
    centres = [t.mean(axis=0) for t in tiles]  # each tile's centre, far from the hinge
    seen: list[tuple[int, int]] = []

    def central(tile: int, index: int, own: bool) -> KeepOut:
        seen.append((tile, index))
        return KeepOut(centres[tile][None], np.array([0.3]))

    reliefs = hinge_reliefs(tiles, hinge, ["top"], 0.4, central, 0.4)
    assert reliefs.skipped == () and reliefs.deep == (0,) and seen
    assert MAX_RELIEF_SHARE < reliefs.share_max <= MAX_DEEP_RELIEF_SHARE
    solids = [relieved_tile_solid(t, reliefs.cuts.get(i, [])) for i, t in enumerate(tiles)]
    assert clearances(solids, 1.0).min_distance >= 0.4 - 1e-4
    for tile, planes in reliefs.cuts.items():
        for plane in planes:  # the ball keeps the wall on the side the tile keeps
            assert centres[tile] @ plane[:3] - plane[3] >= 0.3 + 0.4
    # a ball at the hinge corner's edge of each tile: every relief would open it
    near = [t[0] + 0.4 * (t[4] - t[0]) + 0.05 * (t.mean(axis=0) - t[0]) for t in tiles]

    def at_hinge(tile: int, index: int, own: bool) -> KeepOut:
        return KeepOut(near[tile][None], np.array([0.3]))

    blocked = hinge_reliefs(tiles, hinge, ["top"], 0.4, at_hinge, 0.4)
    assert blocked.skipped == (0,) and blocked.deep == () and not blocked.cuts


def test_where_no_plane_clears_the_features_one_tile_loses_only_what_is_too_near() -> None:
    # The 3 mm pair again: every plane relief would open a ball at the hinge corner of the
    # hinge's own strip (own=True), so one tile instead loses just what lies within the
    # clearance of the other (the other's hull pushed out 0.4 mm), which the strip bridges:
    # the two then print 0.4 mm apart.
    tiles = _hinged_pair(12.0, 3.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 1.3 * (tile[4:, :2] - centre)
    near = [t[0] + 0.4 * (t[4] - t[0]) + 0.05 * (t.mean(axis=0) - t[0]) for t in tiles]

    def strip_at_hinge(tile: int, index: int, own: bool) -> KeepOut:
        if not own:
            return KeepOut()
        return KeepOut(near[tile][None], np.array([0.3]))

    reliefs = hinge_reliefs(tiles, np.array([[0, 0, 1, 0]]), ["top"], 0.4, strip_at_hinge, 0.4)
    assert reliefs.skipped == () and reliefs.hollowed == (0,) and not reliefs.cuts
    assert 0.0 < reliefs.share_max <= MAX_DEEP_RELIEF_SHARE
    ((cut, polyhedra),) = reliefs.hollows.items()
    solids = [tile_solid(t) for t in tiles]
    for points in polyhedra:
        solids[cut] = solids[cut] - trim_tool(points)
    assert clearances(solids, 1.0).min_distance >= 0.4 - 1e-4
    plain = tile_solid(tiles[cut]).volume
    assert 1.0 - solids[cut].volume / plain == pytest.approx(reliefs.share_max, abs=1e-3)

    # a channel there too (own=False: what the tile holds besides this hinge's strip) lies in
    # what either tile would lose: the hinge is left unrelieved
    def channel_at_hinge(tile: int, index: int, own: bool) -> KeepOut:
        return KeepOut(near[tile][None], np.array([0.3]))

    blocked = hinge_reliefs(tiles, np.array([[0, 0, 1, 0]]), ["top"], 0.4, channel_at_hinge, 0.4)
    assert blocked.skipped == (0,) and not blocked.hollows and not blocked.cuts


def test_a_dart_shaped_tile_keeps_its_notch_when_relieved() -> None:
    # Top and bottom faces a dart (reflex corner 2 at (3, 3)), 6 mm thick; the plane
    # x + y = 0.5 sqrt(2) cuts from corner 0 the right triangle of legs 1 mm: 3 mm^3.  The
    # convex polyhedron of the face planes would fill the notch instead.
    ring = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 3.0], [0.0, 10.0]])
    tile = np.vstack(
        [np.column_stack([ring, np.full(4, 6.0)]), np.column_stack([ring, np.zeros(4)])]
    )
    normal = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    relieved = relieved_tile_solid(tile, [np.append(normal, 0.5 * math.sqrt(2.0))])
    assert relieved.is_valid
    assert tile_solid(tile).volume - relieved.volume == pytest.approx(3.0, rel=1e-9)
    assert relieved.volume == pytest.approx(6.0 * 30.0 - 3.0, rel=1e-9)


def test_a_hinge_no_relief_clears_is_a_feature_shortfall_before_any_solid() -> None:
    # Two 6 mm tiles hinged at corner 0 that overlap below the hinge (their bottoms 1.5 times
    # as wide), each with its string channel from side 0 to side 3, the two sides at the
    # hinge: the channels lie in what either tile would lose to the print clearance, so the
    # CAD stage would leave the hinge unrelieved (its tiles print welded).  The checks asked
    # before any solid find it, with the channels' room (negative: they reach into the other
    # tile) against the clearance and a wall.  With one tile's channel on its far sides, that
    # tile is hollowed and every feature fits.
    from drawstring.cad.feature_common import feature_wall_mm
    from drawstring.cad.hinge_plans import design_reliefs, relief_shortfall
    from drawstring.fabrication.profiles import load_profile
    from drawstring.pipeline.cad_stage import feature_shortfall

    profile = load_profile("fdm-dual")
    tiles = _hinged_pair(12.0, 6.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 1.5 * (tile[4:, :2] - centre)
    hinge = np.array([[0, 0, 1, 0]])
    no_lifts = np.zeros((0, 2), dtype=np.int64)
    at_hinge = np.array([[0, 0, 0, 3], [1, 1, 0, 3]])
    made = design_reliefs(tiles, hinge, ["top"], at_hinge, no_lifts, profile, 0.4)
    assert made is not None and made.skipped == (0,)
    welded = relief_shortfall(tiles, hinge, ["top"], at_hinge, no_lifts, profile, 0.4)
    assert welded is not None and welded.hinges == (0,) and welded.tiles == (0, 1)
    assert welded.have < 0.0 and welded.need == pytest.approx(0.4 + feature_wall_mm(profile))
    short = feature_shortfall(profile, tiles, at_hinge, no_lifts, hinge, ["top"])
    assert short is not None and "print welded" in str(short)
    assert short.have < short.need

    far = np.array([[0, 0, 1, 2], [1, 1, 0, 3]])
    made = design_reliefs(tiles, hinge, ["top"], far, no_lifts, profile, 0.4)
    assert made is not None and made.skipped == () and made.hollowed == (0,)
    assert relief_shortfall(tiles, hinge, ["top"], far, no_lifts, profile, 0.4) is None
    assert feature_shortfall(profile, tiles, far, no_lifts, hinge, ["top"]) is None


def test_hinge_reliefs_are_worked_out_once_per_content_of_their_arrays() -> None:
    # The route's checks, the CAD stage's and the solids ask for the reliefs of the same
    # arrays: the second ask with equal arrays (new objects) gets the first result itself;
    # other arrays (a channel moved) get their own, the one worked out afresh.
    from drawstring.cad import hinge_plans
    from drawstring.cad.memo import content_key
    from drawstring.fabrication.profiles import load_profile

    profile = load_profile("fdm-dual")
    tiles = _hinged_pair(12.0, 6.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 1.5 * (tile[4:, :2] - centre)
    hinge = np.array([[0, 0, 1, 0]])
    no_lifts = np.zeros((0, 2), dtype=np.int64)
    at_hinge = np.array([[0, 0, 0, 3], [1, 1, 0, 3]])
    far = np.array([[0, 0, 1, 2], [1, 1, 0, 3]])
    first = hinge_plans.design_reliefs(tiles, hinge, ["top"], at_hinge, no_lifts, profile, 0.4)
    again = hinge_plans.design_reliefs(
        tiles.copy(), hinge.copy(), ["top"], at_hinge.copy(), no_lifts, profile, 0.4
    )
    assert again is first
    other = hinge_plans.design_reliefs(tiles, hinge, ["top"], far, no_lifts, profile, 0.4)
    assert other is not None and first is not None and other.hollowed != first.hollowed
    hinge_plans._RELIEFS.clear()
    hinge_plans._KEEP_OUTS.clear()
    fresh = hinge_plans.design_reliefs(tiles, hinge, ["top"], far, no_lifts, profile, 0.4)
    assert fresh is not None and fresh is not other
    assert (fresh.skipped, fresh.hollowed, fresh.apart) == (other.skipped, other.hollowed, ())
    assert fresh.hollows.keys() == other.hollows.keys()
    for tile, polyhedra in fresh.hollows.items():
        for made, kept in zip(polyhedra, other.hollows[tile], strict=True):
            assert np.array_equal(made, kept)
    # the key tells arrays apart by dtype and shape as well as bytes
    assert content_key(np.zeros(4)) != content_key(np.zeros((2, 2)))
    assert content_key(np.zeros(4)) != content_key(np.zeros(4, dtype=np.int64))
    assert content_key(at_hinge) == content_key(at_hinge.copy())


def test_a_hinge_left_unrelieved_with_room_to_spare_still_ranks_as_a_finite_shortfall() -> None:
    # Tiles 1 deg apart whose bottoms spread three times their tops, with no string through
    # them: the relief would take over half a tile, so the hinge is left unrelieved although
    # no feature is in the way (room: infinity).  The check still refuses it, with a finite
    # room under the need (the values search divides by it) and words without "inf".
    from drawstring.cad.hinge_plans import relief_shortfall
    from drawstring.fabrication.profiles import load_profile
    from drawstring.pipeline.cad_stage import feature_shortfall

    profile = load_profile("fdm-dual")
    tiles = _hinged_pair(1.0, 6.0)
    for tile in tiles:
        centre = tile[4:, :2].mean(axis=0)
        tile[4:, :2] = centre + 3.0 * (tile[4:, :2] - centre)
    hinge = np.array([[0, 0, 1, 0]])
    no_lifts = np.zeros((0, 2), dtype=np.int64)
    no_steps = np.zeros((0, 4), dtype=np.int64)
    welded = relief_shortfall(tiles, hinge, ["top"], no_steps, no_lifts, profile, 0.4)
    assert welded is not None and welded.hinges == (0,) and welded.have >= welded.need
    short = feature_shortfall(profile, tiles, no_steps, no_lifts, hinge, ["top"])
    assert short is not None and "print welded" in str(short) and "inf" not in str(short)
    assert 0.0 < short.have < short.need and math.isfinite(short.have)


def test_tiles_not_hinged_together_that_come_too_close_are_cut_apart() -> None:
    # Two 6 mm box tiles 0.2 mm apart along x, not hinged together (tile 1 is hinged to a far
    # tile 2 only): one loses what lies within 0.4 mm of the other, and the solids then print
    # 0.4 mm apart.  Where each holds a string channel opening on the facing side, no cut
    # clears it: the pair is crowded, and the checks before any solid count it.
    from drawstring.cad.clearance import HingeReliefs, apart_reliefs
    from drawstring.cad.hinge_plans import relief_shortfall
    from drawstring.fabrication.profiles import load_profile

    tiles = np.stack(
        [
            _square(np.array([0.0, 0.0]), 0.0, 6.0, 0.0, 6.0),
            _square(np.array([6.2, 0.0]), 0.0, 6.0, 0.0, 6.0),
            _square(np.array([12.2, 6.0]), 0.0, 6.0, 0.0, 6.0),
        ]
    )
    hinge = np.array([[1, 2, 2, 0]])
    none = HingeReliefs({}, 0.0, 0.0, 0.0, 0, ())
    reliefs = apart_reliefs(tiles, hinge, none, 0.4, lambda *_: KeepOut(), 0.4)
    assert len(reliefs.apart) == 1 and set(reliefs.apart[0]) == {0, 1} and reliefs.crowded == ()
    ((cut, polyhedra),) = reliefs.hollows.items()
    solids = [tile_solid(t) for t in tiles[:2]]
    for points in polyhedra:
        solids[cut] = solids[cut] - trim_tool(points)
    assert clearances(solids, 1.0).min_distance >= 0.4 - 1e-4
    # what it loses: a slab 0.2 mm thick over the 6 x 6 mm face
    assert 1.0 - solids[cut].volume / 216.0 == pytest.approx(0.2 / 6.0, rel=1e-6)

    profile = load_profile("fdm-dual")
    facing = np.array([[0, 0, 3, 1], [1, 1, 3, 1]])  # each channel opens on the facing side
    no_lifts = np.zeros((0, 2), dtype=np.int64)
    crowded = relief_shortfall(tiles, hinge, ["top"], facing, no_lifts, profile, 0.4)
    assert crowded is not None and crowded.pairs == ((0, 1),) and crowded.hinges == ()
    assert crowded.have < crowded.need
    away = np.array([[0, 0, 0, 2], [1, 1, 0, 2]])  # across the tiles, clear of the gap
    assert relief_shortfall(tiles, hinge, ["top"], away, no_lifts, profile, 0.4) is None
