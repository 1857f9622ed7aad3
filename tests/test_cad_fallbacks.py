"""Fallbacks of the CAD stage where the first construction does not fit or fails: a magnet
pocket moved along its face (cad/magnets_labels.py) and a trim whose polyhedron has two
corners a hair apart (cad/features.py).

``ogre_face_trim.npy`` and ``ogre_face_trim_tile.npy`` (tests/data, from ogre_face.obj, see
corpus-provenance.tsv) are the hinge stage's trim of tile 97 and that tile (flat pose, mm) of
``drawstring design ogre_face.obj --tiles 96 --size 220``: two of the trim's grown corners
lie 7.6e-10 mm apart, and the kernel fails to make the edge between them.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from drawstring.cad.feature_common import feature_wall_mm
from drawstring.cad.features import trim_tool
from drawstring.cad.side_faces import bilinear, pocket_fits, pocket_place
from drawstring.cad.tiles import convex_solid, tile_solid
from drawstring.fabrication.profiles import Profile, load_profile

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def profile() -> Profile:
    return dataclasses.replace(
        load_profile("fdm-dual"), magnet_diameter_mm=3.0, magnet_height_mm=1.5
    )


def _face(points_2d: list[tuple[float, float]]) -> np.ndarray:
    """A side quad (top k, top k+1, bottom k, bottom k+1) in the plane y = 0."""
    return np.array([[x, 0.0, z] for x, z in points_2d])


def test_a_pocket_that_breaks_out_at_the_centre_moves_to_where_it_fits(profile: Profile) -> None:
    # Top edge 20 mm, bottom edge 1 mm, 6 mm tall: at the face's centre (5.25, -3) the slanted
    # right edge passes 1.58 mm away, under the pocket's 1.65 mm radius; near the left edge
    # the face is wide enough for the pocket and a wall.
    quad_a = _face([(0.0, 0.0), (20.0, 0.0), (0.0, -6.0), (1.0, -6.0)])
    quad_b = quad_a[[1, 0, 3, 2]]  # the touching face, seen from the other tile
    radius = 0.5 * profile.magnet_diameter_mm + profile.magnet_clearance_mm
    assert not pocket_fits(quad_a, 0.5, 0.5, radius)
    u, v = pocket_place(quad_a, quad_b, 0.5, radius, profile)
    assert (u, v) != (0.5, 0.5)
    assert pocket_fits(quad_a, u, v, radius + feature_wall_mm(profile))
    assert np.linalg.norm(bilinear(quad_a, u, v) - bilinear(quad_a, 0.5, 0.5)) < 6.0


def test_a_pocket_that_fits_stays_and_one_that_fits_nowhere_is_not_moved(
    profile: Profile,
) -> None:
    radius = 0.5 * profile.magnet_diameter_mm + profile.magnet_clearance_mm
    wide = _face([(0.0, 0.0), (20.0, 0.0), (0.0, -6.0), (20.0, -6.0)])
    assert pocket_place(wide, wide[[1, 0, 3, 2]], 0.6, radius, profile) == (0.6, 0.5)
    narrow = _face([(0.0, 0.0), (3.5, 0.0), (0.0, -6.0), (3.5, -6.0)])  # 3.5 mm: goat_head's
    assert pocket_place(narrow, narrow[[1, 0, 3, 2]], 0.5, radius, profile) == (0.5, 0.5)


def test_a_trim_with_corners_a_hair_apart_is_cut() -> None:
    points = np.load(DATA / "ogre_face_trim.npy")
    tile = np.load(DATA / "ogre_face_trim_tile.npy")
    gaps = np.linalg.norm(points[:, None] - points[None], axis=2)
    assert gaps[np.triu_indices(len(points), 1)].min() < 1e-9
    with pytest.raises(Exception):  # noqa: B017 (the kernel's own error class)
        convex_solid(points)
    tool = trim_tool(points)
    assert tool.is_valid  # made again from the points rounded to 1e-5 mm
    block = tile_solid(tile)
    cut = block - tool
    assert cut.is_valid
    # the trim's hull less what lies outside the tile, to the kernel's precision
    assert block.volume - cut.volume == pytest.approx((block & tool).volume, rel=1e-6)
    assert 0.0 < block.volume - cut.volume <= tool.volume


def test_a_pocket_a_relief_would_open_moves_clear_of_it(profile: Profile) -> None:
    # A wide face whose left part (u < 0.6) a relief plane cuts: the pocket leaves the
    # centre for the nearest place the cut leaves a wall clear, along the top edge.
    wide = _face([(0.0, 0.0), (20.0, 0.0), (0.0, -6.0), (20.0, -6.0)])
    radius = 0.5 * profile.magnet_diameter_mm + profile.magnet_clearance_mm
    asked: list[float] = []

    def clear(u: float, v: float, wall: float) -> bool:
        asked.append(wall)
        return (u - 0.6) * 20.0 >= radius + wall  # the cut's edge at u = 0.6, seen on the face

    u, v = pocket_place(wide, wide[[1, 0, 3, 2]], 0.5, radius, profile, clear)
    assert asked[0] == 0.0 and max(asked) == pytest.approx(feature_wall_mm(profile))
    assert (u - 0.6) * 20.0 >= radius + feature_wall_mm(profile) - 1e-9
    # the first place on the grid (1/40 of the face apart) 2.05 mm past the cut: u = 0.725
    assert v == 0.5 and u == pytest.approx(0.725)


def test_a_magnet_pair_that_fits_nowhere_is_left_out_only_where_another_joins_its_split() -> None:
    # tiles 0-1 in part 0, 2-3 in part 1, 4-5 in part 2: split 0|1 has a fitting pair and one
    # that does not (left out); split 1|2 has only pairs that do not fit (kept: they are all
    # that join those parts, with their problem)
    from drawstring.cad.magnets_labels import MagnetPair, pairs_left_out

    parts = np.array([0, 0, 1, 1, 2, 2])

    def pair(a: int, b: int, fits: bool) -> MagnetPair:
        return MagnetPair(a, 0, b, 2, np.zeros(3), 3.0, 1.5, "N", "S", fits)

    fits_01, misses_01 = pair(0, 2, True), pair(1, 3, False)
    misses_12 = [pair(2, 4, False), pair(5, 3, False)]
    left = pairs_left_out([fits_01, misses_01, *misses_12], parts)
    assert left == [misses_01]
    # every pair fits: none left out
    assert pairs_left_out([fits_01, pair(3, 5, True)], parts) == []


def test_a_pocket_a_hollow_relief_would_open_moves_clear_of_it(profile: Profile) -> None:
    # Two 20 mm boxes, 6 mm thick, touching at x = 20; a hollow cut out of tile a around the
    # middle of that face (y 7..13): the pocket pair leaves the middle for a place a wall
    # outside the hollow, and fits; without the hollow it stays in the middle.
    from scipy.spatial import ConvexHull

    from drawstring.cad.hinge_frame import outside_margin
    from drawstring.cad.magnets_labels import magnet_pockets

    def box(x0: float) -> np.ndarray:
        top = [(x0, 0.0), (x0 + 20.0, 0.0), (x0 + 20.0, 20.0), (x0, 20.0)]
        return np.array([[x, y, z] for z in (0.0, -6.0) for x, y in top])

    tile_a, tile_b = box(0.0), box(20.0)
    hollow = np.array([[x, y, z] for x in (17.0, 21.0) for y in (7.0, 13.0) for z in (-7.0, 1.0)])
    *_, middle = magnet_pockets(tile_a, 1, tile_b, 3, profile)
    assert middle.fits and middle.centre[1] == pytest.approx(10.0)
    *_, moved = magnet_pockets(tile_a, 1, tile_b, 3, profile, hollows=([hollow], []))
    assert moved.fits and abs(moved.centre[1] - 10.0) > 3.0
    radius, depth = 0.5 * moved.diameter_mm, moved.depth_mm
    hull = ConvexHull(hollow).equations
    normal = np.array([1.0, 0.0, 0.0])
    wall = feature_wall_mm(profile)
    assert outside_margin(moved.centre, normal, radius, depth, hull) >= wall - 1e-9
    assert outside_margin(middle.centre, normal, radius, depth, hull) < 0.0
