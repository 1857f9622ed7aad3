"""Exact planarity of quads by Gauss-Newton projection.

Soft planarity in the local-global solver (:mod:`drawstring.geometry.solve.solver`) converges
linearly and leaves a residual of order ``w_other / w_planar``; :func:`planarize_quads` removes
it with a few Gauss-Newton minimum-norm steps on the quads' coplanarity constraints (used after
the solves of the assembled stage). :func:`quad_planarity` measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.solve.linalg import cross3, plane_fit

__all__ = ["LinearPull", "PlanarizeResult", "planarize_quads", "quad_planarity"]


@dataclass(frozen=True)
class PlanarizeResult:
    """Outcome of :func:`planarize_quads`.

    Attributes
    ----------
    X : (n, 3) float, mm
    iterations : int
    planarity_before_mm, planarity_after_mm : float
        Max vertex distance to its face's best-fit plane over all quads.
    max_move_mm : float
        Largest vertex displacement.
    """

    X: FloatArray
    iterations: int
    planarity_before_mm: float
    planarity_after_mm: float
    max_move_mm: float


def quad_planarity(x: FloatArray, quads: IntArray) -> FloatArray:
    """Max distance of each quad's vertices to the quad's best-fit plane.

    Parameters
    ----------
    x : (n, 3) float, mm
    quads : (k, 4) int

    Returns
    -------
    distance : (k,) float, mm
    """
    pts = x[quads]
    centroids, normals = plane_fit(pts)
    return np.max(np.abs(np.einsum("ksi,ki->ks", pts - centroids[:, None], normals)), axis=1)


@dataclass(frozen=True)
class LinearPull:
    """Conditions ``directions[i] . X[vertices[i]] = targets[i]`` wanted with ``weight`` by
    :func:`planarize_quads` (each on one vertex, so its metric is block diagonal)."""

    vertices: IntArray
    directions: FloatArray
    targets: FloatArray
    weight: float

    def residuals(self, x: FloatArray) -> FloatArray:
        return np.asarray(np.einsum("ki,ki->k", self.directions, x[self.vertices]) - self.targets)

    def gradient(self, x: FloatArray) -> FloatArray:
        """``weight * C^T (C x - targets)``, flattened like ``x``."""
        out = np.zeros_like(x)
        np.add.at(out, self.vertices, self.weight * self.residuals(x)[:, None] * self.directions)
        return out.reshape(-1)

    def metric_inverse(self, n: int, movable: BoolArray) -> sp.csr_matrix:
        """``(I + weight C^T C)^-1`` over the movable coordinates (block diagonal)."""
        blocks = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        outer = self.weight * self.directions[:, :, None] * self.directions[:, None, :]
        np.add.at(blocks, self.vertices, outer)
        inverse = np.linalg.inv(blocks)
        rows = (3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
        cols = (3 * np.arange(n)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
        full = sp.csr_matrix((inverse.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))
        keep = np.flatnonzero(np.repeat(movable, 3))
        return full[keep][:, keep].tocsr()


def planarize_quads(
    x: ArrayLike,
    quads: ArrayLike,
    *,
    fixed: ArrayLike | None = None,
    tol_mm: float = 0.0,
    max_iter: int = 8,
    pull: LinearPull | None = None,
) -> PlanarizeResult:
    """Nearest configuration with every quad exactly planar (Gauss-Newton, minimum-norm steps).

    Each quad contributes the scalar constraint ``det[v1 - v0, v2 - v0, v3 - v0] = 0`` (scaled by
    its size). Every step moves the vertices by the least-norm correction
    ``dX = -J^T (J J^T + delta I)^{-1} c`` of the linearized constraints, so the result stays as
    close as possible to ``x``; convergence is quadratic from a nearly planar start, as left by
    the local-global solver. Intended as a final polish, not as a design energy.

    Parameters
    ----------
    x : (n, 3) float, mm
    quads : (k, 4) int
    fixed : (f,) int, optional
        Vertices that must not move.
    tol_mm : float
        Stop when every quad's planarity (max vertex-to-plane distance) is at most this.
    max_iter : int
    pull : LinearPull, optional
        Linear conditions on single vertices, wanted in the least-squares sense: the result is
        then the planar configuration nearest ``x`` in ``|X - x|^2 + pull.weight *
        |pull residual|^2`` (each step minimizes that for the linearized constraints, from the
        current point), and it runs all ``max_iter`` steps unless they stop moving.

    Returns
    -------
    PlanarizeResult
    """
    x_start = np.array(x, dtype=np.float64)
    pos = x_start.copy()
    quad_arr = np.asarray(quads, dtype=np.int64)
    n = len(pos)
    movable = np.ones(n, dtype=bool)
    if fixed is not None:
        movable[np.asarray(fixed, dtype=np.int64)] = False
    col_mask = np.repeat(movable, 3)
    before = float(quad_planarity(pos, quad_arr).max(initial=0.0))
    size = np.linalg.norm(pos[quad_arr[:, 2]] - pos[quad_arr[:, 0]], axis=1)
    size = np.maximum(size, 1e-300)
    scale = 1.0 / size**2
    k = len(quad_arr)
    rows = np.repeat(np.arange(k), 12)
    cols = (3 * quad_arr[:, :, None] + np.arange(3)[None, None, :]).reshape(k, 12).reshape(-1)
    iterations = 0
    after = before
    metric_inv = None if pull is None else pull.metric_inverse(n, movable)
    while iterations < max_iter and (after > tol_mm or pull is not None):
        p0, p1, p2, p3 = (pos[quad_arr[:, a]] for a in range(4))
        e1, e2, e3 = p1 - p0, p2 - p0, p3 - p0
        g1 = cross3(e2, e3)
        g2 = cross3(e3, e1)
        g3 = cross3(e1, e2)
        value = np.einsum("ki,ki->k", e1, g1) * scale
        grads = np.stack([-(g1 + g2 + g3), g1, g2, g3], axis=1) * scale[:, None, None]
        jac = sp.csr_matrix((grads.reshape(-1), (rows, cols)), shape=(k, 3 * n))
        jac = jac[:, np.flatnonzero(col_mask)] if not movable.all() else jac
        if pull is None or metric_inv is None:
            normal_eq = (jac @ jac.T).tocsc()
            delta = 1e-12 * float(normal_eq.diagonal().mean())
            normal_eq = normal_eq + delta * sp.identity(k, format="csc")
            lam = spla.splu(normal_eq, permc_spec="MMD_AT_PLUS_A").solve(value)
            step = jac.T @ lam
        else:
            # min |s|_M^2 + 2 grad.s  subject to  jac s = -value  (M = I + w C^T C)
            grad = (pos - x_start).reshape(-1)[col_mask] + pull.gradient(pos)[col_mask]
            scaled_grad = metric_inv @ grad
            normal_eq = (jac @ metric_inv @ jac.T).tocsc()
            delta = 1e-12 * float(normal_eq.diagonal().mean())
            normal_eq = normal_eq + delta * sp.identity(k, format="csc")
            lam = spla.splu(normal_eq, permc_spec="MMD_AT_PLUS_A").solve(value - jac @ scaled_grad)
            step = scaled_grad + metric_inv @ (jac.T @ lam)
        flat = pos.reshape(-1)
        flat[col_mask] -= step
        pos = flat.reshape(n, 3)
        iterations += 1
        new_after = float(quad_planarity(pos, quad_arr).max(initial=0.0))
        if pull is not None:
            after = new_after
            if after <= tol_mm and float(np.abs(step).max(initial=0.0)) <= tol_mm:
                break
            continue
        if new_after >= after and iterations > 1:
            after = new_after
            break
        after = new_after
    return PlanarizeResult(
        X=pos,
        iterations=iterations,
        planarity_before_mm=before,
        planarity_after_mm=after,
        max_move_mm=float(np.linalg.norm(pos - x_start, axis=1).max(initial=0.0)),
    )
