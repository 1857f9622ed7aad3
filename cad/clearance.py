"""Print clearance at the hinges of tiles printed together (``fdm-dual``).

In the flat pose two hinged tiles meet at the hinge and part from it at the gap angle (at
least 12 deg by default).  They turned apart from the assembled pose mostly about the bed's
normal, so they meet not at a point but along a line: the edge from the hinge corner through
the tile's thickness nearly coincides in both.  Within ``gap / angle`` of that edge (2 mm for
a 0.4 mm nozzle at 12 deg) their side faces are closer than a nozzle width, and a slicer would
join the two tiles' perimeter lines there, welding the hinge shut.

:func:`hinge_reliefs` takes the plane through the hinge that contains the mean of the two edges
and parts the rest of the tiles by the widest angle, and cuts from each tile what lies within
half the clearance of it: the two tiles then stay a whole clearance apart, and the TPU pad
bridges the cut.  What is cut is a thin wedge along that edge (``gap / 2`` deep at the edge,
``gap / (2 tan(angle / 2))`` wide, through the whole thickness): in the assembled pose the
side faces still close against each other beyond it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from drawstring.cad.paths import face_planes
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.core.types import FloatArray, IntArray

__all__ = ["HingeReliefs", "hinge_reliefs", "separating_normal"]

#: The first way to relieve a hinge (:func:`_relief_options`) that cuts at most this share of
#: either tile's volume is taken; where none does, the one that cuts least.
THIN_RELIEF_SHARE = 0.05
#: A hinge whose least relief would cut more than this share of either tile's volume is not
#: relieved (its tiles do not part from the hinge and print joined; the design notes name
#: them): a hinge welded shut is worse than a tile cut back near it.  julius_face (corpus)
#: at the 150 tiles drawstring chooses has 8 top hinges whose least relief cuts 5.1 to 13 %.
MAX_RELIEF_SHARE = 0.15


@dataclass(frozen=True)
class HingeReliefs:
    """The slivers :func:`hinge_reliefs` cuts.

    Attributes
    ----------
    cuts : tile -> planes ``(4,)`` float ``(n_x, n_y, n_z, d)``, flat pose, mm: the tile keeps
        the side ``n . x >= d`` of each (:func:`~drawstring.cad.tiles.relieved_tile_solid`).
    reach_max_mm : farthest a two-sided relief reaches from its hinge, seen from above.
    one_sided_reach_mm : farthest a one-sided relief reaches from its hinge (0 without any).
    share_max : largest share of a tile's volume a relief takes.
    one_sided : hinges relieved in one tile only (their tiles overlap below the hinge).
    skipped : hinges (indices) left as they are: a relief would cut too much
        (:data:`MAX_RELIEF_SHARE`).
    """

    cuts: dict[int, list[FloatArray]]
    reach_max_mm: float
    one_sided_reach_mm: float
    share_max: float
    one_sided: int
    skipped: tuple[int, ...]


def separating_normal(
    points_a: FloatArray, points_b: FloatArray
) -> tuple[FloatArray, float] | None:
    """The line through the origin that best separates two point sets in the plane.

    Parameters
    ----------
    points_a, points_b : (k, 2) float, mm, relative to the hinge point (points at it are left
        out).

    Returns
    -------
    (normal, angle): the line's unit normal ``(2,)``, pointing to ``points_a``, and the
    smallest angle (rad) between the line and a direction to a point of either set, as large
    as it can be made (negative where the sets cross every line a little, as two tiles'
    nearly coincident edges may); None without points.

    The smallest angle is the lowest of the sines ``n . u`` over the unit directions ``u``
    (those of ``points_b`` negated); as the line turns, each is a sinusoid, so the highest
    lowest one lies at the crest of one or where two cross: every such angle is tried.
    """
    directions = []
    for points, sign in ((points_a, 1.0), (points_b, -1.0)):
        lengths = np.linalg.norm(points, axis=1)
        far = lengths > 1e-6
        directions.append(sign * points[far] / lengths[far, None])
    rows = np.concatenate(directions)
    if len(rows) == 0:
        return None
    crests = np.arctan2(rows[:, 1], rows[:, 0])
    i, j = np.triu_indices(len(rows), 1)
    difference = rows[i] - rows[j]  # n . u_i = n . u_j where n is normal to the difference
    crossings = np.arctan2(difference[:, 1], difference[:, 0]) + 0.5 * np.pi
    angles = np.concatenate([crests, crossings, crossings + np.pi])
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    lowest = (normals @ rows.T).min(axis=1)
    best = int(np.argmax(lowest))
    return normals[best], float(np.arcsin(np.clip(lowest[best], -1.0, 1.0)))


#: Edges of a tile (vertex order of :mod:`drawstring.cad.tiles`).
_TILE_EDGES = np.array(
    [(k, (k + 1) % 4) for k in range(4)]
    + [(4 + k, 4 + (k + 1) % 4) for k in range(4)]
    + [(k, 4 + k) for k in range(4)]
)


def _sliver(tile: FloatArray, normal: FloatArray, depth: float) -> FloatArray:
    """(k, 3) points whose convex hull is the part of the convex ``tile`` ((8, 3), relative to
    the hinge) within ``depth`` of the plane with unit ``normal`` (none: no part of it is)."""
    height = tile @ normal - depth
    points = [tile[height <= 0]]
    p, q = tile[_TILE_EDGES[:, 0]], tile[_TILE_EDGES[:, 1]]
    hp, hq = height[_TILE_EDGES[:, 0]], height[_TILE_EDGES[:, 1]]
    crossing = (hp < 0) != (hq < 0)
    t = hp[crossing] / (hp[crossing] - hq[crossing])
    points.append(p[crossing] + (q[crossing] - p[crossing]) * t[:, None])
    return np.concatenate(points)


def hinge_reliefs(
    tiles: FloatArray,
    hinges: IntArray,
    sides: Sequence[str],
    clearance_mm: float,
) -> HingeReliefs:
    """Slivers to cut from hinged tiles so that any two stay ``clearance_mm`` apart.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm, the flat (print) pose, the bed in the ``xy`` plane.
    hinges : (H, 4) int ``(tile_a, corner_a, tile_b, corner_b)``.
    sides : (H,) ``"top"`` | ``"bottom"``: the face whose corners the hinge joins.
    clearance_mm : the distance to keep between two hinged tiles (a nozzle width).

    Returns
    -------
    HingeReliefs
        Per tile, one plane per hinge, ``clearance_mm / 2`` off the plane through the hinge
        that best separates its two tiles (:func:`_hinge_plane`): what lies nearer than that
        to the other tile is cut away.
    """
    array = np.asarray(tiles, dtype=np.float64)
    rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    if array.ndim != 3 or array.shape[1:] != (8, 3):
        raise InternalError(f"tiles must be a (T, 8, 3) array, got shape {array.shape}")
    if len(sides) != len(rows):
        raise InternalError(f"{len(sides)} hinge sides for {len(rows)} hinges")
    if not clearance_mm > 0:
        raise InternalError(f"the print clearance must be positive, got {clearance_mm}")
    depth = 0.5 * clearance_mm
    cuts: dict[int, list[FloatArray]] = {}
    reach, one_sided_reach, share, one_sided = 0.0, 0.0, 0.0, 0
    skipped: list[int] = []
    for index, ((a, ca, b, cb), side) in enumerate(zip(rows, sides, strict=True)):
        shift = 0 if side == HingeSide.TOP else 4
        hinge = 0.5 * (array[a, shift + ca] + array[b, shift + cb])
        best: tuple[float, float, list[tuple[int, FloatArray]], bool] | None = None
        for option in _relief_options(array, int(a), int(ca), int(b), int(cb), shift, hinge, depth):
            planes: list[tuple[int, FloatArray]] = []
            option_reach, option_share = 0.0, 0.0
            for tile, towards, keep in option:
                piece = _sliver(array[tile] - hinge, towards, keep)
                if len(piece) == 0:
                    continue
                option_reach = max(option_reach, float(np.linalg.norm(piece[:, :2], axis=1).max()))
                option_share = max(option_share, _volume(piece) / _volume(array[tile]))
                planes.append((tile, np.append(towards, towards @ hinge + keep)))
            if best is None or option_share < best[1]:
                best = (option_reach, option_share, planes, len(option) == 2)
            if option_share <= THIN_RELIEF_SHARE:
                break  # the two-sided relief where it cuts little, else the smallest one
        if best is None or best[1] > MAX_RELIEF_SHARE:
            skipped.append(index)
            continue
        share = max(share, best[1])
        if best[3]:
            reach = max(reach, best[0])
        else:
            one_sided += 1
            one_sided_reach = max(one_sided_reach, best[0])
        for tile, plane in best[2]:
            cuts.setdefault(tile, []).append(plane)
    return HingeReliefs(cuts, reach, one_sided_reach, share, one_sided, tuple(skipped))


def _relief_options(
    tiles: FloatArray, a: int, ca: int, b: int, cb: int, shift: int, hinge: FloatArray, depth: float
) -> Iterator[list[tuple[int, FloatArray, float]]]:
    """Ways to relieve the hinge of tiles ``a`` and ``b`` (corners ``ca``, ``cb``, hinge
    vertices ``shift + c``), each a list of ``(tile, unit normal, depth)``: the tile keeps
    what lies at least ``depth`` beyond the plane through ``hinge`` with that normal.

    First both tiles, half the clearance (``depth``) from the plane that best separates them
    (:func:`_hinge_plane`).  Where they overlap below the hinge (a pair the ``top`` strategy
    trims), that plane cuts deep into both; then one tile alone, a whole clearance beyond a
    side face of the other at the hinge corner (the other lies behind its own face plane)."""
    normal = _hinge_plane(tiles[a] - hinge, tiles[b] - hinge, shift + ca, shift + cb, depth)
    if normal is not None:
        yield [(a, normal, depth), (b, -normal, depth)]
    for cut, other, corner in ((a, b, cb), (b, a, ca)):
        outward = face_planes(tiles[other])[1]
        for face in (corner, (corner - 1) % 4):  # the two side faces at the corner
            yield [(cut, outward[face], 2.0 * depth)]


def _hinge_plane(
    tile_a: FloatArray, tile_b: FloatArray, corner_a: int, corner_b: int, depth: float
) -> FloatArray | None:
    """Unit normal (pointing to tile a) of the plane through the hinge that best separates
    two hinged tiles (relative to the hinge point; ``corner_*`` the hinged vertex of each).

    The tiles turned apart from their assembled pose mostly about the bed's normal, so the
    edges from the hinge to the opposite face's corners of both tiles nearly coincide: the
    plane contains their mean, and is turned about it to part the rest of the tiles (seen
    along it, :func:`separating_normal`) by the widest angle.  Points seen within ``depth``
    of the hinge are left out: the relief takes them away whichever side they fall on."""
    edge_a, edge_b = tile_a[(corner_a + 4) % 8], tile_b[(corner_b + 4) % 8]
    axis = edge_a / np.linalg.norm(edge_a) + edge_b / np.linalg.norm(edge_b)
    if not np.linalg.norm(axis) > 1e-9:
        return None
    axis /= np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    first = np.cross(axis, helper)
    first /= np.linalg.norm(first)
    plane = np.stack([first, np.cross(axis, first)])  # (2, 3) across the axis
    seen_a, seen_b = tile_a @ plane.T, tile_b @ plane.T
    keep_a = np.linalg.norm(seen_a, axis=1) > depth
    keep_b = np.linalg.norm(seen_b, axis=1) > depth
    found = separating_normal(seen_a[keep_a], seen_b[keep_b])
    return None if found is None else np.asarray(found[0] @ plane)


def _volume(points: FloatArray) -> float:
    """Volume (mm^3) of the convex hull of ``points`` (0 when they span no volume)."""
    try:
        return float(ConvexHull(points).volume)
    except QhullError:
        return 0.0
