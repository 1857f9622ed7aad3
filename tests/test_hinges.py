"""Hinge sides, top-hinge trimming and the dual-hinge layout (paper section 4.4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.flat.layout import extrude_flat, optimize_flat
from drawstring.geometry.flat.verify import heightfield_tiles, hinge_gaps, interpenetration
from drawstring.geometry.hinges.placement import (
    _held_apart,
    hinge_vertex_json,
    layout_hinges,
    write_flat_obj,
)
from drawstring.geometry.hinges.sides import hinge_sides
from drawstring.geometry.hinges.trims import hinge_trims
from drawstring.geometry.tiling.linkage import build_linkage


def _grid(n: int, size: float = 100.0):
    linkage = build_linkage(np.ones((n, n), dtype=bool))
    uv = linkage.vertex_ij * (size / n) - 0.5 * size
    return linkage, uv


def _block(flare: float, h: float) -> np.ndarray:
    """2x2 closed block of 10 mm tiles whose bottoms are ``flare`` mm wider on every side."""
    tiles = []
    for j in range(2):
        for i in range(2):
            x0, y0 = 10.0 * i, 10.0 * j
            sq = np.array([[x0, y0], [x0 + 10, y0], [x0 + 10, y0 + 10], [x0, y0 + 10]])
            grow = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * flare
            top = np.c_[sq, np.full(4, h)]
            bottom = np.c_[sq + grow, np.zeros(4)]
            tiles.append(np.vstack([top, bottom]))
    return np.array(tiles)


def test_hinge_sides_on_cylinders() -> None:
    linkage, uv = _grid(6)
    _, outside = heightfield_tiles(uv, linkage.tile_corners, "cylinder", 4.0, 40.0)
    _, inside = heightfield_tiles(uv, linkage.tile_corners, "cylinder_inside", 4.0, 40.0)
    assert not hinge_sides(linkage, outside).any()
    assert hinge_sides(linkage, inside).all()
    _, plane = heightfield_tiles(uv, linkage.tile_corners, "plane", 4.0, 0.0)
    assert not hinge_sides(linkage, plane).any()


def test_hand_built_block_sides_and_trim() -> None:
    linkage, _ = _grid(2)
    h = 3.0
    flared = _block(1.0, h)  # bottoms overhang: every hinge goes to the bottom
    assert hinge_sides(linkage, flared).all()
    assert not hinge_sides(linkage, _block(-1.0, h)).any()
    # Top hinges on the closed flared block: neighbours overlap in the wedge between their
    # leaning contact faces.  At depth fraction u below the top the overlap is 2u wide and
    # 10 + 2u long, so its volume is h * int_0^1 2u (10 + 2u) du = h (10 + 4/3).  The trimmed tile
    # loses its whole contact face toward the other (a trapezoid, 11 L with L = sqrt(h^2 + 1)) and
    # a triangle of area L on each of the two faces beside it: 13 L.
    trims = hinge_trims(linkage, flared)
    assert len(trims) == linkage.n_hinges == 4
    slant = np.sqrt(h * h + 1.0)
    for trim in trims:
        ta, _, tb, _ = linkage.hinges[trim.hinge]
        assert trim.tile == max(ta, tb)
        assert trim.volume_mm3 == pytest.approx(h * (10.0 + 4.0 / 3.0), rel=1e-9)
        assert trim.contact_area_lost_mm2 == pytest.approx(13.0 * slant, rel=1e-6)


def test_dual_layout_inside_cylinder_meets_hinges() -> None:
    linkage, uv = _grid(6)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "cylinder_inside", 4.0, 40.0)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=10.0)
    t2 = extrude_flat(flat, t3)
    assert interpenetration(t2)[0] > 0.1  # top hinges would collide here
    layout = layout_hinges(linkage, flat, t2, t3, strategy="dual")
    assert layout.bottom.all()
    assert layout.hinge_gap_max_mm < 1e-9
    assert hinge_gaps(layout.tiles, layout.hinge_vertices).max() == 0.0
    assert interpenetration(layout.tiles)[0] < 1e-9
    top_layout = layout_hinges(linkage, flat, t2, t3, strategy="top")
    assert top_layout.contact_area_lost_mm2 > 0 and top_layout.problems


def test_dual_pairs_that_never_clear_are_trimmed_not_held_apart() -> None:
    """Top hinges inside a cylinder: the bottoms overhang, so the pairs collide on their hinge
    face at every opening.  A dual layout handed these sides lays such pairs out like top
    hinges (tops apart, overlap trimmed) and their hinges meet; held apart as rigid pairs
    instead, they could not meet."""
    from drawstring.geometry.core.tolerances import FLAT_INTERPENETRATION_TOL_MM3
    from drawstring.geometry.flat.pose import hinge_faces
    from drawstring.geometry.flat.verify import flat_overlap
    from drawstring.geometry.hinges.placement import _hinge_vertex_ids
    from drawstring.geometry.hinges.rigid_layout import rigid_layout
    from drawstring.geometry.tiling.linkage import slit_ends

    linkage, uv = _grid(6)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "cylinder_inside", 4.0, 40.0)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=10.0)
    t2 = extrude_flat(flat, t3)
    on_top = np.zeros(linkage.n_hinges, dtype=bool)
    _, _, fits = hinge_faces(linkage, t3, on_top).window(np.radians(10.0), 0.5 * np.pi)
    never = np.zeros(linkage.n_hinges, dtype=bool)
    never[slit_ends(linkage).hinge[~fits]] = True
    assert never.any()
    layout = layout_hinges(linkage, flat, t2, t3, strategy="dual", bottom=on_top)
    assert {tr.hinge for tr in layout.trims} <= set(np.flatnonzero(never).tolist())
    assert layout.trims and layout.contact_area_lost_mm2 > 0
    assert any(p.startswith("dual hinges:") for p in layout.problems)
    assert layout.hinge_gap_max_mm < 1e-3
    assert flat_overlap(layout.tiles[:, :4, :2])[0] == 0.0
    trims = [(tr.tile, tr.vertices) for tr in layout.trims]
    assert interpenetration(layout.tiles, trims=trims)[0] <= FLAT_INTERPENETRATION_TOL_MM3
    ids = _hinge_vertex_ids(linkage, on_top)
    held = rigid_layout(linkage, t2, ids, min_gap_angle_deg=10.0, trim=np.zeros_like(never))
    assert held.gap_mm[never].max() > 10 * layout.hinge_gap_max_mm + 1e-3


def test_a_layout_like_another_takes_its_first_planes_and_ends_the_same() -> None:
    """``rigid_layout(like=...)`` reuses the earlier layout's first planes for the pairs whose
    trim flag is unchanged and searches the others: the result is bitwise the one found
    without it."""
    from dataclasses import fields, replace

    from drawstring.geometry.hinges.placement import _hinge_vertex_ids
    from drawstring.geometry.hinges.rigid_layout import rigid_layout
    from drawstring.geometry.tiling.linkage import slit_ends

    linkage, uv = _grid(6)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.006)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=12.0)
    t2 = extrude_flat(flat, t3)
    bottom = hinge_sides(linkage, t3, 12.0)
    ids = _hinge_vertex_ids(linkage, bottom)
    trim = np.zeros(linkage.n_hinges, dtype=bool)
    first = rigid_layout(linkage, t2, ids, min_gap_angle_deg=12.0, trim=trim)
    changed = np.zeros_like(trim)
    changed[slit_ends(linkage).hinge[:4]] = True
    alone = rigid_layout(linkage, t2, ids, min_gap_angle_deg=12.0, trim=changed)
    again = rigid_layout(linkage, t2, ids, min_gap_angle_deg=12.0, trim=changed, like=first)
    for name in ("tiles", "merged", "points", "is_merged", "gap_mm"):
        np.testing.assert_array_equal(getattr(again, name), getattr(alone, name))
    for f in fields(alone.first_planes):
        np.testing.assert_array_equal(
            getattr(again.first_planes, f.name), getattr(alone.first_planes, f.name)
        )
    # the rows are taken, not searched again: marked scores come through, except on the rows
    # of the hinges whose flag changed
    planes = first.first_planes
    marked = replace(first, first_planes=replace(planes, score=planes.score + 1.0))
    seen = rigid_layout(linkage, t2, ids, min_gap_angle_deg=12.0, trim=changed, like=marked)
    moved = seen.first_planes.score != alone.first_planes.score
    of_changed = np.isin(alone.first_planes.hinge, np.flatnonzero(changed))
    assert of_changed.any() and (~of_changed).any()
    assert moved[~of_changed].all() and not moved[of_changed].any()
    # planes searched with another clearance are not taken
    wider = rigid_layout(
        linkage, t2, ids, min_gap_angle_deg=12.0, trim=changed, like=marked, clearance_mm=0.05
    )
    fresh = rigid_layout(linkage, t2, ids, min_gap_angle_deg=12.0, trim=changed, clearance_mm=0.05)
    np.testing.assert_array_equal(wider.first_planes.score, fresh.first_planes.score)


def test_flat_obj_is_closed_and_outward(tmp_path: Path) -> None:
    tiles = _block(-0.5, 2.0)
    path = tmp_path / "flat.obj"
    write_flat_obj(path, tiles)
    verts = np.array(
        [
            [float(v) for v in ln.split()[1:]]
            for ln in path.read_text().splitlines()
            if ln[:2] == "v "
        ]
    )
    faces = [
        [int(v) - 1 for v in ln.split()[1:]]
        for ln in path.read_text().splitlines()
        if ln.startswith("f ")
    ]
    assert len(faces) == 6 * len(tiles)
    np.testing.assert_allclose(verts.reshape(-1, 8, 3), tiles)
    volume = 0.0
    for f in faces[:6]:
        for k in range(1, 3):
            a, b, c = verts[f[0]], verts[f[k]], verts[f[k + 1]]
            volume += np.dot(a, np.cross(b, c)) / 6.0
    assert volume > 0  # outward orientation
    edges = {tuple(sorted(e)) for f in TILE_FACES for e in zip(f, np.roll(f, -1), strict=True)}
    assert len(edges) == 12  # closed box


def test_hinge_json_serializes() -> None:
    linkage, uv = _grid(3)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 3.0, 0.004)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=10.0)
    layout = layout_hinges(linkage, flat, extrude_flat(flat, t3), t3)
    data = hinge_vertex_json(layout, linkage)
    assert len(data["hinges"]) == linkage.n_hinges
    json.dumps(data)


@pytest.mark.parametrize("surface", ["saddle", "dome"])
@pytest.mark.parametrize("strategy", ["dual", "top"])
def test_hinged_layout_is_valid(surface: str, strategy: str) -> None:
    """Hard requirements after the hinge layout and the merge: every gap angle (top faces and
    hinge faces) within [theta_min, 90], no footprint overlap, no 3D interpenetration (for
    ``top`` after subtracting the recorded trims)."""
    from drawstring.geometry.core.tolerances import (
        FLAT_GAP_ANGLE_TOL_DEG,
        FLAT_INTERPENETRATION_TOL_MM3,
        FLAT_OVERLAP_TOL_MM2,
    )
    from drawstring.geometry.flat.verify import flat_overlap, gap_opening_angles_deg

    linkage, uv = _grid(8)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, surface, 6.0, 0.004)
    flat = optimize_flat(linkage, top, uv=uv, min_gap_angle_deg=12.0)
    t2 = extrude_flat(flat, t3, 6.0)
    layout = layout_hinges(linkage, flat, t2, t3, strategy=strategy)
    tiles = layout.tiles
    assert flat_overlap(tiles[:, :4, :2])[0] <= FLAT_OVERLAP_TOL_MM2
    trims = [(tr.tile, tr.vertices) for tr in layout.trims]
    assert interpenetration(tiles, trims=trims)[0] <= FLAT_INTERPENETRATION_TOL_MM3
    for angles in (
        gap_opening_angles_deg(linkage, tiles[:, :4]),
        gap_opening_angles_deg(linkage, tiles, layout.bottom),
    ):
        assert angles.min() >= 12.0 - FLAT_GAP_ANGLE_TOL_DEG
        assert angles.max() <= 90.0 + FLAT_GAP_ANGLE_TOL_DEG
    merged = hinge_gaps(tiles, layout.hinge_vertices)
    assert np.count_nonzero(merged == 0.0) >= 0.9 * linkage.n_hinges
    # Tiles stay rigid up to the merge: every vertex moved by at most half the hinge gap.
    assert layout.hinge_gap_max_mm < 1.0


def test_hinge_face_angle_measure() -> None:
    """A bottom-hinged slit end is measured on the bottom sides: flaring the bottoms turns
    the measured sides, and the measure follows the hinge face."""
    from drawstring.geometry.flat.verify import gap_opening_angles_deg

    linkage, _ = _grid(2)
    tiles = _block(1.0, 3.0)
    ends_top = gap_opening_angles_deg(linkage, tiles[:, :4])
    bottom = np.ones(linkage.n_hinges, dtype=bool)
    ends_bottom = gap_opening_angles_deg(linkage, tiles, bottom)
    # Closed block: top and bottom sides of neighbours are parallel, so both are 0 here; open
    # the block by turning the bottom faces only and the bottom measure alone changes.
    np.testing.assert_allclose(ends_top, 0.0, atol=1e-9)
    np.testing.assert_allclose(ends_bottom, 0.0, atol=1e-9)
    turned = tiles.copy()
    c = turned[0, 4:, :2].mean(axis=0)
    ang = np.radians(5.0)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    turned[0, 4:, :2] = (turned[0, 4:, :2] - c) @ rot.T + c
    moved_bottom = np.abs(gap_opening_angles_deg(linkage, turned, bottom))
    assert np.allclose(gap_opening_angles_deg(linkage, turned[:, :4]), ends_top)
    assert np.isclose(moved_bottom.max(), 5.0)


def _dart_and_square(shift: float) -> np.ndarray:
    """A dart-shaped 3 mm tile (reflex corner 2 at (3, 3), a right-angled notch x, y >= 3)
    and a 2 mm square in the notch, its corner moved ``shift`` mm (in x and y) past the tip."""
    dart = np.array([[0.0, 0.0], [8.0, 3.0], [3.0, 3.0], [3.0, 8.0]])
    s = 3.0 - shift
    square = np.array([[s, s], [s + 2.0, s], [s + 2.0, s + 2.0], [s, s + 2.0]])
    return np.array(
        [np.vstack([np.c_[q, np.full(4, 3.0)], np.c_[q, np.zeros(4)]]) for q in (dart, square)]
    )


def test_dart_tile_is_measured_as_its_convex_pieces() -> None:
    """Regression (three-shell): a non-convex tile is not its convex hull.  A square resting in
    the notch of a dart-shaped tile touches it at one point only; the hull would report an
    overlap.  Pushed ``d`` into the dart, the overlap is an L-shaped band: ``4 d - d^2``."""
    from drawstring.geometry.flat.polygons import convex_pieces, reflex_corners
    from drawstring.geometry.flat.verify import flat_overlap

    tiles = _dart_and_square(0.0)
    assert list(reflex_corners(tiles[:, :4])) == [2, -1]
    pieces = convex_pieces(tiles)
    assert sorted(np.flatnonzero(pieces[0, 0])) == [0, 2, 3, 4, 6, 7]
    assert sorted(np.flatnonzero(pieces[0, 1])) == [0, 1, 2, 4, 5, 6]
    assert pieces[1, 0].all() and not pieces[1, 1].any()
    assert flat_overlap(tiles[:, :4, :2])[0] == pytest.approx(0.0, abs=1e-12)
    assert interpenetration(tiles)[0] == pytest.approx(0.0, abs=1e-9)
    d = 0.5
    pushed = _dart_and_square(d)
    assert flat_overlap(pushed[:, :4, :2])[0] == pytest.approx(4 * d - d * d, rel=1e-9)
    assert interpenetration(pushed)[0] == pytest.approx(3.0 * (4 * d - d * d), rel=1e-6)


def test_dual_layout_with_a_dart_tile_is_valid() -> None:
    """A 2x2 block whose centre is pulled into tile 0 (a dart with its reflex corner at the
    hinges): the layout separates the dart's convex pieces, and the result has no overlap."""
    from drawstring.geometry.flat.verify import flat_overlap

    linkage, _ = _grid(2)
    tiles = []
    for j in range(2):
        for i in range(2):
            x0, y0 = 10.0 * i, 10.0 * j
            sq = np.array([[x0, y0], [x0 + 10, y0], [x0 + 10, y0 + 10], [x0, y0 + 10]])
            sq[np.all(sq == 10.0, axis=1)] = (4.0, 4.0)
            tiles.append(np.vstack([np.c_[sq, np.full(4, 3.0)], np.c_[sq, np.zeros(4)]]))
    t3 = np.array(tiles)
    flat = optimize_flat(
        linkage, t3[:, :4], uv=linkage.vertex_ij * 10.0, min_gap_angle_deg=10.0, tiles_3d=t3
    )
    layout = layout_hinges(linkage, flat, extrude_flat(flat, t3), t3, strategy="dual")
    assert flat_overlap(layout.tiles[:, :4, :2])[0] == 0.0
    assert interpenetration(layout.tiles)[0] == 0.0
    assert not any("could not be separated" in p for p in layout.problems)


def test_pairs_held_apart_near_the_tolerance_are_laid_out_again_only_where_they_matter() -> None:
    # four hinge pairs: tile 2k's vertex 0 with tile 2k+1's vertex 0; in T2D pair k is
    # ``start[k]`` mm apart
    start = np.array([2e-6, 8e-4, 1e-6, 3e-4])
    tiles = np.zeros((8, 8, 3))
    tiles[1::2, 0, 0] = start
    ids = np.array([[8 * (2 * k), 8 * (2 * k + 1)] for k in range(4)])
    assert np.allclose(hinge_gaps(tiles, ids, in_plane=True), start)
    free = np.ones(4, dtype=bool)
    # pair 0 is held 9e-4 mm apart from 2e-6 and is the widest: laid out again; pair 1 is
    # only as far apart as the flat layout left it, pair 3 not near the tolerance
    gaps = np.array([9e-4, 8.5e-4, 1e-5, 3.2e-4])
    assert _held_apart(gaps, tiles, ids, free).tolist() == [True, False, False, False]
    # ... unless a pair the flat layout left apart is wider: another layout gains nothing
    gaps[1] = 9.5e-4
    assert not _held_apart(gaps, tiles, ids, free).any()
    # pairs beyond the tolerance always count, and near ones join them where they are wider
    # than every other pair
    gaps = np.array([9e-4, 8.5e-4, 1.5e-3, 3.2e-4])
    assert _held_apart(gaps, tiles, ids, free).tolist() == [True, False, True, False]
    # pairs that are not free (trimmed: separated on their hinge face only) never count, but
    # one that is wider still leaves nothing to gain
    free[2] = False
    assert not _held_apart(gaps, tiles, ids, free).any()
    gaps[2] = 5e-4
    assert _held_apart(gaps, tiles, ids, free).tolist() == [True, False, False, False]
    free[0] = False
    assert not _held_apart(gaps, tiles, ids, free).any()


def test_released_slit_ends_are_laid_out_like_pairs_that_never_clear(monkeypatch) -> None:
    """A slit end the co-optimization released from its clear window is separated on its
    hinge face only (its overlap, if any, trimmed), like an end that never clears."""
    from dataclasses import replace

    import drawstring.geometry.hinges.placement as hinges_module
    from drawstring.geometry.flat.pose import hinge_faces
    from drawstring.geometry.tiling.linkage import slit_ends

    linkage, uv = _grid(6)
    top, t3 = heightfield_tiles(uv, linkage.tile_corners, "saddle", 6.0, 0.006)
    bottom = hinge_sides(linkage, t3, 12.0)
    faces = hinge_faces(linkage, t3, bottom)
    _, _, fits = faces.window(np.radians(12.0), 0.5 * np.pi)
    released = np.zeros(len(fits), dtype=bool)
    released[np.flatnonzero(fits)[:3]] = True
    flat = optimize_flat(
        linkage, top, uv=uv, min_gap_angle_deg=12.0, tiles_3d=t3,
        hinges=replace(faces, released=released),
    )  # fmt: skip
    seen: list[np.ndarray] = []
    rigid_layout = hinges_module.rigid_layout

    def recording(*args, **kwargs):
        seen.append(np.array(kwargs["trim"]))
        return rigid_layout(*args, **kwargs)

    monkeypatch.setattr(hinges_module, "rigid_layout", recording)
    layout_hinges(linkage, flat, extrude_flat(flat, t3), t3, strategy="dual")
    ends = slit_ends(linkage)
    assert seen[0][ends.hinge[released]].all()
    assert not seen[0][ends.hinge[fits & ~released]].any()
