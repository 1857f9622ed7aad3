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

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from drawstring.cad.hinge_pins import KeepOut
from drawstring.cad.paths import face_planes
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.core.tolerances import PRINT_GAP_TOL_MM
from drawstring.geometry.core.types import FloatArray, IntArray

__all__ = [
    "HingeReliefs",
    "apart_reliefs",
    "hinge_reliefs",
    "hollow_piece",
    "hollow_room",
    "separating_normal",
]

#: The first way to relieve a hinge (:func:`_relief_options`) that cuts at most this share of
#: either tile's volume is taken; where none does, the one that cuts least.
THIN_RELIEF_SHARE = 0.05
#: A relief that cuts at most this share of either tile's volume is taken as it is.  julius_face
#: (corpus) at the 150 tiles drawstring chooses has 8 top hinges whose least relief cuts 5.1 to
#: 13 %.
MAX_RELIEF_SHARE = 0.15
#: A deeper relief is measured against what the tile holds (see :func:`hinge_reliefs`'s
#: ``keep_out``): it is taken where every plane it cuts along stays a wall clear of the tile's
#: string channels, lift bores and hinge strips, and the tile keeps at least half its volume;
#: a hinge with no such relief is not relieved (its tiles print joined; the notes name them):
#: a hinge welded shut is worse than a tile cut back near it.
MAX_DEEP_RELIEF_SHARE = 0.5

#: What a relief of a tile's hinge must keep clear of, given (tile, hinge, whether the inner
#: half of the hinge's own strip counts): balls (see :class:`~drawstring.cad.hinge_pins.KeepOut`).
ReliefKeepOut = Callable[[int, int, bool], KeepOut]


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
        (:data:`MAX_RELIEF_SHARE`) or into a feature.
    deep : hinges (indices) relieved past :data:`MAX_RELIEF_SHARE`, their cuts clear of the
        tiles' features.
    hollows : tile -> convex polyhedra ``(k, 3)`` points, flat pose, mm, to subtract: where no
        plane relieves a hinge, one tile loses what lies within the clearance of the other
        (:func:`_hollow`); so too one of two tiles not hinged together that come closer than
        the clearance (:func:`apart_reliefs`).
    hollowed : hinges (indices) relieved so.
    apart : ``(cut, other)`` tiles not hinged together relieved so: ``cut`` loses what lies
        within the clearance of ``other``.
    crowded : ``(tile, tile)`` pairs not hinged together closer than the clearance that no
        such cut clears (it would open a channel, bore or strip, or take half a tile).
    """

    cuts: dict[int, list[FloatArray]]
    reach_max_mm: float
    one_sided_reach_mm: float
    share_max: float
    one_sided: int
    skipped: tuple[int, ...]
    deep: tuple[int, ...] = ()
    hollows: dict[int, list[FloatArray]] = field(default_factory=dict)
    hollowed: tuple[int, ...] = ()
    apart: tuple[tuple[int, int], ...] = ()
    crowded: tuple[tuple[int, int], ...] = ()


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
    keep_out: ReliefKeepOut | None = None,
    wall_mm: float = 0.0,
) -> HingeReliefs:
    """Slivers to cut from hinged tiles so that any two stay ``clearance_mm`` apart.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm, the flat (print) pose, the bed in the ``xy`` plane.
    hinges : (H, 4) int ``(tile_a, corner_a, tile_b, corner_b)``.
    sides : (H,) ``"top"`` | ``"bottom"``: the face whose corners the hinge joins.
    clearance_mm : the distance to keep between two hinged tiles (a nozzle width).
    keep_out : (tile, hinge) -> what a relief of that hinge must leave ``wall_mm`` clear of in
        that tile (its channels, bores and strips); None: no relief cuts more than
        :data:`MAX_RELIEF_SHARE` of a tile.
    wall_mm : the wall a deep relief leaves to ``keep_out``.

    Returns
    -------
    HingeReliefs
        Per tile, one plane per hinge, ``clearance_mm / 2`` off the plane through the hinge
        that best separates its two tiles (:func:`_hinge_plane`): what lies nearer than that
        to the other tile is cut away.  Where every way cuts more than
        :data:`MAX_RELIEF_SHARE`, the least one whose planes clear ``keep_out``
        (:data:`MAX_DEEP_RELIEF_SHARE`).
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
    deep: list[int] = []
    hollows: dict[int, list[FloatArray]] = {}
    hollowed: list[int] = []
    for index, ((a, ca, b, cb), side) in enumerate(zip(rows, sides, strict=True)):
        shift = 0 if side == HingeSide.TOP else 4
        hinge = 0.5 * (array[a, shift + ca] + array[b, shift + cb])
        tried: list[_Relief] = []
        for option in _relief_options(array, int(a), int(ca), int(b), int(cb), shift, hinge, depth):
            tried.append(_measure(array, option, hinge, len(option) == 2))
            if tried[-1].share <= THIN_RELIEF_SHARE:
                break  # the two-sided relief where it cuts little, else the smallest one
        best = min(tried, key=lambda r: r.share, default=None)  # the first of equal ones
        if best is not None and best.share > MAX_RELIEF_SHARE:
            best = _deep_relief(tried, index, keep_out, wall_mm)
            if best is not None:
                deep.append(index)
        if best is None:
            hollow = _hollow(array, int(a), int(b), clearance_mm, index, keep_out, wall_mm)
            if hollow is None:
                skipped.append(index)
            else:
                hollows.setdefault(hollow[0], []).append(hollow[1])
                hollowed.append(index)
                share = max(share, hollow[2])
            continue
        share = max(share, best.share)
        if best.two_sided:
            reach = max(reach, best.reach)
        else:
            one_sided += 1
            one_sided_reach = max(one_sided_reach, best.reach)
        for tile, plane in best.planes:
            cuts.setdefault(tile, []).append(plane)
    return HingeReliefs(
        cuts,
        reach,
        one_sided_reach,
        share,
        one_sided,
        tuple(skipped),
        tuple(deep),
        hollows,
        tuple(hollowed),
    )


@dataclass(frozen=True)
class _Relief:
    """One way to relieve a hinge, measured: how far it reaches from the hinge (seen from
    above), the largest share of a tile it cuts, its planes ``(tile, (n, d))`` and whether it
    cuts both tiles."""

    reach: float
    share: float
    planes: list[tuple[int, FloatArray]]
    two_sided: bool


def _measure(
    tiles: FloatArray,
    option: list[tuple[int, FloatArray, float]],
    hinge: FloatArray,
    two_sided: bool,
) -> _Relief:
    planes: list[tuple[int, FloatArray]] = []
    reach, share = 0.0, 0.0
    for tile, towards, keep in option:
        piece = _sliver(tiles[tile] - hinge, towards, keep)
        if len(piece) == 0:
            continue
        reach = max(reach, float(np.linalg.norm(piece[:, :2], axis=1).max()))
        share = max(share, _volume(piece) / _volume(tiles[tile]))
        planes.append((tile, np.append(towards, towards @ hinge + keep)))
    return _Relief(reach, share, planes, two_sided)


def _deep_relief(
    tried: list[_Relief], hinge: int, keep_out: ReliefKeepOut | None, wall_mm: float
) -> _Relief | None:
    """The way that cuts least of those (``tried``, past :data:`MAX_RELIEF_SHARE`) that keep
    at least :data:`MAX_DEEP_RELIEF_SHARE` of each tile and whose every plane leaves the
    tile's ``keep_out`` a wall clear; None where none does (or without ``keep_out``)."""
    if keep_out is None:
        return None
    for relief in sorted(tried, key=lambda r: r.share):
        if relief.share > MAX_DEEP_RELIEF_SHARE:
            break
        planes = relief.planes
        if all(_clears(p, keep_out(tile, hinge, True), wall_mm) for tile, p in planes):
            return relief
    return None


def _hollow(
    tiles: FloatArray,
    a: int,
    b: int,
    clearance_mm: float,
    hinge: int,
    keep_out: ReliefKeepOut | None,
    wall_mm: float,
) -> tuple[int, FloatArray, float] | None:
    """The least relief of hinged tiles ``a`` and ``b``: one of them loses what lies within
    ``clearance_mm`` of the other, the other's convex hull with its faces pushed out by the
    clearance (a convex polyhedron that holds every point that near).  Of the two ways, the
    one that cuts less is taken, where it keeps at least :data:`MAX_DEEP_RELIEF_SHARE` of the
    tile and stays a wall clear of the tile's string channels, lift bores and other hinges'
    strips (``keep_out``; the hinge's own strip bridges the cut): ``(tile, points, share)``,
    else None."""
    if keep_out is None:
        return None
    found: list[tuple[float, int, FloatArray]] = []
    for cut, other in ((a, b), (b, a)):
        piece = hollow_piece(tiles, cut, other, clearance_mm)
        if piece is None:
            continue
        pushed, polyhedron, share = piece
        balls = keep_out(cut, hinge, False)
        if len(balls.radii):
            # a ball outside the polyhedron by at least radius + wall on one face's plane
            # (a lower bound of its distance) stays clear of the cut
            height = (balls.centres @ pushed[:, :3].T + pushed[:, 3]).max(axis=1)
            if not np.all(height >= balls.radii + wall_mm):
                continue
        if share <= MAX_DEEP_RELIEF_SHARE:
            found.append((share, cut, polyhedron))
    if not found:
        return None
    share, cut, polyhedron = min(found, key=lambda f: f[0])
    return cut, polyhedron, share


def hollow_piece(
    tiles: FloatArray, cut: int, other: int, clearance_mm: float
) -> tuple[FloatArray, FloatArray, float] | None:
    """What tile ``cut`` loses to a hollow relief from tile ``other`` (:func:`_hollow`): the
    other's hull with its faces pushed out by ``clearance_mm``, as halfspaces ``n . x + d <=
    0`` (unit outward normals) and as points, and the share of ``cut``'s volume inside it;
    None where the two do not meet in a volume."""
    try:
        pushed = ConvexHull(tiles[other]).equations.copy()
        pushed[:, 3] -= clearance_mm  # unit outward normals: n . x + d <= clearance
        polyhedron = HalfspaceIntersection(pushed, tiles[other].mean(axis=0)).intersections
        inside = np.vstack([pushed, ConvexHull(tiles[cut]).equations])
        kept = _volume(HalfspaceIntersection(inside, _interior(inside)).intersections)
    except (QhullError, ValueError):
        return None
    return pushed, polyhedron, kept / _volume(tiles[cut])


def hollow_room(tiles: FloatArray, a: int, b: int, hinge: int, keep_out: ReliefKeepOut) -> float:
    """How far (mm) the features of one of hinged tiles ``a`` and ``b`` (``keep_out`` with the
    hinge's own strip left out, as :func:`_hollow` asks it) lie outside the other tile: the
    larger over the two tiles of the least distance, measured on the other's face planes (a
    lower bound; negative where a feature reaches into the other).  The hollow relief cuts
    what lies within the print clearance of the other tile, so it needs the clearance and a
    wall; a tile without features has room: infinity."""
    best = -np.inf
    for cut, other in ((a, b), (b, a)):
        try:
            planes = ConvexHull(tiles[other]).equations
        except (QhullError, ValueError):
            continue
        balls = keep_out(cut, hinge, False)
        if not len(balls.radii):
            return float(np.inf)
        height = (balls.centres @ planes[:, :3].T + planes[:, 3]).max(axis=1)
        best = max(best, float((height - balls.radii).min()))
    return float(best)


def apart_reliefs(
    tiles: FloatArray,
    hinges: IntArray,
    reliefs: HingeReliefs,
    clearance_mm: float,
    keep_out: ReliefKeepOut,
    wall_mm: float,
) -> HingeReliefs:
    """``reliefs`` with tiles not hinged together kept ``clearance_mm`` apart too: where two
    such tiles, relieved at their hinges (convex tiles cut by ``reliefs``' planes and hollows),
    come closer than that (tiles diagonal across a gap whose bottoms spread under top hinges),
    one loses what lies within the clearance of the other (:func:`hollow_piece`), the one that
    loses less of those where the cut stays ``wall_mm`` clear of everything ``keep_out`` says
    the tile holds and keeps half of it; a pair with neither is ``crowded``."""
    import manifold3d
    from scipy.spatial import cKDTree

    rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    hinged = {(int(min(a, b)), int(max(a, b))) for a, _, b, _ in rows.tolist()}
    centres = tiles.mean(axis=1)
    radii = np.linalg.norm(tiles - centres[:, None], axis=2).max(axis=1)
    reach = 2.0 * float(radii.max(initial=0.0)) + clearance_mm
    near = [
        (int(i), int(j))
        for i, j in sorted(map(tuple, cKDTree(centres).query_pairs(reach, output_type="ndarray")))
        if (int(i), int(j)) not in hinged
        and np.linalg.norm(centres[i] - centres[j]) <= radii[i] + radii[j] + clearance_mm
    ]
    if not near:
        return reliefs
    shapes: dict[int, manifold3d.Manifold] = {}

    def shape(tile: int) -> manifold3d.Manifold:
        if tile not in shapes:
            solid = _hull_manifold(tiles[tile])
            for plane in reliefs.cuts.get(tile, []):
                solid = solid.trim_by_plane(plane[:3].tolist(), float(plane[3]))
            for points in reliefs.hollows.get(tile, []):
                solid = solid - _hull_manifold(points)
            shapes[tile] = solid
        return shapes[tile]

    hollows = {tile: list(cuts) for tile, cuts in reliefs.hollows.items()}
    apart: list[tuple[int, int]] = []
    crowded: list[tuple[int, int]] = []
    share = reliefs.share_max
    for i, j in near:
        if shape(i).min_gap(shape(j), clearance_mm) >= clearance_mm - PRINT_GAP_TOL_MM:
            continue
        found = []
        for cut, other in ((i, j), (j, i)):
            piece = hollow_piece(tiles, cut, other, clearance_mm)
            if piece is None or piece[2] > MAX_DEEP_RELIEF_SHARE:
                continue
            balls = keep_out(cut, -1, True)  # no hinge of its own here: every strip counts
            if len(balls.radii):
                height = (balls.centres @ piece[0][:, :3].T + piece[0][:, 3]).max(axis=1)
                if not np.all(height >= balls.radii + wall_mm):
                    continue
            found.append((piece[2], cut, piece[1]))
        if not found:
            crowded.append((i, j))
            continue
        lost, cut, polyhedron = min(found, key=lambda f: (f[0], f[1]))
        hollows.setdefault(cut, []).append(polyhedron)
        apart.append((cut, j if cut == i else i))
        share = max(share, lost)
    return replace(
        reliefs, hollows=hollows, share_max=share, apart=tuple(apart), crowded=tuple(crowded)
    )


def _hull_manifold(points: FloatArray) -> Any:
    """manifold3d solid of the convex hull of ``points`` ((k, 3) mm)."""
    import manifold3d

    hull = ConvexHull(points)
    triangles = hull.simplices.copy()
    centre = points[hull.vertices].mean(axis=0)
    for k, (a, b, c) in enumerate(triangles.tolist()):
        if np.cross(points[b] - points[a], points[c] - points[a]) @ (points[a] - centre) < 0:
            triangles[k] = (a, c, b)  # wound outward
    mesh = manifold3d.Mesh(
        vert_properties=np.asarray(points, dtype=np.float32), tri_verts=triangles.astype(np.uint32)
    )
    return manifold3d.Manifold(mesh)


def _interior(halfspaces: FloatArray) -> FloatArray:
    """A point deepest inside the halfspaces ``n . x + d <= 0`` (raises ValueError where
    they hold none)."""
    from scipy.optimize import linprog

    normals = halfspaces[:, :3]
    lengths = np.linalg.norm(normals, axis=1)[:, None]
    found = linprog(
        [0.0, 0.0, 0.0, -1.0],
        A_ub=np.hstack([normals, lengths]),
        b_ub=-halfspaces[:, 3],
        bounds=[(None, None)] * 3 + [(0.0, None)],
    )
    if not found.success or found.x[3] <= 1e-9:
        raise ValueError("the halfspaces hold no interior point")
    return np.asarray(found.x[:3])


def _clears(plane: FloatArray, keep_out: KeepOut, wall_mm: float) -> bool:
    """Whether every ball of ``keep_out`` lies a wall inside the side ``n . x >= d`` that a
    tile keeps of ``plane`` ``(n, d)`` (``n`` a unit vector)."""
    if not len(keep_out.radii):
        return True
    height = keep_out.centres @ plane[:3] - plane[3]
    return bool(np.all(height >= keep_out.radii + wall_mm))


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
