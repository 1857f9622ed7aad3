"""Hinge parts, each dimensioned from a Profile: the strip joining two tiles' corners
(:func:`hinge_pad`) as a TPU pad keyed by pins or a dovetail, a rubber strip glued into a recess
or a plywood strip screwed or stapled on; the pins' planning around the tiles' other features
(:func:`plan_pins`, :class:`KeepOut`), the screw and staple holes (:func:`strip_hole_plan`) and
what a hinge leaves on the labelled face (:func:`hinge_face_footprints`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import (
    TOOL_OVERSHOOT_MM,
    Footprint,
    _footprint_margin,
    _plane,
    _vec,
    feature_wall_mm,
)
from drawstring.cad.kernel import clean_solid, fuse
from drawstring.cad.paths import FACE_BOTTOM, FACE_TOP, face_planes, unit_vector
from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


HingeSide = Literal["top", "bottom"]


#: Glue recess depth as a fraction of the rubber strip thickness.
GLUE_RECESS_DEPTH_FRACTION = 0.5
#: A TPU hinge pin cut shorter than this many of its radii (to clear a channel or another pin)
#: is left out: a stub that short does not key the pad.
MIN_PIN_LENGTH_RADII = 1.0


#: Per tile of a hinge (a, b): the other corners of its hinge face that hold hinge strips, or
#: None for all of them (see :func:`strip_room`).
StripNeighbours = tuple[Sequence[int] | None, Sequence[int] | None]


# --------------------------------------------------------------------------------------------
# hinges


@dataclass(frozen=True)
class HingeParts:
    """What one hinge adds: a separate part (TPU pad or rubber strip) and tools for its tiles.

    Attributes
    ----------
    pad : the part, or None when only the tools were asked for.
    tools_a, tools_b : tools to subtract from tile a and from tile b.
    notes : interlock parts that did not fit and were left out.
    """

    pad: bd.Solid | None
    tools_a: tuple[bd.Solid, ...]
    tools_b: tuple[bd.Solid, ...]
    notes: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class _HingeFrame:
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
    neighbouring corners' strips overlapping in thin slivers made OCCT's cut of a tile fail."""
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
    frame = _hinge_frame(
        np.asarray(tile_a, dtype=np.float64),
        corner_a,
        np.asarray(tile_b, dtype=np.float64),
        corner_b,
        side,
        profile,
        neighbours,
    )
    return frame.lengths


def _hinge_frame(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> _HingeFrame:
    """The strip of a hinge: half the profile's pad length into each tile, less where its end
    would come within :func:`strip_room` of the centre of the tile's hinge face (the strips of
    neighbouring corners met there: their recesses overlapping in thin slivers made OCCT's
    cut of a tile fail)."""
    if side not in ("top", "bottom"):
        raise InputError(f"hinge side {side!r} must be 'top' or 'bottom'")
    for corner, name in ((corner_a, "corner_a"), (corner_b, "corner_b")):
        if corner not in (0, 1, 2, 3):
            raise InputError(f"{name} = {corner} must be a corner index 0..3")
    face = FACE_TOP if side == "top" else FACE_BOTTOM
    shift = 0 if side == "top" else 4
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
    return _HingeFrame(np.array(kept), normal, (halves[0], halves[1]), (lengths[0], lengths[1]))


def _strip_outline(points: NDArray[np.float64], width: float, normal: NDArray) -> bd.Face:
    """Planar face: the polyline ``points`` thickened to ``width`` with round ends and joints."""
    points = _merge_short_segments(points, width)
    if len(points) == 2:
        return _stadium(points[0], points[1], width, normal)
    wire = bd.Wire.make_polygon([_vec(p) for p in points], close=False)
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
        bd.Edge.make_line(_vec(a - across), _vec(b - across)),
        bd.Edge.make_three_point_arc(_vec(b - across), _vec(b + cap), _vec(b + across)),
        bd.Edge.make_line(_vec(b + across), _vec(a + across)),
        bd.Edge.make_three_point_arc(_vec(a + across), _vec(a - cap), _vec(a - across)),
    ]
    return bd.Face(bd.Wire(edges))


def _slab(
    frame: _HingeFrame, points: NDArray[np.float64], width: float, start: float, stop: float
) -> bd.Solid:
    """The strip outline between depths ``start`` and ``stop`` (mm, positive into the tiles)."""
    face = _strip_outline(points - start * frame.normal, width, frame.normal)
    return clean_solid(bd.Solid.extrude(face, _vec(-(stop - start) * frame.normal)))


def _depth_to_opposite(
    tile: NDArray[np.float64], side: HingeSide, point: NDArray[np.float64], normal: NDArray
) -> tuple[float, bool]:
    """Distance (mm) along ``-normal`` from ``point`` on the hinge face to the opposite face,
    shortest over a pin's rim when the faces are not parallel, and whether they are parallel."""
    centroids, normals = face_planes(tile)
    face = FACE_BOTTOM if side == "top" else FACE_TOP
    cosine = float(-normal @ normals[face])
    distance = float((centroids[face] - point) @ normals[face] / cosine)
    return distance, abs(abs(cosine) - 1.0) < 1e-12


def _place_holes(
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
    for a blind hole, see :func:`_footprint_margin`) and from the planes that cut the tile
    (``cuts``, see :func:`_cut_margin`), and how many stations never fit."""
    placed, missing = [], 0
    for station in stations:
        candidates = np.linspace(station, station + 4.0 * radius, 17)
        for distance in candidates[candidates <= limit + 1e-9]:
            point = corner + distance * direction
            if (
                _footprint_margin(tile, point, normal, depth) >= radius + wall
                and _cut_margin(tile, point, normal, radius, cuts, depth) >= wall
            ):
                placed.append(point)
                break
        else:
            missing += 1
    return placed, missing


def _cut_margin(
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


def _cylinder_between(
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    radius: float,
    start: float,
    stop: float,
) -> bd.Solid:
    """Cylinder on the axis through ``point`` along ``-normal`` between two depths (mm)."""
    return bd.Solid.make_cylinder(radius, stop - start, _plane(point - start * normal, -normal))


def pin_radius(profile: Profile) -> float:
    """Radius (mm) of a through-holes hinge's TPU pin: ``max(0.75 width, 1.5 nozzle)``."""
    return max(0.75 * profile.hinge_width_mm, 1.5 * profile.nozzle_mm)


@dataclass(frozen=True)
class KeepOut:
    """Solids a hinge pin keeps a wall away from, as a union of balls.

    Attributes
    ----------
    centres : (k, 3) float, mm, sampled densely (:data:`_KEEP_OUT_SPACING_MM`) along channels,
        lift bores, hinge strips and pins.
    radii : (k,) float, mm.
    """

    centres: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    radii: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def __add__(self, other: KeepOut) -> KeepOut:
        return KeepOut(
            np.vstack([self.centres, other.centres]), np.concatenate([self.radii, other.radii])
        )


#: Spacing (mm) of the balls of a :class:`KeepOut` along a centre line: the union of balls of
#: radius >= 0.3 mm this far apart falls short of the tube by under 0.005 mm.
_KEEP_OUT_SPACING_MM = 0.1


def _resample(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """A polyline ((k, 3) mm) with points added so that none are more than
    :data:`_KEEP_OUT_SPACING_MM` apart."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:], strict=True):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / _KEEP_OUT_SPACING_MM)))
        out.append(a + np.linspace(0.0, 1.0, count + 1)[1:, None] * (b - a))
    return np.vstack(out)


def _tube_keep_out(points: NDArray[np.float64], radius: float) -> KeepOut:
    centres = _resample(np.asarray(points, dtype=np.float64))
    return KeepOut(centres, np.full(len(centres), radius))


@dataclass(frozen=True)
class HingePin:
    """One TPU pin of a through-holes hinge and the hole it fills.

    Attributes
    ----------
    point : (3,) float, mm, where the pin's axis meets the hinge face plane.
    normal : (3,) float, the hinge face's outward normal; the pin runs along its opposite.
    depth : float, mm, how far below the hinge face the pin ends (it starts at the recess floor,
        ``hinge_thickness_mm`` deep).
    through : whether it ends on the opposite face (its hole is then cut on past that face).
    """

    point: NDArray[np.float64]
    normal: NDArray[np.float64]
    depth: float
    through: bool


#: Per tile half (tile a, tile b) of a hinge: its pin, or None where it has none.
HingePins = tuple[HingePin | None, HingePin | None]


@dataclass(frozen=True)
class PinPlan:
    """The pins of one through-holes hinge (:func:`plan_pins`).

    Attributes
    ----------
    pins : per tile (a, b), the pin or None where none fits.
    short : per tile, whether the pin was cut short to clear another feature.
    notes : one line per pin that does not fit, for the hinge's record.
    """

    pins: HingePins
    short: tuple[bool, bool]
    notes: tuple[str, ...] = field(default=())


def pin_keep_out(pin: HingePin, profile: Profile) -> KeepOut:
    """A planned pin as balls along its axis."""
    start = pin.point - profile.hinge_thickness_mm * pin.normal
    return _tube_keep_out(
        np.stack([start, pin.point - pin.depth * pin.normal]), pin_radius(profile)
    )


def strip_keep_outs(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> tuple[KeepOut, KeepOut]:
    """A TPU hinge's strip (the recess it sits in) as balls, the half in tile a and in tile b:
    from each hinged corner inward as far as the strip runs, half the strip thickness deep."""
    tile_a, tile_b = np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64)
    frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = 0.5 * profile.hinge_thickness_mm
    radius = float(np.hypot(0.5 * profile.hinge_width_mm, depth))
    found = []
    for (corner, direction), length in zip(frame.halves, frame.lengths, strict=True):
        start = corner - depth * frame.normal
        found.append(_tube_keep_out(np.stack([start, start + length * direction]), radius))
    return found[0], found[1]


def _clear_depth(
    point: NDArray[np.float64],
    axis: NDArray[np.float64],
    radius: float,
    start: float,
    stop: float,
    keep_out: KeepOut,
    wall: float,
) -> float:
    """The deepest end (mm, at most ``stop``) of a cylinder of ``radius`` on the axis
    ``point + t axis`` from ``t = start`` that stays ``wall`` away from every ball of
    ``keep_out``; below ``start`` when no length does."""
    if not len(keep_out.radii):
        return stop
    rel = keep_out.centres - point
    along = rel @ axis
    off_axis = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    reach = keep_out.radii + wall
    lateral = np.maximum(off_axis - radius, 0.0)
    near = lateral < reach
    # Axial half-extent of each inflated ball where it meets the infinite cylinder.
    half = np.sqrt(np.maximum(reach[near] ** 2 - lateral[near] ** 2, 0.0))
    low, high = along[near] - half, along[near] + half
    below = high > start  # balls wholly on the hinge face's side of the pin are no obstacle
    if not np.any(below):
        return stop
    if np.any(low[below] <= start):
        return start - 1.0
    return float(min(stop, low[below].min()))


def plan_pins(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    keep_out: tuple[KeepOut | None, KeepOut | None] = (None, None),
    neighbours: StripNeighbours = (None, None),
    cuts: tuple[NDArray[np.float64] | None, NDArray[np.float64] | None] = (None, None),
) -> PinPlan:
    """Where the TPU pins of a through-holes hinge go, one per tile (a "lollipop").

    Each pin sits at the inner end of the strip, slid inward until it keeps a wall from the
    tile's side faces, and runs from the recess floor to the opposite face (blind, one diameter
    short of it, when that face is tilted).  Where side faces leaning in leave no such room
    through the whole tile, the pin is blind: half the tile deep, or the shortest that keys
    the pad, whichever keeps its wall down to its end.  ``keep_out`` per tile (channels, lift
    bores, other hinges' strips and pins, see :class:`KeepOut`) cuts a pin short to keep a wall
    from them; a pin shorter than ``MIN_PIN_LENGTH_RADII`` radii is left out.

    ``keep_out`` entries are None for no other features (only the tile's edges limit the pin).
    ``cuts`` per tile: planes ``(n, d)`` that cut the tile (the hinge reliefs of
    :mod:`drawstring.cad.clearance`); a pin keeps its wall from them as from a side face.
    """
    tiles = (np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    radius = pin_radius(profile)
    wall = max(profile.nozzle_mm, 0.3)
    floor = profile.hinge_thickness_mm
    pins: list[HingePin | None] = []
    short = [False, False]
    notes: list[str] = []
    for index, (tile, (corner, direction), length, keep, cut, name) in enumerate(
        zip(tiles, frame.halves, frame.lengths, keep_out, cuts, ("a", "b"), strict=True)
    ):
        # the axis stays under the strip: a pin beyond its end would not hold it
        points, _ = _place_holes(
            tile, corner, direction, frame.normal, (length - radius,), radius, wall, length,
            cuts=cut,
        )  # fmt: skip
        blind = None
        if not points:
            # Side faces leaning in under the hinge corner (a curved design's tiles) leave no
            # room for a pin through the whole tile; a blind one keeps its wall only as deep
            # as it goes: half the tile, else the shortest pin that still keys the pad.
            span = abs(float((tile[4:8].mean(axis=0) - tile[0:4].mean(axis=0)) @ frame.normal))
            for tried in (0.5 * span, floor + 2.0 * MIN_PIN_LENGTH_RADII * radius):
                points, _ = _place_holes(
                    tile, corner, direction, frame.normal, (length - radius,), radius, wall,
                    length, tried, cut,
                )  # fmt: skip
                if points:
                    blind = tried
                    break
        if not points:
            notes.append(f"pin in tile {name} left out: it does not fit under the strip")
            pins.append(None)
            continue
        point = points[0]
        depth, through = _depth_to_opposite(tile, side, point, frame.normal)
        if not through:
            depth -= radius * 2.0  # tilted opposite face: keep the hole blind
        if blind is not None and blind < depth:
            depth, through = blind, False
        if keep is not None:
            clear = _clear_depth(point, -frame.normal, radius, floor, depth, keep, wall)
            if clear < depth:
                depth, through, short[index] = clear, False, True
        if depth - floor < MIN_PIN_LENGTH_RADII * radius:
            short[index] = False
            notes.append(f"pin in tile {name} left out: no room clear of the tile's other features")
            pins.append(None)
            continue
        pins.append(HingePin(point, frame.normal, float(depth), through))
    return PinPlan((pins[0], pins[1]), (short[0], short[1]), tuple(notes))


def _tpu_pad(
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]],
    frame: _HingeFrame,
    corners: tuple[int, int],
    side: HingeSide,
    profile: Profile,
    build_pad: bool,
    pins: HingePins | None,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Dual-material FDM pad: a TPU strip sunk into both tiles, keyed by pins or a dovetail."""
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    wall = max(profile.nozzle_mm, 0.3)
    recess = _slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, thickness)
    tools: tuple[list[bd.Solid], list[bd.Solid]] = ([recess], [recess])
    keys: list[bd.Solid] = []
    notes: list[str] = []
    if profile.hinge_interlock == "through-holes":
        if pins is None:
            plan = plan_pins(
                tiles[0], corners[0], tiles[1], corners[1], side, profile, neighbours=neighbours
            )
            pins = plan.pins
            notes += plan.notes
        radius = pin_radius(profile)
        for index, pin in enumerate(pins):
            if pin is None:
                continue
            stop = pin.depth + (TOOL_OVERSHOOT_MM if pin.through else 0.0)
            # the hole starts at the recess floor, like the pin: cutting it from above the
            # surface through the recess left it uncut on some hinges (OCCT)
            tools[index].append(_cylinder_between(pin.point, frame.normal, radius, thickness, stop))
            # The pin starts at the strip's underside: starting it inside the strip (which
            # the union makes no different where the strip covers it) left OCCT's fuse
            # non-manifold on some hinges.
            keys.append(_cylinder_between(pin.point, frame.normal, radius, thickness, pin.depth))
    else:
        for index, (tile, (corner, direction), half) in enumerate(
            zip(tiles, frame.halves, frame.lengths, strict=True)
        ):
            # Dovetail: a key 1.8 x wider than the strip just above it, held by the narrow neck.
            key_width = 1.8 * width
            inner = next(
                (
                    distance
                    for distance in np.linspace(0.0, half, 41)
                    if _footprint_margin(tile, corner + distance * direction, frame.normal)
                    >= 0.5 * key_width + wall
                ),
                None,
            )
            if inner is None or half - inner < 0.5 * width:
                notes.append("dovetail key does not fit in the pad length")
                continue
            segment = np.stack([corner + inner * direction, corner + half * direction])
            key = _slab(frame, segment, key_width, 0.5 * thickness, 2.0 * thickness)
            tools[index].append(key)
            keys.append(key)
    pad = None
    if build_pad:
        pad = clean_solid(fuse(_slab(frame, frame.points, width, 0.0, thickness), keys))
    return HingeParts(pad, tuple(tools[0]), tuple(tools[1]), tuple(notes))


def glue_recess(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Laser-cut rubber hinge: a shallow recess where the strip is glued, and the strip itself.

    The recess is ``GLUE_RECESS_DEPTH_FRACTION`` of the strip thickness deep and follows the
    strip outline (``hinge_width_mm`` wide, ``hinge_pad_length_mm`` long, shorter on small tiles:
    :func:`hinge_strip_lengths`); the strip (``pad``) sits in it and stands proud by the rest of
    its thickness.
    """
    tile_a, tile_b = np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float)
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = GLUE_RECESS_DEPTH_FRACTION * thickness
    recess = (_slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, depth),)
    pad = _slab(frame, frame.points, width, depth - thickness, depth) if build_pad else None
    return HingeParts(pad, recess, recess)


@dataclass(frozen=True)
class StripHoles:
    """Pilot holes of a plywood hinge strip (:func:`strip_hole_plan`).

    Attributes
    ----------
    points : per tile (a, b), where each hole's axis meets the hinge face (mm).
    missing : per tile, how many of its holes found no room (they are left out).
    normal : (3,) float, the hinge face's outward normal (the holes run along ``-normal``).
    radius, depth : float, mm.
    kind : ``"screw"`` (one per hole) or ``"staple"`` (one per pair of holes across the strip).
    """

    points: tuple[tuple[NDArray[np.float64], ...], tuple[NDArray[np.float64], ...]]
    missing: tuple[int, int]
    normal: NDArray[np.float64]
    radius: float
    depth: float
    kind: Literal["screw", "staple"]

    @property
    def made(self) -> int:
        """How many holes the strip gets."""
        return len(self.points[0]) + len(self.points[1])

    @property
    def fasteners(self) -> int:
        """Screws, or staples (a staple needs both holes of its pair), the strip takes."""
        if self.kind == "screw":
            return self.made
        return sum(len(points) == 2 for points in self.points)


def strip_hole_wall_mm(profile: Profile) -> float:
    """Wood a strip's pilot hole keeps from the tile's side faces (mm): a tool's width in a
    solid tile; in a box tile the side panels take the outer panel thickness (their finger
    joints reach through the top and bottom panels' edges), so half a tool's width (at least
    1 mm) is kept beyond them."""
    if profile.panel_thickness_mm > 0:
        return profile.panel_thickness_mm + max(0.5 * profile.tool_diameter_mm, 1.0)
    return max(profile.tool_diameter_mm, 1.0)


def _strip_holes_on(
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]], frame: _HingeFrame, profile: Profile
) -> StripHoles:
    """The pilot holes of the strip laid out by ``frame`` (see :func:`strip_hole_plan`)."""
    width = profile.hinge_width_mm
    wall = strip_hole_wall_mm(profile)
    depth = 0.25 * profile.thickness_mm
    screws = profile.hinge_interlock == "screws"
    radius = 0.5 * float(np.clip(0.12 * width, 2.0, 5.0)) if screws else 0.5
    points: list[tuple[NDArray[np.float64], ...]] = []
    missing: list[int] = []
    for tile, (corner, direction), half in zip(tiles, frame.halves, frame.lengths, strict=True):
        # every hole stays under the strip: one beyond its end would hold nothing
        if screws:
            found, lost = _place_holes(
                tile, corner, direction, frame.normal, (half / 3, 2 * half / 3), radius, wall,
                half - radius, depth,
            )  # fmt: skip
        else:
            across = 0.25 * width * unit_vector(np.cross(frame.normal, direction))
            found, lost = [], 0
            for shift in (across, -across):
                hole, miss = _place_holes(
                    tile, corner + shift, direction, frame.normal, (half / 2,), radius, wall,
                    half - radius, depth,
                )  # fmt: skip
                found += hole
                lost += miss
        points.append(tuple(found))
        missing.append(lost)
    return StripHoles(
        (points[0], points[1]),
        (missing[0], missing[1]),
        frame.normal,
        radius,
        depth,
        "screw" if screws else "staple",
    )


def strip_hole_plan(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> StripHoles:
    """Where a plywood hinge strip is screwed or stapled to its two tiles.

    Screws: two holes per tile at a third and two thirds of the half strip, diameter
    ``clip(0.12 width, 2, 5) mm``; staples: one pair of 1 mm holes per tile across the strip.
    Holes are a quarter of the tile thickness deep; each slides inward along the strip (staying
    under it) until it keeps :func:`strip_hole_wall_mm` from the tile's side faces down to that
    depth, and one that finds no room is left out (counted in ``missing``).
    """
    tiles = (np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    return _strip_holes_on(tiles, frame, profile)


def strip_holes(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Plywood hinge: the rubber strip lying on the face and the pilot holes of
    :func:`strip_hole_plan` for screws or staples.  ``pad`` is the strip, touching the face.
    Holes left out are not noted here: the design counts them for all hinges at once."""
    tiles = (np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    holes = _strip_holes_on(tiles, frame, profile)
    tools = tuple(
        tuple(
            _cylinder_between(point, frame.normal, holes.radius, -TOOL_OVERSHOOT_MM, holes.depth)
            for point in points
        )
        for points in holes.points
    )
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    pad = _slab(frame, frame.points, width, -thickness, 0.0) if build_pad else None
    return HingeParts(pad, tools[0], tools[1])


def hinge_pad(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    pins: HingePins | None = None,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """The hinge part and tile tools for the profile's process.

    Parameters
    ----------
    tile_a, tile_b : (8, 3) float, mm, the two tiles in the fabrication (flat) pose; their hinge
        faces lie in one plane.
    corner_a, corner_b : hinged corners 0..3.
    side : ``"top"`` or ``"bottom"``: the face whose corners the hinge joins.
    profile : ``hinge_interlock`` picks the kind.  ``through-holes`` / ``dovetail``: a TPU pad
        ``hinge_thickness_mm`` thick and ``hinge_width_mm`` wide running ``hinge_pad_length_mm``
        / 2 from each corner into its tile (less on small tiles: :func:`hinge_strip_lengths`),
        sunk flush into both tiles, keyed by a TPU pin through each tile (diameter
        ``max(1.5 width, 3 nozzle)``, see :func:`plan_pins`) or by a key 1.8 x wider under the
        strip.  ``glue-recess``: :func:`glue_recess`.  ``screws`` / ``staples``:
        :func:`strip_holes`.
    build_pad : also build the part (tile jobs only need the tools).
    pins : ``through-holes`` only: the pins as :func:`plan_pins` placed them around the tiles'
        other features (default: planned here, clear of the tiles' edges only).
    neighbours : per tile, the other corners of its hinge face holding strips, which the strip
        stops short of (:func:`strip_room`; default: all of them).

    Returns
    -------
    HingeParts: the pad (touching the tiles once the tools are cut, not overlapping them) and
    the tools to subtract from tile a and from tile b.
    """
    tile_a = np.asarray(tile_a, dtype=np.float64)
    tile_b = np.asarray(tile_b, dtype=np.float64)
    if profile.hinge_interlock in ("through-holes", "dovetail"):
        frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
        return _tpu_pad(
            (tile_a, tile_b),
            frame,
            (corner_a, corner_b),
            side,
            profile,
            build_pad,
            pins,
            neighbours,
        )
    if profile.hinge_interlock == "glue-recess":
        return glue_recess(tile_a, corner_a, tile_b, corner_b, side, profile, build_pad, neighbours)
    return strip_holes(tile_a, corner_a, tile_b, corner_b, side, profile, build_pad, neighbours)


# --------------------------------------------------------------------------------------------
# what a hinge leaves on the labelled face


def hinge_face_footprints(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    pins: HingePins | None = None,
    neighbours: StripNeighbours = (None, None),
) -> tuple[list[Footprint], list[Footprint]]:
    """What a hinge puts on the bottom faces of tile a and of tile b (where tile numbers are
    engraved): a bottom hinge's strip (its recess, or the strip glued or screwed on; the holes
    under it lie inside) and the pins whose holes open there (a bottom hinge's pins, a top
    hinge's pins that run through)."""
    tile_a, tile_b = np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64)
    found: tuple[list[Footprint], list[Footprint]] = ([], [])
    if side == "bottom":
        frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
        for kept in found:
            kept.append((frame.points, 0.5 * profile.hinge_width_mm))
    for kept, pin in zip(found, pins or (None, None), strict=True):
        if pin is None:
            continue
        if side == "bottom":
            kept.append((pin.point[None], pin_radius(profile)))
        elif pin.through:
            kept.append(((pin.point - pin.depth * pin.normal)[None], pin_radius(profile)))
    return found
