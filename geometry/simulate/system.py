"""The deployment's constraint system: the groups of one run with their weights and solver, and
what the string and the settle change before every step (:meth:`DeploySystem.actuate`).

The groups and the actuation are described in :mod:`~drawstring.geometry.simulate.deploy`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.simulate.groups import (
    FaceContact,
    FaceSnap,
    Inertia,
    MovingTargets,
    PointCoincidence,
    RigidShape,
)
from drawstring.geometry.simulate.inputs import (
    apply_transform,
    contact_face_pairs,
    place_on_table,
    split_contact_pairs,
)
from drawstring.geometry.simulate.result import SimulationSettings, SimulationTolerances
from drawstring.geometry.simulate.tiles import (
    face_on_face,
    face_partners,
    snap_goal_length,
    tile_edge_lengths,
    tile_volumes,
)
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.solver import LocalGlobalSolver
from drawstring.geometry.tiling.linkage import Linkage

__all__ = ["DeploySystem"]

#: Snap radius of a row that exerts no pull (a magnet pair that has not engaged yet), mm.
_FREE = 1e30


@dataclass
class _Contacts:
    """The contact groups of a run: hinged neighbours' faces, the faces across splits and the
    magnets there (each ``None`` when the run has none)."""

    groups: list[FaceContact]
    split: FaceContact | None
    magnet: FaceSnap | None
    magnet_rows: sp.csr_matrix | None
    magnet_start: FloatArray

    @classmethod
    def of(
        cls,
        linkage: Linkage,
        faces: IntArray,
        goal: FloatArray,
        x: FloatArray,
        side: float,
        cfg: SimulationSettings,
        w_in: float,
        groups: list[ConstraintGroup],
        base: dict[str, float],
    ) -> _Contacts:
        """Build the groups and append them to ``groups`` (their weights to ``base``) in the
        solver's order: contact, split contact, magnet."""
        n = x.shape[0]
        contact_groups: list[FaceContact] = []
        split_contact: FaceContact | None = None
        magnet: FaceSnap | None = None
        magnet_rows: sp.csr_matrix | None = None
        magnet_start = np.zeros(0)
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
                # The magnets across the split: once a pair engaged, its faces are pulled
                # together corner by corner (rows of a snap pair with radius 0; free before).
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
        return cls(contact_groups, split_contact, magnet, magnet_rows, magnet_start)


@dataclass
class DeploySystem:
    """The constraint groups of one simulated deployment, their solver and their actuation.

    Attributes
    ----------
    cfg : the run's settings.
    n_tiles : int
    side : float, mm, mean top-face side of the assembled tiles.
    w_in : float, the inertia weight ``1 / h^2``.
    base : weight of every group in multiples of ``w_in``, by name; every lock level multiplies
        them (a ``stick`` group joins when the first pair sticks).
    lock_at : step -> lock level, after the ramp.
    rest_edges : (T, 18) float, mm, the fabricated tiles' rigid edge lengths.
    rest_centred : (T, 8, 3) float, mm, the fabricated tiles about their centroids.
    table : float, mm, the table's height (the flat pose's lowest level).
    faces, face_partner, stuck : the hinged neighbours' contact faces, each corner's partner
        corner and which pairs stick.
    level : the lock level reached.
    lift_released : the step at which the lift targets were let go (:meth:`release_lift`),
        None while they hold.
    """

    cfg: SimulationSettings
    n_tiles: int
    side: float
    w_in: float
    inertia: Inertia
    rigid_shape: RigidShape
    solver: LocalGlobalSolver
    base: dict[str, float]
    lock_at: dict[int, float]
    rest_edges: FloatArray
    rest_centred: FloatArray
    table: float
    contact_groups: list[FaceContact]
    faces: IntArray
    face_partner: IntArray
    stuck: BoolArray
    use_stick: bool
    hinge: PointCoincidence | None = None
    hinge_gap0: FloatArray = field(default_factory=lambda: np.zeros(0))
    split_contact: FaceContact | None = None
    magnet: FaceSnap | None = None
    magnet_rows: sp.csr_matrix | None = None
    magnet_start: FloatArray = field(default_factory=lambda: np.zeros(0))
    snap: FaceSnap | None = None
    snap_d0: FloatArray = field(default_factory=lambda: np.zeros(0))
    snap_d_end: FloatArray = field(default_factory=lambda: np.zeros(0))
    lift: MovingTargets | None = None
    lift_start: FloatArray = field(default_factory=lambda: np.zeros(0))
    lift_goal: FloatArray = field(default_factory=lambda: np.zeros(0))
    level: float = 1.0
    lift_released: int | None = None

    @classmethod
    def build(
        cls,
        linkage: Linkage,
        flat: FloatArray,
        goal: FloatArray,
        hinges: IntArray,
        pairs: IntArray,
        lift_v: IntArray,
        lift_t: FloatArray,
        side: float,
        cfg: SimulationSettings,
        tol: SimulationTolerances,
    ) -> DeploySystem:
        """The groups of a run from the flat pose ``flat`` towards ``goal`` (the arguments as
        :func:`~drawstring.geometry.simulate.deploy.simulate_deployment` checked them)."""
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
        hinge_gap0 = np.zeros(0)
        if len(hinges):
            hinge = PointCoincidence(hinges, cfg.hinge * w_in)
            groups.append(hinge)
            base["hinge"] = cfg.hinge
            hinge_gap0 = np.linalg.norm(x[hinges[:, 1]] - x[hinges[:, 0]], axis=1) / np.sqrt(2.0)
        faces = contact_face_pairs(linkage)
        contacts = _Contacts.of(linkage, faces, goal, x, side, cfg, w_in, groups, base)
        # Static friction (the settle only): contact faces pressed together stick.  The
        # ``stick`` group holds the pairs that have stuck (rebuilt, one factorization, when more
        # stick).
        use_stick = bool(len(faces)) and cfg.stick > 0
        face_partner = face_partners(goal, faces)
        stuck = np.zeros(len(faces), dtype=bool)
        snap: FaceSnap | None = None
        if len(pairs):
            partner = face_partners(goal, pairs)
            touching = snap_goal_length(goal, pairs) <= tol.gap_closed_rel * side
            snap = FaceSnap(
                pairs, cfg.snap * w_in, mode=cfg.snap_mode, partner=partner, face=touching
            )
            groups.append(snap)
            base["snap"] = cfg.snap
        lift: MovingTargets | None = None
        lift_goal = lift_start = np.zeros(0)
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
        d0 = d_end = np.zeros(0)
        if snap is not None:
            snap_rows = snap.matrix(n)
            d0 = np.linalg.norm(snap_rows @ x, axis=1)
            d_end = np.linalg.norm(snap_rows @ goal.reshape(-1, 3), axis=1)
        lock_at = {
            cfg.ramp_steps + cfg.lock_every * (i + 1): level
            for i, level in enumerate(cfg.lock_levels)
        }
        return cls(
            cfg, n_tiles, side, w_in, inertia, rigid_shape, solver, base, lock_at, rest,
            rest_centred, table, contacts.groups, faces, face_partner, stuck, use_stick,
            hinge=hinge, hinge_gap0=hinge_gap0, split_contact=contacts.split,
            magnet=contacts.magnet, magnet_rows=contacts.magnet_rows,
            magnet_start=contacts.magnet_start, snap=snap, snap_d0=d0, snap_d_end=d_end,
            lift=lift, lift_start=lift_start, lift_goal=lift_goal,
        )  # fmt: skip

    def actuate(self, step: int, x: FloatArray) -> None:
        """What changes before ``step`` is solved at positions ``x : (T * 8, 3)``: the string's
        and the lifts' targets along the ramp, the hinges closing, the lock level, the contact
        axes, the magnets' reel-in, and (in the settle) the pairs that stick."""
        cfg = self.cfg
        ramp = min(1.0, step / cfg.ramp_steps)
        smooth = ramp * ramp * (3.0 - 2.0 * ramp)
        if self.snap is not None:
            self.snap.radius = self.snap_d0 + smooth * (self.snap_d_end - self.snap_d0)
        if self.hinge is not None:
            self.hinge.radius = self.hinge_gap0 * max(0.0, 1.0 - step / cfg.hinge_close_steps)
        if self.lift is not None:
            self.lift.targets = self.lift_start + smooth * (self.lift_goal - self.lift_start)
        if step in self.lock_at:
            self.level = self.lock_at[step]
            for name, weight in self.base.items():
                if weight > 0:
                    self.solver.set_weight(name, weight * self.lock_at[step] * self.w_in)
        for group in self.contact_groups:
            group.set_axes(x)
        if self.magnet is not None and self.split_contact is not None:
            self._reel_magnets(x, smooth)
        if self.use_stick and step > cfg.ramp_steps:
            self._stick(x)

    def locked(self) -> bool:
        """Whether every hinged neighbour pair has stuck (static friction holds each pair's
        faces as assembled)."""
        return self.use_stick and bool(self.stuck.all())

    def release_lift(self, step: int) -> None:
        """Let go of the lift targets from ``step`` on (one refactorization).

        The lift's targets are heights of the assembled shape standing upright on the table.
        A structure pulled up by its exits can hang turned from that pose (the clam shell's
        up axis ends 56 degrees from it); once the string has locked it, those heights no
        longer raise anything but bend the locked structure along its softest flex, which
        costs so little that the settle creeps back only over thousands of steps.  The
        settle has neither table nor gravity, so the locked structure needs nothing holding
        it in place.
        """
        if self.lift is None or self.lift_released is not None:
            return
        self.base["lift"] = 0.0
        self.solver.set_weight("lift", 0.0)
        self.lift_released = step

    def _reel_magnets(self, x: FloatArray, smooth: float) -> None:
        """An engaged magnet reels its pair in no faster than the string (the same ramp from
        the flat length) and, engaging late, from the length it had then by ``magnet_rate``
        tile sides per step instead of snapping it shut in one step."""
        magnet, split_contact = self.magnet, self.split_contact
        assert magnet is not None and split_contact is not None and self.magnet_rows is not None
        length = np.linalg.norm(self.magnet_rows @ x, axis=1)
        engaged = split_contact.active[magnet.row_pair]
        reeled = np.maximum(
            np.minimum(magnet.radius, length) - self.cfg.magnet_rate * self.side, 0.0
        )
        magnet.radius = np.where(
            engaged, np.maximum(reeled, (1.0 - smooth) * self.magnet_start), _FREE
        )

    def _stick(self, x: FloatArray) -> None:
        """Pairs that came face on face stick from now on (the ``stick`` group rebuilt)."""
        cfg = self.cfg
        tiles_now = x.reshape(self.n_tiles, 8, 3)
        newly = ~self.stuck & face_on_face(
            tiles_now, self.faces, self.face_partner, cfg.stick_rel * self.side
        )
        if not newly.any():
            return
        self.stuck |= newly
        stick = FaceSnap(
            self.faces[self.stuck],
            cfg.stick * self.level * self.w_in,
            mode="face",
            partner=self.face_partner[self.stuck],
            name="stick",
        )
        if "stick" in self.base:
            self.solver.replace_group(stick)
        else:
            self.solver.add_group(stick)
            self.base["stick"] = cfg.stick
