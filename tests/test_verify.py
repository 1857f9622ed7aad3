"""Independent measurements of assembled tiles (geometry.verify.assembled_overlap)."""

from __future__ import annotations

import numpy as np
import pytest

from drawstring.geometry.flat.polygons import (
    convex_penetration_depth,
    polygon_in_convex_polyhedron_area,
    reflex_corners,
)
from drawstring.geometry.flat.verify import assembled_overlap


def box(x0: float, y0: float, z0: float, dx: float, dy: float, dz: float) -> np.ndarray:
    """An axis-aligned box as an 8-vertex tile: top corners counter-clockwise, bottom under."""
    top = np.array([[x0, y0], [x0 + dx, y0], [x0 + dx, y0 + dy], [x0, y0 + dy]])
    return np.vstack([np.c_[top, np.full(4, z0 + dz)], np.c_[top, np.full(4, z0)]])


def rotate(tiles: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate tiles rigidly (Rodrigues) so that nothing lies in the (x, y) plane."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    r = np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx
    return np.asarray(tiles @ r.T)


def test_overlapping_boxes_known_volume_and_depth() -> None:
    a = box(0.0, 0.0, 0.0, 10.0, 10.0, 4.0)
    b = box(8.5, 2.0, 1.0, 10.0, 10.0, 4.0)  # overlap 1.5 x 8 x 3
    tiles = rotate(np.stack([a, b]), np.array([1.0, 2.0, 0.5]), 0.7)
    result = assembled_overlap(tiles)
    assert result.volume_mm3 == pytest.approx(1.5 * 8.0 * 3.0, rel=1e-9)
    assert result.depth_max_mm == pytest.approx(1.5, rel=1e-9)
    assert result.pairs.tolist() == [[0, 1]]
    assert result.nonconvex_faces == 0
    assert convex_penetration_depth(a, b) == pytest.approx(1.5, rel=1e-12)


def test_neighbours_sharing_a_face_do_not_count() -> None:
    tiles = np.stack(
        [box(10.0 * i, 10.0 * j, 0.0, 10.0, 10.0, 3.0) for i in range(3) for j in range(3)]
    )
    tiles = rotate(tiles, np.array([0.3, -1.0, 0.2]), 1.1)
    result = assembled_overlap(tiles)
    assert result.volume_mm3 == 0.0
    assert result.depth_max_mm == 0.0
    assert len(result.pairs) == 0
    assert result.to_json()["assembled_overlap_pairs"] == 0


def test_dart_tile_is_counted_and_measured_as_its_pieces() -> None:
    """A dart-shaped (folded) top face is reported; a box resting in its notch touches it only,
    although the two convex hulls overlap."""
    dart_top = np.array([[0.0, 0.0], [4.0, 0.0], [2.0, 1.0], [0.0, 4.0]])  # corner 2 reflex
    dart = np.vstack([np.c_[dart_top, np.full(4, 2.0)], np.c_[dart_top, np.zeros(4)]])
    notch = np.vstack(
        [
            np.c_[np.array([[2.0, 1.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]), np.full(4, 2.0)],
            np.c_[np.array([[2.0, 1.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]), np.zeros(4)],
        ]
    )
    tiles = rotate(np.stack([dart, notch]), np.array([1.0, 1.0, 1.0]), 0.9)
    assert list(reflex_corners(tiles[:, :4], in_plane=True)) == [2, -1]
    result = assembled_overlap(tiles)
    assert result.nonconvex_top.tolist() == [0]
    assert result.nonconvex_bottom.tolist() == [0]
    assert result.volume_mm3 == pytest.approx(0.0, abs=1e-9)
    assert len(result.pairs) == 0
    # The neighbour pushed 0.5 mm towards the dart's reflex corner now cuts into the dart.
    pushed = tiles.copy()
    shift = rotate(np.array([[[0.0, -0.5, 0.0]]]), np.array([1.0, 1.0, 1.0]), 0.9)[0, 0]
    pushed[1] += shift
    moved = assembled_overlap(pushed)
    assert moved.volume_mm3 > 0.1
    assert moved.depth_max_mm > 0.1


def _cube_planes(lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """The cube ``[lo, hi]^3`` as half-spaces: points on its faces and outward normals."""
    normals = np.vstack([np.eye(3), -np.eye(3)])
    points = np.vstack([np.full((3, 3), hi), np.full((3, 3), lo)])
    return points, normals


@pytest.mark.parametrize(
    ("corners", "expected"),
    [
        # a 4 x 4 square at z = 0 cut by the cube [-1, 1]^3 (a 2 x 2 square is inside)
        ([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]], 4.0),
        # a triangle whose corner pokes out of one face: 0.5 - 0.5 * 0.5^2 inside
        ([[0.0, 0.0], [1.5, 0.0], [0.0, 1.0]], 0.75 - 0.5 * 0.5 * (0.5 / 1.5)),
        # wholly inside, and wholly outside
        ([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5]], 0.5),
        ([[3.0, 3.0], [4.0, 3.0], [4.0, 4.0]], 0.0),
    ],
)
def test_polygon_in_convex_polyhedron_area_known(corners: list, expected: float) -> None:
    polygon = np.c_[np.asarray(corners), np.zeros(len(corners))]
    points, normals = _cube_planes(-1.0, 1.0)
    tilted = rotate(polygon[None], np.array([1.0, -2.0, 0.3]), 0.4)[0]
    area = polygon_in_convex_polyhedron_area(
        tilted,
        rotate(points[None], np.array([1.0, -2.0, 0.3]), 0.4)[0],
        rotate(normals[None], np.array([1.0, -2.0, 0.3]), 0.4)[0],
    )
    # the half-spaces are grown by the default tolerance, 1e-9 mm
    assert area == pytest.approx(expected, rel=1e-8, abs=1e-12)


def test_polygon_on_the_polyhedrons_face_counts_as_inside() -> None:
    # the cube's own top face: on the boundary, kept whole within the tolerance
    face = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    points, normals = _cube_planes(-1.0, 1.0)
    assert polygon_in_convex_polyhedron_area(face, points, normals) == pytest.approx(4.0)
