"""Repeated sparse solves with symmetric positive definite matrices of a recurring pattern.

The Levenberg-Marquardt loops of the flat layout, the co-optimization and the rigid hinge
layout factor one normal matrix ``J^T J + damping`` per step.  Its sparsity pattern changes
only when inequality rows become active or inactive, so :class:`SpdSolver` keeps one pattern,
the union of the patterns seen so far, with qdldl's fill-reducing ordering and elimination
tree for it, and refactors only numerically (the matrix's entries scattered into the union,
zeros elsewhere) until a matrix brings an entry outside it.  qdldl's ``LDL^T`` without
pivoting is stable on positive definite matrices.  On one that is not, qdldl may refuse it,
return non-finite values or, when refactoring, keep its previous factor without a word; so
every answer's backward error is checked (:data:`BACKWARD_ERROR_TOL`) and a failed one is
solved again with SuperLU.

qdldl factors column by column.  On large matrices (the co-optimization's joint K2D + K3D
normal matrix at 1600 tiles: 11604 unknowns, 233k stored entries, 1.1M in the factor) that
costs 0.13 s per factorization, where CHOLMOD's supernodal Cholesky, which works on dense
blocks with BLAS, takes 0.03 s on one thread.  Patterns of at least
:data:`SUPERNODAL_MIN_ENTRIES` stored entries are therefore factored by CHOLMOD (through
cvxopt, whose wheels bundle SuiteSparse): its symbolic analysis is kept with the union
pattern, and each matrix is only refactored numerically.  Smaller ones (every matrix of a
200-tile design) stay with qdldl.
"""

from __future__ import annotations

import cvxopt
import cvxopt.cholmod
import numpy as np
import qdldl
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from drawstring.geometry.core.types import FloatArray, IntArray

__all__ = [
    "BACKWARD_ERROR_TOL",
    "SUPERNODAL_MIN_ENTRIES",
    "SpdSolver",
    "upper_triangle",
    "with_diagonal",
]

#: Largest accepted normwise backward error ``|A x - b| / (|A| |x| + |b|)`` (infinity norms) of
#: a qdldl answer, with ``|A|`` bounded from above (see :func:`_backward_error`); a stable
#: ``LDL^T`` of a positive definite matrix stays near machine precision, a stale or broken
#: factor is off by order one.
BACKWARD_ERROR_TOL = 1e-8

#: Union patterns with at least this many stored upper-triangle entries are factored by
#: CHOLMOD's supernodal Cholesky instead of qdldl.  Measured on one thread (numeric
#: factorization of a kept analysis): 11604 unknowns and 233k entries (the 1600-tile joint
#: solve), qdldl 134 ms, CHOLMOD 31 ms; 6560 and 49k (the 1600-tile flat layout), 10.1 ms
#: against 6.9 ms (1600-tile saddle layout 22 -> 20 s); 1628 and 31k (a 200-tile joint
#: solve), 3.3 ms against 1.7 ms, but the other ordering changes the last bits and with them
#: every 200-tile design for a few hundredths of a second, so those stay with qdldl.
SUPERNODAL_MIN_ENTRIES = 40_000


def upper_triangle(matrix: sp.csc_matrix) -> sp.csc_matrix:
    """The upper triangle (diagonal included) of a canonical CSC matrix (sorted indices, no
    duplicates), canonical too: what ``sp.triu(matrix, format="csc")`` gives, entry for entry,
    without its round trip through coordinates (a third of its time)."""
    n = matrix.shape[1]
    cols = np.repeat(np.arange(n, dtype=matrix.indices.dtype), np.diff(matrix.indptr))
    keep = matrix.indices <= cols
    indptr = np.zeros(n + 1, dtype=matrix.indptr.dtype)
    np.cumsum(np.bincount(cols[keep], minlength=n), out=indptr[1:])
    upper = sp.csc_matrix((matrix.data[keep], matrix.indices[keep], indptr), shape=matrix.shape)
    upper.has_canonical_format = True
    return upper


def with_diagonal(upper: sp.csc_matrix) -> sp.csc_matrix:
    """A canonical upper triangle (:func:`upper_triangle`) with every diagonal entry stored,
    the missing ones as explicit zeros, so that each column ends with its diagonal entry."""
    n = upper.shape[1]
    ends = upper.indptr[1:]
    filled = ends > upper.indptr[:-1]
    last = np.full(n, -1, dtype=np.int64)
    last[filled] = upper.indices[ends[filled] - 1]
    missing = np.flatnonzero(last != np.arange(n))
    if missing.size == 0:
        return upper
    at = ends[missing]  # the end of each such column
    added = np.zeros(n, dtype=upper.indptr.dtype)
    added[missing] = 1
    indptr = upper.indptr.copy()
    indptr[1:] += np.cumsum(added)
    out = sp.csc_matrix(
        (
            np.insert(upper.data, at, 0.0),
            np.insert(upper.indices, at, missing.astype(upper.indices.dtype)),
            indptr,
        ),
        shape=upper.shape,
    )
    out.has_canonical_format = True
    return out


def _upper_keys(upper: sp.csc_matrix) -> IntArray:
    """Entry keys ``column * n + row`` of a canonical CSC matrix, ascending."""
    n = upper.shape[0]
    cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(upper.indptr))
    return cols * n + upper.indices.astype(np.int64)


def _widest_row(upper: sp.csc_matrix) -> int:
    """Most stored entries in one row of the symmetric matrix whose upper triangle (a
    canonical CSC matrix) is ``upper``."""
    n = upper.shape[0]
    in_row = np.bincount(upper.indices, minlength=n)  # row i: the diagonal and right of it
    in_col = np.diff(upper.indptr)  # column i: the diagonal and above it (left of it in row i)
    filled = np.flatnonzero(in_col)
    on_diagonal = np.zeros(n, dtype=np.int64)  # a column's last entry is its diagonal one
    on_diagonal[filled] = upper.indices[upper.indptr[filled + 1] - 1] == filled
    return int((in_row + in_col - on_diagonal).max(initial=0))


def _backward_error(
    upper: sp.csc_matrix, x: FloatArray, b: FloatArray, widest: int | None = None
) -> float:
    """Normwise backward error of ``x`` as a solution of ``A x = b``, ``A`` the symmetric
    matrix of which ``upper`` is the upper triangle (inf: not finite).  The infinity norm of
    ``A`` is bounded by its largest entry times ``widest`` (:func:`_widest_row`, found here if
    not given): at most that many times too lenient, against a tolerance that tells a stable
    factorization from a broken one by many orders of magnitude."""
    if not np.all(np.isfinite(x)):
        return float("inf")
    diagonal = upper.diagonal()
    product = upper @ x + upper.T @ x - diagonal * x
    if widest is None:
        widest = _widest_row(upper)
    norm = float(np.abs(upper.data).max(initial=0.0)) * widest
    scale = norm * float(np.abs(x).max(initial=0.0))
    scale += float(np.abs(b).max(initial=0.0))
    residual = float(np.abs(product - b).max(initial=0.0))
    return residual / scale if scale > 0 else residual


class SpdSolver:
    """Solve ``A x = b`` for a sequence of symmetric positive definite sparse ``A`` of one size.

    Examples
    --------
    >>> solver = SpdSolver()
    >>> x = solver.solve(sp.identity(3, format="csc") * 2.0, np.ones(3))
    >>> bool(np.allclose(x, 0.5))
    True
    """

    def __init__(self) -> None:
        self._solver: qdldl.Solver | None = None
        self._keys: IntArray = np.zeros(0, dtype=np.int64)  # the union pattern
        self._indptr: NDArray[np.int32] = np.zeros(0, dtype=np.int32)
        self._indices: NDArray[np.int32] = np.zeros(0, dtype=np.int32)
        # the last matrix's own pattern and where its entries sit in the union
        self._last: tuple[NDArray[np.int32], NDArray[np.int32]] | None = None
        self._pos: IntArray = np.zeros(0, dtype=np.int64)
        self._widest = 0  # of the last matrix's pattern (:func:`_widest_row`)
        self._union = sp.csc_matrix((0, 0))  # the union pattern, refilled for every matrix
        #: the union pattern as a cvxopt matrix and CHOLMOD's symbolic factor of it, when it
        #: is large enough (:data:`SUPERNODAL_MIN_ENTRIES`)
        self._cholmod: tuple[cvxopt.spmatrix, object | None] | None = None
        #: numeric refactorizations in a known pattern, and symbolic analyses
        self.reused = 0
        self.analysed = 0

    def reserve(self, pattern: sp.spmatrix | sp.sparray) -> None:
        """Make room in the factored pattern for every entry of the symmetric ``pattern`` (its
        values are not read), so that matrices within it are refactored numerically only,
        without a new symbolic analysis each time the pattern grows."""
        canonical = sp.csc_matrix(pattern, copy=True)
        canonical.sum_duplicates()
        if len(self._keys) and canonical.shape != self._union.shape:
            raise ValueError(
                f"reserve: a {canonical.shape} pattern for a solver of {self._union.shape} matrices"
            )
        keys = _upper_keys(upper_triangle(canonical))
        if len(keys) and not np.isin(keys, self._keys, assume_unique=True).all():
            self._set_union(np.union1d(self._keys, keys), canonical.shape[0])
            self._last = None

    def solve(self, matrix: sp.spmatrix | sp.sparray, rhs: FloatArray) -> FloatArray:
        """``x`` with ``matrix @ x = rhs``; ``matrix`` ``(n, n)`` symmetric positive definite
        (only its upper triangle is read)."""
        canonical = sp.csc_matrix(matrix, copy=True)
        canonical.sum_duplicates()  # sorted, no duplicates
        return self.solve_upper(upper_triangle(canonical), rhs)

    def solve_upper(self, upper: sp.csc_matrix, rhs: FloatArray) -> FloatArray:
        """:meth:`solve` given the matrix's upper triangle as a canonical CSC matrix (sorted
        indices, no duplicates), e.g. one whose diagonal the caller changes between solves."""
        n = upper.shape[0]
        last = self._last
        if not (
            last is not None
            and np.array_equal(last[0], upper.indptr)
            and np.array_equal(last[1], upper.indices)
        ):
            keys = _upper_keys(upper)
            pos = np.searchsorted(self._keys, keys)
            inside = pos < len(self._keys)
            inside[inside] = self._keys[pos[inside]] == keys[inside]
            if (self._solver is None and self._cholmod is None) or not inside.all():
                # the union and the new keys are both ascending: a stable sort merges the two
                # runs in linear time, and says where each old and new key lands
                both = np.concatenate([self._keys, keys[~inside]])
                order = np.argsort(both, kind="stable")
                landed = np.empty(len(both), dtype=np.int64)
                landed[order] = np.arange(len(both))
                pos[inside] = landed[pos[inside]]
                pos[~inside] = landed[len(self._keys) :]
                self._set_union(both[order], n)
            self._last, self._pos = (upper.indptr.copy(), upper.indices.copy()), pos
            self._widest = _widest_row(upper)
        union = self._union
        union.data[:] = 0.0
        union.data[self._pos] = upper.data
        b = np.asarray(rhs, dtype=np.float64)
        x: FloatArray | None = None
        if self._cholmod is not None:
            x = self._solve_supernodal(union.data, b)
        else:
            try:
                if self._solver is None:
                    self._solver = qdldl.Solver(union, upper=True)
                    self.analysed += 1
                else:
                    self._solver.update(union, upper=True)
                    self.reused += 1
                x = np.asarray(self._solver.solve(b))
            except RuntimeError:  # qdldl refuses a zero pivot it meets while analysing
                pass
        if x is not None and _backward_error(upper, x, b, self._widest) <= BACKWARD_ERROR_TOL:
            return x
        # not numerically positive definite: a pivoting factorization; analyse afresh next time
        # (CHOLMOD's symbolic factor depends on the pattern alone and is kept)
        self._solver, self._last = None, None
        full = sp.csc_matrix(upper + sp.triu(upper, k=1, format="csc").T)
        return np.asarray(spla.splu(full, permc_spec="MMD_AT_PLUS_A").solve(b))

    def _set_union(self, keys: IntArray, n: int) -> None:
        """Make ``keys`` the pattern factored from now on (a new symbolic analysis)."""
        cols, rows = np.divmod(keys, n)
        self._keys = keys
        self._indices = rows.astype(np.int32)
        self._indptr = np.searchsorted(cols, np.arange(n + 1)).astype(np.int32)
        self._union = sp.csc_matrix(
            (np.zeros(len(keys)), self._indices, self._indptr), shape=(n, n)
        )
        self._solver = None
        self._cholmod = None
        if len(keys) >= SUPERNODAL_MIN_ENTRIES:
            # cvxopt keeps the entries given (explicit zeros too) in the same column-major,
            # row-sorted order, so the union's values can be handed over as they are
            pattern = cvxopt.spmatrix(
                cvxopt.matrix(np.zeros(len(keys))),
                cvxopt.matrix(rows.astype(np.int64)),
                cvxopt.matrix(cols.astype(np.int64)),
                (n, n),
            )
            self._cholmod = (pattern, None)

    def _solve_supernodal(self, values: FloatArray, b: FloatArray) -> FloatArray | None:
        """``x`` from CHOLMOD for the union pattern holding ``values`` (None: not positive
        definite)."""
        assert self._cholmod is not None
        pattern, symbolic = self._cholmod
        pattern.V = cvxopt.matrix(values)
        if symbolic is None:
            symbolic = cvxopt.cholmod.symbolic(pattern, uplo="U")
            self._cholmod = (pattern, symbolic)
            self.analysed += 1
        else:
            self.reused += 1
        try:
            cvxopt.cholmod.numeric(pattern, symbolic)
        except ArithmeticError:  # a non-positive pivot
            return None
        x = cvxopt.matrix(b)
        cvxopt.cholmod.solve(symbolic, x)
        return np.array(x).ravel()
