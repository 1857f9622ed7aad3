"""Boundary First Flattening core: the mesh system, its one factorization and boundary solves.

The numerics behind :func:`drawstring.geometry.flatten.conformal.flatten` (see that module's
docstring for the method): disk checks and precomputation (cotangent Laplacian blocks, angle
defects, boundary turning angles, the sparse LU of ``A_II``), the Dirichlet-to-Neumann Schur
complement and Neumann-to-Dirichlet solve on that factorization, length closing of the boundary
curve and the harmonic extension into the interior. The free mode is in
:mod:`~drawstring.geometry.flatten.conformal`, the rectangle mode in
:mod:`~drawstring.geometry.flatten.rectangle`, the automatic corner choice in
:mod:`~drawstring.geometry.flatten.corner_scores` and the principal-direction alignment in
:mod:`~drawstring.geometry.flatten.alignment`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import igl
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.tolerances import (
    DEGENERATE_FACE_REL_AREA,
    FLATTEN_MIN_CLOSED_LENGTH_REL,
    FLATTEN_SCHUR_NULL_REL,
)
from drawstring.geometry.core.types import FloatArray, IntArray

#: Right-hand sides per SuperLU triangular solve call (see ``solve_interior``).
SOLVE_BLOCK_COLUMNS = 4
#: Largest dense block ``Z`` (rows x columns) for the elimination-tree Schur complement solve.
SCHUR_DENSE_MAX_ENTRIES = 10_000_000
#: Unit direction (mm-free) that picks where the boundary loop starts: the boundary vertex
#: farthest along it from the boundary's centroid. Generic on purpose (no symmetry plane of a
#: built-in target is perpendicular to it), pointing towards -x, -y, -z.
LOOP_START_DIRECTION = np.array([-0.80, -0.53, -0.27]) / np.linalg.norm([0.80, 0.53, 0.27])


@dataclass(frozen=True)
class BffSystem:
    """Everything BFF needs about one mesh, computed once (internal)."""

    n: int
    faces: IntArray  # (m, 3)
    interior: IntArray  # (nI,) vertex ids
    boundary: IntArray  # (k,) vertex ids, counter-clockwise loop
    A_IB: sp.csc_matrix  # (nI, k) block of the positive semi-definite cotangent Laplacian
    A_BB: sp.csc_matrix  # (k, k)
    lu: spla.SuperLU | None  # factorization of A_II (None when there is no interior vertex)
    omega: FloatArray  # (nI,) angle defect, rad
    turning: FloatArray  # (k,) boundary exterior angle pi - angle sum, rad
    edge_length: FloatArray  # (k,) length of boundary edge b[i] -> b[i+1], mm
    face_area: FloatArray  # (m,) 3D face area, mm^2
    mass: FloatArray  # (n,) vertex area (a third of the incident face areas), mm^2
    area: float  # total surface area, mm^2
    vertices: FloatArray | None = None  # (n, 3) 3D positions, mm


# --------------------------------------------------------------------------------------------
# mesh checks and precomputation


def boundary_loop(V: FloatArray, F: NDArray[np.generic]) -> IntArray:
    """Check that (V, F) is a disk and return its boundary loop, counter-clockwise.

    The loop follows the direction the boundary edges have in their faces, so the surface lies to
    its left. It starts at the boundary vertex farthest along ``LOOP_START_DIRECTION`` from the
    boundary's centroid, so the start (and every choice that walks the loop from it, such as the
    automatic rectangle corners) depends on the surface, not on how its vertices are numbered.
    """
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0 or not np.all(np.isfinite(V)):
        raise InternalError(f"vertices must be a finite (n, 3) array, got shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0 or not np.issubdtype(F.dtype, np.integer):
        raise InternalError(f"faces must be an (m, 3) integer array, got shape {F.shape}")
    n = len(V)
    if F.min() < 0 or F.max() >= n:
        raise InternalError(f"faces index vertices outside 0..{n - 1}; fix the face list")
    Fi = F.astype(np.int64)
    if np.any((Fi[:, 0] == Fi[:, 1]) | (Fi[:, 1] == Fi[:, 2]) | (Fi[:, 2] == Fi[:, 0])):
        raise InternalError("some faces repeat a vertex; remove degenerate faces")
    used = np.bincount(Fi.ravel(), minlength=n) > 0
    if not used.all():
        raise InternalError(
            f"{int(n - used.sum())} vertices are not used by any face; remove unreferenced vertices"
        )
    tail = Fi.ravel()
    head = Fi[:, [1, 2, 0]].ravel()
    key = tail * n + head
    sorted_keys = np.sort(key)
    if np.any(sorted_keys[1:] == sorted_keys[:-1]):
        raise InternalError(
            "a directed edge appears in two faces: faces are inconsistently oriented or an edge "
            "is non-manifold; orient and repair the mesh"
        )
    twin = head * n + tail
    at = np.minimum(np.searchsorted(sorted_keys, twin), len(sorted_keys) - 1)
    has_twin = sorted_keys[at] == twin
    b_tail, b_head = tail[~has_twin], head[~has_twin]
    n_edges = (len(key) + len(b_tail)) // 2
    euler = n - n_edges + len(Fi)
    if len(b_tail) == 0:
        raise InternalError("the mesh is closed (no boundary); cut it open into a disk first")
    if np.any(np.bincount(b_tail, minlength=n) > 1):
        raise InternalError("a boundary vertex is non-manifold (pinched); repair the mesh")
    successor = np.full(n, -1, dtype=np.int64)
    successor[b_tail] = b_head
    loop = [int(b_tail.min())]
    for _ in range(len(b_tail) - 1):
        nxt = int(successor[loop[-1]])
        if nxt == loop[0]:
            break
        loop.append(nxt)
    if len(loop) != len(b_tail):
        raise InternalError(
            "the mesh has more than one boundary loop; flatten needs a disk (fill holes or cut)"
        )
    if euler != 1:
        raise InternalError(
            f"the mesh has Euler characteristic {euler}, not 1: it is not a disk; cut it open"
        )
    ring = np.asarray(loop, dtype=np.int64)
    reach = (V[ring] - V[ring].mean(axis=0)) @ LOOP_START_DIRECTION
    return np.roll(ring, -int(np.argmax(reach)))


def _corner_angles(V: FloatArray, F: IntArray) -> FloatArray:
    """(m, 3) float, rad, interior angle of each face at each of its corners."""
    P = V[F]
    angles = np.empty(F.shape, dtype=np.float64)
    for c in range(3):
        a = P[:, (c + 1) % 3] - P[:, c]
        b = P[:, (c + 2) % 3] - P[:, c]
        angles[:, c] = np.arctan2(
            np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)
        )
    return angles


def build_system(V: FloatArray, F: IntArray, boundary: IntArray) -> BffSystem:
    """Cotangent Laplacian blocks, curvatures, lengths and the one factorization of ``A_II``."""
    n = len(V)
    double_area = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    if np.any(double_area <= DEGENERATE_FACE_REL_AREA * double_area.mean()):
        raise InternalError("the mesh has zero-area faces; remove or repair degenerate triangles")
    is_boundary = np.zeros(n, dtype=bool)
    is_boundary[boundary] = True
    interior = np.flatnonzero(~is_boundary)
    A = (-igl.cotmatrix(V, F)).tocsr()
    A_I = A[interior]
    A_IB = A_I[:, boundary].tocsc()
    A_BB = A[boundary][:, boundary].tocsc()
    angle_sum = np.bincount(F.ravel(), weights=_corner_angles(V, F).ravel(), minlength=n)
    mass = np.bincount(F.ravel(), weights=np.repeat(double_area / 6.0, 3), minlength=n)
    lu = None
    if len(interior):
        lu = spla.splu(
            A_I[:, interior].tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    edge_length = np.linalg.norm(V[np.roll(boundary, -1)] - V[boundary], axis=1)
    return BffSystem(
        n=n,
        faces=F,
        interior=interior,
        boundary=boundary,
        A_IB=A_IB,
        A_BB=A_BB,
        lu=lu,
        omega=np.asarray(2.0 * math.pi - angle_sum[interior], dtype=np.float64),
        turning=np.asarray(math.pi - angle_sum[boundary], dtype=np.float64),
        edge_length=edge_length,
        face_area=0.5 * double_area,
        mass=np.asarray(mass, dtype=np.float64),
        area=float(double_area.sum() / 2.0),
        vertices=V,
    )


def order_corners(boundary: IntArray, corners: Sequence[int]) -> IntArray:
    """Positions in the boundary loop of four named corners, ``corners[0]`` first, then CCW."""
    ids = np.asarray(corners).ravel()
    if ids.shape != (4,) or not np.issubdtype(ids.dtype, np.integer):
        raise InputError(f"corners must be 4 vertex ids, got {list(np.asarray(corners).ravel())}")
    if len(np.unique(ids)) != 4:
        raise InputError(f"corners must be 4 distinct vertex ids, got {ids.tolist()}")
    position = np.full(int(max(boundary.max(), ids.max())) + 1, -1, dtype=np.int64)
    position[boundary] = np.arange(len(boundary))
    pos = np.where(ids >= 0, position[np.clip(ids, 0, None)], -1)
    if np.any(pos < 0):
        raise InputError(
            f"corner vertices {ids[pos < 0].tolist()} are not on the mesh boundary; "
            "pick boundary vertex ids"
        )
    return np.asarray(pos[np.argsort((pos - pos[0]) % len(boundary))], dtype=np.int64)


# --------------------------------------------------------------------------------------------
# linear algebra on the one factorization


def solve_interior(system: BffSystem, rhs: FloatArray) -> FloatArray:
    """Solve ``A_II x = rhs`` for one or more right-hand sides, (nI,) or (nI, c).

    Columns go to SuperLU a few at a time (``SOLVE_BLOCK_COLUMNS``): as fast as one wide solve
    on an idle machine, and it keeps the BLAS calls small enough to stay single-threaded, which
    avoids multi-threaded BLAS stalls when the cores are busy.
    """
    if system.lu is None:
        return np.zeros_like(rhs)
    if rhs.ndim == 1:
        return np.asarray(system.lu.solve(rhs), dtype=np.float64)
    out = np.empty_like(rhs, dtype=np.float64)
    for start in range(0, rhs.shape[1], SOLVE_BLOCK_COLUMNS):
        block = slice(start, start + SOLVE_BLOCK_COLUMNS)
        out[:, block] = system.lu.solve(np.asfortranarray(rhs[:, block]))
    return out


def schur_complement(system: BffSystem) -> FloatArray:
    """(k, k) dense Dirichlet-to-Neumann matrix ``S = A_BB - A_BI A_II^-1 A_IB``.

    Uses ``P A_II P^T = L D L^T`` from the symmetric LU: the solve ``Z = L^-1 P A_IB`` is confined
    to the elimination-tree ancestors of the interior vertices next to the boundary. Falls back to
    full multi-right-hand-side solves if the factorization pivoted off the diagonal.
    """
    A_BB = system.A_BB.toarray()
    lu = system.lu
    if lu is None:
        return A_BB
    A_IB = system.A_IB
    n_i = A_IB.shape[0]
    reach = None
    if np.array_equal(lu.perm_r, lu.perm_c):
        L = lu.L  # CSC, unit diagonal stored first in each column
        if not L.has_sorted_indices:
            L.sort_indices()
        parent = np.full(n_i, n_i, dtype=np.int64)  # n_i stands for "root"
        has_parent = np.diff(L.indptr) > 1
        parent[has_parent] = L.indices[L.indptr[:-1][has_parent] + 1]
        PC = A_IB.tocsr()[np.argsort(lu.perm_r)]
        starts = np.flatnonzero(np.diff(PC.indptr))
        # Elimination-tree ancestors of the start rows: search from an extra source vertex.
        src = n_i + 1
        tree = sp.csr_matrix(
            (
                np.ones(n_i + len(starts)),
                (np.append(np.arange(n_i), np.full(len(starts), src)), np.append(parent, starts)),
            ),
            shape=(n_i + 2, n_i + 2),
        )
        found = csgraph.breadth_first_order(tree, src, directed=True, return_predecessors=False)
        reach = np.sort(found[found < n_i])
        if len(reach) * A_IB.shape[1] > SCHUR_DENSE_MAX_ENTRIES:
            reach = None
    if reach is None:
        W = solve_interior(system, A_IB.toarray())
        S = A_BB - (A_IB.T @ W)
    else:
        local = np.full(n_i, -1, dtype=np.int64)
        local[reach] = np.arange(len(reach))
        L_cols = L[:, reach]
        L_rr = sp.csc_matrix(
            (L_cols.data, local[L_cols.indices], L_cols.indptr), shape=(len(reach), len(reach))
        )
        Z = spla.spsolve_triangular(L_rr, PC[reach].toarray(), lower=True, unit_diagonal=True)
        d = lu.U.diagonal()[reach]
        S = A_BB - Z.T @ (Z / d[:, None])
    return np.asarray(0.5 * (S + S.T), dtype=np.float64)


def neumann_solve(S: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve ``S x = rhs`` on the boundary, with ``S`` singular only along the constants.

    Uses a Cholesky factorization of ``S + c 1 1^T`` (``c`` the mean diagonal entry over ``k``),
    which is positive definite and agrees with ``S`` up to an added constant in ``x``: for a
    right-hand side that sums to zero (a compatible Neumann problem) it returns the mean-zero
    solution, and the map is linear, so sums of such columns stay consistent. Falls back to an
    eigen-decomposition pseudo-inverse if the factorization fails.

    Parameters
    ----------
    S : (k, k) float, the Dirichlet-to-Neumann matrix.
    rhs : (k,) or (k, c) float.
    """
    k = len(S)
    shifted = S + float(np.trace(S)) / (k * k)
    try:
        factor = sla.cho_factor(shifted, lower=True, check_finite=False)
        return np.asarray(sla.cho_solve(factor, rhs, check_finite=False), dtype=np.float64)
    except np.linalg.LinAlgError:
        evals, evecs = np.linalg.eigh(S)
        keep = evals > FLATTEN_SCHUR_NULL_REL * max(float(evals[-1]), 1e-300)
        return np.asarray(
            (evecs[:, keep] / evals[keep]) @ (evecs[:, keep].T @ rhs), dtype=np.float64
        )


# --------------------------------------------------------------------------------------------
# boundary curve and extension


def close_lengths(lengths: FloatArray, tangents: FloatArray, weights: FloatArray) -> FloatArray:
    """Closest lengths ``x`` to ``lengths`` with ``sum x_e T_e = 0``.

    Minimizes ``sum_e (x_e - l_e)^2 / w_e`` subject to the closing condition (BFF eq. for the
    length-closing step, with ``w_e`` the original 3D edge length).

    Parameters
    ----------
    lengths : (k,) float, mm, target edge lengths.
    tangents : (k, 2) float, unit edge directions.
    weights : (k,) float, mm, how freely each edge may change.
    """
    T = tangents.T  # (2, k)
    gram = (T * weights) @ T.T
    lam = np.linalg.solve(gram, T @ lengths)
    return np.asarray(lengths - weights * (T.T @ lam), dtype=np.float64)


def harmonic_extension(system: BffSystem, boundary_uv: FloatArray) -> FloatArray:
    """(n, 2) float: boundary positions extended harmonically (cotangent weights) inside."""
    uv = np.empty((system.n, 2), dtype=np.float64)
    uv[system.boundary] = boundary_uv
    if len(system.interior):
        uv[system.interior] = solve_interior(system, -(system.A_IB @ boundary_uv))
    return uv


def scaled_lengths(system: BffSystem, u_boundary: FloatArray) -> FloatArray:
    """(k,) float, mm: boundary edge lengths scaled by ``exp`` of the mean endpoint factor."""
    return np.asarray(
        system.edge_length * np.exp(0.5 * (u_boundary + np.roll(u_boundary, -1))), dtype=np.float64
    )


def check_lengths(closed: FloatArray, target: FloatArray) -> bool:
    return bool(np.all(closed > FLATTEN_MIN_CLOSED_LENGTH_REL * target))
