"""The conical condition on a quad mesh: at every inner vertex in exactly four quads, the
angles of opposite quads sum equal (:class:`VertexStars`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.types import FloatArray, IntArray


@dataclass(frozen=True)
class VertexStars:
    """Inner vertices of a quad mesh in exactly four quads, for the conical condition.

    A quad mesh is conical when at every inner vertex the angles of opposite quads sum
    equal, ``a0 + a2 = a1 + a3``: its faces then touch a cone there, and moving every face
    along its normal by one distance gives an offset mesh with the same planar faces.  Each
    side face of that extrusion bisects the dihedral angle of its two tiles' top faces, so a
    corner of it lies as deep under one tile's top face as under the other's: the bottom
    hinges' corners meet when the tiles lie flat
    (:func:`~drawstring.geometry.assembled.reextrude.hinge_depth_pull`).

    Attributes
    ----------
    members : (S, 5) int
        The vertex and its four neighbours (sorted).
    prev_local, next_local : (S, 4) int
        Per quad, in the order 0, 1, 2, 3 around the vertex (0, 2 and 1, 3 opposite), the
        column of ``members`` of the corner before and after the vertex.
    """

    members: IntArray
    prev_local: IntArray
    next_local: IntArray

    def angle_sums(
        self, x: FloatArray, with_jacobian: bool = False
    ) -> tuple[FloatArray, FloatArray | None]:
        """``a0 - a1 + a2 - a3`` (rad) per star, and its gradient ``(S, 5, 3)`` by member."""
        p = x[self.members]  # (S, 5, 3)
        s = np.arange(len(p))[:, None]
        u = p[s, self.prev_local] - p[:, :1]  # (S, 4, 3)
        w = p[s, self.next_local] - p[:, :1]
        lu = np.linalg.norm(u, axis=2)
        lw = np.linalg.norm(w, axis=2)
        uh = u / np.maximum(lu, 1e-300)[..., None]
        wh = w / np.maximum(lw, 1e-300)[..., None]
        cos = np.einsum("ski,ski->sk", uh, wh)
        sin = np.linalg.norm(np.cross(uh, wh), axis=2)
        sign = np.array([1.0, -1.0, 1.0, -1.0])
        sums = np.arctan2(sin, cos) @ sign
        if not with_jacobian:
            return sums, None
        sin = np.maximum(sin, 1e-12)
        d_u = -(wh - cos[..., None] * uh) / (lu * sin)[..., None] * sign[:, None]
        d_w = -(uh - cos[..., None] * wh) / (lw * sin)[..., None] * sign[:, None]
        cols = np.arange(5)
        at_prev = (self.prev_local[..., None] == cols).astype(np.float64)  # (S, 4, 5)
        at_next = (self.next_local[..., None] == cols).astype(np.float64)
        grads = np.einsum("skm,ski->smi", at_prev, d_u) + np.einsum("skm,ski->smi", at_next, d_w)
        grads[:, 0] = -(d_u.sum(axis=1) + d_w.sum(axis=1))
        return sums, grads


def vertex_stars(quads: ArrayLike) -> VertexStars:
    """The :class:`VertexStars` of ``quads`` ``(T, 4)``: every vertex in exactly four quads
    that meet around it edge to edge (a regular grid vertex)."""
    q = np.asarray(quads, dtype=np.int64)
    corner_vertex = q.ravel()
    prev = np.roll(q, 1, axis=1).ravel()
    after = np.roll(q, -1, axis=1).ravel()
    order = np.argsort(corner_vertex, kind="stable")
    count = np.bincount(corner_vertex)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    centres = np.flatnonzero(count == 4)
    slots = order[first[centres][:, None] + np.arange(4)]  # (S, 4) corners around each
    pv, nv = prev[slots], after[slots]
    # the quad opposite quad 0 shares no neighbour with it
    shares = (pv == pv[:, :1]) | (pv == nv[:, :1]) | (nv == pv[:, :1]) | (nv == nv[:, :1])
    alone = ~shares[:, 1:]
    regular = alone.sum(axis=1) == 1
    opposite = 1 + np.argmax(alone, axis=1)
    others = np.sort(np.where(np.arange(1, 4) == opposite[:, None], 9, np.arange(1, 4)), axis=1)
    turn = np.stack(
        [np.zeros(len(centres), dtype=np.int64), others[:, 0], opposite, others[:, 1]], 1
    )
    rows = np.arange(len(centres))[:, None]
    pv, nv = pv[rows, turn], nv[rows, turn]
    around = np.sort(np.concatenate([pv, nv], axis=1), axis=1)
    regular &= np.all(around[:, 0::2] == around[:, 1::2], axis=1)
    regular &= np.all(np.diff(around[:, 0::2], axis=1) > 0, axis=1)
    nbrs = around[:, 0::2]
    members = np.concatenate([centres[:, None], nbrs], axis=1)[regular]
    nbrs = nbrs[regular]
    pv, nv = pv[regular], nv[regular]
    prev_local = 1 + np.argmax(pv[..., None] == nbrs[:, None, :], axis=2)
    next_local = 1 + np.argmax(nv[..., None] == nbrs[:, None, :], axis=2)
    return VertexStars(members, prev_local, next_local)
