"""Projective local-global solver shared by every optimization of the pipeline.

The solver minimizes a sum of constraint-group energies

    E(X) = sum_i w_i * || A_i X - P_i(X) ||_F^2

over vertex positions ``X : (n, dim)`` (Bouaziz et al. 2012, "Shape-Up"; Bouaziz et al. 2014,
"Projective Dynamics"). Each group ``i`` is vectorized over all its elements: a constant sparse
matrix ``A_i`` (rows x n, applied identically to every coordinate column) and a batched
projection ``P_i`` that maps the current ``A_i X`` to the closest point of the group's constraint
set. One iteration is

- local step: ``p_i = P_i(X)`` for every group (one batched numpy call per group);
- global step: ``(sum_i w_i A_i^T A_i + eps I) X' = sum_i w_i A_i^T p_i + eps X``, solved with a
  sparse LU factor that is computed once and reused until the set of groups or a weight changes.

Because each projection is the exact closest point of its set, the alternation never increases
``E`` (the projection step lowers it for fixed ``X``, the global step for fixed projections).

Null space and regularisation
-----------------------------
Groups built from differences (edge lengths, centred planarity, similarity) do not pin
translations, which makes ``sum w A^T A`` singular. The solver always adds a weak proximal term
``eps * ||X' - X||^2`` with ``eps = regularization * mean(diag(sum w A^T A))`` (default ``1e-7``).
It vanishes at a fixed point, never raises the energy, keeps null-space components where they
are, and changes convergence speed by a negligible amount. Vertices listed in ``fixed`` are not
moved at all.

Anderson acceleration
---------------------
With ``anderson = m > 0`` the local-global step is treated as a fixed-point map ``G`` and
accelerated with Anderson mixing over the last ``m`` differences (Peng, Deng, Zhang, Liu 2018,
"Anderson Acceleration for Geometry Optimization and Physics Simulation", ACM TOG 37(4)). The
safeguard evaluates ``E`` at the accelerated iterate (its projections are then reused by the next
global step); when it is not lower than the energy of the last accepted iterate, the iterate is
discarded, the plain local-global step is taken instead and the history is reset. The accepted
energies therefore decrease monotonically exactly as without acceleration. After a rejection
the next attempt waits 1, 2, 4, ... plain steps (up to ``max_backoff``, by default
``ANDERSON_MAX_BACKOFF``), so that stiff problems where acceleration keeps failing do not pay
for a wasted projection every iteration.

Exact planarity
---------------
Soft planarity converges linearly and leaves a residual of order ``w_other / w_planar``;
:func:`planarize_quads` removes it with a few Gauss-Newton minimum-norm steps on the quads'
coplanarity constraints (used after the solves of the assembled stage).

Adding a group
--------------
Subclass :class:`ConstraintGroup`: give ``matrix(n_vertices)`` (the constant ``A``) and
``project(ax, x)`` (batched closest points for the rows of ``A X``). Examples of later groups:
a rigid tile is :class:`EdgeLength` over its 18 edges; a hinge connection is a difference row
``v_a - v_b`` projected to zero; a lift is :class:`ClosenessToPoints` whose targets are moved with
:meth:`ClosenessToPoints.set_targets` (no refactor); an inequality (collision, gap angle) returns
the current value of ``A X`` where it is satisfied so its matrix stays constant. A group whose
projection is expensive may override :meth:`ConstraintGroup.project_warm` with a cheaper
approximate one that is never worse than the last accepted target (see
:class:`ClosenessToSurface`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tolerances import SOLVER_REL_ENERGY_TOL
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.linalg import cross3, plane_fit

logger = logging.getLogger(__name__)


#: Iterations over which the relative energy decrease is averaged by the stopping test.
STOP_WINDOW = 10

#: After a rejected Anderson step, plain steps are taken before the next attempt: 1, 2, 4, ...
#: after consecutive rejections, at most this many (reset by an accepted step).
ANDERSON_MAX_BACKOFF = 16

__all__ = [
    "LinearPull",
    "LocalGlobalSolver",
    "PlanarizeResult",
    "SolverResult",
    "planarize_quads",
    "quad_planarity",
]


# --------------------------------------------------------------------------------------------
# Solver
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SolverResult:
    """Outcome of :meth:`LocalGlobalSolver.solve`.

    Attributes
    ----------
    X : (n, dim) float
        Final positions.
    iterations : int
        Global solves taken (one per iteration).
    converged : bool
        Stopped by ``rel_tol`` / ``abs_tol`` rather than ``max_iter``.
    energy_before, energy_after : dict[str, float]
        Weighted energy ``w ||A X - P(X)||^2`` per group at the start and at the end.
    energy_history : (iterations + 1,) float
        Total energy of every accepted iterate, starting with the initial one.
    time_s : float
    accelerated_accepted, accelerated_rejected : int
        Anderson iterates kept / discarded by the energy safeguard.
    factorizations : int
        Sparse factorizations performed during this solve (0 when a cached factor was reused).
    stopped : bool
        Stopped early by the ``callback`` of :meth:`LocalGlobalSolver.solve`.
    """

    X: FloatArray
    iterations: int
    converged: bool
    energy_before: dict[str, float]
    energy_after: dict[str, float]
    energy_history: FloatArray
    time_s: float
    accelerated_accepted: int
    accelerated_rejected: int
    factorizations: int
    stopped: bool = False

    @property
    def energy_total_before(self) -> float:
        return float(sum(self.energy_before.values()))

    @property
    def energy_total_after(self) -> float:
        return float(sum(self.energy_after.values()))

    @property
    def per_iteration_ms(self) -> float:
        return 1e3 * self.time_s / max(self.iterations, 1)


class LocalGlobalSolver:
    """Local-global solver over a fixed set of constraint groups.

    Parameters
    ----------
    n_vertices : int
    groups : sequence of ConstraintGroup
        Names must be unique.
    fixed : (f,) int, optional
        Vertices that never move.
    regularization : float
        Relative weight of the proximal term ``eps ||X' - X||^2`` (see module docstring).
    lean : bool
        Bitwise the same iterates with fewer temporaries: the per-row energies are summed
        column by column (``sum(axis=1)`` over the ``dim`` columns of a tall ``(rows, dim)``
        array is about 8x slower than adding the columns, which gives the same sums), the
        residuals are squared in place, the groups' rows are cut by precomputed row ranges
        (the views ``np.split`` gives, without its overhead), and when no vertex is fixed the
        global and Anderson steps work on the whole position arrays instead of gathering and
        scattering the free rows (and hand SuperLU the right-hand side without a Fortran
        copy: it makes its own). Off by default (the former code paths).
    """

    def __init__(
        self,
        n_vertices: int,
        groups: Sequence[ConstraintGroup],
        *,
        fixed: ArrayLike | None = None,
        regularization: float = 1e-7,
        lean: bool = False,
    ) -> None:
        if n_vertices <= 0:
            raise InputError("the solver needs at least one vertex")
        if regularization < 0:
            raise InputError("regularization must be >= 0")
        self.n_vertices = int(n_vertices)
        self.regularization = float(regularization)
        self.lean = bool(lean)
        self._groups: list[ConstraintGroup] = []
        fixed_arr = np.unique(np.asarray([] if fixed is None else fixed, dtype=np.int64))
        if fixed_arr.size and (fixed_arr[0] < 0 or fixed_arr[-1] >= n_vertices):
            raise InputError("fixed vertex indices out of range")
        is_free = np.ones(self.n_vertices, dtype=bool)
        is_free[fixed_arr] = False
        self.free = np.flatnonzero(is_free)
        self.fixed = fixed_arr
        self._factor: spla.SuperLU | None = None
        self._matrices: dict[str, sp.csr_matrix] = {}
        for group in groups:
            self.add_group(group)

    # ---- constraint set -----------------------------------------------------------------

    @property
    def groups(self) -> tuple[ConstraintGroup, ...]:
        return tuple(self._groups)

    def group(self, name: str) -> ConstraintGroup:
        """The group called ``name``."""
        for g in self._groups:
            if g.name == name:
                return g
        raise KeyError(name)

    def add_group(self, group: ConstraintGroup) -> None:
        """Add a group (invalidates the factor)."""
        if any(g.name == group.name for g in self._groups):
            raise InputError(f"a group named {group.name!r} already exists; pick another name")
        mat = sp.csr_matrix(group.matrix(self.n_vertices))
        if mat.shape[1] != self.n_vertices:
            raise InputError(f"group {group.name!r} matrix has {mat.shape[1]} columns")
        self._groups.append(group)
        self._matrices[group.name] = mat
        self.invalidate()

    def remove_group(self, name: str) -> None:
        """Remove the group called ``name`` (invalidates the factor)."""
        self._groups = [g for g in self._groups if g.name != name]
        self._matrices.pop(name, None)
        self.invalidate()

    def replace_group(self, group: ConstraintGroup) -> None:
        """Swap the group of the same name for ``group`` (invalidates the factor)."""
        index = next(i for i, g in enumerate(self._groups) if g.name == group.name)
        self._groups[index] = group
        self._matrices[group.name] = sp.csr_matrix(group.matrix(self.n_vertices))
        self.invalidate()

    def set_weight(self, name: str, weight: float) -> None:
        """Change a group's weight (invalidates the factor when it changes)."""
        if not np.isfinite(weight) or weight < 0:
            raise InputError(f"weight of group {name!r} is {weight}; use a finite value >= 0")
        group = self.group(name)
        if group.weight != weight:
            group.weight = float(weight)
            self.invalidate()

    def invalidate(self) -> None:
        """Drop the cached factor (call after changing a group's matrix in place)."""
        self._factor = None

    # ---- assembly -----------------------------------------------------------------------

    def _active(self) -> list[ConstraintGroup]:
        return [g for g in self._groups if g.weight > 0]

    def _assemble(self) -> int:
        """Build the stacked operator and factor the free block; returns factorizations done."""
        if self._factor is not None:
            return 0
        active = self._active()
        if not active:
            raise InputError("no constraint group has a positive weight")
        blocks = [self._matrices[g.name] for g in active]
        self._stack = sp.vstack(blocks, format="csr")
        self._row_weights = np.concatenate(
            [np.full(b.shape[0], g.weight) for g, b in zip(active, blocks, strict=True)]
        )
        self._splits = np.cumsum([b.shape[0] for b in blocks])[:-1]
        ends = [int(e) for e in np.cumsum([b.shape[0] for b in blocks])]
        #: row range of every active group in the stack (the pieces of np.split at _splits)
        self._bounds = list(zip([0, *ends[:-1]], ends, strict=True))
        weighted_t = (self._stack.T @ sp.diags(self._row_weights)).tocsr()
        self._weighted_t = weighted_t
        system = (weighted_t @ self._stack).tocsc()
        free = self.free
        m_ff = system[free][:, free]
        self._m_fc = system[free][:, self.fixed].tocsr()
        diag = m_ff.diagonal()
        self._eps = self.regularization * float(np.mean(diag)) if diag.size else 0.0
        m_ff = (m_ff + self._eps * sp.identity(len(free), format="csc")).tocsc()
        self._factor = spla.splu(
            m_ff,
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        self._active_groups = active
        return 1

    # ---- steps --------------------------------------------------------------------------

    def _local(
        self, x: FloatArray, previous: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Projections of every active group, stacked, and each group's weighted energy.

        ``previous``: the stacked projections of the last accepted iterate, passed to
        :meth:`ConstraintGroup.project_warm` (``None``: exact :meth:`ConstraintGroup.project`).
        """
        ax = self._stack @ x
        parts = self._split(ax)
        if previous is None:
            proj = [g.project(part, x) for g, part in zip(self._active_groups, parts, strict=True)]
        else:
            prev = self._split(previous)
            proj = [
                g.project_warm(part, x, before)
                for g, part, before in zip(self._active_groups, parts, prev, strict=True)
            ]
        stacked = np.concatenate(proj, axis=0)
        if self.lean:
            resid = ax - stacked
            np.square(resid, out=resid)
            per_row = resid[:, 0].copy()  # the same sums as resid.sum(axis=1), in that order
            for k in range(1, resid.shape[1]):
                per_row += resid[:, k]
            per_row *= self._row_weights
        else:
            resid = (ax - stacked) ** 2
            per_row = resid.sum(axis=1) * self._row_weights
        energies = np.array([p.sum() for p in self._split(per_row)])
        return stacked, energies

    def _split(self, rows: FloatArray) -> list[FloatArray]:
        """``rows`` (stacked over the active groups) cut into each group's rows (views)."""
        if self.lean:  # the same views as np.split, without its overhead
            return [rows[a:b] for a, b in self._bounds]
        return np.split(rows, self._splits)

    def _global(self, proj: FloatArray, x: FloatArray, rhs_fixed: FloatArray) -> FloatArray:
        assert self._factor is not None
        if self.lean and not self.fixed.size:  # all free: rhs_fixed is zero
            rhs = np.asarray(self._weighted_t @ proj)
            rhs += self._eps * x
            # SuperLU copies the right-hand side to Fortran order itself
            return np.ascontiguousarray(self._factor.solve(rhs))
        rhs = (self._weighted_t @ proj)[self.free] - rhs_fixed + self._eps * x[self.free]
        out = x.copy()
        out[self.free] = self._factor.solve(np.asfortranarray(rhs))
        return out

    def energies(self, x: ArrayLike) -> dict[str, float]:
        """Weighted energy of every group (zero-weight groups report 0) at ``x``.

        Parameters
        ----------
        x : (n, dim) float
        """
        arr = np.asarray(x, dtype=np.float64)
        self._assemble()
        _, energies = self._local(arr)
        return self._energy_dict(energies)

    def _energy_dict(self, energies: FloatArray) -> dict[str, float]:
        out = {g.name: 0.0 for g in self._groups}
        for g, e in zip(self._active_groups, energies, strict=True):
            out[g.name] = float(e)
        return out

    # ---- main loop ----------------------------------------------------------------------

    def solve(
        self,
        x0: ArrayLike,
        *,
        rel_tol: float = SOLVER_REL_ENERGY_TOL,
        abs_tol: float = 0.0,
        max_iter: int = 1000,
        anderson: int = 5,
        callback: Callable[[int, FloatArray], bool] | None = None,
        max_backoff: int = ANDERSON_MAX_BACKOFF,
        anderson_gram: bool = False,
    ) -> SolverResult:
        """Run local-global iterations from ``x0``.

        Parameters
        ----------
        x0 : (n, dim) float
            Start positions; ``fixed`` vertices keep these values.
        rel_tol : float
            Stop when the total energy falls by less than ``rel_tol`` times itself per iteration,
            on average over the last ``STOP_WINDOW`` iterations (fewer at the start). A negative
            value switches this test off (e.g. to run ``max_iter`` iterations from a zero-energy
            start, where any ``rel_tol >= 0`` stops after the first iteration).
        abs_tol : float
            Stop when the total energy is at most this (mm^2, weighted).
        max_iter : int
            Maximum number of iterations (global solves).
        anderson : int
            Anderson history length ``m``; 0 switches acceleration off.
        callback : callable, optional
            ``callback(iteration, x) -> bool`` after every iteration with the accepted
            positions (do not modify them); returning ``True`` stops the solve there
            (``SolverResult.stopped``, not ``converged``). Not called when converged.
        max_backoff : int
            Most plain steps taken before the next Anderson attempt after consecutive
            rejections (see the module docstring; default :data:`ANDERSON_MAX_BACKOFF`).
        anderson_gram : bool
            Solve Anderson's least-squares problem ``min |F theta - f|`` through its small
            ``m x m`` Gram matrix ``F^T F`` instead of LAPACK's ``lstsq`` on the tall ``F``: the
            same mixing up to round-off (the energy safeguard rejects a poor one), and much
            cheaper for long vectors. ``lstsq`` on a tall matrix is also where a multithreaded
            BLAS sharing the cores with other work can stall: 15-25 ms instead of 0.3 ms for a
            (5000, 8) problem on a 2-core machine. Off by default (bitwise the former
            iterations).

        Returns
        -------
        SolverResult
        """
        start = time.perf_counter()
        x = np.array(x0, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] != self.n_vertices or not np.all(np.isfinite(x)):
            raise InputError(
                f"start positions must be a finite ({self.n_vertices}, dim) array, got {x.shape}"
            )
        if max_iter < 0 or anderson < 0 or max_backoff < 0:
            raise InputError("max_iter, anderson and max_backoff must be >= 0")
        factorizations = self._assemble()
        if self.fixed.size:
            rhs_fixed = np.asarray(self._m_fc @ x[self.fixed])
        else:
            rhs_fixed = np.zeros((len(self.free), x.shape[1]))

        proj, energies = self._local(x)
        before = self._energy_dict(energies)
        energy = float(energies.sum())
        history = [energy]
        accepted = rejected = 0
        converged = energy <= abs_tol
        dim = x.shape[1]
        diff_f: list[FloatArray] = []
        diff_g: list[FloatArray] = []
        prev_f: FloatArray | None = None
        prev_g: FloatArray | None = None
        skip = backoff = 0
        iterations = 0
        stopped = False
        whole = self.lean and not self.fixed.size  # Anderson vectors are views of whole arrays
        while not converged and not stopped and iterations < max_iter:
            iterations += 1
            plain = self._global(proj, x, rhs_fixed)
            if anderson > 0:
                if whole:
                    g_vec = plain.reshape(-1)
                    f_vec = g_vec - x.reshape(-1)
                else:
                    g_vec = plain[self.free].reshape(-1)
                    f_vec = g_vec - x[self.free].reshape(-1)
                if prev_f is not None and prev_g is not None:
                    diff_f.append(f_vec - prev_f)
                    diff_g.append(g_vec - prev_g)
                    if len(diff_f) > anderson:
                        diff_f.pop(0)
                        diff_g.pop(0)
                prev_f, prev_g = f_vec, g_vec
                if diff_f and skip == 0:
                    if anderson_gram:
                        rows_f = np.stack(diff_f)
                        theta = np.linalg.lstsq(rows_f @ rows_f.T, rows_f @ f_vec, rcond=None)[0]
                        mixed = g_vec - theta @ np.stack(diff_g)
                    else:
                        mat_f = np.stack(diff_f, axis=1)
                        theta = np.linalg.lstsq(mat_f, f_vec, rcond=None)[0]
                        mixed = g_vec - np.stack(diff_g, axis=1) @ theta
                    if whole:
                        candidate = mixed.reshape(-1, dim)
                    else:
                        candidate = x.copy()
                        candidate[self.free] = mixed.reshape(-1, dim)
                    cand_proj, cand_energies = self._local(candidate, proj)
                    cand_energy = float(cand_energies.sum())
                    if np.isfinite(cand_energy) and cand_energy < energy:
                        accepted += 1
                        backoff = 0
                        x, proj, energies = candidate, cand_proj, cand_energies
                    else:
                        rejected += 1
                        backoff = min(2 * backoff if backoff else 1, max_backoff)
                        skip = backoff
                        diff_f.clear()
                        diff_g.clear()
                        x = plain
                        proj, energies = self._local(x, proj)
                else:
                    skip = max(skip - 1, 0)
                    x = plain
                    proj, energies = self._local(x, proj)
            else:
                x = plain
                proj, energies = self._local(x, proj)
            new_energy = float(energies.sum())
            history.append(new_energy)
            # relative decrease per iteration, averaged over a window so that one unlucky
            # iteration (e.g. right after an Anderson reset) does not stop a slow descent
            span = min(STOP_WINDOW, iterations)
            if new_energy <= abs_tol or (
                rel_tol >= 0 and history[-1 - span] - new_energy <= span * rel_tol * new_energy
            ):
                converged = True
            energy = new_energy
            if callback is not None and not converged and callback(iterations, x):
                stopped = True

        elapsed = time.perf_counter() - start
        logger.debug(
            "local-global: %d iterations, energy %.3e -> %.3e, %.3f s (AA %d/%d)",
            iterations,
            history[0],
            history[-1],
            elapsed,
            accepted,
            rejected,
        )
        return SolverResult(
            X=x,
            iterations=iterations,
            converged=converged,
            energy_before=before,
            energy_after=self._energy_dict(energies),
            energy_history=np.asarray(history),
            time_s=elapsed,
            accelerated_accepted=accepted,
            accelerated_rejected=rejected,
            factorizations=factorizations,
            stopped=stopped,
        )


# --------------------------------------------------------------------------------------------
# Exact planarity by Gauss-Newton projection
# --------------------------------------------------------------------------------------------


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
