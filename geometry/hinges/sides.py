"""Which face each hinge goes on, top or bottom (paper section 4.4).

Every tile corner has a top vertex ``P`` and the bottom vertex ``Q`` under it; in T3D the four
tiles around a grid vertex share ``P`` and ``Q`` (contact faces are shared).  Flattening keeps
each tile rigid, and a hinge lets its two tiles turn about the vertical axis through the hinged
corner only, so whether they collide in the flat pose depends on the opening at the hinge alone.
For each hinge and each face we compute the openings at which the two flat tiles clear each
other (:func:`~drawstring.geometry.flat.pose.free_openings`, exact separating planes through the
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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import HINGE_LAYOUT_CLEARANCE_MM, HINGE_LAYOUT_TOUCH_MM
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.pose import HingeFaces, free_openings, lay_flat
from drawstring.geometry.tiling.linkage import Linkage, slit_ends

__all__ = [
    "HINGE_SIDE_TOL_DEG",
    "HINGE_SIDE_TOL_REL",
    "dual_hinge_faces",
    "hinge_overhangs",
    "hinge_sides",
]

#: Where both faces clear at openings within this of each other, the overhangs decide.
HINGE_SIDE_TOL_DEG = 0.05
#: A hinge goes to the bottom by overhang only when the bottom overhang exceeds the top overhang
#: by more than this fraction of the tile thickness (ties, e.g. flat targets, stay on top).
HINGE_SIDE_TOL_REL = 1e-9


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


def hinge_sides(linkage: Linkage, tiles_3d: ArrayLike, min_gap_angle_deg: float = 0.0) -> BoolArray:
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
    clear each other (:func:`~drawstring.geometry.flat.pose.free_openings`), within the gap-angle
    bounds ``[min_gap_angle_deg, 90]``.  The hinge goes to the face where they clear at all,
    and where both do, to the one where they clear at the smaller opening; where those differ by
    less than ``HINGE_SIDE_TOL_DEG``, the summed overhang across the pair's shared side decides.
    Where neither face clears, the top: the hinge stage trims that pair's overlap.  The clear
    openings of the chosen faces come back with the sides (the same as ``flatpose.hinge_faces``
    of these tiles).
    """
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    if tiles.ndim != 3 or tiles.shape[1:] != (8, 3) or len(tiles) != linkage.n_tiles:
        raise InternalError(f"tiles_3d has shape {tiles.shape}; pass (T, 8, 3) T3D tiles")
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
