"""Hinge placement on the flat tiles T2D (paper section 4.4).

Hinge side
----------
Every tile corner has a top vertex ``P`` and the bottom vertex ``Q`` under it; in T3D the four
tiles around a grid vertex share ``P`` and ``Q`` (contact faces are shared).  Flattening keeps
each tile rigid, and a hinge lets its two tiles turn about the vertical axis through the hinged
corner only, so whether they collide in the flat pose depends on the opening at the hinge alone.
For each hinge and each face we compute the openings at which the two flat tiles clear each
other (:func:`~drawstring.geometry.flatpose.free_openings`, exact separating planes through the
hinge) and place the hinge on the face where they clear within the gap-angle bounds, at the
smaller opening; where they clear on neither face, on the top, and the overlap of that pair is
trimmed as in the ``top`` strategy.  A tie (both clear from the smallest openings, e.g. a flat
target) is broken by the overhang across the pair's shared side: for tile ``a`` at hinge
corner ``c`` let ``d = Q - P`` projected on ``a``'s top plane and ``m`` the inward unit normal
(in that plane) of ``a``'s top side facing its partner; the *bottom overhang* is
``max(0, -d.m)``, how far the bottom corner pokes across that side, and the *top overhang* the
same with roles swapped.  The hinge goes to the bottom when the summed bottom overhang of both
tiles exceeds the summed top overhang (by more than ``HINGE_SIDE_TOL_REL`` times the
thickness), otherwise to the top.

This is the paper's criterion made measurable: across the shared contact face the bottoms
overhang where the target's normal curvature in that direction is negative (concave seen from
the top), and overhanging bottoms of a top-hinged pair would collide.  Outside of a cylinder:
all top; inside of a cylinder: bottoms overhang along the curved direction, bottom hinges there.
On doubly curved targets a corner can overhang one way across the shared side and the other way
into the void beside it; the clearance test decides those correctly where a per-corner overhang
sum would not.

Strategies
----------
``top``: all hinges at the top.  The region where two hinged tiles overlap in the flat pose is
computed exactly (convex hulls intersected with manifold3d); it is to be removed from the tile
with the larger id, and the side-face (contact) area it takes away is reported.
``dual``: sides as above (decided once, on the eq.-1 tiles, and passed through the flat layout,
which makes the hinge points meet), then the rigid-tile layout ``w_rigid E_rigid +
w_collision E_collision + w_conn E_conn`` (tiles exactly rigid; separating planes between close
pairs, through the hinge for hinged ones; paired hinge vertices to their midpoint), then every
hinge pair is merged into one vertex.  A pair that, on the final tiles, collides on its hinge
face at every opening within the gap-angle bounds is laid out as a ``top`` pair is (separated on
the hinge face only) and its overlap trimmed; without that, the layout would have to hold it
apart and its hinge would not meet.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from drawstring.geometry.errors import InputError
from drawstring.geometry.flat import FlatResult
from drawstring.geometry.flatpose import HingeFaces, free_openings, hinge_faces, lay_flat
from drawstring.geometry.linkage import Linkage, SlitEnds, slit_ends
from drawstring.geometry.tolerances import (
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_GAP_TOL_MM,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_FEASIBLE_MM,
    HINGE_LAYOUT_TOUCH_MM,
    HINGE_TRIM_GROW_MM,
)
from drawstring.geometry.verify import (
    TILE_FACES,
    convex_pieces,
    hinge_gaps,
    polygon_in_convex_polyhedron_area,
)

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
HingeStrategy = Literal["dual", "top"]
HingeSide = Literal["top", "bottom"]

#: Where both faces clear at openings within this of each other, the overhangs decide.
HINGE_SIDE_TOL_DEG = 0.05
#: A hinge goes to the bottom by overhang only when the bottom overhang exceeds the top overhang
#: by more than this fraction of the tile thickness (ties, e.g. flat targets, stay on top).
HINGE_SIDE_TOL_REL = 1e-9

__all__ = [
    "HingeLayout",
    "HingeTrim",
    "dual_hinge_faces",
    "draw_flat",
    "hinge_overhangs",
    "hinge_sides",
    "hinge_vertex_json",
    "layout_hinges",
    "rigid_layout",
    "RigidLayoutResult",
    "SlitEnds",
    "slit_ends",
    "hinge_trims",
    "write_flat_obj",
]


def _corner_overhang(
    tiles: FloatArray, tile: IntArray, corner: IntArray, side: IntArray
) -> tuple[FloatArray, ...]:
    """Bottom and top overhang ``(k,)`` of tile corners across one of their sides ``side``
    (side ``s`` joins corners ``s`` and ``s + 1``; see the module docstring)."""
    t = tiles[tile]  # (k, 8, 3)
    top, bottom = t[:, :4], t[:, 4:]
    normal = np.cross(top[:, 2] - top[:, 0], top[:, 3] - top[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    k = np.arange(len(tile))

    def overhang(face: FloatArray, other: FloatArray) -> FloatArray:
        p = face[k, corner]
        d = other[k, corner] - p
        d -= np.einsum("ki,ki->k", d, normal)[:, None] * normal
        edge = face[k, (side + 1) % 4] - face[k, side]
        inward = np.cross(normal, edge)
        inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-300)
        return np.asarray(np.maximum(0.0, -np.einsum("ki,ki->k", d, inward)))

    return overhang(top, bottom), overhang(bottom, top)


def _shared_sides(linkage: Linkage) -> IntArray:
    """Side ``(H, 2)`` of each hinged tile that faces its partner across the hinge's slit (in
    T3D the two tiles' contact faces on these sides coincide)."""
    ends = slit_ends(linkage)
    h = linkage.hinges
    out = np.zeros((linkage.n_hinges, 2), dtype=np.int64)
    # without a slit end (not expected) fall back to the side leaving the corner
    out[:, 0], out[:, 1] = h[:, 1], h[:, 3]
    for col in range(2):
        tile = ends.tiles[:, col]
        first = h[ends.hinge, 0] == tile
        out[ends.hinge[first], 0] = ends.sides[first, col]
        out[ends.hinge[~first], 1] = ends.sides[~first, col]
    return out


def hinge_overhangs(linkage: Linkage, tiles_3d: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Summed bottom and top overhang ``(H,)`` of both tiles of every hinge across their shared
    side, mm (T3D)."""
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    h = linkage.hinges
    shared = _shared_sides(linkage)
    bot_a, top_a = _corner_overhang(tiles, h[:, 0], h[:, 1], shared[:, 0])
    bot_b, top_b = _corner_overhang(tiles, h[:, 2], h[:, 3], shared[:, 1])
    return bot_a + bot_b, top_a + top_b


def hinge_sides(
    linkage: Linkage, tiles_3d: ArrayLike, min_gap_angle_deg: float = 0.0
) -> NDArray[np.bool_]:
    """Whether each hinge goes to the bottom: ``dual_hinge_faces(...).bottom``.

    Parameters
    ----------
    linkage : Linkage
    tiles_3d : (T, 8, 3) float, mm
        T3D tiles.
    min_gap_angle_deg : float, deg
        ``theta_min`` of the flat layout.

    Returns
    -------
    (H,) bool
        True: bottom hinge; False: top hinge.
    """
    return dual_hinge_faces(linkage, tiles_3d, min_gap_angle_deg).bottom


def dual_hinge_faces(
    linkage: Linkage, tiles_3d: ArrayLike, min_gap_angle_deg: float = 0.0
) -> HingeFaces:
    """Each hinge's face (criterion in the module docstring) and its pair's clear openings.

    Every pair is laid flat and tested on both faces: the openings at which the two tiles
    clear each other (:func:`~drawstring.geometry.flatpose.free_openings`), within the gap-angle
    bounds ``[min_gap_angle_deg, 90]``.  The hinge goes to the face where they clear at all,
    and where both do, to the one where they clear at the smaller opening; where those differ by
    less than ``HINGE_SIDE_TOL_DEG``, the summed overhang across the pair's shared side decides.
    Where neither face clears, the top: the hinge stage trims that pair's overlap.  The clear
    openings of the chosen faces come back with the sides (the same as ``flatpose.hinge_faces``
    of these tiles).
    """
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    if tiles.ndim != 3 or tiles.shape[1:] != (8, 3) or len(tiles) != linkage.n_tiles:
        raise InputError(f"tiles_3d has shape {tiles.shape}; pass (T, 8, 3) T3D tiles")
    bottom, top = hinge_overhangs(linkage, tiles)
    thickness = float(np.mean(np.linalg.norm(tiles[:, :4] - tiles[:, 4:], axis=2)))
    by_overhang = bottom - top > HINGE_SIDE_TOL_REL * max(thickness, 1e-300)
    posed = lay_flat(tiles)
    ends = slit_ends(linkage)
    theta = np.radians(min_gap_angle_deg)
    start = np.full((2, linkage.n_hinges), theta)  # least clear opening within the bounds
    miss = np.zeros((2, linkage.n_hinges))  # how far the clear openings miss the bounds
    clear = []
    for k, face_bottom in enumerate((False, True)):
        side = np.full(linkage.n_hinges, face_bottom)
        lo, hi = free_openings(
            linkage, posed, side, clearance=HINGE_LAYOUT_CLEARANCE_MM, touch=HINGE_LAYOUT_TOUCH_MM
        )
        clear.append((lo, hi))
        # with the margin the flat layout keeps inside the clear openings
        first, last, _ = HingeFaces(side, lo, hi).window(theta, 0.5 * np.pi)
        np.maximum.at(start[k], ends.hinge, first)
        np.maximum.at(miss[k], ends.hinge, np.maximum(first - last, 0.0))
    tol = np.radians(HINGE_SIDE_TOL_DEG)
    by_clearance = np.where(np.abs(start[1] - start[0]) <= tol, by_overhang, start[1] < start[0])
    # a pair that collides on both faces at every opening within the bounds goes on top and
    # has its overlap trimmed (the top strategy for that pair): its top faces stay apart
    sides = np.asarray((miss[1] <= 0) & ((miss[0] > 0) | by_clearance))
    on_bottom = sides[ends.hinge]
    return HingeFaces(
        sides,
        np.where(on_bottom, clear[1][0], clear[0][0]),
        np.where(on_bottom, clear[1][1], clear[0][1]),
    )


@dataclass(frozen=True)
class HingeTrim:
    """Overlap of two hinged tiles in the flat pose, removed from ``tile``.

    Attributes
    ----------
    hinge : int
    tile : int
        The tile trimmed (the larger id of the pair).
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


@dataclass(frozen=True)
class HingeLayout:
    """Flat tiles with their hinges.

    Attributes
    ----------
    strategy : "dual" | "top"
    tiles : (T, 8, 3) float, mm
        Final flat tiles (hinge pairs merged for ``dual``).
    bottom : (H,) bool
        Hinge side (True: bottom).
    hinge_vertices : (H, 2) int
        ``8 * tile + vertex`` of both tiles' hinge vertex.
    hinge_points : (H, 3) float, mm
        Hinge positions (after merging).
    hinge_gap_max_mm : float
        Max paired-vertex distance before merging.
    trims : tuple of HingeTrim
        ``top`` strategy only.
    contact_area_lost_mm2 : float
    iterations : int
    time_s : float
    problems : tuple of str
    rigid_tiles : (T, 8, 3) float, mm, or None
        The tiles before merging: congruent to T3D, separated by the layout's clearance
        except at their hinge points.  These are what gets fabricated; the hinge parts bridge
        the residual hinge mismatch.
    """

    strategy: HingeStrategy
    tiles: FloatArray
    bottom: NDArray[np.bool_]
    hinge_vertices: IntArray
    hinge_points: FloatArray
    hinge_gap_max_mm: float
    trims: tuple[HingeTrim, ...] = field(default=())
    contact_area_lost_mm2: float = 0.0
    iterations: int = 0
    time_s: float = 0.0
    problems: tuple[str, ...] = field(default=())
    rigid_tiles: FloatArray | None = None

    @property
    def sides(self) -> tuple[HingeSide, ...]:
        return tuple("bottom" if b else "top" for b in self.bottom)


def _hinge_vertex_ids(linkage: Linkage, bottom: NDArray[np.bool_]) -> IntArray:
    h = linkage.hinges
    off = np.where(bottom, 4, 0)
    return np.stack([8 * h[:, 0] + h[:, 1] + off, 8 * h[:, 2] + h[:, 3] + off], axis=1)


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
    import manifold3d as m3d

    tiles = np.asarray(tiles_2d, dtype=np.float64)
    trims: list[HingeTrim] = []
    which = np.arange(linkage.n_hinges) if hinges is None else np.asarray(hinges, dtype=np.int64)
    for index in which.tolist():
        a, b = int(linkage.hinges[index, 0]), int(linkage.hinges[index, 2])
        overlap = m3d.Manifold.hull_points(tiles[a]) ^ m3d.Manifold.hull_points(tiles[b])
        volume = float(overlap.volume())
        if volume <= 0:
            continue
        mesh = overlap.to_mesh64()
        verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        tris = np.asarray(mesh.tri_verts, dtype=np.int64)
        p0, p1, p2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        normals = np.cross(p1 - p0, p2 - p0)
        keep = np.linalg.norm(normals, axis=1) > 0
        normals = normals[keep] / np.linalg.norm(normals[keep], axis=1, keepdims=True)
        trimmed = max(a, b)
        lost = sum(
            polygon_in_convex_polyhedron_area(tiles[trimmed][face], p0[keep], normals)
            for face in TILE_FACES[2:]
        )
        # Record the trim grown by a small cube (Minkowski sum) so that subtracting it leaves no
        # numerical sliver, and so that a needle-thin overlap becomes a tool a B-rep cut can take.
        grown = (verts[:, None, :] + _TRIM_GROWTH[None]).reshape(-1, 3)
        trims.append(HingeTrim(index, trimmed, grown, volume, float(lost)))
    return tuple(trims)


# ---------------------------------------------------------------------------------------------
# Rigid planar hinge layout
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Planes:
    """Separating planes of close tile pairs; each plane is attached rigidly to its tile ``a``.

    In world coordinates the plane of pair ``p`` is ``w . (x_xy - o_a) + nz * x_z = offset``
    with ``w = R(phi_a) normal[p, :2]``, ``nz = normal[p, 2]`` and ``o_a`` tile ``a``'s
    origin.  Vertex ``v`` of ``b`` must satisfy ``value - offset >= delta_b[p, v]`` and vertex
    ``u`` of ``a`` ``offset - value >= delta_a[p, u]`` (``inf``: not constrained, e.g. not in
    the convex piece ``piece_a`` / ``piece_b`` of a non-convex tile that the row separates).
    """

    a: IntArray
    b: IntArray
    hinge: IntArray
    normal: FloatArray
    offset: FloatArray
    delta_a: FloatArray
    delta_b: FloatArray
    score: FloatArray
    piece_a: IntArray
    piece_b: IntArray


#: Weight of a violation on the side of the tile that carries a plane (the layout cannot repair
#: it: the plane moves with that tile) against one on the other side when choosing planes.
_CARRIER_VIOLATION_WEIGHT = 1e3


def _plane_scores(
    sa: FloatArray,
    sb: FloatArray,
    anchor: IntArray,
    delta_a: FloatArray,
    delta_b: FloatArray,
    clearance: float,
) -> tuple[FloatArray, FloatArray]:
    """Score and offset ``(P, C)`` of candidate planes from vertex heights ``(P, 8, C)``.

    ``sa``, ``sb``: the vertices of ``a`` and ``b`` projected on each candidate normal.
    ``anchor[p] >= 0``: the plane passes through that vertex of ``a`` (hinged pair); otherwise
    it lies ``clearance`` beyond ``a``'s farthest vertex.  The score is the smallest margin
    beyond the required ones; a violation on ``a``'s side (which the layout cannot repair, the
    plane moving with ``a``) counts ``_CARRIER_VIOLATION_WEIGHT`` times.
    """
    ka = np.isfinite(delta_a)
    p = np.arange(len(anchor))
    far = np.max(np.where(ka[:, :, None], sa, -np.inf), axis=1) + clearance
    offset = np.where((anchor >= 0)[:, None], sa[p, np.maximum(anchor, 0)], far)
    # unconstrained vertices get -inf / +inf requirements and so drop out of the minima
    da = np.where(ka, delta_a, -np.inf)[:, :, None]
    margin_a = np.min(offset[:, None] - sa - da, axis=1)
    db = np.where(np.isfinite(delta_b), delta_b, -np.inf)[:, :, None]
    margin_b = np.min(sb - offset[:, None] - db, axis=1)
    margin_a = np.where(margin_a < 0, _CARRIER_VIOLATION_WEIGHT * margin_a, margin_a)
    return np.minimum(margin_a, margin_b), offset


def _perp(v: FloatArray) -> FloatArray:
    """Vectors ``(k, 2)`` turned by +90 degrees."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def _rotate2(v: FloatArray, angle: FloatArray) -> FloatArray:
    """Rotate vectors ``(..., 2)`` counter-clockwise by ``angle`` (broadcast)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


class _RigidLayout:
    """Rigid, still-flat tiles (3 DOF each: turn about z, translate in x, y).

    Minimizes the squared horizontal distance of paired hinge vertices subject to gap opening
    angle bounds and separating planes between close tile pairs, by an augmented Lagrangian
    whose subproblems are solved by Levenberg-Marquardt (sparse normal equations).
    """

    def __init__(self, shapes: FloatArray) -> None:
        self.shapes = shapes
        self.n = len(shapes)
        self.centre = shapes[:, :, :2].mean(axis=1)
        self.local = shapes[:, :, :2] - self.centre[:, None]
        self.z = shapes[:, :, 2]
        self.phi = np.zeros(self.n)
        self.trans = np.zeros((self.n, 2))
        self.pieces = convex_pieces(shapes)  # (T, 2, 8): collision bodies of every tile

    def positions(
        self, phi: FloatArray | None = None, trans: FloatArray | None = None
    ) -> FloatArray:
        """World ``(T, 8, 3)`` vertices for a pose (default: the current one)."""
        phi = self.phi if phi is None else phi
        trans = self.trans if trans is None else trans
        xy = _rotate2(self.local, phi[:, None]) + (self.centre + trans)[:, None]
        return np.concatenate([xy, self.z[..., None]], axis=-1)

    def origin(self, trans: FloatArray | None = None) -> FloatArray:
        return self.centre + (self.trans if trans is None else trans)


def _close_pairs(x: FloatArray, reach: float) -> IntArray:
    """Tile pairs ``(P, 2)``, ``i < j``, whose vertex sets (x, y) may come within ``reach``."""
    centres = x[:, :, :2].mean(axis=1)
    radius = np.linalg.norm(x[:, :, :2] - centres[:, None], axis=2).max(axis=1)
    tree = cKDTree(centres)
    pairs = np.asarray(
        tree.query_pairs(2.0 * float(radius.max(initial=0.0)) + reach, output_type="ndarray"),
        dtype=np.int64,
    ).reshape(-1, 2)
    dist = np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1)
    pairs = pairs[dist <= radius[pairs[:, 0]] + radius[pairs[:, 1]] + reach]
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def _hinge_of_pairs(linkage: Linkage, n: int, pairs: IntArray) -> tuple[IntArray, ...]:
    """Pairs oriented as ``(a, b)`` with ``a`` the first tile of their hinge, and the hinge
    index of every pair (-1: not hinged)."""
    h = linkage.hinges
    keys = h[:, 0] * n + h[:, 2]
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]

    def lookup(k: IntArray) -> IntArray:
        if not len(sorted_keys):
            return np.full(len(k), -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(sorted_keys, k), len(sorted_keys) - 1)
        return np.asarray(np.where(sorted_keys[pos] == k, order[pos], -1), dtype=np.int64)

    fwd = lookup(pairs[:, 0] * n + pairs[:, 1])
    bwd = lookup(pairs[:, 1] * n + pairs[:, 0])
    swap = (fwd < 0) & (bwd >= 0)
    a = np.where(swap, pairs[:, 1], pairs[:, 0])
    b = np.where(swap, pairs[:, 0], pairs[:, 1])
    return a, b, np.where(fwd >= 0, fwd, bwd)


def _select_planes(
    layout: _RigidLayout,
    linkage: Linkage,
    hinge_ids: IntArray,
    trim: NDArray[np.bool_],
    clearance: float,
    reach: float,
    *,
    touch: float = HINGE_LAYOUT_TOUCH_MM,
    x: FloatArray | None = None,
    pairs: IntArray | None = None,
    previous: _Planes | None = None,
) -> _Planes:
    """Best separating plane of every close pair of convex pieces (sampled, then refined).

    ``x`` defaults to the current pose's vertices (pass merged vertices to re-check them);
    ``pairs`` defaults to all tile pairs within ``reach`` (plus twice the clearance); every
    tile pair gives one row per pair of convex pieces (one piece for a convex tile).  ``trim``
    ``(H,)`` marks hinges whose pair is separated on the hinge face only (its overlap in the
    other face's half is trimmed away).  ``touch``
    is the separation required where a hinged pair may touch.  With
    ``previous`` planes, a row found there is only searched near its previous plane, unless
    that leaves it violated.  The returned score of each plane is its smallest margin beyond
    the required ones.
    """
    x = layout.positions() if x is None else x
    if pairs is None:
        pairs = _close_pairs(x, reach + 2.0 * clearance)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    a, b, hinge = _hinge_of_pairs(linkage, layout.n, pairs)
    # one row per pair of convex pieces
    n_pieces = 1 + layout.pieces[:, 1].any(axis=1).astype(np.int64)
    na, nb = n_pieces[a], n_pieces[b]
    count = na * nb
    row_pair = np.repeat(np.arange(len(a)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    piece_a = local // nb[row_pair]
    piece_b = local % nb[row_pair]
    a, b, hinge = a[row_pair], b[row_pair], hinge[row_pair]
    mask_a = layout.pieces[a, piece_a]
    mask_b = layout.pieces[b, piece_b]
    n_p = len(a)
    k_all = np.arange(n_p)
    hk = np.maximum(hinge, 0)
    va = hinge_ids[hk, 0] % 8  # a's hinge vertex (tile a is hinges[:, 0])
    vb = hinge_ids[hk, 1] % 8
    # a row treats the hinge only if both its pieces hold the hinge vertices
    hinged = (hinge >= 0) & mask_a[k_all, va] & mask_b[k_all, vb]
    hinge = np.where(hinged, hinge, -1)
    delta_a = np.where(mask_a, clearance, np.inf)
    delta_b = np.where(mask_b, clearance, np.inf)
    rows = np.flatnonzero(hinged)
    face_only = hinged & trim[hk]  # separated on the hinge face only
    dual_hinged = hinged & ~trim[hk]
    cut = np.flatnonzero(face_only)
    other = np.arange(4)
    delta_a[cut[:, None], 4 * (1 - va[cut, None] // 4) + other] = np.inf
    delta_b[cut[:, None], 4 * (1 - vb[cut, None] // 4) + other] = np.inf
    # elsewhere the other face's corner under/over the hinge may touch the plane
    both = np.flatnonzero(dual_hinged)
    delta_a[both, (va[both] + 4) % 8] = touch
    delta_b[both, (vb[both] + 4) % 8] = touch
    delta_a[rows, va[rows]] = np.inf  # the plane passes through it
    delta_b[rows, vb[rows]] = 0.0  # b's hinge vertex meets the plane when merged
    anchor = np.where(hinged, va, -1)
    origin = layout.origin()
    o3 = np.concatenate([origin, np.zeros((layout.n, 1))], axis=1)
    rel_a = x[a] - o3[a][:, None]
    rel_b = x[b] - o3[a][:, None]
    # For a hinged pair the tight vertices are the corners of the other face at the hinge: for a
    # horizontal direction e their margins are linear in the plane's vertical slope t, so the
    # best slope is found exactly (a's margin kept >= 0 since the plane moves with a).
    d_pa = rel_a[k_all, (va + 4) % 8] - rel_a[k_all, va]
    d_pb = rel_b[k_all, (vb + 4) % 8] - rel_a[k_all, va]

    def search(
        sel: IntArray, az: FloatArray, spread: FloatArray, base: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Best of azimuths ``(p, K)`` x slopes for rows ``sel``: normals ``(p, 3)``, scores
        and offsets ``(p,)``."""
        c, s = np.cos(az), np.sin(az)
        pa_, pb_ = d_pa[sel], d_pb[sel]
        al1 = -(c * pa_[:, 0:1] + s * pa_[:, 1:2])
        be1 = -pa_[:, 2:3]
        al2 = c * pb_[:, 0:1] + s * pb_[:, 1:2]
        be2 = pb_[:, 2:3]
        den = be2 - be1
        t = np.where(np.abs(den) > 1e-12, (al1 - al2) / np.where(den == 0, 1.0, den), 0.0)
        low = al1 + be1 * t < 0
        t = np.where(low & (np.abs(be1) > 1e-12), -al1 / np.where(be1 == 0, 1.0, be1), t)
        exact = np.clip(t, -0.8, 0.8)[:, :, None] + 0.1 * spread
        tilt = np.where(
            dual_hinged[sel, None, None], exact, base[:, None, None] + spread + 0.0 * c[:, :, None]
        )
        tilt = np.where(face_only[sel, None, None], 0.0, tilt)  # (p, K, S)
        norm = np.sqrt(1.0 + tilt * tilt)
        ra, rb = rel_a[sel], rel_b[sel]

        def heights(r: FloatArray) -> FloatArray:
            flat_part = r[:, :, 0:1] * c[:, None] + r[:, :, 1:2] * s[:, None]  # (p, 8, K)
            h = flat_part[..., None] + r[:, :, 2, None, None] * tilt[:, None]
            return np.asarray((h / norm[:, None]).reshape(len(sel), 8, -1))

        score, offset = _plane_scores(
            heights(ra), heights(rb), anchor[sel], delta_a[sel], delta_b[sel], clearance
        )
        pick = np.argmax(score, axis=1)
        kk, ss = np.unravel_index(pick, tilt.shape[1:])
        q = np.arange(len(sel))
        t_best = tilt[q, kk, ss]
        nrm = np.sqrt(1.0 + t_best * t_best)
        normal = np.stack([c[q, kk] / nrm, s[q, kk] / nrm, t_best / nrm], axis=1)
        return normal, score[q, pick], offset[q, pick]

    def refine(sel: IntArray, guess: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Azimuth +-3 deg by 0.25 deg, slope +-0.05 around ``guess`` normals ``(p, 3)``."""
        az = np.arctan2(guess[:, 1], guess[:, 0])[:, None] + np.radians(np.arange(-3.0, 3.01, 0.25))
        base = guess[:, 2] / np.sqrt(np.maximum(1.0 - guess[:, 2] ** 2, 1e-12))
        return search(sel, az, np.array([0.0, 0.025, -0.025, 0.05, -0.05]), base)

    normal = np.zeros((n_p, 3))
    score = np.full(n_p, -np.inf)
    offset = np.zeros(n_p)
    chunk = 512

    def run(sel: IntArray, guess: FloatArray | None) -> None:
        for start in range(0, len(sel), chunk):
            part = sel[start : start + chunk]
            if guess is None:
                az = np.broadcast_to(np.radians(np.arange(0.0, 360.0, 3.0)), (len(part), 120))
                spread = np.array([0.0, 0.15, -0.15, 0.35, -0.35])
                g, _, _ = search(part, az, spread, np.zeros(len(part)))
            else:
                g = guess[start : start + chunk]
            n_new, s_new, o_new = refine(part, g)
            better = s_new > score[part]
            part = part[better]
            normal[part], score[part], offset[part] = n_new[better], s_new[better], o_new[better]

    todo = k_all
    if previous is not None and len(previous.a):
        # warm start: rows also present before are searched near their previous plane
        def row_key(pa: IntArray, pb: IntArray, ia: IntArray, ib: IntArray) -> IntArray:
            return ((pa * layout.n + pb) * 2 + ia) * 2 + ib

        old = row_key(previous.a, previous.b, previous.piece_a, previous.piece_b)
        order = np.argsort(old, kind="stable")
        new = row_key(a, b, piece_a, piece_b)
        pos = np.minimum(np.searchsorted(old[order], new), len(old) - 1)
        found = old[order][pos] == new
        src = order[pos[found]]
        world = np.concatenate(
            [_rotate2(previous.normal[src, :2], layout.phi[a[found]]), previous.normal[src, 2:]],
            axis=1,
        )
        warm = np.flatnonzero(found)
        run(warm, world)
        todo = np.concatenate([np.flatnonzero(~found), warm[score[warm] < 0]])
    run(np.sort(todo), None)
    body = np.concatenate([_rotate2(normal[:, :2], -layout.phi[a]), normal[:, 2:]], axis=1)
    return _Planes(a, b, hinge, body, offset, delta_a, delta_b, score, piece_a, piece_b)


def _plane_values(
    layout: _RigidLayout,
    planes: _Planes,
    x: FloatArray,
    phi: FloatArray,
    trans: FloatArray,
    *,
    carrier: bool = True,
) -> tuple[FloatArray, FloatArray | None, FloatArray]:
    """Signed distances ``(P, 8)`` of ``b``'s and (if ``carrier``) ``a``'s vertices beyond their
    required margins, and the world plane normals ``(P, 2)`` (x, y part)."""
    origin = (layout.centre + trans)[planes.a]
    w = _rotate2(planes.normal[:, :2], phi[planes.a])
    nz = planes.normal[:, 2]

    def value(t: IntArray) -> FloatArray:
        xt = x[t]
        return np.asarray(
            (xt[:, :, 0] - origin[:, 0:1]) * w[:, 0:1]
            + (xt[:, :, 1] - origin[:, 1:2]) * w[:, 1:2]
            + nz[:, None] * xt[:, :, 2]
            - planes.offset[:, None]
        )

    gb = value(planes.b) - np.where(np.isfinite(planes.delta_b), planes.delta_b, -np.inf)
    if not carrier:
        return gb, None, w
    ga = -value(planes.a) - np.where(np.isfinite(planes.delta_a), planes.delta_a, -np.inf)
    return gb, ga, w


@dataclass
class _Constraints:
    """Current inequality set ``g(pose) >= 0`` of the layout (planes and angle bounds)."""

    planes: _Planes
    ends: SlitEnds
    faces: IntArray  # (F,) faces whose angles are bounded (0 top, 4 bottom)
    angle0: FloatArray  # (F, E) rad at zero pose
    lo: FloatArray  # (F, E) rad
    hi: FloatArray  # (F, E) rad
    scale: float  # mm per rad (mean tile side)


def _constraint_values(
    layout: _RigidLayout,
    con: _Constraints,
    phi: FloatArray,
    trans: FloatArray,
    rows: IntArray | None = None,
) -> tuple[FloatArray, sp.csr_matrix | None]:
    """All inequality values ``(m,)`` (mm) at a pose, and the Jacobian ``(len(rows), 3T)`` of
    the selected ones (plane rows first, then lower and upper angle bounds per face)."""
    x = layout.positions(phi, trans)
    planes = con.planes
    gb, _, w = _plane_values(layout, planes, x, phi, trans, carrier=False)
    mask = np.isfinite(gb)
    g_planes = gb[mask]
    t0, t1 = con.ends.tiles[:, 0], con.ends.tiles[:, 1]
    ang = con.angle0 + (phi[t0] - phi[t1])[None, :]
    g_lo = ((ang - con.lo) * con.scale).ravel()
    g_hi = ((con.hi - ang) * con.scale).ravel()
    g = np.concatenate([g_planes, g_lo, g_hi])
    if rows is None:
        return g, None
    m_p = len(g_planes)
    pr = rows[rows < m_p]
    ar = rows[rows >= m_p] - m_p
    p_idx, v_idx = np.nonzero(mask)
    p_idx, v_idx = p_idx[pr], v_idx[pr]
    a, b = planes.a[p_idx], planes.b[p_idx]
    wp = w[p_idx]
    origin = layout.centre + trans
    xb = x[b, v_idx, :2]
    cols = np.stack([3 * b, 3 * b + 1, 3 * b + 2, 3 * a, 3 * a + 1, 3 * a + 2], axis=1)
    vals = np.stack(
        [
            np.einsum("ki,ki->k", wp, _perp(xb - origin[b])),
            wp[:, 0],
            wp[:, 1],
            np.einsum("ki,ki->k", _perp(wp), xb - origin[a]),
            -wp[:, 0],
            -wp[:, 1],
        ],
        axis=1,
    )
    # Angle bounds, linear in phi: angle = angle0 + phi[t0] - phi[t1].
    end = ar % len(t0)
    sign = np.where(ar < g_lo.size, 1.0, -1.0) * con.scale
    cols_a = np.stack([3 * t0[end], 3 * t1[end]], axis=1)
    vals_a = np.stack([sign, -sign], axis=1)
    n_pr = len(pr)
    row_ids = np.concatenate(
        [np.repeat(np.arange(n_pr), 6), n_pr + np.repeat(np.arange(len(ar)), 2)]
    )
    jac = sp.csr_matrix(
        (
            np.concatenate([vals.ravel(), vals_a.ravel()]),
            (row_ids, np.concatenate([cols.ravel(), cols_a.ravel()])),
        ),
        shape=(len(rows), 3 * layout.n),
    )
    return g, jac


def _hinge_residuals(
    layout: _RigidLayout,
    ids: IntArray,
    phi: FloatArray,
    trans: FloatArray,
    weight: FloatArray,
    *,
    jacobian: bool = True,
) -> tuple[FloatArray, sp.csr_matrix | None]:
    """Horizontal hinge mismatch ``(2H,)`` (mm, weighted) and (if asked) its Jacobian
    ``(2H, 3T)``."""
    ta, va = ids[:, 0] // 8, ids[:, 0] % 8
    tb, vb = ids[:, 1] // 8, ids[:, 1] % 8
    ra = _rotate2(layout.local[ta, va], phi[ta])  # hinge vertices relative to tile origins
    rb = _rotate2(layout.local[tb, vb], phi[tb])
    origin = layout.centre + trans
    xa, xb = origin[ta] + ra, origin[tb] + rb
    sw = np.sqrt(weight)
    res = (sw[:, None] * (xa - xb)).ravel()
    if not jacobian:
        return res, None
    h = len(ids)
    pa, pb = _perp(ra), _perp(rb)
    rows = np.repeat(np.arange(2 * h), 4)
    cols = np.stack(
        [
            np.stack([3 * ta, 3 * ta + 1, 3 * tb, 3 * tb + 1], axis=1),
            np.stack([3 * ta, 3 * ta + 2, 3 * tb, 3 * tb + 2], axis=1),
        ],
        axis=1,
    ).ravel()
    one = np.ones(h)
    vals = (
        np.stack(
            [
                np.stack([pa[:, 0], one, -pb[:, 0], -one], axis=1),
                np.stack([pa[:, 1], one, -pb[:, 1], -one], axis=1),
            ],
            axis=1,
        )
        * sw[:, None, None]
    )
    jac = sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(2 * h, 3 * layout.n))
    return res, jac


def _augmented_lagrangian(
    layout: _RigidLayout,
    con: _Constraints,
    ids: IntArray,
    lam: FloatArray,
    rho: float,
    inner: int,
    weight: FloatArray,
    pin: FloatArray,
) -> tuple[FloatArray, int]:
    """Minimize ``|hinge mismatch|^2 + rho * sum max(0, lam / rho - g)^2`` over the pose.

    ``pin`` ``(3T,)`` is 1 on the pose variables held fixed.

    Damped Gauss-Newton (the objective is piecewise quadratic up to the small rotations); the
    layout's pose is updated in place.  Returns the constraint values at the end and the number
    of accepted steps.
    """
    sr = np.sqrt(rho)

    def evaluate(phi: FloatArray, trans: FloatArray) -> tuple[float, FloatArray, FloatArray]:
        rh, _ = _hinge_residuals(layout, ids, phi, trans, weight, jacobian=False)
        g, _ = _constraint_values(layout, con, phi, trans)
        slack = np.maximum(lam / rho - g, 0.0)
        return float(rh @ rh + rho * (slack @ slack)), rh, g

    def jacobian(phi: FloatArray, trans: FloatArray, g: FloatArray, rh: FloatArray):
        _, jh = _hinge_residuals(layout, ids, phi, trans, weight)
        assert jh is not None
        slack = lam / rho - g
        act = np.flatnonzero(slack > 0)
        _, jg = _constraint_values(layout, con, phi, trans, act)
        assert jg is not None
        res = np.concatenate([rh, sr * slack[act]])
        return res, sp.vstack([jh, -sr * jg], format="csr")

    cost, rh, g = evaluate(layout.phi, layout.trans)
    steps = 0
    for _ in range(inner):
        res, jac = jacobian(layout.phi, layout.trans, g, rh)
        jtj = (jac.T @ jac).tocsc()
        grad = jac.T @ res
        diag = jtj.diagonal()
        top = max(float(diag.max(initial=0.0)), 1e-12)
        # Every component's free rigid motion is fixed by pinning one of its tiles (``pin``);
        # a tiny Levenberg term keeps the system regular.
        damp = sp.diags(1e-9 * np.maximum(diag, 1e-6 * top) + pin * 1e6 * top)
        step = spla.splu(
            (jtj + damp).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        ).solve(-grad).reshape(layout.n, 3)  # fmt: skip
        accepted = False
        alpha = 1.0
        for _ls in range(12):
            phi_new = layout.phi + alpha * step[:, 0]
            trans_new = layout.trans + alpha * step[:, 1:]
            cost_new, rh_new, g_new = evaluate(phi_new, trans_new)
            if cost_new < cost:
                accepted = True
                break
            alpha *= 0.3
        if not accepted:
            break
        improvement = cost - cost_new
        layout.phi, layout.trans = phi_new, trans_new
        cost, rh, g = cost_new, rh_new, g_new
        steps += 1
        if improvement <= 1e-7 * cost or alpha * float(np.abs(step).max()) < 1e-11:
            break
    return g, steps


@dataclass(frozen=True)
class RigidLayoutResult:
    """Outcome of :func:`rigid_layout`.

    Attributes
    ----------
    tiles : (T, 8, 3) float, mm
        Rigid tiles (congruent to the input shapes) before merging.
    merged : (T, 8, 3) float, mm
        Tiles with every merged hinge pair moved to its shared point.
    points : (H, 3) float, mm
        Hinge points (shared point, or the midpoint of an unmerged pair).
    is_merged : (H,) bool
    gap_mm : (H,) float
        3D distance of each hinge pair before merging.
    violation_mm : float
        Largest remaining violation of a separating plane or angle bound (angle bounds in rad
        times the mean tile side), rigid tiles.
    iterations : int
        Accepted Levenberg-Marquardt steps over all rounds.
    """

    tiles: FloatArray
    merged: FloatArray
    points: FloatArray
    is_merged: NDArray[np.bool_]
    gap_mm: FloatArray
    violation_mm: float
    iterations: int


def _merge_points(
    layout: _RigidLayout, planes: _Planes, ids: IntArray, x: FloatArray
) -> FloatArray:
    """Shared point ``(H, 3)`` of every hinge pair: the midpoint moved horizontally onto the
    pair's separating plane (so both tiles stay on their own side after merging)."""
    flat = x.reshape(-1, 3)
    mid = 0.5 * (flat[ids[:, 0]] + flat[ids[:, 1]])
    pair_of = -np.ones(len(ids), dtype=np.int64)
    hinged = np.flatnonzero(planes.hinge >= 0)
    pair_of[planes.hinge[hinged]] = hinged
    out = mid.copy()
    ok = pair_of >= 0
    p = pair_of[ok]
    a = planes.a[p]
    w = _rotate2(planes.normal[p, :2], layout.phi[a])
    nz = planes.normal[p, 2]
    origin = layout.origin()[a]
    value = np.einsum("ki,ki->k", mid[ok, :2] - origin, w) + nz * mid[ok, 2] - planes.offset[p]
    out[ok, :2] -= (value / np.maximum(np.einsum("ki,ki->k", w, w), 1e-300))[:, None] * w
    return out


def rigid_layout(
    linkage: Linkage,
    shapes: ArrayLike,
    hinge_ids: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    min_gap_angle_deg: float = 12.0,
    clearance_mm: float = HINGE_LAYOUT_CLEARANCE_MM,
    max_rounds: int = 40,
    inner_steps: int = 60,
    trim: ArrayLike | None = None,
) -> RigidLayoutResult:
    """Lay rigid flat tiles out so paired hinge vertices meet as closely as possible.

    Every tile keeps its shape (``shapes``, the T2D pose: top face horizontal) and may only
    turn about the vertical axis and translate in the plane (3 DOF).  Minimized: the squared
    horizontal distance of every hinge pair.  Subject to

    * every slit end's opening angle in ``[min_gap_angle_deg, 90]`` on the top faces and, for
      ``dual``, on the bottom faces (linear in the rotations);
    * every close pair of tiles separated by a plane attached to one of them (exact
      non-interpenetration for convex tiles; a non-convex, dart-shaped tile takes part as its
      two convex pieces, :func:`~drawstring.geometry.verify.convex_pieces`, each separated on
      its own, since its hull would fill the notch): with ``clearance_mm`` to spare, except that a
      hinged pair's plane passes through the hinge, which with the corner of the other face at
      the hinge may touch it; for ``top`` hinged pairs, and ``trim`` ones, only the hinge faces
      are separated (their 3D overlap is trimmed).  Planes are re-chosen (sampled max-margin,
      never accepting a violation on the carrying tile's side when avoidable) in the first
      rounds, warm-started from the previous planes.

    The solver is an augmented Lagrangian whose subproblems are solved by Levenberg-Marquardt.
    Hinge pairs are then merged at their midpoint moved horizontally onto the pair's plane; a
    merge that would break an angle bound (after raising that bound's margin and re-solving) or
    a plane is undone, leaving that pair rigid and apart.

    Parameters
    ----------
    linkage : Linkage
    shapes : (T, 8, 3) float, mm
        T2D tiles (start layout and rigid shapes).
    hinge_ids : (H, 2) int
        ``8 * tile + vertex`` of both vertices of every hinge (tile order of ``linkage.hinges``).
    strategy : "dual" | "top"
    min_gap_angle_deg : float, deg
    clearance_mm : float, mm
    max_rounds, inner_steps : solver limits (augmented Lagrangian rounds, LM steps per round).
    trim : (H,) bool, optional
        ``dual`` hinges whose pairs are separated on the hinge face only (default none; every
        hinge for ``top``).

    Returns
    -------
    RigidLayoutResult
    """
    t2 = np.asarray(shapes, dtype=np.float64)
    ids = np.asarray(hinge_ids, dtype=np.int64).reshape(-1, 2)
    cut = np.full(len(ids), strategy == "top") if trim is None else np.asarray(trim, dtype=bool)
    if cut.shape != (len(ids),):
        raise InputError(f"trim has shape {cut.shape}; pass one flag per hinge")
    layout = _RigidLayout(t2)
    ends = slit_ends(linkage)
    faces = np.array([0, 4] if strategy == "dual" else [0], dtype=np.int64)
    angle0 = np.stack([ends.angles(t2, int(f)) for f in faces])
    lo_deg = np.full(angle0.shape, float(min_gap_angle_deg) + HINGE_ANGLE_MARGIN_DEG)
    hi_deg = np.full(angle0.shape, 90.0 - HINGE_ANGLE_MARGIN_DEG)
    side = np.linalg.norm(t2[:, [1, 2, 3, 0], :2] - t2[:, :4, :2], axis=2)
    scale = float(side.mean()) if side.size else 1.0
    weight = np.ones(len(ids))
    reach = 0.5 * scale
    pin = np.zeros(3 * layout.n)
    comp = linkage.tile_component
    first = np.unique(comp, return_index=True)[1]
    pin[(3 * first[:, None] + np.arange(3)).ravel()] = 1.0
    total_steps = 0

    def constraints(planes: _Planes) -> _Constraints:
        return _Constraints(
            planes, ends, faces, angle0, np.radians(lo_deg), np.radians(hi_deg), scale
        )

    state: dict[str, Any] = {"lam": None, "rho": 10.0}

    def solve(planes: _Planes, rounds: int, reselect: int) -> tuple[_Planes, float]:
        """Augmented Lagrangian rounds; multipliers carry over between calls."""
        nonlocal total_steps
        con = constraints(planes)
        g, _ = _constraint_values(layout, con, layout.phi, layout.trans)
        lam = state["lam"] if state["lam"] is not None and len(state["lam"]) == len(g) else None
        lam = np.zeros(len(g)) if lam is None else lam
        rho = float(state["rho"])
        prev = np.inf
        viol = float(np.max(-g, initial=0.0))
        for r in range(rounds):
            if 0 < r <= reselect:
                planes = _select_planes(
                    layout, linkage, ids, cut, clearance_mm, reach, previous=planes
                )
                n_old = len(lam)
                con = constraints(planes)
                g, _ = _constraint_values(layout, con, layout.phi, layout.trans)
                n_ang = 2 * angle0.size
                lam = np.concatenate([np.zeros(len(g) - n_ang), lam[n_old - n_ang :]])
            g, steps = _augmented_lagrangian(layout, con, ids, lam, rho, inner_steps, weight, pin)
            total_steps += steps
            viol = float(np.max(-g, initial=0.0))
            lam = np.maximum(0.0, lam - rho * g)
            logger.debug("rigid layout round %d: violation %.3g mm, rho %.3g", r, viol, rho)
            if viol <= HINGE_LAYOUT_FEASIBLE_MM and r >= reselect:
                break
            if viol > 0.25 * prev:
                rho = min(rho * 5.0, 1e5)
            prev = viol
        state["lam"] = lam
        return planes, viol

    planes = _select_planes(layout, linkage, ids, cut, clearance_mm, reach)
    planes, violation = solve(planes, max_rounds, 2)
    is_merged = np.ones(len(ids), dtype=bool)
    for attempt in range(4):
        x = layout.positions()
        points = _merge_points(layout, planes, ids, x)
        merged = _merged_tiles(x, ids, points, is_merged)
        ang = np.stack([np.degrees(ends.angles(merged, int(f))) for f in faces])
        lo_def = min_gap_angle_deg - ang
        hi_def = ang - 90.0
        need_lo = lo_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        need_hi = hi_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        bad_ends = (need_lo | need_hi).any(axis=0)
        logger.debug(
            "merge angles attempt %d: %d bad ends, deficit %.3g",
            attempt,
            int(bad_ends.sum()),
            float(max(np.max(lo_def, initial=-np.inf), np.max(hi_def, initial=-np.inf))),
        )
        if not bad_ends.any():
            break
        if attempt == 3:
            is_merged &= ~_hinges_of_ends(ends, bad_ends, ids, faces)
            break
        lo_deg[need_lo] += 2.0 * np.maximum(lo_def[need_lo], 0.0) + HINGE_ANGLE_MARGIN_DEG
        hi_deg[need_hi] -= 2.0 * np.maximum(hi_def[need_hi], 0.0) + HINGE_ANGLE_MARGIN_DEG
        planes, violation = solve(planes, max_rounds, 0)
    x = layout.positions()
    points = _merge_points(layout, planes, ids, x)
    gap = hinge_gaps(x, ids)
    for _ in range(len(ids) + 1):
        merged = _merged_tiles(x, ids, points, is_merged)
        undo = _broken_merges(
            layout,
            linkage,
            cut,
            planes,
            ends,
            faces,
            merged,
            ids,
            is_merged,
            min_gap_angle_deg,
        )
        if not undo.any():
            break
        is_merged &= ~undo
    points = np.where(
        is_merged[:, None],
        points,
        0.5 * (x.reshape(-1, 3)[ids[:, 0]] + x.reshape(-1, 3)[ids[:, 1]]),
    )
    return RigidLayoutResult(x, merged, points, is_merged, gap, violation, total_steps)


def _merged_tiles(
    x: FloatArray, ids: IntArray, points: FloatArray, is_merged: NDArray[np.bool_]
) -> FloatArray:
    """Tiles ``(T, 8, 3)`` with both vertices of every merged hinge moved to its point."""
    flat = x.reshape(-1, 3).copy()
    flat[ids[is_merged, 0]] = points[is_merged]
    flat[ids[is_merged, 1]] = points[is_merged]
    return flat.reshape(x.shape)


def _hinges_of_ends(
    ends: SlitEnds, bad: NDArray[np.bool_], ids: IntArray, faces: IntArray
) -> NDArray[np.bool_]:
    """Hinges whose merged vertices enter the angle of any ``bad`` slit end."""
    t0, t1 = ends.tiles[bad, 0], ends.tiles[bad, 1]
    s0, s1 = ends.sides[bad, 0], ends.sides[bad, 1]
    verts = []
    for f in faces:
        verts += [
            8 * t1 + f + s1,
            8 * t1 + f + (s1 + 1) % 4,
            8 * t0 + f + s0,
            8 * t0 + f + (s0 + 1) % 4,
        ]
    used = np.unique(np.concatenate(verts)) if verts else np.zeros(0, dtype=np.int64)
    return np.asarray(np.isin(ids[:, 0], used) | np.isin(ids[:, 1], used))


def _broken_merges(
    layout: _RigidLayout,
    linkage: Linkage,
    trim: NDArray[np.bool_],
    planes: _Planes,
    ends: SlitEnds,
    faces: IntArray,
    merged: FloatArray,
    ids: IntArray,
    is_merged: NDArray[np.bool_],
    min_gap_angle_deg: float,
) -> NDArray[np.bool_]:
    """Merged hinges to undo: those whose moved vertices leave two tiles without a separating
    plane, or a gap angle out of its bounds (checked on the merged tiles)."""
    tol = 1e-9
    gb, ga, _ = _plane_values(layout, planes, merged, layout.phi, layout.trans)
    assert ga is not None
    # Separation only (the clearance is a target of the layout, not a validity condition).
    gb = gb + np.where(np.isfinite(planes.delta_b), planes.delta_b, 0.0)
    ga = ga + np.where(np.isfinite(planes.delta_a), planes.delta_a, 0.0)
    suspect = np.flatnonzero(np.any(gb < -tol, axis=1) | np.any(ga < -tol, axis=1))
    undo = np.zeros(len(ids), dtype=bool)
    if suspect.size:
        pairs = np.stack([planes.a[suspect], planes.b[suspect]], axis=1)
        again = _select_planes(layout, linkage, ids, trim, 0.0, 0.0, x=merged, pairs=pairs)
        broken = again.score < -tol
        tiles = np.concatenate([again.a[broken], again.b[broken]])
        undo |= is_merged & (np.isin(ids[:, 0] // 8, tiles) | np.isin(ids[:, 1] // 8, tiles))
        # only hinges that moved a vertex of a broken pair matter; undo them pairwise
        if broken.any():
            pair_tiles = np.stack([again.a[broken], again.b[broken]], axis=1)
            mine = np.zeros(len(ids), dtype=bool)
            for ta, tb in pair_tiles:
                mine |= np.isin(ids[:, 0] // 8, (ta, tb)) | np.isin(ids[:, 1] // 8, (ta, tb))
            undo &= mine
    bad = np.zeros(len(ends.hinge), dtype=bool)
    for f in faces:
        ang = np.degrees(ends.angles(merged, int(f)))
        bad |= (ang < min_gap_angle_deg) | (ang > 90.0)
    logger.debug(
        "merge check: %d suspect pairs, %d undone for separation, %d bad angles",
        suspect.size,
        int(undo.sum()),
        int(bad.sum()),
    )
    if bad.any():
        undo |= is_merged & _hinges_of_ends(ends, bad, ids, faces)
    return undo


def layout_hinges(
    linkage: Linkage,
    flat: FlatResult,
    tiles_2d: ArrayLike,
    tiles_3d: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    min_gap_angle_deg: float | None = None,
    clearance_mm: float = HINGE_LAYOUT_CLEARANCE_MM,
    max_rounds: int = 40,
    bottom: ArrayLike | None = None,
) -> HingeLayout:
    """Place hinges and lay the rigid tiles out so paired hinge vertices meet.

    ``dual``: each hinge goes to the top or the bottom (:func:`hinge_sides`); ``top``: all on
    top.  Then :func:`rigid_layout` moves the rigid T2D tiles in the plane (this is the paper's
    ``E_Hinge`` with ``w_rigid -> infinity``: tiles exactly rigid; ``E_Collision`` as hard
    separating planes; ``E_Conn`` minimized) keeping every gap angle within
    ``[theta_min, 90]`` deg, and merges every hinge pair into one point where that keeps the
    layout valid.  For ``top`` the 3D overlap of each hinged pair is then computed and recorded
    as a trim of the tile with the larger id.

    Parameters
    ----------
    linkage : Linkage
    flat : FlatResult
        K2D (gives ``theta_min`` unless ``min_gap_angle_deg`` is passed).
    tiles_2d : (T, 8, 3) float, mm
        T2D from :func:`~drawstring.geometry.flat.extrude_flat`.
    tiles_3d : (T, 8, 3) float, mm
        T3D (hinge sides).
    strategy : "dual" | "top"
    min_gap_angle_deg : float, deg, optional
    clearance_mm : float, mm
        Least distance between tiles away from their shared hinge point.
    max_rounds : int
        Augmented Lagrangian rounds.
    bottom : (H,) bool, optional
        ``dual`` hinge sides; default the faces the flat layout was made for (``flat.hinges``,
        whose clear openings, computed on ``tiles_3d``, are then reused), else
        :func:`hinge_sides` of ``tiles_3d``.

    Returns
    -------
    HingeLayout
    """
    start = time.perf_counter()
    t2 = np.asarray(tiles_2d, dtype=np.float64)
    t3 = np.asarray(tiles_3d, dtype=np.float64)
    if t2.shape != t3.shape or t2.shape[1:] != (8, 3) or len(t2) != linkage.n_tiles:
        raise InputError("tiles_2d and tiles_3d must both be (T, 8, 3) for the linkage's tiles")
    if strategy not in ("dual", "top"):
        raise InputError(f"--hinges {strategy!r} is not known; use dual or top")
    theta = flat.min_gap_angle_deg if min_gap_angle_deg is None else float(min_gap_angle_deg)
    problems: list[str] = []
    if strategy == "top":
        sides = np.zeros(linkage.n_hinges, dtype=bool)
    elif bottom is None:
        sides = hinge_sides(linkage, t3) if flat.hinges is None else flat.hinges.bottom
    else:
        sides = np.asarray(bottom, dtype=bool)
        if sides.shape != (linkage.n_hinges,):
            raise InputError(f"bottom has shape {sides.shape}; pass one flag per hinge")
    ids = _hinge_vertex_ids(linkage, sides)
    if strategy == "top":
        trim = np.ones(linkage.n_hinges, dtype=bool)
    else:
        # pairs that collide on their hinge face at every opening within the gap-angle bounds
        # are laid out like top hinges: separated on the hinge face, their overlap trimmed
        ends = slit_ends(linkage)
        bounds = np.radians([theta + HINGE_ANGLE_MARGIN_DEG, 90.0 - HINGE_ANGLE_MARGIN_DEG])
        made_for = flat.hinges
        if made_for is None or not np.array_equal(made_for.bottom, sides):
            made_for = hinge_faces(linkage, t3, sides)
        _, _, fits = made_for.window(*bounds)
        trim = np.zeros(linkage.n_hinges, dtype=bool)
        trim[ends.hinge[~fits]] = True
    never_clear = int(trim.sum())
    result = rigid_layout(
        linkage, t2, ids, strategy=strategy, min_gap_angle_deg=theta,
        clearance_mm=clearance_mm, max_rounds=max_rounds, trim=trim,
    )  # fmt: skip
    # A plane through the hinge that separates the two whole tiles is stricter than keeping
    # them apart; where it holds a pair apart, lay that pair out like a trimmed one: separated
    # on its hinge face, with whatever 3D overlap is left trimmed (often none).
    apart = (hinge_gaps(result.tiles, ids, in_plane=True) > HINGE_GAP_TOL_MM) & ~trim
    logger.info("hinge layout: %d of %d pairs apart", apart.sum(), len(apart))
    if 0 < apart.sum() <= HINGE_RELAYOUT_MAX_SHARE * len(apart):
        retry = rigid_layout(
            linkage, t2, ids, strategy=strategy, min_gap_angle_deg=theta,
            clearance_mm=clearance_mm, max_rounds=max_rounds, trim=trim | apart,
        )  # fmt: skip
        if retry.violation_mm <= max(
            result.violation_mm, HINGE_LAYOUT_FEASIBLE_MM
        ) and _in_plane_max(retry, ids) < _in_plane_max(result, ids):
            result, trim = retry, trim | apart
            problems.append(
                f"dual hinges: laid out {_pairs(int(apart.sum()))} again that planes through "
                "the hinge held apart, separated on their hinge face only"
            )
    gap_max = float(result.gap_mm.max(initial=0.0))
    if result.violation_mm > HINGE_LAYOUT_FEASIBLE_MM:
        problems.append(
            f"hinge layout: tiles could not be separated with every gap angle in [{theta:g}, 90] "
            f"deg (constraint violation {result.violation_mm:.3g} mm)"
        )
    n_apart = int(np.count_nonzero(~result.is_merged))
    if n_apart:
        problems.append(
            f"{_pairs(n_apart, 'hinge ')} left unmerged (up to "
            f"{float(result.gap_mm[~result.is_merged].max()):.3g} mm apart): merging them would "
            "overlap tiles or break a gap-angle bound"
        )
    trims = hinge_trims(linkage, result.merged, np.flatnonzero(trim))
    lost = float(sum(tr.contact_area_lost_mm2 for tr in trims))
    if trims:
        which = f"{strategy} hinges: "
        if never_clear and strategy == "dual":
            which += (
                f"{_pairs(never_clear, verb='collide')} on their hinge face at every opening in "
                f"[{theta:g}, 90] deg; "
            )
        problems.append(
            f"{which}{_pairs(len(trims), 'hinged ', 'overlap')} in the flat pose; trimmed "
            f"{sum(tr.volume_mm3 for tr in trims):.3g} mm^3, losing {lost:.3g} mm^2 of contact"
        )
    return HingeLayout(
        strategy, result.merged, sides, ids, result.points, gap_max, trims, lost,
        result.iterations, time.perf_counter() - start, tuple(problems), result.tiles,
    )  # fmt: skip


#: The second layout (pairs held apart laid out on their hinge face only) runs only when at
#: most this share of the pairs is apart: planes through the hinge hold pairs apart locally
#: (three of 370 at the three-shell's split-line ends); when most pairs are apart, as on the
#: 1600-tile wave (2067 of 3152), the flat tiles themselves are not congruent and a second
#: layout only doubles the stage's time.
HINGE_RELAYOUT_MAX_SHARE = 0.05


def _pairs(count: int, kind: str = "", verb: str = "") -> str:
    """``"1 hinged pair overlaps"``, ``"2 hinged pairs overlap"``."""
    if count == 1:
        return f"1 {kind}pair" + (f" {verb}s" if verb else "")
    return f"{count} {kind}pairs" + (f" {verb}" if verb else "")


def _in_plane_max(result: RigidLayoutResult, ids: IntArray) -> float:
    """Largest in-plane distance of a hinge pair of a rigid layout, before merging, mm."""
    return float(hinge_gaps(result.tiles, ids, in_plane=True).max(initial=0.0))


def write_flat_obj(path: str | Path, tiles: ArrayLike) -> None:
    """Write tiles as closed outward-oriented quad meshes (8 vertices, 6 faces each).

    Vertex order per tile: top BL, BR, TR, TL, then the bottom vertices under them (same as
    ``assembled.obj``); tile ``t`` uses OBJ vertices ``8 t + 1 .. 8 t + 8`` and group ``tile_t``.

    Parameters
    ----------
    path : output file
    tiles : (T, 8, 3) float, mm
    """
    t = np.asarray(tiles, dtype=np.float64)
    lines = ["# drawstring flat configuration (T2D), mm"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in t.reshape(-1, 3)]
    for k in range(len(t)):
        lines.append(f"g tile_{k}")
        for face in TILE_FACES:
            lines.append("f " + " ".join(str(8 * k + int(i) + 1) for i in face))
    Path(path).write_text("\n".join(lines) + "\n")


def hinge_vertex_json(layout: HingeLayout, linkage: Linkage) -> dict[str, Any]:
    """Hinge list for design.json: tiles, corners, side, 0-based OBJ vertex ids, position."""
    rows = []
    for k, (ta, ca, tb, cb) in enumerate(linkage.hinges):
        rows.append(
            {
                "tiles": [int(ta), int(tb)],
                "corners": [int(ca), int(cb)],
                "side": "bottom" if layout.bottom[k] else "top",
                "vertices": [int(layout.hinge_vertices[k, 0]), int(layout.hinge_vertices[k, 1])],
                "point_mm": [float(v) for v in layout.hinge_points[k]],
            }
        )
    out: dict[str, Any] = {"strategy": layout.strategy, "hinges": rows}
    if layout.trims:
        out["trims"] = [
            {
                "hinge": tr.hinge,
                "tile": tr.tile,
                "volume_mm3": tr.volume_mm3,
                "contact_area_lost_mm2": tr.contact_area_lost_mm2,
                "vertices_mm": tr.vertices.tolist(),
            }
            for tr in layout.trims
        ]
    json.dumps(out)  # fail early on anything not serializable
    return out


def draw_flat(
    ax: Any,
    linkage: Linkage,
    layout: HingeLayout,
    flat: FlatResult | None = None,
) -> None:
    """Draw the flat layout on a matplotlib axis.

    Tiles (top faces) coloured by component, bottom outlines thin, gaps shaded by opening angle,
    hinges as filled dots (top) or hollow circles (bottom); a ``dual`` layout's trimmed pairs
    (every ``top`` pair is trimmed where it overlaps) crossed.
    """
    from matplotlib import colormaps
    from matplotlib.collections import PolyCollection

    tiles = layout.tiles
    comp_cmap = colormaps["Pastel1"]
    colours = [comp_cmap(int(c) % 9) for c in linkage.tile_component]
    if flat is not None and flat.junctions.elements.size:
        gap_polys: list[FloatArray] = []
        gap_vals: list[float] = []
        from .verify import gap_opening_angles_deg

        measured = gap_opening_angles_deg(linkage, tiles, layout.bottom)
        ang: dict[int, float] = {}
        for g, value in zip(flat.junctions.gap[flat.junctions.is_end], measured, strict=True):
            ang[int(g)] = min(ang.get(int(g), 90.0), float(value))
        for g in range(linkage.n_gaps):
            sides = linkage.gap_sides[g]
            sides = sides[sides[:, 0] >= 0]
            ring: list[FloatArray] = []
            for t, s in sides:  # the void, traced along the final tiles' top sides
                ring.append(tiles[t, (s + 1) % 4, :2])
                ring.append(tiles[t, s, :2])
            gap_polys.append(np.array(ring))
            gap_vals.append(float(ang.get(g, 0.0)))
        pc = PolyCollection(gap_polys, array=np.array(gap_vals), cmap="viridis", alpha=0.6)
        pc.set_clim(0.0, 90.0)
        ax.add_collection(pc)
        ax.figure.colorbar(pc, ax=ax, label="gap opening angle (deg)", shrink=0.7)
    ax.add_collection(
        PolyCollection(list(tiles[:, 4:, :2]), facecolors="none", edgecolors="0.5", linewidths=0.3)
    )
    ax.add_collection(
        PolyCollection(list(tiles[:, :4, :2]), facecolors=colours, edgecolors="k", linewidths=0.5)
    )
    pts = layout.hinge_points
    top = ~layout.bottom
    ax.plot(pts[top, 0], pts[top, 1], "o", ms=3, color="k", label="top hinge")
    ax.plot(pts[~top, 0], pts[~top, 1], "o", ms=4, mfc="none", mec="r", label="bottom hinge")
    if layout.strategy == "dual" and layout.trims:
        cut = np.array([tr.hinge for tr in layout.trims])
        ax.plot(pts[cut, 0], pts[cut, 1], "x", ms=7, color="m", label="trimmed pair")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize=7)
