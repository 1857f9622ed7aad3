"""The notes a design's solids carry: what the features did not fit, cut short or left out,
one line each, naming the tiles, hinges or route steps as runs of ids."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.clearance import HingeReliefs
from drawstring.cad.features import BEND_RADIUS_SLACK_MM
from drawstring.cad.hinge_frame import StripNeighbours, hinge_strip_lengths
from drawstring.cad.hinge_parts import StripHoles, strip_hole_wall_mm
from drawstring.cad.hinge_pins import PinPlan
from drawstring.cad.magnets_labels import MagnetPair
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.tiling.linkage import id_runs

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

#: Notes list at most this many runs of ids (then how many more there are).
MAX_RUNS = 12


def id_ranges(ids: Iterable[int]) -> str:
    """Sorted ids as runs, ``0-3, 7, 9-10``, the first :data:`MAX_RUNS` of them."""
    return id_runs(ids, MAX_RUNS)


def bend_notes(
    min_radius: NDArray[np.float64], steps: NDArray[np.int64], profile: Profile
) -> list[str]:
    """One note for all route steps whose channel or lift bore bends tighter than the profile
    allows."""
    tight = np.flatnonzero(min_radius < profile.min_bend_radius_mm - BEND_RADIUS_SLACK_MM)
    if not len(tight):
        return []
    worst = int(tight[np.argmin(min_radius[tight])])
    return [
        f"{len(tight)} of {len(steps)} route steps bend tighter than the profile's "
        f"{profile.min_bend_radius_mm:g} mm: bend radius down to {min_radius[worst]:.2f} mm "
        f"(route.json step {worst}, counted from 0; tile {int(steps[worst, 1])})"
        + (f"; steps {id_ranges(tight)}" if len(tight) > 1 else "")
    ]


def strip_notes(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
) -> list[str]:
    """One note for the hinge strips shortened to keep a wall from the other strips of their
    tiles (:func:`~drawstring.cad.hinge_frame.hinge_strip_lengths`)."""
    half = 0.5 * profile.hinge_pad_length_mm
    lengths = np.array(
        [
            hinge_strip_lengths(flat[a], int(ca), flat[b], int(cb), side, profile, crowd)
            for (a, ca, b, cb), side, crowd in zip(hinge_rows, sides, crowds, strict=True)
        ]
    ).reshape(-1, 2)
    short = np.flatnonzero((lengths < half - 1e-9).any(axis=1))
    if not len(short):
        return []
    return [
        f"{int((lengths < half - 1e-9).sum())} of {lengths.size} hinge strip halves run less "
        f"than the profile's {half:g} mm into their tiles (down to {lengths.min():.2f} mm), so "
        f"that the strips of a tile's corners keep a wall apart (hinges {id_ranges(short)})"
    ]


def hole_notes(holes: Sequence[StripHoles], profile: Profile) -> list[str]:
    """One note for the screw or staple holes of the hinge strips that found no room."""
    missing = [h for h, plan in enumerate(holes) if any(plan.missing)]
    if not missing:
        return []
    count = sum(sum(plan.missing) for plan in holes)
    total = count + sum(plan.made for plan in holes)
    bare = sum(
        not points and lost > 0
        for plan in holes
        for points, lost in zip(plan.points, plan.missing, strict=True)
    )
    kind = holes[missing[0]].kind
    note = (
        f"{count} of {total} {kind} holes left out: no room for them "
        f"{strip_hole_wall_mm(profile):g} mm from their tiles' edges (hinges "
        f"{id_ranges(missing)})"
    )
    if bare:
        note += (
            f"; {bare} strip halves have none left: glue those, or use fewer, larger tiles "
            "(--tiles)"
        )
    return [note]


def relief_notes(
    reliefs: HingeReliefs, hinge_rows: NDArray[np.int64], clearance_mm: float
) -> list[str]:
    """What the hinge reliefs cut, and the hinges they left alone."""
    notes = []
    relieved = len(hinge_rows) - len(reliefs.skipped)
    if relieved:
        one_sided = (
            f"; {reliefs.one_sided} pairs that overlap below the hinge have one tile cut "
            f"{clearance_mm:g} mm clear of the other's side face instead, within "
            f"{reliefs.one_sided_reach_mm:.2g} mm of the hinge"
            if reliefs.one_sided
            else ""
        )
        notes.append(
            f"{relieved} hinges relieved for printing: both tiles' side faces are cut back "
            f"{0.5 * clearance_mm:g} mm along the edge at the hinge, tapering out within "
            f"{reliefs.reach_max_mm:.2g} mm of it{one_sided}, so that hinged tiles stay "
            f"{clearance_mm:g} mm apart; the TPU pad bridges the cut"
        )
    if reliefs.deep:
        tiles = sorted({int(t) for h in reliefs.deep for t in hinge_rows[h, [0, 2]]})
        notes.append(
            f"{len(reliefs.deep)} of them cut deeper, up to {100 * reliefs.share_max:.2g} % of "
            f"a tile (tiles {id_ranges(tiles)}): each cut stays a wall clear of the tile's "
            "string channel, lift bore and hinge strips"
        )
    if reliefs.hollowed:
        apart = [cut for cut, _ in reliefs.apart]
        tiles = [t for t, cuts in sorted(reliefs.hollows.items()) if len(cuts) > apart.count(t)]
        notes.append(
            f"{len(reliefs.hollowed)} of them, where no plane parts the tiles without cutting "
            f"into a string channel or hinge strip, have one tile (tiles {id_ranges(tiles)}) "
            f"lose what lies within {clearance_mm:g} mm of the other, clear of its string "
            "channel, lift bore and other hinges' strips"
        )
    if reliefs.apart:
        notes.append(
            f"{len(reliefs.apart)} pairs of tiles not hinged together came closer than "
            f"{clearance_mm:g} mm in the flat pose: "
            + ", ".join(
                f"tile {cut} loses what lies that near tile {other}" for cut, other in reliefs.apart
            )
            + ", clear of its string channel, lift bore and hinge strips"
        )
    if reliefs.skipped:
        tiles = sorted({int(t) for h in reliefs.skipped for t in hinge_rows[h, [0, 2]]})
        notes.append(
            f"{len(reliefs.skipped)} hinges were not relieved for printing (a relief would cut "
            "away half a tile or into its string channel or hinge strips): tiles "
            f"{id_ranges(tiles)} may print joined there"
        )
    return notes


def pin_notes(plans: Sequence[PinPlan]) -> list[str]:
    """Notes on the TPU pins cut short or left out, one line each, naming the hinges."""
    total = 2 * len(plans)
    short = [h for h, plan in enumerate(plans) if any(plan.short)]
    missing = [h for h, plan in enumerate(plans) if None in plan.pins]
    count_short = sum(sum(plan.short) for plan in plans)
    count_missing = sum(pin is None for plan in plans for pin in plan.pins)
    notes = []
    if count_short:
        notes.append(
            f"{count_short} of {total} hinge pins end short of the opposite face to clear a "
            f"string channel, a lift bore or another hinge (hinges {id_ranges(short)})"
        )
    if count_missing:
        notes.append(
            f"{count_missing} of {total} hinge pins left out, no room for them on their tiles: "
            f"those pads are held by their recess only (hinges {id_ranges(missing)})"
        )
    return notes


def left_out_notes(left_out: Sequence[MagnetPair], made: int) -> list[str]:
    """The magnet pairs left out because their pockets fit nowhere on their faces."""
    if not left_out:
        return []
    return [
        f"{len(left_out)} of {made} magnet pairs left out: their {left_out[0].diameter_mm:.2f} "
        "mm pockets fit nowhere on their side faces (tiles "
        + ", ".join(f"{r.tile_a}/{r.tile_b}" for r in left_out)
        + "); other pairs join the same parts"
    ]
