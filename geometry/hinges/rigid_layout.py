"""Rigid planar layout of the flat tiles with their hinge pairs brought together (paper 4.4).

The ``dual`` strategy's ``w_rigid E_rigid + w_collision E_collision + w_conn E_conn`` with the
rigidity exact: every flat tile keeps its T2D shape and only turns about the vertical axis and
translates in the plane (3 degrees of freedom).  Close tile pairs are kept apart by separating
planes attached to one tile of each pair (through the hinge for hinged pairs, or on the hinge
face only for pairs whose overlap is trimmed), gap angles are held in ``[theta_min, 90]``, and
the squared distance of every hinge pair is minimized by an augmented Lagrangian with
Levenberg-Marquardt subproblems.  Then every pair is merged into one point where that keeps the
layout valid.  :func:`~drawstring.geometry.hinges.placement.layout_hinges` decides the hinge
sides and the trims and calls :func:`rigid_layout`; the planes are found and measured in
:mod:`~drawstring.geometry.hinges.separating_planes`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.core.tolerances import (
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_FEASIBLE_MM,
)
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.verify import hinge_gaps
from drawstring.geometry.hinges.augmented_lagrangian import (
    LayoutConstraints,
    augmented_lagrangian,
    constraint_values,
    normal_pattern,
)
from drawstring.geometry.hinges.merging import (
    broken_merges,
    hinges_of_ends,
    merge_points,
    merged_tiles,
)
from drawstring.geometry.hinges.separating_planes import (
    RigidPose,
    SeparatingPlanes,
    select_planes,
)
from drawstring.geometry.solve.spd import SpdSolver
from drawstring.geometry.tiling.linkage import Linkage, SlitEnds, slit_ends

logger = logging.getLogger(__name__)


__all__ = ["HingeStrategy", "RigidLayoutResult", "rigid_layout"]


@dataclass(frozen=True)
class RigidLayoutResult:
    """Outcome of :func:`rigid_layout`.

    Attributes
    ----------
    tiles : (T, 8, 3) float, mm
        Rigid tiles (congruent to the input shapes) before merging.
    merged : (T, 8, 3) float, mm
        Tiles with every merged hinge pair moved to its shared point.
    points : (H, 3) float, mm
        Hinge points (shared point, or the midpoint of an unmerged pair).
    is_merged : (H,) bool
    gap_mm : (H,) float
        3D distance of each hinge pair before merging.
    violation_mm : float
        Largest remaining violation of a separating plane or angle bound (angle bounds in rad
        times the mean tile side), rigid tiles.
    iterations : int
        Accepted Levenberg-Marquardt steps over all rounds.
    first_planes : SeparatingPlanes
        The separating planes chosen at the start layout (``shapes``), before any round.
    """

    tiles: FloatArray
    merged: FloatArray
    points: FloatArray
    is_merged: BoolArray
    gap_mm: FloatArray
    violation_mm: float
    iterations: int
    first_planes: SeparatingPlanes


def rigid_layout(
    linkage: Linkage,
    shapes: ArrayLike,
    hinge_ids: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    min_gap_angle_deg: float = 12.0,
    clearance_mm: float = HINGE_LAYOUT_CLEARANCE_MM,
    max_rounds: int = 40,
    inner_steps: int = 60,
    trim: ArrayLike | None = None,
    like: RigidLayoutResult | None = None,
) -> RigidLayoutResult:
    """Lay rigid flat tiles out so paired hinge vertices meet as closely as possible.

    Every tile keeps its shape (``shapes``, the T2D pose: top face horizontal) and may only
    turn about the vertical axis and translate in the plane (3 DOF).  Minimized: the squared
    horizontal distance of every hinge pair.  Subject to

    * every slit end's opening angle in ``[min_gap_angle_deg, 90]`` on the top faces and, for
      ``dual``, on the bottom faces (linear in the rotations);
    * every close pair of tiles separated by a plane attached to one of them (exact
      non-interpenetration for convex tiles; a non-convex, dart-shaped tile takes part as its
      two convex pieces, :func:`~drawstring.geometry.flat.polygons.convex_pieces`, each separated on
      its own, since its hull would fill the notch): with ``clearance_mm`` to spare, except that a
      hinged pair's plane passes through the hinge, which with the corner of the other face at
      the hinge may touch it; for ``top`` hinged pairs, and ``trim`` ones, only the hinge faces
      are separated (their 3D overlap is trimmed), and for ``top`` also unhinged pairs only
      on their top faces (the paper's ``top`` strategy trims whatever two tiles overlap in the
      flat pose; planes through whole wedge-shaped tiles would hold hinges apart over tiny
      overlaps).  Planes are re-chosen (sampled max-margin, never accepting a violation on the
      carrying tile's side when avoidable) in the first rounds, warm-started from the previous
      planes.

    The solver is an augmented Lagrangian whose subproblems are solved by Levenberg-Marquardt.
    Hinge pairs are then merged at their midpoint moved horizontally onto the pair's plane; a
    merge that would break an angle bound (after raising that bound's margin and re-solving) or
    a plane is undone, leaving that pair rigid and apart.

    Parameters
    ----------
    linkage : Linkage
    shapes : (T, 8, 3) float, mm
        T2D tiles (start layout and rigid shapes).
    hinge_ids : (H, 2) int
        ``8 * tile + vertex`` of both vertices of every hinge (tile order of ``linkage.hinges``).
    strategy : "dual" | "top"
    min_gap_angle_deg : float, deg
    clearance_mm : float, mm
    max_rounds, inner_steps : solver limits (augmented Lagrangian rounds, LM steps per round).
    trim : (H,) bool, optional
        ``dual`` hinges whose pairs are separated on the hinge face only (default none; every
        hinge for ``top``).
    like : RigidLayoutResult, optional
        An earlier layout of these ``shapes`` (with other ``trim`` flags, say): its first
        planes are taken as they are for the pairs whose flags agree, instead of being searched
        for again (the same planes, found once).

    Returns
    -------
    RigidLayoutResult
    """
    t2 = np.asarray(shapes, dtype=np.float64)
    ids = np.asarray(hinge_ids, dtype=np.int64).reshape(-1, 2)
    all_top = strategy == HingeStrategy.TOP
    cut = np.full(len(ids), all_top) if trim is None else np.asarray(trim, dtype=bool)
    if cut.shape != (len(ids),):
        raise InternalError(f"trim has shape {cut.shape}; pass one flag per hinge")
    solver = _LayoutSolver.start(
        linkage, t2, ids, cut, strategy, min_gap_angle_deg, clearance_mm, inner_steps
    )
    layout = solver.layout
    known = None if like is None else like.first_planes
    first_planes = select_planes(layout, linkage, ids, cut, clearance_mm, solver.reach, known=known)
    planes, violation = solver.run(first_planes, max_rounds, 2)
    planes, violation, is_merged = _merge_within_angle_bounds(
        solver, planes, violation, max_rounds, min_gap_angle_deg
    )
    x = layout.positions()
    points = merge_points(layout, planes, ids, x)
    gap = hinge_gaps(x, ids)
    merged, is_merged = _undo_broken_merges(solver, planes, x, points, is_merged, min_gap_angle_deg)
    points = np.where(
        is_merged[:, None],
        points,
        0.5 * (x.reshape(-1, 3)[ids[:, 0]] + x.reshape(-1, 3)[ids[:, 1]]),
    )
    return RigidLayoutResult(
        x, merged, points, is_merged, gap, violation, solver.total_steps, first_planes
    )


#: Penalty weight every call of :meth:`_LayoutSolver.run` starts from (the multipliers carry
#: over between calls, the penalty does not).
_RHO_START = 10.0


@dataclass
class _LayoutSolver:
    """The augmented Lagrangian of one rigid layout: the pose it moves (``layout``), the fixed
    data of its constraints, and what carries over between calls of :meth:`run` (the
    multipliers, the normal-equations solver, the count of accepted steps).

    ``lo_deg`` and ``hi_deg`` ``(F, E)`` are the angle bounds with their margins, raised where a
    merge needs room (:func:`_merge_within_angle_bounds`)."""

    layout: RigidPose
    linkage: Linkage
    ids: IntArray
    cut: BoolArray
    ends: SlitEnds
    faces: IntArray
    angle0: FloatArray
    lo_deg: FloatArray
    hi_deg: FloatArray
    scale: float
    clearance_mm: float
    inner_steps: int
    weight: FloatArray
    reach: float
    pin: FloatArray
    #: One solver for the whole layout, its pattern reserved for all the constraints a set of
    #: planes can make active: one symbolic analysis per set of planes, not one whenever the
    #: active set grows.
    factor: SpdSolver
    lam: FloatArray | None = None
    total_steps: int = 0

    @classmethod
    def start(
        cls,
        linkage: Linkage,
        t2: FloatArray,
        ids: IntArray,
        cut: BoolArray,
        strategy: HingeStrategy,
        min_gap_angle_deg: float,
        clearance_mm: float,
        inner_steps: int,
    ) -> _LayoutSolver:
        """The solver at the start layout ``t2`` (every component pinned by its first tile)."""
        layout = RigidPose(t2)
        layout.unhinged_top_only = strategy == HingeStrategy.TOP
        ends = slit_ends(linkage)
        faces = np.array([0, 4] if strategy == HingeStrategy.DUAL else [0], dtype=np.int64)
        angle0 = np.stack([ends.angles(t2, int(f)) for f in faces])
        lo_deg = np.full(angle0.shape, float(min_gap_angle_deg) + HINGE_ANGLE_MARGIN_DEG)
        hi_deg = np.full(angle0.shape, 90.0 - HINGE_ANGLE_MARGIN_DEG)
        side = np.linalg.norm(t2[:, [1, 2, 3, 0], :2] - t2[:, :4, :2], axis=2)
        scale = float(side.mean()) if side.size else 1.0
        weight = np.ones(len(ids))
        reach = 0.5 * scale
        pin = np.zeros(3 * layout.n)
        comp = linkage.tile_component
        first = np.unique(comp, return_index=True)[1]
        pin[(3 * first[:, None] + np.arange(3)).ravel()] = 1.0
        return cls(
            layout, linkage, ids, cut, ends, faces, angle0, lo_deg, hi_deg, scale,
            clearance_mm, inner_steps, weight, reach, pin, SpdSolver(),
        )  # fmt: skip

    def constraints(self, planes: SeparatingPlanes) -> LayoutConstraints:
        return LayoutConstraints(
            planes,
            self.ends,
            self.faces,
            self.angle0,
            np.radians(self.lo_deg),
            np.radians(self.hi_deg),
            self.scale,
        )

    def run(
        self, planes: SeparatingPlanes, rounds: int, reselect: int
    ) -> tuple[SeparatingPlanes, float]:
        """Augmented Lagrangian rounds, choosing the planes again in rounds ``1..reselect``;
        the planes at the end and the largest constraint violation, mm."""
        layout, ids, ends, factor = self.layout, self.ids, self.ends, self.factor
        con = self.constraints(planes)
        factor.reserve(normal_pattern(layout.n, ids, planes, ends))
        g, _ = constraint_values(layout, con, layout.phi, layout.trans)
        lam = self.lam if self.lam is not None and len(self.lam) == len(g) else None
        lam = np.zeros(len(g)) if lam is None else lam
        rho = _RHO_START
        prev = np.inf
        viol = float(np.max(-g, initial=0.0))
        for r in range(rounds):
            if 0 < r <= reselect:
                planes = select_planes(
                    layout, self.linkage, ids, self.cut, self.clearance_mm, self.reach,
                    previous=planes,
                )  # fmt: skip
                n_old = len(lam)
                con = self.constraints(planes)
                factor.reserve(normal_pattern(layout.n, ids, planes, ends))
                g, _ = constraint_values(layout, con, layout.phi, layout.trans)
                n_ang = 2 * self.angle0.size
                lam = np.concatenate([np.zeros(len(g) - n_ang), lam[n_old - n_ang :]])
            g, steps = augmented_lagrangian(
                layout, con, ids, lam, rho, self.inner_steps, self.weight, self.pin, factor
            )
            self.total_steps += steps
            viol = float(np.max(-g, initial=0.0))
            lam = np.maximum(0.0, lam - rho * g)
            logger.debug("rigid layout round %d: violation %.3g mm, rho %.3g", r, viol, rho)
            if viol <= HINGE_LAYOUT_FEASIBLE_MM and r >= reselect:
                break
            if viol > 0.25 * prev:
                rho = min(rho * 5.0, 1e5)
            prev = viol
        self.lam = lam
        return planes, viol


def _merge_within_angle_bounds(
    solver: _LayoutSolver,
    planes: SeparatingPlanes,
    violation: float,
    max_rounds: int,
    min_gap_angle_deg: float,
) -> tuple[SeparatingPlanes, float, BoolArray]:
    """Where merging the hinge pairs would bring a slit end's angle near its bounds, raise that
    bound's margin and solve again (up to three times); the hinges of ends still too near are
    left unmerged.  Returns the planes, the violation and which hinges are merged."""
    layout, ids, ends, faces = solver.layout, solver.ids, solver.ends, solver.faces
    is_merged = np.ones(len(ids), dtype=bool)
    for attempt in range(4):
        x = layout.positions()
        points = merge_points(layout, planes, ids, x)
        merged = merged_tiles(x, ids, points, is_merged)
        ang = np.stack([np.degrees(ends.angles(merged, int(f))) for f in faces])
        lo_def = min_gap_angle_deg - ang
        hi_def = ang - 90.0
        need_lo = lo_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        need_hi = hi_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        bad_ends = (need_lo | need_hi).any(axis=0)
        logger.debug(
            "merge angles attempt %d: %d bad ends, deficit %.3g",
            attempt,
            int(bad_ends.sum()),
            float(max(np.max(lo_def, initial=-np.inf), np.max(hi_def, initial=-np.inf))),
        )
        if not bad_ends.any():
            break
        if attempt == 3:
            is_merged &= ~hinges_of_ends(ends, bad_ends, ids, faces)
            break
        solver.lo_deg[need_lo] += 2.0 * np.maximum(lo_def[need_lo], 0.0) + HINGE_ANGLE_MARGIN_DEG
        solver.hi_deg[need_hi] -= 2.0 * np.maximum(hi_def[need_hi], 0.0) + HINGE_ANGLE_MARGIN_DEG
        planes, violation = solver.run(planes, max_rounds, 0)
    return planes, violation, is_merged


def _undo_broken_merges(
    solver: _LayoutSolver,
    planes: SeparatingPlanes,
    x: FloatArray,
    points: FloatArray,
    is_merged: BoolArray,
    min_gap_angle_deg: float,
) -> tuple[FloatArray, BoolArray]:
    """The merged tiles, after undoing, round by round, the merges that break a plane or a
    gap-angle bound (:func:`~drawstring.geometry.hinges.merging.broken_merges`), and which
    hinges stay merged."""
    ids = solver.ids
    for _ in range(len(ids) + 1):
        merged = merged_tiles(x, ids, points, is_merged)
        undo = broken_merges(
            solver.layout,
            solver.linkage,
            solver.cut,
            planes,
            solver.ends,
            solver.faces,
            merged,
            ids,
            is_merged,
            min_gap_angle_deg,
        )
        if not undo.any():
            break
        is_merged &= ~undo
    return merged, is_merged
