"""The simulation's inputs from the design: the route's steps and the contact pairs the string
pulls together, the hinges' vertex pairs, the lift vertices and their targets, the assembled
tiles placed on the table, and the side faces that touch in the assembled state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.tiles import kabsch
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "RouteLike",
    "apply_transform",
    "contact_face_pairs",
    "hinge_vertex_pairs",
    "lift_targets_for_gaps",
    "place_on_table",
    "route_snap_pairs",
    "route_steps",
    "split_contact_pairs",
]


@runtime_checkable
class RouteLike(Protocol):
    """A route as the simulation reads it (a :class:`~drawstring.geometry.route.result.Route`)."""

    gaps: IntArray
    tiles: IntArray
    enter_side: IntArray
    leave_side: IntArray


def route_steps(route: RouteLike | ArrayLike) -> IntArray:
    """Route steps ``(gap, tile, enter_side, leave_side)`` as an ``(r, 4)`` int array.

    Parameters
    ----------
    route : a :class:`~drawstring.geometry.route.result.Route` (``gaps``, ``tiles``, ``enter_side``,
        ``leave_side``) or the steps themselves.
    """
    if isinstance(route, RouteLike):
        cols = [route.gaps, route.tiles, route.enter_side, route.leave_side]
        return np.stack([np.asarray(c, dtype=np.int64).reshape(-1) for c in cols], axis=1)
    return np.asarray(route, dtype=np.int64).reshape(-1, 4)


def route_snap_pairs(
    route: Sequence[tuple[int, int, int, int]] | ArrayLike,
) -> tuple[IntArray, IntArray]:
    """Contact pairs the string pulls together, from a closed route.

    Step ``i`` is ``(gap, tile, enter_side, leave_side)``: the string crosses ``gap`` (``-1``: a
    virtual entrance) to enter ``tile`` through ``enter_side`` and leaves it through
    ``leave_side``.  Consecutive steps ``i, i + 1`` (cyclically) give the pair
    ``(tile_i, leave_side_i, tile_{i+1}, enter_side_{i+1})`` across ``gap_{i+1}``.  Steps that
    stay on the same tile are skipped.

    Returns
    -------
    pairs : (P, 4) int
        ``(tile_a, side_a, tile_b, side_b)``.
    gaps : (P,) int
        Gap crossed by each pair (``-1`` for virtual entrances).
    """
    steps = np.asarray(route, dtype=np.int64).reshape(-1, 4)
    if len(steps) < 2:  # the user's route.json can say so (drawstring simulate FOLDER)
        raise InputError("a route needs at least two steps; pass the closed string route")
    nxt = np.roll(steps, -1, axis=0)
    keep = steps[:, 1] != nxt[:, 1]
    pairs = np.stack([steps[:, 1], steps[:, 3], nxt[:, 1], nxt[:, 2]], axis=1)[keep]
    return pairs.astype(np.int64), nxt[keep, 0].astype(np.int64)


def hinge_vertex_pairs(linkage: Linkage, hinge_side: Sequence[str] | None = None) -> IntArray:
    """Vertex ids ``tile * 8 + vertex`` joined by every hinge.

    Parameters
    ----------
    linkage : topology; hinge rows ``(tile_a, corner_a, tile_b, corner_b)``.
    hinge_side : (H,) ``"top"`` | ``"bottom"``; default all ``"top"``.  A top hinge at corner
        ``c`` joins vertex ``c``; a bottom hinge joins vertex ``4 + c``.

    Returns
    -------
    (H, 2) int
    """
    h = linkage.hinges
    sides = [HingeSide.TOP] * len(h) if hinge_side is None else list(hinge_side)
    if len(sides) != len(h) or any(s not in tuple(HingeSide) for s in sides):
        raise InternalError("hinge_side must list 'top' or 'bottom' for every hinge")
    off = np.array([0 if s == HingeSide.TOP else 4 for s in sides], dtype=np.int64)
    return np.stack([h[:, 0] * 8 + h[:, 1] + off, h[:, 2] * 8 + h[:, 3] + off], axis=1)


def lift_targets_for_gaps(
    linkage: Linkage, tiles_assembled: FloatArray, lift_gaps: ArrayLike
) -> tuple[IntArray, FloatArray]:
    """Lift vertices and targets: the top corners around each lift gap and their T3D positions.

    Parameters
    ----------
    linkage : topology.
    tiles_assembled : (T, 8, 3) float, mm
    lift_gaps : (L,) int, gap ids.

    Returns
    -------
    vertices : (k,) int, ``tile * 8 + corner``.
    targets : (k, 3) float, mm, in the frame of ``tiles_assembled``.
    """
    verts: list[int] = []
    for g in np.asarray(lift_gaps, dtype=np.int64).reshape(-1):
        if not 0 <= g < linkage.n_gaps:
            raise InternalError(f"lift gap {g} does not exist; the linkage has {linkage.n_gaps}")
        gv = linkage.gap_vertex[g]
        for t in linkage.gap_tiles(int(g)):
            for c in np.flatnonzero(linkage.tile_corners[t] == gv):
                verts.append(int(t) * 8 + int(c))
    v = np.unique(np.array(verts, dtype=np.int64))
    return v, np.asarray(tiles_assembled.reshape(-1, 3)[v], dtype=np.float64)


def place_on_table(tiles_assembled: FloatArray, tiles_flat: FloatArray) -> FloatArray:
    """Rigid map of the assembled tiles onto the table under the flat layout.

    Rotation about z and translation in xy from a 2D Kabsch fit of the tile centroids (top view),
    then a vertical shift so the lowest vertex sits on the flat layout's lowest level.

    Returns
    -------
    (4, 4) float, homogeneous transform.
    """
    c3 = tiles_assembled.mean(axis=1)
    c2 = tiles_flat.mean(axis=1)
    rot2, t2 = kabsch(c3[:, :2], c2[:, :2])
    mat = np.eye(4)
    mat[:2, :2] = rot2
    mat[:2, 3] = t2
    z_low = tiles_assembled[..., 2].min()
    mat[2, 3] = tiles_flat[..., 2].min() - z_low
    return mat


def apply_transform(mat: FloatArray, pts: FloatArray) -> FloatArray:
    return np.asarray(pts @ mat[:3, :3].T + mat[:3, 3])


def contact_face_pairs(linkage: Linkage) -> IntArray:
    """Side faces of grid-neighbour tiles that touch in the assembled state.

    Tiles in cells ``(i, j)`` and ``(i + 1, j)`` meet with sides 1 and 3, tiles in ``(i, j)``
    and ``(i, j + 1)`` with sides 2 and 0.  Only hinged neighbours are listed: across a split
    line the two parts may lie anywhere in the flat layout, where a face half-space would be
    meaningless (the string's snap pairs bring them together).

    Returns
    -------
    (k, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    """
    return _neighbour_sides(linkage, hinged=True)


def split_contact_pairs(linkage: Linkage) -> IntArray:
    """Side faces of edge-neighbour tiles that touch across a split (no hinge joins them).

    Same orientation as :func:`contact_face_pairs`: cells ``(i, j)`` and ``(i + 1, j)`` give
    ``(a, 1, b, 3)``, cells ``(i, j)`` and ``(i, j + 1)`` give ``(a, 2, b, 0)``.

    Returns
    -------
    (k, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    """
    return _neighbour_sides(linkage, hinged=False)


def _neighbour_sides(linkage: Linkage, *, hinged: bool) -> IntArray:
    """``(tile_a, side_a, tile_b, side_b)`` of the edge-neighbour tiles that a hinge joins
    (``hinged``) or that a split separates: cells ``(i, j)``, ``(i + 1, j)`` meet with sides 1
    and 3, cells ``(i, j)``, ``(i, j + 1)`` with sides 2 and 0."""
    cells = linkage.tile_cells
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(cells)}
    joined = {(int(min(a, b)), int(max(a, b))) for a, _, b, _ in linkage.hinges}
    out = []
    for t, (i, j) in enumerate(cells):
        for (di, dj), sides in (((1, 0), (1, 3)), ((0, 1), (2, 0))):
            other = index.get((int(i) + di, int(j) + dj))
            if other is not None and ((min(t, other), max(t, other)) in joined) == hinged:
                out.append((t, sides[0], other, sides[1]))
    return np.array(out, dtype=np.int64).reshape(-1, 4)
