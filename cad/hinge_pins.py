"""The TPU pins of a through-holes hinge (:func:`plan_pins`), placed at the strip's inner ends
and kept a wall away from the tiles' other features, described as unions of balls
(:class:`KeepOut`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.hinge_frame import StripNeighbours, depth_to_opposite, hinge_frame, place_holes
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


#: A TPU hinge pin cut shorter than this many of its radii (to clear a channel or another pin)
#: is left out: a stub that short does not key the pad.
MIN_PIN_LENGTH_RADII = 1.0


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


def tube_keep_out(points: NDArray[np.float64], radius: float) -> KeepOut:
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
    return tube_keep_out(np.stack([start, pin.point - pin.depth * pin.normal]), pin_radius(profile))


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
    frame = hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = 0.5 * profile.hinge_thickness_mm
    radius = float(np.hypot(0.5 * profile.hinge_width_mm, depth))
    found = []
    for (corner, direction), length in zip(frame.halves, frame.lengths, strict=True):
        start = corner - depth * frame.normal
        found.append(tube_keep_out(np.stack([start, start + length * direction]), radius))
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
    frame = hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
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
        points, _ = place_holes(
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
                points, _ = place_holes(
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
        depth, through = depth_to_opposite(tile, side, point, frame.normal)
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
