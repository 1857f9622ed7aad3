"""Independent measurements of the flat layout and the hinged tiles.

Everything here is measured on output geometry (tile corners, tile vertices), never taken from an
optimizer.  Each measurement names the tolerance it is compared to (``core.tolerances``):

=============================  =====================================  ==========================
measurement                    what                                   tolerance
=============================  =====================================  ==========================
flat_overlap_area_mm2          sum of exact pairwise footprint        FLAT_OVERLAP_TOL_MM2
                               overlap areas (convex clipping;
                               dart-shaped quads as two triangles)
interpenetration_volume_mm3    sum of exact pairwise 3D intersection  FLAT_INTERPENETRATION_TOL_MM3
                               volumes of tiles (manifold3d; a
                               non-convex tile as its convex pieces)
flat_edge_error_max_mm         max |len K2D - len K3D| over sides     FLAT_EDGE_ERROR_TOL_MM
                               and diagonals
flat_gap_angle_min/max_deg     opening angle at every slit end        [theta_min, 90] +-
                                                                      FLAT_GAP_ANGLE_TOL_DEG
hinge_gap_max_mm               max distance of paired hinge vertices  HINGE_GAP_TOL_MM
assembled_overlap_volume_mm3   sum of exact pairwise 3D intersection  (pairs deeper than the
                               volumes of assembled tiles T3D         depth tolerance)
                               (neighbours and nearby tiles)
assembled_overlap_depth_max    largest penetration depth of those     ASSEMBLED_OVERLAP_DEPTH_
_mm                            pairs (separating-axis test)           TOL_MM (here)
assembled_nonconvex_top/       tiles whose top / bottom face is not   0
bottom_faces                   convex in its own plane
=============================  =====================================  ==========================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.polygons import (
    convex_penetration_depth,
    convex_pieces,
    convex_polygon_overlap,
    reflex_corners,
)
from drawstring.geometry.solve.constraints import quad_overlap_mtv
from drawstring.geometry.tiling.linkage import Linkage, slit_ends

#: The 18 rigidity edges of a tile (3 * 8 - 6, Maxwell): 4 top, 4 bottom, 4 vertical edges and
#: one diagonal on each of the 6 faces.
RIGID_EDGES: IntArray = np.array(
    [
        [0, 1], [1, 2], [2, 3], [3, 0],
        [4, 5], [5, 6], [6, 7], [7, 4],
        [0, 4], [1, 5], [2, 6], [3, 7],
        [0, 2], [4, 6], [0, 5], [1, 6], [2, 7], [3, 4],
    ],
    dtype=np.int64,
)  # fmt: skip

__all__ = [
    "RIGID_EDGES",
    "AssembledOverlap",
    "FlatMetrics",
    "assembled_overlap",
    "flat_edge_errors",
    "flat_overlap",
    "gap_opening_angles_deg",
    "heightfield_tiles",
    "hinge_gaps",
    "interpenetration",
]


def _candidate_pairs(centres: FloatArray, radius: float) -> IntArray:
    tree = cKDTree(centres)
    return np.asarray(tree.query_pairs(2.0 * radius * (1 + 1e-9), output_type="ndarray"))


def flat_overlap(footprints: ArrayLike) -> tuple[float, IntArray, FloatArray]:
    """Exact pairwise overlap area of tile footprints.

    Quads may be non-convex (dart-shaped): those are measured as their two convex triangles.

    Broad phase: pairs whose centres are within twice the largest circumradius (k-d tree);
    separating-axis test (exact for convex polygons) drops separated pairs; the rest are clipped
    exactly.  Tiles hinged together touch at a point and contribute (numerically) zero.

    Parameters
    ----------
    footprints : (T, k, 2) float, mm
        Tile outlines (K2D top faces: k = 4); other k must be convex.

    Returns
    -------
    total : float, mm^2
        Compare with ``FLAT_OVERLAP_TOL_MM2``.
    pairs : (P, 2) int
        Pairs with positive overlap area.
    areas : (P,) float, mm^2
    """
    poly = np.asarray(footprints, dtype=np.float64)
    centres = poly.mean(axis=1)
    radius = float(np.max(np.linalg.norm(poly - centres[:, None], axis=2), initial=0.0))
    cand = _candidate_pairs(centres, radius)
    if len(cand) == 0:
        return 0.0, np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    if poly.shape[1] == 4:
        depth, _ = quad_overlap_mtv(poly[cand[:, 0]], poly[cand[:, 1]])
        cand = cand[depth > 0]
        reflex = reflex_corners(poly)
    else:
        reflex = np.full(len(poly), -1, dtype=np.int64)

    def pieces(i: int) -> list[FloatArray]:
        k = int(reflex[i])
        if k < 0:
            return [poly[i]]
        return [poly[i][[k, (k + 1) % 4, (k + 2) % 4]], poly[i][[k, (k + 2) % 4, (k + 3) % 4]]]

    # A dart-shaped (non-convex) quad is clipped as its two convex triangles; they do not overlap
    # each other, so the summed piece overlaps are the exact overlap area.
    areas = np.array(
        [
            sum(convex_polygon_overlap(p, q) for p in pieces(int(i)) for q in pieces(int(j)))
            for i, j in cand
        ]
    )
    hit = areas > 0
    return float(areas.sum()), cand[hit].astype(np.int64), areas[hit]


def _hull_separated(tiles: FloatArray, pairs: IntArray) -> BoolArray:
    """Pairs of 8-vertex tiles separated along some face normal of either tile (conservative)."""
    a, b = tiles[pairs[:, 0]], tiles[pairs[:, 1]]

    def face_normals(t: FloatArray) -> FloatArray:
        f = t[:, TILE_FACES]  # (k, 6, 4, 3)
        n = np.cross(f[:, :, 2] - f[:, :, 0], f[:, :, 3] - f[:, :, 1])
        return np.asarray(n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300))

    axes = np.concatenate([face_normals(a), face_normals(b)], axis=1)  # (k, 12, 3)
    pa = np.einsum("kai,kvi->kav", axes, a)
    pb = np.einsum("kai,kvi->kav", axes, b)
    gap = np.maximum(pb.min(axis=2) - pa.max(axis=2), pa.min(axis=2) - pb.max(axis=2))
    return np.asarray(np.any(gap >= 0, axis=1))


def interpenetration(
    tiles: ArrayLike,
    trims: Sequence[tuple[int, ArrayLike]] | None = None,
    *,
    in_plane: bool = False,
) -> tuple[float, IntArray, FloatArray]:
    """Exact pairwise intersection volume of tiles (manifold3d).

    A convex tile is the hull of its 8 vertices; a non-convex one (dart-shaped top face) the
    union of the hulls of its :func:`convex_pieces`.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    trims : sequence of (tile, (k, 3) float), optional
        Convex polyhedra (vertex sets, mm) removed from a tile before measuring (``top`` hinge
        strategy: the overlap with a hinged neighbour that CAD subtracts); a tile may be listed
        several times.
    in_plane : bool
        Find non-convex tiles in their top face's own plane (assembled tiles) instead of in
        (x, y) (flat tiles); see :func:`convex_pieces`.

    Returns
    -------
    total : float, mm^3
        Compare with ``FLAT_INTERPENETRATION_TOL_MM3``.
    pairs : (P, 2) int
        Pairs with positive volume.
    volumes : (P,) float, mm^3
    """
    import manifold3d as m3d

    t = np.asarray(tiles, dtype=np.float64)
    centres = t.mean(axis=1)
    radius = float(np.max(np.linalg.norm(t - centres[:, None], axis=2), initial=0.0))
    cand = _candidate_pairs(centres, radius)
    if len(cand) == 0:
        return 0.0, np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    cand = cand[~_hull_separated(t, cand)]
    hulls: dict[int, object] = {}
    removed: dict[int, list[FloatArray]] = {}
    for tile, points in trims or ():
        removed.setdefault(int(tile), []).append(np.asarray(points, dtype=np.float64))

    pieces = convex_pieces(t, in_plane=in_plane)

    def hull(i: int) -> m3d.Manifold:
        if i not in hulls:
            solid = m3d.Manifold.hull_points(t[i][pieces[i, 0]])
            if pieces[i, 1].any():  # non-convex tile: the union of its two convex pieces
                solid = solid + m3d.Manifold.hull_points(t[i][pieces[i, 1]])
            for points in removed.get(i, ()):
                solid = solid - m3d.Manifold.hull_points(points)
            hulls[i] = solid
        return hulls[i]

    vols = np.array([(hull(int(i)) ^ hull(int(j))).volume() for i, j in cand])
    hit = vols > 0
    return float(vols.sum()), cand[hit].astype(np.int64), vols[hit]


def flat_edge_errors(corners_2d: ArrayLike, top_3d: ArrayLike) -> FloatArray:
    """|length K2D - length K3D| of every tile's 4 sides and 2 diagonals.

    Parameters
    ----------
    corners_2d : (T, 4, 2) or (T, 4, 3) float, mm
    top_3d : (T, 4, 3) float, mm

    Returns
    -------
    (T, 6) float, mm
        Max compared with ``FLAT_EDGE_ERROR_TOL_MM``.
    """
    pairs = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [1, 3]])
    c2 = np.asarray(corners_2d, dtype=np.float64)
    c3 = np.asarray(top_3d, dtype=np.float64)
    l2 = np.linalg.norm(c2[:, pairs[:, 1]] - c2[:, pairs[:, 0]], axis=2)
    l3 = np.linalg.norm(c3[:, pairs[:, 1]] - c3[:, pairs[:, 0]], axis=2)
    return np.asarray(np.abs(l2 - l3))


def gap_opening_angles_deg(
    linkage: Linkage,
    corners_2d: ArrayLike,
    bottom: ArrayLike | None = None,
) -> FloatArray:
    """Opening angle at every slit end, measured on tile corners.

    At a slit end two gap sides meet at a hinge: the angle is measured from the corners of the
    two tiles themselves (each arm from its own tile's hinge corner), counter-clockwise inside the
    void; negative means the gap is inverted.  The angle depends only on the directions of the
    two sides, i.e. on the two tiles' rotations.

    Which face to measure: the gap opens about its hinge, so its opening is the wedge between
    the two sides *of the face that carries the hinge* (a bottom hinge joins bottom corners; the
    top sides of a bottom-hinged pair do not meet and are generally not parallel to the bottom
    sides, so their angle differs by a fixed per-pair amount).  Pass whole tiles and ``bottom``
    to measure every slit end on its hinge's face; with top corners only (or ``bottom`` omitted)
    every angle is measured on the top faces.

    Parameters
    ----------
    linkage : Linkage
    corners_2d : (T, 4, 2+) or (T, 8, 2+) float, mm
        Top corners, or whole tiles (top corners 0..3, bottom 4..7); only x, y are used.
    bottom : (H,) bool, optional
        Hinge side per hinge of ``linkage.hinges`` (True: bottom); needs whole tiles.

    Returns
    -------
    (E,) float, deg
        Compared with ``[theta_min, 90]`` up to ``FLAT_GAP_ANGLE_TOL_DEG``.
    """
    c = np.asarray(corners_2d, dtype=np.float64)[..., :2]
    offset = np.zeros((linkage.n_tiles, 4), dtype=np.int64)
    if bottom is not None:
        if c.shape[1] != 8:
            raise ValueError("measuring on the hinge faces needs whole (T, 8, 3) tiles")
        h = linkage.hinges
        b = np.asarray(bottom, dtype=bool)
        offset[h[:, 0], h[:, 1]] = np.where(b, 4, 0)
        offset[h[:, 2], h[:, 3]] = np.where(b, 4, 0)
    ends = slit_ends(linkage)
    if not len(ends.hinge):
        return np.zeros(0)
    face = offset[ends.tiles[:, 0], ends.sides[:, 0]]
    return np.asarray(np.degrees(ends.angles(c, face)))


def hinge_gaps(tiles: ArrayLike, hinge_vertices: ArrayLike, in_plane: bool = False) -> FloatArray:
    """Distance between the two vertices of every hinge.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    hinge_vertices : (H, 2) int
        Flat vertex ids ``8 * tile + vertex`` of both sides of each hinge.
    in_plane : bool
        Measure the horizontal (x, y) part only: in a flat layout whose tiles differ in
        thickness, the vertical part at a hinge on the face that does not rest at a common
        height is the two tiles' thickness difference, which no layout in the plane changes.

    Returns
    -------
    (H,) float, mm
        Max compared with ``HINGE_GAP_TOL_MM``.
    """
    flat = np.asarray(tiles, dtype=np.float64).reshape(-1, 3)
    hv = np.asarray(hinge_vertices, dtype=np.int64).reshape(-1, 2)
    d = flat[hv[:, 0]] - flat[hv[:, 1]]
    return np.asarray(np.linalg.norm(d[:, :2] if in_plane else d, axis=1))


@dataclass(frozen=True)
class FlatMetrics:
    """Summary numbers for design.json (see the table in the module docstring)."""

    flat_overlap_area_mm2: float
    flat_interpenetration_mm3: float
    flat_edge_error_max_mm: float
    flat_gap_angle_min_deg: float
    flat_gap_angle_max_deg: float
    hinge_gap_max_mm: float | None = None
    hinge_lost_contact_area_mm2: float | None = None

    def to_json(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items() if v is not None}


def heightfield_tiles(
    uv: ArrayLike,
    quads: ArrayLike,
    surface: str,
    thickness: float,
    parameter: float,
) -> tuple[FloatArray, FloatArray]:
    """Test and benchmark fixture: T3D tiles of a grid lifted onto an analytic surface.

    Top = lifted grid vertices, bottom = top offset by ``-thickness`` along the exact surface
    normal (upward), shared between neighbours.

    Parameters
    ----------
    uv : (n, 2) float, mm, grid positions.
    quads : (T, 4) int, tile corners.
    surface : ``"plane" | "cylinder" | "cylinder_inside" | "saddle" | "dome"``
        Cylinders are wrapped isometrically (``uv`` x is arc length) around the y axis of radius
        ``parameter``; ``cylinder`` is seen from outside (convex side up), ``cylinder_inside``
        from inside.  ``saddle`` is ``z = p (x^2 - y^2)``, ``dome`` ``z = -p (x^2 + y^2)``.
    thickness : float, mm
    parameter : float

    Returns
    -------
    top : (T, 4, 3) float, mm
    tiles : (T, 8, 3) float, mm
    """
    uv_arr = np.asarray(uv, dtype=np.float64)
    x, y = uv_arr[:, 0], uv_arr[:, 1]
    if surface in ("cylinder", "cylinder_inside"):
        r = parameter
        ang = x / r
        if surface == "cylinder":
            pts = np.stack([r * np.sin(ang), y, r * np.cos(ang) - r], axis=1)
            nrm = np.stack([np.sin(ang), 0 * y, np.cos(ang)], axis=1)
        else:
            pts = np.stack([r * np.sin(ang), y, r - r * np.cos(ang)], axis=1)
            nrm = np.stack([-np.sin(ang), 0 * y, np.cos(ang)], axis=1)
    else:
        if surface == "plane":
            z, zx, zy = 0 * x, 0 * x, 0 * x
        elif surface == "saddle":
            z, zx, zy = parameter * (x**2 - y**2), 2 * parameter * x, -2 * parameter * y
        elif surface == "dome":
            z, zx, zy = -parameter * (x**2 + y**2), -2 * parameter * x, -2 * parameter * y
        else:
            raise ValueError(f"unknown surface {surface!r}")
        pts = np.stack([x, y, z], axis=1)
        nrm = np.stack([-zx, -zy, np.ones_like(x)], axis=1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    bottom = pts - thickness * nrm
    q = np.asarray(quads, dtype=np.int64)
    return pts[q], np.concatenate([pts[q], bottom[q]], axis=1)


# --------------------------------------------------------------------------------------------
# Assembled state (T3D): interpenetration of tiles and non-convex faces
# --------------------------------------------------------------------------------------------


#: Assembled tiles: penetration depth (mm) at or below which two tiles count as touching.
ASSEMBLED_OVERLAP_DEPTH_TOL_MM = 1e-3


@dataclass(frozen=True)
class AssembledOverlap:
    """Interpenetration and convexity of assembled tiles (T3D), measured on the tiles alone.

    Attributes
    ----------
    volume_mm3 : float
        Sum of the exact intersection volumes of the listed pairs (manifold3d, as
        :func:`interpenetration`; a non-convex tile is the union of its convex pieces, not its
        hull).  Neighbours that only share a contact face give 0.
    depth_max_mm : float
        Largest penetration depth (shortest separating translation of two tiles' convex
        pieces, :func:`convex_penetration_depth`; max over piece pairs).  0 is right.
    pairs : (P, 2) int
        Tile pairs whose depth exceeds ``depth_tol_mm``.
    volumes, depths : (P,) float, mm^3 and mm
    neighbours : (P,) bool
        The pair shares a tile corner in ``linkage`` (all False when no linkage was given).
    nonconvex_top, nonconvex_bottom : (k,) int
        Tiles whose top (bottom) face is not convex in its own plane (a dart or folded quad).
    """

    volume_mm3: float
    depth_max_mm: float
    pairs: IntArray
    volumes: FloatArray
    depths: FloatArray
    neighbours: BoolArray
    nonconvex_top: IntArray
    nonconvex_bottom: IntArray

    @property
    def nonconvex_faces(self) -> int:
        """Number of non-convex top plus bottom faces (0 is right)."""
        return int(len(self.nonconvex_top) + len(self.nonconvex_bottom))

    def to_json(self) -> dict[str, float | int]:
        """``assembled_overlap_volume_mm3``, ``assembled_overlap_depth_max_mm``,
        ``assembled_overlap_pairs``, ``assembled_nonconvex_top_faces``,
        ``assembled_nonconvex_bottom_faces``."""
        return {
            "assembled_overlap_volume_mm3": float(self.volume_mm3),
            "assembled_overlap_depth_max_mm": float(self.depth_max_mm),
            "assembled_overlap_pairs": int(len(self.pairs)),
            "assembled_nonconvex_top_faces": int(len(self.nonconvex_top)),
            "assembled_nonconvex_bottom_faces": int(len(self.nonconvex_bottom)),
        }


def assembled_overlap(
    tiles: ArrayLike,
    linkage: Linkage | None = None,
    *,
    depth_tol_mm: float = ASSEMBLED_OVERLAP_DEPTH_TOL_MM,
) -> AssembledOverlap:
    """Interpenetration between assembled tiles (neighbours and any other nearby tile).

    Independent of the optimizer: every pair of tiles closer than twice the largest tile
    circumradius is tested (k-d tree, then a separating-axis cull, then an exact manifold3d
    intersection), whether or not the tiles are neighbours in the linkage.  In the assembled
    state neighbours share whole contact faces, so any positive volume is a physical clash.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
        T3D tiles: top corners 0..3, bottom corners 4..7 under them (faces planar).
    linkage : Linkage, optional
        Only used to flag which overlapping pairs are neighbours (share a tile corner).
    depth_tol_mm : float
        Pairs whose penetration depth is at or below this are not listed (touching neighbours
        whose shared faces are planar only to ~1e-6 mm give volumes of ~1e-3 mm^3 at depths of
        ~1e-5 mm).

    Returns
    -------
    AssembledOverlap
    """
    t = np.asarray(tiles, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (8, 3):
        raise InternalError(f"assembled tiles must have shape (T, 8, 3), got {t.shape}")
    nonconvex_top = np.flatnonzero(reflex_corners(t[:, :4], in_plane=True) >= 0)
    nonconvex_bottom = np.flatnonzero(reflex_corners(t[:, 4:], in_plane=True) >= 0)
    _, cand, vols = interpenetration(t, in_plane=True)  # pairs with a positive volume only
    pieces = convex_pieces(t, in_plane=True)

    def piece_sets(i: int) -> list[FloatArray]:
        return [t[i][pieces[i, p]] for p in range(2) if pieces[i, p].any()]

    depths = np.array(
        [
            max(
                convex_penetration_depth(a, b)
                for a in piece_sets(int(i))
                for b in piece_sets(int(j))
            )
            for i, j in cand
        ]
    ).reshape(-1)
    keep = depths > depth_tol_mm
    pairs = cand[keep].astype(np.int64).reshape(-1, 2)
    volumes, depths = vols[keep], depths[keep]
    if linkage is not None and len(pairs):
        corners = np.asarray(linkage.tile_corners)
        neighbours = np.array(
            [bool(np.intersect1d(corners[i], corners[j]).size) for i, j in pairs], dtype=bool
        )
    else:
        neighbours = np.zeros(len(pairs), dtype=bool)
    return AssembledOverlap(
        volume_mm3=float(volumes.sum()),
        depth_max_mm=float(depths.max(initial=0.0)),
        pairs=pairs,
        volumes=volumes,
        depths=depths.reshape(-1),
        neighbours=neighbours,
        nonconvex_top=nonconvex_top.astype(np.int64),
        nonconvex_bottom=nonconvex_bottom.astype(np.int64),
    )
