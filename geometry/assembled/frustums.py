"""Quad meshes and frustum tiles: edges, normals, orientation, the tile vertex arrays, corner
margins, and the measured metrics of an assembled configuration (:func:`measure_assembled`).

The geometry the assembled stage (:mod:`drawstring.geometry.assembled.shape`) and the later stages
share; the tile vertex and face order is described there.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import SIDE_FACES, TILE_FACES
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.solve.linalg import plane_fit


@dataclass(frozen=True)
class QuadMeshEdges:
    """Unique edges of a quad mesh with their quads.

    Attributes
    ----------
    edges : (e, 2) int
        Vertex pairs, oriented as in the first quad that has them.
    quads : (e, 2) int
        The quad on each side (``-1`` on the boundary for the second).
    sides : (e, 2) int
        Side index ``k`` (edge ``k -> k+1``) of the edge in each quad (``-1`` if none).
    """

    edges: IntArray
    quads: IntArray
    sides: IntArray

    @property
    def interior(self) -> BoolArray:
        return np.asarray(self.quads[:, 1] >= 0)


def quad_mesh_edges(quads: IntArray) -> QuadMeshEdges:
    """Unique edges of a quad mesh and the quads on either side.

    Parameters
    ----------
    quads : (m, 4) int

    Returns
    -------
    QuadMeshEdges

    Raises
    ------
    InternalError
        An edge used by more than two quads, or twice in the same direction (inconsistent
        orientation).
    """
    m = len(quads)
    directed = np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2)
    owner = np.repeat(np.arange(m), 4)
    side = np.tile(np.arange(4), m)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if np.any(counts > 2):
        raise InternalError(
            "the quad mesh has an edge shared by more than two quads; pass a manifold"
        )
    order = np.argsort(inverse, kind="stable")
    first = np.ones(len(order), dtype=bool)
    first[1:] = inverse[order[1:]] != inverse[order[:-1]]
    starts = order[first]
    n_edges = len(starts)
    edges = directed[starts]
    quads_out = np.full((n_edges, 2), -1, dtype=np.int64)
    sides_out = np.full((n_edges, 2), -1, dtype=np.int64)
    quads_out[:, 0] = owner[starts]
    sides_out[:, 0] = side[starts]
    seconds = order[~first]
    slot = inverse[seconds]
    quads_out[slot, 1] = owner[seconds]
    sides_out[slot, 1] = side[seconds]
    if np.any(np.all(directed[seconds] == edges[slot], axis=1)):
        raise InternalError(
            "the quad mesh is not consistently oriented; give every quad the same winding"
        )
    return QuadMeshEdges(edges=edges.astype(np.int64), quads=quads_out, sides=sides_out)


def quad_vector_areas(vertices: FloatArray, quads: IntArray) -> FloatArray:
    """Vector area of each quad (half the cross product of its diagonals).

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int

    Returns
    -------
    areas : (m, 3) float, mm^2
        Direction: the normal by the right-hand rule of the corner order.
    """
    d1 = vertices[quads[:, 2]] - vertices[quads[:, 0]]
    d2 = vertices[quads[:, 3]] - vertices[quads[:, 1]]
    return np.asarray(0.5 * np.cross(d1, d2))


def folded_faces(top: FloatArray, bottom: FloatArray, quads: IntArray) -> BoolArray:
    """(m,) bool: the extrusion folded the tile: its bottom faces the other way from its top
    (inside out), or is not convex in its own plane (a dart: one corner folded in) under a
    convex top.

    Where a tile is hardly wider than the tiles are thick, its bottom face, offset inwards
    under a strongly curved top, closes up: two of its corners meet and then cross.  The
    convexity test is the one ``metrics.assembled_nonconvex_*_faces`` measures: each corner's
    turn about the face's own normal (the cross product of its diagonals).  A bottom under a
    top that is not convex itself follows its top, and is not the extrusion's doing.

    Parameters
    ----------
    top, bottom : (n, 3) float, mm
    quads : (m, 4) int
    """
    inside_out = (
        np.einsum("ki,ki->k", quad_vector_areas(top, quads), quad_vector_areas(bottom, quads)) <= 0
    )
    return np.asarray(inside_out | (_reflex(bottom[quads]) & ~_reflex(top[quads])))


def _reflex(faces: FloatArray) -> BoolArray:
    """(m,) bool: the quads ``faces`` (m, 4, 3) have a reflex corner in their own plane."""
    normal = np.cross(faces[:, 2] - faces[:, 0], faces[:, 3] - faces[:, 1])
    incoming = faces - np.roll(faces, 1, axis=1)
    outgoing = np.roll(faces, -1, axis=1) - faces
    turn = np.einsum("kci,ki->kc", np.cross(incoming, outgoing), normal)
    return np.asarray(turn.min(axis=1) < 0)


def vertex_normals(vertices: FloatArray, quads: IntArray) -> FloatArray:
    """Area-weighted vertex normals of a quad mesh.

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int

    Returns
    -------
    normals : (n, 3) float, unit
    """
    areas = quad_vector_areas(vertices, quads)
    acc = np.zeros_like(vertices)
    for corner in range(4):
        np.add.at(acc, quads[:, corner], areas)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.asarray(acc / np.where(norm > 0, norm, 1.0))


def orient_outward(
    vertices: FloatArray, quads: IntArray, surface_vertices: FloatArray, surface_faces: IntArray
) -> IntArray:
    """Flip all quads if most of them face against the target surface's normals.

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int, consistently oriented
    surface_vertices : (p, 3) float, mm
    surface_faces : (f, 3) int, oriented outward

    Returns
    -------
    quads : (m, 4) int, counter-clockwise seen from the target's outward side
    """
    centres = vertices[quads].mean(axis=1)
    _, face_ids, _ = igl.point_mesh_squared_distance(centres, surface_vertices, surface_faces)
    tri = surface_vertices[surface_faces[face_ids]]
    target_normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    agree = np.einsum("ki,ki->k", quad_vector_areas(vertices, quads), target_normals)
    if np.sum(agree < 0) > np.sum(agree > 0):
        return np.ascontiguousarray(quads[:, ::-1])
    return quads


def square_edge_targets(vertices: FloatArray, quads: IntArray, edges: QuadMeshEdges) -> FloatArray:
    """Target length of each edge: mean of its adjacent quads' mean side lengths (paper 4.2).

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int
    edges : QuadMeshEdges

    Returns
    -------
    targets : (e,) float, mm
    """
    sides = vertices[np.roll(quads, -1, axis=1)] - vertices[quads]
    mean_side = np.linalg.norm(sides, axis=2).mean(axis=1)
    a = mean_side[edges.quads[:, 0]]
    b = np.where(edges.interior, mean_side[np.maximum(edges.quads[:, 1], 0)], a)
    return np.asarray(0.5 * (a + b))


def tile_vertices(top: FloatArray, bottom: FloatArray, quads: IntArray) -> FloatArray:
    """Per-tile vertex arrays of T3D.

    Parameters
    ----------
    top, bottom : (n, 3) float, mm
    quads : (m, 4) int

    Returns
    -------
    tiles : (m, 8, 3) float, mm
        Top corners in quad order, then the bottom corners under them.
    """
    return np.concatenate([top[quads], bottom[quads]], axis=1)


def side_quads(quads: IntArray, edges: QuadMeshEdges, n_vertices: int) -> IntArray:
    """Side (contact) faces over every mesh edge in the stacked ``[top; bottom]`` numbering.

    Parameters
    ----------
    quads : (m, 4) int
    edges : QuadMeshEdges
    n_vertices : int
        Bottom vertex ``i`` has id ``n_vertices + i``.

    Returns
    -------
    faces : (e, 4) int
        ``(top_i, bottom_i, bottom_j, top_j)`` for edge ``i -> j`` (as in its first quad), which is
        side face order of :data:`TILE_FACES`.
    """
    i, j = edges.edges[:, 0], edges.edges[:, 1]
    return np.stack([i, i + n_vertices, j + n_vertices, j], axis=1)


def corner_margins(
    vertices: FloatArray, quads: IntArray, reference_normals: FloatArray
) -> FloatArray:
    """Smallest corner margin of every quad (the measure :class:`ConvexCorners` bounds).

    A corner's margin is its height over the diagonal joining its two neighbours, towards the
    outside of the quad (in the plane normal to the quad's diagonal cross product, oriented by
    ``reference_normals``), divided by that diagonal's length: 0.5 at a square's corners, 0 at a
    straight angle, negative at a reflex corner (a dart) or for a quad turned over.

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int
    reference_normals : (m, 3) float

    Returns
    -------
    (m,) float
    """
    p = vertices[quads]
    normal = quad_vector_areas(vertices, quads)
    normal *= np.where(np.einsum("ki,ki->k", normal, reference_normals) < 0, -1.0, 1.0)[:, None]
    a, b, c = np.roll(p, 1, axis=1), p, np.roll(p, -1, axis=1)
    diagonal = c - a
    out = np.cross(diagonal, normal[:, None, :])
    out /= np.maximum(np.linalg.norm(out, axis=2, keepdims=True), 1e-300)
    height = np.einsum("kci,kci->kc", b - a, out)
    length = np.maximum(np.linalg.norm(diagonal, axis=2), 1e-300)
    return np.asarray((height / length).min(axis=1))


def _plane_distances(points: FloatArray, centroids: FloatArray, normals: FloatArray) -> FloatArray:
    return np.asarray(np.abs(np.einsum("ksi,ki->ks", points - centroids[:, None], normals)))


def measure_assembled(
    tiles: FloatArray,
    quads: IntArray,
    target_vertices: FloatArray,
    target_faces: IntArray,
) -> dict[str, float]:
    """Quality of a T3D tile set, measured on the tile vertices alone.

    Parameters
    ----------
    tiles : (m, 8, 3) float, mm
        Tile vertices in the order of :data:`TILE_FACES` (each tile its own copy).
    quads : (m, 4) int
        Only used to know which tiles are neighbours (they share a quad edge) and on which side.
    target_vertices : (p, 3) float, mm
    target_faces : (f, 3) int

    Returns
    -------
    metrics : dict[str, float]
        ``planarity_max_mm`` (max vertex-to-best-fit-plane distance over all six faces of all
        tiles), ``contact_gap_max_mm`` (over neighbouring tiles: max distance of one tile's contact
        face vertices to the best-fit plane of the other's matching face, both ways),
        ``contact_angle_max_deg`` (angle between those faces' planes), ``surface_distance_max_mm``
        and ``surface_distance_mean_mm`` (top vertices to the target), ``tile_side_spread``
        (max / min top side length), ``tile_side_mean_mm``, ``thickness_min_mm`` and
        ``thickness_max_mm`` (distance of bottom vertices to the top face's plane, along the
        outward normal) and ``flipped_tiles`` (tiles whose top faces against the target's normal
        at the closest point; 0 is right).
    """
    tiles = np.asarray(tiles, dtype=np.float64)
    quads = np.asarray(quads, dtype=np.int64)
    faces = tiles[:, TILE_FACES].reshape(-1, 4, 3)
    centroids, normals = plane_fit(faces)
    planarity = float(_plane_distances(faces, centroids, normals).max(initial=0.0))

    edges = quad_mesh_edges(quads)
    inner = edges.interior
    qa, qb = edges.quads[inner, 0], edges.quads[inner, 1]
    sa, sb = edges.sides[inner, 0], edges.sides[inner, 1]
    face_a = tiles[qa[:, None], SIDE_FACES[sa]]
    face_b = tiles[qb[:, None], SIDE_FACES[sb]]
    if len(face_a):
        ca, na = plane_fit(face_a)
        cb, nb = plane_fit(face_b)
        gap = max(
            float(_plane_distances(face_a, cb, nb).max()),
            float(_plane_distances(face_b, ca, na).max()),
        )
        cosang = np.clip(np.abs(np.einsum("ki,ki->k", na, nb)), 0.0, 1.0)
        angle = float(np.degrees(np.arccos(cosang)).max())
    else:
        gap, angle = 0.0, 0.0

    top = tiles[:, :4].reshape(-1, 3)
    sqd, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(top),
        np.ascontiguousarray(target_vertices, dtype=np.float64),
        np.ascontiguousarray(target_faces, dtype=np.int64),
    )
    dist = np.sqrt(np.maximum(sqd, 0.0))
    sides = np.linalg.norm(np.roll(tiles[:, :4], -1, axis=1) - tiles[:, :4], axis=2)

    _, face_ids, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(tiles[:, :4].mean(axis=1)),
        np.ascontiguousarray(target_vertices, dtype=np.float64),
        np.ascontiguousarray(target_faces, dtype=np.int64),
    )
    tri = np.asarray(target_vertices)[np.asarray(target_faces)[face_ids]]
    target_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])

    top_c, top_n = plane_fit(tiles[:, :4])
    outward = quad_vector_areas(
        tiles[:, :4].reshape(-1, 3), np.arange(4 * len(tiles)).reshape(-1, 4)
    )
    top_n = top_n * np.sign(np.einsum("ki,ki->k", top_n, outward))[:, None]
    thick = np.einsum("ksi,ki->ks", top_c[:, None] - tiles[:, 4:], top_n)
    flipped = int(np.sum(np.einsum("ki,ki->k", outward, target_n) < 0))
    return {
        "planarity_max_mm": planarity,
        "contact_gap_max_mm": gap,
        "contact_angle_max_deg": angle,
        "surface_distance_max_mm": float(dist.max(initial=0.0)),
        "surface_distance_mean_mm": float(dist.mean()) if dist.size else 0.0,
        "tile_side_spread": float(sides.max() / sides.min()) if sides.size else 1.0,
        "tile_side_mean_mm": float(sides.mean()) if sides.size else 0.0,
        "thickness_min_mm": float(thick.min()) if thick.size else 0.0,
        "thickness_max_mm": float(thick.max()) if thick.size else 0.0,
        "flipped_tiles": float(flipped),
    }
