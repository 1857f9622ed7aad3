"""The stages from tiling to hinges, and the tiling again where the layout misses.

:func:`shape_and_layout` tiles the flattened target, shapes the assembled tiles (paper eq. 1
and extrusion), lays them flat, co-optimizes both (:func:`co_optimized`) and places the hinges;
where the flat tiles then miss their hinges by more than the targets it tiles again with
tighter splits (:data:`RETILE_ATTEMPTS`) and keeps the most accurate result.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import sys
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry import parallel, verify
from drawstring.geometry.assembled import (
    AssembledResult,
    hinge_depth_pull,
    optimize_assembled,
    quad_vector_areas,
    reextrude,
    remeasured,
    tile_vertices,
)
from drawstring.geometry.coflat import CO_CONICAL, CO_STAGES, CoOptimizedTop, co_optimize_top
from drawstring.geometry.flat import FlatResult, extrude_flat, hinge_face_openings, optimize_flat
from drawstring.geometry.flatpose import HingeFaces, hinge_faces
from drawstring.geometry.flatten import Flattening
from drawstring.geometry.hinges import HingeLayout, dual_hinge_faces, layout_hinges
from drawstring.geometry.linkage import Linkage
from drawstring.geometry.rigid import rigid_copies
from drawstring.geometry.solver import LinearPull
from drawstring.geometry.target import Target
from drawstring.geometry.tiling import Tiling, component_flattenings, tile_surface
from drawstring.geometry.tolerances import (
    FLAT_EDGE_ERROR_TOL_MM,
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_GAP_TOL_MM,
)

from .ahead import Ahead as _Ahead
from .co_ladder import CoLadder

if TYPE_CHECKING:
    from .pipeline import Progress, ResolvedOptions

logger = logging.getLogger(__name__)


def fabricated_tiles(layout: HingeLayout, tiles_3d: NDArray[np.float64]) -> NDArray[np.float64]:
    """(T, 8, 3) the flat tiles as fabricated: each assembled tile moved rigidly onto its place
    in the hinge layout before merging (congruent to T3D; the hinge parts bridge the residual
    hinge gaps)."""
    placed = layout.rigid_tiles if layout.rigid_tiles is not None else layout.tiles
    return rigid_copies(tiles_3d, placed)


def split_bound(options: ResolvedOptions) -> float:
    """Largest tile area ratio a part may have: ``--max-scale-factor``, and no more than a quad
    linkage can absorb with every gap opening between ``--min-gap-angle`` and 90 degrees: a gap
    opened by theta expands the layout by ``1 + sin(theta)``, so the ratio is at most
    ``2 / (1 + sin(theta_min))``."""
    return min(options.max_scale_factor, absorbable_ratio(options.min_gap_angle_deg))


def absorbable_ratio(min_gap_angle_deg: float) -> float:
    """``2 / (1 + sin(theta_min))``: the largest tile area ratio gaps opening between
    ``min_gap_angle_deg`` and 90 degrees can absorb (see :func:`split_bound`)."""
    return 2.0 / (1.0 + math.sin(math.radians(min_gap_angle_deg)))


#: Extra tilings tried, each with a tighter split bound, when the flat layout misses its
#: accuracy targets (flat edge error or hinge gap above 1e-3 mm).  The scale bound of
#: a split is necessary, not sufficient: a part whose area scale varies within it can still
#: leave the tiles no flat layout that keeps their shape (the 200-tile chair: one part of
#: ratio 1.55 < 1.66, 0.5 mm off; two parts of ratio 1.15, 1.5e-4 mm).
RETILE_ATTEMPTS = 2

#: Each extra tiling keeps this share of the current largest part ratio's excess over 1.
RETILE_SHRINK = 0.7

#: Tiling again is tried only when the first tiling's largest part ratio uses at least this
#: share of the bound's excess over 1 (of the 0.66 at 12 deg: 200-tile chair 0.84, seashell
#: 0.58; the 1600-tile wave, whose miss has another cause, 0.05).
RETILE_MIN_SHARE = 0.5

#: A tighter tiling is kept only when it at least halves the accuracy figure or meets the
#: accuracy targets (more parts cost a longer route and more assembly, so a marginal gain that
#: still misses them does not pay for them); one that does neither ends the search.
RETILE_GAIN = 0.5


@dataclass(frozen=True)
class ShapedLayout:
    """One tiling and the shapes laid out on it: assembled (eq. 1, extruded, co-optimized),
    flat and hinged."""

    tiling: Tiling
    assembled: AssembledResult
    flat: FlatResult
    co_block: dict[str, Any]
    #: None when the hinge stage was skipped (``fallback=False`` and a hopeless flat layout)
    hinge_layout: HingeLayout | None
    split_bound: float
    notes: tuple[str, ...]
    #: the co-optimization was refused and its held-openings run skipped, or cut short for
    #: slow progress, or the hinge stage skipped (``fallback=False``): a full run is owed if
    #: this tiling is kept
    fallback_skipped: bool = False

    @property
    def accuracy_mm(self) -> float:
        """The larger of the flat edge error and the hinge gap, mm, as measured on the output
        (:func:`~drawstring.fabrication.pipeline.measure_design`): how far the flat tiles are
        from meeting at their hinges with their assembled shapes (the flat layout's edge error
        where the hinge stage was skipped).  The gap is the whole one, its vertical part too:
        a tighter tiling whose conical co-optimization succeeds closes that part where the
        first tiling's had to go without (the seashell at the CLI defaults: 0.011 mm in one
        part, 5.0e-4 mm in two)."""
        if self.hinge_layout is None:
            return self.flat.edge_error_max_mm
        tiles = self.assembled.tiles
        edge = verify.flat_edge_errors(self.hinge_layout.tiles[:, :4, :2], tiles[:, :4])
        fabricated = fabricated_tiles(self.hinge_layout, tiles)
        gaps = verify.hinge_gaps(fabricated, self.hinge_layout.hinge_vertices)
        return max(float(edge.max(initial=0.0)), float(gaps.max(initial=0.0)))


#: A quad mesh as a dictionary key: vertex array shape and bytes, quad array shape and bytes.
MeshKey = tuple[tuple[int, ...], bytes, tuple[int, ...], bytes]


def shape_and_layout(
    loaded: Target, flat_map: Flattening, options: ResolvedOptions, progress: Progress
) -> ShapedLayout:
    """Tile, shape and lay out the target (stages tiling to hinges), tiling again with a
    tighter split bound (:data:`RETILE_ATTEMPTS`) while the layout misses its accuracy
    targets; the most accurate result is kept (see :data:`RETILE_GAIN`)."""

    def tiled(bound: float) -> Tiling:
        with progress.stage("tiling"):
            return tile_surface(
                loaded.vertices,
                loaded.faces,
                flat_map.uv,
                tiles=options.tiles,
                grid=options.grid,
                max_scale_factor=bound,
            )

    # Tighter split bounds cut the linkage but keep the quad mesh, so eq. 1 and the extrusion
    # are solved once per distinct mesh (1-2 s each at 200 tiles; the chair re-tiles twice).
    shapes: dict[MeshKey, AssembledResult] = {}
    bound = split_bound(options)
    first_tiling = tiled(bound)
    if first_tiling.scale_factor_max - 1.0 < RETILE_MIN_SHARE * (bound - 1.0):
        # its area scale hardly varies: more splits are not what it lacks
        return _shaped(first_tiling, bound, loaded, options, progress, shapes, spare_core=True)
    # A tiling that may be split again goes without the held-openings fallback: its
    # co-optimization is refused for its area scale, which more splits mend (the 200-tile
    # chair in one part: the fallback took 4.5 s and still missed by 0.2 mm).  It runs after
    # all if the first tiling is the one kept.
    ahead: _Ahead[ShapedLayout] | None = None
    prepared: Tiling | None = None  # the first tighter tiling, when tiled ahead of the loop
    if RETILE_AHEAD and _can_fork() and RETILE_ATTEMPTS > 0:
        # The first tighter tiling, which the loop below lays out if the first tiling misses,
        # is laid out meanwhile in a second process (the 200-tile seashell and chair).
        next_bound = _tighter(bound, first_tiling)
        prepared = next_tiling = tiled(next_bound)
        if not _same_parts(next_tiling, first_tiling):
            _assembled_shape(first_tiling, loaded, options, progress, shapes)  # shared by both

            def work(child_progress: Progress) -> ShapedLayout:
                return _shaped(next_tiling, next_bound, loaded, options, child_progress, shapes)

            try:
                ahead = _Ahead(work, "the tiling laid out ahead")
            except OSError as exc:  # no process to spare (fork refused): laid out in turn
                logger.warning("could not lay the tighter tiling out ahead (%s)", exc)
    try:
        first = best = _shaped(
            first_tiling, bound, loaded, options, progress, shapes, fallback=False,
            spare_core=ahead is None,
        )  # fmt: skip
        first_accuracy = best_accuracy = first.accuracy_mm
        target = min(FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM)
        tried: list[str] = []
        for _ in range(RETILE_ATTEMPTS):
            if best_accuracy <= target:
                break
            bound = _tighter(bound, best.tiling)
            tiling = prepared if prepared is not None else tiled(bound)
            prepared = None
            trial: ShapedLayout | None = None
            if ahead is not None:  # laid out meanwhile (its tiling is ``prepared``)
                trial, ahead = ahead.result(progress), None
            if _same_parts(tiling, best.tiling):
                break  # no further split keeps enough cells on each side
            if trial is None:
                trial = _shaped(tiling, bound, loaded, options, progress, shapes, spare_core=True)
            accuracy = trial.accuracy_mm
            tried.append(f"{_parts(tiling)} at bound {bound:.3g}: {accuracy:.2g} mm")
            if not (accuracy < RETILE_GAIN * best_accuracy or accuracy <= target):
                break  # splitting does not help this design (e.g. errors at split-line ends)
            best, best_accuracy = trial, accuracy
    finally:
        if ahead is not None:
            ahead.cancel()  # the first tiling met the targets: its result is not needed
    if best is first and first.fallback_skipped and first_accuracy > target:
        # kept after all: co-optimized in full, with the held-openings fallback
        best = first = _shaped(
            first_tiling, first.split_bound, loaded, options, progress, shapes, spare_core=True
        )
    if not tried:
        return first
    outcome = f"kept {_parts(best.tiling)}" if best is not first else "kept the first tiling"
    note = (
        f"tiling: with split bound {first.split_bound:.3g} ({_parts(first.tiling)}) the flat "
        f"tiles met their hinges with their assembled shapes only to {first_accuracy:.2g} mm; "
        f"tighter splits gave {'; '.join(tried)}; {outcome}"
    )
    return replace(best, notes=(*best.notes, note))


def _tighter(bound: float, tiling: Tiling) -> float:
    """The split bound of the tiling tried after ``tiling`` (split with ``bound``)."""
    return 1.0 + RETILE_SHRINK * (min(bound, tiling.scale_factor_max) - 1.0)


def _parts(tiling: Tiling) -> str:
    count = tiling.linkage.n_components
    return f"{count} part" if count == 1 else f"{count} parts"


def _same_parts(a: Tiling, b: Tiling) -> bool:
    """Whether two tilings of one grid split it into the same parts."""
    return a.linkage.n_tiles == b.linkage.n_tiles and bool(
        np.array_equal(a.linkage.tile_component, b.linkage.tile_component)
    )


def _shaped(
    tiling: Tiling,
    bound: float,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: dict[MeshKey, AssembledResult],
    *,
    fallback: bool = True,
    spare_core: bool = False,
) -> ShapedLayout:
    """Stages assembled to hinges on one tiling (see :func:`shape_and_layout`); with
    ``fallback=False`` a refused co-optimization is not run again holding the eq.-1
    openings, and the hinge stage is skipped when the flat layout is too far off.
    ``spare_core``: no other process lays out a tiling meanwhile, so the co-optimization
    without the conical condition is run ahead while the conical ones run
    (:class:`~.co_ladder.CoLadder`).
    ``shapes`` holds the assembled configurations already solved, by quad mesh; their arrays
    are read-only, as they may be shared between tilings (and so are those of a design that
    keeps the eq.-1 tiles, e.g. with ``--no-co-optimize``)."""
    notes = list(tiling.notes)
    linkage = tiling.linkage
    skipped = False
    assembled = _assembled_shape(tiling, loaded, options, progress, shapes)
    # Hinge sides are decided on the eq.-1 tiles (and again once their bottom corners are
    # pulled to equal depths, which can move a side); the flat layout makes the hinged
    # corners meet on the face that carries each hinge.
    faces = (
        dual_hinge_faces(linkage, assembled.tiles, options.min_gap_angle_deg)
        if options.hinges == "dual"
        else None
    )
    if faces is not None and HINGE_DEPTHS and faces.bottom.any():
        assembled = _bottom_hinge_depths(assembled, linkage, faces.bottom, loaded)
        faces = dual_hinge_faces(linkage, assembled.tiles, options.min_gap_angle_deg)
    with progress.stage("flat"):
        # only a seed when the co-optimization follows (FLAT_SEED_STEPS)
        seed_steps = FLAT_SEED_STEPS if options.co_optimize else None
        flat = flat_layout(linkage, tiling, assembled, options, faces, seed_steps=seed_steps)
    if options.co_optimize:
        with progress.stage("co-optimize"):
            plain = (assembled, flat)
            # With bottom hinges the top is made conical too (their corners then meet in
            # depth); where that costs the flat layout its targets, it is co-optimized again
            # with the next weight of the condition (CONICAL_RETRY_WEIGHTS), and after the
            # last without it (the face scan: 0.012 mm conical, within 1e-3 mm without).
            conical = (
                HINGE_DEPTHS and CO_CONICAL > 0 and faces is not None and bool(faces.bottom.any())
            )
            ladder = CoLadder(
                lambda step: _co_optimized_with_fallback(
                    linkage, tiling, *plain, loaded, options, faces, fallback, *step
                ),
                conical,
                spare_core and _can_fork(),
            )  # fmt: skip
            far = None if fallback else CO_SLOW_REACH * FLAT_EDGE_ERROR_TOL_MM
            assembled, flat, co_block, skipped, note = ladder.run(far)
            if note:
                notes.append(note)
        if not co_block["accepted"]:
            notes.append(f"co-optimization not used: {co_block['reason']}")
            if flat.iterations >= FLAT_SEED_STEPS:
                with progress.stage("flat"):  # the seed is the layout now: finish it
                    flat = flat_layout(
                        linkage, tiling, assembled, options, faces, initial_nodes=flat.nodes
                    )
    else:
        co_block = {"accepted": False, "reason": "off (--no-co-optimize)"}
    hinge_layout: HingeLayout | None = None
    if not fallback and flat.edge_error_max_mm > CO_SLOW_REACH * FLAT_EDGE_ERROR_TOL_MM:
        # A tiling that may still be split skips the hinge stage when its flat layout is too
        # far off for the rigid hinge layout to reach the targets (it takes off about 4x, see
        # CO_SLOW_REACH; on a layout this far off it can add: 200-tile seashell in one part,
        # 0.052 mm flat, 0.082 mm hinged): it is tiled again, and laid out in full if kept.
        skipped = True
    else:
        tiles_2d = extrude_flat(flat, assembled.tiles, options.thickness_mm)
        with progress.stage("hinges"):
            # dual: the sides and clear openings the kept flat layout was made for
            hinge_layout = layout_hinges(
                linkage, flat, tiles_2d, assembled.tiles, strategy=options.hinges
            )
    return ShapedLayout(
        tiling=tiling,
        assembled=assembled,
        flat=flat,
        co_block=co_block,
        hinge_layout=hinge_layout,
        split_bound=bound,
        notes=tuple(notes),
        fallback_skipped=skipped,
    )


#: Pull the bottom hinges' corners to equal depths before the flat layout (dual hinges; see
#: :func:`_bottom_hinge_depths`).
HINGE_DEPTHS = True


def _bottom_hinge_depths(
    assembled: AssembledResult, linkage: Linkage, bottom: NDArray[np.bool_], loaded: Target
) -> AssembledResult:
    """The assembled tiles with their bottom vertices moved (tops held, every face planar) so
    that the ``bottom`` hinges' corners lie as deep under both tiles' top faces as they can
    (:func:`~drawstring.geometry.assembled.hinge_depth_pull`).  Read-only like the eq.-1
    tiles it stands for (a design whose co-optimization is refused keeps it)."""
    moved = reextrude(
        assembled, assembled.top, loaded.vertices, loaded.faces, start_bottom=assembled.bottom,
        pull=_depth_pull(assembled, linkage, bottom),
    )  # fmt: skip
    if moved is None:
        return assembled
    for array in (moved.top, moved.bottom, moved.tiles):
        array.flags.writeable = False
    return moved


def _co_optimized_with_fallback(
    linkage: Linkage,
    tiling: Tiling,
    assembled: AssembledResult,
    flat: FlatResult,
    loaded: Target,
    options: ResolvedOptions,
    faces: HingeFaces | None,
    fallback: bool,
    conical: bool,
    conical_weight: float | None = None,
) -> tuple[AssembledResult, FlatResult, dict[str, Any], bool]:
    """:func:`co_optimized` tracking the clear openings and, when that is refused and
    ``fallback`` (and not ``conical``: the caller tries that again otherwise), again holding the
    eq.-1 tiles' openings; also whether a full run is owed
    (:attr:`ShapedLayout.fallback_skipped`)."""
    first_solves: dict[str, CoOptimizedTop] = {}
    new_assembled, new_flat, co_block = co_optimized(
        linkage, tiling, assembled, flat, loaded, options, faces, give_up_slow=not fallback,
        first_solves=first_solves, conical=conical, conical_weight=conical_weight,
    )  # fmt: skip
    refused = not co_block["accepted"] and faces is not None
    skipped = (refused and not fallback) or bool(co_block.get("cut_short"))
    if refused and fallback and not conical:
        # On the moved tiles some slit ends no longer clear where they did, and the windows
        # that shift between rounds can leave the re-solve stranded (1600-tile wave: 0.14 mm
        # -> 1.4 mm); the clear openings of the eq.-1 tiles held throughout reach 7.5e-4 mm
        # there.  The hinge stage separates the final tiles exactly either way.
        held = co_optimized(
            linkage, tiling, assembled, flat, loaded, options, faces, track_openings=False,
            first_solves=first_solves, conical=conical,
        )  # fmt: skip
        if held[2]["accepted"]:
            new_assembled, new_flat = held[0], held[1]
            co_block = {**held[2], "openings": "held from the eq.-1 tiles"}
    return new_assembled, new_flat, co_block, skipped


def _depth_pull(shape: AssembledResult, linkage: Linkage, bottom: NDArray[np.bool_]) -> LinearPull:
    """The pull of the ``bottom`` hinges' corners of ``shape`` to equal depths under both
    tiles' top faces (:func:`~drawstring.geometry.assembled.hinge_depth_pull`)."""
    hinges = linkage.hinges[bottom]
    vertex = shape.quads[hinges[:, 0], hinges[:, 1]]
    return hinge_depth_pull(shape, vertex, hinges[:, 0], hinges[:, 2])


def _assembled_shape(
    tiling: Tiling,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: dict[MeshKey, AssembledResult],
) -> AssembledResult:
    """The assembled configuration of ``tiling``'s quad mesh (paper eq. 1 and extrusion),
    solved once per mesh and kept in ``shapes`` with read-only arrays."""
    key = (
        tiling.vertices.shape,
        tiling.vertices.tobytes(),
        tiling.quads.shape,
        tiling.quads.tobytes(),
    )
    with progress.stage("assembled"):
        if key not in shapes:
            shapes[key] = optimize_assembled(
                tiling.vertices,
                tiling.quads,
                loaded.vertices,
                loaded.faces,
                thickness=options.thickness_mm,
                w_planar=options.weights[0],
                w_square=options.weights[1],
                w_surface=options.weights[2],
            )
            for array in (shapes[key].top, shapes[key].bottom, shapes[key].tiles):
                array.flags.writeable = False  # shared between tilings: nothing may edit it
        return shapes[key]


#: Lay out the first tighter tiling in a second process while the first tiling is laid out
#: (:class:`~drawstring.fabrication.ahead.Ahead`), where the machine has two cores or more
#: and processes can be forked.
#: Its result is the one the serial run would compute: it is used only if the first tiling
#: misses the targets, and thrown away otherwise.
RETILE_AHEAD = True


def _can_fork() -> bool:
    """Whether work may be run ahead in a forked child (a tiling, :data:`RETILE_AHEAD`; a
    co-optimization, :data:`~.co_ladder.CO_SPECULATE`): two cores or more, Linux (forking a
    process that has loaded macOS system frameworks is unsafe), and not inside a daemonic
    process (e.g. a ``multiprocessing`` pool worker: it may not fork)."""
    return (
        sys.platform.startswith("linux")
        and parallel.thread_count() >= 2
        and "fork" in multiprocessing.get_all_start_methods()
        and not multiprocessing.current_process().daemon
    )


#: Gauss-Newton steps after which the flat layout that only seeds the co-optimization (which
#: moves it anyway) stops, at the end of the first augmented-Lagrangian round whose bounds all
#: hold (a seed that breaks them would make the co-optimization's "keeps every hard bound"
#: test meaningless).  The 200-tile built-ins' plain layouts settle within 125 steps, both
#: hinge strategies, except the three-shell's with dual hinges: its bounds hold after 120
#: steps and it then polished its 0.27 mm least-squares optimum up to the 400-step cap
#: (1.2 s); it now stops at 251 steps and still meets the targets (7 parts; flat edge error
#: 6.2e-5 mm, was 5.7e-5; in-plane hinge gap 7.4e-4 mm as before).  The other fifteen rows
#: are bitwise unchanged.  At 1600 tiles the wave's plain layout stops at 262 steps instead
#: of 308, and its hinges meet within 1.9e-4 mm.  Where the co-optimization is not used, the
#: seed is finished.
FLAT_SEED_STEPS = 150


#: Extra rounds of :func:`co_optimized` on the extruded T3D when re-solving the flat layout
#: with its true bounds loses most of what the joint solve gained.  Each round shrinks the error
#: by about 3x where it converges (peanut at 200 tiles: 0.03, 0.01, 3e-3, 1e-3, 4e-4 mm);
#: two rounds in a row without a new best stop it, and so do the stop rules below, so more
#: rounds run only where the error is still above them.  At 4 the 200-tile seashell's two
#: parts ended at 1.2e-3 mm (met through the hinge layout, 4.2e-4 mm), and with numpy's AVX2
#: kernels instead of AVX-512 (other last bits) at 2.3e-3 mm, a miss (3.1e-3 mm measured);
#: at 7 they reach 3.1e-4 and 6.0e-4 mm, and every 200-tile row meets the targets with
#: either kernel set.
CO_REFINEMENTS = 7
#: :func:`co_optimized` stops when the re-solved flat layout's edge error is within this share
#: of the tolerance, or within the tolerance and this ratio of the joint solve's.  At 0.1 the
#: 200-tile saddle ran a third round from 1.1e-4 mm, and the 1600-tile wave ran on to 4e-5 mm
#: and then missed by one hinge (2.1e-3 mm) in the rigid hinge layout; at 0.3 they stop at
#: 7.9e-5 and 1.8e-4 mm and their hinges meet within 2.1e-4 mm (the other 200-tile rows,
#: both hinge strategies, and the 1600-tile dome are unchanged).
CO_STOP_SHARE = 0.3
CO_STOP_RATIO = 10.0
#: ... (that second rule only within this share of the tolerance: the hinge layout can add to
#: a re-solve that ends near the tolerance; the CLI-default three-shell with dual hinges
#: stopped at 8.4e-4 mm and ended at 1.1e-3 mm, exit 4; with one more round, 8.3e-5 mm)
CO_STOP_NEAR = 0.6
#: The same with bottom hinges, whose rounds pull the bottom corners to equal depths (see
#: co_optimized): the re-solve then follows the moved hinge points, and rounds stopped at 0.6
#: left the 200-tile cloud's hinged layout at 9.9e-4 mm; 0.35 leaves it at 5.8e-4.
CO_STOP_NEAR_CONICAL = 0.35
#: ... and once a re-solve within ``CO_STOP_NEAR`` (``CO_STOP_NEAR_CONICAL``) of the
#: tolerance gains less than this factor on the best before it: the 200-tile seashell's
#: one-part tiling went 0.85, 0.68, 0.65, 0.67, 0.67 um (its joint solves 7e-5 .. 8e-6 mm)
#: where released ends had taken its window drift away.  Within the whole tolerance, the
#: 200-tile wave (AVX-512 kernels) stopped at 9.4e-4 mm, and its hinge layout missed at
#: 1.2e-3 mm; within 0.6 of it, it goes on to 3.8e-4 mm, its hinges 4.9e-4 mm.
CO_STALL_GAIN = 0.9
#: A tiling that may still be split (``give_up_slow``) stops co-optimizing when, shrinking at
#: the rate of its last round for the rounds left, its re-solved error would stay above this
#: many times the tolerance (the rigid hinge layout takes off about 4x: 200-tile seashell
#: 2e-3 -> 4.9e-4 mm).  The 200-tile seashell's first tiling (0.052, 0.039, 0.032, 0.012,
#: 0.025 mm) and the one-part chair's (0.29, 0.42, 2.9 mm) were split in the end; the peanut's
#: (0.031, 0.010, 3.1e-3, 1.1e-3, 3.4e-4 mm) goes on.
CO_SLOW_REACH = 4.0
#: ... and gives up after its first round when that re-solve is this many times worse than
#: the plain layout.  Runs that never recovered: 200-tile wave 130x (1.55 mm against 0.012),
#: one-part chair 6.5x, 1600-tile wave 9x; one that did: the 200-tile wave holding the eq.-1
#: openings, 2.8x (0.032 mm, then 2.3e-3, 2e-4, 9e-5).
CO_GIVE_UP_RATIO = 5.0


def too_slow(
    previous_mm: float, error_mm: float, rounds_left: int, reach: float = CO_SLOW_REACH
) -> bool:
    """Whether co-optimization rounds that took the re-solved edge error from ``previous_mm``
    to ``error_mm`` would, at that rate for ``rounds_left`` more rounds, still end above
    ``reach`` times the tolerance."""
    if rounds_left <= 0 or error_mm <= 0:
        return False
    rate = max(previous_mm / error_mm, 1.0)
    return bool(error_mm / rate**rounds_left > reach * FLAT_EDGE_ERROR_TOL_MM)


@dataclass
class RoundJudge:
    """When :func:`co_optimized` stops its rounds, judged by their re-solved flat edge errors.

    Attributes
    ----------
    plain_mm : the plain layout's flat edge error (the result must beat it to be used).
    conical : the rounds make the bottom hinges meet in depth too (see :func:`co_optimized`).
    give_up_slow : stop when the rounds shrink the error too slowly to reach the tolerance
        (:data:`CO_SLOW_REACH`); ``cut_short`` then says so.
    """

    plain_mm: float
    conical: bool = False
    give_up_slow: bool = False
    best_mm: float = math.inf
    #: rounds in a row below neither the best round nor the plain layout
    worse: int = 0
    rounds: int = 0
    previous_mm: float | None = None
    cut_short: bool = False

    def judge(self, error_mm: float, joint_mm: float) -> tuple[bool, bool]:
        """One more round, its re-solved error and its joint solve's (mm): whether it is the
        best so far, and whether the rounds stop after it."""
        self.rounds += 1
        first_round = self.rounds == 1
        previous = self.plain_mm if self.previous_mm is None else self.previous_mm
        best_before = self.best_mm
        progress = first_round or error_mm < best_before
        if progress:
            self.best_mm = error_mm
        self.worse = 0 if progress and error_mm < self.plain_mm else self.worse + 1
        stop_near = CO_STOP_NEAR_CONICAL if self.conical else CO_STOP_NEAR
        # Stop once the re-solve is well inside the tolerance, or within the tolerance and
        # close to what the joint solve reached (more rounds would not gain much).  A re-solve
        # that misses the tolerance goes on even when it is close to a poor joint solve: the
        # 200-tile seashell with top hinges then meets the targets with its first tiling
        # (7.3e-4 mm) where it stopped at 3.2e-3 mm and was split once more.
        if (
            self.worse >= 2
            or (first_round and error_mm > CO_GIVE_UP_RATIO * self.plain_mm)
            or error_mm <= CO_STOP_SHARE * FLAT_EDGE_ERROR_TOL_MM
            or error_mm <= min(stop_near * FLAT_EDGE_ERROR_TOL_MM, CO_STOP_RATIO * joint_mm)
            or (
                error_mm <= stop_near * FLAT_EDGE_ERROR_TOL_MM
                and error_mm > CO_STALL_GAIN * best_before
            )
        ):
            return progress, True
        # A conical round that lost ground is judged by the rounds after it (``worse``): the
        # CLI-default three-shell's went 0.020, 0.060, 1.1e-3, 3.9e-4, 1.4e-4 mm, where a
        # rate taken from the lost round had given it up after two.  So is a first round
        # above the plain layout: with AVX-512 kernels the same three-shell's went 0.197 mm
        # (plain 0.117), and given up at once it kept a 0.032 mm hinge gap in depth; judged
        # by the next rounds it meets its hinges in 3D (3.8e-4 mm).
        judged = (progress and error_mm < previous) or not self.conical
        left = CO_REFINEMENTS + 1 - self.rounds
        if self.give_up_slow and judged and too_slow(previous, error_mm, left):
            self.cut_short = True
            return progress, True
        if self.conical and judged and too_slow(previous, error_mm, left, reach=1.0):
            # it would miss the tolerance: the caller co-optimizes again without the conical
            # condition (the 1600-tile wave: 0.29, 0.016, 0.0099, 0.0065 mm, ... 0.0027 mm
            # after eight rounds; without, 1.4e-4 mm after four)
            return progress, True
        self.previous_mm = error_mm
        return progress, False


def flat_layout(
    linkage: Linkage,
    tiling: Tiling,
    assembled: AssembledResult,
    options: ResolvedOptions,
    faces: HingeFaces | None,
    initial_nodes: NDArray[np.float64] | None = None,
    seed_steps: int | None = None,
) -> FlatResult:
    """The flat layout K2D of ``assembled`` (each component from its own flattening), its
    gap-angle bounds held on the top and bottom faces; with ``faces`` (dual hinges) its nodes
    are the hinge points and each opening stays where the hinged tiles clear each other.
    With ``seed_steps`` it stops once its bounds hold after that many Gauss-Newton steps."""
    return optimize_flat(
        linkage,
        assembled.tiles[:, :4],
        uv=component_flattenings(linkage, assembled.top, tiling.uv)[0],
        min_gap_angle_deg=options.min_gap_angle_deg,
        tiles_3d=assembled.tiles,
        initial_nodes=initial_nodes,
        hinges=faces,
        angle_margin_deg=2.0 * HINGE_ANGLE_MARGIN_DEG,
        seed_steps=seed_steps,
    )


def co_optimized(
    linkage: Linkage,
    tiling: Tiling,
    assembled: AssembledResult,
    flat: FlatResult,
    target: Target,
    options: ResolvedOptions,
    faces: HingeFaces | None,
    *,
    track_openings: bool = True,
    give_up_slow: bool = False,
    first_solves: dict[str, CoOptimizedTop] | None = None,
    conical: bool = False,
    conical_weight: float | None = None,
) -> tuple[AssembledResult, FlatResult, dict[str, Any]]:
    """K3D and K2D moved together so the flat tiles are congruent to the assembled ones
    (:func:`~drawstring.geometry.coflat.co_optimize_top`; with ``faces``, at their hinge points
    and with the clear openings of the current tiles, or with ``track_openings=False`` those of
    ``faces`` throughout), T3D extruded again under the new K3D and the flat layout solved
    again from the joint one.  The round whose re-solved layout has the smallest edge error is
    the one kept.  The new design is used only when its flat edge error is lower and the flat
    layout keeps every hard bound; otherwise the inputs come back unchanged with the reason
    (at once when round 1's joint solve ends no lower than the plain layout).
    With ``give_up_slow`` the rounds stop early when they converge too slowly to reach the
    tolerance (:data:`CO_SLOW_REACH`; the block then says ``cut_short``).  ``first_solves``
    keeps the first joint solve, which runs on the eq.-1 tiles and openings either way, for
    another call on the same inputs (the held-openings run after a tracked one).  With
    ``conical`` (``faces`` with bottom hinges) every joint solve also makes K3D conical and
    every round pulls the bottom hinges' corners to equal depths under both their tiles'
    top faces (:func:`_depth_pull`), so that those corners meet in 3D, not only seen from
    above; the rounds then stop only within ``CO_STOP_NEAR_CONICAL`` of the tolerance.
    ``conical_weight`` replaces ``coflat.CO_CONICAL``, the weight of that condition."""

    last: list[tuple[NDArray[np.float64], HingeFaces]] = []
    # the openings of the last re-solved layout on its hinge faces, and the slit ends released
    # from their clear windows so far (see HingeFaces.closing)
    held: list[NDArray[np.float64]] = []
    released = np.zeros(len(faces.clear_lo) if faces is not None else 0, dtype=bool)

    def openings(tiles: NDArray[np.float64]) -> HingeFaces | None:
        if faces is None or not track_openings:
            return faces
        # a round's joint solve starts on the tiles the previous re-solve was given
        if not (last and np.array_equal(last[0][0], tiles)):
            fresh = hinge_faces(linkage, tiles, faces.bottom)
            if last and held:
                # A window that closed on the opening laid out in it is released: the joint
                # solve presses the opening against it, its move of K3D closes it further,
                # and the re-solve has to give way every round.
                released[:] |= last[0][1].closing(fresh, held[0])
            fresh = replace(fresh, released=released.copy()) if released.any() else fresh
            last[:] = [(tiles.copy(), fresh)]
        return last[0][1]

    # Round 1 runs the whole continuation. The bottom faces decide the bottom-face angle bounds,
    # so round 2 repeats the last stage with T3D moved along with the new top (a translation of
    # each bottom vertex with its top vertex is usually close enough for those bounds). T3D is
    # then extruded under the new top and the flat layout re-solved with the true bounds; when
    # that costs much of what the joint solve gained, the last stage runs once more on the
    # extruded T3D, starting from the re-solved layout: it holds the extruded tiles' bounds
    # already, so the joint solve need only correct it where the re-extrusion moved the hinge
    # points (the bottom corners).  Started from the last joint solve's nodes instead, it had
    # to undo that shift too and moved K3D further, which moved the bottom corners again: the
    # 200-tile seashell's two parts stalled at 1.5e-3 mm and it was split into four, where now
    # two meet 4e-4 mm.
    block: dict[str, Any] = {"accepted": False, "reason": "", "steps": 0}
    judge = RoundJudge(flat.edge_error_max_mm, conical=conical, give_up_slow=give_up_slow)

    current, nodes = assembled, None
    rounds: list[tuple[tuple[float, float], ...]] = [CO_STAGES, CO_STAGES[-1:]]
    best: tuple[AssembledResult, FlatResult] | None = None
    for _ in range(CO_REFINEMENTS + 1):
        for stages in rounds:
            first = current is assembled  # round 1's first joint solve: the eq.-1 inputs
            if first and first_solves is not None and "eq1" in first_solves:
                co = first_solves["eq1"]
            else:
                co = co_optimize_top(
                    linkage,
                    flat,
                    current.top,
                    current.quads,
                    target.vertices,
                    target.faces,
                    tiles_3d=current.tiles,
                    w_surface=options.weights[2],
                    stages=stages,
                    start_nodes=nodes,
                    hinges=faces if first else openings(current.tiles),
                    conical=conical,
                    conical_weight=conical_weight,
                )
                if first and first_solves is not None:
                    co.top.flags.writeable = co.nodes.flags.writeable = False  # shared
                    first_solves["eq1"] = co
            block["steps"] += co.steps
            moved_bottom = current.bottom + (co.top - current.top)
            current = replace(
                current,
                top=co.top,
                bottom=moved_bottom,
                tiles=tile_vertices(co.top, moved_bottom, current.quads),
            )
            nodes = co.nodes
        if best is None and not co.edge_error_max_mm < flat.edge_error_max_mm:
            # The first round's joint solve, in its own model, ends above the plain layout:
            # the re-solve under the true bounds does no better (1600-tile wave, tracked
            # openings: joint 0.35 mm against a plain 0.13, re-solved 0.63 mm, then 0.66).
            block["reason"] = (
                f"the joint solve did not lower the flat edge error "
                f"({flat.edge_error_max_mm:.3g} -> {co.edge_error_max_mm:.3g} mm)"
            )
            block["joint_refused"] = True
            return assembled, flat, block
        # measured only for the round that is kept (below); the bottoms polished planar from
        # where they moved with the top, not extruded afresh (see reextrude).  With bottom
        # hinges the moved top is conical (co_optimize_top): its bottom hinges' corners are
        # pulled to equal depths under both their tiles every round.
        pull = _depth_pull(current, linkage, faces.bottom) if conical and faces else None
        extruded = reextrude(
            assembled, current.top, target.vertices, target.faces, measure=False,
            start_bottom=current.bottom, pull=pull,
        )  # fmt: skip
        if extruded is None:
            block["reason"] = "the new assembled shape would turn a tile inside out"
            return assembled, flat, block
        current = extruded
        new_flat = flat_layout(
            linkage, tiling, current, options, openings(current.tiles), initial_nodes=nodes
        )
        # A round counts as progress only below both the best round and the plain layout:
        # the result must beat the plain layout to be used, and re-solves that stay above it
        # do not come down in later rounds (the 200-tile chair in one part: 4.5, 2.7, 2.0,
        # 1.9 mm against a plain 0.69 mm).
        error = new_flat.edge_error_max_mm
        nodes = new_flat.nodes
        if new_flat.hinges is not None and track_openings:
            held[:] = [hinge_face_openings(linkage, new_flat, current.tiles)]
        logger.info(
            "co-optimization round: joint %.3g mm, re-solved %.3g mm", co.edge_error_max_mm, error
        )
        progress_made, stop = judge.judge(error, co.edge_error_max_mm)
        if progress_made:
            best = (current, new_flat)
        if stop:
            break
        rounds = [CO_STAGES[-1:]]
    if judge.cut_short:
        block["cut_short"] = True
    # a refinement round can lose (its re-solve may settle elsewhere): keep the best round
    assert best is not None
    new_assembled, new_flat = best
    if best[1].hinges is not None and best[1].hinges.released is not None:
        block["released_ends"] = int(best[1].hinges.released.sum())
    block["move_max_mm"] = round(
        float(np.linalg.norm(new_assembled.top - assembled.top, axis=1).max()), 6
    )
    # the solver's own edge errors go to the log only: design.json holds measured numbers
    logger.info(
        "co-optimization: flat edge error %.3g mm before, %.3g in the joint solve, %.3g after",
        flat.edge_error_max_mm,
        co.edge_error_max_mm,
        new_flat.edge_error_max_mm,
    )
    # A tile is turned over when its top face turned by more than 90 deg from the eq.-1 shape.
    # (Not the target-normal count ``flipped_tiles``: on a scan, the one closest triangle at a
    # tile's centre can face another way; the scanned face had 1 such tile before and 2 after
    # a co-optimization that turned no tile by more than 2.5 deg, and was wrongly refused.)
    turned = int(
        np.sum(
            np.einsum(
                "ki,ki->k",
                quad_vector_areas(assembled.top, assembled.quads),
                quad_vector_areas(new_assembled.top, new_assembled.quads),
            )
            <= 0
        )
    )
    if new_assembled.metrics.get("corner_margin_min", 1.0) <= 0 or turned:
        block["reason"] = "the new assembled shape would fold a tile or turn one over"
        return assembled, flat, block
    hard = [p for p in new_flat.problems if "edge error" not in p]
    old_hard = [p for p in flat.problems if "edge error" not in p]
    if len(hard) > len(old_hard):
        block["reason"] = f"the new flat layout breaks a bound ({hard[0]})"
        return assembled, flat, block
    if not new_flat.edge_error_max_mm < flat.edge_error_max_mm:
        block["reason"] = (
            f"the flat edge error did not drop ({flat.edge_error_max_mm:.3g} -> "
            f"{new_flat.edge_error_max_mm:.3g} mm)"
        )
        return assembled, flat, block
    block["accepted"] = True
    return remeasured(new_assembled, target.vertices, target.faces), new_flat, block
