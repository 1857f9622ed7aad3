"""The stages from tiling to hinges, and the tiling again where the layout misses.

:func:`shape_and_layout` tiles the flattened target, shapes the assembled tiles (paper eq. 1
and extrusion), lays them flat, co-optimizes both (:func:`~.co_rounds.co_optimized`) and
places the hinges; where the flat tiles then miss their hinges by more than the targets it
tiles again with tighter splits (:attr:`~.policy.LayoutPolicy.retile_attempts`) and keeps the
most accurate result.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.assembled.reextrude import reextrude
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.parallel import can_fork
from drawstring.geometry.core.rigid import rigid_copies
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.core.tolerances import FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM
from drawstring.geometry.flat import verify
from drawstring.geometry.flat.coflat import CoOptimizedTop
from drawstring.geometry.flat.layout import FlatResult, extrude_flat
from drawstring.geometry.flat.pose import HingeFaces
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.hinges.placement import HingeLayout, layout_hinges
from drawstring.geometry.hinges.sides import dual_hinge_faces
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.pipeline.ahead import Ahead as _Ahead
from drawstring.pipeline.co_ladder import CoLadder
from drawstring.pipeline.co_rounds import co_optimized, depth_pull, flat_layout
from drawstring.pipeline.policy import LayoutPolicy
from drawstring.pipeline.record import Progress, ResolvedOptions
from drawstring.pipeline.shapes import ShapeCache, assembled_shape

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
    #: the co-optimization ladder paused after a step that missed the flat targets
    #: (``_shaped``'s ``pause_after_miss``); the hinge stage has not run
    paused: _Paused | None = None
    #: ``--fit``: the eq.-1 weights used and what the close fit did (``metrics.fit``)
    fit: dict[str, Any] | None = None

    @property
    def unfinished(self) -> bool:
        """Whether the co-optimization ladder paused (see :attr:`paused`)."""
        return self.paused is not None

    def abandon(self) -> None:
        """Stop a paused ladder's work run ahead: this layout is not gone on with."""
        if self.paused is not None:
            self.paused.ladder.cancel()

    @property
    def accuracy_mm(self) -> float:
        """The larger of the flat edge error and the hinge gap, mm, as measured on the output
        (:func:`~drawstring.pipeline.measure.measure_design`): how far the flat tiles are
        from meeting at their hinges with their assembled shapes (the flat layout's edge error
        where the hinge stage was skipped).  The gap is the whole one, its vertical part too:
        a tighter tiling whose conical co-optimization succeeds closes that part where the
        first tiling's had to go without."""
        if self.hinge_layout is None:
            return self.flat.edge_error_max_mm
        tiles = self.assembled.tiles
        edge = verify.flat_edge_errors(self.hinge_layout.tiles[:, :4, :2], tiles[:, :4])
        fabricated = fabricated_tiles(self.hinge_layout, tiles)
        gaps = verify.hinge_gaps(fabricated, self.hinge_layout.hinge_vertices)
        return max(float(edge.max(initial=0.0)), float(gaps.max(initial=0.0)))


def shape_and_layout(
    loaded: Target,
    flat_map: Flattening,
    options: ResolvedOptions,
    progress: Progress,
    *,
    policy: LayoutPolicy,
    shapes: ShapeCache | None = None,
    first_tiling: Tiling | None = None,
) -> ShapedLayout:
    """Tile, shape and lay out the target (stages tiling to hinges), tiling again with a
    tighter split bound (``policy.retile_attempts``) while the layout misses its accuracy
    targets; the most accurate result is kept (see ``policy.retile_gain``).  ``shapes``: the
    assembled shapes solved so far and their eq.-1 weights (default: none yet, the paper's
    eq. 1 with ``options.weights``); ``first_tiling``: the tiling with the first split bound,
    where it is tiled already (the design's refusing check,
    :func:`~.shapes.refusing_shape`, has run on it: :func:`~.close_fit.fitted_layout`)."""
    run = _Retiling(loaded, flat_map, options, progress, policy, shapes or ShapeCache())
    bound = split_bound(options)
    if first_tiling is None:
        first_tiling = run.tiled(bound)
    if first_tiling.scale_factor_max - 1.0 < policy.retile_min_share * (bound - 1.0):
        # its area scale hardly varies: more splits are not what it lacks
        return run.shaped(first_tiling, bound, spare_core=True)
    # A tiling that may be split again goes without the held-openings fallback: its
    # co-optimization is refused for its area scale, which more splits mend, and the fallback
    # would not.  It runs after all if the first tiling is the one kept.
    if policy.retile_ahead and can_fork() and policy.retile_attempts > 0:
        run.lay_out_ahead(bound, first_tiling)
    first: ShapedLayout | None = None
    try:
        ahead = run.ahead
        first = run.shaped(
            first_tiling, bound, fallback=False, spare_core=ahead is None,
            core_freed=None if ahead is None else ahead.ready,
            pause_after_miss=policy.prefer_split_at_first_weight and policy.retile_attempts > 0,
        )  # fmt: skip
        if first.unfinished:
            # Its first conical co-optimization missed the flat targets: the first tighter
            # tiling decides whether the first one's co-optimizations go on.
            split = run.split_meeting_targets(bound, first_tiling, first)
            if split is not None:
                return split
            first = run.shaped(first_tiling, bound, fallback=False, paused=first)
        first_accuracy = first.accuracy_mm
        best, tried = run.tighter_tilings(bound, first, first_accuracy)
    finally:
        run.cancel()  # the work run ahead, where its result is not needed
        if first is not None:
            first.abandon()  # (a paused ladder, on the way out)
    return run.kept(first_tiling, first, first_accuracy, best, tried)


def shape_on_tiling(
    tiling: Tiling,
    bound: float,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    *,
    policy: LayoutPolicy,
    shapes: ShapeCache,
) -> ShapedLayout:
    """Stages assembled to hinges on ``tiling`` (split with ``bound``) alone, no tighter
    tiling tried: the assembled shape from ``shapes`` (solved there where it is not in it),
    the flat layout, the co-optimization with ``policy`` and the hinges."""
    return _shaped(tiling, bound, loaded, options, progress, shapes, policy=policy)


class _Retiling:
    """One run of :func:`shape_and_layout`: what its steps share, and the first tighter
    tiling where it was tiled, or laid out, before the loop over tighter tilings needs it."""

    def __init__(
        self,
        loaded: Target,
        flat_map: Flattening,
        options: ResolvedOptions,
        progress: Progress,
        policy: LayoutPolicy,
        shapes: ShapeCache,
    ) -> None:
        self.loaded, self.flat_map, self.options = loaded, flat_map, options
        self.progress, self.policy = progress, policy
        #: the accuracy figure (:attr:`ShapedLayout.accuracy_mm`) that meets the targets
        self.target = min(FLAT_EDGE_ERROR_TOL_MM, HINGE_GAP_TOL_MM)
        #: assembled shapes by quad mesh (tighter split bounds cut the linkage, not the mesh)
        self.shapes = shapes
        #: the first tighter tiling laid out in a second process (:meth:`lay_out_ahead`)
        self.ahead: _Ahead[ShapedLayout] | None = None
        #: the first tighter tiling, when tiled ahead of the loop
        self.prepared: Tiling | None = None
        #: the first tighter tiling's layout where the first tiling paused for it (used once)
        self.laid_out: ShapedLayout | None = None

    def tiled(self, bound: float) -> Tiling:
        """Stage tiling: the flattened target tiled with split bound ``bound``."""
        with self.progress.stage("tiling"):
            return tile_surface(
                self.loaded.vertices, self.loaded.faces, self.flat_map.uv,
                tiles=self.options.tiles, grid=self.options.grid, max_scale_factor=bound,
            )  # fmt: skip

    def shaped(
        self, tiling: Tiling, bound: float, progress: Progress | None = None, **kwargs: Any
    ) -> ShapedLayout:
        """:func:`_shaped` on ``tiling`` (split with ``bound``), its keywords passed on."""
        return _shaped(
            tiling, bound, self.loaded, self.options,
            self.progress if progress is None else progress, self.shapes, policy=self.policy,
            **kwargs,
        )  # fmt: skip

    def lay_out_ahead(self, bound: float, first_tiling: Tiling) -> None:
        """Tile the first tighter tiling, which the loop over tighter tilings lays out if the
        first tiling misses, and lay it out meanwhile in a second process where it splits
        the grid otherwise than ``first_tiling`` (the assembled shape, which both tilings
        share, is solved here first)."""
        next_bound = _tighter(bound, first_tiling, self.policy)
        self.prepared = next_tiling = self.tiled(next_bound)
        if _same_parts(next_tiling, first_tiling):
            return
        assembled_shape(first_tiling, self.loaded, self.options, self.progress, self.shapes)

        def work(child_progress: Progress) -> ShapedLayout:
            return self.shaped(next_tiling, next_bound, child_progress)

        try:
            self.ahead = _Ahead(
                work, "the tiling laid out ahead", niceness=self.policy.ahead_niceness
            )
        except OSError as exc:  # no process to spare (fork refused): laid out in turn
            logger.warning("could not lay the tighter tiling out ahead (%s)", exc)

    def split_meeting_targets(
        self, bound: float, first_tiling: Tiling, first: ShapedLayout
    ) -> ShapedLayout | None:
        """After the first tiling's ladder paused on a miss (``first``): the first tighter
        tiling's layout, with a note, if it meets every accuracy target; None otherwise (the
        layout is then kept for the loop over tighter tilings)."""
        next_bound = _tighter(bound, first_tiling, self.policy)
        prepared = self.prepared if self.prepared is not None else self.tiled(next_bound)
        self.prepared = prepared
        if _same_parts(prepared, first_tiling):
            return None
        assert first.paused is not None
        if self.ahead is not None:
            self.laid_out, self.ahead = self.ahead.result(self.progress), None
        if self.laid_out is None:
            # (a core is spare unless the paused ladder runs a step ahead on it)
            self.laid_out = self.shaped(
                prepared, next_bound, spare_core=not first.paused.ladder.running_ahead
            )
        laid_out = self.laid_out
        if laid_out.accuracy_mm > self.target:
            return None
        note = (
            f"tiling: with split bound {bound:.3g} ({_parts(first_tiling)}) the "
            f"conical co-optimization (weight {self.policy.conical_weights[0]:g}) missed "
            f"({first.paused.ladder.missed}); tighter splits gave "
            f"{_parts(prepared)} at bound {next_bound:.3g}: "
            f"{laid_out.accuracy_mm:.2g} mm; kept {_parts(prepared)}, without "
            "trying the first tiling with another weight or without the condition"
        )
        return replace(laid_out, notes=(*laid_out.notes, note))

    def tighter_tilings(
        self, bound: float, first: ShapedLayout, first_accuracy: float
    ) -> tuple[ShapedLayout, list[str]]:
        """The most accurate layout of ``first`` (split with ``bound``) and the tighter
        tilings tried while it misses the targets, and a line on each tiling tried."""
        best, best_accuracy = first, first_accuracy
        tried: list[str] = []
        for _ in range(self.policy.retile_attempts):
            if best_accuracy <= self.target:
                break
            bound = _tighter(bound, best.tiling, self.policy)
            tiling = self.prepared if self.prepared is not None else self.tiled(bound)
            self.prepared = None
            # laid out already (the first tighter tiling)
            trial, self.laid_out = self.laid_out, None
            if self.ahead is not None:  # laid out meanwhile (its tiling is ``prepared``)
                trial, self.ahead = self.ahead.result(self.progress), None
            if _same_parts(tiling, best.tiling):
                break  # no further split keeps enough cells on each side
            if trial is None:
                trial = self.shaped(tiling, bound, spare_core=True)
            accuracy = trial.accuracy_mm
            tried.append(f"{_parts(tiling)} at bound {bound:.3g}: {accuracy:.2g} mm")
            if not (accuracy < self.policy.retile_gain * best_accuracy or accuracy <= self.target):
                break  # splitting does not help this design (e.g. errors at split-line ends)
            best, best_accuracy = trial, accuracy
        return best, tried

    def cancel(self) -> None:
        """Stop the tiling laid out ahead (its result is not needed, or the run ends)."""
        if self.ahead is not None:
            self.ahead.cancel()

    def kept(
        self,
        first_tiling: Tiling,
        first: ShapedLayout,
        first_accuracy: float,
        best: ShapedLayout,
        tried: list[str],
    ) -> ShapedLayout:
        """The layout kept, ``best``, with a note on the tighter tilings ``tried``; the first
        tiling (``first``) laid out in full if it is the one kept and was not."""
        if best is first and first.fallback_skipped and first_accuracy > self.target:
            # kept after all: co-optimized in full, with the held-openings fallback
            best = first = self.shaped(first_tiling, first.split_bound, spare_core=True)
        if not tried:
            return first
        outcome = f"kept {_parts(best.tiling)}" if best is not first else "kept the first tiling"
        note = (
            f"tiling: with split bound {first.split_bound:.3g} ({_parts(first.tiling)}) the flat "
            f"tiles met their hinges with their assembled shapes only to {first_accuracy:.2g} mm; "
            f"tighter splits gave {'; '.join(tried)}; {outcome}"
        )
        return replace(best, notes=(*best.notes, note))


def _tighter(bound: float, tiling: Tiling, policy: LayoutPolicy) -> float:
    """The split bound of the tiling tried after ``tiling`` (split with ``bound``)."""
    return 1.0 + policy.retile_shrink * (min(bound, tiling.scale_factor_max) - 1.0)


def _parts(tiling: Tiling) -> str:
    count = tiling.linkage.n_components
    return f"{count} part" if count == 1 else f"{count} parts"


def _same_parts(a: Tiling, b: Tiling) -> bool:
    """Whether two tilings of one grid split it into the same parts."""
    return a.linkage.n_tiles == b.linkage.n_tiles and bool(
        np.array_equal(a.linkage.tile_component, b.linkage.tile_component)
    )


@dataclass(frozen=True)
class _Paused:
    """A tiling's co-optimization ladder paused after a step that missed the flat targets
    (see :func:`_shaped`'s ``pause_after_miss``), and what the stages after it need."""

    ladder: CoLadder
    faces: HingeFaces | None


def _shaped(
    tiling: Tiling,
    bound: float,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: ShapeCache,
    *,
    policy: LayoutPolicy,
    fallback: bool = True,
    spare_core: bool = False,
    core_freed: Callable[[], bool] | None = None,
    pause_after_miss: bool = False,
    paused: ShapedLayout | None = None,
) -> ShapedLayout:
    """Stages assembled to hinges on one tiling (see :func:`shape_and_layout`); with
    ``fallback=False`` a refused co-optimization is not run again holding the eq.-1
    openings, and the hinge stage is skipped when the flat layout is too far off.
    ``spare_core``: no other process lays out a tiling meanwhile, so the co-optimization
    without the conical condition is run ahead while the conical ones run
    (:class:`~.co_ladder.CoLadder`); ``core_freed`` says whether the process that lays out
    another tiling is done, so that the core it held is spare from then on.
    ``shapes`` holds the assembled configurations already solved, by quad mesh; their arrays
    are read-only, as they may be shared between tilings (and so are those of a design that
    keeps the eq.-1 tiles, e.g. with ``--no-co-optimize``).
    With ``pause_after_miss``, the co-optimization ladder pauses after its first step if that
    misses the flat targets: the result is then ``unfinished`` (no hinge layout), and a call
    with it as ``paused`` goes on from there (:meth:`ShapedLayout.abandon` stops it instead)."""
    linkage = tiling.linkage
    skipped = False
    ladder: CoLadder | None = None
    if paused is not None:
        assert paused.paused is not None
        assembled, flat = paused.assembled, paused.flat
        ladder, faces, notes = paused.paused.ladder, paused.paused.faces, list(paused.notes)
    else:
        notes = list(tiling.notes)
        assembled, faces, flat = _plain_layout(tiling, loaded, options, progress, shapes, policy)
        if options.co_optimize:
            ladder = _co_ladder(
                tiling, assembled, flat, loaded, options, faces, policy, fallback=fallback,
                spare_core=spare_core, core_freed=core_freed,
            )  # fmt: skip
    if ladder is not None:
        with progress.stage("co-optimize"):
            far = None if fallback else policy.co_slow_reach * FLAT_EDGE_ERROR_TOL_MM
            assembled, flat, co_block, skipped, note = ladder.run(far, pause_after_miss)
            if note:
                notes.append(note)
        if ladder.paused:  # the caller decides whether the ladder goes on
            return ShapedLayout(
                tiling=tiling, assembled=assembled, flat=flat, co_block=co_block,
                hinge_layout=None, split_bound=bound, notes=tuple(notes), fallback_skipped=True,
                paused=_Paused(ladder, faces),
            )  # fmt: skip
        if not co_block["accepted"]:
            notes.append(f"co-optimization not used: {co_block['reason']}")
            if policy.co_required:  # not gone on with (its caller keeps none without)
                return ShapedLayout(
                    tiling=tiling, assembled=assembled, flat=flat, co_block=co_block,
                    hinge_layout=None, split_bound=bound, notes=tuple(notes),
                )  # fmt: skip
            if flat.iterations >= policy.flat_seed_steps:
                with progress.stage("flat"):  # the seed is the layout now: finish it
                    flat = flat_layout(
                        linkage, tiling, assembled, options, faces, initial_nodes=flat.nodes
                    )
    else:
        co_block = {"accepted": False, "reason": "off (--no-co-optimize)"}
    hinge_layout: HingeLayout | None = None
    if not fallback and flat.edge_error_max_mm > policy.co_slow_reach * FLAT_EDGE_ERROR_TOL_MM:
        # A tiling that may still be split skips the hinge stage when its flat layout is too
        # far off for the rigid hinge layout to reach the targets (policy.co_slow_reach; on a
        # layout this far off it can add to the error): it is tiled again, and laid out in
        # full if kept.
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


def _plain_layout(
    tiling: Tiling,
    loaded: Target,
    options: ResolvedOptions,
    progress: Progress,
    shapes: ShapeCache,
    policy: LayoutPolicy,
) -> tuple[AssembledResult, HingeFaces | None, FlatResult]:
    """Stages assembled and flat on one tiling: the assembled shape (eq. 1 and extrusion,
    the bottom hinges' corners pulled to equal depths), the hinge faces (dual hinges) and the
    plain flat layout (only a seed when the co-optimization follows)."""
    linkage = tiling.linkage
    assembled = assembled_shape(tiling, loaded, options, progress, shapes)
    # Hinge sides are decided on the eq.-1 tiles (and again once their bottom corners are
    # pulled to equal depths, which can move a side); the flat layout makes the hinged
    # corners meet on the face that carries each hinge.
    faces = (
        dual_hinge_faces(linkage, assembled.tiles, options.min_gap_angle_deg)
        if options.hinges == HingeStrategy.DUAL
        else None
    )
    if faces is not None and policy.hinge_depths and faces.bottom.any():
        assembled = _bottom_hinge_depths(assembled, linkage, faces.bottom, loaded)
        faces = dual_hinge_faces(linkage, assembled.tiles, options.min_gap_angle_deg)
    with progress.stage("flat"):
        # only a seed when the co-optimization follows (policy.flat_seed_steps)
        seed_steps = policy.flat_seed_steps if options.co_optimize else None
        flat = flat_layout(linkage, tiling, assembled, options, faces, seed_steps=seed_steps)
    return assembled, faces, flat


def _co_ladder(
    tiling: Tiling,
    assembled: AssembledResult,
    flat: FlatResult,
    loaded: Target,
    options: ResolvedOptions,
    faces: HingeFaces | None,
    policy: LayoutPolicy,
    *,
    fallback: bool,
    spare_core: bool,
    core_freed: Callable[[], bool] | None,
) -> CoLadder:
    """The co-optimizations of one tiling from its plain layout (``assembled``, ``flat``),
    in turn (see :func:`_shaped` for the keywords)."""
    plain = (assembled, flat)
    # With bottom hinges the top is made conical too (their corners then meet in depth);
    # where that costs the flat layout its targets, it is co-optimized again with the next
    # weight of the condition (policy.conical_weights), and after the last without it.
    conical = (
        policy.hinge_depths
        and bool(policy.conical_weights)
        and faces is not None
        and bool(faces.bottom.any())
    )
    ladder: CoLadder | None = None
    ladder = CoLadder(
        lambda step: _co_optimized_with_fallback(
            tiling.linkage, tiling, *plain, loaded, options, faces, fallback, *step,
            between_rounds=ladder.poll if ladder is not None else None, policy=policy,
        ),
        conical,
        spare_core and can_fork(),
        core_freed if core_freed is not None and can_fork() else None,
        policy=policy,
    )  # fmt: skip
    return ladder


def _bottom_hinge_depths(
    assembled: AssembledResult, linkage: Linkage, bottom: NDArray[np.bool_], loaded: Target
) -> AssembledResult:
    """The assembled tiles with their bottom vertices moved (tops held, every face planar) so
    that the ``bottom`` hinges' corners lie as deep under both tiles' top faces as they can
    (:func:`~drawstring.geometry.assembled.reextrude.hinge_depth_pull`).  Read-only like the eq.-1
    tiles it stands for (a design whose co-optimization is refused keeps it)."""
    moved = reextrude(
        assembled, assembled.top, loaded.vertices, loaded.faces, start_bottom=assembled.bottom,
        pull=depth_pull(assembled, linkage, bottom),
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
    *,
    between_rounds: Callable[[], None] | None = None,
    policy: LayoutPolicy,
) -> tuple[AssembledResult, FlatResult, dict[str, Any], bool]:
    """:func:`co_optimized` tracking the clear openings and, when that is refused and
    ``fallback`` (and not ``conical``: the caller tries that again otherwise), again holding the
    eq.-1 tiles' openings; also whether a full run is owed
    (:attr:`ShapedLayout.fallback_skipped`).  ``between_rounds`` is called after every round."""
    first_solves: dict[str, CoOptimizedTop] = {}
    new_assembled, new_flat, co_block = co_optimized(
        linkage, tiling, assembled, flat, loaded, options, faces, give_up_slow=not fallback,
        first_solves=first_solves, conical=conical, conical_weight=conical_weight,
        between_rounds=between_rounds, policy=policy,
    )  # fmt: skip
    refused = not co_block["accepted"] and faces is not None
    skipped = (refused and not fallback) or bool(co_block.get("cut_short"))
    if refused and fallback and not conical:
        # On the moved tiles some slit ends no longer clear where they did, and the windows
        # that shift between rounds can leave the re-solve stranded; the clear openings of
        # the eq.-1 tiles, held throughout, do not move.  The hinge stage separates the final
        # tiles exactly either way.
        held = co_optimized(
            linkage, tiling, assembled, flat, loaded, options, faces, track_openings=False,
            first_solves=first_solves, conical=conical, between_rounds=between_rounds,
            policy=policy,
        )  # fmt: skip
        if held[2]["accepted"]:
            new_assembled, new_flat = held[0], held[1]
            co_block = {**held[2], "openings": "held from the eq.-1 tiles"}
    return new_assembled, new_flat, co_block, skipped
