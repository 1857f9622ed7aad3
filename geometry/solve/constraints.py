"""Constraint groups of the flat layout and the hinge layout (paper sections 4.3 and 4.4).

Every group follows :class:`drawstring.geometry.solve.groups.ConstraintGroup`: a constant sparse
matrix ``A`` and a batched projection of ``A X`` onto the constraint set.  Inequalities return
the current value of ``A X`` where they hold, so their matrix never changes and the solver's
factor is reused.

* :class:`GapAngleBounds` -- the opening angle at the end of a gap's slit stays in
  ``[lo, hi]`` (fabrication clearance, paper ``E_Fab``); with ``lo > 0`` it also keeps the gap
  counter-clockwise (not inverted), which is the local part of ``E_Collision``.
* :class:`QuadSeparation2D` -- two convex quads (tile footprints) do not overlap: where they do,
  both are pushed apart by half the minimum translation vector (separating-axis test).
* :class:`HingeConnection` -- paired hinge vertices coincide (paper ``E_Conn``).
* :class:`HalfPlane3D` -- a vertex stays on one side of a separating plane through a point
  given by other vertices (conservative 3D non-interpenetration of neighbouring tiles).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.linalg import centering_matrix, difference_matrix

__all__ = [
    "GapAngleBounds",
    "HalfPlane3D",
    "HingeConnection",
    "QuadSeparation2D",
    "convex_overlap_mtv",
    "signed_angles",
    "quad_overlap_mtv",
]


def signed_angles(u: FloatArray, v: FloatArray) -> FloatArray:
    """Counter-clockwise angle from ``u`` to ``v`` in ``(-pi, pi]``.

    Parameters
    ----------
    u, v : (k, 2) float

    Returns
    -------
    (k,) float, rad
    """
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    dot = np.einsum("ki,ki->k", u, v)
    return np.asarray(np.arctan2(cross, dot))


def _rotate(vec: FloatArray, angle: FloatArray) -> FloatArray:
    """Rotate 2D vectors ``(k, 2)`` counter-clockwise by ``angle (k,)``."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * vec[:, 0] - s * vec[:, 1], s * vec[:, 0] + c * vec[:, 1]], axis=1)


class GapAngleBounds(ConstraintGroup):
    """Angle at an apex between two arms kept within ``[lo, hi]`` (2D).

    Each element is ``(apex, q, p)``: the angle is measured counter-clockwise from ``q - apex``
    to ``p - apex`` (for a gap whose boundary runs counter-clockwise ``... p, apex, q ...`` this
    is the interior angle of the void).  Outside the bounds both arms are turned by half the
    excess in opposite directions about the apex, keeping their lengths: the exact closest point
    of the pair of arm vectors with the angle on the bound.

    Parameters
    ----------
    elements : (k, 3) int
        ``(apex, q, p)`` node ids.
    lo, hi : float, rad
    """

    def __init__(
        self,
        elements: ArrayLike,
        lo: float,
        hi: float,
        weight: float = 1.0,
        name: str = "gap_angle",
    ) -> None:
        super().__init__(name, weight)
        self.elements = np.asarray(elements, dtype=np.int64).reshape(-1, 3)
        if not (-np.pi < lo <= hi <= np.pi):
            raise InternalError(
                f"gap angle bounds [{lo}, {hi}] rad must satisfy -pi < lo <= hi <= pi"
            )
        self.lo = float(lo)
        self.hi = float(hi)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        e = self.elements
        pairs = np.stack([e[:, [0, 1]], e[:, [0, 2]]], axis=1).reshape(-1, 2)
        return difference_matrix(pairs, n_vertices)

    def angles(self, x: FloatArray) -> FloatArray:
        """Current angles ``(k,)`` in rad at positions ``x (n, 2)``."""
        e = self.elements
        return signed_angles(x[e[:, 1]] - x[e[:, 0]], x[e[:, 2]] - x[e[:, 0]])

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if ax.shape[1] != 2:
            raise InternalError("GapAngleBounds works on 2D positions only")
        arms = ax.reshape(-1, 2, 2)
        u, v = arms[:, 0], arms[:, 1]
        angle = signed_angles(u, v)
        excess = angle - np.clip(angle, self.lo, self.hi)
        out = arms.copy()
        active = excess != 0
        if np.any(active):
            half = 0.5 * excess[active]
            out[active, 0] = _rotate(u[active], half)
            out[active, 1] = _rotate(v[active], -half)
        return out.reshape(ax.shape)


def _quad_axes(quads: FloatArray) -> FloatArray:
    """Unit edge normals ``(k, 4, 2)`` of 2D quads ``(k, 4, 2)``."""
    edges = np.roll(quads, -1, axis=1) - quads
    normals = np.stack([edges[..., 1], -edges[..., 0]], axis=-1)
    norm = np.linalg.norm(normals, axis=-1, keepdims=True)
    return np.asarray(normals / np.maximum(norm, 1e-300))


def quad_overlap_mtv(qa: FloatArray, qb: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Penetration depth and direction of convex quad pairs (separating-axis test).

    Parameters
    ----------
    qa, qb : (k, 4, 2) float
        Convex quads (either orientation).

    Returns
    -------
    depth : (k,) float
        Smallest overlap of the projections over the 8 edge normals; ``<= 0`` when separated.
    direction : (k, 2) float
        Unit axis of that smallest overlap, pointing from ``qa`` towards ``qb``.
    """
    axes = np.concatenate([_quad_axes(qa), _quad_axes(qb)], axis=1)  # (k, 8, 2)
    pa = np.einsum("kai,kvi->kav", axes, qa)
    pb = np.einsum("kai,kvi->kav", axes, qb)
    overlap_pos = pa.max(axis=2) - pb.min(axis=2)  # push b along +axis
    overlap_neg = pb.max(axis=2) - pa.min(axis=2)  # push b along -axis
    use_pos = overlap_pos <= overlap_neg
    overlap = np.where(use_pos, overlap_pos, overlap_neg)
    best = np.argmin(overlap, axis=1)
    k = np.arange(len(qa))
    depth = overlap[k, best]
    direction = axes[k, best] * np.where(use_pos[k, best], 1.0, -1.0)[:, None]
    return np.asarray(depth), np.asarray(direction)


def convex_overlap_mtv(pa: FloatArray, pb: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Penetration depth and direction (from ``pa`` towards ``pb``) of the convex hulls of
    point sets ``(k, m, 2)``: separating-axis test over the normals of every segment between
    two points of one set, which include the hulls' edges."""
    m = pa.shape[1]
    i, j = np.triu_indices(m, 1)
    axes = np.concatenate([pa[:, j] - pa[:, i], pb[:, j] - pb[:, i]], axis=1)
    axes = np.stack([-axes[..., 1], axes[..., 0]], axis=-1)
    length = np.linalg.norm(axes, axis=2, keepdims=True)
    axes = np.where(length > 1e-12, axes / np.maximum(length, 1e-300), 0.0)
    proj_a = np.einsum("kai,kvi->kav", axes, pa)
    proj_b = np.einsum("kai,kvi->kav", axes, pb)
    overlap_pos = proj_a.max(axis=2) - proj_b.min(axis=2)
    overlap_neg = proj_b.max(axis=2) - proj_a.min(axis=2)
    use_pos = overlap_pos <= overlap_neg
    overlap = np.where(use_pos, overlap_pos, overlap_neg)
    overlap = np.where(length[..., 0] > 1e-12, overlap, np.inf)  # coincident points: no axis
    best = np.argmin(overlap, axis=1)
    k = np.arange(len(pa))
    direction = axes[k, best] * np.where(use_pos[k, best], 1.0, -1.0)[:, None]
    return np.asarray(overlap[k, best]), np.asarray(direction)


class QuadSeparation2D(ConstraintGroup):
    """Pairs of convex quads (tile footprints) that must not overlap.

    ``A`` gives every corner of both quads minus the pair's centroid, so the group pins no
    translation.  Where the quads overlap, quad ``a`` moves by ``-depth/2`` and quad ``b`` by
    ``+depth/2`` along the minimum-translation axis (plus a ``margin``); elsewhere the current
    value is returned.

    Parameters
    ----------
    quads_a, quads_b : (k, 4) int
        Node ids of each pair's corners.
    margin : float, mm
        Extra clearance added to the push.
    """

    def __init__(
        self,
        quads_a: ArrayLike,
        quads_b: ArrayLike,
        margin: float = 0.0,
        weight: float = 1.0,
        name: str = "quad_separation",
    ) -> None:
        super().__init__(name, weight)
        self.quads_a = np.asarray(quads_a, dtype=np.int64).reshape(-1, 4)
        self.quads_b = np.asarray(quads_b, dtype=np.int64).reshape(-1, 4)
        self.margin = float(margin)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(np.hstack([self.quads_a, self.quads_b]), n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        pts = ax.reshape(-1, 8, ax.shape[1]).copy()
        depth, direction = quad_overlap_mtv(pts[:, :4, :2], pts[:, 4:, :2])
        push = np.where(depth > 0, 0.5 * (depth + self.margin), 0.0)
        shift = push[:, None] * direction
        pts[:, :4, :2] -= shift[:, None, :]
        pts[:, 4:, :2] += shift[:, None, :]
        return pts.reshape(ax.shape)


class HingeConnection(ConstraintGroup):
    """Paired hinge vertices pulled to their common midpoint (paper ``E_Conn``).

    Implemented as the difference row ``(x_b - x_a) / sqrt(2)`` projected to zero, whose energy
    ``w |x_b - x_a|^2 / 2`` equals ``w (|x_a - m|^2 + |x_b - m|^2)`` with ``m`` the midpoint, and
    which pins no translation.

    Parameters
    ----------
    pairs : (k, 2) int
    """

    def __init__(self, pairs: ArrayLike, weight: float = 1.0, name: str = "hinge_connection"):
        super().__init__(name, weight)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return sp.csr_matrix(difference_matrix(self.pairs, n_vertices) / np.sqrt(2.0))

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        return np.zeros_like(ax)


class HalfPlane3D(ConstraintGroup):
    """Vertices kept on the positive side of planes through an anchor vertex.

    Element ``(v, anchor)`` with unit normal ``n``: ``(x_v - x_anchor) . n >= 0``.  The row is the
    difference ``x_v - x_anchor``; when the inequality fails the difference is projected onto the
    plane.  Normals are fixed per element (chosen from the start layout), so the constraint is
    conservative and the matrix constant.

    Parameters
    ----------
    elements : (k, 2) int
        ``(vertex, anchor)``.
    normals : (k, dim) float
    """

    def __init__(
        self,
        elements: ArrayLike,
        normals: ArrayLike,
        weight: float = 1.0,
        name: str = "half_plane",
    ) -> None:
        super().__init__(name, weight)
        self.elements = np.asarray(elements, dtype=np.int64).reshape(-1, 2)
        nrm = np.asarray(normals, dtype=np.float64)
        self.normals = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return difference_matrix(self.elements[:, ::-1], n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        side = np.einsum("ki,ki->k", ax, self.normals)
        return ax - np.minimum(side, 0.0)[:, None] * self.normals
