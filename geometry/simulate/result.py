"""The deployment simulation's parameters and outcome (:mod:`drawstring.geometry.simulate.deploy`
runs it): the time-stepping settings, the success tolerances, the result record with its
``design.json`` block, and ``deploy.npz``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.core.npz import save_npz
from drawstring.geometry.core.tolerances import (
    SIM_DEVIATION_REL,
    SIM_EDGE_LENGTH_REL,
    SIM_GAP_CLOSED_REL,
    SIM_PENETRATION_REL,
    SIM_STILL_REL,
)
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.simulate.groups import SnapMode

__all__ = [
    "SimulationResult",
    "SimulationSettings",
    "SimulationTolerances",
    "THOROUGH_SETTINGS",
    "save_deploy_npz",
]


@dataclass(frozen=True)
class SimulationTolerances:
    """Success thresholds, relative to the mean top-face side ``s`` of the assembled tiles.

    Attributes
    ----------
    gap_closed_rel : route pair midpoints at most this times ``s`` apart.
    deviation_rel : every tile within this times ``s`` of T3D after rigid alignment.
    penetration_rel : conservative overlap depth at most this times ``s``.
    edge_length_rel : rigid edges within this times ``s`` of their rest length, every frame.
    settle_rel : the run stops (stuck) when no vertex moved more than this times ``s`` in five
        consecutive steps.
    """

    gap_closed_rel: float = SIM_GAP_CLOSED_REL
    deviation_rel: float = SIM_DEVIATION_REL
    penetration_rel: float = SIM_PENETRATION_REL
    edge_length_rel: float = SIM_EDGE_LENGTH_REL
    settle_rel: float = SIM_STILL_REL


@dataclass(frozen=True)
class SimulationSettings:
    """Time stepping and weights (weights are multiples of the inertia weight ``m / h^2``).

    Attributes
    ----------
    time_step_s : h, s.
    max_steps : step budget.
    ramp_steps : steps over which the string is reeled in (snap radius -> 0, lift -> target).
    lock_levels : after the ramp, every ``lock_every`` steps all constraint weights are
        multiplied by the next level (one refactorization each): the string tension rises until
        the structure is locked against gravity, and the step becomes quasi-static.
    lock_every : steps between lock levels.
    check_every : after the last lock level, the success criteria are measured every this many
        steps and the run stops as soon as they all hold.
    stall_checks : the run stops as stuck when the largest tile deviation did not shrink by
        ``SIM_STALL_PROGRESS`` over this many checks (or when nothing moves for five steps).
    iterations : local-global iterations per step (Anderson accelerated) while the string is
        reeled in.
    settle_iterations : local-global iterations per step from the first lock level on (the
        quasi-static settling, where slow global modes need more iterations per step).
    anderson : Anderson history length.
    damping : fraction of the velocity removed every step.
    rigid, hinge, contact, snap, lift : weights / (m / h^2).
    snap_mode : ``"face"`` (the four corner pairs of the contact faces) or ``"midpoint"``.
    lift_height_only : lift targets prescribe only the height (the string pulls up, the
        tiles find their own place sideways); else the whole assembled position on the table.
    hinge_close_steps : hinges that are open in the flat layout close linearly over this many
        steps.
    table : keep every tile above the table (the lowest level of the flat pose) while the string
        is reeled in (position-based: vertices clamped, tiles re-rigidified, a few rounds);
        the settle after the ramp is quasi-static, with neither table nor gravity (the string
        holds the structure; a table there pins a corner that the lift heights may disagree
        with, which jammed corner tiles).
    split_contact : side faces that touch across a split (:func:`split_contact_pairs`) do not
        pass through each other once they came within half a tile side (weight ``contact``).
    magnets : weight of the magnets across splits: once a split contact engaged, its two faces
        are pulled together corner by corner (0: no magnets).
    magnet_rate : how fast an engaged magnet reels its faces in, tile sides per step.
    rigid_projection : after every step each tile is replaced by the closest rigid copy of its
        rest shape, so the rigid edges hold exactly in every frame (not just up to the soft
        rigid weight's residual).
    stick : weight of static friction in the settle: a hinged neighbour pair whose contact
        faces came within ``stick_rel`` tile sides of lying face on face (every corner next to
        its assembled partner corner) sticks -- its corners are held together from then on
        (0: no sticking).
    stick_rel : how close (tile sides, largest corner distance) two contact faces must come
        before they stick.
    release_lift : at a check in the settle that finds the structure locked (every route pair
        closed, every hinged neighbour pair stuck) but not yet at its assembled shape, the lift
        targets are let go: the string holds the locked structure, and heights fixed for the
        assembled shape standing upright on the table only bend a structure that hangs turned
        from its exits.
    """

    time_step_s: float = 0.002
    max_steps: int = 600
    ramp_steps: int = 150
    lock_levels: tuple[float, ...] = (10.0, 100.0, 1000.0)
    lock_every: int = 20
    check_every: int = 10
    stall_checks: int = 10
    iterations: int = 10
    settle_iterations: int = 20
    anderson: int = 5
    damping: float = 0.1
    rigid: float = 3e4
    hinge: float = 3e4
    contact: float = 3e3
    snap: float = 3e3
    lift: float = 3e3
    snap_mode: SnapMode = "face"
    lift_height_only: bool = True
    hinge_close_steps: int = 80
    table: bool = True
    split_contact: bool = True
    magnets: float = 3e3
    magnet_rate: float = 0.1
    rigid_projection: bool = True
    stick: float = 3e4
    stick_rel: float = 0.03
    release_lift: bool = True


#: Slower, better converged settings: twice the local-global iterations per step, one more
#: lock level and a larger step budget (used by :func:`simulate_stage` when the default run
#: gets stuck).
THOROUGH_SETTINGS = SimulationSettings(
    iterations=20, settle_iterations=20, lock_levels=(10.0, 100.0, 1000.0), max_steps=1000
)


@dataclass(frozen=True)
class SimulationResult:
    """Outcome of :func:`simulate_deployment`.

    Attributes
    ----------
    deployed : bool, every success criterion met.
    steps : time steps taken.
    final_max_deviation_mm : max over tiles of the vertex distance to T3D after alignment.
    max_penetration_mm : conservative overlap depth between neighbouring tiles, final state.
    time_s : wall time.
    open_gaps : route gaps whose pair is still open (``-1`` for virtual entrances), sorted.
    frames : (F, T, 8, 3) float32, mm, from the flat pose to the final state.
    max_edge_error_mm : largest rigid-edge length error over all frames.
    gap_distance_mm : (P,) final midpoint distance of every snap pair.
    per_step_ms : mean wall time of one step.
    iterations : local-global iterations over the whole run.
    factorizations : sparse factorizations over the whole run.
    tile_deviation_mm : (T,) final per-tile deviation.
    reasons : why ``deployed`` is False (empty when it is True).
    lift_released_step : the step at which the lift targets were let go
        (:attr:`SimulationSettings.release_lift`), None when they held to the end.
    """

    deployed: bool
    steps: int
    final_max_deviation_mm: float
    max_penetration_mm: float
    time_s: float
    open_gaps: tuple[int, ...]
    frames: NDArray[np.float32]
    max_edge_error_mm: float = 0.0
    gap_distance_mm: FloatArray = field(default_factory=lambda: np.zeros(0))
    per_step_ms: float = 0.0
    iterations: int = 0
    factorizations: int = 0
    tile_deviation_mm: FloatArray = field(default_factory=lambda: np.zeros(0))
    reasons: tuple[str, ...] = ()
    lift_released_step: int | None = None

    def to_json(self) -> dict[str, object]:
        """The ``design.json`` ``simulation`` block."""
        return {
            "deployed": self.deployed,
            "steps": self.steps,
            "final_max_deviation_mm": self.final_max_deviation_mm,
            "max_penetration_mm": self.max_penetration_mm,
            "time_s": self.time_s,
            "open_gaps": list(self.open_gaps),
            "max_edge_error_mm": self.max_edge_error_mm,
            "per_step_ms": self.per_step_ms,
            "reasons": list(self.reasons),
            "worst_tiles": self.worst_tiles(),
            "lift_released_step": self.lift_released_step,
        }

    def worst_tiles(self, count: int = 5) -> list[dict[str, float | int]]:
        """Where the run ended farthest from the assembled shape: the ``count`` tiles with the
        largest deviation (tile id, mm), largest first."""
        dev = np.asarray(self.tile_deviation_mm, dtype=np.float64)
        order = np.argsort(-dev, kind="stable")[:count]
        return [{"tile": int(t), "deviation_mm": float(dev[t])} for t in order]


def save_deploy_npz(result: SimulationResult, path: str | Path) -> Path:
    """Write ``deploy.npz`` (key ``frames``: (F, T, 8, 3) float32, mm) byte-identically
    (:func:`~drawstring.geometry.core.npz.save_npz`).

    Parameters
    ----------
    result : the simulation (only ``frames`` is written).
    path : output file.

    Returns
    -------
    The path written.
    """
    return save_npz(path, {"frames": np.asarray(result.frames, dtype=np.float32)})
