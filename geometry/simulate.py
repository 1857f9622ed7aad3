"""Deployment simulation from the flat to the assembled configuration (paper section 5.4).

Projective dynamics (Bouaziz et al. 2014) on the shared local-global solver
(:mod:`drawstring.geometry.solver`).  Every time step minimizes

    sum_i m_i / h^2 |x_i - y_i|^2  +  sum_groups w ||A X - P(X)||^2,   y = x + h v + h^2 g,

with the inertia term written as closeness to moving targets ``y`` (one constant matrix, so the
factor is reused), and these groups, each with its own module-level class below:

* ``rigid`` -- :class:`~drawstring.geometry.solver.EdgeLength` over 18 edges per tile (4 top,
  4 bottom, 4 side, and one diagonal per face, chosen so that the six diagonals form the
  tetrahedron on vertices 0, 2, 5, 7: the 18-bar framework is then rigid);
* ``hinge`` -- paired hinge vertices coincide (the linkage's joints);
* ``contact`` -- neighbouring tiles (sharing a grid edge or a grid vertex) do not
  interpenetrate: a separating-axis test over the 12 face normals of the two hexahedra, pushing
  both tiles apart along the axis of least overlap.  Ignoring edge-edge axes can only
  over-estimate the overlap, so the test is conservative;
* ``ground`` -- the table: no vertex below the lowest vertex of the flat pose (frictionless);
* ``snap`` -- the string: for consecutive tiles on the route, the midpoints of the leaving side
  face of one tile and the entering side face of the next are pulled together (they coincide
  in the assembled state);
* ``lift`` -- the string's exits: the top corners around every lift gap are pulled towards their
  assembled positions (placed on the table in the flat layout's frame).

String actuation: the string is *reeled in*.  Each snap pair may be at most ``r(t)`` apart and
``r(t)`` shrinks from the pair's initial distance to zero over ``ramp_steps``; lift targets move
from the lift vertices' start positions to their targets over the same ramp.  Targets move
without touching the system matrix.  String tension (the snap and lift weights) then rises in a
few discrete levels (one refactorization each) to lock the structure.

Success is measured on the final state: every route gap closed within tolerance, every tile
within ``deviation`` of the assembled tiles after one rigid (Kabsch) alignment over all
vertices, the conservative penetration depth below tolerance, all within the step budget.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from drawstring.geometry.errors import InputError
from drawstring.geometry.linkage import Linkage, build_linkage, rotating_squares_layout
from drawstring.geometry.solver import (
    ConstraintGroup,
    EdgeLength,
    LocalGlobalSolver,
    difference_matrix,
)
from drawstring.geometry.tolerances import (
    SIM_DEVIATION_REL,
    SIM_EDGE_LENGTH_REL,
    SIM_GAP_CLOSED_REL,
    SIM_PENETRATION_REL,
    SIM_SETTLE_REL,
)

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
SnapMode = Literal["face", "midpoint"]

__all__ = [
    "DeploymentScene",
    "SimulationResult",
    "SimulationSettings",
    "SimulationTolerances",
    "TILE_EDGES",
    "TILE_FACES",
    "boundary_loop_route",
    "cylinder_scene",
    "deploy_check_from_simulation",
    "hinge_vertex_pairs",
    "kabsch_deviation",
    "lift_targets_for_gaps",
    "max_penetration",
    "route_snap_pairs",
    "side_face_midpoints",
    "simulate_deployment",
    "tile_edge_lengths",
]

#: The 18 edges of a rigid tile: top ring, bottom ring, verticals, and one diagonal per face
#: (top 0-2, bottom 5-7, sides 0-5, 2-5, 2-7, 0-7: the tetrahedron 0, 2, 5, 7).
TILE_EDGES: IntArray = np.array(
    [
        [0, 1], [1, 2], [2, 3], [3, 0],
        [4, 5], [5, 6], [6, 7], [7, 4],
        [0, 4], [1, 5], [2, 6], [3, 7],
        [0, 2], [5, 7], [0, 5], [2, 5], [2, 7], [0, 7],
    ],
    dtype=np.int64,
)  # fmt: skip

#: The six faces of a tile: top, bottom, then side faces 0..3 (vertices k, k+1, 4+k+1, 4+k).
TILE_FACES: IntArray = np.array(
    [[0, 1, 2, 3], [4, 7, 6, 5]] + [[k, (k + 1) % 4, 4 + (k + 1) % 4, 4 + k] for k in range(4)],
    dtype=np.int64,
)

#: Side face k of a tile as vertex indices.
SIDE_FACES: IntArray = TILE_FACES[2:]

GRAVITY_MM_S2 = (0.0, 0.0, -9810.0)


# --------------------------------------------------------------------------------------------
# Small geometric helpers
# --------------------------------------------------------------------------------------------


def side_face_midpoints(tiles: FloatArray) -> FloatArray:
    """Midpoints (vertex means) of the four side faces of every tile.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm

    Returns
    -------
    (T, 4, 3) float, mm
    """
    return np.asarray(tiles[:, SIDE_FACES].mean(axis=2))


def tile_edge_lengths(tiles: FloatArray) -> FloatArray:
    """Lengths of the 18 rigid edges of every tile.

    Parameters
    ----------
    tiles : (..., T, 8, 3) float, mm

    Returns
    -------
    (..., T, 18) float, mm
    """
    diff = tiles[..., TILE_EDGES[:, 1], :] - tiles[..., TILE_EDGES[:, 0], :]
    return np.asarray(np.linalg.norm(diff, axis=-1))


def mean_tile_side(tiles: FloatArray) -> float:
    """Mean length of the top-face sides, mm."""
    top = tiles[:, :4]
    return float(np.linalg.norm(np.roll(top, -1, axis=1) - top, axis=2).mean())


def _kabsch(source: FloatArray, target: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rotation ``R`` and shift ``t`` with ``R @ p + t`` closest to ``target`` (no reflection).

    Parameters
    ----------
    source, target : (n, d) float
    """
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    cov = (source - cs).T @ (target - ct)
    u, _, vt = np.linalg.svd(cov)
    d = np.ones(source.shape[1])
    d[-1] = np.sign(np.linalg.det(u @ vt)) or 1.0
    rot = (u * d) @ vt
    return rot.T, ct - rot.T @ cs


def kabsch_deviation(tiles: FloatArray, reference: FloatArray) -> FloatArray:
    """Per-tile maximum vertex distance after one rigid alignment over all vertices.

    Parameters
    ----------
    tiles, reference : (T, 8, 3) float, mm

    Returns
    -------
    (T,) float, mm
        ``max_v |R x_tv + t - ref_tv|`` with ``(R, t)`` the best rigid map of all vertices.
    """
    src = tiles.reshape(-1, 3)
    dst = reference.reshape(-1, 3)
    rot, shift = _kabsch(src, dst)
    moved = src @ rot.T + shift
    return np.asarray(np.linalg.norm(moved - dst, axis=1).reshape(tiles.shape[0], 8).max(axis=1))


def _face_normals(pts: FloatArray) -> FloatArray:
    """Unit normals ``(k, 6, 3)`` of the six faces of hexahedra ``(k, 8, 3)``."""
    d1 = pts[:, TILE_FACES[:, 2]] - pts[:, TILE_FACES[:, 0]]  # (k, 6, 3)
    d2 = pts[:, TILE_FACES[:, 3]] - pts[:, TILE_FACES[:, 1]]
    n = np.empty_like(d1)
    n[..., 0] = d1[..., 1] * d2[..., 2] - d1[..., 2] * d2[..., 1]
    n[..., 1] = d1[..., 2] * d2[..., 0] - d1[..., 0] * d2[..., 2]
    n[..., 2] = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    norm = np.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2 + n[..., 2] ** 2)
    return np.asarray(n / np.maximum(norm, 1e-300)[..., None])


def hexahedron_overlap(pa: FloatArray, pb: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Overlap depth and push axis of hexahedron pairs (separating axes: the 12 face normals).

    Parameters
    ----------
    pa, pb : (k, 8, 3) float, mm
        Convex hexahedra (tiles).

    Returns
    -------
    depth : (k,) float, mm
        Smallest projection overlap over the 12 axes; ``<= 0`` when a face plane separates them.
        Without the edge-edge axes this is an upper bound of the true penetration depth.
    axis : (k, 3) float
        Unit axis of that overlap, pointing from ``pa`` towards ``pb``.
    """
    axes = np.concatenate([_face_normals(pa), _face_normals(pb)], axis=1)  # (k, 12, 3)
    axes_t = axes.transpose(0, 2, 1)
    proj_a = np.matmul(pa, axes_t)  # (k, 8, 12); reduce over the strided vertex axis (fast)
    proj_b = np.matmul(pb, axes_t)
    over_pos = proj_a.max(axis=1) - proj_b.min(axis=1)
    over_neg = proj_b.max(axis=1) - proj_a.min(axis=1)
    use_pos = over_pos <= over_neg
    overlap = np.where(use_pos, over_pos, over_neg)
    best = np.argmin(overlap, axis=1)
    k = np.arange(len(pa))
    sign = np.where(use_pos[k, best], 1.0, -1.0)
    return np.asarray(overlap[k, best]), np.asarray(axes[k, best] * sign[:, None])


def neighbour_tile_pairs(linkage: Linkage) -> IntArray:
    """Tile pairs whose grid cells share an edge or a vertex (candidate contacts).

    Returns
    -------
    (k, 2) int, ``a < b``.
    """
    cells = linkage.tile_cells
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(cells)}
    pairs = []
    for t, (i, j) in enumerate(cells):
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
            other = index.get((int(i) + di, int(j) + dj))
            if other is not None:
                pairs.append((min(t, other), max(t, other)))
    return np.array(sorted(set(pairs)), dtype=np.int64).reshape(-1, 2)


def max_penetration(tiles: FloatArray, pairs: IntArray) -> float:
    """Largest conservative overlap depth (mm) over the given tile pairs (0 when none overlap).

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    pairs : (k, 2) int
    """
    if len(pairs) == 0:
        return 0.0
    depth, _ = hexahedron_overlap(tiles[pairs[:, 0]], tiles[pairs[:, 1]])
    return float(max(depth.max(), 0.0))


# --------------------------------------------------------------------------------------------
# Route, hinges and lift targets as simulation inputs
# --------------------------------------------------------------------------------------------


def route_snap_pairs(
    route: Sequence[tuple[int, int, int, int]] | ArrayLike,
) -> tuple[IntArray, IntArray]:
    """Contact pairs the string pulls together, from a closed route.

    Step ``i`` is ``(gap, tile, enter_side, leave_side)``: the string crosses ``gap`` (``-1``: a
    virtual entrance) to enter ``tile`` through ``enter_side`` and leaves it through
    ``leave_side``.  Consecutive steps ``i, i + 1`` (cyclically) give the pair
    ``(tile_i, leave_side_i, tile_{i+1}, enter_side_{i+1})`` across ``gap_{i+1}``.  Steps that
    stay on the same tile are skipped.

    Returns
    -------
    pairs : (P, 4) int
        ``(tile_a, side_a, tile_b, side_b)``.
    gaps : (P,) int
        Gap crossed by each pair (``-1`` for virtual entrances).
    """
    steps = np.asarray(route, dtype=np.int64).reshape(-1, 4)
    if len(steps) < 2:
        raise InputError("a route needs at least two steps; pass the closed string route")
    nxt = np.roll(steps, -1, axis=0)
    keep = steps[:, 1] != nxt[:, 1]
    pairs = np.stack([steps[:, 1], steps[:, 3], nxt[:, 1], nxt[:, 2]], axis=1)[keep]
    return pairs.astype(np.int64), nxt[keep, 0].astype(np.int64)


def hinge_vertex_pairs(linkage: Linkage, hinge_side: Sequence[str] | None = None) -> IntArray:
    """Vertex ids ``tile * 8 + vertex`` joined by every hinge.

    Parameters
    ----------
    linkage : topology; hinge rows ``(tile_a, corner_a, tile_b, corner_b)``.
    hinge_side : (H,) ``"top"`` | ``"bottom"``; default all ``"top"``.  A top hinge at corner
        ``c`` joins vertex ``c``; a bottom hinge joins vertex ``4 + c``.

    Returns
    -------
    (H, 2) int
    """
    h = linkage.hinges
    sides = ["top"] * len(h) if hinge_side is None else list(hinge_side)
    if len(sides) != len(h) or any(s not in ("top", "bottom") for s in sides):
        raise InputError("hinge_side must list 'top' or 'bottom' for every hinge")
    off = np.array([0 if s == "top" else 4 for s in sides], dtype=np.int64)
    return np.stack([h[:, 0] * 8 + h[:, 1] + off, h[:, 2] * 8 + h[:, 3] + off], axis=1)


def lift_targets_for_gaps(
    linkage: Linkage, tiles_assembled: FloatArray, lift_gaps: ArrayLike
) -> tuple[IntArray, FloatArray]:
    """Lift vertices and targets: the top corners around each lift gap and their T3D positions.

    Parameters
    ----------
    linkage : topology.
    tiles_assembled : (T, 8, 3) float, mm
    lift_gaps : (L,) int, gap ids.

    Returns
    -------
    vertices : (k,) int, ``tile * 8 + corner``.
    targets : (k, 3) float, mm, in the frame of ``tiles_assembled``.
    """
    verts: list[int] = []
    for g in np.asarray(lift_gaps, dtype=np.int64).reshape(-1):
        if not 0 <= g < linkage.n_gaps:
            raise InputError(f"lift gap {g} does not exist; the linkage has {linkage.n_gaps}")
        gv = linkage.gap_vertex[g]
        for t in linkage.gap_tiles(int(g)):
            for c in np.flatnonzero(linkage.tile_corners[t] == gv):
                verts.append(int(t) * 8 + int(c))
    v = np.unique(np.array(verts, dtype=np.int64))
    return v, np.asarray(tiles_assembled.reshape(-1, 3)[v], dtype=np.float64)


def place_on_table(tiles_assembled: FloatArray, tiles_flat: FloatArray) -> FloatArray:
    """Rigid map of the assembled tiles onto the table under the flat layout.

    Rotation about z and translation in xy from a 2D Kabsch fit of the tile centroids (top view),
    then a vertical shift so the lowest vertex sits on the flat layout's lowest level.

    Returns
    -------
    (4, 4) float, homogeneous transform.
    """
    c3 = tiles_assembled.mean(axis=1)
    c2 = tiles_flat.mean(axis=1)
    rot2, t2 = _kabsch(c3[:, :2], c2[:, :2])
    mat = np.eye(4)
    mat[:2, :2] = rot2
    mat[:2, 3] = t2
    z_low = tiles_assembled[..., 2].min()
    mat[2, 3] = tiles_flat[..., 2].min() - z_low
    return mat


def _apply(mat: FloatArray, pts: FloatArray) -> FloatArray:
    return np.asarray(pts @ mat[:3, :3].T + mat[:3, 3])


# --------------------------------------------------------------------------------------------
# Constraint groups of the simulation
# --------------------------------------------------------------------------------------------


class Inertia(ConstraintGroup):
    """Mass-weighted closeness to the inertial targets ``y`` (rows scaled by ``sqrt(m_i)``).

    Energy ``weight * sum_i m_i |x_i - y_i|^2``; set ``weight = 1 / h^2``.

    Parameters
    ----------
    masses : (n,) float, relative vertex masses.
    """

    def __init__(self, masses: ArrayLike, weight: float, name: str = "inertia") -> None:
        super().__init__(name, weight)
        self.sqrt_m = np.sqrt(np.asarray(masses, dtype=np.float64))
        self.targets = np.zeros((len(self.sqrt_m), 3))

    def set_targets(self, targets: FloatArray) -> None:
        self.targets = np.asarray(targets, dtype=np.float64)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        n = len(self.sqrt_m)
        return sp.csr_matrix((self.sqrt_m, (np.arange(n), np.arange(n))), shape=(n, n_vertices))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        return np.asarray(self.sqrt_m[:, None] * self.targets)


class PointCoincidence(ConstraintGroup):
    """Paired vertices coincide (hinges): rows ``(x_b - x_a) / sqrt 2`` projected to zero.

    Parameters
    ----------
    pairs : (k, 2) int
    """

    def __init__(self, pairs: ArrayLike, weight: float, name: str = "hinge") -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return sp.csr_matrix(difference_matrix(self.pairs, n_vertices) / np.sqrt(2.0))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        return np.zeros_like(ax)


class FaceSnap(ConstraintGroup):
    """Route neighbours' side faces pulled within a (shrinking) distance ``radius``.

    ``mode == "midpoint"`` (the paper): row ``p`` is ``mid(face_b) - mid(face_a)``.
    ``mode == "face"``: four rows per pair, each face corner minus its partner corner of the
    other face (``partner``), i.e. whole-face contact.  The projection shortens every row to at
    most ``radius`` (the string still to be reeled in), zero at the end of the ramp.

    Parameters
    ----------
    pairs : (P, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    partner : (P, 4) int, for ``"face"``: index into face b's corners of the partner of face
        a's corner ``c``.
    """

    def __init__(
        self,
        pairs: ArrayLike,
        weight: float,
        mode: SnapMode = "midpoint",
        partner: IntArray | None = None,
        name: str = "snap",
    ) -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
        self.mode = mode
        self.partner = partner
        per = 1 if mode == "midpoint" else 4
        self.radius = np.zeros(len(self.pairs) * per)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        p = self.pairs
        k = len(p)
        va = p[:, 0, None] * 8 + SIDE_FACES[p[:, 1]]  # (k, 4)
        vb = p[:, 2, None] * 8 + SIDE_FACES[p[:, 3]]
        if self.mode == "midpoint":
            rows = np.repeat(np.arange(k), 8)
            cols = np.concatenate([va, vb], axis=1).reshape(-1)
            vals = np.tile(np.r_[-0.25 * np.ones(4), 0.25 * np.ones(4)], k)
            return sp.csr_matrix((vals, (rows, cols)), shape=(k, n_vertices))
        assert self.partner is not None
        vb_match = np.take_along_axis(vb, self.partner, axis=1)
        edges = np.stack([va.reshape(-1), vb_match.reshape(-1)], axis=1)
        return difference_matrix(edges, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        norm = np.linalg.norm(ax, axis=1)
        scale = np.minimum(1.0, self.radius / np.maximum(norm, 1e-300))
        return np.asarray(ax * scale[:, None])


class MovingTargets(ConstraintGroup):
    """Vertices pulled to targets that may move every step (lift actuation).

    Parameters
    ----------
    indices : (k,) int
    """

    def __init__(self, indices: ArrayLike, weight: float, name: str = "lift") -> None:
        super().__init__(name, weight)
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.targets = np.zeros((len(self.indices), 3))

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        k = len(self.indices)
        return sp.csr_matrix((np.ones(k), (np.arange(k), self.indices)), shape=(k, n_vertices))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        return self.targets


class Ground(ConstraintGroup):
    """Frictionless table: every vertex keeps ``z >= level``.

    Parameters
    ----------
    n : number of vertices.
    level : float, mm
    """

    def __init__(self, n: int, level: float, weight: float, name: str = "ground") -> None:
        super().__init__(name, weight)
        self.n = int(n)
        self.level = float(level)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return sp.identity(n_vertices, format="csr")

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        out = ax.copy()
        np.maximum(out[:, 2], self.level, out=out[:, 2])
        return out


class TileContact(ConstraintGroup):
    """Neighbouring tiles do not interpenetrate (conservative separating-axis projection).

    ``A`` gives the 16 vertices of a pair minus the pair's centroid; where the tiles overlap
    (see :func:`hexahedron_overlap`) tile ``a`` moves by ``-depth / 2`` and tile ``b`` by
    ``+depth / 2`` along the axis of least overlap; elsewhere the current value is returned.

    Parameters
    ----------
    pairs : (k, 2) int, tile pairs.
    """

    def __init__(self, pairs: ArrayLike, weight: float, name: str = "contact") -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        p = self.pairs
        elements = np.concatenate(
            [p[:, :1] * 8 + np.arange(8), p[:, 1:] * 8 + np.arange(8)], axis=1
        )
        k, s = elements.shape
        rows = np.repeat(np.arange(k * s), s)
        cols = np.repeat(elements, s, axis=0).reshape(-1)
        vals = np.tile((np.eye(s) - 1.0 / s).reshape(-1), k)
        return sp.csr_matrix((vals, (rows, cols)), shape=(k * s, n_vertices))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        pts = ax.reshape(-1, 16, 3)
        depth, axis = hexahedron_overlap(pts[:, :8], pts[:, 8:])
        hit = depth > 0
        if not np.any(hit):
            return ax
        out = pts.copy()
        shift = 0.5 * depth[hit, None] * axis[hit]
        out[hit, :8] -= shift[:, None, :]
        out[hit, 8:] += shift[:, None, :]
        return out.reshape(ax.shape)


# --------------------------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SimulationTolerances:
    """Success thresholds, relative to the mean top-face side ``s`` of the assembled tiles.

    Attributes
    ----------
    gap_closed_rel : route pair midpoints at most this times ``s`` apart.
    deviation_rel : every tile within this times ``s`` of T3D after rigid alignment.
    penetration_rel : conservative overlap depth at most this times ``s``.
    edge_length_rel : rigid edges within this times ``s`` of their rest length, every frame.
    settle_rel : the run may stop when no vertex moved more than this times ``s`` in a step.
    """

    gap_closed_rel: float = SIM_GAP_CLOSED_REL
    deviation_rel: float = SIM_DEVIATION_REL
    penetration_rel: float = SIM_PENETRATION_REL
    edge_length_rel: float = SIM_EDGE_LENGTH_REL
    settle_rel: float = SIM_SETTLE_REL


@dataclass(frozen=True)
class SimulationSettings:
    """Time stepping and weights (weights are multiples of the inertia weight ``m / h^2``).

    Attributes
    ----------
    time_step_s : h, s.
    max_steps : step budget.
    ramp_steps : steps over which the string is reeled in (snap radius -> 0, lift -> target).
    lock_levels : multipliers of the snap and lift weights applied after the ramp, one
        refactorization each (the tension rising to lock the structure).
    iterations : local-global iterations per step (Anderson accelerated).
    anderson : Anderson history length.
    damping : fraction of the velocity removed every step.
    rigid, hinge, contact, ground, snap, lift : weights / (m / h^2).
    """

    time_step_s: float = 0.002
    max_steps: int = 400
    ramp_steps: int = 150
    lock_levels: tuple[float, ...] = (3.0, 10.0)
    iterations: int = 12
    anderson: int = 5
    damping: float = 0.1
    rigid: float = 1e4
    hinge: float = 1e4
    contact: float = 1e2
    ground: float = 0.0
    post_contact: int = 0
    snap_mode: SnapMode = "face"
    table: bool = True
    snap: float = 1e2
    lift: float = 1e2


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
        }


def _check_inputs(
    tiles_flat: FloatArray, tiles_assembled: FloatArray, hinge_vertices: IntArray
) -> None:
    if tiles_flat.ndim != 3 or tiles_flat.shape[1:] != (8, 3):
        raise InputError(f"flat tiles must be (T, 8, 3), got {tiles_flat.shape}")
    if tiles_assembled.shape != tiles_flat.shape:
        raise InputError(
            f"assembled tiles {tiles_assembled.shape} and flat tiles {tiles_flat.shape} differ; "
            "pass the same tiles in both poses"
        )
    if not (np.all(np.isfinite(tiles_flat)) and np.all(np.isfinite(tiles_assembled))):
        raise InputError("tile vertices must be finite")
    n = tiles_flat.shape[0] * 8
    if hinge_vertices.size and (hinge_vertices.min() < 0 or hinge_vertices.max() >= n):
        raise InputError("hinge vertex ids must be tile * 8 + vertex within the tile count")


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
        raise InputError(f"{flat.shape[0]} tiles given for a linkage of {linkage.n_tiles}")
    if frame_every < 1 or cfg.max_steps < 1 or cfg.ramp_steps < 1:
        raise InputError("frame_every, max_steps and ramp_steps must be >= 1")
    pairs = np.asarray(snap_pairs, dtype=np.int64).reshape(-1, 4)
    gaps_of_pairs = (
        np.arange(len(pairs)) if snap_gaps is None else np.asarray(snap_gaps, dtype=np.int64)
    )
    lift_v = np.asarray(lift_vertices, dtype=np.int64).reshape(-1)
    lift_t = np.asarray(lift_targets, dtype=np.float64).reshape(-1, 3)
    if len(lift_v) != len(lift_t):
        raise InputError("give one lift target per lift vertex")
    side = mean_tile_side(goal)
    if thickness is not None:
        top_level = flat[:, :4, 2].mean() - flat[..., 2].min()
        if abs(top_level - thickness) > 0.05 * thickness:
            logger.warning(
                "flat tiles' tops are %.3f mm above the table, thickness is %.3f mm",
                top_level,
                thickness,
            )

    n_tiles = flat.shape[0]
    n = n_tiles * 8
    x = flat.reshape(-1, 3).copy()
    rest = tile_edge_lengths(flat)  # (T, 18): the fabricated pieces
    edges = (np.arange(n_tiles)[:, None, None] * 8 + TILE_EDGES[None]).reshape(-1, 2)

    # Tile masses from volume (mean 1): a tetrahedral decomposition of the hexahedron.
    masses = np.repeat(_tile_volumes(flat), 8)
    masses = masses / masses.mean() if masses.mean() > 0 else np.ones(n)

    h = cfg.time_step_s
    w_in = 1.0 / h**2
    contact_pairs = neighbour_tile_pairs(linkage)
    inertia = Inertia(masses, w_in)
    groups: list[ConstraintGroup] = [
        inertia,
        EdgeLength(edges, rest.reshape(-1), weight=cfg.rigid * w_in, name="rigid"),
    ]
    table = float(flat[..., 2].min())
    if cfg.ground > 0:
        groups.append(Ground(n, table, cfg.ground * w_in))
    if len(hinges):
        groups.append(PointCoincidence(hinges, cfg.hinge * w_in))
    if len(contact_pairs) and cfg.contact > 0:
        groups.append(TileContact(contact_pairs, cfg.contact * w_in))
    snap: FaceSnap | None = None
    if len(pairs):
        partner = _face_partners(goal, pairs) if cfg.snap_mode == "face" else None
        snap = FaceSnap(pairs, cfg.snap * w_in, mode=cfg.snap_mode, partner=partner)
        groups.append(snap)
    lift: MovingTargets | None = None
    placement = place_on_table(goal, flat)
    if len(lift_v):
        lift = MovingTargets(lift_v, cfg.lift * w_in)
        groups.append(lift)
        lift_goal = _apply(placement, lift_t)
        lift_start = x[lift_v].copy()
    solver = LocalGlobalSolver(n, groups)

    def snap_distances(pos: FloatArray) -> FloatArray:
        mids = side_face_midpoints(pos.reshape(n_tiles, 8, 3))
        return np.asarray(
            np.linalg.norm(mids[pairs[:, 2], pairs[:, 3]] - mids[pairs[:, 0], pairs[:, 1]], axis=1)
        )

    d0 = np.zeros(0)
    if snap is not None:
        ax0 = solver._matrices["snap"] @ x
        d0 = np.linalg.norm(ax0, axis=1)
    g_vec = np.asarray(gravity, dtype=np.float64)
    v = np.zeros_like(x)
    frames = [x.reshape(n_tiles, 8, 3).astype(np.float32)]
    max_edge_err = 0.0
    iterations = factorizations = 0
    settle = tol.settle_rel * side
    lock_at = [cfg.ramp_steps + 10 * (i + 1) for i in range(len(cfg.lock_levels))]
    quiet = 0
    step = 0
    for step in range(1, cfg.max_steps + 1):
        ramp = min(1.0, step / cfg.ramp_steps)
        smooth = ramp * ramp * (3.0 - 2.0 * ramp)
        if snap is not None:
            snap.radius = d0 * (1.0 - smooth)
        if lift is not None:
            lift.targets = lift_start + smooth * (lift_goal - lift_start)
        for level, at in zip(cfg.lock_levels, lock_at, strict=True):
            if step == at:
                if snap is not None:
                    solver.set_weight("snap", cfg.snap * level * w_in)
                if lift is not None:
                    solver.set_weight("lift", cfg.lift * level * w_in)
                if cfg.contact > 0 and len(contact_pairs):
                    solver.set_weight("contact", cfg.contact * level * w_in)
        y = x + h * v + h * h * g_vec
        if cfg.table:
            y = _lift_above(y, table, n_tiles)  # the table holds the inertial targets
        inertia.set_targets(y)
        res = solver.solve(y, max_iter=cfg.iterations, anderson=cfg.anderson, rel_tol=1e-12)
        iterations += res.iterations
        factorizations += res.factorizations
        x_new = res.X
        if cfg.post_contact and len(contact_pairs):
            x_new = _separate(x_new.reshape(n_tiles, 8, 3), contact_pairs, cfg.post_contact)
            x_new = x_new.reshape(-1, 3)
        if cfg.table:
            x_new = _lift_above(x_new, table, n_tiles)
        move = float(np.linalg.norm(x_new - x, axis=1).max())
        v = (1.0 - cfg.damping) * (x_new - x) / h
        x = x_new
        err = float(np.abs(tile_edge_lengths(x.reshape(n_tiles, 8, 3)) - rest).max())
        max_edge_err = max(max_edge_err, err)
        if step % frame_every == 0:
            frames.append(x.reshape(n_tiles, 8, 3).astype(np.float32))
        if logger.isEnabledFor(logging.DEBUG) and step % 20 == 0 and len(pairs):
            logger.debug(
                "step %d: move %.3g gap %.3g edge %.3g energies %s",
                step,
                move,
                snap_distances(x).max(),
                err,
                {k: f"{v:.2e}" for k, v in res.energy_after.items()},
            )
        locked = step >= (lock_at[-1] if lock_at else cfg.ramp_steps)
        quiet = quiet + 1 if move < settle else 0
        if locked and quiet >= 5:
            break
    final = x.reshape(n_tiles, 8, 3)
    if step % frame_every != 0:
        frames.append(final.astype(np.float32))

    dev = kabsch_deviation(final, goal)
    pen = max_penetration(final, contact_pairs)
    dist = snap_distances(x) if len(pairs) else np.zeros(0)
    open_mask = dist > tol.gap_closed_rel * side
    open_gaps = tuple(sorted({int(g) for g in gaps_of_pairs[open_mask]}))
    reasons = []
    if open_mask.any():
        reasons.append(
            f"{int(open_mask.sum())} route pairs open (> {tol.gap_closed_rel * side:.3g} mm)"
        )
    if dev.max() > tol.deviation_rel * side:
        reasons.append(f"deviation {dev.max():.3g} mm > {tol.deviation_rel * side:.3g} mm")
    if pen > tol.penetration_rel * side:
        reasons.append(f"penetration {pen:.3g} mm > {tol.penetration_rel * side:.3g} mm")
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


def _face_partners(goal: FloatArray, pairs: IntArray) -> IntArray:
    """For each snap pair, the corner of face b nearest (in T3D) to each corner of face a.

    Returns
    -------
    (P, 4) int, indices into ``SIDE_FACES[side_b]``.
    """
    fa = goal[pairs[:, 0, None], SIDE_FACES[pairs[:, 1]]]  # (P, 4, 3)
    fb = goal[pairs[:, 2, None], SIDE_FACES[pairs[:, 3]]]
    dist = np.linalg.norm(fa[:, :, None] - fb[:, None, :], axis=3)
    return np.asarray(np.argmin(dist, axis=2), dtype=np.int64)


def _separate(tiles: FloatArray, pairs: IntArray, rounds: int) -> FloatArray:
    """Push overlapping neighbour tiles apart rigidly (translations, Jacobi rounds).

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm
    pairs : (k, 2) int
    rounds : int

    Returns
    -------
    (T, 8, 3) float, mm
    """
    out = tiles.copy()
    n_tiles = len(tiles)
    for _ in range(rounds):
        depth, axis = hexahedron_overlap(out[pairs[:, 0]], out[pairs[:, 1]])
        hit = depth > 0
        if not np.any(hit):
            break
        shift = 0.5 * depth[hit, None] * axis[hit]
        move = np.zeros((n_tiles, 3))
        count = np.zeros(n_tiles)
        np.add.at(move, pairs[hit, 0], -shift)
        np.add.at(move, pairs[hit, 1], shift)
        np.add.at(count, pairs[hit, 0], 1.0)
        np.add.at(count, pairs[hit, 1], 1.0)
        out += (move / np.maximum(count, 1.0)[:, None])[:, None, :]
    return out


def _tile_volumes(tiles: FloatArray) -> FloatArray:
    """Volumes ``(T,)`` of the hexahedral tiles (six tetrahedra around the 0-6 diagonal), mm^3."""
    tets = np.array(
        [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    )
    p = tiles[:, tets]  # (T, 6, 4, 3)
    vol = np.einsum(
        "tki,tki->tk",
        p[:, :, 1] - p[:, :, 0],
        np.cross(p[:, :, 2] - p[:, :, 0], p[:, :, 3] - p[:, :, 0]),
    )
    return np.asarray(np.abs(vol.sum(axis=1)) / 6.0)


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

    def __call__(self, lift_gaps: NDArray[np.int64]) -> bool:
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
) -> Callable[[NDArray[np.int64]], bool]:
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


# --------------------------------------------------------------------------------------------
# Known-answer scene: a cylinder patch with exact planar frustums
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DeploymentScene:
    """A linkage with exactly congruent flat and assembled tiles, for tests and benchmarks.

    Attributes
    ----------
    linkage : topology of the full grid.
    tiles_flat : (T, 8, 3) float, mm, rotating-squares layout, tops at ``z = thickness``.
    tiles_assembled : (T, 8, 3) float, mm, frustums on a cylinder patch.
    hinge_vertices : (H, 2) int, top hinges.
    route : closed boundary loop, steps ``(gap, tile, enter_side, leave_side)``.
    thickness : float, mm.
    """

    linkage: Linkage
    tiles_flat: FloatArray
    tiles_assembled: FloatArray
    hinge_vertices: IntArray
    route: tuple[tuple[int, int, int, int], ...]
    thickness: float


def boundary_loop_route(linkage: Linkage) -> tuple[tuple[int, int, int, int], ...]:
    """Counter-clockwise loop through the boundary tiles of a full rectangular grid.

    Each step is ``(gap, tile, enter_side, leave_side)``; ``gap`` is the gap between the
    previous tile's leaving side and this tile's entering side (``-1`` if none).
    """
    n_i, n_j = linkage.grid_shape
    if n_i < 2 or n_j < 2:
        raise InputError("the boundary loop needs a grid of at least 2 x 2 tiles")
    cells = (
        [(i, 0) for i in range(n_i)]
        + [(n_i - 1, j) for j in range(1, n_j)]
        + [(i, n_j - 1) for i in range(n_i - 2, -1, -1)]
        + [(0, j) for j in range(n_j - 2, 0, -1)]
    )
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
    tiles = [index[c] for c in cells]
    side_of = {(1, 0): (1, 3), (0, 1): (2, 0), (-1, 0): (3, 1), (0, -1): (0, 2)}
    m = len(cells)
    leave = []
    enter = [0] * m
    for k in range(m):
        a, b = cells[k], cells[(k + 1) % m]
        s_leave, s_enter = side_of[(b[0] - a[0], b[1] - a[1])]
        leave.append(s_leave)
        enter[(k + 1) % m] = s_enter
    gap_of_side: dict[tuple[int, int], set[int]] = {}
    for g in range(linkage.n_gaps):
        for t, s in linkage.gap_sides[g]:
            if t >= 0:
                gap_of_side.setdefault((int(t), int(s)), set()).add(g)
    steps = []
    for k in range(m):
        prev = (k - 1) % m
        common = gap_of_side.get((tiles[prev], leave[prev]), set()) & gap_of_side.get(
            (tiles[k], enter[k]), set()
        )
        gap = min(common) if common else -1
        steps.append((gap, tiles[k], enter[k], leave[k]))
    return tuple(steps)


def cylinder_scene(
    n_i: int,
    n_j: int,
    *,
    side: float = 10.0,
    depth: float = 3.0,
    radius: float | None = None,
    opening: float = 0.5,
) -> DeploymentScene:
    """Frustum tiles on a cylinder patch and their flat rotating-squares layout.

    The cylinder axis is y; tile ``(i, j)`` spans angles ``theta_i .. theta_{i+1}`` (top chord
    ``side``) and ``y_j .. y_{j+1}`` (length ``side``), so every top face is an exact square of
    side ``side`` and every face of every tile is exactly planar; bottom faces lie on the
    cylinder of radius ``radius - depth``.  Neighbouring tiles share whole side faces.  The flat
    tiles are the same solids moved rigidly so that their top squares form the rotating-squares
    layout (``opening`` rad) at ``z = thickness``.

    Parameters
    ----------
    n_i, n_j : tiles along the curved and the straight direction.
    side : float, mm
    depth : float, mm, radial extrusion depth.
    radius : float, mm, default ``1.2 * n_i * side / (pi / 2)`` (about a 75 degree arc).
    opening : float, rad, gap angle of the flat layout.
    """
    if n_i < 2 or n_j < 2:
        raise InputError("a cylinder scene needs at least 2 x 2 tiles")
    link = build_linkage(np.ones((n_i, n_j), dtype=bool))
    r_out = radius if radius is not None else 1.2 * n_i * side / (0.5 * np.pi)
    dtheta = 2.0 * np.arcsin(side / (2.0 * r_out))
    theta = (np.arange(n_i + 1) - 0.5 * n_i) * dtheta
    ys = (np.arange(n_j + 1) - 0.5 * n_j) * side

    def point(i: IntArray, j: IntArray, r: float) -> FloatArray:
        return np.stack([r * np.sin(theta[i]), ys[j], r * np.cos(theta[i])], axis=-1)

    ci, cj = link.tile_cells[:, 0], link.tile_cells[:, 1]
    corner_i = np.stack([ci, ci + 1, ci + 1, ci], axis=1)
    corner_j = np.stack([cj, cj, cj + 1, cj + 1], axis=1)
    top = point(corner_i, corner_j, r_out)
    bottom = point(corner_i, corner_j, r_out - depth)
    assembled = np.concatenate([top, bottom], axis=1)
    assembled[..., 2] -= assembled[..., 2].min()
    thickness = float(depth * np.cos(0.5 * dtheta))

    squares = rotating_squares_layout(link, opening, side)  # (T, 4, 2)
    flat = np.empty_like(assembled)
    for t in range(link.n_tiles):
        target = np.concatenate([squares[t], np.full((4, 1), thickness)], axis=1)
        rot, shift = _kabsch(assembled[t, :4], target)
        flat[t] = assembled[t] @ rot.T + shift
    flat[..., 2] -= flat[..., 2].min()
    return DeploymentScene(
        linkage=link,
        tiles_flat=flat,
        tiles_assembled=assembled,
        hinge_vertices=hinge_vertex_pairs(link),
        route=boundary_loop_route(link),
        thickness=thickness,
    )
