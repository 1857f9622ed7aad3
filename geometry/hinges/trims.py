"""Where two flat tiles overlap in the flat pose, the trim that removes the overlap from one of
them (the ``top`` hinge strategy, and ``dual`` pairs laid out on their hinge face only; paper
section 4.4).

The overlap of two convex pieces is computed exactly (convex hulls intersected with manifold3d)
and recorded, grown by a small cube, as a trim of the tile with the larger id, with the side-face
(contact) area it takes away.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.core.tolerances import HINGE_TRIM_GROW_MM
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flat.polygons import convex_pieces, polygon_in_convex_polyhedron_area
from drawstring.geometry.solve.constraints import convex_overlap_mtv
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "HingeTrim",
    "hinge_trims",
    "pair_count",
    "pair_trims",
    "unhinged_close_pairs",
]


@dataclass(frozen=True)
class HingeTrim:
    """Overlap of two tiles in the flat pose, removed from ``tile``.

    Attributes
    ----------
    hinge : int
        The hinge joining the two tiles, or -1 for an unhinged pair (``top`` strategy).
    tile : int
        The tile trimmed (the larger id of the pair).
    other : int
        The tile it overlapped.
    vertices : (p, 3) float, mm
        Points whose hull is the convex overlap polyhedron grown by a cube of half-side
        ``HINGE_TRIM_GROW_MM`` (CAD subtracts their hull; the growth leaves no numerical sliver
        and gives needle-thin overlaps a thickness a B-rep cut can take).
    volume_mm3 : float
    contact_area_lost_mm2 : float
        Area of the trimmed tile's side faces inside the overlap.
    """

    hinge: int
    tile: int
    vertices: FloatArray
    volume_mm3: float
    contact_area_lost_mm2: float
    other: int


#: Corners of the cube a trim is grown by.
_TRIM_GROWTH = HINGE_TRIM_GROW_MM * np.array(
    [[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)]
)


def hinge_trims(
    linkage: Linkage, tiles_2d: ArrayLike, hinges: ArrayLike | None = None
) -> tuple[HingeTrim, ...]:
    """Exact overlap of hinged tile pairs in the flat pose.

    Parameters
    ----------
    linkage : Linkage
    tiles_2d : (T, 8, 3) float, mm
    hinges : (k,) int, optional
        The hinges to check (default all).

    Returns
    -------
    tuple of HingeTrim
        Only hinges whose tiles overlap with positive volume.
    """
    which = np.arange(linkage.n_hinges) if hinges is None else np.asarray(hinges, dtype=np.int64)
    pairs = linkage.hinges[which][:, [0, 2]]
    return pair_trims(tiles_2d, pairs, which)


def pair_trims(
    tiles_2d: ArrayLike, pairs: ArrayLike, hinges: ArrayLike | None = None
) -> tuple[HingeTrim, ...]:
    """Exact overlap of tile pairs ``(k, 2)`` in the flat pose, each to be removed from the
    pair's larger tile id; ``hinges`` names the hinge of each pair (default -1: unhinged).
    Only pairs that overlap with positive volume are returned."""
    import manifold3d as m3d

    tiles = np.asarray(tiles_2d, dtype=np.float64)
    # a dart-shaped tile is the union of its convex pieces; its hull would fill the notch where
    # a neighbour may sit, so overlaps are taken piece by piece (one trim per overlapping pair
    # of pieces, as verify.interpenetration measures them)
    pieces = convex_pieces(tiles)
    pair_arr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    labels = (
        np.full(len(pair_arr), -1, dtype=np.int64)
        if hinges is None
        else np.asarray(hinges, dtype=np.int64)
    )
    trims: list[HingeTrim] = []
    for (a, b), index in zip(pair_arr.tolist(), labels.tolist(), strict=True):
        for mask_a in pieces[a][pieces[a].any(axis=1)]:
            for mask_b in pieces[b][pieces[b].any(axis=1)]:
                overlap = m3d.Manifold.hull_points(tiles[a][mask_a]) ^ m3d.Manifold.hull_points(
                    tiles[b][mask_b]
                )
                trim = _trim_of(overlap, tiles, a, b, index)
                if trim is not None:
                    trims.append(trim)
    return tuple(trims)


def _trim_of(overlap: Any, tiles: FloatArray, a: int, b: int, index: int) -> HingeTrim | None:
    """The trim of tiles ``a`` and ``b`` for one convex ``overlap`` (a manifold3d solid), or
    None when it has no volume."""
    volume = float(overlap.volume())
    if volume <= 0:
        return None
    mesh = overlap.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    p0, p1, p2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    keep = np.linalg.norm(normals, axis=1) > 0
    normals = normals[keep] / np.linalg.norm(normals[keep], axis=1, keepdims=True)
    points = p0[keep]
    # one clipping plane per face of the overlap, not per triangle of its mesh (the
    # triangles of one face give the same plane to round-off; a plane kept twice only
    # costs time, so rounding that splits a pair is harmless)
    key = np.round(np.c_[normals, np.einsum("ki,ki->k", normals, points)], 9)
    first = np.sort(np.unique(key, axis=0, return_index=True)[1])
    trimmed, other = max(a, b), min(a, b)
    lost = sum(
        polygon_in_convex_polyhedron_area(tiles[trimmed][face], points[first], normals[first])
        for face in TILE_FACES[2:]
    )
    # Record the trim grown by a small cube (Minkowski sum) so that subtracting it leaves no
    # numerical sliver, and so that a needle-thin overlap becomes a tool a B-rep cut can take.
    grown = (verts[:, None, :] + _TRIM_GROWTH[None]).reshape(-1, 3)
    return HingeTrim(index, trimmed, grown, volume, float(lost), other)


def pair_count(trims: tuple[HingeTrim, ...]) -> int:
    """Tile pairs among ``trims`` (a dart-shaped tile's pieces may give a pair several)."""
    return len({(tr.other, tr.tile) for tr in trims})


def unhinged_close_pairs(linkage: Linkage, tiles: FloatArray) -> IntArray:
    """Unhinged tile pairs ``(k, 2)`` of one part whose whole flat tiles, seen from above,
    come closer than a thousandth of a millimetre (candidates for a 3D overlap)."""
    outline = tiles[:, :, :2]
    centres = outline.mean(axis=1)
    radius = float(np.max(np.linalg.norm(outline - centres[:, None], axis=2), initial=0.0))
    pairs = cKDTree(centres).query_pairs(2.0 * radius + 1e-9, output_type="ndarray")
    pairs = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
    hinged = set(map(tuple, np.sort(linkage.hinges[:, [0, 2]], axis=1).tolist()))
    comp = linkage.tile_component
    keep = [
        k for k, (a, b) in enumerate(pairs.tolist()) if (a, b) not in hinged and comp[a] == comp[b]
    ]
    pairs = pairs[keep]
    if not len(pairs):
        return pairs
    depth, _ = convex_overlap_mtv(outline[pairs[:, 0]], outline[pairs[:, 1]])
    return pairs[depth > -1e-3]
