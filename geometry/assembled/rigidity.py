"""Infinitesimal rigidity of the assembled linkage (a numerical check of paper Theorem 5.1).

Every tile is a rigid body with a twist ``(w_t, u_t)``: the velocity of a point ``p`` moving
with tile ``t`` is ``u_t + w_t x (p - c_t)`` (``c_t`` the tile centroid).  Constraints, each
three rows of the rigidity matrix ``R`` (columns ``6 T``, tile ``t`` at ``6t .. 6t + 5`` as
``w_x, w_y, w_z, u_x, u_y, u_z``):

* joint: the two hinged tiles' velocities agree at the hinge point (a ball joint);
* string contact: for consecutive tiles on the route, the two tiles' velocities agree at the
  midpoint of their shared contact face (``contact="midpoint"``), or at three points of that
  face (``contact="face"``: two face corners and the midpoint; the faces then cannot slide or
  turn against each other).

The infinitesimal motions are the null space of ``R``; the six rigid-body motions always lie in
it.  Its dimension comes from the singular values of ``R`` below ``RIGIDITY_SVD_REL`` times the
largest; ``6`` means isostatic (or over-braced): no internal flex.  Internal flexes are the null
vectors orthogonal to the rigid motions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import SIDE_FACES_INWARD
from drawstring.geometry.core.tolerances import RIGIDITY_SVD_REL
from drawstring.geometry.core.types import FloatArray, IntArray

ContactMode = Literal["midpoint", "face"]

__all__ = [
    "RigidityReport",
    "internal_flexes",
    "rigid_motion_basis",
    "rigidity_matrix",
    "rigidity_report",
]


def _skew_triplets(
    tile: IntArray, arm: FloatArray, sign: float
) -> tuple[IntArray, IntArray, FloatArray]:
    """Sparse rows ``sign * (u_t + w_t x arm)`` for points ``(k,)``: (row, col, value) triplets.

    Point ``i`` owns rows ``3 i .. 3 i + 2``; ``w x a = -a x w`` gives the rows of ``-[a]_x``.
    """
    k = len(tile)
    ax, ay, az = arm[:, 0], arm[:, 1], arm[:, 2]
    zero = np.zeros(k)
    # (row offset, column offset within the twist, coefficient)
    pattern = (
        (0, 0, zero), (0, 1, az), (0, 2, -ay),
        (1, 0, -az), (1, 1, zero), (1, 2, ax),
        (2, 0, ay), (2, 1, -ax), (2, 2, zero),
        (0, 3, np.ones(k)), (1, 4, np.ones(k)), (2, 5, np.ones(k)),
    )  # fmt: skip
    rows = np.concatenate([3 * np.arange(k) + r for r, _, _ in pattern])
    cols = np.concatenate([6 * tile + c for _, c, _ in pattern])
    vals = sign * np.concatenate([v for _, _, v in pattern])
    return rows, cols, vals


def rigidity_matrix(
    tiles: ArrayLike,
    joints: ArrayLike,
    contacts: ArrayLike = (),
    *,
    contact: ContactMode = "midpoint",
) -> FloatArray:
    """Rigidity (infinitesimal motion) matrix of rigid tiles joined at points.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm, assembled tiles.
    joints : (H, 2) int, hinge vertex ids ``tile * 8 + vertex`` (the joint point is their mean).
    contacts : (P, 4) int, ``(tile_a, side_a, tile_b, side_b)`` faces held in contact.
    contact : ``"midpoint"`` (one point per contact) or ``"face"`` (three points).

    Returns
    -------
    R : (3 (H + P * m), 6 T) float sparse (CSR), ``m = 1`` or ``3``.
    """
    pts = np.asarray(tiles, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[1:] != (8, 3):
        raise InternalError(f"tiles must be (T, 8, 3), got {pts.shape}")
    n_tiles = len(pts)
    cols = 6 * n_tiles
    centroid = pts.mean(axis=1)
    flat = pts.reshape(-1, 3)
    j = np.asarray(joints, dtype=np.int64).reshape(-1, 2)
    ta, tb = j[:, 0] // 8, j[:, 1] // 8
    point = 0.5 * (flat[j[:, 0]] + flat[j[:, 1]])
    tile_a, tile_b, where = [ta], [tb], [point]
    c = np.asarray(contacts, dtype=np.int64).reshape(-1, 4)
    if len(c):
        fa = pts[c[:, 0, None], SIDE_FACES_INWARD[c[:, 1]]]  # (P, 4, 3)
        fb = pts[c[:, 2, None], SIDE_FACES_INWARD[c[:, 3]]]
        mid = 0.5 * (fa.mean(axis=1) + fb.mean(axis=1))
        if contact == "midpoint":
            extra = [mid]
        elif contact == "face":
            extra = [mid, 0.5 * (fa[:, 0] + fa[:, 1]), 0.5 * (fa[:, 0] + fa[:, 3])]
        else:
            raise InternalError(f"contact mode {contact!r}; use 'midpoint' or 'face'")
        for p in extra:
            tile_a.append(c[:, 0])
            tile_b.append(c[:, 2])
            where.append(p)
    ta_all = np.concatenate(tile_a)
    tb_all = np.concatenate(tile_b)
    p_all = np.concatenate(where)
    ra, ca, va = _skew_triplets(ta_all, p_all - centroid[ta_all], 1.0)
    rb, cb, vb = _skew_triplets(tb_all, p_all - centroid[tb_all], -1.0)
    mat = sp.coo_matrix(
        (np.concatenate([va, vb]), (np.concatenate([ra, rb]), np.concatenate([ca, cb]))),
        shape=(3 * len(p_all), cols),
    )
    return mat.tocsr()


def rigid_motion_basis(tiles: ArrayLike) -> FloatArray:
    """Orthonormal basis ``(6 T, 6)`` of the global rigid motions in twist coordinates.

    A global motion ``v(p) = u + w x p`` gives tile ``t`` the twist ``(w, u + w x c_t)``.
    """
    pts = np.asarray(tiles, dtype=np.float64)
    centroid = pts.mean(axis=1)
    n_tiles = len(pts)
    basis = np.zeros((6 * n_tiles, 6))
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = 1.0
        for t in range(n_tiles):
            basis[6 * t + axis, axis] = 1.0  # rotation rate
            basis[6 * t + 3 : 6 * t + 6, axis] = np.cross(e, centroid[t])
            basis[6 * t + 3 + axis, 3 + axis] = 1.0  # translation
    q, _ = np.linalg.qr(basis)
    return np.asarray(q)


@dataclass(frozen=True)
class RigidityReport:
    """Outcome of :func:`rigidity_report`.

    Attributes
    ----------
    null_dimension : number of independent infinitesimal motions (6 = rigid only).
    internal_flexes : null_dimension - 6 (never negative for a valid matrix).
    flexes : (6 T, internal_flexes) float, orthonormal internal flexes (orthogonal to the rigid
        motions), twist coordinates.
    singular_values : (k,) float, ascending: all ``6 T`` of them for small linkages, the
        smallest ``k`` (more than the null dimension) above :data:`DENSE_MAX_COLUMNS` columns.
    tolerance : float, threshold used on the singular values.
    rows, cols : shape of the rigidity matrix.
    """

    null_dimension: int
    internal_flexes: int
    flexes: FloatArray
    singular_values: FloatArray
    tolerance: float
    rows: int
    cols: int

    @property
    def isostatic(self) -> bool:
        """No internal flex.  (A null space below the six rigid motions only means that the
        tolerance cut into them, as on a near-degenerate linkage: still no flex.)"""
        return self.internal_flexes == 0

    def to_json(self) -> dict[str, object]:
        return {
            "null_dimension": self.null_dimension,
            "internal_flexes": self.internal_flexes,
            "isostatic": self.isostatic,
            "svd_tolerance": self.tolerance,
            "smallest_nonzero_singular_value": float(
                self.singular_values[self.null_dimension]
                if self.null_dimension < len(self.singular_values)
                else 0.0
            ),
        }


def rigidity_report(
    tiles: ArrayLike,
    joints: ArrayLike,
    contacts: ArrayLike = (),
    *,
    contact: ContactMode = "midpoint",
    rel_tol: float = RIGIDITY_SVD_REL,
) -> RigidityReport:
    """Null space of the rigidity matrix: dimension and internal flexes.

    Lengths are scaled by the mean tile size first so that rotation and translation columns are
    comparable and the tolerance is unit-free.

    Parameters
    ----------
    tiles, joints, contacts, contact : see :func:`rigidity_matrix`.
    rel_tol : singular values ``<= rel_tol * s_max`` count as zero.

    Returns
    -------
    RigidityReport
    """
    pts = np.asarray(tiles, dtype=np.float64)
    scale = float(np.linalg.norm(pts[:, 0] - pts[:, 2], axis=1).mean()) or 1.0
    pts = (pts - pts.reshape(-1, 3).mean(axis=0)) / scale
    mat = rigidity_matrix(pts, joints, contacts, contact=contact)
    cols = mat.shape[1]
    if cols <= DENSE_MAX_COLUMNS:
        sing, vecs = _smallest_singular_dense(mat)
        tol = rel_tol * float(sing.max(initial=0.0))
    else:
        s_max = float(np.sqrt(spla.eigsh(mat.T @ mat, k=1, which="LA", v0=_start(cols))[0][0]))
        tol = rel_tol * s_max
        sing, vecs = _smallest_singular_sparse(mat, tol, s_max)
    null = vecs[:, sing <= tol]  # (6T, d)
    flexes = internal_flexes(null, rigid_motion_basis(pts))
    return RigidityReport(
        null_dimension=int(null.shape[1]),
        internal_flexes=int(flexes.shape[1]),
        flexes=np.asarray(flexes),
        singular_values=np.asarray(sing),
        tolerance=tol,
        rows=int(mat.shape[0]),
        cols=int(cols),
    )


#: A direction of the null space is a flex where its part orthogonal to the rigid motions has
#: at least this length (of 1).  A flex's part is of order one; a rigid motion as the sparse
#: eigensolve returns it keeps 1e-5 of noise outside them (the 1600-tile saddle: the six rigid
#: motions lie within 1e-5 of its 8-dimensional null space), which a bound of 1e-6 counted as
#: six more flexes (7 internal flexes in an 8-dimensional null space).
FLEX_MIN_PART = 1e-2


def internal_flexes(null: FloatArray, rigid: FloatArray) -> FloatArray:
    """Orthonormal basis ``(6T, f)`` of the internal flexes: the part of the null space
    ``null`` (orthonormal columns) outside the rigid motions ``rigid`` (orthonormal columns)."""
    resid = null - rigid @ (rigid.T @ null)
    if not resid.size:
        return np.zeros((len(null), 0))
    u, s, _ = np.linalg.svd(resid, full_matrices=False)
    return np.asarray(u[:, s > FLEX_MIN_PART])


#: Up to this many columns (6 per tile) the null space comes from a dense SVD; above it from a
#: sparse shift-invert eigensolve (10x faster at 200 tiles; a dense SVD at 1600 needs ~1 GB).
DENSE_MAX_COLUMNS = 600
#: Largest shift of the shift-invert eigensolve, relative to the largest eigenvalue of
#: ``R^T R`` (tried only when smaller ones leave the factor singular).
SHIFT_REL = 1e-10


def _start(n: int) -> FloatArray:
    """A fixed, generic start vector so that ARPACK runs are reproducible."""
    return np.asarray(1.0 + 0.5 * np.sin(np.arange(n) * 0.7548776662))


def _smallest_singular_dense(mat: sp.csr_matrix) -> tuple[FloatArray, FloatArray]:
    """All singular values of ``mat`` (ascending) and the matching right singular vectors."""
    dense = mat.toarray()
    cols = dense.shape[1]
    full = np.zeros((max(dense.shape[0], cols), cols))
    full[: dense.shape[0]] = dense  # pad so the SVD returns all right singular vectors
    _, sing, vt = np.linalg.svd(full)
    order = np.argsort(sing, kind="stable")
    return np.asarray(sing[order]), np.asarray(vt[order].T)


def _smallest_singular_sparse(
    mat: sp.csr_matrix, tol: float, s_max: float
) -> tuple[FloatArray, FloatArray]:
    """The smallest singular values of ``mat`` (ascending) and their right singular vectors.

    Shift-invert Lanczos on ``R^T R + shift I`` (positive definite, so it factors) finds the
    subspace of the ``k`` smallest; a Rayleigh-Ritz step on ``R`` itself (SVD of ``R Q``) then
    gives singular values accurate to machine precision times ``|R|`` (squaring in ``R^T R``
    alone would lose half the digits).  ``k`` doubles until the largest value found is above
    ``tol``, so the null space is complete.  The shift starts at ``max(tol, 1e-12) ** 2``;
    where that vanishes in rounding next to the Gram matrix's entries and a null space leaves
    the factor exactly singular, it grows a hundredfold per try up to ``SHIFT_REL * s_max ** 2`` (a
    larger shift than needed is avoided: the null space's eigenvalues then look alike to
    Lanczos, which can miss some of them).
    """
    cols = mat.shape[1]
    gram = (mat.T @ mat).tocsc()
    shift = max(tol, 1e-12) ** 2
    k = 24
    while True:
        k = min(k, cols - 1)
        try:
            _, vecs = spla.eigsh(gram, k=k, sigma=-shift, which="LM", v0=_start(cols))
        except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
            if isinstance(exc, spla.ArpackError) or "singular" not in str(exc):
                raise
            if shift >= SHIFT_REL * s_max**2:
                raise
            shift = min(100.0 * shift, SHIFT_REL * s_max**2)
            continue
        q, _ = np.linalg.qr(vecs)
        _, sing, wt = np.linalg.svd(np.asarray(mat @ q), full_matrices=False)
        order = np.argsort(sing, kind="stable")
        sing, right = sing[order], q @ wt[order].T
        if sing[-1] > tol or k == cols - 1:
            return np.asarray(sing), np.asarray(right)
        k *= 2
