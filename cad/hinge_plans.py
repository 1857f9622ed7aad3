"""What every hinge of a design needs planned before its tiles are cut: which other corners
of a tile's hinge face hold strips (:func:`strip_neighbours`), the TPU pins placed clear of the
tiles' other features (:func:`plan_all_pins`) and the plywood strips' pilot holes
(:func:`strip_hole_plans`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull

from drawstring.cad.clearance import (
    HingeReliefs,
    ReliefKeepOut,
    apart_reliefs,
    hinge_reliefs,
    hollow_room,
)
from drawstring.cad.feature_common import feature_wall_mm
from drawstring.cad.features import channel_keep_out
from drawstring.cad.hinge_frame import StripNeighbours, strip_min_reach_mm
from drawstring.cad.hinge_parts import StripHoles, strip_hole_plan
from drawstring.cad.hinge_pins import KeepOut, PinPlan, pin_keep_out, plan_pins, strip_keep_outs
from drawstring.cad.memo import Memo, content_key
from drawstring.cad.paths import SIDE_TOP_FACE
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


def strip_neighbours(
    hinges: NDArray[np.int64], hinge_side: Sequence[HingeSide]
) -> list[StripNeighbours]:
    """Per hinge ``(tile_a, corner_a, tile_b, corner_b)``, the other corners of tile a's and of
    tile b's hinge face that hold strips too (hinges on the same face of the same tile), which
    the strip keeps a wall from (:func:`~drawstring.cad.hinge_frame.strip_room`)."""
    rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    held: dict[tuple[int, str], set[int]] = {}
    for (a, ca, b, cb), side in zip(rows.tolist(), hinge_side, strict=True):
        held.setdefault((a, side), set()).add(ca)
        held.setdefault((b, side), set()).add(cb)
    return [
        (
            tuple(sorted(held[(a, side)] - {ca})),
            tuple(sorted(held[(b, side)] - {cb})),
        )
        for (a, ca, b, cb), side in zip(rows.tolist(), hinge_side, strict=True)
    ]


def _feature_keep_outs(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
) -> tuple[list[KeepOut], list[list[tuple[int, KeepOut]]]]:
    """Per tile, its channels and lift bores as balls, and its hinges' strips ``(hinge,
    balls)``: new lists (the caller may change them) of what is worked out once per content
    of the arrays (:class:`~.memo.Memo`: the reliefs and the pins ask it of the same ones)."""
    key = content_key(flat, hinge_rows, list(sides), steps, lifts, profile, crowds)
    keep, strips = _KEEP_OUTS.get(
        key, lambda: _feature_keep_outs_of(flat, hinge_rows, sides, steps, lifts, profile, crowds)
    )
    return list(keep), [list(s) for s in strips]


_KEEP_OUTS: Memo[tuple[list[KeepOut], list[list[tuple[int, KeepOut]]]]] = Memo()


def _feature_keep_outs_of(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
) -> tuple[list[KeepOut], list[list[tuple[int, KeepOut]]]]:
    keep = [KeepOut() for _ in flat]
    for _, tile, enter, leave in steps:
        keep[tile] += channel_keep_out(flat[tile], int(enter), int(leave), profile)
    for tile, side in lifts:
        keep[tile] += channel_keep_out(flat[tile], int(side), SIDE_TOP_FACE, profile)
    strips: list[list[tuple[int, KeepOut]]] = [[] for _ in flat]
    for hinge, ((a, ca, b, cb), side) in enumerate(zip(hinge_rows, sides, strict=True)):
        in_a, in_b = strip_keep_outs(
            flat[a], int(ca), flat[b], int(cb), side, profile, crowds[hinge]
        )
        strips[a].append((hinge, in_a))
        strips[b].append((hinge, in_b))
    return keep, strips


def design_reliefs(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    clearance_mm: float,
) -> HingeReliefs | None:
    """The hinge reliefs (:func:`~drawstring.cad.clearance.hinge_reliefs`) of tiles printed
    together (``clearance_mm > 0``), measured against what the tiles hold
    (:func:`relief_keep_outs`), with tiles not hinged together that still come closer than the
    clearance cut apart (:func:`~drawstring.cad.clearance.apart_reliefs`); None for loose
    tiles or no hinges.

    Worked out once per content of the arrays (:class:`~.memo.Memo`): the route's checks, the
    CAD stage's and the solids ask it of the same ones.  The result is shared: read-only."""
    if not (clearance_mm > 0 and len(hinge_rows)):
        return None
    key = content_key(flat, hinge_rows, list(sides), steps, lifts, profile, clearance_mm)
    return _RELIEFS.get(
        key, lambda: _design_reliefs(flat, hinge_rows, sides, steps, lifts, profile, clearance_mm)
    )


_RELIEFS: Memo[HingeReliefs] = Memo()


def _design_reliefs(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    clearance_mm: float,
) -> HingeReliefs:
    crowds = strip_neighbours(hinge_rows, sides)
    keep_out = relief_keep_outs(flat, hinge_rows, sides, steps, lifts, profile, crowds)
    wall = feature_wall_mm(profile)
    reliefs = hinge_reliefs(flat, hinge_rows, sides, clearance_mm, keep_out, wall)
    return apart_reliefs(flat, hinge_rows, reliefs, clearance_mm, keep_out, wall)


@dataclass(frozen=True)
class ReliefShortfall:
    """Hinges of tiles printed together that no relief clears (:func:`relief_shortfall`).

    Attributes
    ----------
    hinges : the hinges (indices) left unrelieved.
    pairs : tiles not hinged together that come closer than the clearance, left so.
    tiles : ``(tile_a, tile_b)`` of the hinge or pair with the least room.
    have : mm, how far that hinge's features lie outside the other tile, at best
        (:func:`~drawstring.cad.clearance.hollow_room`; negative where they reach into it).
    need : mm, the print clearance and a wall.
    """

    hinges: tuple[int, ...]
    pairs: tuple[tuple[int, int], ...]
    tiles: tuple[int, int]
    have: float
    need: float


def relief_shortfall(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    clearance_mm: float,
) -> ReliefShortfall | None:
    """The hinges the CAD stage would leave unrelieved, and the tiles not hinged together it
    would leave closer than ``clearance_mm`` (:func:`design_reliefs` on the same arrays: those
    tiles would print welded), with the room of the one nearest to a relief; None where every
    tile is kept apart (or the tiles are made loose).  Arrays only: asked before any solid is
    built."""
    reliefs = design_reliefs(flat, hinge_rows, sides, steps, lifts, profile, clearance_mm)
    if reliefs is None or not (reliefs.skipped or reliefs.crowded):
        return None
    crowds = strip_neighbours(hinge_rows, sides)
    keep_out = relief_keep_outs(flat, hinge_rows, sides, steps, lifts, profile, crowds)
    rows = np.asarray(hinge_rows, dtype=np.int64).reshape(-1, 4)
    pairs = [(int(rows[h, 0]), int(rows[h, 2]), h) for h in reliefs.skipped]
    pairs += [(a, b, -1) for a, b in reliefs.crowded]  # -1: no hinge, every strip counts
    have, a, b = min((hollow_room(flat, a, b, h, keep_out), a, b) for a, b, h in pairs)
    return ReliefShortfall(
        reliefs.skipped, reliefs.crowded, (a, b), have, clearance_mm + feature_wall_mm(profile)
    )


def strip_room_mm(
    profile: Profile,
    tiles: NDArray[np.float64],
    hinges: NDArray[np.int64],
    sides: Sequence[HingeSide],
) -> tuple[float, float] | None:
    """(have, need) mm at the hinged corner with the least room for its hinge strip: the
    distance from the corner to the centre of its tile's hinge face (on ``sides``), in both
    tiles of each hinge, against what the strip needs there
    (:func:`~drawstring.cad.hinge_frame.strip_min_reach_mm`: more where a corner holding
    another strip on the same face is close in angle); None without hinges."""
    rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    if not len(rows):
        return None
    corners = []
    for (a, ca, b, cb), side, crowd in zip(
        rows.tolist(), sides, strip_neighbours(rows, sides), strict=True
    ):
        shift = 0 if side == HingeSide.TOP else 4
        for tile, k, others in ((a, ca, crowd[0]), (b, cb, crowd[1])):
            ring = tiles[tile, shift : shift + 4]
            have = float(np.linalg.norm(ring.mean(axis=0) - ring[k]))
            corners.append((have, strip_min_reach_mm(profile, ring, k, others)))
    return min(corners, key=lambda c: c[0] / c[1])


def relief_keep_outs(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
) -> ReliefKeepOut:
    """What a deep hinge relief (:func:`~drawstring.cad.clearance.hinge_reliefs`) of a tile
    keeps clear of, by (tile, hinge): the tile's string channels and lift bores, the strips of
    its other hinges, and (``own_strip``) the inner half of the hinge's own strip, where its
    pad is seated (the outer half spans the cut, as at every relieved hinge)."""
    keep, strips = _feature_keep_outs(flat, hinge_rows, sides, steps, lifts, profile, crowds)

    def of(tile: int, hinge: int, own_strip: bool = True) -> KeepOut:
        found = keep[tile]
        for other, strip in strips[tile]:
            if other != hinge:
                found = found + strip
            elif own_strip:  # balls from the corner inward: the inner half
                inner = slice(len(strip.radii) // 2, None)
                found = found + KeepOut(strip.centres[inner], strip.radii[inner])
        return found

    return of


def plan_all_pins(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
    reliefs: Mapping[int, Sequence[NDArray[np.float64]]],
    hollows: Mapping[int, Sequence[NDArray[np.float64]]] | None = None,
) -> list[PinPlan]:
    """The TPU pins of every through-holes hinge, each kept a wall away from its tile's
    channels and lift bores, the other hinges' strips, the pins planned before it (hinge
    order) and the planes of its tile's hinge reliefs (tile -> planes), so that no pin blocks
    the string, no two holes merge and no relief opens a hole; a pin that would come within a
    wall of a convex relief cut from its tile (``hollows``: tile -> (k, 3) points) is left
    out."""
    keep, strips = _feature_keep_outs(flat, hinge_rows, sides, steps, lifts, profile, crowds)

    def others(tile: int, hinge: int) -> KeepOut:
        found = keep[tile]
        for other, strip in strips[tile]:
            if other != hinge:
                found = found + strip
        return found

    plans = []
    for hinge, ((a, ca, b, cb), side) in enumerate(zip(hinge_rows, sides, strict=True)):
        plan = plan_pins(
            flat[a],
            int(ca),
            flat[b],
            int(cb),
            side,
            profile,
            (others(a, hinge), others(b, hinge)),
            crowds[hinge],
            (planes_of(reliefs, a), planes_of(reliefs, b)),
        )
        if hollows:
            plan = _clear_of_hollows(
                plan, (hollows.get(int(a), ()), hollows.get(int(b), ())), profile
            )
        for tile, pin in zip((a, b), plan.pins, strict=True):
            if pin is not None:
                keep[tile] = keep[tile] + pin_keep_out(pin, profile)
        plans.append(plan)
    return plans


def _clear_of_hollows(
    plan: PinPlan, hollows: tuple[Sequence[NDArray[np.float64]], ...], profile: Profile
) -> PinPlan:
    """``plan`` without the pins that come within a wall of their tile's convex relief cuts
    (a ball of the pin lies a wall outside a cut where it does outside one of its planes)."""
    pins, short, notes = list(plan.pins), list(plan.short), list(plan.notes)
    for index, (pin, cuts) in enumerate(zip(plan.pins, hollows, strict=True)):
        if pin is None:
            continue
        balls = pin_keep_out(pin, profile)
        for points in cuts:
            planes = ConvexHull(points).equations
            height = (balls.centres @ planes[:, :3].T + planes[:, 3]).max(axis=1)
            if np.any(height < balls.radii + feature_wall_mm(profile)):
                pins[index], short[index] = None, False  # left out, not also cut short
                notes.append(f"pin in tile {'ab'[index]} left out: its hinge's relief cuts there")
                break
    return PinPlan((pins[0], pins[1]), (short[0], short[1]), tuple(notes))


def planes_of(
    reliefs: Mapping[int, Sequence[NDArray[np.float64]]], tile: int
) -> NDArray[np.float64] | None:
    """The planes ``(n, d)`` that cut ``tile`` as one ``(k, 4)`` array, or None."""
    found = reliefs.get(int(tile))
    return None if not found else np.asarray(found, dtype=np.float64).reshape(-1, 4)


def strip_hole_plans(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    profile: Profile,
    crowds: Sequence[StripNeighbours] | None = None,
) -> list[StripHoles]:
    """The pilot holes of every plywood hinge strip (:func:`strip_hole_plan`) on the flat
    tiles, hinge by hinge; ``crowds`` as :func:`strip_neighbours` gives them (computed when
    not passed)."""
    if crowds is None:
        crowds = strip_neighbours(hinge_rows, sides)
    return [
        strip_hole_plan(flat[a], int(ca), flat[b], int(cb), side, profile, crowd)
        for (a, ca, b, cb), side, crowd in zip(hinge_rows, sides, crowds, strict=True)
    ]
