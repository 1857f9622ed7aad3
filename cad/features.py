"""Fabrication features cut into (or added next to) the tiles, each dimensioned from a Profile.

Every function takes tile vertices ((8, 3) float, mm, contract order; see :mod:`.tiles`) and
returns build123d solids: *tools* to subtract from a tile, or separate parts (hinge pads, rubber
strips).  Tools poke ``TOOL_OVERSHOOT_MM`` out of the faces they open so that no boolean meets a
coplanar face.

Route sides: ``0..3`` are the tile's side faces; ``SIDE_TOP_FACE`` (4) means the top face (a lift
point, where the string leaves the linkage upward).

This module holds the string channels and lift bores, and builds a tile (trims and the batched
cut).  Magnet pockets and labels live in :mod:`.magnets_labels`; hinge strips, pads, pins and
holes in :mod:`.hinge_frame`, :mod:`.hinge_pins` and :mod:`.hinge_parts`; the helpers they
share in :mod:`.feature_common`.  The names other modules use are re-exported here
(``__all__``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import (
    TOOL_OVERSHOOT_MM,
    Footprint,
    bd_plane,
    channel_radius,
    feature_wall_mm,
    footprint_margin,
    vector3,
)
from drawstring.cad.hinge_frame import (
    StripNeighbours,
    hinge_strip_lengths,
    strip_min_reach_mm,
    strip_room,
)
from drawstring.cad.hinge_parts import (
    GLUE_RECESS_DEPTH_FRACTION,
    StripHoles,
    hinge_face_footprints,
    hinge_pad,
    strip_hole_plan,
    strip_holes,
)
from drawstring.cad.hinge_pins import (
    HingePins,
    KeepOut,
    PinPlan,
    pin_keep_out,
    pin_radius,
    plan_pins,
    strip_keep_outs,
    tube_keep_out,
)
from drawstring.cad.kernel import bounding_box, clean_solid, cut, fuse
from drawstring.cad.magnets_labels import (
    MagnetPair,
    label_depth,
    label_engraving,
    magnet_pockets,
)
from drawstring.cad.paths import (
    SIDE_TOP_FACE,
    ChannelPath,
    LiftPath,
    arc_samples,
    channel_path,
    check_side,
    face_planes,
    lift_path,
    unit_vector,
)
from drawstring.cad.tiles import convex_solid, tile_solid
from drawstring.geometry.core.errors import InternalError

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)

__all__ = [
    # channels, lift bores, building a tile
    "BEND_RADIUS_SLACK_MM",
    "SHARED_OPENING_INSET_MM",
    "build_tile",
    "channel_keep_out",
    "channel_min_face_mm",
    "channel_min_thickness_mm",
    "hinge_sink_depth",
    "lift_bore",
    "lift_bore_depth_mm",
    "lift_chamfer",
    "string_channel",
    "tight_channel",
    "trim_tool",
    # re-exported from .feature_common
    "TOOL_OVERSHOOT_MM",
    "Footprint",
    "channel_radius",
    "feature_wall_mm",
    # re-exported from .magnets_labels
    "MagnetPair",
    "label_depth",
    "label_engraving",
    "magnet_pockets",
    # re-exported from .hinge_frame, .hinge_pins and .hinge_parts
    "GLUE_RECESS_DEPTH_FRACTION",
    "HingePins",
    "KeepOut",
    "PinPlan",
    "StripHoles",
    "StripNeighbours",
    "hinge_face_footprints",
    "hinge_pad",
    "hinge_strip_lengths",
    "pin_keep_out",
    "pin_radius",
    "plan_pins",
    "strip_hole_plan",
    "strip_holes",
    "strip_keep_outs",
    "strip_min_reach_mm",
    "strip_room",
]


#: A bend this little (mm) below the profile's minimum radius is not reported (rounding).
BEND_RADIUS_SLACK_MM = 1e-6


def channel_min_face_mm(profile: Profile) -> float:
    """Narrowest side face (mm, edge length at mid-thickness) a string channel can open through:
    the bore and a :func:`feature_wall_mm` either side of it."""
    return 2.0 * (channel_radius(profile) + feature_wall_mm(profile))


def hinge_sink_depth(profile: Profile) -> float:
    """How deep (mm) the hinge features reach into a tile from its hinge face, pins aside (they
    are cut short around the channels): the TPU recess, the dovetail key, the glue recess or the
    screw and staple holes."""
    if profile.hinge_interlock == "through-holes":
        return profile.hinge_thickness_mm
    if profile.hinge_interlock == "dovetail":
        return 2.0 * profile.hinge_thickness_mm
    if profile.hinge_interlock == "glue-recess":
        return GLUE_RECESS_DEPTH_FRACTION * profile.hinge_thickness_mm
    return 0.25 * profile.thickness_mm


def channel_min_thickness_mm(profile: Profile) -> float:
    """Thinnest tile (mm) whose mid-thickness string channel keeps a :func:`feature_wall_mm`
    from the hinge features and the label sunk into its top and bottom faces."""
    sunk = max(hinge_sink_depth(profile), label_depth(profile))
    return 2.0 * (channel_radius(profile) + feature_wall_mm(profile) + sunk)


#: A channel whose centre line bends tighter than this many times its own radius is cut as
#: straight bores along the Bezier's control polygon (:func:`_polygon_tube`): a tube swept
#: round a bend tighter than its radius folds onto itself, and OCCT's boolean fails on it
#: (minimal_surface, corpus, at 280 mm: a 0.54 mm bend in a 0.8 mm channel).
TIGHT_BEND_RADII = 1.25


def tight_channel(path: ChannelPath, radius: float) -> bool:
    """Whether the channel along ``path`` is cut as straight bores (:data:`TIGHT_BEND_RADII`)."""
    return bool(path.min_radius < TIGHT_BEND_RADII * radius)


def channel_centre_line(path: ChannelPath, radius: float) -> NDArray[np.float64]:
    """(k, 3) points along the centre line the channel of ``radius`` is cut along: the Bezier,
    or its control polygon where the bend is tight (:func:`tight_channel`)."""
    if tight_channel(path, radius):
        return _polygon(path, radius)
    return path.points(129)


def _polygon(path: ChannelPath, radius: float) -> NDArray[np.float64]:
    """The control polygon of ``path``, its first and last legs (straight in along the
    openings' normals) at least :data:`TIGHT_BEND_RADII` channel radii long so that the next
    leg's bore stays behind the face and the opening stays round and centred, without its
    zero-length legs."""
    control = path.control.copy()
    lead = TIGHT_BEND_RADII * radius
    control[1] = control[0] + max(float(np.linalg.norm(control[1] - control[0])), lead) * (
        path.start_tangent
    )
    control[2] = control[3] - max(float(np.linalg.norm(control[3] - control[2])), lead) * (
        path.end_tangent
    )
    points = [control[0]]
    for point in control[1:]:
        if np.linalg.norm(point - points[-1]) > 1e-6:
            points.append(point)
    return np.array(points)


def _polygon_tube(path: ChannelPath, radius: float) -> tuple[bd.Solid, ...]:
    """Cylinders of ``radius`` along the control polygon of ``path``, the first and last
    extended straight past the openings, meeting end to end at its corners (the string runs
    on the inside of each corner, which the cylinders cover; carried past the corners, their
    end faces leave slivers that OCCT meshes open).  Kept apart, each a tool of the tile's one
    cut: fused, their seams can leave such slivers too."""
    points = _polygon(path, radius)
    overshoot = radius + TOOL_OVERSHOOT_MM
    ends = [points[0] - overshoot * path.start_tangent, *points[1:-1]]
    ends.append(points[-1] + overshoot * path.end_tangent)
    return tuple(
        bd.Solid.make_cylinder(
            radius, float(np.linalg.norm(end - start)), bd_plane(start, end - start)
        )
        for start, end in zip(ends[:-1], ends[1:], strict=True)
    )


def _tube(path: ChannelPath, radius: float) -> bd.Solid:
    """Circular tube of ``radius`` around ``path``, extended straight past both openings."""
    overshoot = radius + TOOL_OVERSHOOT_MM
    start, end = path.control[0], path.control[3]
    outer_start = start - overshoot * path.start_tangent
    outer_end = end + overshoot * path.end_tangent
    offsets = path.control - start
    chord = unit_vector(end - start)
    if np.abs(offsets - np.outer(offsets @ chord, chord)).max() < 1e-9:
        # Straight: a plain cylinder (sweeping along a straight line has no defined frame).
        length = float(np.linalg.norm(outer_end - outer_start))
        return bd.Solid.make_cylinder(radius, length, bd_plane(outer_start, chord))
    edges = [
        bd.Edge.make_line(vector3(outer_start), vector3(start)),
        bd.Edge.make_bezier(*[vector3(p) for p in path.control]),
        bd.Edge.make_line(vector3(end), vector3(outer_end)),
    ]
    section = bd.Wire([bd.Edge.make_circle(radius, bd_plane(outer_start, path.start_tangent))])
    tube = bd.Solid.sweep(section, bd.Wire(edges), transition=bd.Transition.ROUND)
    return clean_solid(tube)


def string_channel(
    tile: NDArray[np.float64], enter_side: int, leave_side: int, profile: Profile
) -> tuple[bd.Solid, ...]:
    """Tools: the string channel through one tile.

    Parameters
    ----------
    tile : (8, 3) float, mm.
    enter_side, leave_side : side faces 0..3 the string enters and leaves through.
    profile : gives the bore diameter (string diameter + clearance).

    Returns
    -------
    The solid tube of diameter ``string + clearance`` swept along :func:`channel_path`, or
    where that bends tighter than the tube can follow (:func:`tight_channel`) straight bores
    along its control polygon, one solid each; a bend tighter than
    ``profile.min_bend_radius_mm`` is logged (the tile is too small for it).
    """
    check_side(enter_side, "enter_side")
    check_side(leave_side, "leave_side")
    path = channel_path(tile, enter_side, leave_side)
    if path.min_radius < profile.min_bend_radius_mm - BEND_RADIUS_SLACK_MM:
        log.debug(
            "channel bend radius %.2f mm < profile minimum %.2f mm",
            path.min_radius,
            profile.min_bend_radius_mm,
        )
    radius = channel_radius(profile)
    if tight_channel(path, radius):
        return _polygon_tube(path, radius)
    return (_tube(path, radius),)


def lift_bore_depth_mm(
    tile: NDArray[np.float64], side: int, profile: Profile
) -> tuple[float, float]:
    """How deep ``tile`` is from side face ``side`` inward, and how deep it would have to be
    for the lift bore from that side (:func:`lift_path`) to keep a :func:`feature_wall_mm`
    from every other side face (mm).

    The bore's bend rises from mid-thickness to the top face, so it reaches about half the
    tile's thickness in from its side face whatever the tile's size: on a small tile it breaks
    out through the far side face.
    """
    tile = np.asarray(tile, dtype=np.float64)
    path = lift_path(tile, side)
    centroids, normals = face_planes(tile)
    points = np.vstack([path.entry[None], arc_samples(path.arc)])
    others = [k for k in range(4) if k != side]
    beyond = np.einsum("pd,kd->pk", points, normals[others]) - np.einsum(
        "kd,kd->k", centroids[others], normals[others]
    )
    overshoot = float(beyond.max()) + channel_radius(profile) + feature_wall_mm(profile)
    opposite = (side + 2) % 4
    depth = float((centroids[opposite] - path.entry) @ normals[opposite])
    return depth, depth + overshoot


def lift_chamfer(tile: NDArray[np.float64], path: LiftPath, profile: Profile) -> float:
    """Depth (mm) of the 45-degree chamfer at a lift bore's exit: ``max(radius, 0.5 mm)``, or 0
    (no chamfer) where its rim would come nearer than :func:`feature_wall_mm` to the top face's
    edges.  Not a shallower one: a chamfer whose cone starts in the bore's bend (under about
    0.55 mm for the shipped FDM profiles, measured on a 4.4 mm tile) gives a solid that OCCT
    meshes with open seams."""
    radius = channel_radius(profile)
    chamfer = max(radius, 0.5)
    top = np.asarray(tile, dtype=np.float64)[:4]
    margin = footprint_margin(np.concatenate([top, top]), path.arc[2], path.end_tangent)
    return chamfer if margin >= radius + chamfer + feature_wall_mm(profile) else 0.0


#: How much thinner (mm, radius) a lift bore is cut where a string channel opens through the
#: same side face: the two tubes would otherwise share their cylinder just outside the face, and
#: OCCT then leaves seams that mesh open (saddle, 47 mm, 200 tiles: tile 98).
SHARED_OPENING_INSET_MM = 0.02


def lift_bore(
    tile: NDArray[np.float64], side: int, profile: Profile, *, shared: bool = False
) -> bd.Solid:
    """Tool: a channel from side ``side`` that leaves upward through the top face.

    Follows :func:`lift_path`.  The exit is chamfered at 45 degrees (depth
    :func:`lift_chamfer`) so the string, pulled upward, does not run over a sharp edge.
    ``shared``: a string channel opens through the same side face; the bore is then
    :data:`SHARED_OPENING_INSET_MM` thinner, inside that channel where they overlap.
    """
    tile = np.asarray(tile, dtype=np.float64)
    radius = channel_radius(profile) - (SHARED_OPENING_INSET_MM if shared else 0.0)
    path = lift_path(tile, side)
    if path.radius < profile.min_bend_radius_mm - BEND_RADIUS_SLACK_MM:
        log.debug(
            "lift bore bend radius %.2f mm < profile minimum %.2f mm",
            path.radius,
            profile.min_bend_radius_mm,
        )
    overshoot = radius + TOOL_OVERSHOOT_MM
    outer_start = path.entry - overshoot * path.start_tangent
    exit_point = path.arc[2]
    outer_end = exit_point + overshoot * path.end_tangent
    edges = [bd.Edge.make_line(vector3(outer_start), vector3(path.arc[0]))]
    edges.append(bd.Edge.make_three_point_arc(*[vector3(p) for p in path.arc]))
    edges.append(bd.Edge.make_line(vector3(exit_point), vector3(outer_end)))
    section = bd.Wire([bd.Edge.make_circle(radius, bd_plane(outer_start, path.start_tangent))])
    tube = clean_solid(bd.Solid.sweep(section, bd.Wire(edges), transition=bd.Transition.ROUND))
    chamfer = lift_chamfer(tile, path, profile)
    if chamfer <= 0.0:
        return tube
    cone_base = exit_point - chamfer * path.end_tangent
    height = chamfer + TOOL_OVERSHOOT_MM
    cone = bd.Solid.make_cone(
        radius, radius + height, height, bd_plane(cone_base, path.end_tangent)
    )
    return clean_solid(fuse(tube, [cone]))


def channel_keep_out(
    tile: NDArray[np.float64], enter_side: int, leave_side: int, profile: Profile
) -> KeepOut:
    """The string channel of one route step through ``tile`` ((8, 3), mm) as balls, or its lift
    bore when a side is ``SIDE_TOP_FACE`` (the chamfered exit as balls of the chamfer's top
    radius)."""
    tile = np.asarray(tile, dtype=np.float64)
    radius = channel_radius(profile)
    if SIDE_TOP_FACE not in (enter_side, leave_side):
        path = channel_path(tile, enter_side, leave_side)
        return tube_keep_out(channel_centre_line(path, radius), radius)
    side = enter_side if leave_side == SIDE_TOP_FACE else leave_side
    path = lift_path(tile, side)
    chamfer = lift_chamfer(tile, path, profile)
    exit_point = path.arc[2]
    bore = tube_keep_out(
        np.vstack([path.entry[None], arc_samples(path.arc), exit_point[None]]), radius
    )
    top = exit_point + (radius + TOOL_OVERSHOOT_MM) * path.end_tangent
    flare = tube_keep_out(np.stack([exit_point - chamfer * path.end_tangent, top]), radius)
    return bore + KeepOut(flare.centres, flare.radii + chamfer)


# --------------------------------------------------------------------------------------------
# trims and the batched cut


def trim_tool(points: NDArray[np.float64]) -> bd.Solid:
    """Tool: the convex polyhedron spanned by ``points`` ((k, 3) float, mm), to subtract."""
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or len(array) < 4:
        raise InternalError(f"a trim polyhedron needs (k >= 4, 3) points, got shape {array.shape}")
    try:
        return convex_solid(array)
    except Exception as exc:  # the kernel's own errors: an edge between points a hair apart
        first = exc
    # Made again from points a hair apart merged, then from points rounded to a grid (each
    # moves under 1e-5 mm), the first valid solid kept; else the first one made.
    made: bd.Solid | None = None
    for points in (
        _distinct_points(array, TRIM_POINT_MERGE_MM),
        *(np.unique(np.round(array, digits), axis=0) for digits in TRIM_GRID_DECIMALS),
    ):
        try:
            solid = convex_solid(points)
        except Exception:
            continue
        if solid.is_valid:
            return solid
        made = made or solid
    if made is None:
        raise first  # the kernel's failure, which the tile's build notes
    return made


#: Points of a trim polyhedron nearer each other than this (mm) are one point where the kernel
#: fails on the edge between them (two of the overlap's corners that coincide).
TRIM_POINT_MERGE_MM = 1e-6
#: Decimals (mm) a trim polyhedron's points are rounded to where merging them is not enough.
TRIM_GRID_DECIMALS = (5, 4)


def _distinct_points(points: NDArray[np.float64], within: float) -> NDArray[np.float64]:
    """``points`` without those nearer than ``within`` to an earlier one."""
    kept: list[int] = []
    for index, point in enumerate(points):
        if not kept or np.linalg.norm(points[kept] - point, axis=1).min() >= within:
            kept.append(index)
    return points[kept]


#: Shifts (mm) tried, in order, when a single feature's boolean cut fails.
_NUDGES_MM = ((0.0, 0.0, 0.0), (0.002, 0.0, 0.0), (0.0, 0.002, 0.0), (0.0, 0.0, 0.002))


def _plausible(pieces: list[bd.Solid] | None, base: bd.Solid) -> float | None:
    """The volume (mm^3) of a cut result's largest piece where the result is plausible, else
    None.  It is plausible when that piece is a valid, manifold solid keeping at least half
    the volume: the features are small next to a tile, so anything less (or a non-manifold
    seam where two tools touch, or a kernel error while measuring it) is a failed boolean."""
    if not pieces:
        return None
    try:
        volumes = [p.volume for p in pieces]  # each volume integral once
        largest = pieces[int(np.argmax(volumes))]
        if max(volumes) < 0.5 * base.volume:
            return None
        return float(max(volumes)) if largest.is_manifold and largest.is_valid else None
    except Exception:  # OCCT's own failures (Standard_Failure) are not RuntimeErrors
        log.debug("checking a cut result failed", exc_info=True)
        return None


def _try_cut(base: bd.Solid, tools: Sequence[bd.Shape]) -> list[bd.Solid] | None:
    """:func:`~drawstring.cad.kernel.cut`, or None where the kernel fails or raises."""
    try:
        return cut(base, tools)
    except Exception:  # OCCT's own failures (Standard_Failure) are not RuntimeErrors
        log.debug("OCCT cut failed", exc_info=True)
        return None


def build_tile(
    tile: NDArray[np.float64] | bd.Solid,
    tools: list[bd.Shape],
    *,
    failed: list[int] | None = None,
    dropped: list[float] | None = None,
    checked: list[tuple[bool, float]] | None = None,
) -> bd.Solid:
    """The tile minus the tools that touch it, in one boolean operation.

    Tools whose bounding box misses the tile's are skipped.  If the cut splits the tile, the
    largest piece is kept and the volumes (mm^3) of the others are appended to ``dropped``
    (logged when no list is given).  Where the batched cut fails (or raises),
    the tools are cut one at a time; a tool whose cut fails even on its own and slightly
    shifted raises ``RuntimeError``, or, given a ``failed`` list, is left uncut and its index
    in ``tools`` appended there.  ``checked`` receives the result's
    :func:`~drawstring.cad.kernel.solid_checks` ``(True, volume)`` where the cut measured them
    on its way (a valid, manifold largest piece), so that they are not measured again.
    """
    base = tile if isinstance(tile, bd.Solid) else tile_solid(np.asarray(tile))
    box = bounding_box(base)
    touching = []
    for index, tool in enumerate(tools):
        tool_box = bounding_box(tool)
        if np.all(tool_box[0] <= box[1] + 1e-6) and np.all(tool_box[1] >= box[0] - 1e-6):
            touching.append((index, tool))
    batched = _try_cut(base, [tool for _, tool in touching])
    known = _plausible(batched, base)  # the volume of the largest piece, checked valid
    if batched is not None and known is not None:
        pieces = batched
    else:
        # OCCT's batched cut can fail where two tools share a face (a channel and a lift bore
        # leaving through the same opening); cutting one tool at a time avoids that.
        pieces = [base]
        for index, tool in touching:
            current = max(pieces, key=lambda s: s.volume)
            for nudge in _NUDGES_MM:
                # A coincident face can defeat the boolean; a micrometre shift does not change
                # what is printed.
                moved = tool if not any(nudge) else tool.moved(bd.Location(nudge))
                attempt = _try_cut(current, [moved])
                volume = _plausible(attempt, current)
                if attempt is not None and volume is not None:
                    known = volume
                    if dropped is not None:  # an earlier tool's cut split the tile
                        dropped.extend(float(p.volume) for p in pieces if p is not current)
                    pieces = attempt
                    break
            else:
                if failed is None:
                    raise RuntimeError("a feature's cut failed even after shifting it slightly")
                failed.append(index)
    if not pieces:
        raise RuntimeError("cutting the features removed the whole tile")
    kept = pieces[0] if len(pieces) == 1 else max(pieces, key=lambda s: s.volume)
    if len(pieces) > 1:
        rest = [float(p.volume) for p in pieces if p is not kept]
        if dropped is None:
            log.warning("features split a tile into %d pieces; keeping the largest", len(pieces))
        else:
            dropped.extend(rest)
    if checked is not None and known is not None:
        checked.append((True, known))
    return clean_solid(kept)
