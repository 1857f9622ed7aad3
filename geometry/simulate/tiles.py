"""Geometry of the simulated tiles: their edges and faces, side-face midpoints, rigid alignment,
overlap depths, the snap pairs' lengths and the contact faces' partner corners.

Tiles are ``(T, 8, 3)`` arrays in the vertex order of ``assembled.obj``: top corners 0..3, the
bottom corners 4..7 under them.
"""

from __future__ import annotations

import numpy as np

from drawstring.geometry.core.rigid import rigid_fit
from drawstring.geometry.core.tile import SIDE_FACES_INWARD, TILE_FACES_SIDES_INWARD
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "TILE_EDGES",
    "face_on_face",
    "face_partners",
    "hexahedron_overlap",
    "kabsch",
    "kabsch_deviation",
    "max_penetration",
    "mean_tile_side",
    "neighbour_tile_pairs",
    "side_face_midpoints",
    "snap_goal_length",
    "tile_edge_lengths",
    "tile_volumes",
]


#: The 18 edges of a rigid tile: top ring, bottom ring, verticals, and one diagonal per face
#: (top 0-2, bottom 5-7, sides 0-5, 2-5, 2-7, 0-7: the tetrahedron 0, 2, 5, 7).
TILE_EDGES: IntArray = np.array(
    [
        [0, 1], [1, 2], [2, 3], [3, 0],
        [4, 5], [5, 6], [6, 7], [7, 4],
        [0, 4], [1, 5], [2, 6], [3, 7],
        [0, 2], [5, 7], [0, 5], [2, 5], [2, 7], [0, 7],
    ],
    dtype=np.int64,
)  # fmt: skip


def side_face_midpoints(tiles: FloatArray) -> FloatArray:
    """Midpoints (vertex means) of the four side faces of every tile.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm

    Returns
    -------
    (T, 4, 3) float, mm
    """
    return np.asarray(tiles[:, SIDE_FACES_INWARD].mean(axis=2))


def tile_edge_lengths(tiles: FloatArray) -> FloatArray:
    """Lengths of the 18 rigid edges of every tile.

    Parameters
    ----------
    tiles : (..., T, 8, 3) float, mm

    Returns
    -------
    (..., T, 18) float, mm
    """
    diff = tiles[..., TILE_EDGES[:, 1], :] - tiles[..., TILE_EDGES[:, 0], :]
    return np.asarray(np.linalg.norm(diff, axis=-1))


def mean_tile_side(tiles: FloatArray) -> float:
    """Mean length of the top-face sides, mm."""
    top = tiles[:, :4]
    return float(np.linalg.norm(np.roll(top, -1, axis=1) - top, axis=2).mean())


def kabsch(source: FloatArray, target: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rotation ``R`` and shift ``t`` with ``R @ p + t`` closest to ``target`` (no reflection).

    Parameters
    ----------
    source, target : (n, d) float
    """
    rot, shift = rigid_fit(source[None], target[None])
    return rot[0], shift[0]


def kabsch_deviation(tiles: FloatArray, reference: FloatArray) -> FloatArray:
    """Per-tile maximum vertex distance after one rigid alignment over all vertices.

    Parameters
    ----------
    tiles, reference : (T, 8, 3) float, mm

    Returns
    -------
    (T,) float, mm
        ``max_v |R x_tv + t - ref_tv|`` with ``(R, t)`` the best rigid map of all vertices.
    """
    src = tiles.reshape(-1, 3)
    dst = reference.reshape(-1, 3)
    rot, shift = kabsch(src, dst)
    moved = src @ rot.T + shift
    return np.asarray(np.linalg.norm(moved - dst, axis=1).reshape(tiles.shape[0], 8).max(axis=1))


def _face_normals(pts: FloatArray) -> FloatArray:
    """Unit normals ``(k, 6, 3)`` of the six faces of hexahedra ``(k, 8, 3)``."""
    d1 = pts[:, TILE_FACES_SIDES_INWARD[:, 2]] - pts[:, TILE_FACES_SIDES_INWARD[:, 0]]  # (k, 6, 3)
    d2 = pts[:, TILE_FACES_SIDES_INWARD[:, 3]] - pts[:, TILE_FACES_SIDES_INWARD[:, 1]]
    n = np.empty_like(d1)
    n[..., 0] = d1[..., 1] * d2[..., 2] - d1[..., 2] * d2[..., 1]
    n[..., 1] = d1[..., 2] * d2[..., 0] - d1[..., 0] * d2[..., 2]
    n[..., 2] = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    norm = np.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2 + n[..., 2] ** 2)
    return np.asarray(n / np.maximum(norm, 1e-300)[..., None])


def hexahedron_overlap(pa: FloatArray, pb: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Overlap depth and push axis of hexahedron pairs (separating axes: the 12 face normals).

    Parameters
    ----------
    pa, pb : (k, 8, 3) float, mm
        Convex hexahedra (tiles).

    Returns
    -------
    depth : (k,) float, mm
        Smallest projection overlap over the 12 axes; ``<= 0`` when a face plane separates them.
        Without the edge-edge axes this is an upper bound of the true penetration depth.
    axis : (k, 3) float
        Unit axis of that overlap, pointing from ``pa`` towards ``pb``.
    """
    axes = np.concatenate([_face_normals(pa), _face_normals(pb)], axis=1)  # (k, 12, 3)
    axes_t = axes.transpose(0, 2, 1)
    proj_a = np.matmul(pa, axes_t)  # (k, 8, 12); reduce over the strided vertex axis (fast)
    proj_b = np.matmul(pb, axes_t)
    over_pos = proj_a.max(axis=1) - proj_b.min(axis=1)
    over_neg = proj_b.max(axis=1) - proj_a.min(axis=1)
    use_pos = over_pos <= over_neg
    overlap = np.where(use_pos, over_pos, over_neg)
    best = np.argmin(overlap, axis=1)
    k = np.arange(len(pa))
    sign = np.where(use_pos[k, best], 1.0, -1.0)
    return np.asarray(overlap[k, best]), np.asarray(axes[k, best] * sign[:, None])


def neighbour_tile_pairs(linkage: Linkage) -> IntArray:
    """Tile pairs whose grid cells share an edge or a vertex (candidate contacts).

    Returns
    -------
    (k, 2) int, ``a < b``.
    """
    cells = linkage.tile_cells
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(cells)}
    pairs = []
    for t, (i, j) in enumerate(cells):
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
            other = index.get((int(i) + di, int(j) + dj))
            if other is not None:
                pairs.append((min(t, other), max(t, other)))
    return np.array(sorted(set(pairs)), dtype=np.int64).reshape(-1, 2)


def max_penetration(tiles: FloatArray, pairs: IntArray) -> float:
    """Largest conservative overlap depth (mm) over the given tile pairs (0 when none overlap).

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    pairs : (k, 2) int
    """
    if len(pairs) == 0:
        return 0.0
    depth, _ = hexahedron_overlap(tiles[pairs[:, 0]], tiles[pairs[:, 1]])
    return float(max(depth.max(), 0.0))


def snap_goal_length(tiles: FloatArray, pairs: IntArray) -> FloatArray:
    """Distance between the paired side-face midpoints of every snap pair.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    pairs : (P, 4) int

    Returns
    -------
    (P,) float, mm (zero in the assembled state for faces that touch there).
    """
    mids = side_face_midpoints(tiles)
    return np.asarray(
        np.linalg.norm(mids[pairs[:, 2], pairs[:, 3]] - mids[pairs[:, 0], pairs[:, 1]], axis=1)
    )


def face_partners(goal: FloatArray, pairs: IntArray) -> IntArray:
    """For each snap pair, the corner of face b nearest (in T3D) to each corner of face a.

    Returns
    -------
    (P, 4) int, indices into ``SIDE_FACES_INWARD[side_b]``.
    """
    fa = goal[pairs[:, 0, None], SIDE_FACES_INWARD[pairs[:, 1]]]  # (P, 4, 3)
    fb = goal[pairs[:, 2, None], SIDE_FACES_INWARD[pairs[:, 3]]]
    dist = np.linalg.norm(fa[:, :, None] - fb[:, None, :], axis=3)
    return np.asarray(np.argmin(dist, axis=2), dtype=np.int64)


def face_on_face(tiles: FloatArray, pairs: IntArray, partner: IntArray, limit: float) -> BoolArray:
    """Which face pairs lie face on face: every corner within ``limit`` of its partner corner.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    pairs : (k, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    partner : (k, 4) int, partner corner in face b of every corner of face a
        (:func:`face_partners` of the assembled tiles).
    limit : float, mm.

    Returns
    -------
    (k,) bool
    """
    fa = tiles[pairs[:, 0, None], SIDE_FACES_INWARD[pairs[:, 1]]]  # (k, 4, 3)
    fb = np.take_along_axis(
        tiles[pairs[:, 2, None], SIDE_FACES_INWARD[pairs[:, 3]]], partner[..., None], 1
    )
    return np.asarray(np.linalg.norm(fa - fb, axis=2).max(axis=1) < limit, dtype=bool)


def tile_volumes(tiles: FloatArray) -> FloatArray:
    """Volumes ``(T,)`` of the hexahedral tiles (six tetrahedra around the 0-6 diagonal), mm^3."""
    tets = np.array(
        [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    )
    p = tiles[:, tets]  # (T, 6, 4, 3)
    vol = np.einsum(
        "tki,tki->tk",
        p[:, :, 1] - p[:, :, 0],
        np.cross(p[:, :, 2] - p[:, :, 0], p[:, :, 3] - p[:, :, 0]),
    )
    return np.asarray(np.abs(vol.sum(axis=1)) / 6.0)
