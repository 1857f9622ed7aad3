"""Build every tile and hinge part of a design as B-rep solids, in parallel worker processes.

Each tile is cut once, with only the tools that touch it (channels and lift bores of its route
steps, its hinges' pad recesses and interlocks, its magnet pockets, trims and its label).  Work is
split into chunks of tiles; each worker builds the tools it needs from plain arrays (nothing but
numbers cross the process boundary on the way in; the finished solids pickle on the way out).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.clearance import HingeReliefs, hinge_reliefs
from drawstring.cad.features import (
    BEND_RADIUS_SLACK_MM,
    Footprint,
    HingePins,
    HingeSide,
    KeepOut,
    MagnetPair,
    PinPlan,
    StripHoles,
    StripNeighbours,
    build_tile,
    channel_keep_out,
    feature_wall_mm,
    hinge_face_footprints,
    hinge_pad,
    hinge_strip_lengths,
    label_engraving,
    lift_bore,
    lift_chamfer,
    magnet_pockets,
    pin_keep_out,
    plan_pins,
    string_channel,
    strip_hole_plan,
    strip_keep_outs,
    trim_tool,
)
from drawstring.cad.features import channel_radius as _channel_radius
from drawstring.cad.hinge_parts import strip_hole_wall_mm
from drawstring.cad.paths import SIDE_TOP_FACE, channel_path, lift_path
from drawstring.cad.tiles import move_solid, relieved_tile_solid, rigid_transforms, tile_solid
from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.tiling.linkage import id_runs

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)

Pose = Literal["flat", "assembled"]

#: Below this many tiles the build runs in the calling process (worker start-up does not pay).
PARALLEL_MIN_TILES = 24


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


@dataclass
class _TileJob:
    """Everything a worker needs to build one tile (plain numbers and small tool solids)."""

    tile: int
    vertices: NDArray[np.float64]
    channels: list[tuple[int, int]] = field(default_factory=list)
    lifts: list[int] = field(default_factory=list)
    tools: list[bd.Solid] = field(default_factory=list)
    trims: list[NDArray[np.float64]] = field(default_factory=list)
    reliefs: list[NDArray[np.float64]] = field(default_factory=list)  # planes: keep n . x >= d
    hinges: list[tuple[int, bool]] = field(default_factory=list)
    label: bool = False
    pads: list[int] = field(default_factory=list)


_HingeData = tuple[
    NDArray[np.float64], int, NDArray[np.float64], int, HingeSide, HingePins | None, StripNeighbours
]


@dataclass
class _JobResult:
    """A worker's tile: its solid, the pads it built, its notes, whether its number was
    engraved, and the features whose cut failed and were left out."""

    tile: int
    solid: bd.Solid
    pads: list[tuple[int, bd.Solid]]
    notes: list[str]
    labelled: bool
    failed: list[str]
    dropped_mm3: float = 0.0  # pieces the features cut off the tile (the largest is kept)


def normalize_route(route_steps: NDArray[np.int64] | Sequence[Sequence[int]]) -> NDArray[np.int64]:
    """Route steps as an (S, 4) int array ``(gap, tile, enter_side, leave_side)``.

    Accepts (S, 3) ``(tile, enter, leave)`` (gap column filled with 0) or (S, 4).  Sides are 0..3
    or ``SIDE_TOP_FACE`` (4, through the top face); gap -1 marks a virtual entrance.
    """
    steps = np.asarray(route_steps, dtype=np.int64)
    if steps.size == 0:
        return np.zeros((0, 4), dtype=np.int64)
    if steps.ndim != 2 or steps.shape[1] not in (3, 4):
        raise InputError(f"route steps must be (S, 3) or (S, 4) ints, got shape {steps.shape}")
    if steps.shape[1] == 3:
        steps = np.hstack([np.zeros((len(steps), 1), dtype=np.int64), steps])
    sides = steps[:, 2:]
    if np.any((sides < 0) | (sides > SIDE_TOP_FACE)):
        raise InputError(f"route sides must be 0..3 or {SIDE_TOP_FACE} (top face)")
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


def _kernel_failure(what: str, exc: Exception) -> None:
    """Re-raise bad input; log any other exception (OCP's Standard_Failure, build123d's errors)
    as the kernel failure of ``what``, which the caller leaves out."""
    if isinstance(exc, InputError):
        raise exc
    log.debug("%s: %s: %s", what, type(exc).__name__, exc, exc_info=exc)


def _build_job(job: _TileJob, profile: Profile, hinge_data: tuple[_HingeData, ...]) -> _JobResult:
    """Worker: build the tools of one tile, cut them, and build the pads this tile owns.

    A feature whose tool or cut fails in the kernel (any exception but :class:`InputError`) is
    left out and named in the result's ``failed``; a tile whose cut fails altogether is the
    plain block, every feature named; a hinge part that cannot be built is left out, named too.
    """
    notes: list[str] = []
    failed: list[str] = []
    tools: list[bd.Shape] = list(job.tools)
    names = ["magnet pocket"] * len(tools)

    def add(name: str, make: Callable[[], bd.Shape | None]) -> bool:
        """Add a tool; False only where ``make`` finds no room for it (returns None)."""
        try:
            tool = make()
        except Exception as exc:  # the kernel's own errors, whatever their class
            _kernel_failure(f"tile {job.tile}: {name}", exc)
            failed.append(name)
            return True
        if tool is None:
            return False
        tools.append(tool)
        names.append(name)
        return True

    for a, b in job.channels:
        add("string channel", partial(string_channel, job.vertices, a, b, profile))
    opened = {side for pair in job.channels for side in pair}
    for side in job.lifts:
        add("lift bore", partial(lift_bore, job.vertices, side, profile, shared=side in opened))
    for points in job.trims:
        add("trim", partial(trim_tool, points))
    owned = set(job.pads)
    built_pads: dict[int, bd.Solid] = {}
    bottom: list[Footprint] = []  # what the hinges put where the tile's number goes
    for hinge, is_a in job.hinges:
        tile_a, corner_a, tile_b, corner_b, side, pins, crowd = hinge_data[hinge]
        # The pad this tile owns comes out of the same call as its tools (one frame, one build).
        make_pad = hinge in owned and hinge not in built_pads
        try:
            if job.label:
                on_a, on_b = hinge_face_footprints(
                    tile_a, corner_a, tile_b, corner_b, side, profile, pins, crowd
                )
                bottom.extend(on_a if is_a else on_b)
            parts = hinge_pad(
                tile_a,
                corner_a,
                tile_b,
                corner_b,
                side,
                profile,
                build_pad=make_pad,
                pins=pins,
                neighbours=crowd,
            )
        except Exception as exc:
            _kernel_failure(f"tile {job.tile}: hinge {hinge}", exc)
            failed.append(f"hinge {hinge} recess or key")
            continue
        own = parts.tools_a if is_a else parts.tools_b
        tools.extend(own)
        names += [f"hinge {hinge} recess or key"] * len(own)
        if is_a:
            notes.extend(f"hinge {hinge}: {n}" for n in parts.notes)
        if make_pad and parts.pad is not None:
            built_pads[hinge] = parts.pad
    labelled = False
    if job.label:
        labelled = add(
            "number engraving", partial(label_engraving, job.vertices, job.tile, profile, bottom)
        )
    block: bd.Solid | None = None
    if job.reliefs:
        try:
            block = relieved_tile_solid(job.vertices, job.reliefs)
        except Exception as exc:  # the plain block follows, its reliefs named as failed
            _kernel_failure(f"tile {job.tile}: hinge relief", exc)
            failed.append("hinge relief")
    try:
        block = block if block is not None else tile_solid(job.vertices)
    except Exception as exc:
        _kernel_failure(f"tile {job.tile}: block", exc)
        raise InputError(
            f"tile {job.tile}: the CAD kernel cannot make a solid of its 8 vertices "
            f"({type(exc).__name__}); check the tile vertices"
        ) from exc
    failed_tools: list[int] = []
    dropped: list[float] = []
    try:
        solid = build_tile(block, tools, failed=failed_tools, dropped=dropped)
    except Exception as exc:
        _kernel_failure(f"tile {job.tile}: cut", exc)
        solid, failed_tools = block, list(range(len(tools)))
        dropped.clear()  # the uncut block is kept
    failed += [names[i] for i in failed_tools]
    pads = []
    for hinge in job.pads:
        if hinge not in built_pads:
            tile_a, corner_a, tile_b, corner_b, side, pins, crowd = hinge_data[hinge]
            try:
                pad = hinge_pad(
                    tile_a,
                    corner_a,
                    tile_b,
                    corner_b,
                    side,
                    profile,
                    build_pad=True,
                    pins=pins,
                    neighbours=crowd,
                ).pad
            except Exception as exc:
                _kernel_failure(f"tile {job.tile}: hinge {hinge} part", exc)
                pad = None
            if pad is None:
                failed.append(f"hinge {hinge} part")
                continue
            built_pads[hinge] = pad
        pads.append((hinge, built_pads[hinge]))
    return _JobResult(job.tile, solid, pads, notes, labelled, failed, sum(dropped))


def strip_neighbours(
    hinges: NDArray[np.int64], hinge_side: Sequence[HingeSide]
) -> list[StripNeighbours]:
    """Per hinge ``(tile_a, corner_a, tile_b, corner_b)``, the other corners of tile a's and of
    tile b's hinge face that hold strips too (hinges on the same face of the same tile), which
    the strip keeps a wall from (:func:`~drawstring.cad.hinge_parts.strip_room`)."""
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


def _plan_all_pins(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
    reliefs: Mapping[int, Sequence[NDArray[np.float64]]],
) -> list[PinPlan]:
    """The TPU pins of every through-holes hinge, each kept a wall away from its tile's
    channels and lift bores, the other hinges' strips, the pins planned before it (hinge
    order) and the planes of its tile's hinge reliefs (tile -> planes), so that no pin blocks
    the string, no two holes merge and no relief opens a hole."""
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
            (_planes(reliefs, a), _planes(reliefs, b)),
        )
        for tile, pin in zip((a, b), plan.pins, strict=True):
            if pin is not None:
                keep[tile] = keep[tile] + pin_keep_out(pin, profile)
        plans.append(plan)
    return plans


def _planes(
    reliefs: Mapping[int, Sequence[NDArray[np.float64]]], tile: int
) -> NDArray[np.float64] | None:
    found = reliefs.get(int(tile))
    return None if not found else np.asarray(found, dtype=np.float64).reshape(-1, 4)


def _build_chunk(
    jobs: list[_TileJob], profile: Profile, hinge_data: tuple[_HingeData, ...]
) -> list[_JobResult]:
    return [_build_job(job, profile, hinge_data) for job in jobs]


def _check_tiles(name: str, tiles: NDArray[np.float64]) -> NDArray[np.float64]:
    array = np.asarray(tiles, dtype=np.float64)
    if array.ndim != 3 or array.shape[1:] != (8, 3):
        raise InputError(f"{name} must be a (T, 8, 3) array of tile vertices, got {array.shape}")
    return array


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
    pose: Pose = "flat",
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
    Bad input still raises :class:`InputError`.
    """
    if pose not in ("flat", "assembled"):
        raise InputError(f"pose {pose!r} must be 'flat' or 'assembled'")
    flat = _check_tiles("tiles_2d", tiles_2d)
    assembled = _check_tiles("tiles_3d", tiles_3d)
    if flat.shape != assembled.shape:
        raise InputError(f"tiles_2d {flat.shape} and tiles_3d {assembled.shape} differ in shape")
    n_tiles = len(flat)
    hinge_rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    sides = list(hinge_side)
    if len(sides) != len(hinge_rows):
        raise InputError(f"hinge_side has {len(sides)} entries for {len(hinge_rows)} hinges")
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
            raise InputError(f"{name} refers to a tile outside 0..{n_tiles - 1}")

    jobs = [_TileJob(t, flat[t], label=labels) for t in range(n_tiles)]
    notes: list[str] = []
    min_radius = np.full(len(steps), np.inf)
    channel_sides: list[set[int]] = [set() for _ in range(n_tiles)]
    for index, (_, tile, enter, leave) in enumerate(steps):
        if SIDE_TOP_FACE in (enter, leave):
            if enter == leave:
                raise InputError(f"route step {index} enters and leaves through the top face")
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
    for tile, side in lifts:
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
            f"lift bores leave tiles {_id_ranges(plain)} without a chamfer: their top faces are "
            "too small for one (the string runs over the bore's edge there)"
        )

    magnets = []
    clearance = _channel_radius(profile) + 0.5 * profile.magnet_diameter_mm
    # the web left to the channel: a printed wall, or for plywood half the tool's width of wood
    clearance += profile.magnet_clearance_mm + max(
        profile.nozzle_mm, 0.5, 0.5 * profile.tool_diameter_mm
    )
    failed: list[tuple[int, str]] = []
    for tile_a, side_a, tile_b, side_b in pairs:
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
            )
        except Exception as exc:
            _kernel_failure(f"tiles {tile_a} and {tile_b}: magnet pockets", exc)
            failed += [(int(tile_a), "magnet pocket"), (int(tile_b), "magnet pocket")]
            continue
        jobs[tile_a].tools.append(tool_a)
        jobs[tile_b].tools.append(tool_b)
        magnets.append(record)
    broken = [m for m in magnets if not m.fits]
    if broken:
        broken_pairs = ", ".join(f"{m.tile_a}/{m.tile_b}" for m in broken[:_MAX_RUNS])
        more = f" and {len(broken) - _MAX_RUNS} more" if len(broken) > _MAX_RUNS else ""
        notes.append(
            f"{len(broken)} of {len(magnets)} magnet pairs have pockets "
            f"({broken[0].diameter_mm:.2f} mm) breaking out of their side faces (tiles "
            f"{broken_pairs}{more})"
        )

    if not (np.isfinite(print_clearance_mm) and print_clearance_mm >= 0):
        raise InputError(f"print_clearance_mm must be 0 or more, got {print_clearance_mm}")
    for tile, polyhedra in (trims or {}).items():
        if not 0 <= tile < n_tiles:
            raise InputError(f"trims refer to tile {tile} outside 0..{n_tiles - 1}")
        for points in polyhedra:
            jobs[tile].trims.append(np.asarray(points, dtype=np.float64))

    for side in sides:
        if side not in ("top", "bottom"):
            raise InputError(f"hinge side {side!r} must be 'top' or 'bottom'")
    relief_planes: dict[int, list[NDArray[np.float64]]] = {}
    if print_clearance_mm > 0 and len(hinge_rows):
        reliefs = hinge_reliefs(flat, hinge_rows, sides, print_clearance_mm)
        relief_planes = reliefs.cuts
        for tile, planes in reliefs.cuts.items():
            jobs[tile].reliefs.extend(planes)
        notes.extend(_relief_notes(reliefs, hinge_rows, print_clearance_mm))
    notes.extend(_bend_notes(min_radius, steps, profile))
    crowds = strip_neighbours(hinge_rows, sides)
    notes.extend(_strip_notes(flat, hinge_rows, sides, profile, crowds))
    plans: list[PinPlan | None] = [None] * len(hinge_rows)
    if profile.hinge_interlock == "through-holes":
        plans = list(
            _plan_all_pins(flat, hinge_rows, sides, steps, lifts, profile, crowds, relief_planes)
        )
        notes.extend(_pin_notes(plans))
    fasteners = 0
    if profile.hinge_interlock in ("screws", "staples"):
        holes = strip_hole_plans(flat, hinge_rows, sides, profile, crowds)
        fasteners = sum(h.fasteners for h in holes)
        notes.extend(_hole_notes(holes, profile))
    hinge_data = tuple(
        (flat[a], int(ca), flat[b], int(cb), side, None if plan is None else plan.pins, crowd)
        for (a, ca, b, cb), side, plan, crowd in zip(hinge_rows, sides, plans, crowds, strict=True)
    )
    for index, (a, _, b, _) in enumerate(hinge_rows):
        jobs[a].hinges.append((index, True))
        jobs[b].hinges.append((index, False))
        jobs[a].pads.append(index)  # tile a's worker builds the pad

    results = _run_jobs(jobs, profile, hinge_data, workers)

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
            f"{_id_ranges([t for t, _ in split])}"
        )
    unlabelled = [r.tile for r in results if not r.labelled] if labels else []
    if unlabelled:
        notes.append(
            f"tile numbers not engraved on {len(unlabelled)} of {n_tiles} tiles, too small "
            f"for digits of {feature_wall_mm(profile):g} mm strokes clear of the hinge strips "
            f"and pins on their bottom faces: {_id_ranges(unlabelled)}"
        )
    transforms, residual = rigid_transforms(flat, assembled)
    if residual.size and residual.max() > 1e-3:
        notes.append(
            f"flat and assembled tiles differ by up to {residual.max():.3g} mm beyond a rigid "
            "motion; checks in the assembled pose are approximate"
        )
    built = tuple(t for t in tiles if t is not None)
    pad_hinge = np.array(sorted(pads), dtype=np.int64)
    pad_solids = tuple(pads[h] for h in pad_hinge)
    if pose == "assembled":
        built = tuple(move_solid(s, m) for s, m in zip(built, transforms, strict=True))
        pad_solids, pad_hinge = (), np.zeros(0, dtype=np.int64)
    for note in notes:  # returned in CadResult.notes, which the design lists
        log.info("%s", note)
    return CadResult(
        pose,
        built,
        pad_solids,
        pad_hinge,
        tuple(magnets),
        min_radius,
        transforms,
        tuple(notes),
        tuple(failed),
        fasteners,
        tuple(int(t) for t in unlabelled),
    )


#: Notes list at most this many runs of ids (then how many more there are).
_MAX_RUNS = 12


def _id_ranges(ids: Iterable[int]) -> str:
    """Sorted ids as runs, ``0-3, 7, 9-10``, the first :data:`_MAX_RUNS` of them."""
    return id_runs(ids, _MAX_RUNS)


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


def _bend_notes(
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
        + (f"; steps {_id_ranges(tight)}" if len(tight) > 1 else "")
    ]


def _strip_notes(
    flat: NDArray[np.float64],
    hinge_rows: NDArray[np.int64],
    sides: Sequence[HingeSide],
    profile: Profile,
    crowds: Sequence[StripNeighbours],
) -> list[str]:
    """One note for the hinge strips shortened to keep a wall from the other strips of their
    tiles (:func:`~drawstring.cad.hinge_parts.hinge_strip_lengths`)."""
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
        f"that the strips of a tile's corners keep a wall apart (hinges {_id_ranges(short)})"
    ]


def _hole_notes(holes: Sequence[StripHoles], profile: Profile) -> list[str]:
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
        f"{_id_ranges(missing)})"
    )
    if bare:
        note += (
            f"; {bare} strip halves have none left: glue those, or use fewer, larger tiles "
            "(--tiles)"
        )
    return [note]


def _relief_notes(
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
    if reliefs.skipped:
        tiles = sorted({int(t) for h in reliefs.skipped for t in hinge_rows[h, [0, 2]]})
        notes.append(
            f"{len(reliefs.skipped)} hinges were not relieved for printing (a relief would cut "
            f"away too much of a tile): tiles {_id_ranges(tiles)} may print joined there"
        )
    return notes


def _pin_notes(plans: Sequence[PinPlan]) -> list[str]:
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
            f"string channel, a lift bore or another hinge (hinges {_id_ranges(short)})"
        )
    if count_missing:
        notes.append(
            f"{count_missing} of {total} hinge pins left out, no room for them on their tiles: "
            f"those pads are held by their recess only (hinges {_id_ranges(missing)})"
        )
    return notes


def _run_jobs(
    jobs: list[_TileJob],
    profile: Profile,
    hinge_data: tuple[_HingeData, ...],
    workers: int | None,
) -> list[_JobResult]:
    count = workers if workers is not None else (os.cpu_count() or 1)
    if count <= 1 or len(jobs) < PARALLEL_MIN_TILES:
        return _build_chunk(jobs, profile, hinge_data)
    # Interleave tiles over chunks so each chunk gets a similar mix of features.
    n_chunks = min(len(jobs), 4 * count)
    chunks = [jobs[i::n_chunks] for i in range(n_chunks)]
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    results: list[_JobResult] = []
    with parallel.process_pool(count, context) as pool:
        futures = [pool.submit(_build_chunk, chunk, profile, hinge_data) for chunk in chunks]
        for future in futures:
            results.extend(future.result())
    return results
