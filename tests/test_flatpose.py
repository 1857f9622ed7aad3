"""Hinged tiles lying flat: hinge points and collision-free openings (issue 4, dual hinges)."""

from __future__ import annotations

import numpy as np
import pytest

from drawstring.geometry.flat.pose import free_openings, hinge_faces, hinge_points, lay_flat
from drawstring.geometry.flat.verify import heightfield_tiles, interpenetration
from drawstring.geometry.hinges.sides import hinge_sides
from drawstring.geometry.tiling.linkage import build_linkage, slit_ends

CLEARANCE = 0.1
TOUCH = 1e-5


def _grid(n: int, size: float):
    linkage = build_linkage(np.ones((n, n), dtype=bool))
    uv = linkage.vertex_ij * (size / n) - 0.5 * size
    return linkage, uv


def _block(flare: float, h: float = 3.0) -> np.ndarray:
    """2x2 block of 10 mm tiles whose bottoms are ``flare`` mm wider on every side."""
    tiles = []
    for j in range(2):
        for i in range(2):
            sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float) + [10 * i, 10 * j]
            grow = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * flare
            tiles.append(np.vstack([np.c_[sq, np.full(4, h)], np.c_[sq + grow, np.zeros(4)]]))
    return np.array(tiles)


def _pose_pair(linkage, tiles: np.ndarray, bottom: np.ndarray, end: int, opening: float):
    """The two tiles of slit end ``end`` with the second turned about the hinge so that the
    opening on the hinge face is ``opening`` (rad) and its hinge vertex on the first's."""
    ends = slit_ends(linkage)
    t0, t1 = ends.tiles[end]
    h = linkage.hinges[ends.hinge[end]]
    c0 = h[1] if h[0] == t0 else h[3]
    c1 = h[1] if h[0] == t1 else h[3]
    face = 4 if bottom[ends.hinge[end]] else 0
    pair = tiles[[t0, t1]].copy()
    turn = float(ends.angles(tiles, face)[end]) - opening  # turning t1 by d lowers it by d
    apex = pair[1, face + c1, :2].copy()
    rel = pair[1, :, :2] - apex
    c, s = np.cos(turn), np.sin(turn)
    pair[1, :, :2] = np.c_[c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]]
    pair[1, :, :2] += pair[0, face + c0, :2]
    return pair


def test_boxes_clear_once_the_arms_are_a_clearance_apart() -> None:
    # Upright boxes hinged at a corner: the best separating line is the void's bisector, so the
    # tiles clear from the opening at which the sides' far ends stand ``clearance`` off it,
    # 2 asin(c / L), on either face, and stay clear up to 90 deg.
    linkage, _ = _grid(2, 20.0)
    tiles = _block(0.0)
    expected = np.degrees(2.0 * np.arcsin(CLEARANCE / 10.0))
    for face_bottom in (False, True):
        bottom = np.full(linkage.n_hinges, face_bottom)
        lo, hi = free_openings(linkage, tiles, bottom, clearance=CLEARANCE, touch=TOUCH)
        assert len(lo) == linkage.n_hinges
        assert np.degrees(lo) == pytest.approx(np.full(len(lo), expected), abs=0.01)
        assert np.degrees(hi) == pytest.approx(np.full(len(hi), 90.0))


def test_overhanging_faces_never_clear_and_decide_the_hinge_side() -> None:
    # Bottoms 1 mm wider than tops: hinged at the top, the bottom corners under the hinge poke
    # into each other at every opening; hinged at the bottom the tops are inset and clear.
    linkage, _ = _grid(2, 20.0)
    flared = _block(1.0)
    top_lo, top_hi = free_openings(
        linkage, flared, np.zeros(linkage.n_hinges, bool), clearance=CLEARANCE, touch=TOUCH
    )
    assert (top_lo > top_hi).all()
    bot_lo, bot_hi = free_openings(
        linkage, flared, np.ones(linkage.n_hinges, bool), clearance=CLEARANCE, touch=TOUCH
    )
    assert (bot_lo < np.radians(2.0)).all() and (bot_hi == pytest.approx(0.5 * np.pi))
    assert hinge_sides(linkage, flared, 12.0).all()
    assert not hinge_sides(linkage, _block(-1.0), 12.0).any()


def test_hinge_points_are_the_bottom_corners_seen_from_above() -> None:
    linkage, _ = _grid(2, 20.0)
    flared = _block(1.0)
    bottom = np.zeros(linkage.n_hinges, bool)
    bottom[0] = True
    pts = hinge_points(linkage, flared, bottom)
    h = linkage.hinges[0]
    for tile, corner in ((h[0], h[1]), (h[2], h[3])):
        # the top plane is z = 3: the bottom corner's (x, y) at the top's height
        assert pts[tile, corner] == pytest.approx(np.r_[flared[tile, 4 + corner, :2], 3.0])
    others = np.ones((linkage.n_tiles, 4), bool)
    others[h[0], h[1]] = others[h[2], h[3]] = False
    assert np.allclose(pts[others], flared[:, :4][others])


@pytest.mark.parametrize("surface,parameter", [("saddle", 0.004), ("dome", 0.004)])
def test_free_openings_agree_with_exact_interpenetration(surface: str, parameter: float) -> None:
    # Independent check with manifold3d: inside the interval the posed pair does not
    # interpenetrate; just outside it, where the interval is bounded by a collision (not by
    # the clearance asked for), it does.
    linkage, uv = _grid(6, 90.0)
    _, t3 = heightfield_tiles(uv, linkage.tile_corners, surface, 6.0, parameter)
    bottom = hinge_sides(linkage, t3, 12.0)
    faces = hinge_faces(linkage, t3, bottom)
    flat = lay_flat(t3)
    assert np.allclose(flat[:, :4, 2], 0.0, atol=1e-9)
    ends = slit_ends(linkage)
    assert len(faces.clear_lo) == len(ends.hinge)
    checked = 0
    for e in range(len(ends.hinge)):
        lo, hi = faces.clear_lo[e], faces.clear_hi[e]
        if lo > hi:
            continue
        inside = _pose_pair(linkage, flat, bottom, e, 0.5 * (lo + hi))
        assert interpenetration(inside)[0] < 1e-9
        checked += 1
    assert checked >= 0.9 * len(ends.hinge)
    # the other face of the same tiles collides where its interval is empty
    other = ~bottom
    lo_o, hi_o = free_openings(linkage, flat, other, clearance=0.0, touch=0.0)
    empty = np.flatnonzero(lo_o > hi_o)
    for e in empty[:5]:
        posed = _pose_pair(linkage, flat, other, e, np.radians(20.0))
        assert interpenetration(posed)[0] > 1e-6


def test_hinge_sides_pick_a_face_that_clears_within_the_bounds() -> None:
    # On a saddle some corners overhang one way across the shared side and the other way into
    # the void beside it; the chosen face must be one on which the pair clears within
    # [theta_min, 90] wherever either face does.
    linkage, uv = _grid(8, 120.0)
    _, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.006)
    theta = np.radians(12.0)
    bottom = hinge_sides(linkage, t3, 12.0)
    flat = lay_flat(t3)
    ends = slit_ends(linkage)

    def clears(faces_bottom: np.ndarray) -> np.ndarray:
        lo, hi = free_openings(linkage, flat, faces_bottom, clearance=CLEARANCE, touch=TOUCH)
        return np.maximum(lo, theta) <= np.minimum(hi, 0.5 * np.pi)

    on_top = clears(np.zeros(linkage.n_hinges, bool))
    on_bottom = clears(np.ones(linkage.n_hinges, bool))
    chosen = clears(bottom)
    either = on_top | on_bottom
    assert either.all() and chosen[either].all()
    # both faces occur, and the top one is not always the answer
    assert 0 < bottom.sum() < linkage.n_hinges
    assert (~on_top).any() or (~on_bottom).any()
    assert len(ends.hinge) == linkage.n_hinges


def test_windows_that_close_on_their_opening_are_released() -> None:
    """``HingeFaces.closing`` flags a slit end only when its opening stands at an end of its
    clear window and that end moved inwards on the newer tiles; ``window`` then treats a
    released end like one that never clears."""
    from drawstring.geometry.core.tolerances import FLAT_FREE_MARGIN_DEG
    from drawstring.geometry.flat.pose import CLOSING_BIND_DEG, CLOSING_SHIFT_DEG, HingeFaces

    deg = np.radians
    bottom = np.zeros(4, dtype=bool)
    lo = deg(np.array([5.0, 5.0, 5.0, 5.0]))
    hi = deg(np.array([40.0, 40.0, 40.0, 40.0]))
    faces = HingeFaces(bottom, lo, hi)
    held = FLAT_FREE_MARGIN_DEG + 0.5 * CLOSING_BIND_DEG  # inside the binding band
    opening = deg(np.array([40.0 - held, 20.0, 5.0 + held, 40.0 - held]))
    step = 10 * CLOSING_SHIFT_DEG
    newer = HingeFaces(
        bottom,
        lo + deg(np.array([0.0, step, step, 0.0])),
        hi - deg(np.array([step, step, 0.0, -step])),  # end 3's window widens
    )
    assert faces.closing(newer, opening).tolist() == [True, False, True, False]
    # a shift within CLOSING_SHIFT_DEG is not a closing window
    barely = HingeFaces(bottom, lo, hi - deg(0.5 * CLOSING_SHIFT_DEG))
    assert not faces.closing(barely, opening).any()
    # an opening further from the end than the band is not held by it
    free = opening - deg(np.array([2 * CLOSING_BIND_DEG, 0.0, -2 * CLOSING_BIND_DEG, 0.0]))
    assert faces.closing(newer, free).tolist() == [False, False, False, False]
    released = HingeFaces(bottom, lo, hi, released=np.array([True, False, False, False]))
    assert released.window(deg(10.0), deg(90.0))[2].tolist() == [False, True, True, True]
    assert faces.window(deg(10.0), deg(90.0))[2].all()


def test_hinge_face_openings_match_the_extruded_tiles() -> None:
    """The openings a dual layout's hard rows bound, read back on its rigid flat tiles by the
    independent measure of ``verify`` (each slit end on its hinge face)."""
    from drawstring.geometry.flat.layout import extrude_flat, hinge_face_openings, optimize_flat
    from drawstring.geometry.flat.verify import gap_opening_angles_deg

    linkage, uv = _grid(6, 90.0)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.006)
    bottom = hinge_sides(linkage, t3, 12.0)
    assert 0 < bottom.sum() < linkage.n_hinges
    faces = hinge_faces(linkage, t3, bottom)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=12.0, tiles_3d=t3, hinges=faces)
    measured = gap_opening_angles_deg(linkage, extrude_flat(flat, t3), bottom)
    opened = np.degrees(hinge_face_openings(linkage, flat, t3))
    # they differ only by how far the layout's tiles are from rigid (its edge error)
    side = float(np.mean(flat.edge_targets[:, :4]))
    misfit = np.degrees(4.0 * flat.edge_error_max_mm / side)
    np.testing.assert_allclose(opened, measured, atol=misfit)
    lo, hi, fits = faces.window(np.radians(12.0), 0.5 * np.pi)
    assert np.all(opened[fits] >= np.degrees(lo[fits]) - 1e-3)
    assert np.all(opened[fits] <= np.degrees(hi[fits]) + 1e-3)


def test_free_openings_do_not_depend_on_how_the_checks_are_split(monkeypatch) -> None:
    # The grid's checks go in one batch per core: each end is checked on its own, so the
    # windows are bitwise the same on any number of cores.
    from drawstring.geometry.flat import pose as flatpose

    linkage, uv = _grid(5, 80.0)
    _, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.004)
    bottom = hinge_sides(linkage, t3, 12.0)
    flat = lay_flat(t3)
    found = []
    for threads, rows in ((1, 2048), (3, 7)):
        monkeypatch.setattr(flatpose, "thread_count", lambda threads=threads: threads)
        monkeypatch.setattr(flatpose, "_CHECK_BLOCK_ROWS", rows)
        monkeypatch.setattr(flatpose, "map_blocks", lambda work, blocks: [work(b) for b in blocks])
        found.append(free_openings(linkage, flat, bottom, clearance=CLEARANCE, touch=TOUCH))
    assert np.array_equal(found[0][0], found[1][0]) and np.array_equal(found[0][1], found[1][1])
    assert np.any(found[0][0] > 0) or np.any(found[0][1] < 0.5 * np.pi)  # some ends bisected
