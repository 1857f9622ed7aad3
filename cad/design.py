"""Build every tile and hinge part of a design as B-rep solids, in parallel worker processes.

Each tile is cut once, with only the tools that touch it (channels and lift bores of its route
steps, its hinges' pad recesses and interlocks, its magnet pockets, trims and its label).  Work is
split into chunks of tiles; each worker builds the tools it needs from plain arrays (nothing but
numbers cross the process boundary on the way in; the finished solids pickle on the way out):
:mod:`.tile_build`.  The hinges are planned first (:mod:`.hinge_plans`); the notes are worded in
:mod:`.design_notes`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, TypeVar

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.clearance import HingeReliefs
from drawstring.cad.design_notes import (
    MAX_RUNS,
    bend_notes,
    hole_notes,
    id_ranges,
    left_out_notes,
    pin_notes,
    relief_notes,
    strip_notes,
)
from drawstring.cad.feature_common import channel_radius as _channel_radius
from drawstring.cad.feature_common import feature_wall_mm
from drawstring.cad.features import lift_chamfer
from drawstring.cad.hinge_pins import PinPlan
from drawstring.cad.hinge_plans import (
    design_reliefs,
    plan_all_pins,
    planes_of,
    strip_hole_plans,
    strip_neighbours,
)
from drawstring.cad.kernel import solid_checks
from drawstring.cad.magnets_labels import MagnetPair, magnet_pockets, pairs_left_out
from drawstring.cad.part_mesh import PartMeshes
from drawstring.cad.paths import SIDE_TOP_FACE, channel_path, lift_path
from drawstring.cad.tile_build import (
    HingeData,
    JobResult,
    TileJob,
    kernel_failure,
    part_checks,
    part_meshes,
    run_jobs,
)
from drawstring.cad.tiles import move_solid, rigid_transforms
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import HingeSide, Pose
from drawstring.geometry.tiling.linkage import hinged_components

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)

T = TypeVar("T")


@dataclass(frozen=True)
class CadResult:
    """Solids of a design.

    Attributes
    ----------
    pose : ``"flat"`` (fabrication pose, T2D) or ``"assembled"`` (tiles moved rigidly onto T3D;
        hinge pads are left out because they bend).
    tiles : T solids in linkage tile order.
    pads : hinge parts (TPU pads or rubber strips), one per hinge in ``pad_hinge``.
    pad_hinge : (P,) int, hinge index of each pad.
    magnets : the magnet pairs with centre and polarity.
    channel_min_radius : (S,) float, mm, smallest bend radius of each route step's channel.
    transforms : (T, 4, 4) float, rigid motions from the flat pose to the assembled pose.
    notes : human-readable problems (features that did not fit, tight bends).
    failed : ``(tile, feature)`` for each feature (or hinge part) left out because the CAD
        kernel failed on it (:func:`build_design_solids`); the solid checks count those tiles
        as faults.
    fasteners : screws or staples that hold the plywood hinge strips, one per pilot hole or
        pair of holes made (:func:`~drawstring.cad.hinge_parts.strip_hole_plan`; 0 for other
        interlocks).
    unlabelled : tiles whose number could not be engraved (too small for the digits).
    tile_checks, pad_checks : ``(valid, volume mm^3)`` of each of ``tiles`` and ``pads``
        (:func:`~drawstring.cad.kernel.solid_checks`), measured by the workers that built
        them; empty, or not one per solid, where the solids were made otherwise (then
        :meth:`checks` measures them).
    unengraved : the tiles in the flat pose without their engraved numbers, the solids of the
        STEP files (:func:`~drawstring.cad.magnets_labels.fill_engraving`; the assembled pose
        moves them by ``transforms``): one per tile, the engraved solid where a tile has no
        number or its pockets could not be filled; empty where no number is engraved.
    number_outlines : the outlines of the engraved numbers on the bottom faces, flat pose,
        one per tile of ``unengraved`` (None where it is the engraved solid): per stroke the
        (k, 3) corners of a closed polygon, mm.
    tile_meshes, pad_meshes : the meshes of each of ``tiles`` and ``pads`` in the flat pose
        (:func:`~drawstring.cad.part_mesh.mesh_part` at the profile's
        :func:`~drawstring.cad.part_mesh.mesh_tolerance`, None where the kernel failed to mesh
        it closed), made by the workers that built them: the interference checks measure the
        first, the print files write the second; empty, or not one per solid, where the
        solids were made otherwise or moved (then the checks and the print files mesh them).
    meshed_here : whether the meshes were made on this machine (not on a cluster, whose
        meshes the print files do not use: the same design gives the same files anywhere).
    """

    pose: Pose
    tiles: tuple[bd.Solid, ...]
    pads: tuple[bd.Solid, ...]
    pad_hinge: NDArray[np.int64]
    magnets: tuple[MagnetPair, ...]
    channel_min_radius: NDArray[np.float64]
    transforms: NDArray[np.float64]
    notes: tuple[str, ...] = field(default=())
    failed: tuple[tuple[int, str], ...] = field(default=())
    fasteners: int = 0
    unlabelled: tuple[int, ...] = field(default=())
    tile_checks: tuple[tuple[bool, float], ...] = field(default=())
    pad_checks: tuple[tuple[bool, float], ...] = field(default=())
    unengraved: tuple[bd.Solid, ...] = field(default=())
    number_outlines: tuple[list[NDArray[np.float64]] | None, ...] = field(default=())
    tile_meshes: tuple[PartMeshes | None, ...] = field(default=())
    pad_meshes: tuple[PartMeshes | None, ...] = field(default=())
    meshed_here: bool = True

    def checks(self, part: Literal["tiles", "pads"]) -> tuple[NDArray[np.bool_], NDArray]:
        """(n,) bool validity and (n,) float volumes (mm^3) of the tiles or the pads."""
        solids, known = (
            (self.tiles, self.tile_checks) if part == "tiles" else (self.pads, self.pad_checks)
        )
        facts = list(known) if len(known) == len(solids) else [solid_checks(s) for s in solids]
        return (
            np.array([valid for valid, _ in facts], dtype=bool),
            np.array([volume for _, volume in facts], dtype=np.float64),
        )

    def records(self) -> dict[str, object]:
        """JSON-ready summary: magnet pairs with polarity, pads per hinge, notes."""
        return {
            "pose": self.pose,
            "tiles": len(self.tiles),
            "pads": [int(h) for h in self.pad_hinge],
            "magnets": [m.to_json() for m in self.magnets],
            "channel_min_radius_mm": [
                None if not np.isfinite(r) else round(float(r), 4) for r in self.channel_min_radius
            ],
            "notes": list(self.notes),
            "failed": [{"tile": tile, "feature": name} for tile, name in self.failed],
        }


def normalize_route(route_steps: NDArray[np.int64] | Sequence[Sequence[int]]) -> NDArray[np.int64]:
    """Route steps as an (S, 4) int array ``(gap, tile, enter_side, leave_side)``.

    Accepts (S, 3) ``(tile, enter, leave)`` (gap column filled with 0) or (S, 4).  Sides are 0..3
    or ``SIDE_TOP_FACE`` (4, through the top face); gap -1 marks a virtual entrance.
    """
    steps = np.asarray(route_steps, dtype=np.int64)
    if steps.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    if steps.ndim != 2 or steps.shape[1] not in (3, 4):
        raise InternalError(f"route steps must be (S, 3) or (S, 4) ints, got shape {steps.shape}")
    if steps.shape[1] == 3:
        steps = np.hstack([np.zeros((len(steps), 1), dtype=np.int64), steps])
    sides = steps[:, 2:]
    if np.any((sides < 0) | (sides > SIDE_TOP_FACE)):
        raise InternalError(f"route sides must be 0..3 or {SIDE_TOP_FACE} (top face)")
    return steps


def route_links(route_steps: NDArray[np.int64]) -> NDArray[np.int64]:
    """(K, 4) int ``(tile_a, leave_side_a, tile_b, enter_side_b)`` for consecutive steps (cyclic)
    whose string passes from one tile's side face straight into the next tile's side face."""
    steps = normalize_route(route_steps)
    links = []
    for index in range(len(steps)):
        here, after = steps[index], steps[(index + 1) % len(steps)]
        if len(steps) < 2 or after[0] < 0:
            continue
        if here[3] == SIDE_TOP_FACE or after[2] == SIDE_TOP_FACE:
            continue
        links.append((here[1], here[3], after[1], after[2]))
    return np.array(links, dtype=np.int64).reshape(-1, 4)


def build_design_solids(
    tiles_2d: NDArray[np.float64],
    tiles_3d: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[HingeSide],
    route_steps: NDArray[np.int64] | Sequence[Sequence[int]],
    lift_tiles: NDArray[np.int64] | Sequence[Sequence[int]],
    magnet_pairs: NDArray[np.int64] | Sequence[Sequence[int]],
    trims: dict[int, Sequence[NDArray[np.float64]]] | None,
    profile: Profile,
    pose: Pose = Pose.FLAT,
    *,
    labels: bool = True,
    workers: int | None = None,
    print_clearance_mm: float = 0.0,
) -> CadResult:
    """Solids of every tile with all its features, and the hinge parts.

    Parameters
    ----------
    tiles_2d : (T, 8, 3) float, mm, fabrication pose (features are cut here).
    tiles_3d : (T, 8, 3) float, mm, assembled pose (magnet pockets are placed here so that the
        pairs face each other; the assembled result moves the flat tiles rigidly onto it).
    hinges : (H, 4) int ``(tile_a, corner_a, tile_b, corner_b)``.
    hinge_side : (H,) ``"top"`` | ``"bottom"``.
    route_steps : (S, 3) ``(tile, enter, leave)`` or (S, 4) ``(gap, tile, enter, leave)``; a
        side of ``SIDE_TOP_FACE`` (4) makes a chamfered lift bore through the top face.
    lift_tiles : (L, 2) int ``(tile, side)``: extra lift bores from side ``side`` to the top.
    magnet_pairs : (M, 4) int ``(tile_a, side_a, tile_b, side_b)``, faces touching across splits.
    trims : tile -> convex polyhedra ((k, 3) float, flat pose) to subtract, or None.
    profile : dimensions of every feature.
    pose : ``"flat"`` or ``"assembled"``.
    labels : engrave tile numbers on the bottom faces.
    workers : worker processes (default: CPU count, used from ``PARALLEL_MIN_TILES`` tiles on).
    print_clearance_mm : tiles printed together in the flat pose keep this far apart (0: they
        are made loose): each hinged pair is relieved at its hinge (:func:`~drawstring.cad.
        clearance.hinge_reliefs`; where the top strategy's tiles overlap, one of them is cut
        a whole clearance clear of the other) and its pins keep their wall from the cuts.

    A feature or hinge part the CAD kernel fails on (an exception from OCP or build123d, or a
    cut that fails however it is shifted) is left out, noted and listed in
    ``CadResult.failed`` with its tile; a tile whose cut fails altogether is its plain block.
    Arrays that break this contract raise :class:`InternalError`.
    """
    if pose not in tuple(Pose):
        raise InternalError(f"pose {pose!r} must be 'flat' or 'assembled'")
    inputs = _checked_inputs(
        tiles_2d, tiles_3d, hinges, hinge_side, route_steps, lift_tiles, magnet_pairs
    )
    flat = inputs.flat
    jobs = [TileJob(t, flat[t], label=labels) for t in range(len(flat))]
    notes: list[str] = []
    min_radius, channel_sides = _route_tools(jobs, inputs, profile, notes)
    if not (np.isfinite(print_clearance_mm) and print_clearance_mm >= 0):
        raise InternalError(f"print_clearance_mm must be 0 or more, got {print_clearance_mm}")
    reliefs = _reliefs(inputs, profile, print_clearance_mm)
    magnets, failed = _magnet_tools(jobs, inputs, channel_sides, profile, notes, reliefs)
    _trim_tools(jobs, trims)
    hinge_data, fasteners = _plan_hinges(
        jobs, inputs, profile, print_clearance_mm, reliefs, min_radius, notes
    )
    results = run_jobs(jobs, profile, hinge_data, workers)
    tiles, pads, unlabelled = _gather(results, inputs, labels, failed, notes, profile)
    plain = _unengraved(results, tiles)  # before the assembled pose moves the tiles
    transforms, residual = rigid_transforms(flat, inputs.assembled)
    if residual.size and residual.max() > 1e-3:
        notes.append(
            f"flat and assembled tiles differ by up to {residual.max():.3g} mm beyond a rigid "
            "motion; checks in the assembled pose are approximate"
        )
    pad_hinge = np.array(sorted(pads), dtype=np.int64)
    pad_solids = tuple(pads[h] for h in pad_hinge)
    tile_checks, pad_checks = _in_order(part_checks(results), len(tiles), pad_hinge)
    tile_meshes, pad_meshes = _in_order(part_meshes(results), len(tiles), pad_hinge)
    if pose == Pose.ASSEMBLED:
        tiles = tuple(move_solid(s, m) for s, m in zip(tiles, transforms, strict=True))
        pad_solids, pad_hinge, pad_checks = (), np.zeros(0, dtype=np.int64), ()
        tile_meshes, pad_meshes = (), ()
    for note in notes:  # returned in CadResult.notes, which the design lists
        log.info("%s", note)
    return CadResult(
        pose,
        tiles,
        pad_solids,
        pad_hinge,
        tuple(magnets),
        min_radius,
        transforms,
        tuple(notes),
        tuple(failed),
        fasteners,
        tuple(int(t) for t in unlabelled),
        tile_checks,
        pad_checks,
        *plain,
        tile_meshes=tile_meshes,
        pad_meshes=pad_meshes,
        meshed_here=all(r.meshed_here for r in results),
    )


def _unengraved(
    results: list[JobResult], tiles: tuple[bd.Solid, ...]
) -> tuple[tuple[bd.Solid, ...], tuple[list[NDArray[np.float64]] | None, ...]]:
    """``CadResult.unengraved`` and ``number_outlines`` from the workers' results."""
    filled = {r.tile: r.unengraved for r in results if r.unengraved is not None}
    if not filled:
        return (), ()
    return (
        tuple(filled[t][0] if t in filled else s for t, s in enumerate(tiles)),
        tuple(filled[t][1] if t in filled else None for t in range(len(tiles))),
    )


def _trim_tools(
    jobs: list[TileJob], trims: dict[int, Sequence[NDArray[np.float64]]] | None
) -> None:
    """The trims' convex polyhedra into their tiles' jobs."""
    for tile, polyhedra in (trims or {}).items():
        if not 0 <= tile < len(jobs):
            raise InternalError(f"trims refer to tile {tile} outside 0..{len(jobs) - 1}")
        for points in polyhedra:
            jobs[tile].trims.append(np.asarray(points, dtype=np.float64))


def _in_order(
    known: dict[tuple[str, int], T], n_tiles: int, pad_hinge: NDArray[np.int64]
) -> tuple[tuple[T, ...], tuple[T, ...]]:
    """What the workers measured of each tile (in tile order) and each hinge part (in
    ``pad_hinge`` order), keyed as :func:`.part_checks` keys it; parts without it are left
    out (the tuple is then not one per part, and the caller measures them)."""
    tiles = tuple(known[("tile", t)] for t in range(n_tiles) if ("tile", t) in known)
    pads = tuple(known[("pad", int(h))] for h in pad_hinge if ("pad", int(h)) in known)
    return tiles, pads


@dataclass(frozen=True)
class _Inputs:
    """The design's arrays, checked: tiles (T, 8, 3) in both poses, hinges (H, 4) and their
    sides, route steps (S, 4), lift bores (L, 2) and magnet pairs (M, 4)."""

    flat: NDArray[np.float64]
    assembled: NDArray[np.float64]
    hinge_rows: NDArray[np.int64]
    sides: list[HingeSide]
    steps: NDArray[np.int64]
    lifts: NDArray[np.int64]
    pairs: NDArray[np.int64]


def _check_tiles(name: str, tiles: NDArray[np.float64]) -> NDArray[np.float64]:
    array = np.asarray(tiles, dtype=np.float64)
    if array.ndim != 3 or array.shape[1:] != (8, 3):
        raise InternalError(f"{name} must be a (T, 8, 3) array of tile vertices, got {array.shape}")
    return array


def _checked_inputs(
    tiles_2d: NDArray[np.float64],
    tiles_3d: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[HingeSide],
    route_steps: NDArray[np.int64] | Sequence[Sequence[int]],
    lift_tiles: NDArray[np.int64] | Sequence[Sequence[int]],
    magnet_pairs: NDArray[np.int64] | Sequence[Sequence[int]],
) -> _Inputs:
    """The arrays of :func:`build_design_solids` in their shapes, every tile id in range."""
    flat = _check_tiles("tiles_2d", tiles_2d)
    assembled = _check_tiles("tiles_3d", tiles_3d)
    if flat.shape != assembled.shape:
        raise InternalError(f"tiles_2d {flat.shape} and tiles_3d {assembled.shape} differ in shape")
    n_tiles = len(flat)
    hinge_rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    sides = list(hinge_side)
    if len(sides) != len(hinge_rows):
        raise InternalError(f"hinge_side has {len(sides)} entries for {len(hinge_rows)} hinges")
    for side in sides:
        if side not in tuple(HingeSide):
            raise InternalError(f"hinge side {side!r} must be 'top' or 'bottom'")
    steps = normalize_route(route_steps)
    lifts = np.asarray(lift_tiles, dtype=np.int64).reshape(-1, 2)
    pairs = np.asarray(magnet_pairs, dtype=np.int64).reshape(-1, 4)
    for name, ids in (
        ("hinges", hinge_rows[:, [0, 2]]),
        ("route_steps", steps[:, 1]),
        ("lift_tiles", lifts[:, 0]),
        ("magnet_pairs", pairs[:, [0, 2]]),
    ):
        if ids.size and (ids.min() < 0 or ids.max() >= n_tiles):
            raise InternalError(f"{name} refers to a tile outside 0..{n_tiles - 1}")
    return _Inputs(flat, assembled, hinge_rows, sides, steps, lifts, pairs)


def _route_tools(
    jobs: list[TileJob], inputs: _Inputs, profile: Profile, notes: list[str]
) -> tuple[NDArray[np.float64], list[set[int]]]:
    """The channels and lift bores of the route and the extra lift bores into the tiles'
    jobs; returns each route step's smallest bend radius and the sides of each tile the
    string opens."""
    flat, steps = inputs.flat, inputs.steps
    min_radius = np.full(len(steps), np.inf)
    channel_sides: list[set[int]] = [set() for _ in jobs]
    for index, (_, tile, enter, leave) in enumerate(steps):
        if SIDE_TOP_FACE in (enter, leave):
            if enter == leave:
                raise InternalError(f"route step {index} enters and leaves through the top face")
            min_radius[index] = lift_path(flat[tile], int(min(enter, leave))).radius
        else:
            min_radius[index] = channel_path(flat[tile], int(enter), int(leave)).min_radius
        if SIDE_TOP_FACE in (enter, leave):
            side = leave if enter == SIDE_TOP_FACE else enter
            jobs[tile].lifts.append(int(side))
            channel_sides[tile].add(int(side))
        else:
            jobs[tile].channels.append((int(enter), int(leave)))
            channel_sides[tile].update((int(enter), int(leave)))
    for tile, side in inputs.lifts:
        jobs[tile].lifts.append(int(side))
        channel_sides[tile].add(int(side))
    plain = sorted(
        {
            job.tile
            for job in jobs
            for side in job.lifts
            if lift_chamfer(job.vertices, lift_path(job.vertices, side), profile) <= 0.0
        }
    )
    if plain:
        notes.append(
            f"lift bores leave tiles {id_ranges(plain)} without a chamfer: their top faces are "
            "too small for one (the string runs over the bore's edge there)"
        )
    return min_radius, channel_sides


def _magnet_tools(
    jobs: list[TileJob],
    inputs: _Inputs,
    channel_sides: list[set[int]],
    profile: Profile,
    notes: list[str],
    reliefs: HingeReliefs | None,
) -> tuple[list[MagnetPair], list[tuple[int, str]]]:
    """The magnet pockets into the tiles' jobs, set off the string where it opens the same
    side and clear of the tiles' relief planes and hollows; returns the pairs made and
    ``(tile, "magnet pocket")`` where the kernel failed."""
    cuts = {} if reliefs is None else reliefs.cuts
    hollows = {} if reliefs is None else reliefs.hollows
    flat, assembled = inputs.flat, inputs.assembled
    magnets = []
    clearance = _channel_radius(profile) + 0.5 * profile.magnet_diameter_mm
    # the web left to the channel: a printed wall, or for plywood half the tool's width of wood
    clearance += profile.magnet_clearance_mm + max(
        profile.nozzle_mm, 0.5, 0.5 * profile.tool_diameter_mm
    )
    failed: list[tuple[int, str]] = []
    made: list[tuple[bd.Solid, bd.Solid, MagnetPair]] = []
    for tile_a, side_a, tile_b, side_b in inputs.pairs:
        shared = side_a in channel_sides[tile_a] or side_b in channel_sides[tile_b]
        try:
            tool_a, tool_b, record = magnet_pockets(
                assembled[tile_a],
                int(side_a),
                assembled[tile_b],
                int(side_b),
                profile,
                flat_a=flat[tile_a],
                flat_b=flat[tile_b],
                offset_mm=clearance if shared else 0.0,
                tile_ids=(int(tile_a), int(tile_b)),
                cuts=(planes_of(cuts, tile_a), planes_of(cuts, tile_b)),
                hollows=(hollows.get(int(tile_a), []), hollows.get(int(tile_b), [])),
            )
        except Exception as exc:
            kernel_failure(f"tiles {tile_a} and {tile_b}: magnet pockets", exc)
            failed += [(int(tile_a), "magnet pocket"), (int(tile_b), "magnet pocket")]
            continue
        made.append((tool_a, tool_b, record))
    parts = hinged_components(len(flat), inputs.hinge_rows)
    left_out = pairs_left_out([r for _, _, r in made], parts)
    for tool_a, tool_b, record in made:
        if any(record is r for r in left_out):
            continue
        jobs[record.tile_a].tools.append(tool_a)
        jobs[record.tile_b].tools.append(tool_b)
        magnets.append(record)
    notes.extend(left_out_notes(left_out, len(made)))
    broken = [m for m in magnets if not m.fits]
    if broken:
        broken_pairs = ", ".join(f"{m.tile_a}/{m.tile_b}" for m in broken[:MAX_RUNS])
        more = f" and {len(broken) - MAX_RUNS} more" if len(broken) > MAX_RUNS else ""
        notes.append(
            f"{len(broken)} of {len(magnets)} magnet pairs have pockets "
            f"({broken[0].diameter_mm:.2f} mm) breaking out of their side faces (tiles "
            f"{broken_pairs}{more})"
        )
    return magnets, failed


def _reliefs(inputs: _Inputs, profile: Profile, clearance_mm: float) -> HingeReliefs | None:
    return design_reliefs(
        inputs.flat, inputs.hinge_rows, inputs.sides, inputs.steps, inputs.lifts, profile,
        clearance_mm,
    )  # fmt: skip


def _plan_hinges(
    jobs: list[TileJob],
    inputs: _Inputs,
    profile: Profile,
    print_clearance_mm: float,
    reliefs: HingeReliefs | None,
    min_radius: NDArray[np.float64],
    notes: list[str],
) -> tuple[tuple[HingeData, ...], int]:
    """The hinge reliefs, pins and strip holes planned, each hinge into its tiles' jobs (tile
    a's worker builds its part); returns the hinges as the workers build them and the number
    of fasteners the strips take."""
    flat, hinge_rows, sides = inputs.flat, inputs.hinge_rows, inputs.sides
    relief_planes: dict[int, list[NDArray[np.float64]]] = {}
    hollows: dict[int, list[NDArray[np.float64]]] = {}
    crowds = strip_neighbours(hinge_rows, sides)
    if reliefs is not None:
        relief_planes, hollows = reliefs.cuts, reliefs.hollows
        for tile, planes in reliefs.cuts.items():
            jobs[tile].reliefs.extend(planes)
        for tile, polyhedra in hollows.items():  # cut as the hinge stage's trims are
            jobs[tile].trims.extend(polyhedra)
        notes.extend(relief_notes(reliefs, hinge_rows, print_clearance_mm))
    notes.extend(bend_notes(min_radius, inputs.steps, profile))
    notes.extend(strip_notes(flat, hinge_rows, sides, profile, crowds))
    plans: list[PinPlan | None] = [None] * len(hinge_rows)
    if profile.hinge_interlock == "through-holes":
        plans = list(
            plan_all_pins(
                flat,
                hinge_rows,
                sides,
                inputs.steps,
                inputs.lifts,
                profile,
                crowds,
                relief_planes,
                hollows,
            )
        )
        notes.extend(pin_notes(plans))
    fasteners = 0
    if profile.hinge_interlock in ("screws", "staples"):
        holes = strip_hole_plans(flat, hinge_rows, sides, profile, crowds)
        fasteners = sum(h.fasteners for h in holes)
        notes.extend(hole_notes(holes, profile))
    hinge_data = tuple(
        (flat[a], int(ca), flat[b], int(cb), side, None if plan is None else plan.pins, crowd)
        for (a, ca, b, cb), side, plan, crowd in zip(hinge_rows, sides, plans, crowds, strict=True)
    )
    for index, (a, _, b, _) in enumerate(hinge_rows):
        jobs[a].hinges.append((index, True))
        jobs[b].hinges.append((index, False))
        jobs[a].pads.append(index)  # tile a's worker builds the pad
    return hinge_data, fasteners


def _gather(
    results: list[JobResult],
    inputs: _Inputs,
    labels: bool,
    failed: list[tuple[int, str]],
    notes: list[str],
    profile: Profile,
) -> tuple[tuple[bd.Solid, ...], dict[int, bd.Solid], list[int]]:
    """The workers' tiles in tile order, their pads by hinge and the tiles left unlabelled;
    their notes and failures into ``notes`` and ``failed`` (sorted by tile)."""
    n_tiles = len(inputs.flat)
    tiles: list[bd.Solid | None] = [None] * n_tiles
    pads: dict[int, bd.Solid] = {}
    for done in sorted(results, key=lambda r: r.tile):
        tiles[done.tile] = done.solid
        pads.update(done.pads)
        notes.extend(done.notes)
        failed += [(done.tile, name) for name in done.failed]
    failed.sort(key=lambda f: f[0])
    notes.extend(
        f"tile {tile}: its {name} failed in the CAD kernel and was left out"
        for tile, name in failed
    )
    split = sorted((r.tile, r.dropped_mm3) for r in results if r.dropped_mm3 > 0)
    if split:
        notes.append(
            f"features cut {len(split)} of {n_tiles} tiles into pieces; each keeps its largest "
            f"piece, dropping up to {max(v for _, v in split):.3g} mm^3: "
            f"{id_ranges([t for t, _ in split])}"
        )
    unlabelled = sorted(r.tile for r in results if not r.labelled) if labels else []
    if unlabelled:
        notes.append(
            f"tile numbers not engraved on {len(unlabelled)} of {n_tiles} tiles, too small "
            f"for digits of {feature_wall_mm(profile):g} mm strokes clear of the hinge strips "
            f"and pins on their bottom faces: {id_ranges(unlabelled)}"
        )
    return tuple(t for t in tiles if t is not None), pads, unlabelled
