"""The repeated sparse SPD solver of the Levenberg-Marquardt loops: answers against dense
solves while the sparsity pattern repeats, shrinks, grows and returns."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from drawstring.geometry.solve import spd as spd_module
from drawstring.geometry.solve.spd import SpdSolver, _widest_row, upper_triangle, with_diagonal


def spd(n: int, density: float, seed: int) -> sp.csc_matrix:
    rng = np.random.default_rng(seed)
    rows = sp.random(3 * n, n, density=density, random_state=rng, format="csr")
    return sp.csc_matrix(rows.T @ rows + sp.identity(n))


def test_solves_match_dense_answers_as_the_pattern_changes() -> None:
    n = 60
    rhs = np.linspace(-1.0, 1.0, n)
    base = spd(n, 0.05, 0)
    extra = spd(n, 0.05, 1)
    other = spd(n, 0.05, 2)
    sequence = [base, 2.0 * base, base + extra, base, 3.0 * base + extra, extra, other]
    solver = SpdSolver()
    for matrix in sequence:
        x = solver.solve(matrix, rhs)
        np.testing.assert_allclose(x, np.linalg.solve(matrix.toarray(), rhs), rtol=1e-10)
    # base's pattern grows into base + extra's (one more analysis); base, 3 base + extra and
    # extra then fit inside it; ``other`` brings entries of its own
    assert solver.analysed == 3
    assert solver.reused == len(sequence) - 3


def test_a_reserved_pattern_is_analysed_once_for_every_matrix_inside_it() -> None:
    n = 60
    rhs = np.linspace(-1.0, 1.0, n)
    base, extra = spd(n, 0.05, 0), spd(n, 0.05, 1)
    solver = SpdSolver()
    solver.reserve(base + extra)
    for matrix in [base, base + extra, 2.0 * extra + sp.identity(n), base]:
        x = solver.solve(matrix, rhs)
        np.testing.assert_allclose(x, np.linalg.solve(matrix.toarray(), rhs), rtol=1e-10)
    assert solver.analysed == 1 and solver.reused == 3
    # reserving what is already there keeps the factor; a new entry makes a new analysis
    solver.reserve(base)
    solver.solve(base, rhs)
    assert solver.analysed == 1
    other = spd(n, 0.05, 2)
    solver.reserve(other)
    x = solver.solve(base, rhs)
    np.testing.assert_allclose(x, np.linalg.solve(base.toarray(), rhs), rtol=1e-10)
    assert solver.analysed == 2
    with pytest.raises(ValueError, match="reserve"):
        solver.reserve(spd(n + 1, 0.05, 3))


def test_a_full_symmetric_matrix_and_its_upper_triangle_give_the_same_answer() -> None:
    matrix = spd(40, 0.1, 2)
    rhs = np.arange(40.0)
    full = SpdSolver().solve(matrix, rhs)
    upper = SpdSolver().solve(sp.triu(matrix), rhs)
    np.testing.assert_allclose(full, upper, rtol=1e-12)


def test_upper_triangle_is_scipys_entry_for_entry() -> None:
    # explicit zeros included (scipy keeps them too), and a non-square case
    matrix = spd(50, 0.08, 3)
    matrix.data[::7] = 0.0
    wide = sp.csc_matrix(sp.random(30, 45, density=0.2, random_state=4, format="csc"))
    for case in (matrix, wide):
        case.sum_duplicates()
        expected = sp.csc_matrix(sp.triu(case, format="csc"))
        got = upper_triangle(case)
        assert got.shape == expected.shape
        for name in ("indptr", "indices", "data"):
            assert np.array_equal(getattr(got, name), getattr(expected, name)), name


def test_an_indefinite_matrix_falls_back_to_a_pivoting_solve() -> None:
    # a zero leading pivot breaks LDL^T without pivoting; LU with pivoting solves it
    matrix = sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 0.0]]))
    solver = SpdSolver()
    x = solver.solve(matrix, np.array([2.0, 3.0]))
    np.testing.assert_allclose(x, [3.0, 2.0])


def test_a_refactored_indefinite_matrix_is_not_answered_with_the_old_factor() -> None:
    # qdldl keeps its previous factor when a refactorization meets a zero pivot; the answer to
    # the first matrix must not come back for the second
    solver = SpdSolver()
    first = sp.csc_matrix(np.array([[2.0, 1.0], [1.0, 2.0]]))
    np.testing.assert_allclose(solver.solve(first, np.ones(2)), [1 / 3, 1 / 3])
    second = sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 2.0]]))
    np.testing.assert_allclose(solver.solve(second, np.ones(2)), [-1.0, 1.0])
    np.testing.assert_allclose(solver.solve(first, np.ones(2)), [1 / 3, 1 / 3])


def test_the_pivoting_fallback_reads_only_the_upper_triangle_too() -> None:
    matrix = sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 0.0]]))
    x = SpdSolver().solve(sp.triu(matrix), np.array([2.0, 3.0]))
    np.testing.assert_allclose(x, [3.0, 2.0])


def test_an_upper_triangle_whose_diagonal_changes_in_place_is_solved_afresh() -> None:
    # The Levenberg-Marquardt loop keeps one upper triangle per step and rewrites only its
    # diagonal (the damping) between tries: every try must see its own matrix.
    n = 40
    matrix = spd(n, 0.1, 3)
    upper = sp.csc_matrix(sp.triu(matrix, format="csc"))
    upper.sum_duplicates()
    at = upper.indptr[1:] - 1  # the diagonal closes every column of an upper triangle
    base = upper.data[at].copy()
    rhs = np.cos(np.arange(n, dtype=float))
    solver = SpdSolver()
    for damping in (0.0, 1.0, 1e3, 1e-3):
        upper.data[at] = base * (1.0 + damping)
        full = matrix + sp.diags(damping * base)
        x = solver.solve_upper(upper, rhs)
        np.testing.assert_allclose(x, np.linalg.solve(full.toarray(), rhs), rtol=1e-10)
    assert solver.analysed == 1


def test_large_patterns_go_to_the_supernodal_factor_with_the_same_answers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the CHOLMOD path, taken here at a low threshold: answers against dense solves while the
    # pattern repeats (numeric refactorizations only), grows (a new analysis) and the
    # diagonal changes in place; an indefinite matrix still falls back to SuperLU
    monkeypatch.setattr(spd_module, "SUPERNODAL_MIN_ENTRIES", 50)
    n = 60
    rhs = np.sin(np.arange(n, dtype=float))
    base = spd(n, 0.05, 0)
    extra = spd(n, 0.05, 1)
    solver = SpdSolver()
    for matrix in (base, 2.0 * base, base + extra, base, 3.0 * base + extra):
        x = solver.solve(matrix, rhs)
        np.testing.assert_allclose(x, np.linalg.solve(matrix.toarray(), rhs), rtol=1e-10)
    assert solver._cholmod is not None  # the path under test was taken
    assert solver.analysed == 2 and solver.reused == 3
    indefinite = base - 50.0 * sp.identity(n, format="csc")
    x = solver.solve(indefinite, rhs)
    np.testing.assert_allclose(x, np.linalg.solve(indefinite.toarray(), rhs), rtol=1e-8)
    x = solver.solve(base, rhs)
    np.testing.assert_allclose(x, np.linalg.solve(base.toarray(), rhs), rtol=1e-10)


def test_small_patterns_stay_with_qdldl() -> None:
    solver = SpdSolver()
    solver.solve(spd(60, 0.05, 0), np.ones(60))
    assert solver._cholmod is None


def test_with_diagonal_stores_every_diagonal_entry_as_adding_a_diagonal_matrix_would() -> None:
    # Columns 0 and 3 have no diagonal entry (column 3 none at all) and column 5 no entries;
    # damping added on the stored diagonal must give what adding a diagonal matrix gives.
    n = 6
    matrix = spd(n, 0.3, 5).tolil()
    matrix[0, 0] = 0.0
    matrix[3, :] = 0.0
    matrix[:, 3] = 0.0
    matrix[5, :] = 0.0
    matrix[:, 5] = 0.0
    matrix = sp.csc_matrix(matrix)
    matrix.eliminate_zeros()
    upper = with_diagonal(upper_triangle(matrix))
    at = upper.indptr[1:] - 1
    assert np.array_equal(upper.indices[at], np.arange(n))
    damping = np.linspace(1.0, 2.0, n)
    upper.data[at] += damping
    expected = sp.csc_matrix(sp.triu(matrix + sp.diags(damping), format="csc"))
    expected.sum_duplicates()
    for name in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(upper, name), getattr(expected, name)), name
    whole = sp.csc_matrix(spd(n, 0.5, 6))
    whole.sum_duplicates()  # canonical: sorted indices
    full = upper_triangle(whole)
    assert with_diagonal(full) is full  # nothing missing: unchanged


@pytest.mark.parametrize("seed", range(6))
def test_the_widest_row_counts_the_entries_of_the_symmetric_pattern(seed: int) -> None:
    # The backward-error check bounds the matrix norm with it: it must count every stored
    # entry of the densest row, on both sides of the diagonal, the diagonal once.
    rng = np.random.default_rng(seed)
    n = 25
    matrix = sp.random(n, n, density=0.15, random_state=rng, format="csc")
    matrix = sp.csc_matrix(matrix + matrix.T)
    matrix.sum_duplicates()
    upper = upper_triangle(matrix)
    if seed % 2:
        upper = with_diagonal(upper)  # explicit zeros count as stored
    cols = np.repeat(np.arange(n), np.diff(upper.indptr))
    mask = np.zeros((n, n), dtype=bool)
    mask[upper.indices, cols] = mask[cols, upper.indices] = True
    assert _widest_row(upper) == mask.sum(axis=1).max()


def test_an_empty_upper_triangle_gets_its_diagonal_and_no_row_width() -> None:
    empty = sp.csc_matrix((3, 3))
    assert _widest_row(empty) == 0
    filled = with_diagonal(empty)
    assert filled.nnz == 3 and np.array_equal(filled.indices, [0, 1, 2])
