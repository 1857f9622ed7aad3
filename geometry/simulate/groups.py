"""The simulation's geometry helpers, its inputs (route, hinges, lift targets) and its
constraint groups (:mod:`drawstring.geometry.simulate.deploy` runs them).

Tiles are ``(T, 8, 3)`` arrays in the vertex order of ``assembled.obj``: top corners 0..3, the
bottom corners 4..7 under them.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.rigid import rigid_fit
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.solver import (
    ConstraintGroup,
    centering_matrix,
    difference_matrix,
)
from drawstring.geometry.tiling.linkage import Linkage

logger = logging.getLogger(__name__)

SnapMode = Literal["face", "midpoint"]

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
    rot, shift = rigid_fit(source[None], target[None])
    return rot[0], shift[0]


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
    if len(steps) < 2:  # the user's route.json can say so (drawstring simulate FOLDER)
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
        raise InternalError("hinge_side must list 'top' or 'bottom' for every hinge")
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
            raise InternalError(f"lift gap {g} does not exist; the linkage has {linkage.n_gaps}")
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
        # the projection sqrt(m) * y, computed once per targets array (not every iteration)
        self._rows: FloatArray | None = None
        self._rows_of: FloatArray | None = None

    def set_targets(self, targets: FloatArray) -> None:
        self.targets = np.asarray(targets, dtype=np.float64)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        n = len(self.sqrt_m)
        return sp.csr_matrix((self.sqrt_m, (np.arange(n), np.arange(n))), shape=(n, n_vertices))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if self._rows is None or self._rows_of is not self.targets:
            self._rows = np.asarray(self.sqrt_m[:, None] * self.targets)
            self._rows_of = self.targets
        return self._rows


class PointCoincidence(ConstraintGroup):
    """Paired vertices coincide (hinges): rows ``(x_b - x_a) / sqrt 2`` shortened to ``radius``.

    ``radius`` (per row, default zero) lets a hinge that is open in the fabricated layout close
    over a few steps instead of jerking the tiles in the first one.

    Parameters
    ----------
    pairs : (k, 2) int
    """

    def __init__(self, pairs: ArrayLike, weight: float, name: str = "hinge") -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self.radius = np.zeros(len(self.pairs))

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return sp.csr_matrix(difference_matrix(self.pairs, n_vertices) / np.sqrt(2.0))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if not np.any(self.radius):
            return np.zeros_like(ax)
        norm = np.linalg.norm(ax, axis=1)
        scale = np.minimum(1.0, self.radius / np.maximum(norm, 1e-300))
        return np.asarray(ax * scale[:, None])


class FaceSnap(ConstraintGroup):
    """The string between route neighbours: each row kept at most ``radius`` long.

    A pair whose faces touch in the assembled state (``face[p]`` True, ``mode == "face"``) has
    four rows, each corner of face a minus its partner corner of face b (``partner``): whole-face
    contact.  Other pairs (the string crossing a gap whose two faces do not meet, and every pair
    with ``mode == "midpoint"``, the paper's choice) have one row, ``mid(face_b) - mid(face_a)``.
    The projection shortens every row to at most ``radius`` (the string still to be reeled in),
    which the simulation moves from the start length to the assembled length.

    Parameters
    ----------
    pairs : (P, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    partner : (P, 4) int, for face rows: index into face b's corners of the partner of face
        a's corner ``c``.
    face : (P,) bool, pairs that get face rows (default: all when ``mode == "face"``).
    """

    def __init__(
        self,
        pairs: ArrayLike,
        weight: float,
        mode: SnapMode = "midpoint",
        partner: IntArray | None = None,
        name: str = "snap",
        face: ArrayLike | None = None,
    ) -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
        self.mode = mode
        self.partner = partner
        k = len(self.pairs)
        if mode == "midpoint":
            self.face = np.zeros(k, dtype=bool)
        elif face is None:
            self.face = np.ones(k, dtype=bool)
        else:
            self.face = np.asarray(face, dtype=bool).reshape(k)
        #: pair of every row
        self.row_pair = np.concatenate(
            [np.flatnonzero(self.face).repeat(4), np.flatnonzero(~self.face)]
        )
        self.radius = np.zeros(len(self.row_pair))

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        p = self.pairs
        va = p[:, 0, None] * 8 + SIDE_FACES[p[:, 1]]  # (P, 4)
        vb = p[:, 2, None] * 8 + SIDE_FACES[p[:, 3]]
        blocks = []
        if self.face.any():
            assert self.partner is not None
            vb_match = np.take_along_axis(vb, self.partner, axis=1)[self.face]
            edges = np.stack([va[self.face].reshape(-1), vb_match.reshape(-1)], axis=1)
            blocks.append(difference_matrix(edges, n_vertices))
        mid = ~self.face
        if mid.any():
            k = int(mid.sum())
            rows = np.repeat(np.arange(k), 8)
            cols = np.concatenate([va[mid], vb[mid]], axis=1).reshape(-1)
            vals = np.tile(np.r_[-0.25 * np.ones(4), 0.25 * np.ones(4)], k)
            blocks.append(sp.csr_matrix((vals, (rows, cols)), shape=(k, n_vertices)))
        return sp.csr_matrix(sp.vstack(blocks, format="csr"))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        norm = np.linalg.norm(ax, axis=1)
        scale = np.minimum(1.0, self.radius / np.maximum(norm, 1e-300))
        return np.asarray(ax * scale[:, None])


class MovingTargets(ConstraintGroup):
    """Vertices pulled to targets that may move every step (lift actuation).

    With ``height_only`` the targets prescribe only ``z`` (the string lifts; it does not drag
    sideways): the projection keeps the current ``x, y``.

    Parameters
    ----------
    indices : (k,) int
    """

    def __init__(
        self, indices: ArrayLike, weight: float, name: str = "lift", height_only: bool = False
    ) -> None:
        super().__init__(name, weight)
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.targets = np.zeros((len(self.indices), 3))
        self.height_only = height_only

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        k = len(self.indices)
        return sp.csr_matrix((np.ones(k), (np.arange(k), self.indices)), shape=(k, n_vertices))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if not self.height_only:
            return self.targets
        out = ax.copy()
        out[:, 2] = self.targets[:, 2]
        return out


def _svd_rotations(cov: FloatArray) -> FloatArray:
    """``Q`` in SO(3) maximizing ``tr(Q^T C)`` for each ``C : (T, 3, 3)`` (Kabsch by SVD)."""
    u, _, vt = np.linalg.svd(cov)
    flip = np.linalg.det(np.matmul(u, vt)) < 0
    u[flip, :, 2] *= -1.0
    return np.asarray(np.matmul(u, vt))


def best_rotations(
    cov: FloatArray, guess: FloatArray, *, tol: float = 1e-9, max_iter: int = 6
) -> FloatArray:
    """``Q`` in SO(3) maximizing ``tr(Q^T C)`` for each ``C``, by Newton steps from ``guess``.

    The rotational part of ``C``'s polar decomposition (the Kabsch rotation, reflections
    excluded), for a batch of 3 x 3 matrices, when a good guess is at hand (the previous
    iteration's rotations): each step writes ``Q = Q0 exp([w]x)`` and solves the 3 x 3 Newton
    system ``(tr(B) I - sym(B)) w = axial(B - B^T)`` with ``B = Q0^T C`` in closed form, so the
    whole batch costs a few dozen vectorized array operations instead of ``T`` LAPACK SVDs.  It
    converges quadratically; the loop stops when every rotation step is below ``tol`` rad (the
    result then agrees with the SVD to rounding).  Matrices that did not converge or did not
    end at a maximum (the Newton matrix not positive definite) are solved by SVD.

    Parameters
    ----------
    cov : (T, 3, 3) float
    guess : (T, 3, 3) float, rotations.

    Returns
    -------
    (T, 3, 3) float, proper rotations.
    """
    c = np.ascontiguousarray(np.asarray(cov, dtype=np.float64).transpose(1, 2, 0))  # (3, 3, T)
    q = np.ascontiguousarray(np.asarray(guess, dtype=np.float64).transpose(1, 2, 0))
    ok = np.zeros(c.shape[2], dtype=bool)
    for _ in range(max_iter):
        b = np.einsum("kit,kjt->ijt", q, c)
        g0, g1, g2 = b[2, 1] - b[1, 2], b[0, 2] - b[2, 0], b[1, 0] - b[0, 1]
        trace = b[0, 0] + b[1, 1] + b[2, 2]
        h00, h11, h22 = trace - b[0, 0], trace - b[1, 1], trace - b[2, 2]
        h01 = -0.5 * (b[0, 1] + b[1, 0])
        h02 = -0.5 * (b[0, 2] + b[2, 0])
        h12 = -0.5 * (b[1, 2] + b[2, 1])
        c00, c11, c22 = h11 * h22 - h12 * h12, h00 * h22 - h02 * h02, h00 * h11 - h01 * h01
        c01, c02, c12 = h02 * h12 - h01 * h22, h01 * h12 - h02 * h11, h01 * h02 - h00 * h12
        det = h00 * c00 + h01 * c01 + h02 * c02
        positive = (h00 > 0) & (c22 > 0) & (det > 0)
        inv = np.where(positive, 1.0 / np.where(positive, det, 1.0), 0.0)
        w0 = (c00 * g0 + c01 * g1 + c02 * g2) * inv
        w1 = (c01 * g0 + c11 * g1 + c12 * g2) * inv
        w2 = (c02 * g0 + c12 * g1 + c22 * g2) * inv
        ang2 = w0 * w0 + w1 * w1 + w2 * w2
        ang = np.sqrt(ang2)
        small = ang < 1e-4
        safe = np.where(small, 1.0, ang)
        a = np.where(small, 1.0 - ang2 / 6.0, np.sin(safe) / safe)
        bb = np.where(small, 0.5 - ang2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
        turn = np.empty_like(q)  # Rodrigues: exp([w]x)
        turn[0, 0] = 1.0 - bb * (w1 * w1 + w2 * w2)
        turn[1, 1] = 1.0 - bb * (w0 * w0 + w2 * w2)
        turn[2, 2] = 1.0 - bb * (w0 * w0 + w1 * w1)
        b01, b02, b12 = bb * w0 * w1, bb * w0 * w2, bb * w1 * w2
        turn[0, 1], turn[1, 0] = b01 - a * w2, b01 + a * w2
        turn[0, 2], turn[2, 0] = b02 + a * w1, b02 - a * w1
        turn[1, 2], turn[2, 1] = b12 - a * w0, b12 + a * w0
        q = np.einsum("ikt,kjt->ijt", q, turn)
        ok = positive & (ang < tol)
        if ok.all():
            break
    out = np.ascontiguousarray(q.transpose(2, 0, 1))
    if not ok.all():
        bad = np.flatnonzero(~ok)
        out[bad] = _svd_rotations(np.asarray(cov)[bad])
    return out


class RigidShape(ConstraintGroup):
    """Every tile keeps its rest shape: its eight vertices projected onto the closest rigid copy.

    ``A`` gives each tile's vertices minus the tile centroid; the projection is the rest shape
    (centred) turned by the best rotation (batched Kabsch), so the group is the exact
    closest-point projection onto the rigid motions of the tile.  The rotations are kept from
    call to call and refined by :func:`best_rotations` (Newton steps from the last ones; SVD on
    the first call and wherever Newton does not converge).

    Parameters
    ----------
    rest : (T, 8, 3) float, mm, the fabricated tiles.
    """

    def __init__(self, rest: ArrayLike, weight: float, name: str = "rigid") -> None:
        super().__init__(name, weight)
        arr = np.asarray(rest, dtype=np.float64)
        self.rest = arr - arr.mean(axis=1, keepdims=True)
        self.rest_t = np.ascontiguousarray(self.rest.transpose(0, 2, 1))
        #: (T, 3, 3) last rotations ``Q`` (copies are ``rest @ Q``); None before the first call
        self.rotation: FloatArray | None = None

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        n_tiles = len(self.rest)
        return centering_matrix(np.arange(n_tiles * 8).reshape(n_tiles, 8), n_vertices)

    def rotations(self, centred: FloatArray) -> FloatArray:
        """Best rotations ``(T, 3, 3)`` of the rest shapes onto ``centred : (T, 8, 3)``."""
        cov = np.matmul(self.rest_t, centred)
        if self.rotation is None:
            self.rotation = _svd_rotations(cov)
        else:
            self.rotation = best_rotations(cov, self.rotation)
        return self.rotation

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        rot = self.rotations(ax.reshape(-1, 8, 3))
        return np.asarray(np.matmul(self.rest, rot).reshape(ax.shape))

    def rigid_copies(self, x: FloatArray) -> FloatArray:
        """The closest rigid copies ``(T * 8, 3)`` of the rest shapes to ``x : (T * 8, 3)``."""
        tiles = x.reshape(-1, 8, 3)
        centre = tiles.mean(axis=1, keepdims=True)
        rot = self.rotations(tiles - centre)
        return np.asarray((np.matmul(self.rest, rot) + centre).reshape(-1, 3))


def contact_face_pairs(linkage: Linkage) -> IntArray:
    """Side faces of grid-neighbour tiles that touch in the assembled state.

    Tiles in cells ``(i, j)`` and ``(i + 1, j)`` meet with sides 1 and 3, tiles in ``(i, j)``
    and ``(i, j + 1)`` with sides 2 and 0.  Only hinged neighbours are listed: across a split
    line the two parts may lie anywhere in the flat layout, where a face half-space would be
    meaningless (the string's snap pairs bring them together).

    Returns
    -------
    (k, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    """
    return _neighbour_sides(linkage, hinged=True)


def split_contact_pairs(linkage: Linkage) -> IntArray:
    """Side faces of edge-neighbour tiles that touch across a split (no hinge joins them).

    Same orientation as :func:`contact_face_pairs`: cells ``(i, j)`` and ``(i + 1, j)`` give
    ``(a, 1, b, 3)``, cells ``(i, j)`` and ``(i, j + 1)`` give ``(a, 2, b, 0)``.

    Returns
    -------
    (k, 4) int, ``(tile_a, side_a, tile_b, side_b)``.
    """
    return _neighbour_sides(linkage, hinged=False)


def _neighbour_sides(linkage: Linkage, *, hinged: bool) -> IntArray:
    """``(tile_a, side_a, tile_b, side_b)`` of the edge-neighbour tiles that a hinge joins
    (``hinged``) or that a split separates: cells ``(i, j)``, ``(i + 1, j)`` meet with sides 1
    and 3, cells ``(i, j)``, ``(i, j + 1)`` with sides 2 and 0."""
    cells = linkage.tile_cells
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(cells)}
    joined = {(int(min(a, b)), int(max(a, b))) for a, _, b, _ in linkage.hinges}
    out = []
    for t, (i, j) in enumerate(cells):
        for (di, dj), sides in (((1, 0), (1, 3)), ((0, 1), (2, 0))):
            other = index.get((int(i) + di, int(j) + dj))
            if other is not None and ((min(t, other), max(t, other)) in joined) == hinged:
                out.append((t, sides[0], other, sides[1]))
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def _side_normals(tiles: FloatArray, tile: IntArray, side: IntArray) -> FloatArray:
    """Unit normals ``(k, 3)`` of side faces, pointing into their tiles."""
    face = tiles[tile[:, None], SIDE_FACES[side]]  # (k, 4, 3)
    n = np.cross(face[:, 2] - face[:, 0], face[:, 3] - face[:, 1])
    return np.asarray(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))


class FaceContact(ConstraintGroup):
    """Touching side faces of neighbour tiles do not pass through each other.

    For every pair, rows give the four corners of face b minus the centroid of face a, and the
    four corners of face a minus the centroid of face b.  With the contact axis ``n`` (from a
    towards b: the mean of the two faces' normals, frozen by :meth:`set_axes` once per time
    step so the projection is a fixed convex set), the projection removes the negative part of
    ``n . r`` (face b's corners stay in front of face a) and of ``-n . r`` (and vice versa).
    Rows that are satisfied return their current value.

    Parameters
    ----------
    pairs : (k, 4) int, ``(tile_a, side_a, tile_b, side_b)`` (:func:`contact_face_pairs`).
    """

    def __init__(
        self,
        pairs: ArrayLike,
        weight: float,
        name: str = "contact",
        engage_distance: float | None = None,
    ) -> None:
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
        self.axes = np.zeros((len(self.pairs), 3))
        #: pairs whose rows act; all of them unless ``engage_distance`` gates them
        self.engage_distance = engage_distance
        self.active = np.full(len(self.pairs), engage_distance is None)
        # (2, k, 3) axes of the two row blocks (n, -n), built once per set of axes
        self._signed: FloatArray | None = None
        self._signed_of: FloatArray | None = None

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        p = self.pairs
        k = len(p)
        fa = p[:, 0, None] * 8 + SIDE_FACES[p[:, 1]]  # (k, 4)
        fb = p[:, 2, None] * 8 + SIDE_FACES[p[:, 3]]
        rows = np.arange(8 * k).reshape(2, k, 4)
        corner = np.stack([fb, fa])  # block 0: corners of b, block 1: corners of a
        other = np.stack([fa, fb])
        r_all = np.concatenate(
            [rows.reshape(-1), np.repeat(rows[..., None], 4, axis=3).reshape(-1)]
        )
        c_all = np.concatenate(
            [corner.reshape(-1), np.repeat(other[:, :, None, :], 4, axis=2).reshape(-1)]
        )
        v_all = np.concatenate([np.ones(8 * k), np.full(32 * k, -0.25)])
        return sp.csr_matrix((v_all, (r_all, c_all)), shape=(8 * k, n_vertices))

    def set_axes(self, x: FloatArray) -> None:
        """Freeze the contact axes at positions ``x : (T * 8, 3)``."""
        tiles = x.reshape(-1, 8, 3)
        p = self.pairs
        n = _side_normals(tiles, p[:, 2], p[:, 3]) - _side_normals(tiles, p[:, 0], p[:, 1])
        self.axes = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        if self.engage_distance is not None:
            # Gated pairs (across a split) engage for good once their faces come close while
            # face b is still (nearly) in front of face a: far apart in the flat layout, a
            # half-space between them would be meaningless.
            mid_a = tiles[p[:, 0, None], SIDE_FACES[p[:, 1]]].mean(axis=1)
            mid_b = tiles[p[:, 2, None], SIDE_FACES[p[:, 3]]].mean(axis=1)
            gap = mid_b - mid_a
            ahead = np.sum(gap * self.axes, axis=1) > -0.5 * self.engage_distance
            near = np.linalg.norm(gap, axis=1) < self.engage_distance
            self.active |= near & ahead

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if not self.active.any():
            return ax
        k = len(self.pairs)
        r = ax.reshape(2, k, 4, 3)
        if self._signed is None or self._signed_of is not self.axes:
            self._signed = np.stack([self.axes, -self.axes])  # (2, k, 3)
            self._signed_of = self.axes
        axis = self._signed
        push = np.einsum("pkcd,pkd->pkc", r, axis)
        np.minimum(push, 0.0, out=push)
        if not self.active.all():
            push *= self.active[None, :, None]
        if not push.any():
            # Every row satisfied: the rows themselves (subtracting zeros would change no bit;
            # rows of a sparse product are never -0.0).
            return ax
        out = push[..., None] * axis[:, :, None, :]
        np.subtract(r, out, out=out)
        return np.asarray(out.reshape(ax.shape))
