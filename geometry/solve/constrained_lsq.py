"""Least squares under inequality rows: the solver of the flat layout and the joint solve.

:func:`constrained_least_squares` minimizes a least-squares objective over 2D positions (or any
variables packed as a ``(rows, 2)`` array) subject to blocks of inequality rows
``values(x) >= 0``: :class:`AngleRows` (an angle at a junction within bounds) and
:class:`SeparationRows` (two points kept apart along a direction).  It is an augmented
Lagrangian whose subproblems are solved by Levenberg-Marquardt, one sparse factorization per
step.  :class:`EdgeLeastSquares` is the flat layout's objective (edge lengths to targets).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.constraints import signed_angles
from drawstring.geometry.solve.spd import SpdSolver, upper_triangle, with_diagonal

logger = logging.getLogger(__name__)


__all__ = [
    "AngleRows",
    "EdgeLeastSquares",
    "LeastSquares",
    "SeparationRows",
    "constrained_least_squares",
    "separation_rows",
]


#: Largest Levenberg-Marquardt damping (relative to the diagonal of ``J^T J``).  Its steps are
#: already 1e-12 of a gradient step.  A subproblem that cannot descend (the three-shell's joint
#: solve at the CLI's default size) stops at this bound instead of multiplying the damping by 8
#: for every refused trial until it overflows and every round factors an infinite matrix.
LM_DAMPING_MAX = 1e12


def _csr_rows(
    cols: IntArray,
    vals: FloatArray,
    n_cols: int,
    pattern: _RowPattern | None = None,
) -> sp.csr_matrix:
    """The sparse matrix with ``cols.shape[1]`` entries per row (columns ``cols``, values
    ``vals``), built directly in canonical CSR form: the matrix ``csr_matrix((vals, (rows,
    cols)))`` would give, without its coordinate sorting, when no row repeats a column.
    ``pattern`` is :func:`_row_pattern` of ``cols``, where the caller keeps it."""
    k, width = cols.shape
    if pattern is None:
        pattern = _row_pattern(cols)
    if pattern is None:  # a row repeats a column
        rows = np.repeat(np.arange(k), width)
        return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(k, n_cols))
    order, indices, indptr = pattern
    v = np.take_along_axis(vals, order, axis=1)
    return sp.csr_matrix((v.ravel(), indices, indptr), shape=(k, n_cols))


#: Per row, the order of its columns, then the CSR column indices and row pointers.
_RowPattern = tuple[IntArray, NDArray[np.int32], NDArray[np.int32]]


def _row_pattern(cols: IntArray) -> _RowPattern | None:
    """How :func:`_csr_rows` sorts ``cols`` ``(k, width)`` into CSR form (None: a row repeats
    a column)."""
    k, width = cols.shape
    order = np.argsort(cols, axis=1, kind="stable")
    c = np.take_along_axis(cols, order, axis=1)
    if width > 1 and np.any(c[:, 1:] == c[:, :-1]):
        return None
    indptr = np.arange(0, k * width + 1, width, dtype=np.int32)
    return order, c.ravel().astype(np.int32), indptr


@dataclass(frozen=True)
class AngleRows:
    """Inequalities ``lo <= angle(apex, q, p) + offset <= hi`` (rad) at junctions.

    ``arm`` (mm) scales each row so that its value is a length (angle times a typical arm),
    comparable with the edge residuals.  Angles are read in ``(branch, branch + 2 pi]``, so a
    reflex angle (a concave component boundary) is not mistaken for an inverted one.
    """

    elements: IntArray
    offset: FloatArray
    lo: FloatArray
    hi: FloatArray
    arm: FloatArray
    branch: float = -np.pi

    @property
    def n_rows(self) -> int:
        return 2 * len(self.elements)

    def angles(self, x: FloatArray) -> FloatArray:
        """Angles ``(k,)`` in rad, offsets included."""
        e = self.elements
        raw = signed_angles(x[e[:, 1]] - x[e[:, 0]], x[e[:, 2]] - x[e[:, 0]]) + self.offset
        return np.where(raw <= self.branch, raw + 2.0 * np.pi, raw)

    def values(self, x: FloatArray) -> FloatArray:
        """``(2k,)`` mm: lower-bound rows then upper-bound rows (``>= 0`` where they hold)."""
        ang = self.angles(x)
        return np.concatenate([self.arm * (ang - self.lo), self.arm * (self.hi - ang)])

    def jacobian(self, x: FloatArray, rows: IntArray) -> sp.csr_matrix:
        """Gradient rows ``(len(rows), 2n)`` of :meth:`values` for the given row ids."""
        k = len(self.elements)
        el = self.elements[rows % k]
        sign = np.where(rows < k, 1.0, -1.0) * self.arm[rows % k]
        u = x[el[:, 1]] - x[el[:, 0]]
        v = x[el[:, 2]] - x[el[:, 0]]
        du = -np.stack([-u[:, 1], u[:, 0]], axis=1) / np.einsum("ki,ki->k", u, u)[:, None]
        dv = np.stack([-v[:, 1], v[:, 0]], axis=1) / np.einsum("ki,ki->k", v, v)[:, None]
        vals = sign[:, None] * np.concatenate([-(du + dv), du, dv], axis=1)
        cols = np.stack([2 * el, 2 * el + 1], axis=2).reshape(-1, 6)
        return _csr_rows(cols, vals, 2 * len(x))


@dataclass(frozen=True)
class SeparationRows:
    """Linear inequalities ``n . (x_b - x_a) >= margin`` keeping two tiles apart along ``n``."""

    a: IntArray
    b: IntArray
    normal: FloatArray
    margin: FloatArray

    @property
    def n_rows(self) -> int:
        return len(self.a)

    def values(self, x: FloatArray) -> FloatArray:
        return np.einsum("ki,ki->k", x[self.b] - x[self.a], self.normal) - self.margin

    def jacobian(self, x: FloatArray, rows: IntArray) -> sp.csr_matrix:
        a, b, nrm = self.a[rows], self.b[rows], self.normal[rows]
        cols = np.stack([2 * a, 2 * a + 1, 2 * b, 2 * b + 1], axis=1)
        vals = np.concatenate([-nrm, nrm], axis=1)
        return _csr_rows(cols, vals, 2 * len(x))


def separation_rows(
    corner_node: IntArray, pairs: IntArray, normals: FloatArray, margin: float
) -> SeparationRows:
    """Rows keeping every corner of tile ``b`` beyond every corner of tile ``a`` along the pair's
    axis (16 rows per pair, less the rows of a node both tiles share)."""
    na = np.repeat(corner_node[pairs[:, 0]], 4, axis=1).ravel()
    nb = np.tile(corner_node[pairs[:, 1]], (1, 4)).ravel()
    nrm = np.repeat(normals, 16, axis=0)
    keep = na != nb
    return SeparationRows(na[keep], nb[keep], nrm[keep], np.full(int(keep.sum()), margin))


class LeastSquares(Protocol):
    """A least-squares objective for :func:`constrained_least_squares`: residuals and their sparse
    Jacobian over the flattened ``(rows, 2)`` position array."""

    def residual(self, x: FloatArray) -> FloatArray: ...

    def residual_jacobian(self, x: FloatArray) -> tuple[FloatArray, sp.csr_matrix]: ...


@dataclass
class EdgeLeastSquares:
    """``sum w (|x_j - x_i| - L)^2`` with its Gauss-Newton Jacobian."""

    edges: IntArray
    targets: FloatArray
    sqrt_w: FloatArray

    def __post_init__(self) -> None:
        e = self.edges
        self._cols = np.stack([2 * e[:, 0], 2 * e[:, 0] + 1, 2 * e[:, 1], 2 * e[:, 1] + 1], axis=1)
        self._pattern = _row_pattern(self._cols)  # the edges, and so the pattern, are fixed

    def residual_jacobian(self, x: FloatArray) -> tuple[FloatArray, sp.csr_matrix]:
        e = self.edges
        d = x[e[:, 1]] - x[e[:, 0]]
        length = np.linalg.norm(d, axis=1)
        unit = d / np.maximum(length, 1e-300)[:, None]
        vals = self.sqrt_w[:, None] * np.concatenate([-unit, unit], axis=1)
        jac = _csr_rows(self._cols, vals, 2 * len(x), self._pattern)
        return self.sqrt_w * (length - self.targets), jac

    def residual(self, x: FloatArray) -> FloatArray:
        d = x[self.edges[:, 1]] - x[self.edges[:, 0]]
        return self.sqrt_w * (np.linalg.norm(d, axis=1) - self.targets)


#: Shortest share of a failed step that :func:`constrained_least_squares` tries (its
#: ``line_search``) before it factors a damped step instead.
SECANT_MIN_STEP = 1e-3


def _secant_minimum(
    r0: FloatArray, r1: FloatArray, c0: FloatArray, c1: FloatArray, rho: float
) -> float:
    """Where on ``[0, 1]`` the cost ``|r|^2 + sum max(0, c)^2 / (2 rho)`` is least when the
    residuals ``r`` and penalty arguments ``c`` move linearly from their values at the start of
    a step (``r0``, ``c0``) to those at its end (``r1``, ``c1``): exact for that piecewise
    quadratic model."""
    dr = r1 - r0
    dc = c1 - c0
    scale = 0.5 / rho
    # quadratic a t^2 + b t + e of the residuals and of the rows active just after t = 0
    a = float(dr @ dr)
    b = 2.0 * float(r0 @ dr)
    e = float(r0 @ r0)
    on = (c0 > 0) | ((c0 == 0) & (dc > 0))
    a += scale * float(dc[on] @ dc[on])
    b += scale * 2.0 * float(c0[on] @ dc[on])
    e += scale * float(c0[on] @ c0[on])
    # rows that switch on (dc > 0) or off (dc < 0) inside (0, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -c0 / dc
    cross = np.flatnonzero((dc != 0) & (t > 0) & (t < 1))
    order = cross[np.argsort(t[cross], kind="stable")]
    sign = np.where(dc[order] > 0, 1.0, -1.0) * scale
    da = np.concatenate([[a], a + np.cumsum(sign * dc[order] ** 2)])
    db = np.concatenate([[b], b + np.cumsum(sign * 2.0 * c0[order] * dc[order])])
    de = np.concatenate([[e], e + np.cumsum(sign * c0[order] ** 2)])
    lo = np.concatenate([[0.0], t[order]])
    hi = np.concatenate([t[order], [1.0]])
    # each piece's vertex (where it is convex) and both its ends
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(da > 0, np.clip(-db / (2.0 * da), lo, hi), lo)
    candidates = np.concatenate([vertex, lo, hi])
    value = (np.tile(da, 3) * candidates + np.tile(db, 3)) * candidates + np.tile(de, 3)
    value = np.where(np.isfinite(value), value, np.inf)  # a NaN would hide a finite least
    return float(candidates[int(np.argmin(value))])


class _Subproblem:
    """The least-squares subproblem of the augmented Lagrangian: the objective's residuals and,
    for multipliers ``lam`` and penalty ``rho``, the penalty rows
    ``max(0, lam - rho g) / sqrt(2 rho)`` of the constraint blocks' values ``g``.

    The residuals and row values of the last point evaluated are kept: a trial that is accepted
    becomes the next step's point, whose row values (and, at a multiplier update, residuals)
    are then not computed again.  Points are never changed in place.
    """

    def __init__(
        self, objective: LeastSquares, constraints: list[AngleRows | SeparationRows]
    ) -> None:
        self.objective = objective
        self.constraints = constraints
        sizes = [c.n_rows for c in constraints]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        #: Constraint rows over all blocks.
        self.n_rows = int(self.offsets[-1])
        self._last: list[tuple[FloatArray, FloatArray, FloatArray]] = []

    def values(self, x: FloatArray) -> FloatArray:
        """Every block's row values at ``x``, stacked."""
        if not self.constraints:
            return np.zeros(0)
        return np.concatenate([c.values(x) for c in self.constraints])

    def jacobian_rows(self, x: FloatArray, act: IntArray) -> list[sp.csr_matrix]:
        """Gradient rows of the stacked rows ``act``, one matrix per block that has some."""
        out = []
        for k, c in enumerate(self.constraints):
            sel = act[(act >= self.offsets[k]) & (act < self.offsets[k + 1])] - self.offsets[k]
            if sel.size:
                out.append(c.jacobian(x, sel))
        return out

    def evaluated(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The residuals and row values at ``x`` (kept for the last point asked)."""
        if not (self._last and self._last[0][0] is x):
            self._last[:] = [(x, self.objective.residual(x), self.values(x))]
        return self._last[0][1], self._last[0][2]

    def cost(self, x: FloatArray, lam: FloatArray, rho: float) -> float:
        """The subproblem's cost: squared residuals plus squared penalty rows."""
        r, g = self.evaluated(x)
        pen, _ = _penalty_rows(g, lam, rho)
        return float(r @ r + pen @ pen)

    def normal_system(self, x: FloatArray, lam: FloatArray, rho: float) -> _NormalSystem:
        """The Gauss-Newton system ``J^T J s = -J^T r`` of the subproblem at ``x``."""
        r, jac = self.objective.residual_jacobian(x)
        pen, act = _penalty_rows(self.evaluated(x)[1], lam, rho)
        blocks = [jac]
        if act.size:
            blocks += self.jacobian_rows(x, act)
            for block in blocks[1:]:
                block.data *= -np.sqrt(0.5 * rho)
        jr = sp.vstack(blocks, format="csr")
        res = np.concatenate([r, pen])
        jtj = (jr.T @ jr).tocsc()
        grad = jr.T @ res
        diag = jtj.diagonal()
        scale = float(diag.mean()) if diag.size else 1.0
        # The upper triangle once per step; the damping changes only its diagonal, the
        # last entry of every column once every diagonal entry is stored (a variable no
        # residual touches, e.g. the joint solve's padding, has none in J^T J: it gets an
        # explicit zero, the same matrix as adding the damping as a diagonal matrix).
        jtj.sum_duplicates()  # sorted for upper_triangle: the product may leave them unsorted
        upper = with_diagonal(upper_triangle(jtj))
        at = upper.indptr[1:] - 1
        return _NormalSystem(upper, at, upper.data[at].copy(), diag, scale, grad)


@dataclass(frozen=True)
class _NormalSystem:
    """Upper triangle of ``J^T J`` (``upper``; its diagonal entries at ``upper.data[at]``, their
    undamped values ``base``), the diagonal ``diag`` and its mean ``scale``, and ``J^T r``."""

    upper: sp.csc_matrix
    at: IntArray
    base: FloatArray
    diag: FloatArray
    scale: float
    grad: FloatArray


def _penalty_rows(g: FloatArray, lam: FloatArray, rho: float) -> tuple[FloatArray, IntArray]:
    """The active penalty rows ``max(0, lam - rho g) / sqrt(2 rho)`` and their row ids."""
    c = np.maximum(0.0, lam - rho * g)
    act = np.flatnonzero(c > 0)
    return c[act] / np.sqrt(2.0 * rho), act


def _row_tolerances(
    constraints: list[AngleRows | SeparationRows], angle_tol: float, length_tol: float
) -> FloatArray:
    """Violation tolerance of each row, mm (angle rows: angle tolerance times the arm)."""
    return np.concatenate(
        [
            np.tile(c.arm * angle_tol, 2)
            if isinstance(c, AngleRows)
            else np.full(c.n_rows, length_tol)
            for c in constraints
        ]
        or [np.zeros(0)]
    )


@dataclass
class _LevenbergMarquardt:
    """Levenberg-Marquardt on the subproblems of one solve: the damping ``mu`` and the count of
    factorizations carry over from one multiplier round to the next."""

    max_steps: int
    line_search: bool
    mu: float = 1e-4
    steps: int = 0
    factor: SpdSolver = field(default_factory=SpdSolver)

    def minimize(
        self, problem: _Subproblem, x: FloatArray, lam: FloatArray, rho: float
    ) -> tuple[FloatArray, float]:
        """Steps from ``x`` until the cost stops falling (or the factorizations run out);
        returns the point reached and the largest coordinate move of a step taken."""
        moved = 0.0
        c0 = problem.cost(x, lam, rho)
        for _inner in range(40):
            if self.steps >= self.max_steps:
                break
            x, improved, decrease, c0, step = self._step(problem, x, lam, rho, c0)
            if improved:
                moved = max(moved, float(np.abs(step).max()))
            if not improved or decrease <= 1e-14 * max(c0, 1e-30) or np.abs(step).max() < 1e-10:
                break
        return x, moved

    def _step(
        self, problem: _Subproblem, x: FloatArray, lam: FloatArray, rho: float, c0: float
    ) -> tuple[FloatArray, bool, float, float, FloatArray]:
        """One step from ``x`` (cost ``c0``), raising the damping until a trial lowers the cost.

        Returns the new point, whether it moved, the cost decrease, the new cost and the step
        (the one taken when it moved, else the last one tried).
        """
        n = len(x)
        system = problem.normal_system(x, lam, rho)
        r0, g0 = problem.evaluated(x)
        for _try in range(8):
            system.upper.data[system.at] = system.base + (
                self.mu * system.diag + 1e-10 * system.scale
            )
            step = self.factor.solve_upper(system.upper, -system.grad)
            self.steps += 1
            trial = x + step.reshape(n, 2)
            c1 = problem.cost(trial, lam, rho)
            if not c1 < c0 and self.line_search:
                # Most failed steps run into rows that were inactive where the step was
                # computed; the point along it where the residuals and rows, interpolated
                # between its ends, cost least is tried before a damped step is factored.
                r1, g1 = problem.evaluated(trial)
                alpha = _secant_minimum(r0, r1, lam - rho * g0, lam - rho * g1, rho)
                if SECANT_MIN_STEP < alpha < 1.0 - 1e-12:  # (at 1: the trial itself)
                    short = x + alpha * step.reshape(n, 2)
                    c_short = problem.cost(short, lam, rho)
                    if c_short < c0:
                        return short, True, c0 - c_short, c_short, alpha * step
            if c1 < c0:
                self.mu = max(self.mu / 3.0, 1e-12)
                return trial, True, c0 - c1, c1, step
            if self.mu >= LM_DAMPING_MAX:
                break  # stalled: a larger damping only repeats a vanishing step
            self.mu = min(self.mu * 8.0, LM_DAMPING_MAX)
        return x, False, 0.0, c0, step


def constrained_least_squares(
    x0: FloatArray,
    objective: LeastSquares,
    constraints: list[AngleRows | SeparationRows],
    *,
    max_steps: int,
    angle_tol: float,
    length_tol: float,
    rho0: float = 10.0,
    feasible_stop: int | None = None,
    line_search: bool = False,
) -> tuple[FloatArray, int, float]:
    """Minimize the edge energy subject to ``values >= 0`` of every constraint block.

    Augmented Lagrangian (multipliers ``lam``, penalty ``rho``) whose subproblems ``sum w r^2 + sum
    max(0, lam - rho g)^2 / (2 rho)`` are least-squares problems solved by Levenberg-Marquardt
    (Gauss-Newton steps, one sparse factorization each, reusing the ordering while the pattern
    repeats: :class:`~drawstring.geometry.solve.spd.SpdSolver`). Gauge freedom (rigid motions) is
    removed by a tiny diagonal term.  Stops when every row holds to within its tolerance
    (``angle_tol`` rad for angle rows, ``length_tol`` mm for separation rows) and the positions have
    settled, or after ``max_steps`` factorizations.  With ``feasible_stop``, once that many
    factorizations are used it also stops at the end of the first multiplier round whose rows all
    hold, settled or not (a feasible start for another solver, e.g. the co-optimization's).  With
    ``line_search``, a step that raises the cost is first shortened to the least of the cost along
    it, modelled from its two ends (:func:`_secant_minimum`), before the damping is raised and the
    system factored again: most failed steps run into rows inactive where the step was computed,
    and a raised damping takes several refactorizations to rise and several steps to fall again.

    Returns
    -------
    x : (n, 2) float, mm
    steps : int
        Factorizations used.
    violation : float
        Largest remaining violation in units of the row tolerances (``<= 1``: converged).
    """
    x = x0.copy()
    problem = _Subproblem(objective, constraints)
    m = problem.n_rows
    row_tol = _row_tolerances(constraints, angle_tol, length_tol)
    lam = np.zeros(m)
    rho = rho0
    solver = _LevenbergMarquardt(max_steps, line_search)
    prev_viol = np.inf
    violation = 0.0
    for _outer in range(60):
        x, moved = solver.minimize(problem, x, lam, rho)
        # --- multiplier update ------------------------------------------------------------
        g = problem.evaluated(x)[1]
        viol_rows = np.maximum(-g, 0.0) / row_tol if m else np.zeros(0)
        violation = float(viol_rows.max(initial=0.0))  # in units of the tolerance
        lam = np.maximum(0.0, lam - rho * g)
        logger.debug(
            "flat AL round %d: violation %.3g tol, rho %.3g, steps %d",
            _outer,
            violation,
            rho,
            solver.steps,
        )
        if solver.steps >= max_steps:
            break
        if violation <= 1.0 and moved < 1e-7:
            break
        if feasible_stop is not None and solver.steps >= feasible_stop and violation <= 1.0:
            break
        if violation > 0.25 * prev_viol:
            rho = min(rho * 10.0, 1e8 * rho0)
        prev_viol = violation
    return x, solver.steps, violation
