"""Glue between the geometry stages and the CAD layer: what each tile's solid needs.

The geometry pipeline speaks in linkages, routes and hinge layouts; :mod:`drawstring.cad` takes
plain arrays.  This module translates one into the other and runs the CAD build in both poses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import Process, Profile, print_clearance_mm
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import HingeSide, HingeStrategy, Pose, Side
from drawstring.geometry.core.tolerances import PRINT_GAP_TOL_MM
from drawstring.geometry.route.result import Route
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.pipeline.cad_measures import finite_max, sunk_fraction, worst_links
from drawstring.pipeline.layout_stage import fabricated_tiles
from drawstring.pipeline.record import Design, ResolvedOptions

if TYPE_CHECKING:  # the CAD kernel loads only where solids are built
    from drawstring.cad.design import CadResult
    from drawstring.cad.hinge_plans import ReliefShortfall
    from drawstring.fabrication.measures import Measures
    from drawstring.fabrication.printers import Printer


@dataclass(frozen=True)
class CadInputs:
    """Arrays :func:`drawstring.cad.design.build_design_solids` takes, derived from a design.

    Attributes
    ----------
    route_steps : (S, 4) int, ``(gap, tile, enter_side, leave_side)`` in route order.
    lift_tiles : (L, 2) int, ``(tile, side)``: the string leaves ``tile`` through side ``side``
        into a lift gap; a bore from that side up through the top face lets it out.
    magnet_pairs : (M, 4) int, ``(tile_a, side_a, tile_b, side_b)`` touching across a split.
    trims : tile -> convex polyhedra (vertex arrays, flat pose) to subtract (top hinges only).
    """

    route_steps: NDArray[np.int64]
    lift_tiles: NDArray[np.int64]
    magnet_pairs: NDArray[np.int64]
    trims: dict[int, Sequence[NDArray[np.float64]]]


def route_steps(route: Route) -> NDArray[np.int64]:
    """(S, 4) int rows ``(gap, tile, enter_side, leave_side)`` of a route."""
    return np.stack([route.gaps, route.tiles, route.enter_side, route.leave_side], axis=1).astype(
        np.int64
    )


def lift_exits(route: Route, lift_gaps: NDArray[np.int64]) -> NDArray[np.int64]:
    """(L, 2) ``(tile, side)`` for the string to leave and re-enter through the top faces
    (:func:`lift_bores` of the route's steps)."""
    return lift_bores(route_steps(route), lift_gaps)


def lift_bores(steps: NDArray[np.int64], lift_gaps: NDArray[np.int64]) -> NDArray[np.int64]:
    """(L, 2) ``(tile, side)``: the lift bores of a route given as (S, 4) rows ``(gap, tile,
    enter_side, leave_side)`` (:func:`route_steps`, or ``route.json``'s steps), sorted.

    At a lift gap the route arrives from the previous step's tile (through its leaving side) and
    departs into this step's tile (through its entering side); both tiles get a bore from that
    side up through the top face, so the pulled loop runs out of one and back into the other.
    """
    rows: list[tuple[int, int]] = []
    steps = np.asarray(steps, dtype=np.int64).reshape(-1, 4)
    count = len(steps)
    for gap in np.asarray(lift_gaps, dtype=np.int64).tolist():
        hits = np.flatnonzero(steps[:, 0] == gap)
        for k in hits.tolist():
            before = (k - 1) % count
            rows.append((int(steps[before, 1]), int(steps[before, 3])))
            rows.append((int(steps[k, 1]), int(steps[k, 2])))
    return np.array(sorted(set(rows)), dtype=np.int64).reshape(-1, 2)


def split_contacts(linkage: Linkage) -> NDArray[np.int64]:
    """(M, 4) ``(tile_a, side_a, tile_b, side_b)``: neighbours across every split line."""
    tile_at = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
    rows: list[tuple[int, int, int, int]] = []
    for split in linkage.splits:
        for k in range(split.lo, split.hi):
            if split.axis == "x":
                a = tile_at.get((split.line - 1, k))
                b = tile_at.get((split.line, k))
                sides = (Side.RIGHT, Side.LEFT)
            else:
                a = tile_at.get((k, split.line - 1))
                b = tile_at.get((k, split.line))
                sides = (Side.TOP, Side.BOTTOM)
            if a is not None and b is not None:
                rows.append((a, sides[0], b, sides[1]))
    return np.array(sorted(set(rows)), dtype=np.int64).reshape(-1, 4)


def cad_inputs(result: Design) -> CadInputs:
    """Collect the CAD layer's inputs from a finished geometry design."""
    pieces: dict[int, list[NDArray[np.float64]]] = {}
    for trim in result.hinge_layout.trims:
        pieces.setdefault(int(trim.tile), []).append(np.asarray(trim.vertices, dtype=np.float64))
    trims: dict[int, Sequence[NDArray[np.float64]]] = dict(pieces)
    return CadInputs(
        route_steps=route_steps(result.route),
        lift_tiles=lift_exits(result.route, result.lift.lift_gaps),
        magnet_pairs=split_contacts(result.tiling.linkage),
        trims=trims,
    )


def print_tiles(result: Design) -> NDArray[np.float64]:
    """(T, 8, 3) flat tiles to fabricate (see :func:`~drawstring.pipeline.run.
    fabricated_tiles`): congruent to the assembled ones, placed by the hinge layout."""
    return fabricated_tiles(result.hinge_layout, result.tiles_assembled)


def route_lengths(result: Design) -> tuple[float, float]:
    """(flat, assembled) string route length of a design, mm: along the channels of the tiles
    as printed and as assembled (:func:`~drawstring.cad.paths.route_lengths`, the value every output
    reports; it needs no solids)."""
    from drawstring.cad.paths import route_lengths as measured

    return measured(
        print_tiles(result),
        result.tiles_assembled,
        route_steps(result.route),
        lift_exits(result.route, result.lift.lift_gaps),
    )


def fabrication_measures(result: Design, cad_flat: CadResult) -> Measures:
    """Route, string and mass measured on a design's solids (:func:`~.measures.
    measure_fabrication` with the design's print tiles, route and lift bores)."""
    from drawstring.fabrication.measures import measure_fabrication

    inputs = cad_inputs(result)
    return measure_fabrication(
        result.profile,
        print_tiles(result),
        result.tiles_assembled,
        inputs.route_steps,
        inputs.lift_tiles,
        cad_flat,
        hinges=result.tiling.linkage.hinges,
        hinge_side=result.hinge_layout.sides,
    )


#: Side faces of a tile, as (top corner, next top corner, bottom corner, next bottom corner).
_SIDE_EDGES = np.array([[k, (k + 1) % 4, 4 + k, 4 + (k + 1) % 4] for k in range(4)])


def channel_faces_mm(
    tiles: NDArray[np.float64], steps: NDArray[np.int64], lift_tiles: NDArray[np.int64]
) -> NDArray[np.float64]:
    """Width (mm, edge length at mid-thickness) of every side face a string channel or lift
    bore opens through, one per opening, for the route ``steps`` (:func:`route_steps`) and
    its lift bores ``lift_tiles`` (:func:`lift_exits`)."""
    openings = [
        (tile, side)
        for _, tile, enter, leave in steps.tolist()
        for side in (enter, leave)
        if side < 4  # 4: a lift bore's exit through the top face
    ]
    openings += [(tile, side) for tile, side in lift_tiles.tolist()]
    if not openings:
        return np.zeros(0)
    tile_ids, sides = np.array(openings, dtype=np.int64).T
    corners = tiles[tile_ids[:, None], _SIDE_EDGES[sides]]  # (K, 4, 3)
    top = np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1)
    bottom = np.linalg.norm(corners[:, 3] - corners[:, 2], axis=1)
    return np.asarray(0.5 * (top + bottom))


def _round_up(value: float) -> float:
    """``value`` rounded up to two significant digits."""
    step = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.ceil(value / step - 1e-9) * step


def feature_shortfall(
    profile: Profile,
    tiles: NDArray[np.float64],
    steps: NDArray[np.int64],
    lift_tiles: NDArray[np.int64],
    hinges: NDArray[np.int64],
    sides: Sequence[HingeSide],
) -> FeatureShortfall | None:
    """The worst feature the profile cannot give up on that does not fit the flat ``tiles`` as
    fabricated, (T, 8, 3): the side faces the route ``steps`` and the lift bores
    ``lift_tiles`` open through (:func:`channel_faces_mm`), the lift-point tiles' depth, the
    hinged corners' room for their strips on the faces ``sides``
    (:func:`~drawstring.cad.hinge_plans.strip_room_mm`), and for tiles printed together the
    print clearance at every hinge (:func:`relief_words`); None where all fit."""
    from drawstring.cad.features import channel_min_face_mm, lift_bore_depth_mm
    from drawstring.cad.hinge_plans import relief_shortfall, strip_room_mm

    bore = f"{profile.string_diameter_mm + profile.channel_clearance_mm:g} mm string channel"
    found: list[tuple[str, float, float, type[FeatureShortfall]]] = []
    faces = channel_faces_mm(tiles, steps, lift_tiles)
    need_face = channel_min_face_mm(profile)
    if len(faces) and faces.min() < need_face - 1e-9:
        what = (
            f"side faces as narrow as {faces.min():.2f} mm where the string runs, and the "
            f"{bore} needs {need_face:.2f} mm with its walls"
        )
        found.append((what, float(faces.min()), need_face, FeatureShortfall))
    bores = {(int(t), int(s)) for t, s in lift_tiles.tolist()}
    for _, tile, enter, leave in steps.tolist():
        if 4 in (enter, leave):  # through the top face: a lift bore from the other side
            bores.add((int(tile), int(min(enter, leave))))
    if bores:
        depths = [lift_bore_depth_mm(tiles[t], s, profile) for t, s in sorted(bores)]
        have, need = min(depths, key=lambda d: d[0] / d[1])
        if have < need - 1e-9:
            what = (
                f"lift-point tiles {have:.2f} mm deep, and the lift bore, which bends up "
                f"from mid-thickness to the top face, needs {need:.2f} mm"
            )
            found.append((what, have, need, FeatureShortfall))
    strips = strip_room_mm(profile, tiles, hinges, sides)
    if strips is not None and strips[0] < strips[1] - 1e-9:
        found.append((strip_words(profile, *strips), *strips, FeatureShortfall))
    clearance = print_clearance_mm(profile)
    welded = relief_shortfall(tiles, hinges, sides, steps, lift_tiles, profile, clearance)
    if welded is not None:  # a room at or below 0 ranks worst (and steps on by a whole step);
        # a pair left for another cause than room (its cut would take over half a tile, or no
        # hull) still ranks as a shortfall, by half the room a relief needs
        have = min(max(welded.have, 1e-3), 0.5 * welded.need)
        found.append((relief_words(welded, clearance), have, welded.need, WeldedHinges))
    if not found:
        return None
    what, have, need, kind = max(found, key=lambda f: f[2] / f[1])
    return kind(what, have, need)


def strip_words(profile: Profile, have: float, need: float) -> str:
    """What a hinge strip's shortfall (:func:`strip_room_mm`) means, in words."""
    return (
        f"hinged corners {have:.2f} mm from their tiles' centres, and a "
        f"{profile.hinge_width_mm:g} mm wide hinge strip needs {need:.2f} mm"
    )


def relief_words(welded: ReliefShortfall, clearance_mm: float) -> str:
    """What tiles no print-clearance relief keeps apart (:func:`~drawstring.cad.hinge_plans.
    relief_shortfall`) mean, in words."""
    a, b = welded.tiles
    if welded.have < 0:
        room = f"reach {-welded.have:.2f} mm into the other tile"
    elif welded.have < welded.need:
        room = f"lie {welded.have:.2f} mm from the other tile"
    else:
        room = "leave no cut of at most half a tile that clears them"
    counts = [f"{len(welded.hinges)} hinged pair(s)"] if welded.hinges else []
    counts += [f"{len(welded.pairs)} pair(s) not hinged together"] if welded.pairs else []
    return (
        f"{' and '.join(counts)} lie so close in the flat layout that they would print welded "
        f"(tiles {a} and {b}: their string channels, lift bores and strips {room}, and "
        f"cutting a {clearance_mm:g} mm print clearance with a wall needs {welded.need:.2f} mm)"
    )


def thickness_refusal(profile: Profile, thickness: float) -> InputError | None:
    """The one-line refusal of tiles too thin for the profile's string channel (the hinge
    recesses and labels sunk above and below it), or None.  It depends on the profile and the
    thickness alone, so the pipeline asks it before any stage runs."""
    from drawstring.cad.features import channel_min_thickness_mm

    need_thickness = channel_min_thickness_mm(profile)
    if thickness >= need_thickness - 1e-9:
        return None
    return InputError(
        f"{thickness:g} mm thick tiles are too thin for the {profile.name} profile's string "
        f"channel ({profile.string_diameter_mm + profile.channel_clearance_mm:g} mm bore at "
        f"mid-thickness, walls and hinge recesses above and below it need "
        f"{need_thickness:.2f} mm); use --thickness {_round_up(need_thickness):g} or more"
    )


class FeatureShortfall(InputError):
    """Tiles too small for the profile's features: found on the first tiling's eq.-1 tiles
    before the layout (boundary tiles for the string channel,
    :func:`boundary_channel_shortfall`; hinged corners for their hinge strips,
    :func:`hinge_strip_shortfall`), or on the laid-out tiles and their route
    (:func:`feature_shortfall`); ``have`` and ``need`` in mm."""

    def __init__(self, message: str, have: float, need: float) -> None:
        super().__init__(message)
        self.have = have
        self.need = need


class WeldedHinges(FeatureShortfall):
    """Hinged tiles that overlap in the flat layout where their string channels, lift bores or
    strips run, or tiles not hinged together that come as close there, so that no
    print-clearance relief clears them (:func:`relief_words`).  The
    overlap follows the shape's scale factor between neighbouring tiles, which a larger size
    may keep (minimal_surface, corpus, at 280 and 380 mm: channels 1.31 and 1.13 mm into the
    other tile); another tile count tiles the shape anew."""


def boundary_channel_shortfall(
    profile: Profile, tiles: NDArray[np.float64], boundary: NDArray[np.bool_]
) -> tuple[float, float] | None:
    """(have, need) mm when some boundary tile has fewer than two side faces wide enough for
    the profile's string channel, else None.

    The route passes every boundary tile, in through one side face and out through another,
    so each needs two faces at least :func:`~drawstring.cad.features.channel_min_face_mm` wide
    at mid-thickness.  Asked on the eq.-1 tiles right after the assembled stage, seconds in,
    it refuses what :func:`feature_fit_refusal` would refuse only after the layout, the route
    and the simulation.  Necessary, not sufficient: that later check still runs on the faces
    the route uses."""
    from drawstring.cad.features import channel_min_face_mm

    need = channel_min_face_mm(profile)
    corners = tiles[:, _SIDE_EDGES]  # (T, 4 sides, 4 corners, 3)
    widths = 0.5 * (
        np.linalg.norm(corners[:, :, 1] - corners[:, :, 0], axis=2)
        + np.linalg.norm(corners[:, :, 3] - corners[:, :, 2], axis=2)
    )
    second = np.sort(widths, axis=1)[:, 2][np.asarray(boundary, dtype=bool)]
    if not len(second) or float(second.min()) >= need - 1e-9:
        return None
    return float(second.min()), need


def hinge_strip_shortfall(
    profile: Profile,
    linkage: Linkage,
    tiles: NDArray[np.float64],
    min_gap_angle_deg: float,
    hinges: HingeStrategy,
) -> tuple[float, float] | None:
    """(have, need) mm where some hinged corner of the eq.-1 ``tiles`` has too little room
    for its hinge strip (:func:`strip_room_mm`), else None.

    The hinge faces are not known before the hinge stage, so the strips are checked on every
    face they can end on: all on top, and with ``dual`` also on the faces
    :func:`~drawstring.geometry.hinges.sides.dual_hinge_faces` gives these tiles (``--hinges``
    left unset ends in either).  Asked right after the assembled stage, seconds in, it refuses
    what :func:`feature_fit_refusal` would refuse only after the layout, the route and the
    simulation.  The co-optimization moves the tiles a little: on minimal_surface (corpus) at
    --size 230 the eq.-1 tiles give 0.99 mm of 1.24 mm needed, the design's top-hinged tiles
    1.14 of 1.34."""
    from drawstring.cad.hinge_plans import strip_room_mm
    from drawstring.geometry.hinges.sides import dual_hinge_faces

    top = [HingeSide.TOP] * linkage.n_hinges
    assignments = [top]
    if hinges == HingeStrategy.DUAL:
        faces = dual_hinge_faces(linkage, tiles, min_gap_angle_deg)
        assignments.append([HingeSide.BOTTOM if b else HingeSide.TOP for b in faces.bottom])
    worst = None
    for sides in assignments:
        found = strip_room_mm(profile, tiles, linkage.hinges, sides)
        if found is not None and (worst is None or found[0] / found[1] < worst[0] / worst[1]):
            worst = found
    if worst is None or worst[0] >= worst[1] - 1e-9:
        return None
    return worst


def feature_fit_refusal(result: Design) -> InputError | None:
    """The one-line refusal of tiles too small or too thin for the profile's string channel,
    lift bores or hinge strips, or too large for its print bed (:func:`bed_refusal`), or None
    when they fit: the checks :func:`~.routed.routed_shortfall` asks right after the route
    (where a refusal comes with a checked ``retry with:``), asked again on the design the CAD
    stage is given.

    Checked before any solid is built: the tile thickness against
    :func:`~drawstring.cad.features.channel_min_thickness_mm`; the side faces the string passes
    against :func:`~drawstring.cad.features.channel_min_face_mm`; each lift-point tile's depth
    against :func:`~drawstring.cad.features.lift_bore_depth_mm`; and each hinged corner's
    distance from its face's centre against
    :func:`~drawstring.cad.hinge_frame.strip_min_reach_mm`.  Every other feature gives way on a
    small tile (pins cut short or left out, strips shortened, chamfers and numbers dropped, each
    with a note).

    The bounds keep a :func:`~drawstring.cad.feature_common.feature_wall_mm` (one nozzle) of
    material around each feature: below them a lift bore cuts a notch out of the far side
    face, or the channel checks find openings missing, and in between the wall left is
    thinner than a nozzle.  On small fdm-dual tiles the lift bores usually decide (their bend
    rises half the tile thickness).
    """
    profile, options = result.profile, result.options
    too_thin = thickness_refusal(profile, options.thickness_mm)
    if too_thin is not None:
        return too_thin
    inputs = cad_inputs(result)
    tiles = print_tiles(result)
    short = feature_shortfall(
        profile, tiles, inputs.route_steps, inputs.lift_tiles,
        result.tiling.linkage.hinges, result.hinge_layout.sides,
    )  # fmt: skip
    if short is None:
        return bed_refusal(profile, result.printer, tiles)
    return InputError(f"{tiles_too_small(options, profile, short)}; {MORE_ROOM}")


#: What gives the tiles more room for their features, in words.
MORE_ROOM = "give the tiles more room with a larger --size or fewer tiles"


def tiles_too_small(options: ResolvedOptions, profile: Profile, short: FeatureShortfall) -> str:
    """The start of a refusal of tiles too small for the profile's features: the size, the
    tile count or grid, the profile and what does not fit."""
    count = (
        f"--grid {options.grid[0]} {options.grid[1]}" if options.grid else f"{options.tiles} tiles"
    )
    return (
        f"--size {options.size_mm:g} mm with {count} gives tiles too small for the "
        f"{profile.name} profile: {short}"
    )


def bed_refusal(
    profile: Profile, printer: Printer | None, tiles: NDArray[np.float64]
) -> InputError | None:
    """The one-line refusal of a tile of the flat ``tiles`` as fabricated, (T, 8, 3), too
    large for the bed of ``printer`` (None: the profile's), or None: asked before any solid is
    built (the print jobs are planned only after the solids are meshed).

    ``fdm-dual`` prints the tiles as the flat layout places them (the layout may turn a quarter
    as a whole, :func:`~.exports_3mf.tile_bed_refusal`); ``laser-epdm`` nests them loose, each
    turned to fit (:func:`~.exports_beds.nest_footprints`).  ``plywood-cnc`` sheets are checked
    when the panels are laid out.
    """
    from drawstring.fabrication.beds import nest_footprints
    from drawstring.fabrication.mesh3mf import tile_bed_refusal
    from drawstring.fabrication.printers import print_bed

    bed = print_bed(profile, printer)
    if profile.process == Process.FDM_DUAL:
        return tile_bed_refusal(tiles, bed)
    if profile.process == Process.LASER_EPDM:
        try:
            nest_footprints(list(tiles), bed)
        except InputError as error:
            return error
    return None


def build_cad(result: Design) -> tuple[CadResult, CadResult]:
    """Solids of every tile and hinge part, in the flat (print) and the assembled pose.

    Raises
    ------
    InputError
        When the tiles are too small or too thin for the string channel
        (:func:`feature_fit_refusal`), before any solid is built.
    """
    from drawstring.cad.design import build_design_solids
    from drawstring.cad.tiles import move_solid

    refusal = feature_fit_refusal(result)
    if refusal is not None:
        raise refusal
    inputs = cad_inputs(result)
    flat = build_design_solids(
        print_tiles(result),
        result.tiles_assembled,
        result.tiling.linkage.hinges,
        result.hinge_layout.sides,
        inputs.route_steps,
        inputs.lift_tiles,
        inputs.magnet_pairs,
        inputs.trims,
        result.profile,
        pose=Pose.FLAT,
        print_clearance_mm=print_clearance_mm(result.profile),
    )
    # The assembled pose is the same solids moved rigidly (hinge parts bend, so they stay out).
    moved = tuple(
        move_solid(solid, motion) for solid, motion in zip(flat.tiles, flat.transforms, strict=True)
    )
    assembled = replace(
        flat,
        pose=Pose.ASSEMBLED,
        tiles=moved,
        pads=(),
        pad_hinge=np.zeros(0, dtype=np.int64),
        pad_checks=(),
        tile_meshes=(),
        pad_meshes=(),
    )
    return flat, assembled


def measure_cad(result: Design, cad_flat: CadResult) -> dict[str, Any]:
    """Checks measured on the solids (issue 7 section 3), for design.json ``metrics.cad``.

    Validity (BRepCheck, closed, positive volume, meshes closed) of every tile and hinge part,
    a tile missing a feature the CAD kernel failed on counting as not valid
    (``tiles_not_valid``, ``CadResult.failed``); interference volumes between tiles and between
    tiles and hinge parts in the flat print pose (manifold3d); channel continuity (distance
    between each channel exit and the next tile's entry in the assembled pose); magnet pockets
    paired (distance apart and facing) in the assembled pose.  Mass, route and string length as
    the fabrication files state them (:func:`fabrication_measures`).
    """
    from drawstring.cad.checks import (
        channel_continuity,
        clearances,
        interference,
        part_manifolds,
        pockets_paired,
    )

    inputs = cad_inputs(result)
    flat_tiles = print_tiles(result)
    valid_tiles = cad_flat.checks("tiles")[0]
    valid_pads, pad_volumes = cad_flat.checks("pads")

    # One tessellation of each tile serves both interference checks.  A tile that meshes with
    # open seams, or that the kernel fails to mesh, counts as not valid (it cannot be exported
    # as a closed mesh either).
    tile_meshes, tiles_meshed = part_manifolds(cad_flat.tiles, cad_flat.tile_meshes)
    pad_meshes, pads_meshed = part_manifolds(cad_flat.pads, cad_flat.pad_meshes)
    valid_tiles &= tiles_meshed
    valid_pads &= pads_meshed
    meshed_pads = np.flatnonzero(pads_meshed)
    tiles_vs_tiles = interference(tile_meshes)
    tiles_vs_pads = interference(tile_meshes, pad_meshes) if pad_meshes else None
    # A tile missing a feature the kernel failed on is a fault too (CadResult.failed).
    not_valid = sorted(
        {int(t) for t in np.flatnonzero(~valid_tiles)} | {t for t, _ in cad_flat.failed}
    )
    channels = channel_continuity(
        cad_flat.tiles, flat_tiles, cad_flat.transforms, inputs.route_steps, result.profile
    )
    pockets, facing = pockets_paired(
        cad_flat.tiles, flat_tiles, cad_flat.transforms, cad_flat.magnets
    )
    clearance = print_clearance_mm(result.profile)
    printed: dict[str, Any] = {}
    if clearance > 0:
        # tiles printed together: how close any two come (a slicer joins tiles closer than
        # a nozzle width); searched a little beyond, so that the closest is stated
        near = clearances(tile_meshes, 2.0 * clearance)
        printed = {
            "print_clearance_mm": clearance,
            "tile_gap_min_mm": round(near.min_distance, 6) if near.pairs.size else None,
            "tile_pairs_closer": int(
                np.count_nonzero(near.distances < clearance - PRINT_GAP_TOL_MM)
            ),
        }
    return {
        "solids_valid": bool(not not_valid and valid_pads.all()),
        "tiles_not_valid": not_valid,
        "tiles": len(cad_flat.tiles),
        "hinge_parts": len(cad_flat.pads),
        "interference_tiles_max_mm3": round(tiles_vs_tiles.max_volume, 6),
        "interference_tiles_pads_max_mm3": round(
            tiles_vs_pads.max_volume if tiles_vs_pads is not None else 0.0, 6
        ),
        "interference_tiles_pads_max_rel": round(
            sunk_fraction(tiles_vs_pads, pad_volumes[meshed_pads]), 6
        ),
        "channel_opening_distance_max_mm": round(finite_max(channels.distances), 6),
        "channel_openings_missing": int(np.count_nonzero(~np.isfinite(channels.distances))),
        "channel_worst_links": worst_links(channels.links, channels.distances),
        "magnet_pairs": len(cad_flat.magnets),
        "magnet_pocket_distance_max_mm": round(finite_max(pockets.distances), 6),
        "magnet_pockets_missing": int(np.count_nonzero(~np.isfinite(pockets.distances))),
        "magnet_pockets_breaking_out": sum(not m.fits for m in cad_flat.magnets),
        "magnet_pockets_facing": bool(np.all(facing < -0.999)) if len(facing) else True,
        **printed,
        **fabrication_measures(result, cad_flat).to_json(),
        "notes": list(cad_flat.notes),
    }
