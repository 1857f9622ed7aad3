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
:func:`~drawstring.geometry.solve.planarity.planarize_quads` removes it with a few Gauss-Newton
minimum-norm steps on the quads' coplanarity constraints (used after the solves of the assembled
stage).

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

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import SOLVER_REL_ENERGY_TOL
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.solve.groups import ConstraintGroup

logger = logging.getLogger(__name__)


#: Iterations over which the relative energy decrease is averaged by the stopping test.
STOP_WINDOW = 10

#: After a rejected Anderson step, plain steps are taken before the next attempt: 1, 2, 4, ...
#: after consecutive rejections, at most this many (reset by an accepted step).
ANDERSON_MAX_BACKOFF = 16

__all__ = ["LocalGlobalSolver", "SolverResult"]


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
        copy: it makes its own). Off by default.
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
            raise InternalError("the solver needs at least one vertex")
        if regularization < 0:
            raise InternalError("regularization must be >= 0")
        self.n_vertices = int(n_vertices)
        self.regularization = float(regularization)
        self.lean = bool(lean)
        self._groups: list[ConstraintGroup] = []
        fixed_arr = np.unique(np.asarray([] if fixed is None else fixed, dtype=np.int64))
        if fixed_arr.size and (fixed_arr[0] < 0 or fixed_arr[-1] >= n_vertices):
            raise InternalError("fixed vertex indices out of range")
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
            raise InternalError(f"a group named {group.name!r} already exists; pick another name")
        mat = sp.csr_matrix(group.matrix(self.n_vertices))
        if mat.shape[1] != self.n_vertices:
            raise InternalError(f"group {group.name!r} matrix has {mat.shape[1]} columns")
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
            raise InternalError(f"weight of group {name!r} is {weight}; use a finite value >= 0")
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
            raise InternalError("no constraint group has a positive weight")
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
            same mixing up to round-off (the energy safeguard rejects a poor one), much cheaper
            for long vectors, and clear of the tall ``lstsq``, which stalls when a multithreaded
            BLAS shares the cores with other work. Off by default.

        Returns
        -------
        SolverResult
        """
        start = time.perf_counter()
        x = self._start_positions(x0)
        if max_iter < 0 or anderson < 0 or max_backoff < 0:
            raise InternalError("max_iter, anderson and max_backoff must be >= 0")
        factorizations = self._assemble()
        rhs_fixed = self._fixed_rhs(x)
        proj, energies = self._local(x)
        before = self._energy_dict(energies)
        energy = float(energies.sum())
        history = [energy]
        mixing = _AndersonMixing(anderson, max_backoff, anderson_gram)
        converged = energy <= abs_tol
        iterations = 0
        stopped = False
        while not converged and not stopped and iterations < max_iter:
            iterations += 1
            x, proj, energies = self._iterate(x, proj, energy, rhs_fixed, mixing)
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
            mixing.accepted,
            mixing.rejected,
        )
        return SolverResult(
            X=x,
            iterations=iterations,
            converged=converged,
            energy_before=before,
            energy_after=self._energy_dict(energies),
            energy_history=np.asarray(history),
            time_s=elapsed,
            accelerated_accepted=mixing.accepted,
            accelerated_rejected=mixing.rejected,
            factorizations=factorizations,
            stopped=stopped,
        )

    def _start_positions(self, x0: ArrayLike) -> FloatArray:
        """``x0`` as a float copy, checked to be finite and one row per vertex."""
        x = np.array(x0, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] != self.n_vertices or not np.all(np.isfinite(x)):
            raise InternalError(
                f"start positions must be a finite ({self.n_vertices}, dim) array, got {x.shape}"
            )
        return x

    def _fixed_rhs(self, x: FloatArray) -> FloatArray:
        """The fixed vertices' constant share ``M_fc X_c`` of the free block's right-hand side."""
        if self.fixed.size:
            return np.asarray(self._m_fc @ x[self.fixed])
        return np.zeros((len(self.free), x.shape[1]))

    def _iterate(
        self,
        x: FloatArray,
        proj: FloatArray,
        energy: float,
        rhs_fixed: FloatArray,
        mixing: _AndersonMixing,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One iteration from the accepted iterate ``x`` (its projections ``proj`` and total
        ``energy``): the global step, then the Anderson-mixed iterate when the history allows
        one and the safeguard accepts it, else the plain step. Returns the new accepted iterate,
        its projections and its per-group energies."""
        plain = self._global(proj, x, rhs_fixed)
        if mixing.depth == 0:
            return (plain, *self._local(plain, proj))
        whole = self.lean and not self.fixed.size  # Anderson vectors are views of whole arrays
        if whole:
            g_vec = plain.reshape(-1)
            f_vec = g_vec - x.reshape(-1)
        else:
            g_vec = plain[self.free].reshape(-1)
            f_vec = g_vec - x[self.free].reshape(-1)
        mixing.push(f_vec, g_vec)
        if not mixing.ready():
            mixing.wait()
            return (plain, *self._local(plain, proj))
        mixed = mixing.mixed(f_vec, g_vec)
        if whole:
            candidate = mixed.reshape(-1, x.shape[1])
        else:
            candidate = x.copy()
            candidate[self.free] = mixed.reshape(-1, x.shape[1])
        cand_proj, cand_energies = self._local(candidate, proj)
        cand_energy = float(cand_energies.sum())
        if np.isfinite(cand_energy) and cand_energy < energy:
            mixing.accept()
            return candidate, cand_proj, cand_energies
        mixing.reject()
        return (plain, *self._local(plain, proj))


class _AndersonMixing:
    """Anderson acceleration state of one solve: the last ``depth`` differences of the residuals
    ``f = G(x) - x`` and of the images ``g = G(x)``, and the backoff after rejected steps.

    Parameters
    ----------
    depth : int
        History length ``m``; 0 switches acceleration off.
    max_backoff : int
        Most plain steps taken before the next attempt after consecutive rejections.
    gram : bool
        Solve the mixing least-squares problem through its ``m x m`` Gram matrix.
    """

    def __init__(self, depth: int, max_backoff: int, gram: bool) -> None:
        self.depth = depth
        self.max_backoff = max_backoff
        self.gram = gram
        self.diff_f: list[FloatArray] = []
        self.diff_g: list[FloatArray] = []
        self.prev_f: FloatArray | None = None
        self.prev_g: FloatArray | None = None
        self.skip = 0
        self.backoff = 0
        #: Mixed iterates kept / discarded by the energy safeguard.
        self.accepted = 0
        self.rejected = 0

    def push(self, f_vec: FloatArray, g_vec: FloatArray) -> None:
        """Record this iteration's residual and image (keeps the last ``depth`` differences)."""
        if self.prev_f is not None and self.prev_g is not None:
            self.diff_f.append(f_vec - self.prev_f)
            self.diff_g.append(g_vec - self.prev_g)
            if len(self.diff_f) > self.depth:
                self.diff_f.pop(0)
                self.diff_g.pop(0)
        self.prev_f, self.prev_g = f_vec, g_vec

    def ready(self) -> bool:
        """A mixed iterate can be tried now (a history exists and no backoff is pending)."""
        return bool(self.diff_f) and self.skip == 0

    def wait(self) -> None:
        """One plain step taken instead of a mixed one (counts down the backoff)."""
        self.skip = max(self.skip - 1, 0)

    def mixed(self, f_vec: FloatArray, g_vec: FloatArray) -> FloatArray:
        """The Anderson-mixed image ``g - dG theta`` with ``theta = argmin |dF theta - f|``."""
        if self.gram:
            rows_f = np.stack(self.diff_f)
            theta = np.linalg.lstsq(rows_f @ rows_f.T, rows_f @ f_vec, rcond=None)[0]
            return np.asarray(g_vec - theta @ np.stack(self.diff_g))
        mat_f = np.stack(self.diff_f, axis=1)
        theta = np.linalg.lstsq(mat_f, f_vec, rcond=None)[0]
        return np.asarray(g_vec - np.stack(self.diff_g, axis=1) @ theta)

    def accept(self) -> None:
        """The mixed iterate lowered the energy and was kept."""
        self.accepted += 1
        self.backoff = 0

    def reject(self) -> None:
        """The mixed iterate did not lower the energy: wait 1, 2, 4, ... plain steps (at most
        ``max_backoff``) before the next attempt, and start a new history."""
        self.rejected += 1
        self.backoff = min(2 * self.backoff if self.backoff else 1, self.max_backoff)
        self.skip = self.backoff
        self.diff_f.clear()
        self.diff_g.clear()
