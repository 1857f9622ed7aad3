"""Deployment simulation from the flat to the assembled configuration (paper section 5.4).

Projective dynamics (Bouaziz et al. 2014) on the shared local-global solver
(:mod:`drawstring.geometry.solve.solver`).  Every time step minimizes

    sum_i m_i / h^2 |x_i - y_i|^2  +  sum_groups w ||A X - P(X)||^2,   y = x + h v + h^2 g,

with the inertia term written as closeness to moving targets ``y`` (one constant matrix, so the
factor is reused), and these groups, each with its own module-level class below:

* ``rigid`` -- :class:`RigidShape`: each tile's eight vertices projected onto the closest rigid
  copy of the fabricated (flat) tile (batched Kabsch);
* ``hinge`` -- paired hinge vertices coincide (the linkage's joints);
* ``contact`` -- :class:`FaceContact`: the side faces of grid neighbours (which touch in the
  assembled state) do not pass through each other; half-space rows along an axis frozen once
  per step, so the matrix is constant and a step costs no collision search;
* ``split_contact`` -- the same for the faces that touch across a split line
  (:func:`split_contact_pairs`); such a pair engages (for good) once its faces come within half
  a tile side, since far apart in the flat layout a half-space between them means nothing;
* ``magnet`` -- the magnets across splits: an engaged split pair is reeled in corner by corner
  (``magnet_rate`` tile sides per step) until its faces touch;
* ``snap`` -- the string: for consecutive tiles on the route, the paired side faces are reeled
  in.  Faces that touch in the assembled state are pulled together corner by corner; where the
  string crosses a gap between faces that do not meet, the midpoints are reeled in to their
  assembled distance;
* ``lift`` -- the string's exits: the top corners around every lift gap are pulled up to their
  assembled height (the assembled tiles placed on the table under the flat layout);
* ``stick`` -- static friction in the settle: once the string is reeled in, a hinged neighbour
  pair whose contact faces lie face on face (every corner within ``stick_rel``, 3 % of a tile
  side, of its assembled partner corner; :func:`face_on_face`) sticks: its corners are held
  together from then on, as in the assembled state.  Faces pressed together by the taut
  string neither slide nor separate under static friction.  Without this the unilateral
  contacts alone fix the interior: after the boundary loop closes, the linkage is isostatic
  but its softest flex is nearly free (smallest nonzero singular value of the rigidity matrix
  ~6e-6 relative), and the settle of a 40 x 40 linkage crept for hundreds of steps.  Pairs
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
from drawstring.geometry.core.rigid import rigid_copies
from drawstring.geometry.core.tolerances import SIM_STALL_PROGRESS
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.groups import (
    FaceContact,
    FaceSnap,
    Inertia,
    MovingTargets,
    PointCoincidence,
    RigidShape,
)
from drawstring.geometry.simulate.inputs import (
    RouteLike,
    apply_transform,
    contact_face_pairs,
    lift_targets_for_gaps,
    place_on_table,
    route_snap_pairs,
    route_steps,
    split_contact_pairs,
)
from drawstring.geometry.simulate.result import (
    THOROUGH_SETTINGS,
    SimulationResult,
    SimulationSettings,
    SimulationTolerances,
)
from drawstring.geometry.simulate.tiles import (
    face_on_face,
    face_partners,
    kabsch_deviation,
    max_penetration,
    mean_tile_side,
    neighbour_tile_pairs,
    snap_goal_length,
    tile_edge_lengths,
    tile_volumes,
)
from drawstring.geometry.solve.solver import (
    ConstraintGroup,
    LocalGlobalSolver,
)
from drawstring.geometry.tiling.linkage import Linkage

logger = logging.getLogger(__name__)


__all__ = [
    "GRAVITY_MM_S2",
    "deploy_check_from_simulation",
    "simulate_deployment",
    "simulate_stage",
]

GRAVITY_MM_S2 = (0.0, 0.0, -9810.0)

#: Snap radius of a row that exerts no pull (a magnet pair that has not engaged yet), mm.
_FREE = 1e30


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
    side = mean_tile_side(goal)
    if thickness is not None:
        top_level = flat[:, :4, 2].mean() - flat[..., 2].min()
        if abs(top_level - thickness) > 0.05 * thickness:
            # a sanity check of the caller's pose; on a strongly non-conical quad mesh the
            # tiles' own thicknesses (design.json thickness_min/max_mm) spread this far
            logger.info(
                "flat tiles' tops are %.3f mm above the table, thickness is %.3f mm",
                top_level,
                thickness,
            )

    n_tiles = flat.shape[0]
    n = n_tiles * 8
    x = flat.reshape(-1, 3).copy()
    rest = tile_edge_lengths(flat)  # (T, 18): the fabricated pieces

    # Tile masses from volume (mean 1): a tetrahedral decomposition of the hexahedron.
    masses = np.repeat(tile_volumes(flat), 8)
    masses = masses / masses.mean() if masses.mean() > 0 else np.ones(n)

    h = cfg.time_step_s
    w_in = 1.0 / h**2
    inertia = Inertia(masses, w_in)
    base = {"rigid": cfg.rigid}
    rigid_shape = RigidShape(flat, cfg.rigid * w_in)
    groups: list[ConstraintGroup] = [inertia, rigid_shape]
    hinge: PointCoincidence | None = None
    if len(hinges):
        hinge = PointCoincidence(hinges, cfg.hinge * w_in)
        groups.append(hinge)
        base["hinge"] = cfg.hinge
        hinge_gap0 = np.linalg.norm(x[hinges[:, 1]] - x[hinges[:, 0]], axis=1) / np.sqrt(2.0)
    contact_groups: list[FaceContact] = []
    split_contact: FaceContact | None = None
    magnet: FaceSnap | None = None
    faces = contact_face_pairs(linkage)
    contact_pairs = neighbour_tile_pairs(linkage)
    if len(faces) and cfg.contact > 0:
        contact = FaceContact(faces, cfg.contact * w_in)
        groups.append(contact)
        contact_groups.append(contact)
        base["contact"] = cfg.contact
    split_faces = split_contact_pairs(linkage)
    if len(split_faces) and cfg.contact > 0 and cfg.split_contact:
        split_contact = FaceContact(
            split_faces, cfg.contact * w_in, name="split_contact", engage_distance=0.5 * side
        )
        groups.append(split_contact)
        base["split_contact"] = cfg.contact
        contact_groups.append(split_contact)
        if cfg.magnets > 0:
            # The magnets across the split: once a pair engaged, its faces are pulled together
            # corner by corner (rows of a snap pair with radius 0; free before).
            magnet = FaceSnap(
                split_faces,
                cfg.magnets * w_in,
                mode="face",
                partner=face_partners(goal, split_faces),
                name="magnet",
            )
            groups.append(magnet)
            base["magnet"] = cfg.magnets
            magnet_rows = magnet.matrix(n)
            magnet.radius = np.full(len(magnet.row_pair), _FREE)
            magnet_start = np.linalg.norm(magnet_rows @ x, axis=1)
    # Static friction (the settle only): contact faces pressed together stick.  The ``stick``
    # group holds the pairs that have stuck (rebuilt, one factorization, when more stick).
    use_stick = bool(len(faces)) and cfg.stick > 0
    face_partner = face_partners(goal, faces)
    stuck = np.zeros(len(faces), dtype=bool)
    level = 1.0
    snap: FaceSnap | None = None
    if len(pairs):
        partner = face_partners(goal, pairs)
        touching = snap_goal_length(goal, pairs) <= tol.gap_closed_rel * side
        snap = FaceSnap(pairs, cfg.snap * w_in, mode=cfg.snap_mode, partner=partner, face=touching)
        groups.append(snap)
        base["snap"] = cfg.snap
    lift: MovingTargets | None = None
    placement = place_on_table(goal, flat)
    if len(lift_v):
        lift = MovingTargets(lift_v, cfg.lift * w_in, height_only=cfg.lift_height_only)
        groups.append(lift)
        base["lift"] = cfg.lift
        lift_goal = apply_transform(placement, lift_t)
        lift_start = x[lift_v].copy()
    table = float(flat[..., 2].min())
    solver = LocalGlobalSolver(n, groups, lean=True)
    rest_centred = flat - flat.mean(axis=1, keepdims=True)

    goal_len = snap_goal_length(goal, pairs)
    goal_pen = max_penetration(goal, contact_pairs)

    def snap_distances(pos: FloatArray) -> FloatArray:
        """How far every pair is from its assembled midpoint distance, mm."""
        if not len(pairs):
            return np.zeros(0)
        return np.asarray(np.abs(snap_goal_length(pos.reshape(n_tiles, 8, 3), pairs) - goal_len))

    def failures(pos: FloatArray) -> tuple[list[str], FloatArray, FloatArray, float]:
        """Unmet success criteria at ``pos``, with the gap distances, deviations, penetration."""
        tiles = pos.reshape(n_tiles, 8, 3)
        dist = snap_distances(pos)
        dev = kabsch_deviation(tiles, goal)
        pen = max_penetration(tiles, contact_pairs)
        reasons = []
        n_open = int(np.count_nonzero(dist > tol.gap_closed_rel * side))
        if n_open:
            reasons.append(f"{n_open} route pairs open (> {tol.gap_closed_rel * side:.3g} mm)")
        if dev.max() > tol.deviation_rel * side:
            reasons.append(f"deviation {dev.max():.3g} mm > {tol.deviation_rel * side:.3g} mm")
        if pen > tol.penetration_rel * side:
            note = (
                f" (the assembled tiles themselves overlap by {goal_pen:.3g} mm)"
                if goal_pen > tol.penetration_rel * side
                else ""
            )
            reasons.append(f"penetration {pen:.3g} mm > {tol.penetration_rel * side:.3g} mm{note}")
        return reasons, dist, dev, pen

    d0 = d_end = np.zeros(0)
    if snap is not None:
        snap_rows = snap.matrix(n)
        d0 = np.linalg.norm(snap_rows @ x, axis=1)
        d_end = np.linalg.norm(snap_rows @ goal.reshape(-1, 3), axis=1)
    g_vec = np.asarray(gravity, dtype=np.float64)
    v = np.zeros_like(x)
    frames = [x.reshape(n_tiles, 8, 3).astype(np.float32)]
    max_edge_err = 0.0
    iterations = factorizations = 0
    settle = tol.settle_rel * side
    lock_at = {
        cfg.ramp_steps + cfg.lock_every * (i + 1): level for i, level in enumerate(cfg.lock_levels)
    }
    check_from = max(lock_at, default=cfg.ramp_steps)
    quiet = 0
    progress: list[float] = []
    step = 0
    verdict: tuple[list[str], FloatArray, FloatArray, float] | None = None
    for step in range(1, cfg.max_steps + 1):
        ramp = min(1.0, step / cfg.ramp_steps)
        smooth = ramp * ramp * (3.0 - 2.0 * ramp)
        if snap is not None:
            snap.radius = d0 + smooth * (d_end - d0)
        if hinge is not None:
            hinge.radius = hinge_gap0 * max(0.0, 1.0 - step / cfg.hinge_close_steps)
        if lift is not None:
            lift.targets = lift_start + smooth * (lift_goal - lift_start)
        if step in lock_at:
            level = lock_at[step]
            for name, weight in base.items():
                if weight > 0:
                    solver.set_weight(name, weight * lock_at[step] * w_in)
        for group in contact_groups:
            group.set_axes(x)
        if magnet is not None and split_contact is not None:
            # An engaged magnet reels its pair in no faster than the string (the same ramp from
            # the flat length) and, engaging late, from the length it had then by ``magnet_rate``
            # tile sides per step instead of snapping it shut in one step.
            length = np.linalg.norm(magnet_rows @ x, axis=1)
            engaged = split_contact.active[magnet.row_pair]
            reeled = np.maximum(np.minimum(magnet.radius, length) - cfg.magnet_rate * side, 0.0)
            magnet.radius = np.where(
                engaged, np.maximum(reeled, (1.0 - smooth) * magnet_start), _FREE
            )
        if use_stick and step > cfg.ramp_steps:
            tiles_now = x.reshape(n_tiles, 8, 3)
            newly = ~stuck & face_on_face(tiles_now, faces, face_partner, cfg.stick_rel * side)
            if newly.any():
                stuck |= newly
                stick = FaceSnap(
                    faces[stuck],
                    cfg.stick * level * w_in,
                    mode="face",
                    partner=face_partner[stuck],
                    name="stick",
                )
                if "stick" in base:
                    solver.replace_group(stick)
                else:
                    solver.add_group(stick)
                    base["stick"] = cfg.stick
        on_table = cfg.table and step <= cfg.ramp_steps
        # After the reel-in the string holds the structure: the settle is quasi-static, without
        # the table (which pins a corner the lift heights may not agree with) and gravity.
        y = x + h * v + (h * h * g_vec if on_table or not cfg.table else 0.0)
        inertia.set_targets(y)
        n_iter = cfg.iterations if step <= cfg.ramp_steps else cfg.settle_iterations
        res = solver.solve(y, max_iter=n_iter, anderson=cfg.anderson, rel_tol=1e-12)
        iterations += res.iterations
        factorizations += res.factorizations
        x_new = res.X
        if cfg.rigid_projection:
            x_new = rigid_shape.rigid_copies(x_new)
        if on_table:
            x_new = _table_contact(x_new, table, rest_centred, cfg.rigid_projection)
        move = float(np.linalg.norm(x_new - x, axis=1).max())
        v = (1.0 - cfg.damping) * (x_new - x) / h
        x = x_new
        err = float(np.abs(tile_edge_lengths(x.reshape(n_tiles, 8, 3)) - rest).max())
        max_edge_err = max(max_edge_err, err)
        if step % frame_every == 0:
            frames.append(x.reshape(n_tiles, 8, 3).astype(np.float32))
        quiet = quiet + 1 if move < settle else 0
        if step >= check_from and (step - check_from) % cfg.check_every == 0:
            verdict = failures(x)
            logger.debug("step %d: %s", step, "; ".join(verdict[0]) or "deployed")
            if not verdict[0]:
                break
            if (
                goal_pen > tol.penetration_rel * side
                and len(verdict[0]) == 1
                and verdict[3] <= goal_pen + tol.penetration_rel * side
            ):
                break  # at the assembled shape, which overlaps itself: nothing left to gain
            progress.append(float(verdict[2].max()))
            if len(progress) > cfg.stall_checks and min(progress[-cfg.stall_checks :]) > (
                1.0 - SIM_STALL_PROGRESS
            ) * min(progress[: -cfg.stall_checks]):
                break  # stuck: the deviation stopped shrinking
        verdict = None
        if step >= check_from and quiet >= 5:
            break
    final = x.reshape(n_tiles, 8, 3)
    if step % frame_every != 0:
        frames.append(final.astype(np.float32))

    reasons, dist, dev, pen = verdict if verdict is not None else failures(x)
    open_mask = dist > tol.gap_closed_rel * side
    open_gaps = tuple(sorted({int(g) for g in gaps_of_pairs[open_mask]}))
    if max_edge_err > tol.edge_length_rel * side:
        reasons.append(f"edge error {max_edge_err:.3g} mm > {tol.edge_length_rel * side:.3g} mm")
    if len(pairs) == 0 and len(lift_v) == 0:
        reasons.append("no string: nothing pulls")
    elapsed = time.perf_counter() - start
    result = SimulationResult(
        deployed=not reasons,
        steps=step,
        final_max_deviation_mm=float(dev.max()),
        max_penetration_mm=pen,
        time_s=elapsed,
        open_gaps=open_gaps,
        frames=np.stack(frames).astype(np.float32),
        max_edge_error_mm=max_edge_err,
        gap_distance_mm=dist,
        per_step_ms=1e3 * elapsed / max(step, 1),
        iterations=iterations,
        factorizations=factorizations,
        tile_deviation_mm=dev,
        reasons=tuple(reasons),
    )
    logger.info(
        "simulation: deployed=%s steps=%d dev=%.3g mm pen=%.3g mm edge=%.3g mm %.2f s %s",
        result.deployed,
        step,
        result.final_max_deviation_mm,
        pen,
        max_edge_err,
        elapsed,
        "; ".join(reasons),
    )
    return result


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


def _lift_above(x: FloatArray, level: float, n_tiles: int) -> FloatArray:
    """Translate every tile that dips below ``level`` straight up until it touches it (rigid).

    Parameters
    ----------
    x : (T * 8, 3) float, mm

    Returns
    -------
    (T * 8, 3) float, mm
    """
    tiles = x.reshape(n_tiles, 8, 3)
    dip = np.maximum(level - tiles[:, :, 2].min(axis=1), 0.0)
    if not np.any(dip):
        return x
    out = tiles.copy()
    out[:, :, 2] += dip[:, None]
    return out.reshape(-1, 3)


def _table_contact(
    x: FloatArray, level: float, rest: FloatArray, rigid: bool, rounds: int = 4
) -> FloatArray:
    """Keep the tiles above the table by alternating projections (position-based contact).

    Vertices below ``level`` are raised to it, then every tile is made rigid again (closest
    rigid copy of its rest shape); a few rounds let a tile that carries the structure pivot on
    its lowest corner instead of being shoved up as a whole (which jams the hinges).

    Parameters
    ----------
    x : (T * 8, 3) float, mm
    level : table height, mm.
    rest : (T, 8, 3) float, centred rest shapes.
    rigid : re-rigidify after each clamp (else one clamp).

    Returns
    -------
    (T * 8, 3) float, mm
    """
    if x[:, 2].min() >= level:
        return x
    out = x.copy()
    for _ in range(rounds if rigid else 1):
        low = out[:, 2] < level
        if not low.any():
            break
        out[low, 2] = level
        if rigid:
            tiles = out.reshape(-1, 8, 3)
            hit = np.flatnonzero(low.reshape(-1, 8).any(axis=1))
            tiles[hit] = rigid_copies(rest[hit], tiles[hit])
    if rigid:
        return _lift_above(out, level, len(rest))  # the last clamp, rigidly
    return out


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
