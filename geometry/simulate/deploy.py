"""Deployment simulation from the flat to the assembled configuration (paper section 5.4).

Projective dynamics (Bouaziz et al. 2014) on the shared local-global solver
(:mod:`drawstring.geometry.solve.solver`).  Every time step minimizes

    sum_i m_i / h^2 |x_i - y_i|^2  +  sum_groups w ||A X - P(X)||^2,   y = x + h v + h^2 g,

with the inertia term written as closeness to moving targets ``y`` (one constant matrix, so the
factor is reused), and these groups (:mod:`~drawstring.geometry.simulate.groups`; the run's
system is :class:`~drawstring.geometry.simulate.system.DeploySystem`, its time stepping
:mod:`~drawstring.geometry.simulate.stepping`):

* ``rigid`` -- :class:`RigidShape`: each tile's eight vertices projected onto the closest rigid
  copy of the fabricated (flat) tile (batched Kabsch);
* ``hinge`` -- paired hinge vertices coincide (the linkage's joints);
* ``contact`` -- :class:`FaceContact`: the side faces of grid neighbours (which touch in the
  assembled state) do not pass through each other; half-space rows along an axis frozen once
  per step, so the matrix is constant and a step costs no collision search;
* ``split_contact`` -- the same for the faces that touch across a split line
  (:func:`~.inputs.split_contact_pairs`); such a pair engages (for good) once its faces come
  within half a tile side, since far apart in the flat layout a half-space between them means
  nothing;
* ``magnet`` -- the magnets across splits: an engaged split pair is reeled in corner by corner
  (``magnet_rate`` tile sides per step) until its faces touch;
* ``snap`` -- the string: for consecutive tiles on the route, the paired side faces are reeled
  in.  Faces that touch in the assembled state are pulled together corner by corner; where the
  string crosses a gap between faces that do not meet, the midpoints are reeled in to their
  assembled distance;
* ``lift`` -- the string's exits: the top corners around every lift gap are pulled up to their
  assembled height (the assembled tiles placed on the table under the flat layout), until a
  check in the settle finds the structure locked by the string (every route pair closed, every
  hinged pair stuck) but off its shape: then they are let go
  (:meth:`~.system.DeploySystem.release_lift`);
* ``stick`` -- static friction in the settle: once the string is reeled in, a hinged neighbour
  pair whose contact faces lie face on face (every corner within ``stick_rel``, 3 % of a tile
  side, of its assembled partner corner; :func:`~.tiles.face_on_face`) sticks: its corners are held
  together from then on, as in the assembled state.  Faces pressed together by the taut
  string neither slide nor separate under static friction.  Without this the unilateral
  contacts alone fix the interior: after the boundary loop closes, the linkage is isostatic
  but its softest flex is nearly free (smallest nonzero singular value of the rigidity matrix
  ~6e-6 relative), and the settle of a 40 x 40 linkage creeps for hundreds of steps.  Pairs
  only stick once close to face on face, so nothing sticks in the flat pose or without the
  string; the group is rebuilt (one factorization) when more pairs stick;
* the table -- tiles never dip below the lowest level of the flat pose (rigid push up).

String actuation: the string is *reeled in*.  Each snap row may be at most ``r(t)`` long and
``r(t)`` goes from its flat length to its assembled length over ``ramp_steps``; lift targets
move over the same ramp.  Targets move without touching the system matrix.  Then the tension
rises in a few discrete lock levels (every weight times 10, 100: one refactorization each),
which makes the step quasi-static and locks the structure against gravity.

Success is measured (every ``check_every`` steps after the last lock level; the run stops at the
first success): every route pair at its assembled distance within tolerance, every tile within
``deviation`` of the assembled tiles after one rigid (Kabsch) alignment over all vertices, the
conservative penetration depth below tolerance, rigid edges within tolerance in every step, all
within the step budget.  Otherwise the result is "stuck" with the open route gaps.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.inputs import (
    RouteLike,
    lift_targets_for_gaps,
    route_snap_pairs,
    route_steps,
)
from drawstring.geometry.simulate.result import (
    THOROUGH_SETTINGS,
    SimulationResult,
    SimulationSettings,
    SimulationTolerances,
)
from drawstring.geometry.simulate.stepping import SuccessCheck, run_steps
from drawstring.geometry.simulate.system import DeploySystem
from drawstring.geometry.simulate.tiles import mean_tile_side, neighbour_tile_pairs
from drawstring.geometry.tiling.linkage import Linkage

logger = logging.getLogger(__name__)


__all__ = [
    "GRAVITY_MM_S2",
    "deploy_check_from_simulation",
    "simulate_deployment",
    "simulate_stage",
]

GRAVITY_MM_S2 = (0.0, 0.0, -9810.0)


# --------------------------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------------------------


def _check_inputs(
    tiles_flat: FloatArray, tiles_assembled: FloatArray, hinge_vertices: IntArray
) -> None:
    if tiles_flat.ndim != 3 or tiles_flat.shape[1:] != (8, 3):
        raise InternalError(f"flat tiles must be (T, 8, 3), got {tiles_flat.shape}")
    if tiles_assembled.shape != tiles_flat.shape:
        raise InternalError(
            f"assembled tiles {tiles_assembled.shape} and flat tiles {tiles_flat.shape} differ; "
            "pass the same tiles in both poses"
        )
    if not (np.all(np.isfinite(tiles_flat)) and np.all(np.isfinite(tiles_assembled))):
        # the user's tiles.npz can hold them (drawstring simulate FOLDER)
        raise InputError("tile vertices must be finite")
    n = tiles_flat.shape[0] * 8
    if hinge_vertices.size and (hinge_vertices.min() < 0 or hinge_vertices.max() >= n):
        raise InternalError("hinge vertex ids must be tile * 8 + vertex within the tile count")


def simulate_deployment(
    linkage: Linkage,
    tiles_flat: ArrayLike,
    tiles_assembled: ArrayLike,
    hinge_vertices: ArrayLike,
    snap_pairs: ArrayLike,
    lift_vertices: ArrayLike = (),
    lift_targets: ArrayLike = (),
    *,
    snap_gaps: ArrayLike | None = None,
    thickness: float | None = None,
    gravity: tuple[float, float, float] = GRAVITY_MM_S2,
    settings: SimulationSettings | None = None,
    tolerances: SimulationTolerances | None = None,
    frame_every: int = 5,
) -> SimulationResult:
    """Simulate the string pull from the flat pose and measure whether the linkage assembles.

    Parameters
    ----------
    linkage : topology (grid cells give the contact candidates).
    tiles_flat : (T, 8, 3) float, mm, T2D: the start pose, bottoms on the table.
    tiles_assembled : (T, 8, 3) float, mm, T3D: the goal (any rigid placement).
    hinge_vertices : (H, 2) int, ``tile * 8 + vertex`` ids that the hinges join
        (:func:`hinge_vertex_pairs`).
    snap_pairs : (P, 4) int, ``(tile_a, side_a, tile_b, side_b)`` from :func:`route_snap_pairs`;
        empty: no string.
    lift_vertices : (k,) int, vertex ids pulled up (:func:`lift_targets_for_gaps`).
    lift_targets : (k, 3) float, mm, their goals in the frame of ``tiles_assembled``.
    snap_gaps : (P,) int, gap of every snap pair (reported in ``open_gaps``); default the pair
        index.
    thickness : float, mm, tile thickness; only checked against the flat pose (top faces at
        ``z = thickness`` above the table) when given.
    gravity : (3,) mm / s^2.
    settings, tolerances : see :class:`SimulationSettings`, :class:`SimulationTolerances`.
    frame_every : keep every this many steps as a frame (the first and last always).

    Returns
    -------
    SimulationResult
    """
    start = time.perf_counter()
    cfg = settings or SimulationSettings()
    tol = tolerances or SimulationTolerances()
    flat, goal, hinges, pairs, gaps_of_pairs, lift_v, lift_t = _checked_arrays(
        linkage, cfg, frame_every, tiles_flat, tiles_assembled, hinge_vertices, snap_pairs,
        snap_gaps, lift_vertices, lift_targets,
    )  # fmt: skip
    side = mean_tile_side(goal)
    if thickness is not None:
        _check_thickness(flat, thickness)
    system = DeploySystem.build(linkage, flat, goal, hinges, pairs, lift_v, lift_t, side, cfg, tol)
    check = SuccessCheck.of(goal, pairs, neighbour_tile_pairs(linkage), side, tol)
    run = run_steps(system, check, flat, gravity, frame_every)
    reasons, dist, dev, pen = run.verdict if run.verdict is not None else check.failures(run.x)
    open_mask = dist > tol.gap_closed_rel * side
    open_gaps = tuple(sorted({int(g) for g in gaps_of_pairs[open_mask]}))
    if run.max_edge_err > tol.edge_length_rel * side:
        reasons.append(
            f"edge error {run.max_edge_err:.3g} mm > {tol.edge_length_rel * side:.3g} mm"
        )
    if len(pairs) == 0 and len(lift_v) == 0:
        reasons.append("no string: nothing pulls")
    elapsed = time.perf_counter() - start
    result = SimulationResult(
        deployed=not reasons,
        steps=run.step,
        final_max_deviation_mm=float(dev.max()),
        max_penetration_mm=pen,
        time_s=elapsed,
        open_gaps=open_gaps,
        frames=np.stack(run.frames).astype(np.float32),
        max_edge_error_mm=run.max_edge_err,
        gap_distance_mm=dist,
        per_step_ms=1e3 * elapsed / max(run.step, 1),
        iterations=run.iterations,
        factorizations=run.factorizations,
        tile_deviation_mm=dev,
        reasons=tuple(reasons),
        lift_released_step=system.lift_released,
    )
    logger.info(
        "simulation: deployed=%s steps=%d dev=%.3g mm pen=%.3g mm edge=%.3g mm %.2f s %s",
        result.deployed,
        run.step,
        result.final_max_deviation_mm,
        pen,
        run.max_edge_err,
        elapsed,
        "; ".join(reasons),
    )
    return result


def _checked_arrays(
    linkage: Linkage,
    cfg: SimulationSettings,
    frame_every: int,
    tiles_flat: ArrayLike,
    tiles_assembled: ArrayLike,
    hinge_vertices: ArrayLike,
    snap_pairs: ArrayLike,
    snap_gaps: ArrayLike | None,
    lift_vertices: ArrayLike,
    lift_targets: ArrayLike,
) -> tuple[FloatArray, FloatArray, IntArray, IntArray, IntArray, IntArray, FloatArray]:
    """:func:`simulate_deployment`'s arguments as arrays, checked: the flat and goal poses, the
    hinge vertex pairs, the snap pairs and their gaps, the lift vertices and their targets."""
    flat = np.asarray(tiles_flat, dtype=np.float64)
    goal = np.asarray(tiles_assembled, dtype=np.float64)
    hinges = np.asarray(hinge_vertices, dtype=np.int64).reshape(-1, 2)
    _check_inputs(flat, goal, hinges)
    if flat.shape[0] != linkage.n_tiles:
        raise InternalError(f"{flat.shape[0]} tiles given for a linkage of {linkage.n_tiles}")
    counts = (cfg.max_steps, cfg.ramp_steps, cfg.hinge_close_steps, cfg.check_every)
    if min(frame_every, cfg.stall_checks, *counts) < 1:
        raise InternalError(
            "frame_every, max_steps, ramp_steps, hinge_close_steps, check_every and "
            "stall_checks must be >= 1"
        )
    pairs = np.asarray(snap_pairs, dtype=np.int64).reshape(-1, 4)
    gaps_of_pairs = (
        np.arange(len(pairs)) if snap_gaps is None else np.asarray(snap_gaps, dtype=np.int64)
    )
    lift_v = np.asarray(lift_vertices, dtype=np.int64).reshape(-1)
    lift_t = np.asarray(lift_targets, dtype=np.float64).reshape(-1, 3)
    if len(lift_v) != len(lift_t):
        raise InternalError("give one lift target per lift vertex")
    return flat, goal, hinges, pairs, gaps_of_pairs, lift_v, lift_t


def _check_thickness(flat: FloatArray, thickness: float) -> None:
    """Log when the flat tiles' tops do not sit ``thickness`` above the table."""
    top_level = flat[:, :4, 2].mean() - flat[..., 2].min()
    if abs(top_level - thickness) > 0.05 * thickness:
        # a sanity check of the caller's pose; on a strongly non-conical quad mesh the
        # tiles' own thicknesses (design.json thickness_min/max_mm) spread this far
        logger.info(
            "flat tiles' tops are %.3f mm above the table, thickness is %.3f mm",
            top_level,
            thickness,
        )


def simulate_stage(
    linkage: Linkage,
    tiles_flat: ArrayLike,
    tiles_assembled: ArrayLike,
    hinge_vertices: ArrayLike,
    route: RouteLike | ArrayLike,
    lift_gaps: ArrayLike,
    thickness: float | None = None,
    *,
    gravity: tuple[float, float, float] = GRAVITY_MM_S2,
    settings: SimulationSettings | None = None,
    tolerances: SimulationTolerances | None = None,
    frame_every: int = 5,
    retry: SimulationSettings | None = THOROUGH_SETTINGS,
) -> SimulationResult:
    """The pipeline's simulation stage: deploy the flat linkage by its string route.

    Parameters
    ----------
    linkage : topology.
    tiles_flat : (T, 8, 3) float, mm, T2D after the hinge layout (fabricated tiles).
    tiles_assembled : (T, 8, 3) float, mm, T3D.
    hinge_vertices : (H, 2) int, ``tile * 8 + vertex`` of both tiles of every hinge.
    route : the closed string route (:class:`~drawstring.geometry.route.result.Route` or ``(r, 4)``
        steps).
    lift_gaps : (L,) int, gap ids of the lift points; those the route does not pass are not
        pulled (the string leaves the structure only on its route).
    thickness : float, mm, optional consistency check of the flat pose.
    gravity, settings, tolerances, frame_every : see :func:`simulate_deployment`.
    retry : when ``settings`` is not given and the default run gets stuck, run again with these
        settings and keep whichever result deployed (else the smaller deviation); ``None``: no
        retry.  The default settings are fast but converge slowly on some shapes (the chair
        creeps); the thorough ones are slower per step and jam some others (the seashell).

    Returns
    -------
    SimulationResult
    """
    steps = route_steps(route)
    pairs, pair_gaps = route_snap_pairs(steps)
    goal = np.asarray(tiles_assembled, dtype=np.float64)
    # The string can only pull where it leaves the structure: a lift gap the route does not
    # pass (metrics.route.lift_gaps_missed) is not pulled.
    wanted = np.asarray(lift_gaps, dtype=np.int64).reshape(-1)
    reached = wanted[np.isin(wanted, steps[:, 0])]
    if len(reached) < len(wanted):
        logger.info(
            "simulation: lift gaps %s are not on the route and are not pulled",
            sorted(set(wanted.tolist()) - set(reached.tolist())),
        )
    verts, targets = lift_targets_for_gaps(linkage, goal, reached)

    def run(cfg: SimulationSettings | None) -> SimulationResult:
        return simulate_deployment(
            linkage,
            tiles_flat,
            goal,
            hinge_vertices,
            pairs,
            verts,
            targets,
            snap_gaps=pair_gaps,
            thickness=thickness,
            gravity=gravity,
            settings=cfg,
            tolerances=tolerances,
            frame_every=frame_every,
        )

    result = run(settings)
    if result.deployed or settings is not None or retry is None:
        return result
    logger.info("simulation: stuck with the default settings; retrying with %s", retry)
    second = run(retry)
    total = result.time_s + second.time_s  # the reported wall time covers both runs
    if second.deployed or second.final_max_deviation_mm < result.final_max_deviation_mm:
        return replace(second, time_s=total)
    return replace(result, time_s=total)


# --------------------------------------------------------------------------------------------
# Plug-in for the lift-point threshold sweep
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _SimulationCheck:
    """``check(lift_gaps) -> bool`` backed by :func:`simulate_deployment`."""

    name: str
    linkage: Linkage
    tiles_flat: FloatArray
    tiles_assembled: FloatArray
    hinge_vertices: IntArray
    route_for: Callable[[IntArray], Sequence[tuple[int, int, int, int]]]
    options: dict[str, object]

    def __call__(self, lift_gaps: IntArray) -> bool:
        gaps = np.asarray(lift_gaps, dtype=np.int64).reshape(-1)
        pairs, pair_gaps = route_snap_pairs(self.route_for(gaps))
        verts, targets = lift_targets_for_gaps(self.linkage, self.tiles_assembled, gaps)
        result = simulate_deployment(
            self.linkage,
            self.tiles_flat,
            self.tiles_assembled,
            self.hinge_vertices,
            pairs,
            verts,
            targets,
            snap_gaps=pair_gaps,
            **self.options,  # type: ignore[arg-type]
        )
        return result.deployed


def deploy_check_from_simulation(
    linkage: Linkage,
    tiles_flat: ArrayLike,
    tiles_assembled: ArrayLike,
    hinge_vertices: ArrayLike,
    route_for: Callable[[IntArray], Sequence[tuple[int, int, int, int]]]
    | Sequence[tuple[int, int, int, int]],
    **options: object,
) -> Callable[[IntArray], bool]:
    """A deployment check for ``select_lift_points(..., deploy_check=...)``.

    Parameters
    ----------
    linkage, tiles_flat, tiles_assembled, hinge_vertices : as :func:`simulate_deployment`.
    route_for : ``route_for(lift_gaps) -> route steps`` (the route depends on the lift points),
        or one fixed route.
    **options : keyword options of :func:`simulate_deployment` (``settings``, ``tolerances``, ...).

    Returns
    -------
    ``check(lift_gaps) -> bool`` with a ``name`` attribute; True when the simulated deployment
    with those lift gaps succeeds.
    """
    if callable(route_for):
        fn = route_for
    else:
        fixed = list(route_for)

        def fn(_: IntArray) -> Sequence[tuple[int, int, int, int]]:
            return fixed

    return _SimulationCheck(
        name="projective-dynamics deployment simulation",
        linkage=linkage,
        tiles_flat=np.asarray(tiles_flat, dtype=np.float64),
        tiles_assembled=np.asarray(tiles_assembled, dtype=np.float64),
        hinge_vertices=np.asarray(hinge_vertices, dtype=np.int64).reshape(-1, 2),
        route_for=fn,
        options=dict(options),
    )
