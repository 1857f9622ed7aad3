"""The layout of a hinge strip on its tiles' hinge face, shared by every kind of hinge part:
how far the strip runs into each tile (:func:`strip_room`, :func:`hinge_strip_lengths`), the
strip's polyline and frame (:func:`hinge_frame`), slabs of its outline (:func:`slab`) and the
holes along it (:func:`place_holes`, :func:`cylinder_between`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import bd_plane, feature_wall_mm, footprint_margin, vector3
from drawstring.cad.kernel import clean_solid
from drawstring.cad.paths import FACE_BOTTOM, FACE_TOP, face_planes, unit_vector
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


#: Per tile of a hinge (a, b): the other corners of its hinge face that hold hinge strips, or
#: None for all of them (see :func:`strip_room`).
StripNeighbours = tuple[Sequence[int] | None, Sequence[int] | None]


@dataclass(frozen=True)
class HingeFrame:
    """Layout of a hinge strip on the hinge face plane (mm).

    points : (k, 3) polyline: end inside tile a, corner a, [corner b], end inside tile b.
    normal : (3,) outward normal of the hinge face (up for "top", down for "bottom").
    halves : per tile, (corner point, unit direction from the corner into the tile).
    lengths : per tile, how far (mm) the strip runs from the corner into the tile.
    """

    points: NDArray[np.float64]
    normal: NDArray[np.float64]
    halves: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    lengths: tuple[float, float]


def strip_room(
    profile: Profile,
    ring: NDArray[np.float64] | None = None,
    corner: int = 0,
    others: Sequence[int] | None = None,
) -> float:
    """How far (mm) a hinge strip's end stays from the centre of its tile's hinge face, so that
    the strips of the face's corners, which all run towards that centre, keep a
    :func:`feature_wall_mm` between them: half the strip width and a wall, and, given the
    face's corners ``ring`` ((4, 3), mm), at least ``(width + wall) / (2 sin(angle / 2))``,
    where ``angle`` is the smallest one at the centre between ``corner`` and another corner of
    the face that holds a strip (``others``; None: any corner).  Two strips ending that far out
    on rays that far apart are a width and a wall apart; on a square face that is 0.71 (width
    + wall), more than half a width and a wall for any strip over 1.41 walls wide.  Recesses of
    neighbouring corners' strips overlapping in thin slivers make OCCT's cut of a tile fail."""
    width, wall = profile.hinge_width_mm, feature_wall_mm(profile)
    room = 0.5 * width + wall
    if ring is None:
        return room
    spokes = np.asarray(ring, dtype=np.float64) - np.asarray(ring, dtype=np.float64).mean(axis=0)
    lengths = np.linalg.norm(spokes, axis=1)
    if lengths.min() < 1e-12:
        return float("inf")
    units = spokes / lengths[:, None]
    crowd = [k for k in (range(4) if others is None else others) if k != corner]
    if not crowd:
        return room
    cosines = units[crowd] @ units[corner]
    half_angle = 0.5 * float(np.arccos(np.clip(cosines.max(), -1.0, 1.0)))
    if half_angle < 1e-9:
        return float("inf")
    return max(room, (width + wall) / (2.0 * np.sin(half_angle)))


def strip_min_reach_mm(
    profile: Profile,
    ring: NDArray[np.float64] | None = None,
    corner: int = 0,
    others: Sequence[int] | None = None,
) -> float:
    """Shortest distance (mm) from a hinged corner to its face's centre that still leaves the
    strip half a width of its own in the tile (see :func:`strip_room`)."""
    return strip_room(profile, ring, corner, others) + 0.5 * profile.hinge_width_mm


def hinge_strip_lengths(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> tuple[float, float]:
    """How far (mm) a hinge's strip runs into tile a and into tile b: half the profile's pad
    length, less where the strip's end would come within :func:`strip_room` of the centre of
    the tile's hinge face (never under half the strip width).  ``neighbours``: per tile, the
    other corners of its hinge face that hold strips (None: all of them)."""
    frame = hinge_frame(
        np.asarray(tile_a, dtype=np.float64),
        corner_a,
        np.asarray(tile_b, dtype=np.float64),
        corner_b,
        side,
        profile,
        neighbours,
    )
    return frame.lengths


def hinge_frame(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> HingeFrame:
    """The strip of a hinge: half the profile's pad length into each tile, less where its end
    would come within :func:`strip_room` of the centre of the tile's hinge face (the strips of
    neighbouring corners meet there, and recesses overlapping in thin slivers make OCCT's cut
    of a tile fail)."""
    if side not in tuple(HingeSide):
        raise InternalError(f"hinge side {side!r} must be 'top' or 'bottom'")
    for corner, name in ((corner_a, "corner_a"), (corner_b, "corner_b")):
        if corner not in (0, 1, 2, 3):
            raise InternalError(f"{name} = {corner} must be a corner index 0..3")
    face = FACE_TOP if side == HingeSide.TOP else FACE_BOTTOM
    shift = 0 if side == HingeSide.TOP else 4
    normal = unit_vector(face_planes(tile_a)[1][face] + face_planes(tile_b)[1][face])
    point_a, point_b = tile_a[shift + corner_a], tile_b[shift + corner_b]
    level = 0.5 * (point_a + point_b) @ normal
    half_length = 0.5 * profile.hinge_pad_length_mm
    halves = []
    lengths = []
    for tile, corner, point, others in zip(
        (tile_a, tile_b), (corner_a, corner_b), (point_a, point_b), neighbours, strict=True
    ):
        point = point - (point @ normal - level) * normal
        ring = tile[shift : shift + 4]
        towards = ring.mean(axis=0) - point
        towards = towards - (towards @ normal) * normal
        halves.append((point, unit_vector(towards)))
        reach = float(np.linalg.norm(towards)) - strip_room(profile, ring, corner, others)
        lengths.append(max(min(half_length, reach), 0.5 * profile.hinge_width_mm))
    (pa, da), (pb, db) = halves
    points = [pa + lengths[0] * da]
    for candidate in (pa, pb, pb + lengths[1] * db):
        if np.linalg.norm(candidate - points[-1]) > 1e-6:
            points.append(candidate)
    kept = [points[0]]  # drop interior points where the polyline runs straight on
    for i in range(1, len(points) - 1):
        turn = np.cross(unit_vector(points[i] - kept[-1]), unit_vector(points[i + 1] - points[i]))
        if np.linalg.norm(turn) > 1e-6:
            kept.append(points[i])
    kept.append(points[-1])
    return HingeFrame(np.array(kept), normal, (halves[0], halves[1]), (lengths[0], lengths[1]))


def _strip_outline(points: NDArray[np.float64], width: float, normal: NDArray) -> bd.Face:
    """Planar face: the polyline ``points`` thickened to ``width`` with round ends and joints."""
    points = _merge_short_segments(points, width)
    if len(points) == 2:
        return _stadium(points[0], points[1], width, normal)
    wire = bd.Wire.make_polygon([vector3(p) for p in points], close=False)
    outline = wire.offset_2d(0.5 * width, kind=bd.Kind.ARC, side=bd.Side.BOTH)
    return bd.Face(outline)


def _merge_short_segments(points: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Join interior polyline points closer than ``width`` into their midpoint.

    OCCT's 2D offset fails on a polyline whose middle segment is shorter than the offset (a
    hinge whose two corners are a fraction of a millimetre apart); at that scale the pad is
    the same with the two joints merged.
    """
    pts = [np.asarray(p, dtype=np.float64) for p in points]
    k = 1
    while k < len(pts) - 2:
        if np.linalg.norm(pts[k + 1] - pts[k]) < width:
            pts[k : k + 2] = [0.5 * (pts[k] + pts[k + 1])]
        else:
            k += 1
    return np.array(pts)


def _stadium(
    a: NDArray[np.float64], b: NDArray[np.float64], width: float, normal: NDArray[np.float64]
) -> bd.Face:
    """Planar face: segment ``a``-``b`` thickened to ``width`` with round ends."""
    along = unit_vector(b - a)
    across = 0.5 * width * unit_vector(np.cross(normal, along))
    cap = 0.5 * width * along
    edges = [
        bd.Edge.make_line(vector3(a - across), vector3(b - across)),
        bd.Edge.make_three_point_arc(vector3(b - across), vector3(b + cap), vector3(b + across)),
        bd.Edge.make_line(vector3(b + across), vector3(a + across)),
        bd.Edge.make_three_point_arc(vector3(a + across), vector3(a - cap), vector3(a - across)),
    ]
    return bd.Face(bd.Wire(edges))


def slab(
    frame: HingeFrame, points: NDArray[np.float64], width: float, start: float, stop: float
) -> bd.Solid:
    """The strip outline between depths ``start`` and ``stop`` (mm, positive into the tiles)."""
    face = _strip_outline(points - start * frame.normal, width, frame.normal)
    return clean_solid(bd.Solid.extrude(face, vector3(-(stop - start) * frame.normal)))


def depth_to_opposite(
    tile: NDArray[np.float64], side: HingeSide, point: NDArray[np.float64], normal: NDArray
) -> tuple[float, bool]:
    """Distance (mm) along ``-normal`` from ``point`` on the hinge face to the opposite face,
    shortest over a pin's rim when the faces are not parallel, and whether they are parallel."""
    centroids, normals = face_planes(tile)
    face = FACE_BOTTOM if side == HingeSide.TOP else FACE_TOP
    cosine = float(-normal @ normals[face])
    distance = float((centroids[face] - point) @ normals[face] / cosine)
    return distance, abs(abs(cosine) - 1.0) < 1e-12


def place_holes(
    tile: NDArray[np.float64],
    corner: NDArray[np.float64],
    direction: NDArray[np.float64],
    normal: NDArray[np.float64],
    stations: tuple[float, ...],
    radius: float,
    wall: float,
    limit: float = np.inf,
    depth: float | None = None,
    cuts: NDArray[np.float64] | None = None,
) -> tuple[list[NDArray[np.float64]], int]:
    """Hole axes along one half of a strip, each slid inward (up to ``limit`` mm from the
    corner) until it keeps ``wall`` from the tile's side faces (within ``depth`` of the face
    for a blind hole, see :func:`footprint_margin`) and from the planes that cut the tile
    (``cuts``, see :func:`cut_margin`), and how many stations never fit."""
    placed, missing = [], 0
    for station in stations:
        candidates = np.linspace(station, station + 4.0 * radius, 17)
        for distance in candidates[candidates <= limit + 1e-9]:
            point = corner + distance * direction
            if (
                footprint_margin(tile, point, normal, depth) >= radius + wall
                and cut_margin(tile, point, normal, radius, cuts, depth) >= wall
            ):
                placed.append(point)
                break
        else:
            missing += 1
    return placed, missing


def cut_margin(
    tile: NDArray[np.float64],
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    radius: float,
    cuts: NDArray[np.float64] | None,
    depth: float | None = None,
) -> float:
    """Least distance (mm) from a hole of ``radius`` on the axis from ``point`` along
    ``-normal`` to the planes ``(n, d)`` of ``cuts`` that cut the tile (it keeps ``n . x >= d``,
    see :func:`drawstring.cad.tiles.relieved_tile_solid`): the hole runs ``depth`` deep, or
    through the tile without one; negative where it breaks through a plane; inf without cuts."""
    if cuts is None or not len(cuts):
        return float("inf")
    planes = np.asarray(cuts, dtype=np.float64).reshape(-1, 4)
    lengths = np.linalg.norm(planes[:, :3], axis=1)
    unit, offsets = planes[:, :3] / lengths[:, None], planes[:, 3] / lengths
    reach = float(((point - tile) @ normal).max()) if depth is None else depth
    ends = np.stack([point, point - reach * normal])  # (2, 3) the axis's two ends
    # the rim of a circle of the hole reaches radius * sin(angle to the plane's normal) nearer
    rim = radius * np.sqrt(np.clip(1.0 - (unit @ normal) ** 2, 0.0, 1.0))
    return float(((ends @ unit.T) - offsets[None, :] - rim[None, :]).min())


def outside_margin(
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    radius: float,
    depth: float,
    hull: NDArray[np.float64],
) -> float:
    """How far (mm) a hole of ``radius``, ``depth`` deep on the axis from ``point`` along
    ``-normal``, lies outside the convex region whose facets are ``hull`` (``(k, 4)`` rows
    ``(m, e)`` with ``m . x + e <= 0`` inside, as scipy's ``ConvexHull.equations``): the
    largest margin over the facets that separate them; negative where the hole enters it."""
    ends = np.stack([point, point - depth * normal])
    rim = radius * np.sqrt(np.clip(1.0 - (hull[:, :3] @ normal) ** 2, 0.0, 1.0))
    return float(((ends @ hull[:, :3].T + hull[:, 3]).min(axis=0) - rim).max())


def cylinder_between(
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    radius: float,
    start: float,
    stop: float,
) -> bd.Solid:
    """Cylinder on the axis through ``point`` along ``-normal`` between two depths (mm)."""
    return bd.Solid.make_cylinder(radius, stop - start, bd_plane(point - start * normal, -normal))
