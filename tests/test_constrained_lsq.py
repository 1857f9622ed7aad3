"""The augmented-Lagrangian least squares of the flat layout and the joint solve."""

from __future__ import annotations

import warnings

import numpy as np

from drawstring.geometry.constrained_lsq import (
    EdgeLeastSquares,
    SeparationRows,
    constrained_least_squares,
)


def test_an_infeasible_problem_stops_with_finite_numbers_and_reports_its_violation() -> None:
    # A right triangle whose first side must be 2 mm long one way and 2 mm long the other:
    # no point satisfies both rows.  The solver must say so (violation above 1 tolerance) and
    # stop without numerical overflow: its damping used to grow eightfold with every refused
    # trial of every multiplier round until it overflowed (RuntimeWarnings on the user's
    # terminal, eight wasted factorizations per round; 471 in all here).
    x0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    objective = EdgeLeastSquares(
        np.array([[0, 1], [0, 2], [1, 2]]), np.array([1.0, 1.0, np.sqrt(2.0)]), np.ones(3)
    )
    rows = SeparationRows(
        np.array([0, 0]), np.array([1, 1]), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.full(2, 2.0)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any overflow or invalid value fails the test
        x, steps, violation = constrained_least_squares(
            x0, objective, [rows], max_steps=5000, angle_tol=1e-3, length_tol=1e-4
        )
    assert np.all(np.isfinite(x))
    assert violation > 1.0  # infeasible, and reported as such
    assert steps < 200  # stalled rounds end at once instead of refactoring the same matrix


def test_a_feasible_problem_meets_its_rows_and_its_targets() -> None:
    # The same triangle with one row it can meet: the first side 1 mm along +x.  Known answer:
    # the triangle itself (already optimal), violation within the tolerance.
    x0 = np.array([[0.0, 0.0], [1.2, 0.1], [0.1, 0.9]])
    objective = EdgeLeastSquares(
        np.array([[0, 1], [0, 2], [1, 2]]), np.array([1.0, 1.0, np.sqrt(2.0)]), np.ones(3)
    )
    rows = SeparationRows(np.array([0]), np.array([1]), np.array([[1.0, 0.0]]), np.full(1, 0.5))
    x, _, violation = constrained_least_squares(
        x0, objective, [rows], max_steps=500, angle_tol=1e-3, length_tol=1e-6
    )
    assert violation <= 1.0
    assert np.allclose(objective.residual(x), 0.0, atol=1e-6)
    assert (x[1] - x[0]) @ np.array([1.0, 0.0]) >= 0.5 - 1e-6
