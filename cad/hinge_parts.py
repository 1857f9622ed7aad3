"""Hinge parts, each dimensioned from a Profile: the strip joining two tiles' corners
(:func:`hinge_pad`) as a TPU pad keyed by pins or a dovetail, a rubber strip glued into a recess
or a plywood strip screwed or stapled on; the screw and staple holes (:func:`strip_hole_plan`)
and what a hinge leaves on the labelled face (:func:`hinge_face_footprints`).  The strip's
layout is :mod:`.hinge_frame`'s, the pins' planning :mod:`.hinge_pins`'."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import TOOL_OVERSHOOT_MM, Footprint, footprint_margin
from drawstring.cad.hinge_frame import (
    HingeFrame,
    StripNeighbours,
    cylinder_between,
    hinge_frame,
    place_holes,
    slab,
)
from drawstring.cad.hinge_pins import HingePins, pin_radius, plan_pins
from drawstring.cad.kernel import clean_solid, fuse
from drawstring.cad.paths import unit_vector
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


#: Glue recess depth as a fraction of the rubber strip thickness.
GLUE_RECESS_DEPTH_FRACTION = 0.5


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


def _tpu_pad(
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]],
    frame: HingeFrame,
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
    recess = slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, thickness)
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
            # the hole starts at the recess floor, like the pin: cut from above the surface
            # through the recess, OCCT leaves it uncut on some hinges
            tools[index].append(cylinder_between(pin.point, frame.normal, radius, thickness, stop))
            # The pin starts at the strip's underside: a pin starting inside the strip (the
            # same union where the strip covers it) leaves OCCT's fuse non-manifold on some
            # hinges.
            keys.append(cylinder_between(pin.point, frame.normal, radius, thickness, pin.depth))
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
                    if footprint_margin(tile, corner + distance * direction, frame.normal)
                    >= 0.5 * key_width + wall
                ),
                None,
            )
            if inner is None or half - inner < 0.5 * width:
                notes.append("dovetail key does not fit in the pad length")
                continue
            segment = np.stack([corner + inner * direction, corner + half * direction])
            key = slab(frame, segment, key_width, 0.5 * thickness, 2.0 * thickness)
            tools[index].append(key)
            keys.append(key)
    pad = None
    if build_pad:
        pad = clean_solid(fuse(slab(frame, frame.points, width, 0.0, thickness), keys))
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
    frame = hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = GLUE_RECESS_DEPTH_FRACTION * thickness
    recess = (slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, depth),)
    pad = slab(frame, frame.points, width, depth - thickness, depth) if build_pad else None
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
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]], frame: HingeFrame, profile: Profile
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
            found, lost = place_holes(
                tile, corner, direction, frame.normal, (half / 3, 2 * half / 3), radius, wall,
                half - radius, depth,
            )  # fmt: skip
        else:
            across = 0.25 * width * unit_vector(np.cross(frame.normal, direction))
            found, lost = [], 0
            for shift in (across, -across):
                hole, miss = place_holes(
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
    frame = hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
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
    frame = hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    holes = _strip_holes_on(tiles, frame, profile)
    tools = tuple(
        tuple(
            cylinder_between(point, frame.normal, holes.radius, -TOOL_OVERSHOOT_MM, holes.depth)
            for point in points
        )
        for points in holes.points
    )
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    pad = slab(frame, frame.points, width, -thickness, 0.0) if build_pad else None
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
        frame = hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
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
    if side == HingeSide.BOTTOM:
        frame = hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
        for kept in found:
            kept.append((frame.points, 0.5 * profile.hinge_width_mm))
    for kept, pin in zip(found, pins or (None, None), strict=True):
        if pin is None:
            continue
        if side == HingeSide.BOTTOM:
            kept.append((pin.point[None], pin_radius(profile)))
        elif pin.through:
            kept.append(((pin.point - pin.depth * pin.normal)[None], pin_radius(profile)))
    return found
