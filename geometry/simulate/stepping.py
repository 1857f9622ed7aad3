"""The deployment's time stepping: one step's solve (with the table's contact), the run of steps
until the structure deploys, stalls or settles, and the success criteria measured along the way.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from drawstring.geometry.core.rigid import rigid_copies
from drawstring.geometry.core.tolerances import SIM_STALL_PROGRESS
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.result import SimulationSettings, SimulationTolerances
from drawstring.geometry.simulate.system import DeploySystem
from drawstring.geometry.simulate.tiles import (
    kabsch_deviation,
    max_penetration,
    snap_goal_length,
    tile_edge_lengths,
)

logger = logging.getLogger(__name__)

__all__ = ["StepRun", "SuccessCheck", "run_steps", "table_contact"]

#: Unmet success criteria at a pose, with the route pairs' distances from their assembled
#: lengths (mm), the tiles' deviations (mm) and the largest penetration (mm).
Verdict = tuple[list[str], FloatArray, FloatArray, float]


@dataclass(frozen=True)
class SuccessCheck:
    """The success criteria of a deployment (:class:`SimulationTolerances` times the tile side
    ``side``): every route pair at its assembled distance, every tile at its assembled place
    after one rigid alignment, no penetration beyond the assembled tiles' own."""

    goal: FloatArray
    pairs: IntArray
    contact_pairs: IntArray
    side: float
    tol: SimulationTolerances
    goal_len: FloatArray
    goal_pen: float

    @classmethod
    def of(
        cls,
        goal: FloatArray,
        pairs: IntArray,
        contact_pairs: IntArray,
        side: float,
        tol: SimulationTolerances,
    ) -> SuccessCheck:
        goal_len = snap_goal_length(goal, pairs)
        goal_pen = max_penetration(goal, contact_pairs)
        return cls(goal, pairs, contact_pairs, side, tol, goal_len, goal_pen)

    def snap_distances(self, pos: FloatArray) -> FloatArray:
        """How far every pair is from its assembled midpoint distance, mm."""
        if not len(self.pairs):
            return np.zeros(0)
        tiles = pos.reshape(len(self.goal), 8, 3)
        return np.asarray(np.abs(snap_goal_length(tiles, self.pairs) - self.goal_len))

    def failures(self, pos: FloatArray) -> Verdict:
        """Unmet success criteria at ``pos``, with the gap distances, deviations, penetration."""
        tol, side, goal_pen = self.tol, self.side, self.goal_pen
        tiles = pos.reshape(len(self.goal), 8, 3)
        dist = self.snap_distances(pos)
        dev = kabsch_deviation(tiles, self.goal)
        pen = max_penetration(tiles, self.contact_pairs)
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

    def locked_off_shape(self, verdict: Verdict, system: DeploySystem) -> bool:
        """Whether a failed check's ``verdict`` finds the structure locked by the string
        (every route pair closed, every hinged neighbour pair stuck) but off its shape."""
        closed = not np.any(verdict[1] > self.tol.gap_closed_rel * self.side)
        return bool(verdict[0]) and closed and system.locked()

    def stops(self, verdict: Verdict, progress: list[float], cfg: SimulationSettings) -> bool:
        """Whether a check's ``verdict`` ends the run: deployed, at an assembled shape that
        overlaps itself, or stuck (the deviation, appended to ``progress``, stopped
        shrinking)."""
        tol, side, goal_pen = self.tol, self.side, self.goal_pen
        if not verdict[0]:
            return True
        if (
            goal_pen > tol.penetration_rel * side
            and len(verdict[0]) == 1
            and verdict[3] <= goal_pen + tol.penetration_rel * side
        ):
            return True  # at the assembled shape, which overlaps itself: nothing left to gain
        progress.append(float(verdict[2].max()))
        return len(progress) > cfg.stall_checks and min(progress[-cfg.stall_checks :]) > (
            1.0 - SIM_STALL_PROGRESS
        ) * min(progress[: -cfg.stall_checks])  # stuck: the deviation stopped shrinking


@dataclass
class StepRun:
    """The state of a run of steps: positions and velocities ``(T * 8, 3)``, the frames kept,
    the largest rigid-edge error so far, the solver's work, and the last check's verdict when
    the run stopped at a check (else None)."""

    x: FloatArray
    v: FloatArray
    frames: list[FloatArray]
    step: int = 0
    max_edge_err: float = 0.0
    iterations: int = 0
    factorizations: int = 0
    quiet: int = 0
    progress: list[float] = field(default_factory=list)
    verdict: Verdict | None = None


def run_steps(
    system: DeploySystem,
    check: SuccessCheck,
    flat: FloatArray,
    gravity: tuple[float, float, float],
    frame_every: int,
) -> StepRun:
    """Step from the flat pose until the check passes or stops the run, nothing moves for five
    steps after the last lock level, or the step budget is spent."""
    cfg = system.cfg
    x = flat.reshape(-1, 3).copy()
    run = StepRun(x, np.zeros_like(x), [x.reshape(system.n_tiles, 8, 3).astype(np.float32)])
    g_vec = np.asarray(gravity, dtype=np.float64)
    settle = check.tol.settle_rel * system.side
    check_from = max(system.lock_at, default=cfg.ramp_steps)
    for step in range(1, cfg.max_steps + 1):
        run.step = step
        system.actuate(step, run.x)
        move = _advance(system, run, step, g_vec, frame_every)
        run.quiet = run.quiet + 1 if move < settle else 0
        if step >= check_from and (step - check_from) % cfg.check_every == 0:
            run.verdict = check.failures(run.x)
            logger.debug("step %d: %s", step, "; ".join(run.verdict[0]) or "deployed")
            if (
                cfg.release_lift
                and system.lift is not None
                and system.lift_released is None
                and check.locked_off_shape(run.verdict, system)
            ):
                # the settle goes on without the lift: stillness and the deviation's progress
                # are counted afresh from here
                system.release_lift(step)
                run.quiet = 0
                run.progress.clear()
            elif check.stops(run.verdict, run.progress, cfg):
                break
        run.verdict = None
        if step >= check_from and run.quiet >= 5:
            break
    if run.step % frame_every != 0:
        run.frames.append(run.x.reshape(system.n_tiles, 8, 3).astype(np.float32))
    return run


def _advance(
    system: DeploySystem, run: StepRun, step: int, g_vec: FloatArray, frame_every: int
) -> float:
    """Solve one time step (gravity and the table while the string is reeled in; after the
    reel-in the string holds the structure: the settle is quasi-static, without the table,
    which pins a corner the lift heights may not agree with, and gravity), update ``run`` and
    return the largest vertex move, mm."""
    cfg = system.cfg
    h = cfg.time_step_s
    x, v = run.x, run.v
    on_table = cfg.table and step <= cfg.ramp_steps
    y = x + h * v + (h * h * g_vec if on_table or not cfg.table else 0.0)
    system.inertia.set_targets(y)
    n_iter = cfg.iterations if step <= cfg.ramp_steps else cfg.settle_iterations
    res = system.solver.solve(y, max_iter=n_iter, anderson=cfg.anderson, rel_tol=1e-12)
    run.iterations += res.iterations
    run.factorizations += res.factorizations
    x_new = res.X
    if cfg.rigid_projection:
        x_new = system.rigid_shape.rigid_copies(x_new)
    if on_table:
        x_new = table_contact(x_new, system.table, system.rest_centred, cfg.rigid_projection)
    move = float(np.linalg.norm(x_new - x, axis=1).max())
    run.v = (1.0 - cfg.damping) * (x_new - x) / h
    run.x = x_new
    tiles = run.x.reshape(system.n_tiles, 8, 3)
    err = float(np.abs(tile_edge_lengths(tiles) - system.rest_edges).max())
    run.max_edge_err = max(run.max_edge_err, err)
    if step % frame_every == 0:
        run.frames.append(tiles.astype(np.float32))
    return move


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


def table_contact(
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
