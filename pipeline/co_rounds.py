"""The rounds of one co-optimization: joint solve, re-extrusion and flat re-solve.

:func:`co_optimized` moves the assembled top (K3D) and the flat layout (K2D) together so the
flat tiles become congruent to the assembled ones (the joint solve,
:func:`~drawstring.geometry.flat.coflat.co_optimize_top`), extrudes the tiles again under the moved
top and solves the flat layout again with its true bounds (:func:`flat_layout`), for up to
:attr:`~.policy.LayoutPolicy.co_refinements` more rounds.  :class:`RoundJudge` decides when
the rounds stop.  The layout stage (:mod:`~drawstring.pipeline.layout_stage`) runs it, through
the ladder of conical weights (:mod:`~drawstring.pipeline.co_ladder`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.assembled.frustums import quad_vector_areas, tile_vertices
from drawstring.geometry.assembled.reextrude import hinge_depth_pull, reextrude, remeasured
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.tolerances import FLAT_EDGE_ERROR_TOL_MM, HINGE_ANGLE_MARGIN_DEG
from drawstring.geometry.flat.coflat import CO_STAGES, CoOptimizedTop, co_optimize_top
from drawstring.geometry.flat.layout import FlatResult, hinge_face_openings, optimize_flat
from drawstring.geometry.flat.pose import HingeFaces, hinge_faces
from drawstring.geometry.solve.planarity import LinearPull
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import Tiling, component_flattenings
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.pipeline.policy import DEFAULT_POLICY, LayoutPolicy
from drawstring.pipeline.record import ResolvedOptions

logger = logging.getLogger(__name__)

__all__ = [
    "RoundJudge",
    "co_optimized",
    "depth_pull",
    "flat_layout",
    "too_slow",
]


def depth_pull(shape: AssembledResult, linkage: Linkage, bottom: NDArray[np.bool_]) -> LinearPull:
    """The pull of the ``bottom`` hinges' corners of ``shape`` to equal depths under both
    tiles' top faces (:func:`~drawstring.geometry.assembled.reextrude.hinge_depth_pull`)."""
    hinges = linkage.hinges[bottom]
    vertex = shape.quads[hinges[:, 0], hinges[:, 1]]
    return hinge_depth_pull(shape, vertex, hinges[:, 0], hinges[:, 2])


def too_slow(
    previous_mm: float,
    error_mm: float,
    rounds_left: int,
    reach: float = DEFAULT_POLICY.co_slow_reach,
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
        (``policy.co_slow_reach``); ``cut_short`` then says so.
    policy : the stop rules' thresholds (:class:`~.policy.LayoutPolicy`).
    """

    plain_mm: float
    conical: bool = False
    give_up_slow: bool = False
    policy: LayoutPolicy = DEFAULT_POLICY
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
        policy = self.policy
        stop_near = policy.co_stop_near_conical if self.conical else policy.co_stop_near
        # Stop once the re-solve is well inside the tolerance, or within the tolerance and
        # close to what the joint solve reached (more rounds would not gain much).  A re-solve
        # that misses the tolerance goes on even when it is close to a poor joint solve: later
        # rounds can still bring it within, where stopping would leave the tiling to be
        # split.
        if (
            self.worse >= 2
            or (first_round and error_mm > policy.co_give_up_ratio * self.plain_mm)
            or error_mm <= policy.co_stop_share * FLAT_EDGE_ERROR_TOL_MM
            or error_mm <= min(stop_near * FLAT_EDGE_ERROR_TOL_MM, policy.co_stop_ratio * joint_mm)
            or (
                error_mm <= stop_near * FLAT_EDGE_ERROR_TOL_MM
                and error_mm > policy.co_stall_gain * best_before
            )
        ):
            return progress, True
        # A conical round that lost ground is judged by the rounds after it (``worse``), and
        # so is a conical first round above the plain layout: conical rounds can lose ground
        # once and then converge, and a rate taken from the lost round would give them up
        # (and the bottom hinges their depth) too early.
        judged = (progress and error_mm < previous) or not self.conical
        left = policy.co_refinements + 1 - self.rounds
        if (
            self.give_up_slow
            and judged
            and too_slow(previous, error_mm, left, policy.co_slow_reach)
        ):
            self.cut_short = True
            return progress, True
        if self.conical and judged and too_slow(previous, error_mm, left, reach=1.0):
            # it would miss the tolerance: the caller co-optimizes again without the conical
            # condition
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
    between_rounds: Callable[[], None] | None = None,
    policy: LayoutPolicy = DEFAULT_POLICY,
) -> tuple[AssembledResult, FlatResult, dict[str, Any]]:
    """K3D and K2D moved together so the flat tiles are congruent to the assembled ones
    (:func:`~drawstring.geometry.flat.coflat.co_optimize_top`; with ``faces``, at their hinge points
    and with the clear openings of the current tiles, or with ``track_openings=False`` those of
    ``faces`` throughout), T3D extruded again under the new K3D and the flat layout solved
    again from the joint one.  The round whose re-solved layout has the smallest edge error is
    the one kept.  The new design is used only when its flat edge error is lower and the flat
    layout keeps every hard bound; otherwise the inputs come back unchanged with the reason
    (at once when round 1's joint solve ends no lower than the plain layout).
    With ``give_up_slow`` the rounds stop early when they converge too slowly to reach the
    tolerance (``policy.co_slow_reach``; the block then says ``cut_short``).  ``first_solves``
    keeps the first joint solve, which runs on the eq.-1 tiles and openings either way, for
    another call on the same inputs (the held-openings run after a tracked one).  With
    ``conical`` (``faces`` with bottom hinges) every joint solve also makes K3D conical and
    every round pulls the bottom hinges' corners to equal depths under both their tiles'
    top faces (:func:`depth_pull`), so that those corners meet in 3D, not only seen from
    above; the rounds then stop only within ``policy.co_stop_near_conical`` of the tolerance.
    ``conical_weight`` replaces ``coflat.CO_CONICAL``, the weight of that condition.
    ``between_rounds`` is called after every round that does not end the run (the ladder
    starts work ahead there once a core is spare, :meth:`~.co_ladder.CoLadder.poll`)."""

    openings = _Openings(linkage, faces, track_openings)
    block: dict[str, Any] = {"accepted": False, "reason": "", "steps": 0}
    judge = RoundJudge(
        flat.edge_error_max_mm, conical=conical, give_up_slow=give_up_slow, policy=policy
    )
    current, nodes = assembled, None
    # the joint solve's pull to the target: eq. 1's surface weight (--weights), or the policy's
    surface = policy.co_surface or (options.weights[2], 0.0)
    rounds: list[tuple[tuple[float, float], ...]] = [CO_STAGES, CO_STAGES[-1:]]
    best: tuple[AssembledResult, FlatResult] | None = None
    for _ in range(policy.co_refinements + 1):
        current, co = _joint_round(
            rounds, linkage, assembled, current, nodes, flat, target, surface, openings,
            first_solves, conical, conical_weight, block,
        )  # fmt: skip
        if best is None and not co.edge_error_max_mm < flat.edge_error_max_mm:
            # The first round's joint solve, in its own model, ends above the plain layout:
            # the re-solve under the true bounds does no better.
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
        pull = depth_pull(current, linkage, faces.bottom) if conical and faces else None
        extruded = reextrude(
            assembled, current.top, target.vertices, target.faces, measure=False,
            start_bottom=current.bottom, pull=pull,
        )  # fmt: skip
        # (``policy.co_required``: refused at a round that folds, later rounds start there)
        if extruded is None or (policy.co_required and _folds(assembled, extruded)):
            block["reason"] = INSIDE_OUT_REASON if extruded is None else FOLD_REASON
            return assembled, flat, block
        current = extruded
        new_flat = flat_layout(
            linkage, tiling, current, options, openings(current.tiles), initial_nodes=co.nodes
        )
        # A round counts as progress only below both the best round and the plain layout
        # (RoundJudge): the result must beat the plain layout to be used, and re-solves that
        # stay above it do not come down in later rounds.
        error = new_flat.edge_error_max_mm
        nodes = new_flat.nodes
        openings.hold(new_flat, current.tiles)
        logger.info(
            "co-optimization round: joint %.3g mm, re-solved %.3g mm", co.edge_error_max_mm, error
        )
        progress_made, stop = judge.judge(error, co.edge_error_max_mm)
        if progress_made:
            best = (current, new_flat)
        if stop:
            break
        if between_rounds is not None:
            between_rounds()
        rounds = [CO_STAGES[-1:]]
    if judge.cut_short:
        block["cut_short"] = True
    # a refinement round can lose (its re-solve may settle elsewhere): keep the best round
    assert best is not None
    return _verdict(assembled, flat, best, co, target, block)


class _Openings:
    """The hinge faces each solve of :func:`co_optimized` lays out on: ``faces`` as given,
    or with ``track`` those of the current tiles (their clear openings), where the slit ends
    whose windows closed on their openings are released (see ``HingeFaces.closing``).
    Calling it with the tiles gives their faces."""

    def __init__(self, linkage: Linkage, faces: HingeFaces | None, track: bool) -> None:
        self._linkage, self._faces, self._track = linkage, faces, track
        #: the tiles last given, and their faces
        self._last: tuple[NDArray[np.float64], HingeFaces] | None = None
        #: the openings of the last re-solved layout on its hinge faces
        self._held: NDArray[np.float64] | None = None
        #: the slit ends released from their clear windows so far
        self._released = np.zeros(len(faces.clear_lo) if faces is not None else 0, dtype=bool)

    def __call__(self, tiles: NDArray[np.float64]) -> HingeFaces | None:
        faces = self._faces
        if faces is None or not self._track:
            return faces
        last = self._last
        # a round's joint solve starts on the tiles the previous re-solve was given
        if last is None or not np.array_equal(last[0], tiles):
            fresh = hinge_faces(self._linkage, tiles, faces.bottom)
            if last is not None and self._held is not None:
                # A window that closed on the opening laid out in it is released: the joint
                # solve presses the opening against it, its move of K3D closes it further,
                # and the re-solve has to give way every round.
                self._released |= last[1].closing(fresh, self._held)
            released = self._released
            fresh = replace(fresh, released=released.copy()) if released.any() else fresh
            self._last = last = (tiles.copy(), fresh)
        return last[1]

    @property
    def faces_given(self) -> HingeFaces | None:
        """The hinge faces of the eq.-1 tiles, as given."""
        return self._faces

    def hold(self, flat: FlatResult, tiles: NDArray[np.float64]) -> None:
        """Keep the openings of the re-solved ``flat`` on its hinge faces (tracked faces)."""
        if flat.hinges is not None and self._track:
            self._held = hinge_face_openings(self._linkage, flat, tiles)


def _joint_round(
    rounds: list[tuple[tuple[float, float], ...]],
    linkage: Linkage,
    assembled: AssembledResult,
    current: AssembledResult,
    nodes: NDArray[np.float64] | None,
    flat: FlatResult,
    target: Target,
    surface: tuple[float, float],
    openings: _Openings,
    first_solves: dict[str, CoOptimizedTop] | None,
    conical: bool,
    conical_weight: float | None,
    block: dict[str, Any],
) -> tuple[AssembledResult, CoOptimizedTop]:
    """The joint solves of one round of :func:`co_optimized`, one per continuation schedule
    in ``rounds``, each from the last: the moved assembled shape (T3D moved along with its new
    top) and the last joint solve.  Their steps are added to ``block``; ``surface``: the
    weights of their pull to the target, at the vertices and at the quads' face samples.

    Round 1 runs the whole continuation. The bottom faces decide the bottom-face angle bounds,
    so round 2 repeats the last stage with T3D moved along with the new top (a translation of
    each bottom vertex with its top vertex is usually close enough for those bounds). T3D is
    then extruded under the new top and the flat layout re-solved with the true bounds; when
    that costs much of what the joint solve gained, the last stage runs once more on the
    extruded T3D, starting from the re-solved layout: it holds the extruded tiles' bounds
    already, so the joint solve need only correct it where the re-extrusion moved the hinge
    points (the bottom corners).  A start from the last joint solve's nodes would have to
    undo that shift too and move K3D further, which moves the bottom corners again, so that
    the rounds stall.
    """
    co: CoOptimizedTop | None = None
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
                w_surface=surface[0],
                w_samples=surface[1],
                stages=stages,
                start_nodes=nodes,
                hinges=openings.faces_given if first else openings(current.tiles),
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
    assert co is not None
    return current, co


def _verdict(
    assembled: AssembledResult,
    flat: FlatResult,
    best: tuple[AssembledResult, FlatResult],
    co: CoOptimizedTop,
    target: Target,
    block: dict[str, Any],
) -> tuple[AssembledResult, FlatResult, dict[str, Any]]:
    """:func:`co_optimized`'s outcome: the ``best`` round (measured) where it keeps every
    tile's orientation and every hard bound of the plain ``flat`` layout and lowers its edge
    error, else the inputs with the reason in ``block`` (``co``: the last joint solve)."""
    new_assembled, new_flat = best
    if new_flat.hinges is not None and new_flat.hinges.released is not None:
        block["released_ends"] = int(new_flat.hinges.released.sum())
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
    if _folds(assembled, new_assembled):
        block["reason"] = FOLD_REASON
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


#: Why a co-optimization whose re-extruded shape has a tile inside out is refused.
INSIDE_OUT_REASON = "the new assembled shape would turn a tile inside out"
#: Why a co-optimization whose shape folds a tile or turns one over (:func:`_folds`) is
#: refused.
FOLD_REASON = "the new assembled shape would fold a tile or turn one over"


def _folds(before: AssembledResult, after: AssembledResult) -> bool:
    """Whether ``after``, the co-optimized ``before``, folds a tile (a top corner no longer
    convex) or turns one over."""
    return after.metrics.get("corner_margin_min", 1.0) <= 0 or _turned_over(before, after) > 0


def _turned_over(before: AssembledResult, after: AssembledResult) -> int:
    """How many tiles turned over: their top face turned by more than 90 deg.

    (Not the target-normal count ``flipped_tiles``: on a scanned mesh the one closest
    triangle at a tile's centre can face another way, which says nothing of the tile.)
    """
    turns = np.einsum(
        "ki,ki->k",
        quad_vector_areas(before.top, before.quads),
        quad_vector_areas(after.top, after.quads),
    )
    return int(np.sum(turns <= 0))
