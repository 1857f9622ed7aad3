"""The deployment simulation's constraint groups (:mod:`drawstring.geometry.simulate.deploy` runs
them): inertia, rigid tiles, hinges, the string's snap pairs and magnets, lift targets and face
contacts, each a :class:`~drawstring.geometry.solve.groups.ConstraintGroup` of the local-global
solver.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.tile import SIDE_FACES_INWARD
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.linalg import centering_matrix, difference_matrix

SnapMode = Literal["face", "midpoint"]

__all__ = [
    "FaceContact",
    "FaceSnap",
    "Inertia",
    "MovingTargets",
    "PointCoincidence",
    "RigidShape",
    "SnapMode",
    "best_rotations",
]


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
        va = p[:, 0, None] * 8 + SIDE_FACES_INWARD[p[:, 1]]  # (P, 4)
        vb = p[:, 2, None] * 8 + SIDE_FACES_INWARD[p[:, 3]]
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


def _side_normals(tiles: FloatArray, tile: IntArray, side: IntArray) -> FloatArray:
    """Unit normals ``(k, 3)`` of side faces, pointing into their tiles."""
    face = tiles[tile[:, None], SIDE_FACES_INWARD[side]]  # (k, 4, 3)
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
    pairs : (k, 4) int, ``(tile_a, side_a, tile_b, side_b)`` (:func:`~.inputs.contact_face_pairs`).
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
        fa = p[:, 0, None] * 8 + SIDE_FACES_INWARD[p[:, 1]]  # (k, 4)
        fb = p[:, 2, None] * 8 + SIDE_FACES_INWARD[p[:, 3]]
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
            mid_a = tiles[p[:, 0, None], SIDE_FACES_INWARD[p[:, 1]]].mean(axis=1)
            mid_b = tiles[p[:, 2, None], SIDE_FACES_INWARD[p[:, 3]]].mean(axis=1)
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
